//! End-to-end test of `cnfmp train | predict | eval` through the real binary: a small
//! generated dataset, a tiny model trained for a few steps, prediction on a rendered held-out
//! scene, a two-scene evaluation, and the bad inputs that must exit with code 2.

use std::path::Path;
use std::process::Output;

use serde_json::Value;

mod common;
use common::{TINY_CONFIG, arg, cnfmp, copy_tree, repo, stderr};


fn assert_bad_input(output: &Output, needle: &str) {
    assert_eq!(output.status.code(), Some(2), "{}", stderr(output));
    assert!(
        stderr(output).contains(needle),
        "expected {needle:?} in: {}",
        stderr(output)
    );
}

/// A configuration small enough to train in seconds on one thread.
#[test]
fn train_predict_eval_and_bad_inputs() {
    let dir = tempfile::tempdir().unwrap();
    let dataset = dir.path().join("wall");
    let output = cnfmp(&[
        "dataset",
        "generate",
        "--task",
        "wall_avoidance",
        "--episodes",
        "2",
        "--seed",
        "300",
        "--out",
        arg(&dataset),
    ]);
    assert!(output.status.success(), "{}", stderr(&output));

    let config = dir.path().join("tiny.json");
    std::fs::write(&config, TINY_CONFIG).unwrap();
    let model = dir.path().join("model");
    let output = cnfmp(&[
        "train",
        "--dataset",
        arg(&dataset),
        "--out",
        arg(&model),
        "--config",
        arg(&config),
        "--steps",
        "20",
        "--seed",
        "4",
        "--threads",
        "2",
    ]);
    assert!(output.status.success(), "{}", stderr(&output));
    let report: Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(report["steps"], 20);
    assert_eq!(report["demos"], 2);
    assert_eq!(report["model_type"], "cnfmp", "the default model type");
    let unknown_type = cnfmp(&["train", "--dataset", arg(&dataset), "--out", arg(&dir.path().join("x")), "--model-type", "cnmp"]);
    assert_bad_input(&unknown_type, "unknown model type 'cnmp'; known: cnfmp, cnfmp-nogate, cnn-cnmp, nfmp");
    assert!(
        stderr(&output).contains("step 20/20"),
        "progress is shown: {}",
        stderr(&output)
    );
    let card = std::fs::read_to_string(model.join("README.md")).unwrap();
    assert!(
        card.contains("--steps 20 --seed 4"),
        "the card records the command: {card}"
    );
    // --threads wins over CNFMP_TORCH_THREADS, which the tests set to 1.
    assert!(card.contains("2 torch thread(s)"), "the card records the training's threads: {card}");
    // Without either, training uses every core the process may use.
    let default_threads = dir.path().join("default-threads");
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_cnfmp"))
        .args(["train", "--dataset", arg(&dataset), "--out", arg(&default_threads), "--config", arg(&config)])
        .args(["--steps", "2"])
        .env_remove("CNFMP_TORCH_THREADS")
        .output()
        .unwrap();
    assert!(output.status.success(), "{}", stderr(&output));
    let cores = std::thread::available_parallelism().unwrap().get();
    let card = std::fs::read_to_string(default_threads.join("README.md")).unwrap();
    assert!(card.contains(&format!("{cores} torch thread(s)")), "{cores} cores: {card}");
    let no_threads = cnfmp(&["train", "--dataset", arg(&dataset), "--out", arg(&dir.path().join("y")), "--threads", "0"]);
    assert!(!no_threads.status.success() && stderr(&no_threads).contains("--threads"), "{}", stderr(&no_threads));
    let again = cnfmp(&[
        "train",
        "--dataset",
        arg(&dataset),
        "--out",
        arg(&model),
        "--steps",
        "1",
    ]);
    assert_bad_input(&again, "already exists");

    let scene = dir.path().join("scene");
    let output = cnfmp(&[
        "sim",
        "render",
        "--task",
        "wall_avoidance",
        "--seed",
        "1000005",
        "--out",
        arg(&scene),
    ]);
    assert!(output.status.success(), "{}", stderr(&output));
    let (image, masks, objects) = (
        scene.join("image.png"),
        scene.join("masks.png"),
        scene.join("objects.json"),
    );
    let traj = dir.path().join("traj.json");
    let predict = |model: &Path, image: &Path, masks: &Path, objects: &Path| {
        cnfmp(&[
            "predict",
            "--model",
            arg(model),
            "--image",
            arg(image),
            "--masks",
            arg(masks),
            "--objects",
            arg(objects),
            "--out",
            arg(&traj),
        ])
    };
    let output = predict(&model, &image, &masks, &objects);
    assert!(output.status.success(), "{}", stderr(&output));
    let predicted: Value = serde_json::from_str(&std::fs::read_to_string(&traj).unwrap()).unwrap();
    assert_eq!(predicted["fps"], 50.0);
    assert!(predicted["frames"].as_array().unwrap().len() > 100);
    let objects_out = predicted["objects"].as_array().unwrap();
    assert_eq!(objects_out.len(), 2);
    assert!(
        objects_out
            .iter()
            .all(|o| o["psnr_db"].as_f64().unwrap() > 0.0),
        "{predicted}"
    );
    // The file is a valid trajectory for the rest of the CLI.
    let output = cnfmp(&["trajectory", "inspect", arg(&traj)]);
    assert!(output.status.success(), "{}", stderr(&output));

    // Bad inputs: exit code 2, a message naming the problem, the earlier output untouched.
    let before = std::fs::read(&traj).unwrap();
    let weightless = dir.path().join("weightless");
    std::fs::create_dir(&weightless).unwrap();
    std::fs::copy(model.join("config.json"), weightless.join("config.json")).unwrap();
    assert_bad_input(
        &predict(&weightless, &image, &masks, &objects),
        "model.safetensors",
    );
    let configless = dir.path().join("configless");
    std::fs::create_dir(&configless).unwrap();
    assert_bad_input(
        &predict(&configless, &image, &masks, &objects),
        "config.json",
    );
    let other = dir.path().join("other");
    let output = cnfmp(&[
        "sim",
        "render",
        "--task",
        "cube_stacking",
        "--seed",
        "1000000",
        "--out",
        arg(&other),
    ]);
    assert!(output.status.success(), "{}", stderr(&output));
    let small_masks = dir.path().join("small.png");
    // A 1x1 8-bit grey PNG.
    std::fs::write(
        &small_masks,
        [
            0x89, 0x50, 0x4E, 0x47, 0x0D, 0x0A, 0x1A, 0x0A, 0, 0, 0, 0x0D, 0x49, 0x48, 0x44, 0x52,
            0, 0, 0, 1, 0, 0, 0, 1, 8, 0, 0, 0, 0, 0x3A, 0x7E, 0x9B, 0x55, 0, 0, 0, 0x0A, 0x49,
            0x44, 0x41, 0x54, 0x78, 0x9C, 0x63, 0x60, 0, 0, 0, 2, 0, 1, 0x48, 0xAF, 0xA4, 0x71, 0,
            0, 0, 0, 0x49, 0x45, 0x4E, 0x44, 0xAE, 0x42, 0x60, 0x82,
        ],
    )
    .unwrap();
    assert_bad_input(
        &predict(&model, &image, &small_masks, &objects),
        "must have the same size",
    );
    let one_object = dir.path().join("one.json");
    std::fs::write(&one_object, r#"["wall"]"#).unwrap();
    assert_bad_input(
        &predict(&model, &image, &masks, &one_object),
        "the masks use label 2 but the objects name 1 object(s)",
    );
    assert_bad_input(
        &predict(
            &model,
            &image,
            &other.join("masks.png"),
            &other.join("objects.json"),
        ),
        "object slot",
    );
    assert_eq!(
        std::fs::read(&traj).unwrap(),
        before,
        "a failed predict leaves the earlier output alone"
    );

    // Many scenes in one call: a scene folder like the one predicted above (the same
    // trajectory), one with masks of the wrong size (reported, skipped, exit code 2).
    let scenes = dir.path().join("scenes");
    for (name, masks) in [("a", &masks), ("b", &small_masks)] {
        std::fs::create_dir_all(scenes.join(name)).unwrap();
        std::fs::copy(&image, scenes.join(name).join("image.png")).unwrap();
        std::fs::copy(masks, scenes.join(name).join("masks.png")).unwrap();
        std::fs::copy(&objects, scenes.join(name).join("objects.json")).unwrap();
    }
    let batch = dir.path().join("batch");
    let predict_scenes = |scenes: &Path, out: &Path| cnfmp(&["predict", "--model", arg(&model), "--scenes", arg(scenes), "--out", arg(out)]);
    let output = predict_scenes(&scenes, &batch);
    assert_bad_input(&output, "1 of 2 scenes were not predicted (first b:");
    let frames = |path: &Path| serde_json::from_str::<Value>(&std::fs::read_to_string(path).unwrap()).unwrap()["frames"].clone();
    assert_eq!(frames(&batch.join("a.json")), predicted["frames"], "one process for many scenes predicts as one per scene");
    assert!(!batch.join("b.json").exists());
    let summary: Value = serde_json::from_str(&std::fs::read_to_string(batch.join("summary.json")).unwrap()).unwrap();
    assert_eq!((summary["predicted"].as_u64(), summary["failed"].as_u64()), (Some(1), Some(1)), "{summary}");
    assert!(summary["per_scene"][1]["error"].as_str().unwrap().contains("must have the same size"), "{summary}");
    assert_bad_input(&predict_scenes(&scenes, &batch), "not an empty directory");
    // A JSON lines file: paths relative to it, object names inline.
    let lines = dir.path().join("scenes.jsonl");
    std::fs::write(&lines, "{\"name\": \"x\", \"image\": \"scene/image.png\", \"masks\": \"scene/masks.png\", \"objects\": [\"wall\", \"goal marker\"]}\n\
        {\"image\": \"scene/image.png\", \"masks\": \"scene/masks.png\", \"objects\": \"scene/objects.json\"}\n").unwrap();
    let from_lines = dir.path().join("from-lines");
    let output = predict_scenes(&lines, &from_lines);
    assert!(output.status.success(), "{}", stderr(&output));
    assert!(String::from_utf8_lossy(&output.stdout).contains("2 of 2 scenes predicted"), "{}", String::from_utf8_lossy(&output.stdout));
    assert_eq!(frames(&from_lines.join("x.json")), predicted["frames"]);
    assert_eq!(frames(&from_lines.join("scene-0002.json")), predicted["frames"]);

    let report = dir.path().join("eval.json");
    // `cnfmp eval` of the tiny model on wall_avoidance: `episodes` scenes from `seed_start`.
    let eval = |episodes: &str, seed_start: &str, more: &[&str]| {
        let mut args = vec!["eval", "--model", arg(&model), "--task", "wall_avoidance"];
        args.extend(["--episodes", episodes, "--seed-start", seed_start]);
        args.extend_from_slice(more);
        cnfmp(&args)
    };
    let output = eval("2", "1000010", &["--json", arg(&report)]);
    assert!(output.status.success(), "{}", stderr(&output));
    assert!(
        String::from_utf8_lossy(&output.stdout).contains("on 2 held-out wall_avoidance scenes")
    );
    let summary: Value = serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    let episodes = summary["per_episode"].as_array().unwrap();
    assert_eq!(episodes.len(), 2);
    assert_eq!(episodes[1]["seed"], 1000011);
    assert!(episodes.iter().all(|e| e["med_cm"].as_f64().unwrap() > 0.0));
    let rate = summary["success_rate"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&rate));
    // Two scenes say little: the 95% interval brackets the rate and is wide.
    let interval: Vec<f64> = summary["success_interval_95"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    assert!(interval[0] <= rate && rate <= interval[1] && interval[1] - interval[0] > 0.5, "{interval:?}");
    assert_bad_input(&eval("2", "5", &[]), "held-out");
    // Validation scenes for choosing settings: training-range seeds above the demonstrations'.
    let output = eval("1", "500000", &["--validation"]);
    assert!(output.status.success(), "{}", stderr(&output));
    assert!(
        String::from_utf8_lossy(&output.stdout).contains("on 1 validation wall_avoidance scenes (seeds 500000..=500000)")
    );
    assert_bad_input(&eval("2", "999999", &["--validation"]), "not all within 500000..=899999");
    assert_bad_input(
        &cnfmp(&[
            "eval",
            "--model",
            arg(&model),
            "--task",
            "cube_stacking",
            "--episodes",
            "1",
        ]),
        "trained on wall_avoidance",
    );
}

/// A model directory that cannot be loaded (here: a config field this cnfmp does not know) is
/// refused before the first scene with the loader's message, by `eval` and by
/// `predict --scenes`, rather than failing every scene with it.
#[test]
fn a_model_that_cannot_be_loaded_is_refused_before_the_first_scene() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("model");
    copy_tree(&repo().join("models/wall_avoidance"), &model);
    let config_path = model.join("config.json");
    let mut config: Value = serde_json::from_str(&std::fs::read_to_string(&config_path).unwrap()).unwrap();
    config["bogus_field"] = Value::from(1);
    std::fs::write(&config_path, serde_json::to_string_pretty(&config).unwrap()).unwrap();

    let output = cnfmp(&["eval", "--model", arg(&model), "--task", "wall_avoidance", "--episodes", "3", "--seed-start", "1000000"]);
    assert_bad_input(&output, "cannot load the model: ");
    assert!(stderr(&output).contains("unknown field(s) bogus_field"), "{}", stderr(&output));
    assert!(!stderr(&output).contains("[1/3]"), "no episode runs: {}", stderr(&output));

    let scenes = dir.path().join("scenes");
    std::fs::create_dir_all(scenes.join("a")).unwrap();
    std::fs::write(scenes.join("a/image.png"), "never read").unwrap();
    std::fs::write(scenes.join("a/prompt.txt"), "reach the goal marker").unwrap();
    let out = dir.path().join("batch");
    let output = cnfmp(&["predict", "--model", arg(&model), "--scenes", arg(&scenes), "--out", arg(&out)]);
    assert_bad_input(&output, "unknown field(s) bogus_field");
    assert!(!out.exists(), "nothing is written");
}

