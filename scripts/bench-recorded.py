"""The re-recorded benchmark: a simulated task's demonstrations recorded as a lab records
them, then annotated, trained and judged by physics on held-out scenes.

1. Record: `--demos` expert demonstrations (training seeds from 0), each re-timed with its
   own speed profile (duration scaled by a factor in [0.7, 1.3], up to two pauses of up to
   0.5 s at random moments), its scene rendered by the task's camera at 640x480 (same
   vertical field of view as the 128x128 benchmark camera, so it sees more of the table on
   the sides), written by lerobot at 15 fps as video, with the task prompt and no masks
   (`<work>/recording`).
2. Annotate with the language segmenter (`cnfmp.data.annotate`, the code of `cnfmp dataset
   annotate`): throughput, and the IoU of its masks against the simulator's.
3. Train with and without alignment by gripper events (`--config` files as `cnfmp train`).
4. For each model, `--scenes` held-out scenes: rendered at 640x480, masks from the
   segmenter on the scene's prompt, predict, execute by physics; success and MED (cm) against
   the expert.

Prints one JSON line per stage.

    .venv/bin/python scripts/bench-recorded.py --task wall_avoidance --work /tmp/rerecorded
"""

from __future__ import annotations

import argparse
import json
import os
import re
import time

import numpy as np

from cnfmp import runtime

runtime.configure(threads=1)  # before torch loads, as the CLI runs

from cnfmp.core import api as core, trial  # noqa: E402
from cnfmp.core.training import train  # noqa: E402
from cnfmp.data import annotate, generate  # noqa: E402
from cnfmp.images import encode_png  # noqa: E402
from cnfmp.seeds import HELDOUT_SEEDS, TRAIN_SEEDS  # noqa: E402
from cnfmp.segmenter.api import backend  # noqa: E402

WIDTH, HEIGHT, FPS = 640, 480, 15
CAMERA = "observation.images.front"


def render(task: str, seed: int) -> tuple[np.ndarray, np.ndarray, str]:
    """The scene of (task, seed) as the task's camera sees it at WIDTH x HEIGHT, gripper parked
    out of view: (image (H, W, 3) uint8, label map (H, W) uint8, prompt)."""
    from cnfmp.sim import engine
    from cnfmp.sim.tasks import get_task

    scene = get_task(task).scene(seed)
    simulation = engine.Simulation(scene)
    try:
        simulation.set_camera_size(WIDTH, HEIGHT)
        image, labels = simulation.render_scene()
    finally:
        simulation.close()
    return image, labels, scene.prompt


def retime(values: np.ndarray, source_fps: float, rng: np.random.Generator) -> np.ndarray:
    """(T, D) values at `source_fps` replayed at FPS with a random speed profile: the duration
    scaled by U(0.7, 1.3), then up to two pauses of U(0, 0.5) s (the pose held)."""
    duration = (len(values) - 1) / source_fps * rng.uniform(0.7, 1.3)
    source = np.linspace(0, len(values) - 1, int(round(duration * FPS)) + 1)
    for _ in range(rng.integers(0, 3)):
        at = rng.integers(1, len(source) - 1)
        source = np.concatenate([source[:at], np.full(int(round(rng.uniform(0, 0.5) * FPS)), source[at]), source[at:]])
    return np.stack([np.interp(source, np.arange(len(values)), column) for column in values.T], axis=1)


def record(task: str, demos: int, out: str, seed: int) -> dict:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    rng = np.random.default_rng(seed)
    names = generate.STATE_NAMES
    dataset = LeRobotDataset.create(repo_id=f"bench/{task}", fps=FPS, root=out, use_videos=True, features={
        CAMERA: {"dtype": "video", "shape": (HEIGHT, WIDTH, 3), "names": ["height", "width", "channels"]},
        "observation.state": {"dtype": "float32", "shape": (8,), "names": names},
        "action": {"dtype": "float32", "shape": (8,), "names": names}})
    truth, durations = [], []
    for scene_seed in range(TRAIN_SEEDS.start, TRAIN_SEEDS.start + demos):
        episode = generate.simulate_episode(task, scene_seed)
        both = retime(np.concatenate([episode["state"], episode["action"]], axis=1), generate.DATASET_FPS, rng)
        both[:, 3:7] /= np.linalg.norm(both[:, 3:7], axis=1, keepdims=True)
        both[:, 11:15] /= np.linalg.norm(both[:, 11:15], axis=1, keepdims=True)
        frame, labels, _ = render(task, scene_seed)
        for row in both.astype(np.float32):
            dataset.add_frame({CAMERA: frame, "observation.state": row[:8], "action": row[8:], "task": episode["prompt"]})
        dataset.save_episode()
        truth.append(labels)
        durations.append(len(both) / FPS)
    dataset.finalize()
    return {"truth": truth, "durations_s": [round(d, 2) for d in durations]}


