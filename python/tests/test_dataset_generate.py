"""Dataset generation: a real LeRobot v3.0 dataset, read back by lerobot itself and checked
by lerobot-doctor; bad requests write nothing; a failure leaves nothing half-written."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from cnfmp.data import generate
from cnfmp.errors import InputError
from cnfmp.sim.tasks import cube_stacking


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("datasets") / "cubes"
    report = json.loads(generate.generate_dataset("cube_stacking", 2, 40, str(out), workers=2, progress=False))
    assert report["episodes"] == 2 and report["seeds"] == [40, 41] and report["skipped_seeds"] == []
    return out, report


def test_lerobot_reads_the_dataset_back(dataset_dir):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    out, report = dataset_dir
    dataset = LeRobotDataset("cnfmp/cube_stacking", root=out)
    assert dataset.num_episodes == 2
    assert dataset.num_frames == report["frames"]
    assert dataset.fps == generate.DATASET_FPS
    frame = dataset[0]
    assert tuple(frame[generate.IMAGE_KEY].shape) == (3, 128, 128)
    assert tuple(frame["observation.state"].shape) == (8,)
    assert tuple(frame["action"].shape) == (8,)
    scene = cube_stacking.make_scene(40)
    assert frame["task"] == scene.prompt
    assert json.loads(frame["annotation.objects"]) == scene.objects
    assert json.loads(frame["annotation.scene"]) == {"task": "cube_stacking", "seed": 40}
    masks = np.asarray(frame["annotation.masks"])
    assert masks.shape == (128, 128) and set(np.unique(masks)) == {0, 1, 2, 3}
    # Frame 0's state is the gripper's measured home pose, fully open.
    state = np.asarray(frame["observation.state"])
    np.testing.assert_allclose(state[:3], [0.0, -0.05, 0.40], atol=0.005)
    assert state[7] > 0.95
    last = dataset[report["frames"] - 1]
    assert json.loads(last["annotation.scene"])["seed"] == 41


def test_lerobot_doctor_passes(dataset_dir):
    out, _ = dataset_dir
    checks = "metadata,temporal,actions,videos,statistics,episodes,consistency,training,portability,per_episode"
    # The console script lives in the base venv; run its entry point with this interpreter.
    runner = "import sys; from lerobot_doctor.cli import main; sys.argv[0] = 'lerobot-doctor'; sys.exit(main())"
    proc = subprocess.run([sys.executable, "-c", runner, "check", str(out), "--checks", checks, "--ci", "--fail-on", "fail"],
                          capture_output=True, text=True, timeout=120, env=dict(os.environ, HF_HUB_OFFLINE="1"))
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    summary = json.JSONDecoder().raw_decode(proc.stdout)[0]["summary"]
    assert summary["FAIL"] == 0 and summary["PASS"] >= 9, summary


@pytest.mark.parametrize("task, episodes, seed, message", [
    ("juggling", 2, 0, "unknown task"),
    ("cube_stacking", 0, 0, "episodes must be"),
    ("cube_stacking", -3, 0, "episodes must be"),
    ("cube_stacking", 5, 999_998, "cross the end of the training range"),
    ("cube_stacking", 2, -1, "seed must be"),
])
def test_bad_requests_write_nothing(tmp_path, task, episodes, seed, message):
    with pytest.raises(InputError, match=message):
        generate.generate_dataset(task, episodes, seed, str(tmp_path / "out"), progress=False)
    assert os.listdir(tmp_path) == []


def test_existing_output_is_refused_and_kept(tmp_path):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "keep.txt").write_text("precious")
    with pytest.raises(InputError, match="already exists"):
        generate.generate_dataset("cube_stacking", 1, 0, str(tmp_path / "out"), progress=False)
    assert (tmp_path / "out" / "keep.txt").read_text() == "precious"


def test_a_failure_midway_leaves_nothing_behind(tmp_path, monkeypatch):
    def broken(dataset, episode):
        raise RuntimeError("disk full (simulated)")

    monkeypatch.setattr(generate, "_write_episode", broken)
    with pytest.raises(RuntimeError, match="disk full"):
        generate.generate_dataset("cube_stacking", 1, 0, str(tmp_path / "out"), workers=1, progress=False)
    assert os.listdir(tmp_path) == []
