"""Expert success on held-out scenes: ``python -m cnfmp.sim.validate [--episodes N] [TASK ...]``.

Runs each task's scripted expert on seeds HELDOUT_SEEDS.start, +1, ... in 2 worker processes,
judges every run by physics and prints a JSON line per task with the success count, the
failing seeds with their reasons, and the wall time. This is the benchmark's sanity check:
a task whose expert fails cannot measure anything.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import sys
import time

from cnfmp.seeds import HELDOUT_SEEDS
from cnfmp.sim.tasks import get_task, task_names


def _init() -> None:
    from cnfmp import runtime

    runtime.configure(threads=1)


def _run(args) -> tuple[int, bool, list[str]]:
    from cnfmp.sim import engine

    task_name, seed = args
    task = get_task(task_name)
    scene = task.scene(seed)
    verdict = engine.run_episode(scene, task.expert(scene), task.judge)
    return seed, verdict.success, verdict.reasons


def expert_success(task: str, episodes: int, workers: int = 2) -> dict:
    """Success of `task`'s expert on the first `episodes` held-out seeds."""
    get_task(task)
    seeds = range(HELDOUT_SEEDS.start, HELDOUT_SEEDS.start + episodes)
    start = time.perf_counter()
    with multiprocessing.get_context("spawn").Pool(workers, initializer=_init) as pool:
        results = pool.map(_run, [(task, s) for s in seeds])
    seconds = time.perf_counter() - start
    failures = {seed: reasons for seed, ok, reasons in results if not ok}
    return {"task": task, "episodes": episodes, "successes": episodes - len(failures),
            "first_seed": seeds.start, "failures": failures, "seconds": round(seconds, 1)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("tasks", nargs="*", help="tasks (default: all)")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    for task in args.tasks or task_names():
        print(json.dumps(expert_success(task, args.episodes, args.workers)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
