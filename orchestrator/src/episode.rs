//! One simulated episode, the steps every evaluation shares: render a scene of (task, seed),
//! execute a predicted trajectory by physics, judge it, and measure its distance to the
//! scripted expert (MED). `cnfmp eval` predicts in process between render and execute,
//! `cnfmp demo` over HTTP; the Table-I benchmark runs `cnfmp eval`.

use std::path::PathBuf;

use segmenter_bridge::ndarray::{Array1, Array2};
use segmenter_bridge::{Bridge, BridgeError, SceneInfo};
use serde_json::Map;
use tempfile::TempDir;

use crate::failure::Failure;
use crate::files::read_bytes;
use crate::trajectory::Trajectory;
use crate::trajectory::compare::mean_euclidean_distance_cm;
use crate::trajectory::joints::Predicted;
use crate::trajectory::resample::{ResampleTarget, resample};

/// The simulator as evaluations use it: rendered scenes go to a scratch directory that
/// lives as long as this value.
pub struct Simulator<'a> {
    bridge: &'a Bridge,
    /// The simulator's control rate (Hz): trajectories are executed and compared at it.
    control_hz: f64,
    scratch: TempDir,
}

/// A rendered scene: what a camera saw and what the simulator knows of it.
pub struct RenderedScene {
    pub info: SceneInfo,
    /// The image (PNG) and the label map of its objects (PNG; label k = `info.objects[k-1]`).
    pub image: Vec<u8>,
    pub masks: Vec<u8>,
    /// The scan directory (`cnfmp.scan`), when the scene was rendered with its scan.
    pub scan: Option<PathBuf>,
}

/// The judge's verdict on a trajectory, or why it could not be executed.
pub struct Verdict {
    pub success: bool,
    /// Why it failed (empty on success).
    pub reasons: Vec<String>,
}

impl<'a> Simulator<'a> {
    pub fn new(bridge: &'a Bridge) -> Result<Self, Failure> {
        let scratch = tempfile::tempdir()
            .map_err(|err| Failure::Environment(format!("cannot create a temporary directory: {err}")))?;
        Ok(Simulator { bridge, control_hz: bridge.sim_control_hz()?, scratch })
    }

    /// Renders the scene of (`task`, `seed`), with its scan when `scan`.
    pub fn render(&self, task: &str, seed: u64, scan: bool) -> Result<RenderedScene, Failure> {
        let dir = self.scratch.path().join(format!("{task}-{seed}"));
        if dir.exists() {
            // A second render of the same scene (a rerun in one process) starts clean.
            std::fs::remove_dir_all(&dir).map_err(|err| Failure::Environment(format!("cannot clear {}: {err}", dir.display())))?;
        }
        let info = self.bridge.sim_render(task, seed, &dir, scan)?;
        let read = |name: &str, what: &str| read_bytes(&dir.join(name), what);
        Ok(RenderedScene {
            image: read("image.png", "rendered image")?,
            masks: read("masks.png", "rendered masks")?,
            info,
            scan: scan.then(|| dir.join("scan")),
        })
    }

    /// The tool path of a prediction: its poses, or for a joint-space model the poses the
    /// simulator's arm puts the gripper at (forward kinematics, used only for this check).
    /// Joints that are not the arm's are bad input.
    pub fn tool_path(&self, predicted: Predicted) -> Result<Trajectory, Failure> {
        let joints = match predicted {
            Predicted::Pose(trajectory) => return Ok(trajectory),
            Predicted::Joints(joints) => joints,
        };
        let n = joints.frames.len();
        let values: Vec<f64> = joints.frames.iter().flat_map(|frame| frame.joints.iter().copied()).collect();
        let angles = Array2::from_shape_vec((n, joints.joint_names.len()), values)
            .map_err(|err| Failure::Environment(format!("joint values: {err}")))?;
        let t = Array1::from_iter(joints.frames.iter().map(|frame| frame.t));
        let gripper = Array1::from_iter(joints.frames.iter().map(|frame| frame.gripper));
        let arrays = self.bridge.sim_forward_kinematics(joints.joint_names.clone(), joints.fps, t, angles, gripper)?;
        Trajectory::from_arrays(&arrays, joints.metadata)
            .map_err(|err| Failure::Environment(format!("the arm's forward kinematics gave an invalid trajectory: {err}")))
    }

    /// `trajectory` resampled at the control rate, as it is executed and compared.
    pub fn at_control_rate(&self, trajectory: &Trajectory) -> Result<Trajectory, Failure> {
        Ok(resample(trajectory, ResampleTarget::Fps(self.control_hz))?)
    }

    /// Executes `trajectory` (at the control rate) in the scene and judges it. A trajectory
    /// the simulator refuses (a frame outside the workspace) is a failed episode.
    pub fn execute(&self, task: &str, seed: u64, trajectory: &Trajectory) -> Result<Verdict, Failure> {
        match self.bridge.sim_execute(task, seed, trajectory.to_arrays()) {
            Ok(report) => Ok(Verdict { success: report.success, reasons: report.reasons }),
            Err(BridgeError::InvalidInput(message)) => Ok(Verdict { success: false, reasons: vec![format!("not executed: {message}")] }),
            Err(other) => Err(other.into()),
        }
    }

    /// MED (cm) of `trajectory` (at the control rate) to the scripted expert's.
    pub fn med_cm(&self, task: &str, seed: u64, trajectory: &Trajectory) -> Result<f64, Failure> {
        let (expert, _) = self.bridge.sim_expert(task, seed)?;
        let expert = Trajectory::from_arrays(&expert, Map::new())
            .map_err(|err| Failure::Environment(format!("the {task} expert produced an invalid trajectory: {err}")))?;
        mean_euclidean_distance_cm(trajectory, &expert).map_err(Failure::Environment)
    }
}
