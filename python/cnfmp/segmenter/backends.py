"""The segmenter backends by name, and the loader that picks one (each implements
:class:`cnfmp.segmenter.base.Backend`). Weights always come from local directories: a
missing or invalid directory is an :class:`InputError`, never a hub lookup. Each backend's
module is imported when it is loaded: torch and transformers are heavy.

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

import os
from pathlib import Path

from cnfmp.errors import InputError
from cnfmp.segmenter.base import Backend

BACKENDS = ("auto", "film", "clipseg", "owlv2-sam", "color")


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


__all__ = ["BACKENDS", "default_film_dir", "load_backend", "require_dir"]
