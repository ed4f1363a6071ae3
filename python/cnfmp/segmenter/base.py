"""The one interface every segmenter backend implements, and the checks they share.

A backend turns an RGB image and a list of phrases into one probability map per phrase; the
shared OpenCV chain (:mod:`cnfmp.segmenter.postprocess`) turns those into masks, so backends
differ only in how they ground language. The backends themselves, and the loader that picks
one by name, are in :mod:`cnfmp.segmenter.backends`.
"""

from __future__ import annotations

import abc

import numpy as np

from cnfmp.errors import InputError
from cnfmp.segmenter.postprocess import PostprocessConfig


class Backend(abc.ABC):
    """A way to ground phrases in an image."""

    #: Backend name as the CLI and config spell it.
    name: str = ""
    #: Post-processing settings tuned for this backend's probabilities.
    postprocess: PostprocessConfig = PostprocessConfig()
    #: Whether the backend can ground words outside prompts/vocabulary.json (pretrained
    #: vision-language models can; film and color only know the vocabulary, so a phrase the
    #: parser cannot ground is answered "not found" without asking them).
    open_vocabulary: bool = False
    #: Whether the backend grounds a category alone ("cube": every cube, whatever its colour).
    #: Such a backend is asked about the category when a coloured phrase lights up several
    #: objects, and the one that is also of the category wins (see :func:`cnfmp.segmenter.segment`).
    grounds_categories: bool = False

    @abc.abstractmethod
    def probabilities(self, image: np.ndarray, phrases: list[str]) -> np.ndarray:
        """(H, W, 3) uint8 RGB and P phrases -> (P, H, W) float32 probabilities in [0, 1] at
        the image's resolution: how likely each pixel belongs to the object each phrase names."""

    def describe(self) -> dict:
        """Name and weights, for reports."""
        return {"backend": self.name}

    def warm(self, phrases: list[str]) -> None:
        """Prepares for `phrases` (e.g. caches their text embeddings) so the first request
        naming them is as fast as later ones; nothing by default."""


#: Smallest image side accepted (px): below it there is nothing to segment.
MIN_IMAGE_SIDE = 8


def check_image(image: np.ndarray) -> np.ndarray:
    """`image` as a contiguous (H, W, 3) uint8 array, or an InputError naming what is wrong."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise InputError(f"the image must be (H, W, 3) uint8 RGB, got shape {image.shape} and dtype {image.dtype}")
    if min(image.shape[:2]) < MIN_IMAGE_SIDE:
        raise InputError(f"the image is {image.shape[1]}x{image.shape[0]} px; each side must be at least "
                         f"{MIN_IMAGE_SIDE} px")
    return np.ascontiguousarray(image)


__all__ = ["Backend", "check_image"]
