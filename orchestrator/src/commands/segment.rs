//! `cnfmp segment` and `cnfmp segmenter train | eval`: prompt -> coarse object masks from the
//! command line, and the film backend's training and held-out evaluation.
//!
//! The numerics run in Python (`cnfmp.segmenter`) through the bridge; this module checks
//! arguments before the interpreter starts and writes outputs atomically. `--scenes`
//! segments many scenes in one process, the segmenter loaded once.

use std::fs;
use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::{Args, Subcommand};
use segmenter_bridge::{Bridge, SegmenterTrainRequest, Segmentation};
use serde::Serialize;

use crate::seeds::{first_heldout_seed, heldout_seed_range};
use super::shared::command_line;
use crate::model_dir::check_training_outputs;
use crate::segmentation::{BackendArgs, describe, run_segmenter};
use super::print_stdout;
use crate::failure::Failure;
use crate::files::{StagedDirectory, write_atomically, write_directory_atomically};
use super::scenes::{BatchTimings, Needs, SUMMARY_FILE, SceneObjects, end_batch, for_each_scene, list_scenes};

#[derive(Debug, Args)]
pub struct SegmentArgs {
    /// Scene image (PNG or JPEG).
    #[arg(long, required_unless_present = "scenes")]
    image: Option<PathBuf>,
    /// What to find, e.g. "put the red ball in the box".
    #[arg(long, required_unless_present = "scenes")]
    prompt: Option<String>,
    /// Many scenes in one call, the segmenter loaded once: a directory of scene folders (each
    /// with image.png or .jpg and prompt.txt or a "prompt" in objects.json: what `cnfmp sim
    /// render` writes), or a JSON lines file, one scene per line: {"name": ..., "image": PATH,
    /// "prompt": TEXT} (paths relative to the file). --out then holds a folder per scene and
    /// summary.json.
    #[arg(long, conflicts_with_all = ["image", "prompt"])]
    scenes: Option<PathBuf>,
    /// Output directory (created; must not exist or be empty): segmentation.json, masks.png
    /// (label map) + objects.json (what `cnfmp predict --masks/--objects` reads),
    /// mask_<k>.png per phrase, overlay.png; with --scenes, <name>/ holding those per scene
    /// and summary.json.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    backend: BackendArgs,
}

#[derive(Debug, Subcommand)]
pub enum SegmenterCommand {
    /// Train the film segmenter on simulator renders of training seeds (progress on stderr).
    Train(SegmenterTrainArgs),
    /// Mean IoU against the simulator's masks on held-out renders: seen phrasings, unseen
    /// paraphrases, held-out object instances; rejection of absent objects; latency.
    Eval(SegmenterEvalArgs),
}

#[derive(Debug, Args)]
pub struct SegmenterTrainArgs {
    /// Directory to create: config.json, model.safetensors, README.md (must not exist).
    #[arg(long)]
    out: PathBuf,
    /// JSON file of config fields (python/cnfmp/segmenter/configuration_film.py).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Optimisation steps (overrides the config).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    steps: Option<u64>,
    /// Seed (overrides the config).
    #[arg(long)]
    seed: Option<u64>,
    /// Multiply every task's number of training scenes (e.g. 0.05 for a quick run).
    #[arg(long)]
    scenes_scale: Option<f64>,
}

#[derive(Debug, Args)]
pub struct SegmenterEvalArgs {
    /// Task whose held-out scenes are rendered.
    #[arg(long)]
    task: String,
    /// Number of scenes.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=100_000))]
    episodes: u64,
    /// First scene seed; all scenes must be held-out (1000000..=1999999).
    #[arg(long, default_value_t = first_heldout_seed())]
    seed_start: u64,
    #[command(flatten)]
    backend: BackendArgs,
    /// Write the report (with per-scene results) as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
}

pub(crate) fn read_image(path: &Path) -> Result<Vec<u8>, Failure> {
    fs::read(path).map_err(|err| Failure::BadInput(format!("cannot read image {}: {err}", path.display())))
}

