"""Training of a compositional NF-MP model (``cnfmp``, ``cnfmp-nogate``) from demonstrations.

Each step takes a batch of demonstrations, draws pixels (most from each object's dilated
coarse mask, the rest uniform: the masks only bias where the fields are supervised) and time
samples, and fits the scene fields, the endpoint and demonstration latents and the motion
networks jointly. :func:`train_model` is this type's entry in :mod:`cnfmp.core.models`;
:func:`cnfmp.core.training.train` runs it and writes the model directory.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import torch

from cnfmp.core import data as core_data, segment_timing
from cnfmp.core.configuration_cnfmp import (ANNEAL_FRACTION, CENTRE_PRIOR_WEIGHT, DRAW_FRACTION, IMAGE_WEIGHT,
                                             LIPSCHITZ_WEIGHT, MASK_PRIOR_WEIGHT, WEIGHT_PRIOR_WEIGHT, CnfmpConfig)
from cnfmp.core.layers import pixel_coords
from cnfmp.core.modeling_cnfmp import CnfmpModel, SceneRender
from cnfmp.core.motion import LossLog, demonstration_targets, motion_loss, time_basis
from cnfmp.core.statistics_choice import choose_observed_statistics
from cnfmp.core.tool_axis import choose_tool_axis_object
from cnfmp.errors import InputError

#: Inference settings of the motion refit's latent fit (:func:`refit_motion`), in place of the
#: model's own: a thorough search (every simplex candidate scored on the image, 20 refinement
#: steps), paid once per demonstration at the end of training, so the motion learns from the
#: best latents inference finds rather than from the cheaper fit a served model runs.
REFIT_SEARCH = {"search_pool": 0, "search_candidates": 96, "search_starts": 4, "refine_steps": 20,
                "refine_learning_rate": 0.2, "search_screen_pixels": 0}


def fit_config_to_data(config: CnfmpConfig, demos: core_data.Demonstrations) -> CnfmpConfig:
    """The "(from data)" fields of `config` filled in from the demonstrations."""
    slots = max(len(objs) for objs in demos.objects)
    highest = int(demos.masks.max())
    if highest > slots:
        raise InputError(f"masks use label {highest} but annotation.objects names only {slots} object(s)")
    present = np.stack([[(masks == k).any() for k in range(1, slots + 1)] for masks in demos.masks])
    fullest = max(range(len(demos)), key=lambda b: len(demos.objects[b]))
    roles = list(demos.roles[fullest]) if demos.roles else []
    # Roles order a prompt's phrases onto the slots only when each slot has its own.
    usable = len(roles) == slots and len(set(roles)) == slots and "unknown" not in roles
    return dataclasses.replace(
        config.fitted_to(demos), num_objects=slots, object_names=demos.objects[fullest],
        object_roles=roles if usable else [],
        slot_can_be_absent=[bool(not present[:, k].all()) for k in range(slots)],
    )


class TrainingSet:
    """Demonstrations as tensors at field resolution, with per-object pixel pools for the
    mask-biased sampling and padded trajectory targets."""

    def __init__(self, demos: core_data.Demonstrations, config: CnfmpConfig):
        n, res = config.num_objects, config.field_resolution
        scenes = [core_data.scene_inputs(img, m, n, res, config.mask_dilation) for img, m in zip(demos.images, demos.masks)]
        self.rgb = torch.from_numpy(np.stack([s.rgb.reshape(-1, 3) for s in scenes]))  # (B, R*R, 3)
        self.colour = torch.from_numpy(np.stack([s.colour for s in scenes]))  # (B, N, 3)
        self.present = torch.from_numpy(np.stack([s.present for s in scenes]))  # (B, N)
        self.observations = torch.from_numpy(np.stack([s.observations for s in scenes]))  # (B, N, 10)
        self.centre = self.observations[..., :2]  # (B, N, 2) mask centroids
        # Coarse label per field pixel (0 background, k object k), for the weak mask prior.
        labels = np.zeros((len(scenes), res * res), np.int64)
        for b, s in enumerate(scenes):
            for k in range(n):
                labels[b][s.masks[k].reshape(-1)] = k + 1
        self.labels = torch.from_numpy(labels)
        everywhere = np.arange(res * res)
        self.pools = [[np.flatnonzero(s.dilated[k].reshape(-1)) if s.present[k] else everywhere
                       for k in range(n)] for s in scenes]
        self.coords = pixel_coords(res)
        self.targets, self.times = demonstration_targets(demos.trajectories, demos.fps, config)  # (B, F, 7), (F,)
        self.frames = len(self.times)

    def __len__(self) -> int:
        return self.rgb.shape[0]

    def sample_pixels(self, rng: np.random.Generator, batch: np.ndarray, per_object: int, uniform: int) -> torch.Tensor:
        """Flat pixel indices (b, N * per_object + uniform): object k's block first, in slot
        order, then the uniform block."""
        total = self.coords.shape[0]
        rows = []
        for b in batch:
            blocks = [rng.choice(pool, size=per_object) for pool in self.pools[b]]
            blocks.append(rng.integers(0, total, size=uniform))
            rows.append(np.concatenate(blocks))
        return torch.from_numpy(np.stack(rows))


def image_losses(model: CnfmpModel, scene: SceneRender, target: torch.Tensor, present: torch.Tensor,
                 per_object: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(composite MSE over every sampled pixel, mean per-object expert MSE over each present
    object's own block of pixels)."""
    composite = torch.mean((scene.rgb - target) ** 2)
    n = model.config.num_objects
    logits = scene.logits
    local, count = torch.zeros(()), torch.zeros(())
    for k in range(n):
        block = slice(k * per_object, (k + 1) * per_object)
        expert = model.expert_image(scene.object_rgb[:, k, block], logits[:, k, block],
                                    scene.background_rgb[:, block], logits[:, n, block])
        err = ((expert - target[:, block]) ** 2).mean(dim=(1, 2))
        local = local + (err * present[:, k]).sum()
        count = count + present[:, k].sum()
    return composite, local / count.clamp(min=1)


