"""Entry points of the simulator for the Rust bridge (and notebooks): small functions with
plain arguments; bad input raises :class:`cnfmp.errors.InputError`.

Trajectories cross as numpy arrays at :data:`CONTROL_HZ`: the Rust side resamples a
trajectory file to this rate before calling :func:`execute`.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile

import numpy as np

from cnfmp.errors import InputError
from cnfmp.sim import engine
from cnfmp.sim.scene import CONTROL_HZ
from cnfmp.sim.task import check_seed, get_task, task_names

__all__ = ["CONTROL_HZ", "execute", "expert", "render", "task_names", "tasks_json"]


def tasks_json() -> str:
    """``[{"name", "description"}]`` for every task, as JSON."""
    return json.dumps([{"name": n, "description": get_task(n).description} for n in task_names()])


def _scene(task: str, seed: int):
    check_seed(seed)
    return get_task(task), get_task(task).scene(int(seed))


def render(task: str, seed: int, out_dir: str) -> str:
    """Writes the camera's view of the scene at the start of an episode (the gripper at its
    start pose, out of view for every task but wall_avoidance), exactly what frame 0 of a
    dataset episode shows, so a model sees the same kind of image it was trained on.

    Files in `out_dir` (created; must not exist or be empty): ``image.png`` (128x128 RGB),
    ``masks.png`` (128x128 8-bit label map: 0 background, k the k-th object),
    ``objects.json`` (``{"task", "seed", "prompt", "objects": [names in label order]}``).
    Written to a temporary directory first and renamed, so a failure leaves nothing behind.
    Returns the objects.json content.
    """
    from PIL import Image

    _, scene = _scene(task, seed)
    if os.path.exists(out_dir) and (not os.path.isdir(out_dir) or os.listdir(out_dir)):
        raise InputError(f"{out_dir} already exists and is not an empty directory; choose a new --out")
    sim = engine.Simulation(scene)
    try:
        rgb, labels = sim.render_rgb(), sim.render_labels()
    finally:
        sim.close()
    info = {"task": scene.task, "seed": scene.seed, "prompt": scene.prompt, "objects": scene.objects}
    parent = os.path.dirname(os.path.abspath(out_dir))
    os.makedirs(parent, exist_ok=True)
    staging = tempfile.mkdtemp(prefix=".cnfmp-render-", dir=parent)
    try:
        Image.fromarray(rgb).save(os.path.join(staging, "image.png"))
        Image.fromarray(labels).save(os.path.join(staging, "masks.png"))
        with open(os.path.join(staging, "objects.json"), "w", encoding="utf-8") as f:
            json.dump(info, f, indent=2)
            f.write("\n")
        if os.path.isdir(out_dir):
            os.rmdir(out_dir)  # empty (checked above); rename needs the name free
        os.rename(staging, out_dir)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return json.dumps(info)


def expert(task: str, seed: int) -> dict:
    """The scripted expert's trajectory for (task, seed) at CONTROL_HZ.

    Returns ``{"fps": float, "t": (T,), "position": (T, 3), "orientation": (T, 4) wxyz,
    "gripper": (T,), "prompt": str}`` (float64 arrays).
    """
    task_obj, scene = _scene(task, seed)
    path = task_obj.expert(scene)
    return {"fps": float(CONTROL_HZ), "prompt": scene.prompt,
            **{k: np.ascontiguousarray(path[k], dtype=np.float64) for k in ("t", "position", "orientation", "gripper")}}


def execute(task: str, seed: int, position, orientation, gripper) -> str:
    """Executes a trajectory sampled at CONTROL_HZ in the (task, seed) scene and judges it.

    Args:
        position: (T, 3) TCP positions (m); orientation: (T, 4) quaternions wxyz;
            gripper: (T,) opening commands in [0, 1].

    Returns JSON ``{"task", "seed", "prompt", "success", "reasons", "metrics", "frames",
    "duration_s"}``. Raises InputError when a frame leaves the workspace.
    """
    task_obj, scene = _scene(task, seed)
    trajectory = {"position": position, "orientation": orientation, "gripper": gripper}
    verdict = engine.run_episode(scene, trajectory, task_obj.judge)
    frames = len(np.asarray(position))
    return json.dumps({
        "task": scene.task, "seed": scene.seed, "prompt": scene.prompt,
        "success": verdict.success, "reasons": verdict.reasons, "metrics": verdict.metrics,
        "frames": frames, "duration_s": frames / CONTROL_HZ,
    })
