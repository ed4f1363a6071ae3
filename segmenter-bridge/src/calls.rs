//! Typed calls into the `cnfmp` Python package. Each method names the Python entry point it
//! runs; arguments and results are plain Rust types, so no other crate touches pyo3.

use std::path::Path;

use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods};
use pyo3::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::BridgeError;
use crate::worker::Bridge;

/// One line of the environment report (`cnfmp.doctor.collect`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Eq)]
pub struct DoctorCheck {
    /// What was checked (`python`, `torch`, `mujoco render`, ...).
    pub name: String,
    pub ok: bool,
    /// What was found (versions, paths, settings).
    pub detail: String,
    /// One-line fix; empty when `ok`.
    pub fix: String,
    /// For the render check: the MuJoCo GL backend used.
    #[serde(default)]
    pub backend: Option<String>,
}

/// The embedded interpreter, as it describes itself.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Eq)]
pub struct PythonInfo {
    pub version: String,
    pub executable: String,
    pub prefix: String,
    pub base_prefix: String,
}

/// The whole environment report.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct DoctorReport {
    pub checks: Vec<DoctorCheck>,
    pub python: PythonInfo,
    /// What a cold start costs ([`Bridge::startup_costs`]), when measured.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub startup: Option<StartupReport>,
}

/// One stage of a cold start and its wall time.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct StartupStage {
    pub name: String,
    pub ms: f64,
}

/// A cold start timed in a fresh interpreter (`cnfmp.doctor.startup_costs`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct StartupReport {
    pub stages: Vec<StartupStage>,
    /// Wall time of the whole probe process (ms), interpreter start and exit included.
    pub process_ms: f64,
}

/// What `cnfmp.doctor.startup_costs` returns: the report, or why the probe failed.
#[derive(Deserialize)]
#[serde(untagged)]
enum StartupOutcome {
    Measured(StartupReport),
    Failed { error: String },
}

impl DoctorReport {
    /// True when every check passed.
    pub fn healthy(&self) -> bool {
        self.checks.iter().all(|check| check.ok)
    }
}

/// Result of [`Bridge::array_round_trip`].
#[derive(Debug, Clone, PartialEq)]
pub struct ArrayRoundTrip {
    /// The values Python handed back (each input value doubled), in the input's shape.
    pub values: numpy::ndarray::ArrayD<f64>,
    /// True when Python worked on the very buffer Rust allocated: no copy either way.
    pub same_buffer: bool,
}

impl Bridge {
    /// Runs every environment check (`cnfmp.doctor.collect`): interpreter, pinned packages,
    /// torch threads, a MuJoCo test render. Takes a few seconds (it imports torch and lerobot).
    pub fn doctor(&self) -> Result<DoctorReport, BridgeError> {
        let json = self.call(|py| {
            let run = || -> PyResult<String> { py.import("cnfmp.doctor")?.call_method0("collect")?.extract() };
            run().map_err(|err| BridgeError::python(py, &err))
        })?;
        serde_json::from_str(&json).map_err(|err| BridgeError::Protocol(format!("doctor report: {err}")))
    }

    /// Times a cold start in a fresh interpreter on the venv (`cnfmp.doctor.startup_costs`):
    /// imports, the prompt segmenter and, with `model_dir`, that model's load and first and
    /// warm predictions of a synthetic scene. Takes about as long as a cold `cnfmp predict`.
    /// Errors: [`BridgeError::InvalidInput`] with the probe's last error line when it failed.
    pub fn startup_costs(&self, model_dir: Option<&Path>) -> Result<StartupReport, BridgeError> {
        let model_dir = model_dir.map(Path::to_path_buf);
        let json = self.call(move |py| {
            let run = || -> PyResult<String> {
                let report = py.import("cnfmp.doctor")?.call_method("startup_costs", (), Some(&kwargs!(py, model_dir = model_dir)))?;
                py.import("json")?.call_method1("dumps", (report,))?.extract()
            };
            run().map_err(|err| BridgeError::python(py, &err))
        })?;
        match serde_json::from_str(&json).map_err(|err| BridgeError::Protocol(format!("start-up report: {err}")))? {
            StartupOutcome::Measured(report) => Ok(report),
            StartupOutcome::Failed { error } => Err(BridgeError::InvalidInput(format!("the start-up probe failed: {error}"))),
        }
    }

    /// Moves `values` (any shape) into a numpy array without copying, has Python double it in
    /// place (`cnfmp.runtime.bridge_selftest`), and reports whether the buffer Python returned
    /// is the one Rust allocated. Used by `cnfmp doctor` and the tests to prove zero-copy.
    pub fn array_round_trip(&self, values: numpy::ndarray::ArrayD<f64>) -> Result<ArrayRoundTrip, BridgeError> {
        self.call(move |py| {
            let sent_at = values.as_ptr() as usize;
            let sent = values.into_pyarray(py);
            let run = || -> PyResult<Bound<'_, PyArrayDyn<f64>>> {
                let back = py.import("cnfmp.runtime")?.call_method("bridge_selftest", (), Some(&kwargs!(py, array = sent)))?;
                Ok(back.cast_into::<PyArrayDyn<f64>>()?)
            };
            let back = run().map_err(|err| BridgeError::python(py, &err))?;
            let same_buffer = back.data() as usize == sent_at;
            let view = back.readonly();
            Ok(ArrayRoundTrip { values: view.as_array().to_owned(), same_buffer })
        })
    }
}
