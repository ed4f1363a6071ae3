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
from cnfmp.sim.scene import CONTROL_HZ, IMAGE_SIZE, project_to_image
from cnfmp.sim.task import check_seed
from cnfmp.sim.tasks import get_task, task_names

__all__ = ["CONTROL_HZ", "draw_trajectory", "execute", "expert", "forward_kinematics", "render", "task_names",
           "tasks_json"]

#: Trajectory overlays are drawn this large (px) so the path is legible.
_OVERLAY_SIDE = 512


def tasks_json() -> str:
    """``[{"name", "description"}]`` for every task, as JSON."""
    return json.dumps([{"name": n, "description": get_task(n).description} for n in task_names()])


def _scene(task: str, seed: int):
    check_seed(seed)
    return get_task(task), get_task(task).scene(int(seed))


def render(task: str, seed: int, out_dir: str, scan: bool = False) -> str:
    """Writes the camera's view of the scene at the start of an episode (the gripper at its
    start pose, out of view for every task but wall_avoidance), exactly what frame 0 of a
    dataset episode shows, so a model sees the same kind of image it was trained on.

    Files in `out_dir` (created; must not exist or be empty): ``image.png`` (128x128 RGB),
    ``masks.png`` (128x128 8-bit label map: 0 background, k the k-th object),
    ``objects.json`` (``{"task", "seed", "prompt", "objects": [names in label order]}``);
    with `scan`, ``scan/``: the scene's depth scan from the four fixed cameras
    (:mod:`cnfmp.sim.scan`, the gripper parked). Written to a temporary directory first
    and renamed, so a failure leaves nothing behind.
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
        if scan:
            from cnfmp import scan as scans
            from cnfmp.sim.scan import render_scan

            scans.write_scan(render_scan(scene), os.path.join(staging, "scan"))
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


def forward_kinematics(joint_names: list[str], fps: float, t, joints, gripper) -> dict:
    """A joint-space trajectory of the simulator's arm (:mod:`cnfmp.sim.arm`) as the tool
    poses it puts the gripper at: how `cnfmp eval` executes and scores a joint-space model.

    Args:
        joint_names: the trajectory's joints, which must be the arm's (arm.JOINT_NAMES).
        fps: its rate (Hz); t: (T,) s; joints: (T, 6) rad; gripper: (T,) in [0, 1].

    Returns ``{"fps", "t", "position" (T, 3), "orientation" (T, 4) wxyz, "gripper"}``.
    InputError for joints that are not the arm's.
    """
    from cnfmp.sim import arm

    if not arm.is_arm_joints(joint_names):
        raise InputError(f"the trajectory's joints ({', '.join(joint_names)}) are not the simulator arm's "
                         f"({', '.join(arm.JOINT_NAMES)}), so the simulator cannot execute it; a joint-space model "
                         "can be evaluated here only when it was trained on `cnfmp dataset generate --joint-space` data")
    position, orientation = arm.Arm().forward(np.asarray(joints, np.float64))
    return {"fps": float(fps), "t": np.ascontiguousarray(t, dtype=np.float64), "position": position,
            "orientation": orientation, "gripper": np.ascontiguousarray(gripper, dtype=np.float64)}


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


def draw_trajectory(image_data: bytes, labels_data: bytes | None, position, gripper) -> bytes:
    """A picture of a predicted motion: the scene image (upscaled to 512 px) with each
    labelled object tinted and outlined, and the end-effector path projected through the
    front camera, coloured from blue (start) to red (end), with a ring wherever the gripper
    closes or opens.

    Args:
        image_data: the encoded camera image (128x128, the simulator camera's view).
        labels_data: an encoded 8-bit label map of the same size, or None.
        position: (T, 3) TCP positions (m); gripper: (T,) openings in [0, 1].

    Returns the PNG bytes.
    """
    import cv2

    from cnfmp.images import decode_image, decode_labels, encode_png

    image = decode_image(image_data)
    height, width = image.shape[:2]
    scale = _OVERLAY_SIDE / max(height, width)
    big = cv2.resize(image, (round(width * scale), round(height * scale)), interpolation=cv2.INTER_NEAREST)
    if labels_data is not None:
        labels = decode_labels(labels_data)
        if labels.shape != (height, width):
            raise InputError(f"the label map is {labels.shape[1]}x{labels.shape[0]} but the image is {width}x{height}")
        labels = cv2.resize(labels, big.shape[1::-1], interpolation=cv2.INTER_NEAREST)
        for label in range(1, int(labels.max(initial=0)) + 1):
            mask = (labels == label).astype(np.uint8)
            colour = np.array(_LABEL_COLOURS[(label - 1) % len(_LABEL_COLOURS)], dtype=np.float64)
            big[mask > 0] = (0.6 * big[mask > 0] + 0.4 * colour).astype(np.uint8)
            contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            cv2.drawContours(big, contours, -1, tuple(int(c) for c in colour), 2, cv2.LINE_AA)
    position = np.asarray(position, dtype=np.float64).reshape(-1, 3)
    gripper = np.asarray(gripper, dtype=np.float64).reshape(-1)
    pixels = project_to_image(position) * (big.shape[1] / IMAGE_SIZE)
    visible = np.isfinite(pixels).all(axis=1)
    points = np.round(np.where(visible[:, None], pixels, 0.0)).astype(np.int64)
    steps = max(len(points) - 1, 1)
    for k in range(len(points) - 1):
        if visible[k] and visible[k + 1]:
            colour = (int(255 * k / steps), 40, int(255 * (1 - k / steps)))
            cv2.line(big, tuple(map(int, points[k])), tuple(map(int, points[k + 1])), colour, 2, cv2.LINE_AA)
    closed = gripper < 0.5
    for k in np.flatnonzero(closed[1:] != closed[:-1]) + 1:
        if visible[k]:
            cv2.circle(big, tuple(map(int, points[k])), 9, (255, 255, 255), 2, cv2.LINE_AA)
    return encode_png(big)


#: Object tints (RGB) per label, cycled.
_LABEL_COLOURS = [(230, 25, 75), (60, 180, 75), (0, 130, 200), (245, 130, 48), (145, 30, 180)]
