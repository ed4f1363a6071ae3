"""CLIPSeg segmenter backend: phrases -> per-pixel probabilities with transformers' CLIPSeg.

Weights come from a local directory laid out like a downloaded CIDAS/clipseg-rd64-refined
(config.json, model.safetensors or pytorch_model.bin, preprocessor_config.json, tokenizer
files). The CLIP vision encoder runs once per image; its extracted activations are shared by
all phrases, so each extra phrase costs one text encoding and one light decoder pass.

Also holds the local-directory loading helpers the other transformers backends use: every
problem with a weights directory becomes an :class:`InputError` naming the directory.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from cnfmp.errors import InputError
from cnfmp.segmenter.base import Backend, check_image
from cnfmp.segmenter.postprocess import PostprocessConfig

#: Weight files transformers can load, safest first.
_SAFE_WEIGHTS = ("model.safetensors", "model.safetensors.index.json")
_PICKLE_WEIGHTS = ("pytorch_model.bin", "pytorch_model.bin.index.json")


def check_config(directory: Path, model_type: str, what: str) -> None:
    """Raise an InputError unless `directory` holds a readable config.json for `model_type`."""
    directory = Path(directory)
    if not directory.is_dir():
        raise InputError(f"{what} weights directory {directory} does not exist")
    path = directory / "config.json"
    if not path.is_file():
        raise InputError(f"{what} weights directory {directory} has no config.json")
    try:
        config = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path} is not a valid JSON config: {exc}") from exc
    if not isinstance(config, dict):
        raise InputError(f"{path} is not a valid config: expected a JSON object")
    found = config.get("model_type")
    if found != model_type:
        raise InputError(f"{path} describes a {found!r} model, not {what} (model_type {model_type!r})")


def load_local_model(model_class, directory: Path, model_type: str, what: str) -> torch.nn.Module:
    """`model_class` from `directory` without touching the hub, in eval mode; safetensors
    preferred over pickled weights. A missing file, a failed load or a checkpoint that lacks
    some of the model's weights (they would silently stay random) is an InputError."""
    directory = Path(directory)
    check_config(directory, model_type, what)
    if any((directory / name).is_file() for name in _SAFE_WEIGHTS):
        use_safetensors = True
    elif any((directory / name).is_file() for name in _PICKLE_WEIGHTS):
        use_safetensors = False
    else:
        raise InputError(f"{what} weights directory {directory} has no model.safetensors or pytorch_model.bin")
    from transformers.utils import logging as hf_logging

    # transformers logs mismatched checkpoints at length; the InputError below says it once.
    verbosity = hf_logging.get_verbosity()
    hf_logging.set_verbosity_error()
    try:
        model, info = model_class.from_pretrained(
            directory, local_files_only=True, use_safetensors=use_safetensors, output_loading_info=True
        )
    except Exception as exc:  # any failure here means the directory's files are unusable
        raise InputError(f"could not load {what} weights from {directory}: {type(exc).__name__}: {exc}") from exc
    finally:
        hf_logging.set_verbosity(verbosity)
    missing = info.get("missing_keys") or []
    if missing:
        shown = ", ".join(sorted(missing)[:3])
        raise InputError(
            f"{what} weights in {directory} lack {len(missing)} of the model's tensors ({shown}, ...); "
            f"is this a {model_type} checkpoint?"
        )
    return model.eval()


def load_local_processor(processor_class, directory: Path, what: str):
    """`processor_class` (image processor + tokenizer) from `directory`, offline; an InputError
    when its preprocessor or tokenizer files are missing or unreadable."""
    try:
        # The slow processors are the reference preprocessing the checkpoints were published with.
        return processor_class.from_pretrained(directory, local_files_only=True, use_fast=False)
    except Exception as exc:  # missing/garbled preprocessor_config.json or tokenizer files
        raise InputError(
            f"could not load the {what} processor (preprocessor_config.json and tokenizer files) "
            f"from {directory}: {type(exc).__name__}: {exc}"
        ) from exc


def pick_device(device: str | torch.device | None) -> torch.device:
    """`device`, or the GPU when one is present (the models cost seconds per prompt on a CPU)."""
    if device is not None:
        return torch.device(device)
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


class ClipSegBackend(Backend):
    """CLIPSeg (CIDAS/clipseg-rd64-refined layout) loaded from a local directory."""

    name = "clipseg"
    open_vocabulary = True
    grounds_categories = True
    # CLIPSeg's sigmoid outputs are soft: a clearly visible object peaks around 0.5-0.9, so the
    # default 0.5/0.6 cut-offs would drop its edges and many true detections.
    postprocess = PostprocessConfig(threshold=0.4, min_score=0.5)

    def __init__(self, weights_dir: Path, device: str | torch.device | None = None):
        from transformers import CLIPSegForImageSegmentation, CLIPSegProcessor

        self.weights_dir = Path(weights_dir)
        self.device = pick_device(device)
        self.model = load_local_model(CLIPSegForImageSegmentation, self.weights_dir, "clipseg", "CLIPSeg").to(self.device)
        self.processor = load_local_processor(CLIPSegProcessor, self.weights_dir, "CLIPSeg")
        # Longer phrases are truncated rather than overflowing the text position embeddings.
        self.max_text_tokens = int(self.model.config.text_config.max_position_embeddings)

    def describe(self) -> dict:
        return {"backend": self.name, "weights": str(self.weights_dir), "device": str(self.device)}

    def probabilities(self, image: np.ndarray, phrases: list[str]) -> np.ndarray:
        """(H, W, 3) uint8 RGB and P phrases -> (P, H, W) float32 in [0, 1]: sigmoid of the
        decoder's (P, S, S) logits (S = the processor's input side, 352 for rd64-refined),
        resized bilinearly back to H x W."""
        image = check_image(image)
        height, width = image.shape[:2]
        if not phrases:
            return np.zeros((0, height, width), np.float32)
        model, clip = self.model, self.model.clip
        pixels = self.processor.image_processor(images=image, return_tensors="pt")["pixel_values"].to(self.device)
        text = self.processor.tokenizer(
            list(phrases), padding=True, truncation=True, max_length=self.max_text_tokens, return_tensors="pt"
        ).to(self.device)
        with torch.inference_mode():
            # (1, 3, S, S) -> hidden states, each (1, 1 + tokens, hidden); the decoder reads the
            # layers in extract_layers (+1: index 0 is the patch embedding).
            vision = clip.vision_model(pixel_values=pixels, output_hidden_states=True, interpolate_pos_encoding=True)
            activations = [vision.hidden_states[i + 1].expand(len(phrases), -1, -1) for i in model.extract_layers]
            # (P, projection_dim) phrase embeddings that FiLM-condition the decoder.
            conditional = clip.get_text_features(input_ids=text["input_ids"], attention_mask=text["attention_mask"])
            logits = model.decoder(activations, conditional).logits  # (P, S, S), or (S, S) squeezed when P == 1
            logits = logits.reshape(len(phrases), 1, *logits.shape[-2:]).float()
            probabilities = F.interpolate(logits.sigmoid(), size=(height, width), mode="bilinear", align_corners=False)
            return probabilities[:, 0].clamp(0.0, 1.0).cpu().numpy()


__all__ = ["ClipSegBackend", "check_config", "load_local_model", "load_local_processor", "pick_device"]
