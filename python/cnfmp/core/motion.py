"""The motion side shared by the core's models: trajectories <-> normalised generator
targets, the Gaussian time basis, and the basis-function trajectory generator.

Time is normalised to [0, 1] inside models; files carry seconds. Generator outputs are
normalised position (config.position_mean / position_std), rotation (rad) relative to
config.reference_quat in the config's rotation_chart, and gripper opening; or, for a joint-
space model (config.joint_names), the normalised joint values (config.joint_mean /
joint_std) and the gripper. `config` is any
:class:`cnfmp.core.configuration_common.MotionConfig`.
"""

from __future__ import annotations

import time

import numpy as np
import torch
from torch import nn

from cnfmp import geometry
from cnfmp.core.configuration_common import MotionConfig

#: Outputs of a pose model's trajectory generator: position (3), rotation (3, in the config's
#: rotation_chart), gripper (1).
MOTION_DIM = 7


def motion_dim(config: MotionConfig) -> int:
    """Outputs of the config's trajectory generator: MOTION_DIM for a pose, or its joints + 1."""
    return len(config.joint_names) + 1 if config.in_joint_space else MOTION_DIM


def time_basis_size(config: MotionConfig) -> int:
    """Number of time basis functions: `time_basis_per_second` per second of the trajectory."""
    return max(4, int(round(config.time_basis_per_second * config.duration_s)))


def time_basis(t: torch.Tensor, config: MotionConfig) -> torch.Tensor:
    """Normalised Gaussian basis of normalised time: (T,) in [0, 1] -> (T, M), rows summing
    to one; centres evenly spaced over [0, 1], widths equal to the spacing."""
    m = time_basis_size(config)
    centres = torch.linspace(0.0, 1.0, m, dtype=t.dtype)
    width = 1.0 / (m - 1)
    bumps = torch.exp(-0.5 * ((t[:, None] - centres) / width) ** 2)
    return bumps / bumps.sum(dim=-1, keepdim=True)


