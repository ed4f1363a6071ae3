"""The compositional neural-field movement primitive (paper §II-B) in torch.

Scene: an object-centric spatial mixture of experts. Object i has a latent z_i, a deformation
field Delta_i(x | z_i) and an appearance field F_i evaluated at x_i = x - Delta_i(x | z_i); a
background field F_bg sees x itself. Every field also emits a mask logit, and the masks are the
softmax over the object and background logits (soft competition):
``I(x) = sum_i M_i F_i(x_i) + M_bg F_bg(x)``.

Latent relabeling: z_i is a convex combination of `num_endpoints` learned endpoint latents of
object i; a demonstration (or a new scene) is a point on each object's simplex.

Motion: ``z(t) = sum_i w_i(t) z_i`` with ``w(t) = softmax(s(t))`` from a learned relevance
network, and a generator ``G(t | z(t))`` (a movement primitive on a Gaussian time basis whose
basis weights the latent shifts, FiLM-style) outputs normalised position, rotation
(tangent-space axis-angle at the config's reference orientation) and gripper.

Each appearance field F_i sees only its template coordinates x_i and the object's observed
colour (the median colour under its coarse mask), never z_i: one expert covers a red, green
or blue cube, and every geometric difference between scenes must go through the deformation,
so the latent carries geometry. The deformation's translation is anchored to the centroid of
the coarse mask: it is that centroid plus a small latent offset (kept small by the centre
prior), and the motion reads the centroid itself beside the latent, with the mask statistics of
`observed_statistics` (by default where the image inside the mask is darker, which tells a
pose the template's turn cannot).
With `tool_axis_object` (chosen by training), the direction of the tool axis bypasses the
latents: its own movement primitive reads that object's mask statistics alone (rotation in
the swing-twist chart, whose swing is the tilt of the finger axis).

Coordinates are image coordinates in [-1, 1]^2 (x right, y down); time is normalised to [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from cnfmp.core.configuration_cnfmp import CnfmpConfig
from cnfmp.core.data import OBSERVATION_NAMES
from cnfmp.core.layers import (FilmMLP, LipschitzLinear, encoded_size, fourier_features, plain_mlp,
                               regular_grid)
from cnfmp.core.motion import BasisGenerator, motion_dim, time_basis, time_basis_size
from cnfmp.errors import InputError

#: Largest entry of an object deformation's linear part A(z) (turns up to ~50 deg, scale
#: changes up to ~+-50%), and largest residual displacement (image coordinates in [-1, 1]:
#: 0.15 is about 5 px at 64 px).
LINEAR_BOUND = 0.8
RESIDUAL_BOUND = 0.15
STRETCH_BOUND = 0.3
#: Statistics of the tool-axis object that the tilt readout reads: all its observations
#: (:attr:`cnfmp.core.data.SceneInputs.observations`, :data:`cnfmp.core.data.OBSERVATION_NAMES`).
TILT_FEATURES = len(OBSERVATION_NAMES)
#: The columns of the observations that each value of the config's `observed_statistics`
#: lets the motion read beside the centroid (columns 0-1).
_FIRST = OBSERVATION_NAMES.index("dark_dx")
OBSERVED_COLUMNS = {"centroid": slice(_FIRST, _FIRST), "shading": slice(_FIRST, OBSERVATION_NAMES.index("luminance") + 1),
                    "all": slice(_FIRST, len(OBSERVATION_NAMES))}


def observed_width(config: CnfmpConfig) -> int:
    """How many of each object's mask statistics the motion reads beside its centroid."""
    if config.observed_statistics is None:
        raise InputError("observed_statistics is null: training chooses it (cnfmp train); a model needs a value")
    columns = OBSERVED_COLUMNS[config.observed_statistics]
    return columns.stop - columns.start


