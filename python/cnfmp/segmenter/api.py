"""Entry points of the segmenter for the Rust bridge (and notebooks): segment, train, evaluate.

Backends stay resident (keyed by name and weights directory), so a server pays for loading
once. Bad input raises :class:`cnfmp.errors.InputError`.
"""

from __future__ import annotations

import json
import os
import sys

import cv2
import numpy as np

from cnfmp import helper_processes, runtime
from cnfmp.errors import InputError
from cnfmp.images import decode_image, encode_png
from cnfmp.segmenter import Segmentation, order_by_roles, phrases, segment as segment_array, task_roles
from cnfmp.segmenter.backends import load_backend
from cnfmp.segmenter.base import Backend

_BACKENDS: dict[tuple[str, str | None], Backend] = {}
#: Overlay colours (RGB) per phrase, cycled (also annotation's contact sheet).
OVERLAY_COLOURS = [(230, 25, 75), (60, 180, 75), (0, 130, 200), (245, 130, 48), (145, 30, 180), (70, 240, 240)]
#: Overlays are drawn at least this large (px), so the labels are legible.
_OVERLAY_SIDE = 512


def backend(name: str = "auto", weights: str | None = None) -> Backend:
    """The resident backend `name` (weights from `weights` or its default location)."""
    key = (name, None if weights is None else os.path.abspath(os.fspath(weights)))
    if key not in _BACKENDS:
        loaded = load_backend(name, weights)
        # What `auto` resolved to is the same backend when asked for by name (a server asks
        # by the resolved name), whichever was asked for first: one instance, one warm cache.
        _BACKENDS[key] = _BACKENDS.setdefault((loaded.name, key[1]), loaded)
    return _BACKENDS[key]


def preload(name: str = "auto", weights: str | None = None) -> str:
    """Loads backend `name`, warms it for every canonical phrase of the vocabulary and runs
    it once on a blank image on every worker thread, so a server's first request pays
    neither for loading nor for first-call costs. Returns the backend's name."""
    loaded = backend(name, weights)
    loaded.warm(phrases.canonical_texts())
    blank = encode_png(np.full((128, 128, 3), 128, dtype=np.uint8))
    # The request path, once on every thread a batch's segmentations run on, and in every
    # helper process, which loads the backend for its share of a batch.
    request = dict(image_data=blank, prompt="put the red cube on the paper", backend_name=name, weights=weights,
                   pictures=False)
    runtime.on_every_worker(lambda: segment(**request))
    for helper in helper_processes.helpers():
        try:
            helper.submit(f"{__name__}:segment_or_error", request).result()
        except helper_processes.HelperError as err:
            print(f"cnfmp: {err}; its share of segmentation is done in this process", file=sys.stderr)
    return loaded.name


