//! Errors of the bridge: a missing venv, a failed start, or a Python exception carried into
//! Rust with its type, message and the last frames of its traceback.

use std::fmt;
use std::path::PathBuf;

use pyo3::prelude::*;
use pyo3::types::PyTracebackMethods;

/// How many innermost traceback frames a [`PythonException`] keeps.
pub const TRACEBACK_FRAMES: usize = 5;

/// A Python exception raised by a bridge call.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PythonException {
    /// Exception type, module-qualified except for builtins (`ValueError`, `cnfmp.sim.BadScene`).
    pub type_name: String,
    /// `str(exception)`.
    pub message: String,
    /// The last [`TRACEBACK_FRAMES`] frames, innermost last, each `File "f.py", line N, in fn`
    /// followed by the source line when Python has it.
    pub traceback: Vec<String>,
}

impl PythonException {
    /// Captures `err`'s type, message and traceback tail. Never fails: whatever cannot be
    /// read (a broken `__str__`, say) is replaced by a placeholder naming the problem.
    pub(crate) fn from_pyerr(py: Python<'_>, err: &PyErr) -> Self {
        let type_name = err
            .get_type(py)
            .fully_qualified_name()
            .map(|name| name.to_string())
            .unwrap_or_else(|_| "<unknown exception type>".to_owned());
        let type_name = type_name.strip_prefix("builtins.").unwrap_or(&type_name).to_owned();
        let message = err
            .value(py)
            .str()
            .map(|text| text.to_string())
            .unwrap_or_else(|_| "<exception message could not be read>".to_owned());
        let traceback = err
            .traceback(py)
            .and_then(|tb| tb.format().ok())
            .map(|text| frames_of(&text))
            .unwrap_or_default();
        PythonException { type_name, message, traceback }
    }

    /// The traceback tail as text, one frame per paragraph, innermost last.
    pub fn traceback_text(&self) -> String {
        self.traceback.join("\n")
    }
}

/// Splits a formatted traceback into frames (each starts with `File "`) and keeps the tail.
fn frames_of(formatted: &str) -> Vec<String> {
    let mut frames: Vec<String> = Vec::new();
    for line in formatted.lines() {
        let trimmed = line.trim();
        if trimmed.starts_with("File \"") {
            frames.push(trimmed.to_owned());
        } else if let Some(frame) = frames.last_mut()
            && !trimmed.is_empty()
            && !trimmed.chars().all(|c| c == '^' || c == '~')
        {
            frame.push_str("\n    ");
            frame.push_str(trimmed);
        }
    }
    let skip = frames.len().saturating_sub(TRACEBACK_FRAMES);
    frames.split_off(skip)
}

impl fmt::Display for PythonException {
    /// `Type: message`, plus where it was raised (the innermost frame's first line).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.type_name, self.message)?;
        if let Some(location) = self.traceback.last().and_then(|frame| frame.lines().next()) {
            write!(f, " ({location})")?;
        }
        Ok(())
    }
}

/// Everything a bridge call can fail with.
#[derive(Debug, Clone, thiserror::Error)]
pub enum BridgeError {
    /// No usable venv where the bridge was told to look.
    #[error("Python venv not usable at {venv}: {reason}; fix: run `make setup` in the repository root (or set CNFMP_VENV to the project venv)")]
    VenvMissing { venv: PathBuf, reason: String },
    /// The interpreter did not start, or started on the wrong prefix.
    #[error("embedded Python failed to start: {0}")]
    Start(String),
    /// The caller's input was wrong: Python raised `cnfmp.errors.InputError`, whose message
    /// says what and how to fix it.
    #[error("{0}")]
    InvalidInput(String),
    /// The prompt cannot drive the model (Python raised `cnfmp.errors.NotGrounded`): a role
    /// the model needs is missing from the prompt or its object was not found in the image.
    /// A kind of invalid input; servers answer it differently from a malformed request.
    #[error("{0}")]
    NotGrounded(String),
    /// A Python exception raised inside a call.
    #[error("Python raised {0}")]
    Python(PythonException),
    /// A call returned something the Rust side could not decode.
    #[error("unexpected reply from Python: {0}")]
    Protocol(String),
    /// A bridge call panicked on the worker thread (a bug in the bridge; the worker survives).
    #[error("a bridge call panicked: {0}")]
    Panicked(String),
    /// The worker thread is gone (it panicked, or the process is shutting down).
    #[error("the Python worker thread is no longer running")]
    WorkerGone,
}

impl BridgeError {
    /// Wraps a `PyErr` raised while attached: `cnfmp.errors.NotGrounded` becomes
    /// [`BridgeError::NotGrounded`], any other `cnfmp.errors.InputError`
    /// [`BridgeError::InvalidInput`], anything else [`BridgeError::Python`].
    pub(crate) fn python(py: Python<'_>, err: &PyErr) -> Self {
        let is = |name: &str| {
            py.import("cnfmp.errors")
                .and_then(|module| module.getattr(name))
                .is_ok_and(|class| err.is_instance(py, &class))
        };
        let exception = PythonException::from_pyerr(py, err);
        if is("NotGrounded") {
            BridgeError::NotGrounded(exception.message)
        } else if is("InputError") {
            BridgeError::InvalidInput(exception.message)
        } else {
            BridgeError::Python(exception)
        }
    }

    /// True for the caller's mistakes ([`BridgeError::InvalidInput`] and
    /// [`BridgeError::NotGrounded`]), false for failures of the environment or the code.
    pub fn is_bad_input(&self) -> bool {
        matches!(self, BridgeError::InvalidInput(_) | BridgeError::NotGrounded(_))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_keep_source_lines_and_drop_markers() {
        let text = "Traceback (most recent call last):\n  File \"a.py\", line 1, in <module>\n    f()\n    ^^^\n  File \"b.py\", line 2, in f\n    raise ValueError\n";
        let frames = frames_of(text);
        assert_eq!(frames, vec![
            "File \"a.py\", line 1, in <module>\n    f()".to_owned(),
            "File \"b.py\", line 2, in f\n    raise ValueError".to_owned(),
        ]);
    }

    #[test]
    fn frames_keep_only_the_innermost_tail() {
        let text: String = (0..9).map(|i| format!("  File \"m.py\", line {i}, in f{i}\n")).collect();
        let frames = frames_of(&text);
        assert_eq!(frames.len(), TRACEBACK_FRAMES);
        assert!(frames.last().unwrap().contains("line 8"));
        assert!(frames.first().unwrap().contains("line 4"));
    }
}
