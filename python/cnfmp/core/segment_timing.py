"""Per-scene timing of a task's gripper-event segments.

Alignment (:mod:`cnfmp.core.alignment`) puts every demonstration's gripper events on the
median timeline, so the model learns phase-normalised motion. How long each segment takes
may still depend on the scene (a far object takes longer to reach), so training also fits a
ridge regression from the latents the motion reads (the scene as the model sees it) to each
segment's log duration, its strength chosen by leave-one-out cross-validation over the
demonstrations. It is kept only when it predicts the held-out demonstrations' durations
clearly better than one timing for every scene does; a pace that varies at random from
demonstration to demonstration (an operator's) is not learnable, and the median stays.
Predictions are re-timed piecewise-linearly from the median knots to the scene's own.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

#: Ridge strengths tried (on standardised features), weakest first.
RIDGE_STRENGTHS = tuple(np.logspace(-2, 4, 13))
#: A per-scene timing is kept when its leave-one-out error is below this share of the
#: error of one timing for all scenes.
KEEP_BELOW = 0.8
#: Fewest demonstrations with the task's number of events to fit a per-scene timing on.
MIN_DEMOS = 5
#: A prediction's segment durations are kept within the demonstrations' range widened by
#: this factor each way: a scene unlike every demonstration does not get an extrapolated pace.
RANGE_MARGIN = 1.25


@dataclass(frozen=True)
class SegmentTiming:
    """A fitted per-scene timing (shapes: F features, S segments).

    Attributes:
        knots_s: (S + 1,) the aligned timeline's knots: 0, the median event times, the end (s).
        feature_mean, feature_scale: (F,) standardisation of the motion latents.
        weights: (F, S) and bias (S,): standardised features -> log segment durations (s).
        low, high: (S,) the range a predicted duration is kept in (s).
        strength: the ridge strength chosen; loo_error_s, constant_error_s: leave-one-out RMS
            error of the segment durations (s), per scene and with one timing.
    """

    knots_s: list[float]
    feature_mean: list[float]
    feature_scale: list[float]
    weights: list[list[float]]
    bias: list[float]
    low: list[float]
    high: list[float]
    strength: float
    loo_error_s: float
    constant_error_s: float

    @classmethod
    def from_dict(cls, values: dict) -> "SegmentTiming":
        return cls(**values)

    def to_dict(self) -> dict:
        return asdict(self)

    def describe(self) -> str:
        return (f"per scene, {len(self.bias)} segment(s) from the motion latents (leave-one-out error "
                f"{self.loo_error_s:.3f} s against {self.constant_error_s:.3f} s for one timing)")

    def knots(self, features: np.ndarray) -> np.ndarray:
        """The scene's knots (S + 1,) in s, from its motion latents `features` (F,)."""
        standard = (np.asarray(features, np.float64) - self.feature_mean) / self.feature_scale
        durations = np.exp(standard @ np.asarray(self.weights) + self.bias)
        durations = np.clip(durations, self.low, self.high)
        return np.concatenate([[0.0], np.cumsum(durations)])


def _loo_ridge(features: np.ndarray, targets: np.ndarray, strength: float) -> tuple[np.ndarray, np.ndarray]:
    """Ridge regression of targets (B, S) on centred features (B, F) with an unpenalised
    intercept: (weights (F, S), leave-one-out predictions (B, S)), the latter from the hat
    matrix rather than B refits."""
    count = len(features)
    centred = targets - targets.mean(axis=0)
    solve = np.linalg.inv(features @ features.T + strength * np.eye(count))
    hat = features @ features.T @ solve  # of the centred part; the intercept adds 1 / B
    residual = centred - hat @ centred
    leverage = np.diag(hat) + 1.0 / count
    return features.T @ solve @ centred, targets - residual / (1.0 - leverage)[:, None]


def fit(features: np.ndarray, knots_s: np.ndarray, reference_knots_s: np.ndarray) -> SegmentTiming | None:
    """A per-scene timing, or None when one timing serves the demonstrations as well.

    Args:
        features: (B, F) the motion latents of B demonstrations (flattened over objects).
        knots_s: (B, S + 1) their knots as recorded: 0, each gripper event, the end (s).
        reference_knots_s: (S + 1,) the aligned timeline's knots (the medians).
    """
    features, knots_s = np.asarray(features, np.float64), np.asarray(knots_s, np.float64)
    durations = np.diff(knots_s, axis=1)
    if len(features) < MIN_DEMOS or (durations <= 0).any():
        return None
    mean = features.mean(axis=0)
    scale = features.std(axis=0)
    scale = np.where(scale > 1e-9, scale, 1.0)
    standard = (features - mean) / scale
    logs = np.log(durations)
    count = len(features)

    def rms(predicted_logs: np.ndarray) -> float:
        return float(np.sqrt(np.mean((np.exp(predicted_logs) - durations) ** 2)))

    constant = rms(logs.mean(axis=0) - (logs - logs.mean(axis=0)) / (count - 1))  # leave-one-out means
    errors = [(rms(_loo_ridge(standard, logs, strength)[1]), strength) for strength in RIDGE_STRENGTHS]
    error, strength = min(errors)
    if not error < KEEP_BELOW * constant:
        return None
    weights, _ = _loo_ridge(standard, logs, strength)
    low, high = durations.min(axis=0) / RANGE_MARGIN, durations.max(axis=0) * RANGE_MARGIN
    return SegmentTiming([float(v) for v in reference_knots_s], mean.tolist(), scale.tolist(), weights.tolist(),
                         logs.mean(axis=0).tolist(), low.tolist(), high.tolist(), float(strength), error, constant)


def retime(trajectory: dict, from_knots_s: np.ndarray, to_knots_s: np.ndarray, fps: float) -> dict:
    """A decoded trajectory (``{"t" (T,) s at `fps`, "position" (T, 3), "orientation" (T, 4)
    wxyz, "gripper" (T,)}``, or "joints" (T, J) in place of the pose) re-timed so that its
    time from_knots_s[k] falls at to_knots_s[k], linear in between and shifted after the last
    knot, resampled at `fps` (:func:`cnfmp.core.alignment.warp`, the warp alignment uses)."""
    from cnfmp.core.alignment import warp

    times = np.asarray(trajectory["t"], np.float64)
    end = times[-1] + (to_knots_s[-1] - from_knots_s[-1])
    poses = "orientation" in trajectory
    parts = ("position", "orientation", "gripper") if poses else ("joints", "gripper")
    columns = [np.asarray(trajectory[part], np.float64).reshape(len(times), -1) for part in parts]
    warped = warp(np.concatenate(columns, axis=1), np.append(from_knots_s, times[-1]) * fps,
                  np.append(to_knots_s, end) * fps, poses)
    out, start = {"t": np.arange(len(warped)) / fps}, 0
    for part, column in zip(parts, columns):
        out[part] = warped[:, start:start + column.shape[1]]
        start += column.shape[1]
    out["gripper"] = out["gripper"][:, 0]
    return out
