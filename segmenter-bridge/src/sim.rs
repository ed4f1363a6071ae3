//! Typed calls into the simulator (`cnfmp.sim.api`) and the dataset writer
//! (`cnfmp.data.generate`). Trajectories cross as numpy arrays without copies.

use std::path::Path;

use numpy::ndarray::{Array1, Array2};
use numpy::{IntoPyArray, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::error::BridgeError;
use crate::worker::Bridge;

/// A trajectory as arrays: T frames of time (s), TCP position (m), orientation quaternion
/// `[w, x, y, z]` and gripper opening in [0, 1].
#[derive(Debug, Clone, PartialEq)]
pub struct TrajectoryArrays {
    /// Sampling rate (Hz).
    pub fps: f64,
    /// (T,)
    pub t: Array1<f64>,
    /// (T, 3)
    pub position: Array2<f64>,
    /// (T, 4)
    pub orientation: Array2<f64>,
    /// (T,)
    pub gripper: Array1<f64>,
}

/// A benchmark task.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Eq)]
pub struct TaskInfo {
    pub name: String,
    pub description: String,
}

/// What `cnfmp sim render` wrote: the content of `objects.json`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Eq)]
pub struct SceneInfo {
    pub task: String,
    pub seed: u64,
    pub prompt: String,
    /// Object names in label order (label k = objects[k - 1]).
    pub objects: Vec<String>,
}

/// The judge's verdict on an executed trajectory.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct ExecutionReport {
    pub task: String,
    pub seed: u64,
    pub prompt: String,
    pub success: bool,
    /// Why it failed (empty on success).
    pub reasons: Vec<String>,
    /// The measurements the judge used (task-specific).
    pub metrics: serde_json::Value,
    /// Control steps executed, and their duration (s).
    pub frames: u64,
    pub duration_s: f64,
}

/// Summary of a generated dataset.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct DatasetReport {
    pub out: String,
    pub episodes: u64,
    pub frames: u64,
    pub seeds: Vec<u64>,
    /// Seeds whose expert run failed the judge and were replaced by the next seed.
    pub skipped_seeds: Vec<u64>,
    pub seconds: f64,
    pub episodes_per_second: f64,
}

/// `dict[key]`, or a KeyError naming it (for the calls that return dicts of arrays).
pub(crate) fn item<'py>(dict: &Bound<'py, PyDict>, key: &str) -> PyResult<Bound<'py, PyAny>> {
    dict.get_item(key)?.ok_or_else(|| pyo3::exceptions::PyKeyError::new_err(key.to_owned()))
}

/// The answers of a Python batch call that returns one entry per item: its value, read with
/// `read`, or the item's own exception (returned, not raised), which fails that item alone.
pub(crate) fn batch_items<'py, T>(
    py: Python<'py>,
    answers: &Bound<'py, PyAny>,
    read: impl Fn(&Bound<'py, PyAny>) -> PyResult<T>,
) -> PyResult<Vec<Result<T, BridgeError>>> {
    let exception = py.get_type::<pyo3::exceptions::PyBaseException>();
    let mut items = Vec::new();
    for answer in answers.try_iter()? {
        let answer = answer?;
        items.push(if answer.is_instance(&exception)? {
            Err(BridgeError::python(py, &PyErr::from_value(answer)))
        } else {
            Ok(read(&answer)?)
        });
    }
    Ok(items)
}

/// `answers` of the batch call `call`, refused unless there is one per item asked for.
pub(crate) fn one_per_item<T>(answers: Vec<T>, expected: usize, call: &str) -> Result<Vec<T>, BridgeError> {
    if answers.len() == expected {
        Ok(answers)
    } else {
        Err(BridgeError::Protocol(format!("{call} answered {} item(s) of {expected}", answers.len())))
    }
}

pub(crate) fn vector(dict: &Bound<'_, PyDict>, key: &str) -> PyResult<Array1<f64>> {
    Ok(item(dict, key)?.extract::<PyReadonlyArray1<f64>>()?.as_array().to_owned())
}

pub(crate) fn matrix(dict: &Bound<'_, PyDict>, key: &str) -> PyResult<Array2<f64>> {
    Ok(item(dict, key)?.extract::<PyReadonlyArray2<f64>>()?.as_array().to_owned())
}

