"""Configuration of the CNN-CNMP baseline (paper Table I): a convolutional image encoder whose
feature vector is tiled into a conditional neural movement primitive (CNMP).

The CNMP encodes observed trajectory points (t, y) together with the image feature,
averages them into one representation, and decodes a Gaussian (mean, standard deviation)
for the trajectory at any query time; it is trained by Gaussian negative log-likelihood. At
prediction time it is conditioned on the image and the first trajectory point, which in every
benchmark task is the robot's fixed ready pose.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from cnfmp.core.configuration_common import MotionConfig
from cnfmp.errors import InputError

MODEL_TYPE = "cnn-cnmp"


@dataclass
class CnnCnmpConfig(MotionConfig):
    # ---- from data ----
    #: Generator target (normalised position, rotation vector, gripper; 7 values) of the
    #: demonstrations' first point, averaged: the observation prediction is conditioned on.
    start_target: list[float] = field(default_factory=lambda: [0.0] * 7)

    # ---- image encoder ----
    #: Side (px) of the square image the encoder sees (camera images are area-resized to it);
    #: must be divisible by 2 ** len(conv_channels).
    image_size: int = 128
    #: Output channels of the stride-2, 4x4 convolutions (each halves the image side): the
    #: prior work's 8 -> 128 channel stack for 128 px images.
    conv_channels: list[int] = field(default_factory=lambda: [8, 16, 32, 64, 128])
    #: Size of the image feature vector the convolutions are flattened into.
    image_feature_dim: int = 128

    # ---- CNMP ----
    #: Width and hidden layers of the observation encoder and of the query decoder.
    width: int = 128
    encoder_layers: int = 3
    decoder_layers: int = 3
    #: Observations per training sample: the first point plus up to this many - 1 random
    #: others (1 trains exactly the prediction-time conditioning).
    max_context_points: int = 1
    #: Query times per demonstration per step.
    target_points: int = 64
    #: beta of the beta-NLL loss (Seitzer et al., 2022): 0 is the plain Gaussian NLL, 0.5
    #: weights each point by its predicted standard deviation. The plain NLL lets the model
    #: explain the scenes' differences as variance and keep predicting the mean motion for
    #: thousands of steps before the image starts to matter.
    nll_beta: float = 0.5
    #: Floor of the predicted standard deviation (normalised units), for a stable likelihood.
    min_std: float = 0.01

    # ---- training ----
    #: Demonstrations per step (all of them when the dataset is smaller).
    batch_demos: int = 16
    #: Adam learning rate.
    learning_rate: float = 1e-3

    steps: int = 4000
    model_type: str = MODEL_TYPE

    def check(self, source: str = "config") -> None:
        super().check(source)
        for name in ["image_size", "image_feature_dim", "width", "encoder_layers", "decoder_layers",
                     "max_context_points", "target_points", "batch_demos"]:
            if not isinstance(getattr(self, name), int) or getattr(self, name) < 1:
                raise InputError(f"{source}: {name} must be a whole number >= 1, got {getattr(self, name)!r}")
        if not self.conv_channels or any(not isinstance(c, int) or c < 1 for c in self.conv_channels):
            raise InputError(f"{source}: conv_channels must be a non-empty list of whole numbers >= 1")
        if self.image_size % (2 ** len(self.conv_channels)):
            raise InputError(f"{source}: image_size {self.image_size} is not divisible by 2 ** {len(self.conv_channels)} "
                             "(one halving per convolution)")
        if not (self.learning_rate > 0 and self.min_std > 0):
            raise InputError(f"{source}: learning_rate and min_std must be > 0")
