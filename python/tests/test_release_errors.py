"""scripts/release-errors.py: the release frames it compares at, its per-scene errors on a
shipped model's own training scene, and its refusal of held-out seeds."""

import os
import subprocess
import sys

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SCRIPT = os.path.join(ROOT, "scripts", "release-errors.py")


@pytest.fixture(scope="module")
def script(load_script):
    return load_script("release-errors")


def test_release_frames_are_the_closed_to_open_crossings(script):
    gripper = np.array([0.7, 0.7, 0.0, 0.0, 0.7, 0.7, 0.0, 0.8, 0.8])
    assert script.release_frames(gripper) == [4, 7]
    assert script.release_frames(np.zeros(5)) == []


def test_a_training_scene_of_the_shipped_cube_model_releases_where_the_expert_does(script):
    from cnfmp.sim import api as sim

    row = script.scene_errors(os.path.join(ROOT, "models", "cube_stacking"), "cube_stacking", 0)
    releases = len(script.release_frames(sim.expert("cube_stacking", 0)["gripper"]))
    assert releases >= 1
    assert len(row["xy_cm"]) == len(row["z_cm"]) == len(row["axis_deg"]) == releases
    # Its own demonstration: the model places within a few centimetres and degrees.
    assert max(row["xy_cm"]) < 3.0 and max(row["axis_deg"]) < 30.0
    summary = script.summary([row])
    assert summary["scenes"] == 1 and summary["success"] in (0.0, 1.0)
    assert summary["xy_cm"]["mean"] == pytest.approx(np.mean(row["xy_cm"]), abs=0.01)


def test_held_out_seeds_are_refused():
    run = subprocess.run([sys.executable, SCRIPT, "--model", os.path.join(ROOT, "models", "cube_stacking"),
                          "--seed-start", "999999", "--scenes", "2"], capture_output=True, text=True)
    assert run.returncode == 2
    assert "held-out" in run.stderr and "Traceback" not in run.stderr
