"""LeRobot v3.0 datasets from staged episodes, and back out again (lerobot 0.4.4).

`cnfmp dataset convert` (Rust) stages every source episode first, in parallel: the
trajectory validated and resampled to the dataset fps, the camera images as RGB PNG files,
the coarse masks as one grayscale label-map PNG, and an ``episode.json`` describing them.
This module does the parts that need lerobot:

- :func:`write_staged`: one pass over the staged episodes, in order, writing the dataset with
  lerobot's own writer (``save_episode`` with a whole-episode buffer whose image entries are
  the staged PNG paths, so lerobot embeds those files as they are: no image is re-encoded).
- :func:`export_episode`: one episode of a dataset as a raw episode folder (the inverse).
- :func:`inspect`: the read-back half of ``cnfmp dataset validate``.

The feature layout is the one :mod:`cnfmp.data.generate` writes, so converted datasets
train with ``cnfmp train`` like simulated ones.
"""

from __future__ import annotations

import json
import os

import numpy as np

from cnfmp.data.generate import IMAGE_KEY, features, progress_bar
from cnfmp.errors import InputError


def _read_label_map(path: str) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as image:
        return np.asarray(image.convert("L"), dtype=np.uint8)


def write_staged(staging_dir: str, episode_dirs: list[str], out_dir: str, fps: int, progress: bool = True) -> str:
    """Writes the staged episodes (``staging_dir/<d>`` for d in `episode_dirs`, in that order)
    as a LeRobot v3.0 dataset at `out_dir` (which must not exist) and finalizes it.

    Every staged episode carries ``episode.json``: ``{"name", "source", "prompt", "task",
    "objects", "width", "height", "images": [png file names], "frame_images": [index into
    images per frame], "masks": png file name, "trajectory": trajectory JSON at `fps`}``.
    The image size of the dataset is that of the first episode; a later episode of another
    size is left out and reported (``skipped``), never resized silently.

    Returns JSON ``{"episodes", "frames", "skipped": [{"episode", "file", "reason"}]}``.
    """
    import datasets
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    datasets.disable_progress_bars()
    if os.path.exists(out_dir):
        raise InputError(f"{out_dir} already exists")
    if not episode_dirs:
        raise InputError("no episode could be converted, so there is no dataset to write")
    dataset, size, frames, skipped = None, None, 0, []
    bar = progress_bar(len(episode_dirs), "writing", progress)
    for name in episode_dirs:
        episode_dir = os.path.join(staging_dir, name)
        with open(os.path.join(episode_dir, "episode.json")) as handle:
            episode = json.load(handle)
        shape = (int(episode["height"]), int(episode["width"]))
        if size is None:
            size = shape
            dataset = LeRobotDataset.create(repo_id="cnfmp/converted", fps=int(fps), features=features(*size),
                                            root=out_dir, robot_type="cnfmp_converted", use_videos=False)
        if shape != size:
            skipped.append({"episode": episode["name"], "file": episode["source"],
                            "reason": f"its images are {shape[1]}x{shape[0]} but the dataset's are "
                                      f"{size[1]}x{size[0]} (set by its first episode); convert "
                                      "different cameras into separate datasets"})
            bar.update(1)
            continue
        frames += _save_episode(dataset, episode_dir, episode, fps)
        bar.update(1)
    bar.close()
    dataset.finalize()
    return json.dumps({"episodes": dataset.meta.total_episodes, "frames": frames, "skipped": skipped})


def _save_episode(dataset, episode_dir: str, episode: dict, fps: int) -> int:
    poses = np.asarray([f["position"] + f["orientation"] + [f["gripper"]] for f in episode["trajectory"]["frames"]],
                       dtype=np.float32)
    count = len(poses)
    # The action of a frame is the pose of the next one (the last frame holds its pose), as in
    # simulated datasets, so the core's "first state + actions" is the whole trajectory.
    action = np.concatenate([poses[1:], poses[-1:]])
    images = [os.path.join(episode_dir, name) for name in episode["images"]]
    masks = _read_label_map(os.path.join(episode_dir, episode["masks"]))
    scene = json.dumps({"task": episode["task"], "seed": int(episode.get("seed", -1)), "episode": episode["name"]})
    objects = json.dumps(episode["objects"])
    buffer = {
        "size": count,
        "task": [episode["prompt"]] * count,
        "episode_index": dataset.meta.total_episodes,
        "index": None, "task_index": None,  # filled in by save_episode
        "frame_index": np.arange(count),
        "timestamp": (np.arange(count) / fps).astype(np.float32),
        IMAGE_KEY: [images[k] for k in episode["frame_images"]],
        "observation.state": list(poses),
        "action": list(action),
        "annotation.masks": [masks] * count,
        "annotation.objects": [objects] * count,
        "annotation.scene": [scene] * count,
    }
    dataset.save_episode(episode_data=buffer)
    return count


