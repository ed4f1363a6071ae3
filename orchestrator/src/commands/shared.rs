//! Helpers that several commands share: the command line recorded in model cards, and the
//! validated trajectory of a prediction.

use segmenter_bridge::Prediction;

use crate::failure::Failure;
use crate::trajectory::joints::Predicted;

/// The command line as typed (recorded in model cards).
pub(crate) fn command_line() -> String {
    std::iter::once("cnfmp".to_owned())
        .chain(std::env::args().skip(1))
        .collect::<Vec<_>>()
        .join(" ")
}

/// The prediction's trajectory (end-effector poses, or joint values for a joint-space model),
/// validated by the Rust trajectory code (the diagnostics stay as metadata).
pub(crate) fn trajectory_of(prediction: &Prediction) -> Result<Predicted, Failure> {
    Predicted::from_json_str(&prediction.json).map_err(|err| {
        Failure::Environment(format!("the model produced an invalid trajectory: {err}"))
    })
}
