"""incline_pick_place: pick up a 4 cm block and set it down flat on a tilted plate (a ramp),
with the gripper tilted to match the slope.

Variation (per seed): the plate's slope angle (uniform in [10, 35] deg), the direction in
which it rises (yaw uniform over the full turn) and its position (centre x in [-0.08, 0.08],
y in [-0.04, 0.08] m); the block's colour, position (x in [-0.19, 0.19], y in [-0.11, 0.15] m,
at least 15 cm from the plate centre) and yaw (uniform in [-45, 45] deg). The plate is a static
14 x 12 x 1.2 cm box whose lower edge rests on the table and whose upper edge stands on a
vertical back support, so the slope shows in the image. Objects in label order: the block,
the plate (with its support). Grasp: real finger contacts.
Success: the block's centre, seen in the plate's frame, lies over the plate's face at least
1 cm inside its edges and half a block (+- 1 cm) above it; the block was released with the
tool centre point at most 4 cm above the face (placed, not dropped) and with the gripper's
finger axis within 15 deg of the plate's inward normal (a block released above a slope settles
flat whatever the tilt, so the orientation is judged at release); nothing is left in the
fingers and the block is at rest.
"""

from __future__ import annotations

import numpy as np

from cnfmp import geometry, prompts
from cnfmp.sim.scene import scene_xml
from cnfmp.sim.task import Scene, Task, Verdict
from cnfmp.sim.tasks.common import (Waypoint, box_body, expert_path, fmt, grasp_yaw,
                                    released_and_at_rest, sample_positions)

BLOCK_HALF = 0.02
BLOCK_MASS = 0.08
#: Half extents of the plate (m): 14 cm across the slope (x), 12 cm along it (y), 1.2 cm thick.
PLATE_HALF = np.array([0.07, 0.06, 0.006])
PLATE_RGBA = "0.45 0.47 0.52 1"
SUPPORT_RGBA = "0.32 0.33 0.36 1"
#: The back support: 1 cm thick, 1 cm narrower than the plate on each side.
SUPPORT_HALF_THICKNESS = 0.005
SUPPORT_INSET = 0.01
#: High friction on both surfaces so the block stays put at 35 deg (tan 35 deg = 0.70).
FRICTION = "1.5 0.01 0.0001"
SLOPE_RANGE = np.radians([10.0, 35.0])
#: How far the plate's lower edge sinks into the table (m), so no gap shows under it.
PLATE_SINK = 0.002
#: Least distance from the block to the plate centre (m): the plate's footprint radius (9.2 cm)
#: plus the reach of the open fingers around the block (4.4 cm), so picking never brushes it.
MIN_BLOCK_TO_PLATE = 0.15
#: TCP offset from the block's centre towards its bottom face when grasping it (m).
GRASP_BELOW_CENTRE = 0.01
#: Finger command while approaching and releasing: a 6.3 cm gap around the 4 cm block.
APPROACH_OPENING = 0.7
#: The block is released this far (m) above the face, and approached along the face normal
#: over the last APPROACH_DISTANCE.
PLACE_CLEARANCE = 0.004
APPROACH_DISTANCE = 0.06
TRANSIT_Z = 0.22
#: Judge tolerances.
EDGE_MARGIN = 0.01
HEIGHT_TOLERANCE = 0.01
MAX_RELEASE_HEIGHT = 0.04
MAX_TILT_ERROR = np.radians(15.0)


