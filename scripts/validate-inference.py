"""Compares inference settings of a core model on validation scenes: training-range seeds
that no shipped model was trained on (by default from the first validation seed; the
demonstrations use 0..99), never the held-out range, so choosing a setting here leaves the
held-out figures unbiased.

For each scene: render, take the coarse masks from the simulator (`--masks simulator`, as
`cnfmp eval` does) or segment the scene's prompt with the film backend (`--masks prompt`, as
the HTTP API does), predict with the model's config overridden by the variant, execute by
physics.
Prints one JSON line per variant: success rate, the predict call's p50 latency and the mean
scene-fit PSNR.

Blind spot: training-range language_pick_place scenes never show the held-out object
instances (colour and category combinations kept out of training), where inference is
hardest, so a cheaper setting can look as good here as it is not on held-out scenes
(docs/experiments.md, HTTP serving: search_starts 2).

    .venv/bin/python scripts/validate-inference.py --model models/language_pick_place \\
        --scenes 80 '{}' '{"search_starts": 2}'
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from cnfmp import runtime

runtime.configure(threads=1)  # before torch loads: one thread, deterministic kernels, as the CLI runs

from cnfmp.core import api as core, trial  # noqa: E402
from cnfmp.errors import InputError  # noqa: E402
from cnfmp.seeds import VALIDATION_SEEDS  # noqa: E402
from cnfmp.segmenter import api as segmenter  # noqa: E402


def validate(model_dir: str, task: str, variant: dict, scenes: int, seed_start: int, masks: str,
             segmenter_weights: str | None = None) -> dict:
    predictor = core.predictor(model_dir)
    original = {name: getattr(predictor.config, name) for name in variant}
    for name, value in variant.items():
        setattr(predictor.config, name, value)
    successes, latencies, psnrs = 0, [], []
    try:
        for seed in range(seed_start, seed_start + scenes):
            image, labels, info = trial.render(task, seed)
            names = info["objects"]
            if masks == "prompt":
                try:
                    found = segmenter.segment(image, info["prompt"], "film", segmenter_weights, task, pictures=False)
                except InputError:
                    continue  # not grounded: a failed scene
                labels, names = found["labels_png"], found["slot_names"]
            started = time.perf_counter()
            result = json.loads(core.predict(model_dir, image, labels, names))
            latencies.append(time.perf_counter() - started)
            psnrs.append(result["scene_psnr_db"])
            successes += trial.execute(task, seed, *trial.trajectory_arrays(result))[0]
    finally:
        for name, value in original.items():
            setattr(predictor.config, name, value)
    return {"variant": variant, "masks": masks, "scenes": scenes, "seed_start": seed_start, "success": successes / scenes,
            "predict_p50_ms": round(1000 * float(np.median(latencies)), 1) if latencies else None,
            "scene_psnr_db_mean": round(float(np.mean(psnrs)), 2) if psnrs else None}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", required=True, help="core model directory")
    parser.add_argument("--task", default=None, help="task (default: the model's)")
    parser.add_argument("--scenes", type=int, default=80)
    parser.add_argument("--seed-start", type=int, default=VALIDATION_SEEDS.start)
    parser.add_argument("--masks", choices=["prompt", "simulator"], default="prompt",
                        help="coarse masks from the segmenter (default) or the simulator")
    parser.add_argument("--segmenter-weights", default=None,
                        help="film segmenter directory for --masks prompt (default: models/segmenter)")
    parser.add_argument("variants", nargs="+", help='JSON objects of config overrides, e.g. \'{"search_starts": 2}\'')
    args = parser.parse_args()
    problem = trial.validation_range_error(args.seed_start, args.scenes)
    if problem:
        parser.error(problem)
    task = args.task or core.predictor(args.model).config.task
    for variant in args.variants:
        print(json.dumps(validate(args.model, task, json.loads(variant), args.scenes, args.seed_start, args.masks,
                                  args.segmenter_weights)),
              flush=True)


if __name__ == "__main__":
    main()
