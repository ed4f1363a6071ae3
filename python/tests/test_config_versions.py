"""Config versions: config.json carries ``config_version``; a file written before versions
existed loads as version 1, a newer or malformed version is refused, an older one is upgraded
step by step or refused with a message that says to retrain."""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass

import numpy as np
import pytest

from cnfmp.configuration import JsonConfig
from cnfmp.core import data as core_data, models, training_cnfmp
from cnfmp.core.configuration_cnfmp import CnfmpConfig
from cnfmp.core.configuration_common import MotionConfig
from cnfmp.errors import InputError

TINY = dict(field_resolution=16, latent_dim=8, num_endpoints=3, field_width=16, field_layers=2,
            appearance_octaves=2, pixels_per_object=32, uniform_pixels=32, mask_dilation=1, time_samples=16,
            search_candidates=8, search_starts=2, refine_steps=3, inference_pixels=64, output_fps=10.0,
            motion_refit_steps=3, steps=5, seed=0)


def write_config(path, values: dict) -> str:
    path.write_text(json.dumps(values))
    return str(path)


def saved_model_and_copy(tmp_path, copy_name: str):
    """(demonstrations, model, its saved directory, a copy of that directory) of a tiny model."""
    demos = tiny_demonstrations()
    model, _ = training_cnfmp.train_model(demos, CnfmpConfig(**TINY))
    saved, copy = tmp_path / "today", tmp_path / copy_name
    saved.mkdir()
    models.save_model(model, str(saved))
    shutil.copytree(saved, copy)
    return demos, model, saved, copy


def predict_both(demos, directories, scene: int, seed: int) -> list[dict]:
    """Each model directory's prediction of demonstration `scene`, after asserting that they
    predict the same trajectory."""
    one, two = (models.load_predictor(str(d)).predict(demos.images[scene], demos.masks[scene], seed=seed)
                for d in directories)
    for key in ("position", "orientation", "gripper"):
        np.testing.assert_array_equal(one["trajectory"][key], two["trajectory"][key])
    return [one, two]


def test_every_model_type_writes_the_current_config_version():
    assert JsonConfig.current_version() is None  # a class without the field has no versions
    for kind in models.model_types().values():
        config = kind.config_class()
        version = 7 if isinstance(config, CnfmpConfig) else 1  # cnfmp: defaults in 2, fields renamed or retired in 3-7
        assert kind.config_class.current_version() == version and config.config_version == version
        assert json.loads(config.to_json())["config_version"] == version


def test_a_config_without_a_version_is_of_the_version_its_reader_says_and_writes_the_current_one(tmp_path):
    path = write_config(tmp_path / "config.json", {"model_type": "cnfmp", "steps": 7})
    # A training config file: the current version, today's defaults.
    current = CnfmpConfig.from_file(path)
    assert (current.config_version, current.steps) == (7, 7)
    assert current.tool_axis_object is None and current.observed_statistics is None  # training chooses
    again = CnfmpConfig.from_dict(json.loads(current.to_json()))
    assert json.loads(again.to_json())["config_version"] == 7 and again == current
    # A model directory written before versions existed: version 1, upgraded with its
    # defaults, which version 5 no longer trains (a centre projective in the latent).
    with pytest.raises(InputError, match=r"config.json: anchored_centres is no longer a setting .* "
                                         r"anchored_centres true\); .* retrain it"):
        CnfmpConfig.from_file(path, unversioned=1)
    # One that named today's behaviour loads, with what version 1 had of the later fields.
    old = CnfmpConfig.from_dict({"steps": 7, "anchored_centres": True, "motion_shapes_latents": False}, unversioned=1)
    assert (old.config_version, old.steps) == (7, 7)
    assert old.tool_axis_object == -1  # a version-1 model never read the tool axis apart
    assert old.observed_statistics == "centroid"  # nor any mask statistic


def test_version_2_tilt_object_becomes_the_tool_axis_object_and_the_old_name_is_refused_now():
    """Version 3 renamed the recipe's `tilt_object` to `tool_axis_object`, which training
    chooses; a version-2 model keeps its slot, or none where it had none."""
    base = {"config_version": 2, "num_objects": 2, "rotation_chart": "swing_twist", "shading_moments": True}
    assert CnfmpConfig.from_dict({**base, "tilt_object": 1}).tool_axis_object == 1
    assert CnfmpConfig.from_dict({**base, "tilt_object": -1}).tool_axis_object == -1
    assert CnfmpConfig.from_dict({"config_version": 2}).tool_axis_object == -1
    with pytest.raises(InputError, match=r"unknown field\(s\) tilt_object"):
        CnfmpConfig.from_dict({"tilt_object": 1})
    with pytest.raises(InputError, match="unknown field"):  # the new name in an old file is a mistake too
        CnfmpConfig.from_dict({"config_version": 2, "tool_axis_object": 1, "tilt_object": 1})


