//! How a command fails: a message for the user and the exit code scripts can rely on.

use std::fmt;

/// A failed command. Exit codes: 2 for bad input (the user can fix the arguments or files),
/// 1 for an environment or runtime problem (fix the installation, or report a bug).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Failure {
    BadInput(String),
    Environment(String),
}

impl Failure {
    /// The same failure with `context` (what was being done) before its message.
    pub fn with_context(self, context: &str) -> Self {
        match self {
            Failure::BadInput(message) => Failure::BadInput(format!("{context}: {message}")),
            Failure::Environment(message) => Failure::Environment(format!("{context}: {message}")),
        }
    }

    pub fn exit_code(&self) -> i32 {
        match self {
            Failure::BadInput(_) => 2,
            Failure::Environment(_) => 1,
        }
    }
}

impl fmt::Display for Failure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Failure::BadInput(message) | Failure::Environment(message) => f.write_str(message),
        }
    }
}

impl From<crate::trajectory::TrajectoryError> for Failure {
    fn from(err: crate::trajectory::TrajectoryError) -> Self {
        Failure::BadInput(err.to_string())
    }
}

impl From<segmenter_bridge::BridgeError> for Failure {
    fn from(err: segmenter_bridge::BridgeError) -> Self {
        match err {
            segmenter_bridge::BridgeError::InvalidInput(message) | segmenter_bridge::BridgeError::NotGrounded(message) => {
                Failure::BadInput(message)
            }
            other => Failure::Environment(other.to_string()),
        }
    }
}
