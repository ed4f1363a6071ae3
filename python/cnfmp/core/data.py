"""Demonstrations for the core models, read from a LeRobot v3.0 dataset by lerobot itself.

A demonstration is what the method trains on (paper §II): the scene image and coarse object
masks of the episode's first frame, and the whole commanded end-effector trajectory. Also
the per-scene inputs of the models (image + label map -> :class:`SceneInputs`: arrays at
field resolution and each object's mask statistics), shared by training and prediction so
both see identical preprocessing.
"""

from __future__ import annotations

import dataclasses

import json
from dataclasses import dataclass

from typing import TYPE_CHECKING

import numpy as np

from cnfmp.errors import InputError

if TYPE_CHECKING:
    from cnfmp.core.alignment import RecordedTiming
    from cnfmp.data.recorded import MotionLayout


@dataclass
class Demonstrations:
    """Demonstrations of one task.

    Attributes:
        task: task name (from ``annotation.scene``).
        fps: frame rate of the trajectories (Hz).
        images: (B, H, W, 3) uint8 first-frame camera images.
        masks: (B, H, W) uint8 label maps (0 background, k = objects[b][k-1]).
        objects: per demonstration, the object names in label order.
        trajectories: per demonstration, (T_b, 8) float64 ``x y z qw qx qy qz gripper``
            poses at `fps` (gripper in [0, 1]); in joint space (T_b, J + 1): the joint values
            in `joint_names` order, then the gripper.
        seeds: scene seeds (-1 where the dataset does not record them).
        prompts: the language instruction of each demonstration.
        camera: the camera feature the images come from.
        layout: how the trajectories were read (None: given as poses).
        gripper_range: the recorded gripper values read as 0 and 1 (None: kept as recorded).
        roles: per demonstration, the prompt role of each object in label order, where
            `cnfmp dataset annotate` recorded them (else empty).
        scans: per demonstration, the scan taken before it (:class:`cnfmp.scan.Scan`),
            where the dataset records scans (else empty).
        timing: for trajectories aligned by their gripper events, how they were timed
            before (:class:`cnfmp.core.alignment.RecordedTiming`); None as recorded.
    """

    task: str
    fps: float
    images: np.ndarray
    masks: np.ndarray
    objects: list[list[str]]
    trajectories: list[np.ndarray]
    seeds: list[int]
    prompts: list[str]
    camera: str = ""
    layout: MotionLayout | None = None
    gripper_range: tuple[float, float] | None = None
    roles: list[list[str]] = dataclasses.field(default_factory=list)
    scans: list = dataclasses.field(default_factory=list)
    timing: RecordedTiming | None = None

    def __len__(self) -> int:
        return len(self.trajectories)

    @property
    def motion(self) -> str:
        """How the trajectories were read, for logs and the model card."""
        if self.layout is None:
            return "given as poses"
        low_high = "" if self.gripper_range is None else f"; gripper {self.gripper_range[0]:g}..{self.gripper_range[1]:g} read as 0..1"
        return self.layout.describe() + low_high

    @property
    def joint_names(self) -> list[str]:
        """The joints of a joint-space recording, in the trajectories' column order (empty
        for poses)."""
        return [] if self.layout is None else self.layout.joint_names

    def recorded_motion(self) -> dict:
        """The layout as a model config keeps it (``MotionConfig.recorded_motion``); empty
        when the recording is the pose form itself."""
        from cnfmp.data.generate import STATE_NAMES

        if self.layout is None or (list(self.layout.names) == STATE_NAMES and self.gripper_range is None):
            return {}
        return {"source": self.layout.source, "names": list(self.layout.names),
                "gripper_range": None if self.gripper_range is None else list(self.gripper_range)}


@dataclass(frozen=True)
class RecordingOptions:
    """How to read a dataset a robot recorded (``cnfmp train --camera --motion-from
    --motion-names``); the defaults read datasets cnfmp wrote as they are.

    Attributes:
        camera: the camera feature whose first frames are the scenes (None: the annotated
            one, else the only one).
        motion_from: the feature the trajectories come from: "action" (the commanded poses)
            or "observation.state" (the measured ones).
        motion_names: names of the motion vector's dimensions, overriding the dataset's
            (see :mod:`cnfmp.data.recorded` for the names understood).
    """

    camera: str | None = None
    motion_from: str = "action"
    motion_names: tuple[str, ...] | None = None


