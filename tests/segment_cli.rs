//! End-to-end tests of `cnfmp segment` and `cnfmp predict --prompt` through the real binary,
//! with the shipped film segmenter: a rendered held-out scene is segmented from its own prompt
//! and matches the simulator's masks; many scenes are segmented in one process (`--scenes`); a
//! prompt drives a (tiny) core model; bad input exits 2.

use std::path::Path;
use std::process::Output;

use cnfmp::images::read_label_map;
use serde_json::Value;

mod common;
use common::{TINY_CONFIG, arg, cnfmp, stderr};

fn assert_bad_input(output: &Output, needle: &str) {
    assert_eq!(output.status.code(), Some(2), "{}", stderr(output));
    assert!(stderr(output).contains(needle), "expected {needle:?} in: {}", stderr(output));
}

fn render(task: &str, seed: u64, out: &Path) -> Value {
    let output = cnfmp(&["sim", "render", "--task", task, "--seed", &seed.to_string(), "--out", arg(out)]);
    assert!(output.status.success(), "{}", stderr(&output));
    serde_json::from_str(&std::fs::read_to_string(out.join("objects.json")).unwrap()).unwrap()
}

/// IoU of label `a` in map `x` and label `b` in map `y` (same size).
fn iou(x: &Path, a: u8, y: &Path, b: u8) -> f64 {
    let (x, y) = (read_label_map(x).unwrap(), read_label_map(y).unwrap());
    assert_eq!((x.width, x.height), (y.width, y.height));
    let (mut both, mut either) = (0usize, 0usize);
    for (p, q) in x.pixels.iter().zip(&y.pixels) {
        both += usize::from(*p == a && *q == b);
        either += usize::from(*p == a || *q == b);
    }
    both as f64 / either.max(1) as f64
}

#[test]
fn segment_a_held_out_scene_from_its_prompt() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    let info = render("language_pick_place", 1_000_010, &scene);
    let prompt = info["prompt"].as_str().unwrap();
    let out = dir.path().join("segmented");
    let output = cnfmp(&["segment", "--image", arg(&scene.join("image.png")), "--prompt", prompt, "--out", arg(&out)]);
    assert!(output.status.success(), "{}", stderr(&output));
    for name in ["segmentation.json", "masks.png", "objects.json", "overlay.png", "mask_1.png", "mask_2.png"] {
        assert!(out.join(name).is_file(), "{name} written");
    }
    let document: Value = serde_json::from_str(&std::fs::read_to_string(out.join("segmentation.json")).unwrap()).unwrap();
    assert_eq!(document["backend"], "film", "auto picks the shipped film checkpoint");
    let objects = document["objects"].as_array().unwrap();
    assert_eq!(objects[0]["role"], "target");
    assert_eq!(objects[1]["role"], "destination");
    // The prompt names the simulator's objects 1 (thing to move) and 2 (place), in that order.
    for label in [1u8, 2] {
        let overlap = iou(&out.join("masks.png"), label, &scene.join("masks.png"), label);
        assert!(overlap > 0.6, "object {label} IoU {overlap:.2} ({document})");
    }

    // A prompt naming nothing there is answered as such, not as an empty success.
    let nothing = dir.path().join("nothing");
    let output = cnfmp(&["segment", "--image", arg(&scene.join("image.png")), "--prompt", "the unicorn", "--out", arg(&nothing)]);
    assert!(output.status.success(), "{}", stderr(&output));
    assert!(String::from_utf8_lossy(&output.stdout).contains("NOT FOUND"));
    let document: Value = serde_json::from_str(&std::fs::read_to_string(nothing.join("segmentation.json")).unwrap()).unwrap();
    assert_eq!(document["nothing_found"], true);
    assert!(document["objects"][0]["score"].as_f64().unwrap() < 0.6);

    // Bad input: exit code 2 with the problem named, and nothing written.
    let bad = dir.path().join("bad");
    let image = scene.join("image.png");
    assert_bad_input(&cnfmp(&["segment", "--image", arg(&image), "--prompt", "  ", "--out", arg(&bad)]), "prompt is empty");
    assert_bad_input(
        &cnfmp(&["segment", "--image", arg(&scene.join("objects.json")), "--prompt", "the red ball", "--out", arg(&bad)]),
        "not an image",
    );
    assert_bad_input(
        &cnfmp(&["segment", "--image", arg(&dir.path().join("missing.png")), "--prompt", "the red ball", "--out", arg(&bad)]),
        "cannot read image",
    );
    assert_bad_input(
        &cnfmp(&["segment", "--image", arg(&image), "--prompt", "the red ball", "--out", arg(&bad), "--backend", "film", "--weights", arg(&dir.path().join("none"))]),
        "does not exist",
    );
    assert_bad_input(&cnfmp(&["segment", "--image", arg(&image), "--prompt", "the red ball", "--out", arg(&out)]), "already exists");
    assert!(!bad.exists());
    let grey = dir.path().join("grey.png");
    let pixels = cnfmp::images::Image { width: 64, height: 64, channels: 3, pixels: vec![128; 64 * 64 * 3] };
    cnfmp::images::write_png(&grey, &pixels).unwrap();
    let output = cnfmp(&["segment", "--image", arg(&grey), "--prompt", "the red ball", "--out", arg(&bad)]);
    assert!(output.status.success(), "{}", stderr(&output));
    assert!(stderr(&output).contains("nothing the prompt names was found"), "{}", stderr(&output));
}

