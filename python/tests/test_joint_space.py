"""Joint-space demonstrations: the simulator's arm (its kinematics), a dataset recorded in the
arm's joint angles, trained as recorded and predicted back in joint space, and executed by
the simulator through forward kinematics."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cnfmp import geometry
from cnfmp.core import api, data as core_data, training
from cnfmp.data import generate, lerobot_io, recorded
from cnfmp.errors import InputError
from cnfmp.images import encode_png
from cnfmp.sim import api as sim_api, arm


def test_inverse_kinematics_reaches_what_forward_kinematics_gives():
    kinematics = arm.Arm()
    rng = np.random.default_rng(0)
    angles = arm.REST_ANGLES + np.cumsum(rng.normal(0, 0.02, (40, 6)), axis=0)  # a smooth joint path
    positions, quats = kinematics.forward(angles)
    solved = kinematics.inverse(positions, quats)
    positions_again, quats_again = kinematics.forward(solved)
    assert np.abs(positions_again - positions).max() < 2 * arm.POSITION_TOLERANCE_M
    angle = (geometry.to_rotation(quats_again) * geometry.to_rotation(quats).inv()).magnitude()
    assert angle.max() < 2 * arm.ROTATION_TOLERANCE_RAD
    # Solved frame by frame from the previous solution: the arm moves continuously.
    assert np.abs(np.diff(solved, axis=0)).max() < 0.2
    with pytest.raises(InputError, match="cannot reach frame 1"):
        kinematics.inverse(np.array([positions[0], [0.0, 3.0, 0.5]]), quats[:2])
    with pytest.raises(InputError, match=r"shape \(T, 6\)"):
        kinematics.forward(np.zeros((3, 5)))


def test_joint_layouts_keep_the_recordings_order_and_units():
    names = ["gripper", "base.pos", "shoulder.pos", "elbow.pos"]
    layout = recorded.motion_layout("action", names)
    assert layout.rotation == recorded.JOINTS and layout.joints == (1, 2, 3) and layout.gripper == 0
    assert layout.joint_names == ["base.pos", "shoulder.pos", "elbow.pos"] and "3 joints" in layout.describe()
    values = np.array([[10.0, 0.1, 0.2, 0.3], [60.0, 0.4, 0.5, 0.6]])
    motion, scale = recorded.to_motion([values], layout)
    np.testing.assert_allclose(motion[0], [[0.1, 0.2, 0.3, 0.0], [0.4, 0.5, 0.6, 1.0]])
    back_names, back = recorded.from_motion(motion[0], layout, scale)
    assert back_names == names
    np.testing.assert_allclose(back, values)
    with pytest.raises(InputError, match="names two dimensions alike"):
        recorded.motion_layout("action", ["a.pos", "a", "gripper"])
    with pytest.raises(InputError, match="only a gripper"):
        recorded.motion_layout("action", ["gripper.pos"])


def test_the_simulator_rejects_joints_that_are_not_its_arms():
    with pytest.raises(InputError, match="not the simulator arm's"):
        sim_api.forward_kinematics(["a", "b", "c", "d", "e", "f"], 50.0, [0.0], np.zeros((1, 6)), [1.0])


@pytest.fixture(scope="module")
def joint_dataset(tmp_path_factory):
    out = str(tmp_path_factory.mktemp("joints") / "wall_joints")
    report = json.loads(generate.generate_dataset("wall_avoidance", 2, 60, out, workers=1, progress=False,
                                                  joint_space=True))
    return out, report


def test_a_joint_space_recording_is_the_experts_motion_through_the_arm(joint_dataset):
    out, report = joint_dataset
    seed = report["seeds"][0]
    inspection = json.loads(lerobot_io.inspect(out))
    assert inspection["joint_names"] == list(arm.JOINT_NAMES)
    demos = core_data.load_demonstrations(out)
    joints = demos.trajectories[0]
    assert joints.shape[1] == len(arm.JOINT_NAMES) + 1
    # Forward kinematics of the recorded angles is the pose the same expert run records (the
    # trajectory: the first measured state, then the commanded actions).
    pose_episode = generate.simulate_episode("wall_avoidance", seed)
    expected = np.concatenate([pose_episode["state"][:1, :3], pose_episode["action"][:, :3]])
    positions, _ = arm.Arm().forward(joints[:, :-1])
    assert positions.shape == expected.shape and np.abs(positions - expected).max() < 1e-3


def test_a_joint_space_model_predicts_joints_the_simulator_executes(joint_dataset, tmp_path):
    out, _ = joint_dataset
    shorter = tmp_path / "shorter.json"  # the default config, fewer steps so that a test can run it
    shorter.write_text(json.dumps({"steps": 20, "motion_refit_steps": 5}))
    model_dir = str(tmp_path / "model")
    json.loads(training.train(out, model_dir, [str(shorter)], progress=False))
    config = json.loads(open(f"{model_dir}/config.json").read())
    assert config["joint_names"] == list(arm.JOINT_NAMES)
    demos = core_data.load_demonstrations(out)
    prediction = json.loads(api.predict(model_dir, encode_png(demos.images[0]), encode_png(demos.masks[0]),
                                        demos.objects[0]))
    assert prediction["joint_names"] == list(arm.JOINT_NAMES)
    frames = prediction["frames"]
    assert len(frames) > 10 and set(frames[0]) == {"t", "joints", "gripper"}
    joints = np.array([f["joints"] for f in frames])
    assert joints.shape[1] == 6 and np.isfinite(joints).all()
    tool = sim_api.forward_kinematics(prediction["joint_names"], prediction["fps"], [f["t"] for f in frames], joints,
                                      [f["gripper"] for f in frames])
    assert tool["position"].shape == (len(frames), 3)
    # Even a barely trained model starts where the demonstrations start (standardised motion).
    start = demos.trajectories[0][0, :-1]
    assert np.abs(joints[0] - start).max() < 0.5
