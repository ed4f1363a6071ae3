"""The 3D compositional neural-field movement primitive (``cnfmp-3d``) in torch: the paper's
occupancy-field variant (§II, eq. 2 with occupancy).

Scene: object i has a latent z_i (a point on its simplex of learned endpoints, as in 2D), a
pose read from it (centre ``c(z) = anchor + W z``, anchored at the centroid of the object's
scan points, and a turn about the vertical by ``theta(z)``), a bounded anisotropic scale and
a bounded Lipschitz FiLM residual; its template, an MLP on the deformed coordinates, gives an
occupancy logit and a mask logit and never sees z. A background field sees the box
coordinates. The masks are the softmax of the mask logits (soft competition) and the scene's
occupancy is ``o(x) = sum_k M_k(x) sigmoid(occ_k(x))``.

Motion: a temporal mixture of experts over the objects' frames and the world's. Expert i
moves in object i's frame: its local movement primitive (affine in z_i and the object's
centre, on a Gaussian time basis) is turned by theta_i and carried to c_i; the world expert
is a fixed movement primitive (start and end poses that no object owns). The gates w(t) are
learned, as in 2D. Read in its object's frame, a pick follows the object wherever it stands
with nothing to learn about where: four demonstrations then determine the rest.

Coordinates inside the networks: box coordinates (the config's scene box is [-1, 1]^3);
positions of the motion: metres, then normalised as every model's (:mod:`cnfmp.core.motion`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from cnfmp.core.configuration_cnfmp3d import Cnfmp3dConfig
from cnfmp.core.layers import FilmMLP, LipschitzLinear, encoded_size, fourier_features, plain_mlp
from cnfmp.core.motion import MOTION_DIM, BasisGenerator, time_basis, time_basis_size
from cnfmp.errors import InputError

#: Largest turn (rad) of an object's frame about the vertical, largest relative scale change
#: per axis, largest residual displacement (box coordinates).
TURN_BOUND = math.pi / 2
SCALE_BOUND = 0.3
RESIDUAL_BOUND = 0.05


def turn_about_z(angle: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (..., 3, 3) about +z by `angle` (...,) rad."""
    cos, sin = torch.cos(angle), torch.sin(angle)
    zero, one = torch.zeros_like(angle), torch.ones_like(angle)
    return torch.stack([cos, -sin, zero, sin, cos, zero, zero, zero, one], dim=-1).view(*angle.shape, 3, 3)