def load_demonstrations(dataset_dir: str, options: RecordingOptions = RecordingOptions()) -> Demonstrations:
    """Reads every episode of the LeRobot dataset at `dataset_dir`.

    The scene of an episode is its first frame of the chosen camera (image or video, any
    size) with its coarse masks (``annotation.masks``, ``annotation.objects``). The
    trajectory comes from `options.motion_from`, turned into end-effector poses by its layout
    (:mod:`cnfmp.data.recorded`). Read from ``action`` when ``observation.state`` has the same
    layout, it is the first measured state followed by every frame's action (the commanded
    pose of the next frame). Raises InputError when the directory is not a LeRobot dataset
    with what the core needs.
    """
    # Imported here: the dataset readers pull in the simulator and scipy, which inference
    # (scene_inputs, a cold `cnfmp predict`) never needs.
    from cnfmp import scan as scans
    from cnfmp.data import recorded
    from cnfmp.data.lerobot_io import annotated_scene, first_frame, open_dataset

    dataset = open_dataset(dataset_dir)
    features = dataset.meta.features
    missing = sorted({options.motion_from, "annotation.masks", "annotation.objects"} - set(features))
    if missing:
        hint = ("; add coarse masks with `cnfmp dataset annotate`" if "annotation.masks" in missing else "")
        raise InputError(f"{dataset_dir}: the dataset lacks feature(s) {', '.join(missing)}{hint}")
    if dataset.num_episodes == 0:
        raise InputError(f"{dataset_dir}: the dataset has no episodes")
    camera = recorded.choose_camera(features, options.camera, annotated_scene(dataset).get("camera"))
    names = options.motion_names or features[options.motion_from].get("names")
    layout = recorded.motion_layout(options.motion_from, names)
    state_names = features.get("observation.state", {}).get("names")
    prepend_state = options.motion_from == "action" and options.motion_names is None and state_names == names

    columns = [options.motion_from] + (["observation.state"] if prepend_state else [])
    table = dataset.hf_dataset.with_format(None).select_columns(columns)[:]
    motion = np.asarray(table[options.motion_from], float)
    state = np.asarray(table["observation.state"], float) if prepend_state else None
    starts = dataset.meta.episodes["dataset_from_index"]
    ends = dataset.meta.episodes["dataset_to_index"]
    images, masks, objects, episodes, seeds, prompts, roles, tasks = [], [], [], [], [], [], [], set()
    scanned = []
    for episode, (start, end) in enumerate(zip(starts, ends)):
        first, image = first_frame(dataset, episode, camera)
        if scans.CAMERAS_FEATURE in features:
            row = {key: (value.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
                   if key != scans.CAMERAS_FEATURE else value
                   for key, value in first.items() if key.startswith(scans.SCAN_FEATURE_PREFIX)}
            scanned.append(scans.from_dataset_row(row, f"{dataset_dir}: episode {episode}"))
        images.append(image)
        masks.append(np.asarray(first["annotation.masks"], dtype=np.uint8))
        if masks[-1].shape != images[-1].shape[:2]:
            raise InputError(f"{dataset_dir}: episode {len(masks) - 1}'s masks are {masks[-1].shape[1]}x"
                             f"{masks[-1].shape[0]} but camera {camera} is {images[-1].shape[1]}x{images[-1].shape[0]}")
        objects.append(list(json.loads(first["annotation.objects"])))
        prompts.append(str(first["task"]))
        scene = json.loads(first.get("annotation.scene", "{}") or "{}")
        seeds.append(int(scene.get("seed", -1)))
        roles.append(list(scene.get("roles", [])))
        tasks.add(scene.get("task", ""))
        rows = motion[start:end]
        episodes.append(np.concatenate([state[start:start + 1], rows]) if prepend_state else rows)
    if len(tasks) > 1:
        raise InputError(f"{dataset_dir}: episodes of several tasks ({', '.join(sorted(tasks))}); train one task per model")
    trajectories, scale = recorded.to_motion(episodes, layout)
    return Demonstrations(tasks.pop(), float(dataset.fps), np.stack(images), np.stack(masks), objects,
                          trajectories, seeds, prompts, camera, layout, scale, roles, scanned)


def task_object_labels(labels: np.ndarray, count: int) -> np.ndarray:
    """A label map (any shape, uint8) with only its first `count` objects; later labels
    (distractors) become background (0)."""
    return np.where(labels > count, 0, labels).astype(np.uint8)


def keep_task_objects(demos: Demonstrations, count: int) -> Demonstrations:
    """`demos` with only the first `count` labelled objects; later labels become background."""
    return dataclasses.replace(demos, masks=task_object_labels(demos.masks, count),
                               objects=[names[:count] for names in demos.objects],
                               roles=[names[:count] for names in demos.roles])


#: What :attr:`SceneInputs.observations` holds for each object, in its column order, all in
#: image coordinates ([-1, 1] across the image, x right, y down) unless said otherwise:
#: the mask's centroid (2); its shading moments (3, :func:`_shading_moments`): the offset from
#: the centroid to the darkness-weighted centroid and the mean luminance in [0, 1]; and its
#: tilt cues (5, :func:`_tilt_cues`): the elongation (long axis at twice its angle, scaled by
#: how elongated the mask is, unitless), the size (RMS distance of its pixels from the
#: centroid) and the offset from the centroid to the centroid of its shaded part.
OBSERVATION_NAMES = ("centroid_x", "centroid_y", "dark_dx", "dark_dy", "luminance", "elongation_cos",
                     "elongation_sin", "size", "shaded_dx", "shaded_dy")


@dataclass(frozen=True)
class SceneInputs:
    """One scene's image and coarse masks prepared for a model: what training
    (:class:`cnfmp.core.training_cnfmp.TrainingSet`) and inference
    (:meth:`cnfmp.core.inference.Predictor.infer_scene`) read, made by :func:`scene_inputs`
    alone so that both see identical preprocessing. R is the field resolution, N the
    model's object slots (slot k holds label k + 1).

    Attributes:
        rgb: (R, R, 3) float32 image in [0, 1], area-resampled to the field resolution.
        masks: (N, R, R) bool coarse masks at field resolution (a pixel at least 1/4 covered).
        dilated: (N, R, R) bool the masks dilated by the config's `mask_dilation` (px).
        colour: (N, 3) float32 median RGB colour in [0, 1] of each mask (0 when absent).
        observations: (N, len(OBSERVATION_NAMES)) float32 each object's mask statistics, at
            full image resolution, in the order of OBSERVATION_NAMES (:func:`observe_mask`;
            0 when absent): what the model reads of an object besides its latent (the
            centroids, the columns of the config's
            `observed_statistics`, all ten for the object of `tool_axis_object`).
        present: (N,) bool whether the slot's mask has any pixel at field resolution.
    """

    rgb: np.ndarray
    masks: np.ndarray
    dilated: np.ndarray
    colour: np.ndarray
    observations: np.ndarray
    present: np.ndarray

    @property
    def centre(self) -> np.ndarray:
        """(N, 2) float32 mask centroids in image coordinates (contiguous copy of
        ``observations[:, :2]``)."""
        return np.ascontiguousarray(self.observations[:, :2])


def observe_mask(image: np.ndarray, mask: np.ndarray) -> list[float]:
    """The statistics of one object's mask that the motion may read: len(OBSERVATION_NAMES)
    floats in that order (centroid, shading moments, tilt cues; image coordinates in [-1, 1]
    across the image, luminance in [0, 1]), computed in float64; all 0 for an empty mask.

    Args:
        image: (H, W, 3) uint8 camera image.
        mask: (H, W) bool full-resolution mask of the object.
    """
    if not mask.any():
        return [0.0] * len(OBSERVATION_NAMES)
    height, width = mask.shape
    rows, cols = np.nonzero(mask)
    centre = [(cols.mean() + 0.5) / width * 2 - 1, (rows.mean() + 0.5) / height * 2 - 1]
    luminance = image[rows, cols].astype(np.float64).mean(axis=1)  # 0..255
    return [*centre, *_shading_moments(luminance, rows, cols, height, width),
            *_tilt_cues(luminance, rows, cols, height, width)]


def scene_inputs(image: np.ndarray, labels: np.ndarray, num_objects: int, resolution: int,
                 dilation: int) -> SceneInputs:
    """One scene's image and coarse masks prepared for the fields and the motion.

    Args:
        image: (H, W, 3) uint8 camera image; labels: (H, W) uint8 label map (0 background,
            k the k-th object); num_objects: the model's object slots N.
        resolution: field resolution R (px); dilation: mask dilation at that resolution (px).

    Returns the :class:`SceneInputs`. InputError for mismatched sizes or labels beyond the slots.
    """
    import cv2

    image, labels = np.asarray(image), np.asarray(labels)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise InputError(f"image must be an (H, W, 3) uint8 RGB image, got shape {image.shape} dtype {image.dtype}")
    if labels.shape != image.shape[:2]:
        raise InputError(f"the masks are {labels.shape[1]}x{labels.shape[0]} but the image is "
                         f"{image.shape[1]}x{image.shape[0]}; they must have the same size")
    highest = int(labels.max(initial=0))
    if highest > num_objects:
        raise InputError(f"the masks use label {highest} but the model has {num_objects} object slot(s)")
    rgb = cv2.resize(image, (resolution, resolution), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
    kernel = np.ones((2 * dilation + 1, 2 * dilation + 1), np.uint8)
    masks, dilated, colours, observations = [], [], [], []
    for k in range(1, num_objects + 1):
        full = labels == k
        # Coverage >= 1/4 of a field pixel counts, so thin or far objects keep their mask.
        coverage = cv2.resize(full.astype(np.float32), (resolution, resolution), interpolation=cv2.INTER_AREA)
        small = coverage >= 0.25
        masks.append(small)
        dilated.append(cv2.dilate(small.astype(np.uint8), kernel) > 0)
        colours.append(np.median(image[full], axis=0) / 255.0 if full.any() else np.zeros(3))
        observations.append(observe_mask(image, full))
    return SceneInputs(rgb=rgb, masks=np.stack(masks), dilated=np.stack(dilated),
                       colour=np.asarray(colours, np.float32), observations=np.asarray(observations, np.float32),
                       present=np.array([m.any() for m in masks]))


def _shading_moments(luminance: np.ndarray, rows: np.ndarray, cols: np.ndarray, height: int,
                     width: int) -> list[float]:
    """[dx, dy, mean luminance in [0, 1]] of one non-empty mask, given as its pixels'
    `luminance` (0..255), `rows` and `cols` in a `height` x `width` image: the offset from its
    centroid to its darkness-weighted centroid in image coordinates ([-1, 1] across the
    image), each pixel weighted by the square of how much darker it is than the mask's
    brightest pixel."""
    luminance = luminance / 255.0
    darkness = (luminance.max() - luminance) ** 2 + 1e-9  # a uniform mask: no offset, no 0/0
    dx = ((darkness * cols).sum() / darkness.sum() - cols.mean()) / width * 2
    dy = ((darkness * rows).sum() / darkness.sum() - rows.mean()) / height * 2
    return [dx, dy, luminance.mean()]


#: A pixel belongs to a mask's shaded part when its luminance is under this fraction of the
#: mask's median luminance (validation scenes: 0.8-0.95 work alike, docs/experiments.md).
SHADED_BELOW_MEDIAN = 0.9


def _tilt_cues(luminance: np.ndarray, rows: np.ndarray, cols: np.ndarray, height: int,
               width: int) -> list[float]:
    """[elongation_cos, elongation_sin, size, shaded_dx, shaded_dy] of one non-empty mask, given
    as its pixels' `luminance`, `rows` and `cols` in a `height` x `width` image, in image
    coordinates ([-1, 1] across the image).

    With x, y the pixels' offsets from the mask's centroid and s^2 = mean(x^2 + y^2): the
    elongation is (mean(x^2 - y^2), mean(2 x y)) / s^2 (the direction of the mask's long axis
    at twice its angle, scaled by how elongated it is), the size is s, and the shaded offset
    runs from the centroid to the centroid of the shaded part (pixels darker than
    SHADED_BELOW_MEDIAN times the mask's median luminance; 0 when there are none). Where a
    tilted surface's shaded faces and support lie tells which way it rises better than the
    darkness-weighted moment of :func:`_shading_moments`, which the darkest pixels dominate.
    """
    x = (cols - cols.mean()) / width * 2
    y = (rows - rows.mean()) / height * 2
    spread = (x * x + y * y).mean() + 1e-12  # a one-pixel mask: no 0/0
    shaded = luminance < SHADED_BELOW_MEDIAN * np.median(luminance)
    offset = [x[shaded].mean(), y[shaded].mean()] if shaded.any() else [0.0, 0.0]
    return [(x * x - y * y).mean() / spread, 2.0 * (x * y).mean() / spread, float(np.sqrt(spread)), *offset]
