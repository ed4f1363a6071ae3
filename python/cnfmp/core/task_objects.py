"""Which of a scene's labelled objects a task is about, chosen from its demonstrations.

A segmenter labels every object it finds, the task's first (the prompt's target and place)
and then whatever else stands on the table. A distractor given a slot of its own costs
training time and, worse, gives the motion inputs whose variation over 20 demonstrations it
can only memorise. Before training, each demonstration's trajectory (its position and
gripper) is predicted from the mask statistics (:data:`cnfmp.core.data.OBSERVATION_NAMES`,
plus presence) of its first 1, 2, ... objects by ridge regression, one demonstration left
out at a time. The first c objects are
kept, the others left to the background, when c objects predict the left-out trajectories
best on average and all of them predict significantly worse (a paired one-sided t-test
over the demonstrations, p < :data:`SIGNIFICANCE`). Otherwise every object keeps its slot.

The rule leans towards keeping objects, since a task object lost is a task failed and a
distractor kept only costs time: a relevant object is dropped only if predicting without it
is better on average than with it, which a linear effect of its position prevents; and a
distractor that happens to help the fit by chance (20 scenes, 11 statistics) keeps a slot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cnfmp.core import data as core_data

#: One-sided p-value below which all the objects' left-out error counts as worse than the
#: best count's.
SIGNIFICANCE = 0.05
#: Fewest demonstrations the choice is made on; with fewer, every object keeps its slot.
MIN_DEMOS = 6
#: Phase samples per trajectory that the regression predicts.
PHASES = 32
#: The trajectory dimensions predicted: position (x y z) and gripper. Not the rotation: the
#: grasp's turn follows an object's yaw, which its mask statistics do not carry linearly
#: (language_pick_place, 30 demonstrations: the left-out error of the rotation is its whole
#: variance with any number of objects), so it would only add noise to the comparison.
#: (A joint-space trajectory has no separate position: every joint and the gripper.)
TARGET_DIMS = (0, 1, 2, 7)
#: Ridge penalties tried (relative to the number of demonstrations; features standardised).
PENALTIES = (1e-2, 1e-1, 1.0, 10.0, 100.0)


@dataclass(frozen=True)
class TaskObjectChoice:
    """The outcome of :func:`choose_task_objects`.

    Attributes:
        count: objects kept (the first `count` labels); equal to `available` when all stay.
        available: objects the demonstrations label at most.
        left_out_mse: mean left-out error (standardised trajectory units) for 1..available objects.
        p_value: the one-sided p-value of the test of all the objects against the first
            `count` (None when every object keeps its slot).
        reason: one line for the log and the model card.
    """

    count: int
    available: int
    left_out_mse: tuple[float, ...]
    p_value: float | None
    reason: str

    @property
    def drops_objects(self) -> bool:
        return self.count < self.available

    def describe(self) -> str:
        """The reason and, where the test ran, the left-out error per count (one line)."""
        if not self.left_out_mse:
            return self.reason
        errors = ", ".join(f"{e:.3f}" for e in self.left_out_mse)
        return f"{self.reason}; left-out error for 1..{self.available} objects: {errors}"


def object_statistics(demos: core_data.Demonstrations, slot: int) -> tuple[np.ndarray, np.ndarray]:
    """Slot `slot`'s mask statistics in every demonstration, standardised over the
    demonstrations where the object is present: ((B, len(OBSERVATION_NAMES)) statistics, 0
    where absent; (B,) bool presence). A statistic that never varies is centred, not scaled."""
    stats = np.zeros((len(demos), len(core_data.OBSERVATION_NAMES)))
    present = np.zeros(len(demos), bool)
    for b in range(len(demos)):
        mask = demos.masks[b] == slot + 1
        if mask.any():
            stats[b] = core_data.observe_mask(demos.images[b], mask)
            present[b] = True
    if not present.any():
        return stats, present
    mean = stats[present].mean(axis=0)
    spread = stats[present].std(axis=0)
    spread[spread < 1e-9] = 1.0
    return np.where(present[:, None], (stats - mean) / spread, 0.0), present


def _features(demos: core_data.Demonstrations, count: int) -> np.ndarray:
    """(B, count * (len(OBSERVATION_NAMES) + 1)) the first `count` objects' standardised mask
    statistics (:func:`object_statistics`) and a centred presence indicator per object."""
    columns = []
    for slot in range(count):
        stats, present = object_statistics(demos, slot)
        columns += [stats, (present - present.mean())[:, None]]
    return np.concatenate(columns, axis=1)


def phase_samples(trajectories: list[np.ndarray], dims) -> np.ndarray:
    """(B, PHASES, len(dims)) each trajectory's columns `dims` at PHASES evenly spaced phases
    of its own duration."""
    samples = []
    for trajectory in trajectories:
        frames = np.linspace(0.0, len(trajectory) - 1, PHASES)
        samples.append(np.stack([np.interp(frames, np.arange(len(trajectory)), trajectory[:, d])
                                 for d in dims], axis=1))
    return np.asarray(samples)


def standardised_targets(samples: np.ndarray) -> np.ndarray:
    """Phase samples (B, PHASES, D) -> (B, PHASES * D') regression targets: centred per phase
    and dimension over the demonstrations and scaled per dimension by its spread over every
    phase and demonstration (so a dimension that barely varies at one phase does not turn its
    noise into unit variance); dimensions that never vary are left out."""
    spread = samples.reshape(-1, samples.shape[2]).std(axis=0)
    varying = spread > 1e-6
    centred = samples[:, :, varying] - samples[:, :, varying].mean(axis=0)
    return (centred / spread[varying]).reshape(len(samples), -1)


def motion_targets(demos: core_data.Demonstrations) -> np.ndarray:
    """(B, PHASES * D') the trajectories' TARGET_DIMS (every joint and the gripper in joint
    space) as :func:`standardised_targets`."""
    dims = range(demos.trajectories[0].shape[1]) if demos.joint_names else TARGET_DIMS
    return standardised_targets(phase_samples(demos.trajectories, dims))


def left_out_errors(features: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """(B,) each demonstration's squared error (mean over the targets) when a ridge fit with
    intercept on the others predicts it, at the penalty of PENALTIES that does best overall."""
    b = len(features)
    best = None
    for penalty in PENALTIES:
        errors = np.empty(b)
        for left in range(b):
            keep = np.arange(b) != left
            x, y = features[keep], targets[keep]
            x_mean, y_mean = x.mean(axis=0), y.mean(axis=0)
            xc = x - x_mean
            gram = xc.T @ xc + penalty * (b - 1) * np.eye(x.shape[1])
            coef = np.linalg.solve(gram, xc.T @ (y - y_mean))
            prediction = y_mean + (features[left] - x_mean) @ coef
            errors[left] = ((prediction - targets[left]) ** 2).mean()
        if best is None or errors.mean() < best.mean():
            best = errors
    return best


def larger_p_value(errors: np.ndarray, baseline: np.ndarray) -> float:
    """One-sided p-value of a paired t-test that `errors` (B,) are larger than `baseline`
    (B,) on average, over the same demonstrations; 1 when they never differ."""
    from scipy import stats

    difference = errors - baseline
    spread = difference.std(ddof=1)
    if spread <= 1e-12:
        return 1.0
    return float(stats.t.sf(difference.mean() / (spread / np.sqrt(len(difference))), df=len(difference) - 1))


def choose_task_objects(demos: core_data.Demonstrations) -> TaskObjectChoice:
    """How many of the demonstrations' labelled objects (in label order) the task is about,
    by the left-out test of this module's header. `demos`: trajectories as training reads
    them (aligned in time or not)."""
    available = max(len(names) for names in demos.objects)
    if available < 2 or len(demos) < MIN_DEMOS:
        why = "one object" if available < 2 else f"fewer than {MIN_DEMOS} demonstrations to test on"
        return TaskObjectChoice(available, available, (), None, f"every object kept ({why})")
    targets = motion_targets(demos)
    errors = [left_out_errors(_features(demos, count), targets) for count in range(1, available + 1)]
    means = tuple(float(e.mean()) for e in errors)
    best = int(np.argmin(means)) + 1
    if best < available:
        p = larger_p_value(errors[-1], errors[best - 1])  # all the objects against the best count
        if p < SIGNIFICANCE:
            return TaskObjectChoice(best, available, means, p,
                                    f"the first {best} of {available} objects kept: they predict left-out "
                                    f"demonstrations best, and all {available} significantly worse (p = {p:.2g})")
    return TaskObjectChoice(available, available, means, None,
                            f"all {available} objects kept: no smaller set predicts left-out demonstrations "
                            "significantly better")