def draw_overlay(image: np.ndarray, segmentation: Segmentation) -> np.ndarray:
    """(H, W, 3) uint8 image with each found mask tinted, outlined and labelled, upscaled
    (nearest) to at least :data:`_OVERLAY_SIDE` px."""
    scale = max(1, round(_OVERLAY_SIDE / max(image.shape[:2])))
    big = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST).astype(np.float32)
    lines = []
    for k, (phrase, result) in enumerate(zip(segmentation.phrases, segmentation.results)):
        colour = OVERLAY_COLOURS[k % len(OVERLAY_COLOURS)]
        if not result.found:
            lines.append((f"{k + 1}: {phrase.text} - not found ({result.score:.2f})", colour))
            continue
        mask = cv2.resize(result.mask.astype(np.uint8), None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
        big[mask > 0] = 0.55 * big[mask > 0] + 0.45 * np.array(colour, np.float32)
        lines.append((f"{k + 1}: {phrase.text} ({phrase.role}, {result.score:.2f})", colour))
    big = big.round().astype(np.uint8)
    for k, result in enumerate(segmentation.results):
        if result.found:
            mask = cv2.resize(result.mask.astype(np.uint8), None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
            contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            cv2.drawContours(big, contours, -1, OVERLAY_COLOURS[k % len(OVERLAY_COLOURS)], 2)
    for row, (text, colour) in enumerate(lines):
        origin = (8, 22 + 22 * row)
        cv2.putText(big, text, origin, cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(big, text, origin, cv2.FONT_HERSHEY_SIMPLEX, 0.55, colour, 1, cv2.LINE_AA)
    return big


def segment(image_data: bytes, prompt: str, backend_name: str = "auto", weights: str | None = None,
            task: str | None = None, pictures: bool = True, roles: list[str] | None = None) -> dict:
    """Segments an encoded image for `prompt`.

    Args:
        roles: when given, the label map is ordered for a core model whose object slots take
            these prompt roles (label k = the phrase filling the model's k-th slot, see
            :func:`cnfmp.segmenter.order_by_roles`) and the JSON gains ``"slots"``.
        task: the same with the roles of that benchmark task (``task_roles`` in
            prompts/vocabulary.json), when `roles` is not given.
        pictures: when False, ``mask_pngs`` and ``overlay_png`` are left empty (a server
            answering with JSON does not pay for encoding them).

    Returns ``{"json": str (Segmentation.to_dict()), "labels_png": bytes (8-bit label map),
    "mask_pngs": [bytes] (one 0/255 mask per phrase), "overlay_png": bytes,
    "slot_names": [str] (phrases in slot order; all phrases when no task)}``.
    """
    if roles is None and task is not None:
        roles = task_roles(task)  # a task prompts cannot drive is refused before a backend loads
    image = decode_image(image_data)
    result = segment_array(image, prompt, backend(backend_name, weights))
    document = result.to_dict()
    if roles is None:
        order, labels = list(range(len(result.phrases))), result.labels
    else:
        order = order_by_roles(result, list(roles))
        labels = np.zeros_like(result.labels)
        for slot, index in enumerate(order, start=1):
            labels[result.labels == index + 1] = slot
        document["slots"] = [{"slot": slot, "label": index + 1, "role": result.phrases[index].role,
                              "phrase": result.phrases[index].text} for slot, index in enumerate(order, start=1)]
    return {
        "json": json.dumps(document),
        "labels_png": encode_png(labels),
        "mask_pngs": [encode_png((r.mask * 255).astype(np.uint8)) for r in result.results] if pictures else [],
        "overlay_png": encode_png(draw_overlay(image, result)) if pictures else b"",
        "slot_names": [result.phrases[i].text for i in order],
    }


def segment_batch(requests: list[dict]) -> list:
    """:func:`segment` for several requests at once (a server's batch): shared with the
    helper processes where they run (:func:`cnfmp.helper_processes.share`), else side by
    side on the worker pool (:func:`cnfmp.runtime.worker_pool`).

    Args:
        requests: one dict of :func:`segment`'s keyword arguments per image.

    Returns one entry per request, in order: what :func:`segment` returns, or the
    :class:`cnfmp.errors.InputError` that request raised (its bad input fails it alone).
    """
    helpers = helper_processes.helpers()
    if helpers and len(requests) > 1:
        return helper_processes.share(
            len(requests), lambda j: segment_or_error(requests[j]),
            lambda helper, j: helper.submit(f"{__name__}:segment_or_error", requests[j]).result())
    return list(runtime.worker_pool().map(segment_or_error, requests))


def segment_or_error(request: dict):
    """:func:`segment` of one request's keyword arguments, or the InputError it raised (a
    helper process's handler too)."""
    try:
        return segment(**request)
    except InputError as err:
        return err


def train(out_dir: str, config_path: str | None, steps: int | None, seed: int | None, scenes_scale: float | None,
          command: str) -> str:
    """See :func:`cnfmp.segmenter.training_film.train`; progress goes to stderr."""
    from cnfmp.segmenter import training_film

    return training_film.train(os.fspath(out_dir), None if config_path is None else os.fspath(config_path),
                               steps, seed, scenes_scale, command=command)


def evaluate(task: str, episodes: int, seed_start: int, backend_name: str = "auto", weights: str | None = None) -> str:
    """See :func:`cnfmp.segmenter.evaluation.evaluate`; progress goes to stderr. Returns JSON."""
    import sys

    from cnfmp.segmenter import evaluation
    from cnfmp.sim.tasks import get_task

    get_task(task)  # an unknown task is an InputError before anything loads
    report = evaluation.evaluate(backend(backend_name, weights), task, episodes, seed_start,
                                 log=lambda line: print(line, file=sys.stderr, flush=True))
    return json.dumps(report)


__all__ = ["backend", "draw_overlay", "evaluate", "segment", "train"]
