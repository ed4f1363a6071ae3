"""bar_into_tray: a long bar lying at any yaw, picked across its width and dropped into a
narrow tray that stands at another yaw, so both the grasp and the place turn with the
objects.

Variation (per seed): the bar's yaw and the tray's yaw (each uniform in [-70, 70] deg),
their positions (centres in x [-0.16, 0.16], y [-0.08, 0.14] m, at least 19 cm apart), and
their colours (distinct, from five). The bar is 12 x 3 x 3 cm; the tray is a fixed open
box, 16 x 6 cm inside, with 3 cm walls, so the bar fits only within about 14 deg of the
tray's long axis and 1.5 cm of its centre. Objects in label order: bar, tray.
Grasp: real finger contacts, the fingers closing on the bar's long faces at its middle.
Unlike the other tasks, what the motion has to get right is two orientations read from the
image (the grasp yaw from the bar, the release yaw from the tray), over a range of 140 deg.
Success: the bar lies inside the tray (its centre within the tray's inner floor, its bottom
on that floor, tilted less than 10 deg from flat), nothing is in the fingers, everything is
at rest.
"""

from __future__ import annotations

import numpy as np

from cnfmp import geometry, prompts
from cnfmp.sim.scene import scene_xml
from cnfmp.sim.task import Scene, Task, Verdict
from cnfmp.sim.tasks.common import (box_body, expert_path, fmt, pick_and_place, released_and_at_rest, rgba,
                                    sample_positions)

#: The bar's half sizes (m): long axis along its local x.
BAR_HALF = np.array([0.06, 0.015, 0.015])
BAR_MASS = 0.08
#: The tray's inner half sizes (m), wall thickness, wall height above the floor and floor
#: thickness.
TRAY_INNER_HALF = np.array([0.08, 0.03])
TRAY_WALL = 0.005
TRAY_WALL_HEIGHT = 0.03
TRAY_FLOOR = 0.004
YAW_RANGE = np.radians(70.0)
VIEW_LOW, VIEW_HIGH = np.array([-0.16, -0.08]), np.array([0.16, 0.14])
#: Centres at least this far apart (m): the tray's outer half diagonal plus the bar's half
#: length and 1.6 cm, so the bar never overlaps the tray whatever the two yaws.
MIN_DISTANCE = 0.19
#: TCP height relative to the bar's centre when grasping it: fingertips 1 cm under it.
GRASP_BELOW_CENTRE = 0.01
#: The bar's bottom is released this far above the tray's rim (m), so the fingers, beside
#: the bar, stay clear of the walls.
DROP_ABOVE_RIM = 0.012
TRANSIT_Z = 0.22
#: Finger command while approaching and releasing: wide enough for the 3 cm bar, narrow
#: enough to stay inside the tray's outline when releasing.
GRIP_OPEN = 0.7

TILT_TOLERANCE_DEG = 10.0
#: A bar in the tray rests on its floor: its bottom at most this far above the floor's top
#: (m; a bar bridging the walls rests 3 cm up).
FLOOR_SLACK = 0.008


def tray_body(name: str, xy, yaw: float, colour: str) -> str:
    """MJCF for the fixed tray: a floor plate and four walls, its origin at the floor's
    bottom centre, its long axis along its local x."""
    quat = geometry.from_rotation(geometry.Rotation.from_euler("z", yaw))
    (ix, iy), t, h = TRAY_INNER_HALF, TRAY_WALL, TRAY_WALL_HEIGHT
    wall_z = TRAY_FLOOR + h / 2
    boxes = [((ix + 2 * t, iy + 2 * t, TRAY_FLOOR / 2), (0.0, 0.0, TRAY_FLOOR / 2)),
             ((ix + 2 * t, t / 2, h / 2), (0.0, iy + t / 2, wall_z)),
             ((ix + 2 * t, t / 2, h / 2), (0.0, -(iy + t / 2), wall_z)),
             ((t / 2, iy, h / 2), (ix + t / 2, 0.0, wall_z)),
             ((t / 2, iy, h / 2), (-(ix + t / 2), 0.0, wall_z))]
    geoms = "".join(f'<geom type="box" size="{fmt(size)}" pos="{fmt(pos)}" rgba="{rgba(colour)}"/>'
                    for size, pos in boxes)
    return f'<body name="{name}" pos="{fmt((*xy, 0.0))}" quat="{fmt(quat)}">{geoms}</body>'


