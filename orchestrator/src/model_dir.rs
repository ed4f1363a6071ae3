//! Model directories: the task a trained one was trained on, loading one before a batch's
//! first scene, and the checks every training command makes before it creates a new one.

use std::fs;
use std::path::{Path, PathBuf};

use segmenter_bridge::{Bridge, ModelDescription};
use serde_json::Value;

use crate::failure::Failure;
use crate::files::require_file;

/// Checks shared by every training command before the interpreter starts: the model
/// directory must be new and every given config file must exist.
pub fn check_training_outputs(out: &Path, configs: &[PathBuf]) -> Result<(), Failure> {
    if out.exists() {
        return Err(Failure::BadInput(format!(
            "{} already exists; models are never overwritten, choose a new --out",
            out.display()
        )));
    }
    configs.iter().try_for_each(|config| require_file(config, "config"))
}

/// The task a model directory was trained on (its config.json's "task"; empty when the
/// config names none, as the segmenter's checkpoint directory does).
pub fn model_task(model: &Path) -> Result<String, Failure> {
    let config_path = model.join("config.json");
    require_file(&config_path, "model config")?;
    let text = fs::read_to_string(&config_path)
        .map_err(|err| Failure::BadInput(format!("cannot read {}: {err}", config_path.display())))?;
    let config: Value = serde_json::from_str(&text)
        .map_err(|err| Failure::BadInput(format!("{} is not JSON: {err}", config_path.display())))?;
    Ok(config.get("task").and_then(Value::as_str).unwrap_or_default().to_owned())
}

/// Loads the model at `model` into the worker (it stays resident for the predictions that
/// follow) and describes it. Commands that run many scenes call it before the first, so a
/// model that cannot be loaded (an unknown config field, a newer config_version, weights that
/// do not match) is refused once with the loader's message instead of failing every scene.
pub fn load_model(bridge: &Bridge, model: &Path) -> Result<ModelDescription, Failure> {
    bridge
        .core_describe(model)
        .map_err(|err| Failure::from(err).with_context("cannot load the model"))
}
