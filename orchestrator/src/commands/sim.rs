//! `cnfmp sim tasks | render | expert | execute`: the MuJoCo benchmark from the command line.

use std::path::PathBuf;

use clap::{Args, Subcommand};
use segmenter_bridge::Bridge;
use serde_json::{Map, Value};

use super::print_stdout;
use crate::failure::Failure;
use crate::files::write_atomically;
use crate::trajectory::Trajectory;
use crate::trajectory::resample::{ResampleTarget, resample};

#[derive(Debug, Subcommand)]
pub enum SimCommand {
    /// List the benchmark tasks.
    Tasks,
    /// Render the camera's view of the scene at the episode start: image.png, masks.png,
    /// objects.json (the inputs of `cnfmp predict`).
    Render {
        #[command(flatten)]
        scene: SceneArgs,
        /// Output directory (must not exist, or be empty).
        #[arg(long)]
        out: PathBuf,
        /// Also write the scene's depth scan from the four fixed cameras (front, left, right,
        /// top) into OUT/scan: per view RGB, 16-bit depth in millimetres and label map
        /// PNGs, and cameras.json with intrinsics and world-from-camera poses (OpenCV axes).
        #[arg(long)]
        scan: bool,
    },
    /// Write the scripted expert's trajectory for the scene.
    Expert {
        #[command(flatten)]
        scene: SceneArgs,
        /// Output trajectory JSON (replaced atomically).
        #[arg(long)]
        out: PathBuf,
    },
    /// Execute a trajectory in the scene by physics and print the judge's verdict as JSON
    /// (exit 0 whether it succeeded or not).
    Execute {
        #[command(flatten)]
        scene: SceneArgs,
        /// Trajectory JSON; resampled to the simulator's control rate before execution.
        #[arg(long)]
        trajectory: PathBuf,
    },
}

/// Which scene: a scene is fully determined by (task, seed).
#[derive(Debug, Args)]
pub struct SceneArgs {
    /// Task name (see `cnfmp sim tasks`).
    #[arg(long)]
    task: String,
    /// Scene seed; training seeds are 0..=999999, held-out seeds 1000000..=1999999.
    #[arg(long)]
    seed: u64,
}

pub fn run(command: SimCommand) -> Result<(), Failure> {
    match command {
        SimCommand::Tasks => {
            let tasks = Bridge::start_default()?.sim_tasks()?;
            let lines: Vec<String> = tasks.iter().map(|task| format!("{:<22} {}", task.name, task.description)).collect();
            print_stdout(&lines.join("\n"))?;
        }
        SimCommand::Render { scene, out, scan } => {
            let info = Bridge::start_default()?.sim_render(&scene.task, scene.seed, &out, scan)?;
            eprintln!(
                "{}: {} objects ({}), prompt: {}{}",
                out.display(),
                info.objects.len(),
                info.objects.join(", "),
                info.prompt,
                if scan { "; scan of 4 views in scan/" } else { "" }
            );
        }
        SimCommand::Expert { scene, out } => {
            let (arrays, prompt) = Bridge::start_default()?.sim_expert(&scene.task, scene.seed)?;
            let mut metadata = Map::new();
            metadata.insert("task".into(), Value::from(scene.task.clone()));
            metadata.insert("seed".into(), Value::from(scene.seed));
            metadata.insert("prompt".into(), Value::from(prompt));
            let trajectory = Trajectory::from_arrays(&arrays, metadata)
                .map_err(|err| Failure::Environment(format!("the {} expert produced an invalid trajectory: {err}", scene.task)))?;
            write_atomically(&out, trajectory.to_json_string().as_bytes())?;
            eprintln!("{}: {} frames at {} Hz, {:.2} s", out.display(), trajectory.frames.len(), trajectory.fps, trajectory.duration());
        }
        SimCommand::Execute { scene, trajectory } => {
            // Validate the file before paying for the interpreter's start-up.
            let input = Trajectory::load(&trajectory)?;
            let bridge = Bridge::start_default()?;
            let control = resample(&input, ResampleTarget::Fps(bridge.sim_control_hz()?))?;
            let report = bridge.sim_execute(&scene.task, scene.seed, control.to_arrays())?;
            print_stdout(&serde_json::to_string_pretty(&report).expect("report serialises"))?;
        }
    }
    Ok(())
}
