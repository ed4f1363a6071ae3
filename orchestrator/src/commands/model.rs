//! `cnfmp train | eval`: the compositional NF-MP core from the command line (`predict` has
//! its own module).
//!
//! Training runs in Python (torch) through the bridge; this module validates arguments before
//! the interpreter starts, and runs the evaluation loop: per held-out scene, an episode of
//! [`crate::episode`] with the prediction made in process, then the summary.

use std::path::PathBuf;
use std::time::Instant;

use clap::Args;
use segmenter_bridge::{Bridge, BridgeConfig, BridgeError, ObjectEstimate, SegmentDocument, TrainRequest};
use serde::Serialize;
use serde_json::{Map, Value};

use super::print_stdout;
use super::shared::{command_line, trajectory_of};
use super::stats::{mean, quantile, wilson_interval_95};
use crate::episode::Simulator;
use crate::failure::Failure;
use crate::files::write_atomically;
use crate::helpers::HelperArgs;
use crate::model_dir::{check_training_outputs, load_model, model_task};
use crate::seeds::{first_heldout_seed, heldout_seed_range, validation_seed_range};
use crate::segmentation::{BackendArgs, prompt_roles, run_segmenter};

#[derive(Debug, Args)]
pub struct TrainArgs {
    /// LeRobot v3.0 dataset with coarse masks (from `cnfmp dataset generate`, `convert` or
    /// `annotate`; a lerobot recording gets its masks from `cnfmp dataset annotate`).
    #[arg(long)]
    dataset: PathBuf,
    /// Model directory to create: config.json, model.safetensors, README.md (must not exist).
    #[arg(long)]
    out: PathBuf,
    /// JSON file of config fields (see python/cnfmp/core/configuration_cnfmp.py); defaults
    /// otherwise. Its inference settings (search, refinement) are what the model ships with;
    /// they change predictions, not weights. Repeat to layer files: a later file's fields win.
    #[arg(long = "config")]
    configs: Vec<PathBuf>,
    /// Optimisation steps (overrides the config).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    steps: Option<u64>,
    /// Seed of initialisation and sampling (overrides the config).
    #[arg(long)]
    seed: Option<u64>,
    /// Kind of model: cnfmp (the compositional model), cnfmp-nogate (the ablation without
    /// temporal gating), cnn-cnmp or nfmp (the baselines of the paper's Table I). Default:
    /// the --config file's model_type, else cnfmp.
    // Python checks the name: cnfmp.core.models holds the one registry.
    #[arg(long)]
    model_type: Option<String>,
    /// Camera feature whose first frames are the scenes, e.g. observation.images.front.
    /// Default: the camera the masks were annotated on, else the dataset's only camera.
    #[arg(long)]
    camera: Option<String>,
    /// Feature the trajectories come from: `action` (commanded) or `observation.state` (measured).
    #[arg(long, default_value = "action", value_parser = ["action", "observation.state"])]
    motion_from: String,
    /// Names of the motion vector's dimensions, comma-separated, when the dataset's are
    /// missing or differ: x,y,z plus qw,qx,qy,qz or rx,ry,rz (rotation vector) or
    /// roll,pitch,yaw (fixed-axis x-y-z, rad), plus gripper; e.g. x,y,z,rx,ry,rz,gripper.
    #[arg(long, value_delimiter = ',')]
    motion_names: Option<Vec<String>>,
    /// Keep the demonstrations' timing as recorded instead of aligning their gripper
    /// closing and opening events (piecewise-linear time warps to the median event times).
    #[arg(long)]
    no_time_alignment: bool,
    /// torch threads of the training (>= 1). Default: CNFMP_TORCH_THREADS, else one per core
    /// this process may use (a cup_stacking training on 2 cores: 180 s with 2 threads, about
    /// 300 s with 1). Give 1 to each of trainings run side by side: two trainings of 2 threads
    /// on 2 cores run 1.5x slower than two of 1. The weights depend on it (float rounding);
    /// the model card records it.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=1024))]
    threads: Option<u64>,
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
    /// all validation scenes (500000..=899999) with --validation.
    #[arg(long, default_value_t = first_heldout_seed())]
    seed_start: u64,
    /// Evaluate on validation scenes instead (give --seed-start too): training-range seeds no
    /// demonstration uses (500000..=899999), for choosing a recipe or setting without
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
    #[command(flatten)]
    helpers: HelperArgs,
}

