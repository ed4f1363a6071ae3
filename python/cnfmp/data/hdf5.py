"""Reading robomimic-style HDF5 demonstration files (via h5py) for `cnfmp dataset convert`.

Layout read (robomimic / robosuite conventions)::

    data/                       attrs: env_args (JSON, optional: env_kwargs.control_freq = fps,
                                       env_name), problem_info (JSON, optional: language_instruction)
      demo_<k>/                 attrs: lang | language_instruction | instruction (optional),
                                       objects (JSON list, optional: names of the mask labels)
        obs/<camera>_image      (T, H, W, 3) uint8 RGB
        obs/<camera>_masks      (T, H, W) or (H, W) uint8 label map (optional, cnfmp extension)
        obs/robot0_eef_pos      (T, 3) metres
        obs/robot0_eef_quat     (T, 4) quaternion in robosuite's [x, y, z, w] order
        obs/robot0_gripper_qpos (T, 2) finger joint positions (m), or (T, 1)
        actions                 (T, A) (read only to check the episode length)

The camera is ``agentview`` when present, else the first ``*_image`` key in name order.
Gripper opening = finger separation / :data:`GRIPPER_MAX_OPENING` (Panda: 0.08 m), clipped
to [0, 1]. h5py serialises all access behind one global lock, so demos are read one at a
time; the caller parallelises the rest (validation, resampling, PNG encoding).
"""

from __future__ import annotations

import json
import os
import re

import numpy as np

from cnfmp.errors import InputError

#: Finger separation (m) of a fully open gripper (Franka Panda: two fingers of 0.04 m).
GRIPPER_MAX_OPENING = 0.08
#: Control rate of robomimic datasets when the file does not say (Hz).
DEFAULT_FPS = 20.0


def _open(path: str):
    import h5py

    if not os.path.isfile(path):
        raise InputError(f"{path}: no such file")
    try:
        handle = h5py.File(path, "r")
    except OSError as err:
        raise InputError(f"{path}: not a readable HDF5 file ({err})") from err
    if "data" not in handle:
        handle.close()
        raise InputError(f"{path}: no 'data' group; robomimic files keep demos under data/demo_<k>")
    return handle


def _json_attr(group, name: str) -> dict:
    value = group.attrs.get(name)
    if value is None:
        return {}
    try:
        parsed = json.loads(value.decode() if isinstance(value, bytes) else str(value))
    except ValueError:
        return {}
    return parsed if isinstance(parsed, dict) else {}


def list_demos(path: str) -> str:
    """JSON ``{"demos": [names in numeric order], "fps": Hz (the file's control_freq, else
    :data:`DEFAULT_FPS`), "fps_recorded": bool, "camera": name or null}``."""
    with _open(path) as handle:
        data = handle["data"]
        demos = sorted((name for name in data if re.fullmatch(r"demo_\d+", name)), key=lambda n: int(n[5:]))
        fps = _json_attr(data, "env_args").get("env_kwargs", {}).get("control_freq")
        camera = None
        if demos and "obs" in data[demos[0]]:
            cameras = sorted(key[:-6] for key in data[demos[0]]["obs"] if key.endswith("_image"))
            camera = "agentview" if "agentview" in cameras else (cameras[0] if cameras else None)
    return json.dumps({"demos": demos, "fps": float(fps) if fps else DEFAULT_FPS, "fps_recorded": bool(fps),
                       "camera": camera})


def read_demo(path: str, demo: str, camera: str | None) -> dict:
    """One demo as arrays: ``{"images" (T,H,W,3) uint8, "masks" (H,W) uint8, "objects",
    "position" (T,3), "orientation" (T,4) [w,x,y,z], "gripper" (T,), "prompt"}``.

    Raises InputError naming the dataset (``data/demo_3/obs/robot0_eef_quat``) and the reason
    for a missing or malformed field.
    """
    with _open(path) as handle:
        data = handle["data"]
        if demo not in data:
            raise InputError(f"data/{demo}: no such demo")
        group = data[demo]

        def field(name: str, shape_tail: tuple, dtype=None) -> np.ndarray:
            if name not in group:
                raise InputError(f"data/{demo}/{name}: missing")
            values = np.asarray(group[name])
            if values.ndim != 1 + len(shape_tail) or any(t is not None and values.shape[1 + i] != t for i, t in enumerate(shape_tail)):
                raise InputError(f"data/{demo}/{name}: shape {values.shape}, expected (T, {', '.join(str(t or 'any') for t in shape_tail)})")
            if dtype is not None and values.dtype != dtype:
                raise InputError(f"data/{demo}/{name}: dtype {values.dtype}, expected {np.dtype(dtype).name}")
            return values

        if camera is None:
            raise InputError(f"data/{demo}/obs: no <camera>_image dataset")
        images = field(f"obs/{camera}_image", (None, None, 3), np.uint8)
        position = field("obs/robot0_eef_pos", (3,)).astype(np.float64)
        quat_xyzw = field("obs/robot0_eef_quat", (4,)).astype(np.float64)
        qpos = field("obs/robot0_gripper_qpos", (None,)).astype(np.float64)
        lengths = {len(images), len(position), len(quat_xyzw), len(qpos)}
        if "actions" in group:
            lengths.add(len(group["actions"]))
        if len(lengths) != 1:
            raise InputError(f"data/{demo}: images, eef_pos, eef_quat, gripper_qpos and actions differ in length {sorted(lengths)}")
        separation = qpos[:, 0] - qpos[:, 1] if qpos.shape[1] >= 2 else 2 * qpos[:, 0]
        masks_key = f"obs/{camera}_masks"
        if masks_key in group:
            masks = np.asarray(group[masks_key])
            masks = masks[0] if masks.ndim == 3 else masks
            if masks.shape != images.shape[1:3]:
                raise InputError(f"data/{demo}/{masks_key}: masks {masks.shape} do not match the images {images.shape[1:3]}")
        else:
            masks = np.zeros(images.shape[1:3], np.uint8)
        objects = group.attrs.get("objects")
        objects = json.loads(objects) if objects is not None else []
        prompt = next((str(group.attrs[key]) for key in ("lang", "language_instruction", "instruction") if key in group.attrs), None)
        if prompt is None:
            prompt = _json_attr(data, "problem_info").get("language_instruction") or \
                _json_attr(data, "env_args").get("env_name") or os.path.splitext(os.path.basename(path))[0]
        return {
            "images": np.ascontiguousarray(images),
            "masks": np.ascontiguousarray(masks.astype(np.uint8)),
            "objects": [str(name) for name in objects],
            "position": position,
            # robosuite stores [x, y, z, w]; cnfmp files use [w, x, y, z].
            "orientation": np.ascontiguousarray(quat_xyzw[:, [3, 0, 1, 2]]),
            "gripper": np.clip(separation / GRIPPER_MAX_OPENING, 0.0, 1.0),
            "prompt": str(prompt),
        }
