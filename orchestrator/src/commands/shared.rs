//! Helpers that several commands share: model directories (new ones for training, the task
//! of a trained one), input files, the command line recorded in model cards, and the
//! validated trajectory of a prediction.

use std::fs;
use std::path::Path;

use segmenter_bridge::Prediction;
use serde_json::Value;

use crate::failure::Failure;
use crate::trajectory::Trajectory;

/// Checks shared by every training command before the interpreter starts: the model
/// directory must be new and a given config file must exist.
pub(crate) fn check_training_outputs(out: &Path, config: Option<&Path>) -> Result<(), Failure> {
    if out.exists() {
        return Err(Failure::BadInput(format!(
            "{} already exists; models are never overwritten, choose a new --out",
            out.display()
        )));
    }
    config.map_or(Ok(()), |config| require_file(config, "config"))
}

/// The command line as typed (recorded in model cards).
pub(crate) fn command_line() -> String {
    std::iter::once("cnfmp".to_owned())
        .chain(std::env::args().skip(1))
        .collect::<Vec<_>>()
        .join(" ")
}

fn require_file(path: &Path, what: &str) -> Result<(), Failure> {
    if path.is_file() {
        Ok(())
    } else {
        Err(Failure::BadInput(format!(
            "{what} {} does not exist or is not a file",
            path.display()
        )))
    }
}

/// The task a model directory was trained on (its config.json's "task"; empty when the
/// config names none, as the segmenter's checkpoint directory does).
pub(crate) fn model_task(model: &Path) -> Result<String, Failure> {
    let config_path = model.join("config.json");
    require_file(&config_path, "model config")?;
    let text = fs::read_to_string(&config_path)
        .map_err(|err| Failure::BadInput(format!("cannot read {}: {err}", config_path.display())))?;
    let config: Value = serde_json::from_str(&text)
        .map_err(|err| Failure::BadInput(format!("{} is not JSON: {err}", config_path.display())))?;
    Ok(config.get("task").and_then(Value::as_str).unwrap_or_default().to_owned())
}

pub(crate) fn read_bytes(path: &Path, what: &str) -> Result<Vec<u8>, Failure> {
    fs::read(path)
        .map_err(|err| Failure::BadInput(format!("cannot read {what} {}: {err}", path.display())))
}

/// The prediction's trajectory, validated by the Rust trajectory code (the diagnostics stay
/// as metadata).
pub(crate) fn trajectory_of(prediction: &Prediction) -> Result<Trajectory, Failure> {
    Trajectory::from_json_str(&prediction.json).map_err(|err| {
        Failure::Environment(format!("the model produced an invalid trajectory: {err}"))
    })
}
