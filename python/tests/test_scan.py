"""Scans (cnfmp.scan, cnfmp.sim.scan): the simulator's four depth views back-project onto the scene's
true geometry, survive the file format, and bad scans are refused naming view and file."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from PIL import Image

from cnfmp.errors import InputError
from cnfmp import scan as scans
from cnfmp.sim.scan import render_scan
from cnfmp.sim.tasks import drawer_place


@pytest.fixture(scope="module")
def scene():
    return drawer_place.make_scene(1_000_001)


@pytest.fixture(scope="module")
def scan(scene):
    return render_scan(scene)


@pytest.fixture
def written(scan, tmp_path):
    out = tmp_path / "scan"
    scans.write_scan(scan, str(out))
    return out


def test_every_view_back_projects_the_table_and_the_carton_where_they_are(scan, scene):
    assert [view.name for view in scan.views] == ["front", "left", "right", "top"]
    cx, cy = scene.params["carton_xy"]
    for view in scan.views:
        points, labels = view.points()
        table = points[(labels == 0) & (points[:, 1] < -0.1) & (np.abs(points[:, 0]) < 0.25) & (points[:, 2] > -0.1)]
        assert len(table) > 500 and np.abs(table[:, 2]).max() < 0.002, view.name
        carton = points[labels == 1]
        assert len(carton) > 20, view.name
        # Within the carton's bounding cylinder (yaw unknown here) and its height.
        radial = np.hypot(carton[:, 0] - cx, carton[:, 1] - cy)
        assert radial.max() < np.hypot(0.03, 0.03) + 0.003, view.name
        assert carton[:, 2].min() > -0.002 and carton[:, 2].max() < 0.05 + 0.002, view.name
        drawer = points[labels == 2]
        assert len(drawer) > 100 and drawer[:, 1].min() > drawer_place.CABINET_FRONT_Y - scene.params["opening"] - 0.015


def test_a_written_scan_reads_back_to_the_millimetre(scan, written):
    meta = json.loads((written / "cameras.json").read_text())
    assert meta["format"] == "cnfmp-scan" and meta["objects"] == ["carton box", "drawer"]
    back = scans.read_scan(str(written))
    assert back.objects == scan.objects
    for a, b in zip(scan.views, back.views):
        assert a.name == b.name and np.array_equal(a.rgb, b.rgb) and np.array_equal(a.labels, b.labels)
        assert np.abs(a.depth - b.depth).max() <= 0.0005 + 1e-6
        assert np.allclose(a.intrinsics, b.intrinsics) and np.allclose(a.world_from_camera, b.world_from_camera)


def test_depth_in_metres_as_npy_is_read_too(scan, written):
    meta = json.loads((written / "cameras.json").read_text())
    np.save(written / "front_depth.npy", scan.views[0].depth.astype(np.float64))
    meta["views"][0]["depth"] = "front_depth.npy"
    (written / "cameras.json").write_text(json.dumps(meta))
    assert np.array_equal(scans.read_scan(str(written)).views[0].depth, scan.views[0].depth)


def edit(written, change):
    meta = json.loads((written / "cameras.json").read_text())
    change(meta)
    (written / "cameras.json").write_text(json.dumps(meta))


@pytest.mark.parametrize("change, message", [
    (lambda m: m["views"][1].pop("world_from_camera"), r"view left: \"world_from_camera\" is missing"),
    (lambda m: m["views"][2].update(world_from_camera=[[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
     "view right: world_from_camera is not a rigid transform"),
    (lambda m: m["views"][0].update(intrinsics=[[1, 0], [0, 1]]), "view front: intrinsics must be a finite 3x3"),
    (lambda m: m["views"][3].update(labels="nowhere.png"), "view top: the labels file .*nowhere.png is missing"),
    (lambda m: m.pop("objects"), "needs \"objects\""),
])
def test_a_scan_with_a_bad_camera_entry_is_refused_naming_it(written, change, message):
    edit(written, change)
    with pytest.raises(InputError, match=message):
        scans.read_scan(str(written))


def test_depth_of_another_size_than_its_view_is_refused(written):
    Image.fromarray(np.zeros((64, 64), np.uint16)).save(written / "left_depth.png")
    with pytest.raises(InputError, match=r"view left: left_depth.png is 64x64 px but the view is 128x128"):
        scans.read_scan(str(written))


def test_nan_depth_is_refused(written):
    depth = np.full((128, 128), 0.5)
    depth[3, 4] = np.nan
    np.save(written / "front_depth.npy", depth)
    edit(written, lambda m: m["views"][0].update(depth="front_depth.npy"))
    with pytest.raises(InputError, match="view front: .*front_depth.npy holds NaN depth \\(1 pixels\\)"):
        scans.read_scan(str(written))


def test_a_directory_without_cameras_json_is_not_a_scan(tmp_path):
    with pytest.raises(InputError, match="cameras.json is missing"):
        scans.read_scan(str(tmp_path))


def test_writing_into_a_used_directory_is_refused_and_writes_nothing(scan, tmp_path):
    (tmp_path / "keep.txt").write_text("mine")
    with pytest.raises(InputError, match="not an empty directory"):
        scans.write_scan(scan, str(tmp_path))
    assert os.listdir(tmp_path) == ["keep.txt"]
