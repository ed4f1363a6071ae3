//! `cnfmp train | predict | eval`: the compositional NF-MP core from the command line.
//!
//! Training and inference run in Python (torch) through the bridge; this module validates
//! arguments before the interpreter starts, writes outputs atomically, and runs the
//! evaluation loop: render a held-out scene, predict from image + masks, execute by physics,
//! compare with the expert (MED), report.

use std::fs;
use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use segmenter_bridge::{Bridge, BridgeError, ObjectEstimate, Prediction, SegmentDocument, Segmentation, TrainRequest};
use serde::Serialize;
use serde_json::{Map, Value};

use super::print_stdout;
use super::scenes::{ObjectNames, SUMMARY_FILE, SceneInput, SceneObjects, list_scenes};
use super::segment::{BackendArgs, describe, run_segmenter};
use crate::failure::Failure;
use crate::files::write_atomically;
use crate::progress::Progress;
use crate::scene_masks::{self, CoarseMasks};
use crate::trajectory::Trajectory;
use crate::trajectory::compare::mean_euclidean_distance_cm;
use crate::trajectory::resample::{ResampleTarget, resample};

/// First held-out scene seed (seeds below it are for training; see `cnfmp sim`).
pub const FIRST_HELDOUT_SEED: u64 = 1_000_000;
/// First validation scene seed: the upper half of the training range, far above any
/// dataset's demonstrations (which number from 0). The validation scripts under `scripts/`
/// start at the same seed (`VALIDATION_SEED_START` in `python/cnfmp/core/trial.py`).
pub const FIRST_VALIDATION_SEED: u64 = 500_000;
/// One past the last held-out seed.
pub const HELDOUT_SEED_END: u64 = 2_000_000;

#[derive(Debug, Args)]
pub struct TrainArgs {
    /// LeRobot v3.0 dataset (from `cnfmp dataset generate` or `cnfmp dataset convert`).
    #[arg(long)]
    dataset: PathBuf,
    /// Model directory to create: config.json, model.safetensors, README.md (must not exist).
    #[arg(long)]
    out: PathBuf,
    /// JSON file of config fields (see python/cnfmp/core/configuration_cnfmp.py); defaults
    /// otherwise. An "after_training" object in it holds inference settings the model ships
    /// with, set after training (training's own inference uses the file's other values).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Optimisation steps (overrides the config).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    steps: Option<u64>,
    /// Seed of initialisation and sampling (overrides the config).
    #[arg(long)]
    seed: Option<u64>,
    /// Kind of model: cnfmp (the compositional model), cnfmp-nogate (the ablation without
    /// temporal gating), cnn-cnmp or nfmp (the baselines of the paper's Table I). Default:
    /// the --config file's model_type, else cnfmp.
    #[arg(long, value_parser = MODEL_TYPES)]
    model_type: Option<String>,
}

/// Every model type `cnfmp train` builds (python/cnfmp/core/models.py).
pub const MODEL_TYPES: [&str; 4] = ["cnfmp", "cnfmp-nogate", "cnn-cnmp", "nfmp"];

#[derive(Debug, Args)]
pub struct PredictArgs {
    /// Model directory written by `cnfmp train`.
    #[arg(long)]
    model: PathBuf,
    /// Scene image (PNG or JPEG).
    #[arg(long, required_unless_present = "scenes")]
    image: Option<PathBuf>,
    /// Coarse masks: an 8-bit label map of the image's size (0 background, k the k-th object).
    /// Without masks, --prompt is segmented instead.
    #[arg(long, requires = "objects", conflicts_with = "prompt", required_unless_present_any = ["prompt", "scenes"])]
    masks: Option<PathBuf>,
    /// Object names in label order: a JSON list, or an object with an "objects" list (the
    /// objects.json `cnfmp sim render` and `cnfmp segment` write).
    #[arg(long, requires = "masks")]
    objects: Option<PathBuf>,
    /// Find the objects with the language segmenter: its phrases fill the model's object
    /// slots by role (e.g. target, destination), e.g. "put the red ball in the box".
    #[arg(long)]
    prompt: Option<String>,
    /// Many scenes in one call, the model loaded once: a directory of scene folders (each with
    /// image.png or .jpg, and masks.png + objects.json, or else prompt.txt or a "prompt" in
    /// objects.json: what `cnfmp sim render` writes), or a JSON lines file, one scene per line:
    /// {"name": ..., "image": PATH, "masks": PATH, "objects": [NAMES] or PATH} or
    /// {"image": PATH, "prompt": TEXT} (paths relative to the file). --out is then a new
    /// directory: <name>.json per scene and summary.json.
    #[arg(long, conflicts_with_all = ["image", "masks", "objects", "prompt"])]
    scenes: Option<PathBuf>,
    #[command(flatten)]
    segmenter: BackendArgs,
    /// Output trajectory JSON (replaced atomically), with the inferred weights and confidences;
    /// with --scenes, a directory that must not exist or be empty.
    #[arg(long)]
    out: PathBuf,
}

