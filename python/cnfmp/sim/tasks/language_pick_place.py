"""language_pick_place: a cluttered table of 3-6 objects; the prompt names the object to
move and the place to put it ("put the red ball in the blue box", "place the green mug on
the paper").

Objects (label order): the named object, the named place, then the distractors.
Things to move: cube (edge 4-5 cm), ball (radius 2-2.5 cm), cup (outer radius 2.5-3 cm,
height 5-6 cm, an eight-walled ring on a disc; with a handle it is called a mug), can
(cylinder, radius 2-2.4 cm, height 5.5-6.5 cm). Places: box (open tray, inner side
11-13 cm, walls 3-4 cm high), paper (14 x 10 cm white sheet, 1.5 mm thick), plate (flat
disc, radius 6-7 cm). Every object is a free body.
Variation (per seed): object count (3-6: one named object, one named place, 1-4 movable
distractors and sometimes a second place), categories, colours, sizes, handles, positions
(x in [-0.2, 0.2], y in [-0.12, 0.16] m, never closer than the gripper needs) and yaws, and
the prompt template. Category-level split: each movable category has two held-out colours
(:data:`HELDOUT_COLOURS`; each colour is held out for exactly one category, so every colour
and every category is seen in training). Scenes from held-out seeds name an object of a
held-out (category, colour); training scenes show training combinations only.
Grasp: weld on close.
Success: the named object rests in the box (centre inside the inner walls, on the floor) or
on the paper / plate (centre over its extent, on its surface), released and at rest, and
no other object (places included) moved more than 2 cm.
"""

from __future__ import annotations

import numpy as np

from cnfmp import geometry, prompts
from cnfmp.seeds import HELDOUT_SEEDS
from cnfmp.sim import engine
from cnfmp.sim.scene import FINGER_TRAVEL, scene_xml
from cnfmp.sim.task import Scene, Task, Verdict
from cnfmp.sim.tasks.common import (COLOURS, box_body, expert_path, fmt, grasp_yaw,
                                    pick_and_place, released_and_at_rest, rgba)

# --- Language: vocabulary and prompt templates, from prompts/language_pick_place.json ------

_VOCABULARY = prompts.load("language_pick_place")
#: Categories of things to move, and the noun each is called by.
MOVABLE_NOUNS: dict[str, str] = _VOCABULARY["movable_nouns"]
#: A cup with a handle is called a mug.
MUG_NOUN: str = _VOCABULARY["mug_noun"]
#: Colours held out per movable category: (category, colour) pairs never shown in training.
HELDOUT_COLOURS = {category: tuple(colours) for category, colours in _VOCABULARY["heldout_colours"].items()}
#: The complementary training colours per movable category.
TRAINING_COLOURS = {category: tuple(c for c in COLOURS if c not in held_out)
                    for category, held_out in HELDOUT_COLOURS.items()}
#: Kinds of places, with the colours each comes in ("all": every colour of COLOURS).
PLACE_COLOURS = {kind: tuple(COLOURS) if colours == "all" else tuple(colours)
                 for kind, colours in _VOCABULARY["place_colours"].items()}
#: Prompt templates per place kind; {object} and {place} are object names ("red ball").
PROMPT_TEMPLATES = {kind: tuple(templates) for kind, templates in _VOCABULARY["templates"].items()}
#: How the judge's reasons relate an object to each place kind.
PLACE_PREPOSITION: dict[str, str] = _VOCABULARY["place_preposition"]

# --- Geometry (m, kg) -----------------------------------------------------------------------

CUP_WALLS = 8
CUP_WALL_THICKNESS = 0.004
CUP_BASE_THICKNESS = 0.005
#: Mug handle: capsule radius and how far its outer bar stands off the wall.
HANDLE_RADIUS = 0.004
HANDLE_REACH = 0.014
HANDLE_MASS = 0.002
BOX_WALL_THICKNESS = 0.005
BOX_FLOOR_THICKNESS = 0.005
PAPER_HALF_SIZE = (0.07, 0.05)
PAPER_THICKNESS = 0.0015
PLATE_THICKNESS = 0.008
MASS = {"cube": 0.1, "ball": 0.06, "cup": 0.08, "can": 0.12, "box": 0.4, "paper": 0.01,
        "plate": 0.15}
FRICTION = "1.5 0.01 0.0001"
#: Balls get rolling friction (condim 6) so that a ball set down stays where it was put.
BALL_FRICTION = "1.0 0.01 0.002"