def open_dataset(dataset_dir: str):
    """Opens the LeRobot dataset at `dataset_dir` with lerobot's own reader, offline.

    InputError when the directory is not a dataset or lerobot cannot read it.
    """
    if not os.path.isfile(os.path.join(dataset_dir, "meta", "info.json")):
        raise InputError(f"{dataset_dir} is not a LeRobot dataset (no meta/info.json)")
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    try:
        # pyav: lerobot's default video decoder (torchcodec) needs a system FFmpeg (facts.md).
        return LeRobotDataset(f"local/{os.path.basename(os.path.abspath(dataset_dir))}", root=dataset_dir,
                              video_backend="pyav")
    except Exception as err:  # lerobot raises many types for a damaged dataset
        missing = _missing_files(dataset_dir)
        if missing:  # lerobot would have fetched them from the hub: name them instead
            raise InputError(f"{dataset_dir}: {len(missing)} file(s) of the dataset are missing, e.g. "
                             f"{missing[0]}") from err
        raise InputError(f"{dataset_dir}: lerobot cannot read this dataset: {err}") from err


def annotated_scene(dataset) -> dict:
    """The ``annotation.scene`` JSON of the dataset's first frame (task, seed, camera, roles as
    the writer recorded them); empty when the dataset has none."""
    if "annotation.scene" not in dataset.meta.features:
        return {}
    return json.loads(dataset.hf_dataset[0]["annotation.scene"] or "{}")


def _missing_files(dataset_dir: str) -> list[str]:
    """The data and video files the dataset's episode index lists that are not on disk."""
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    try:
        meta = LeRobotDatasetMetadata("local/check", root=dataset_dir)
        paths = {str(meta.get_data_file_path(e)) for e in range(meta.total_episodes)}
        paths |= {str(meta.get_video_file_path(e, key)) for e in range(meta.total_episodes) for key in meta.video_keys}
    except Exception:  # the metadata itself is damaged: lerobot's own message says more
        return []
    return sorted(os.path.join(dataset_dir, p) for p in paths if not os.path.isfile(os.path.join(dataset_dir, p)))


def first_frame(dataset, episode: int, camera: str) -> tuple[dict, np.ndarray]:
    """Episode `episode`'s first frame of `dataset` as lerobot returns it, and its `camera`
    image as (H, W, 3) uint8. InputError naming the file when the camera's video is
    missing or cannot be decoded."""
    start = int(dataset.meta.episodes["dataset_from_index"][episode])
    try:
        frame = dataset[start]
    except Exception as err:  # pyav and lerobot raise many types for a bad video
        if camera in dataset.meta.video_keys:
            path = os.path.join(str(dataset.root), str(dataset.meta.get_video_file_path(episode, camera)))
            state = "is missing" if not os.path.isfile(path) else "cannot be decoded"
            raise InputError(f"episode {episode}: the video {path} of camera {camera} {state} ({err})") from err
        raise InputError(f"episode {episode}: lerobot cannot read its first frame ({err})") from err
    return frame, (frame[camera].permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)


_OPEN: dict[str, object] = {}


def _open(dataset_dir: str):
    """The dataset at `dataset_dir`, opened once per process (export calls come per episode)."""
    dataset_dir = os.path.abspath(dataset_dir)
    if dataset_dir not in _OPEN:
        dataset = open_dataset(dataset_dir)
        missing = sorted({IMAGE_KEY, "observation.state"} - set(dataset.features))
        if missing:
            raise InputError(f"{dataset_dir}: the dataset lacks feature(s) {', '.join(missing)}")
        _OPEN.clear()
        _OPEN[dataset_dir] = dataset
    return _OPEN[dataset_dir]


