"""The one interface every segmenter backend implements, and the loader that picks one.

A backend turns an RGB image and a list of phrases into one probability map per phrase; the
shared OpenCV chain (:mod:`cnfmp.segmenter.postprocess`) turns those into masks, so backends
differ only in how they ground language. Weights always come from local directories: a
missing or invalid directory is an :class:`InputError`, never a hub lookup.

Backends (``name``: weights):
- ``film``: our FiLM U-Net + MiniLM phrase encoder; ``models/segmenter`` by default.
- ``clipseg``: transformers CLIPSeg; a directory laid out like a downloaded
  CIDAS/clipseg-rd64-refined, or ``$CNFMP_CLIPSEG_DIR``.
- ``owlv2-sam``: OWLv2 boxes refined by SAM; a directory holding ``owlv2/`` and ``sam/``, or
  ``$CNFMP_OWLV2_DIR`` and ``$CNFMP_SAM_DIR``. Opt-in: ~40 s per prompt on a CPU.
- ``color``: an HSV heuristic without torch or weights.
- ``auto``: film if its checkpoint loads, else clipseg if configured, else color.
"""

from __future__ import annotations

import abc
import os
from pathlib import Path

import numpy as np

from cnfmp.errors import InputError
from cnfmp.segmenter.postprocess import PostprocessConfig

BACKENDS = ("auto", "film", "clipseg", "owlv2-sam", "color")


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


def default_film_dir() -> Path:
    """The shipped film checkpoint: ``$CNFMP_SEGMENTER_DIR`` or the repository's ``models/segmenter``."""
    configured = os.environ.get("CNFMP_SEGMENTER_DIR")
    return Path(configured) if configured else Path(__file__).resolve().parents[3] / "models" / "segmenter"


def require_dir(path: str | os.PathLike | None, what: str, env: str | None = None) -> Path:
    """`path` as a directory that exists, else an InputError that says how to provide one."""
    if path is None:
        hint = f" (pass a weights directory or set ${env})" if env else ""
        raise InputError(f"no {what} weights directory given{hint}; cnfmp never downloads weights")
    path = Path(path)
    if not path.is_dir():
        raise InputError(f"{what} weights directory {path} does not exist")
    return path


def load_backend(name: str = "auto", weights: str | os.PathLike | None = None) -> Backend:
    """The backend `name` with weights from `weights` (or its default location)."""
    if name not in BACKENDS:
        raise InputError(f"unknown segmenter backend {name!r}; choose one of {', '.join(BACKENDS)}")
    if name == "auto":
        if weights is not None:
            raise InputError("--weights needs an explicit backend (film, clipseg or owlv2-sam), not auto")
        try:
            return load_backend("film")
        except InputError:
            pass
        if os.environ.get("CNFMP_CLIPSEG_DIR"):
            return load_backend("clipseg")
        return load_backend("color")
    if name == "film":
        from cnfmp.segmenter.modeling_film import FilmBackend

        return FilmBackend.from_dir(require_dir(weights or default_film_dir(), "film segmenter", "CNFMP_SEGMENTER_DIR"))
    if name == "clipseg":
        from cnfmp.segmenter.clipseg import ClipSegBackend

        return ClipSegBackend(require_dir(weights or os.environ.get("CNFMP_CLIPSEG_DIR"), "CLIPSeg", "CNFMP_CLIPSEG_DIR"))
    if name == "owlv2-sam":
        from cnfmp.segmenter.owlv2_sam import Owlv2SamBackend

        if weights is not None:
            root = require_dir(weights, "OWLv2 + SAM")
            owlv2, sam = root / "owlv2", root / "sam"
        else:
            owlv2, sam = os.environ.get("CNFMP_OWLV2_DIR"), os.environ.get("CNFMP_SAM_DIR")
        return Owlv2SamBackend(require_dir(owlv2, "OWLv2", "CNFMP_OWLV2_DIR"), require_dir(sam, "SAM", "CNFMP_SAM_DIR"))
    from cnfmp.segmenter.color import ColorBackend

    return ColorBackend()


__all__ = ["BACKENDS", "Backend", "check_image", "default_film_dir", "load_backend", "require_dir"]
