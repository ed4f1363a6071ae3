//! Starting the embedded CPython on the project venv, exactly once per process.
//!
//! The recipe (../shared/facts.md): a `PyConfig` whose `executable` is `<venv>/bin/python3`
//! makes `sys.prefix` the venv and keeps global site-packages out. The interpreter cannot be
//! re-initialised within a process, so the caller ([`crate::Bridge::start`]) guards this with a
//! process-wide `OnceLock`. pyo3's `auto-initialize` feature stays off: any `Python::attach`
//! that ran before this init would panic loudly instead of silently starting the wrong Python.

use std::ffi::{CStr, CString};
use std::mem::MaybeUninit;
use std::os::unix::ffi::OsStrExt;
use std::path::{Path, PathBuf};

use pyo3::ffi;

use crate::error::BridgeError;

/// Where and how to start the embedded interpreter.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BridgeConfig {
    /// The project venv (the directory holding `pyvenv.cfg`).
    pub venv: PathBuf,
    /// torch intra-op (and OpenMP/BLAS) threads, >= 1. One unless measured otherwise.
    pub torch_threads: usize,
}

impl BridgeConfig {
    /// The default configuration: venv from `CNFMP_VENV`, else the venv this binary was
    /// built against (`PYO3_PYTHON`'s venv, recorded by build.rs); threads from
    /// `CNFMP_TORCH_THREADS`, else 1.
    pub fn from_env() -> Result<Self, BridgeError> {
        Self::from_env_or_threads(1)
    }

    /// [`BridgeConfig::from_env`] with `default_threads` where `CNFMP_TORCH_THREADS` is not
    /// set (a command that owns the machine, such as training, uses its cores).
    pub fn from_env_or_threads(default_threads: usize) -> Result<Self, BridgeError> {
        let venv = match std::env::var_os("CNFMP_VENV") {
            Some(path) if !path.is_empty() => PathBuf::from(path),
            _ => match option_env!("CNFMP_BUILD_VENV") {
                Some(path) => PathBuf::from(path),
                None => {
                    return Err(BridgeError::VenvMissing {
                        venv: PathBuf::from("<none>"),
                        reason: "this binary was built without PYO3_PYTHON and CNFMP_VENV is not set".into(),
                    });
                }
            },
        };
        let torch_threads = match std::env::var("CNFMP_TORCH_THREADS") {
            Ok(text) => match text.trim().parse::<usize>() {
                Ok(n) if n >= 1 => n,
                _ => {
                    return Err(BridgeError::Start(format!(
                        "CNFMP_TORCH_THREADS must be a whole number >= 1, got {text:?}"
                    )));
                }
            },
            Err(_) => default_threads.max(1),
        };
        Ok(BridgeConfig { venv, torch_threads })
    }

    /// `<venv>/bin/python3`, after checking the venv looks like one.
    pub(crate) fn checked_python(&self) -> Result<PathBuf, BridgeError> {
        let missing = |reason: String| BridgeError::VenvMissing { venv: self.venv.clone(), reason };
        if !self.venv.join("pyvenv.cfg").is_file() {
            return Err(missing("pyvenv.cfg does not exist (a missing venv would silently fall back to the system interpreter)".into()));
        }
        let python = self.venv.join("bin").join("python3");
        if !python.exists() {
            return Err(missing(format!("{} does not exist", python.display())));
        }
        Ok(python)
    }
}

/// Initialises CPython with `executable` = `python` and releases the GIL.
///
/// # Safety contract (upheld by the caller)
/// Called at most once per process, before any other use of the Python C API.
pub(crate) fn initialize(python: &Path) -> Result<(), BridgeError> {
    let executable = CString::new(python.as_os_str().as_bytes())
        .map_err(|_| BridgeError::Start(format!("venv path contains a NUL byte: {}", python.display())))?;
    // SAFETY: runs once (caller's OnceLock), on a PyConfig we initialise and clear ourselves;
    // every PyStatus is checked before moving on.
    unsafe {
        if ffi::Py_IsInitialized() != 0 {
            return Err(BridgeError::Start("Python was already initialised by someone else in this process".into()));
        }
        let mut config = MaybeUninit::<ffi::PyConfig>::uninit();
        ffi::PyConfig_InitPythonConfig(config.as_mut_ptr());
        let mut config = config.assume_init();
        let status = ffi::PyConfig_SetBytesString(&mut config, &mut config.executable, executable.as_ptr());
        if ffi::PyStatus_Exception(status) != 0 {
            ffi::PyConfig_Clear(&mut config);
            return Err(BridgeError::Start(status_message("setting PyConfig.executable", status)));
        }
        let status = ffi::Py_InitializeFromConfig(&config);
        ffi::PyConfig_Clear(&mut config);
        if ffi::PyStatus_Exception(status) != 0 {
            return Err(BridgeError::Start(status_message("Py_InitializeFromConfig", status)));
        }
        // The initialising thread holds the GIL; hand it back so the worker can attach.
        ffi::PyEval_SaveThread();
    }
    Ok(())
}

fn status_message(step: &str, status: ffi::PyStatus) -> String {
    let detail = if status.err_msg.is_null() {
        format!("exit code {}", status.exitcode)
    } else {
        // SAFETY: CPython sets err_msg to a static NUL-terminated string.
        unsafe { CStr::from_ptr(status.err_msg) }.to_string_lossy().into_owned()
    };
    format!("{step} failed: {detail}")
}
