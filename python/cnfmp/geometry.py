"""Rotations and smooth motion on the Python side (quaternions are ``[w, x, y, z]``).

The one place Python converts between quaternions, rotation matrices and rotation vectors.
The charts the models predict in (:func:`to_tangent`, :func:`to_swing_twist` and their
inverses) are plain numpy quaternion algebra: they run on every prediction, and importing
scipy's rotations (scipy.spatial with its trees and hulls) would cost a cold `cnfmp predict`
over a second on a 2-core host. Everything else, used by the simulator and its scripted
experts, is scipy's ``Rotation``/``Slerp``, imported on first use. Also builds smooth
(minimum-jerk) paths through waypoints, which the scripted experts use.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Rotation", "Waypoint", "from_rotation", "from_swing_twist", "from_tangent", "min_jerk", "path_through",
           "quat_down", "tilt_from_vertical", "to_rotation", "to_swing_twist", "to_tangent", "yaw_of"]


def __getattr__(name: str):
    """``geometry.Rotation`` and ``geometry.Slerp``: scipy's, imported when first asked for."""
    if name in ("Rotation", "Slerp"):
        from scipy.spatial import transform

        return getattr(transform, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def to_rotation(quat_wxyz):
    """``[w, x, y, z]`` (..., 4) -> scipy Rotation."""
    from scipy.spatial.transform import Rotation

    q = np.asarray(quat_wxyz, dtype=np.float64)
    return Rotation.from_quat(q[..., [1, 2, 3, 0]])


def from_rotation(rotation) -> np.ndarray:
    """scipy Rotation -> ``[w, x, y, z]`` (..., 4) with w >= 0."""
    q = rotation.as_quat()[..., [3, 0, 1, 2]]
    return np.where(q[..., :1] < 0, -q, q)


def _unit(quat_wxyz) -> np.ndarray:
    """Normalised ``[w, x, y, z]`` (..., 4) with w >= 0 (q and -q are one rotation)."""
    q = np.asarray(quat_wxyz, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def _multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of ``[w, x, y, z]`` quaternions (..., 4), broadcast: the rotation
    `b` first, then `a`."""
    aw, av = a[..., :1], a[..., 1:]
    bw, bv = b[..., :1], b[..., 1:]
    w = aw * bw - np.sum(av * bv, axis=-1, keepdims=True)
    v = aw * bv + bw * av + np.cross(av, bv)
    return np.concatenate([w, v], axis=-1)


def _conjugate(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def _exp(rotvec) -> np.ndarray:
    """Rotation vectors (..., 3, rad) -> unit quaternions ``[w, x, y, z]`` (..., 4)."""
    v = np.asarray(rotvec, dtype=np.float64)
    angle = np.linalg.norm(v, axis=-1, keepdims=True)
    # sin(angle/2)/angle, by its series where the division loses precision.
    small = angle < 1e-4
    scale = np.where(small, 0.5 - angle**2 / 48.0, np.sin(angle / 2) / np.where(small, 1.0, angle))
    return np.concatenate([np.cos(angle / 2), scale * v], axis=-1)


def _log(quat_wxyz) -> np.ndarray:
    """Unit quaternions ``[w, x, y, z]`` (..., 4) -> rotation vectors (..., 3, rad), the
    angle within [0, pi]."""
    q = _unit(quat_wxyz)
    sine = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)  # sin(angle/2)
    angle = 2.0 * np.arctan2(sine, q[..., :1])
    small = sine < 1e-6
    # angle / sin(angle/2), by its series (2/w (1 + ...)) near the identity.
    scale = np.where(small, 2.0 / q[..., :1], angle / np.where(small, 1.0, sine))
    return scale * q[..., 1:]


def to_tangent(quat_wxyz, reference_wxyz) -> np.ndarray:
    """Orientations ``[w, x, y, z]`` (..., 4) -> rotation vectors (..., 3, rad) in the tangent
    space at `reference_wxyz` (4,): ``omega = log(R_ref^T R)``, the rotation that takes the
    reference to R, expressed in the reference's frame (the models' rotation output)."""
    return _log(_multiply(_conjugate(_unit(reference_wxyz)), _unit(quat_wxyz)))


def from_tangent(rotvec, reference_wxyz) -> np.ndarray:
    """Inverse of :func:`to_tangent`: ``R = R_ref exp(omega)`` as ``[w, x, y, z]`` (..., 4)."""
    return _unit(_multiply(_unit(reference_wxyz), _exp(rotvec)))


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
    # w >= 0 (from _unit) keeps the twist in [-pi, pi].
    relative = _unit(_multiply(_conjugate(_unit(reference_wxyz)), _unit(quat_wxyz)))
    twist = 2.0 * np.arctan2(relative[..., 3], relative[..., 0])
    swing = _log(_multiply(relative, _conjugate(_exp(twist[..., None] * np.array([0.0, 0.0, 1.0])))))
    return np.concatenate([swing[..., :2], twist[..., None]], axis=-1)


def from_swing_twist(swing_twist, reference_wxyz) -> np.ndarray:
    """Inverse of :func:`to_swing_twist`: ``R = R_ref exp([sx, sy, 0]) exp([0, 0, twist])`` as
    ``[w, x, y, z]`` (..., 4)."""
    values = np.asarray(swing_twist, float)
    swing = np.concatenate([values[..., :2], np.zeros_like(values[..., :1])], axis=-1)
    twist = np.concatenate([np.zeros_like(values[..., :2]), values[..., 2:3]], axis=-1)
    return _unit(_multiply(_multiply(_unit(reference_wxyz), _exp(swing)), _exp(twist)))


def quat_down(yaw: float) -> np.ndarray:
    """Gripper pointing straight down (+z along the fingers = world -z), turned by `yaw`
    (rad) about world z; the fingers then close along world (-sin yaw, cos yaw)."""
    from scipy.spatial.transform import Rotation

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
    from scipy.spatial.transform import Slerp

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
