"""Training's choice of the objects a task is about (cnfmp.core.task_objects), on synthetic
demonstrations whose motion depends on known objects, and through `training.train`."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cnfmp.core import data as core_data
from cnfmp.core.task_objects import choose_task_objects


def scenes(count: int, objects: int, relevant: int, seed: int = 0) -> core_data.Demonstrations:
    """`count` 64x64 scenes of `objects` rectangles at random places, none touching another; each
    trajectory goes to the first `relevant` objects in turn (table position = image position)
    with a small offset of its own, the others stand about. Demonstration lengths vary."""
    rng = np.random.default_rng(seed)
    images = np.full((count, 64, 64, 3), 90, np.uint8)
    masks = np.zeros((count, 64, 64), np.uint8)
    trajectories = []
    cells = [(4 + 8 * column, 4 + 8 * row) for row in range(7) for column in range(7)]
    for b in range(count):
        centres = []
        for k, cell in enumerate(rng.permutation(len(cells))[:objects]):
            # Size, shading and shape vary, as real objects' masks do, so that every mask
            # statistic varies from scene to scene; only the centre matters to the motion.
            x, y = np.asarray(cells[cell]) + rng.integers(0, 2, size=2)
            w, h = rng.integers(3, 7, size=2)
            shade = np.linspace(rng.uniform(0.5, 1.0), 1.0, w)[None, :, None]
            images[b, y:y + h, x:x + w] = (shade * (200, 40 * k % 256 + 10, 90)).astype(np.uint8)
            masks[b, y:y + h, x:x + w] = k + 1
            centres.append(((x + w / 2) / 32 - 1, (y + h / 2) / 32 - 1))
        frames = int(rng.integers(40, 60))
        phase = np.linspace(0, 1, frames)
        pose = np.zeros((frames, 8))
        pose[:, 3] = 1.0
        for k in range(relevant):  # a leg towards each relevant object, in turn
            leg = np.clip(phase * relevant - k, 0, 1)[:, None]
            pose[:, :2] += 0.1 * leg * np.asarray(centres[k])
        pose[:, 2] = 0.05 + 0.02 * np.sin(np.pi * phase)
        pose[:, 7] = 0.5 + 0.5 * np.cos(2 * np.pi * phase)
        trajectories.append(pose + rng.normal(0, 1e-3, (1, 8)) + rng.normal(0, 1e-4, pose.shape))
    names = [[f"object {k + 1}" for k in range(objects)]] * count
    return core_data.Demonstrations("synthetic", 10.0, images, masks, names, trajectories, [-1] * count,
                                    ["put it there"] * count)


def test_objects_after_the_task_s_are_left_to_the_background():
    choice = choose_task_objects(scenes(24, objects=4, relevant=2))
    assert (choice.count, choice.available) == (2, 4) and choice.drops_objects
    assert choice.p_value is not None and choice.p_value < 0.05
    assert len(choice.left_out_mse) == 4 and choice.left_out_mse[1] == min(choice.left_out_mse)
    assert "first 2 of 4" in choice.reason


def test_every_object_the_motion_visits_keeps_its_slot():
    choice = choose_task_objects(scenes(24, objects=3, relevant=3))
    assert (choice.count, choice.available, choice.p_value) == (3, 3, None) and not choice.drops_objects
    assert "all 3 objects kept" in choice.reason


def test_too_few_demonstrations_or_a_single_object_keep_everything():
    assert choose_task_objects(scenes(4, objects=3, relevant=1)).count == 3
    assert "fewer than" in choose_task_objects(scenes(4, objects=3, relevant=1)).reason
    single = choose_task_objects(scenes(12, objects=1, relevant=1))
    assert (single.count, single.left_out_mse) == (1, ())


def test_training_with_no_task_objects_chooses_them_and_says_so_on_the_card(tmp_path, monkeypatch):
    """`training.train` without `task_objects` runs the choice and trains on the chosen objects;
    a config that sets it is obeyed without a choice."""
    from cnfmp.core import training
    from cnfmp.core.models import CONFIG_FILE

    demos = scenes(12, objects=3, relevant=1)
    monkeypatch.setattr(core_data, "load_demonstrations", lambda *args, **kwargs: demos)
    tiny = dict(field_resolution=16, latent_dim=4, num_endpoints=2, field_width=8, field_layers=1,
                appearance_octaves=1, pixels_per_object=16, uniform_pixels=16, mask_dilation=1, time_samples=8,
                search_pool=0, search_candidates=4, search_starts=1, refine_steps=1, inference_pixels=16,
                output_fps=10.0, motion_refit_steps=0, steps=2)
    config = tmp_path / "tiny.json"
    config.write_text(json.dumps(tiny))
    training.train("unused", str(tmp_path / "chosen"), [str(config)], progress=False)
    saved = json.loads((tmp_path / "chosen" / CONFIG_FILE).read_text())
    assert (saved["task_objects"], saved["num_objects"], saved["object_names"]) == (1, 1, ["object 1"])
    card = (tmp_path / "chosen" / "README.md").read_text()
    assert "| task objects | the first 1 of 3 objects kept" in card
    # The statistics choice ran too: its value is saved and the card says why.
    assert f"| mask statistics read | {saved['observed_statistics']}: " in card

    config.write_text(json.dumps({**tiny, "task_objects": 2}))
    training.train("unused", str(tmp_path / "set"), [str(config)], progress=False)
    saved = json.loads((tmp_path / "set" / CONFIG_FILE).read_text())
    assert (saved["task_objects"], saved["num_objects"]) == (2, 2)
    assert "the first 2 (set by the config)" in (tmp_path / "set" / "README.md").read_text()


@pytest.mark.parametrize("relevant", [1, 2])
def test_the_choice_does_not_depend_on_the_demonstrations_order(relevant):
    demos = scenes(20, objects=3, relevant=relevant, seed=3)
    order = np.random.default_rng(0).permutation(len(demos))
    shuffled = core_data.Demonstrations("synthetic", 10.0, demos.images[order], demos.masks[order],
                                        [demos.objects[k] for k in order], [demos.trajectories[k] for k in order],
                                        [-1] * len(demos), demos.prompts)
    assert choose_task_objects(shuffled).count == choose_task_objects(demos).count == relevant
