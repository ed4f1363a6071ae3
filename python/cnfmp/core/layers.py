"""Building blocks of the coordinate networks (neural fields) shared by the core's models:
positional encoding, FiLM-modulated MLPs, Lipschitz-bounded linear layers, the pixel grid and
regular grids over a box.

Coordinates are image coordinates in [-1, 1]^2 (x right, y down).
"""

from __future__ import annotations

import functools
import math

import torch
from torch import nn
from torch.nn import functional as F


def fourier_features(x: torch.Tensor, octaves: int, progress: float | None = None) -> torch.Tensor:
    """Positional encoding ``[x, sin(2^k pi x), cos(2^k pi x)]_{k < octaves}``.

    x: (..., d) -> (..., d * (1 + 2 * octaves)). With `progress` in [0, 1], octave k is faded in
    as progress * octaves passes k (coarse-to-fine annealing); None means all on.
    """
    if octaves == 0:
        return x
    freqs = _octave_frequencies(octaves, x.dtype, x.device)
    angles = x[..., None, :] * freqs[:, None]  # (..., L, d)
    enc = torch.cat([torch.sin(angles), torch.cos(angles)], dim=-1)
    if progress is not None:
        ramp = torch.clamp(progress * octaves - torch.arange(octaves, dtype=x.dtype, device=x.device), 0.0, 1.0)
        enc = enc * (0.5 - 0.5 * torch.cos(math.pi * ramp))[:, None]
    return torch.cat([x, enc.flatten(-2)], dim=-1)


@functools.lru_cache(maxsize=64)
def _octave_frequencies(octaves: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """``2^k pi`` for k < octaves, (octaves,): built once per kind, not at every call."""
    return (2.0 ** torch.arange(octaves, dtype=dtype, device=device)) * math.pi


def encoded_size(dim: int, octaves: int) -> int:
    return dim * (1 + 2 * octaves)


class LipschitzLinear(nn.Module):
    """Linear layer whose infinity-norm is capped by a learned bound softplus(c), the
    per-layer Lipschitz constant of Liu et al. (2022); the product of the bounds is the penalty."""

    def __init__(self, fan_in: int, fan_out: int):
        super().__init__()
        self.linear = nn.Linear(fan_in, fan_out)
        with torch.no_grad():
            initial = self.linear.weight.abs().sum(dim=1).max()
        self.raw_bound = nn.Parameter(torch.log(torch.expm1(initial)))

    def bound(self) -> torch.Tensor:
        return F.softplus(self.raw_bound)

    def capped_weight(self) -> torch.Tensor:
        """The weight with its rows scaled so that its infinity-norm is at most the bound."""
        row_norms = self.linear.weight.abs().sum(dim=1)
        scale = torch.clamp(self.bound() / row_norms, max=1.0)
        return self.linear.weight * scale[:, None]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if torch.is_grad_enabled() and (self.linear.weight.requires_grad or self.raw_bound.requires_grad):
            return F.linear(x, self.capped_weight(), self.linear.bias)
        # Frozen (inference): the capped weight is the same at every call until the
        # parameters change in place, which bumps their version counters.
        key = (self.linear.weight._version, self.raw_bound._version, self.linear.weight.data_ptr())
        if getattr(self, "_frozen", (None,))[0] != key:
            with torch.no_grad():
                self._frozen = (key, self.capped_weight())
        return F.linear(x, self._frozen[1], self.linear.bias)


class FilmMLP(nn.Module):
    """Coordinate MLP whose hidden layers are modulated by a condition vector (FiLM):
    ``h <- relu((1 + gamma_l(c)) * (W_l h + b_l) + beta_l(c))``.

    forward(x: (B or 1, P, in_dim), c: (B, cond_dim)) -> (B, P, out_dim). With `lipschitz`, the
    condition-to-modulation network is built from :class:`LipschitzLinear` layers.
    """

    def __init__(self, in_dim: int, cond_dim: int, width: int, layers: int, out_dim: int, lipschitz: bool = False):
        super().__init__()
        self.hidden = nn.ModuleList([nn.Linear(in_dim if k == 0 else width, width) for k in range(layers)])
        linear = LipschitzLinear if lipschitz else nn.Linear
        self.film = nn.Sequential(linear(cond_dim, width), nn.SiLU(), linear(width, 2 * width * layers))
        self.out = nn.Linear(width, out_dim)
        self.width, self.layers = width, layers
        with torch.no_grad():  # start as the unmodulated network
            last = self.film[2].linear if lipschitz else self.film[2]
            last.weight.mul_(0.1)
            last.bias.zero_()

    def lipschitz_bound(self) -> torch.Tensor:
        """Product of the modulation layers' bounds (1 when not Lipschitz-constrained)."""
        bounds = [m.bound() for m in self.film if isinstance(m, LipschitzLinear)]
        return torch.stack(bounds).prod() if bounds else torch.ones(())

    def forward(self, x: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        mod = self.film(cond).view(cond.shape[0], self.layers, 2, self.width)
        h = x.expand(cond.shape[0], -1, -1) if x.shape[0] != cond.shape[0] else x
        for k, layer in enumerate(self.hidden):
            # (1 + gamma) (W h + b) + beta as one batched product per scene: the modulation
            # is folded into that scene's weights and bias, so the pixel-sized tensors see a
            # single matrix product and the ReLU (most of a training step is elementwise
            # passes over them).
            scale = 1.0 + mod[:, k, 0]  # (B, W)
            weight = scale[:, :, None] * layer.weight  # (B, W, in)
            bias = (scale * layer.bias + mod[:, k, 1])[:, None, :]  # (B, 1, W)
            h = F.relu(torch.baddbmm(bias, h, weight.transpose(1, 2)))
        return self.out(h)


def plain_mlp(in_dim: int, width: int, layers: int, out_dim: int) -> nn.Sequential:
    parts: list[nn.Module] = []
    for k in range(layers):
        parts += [nn.Linear(in_dim if k == 0 else width, width), nn.ReLU()]
    return nn.Sequential(*parts, nn.Linear(width, out_dim))


def pixel_coords(resolution: int) -> torch.Tensor:
    """(R * R, 2) centres of the pixels in row-major order, as (x, y) in [-1, 1]."""
    centres = (torch.arange(resolution, dtype=torch.float32) + 0.5) / resolution * 2.0 - 1.0
    y, x = torch.meshgrid(centres, centres, indexing="ij")
    return torch.stack([x.reshape(-1), y.reshape(-1)], dim=-1)


def regular_grid(lower: torch.Tensor, upper: torch.Tensor, spacing: float) -> tuple[torch.Tensor, int, int]:
    """A regular grid over the box [lower, upper] (corners (2,), x then y) whose points are at
    most `spacing` apart along each axis, at least two per axis: points (rows * columns, 2)
    in row-major order (rows follow y), rows, columns."""
    counts = [max(2, int(math.ceil(float(upper[k] - lower[k]) / spacing)) + 1) for k in range(2)]
    xs, ys = (torch.linspace(float(lower[k]), float(upper[k]), counts[k]) for k in range(2))
    gy, gx = torch.meshgrid(ys, xs, indexing="ij")
    return torch.stack([gx.reshape(-1), gy.reshape(-1)], dim=-1), counts[1], counts[0]
