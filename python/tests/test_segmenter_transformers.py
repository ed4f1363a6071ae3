"""The transformers segmenter backends (CLIPSeg, OWLv2 + SAM) on tiny random-initialised
checkpoints saved to disk and loaded through the production loader: output contract, one
image encoding per image, agreement with the models' own forward passes, and InputErrors for
broken weights directories."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import torch
from transformers import (
    CLIPSegConfig,
    CLIPSegForImageSegmentation,
    CLIPSegProcessor,
    CLIPTokenizer,
    Owlv2Config,
    Owlv2ForObjectDetection,
    Owlv2ImageProcessor,
    Owlv2Processor,
    SamConfig,
    SamImageProcessor,
    SamModel,
    SamProcessor,
    ViTImageProcessor,
)
from transformers.models.clip.tokenization_clip import bytes_to_unicode

from cnfmp.errors import InputError
from cnfmp.segmenter.backends import load_backend

PHRASES = ["red cup", "blue cube"]
TEXT = dict(vocab_size=514, hidden_size=32, intermediate_size=64, num_hidden_layers=2, num_attention_heads=2,
            max_position_embeddings=16, bos_token_id=512, eos_token_id=513, pad_token_id=0)
VISION = dict(hidden_size=32, intermediate_size=64, num_hidden_layers=2, num_attention_heads=2, image_size=32,
              patch_size=8)


@pytest.fixture(scope="module")
def tokenizer(tmp_path_factory):
    """A byte-level CLIP tokenizer without merges: the 256 byte symbols, their end-of-word
    forms and the two specials (ids 512, 513), laid out like CLIP's own vocab."""
    directory = tmp_path_factory.mktemp("tokenizer")
    symbols = list(bytes_to_unicode().values())
    vocab = {s: i for i, s in enumerate(symbols)} | {s + "</w>": i + 256 for i, s in enumerate(symbols)}
    vocab |= {"<|startoftext|>": 512, "<|endoftext|>": 513}
    (directory / "vocab.json").write_text(json.dumps(vocab))
    (directory / "merges.txt").write_text("#version: 0.2\n")
    return CLIPTokenizer(str(directory / "vocab.json"), str(directory / "merges.txt"), pad_token="!", model_max_length=16)


@pytest.fixture(scope="module")
def clipseg_dir(tmp_path_factory, tokenizer):
    directory = tmp_path_factory.mktemp("clipseg")
    torch.manual_seed(0)
    config = CLIPSegConfig(text_config=TEXT, vision_config=VISION, projection_dim=16, extract_layers=[0, 1],
                           reduce_dim=16, decoder_num_attention_heads=2, decoder_intermediate_size=32)
    CLIPSegForImageSegmentation(config).save_pretrained(directory)
    image_processor = ViTImageProcessor(size={"height": 32, "width": 32})
    CLIPSegProcessor(image_processor=image_processor, tokenizer=tokenizer).save_pretrained(directory)
    return directory


@pytest.fixture(scope="module")
def owlv2_sam_dir(tmp_path_factory, tokenizer):
    root = tmp_path_factory.mktemp("owlv2-sam")
    torch.manual_seed(0)
    # OWLv2's class head compares projected text embeddings in the text hidden size.
    detector = Owlv2ForObjectDetection(Owlv2Config(text_config=TEXT, vision_config=VISION, projection_dim=32))
    # Random logit shifts and scales saturate every score at 1; a constant scale of 3 keeps the
    # scores (3 x cosine similarity) phrase-dependent, so phrases pick different boxes. A zero
    # box head leaves each patch's prior box (the patch itself) instead of degenerate boxes.
    with torch.no_grad():
        for layer, bias in ((detector.class_head.logit_shift, 0.0), (detector.class_head.logit_scale, 2.0),
                            (detector.box_head.dense2, 0.0)):
            layer.weight.zero_()
            layer.bias.fill_(bias)
    detector.save_pretrained(root / "owlv2")
    Owlv2Processor(image_processor=Owlv2ImageProcessor(size={"height": 32, "width": 32}),
                   tokenizer=tokenizer).save_pretrained(root / "owlv2")
    # 64 px input, 16 px patches -> a 4x4 embedding; num_pos_feats is half the prompt encoder's width.
    config = SamConfig(
        vision_config=dict(hidden_size=32, output_channels=16, num_hidden_layers=2, num_attention_heads=2,
                           image_size=64, patch_size=16, window_size=2, global_attn_indexes=[1], num_pos_feats=8,
                           mlp_dim=64),
        prompt_encoder_config=dict(hidden_size=16, image_size=64, patch_size=16),
        mask_decoder_config=dict(hidden_size=16, mlp_dim=32, num_hidden_layers=2, num_attention_heads=2,
                                 iou_head_hidden_dim=16),
    )
    sam = SamModel(config)
    # SAM's own initialisation leaves the mask logits ~0 whatever the prompt; noise makes them depend on it.
    with torch.no_grad():
        for parameter in sam.parameters():
            parameter.add_(torch.randn_like(parameter) * 0.3)
    sam.save_pretrained(root / "sam")
    SamProcessor(SamImageProcessor(size={"longest_edge": 64}, pad_size={"height": 64, "width": 64},
                                   mask_size={"longest_edge": 16},
                                   mask_pad_size={"height": 16, "width": 16})).save_pretrained(root / "sam")
    return root


