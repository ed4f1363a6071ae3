//! # segmenter-bridge
//!
//! The one place Rust touches Python. It starts CPython embedded in the process on the
//! project venv (never the system interpreter), applies thread limits before torch loads,
//! and runs one dedicated Python worker thread fed by a channel. Other crates call typed
//! methods on [`Bridge`]; they never see pyo3.
//!
//! ```no_run
//! let bridge = segmenter_bridge::Bridge::start_default()?;
//! let report = bridge.doctor()?;
//! println!("Python prefix: {}", report.python.prefix);
//! # Ok::<(), segmenter_bridge::BridgeError>(())
//! ```
//!
//! Arrays cross without copies (`into_pyarray` moves a Rust buffer into numpy, readonly views
//! read numpy buffers in place). A Python exception becomes [`BridgeError::Python`] carrying
//! the exception type, message and the innermost traceback frames.

/// Keyword arguments of a Python call, `kwargs!(py, task = task, seed = seed)`: a dict built
/// on the Python thread (the `?` inside needs a `PyResult` context). Every call into the
/// package names its arguments, so a reordered Python signature cannot silently swap them.
macro_rules! kwargs {
    ($py:expr $(, $name:ident = $value:expr)* $(,)?) => {{
        let dict = pyo3::types::PyDict::new($py);
        $( dict.set_item(stringify!($name), $value)?; )*
        dict
    }};
}

mod calls;
mod core;
mod dataset;
mod error;
mod interpreter;
mod segment;
mod sim;
mod worker;

#[cfg(test)]
mod tests;

pub use calls::{ArrayRoundTrip, DoctorCheck, DoctorReport, PythonInfo, StartupReport, StartupStage};
pub use dataset::{AnnotateReport, AnnotateRequest, DatasetCheck, DatasetEpisodes, DatasetInspection, Hdf5Demo, Hdf5Listing, InspectedEpisode, SkippedEpisode, StagedWriteReport};
pub use core::{DrawChoice, ModelDescription, ModelInfo, ObjectEstimate, Prediction, RecordedMotion, ScanLabelling, SceneToPredict, TrainReport, TrainRequest};
pub use error::{BridgeError, PythonException, TRACEBACK_FRAMES};
pub use interpreter::BridgeConfig;
pub use segment::{SegmentDocument, SegmentRequest, SegmentedObject, Segmentation, SegmenterTrainRequest, SlotAssignment};
pub use sim::{DatasetReport, ExecutionReport, SceneInfo, TaskInfo, TrajectoryArrays};
/// The ndarray version the bridge's array calls use.
pub use numpy::ndarray;
pub use worker::Bridge;
