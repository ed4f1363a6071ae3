//! The one Python worker thread: it holds the interpreter and runs jobs sent over a channel.
//!
//! Measured on 2 cores (../shared/facts.md), one dedicated thread fed by a channel beat
//! `spawn_blocking` per request 2-3x for small requests, and keeps Python glue (which holds
//! the GIL) off the async runtime's threads. The worker stays attached and detaches only
//! while it waits for the next job, so its thread state lives as long as the process.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use crossbeam_channel::{Receiver, Sender};
use pyo3::prelude::*;

use crate::error::BridgeError;
use crate::interpreter::{self, BridgeConfig};

type Job = Box<dyn for<'py> FnOnce(Python<'py>) + Send>;

/// Handle to the embedded interpreter's worker thread. One per process: get it with
/// [`Bridge::start`]; every typed call (see the crate docs) is a method on it.
#[derive(Debug)]
pub struct Bridge {
    jobs: Sender<Job>,
    config: BridgeConfig,
    /// `sys.prefix` as the interpreter reports it (the venv).
    prefix: PathBuf,
}

static BRIDGE: OnceLock<Result<Bridge, BridgeError>> = OnceLock::new();

impl Bridge {
    /// Starts the interpreter on `config.venv` and the worker thread, or returns the bridge
    /// this process already started. Thread limits are applied (`cnfmp.runtime.configure`)
    /// before anything imports torch.
    ///
    /// Errors: [`BridgeError::VenvMissing`] when the venv is not there; [`BridgeError::Start`]
    /// when the interpreter fails, comes up on another prefix, or the process already
    /// started a bridge with a different configuration.
    pub fn start(config: BridgeConfig) -> Result<&'static Bridge, BridgeError> {
        let started = BRIDGE.get_or_init(|| Bridge::spawn(config.clone())).as_ref().map_err(Clone::clone)?;
        if started.config != config {
            return Err(BridgeError::Start(format!(
                "this process already runs Python with {:?}; cannot restart it with {:?}",
                started.config, config
            )));
        }
        Ok(started)
    }

    /// [`Bridge::start`] with [`BridgeConfig::from_env`].
    pub fn start_default() -> Result<&'static Bridge, BridgeError> {
        Bridge::start(BridgeConfig::from_env()?)
    }

    fn spawn(config: BridgeConfig) -> Result<Bridge, BridgeError> {
        let python = config.checked_python()?;
        interpreter::initialize(&python)?;
        let (jobs, inbox) = crossbeam_channel::unbounded::<Job>();
        let (ready_tx, ready_rx) = crossbeam_channel::bounded(1);
        let threads = config.torch_threads;
        std::thread::Builder::new()
            .name("cnfmp-python".into())
            .spawn(move || {
                Python::attach(|py| {
                    let _ = ready_tx.send(configure(py, threads));
                    serve(py, &inbox);
                })
            })
            .map_err(|err| BridgeError::Start(format!("cannot spawn the Python worker thread: {err}")))?;
        let prefix = ready_rx.recv().map_err(|_| BridgeError::WorkerGone)??;
        check_prefix(&prefix, &config.venv)?;
        Ok(Bridge { jobs, config, prefix })
    }

    /// The configuration this bridge was started with.
    pub fn config(&self) -> &BridgeConfig {
        &self.config
    }

    /// `sys.prefix` of the embedded interpreter (always the venv, checked at start).
    pub fn prefix(&self) -> &Path {
        &self.prefix
    }

    /// Runs `job` on the worker thread and waits for its result. A panic inside `job` does
    /// not kill the worker; the caller gets [`BridgeError::Panicked`].
    pub(crate) fn call<R, F>(&self, job: F) -> Result<R, BridgeError>
    where
        R: Send + 'static,
        F: for<'py> FnOnce(Python<'py>) -> Result<R, BridgeError> + Send + 'static,
    {
        let (reply_tx, reply_rx) = crossbeam_channel::bounded(1);
        let boxed: Job = Box::new(move |py| {
            let result = catch_unwind(AssertUnwindSafe(|| job(py))).unwrap_or_else(|panic| {
                let what = panic
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "unknown panic".into());
                Err(BridgeError::Panicked(what))
            });
            let _ = reply_tx.send(result);
        });
        self.jobs.send(boxed).map_err(|_| BridgeError::WorkerGone)?;
        reply_rx.recv().map_err(|_| BridgeError::WorkerGone)?
    }
}

/// Applies thread limits and offline flags; returns `sys.prefix`.
fn configure(py: Python<'_>, threads: usize) -> Result<PathBuf, BridgeError> {
    let run = || -> PyResult<PathBuf> {
        py.import("cnfmp.runtime")?.call_method("configure", (), Some(&kwargs!(py, threads = threads)))?;
        py.import("sys")?.getattr("prefix")?.extract::<PathBuf>()
    };
    run().map_err(|err| match err.is_instance_of::<pyo3::exceptions::PyModuleNotFoundError>(py) {
        true => BridgeError::Start(format!(
            "the venv does not contain the cnfmp package ({}); fix: run `make setup`",
            crate::error::PythonException::from_pyerr(py, &err)
        )),
        false => BridgeError::python(py, &err),
    })
}

fn serve(py: Python<'_>, inbox: &Receiver<Job>) {
    // Detached while waiting, so other threads (and torch's own) may hold the GIL meanwhile.
    while let Ok(job) = py.detach(|| inbox.recv()) {
        job(py);
    }
}

fn check_prefix(prefix: &Path, venv: &Path) -> Result<(), BridgeError> {
    let same = match (prefix.canonicalize(), venv.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    };
    if same {
        Ok(())
    } else {
        Err(BridgeError::Start(format!(
            "the interpreter came up with sys.prefix={} instead of the venv {}; is PYTHONHOME set?",
            prefix.display(),
            venv.display()
        )))
    }
}
