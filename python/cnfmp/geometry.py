"""Rotations and smooth motion on the Python side (quaternions are ``[w, x, y, z]``).

The one place Python converts between quaternions, rotation matrices and rotation vectors;
scipy does the algebra. Also builds smooth (minimum-jerk) paths through waypoints, which the
scripted experts use.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

__all__ = ["Rotation", "Waypoint", "from_rotation", "from_swing_twist", "from_tangent", "min_jerk", "path_through",
           "quat_down", "tilt_from_vertical", "to_rotation", "to_swing_twist", "to_tangent", "yaw_of"]


def to_rotation(quat_wxyz) -> Rotation:
    """``[w, x, y, z]`` (..., 4) -> scipy Rotation."""
    q = np.asarray(quat_wxyz, dtype=np.float64)
    return Rotation.from_quat(q[..., [1, 2, 3, 0]])


def from_rotation(rotation: Rotation) -> np.ndarray:
    """scipy Rotation -> ``[w, x, y, z]`` (..., 4) with w >= 0."""
    q = rotation.as_quat()[..., [3, 0, 1, 2]]
    return np.where(q[..., :1] < 0, -q, q)


def to_tangent(quat_wxyz, reference_wxyz) -> np.ndarray:
    """Orientations ``[w, x, y, z]`` (..., 4) -> rotation vectors (..., 3, rad) in the tangent
    space at `reference_wxyz` (4,): ``omega = log(R_ref^T R)``, the rotation that takes the
    reference to R, expressed in the reference's frame (the models' rotation output)."""
    return (to_rotation(reference_wxyz).inv() * to_rotation(quat_wxyz)).as_rotvec()


def from_tangent(rotvec, reference_wxyz) -> np.ndarray:
    """Inverse of :func:`to_tangent`: ``R = R_ref exp(omega)`` as ``[w, x, y, z]`` (..., 4)."""
    return from_rotation(to_rotation(reference_wxyz) * Rotation.from_rotvec(np.asarray(rotvec, float)))


def to_swing_twist(quat_wxyz, reference_wxyz) -> np.ndarray:
    """Orientations ``[w, x, y, z]`` (..., 4) -> ``[swing_x, swing_y, twist]`` (..., 3, rad)
    relative to `reference_wxyz` (4,), the chart with ``R_ref^T R = exp(swing) exp(twist z)``:
    the twist turns the gripper about the reference's finger axis (+z), the swing (a rotation
    vector with no z part) then tilts that axis. The finger axis depends on the swing alone.

    Why a second chart: in the tangent chart a tilt and a turn about the fingers combine
    non-additively (the rotation vector of a tilted, turned gripper has cross terms), so a
    motion that is affine in its latents cannot read the tilt from one object and the turn
    from another exactly; in this chart both enter additively. Singular only for a swing of
    half a turn (fingers pointing back up), which no task comes near."""
    relative = (to_rotation(reference_wxyz).inv() * to_rotation(quat_wxyz)).as_quat()  # x y z w
    # q and -q are one rotation; w >= 0 keeps the twist in [-pi, pi].
    relative = np.where(relative[..., 3:] < 0, -relative, relative)
    twist = 2.0 * np.arctan2(relative[..., 2], relative[..., 3])
    twist_rotation = Rotation.from_rotvec(twist[..., None] * np.array([0.0, 0.0, 1.0]))
    swing = (Rotation.from_quat(relative) * twist_rotation.inv()).as_rotvec()
    return np.concatenate([swing[..., :2], twist[..., None]], axis=-1)


def from_swing_twist(swing_twist, reference_wxyz) -> np.ndarray:
    """Inverse of :func:`to_swing_twist`: ``R = R_ref exp([sx, sy, 0]) exp([0, 0, twist])`` as
    ``[w, x, y, z]`` (..., 4)."""
    values = np.asarray(swing_twist, float)
    swing = np.concatenate([values[..., :2], np.zeros_like(values[..., :1])], axis=-1)
    twist = np.concatenate([np.zeros_like(values[..., :2]), values[..., 2:3]], axis=-1)
    return from_rotation(to_rotation(reference_wxyz) * Rotation.from_rotvec(swing) * Rotation.from_rotvec(twist))


def quat_down(yaw: float) -> np.ndarray:
    """Gripper pointing straight down (+z along the fingers = world -z), turned by `yaw`
    (rad) about world z; the fingers then close along world (-sin yaw, cos yaw)."""
    return from_rotation(Rotation.from_euler("z", yaw) * Rotation.from_euler("x", np.pi))


def tilt_from_vertical(quat_wxyz) -> float:
    """Angle (rad) between the gripper's finger axis (+z) and world -z."""
    z_axis = to_rotation(quat_wxyz).apply([0.0, 0.0, 1.0])
    return float(np.arccos(np.clip(-z_axis[2], -1.0, 1.0)))


def yaw_of(quat_wxyz) -> float:
    """Rotation about world z (rad) of a body's x axis."""
    x_axis = to_rotation(quat_wxyz).apply([1.0, 0.0, 0.0])
    return float(np.arctan2(x_axis[1], x_axis[0]))


def min_jerk(s: np.ndarray) -> np.ndarray:
    """Minimum-jerk time scaling on [0, 1]: zero velocity and acceleration at both ends."""
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s**2)


@dataclass
class Waypoint:
    """A pose to reach, the gripper command on arrival, and how long the move takes (s)."""

    position: np.ndarray
    quat: np.ndarray
    gripper: float
    duration: float


def path_through(start: Waypoint, waypoints: list[Waypoint], hz: float) -> dict:
    """Samples a smooth path from `start` through `waypoints` at `hz`.

    Each segment moves with minimum-jerk timing (rest to rest); the orientation follows the
    geodesic, the gripper command changes linearly over the segment. Returns
    ``{"t": (T,), "position": (T, 3), "orientation": (T, 4) wxyz, "gripper": (T,)}``.
    """
    times, positions, quats, grippers = [np.zeros(1)], [start.position[None]], [start.quat[None]], [np.array([start.gripper])]
    previous, t0 = start, 0.0
    for wp in waypoints:
        steps = max(1, int(round(wp.duration * hz)))
        s = np.arange(1, steps + 1) / steps
        blend = min_jerk(s)
        times.append(t0 + s * steps / hz)
        positions.append(previous.position[None] + blend[:, None] * (wp.position - previous.position)[None])
        slerp = Slerp([0.0, 1.0], to_rotation(np.stack([previous.quat, wp.quat])))
        quats.append(from_rotation(slerp(blend)))
        grippers.append(previous.gripper + s * (wp.gripper - previous.gripper))
        previous, t0 = wp, t0 + steps / hz
    return {
        "t": np.concatenate(times),
        "position": np.concatenate(positions),
        "orientation": np.concatenate(quats),
        "gripper": np.concatenate(grippers),
    }
