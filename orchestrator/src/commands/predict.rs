//! `cnfmp predict`: one scene (image + coarse masks, or image + prompt) or many scenes in one
//! warm process (`--scenes`). Inputs are checked before the interpreter starts; outputs are
//! written atomically, one trajectory per scene as soon as it is predicted.

use std::fs;
use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use segmenter_bridge::{Bridge, ObjectEstimate, Prediction, ScanLabelling, Segmentation};
use serde::Serialize;
use serde_json::{Map, Value};

use super::scenes::{BatchTimings, Needs, ObjectNames, SUMMARY_FILE, SceneInput, SceneObjects, end_batch, for_each_scene, list_scenes};
use crate::segmentation::{BackendArgs, describe, prompt_roles, run_segmenter};
use super::shared::trajectory_of;
use crate::files::read_bytes;
use crate::model_dir::{load_model, model_task};
use crate::failure::Failure;
use crate::files::{require_new_or_empty_dir, write_atomically};
use crate::scene_masks::{self, CoarseMasks};
use crate::trajectory::joints::Predicted;

#[derive(Debug, Args)]
pub struct PredictArgs {
    /// Model directory written by `cnfmp train`.
    #[arg(long)]
    model: PathBuf,
    /// Scene image (PNG or JPEG).
    #[arg(long, required_unless_present_any = ["scenes", "scan"])]
    image: Option<PathBuf>,
    /// A scan instead of an image, for a model that takes scans (cnfmp-3d): a directory with
    /// cameras.json (intrinsics and world-from-camera poses, OpenCV axes) and per view a depth
    /// map (16-bit PNG in millimetres or .npy in metres) and a label map (8-bit, 0 background,
    /// k the k-th object), as `cnfmp sim render --scan` writes it; or a labelled point cloud
    /// with its sensor origins (.npz: points, labels, origins, view; .ply: vertex x y z label
    /// view and an origin element), each origin then seen as a virtual depth view.
    /// With --prompt, the label maps are the segmenter's on the views' RGB images instead.
    #[arg(long, conflicts_with_all = ["image", "masks", "objects", "scenes"])]
    scan: Option<PathBuf>,
    /// With --scan: also write a picture (PNG) of the scan's points beside the reconstructed
    /// surface (marching cubes of the model's occupancy, coloured by object), with the path.
    #[arg(long, requires = "scan")]
    figure: Option<PathBuf>,
    /// Coarse masks: an 8-bit label map of the image's size (0 background, k the k-th object).
    /// Without masks, --prompt is segmented instead.
    #[arg(long, requires = "objects", conflicts_with = "prompt", required_unless_present_any = ["prompt", "scenes", "scan"])]
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
    trajectory: Predicted,
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
        trajectory.metadata_mut().insert("segmentation".into(), document);
    }
    Ok(PredictedScene { trajectory, prediction, segmentation })
}

/// The model's own time for a prediction (ms; NaN when it reports none).
fn inference_ms(prediction: &Prediction) -> f64 {
    prediction.timings_ms.get("total").and_then(Value::as_f64).unwrap_or(f64::NAN)
}

pub fn predict(args: PredictArgs) -> Result<(), Failure> {
    if let Some(scan) = &args.scan {
        let labelling = args.prompt.map(|prompt| ScanLabelling {
            prompt,
            backend: args.segmenter.backend.clone(),
            weights: args.segmenter.weights.clone(),
        });
        return predict_scan(&args.model, scan, args.figure.as_deref(), labelling, &args.out);
    }
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
        done.trajectory.frame_count(),
        done.trajectory.fps(),
        done.trajectory.duration(),
        describe_objects(&done.prediction.objects),
        inference_ms(&done.prediction)
    );
    Ok(())
}

