"""One trial of a core model on a simulator scene: render it, predict from its image and
coarse masks, execute the prediction by physics. It is what `cnfmp eval` does per episode,
for the scripts that study models on validation scenes (`scripts/validate-inference.py`,
`scripts/release-errors.py`), which must never touch the held-out seeds.
"""

from __future__ import annotations

import json
import tempfile

import numpy as np

from cnfmp.errors import InputError
from cnfmp.seeds import TRAIN_SEEDS
from cnfmp.sim import api as sim


def validation_range_error(seed_start: int, scenes: int) -> str | None:
    """Why scenes `seed_start`.. (`scenes` of them) may not be used to study a model, or None
    when they lie in the training range (held-out scenes are for `cnfmp eval` alone)."""
    if scenes < 1:
        return "--scenes must be at least 1"
    if seed_start < TRAIN_SEEDS.start or seed_start + scenes > TRAIN_SEEDS.stop:
        return (f"scenes must stay in the training range (seeds {TRAIN_SEEDS.start}..{TRAIN_SEEDS.stop - 1}); "
                "held-out scenes are for cnfmp eval")
    return None


def render(task: str, seed: int) -> tuple[bytes, bytes, dict]:
    """The scene as `cnfmp sim render` writes it: image PNG, label-map PNG and the
    objects.json content (``{"task", "seed", "prompt", "objects"}``)."""
    with tempfile.TemporaryDirectory() as scratch:
        info = json.loads(sim.render(task, seed, f"{scratch}/scene"))
        with open(f"{scratch}/scene/image.png", "rb") as file:
            image = file.read()
        with open(f"{scratch}/scene/masks.png", "rb") as file:
            labels = file.read()
    return image, labels, info


def trajectory_arrays(prediction: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A prediction's frames (the trajectory JSON of `cnfmp predict`) as position (T, 3) m,
    orientation (T, 4) wxyz and gripper (T,) arrays."""
    frames = prediction["frames"]
    return tuple(np.array([f[key] for f in frames]) for key in ("position", "orientation", "gripper"))


def execute(task: str, seed: int, position: np.ndarray, orientation: np.ndarray,
            gripper: np.ndarray) -> tuple[bool, list[str]]:
    """The physics verdict of a trajectory on the scene: (success, reasons). A trajectory
    that leaves the workspace is a failed scene, its reason the simulator's message."""
    try:
        verdict = json.loads(sim.execute(task, seed, position, orientation, gripper))
    except InputError as error:
        return False, [str(error)]
    return bool(verdict["success"]), verdict["reasons"]
