"""Pictures of every task for the docs: ``python -m cnfmp.sim.gallery OUT_DIR [--seed S]``.

For each task writes ``OUT_DIR/<task>.png``: the scene image beside its object masks (each
label in its own colour), scaled 2x, from the held-out scene `seed`.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from cnfmp.seeds import HELDOUT_SEEDS
from cnfmp.sim.tasks import get_task, task_names

# Label colours for the mask panel (background black).
_PALETTE = np.array([[0, 0, 0], [230, 25, 75], [60, 180, 75], [255, 225, 25], [0, 130, 200],
                     [245, 130, 48], [145, 30, 180], [70, 240, 240], [240, 50, 230]], dtype=np.uint8)


def task_picture(task: str, seed: int) -> np.ndarray:
    """(256, 512, 3) uint8: scene image and coloured masks side by side, scaled 2x."""
    from cnfmp.sim import engine

    sim = engine.Simulation(get_task(task).scene(seed))
    try:
        rgb, labels = sim.render_scene()
    finally:
        sim.close()
    picture = np.concatenate([rgb, _PALETTE[labels % len(_PALETTE)]], axis=1)
    return picture.repeat(2, axis=0).repeat(2, axis=1)


def main(argv=None) -> int:
    from PIL import Image

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out_dir")
    parser.add_argument("--seed", type=int, default=HELDOUT_SEEDS.start)
    args = parser.parse_args(argv)
    os.makedirs(args.out_dir, exist_ok=True)
    for task in task_names():
        path = os.path.join(args.out_dir, f"{task}.png")
        Image.fromarray(task_picture(task, args.seed)).save(path, optimize=True)
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
