"""Where a core model's trajectories go wrong: the pose error against the expert at each of
the expert's releases (the gripper opening after a hold), and the physics verdict.

For each scene: render, predict from the image and the simulator's masks (as `cnfmp eval`
does), compare the predicted trajectory with the scripted expert's at the frames where the
expert opens the gripper (horizontal position error, height error, angle between the two
finger axes), and execute the prediction. Run it on the model's own training scenes and on
validation scenes (training-range seeds it never saw, by default from the first validation
seed) to tell a model that cannot fit its demonstrations from one that does not generalise.
Held-out seeds are refused, so nothing is tuned on them.

    .venv/bin/python scripts/release-errors.py --model models/cup_stacking --seed-start 0 --scenes 20
    .venv/bin/python scripts/release-errors.py --model models/cup_stacking --seed-start 500000 --scenes 20

Prints one line per scene, then a JSON summary: success rate and the mean and 90th percentile
of each error over all releases.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from cnfmp import runtime

runtime.configure(threads=1)  # before torch loads: one thread, deterministic kernels, as the CLI runs

from cnfmp import geometry  # noqa: E402
from cnfmp.core import api as core, trial  # noqa: E402
from cnfmp.seeds import VALIDATION_SEEDS  # noqa: E402
from cnfmp.sim import api as sim  # noqa: E402
from cnfmp.sim.engine import CLOSED_BELOW  # noqa: E402


def release_frames(gripper: np.ndarray) -> list[int]:
    """Frames (indices) where the gripper command crosses from closed to open, as the
    simulator's judge counts a release."""
    return [i for i in range(1, len(gripper)) if gripper[i - 1] < CLOSED_BELOW <= gripper[i]]


def finger_axis(quat: np.ndarray) -> np.ndarray:
    """The gripper's finger axis (its local z) in the world for a wxyz quaternion."""
    return geometry.to_rotation(quat).apply([0.0, 0.0, 1.0])


def scene_errors(model_dir: str, task: str, seed: int) -> dict:
    """Predicts and executes one scene; returns its verdict and per-release errors: horizontal
    position (cm), height (cm, predicted minus expert) and finger axis (deg)."""
    image, labels, info = trial.render(task, seed)
    position, orientation, gripper = trial.trajectory_arrays(json.loads(core.predict(model_dir, image, labels,
                                                                                      info["objects"])))
    expert = sim.expert(task, seed)
    shared = min(len(position), len(expert["position"]))
    errors = {"xy_cm": [], "z_cm": [], "axis_deg": []}
    for i in release_frames(expert["gripper"][:shared]):
        errors["xy_cm"].append(float(np.linalg.norm(position[i, :2] - expert["position"][i, :2]) * 100))
        errors["z_cm"].append(float((position[i, 2] - expert["position"][i, 2]) * 100))
        cosine = float(np.clip(finger_axis(orientation[i]) @ finger_axis(expert["orientation"][i]), -1.0, 1.0))
        errors["axis_deg"].append(float(np.degrees(np.arccos(cosine))))
    success, reasons = trial.execute(task, seed, position, orientation, gripper)
    return {"seed": seed, "success": success, "reasons": reasons, **errors}


def summary(rows: list[dict]) -> dict:
    """Success rate and, per error, mean and 90th percentile over every release."""
    out: dict = {"scenes": len(rows), "success": sum(r["success"] for r in rows) / max(1, len(rows))}
    for name in ("xy_cm", "z_cm", "axis_deg"):
        values = np.abs(np.concatenate([r[name] for r in rows])) if rows else np.zeros(0)
        out[name] = ({"mean": round(float(values.mean()), 2), "p90": round(float(np.percentile(values, 90)), 2)}
                     if values.size else None)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", required=True, help="core model directory")
    parser.add_argument("--task", default=None, help="task (default: the model's)")
    parser.add_argument("--seed-start", type=int, default=VALIDATION_SEEDS.start,
                        help=f"first scene seed (0.. are the demonstrations' scenes; default {VALIDATION_SEEDS.start})")
    parser.add_argument("--scenes", type=int, default=20)
    args = parser.parse_args()
    problem = trial.validation_range_error(args.seed_start, args.scenes)
    if problem:
        parser.error(problem)
    task = args.task or core.predictor(args.model).config.task
    rows = []
    for seed in range(args.seed_start, args.seed_start + args.scenes):
        rows.append(scene_errors(args.model, task, seed))
        row = rows[-1]
        print(f"seed {seed}: {'success' if row['success'] else 'failure'}; at release xy "
              f"{[round(v, 2) for v in row['xy_cm']]} cm, z {[round(v, 2) for v in row['z_cm']]} cm, "
              f"finger axis {[round(v, 1) for v in row['axis_deg']]} deg", flush=True)
    print(json.dumps({"model": args.model, "task": task, "seed_start": args.seed_start, **summary(rows)}))


if __name__ == "__main__":
    main()
