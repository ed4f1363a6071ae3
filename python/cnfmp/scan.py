"""Scans: a scene seen by several calibrated depth cameras, as a lab's multi-view rig or a
depth scanner gives it, the files a scan is exchanged in, and its form inside a LeRobot
dataset.

A scan is a list of views; each view has an RGB image, a depth image (metres along the
camera's optical axis; 0 where the camera measured nothing), a label map (0 background, k
the k-th object, as ``masks.png`` of a 2D scene), its pinhole intrinsics and its pose.
Camera frames follow OpenCV's convention (x right, y down, z forward, into the scene), and a
pose is the 4x4 world-from-camera transform, metres. The simulator renders one from its four
fixed cameras (:func:`cnfmp.sim.scan.render_scan`).

On disk (``cameras.json`` + per view ``<name>_rgb.png``, ``<name>_depth.png``,
``<name>_labels.png``): ``cameras.json`` is ``{"format": "cnfmp-scan", "version": 1,
"depth_unit": "mm", "objects": [names in label order], "views": [{"name", "width",
"height", "intrinsics": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], "world_from_camera": 4x4,
"rgb" (optional), "depth", "labels": file names}]}``; depth PNGs are 16-bit millimetres (0 = no
measurement), or ``.npy`` float metres.

In a LeRobot dataset (lerobot 0.4.4 has no depth feature and stores images as 8-bit RGB),
each view is the image feature ``annotation.scan.<name>``, losslessly packed: red = depth
in millimetres // 256, green = depth in millimetres % 256, blue = the label; and
``annotation.scan.cameras`` is the JSON of ``cameras.json`` without file names. Like
``annotation.masks``, both hold the scan taken before the episode on every frame of it
(:func:`dataset_features`, :func:`dataset_values`, :func:`from_dataset_row`).
"""

from __future__ import annotations

import json
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


@dataclass(frozen=True)
class ScanView:
    """One calibrated view. H x W pixels.

    Attributes:
        name: the camera's name.
        rgb: (H, W, 3) uint8 image, or None where the scan has none (a dataset's scan).
        depth: (H, W) float32 metres along the optical axis; 0 where nothing was measured.
        labels: (H, W) uint8 label map, 0 background, k the k-th object.
        intrinsics: (3, 3) pinhole matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], pixels.
        world_from_camera: (4, 4) pose of the OpenCV camera frame in the world, metres.
    """

    name: str
    rgb: np.ndarray | None
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
            kinds = ("rgb", "depth", "labels") if view.rgb is not None else ("depth", "labels")
            files = {kind: f"{view.name}_{kind}.png" for kind in kinds}
            millimetres = _millimetres(view)
            if view.rgb is not None:
                Image.fromarray(view.rgb).save(os.path.join(staging, files["rgb"]))
            Image.fromarray(millimetres).save(os.path.join(staging, files["depth"]))
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
    for key in ("intrinsics", "world_from_camera", "depth", "labels", "width", "height"):
        if key not in entry:
            raise InputError(f"{where}: \"{key}\" is missing")
    intrinsics, pose = _camera(entry, where)
    size = (int(entry["height"]), int(entry["width"]))
    rgb = _image(scan_dir, entry["rgb"], where, "rgb") if "rgb" in entry else None
    depth = _depth(scan_dir, entry["depth"], where, depth_unit)
    labels = _image(scan_dir, entry["labels"], where, "labels")
    for kind, array in (("rgb", rgb), ("depth", depth), ("labels", labels)):
        if array is not None and array.shape[:2] != size:
            raise InputError(f"{where}: {entry[kind]} is {array.shape[1]}x{array.shape[0]} px but the view is "
                             f"{size[1]}x{size[0]}")
    if rgb is not None and (rgb.ndim != 3 or rgb.shape[2] < 3):
        raise InputError(f"{where}: {entry['rgb']} is not an RGB image")
    if labels.ndim != 2:
        raise InputError(f"{where}: {entry['labels']} is not a single-channel label map")
    rgb = None if rgb is None else np.ascontiguousarray(rgb[..., :3]).astype(np.uint8)
    return ScanView(name, rgb, depth, labels.astype(np.uint8),
                    intrinsics, pose)


def _millimetres(view: ScanView) -> np.ndarray:
    """The view's depth as 16-bit millimetres (H, W); InputError beyond 65.535 m."""
    millimetres = np.round(view.depth.astype(np.float64) * 1000.0)
    if millimetres.max(initial=0) > 65535:
        raise InputError(f"view {view.name}: depth beyond 65.535 m cannot be stored as 16-bit millimetres")
    return millimetres.astype(np.uint16)


