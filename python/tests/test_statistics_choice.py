"""Training's choice of the mask statistics the motion reads
(:mod:`cnfmp.core.statistics_choice`), on synthetic demonstrations whose grasp turns with a
bar's yaw (which only the masks' elongation shows) or follows only where the objects are;
that training applies it and a config overrules it; and what a version-5 file meant."""

from __future__ import annotations

import numpy as np

from cnfmp import geometry
from cnfmp.core import data as core_data, statistics_choice, training_cnfmp
from cnfmp.core.configuration_cnfmp import CnfmpConfig


def demonstrations(grasp_turns_with_bar: bool, count: int = 16, seed: int = 0) -> core_data.Demonstrations:
    """`count` scenes of a bar (20 x 4 px, yaw in +-40 deg) and a square at random places;
    each demonstration moves from the bar to the square, its gripper turned by the bar's yaw
    when `grasp_turns_with_bar`, by a yaw no mask shows otherwise."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:64, 0:80]
    images, masks, trajectories = [], [], []
    for _ in range(count):
        image = np.full((64, 80, 3), 200, np.uint8)
        labels = np.zeros((64, 80), np.uint8)
        bar_centre, square = rng.uniform([18, 14], [46, 34]), rng.integers([8, 48], [48, 68])
        yaw = rng.uniform(-np.radians(40), np.radians(40))
        along = (cols - bar_centre[1]) * np.cos(yaw) + (rows - bar_centre[0]) * np.sin(yaw)
        across = -(cols - bar_centre[1]) * np.sin(yaw) + (rows - bar_centre[0]) * np.cos(yaw)
        labels[(np.abs(along) <= 10) & (np.abs(across) <= 2)] = 1
        labels[square[0]:square[0] + 8, square[1]:square[1] + 8] = 2
        image[labels == 1], image[labels == 2] = (200, 40, 40), (40, 40, 200)
        turn = yaw if grasp_turns_with_bar else rng.uniform(-np.radians(40), np.radians(40))
        frames = 21
        start = np.array([bar_centre[1] / 80, bar_centre[0] / 64, 0.1])
        end = np.array([(square[1] + 4) / 80, (square[0] + 4) / 64, 0.1])
        position = np.linspace(start, end, frames)
        quats = np.stack([geometry.quat_down(turn * (k >= 5)) for k in range(frames)])
        gripper = ((np.arange(frames) > 5) & (np.arange(frames) < 15)).astype(float)[:, None]
        trajectories.append(np.concatenate([position, quats, gripper], axis=1))
        images.append(image)
        masks.append(labels)
    return core_data.Demonstrations("synthetic", 10.0, np.stack(images), np.stack(masks), [["bar", "box"]] * count,
                                    trajectories, list(range(count)), ["put the bar in the box"] * count)


def test_a_grasp_that_turns_with_a_bar_reads_every_statistic_and_one_that_does_not_the_shading():
    turns = statistics_choice.choose_observed_statistics(demonstrations(grasp_turns_with_bar=True))
    assert turns.name == "all", turns.reason
    assert turns.left_out_mse["all"] < 0.8 * turns.left_out_mse["shading"] and turns.p_value < 0.05
    plain = statistics_choice.choose_observed_statistics(demonstrations(grasp_turns_with_bar=False))
    assert plain.name == "shading", plain.reason
    assert "do not predict" in plain.reason
    few = statistics_choice.choose_observed_statistics(demonstrations(grasp_turns_with_bar=True, count=4))
    assert few.name == "shading" and few.p_value is None and "fewer than" in few.reason


def test_training_applies_the_choice_and_a_config_or_a_version_5_file_overrules_it():
    demos = demonstrations(grasp_turns_with_bar=True)
    chosen, why = training_cnfmp.choose_statistics(CnfmpConfig(), demos)
    assert chosen.observed_statistics == "all" and "predict left-out demonstrations significantly better" in why
    kept, why = training_cnfmp.choose_statistics(CnfmpConfig(observed_statistics="centroid"), demos)
    assert kept.observed_statistics == "centroid" and why == "centroid (set by the config)"
    # Version 5 read a file that left the field out as "shading"; version 6 leaves it to training.
    assert CnfmpConfig.from_dict({"config_version": 5}).observed_statistics == "shading"
    assert CnfmpConfig.from_dict({"config_version": 6}).observed_statistics is None
