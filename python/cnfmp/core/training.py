"""Training one model of any type (:mod:`cnfmp.core.models`) from a dataset: the seeded run
of ``cnfmp train``. Reads the config file (with its ``after_training`` section), runs the
type's training and writes the model directory: ``config.json``, ``model.safetensors`` and
a ``README.md`` card.
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
from cnfmp.errors import InputError

#: Key of a config file's section of inference settings that the model ships with, set after
#: training: training's motion refit runs inference with the values outside it, so a
#: setting chosen on validation scenes after a model was trained changes its predictions
#: without changing its weights, and the file still reproduces the shipped model.
AFTER_TRAINING = "after_training"


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
    values, after_training, source = read_configs(config_paths)
    model_type = model_type or values.get("model_type") or models.DEFAULT_MODEL_TYPE
    kind = models.model_type(str(model_type))
    config = kind.config_class.from_dict(values, source=source)
    overrides = {k: v for k, v in (("steps", steps), ("seed", seed)) if v is not None}
    config = dataclasses.replace(config, **overrides)
    config.check()
    _shipped_config(config, after_training, source)  # refuse a bad section before training
    demos = core_data.load_demonstrations(dataset_dir, recording)
    if getattr(config, "task_objects", 0):
        demos = core_data.keep_task_objects(demos, config.task_objects)
    timing = "as recorded"
    if align_time:
        trajectories, aligned = align_demonstrations(demos.trajectories, demos.fps)
        demos, timing = dataclasses.replace(demos, trajectories=trajectories), aligned.describe()
    log = (lambda line: print(line, file=sys.stderr, flush=True)) if progress else None
    if log:
        log(f"training {kind.name} on {len(demos)} {demos.task} demonstrations from {dataset_dir}, "
            f"{config.steps} steps, seed {config.seed}")
        log(f"camera {demos.camera}; motion {demos.motion}; timing: {timing}")
    model, summary = kind.train(demos, config, log)
    if after_training:
        model.config = _shipped_config(model.config, after_training, source)

    def fill(staging: str) -> None:
        models.save_model(model, staging)
        with open(os.path.join(staging, models.CARD_FILE), "w", encoding="utf-8") as f:
            f.write(model_card(kind, model.config, summary, dataset_dir, demos, command, after_training, timing))

    publish_directory(out_dir, fill)
    return json.dumps({"out": out_dir, "task": demos.task, "model_type": kind.name, **summary})


def read_configs(paths: Sequence[str]) -> tuple[dict, dict, str]:
    """The fields of the config files `paths` layered in order (a later file's field wins;
    their AFTER_TRAINING sections layer field by field the same way), that section apart, and
    the files' names for messages. No file: every field at its default."""
    values: dict = {}
    after_training: dict = {}
    for path in paths:
        layer = read_json_object(path)
        section = layer.pop(AFTER_TRAINING, {})
        if not isinstance(section, dict):
            raise InputError(f"{path}: {AFTER_TRAINING} must be a JSON object of inference settings")
        values.update(layer)
        after_training.update(section)
    return values, after_training, " + ".join(map(str, paths)) or "config"


def _shipped_config(config, after_training, source: str):
    """`config` with the inference settings of a config file's AFTER_TRAINING section; an
    InputError for anything there that is not an inference setting of the model type."""
    if not isinstance(after_training, dict):
        raise InputError(f"{source}: {AFTER_TRAINING} must be a JSON object of inference settings")
    allowed = getattr(type(config), "INFERENCE_FIELDS", ())
    other = sorted(set(after_training) - set(allowed))
    if other:
        raise InputError(f"{source}: {AFTER_TRAINING} may set only inference settings "
                         f"({', '.join(allowed) or 'this model type has none'}), not {', '.join(other)}")
    shipped = dataclasses.replace(config, **after_training)
    shipped.check(source)
    return shipped


def model_card(kind: models.ModelType, config, summary: dict, dataset_dir: str, demos: core_data.Demonstrations,
               command: str, after_training: dict | None = None, timing: str = "as recorded") -> str:
    seeds = [s for s in demos.seeds if s >= 0]
    seed_text = f"{min(seeds)}..{max(seeds)}" if seeds else "not recorded"
    losses = ", ".join(f"{name.replace('_', ' ')} {value:.5f}" for name, value in summary["final_losses"].items())
    objects = (f"| objects (slots, label order) | {', '.join(config.object_names)} |\n"
               if isinstance(config, CnfmpConfig) else "")
    extra = (f" (plus {len(demos) * config.num_objects * config.num_endpoints} demonstration simplex weights)"
             if isinstance(config, CnfmpConfig) else "")
    choice = summary.get("draws")
    draws = (f"| draws | {choice['count']} initialisations trained {choice['steps']} steps each; draw "
             f"{choice['chosen'] + 1} went on (trajectory loss then: "
             f"{', '.join(f'{v:.5f}' for v in choice['motion_mse'])}) |\n" if choice else "")
    shipped = (f"| set after training | {', '.join(f'`{k}` {v}' for k, v in after_training.items())} "
               "(inference only; training's motion refit ran with the config file's other values) |\n"
               if after_training else "")
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
| trajectory | {config.duration_s:.1f} s at {config.output_fps:g} Hz |
{shipped}
Command:

```
{command or "cnfmp train --dataset " + dataset_dir + " --out <dir>"}
```

Held-out metrics: see `docs/benchmarks.md` (`cnfmp eval --model <dir> --task {config.task} ...`).
"""
