"""Demonstration datasets from the simulator, written as LeRobot v3.0 datasets (lerobot 0.4.4).

Worker processes each simulate whole episodes (scene, scripted expert executed by physics,
camera frames); the parent writes them in seed order with lerobot's own writer. The dataset
is built in a temporary directory beside the target and renamed into place only after
``finalize()``, so an interrupted run leaves nothing half-written.

Layout (design.md): per frame at :data:`DATASET_FPS`,
``observation.images.front`` (128x128x3 image), ``observation.state`` (measured TCP pose +
finger opening), ``action`` (commanded pose + gripper of the next frame), the prompt as the
lerobot task, ``annotation.masks`` (128x128 uint8 label map of the frame), ``annotation.objects``
(JSON list of object names in label order) and ``annotation.scene`` (JSON
``{"task", "seed"}``: the scene this episode was recorded in); with scans (``--scan``, the
default of tasks that record them), also each episode's scan before the expert moves, on
every frame (``annotation.scan.<camera>`` and ``annotation.scan.cameras``, see
:mod:`cnfmp.scan`). With ``--joint-space``, ``observation.state`` and ``action`` are instead
the six joint angles of the simulator's arm (:mod:`cnfmp.sim.arm`, by inverse kinematics of
the same poses) + the gripper, named as a lerobot recording names them (:func:`motion_names`).
An episode whose expert run fails the judge is skipped (and reported); the next seed is used.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import shutil
import sys
import time

import numpy as np

from cnfmp.errors import InputError
from cnfmp.seeds import HELDOUT_SEEDS, TRAIN_SEEDS
from cnfmp.sim import scene as sc
from cnfmp.sim.task import check_seed
from cnfmp.sim.tasks import get_task

#: Frames per second of the datasets: every CONTROL_HZ / DATASET_FPS-th control step.
DATASET_FPS = 10
STATE_NAMES = ["x", "y", "z", "qw", "qx", "qy", "qz", "gripper"]
IMAGE_KEY = "observation.images.front"


def motion_names(joint_space: bool = False) -> list[str]:
    """Dimension names of ``observation.state`` and ``action``: the pose form STATE_NAMES, or
    the simulator arm's joints + gripper."""
    if not joint_space:
        return STATE_NAMES
    from cnfmp.sim import arm

    return [*arm.JOINT_NAMES, arm.GRIPPER_NAME]


def features(height: int = sc.IMAGE_SIZE, width: int = sc.IMAGE_SIZE, scan=None, joint_space: bool = False) -> dict:
    """The LeRobot feature specification of our datasets (simulated: 128x128 images;
    converted: the source camera's size), with the features of `scan`'s views when given
    (a :class:`cnfmp.scan.Scan` of the same rig); the motion in joint space with
    `joint_space`."""
    from cnfmp import scan as scans

    names = motion_names(joint_space)
    return {
        **(scans.dataset_features(scan) if scan is not None else {}),
        IMAGE_KEY: {"dtype": "image", "shape": (height, width, 3), "names": ["height", "width", "channels"]},
        "observation.state": {"dtype": "float32", "shape": (len(names),), "names": names},
        "action": {"dtype": "float32", "shape": (len(names),), "names": names},
        "annotation.masks": {"dtype": "uint8", "shape": (height, width), "names": ["height", "width"]},
        "annotation.objects": {"dtype": "string", "shape": (1,), "names": None},
        # (1,)-shaped numeric features fail to encode with numpy 2.4 in lerobot 0.4.4, so the
        # scene identity travels as a JSON string: {"task": ..., "seed": ...}.
        "annotation.scene": {"dtype": "string", "shape": (1,), "names": None},
    }


def simulate_episode(task_name: str, seed: int, scan: bool = False, joint_space: bool = False) -> dict:
    """Runs the expert for (task, seed) and records it at DATASET_FPS.

    Returns ``{"task", "seed", "success", "reasons", "prompt", "objects", "images" (N,128,128,3) uint8,
    "masks" (N,128,128) uint8, "state" (N,D) float32, "action" (N,D) float32, "scan"}``; "scan" is
    the scene's :class:`cnfmp.scan.Scan` before the episode when `scan`, else None; D is 8
    (the pose form), or 7 (the arm's joints + gripper) with `joint_space`.
    """
    from cnfmp.sim import engine
    from cnfmp.sim.scan import render_scan

    task = get_task(task_name)
    scene = task.scene(seed)
    scanned = render_scan(scene) if scan else None
    path = task.expert(scene)
    every = sc.CONTROL_HZ // DATASET_FPS
    sim = engine.Simulation(scene)
    try:
        log, images = sim.execute(path, frame_every=every)
    finally:
        sim.close()
    verdict = task.judge(scene, log)
    picked = np.arange(0, len(path["position"]), every)
    state = np.concatenate([log.ee_position[picked], log.ee_quat[picked], log.finger_opening[picked, None]], axis=1)
    nxt = np.minimum(picked + every, len(path["position"]) - 1)
    action = np.concatenate([path["position"][nxt], path["orientation"][nxt], path["gripper"][nxt, None]], axis=1)
    if joint_space:
        state, action = _in_joint_space(path, log, picked, nxt)
    rgb, masks = zip(*images)
    return {
        "task": task_name, "seed": seed, "success": verdict.success, "reasons": verdict.reasons,
        "prompt": scene.prompt, "objects": scene.objects,
        "images": np.stack(rgb), "masks": np.stack(masks),
        "state": state.astype(np.float32), "action": action.astype(np.float32), "scan": scanned,
    }


