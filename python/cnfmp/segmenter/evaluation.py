"""``cnfmp segmenter eval``: IoU of a backend's masks against the simulator's, on held-out
scenes, split three ways:

- ``seen``: objects of training (category, colour) combinations, named with training phrasings;
- ``paraphrase``: the same objects named with paraphrases never used in training (held-out
  synonyms and templates of prompts/vocabulary.json), grounded as :func:`segment` does: the
  parser resolves what the vocabulary knows and the backend sees the canonical wording;
- ``paraphrase_raw``: the same paraphrases handed to the backend as written, which measures
  what the backend's own text encoder generalises to;
- ``heldout_instance``: objects of (category, colour) combinations never shown in training
  (language_pick_place's held-out combinations), named with training phrasings.

Also reported: how often a phrase naming something absent from the scene
(``rejection_rate``) or something outside the vocabulary never used in training ("the
unicorn", ``unknown_rejection_rate``) is answered with "not found", and the grounding latency
per scene. Phrases whose maps are ambiguous are arbitrated by their category as
:func:`cnfmp.segmenter.segment` does (:func:`cnfmp.segmenter.arbitrate`).
"""

from __future__ import annotations

import time

import numpy as np

from cnfmp.errors import InputError
from cnfmp.segmenter import arbitrate, phrases as vocab
from cnfmp.segmenter.base import Backend
from cnfmp.segmenter.postprocess import extract
from cnfmp.segmenter.training_film import is_absent, render_scene, vocabulary_things

SPLITS = ("seen", "paraphrase", "paraphrase_raw", "heldout_instance")


def _is_heldout_instance(task: str, scene_params: dict, label: int) -> bool:
    if task != "language_pick_place":
        return False
    from cnfmp.sim.tasks.language_pick_place import MOVABLE_NOUNS, is_heldout_combination

    obj = scene_params["objects"][label - 1]
    return obj["category"] in MOVABLE_NOUNS and is_heldout_combination(obj["category"], obj["colour"])


def iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0


def evaluate(backend: Backend, task: str, episodes: int, seed_start: int, log=None) -> dict:
    """Evaluates `backend` on `episodes` held-out scenes of `task` from `seed_start`."""
    from cnfmp.seeds import HELDOUT_SEEDS
    from cnfmp.sim.tasks import get_task

    if seed_start not in HELDOUT_SEEDS or seed_start + episodes - 1 not in HELDOUT_SEEDS:
        raise InputError(f"evaluation scenes must be held-out: seeds {seed_start}..={seed_start + episodes - 1} "
                         f"are not all within {HELDOUT_SEEDS.start}..={HELDOUT_SEEDS.stop - 1}")
    task_obj = get_task(task)
    scores: dict[str, list[float]] = {s: [] for s in SPLITS}
    rejections, unknown_rejections, latencies, per_scene = [], [], [], []
    unknown = vocab.unknown_phrasings("paraphrase")
    started = time.monotonic()
    for index, seed in enumerate(range(seed_start, seed_start + episodes)):
        rng = np.random.default_rng(seed)
        image, labels, names = render_scene(task, seed)
        params = task_obj.scene(seed).params
        queries: list[tuple[str, int, str]] = []  # (split, label, phrase)
        for label, name in enumerate(names, start=1):
            if not (labels == label).any():
                continue  # hidden behind something: there is nothing to find
            thing = vocab.ground_name(name)
            train_options = vocab.phrasings(*thing, "train")
            if _is_heldout_instance(task, params, label):
                queries.append(("heldout_instance", label, train_options[rng.integers(len(train_options))]))
                continue
            paraphrases = vocab.phrasings(*thing, "paraphrase")
            paraphrase = paraphrases[rng.integers(len(paraphrases))]
            queries.append(("seen", label, train_options[rng.integers(len(train_options))]))
            queries.append(("paraphrase", label, paraphrase))
            queries.append(("paraphrase_raw", label, paraphrase))
        present = [vocab.ground_name(n) for n in names]
        absent = [t for t in vocabulary_things() if is_absent(t, present)]
        negative = absent[rng.integers(len(absent))]
        negative_options = vocab.phrasings(*negative, "train")
        phrase_list = [q[2] for q in queries] + [negative_options[rng.integers(len(negative_options))],
                                                 unknown[rng.integers(len(unknown))]]
        call = time.perf_counter()
        splits = [q[0] for q in queries] + ["absent", "unknown"]
        # Grounded as segment() grounds a one-phrase prompt (the parsed phrase's canonical
        # wording, ambiguous maps arbitrated), except the raw paraphrases, handed to the
        # backend as written to measure it alone.
        parsed = [None if split == "paraphrase_raw" else next(iter(vocab.parse(text)), None)
                  for split, text in zip(splits, phrase_list)]
        grounded = [text if phrase is None else vocab.canonical(phrase) for phrase, text in zip(parsed, phrase_list)]
        probabilities = backend.probabilities(image, grounded)
        results = [extract(p, backend.postprocess) for p in probabilities]
        results = arbitrate(image, backend, parsed, probabilities, results)
        latencies.append(1e3 * (time.perf_counter() - call))
        scene_scores = []
        for (split, label, phrase), result in zip(queries, results):
            value = iou(result.mask, labels == label)
            scores[split].append(value)
            scene_scores.append({"split": split, "object": names[label - 1], "phrase": phrase, "iou": round(value, 4),
                                 "found": result.found, "score": round(result.score, 4)})
        rejections.append(not results[-2].found)
        unknown_rejections.append(not results[-1].found)
        per_scene.append({"seed": seed, "objects": scene_scores,
                          "absent": {"phrase": phrase_list[-2], "rejected": rejections[-1]},
                          "unknown": {"phrase": phrase_list[-1], "rejected": unknown_rejections[-1]}})
        if log and ((index + 1) % 20 == 0 or index + 1 == episodes):
            means = ", ".join(f"{s} {np.mean(v):.3f}" for s, v in scores.items() if v)
            log(f"[{index + 1}/{episodes}] mean IoU: {means}; rejected: absent {np.mean(rejections):.2f}, "
                f"unknown {np.mean(unknown_rejections):.2f}")
    warm = latencies[1:] or latencies
    return {
        "task": task, "backend": backend.describe(), "episodes": episodes, "seed_start": seed_start,
        "mean_iou": {s: (float(np.mean(v)) if v else None) for s, v in scores.items()},
        "count": {s: len(v) for s, v in scores.items()},
        "rejection_rate": float(np.mean(rejections)),
        "unknown_rejection_rate": float(np.mean(unknown_rejections)),
        "latency_ms_p50": float(np.percentile(warm, 50)), "latency_ms_p95": float(np.percentile(warm, 95)),
        "phrases_per_scene": float(np.mean([len(s["objects"]) + 2 for s in per_scene])),
        "wall_time_s": round(time.monotonic() - started, 1), "per_scene": per_scene,
    }


__all__ = ["SPLITS", "evaluate", "iou"]
