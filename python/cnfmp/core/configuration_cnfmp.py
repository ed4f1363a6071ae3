"""Configuration of the compositional neural-field movement primitive (paper §II-B).

One dataclass holds every choice that shapes the model, its training and its inference. It is
saved as ``config.json`` beside the weights; loading a model rebuilds the networks from it, so
a model directory is self-describing. Fields marked "(from data)" are filled in by training
from the dataset and need not be set in a config file.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

from cnfmp.core.configuration_common import MotionConfig
from cnfmp.errors import InputError

MODEL_TYPE = "cnfmp"
#: The ablation without temporal gating (paper Table I, "ours without gating").
NOGATE_MODEL_TYPE = "cnfmp-nogate"


#: What a version-1 config (written before 2026-12-03) meant by leaving a field out: the
#: defaults that version 2 changed. Upgrading fills them in, so a version-1 model trained
#: with them is refused at version 5 (VERSION_5_RETIRED) rather than loaded as a model of
#: another kind.
VERSION_1_DEFAULTS = {"anchored_centres": False, "motion_shapes_latents": True}
#: Fields version 3 retired, each with the one behaviour that stayed: a version-2 file that
#: holds that value loads without the field; any other value is refused (retrain the model).
#: Every shipped model had these values (simplex_entropy_weight: no entropy bonus on the
#: demonstrations' simplex weights; gate_present_only: an absent object's gate is zero).
VERSION_3_RETIRED = {"simplex_entropy_weight": 0.0, "gate_present_only": True}
#: Fields version 5 retired in the same way. anchored_centres true: each template is centred
#: on its coarse mask's centroid plus a small latent offset, and the motion reads the
#: centroid beside the latent (version 1's alternative, a centre projective in the latent,
#: is gone); motion_shapes_latents false: the trajectory loss does not move the latents
#: (anchored centres need it: shaped by the motion, the latents memorise each
#: demonstration's position and the motion stops reading the centroid; docs/experiments.md,
#: "Anchored centres").
VERSION_5_RETIRED = {"anchored_centres": True, "motion_shapes_latents": False}
#: The values of `observed_statistics` (the columns each reads:
#: :data:`cnfmp.core.modeling_cnfmp.OBSERVED_COLUMNS`).
OBSERVED_STATISTICS = ("centroid", "shading", "all")

# ---- the method's fixed choices (config fields up to version 6) ----
# Each is measured in docs/experiments.md; none is a setting a task needs changed.
#: Fraction of the training steps over which the appearance and background octaves are
#: switched on, coarse to fine.
ANNEAL_FRACTION = 0.4
#: Weight of the Lipschitz penalty (product of the learned per-layer bounds) on the latent-to-
#: deformation networks.
LIPSCHITZ_WEIGHT = 1e-6
#: Weight of a weak mask prior: cross-entropy between the soft competition and the coarse
#: labels at the sampled pixels. The sampling bias alone lets an expert paint other objects
#: in the composite; this small term keeps each expert on its own object.
MASK_PRIOR_WEIGHT = 0.05
#: Weight of the image losses (composite + per-object) relative to the trajectory loss.
IMAGE_WEIGHT = 1.0
#: Weight of the centre prior: squared distance (image coordinates in [-1, 1]) between each
#: object's template centre c(z_i) and its coarse mask's centroid, in training and in
#: inference. The coarse masks roughly localise the objects (paper §II); this term anchors
#: the translation part of every latent there. A template's centre is its mask's centroid plus
#: a small latent-dependent offset (a tall object's centroid is not where its base is), and
#: the motion reads the centroid, through a learned projective map from image to table,
#: beside the latent: the latent is left to shape and pose, so a new scene that pairs one
#: demonstration's position with another's pose needs no latent training never tied to a motion.
CENTRE_PRIOR_WEIGHT = 1.0
#: Weight of a pull of each object's simplex weights towards the simplex centre (squared
#: distance), in training and in inference alike. Directions of the latent that the image
#: does not determine then rest at the same place for demonstrations and new scenes, so the
#: motion cannot read anything from them that inference would not reproduce.
WEIGHT_PRIOR_WEIGHT = 1e-3
#: With `draws` > 1: the fraction of `steps` each draw trains before the choice (which costs
#: (draws - 1) x this fraction of a run in extra time).
DRAW_FRACTION = 0.3
#: Inference searches each object's simplex enlarged about its centre by this fraction, so a
#: scene slightly outside the demonstrations' span stays reachable (weights down to
#: -margin / num_endpoints).
SIMPLEX_MARGIN = 0.5
#: Pixels of an object's dilated mask the cheap search scores its candidates on.
SEARCH_PIXELS = 128
#: Inference's refinement reads each object's appearance from a grid with this many samples
#: per field pixel along each axis, baked once per object and scene, instead of evaluating its
#: network at every step (most of a step's cost). Training's motion refit, and a fit asked to
#: be exact, evaluate the network.
TEXELS_PER_PIXEL = 1
#: Inference's refinement evaluates each object's (low-frequency) deformation residual on a
#: grid this many field pixels apart over the fitted pixels and interpolates it, instead of at
#: every pixel (exact fits evaluate it everywhere).
RESIDUAL_GRID_PIXELS = 3.0
#: Fields version 7 made fixed choices (the constants above). These shape what a trained model
#: predicts, so a version-6 file that holds another value is refused (retrain the model).
VERSION_7_RETIRED = {"centre_prior_weight": CENTRE_PRIOR_WEIGHT, "weight_prior_weight": WEIGHT_PRIOR_WEIGHT,
                     "simplex_margin": SIMPLEX_MARGIN}
#: Fields version 7 made fixed choices that a version-6 file may hold with any value: they
#: shaped training only (the weights already carry them), or they approximated inference's
#: exact fit (the fixed approximation then applies).
VERSION_7_DROPPED = ("anneal_fraction", "lipschitz_weight", "mask_prior_weight", "image_weight", "draw_fraction",
                     "search_pixels", "texels_per_pixel", "residual_grid_pixels")


def _retire(values: dict, retired: dict, source: str) -> dict:
    """`values` (a copy, changed in place) without the `retired` fields; InputError for one
    that holds another value than the behaviour that stayed."""
    for name, kept in retired.items():
        if name in values and values.pop(name) != kept:
            raise InputError(f"{source}: {name} is no longer a setting (cnfmp now always trains as "
                             f"{name} {json.dumps(kept)}); this model was trained otherwise: retrain it "
                             "with `cnfmp train`")
    return values


@dataclass
class CnfmpConfig(MotionConfig):
    """Configuration of a cnfmp model: its fields, their training and their inference.

    For a new task, change nothing: `cnfmp train --dataset D --out M` fills the "(from
    data)" fields, chooses from the demonstrations which labelled objects the task is about
    (`task_objects`), which of their masks' statistics the motion reads
    (`observed_statistics`) and whether the tool axis is read from one object's mask
    (`tool_axis_object`), and trains the default recipe (docs/benchmarks.md, "Core models",
    for what it reaches on the benchmark tasks). What a user may reasonably change, and when:

    - `steps` (2000): fewer for a quick look (the losses are printed as training goes), more
      when the trajectory loss is still falling at the end.
    - `task_objects`, `observed_statistics`, `tool_axis_object`: to overrule training's
      choices (the card says what it chose and why); `observed_statistics` "centroid" when
      the image inside the masks says nothing about the motion.
    - `draws` (1): several initialisations, the one whose motion fits best going on, when a
      seed's trajectory loss stays far above another seed's.
    - The inference settings (`search_candidates`, `search_starts`, `refine_steps`, ...):
      latency against fit; they change predictions, not weights, so they may also be edited
      in a trained model's config.json.

    The rest are the method's own choices, measured in docs/experiments.md; change them to
    study the method, not to fit a task. Those no study here has needed changed are constants
    of this module (its "fixed choices", e.g. CENTRE_PRIOR_WEIGHT), not fields.
    """

    #: Version 2: objects anchored on their masks' centroids, latents not shaped by the
    #: motion, by default (version 1 had neither). Version 3: `tilt_object`, a slot named by
    #: the recipe, became `tool_axis_object`, chosen by training. Version 4: the switch
    #: `shading_moments` became `observed_statistics`, "shading" by default. Version 5: the
    #: switches `anchored_centres` and `motion_shapes_latents` went, each keeping version 4's
    #: default (:meth:`upgrade`). Version 6: `observed_statistics` left out is chosen by
    #: training (version 5 read it as "shading"). Version 7: eleven of the method's own
    #: choices left the config for constants of this module (VERSION_7_RETIRED, _DROPPED).
    config_version: int = 7

    # ---- what the model is for (from data) ----
    #: Object slots, in label order (label k of a mask = slot k-1). A scene may leave trailing
    #: slots empty (e.g. two cups of at most three); the slot then uses a learned "absent" latent.
    num_objects: int = 0
    #: Use only the first N labelled objects of every scene, the ones the task is about (the
    #: named object and place of language_pick_place); later labels (distractors) count as
    #: background, in training and in prediction. 0 = training chooses N from the
    #: demonstrations (:mod:`cnfmp.core.task_objects`; the card says what it chose and why)
    #: and writes it here, or leaves 0 when every labelled object gets a slot.
    task_objects: int = 0
    #: Object names of the first demonstration, per slot (for cards and listings).
    object_names: list[str] = field(default_factory=list)
    #: The prompt role filling each slot (target, destination, ...), as `cnfmp dataset
    #: annotate` recorded them; lets prompts drive a model whose task the vocabulary's
    #: task_roles does not list (they win over the vocabulary's for a task of the same name).
    #: Empty: the vocabulary's roles for the task, if any.
    object_roles: list[str] = field(default_factory=list)
    #: Whether each slot was ever empty in training (an empty slot is only accepted then).
    slot_can_be_absent: list[bool] = field(default_factory=list)

    # ---- scene fields ----
    #: Side (px) of the square image the fields are fit to: the camera image, of any size and
    #: aspect ratio, is area-resampled to it (training and prediction alike, so a wide image's
    #: squeeze is learned, not corrected).
    field_resolution: int = 64
    #: Dimension of each object's latent z_i.
    latent_dim: int = 16
    #: Endpoint latents per object (latent relabeling): z_i is a convex combination of these.
    num_endpoints: int = 4
    #: Width of the hidden layers of every coordinate MLP (deformation, appearance, background).
    field_width: int = 64
    #: Hidden layers of each coordinate MLP.
    field_layers: int = 3
    #: Positional-encoding octaves of the deformation fields (kept low: deformations are smooth).
    deformation_octaves: int = 2
    #: Positional-encoding octaves of the appearance and background fields; annealed in
    #: coarse-to-fine over the first ANNEAL_FRACTION of training.
    appearance_octaves: int = 6
    #: Positional-encoding octaves of the background field (annealed like the appearance).
    #: Fewer than the objects': a detailed background paints the average of the objects'
    #: positions into the table and steals their pixels from the experts.
    background_octaves: int = 4
    #: Whether the linear part of each object's deformation is a similarity (turn and scale,
    #: unbounded and linear in the latent) times a bounded stretch, instead of a bounded map
    #: (turns up to ~50 deg, scale within ~+-50%, saturating): the template may then turn by
    #: any angle and scale without saturating (off by default; docs/experiments.md says
    #: where it was measured).
    full_turns: bool = False

    # ---- object-centric pixel sampling ----
    #: Pixels drawn per step from each object's dilated coarse mask.
    pixels_per_object: int = 192
    #: Pixels drawn per step uniformly over the image.
    uniform_pixels: int = 256
    #: Dilation (px at field resolution) of the coarse masks before sampling and inference.
    mask_dilation: int = 3

    #: Which of each object's mask statistics (:data:`cnfmp.core.data.OBSERVATION_NAMES`) the
    #: motion reads beside its latent and centroid, through a learned linear map into the
    #: latent space (one per object slot): "centroid" (none more),
    #: "shading" (the offset from the centroid to the darkness-weighted centroid and the mean
    #: luminance) or "all" (also the elongation, the size and the shaded part's offset).
    #: None (the default) lets training choose "shading" or "all" from the demonstrations
    #: (:mod:`cnfmp.core.statistics_choice`: "all" when it predicts left-out demonstrations
    #: significantly better; the card says what it chose and why).
    #: Shaded faces and the parts under an object's top show on one side of it, which tells a
    #: pose the template's turn cannot: a near-square ramp's template turns with its yaw only
    #: modulo a quarter turn, and the shading shows where the rising edge is (docs/
    #: experiments.md, "Shading moments", "The tool axis chosen by training").
    observed_statistics: str | None = None
    #: Slot (0-based, in label order) of the object whose mask the direction of the tool axis
    #: is read from, or -1 for none; None (the default) lets training choose it from the
    #: demonstrations (:mod:`cnfmp.core.tool_axis`: the object whose mask statistics predict
    #: the demonstrations' swing, when one does; the card says what it chose and why). With a
    #: slot, the two swing outputs of the rotation (where the finger axis points; training
    #: then sets `rotation_chart` "swing_twist") come from a movement primitive of their own
    #: that reads only that object's mask statistics (:data:`cnfmp.core.data.OBSERVATION_NAMES`),
    #: each standardised over the training demonstrations; no latent enters them. A tilt read
    #: through the gated latents fits 20 demonstrations instead of the surface's pose; ten
    #: statistics of one mask do not (docs/experiments.md, "The tilt from the ramp's mask
    #: statistics"). Set -1 to keep the swing with the latents, or a slot to overrule the choice.
    tool_axis_object: int | None = None

    # ---- motion ----
    #: Weight of the penalty on the generator's latent weights (mean square): a ridge that
    #: keeps the motion from reading more out of the latent than the demonstrations support.
    generator_weight_decay: float = 1e-3
    #: Width of the relevance-score network s_i(t) (temporal gating).
    gating_width: int = 32
    #: Whether the temporal gating is learned; False gives the ablation with constant, equal
    #: weights (z(t) = mean of the object latents).
    temporal_gating: bool = True
    #: Steps of the motion refit that ends training: every demonstration's latents are
    #: inferred from its image exactly as for a new scene, and the gating and trajectory
    #: generator alone are fit to them, so the motion reads the latents inference produces
    #: rather than the ones optimised jointly with the scene. 0 skips it.
    motion_refit_steps: int = 500
    #: Time samples per demonstration per training step.
    time_samples: int = 64
    #: Loss weights: trajectory position, rotation (rad), gripper.
    position_weight: float = 1.0
    rotation_weight: float = 1.0
    gripper_weight: float = 0.3

    # ---- training ----
    #: Demonstrations per step (all of them when the dataset is smaller).
    batch_demos: int = 16
    #: Adam learning rate of the networks and of the endpoint and demonstration latents.
    learning_rate: float = 2e-3
    latent_learning_rate: float = 1e-2
    #: Independent initialisations ("draws"), each trained in turn for the first
    #: DRAW_FRACTION of the steps; the one whose trajectory loss is lowest over its last
    #: logged window goes on alone: a guard against an initialisation that settles where the
    #: motion cannot fit the demonstrations (its trajectory loss then stands well above other
    #: seeds' early on; docs/experiments.md, "Training draws"). Draw 0 is the seed's single
    #: run, so 1 draw trains exactly as a plain seeded run.
    draws: int = 1

    # ---- inference ----
    #: The fields below: they change how a trained model predicts, not its weights (training's
    #: motion refit fits the demonstrations' latents with a search of its own,
    #: :data:`cnfmp.core.training_cnfmp.REFIT_SEARCH`; only `inference_pixels` reaches it).
    #: Random simplex points drawn per object, ranked by the centre prior alone (where each
    #: would put the object's centre against its mask's centroid: no image is read, so
    #: thousands cost well under a millisecond); the best `search_candidates` of them go on
    #: to the image search. At most `search_candidates` (0, say) draws exactly those.
    search_pool: int = 2048
    #: Candidates of the cheap search scored on the image: random simplex points (the best of
    #: the pool, plus every training demonstration's weights and the simplex vertices).
    search_candidates: int = 24
    #: A screen before that: every candidate is first scored on this many of those pixels
    #: and only the best `search_screen_keep` go on to all SEARCH_PIXELS (the search costs
    #: candidates x pixels, and most candidates are far off); 0 scores every candidate on
    #: every search pixel.
    search_screen_pixels: int = 32
    search_screen_keep: int = 16
    #: Best candidates refined by gradient steps (multi-start).
    search_starts: int = 4
    #: Adam steps on the simplex logits per start, and their learning rate.
    refine_steps: int = 3
    refine_learning_rate: float = 0.05
    #: Most pixels of an object's dilated mask used by inference.
    inference_pixels: int = 256

    model_type: str = MODEL_TYPE

    @classmethod
    def upgrade(cls, values: dict, version: int, source: str) -> dict:
        """Version 1 -> 2: the fields whose default changed get their version-1 value where
        the file leaves them out. Version 2 -> 3: `tilt_object` is `tool_axis_object` (-1,
        none, where the file leaves it out: a version-2 model never chose one), and the
        fields of VERSION_3_RETIRED go (refused unless they hold the behaviour that stayed).
        Version 3 -> 4: `shading_moments` true is `observed_statistics` "shading", false or
        left out (version 3's default) "centroid". Version 4 -> 5: the fields of
        VERSION_5_RETIRED go, likewise (a version-1 model, which had neither behaviour, is
        refused there). Version 5 -> 6: `observed_statistics` left out is "shading", version
        5's default. Version 6 -> 7: the fields of VERSION_7_DROPPED go whatever their value,
        those of VERSION_7_RETIRED as version 5's did."""
        if version == 1:
            return {**VERSION_1_DEFAULTS, **values}
        if version == 2:
            values = dict(values)
            if "tool_axis_object" not in values:  # both names: tilt_object is refused as unknown
                values["tool_axis_object"] = values.pop("tilt_object", -1)
            return _retire(values, VERSION_3_RETIRED, source)
        if version == 3:
            values = dict(values)
            if "observed_statistics" not in values:  # both names: shading_moments is refused as unknown
                shading = values.pop("shading_moments", False)
                if not isinstance(shading, bool):
                    raise InputError(f"{source}: shading_moments must be true or false, got {shading!r}")
                values["observed_statistics"] = "shading" if shading else "centroid"
            return values
        if version == 4:
            return _retire(dict(values), VERSION_5_RETIRED, source)
        if version == 5:
            return {"observed_statistics": "shading", **values}
        if version == 6:
            values = {k: v for k, v in values.items() if k not in VERSION_7_DROPPED}
            return _retire(values, VERSION_7_RETIRED, source)
        return super().upgrade(values, version, source)

    @property
    def tool_axis_slot(self) -> int:
        """The slot the swing is read from, or -1 (also while training has not chosen yet)."""
        return -1 if self.tool_axis_object is None else self.tool_axis_object

    def check(self, source: str = "config") -> None:
        """InputError for values no model can be built with."""
        super().check(source)
        positive = ["field_resolution", "latent_dim", "num_endpoints", "field_width", "field_layers",
                    "pixels_per_object", "uniform_pixels",
                    "gating_width", "time_samples", "batch_demos", "draws", "search_candidates",
                    "search_starts", "inference_pixels"]
        for name in positive:
            if not isinstance(getattr(self, name), int) or getattr(self, name) < 1:
                raise InputError(f"{source}: {name} must be a whole number >= 1, got {getattr(self, name)!r}")
        for name in ["learning_rate", "latent_learning_rate"]:
            if not getattr(self, name) > 0:
                raise InputError(f"{source}: {name} must be > 0, got {getattr(self, name)!r}")
        for name in ["task_objects", "search_pool", "search_screen_pixels", "search_screen_keep"]:
            if not isinstance(getattr(self, name), int) or getattr(self, name) < 0:
                raise InputError(f"{source}: {name} must be a whole number >= 0, got {getattr(self, name)!r}")
        if self.observed_statistics is not None and self.observed_statistics not in OBSERVED_STATISTICS:
            raise InputError(f"{source}: observed_statistics must be null (training chooses) or one of "
                             f"{', '.join(OBSERVED_STATISTICS)}, got {self.observed_statistics!r}")
        slot = self.tool_axis_object
        if slot is not None and (isinstance(slot, bool) or not isinstance(slot, int) or slot < -1):
            raise InputError(f"{source}: tool_axis_object must be null (training chooses), -1 (none) or an "
                             f"object slot >= 0, got {slot!r}")
        slot = self.tool_axis_slot
        # num_objects is 0 until the config is fitted to demonstrations.
        if 0 < self.num_objects <= slot:
            raise InputError(f"{source}: tool_axis_object is slot {slot} but the model has only "
                             f"{self.num_objects} object slot(s)")
        if 0 <= slot < len(self.slot_can_be_absent) and self.slot_can_be_absent[slot]:
            raise InputError(f"{source}: tool_axis_object is slot {slot}, which some demonstrations lack; "
                             "the tool axis is read from that object's mask in every scene")
        if slot >= 0 and self.rotation_chart != "swing_twist":
            raise InputError(f"{source}: tool_axis_object needs rotation_chart \"swing_twist\" (the tool "
                             "axis's direction is its swing outputs)")
        if slot >= 0 and self.joint_names:
            raise InputError(f"{source}: tool_axis_object reads a pose's swing; a joint-space model has none")


@dataclass
class CnfmpNoGateConfig(CnfmpConfig):
    """The ablation of Table I without temporal gating: every object latent enters the
    motion with the same constant weight, z(t) = mean_i z_i. Otherwise identical to cnfmp."""

    temporal_gating: bool = False
    model_type: str = NOGATE_MODEL_TYPE

    def check(self, source: str = "config") -> None:
        super().check(source)
        if self.temporal_gating:
            raise InputError(f"{source}: {NOGATE_MODEL_TYPE} is the model without temporal gating; "
                             "temporal_gating must be false")