/// `cnfmp predict --scan`: one scan with a model that takes scans.
fn predict_scan(model: &Path, scan: &Path, figure: Option<&Path>, labelling: Option<ScanLabelling>, out: &Path) -> Result<(), Failure> {
    model_task(model)?;
    let cloud = scan.is_file() && scan.extension().is_some_and(|ext| ext == "npz" || ext == "ply");
    if !cloud && !scan.join("cameras.json").is_file() {
        return Err(Failure::BadInput(format!(
            "{} is not a scan: neither a directory with cameras.json nor a point cloud (.npz, .ply)",
            scan.display()
        )));
    }
    let bridge = Bridge::start_default()?;
    if !load_model(bridge, model)?.takes_scans() {
        return Err(Failure::BadInput(format!(
            "the model at {} predicts from an image and masks (--image, --masks), not from a scan",
            model.display()
        )));
    }
    let prediction = bridge.core_predict_scan(model, scan, figure, labelling)?;
    let trajectory = trajectory_of(&prediction)?;
    write_atomically(out, trajectory.to_json_string().as_bytes())?;
    let objects: Vec<String> = prediction.objects.iter().map(|o| o.name.clone()).collect();
    eprintln!(
        "{}: {} frames at {} Hz, {:.2} s; objects: {}; inference {:.0} ms",
        out.display(),
        trajectory.frame_count(),
        trajectory.fps(),
        trajectory.duration(),
        objects.join(", "),
        inference_ms(&prediction)
    );
    if let Some(figure) = figure {
        eprintln!("figure: {}", figure.display());
    }
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
    #[serde(flatten)]
    timings: BatchTimings,
    per_scene: Vec<SceneReport>,
}

/// `cnfmp predict --scenes`: every scene of `scenes` in this one process, a trajectory file
/// per scene in `out` as soon as it is predicted. A scene with bad input is reported and
/// skipped; the command then exits with code 2 after the others are done.
fn predict_scenes(model: &Path, scenes: &Path, backend: &BackendArgs, out: &Path) -> Result<(), Failure> {
    let started = Instant::now();
    let scenes = list_scenes(scenes, Needs::MasksOrPrompt)?;
    model_task(model)?;
    require_new_or_empty_dir(out)?;
    let bridge = Bridge::start_default()?;
    load_model(bridge, model)?;
    fs::create_dir_all(out).map_err(|err| Failure::BadInput(format!("cannot create {}: {err}", out.display())))?;
    let loop_started = Instant::now();
    let (outcomes, outcome) = for_each_scene("predict", "not predicted", &scenes, |scene| {
        let done = predict_scene(bridge, model, scene, backend)?;
        write_atomically(&out.join(format!("{}.json", scene.name)), done.trajectory.to_json_string().as_bytes())?;
        Ok(done)
    });
    let latencies: Vec<f64> = outcomes.iter().filter(|o| o.result.is_ok()).map(|o| o.latency_ms).collect();
    let timings = BatchTimings::new(&latencies, started, loop_started);
    let reports: Vec<SceneReport> = outcomes
        .into_iter()
        .map(|o| {
            let name = o.scene.name.clone();
            match o.result {
                Ok(done) => SceneReport {
                    name,
                    predicted: true,
                    error: None,
                    latency_ms: o.latency_ms,
                    frames: Some(done.trajectory.frame_count()),
                    objects: done.prediction.objects,
                    timings_ms: done.prediction.timings_ms,
                },
                Err(message) => {
                    SceneReport { name, predicted: false, error: Some(message), latency_ms: o.latency_ms, frames: None, objects: Vec::new(), timings_ms: Map::new() }
                }
            }
        })
        .collect();
    let summary = ScenesSummary {
        model: model.display().to_string(),
        scenes: scenes.len(),
        predicted: latencies.len(),
        failed: reports.len() - latencies.len(),
        timings,
        per_scene: reports,
    };
    let text = serde_json::to_string_pretty(&summary).expect("summary serialises");
    write_atomically(&out.join(SUMMARY_FILE), format!("{text}\n").as_bytes())?;
    outcome?;
    let errors: Vec<(&str, Option<&str>)> = summary.per_scene.iter().map(|r| (r.name.as_str(), r.error.as_deref())).collect();
    end_batch(&summary.model, "predicted", "trajectories", out, &summary.timings, &errors)
}
