"""Prompt -> ordered object phrases with roles, grounded in the vocabulary of
``prompts/vocabulary.json``.

"put the red ball in the box" -> [red ball (target), box (destination)]. A phrase is a noun of
the vocabulary (longest match first, so "sheet of paper" beats "paper") with an optional
colour before it ("red", "red-coloured") or after it ("the cup that is red"). Roles:

- ``destination``: the phrase follows a destination word ("in", "onto", "to", ...), or,
  when none does, it is the first place named ("reach the goal marker"),
- ``obstacle``: a fixture (a wall),
- ``target``: the first other movable thing,
- ``object``: anything else (a second thing to move in a stacking prompt).

A thing named twice ("the red cup in the blue cup, then the green cup in the red cup") keeps
its first mention. Backends ground a phrase's canonical wording (:func:`canonical`), so the
vocabulary's synonyms resolve here, not in a network. The vocabulary also says which synonyms and templates are held out of
segmenter training (``phrasings``), so evaluation can measure unseen paraphrases.
"""

from __future__ import annotations

import functools
import json
import re
from dataclasses import asdict, dataclass, replace

from cnfmp.errors import InputError
from cnfmp.prompts import prompts_dir

#: Longest prompt accepted (characters).
MAX_PROMPT_CHARS = 1000
#: Words skipped between a destination word and the phrase ("in the red box").
_DETERMINERS = {"the", "a", "an", "that", "this", "its"}
_COLOUR_SUFFIXES = ("-coloured", "-colored")
_WORD = re.compile(r"[a-z]+(?:-[a-z]+)*")


@dataclass(frozen=True)
class Phrase:
    """One object named by a prompt.

    Attributes:
        text: the phrase as the prompt words it ("crimson ball"), what backends ground.
        role: target | destination | obstacle | object | unknown.
        category: the vocabulary category ("ball"), None when ungrounded.
        colour: the canonical colour ("red"), None when the phrase names none.
        span: [start, end) character offsets in the prompt.
    """

    text: str
    role: str
    category: str | None
    colour: str | None
    span: tuple[int, int]

    def to_dict(self) -> dict:
        return asdict(self)


@functools.cache
def vocabulary() -> dict:
    """The parsed ``prompts/vocabulary.json``."""
    path = prompts_dir() / "vocabulary.json"
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise RuntimeError(f"vocabulary {path} is missing; set CNFMP_PROMPTS_DIR to the repository's prompts/") from None


@functools.cache
def _lexicon() -> tuple[list[tuple[tuple[str, ...], str]], dict[str, str], list[tuple[str, ...]]]:
    """(noun word tuples -> category, longest first), colour word -> colour, destination word tuples."""
    vocab = vocabulary()
    nouns = [(tuple(noun.split()), category) for category, entry in vocab["categories"].items()
             for noun in entry["train"] + entry["paraphrase"]]
    nouns.sort(key=lambda item: -len(item[0]))
    colours = {word: colour for colour, entry in vocab["colours"].items() for word in entry["train"] + entry["paraphrase"]}
    destinations = sorted((tuple(w.split()) for w in vocab["destination_words"]), key=len, reverse=True)
    return nouns, colours, destinations


def _colour_of(word: str, colours: dict[str, str]) -> str | None:
    for suffix in _COLOUR_SUFFIXES:
        if word.endswith(suffix):
            word = word[: -len(suffix)]
    return colours.get(word)


def check_prompt(prompt: str) -> str:
    """The prompt stripped; InputError when it is empty or too long."""
    if not isinstance(prompt, str) or not prompt.strip():
        raise InputError("the prompt is empty; name the objects, e.g. \"put the red ball in the box\"")
    if len(prompt) > MAX_PROMPT_CHARS:
        raise InputError(f"the prompt has {len(prompt)} characters; at most {MAX_PROMPT_CHARS} are accepted")
    return prompt.strip()