def make_scene(seed: int) -> Scene:
    rng = np.random.default_rng([seed, 11])
    vocabulary = prompts.load("bar_into_tray")
    bar_colour, tray_colour = (str(c) for c in rng.choice(vocabulary["colours"], size=2, replace=False))
    xy = sample_positions(rng, 2, VIEW_LOW, VIEW_HIGH, MIN_DISTANCE)
    yaws = rng.uniform(-YAW_RANGE, YAW_RANGE, size=2)
    bodies = [f"bar_{bar_colour}", f"tray_{tray_colour}"]
    xml = "\n    ".join([
        box_body(bodies[0], (*xy[0], BAR_HALF[2]), yaws[0], BAR_HALF, bar_colour, mass=BAR_MASS),
        tray_body(bodies[1], xy[1], yaws[1], tray_colour)])
    objects = [vocabulary["bar"].format(colour=bar_colour), vocabulary["tray"].format(colour=tray_colour)]
    template = vocabulary["templates"][rng.integers(len(vocabulary["templates"]))]
    prompt = template.format(bar=objects[0], tray=objects[1])
    params = {"colours": [bar_colour, tray_colour], "xy": xy.tolist(), "yaw": yaws.tolist()}
    return Scene("bar_into_tray", seed, scene_xml(xml), objects, [[b] for b in bodies], prompt, params)


def expert(scene: Scene) -> dict:
    xy, (bar_yaw, tray_yaw) = np.array(scene.params["xy"]), scene.params["yaw"]
    pick = (*xy[0], BAR_HALF[2] - GRASP_BELOW_CENTRE)
    rim_z = TRAY_FLOOR + TRAY_WALL_HEIGHT
    place = (*xy[1], rim_z + DROP_ABOVE_RIM + BAR_HALF[2] - GRASP_BELOW_CENTRE)
    # Gripper yaw 0 closes the fingers along world y, i.e. on the long faces of a bar of yaw 0.
    return expert_path(pick_and_place(pick, bar_yaw, place, tray_yaw, TRANSIT_Z, grip_opening=GRIP_OPEN))


def judge(scene: Scene, log) -> Verdict:
    bar, tray = scene.objects
    tray_xy, tray_yaw = np.array(scene.params["xy"][1]), scene.params["yaw"][1]
    position = log.final_position[bar]
    # The bar's centre in the tray's frame.
    c, s = np.cos(tray_yaw), np.sin(tray_yaw)
    dx, dy = position[:2] - tray_xy
    local = np.array([c * dx + s * dy, -s * dx + c * dy])
    rotation = geometry.to_rotation(log.final_quat[bar])
    tilt = float(np.degrees(np.arcsin(np.clip(abs(rotation.apply([1.0, 0.0, 0.0])[2]), 0.0, 1.0))))
    bottom_z = float(position[2] - BAR_HALF[2])
    reasons = []
    if np.any(np.abs(local) > TRAY_INNER_HALF) or bottom_z > TRAY_FLOOR + FLOOR_SLACK:
        reasons.append(f"{bar} is not in {tray} (centre at ({local[0]:+.3f}, {local[1]:+.3f}) m in the "
                       f"tray's frame, bottom at z = {bottom_z:.3f} m, the tray's floor at {TRAY_FLOOR:.3f} m)")
    if tilt > TILT_TOLERANCE_DEG:
        reasons.append(f"{bar} is not lying flat (long axis tilted {tilt:.0f} deg)")
    reasons += released_and_at_rest(scene, log, [bar])
    return Verdict(not reasons, reasons, {"bar_in_tray_frame_m": local.tolist(), "bar_bottom_z_m": bottom_z,
                                          "bar_tilt_deg": tilt})


TASK = Task("bar_into_tray", __doc__.split("\n\n")[0], make_scene, expert, judge)