def episodes_of(dataset_dir: str) -> str:
    """JSON ``{"episodes": E, "fps": F, "names": [name per episode], "lengths": [frames per
    episode]}`` of a LeRobot dataset.

    The name is the one the episode had when it was converted (``annotation.scene``), else
    ``episode_<index>``.
    """
    dataset = _open(dataset_dir)
    names = []
    starts = dataset.meta.episodes["dataset_from_index"]
    scenes = dataset.hf_dataset.with_format(None)["annotation.scene"] if "annotation.scene" in dataset.features else None
    for k, start in enumerate(starts):
        scene = json.loads(scenes[int(start)] or "{}") if scenes is not None else {}
        names.append(str(scene.get("episode") or f"episode_{k:06d}"))
    if len(set(names)) != len(names):  # recorded names clash: fall back to indices
        names = [f"episode_{k:06d}" for k in range(len(names))]
    lengths = [int(end) - int(start) for start, end in zip(starts, dataset.meta.episodes["dataset_to_index"])]
    return json.dumps({"episodes": len(names), "fps": float(dataset.fps), "names": names, "lengths": lengths})


def export_episode(dataset_dir: str, index: int, out_dir: str) -> dict:
    """Writes episode `index` of the dataset as a raw episode folder `out_dir` (created):
    ``image.png`` (first frame), ``frames/NNNNNN.png`` (only when the camera image changes
    during the episode), ``masks.png`` + ``objects.json`` (first frame's label map),
    ``meta.json`` (task, prompt, fps, seed). The trajectory file is written by the caller
    from the returned arrays, so every trajectory file goes through one writer.

    Returns ``{"fps", "t" (T,) = frame_index / fps (s), "position" (T,3), "orientation" (T,4)
    [w,x,y,z], "gripper" (T,)}`` from ``observation.state``.
    """
    from PIL import Image

    dataset = _open(dataset_dir)
    if not 0 <= index < dataset.meta.total_episodes:
        raise InputError(f"episode {index} does not exist (the dataset has {dataset.meta.total_episodes})")
    start = int(dataset.meta.episodes["dataset_from_index"][index])
    end = int(dataset.meta.episodes["dataset_to_index"][index])
    rows = dataset.hf_dataset.with_format(None)[start:end]
    state = np.asarray(rows["observation.state"], dtype=np.float64)
    # Frame k is at k / fps exactly (validate checks the stored float32 timestamps agree), so
    # converting the export again lands on the same grid with no interpolation.
    times = np.asarray(rows["frame_index"], dtype=np.float64) / float(dataset.fps)
    os.makedirs(out_dir)
    images = [np.asarray(image.convert("RGB")) for image in rows[IMAGE_KEY]]
    Image.fromarray(images[0]).save(os.path.join(out_dir, "image.png"))
    if any(not np.array_equal(image, images[0]) for image in images[1:]):
        os.makedirs(os.path.join(out_dir, "frames"))
        for k, image in enumerate(images):
            Image.fromarray(image).save(os.path.join(out_dir, "frames", f"{k:06d}.png"))
    scene = json.loads(rows["annotation.scene"][0] or "{}") if "annotation.scene" in rows else {}
    if "annotation.masks" in rows:
        Image.fromarray(np.asarray(rows["annotation.masks"][0], dtype=np.uint8)).save(os.path.join(out_dir, "masks.png"))
        with open(os.path.join(out_dir, "objects.json"), "w") as handle:
            json.dump(json.loads(rows["annotation.objects"][0]), handle, indent=2)
    task_index = int(rows["task_index"][0])
    meta = {"task": scene.get("task", ""), "prompt": str(dataset.meta.tasks.index[task_index]),
            "fps": float(dataset.fps)}
    if int(scene.get("seed", -1)) >= 0:
        meta["seed"] = int(scene["seed"])
    with open(os.path.join(out_dir, "meta.json"), "w") as handle:
        json.dump(meta, handle, indent=2)
    return {"fps": float(dataset.fps), "t": times, "position": state[:, 0:3],
            "orientation": state[:, 3:7], "gripper": state[:, 7]}


