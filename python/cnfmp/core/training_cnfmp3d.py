"""Training of a cnfmp-3d model from demonstrations with scans.

Two stages. The scene: every step draws, per demonstration, samples near each object's scan
points, near the background's and uniformly in the scene box (labels from free-space
carving, computed once), and fits the occupancy fields, the endpoint and demonstration
latents. The motion: inference's own latent fit runs on every demonstration's scan, and the
gates and movement primitives are fitted to the trajectories from those latents and object
frames, so training and prediction feed the motion the same kind of input.
:func:`train_model` is this type's entry in :mod:`cnfmp.core.models`.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import torch
from torch.nn import functional as F

from cnfmp.core import data as core_data
from cnfmp.core import occupancy
from cnfmp.core.configuration_cnfmp3d import Cnfmp3dConfig
from cnfmp.core.modeling_cnfmp3d import Cnfmp3dModel
from cnfmp.core.motion import LossLog, demonstration_targets, motion_loss
from cnfmp.errors import InputError

#: Candidate samples drawn per demonstration and kind, of which each step takes its share.
POOL_FACTOR = 16
#: How far (fraction of the extent) the baked template box reaches beyond the training
#: samples' template coordinates.
TEMPLATE_BOX_PADDING = 0.15


def fit_config_to_data(config: Cnfmp3dConfig, demos: core_data.Demonstrations) -> Cnfmp3dConfig:
    """The "(from data)" fields of `config` from the demonstrations: the motion's, the
    object slots and the scene box around every scan's object points."""
    if len(demos.scans) != len(demos):
        raise InputError("cnfmp-3d trains on scans, and the dataset records none; record them with "
                         "`cnfmp dataset generate --scan` (or add annotation.scan.* features, see README)")
    if demos.joint_names:
        raise InputError("cnfmp-3d moves the gripper in each object's frame, so it learns end-effector poses; "
                         f"this dataset's motion is joint space ({', '.join(demos.joint_names)}): train the 2D "
                         "cnfmp on it, or record the tool pose")
    slots = max(int(v.labels.max(initial=0)) for s in demos.scans for v in s.views)
    if slots == 0:
        raise InputError("the scans' label maps label no object")
    names = list(demos.scans[0].objects)[:slots] or [f"object {k + 1}" for k in range(slots)]
    points = [occupancy.scan_points(scan, None, slots, tuple(scan.objects)) for scan in demos.scans]
    box = occupancy.fit_box([p.points[p.labels > 0] for p in points], config.box_margin_m)
    return dataclasses.replace(config.fitted_to(demos), num_objects=slots, object_names=names,
                               box_centre=[float(v) for v in box.centre], box_half=box.half)


class ScanSamples:
    """The demonstrations' labelled sample pools as tensors, per kind: each object's
    near-surface samples, the background's, uniform ones; and each object's anchor."""

    def __init__(self, demos: core_data.Demonstrations, config: Cnfmp3dConfig):
        box = occupancy.SceneBox.of(config)
        n = config.num_objects
        rng = np.random.default_rng(config.seed)
        pools: list[list[occupancy.LabelledSamples]] = []
        anchors = []
        for scan in demos.scans:
            points = occupancy.scan_points(scan, box, n, tuple(scan.objects))
            kinds = [occupancy.near_surface(points.of_object(k), POOL_FACTOR * config.samples_per_object,
                                            config.surface_jitter_m, rng) for k in range(n)]
            background = points.points[points.labels == 0]
            kinds.append(occupancy.near_surface(background, POOL_FACTOR * config.background_samples,
                                                config.surface_jitter_m, rng))
            kinds.append(box.to_world(rng.uniform(-1.0, 1.0, (POOL_FACTOR * config.uniform_samples, 3))))
            pools.append([occupancy.label_samples(w, scan, points, box, config) for w in kinds])
            anchors.append(points.anchors(box, n))
        self.counts = [config.samples_per_object] * n + [config.background_samples, config.uniform_samples]
        stack = lambda kind, field: torch.from_numpy(np.stack([getattr(p[kind], field) for p in pools]))  # noqa: E731
        #: Per kind: points (B, S, 3), occupied (B, S), known (B, S), coarse (B, S).
        self.kinds = [{field: stack(kind, field) for field in ("points", "occupied", "known", "coarse")}
                      for kind in range(n + 2)]
        #: (B, N, 3) box coordinates: each object's scan-point centroid.
        self.anchors = torch.from_numpy(np.stack(anchors))

    def __len__(self) -> int:
        return self.anchors.shape[0]

    def draw(self, rng: np.random.Generator) -> "StepSamples":
        """One step's samples of every demonstration."""
        parts, blocks, start = {f: [] for f in ("points", "occupied", "known", "coarse")}, [], 0
        for kind, count in zip(self.kinds, self.counts):
            index = torch.from_numpy(rng.integers(0, kind["points"].shape[1], count))
            for field in parts:
                parts[field].append(kind[field][:, index])
            blocks.append(slice(start, start + count))
            start += count
        return StepSamples(**{f: torch.cat(v, dim=1) for f, v in parts.items()}, blocks=blocks)


