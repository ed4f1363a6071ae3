"""cup_stacking: the expert nests the cups, the scene is a function of the seed, bad nesting
fails."""

import numpy as np
import pytest

from cnfmp.sim import engine
from cnfmp.sim.scene import CONTROL_HZ
from cnfmp.sim.tasks import cup_stacking

SEEDS = [1_000_000, 1_000_001, 1_000_002]
#: Held-out seeds with two cups, for the bad trajectories that act on the only placement.
TWO_CUP_SEEDS = [1_000_001, 1_000_003]


def run(scene, trajectory):
    return engine.run_episode(scene, trajectory, cup_stacking.judge)


def grasp_step(trajectory) -> int:
    """The first control step at which the fingers are commanded closed on a cup."""
    return int(np.argmax(trajectory["gripper"] < 0.5))


@pytest.mark.parametrize("seed", SEEDS)
def test_expert_nests_the_cups(seed):
    scene = cup_stacking.make_scene(seed)
    verdict = run(scene, cup_stacking.expert(scene))
    assert verdict.success, verdict.reasons
    pairs = verdict.metrics["nesting"]
    assert len(pairs) == len(scene.objects) - 1
    for pair in pairs.values():
        assert pair["lateral_m"] < 0.005
        assert 0.0 < pair["base_rise_m"] < 0.01


def test_scene_is_a_function_of_the_seed():
    a, b, c = (cup_stacking.make_scene(s) for s in (7, 7, 8))
    assert (a.xml, a.prompt, a.objects) == (b.xml, b.prompt, b.objects)
    assert a.xml != c.xml
    counts = {len(cup_stacking.make_scene(s).objects) for s in range(1_000_000, 1_000_010)}
    assert counts == {2, 3}


def test_scene_sizes_cups_to_nest_with_clearance():
    scene = cup_stacking.make_scene(SEEDS[0])
    radii, clearances = scene.params["radius"], scene.params["clearance"]
    for outer, inner, clearance in zip(radii, radii[1:], clearances):
        gap = outer - cup_stacking.WALL_THICKNESS - cup_stacking.circumradius(inner)
        assert gap == pytest.approx(clearance)
        assert 0.008 < gap < 0.013


@pytest.mark.parametrize("seed", TWO_CUP_SEEDS)
def test_a_4cm_place_offset_fails(seed):
    scene = cup_stacking.make_scene(seed)
    trajectory = cup_stacking.expert(scene)
    # From 1 s after the grasp on, aim 4 cm off in x: the cup comes down on the outer rim.
    trajectory["position"][grasp_step(trajectory) + CONTROL_HZ:, 0] += 0.04
    verdict = run(scene, trajectory)
    assert not verdict.success
    missed = [r for r in verdict.reasons if "is not nested in" in r or "not upright" in r]
    assert missed, verdict.reasons


def test_releasing_in_transit_fails():
    scene = cup_stacking.make_scene(SEEDS[1])
    trajectory = cup_stacking.expert(scene)
    # Open 1.5 s after the grasp, while carrying the cup high over the table.
    trajectory["gripper"][grasp_step(trajectory) + int(1.5 * CONTROL_HZ):] = 1.0
    verdict = run(scene, trajectory)
    assert not verdict.success
    assert any("is not nested in" in reason for reason in verdict.reasons), verdict.reasons


def test_putting_the_big_cup_into_the_small_one_fails():
    scene = cup_stacking.make_scene(SEEDS[0])
    swapped = cup_stacking.make_scene(SEEDS[0])
    # The expert of a scene whose first two cups trade places picks the outer cup and
    # places it on the second one.
    for key in ("xy", "radius", "height"):
        values = swapped.params[key]
        values[0], values[1] = values[1], values[0]
    verdict = run(scene, cup_stacking.expert(swapped))
    assert not verdict.success
    first, second = scene.objects[:2]
    assert any(f"{second} is not nested in {first}" in r for r in verdict.reasons), verdict.reasons


def test_doing_nothing_fails():
    scene = cup_stacking.make_scene(SEEDS[0])
    still = {k: v[:1].repeat(50, axis=0) for k, v in cup_stacking.expert(scene).items()}
    verdict = run(scene, still)
    assert not verdict.success
    assert any("is not nested in" in reason for reason in verdict.reasons), verdict.reasons