class ObjectField(nn.Module):
    """One spatial expert: a latent-conditioned deformation and a fixed appearance template.

    Canonical coordinates ``x_i = (I + A(z)) (x - c(z)) + r(x - c(z) | z)``, i.e.
    ``Delta(x | z) = x - x_i``: c(z) is the object's centre in the image (linear in z, so a
    convex combination of latents moves the object along the line between their centres),
    A(z) a bounded linear map for turns and scale (or, with `full_turns`, a similarity linear
    in z times a bounded stretch), r a low-frequency FiLM
    residual for what neither captures (slopes, heights, perspective). The appearance F and
    mask logit depend on x_i and the object's observed colour only, never on z (paper eq. 2):
    every difference between scenes has to be explained by moving the template, which is
    what makes the latent geometric and lets it generalise from a few demonstrations.

    forward(coords (B, P, 2), latent (B, D), colour (B, 3), progress) ->
    (rgb (B, P, 3) in [0, 1], mask logit (B, P), canonical coords (B, P, 2)).
    """

    def __init__(self, config: CnfmpConfig):
        super().__init__()
        self.config = config
        self.centre = LipschitzLinear(config.latent_dim, 2)
        self.linear = nn.Linear(config.latent_dim, 4)
        self.deformation = FilmMLP(encoded_size(2, config.deformation_octaves), config.latent_dim, config.field_width,
                                   config.field_layers, 2, lipschitz=True)
        self.appearance = FilmMLP(encoded_size(2, config.appearance_octaves), 3, config.field_width,
                                  config.field_layers, 4)
        with torch.no_grad():  # start as a pure translation
            self.linear.weight.mul_(0.1)
            self.linear.bias.zero_()
            self.deformation.out.weight.zero_()
            self.deformation.out.bias.zero_()
            self.centre.linear.bias.zero_()
            self.centre.linear.weight.mul_(0.1)  # an offset from the centroid: start near none

    def object_centre(self, latent: torch.Tensor, anchor: torch.Tensor) -> torch.Tensor:
        """The object's centre ``c = anchor + W z + b`` in image coordinates: latent (..., D)
        and the centroid of its coarse mask `anchor` (..., 2) -> (..., 2). The latent only
        shifts the template off the centroid (a tall object's centroid is not where its base
        is)."""
        return anchor + self.centre(latent)

    def canonical(self, coords: torch.Tensor, latent: torch.Tensor, anchor: torch.Tensor,
                  coarse: "CoarseResidual | None" = None) -> torch.Tensor:
        """Image coordinates (B, P, 2) -> the template's coordinates x_i (B, P, 2).

        The linear part and the residual are bounded (entries of A within +-LINEAR_BOUND,
        residual within +-RESIDUAL_BOUND): unbounded, the residual learns to undo the
        translation and the template stops following the object. With `coarse` (built for
        these `coords`), the residual is evaluated on its grid and interpolated. `anchor` (B, 2):
        the mask centroids."""
        centre = self.object_centre(latent, anchor)
        local = coords - centre[:, None, :]
        raw = self.linear(latent)
        if self.config.full_turns:
            # A similarity (any turn, any scale) linear in z, times a bounded stretch.
            u, v, a, b = raw.unbind(dim=-1)
            similarity = torch.stack([1.0 + u, -v, v, 1.0 + u], dim=-1).view(-1, 2, 2)
            a, b = STRETCH_BOUND * torch.tanh(a), STRETCH_BOUND * torch.tanh(b)
            stretch = torch.stack([1.0 + a, b, b, 1.0 - a], dim=-1).view(-1, 2, 2)
            matrix = similarity @ stretch
        else:
            matrix = torch.eye(2, dtype=coords.dtype) + LINEAR_BOUND * torch.tanh(raw.view(-1, 2, 2))
        warped = torch.einsum("bij,bpj->bpi", matrix, local)

        def residual_at(offsets: torch.Tensor) -> torch.Tensor:
            raw = self.deformation(fourier_features(offsets, self.config.deformation_octaves), latent)
            return RESIDUAL_BOUND * torch.tanh(raw / RESIDUAL_BOUND)

        return warped + (residual_at(local) if coarse is None else coarse(residual_at, centre))

    def appearance_terms(self, canonical: torch.Tensor, colour: torch.Tensor, progress=None) -> torch.Tensor:
        """The appearance field at template coordinates (B, P, 2) for colours (B, 3): raw
        outputs (B, P, 4), rgb logits then the mask logit."""
        return self.appearance(fourier_features(canonical, self.config.appearance_octaves, progress), colour)

    def forward(self, coords, latent, colour, anchor, progress=None, baked: "BakedAppearance | None" = None,
                coarse: "CoarseResidual | None" = None):
        """Coordinates (B, P, 2), latent (B, D), colour (B, 3) and mask centroid `anchor`
        (B, 2) -> (rgb (B, P, 3), mask logit (B, P), canonical coordinates (B, P, 2))."""
        canonical = self.canonical(coords, latent, anchor, coarse)
        out = self.appearance_terms(canonical, colour, progress) if baked is None else baked(canonical)
        return torch.sigmoid(out[..., :3]), out[..., 3], canonical


