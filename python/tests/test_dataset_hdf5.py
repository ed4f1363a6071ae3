"""The robomimic HDF5 reader (cnfmp.data.hdf5) on files written here with h5py."""

import json

import h5py
import numpy as np
import pytest

from cnfmp.data import hdf5
from cnfmp.errors import InputError


def _write(path, demos=(0, 2, 10), drop=None, frames=5):
    with h5py.File(path, "w") as f:
        data = f.create_group("data")
        data.attrs["problem_info"] = json.dumps({"language_instruction": "stack the blocks"})
        for k in demos:
            g = data.create_group(f"demo_{k}")
            fields = {
                "obs/frontview_image": np.zeros((frames, 8, 8, 3), np.uint8),
                "obs/robot0_eef_pos": np.zeros((frames, 3)),
                "obs/robot0_eef_quat": np.tile([0.0, 0.0, 0.0, 1.0], (frames, 1)),
                "obs/robot0_gripper_qpos": np.tile([0.02, -0.02], (frames, 1)),
                "actions": np.zeros((frames, 7)),
            }
            for name, value in fields.items():
                if name != drop:
                    g.create_dataset(name, data=value)


def test_demos_in_numeric_order_with_default_fps(tmp_path):
    path = str(tmp_path / "a.hdf5")
    _write(path)
    listing = json.loads(hdf5.list_demos(path))
    assert listing["demos"] == ["demo_0", "demo_2", "demo_10"]
    assert listing["fps"] == hdf5.DEFAULT_FPS and listing["fps_recorded"] is False
    assert listing["camera"] == "frontview"
    demo = hdf5.read_demo(path, "demo_2", listing["camera"])
    np.testing.assert_allclose(demo["orientation"][0], [1.0, 0.0, 0.0, 0.0])  # xyzw -> wxyz
    np.testing.assert_allclose(demo["gripper"], 0.5)  # 0.04 m of 0.08 m
    assert demo["prompt"] == "stack the blocks"
    assert demo["masks"].shape == (8, 8) and not demo["masks"].any() and demo["objects"] == []


def test_missing_field_and_bad_files_name_the_problem(tmp_path):
    path = str(tmp_path / "b.hdf5")
    _write(path, drop="obs/robot0_eef_quat")
    with pytest.raises(InputError, match="data/demo_0/obs/robot0_eef_quat: missing"):
        hdf5.read_demo(path, "demo_0", "frontview")
    not_hdf5 = tmp_path / "c.hdf5"
    not_hdf5.write_text("hello")
    with pytest.raises(InputError, match="not a readable HDF5 file"):
        hdf5.list_demos(str(not_hdf5))
    with pytest.raises(InputError, match="no such file"):
        hdf5.list_demos(str(tmp_path / "missing.hdf5"))