def test_version_3_retires_fields_that_held_one_value_and_refuses_a_model_trained_otherwise(tmp_path):
    from cnfmp.core.configuration_cnfmp import VERSION_3_RETIRED

    kept = CnfmpConfig.from_dict({"config_version": 2, **VERSION_3_RETIRED, "anchored_centres": True,
                                  "motion_shapes_latents": False})
    assert kept == CnfmpConfig(tool_axis_object=-1, observed_statistics="centroid")
    path = write_config(tmp_path / "config.json", {"config_version": 2, "simplex_entropy_weight": 0.01})
    with pytest.raises(InputError, match=r"config.json: simplex_entropy_weight is no longer a setting .* "
                                         r"simplex_entropy_weight 0.0\); .* retrain it"):
        CnfmpConfig.from_file(path)
    with pytest.raises(InputError, match="gate_present_only is no longer a setting"):
        CnfmpConfig.from_dict({"config_version": 2, "gate_present_only": False})
    with pytest.raises(InputError, match=r"unknown field\(s\) gate_present_only"):  # not a field of today's files
        CnfmpConfig.from_dict({"gate_present_only": True})


def test_version_3_shading_moments_become_the_observed_statistics_and_a_version_3_directory_loads(tmp_path):
    """Version 4 replaced the switch `shading_moments` (default false) by `observed_statistics`
    (default "shading"); a version-3 model directory, its weights' ``shading_embedding``
    included, predicts as before."""
    assert CnfmpConfig.from_dict({"config_version": 3, "shading_moments": True}).observed_statistics == "shading"
    assert CnfmpConfig.from_dict({"config_version": 3, "shading_moments": False}).observed_statistics == "centroid"
    assert CnfmpConfig.from_dict({"config_version": 3}).observed_statistics == "centroid"  # version 3's default
    with pytest.raises(InputError, match="shading_moments must be true or false"):
        CnfmpConfig.from_dict({"config_version": 3, "shading_moments": "yes"})
    with pytest.raises(InputError, match=r"unknown field\(s\) shading_moments"):
        CnfmpConfig.from_dict({"shading_moments": True})

    from safetensors.torch import load_file, save_file

    demos, _, saved, old = saved_model_and_copy(tmp_path, "version-3")
    values = json.loads((old / models.CONFIG_FILE).read_text())
    assert values.pop("observed_statistics") == "shading"
    values.update(config_version=3, shading_moments=True)
    (old / models.CONFIG_FILE).write_text(json.dumps(values, indent=2))
    tensors = load_file(str(old / models.WEIGHTS_FILE))
    tensors["shading_embedding"] = tensors.pop("statistics_embedding")
    save_file(tensors, str(old / models.WEIGHTS_FILE))

    assert models.read_config(str(old)) == models.read_config(str(saved))
    predict_both(demos, (saved, old), scene=1, seed=2)


def test_version_5_retires_the_anchored_centres_switches_and_the_shipped_models_load(tmp_path):
    """Version 5 dropped `anchored_centres` and `motion_shapes_latents`, keeping version 4's
    defaults; a version-4 file with them loads, one trained otherwise is refused, and a
    version-5 file may not name them."""
    from cnfmp.core.configuration_cnfmp import VERSION_5_RETIRED

    version_5 = CnfmpConfig(observed_statistics="shading")  # version 5's default (version 6 lets training choose)
    assert CnfmpConfig.from_dict({"config_version": 4, **VERSION_5_RETIRED}) == version_5
    assert CnfmpConfig.from_dict({"config_version": 4}) == version_5
    for name, value in (("anchored_centres", False), ("motion_shapes_latents", True)):
        with pytest.raises(InputError, match=f"{name} is no longer a setting .* retrain it"):
            CnfmpConfig.from_dict({"config_version": 4, name: value})
        with pytest.raises(InputError, match=rf"unknown field\(s\) {name}"):
            CnfmpConfig.from_dict({name: value})
    # Every shipped cnfmp model loads.
    import os
    repo = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    loaded = 0
    for name in os.listdir(os.path.join(repo, "models")):
        path = os.path.join(repo, "models", name, models.CONFIG_FILE)
        raw = json.load(open(path))
        if raw.get("model_type") == "cnfmp":
            config = models.read_config(os.path.dirname(path))
            # A trained model carries training's choice, never the "choose" value null.
            assert config.observed_statistics in ("shading", "all"), name
            assert config.config_version == 7 and config.observed_statistics == raw["observed_statistics"], name
            loaded += 1
    assert loaded >= 5


