"""Writing an artifact (a trained model's directory, a picture) so that it appears complete
or not at all.

The files are written into a private sibling directory which is renamed into place once
everything is there: an interrupted run never leaves a directory that looks like a model.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from typing import Callable

from cnfmp.errors import InputError


def publish_directory(out_dir: str, fill: Callable[[str], None]) -> None:
    """Creates `out_dir` (must not exist) holding what `fill(staging_dir)` writes.

    Files are made world-readable (0644, directory 0755): mkdtemp's private modes are
    wrong for an artifact meant to be shared and committed.
    """
    if os.path.exists(out_dir):
        raise InputError(f"{out_dir} already exists; models are never overwritten, choose a new --out")
    parent = os.path.dirname(os.path.abspath(out_dir))
    os.makedirs(parent, exist_ok=True)
    staging = tempfile.mkdtemp(prefix=".cnfmp-model-", dir=parent)
    try:
        fill(staging)
        os.chmod(staging, 0o755)
        for name in os.listdir(staging):
            os.chmod(os.path.join(staging, name), 0o644)
        os.rename(staging, out_dir)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise


def write_bytes_atomically(path: str, data: bytes) -> None:
    """Writes `data` to `path` through a temporary sibling renamed over it (mode 0644)."""
    parent = os.path.dirname(os.path.abspath(path))
    os.makedirs(parent, exist_ok=True)
    handle, staging = tempfile.mkstemp(prefix=".cnfmp-", dir=parent)
    try:
        with os.fdopen(handle, "wb") as f:
            f.write(data)
        os.chmod(staging, 0o644)
        os.replace(staging, path)
    except BaseException:
        if os.path.exists(staging):
            os.unlink(staging)
        raise


__all__ = ["publish_directory", "write_bytes_atomically"]