# --- Scene layout ---------------------------------------------------------------------------

#: Total object count range (inclusive), places included.
OBJECT_COUNT = (3, 6)
#: Chance of a second, distractor place when there are at least 4 objects.
SECOND_PLACE_CHANCE = 0.4
#: Centre ranges (x, y) for movable objects and for places (kept central so that whole
#: places stay in the camera's view).
MOVABLE_AREA = ((-0.2, -0.12), (0.2, 0.16))
PLACE_AREA = ((-0.14, -0.06), (0.14, 0.10))
#: Free gap between footprints (m): more than an open finger plus its thickness needs
#: beside a grasped object, so picking never brushes a neighbour.
CLEARANCE = 0.035
PLACE_GAP = 0.02
#: Yaw range (+-, rad) where it is not a full turn: the paper stays roughly landscape so it
#: fits the view; a square box repeats every quarter turn.
YAW_HALF_RANGE = {"paper": np.pi / 6, "box": np.pi / 4}
LAYOUT_ATTEMPTS = 2_000
TRIES_PER_OBJECT = 200

# --- Expert ---------------------------------------------------------------------------------

#: Finger gap beyond the object's width on each side while approaching and releasing (m).
FINGER_MARGIN = 0.012
#: The palm sits 5.8 cm above the TCP: grasp tall objects this far below their top.
GRASP_BELOW_TOP = 0.045
#: Lowest TCP height above an object's bottom when grasping (the pads end 3 mm below it).
MIN_GRASP_HEIGHT = 0.012
#: Ball grasp: TCP this far below the ball's centre, the pads then span its equator.
BALL_GRASP_BELOW_CENTRE = 0.01
#: Release this far above the resting height (m).
PLACE_CLEARANCE = 0.004
TRANSIT_Z = 0.20

# --- Judge ----------------------------------------------------------------------------------

#: Allowed height error of the named object's resting height on the place (m).
HEIGHT_TOLERANCE = 0.01
#: Largest displacement of any other object (m).
MAX_DISPLACEMENT = 0.02

#: Salt for the scene sampler's random stream.
_SEED_SALT = 11


# --- Object models --------------------------------------------------------------------------

def _sample_movable(rng: np.random.Generator, category: str, colour: str) -> dict:
    """A movable object's shape parameters (m), resting height of its body origin above the
    surface it stands on, footprint radius, and the TCP height above its bottom for a grasp."""
    if category == "cube":
        half = rng.uniform(0.02, 0.025)
        shape = {"half": half, "height": 2 * half, "width": 2 * half, "rest_height": half,
                 "footprint": float(half * np.sqrt(2))}
    elif category == "ball":
        radius = rng.uniform(0.02, 0.025)
        shape = {"radius": radius, "height": 2 * radius, "width": 2 * radius,
                 "rest_height": radius, "footprint": radius}
    elif category == "cup":
        radius, height = rng.uniform(0.025, 0.03), rng.uniform(0.05, 0.06)
        handle = bool(rng.random() < 0.5)
        shape = {"radius": radius, "height": height, "width": 2 * radius, "handle": handle,
                 "rest_height": 0.0, "footprint": radius + handle * (HANDLE_REACH + HANDLE_RADIUS)}
    else:  # can
        radius, height = rng.uniform(0.02, 0.024), rng.uniform(0.055, 0.065)
        shape = {"radius": radius, "height": height, "width": 2 * radius,
                 "rest_height": height / 2, "footprint": radius}
    if category == "ball":
        grasp_height = shape["radius"] - BALL_GRASP_BELOW_CENTRE
    else:
        grasp_height = max(MIN_GRASP_HEIGHT, shape["height"] - GRASP_BELOW_TOP)
    noun = MUG_NOUN if shape.get("handle") else MOVABLE_NOUNS[category]
    return {"category": category, "colour": colour, "name": f"{colour} {noun}",
            "body": f"{category}_{colour}", "grasp_height": float(grasp_height), **shape}