class BasisGenerator(nn.Module):
    """Trajectory generator G(t | z): a movement primitive whose basis weights are FiLM-
    modulated by the latent, ``G(t | z) = sum_m phi_m(t) (a_m + B_m z)``: phi the Gaussian
    time basis, a_m (out,) the mean weights, B_m (out, D) the latent's shift of basis m.

    For every t the output is affine in z, hence in each object's simplex weights, so the
    motion interpolates between demonstrations the way the latents do; and z acts only
    through the time-local basis, so a latent moves the motion where it matters and leaves
    the fixed start pose alone. forward(basis (T, M), z (B, T, D)) -> (B, T, out_dim).
    """

    def __init__(self, basis_size: int, latent_dim: int, out_dim: int):
        super().__init__()
        self.mean = nn.Parameter(torch.zeros(basis_size, out_dim))
        self.latent_weights = nn.Parameter(0.01 * torch.randn(basis_size, out_dim, latent_dim))

    def sensitivity(self) -> torch.Tensor:
        """Mean squared latent weight: the penalty that keeps the motion's response to the
        latent no larger than the demonstrations need."""
        return (self.latent_weights ** 2).mean()

    def forward(self, basis: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        shift = torch.einsum("tm,mod,btd->bto", basis, self.latent_weights, z)
        return (basis @ self.mean)[None] + shift


def _rotation_chart(config: MotionConfig):
    """(to_chart, from_chart) of the config's rotation_chart (see MotionConfig)."""
    if config.rotation_chart == "swing_twist":
        return geometry.to_swing_twist, geometry.from_swing_twist
    return geometry.to_tangent, geometry.from_tangent


def trajectory_targets(trajectory: np.ndarray, config: MotionConfig) -> np.ndarray:
    """(T, 8) ``x y z qw qx qy qz gripper`` -> (T, 7) generator targets; in joint space
    (T, J + 1) joints + gripper -> the same, the joints standardised."""
    if config.in_joint_space:
        joints = (trajectory[:, :-1] - np.asarray(config.joint_mean)) / np.asarray(config.joint_std)
        return np.concatenate([joints, trajectory[:, -1:]], axis=1)
    pos = (trajectory[:, :3] - np.asarray(config.position_mean)) / np.asarray(config.position_std)
    rot = _rotation_chart(config)[0](trajectory[:, 3:7], config.reference_quat)
    return np.concatenate([pos, rot, trajectory[:, 7:8]], axis=1)


def decode_trajectory(outputs: np.ndarray, config: MotionConfig) -> dict:
    """(T, 7) generator outputs -> ``{"t" (T,) s, "position" (T, 3) m, "orientation" (T, 4)
    wxyz, "gripper" (T,) in [0, 1]}`` on the config's output grid; in joint space (T, J + 1)
    -> ``{"t", "joints" (T, J) in the recording's units, "gripper"}``."""
    steps = outputs.shape[0]
    if config.in_joint_space:
        return {"t": np.arange(steps) / config.output_fps,
                "joints": outputs[:, :-1] * np.asarray(config.joint_std) + np.asarray(config.joint_mean),
                "gripper": np.clip(outputs[:, -1], 0.0, 1.0)}
    return {
        "t": np.arange(steps) / config.output_fps,
        "position": outputs[:, :3] * np.asarray(config.position_std) + np.asarray(config.position_mean),
        "orientation": _rotation_chart(config)[1](outputs[:, 3:6], config.reference_quat),
        "gripper": np.clip(outputs[:, 6], 0.0, 1.0),
    }


def output_times(config: MotionConfig) -> np.ndarray:
    """Normalised times of the decoded trajectory: every 1/output_fps s over duration_s."""
    steps = int(round(config.duration_s * config.output_fps)) + 1
    return np.arange(steps) / config.output_fps / config.duration_s


def demonstration_targets(trajectories: list[np.ndarray], fps: float, config: MotionConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """Every demonstration's generator targets on one common frame grid.

    Args:
        trajectories: per demonstration (T_b, 8) ``x y z qw qx qy qz gripper`` (in joint
            space (T_b, J + 1)) at `fps`.
        config: a config fitted to the demonstrations (its duration_s is the longest).

    Returns (targets (B, F, motion_dim) float32, normalised frame times (F,)); a shorter demonstration
    holds its last pose to the end.
    """
    frames = int(round(config.duration_s * fps)) + 1
    targets = []
    for trajectory in trajectories:
        t = trajectory_targets(trajectory, config)
        targets.append(np.concatenate([t, np.repeat(t[-1:], frames - len(t), axis=0)]))
    times = torch.arange(frames, dtype=torch.float32) / (frames - 1)
    return torch.from_numpy(np.stack(targets).astype(np.float32)), times


def motion_loss(config, outputs: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
    """Weighted mean squared error of generator outputs (..., 7) against targets (..., 7):
    position, rotation and gripper weighted by the config's ``position_weight``,
    ``rotation_weight`` and ``gripper_weight``. In joint space (..., J + 1): the standardised
    joints weighted as positions are (both are standardised units), the gripper as a gripper."""
    err = (outputs - targets) ** 2
    if config.in_joint_space:
        return config.position_weight * err[..., :-1].mean() + config.gripper_weight * err[..., -1].mean()
    return (config.position_weight * err[..., :3].mean() + config.rotation_weight * err[..., 3:6].mean()
            + config.gripper_weight * err[..., 6].mean())


class LossLog:
    """The loss history of a training run: a progress line every ~5% of the steps (through
    `log`, when given) and the final losses, the mean over the last such window."""

    def __init__(self, steps: int, names: list[str], log=None):
        self.steps, self.names, self.log = steps, names, log
        self.every = max(1, steps // 20)
        self.history: list[list[float]] = []
        self.started = time.monotonic()

    def record(self, step: int, values: list[float], extra: str = "") -> None:
        """Losses of step `step` (0-based), in the order of `names`; `extra` joins the line."""
        self.history.append(values)
        if self.log and (step % self.every == 0 or step == self.steps - 1):
            recent = np.mean(self.history[-self.every:], axis=0)
            elapsed = time.monotonic() - self.started
            losses = "  ".join(f"{name} {value:.5f}" for name, value in zip(self.names, recent))
            self.log(f"step {step + 1}/{self.steps}  {losses}  {extra + '  ' if extra else ''}{elapsed:.0f}s elapsed, "
                     f"~{elapsed / (step + 1) * (self.steps - step - 1):.0f}s left")

    def final(self) -> dict[str, float]:
        return dict(zip(self.names, (float(v) for v in np.mean(self.history[-self.every:], axis=0))))

    def seconds(self) -> float:
        return round(time.monotonic() - self.started, 1)