class ObjectField3d(nn.Module):
    """One object's occupancy expert: a latent-conditioned pose and deformation in front of
    a fixed template. forward(coords (B, P, 3), latent (B, D), anchor (B, 3)) ->
    (occupancy logit (B, P), mask logit (B, P))."""

    def __init__(self, config: Cnfmp3dConfig):
        super().__init__()
        self.config = config
        d = config.latent_dim
        self.centre = LipschitzLinear(d, 3)
        self.turn = nn.Linear(d, 1)
        self.scale = nn.Linear(d, 3)
        self.deformation = FilmMLP(encoded_size(3, config.deformation_octaves), d, config.field_width // 2,
                                   2, 3, lipschitz=True)
        self.template = plain_mlp(encoded_size(3, config.template_octaves), config.field_width, config.field_layers, 2)
        with torch.no_grad():  # start as the anchor itself, unturned, unscaled
            for layer in (self.centre.linear, self.turn, self.scale):
                layer.weight.mul_(0.1)
                layer.bias.zero_()
            self.deformation.out.weight.zero_()
            self.deformation.out.bias.zero_()

    def pose(self, latent: torch.Tensor, anchor: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The object frame: centre (..., 3) box coordinates and turn (...,) rad, from
        latents (..., D) and anchors (..., 3)."""
        return anchor + self.centre(latent), TURN_BOUND * torch.tanh(self.turn(latent)[..., 0])

    def canonical(self, coords: torch.Tensor, latent: torch.Tensor, anchor: torch.Tensor) -> torch.Tensor:
        """Box coordinates (B, P, 3) -> template coordinates (B, P, 3):
        ``s(z) * R(theta(z))^T (x - c(z)) + r``, r the bounded residual."""
        centre, turn = self.pose(latent, anchor)
        local = torch.einsum("bji,bpj->bpi", turn_about_z(turn), coords - centre[:, None, :])
        scaled = local * (1.0 + SCALE_BOUND * torch.tanh(self.scale(latent)))[:, None, :]
        raw = self.deformation(fourier_features(scaled, self.config.deformation_octaves), latent)
        return scaled + RESIDUAL_BOUND * torch.tanh(raw / RESIDUAL_BOUND)

    def template_terms(self, canonical: torch.Tensor) -> torch.Tensor:
        """Template coordinates (..., 3) -> (occupancy logit, mask logit) (..., 2)."""
        return self.template(fourier_features(canonical, self.config.template_octaves))

    def forward(self, coords, latent, anchor, baked: "BakedTemplate | None" = None):
        canonical = self.canonical(coords, latent, anchor)
        out = self.template_terms(canonical) if baked is None else baked(canonical)
        return out[..., 0], out[..., 1]


class BakedTemplate:
    """A frozen template sampled once on a regular grid of template coordinates and read
    back by trilinear interpolation (nearest edge value outside): inference evaluates it at
    slowly moving coordinates for every start and step of the latent fit."""

    def __init__(self, field: ObjectField3d, lower: torch.Tensor, upper: torch.Tensor, spacing: float):
        """lower, upper (3,): the box of template coordinates; spacing: grid step (box units)."""
        counts = [max(2, int(math.ceil(float(upper[k] - lower[k]) / spacing)) + 1) for k in range(3)]
        axes = [torch.linspace(float(lower[k]), float(upper[k]), counts[k]) for k in range(3)]
        gz, gy, gx = torch.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
        grid = torch.stack([gx, gy, gz], dim=-1).reshape(-1, 3)
        with torch.no_grad():
            values = torch.cat([field.template_terms(chunk) for chunk in grid.split(65536)])
        #: (1, 2, Z, Y, X), as grid_sample reads a volume.
        self.volume = values.view(counts[2], counts[1], counts[0], 2).permute(3, 0, 1, 2)[None].contiguous()
        self.lower, self.extent = lower, upper - lower

    def __call__(self, canonical: torch.Tensor) -> torch.Tensor:
        """Template coordinates (B, P, 3) -> (occupancy logit, mask logit) (B, P, 2)."""
        b, p, _ = canonical.shape
        unit = 2.0 * (canonical - self.lower) / self.extent - 1.0
        out = F.grid_sample(self.volume, unit.reshape(1, b * p, 1, 1, 3), mode="bilinear", padding_mode="border",
                            align_corners=True)
        return out.view(2, b, p).permute(1, 2, 0)



@dataclass
class OccupancyRender:
    """The scene at a set of points (:meth:`Cnfmp3dModel.scene`): B scenes, N slots, P points."""

    #: The composite occupancy (B, P) in [0, 1].
    occupancy: torch.Tensor
    #: Occupancy logits (B, N + 1, P): per object slot, then the background.
    occupancy_logits: torch.Tensor
    #: The soft competition's logits (B, N + 1, P), ordered likewise.
    mask_logits: torch.Tensor

class Cnfmp3dModel(nn.Module):
    """Occupancy fields, latents and motion of one task (B scenes, N objects, K endpoints,
    D latent size, P points, T times)."""

    def __init__(self, config: Cnfmp3dConfig, num_demos: int):
        super().__init__()
        config.check()
        self.config = config
        n, k, d = config.num_objects, config.num_endpoints, config.latent_dim
        self.objects = nn.ModuleList([ObjectField3d(config) for _ in range(n)])
        self.background = plain_mlp(encoded_size(3, config.background_octaves), config.field_width,
                                    config.field_layers, 2)
        self.endpoints = nn.Parameter(0.5 * torch.randn(n, k, d))
        #: Simplex logits of each training demonstration (B_train, N, K): the first
        #: candidates of inference's search.
        self.demo_logits = nn.Parameter(0.3 * torch.randn(num_demos, n, k))
        time_in = time_basis_size(config)
        self.gating = plain_mlp(time_in, config.gating_width, 2, n + 1)
        #: Per object, its local movement primitive, read from its latent and centre.
        self.local_motion = nn.ModuleList([BasisGenerator(time_in, d + 3, MOTION_DIM) for _ in range(n)])
        #: The world expert's movement primitive (normalised position, rotation, gripper).
        self.world_motion = nn.Parameter(torch.zeros(time_in, MOTION_DIM))
        #: The gripper's rotation vector (in the reference frame) of a turn about world +z.
        reference = torch.tensor(config.reference_quat, dtype=torch.float32)
        self.register_buffer("vertical_axis", _rotate_inverse(reference, torch.tensor([0.0, 0.0, 1.0])))

    # ---- latents ----
    def latents(self, weights: torch.Tensor) -> torch.Tensor:
        """Simplex weights (B, N, K) -> object latents (B, N, D)."""
        return torch.einsum("bnk,nkd->bnd", weights, self.endpoints)

    def object_latent(self, slot: int, weights: torch.Tensor) -> torch.Tensor:
        """Weights (C, K) on slot `slot`'s simplex -> latents (C, D)."""
        return weights @ self.endpoints[slot]

    def poses(self, latents: torch.Tensor, anchors: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Latents (B, N, D), anchors (B, N, 3) -> centres (B, N, 3) box coordinates, turns (B, N) rad."""
        parts = [field.pose(latents[:, k], anchors[:, k]) for k, field in enumerate(self.objects)]
        return torch.stack([c for c, _ in parts], dim=1), torch.stack([t for _, t in parts], dim=1)

    # ---- scene ----
    def background_terms(self, coords: torch.Tensor) -> torch.Tensor:
        """Box coordinates (B, P, 3) -> (occupancy logit, mask logit) (B, P, 2)."""
        return self.background(fourier_features(coords, self.config.background_octaves))

    def scene(self, coords: torch.Tensor, latents: torch.Tensor, anchors: torch.Tensor) -> OccupancyRender:
        """The scene at `coords` (B, P, 3) box coordinates, for latents (B, N, D) and object
        anchors (B, N, 3)."""
        parts = [field(coords, latents[:, k], anchors[:, k]) for k, field in enumerate(self.objects)]
        background = self.background_terms(coords)
        occupancy_logits = torch.stack([o for o, _ in parts] + [background[..., 0]], dim=1)
        mask_logits = torch.stack([m for _, m in parts] + [background[..., 1]], dim=1)
        masks = torch.softmax(mask_logits, dim=1)
        return OccupancyRender(occupancy=(masks * torch.sigmoid(occupancy_logits)).sum(dim=1),
                               occupancy_logits=occupancy_logits, mask_logits=mask_logits)

    @staticmethod
    def expert_occupancy(object_terms: torch.Tensor, background_terms: torch.Tensor) -> torch.Tensor:
        """One object's expert against the background alone, the occupancy (..., P) in
        [0, 1] training and inference fit to the object's own samples; terms (..., P, 2)."""
        m = torch.sigmoid(object_terms[..., 1] - background_terms[..., 1])
        return m * torch.sigmoid(object_terms[..., 0]) + (1.0 - m) * torch.sigmoid(background_terms[..., 0])

    # ---- motion ----
    def gates(self, t: torch.Tensor) -> torch.Tensor:
        """Temporal gates (T,) -> (T, N + 1): the objects', then the world's; rows sum to one."""
        return torch.softmax(self.gating(time_basis(t, self.config)), dim=-1)

    def motion(self, t: torch.Tensor, latents: torch.Tensor, centres: torch.Tensor, turns: torch.Tensor) -> torch.Tensor:
        """Normalised times (T,), latents (B, N, D), object centres (B, N, 3) box coordinates
        and turns (B, N) rad -> generator outputs (B, T, 7): normalised position, rotation
        (tangent chart at the reference orientation), gripper."""
        c = self.config
        basis = time_basis(t, c)
        gates = self.gates(t)  # (T, N + 1)
        mean, std = torch.tensor(c.position_mean), torch.tensor(c.position_std)
        local_scale = float(np.mean(c.position_std))
        box_centre = torch.tensor(c.box_centre, dtype=torch.float32)
        world_position = box_centre + centres * c.box_half  # (B, N, 3) m
        rotation = torch.zeros(latents.shape[0], len(t), 3)
        position = torch.zeros(latents.shape[0], len(t), 3)
        gripper = torch.zeros(latents.shape[0], len(t))
        for k, generator in enumerate(self.local_motion):
            inputs = torch.cat([latents[:, k], centres[:, k]], dim=-1)
            local = generator(basis, inputs[:, None, :].expand(-1, len(t), -1))  # (B, T, 7)
            turned = torch.einsum("bij,btj->bti", turn_about_z(turns[:, k]), local[..., :3] * local_scale)
            w = gates[None, :, k, None]
            position = position + w * (world_position[:, k, None, :] + turned)
            rotation = rotation + w * (local[..., 3:6] + turns[:, k, None, None] * self.vertical_axis)
            gripper = gripper + w[..., 0] * local[..., 6]
        world = basis @ self.world_motion  # (T, 7)
        w = gates[None, :, -1, None]
        position = position + w * (world[None, :, :3] * std + mean)
        rotation = rotation + w * world[None, :, 3:6]
        gripper = gripper + w[..., 0] * world[None, :, 6]
        return torch.cat([(position - mean) / std, rotation, gripper[..., None]], dim=-1)

    def motion_penalty(self) -> torch.Tensor:
        """Mean squared latent-and-centre weight of the local movement primitives."""
        return torch.stack([g.sensitivity() for g in self.local_motion]).mean()

    def motion_parameters(self) -> list[nn.Parameter]:
        return list(self.gating.parameters()) + list(self.local_motion.parameters()) + [self.world_motion]

    def lipschitz_penalty(self) -> torch.Tensor:
        return torch.stack([f.deformation.lipschitz_bound() * f.centre.bound() for f in self.objects]).sum()

    @classmethod
    def from_state(cls, config: Cnfmp3dConfig, state: dict) -> "Cnfmp3dModel":
        """An untrained model shaped for the saved tensors `state` (its demonstration count)."""
        if "demo_logits" not in state:
            raise InputError("the weights have no demo_logits tensor; not a cnfmp-3d model")
        return cls(config, num_demos=state["demo_logits"].shape[0])

    def parameter_count(self) -> int:
        return sum(p.numel() for name, p in self.named_parameters() if name != "demo_logits")


def _rotate_inverse(quat_wxyz: torch.Tensor, vector: torch.Tensor) -> torch.Tensor:
    """R(q)^T v for a unit quaternion [w, x, y, z] (4,) and a vector (3,)."""
    w, xyz = quat_wxyz[0], -quat_wxyz[1:] / quat_wxyz.norm()
    w = w / quat_wxyz.norm()
    t = 2.0 * torch.linalg.cross(xyz, vector)
    return vector + w * t + torch.linalg.cross(xyz, t)


__all__ = ["BakedTemplate", "Cnfmp3dModel", "ObjectField3d", "turn_about_z"]
