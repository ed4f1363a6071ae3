"""Training's choice of the object whose mask the tool axis is read from
(:mod:`cnfmp.core.tool_axis`), on synthetic demonstrations whose swing follows one object, none,
or nothing the masks show; and that training applies the choice."""

from __future__ import annotations

import numpy as np

from cnfmp import geometry
from cnfmp.core import data as core_data, tool_axis, training_cnfmp
from cnfmp.core.configuration_cnfmp import CnfmpConfig

REFERENCE = np.array([0.0, 1.0, 0.0, 0.0])  # fingers down


def demonstrations(swing_of, count: int = 12, seed: int = 0) -> core_data.Demonstrations:
    """`count` scenes of two squares at random places; each demonstration holds the swing
    `swing_of(x2, rng)` (rad, 2) of its second square's centroid x for its second half."""
    rng = np.random.default_rng(seed)
    images, masks, trajectories = [], [], []
    for _ in range(count):
        image = np.full((48, 64, 3), 200, np.uint8)
        labels = np.zeros((48, 64), np.uint8)
        (r1, c1), (r2, c2) = rng.integers(2, 20, 2), rng.integers(24, 38, 2)
        c1, c2 = c1, c2 + 10
        labels[r1:r1 + 8, c1:c1 + 8], labels[r2:r2 + 8, c2:c2 + 8] = 1, 2
        image[labels == 1], image[labels == 2] = (200, 40, 40), (60, 60, 60)
        x2 = (c2 + 4) / 64 * 2 - 1
        swing = np.asarray(swing_of(x2, rng))
        frames = 21
        quats = np.stack([geometry.from_swing_twist([*(swing * (k >= 10)), 0.0], REFERENCE) for k in range(frames)])
        position = np.linspace([0.4, 0.0, 0.3], [0.5, 0.1, 0.1], frames)
        gripper = (np.arange(frames) > 12).astype(float)[:, None]
        trajectories.append(np.concatenate([position, quats, gripper], axis=1))
        images.append(image)
        masks.append(labels)
    return core_data.Demonstrations("synthetic", 10.0, np.stack(images), np.stack(masks), [["cube", "ramp"]] * count,
                                    trajectories, list(range(count)), ["tilt to the ramp"] * count)


def test_a_swing_that_follows_one_objects_mask_reads_that_object():
    choice = tool_axis.choose_tool_axis_object(demonstrations(lambda x2, rng: [0.5 * x2, -0.3 * x2]))
    assert choice.slot == 1, choice.reason
    assert choice.left_out_mse[1] < tool_axis.MAX_ERROR_RATIO * choice.constant_mse
    assert "slot 2 (ramp)" in choice.reason


def test_an_axis_that_never_tilts_and_a_tilt_no_mask_tells_read_nothing_apart():
    level = tool_axis.choose_tool_axis_object(demonstrations(lambda x2, rng: [0.0, 0.0]))
    assert level.slot == -1 and "points the same way" in level.reason
    noise = tool_axis.choose_tool_axis_object(demonstrations(lambda x2, rng: rng.normal(0.0, 0.3, 2)))
    assert noise.slot == -1 and "no object's mask tells the tool axis" in noise.reason
    few = tool_axis.choose_tool_axis_object(demonstrations(lambda x2, rng: [0.5 * x2, 0.0], count=4))
    assert few.slot == -1 and "fewer than" in few.reason


def test_training_applies_the_choice_with_the_chart_it_needs_and_a_config_overrules_it():
    demos = demonstrations(lambda x2, rng: [0.5 * x2, -0.3 * x2])
    chosen, why = training_cnfmp.choose_tool_axis(training_cnfmp.fit_config_to_data(CnfmpConfig(), demos), demos)
    assert (chosen.tool_axis_object, chosen.rotation_chart) == (1, "swing_twist") and "ramp" in why
    chosen.check()
    kept, why = training_cnfmp.choose_tool_axis(CnfmpConfig(tool_axis_object=-1), demos)
    assert (kept.tool_axis_object, kept.rotation_chart) == (-1, "tangent") and "set by the config" in why
    level = demonstrations(lambda x2, rng: [0.0, 0.0])
    plain, _ = training_cnfmp.choose_tool_axis(CnfmpConfig(), level)
    assert (plain.tool_axis_object, plain.rotation_chart) == (-1, "tangent")
