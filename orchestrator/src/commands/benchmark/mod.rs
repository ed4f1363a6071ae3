//! `cnfmp benchmark table1`: the paper's Table I measured on our benchmark in one run (and
//! `cnfmp benchmark data-efficiency`, in `data_efficiency`, on the same job machinery).
//!
//! The run is a small job graph (`plan`): training datasets -> one training per method and
//! task -> one held-out evaluation per model, every job a child `cnfmp` process with its own
//! log, run `--jobs` at a time as soon as what it needs is done (`scheduler`). Finished outputs (a dataset, a model directory, an evaluation JSON) are
//! reused by a rerun unless `--force` or unless something it was made from is redone; a model
//! whose training config changed is retrained and evaluated again (after a code change, use
//! `--force`). The report (`report`: Markdown, CSV, PNG chart) is written from the evaluation
//! JSONs. Held-out scenes are the evaluation's seeds
//! only: no training, model selection or early stopping ever sees them.

mod data_efficiency;
mod plan;
mod report;
mod scheduler;
mod table;

use std::fs;
use std::path::PathBuf;
use std::time::Instant;

use clap::{Args, Subcommand};

use super::print_stdout;
use super::shared::command_line;
use crate::failure::Failure;
use plan::{Settings, plan};
use report::{Report, collect_results, machine_description, today, write_reports};
use scheduler::{State, run_jobs};

#[derive(Debug, Subcommand)]
pub enum BenchmarkCommand {
    /// Reproduce the paper's Table I: train every method on the same demonstrations, evaluate
    /// all on the same held-out scenes, write reports/table1.{md,csv,png}.
    Table1(Table1Args),
    /// Success and MED of the default recipe against the number of demonstrations (5, 10, 20,
    /// 30 by default) on every 2D task: write reports/data_efficiency.{md,csv,png}.
    DataEfficiency(data_efficiency::DataEfficiencyArgs),
}

#[derive(Debug, Args)]
pub struct Table1Args {
    /// Tiny datasets, steps and episode counts: the whole pipeline in a few minutes (a smoke
    /// test of the machinery; its numbers mean nothing).
    #[arg(long)]
    quick: bool,
    /// Directory of the reports (table1.md, table1.csv, table1.png).
    #[arg(long, default_value = "reports")]
    out: PathBuf,
    /// Directory of the datasets, models, evaluations and logs [default: OUT/table1-work, or
    /// OUT/table1-quick-work with --quick].
    #[arg(long)]
    work: Option<PathBuf>,
    /// Jobs (child processes, one torch thread each) run at once [default: the cores available].
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=64))]
    jobs: Option<u32>,
    /// Held-out scenes per task (seeds from 1000000) [default: 50, or 3 with --quick].
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=10_000))]
    episodes: Option<u64>,
    /// Per-task configuration overrides of the cnfmp models: DIR/<task>.json where it exists
    /// (the files the shipped models were trained with).
    #[arg(long, default_value = "configs/core")]
    configs: PathBuf,
    /// Training steps and inference effort of --quick: DIR/<model type>.json, layered over
    /// the per-task files.
    #[arg(long, default_value = "configs/quick")]
    quick_configs: PathBuf,
    /// Redo every job, ignoring finished outputs in the work directory.
    #[arg(long)]
    force: bool,
}

pub fn run(command: BenchmarkCommand) -> Result<(), Failure> {
    match command {
        BenchmarkCommand::Table1(args) => table1(args),
        BenchmarkCommand::DataEfficiency(args) => data_efficiency::run(args),
    }
}

fn table1(args: Table1Args) -> Result<(), Failure> {
    let started = Instant::now();
    let episodes = args.episodes.unwrap_or(if args.quick { 3 } else { 50 });
    let jobs = args.jobs.map_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()), |n| n as usize);
    let work = args.work.clone().unwrap_or_else(|| args.out.join(if args.quick { "table1-quick-work" } else { "table1-work" }));
    // A missing directory would silently train the shipped recipes with default configs.
    if !args.configs.is_dir() {
        return Err(Failure::BadInput(format!(
            "--configs {} is not a directory (run from the repository root, or name the per-task config directory)",
            args.configs.display()
        )));
    }
    if args.quick && !args.quick_configs.is_dir() {
        return Err(Failure::BadInput(format!(
            "--quick-configs {} is not a directory (run from the repository root, or name the quick settings' directory)",
            args.quick_configs.display()
        )));
    }
    for dir in ["datasets", "models", "evals", "logs", "configs", "reports"] {
        fs::create_dir_all(work.join(dir))
            .map_err(|err| Failure::Environment(format!("cannot create {}: {err}", work.join(dir).display())))?;
    }
    let exe = std::env::current_exe().map_err(|err| Failure::Environment(format!("cannot find the cnfmp binary: {err}")))?;
    let settings = Settings { work: &work, configs: &args.configs, quick_configs: &args.quick_configs, quick: args.quick, episodes };
    let plan = plan(&settings)?;
    eprintln!(
        "table1{}: {} jobs ({} datasets, {} trainings, {} evaluations of {episodes} held-out scenes each), {jobs} at a time; work in {}",
        if args.quick { " --quick" } else { "" },
        plan.jobs.len(),
        plan.datasets,
        plan.rows.len(),
        plan.rows.len(),
        work.display()
    );
    let states = run_jobs(&exe, &plan.jobs, jobs, args.force, started)?;
    let reused = states.iter().filter(|s| **s == State::Reused).count();
    let report = Report {
        command: command_line(),
        quick: args.quick,
        episodes,
        jobs,
        reused,
        total_jobs: plan.jobs.len(),
        wall_time_s: started.elapsed().as_secs_f64(),
        machine: machine_description(),
        date: today(),
        results: collect_results(&plan.rows, episodes)?,
    };
    write_reports(&args.out, &report)?;
    print_stdout(&report.markdown_table())?;
    eprintln!(
        "wrote {} ({}, {}), {reused} of {} jobs reused, {:.0} s",
        args.out.join("table1.md").display(),
        args.out.join("table1.csv").display(),
        args.out.join("table1.png").display(),
        plan.jobs.len(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}
