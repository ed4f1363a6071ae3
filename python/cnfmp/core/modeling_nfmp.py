"""The NFMP baseline (paper Table I) in torch: model, training and prediction.

Scene: ``I(x) = F(x - Delta(x | z))``: one image field F shared by every scene, one global
deformation Delta conditioned (FiLM) on the scene's latent z. Motion: the basis-function
generator of the core driven by the same z, constant in time. Training fits one free latent
per demonstration jointly with the networks. Prediction fits softmax weights over the
training latents to the new image (RGB loss only, as the original) and decodes the motion of
the weighted latent.

Coordinates are image coordinates in [-1, 1]^2; time is normalised to [0, 1].
"""

from __future__ import annotations

import time

import numpy as np
import torch
from torch import nn

from cnfmp.core import data as core_data
from cnfmp.core.adam import Adam
from cnfmp.core.configuration_nfmp import NfmpConfig
from cnfmp.core.inference import psnr_db
from cnfmp.core.layers import FilmMLP, encoded_size, fourier_features, pixel_coords, plain_mlp
from cnfmp.core.motion import (BasisGenerator, LossLog, decode_trajectory, demonstration_targets, motion_dim,
                               motion_loss, output_times, time_basis, time_basis_size)
from cnfmp.errors import InputError


def field_image(image: np.ndarray, resolution: int) -> torch.Tensor:
    """(H, W, 3) uint8 -> (R * R, 3) float32 in [0, 1], row-major like :func:`pixel_coords`."""
    import cv2

    small = cv2.resize(np.asarray(image), (resolution, resolution), interpolation=cv2.INTER_AREA)
    return torch.from_numpy(small.astype(np.float32).reshape(-1, 3) / 255.0)


class NfmpModel(nn.Module):
    """Shapes: B scenes, P pixels, T times, D latent size."""

    def __init__(self, config: NfmpConfig, num_demos: int):
        super().__init__()
        config.check()
        self.config = config
        self.demo_latents = nn.Parameter(0.1 * torch.randn(num_demos, config.latent_dim))
        self.deformation = FilmMLP(encoded_size(2, config.deformation_octaves), config.latent_dim, config.field_width,
                                   config.field_layers, 2)
        self.image_field = plain_mlp(encoded_size(2, config.appearance_octaves), config.field_width,
                                     config.field_layers, 3)
        self.generator = BasisGenerator(time_basis_size(config), config.latent_dim, motion_dim(config))
        with torch.no_grad():  # start undeformed
            self.deformation.out.weight.zero_()
            self.deformation.out.bias.zero_()

    def render(self, coords: torch.Tensor, latents: torch.Tensor, progress: float | None = None) -> torch.Tensor:
        """Colours (B, P, 3) in [0, 1] at image coordinates (B, P, 2) of scenes with latents (B, D)."""
        c = self.config
        warped = coords - self.deformation(fourier_features(coords, c.deformation_octaves), latents)
        return torch.sigmoid(self.image_field(fourier_features(warped, c.appearance_octaves, progress)))

    def motion(self, t: torch.Tensor, latents: torch.Tensor) -> torch.Tensor:
        """Normalised times (T,) and latents (B, D) -> generator outputs (B, T, 7)."""
        z_t = latents[:, None, :].expand(-1, t.shape[0], -1)
        return self.generator(time_basis(t, self.config), z_t)

    @classmethod
    def from_state(cls, config: NfmpConfig, state: dict) -> "NfmpModel":
        if "demo_latents" not in state:
            raise InputError("the weights have no demo_latents tensor; not an nfmp model")
        return cls(config, num_demos=state["demo_latents"].shape[0])

    def parameter_count(self) -> int:
        return sum(p.numel() for name, p in self.named_parameters() if name != "demo_latents")


