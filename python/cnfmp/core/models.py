"""The model types of the core and their directories.

A model directory holds ``config.json`` (the type's configuration dataclass, whose
``model_type`` names the type and ``config_version`` its format, see
:mod:`cnfmp.configuration`), ``model.safetensors`` and a ``README.md`` card. Every type
is trained by ``cnfmp train --model-type T`` and evaluated by the same ``cnfmp eval``:

- ``cnfmp``: the compositional neural-field movement primitive (paper §II-B).
- ``cnfmp-nogate``: the same without temporal gating (the paper's ablation).
- ``cnn-cnmp``: a CNN image encoder tiled into a conditional neural movement primitive.
- ``nfmp``: the scene-level neural-field movement primitive (one latent per scene, no objects).
- ``cnfmp-3d``: the compositional primitive on occupancy fields, for scenes given as scans.

Loading never executes code from the directory: the config picks a class from this table
and the weights are plain tensors.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from typing import Callable

from cnfmp.errors import InputError

CONFIG_FILE, WEIGHTS_FILE, CARD_FILE = "config.json", "model.safetensors", "README.md"
DEFAULT_MODEL_TYPE = "cnfmp"


@dataclass(frozen=True)
class ModelType:
    """What the core needs to know about one kind of model.

    Attributes:
        name: the ``model_type`` of its configs.
        summary: one line for model cards and listings.
        config_class: its configuration dataclass.
        train: ``train(demos, config, log) -> (model, summary dict)``; the summary has
            ``steps``, ``demos``, ``seconds``, ``final_losses`` and ``parameters``.
        from_state: ``from_state(config, tensors) -> model`` with the architecture the
            saved tensors need (e.g. how many demonstration latents).
        predictor: ``predictor(model)`` -> an object with ``config``, ``model`` and
            ``predict(image, labels, seed) -> dict`` (see :func:`cnfmp.core.api.predict`).
    """

    name: str
    summary: str
    config_class: type
    train: Callable
    from_state: Callable
    predictor: Callable


def model_types() -> dict[str, ModelType]:
    """Every model type by name (imported on first use: torch is heavy)."""
    from cnfmp.core import modeling_cnn_cnmp, modeling_nfmp, training_cnfmp, training_cnfmp3d
    from cnfmp.core.configuration_cnfmp3d import Cnfmp3dConfig
    from cnfmp.core.inference_cnfmp3d import Predictor3d
    from cnfmp.core.modeling_cnfmp3d import Cnfmp3dModel
    from cnfmp.core.configuration_cnfmp import CnfmpConfig, CnfmpNoGateConfig
    from cnfmp.core.configuration_cnn_cnmp import CnnCnmpConfig
    from cnfmp.core.configuration_nfmp import NfmpConfig
    from cnfmp.core.inference import Predictor
    from cnfmp.core.modeling_cnfmp import CnfmpModel

    compositional = dict(train=training_cnfmp.train_model, from_state=CnfmpModel.from_state, predictor=Predictor)
    types = [
        ModelType("cnfmp", "Compositional neural-field movement primitive (paper §II-B)", CnfmpConfig, **compositional),
        ModelType("cnfmp-nogate", "Compositional neural-field movement primitive without temporal gating "
                  "(ablation: constant, equal weights on the object latents)", CnfmpNoGateConfig, **compositional),
        ModelType("cnn-cnmp", "Baseline: CNN image encoder tiled into a conditional neural movement primitive",
                  CnnCnmpConfig, modeling_cnn_cnmp.train_model, modeling_cnn_cnmp.CnnCnmpModel.from_state,
                  modeling_cnn_cnmp.Predictor),
        ModelType("nfmp", "Baseline: scene-level neural-field movement primitive (one latent per scene, "
                  "one global deformation, no objects)", NfmpConfig, modeling_nfmp.train_model,
                  modeling_nfmp.NfmpModel.from_state, modeling_nfmp.Predictor),
        ModelType("cnfmp-3d", "Compositional neural-field movement primitive on occupancy fields, for scenes "
                  "given as scans (paper §III-B)", Cnfmp3dConfig, training_cnfmp3d.train_model,
                  Cnfmp3dModel.from_state, Predictor3d),
    ]
    return {t.name: t for t in types}


def model_type(name: str) -> ModelType:
    """The model type called `name`; InputError naming the known ones otherwise."""
    types = model_types()
    if name not in types:
        raise InputError(f"unknown model type {name!r}; known: {', '.join(types)}")
    return types[name]


def save_model(model, out_dir: str) -> None:
    """Writes `model`'s config.json and model.safetensors into `out_dir` (which must exist)."""
    from safetensors.torch import save_file

    with open(os.path.join(out_dir, CONFIG_FILE), "w", encoding="utf-8") as f:
        f.write(model.config.to_json())
    save_file({k: v.detach().contiguous() for k, v in model.state_dict().items()}, os.path.join(out_dir, WEIGHTS_FILE))


def read_config(model_dir: str):
    """The configuration in `model_dir`/config.json, as its model type's dataclass at the
    current config version (see :mod:`cnfmp.configuration`); InputError for a version this
    cnfmp cannot read."""
    if not os.path.isdir(model_dir):
        raise InputError(f"model directory {model_dir} does not exist")
    path = os.path.join(model_dir, CONFIG_FILE)
    if not os.path.isfile(path):
        raise InputError(f"{model_dir} is not a model directory: {CONFIG_FILE} is missing")
    try:
        with open(path, encoding="utf-8") as f:
            name = json.load(f).get("model_type", DEFAULT_MODEL_TYPE)
    except (OSError, ValueError, AttributeError) as err:
        raise InputError(f"{path} is not a readable JSON object: {err}") from err
    # config.json files written before versions existed are version 1.
    return model_type(str(name)).config_class.from_file(path, unversioned=1)


def load_model(model_dir: str):
    """Rebuilds the model in `model_dir` from its config and weights, frozen in eval mode.
    InputError for a missing, unreadable or mismatched file."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    config = read_config(model_dir)
    weights_path = os.path.join(model_dir, WEIGHTS_FILE)
    if not os.path.isfile(weights_path):
        raise InputError(f"{model_dir} is not a complete model directory: {WEIGHTS_FILE} is missing")
    try:
        state = load_file(weights_path)
    except (SafetensorError, OSError) as err:
        raise InputError(f"{weights_path}: not a readable safetensors file: {err}") from err
    model = model_type(config.model_type).from_state(config, state)
    try:
        model.load_state_dict(state)
    except RuntimeError as err:
        raise InputError(f"{weights_path} does not match {CONFIG_FILE}: {str(err).splitlines()[0]}") from err
    model.eval()
    for p in model.parameters():
        p.requires_grad_(False)
    return model


def load_predictor(model_dir: str):
    """The predictor of the model in `model_dir` (see :class:`ModelType`)."""
    model = load_model(model_dir)
    return model_type(model.config.model_type).predictor(model)


__all__ = ["CARD_FILE", "CONFIG_FILE", "DEFAULT_MODEL_TYPE", "WEIGHTS_FILE", "ModelType", "load_model",
           "load_predictor", "model_type", "model_types", "read_config", "save_model"]