def _camera(entry: dict, where: str) -> tuple[np.ndarray, np.ndarray]:
    """A view entry's intrinsics (3, 3) and world-from-camera pose (4, 4), checked: finite,
    positive focal lengths, a rigid pose."""
    intrinsics = _matrix(entry.get("intrinsics"), (3, 3), where, "intrinsics")
    pose = _matrix(entry.get("world_from_camera"), (4, 4), where, "world_from_camera")
    rotation = pose[:3, :3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-4) or not np.allclose(pose[3], [0, 0, 0, 1]) \
            or np.linalg.det(rotation) < 0:
        raise InputError(f"{where}: world_from_camera is not a rigid transform (rotation and translation)")
    if not (intrinsics[0, 0] > 0 and intrinsics[1, 1] > 0):
        raise InputError(f"{where}: intrinsics need positive focal lengths")
    return intrinsics, pose


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


# ---- inside a LeRobot dataset ----
SCAN_FEATURE_PREFIX = "annotation.scan."
CAMERAS_FEATURE = SCAN_FEATURE_PREFIX + "cameras"


def dataset_features(scan: Scan) -> dict:
    """The LeRobot feature specification of `scan`'s views (module docstring)."""
    specs = {SCAN_FEATURE_PREFIX + view.name: {"dtype": "image", "shape": (*view.depth.shape, 3),
                                               "names": ["height", "width", "channels"]} for view in scan.views}
    return {**specs, CAMERAS_FEATURE: {"dtype": "string", "shape": (1,), "names": None}}


def dataset_values(scan: Scan) -> dict:
    """`scan` as the values of one frame of :func:`dataset_features` (packed images and the
    cameras' JSON). InputError for depth beyond the 16-bit millimetre range."""
    values, cameras = {}, []
    for view in scan.views:
        millimetres = _millimetres(view)
        values[SCAN_FEATURE_PREFIX + view.name] = np.stack(
            [(millimetres >> 8).astype(np.uint8), (millimetres & 255).astype(np.uint8), view.labels], axis=-1)
        height, width = view.depth.shape
        cameras.append({"name": view.name, "width": width, "height": height, "intrinsics": view.intrinsics.tolist(),
                        "world_from_camera": view.world_from_camera.tolist()})
    values[CAMERAS_FEATURE] = json.dumps({"format": SCAN_FORMAT, "version": SCAN_VERSION, "depth_unit": "mm",
                                          "packing": "red = mm // 256, green = mm % 256, blue = label",
                                          "objects": list(scan.objects), "views": cameras})
    return values


def from_dataset_row(row: dict, where: str) -> Scan:
    """The scan of one dataset frame `row` (feature -> value: the packed images as arrays or
    PIL images, the cameras' JSON); `where` names the frame in errors. InputError when the
    row has no scan or a view is missing or of another size than its camera says."""
    if CAMERAS_FEATURE not in row:
        raise InputError(f"{where}: no scan ({CAMERAS_FEATURE} is missing); record one with "
                         "`cnfmp dataset generate --scan`")
    try:
        meta = json.loads(row[CAMERAS_FEATURE])
    except (TypeError, ValueError) as err:
        raise InputError(f"{where}: {CAMERAS_FEATURE} is not JSON: {err}") from None
    views = []
    for entry in meta.get("views", []):
        key = SCAN_FEATURE_PREFIX + str(entry.get("name"))
        if key not in row:
            raise InputError(f"{where}: the cameras name view {entry.get('name')!r} but {key} is missing")
        packed = np.asarray(row[key])
        view_where = f"{where}, view {entry.get('name')}"
        if packed.ndim != 3 or packed.shape[:2] != (int(entry["height"]), int(entry["width"])):
            raise InputError(f"{view_where}: {key} is {packed.shape} but the camera is "
                             f"{entry['width']}x{entry['height']}")
        millimetres = packed[..., 0].astype(np.uint16) << 8 | packed[..., 1].astype(np.uint16)
        views.append(ScanView(str(entry["name"]), None, millimetres.astype(np.float32) / 1000.0,
                              packed[..., 2].astype(np.uint8), *_camera(entry, view_where)))
    if not views:
        raise InputError(f"{where}: {CAMERAS_FEATURE} names no views")
    return Scan(tuple(views), tuple(meta.get("objects", [])))


__all__ = ["CAMERAS_FEATURE", "dataset_features", "dataset_values", "from_dataset_row", "CAMERAS_FILE", "Scan", "ScanView", "read_scan", "write_scan"]
