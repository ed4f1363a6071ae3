"""Temporal alignment of demonstrations by their gripper transitions (paper §III-B).

People demonstrate at their own pace: one grasps after 2 s, another after 3.5 s. Before
training, each demonstration is warped piecewise-linearly in time so that its gripper closing
and opening events, and its end, fall at the median times of the demonstrations with the same
number of events; the model then learns phase-normalised motion, and the predicted trajectory
runs on the median segment durations, in seconds, or on the scene's own where training finds
them predictable from the scene (:mod:`cnfmp.core.segment_timing`). Demonstrations with another number of events
than the others (a task with variants, or a fumbled grasp) are aligned among their own kind
and reported.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

def event_thresholds(grippers: list[np.ndarray]) -> tuple[float, float]:
    """The event detector's hysteresis band (close below, open above) for gripper openings
    in [0, 1]: the threshold that best splits all the values of `grippers` (list of (T,))
    into a closed and an open level (Otsu's criterion: most variance between the two), give
    or take a quarter of the gap between the levels' means.

    Read from the data because grippers settle where the task puts them: a cup grasp
    reopens only to 0.55 to clear the next cup, a grasp on a thick object closes to 0.4,
    and fixed thresholds would miss those events. A band rather than one threshold, so
    sensor noise around it makes no extra events. A gripper that never moves gives (-1, 2):
    no events."""
    values = np.sort(np.concatenate([np.asarray(g, np.float64).ravel() for g in grippers]))
    if len(values) < 2 or values[-1] - values[0] < 1e-6:
        return -1.0, 2.0
    # Between-class variance of every split between consecutive values.
    prefix = np.cumsum(values)
    count = np.arange(1, len(values))
    low_mean = prefix[:-1] / count
    high_mean = (prefix[-1] - prefix[:-1]) / (len(values) - count)
    between = count * (len(values) - count) * (high_mean - low_mean) ** 2
    between[values[1:] - values[:-1] <= 0] = -1.0  # only splits between distinct values
    split = int(np.argmax(between))
    threshold = 0.5 * (values[split] + values[split + 1])
    band = 0.25 * (high_mean[split] - low_mean[split])
    return threshold - band, threshold + band


def gripper_events(gripper: np.ndarray, thresholds: tuple[float, float] | None = None) -> list[int]:
    """Frame indices where the gripper (T,) opening in [0, 1] closes (falls below
    thresholds[0]) or opens (rises above thresholds[1]), in order (the first frame of the new
    state); the state starts as the first frame's. `thresholds` default: this signal's own
    (:func:`event_thresholds`)."""
    close_below, open_above = thresholds or event_thresholds([gripper])
    closed = bool(gripper[0] < 0.5 * (close_below + open_above))
    events = []
    for frame, value in enumerate(gripper):
        if not closed and value < close_below:
            closed = True
            events.append(frame)
        elif closed and value > open_above:
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
        knots_s: per demonstration, its knots before alignment: 0, its events, its end (s).
    """

    events: list[list[int]]
    groups: dict[int, dict]
    majority: int
    moved_s: list[float]
    knots_s: list[list[float]]

    def timing(self) -> "RecordedTiming":
        """The majority's timeline and each of its demonstrations' own knots."""
        group = self.groups[self.majority]
        return RecordedTiming([0.0, *group["event_times_s"], group["duration_s"]],
                              [self.knots_s[b] if len(e) == self.majority else None for b, e in enumerate(self.events)])

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


@dataclass(frozen=True)
class RecordedTiming:
    """How the demonstrations were timed before alignment, for learning a per-scene timing
    (:mod:`cnfmp.core.segment_timing`).

    Attributes:
        reference_knots_s: the aligned timeline of the task's number of events: 0, the median
            event times, the median end (s).
        demo_knots_s: per demonstration its own knots as recorded (s), or None for one with
            another number of events.
    """

    reference_knots_s: list[float]
    demo_knots_s: list[list[float] | None]


def warp(trajectory: np.ndarray, source_knots: np.ndarray, target_knots: np.ndarray, poses: bool) -> np.ndarray:
    """`trajectory` (T, D) resampled at whole frames 0..target_knots[-1] so that its frame
    source_knots[k] lands on target_knots[k], linear in between (with `poses`, D = 8 and the
    quaternion part is renormalised; else every column is interpolated as it is)."""
    frames = np.arange(int(round(target_knots[-1])) + 1, dtype=np.float64)
    source = np.interp(frames, target_knots, source_knots)
    low = np.clip(np.floor(source).astype(int), 0, len(trajectory) - 1)
    high = np.minimum(low + 1, len(trajectory) - 1)
    weight = (source - low)[:, None]
    out = (1 - weight) * trajectory[low] + weight * trajectory[high]
    if not poses:
        return out
    quat_low, quat_high = trajectory[low, 3:7], trajectory[high, 3:7]
    quat_high = np.where(np.sum(quat_low * quat_high, axis=1, keepdims=True) < 0, -quat_high, quat_high)
    quat = (1 - weight) * quat_low + weight * quat_high
    out[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    return out


def align_demonstrations(trajectories: list[np.ndarray], fps: float, poses: bool = True) -> tuple[list[np.ndarray], Alignment]:
    """Warps every trajectory at `fps` so that its gripper events and its end fall at the
    median frames of its group (the demonstrations with the same number of events), the
    events detected with one band for all of them (:func:`event_thresholds`). Trajectories
    are (T_b, 8) ``x y z qw qx qy qz gripper`` with `poses`, else (T_b, D) joint values with
    the gripper last. Returns (aligned trajectories, :class:`Alignment`)."""
    thresholds = event_thresholds([t[:, -1] for t in trajectories])
    events = [gripper_events(t[:, -1], thresholds) for t in trajectories]
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
            aligned[b] = warp(trajectories[b], source, target, poses)
            moved[b] = float(np.abs(source - target).max()) / fps
        groups[count] = {"demos": members, "event_times_s": [float(t) / fps for t in target[1:-1]],
                         "duration_s": float(target[-1]) / fps}
    knots_s = [[0.0, *(frame / fps for frame in e), (len(t) - 1) / fps] for e, t in zip(events, trajectories)]
    return aligned, Alignment(events, groups, majority, moved, knots_s)