pub fn train(args: TrainArgs) -> Result<(), Failure> {
    if !args.dataset.is_dir() {
        return Err(Failure::BadInput(format!(
            "dataset {} is not a directory",
            args.dataset.display()
        )));
    }
    check_training_outputs(&args.out, &args.configs)?;
    let command = command_line();
    let request = TrainRequest {
        dataset: args.dataset,
        out: args.out,
        configs: args.configs,
        steps: args.steps,
        seed: args.seed,
        model_type: args.model_type,
        command,
        camera: args.camera,
        motion_from: args.motion_from,
        motion_names: args.motion_names,
        align_time: !args.no_time_alignment,
    };
    let cores = std::thread::available_parallelism().map_or(1, usize::from);
    let mut bridge = BridgeConfig::from_env_or_threads(cores)?;
    if let Some(threads) = args.threads {
        bridge.torch_threads = threads as usize;
    }
    let report = Bridge::start(bridge)?.core_train(&request)?;
    print_stdout(&serde_json::to_string_pretty(&report).expect("report serialises"))
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
    args.helpers.start(bridge, "cnfmp eval")?;
    let takes_scans = load_model(bridge, &args.model)?.takes_scans();
    if takes_scans && args.from_prompt {
        return Err(Failure::BadInput(format!(
            "the model at {} predicts from scans; --from-prompt segments one image and is not supported for it",
            args.model.display()
        )));
    }
    let simulator = Simulator::new(bridge)?;
    let roles = if args.from_prompt { Some(prompt_roles(bridge, &args.model)?) } else { None };
    let mut episodes: Vec<Episode> = Vec::new();
    for (index, seed) in (args.seed_start..=last).enumerate() {
        let episode = run_episode(bridge, &simulator, &args, roles.as_deref(), takes_scans, seed)?;
        let successes = episodes.iter().filter(|e| e.success).count() + usize::from(episode.success);
        let outcome = match (episode.success, episode.med_cm.is_finite()) {
            (true, _) => format!("success MED {:.2} cm, {:.0} ms", episode.med_cm, episode.latency_ms),
            (false, true) => format!("FAIL MED {:.2} cm, {:.0} ms ({})", episode.med_cm, episode.latency_ms, episode.reasons.join("; ")),
            (false, false) => format!("FAIL ({})", episode.reasons.join("; ")),
        };
        eprintln!("[{}/{}] seed {seed}: {outcome}  (success so far {successes}/{})", index + 1, args.episodes, index + 1);
        episodes.push(episode);
    }
    let summary = EvalSummary::new(&args, episodes, started);
    if let Some(path) = &args.json {
        write_atomically(path, serde_json::to_string_pretty(&summary).expect("summary serialises").as_bytes())?;
    }
    // A model without an image field (cnfmp-3d, the CNN baseline) has no PSNR or mask IoU.
    let mut fits = String::new();
    if summary.scene_psnr_db_mean.is_finite() {
        fits += &format!(", scene PSNR {:.1} dB", summary.scene_psnr_db_mean);
    }
    if summary.mask_iou_mean.is_finite() {
        fits += &format!(", mask IoU {:.2}", summary.mask_iou_mean);
    }
    print_stdout(&format!(
        "{} on {} {scenes} {} scenes (seeds {}..={last}): success {:.2} (95% interval {:.2}-{:.2}), MED {:.2} cm, \
         latency p50 {:.0} ms / p95 {:.0} ms{fits}",
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
    ))
}

/// One episode of `cnfmp eval`: render, find the objects (the simulator's masks, or the
/// segmenter from the prompt), predict (from the scene's scan for a model that takes
/// scans), execute, compare with the expert. A scene the segmenter cannot ground or the
/// model cannot take is a failed episode, not a failed evaluation.
fn run_episode(
    bridge: &Bridge,
    simulator: &Simulator,
    args: &EvalArgs,
    roles: Option<&[String]>,
    takes_scans: bool,
    seed: u64,
) -> Result<Episode, Failure> {
    let scene = simulator.render(&args.task, seed, takes_scans)?;
    let call = Instant::now();
    let elapsed_ms = || call.elapsed().as_secs_f64() * 1e3;
    let (masks, objects, segmentation) = if let Some(roles) = roles {
        match run_segmenter(bridge, scene.image.clone(), &scene.info.prompt, &args.segmenter, Some(roles), false) {
            Ok(found) => (found.labels_png, found.slot_names, Some(found.document)),
            Err(Failure::BadInput(message)) => return Ok(Episode::unpredicted(seed, format!("not segmented: {message}"), elapsed_ms())),
            Err(other) => return Err(other),
        }
    } else {
        (scene.masks, scene.info.objects, None)
    };
    let predicted = match &scene.scan {
        Some(scan) => bridge.core_predict_scan(&args.model, scan, None, None),
        None => bridge.core_predict(&args.model, scene.image, masks, objects),
    };
    let prediction = match predicted {
        Ok(prediction) => prediction,
        Err(BridgeError::InvalidInput(message)) => return Ok(Episode::unpredicted(seed, format!("not predicted: {message}"), elapsed_ms())),
        Err(other) => return Err(other.into()),
    };
    let latency_ms = elapsed_ms();
    let tool_path = match simulator.tool_path(trajectory_of(&prediction)?) {
        Ok(path) => path,
        Err(Failure::BadInput(message)) => return Ok(Episode::unpredicted(seed, format!("not executable: {message}"), latency_ms)),
        Err(other) => return Err(other),
    };
    let predicted = simulator.at_control_rate(&tool_path)?;
    let verdict = simulator.execute(&args.task, seed, &predicted)?;
    Ok(Episode {
        seed,
        success: verdict.success,
        reasons: verdict.reasons,
        med_cm: simulator.med_cm(&args.task, seed, &predicted)?,
        latency_ms,
        scene_psnr_db: prediction.scene_psnr_db,
        objects: prediction.objects,
        timings_ms: prediction.timings_ms,
        segmentation,
    })
}

impl EvalSummary {
    fn new(args: &EvalArgs, episodes: Vec<Episode>, started: Instant) -> Self {
        let warm: Vec<f64> = episodes.iter().skip(usize::from(episodes.len() > 1)).map(|e| e.latency_ms).collect();
        let ious = episodes.iter().flat_map(|e| e.objects.iter().filter_map(|o| o.mask_iou));
        let successes = episodes.iter().filter(|e| e.success).count();
        EvalSummary {
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
        }
    }
}
