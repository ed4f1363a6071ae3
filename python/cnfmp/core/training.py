"""Training one model of any type (:mod:`cnfmp.core.models`) from a dataset: the seeded run
of ``cnfmp train``. Reads the config files, runs the type's training and writes the model
directory: ``config.json``, ``model.safetensors`` and a ``README.md`` card.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
from collections.abc import Sequence

import torch

from cnfmp.artifacts import publish_directory
from cnfmp.configuration import read_json_object
from cnfmp.core import data as core_data
from cnfmp.core import models
from cnfmp.core.alignment import align_demonstrations
from cnfmp.core.configuration_cnfmp import CnfmpConfig
from cnfmp.core.task_objects import choose_task_objects
from cnfmp.errors import InputError

#: A config file section of earlier versions (inference settings applied after training's
#: motion refit). The refit now runs its own search (training_cnfmp.REFIT_SEARCH), so the
#: inference settings at a file's top level are the ones the model ships with.
RETIRED_SECTION = "after_training"


def train(dataset_dir: str, out_dir: str, config_paths: Sequence[str] = (), steps: int | None = None,
          seed: int | None = None, command: str = "", progress: bool = True, model_type: str | None = None,
          recording: core_data.RecordingOptions = core_data.RecordingOptions(), align_time: bool = True) -> str:
    """Trains a model of `model_type` (see :mod:`cnfmp.core.models`; by default the config
    files', else cnfmp) on the LeRobot dataset at `dataset_dir` and writes the model
    directory `out_dir` (must not exist; written to a temporary sibling and renamed when
    complete). The config files layer as :func:`read_configs` says. `recording` says which
    camera and motion vector to read; with `align_time` the demonstrations are first aligned
    by their gripper events (:mod:`cnfmp.core.alignment`).

    Returns JSON ``{"out", "task", "model_type", "demos", "steps", "seconds", "final_losses", "parameters"}``.
    """
    if os.path.exists(out_dir):
        raise InputError(f"{out_dir} already exists; models are never overwritten, choose a new --out")
    values, source = read_configs(config_paths)
    model_type = model_type or values.get("model_type") or models.DEFAULT_MODEL_TYPE
    kind = models.model_type(str(model_type))
    config = kind.config_class.from_dict(values, source=source)
    overrides = {k: v for k, v in (("steps", steps), ("seed", seed)) if v is not None}
    config = dataclasses.replace(config, **overrides)
    config.check()
    demos = core_data.load_demonstrations(dataset_dir, recording)
    timing = "as recorded"
    if align_time:
        trajectories, aligned = align_demonstrations(demos.trajectories, demos.fps, poses=not demos.joint_names)
        demos = dataclasses.replace(demos, trajectories=trajectories, timing=aligned.timing())
        timing = aligned.describe()
    objects = None  # how the task's objects were chosen, for the log and the card
    if isinstance(config, CnfmpConfig):
        if config.task_objects:
            objects = f"the first {config.task_objects} (set by the config)"
        else:
            choice = choose_task_objects(demos)
            objects = choice.describe()
            if choice.drops_objects:
                config = dataclasses.replace(config, task_objects=choice.count)
        if config.task_objects:
            demos = core_data.keep_task_objects(demos, config.task_objects)
    log = (lambda line: print(line, file=sys.stderr, flush=True)) if progress else None
    if log:
        log(f"training {kind.name} on {len(demos)} {demos.task} demonstrations from {dataset_dir}, "
            f"{config.steps} steps, seed {config.seed}")
        log(f"camera {demos.camera}; motion {demos.motion}; timing: {timing}")
        if objects:
            log(f"task objects: {objects}")
    model, summary = kind.train(demos, config, log)

    def fill(staging: str) -> None:
        models.save_model(model, staging)
        with open(os.path.join(staging, models.CARD_FILE), "w", encoding="utf-8") as f:
            f.write(model_card(kind, model.config, summary, dataset_dir, demos, command, timing, objects))

    publish_directory(out_dir, fill)
    return json.dumps({"out": out_dir, "task": demos.task, "model_type": kind.name, **summary})


def read_configs(paths: Sequence[str]) -> tuple[dict, str]:
    """The fields of the config files `paths` layered in order (a later file's field wins)
    and the files' names for messages. No file: every field at its default."""
    values: dict = {}
    for path in paths:
        layer = read_json_object(path)
        if RETIRED_SECTION in layer:
            raise InputError(f"{path}: the {RETIRED_SECTION!r} section is no longer read: training's motion refit "
                             "runs its own search, so put these inference settings at the file's top level, "
                             "where they are what the model ships with")
        values.update(layer)
    return values, " + ".join(map(str, paths)) or "config"


def model_card(kind: models.ModelType, config, summary: dict, dataset_dir: str, demos: core_data.Demonstrations,
               command: str, timing: str = "as recorded", task_objects: str | None = None) -> str:
    seeds = [s for s in demos.seeds if s >= 0]
    seed_text = f"{min(seeds)}..{max(seeds)}" if seeds else "not recorded"
    losses = ", ".join(f"{name.replace('_', ' ')} {value:.5f}" for name, value in summary["final_losses"].items())
    objects = (f"| objects (slots, label order) | {', '.join(config.object_names)} |\n"
               if getattr(config, "object_names", None) else "")
    if demos.scans:
        views = demos.scans[0].views
        objects += f"| scans | {len(views)} views ({', '.join(v.name for v in views)}) per demonstration |\n"
    if task_objects:
        objects += f"| task objects | {task_objects} |\n"
    extra = (f" (plus {len(demos) * config.num_objects * config.num_endpoints} demonstration simplex weights)"
             if isinstance(config, CnfmpConfig) else "")
    segments = f"| segment timing | {summary['segment_timing']} |\n" if summary.get("segment_timing") else ""
    if summary.get("tool_axis"):
        objects += f"| tool axis | {summary['tool_axis']} |\n"
    if summary.get("observed_statistics"):
        objects += f"| mask statistics read | {summary['observed_statistics']} |\n"
    choice = summary.get("draws")
    draws = (f"| draws | {choice['count']} initialisations trained {choice['steps']} steps each; draw "
             f"{choice['chosen'] + 1} went on (trajectory loss then: "
             f"{', '.join(f'{v:.5f}' for v in choice['motion_mse'])}) |\n" if choice else "")
    return f"""# cnfmp model: {config.task} ({kind.name})

{kind.summary}, trained by `cnfmp train --model-type {kind.name}`.

| | |
|---|---|
| task | `{config.task}` |
| model type | `{kind.name}` |
{objects}| dataset | `{os.path.basename(os.path.abspath(dataset_dir))}`: {len(demos)} demonstrations, scene seeds {seed_text} |
| steps | {summary['steps']} (seed {config.seed}) |
| wall time | {summary['seconds']:.0f} s, {torch.get_num_threads()} torch thread(s) |
| parameters | {summary['parameters']:,}{extra} |
{draws}| final losses | {losses} (normalised units) |
| camera | `{demos.camera}` |
| motion | {demos.motion} |
| timing | {timing} |
{segments}| trajectory | {config.duration_s:.1f} s at {config.output_fps:g} Hz |

Command:

```
{command or "cnfmp train --dataset " + dataset_dir + " --out <dir>"}
```

Held-out metrics: see `docs/benchmarks.md` (`cnfmp eval --model <dir> --task {config.task} ...`).
"""