pub fn segment(args: SegmentArgs) -> Result<(), Failure> {
    let (image, prompt) = match (args.image, args.prompt, args.scenes) {
        (None, None, Some(scenes)) => return segment_scenes(&scenes, &args.backend, &args.out),
        (Some(image), Some(prompt), None) => (image, prompt),
        _ => return Err(Failure::BadInput("give --image with --prompt, or --scenes".into())),
    };
    let image = read_image(&image)?;
    let bridge = Bridge::start_default()?;
    let result = run_segmenter(bridge, image, &prompt, &args.backend, None, true)?;
    write_directory_atomically(&args.out, &output_files(&prompt, &result))?;
    let d = &result.document;
    eprintln!(
        "{}: {} of {} phrase(s) found by {} in {:.0} ms",
        args.out.display(),
        d.found,
        d.objects.len(),
        d.backend,
        d.timings_ms.get("total").and_then(serde_json::Value::as_f64).unwrap_or(f64::NAN)
    );
    print_stdout(&describe(&result))?;
    if d.nothing_found {
        eprintln!("nothing the prompt names was found in the image");
    }
    Ok(())
}

/// The files of one segmented scene (name, contents): segmentation.json, masks.png,
/// objects.json, overlay.png and mask_<k>.png per phrase.
fn output_files(prompt: &str, result: &Segmentation) -> Vec<(String, Vec<u8>)> {
    let document = serde_json::to_string_pretty(&result.document).expect("segmentation serialises");
    let objects = serde_json::json!({"prompt": prompt, "objects": result.slot_names});
    let mut files = vec![
        ("segmentation.json".to_owned(), format!("{document}\n").into_bytes()),
        ("masks.png".to_owned(), result.labels_png.clone()),
        ("objects.json".to_owned(), format!("{}\n", serde_json::to_string_pretty(&objects).expect("serialises")).into_bytes()),
        ("overlay.png".to_owned(), result.overlay_png.clone()),
    ];
    for (k, mask) in result.mask_pngs.iter().enumerate() {
        files.push((format!("mask_{}.png", k + 1), mask.clone()));
    }
    files
}

/// One scene of a `cnfmp segment --scenes` call, as summary.json reports it.
#[derive(Debug, Serialize)]
struct SegmentedScene {
    name: String,
    ok: bool,
    /// Why the scene has no segmentation (bad input: its image, or its prompt).
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<String>,
    /// How many of the prompt's phrases were found.
    found: u32,
    /// The phrases in label order (objects.json's list); those not found have no pixels.
    objects: Vec<String>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    not_found: Vec<String>,
    /// Wall time of the scene (ms): reading its image, segmenting, writing its files.
    latency_ms: f64,
}

/// summary.json of a `cnfmp segment --scenes` call.
#[derive(Debug, Serialize)]
struct SegmentSummary {
    /// The backend that segmented (what auto resolved to).
    backend: String,
    scenes: usize,
    segmented: usize,
    failed: usize,
    #[serde(flatten)]
    timings: BatchTimings,
    per_scene: Vec<SegmentedScene>,
}

/// `cnfmp segment --scenes`: every scene of `scenes` in this one process, the segmenter loaded
/// (and a bad --backend or --weights refused) before the first. `out` appears complete or not
/// at all: a folder per segmented scene and summary.json. A scene with bad input is reported
/// and skipped; the command then exits with code 2 after the others are done.
fn segment_scenes(scenes: &Path, backend: &BackendArgs, out: &Path) -> Result<(), Failure> {
    let started = Instant::now();
    let scenes = list_scenes(scenes, Needs::Prompt)?;
    let staged = StagedDirectory::new(out)?;
    let bridge = Bridge::start_default()?;
    let backend_name = bridge.segmenter_preload(&backend.backend, backend.weights.clone())?;
    let loop_started = Instant::now();
    let (outcomes, outcome) = for_each_scene("segment", "not segmented", &scenes, |scene| {
        let SceneObjects::Prompt(prompt) = &scene.objects else { unreachable!("scenes listed for segmenting have prompts") };
        let found = run_segmenter(bridge, read_image(&scene.image)?, prompt, backend, None, true)?;
        // A failure to write is not the scene's: it stops the batch (and nothing is left).
        for (name, contents) in output_files(prompt, &found) {
            staged.write(&format!("{}/{name}", scene.name), &contents).map_err(|err| Failure::Environment(err.to_string()))?;
        }
        Ok(found.document)
    });
    outcome?;
    let latencies: Vec<f64> = outcomes.iter().filter(|o| o.result.is_ok()).map(|o| o.latency_ms).collect();
    let timings = BatchTimings::new(&latencies, started, loop_started);
    let reports: Vec<SegmentedScene> = outcomes
        .into_iter()
        .map(|o| {
            let (name, latency_ms) = (o.scene.name.clone(), o.latency_ms);
            match o.result {
                Ok(d) => SegmentedScene {
                    name,
                    ok: true,
                    error: None,
                    found: d.found,
                    not_found: d.objects.iter().filter(|p| !p.found).map(|p| p.phrase.clone()).collect(),
                    objects: d.objects.into_iter().map(|p| p.phrase).collect(),
                    latency_ms,
                },
                Err(message) => {
                    SegmentedScene { name, ok: false, error: Some(message), found: 0, objects: Vec::new(), not_found: Vec::new(), latency_ms }
                }
            }
        })
        .collect();
    let summary = SegmentSummary {
        backend: backend_name,
        scenes: scenes.len(),
        segmented: latencies.len(),
        failed: reports.len() - latencies.len(),
        timings,
        per_scene: reports,
    };
    let text = serde_json::to_string_pretty(&summary).expect("summary serialises");
    staged.write(SUMMARY_FILE, format!("{text}\n").as_bytes())?;
    staged.finish()?;
    let errors: Vec<(&str, Option<&str>)> = summary.per_scene.iter().map(|r| (r.name.as_str(), r.error.as_deref())).collect();
    end_batch(&summary.backend, "segmented", "a folder per scene", out, &summary.timings, &errors)
}