class BakedAppearance:
    """A frozen object's appearance field for one colour, sampled once on a regular grid of
    template coordinates and read back by bilinear interpolation.

    Inference evaluates the same frozen template at slowly moving coordinates for every step
    of every start; a lookup replaces the positional encoding and the MLP (forward and
    backward), which are most of a refinement step's cost. Outside the grid the nearest edge
    value is used, so the box should cover the coordinates the fit will visit.
    """

    def __init__(self, field: ObjectField, colour: torch.Tensor, lower: torch.Tensor, upper: torch.Tensor,
                 spacing: float):
        """colour (3,); lower, upper (2,): corners of the box in template coordinates;
        spacing: grid step in template coordinates (image coordinates in [-1, 1])."""
        grid, rows, columns = regular_grid(lower, upper, spacing)
        with torch.no_grad():
            values = field.appearance_terms(grid[None], colour[None])
        #: (1, 4, rows, columns): rows follow y, columns x, as grid_sample reads them.
        self.texture = values.view(1, rows, columns, 4).permute(0, 3, 1, 2).contiguous()
        self.lower, self.extent = lower, upper - lower

    def __call__(self, canonical: torch.Tensor) -> torch.Tensor:
        """Template coordinates (B, P, 2) -> raw appearance outputs (B, P, 4)."""
        b, p, _ = canonical.shape
        unit = 2.0 * (canonical - self.lower) / self.extent - 1.0
        out = F.grid_sample(self.texture, unit.reshape(1, b * p, 1, 2), mode="bilinear", padding_mode="border",
                            align_corners=True)
        return out.view(4, b, p).permute(1, 2, 0)


class CoarseResidual:
    """Evaluates an object's deformation residual on a regular grid of image points over the
    box of a fixed set of pixels, and interpolates it bilinearly at those pixels.

    The residual is low-frequency (few octaves, bounded), so a grid a few pixels apart
    carries it; inference's refinement runs the deformation network on that grid instead of
    on every fitted pixel at every step. Gradients flow through the interpolation.
    """

    def __init__(self, coords: torch.Tensor, spacing: float):
        """coords (1, P, 2): the fitted pixels (image coordinates); spacing: grid step (image
        coordinates)."""
        lower = coords[0].min(dim=0).values
        extent = torch.clamp(coords[0].max(dim=0).values - lower, min=1e-6)
        points, self.rows, self.columns = regular_grid(lower, lower + extent, spacing)
        #: (1, G, 2) grid points, rows following y.
        self.points = points[None]
        #: Where the pixels fall on the grid, as grid_sample reads it: (1, P, 1, 2) in [-1, 1].
        self.unit = (2.0 * (coords - lower) / extent - 1.0)[:, :, None, :]

    @property
    def size(self) -> int:
        return self.points.shape[1]

    def __call__(self, residual_at, centre: torch.Tensor) -> torch.Tensor:
        """`residual_at` maps offsets from the object centre (B, G, 2) to residuals (B, G, 2);
        centre (B, 2) -> residuals at the pixels (B, P, 2)."""
        b = centre.shape[0]
        values = residual_at(self.points - centre[:, None, :])
        grid = values.view(b, self.rows, self.columns, 2).permute(0, 3, 1, 2)
        out = F.grid_sample(grid, self.unit.expand(b, -1, -1, -1), mode="bilinear", align_corners=True)
        return out[..., 0].transpose(1, 2)


