"""Scans: a scene seen by several calibrated depth cameras, as a lab's multi-view rig or a
depth scanner gives it, and the files a scan is exchanged in.

A scan is a list of views; each view has an RGB image, a depth image (metres along the
camera's optical axis; 0 where the camera measured nothing), a label map (0 background, k
the k-th object, as ``masks.png`` of a 2D scene), its pinhole intrinsics and its pose.
Camera frames follow OpenCV's convention (x right, y down, z forward, into the scene), and a
pose is the 4x4 world-from-camera transform, metres. The simulator renders one from its four
fixed cameras (front, left, right, top: :data:`cnfmp.sim.scene.SCAN_CAMERAS`) with the
gripper parked out of view.

On disk (``cameras.json`` + per view ``<name>_rgb.png``, ``<name>_depth.png``,
``<name>_labels.png``): ``cameras.json`` is ``{"format": "cnfmp-scan", "version": 1,
"depth_unit": "mm", "objects": [names in label order], "views": [{"name", "width",
"height", "intrinsics": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], "world_from_camera": 4x4,
"rgb", "depth", "labels": file names}]}``; depth PNGs are 16-bit millimetres (0 = no
measurement), or ``.npy`` float metres.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from dataclasses import dataclass

import numpy as np

from cnfmp.errors import InputError

SCAN_FORMAT, SCAN_VERSION = "cnfmp-scan", 1
CAMERAS_FILE = "cameras.json"
#: Depth beyond this (m) is no measurement: the renderer's far plane, a sensor's range.
MAX_DEPTH_M = 5.0
#: OpenCV camera axes from MuJoCo's (x right, y up, looking along -z).
_MUJOCO_TO_OPENCV = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class ScanView:
    """One calibrated view. H x W pixels.

    Attributes:
        name: the camera's name.
        rgb: (H, W, 3) uint8 image.
        depth: (H, W) float32 metres along the optical axis; 0 where nothing was measured.
        labels: (H, W) uint8 label map, 0 background, k the k-th object.
        intrinsics: (3, 3) pinhole matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], pixels.
        world_from_camera: (4, 4) pose of the OpenCV camera frame in the world, metres.
    """

    name: str
    rgb: np.ndarray
    depth: np.ndarray
    labels: np.ndarray
    intrinsics: np.ndarray
    world_from_camera: np.ndarray

    def points(self) -> tuple[np.ndarray, np.ndarray]:
        """Every measured pixel back-projected into the world: points (M, 3) metres and their
        labels (M,) uint8."""
        rows, cols = np.nonzero(self.depth > 0)
        z = self.depth[rows, cols].astype(np.float64)
        fx, fy, cx, cy = self.intrinsics[0, 0], self.intrinsics[1, 1], self.intrinsics[0, 2], self.intrinsics[1, 2]
        # Pixel (col, row) covers [col, col + 1): its centre is at col + 0.5.
        camera = np.stack([(cols + 0.5 - cx) / fx * z, (rows + 0.5 - cy) / fy * z, z], axis=1)
        world = camera @ self.world_from_camera[:3, :3].T + self.world_from_camera[:3, 3]
        return world, self.labels[rows, cols]


@dataclass(frozen=True)
class Scan:
    """Views of one scene, and the names of its labelled objects in label order."""

    views: tuple[ScanView, ...]
    objects: tuple[str, ...]

    def points(self) -> tuple[np.ndarray, np.ndarray]:
        """The fused point cloud: (M, 3) world points (m) and (M,) labels, all views."""
        parts = [view.points() for view in self.views]
        return np.concatenate([p for p, _ in parts]), np.concatenate([lab for _, lab in parts])


def render_scan(scene, cameras: tuple[str, ...] | None = None) -> Scan:
    """The simulator's scan of `scene` (a :class:`cnfmp.sim.task.Scene`) at the start of an
    episode, from `cameras` (default: front and :data:`cnfmp.sim.scene.SCAN_CAMERAS`)."""
    import mujoco

    from cnfmp.sim import engine, scene as sc

    names = cameras or ("front", *sc.SCAN_CAMERAS)
    sim = engine.Simulation(scene)
    try:
        rendered = sim.render_views(list(names))
        m, d = sim.model, sim.data
        views = []
        for name, (rgb, depth, labels) in zip(names, rendered):
            cam = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, name)
            height, width = depth.shape
            focal = 0.5 * height / math.tan(math.radians(float(m.cam_fovy[cam])) / 2)
            intrinsics = np.array([[focal, 0.0, width / 2], [0.0, focal, height / 2], [0.0, 0.0, 1.0]])
            pose = np.eye(4)
            pose[:3, :3] = d.cam_xmat[cam].reshape(3, 3) @ _MUJOCO_TO_OPENCV
            pose[:3, 3] = d.cam_xpos[cam]
            depth = np.where(depth < MAX_DEPTH_M, depth, 0.0).astype(np.float32)
            views.append(ScanView(name, rgb, depth, labels, intrinsics, pose))
    finally:
        sim.close()
    return Scan(tuple(views), tuple(scene.objects))


def write_scan(scan: Scan, out_dir: str) -> None:
    """Writes `scan` into `out_dir` (created; must not exist or be empty) in the format of
    the module docstring, through a temporary directory renamed at the end, so a failure
    leaves nothing behind."""
    from PIL import Image

    if os.path.exists(out_dir) and (not os.path.isdir(out_dir) or os.listdir(out_dir)):
        raise InputError(f"{out_dir} already exists and is not an empty directory; choose a new --out")
    parent = os.path.dirname(os.path.abspath(out_dir))
    os.makedirs(parent, exist_ok=True)
    staging = tempfile.mkdtemp(prefix=".cnfmp-scan-", dir=parent)
    try:
        entries = []
        for view in scan.views:
            files = {kind: f"{view.name}_{kind}.png" for kind in ("rgb", "depth", "labels")}
            millimetres = np.round(view.depth.astype(np.float64) * 1000.0)
            if millimetres.max(initial=0) > 65535:
                raise InputError(f"view {view.name}: depth beyond 65.535 m cannot be written as 16-bit millimetres")
            Image.fromarray(view.rgb).save(os.path.join(staging, files["rgb"]))
            Image.fromarray(millimetres.astype(np.uint16)).save(os.path.join(staging, files["depth"]))
            Image.fromarray(view.labels).save(os.path.join(staging, files["labels"]))
            height, width = view.depth.shape
            entries.append({"name": view.name, "width": width, "height": height,
                            "intrinsics": view.intrinsics.tolist(), "world_from_camera": view.world_from_camera.tolist(),
                            **files})
        with open(os.path.join(staging, CAMERAS_FILE), "w", encoding="utf-8") as f:
            json.dump({"format": SCAN_FORMAT, "version": SCAN_VERSION, "depth_unit": "mm",
                       "objects": list(scan.objects), "views": entries}, f, indent=2)
            f.write("\n")
        if os.path.isdir(out_dir):
            os.rmdir(out_dir)
        os.rename(staging, out_dir)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise


def read_scan(scan_dir: str) -> Scan:
    """The scan in `scan_dir` (format of the module docstring). InputError naming the view
    and the file for: a missing or unreadable ``cameras.json``, a view without intrinsics
    or pose (or a pose that is not a rigid transform), a missing image, a depth or label map
    of another size than the view says, NaN or negative depth."""
    path = os.path.join(scan_dir, CAMERAS_FILE)
    try:
        with open(path, encoding="utf-8") as f:
            meta = json.load(f)
    except FileNotFoundError:
        raise InputError(f"{scan_dir} is not a scan: {CAMERAS_FILE} is missing") from None
    except (OSError, ValueError) as err:
        raise InputError(f"{path} is not readable JSON: {err}") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("views"), list) or not meta["views"]:
        raise InputError(f"{path}: needs a non-empty \"views\" list")
    objects = meta.get("objects")
    if not isinstance(objects, list) or not all(isinstance(o, str) for o in objects):
        raise InputError(f"{path}: needs \"objects\", the object names in label order")
    views = [_read_view(scan_dir, path, index, entry, meta.get("depth_unit", "mm"))
             for index, entry in enumerate(meta["views"])]
    return Scan(tuple(views), tuple(objects))


def _read_view(scan_dir: str, path: str, index: int, entry, depth_unit: str) -> ScanView:
    if not isinstance(entry, dict):
        raise InputError(f"{path}: view {index + 1} is not an object")
    name = str(entry.get("name", f"view {index + 1}"))
    where = f"{path}, view {name}"
    for key in ("intrinsics", "world_from_camera", "rgb", "depth", "labels", "width", "height"):
        if key not in entry:
            raise InputError(f"{where}: \"{key}\" is missing")
    intrinsics = _matrix(entry["intrinsics"], (3, 3), where, "intrinsics")
    pose = _matrix(entry["world_from_camera"], (4, 4), where, "world_from_camera")
    rotation = pose[:3, :3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-4) or not np.allclose(pose[3], [0, 0, 0, 1]) \
            or np.linalg.det(rotation) < 0:
        raise InputError(f"{where}: world_from_camera is not a rigid transform (rotation and translation)")
    if not (intrinsics[0, 0] > 0 and intrinsics[1, 1] > 0):
        raise InputError(f"{where}: intrinsics need positive focal lengths")
    size = (int(entry["height"]), int(entry["width"]))
    rgb = _image(scan_dir, entry["rgb"], where, "rgb")
    depth = _depth(scan_dir, entry["depth"], where, depth_unit)
    labels = _image(scan_dir, entry["labels"], where, "labels")
    for kind, array in (("rgb", rgb), ("depth", depth), ("labels", labels)):
        if array.shape[:2] != size:
            raise InputError(f"{where}: {entry[kind]} is {array.shape[1]}x{array.shape[0]} px but the view is "
                             f"{size[1]}x{size[0]}")
    if rgb.ndim != 3 or rgb.shape[2] < 3:
        raise InputError(f"{where}: {entry['rgb']} is not an RGB image")
    if labels.ndim != 2:
        raise InputError(f"{where}: {entry['labels']} is not a single-channel label map")
    return ScanView(name, np.ascontiguousarray(rgb[..., :3]).astype(np.uint8), depth, labels.astype(np.uint8),
                    intrinsics, pose)


def _matrix(value, shape, where: str, key: str) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{where}: {key} is not a matrix of numbers") from None
    if array.shape != shape or not np.isfinite(array).all():
        raise InputError(f"{where}: {key} must be a finite {shape[0]}x{shape[1]} matrix, got shape {array.shape}")
    return array


def _image(scan_dir: str, name: str, where: str, kind: str) -> np.ndarray:
    from PIL import Image, UnidentifiedImageError

    file = os.path.join(scan_dir, str(name))
    try:
        with Image.open(file) as image:
            return np.asarray(image)
    except FileNotFoundError:
        raise InputError(f"{where}: the {kind} file {file} is missing") from None
    except (UnidentifiedImageError, OSError) as err:
        raise InputError(f"{where}: the {kind} file {file} is not a readable image: {err}") from None


def _depth(scan_dir: str, name: str, where: str, depth_unit: str) -> np.ndarray:
    file = os.path.join(scan_dir, str(name))
    if str(name).endswith(".npy"):
        try:
            depth = np.load(file).astype(np.float64)  # metres
        except FileNotFoundError:
            raise InputError(f"{where}: the depth file {file} is missing") from None
        except (OSError, ValueError) as err:
            raise InputError(f"{where}: the depth file {file} is not a readable .npy array: {err}") from None
    else:
        if depth_unit != "mm":
            raise InputError(f"{where}: depth PNGs are millimetres; depth_unit {depth_unit!r} is not supported")
        depth = _image(scan_dir, name, where, "depth").astype(np.float64) / 1000.0
    if depth.ndim != 2:
        raise InputError(f"{where}: {file} is not a single-channel depth map")
    if np.isnan(depth).any():
        raise InputError(f"{where}: {file} holds NaN depth ({int(np.isnan(depth).sum())} pixels); "
                         "write 0 where nothing was measured")
    if (depth < 0).any() or np.isinf(depth).any():
        raise InputError(f"{where}: {file} holds negative or infinite depth")
    return depth.astype(np.float32)


__all__ = ["CAMERAS_FILE", "Scan", "ScanView", "read_scan", "render_scan", "write_scan"]
