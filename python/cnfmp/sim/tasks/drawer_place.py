"""drawer_place: a carton box on the table is picked and placed inside the open part of a
drawer, whose opening varies.

Variation (per seed): the drawer's opening (10-16 cm, the slide joint's position), the
cabinet's x position (+-5 cm), the carton's position (x in [-0.20, 0.20], y in [-0.21,
-0.12] m) and yaw (uniform in [-45, 45] deg). Objects in label order: the carton box, the
drawer (its front panel, walls and floor); the cabinet around it is background.
Grasp: real finger contacts, the fingers closing along the drawer's width (world x), so the
wrist never reaches over the cabinet.
Success: the carton lies inside the drawer's inner footprint (its four bottom corners, in
the drawer's frame), resting on the drawer's floor, upright (within 15 deg), released and
at rest; the drawer moved by at most 1 cm; nothing touched the cabinet.

The cabinet is static; the drawer slides on a damped, frictional slide joint (no contact
with the cabinet: the joint alone holds it). Four fixed cameras (front, left, right, top)
see the scene for scans (:mod:`cnfmp.sim.scan`).
"""

from __future__ import annotations

import numpy as np

from cnfmp import geometry
from cnfmp.sim.scene import scene_xml
from cnfmp.sim.task import Scene, Task, Verdict
from cnfmp.sim.tasks.common import box_body, expert_path, fmt, grasp_yaw, released_and_at_rest

#: Carton half sizes (m): 6 x 6 x 5 cm.
CARTON_HALF = (0.03, 0.03, 0.025)
#: The drawer's opening range (m): how far its front stands out of the cabinet.
OPENING_RANGE = (0.10, 0.16)
#: The cabinet's front plane (world y, m) and its x position range (m).
CABINET_FRONT_Y = 0.12
CABINET_X_RANGE = (-0.05, 0.05)
#: The drawer's inner footprint in its own frame (m): x within +-INNER_HALF_X, y from 0
#: (the front panel's inner face) to INNER_DEPTH; its floor's top at FLOOR_TOP_Z (world z:
#: the joint moves it along y only).
INNER_HALF_X = 0.125
INNER_DEPTH = 0.26
FLOOR_TOP_Z = 0.02
DRAWER_WALL_TOP_Z = 0.095
#: Where the cabinet's body over the drawer starts (world z, m).
CABINET_SHELF_Z = 0.11
CABINET_HEIGHT = 0.22
CABINET_DEPTH = 0.30
CABINET_HALF_X = 0.16
#: The slide joint's damping (N s/m) and dry friction (N): a brush of the fingers does not
#: move it, a push does.
DRAWER_DAMPING = 8.0
DRAWER_FRICTION = 3.0
#: TCP height relative to the carton's centre when grasping (m), and the release height
#: above the resting height.
GRASP_BELOW_CENTRE = 0.01
PLACE_CLEARANCE = 0.006
TRANSIT_Z = 0.24
#: The judge's tolerances.
DRAWER_MOVE_TOLERANCE = 0.01
HEIGHT_TOLERANCE = 0.01
UPRIGHT_TOLERANCE_DEG = 15.0
#: The gripper's yaw while carrying and placing: fingers closing along world x.
PLACE_YAW = np.pi / 2

CARTON, DRAWER, CABINET = "carton", "drawer", "cabinet"
OBJECT_NAMES = ("carton box", "drawer")


def _box(name: str, centre, half, rgba: str) -> str:
    return f'<geom name="{name}" type="box" pos="{fmt(centre)}" size="{fmt(half)}" rgba="{rgba}"/>'