#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Model directory written by `cnfmp train`.
    #[arg(long)]
    model: PathBuf,
    /// Task of the held-out scenes (the model's task).
    #[arg(long)]
    task: String,
    /// Number of scenes.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=100_000))]
    episodes: u64,
    /// First scene seed; scenes use consecutive seeds, all held-out (1000000..=1999999), or
    /// all validation scenes (500000..=999999) with --validation.
    #[arg(long, default_value_t = FIRST_HELDOUT_SEED)]
    seed_start: u64,
    /// Evaluate on validation scenes instead (give --seed-start too): training-range seeds no
    /// demonstration uses (500000..=999999), for choosing a recipe or setting without
    /// touching the held-out ones.
    #[arg(long)]
    validation: bool,
    /// Write the summary and per-episode results as JSON here (replaced atomically).
    #[arg(long)]
    json: Option<PathBuf>,
    /// Find the objects with the language segmenter from each scene's prompt instead of
    /// using the simulator's masks: prompt + image -> segmenter -> model -> physics.
    #[arg(long)]
    from_prompt: bool,
    #[command(flatten)]
    segmenter: BackendArgs,
}

/// The last seed of `episodes` consecutive scenes from `seed_start`, all of which must be
/// held-out; a bad-input failure otherwise.
pub(crate) fn heldout_seed_range(seed_start: u64, episodes: u64) -> Result<u64, Failure> {
    seeds_within(
        seed_start,
        episodes,
        FIRST_HELDOUT_SEED..HELDOUT_SEED_END,
        "evaluation scenes must be held-out",
    )
}

/// The last seed of `episodes` consecutive validation scenes from `seed_start`: training-range
/// seeds from FIRST_VALIDATION_SEED, which no dataset of demonstrations reaches; a bad-input
/// failure otherwise.
pub(crate) fn validation_seed_range(seed_start: u64, episodes: u64) -> Result<u64, Failure> {
    seeds_within(
        seed_start,
        episodes,
        FIRST_VALIDATION_SEED..FIRST_HELDOUT_SEED,
        "validation scenes must be training-range seeds no demonstration uses",
    )
}

/// The last of `episodes` consecutive seeds from `seed_start` when all lie in `allowed`; else
/// a bad-input failure that starts with `rule`.
fn seeds_within(
    seed_start: u64,
    episodes: u64,
    allowed: std::ops::Range<u64>,
    rule: &str,
) -> Result<u64, Failure> {
    let last = seed_start.saturating_add(episodes.saturating_sub(1));
    if seed_start < allowed.start || last >= allowed.end {
        return Err(Failure::BadInput(format!(
            "{rule}: seeds {seed_start}..={last} are not all within {}..={}",
            allowed.start,
            allowed.end - 1
        )));
    }
    Ok(last)
}

/// Checks shared by every training command before the interpreter starts: the model
/// directory must be new and a given config file must exist.
pub(crate) fn check_training_outputs(out: &Path, config: Option<&Path>) -> Result<(), Failure> {
    if out.exists() {
        return Err(Failure::BadInput(format!(
            "{} already exists; models are never overwritten, choose a new --out",
            out.display()
        )));
    }
    config.map_or(Ok(()), |config| require_file(config, "config"))
}