@pytest.fixture(scope="module")
def image():
    """(48, 40, 3) uint8: non-square, so aspect-ratio handling is exercised."""
    return np.random.default_rng(0).integers(0, 256, (48, 40, 3), dtype=np.uint8)


def check_probabilities(probabilities, count, image):
    assert probabilities.shape == (count, *image.shape[:2])
    assert probabilities.dtype == np.float32
    assert np.isfinite(probabilities).all()
    assert ((probabilities >= 0.0) & (probabilities <= 1.0)).all()


def test_clipseg_contract_and_single_image_encoding(clipseg_dir, image):
    backend = load_backend("clipseg", clipseg_dir)
    assert backend.name == "clipseg" and backend.describe()["weights"] == str(clipseg_dir)
    calls = []
    hook = backend.model.clip.vision_model.register_forward_hook(lambda *_: calls.append(1))
    try:
        probabilities = backend.probabilities(image, PHRASES)
    finally:
        hook.remove()
    assert len(calls) == 1
    check_probabilities(probabilities, 2, image)
    assert np.abs(probabilities[0] - probabilities[1]).max() > 1e-4
    check_probabilities(backend.probabilities(image, PHRASES[:1]), 1, image)
    check_probabilities(backend.probabilities(image, []), 0, image)


def test_clipseg_matches_the_full_forward(clipseg_dir, image):
    """Sharing the image's activations across phrases changes nothing: the maps equal the
    model's own forward on the image repeated once per phrase."""
    backend = load_backend("clipseg", clipseg_dir)
    text = backend.processor.tokenizer(PHRASES, padding=True, return_tensors="pt")
    pixels = backend.processor.image_processor(images=[image] * len(PHRASES), return_tensors="pt")
    with torch.inference_mode():
        logits = backend.model(**text.to(backend.device), **pixels.to(backend.device)).logits
    expected = torch.nn.functional.interpolate(logits.sigmoid()[:, None], size=image.shape[:2], mode="bilinear")[:, 0]
    np.testing.assert_allclose(backend.probabilities(image, PHRASES), expected.cpu().numpy(), atol=1e-4)


def test_clipseg_loads_pickled_weights(tmp_path, clipseg_dir, image):
    """A checkpoint with only pytorch_model.bin (older downloads) loads and agrees."""
    reference = load_backend("clipseg", clipseg_dir)
    pickled = copy_dir(clipseg_dir, tmp_path / "pickled", skip={"model.safetensors"})
    torch.save(reference.model.state_dict(), pickled / "pytorch_model.bin")
    backend = load_backend("clipseg", pickled)
    np.testing.assert_allclose(backend.probabilities(image, PHRASES), reference.probabilities(image, PHRASES), atol=1e-6)


def test_owlv2_sam_contract_and_single_image_encodings(owlv2_sam_dir, image):
    backend = load_backend("owlv2-sam", owlv2_sam_dir)
    assert backend.name == "owlv2-sam"
    calls = {"owlv2": 0, "sam": 0}

    def counter(key):
        def hook(*_):
            calls[key] += 1
        return hook

    hooks = [backend.detector.owlv2.vision_model.register_forward_hook(counter("owlv2")),
             backend.sam.vision_encoder.register_forward_hook(counter("sam"))]
    try:
        probabilities = backend.probabilities(image, PHRASES)
    finally:
        for hook in hooks:
            hook.remove()
    assert calls == {"owlv2": 1, "sam": 1}
    check_probabilities(probabilities, 2, image)
    assert np.abs(probabilities[0] - probabilities[1]).max() > 1e-4
    # Each map is SAM's mask probability scaled by the phrase's box score.
    boxes, scores = backend.detect(image, PHRASES)
    masks = backend.segment_boxes(image, boxes)
    np.testing.assert_allclose(probabilities, masks * scores[:, None, None], atol=1e-6)
    check_probabilities(backend.probabilities(image, []), 0, image)


def test_owlv2_boxes_match_the_processors_post_processing(owlv2_sam_dir, image):
    backend = load_backend("owlv2-sam", owlv2_sam_dir)
    height, width = image.shape[:2]
    for phrase in PHRASES:
        boxes, scores = backend.detect(image, [phrase])
        inputs = backend.detector_processor(text=[phrase], images=image, return_tensors="pt")
        with torch.inference_mode():
            output = backend.detector(**inputs.to(backend.device))
        result = backend.detector_processor.image_processor.post_process_object_detection(
            output, threshold=0.0, target_sizes=[(height, width)])[0]
        best = int(result["scores"].argmax())
        assert scores[0] == pytest.approx(float(result["scores"][best]), abs=1e-6)
        expected = result["boxes"][best].numpy().clip(0, [width, height, width, height])
        np.testing.assert_allclose(boxes[0], expected, atol=1e-4)
        # One of the prior boxes of the 4 x 4 patches of the image padded to 48 x 48: patch-sized
        # (12 px) and centred on a patch's bottom-right corner.
        priors = np.array([[x - 6, y - 6, x + 6, y + 6] for y in (12, 24, 36, 48) for x in (12, 24, 36, 48)])
        priors = priors.clip(0, [width, height, width, height])
        assert np.abs(priors - boxes[0]).max(axis=1).min() < 1e-2