#[test]
fn a_shipped_scan_model_predicts_a_held_out_scan_and_refuses_what_is_not_one() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    let rendered = cnfmp(&["sim", "render", "--task", "drawer_place", "--seed", "1000004", "--scan", "--out", arg(&scene)]);
    assert!(rendered.status.success(), "{}", stderr(&rendered));
    let model = repo().join("models/drawer_place");
    let (out, figure) = (dir.path().join("trajectory.json"), dir.path().join("fit.png"));
    let predicted = cnfmp(&["predict", "--model", arg(&model), "--scan", arg(&scene.join("scan")), "--figure", arg(&figure),
                            "--out", arg(&out)]);
    assert!(predicted.status.success(), "{}", stderr(&predicted));
    assert!(std::fs::read(&figure).unwrap().starts_with(b"\x89PNG"));
    let executed = cnfmp(&["sim", "execute", "--task", "drawer_place", "--seed", "1000004", "--trajectory", arg(&out)]);
    let verdict: serde_json::Value = serde_json::from_slice(&executed.stdout).unwrap();
    assert_eq!(verdict["success"], true, "the shipped drawer model failed a held-out scene: {verdict}");

    let refused = dir.path().join("refused.json");
    let not_a_scan = cnfmp(&["predict", "--model", arg(&model), "--scan", arg(dir.path()), "--out", arg(&refused)]);
    assert_bad_input(&not_a_scan, "is not a scan");
    let image_model = repo().join("models/cube_stacking");
    let wrong_model = cnfmp(&["predict", "--model", arg(&image_model), "--scan", arg(&scene.join("scan")), "--out", arg(&refused)]);
    assert_bad_input(&wrong_model, "not from a scan");
    let image_to_scan_model = cnfmp(&["predict", "--model", arg(&model), "--image", arg(&scene.join("image.png")), "--masks",
                                      arg(&scene.join("masks.png")), "--objects", arg(&scene.join("objects.json")), "--out", arg(&refused)]);
    assert_bad_input(&image_to_scan_model, "predicts from a scan");
    let unpromptable = cnfmp(&["predict", "--model", arg(&model), "--scan", arg(&scene.join("scan")), "--prompt",
                                "put the carton box in the drawer", "--out", arg(&refused)]);
    assert_bad_input(&unpromptable, "no prompt roles");
    assert!(!refused.exists(), "a refused prediction wrote its output");
}