def mask_iou(found: np.ndarray, truth: np.ndarray) -> list[float]:
    """Per annotated object (label of `found`), the IoU of its mask against the simulator's
    object it overlaps most (label maps of one frame)."""
    ious = []
    for k in range(1, int(found.max()) + 1):
        mask = found == k
        ious.append(max(float((mask & (truth == j)).sum() / max(1, (mask | (truth == j)).sum()))
                        for j in range(1, int(truth.max()) + 1)))
    return ious


def evaluate(model_dir: str, task: str, scenes: int, segmenter) -> dict:
    successes, meds, failures = 0, [], {}
    for seed in range(HELDOUT_SEEDS.start, HELDOUT_SEEDS.start + scenes):
        frame, _, prompt = render(task, seed)
        found = annotate.annotate_image(frame, prompt, None, segmenter)
        if found["missing"]:
            failures["not segmented"] = failures.get("not segmented", 0) + 1
            continue
        prediction = json.loads(core.predict(model_dir, encode_png(frame), encode_png(found["labels"]), found["objects"]))
        position, orientation, gripper = trial.trajectory_arrays(prediction)
        success, reasons = trial.execute(task, seed, position, orientation, gripper)
        successes += success
        for reason in reasons:
            kind = re.sub(r"[-+]?\d+(\.\d+)?", "#", reason).split(":")[0]  # one count per kind of failure
            failures[kind] = failures.get(kind, 0) + 1
        from cnfmp.sim import api as sim

        expert = sim.expert(task, seed)
        times = np.arange(len(position)) / prediction["fps"]
        reference = np.stack([np.interp(times, expert["t"], c) for c in expert["position"].T], axis=1)
        meds.append(100 * float(np.linalg.norm(position - reference, axis=1).mean()))
    return {"success": successes / scenes, "med_cm": round(float(np.mean(meds)), 2) if meds else None,
            "failures": failures}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="wall_avoidance")
    parser.add_argument("--demos", type=int, default=20)
    parser.add_argument("--scenes", type=int, default=100)
    parser.add_argument("--work", required=True, help="working directory (created; must not exist)")
    parser.add_argument("--config", action="append", default=[], help="config file for training (repeatable)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the speed profiles (training seeds come from the config)")
    args = parser.parse_args()
    os.makedirs(args.work)
    recording, annotated = os.path.join(args.work, "recording"), os.path.join(args.work, "annotated")
    started = time.perf_counter()
    recorded = record(args.task, args.demos, recording, args.seed)
    print(json.dumps({"stage": "record", "demos": args.demos, "seconds": round(time.perf_counter() - started, 1),
                      "durations_s": recorded["durations_s"]}), flush=True)

    started = time.perf_counter()
    report = json.loads(annotate.annotate(recording, annotated, progress=False))
    seconds = time.perf_counter() - started
    from cnfmp.core.data import load_demonstrations

    demos = load_demonstrations(annotated)
    ious = [iou for masks, truth in zip(demos.masks, recorded["truth"]) for iou in mask_iou(masks, truth)]
    print(json.dumps({"stage": "annotate", "annotated": report["annotated"], "skipped": len(report["skipped"]),
                      "episodes_per_s": round(report["episodes"] / seconds, 2), "mask_iou_mean": round(float(np.mean(ious)), 3),
                      "mask_iou_min": round(float(np.min(ious)), 3)}), flush=True)

    segmenter = backend("auto")
    for aligned in (True, False):
        model = os.path.join(args.work, "model-aligned" if aligned else "model-as-recorded")
        summary = json.loads(train(annotated, model, args.config, progress=False, align_time=aligned))
        result = evaluate(model, args.task, args.scenes, segmenter)
        print(json.dumps({"stage": "evaluate", "aligned": aligned, "train_seconds": summary["seconds"],
                          "scenes": args.scenes, **result}), flush=True)


if __name__ == "__main__":
    main()
