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
the coarse mask (the centre prior), and is a projective function of the latent, as the camera
sees the table.

Coordinates are image coordinates in [-1, 1]^2 (x right, y down); time is normalised to [0, 1].
"""

from __future__ import annotations

import math
import os

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from cnfmp import geometry
from cnfmp.core.configuration_cnfmp import CnfmpConfig
from cnfmp.errors import InputError

#: Outputs of the trajectory generator: position (3), rotation vector (3), gripper (1).
MOTION_DIM = 7
#: Largest entry of an object deformation's linear part A(z) (turns up to ~50 deg, scale
#: changes up to ~+-50%), and largest residual displacement (image coordinates in [-1, 1]:
#: 0.15 is about 5 px at 64 px).
LINEAR_BOUND = 0.8
RESIDUAL_BOUND = 0.15


def fourier_features(x: torch.Tensor, octaves: int, progress: float | None = None) -> torch.Tensor:
    """Positional encoding ``[x, sin(2^k pi x), cos(2^k pi x)]_{k < octaves}``.

    x: (..., d) -> (..., d * (1 + 2 * octaves)). With `progress` in [0, 1], octave k is faded in
    as progress * octaves passes k (coarse-to-fine annealing); None means all on.
    """
    if octaves == 0:
        return x
    freqs = (2.0 ** torch.arange(octaves, dtype=x.dtype, device=x.device)) * math.pi
    angles = x[..., None, :] * freqs[:, None]  # (..., L, d)
    enc = torch.cat([torch.sin(angles), torch.cos(angles)], dim=-1)
    if progress is not None:
        ramp = torch.clamp(progress * octaves - torch.arange(octaves, dtype=x.dtype, device=x.device), 0.0, 1.0)
        enc = enc * (0.5 - 0.5 * torch.cos(math.pi * ramp))[:, None]
    return torch.cat([x, enc.flatten(-2)], dim=-1)


def encoded_size(dim: int, octaves: int) -> int:
    return dim * (1 + 2 * octaves)


def time_basis_size(config: CnfmpConfig) -> int:
    """Number of time basis functions: `time_basis_per_second` per second of the trajectory."""
    return max(4, int(round(config.time_basis_per_second * config.duration_s)))


def time_basis(t: torch.Tensor, config: CnfmpConfig) -> torch.Tensor:
    """Normalised Gaussian basis of normalised time: (T,) in [0, 1] -> (T, M), rows summing
    to one; centres evenly spaced over [0, 1], widths equal to the spacing."""
    m = time_basis_size(config)
    centres = torch.linspace(0.0, 1.0, m, dtype=t.dtype)
    width = 1.0 / (m - 1)
    bumps = torch.exp(-0.5 * ((t[:, None] - centres) / width) ** 2)
    return bumps / bumps.sum(dim=-1, keepdim=True)


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

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        row_norms = self.linear.weight.abs().sum(dim=1)
        scale = torch.clamp(self.bound() / row_norms, max=1.0)
        return F.linear(x, self.linear.weight * scale[:, None], self.linear.bias)


class FilmMLP(nn.Module):
    """Coordinate MLP whose hidden layers are modulated by a condition vector (FiLM):
    ``h <- relu((1 + gamma_l(c)) * (W_l h + b_l) + beta_l(c))``.

    forward(x: (B, P, in_dim), c: (B, cond_dim)) -> (B, P, out_dim). With `lipschitz`, the
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
        h = x
        for k, layer in enumerate(self.hidden):
            gamma, beta = mod[:, k, 0, None, :], mod[:, k, 1, None, :]
            h = F.relu((1.0 + gamma) * layer(h) + beta)
        return self.out(h)


def plain_mlp(in_dim: int, width: int, layers: int, out_dim: int) -> nn.Sequential:
    parts: list[nn.Module] = []
    for k in range(layers):
        parts += [nn.Linear(in_dim if k == 0 else width, width), nn.ReLU()]
    return nn.Sequential(*parts, nn.Linear(width, out_dim))


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