def cabinet_xml(x: float) -> str:
    """The static cabinet (side walls, back, the shelf over the drawer, the top and the front
    panel over the upper compartment), its front plane at CABINET_FRONT_Y."""
    wood, t = "0.55 0.42 0.30 1", 0.01
    y0, depth, height, hx = CABINET_FRONT_Y, CABINET_DEPTH, CABINET_HEIGHT, CABINET_HALF_X
    yc = y0 + depth / 2
    parts = [
        _box("cabinet_left", (-hx + t, yc, height / 2), (t, depth / 2, height / 2), wood),
        _box("cabinet_right", (hx - t, yc, height / 2), (t, depth / 2, height / 2), wood),
        _box("cabinet_back", (0, y0 + depth - t, height / 2), (hx, t, height / 2), wood),
        _box("cabinet_shelf", (0, yc, CABINET_SHELF_Z + t / 2), (hx, depth / 2, t / 2), wood),
        _box("cabinet_top", (0, yc, height - t / 2), (hx, depth / 2, t / 2), wood),
        _box("cabinet_front", (0, y0 + t / 2, (CABINET_SHELF_Z + height) / 2), (hx, t / 2, (height - CABINET_SHELF_Z) / 2),
             wood),
    ]
    return f'<body name="{CABINET}" pos="{x:.6f} 0 0">' + "".join(parts) + "</body>"


def drawer_xml(x: float, opening: float) -> str:
    """The drawer on its slide joint (qpos = how far it is open, m), closed at the cabinet's
    front plane: front panel, floor, side walls and back, all in its own frame."""
    light, t = "0.80 0.74 0.62 1", 0.01
    wall_half_z = (DRAWER_WALL_TOP_Z - FLOOR_TOP_Z) / 2 + t / 2
    wall_z = FLOOR_TOP_Z - t / 2 + wall_half_z
    parts = [
        _box("drawer_front", (0, -0.006, 0.06), (CABINET_HALF_X - 0.012, 0.006, 0.05), "0.35 0.50 0.65 1"),
        _box("drawer_floor", (0, INNER_DEPTH / 2, FLOOR_TOP_Z - t / 2), (INNER_HALF_X + t, INNER_DEPTH / 2, t / 2), light),
        _box("drawer_left", (-INNER_HALF_X - t / 2, INNER_DEPTH / 2, wall_z), (t / 2, INNER_DEPTH / 2, wall_half_z), light),
        _box("drawer_right", (INNER_HALF_X + t / 2, INNER_DEPTH / 2, wall_z), (t / 2, INNER_DEPTH / 2, wall_half_z), light),
        _box("drawer_back", (0, INNER_DEPTH + t / 2, wall_z), (INNER_HALF_X + t, t / 2, wall_half_z), light),
    ]
    joint = (f'<joint name="drawer_slide" type="slide" axis="0 -1 0" range="0 {INNER_DEPTH - 0.02:.3f}" '
             f'damping="{DRAWER_DAMPING}" frictionloss="{DRAWER_FRICTION}" ref="0"/>')
    # The joint's qpos0 is the body's position in the file; the opening is the initial qpos,
    # so the body is written already open and the joint's reference is shifted to match.
    joint = joint.replace('ref="0"', f'ref="{opening:.6f}"')
    return (f'<body name="{DRAWER}" pos="{x:.6f} {CABINET_FRONT_Y - opening:.6f} 0">{joint}'
            + "".join(parts) + '<inertial pos="0 0.13 0.05" mass="1.0" diaginertia="0.01 0.01 0.01"/></body>')


def make_scene(seed: int) -> Scene:
    rng = np.random.default_rng([seed, 6])
    opening = float(rng.uniform(*OPENING_RANGE))
    cabinet_x = float(rng.uniform(*CABINET_X_RANGE))
    carton_xy = (float(rng.uniform(-0.20, 0.20)), float(rng.uniform(-0.21, -0.12)))
    carton_yaw = float(rng.uniform(-np.pi / 4, np.pi / 4))
    carton = box_body(CARTON, (*carton_xy, CARTON_HALF[2]), carton_yaw, CARTON_HALF, "orange", mass=0.08)
    xml = "\n    ".join([cabinet_xml(cabinet_x), drawer_xml(cabinet_x, opening), carton])
    contact = f'<contact><exclude body1="{CABINET}" body2="{DRAWER}"/></contact>'
    params = {"opening": opening, "cabinet_x": cabinet_x, "carton_xy": list(carton_xy), "carton_yaw": carton_yaw}
    prompt = "put the carton box in the drawer"
    return Scene("drawer_place", seed, scene_xml(xml).replace("</mujoco>", f"  {contact}\n</mujoco>"),
                 list(OBJECT_NAMES), [[CARTON], [DRAWER]], prompt, params)


