"""incline_pick_place: the expert succeeds, the scene is a function of the seed, and misplaced,
dropped or untilted placements fail."""

import numpy as np
import pytest

from cnfmp.sim import engine
from cnfmp.sim.scene import CONTROL_HZ
from cnfmp.sim.tasks import incline_pick_place

SEEDS = [1_000_000, 1_000_001, 1_000_002]
#: A held-out scene whose plate is steep (32.9 deg), for the tilt test.
STEEP_SEED = 1_000_003


def run(scene, trajectory):
    return engine.run_episode(scene, trajectory, incline_pick_place.judge)


def grasp_closed_step(trajectory) -> int:
    return int(np.argmax(trajectory["gripper"] < 0.5))


@pytest.mark.parametrize("seed", SEEDS)
def test_expert_places_the_block_on_the_ramp(seed):
    scene = incline_pick_place.make_scene(seed)
    verdict = run(scene, incline_pick_place.expert(scene))
    assert verdict.success, verdict.reasons
    assert np.abs(verdict.metrics["block_in_plate_frame_m"][:2]).max() < 0.01
    assert verdict.metrics["tilt_error_deg"] < 2.0


def test_scene_is_a_function_of_the_seed():
    a, b, c = (incline_pick_place.make_scene(s) for s in (7, 7, 8))
    assert (a.xml, a.prompt, a.objects) == (b.xml, b.prompt, b.objects)
    assert a.xml != c.xml
    assert a.params["slope"] != c.params["slope"]


def test_placing_4cm_beyond_the_plate_edge_fails():
    scene = incline_pick_place.make_scene(SEEDS[0])
    trajectory = incline_pick_place.expert(scene)
    rotation, _ = incline_pick_place.plate_face(scene.params)
    # Once the block is lifted, shift the rest of the motion (gradually, over 1 s, so the grasp
    # holds) along the plate's level edge until the release point lies 4 cm past its side.
    offset = (incline_pick_place.PLATE_HALF[0] + 0.04) * rotation.apply([1.0, 0.0, 0.0])
    lifted = grasp_closed_step(trajectory) + CONTROL_HZ
    ramp = np.clip((np.arange(len(trajectory["position"])) - lifted) / CONTROL_HZ, 0.0, 1.0)
    trajectory["position"] += ramp[:, None] * offset
    verdict = run(scene, trajectory)
    assert not verdict.success
    assert any("is not over the grey ramp's face" in r for r in verdict.reasons), verdict.reasons
    assert verdict.metrics["block_in_plate_frame_m"][0] > incline_pick_place.PLATE_HALF[0]


def test_releasing_during_transit_fails():
    scene = incline_pick_place.make_scene(SEEDS[1])
    trajectory = incline_pick_place.expert(scene)
    # Open 1.5 s after the grasp closed: the block is high above the table, on its way.
    trajectory["gripper"][grasp_closed_step(trajectory) + int(1.5 * CONTROL_HZ):] = 1.0
    verdict = run(scene, trajectory)
    assert not verdict.success
    assert any("was dropped" in r for r in verdict.reasons), verdict.reasons


def test_placing_with_the_gripper_pointing_down_fails_on_a_steep_ramp():
    scene = incline_pick_place.make_scene(STEEP_SEED)
    assert np.degrees(scene.params["slope"]) >= 20.0
    trajectory = incline_pick_place.expert(scene)
    # Keep the grasp's downward orientation to the end, and lift the place by the amount the
    # untilted block's lower edge would otherwise dig into the slope.
    closed = grasp_closed_step(trajectory)
    trajectory["orientation"][closed:] = trajectory["orientation"][closed]
    corner_lift = 2 * incline_pick_place.BLOCK_HALF * np.sin(scene.params["slope"])
    trajectory["position"][closed + CONTROL_HZ:, 2] += corner_lift
    verdict = run(scene, trajectory)
    assert not verdict.success
    assert verdict.metrics["tilt_error_deg"] > 15.0
    assert any("gripper tilt at release" in r for r in verdict.reasons), verdict.reasons


def test_doing_nothing_fails():
    scene = incline_pick_place.make_scene(SEEDS[0])
    still = {k: v[:1].repeat(50, axis=0) for k, v in incline_pick_place.expert(scene).items()}
    verdict = run(scene, still)
    assert not verdict.success
    assert any("never released" in r for r in verdict.reasons), verdict.reasons
