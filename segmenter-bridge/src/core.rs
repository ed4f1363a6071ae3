//! Typed calls into the compositional NF-MP core (`cnfmp.core.api`): training a model from a
//! LeRobot dataset and predicting a trajectory for a scene image and its coarse masks.

use std::path::{Path, PathBuf};

use pyo3::prelude::*;
use pyo3::types::PyBytes;
use serde::{Deserialize, Serialize};

use crate::error::BridgeError;
use crate::sim::{batch_items, one_per_item};
use crate::worker::Bridge;

/// What `cnfmp train` asks for.
#[derive(Debug, Clone)]
pub struct TrainRequest {
    /// LeRobot v3.0 dataset directory.
    pub dataset: PathBuf,
    /// Model directory to create (must not exist).
    pub out: PathBuf,
    /// JSON config files (fields of the model type's config dataclass), layered in order: a
    /// later file's field wins. None: the defaults.
    pub configs: Vec<PathBuf>,
    /// Model type (`cnfmp`, `cnfmp-nogate`, `cnn-cnmp`, `nfmp`); None = the config file's,
    /// else `cnfmp`.
    pub model_type: Option<String>,
    /// Overrides of the config's steps and seed.
    pub steps: Option<u64>,
    pub seed: Option<u64>,
    /// The command line, recorded in the model card.
    pub command: String,
    /// The camera feature of the scenes (None: the annotated one, else the only one).
    pub camera: Option<String>,
    /// The feature the trajectories come from: `action` or `observation.state`.
    pub motion_from: String,
    /// Names of the motion vector's dimensions, overriding the dataset's.
    pub motion_names: Option<Vec<String>>,
    /// Align the demonstrations by their gripper events before training.
    pub align_time: bool,
}

/// Summary of a finished training run.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct TrainReport {
    pub out: String,
    pub task: String,
    pub model_type: String,
    pub demos: u64,
    pub steps: u64,
    /// Wall time of the optimisation (s).
    pub seconds: f64,
    /// Final training losses by name (normalised units), e.g. `image_mse`, `motion_mse`
    /// (which ones depends on the model type).
    pub final_losses: std::collections::BTreeMap<String, f64>,
    /// Network and latent parameters (without the per-demonstration simplex weights).
    pub parameters: u64,
    /// How the run chose among several initialisations (cnfmp's `draws` > 1), else absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub draws: Option<DrawChoice>,
}

/// The choice among a training run's initialisations ("draws").
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct DrawChoice {
    /// Initialisations trained.
    pub count: u32,
    /// Steps each trained before the choice.
    pub steps: u64,
    /// The one that went on (0-based; draw 0 is the seed's plain run).
    pub chosen: u32,
    /// Each draw's trajectory loss at the choice (normalised units).
    pub motion_mse: Vec<f64>,
}

/// Per object slot: what inference found.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct ObjectEstimate {
    /// 1-based slot = label in the masks.
    pub slot: u32,
    pub name: String,
    pub present: bool,
    /// Simplex weights over the slot's endpoint latents (None when absent).
    pub weights: Option<Vec<f64>>,
    /// Reconstruction error of the object's masked region (MSE on [0, 1] RGB) and as PSNR
    /// (dB): the confidence signal; lower MSE = more confident.
    pub reconstruction_mse: Option<f64>,
    pub psnr_db: Option<f64>,
    /// IoU of the learned mask with the given coarse mask.
    pub mask_iou: Option<f64>,
}

/// Which model produced a prediction.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct ModelInfo {
    pub dir: String,
    /// The task the model was trained on.
    pub task: String,
    #[serde(rename = "type")]
    pub model_type: String,
}

/// How a scan's objects are found from a prompt instead of its label maps: the segmenter
/// `backend` (with `weights`) on each view's RGB image.
#[derive(Debug, Clone)]
pub struct ScanLabelling {
    pub prompt: String,
    pub backend: String,
    pub weights: Option<PathBuf>,
}

/// A prediction: the trajectory JSON of design.md (`fps`, `frames`) plus diagnostics.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Prediction {
    /// The complete JSON document (trajectory and diagnostics), as Python wrote it.
    #[serde(skip)]
    pub json: String,
    pub model: ModelInfo,
    pub objects: Vec<ObjectEstimate>,
    /// Whole-image reconstruction PSNR (dB) at field resolution; None for models without a
    /// scene field (cnn-cnmp).
    pub scene_psnr_db: Option<f64>,
    /// Stage timings (ms): decode_inputs, load_model (near zero once resident), infer_latents,
    /// decode_trajectory, total.
    pub timings_ms: serde_json::Map<String, serde_json::Value>,
    /// The trajectory in the form the model's training data recorded it, for a model
    /// trained on another form than x y z + quaternion + gripper in [0, 1].
    #[serde(default)]
    pub recorded: Option<RecordedMotion>,
}

