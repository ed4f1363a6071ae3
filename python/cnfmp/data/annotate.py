"""`cnfmp dataset annotate`: coarse object masks for a LeRobot dataset that has none.

A lab's recording (``lerobot-record``) holds camera streams, motion and a task string per
episode, but no masks. For each episode this runs the language segmenter on the first frame
of one camera with the episode's task prompt (or a given object list), orders the objects by
their role in the prompt (the thing moved, then where it goes, then obstacles, then others)
so that label k means the same part in every episode, and writes a copy of the dataset with
``annotation.masks``, ``annotation.objects`` and ``annotation.scene`` (task name, camera,
roles) added to every frame. Videos are copied, not re-encoded.

An episode where an object is not found is reported (episode, phrase, score) and left out,
unless a hand-made label map ``<masks_dir>/episode_<index>.png`` exists for it (such a file
is used whenever it exists). The per-episode results are kept in ``<out>.staging`` so an
interrupted run resumes where it stopped; the dataset appears at `out` only when complete,
with ``annotation/contact_sheet.png`` (one thumbnail per episode, masks overlaid) and
``annotation/report.json`` inside.
"""

from __future__ import annotations

import json
import os
import re
import shutil

import numpy as np

from cnfmp.data.recorded import choose_camera
from cnfmp.errors import InputError

#: Object slots follow these prompt roles, in this order (then order of mention).
ROLE_ORDER = ("target", "destination", "obstacle", "object", "unknown")
ANNOTATION_DIR = "annotation"
#: The features annotation adds.
ANNOTATION_FEATURES = ("annotation.masks", "annotation.objects", "annotation.scene")
_THUMB_WIDTH = 200


def annotate_image(image: np.ndarray, prompt: str, objects: list[str] | None, segmenter) -> dict:
    """Segments one scene image (H, W, 3) uint8 as annotation does, so that a model trained on an
    annotated dataset gets the same slot order at prediction. Returns ``{"labels" (H, W) uint8, "objects", "roles",
    "scores", "missing": [{"phrase", "score"}]}``, objects in ROLE_ORDER order."""
    from cnfmp.segmenter import segment

    if objects:
        # One call per named object: each name is one phrase, found or not on its own.
        parts = [segment(image, name, segmenter) for name in objects]
        # Named one by one, the objects have no roles relative to each other.
        phrases = [(name, "unknown", p.results[0], p.probabilities[0]) for name, p in zip(objects, parts)]
        order = list(range(len(phrases)))  # the user's order is the slot order
    else:
        found = segment(image, prompt, segmenter)
        phrases = [(p.text, p.role, r, prob) for p, r, prob in zip(found.phrases, found.results, found.probabilities)]
        order = sorted(range(len(phrases)), key=lambda k: (ROLE_ORDER.index(phrases[k][1])
                                                           if phrases[k][1] in ROLE_ORDER else len(ROLE_ORDER), k))
    missing = [{"phrase": phrases[k][0], "score": round(float(phrases[k][2].score), 3)}
               for k in order if not phrases[k][2].found]
    labels = np.zeros(image.shape[:2], np.uint8)
    best = np.zeros(image.shape[:2], np.float32)
    for slot, k in enumerate(order, start=1):
        _, _, result, probability = phrases[k]
        take = result.mask & (probability >= best)  # an overlap goes to the surer object
        labels[take], best[take] = slot, probability[take]
    return {"labels": labels, "objects": [phrases[k][0] for k in order], "roles": [phrases[k][1] for k in order],
            "scores": [round(float(phrases[k][2].score), 3) for k in order], "missing": missing}


def _hand_made(path: str, shape: tuple[int, int], objects: list[str] | None, prompt: str) -> dict:
    """A hand-made label map (8-bit PNG, 0 background, k the k-th object) as an episode result."""
    from PIL import Image

    from cnfmp.segmenter import phrases as prompt_phrases

    with Image.open(path) as picture:
        labels = np.asarray(picture.convert("L"), np.uint8)
    if labels.shape != shape:
        raise InputError(f"{path} is {labels.shape[1]}x{labels.shape[0]} but the camera's frames are {shape[1]}x{shape[0]}")
    count = int(labels.max())
    if count == 0:
        raise InputError(f"{path} labels no object (every pixel is 0)")
    if objects:
        names, roles = list(objects), ["unknown"] * len(objects)
    else:
        parsed = sorted(prompt_phrases.parse(prompt), key=lambda p: ROLE_ORDER.index(p.role))
        names, roles = [p.text for p in parsed], [p.role for p in parsed]
    if len(names) < count:
        names += [f"object {k}" for k in range(len(names) + 1, count + 1)]
        roles += ["unknown"] * (count - len(roles))
    return {"labels": labels, "objects": names[:count], "roles": roles[:count], "scores": [1.0] * count,
            "missing": [], "hand_made": True}


