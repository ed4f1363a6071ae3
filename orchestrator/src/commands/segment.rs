//! `cnfmp segment` and `cnfmp segmenter train | eval`: prompt -> coarse object masks from the
//! command line, and the film backend's training and held-out evaluation.
//!
//! The numerics run in Python (`cnfmp.segmenter`) through the bridge; this module checks
//! arguments before the interpreter starts and writes outputs atomically.

use std::fs;
use std::path::{Path, PathBuf};

use clap::{Args, Subcommand};
use segmenter_bridge::{Bridge, SegmenterTrainRequest};

use crate::seeds::{first_heldout_seed, heldout_seed_range};
use super::shared::command_line;
use crate::model_dir::check_training_outputs;
use crate::segmentation::{BackendArgs, describe, run_segmenter};
use super::print_stdout;
use crate::failure::Failure;
use crate::files::{write_atomically, write_directory_atomically};

#[derive(Debug, Args)]
pub struct SegmentArgs {
    /// Scene image (PNG or JPEG).
    #[arg(long)]
    image: PathBuf,
    /// What to find, e.g. "put the red ball in the box".
    #[arg(long)]
    prompt: String,
    /// Output directory (created; must not exist or be empty): segmentation.json, masks.png
    /// (label map) + objects.json (what `cnfmp predict --masks/--objects` reads),
    /// mask_<k>.png per phrase, overlay.png.
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
    let image = read_image(&args.image)?;
    let bridge = Bridge::start_default()?;
    let result = run_segmenter(bridge, image, &args.prompt, &args.backend, None, true)?;
    let document = serde_json::to_string_pretty(&result.document).expect("segmentation serialises");
    let objects = serde_json::json!({"prompt": args.prompt, "objects": result.slot_names});
    let mut files = vec![
        ("segmentation.json".to_owned(), format!("{document}\n").into_bytes()),
        ("masks.png".to_owned(), result.labels_png.clone()),
        ("objects.json".to_owned(), format!("{}\n", serde_json::to_string_pretty(&objects).expect("serialises")).into_bytes()),
        ("overlay.png".to_owned(), result.overlay_png.clone()),
    ];
    for (k, mask) in result.mask_pngs.iter().enumerate() {
        files.push((format!("mask_{}.png", k + 1), mask.clone()));
    }
    write_directory_atomically(&args.out, &files)?;
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
