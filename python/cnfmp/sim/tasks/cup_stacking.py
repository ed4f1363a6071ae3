"""cup_stacking: two or three open cups of different sizes at varying positions, nested one
inside the next in a given order (smaller into larger).

Variation (per seed): the number of cups (2 or 3), their colours (distinct, from six), the
innermost cup's outer radius (2.5-2.9 cm), the clearance between each cup and the one it
goes into (0.9-1.2 cm radially), each cup's height (5.5-7 cm), and the cup positions
(whole cups inside x in [-0.2, 0.2], y in [-0.12, 0.16] m, at least 3 cm apart). A cup is
a 10-sided wall of thin boxes (3.5 mm) on a 4 mm floor disc. Objects in label order: the
cups from the outermost (bottom) to the innermost; the prompt names the nesting order.
Grasp: weld on close. The gripper takes a cup by the front wall (the -y side), one finger
inside and one outside, 1.5 cm below the rim.
Success: each cup rests inside the previous one (its base between that cup's floor and rim,
its centre within the clearance of that cup's centre), the outermost cup stands on the
table, every cup is upright within 10 deg, nothing is in the fingers, everything is at rest.
"""

from __future__ import annotations

import numpy as np

from cnfmp import geometry, prompts
from cnfmp.sim.engine import weld_xml
from cnfmp.sim.scene import scene_xml
from cnfmp.sim.task import Scene, Task, Verdict
from cnfmp.sim.tasks.common import (Waypoint, expert_path, fmt, pick_and_place, released_and_at_rest, rgba,
                                    sample_positions)

#: Wall segments per cup: few boxes keep contacts cheap (facts.md).
WALL_SEGMENTS = 10
WALL_THICKNESS = 0.0035
FLOOR_THICKNESS = 0.004
CUP_MASS = 0.06
#: Stiff contacts (time constant 2 physics steps, the least MuJoCo allows): with the default
#: 20 ms a cup dropped 2-3 cm sinks through a 4 mm floor before the contact stops it.
CUP_SOLREF = "0.004 1"
#: Share of the cup's mass in its floor disc; the rest is spread over the wall.
FLOOR_MASS_SHARE = 0.4
INNERMOST_RADIUS = (0.025, 0.029)
CLEARANCE = (0.009, 0.012)
HEIGHT = (0.055, 0.07)
#: Table area the cups stand in, in the camera's view (m), and the gap between rims.
VIEW_LOW, VIEW_HIGH = np.array([-0.2, -0.12]), np.array([0.2, 0.16])
RIM_GAP = 0.03

#: The gripper takes each cup at the wall point facing -y, fingers closing along world y.
GRASP_DIRECTION = np.array([0.0, -1.0])
GRASP_YAW = 0.0
#: Fingertips this far below the rim when grasping (m).
GRIP_DEPTH = 0.015
#: Finger command while approaching and releasing: wide enough to clear the wall on both
#: sides, narrow enough that the inside finger misses the opposite wall, and >= 0.5 so the
#: weld lets go.
GRIP_OPEN = 0.55
#: Release with the fingertips this far above the outer cup's rim: the outside finger is
#: thicker than the clearance, so it cannot enter the outer cup.
RIM_MARGIN = 0.006
#: The carried cup is released at least this far above where it comes to rest (m).
MIN_DROP = 0.008
TRANSIT_Z = 0.20

UPRIGHT_TOLERANCE_DEG = 10.0
#: Slack on the lateral check for the polygonal walls and contact penetration (m).
LATERAL_SLACK = 0.003
#: Contact penetration allowed when checking that a base rests on the table or a floor (m).
FLOOR_SLACK = 0.003


def circumradius(radius: float) -> float:
    """Distance from a cup's axis to its outer wall corners (the walls' flats lie at `radius`)."""
    return radius / np.cos(np.pi / WALL_SEGMENTS)


def cup_body(name: str, xy, radius: float, height: float, colour: str) -> str:
    """MJCF for a cup whose body origin is the centre of its base, so the body position is
    where the cup stands."""
    wall_half_height = (height - FLOOR_THICKNESS) / 2
    # Each box's outer face is a flat at `radius`; its half width closes the outer polygon
    # (neighbouring boxes overlap on the inside).
    half_width = radius * np.tan(np.pi / WALL_SEGMENTS)
    wall_mass = CUP_MASS * (1 - FLOOR_MASS_SHARE) / WALL_SEGMENTS
    walls = []
    for angle in np.arange(WALL_SEGMENTS) * 2 * np.pi / WALL_SEGMENTS:
        centre = (radius - WALL_THICKNESS / 2) * np.array([np.cos(angle), np.sin(angle)])
        quat = geometry.from_rotation(geometry.Rotation.from_euler("z", angle))
        walls.append(
            f'<geom type="box" size="{fmt((WALL_THICKNESS / 2, half_width, wall_half_height))}" '
            f'pos="{fmt((*centre, FLOOR_THICKNESS + wall_half_height))}" quat="{fmt(quat)}" '
            f'rgba="{rgba(colour)}" mass="{wall_mass:.6f}" solref="{CUP_SOLREF}"/>')
    floor = (f'<geom type="cylinder" size="{radius:.6f} {FLOOR_THICKNESS / 2:.6f}" '
             f'pos="0 0 {FLOOR_THICKNESS / 2:.6f}" rgba="{rgba(colour)}" '
             f'mass="{CUP_MASS * FLOOR_MASS_SHARE:.6f}" solref="{CUP_SOLREF}"/>')
    return (f'<body name="{name}" pos="{fmt((*xy, 0.0))}"><freejoint/>{floor}'
            + "".join(walls) + "</body>")


