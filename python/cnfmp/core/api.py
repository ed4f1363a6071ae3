"""Entry points of the core model for the Rust bridge (and notebooks): train and predict.

Loaded models stay resident (keyed by directory and file modification times), so a server or
an evaluation loop pays for loading once. Bad input raises :class:`cnfmp.errors.InputError`.
"""

from __future__ import annotations

import json
import os
import time

import numpy as np

from cnfmp.core import models
from cnfmp.core.configuration_cnfmp import CnfmpConfig
from cnfmp.core.data import task_object_labels
from cnfmp.errors import InputError
from cnfmp.images import decode_image, decode_labels, encode_png

__all__ = ["describe", "predict", "predict_batch", "predict_scan", "start_helpers", "synthetic_scene", "train", "warm_up"]

_LOADED: dict[str, tuple[tuple, object]] = {}


def train(dataset_dir: str, out_dir: str, config_paths: list[str], steps: int | None, seed: int | None,
          command: str, model_type: str | None = None, camera: str | None = None, motion_from: str = "action",
          motion_names: list[str] | None = None, align_time: bool = True) -> str:
    """See :func:`cnfmp.core.training.train` (the recording options: :class:`cnfmp.core.data.RecordingOptions`);
    progress goes to stderr."""
    from cnfmp.core import training
    from cnfmp.core.data import RecordingOptions

    recording = RecordingOptions(camera, motion_from, tuple(motion_names) if motion_names else None)
    return training.train(os.fspath(dataset_dir), os.fspath(out_dir), [os.fspath(path) for path in config_paths],
                          steps, seed, command=command, model_type=model_type, recording=recording,
                          align_time=align_time)


def predictor(model_dir: str):
    """The resident predictor of `model_dir`, (re)loaded when its files changed."""
    model_dir = os.path.abspath(os.fspath(model_dir))
    try:
        key = tuple(os.stat(os.path.join(model_dir, name)).st_mtime_ns
                    for name in (models.CONFIG_FILE, models.WEIGHTS_FILE))
    except OSError:
        key = None  # load_predictor names what is missing
    cached = _LOADED.get(model_dir)
    if cached is None or cached[0] != key or key is None:
        _LOADED[model_dir] = (key, models.load_predictor(model_dir))
    return _LOADED[model_dir][1]


def predict(model_dir: str, image_png: bytes, masks_png: bytes, objects: list[str], seed: int = 0) -> str:
    """Predicts the trajectory for a scene image and its coarse masks.

    Args:
        model_dir: a directory written by ``cnfmp train``.
        image_png: the encoded scene image; masks_png: the encoded label map (same size).
        objects: object names in label order (``objects.json``'s list).
        seed: seed of inference's random search candidates.

    Returns the trajectory JSON of design.md, ``{"fps", "frames": [{"t", "position",
    "orientation", "gripper"}]}`` (a joint-space model: ``{"fps", "joint_names", "frames":
    [{"t", "joints", "gripper"}]}``), plus ``"model"``, ``"objects"`` (per slot: name, present,
    simplex weights, reconstruction MSE and PSNR as confidence, mask IoU; empty for the
    baselines, which have no objects), ``"scene_psnr_db"`` (null for models without a scene
    field) and ``"timings_ms"``; for a model trained on a recording in another form,
    ``"recorded"``: the frames in that form (:func:`_recorded_form`).
    """
    answer = predict_batch(model_dir, [(image_png, masks_png, objects)], seed)[0]
    if isinstance(answer, Exception):
        raise answer
    return answer


def predict_batch(model_dir: str, scenes: list[tuple[bytes, bytes, list[str]]], seed: int = 0) -> list:
    """:func:`predict` for several scenes of one model at once (a server's batch): the
    objects of every scene are fitted together, so the cores stay busy, and each scene's
    answer is the one :func:`predict` gives it alone (only its timings differ: the fit's is
    the whole batch's).

    Args:
        scenes: (image_png, masks_png, objects) per scene, as :func:`predict` takes them.

    Returns one entry per scene, in order: the JSON document of :func:`predict`, or the
    exception that scene raised (:class:`cnfmp.errors.InputError` for its bad input); one
    scene's bad input does not fail the others. A model that cannot be loaded raises.
    """
    started = time.perf_counter()
    model = predictor(model_dir)
    loaded = time.perf_counter()
    c = model.config
    object_centric = isinstance(c, CnfmpConfig)
    answers: list = [None] * len(scenes)
    prepared = []  # (index, inputs, objects, decode seconds)
    for index, (image_png, masks_png, objects) in enumerate(scenes):
        decoding = time.perf_counter()
        try:
            image, labels, objects = _decoded_scene(c, image_png, masks_png, objects)
            inputs = model.prepare(image, labels) if object_centric else (image, labels)
        except InputError as err:
            answers[index] = err
            continue
        prepared.append((index, inputs, objects, time.perf_counter() - decoding))
    if object_centric:
        results = model.predict_prepared([inputs for _, inputs, _, _ in prepared], [seed] * len(prepared))
    else:  # the baselines fit one global latent per image; nothing to share
        results = [model.predict(*inputs, seed=seed) for _, inputs, _, _ in prepared]
    for (index, _, objects, decode_s), result in zip(prepared, results):
        answers[index] = _document(model_dir, c, result, objects, {
            "decode_inputs": 1000 * decode_s, "load_model": 1000 * (loaded - started),
            "infer_latents": 1000 * result["seconds"]["infer"], "decode_trajectory": 1000 * result["seconds"]["decode"],
            "total": 1000 * (time.perf_counter() - started)})
    return answers


