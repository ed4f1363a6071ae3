"""Demonstrations as a lab records them: a LeRobot dataset written the way `lerobot-record`
writes one (video camera streams at 320x240, two cameras, a rotation-vector end-effector
pose with a gripper in millimetres, a task string, no masks, episodes demonstrated at
different speeds), annotated by the language segmenter, aligned by gripper events and trained."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from PIL import Image

from cnfmp import geometry
from cnfmp.core import alignment, api, data as core_data, segment_timing, training
from cnfmp.core.configuration_cnfmp import CnfmpConfig
from cnfmp.data import annotate, generate, recorded
from cnfmp.errors import InputError
from cnfmp.images import encode_png
from cnfmp.segmenter import api as segmenter_api

WIDTH, HEIGHT = 320, 240
MOTION_NAMES = ["ee.x", "ee.y", "ee.z", "ee.rx", "ee.ry", "ee.rz", "gripper.pos"]
GRIPPER_MM = 85.0
#: Per episode, how much slower than the expert the operator moved (time stretch factor).
SPEEDS = [1.0, 1.5, 0.8, 1.25]
#: The recording's frame rate; the simulator's demonstrations are resampled from 10 Hz.
FPS = 15


def _camera_frame(image: np.ndarray) -> np.ndarray:
    """A 128x128 render as a 320x240 camera frame: scaled to 240x240, grey bars at the sides."""
    import cv2

    frame = np.full((HEIGHT, WIDTH, 3), 128, np.uint8)
    left = (WIDTH - HEIGHT) // 2
    frame[:, left:left + HEIGHT] = cv2.resize(image, (HEIGHT, HEIGHT), interpolation=cv2.INTER_LINEAR)
    return frame


def _stretch(values: np.ndarray, factor: float) -> np.ndarray:
    """(T, D) values resampled to round(T * factor) frames (a slower or faster demonstration)."""
    frames = max(2, int(round(len(values) * factor)))
    source = np.linspace(0, len(values) - 1, frames)
    return np.stack([np.interp(source, np.arange(len(values)), column) for column in values.T], axis=1)


def _motion(state: np.ndarray) -> np.ndarray:
    """(T, 8) ``x y z qw qx qy qz gripper`` -> (T, 7) ``x y z rx ry rz gripper_mm``."""
    rotvec = geometry.to_rotation(state[:, 3:7]).as_rotvec()
    return np.concatenate([state[:, :3], rotvec, state[:, 7:8] * GRIPPER_MM], axis=1).astype(np.float32)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A lerobot-record-like dataset of language_pick_place demonstrations; returns (dir, episodes)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = tmp_path_factory.mktemp("recorded") / "my_robot_pick"
    spec = {"dtype": "video", "shape": (HEIGHT, WIDTH, 3), "names": ["height", "width", "channels"]}
    features = {"observation.images.front": spec, "observation.images.wrist": spec,
                "observation.state": {"dtype": "float32", "shape": (7,), "names": MOTION_NAMES},
                "action": {"dtype": "float32", "shape": (7,), "names": MOTION_NAMES}}
    dataset = LeRobotDataset.create(repo_id="lab/my_robot_pick", fps=FPS, features=features, root=str(root),
                                    use_videos=True)
    rate = FPS / generate.DATASET_FPS
    episodes = []
    for seed, speed in zip(range(300, 300 + len(SPEEDS)), SPEEDS):
        episode = generate.simulate_episode("language_pick_place", seed)
        state = _stretch(_motion(episode["state"]), speed * rate)
        action = _stretch(_motion(episode["action"]), speed * rate)
        front = _camera_frame(episode["images"][0])
        for k in range(len(state)):
            dataset.add_frame({"observation.images.front": front, "observation.images.wrist": 255 - front,
                               "observation.state": state[k].astype(np.float32),
                               "action": action[k].astype(np.float32), "task": episode["prompt"]})
        dataset.save_episode()
        episodes.append({"prompt": episode["prompt"], "objects": episode["objects"], "mask": episode["masks"][0],
                         "frames": len(state), "image": front})
    dataset.finalize()
    return str(root), episodes


@pytest.fixture(scope="module")
def annotated(recording, tmp_path_factory):
    source, _ = recording
    out = str(tmp_path_factory.mktemp("annotated") / "my_robot_pick_masks")
    report = json.loads(annotate.annotate(source, out, camera="observation.images.front", progress=False))
    return out, report


def test_motion_layouts_are_read_from_names():
    layout = recorded.motion_layout("action", MOTION_NAMES)
    assert (layout.position, layout.rotation, layout.rotation_indices, layout.gripper) == ((0, 1, 2), "rotvec", (3, 4, 5), 6)
    euler = recorded.motion_layout("observation.state", {"motors": ["gripper", "roll", "pitch", "yaw", "x", "y", "z"]})
    assert euler.rotation == "euler" and euler.position == (4, 5, 6) and euler.gripper == 0
    quat = recorded.motion_layout("action", ["x", "y", "z", "qx", "qy", "qz", "qw", "gripper"])
    assert quat.rotation_indices == (6, 3, 4, 5)
    poses, scale = recorded.to_motion([np.array([[0, 0, 0, 0, 0, 0, 1, 20.0], [0, 0, 0, 0, 0, 0, 1, 80.0]])], quat)
    np.testing.assert_allclose(poses[0][:, 3:7], [[1, 0, 0, 0]] * 2)
    assert scale == (20.0, 80.0) and poses[0][:, 7].tolist() == [0.0, 1.0]
    euler_values = np.array([[0.5, 0, 0, np.pi / 2, 1, 2, 3]] * 2)
    euler_pose, _ = recorded.to_motion([euler_values], euler)
    np.testing.assert_allclose(euler_pose[0][0, 3:7], [np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)], atol=1e-9)
    # And back: the recording's own form, dimension by dimension.
    names, back = recorded.from_motion(euler_pose[0], euler, None)
    assert names == ["gripper", "roll", "pitch", "yaw", "x", "y", "z"]
    np.testing.assert_allclose(back, euler_values, atol=1e-9)
    names, back = recorded.from_motion(poses[0], quat, scale)
    assert names == ["x", "y", "z", "qx", "qy", "qz", "qw", "gripper"] and back[:, 7].tolist() == [20.0, 80.0]


@pytest.mark.parametrize("names, message", [
    (["x", "y", "elbow.pos", "wrist.pos", "gripper.pos"], "neither an end-effector pose nor joint space: no z"),
    (["x", "y", "z", "rx", "ry", "rz"], "exactly one dimension named like 'gripper'"),
    (None, "does not name its dimensions"),
])
def test_motion_vectors_the_core_cannot_learn_are_refused(names, message):
    with pytest.raises(InputError, match=message):
        recorded.motion_layout("action", names)


def test_the_camera_is_the_annotated_one_or_chosen():
    features = {"observation.images.front": {"dtype": "video"}, "observation.images.wrist": {"dtype": "image"},
                "action": {"dtype": "float32"}}
    with pytest.raises(InputError, match="2 cameras .*choose one with --camera"):
        recorded.choose_camera(features, None, None)
    assert recorded.choose_camera(features, "observation.images.wrist", None) == "observation.images.wrist"
    assert recorded.choose_camera(features, None, "observation.images.front") == "observation.images.front"
    with pytest.raises(InputError, match="masks were made on camera"):
        recorded.choose_camera(features, "observation.images.wrist", "observation.images.front")
    with pytest.raises(InputError, match="no camera 'top'"):
        recorded.choose_camera(features, "top", None)


def test_gripper_events_use_hysteresis_and_alignment_moves_them_to_the_median():
    noisy = np.array([1, 0.6, 0.4, 0.3, 0.4, 0.36, 0.2, 0.5, 0.7, 1.0])
    assert alignment.gripper_events(noisy, (0.35, 0.65)) == [3, 8]
    # The band comes from the data: a gripper that reopens only to 0.55 (to clear a cup) and
    # jitters by 0.05 about each level still makes exactly its four events.
    rng = np.random.default_rng(0)
    cup_like = np.repeat([1.0, 0.55, 0.0, 0.55, 0.0, 0.55], [5, 15, 20, 15, 20, 15]) + rng.uniform(-0.05, 0.05, 90)
    close_below, open_above = alignment.event_thresholds([cup_like])
    assert 0.05 < close_below < open_above < 0.5
    assert alignment.gripper_events(cup_like) == [20, 40, 55, 75]
    assert alignment.event_thresholds([np.full(10, 0.7)]) == (-1.0, 2.0)  # never moves: no events

    def demo(close: int, open_: int, length: int) -> np.ndarray:
        trajectory = np.zeros((length, 8))
        trajectory[:, 0] = np.arange(length)  # x tells which source frame a row came from
        trajectory[:, 3] = 1.0
        trajectory[:, 7] = 1.0
        trajectory[close:open_, 7] = 0.0
        return trajectory

    demos = [demo(10, 30, 40), demo(20, 50, 70), demo(14, 40, 50), demo(10, 20, 25)[:, :]]
    demos[3][:, 7] = 1.0  # no gripper events: its own group
    aligned, report = alignment.align_demonstrations(demos, fps=10.0)
    assert report.majority == 2 and report.outliers() == [3]
    assert report.groups[2]["event_times_s"] == [1.4, 4.0] and report.groups[2]["duration_s"] == 4.9
    for trajectory in aligned[:3]:
        assert len(trajectory) == 50 and alignment.gripper_events(trajectory[:, 7]) == [14, 40]
    np.testing.assert_allclose(aligned[1][14, 0], 20.0)  # its closing frame landed on the median
    np.testing.assert_allclose(aligned[3], demos[3])  # alone in its group: unchanged


def test_annotate_adds_masks_from_the_prompt_and_keeps_the_videos(recording, annotated):
    source, episodes = recording
    out, report = annotated
    assert report["annotated"] == len(episodes) and not report["skipped"] and report["camera"] == "observation.images.front"
    assert report["task"] == "my_robot_pick" and os.path.isfile(report["contact_sheet"])
    assert not os.path.exists(out + ".staging") and not os.path.exists(out + ".partial")
    demos = core_data.load_demonstrations(out)
    assert demos.images.shape == (len(episodes), HEIGHT, WIDTH, 3) and demos.camera == "observation.images.front"
    assert demos.task == "my_robot_pick" and "rotvec" in demos.motion and "gripper 0..85 read as 0..1" in demos.motion
    for b, episode in enumerate(episodes):
        # The segmenter's masks cover the simulator's true masks of the same objects.
        truth = np.asarray(Image.fromarray(episode["mask"]).resize((HEIGHT, HEIGHT), Image.NEAREST))
        left = (WIDTH - HEIGHT) // 2
        for label in (1, 2):
            found = demos.masks[b][:, left:left + HEIGHT] == label
            overlap = (found & (truth == label)).sum() / max(1, (found | (truth == label)).sum())
            assert overlap > 0.5, (b, label, overlap)
        assert len(demos.trajectories[b]) == episode["frames"] + 1
        assert demos.trajectories[b][:, 7].min() >= 0 and demos.trajectories[b][:, 7].max() <= 1.0
    with pytest.raises(InputError, match="already has coarse masks"):
        annotate.annotate(out, out + "-again", progress=False)


def test_training_reads_the_recording_aligned(annotated, tmp_path):
    out, _ = annotated
    model_dir = str(tmp_path / "model")
    config = tmp_path / "tiny.json"
    config.write_text(json.dumps({"field_resolution": 32, "latent_dim": 8, "field_width": 32, "field_layers": 2,
                                  "num_endpoints": 2, "steps": 30, "search_candidates": 8, "refine_steps": 3}))
    report = json.loads(training.train(out, model_dir, [str(config)], progress=False))
    assert report["task"] == "my_robot_pick" and report["demos"] == len(SPEEDS)
    card = open(os.path.join(model_dir, "README.md")).read()
    assert "`observation.images.front`" in card and "rotvec" in card
    assert "4 demonstrations with 2 gripper event(s)" in card
    # Predict on a training scene: a trajectory of the aligned duration, at the camera's size.
    demos = core_data.load_demonstrations(out)
    prediction = json.loads(api.predict(model_dir, encode_png(demos.images[0]), encode_png(demos.masks[0]),
                                        demos.objects[0]))
    frames = prediction["frames"]
    assert abs(frames[-1]["t"] - json.loads(open(os.path.join(model_dir, "config.json")).read())["duration_s"]) < 0.2
    # The prediction also comes back in the recording's own form: rotation vector, gripper in mm.
    recorded_form = prediction["recorded"]
    assert recorded_form["names"] == MOTION_NAMES and len(recorded_form["values"]) == len(frames)
    values = np.asarray(recorded_form["values"])
    np.testing.assert_allclose(values[:, :3], [f["position"] for f in frames], atol=1e-5)
    between = geometry.Rotation.from_rotvec(values[:, 3:6]).inv() * geometry.to_rotation([f["orientation"] for f in frames])
    assert between.magnitude().max() < 1e-4
    assert np.abs(np.diff(values[:, 3:6], axis=0)).max() < 0.5  # continuous: no jump between equivalent vectors
    np.testing.assert_allclose(values[:, 6], np.asarray([f["gripper"] for f in frames]) * (values[:, 6].max() / max(
        f["gripper"] for f in frames)), atol=1e-3)
    assert values[:, 6].max() > 1.5  # millimetres, not [0, 1]
    # The annotation's roles travel with the model: a prompt orders the segmenter's masks for it.
    roles = json.loads(api.describe(model_dir))["roles"]
    assert roles == ["target", "destination"]
    found = segmenter_api.segment(encode_png(demos.images[0]), demos.prompts[0], roles=roles, pictures=False)
    assert found["slot_names"] == demos.objects[0]
    with pytest.raises(InputError, match="masks were made on camera"):
        training.train(out, str(tmp_path / "other"), [str(config)], progress=False,
                       recording=core_data.RecordingOptions(camera="observation.images.wrist"))


def test_a_recording_without_masks_is_refused_with_the_fix(recording, tmp_path):
    source, _ = recording
    with pytest.raises(InputError, match="cnfmp dataset annotate"):
        training.train(source, str(tmp_path / "model"), progress=False)


def test_an_object_not_found_is_reported_and_hand_made_masks_fill_in(recording, tmp_path):
    source, episodes = recording
    masks_dir = tmp_path / "hand"
    masks_dir.mkdir()
    hand = np.zeros((HEIGHT, WIDTH), np.uint8)
    hand[100:140, 100:140] = 1
    Image.fromarray(hand).save(masks_dir / "episode_1.png")
    out = str(tmp_path / "with_unicorn")
    report = json.loads(annotate.annotate(source, out, camera="observation.images.front",
                                          objects=["unicorn"], masks_dir=str(masks_dir), progress=False))
    assert report["annotated"] == 1 and report["hand_made"] == 1
    assert [s["episode"] for s in report["skipped"]] == [0, 2, 3]
    assert report["skipped"][0]["missing"][0]["phrase"] == "unicorn"
    demos = core_data.load_demonstrations(out)
    assert len(demos) == 1 and demos.objects == [["unicorn"]] and (demos.masks[0] == hand).all()
    assert len(demos.trajectories[0]) == episodes[1]["frames"] + 1


def test_bad_recordings_get_clear_errors_and_leave_nothing(recording, tmp_path):
    import glob
    import shutil

    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    source, _ = recording
    out = str(tmp_path / "out")
    with pytest.raises(InputError, match="no camera 'observation.images.top'"):
        annotate.annotate(source, out, camera="observation.images.top", progress=False)
    broken = str(tmp_path / "broken")
    shutil.copytree(source, broken)
    video = sorted(glob.glob(os.path.join(broken, "videos", "observation.images.front", "**", "*.mp4"), recursive=True))[0]
    with open(video, "wb") as handle:
        handle.write(b"not a video")
    with pytest.raises(InputError, match=f"the video {video} of camera observation.images.front cannot be decoded"):
        annotate.annotate(broken, out, camera="observation.images.front", progress=False)
    os.remove(video)
    with pytest.raises(InputError, match=f"file\\(s\\) of the dataset are missing, e.g. {video}"):
        annotate.annotate(broken, out, camera="observation.images.front", progress=False)
    assert not glob.glob(out + "*"), "nothing is left behind by a refused annotation"
    # An interrupted run resumes only with the same command.
    os.makedirs(out + ".staging")
    with open(os.path.join(out + ".staging", "command.json"), "w") as handle:
        json.dump({"dataset": os.path.abspath(source), "camera": "observation.images.front", "objects": ["unicorn"],
                   "backend": "auto", "weights": None, "masks_dir": None}, handle)
    with pytest.raises(InputError, match="another annotate command \\(it differs in: objects\\)"):
        annotate.annotate(source, out, camera="observation.images.front", progress=False)
    shutil.rmtree(out + ".staging")

    # No task prompt, no --objects; and a gripper in millimetres that never moves.
    spec = {"dtype": "float32", "shape": (7,), "names": MOTION_NAMES}
    silent = LeRobotDataset.create(repo_id="lab/silent", fps=FPS, root=str(tmp_path / "silent"), use_videos=True,
                                   features={"observation.images.front": {"dtype": "video", "shape": (HEIGHT, WIDTH, 3),
                                                                          "names": ["height", "width", "channels"]},
                                             "action": spec})
    for k in range(3):
        silent.add_frame({"observation.images.front": np.zeros((HEIGHT, WIDTH, 3), np.uint8),
                          "action": np.array([0, 0, 0.1 * k, 0, 0, 0, 40.0], np.float32), "task": " "})
    silent.save_episode()
    silent.finalize()
    with pytest.raises(InputError, match="no task prompt"):
        annotate.annotate(str(tmp_path / "silent"), out, progress=False)
    episode = [np.array([[0, 0, 0.1 * k, 0, 0, 0, 40.0] for k in range(3)])]
    with pytest.raises(InputError, match="stays at 40 in every episode"):
        recorded.to_motion(episode, recorded.motion_layout("action", MOTION_NAMES))
    assert not glob.glob(out + "*")


@pytest.mark.parametrize("roles, kept", [
    (["target", "destination"], ["target", "destination"]),
    (["unknown", "unknown"], []),  # objects named one by one (--objects): no roles
    (["object", "object"], []),  # two slots one role: a prompt could not tell them apart
    ([], []),
])
def test_only_roles_that_tell_the_slots_apart_go_into_the_model(roles, kept):
    from cnfmp.core.configuration_cnfmp import CnfmpConfig
    from cnfmp.core.training_cnfmp import fit_config_to_data

    masks = np.zeros((1, 8, 8), np.uint8)
    masks[0, :2], masks[0, -2:] = 1, 2
    trajectory = np.tile([0.0, 0.0, 0.1, 1.0, 0.0, 0.0, 0.0, 1.0], (5, 1))
    demos = core_data.Demonstrations("lab", 10.0, np.zeros((1, 8, 8, 3), np.uint8), masks, [["a", "b"]],
                                     [trajectory], [-1], ["put a on b"], roles=[roles])
    assert fit_config_to_data(CnfmpConfig(), demos).object_roles == kept


def test_a_small_camera_and_two_demonstration_lengths_train_with_the_default_config(tmp_path):
    """A 160x120 image camera (not video) at 10 fps, two demonstrations of different lengths:
    annotated, then trained with the default config (only shortened) and predicted at that size."""
    import cv2
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    width, height = 160, 120
    root = tmp_path / "small_camera"
    spec = {"dtype": "image", "shape": (height, width, 3), "names": ["height", "width", "channels"]}
    dataset = LeRobotDataset.create(repo_id="lab/small_camera", fps=10, root=str(root), use_videos=False, features={
        "observation.images.top": spec, "action": {"dtype": "float32", "shape": (7,), "names": MOTION_NAMES}})
    lengths = []
    for seed, speed in [(320, 1.0), (321, 1.6)]:
        episode = generate.simulate_episode("language_pick_place", seed)
        action = _stretch(_motion(episode["action"]), speed)
        frame = np.full((height, width, 3), 128, np.uint8)
        frame[:, 20:140] = cv2.resize(episode["images"][0], (height, height), interpolation=cv2.INTER_AREA)
        for row in action:
            dataset.add_frame({"observation.images.top": frame, "action": row.astype(np.float32),
                               "task": episode["prompt"]})
        dataset.save_episode()
        lengths.append(len(action))
    dataset.finalize()
    assert lengths[1] > 1.4 * lengths[0]

    annotated_dir = str(tmp_path / "small_camera_masks")
    report = json.loads(annotate.annotate(str(root), annotated_dir, progress=False))
    assert report["annotated"] == 2 and report["camera"] == "observation.images.top"
    shorter = tmp_path / "shorter.json"  # the default config, fewer steps so that a test can run it
    shorter.write_text(json.dumps({"steps": 30, "motion_refit_steps": 10}))
    model_dir = str(tmp_path / "model")
    trained = json.loads(training.train(annotated_dir, model_dir, [str(shorter)], progress=False))
    assert trained["demos"] == 2
    config = json.loads(open(os.path.join(model_dir, "config.json")).read())
    assert config["field_resolution"] == CnfmpConfig.field_resolution and config["num_endpoints"] == CnfmpConfig.num_endpoints
    demos = core_data.load_demonstrations(annotated_dir)
    assert demos.images.shape == (2, height, width, 3)
    prediction = json.loads(api.predict(model_dir, encode_png(demos.images[1]), encode_png(demos.masks[1]),
                                        demos.objects[1]))
    # Both demonstrations are aligned to one duration, between their own.
    assert abs(prediction["frames"][-1]["t"] - config["duration_s"]) < 0.2
    assert (lengths[0] - 1) / 10 - 0.2 <= config["duration_s"] <= (lengths[1] - 1) / 10 + 0.2
    assert np.isfinite([f["position"] for f in prediction["frames"]]).all()


def test_a_pace_that_follows_the_scene_is_learned_and_a_random_one_is_not():
    rng = np.random.default_rng(3)
    features = rng.normal(size=(20, 6)) @ rng.normal(size=(6, 24))  # latents: a few scene factors
    # Segment durations that follow the scene (a far object takes longer), then at random.
    durations = np.stack([1.0 + 0.3 * np.tanh(features[:, 0]), 2.0 + 0.5 * np.tanh(features[:, 1])], axis=1)
    knots = np.concatenate([np.zeros((20, 1)), np.cumsum(durations, axis=1)], axis=1)
    timing = segment_timing.fit(features, knots, np.median(knots, axis=0))
    assert timing is not None and timing.loo_error_s < 0.5 * timing.constant_error_s
    predicted = np.array([timing.knots(f) for f in features])
    assert np.abs(predicted - knots).mean() < 0.5 * np.abs(np.median(knots, axis=0) - knots).mean()
    shuffled = rng.permutation(knots)
    assert segment_timing.fit(features, shuffled, np.median(knots, axis=0)) is None
    assert segment_timing.fit(features[:4], knots[:4], np.median(knots, axis=0)) is None  # too few to tell
    # Re-timing moves the median's knots onto the scene's and keeps the path.
    times = np.arange(151) / 50.0
    trajectory = {"t": times, "position": np.stack([times, 0 * times, 0 * times], axis=1),
                  "orientation": np.tile([1.0, 0, 0, 0], (151, 1)), "gripper": (times < 1.0).astype(float)}
    retimed = segment_timing.retime(trajectory, np.array([0.0, 1.0, 3.0]), np.array([0.0, 1.5, 3.5]), 50.0)
    assert retimed["t"][-1] == pytest.approx(3.5) and len(retimed["t"]) == 176
    assert retimed["position"][75, 0] == pytest.approx(1.0) and retimed["position"][-1, 0] == pytest.approx(3.0)
    np.testing.assert_allclose(np.linalg.norm(retimed["orientation"], axis=1), 1.0)
