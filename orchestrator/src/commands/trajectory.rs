//! `cnfmp trajectory inspect | resample | smooth`: trajectory files in, summaries or new
//! trajectory files out. Pure Rust: no Python is started.

use std::path::PathBuf;

use clap::{ArgGroup, Args, Subcommand};

use super::print_stdout;
use crate::failure::Failure;
use crate::files::write_atomically;
use crate::trajectory::resample::{ResampleTarget, resample};
use crate::trajectory::smooth::smooth;
use crate::trajectory::summary::summarize;
use crate::trajectory::Trajectory;

#[derive(Debug, Subcommand)]
pub enum TrajectoryCommand {
    /// Validate a trajectory file and print its summary: duration, frames, path length, speeds.
    Inspect {
        /// Trajectory JSON file.
        file: PathBuf,
        /// Print the summary as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Resample onto a new time grid (linear positions and gripper, slerp rotations).
    Resample(ResampleArgs),
    /// Smooth positions and rotations with a Gaussian kernel in time; ends stay fixed.
    Smooth {
        /// Trajectory JSON file.
        file: PathBuf,
        /// Kernel standard deviation in seconds.
        #[arg(long, value_name = "SECONDS")]
        sigma: f64,
        /// Output trajectory file (replaced atomically).
        #[arg(long)]
        out: PathBuf,
    },
}

#[derive(Debug, Args)]
#[command(group(ArgGroup::new("grid").required(true).args(["fps", "steps"])))]
pub struct ResampleArgs {
    /// Trajectory JSON file.
    file: PathBuf,
    /// New rate in frames per second.
    #[arg(long)]
    fps: Option<f64>,
    /// New number of evenly spaced frames (first and last kept).
    #[arg(long)]
    steps: Option<usize>,
    /// Output trajectory file (replaced atomically).
    #[arg(long)]
    out: PathBuf,
}

pub fn run(command: TrajectoryCommand) -> Result<(), Failure> {
    match command {
        TrajectoryCommand::Inspect { file, json } => {
            let summary = summarize(&Trajectory::load(&file)?);
            if json {
                print_stdout(&serde_json::to_string_pretty(&summary).expect("summary serialises"))?;
            } else {
                print_stdout(&format!("{}\n{summary}", file.display()))?;
            }
        }
        TrajectoryCommand::Resample(args) => {
            let target = match (args.fps, args.steps) {
                (Some(fps), _) => ResampleTarget::Fps(fps),
                (_, Some(steps)) => ResampleTarget::Steps(steps),
                (None, None) => unreachable!("clap requires --fps or --steps"),
            };
            let input = Trajectory::load(&args.file)?;
            let output = resample(&input, target)?;
            write_atomically(&args.out, output.to_json_string().as_bytes())?;
            eprintln!("{}: {} frames -> {}: {} frames at {} Hz", args.file.display(), input.frames.len(), args.out.display(), output.frames.len(), output.fps);
        }
        TrajectoryCommand::Smooth { file, sigma, out } => {
            let output = smooth(&Trajectory::load(&file)?, sigma)?;
            write_atomically(&out, output.to_json_string().as_bytes())?;
            eprintln!("{}: smoothed (sigma {sigma} s) -> {}", file.display(), out.display());
        }
    }
    Ok(())
}
