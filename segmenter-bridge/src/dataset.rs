//! Typed calls for dataset conversion and validation: writing staged episodes as a LeRobot
//! dataset and reading episodes back (`cnfmp.data.lerobot_io`), and reading robomimic-style
//! HDF5 demos (`cnfmp.data.hdf5`).

use std::path::{Path, PathBuf};

use numpy::ndarray::{Array1, Array2, Array4};
use numpy::{PyReadonlyArray2, PyReadonlyArray4};
use pyo3::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::BridgeError;
use crate::sim::{TrajectoryArrays, item, matrix, vector};
use crate::worker::Bridge;

/// An episode left out of a dataset, and why.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Eq)]
pub struct SkippedEpisode {
    /// The episode's name in the source (folder name, HDF5 demo).
    pub episode: String,
    /// The file (or HDF5 path) at fault.
    pub file: String,
    pub reason: String,
}

/// What [`Bridge::write_staged`] wrote.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Eq)]
pub struct StagedWriteReport {
    pub episodes: u64,
    pub frames: u64,
    /// Staged episodes that could not join the dataset (an image size unlike the first's).
    pub skipped: Vec<SkippedEpisode>,
}

/// The episodes of a LeRobot dataset, for export.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct DatasetEpisodes {
    pub episodes: u64,
    pub fps: f64,
    /// One folder-safe name per episode (recorded at conversion, else `episode_<index>`).
    pub names: Vec<String>,
    /// Frames per episode.
    pub lengths: Vec<u64>,
}

/// One result line of a dataset validation.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Eq)]
pub struct DatasetCheck {
    pub name: String,
    pub ok: bool,
    pub detail: String,
}

/// The states of one episode as lerobot reads them back.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct InspectedEpisode {
    pub index: u64,
    /// Frame times (s).
    pub timestamps: Vec<f64>,
    /// Per frame `[x, y, z, qw, qx, qy, qz, gripper]`, or for a joint-space recording the
    /// joint values in `DatasetInspection::joint_names` order, then the gripper.
    pub state: Vec<Vec<f64>>,
}

/// What lerobot's reader says about a dataset (`cnfmp.data.lerobot_io.inspect`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct DatasetInspection {
    pub checks: Vec<DatasetCheck>,
    pub fps: f64,
    /// The joints of a joint-space recording; `None` for end-effector poses.
    #[serde(default)]
    pub joint_names: Option<Vec<String>>,
    pub episodes: Vec<InspectedEpisode>,
}

/// What an HDF5 file holds (`cnfmp.data.hdf5.list_demos`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct Hdf5Listing {
    /// `demo_<k>` names in numeric order.
    pub demos: Vec<String>,
    /// The control rate the file records (Hz), else robomimic's usual 20 Hz.
    pub fps: f64,
    /// Whether `fps` came from the file.
    pub fps_recorded: bool,
    /// The camera whose images are read (`agentview` when present).
    pub camera: Option<String>,
}

/// One HDF5 demo as arrays (T frames).
#[derive(Debug, Clone, PartialEq)]
pub struct Hdf5Demo {
    /// (T, H, W, 3) RGB.
    pub images: Array4<u8>,
    /// (H, W) label map (0 background, k = objects[k - 1]); zeros when the file has none.
    pub masks: Array2<u8>,
    pub objects: Vec<String>,
    /// (T, 3) metres.
    pub position: Array2<f64>,
    /// (T, 4) `[w, x, y, z]`.
    pub orientation: Array2<f64>,
    /// (T,) opening in [0, 1] (unchecked: the caller validates).
    pub gripper: Array1<f64>,
    pub prompt: String,
}

/// What `cnfmp dataset annotate` asks for (`cnfmp.data.annotate.annotate`).
#[derive(Debug, Clone)]
pub struct AnnotateRequest {
    /// LeRobot dataset without masks.
    pub dataset: PathBuf,
    /// Annotated copy to create (must not exist).
    pub out: PathBuf,
    /// Camera feature to segment; None: the only one.
    pub camera: Option<String>,
    /// Objects to find in every episode, in slot order; None: those each task prompt names.
    pub objects: Option<Vec<String>>,
    pub backend: String,
    pub weights: Option<PathBuf>,
    /// Folder of hand-made label maps `episode_<index>.png`.
    pub masks_dir: Option<PathBuf>,
    /// Task name recorded for the models; None: the dataset folder's name.
    pub task: Option<String>,
}

/// A phrase the segmenter did not find in an episode's first frame.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct MissingObject {
    pub phrase: String,
    /// Best mean probability of a candidate mask (the found threshold is the segmenter's).
    pub score: f64,
}

/// An episode left out of an annotated dataset.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct UnannotatedEpisode {
    pub episode: u64,
    pub prompt: String,
    pub missing: Vec<MissingObject>,
}

