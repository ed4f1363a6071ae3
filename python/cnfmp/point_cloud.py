"""Fused point clouds as scans: a labelled point cloud with the sensor origin each point was
seen from becomes, per origin, a virtual depth view (a pinhole camera at the origin looking at
its points, each pixel the nearest point along its ray), so that free-space carving and
everything else that reads a :class:`cnfmp.scan.Scan` takes it as it is.

Free space needs the origins: a point only says where a surface is, the ray it came along
says that everything before it is empty. Files:

- ``.npz``: ``points`` (M, 3) float metres (world), ``labels`` (M,) integers (0 background,
  k the k-th object), ``origins`` (V, 3) metres, ``view`` (M,) the index of each point's
  origin; optional ``objects`` (names in label order).
- ``.ply`` (ASCII or binary little-endian): a ``vertex`` element with ``x y z label view``,
  an ``origin`` element with ``x y z``, optional ``comment objects: name, name``.
"""

from __future__ import annotations

import os

import numpy as np

from cnfmp.errors import InputError
from cnfmp.scan import Scan, ScanView

#: Side (px) bounds of a virtual view: about one point per pixel, within these.
MIN_VIEW_PX, MAX_VIEW_PX = 64, 256
#: The virtual camera's field of view reaches this much beyond its farthest point.
FIELD_MARGIN = 1.05


def read_point_cloud(path: str) -> Scan:
    """The scan of the point cloud file `path` (module docstring). InputError for an
    unreadable file, missing or mismatched arrays, non-finite points, or no origins."""
    if path.endswith(".npz"):
        points, labels, origins, view, objects = _read_npz(path)
    elif path.endswith(".ply"):
        points, labels, origins, view, objects = _read_ply(path)
    else:
        raise InputError(f"{path}: a point cloud is a .npz or .ply file")
    return cloud_scan(points, labels, origins, view, objects, path)


def cloud_scan(points: np.ndarray, labels: np.ndarray, origins: np.ndarray, view: np.ndarray,
               objects: tuple[str, ...], where: str = "point cloud") -> Scan:
    """The scan of a labelled cloud: points (M, 3) m, labels (M,), origins (V, 3) m, view (M,)
    the origin of each point; one virtual view per origin that saw points."""
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
        raise InputError(f"{where}: points must be an (M, 3) array of at least one point, got shape {points.shape}")
    if not np.isfinite(points).all():
        raise InputError(f"{where}: points holds NaN or infinite coordinates")
    labels, view = np.asarray(labels), np.asarray(view)
    if labels.shape != (len(points),) or view.shape != (len(points),):
        raise InputError(f"{where}: labels and view need one value per point ({len(points)}), got shapes "
                         f"{labels.shape} and {view.shape}")
    if labels.min() < 0 or labels.max() > 255:
        raise InputError(f"{where}: labels must be in 0..255")
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    if len(origins) == 0 or not np.isfinite(origins).all():
        raise InputError(f"{where}: needs the sensor origins (finite, at least one): free space is only known along "
                         "the rays the points were seen along")
    if view.min() < 0 or view.max() >= len(origins):
        raise InputError(f"{where}: view indices must be in 0..{len(origins) - 1} (one per origin)")
    views = [_virtual_view(points[view == v], labels[view == v].astype(np.uint8), origins[v], f"origin {v}")
             for v in range(len(origins)) if (view == v).any()]
    return Scan(tuple(views), tuple(objects))


