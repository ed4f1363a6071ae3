//! `cnfmp predict`: one scene (image + coarse masks, or image + prompt) or many scenes in one
//! warm process (`--scenes`). Inputs are checked before the interpreter starts; outputs are
//! written atomically, one trajectory per scene as soon as it is predicted.

use std::fs;
use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use segmenter_bridge::{Bridge, ObjectEstimate, Prediction, Segmentation};
use serde::Serialize;
use serde_json::{Map, Value};

use super::print_stdout;
use super::scenes::{ObjectNames, SUMMARY_FILE, SceneInput, SceneObjects, list_scenes};
use crate::segmentation::{BackendArgs, describe, prompt_roles, run_segmenter};
use super::shared::trajectory_of;
use crate::files::read_bytes;
use crate::model_dir::model_task;
use super::stats::quantile;
use crate::failure::Failure;
use crate::files::{require_new_or_empty_dir, write_atomically};
use crate::progress::Progress;
use crate::scene_masks::{self, CoarseMasks};
use crate::trajectory::Trajectory;

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

/// A scene's coarse masks, checked against its image.
fn read_masks(image: &[u8], masks: &Path, names: &ObjectNames) -> Result<CoarseMasks, Failure> {
    let size = scene_masks::image_size(image)
        .ok_or_else(|| Failure::BadInput("the image is not in a format we read (PNG, JPEG, BMP, ...)".into()))?;
    let names = match names {
        ObjectNames::File(path) => scene_masks::parse_objects_text(&read_bytes(path, "objects")?)
            .map_err(|err| Failure::BadInput(format!("{}: {err}", path.display())))?,
        ObjectNames::Listed(names) => scene_masks::check_names(names.clone())
            .map_err(|err| Failure::BadInput(format!("objects: {err}")))?,
    };
    CoarseMasks::from_png(&read_bytes(masks, "masks")?, names, size)
        .map_err(|err| Failure::BadInput(format!("{}: {err}", masks.display())))
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

/// Predicts one scene with the resident model of `task`: masks as given, or the prompt
/// segmented first. Bad input (an unreadable image, masks of another size, a prompt the
/// segmenter cannot ground) is a `Failure::BadInput` naming it.
fn predict_scene(bridge: &Bridge, model: &Path, scene: &SceneInput, backend: &BackendArgs) -> Result<PredictedScene, Failure> {
    let image = read_bytes(&scene.image, "image")?;
    let (prediction, segmentation) = match &scene.objects {
        SceneObjects::Masks { masks, names } => {
            let masks = read_masks(&image, masks, names)?;
            (bridge.core_predict(model, image, masks.png(), masks.objects)?, None)
        }
        SceneObjects::Prompt(prompt) => {
            let roles = prompt_roles(bridge, model)?;
            let found = run_segmenter(bridge, image.clone(), prompt, backend, Some(&roles), false)?;
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
    model_task(&args.model)?; // a directory that is no model is refused before Python starts
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

impl ScenesSummary {
    /// The summary of a run that started at `started` and began predicting at `loop_started`.
    /// The first prediction pays the start-up; the scenes refused before reaching the model
    /// say nothing about its speed.
    fn new(model: &Path, scenes: usize, reports: Vec<SceneReport>, started: Instant, loop_started: Instant) -> Self {
        let latencies: Vec<f64> = reports.iter().filter(|r| r.predicted).map(|r| r.latency_ms).collect();
        let warm = &latencies[usize::from(latencies.len() > 1)..];
        let warm_p50 = quantile(warm, 0.5);
        ScenesSummary {
            model: model.display().to_string(),
            scenes,
            predicted: latencies.len(),
            failed: reports.len() - latencies.len(),
            wall_time_s: started.elapsed().as_secs_f64(),
            startup_s: latencies.first().map_or(f64::NAN, |first| (loop_started - started).as_secs_f64() + (first - warm_p50).max(0.0) / 1e3),
            latency_ms_p50: warm_p50,
            latency_ms_p95: quantile(warm, 0.95),
            per_scene: reports,
        }
    }
}

/// `cnfmp predict --scenes`: every scene of `scenes` in this one process, a trajectory file
/// per scene in `out` as soon as it is predicted. A scene with bad input is reported and
/// skipped; the command then exits with code 2 after the others are done.
fn predict_scenes(model: &Path, scenes: &Path, backend: &BackendArgs, out: &Path) -> Result<(), Failure> {
    let started = Instant::now();
    let scenes = list_scenes(scenes)?;
    model_task(model)?;
    require_new_or_empty_dir(out)?;
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
    let summary = ScenesSummary::new(model, scenes.len(), reports, started, loop_started);
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