def _sample_place(rng: np.random.Generator, kind: str, colour: str) -> dict:
    """A place's shape parameters (m): surface height above the table, outline half sizes
    (box, paper) or radius (plate), and the bounding radius used for layout."""
    if kind == "box":
        inner = rng.uniform(0.055, 0.065)
        outer = inner + BOX_WALL_THICKNESS
        shape = {"inner_half": inner, "wall_height": rng.uniform(0.03, 0.04),
                 "half_size": [outer, outer], "surface": BOX_FLOOR_THICKNESS}
    elif kind == "paper":
        shape = {"half_size": list(PAPER_HALF_SIZE), "surface": PAPER_THICKNESS}
    else:
        shape = {"radius": rng.uniform(0.06, 0.07), "surface": PLATE_THICKNESS}
    bound = float(np.hypot(*shape["half_size"])) if "half_size" in shape else shape["radius"]
    name = "paper" if kind == "paper" else f"{colour} {kind}"
    return {"category": kind, "colour": colour, "name": name,
            "body": kind if kind == "paper" else f"{kind}_{colour}", "bound": bound, **shape}


def _body(obj: dict, geoms: str) -> str:
    """A free body at the object's sampled pose (origin at its resting height)."""
    quat = geometry.from_rotation(geometry.Rotation.from_euler("z", obj["yaw"]))
    position = (*obj["xy"], obj.get("rest_height", 0.0))
    return (f'<body name="{obj["body"]}" pos="{fmt(position)}" quat="{fmt(quat)}"><freejoint/>'
            f'{geoms}</body>')


def _geom(kind: str, size, colour: str, mass: float, pos=(0, 0, 0), yaw: float = 0.0,
          friction: str = FRICTION, condim: int = 4) -> str:
    quat = geometry.from_rotation(geometry.Rotation.from_euler("z", yaw))
    return (f'<geom type="{kind}" size="{fmt(size)}" pos="{fmt(pos)}" quat="{fmt(quat)}" '
            f'rgba="{rgba(colour)}" mass="{mass:.4f}" friction="{friction}" condim="{condim}"/>')


def _cup_geoms(obj: dict) -> str:
    """A disc with a ring of flat walls on it (origin at the bottom centre), and a handle
    along the cup's +x when it is a mug; the fingers then close on the walls facing +-y."""
    radius, height, colour = obj["radius"], obj["height"], obj["colour"]
    wall_mass = MASS["cup"] / (CUP_WALLS + 1)
    wall_half_height = (height - CUP_BASE_THICKNESS) / 2
    wall = (CUP_WALL_THICKNESS / 2, radius * np.tan(np.pi / CUP_WALLS), wall_half_height)
    parts = [_geom("cylinder", (radius, CUP_BASE_THICKNESS / 2), colour, wall_mass,
                   pos=(0, 0, CUP_BASE_THICKNESS / 2))]
    for k in range(CUP_WALLS):
        angle = 2 * np.pi * k / CUP_WALLS
        centre = radius - CUP_WALL_THICKNESS / 2
        parts.append(_geom("box", wall, colour, wall_mass, yaw=angle,
                           pos=(centre * np.cos(angle), centre * np.sin(angle),
                                CUP_BASE_THICKNESS + wall_half_height)))
    if obj["handle"]:
        low, high = CUP_BASE_THICKNESS + 0.25 * height, 0.85 * height
        bar = radius + HANDLE_REACH
        for start, end in (((radius, 0, low), (bar, 0, low)), ((bar, 0, low), (bar, 0, high)),
                           ((radius, 0, high), (bar, 0, high))):
            parts.append(f'<geom type="capsule" fromto="{fmt(start)} {fmt(end)}" '
                         f'size="{HANDLE_RADIUS}" rgba="{rgba(colour)}" mass="{HANDLE_MASS}" condim="4"/>')
    return "".join(parts)


def _box_geoms(place: dict) -> str:
    """An open tray (origin at the bottom centre): a floor, and four walls standing on it so
    that only the floor touches the table (fewer contacts to solve)."""
    inner, colour = place["inner_half"], place["colour"]
    outer = inner + BOX_WALL_THICKNESS
    wall_half_height = (place["wall_height"] - BOX_FLOOR_THICKNESS) / 2
    mass = MASS["box"] / 5
    parts = [_geom("box", (outer, outer, BOX_FLOOR_THICKNESS / 2), colour, mass,
                   pos=(0, 0, BOX_FLOOR_THICKNESS / 2))]
    wall_centre = inner + BOX_WALL_THICKNESS / 2
    for k in range(4):
        angle = k * np.pi / 2
        parts.append(_geom("box", (BOX_WALL_THICKNESS / 2, outer, wall_half_height), colour, mass,
                           yaw=angle, pos=(wall_centre * np.cos(angle), wall_centre * np.sin(angle),
                                           BOX_FLOOR_THICKNESS + wall_half_height)))
    return "".join(parts)