class ObjectField(nn.Module):
    """One spatial expert: a latent-conditioned deformation and a fixed appearance template.

    Canonical coordinates ``x_i = (I + A(z)) (x - c(z)) + r(x - c(z) | z)``, i.e.
    ``Delta(x | z) = x - x_i``: c(z) is the object's centre in the image (linear in z, so a
    convex combination of latents moves the object along the line between their centres),
    A(z) a small linear map for turns and scale (linear in z), r a low-frequency FiLM
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
        self.perspective = nn.Parameter(torch.zeros(config.latent_dim))
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

    def object_centre(self, latent: torch.Tensor) -> torch.Tensor:
        """The object's centre c(z) in image coordinates: (..., D) -> (..., 2).

        A projective function of the latent, ``c(z) = (W z + b) exp(-g . z)``, the way a
        camera sees positions on the table: the latent can then hold the object's position
        linearly in the world, which is what the (affine) motion needs, while the image
        position follows the perspective."""
        return self.centre(latent) * torch.exp(-(latent @ self.perspective))[..., None]

    def canonical(self, coords: torch.Tensor, latent: torch.Tensor) -> torch.Tensor:
        """Image coordinates (B, P, 2) -> the template's coordinates x_i (B, P, 2).

        The linear part and the residual are bounded (entries of A within +-LINEAR_BOUND,
        residual within +-RESIDUAL_BOUND): unbounded, the residual learns to undo the
        translation and the template stops following the object."""
        local = coords - self.object_centre(latent)[:, None, :]
        matrix = torch.eye(2, dtype=coords.dtype) + LINEAR_BOUND * torch.tanh(self.linear(latent).view(-1, 2, 2))
        warped = torch.einsum("bij,bpj->bpi", matrix, local)
        residual = self.deformation(fourier_features(local, self.config.deformation_octaves), latent)
        return warped + RESIDUAL_BOUND * torch.tanh(residual / RESIDUAL_BOUND)

    def forward(self, coords, latent, colour, progress=None):
        canonical = self.canonical(coords, latent)
        out = self.appearance(fourier_features(canonical, self.config.appearance_octaves, progress), colour)
        return torch.sigmoid(out[..., :3]), out[..., 3], canonical


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
        self.generator = BasisGenerator(time_in, d, MOTION_DIM)

    # ---- latents ----
    def latents(self, weights: torch.Tensor, present: torch.Tensor) -> torch.Tensor:
        """Simplex weights (B, N, K) and presence (B, N) bool -> object latents (B, N, D)."""
        z = torch.einsum("bnk,nkd->bnd", weights, self.endpoints)
        return torch.where(present[..., None], z, self.absent[None].expand_as(z))

    def object_centres(self, latents: torch.Tensor) -> torch.Tensor:
        """Object latents (B, N, D) -> template centres c(z_i) (B, N, 2), image coordinates."""
        return torch.stack([field.object_centre(latents[:, k]) for k, field in enumerate(self.objects)], dim=1)

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

    def scene(self, coords, latents, colours, present, progress=None) -> dict:
        """Renders the scene at `coords` (B, P, 2).

        Returns ``{"rgb": (B, P, 3) composite, "object_rgb": (B, N, P, 3), "logits":
        (B, N + 1, P) object logits then background (absent objects at -inf), "masks":
        (B, N + 1, P) softmax of the logits, "canonical": (B, N, P, 2) template coordinates}``.
        """
        rgbs, logits, canonicals = [], [], []
        for slot, field in enumerate(self.objects):
            rgb, logit, canonical = field(coords, latents[:, slot], colours[:, slot], progress)
            rgbs.append(rgb)
            logits.append(torch.where(present[:, slot, None], logit, torch.full_like(logit, -1e4)))
            canonicals.append(canonical)
        bg_rgb, bg_logit = self.background_terms(coords, progress)
        all_logits = torch.stack(logits + [bg_logit], dim=1)
        masks = torch.softmax(all_logits, dim=1)
        all_rgb = torch.stack(rgbs + [bg_rgb], dim=1)
        return {"rgb": (masks[..., None] * all_rgb).sum(dim=1), "object_rgb": torch.stack(rgbs, dim=1),
                "logits": all_logits, "masks": masks, "canonical": torch.stack(canonicals, dim=1),
                "background_rgb": bg_rgb}

    @staticmethod
    def expert_image(object_rgb, object_logit, bg_rgb, bg_logit) -> torch.Tensor:
        """One object's expert against the background alone (the per-object reconstruction
        that training and inference fit to the object's masked region): (..., P, 3)."""
        m = torch.sigmoid(object_logit - bg_logit)[..., None]
        return m * object_rgb + (1.0 - m) * bg_rgb

    # ---- motion ----
    def gates(self, t: torch.Tensor) -> torch.Tensor:
        """Temporal gating weights w(t): (T,) -> (T, N), rows summing to one (constant and
        equal without temporal gating)."""
        scores = self.gating(time_basis(t, self.config))
        if not self.config.temporal_gating:
            scores = torch.zeros_like(scores)
        return torch.softmax(scores, dim=-1)

    def motion(self, t: torch.Tensor, latents: torch.Tensor) -> torch.Tensor:
        """Normalised times (T,) and object latents (B, N, D) -> generator outputs (B, T, 7):
        normalised position, rotation vector (rad), gripper."""
        if self.training and not self.config.motion_shapes_latents:
            latents = latents.detach()
        z_t = torch.einsum("tn,bnd->btd", self.gates(t), latents)  # (B, T, D)
        return self.generator(time_basis(t, self.config), z_t)

    def lipschitz_penalty(self) -> torch.Tensor:
        bounds = [field.deformation.lipschitz_bound() * field.centre.bound() for field in self.objects]
        return torch.stack(bounds).sum()

    def parameter_count(self, include_demos: bool = False) -> int:
        return sum(p.numel() for name, p in self.named_parameters() if include_demos or name != "demo_logits")