class _Draw:
    """One initialisation of a training run: its model, optimiser, learning-rate schedule,
    sampling generator and loss history."""

    def __init__(self, config: CnfmpConfig, data: TrainingSet, index: int, log=None):
        if index == 0:  # seeded exactly as a plain run, so one draw trains bit for bit as before
            torch.manual_seed(config.seed)
            self.rng = np.random.default_rng(config.seed)
        else:
            torch.manual_seed(int(np.random.SeedSequence([config.seed, index]).generate_state(1)[0]))
            self.rng = np.random.default_rng([config.seed, index])
        self.index, self.step = index, 0
        self.model = model = CnfmpModel(config, num_demos=len(data))
        with torch.no_grad():  # the generator starts at the demonstrations' mean motion
            basis = time_basis(data.times, config)
            model.generator.mean.copy_(torch.linalg.lstsq(basis, data.targets.mean(dim=0)).solution)
            if config.tool_axis_slot >= 0:
                statistics = model.tilt_statistics(data.observations, data.present)
                model.tilt_mean.copy_(statistics.mean(dim=0))
                # A statistic that never varies (a uniform mask's shaded offset) stays unscaled.
                model.tilt_std.copy_(statistics.std(dim=0, unbiased=False).clamp(min=1e-6))
                model.tilt_generator.mean.copy_(model.generator.mean[:, 3:5])
        latent_params = [model.endpoints, model.absent, model.demo_logits]
        net_params = [p for name, p in model.named_parameters() if name not in ("endpoints", "absent", "demo_logits")]
        self.optimiser = torch.optim.Adam([{"params": net_params, "lr": config.learning_rate},
                                           {"params": latent_params, "lr": config.latent_learning_rate}])
        self.schedule = torch.optim.lr_scheduler.LambdaLR(
            self.optimiser, lambda step: 0.1 + 0.9 * 0.5 * (1 + np.cos(np.pi * min(step / config.steps, 1.0))))
        self.losses = LossLog(config.steps, ["image", "object", "motion"], log)

    def train(self, data: TrainingSet, until: int) -> None:
        """Runs the training steps up to (not including) step `until`."""
        model, config, rng = self.model, self.model.config, self.rng
        batch_size = min(config.batch_demos, len(data))
        for step in range(self.step, until):
            progress = min(1.0, step / max(1.0, ANNEAL_FRACTION * config.steps))
            batch = rng.choice(len(data), size=batch_size, replace=False)
            pixels = data.sample_pixels(rng, batch, config.pixels_per_object, config.uniform_pixels)
            bt = torch.from_numpy(batch)
            coords = data.coords[pixels]
            target = torch.gather(data.rgb[bt], 1, pixels[..., None].expand(-1, -1, 3))
            present = data.present[bt]
            weights = torch.softmax(model.demo_logits[bt], dim=-1)
            latents = model.latents(weights, present)
            anchors = data.centre[bt]
            scene = model.scene(coords, latents, data.colour[bt], present, anchors, progress)
            composite, local = image_losses(model, scene, target, present, config.pixels_per_object)
            # Logits are ordered objects then background; labels 0 = background, k = object k.
            label = torch.gather(data.labels[bt], 1, pixels)
            label = torch.where(label == 0, torch.full_like(label, config.num_objects), label - 1)
            mask_prior = torch.nn.functional.cross_entropy(scene.logits, label)
            frames = torch.from_numpy(rng.integers(0, data.frames, size=config.time_samples))
            motion = motion_loss(model.config, model.motion(data.times[frames], latents, present, data.observations[bt]),
                                 data.targets[bt][:, frames])
            lipschitz = model.lipschitz_penalty()
            centre_err = ((model.object_centres(latents, anchors) - anchors) ** 2).sum(dim=-1)
            centre_prior = (centre_err * present).sum() / present.sum().clamp(min=1)
            weight_prior = (model.weight_spread(weights) * present).sum() / present.sum().clamp(min=1)
            loss = (IMAGE_WEIGHT * (composite + local) + motion + MASK_PRIOR_WEIGHT * mask_prior
                    + CENTRE_PRIOR_WEIGHT * centre_prior + WEIGHT_PRIOR_WEIGHT * weight_prior
                    + config.generator_weight_decay * model.motion_penalty()
                    + LIPSCHITZ_WEIGHT * lipschitz)
            self.optimiser.zero_grad(set_to_none=True)
            loss.backward()
            self.optimiser.step()
            self.schedule.step()
            self.losses.record(step, [composite.item(), local.item(), motion.item()],
                               f"lipschitz {lipschitz.item():.3g}")
        self.step = max(self.step, until)

    def motion_loss(self) -> float:
        """The trajectory loss over the last logged window of steps."""
        return self.losses.final()["motion"]