def predict_scan(model_dir: str, scan_dir: str, seed: int = 0, figure: str | None = None, prompt: str | None = None,
                 backend_name: str = "auto", weights: str | None = None) -> str:
    """Predicts the trajectory for a scan (a directory of :mod:`cnfmp.scan`: ``cameras.json``
    with the views' depth and label maps; or a labelled point cloud file with its sensor
    origins, :mod:`cnfmp.point_cloud`) with a cnfmp-3d model.

    Returns the trajectory JSON of :func:`predict`; per object slot its simplex weights,
    the fit's loss, its centre (world, m) and turn about the vertical (deg). With `prompt`,
    the scan's label maps are replaced by the segmenter's on its RGB views (backend
    `backend_name`, `weights`), ordered by the model's prompt roles. With `figure`,
    also writes a picture of the scan's points, the reconstructed surface and the path there
    (PNG, :func:`cnfmp.core.figures_3d.scan_figure`). InputError for a bad scan or a model
    that does not take scans.
    """
    from cnfmp import scan as scans
    from cnfmp.core.configuration_cnfmp3d import Cnfmp3dConfig

    started = time.perf_counter()
    model = predictor(model_dir)
    loaded = time.perf_counter()
    c = model.config
    if not isinstance(c, Cnfmp3dConfig):
        raise InputError(f"the model in {model_dir} ({c.model_type}) predicts from an image and masks, not from a scan")
    from cnfmp.point_cloud import is_point_cloud, read_point_cloud

    path = os.fspath(scan_dir)
    scan = read_point_cloud(path) if is_point_cloud(path) else scans.read_scan(path)
    if prompt is not None:
        scan = segmented_scan(c, scan, prompt, backend_name, weights)
    read = time.perf_counter()
    result = model.predict_scan(scan, seed)
    fit = result["fit"]
    from cnfmp.core.occupancy import SceneBox

    box = SceneBox.of(c)
    slots = [{"slot": k + 1, "name": scan.objects[k] if k < len(scan.objects) else c.object_names[k], "present": True,
              "weights": fit.weights[k].double().numpy().round(5).tolist(), "fit_loss": round(fit.losses[k], 6),
              "centre_m": box.to_world(fit.centres[k].double().numpy()).round(4).tolist(),
              "turn_deg": round(float(np.degrees(float(fit.turns[k]))), 2)} for k in range(c.num_objects)]
    timings = {"load_model": 1000 * (loaded - started), "decode_inputs": 1000 * (read - loaded),
               "infer_latents": 1000 * result["seconds"]["infer"], "decode_trajectory": 1000 * result["seconds"]["decode"],
               "total": 1000 * (time.perf_counter() - started)}
    if figure:
        from cnfmp.core.figures_3d import scan_figure

        scan_figure(model.model, scan, fit, result["trajectory"], os.fspath(figure))
    return _trajectory_document(model_dir, c, result["trajectory"], slots, None, timings)


def segmented_scan(config, scan, prompt: str, backend_name: str = "auto", weights: str | None = None):
    """`scan` with each view's label map found by the segmenter on its RGB image for
    `prompt`, label k the phrase filling the model's k-th slot (its prompt roles). A view
    where the segmenter grounds nothing is left unlabelled (background); InputError when the
    model has no prompt roles, a view has no RGB image, or no view grounds the prompt."""
    import dataclasses

    from cnfmp.scan import Scan
    from cnfmp.segmenter import api as segmenter_api
    from cnfmp.segmenter import phrases

    roles = phrases.vocabulary()["task_roles"].get(config.task)
    if not roles:
        raise InputError(f"the model's task {config.task!r} has no prompt roles (prompts/vocabulary.json), so a "
                         "prompt cannot name its objects; send the scan with its label maps")
    views, failures = [], []
    for view in scan.views:
        if view.rgb is None:
            raise InputError(f"view {view.name} has no RGB image: a prompt is segmented on the views' colour")
        try:
            found = segmenter_api.segment(encode_png(view.rgb), prompt, backend_name, weights, roles=list(roles),
                                          pictures=False)
            labels = decode_labels(found["labels_png"])
        except InputError as err:
            failures.append(f"{view.name}: {err}")
            labels = np.zeros_like(view.labels)
        views.append(dataclasses.replace(view, labels=labels))
    if len(failures) == len(views):
        raise InputError(f"the prompt {prompt!r} was grounded in no view of the scan ({'; '.join(failures)})")
    names = tuple(scan.objects) or tuple(config.object_names)
    return Scan(tuple(views), names)