# ---- trajectories <-> generator targets ----

def trajectory_targets(trajectory: np.ndarray, config: CnfmpConfig) -> np.ndarray:
    """(T, 8) ``x y z qw qx qy qz gripper`` -> (T, 7) generator targets."""
    pos = (trajectory[:, :3] - np.asarray(config.position_mean)) / np.asarray(config.position_std)
    rot = geometry.to_tangent(trajectory[:, 3:7], config.reference_quat)
    return np.concatenate([pos, rot, trajectory[:, 7:8]], axis=1)


def decode_trajectory(outputs: np.ndarray, config: CnfmpConfig) -> dict:
    """(T, 7) generator outputs -> ``{"t" (T,) s, "position" (T, 3) m, "orientation" (T, 4)
    wxyz, "gripper" (T,) in [0, 1]}`` on the config's output grid."""
    steps = outputs.shape[0]
    return {
        "t": np.arange(steps) / config.output_fps,
        "position": outputs[:, :3] * np.asarray(config.position_std) + np.asarray(config.position_mean),
        "orientation": geometry.from_tangent(outputs[:, 3:6], config.reference_quat),
        "gripper": np.clip(outputs[:, 6], 0.0, 1.0),
    }


def output_times(config: CnfmpConfig) -> np.ndarray:
    """Normalised times of the decoded trajectory: every 1/output_fps s over duration_s."""
    steps = int(round(config.duration_s * config.output_fps)) + 1
    return np.arange(steps) / config.output_fps / config.duration_s


def pixel_coords(resolution: int) -> torch.Tensor:
    """(R * R, 2) centres of the pixels in row-major order, as (x, y) in [-1, 1]."""
    centres = (torch.arange(resolution, dtype=torch.float32) + 0.5) / resolution * 2.0 - 1.0
    y, x = torch.meshgrid(centres, centres, indexing="ij")
    return torch.stack([x.reshape(-1), y.reshape(-1)], dim=-1)


# ---- model directories ----

CONFIG_FILE, WEIGHTS_FILE, CARD_FILE = "config.json", "model.safetensors", "README.md"


def save_model(model: CnfmpModel, out_dir: str) -> None:
    """Writes config.json and model.safetensors into `out_dir` (which must exist)."""
    from safetensors.torch import save_file

    with open(os.path.join(out_dir, CONFIG_FILE), "w", encoding="utf-8") as f:
        f.write(model.config.to_json())
    save_file({k: v.detach().contiguous() for k, v in model.state_dict().items()}, os.path.join(out_dir, WEIGHTS_FILE))


def load_model(model_dir: str) -> CnfmpModel:
    """Rebuilds the model from config.json and loads model.safetensors (no code is executed
    from the directory). InputError for a missing or mismatched file."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    if not os.path.isdir(model_dir):
        raise InputError(f"model directory {model_dir} does not exist")
    config_path = os.path.join(model_dir, CONFIG_FILE)
    if not os.path.isfile(config_path):
        raise InputError(f"{model_dir} is not a model directory: {CONFIG_FILE} is missing")
    config = CnfmpConfig.from_file(config_path)
    weights_path = os.path.join(model_dir, WEIGHTS_FILE)
    if not os.path.isfile(weights_path):
        raise InputError(f"{model_dir} is not a complete model directory: {WEIGHTS_FILE} is missing")
    try:
        state = load_file(weights_path)
    except (SafetensorError, OSError) as err:
        raise InputError(f"{weights_path}: not a readable safetensors file: {err}") from err
    if "demo_logits" not in state:
        raise InputError(f"{weights_path}: no demo_logits tensor; not a cnfmp model")
    model = CnfmpModel(config, num_demos=state["demo_logits"].shape[0])
    try:
        model.load_state_dict(state)
    except RuntimeError as err:
        raise InputError(f"{weights_path} does not match {CONFIG_FILE}: {str(err).splitlines()[0]}") from err
    model.eval()
    for p in model.parameters():
        p.requires_grad_(False)
    return model
