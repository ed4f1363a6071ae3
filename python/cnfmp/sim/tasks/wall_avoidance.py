"""wall_avoidance: reach a goal marker on the far side of a wall, going over the wall without
touching it.

Variation (per seed): the wall's height (uniform in [0.08, 0.16] m), thickness ([0.01,
0.05] m) and position (its near face at y in [-0.06, 0.04] m; taller walls stand nearer
the camera), and the goal marker's position (x in [-0.15, 0.15] m; y between 4.5 cm behind
the wall and 0.24 m, and never where the wall hides it from the camera). The gripper starts
at a fixed ready pose low in front of the wall (TCP at x 0, y -0.20 m, 6 cm above the table;
10-26 cm before the wall's near face), so the straight line to the goal runs through the
wall. The robot's start pose is known and fixed, as in the paper's task; what varies is the
scene. The wall is one static box spanning 0.84 m in x, so going around it would leave the workspace.
Objects in label order: wall, goal marker (a flat disc on the table that nothing collides
with). No grasp: the gripper stays open throughout.
Success: no contact between the gripper and the wall at any physics step, and the final
measured tool centre point within 2 cm of the goal: 1.5 cm above the marker's centre.
The 27 training seeds of `cnfmp.seeds.NFMP_GRID_SEEDS` are a 3x3x3 grid of wall height, goal
x and goal y instead of random draws, for the grid-trained NFMP baseline.
"""

from __future__ import annotations

import functools
import xml.etree.ElementTree as ElementTree

import numpy as np

from cnfmp import geometry, prompts
from cnfmp.seeds import NFMP_GRID_SEEDS
from cnfmp.sim.scene import scene_xml
from cnfmp.sim.task import Scene, Task, Verdict
from cnfmp.sim.tasks.common import Waypoint, expert_path, fmt, rgba

#: Wall height range (m). Taller walls would hide the whole table up to GOAL_Y_MAX from the
#: front camera unless they stood nearer the camera than the home pose.
HEIGHT_RANGE = (0.08, 0.16)
THICKNESS_RANGE = (0.01, 0.05)
#: Range of the wall's near-face y (m); the far end shrinks for tall walls (_far_face_limit).
NEAR_FACE_Y_RANGE = (-0.06, 0.04)
#: Half the wall's length along x (m): the workspace ends at |x| = 0.45, so the gripper
#: (6 cm half-width) cannot pass beside it.
WALL_HALF_LENGTH = 0.42
WALL_RGBA = "0.55 0.56 0.60 1"
GOAL_X_RANGE = (-0.15, 0.15)
#: Farthest goal y (m): farther back the marker shrinks to a few pixels.
GOAL_Y_MAX = 0.24
#: Narrowest interval the goal y is drawn from (m), for the tallest wall farthest back.
GOAL_Y_MIN_SPAN = 0.02
#: The goal centre stays this far behind the wall's far face (m): the gripper, turned with
#: its fingers along the wall, reaches 2 cm in y (wrist radius); 2.5 cm margin on top.
GOAL_BEHIND_WALL = 0.045
GOAL_RADIUS = 0.03
GOAL_THICKNESS = 0.002
#: The goal is the TCP position this high above the marker's centre (m): the fingertips
#: end 3 mm below the TCP, so they stop about 1 cm above the table.
GOAL_HOVER = 0.015
#: TCP height above the wall's top while crossing it (m): 3 mm fingertip overhang below
#: the TCP plus about 4 cm margin.
CLEARANCE = 0.045
#: Gripper yaw while reaching (rad): the fingers and the long side of the palm lie along
#: the wall, so the gripper is thinnest across it.
REACH_YAW = np.pi / 2
#: Gripper start, the TCP's ready pose (m): in front of every wall, low enough that the
#: straight line to any goal runs through the wall.
START_POSITION = np.array([0.0, -0.20, 0.06])
#: Durations (s): rising to the crossing height, crossing to above the goal, the descent,
#: and holding still at the goal.
RISE_S, CROSS_S, DESCEND_S, HOLD_S = 1.0, 1.5, 1.2, 0.4
GOAL_TOLERANCE = 0.02
#: Levels of the grid-structured set the NFMP baseline trains on (3 levels of each of 3
#: parameters, 27 scenes): seed NFMP_GRID_SEEDS.start + 9 h + 3 x + y has wall height level h,
#: goal x level x and goal y level y (levels at 1/6, 1/2 and 5/6 of each range; the goal y
#: range depends on the wall).
GRID_LEVELS = (1 / 6, 1 / 2, 5 / 6)
GRIPPER_BODIES = ("gripper", "gripper_left", "gripper_right")


@functools.cache
def _camera_yz() -> tuple[float, float]:
    """(y, z) of the scene camera (m), read from the shared scene so the visibility rule
    follows it if it moves."""
    camera = ElementTree.fromstring(scene_xml("")).find(".//camera[@name='front']")
    _, y, z = (float(v) for v in camera.get("pos").split())
    return y, z


def _hidden_until(far_face_y: float, height: float) -> float:
    """The table y (m) up to which the wall hides the table from the camera: where the
    camera's ray over the wall's far top edge meets the table."""
    camera_y, camera_z = _camera_yz()
    return camera_y + (far_face_y - camera_y) * camera_z / (camera_z - height)


