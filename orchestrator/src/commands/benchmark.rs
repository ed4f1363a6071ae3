//! `cnfmp benchmark table1`: the paper's Table I measured on our benchmark in one run.
//!
//! The run is a small job graph: training datasets (low and high regimes per task, the wall
//! grid for NFMP) -> one training per method and task -> one held-out evaluation per model,
//! every job a child `cnfmp` process with its own log, run `--jobs` at a time as soon as what
//! it needs is done. Finished outputs (a dataset, a model directory, an evaluation JSON) are
//! reused by a rerun unless `--force` or unless something it was made from is redone; a model
//! whose training config changed is retrained and evaluated again (after a code change, use
//! `--force`). The report (Markdown, CSV, PNG
//! chart) is written from the evaluation JSONs. Held-out scenes are the evaluation's seeds
//! only: no training, model selection or early stopping ever sees them.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use clap::{Args, Subcommand};
use segmenter_bridge::Bridge;
use serde::Serialize;
use serde_json::{Map, Value};

use super::seeds::FIRST_HELDOUT_SEED;
use super::shared::command_line;
use super::print_stdout;
use crate::failure::Failure;
use crate::files::write_atomically;

#[derive(Debug, Subcommand)]
pub enum BenchmarkCommand {
    /// Reproduce the paper's Table I: train every method on the same demonstrations, evaluate
    /// all on the same held-out scenes, write reports/table1.{md,csv,png}.
    Table1(Table1Args),
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
    /// Redo every job, ignoring finished outputs in the work directory.
    #[arg(long)]
    force: bool,
}

pub fn run(command: BenchmarkCommand) -> Result<(), Failure> {
    match command {
        BenchmarkCommand::Table1(args) => table1(args),
    }
}

/// The Table-I tasks, in the paper's column order.
const TASKS: [&str; 4] = ["wall_avoidance", "incline_pick_place", "cup_stacking", "cube_stacking"];
/// Training-set sizes (low, high regime) per task, as in the paper.
const SIZES: [(usize, usize); 4] = [(10, 30), (20, 50), (20, 50), (30, 100)];
/// Sizes of --quick.
const QUICK_SIZES: (usize, usize) = (3, 5);
/// The NFMP grid: training seeds 900000.. of wall_avoidance are a 3x3x3 parameter grid
/// (python/cnfmp/sim/tasks/wall_avoidance.py, GRID_SEEDS).
const GRID_SEED: u64 = 900_000;
const GRID_SIZE: usize = 27;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Regime {
    Low,
    High,
    Grid,
}

/// A row of the table: a model type trained on one regime's demonstrations.
struct Method {
    /// Row label in the paper's wording.
    label: &'static str,
    /// File-name key of the row.
    key: &'static str,
    model_type: &'static str,
    regime: Regime,
    /// Tasks it is evaluated on (the paper reports NFMP on wall avoidance only).
    tasks: &'static [&'static str],
}

const METHODS: [Method; 5] = [
    Method { label: "CNN-CNMP (low)", key: "cnn-cnmp-low", model_type: "cnn-cnmp", regime: Regime::Low, tasks: &TASKS },
    Method { label: "CNN-CNMP (high)", key: "cnn-cnmp-high", model_type: "cnn-cnmp", regime: Regime::High, tasks: &TASKS },
    Method { label: "NFMP (grid)", key: "nfmp-grid", model_type: "nfmp", regime: Regime::Grid, tasks: &["wall_avoidance"] },
    Method { label: "ours without gating (low)", key: "cnfmp-nogate-low", model_type: "cnfmp-nogate", regime: Regime::Low, tasks: &TASKS },
    Method { label: "ours (low)", key: "cnfmp-low", model_type: "cnfmp", regime: Regime::Low, tasks: &TASKS },
];

