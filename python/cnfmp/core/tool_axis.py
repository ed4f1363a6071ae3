"""Whether the direction of the tool axis is read from one object's mask, chosen from the
demonstrations.

In the swing-twist chart (:func:`cnfmp.geometry.to_swing_twist`) a gripper's orientation is a
swing, where its finger axis points, and a twist about that axis. In most tasks the axis
points down all the time and only the twist follows an object's yaw. In some it tilts to meet
a surface whose pose the image shows (a ramp, a slanted shelf, a tilted container), and then
its direction is a function of that one object's pose. Read through the gated latents, that
function is learnt from as many scenes as there are demonstrations with a 16-dimensional
input per object, and the readout fits the demonstrations instead of the slope; read from the
ten statistics of the object's mask (:data:`cnfmp.core.data.OBSERVATION_NAMES`) by a movement
primitive of its own, it carries to new scenes (docs/experiments.md, "The tilt from the
ramp's mask statistics").

So before training, each demonstration's swing, sampled at fixed phases, is predicted by ridge
regression on one object's standardised mask statistics, one demonstration left out at a time,
for every object present in all of them. The object that predicts it best is chosen when its
left-out error is below :data:`MAX_ERROR_RATIO` of the error of predicting the others' mean,
significantly so (a paired one-sided t-test over the demonstrations, p <
:data:`cnfmp.core.task_objects.SIGNIFICANCE`). Otherwise, and when the axis barely turns at all
(:data:`MIN_SWING_RAD`), the swing stays with the latents like every other output.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cnfmp import geometry
from cnfmp.core import data as core_data
from cnfmp.core import task_objects

#: Fewest demonstrations the choice is made on; with fewer, the swing stays with the latents.
MIN_DEMOS = 6
#: Below this RMS spread of the swing over the demonstrations (rad; ~1 deg) there is nothing to
#: read: the axis points the same way in every demonstration.
MIN_SWING_RAD = np.radians(1.0)
#: An object is chosen only when its statistics at least halve the left-out error of the
#: demonstrations' mean swing (squared, so the error in angle falls by about 30%).
MAX_ERROR_RATIO = 0.5


@dataclass(frozen=True)
class ToolAxisChoice:
    """The outcome of :func:`choose_tool_axis_object`.

    Attributes:
        slot: the object slot (0-based) whose mask the swing is read from, or -1 for none.
        left_out_mse: per object slot, the mean left-out squared error of the swing (rad^2)
            from its statistics (None for a slot some demonstration lacks); empty when the
            test did not run.
        constant_mse: the left-out squared error of the others' mean swing (rad^2).
        reason: one line for the log and the model card.
    """

    slot: int
    left_out_mse: tuple[float | None, ...]
    constant_mse: float
    reason: str


def _swings(demos: core_data.Demonstrations) -> np.ndarray:
    """(B, PHASES, 2) each demonstration's swing (rad) relative to the first demonstration's
    start orientation, at :data:`cnfmp.core.task_objects.PHASES` evenly spaced phases of its
    own duration."""
    quats = task_objects.phase_samples(demos.trajectories, range(3, 7))
    return geometry.to_swing_twist(quats, demos.trajectories[0][0, 3:7])[..., :2]


def choose_tool_axis_object(demos: core_data.Demonstrations) -> ToolAxisChoice:
    """Which object's mask statistics the swing is read from (the test of this module's
    header). `demos`: pose trajectories (x y z qw qx qy qz gripper) as training reads them."""
    swings = _swings(demos)
    spread = float(np.sqrt(((swings - swings.mean(axis=0)) ** 2).sum(axis=-1).mean()))
    if spread < MIN_SWING_RAD:
        return ToolAxisChoice(-1, (), 0.0, f"the tool axis points the same way in every demonstration "
                                           f"(spread {np.degrees(spread):.2f} deg): read with the rest of the motion")
    if len(demos) < MIN_DEMOS:
        return ToolAxisChoice(-1, (), 0.0, f"the tool axis tilts, but fewer than {MIN_DEMOS} demonstrations "
                                           "to test which object it follows: read with the rest of the motion")
    targets = swings.reshape(len(demos), -1)
    count = len(demos)
    # Predicting the left-out demonstration by the others' mean: (x - mean_others) = (x - mean) * B / (B - 1).
    constant = ((targets - targets.mean(axis=0)) ** 2).mean(axis=1) * (count / (count - 1)) ** 2
    slots = max(len(names) for names in demos.objects)
    errors: list[np.ndarray | None] = []
    for slot in range(slots):
        stats, present = task_objects.object_statistics(demos, slot)
        errors.append(task_objects.left_out_errors(stats, targets) if present.all() else None)
    means = tuple(None if e is None else float(e.mean()) for e in errors)
    candidates = [k for k, e in enumerate(errors) if e is not None]
    if not candidates:
        return ToolAxisChoice(-1, means, float(constant.mean()), "the tool axis tilts, but no object is in every "
                                                                 "demonstration: read with the rest of the motion")
    best = min(candidates, key=lambda k: means[k])
    ratio = means[best] / max(float(constant.mean()), 1e-12)
    p = task_objects.larger_p_value(constant, errors[best])
    name = demos.objects[0][best] if best < len(demos.objects[0]) else f"object {best + 1}"
    figures = (f"left-out error {np.degrees(np.sqrt(means[best])):.1f} deg from its mask against "
               f"{np.degrees(np.sqrt(constant.mean())):.1f} deg from the mean, p = {p:.2g}")
    if ratio < MAX_ERROR_RATIO and p < task_objects.SIGNIFICANCE:
        return ToolAxisChoice(best, means, float(constant.mean()),
                              f"the tool axis follows slot {best + 1} ({name}): {figures}")
    return ToolAxisChoice(-1, means, float(constant.mean()),
                          f"no object's mask tells the tool axis well enough (best slot {best + 1}, {name}: "
                          f"{figures}): read with the rest of the motion")


__all__ = ["MAX_ERROR_RATIO", "MIN_DEMOS", "MIN_SWING_RAD", "ToolAxisChoice", "choose_tool_axis_object"]
