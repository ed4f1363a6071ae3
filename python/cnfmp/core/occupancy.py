"""What a scan says about occupancy, for the 3D model (``cnfmp-3d``): the scene box, the
fused labelled points, and labelled samples.

Labels come from free-space carving: a point is free when some view measures depth behind
it (the camera saw through it), occupied when every view that measures its pixel sees it at
or behind the surface, and unknown when no view measures it. Each sample also carries a
coarse object label (the nearest scan point's label within a radius), the 3D counterpart of
the 2D model's coarse masks. Coordinates: world metres in, box coordinates out
(``(x - box_centre) / box_half``, the box is [-1, 1]^3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cnfmp.errors import InputError


@dataclass(frozen=True)
class SceneBox:
    """The cube the fields model: centre (3,) and half side (m)."""

    centre: np.ndarray
    half: float

    def to_box(self, world: np.ndarray) -> np.ndarray:
        """World points (..., 3) m -> box coordinates (..., 3)."""
        return (world - self.centre) / self.half

    def to_world(self, box: np.ndarray) -> np.ndarray:
        return box * self.half + self.centre

    @classmethod
    def of(cls, config) -> "SceneBox":
        """The scene box a cnfmp-3d config's training chose (``box_centre``, ``box_half``)."""
        return cls(np.asarray(config.box_centre, dtype=np.float64), float(config.box_half))


def fit_box(object_points: list[np.ndarray], margin_m: float) -> SceneBox:
    """The smallest cube around every scan's object points (each (M, 3) m) with `margin_m`
    on every side; the table top below the objects is inside it when the margin reaches it."""
    points = np.concatenate(object_points)
    lower, upper = points.min(axis=0) - margin_m, points.max(axis=0) + margin_m
    return SceneBox(((lower + upper) / 2).astype(np.float64), float((upper - lower).max() / 2))


@dataclass
class ScanPoints:
    """A scan's fused points inside a box.

    Attributes:
        points: (M, 3) world points (m); labels: (M,) 0 background, k the k-th object.
    """

    points: np.ndarray
    labels: np.ndarray

    def of_object(self, slot: int) -> np.ndarray:
        """The points of object slot `slot` (label slot + 1): (M_k, 3)."""
        return self.points[self.labels == slot + 1]

    def anchors(self, box: SceneBox, num_objects: int) -> np.ndarray:
        """Each object's anchor, the centroid of its points: (N, 3) float32 box coordinates."""
        return np.stack([box.to_box(self.of_object(k)).mean(axis=0) for k in range(num_objects)]).astype(np.float32)

    def around_object(self, slot: int, reach_m: float) -> "ScanPoints":
        """The points within `reach_m` of object `slot`'s bounding box (every point a sample
        near the object can take its coarse label from)."""
        own = self.of_object(slot)
        lower, upper = own.min(axis=0) - reach_m, own.max(axis=0) + reach_m
        near = np.all((self.points >= lower) & (self.points <= upper), axis=1)
        return ScanPoints(self.points[near], self.labels[near])


def scan_points(scan, box: SceneBox | None = None, num_objects: int | None = None,
                objects: tuple[str, ...] = ()) -> ScanPoints:
    """The fused points of `scan` (a :class:`cnfmp.scan.Scan`), cropped to `box` when given.
    With `num_objects`, labels beyond it are background, and an object slot without points
    is an InputError naming it (`objects`: names for the message)."""
    points, labels = scan.points()
    if box is not None:
        inside = np.all(np.abs(box.to_box(points)) <= 1.0, axis=1)
        points, labels = points[inside], labels[inside]
    if num_objects is not None:
        labels = np.where(labels > num_objects, 0, labels).astype(np.uint8)
        for slot in range(num_objects):
            if not (labels == slot + 1).any():
                name = objects[slot] if slot < len(objects) else f"object {slot + 1}"
                raise InputError(f"the scan has no points of {name} (label {slot + 1})"
                                 + (" inside the model's scene box" if box is not None else ""))
    return ScanPoints(points, labels)