/// The paper's Table I (MED cm, success), per method row and task; None where not reported.
const PAPER: [[Option<(f64, f64)>; 4]; 5] = [
    [Some((2.66, 0.63)), Some((3.98, 0.11)), Some((9.03, 0.03)), Some((13.44, 0.00))],
    [Some((1.33, 0.97)), Some((2.12, 0.68)), Some((2.81, 0.23)), Some((5.87, 0.00))],
    [Some((0.65, 0.99)), None, None, None],
    [Some((0.66, 1.00)), Some((0.85, 1.00)), Some((1.06, 0.81)), Some((1.39, 0.79))],
    [Some((0.48, 1.00)), Some((0.73, 1.00)), Some((0.60, 1.00)), Some((0.66, 0.97))],
];

/// Training steps and inference effort of --quick, per model type (merged into the configs).
fn quick_overrides(model_type: &str) -> Map<String, Value> {
    let overrides = match model_type {
        "cnfmp" | "cnfmp-nogate" => serde_json::json!({"steps": 40, "motion_refit_steps": 20, "search_candidates": 16,
                                                        "search_starts": 2, "refine_steps": 5}),
        "nfmp" => serde_json::json!({"steps": 40, "inference_steps": 10}),
        _ => serde_json::json!({"steps": 40}),
    };
    overrides.as_object().cloned().unwrap_or_default()
}

/// "a vs b" with two decimals, or as many more (up to four) as it takes for two different
/// values not to read as a tie.
fn versus(a: f64, b: f64) -> String {
    let digits = (2..=4).find(|&d| format!("{a:.d$}") != format!("{b:.d$}")).unwrap_or(4);
    format!("{a:.digits$} vs {b:.digits$}")
}

/// One child process of the run.
struct Job {
    /// What it is, for progress lines ("train cnn-cnmp-low/cube_stacking").
    name: String,
    args: Vec<String>,
    /// What exists once it has succeeded (a directory or a file the child writes atomically).
    output: PathBuf,
    /// Where its stdout goes (kept only on success), if anywhere.
    stdout: Option<PathBuf>,
    log: PathBuf,
    /// Jobs that must succeed first (indices).
    needs: Vec<usize>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Waiting,
    Running,
    Done,
    Reused,
    Failed,
}

/// Dataset jobs by (task, demonstrations, first seed): their index in the plan.
type Datasets = BTreeMap<(String, usize, u64), usize>;

