"""Configuration of the NFMP baseline (paper Table I): the scene-level neural-field movement
primitive the compositional model extends.

One latent per demonstration conditions one global deformation of one shared image field
(no objects, no masks); the same latent drives the trajectory generator. FiLM replaces the
original hypernetwork, as in the paper's own baseline. A new scene is explained by convex
weights over the training latents, fit to the whole image by Adam.
"""

from __future__ import annotations

from dataclasses import dataclass

from cnfmp.core.configuration_common import MotionConfig
from cnfmp.errors import InputError

MODEL_TYPE = "nfmp"


@dataclass
class NfmpConfig(MotionConfig):
    # ---- scene field ----
    #: Side (px) of the square image the field is fit to (camera images are area-resized).
    field_resolution: int = 64
    #: Dimension of each demonstration's latent.
    latent_dim: int = 16
    #: Width and hidden layers of the deformation and image MLPs.
    field_width: int = 128
    field_layers: int = 3
    #: Positional-encoding octaves of the deformation (low: deformations are smooth) and of
    #: the image field (annealed coarse-to-fine over the first `anneal_fraction` of training).
    deformation_octaves: int = 2
    appearance_octaves: int = 6
    anneal_fraction: float = 0.4
    #: Pixels drawn uniformly per demonstration per step.
    pixels_per_scene: int = 1024

    # ---- motion ----
    #: Time samples per demonstration per step.
    time_samples: int = 64
    #: Ridge on the generator's latent weights (mean square).
    generator_weight_decay: float = 1e-3
    #: Loss weights: trajectory position, rotation (rad), gripper; image MSE.
    position_weight: float = 1.0
    rotation_weight: float = 1.0
    gripper_weight: float = 0.3
    image_weight: float = 1.0

    # ---- training ----
    batch_demos: int = 16
    #: Adam learning rates of the networks and of the demonstration latents.
    learning_rate: float = 2e-3
    latent_learning_rate: float = 1e-2

    # ---- inference (these change how a trained model predicts, not its weights) ----
    #: Adam steps on the softmax logits over the training latents, their learning rate, and
    #: the pixels of the image (a fixed random subset) the RGB loss is measured on.
    inference_steps: int = 100
    inference_learning_rate: float = 0.1
    inference_pixels: int = 2048

    model_type: str = MODEL_TYPE

    def check(self, source: str = "config") -> None:
        super().check(source)
        for name in ["field_resolution", "latent_dim", "field_width", "field_layers", "pixels_per_scene",
                     "time_samples", "batch_demos", "inference_steps", "inference_pixels"]:
            if not isinstance(getattr(self, name), int) or getattr(self, name) < 1:
                raise InputError(f"{source}: {name} must be a whole number >= 1, got {getattr(self, name)!r}")
        for name in ["learning_rate", "latent_learning_rate", "inference_learning_rate"]:
            if not getattr(self, name) > 0:
                raise InputError(f"{source}: {name} must be > 0, got {getattr(self, name)!r}")
        if not 0.0 <= self.anneal_fraction <= 1.0:
            raise InputError(f"{source}: anneal_fraction must be in [0, 1], got {self.anneal_fraction!r}")