/// A predicted trajectory in a recording's own form (`cnfmp.data.recorded`): the named
/// dimensions in the recording's order, rotations as recorded (quaternion, rotation vector
/// or Euler angles), the gripper in the recording's units.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct RecordedMotion {
    /// The feature the training trajectories came from (`action` or `observation.state`).
    pub source: String,
    pub names: Vec<String>,
    /// One row per frame of the trajectory, `names.len()` values each.
    pub values: Vec<Vec<f64>>,
}

/// One scene to predict: the encoded image, the label-map masks of the same size, and the
/// names of the labels in order.
#[derive(Debug, Clone)]
pub struct SceneToPredict {
    pub image: Vec<u8>,
    pub masks: Vec<u8>,
    pub objects: Vec<String>,
}

/// A loaded model, as `cnfmp.core.api.describe` reports it.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct ModelDescription {
    pub task: String,
    #[serde(rename = "type")]
    pub model_type: String,
    /// Object slot names (label order) of the training scenes.
    pub objects: Vec<String>,
    /// Slots the model uses (labels beyond are background).
    pub task_objects: u32,
    /// Scenes may hold more objects than the model's slots: those beyond `task_objects` are
    /// taken as background (distractors).
    pub takes_distractors: bool,
    pub parameters: u64,
    /// The prompt role filling each slot, or None when prompts cannot drive this task.
    pub roles: Option<Vec<String>>,
    /// Rate (Hz) and length (s) of the trajectories it produces.
    pub output_fps: f64,
    pub duration_s: f64,
    /// What a scene is for this model: "image" (an image and coarse masks) or "scan"
    /// (calibrated depth views, `cnfmp-3d`).
    #[serde(default = "image_input")]
    pub input: String,
}

fn image_input() -> String {
    "image".into()
}

impl ModelDescription {
    /// Whether the model predicts from scans rather than images.
    pub fn takes_scans(&self) -> bool {
        self.input == "scan"
    }
}

impl Bridge {
    /// Loads the model in `model_dir` (it stays resident for later predictions) and
    /// describes it (`cnfmp.core.api.describe`).
    pub fn core_describe(&self, model_dir: &Path) -> Result<ModelDescription, BridgeError> {
        let model_dir = model_dir.to_path_buf();
        self.call_json("cnfmp.core.api", "describe", move |py| Ok(kwargs!(py, model_dir = model_dir)))
    }

    /// Predicts a synthetic scene with the (resident) model in `model_dir`, so that the first
    /// real prediction does not pay the first call's costs (`cnfmp.core.api.warm_up`).
    /// Returns the time it took (ms).
    pub fn core_warm_up(&self, model_dir: &Path) -> Result<f64, BridgeError> {
        let model_dir = model_dir.to_path_buf();
        self.call_json("cnfmp.core.api", "warm_up", move |py| Ok(kwargs!(py, model_dir = model_dir)))
    }

    /// Starts helper processes that fit objects beside the embedded interpreter
    /// (`cnfmp.core.api.start_helpers`): `count`, or by default one per core the process may
    /// use beyond the first. Call it before the warm-ups. Returns how many run.
    pub fn core_start_helpers(&self, count: Option<u32>) -> Result<u32, BridgeError> {
        self.call_json("cnfmp.core.api", "start_helpers", move |py| Ok(kwargs!(py, count = count)))
    }

    /// Trains a model (`cnfmp.core.api.train`); progress lines go to stderr.
    pub fn core_train(&self, request: &TrainRequest) -> Result<TrainReport, BridgeError> {
        let r = request.clone();
        self.call_json("cnfmp.core.api", "train", move |py| {
            Ok(kwargs!(py, dataset_dir = r.dataset, out_dir = r.out, config_paths = r.configs, steps = r.steps, seed = r.seed,
                       command = r.command, model_type = r.model_type, camera = r.camera,
                       motion_from = r.motion_from, motion_names = r.motion_names, align_time = r.align_time))
        })
    }

    /// Predicts the trajectory for an encoded scene image and label-map masks of the same
    /// size, with `objects` naming the labels in order. The model stays loaded for later calls.
    pub fn core_predict(
        &self,
        model_dir: &Path,
        image: Vec<u8>,
        masks: Vec<u8>,
        objects: Vec<String>,
    ) -> Result<Prediction, BridgeError> {
        let mut answers = self.core_predict_batch(model_dir, vec![SceneToPredict { image, masks, objects }])?;
        answers.pop().unwrap_or_else(|| Err(BridgeError::Protocol("cnfmp.core.api.predict_batch answered nothing".into())))
    }