def _in_joint_space(path: dict, log, picked: np.ndarray, nxt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The (state, action) rows of an episode as the arm's joint angles + gripper: the
    commanded path solved at every control step (so the arm moves continuously), the action
    its next frame's angles, the state the measured pose solved from the commanded angles of
    the same frame."""
    from cnfmp.sim import arm

    kinematics = arm.Arm()
    commanded = kinematics.inverse(path["position"], path["orientation"])
    measured = np.stack([kinematics.inverse(log.ee_position[k:k + 1], log.ee_quat[k:k + 1], commanded[k])[0]
                         for k in picked])
    state = np.concatenate([measured, log.finger_opening[picked, None]], axis=1)
    action = np.concatenate([commanded[nxt], path["gripper"][nxt, None]], axis=1)
    return state, action


def _worker_init() -> None:
    from cnfmp import runtime

    runtime.configure(threads=1)


def _simulate(args):
    return simulate_episode(*args)


def _check_request(task: str, episodes: int, seed: int, out_dir: str) -> None:
    get_task(task)
    check_seed(seed)
    if not isinstance(episodes, (int, np.integer)) or episodes <= 0:
        raise InputError(f"--episodes must be a whole number > 0, got {episodes}")
    if os.path.exists(out_dir):
        raise InputError(f"{out_dir} already exists; datasets are never overwritten, choose a new --out")
    for split in (TRAIN_SEEDS, HELDOUT_SEEDS):
        if seed in split and seed + episodes - 1 >= split.stop:
            raise InputError(f"seeds {seed}..{seed + episodes - 1} cross the end of the "
                             f"{'training' if split is TRAIN_SEEDS else 'held-out'} range "
                             f"{split.start}..{split.stop - 1}; training and held-out seeds must stay disjoint")


def generate_dataset(task: str, episodes: int, seed: int, out_dir: str, workers: int = 2,
                     progress: bool = True, scan: bool | None = None, joint_space: bool = False) -> str:
    """Writes a LeRobot dataset of `episodes` successful expert demonstrations of `task`,
    from seeds `seed`, `seed + 1`, ... (a seed whose expert run fails is skipped), with each
    episode's scan when `scan` (None: when the task records scans, ``Task.records_scans``),
    its motion as the simulator arm's joint angles with `joint_space`.

    Returns JSON ``{"out", "episodes", "frames", "seeds", "skipped_seeds", "seconds",
    "episodes_per_second"}``. Raises InputError for an unknown task, episodes <= 0, an
    existing `out_dir`, or a seed range that crosses the training/held-out boundary.
    """
    import datasets
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    datasets.disable_progress_bars()  # one bar per episode write would drown ours
    _check_request(task, episodes, seed, out_dir)
    if scan is None:
        scan = get_task(task).records_scans
    out_dir = os.path.abspath(out_dir)
    parent = os.path.dirname(out_dir)
    os.makedirs(parent, exist_ok=True)
    staging = os.path.join(parent, f".{os.path.basename(out_dir)}.partial-{os.getpid()}")
    shutil.rmtree(staging, ignore_errors=True)
    start = time.perf_counter()
    written, skipped, frames = [], [], 0
    bar = progress_bar(episodes, f"{task}", progress)
    context = multiprocessing.get_context("spawn")  # fork is unsafe in a threaded (embedded) parent
    try:
        dataset = None  # created with the first episode, whose scan says the views' features
        with context.Pool(workers, initializer=_worker_init) as pool:
            next_seed = seed
            while len(written) < episodes:
                # Ask for exactly as many episodes as are missing (more after skipped seeds).
                batch = [(task, s, scan, joint_space) for s in range(next_seed, next_seed + episodes - len(written))]
                next_seed += len(batch)
                for episode in pool.imap(_simulate, batch):
                    if not episode["success"]:
                        skipped.append(episode["seed"])
                        continue
                    if dataset is None:
                        dataset = LeRobotDataset.create(repo_id=f"cnfmp/{task}", fps=DATASET_FPS,
                                                        features=features(scan=episode["scan"], joint_space=joint_space),
                                                        root=staging, use_videos=False,
                                                        robot_type="cnfmp_arm" if joint_space else "cnfmp_floating_gripper")
                    frames += _write_episode(dataset, episode)
                    written.append(episode["seed"])
                    bar.update(1)
                if len(skipped) > max(5, episodes // 10):
                    raise RuntimeError(f"the {task} expert failed on {len(skipped)} seeds {skipped[:10]}...; "
                                       "the simulator or expert is broken")
        dataset.finalize()
        os.rename(staging, out_dir)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    finally:
        bar.close()
    seconds = time.perf_counter() - start
    return json.dumps({"out": out_dir, "episodes": len(written), "frames": frames, "seeds": written,
                       "skipped_seeds": skipped, "seconds": seconds,
                       "episodes_per_second": len(written) / seconds})


def _write_episode(dataset, episode: dict) -> int:
    from cnfmp import scan as scans

    objects = json.dumps(episode["objects"])
    scene = json.dumps({"task": episode["task"], "seed": episode["seed"]})
    scanned = scans.dataset_values(episode["scan"]) if episode["scan"] is not None else {}
    for i in range(len(episode["images"])):
        dataset.add_frame({
            **scanned,
            IMAGE_KEY: episode["images"][i],
            "observation.state": episode["state"][i],
            "action": episode["action"][i],
            "annotation.masks": episode["masks"][i],
            "annotation.objects": objects,
            "annotation.scene": scene,
            "task": episode["prompt"],
        })
    dataset.save_episode()
    return len(episode["images"])


def progress_bar(total: int, label: str, enabled: bool):
    """A tqdm bar on stderr counting episodes (disabled when `enabled` is false)."""
    from tqdm import tqdm

    return tqdm(total=total, desc=label, unit="episode", disable=not enabled, file=sys.stderr,
                dynamic_ncols=True)
