"""The ``color`` backend: an HSV heuristic needing neither torch nor weights, the fallback
when no learned backend is available.

It grounds only the colour word of a phrase ("red" in "the red ball"): a pixel's probability
falls off with its hue distance from the colour's hue, gated by saturation, or for white,
grey and black by saturation and brightness. It cannot tell a red ball from a red box, and a
phrase without a colour finds nothing, which it reports as such.
"""

from __future__ import annotations

import cv2
import numpy as np

from cnfmp.segmenter.base import Backend
from cnfmp.segmenter.phrases import parse
from cnfmp.segmenter.postprocess import PostprocessConfig

#: Hue centres (degrees on OpenCV's 0-180 scale, i.e. half-degrees) of chromatic colours.
HUES = {"red": 0.0, "orange": 13.0, "yellow": 25.0, "green": 60.0, "blue": 112.0, "purple": 140.0}
#: Hue tolerance (same scale): the probability is exp(-d^2 / (2 sigma^2)).
HUE_SIGMA = 6.0
#: Saturation (0-255) above which a pixel counts as chromatic.
MIN_SATURATION = 90
#: Achromatic colours: value (0-255) range; saturation must be below MAX_GREY_SATURATION.
VALUES = {"white": (200, 256), "grey": (90, 200), "black": (0, 60)}
MAX_GREY_SATURATION = 40


class ColorBackend(Backend):
    name = "color"
    postprocess = PostprocessConfig(threshold=0.5, min_score=0.6)

    def probabilities(self, image: np.ndarray, phrases: list[str]) -> np.ndarray:
        hsv = cv2.cvtColor(np.ascontiguousarray(image, dtype=np.uint8), cv2.COLOR_RGB2HSV).astype(np.float32)
        hue, saturation, value = hsv[..., 0], hsv[..., 1], hsv[..., 2]
        maps = []
        for phrase in phrases:
            found = parse(phrase) if phrase.strip() else []
            colour = found[0].colour if found else None
            if colour in HUES:
                distance = np.abs(hue - HUES[colour])
                distance = np.minimum(distance, 180.0 - distance)  # hue is circular
                chroma = np.clip((saturation - MIN_SATURATION) / 40.0, 0.0, 1.0)
                maps.append(np.exp(-distance**2 / (2 * HUE_SIGMA**2)) * chroma)
            elif colour in VALUES:
                low, high = VALUES[colour]
                grey = (saturation < MAX_GREY_SATURATION) & (value >= low) & (value < high)
                maps.append(grey.astype(np.float32))
            else:
                maps.append(np.zeros(hue.shape, np.float32))
        return np.stack(maps).astype(np.float32)


__all__ = ["ColorBackend"]
