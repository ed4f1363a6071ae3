"""wall_avoidance: the expert reaches the goal untouched, the scene is a function of the seed
and keeps the goal in view, paths through the wall or to the wrong place fail."""

import numpy as np
import pytest

from cnfmp.sim import engine
from cnfmp.sim.tasks import wall_avoidance

SEEDS = [1_000_000, 1_000_001, 1_000_002]


def run(scene, trajectory):
    return engine.run_episode(scene, trajectory, wall_avoidance.judge)


@pytest.mark.parametrize("seed", SEEDS)
def test_expert_reaches_the_goal_without_touching_the_wall(seed):
    scene = wall_avoidance.make_scene(seed)
    verdict = run(scene, wall_avoidance.expert(scene))
    assert verdict.success, verdict.reasons
    assert verdict.metrics["goal_distance_m"] < 0.005


def test_scene_is_a_function_of_the_seed():
    a, b, c = (wall_avoidance.make_scene(s) for s in (7, 7, 8))
    assert (a.xml, a.prompt, a.params) == (b.xml, b.prompt, b.params)
    assert a.xml != c.xml


def test_the_goal_marker_is_visible_behind_the_tallest_walls():
    scenes = [wall_avoidance.make_scene(seed) for seed in range(1_000_000, 1_000_040)]
    tallest = sorted(scenes, key=lambda s: s.params["wall_height"])[-2:]
    for scene in tallest:
        sim = engine.Simulation(scene)
        try:
            _, labels = sim.render_scene()
        finally:
            sim.close()
        wall_label, goal_label = 1, 2
        assert (labels == wall_label).sum() > 1000
        # The whole 6 cm disc shows: about 70 pixels (a partly hidden one shows far fewer).
        assert (labels == goal_label).sum() > 50, scene.params


@pytest.mark.parametrize("seed", SEEDS[:2])
def test_a_path_below_the_wall_top_fails_on_contact(seed):
    scene = wall_avoidance.make_scene(seed)
    trajectory = wall_avoidance.expert(scene)
    below_top = scene.params["wall_height"] - 0.03
    trajectory["position"][:, 2] = np.minimum(trajectory["position"][:, 2], below_top)
    verdict = run(scene, trajectory)
    assert not verdict.success
    assert "the gripper touched the wall" in verdict.reasons, verdict.reasons


def test_grazing_the_wall_top_fails():
    scene = wall_avoidance.make_scene(SEEDS[2])
    trajectory = wall_avoidance.expert(scene)
    # TCP 3 mm above the top: the fingertips, 3 mm below the TCP, just reach it.
    skimming = scene.params["wall_height"] + 0.003
    trajectory["position"][:, 2] = np.minimum(trajectory["position"][:, 2], skimming)
    verdict = run(scene, trajectory)
    assert not verdict.success
    assert "the gripper touched the wall" in verdict.reasons, verdict.reasons


@pytest.mark.parametrize("seed", SEEDS[:2])
def test_a_4cm_goal_offset_fails_on_distance(seed):
    scene = wall_avoidance.make_scene(seed)
    trajectory = wall_avoidance.expert(scene)
    # Drift 4 cm along the wall (x) over the whole path: the wall is still cleared.
    steps = len(trajectory["position"])
    trajectory["position"][:, 0] += np.linspace(0.0, 0.04, steps)
    verdict = run(scene, trajectory)
    assert not verdict.success
    assert len(verdict.reasons) == 1 and "m from the goal" in verdict.reasons[0], verdict.reasons
    assert verdict.metrics["goal_distance_m"] == pytest.approx(0.04, abs=0.005)


@pytest.mark.parametrize("seed", SEEDS)
def test_the_straight_line_to_the_goal_hits_the_wall(seed):
    scene = wall_avoidance.make_scene(seed)
    expert = wall_avoidance.expert(scene)
    # Same start, end and timing as the expert, but straight from start to goal.
    s = np.linspace(0.0, 1.0, len(expert["position"]))[:, None]
    straight = dict(expert, position=(1 - s) * expert["position"][0] + s * expert["position"][-1])
    verdict = run(scene, straight)
    assert not verdict.success
    assert "the gripper touched the wall" in verdict.reasons, verdict.reasons
