"""Pictures of every task for the docs: ``python -m cnfmp.sim.gallery OUT_DIR [--seed S]``.

For each task writes ``OUT_DIR/<task>.png``: the scene image beside its object masks (each
label in its own colour), scaled 2x, from the held-out scene `seed`; with ``--scan TASK``,
also ``OUT_DIR/<TASK>_scan.png``: that scene's four scan views (:mod:`cnfmp.sim.scan`), RGB
above depth (near light, far dark) above labels.
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


def scan_picture(task: str, seed: int) -> np.ndarray:
    """(3 * 128, 4 * 128, 3) uint8: each scan view's RGB, depth and labels in a column."""
    from cnfmp.sim import scan

    columns = []
    for view in scan.render_scan(get_task(task).scene(seed)).views:
        measured = view.depth > 0
        near, far = np.percentile(view.depth[measured], [1, 99]) if measured.any() else (0.0, 1.0)
        shade = np.where(measured, 255 * (1 - np.clip((view.depth - near) / max(far - near, 1e-6), 0, 1)), 0)
        depth = np.repeat(shade.astype(np.uint8)[..., None], 3, axis=2)
        columns.append(np.concatenate([view.rgb, depth, _PALETTE[view.labels % len(_PALETTE)]], axis=0))
    return np.concatenate(columns, axis=1)


def main(argv=None) -> int:
    from PIL import Image

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out_dir")
    parser.add_argument("--seed", type=int, default=HELDOUT_SEEDS.start)
    parser.add_argument("--scan", metavar="TASK", help="also picture this task's scan views")
    args = parser.parse_args(argv)
    os.makedirs(args.out_dir, exist_ok=True)
    for task in task_names():
        path = os.path.join(args.out_dir, f"{task}.png")
        Image.fromarray(task_picture(task, args.seed)).save(path, optimize=True)
        print(path)
    if args.scan:
        path = os.path.join(args.out_dir, f"{args.scan}_scan.png")
        Image.fromarray(scan_picture(args.scan, args.seed)).save(path, optimize=True)
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
