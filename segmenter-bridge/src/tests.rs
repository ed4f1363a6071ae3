//! Tests against the real embedded interpreter on the project venv (one per test process,
//! shared by every test here, as in production).

use std::ffi::CString;

use pyo3::prelude::*;

use crate::ndarray::{ArrayD, IxDyn};
use crate::{Bridge, BridgeConfig, BridgeError};

fn bridge() -> &'static Bridge {
    Bridge::start_default().expect("the project venv must exist: run `make setup`")
}

/// Runs `code` as a module body on the worker and returns the error it raises.
fn raise(code: &str) -> BridgeError {
    let code = CString::new(code).unwrap();
    bridge()
        .call(move |py| py.run(&code, None, None).map_err(|err| BridgeError::python(py, &err)))
        .expect_err("the code must raise")
}

#[test]
fn array_crosses_without_copy_and_comes_back_doubled() {
    let values = ArrayD::from_shape_fn(IxDyn(&[2, 3]), |ix| (ix[0] * 3 + ix[1]) as f64 - 1.5);
    let expected = values.mapv(|v| 2.0 * v);
    let trip = bridge().array_round_trip(values).unwrap();
    assert!(trip.same_buffer, "Python must work on the buffer Rust allocated");
    assert_eq!(trip.values, expected);
}

#[test]
fn interpreter_runs_on_the_venv_with_one_thread() {
    let bridge = bridge();
    let venv = BridgeConfig::from_env().unwrap().venv.canonicalize().unwrap();
    assert_eq!(bridge.prefix().canonicalize().unwrap(), venv);
    let (threads, omp, offline): (i64, String, String) = bridge
        .call(|py| {
            let run = || -> PyResult<_> {
                let torch_threads = py.import("torch")?.call_method0("get_num_threads")?.extract()?;
                let environ = py.import("os")?.getattr("environ")?;
                Ok((torch_threads, environ.get_item("OMP_NUM_THREADS")?.extract()?, environ.get_item("HF_HUB_OFFLINE")?.extract()?))
            };
            run().map_err(|err| BridgeError::python(py, &err))
        })
        .unwrap();
    assert_eq!((threads, omp.as_str(), offline.as_str()), (1, "1", "1"));
}

#[test]
fn python_exception_carries_type_message_and_traceback() {
    let err = raise("def inner():\n    raise ValueError('scene 7 has no objects')\n\ndef outer():\n    inner()\n\nouter()\n");
    let BridgeError::Python(exc) = err else { panic!("expected a Python error, got {err:?}") };
    assert_eq!(exc.type_name, "ValueError");
    assert_eq!(exc.message, "scene 7 has no objects");
    let last = exc.traceback.last().expect("a traceback");
    assert!(last.contains("line 2, in inner"), "{last}");
    assert!(exc.traceback.iter().any(|frame| frame.contains("in outer")));
    assert!(exc.to_string().starts_with("ValueError: scene 7 has no objects (File"), "{exc}");
}

#[test]
fn exception_from_package_code_names_its_module() {
    let err = bridge()
        .call(|py| {
            let module = py.import("cnfmp.runtime").map_err(|e| BridgeError::python(py, &e))?;
            module.call_method1("bridge_selftest", ("not an array",)).map(|_| ()).map_err(|e| BridgeError::python(py, &e))
        })
        .unwrap_err();
    let BridgeError::Python(exc) = err else { panic!("expected a Python error") };
    assert_eq!(exc.type_name, "TypeError");
    assert!(exc.message.contains("expected a float64 numpy array, got str"), "{}", exc.message);
    let last = exc.traceback.last().unwrap();
    assert!(last.contains("runtime.py") && last.contains("raise TypeError"), "frame with source line: {last}");
}

#[test]
fn non_builtin_exception_type_is_module_qualified() {
    let err = raise("import json\njson.loads('{')\n");
    let BridgeError::Python(exc) = err else { panic!("expected a Python error") };
    assert_eq!(exc.type_name, "json.decoder.JSONDecodeError");
}

#[test]
fn worker_survives_a_panicking_call() {
    let err = bridge().call(|_py| -> Result<(), BridgeError> { panic!("boom") }).unwrap_err();
    assert!(matches!(&err, BridgeError::Panicked(what) if what == "boom"), "{err:?}");
    let trip = bridge().array_round_trip(ArrayD::from_elem(IxDyn(&[1]), 4.0)).unwrap();
    assert_eq!(trip.values[[0]], 8.0);
}

#[test]
fn restarting_with_another_configuration_is_refused() {
    let mut other = bridge().config().clone();
    other.torch_threads += 1;
    let err = Bridge::start(other).unwrap_err();
    assert!(err.to_string().contains("cannot restart"), "{err}");
}

#[test]
fn missing_venv_is_reported_with_the_fix() {
    let dir = std::env::temp_dir().join("cnfmp-no-such-venv");
    let config = BridgeConfig { venv: dir.clone(), torch_threads: 1 };
    let err = config.checked_python().unwrap_err();
    assert!(matches!(err, BridgeError::VenvMissing { .. }));
    let text = err.to_string();
    assert!(text.contains("pyvenv.cfg does not exist") && text.contains("make setup"), "{text}");
    assert!(text.contains(&dir.display().to_string()));
}
