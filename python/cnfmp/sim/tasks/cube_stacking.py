"""cube_stacking: three 5 cm cubes at varying positions and yaw, stacked into a tower in a
given order.

Variation (per seed): cube positions (x in [-0.18, 0.18], y in [-0.10, 0.14] m, at least
11 cm apart), yaw of each cube (uniform in [-45, 45] deg), and the stacking order (a
permutation of red, green, blue). Objects in label order: bottom, middle, top cube.
Grasp: real finger contacts.
Success: each consecutive pair stacked (height difference 5 cm +- 1 cm, lateral offset
< 2 cm), the bottom cube on the table, nothing in the fingers, everything at rest.
"""

from __future__ import annotations

import numpy as np

from cnfmp import prompts
from cnfmp.sim.scene import scene_xml
from cnfmp.sim.task import Scene, Task, Verdict
from cnfmp.sim.tasks.common import (box_body, expert_path, grasp_yaw, pick_and_place,
                                    released_and_at_rest, sample_positions)

HALF = 0.025
#: TCP height relative to a cube's centre when grasping it: fingertips 1.3 cm under it.
GRASP_BELOW_CENTRE = 0.013
#: Release this far above the resting height (m).
PLACE_CLEARANCE = 0.004
HEIGHT_TOLERANCE = 0.01
LATERAL_TOLERANCE = 0.02
TRANSIT_Z = 0.26


def make_scene(seed: int) -> Scene:
    rng = np.random.default_rng([seed, 4])
    vocabulary = prompts.load("cube_stacking")
    colours = [str(c) for c in rng.permutation(vocabulary["colours"])]
    xy = sample_positions(rng, 3, (-0.18, -0.10), (0.18, 0.14), 0.11)
    yaws = rng.uniform(-np.pi / 4, np.pi / 4, size=3)
    bodies = [f"cube_{c}" for c in colours]
    xml = "\n    ".join(
        box_body(body, (x, y, HALF), yaw, (HALF, HALF, HALF), colour, mass=0.1)
        for body, colour, (x, y), yaw in zip(bodies, colours, xy, yaws))
    bottom, middle, top = colours
    template = vocabulary["templates"][rng.integers(len(vocabulary["templates"]))]
    prompt = template.format(bottom=bottom, middle=middle, top=top)
    params = {"colours": colours, "xy": xy.tolist(), "yaw": yaws.tolist()}
    objects = [vocabulary["object"].format(colour=c) for c in colours]
    return Scene("cube_stacking", seed, scene_xml(xml), objects, [[b] for b in bodies], prompt, params)


def expert(scene: Scene) -> dict:
    xy, yaws = np.array(scene.params["xy"]), np.array(scene.params["yaw"])
    base_yaw = grasp_yaw(yaws[0])
    waypoints = []
    for level in (1, 2):
        pick = (*xy[level], HALF - GRASP_BELOW_CENTRE)
        place = (*xy[0], HALF + 2 * HALF * level - GRASP_BELOW_CENTRE + PLACE_CLEARANCE)
        waypoints += pick_and_place(pick, grasp_yaw(yaws[level]), place, base_yaw, TRANSIT_Z)
    return expert_path(waypoints)


def judge(scene: Scene, log) -> Verdict:
    names = scene.objects
    final = {n: log.final_position[n] for n in names}
    reasons, metrics = [], {}
    if abs(final[names[0]][2] - HALF) > HEIGHT_TOLERANCE:
        reasons.append(f"{names[0]} is not on the table (centre at z = {final[names[0]][2]:.3f} m)")
    for lower, upper in zip(names, names[1:]):
        dz = final[upper][2] - final[lower][2]
        lateral = float(np.linalg.norm(final[upper][:2] - final[lower][:2]))
        metrics[f"{upper} on {lower}"] = {"dz_m": float(dz), "lateral_m": lateral}
        if abs(dz - 2 * HALF) > HEIGHT_TOLERANCE or lateral > LATERAL_TOLERANCE:
            reasons.append(f"{upper} is not stacked on {lower} (height difference {dz:.3f} m, "
                           f"lateral offset {lateral:.3f} m)")
    reasons += released_and_at_rest(scene, log, names)
    return Verdict(not reasons, reasons, metrics)


TASK = Task("cube_stacking", __doc__.split("\n\n")[0], make_scene, expert, judge)