def train_model(demos: core_data.Demonstrations, config: NfmpConfig, log=None) -> tuple[NfmpModel, dict]:
    """Fits the networks and one latent per demonstration jointly (image MSE on uniformly
    drawn pixels + trajectory MSE); returns the model and the run's summary."""
    config = config.fitted_to(demos)
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    rgb = torch.stack([field_image(img, config.field_resolution) for img in demos.images])  # (B, R*R, 3)
    coords = pixel_coords(config.field_resolution)
    targets, times = demonstration_targets(demos.trajectories, demos.fps, config)
    model = NfmpModel(config, num_demos=len(demos))
    with torch.no_grad():  # the generator starts at the demonstrations' mean motion
        model.generator.mean.copy_(torch.linalg.lstsq(time_basis(times, config), targets.mean(dim=0)).solution)
    nets = [p for name, p in model.named_parameters() if name != "demo_latents"]
    optimiser = torch.optim.Adam([{"params": nets, "lr": config.learning_rate},
                                  {"params": [model.demo_latents], "lr": config.latent_learning_rate}])
    schedule = torch.optim.lr_scheduler.LambdaLR(
        optimiser, lambda step: 0.1 + 0.9 * 0.5 * (1 + np.cos(np.pi * min(step / config.steps, 1.0))))
    batch_size = min(config.batch_demos, len(demos))
    losses = LossLog(config.steps, ["image", "motion"], log)
    for step in range(config.steps):
        progress = min(1.0, step / max(1.0, config.anneal_fraction * config.steps))
        batch = torch.from_numpy(rng.choice(len(demos), size=batch_size, replace=False))
        pixels = torch.from_numpy(rng.integers(0, coords.shape[0], size=(batch_size, config.pixels_per_scene)))
        frames = torch.from_numpy(rng.integers(0, len(times), size=config.time_samples))
        latents = model.demo_latents[batch]
        image = torch.mean((model.render(coords[pixels], latents, progress) - rgb[batch[:, None], pixels]) ** 2)
        motion = motion_loss(config, model.motion(times[frames], latents), targets[batch][:, frames])
        loss = config.image_weight * image + motion + config.generator_weight_decay * model.generator.sensitivity()
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        schedule.step()
        losses.record(step, [image.item(), motion.item()])
    model.eval()
    final = losses.final()
    summary = {"steps": config.steps, "demos": len(demos), "seconds": losses.seconds(),
               "final_losses": {"image_mse": final["image"], "motion_mse": final["motion"]},
               "parameters": model.parameter_count()}
    return model, summary


class Predictor:
    """A loaded NFMP ready to predict from an image (masks are not used: no objects)."""

    def __init__(self, model: NfmpModel):
        self.model = model.eval()
        for p in model.parameters():
            p.requires_grad_(False)
        self.config = model.config
        self.coords = pixel_coords(self.config.field_resolution)
        self.times = torch.from_numpy(output_times(self.config)).float()

    def predict(self, image: np.ndarray, labels: np.ndarray, seed: int = 0) -> dict:
        """``{"trajectory", "scene_psnr_db", "seconds": {"infer", "decode"}}`` for an (H, W, 3)
        uint8 image; `seed` draws the pixel subset of the fit; `labels` is unused."""
        c = self.config
        started = time.perf_counter()
        rgb = field_image(image, c.field_resolution)
        pixels = torch.from_numpy(np.random.default_rng(seed).permutation(rgb.shape[0])[: c.inference_pixels])
        coords, target = self.coords[pixels][None], rgb[pixels][None]
        logits = torch.zeros(1, self.model.demo_latents.shape[0], requires_grad=True)
        optimiser = Adam(logits, lr=c.inference_learning_rate)
        for _ in range(c.inference_steps):
            latent = torch.softmax(logits, dim=-1) @ self.model.demo_latents
            loss = torch.mean((self.model.render(coords, latent) - target) ** 2)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
        with torch.no_grad():
            latent = torch.softmax(logits, dim=-1) @ self.model.demo_latents
            outputs = self.model.motion(self.times, latent)[0].numpy().astype(np.float64)
            scene_mse = float(torch.mean((self.model.render(self.coords[None], latent)[0] - rgb) ** 2))
        inferred = time.perf_counter()
        trajectory = decode_trajectory(outputs, c)
        return {"trajectory": trajectory, "scene_psnr_db": psnr_db(scene_mse),
                "seconds": {"infer": inferred - started, "decode": time.perf_counter() - inferred}}
