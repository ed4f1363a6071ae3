"""Language-conditioned segmentation: a prompt and a scene image -> one coarse mask per object
the prompt names, with its role, score, bounding box and centroid.

    from cnfmp.segmenter import segment
    result = segment(image, "put the red ball in the box")   # image: (H, W, 3) uint8 RGB
    result.labels            # (H, W) uint8: 0 background, k the k-th phrase
    [p.role for p in result.phrases]   # ["target", "destination"]

The prompt is parsed into phrases (:mod:`.phrases`), a backend (:mod:`.backends`) grounds each
phrase's canonical wording (synonyms resolved by the vocabulary: "cobalt glass" -> "blue
cup") as a probability map, and the shared OpenCV chain (:mod:`.postprocess`) extracts the
masks. A prompt naming nothing in the vocabulary is grounded as a whole by open-vocabulary
backends (clipseg, owlv2-sam) and reported as not found by the others; whatever cannot be
found is reported as such, with its (low) score.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from cnfmp.errors import NotGrounded
from cnfmp.segmenter import phrases as _phrases
from cnfmp.segmenter.backends import load_backend
from cnfmp.segmenter.base import Backend, check_image
from cnfmp.segmenter.postprocess import ObjectMask, extract, label_map

@dataclass
class Segmentation:
    """What :func:`segment` found. ``phrases[k]`` owns ``results[k]`` and label k+1 of
    ``labels``; ``probabilities`` is (P, H, W) float32; ``timings_ms`` per stage."""

    prompt: str
    backend: str
    phrases: list[_phrases.Phrase]
    results: list[ObjectMask]
    probabilities: np.ndarray
    labels: np.ndarray
    timings_ms: dict[str, float] = field(default_factory=dict)

    def objects(self) -> list[dict]:
        """Per phrase: phrase, role, category, colour (None when the vocabulary does not know
        the phrase), found, score, area (px), bbox [x0, y0, x1, y1) and centroid [x, y] (px),
        label."""
        return [{"phrase": p.text, "role": p.role, "category": p.category, "colour": p.colour,
                 "found": r.found, "score": round(r.score, 4), "area": r.area, "bbox": r.bbox,
                 "centroid": None if r.centroid is None else [round(v, 2) for v in r.centroid],
                 "label": k + 1}
                for k, (p, r) in enumerate(zip(self.phrases, self.results))]

    def to_dict(self) -> dict:
        found = sum(r.found for r in self.results)
        return {"prompt": self.prompt, "backend": self.backend, "image_size": list(self.labels.shape),
                "found": found, "nothing_found": found == 0, "objects": self.objects(),
                "timings_ms": {k: round(v, 3) for k, v in self.timings_ms.items()}}


def segment(image: np.ndarray, prompt: str, backend: Backend | str = "auto") -> Segmentation:
    """Masks for the objects `prompt` names in `image` ((H, W, 3) uint8 RGB).

    Raises InputError for an empty or overlong prompt or a malformed image; an image where
    nothing matches (a black frame, "the unicorn") is a result with ``found == 0``.
    """
    started = time.perf_counter()
    image = check_image(image)
    prompt = _phrases.check_prompt(prompt)
    found = _phrases.parse(prompt)
    if not found:  # nothing from the vocabulary: the prompt as a whole is the one phrase
        found = [_phrases.Phrase(prompt, "unknown", None, None, (0, len(prompt)))]
    backend = load_backend(backend) if isinstance(backend, str) else backend
    parsed = time.perf_counter()
    # A closed-vocabulary backend is not asked about what the vocabulary cannot ground: its
    # answer would be a guess. Such a phrase gets an all-zero map, i.e. "not found".
    asked = [k for k, p in enumerate(found) if p.category is not None or backend.open_vocabulary]
    probabilities = np.zeros((len(found), *image.shape[:2]), np.float32)
    if asked:
        probabilities[asked] = backend.probabilities(image, [_phrases.canonical(found[k]) for k in asked])
    grounded = time.perf_counter()
    results = [extract(p, backend.postprocess) for p in probabilities]
    arbitrated = time.perf_counter()
    results = arbitrate(image, backend, found, probabilities, results)
    arbitrated = time.perf_counter() - arbitrated
    labels = label_map(probabilities, results)
    done = time.perf_counter()
    timings = {"parse": 1e3 * (parsed - started), "ground": 1e3 * (grounded - parsed),
               "postprocess": 1e3 * (done - grounded - arbitrated), "arbitrate": 1e3 * arbitrated,
               "total": 1e3 * (done - started)}
    return Segmentation(prompt, backend.name, found, results, probabilities, labels, timings)


def arbitrate(image: np.ndarray, backend: Backend, found: list[_phrases.Phrase | None], probabilities: np.ndarray,
              results: list[ObjectMask]) -> list[ObjectMask]:
    """`results` with each ambiguous coloured phrase decided by its category.

    "orange cube" on a scene holding an orange cube and an orange can: a network asked about
    a (colour, category) combination it never saw tends to light up both. Where the map of a
    phrase with a colour and a category (``found[k]``; None: not to arbitrate) leaves several
    candidate components, a backend that grounds categories is asked about the category
    alone ("cube"), once per category, and the candidate that is also of the category wins
    (:func:`cnfmp.segmenter.postprocess.extract` with a support map). ``probabilities`` is
    (P, H, W), one map per phrase.
    """
    ambiguous = [k for k, (p, r) in enumerate(zip(found, results))
                 if r.candidates > 1 and p is not None and p.colour is not None and p.category is not None]
    if not ambiguous or not backend.grounds_categories:
        return results
    categories = sorted({found[k].category for k in ambiguous})
    category_maps = dict(zip(categories, backend.probabilities(
        image, [_phrases.canonical_text(c, None) for c in categories])))
    results = list(results)
    for k in ambiguous:
        results[k] = extract(probabilities[k], backend.postprocess, support=category_maps[found[k].category])
    return results


def task_roles(task: str) -> list[str]:
    """The prompt roles that fill a `task` model's object slots, in slot order
    (``task_roles`` in prompts/vocabulary.json); NotGrounded when prompts cannot drive it."""
    roles = _phrases.vocabulary()["task_roles"].get(task)
    if roles is None:
        known = ", ".join(sorted(_phrases.vocabulary()["task_roles"]))
        raise NotGrounded(f"prompts cannot yet be mapped onto {task} models (roles are known for {known}); "
                          "pass coarse masks instead")
    return list(roles)


def order_by_roles(segmentation: Segmentation, roles: list[str]) -> list[int]:
    """For a model whose object slots take the prompt roles `roles` in order (a task's
    ``task_roles`` in prompts/vocabulary.json, or the roles recorded by `cnfmp dataset
    annotate`), the phrase index that fills each slot: slot k takes the first phrase whose
    role is the k-th role.

    Raises NotGrounded when the prompt lacks one of the roles, or when a needed object was
    not found in the image.
    """
    order = []
    for role in roles:
        index = next((k for k, p in enumerate(segmentation.phrases) if p.role == role), None)
        if index is None:
            named = ", ".join(f"{p.text!r} ({p.role})" for p in segmentation.phrases)
            raise NotGrounded(f"the model needs a {role} in the prompt ({' and '.join(roles)}); "
                             f"the prompt names {named}")
        if not segmentation.results[index].found:
            raise NotGrounded(f"the {role} {segmentation.phrases[index].text!r} was not found in the image "
                             f"(best score {segmentation.results[index].score:.2f})")
        order.append(index)
    return order


__all__ = ["Segmentation", "arbitrate", "check_image", "order_by_roles", "segment", "task_roles"]