pub fn run(command: SegmenterCommand) -> Result<(), Failure> {
    match command {
        SegmenterCommand::Train(args) => train(args),
        SegmenterCommand::Eval(args) => eval(args),
    }
}

fn train(args: SegmenterTrainArgs) -> Result<(), Failure> {
    check_training_outputs(&args.out, args.config.as_slice())?;
    if let Some(scale) = args.scenes_scale
        && !(scale > 0.0 && scale.is_finite())
    {
        return Err(Failure::BadInput(format!("--scenes-scale must be a positive number, got {scale}")));
    }
    let command = command_line();
    let report = Bridge::start_default()?.segmenter_train(SegmenterTrainRequest {
        out: args.out,
        config: args.config,
        steps: args.steps,
        seed: args.seed,
        scenes_scale: args.scenes_scale,
        command,
    })?;
    print_stdout(&serde_json::to_string_pretty(&report).expect("report serialises"))
}

fn eval(args: SegmenterEvalArgs) -> Result<(), Failure> {
    let last = heldout_seed_range(args.seed_start, args.episodes)?;
    let bridge = Bridge::start_default()?;
    let mut report = bridge.segmenter_eval(&args.task, args.episodes, args.seed_start, &args.backend.backend, args.backend.weights.clone())?;
    if let Some(path) = &args.json {
        write_atomically(path, serde_json::to_string_pretty(&report).expect("report serialises").as_bytes())?;
    }
    if let Some(map) = report.as_object_mut() {
        map.remove("per_scene");
    }
    let iou = |split: &str| report["mean_iou"][split].as_f64().map_or("n/a".to_owned(), |v| format!("{v:.3}"));
    let count = |split: &str| report["count"][split].as_u64().unwrap_or(0);
    print_stdout(&format!(
        "{} on {} held-out {} scenes (seeds {}..={last}): mean IoU seen {} (n={}), paraphrase {} (n={}; as written to the backend {}), \
         held-out instance {} (n={}); \
         rejected: absent objects {:.2}, unknown things {:.2}; latency p50 {:.1} ms / p95 {:.1} ms per scene ({:.1} phrases)",
        report["backend"]["backend"].as_str().unwrap_or("?"),
        args.episodes,
        args.task,
        args.seed_start,
        iou("seen"),
        count("seen"),
        iou("paraphrase"),
        count("paraphrase"),
        iou("paraphrase_raw"),
        iou("heldout_instance"),
        count("heldout_instance"),
        report["rejection_rate"].as_f64().unwrap_or(f64::NAN),
        report["unknown_rejection_rate"].as_f64().unwrap_or(f64::NAN),
        report["latency_ms_p50"].as_f64().unwrap_or(f64::NAN),
        report["latency_ms_p95"].as_f64().unwrap_or(f64::NAN),
        report["phrases_per_scene"].as_f64().unwrap_or(f64::NAN),
    ))
}