def _decoded_scene(config, image_png: bytes, masks_png: bytes, objects: list[str]) -> tuple:
    """A scene's image (H, W, 3) uint8, label map (H, W) uint8 and object names as `config`'s
    model reads them (distractors beyond its task objects become background); InputError for
    undecodable files and object lists that do not fit the masks or the model."""
    image, labels = decode_image(image_png), decode_labels(masks_png)
    highest = int(labels.max(initial=0))
    if len(objects) < highest:
        raise InputError(f"the objects list names {len(objects)} object(s) but the masks use label {highest}; "
                         "name every labelled object, in label order")
    if isinstance(config, CnfmpConfig):
        if config.task_objects:  # distractors are background to this model
            labels, objects = task_object_labels(labels, config.task_objects), list(objects)[:config.task_objects]
        if len(objects) > config.num_objects:
            raise InputError(f"{len(objects)} objects given but the model ({config.task}) has {config.num_objects} "
                             f"object slot(s): {', '.join(config.object_names)}")
    return image, labels, objects


def _document(model_dir: str, c, result: dict, objects: list[str], timings_ms: dict) -> str:
    """The JSON answer of :func:`predict` for one scene's prediction `result`."""
    traj = result["trajectory"]
    slots = []
    for slot in range(c.num_objects if isinstance(c, CnfmpConfig) else 0):
        present = bool(result["present"][slot])
        slots.append({
            "slot": slot + 1, "name": objects[slot] if slot < len(objects) else c.object_names[slot],
            "present": present,
            "weights": result["weights"][slot].astype(np.float64).round(5).tolist() if present else None,
            "reconstruction_mse": result["object_mse"][slot], "psnr_db": result["object_psnr_db"][slot],
            "mask_iou": result["mask_iou"][slot],
        })
    return _trajectory_document(model_dir, c, traj, slots, result.get("scene_psnr_db"), timings_ms)


def _trajectory_document(model_dir: str, c, traj: dict, slots: list[dict], scene_psnr_db, timings_ms: dict) -> str:
    """The JSON answer of a prediction: trajectory `traj` (decode_trajectory's dict), the
    per-slot diagnostics, the scene's PSNR (None without one) and the timings."""
    # Rounded and converted as whole arrays: per frame, numpy calls cost ~3 ms a scene.
    keys = ("t", "joints", "gripper") if c.in_joint_space else ("t", "position", "orientation", "gripper")
    columns = [np.asarray(traj[key], dtype=np.float64).round(6).tolist() for key in keys]
    frames = [dict(zip(keys, values)) for values in zip(*columns)]
    recorded = _recorded_form(c, traj)
    return json.dumps({
        "fps": c.output_fps, **({"joint_names": list(c.joint_names)} if c.in_joint_space else {}),
        "frames": frames, **({"recorded": recorded} if recorded else {}),
        "model": {"dir": os.path.abspath(model_dir), "task": c.task, "type": c.model_type},
        "objects": slots, "scene_psnr_db": scene_psnr_db,
        # load_model is near zero once the model is resident (it then only checks file times).
        "timings_ms": timings_ms,
    })


def _recorded_form(config, trajectory: dict) -> dict | None:
    """The predicted trajectory in the form the training data recorded it
    (``MotionConfig.recorded_motion``): ``{"source", "names", "values": [[...] per frame]}``,
    or None for a model trained on poses."""
    if not config.recorded_motion:
        return None
    from cnfmp.data import recorded

    spec = config.recorded_motion
    layout = recorded.motion_layout(spec["source"], spec["names"])
    parts = ("joints",) if config.in_joint_space else ("position", "orientation")
    motion = np.concatenate([*(trajectory[part] for part in parts), trajectory["gripper"][:, None]], axis=1)
    names, values = recorded.from_motion(motion, layout, spec.get("gripper_range"))
    return {"source": spec["source"], "names": names, "values": values.round(6).tolist()}


