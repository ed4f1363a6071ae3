"""Configuration fields every movement-primitive model of the core shares: what the
demonstrations say about the motion (filled in by training), the trajectory's time basis and
output rate, and the training run's seed and length.

The cnfmp model and the baselines (``configuration_cnn_cnmp``, ``configuration_nfmp``) all
derive from :class:`MotionConfig`, so trajectories are normalised, encoded and decoded the
same way by every method the benchmark compares.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from cnfmp.configuration import JsonConfig
from cnfmp.errors import InputError


#: The encodings of the rotation outputs (`MotionConfig.rotation_chart`).
ROTATION_CHARTS = ("tangent", "swing_twist")


@dataclass
class MotionConfig(JsonConfig):
    # ---- file format ----
    #: Version of the config format, written into every model's config.json: raised when a
    #: field changes its name or meaning, with an :meth:`~cnfmp.configuration.JsonConfig.upgrade`
    #: step from the version before or none (then older models are refused, to be retrained).
    #: A config.json without it was written before versions existed: version 1.
    config_version: int = 1

    # ---- what the demonstrations say about the motion (from data) ----
    #: Task the demonstrations came from (informative; the models themselves are task-agnostic).
    task: str = ""
    #: Trajectory duration (s): the longest demonstration; shorter ones are held at their end.
    duration_s: float = 0.0
    #: Orientation the rotation outputs are relative to, quaternion [w, x, y, z] (the first
    #: demonstration's start orientation).
    reference_quat: list[float] = field(default_factory=lambda: [1.0, 0.0, 0.0, 0.0])
    #: Per-axis mean and standard deviation (m) of the demonstrated positions; the models
    #: work in these normalised units.
    position_mean: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    position_std: list[float] = field(default_factory=lambda: [1.0, 1.0, 1.0])
    #: The joints of a joint-space model, as the recording names them (empty: the motion is
    #: an end-effector pose). A joint-space model learns and predicts these values and the
    #: gripper; the position and rotation fields above are then unused.
    joint_names: list[str] = field(default_factory=list)
    #: Per-joint mean and standard deviation over the demonstrations (the recording's units,
    #: e.g. rad): the model works in these normalised units. Empty for a pose model.
    joint_mean: list[float] = field(default_factory=list)
    joint_std: list[float] = field(default_factory=list)
    #: How the recording's motion vector maps onto the pose the model learns (see
    #: :mod:`cnfmp.data.recorded`): ``{"source", "names", "gripper_range": [low, high] or
    #: null}``. Predictions also come back in that form (``"recorded"`` in the trajectory
    #: JSON). Empty when the recording is the pose form itself (x y z qw qx qy qz gripper).
    recorded_motion: dict = field(default_factory=dict)
    #: The scene's own timing of the gripper-event segments, where training found it
    #: predictable (:class:`cnfmp.core.segment_timing.SegmentTiming` as a dict); empty: every
    #: prediction runs on the aligned demonstrations' median timing.
    segment_timing: dict = field(default_factory=dict)

    # ---- motion encoding ----
    #: How the generator's three rotation outputs encode an orientation relative to
    #: `reference_quat`: "tangent", the rotation vector log(R_ref^T R) (paper §II-B), or
    #: "swing_twist", [swing_x, swing_y, twist] with R_ref^T R = exp(swing) exp(twist about the
    #: fingers) (:func:`cnfmp.geometry.to_swing_twist`). The two agree while the fingers point
    #: where the reference's do; for a gripper that both tilts and turns, swing-twist keeps
    #: the tilt and the turn additive, which an affine generator can then read from different
    #: objects (incline: the ramp's slope and the block's yaw).
    rotation_chart: str = "tangent"
    #: Time basis of the motion: normalised Gaussian bumps spread evenly over the trajectory,
    #: this many per second of duration (at least 4 in all), each as wide as their spacing
    #: (the basis of classic movement primitives). Smooth by construction, so the motion
    #: cannot wiggle between the 10 Hz demonstration samples it is fit to.
    time_basis_per_second: float = 5.0
    #: Rate (Hz) of the decoded trajectory.
    output_fps: float = 50.0

    # ---- training ----
    #: Optimisation steps (one seeded run).
    steps: int = 2000
    #: Seed of the weights' initialisation and of every random draw of training.
    seed: int = 0

    def check(self, source: str = "config") -> None:
        if not isinstance(self.steps, int) or self.steps < 1:
            raise InputError(f"{source}: steps must be a whole number >= 1, got {self.steps!r}")
        if self.rotation_chart not in ROTATION_CHARTS:
            raise InputError(f"{source}: rotation_chart must be one of {', '.join(ROTATION_CHARTS)}, "
                             f"got {self.rotation_chart!r}")
        for name in ["output_fps", "time_basis_per_second"]:
            if not getattr(self, name) > 0:
                raise InputError(f"{source}: {name} must be > 0, got {getattr(self, name)!r}")

    @property
    def in_joint_space(self) -> bool:
        """Whether the model's motion is joint values + gripper rather than a pose."""
        return bool(self.joint_names)

    def fitted_to(self, demos) -> "MotionConfig":
        """This config with the "(from data)" motion fields filled in from `demos`
        (:class:`cnfmp.core.data.Demonstrations`)."""
        longest = max(len(traj) for traj in demos.trajectories)
        fitted = dataclasses.replace(self, task=demos.task, duration_s=(longest - 1) / demos.fps,
                                     recorded_motion=demos.recorded_motion(), joint_names=demos.joint_names)
        values = np.concatenate([traj[:, :-1] for traj in demos.trajectories])
        if demos.joint_names:
            # A joint that never moves keeps a unit spread, so it standardises to 0, not 0/0.
            return dataclasses.replace(fitted, joint_mean=[float(v) for v in values.mean(axis=0)],
                                       joint_std=[float(v) if v > 1e-6 else 1.0 for v in values.std(axis=0)])
        return dataclasses.replace(
            fitted, reference_quat=[float(v) for v in demos.trajectories[0][0, 3:7]],
            position_mean=[float(v) for v in values[:, :3].mean(axis=0)],
            position_std=[float(max(v, 1e-3)) for v in values[:, :3].std(axis=0)],
        )


__all__ = ["ROTATION_CHARTS", "MotionConfig"]