/// The command line as typed (recorded in model cards).
pub(crate) fn command_line() -> String {
    std::iter::once("cnfmp".to_owned())
        .chain(std::env::args().skip(1))
        .collect::<Vec<_>>()
        .join(" ")
}

fn require_file(path: &Path, what: &str) -> Result<(), Failure> {
    if path.is_file() {
        Ok(())
    } else {
        Err(Failure::BadInput(format!(
            "{what} {} does not exist or is not a file",
            path.display()
        )))
    }
}

pub fn train(args: TrainArgs) -> Result<(), Failure> {
    if !args.dataset.is_dir() {
        return Err(Failure::BadInput(format!(
            "dataset {} is not a directory",
            args.dataset.display()
        )));
    }
    check_training_outputs(&args.out, args.config.as_deref())?;
    let command = command_line();
    let request = TrainRequest {
        dataset: args.dataset,
        out: args.out,
        config: args.config,
        steps: args.steps,
        seed: args.seed,
        model_type: args.model_type,
        command,
    };
    let report = Bridge::start_default()?.core_train(&request)?;
    print_stdout(&serde_json::to_string_pretty(&report).expect("report serialises"))
}

/// A scene's coarse masks, checked against its image.
fn read_masks(image: &[u8], masks: &Path, names: &ObjectNames) -> Result<CoarseMasks, Failure> {
    let size = scene_masks::image_size(image)
        .ok_or_else(|| Failure::BadInput("the image is not in a format we read (PNG, JPEG, BMP, ...)".into()))?;
    let names = match names {
        ObjectNames::File(path) => scene_masks::parse_objects_text(&read_bytes(path, "objects")?)
            .map_err(|err| Failure::BadInput(format!("{}: {err}", path.display())))?,
        ObjectNames::Listed(names) => scene_masks::parse_objects(&Value::from(names.clone()))
            .map_err(|err| Failure::BadInput(format!("objects: {err}")))?,
    };
    CoarseMasks::from_png(&read_bytes(masks, "masks")?, names, size)
        .map_err(|err| Failure::BadInput(format!("{}: {err}", masks.display())))
}

/// The task a model directory was trained on (its config.json's "task"; empty when the
/// config names none, as the segmenter's checkpoint directory does).
pub(crate) fn model_task(model: &Path) -> Result<String, Failure> {
    let config_path = model.join("config.json");
    require_file(&config_path, "model config")?;
    let text = fs::read_to_string(&config_path)
        .map_err(|err| Failure::BadInput(format!("cannot read {}: {err}", config_path.display())))?;
    let config: Value = serde_json::from_str(&text)
        .map_err(|err| Failure::BadInput(format!("{} is not JSON: {err}", config_path.display())))?;
    Ok(config.get("task").and_then(Value::as_str).unwrap_or_default().to_owned())
}

fn read_bytes(path: &Path, what: &str) -> Result<Vec<u8>, Failure> {
    fs::read(path)
        .map_err(|err| Failure::BadInput(format!("cannot read {what} {}: {err}", path.display())))
}

/// The prediction's trajectory, validated by the Rust trajectory code (the diagnostics stay
/// as metadata).
fn trajectory_of(prediction: &Prediction) -> Result<Trajectory, Failure> {
    Trajectory::from_json_str(&prediction.json).map_err(|err| {
        Failure::Environment(format!("the model produced an invalid trajectory: {err}"))
    })
}