def _object_xml(obj: dict) -> str:
    category, colour, mass = obj["category"], obj["colour"], MASS[obj["category"]]
    if category == "cube":
        half = obj["half"]
        return box_body(obj["body"], (*obj["xy"], half), obj["yaw"], (half, half, half), colour, mass)
    if category == "ball":
        return _body(obj, _geom("sphere", (obj["radius"],), colour, mass, friction=BALL_FRICTION, condim=6))
    if category == "can":
        return _body(obj, _geom("cylinder", (obj["radius"], obj["height"] / 2), colour, mass))
    if category == "cup":
        return _body(obj, _cup_geoms(obj))
    if category == "box":
        return _body(obj, _box_geoms(obj))
    if category == "paper":
        return _body(obj, _geom("box", (*PAPER_HALF_SIZE, PAPER_THICKNESS / 2), colour, mass,
                                pos=(0, 0, PAPER_THICKNESS / 2)))
    # plate
    return _body(obj, _geom("cylinder", (obj["radius"], PLATE_THICKNESS / 2), colour, mass,
                            pos=(0, 0, PLATE_THICKNESS / 2)))


# --- Layout ---------------------------------------------------------------------------------

def _in_place_frame(place: dict, xy) -> np.ndarray:
    """`xy` (world, m) in the frame of a place centred at place["xy"] turned by place["yaw"]."""
    c, s = np.cos(place["yaw"]), np.sin(place["yaw"])
    d = np.asarray(xy, float) - np.asarray(place["xy"], float)
    return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])


def _distance_to_place(place: dict, xy) -> float:
    """Distance (m) from `xy` to the place's outline (0 inside it)."""
    local = _in_place_frame(place, xy)
    if "half_size" in place:
        return float(np.linalg.norm(np.maximum(np.abs(local) - place["half_size"], 0.0)))
    return max(float(np.linalg.norm(local)) - place["radius"], 0.0)


def _fits(obj: dict, placed: list[dict]) -> bool:
    """Whether `obj` keeps its distance from everything laid out before it (places are laid
    out first, so a place only ever meets other places)."""
    for other in placed:
        centres = float(np.linalg.norm(np.subtract(obj["xy"], other["xy"])))
        if "bound" in obj:
            slack = centres - obj["bound"] - other["bound"] - PLACE_GAP
        elif "bound" in other:
            slack = _distance_to_place(other, obj["xy"]) - obj["footprint"] - CLEARANCE
        else:
            slack = centres - obj["footprint"] - other["footprint"] - CLEARANCE
        if slack < 0:
            return False
    return True


def _lay_out(rng: np.random.Generator, places: list[dict], movables: list[dict]) -> None:
    """Samples positions and yaws in place, places first, each object by rejection against
    those already laid out; starts over when one does not fit."""
    for _ in range(LAYOUT_ATTEMPTS):
        placed: list[dict] = []
        for obj, area in [(p, PLACE_AREA) for p in places] + [(m, MOVABLE_AREA) for m in movables]:
            half_range = YAW_HALF_RANGE.get(obj["category"], np.pi)
            for _ in range(TRIES_PER_OBJECT):
                obj["xy"] = rng.uniform(*area).tolist()
                obj["yaw"] = float(rng.uniform(-half_range, half_range))
                if _fits(obj, placed):
                    placed.append(obj)
                    break
            else:
                break
        else:
            return
    raise RuntimeError("could not lay out the scene; the table is too crowded")


# --- Scene ----------------------------------------------------------------------------------

def is_heldout_combination(category: str, colour: str) -> bool:
    return colour in HELDOUT_COLOURS[category]


