"""Building blocks the task modules share: colours, object MJCF, placement sampling, checks."""

from __future__ import annotations

import numpy as np

from cnfmp import geometry
from cnfmp.sim.scene import CONTROL_HZ, FINGER_TRAVEL, HOME_POSITION, HOME_QUAT
from cnfmp.geometry import Waypoint

#: Named colours (RGB in [0, 1]) used across tasks.
COLOURS = {
    "red": (0.85, 0.12, 0.10),
    "green": (0.15, 0.65, 0.20),
    "blue": (0.12, 0.30, 0.85),
    "yellow": (0.95, 0.80, 0.10),
    "purple": (0.55, 0.20, 0.70),
    "orange": (0.95, 0.50, 0.10),
    "white": (0.92, 0.92, 0.90),
    "black": (0.12, 0.12, 0.12),
}

#: Speed above which an object does not count as at rest (m/s).
REST_SPEED = 0.02


def rgba(colour: str) -> str:
    r, g, b = COLOURS[colour]
    return f"{r} {g} {b} 1"


def fmt(values) -> str:
    return " ".join(f"{float(v):.6f}" for v in values)


def sample_positions(rng: np.random.Generator, count: int, low, high, min_distance: float,
                     avoid=()) -> np.ndarray:
    """`count` xy positions uniform in the box [low, high], pairwise (and from `avoid`) at
    least `min_distance` apart, by rejection."""
    low, high = np.asarray(low, float), np.asarray(high, float)
    for _ in range(10_000):
        points = rng.uniform(low, high, size=(count, 2))
        everything = np.concatenate([points, np.reshape(np.asarray(avoid, float), (-1, 2))])
        dists = np.linalg.norm(everything[:, None] - everything[None], axis=-1)
        np.fill_diagonal(dists, np.inf)
        if dists[:count].min() >= min_distance:
            return points
    raise RuntimeError("could not place the objects; the sampling box is too small")


def box_body(name: str, position, yaw: float, half_sizes, colour: str, mass: float,
             friction: str = "1.5 0.01 0.0001") -> str:
    quat = geometry.from_rotation(geometry.Rotation.from_euler("z", yaw))
    return (f'<body name="{name}" pos="{fmt(position)}" quat="{fmt(quat)}"><freejoint/>'
            f'<geom type="box" size="{fmt(half_sizes)}" rgba="{rgba(colour)}" mass="{mass}" '
            f'friction="{friction}" condim="4"/></body>')


def grasp_yaw(object_yaw: float, symmetry: float = np.pi / 2) -> float:
    """The gripper yaw in [-symmetry/2, symmetry/2) that closes the fingers on faces of an
    object with the given yaw and rotational symmetry (pi/2 for a square)."""
    return float((object_yaw + symmetry / 2) % symmetry - symmetry / 2)




def pick_and_place(pick_xyz, pick_yaw, place_xyz, place_yaw, transit_z: float,
                   grip_opening: float = 1.0) -> list[Waypoint]:
    """Waypoints that pick at TCP position `pick_xyz` and release at `place_xyz`, moving
    between them at height `transit_z`, gripper pointing down; `grip_opening` is the open
    command used while approaching and on release (a narrower opening clears neighbours and
    a box's walls)."""
    pick_xyz, place_xyz = np.asarray(pick_xyz, float), np.asarray(place_xyz, float)
    down_pick, down_place = geometry.quat_down(pick_yaw), geometry.quat_down(place_yaw)
    above = lambda xyz: np.array([xyz[0], xyz[1], transit_z])  # noqa: E731
    return [
        Waypoint(above(pick_xyz), down_pick, grip_opening, 1.0),
        Waypoint(pick_xyz, down_pick, grip_opening, 0.8),
        Waypoint(pick_xyz, down_pick, 0.0, 0.5),
        Waypoint(above(pick_xyz), down_pick, 0.0, 0.8),
        Waypoint(above(place_xyz), down_place, 0.0, 1.0),
        Waypoint(place_xyz, down_place, 0.0, 0.8),
        Waypoint(place_xyz, down_place, grip_opening, 0.4),
        Waypoint(above(place_xyz), down_place, grip_opening, 0.6),
    ]


def expert_path(waypoints: list[Waypoint], start_position=HOME_POSITION, start_quat=HOME_QUAT) -> dict:
    """The expert trajectory through `waypoints` at the control rate, from the gripper's start
    pose (the home pose unless the task's scene starts it elsewhere), fully open."""
    start = Waypoint(np.asarray(start_position, float), np.asarray(start_quat, float), 1.0, 0.0)
    return geometry.path_through(start, waypoints, CONTROL_HZ)


def released_and_at_rest(scene, log, names) -> list[str]:
    """Failure reasons shared by pick-and-place judges: an object still in the fingers, an
    object still moving."""
    reasons = []
    held = sorted(set(names) & log.final_finger_contacts)
    if held:
        reasons.append(f"not released: {', '.join(held)} still touching the fingers")
    moving = [n for n in names if log.final_speed[n] > REST_SPEED]
    if moving:
        reasons.append("not at rest: " + ", ".join(f"{n} at {log.final_speed[n]:.3f} m/s" for n in moving))
    return reasons


__all__ = ["COLOURS", "FINGER_TRAVEL", "REST_SPEED", "Waypoint", "box_body", "expert_path", "fmt",
           "grasp_yaw", "pick_and_place", "released_and_at_rest", "rgba", "sample_positions"]