def _far_face_limit(height: float) -> float:
    """The farthest far-face y (m) at which a wall of `height` still leaves goal positions
    that are fully visible and at most GOAL_Y_MAX (the inverse of _hidden_until)."""
    camera_y, camera_z = _camera_yz()
    hidden_until = GOAL_Y_MAX - GOAL_Y_MIN_SPAN - GOAL_RADIUS
    return camera_y + (hidden_until - camera_y) * (camera_z - height) / camera_z


def grid_cell(seed: int) -> tuple[float, float, float] | None:
    """For a grid seed, the (wall height, goal x, goal y) levels of its cell as fractions of
    each parameter's range; None for any other seed."""
    if seed not in NFMP_GRID_SEEDS:
        return None
    cell = seed - NFMP_GRID_SEEDS.start
    return GRID_LEVELS[cell // 9], GRID_LEVELS[cell // 3 % 3], GRID_LEVELS[cell % 3]


def _within(interval: tuple[float, float], fraction: float) -> float:
    return interval[0] + fraction * (interval[1] - interval[0])


def make_scene(seed: int) -> Scene:
    rng = np.random.default_rng([seed, 9])
    grid = grid_cell(seed)
    if grid is None:
        height = rng.uniform(*HEIGHT_RANGE)
        thickness = rng.uniform(*THICKNESS_RANGE)
        near_face = rng.uniform(NEAR_FACE_Y_RANGE[0], min(NEAR_FACE_Y_RANGE[1], _far_face_limit(height) - thickness))
    else:  # the grid varies height and goal; the wall's thickness and place sit mid-range
        height = _within(HEIGHT_RANGE, grid[0])
        thickness = _within(THICKNESS_RANGE, 0.5)
        near_face = _within((NEAR_FACE_Y_RANGE[0], min(NEAR_FACE_Y_RANGE[1], _far_face_limit(height) - thickness)), 0.5)
    far_face = near_face + thickness
    goal_y_low = max(far_face + GOAL_BEHIND_WALL, _hidden_until(far_face, height) + GOAL_RADIUS)
    if grid is None:
        goal_xy = np.array([rng.uniform(*GOAL_X_RANGE), rng.uniform(goal_y_low, GOAL_Y_MAX)])
    else:
        goal_xy = np.array([_within(GOAL_X_RANGE, grid[1]), _within((goal_y_low, GOAL_Y_MAX), grid[2])])
    wall_centre = (0.0, near_face + thickness / 2, height / 2)
    # A static body (no joint); the goal's geoms neither collide nor push, but the marker
    # has its own body so it gets a mask.
    xml = (f'<body name="wall" pos="{fmt(wall_centre)}"><geom type="box" '
           f'size="{fmt((WALL_HALF_LENGTH, thickness / 2, height / 2))}" rgba="{WALL_RGBA}"/></body>\n    '
           f'<body name="goal" pos="{fmt((*goal_xy, GOAL_THICKNESS / 2))}"><geom type="cylinder" '
           f'size="{fmt((GOAL_RADIUS, GOAL_THICKNESS / 2))}" rgba="{rgba("red")}" contype="0" conaffinity="0"/></body>')
    start = START_POSITION
    params = {"wall_height": height, "wall_thickness": thickness, "wall_near_face_y": near_face,
              "goal": [*goal_xy.tolist(), GOAL_HOVER], "start": start.tolist()}
    vocabulary = prompts.load("wall_avoidance")
    prompt = vocabulary["templates"][rng.integers(len(vocabulary["templates"]))]
    xml = scene_xml(xml, gripper_position=start, gripper_quat=geometry.quat_down(REACH_YAW))
    return Scene("wall_avoidance", seed, xml, vocabulary["objects"], [["wall"], ["goal"]], prompt, params)


def expert(scene: Scene) -> dict:
    """Rise straight up from the start to the crossing height, cross to above the goal
    (fingers along the wall, so the gripper is thinnest across it), descend and hold."""
    goal, start = np.array(scene.params["goal"]), np.array(scene.params["start"])
    crossing_z = scene.params["wall_height"] + CLEARANCE
    down = geometry.quat_down(REACH_YAW)
    return expert_path([
        Waypoint(np.array([start[0], start[1], crossing_z]), down, 1.0, RISE_S),
        Waypoint(np.array([goal[0], goal[1], crossing_z]), down, 1.0, CROSS_S),
        Waypoint(goal, down, 1.0, DESCEND_S),
        Waypoint(goal, down, 1.0, HOLD_S),
    ], start_position=start, start_quat=down)


def judge(scene: Scene, log) -> Verdict:
    goal = np.array(scene.params["goal"])
    distance = float(np.linalg.norm(log.ee_position[-1] - goal))
    touched_wall = log.touched_any(GRIPPER_BODIES, ["wall"])
    reasons = []
    if touched_wall:
        reasons.append("the gripper touched the wall")
    if distance > GOAL_TOLERANCE:
        reasons.append(f"the gripper ended {distance:.3f} m from the goal (tolerance {GOAL_TOLERANCE} m)")
    return Verdict(not reasons, reasons, {"goal_distance_m": distance, "touched_wall": touched_wall})


TASK = Task("wall_avoidance", __doc__.split("\n\n")[0], make_scene, expert, judge)
