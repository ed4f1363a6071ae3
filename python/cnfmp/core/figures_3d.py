"""Pictures of a cnfmp-3d prediction, like the paper's Fig. 5: the scan's fused points
coloured by their labels beside the reconstructed surface (marching cubes of the composite
occupancy, each face coloured by the object whose mask owns it), both with the predicted
gripper path and its key poses (start, every grasp and release, end), seen from one oblique
viewpoint. Drawn with OpenCV (painter's algorithm); meshes by PyMCubes.
"""

from __future__ import annotations

import numpy as np

from cnfmp.core.occupancy import SceneBox
from cnfmp.images import LABEL_PALETTE as PALETTE

#: Side of each panel (px), the grid spacing of the reconstruction (m), and how far the
#: pictured region reaches around the objects' scan points (m).
PANEL_PX = 480
GRID_SPACING_M = 0.008
REGION_MARGIN_M = 0.04
#: The viewpoint: azimuth from the -y axis (the front cameras' side) and elevation (deg).
VIEW_AZIMUTH_DEG = -35.0
VIEW_ELEVATION_DEG = 35.0
BACKGROUND_GREY = np.array([170, 170, 170], np.uint8)


def reconstruction(model, fit, lower: np.ndarray, upper: np.ndarray, spacing_m: float = GRID_SPACING_M):
    """The composite occupancy's 0.5 surface over the world box [lower, upper] (m): vertices
    (V, 3) world m, triangles (F, 3) indices, and per face the owning slot (F,) (0..N-1 the
    objects, N the background), for the latents of `fit`
    (:class:`cnfmp.core.inference_cnfmp3d.FittedScan`)."""
    import mcubes
    import torch

    c = model.config
    axes = [np.arange(lower[k], upper[k] + spacing_m / 2, spacing_m) for k in range(3)]
    gx, gy, gz = np.meshgrid(*axes, indexing="ij")
    world = np.stack([gx, gy, gz], axis=-1).reshape(-1, 3)
    box = SceneBox.of(c).to_box(world)
    occupancy, owner = [], []
    with torch.no_grad():
        for chunk in np.array_split(box.astype(np.float32), max(1, len(box) // 32768)):
            scene = model.scene(torch.from_numpy(chunk)[None], fit.latents[None], fit.anchors[None])
            occupancy.append(scene.occupancy[0].numpy())
            owner.append(scene.mask_logits[0].argmax(dim=0).numpy())
    volume = np.concatenate(occupancy).reshape(gx.shape)
    owners = np.concatenate(owner).reshape(gx.shape)
    vertices, triangles = mcubes.marching_cubes(volume, 0.5)
    if len(triangles) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), int), np.zeros(0, int)
    centroids = vertices[triangles].mean(axis=1)
    index = np.clip(np.round(centroids).astype(int), 0, np.array(volume.shape) - 1)
    face_owner = owners[index[:, 0], index[:, 1], index[:, 2]]
    return lower + vertices * spacing_m, triangles.astype(int), face_owner


