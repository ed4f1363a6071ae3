"""Prompt templates and object vocabularies, kept as data in the repository's `prompts/`.

Each task has `prompts/<task>.json`; the scene samplers pick a template with their seeded
generator, so a prompt is part of the scene that (task, seed) determines. The directory is
found next to the package source (editable install) or through `CNFMP_PROMPTS_DIR`.
"""

from __future__ import annotations

import functools
import json
import os
from pathlib import Path


def prompts_dir() -> Path:
    configured = os.environ.get("CNFMP_PROMPTS_DIR")
    return Path(configured) if configured else Path(__file__).resolve().parents[2] / "prompts"


@functools.cache
def load(task: str) -> dict:
    """The prompt vocabulary of `task` (the parsed `prompts/<task>.json`)."""
    path = prompts_dir() / f"{task}.json"
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except FileNotFoundError:
        raise RuntimeError(f"prompt file {path} is missing; set CNFMP_PROMPTS_DIR to the repository's prompts/") from None