@dataclasses.dataclass
class StepSamples:
    """One training step's labelled samples of every demonstration (B demonstrations, P
    samples): each object's near-surface block, then the background's and the uniform one."""

    #: Sample positions (B, P, 3), box coordinates.
    points: torch.Tensor
    #: Whether each sample is occupied (B, P) float, and whether the scan tells (B, P) bool.
    occupied: torch.Tensor
    known: torch.Tensor
    #: Coarse slot label per sample (B, P) int64 (N: the background).
    coarse: torch.Tensor
    #: Per kind (each object, the background, uniform) its slice of P.
    blocks: list[slice]


def scene_losses(model: Cnfmp3dModel, batch: StepSamples, latents: torch.Tensor, anchors: torch.Tensor) -> dict:
    """The scene's losses on one step's samples: composite occupancy (BCE on the carved
    points), each object's expert against the background on its own samples, the mask
    logits against the coarse labels."""
    scene = model.scene(batch.points, latents, anchors)
    known, occupied = batch.known.float(), batch.occupied
    bce = lambda p, target, weight: (F.binary_cross_entropy(p.clamp(1e-5, 1 - 1e-5), target, reduction="none")  # noqa: E731
                                     * weight).sum() / weight.sum().clamp(min=1.0)
    composite = bce(scene.occupancy, occupied, known)
    terms = torch.stack([scene.occupancy_logits, scene.mask_logits], dim=-1)  # (B, N + 1, P, 2)
    expert = []
    for k in range(model.config.num_objects):
        block = batch.blocks[k]
        expert.append(bce(model.expert_occupancy(terms[:, k, block], terms[:, -1, block]),
                          occupied[:, block], known[:, block]))
    masks = F.cross_entropy(scene.mask_logits, batch.coarse)
    return {"occupancy": composite, "expert": torch.stack(expert).mean(), "masks": masks}


