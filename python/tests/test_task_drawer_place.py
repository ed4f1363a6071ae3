"""drawer_place: the expert succeeds, the scene is a function of the seed, and trajectories
planned for another opening, never released or lowered onto the cabinet fail with their
reason."""

import numpy as np
import pytest

from cnfmp.sim import engine
from cnfmp.sim.scene import CONTROL_HZ
from cnfmp.sim.tasks import drawer_place

SEEDS = [1_000_000, 1_000_001, 1_000_002]


def run(scene, trajectory):
    return engine.run_episode(scene, trajectory, drawer_place.judge)


def closed_span(trajectory) -> np.ndarray:
    return np.nonzero(trajectory["gripper"] < 0.5)[0]


@pytest.mark.parametrize("seed", SEEDS)
def test_the_expert_places_the_carton_in_the_drawer(seed):
    scene = drawer_place.make_scene(seed)
    verdict = run(scene, drawer_place.expert(scene))
    assert verdict.success, verdict.reasons
    assert abs(verdict.metrics["drawer_moved_m"]) < 0.005
    assert verdict.metrics["tilt_deg"] < 5 and abs(verdict.metrics["height_above_floor_m"]) < 0.005


def test_the_scene_is_a_function_of_the_seed_and_the_opening_varies():
    a, b, c = (drawer_place.make_scene(s) for s in (7, 7, 8))
    assert (a.xml, a.prompt, a.objects) == (b.xml, b.prompt, b.objects)
    assert a.xml != c.xml
    openings = [drawer_place.make_scene(s).params["opening"] for s in range(50)]
    assert drawer_place.OPENING_RANGE[0] <= min(openings) < 0.11 and 0.15 < max(openings) <= drawer_place.OPENING_RANGE[1]


def test_the_scene_starts_with_the_drawer_at_its_opening():
    from cnfmp.sim.engine import Simulation

    scene = drawer_place.make_scene(SEEDS[0])
    sim = Simulation(scene)
    try:
        y = sim.data.body("drawer").xpos[1]
    finally:
        sim.close()
    assert y == pytest.approx(drawer_place.CABINET_FRONT_Y - scene.params["opening"], abs=1e-6)  # the MJCF keeps 6 decimals


def test_a_plan_for_a_wider_opening_lowers_the_carton_onto_the_drawer_front():
    scene = drawer_place.make_scene(SEEDS[0])
    planned = drawer_place.make_scene(SEEDS[0])
    planned.params = dict(scene.params, opening=scene.params["opening"] + 0.09)
    verdict = run(scene, drawer_place.expert(planned))
    assert not verdict.success
    signs = ("not inside the drawer", "not on the drawer's floor", "not upright", "the drawer was")
    assert any(sign in r for r in verdict.reasons for sign in signs), verdict.reasons


def test_a_plan_for_a_wider_opening_lowers_the_carton_onto_the_cabinet():
    scene = drawer_place.make_scene(SEEDS[1])
    planned = drawer_place.make_scene(SEEDS[1])
    planned.params = dict(scene.params, opening=scene.params["opening"] - 0.12)  # under the cabinet's shelf
    verdict = run(scene, drawer_place.expert(planned))
    assert not verdict.success
    assert any("touched the cabinet" in r for r in verdict.reasons), verdict.reasons


def test_never_releasing_fails():
    scene = drawer_place.make_scene(SEEDS[2])
    trajectory = drawer_place.expert(scene)
    closed = closed_span(trajectory)
    trajectory["gripper"][closed[0]:] = 0.0
    verdict = run(scene, trajectory)
    assert not verdict.success
    assert any("not released" in r for r in verdict.reasons), verdict.reasons


def test_pulling_the_drawer_fails():
    scene = drawer_place.make_scene(SEEDS[0])
    trajectory = drawer_place.expert(scene)
    # After the release, hook the drawer's front panel from inside and pull it 4 cm.
    end = len(trajectory["gripper"])
    front_y = drawer_place.CABINET_FRONT_Y - scene.params["opening"]
    x = scene.params["cabinet_x"] + 0.08
    hook = np.array([x, front_y + 0.02, 0.06])
    extra = 3 * CONTROL_HZ
    path = np.concatenate([np.linspace(trajectory["position"][-1], hook + [0, 0, 0.12], CONTROL_HZ),
                           np.linspace(hook + [0, 0, 0.12], hook, CONTROL_HZ),
                           np.linspace(hook, hook - [0, 0.06, 0], CONTROL_HZ)])
    trajectory = {"position": np.concatenate([trajectory["position"], path]),
                  "orientation": np.concatenate([trajectory["orientation"], np.repeat(trajectory["orientation"][-1:], extra, 0)]),
                  "gripper": np.concatenate([trajectory["gripper"], np.ones(extra)])}
    assert len(trajectory["position"]) == end + extra
    verdict = run(scene, trajectory)
    assert not verdict.success
    assert any("the drawer was pulled" in r for r in verdict.reasons), verdict.reasons