class _View:
    """An orthographic oblique view fitted to a world box: world (.., 3) -> pixel (.., 2), depth (..,)."""

    def __init__(self, lower: np.ndarray, upper: np.ndarray, size: int):
        az, el = np.radians(VIEW_AZIMUTH_DEG), np.radians(VIEW_ELEVATION_DEG)
        toward = np.array([np.sin(az) * np.cos(el), -np.cos(az) * np.cos(el), np.sin(el)])  # to the viewer
        right = np.cross([0.0, 0.0, 1.0], toward)
        right /= np.linalg.norm(right)
        up = np.cross(toward, right)
        self.axes = np.stack([right, up, toward])
        self.toward = toward
        corners = np.array([[x, y, z] for x in (lower[0], upper[0]) for y in (lower[1], upper[1]) for z in (lower[2], upper[2])])
        projected = corners @ self.axes[:2].T
        self.low, span = projected.min(axis=0), projected.max(axis=0) - projected.min(axis=0)
        self.scale = 0.9 * size / span.max()
        self.offset = (size - self.scale * span) / 2

    def __call__(self, world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        plane = (world @ self.axes[:2].T - self.low) * self.scale + self.offset
        return np.stack([plane[..., 0], PANEL_PX - plane[..., 1]], axis=-1), world @ self.toward


def _colour(slot: np.ndarray, num_objects: int) -> np.ndarray:
    """Slot indices (0..N-1 objects, N background) -> RGB (.., 3) uint8."""
    colours = np.concatenate([PALETTE[1:1 + num_objects], BACKGROUND_GREY[None]])
    return colours[np.clip(slot, 0, num_objects)]


def _draw_path(image: np.ndarray, view: _View, position: np.ndarray, gripper: np.ndarray) -> None:
    import cv2

    pixels, _ = view(position)
    count = len(pixels)
    for i in range(count - 1):
        f = i / max(1, count - 2)
        colour = (int(255 * f), 40, int(255 * (1 - f)))  # RGB: blue at the start, red at the end
        cv2.line(image, tuple(np.round(pixels[i]).astype(int)), tuple(np.round(pixels[i + 1]).astype(int)), colour, 2,
                 cv2.LINE_AA)
    closed = gripper < 0.5
    keys = [0, count - 1] + [i for i in range(1, count) if closed[i] != closed[i - 1]]
    for i in keys:
        cv2.circle(image, tuple(np.round(pixels[i]).astype(int)), 7, (0, 0, 0), 2, cv2.LINE_AA)


def scan_figure(model, scan, fit, trajectory: dict, out_path: str) -> None:
    """Writes the picture (PNG, 2 x PANEL_PX wide) of the prediction `trajectory`
    (decode_trajectory's dict) for `scan` with its latent fit `fit` to `out_path`,
    atomically."""
    import cv2

    from cnfmp.artifacts import write_bytes_atomically

    n = model.config.num_objects
    points = fit.points
    objects = points.points[points.labels > 0]
    lower = np.minimum(objects.min(axis=0) - REGION_MARGIN_M, trajectory["position"].min(axis=0))
    upper = np.maximum(objects.max(axis=0) + REGION_MARGIN_M, trajectory["position"].max(axis=0))
    lower[2] = max(lower[2], -0.02)  # the table's top, not its thickness
    view = _View(lower, upper, PANEL_PX)

    left = np.full((PANEL_PX, PANEL_PX, 3), 255, np.uint8)
    inside = np.all((points.points >= lower) & (points.points <= upper), axis=1)
    shown, labels = points.points[inside], points.labels[inside].astype(int)
    pixels, depth = view(shown)
    colours = _colour(np.where(labels > 0, labels - 1, n), n)
    for i in np.argsort(depth):
        cv2.circle(left, tuple(np.round(pixels[i]).astype(int)), 1, tuple(int(v) for v in colours[i]), -1)

    right = np.full((PANEL_PX, PANEL_PX, 3), 255, np.uint8)
    vertices, triangles, owner = reconstruction(model, fit, lower, upper)
    if len(triangles):
        corners = vertices[triangles]  # (F, 3, 3)
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normals /= np.linalg.norm(normals, axis=1, keepdims=True) + 1e-12
        light = view.toward + np.array([0.0, 0.0, 0.5])
        shade = 0.35 + 0.65 * np.abs(normals @ (light / np.linalg.norm(light)))
        face_colours = _colour(owner, n).astype(float) * shade[:, None]
        face_pixels, face_depth = view(corners)
        for f in np.argsort(face_depth.mean(axis=1)):
            cv2.fillConvexPoly(right, np.round(face_pixels[f]).astype(np.int32), tuple(float(v) for v in face_colours[f]),
                               cv2.LINE_AA)
    for panel, title in ((left, "scan points"), (right, "reconstruction (marching cubes)")):
        _draw_path(panel, view, trajectory["position"], trajectory["gripper"])
        cv2.putText(panel, title, (10, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    picture = np.concatenate([left, right], axis=1)
    ok, png = cv2.imencode(".png", cv2.cvtColor(picture, cv2.COLOR_RGB2BGR))
    if not ok:
        raise RuntimeError("OpenCV could not encode the figure")
    write_bytes_atomically(out_path, png.tobytes())


__all__ = ["reconstruction", "scan_figure"]
