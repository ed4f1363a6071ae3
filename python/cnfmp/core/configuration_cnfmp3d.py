"""Configuration of the 3D compositional neural-field movement primitive (``cnfmp-3d``): the
paper's occupancy-field variant (§II, §III-B), for scenes given as scans (several calibrated
depth views, :mod:`cnfmp.scan`) instead of one image.

Saved as ``config.json`` beside the weights, like every model type; fields marked "(from
data)" are filled in by training.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from cnfmp.core.configuration_common import MotionConfig
from cnfmp.errors import InputError

MODEL_TYPE = "cnfmp-3d"


@dataclass
class Cnfmp3dConfig(MotionConfig):
    """Configuration of a cnfmp-3d model.

    For a new task, change nothing: ``cnfmp train --model-type cnfmp-3d --dataset D --out M``
    on a dataset with scans (``cnfmp dataset generate --scan``, or a converted recording with
    ``annotation.scan.*``) fills the "(from data)" fields and trains the default recipe. What
    a user may reasonably change:

    - `steps` (1500): the scene fields' optimisation steps; more when the occupancy loss
      is still falling at the end.
    - `box_margin_m` (0.08): how far around the objects the scene box (the volume the
      fields model) reaches; larger when a background structure the motion must avoid
      stands further away.
    - The inference settings (`search_candidates`, `search_starts`, `refine_steps`, ...):
      latency against fit; they may be edited in a trained model's config.json.

    The rest are the method's choices (docs/experiments.md, "3D scenes").
    """

    model_type: str = MODEL_TYPE
    steps: int = 1500

    # ---- what the model is for (from data) ----
    #: Object slots in label order (label k of a scan's label maps = slot k-1).
    num_objects: int = 0
    object_names: list[str] = field(default_factory=list)
    #: The scene box the fields model (world, m): its centre and half side; coordinates
    #: inside the networks are (x - box_centre) / box_half, so the box is [-1, 1]^3. Chosen
    #: by training: the demonstrations' object points with `box_margin_m` around them.
    box_centre: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    box_half: float = 1.0
    #: Per object slot, the box of template coordinates its training samples covered (the
    #: grid inference bakes the template on): lower then upper corner, 6 numbers.
    template_boxes: list[list[float]] = field(default_factory=list)

    # ---- scene fields ----
    box_margin_m: float = 0.08
    #: Latent size per object, and endpoints of each object's latent simplex.
    latent_dim: int = 8
    num_endpoints: int = 4
    field_width: int = 96
    field_layers: int = 3
    #: Octaves of the positional encodings: object templates, the background, the
    #: deformation residual.
    template_octaves: int = 5
    background_octaves: int = 6
    deformation_octaves: int = 2
    #: Training samples per scene and step: near each object's surface, near the
    #: background's, and uniform in the box.
    samples_per_object: int = 384
    background_samples: int = 256
    uniform_samples: int = 384
    #: Jitter of the near-surface samples (m): half at each of the two spreads.
    surface_jitter_m: list[float] = field(default_factory=lambda: [0.005, 0.02])
    #: A point is free when a view measures depth at least this far (m) behind it.
    carve_margin_m: float = 0.004
    #: Coarse 3D labels: a sample takes the label of the nearest scan point within this (m).
    coarse_label_radius_m: float = 0.02
    #: Loss weights: each object against the background on its own samples, the mask
    #: logits against the coarse labels, the deformations' Lipschitz bounds.
    expert_weight: float = 1.0
    mask_prior_weight: float = 0.05
    lipschitz_weight: float = 1e-6
    learning_rate: float = 2e-3
    latent_learning_rate: float = 1e-2

    # ---- motion ----
    #: Steps of the motion's fit to the demonstrations (after the scene's).
    motion_steps: int = 1500
    motion_learning_rate: float = 1e-2
    gating_width: int = 32
    #: Ridge on the local motions' response to latent and position (mean square): the
    #: motion follows each object's frame unless the demonstrations say otherwise.
    generator_weight_decay: float = 1e-3
    position_weight: float = 1.0
    rotation_weight: float = 1.0
    gripper_weight: float = 0.3

    # ---- inference (change predictions, not weights) ----
    #: Samples near each object's scan points the latent fit scores.
    fit_samples: int = 1024
    search_candidates: int = 24
    search_samples: int = 192
    search_starts: int = 4
    refine_steps: int = 12
    refine_samples: int = 384
    refine_learning_rate: float = 0.05
    #: Spacing (m) of the grid inference bakes each object template on at load time.
    bake_spacing_m: float = 0.006

    def check(self, source: str = "config") -> None:
        super().check(source)
        if self.model_type != MODEL_TYPE:
            raise InputError(f"{source}: model_type must be {MODEL_TYPE!r}, got {self.model_type!r}")
        for name in ("latent_dim", "num_endpoints", "field_width", "field_layers", "samples_per_object",
                     "uniform_samples", "motion_steps", "fit_samples", "search_samples", "search_starts",
                     "refine_samples"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise InputError(f"{source}: {name} must be a whole number >= 1, got {value!r}")
        for name in ("box_margin_m", "carve_margin_m", "coarse_label_radius_m", "learning_rate",
                     "motion_learning_rate", "refine_learning_rate", "bake_spacing_m"):
            if not getattr(self, name) > 0:
                raise InputError(f"{source}: {name} must be > 0, got {getattr(self, name)!r}")
        if self.search_starts > self.search_candidates + self.num_endpoints:
            raise InputError(f"{source}: search_starts ({self.search_starts}) exceeds the candidates searched")


__all__ = ["MODEL_TYPE", "Cnfmp3dConfig"]