def place_target(params: dict) -> np.ndarray:
    """Where the expert puts the carton's centre (world, m): in the middle of the drawer's
    open part (between its front panel's inner face and the cabinet's front plane), on the
    floor."""
    y = CABINET_FRONT_Y - params["opening"] / 2
    return np.array([params["cabinet_x"], y, FLOOR_TOP_Z + CARTON_HALF[2]])


def expert(scene: Scene) -> dict:
    p = scene.params
    pick = np.array([*p["carton_xy"], CARTON_HALF[2] - GRASP_BELOW_CENTRE])
    # Of the carton's four equivalent grasps, the one nearest the placing yaw.
    pick_yaw = PLACE_YAW + grasp_yaw(p["carton_yaw"] - PLACE_YAW)
    place = place_target(p) + np.array([0.0, 0.0, PLACE_CLEARANCE - GRASP_BELOW_CENTRE])
    down_pick, down_place = geometry.quat_down(pick_yaw), geometry.quat_down(PLACE_YAW)
    above = lambda xyz, z=TRANSIT_Z: np.array([xyz[0], xyz[1], z])  # noqa: E731
    waypoints = [
        geometry.Waypoint(above(pick), down_pick, 1.0, 1.0),
        geometry.Waypoint(pick, down_pick, 1.0, 0.8),
        geometry.Waypoint(pick, down_pick, 0.0, 0.5),
        geometry.Waypoint(above(pick), down_pick, 0.0, 0.8),
        geometry.Waypoint(above(place), down_place, 0.0, 1.2),
        geometry.Waypoint(place, down_place, 0.0, 1.0),
        geometry.Waypoint(place, down_place, 1.0, 0.4),
        geometry.Waypoint(above(place), down_place, 1.0, 0.8),
    ]
    return expert_path(waypoints)


def judge(scene: Scene, log) -> Verdict:
    carton, drawer = scene.objects
    reasons, metrics = [], {}
    opened = CABINET_FRONT_Y - float(log.final_position[drawer][1])
    moved = opened - scene.params["opening"]
    metrics["drawer_moved_m"] = moved
    if abs(moved) > DRAWER_MOVE_TOLERANCE:
        reasons.append(f"the drawer was {'pulled' if moved > 0 else 'pushed'} by {abs(moved) * 100:.1f} cm")
    # The carton's bottom corners in the drawer's frame (the drawer only translates).
    rotation = geometry.to_rotation(log.final_quat[carton])
    hx, hy, hz = CARTON_HALF
    corners = rotation.apply([[sx * hx, sy * hy, -hz] for sx in (-1, 1) for sy in (-1, 1)])
    local = corners + log.final_position[carton] - log.final_position[drawer]
    outside = np.maximum(np.abs(local[:, 0]) - INNER_HALF_X, 0.0).max() + np.maximum(
        np.maximum(-local[:, 1], local[:, 1] - INNER_DEPTH), 0.0).max()
    metrics["outside_footprint_m"] = float(outside)
    if outside > 0.0:
        reasons.append(f"the carton is not inside the drawer (a corner {outside * 100:.1f} cm outside its footprint)")
    height = float(log.final_position[carton][2]) - (FLOOR_TOP_Z + hz)
    metrics["height_above_floor_m"] = height
    if abs(height) > HEIGHT_TOLERANCE:
        reasons.append(f"the carton is not on the drawer's floor (its centre {height * 100:+.1f} cm from resting on it)")
    tilt = float(np.degrees(np.arccos(np.clip(rotation.apply([0.0, 0.0, 1.0])[2], -1.0, 1.0))))
    metrics["tilt_deg"] = tilt
    if tilt > UPRIGHT_TOLERANCE_DEG:
        reasons.append(f"the carton is not upright (tilted {tilt:.0f} deg)")
    touching = sorted(name for pair in log.touched if CABINET in pair for name in pair if name != CABINET)
    if touching:
        reasons.append(f"touched the cabinet: {', '.join(sorted(set(touching)))}")
    reasons += released_and_at_rest(scene, log, [carton])
    return Verdict(not reasons, reasons, metrics)


TASK = Task("drawer_place", __doc__.split("\n\n")[0], make_scene, expert, judge, records_scans=True)