def test_version_7_fixes_the_method_s_own_choices_and_a_version_6_directory_predicts_as_before(tmp_path):
    """Version 7 made eleven fields constants: a version-6 model directory loads and predicts
    exactly as a version-7 one; a training-only or approximation field may hold any value
    there, a prediction-shaping one only the value that stayed; a version-7 file names none."""
    from cnfmp.core import configuration_cnfmp as c

    version_6 = {"anneal_fraction": 0.25, "lipschitz_weight": 1e-4, "mask_prior_weight": 0.1, "image_weight": 2.0,
                 "draw_fraction": 0.5, "search_pixels": 64, "texels_per_pixel": 0, "residual_grid_pixels": 0.0,
                 **c.VERSION_7_RETIRED}
    assert set(version_6) == set(c.VERSION_7_DROPPED) | set(c.VERSION_7_RETIRED) and len(version_6) == 11
    demos, _, saved, old = saved_model_and_copy(tmp_path, "version-6")
    values = json.loads((old / models.CONFIG_FILE).read_text())
    assert values["config_version"] == 7 and not set(version_6) & set(values)
    (old / models.CONFIG_FILE).write_text(json.dumps({**values, **version_6, "config_version": 6}, indent=2))
    assert models.read_config(str(old)) == models.read_config(str(saved))
    predict_both(demos, (saved, old), scene=0, seed=1)
    for name, kept in c.VERSION_7_RETIRED.items():
        with pytest.raises(InputError, match=rf"{name} is no longer a setting .* retrain it"):
            CnfmpConfig.from_dict({"config_version": 6, name: 2 * kept})
    for name in version_6:
        with pytest.raises(InputError, match=rf"unknown field\(s\) {name}"):
            CnfmpConfig.from_dict({name: version_6[name]})


def test_newer_and_malformed_versions_are_refused(tmp_path):
    newer = write_config(tmp_path / "newer.json", {"config_version": 8, "steps": 7})
    with pytest.raises(InputError, match=r"newer.json: config_version 8 was written by a newer cnfmp.*update cnfmp"):
        CnfmpConfig.from_file(newer)
    # A newer file's new fields are not what is wrong with it: the version is named first.
    with pytest.raises(InputError, match="newer cnfmp"):
        CnfmpConfig.from_dict({"config_version": 8, "a_field_of_version_8": 1})
    for bad in (0, -1, "1", 1.0, True, None):
        with pytest.raises(InputError, match="config_version must be a whole number >= 1"):
            CnfmpConfig.from_dict({"config_version": bad})
    with pytest.raises(InputError, match="config_version must be a whole number >= 1, got 0"):
        CnfmpConfig.from_dict({}, unversioned=0)


def test_unknown_fields_and_other_model_types_are_still_refused_by_name(tmp_path):
    path = write_config(tmp_path / "typo.json", {"config_version": 4, "stepz": 7})
    with pytest.raises(InputError, match=r"typo.json: unknown field\(s\) stepz; known: .*config_version"):
        CnfmpConfig.from_file(path)
    # model_type is named first, even with a version this cnfmp cannot read.
    with pytest.raises(InputError, match="model_type is 'nfmp', expected 'cnfmp'"):
        CnfmpConfig.from_dict({"model_type": "nfmp", "config_version": 9, "latent_size": 3})


@dataclass
class RenamingConfig(MotionConfig):
    """A config at version 3 whose version 1 called `steps` `iterations` and whose version 2
    had a `legacy` field since dropped."""

    config_version: int = 3
    model_type: str = "renaming"

    @classmethod
    def upgrade(cls, values: dict, version: int, source: str) -> dict:
        cls.steps_taken.append(version)
        if version == 1:
            values = {("steps" if k == "iterations" else k): v for k, v in values.items()}
            return {**values, "legacy": 0}
        if version == 2:
            return {k: v for k, v in values.items() if k != "legacy"}
        return super().upgrade(values, version, source)