def make_scene(seed: int) -> Scene:
    rng = np.random.default_rng([seed, 11])
    slope = rng.uniform(*SLOPE_RANGE)
    plate_yaw = rng.uniform(-np.pi, np.pi)
    plate_xy = rng.uniform((-0.08, -0.04), (0.08, 0.08))
    block_xy = sample_positions(rng, 1, (-0.19, -0.11), (0.19, 0.15), MIN_BLOCK_TO_PLATE,
                                avoid=[plate_xy])[0]
    block_yaw = rng.uniform(-np.pi / 4, np.pi / 4)
    vocabulary = prompts.load("incline_pick_place")
    colour = str(rng.choice(vocabulary["colours"]))
    params = {"colour": colour, "block_xy": block_xy.tolist(), "block_yaw": float(block_yaw),
              "plate_xy": plate_xy.tolist(), "plate_yaw": float(plate_yaw), "slope": float(slope)}
    block = box_body("block", (*block_xy, BLOCK_HALF), block_yaw, (BLOCK_HALF,) * 3, colour,
                     BLOCK_MASS, FRICTION)
    template = vocabulary["templates"][rng.integers(len(vocabulary["templates"]))]
    objects = [name.format(colour=colour) for name in vocabulary["objects"]]
    return Scene("incline_pick_place", seed, scene_xml(block + "\n    " + _plate_xml(params)),
                 objects, [["block"], ["plate"]], template.format(colour=colour), params)


def _plate_pose(params: dict) -> tuple[geometry.Rotation, np.ndarray]:
    """The plate box's orientation and centre. Its local y axis runs up the slope, so the
    rotation is a yaw about world z after a tilt about the plate's own x axis; the centre
    is raised so that the lower edge of the bottom face sits PLATE_SINK under the table."""
    slope = params["slope"]
    rotation = (geometry.Rotation.from_euler("z", params["plate_yaw"])
                * geometry.Rotation.from_euler("x", slope))
    half_y, half_z = PLATE_HALF[1:]
    height = half_y * np.sin(slope) + half_z * np.cos(slope) - PLATE_SINK
    return rotation, np.array([*params["plate_xy"], height])


def _plate_xml(params: dict) -> str:
    """The static plate and, under its upper edge, a vertical back support that makes the
    slope readable in the camera image. Static geoms never collide with the table."""
    rotation, centre = _plate_pose(params)
    half_x, half_y, half_z = PLATE_HALF
    slope = params["slope"]
    # Highest point of the plate's underside; the support reaches it from the table, its back
    # flush with the upper edge, so its top stays hidden inside the plate.
    top = centre[2] + half_y * np.sin(slope) - half_z * np.cos(slope)
    back = half_y * np.cos(slope) + half_z * np.sin(slope) - SUPPORT_HALF_THICKNESS
    level = geometry.Rotation.from_euler("z", params["plate_yaw"])
    support_centre = np.array([*params["plate_xy"], 0.0]) + level.apply([0.0, back, top / 2])
    # Geom poses are given in the plate's (tilted) frame.
    local_pos = rotation.inv().apply(support_centre - centre)
    local_quat = geometry.from_rotation(rotation.inv() * level)
    support_half = (half_x - SUPPORT_INSET, SUPPORT_HALF_THICKNESS, top / 2)
    return (f'<body name="plate" pos="{fmt(centre)}" quat="{fmt(geometry.from_rotation(rotation))}">'
            f'<geom type="box" size="{fmt(PLATE_HALF)}" rgba="{PLATE_RGBA}" friction="{FRICTION}" '
            f'condim="4"/>'
            f'<geom type="box" size="{fmt(support_half)}" pos="{fmt(local_pos)}" '
            f'quat="{fmt(local_quat)}" rgba="{SUPPORT_RGBA}"/></body>')


def plate_face(params: dict) -> tuple[geometry.Rotation, np.ndarray]:
    """The plate's orientation and the centre of its top face; the rotation's z axis is the
    face's outward normal."""
    rotation, centre = _plate_pose(params)
    return rotation, centre + rotation.apply([0.0, 0.0, PLATE_HALF[2]])