def _virtual_view(points: np.ndarray, labels: np.ndarray, origin: np.ndarray, name: str) -> ScanView:
    """A pinhole view from `origin` towards the centroid of `points`, each pixel the nearest
    point whose ray falls in it (0 depth where none does)."""
    forward = points.mean(axis=0) - origin
    if np.linalg.norm(forward) < 1e-9:
        raise InputError(f"{name}: the origin is at its points' centroid; a view needs a direction")
    forward /= np.linalg.norm(forward)
    helper = np.array([0.0, 0.0, 1.0]) if abs(forward[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    right = np.cross(forward, helper)
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)  # OpenCV axes: x right, y down, z forward
    rotation = np.stack([right, down, forward], axis=1)  # world from camera
    camera = (points - origin) @ rotation
    ahead = camera[:, 2] > 1e-6
    camera, labels = camera[ahead], labels[ahead]
    if len(camera) == 0:
        raise InputError(f"{name}: no point lies in front of its origin")
    side = int(np.clip(np.sqrt(len(camera)), MIN_VIEW_PX, MAX_VIEW_PX))
    tangent = np.max(np.abs(camera[:, :2] / camera[:, 2:3])) * FIELD_MARGIN
    focal = (side / 2) / max(tangent, 1e-6)
    cols = np.floor(camera[:, 0] / camera[:, 2] * focal + side / 2).astype(int)
    rows = np.floor(camera[:, 1] / camera[:, 2] * focal + side / 2).astype(int)
    keep = (cols >= 0) & (cols < side) & (rows >= 0) & (rows < side)
    cols, rows, z, labels = cols[keep], rows[keep], camera[keep, 2], labels[keep]
    depth = np.zeros((side, side), np.float32)
    label_map = np.zeros((side, side), np.uint8)
    order = np.argsort(-z)  # far first: the nearest point of a pixel is written last
    depth[rows[order], cols[order]] = z[order]
    label_map[rows[order], cols[order]] = labels[order]
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rotation, origin
    intrinsics = np.array([[focal, 0.0, side / 2], [0.0, focal, side / 2], [0.0, 0.0, 1.0]])
    return ScanView(name, None, depth, label_map, intrinsics, pose)


def _read_npz(path: str):
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
    except FileNotFoundError:
        raise InputError(f"{path}: no such point cloud file") from None
    except (OSError, ValueError) as err:
        raise InputError(f"{path}: not a readable .npz file: {err}") from None
    missing = [key for key in ("points", "labels", "origins", "view") if key not in arrays]
    if missing:
        raise InputError(f"{path}: the point cloud lacks {', '.join(missing)} (it needs points, labels, origins, view)")
    objects = tuple(str(name) for name in arrays.get("objects", np.array([], dtype=str)).tolist())
    return arrays["points"], arrays["labels"], arrays["origins"], arrays["view"], objects


def _read_ply(path: str):
    """The vertex (x y z label view) and origin (x y z) elements of a PLY file."""
    try:
        with open(path, "rb") as f:
            header, elements, objects = _ply_header(f, path)
            body = f.read()
    except FileNotFoundError:
        raise InputError(f"{path}: no such point cloud file") from None
    except OSError as err:
        raise InputError(f"{path}: not readable: {err}") from None
    data = _ply_elements(header, elements, body, path)
    if "vertex" not in data or "origin" not in data:
        raise InputError(f"{path}: a point cloud needs a vertex element (x y z label view) and an origin element (x y z)")
    vertex, origin = data["vertex"], data["origin"]
    for name in ("x", "y", "z", "label", "view"):
        if name not in vertex:
            raise InputError(f"{path}: the vertex element has no {name!r} property")
    points = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1)
    origins = np.stack([origin["x"], origin["y"], origin["z"]], axis=1)
    return points, vertex["label"].astype(np.int64), origins, vertex["view"].astype(np.int64), objects


_PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4",
              "float": "f4", "double": "f8", "int8": "i1", "uint8": "u1", "int16": "i2", "uint16": "u2",
              "int32": "i4", "uint32": "u4", "float32": "f4", "float64": "f8"}


def _ply_header(f, path: str):
    if f.readline().strip() != b"ply":
        raise InputError(f"{path}: not a PLY file")
    form, elements, objects = None, [], ()
    while True:
        line = f.readline()
        if not line:
            raise InputError(f"{path}: the PLY header has no end_header")
        words = line.decode("ascii", "replace").split()
        if not words:
            continue
        if words[0] == "format":
            form = words[1]
        elif words[0] == "comment" and len(words) > 1 and words[1] == "objects:":
            objects = tuple(name.strip() for name in " ".join(words[2:]).split(",") if name.strip())
        elif words[0] == "element":
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property":
            if words[1] == "list" or words[1] not in _PLY_TYPES or not elements:
                raise InputError(f"{path}: unsupported PLY property line {line.decode(errors='replace').strip()!r}")
            elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
        elif words[0] == "end_header":
            break
    if form not in ("ascii", "binary_little_endian"):
        raise InputError(f"{path}: PLY format {form!r} is not read (ascii or binary_little_endian)")
    return form, elements, objects


def _ply_elements(form: str, elements: list, body: bytes, path: str) -> dict:
    data, offset = {}, 0
    if form == "ascii":
        rows = body.decode("ascii", "replace").split("\n")
        for name, count, props in elements:
            try:
                table = np.array([[float(v) for v in rows[offset + i].split()] for i in range(count)]).reshape(count, len(props))
            except (ValueError, IndexError):
                raise InputError(f"{path}: the {name} element's rows do not match its {len(props)} properties") from None
            data[name] = {prop: table[:, k] for k, (prop, _) in enumerate(props)}
            offset += count
        return data
    for name, count, props in elements:
        dtype = np.dtype([(prop, "<" + kind) for prop, kind in props])
        size = dtype.itemsize * count
        if offset + size > len(body):
            raise InputError(f"{path}: the file ends inside the {name} element")
        table = np.frombuffer(body, dtype=dtype, count=count, offset=offset)
        data[name] = {prop: table[prop].astype(np.float64) for prop, _ in props}
        offset += size
    return data


def is_point_cloud(path: str) -> bool:
    """Whether `path` names a point cloud file (by its extension) rather than a scan directory."""
    return os.path.isfile(path) and path.endswith((".npz", ".ply"))


__all__ = ["cloud_scan", "is_point_cloud", "read_point_cloud"]