@dataclass
class Version2Config(MotionConfig):
    config_version: int = 2
    model_type: str = "version-2"


def test_older_versions_upgrade_step_by_step_and_the_base_refuses_with_a_retrain_message():
    RenamingConfig.steps_taken = []
    config = RenamingConfig.from_dict({"config_version": 1, "iterations": 12})
    assert RenamingConfig.steps_taken == [1, 2] and config.steps == 12 and config.config_version == 3
    RenamingConfig.steps_taken = []
    config = RenamingConfig.from_dict({"iterations": 12}, unversioned=1)
    assert RenamingConfig.steps_taken == [1, 2] and config.steps == 12
    RenamingConfig.steps_taken = []
    assert RenamingConfig.from_dict({"steps": 4}).steps == 4 and RenamingConfig.steps_taken == []
    # A class that does not override upgrade reads no older version.
    with pytest.raises(InputError, match=r"src: config_version 1 is a config format this cnfmp cannot read "
                                         r"\(it reads version 2\); retrain the model with `cnfmp train`"):
        Version2Config.from_dict({"steps": 4}, source="src", unversioned=1)
    assert Version2Config.from_dict({"steps": 4}).config_version == 2


def tiny_demonstrations() -> core_data.Demonstrations:
    """Two synthetic demonstrations of two objects (no simulator): enough to train a few steps."""
    rng = np.random.default_rng(0)
    images = rng.integers(60, 200, (2, 32, 32, 3), dtype=np.uint8)
    masks = np.zeros((2, 32, 32), np.uint8)
    masks[0, 4:12, 4:12], masks[0, 18:28, 16:26] = 1, 2
    masks[1, 6:14, 14:22], masks[1, 20:30, 4:14] = 1, 2
    trajectories = []
    for b in range(2):
        t = np.linspace(0, 1, 11)[:, None]
        position = np.array([0.4, 0.0, 0.3]) + t * np.array([0.1 * (b + 1), -0.05, -0.2])
        quat = np.tile([0.0, 1.0, 0.0, 0.0], (11, 1))
        trajectories.append(np.concatenate([position, quat, (t > 0.5).astype(float)], axis=1))
    return core_data.Demonstrations("synthetic", 10.0, images, masks, [["a", "b"]] * 2, trajectories,
                                    [0, 1], ["move a to b"] * 2)


def test_a_saved_model_directory_carries_its_version_and_loads_as_before_without_it(tmp_path, monkeypatch):
    demos, model, saved, old = saved_model_and_copy(tmp_path, "before-versions")
    assert json.loads((saved / models.CONFIG_FILE).read_text())["config_version"] == 7
    values = json.loads((old / models.CONFIG_FILE).read_text())
    del values["config_version"]
    # Version-1 files named the two switches that version 5 retired (every file written
    # since they existed); without them a version-1 model is one version 5 refuses.
    values.update(anchored_centres=True, motion_shapes_latents=False)
    (old / models.CONFIG_FILE).write_text(json.dumps(values, indent=2))

    assert models.read_config(str(old)) == models.read_config(str(saved)) == model.config
    one, two = predict_both(demos, (saved, old), scene=1, seed=2)
    np.testing.assert_array_equal(one["weights"], two["weights"])
    assert one["object_mse"] == two["object_mse"]

    # Were the current version 8, the directory without the key would be upgraded from
    # version 1 (not taken as current) through 2 to 7, and the one with it from 7.
    upgraded = []
    monkeypatch.setattr(CnfmpConfig, "current_version", classmethod(lambda cls: 8))
    step = CnfmpConfig.upgrade  # the real steps up to 7, none from 7 to 8
    monkeypatch.setattr(CnfmpConfig, "upgrade", classmethod(
        lambda cls, values, version, source: upgraded.append(version) or (
            values if version == 7 else step(values, version, source))))
    assert models.read_config(str(old)).config_version == 8 and upgraded == [1, 2, 3, 4, 5, 6, 7]
    assert models.read_config(str(saved)).config_version == 8 and upgraded == [1, 2, 3, 4, 5, 6, 7, 7]
    monkeypatch.undo()
    monkeypatch.setattr(JsonConfig, "current_version", classmethod(lambda cls: 8))
    with pytest.raises(InputError, match=r"config.json: config_version 7 .* retrain the model with `cnfmp train`"):
        models.read_config(str(saved))
