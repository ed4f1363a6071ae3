"""Which of each object's mask statistics the motion reads, chosen from the demonstrations.

The motion reads every object's mask centroid and a set of its other mask statistics
(:data:`cnfmp.core.modeling_cnfmp.OBSERVED_COLUMNS`) beside its latent: "shading" (where the
darker part of the mask lies, and its brightness) or "all" (also the mask's elongation, size
and shaded part's offset). A task whose motion turns with an elongated object or depends on
an object's size needs the second; on a task where it does not, five more inputs per object
give the learned map room to fit 20-30 demonstrations in ways that do not carry to new
scenes (docs/experiments.md, "Every mask statistic for the motion, chosen by training").

So before training, each demonstration's trajectory (position, rotation as a rotation vector
at the first demonstration's start orientation, gripper; every joint in joint space),
sampled at fixed phases, is predicted by ridge regression on the standardised statistics of
all its objects, one demonstration left out at a time, once from the "shading" set and once
from "all". "all" is chosen when its left-out error is lower, significantly so (a paired
one-sided t-test over the demonstrations, p < :data:`cnfmp.core.task_objects.SIGNIFICANCE`);
otherwise "shading".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cnfmp import geometry
from cnfmp.core import data as core_data
from cnfmp.core import task_objects
from cnfmp.core.modeling_cnfmp import OBSERVED_COLUMNS

#: The set the motion reads unless the demonstrations show that the rest helps.
DEFAULT = "shading"
#: The set chosen when it predicts the left-out demonstrations significantly better.
RICHER = "all"
#: Fewest demonstrations the choice is made on; with fewer, DEFAULT.
MIN_DEMOS = 6
#: The mask centroid (columns 0 and 1 of the statistics), read with every set.
CENTROID = slice(0, 2)


@dataclass(frozen=True)
class StatisticsChoice:
    """The outcome of :func:`choose_observed_statistics`.

    Attributes:
        name: the chosen value of `observed_statistics` ("shading" or "all").
        left_out_mse: per set tried, the mean left-out error (standardised trajectory units);
            empty when the test did not run.
        p_value: the one-sided p-value that "shading" predicts worse than "all" (None when the
            test did not run).
        reason: one line for the log and the model card.
    """

    name: str
    left_out_mse: dict[str, float]
    p_value: float | None
    reason: str


def _targets(demos: core_data.Demonstrations) -> np.ndarray:
    """(B, PHASES * D') the trajectories as regression targets
    (:func:`cnfmp.core.task_objects.standardised_targets`): position, rotation vector and
    gripper for poses, every column in joint space."""
    if demos.joint_names:
        return task_objects.motion_targets(demos)  # every joint and the gripper
    samples = task_objects.phase_samples(demos.trajectories, range(8))
    rotation = geometry.to_tangent(samples[..., 3:7], demos.trajectories[0][0, 3:7])
    return task_objects.standardised_targets(np.concatenate([samples[..., :3], rotation, samples[..., 7:]], axis=-1))


def _features(demos: core_data.Demonstrations, name: str) -> np.ndarray:
    """(B, F) every object's standardised centroid and statistics of the set `name`, and a
    centred presence indicator per object."""
    columns = []
    for slot in range(max(len(names) for names in demos.objects)):
        stats, present = task_objects.object_statistics(demos, slot)
        columns += [stats[:, CENTROID], stats[:, OBSERVED_COLUMNS[name]], (present - present.mean())[:, None]]
    return np.concatenate(columns, axis=1)


def choose_observed_statistics(demos: core_data.Demonstrations) -> StatisticsChoice:
    """Which mask statistics the motion reads (the test of this module's header). `demos`:
    trajectories as training reads them (aligned in time or not, task objects kept)."""
    if len(demos) < MIN_DEMOS:
        return StatisticsChoice(DEFAULT, {}, None, f"{DEFAULT} (fewer than {MIN_DEMOS} demonstrations to test "
                                                   "whether the rest helps)")
    targets = _targets(demos)
    errors = {name: task_objects.left_out_errors(_features(demos, name), targets) for name in (DEFAULT, RICHER)}
    means = {name: float(e.mean()) for name, e in errors.items()}
    p = task_objects.larger_p_value(errors[DEFAULT], errors[RICHER])
    figures = (f"left-out error {means[RICHER]:.3f} from every statistic against {means[DEFAULT]:.3f} from "
               f"the shading ones, p = {p:.2g}")
    if means[RICHER] < means[DEFAULT] and p < task_objects.SIGNIFICANCE:
        return StatisticsChoice(RICHER, means, p, f"{RICHER}: the masks' elongation, size and shaded offset "
                                                  f"predict left-out demonstrations significantly better ({figures})")
    return StatisticsChoice(DEFAULT, means, p, f"{DEFAULT}: the rest of the masks' statistics do not predict "
                                               f"left-out demonstrations significantly better ({figures})")


__all__ = ["MIN_DEMOS", "StatisticsChoice", "choose_observed_statistics"]