def train_model(demos: core_data.Demonstrations, config: CnfmpConfig, log=None) -> tuple[CnfmpModel, dict]:
    """Trains a model on `demos`; returns it with a summary of the run (final losses, wall
    time, and with several draws each draw's trajectory loss at the choice). `log(line)`
    receives progress lines (every ~5% of the steps)."""
    started = time.monotonic()
    config, tool_axis = choose_tool_axis(fit_config_to_data(config, demos), demos)
    config, statistics = choose_statistics(config, demos)
    if log:
        log(f"tool axis: {tool_axis}")
        log(f"mask statistics the motion reads: {statistics}")
    data = TrainingSet(demos, config)
    choice = {}
    if config.draws == 1:
        run = _Draw(config, data, 0, log)
    else:
        until = max(1, round(DRAW_FRACTION * config.steps))
        draws = []
        for index in range(config.draws):
            prefix = f"draw {index + 1}/{config.draws}: "
            draws.append(_Draw(config, data, index, log and (lambda line, p=prefix: log(p + line))))
            draws[-1].train(data, until)
        losses = [d.motion_loss() for d in draws]
        run = draws[int(np.argmin(losses))]
        choice = {"draws": {"count": config.draws, "steps": until, "chosen": run.index,
                            "motion_mse": [round(loss, 6) for loss in losses]}}
        if log:
            log(f"draw {run.index + 1} of {config.draws} goes on (trajectory loss at step {until}: "
                + ", ".join(f"{loss:.5f}" for loss in losses) + ")")
        run.losses.log = log
    run.train(data, config.steps)
    model = run.model
    model.eval()
    final = run.losses.final()
    if config.motion_refit_steps:  # the motion the model ships with is the refit one
        final["motion"], latents = refit_motion(model, data, demos, log)
    else:
        with torch.no_grad():
            latents = model.latents(torch.softmax(model.demo_logits, dim=-1), data.present)
    timing = fit_segment_timing(model, data, demos, latents)
    summary = {"steps": config.steps, "demos": len(data), "seconds": round(time.monotonic() - started, 1),
               "final_losses": {f"{name}_mse": value for name, value in final.items()},
               "parameters": model.parameter_count(), "tool_axis": tool_axis,
               "observed_statistics": statistics, **choice,
               **({"segment_timing": timing} if timing else {})}
    return model, summary


