//! `cnfmp dataset generate | convert | annotate | validate`: LeRobot v3.0 datasets of scripted
//! expert demonstrations, batch conversion of recorded ones, coarse masks for a lab's own
//! recordings, and validation.

use std::path::PathBuf;

use clap::Subcommand;
use segmenter_bridge::{AnnotateRequest, Bridge};

use super::print_stdout;
use crate::convert::{self, ConvertOptions, Source, Target};
use crate::failure::Failure;
use crate::segmentation::BackendArgs;

#[derive(Debug, Subcommand)]
pub enum DatasetCommand {
    /// Simulate expert demonstrations and write them as a LeRobot v3.0 dataset.
    Generate {
        /// Task name (see `cnfmp sim tasks`).
        #[arg(long)]
        task: String,
        /// Number of (successful) episodes.
        #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
        episodes: u64,
        /// First scene seed; episodes use consecutive seeds. Training seeds are
        /// 0..=999999, held-out seeds 1000000..=1999999; a range may not cross the boundary.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Output directory; must not exist (datasets are never overwritten).
        #[arg(long)]
        out: PathBuf,
        /// Simulation worker processes.
        #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=64))]
        workers: u32,
        /// Also record each episode's scan before the expert moves (the four cameras' depth
        /// and label maps with their intrinsics and poses, for 3D models). Default: on for
        /// tasks whose scenes one image does not tell (drawer_place), off otherwise.
        #[arg(long, overrides_with = "no_scan")]
        scan: bool,
        /// Do not record scans, even for a task that records them by default.
        #[arg(long)]
        no_scan: bool,
        /// Record the motion as the joint angles of the simulator's six-joint arm (inverse
        /// kinematics of the expert's tool poses; names shoulder_pan.pos ... wrist_twist.pos,
        /// gripper.pos), as a lab's arm records it, instead of tool poses.
        #[arg(long)]
        joint_space: bool,
    },
    /// Convert recorded demonstrations into a LeRobot v3.0 dataset (or a dataset back into
    /// raw episode folders). Resumable: rerun the same command after an interruption.
    /// The dataset appears at --out only when complete.
    Convert {
        /// Source as FORMAT:PATH: `raw:DIR` (one folder per episode, see the README),
        /// `hdf5:FILE` (robomimic-style), or `lerobot:DIR` (with `--to raw`).
        #[arg(long = "from", value_name = "FORMAT:PATH", value_parser = clap::value_parser!(Source))]
        from: Source,
        /// Output directory; must not exist.
        #[arg(long)]
        out: PathBuf,
        /// Output format.
        #[arg(long, value_enum, default_value_t = Target::Lerobot)]
        to: Target,
        /// Dataset frame rate (Hz); trajectories are resampled to it. Default: the rate
        /// the first episode records (raw: meta.json or trajectory.json; hdf5: control_freq, else 20).
        #[arg(long, value_parser = clap::value_parser!(u32).range(1..=1000))]
        fps: Option<u32>,
        /// Worker threads reading, checking and staging episodes.
        #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=64))]
        workers: u32,
        /// Stop at the first bad episode instead of skipping and reporting it.
        #[arg(long)]
        strict: bool,
    },
    /// Add coarse object masks to a LeRobot dataset recorded without them (e.g. by
    /// lerobot-record): the language segmenter runs on each episode's first frame with the
    /// episode's task prompt (or --objects) and a copy with annotation.masks / .objects /
    /// .scene is written; videos are copied as they are. Writes annotation/contact_sheet.png
    /// inside for review. Resumable; the dataset appears at --out only when complete.
    Annotate {
        /// LeRobot v3.0 dataset without masks.
        #[arg(long)]
        dataset: PathBuf,
        /// Output directory; must not exist.
        #[arg(long)]
        out: PathBuf,
        /// Camera feature to segment (default: the dataset's only camera).
        #[arg(long)]
        camera: Option<String>,
        /// Objects to find in every episode, comma-separated, in slot order, e.g. "red cup, paper"
        /// (default: the objects each episode's task prompt names, the moved one first).
        #[arg(long, value_delimiter = ',')]
        objects: Option<Vec<String>>,
        /// Folder of hand-made label maps episode_<index>.png (8-bit, 0 background, k the
        /// k-th object), used for the episodes that have one.
        #[arg(long)]
        masks_dir: Option<PathBuf>,
        /// Task name the models of this dataset carry (default: the dataset folder's name).
        #[arg(long)]
        task: Option<String>,
        #[command(flatten)]
        segmenter: BackendArgs,
    },
    /// Check a LeRobot dataset: lerobot's own reader, cnfmp's checks of annotations and
    /// trajectories, and lerobot-doctor. Exit 0 when every check passes, 2 otherwise.
    Validate {
        /// Dataset directory.
        dir: PathBuf,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
    },
}

