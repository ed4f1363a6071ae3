"""The simulator core: scene image and masks, workspace checks, the entry points the bridge
calls, and determinism."""

import io
import json
import os

import numpy as np
import pytest
from PIL import Image

from cnfmp.errors import InputError
from cnfmp.images import encode_png as encode_labels
from cnfmp.sim import api, engine
from cnfmp.sim.scene import CONTROL_HZ, WORKSPACE, project_to_image
from cnfmp.sim.tasks import cube_stacking, get_task


def test_scene_image_shows_each_object_and_no_gripper():
    scene = cube_stacking.make_scene(1_000_000)
    sim = engine.Simulation(scene)
    try:
        rgb, labels = sim.render_scene()
        home_labels = sim.render_labels()  # gripper at its home pose: still out of view
    finally:
        sim.close()
    assert rgb.shape == (128, 128, 3) and rgb.dtype == np.uint8
    assert labels.shape == (128, 128)
    counts = np.bincount(labels.ravel(), minlength=4)
    assert counts[1:].min() > 80, counts  # every cube clearly visible
    assert set(np.unique(labels)) == {0, 1, 2, 3}
    np.testing.assert_array_equal(labels, home_labels)
    # A red cube's pixels are red.
    red_label = scene.objects.index("red cube") + 1
    mean = rgb[labels == red_label].mean(axis=0)
    assert mean[0] > 1.5 * mean[1] and mean[0] > 1.5 * mean[2], mean


def test_rendering_is_deterministic():
    images = []
    for _ in range(2):
        sim = engine.Simulation(cube_stacking.make_scene(5))
        images.append(sim.render_scene()[0])
        sim.close()
    assert np.abs(images[0].astype(int) - images[1].astype(int)).max() <= 1


def test_render_writes_the_three_files(tmp_path):
    out = tmp_path / "scene"
    info = json.loads(api.render("cube_stacking", 3, str(out)))
    assert sorted(os.listdir(out)) == ["image.png", "masks.png", "objects.json"]
    assert info == json.loads((out / "objects.json").read_text())
    assert info["objects"] == cube_stacking.make_scene(3).objects
    masks = np.array(Image.open(out / "masks.png"))
    assert masks.shape == (128, 128) and masks.max() == len(info["objects"])
    with pytest.raises(InputError, match="already exists"):
        api.render("cube_stacking", 3, str(out))


def test_render_rejects_unknown_task_and_negative_seed(tmp_path):
    with pytest.raises(InputError, match="unknown task 'juggling'.*cube_stacking"):
        api.render("juggling", 1, str(tmp_path / "a"))
    with pytest.raises(InputError, match="seed"):
        api.render("cube_stacking", -1, str(tmp_path / "b"))
    assert not os.listdir(tmp_path)


def test_expert_entry_point_returns_control_rate_arrays():
    result = api.expert("cube_stacking", 11)
    n = len(result["t"])
    assert result["fps"] == CONTROL_HZ
    assert result["position"].shape == (n, 3) and result["orientation"].shape == (n, 4)
    np.testing.assert_allclose(np.diff(result["t"]), 1.0 / CONTROL_HZ)
    np.testing.assert_allclose(np.linalg.norm(result["orientation"], axis=1), 1.0, atol=1e-9)
    # Smooth (facts.md: 1 cm per-step jitter breaks grasps): speed under 1 m/s and the
    # step-to-step change of velocity under 2 mm per step (about 5 m/s^2).
    steps = np.diff(result["position"], axis=0)
    assert np.linalg.norm(steps, axis=1).max() < 1.0 / CONTROL_HZ
    assert np.linalg.norm(np.diff(steps, axis=0), axis=1).max() < 0.002


def test_execute_rejects_frames_outside_the_workspace():
    result = api.expert("cube_stacking", 11)
    result["position"][30, 2] = WORKSPACE[1, 2] + 0.1
    with pytest.raises(InputError, match="frame 30 .* leaves the workspace"):
        api.execute("cube_stacking", 11, result["position"], result["orientation"], result["gripper"])


def test_execute_reports_the_verdict():
    result = api.expert("cube_stacking", 12)
    report = json.loads(api.execute("cube_stacking", 12, result["position"], result["orientation"], result["gripper"]))
    assert report["success"] is True and report["reasons"] == []
    assert report["frames"] == len(result["t"])


def test_every_task_is_registered_and_described():
    names = json.loads(api.tasks_json())
    assert {"cube_stacking"} <= {t["name"] for t in names}
    assert all(t["description"] for t in names)
    assert get_task("cube_stacking").name == "cube_stacking"


def test_projection_puts_each_object_on_its_own_label():
    import mujoco

    from cnfmp.sim.tasks import language_pick_place

    scene = language_pick_place.make_scene(1_000_003)
    sim = engine.Simulation(scene)
    try:
        labels = sim.render_labels()
        for label, bodies in enumerate(scene.object_bodies, start=1):
            body = mujoco.mj_name2id(sim.model, mujoco.mjtObj.mjOBJ_BODY, bodies[0])
            column, row = project_to_image(sim.data.xpos[body][None])[0]
            assert labels[int(row), int(column)] == label, (scene.objects[label - 1], column, row)
    finally:
        sim.close()
    assert np.isnan(project_to_image(np.array([[0.0, -1.0, 0.5]]))).all()  # behind the camera


def test_draw_trajectory_draws_the_path_on_the_scene(tmp_path):
    api.render("language_pick_place", 1_000_003, str(tmp_path / "scene"))
    image = (tmp_path / "scene" / "image.png").read_bytes()
    masks = (tmp_path / "scene" / "masks.png").read_bytes()
    expert = api.expert("language_pick_place", 1_000_003)
    drawn = np.asarray(Image.open(io.BytesIO(
        api.draw_trajectory(image, masks, expert["position"], expert["gripper"]))))
    plain = np.asarray(Image.open(io.BytesIO(api.draw_trajectory(image, None, [[0.0, -1.0, 0.5]], [1.0]))))
    assert drawn.shape == plain.shape == (512, 512, 3)
    # The grasp point (first gripper closing) is ringed in white where the path projects.
    closing = int(np.flatnonzero(np.asarray(expert["gripper"]) < 0.5)[0])
    column, row = (project_to_image(np.asarray(expert["position"])[closing][None])[0] * 4).round().astype(int)
    ring = drawn[row - 12:row + 13, column - 12:column + 13]
    assert (ring == 255).all(axis=-1).any(), "no white ring at the grasp point"
    assert (np.abs(drawn.astype(int) - plain.astype(int)).sum(axis=-1) > 30).mean() > 0.02
    with pytest.raises(InputError, match="label map"):
        api.draw_trajectory(image, encode_labels(np.zeros((64, 64), np.uint8)), expert["position"], expert["gripper"])