def train_model(demos: core_data.Demonstrations, config: Cnfmp3dConfig, log=None) -> tuple[Cnfmp3dModel, dict]:
    """Trains a cnfmp-3d model on `demos` (with scans); returns it and the run's summary
    (steps, demos, seconds, final losses, parameters). `log(line)` receives progress."""
    started = time.monotonic()
    config = fit_config_to_data(config, demos)
    torch.manual_seed(config.seed)
    data = ScanSamples(demos, config)
    if log:
        log(f"scene box: centre {np.round(config.box_centre, 3).tolist()} m, half side {config.box_half:.3f} m; "
            f"labelled samples ready in {time.monotonic() - started:.1f}s")
    model = Cnfmp3dModel(config, num_demos=len(data))
    latent_params = [model.endpoints, model.demo_logits]
    scene_params = [p for name, p in model.named_parameters()
                    if name not in ("endpoints", "demo_logits") and not name.startswith(("gating", "local_motion", "world_motion"))]
    optimiser = torch.optim.Adam([{"params": scene_params, "lr": config.learning_rate},
                                  {"params": latent_params, "lr": config.latent_learning_rate}])
    schedule = torch.optim.lr_scheduler.LambdaLR(optimiser, lambda s: 0.5 * (1 + np.cos(np.pi * min(s / config.steps, 1.0))))
    losses = LossLog(config.steps, ["occupancy", "expert", "masks"], log)
    rng = np.random.default_rng(config.seed + 1)
    model.train()
    for step in range(config.steps):
        batch = data.draw(rng)
        latents = model.latents(torch.softmax(model.demo_logits, dim=-1))
        parts = scene_losses(model, batch, latents, data.anchors)
        loss = (parts["occupancy"] + config.expert_weight * parts["expert"] + config.mask_prior_weight * parts["masks"]
                + config.lipschitz_weight * model.lipschitz_penalty())
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        schedule.step()
        losses.record(step, [parts[k].item() for k in ("occupancy", "expert", "masks")])
    model.eval()
    config.template_boxes = template_boxes(model, data)
    motion = fit_motion(model, demos, log)
    for p in model.parameters():
        p.requires_grad_(False)
    final = {f"{name}_bce" if name != "masks" else "masks_ce": value for name, value in losses.final().items()}
    final["motion_mse"] = motion
    summary = {"steps": config.steps, "demos": len(data), "seconds": round(time.monotonic() - started, 1),
               "final_losses": final, "parameters": model.parameter_count()}
    return model, summary


def template_boxes(model: Cnfmp3dModel, data: ScanSamples) -> list[list[float]]:
    """Per object the box of template coordinates of its training samples, padded: where
    inference bakes the template."""
    boxes = []
    with torch.no_grad():
        latents = model.latents(torch.softmax(model.demo_logits, dim=-1))
        for k, field in enumerate(model.objects):
            canonical = field.canonical(data.kinds[k]["points"], latents[:, k], data.anchors[:, k]).reshape(-1, 3)
            lower, upper = canonical.min(dim=0).values, canonical.max(dim=0).values
            pad = TEMPLATE_BOX_PADDING * (upper - lower)
            boxes.append([float(v) for v in torch.cat([lower - pad, upper + pad])])
    return boxes


def fit_motion(model: Cnfmp3dModel, demos: core_data.Demonstrations, log=None) -> float:
    """Fits the gates and movement primitives to the demonstrations' trajectories from the
    latents and object frames inference finds on their scans; returns the final motion MSE."""
    from cnfmp.core.inference_cnfmp3d import Predictor3d

    config = model.config
    predictor = Predictor3d(model)  # freezes the scene
    fitted = [predictor.fit_scan(scan, seed=config.seed + b) for b, scan in enumerate(demos.scans)]
    latents = torch.stack([f.latents for f in fitted])
    centres = torch.stack([f.centres for f in fitted])
    turns = torch.stack([f.turns for f in fitted])
    targets, times = demonstration_targets(demos.trajectories, demos.fps, config)
    params = model.motion_parameters()
    for p in params:
        p.requires_grad_(True)
    optimiser = torch.optim.Adam(params, lr=config.motion_learning_rate)
    steps = config.motion_steps
    schedule = torch.optim.lr_scheduler.LambdaLR(optimiser, lambda s: 0.5 * (1 + np.cos(np.pi * min(s / steps, 1.0))))
    for step in range(steps):
        loss = motion_loss(config, model.motion(times, latents, centres, turns), targets)
        optimiser.zero_grad(set_to_none=True)
        (loss + config.generator_weight_decay * model.motion_penalty()).backward()
        optimiser.step()
        schedule.step()
        if log and (step % max(1, steps // 5) == 0 or step == steps - 1):
            log(f"motion {step + 1}/{steps}  motion {loss.item():.5f}")
    return float(loss.item())


__all__ = ["ScanSamples", "fit_config_to_data", "fit_motion", "train_model"]