pub fn run(command: DatasetCommand) -> Result<(), Failure> {
    match command {
        DatasetCommand::Generate { task, episodes, seed, out, workers, scan, no_scan, joint_space } => {
            if out.exists() {
                return Err(Failure::BadInput(format!("{} already exists; datasets are never overwritten, choose a new --out", out.display())));
            }
            let scan = if scan { Some(true) } else if no_scan { Some(false) } else { None };
            let report = Bridge::start_default()?.dataset_generate(&task, episodes, seed, &out, workers, scan, joint_space)?;
            print_stdout(&serde_json::to_string_pretty(&report).expect("report serialises"))?;
        }
        DatasetCommand::Convert { from, out, to, fps, workers, strict } => {
            let options = ConvertOptions { source: from, to, out, fps, workers: workers as usize, strict };
            let report = convert::convert(&options)?;
            eprintln!(
                "converted {} of {} episodes ({} frames at {} fps, {} skipped, {} resumed) into {} in {:.1} s",
                report.converted, report.episodes, report.frames, report.fps, report.skipped.len(), report.resumed, report.out, report.seconds
            );
            print_stdout(&serde_json::to_string_pretty(&report).expect("report serialises"))?;
        }
        DatasetCommand::Annotate { dataset, out, camera, objects, masks_dir, task, segmenter } => {
            if out.exists() {
                return Err(Failure::BadInput(format!("{} already exists; datasets are never overwritten, choose a new --out", out.display())));
            }
            if !dataset.is_dir() {
                return Err(Failure::BadInput(format!("dataset {} is not a directory", dataset.display())));
            }
            let request = AnnotateRequest { dataset, out, camera, objects, backend: segmenter.backend, weights: segmenter.weights, masks_dir, task };
            let report = Bridge::start_default()?.annotate_dataset(&request)?;
            eprintln!(
                "annotated {} of {} episodes ({} hand-made, {} skipped, {} resumed) from camera {} into {}; review {}",
                report.annotated, report.episodes, report.hand_made, report.skipped.len(), report.resumed, report.camera, report.out, report.contact_sheet
            );
            for skipped in &report.skipped {
                let missing: Vec<String> = skipped.missing.iter().map(|m| format!("{:?} (score {:.2})", m.phrase, m.score)).collect();
                eprintln!("  episode {} skipped: {} not found in {:?}", skipped.episode, missing.join(", "), skipped.prompt);
            }
            print_stdout(&serde_json::to_string_pretty(&report).expect("report serialises"))?;
        }
        DatasetCommand::Validate { dir, json } => {
            let report = convert::validate::validate(&dir)?;
            if json {
                print_stdout(&serde_json::to_string_pretty(&report).expect("report serialises"))?;
            } else {
                let lines: Vec<String> = report.checks.iter().map(|c| format!("{} {}: {}", if c.ok { "PASS" } else { "FAIL" }, c.name, c.detail)).collect();
                print_stdout(&lines.join("\n"))?;
            }
            let failed: Vec<&str> = report.checks.iter().filter(|c| !c.ok).map(|c| c.name.as_str()).collect();
            if !failed.is_empty() {
                return Err(Failure::BadInput(format!("{} failed {} check(s): {}", dir.display(), failed.len(), failed.join(", "))));
            }
        }
    }
    Ok(())
}