@dataclass
class SceneRender:
    """A rendered scene (:meth:`CnfmpModel.scene`): B scenes, N object slots, P pixels."""

    #: The composite image (B, P, 3).
    rgb: torch.Tensor
    #: Each object's own colour field (B, N, P, 3).
    object_rgb: torch.Tensor
    #: The background's colour field (B, P, 3).
    background_rgb: torch.Tensor
    #: The soft competition's logits (B, N + 1, P): the objects' then the background's (an
    #: absent object's at -1e4).
    logits: torch.Tensor
    #: Their softmax over the slots (B, N + 1, P): each pixel's share per object and background.
    masks: torch.Tensor
    #: Each object's template coordinates at the pixels (B, N, P, 2).
    canonical: torch.Tensor


class CnfmpModel(nn.Module):
    """Scene fields, latents and motion of one task (shapes: B scenes, N objects, K endpoints,
    D latent size, P pixels, T times)."""

    def __init__(self, config: CnfmpConfig, num_demos: int):
        super().__init__()
        config.check()
        self.config = config
        n, k, d = config.num_objects, config.num_endpoints, config.latent_dim
        self.objects = nn.ModuleList([ObjectField(config) for _ in range(n)])
        self.background = plain_mlp(encoded_size(2, config.background_octaves), config.field_width,
                                    config.field_layers, 4)
        self.endpoints = nn.Parameter(0.5 * torch.randn(n, k, d))
        self.absent = nn.Parameter(0.5 * torch.randn(n, d))
        #: Simplex logits of each training demonstration (B_train, N, K); kept in the model
        #: file as the first candidates of inference's search.
        self.demo_logits = nn.Parameter(0.3 * torch.randn(num_demos, n, k))
        time_in = time_basis_size(config)
        self.gating = plain_mlp(time_in, config.gating_width, 2, n)
        self.generator = BasisGenerator(time_in, d, motion_dim(config))
        #: The inverse camera map's denominator: a centroid (u, v) is on the table at a
        #: position affine in ``(u, v, 1) / (1 + h . (u, v))``.
        self.table_projection = nn.Parameter(torch.zeros(2))
        #: How each object's table position enters its latent for the motion: (N, D, 3).
        self.position_embedding = nn.Parameter(0.5 * torch.randn(n, d, 3))
        statistics = observed_width(config)
        if statistics:
            #: How each object's observed mask statistics enter its latent for the motion:
            #: (N, D, S), S the columns of `observed_statistics`.
            self.statistics_embedding = nn.Parameter(0.5 * torch.randn(n, d, statistics))
        if config.tool_axis_slot >= 0:
            #: Mean and spread of the tool-axis object's statistics over the training
            #: demonstrations, which standardise them: (TILT_FEATURES,) each.
            self.register_buffer("tilt_mean", torch.zeros(TILT_FEATURES))
            self.register_buffer("tilt_std", torch.ones(TILT_FEATURES))
            #: The gripper's swing (2 rotation outputs) over time, from those statistics alone.
            self.tilt_generator = BasisGenerator(time_in, TILT_FEATURES, 2)

    # ---- latents ----
    def latents(self, weights: torch.Tensor, present: torch.Tensor) -> torch.Tensor:
        """Simplex weights (B, N, K) and presence (B, N) bool -> object latents (B, N, D)."""
        z = torch.einsum("bnk,nkd->bnd", weights, self.endpoints)
        return torch.where(present[..., None], z, self.absent[None].expand_as(z))

    def object_centres(self, latents: torch.Tensor, anchors: torch.Tensor) -> torch.Tensor:
        """Object latents (B, N, D) and mask centroids (B, N, 2) -> template centres c(z_i)
        (B, N, 2), image coordinates."""
        return torch.stack([field.object_centre(latents[:, k], anchors[:, k])
                            for k, field in enumerate(self.objects)], dim=1)

    def motion_latents(self, latents: torch.Tensor, observations: torch.Tensor | None,
                       present: torch.Tensor | None):
        """The latents the motion reads (B, N, D): each present object's latent plus its
        embedded table position, from its mask centroid, and its embedded mask statistics of
        `observed_statistics`, from its observations (B, N, len(OBSERVATION_NAMES),
        :attr:`cnfmp.core.data.SceneInputs.observations`)."""
        if observations is None:
            raise ValueError("the motion reads the masks' observations: pass them")
        anchors = observations[..., :2]
        homogeneous = torch.cat([anchors, torch.ones_like(anchors[..., :1])], dim=-1)
        table = homogeneous / (1.0 + anchors @ self.table_projection)[..., None]
        observed = torch.einsum("ndk,bnk->bnd", self.position_embedding, table)
        if observed_width(self.config):
            statistics = observations[..., OBSERVED_COLUMNS[self.config.observed_statistics]]
            observed = observed + torch.einsum("ndk,bnk->bnd", self.statistics_embedding, statistics)
        if present is not None:
            observed = observed * present[..., None]
        return latents + observed

    @staticmethod
    def weight_spread(weights: torch.Tensor) -> torch.Tensor:
        """Squared distance of simplex weights (..., K) from the simplex centre -> (...,): the
        weight prior, the same in training and inference."""
        return ((weights - 1.0 / weights.shape[-1]) ** 2).sum(dim=-1)

    def object_latent(self, slot: int, weights: torch.Tensor) -> torch.Tensor:
        """Weights (C, K) on slot `slot`'s simplex -> latents (C, D)."""
        return weights @ self.endpoints[slot]

    # ---- scene ----
    def background_terms(self, coords: torch.Tensor, progress=None) -> tuple[torch.Tensor, torch.Tensor]:
        out = self.background(fourier_features(coords, self.config.background_octaves, progress))
        return torch.sigmoid(out[..., :3]), out[..., 3]

    def scene(self, coords, latents, colours, present, anchors, progress=None, map_objects=map) -> SceneRender:
        """Renders the scene at `coords` (B, P, 2) for object latents (B, N, D), colours
        (B, N, 3), presence (B, N) bool and mask centroids `anchors` (B, N, 2). `map_objects`
        maps the per-object rendering over the slots (inference passes a thread pool's map to
        render objects in parallel)."""
        rendered = map_objects(lambda slot: self.objects[slot](coords, latents[:, slot], colours[:, slot],
                                                               anchors[:, slot], progress),
                               range(len(self.objects)))
        return self.composite(list(rendered), present, self.background_terms(coords, progress))

    @staticmethod
    def composite(rendered: list[tuple], present: torch.Tensor, background: tuple) -> SceneRender:
        """The scene of :meth:`scene` from its parts: per slot the (rgb (B, P, 3), mask logit
        (B, P), canonical (B, P, 2)) an object field returns, presence (B, N) bool, and the
        background's (rgb (B, P, 3), logit (B, P))."""
        rgbs, logits, canonicals = [], [], []
        for slot, (rgb, logit, canonical) in enumerate(rendered):
            rgbs.append(rgb)
            logits.append(torch.where(present[:, slot, None], logit, torch.full_like(logit, -1e4)))
            canonicals.append(canonical)
        bg_rgb, bg_logit = background
        all_logits = torch.stack(logits + [bg_logit], dim=1)
        masks = torch.softmax(all_logits, dim=1)
        all_rgb = torch.stack(rgbs + [bg_rgb], dim=1)
        return SceneRender(rgb=(masks[..., None] * all_rgb).sum(dim=1), object_rgb=torch.stack(rgbs, dim=1),
                           background_rgb=bg_rgb, logits=all_logits, masks=masks,
                           canonical=torch.stack(canonicals, dim=1))

    @staticmethod
    def expert_image(object_rgb, object_logit, bg_rgb, bg_logit) -> torch.Tensor:
        """One object's expert against the background alone (the per-object reconstruction
        that training and inference fit to the object's masked region): (..., P, 3)."""
        m = torch.sigmoid(object_logit - bg_logit)[..., None]
        return m * object_rgb + (1.0 - m) * bg_rgb

    # ---- motion ----
    def gates(self, t: torch.Tensor, present: torch.Tensor | None = None) -> torch.Tensor:
        """Temporal gating weights w(t): (T,) -> (T, N), rows summing to one (constant and
        equal without temporal gating). With presence (B, N) bool, where a scene lacks an
        object: (B, T, N), the absent objects at zero and the present ones sharing one (one
        time profile could not serve scenes with and without an object: cup stacking's third
        cup)."""
        scores = self.gating(time_basis(t, self.config))
        if not self.config.temporal_gating:
            scores = torch.zeros_like(scores)
        # Every object present: the plain (T, N) weights.
        if present is None or bool(present.all()):
            return torch.softmax(scores, dim=-1)
        return torch.softmax(torch.where(present[:, None, :], scores[None], float("-inf")), dim=-1)

    def motion(self, t: torch.Tensor, latents: torch.Tensor, present: torch.Tensor | None = None,
               observations: torch.Tensor | None = None) -> torch.Tensor:
        """Normalised times (T,), object latents (B, N, D), their presence (B, N) bool and
        their masks' observations (B, N, len(OBSERVATION_NAMES)) -> generator outputs
        (B, T, 7): normalised position, rotation (rad, in the config's rotation_chart),
        gripper."""
        if self.training:  # the trajectory loss does not shape the latents (VERSION_5_RETIRED)
            latents = latents.detach()
        latents = self.motion_latents(latents, observations, present)
        gates = self.gates(t, present)
        z_t = torch.einsum("tn,bnd->btd" if gates.dim() == 2 else "btn,bnd->btd", gates, latents)  # (B, T, D)
        basis = time_basis(t, self.config)
        outputs = self.generator(basis, z_t)
        if self.config.tool_axis_slot < 0:
            return outputs
        # The tilt readout's swing replaces the shared generator's (whose weights for those two
        # outputs then go unused: one generator for every model keeps the rest uniform).
        features = (self.tilt_statistics(observations, present) - self.tilt_mean) / self.tilt_std
        swing = self.tilt_generator(basis, features[:, None].expand(-1, len(t), -1))
        return torch.cat([outputs[..., :3], swing, outputs[..., 5:]], dim=-1)

    def tilt_statistics(self, observations: torch.Tensor | None, present: torch.Tensor | None) -> torch.Tensor:
        """The tool-axis object's mask statistics (B, TILT_FEATURES), unstandardised, from the
        objects' observations (B, N, TILT_FEATURES)."""
        slot = self.config.tool_axis_slot
        if observations is None:
            raise ValueError("a model with tool_axis_object needs the masks' observations")
        if present is not None and not bool(present[:, slot].all()):
            names = self.config.object_names
            name = f" ({names[slot]})" if slot < len(names) else ""
            raise InputError(f"the scene has no object {slot + 1}{name}, whose mask the tool axis is read from")
        return observations[:, slot]

    def motion_penalty(self) -> torch.Tensor:
        """Mean squared latent (and tilt-statistic) weight of the motion's generators: the
        penalty, weighted by `generator_weight_decay`, that keeps the motion's response to
        its inputs no larger than the demonstrations need."""
        penalty = self.generator.sensitivity()
        if self.config.tool_axis_slot >= 0:
            penalty = penalty + self.tilt_generator.sensitivity()
        return penalty

    def motion_parameters(self) -> list[nn.Parameter]:
        """The parameters that map object latents (and positions and mask statistics, and
        the tool-axis object's statistics) to the motion."""
        extra = [self.table_projection, self.position_embedding]
        if observed_width(self.config):
            extra.append(self.statistics_embedding)
        if self.config.tool_axis_slot >= 0:
            extra += list(self.tilt_generator.parameters())
        return list(self.gating.parameters()) + list(self.generator.parameters()) + extra

    def lipschitz_penalty(self) -> torch.Tensor:
        bounds = [field.deformation.lipschitz_bound() * field.centre.bound() for field in self.objects]
        return torch.stack(bounds).sum()

    @classmethod
    def from_state(cls, config: CnfmpConfig, state: dict) -> "CnfmpModel":
        """An untrained model shaped for the saved tensors `state` (its demonstration count).
        Renames in `state` the tensor that config version 3 called ``shading_embedding``."""
        if "demo_logits" not in state:
            raise InputError("the weights have no demo_logits tensor; not a cnfmp model")
        if "shading_embedding" in state:
            state["statistics_embedding"] = state.pop("shading_embedding")
        return cls(config, num_demos=state["demo_logits"].shape[0])

    def parameter_count(self, include_demos: bool = False) -> int:
        return sum(p.numel() for name, p in self.named_parameters() if include_demos or name != "demo_logits")
