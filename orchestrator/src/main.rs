//! The `cnfmp` command line. Each subcommand lives in `cnfmp::commands`; this file parses
//! arguments and turns failures into a one-line message and an exit code (2 bad input,
//! 1 environment or runtime problem).

use clap::{Parser, Subcommand};

use cnfmp::commands::{self, dataset::DatasetCommand, model, segment::SegmenterCommand, sim::SimCommand, trajectory::TrajectoryCommand};

/// Compositional Neural Field Movement Primitives: scene image + prompt -> robot trajectory.
#[derive(Debug, Parser)]
#[command(name = "cnfmp", version, about, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Check the installation: embedded Python on the venv, torch, MuJoCo rendering, lerobot,
    /// and what a cold start costs.
    Doctor(commands::doctor::DoctorArgs),
    /// Inspect, resample or smooth trajectory JSON files.
    #[command(subcommand)]
    Trajectory(TrajectoryCommand),
    /// The MuJoCo benchmark: render scenes, scripted experts, execute and judge trajectories.
    #[command(subcommand)]
    Sim(SimCommand),
    /// LeRobot datasets: generate demonstrations from the simulator, convert recorded ones, validate.
    #[command(subcommand)]
    Dataset(DatasetCommand),
    /// Train a model (cnfmp, or a baseline with --model-type) on a LeRobot dataset (progress on stderr).
    Train(model::TrainArgs),
    /// Find the objects a prompt names in an image: per-object masks, a label map, an overlay, JSON.
    Segment(commands::segment::SegmentArgs),
    /// The language segmenter's film backend: train it on simulator renders, evaluate any backend.
    #[command(subcommand)]
    Segmenter(SegmenterCommand),
    /// Predict a trajectory from a scene image and its coarse masks, or from a prompt.
    Predict(commands::predict::PredictArgs),
    /// Evaluate a model on held-out simulator scenes: MED against the expert and success by physics.
    Eval(model::EvalArgs),
    /// Serve the HTTP API: POST a scene image and a prompt to /v1/trajectories, get a trajectory.
    Serve(cnfmp::serve::ServeArgs),
    /// Benchmarks that train and evaluate models in one run (the paper's Table I, data efficiency).
    #[command(subcommand)]
    Benchmark(commands::benchmark::BenchmarkCommand),
    /// The main job end to end: serve the shipped models, send a held-out scene and its prompt
    /// over HTTP, execute the returned trajectory in the simulator, write an overlay picture.
    Demo(commands::demo::DemoArgs),
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Doctor(args) => commands::doctor::run(args),
        Command::Trajectory(command) => commands::trajectory::run(command),
        Command::Sim(command) => commands::sim::run(command),
        Command::Dataset(command) => commands::dataset::run(command),
        Command::Train(args) => model::train(args),
        Command::Segment(args) => commands::segment::segment(args),
        Command::Segmenter(command) => commands::segment::run(command),
        Command::Predict(args) => commands::predict::predict(args),
        Command::Eval(args) => model::eval(args),
        Command::Serve(args) => cnfmp::serve::run(args),
        Command::Demo(args) => commands::demo::run(args),
        Command::Benchmark(command) => commands::benchmark::run(command),
    };
    if let Err(failure) = result {
        eprintln!("error: {failure}");
        std::process::exit(failure.exit_code());
    }
}

