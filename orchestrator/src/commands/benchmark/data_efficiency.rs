//! `cnfmp benchmark data-efficiency`: success and MED of the default recipe against the number
//! of demonstrations, per task, in one run.
//!
//! The job graph is Table I's (`scheduler`): per task and size a dataset of the first N
//! training seeds (so each smaller set is a prefix of the larger ones), one `cnfmp train` with
//! no config (the default recipe a new user gets), one evaluation on the held-out scenes.
//! Finished outputs are reused by a rerun unless `--force`; after a change of the code or the
//! defaults, use `--force`. The report is Markdown, CSV and a PNG chart.

use std::fs;
use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use segmenter_bridge::Bridge;
use serde::Serialize;
use serde_json::Value;

use super::plan::{Datasets, dataset_job, path_arg};
use super::report::{machine_description, read_json, today};
use super::scheduler::{Job, State, run_jobs};
use super::table::TASKS as TABLE1_TASKS;
use crate::commands::print_stdout;
use crate::commands::shared::command_line;
use crate::failure::Failure;
use crate::files::write_atomically;
use crate::seeds::{SEEDS, first_heldout_seed};

/// The tasks measured by default: Table I's, the language task and the task added to check
/// the default recipe on something no model was designed on.
const DEFAULT_EXTRA_TASKS: [&str; 2] = ["language_pick_place", "bar_into_tray"];
const DEFAULT_SIZES: [usize; 4] = [5, 10, 20, 30];

#[derive(Debug, Args)]
pub struct DataEfficiencyArgs {
    /// Tasks to measure [default: wall_avoidance, incline_pick_place, cup_stacking,
    /// cube_stacking, language_pick_place, bar_into_tray].
    #[arg(long, value_delimiter = ',')]
    tasks: Vec<String>,
    /// Training-set sizes (demonstrations, from training seed 0).
    #[arg(long, value_delimiter = ',', default_values_t = DEFAULT_SIZES, value_parser = clap::value_parser!(usize))]
    sizes: Vec<usize>,
    /// Training seed of every model (`cnfmp train --seed`).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Optimisation steps of every training instead of the default's (`cnfmp train --steps`):
    /// for a smoke run of the machinery, whose figures then mean nothing.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    steps: Option<u64>,
    /// Held-out scenes per evaluation (seeds from 1000000).
    #[arg(long, default_value_t = 50, value_parser = clap::value_parser!(u64).range(1..=10_000))]
    episodes: u64,
    /// Directory of the reports (data_efficiency.md, .csv, .png).
    #[arg(long, default_value = "reports")]
    out: PathBuf,
    /// Directory of the datasets, models, evaluations and logs [default: OUT/data-efficiency-work].
    #[arg(long)]
    work: Option<PathBuf>,
    /// Jobs (child processes, one torch thread each) run at once [default: the cores available].
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=64))]
    jobs: Option<u32>,
    /// Redo every job, ignoring finished outputs in the work directory.
    #[arg(long)]
    force: bool,
}

/// One point of the curves: a task at a training-set size, and where its results will be.
struct Point {
    task: String,
    demos: usize,
    evaluation: PathBuf,
    training: PathBuf,
}

#[derive(Debug, Serialize)]
struct Measured {
    task: String,
    demos: usize,
    episodes: u64,
    success_rate: f64,
    med_cm: f64,
    train_seconds: f64,
}