impl TrajectoryArrays {
    /// Reads `{"fps", "t", "position", "orientation", "gripper"}` from a Python dict.
    pub(crate) fn from_dict(dict: &Bound<'_, PyDict>) -> PyResult<Self> {
        Ok(TrajectoryArrays {
            fps: item(dict, "fps")?.extract()?,
            t: vector(dict, "t")?,
            position: matrix(dict, "position")?,
            orientation: matrix(dict, "orientation")?,
            gripper: vector(dict, "gripper")?,
        })
    }
}

impl Bridge {
    /// Calls `module.function(**kwargs(py))`, which returns a JSON string, and decodes it.
    pub(crate) fn call_json<T, K>(&self, module: &'static str, function: &'static str, kwargs: K) -> Result<T, BridgeError>
    where
        T: DeserializeOwned + Send + 'static,
        K: for<'py> FnOnce(Python<'py>) -> PyResult<Bound<'py, PyDict>> + Send + 'static,
    {
        let json: String = self.call(move |py| {
            let run = || -> PyResult<String> { py.import(module)?.call_method(function, (), Some(&kwargs(py)?))?.extract() };
            run().map_err(|err| BridgeError::python(py, &err))
        })?;
        serde_json::from_str(&json).map_err(|err| BridgeError::Protocol(format!("{module}.{function}: {err}")))
    }

    /// Calls `module.function(**kwargs(py))`, which returns a dict (of arrays), and reads the
    /// result from it with `read` on the Python thread.
    pub(crate) fn call_dict<T, K, F>(&self, module: &'static str, function: &'static str, kwargs: K, read: F) -> Result<T, BridgeError>
    where
        T: Send + 'static,
        K: for<'py> FnOnce(Python<'py>) -> PyResult<Bound<'py, PyDict>> + Send + 'static,
        F: for<'py> FnOnce(&Bound<'py, PyDict>) -> PyResult<T> + Send + 'static,
    {
        self.call(move |py| {
            let run = || -> PyResult<T> {
                let result = py.import(module)?.call_method(function, (), Some(&kwargs(py)?))?;
                read(result.cast::<PyDict>()?)
            };
            run().map_err(|err| BridgeError::python(py, &err))
        })
    }

    /// The benchmark tasks (`cnfmp.sim.api.tasks_json`).
    pub fn sim_tasks(&self) -> Result<Vec<TaskInfo>, BridgeError> {
        self.call_json("cnfmp.sim.api", "tasks_json", |py| Ok(kwargs!(py)))
    }

    /// The rate (Hz) at which the simulator executes trajectories; resample to it before
    /// [`Bridge::sim_execute`].
    pub fn sim_control_hz(&self) -> Result<f64, BridgeError> {
        self.call(|py| {
            let run = || -> PyResult<f64> { py.import("cnfmp.sim.api")?.getattr("CONTROL_HZ")?.extract() };
            run().map_err(|err| BridgeError::python(py, &err))
        })
    }

    /// Renders the (task, seed) scene into `out` (image.png, masks.png, objects.json; with
    /// `scan`, also the four-camera depth scan in `out/scan`; see `cnfmp.sim.api.render`).
    /// `out` must not exist or be empty.
    pub fn sim_render(&self, task: &str, seed: u64, out: &Path, scan: bool) -> Result<SceneInfo, BridgeError> {
        let (task, out) = (task.to_owned(), out.to_path_buf());
        self.call_json("cnfmp.sim.api", "render", move |py| {
            Ok(kwargs!(py, task = task, seed = seed, out_dir = out, scan = scan))
        })
    }

    /// The scripted expert's trajectory for (task, seed), at the control rate, and the prompt.
    pub fn sim_expert(&self, task: &str, seed: u64) -> Result<(TrajectoryArrays, String), BridgeError> {
        let task = task.to_owned();
        self.call_dict("cnfmp.sim.api", "expert", move |py| Ok(kwargs!(py, task = task, seed = seed)), |dict| {
            Ok((TrajectoryArrays::from_dict(dict)?, item(dict, "prompt")?.extract()?))
        })
    }

    /// The tool poses of a joint-space trajectory of the simulator's arm
    /// (`cnfmp.sim.api.forward_kinematics`): `t` (T,) s, `joints` (T, J) rad named
    /// `joint_names`, `gripper` (T,). Joints that are not the arm's are
    /// [`BridgeError::InvalidInput`].
    pub fn sim_forward_kinematics(
        &self,
        joint_names: Vec<String>,
        fps: f64,
        t: Array1<f64>,
        joints: Array2<f64>,
        gripper: Array1<f64>,
    ) -> Result<TrajectoryArrays, BridgeError> {
        self.call_dict(
            "cnfmp.sim.api",
            "forward_kinematics",
            move |py| {
                Ok(kwargs!(py, joint_names = joint_names, fps = fps, t = t.into_pyarray(py),
                           joints = joints.into_pyarray(py), gripper = gripper.into_pyarray(py)))
            },
            |dict| TrajectoryArrays::from_dict(dict),
        )
    }

    /// Executes `trajectory` (sampled at [`Bridge::sim_control_hz`]) in the (task, seed)
    /// scene by physics and returns the judge's verdict. A frame outside the workspace is
    /// [`BridgeError::InvalidInput`].
    pub fn sim_execute(&self, task: &str, seed: u64, trajectory: TrajectoryArrays) -> Result<ExecutionReport, BridgeError> {
        let task = task.to_owned();
        let json: String = self.call(move |py| {
            let TrajectoryArrays { position, orientation, gripper, .. } = trajectory;
            let run = || -> PyResult<String> {
                let kwargs = kwargs!(py, task = task, seed = seed, position = position.into_pyarray(py),
                                     orientation = orientation.into_pyarray(py), gripper = gripper.into_pyarray(py));
                py.import("cnfmp.sim.api")?.call_method("execute", (), Some(&kwargs))?.extract()
            };
            run().map_err(|err| BridgeError::python(py, &err))
        })?;
        serde_json::from_str(&json).map_err(|err| BridgeError::Protocol(format!("cnfmp.sim.api.execute: {err}")))
    }

    /// Writes a LeRobot v3.0 dataset of `episodes` expert demonstrations of `task` from seeds
    /// `seed`, `seed + 1`, ... into `out` (which must not exist), with `workers` processes
    /// and a progress bar on stderr.
    /// Draws a predicted motion on its scene (`cnfmp.sim.api.draw_trajectory`): the encoded
    /// camera image with the objects of `labels` (an encoded label map of the same size)
    /// tinted, and the TCP path (`position`, (T, 3) m) projected through the front camera with
    /// a ring wherever `gripper` ((T,), [0, 1]) closes or opens. Returns the PNG bytes.
    pub fn sim_draw_trajectory(
        &self,
        image: Vec<u8>,
        labels: Option<Vec<u8>>,
        position: Array2<f64>,
        gripper: Array1<f64>,
    ) -> Result<Vec<u8>, BridgeError> {
        self.call(move |py| {
            let run = || -> PyResult<Vec<u8>> {
                let kwargs = kwargs!(py,
                    image_data = pyo3::types::PyBytes::new(py, &image),
                    labels_data = labels.map(|labels| pyo3::types::PyBytes::new(py, &labels)),
                    position = position.into_pyarray(py),
                    gripper = gripper.into_pyarray(py),
                );
                py.import("cnfmp.sim.api")?.call_method("draw_trajectory", (), Some(&kwargs))?.extract()
            };
            run().map_err(|err| BridgeError::python(py, &err))
        })
    }

    /// Writes a dataset of expert demonstrations (`cnfmp.data.generate.generate_dataset`):
    /// `scan` None for the task's default, `joint_space` for the motion as the simulator
    /// arm's joint angles instead of tool poses.
    #[allow(clippy::too_many_arguments)]
    pub fn dataset_generate(
        &self,
        task: &str,
        episodes: u64,
        seed: u64,
        out: &Path,
        workers: u32,
        scan: Option<bool>,
        joint_space: bool,
    ) -> Result<DatasetReport, BridgeError> {
        let (task, out) = (task.to_owned(), out.to_path_buf());
        self.call_json("cnfmp.data.generate", "generate_dataset", move |py| {
            Ok(kwargs!(py, task = task, episodes = episodes, seed = seed, out_dir = out, workers = workers, scan = scan, joint_space = joint_space))
        })
    }
}