def choose_tool_axis(config: CnfmpConfig, demos: core_data.Demonstrations) -> tuple[CnfmpConfig, str]:
    """`config` with `tool_axis_object` chosen from `demos` where the config leaves it to
    training (:mod:`cnfmp.core.tool_axis`; a chosen slot also sets the swing-twist chart its
    readout needs), and one line saying how it was set."""
    if config.tool_axis_object is not None:
        slot = config.tool_axis_object
        return config, (f"read from slot {slot + 1}'s mask (set by the config)" if slot >= 0
                        else "read with the rest of the motion (set by the config)")
    if config.in_joint_space:
        return dataclasses.replace(config, tool_axis_object=-1), "none: the motion is in joint space"
    choice = choose_tool_axis_object(demos)
    chart = {"rotation_chart": "swing_twist"} if choice.slot >= 0 else {}
    return dataclasses.replace(config, tool_axis_object=choice.slot, **chart), choice.reason


def choose_statistics(config: CnfmpConfig, demos: core_data.Demonstrations) -> tuple[CnfmpConfig, str]:
    """`config` with `observed_statistics` chosen from `demos` where the config leaves it to
    training (:mod:`cnfmp.core.statistics_choice`), and one line saying how it was set."""
    if config.observed_statistics is not None:
        return config, f"{config.observed_statistics} (set by the config)"
    choice = choose_observed_statistics(demos)
    return dataclasses.replace(config, observed_statistics=choice.name), choice.reason


def fit_segment_timing(model: CnfmpModel, data: TrainingSet, demos: core_data.Demonstrations,
                       latents: torch.Tensor) -> str | None:
    """Sets the model's per-scene segment timing (:mod:`cnfmp.core.segment_timing`) from the
    demonstrations' latents (B, N, D) as the motion reads them, where the demonstrations were
    aligned; returns what was decided, for the log and the card (None as recorded)."""
    if demos.timing is None:
        return None
    with torch.no_grad():
        features = model.motion_latents(latents, data.observations, data.present).flatten(1).numpy()
    members = [b for b, knots in enumerate(demos.timing.demo_knots_s) if knots is not None]
    if len(members) < segment_timing.MIN_DEMOS:
        return (f"one for every scene, the median's ({len(members)} demonstrations with the task's gripper events; "
                f"a per-scene timing needs {segment_timing.MIN_DEMOS})")
    timing = segment_timing.fit(features[members], np.array([demos.timing.demo_knots_s[b] for b in members]),
                                np.array(demos.timing.reference_knots_s))
    model.config = dataclasses.replace(model.config, segment_timing=timing.to_dict() if timing else {})
    if timing:
        return timing.describe()
    return "one for every scene, the median's (a per-scene timing did not predict held-out demonstrations better)"


def refit_motion(model: CnfmpModel, data: TrainingSet, demos: core_data.Demonstrations,
                 log=None) -> tuple[float, torch.Tensor]:
    """Fits the gating and the trajectory generator to the latents that inference finds for
    every demonstration's image (the scene networks and endpoints stay as trained); returns
    the final motion MSE and those latents (B, N, D). Training and prediction then feed the
    motion the same kind of latent."""
    from cnfmp.core.inference import Predictor

    config = model.config
    predictor = Predictor(model, dataclasses.replace(config, **REFIT_SEARCH))  # freezes every parameter
    scenes = [core_data.scene_inputs(demos.images[b], demos.masks[b], config.num_objects,
                                     config.field_resolution, config.mask_dilation) for b in range(len(data))]
    # Exact: the refit must not depend on an inference speed-up chosen after training.
    fitted = predictor.infer_scenes(scenes, [config.seed + b for b in range(len(data))], exact=True)
    with torch.no_grad():
        latents = model.latents(torch.stack([weights for weights, _ in fitted]), data.present)
    motion_params = model.motion_parameters()
    for p in motion_params:
        p.requires_grad_(True)
    model.train()
    optimiser = torch.optim.Adam(motion_params, lr=config.learning_rate)
    steps = config.motion_refit_steps
    schedule = torch.optim.lr_scheduler.LambdaLR(optimiser, lambda step: 0.5 * (1 + np.cos(np.pi * min(step / steps, 1.0))))
    for step in range(steps):
        loss = motion_loss(model.config, model.motion(data.times, latents, data.present, data.observations),
                           data.targets)
        penalty = config.generator_weight_decay * model.motion_penalty()
        optimiser.zero_grad(set_to_none=True)
        (loss + penalty).backward()
        optimiser.step()
        schedule.step()
        if log and (step % max(1, steps // 5) == 0 or step == steps - 1):
            log(f"motion refit {step + 1}/{steps}  motion {loss.item():.5f}")
    for p in model.parameters():
        p.requires_grad_(False)
    model.eval()
    return float(loss.item()), latents
