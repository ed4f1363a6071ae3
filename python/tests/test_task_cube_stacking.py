"""cube_stacking: the expert succeeds, the scene is a function of the seed, bad stacks fail."""

import numpy as np
import pytest

from cnfmp.sim import engine
from cnfmp.sim.scene import CONTROL_HZ
from cnfmp.sim.tasks import cube_stacking

SEEDS = [1_000_000, 1_000_001, 1_000_002]


def run(scene, trajectory):
    return engine.run_episode(scene, trajectory, cube_stacking.judge)


@pytest.mark.parametrize("seed", SEEDS)
def test_expert_stacks_the_tower(seed):
    scene = cube_stacking.make_scene(seed)
    verdict = run(scene, cube_stacking.expert(scene))
    assert verdict.success, verdict.reasons
    for pair in verdict.metrics.values():
        assert pair["lateral_m"] < 0.01


def test_scene_is_a_function_of_the_seed():
    a, b, c = (cube_stacking.make_scene(s) for s in (7, 7, 8))
    assert (a.xml, a.prompt, a.objects) == (b.xml, b.prompt, b.objects)
    assert a.xml != c.xml


def test_a_4cm_place_offset_fails():
    scene = cube_stacking.make_scene(SEEDS[0])
    trajectory = cube_stacking.expert(scene)
    # Shift everything after the first grasp closes by 4 cm in x: the second cube lands
    # beside the base.
    first_close = int(np.argmax(trajectory["gripper"] < 0.5))
    trajectory["position"][first_close + CONTROL_HZ:, 0] += 0.04
    verdict = run(scene, trajectory)
    assert not verdict.success
    assert any("is not stacked on" in reason for reason in verdict.reasons), verdict.reasons


def test_releasing_early_fails():
    scene = cube_stacking.make_scene(SEEDS[1])
    trajectory = cube_stacking.expert(scene)
    closed = np.nonzero(trajectory["gripper"] < 0.5)[0]
    # Open during the first transit, 1.5 s after the first grasp closed.
    trajectory["gripper"][closed[0] + int(1.5 * CONTROL_HZ):] = 1.0
    verdict = run(scene, trajectory)
    assert not verdict.success
    assert any("is not stacked on" in reason for reason in verdict.reasons), verdict.reasons


def test_moving_the_wrong_object_fails():
    scene = cube_stacking.make_scene(SEEDS[2])
    xy = np.array(scene.params["xy"])
    # Swap the base and the second cube: the expert builds the tower in the wrong order.
    scene.params["xy"] = [xy[1].tolist(), xy[0].tolist(), xy[2].tolist()]
    scene.params["yaw"] = [scene.params["yaw"][1], scene.params["yaw"][0], scene.params["yaw"][2]]
    verdict = run(cube_stacking.make_scene(SEEDS[2]), cube_stacking.expert(scene))
    assert not verdict.success
    assert any("not on the table" in r or "is not stacked on" in r for r in verdict.reasons), verdict.reasons


def test_doing_nothing_fails():
    scene = cube_stacking.make_scene(SEEDS[0])
    still = {k: v[:1].repeat(50, axis=0) for k, v in cube_stacking.expert(scene).items()}
    verdict = run(scene, still)
    assert not verdict.success
