"""language_pick_place: the expert succeeds, the scene is a function of the seed, the
held-out split holds, and misplacing, moving the wrong object or dropping early fail."""

import copy

import numpy as np
import pytest

from cnfmp.seeds import HELDOUT_SEEDS, TRAIN_SEEDS
from cnfmp.sim import engine
from cnfmp.sim.scene import CONTROL_HZ
from cnfmp.sim.tasks import language_pick_place as task

#: Held-out seeds whose named places are, in order, the paper, a box and a plate.
SEEDS = [1_000_000, 1_000_002, 1_000_003]


def run(scene, trajectory):
    return engine.run_episode(scene, trajectory, task.judge)


def expert_for_edited(scene, edit):
    """The expert's trajectory for a copy of `scene` whose params `edit` changed."""
    wrong = copy.deepcopy(scene)
    edit(wrong.params["objects"])
    return task.expert(wrong)


def misplaced(verdict, scene) -> bool:
    target, place = scene.objects[:2]
    return any(r.startswith((f"{target} is not in the {place}", f"{target} is not on the {place}"))
               for r in verdict.reasons)


def test_seeds_cover_every_place_kind():
    kinds = [task.make_scene(seed).params["objects"][1]["category"] for seed in SEEDS]
    assert kinds == ["paper", "box", "plate"]


@pytest.mark.parametrize("seed", SEEDS)
def test_expert_puts_the_object_in_place(seed):
    scene = task.make_scene(seed)
    verdict = run(scene, task.expert(scene))
    assert verdict.success, verdict.reasons
    assert max(verdict.metrics.values()) <= task.MAX_DISPLACEMENT


def test_scene_is_a_function_of_the_seed():
    a, b, c = (task.make_scene(s) for s in (7, 7, 8))
    assert (a.xml, a.prompt, a.objects, a.params) == (b.xml, b.prompt, b.objects, b.params)
    assert a.xml != c.xml


def test_prompt_names_the_first_two_objects_and_names_are_unique():
    for seed in range(40):
        scene = task.make_scene(seed)
        target, place = scene.objects[:2]
        assert target in scene.prompt and place in scene.prompt
        assert len(set(scene.objects)) == len(scene.objects)
        assert 3 <= len(scene.objects) <= 6


def test_heldout_seeds_name_only_heldout_combinations():
    for seed in HELDOUT_SEEDS[:200]:
        target = task.make_scene(seed).params["objects"][0]
        assert task.is_heldout_combination(target["category"], target["colour"]), (seed, target["name"])


def test_training_seeds_show_only_training_combinations():
    movable = set(task.MOVABLE_NOUNS)
    for seed in TRAIN_SEEDS[:200]:
        for obj in task.make_scene(seed).params["objects"]:
            if obj["category"] in movable:
                assert not task.is_heldout_combination(obj["category"], obj["colour"]), (seed, obj["name"])


def test_heldout_and_training_colours_split_every_category():
    for category, held_out in task.HELDOUT_COLOURS.items():
        assert set(held_out).isdisjoint(task.TRAINING_COLOURS[category])
        assert set(held_out) | set(task.TRAINING_COLOURS[category]) == set(task.COLOURS)


@pytest.mark.parametrize("seed", SEEDS)
def test_placing_beside_the_place_fails(seed):
    scene = task.make_scene(seed)
    place = scene.params["objects"][1]
    half_size = place["half_size"][0] if "half_size" in place else place["radius"]
    # Aim 1.5 half-sizes along the place's own x axis: past its edge, off the place.
    offset = 1.5 * half_size * np.array([np.cos(place["yaw"]), np.sin(place["yaw"])])

    def shift_place(objects):
        objects[1]["xy"] = (np.array(objects[1]["xy"]) + offset).tolist()

    verdict = run(scene, expert_for_edited(scene, shift_place))
    assert not verdict.success
    assert misplaced(verdict, scene), verdict.reasons


@pytest.mark.parametrize("seed", SEEDS[1:])
def test_moving_the_wrong_object_fails(seed):
    scene = task.make_scene(seed)
    distractor = scene.params["objects"][2]
    assert distractor["category"] in task.MOVABLE_NOUNS

    def pick_the_distractor(objects):
        objects[0] = objects[2]

    verdict = run(scene, expert_for_edited(scene, pick_the_distractor))
    assert not verdict.success
    assert misplaced(verdict, scene), verdict.reasons
    assert any(r.startswith(f"{distractor['name']} was displaced") for r in verdict.reasons), verdict.reasons


@pytest.mark.parametrize("seed", SEEDS[:2])
def test_releasing_early_fails(seed):
    scene = task.make_scene(seed)
    trajectory = task.expert(scene)
    closed = np.nonzero(trajectory["gripper"] < 0.5)[0]
    # Open 1.5 s after the grasp closed: during the lift, far from the place.
    trajectory["gripper"][closed[0] + int(1.5 * CONTROL_HZ):] = 1.0
    verdict = run(scene, trajectory)
    assert not verdict.success
    assert misplaced(verdict, scene), verdict.reasons


def test_doing_nothing_fails():
    scene = task.make_scene(SEEDS[0])
    still = {k: v[:1].repeat(50, axis=0) for k, v in task.expert(scene).items()}
    verdict = run(scene, still)
    assert not verdict.success
    assert misplaced(verdict, scene), verdict.reasons