def inspect(dataset_dir: str) -> str:
    """The read-back checks of ``cnfmp dataset validate``: opens the dataset with lerobot's
    own ``LeRobotDataset``, decodes the first and last frame of every episode through it, and
    checks the annotations against the images.

    The camera is the annotated one (else the benchmark's front camera, else the first); the
    trajectories are the measured states (else the actions) read by their layout
    (:mod:`cnfmp.data.recorded`).

    Returns JSON ``{"checks": [{"name", "ok", "detail"}], "fps", "joint_names", "episodes":
    [{"index", "timestamps": [...], "state": [[floats] per frame]}]}``: a state is the 8 values
    ``x y z qw qx qy qz gripper``, or with ``joint_names`` (null for a pose recording) the joint
    values then the gripper. The trajectory invariants are checked by the caller (the Rust
    trajectory code).
    """
    checks = []
    try:
        dataset = open_dataset(dataset_dir)  # not the export cache: validate the files as they are now
    except InputError as err:
        return json.dumps({"checks": [{"name": "lerobot read-back", "ok": False, "detail": str(err)}],
                           "fps": 0.0, "joint_names": None, "episodes": []})
    from cnfmp.data import recorded

    info = dataset.meta.info
    features = dataset.meta.features
    checks.append({"name": "format version", "ok": info.get("codebase_version") == "v3.0",
                   "detail": f"codebase_version {info.get('codebase_version')} (cnfmp writes v3.0)"})
    cameras = recorded.camera_keys(features)
    camera = annotated_scene(dataset).get("camera") or (IMAGE_KEY if IMAGE_KEY in cameras else (cameras or [None])[0])
    needed = {"action", "annotation.masks", "annotation.objects"}
    missing = sorted(needed - set(features)) + ([] if camera else ["a camera (image or video feature)"])
    checks.append({"name": "cnfmp features", "ok": not missing,
                   "detail": f"missing {', '.join(missing)}" if missing else
                   f"camera {camera}, action, masks and objects present"})
    source = "observation.state" if "observation.state" in features else "action"
    layout = None
    if source in features:
        try:
            layout = recorded.motion_layout(source, features[source].get("names"))
            checks.append({"name": "motion layout", "ok": True, "detail": layout.describe()})
        except InputError as err:
            checks.append({"name": "motion layout", "ok": False, "detail": str(err)})
    problems, episodes = [], []
    table = dataset.hf_dataset.with_format(None).select_columns([source, "timestamp"])[:] if layout else None
    starts = dataset.meta.episodes["dataset_from_index"]
    ends = dataset.meta.episodes["dataset_to_index"]
    try:
        for k, (start, end) in enumerate(zip(starts, ends)):
            start, end = int(start), int(end)
            for row in {start, end - 1}:
                item = dataset[row]  # decodes through lerobot's own transforms
                if camera is None or "annotation.masks" not in item:
                    continue
                image = item[camera]
                labels = np.asarray(item["annotation.masks"])
                objects = json.loads(item["annotation.objects"])
                if labels.shape != tuple(image.shape[1:]):
                    problems.append(f"episode {k} frame {row - start}: masks {labels.shape} do not match the image {tuple(image.shape[1:])}")
                elif int(labels.max(initial=0)) > len(objects):
                    problems.append(f"episode {k} frame {row - start}: label {int(labels.max())} but only {len(objects)} object name(s)")
            if table is not None:
                episodes.append({"index": k, "timestamps": table["timestamp"][start:end],
                                 "motion": np.asarray(table[source][start:end], np.float64)})
        if layout is not None and episodes:
            poses, _ = recorded.to_motion([e.pop("motion") for e in episodes], layout)
            for episode, pose in zip(episodes, poses):
                episode["state"] = pose.tolist()
        checks.append({"name": "lerobot read-back", "ok": True,
                       "detail": f"LeRobotDataset read {dataset.meta.total_episodes} episodes, {dataset.meta.total_frames} frames"})
    except Exception as err:  # noqa: BLE001 - any failure to decode is the finding
        episodes = []
        checks.append({"name": "lerobot read-back", "ok": False, "detail": f"{type(err).__name__}: {err}"})
    checks.append({"name": "annotations", "ok": not problems,
                   "detail": "; ".join(problems[:5]) if problems else "label maps match the images and name every label"})
    joint_names = list(layout.joint_names) if layout is not None and layout.joint_names else None
    return json.dumps({"checks": checks, "fps": float(dataset.fps), "joint_names": joint_names, "episodes": episodes})