fn describe_objects(objects: &[ObjectEstimate]) -> String {
    if objects.is_empty() {
        return "none (a scene-level model)".into();
    }
    objects
        .iter()
        .map(|o| match (o.present, o.psnr_db) {
            (true, Some(psnr)) => format!("{} (fit {psnr:.1} dB)", o.name),
            _ => format!("{} (absent)", o.name),
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// One scene's prediction: the validated trajectory (with what the segmenter found in its
/// metadata when a prompt was used) and the model's report.
struct PredictedScene {
    trajectory: Trajectory,
    prediction: Prediction,
    segmentation: Option<Segmentation>,
}

/// Predicts one scene with the resident model: masks as given, or the prompt segmented first.
/// Bad input (an unreadable image, masks of another size, a prompt the segmenter cannot
/// ground) is a `Failure::BadInput` naming it.
fn predict_scene(bridge: &Bridge, model: &Path, scene: &SceneInput, backend: &BackendArgs) -> Result<PredictedScene, Failure> {
    let image = read_bytes(&scene.image, "image")?;
    let (prediction, segmentation) = match &scene.objects {
        SceneObjects::Masks { masks, names } => {
            let masks = read_masks(&image, masks, names)?;
            (bridge.core_predict(model, image, masks.png(), masks.objects)?, None)
        }
        SceneObjects::Prompt(prompt) => {
            let task = model_task(model)?;
            let found = run_segmenter(bridge, image.clone(), prompt, backend, Some(&task), false)?;
            let prediction = bridge.core_predict(model, image, found.labels_png.clone(), found.slot_names.clone())?;
            (prediction, Some(found))
        }
    };
    let mut trajectory = trajectory_of(&prediction)?;
    if let Some(found) = &segmentation {
        let document = serde_json::to_value(&found.document).expect("segmentation serialises");
        trajectory.metadata.insert("segmentation".into(), document);
    }
    Ok(PredictedScene { trajectory, prediction, segmentation })
}

/// The model's own time for a prediction (ms; NaN when it reports none).
fn inference_ms(prediction: &Prediction) -> f64 {
    prediction.timings_ms.get("total").and_then(Value::as_f64).unwrap_or(f64::NAN)
}

pub fn predict(args: PredictArgs) -> Result<(), Failure> {
    let (image, objects) = match (args.image, args.masks, args.objects, args.prompt, args.scenes) {
        (None, None, None, None, Some(scenes)) => return predict_scenes(&args.model, &scenes, &args.segmenter, &args.out),
        (Some(image), Some(masks), Some(objects), None, None) => {
            (image, SceneObjects::Masks { masks, names: ObjectNames::File(objects) })
        }
        (Some(image), None, None, Some(prompt), None) => (image, SceneObjects::Prompt(prompt)),
        _ => return Err(Failure::BadInput("give --image with --masks and --objects, or --image with --prompt, or --scenes".into())),
    };
    let scene = SceneInput { name: args.out.display().to_string(), image, objects };
    let done = predict_scene(Bridge::start_default()?, &args.model, &scene, &args.segmenter)?;
    if let Some(found) = &done.segmentation {
        eprintln!("segmented by {}:\n{}", found.document.backend, describe(found));
    }
    write_atomically(&args.out, done.trajectory.to_json_string().as_bytes())?;
    eprintln!(
        "{}: {} frames at {} Hz, {:.2} s; objects: {}; inference {:.0} ms",
        args.out.display(),
        done.trajectory.frames.len(),
        done.trajectory.fps,
        done.trajectory.duration(),
        describe_objects(&done.prediction.objects),
        inference_ms(&done.prediction)
    );
    Ok(())
}

/// One scene of a `cnfmp predict --scenes` call, as summary.json reports it.
#[derive(Debug, Serialize)]
struct SceneReport {
    name: String,
    predicted: bool,
    /// Why the scene has no trajectory (bad input: its files, or a prompt not grounded).
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<String>,
    /// Wall time of the scene (ms): reading its files, segmenting, predicting, writing.
    latency_ms: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    frames: Option<usize>,
    objects: Vec<ObjectEstimate>,
    timings_ms: Map<String, Value>,
}

/// summary.json of a `cnfmp predict --scenes` call.
#[derive(Debug, Serialize)]
struct ScenesSummary {
    model: String,
    scenes: usize,
    predicted: usize,
    failed: usize,
    /// From the command's start to the last scene written (s).
    wall_time_s: f64,
    /// Start-up paid once (s): listing the scenes, starting the interpreter, the imports and
    /// the model load, i.e. the time before the first prediction plus its latency less the warm
    /// median.
    startup_s: f64,
    /// Over every scene but the first (which pays the start-up).
    latency_ms_p50: f64,
    latency_ms_p95: f64,
    per_scene: Vec<SceneReport>,
}

/// `cnfmp predict --scenes`: every scene of `scenes` in this one process, a trajectory file
/// per scene in `out` as soon as it is predicted. A scene with bad input is reported and
/// skipped; the command then exits with code 2 after the others are done.
fn predict_scenes(model: &Path, scenes: &Path, backend: &BackendArgs, out: &Path) -> Result<(), Failure> {
    let started = Instant::now();
    let scenes = list_scenes(scenes)?;
    if out.exists() && (!out.is_dir() || fs::read_dir(out).map_or(true, |mut entries| entries.next().is_some())) {
        return Err(Failure::BadInput(format!("{} already exists and is not an empty directory; choose a new --out", out.display())));
    }
    fs::create_dir_all(out).map_err(|err| Failure::BadInput(format!("cannot create {}: {err}", out.display())))?;
    let bridge = Bridge::start_default()?;
    let loop_started = Instant::now();
    let mut progress = Progress::new("predict", scenes.len() as u64, 0);
    let mut reports = Vec::with_capacity(scenes.len());
    let mut outcome = Ok(());
    for scene in &scenes {
        let call = Instant::now();
        let predicted = predict_scene(bridge, model, scene, backend).and_then(|done| {
            write_atomically(&out.join(format!("{}.json", scene.name)), done.trajectory.to_json_string().as_bytes())?;
            Ok(done)
        });
        let latency_ms = call.elapsed().as_secs_f64() * 1e3;
        reports.push(match predicted {
            Ok(done) => SceneReport {
                name: scene.name.clone(),
                predicted: true,
                error: None,
                latency_ms,
                frames: Some(done.trajectory.frames.len()),
                objects: done.prediction.objects,
                timings_ms: done.prediction.timings_ms,
            },
            Err(Failure::BadInput(message)) => {
                progress.note(&format!("{}: not predicted: {message}", scene.name));
                SceneReport { name: scene.name.clone(), predicted: false, error: Some(message), latency_ms, frames: None, objects: Vec::new(), timings_ms: Map::new() }
            }
            Err(failure) => {
                // The environment broke (not the scene): stop, keeping what is written.
                outcome = Err(failure);
                break;
            }
        });
        progress.advance(1);
    }
    progress.finish();
    // The first prediction pays the start-up; the scenes refused before reaching the model
    // say nothing about its speed.
    let latencies: Vec<f64> = reports.iter().filter(|r| r.predicted).map(|r| r.latency_ms).collect();
    let warm = &latencies[usize::from(latencies.len() > 1)..];
    let warm_p50 = quantile(warm, 0.5);
    let summary = ScenesSummary {
        model: model.display().to_string(),
        scenes: scenes.len(),
        predicted: latencies.len(),
        failed: reports.len() - latencies.len(),
        wall_time_s: started.elapsed().as_secs_f64(),
        startup_s: latencies.first().map_or(f64::NAN, |first| (loop_started - started).as_secs_f64() + (first - warm_p50).max(0.0) / 1e3),
        latency_ms_p50: warm_p50,
        latency_ms_p95: quantile(warm, 0.95),
        per_scene: reports,
    };
    let text = serde_json::to_string_pretty(&summary).expect("summary serialises");
    write_atomically(&out.join(SUMMARY_FILE), format!("{text}\n").as_bytes())?;
    outcome?;
    print_stdout(&format!(
        "{}: {} of {} scenes predicted in {:.1} s (start-up {:.1} s, then p50 {:.0} ms / p95 {:.0} ms per scene); trajectories and {SUMMARY_FILE} in {}",
        summary.model,
        summary.predicted,
        summary.scenes,
        summary.wall_time_s,
        summary.startup_s,
        summary.latency_ms_p50,
        summary.latency_ms_p95,
        out.display()
    ))?;
    match summary.per_scene.iter().find(|r| !r.predicted) {
        None => Ok(()),
        Some(first) => Err(Failure::BadInput(format!(
            "{} of {} scenes were not predicted (first {}: {}); see {}",
            summary.failed,
            summary.scenes,
            first.name,
            first.error.as_deref().unwrap_or("?"),
            out.join(SUMMARY_FILE).display()
        ))),
    }
}

/// One evaluated scene.
#[derive(Debug, Serialize)]
struct Episode {
    seed: u64,
    success: bool,
    reasons: Vec<String>,
    med_cm: f64,
    /// Wall time of the predict call (ms), model loaded (the first call includes loading);
    /// with --from-prompt, segmentation included.
    latency_ms: f64,
    scene_psnr_db: Option<f64>,
    objects: Vec<ObjectEstimate>,
    timings_ms: Map<String, Value>,
    /// What the segmenter found (--from-prompt).
    #[serde(skip_serializing_if = "Option::is_none")]
    segmentation: Option<SegmentDocument>,
}

impl Episode {
    /// An episode that failed before a trajectory existed (the segmenter found no usable
    /// objects, or the model could not take the scene); `reason` says which.
    fn unpredicted(seed: u64, reason: String, latency_ms: f64) -> Self {
        Episode {
            seed,
            success: false,
            reasons: vec![reason],
            med_cm: f64::NAN,
            latency_ms,
            scene_psnr_db: None,
            objects: Vec::new(),
            timings_ms: Map::new(),
            segmentation: None,
        }
    }
}

#[derive(Debug, Serialize)]
struct EvalSummary {
    model: String,
    task: String,
    episodes: usize,
    seed_start: u64,
    success_rate: f64,
    /// 95% Wilson score interval of the success rate, [low, high]: how far the rate of
    /// this many scenes can be trusted (45 of 50 is 0.79..0.96).
    success_interval_95: [f64; 2],
    med_cm: f64,
    /// Over every episode but the first (which loads the model).
    latency_ms_p50: f64,
    latency_ms_p95: f64,
    scene_psnr_db_mean: f64,
    mask_iou_mean: f64,
    wall_time_s: f64,
    per_episode: Vec<Episode>,
}

/// The 95% Wilson score interval [low, high] of a success rate of `successes` out of
/// `trials` (both bounds within 0..=1; [0, 1] for no trials). Unlike the normal
/// approximation it stays inside 0..=1 and keeps a width at 50 of 50.
fn wilson_interval_95(successes: usize, trials: usize) -> [f64; 2] {
    if trials == 0 {
        return [0.0, 1.0];
    }
    const Z: f64 = 1.959_964;
    let n = trials as f64;
    let p = successes as f64 / n;
    let centre = p + Z * Z / (2.0 * n);
    let spread = Z * (p * (1.0 - p) / n + Z * Z / (4.0 * n * n)).sqrt();
    let scale = 1.0 + Z * Z / n;
    [((centre - spread) / scale).max(0.0), ((centre + spread) / scale).min(1.0)]
}

/// The q-quantile (0..=1) of `values` by linear interpolation; NaN when empty.
fn quantile(values: &[f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let position = q * (sorted.len() - 1) as f64;
    let (low, high) = (position.floor() as usize, position.ceil() as usize);
    sorted[low] + (sorted[high] - sorted[low]) * (position - low as f64)
}

/// Mean of the finite values (an episode the segmenter could not ground has no MED); NaN
/// when there are none.
fn mean(values: impl Iterator<Item = f64>) -> f64 {
    let (sum, count) = values.filter(|v| v.is_finite()).fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    if count == 0 {
        f64::NAN
    } else {
        sum / count as f64
    }
}

pub fn eval(args: EvalArgs) -> Result<(), Failure> {
    let (last, scenes) = if args.validation {
        (validation_seed_range(args.seed_start, args.episodes)?, "validation")
    } else {
        (heldout_seed_range(args.seed_start, args.episodes)?, "held-out")
    };
    let model_task = model_task(&args.model)?;
    if model_task != args.task {
        return Err(Failure::BadInput(format!(
            "the model at {} was trained on {model_task}, not {}",
            args.model.display(),
            args.task
        )));
    }
    let started = Instant::now();
    let bridge = Bridge::start_default()?;
    let control_hz = bridge.sim_control_hz()?;
    let scratch = tempfile::tempdir().map_err(|err| {
        Failure::Environment(format!("cannot create a temporary directory: {err}"))
    })?;
    let mut episodes = Vec::new();
    for (index, seed) in (args.seed_start..=last).enumerate() {
        let scene_dir = scratch.path().join(format!("scene-{seed}"));
        let scene = bridge.sim_render(&args.task, seed, &scene_dir)?;
        let image = read_bytes(&scene_dir.join("image.png"), "rendered image")?;
        let call = Instant::now();
        let (masks, objects, segmentation) = if args.from_prompt {
            // A prompt the segmenter cannot ground in the image is a failed episode.
            match run_segmenter(bridge, image.clone(), &scene.prompt, &args.segmenter, Some(&args.task), false) {
                Ok(found) => (found.labels_png, found.slot_names, Some(found.document)),
                Err(Failure::BadInput(message)) => {
                    let episode = Episode::unpredicted(seed, format!("not segmented: {message}"), call.elapsed().as_secs_f64() * 1e3);
                    eprintln!("[{}/{}] seed {seed}: FAIL ({})", index + 1, args.episodes, episode.reasons.join("; "));
                    episodes.push(episode);
                    continue;
                }
                Err(other) => return Err(other),
            }
        } else {
            (read_bytes(&scene_dir.join("masks.png"), "rendered masks")?, scene.objects.clone(), None)
        };
        // A scene the model cannot take (e.g. fewer objects than every training scene had)
        // is a failed episode, not a failed evaluation.
        let prediction = match bridge.core_predict(&args.model, image, masks, objects) {
            Ok(prediction) => prediction,
            Err(BridgeError::InvalidInput(message)) => {
                let episode = Episode::unpredicted(seed, format!("not predicted: {message}"), call.elapsed().as_secs_f64() * 1e3);
                eprintln!("[{}/{}] seed {seed}: FAIL ({})", index + 1, args.episodes, episode.reasons.join("; "));
                episodes.push(episode);
                continue;
            }
            Err(other) => return Err(other.into()),
        };
        let latency_ms = call.elapsed().as_secs_f64() * 1e3;
        let predicted = resample(
            &trajectory_of(&prediction)?,
            ResampleTarget::Fps(control_hz),
        )?;
        // A trajectory the simulator refuses (a frame outside the workspace) is a failed
        // episode, not a failed evaluation.
        let (success, reasons) = match bridge.sim_execute(&args.task, seed, predicted.to_arrays()) {
            Ok(verdict) => (verdict.success, verdict.reasons),
            Err(BridgeError::InvalidInput(message)) => {
                (false, vec![format!("not executed: {message}")])
            }
            Err(other) => return Err(other.into()),
        };
        let (expert, _) = bridge.sim_expert(&args.task, seed)?;
        let expert = Trajectory::from_arrays(&expert, Map::new()).map_err(|err| {
            Failure::Environment(format!(
                "the {} expert produced an invalid trajectory: {err}",
                args.task
            ))
        })?;
        let med_cm =
            mean_euclidean_distance_cm(&predicted, &expert).map_err(Failure::Environment)?;
        episodes.push(Episode {
            seed,
            success,
            reasons,
            med_cm,
            latency_ms,
            scene_psnr_db: prediction.scene_psnr_db,
            objects: prediction.objects,
            timings_ms: prediction.timings_ms,
            segmentation,
        });
        let successes = episodes.iter().filter(|e| e.success).count();
        let episode = episodes.last().expect("just pushed");
        eprintln!(
            "[{}/{}] seed {seed}: {} MED {:.2} cm, {:.0} ms{}  (success so far {successes}/{})",
            index + 1,
            args.episodes,
            if episode.success { "success" } else { "FAIL" },
            episode.med_cm,
            episode.latency_ms,
            if episode.success {
                String::new()
            } else {
                format!(" ({})", episode.reasons.join("; "))
            },
            episodes.len()
        );
    }
    let warm: Vec<f64> = episodes
        .iter()
        .skip(usize::from(episodes.len() > 1))
        .map(|e| e.latency_ms)
        .collect();
    let ious = episodes
        .iter()
        .flat_map(|e| e.objects.iter().filter_map(|o| o.mask_iou));
    let successes = episodes.iter().filter(|e| e.success).count();
    let summary = EvalSummary {
        model: args.model.display().to_string(),
        task: args.task.clone(),
        episodes: episodes.len(),
        seed_start: args.seed_start,
        success_rate: successes as f64 / episodes.len() as f64,
        success_interval_95: wilson_interval_95(successes, episodes.len()),
        med_cm: mean(episodes.iter().map(|e| e.med_cm)),
        latency_ms_p50: quantile(&warm, 0.5),
        latency_ms_p95: quantile(&warm, 0.95),
        scene_psnr_db_mean: mean(episodes.iter().filter_map(|e| e.scene_psnr_db)),
        mask_iou_mean: mean(ious),
        wall_time_s: started.elapsed().as_secs_f64(),
        per_episode: episodes,
    };
    if let Some(path) = &args.json {
        write_atomically(
            path,
            serde_json::to_string_pretty(&summary)
                .expect("summary serialises")
                .as_bytes(),
        )?;
    }
    print_stdout(&format!(
        "{} on {} {scenes} {} scenes (seeds {}..={last}): success {:.2} (95% interval {:.2}-{:.2}), MED {:.2} cm, \
         latency p50 {:.0} ms / p95 {:.0} ms, scene PSNR {:.1} dB, mask IoU {:.2}",
        summary.model,
        summary.episodes,
        summary.task,
        summary.seed_start,
        summary.success_rate,
        summary.success_interval_95[0],
        summary.success_interval_95[1],
        summary.med_cm,
        summary.latency_ms_p50,
        summary.latency_ms_p95,
        summary.scene_psnr_db_mean,
        summary.mask_iou_mean
    ))
}

#[cfg(test)]
mod tests {
    use super::{FIRST_HELDOUT_SEED, heldout_seed_range, quantile, validation_seed_range, wilson_interval_95};

    #[test]
    fn success_intervals_bracket_the_rate_and_narrow_with_more_scenes() {
        let at_the_line = wilson_interval_95(45, 50);
        assert!((at_the_line[0] - 0.786).abs() < 1e-3 && (at_the_line[1] - 0.957).abs() < 1e-3, "{at_the_line:?}");
        let same_rate_more_scenes = wilson_interval_95(270, 300);
        assert!(same_rate_more_scenes[0] > at_the_line[0] && same_rate_more_scenes[1] < at_the_line[1]);
        // Every success: the upper bound is 1, the lower one is not.
        let all = wilson_interval_95(50, 50);
        assert!((all[1] - 1.0).abs() < 1e-9 && (all[0] - 0.929).abs() < 1e-3, "{all:?}");
        assert_eq!(wilson_interval_95(0, 0), [0.0, 1.0]);
    }

    #[test]
    fn validation_and_held_out_seed_ranges_do_not_overlap() {
        assert_eq!(validation_seed_range(500_000, 80).unwrap(), 500_079);
        assert_eq!(validation_seed_range(999_990, 10).unwrap(), 999_999);
        assert!(validation_seed_range(499_999, 1).is_err()); // too close to the demonstrations
        assert!(validation_seed_range(999_999, 2).is_err()); // runs into the held-out seeds
        assert!(validation_seed_range(FIRST_HELDOUT_SEED, 1).is_err());
        assert!(heldout_seed_range(999_999, 1).is_err());
        assert_eq!(heldout_seed_range(FIRST_HELDOUT_SEED, 50).unwrap(), FIRST_HELDOUT_SEED + 49);
    }

    #[test]
    fn quantiles_interpolate() {
        let values = [4.0, 1.0, 3.0, 2.0];
        assert_eq!(quantile(&values, 0.0), 1.0);
        assert_eq!(quantile(&values, 1.0), 4.0);
        assert!((quantile(&values, 0.5) - 2.5).abs() < 1e-12);
        assert!(quantile(&[], 0.5).is_nan());
    }
}