def parse(prompt: str) -> list[Phrase]:
    """The object phrases of `prompt`, in order of first mention, with their roles.

    Returns an empty list when the prompt names nothing in the vocabulary (the caller decides
    whether to ground the raw prompt instead). Raises InputError for an empty or overlong prompt.
    """
    prompt = check_prompt(prompt)
    nouns, colours, destinations = _lexicon()
    vocab = vocabulary()
    matches = list(_WORD.finditer(prompt.lower()))
    words = [m.group() for m in matches]
    phrases: list[Phrase] = []
    seen: set[tuple[str, str | None]] = set()
    has_target = False
    i = 0
    while i < len(words):
        hit = next(((n, c) for n, c in nouns if tuple(words[i:i + len(n)]) == n), None)
        if hit is None:
            i += 1
            continue
        noun, category = hit
        start, end = i, i + len(noun)
        colour = _colour_of(words[i - 1], colours) if i > 0 else None
        if colour is not None:
            start = i - 1
        elif words[end:end + 2] in (["that", "is"], ["which", "is"]) and end + 2 < len(words):
            colour = _colour_of(words[end + 2], colours)
            if colour is not None:
                end += 3
        before = start
        while before > 0 and words[before - 1] in _DETERMINERS:
            before -= 1
        is_destination = any(tuple(words[max(0, before - len(d)):before]) == d for d in destinations)
        kind = vocab["categories"][category]["kind"]
        if is_destination:
            role = "destination"
        elif kind == "fixture":
            role = "obstacle"
        elif kind == "movable" and not has_target:
            role, has_target = "target", True
        else:
            role = "object"
        key = (category, colour)
        if key not in seen:
            seen.add(key)
            span = (matches[start].start(), matches[end - 1].end())
            phrases.append(Phrase(prompt[span[0]:span[1]], role, category, colour, span))
        i = end
    if not any(p.role == "destination" for p in phrases):
        # A place named without a destination word ("reach the goal marker") is still where
        # the motion ends.
        place = next((k for k, p in enumerate(phrases)
                      if p.role == "object" and vocab["categories"][p.category]["kind"] == "place"), None)
        if place is not None:
            phrases[place] = replace(phrases[place], role="destination")
    return phrases


def canonical(phrase: Phrase) -> str:
    """The text a backend grounds for `phrase`: for a phrase the vocabulary grounds, its
    canonical wording ("cobalt glass" -> "blue cup": the colour's name and the category's
    first noun), so synonyms the vocabulary knows cost the backend nothing; anything else
    as written, left to the backend's text encoder."""
    if phrase.category is None:
        return phrase.text
    return canonical_text(phrase.category, phrase.colour)


def canonical_text(category: str, colour: str | None) -> str:
    """The canonical wording of (category, colour): "blue cup", or "cup" without a colour."""
    noun = vocabulary()["categories"][category]["train"][0]
    return f"{colour} {noun}" if colour else noun


def canonical_texts() -> list[str]:
    """Every canonical wording the vocabulary can produce: what a closed-vocabulary backend
    is ever asked to ground (each category alone and in each colour)."""
    vocab = vocabulary()
    return [canonical_text(category, colour) for category in vocab["categories"] for colour in [None, *vocab["colours"]]]


def phrasings(category: str, colour: str | None, split: str) -> list[str]:
    """Every way the vocabulary words (category, colour) in `split` ("train" or "paraphrase"):
    a paraphrase uses a held-out synonym or a held-out template."""
    vocab = vocabulary()
    nouns = vocab["categories"][category]
    if colour is None:
        templates = vocab["uncoloured_templates"]
        if split == "train":
            return [t.format(noun=n) for t in templates["train"] for n in nouns["train"]]
        return ([t.format(noun=n) for t in templates["paraphrase"] for n in nouns["train"] + nouns["paraphrase"]]
                + [t.format(noun=n) for t in templates["train"] for n in nouns["paraphrase"]])
    colour_words = vocab["colours"][colour]
    templates = vocab["templates"]
    if split == "train":
        return [t.format(colour=c, noun=n) for t in templates["train"] for c in colour_words["train"] for n in nouns["train"]]
    all_colours = colour_words["train"] + colour_words["paraphrase"]
    all_nouns = nouns["train"] + nouns["paraphrase"]
    return sorted({t.format(colour=c, noun=n) for t in templates["train"] + templates["paraphrase"]
                   for c in all_colours for n in all_nouns}
                  - set(phrasings(category, colour, "train")))


def unknown_phrasings(split: str) -> list[str]:
    """Phrases naming things that never appear in our scenes (``unknown_things`` of the
    vocabulary), in `split`: "the dog", "a red dog", ..."""
    vocab = vocabulary()
    colours = [entry["train"][0] for entry in vocab["colours"].values()]
    return [phrase for thing in vocab["unknown_things"][split]
            for phrase in (f"the {thing}", f"a {thing}", *(f"the {c} {thing}" for c in colours))]


def ground_name(name: str) -> tuple[str, str | None]:
    """(category, colour) of a simulator object name ("red ball", "wall", "green mug")."""
    found = parse(name)
    if not found:
        raise ValueError(f"object name {name!r} is not in prompts/vocabulary.json")
    return found[0].category, found[0].colour


__all__ = ["MAX_PROMPT_CHARS", "Phrase", "canonical", "check_prompt", "ground_name", "parse", "phrasings", "unknown_phrasings",
           "vocabulary"]