/// What [`Bridge::annotate_dataset`] wrote.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct AnnotateReport {
    pub out: String,
    pub episodes: u64,
    pub annotated: u64,
    /// Episodes whose masks came from --masks-dir.
    pub hand_made: u64,
    pub skipped: Vec<UnannotatedEpisode>,
    pub camera: String,
    pub task: String,
    /// Episodes whose segmentation a previous, interrupted run had already done.
    pub resumed: u64,
    /// PNG with one thumbnail per episode, masks overlaid.
    pub contact_sheet: String,
}

impl Bridge {
    /// Adds coarse masks to a LeRobot dataset (a copy at `request.out`), with a progress bar
    /// on stderr. Resumable: an interrupted run's segmentations are reused.
    pub fn annotate_dataset(&self, request: &AnnotateRequest) -> Result<AnnotateReport, BridgeError> {
        let r = request.clone();
        self.call_json("cnfmp.data.annotate", "annotate", move |py| {
            Ok(kwargs!(py, dataset_dir = r.dataset, out_dir = r.out, camera = r.camera, objects = r.objects,
                       backend_name = r.backend, weights = r.weights, masks_dir = r.masks_dir, task = r.task))
        })
    }

    /// Writes the staged episode folders `staging/<name>` (in order) as a LeRobot v3.0 dataset
    /// at `out` (must not exist) at `fps`, with a progress bar on stderr.
    pub fn write_staged(&self, staging: &Path, episodes: Vec<String>, out: &Path, fps: u32) -> Result<StagedWriteReport, BridgeError> {
        let (staging, out) = (staging.to_path_buf(), out.to_path_buf());
        self.call_json("cnfmp.data.lerobot_io", "write_staged", move |py| {
            Ok(kwargs!(py, staging_dir = staging, episode_dirs = episodes, out_dir = out, fps = fps))
        })
    }

    /// The episodes of the LeRobot dataset at `dir`.
    pub fn dataset_episodes(&self, dir: &Path) -> Result<DatasetEpisodes, BridgeError> {
        let dir = dir.to_path_buf();
        self.call_json("cnfmp.data.lerobot_io", "episodes_of", move |py| Ok(kwargs!(py, dataset_dir = dir)))
    }

    /// Writes episode `index` of the dataset at `dir` as a raw episode folder `out` (images,
    /// masks, objects, meta) and returns its trajectory (from `observation.state`), which the
    /// caller writes.
    pub fn export_episode(&self, dir: &Path, index: u64, out: &Path) -> Result<TrajectoryArrays, BridgeError> {
        let (dir, out) = (dir.to_path_buf(), out.to_path_buf());
        self.call_dict(
            "cnfmp.data.lerobot_io",
            "export_episode",
            move |py| Ok(kwargs!(py, dataset_dir = dir, index = index, out_dir = out)),
            TrajectoryArrays::from_dict,
        )
    }

    /// Reads the dataset at `dir` back with lerobot's `LeRobotDataset` (`cnfmp dataset validate`).
    pub fn inspect_dataset(&self, dir: &Path) -> Result<DatasetInspection, BridgeError> {
        let dir = dir.to_path_buf();
        self.call_json("cnfmp.data.lerobot_io", "inspect", move |py| Ok(kwargs!(py, dataset_dir = dir)))
    }

    /// The demos of a robomimic-style HDF5 file.
    pub fn hdf5_demos(&self, file: &Path) -> Result<Hdf5Listing, BridgeError> {
        let file = file.to_path_buf();
        self.call_json("cnfmp.data.hdf5", "list_demos", move |py| Ok(kwargs!(py, path = file)))
    }

    /// Reads one demo of an HDF5 file; a malformed demo is [`BridgeError::InvalidInput`]
    /// naming the HDF5 path at fault.
    pub fn hdf5_demo(&self, file: &Path, demo: &str, camera: Option<String>) -> Result<Hdf5Demo, BridgeError> {
        let (file, demo) = (file.to_path_buf(), demo.to_owned());
        self.call_dict("cnfmp.data.hdf5", "read_demo", move |py| Ok(kwargs!(py, path = file, demo = demo, camera = camera)), |dict| {
            Ok(Hdf5Demo {
                images: item(dict, "images")?.extract::<PyReadonlyArray4<u8>>()?.as_array().to_owned(),
                masks: item(dict, "masks")?.extract::<PyReadonlyArray2<u8>>()?.as_array().to_owned(),
                objects: item(dict, "objects")?.extract()?,
                position: matrix(dict, "position")?,
                orientation: matrix(dict, "orientation")?,
                gripper: vector(dict, "gripper")?,
                prompt: item(dict, "prompt")?.extract()?,
            })
        })
    }
}