def carve(world: np.ndarray, scan, margin_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Free-space carving of points `world` (S, 3) m against every view of `scan`.

    Returns (occupied (S,) float32 in {0, 1}, known (S,) bool): known where at least one view
    measured depth at the point's pixel; occupied where known and no view measured depth
    more than `margin_m` behind the point (it lies at or behind every surface seen)."""
    free = np.zeros(len(world), dtype=bool)
    known = np.zeros(len(world), dtype=bool)
    for view in scan.views:
        pose = view.world_from_camera
        camera = (world - pose[:3, 3]) @ pose[:3, :3]
        z = camera[:, 2]
        height, width = view.depth.shape
        fx, fy, cx, cy = view.intrinsics[0, 0], view.intrinsics[1, 1], view.intrinsics[0, 2], view.intrinsics[1, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            cols = np.floor(camera[:, 0] / z * fx + cx)
            rows = np.floor(camera[:, 1] / z * fy + cy)
        inside = (z > 1e-6) & (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
        index = np.flatnonzero(inside)
        measured = view.depth[rows[index].astype(int), cols[index].astype(int)]
        seen = measured > 0
        known[index[seen]] = True
        free[index[seen & (measured > z[index] + margin_m)]] = True
    return (known & ~free).astype(np.float32), known


def coarse_labels(samples: np.ndarray, points: ScanPoints, radius_m: float, num_objects: int) -> np.ndarray:
    """Per sample (S, 3) m the slot of the nearest scan point within `radius_m`: 0..N-1 for
    the objects, N (the background's slot) for background points and empty space. (S,) int64."""
    from scipy.spatial import cKDTree

    # Only scan points within the radius of the samples' bounding box can be found: the tree
    # over them alone is much cheaper to build than over the whole scan.
    near = np.all((points.points >= samples.min(axis=0) - radius_m) & (points.points <= samples.max(axis=0) + radius_m),
                  axis=1)
    label = np.full(len(samples), 0, dtype=np.int64)
    if near.any():
        candidates, candidate_labels = points.points[near], points.labels[near]
        distance, nearest = cKDTree(candidates).query(samples, k=1, distance_upper_bound=radius_m)
        found = np.isfinite(distance)
        label[found] = candidate_labels[nearest[found]]
    return np.where(label > 0, label - 1, num_objects)


def near_surface(points: np.ndarray, count: int, jitter_m: list[float], rng: np.random.Generator) -> np.ndarray:
    """`count` samples (count, 3) m around `points` (M, 3): random points moved by Gaussian
    noise, half of them with each spread of `jitter_m`."""
    picked = points[rng.integers(0, len(points), count)]
    spreads = np.where(np.arange(count) < count // 2, jitter_m[0], jitter_m[-1])
    return picked + rng.normal(size=(count, 3)) * spreads[:, None]


@dataclass
class LabelledSamples:
    """Samples of one scan with their labels, in box coordinates.

    Attributes:
        points: (S, 3) float32 box coordinates.
        occupied: (S,) float32 in {0, 1}; known: (S,) bool (see :func:`carve`).
        coarse: (S,) int64 coarse slot labels (N: background).
    """

    points: np.ndarray
    occupied: np.ndarray
    known: np.ndarray
    coarse: np.ndarray


def label_samples(world: np.ndarray, scan, points: ScanPoints, box: SceneBox, config) -> LabelledSamples:
    """Carved and coarse labels of samples `world` (S, 3) m of `scan`; `config` gives the
    margins (a :class:`cnfmp.core.configuration_cnfmp3d.Cnfmp3dConfig`)."""
    occupied, known = carve(world, scan, config.carve_margin_m)
    coarse = coarse_labels(world, points, config.coarse_label_radius_m, config.num_objects)
    return LabelledSamples(box.to_box(world).astype(np.float32), occupied, known, coarse)


__all__ = ["LabelledSamples", "SceneBox", "ScanPoints", "carve", "coarse_labels", "fit_box", "label_samples",
           "near_surface", "scan_points"]