    /// Predicts several scenes with the (resident) model in `model_dir` in one call
    /// (`cnfmp.core.api.predict_batch`): their objects are fitted together, and each answer is
    /// the one [`Bridge::core_predict`] gives that scene alone (its timings aside). One result
    /// per scene, in order: a scene's bad input fails that scene alone. The outer error is for
    /// the whole call (a model that cannot be loaded, say).
    pub fn core_predict_batch(
        &self,
        model_dir: &Path,
        scenes: Vec<SceneToPredict>,
    ) -> Result<Vec<Result<Prediction, BridgeError>>, BridgeError> {
        let model_dir = model_dir.to_path_buf();
        let count = scenes.len();
        let answers: Vec<Result<String, BridgeError>> = self.call(move |py| {
            let run = || -> PyResult<Vec<Result<String, BridgeError>>> {
                let scenes: Vec<_> = scenes
                    .into_iter()
                    .map(|s| (PyBytes::new(py, &s.image), PyBytes::new(py, &s.masks), s.objects))
                    .collect();
                let kwargs = kwargs!(py, model_dir = model_dir, scenes = scenes);
                let answers = py.import("cnfmp.core.api")?.call_method("predict_batch", (), Some(&kwargs))?;
                batch_items(py, &answers, |answer| answer.extract::<String>())
            };
            run().map_err(|err| BridgeError::python(py, &err))
        })?;
        Ok(one_per_item(answers, count, "cnfmp.core.api.predict_batch")?
            .into_iter()
            .map(|answer| {
                let json = answer?;
                let mut prediction: Prediction = serde_json::from_str(&json)
                    .map_err(|err| BridgeError::Protocol(format!("cnfmp.core.api.predict_batch: {err}")))?;
                prediction.json = json;
                Ok(prediction)
            })
            .collect())
    }

    /// Predicts the trajectory for the scan in `scan_dir` (`cameras.json` with depth and label
    /// maps, `cnfmp.scan`) with the (resident) cnfmp-3d model in `model_dir`
    /// (`cnfmp.core.api.predict_scan`); with `figure`, also writes the picture of the scan's
    /// points, the reconstructed surface and the path there (PNG). A bad scan is `InvalidInput`.
    /// With `labelling`, the scan's label maps are the segmenter's on its RGB views for a prompt.
    pub fn core_predict_scan(
        &self,
        model_dir: &Path,
        scan_dir: &Path,
        figure: Option<&Path>,
        labelling: Option<ScanLabelling>,
    ) -> Result<Prediction, BridgeError> {
        let (model_dir, scan_dir, figure) = (model_dir.to_path_buf(), scan_dir.to_path_buf(), figure.map(Path::to_path_buf));
        let json: String = self.call(move |py| {
            let run = || -> PyResult<String> {
                let kwargs = kwargs!(py, model_dir = model_dir, scan_dir = scan_dir, figure = figure);
                if let Some(labelling) = labelling {
                    kwargs.set_item("prompt", labelling.prompt)?;
                    kwargs.set_item("backend_name", labelling.backend)?;
                    kwargs.set_item("weights", labelling.weights)?;
                }
                py.import("cnfmp.core.api")?.call_method("predict_scan", (), Some(&kwargs))?.extract()
            };
            run().map_err(|err| BridgeError::python(py, &err))
        })?;
        let mut prediction: Prediction = serde_json::from_str(&json)
            .map_err(|err| BridgeError::Protocol(format!("cnfmp.core.api.predict_scan: {err}")))?;
        prediction.json = json;
        Ok(prediction)
    }

    /// Draws the benchmark chart (`cnfmp.core.report.table_chart`): MED and success per task
    /// for each method, from `results_json` (a list of objects with `method`, `task`, `med_cm`,
    /// `success_rate`), methods and tasks in the given order. Returns PNG bytes.
    pub fn core_table_chart(&self, results_json: &str, methods: &[String], tasks: &[String]) -> Result<Vec<u8>, BridgeError> {
        let (results_json, methods, tasks) = (results_json.to_owned(), methods.to_vec(), tasks.to_vec());
        self.call(move |py| {
            let run = || -> PyResult<Vec<u8>> {
                let kwargs = kwargs!(py, results_json = results_json, methods = methods, tasks = tasks);
                py.import("cnfmp.core.report")?.call_method("table_chart", (), Some(&kwargs))?.extract()
            };
            run().map_err(|err| BridgeError::python(py, &err))
        })
    }

    /// Draws the data-efficiency chart (`cnfmp.core.report.curve_chart`): success and MED
    /// against the number of demonstrations, one line per task, from `results_json` (a list
    /// of objects with `task`, `demos`, `med_cm`, `success_rate`). Returns PNG bytes.
    pub fn core_curve_chart(&self, results_json: &str, tasks: &[String], sizes: &[usize]) -> Result<Vec<u8>, BridgeError> {
        let (results_json, tasks, sizes) = (results_json.to_owned(), tasks.to_vec(), sizes.to_vec());
        self.call(move |py| {
            let run = || -> PyResult<Vec<u8>> {
                let kwargs = kwargs!(py, results_json = results_json, tasks = tasks, sizes = sizes);
                py.import("cnfmp.core.report")?.call_method("curve_chart", (), Some(&kwargs))?.extract()
            };
            run().map_err(|err| BridgeError::python(py, &err))
        })
    }
}