fn table1(args: Table1Args) -> Result<(), Failure> {
    let started = Instant::now();
    let episodes = args.episodes.unwrap_or(if args.quick { 3 } else { 50 });
    let jobs = args.jobs.map_or_else(
        || std::thread::available_parallelism().map_or(1, |n| n.get()),
        |n| n as usize,
    );
    let work = args.work.clone().unwrap_or_else(|| {
        args.out.join(if args.quick { "table1-quick-work" } else { "table1-work" })
    });
    // A missing directory would silently train the shipped recipes with default configs.
    if !args.configs.is_dir() {
        return Err(Failure::BadInput(format!(
            "--configs {} is not a directory (run from the repository root, or name the per-task config directory)",
            args.configs.display()
        )));
    }
    for dir in ["datasets", "models", "evals", "logs", "configs", "reports"] {
        fs::create_dir_all(work.join(dir)).map_err(|err| {
            Failure::Environment(format!("cannot create {}: {err}", work.join(dir).display()))
        })?;
    }
    let exe = std::env::current_exe()
        .map_err(|err| Failure::Environment(format!("cannot find the cnfmp binary: {err}")))?;

    let mut plan: Vec<Job> = Vec::new();
    let mut datasets = Datasets::new();
    let mut rows: Vec<(usize, &str, usize)> = Vec::new(); // (method, task, evaluation job)
    for (m, method) in METHODS.iter().enumerate() {
        for task in method.tasks {
            let t = TASKS.iter().position(|x| x == task).expect("a Table-I task");
            let (count, seed) = match method.regime {
                Regime::Low => (if args.quick { QUICK_SIZES.0 } else { SIZES[t].0 }, 0),
                Regime::High => (if args.quick { QUICK_SIZES.1 } else { SIZES[t].1 }, 0),
                Regime::Grid => (GRID_SIZE, GRID_SEED),
            };
            let dataset = dataset_job(&mut plan, &mut datasets, &work, task, count, seed);
            let model_dir = work.join("models").join(method.key).join(task);
            let (config, names_seed) = write_config(&work, &args, method, task, &model_dir)?;
            let mut train_args = vec![
                "train".into(), "--dataset".into(), path_arg(&plan[dataset].output),
                "--out".into(), path_arg(&model_dir), "--model-type".into(), method.model_type.into(),
            ];
            // Seed 0 unless the recipe names the seed its shipped model was trained with, so
            // that "ours" is the shipped model.
            if !names_seed {
                train_args.extend(["--seed".into(), "0".into()]);
            }
            if let Some(config) = config {
                train_args.extend(["--config".into(), path_arg(&config)]);
            }
            plan.push(Job {
                name: format!("train {}/{task}", method.key),
                args: train_args,
                output: model_dir.clone(),
                stdout: Some(train_report(&work, method, task)),
                log: work.join("logs").join(format!("train-{}-{task}.log", method.key)),
                needs: vec![dataset],
            });
            let trained = plan.len() - 1;
            let eval_json = work.join("evals").join(format!("{}-{task}-{episodes}.json", method.key));
            plan.push(Job {
                name: format!("eval {}/{task}", method.key),
                args: vec![
                    "eval".into(), "--model".into(), path_arg(&model_dir), "--task".into(), (*task).into(),
                    "--episodes".into(), episodes.to_string(), "--seed-start".into(), FIRST_HELDOUT_SEED.to_string(),
                    "--json".into(), path_arg(&eval_json),
                ],
                output: eval_json,
                stdout: None,
                log: work.join("logs").join(format!("eval-{}-{task}.log", method.key)),
                needs: vec![trained],
            });
            rows.push((m, task, plan.len() - 1));
        }
    }

    eprintln!(
        "table1{}: {} jobs ({} datasets, {} trainings, {} evaluations of {episodes} held-out scenes each), {jobs} at a time; work in {}",
        if args.quick { " --quick" } else { "" },
        plan.len(),
        datasets.len(),
        rows.len(),
        rows.len(),
        work.display()
    );
    let states = run_jobs(&exe, &plan, jobs, args.force, started)?;
    let reused = states.iter().filter(|s| **s == State::Reused).count();

    let results = collect_results(&plan, &rows, &work, episodes)?;
    let report = Report {
        command: command_line(),
        quick: args.quick,
        episodes,
        jobs,
        reused,
        total_jobs: plan.len(),
        wall_time_s: started.elapsed().as_secs_f64(),
        machine: machine_description(),
        date: today(),
        results,
    };
    write_reports(&args.out, &report)?;
    print_stdout(&report.markdown_table())?;
    eprintln!(
        "wrote {} ({}, {}), {reused} of {} jobs reused, {:.0} s",
        args.out.join("table1.md").display(),
        args.out.join("table1.csv").display(),
        args.out.join("table1.png").display(),
        plan.len(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

fn path_arg(path: &Path) -> String {
    path.to_string_lossy().into_owned()
}

/// The index of the job generating `count` demonstrations of `task` from `seed` (added to the
/// plan the first time it is asked for).
fn dataset_job(plan: &mut Vec<Job>, datasets: &mut Datasets, work: &Path, task: &str, count: usize, seed: u64) -> usize {
    *datasets.entry((task.to_owned(), count, seed)).or_insert_with(|| {
        let name = if seed == 0 { format!("{task}-{count}") } else { format!("{task}-{count}-from-{seed}") };
        let out = work.join("datasets").join(&name);
        plan.push(Job {
            name: format!("dataset {name}"),
            args: vec![
                "dataset".into(), "generate".into(), "--task".into(), task.into(), "--episodes".into(),
                count.to_string(), "--seed".into(), seed.to_string(), "--out".into(), path_arg(&out),
                "--workers".into(), "1".into(),
            ],
            output: out,
            stdout: None,
            log: work.join("logs").join(format!("dataset-{name}.log")),
            needs: Vec::new(),
        });
        plan.len() - 1
    })
}

/// Where the training of `method` on `task` writes its JSON report (the child's stdout).
fn train_report(work: &Path, method: &Method, task: &str) -> PathBuf {
    work.join("reports").join(format!("train-{}-{task}.json", method.key))
}

/// Writes the training config of `method` on `task` (the task's override file for cnfmp
/// types, then the --quick settings) and returns its path (None when there is nothing to set)
/// and whether it names the training seed.
/// A model already in `model_dir` that was trained with another config is removed, with its
/// training report, so that the run retrains it (and, by `run_jobs`, evaluates it again).
fn write_config(work: &Path, args: &Table1Args, method: &Method, task: &str, model_dir: &Path) -> Result<(Option<PathBuf>, bool), Failure> {
    let mut config = Map::new();
    let task_file = args.configs.join(format!("{task}.json"));
    if method.model_type.starts_with("cnfmp") && task_file.is_file() {
        let text = fs::read_to_string(&task_file)
            .map_err(|err| Failure::BadInput(format!("cannot read {}: {err}", task_file.display())))?;
        match serde_json::from_str::<Value>(&text) {
            Ok(Value::Object(fields)) => config.extend(fields),
            _ => return Err(Failure::BadInput(format!("{} is not a JSON object of config fields", task_file.display()))),
        }
    }
    if args.quick {
        let quick = quick_overrides(method.model_type);
        // The shipped inference settings (set after training) must not undo --quick's effort.
        if let Some(Value::Object(after)) = config.get_mut("after_training") {
            for (name, value) in &quick {
                if after.contains_key(name) {
                    after.insert(name.clone(), value.clone());
                }
            }
        }
        config.extend(quick);
    }
    let names_seed = config.contains_key("seed");
    let path = work.join("configs").join(format!("{}-{task}.json", method.key));
    let text = (!config.is_empty()).then(|| serde_json::to_string_pretty(&Value::Object(config)).expect("config serialises"));
    let recorded = fs::read_to_string(&path).ok();
    if recorded != text && model_dir.exists() {
        // A model trained with another config must not be reused.
        eprintln!("{}/{task}: its training config changed; it will be retrained and evaluated again", method.key);
        remove_output(model_dir)?;
        remove_output(&train_report(work, method, task))?;
    }
    match text {
        Some(text) => {
            write_atomically(&path, text.as_bytes())?;
            Ok((Some(path), names_seed))
        }
        None => {
            remove_output(&path)?;
            Ok((None, names_seed))
        }
    }
}

/// Runs the plan, `parallel` jobs at a time, each as soon as what it needs has succeeded.
/// A job whose output exists is reused (unless `force`, which removes it first). A failed
/// job fails its dependents; the others go on, and the run fails at the end naming them.
fn run_jobs(exe: &Path, plan: &[Job], parallel: usize, force: bool, started: Instant) -> Result<Vec<State>, Failure> {
    let mut states = vec![State::Waiting; plan.len()];
    let mut running: Vec<(usize, Child, Instant)> = Vec::new();
    let mut finished = 0usize;
    let stamp = |started: Instant| format!("{:>5.0}s", started.elapsed().as_secs_f64());
    // A finished output is reused only when everything it was made from was reused too: an
    // evaluation of a model that is being retrained is stale. Jobs need only earlier jobs.
    for (index, job) in plan.iter().enumerate() {
        debug_assert!(job.needs.iter().all(|&n| n < index), "{} needs a later job", job.name);
        let inputs_reused = job.needs.iter().all(|&n| states[n] == State::Reused);
        if !force && inputs_reused && job.output.exists() {
            states[index] = State::Reused;
            finished += 1;
        } else {
            remove_output(&job.output)?;
        }
    }
    if finished > 0 {
        eprintln!("{} reusing {finished} finished job(s) (--force redoes them)", stamp(started));
    }
    loop {
        // Fail the dependents of failed jobs.
        for index in 0..plan.len() {
            if states[index] == State::Waiting && plan[index].needs.iter().any(|&n| states[n] == State::Failed) {
                states[index] = State::Failed;
                finished += 1;
                eprintln!("{} [{finished}/{}] skipped {}: a job it needs failed", stamp(started), plan.len(), plan[index].name);
            }
        }
        while running.len() < parallel {
            let Some(index) = (0..plan.len()).find(|&i| {
                states[i] == State::Waiting && plan[i].needs.iter().all(|&n| matches!(states[n], State::Done | State::Reused))
            }) else {
                break;
            };
            let child = spawn(exe, &plan[index])?;
            states[index] = State::Running;
            eprintln!("{} started {}", stamp(started), plan[index].name);
            running.push((index, child, Instant::now()));
        }
        if running.is_empty() {
            break;
        }
        std::thread::sleep(Duration::from_millis(200));
        let mut still = Vec::new();
        for (index, mut child, since) in running.drain(..) {
            let status = child
                .try_wait()
                .map_err(|err| Failure::Environment(format!("cannot wait for {}: {err}", plan[index].name)))?;
            let Some(status) = status else {
                still.push((index, child, since));
                continue;
            };
            finished += 1;
            let job = &plan[index];
            let kept = job.stdout.as_ref().map_or(Ok(()), |path| keep_stdout(path, status.success()));
            if status.success() && job.output.exists() && kept.is_ok() {
                states[index] = State::Done;
                eprintln!("{} [{finished}/{}] done {} in {:.0} s", stamp(started), plan.len(), job.name, since.elapsed().as_secs_f64());
            } else {
                states[index] = State::Failed;
                eprintln!(
                    "{} [{finished}/{}] FAILED {} ({status}); the end of {}:\n{}",
                    stamp(started),
                    plan.len(),
                    job.name,
                    job.log.display(),
                    log_tail(&job.log)
                );
            }
        }
        running = still;
    }
    let failed: Vec<&str> = (0..plan.len()).filter(|&i| states[i] == State::Failed).map(|i| plan[i].name.as_str()).collect();
    if !failed.is_empty() {
        return Err(Failure::Environment(format!(
            "{} of {} jobs failed or were skipped: {}; see the logs in {}",
            failed.len(),
            plan.len(),
            failed.join(", "),
            plan[0].log.parent().map_or_else(String::new, |p| p.display().to_string())
        )));
    }
    Ok(states)
}

fn spawn(exe: &Path, job: &Job) -> Result<Child, Failure> {
    let open = |path: &Path| {
        fs::File::create(path).map_err(|err| Failure::Environment(format!("cannot create {}: {err}", path.display())))
    };
    let log = open(&job.log)?;
    let stdout = match &job.stdout {
        Some(path) => Stdio::from(open(&partial(path))?),
        None => Stdio::from(log.try_clone().map_err(|err| Failure::Environment(format!("cannot share the log: {err}")))?),
    };
    Command::new(exe)
        .args(&job.args)
        .stdin(Stdio::null())
        .stdout(stdout)
        .stderr(Stdio::from(log))
        // Jobs run side by side, one core each: inference must not start a second thread.
        .env("CNFMP_INFERENCE_THREADS", "1")
        .spawn()
        .map_err(|err| Failure::Environment(format!("cannot start {}: {err}", job.name)))
}

/// Where a job's stdout is written until it has succeeded.
fn partial(path: &Path) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    path.with_file_name(name)
}

/// Moves a finished job's stdout into place, or drops it when the job failed.
fn keep_stdout(path: &Path, success: bool) -> Result<(), Failure> {
    let from = partial(path);
    if success {
        fs::rename(&from, path).map_err(|err| Failure::Environment(format!("cannot write {}: {err}", path.display())))
    } else {
        let _ = fs::remove_file(from);
        Ok(())
    }
}

fn remove_output(path: &Path) -> Result<(), Failure> {
    let removed = if path.is_dir() {
        fs::remove_dir_all(path)
    } else if path.exists() {
        fs::remove_file(path)
    } else {
        Ok(())
    };
    removed.map_err(|err| Failure::Environment(format!("cannot remove the stale {}: {err}", path.display())))
}

/// The last lines of a log, indented.
fn log_tail(path: &Path) -> String {
    let text = fs::read_to_string(path).unwrap_or_default();
    let lines: Vec<&str> = text.lines().collect();
    lines[lines.len().saturating_sub(15)..].iter().map(|l| format!("    {l}")).collect::<Vec<_>>().join("\n")
}

/// One cell of the table, measured.
#[derive(Debug, Clone, Serialize)]
struct Cell {
    method: &'static str,
    model_type: &'static str,
    task: String,
    demos: u64,
    episodes: u64,
    success_rate: f64,
    med_cm: f64,
    latency_ms_p50: f64,
    train_seconds: f64,
    eval_seconds: f64,
    parameters: u64,
}

fn read_json(path: &Path) -> Result<Value, Failure> {
    let text = fs::read_to_string(path).map_err(|err| Failure::Environment(format!("cannot read {}: {err}", path.display())))?;
    serde_json::from_str(&text).map_err(|err| Failure::Environment(format!("{} is not JSON: {err}", path.display())))
}

fn collect_results(plan: &[Job], rows: &[(usize, &str, usize)], work: &Path, episodes: u64) -> Result<Vec<Cell>, Failure> {
    let number = |value: &Value, key: &str| value.get(key).and_then(Value::as_f64).unwrap_or(f64::NAN);
    rows.iter()
        .map(|&(m, task, eval)| {
            let method = &METHODS[m];
            let evaluation = read_json(&plan[eval].output)?;
            let train_path = train_report(work, method, task);
            // A model reused from an earlier run without its report still has a card; its
            // training time is then unknown here.
            let training = read_json(&train_path).unwrap_or(Value::Null);
            Ok(Cell {
                method: method.label,
                model_type: method.model_type,
                task: task.to_owned(),
                demos: training.get("demos").and_then(Value::as_u64).unwrap_or(0),
                episodes,
                success_rate: number(&evaluation, "success_rate"),
                med_cm: number(&evaluation, "med_cm"),
                latency_ms_p50: number(&evaluation, "latency_ms_p50"),
                train_seconds: number(&training, "seconds"),
                eval_seconds: number(&evaluation, "wall_time_s"),
                parameters: training.get("parameters").and_then(Value::as_u64).unwrap_or(0),
            })
        })
        .collect()
}

struct Report {
    command: String,
    quick: bool,
    episodes: u64,
    jobs: usize,
    reused: usize,
    total_jobs: usize,
    wall_time_s: f64,
    machine: String,
    date: String,
    results: Vec<Cell>,
}

impl Report {
    fn cell(&self, method: &Method, task: &str) -> Option<&Cell> {
        self.results.iter().find(|c| c.method == method.label && c.task == task)
    }

    /// MED / success per method and task, in the paper's layout.
    fn markdown_table(&self) -> String {
        let mut out = String::from("| method | wall avoidance | incline pick-place | cup stacking | cube stacking |\n|---|---|---|---|---|\n");
        for method in &METHODS {
            let cells: Vec<String> = TASKS
                .iter()
                .map(|task| self.cell(method, task).map_or("n/a".into(), |c| format!("{:.2} / {:.2}", c.med_cm, c.success_rate)))
                .collect();
            out += &format!("| {} | {} |\n", method.label, cells.join(" | "));
        }
        out
    }

    fn paper_table(&self) -> String {
        let mut out = String::from("| method | wall avoidance | incline pick-place | cup stacking | cube stacking |\n|---|---|---|---|---|\n");
        for (method, paper) in METHODS.iter().zip(PAPER) {
            let cells: Vec<String> = paper.iter().map(|c| c.map_or("n/a".into(), |(med, s)| format!("{med:.2} / {s:.2}"))).collect();
            out += &format!("| {} | {} |\n", method.label, cells.join(" | "));
        }
        out
    }

    /// The claims, each checked on the measured table.
    fn claims(&self) -> Vec<(String, bool)> {
        let [cnn_low, cnn_high, _, nogate, ours] = &METHODS;
        let mut claims = Vec::new();
        for task in TASKS {
            let get = |m: &Method| self.cell(m, task).map_or((f64::NAN, f64::NAN), |c| (c.med_cm, c.success_rate));
            let ((ours_med, ours_success), (low_med, low_success), (high_med, _)) = (get(ours), get(cnn_low), get(cnn_high));
            claims.push((
                format!("{task}: ours (low) beats CNN-CNMP (low) on MED ({} cm) and success ({ours_success:.2} vs {low_success:.2})", versus(ours_med, low_med)),
                ours_med < low_med && ours_success > low_success,
            ));
            claims.push((format!("{task}: ours (low) beats CNN-CNMP (high) on MED ({} cm)", versus(ours_med, high_med)), ours_med < high_med));
            if matches!(task, "cup_stacking" | "cube_stacking") {
                let (nogate_med, nogate_success) = get(nogate);
                claims.push((
                    format!("{task}: ours beats ours without gating (MED {} cm, success {ours_success:.2} vs {nogate_success:.2})", versus(ours_med, nogate_med)),
                    ours_med < nogate_med && ours_success >= nogate_success,
                ));
            }
        }
        claims
    }

    fn markdown(&self) -> String {
        let mut out = format!(
            "# Table I on the cnfmp benchmark{}\n\nMED (cm) / success rate on the same {} held-out scenes per task (seeds {}..={}), every method trained on the same demonstrations (training seeds from 0; low / high regime: {}; NFMP on the 27-scene wall grid, training seeds 900000..900026). Each model is one training run, seeded 0 unless its recipe (configs/core) names the seed of the shipped model.\n\n",
            if self.quick { " (--quick: tiny sizes and steps; the numbers mean nothing)" } else { "" },
            self.episodes,
            FIRST_HELDOUT_SEED,
            FIRST_HELDOUT_SEED + self.episodes - 1,
            if self.quick {
                format!("{} / {} demonstrations for every task", QUICK_SIZES.0, QUICK_SIZES.1)
            } else {
                TASKS.iter().zip(SIZES).map(|(t, (l, h))| format!("{t} {l} / {h}")).collect::<Vec<_>>().join(", ")
            }
        );
        out += &self.markdown_table();
        out += "\n![Table I](table1.png)\n\n## The claims, checked\n\n";
        for (claim, holds) in self.claims() {
            out += &format!("- {} {claim}\n", if holds { "yes:" } else { "**no**:" });
        }
        out += "\nWhere a claim fails it is reported as measured: nothing was tuned on the held-out scenes.\n\n";
        out += "## The paper's Table I (their simulator, for reference)\n\n";
        out += &self.paper_table();
        out += "\n## Time per method\n\n| method | training (s, sum over tasks) | evaluation (s, sum) | parameters | inference p50 (ms, per task) |\n|---|---|---|---|---|\n";
        for method in &METHODS {
            let cells: Vec<&Cell> = method.tasks.iter().filter_map(|t| self.cell(method, t)).collect();
            let train: f64 = cells.iter().map(|c| c.train_seconds).sum();
            let eval: f64 = cells.iter().map(|c| c.eval_seconds).sum();
            let params: Vec<String> = cells.iter().map(|c| c.parameters.to_string()).collect();
            let latency: Vec<String> = cells.iter().map(|c| format!("{:.0}", c.latency_ms_p50)).collect();
            out += &format!("| {} | {train:.0} | {eval:.0} | {} | {} |\n", method.label, params.join(", "), latency.join(", "));
        }
        out += &format!(
            "\nTraining time is each run's optimisation wall time (one torch thread); evaluation time includes rendering, prediction, physics and the expert for MED.\n\n## Run\n\n- command: `{}`\n- date: {}\n- machine: {}\n- wall time: {:.0} s, {} jobs, {} at a time{}\n",
            self.command,
            self.date,
            self.machine,
            self.wall_time_s,
            self.total_jobs,
            self.jobs,
            if self.reused > 0 { format!(", {} reused from an earlier run (their time is not in this wall time)", self.reused) } else { String::new() }
        );
        out
    }

    fn csv(&self) -> String {
        let mut out = String::from("method,model_type,task,demos,heldout_episodes,success_rate,med_cm,latency_ms_p50,train_seconds,eval_seconds,parameters\n");
        for c in &self.results {
            out += &format!(
                "{},{},{},{},{},{:.4},{:.4},{:.1},{:.1},{:.1},{}\n",
                c.method, c.model_type, c.task, c.demos, c.episodes, c.success_rate, c.med_cm, c.latency_ms_p50, c.train_seconds, c.eval_seconds, c.parameters
            );
        }
        out
    }
}

fn write_reports(out: &Path, report: &Report) -> Result<(), Failure> {
    fs::create_dir_all(out).map_err(|err| Failure::Environment(format!("cannot create {}: {err}", out.display())))?;
    let chart = Bridge::start_default()?.core_table_chart(
        &serde_json::to_string(&report.results).expect("results serialise"),
        &METHODS.iter().map(|m| m.label.to_owned()).collect::<Vec<_>>(),
        &TASKS.iter().map(|t| (*t).to_owned()).collect::<Vec<_>>(),
    )?;
    write_atomically(&out.join("table1.png"), &chart)?;
    write_atomically(&out.join("table1.csv"), report.csv().as_bytes())?;
    write_atomically(&out.join("table1.md"), report.markdown().as_bytes())
}

/// CPU model, cores and memory, from /proc (Linux), for the report.
fn machine_description() -> String {
    let cpu = fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|text| text.lines().find(|l| l.starts_with("model name")).and_then(|l| l.split(':').nth(1)).map(|s| s.trim().to_owned()))
        .unwrap_or_else(|| "unknown CPU".into());
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    let memory_gib = fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|text| text.lines().next().and_then(|l| l.split_whitespace().nth(1)).and_then(|kb| kb.parse::<f64>().ok()))
        .map_or(String::new(), |kb| format!(", {:.0} GiB", kb / 1024.0 / 1024.0));
    format!("{cpu}, {cores} cores available{memory_gib}, no GPU used")
}

/// Today's date (UTC), YYYY-MM-DD, from `date`.
fn today() -> String {
    Command::new("date")
        .args(["-u", "+%F"])
        .output()
        .ok()
        .filter(|out| out.status.success())
        .map_or_else(|| "unknown date".into(), |out| String::from_utf8_lossy(&out.stdout).trim().to_owned())
}

#[cfg(test)]
mod tests {
    use super::versus;

    #[test]
    fn a_comparison_shows_enough_digits_to_tell_the_values_apart() {
        assert_eq!(versus(0.66, 17.52), "0.66 vs 17.52");
        assert_eq!(versus(1.7726, 1.7710), "1.773 vs 1.771");
        assert_eq!(versus(1.77261, 1.77259), "1.7726 vs 1.7726", "stops at four digits");
        assert_eq!(versus(2.5, 2.5), "2.5000 vs 2.5000");
    }
}
