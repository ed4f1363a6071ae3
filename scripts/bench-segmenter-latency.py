"""Latency of the language segmenter with the backend loaded: one prompt on a 128x128 render
(parse, ground, OpenCV post-processing), over held-out language_pick_place scenes with their
own prompts. Phrase embeddings are cached by the film backend, so two figures are printed:
every phrase new to the encoder (cache cleared before each call) and the cache warm (the
same prompts again, as a server sees them).

Usage: .venv/bin/python scripts/bench-segmenter-latency.py [--backend film] [--scenes 50]
"""

import argparse
import time

import numpy as np

from cnfmp import runtime

runtime.configure(threads=1)

from cnfmp.seeds import HELDOUT_SEEDS  # noqa: E402
from cnfmp.segmenter import segment  # noqa: E402
from cnfmp.segmenter.backends import load_backend  # noqa: E402
from cnfmp.segmenter.training_film import render_scene  # noqa: E402
from cnfmp.sim.tasks import get_task  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backend", default="film")
    parser.add_argument("--scenes", type=int, default=50)
    args = parser.parse_args()
    backend = load_backend(args.backend)
    task = get_task("language_pick_place")
    scenes = [(render_scene("language_pick_place", s)[0], task.scene(s).prompt)
              for s in HELDOUT_SEEDS[:args.scenes]]
    segment(*scenes[0], backend)  # first call: lazy initialisation
    cache = getattr(getattr(backend, "encoder", None), "cache", None)
    for label in ("cold phrase cache", "warm phrase cache"):
        times = []
        for image, prompt in scenes:
            if label.startswith("cold") and cache is not None:
                cache.clear()
            started = time.perf_counter()
            segment(image, prompt, backend)
            times.append(1e3 * (time.perf_counter() - started))
        print(f"{args.backend}, 128x128, one prompt ({label}), {len(times)} scenes: "
              f"p50 {np.percentile(times, 50):.1f} ms, p95 {np.percentile(times, 95):.1f} ms")


if __name__ == "__main__":
    main()
