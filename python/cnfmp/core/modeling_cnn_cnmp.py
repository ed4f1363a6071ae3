"""The CNN-CNMP baseline (paper Table I) in torch: model, training and prediction.

Image -> 5 stride-2 convolutions -> one feature vector v. Every observation (t, y) is encoded
with v into r_j; their mean r conditions the decoder, which maps (r, v, t) to a Gaussian over
the 7 generator outputs (normalised position, rotation vector, gripper) at query time t.
Training maximises the likelihood of random query points of each demonstration given its
image and first point; prediction decodes the mean on the output grid.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from cnfmp.core import data as core_data
from cnfmp.core.configuration_cnn_cnmp import CnnCnmpConfig
from cnfmp.core.layers import plain_mlp
from cnfmp.core.motion import LossLog, motion_dim, decode_trajectory, demonstration_targets, output_times


def image_tensor(images: np.ndarray, size: int) -> torch.Tensor:
    """(B, H, W, 3) uint8 images -> (B, 3, size, size) float32 in [-0.5, 0.5]."""
    import cv2

    resized = [img if img.shape[:2] == (size, size) else cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)
               for img in images]
    return torch.from_numpy(np.stack(resized).astype(np.float32) / 255.0 - 0.5).permute(0, 3, 1, 2).contiguous()


class CnnCnmpModel(nn.Module):
    """forward(images (B, 3, S, S), context_t (B, C), context_y (B, C, 7), query_t (B, T)) ->
    (mean (B, T, 7), std (B, T, 7)) in normalised generator units."""

    def __init__(self, config: CnnCnmpConfig):
        super().__init__()
        config.check()
        self.config = config
        layers: list[nn.Module] = []
        channels_in = 3
        for channels in config.conv_channels:
            layers += [nn.Conv2d(channels_in, channels, kernel_size=4, stride=2, padding=1), nn.ReLU()]
            channels_in = channels
        side = config.image_size // 2 ** len(config.conv_channels)
        self.encoder_cnn = nn.Sequential(*layers, nn.Flatten(), nn.Linear(channels_in * side * side, config.image_feature_dim))
        v, self.motion_dim = config.image_feature_dim, motion_dim(config)
        self.observation_encoder = plain_mlp(1 + self.motion_dim + v, config.width, config.encoder_layers, config.width)
        self.decoder = plain_mlp(config.width + v + 1, config.width, config.decoder_layers, 2 * self.motion_dim)

    def image_features(self, images: torch.Tensor) -> torch.Tensor:
        return self.encoder_cnn(images)

    def forward(self, images, context_t, context_y, query_t):
        features = self.image_features(images)  # (B, V)
        c, t = context_t.shape[1], query_t.shape[1]
        observed = torch.cat([context_t[..., None], context_y, features[:, None].expand(-1, c, -1)], dim=-1)
        representation = self.observation_encoder(observed).mean(dim=1)  # (B, W)
        queries = torch.cat([representation[:, None].expand(-1, t, -1), features[:, None].expand(-1, t, -1),
                             query_t[..., None]], dim=-1)
        out = self.decoder(queries)
        mean, raw_std = out[..., :self.motion_dim], out[..., self.motion_dim:]
        return mean, self.config.min_std + F.softplus(raw_std)

    @classmethod
    def from_state(cls, config: CnnCnmpConfig, state: dict) -> "CnnCnmpModel":
        return cls(config)

    def parameter_count(self) -> int:
        return sum(p.numel() for p in self.parameters())


def train_model(demos: core_data.Demonstrations, config: CnnCnmpConfig, log=None) -> tuple[CnnCnmpModel, dict]:
    """Trains the baseline on `demos` (Gaussian NLL, batched over demonstrations); returns the
    model and the run's summary (see :class:`cnfmp.core.models.ModelType`)."""
    config = config.fitted_to(demos)
    targets, times = demonstration_targets(demos.trajectories, demos.fps, config)  # (B, F, 7), (F,)
    config = dataclasses.replace(config, start_target=[float(v) for v in targets[:, 0].mean(dim=0)])
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    images = image_tensor(demos.images, config.image_size)
    model = CnnCnmpModel(config)
    optimiser = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
    batch_size, frames = min(config.batch_demos, len(demos)), len(times)
    losses = LossLog(config.steps, ["nll", "motion"], log)
    model.train()
    for step in range(config.steps):
        batch = torch.from_numpy(rng.choice(len(demos), size=batch_size, replace=False))
        extra = int(rng.integers(0, config.max_context_points))
        context = np.concatenate([np.zeros((batch_size, 1), np.int64),
                                  rng.integers(0, frames, size=(batch_size, extra))], axis=1)
        query = rng.integers(0, frames, size=(batch_size, config.target_points))
        context, query = torch.from_numpy(context), torch.from_numpy(query)
        rows = batch[:, None]
        mean, std = model(images[batch], times[context], targets[rows, context], times[query])
        nll = F.gaussian_nll_loss(mean, targets[rows, query], std ** 2, reduction="none")
        # beta-NLL (Seitzer et al., 2022): each point's NLL weighted by its (detached)
        # variance ** beta, so points the model deems uncertain still pull the mean.
        nll = (nll * (std.detach() ** (2 * config.nll_beta))).mean()
        optimiser.zero_grad(set_to_none=True)
        nll.backward()
        optimiser.step()
        with torch.no_grad():
            losses.record(step, [nll.item(), ((mean - targets[rows, query]) ** 2).mean().item()])
    model.eval()
    final = losses.final()
    summary = {"steps": config.steps, "demos": len(demos), "seconds": losses.seconds(),
               "final_losses": {"nll": final["nll"], "motion_mse": final["motion"]},
               "parameters": model.parameter_count()}
    return model, summary


class Predictor:
    """A loaded CNN-CNMP ready to predict from an image (masks are not used: no objects)."""

    def __init__(self, model: CnnCnmpModel):
        self.model = model.eval()
        self.config = model.config
        self.times = torch.from_numpy(output_times(self.config)).float()

    def predict(self, image: np.ndarray, labels: np.ndarray, seed: int = 0) -> dict:
        """``{"trajectory": decode_trajectory dict, "seconds": {"infer", "decode"}}`` for an
        (H, W, 3) uint8 image; `labels` and `seed` are unused (no masks, no search)."""
        c = self.config
        started = time.perf_counter()
        with torch.no_grad():
            mean, _ = self.model(image_tensor(np.asarray(image)[None], c.image_size), torch.zeros(1, 1),
                                 torch.tensor(c.start_target, dtype=torch.float32)[None, None], self.times[None])
        inferred = time.perf_counter()
        trajectory = decode_trajectory(mean[0].numpy().astype(np.float64), c)
        return {"trajectory": trajectory, "seconds": {"infer": inferred - started, "decode": time.perf_counter() - inferred}}