def _check_staging(staging: str, command: dict) -> None:
    """Refuses to resume from `staging` when another command made it (other objects, camera,
    segmenter...): its cached masks would not be what this command asks for."""
    path = os.path.join(staging, "command.json")
    if not os.path.isfile(path):
        return
    with open(path) as handle:
        before = json.load(handle)
    if before != command:
        changed = ", ".join(sorted(k for k in command if before.get(k) != command[k]))
        raise InputError(f"{staging} holds the work of another annotate command (it differs in: {changed}); "
                         "rerun that command to finish it, or remove the folder to start over")


def _contact_sheet(thumbs: list[tuple[np.ndarray, np.ndarray, str, bool]]) -> np.ndarray:
    """One image of (image, labels, caption, ok) thumbnails, six to a row."""
    import cv2

    from cnfmp.segmenter.api import OVERLAY_COLOURS

    palette = np.array([(0, 0, 0), *OVERLAY_COLOURS], np.float32)  # label 0 (background) is never tinted
    tiles = []
    for image, labels, caption, ok in thumbs:
        height = max(1, round(image.shape[0] * _THUMB_WIDTH / image.shape[1]))
        tile = cv2.resize(image, (_THUMB_WIDTH, height), interpolation=cv2.INTER_AREA).astype(np.float32)
        small = cv2.resize(labels, (_THUMB_WIDTH, height), interpolation=cv2.INTER_NEAREST)
        colour = palette[np.where(small > 0, (small - 1) % (len(palette) - 1) + 1, 0)]
        tile = np.where(small[..., None] > 0, 0.5 * tile + 0.5 * colour, tile).round().astype(np.uint8)
        band = np.full((18, _THUMB_WIDTH, 3), (255, 255, 255) if ok else (255, 200, 200), np.uint8)
        cv2.putText(band, caption[:34], (3, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (0, 0, 0), 1, cv2.LINE_AA)
        tiles.append(np.concatenate([band, tile]))
    tall = max(t.shape[0] for t in tiles)
    tiles = [np.pad(t, ((0, tall - t.shape[0]), (0, 0), (0, 0)), constant_values=255) for t in tiles]
    columns = min(6, len(tiles))
    tiles += [np.full_like(tiles[0], 255)] * (-len(tiles) % columns)
    rows = [np.concatenate(tiles[r:r + columns], axis=1) for r in range(0, len(tiles), columns)]
    return np.concatenate(rows)


def annotate(dataset_dir: str, out_dir: str, camera: str | None = None, objects: list[str] | None = None,
             backend_name: str = "auto", weights: str | None = None, masks_dir: str | None = None,
             task: str | None = None, progress: bool = True) -> str:
    """Writes a copy of the dataset at `dataset_dir` with coarse masks to `out_dir` (must not
    exist). See the module docstring.

    Args:
        camera: the camera feature to segment (None: the only one).
        objects: the objects to find in every episode, in slot order (None: those the
            episode's task prompt names, ordered by role).
        backend_name, weights: the segmenter (see :func:`cnfmp.segmenter.api.backend`).
        masks_dir: folder of hand-made label maps ``episode_<index>.png``.
        task: the task name recorded for the models (None: the dataset folder's name).

    Returns JSON ``{"out", "episodes", "annotated", "hand_made", "skipped": [{"episode",
    "prompt", "missing": [{"phrase", "score"}]}], "camera", "contact_sheet", "resumed"}``.
    """
    import cv2
    from lerobot.datasets.dataset_tools import add_features, delete_episodes

    from cnfmp.data.generate import progress_bar
    from cnfmp.data.lerobot_io import first_frame, open_dataset
    from cnfmp.segmenter.api import backend

    dataset_dir, out_dir = os.fspath(dataset_dir), os.fspath(out_dir)
    masks_dir = None if masks_dir is None else os.fspath(masks_dir)
    weights = None if weights is None else os.fspath(weights)
    if os.path.exists(out_dir):
        raise InputError(f"{out_dir} already exists; datasets are never overwritten, choose a new --out")
    if masks_dir is not None and not os.path.isdir(masks_dir):
        raise InputError(f"--masks-dir {masks_dir} is not a directory")
    objects = [o.strip() for o in objects or [] if o.strip()] or None
    dataset = open_dataset(dataset_dir)
    features = dataset.meta.features
    if "annotation.masks" in features:
        raise InputError(f"{dataset_dir} already has coarse masks (annotation.masks); it trains as it is")
    present = sorted(name for name in ANNOTATION_FEATURES if name in features)
    if present:
        raise InputError(f"{dataset_dir} already has {', '.join(present)} but no masks; remove them "
                         "(lerobot's dataset_tools.remove_feature) before annotating")
    camera = choose_camera(features, camera, None)
    if objects is None:
        prompts = [str(t) for t in dataset.meta.tasks.index]
        if not any(p.strip() for p in prompts):
            raise InputError(f"{dataset_dir}: the episodes have no task prompt to find the objects from; "
                             "name them with --objects, e.g. --objects \"red cube, paper\"")
    task = task or re.sub(r"[^A-Za-z0-9_.-]+", "_", os.path.basename(os.path.abspath(dataset_dir))).strip("_") or "task"
    staging = out_dir.rstrip("/") + ".staging"  # made when the first result is kept
    command = {"dataset": os.path.abspath(dataset_dir), "camera": camera, "objects": objects,
               "backend": backend_name, "weights": weights, "masks_dir": masks_dir}
    _check_staging(staging, command)
    segmenter = None
    starts = dataset.meta.episodes["dataset_from_index"]
    results, thumbs, resumed = {}, [], 0
    bar = progress_bar(len(starts), "annotating", progress)
    for episode in range(len(starts)):
        cached = os.path.join(staging, f"episode_{episode}.npz")
        first, image = first_frame(dataset, episode, camera)
        prompt = str(first["task"])
        if not objects and not prompt.strip():
            raise InputError(f"episode {episode} has no task prompt; name the objects with --objects")
        hand = os.path.join(masks_dir, f"episode_{episode}.png") if masks_dir else None
        if os.path.exists(cached):
            with np.load(cached) as saved:
                result = json.loads(str(saved["meta"]))
                result["labels"] = saved["labels"]
            resumed += 1
        else:
            if hand is not None and os.path.exists(hand):
                result = _hand_made(hand, image.shape[:2], objects, prompt)
            else:
                segmenter = segmenter or backend(backend_name, weights)
                result = annotate_image(image, prompt, objects, segmenter)
            meta = {k: v for k, v in result.items() if k != "labels"}
            if not os.path.isdir(staging):
                os.makedirs(staging)
                with open(os.path.join(staging, "command.json"), "w") as handle:
                    json.dump(command, handle)
            np.savez(cached + ".tmp.npz", labels=result["labels"], meta=json.dumps(meta))
            os.replace(cached + ".tmp.npz", cached)
        result["prompt"] = prompt
        results[episode] = result
        ok = not result["missing"]
        caption = f"{episode}: " + (", ".join(result["objects"]) if ok else
                                    "NOT FOUND " + ", ".join(m["phrase"] for m in result["missing"]))
        thumbs.append((image, result["labels"], caption, ok))
        bar.update(1)
    bar.close()

    kept = [e for e, r in results.items() if not r["missing"]]
    skipped = [{"episode": e, "prompt": r["prompt"], "missing": r["missing"]} for e, r in results.items() if r["missing"]]
    if not kept:
        raise InputError(f"no episode could be annotated: {json.dumps(skipped[:3])}; give hand-made label maps "
                         "with --masks-dir, or name the objects with --objects")
    partial = out_dir.rstrip("/") + ".partial"
    shutil.rmtree(partial, ignore_errors=True)
    shutil.rmtree(partial + "-kept", ignore_errors=True)
    source = dataset
    if skipped:
        source = delete_episodes(dataset, [s["episode"] for s in skipped], output_dir=partial + "-kept",
                                 repo_id="cnfmp/annotating")
    height, width = thumbs[0][1].shape

    def scene(ep: int) -> str:
        r = results[kept[int(ep)]]
        return json.dumps({"task": task, "camera": camera, "roles": r["roles"]})

    add_features(source, {
        "annotation.masks": (lambda row, ep, frame: results[kept[int(ep)]]["labels"],
                             {"dtype": "uint8", "shape": (height, width), "names": ["height", "width"]}),
        "annotation.objects": (lambda row, ep, frame: json.dumps(results[kept[int(ep)]]["objects"]),
                               {"dtype": "string", "shape": (1,), "names": None}),
        "annotation.scene": (lambda row, ep, frame: scene(ep), {"dtype": "string", "shape": (1,), "names": None}),
    }, output_dir=partial, repo_id=f"cnfmp/{task}")
    shutil.rmtree(partial + "-kept", ignore_errors=True)
    report = {"out": out_dir, "episodes": len(starts), "annotated": len(kept),
              "hand_made": sum(1 for e in kept if results[e].get("hand_made")), "skipped": skipped,
              "camera": camera, "task": task, "resumed": resumed,
              "contact_sheet": os.path.join(out_dir, ANNOTATION_DIR, "contact_sheet.png")}
    os.makedirs(os.path.join(partial, ANNOTATION_DIR))
    sheet = _contact_sheet(thumbs)
    cv2.imwrite(os.path.join(partial, ANNOTATION_DIR, "contact_sheet.png"), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
    with open(os.path.join(partial, ANNOTATION_DIR, "report.json"), "w") as handle:
        json.dump(report, handle, indent=2)
    os.rename(partial, out_dir)
    shutil.rmtree(staging, ignore_errors=True)
    return json.dumps(report)