#[test]
fn segment_many_scenes_in_one_process() {
    let dir = tempfile::tempdir().unwrap();
    let scenes = dir.path().join("scenes");
    let prompts: Vec<String> = [1_000_010u64, 1_000_011]
        .iter()
        .map(|seed| render("language_pick_place", *seed, &scenes.join(format!("s{seed}")))["prompt"].as_str().unwrap().to_owned())
        .collect();
    // A scene whose image is not one: reported, and the others go on.
    std::fs::create_dir_all(scenes.join("bad")).unwrap();
    std::fs::write(scenes.join("bad/image.png"), "not a png").unwrap();
    std::fs::write(scenes.join("bad/prompt.txt"), "put the red cube on the plate\n").unwrap();
    let out = dir.path().join("segmented");
    let output = cnfmp(&["segment", "--scenes", arg(&scenes), "--out", arg(&out)]);
    assert_bad_input(&output, "1 of 3 scenes were not segmented (first bad:");
    assert!(String::from_utf8_lossy(&output.stdout).contains("2 of 3 scenes segmented"), "{}", String::from_utf8_lossy(&output.stdout));
    let read = |path: &Path| -> Value { serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap() };
    for (seed, prompt) in [1_000_010u64, 1_000_011].iter().zip(&prompts) {
        let scene = out.join(format!("s{seed}"));
        for name in ["segmentation.json", "masks.png", "objects.json", "overlay.png", "mask_1.png", "mask_2.png"] {
            assert!(scene.join(name).is_file(), "{name} written for s{seed}");
        }
        let objects = read(&scene.join("objects.json"));
        assert_eq!(objects["prompt"].as_str(), Some(prompt.as_str()), "the prompt is the one objects.json of the render holds");
        let listed = objects["objects"].as_array().unwrap().len();
        let mut labels: Vec<u8> = read_label_map(&scene.join("masks.png")).unwrap().pixels;
        labels.sort_unstable();
        labels.dedup();
        assert_eq!(labels, (0..=listed as u8).collect::<Vec<_>>(), "masks.png of s{seed} holds the labels objects.json lists");
    }
    assert!(!out.join("bad").exists());
    let summary = read(&out.join("summary.json"));
    assert_eq!((summary["segmented"].as_u64(), summary["failed"].as_u64()), (Some(2), Some(1)), "{summary}");
    assert_eq!(summary["backend"], "film");
    assert!(summary["startup_s"].as_f64().unwrap() > 0.0 && summary["latency_ms_p50"].as_f64().unwrap() > 0.0, "{summary}");
    let per_scene = summary["per_scene"].as_array().unwrap();
    assert_eq!(per_scene[0]["name"], "bad");
    assert_eq!(per_scene[0]["ok"], false);
    assert!(per_scene[0]["error"].as_str().unwrap().contains("not an image"), "{summary}");
    for good in &per_scene[1..] {
        assert_eq!((good["ok"].as_bool(), good["found"].as_u64()), (Some(true), Some(2)), "{summary}");
    }
    let staging_left = std::fs::read_dir(dir.path()).unwrap().filter(|e| e.as_ref().unwrap().file_name().to_string_lossy().starts_with('.')).count();
    assert_eq!(staging_left, 0, "no staging directory is left beside the output");

    // Refused before any work: a scene without a prompt, --scenes with --image, an output that exists.
    std::fs::create_dir_all(scenes.join("silent")).unwrap();
    std::fs::copy(scenes.join("s1000010/image.png"), scenes.join("silent/image.png")).unwrap();
    let other = dir.path().join("other");
    assert_bad_input(&cnfmp(&["segment", "--scenes", arg(&scenes), "--out", arg(&other)]), "silent has no prompt");
    let output = cnfmp(&["segment", "--scenes", arg(&scenes), "--image", arg(&scenes.join("silent/image.png")), "--out", arg(&other)]);
    assert_eq!(output.status.code(), Some(2), "{}", stderr(&output));
    assert!(stderr(&output).contains("cannot be used with"), "{}", stderr(&output));
    std::fs::remove_dir_all(scenes.join("silent")).unwrap();
    assert_bad_input(&cnfmp(&["segment", "--scenes", arg(&scenes), "--out", arg(&out)]), "already exists");
    assert!(!other.exists());
}

