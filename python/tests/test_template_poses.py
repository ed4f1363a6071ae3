"""scripts/template-poses.py: the template pose it reads off a latent, the scene parameters
it shows next to it, and its refusal of held-out seeds and of models without full turns."""

import os
import subprocess
import sys

import pytest
import torch

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SCRIPT = os.path.join(ROOT, "scripts", "template-poses.py")


@pytest.fixture(scope="module")
def script(load_script):
    return load_script("template-poses")


@pytest.fixture(scope="module")
def incline(tmp_path_factory) -> str:
    """An untrained incline model with full turns and two demonstrations (the shipped one
    has no full turns): the script reads the training latents' template poses off it."""
    from cnfmp.core import models
    from cnfmp.core.configuration_cnfmp import CnfmpConfig
    from cnfmp.core.modeling_cnfmp import CnfmpModel

    config = CnfmpConfig(task="incline_pick_place", num_objects=2, object_names=["block", "ramp"],
                         slot_can_be_absent=[False, False], duration_s=1.0, full_turns=True, tool_axis_object=-1,
                         observed_statistics="shading",
                         field_resolution=16, latent_dim=4, field_width=16, field_layers=2)
    torch.manual_seed(0)
    out = tmp_path_factory.mktemp("incline")
    models.save_model(CnfmpModel(config, num_demos=2), str(out))
    return str(out)


def test_the_pose_is_the_turn_and_scale_of_the_similarity(script):
    from cnfmp.core.configuration_cnfmp import CnfmpConfig
    from cnfmp.core.modeling_cnfmp import ObjectField

    field = ObjectField(CnfmpConfig(latent_dim=2, full_turns=True))
    with torch.no_grad():  # (u, v, a, b) = (z0 - 1, z1, 0, 0): the similarity [[z0, -z1], [z1, z0]]
        field.linear.weight.copy_(torch.tensor([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0], [0.0, 0.0]]))
        field.linear.bias.copy_(torch.tensor([-1.0, 0.0, 0.0, 0.0]))
    turn, scale, stretch_a, stretch_b = script.template_pose(field, torch.tensor([0.0, 2.0]))
    assert turn == pytest.approx(90.0) and scale == pytest.approx(2.0)
    assert stretch_a == stretch_b == 0.0
    turn, scale, _, _ = script.template_pose(field, torch.tensor([-1.0, -1.0]))
    assert turn == pytest.approx(-135.0) and scale == pytest.approx(2 ** 0.5)


def test_scene_parameters_are_shown_in_degrees(script):
    line = script.scene_summary("incline_pick_place", 1)
    assert "slope " in line and "plate_yaw " in line
    slope = float(line.split("slope ")[1].split(",")[0])
    assert 10.0 <= slope <= 35.0  # the task's slope range, in degrees


def test_training_scenes_print_one_line_each(incline):
    run = subprocess.run([sys.executable, SCRIPT, "--model", incline, "--slot", "2", "--scenes", "2"],
                         capture_output=True, text=True, check=True)
    lines = run.stdout.strip().splitlines()
    assert [line.split(":")[0] for line in lines] == ["seed 0", "seed 1"]
    assert all("turn" in line and "plate_yaw" in line for line in lines)


@pytest.mark.parametrize("args, message", [
    (["--slot", "2", "--validation", "--seed-start", "999999", "--scenes", "2"], "held-out"),
    (["--slot", "3"], "--slot must be in 1..2"),
    (["--model", os.path.join(ROOT, "models", "cup_stacking"), "--slot", "1"], "full_turns"),
])
def test_bad_requests_are_refused(args, message, incline):
    model = [] if "--model" in args else ["--model", incline]
    run = subprocess.run([sys.executable, SCRIPT, *model, *args], capture_output=True, text=True)
    assert run.returncode == 2
    assert message in run.stderr and "Traceback" not in run.stderr
