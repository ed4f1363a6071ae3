"""The simulator's scans: a scene seen by its four fixed depth cameras (front and
:data:`cnfmp.sim.scene.SCAN_CAMERAS`) with the gripper parked out of view, as a
:class:`cnfmp.scan.Scan`."""

from __future__ import annotations

import math

import numpy as np

from cnfmp.scan import MAX_DEPTH_M, Scan, ScanView

#: OpenCV camera axes from MuJoCo's (x right, y up, looking along -z).
_MUJOCO_TO_OPENCV = np.diag([1.0, -1.0, -1.0])


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


__all__ = ["render_scan"]