def make_scene(seed: int) -> Scene:
    rng = np.random.default_rng([seed, _SEED_SALT])
    heldout = seed in HELDOUT_SEEDS
    count = int(rng.integers(OBJECT_COUNT[0], OBJECT_COUNT[1] + 1))

    place_kinds = list(PLACE_COLOURS)
    target_kind = str(rng.choice(place_kinds))
    place_keys = [(target_kind, str(rng.choice(PLACE_COLOURS[target_kind])))]
    if count >= 4 and rng.random() < SECOND_PLACE_CHANCE:
        options = [(k, c) for k in place_kinds for c in PLACE_COLOURS[k]
                   if (k, c) != place_keys[0] and not (k == "paper" == target_kind)]
        place_keys.append(options[rng.integers(len(options))])

    categories = list(MOVABLE_NOUNS)
    target_category = str(rng.choice(categories))
    target_colours = (HELDOUT_COLOURS if heldout else TRAINING_COLOURS)[target_category]
    movable_keys = [(target_category, str(rng.choice(target_colours)))]
    # Distractors: any distinct combination in held-out scenes; training scenes never show a
    # held-out combination.
    options = [(k, c) for k in categories for c in COLOURS
               if (k, c) != movable_keys[0] and (heldout or not is_heldout_combination(k, c))]
    for index in rng.choice(len(options), size=count - len(place_keys) - 1, replace=False):
        movable_keys.append(options[index])

    places = [_sample_place(rng, *key) for key in place_keys]
    movables = [_sample_movable(rng, *key) for key in movable_keys]
    _lay_out(rng, places, movables)

    ordered = [movables[0], places[0]] + movables[1:] + places[1:]
    target, place = ordered[0], ordered[1]
    templates = PROMPT_TEMPLATES[place["category"]]
    template = templates[rng.integers(len(templates))]
    prompt = template.format(object=target["name"], place=place["name"])
    xml = "\n    ".join(_object_xml(obj) for obj in ordered)
    welds = "".join(engine.weld_xml(obj["body"]) for obj in movables)
    params = {"objects": ordered, "heldout": heldout}
    return Scene("language_pick_place", seed, scene_xml(xml, extra_equality=welds),
                 [obj["name"] for obj in ordered], [[obj["body"]] for obj in ordered],
                 prompt, params, weld_grasp=True)


# --- Expert ---------------------------------------------------------------------------------

def expert(scene: Scene) -> dict:
    target, place = scene.params["objects"][:2]
    # A cube is gripped on opposite faces; a cup on the walls across its handle axis; balls
    # and cans are round, so the same rule just varies the yaw.
    symmetry = np.pi / 2 if target["category"] == "cube" else np.pi
    yaw = grasp_yaw(target["yaw"], symmetry)
    opening = min(1.0, (target["width"] / 2 + FINGER_MARGIN) / FINGER_TRAVEL)
    pick = (*target["xy"], target["grasp_height"])
    drop = (*place["xy"], place["surface"] + target["grasp_height"] + PLACE_CLEARANCE)
    return expert_path(pick_and_place(pick, yaw, drop, yaw, TRANSIT_Z, grip_opening=opening))


# --- Judge ----------------------------------------------------------------------------------

def _placement_error(place: dict, place_position, place_quat, obj: dict, obj_position) -> str | None:
    """Why `obj` (final origin at `obj_position`) is not resting in/on `place` (final pose),
    or None when it is."""
    moved_place = dict(place, xy=list(place_position[:2]), yaw=geometry.yaw_of(place_quat))
    local = _in_place_frame(moved_place, obj_position[:2])
    if place["category"] == "box":
        inside = bool(np.all(np.abs(local) <= place["inner_half"]))
    elif place["category"] == "paper":
        inside = bool(np.all(np.abs(local) <= place["half_size"]))
    else:
        inside = float(np.linalg.norm(local)) <= place["radius"]
    height = obj_position[2] - obj["rest_height"] - (place_position[2] + place["surface"])
    if inside and abs(height) <= HEIGHT_TOLERANCE:
        return None
    return (f"{obj['name']} is not {PLACE_PREPOSITION[place['category']]} the {place['name']} "
            f"(centre at {local[0]:+.3f}, {local[1]:+.3f} m in its frame, "
            f"{height:+.3f} m above its surface)")


def judge(scene: Scene, log) -> Verdict:
    objects = scene.params["objects"]
    target, place = objects[:2]
    names = scene.objects
    reasons, metrics = [], {}
    error = _placement_error(place, log.final_position[place["name"]], log.final_quat[place["name"]],
                             target, log.final_position[target["name"]])
    if error:
        reasons.append(error)
    for name in names[1:]:
        moved = float(np.linalg.norm(log.final_position[name] - log.object_position[name][0]))
        metrics[f"{name} displacement_m"] = moved
        if moved > MAX_DISPLACEMENT:
            reasons.append(f"{name} was displaced by {moved:.3f} m (limit {MAX_DISPLACEMENT} m)")
    reasons += released_and_at_rest(scene, log, names)
    return Verdict(not reasons, reasons, metrics)


TASK = Task("language_pick_place", __doc__.split("\n\n")[0], make_scene, expert, judge)