def test_sam_masks_follow_the_box(owlv2_sam_dir, image):
    backend = load_backend("owlv2-sam", owlv2_sam_dir)
    boxes = np.array([[0, 0, 20, 24], [20, 24, 40, 48]], np.float32)
    masks = backend.segment_boxes(image, boxes)
    check_probabilities(masks, 2, image)
    assert np.abs(masks[0] - masks[1]).max() > 1e-4
    # Same as SAM's own pipeline: processor-scaled boxes, full forward, upscaled best-IoU masks.
    inputs = backend.sam_processor(images=image, input_boxes=[boxes.tolist()], return_tensors="pt").to(backend.device)
    with torch.inference_mode():
        output = backend.sam(pixel_values=inputs["pixel_values"], input_boxes=inputs["input_boxes"])
    logits = backend.sam_processor.post_process_masks(output.pred_masks, inputs["original_sizes"],
                                                      inputs["reshaped_input_sizes"], binarize=False)[0]
    best = output.iou_scores[0].argmax(-1)
    expected = logits[torch.arange(2, device=best.device), best].sigmoid().cpu().numpy()
    np.testing.assert_allclose(masks, expected, atol=1e-4)


def test_missing_weights_directory(tmp_path):
    missing = tmp_path / "nowhere"
    with pytest.raises(InputError, match=re.escape(str(missing))):
        load_backend("clipseg", missing)
    with pytest.raises(InputError, match=re.escape(str(missing))):
        load_backend("owlv2-sam", missing)
    from cnfmp.segmenter.clipseg import ClipSegBackend

    with pytest.raises(InputError, match=f"{re.escape(str(missing))} does not exist"):
        ClipSegBackend(missing)


def test_owlv2_sam_root_without_sam(tmp_path, owlv2_sam_dir):
    (tmp_path / "owlv2").symlink_to(owlv2_sam_dir / "owlv2")
    with pytest.raises(InputError, match=re.escape(str(tmp_path / "sam"))):
        load_backend("owlv2-sam", tmp_path)


@pytest.mark.parametrize("config", [None, "{not json", "[]", json.dumps({"model_type": "sam"})])
def test_bad_config(tmp_path, config):
    if config is not None:
        (tmp_path / "config.json").write_text(config)
    with pytest.raises(InputError, match=re.escape(str(tmp_path))) as error:
        load_backend("clipseg", tmp_path)
    assert ("no config.json" if config is None else "config") in str(error.value)


def copy_dir(source, target, skip=()):
    target.mkdir()
    for path in source.iterdir():
        if path.name not in skip:
            (target / path.name).write_bytes(path.read_bytes())
    return target


def test_missing_or_corrupt_weights(tmp_path, clipseg_dir):
    no_weights = copy_dir(clipseg_dir, tmp_path / "no-weights", skip={"model.safetensors"})
    with pytest.raises(InputError, match=f"{re.escape(str(no_weights))} has no model.safetensors"):
        load_backend("clipseg", no_weights)
    corrupt = copy_dir(clipseg_dir, tmp_path / "corrupt", skip={"model.safetensors"})
    (corrupt / "model.safetensors").write_bytes(b"\x00" * 64)
    with pytest.raises(InputError, match=f"could not load CLIPSeg weights from {re.escape(str(corrupt))}"):
        load_backend("clipseg", corrupt)


def test_weights_of_another_architecture(tmp_path, clipseg_dir, owlv2_sam_dir):
    """An OWLv2 checkpoint under a CLIPSeg config would leave the decoder random: refused."""
    mixed = copy_dir(clipseg_dir, tmp_path / "mixed", skip={"model.safetensors"})
    (mixed / "model.safetensors").write_bytes((owlv2_sam_dir / "owlv2" / "model.safetensors").read_bytes())
    with pytest.raises(InputError, match=re.escape(str(mixed))):
        load_backend("clipseg", mixed)


def test_missing_processor_files(tmp_path, clipseg_dir):
    bare = copy_dir(clipseg_dir, tmp_path / "bare", skip={"preprocessor_config.json", "vocab.json", "merges.txt"})
    with pytest.raises(InputError, match=f"CLIPSeg processor.*{re.escape(str(bare))}"):
        load_backend("clipseg", bare)


def test_wrong_image(clipseg_dir):
    backend = load_backend("clipseg", clipseg_dir)
    with pytest.raises(InputError, match="uint8 RGB"):
        backend.probabilities(np.zeros((8, 8), np.uint8), PHRASES)
