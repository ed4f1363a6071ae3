"""The Table-I baselines and the ablation on a small generated dataset: each trains (its loss
falls), saves and loads exactly, predicts the trajectory schema through the shared API, and
is picked by the model-type registry; plus the wall grid scenes NFMP trains on."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
from PIL import Image

from cnfmp.core import api, models, training
from cnfmp.core import data as core_data
from cnfmp.core.configuration_cnfmp import CnfmpNoGateConfig
from cnfmp.core.configuration_cnn_cnmp import CnnCnmpConfig
from cnfmp.core.configuration_nfmp import NfmpConfig
from cnfmp.data import generate
from cnfmp.errors import InputError

TINY_CNN = dict(image_size=64, conv_channels=[8, 16, 16, 32], image_feature_dim=32, width=32, target_points=32,
                output_fps=10.0)
TINY_NFMP = dict(field_resolution=32, latent_dim=8, field_width=48, field_layers=2, appearance_octaves=4,
                 pixels_per_scene=256, inference_steps=40, inference_pixels=512, output_fps=10.0)


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("baselines") / "wall"
    generate.generate_dataset("wall_avoidance", 3, 210, str(out), workers=2, progress=False)
    return str(out)


@pytest.fixture(scope="module")
def demos(dataset_dir):
    return core_data.load_demonstrations(dataset_dir)


def png(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(array).save(buffer, format="PNG")
    return buffer.getvalue()


def med_cm(a: np.ndarray, b: np.ndarray) -> float:
    steps = max(len(a), len(b))
    pad = lambda x: np.concatenate([x, np.repeat(x[-1:], steps - len(x), axis=0)])  # noqa: E731
    return float(np.linalg.norm(pad(a) - pad(b), axis=1).mean() * 100)


def first_and_last(lines: list[str], key: str) -> tuple[float, float]:
    values = [float(line.rsplit(f"{key} ", 1)[1].split()[0]) for line in lines if line.startswith("step ")]
    return values[0], values[-1]


@pytest.mark.parametrize("model_type, config", [("cnn-cnmp", CnnCnmpConfig(**TINY_CNN, steps=3000, seed=1)),
                                                ("nfmp", NfmpConfig(**TINY_NFMP, steps=300, seed=1))])
def test_baselines_train_and_save_and_load_exactly(model_type, config, demos, tmp_path):
    kind = models.model_type(model_type)
    lines: list[str] = []
    model, summary = kind.train(demos, config, lines.append)
    first, last = first_and_last(lines, "motion")
    assert last < 0.6 * first, (first, last)
    assert summary["demos"] == 3 and summary["parameters"] == model.parameter_count() > 0
    models.save_model(model, str(tmp_path))
    loaded = models.load_predictor(str(tmp_path))
    assert type(loaded.model) is type(model) and loaded.config == model.config
    fresh = kind.predictor(model)
    own, cross = [], []
    for index in range(len(demos)):
        ours = fresh.predict(demos.images[index], demos.masks[index], seed=0)
        theirs = loaded.predict(demos.images[index], demos.masks[index], seed=0)
        np.testing.assert_array_equal(ours["trajectory"]["position"], theirs["trajectory"]["position"])
        for other in range(len(demos)):
            (own if other == index else cross).append(med_cm(ours["trajectory"]["position"],
                                                             demos.trajectories[other][:, :3]))
    if model_type == "nfmp":
        # The latent fitted to a training image carries that demonstration's motion. Not per
        # image: NFMP's one shared field may explain an image about as well by a blend of
        # latents, and which it settles on moves with the CPU's float kernels (seed 1: own
        # MEDs 0.08 / 0.10 / 0.09 cm with AVX2 kernels, 5.1 / 0.1 / 0.1 cm with the default
        # ones). On average, own / cross MED was 0.02 and 0.30 there; 0.5 leaves room.
        assert np.mean(own) < 0.5 * np.mean(cross), (own, cross)


def test_the_predict_api_serves_baselines_without_objects(demos, tmp_path):
    model, _ = models.model_type("cnn-cnmp").train(demos, CnnCnmpConfig(**TINY_CNN, steps=20, seed=0))
    models.save_model(model, str(tmp_path))
    result = json.loads(api.predict(str(tmp_path), png(demos.images[0]), png(demos.masks[0]), ["wall", "goal marker"]))
    assert result["objects"] == [] and result["scene_psnr_db"] is None
    assert result["model"]["type"] == "cnn-cnmp" and result["fps"] == 10.0
    assert len(result["frames"]) == len(demos.trajectories[0])
    described = json.loads(api.describe(str(tmp_path)))
    assert described["type"] == "cnn-cnmp" and described["roles"] is None and described["objects"] == []


def test_train_picks_the_model_type_and_refuses_mismatched_configs(dataset_dir, tmp_path):
    out = tmp_path / "nogate"
    report = json.loads(training.train(dataset_dir, str(out), [], steps=3, seed=0, progress=False,
                                       model_type="cnfmp-nogate"))
    assert report["model_type"] == "cnfmp-nogate"
    saved = json.loads((out / models.CONFIG_FILE).read_text())
    assert saved["model_type"] == "cnfmp-nogate" and saved["temporal_gating"] is False
    assert "without temporal gating" in (out / models.CARD_FILE).read_text()
    assert isinstance(models.read_config(str(out)), CnfmpNoGateConfig)

    nfmp_config = tmp_path / "nfmp.json"
    nfmp_config.write_text(json.dumps({"model_type": "nfmp", **TINY_NFMP}))
    with pytest.raises(InputError, match="model_type is 'nfmp', expected 'cnn-cnmp'"):
        training.train(dataset_dir, str(tmp_path / "x"), [str(nfmp_config)], steps=3, seed=0, progress=False,
                       model_type="cnn-cnmp")
    # Without --model-type the config file's type is used.
    report = json.loads(training.train(dataset_dir, str(tmp_path / "nfmp"), [str(nfmp_config)], steps=3, seed=0,
                                       progress=False))
    assert report["model_type"] == "nfmp" and set(report["final_losses"]) == {"image_mse", "motion_mse"}
    with pytest.raises(InputError, match="unknown model type 'cnmp'; known: cnfmp, cnfmp-nogate, cnn-cnmp, nfmp"):
        training.train(dataset_dir, str(tmp_path / "y"), [], steps=3, progress=False, model_type="cnmp")
    with pytest.raises(InputError, match="temporal_gating must be false"):
        CnfmpNoGateConfig.from_dict({"temporal_gating": True})
    with pytest.raises(InputError, match="not divisible"):
        CnnCnmpConfig.from_dict({"image_size": 100})


def test_the_wall_grid_seeds_are_a_3x3x3_grid_of_height_and_goal():
    from cnfmp.seeds import NFMP_GRID_SEEDS, NFMP_GRID_TASK
    from cnfmp.sim.tasks import wall_avoidance

    assert NFMP_GRID_TASK == wall_avoidance.TASK.name  # the one task whose scenes know the grid
    scenes = [wall_avoidance.make_scene(seed) for seed in NFMP_GRID_SEEDS]
    heights = sorted({round(s.params["wall_height"], 6) for s in scenes})
    goal_x = sorted({round(s.params["goal"][0], 6) for s in scenes})
    assert len(scenes) == 27 and len(heights) == 3 and len(goal_x) == 3
    assert len({round(s.params["wall_thickness"], 6) for s in scenes}) == 1
    assert len({(round(s.params["goal"][0], 6), round(s.params["goal"][1], 6), round(s.params["wall_height"], 6))
                for s in scenes}) == 27
    assert wall_avoidance.grid_cell(NFMP_GRID_SEEDS.stop) is None
    assert wall_avoidance.grid_cell(5) is None and wall_avoidance.grid_cell(1_000_000) is None


def test_the_table_chart_is_a_png_with_a_bar_per_method_and_task():
    import cv2

    results = [{"method": m, "task": t, "med_cm": 1.0 + i, "success_rate": 0.5}
               for i, m in enumerate(["A", "B"]) for t in ["wall_avoidance", "cube_stacking"]]
    results.append({"method": "A", "task": "cup_stacking", "med_cm": None, "success_rate": None})
    from cnfmp.core.report import table_chart

    image = cv2.imdecode(np.frombuffer(table_chart(json.dumps(results), ["A", "B"], ["wall_avoidance", "cup_stacking",
                                                                                      "cube_stacking"]), np.uint8),
                         cv2.IMREAD_COLOR)
    assert image is not None and image.shape[1] == 1000 and image.shape[0] > 500
    assert (image != 255).any(axis=2).mean() > 0.02  # bars and text were drawn


def test_the_curve_chart_draws_a_line_per_task_in_its_colour_and_skips_missing_points():
    import cv2

    from cnfmp.core.report import PALETTE, curve_chart

    tasks, sizes = ["wall_avoidance", "cup_stacking"], [5, 10, 20]
    results = [{"task": t, "demos": n, "med_cm": 3.0 / n, "success_rate": n / 20} for t in tasks for n in sizes]
    results[-1] = {"task": "cup_stacking", "demos": 20, "med_cm": None, "success_rate": float("nan")}
    rgb = cv2.cvtColor(cv2.imdecode(np.frombuffer(curve_chart(json.dumps(results), tasks, sizes), np.uint8),
                                    cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    assert rgb.shape[1] == 1000
    for k in range(len(tasks)):
        drawn = (np.abs(rgb.astype(int) - PALETTE[k]).sum(axis=2) < 10).sum()
        assert drawn > 300, (tasks[k], drawn)  # its two lines, markers and legend swatch
    # The right edge (20 demonstrations): only wall's colour, cup's point there is missing.
    right = rgb[:, 930:960]
    assert (np.abs(right.astype(int) - PALETTE[0]).sum(axis=2) < 10).any()
    assert not (np.abs(right.astype(int) - PALETTE[1]).sum(axis=2) < 10).any()


def test_the_curve_chart_labels_a_point_above_its_axis_with_its_value():
    import cv2

    from cnfmp.core.report import curve_chart

    def chart(med_cm: float) -> np.ndarray:
        results = [{"task": "wall_avoidance", "demos": 5, "med_cm": med_cm, "success_rate": 0.1},
                   {"task": "wall_avoidance", "demos": 10, "med_cm": 1.0, "success_rate": 0.9}]
        return cv2.imdecode(np.frombuffer(curve_chart(json.dumps(results), ["wall_avoidance"], [5, 10]), np.uint8),
                            cv2.IMREAD_COLOR)

    # The MED axis stops at 10 cm: 14 and 50 draw the same point and line, and differ only by
    # the label beside it; 10 is on the axis and has none.
    on_axis, clipped, far = chart(10.0), chart(14.0), chart(50.0)
    assert (clipped != far).any() and (clipped != on_axis).any()
    columns = np.flatnonzero((clipped != far).any(axis=(0, 2)))
    assert 500 < columns.min() and columns.max() < 620, columns  # beside the 5-demonstration point (x 510)
