"""Scene-fit pictures of trained models, like the paper's Fig. 1: for a held-out scene, the
camera image, the model's reconstruction, the learned masks (soft competition, argmax) and
the coarse masks it was given.

``python -m cnfmp.core.figures MODELS_DIR OUT_DIR [--seed SEED]`` (by default the first held-out
seed) writes ``OUT_DIR/<task>.png`` for every model directory in MODELS_DIR.
"""

from __future__ import annotations

import argparse
import json
import os

import numpy as np

from cnfmp.images import LABEL_PALETTE as PALETTE
from cnfmp.seeds import HELDOUT_SEEDS


def scene_fit_picture(model_dir: str, seed: int) -> np.ndarray:
    """(128, 512, 3) uint8: image | reconstruction | learned masks | coarse masks."""
    import cv2

    from cnfmp.core.api import predictor
    from cnfmp.core.data import task_object_labels
    from cnfmp.sim import engine
    from cnfmp.sim.tasks import get_task

    model = predictor(model_dir)
    task = get_task(model.config.task)
    scene = task.scene(seed)
    sim = engine.Simulation(scene)
    try:
        image, labels = sim.render_rgb(), sim.render_labels()
    finally:
        sim.close()
    if model.config.task_objects:  # distractors are background to this model, as in predict
        labels = task_object_labels(labels, model.config.task_objects)
    result = model.predict(image, labels)
    n = model.config.num_objects
    owner = result["learned_masks"]  # slot index, n = background
    learned = np.where(owner == n, 0, owner + 1).astype(np.int64)
    size = image.shape[0]

    def up(picture):
        return cv2.resize(picture, (size, size), interpolation=cv2.INTER_NEAREST)

    return np.concatenate([image, up(result["reconstruction"]), up(PALETTE[learned % len(PALETTE)]),
                           PALETTE[labels.astype(np.int64) % len(PALETTE)]], axis=1)


def main(argv=None) -> None:
    from PIL import Image

    from cnfmp import runtime

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("models_dir")
    parser.add_argument("out_dir")
    parser.add_argument("--seed", type=int, default=HELDOUT_SEEDS.start)
    args = parser.parse_args(argv)
    runtime.configure(1)
    os.makedirs(args.out_dir, exist_ok=True)
    from cnfmp.core.models import model_types

    for name in sorted(os.listdir(args.models_dir)):
        model_dir = os.path.join(args.models_dir, name)
        config = os.path.join(model_dir, "config.json")
        if not os.path.isfile(config):
            continue
        with open(config, encoding="utf-8") as f:
            kind = json.load(f).get("model_type")
        if kind in model_types():  # core models only: models/ also holds the segmenter's checkpoint
            out = os.path.join(args.out_dir, f"{name}.png")
            Image.fromarray(scene_fit_picture(model_dir, args.seed)).save(out)
            print(out)


if __name__ == "__main__":
    main()
