"""OpenCV post-processing shared by every segmenter backend: a per-phrase probability map ->
one coarse object mask with its score, bounding box, centroid and area.

Chain: threshold, morphological opening then closing (kernel scaled to the image), connected
components, drop components under the minimum area, keep the component holding the most
probability (a phrase names one object). Costs ~0.3 ms at 128x128 (facts.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class PostprocessConfig:
    """Fields:
        threshold: probability above which a pixel belongs to the phrase's object.
        min_area_fraction: components smaller than this fraction of the image are dropped
            (0.0005 = 8 px at 128x128).
        min_score: a mask whose mean probability is below this is reported as not found.
        kernel_fraction: morphology kernel side as a fraction of the shorter image side
            (at least 1 px; 0.02 = 3 px at 128x128).
    """

    threshold: float = 0.5
    min_area_fraction: float = 0.0005
    min_score: float = 0.6
    kernel_fraction: float = 0.02


@dataclass
class ObjectMask:
    """One phrase's result. ``mask`` is (H, W) bool; bbox is [x0, y0, x1, y1) in pixels;
    centroid is (x, y) in pixels; score in [0, 1] is the mean probability inside the mask,
    or the highest probability anywhere when nothing was found."""

    mask: np.ndarray
    found: bool
    score: float
    area: int
    bbox: list[int] | None
    centroid: list[float] | None
    candidates: int = 0


def _as_probability(array: np.ndarray) -> np.ndarray:
    return np.nan_to_num(np.asarray(array, dtype=np.float32), nan=0.0).clip(0.0, 1.0)


def extract(probability: np.ndarray, config: PostprocessConfig = PostprocessConfig(),
            support: np.ndarray | None = None) -> ObjectMask:
    """(H, W) float probabilities in [0, 1] -> the phrase's object mask.

    `support`, (H, W) probabilities of a looser description of the same object, re-ranks the
    candidate components by their probability mass times the support's mean inside them
    (mass alone breaks ties, e.g. a support that is zero everywhere); the chosen mask and its
    score still come from `probability`.
    """
    probability = _as_probability(probability)
    support = None if support is None else _as_probability(support)
    height, width = probability.shape
    binary = (probability > config.threshold).astype(np.uint8)
    side = max(1, round(config.kernel_fraction * min(height, width)))
    if side > 1:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (side, side))
        binary = cv2.morphologyEx(binary, cv2.MORPH_OPEN, kernel)
        binary = cv2.morphologyEx(binary, cv2.MORPH_CLOSE, kernel)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8)
    min_area = max(1, round(config.min_area_fraction * height * width))
    best, best_mass, best_rank, candidates = 0, 0.0, (0.0, 0.0), 0
    for label in range(1, count):
        if stats[label, cv2.CC_STAT_AREA] < min_area:
            continue
        candidates += 1
        inside = labels == label
        mass = float(probability[inside].sum())
        rank = (mass * (1.0 if support is None else float(support[inside].mean())), mass)
        if rank > best_rank:
            best, best_mass, best_rank = label, mass, rank
    peak = float(probability.max(initial=0.0))
    if best == 0:
        return ObjectMask(np.zeros((height, width), bool), False, peak, 0, None, None, candidates)
    mask = labels == best
    area = int(stats[best, cv2.CC_STAT_AREA])
    score = best_mass / area
    x, y, w, h = (int(stats[best, k]) for k in (cv2.CC_STAT_LEFT, cv2.CC_STAT_TOP, cv2.CC_STAT_WIDTH, cv2.CC_STAT_HEIGHT))
    ys, xs = np.nonzero(mask)
    found = score >= config.min_score
    if not found:
        return ObjectMask(np.zeros((height, width), bool), False, score, 0, None, None, candidates)
    return ObjectMask(mask, True, score, area, [x, y, x + w, y + h], [float(xs.mean()), float(ys.mean())],
                      candidates)


def label_map(probabilities: np.ndarray, results: list[ObjectMask]) -> np.ndarray:
    """(P, H, W) probabilities and the phrases' masks -> (H, W) uint8 labels (0 background, k
    the k-th phrase); where masks overlap, the phrase with the higher probability wins."""
    labels = np.zeros(probabilities.shape[1:], np.uint8)
    best = np.zeros(probabilities.shape[1:], np.float32)
    for k, (probability, result) in enumerate(zip(probabilities, results), start=1):
        claim = result.mask & (probability > best)
        labels[claim], best[claim] = k, probability[claim]
    return labels


__all__ = ["ObjectMask", "PostprocessConfig", "extract", "label_map"]