def describe(model_dir: str) -> str:
    """Loads `model_dir` (it stays resident, so the first request does not pay for it) and
    describes it as JSON: ``{"task", "type", "objects": [slot names], "task_objects",
    "takes_distractors" (objects beyond the task objects are background), "parameters", "roles": [what fills each slot from a prompt, or null when prompts cannot
    be mapped onto this task], "output_fps", "duration_s", "input": "image" or "scan"}``."""
    from cnfmp.core.configuration_cnfmp3d import Cnfmp3dConfig
    from cnfmp.segmenter import phrases

    model = predictor(model_dir)
    c = model.config
    if isinstance(c, Cnfmp3dConfig):
        return json.dumps({"task": c.task, "type": c.model_type, "objects": list(c.object_names),
                           "task_objects": c.num_objects, "takes_distractors": False,
                           "parameters": model.model.parameter_count(),
                           "roles": phrases.vocabulary()["task_roles"].get(c.task), "output_fps": c.output_fps,
                           "duration_s": c.duration_s, "input": "scan"})
    object_centric = isinstance(c, CnfmpConfig)
    # Prompts fill object slots; a model without objects can only be driven by masks.
    # The roles recorded with the training data describe the model's own slots, so they win
    # over the vocabulary's for a task of the same name.
    roles = (list(c.object_roles) or phrases.vocabulary()["task_roles"].get(c.task)) if object_centric else None
    return json.dumps({
        "task": c.task, "type": c.model_type, "objects": list(c.object_names) if object_centric else [],
        "task_objects": (c.task_objects or c.num_objects) if object_centric else 0,
        "takes_distractors": bool(object_centric and c.task_objects),
        "parameters": model.model.parameter_count(),
        "roles": roles, "output_fps": c.output_fps, "duration_s": c.duration_s, "input": "image",
    })


def synthetic_scene(names: list[str]) -> tuple[bytes, bytes, list[str]]:
    """A 160x120 grey scene with one flat 24-px square per object name, its label map (both
    PNG) and the names: what warm-ups and start-up probes predict, never a real scene."""
    image = np.full((120, 160, 3), 128, np.uint8)
    labels = np.zeros((120, 160), np.uint8)
    for k in range(len(names)):
        x, y = 10 + 36 * (k % 4), 20 + 50 * (k // 4)
        image[y:y + 24, x:x + 24] = (60 * k % 256, 200, 90)
        labels[y:y + 24, x:x + 24] = k + 1
    return encode_png(image), encode_png(labels), list(names)


def start_helpers(count: int | None = None) -> str:
    """Starts `count` helper processes (default: one per core beyond the first, see
    :func:`cnfmp.helper_processes.default_count`) that fit objects beside this process, for
    a server or an evaluation that predicts many scenes; returns how many run, as JSON.
    Call it before the warm-ups, so that they load the models into the helpers too."""
    from cnfmp import helper_processes

    return json.dumps(helper_processes.start(count, preload=("cnfmp.core.inference", "cnfmp.core.inference_cnfmp3d")))


def synthetic_scan(config):
    """A scan of one downward-looking camera over `config`'s scene box (a cnfmp-3d config):
    a flat floor at the box's lower quarter and one 6 cm raised square per object slot. What
    warm-ups predict, never a real scene."""
    from cnfmp.scan import Scan, ScanView

    size, focal = 96, 96.0
    centre, half = np.asarray(config.box_centre), config.box_half
    height = 2.0 * half
    pose = np.eye(4)
    pose[:3, :3] = np.diag([1.0, -1.0, -1.0])  # OpenCV axes looking straight down
    pose[:3, 3] = centre + [0.0, 0.0, height]
    floor = height + 0.5 * half
    depth = np.full((size, size), floor, np.float32)
    labels = np.zeros((size, size), np.uint8)
    side = int(round(0.06 / floor * focal))
    for k in range(config.num_objects):
        row, col = size // 2 - side // 2, 8 + k * (side + 8)
        depth[row:row + side, col:col + side] = floor - 0.05
        labels[row:row + side, col:col + side] = k + 1
    intrinsics = np.array([[focal, 0, size / 2], [0, focal, size / 2], [0, 0, 1]])
    return Scan((ScanView("synthetic", None, depth, labels, intrinsics, pose),), tuple(config.object_names))


def warm_up(model_dir: str) -> str:
    """Loads `model_dir` and predicts a synthetic scene (or, for a model that takes scans,
    a synthetic scan) with it, so that a server's first real request does not pay the first
    call's costs (allocator growth, the fit's lazily built pieces). Returns the time it took
    as JSON (ms)."""
    from cnfmp.core.configuration_cnfmp3d import Cnfmp3dConfig

    started = time.perf_counter()
    model = predictor(model_dir)
    if isinstance(model.config, Cnfmp3dConfig):
        model.predict_scan(synthetic_scan(model.config))
    else:
        names = json.loads(describe(model_dir))["objects"] or ["object 1", "object 2"]
        predict(model_dir, *synthetic_scene(names))
    return json.dumps(round(1000 * (time.perf_counter() - started), 1))