def expert(scene: Scene) -> dict:
    params = scene.params
    rotation, face_centre = plate_face(params)
    normal = rotation.apply([0.0, 0.0, 1.0])
    down = geometry.quat_down(grasp_yaw(params["block_yaw"]))
    # The smallest turn that makes the fingers point into the face: about the plate's level
    # (x) axis by the slope angle, which keeps the block's bottom face parallel to the slope.
    tilt = geometry.Rotation.from_rotvec(params["slope"] * rotation.apply([1.0, 0.0, 0.0]))
    tilted = geometry.from_rotation(tilt * geometry.to_rotation(down))
    pick = np.array([*params["block_xy"], BLOCK_HALF - GRASP_BELOW_CENTRE])
    # While held, the TCP sits GRASP_BELOW_CENTRE from the block centre along the fingers.
    block_target = face_centre + (BLOCK_HALF + PLACE_CLEARANCE) * normal
    place = block_target - GRASP_BELOW_CENTRE * normal
    approach = place + APPROACH_DISTANCE * normal
    lifted = np.array([pick[0], pick[1], TRANSIT_Z])
    over_plate = np.array([approach[0], approach[1], TRANSIT_Z])
    return expert_path([
        Waypoint(lifted, down, APPROACH_OPENING, 1.0),
        Waypoint(pick, down, APPROACH_OPENING, 0.8),
        Waypoint(pick, down, 0.0, 0.5),
        Waypoint(lifted, down, 0.0, 0.8),
        Waypoint(over_plate, tilted, 0.0, 1.2),
        Waypoint(approach, tilted, 0.0, 0.7),
        Waypoint(place, tilted, 0.0, 0.6),
        Waypoint(place, tilted, APPROACH_OPENING, 0.4),
        Waypoint(approach, tilted, APPROACH_OPENING, 0.6),
    ])


def judge(scene: Scene, log) -> Verdict:
    block, plate = scene.objects
    rotation, face_centre = plate_face(scene.params)
    inward_normal = rotation.apply([0.0, 0.0, -1.0])
    on_face = rotation.inv().apply(log.final_position[block] - face_centre)
    reasons = []
    metrics = {"block_in_plate_frame_m": on_face.tolist()}
    inset = PLATE_HALF[:2] - EDGE_MARGIN
    if np.any(np.abs(on_face[:2]) > inset):
        reasons.append(f"{block} is not over the {plate}'s face: centre at "
                       f"({on_face[0]:.3f}, {on_face[1]:.3f}) m in the plate frame, face bounds "
                       f"+-{inset[0]:.3f} x +-{inset[1]:.3f} m")
    if abs(on_face[2] - BLOCK_HALF) > HEIGHT_TOLERANCE:
        reasons.append(f"{block} is not resting on the {plate}'s face: centre {on_face[2]:.3f} m "
                       f"above it, expected {BLOCK_HALF:.3f} m")
    if log.release_step is None:
        reasons.append(f"the gripper never released {block}")
    else:
        release_height = float(rotation.inv().apply(log.ee_position[log.release_step] - face_centre)[2])
        fingers = geometry.to_rotation(log.release_quat).apply([0.0, 0.0, 1.0])
        tilt_error = float(np.arccos(np.clip(fingers @ inward_normal, -1.0, 1.0)))
        metrics.update(release_height_m=release_height, tilt_error_deg=float(np.degrees(tilt_error)))
        if release_height > MAX_RELEASE_HEIGHT:
            reasons.append(f"{block} was dropped: released with the gripper {release_height:.3f} m "
                           f"above the {plate}'s face (at most {MAX_RELEASE_HEIGHT} m)")
        if tilt_error > MAX_TILT_ERROR:
            reasons.append(f"gripper tilt at release is {np.degrees(tilt_error):.1f} deg off the "
                           f"{plate}'s normal (at most {np.degrees(MAX_TILT_ERROR):.0f} deg)")
    reasons += released_and_at_rest(scene, log, [block])
    return Verdict(not reasons, reasons, metrics)


TASK = Task("incline_pick_place", __doc__.split("\n\n")[0], make_scene, expert, judge)