#[test]
fn predict_from_a_prompt() {
    let dir = tempfile::tempdir().unwrap();
    let dataset = dir.path().join("data");
    let output = cnfmp(&["dataset", "generate", "--task", "language_pick_place", "--episodes", "2", "--seed", "400", "--out", arg(&dataset)]);
    assert!(output.status.success(), "{}", stderr(&output));
    let config = dir.path().join("tiny.json");
    std::fs::write(&config, TINY_CONFIG.replacen('{', "{\"task_objects\": 2, ", 1)).unwrap();
    let model = dir.path().join("model");
    let output = cnfmp(&["train", "--dataset", arg(&dataset), "--out", arg(&model), "--config", arg(&config), "--steps", "10"]);
    assert!(output.status.success(), "{}", stderr(&output));
    let scene = dir.path().join("scene");
    let info = render("language_pick_place", 1_000_010, &scene);
    let image = scene.join("image.png");
    let trajectory = dir.path().join("traj.json");
    let output = cnfmp(&[
        "predict", "--model", arg(&model), "--image", arg(&image), "--prompt", info["prompt"].as_str().unwrap(), "--out", arg(&trajectory),
    ]);
    assert!(output.status.success(), "{}", stderr(&output));
    let written: Value = serde_json::from_str(&std::fs::read_to_string(&trajectory).unwrap()).unwrap();
    assert!(written["frames"].as_array().unwrap().len() > 10);
    let slots = written["segmentation"]["slots"].as_array().unwrap();
    assert_eq!(slots.len(), 2);
    assert_eq!(slots[0]["role"], "target");
    assert_eq!(slots[1]["role"], "destination");
    // The simulator's masks with distractors (labels 3+) are accepted: they are background here.
    let output = cnfmp(&[
        "predict", "--model", arg(&model), "--image", arg(&image), "--masks", arg(&scene.join("masks.png")),
        "--objects", arg(&scene.join("objects.json")), "--out", arg(&dir.path().join("traj2.json")),
    ]);
    assert!(output.status.success(), "{}", stderr(&output));

    let bad = dir.path().join("bad.json");
    assert_bad_input(
        &cnfmp(&["predict", "--model", arg(&model), "--image", arg(&image), "--prompt", &format!("pick up the {}", info["objects"][0].as_str().unwrap()), "--out", arg(&bad)]),
        "needs a destination",
    );
    let output = cnfmp(&["predict", "--model", arg(&model), "--image", arg(&image), "--out", arg(&bad)]);
    assert_eq!(output.status.code(), Some(2), "neither masks nor a prompt: {}", stderr(&output));
    assert!(!bad.exists());
}
