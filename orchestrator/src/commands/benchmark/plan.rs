//! The job graph of a Table-I run: training datasets (low and high regimes per task, the grid
//! for NFMP) -> one training per method and task -> one held-out evaluation per model.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

use super::scheduler::{Job, remove_output};
use super::table::{METHODS, Method};
use crate::failure::Failure;
use crate::files::write_atomically;
use crate::seeds::first_heldout_seed;

/// What the plan depends on.
pub(super) struct Settings<'a> {
    /// Directory of the datasets, models, evaluations, configs and logs.
    pub work: &'a Path,
    /// Per-task configuration overrides of the cnfmp models (DIR/<task>.json).
    pub configs: &'a Path,
    /// The --quick settings per model type (DIR/<model type>.json).
    pub quick_configs: &'a Path,
    pub quick: bool,
    /// Held-out scenes per evaluation.
    pub episodes: u64,
}

/// A cell of the table: a method on a task, and where its results will be.
pub(super) struct Row {
    pub method: &'static Method,
    pub task: &'static str,
    /// The evaluation's JSON.
    pub evaluation: PathBuf,
    /// The training's JSON report.
    pub training: PathBuf,
}

pub(super) struct Plan {
    pub jobs: Vec<Job>,
    pub rows: Vec<Row>,
    pub datasets: usize,
}

/// Dataset jobs by (task, demonstrations, first seed): their index in the plan.
pub(super) type Datasets = BTreeMap<(String, usize, u64), usize>;

/// Plans every job of the table. Records each training's config files in the work directory
/// and removes a model trained from other ones, so that the run retrains it.
pub(super) fn plan(settings: &Settings) -> Result<Plan, Failure> {
    let mut jobs: Vec<Job> = Vec::new();
    let mut datasets = Datasets::new();
    let mut rows = Vec::new();
    for method in &METHODS {
        for task in method.tasks() {
            let (count, seed) = method.demonstrations(task, settings.quick);
            let dataset = dataset_job(&mut jobs, &mut datasets, settings.work, task, count, seed);
            let row = Row {
                method,
                task,
                evaluation: settings.work.join("evals").join(format!("{}-{task}-{}.json", method.key, settings.episodes)),
                training: settings.work.join("reports").join(format!("train-{}-{task}.json", method.key)),
            };
            let training = training_job(settings, &row, &jobs[dataset].output, dataset)?;
            jobs.push(training);
            let evaluation = evaluation_job(settings, &row, jobs.len() - 1);
            jobs.push(evaluation);
            rows.push(row);
        }
    }
    Ok(Plan { jobs, rows, datasets: datasets.len() })
}

pub(super) fn path_arg(path: &Path) -> String {
    path.to_string_lossy().into_owned()
}

fn model_dir(settings: &Settings, row: &Row) -> PathBuf {
    settings.work.join("models").join(row.method.key).join(row.task)
}

/// The index of the job generating `count` demonstrations of `task` from `seed` (added to the
/// plan the first time it is asked for).
pub(super) fn dataset_job(jobs: &mut Vec<Job>, datasets: &mut Datasets, work: &Path, task: &str, count: usize, seed: u64) -> usize {
    *datasets.entry((task.to_owned(), count, seed)).or_insert_with(|| {
        let name = if seed == 0 { format!("{task}-{count}") } else { format!("{task}-{count}-from-{seed}") };
        let out = work.join("datasets").join(&name);
        jobs.push(Job {
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
        jobs.len() - 1
    })
}

fn training_job(settings: &Settings, row: &Row, dataset: &Path, dataset_job: usize) -> Result<Job, Failure> {
    let (method, task) = (row.method, row.task);
    let model_dir = model_dir(settings, row);
    let mut args = vec![
        "train".into(), "--dataset".into(), path_arg(dataset),
        "--out".into(), path_arg(&model_dir), "--model-type".into(), method.model_type.into(),
    ];
    // No --seed: the config's seed (0 unless the recipe names the seed its shipped model was
    // trained with, so that "ours" is the shipped model).
    for config in training_configs(settings, row, &model_dir)? {
        args.extend(["--config".into(), path_arg(&config)]);
    }
    Ok(Job {
        name: format!("train {}/{task}", method.key),
        args,
        output: model_dir,
        stdout: Some(row.training.clone()),
        log: settings.work.join("logs").join(format!("train-{}-{task}.log", method.key)),
        needs: vec![dataset_job],
    })
}

fn evaluation_job(settings: &Settings, row: &Row, training_job: usize) -> Job {
    let (method, task) = (row.method, row.task);
    Job {
        name: format!("eval {}/{task}", method.key),
        args: vec![
            "eval".into(), "--model".into(), path_arg(&model_dir(settings, row)), "--task".into(), task.into(),
            "--episodes".into(), settings.episodes.to_string(), "--seed-start".into(), first_heldout_seed().to_string(),
            "--json".into(), path_arg(&row.evaluation),
        ],
        output: row.evaluation.clone(),
        stdout: None,
        log: settings.work.join("logs").join(format!("eval-{}-{task}.log", method.key)),
        needs: vec![training_job],
    }
}

/// The config files the row's training layers (`cnfmp train` merges them; a later file
/// wins): the task's recipe for the cnfmp types, then with --quick the model type's quick
/// settings. Their names and contents are recorded in the work directory; a model already in
/// `model_dir` that was trained from other contents is removed, with its training report,
/// so that the run retrains it (and, by `run_jobs`, evaluates it again).
fn training_configs(settings: &Settings, row: &Row, model_dir: &Path) -> Result<Vec<PathBuf>, Failure> {
    let (method, task) = (row.method, row.task);
    let recipe = settings.configs.join(format!("{task}.json"));
    let quick = settings.quick_configs.join(format!("{}.json", method.model_type));
    if settings.quick && !quick.is_file() {
        return Err(Failure::BadInput(format!("--quick needs {}, the quick settings of {}", quick.display(), method.model_type)));
    }
    let configs: Vec<PathBuf> = [(method.model_type.starts_with("cnfmp") && recipe.is_file(), recipe), (settings.quick, quick)]
        .into_iter()
        .filter_map(|(used, path)| used.then_some(path))
        .collect();
    let mut contents = String::new();
    for config in &configs {
        let text = fs::read_to_string(config)
            .map_err(|err| Failure::BadInput(format!("cannot read {}: {err}", config.display())))?;
        // Only the shape is checked here; `cnfmp train` checks the fields.
        if !serde_json::from_str::<serde_json::Value>(&text).is_ok_and(|value| value.is_object()) {
            return Err(Failure::BadInput(format!("{} is not a JSON object of config fields", config.display())));
        }
        // Names and contents, not paths: the same files copied elsewhere are the same config.
        contents += &format!("{}\n{text}\n", config.file_name().unwrap_or_default().to_string_lossy());
    }
    let record = settings.work.join("configs").join(format!("{}-{task}.txt", method.key));
    if fs::read_to_string(&record).ok().as_deref() != Some(contents.as_str()) && model_dir.exists() {
        eprintln!("{}/{task}: its training config changed; it will be retrained and evaluated again", method.key);
        remove_output(model_dir)?;
        remove_output(&row.training)?;
    }
    write_atomically(&record, contents.as_bytes())?;
    Ok(configs)
}
