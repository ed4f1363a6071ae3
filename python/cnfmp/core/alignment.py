"""Temporal alignment of demonstrations by their gripper transitions (paper §III-B).

People demonstrate at their own pace: one grasps after 2 s, another after 3.5 s. Before
training, each demonstration is warped piecewise-linearly in time so that its gripper closing
and opening events, and its end, fall at the median times of the demonstrations with the same
number of events; the model then learns one timing per task and the predicted trajectory runs
on those median segment durations, in seconds. Demonstrations with another number of events
than the others (a task with variants, or a fumbled grasp) are aligned among their own kind
and reported.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

#: Hysteresis of the event detector on the gripper opening (0 closed, 1 open): a closing
#: event when the opening falls below CLOSE_BELOW, an opening event when it rises above
#: OPEN_ABOVE again, so sensor noise around one threshold makes no extra events.
CLOSE_BELOW, OPEN_ABOVE = 0.35, 0.65


def gripper_events(gripper: np.ndarray) -> list[int]:
    """Frame indices where the gripper (T,) opening in [0, 1] closes or opens, in order
    (the first frame of the new state); the state starts as the first frame's."""
    closed = bool(gripper[0] < 0.5)
    events = []
    for frame, value in enumerate(gripper):
        if not closed and value < CLOSE_BELOW:
            closed = True
            events.append(frame)
        elif closed and value > OPEN_ABOVE:
            closed = False
            events.append(frame)
    return events


@dataclass
class Alignment:
    """What :func:`align_demonstrations` did.

    Attributes:
        events: per demonstration, its event frames before alignment.
        groups: per event count, ``{"demos": [indices], "event_times_s": [median times],
            "duration_s": median duration}``.
        majority: the most common event count (the task's).
        moved_s: per demonstration, the largest shift of an event or end it needed (s).
    """

    events: list[list[int]]
    groups: dict[int, dict]
    majority: int
    moved_s: list[float]

    def outliers(self) -> list[int]:
        """Demonstrations whose number of events differs from the majority's."""
        return [b for b, e in enumerate(self.events) if len(e) != self.majority]

    def describe(self) -> str:
        """One line for logs and the model card."""
        group = self.groups[self.majority]
        times = ", ".join(f"{t:.2f}" for t in group["event_times_s"]) or "none"
        line = (f"{len(group['demos'])} demonstrations with {self.majority} gripper event(s) at {times} s, "
                f"{group['duration_s']:.2f} s long (largest shift {max(self.moved_s):.2f} s)")
        others = self.outliers()
        if others:
            line += f"; {len(others)} with another count aligned among themselves (demonstrations {', '.join(map(str, others))})"
        return line


def _warp(trajectory: np.ndarray, source_knots: np.ndarray, target_knots: np.ndarray) -> np.ndarray:
    """`trajectory` (T, 8) resampled at whole frames 0..target_knots[-1] so that its frame
    source_knots[k] lands on target_knots[k], linear in between (quaternion part renormalised)."""
    frames = np.arange(int(round(target_knots[-1])) + 1, dtype=np.float64)
    source = np.interp(frames, target_knots, source_knots)
    low = np.clip(np.floor(source).astype(int), 0, len(trajectory) - 1)
    high = np.minimum(low + 1, len(trajectory) - 1)
    weight = (source - low)[:, None]
    quat_low, quat_high = trajectory[low, 3:7], trajectory[high, 3:7]
    quat_high = np.where(np.sum(quat_low * quat_high, axis=1, keepdims=True) < 0, -quat_high, quat_high)
    out = (1 - weight) * trajectory[low] + weight * trajectory[high]
    quat = (1 - weight) * quat_low + weight * quat_high
    out[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    return out


def align_demonstrations(trajectories: list[np.ndarray], fps: float) -> tuple[list[np.ndarray], Alignment]:
    """Warps every (T_b, 8) ``x y z qw qx qy qz gripper`` trajectory at `fps` so that its gripper
    events and its end fall at the median frames of its group (the demonstrations with the
    same number of events). Returns (aligned trajectories, :class:`Alignment`)."""
    events = [gripper_events(t[:, 7]) for t in trajectories]
    counts = Counter(len(e) for e in events)
    majority = max(counts, key=lambda count: (counts[count], -count))
    aligned: list[np.ndarray | None] = [None] * len(trajectories)
    moved = [0.0] * len(trajectories)
    groups = {}
    for count in sorted(counts):
        members = [b for b, e in enumerate(events) if len(e) == count]
        knots = np.array([[0, *events[b], len(trajectories[b]) - 1] for b in members], np.float64)
        target = np.median(knots, axis=0)
        for b, source in zip(members, knots):
            aligned[b] = _warp(trajectories[b], source, target)
            moved[b] = float(np.abs(source - target).max()) / fps
        groups[count] = {"demos": members, "event_times_s": [float(t) / fps for t in target[1:-1]],
                         "duration_s": float(target[-1]) / fps}
    return aligned, Alignment(events, groups, majority, moved)
