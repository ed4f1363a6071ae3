"""The scene seed ranges, read from ``seeds.json`` next to this file: the one source that the
Rust binary compiles in too, so Python and Rust cannot disagree on which seeds are for what.

A scene is fully determined by (task, seed). Training scenes and demonstrations take seeds
from ``TRAIN_SEEDS`` (datasets number from its start); validation scenes, on which scripts
study and tune models, are the upper part of it, far above any dataset's demonstrations;
evaluation uses ``HELDOUT_SEEDS`` alone, disjoint from training. The grid-trained NFMP
baseline trains on the ``NFMP_GRID_SEEDS`` scenes of ``NFMP_GRID_TASK``, training seeds that
the task lays out as a parameter grid.
"""

from __future__ import annotations

import json
from pathlib import Path

_RANGES = json.loads(Path(__file__).with_name("seeds.json").read_text(encoding="utf-8"))

#: Seeds for training scenes and demonstrations.
TRAIN_SEEDS = range(*_RANGES["training"])
#: Seeds for validation scenes: part of TRAIN_SEEDS that no dataset's demonstrations reach.
VALIDATION_SEEDS = range(*_RANGES["validation"])
#: Seeds for held-out scenes (evaluation); disjoint from TRAIN_SEEDS.
HELDOUT_SEEDS = range(*_RANGES["heldout"])
#: The task and the seeds of the grid-trained NFMP baseline's scenes (one per grid cell).
NFMP_GRID_TASK = _RANGES["nfmp_grid"]["task"]
NFMP_GRID_SEEDS = range(*_RANGES["nfmp_grid"]["seeds"])

__all__ = ["HELDOUT_SEEDS", "NFMP_GRID_SEEDS", "NFMP_GRID_TASK", "TRAIN_SEEDS", "VALIDATION_SEEDS"]