def make_scene(seed: int) -> Scene:
    rng = np.random.default_rng([seed, 7])
    count = int(rng.integers(2, 4))
    vocabulary = prompts.load("cup_stacking")
    colours = [str(c) for c in rng.choice(vocabulary["colours"], size=count, replace=False)]
    clearances = rng.uniform(*CLEARANCE, size=count - 1)
    # Radii from the innermost cup outwards: each cup's inner flats sit `clearance` beyond
    # the corners of the cup that goes into it.
    radii = [rng.uniform(*INNERMOST_RADIUS)]
    for clearance in clearances[::-1]:
        radii.append(circumradius(radii[-1]) + clearance + WALL_THICKNESS)
    radii = radii[::-1]
    heights = rng.uniform(*HEIGHT, size=count)
    widest = circumradius(radii[0])
    xy = sample_positions(rng, count, VIEW_LOW + widest, VIEW_HIGH - widest, 2 * widest + RIM_GAP)
    bodies = [f"cup_{c}" for c in colours]
    xml = "\n    ".join(cup_body(body, p, r, h, c)
                        for body, p, r, h, c in zip(bodies, xy, radii, heights, colours))
    welds = "".join(weld_xml(body) for body in bodies)
    steps = [vocabulary["step"].format(inner=inner, outer=outer) for outer, inner in zip(colours, colours[1:])]
    template = vocabulary["templates"][rng.integers(len(vocabulary["templates"]))]
    prompt = template.format(steps=vocabulary["joiner"].join(steps))
    params = {"colours": colours, "xy": xy.tolist(), "radius": [float(r) for r in radii],
              "height": heights.tolist(), "clearance": clearances.tolist()}
    return Scene("cup_stacking", seed, scene_xml(xml, extra_equality=welds),
                 [vocabulary["object"].format(colour=c) for c in colours], [[b] for b in bodies], prompt, params,
                 weld_grasp=True)


def nest_waypoints(pick_xy, radius: float, height: float, target_xy, target_base_z: float,
                   outer_rim_z: float) -> list[Waypoint]:
    """Waypoints that take a cup (standing on the table at `pick_xy`) by its wall and lower
    it, centred on `target_xy`, until its base is just above `target_base_z` or its
    fingers just above `outer_rim_z`, whichever is higher, then let go and back off up."""
    grasp_offset = (radius - WALL_THICKNESS / 2) * GRASP_DIRECTION
    pick = np.array([*(np.asarray(pick_xy) + grasp_offset), height - GRIP_DEPTH])
    place_z = max(outer_rim_z + RIM_MARGIN, target_base_z + MIN_DROP + height - GRIP_DEPTH)
    place = np.array([*(np.asarray(target_xy) + grasp_offset), place_z])
    return pick_and_place(pick, GRASP_YAW, place, GRASP_YAW, TRANSIT_Z, grip_opening=GRIP_OPEN)


def expert(scene: Scene) -> dict:
    p = scene.params
    xy, radii, heights = np.array(p["xy"]), p["radius"], p["height"]
    waypoints = []
    # Cup k+1 goes into cup k, which by then stands on the floors of the k cups below it.
    for outer in range(len(radii) - 1):
        outer_base_z = outer * FLOOR_THICKNESS
        inner = outer + 1
        waypoints += nest_waypoints(xy[inner], radii[inner], heights[inner], xy[0],
                                    outer_base_z + FLOOR_THICKNESS, outer_base_z + heights[outer])
    return expert_path(waypoints)


def tilt_deg(quat) -> float:
    """Angle between a body's z axis and world z (deg)."""
    z_axis = geometry.to_rotation(quat).apply([0.0, 0.0, 1.0])
    return float(np.degrees(np.arccos(np.clip(z_axis[2], -1.0, 1.0))))


def judge(scene: Scene, log) -> Verdict:
    names, p = scene.objects, scene.params
    base = {n: log.final_position[n] for n in names}
    reasons, nesting = [], {}
    tilts = {n: tilt_deg(log.final_quat[n]) for n in names}
    tilted = [n for n in names if tilts[n] > UPRIGHT_TOLERANCE_DEG]
    if tilted:
        reasons.append("not upright: "
                       + ", ".join(f"{n} tilted {tilts[n]:.0f} deg" for n in tilted))
    bottom_z = base[names[0]][2]
    if abs(bottom_z) > FLOOR_SLACK:
        reasons.append(f"{names[0]} is not standing on the table (base at z = {bottom_z:.3f} m)")
    for k, (outer, inner) in enumerate(zip(names, names[1:])):
        rise = float(base[inner][2] - base[outer][2])
        lateral = float(np.linalg.norm(base[inner][:2] - base[outer][:2]))
        nesting[f"{inner} in {outer}"] = {"base_rise_m": rise, "lateral_m": lateral}
        inside = FLOOR_THICKNESS - FLOOR_SLACK <= rise <= p["height"][k]
        centred = lateral <= p["clearance"][k] + LATERAL_SLACK
        if not (inside and centred):
            reasons.append(f"{inner} is not nested in {outer} (its base {rise:+.3f} m from that "
                           f"cup's base, centres {lateral:.3f} m apart)")
    reasons += released_and_at_rest(scene, log, names)
    return Verdict(not reasons, reasons, {"nesting": nesting, "tilt_deg": tilts})


TASK = Task("cup_stacking", __doc__.split("\n\n")[0], make_scene, expert, judge)