pub fn run(args: DataEfficiencyArgs) -> Result<(), Failure> {
    let started = Instant::now();
    let tasks: Vec<String> = if args.tasks.is_empty() {
        TABLE1_TASKS.iter().chain(&DEFAULT_EXTRA_TASKS).map(|t| (*t).to_owned()).collect()
    } else {
        args.tasks.clone()
    };
    let mut sizes = args.sizes.clone();
    sizes.sort_unstable();
    sizes.dedup();
    if sizes.first() == Some(&0) || sizes.is_empty() {
        return Err(Failure::BadInput("--sizes must be numbers of demonstrations >= 1, e.g. 5,10,20,30".into()));
    }
    let jobs = args.jobs.map_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()), |n| n as usize);
    let work = args.work.clone().unwrap_or_else(|| args.out.join("data-efficiency-work"));
    for dir in ["datasets", "models", "evals", "logs", "reports"] {
        fs::create_dir_all(work.join(dir))
            .map_err(|err| Failure::Environment(format!("cannot create {}: {err}", work.join(dir).display())))?;
    }
    let (plan, points) = plan(&work, &tasks, &sizes, &args);
    eprintln!(
        "data-efficiency: {} tasks x {} sizes ({}), {} jobs, {jobs} at a time, {} held-out scenes per model; work in {}",
        tasks.len(),
        sizes.len(),
        sizes.iter().map(usize::to_string).collect::<Vec<_>>().join(", "),
        plan.len(),
        args.episodes,
        work.display()
    );
    let exe = std::env::current_exe().map_err(|err| Failure::Environment(format!("cannot find the cnfmp binary: {err}")))?;
    let states = run_jobs(&exe, &plan, jobs, args.force, started)?;
    let reused = states.iter().filter(|s| **s == State::Reused).count();
    let measured = points.iter().map(|p| measure(p, args.episodes)).collect::<Result<Vec<_>, _>>()?;
    let report = markdown(&measured, &tasks, &sizes, &args, started.elapsed().as_secs_f64(), reused, plan.len());
    let chart = Bridge::start_default()?.core_curve_chart(&serde_json::to_string(&measured).expect("results serialise"), &tasks, &sizes)?;
    fs::create_dir_all(&args.out).map_err(|err| Failure::Environment(format!("cannot create {}: {err}", args.out.display())))?;
    write_atomically(&args.out.join("data_efficiency.png"), &chart)?;
    write_atomically(&args.out.join("data_efficiency.csv"), csv(&measured).as_bytes())?;
    write_atomically(&args.out.join("data_efficiency.md"), report.as_bytes())?;
    print_stdout(&table(&measured, &tasks, &sizes))?;
    eprintln!(
        "wrote {} (.csv, .png), {reused} of {} jobs reused, {:.0} s",
        args.out.join("data_efficiency.md").display(),
        plan.len(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Dataset, training and evaluation jobs for every task and size.
fn plan(work: &Path, tasks: &[String], sizes: &[usize], args: &DataEfficiencyArgs) -> (Vec<Job>, Vec<Point>) {
    let (seed, episodes) = (args.seed, args.episodes);
    let mut jobs = Vec::new();
    let mut datasets = Datasets::new();
    let mut points = Vec::new();
    for task in tasks {
        for &demos in sizes {
            let dataset = dataset_job(&mut jobs, &mut datasets, work, task, demos, SEEDS.training.start);
            let steps = args.steps.map_or(String::new(), |n| format!("-steps{n}"));
            let name = format!("{task}-{demos}-seed{seed}{steps}");
            let model = work.join("models").join(&name);
            let point = Point {
                task: task.clone(),
                demos,
                evaluation: work.join("evals").join(format!("{name}-{episodes}.json")),
                training: work.join("reports").join(format!("train-{name}.json")),
            };
            jobs.push(Job {
                name: format!("train {name}"),
                args: vec![
                    "train".into(), "--dataset".into(), path_arg(&jobs[dataset].output), "--out".into(), path_arg(&model),
                    "--seed".into(), seed.to_string(),
                ]
                .into_iter()
                .chain(args.steps.into_iter().flat_map(|n| ["--steps".to_owned(), n.to_string()]))
                .collect(),
                output: model.clone(),
                stdout: Some(point.training.clone()),
                log: work.join("logs").join(format!("train-{name}.log")),
                needs: vec![dataset],
            });
            let training = jobs.len() - 1;
            jobs.push(Job {
                name: format!("eval {name}"),
                args: vec![
                    "eval".into(), "--model".into(), path_arg(&model), "--task".into(), task.clone(), "--episodes".into(),
                    episodes.to_string(), "--seed-start".into(), first_heldout_seed().to_string(), "--json".into(),
                    path_arg(&point.evaluation),
                ],
                output: point.evaluation.clone(),
                stdout: None,
                log: work.join("logs").join(format!("eval-{name}.log")),
                needs: vec![training],
            });
            points.push(point);
        }
    }
    (jobs, points)
}

fn measure(point: &Point, episodes: u64) -> Result<Measured, Failure> {
    let number = |value: &Value, key: &str| value.get(key).and_then(Value::as_f64).unwrap_or(f64::NAN);
    let evaluation = read_json(&point.evaluation)?;
    let training = read_json(&point.training).unwrap_or(Value::Null);
    Ok(Measured {
        task: point.task.clone(),
        demos: point.demos,
        episodes,
        success_rate: number(&evaluation, "success_rate"),
        med_cm: number(&evaluation, "med_cm"),
        train_seconds: number(&training, "seconds"),
    })
}

/// Success / MED (cm) per task (rows) and size (columns).
fn table(measured: &[Measured], tasks: &[String], sizes: &[usize]) -> String {
    let mut out = format!(
        "| task | {} |\n|---{}|\n",
        sizes.iter().map(|n| format!("{n} demos")).collect::<Vec<_>>().join(" | "),
        "|---".repeat(sizes.len())
    );
    for task in tasks {
        let cells: Vec<String> = sizes
            .iter()
            .map(|&n| {
                measured
                    .iter()
                    .find(|m| &m.task == task && m.demos == n)
                    .map_or("n/a".into(), |m| format!("{:.2} / {:.2}", m.success_rate, m.med_cm))
            })
            .collect();
        out += &format!("| {task} | {} |\n", cells.join(" | "));
    }
    out
}

fn markdown(
    measured: &[Measured], tasks: &[String], sizes: &[usize], args: &DataEfficiencyArgs, wall_time_s: f64, reused: usize, total: usize,
) -> String {
    let train: f64 = measured.iter().map(|m| m.train_seconds).filter(|s| s.is_finite()).sum();
    format!(
        "# Data efficiency of the default recipe\n\nSuccess rate / MED (cm) on the same {} held-out scenes per task (seeds {}..={}), each model trained by `cnfmp train` with no config (the default recipe{}) and seed {} on the first N demonstrations (training seeds from {}).\n\n{}\n![data efficiency](data_efficiency.png)\n\n## Run\n\n- command: `{}`\n- date: {}\n- machine: {}\n- wall time: {wall_time_s:.0} s, {total} jobs{}; training {train:.0} s in all (one torch thread each)\n",
        args.episodes,
        first_heldout_seed(),
        first_heldout_seed() + args.episodes - 1,
        args.steps.map_or(String::new(), |n| format!(", but {n} steps: a smoke run whose figures mean nothing")),
        args.seed,
        SEEDS.training.start,
        table(measured, tasks, sizes),
        command_line(),
        today(),
        machine_description(),
        if reused > 0 { format!(", {reused} reused from an earlier run (their time is not in this wall time)") } else { String::new() }
    )
}

fn csv(measured: &[Measured]) -> String {
    let mut out = String::from("task,demos,heldout_episodes,success_rate,med_cm,train_seconds\n");
    for m in measured {
        out += &format!("{},{},{},{:.4},{:.4},{:.1}\n", m.task, m.demos, m.episodes, m.success_rate, m.med_cm, m.train_seconds);
    }
    out
}
