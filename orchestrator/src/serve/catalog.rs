//! The models a server serves: every core model directory under `--models`, loaded at start
//! (so no request pays for loading) and looked up by name or task.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

use segmenter_bridge::{Bridge, ModelDescription};

use super::api::ModelSummary;
use super::error::ApiError;
use crate::model_dir::model_task;
use crate::failure::Failure;

/// One served model.
#[derive(Debug, Clone)]
pub struct ServedModel {
    pub dir: PathBuf,
    pub summary: ModelSummary,
    /// The model reads only its first slots and takes any further objects of a scene as
    /// background (distractors); otherwise masks may name at most its slots.
    pub takes_distractors: bool,
}

/// Every served model, in name order.
#[derive(Debug, Clone)]
pub struct Catalog {
    models: Vec<ServedModel>,
    default: Option<usize>,
}

/// True for a directory holding a core model: its config.json names a task (the segmenter's
/// checkpoint directory, say, does not).
fn is_core_model(dir: &Path) -> bool {
    model_task(dir).is_ok_and(|task| !task.is_empty())
}

/// The rows of a model card's first two-column table (`| key | value |`), backticks removed.
fn card_summary(dir: &Path) -> BTreeMap<String, String> {
    let text = fs::read_to_string(dir.join("README.md")).unwrap_or_default();
    text.lines()
        .skip_while(|line| !line.starts_with('|'))
        .take_while(|line| line.starts_with('|'))
        .filter_map(|line| {
            let cells: Vec<&str> = line.trim().trim_matches('|').split('|').map(str::trim).collect();
            match cells.as_slice() {
                [key, value] if !key.is_empty() && !key.starts_with('-') => {
                    Some((key.replace('`', ""), value.replace('`', "")))
                }
                _ => None,
            }
        })
        .collect()
}

impl Catalog {
    /// Loads every core model under `models_dir` through `bridge` (each stays resident and
    /// predicts a synthetic scene once, so no request pays first-call costs), reporting each
    /// on stderr. `default_model` is used when a request names neither a
    /// model nor a task; it must be one of them when there is more than one model.
    pub fn load(bridge: &Bridge, models_dir: &Path, default_model: &str) -> Result<Catalog, Failure> {
        let entries = fs::read_dir(models_dir).map_err(|err| {
            Failure::BadInput(format!("cannot read the models directory {}: {err}", models_dir.display()))
        })?;
        let mut dirs: Vec<PathBuf> = entries
            .filter_map(Result::ok)
            .map(|entry| entry.path())
            .filter(|path| path.is_dir() && is_core_model(path))
            .collect();
        dirs.sort();
        if dirs.is_empty() {
            return Err(Failure::BadInput(format!(
                "{} holds no model directories (each needs the config.json `cnfmp train` writes)",
                models_dir.display()
            )));
        }
        let mut models = Vec::new();
        for dir in dirs {
            let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            let description: ModelDescription = bridge.core_describe(&dir).map_err(|err| {
                Failure::from(err).with_context(&format!("cannot load the model {}", dir.display()))
            })?;
            // The first request must not pay the first prediction's costs.
            let warm_up_ms = bridge.core_warm_up(&dir).map_err(|err| {
                Failure::from(err).with_context(&format!("cannot warm up the model {}", dir.display()))
            })?;
            eprintln!(
                "cnfmp serve: loaded {name} ({}, {} parameters, objects: {}{}; warm-up {warm_up_ms:.0} ms)",
                description.task,
                description.parameters,
                description.objects.join(", "),
                if description.takes_scans() {
                    "; served from scans (/v1/scan-trajectories)"
                } else if description.roles.is_some() {
                    ""
                } else {
                    "; no prompt roles: served from masks"
                }
            );
            let takes_scans = description.takes_scans();
            let summary = ModelSummary {
                card: card_summary(&dir),
                name,
                task: description.task,
                model_type: description.model_type,
                objects: description.objects.into_iter().take(description.task_objects as usize).collect(),
                inputs: if takes_scans {
                    vec!["scan".into()]
                } else if description.roles.is_some() {
                    vec!["prompt".into(), "masks".into()]
                } else {
                    vec!["masks".into()]
                },
                roles: description.roles,
                parameters: description.parameters,
                output_fps: description.output_fps,
                duration_s: description.duration_s,
                default: false,
            };
            models.push(ServedModel { dir, summary, takes_distractors: description.takes_distractors });
        }
        Ok(Catalog::new(models, default_model))
    }

    /// The catalog of `models` (in name order). `default_model` is used when a request names
    /// neither a model nor a task; with one model, that one is the default.
    pub fn new(mut models: Vec<ServedModel>, default_model: &str) -> Catalog {
        let default = match models.iter().position(|m| m.summary.name == default_model) {
            Some(index) => Some(index),
            None if models.len() == 1 => Some(0),
            None => {
                eprintln!("cnfmp serve: no model named {default_model:?}; requests must name a model or a task");
                None
            }
        };
        if let Some(index) = default {
            models[index].summary.default = true;
        }
        Catalog { models, default }
    }

    pub fn models(&self) -> impl Iterator<Item = &ServedModel> {
        self.models.iter()
    }

    /// The model a request asks for: by `model` name, else the first trained on `task`,
    /// else the default. 404 for an unknown name or task.
    pub fn select(&self, model: Option<&str>, task: Option<&str>) -> Result<&ServedModel, ApiError> {
        let names = || self.models.iter().map(|m| m.summary.name.as_str()).collect::<Vec<_>>().join(", ");
        if let Some(name) = model {
            let found = self.models.iter().find(|m| m.summary.name == name);
            let served = found.ok_or_else(|| {
                ApiError::not_found("unknown_model", format!("no model named {name:?} is served; served: {}", names()))
            })?;
            if let Some(task) = task.filter(|task| *task != served.summary.task) {
                return Err(ApiError::bad_request(
                    "model_task_mismatch",
                    format!("the model {name:?} was trained on {}, not {task:?}", served.summary.task),
                ));
            }
            return Ok(served);
        }
        if let Some(task) = task {
            return self.models.iter().find(|m| m.summary.task == task).ok_or_else(|| {
                let tasks: Vec<&str> = self.models.iter().map(|m| m.summary.task.as_str()).collect();
                ApiError::not_found(
                    "unknown_task",
                    format!("no served model is trained on {task:?}; served tasks: {}", tasks.join(", ")),
                )
            });
        }
        self.default.map(|index| &self.models[index]).ok_or_else(|| {
            ApiError::bad_request("model_required", format!("name a \"model\" or a \"task\"; served models: {}", names()))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn card_summary_reads_the_first_table() {
        let dir = tempfile::tempdir().unwrap();
        fs::write(
            dir.path().join("README.md"),
            "# card\n\n| | |\n|---|---|\n| task | `wall_avoidance` |\n| steps | 2000 (seed 0) |\n\nText.\n\n| a | b |\n",
        )
        .unwrap();
        let summary = card_summary(dir.path());
        assert_eq!(summary.len(), 2, "{summary:?}");
        assert_eq!(summary["task"], "wall_avoidance");
        assert_eq!(summary["steps"], "2000 (seed 0)");
    }
}
