//! Joint-space trajectories: what a model trained on a joint-space recording predicts, and
//! the one form or the other a prediction comes back in ([`Predicted`]).
//!
//! File format (seconds; joint values in the recording's units, e.g. rad; gripper 1 = open):
//! `{"fps": F, "joint_names": [...], "frames": [{"t": s, "joints": [...], "gripper": g}, ...]}`
//! plus any other top-level keys (metadata), kept as they are. A file with `joint_names` is
//! joint space; one without is the end-effector form of [`super::Trajectory`].

use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::{Trajectory, TrajectoryError, check_finite, check_gripper_and_time, parse_error};

/// One time step of a joint-space trajectory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename = "frame")]
pub struct JointFrame {
    /// Time since the start (s).
    pub t: f64,
    /// One value per joint, in `joint_names` order.
    pub joints: Vec<f64>,
    /// Gripper opening in [0, 1], 1 = open.
    pub gripper: f64,
}

/// A validated joint-space trajectory: at least one frame, strictly increasing time, one
/// finite value per named joint, gripper in [0, 1].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename = "trajectory")]
pub struct JointTrajectory {
    /// Nominal sampling rate (Hz, > 0).
    pub fps: f64,
    /// The joints, as the training recording names them.
    pub joint_names: Vec<String>,
    pub frames: Vec<JointFrame>,
    /// Every other top-level key, kept verbatim.
    #[serde(flatten)]
    pub metadata: Map<String, Value>,
}

impl JointTrajectory {
    /// Parses and validates joint-space trajectory JSON.
    pub fn from_json_str(text: &str) -> Result<Self, TrajectoryError> {
        let mut deserializer = serde_json::Deserializer::from_str(text);
        let trajectory: JointTrajectory =
            serde_path_to_error::deserialize(&mut deserializer).map_err(|err| parse_error(text, err))?;
        trajectory.validate()?;
        Ok(trajectory)
    }

    /// Checks every invariant; the error names the first offending frame and field.
    pub fn validate(&self) -> Result<(), TrajectoryError> {
        if !(self.fps.is_finite() && self.fps > 0.0) {
            return Err(TrajectoryError::new("fps", format!("must be a finite number > 0, got {}", self.fps)));
        }
        if self.joint_names.is_empty() {
            return Err(TrajectoryError::new("joint_names", "is empty; a joint-space trajectory names its joints"));
        }
        if self.frames.is_empty() {
            return Err(TrajectoryError::new("frames", "is empty; a trajectory needs at least one frame"));
        }
        for (i, frame) in self.frames.iter().enumerate() {
            let field = |name: &str| format!("frames[{i}].{name}");
            check_finite(&field("t"), &[frame.t])?;
            if frame.joints.len() != self.joint_names.len() {
                return Err(TrajectoryError::new(
                    field("joints"),
                    format!("has {} values for {} joints ({})", frame.joints.len(), self.joint_names.len(), self.joint_names.join(", ")),
                ));
            }
            check_finite(&field("joints"), &frame.joints)?;
            check_gripper_and_time(i, frame.gripper, frame.t, i.checked_sub(1).map(|j| self.frames[j].t))?;
        }
        Ok(())
    }

    /// Time from the first to the last frame (s).
    pub fn duration(&self) -> f64 {
        self.frames[self.frames.len() - 1].t - self.frames[0].t
    }
}

/// A model's predicted trajectory, in the form the model was trained on.
#[derive(Debug, Clone, PartialEq)]
pub enum Predicted {
    /// End-effector poses.
    Pose(Trajectory),
    /// Joint values of the recording's arm.
    Joints(JointTrajectory),
}

impl Predicted {
    /// Parses and validates a prediction's JSON: joint space when it has `joint_names`.
    pub fn from_json_str(text: &str) -> Result<Self, TrajectoryError> {
        let joint_space = serde_json::from_str::<Map<String, Value>>(text)
            .map(|top| top.contains_key("joint_names"))
            .unwrap_or(false);
        if joint_space {
            JointTrajectory::from_json_str(text).map(Predicted::Joints)
        } else {
            Trajectory::from_json_str(text).map(Predicted::Pose)
        }
    }

    /// The file form (pretty-printed, newline-terminated).
    pub fn to_json_string(&self) -> String {
        match self {
            Predicted::Pose(trajectory) => trajectory.to_json_string(),
            // Plain numbers, strings and a JSON map cannot fail to serialise.
            Predicted::Joints(trajectory) => serde_json::to_string_pretty(trajectory).expect("trajectory serialises") + "\n",
        }
    }

    pub fn frame_count(&self) -> usize {
        match self {
            Predicted::Pose(trajectory) => trajectory.frames.len(),
            Predicted::Joints(trajectory) => trajectory.frames.len(),
        }
    }

    pub fn fps(&self) -> f64 {
        match self {
            Predicted::Pose(trajectory) => trajectory.fps,
            Predicted::Joints(trajectory) => trajectory.fps,
        }
    }

    /// Time from the first to the last frame (s).
    pub fn duration(&self) -> f64 {
        match self {
            Predicted::Pose(trajectory) => trajectory.duration(),
            Predicted::Joints(trajectory) => trajectory.duration(),
        }
    }

    /// The top-level keys besides the motion itself.
    pub fn metadata_mut(&mut self) -> &mut Map<String, Value> {
        match self {
            Predicted::Pose(trajectory) => &mut trajectory.metadata,
            Predicted::Joints(trajectory) => &mut trajectory.metadata,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TWO_FRAMES: &str = r#"{"fps": 50, "joint_names": ["a", "b"], "frames": [
        {"t": 0, "joints": [0.1, -0.2], "gripper": 1}, {"t": 0.02, "joints": [0.11, -0.2], "gripper": 0.9}],
        "model": {"task": "t"}}"#;

    #[test]
    fn a_joint_space_prediction_parses_round_trips_and_keeps_its_metadata() {
        let Predicted::Joints(trajectory) = Predicted::from_json_str(TWO_FRAMES).unwrap() else { panic!("not joints") };
        assert_eq!(trajectory.joint_names, ["a", "b"]);
        assert_eq!(trajectory.frames[1].joints, [0.11, -0.2]);
        assert_eq!(trajectory.metadata["model"]["task"], "t");
        let again = Predicted::from_json_str(&Predicted::Joints(trajectory.clone()).to_json_string()).unwrap();
        assert_eq!(again, Predicted::Joints(trajectory));
    }

    #[test]
    fn a_pose_prediction_stays_a_pose() {
        let text = r#"{"fps": 10, "frames": [{"t": 0, "position": [0, 0, 0], "orientation": [1, 0, 0, 0], "gripper": 1}]}"#;
        assert!(matches!(Predicted::from_json_str(text).unwrap(), Predicted::Pose(_)));
    }

    #[test]
    fn bad_joint_frames_are_named() {
        let short = TWO_FRAMES.replace("[0.11, -0.2]", "[0.11]");
        let err = Predicted::from_json_str(&short).unwrap_err();
        assert_eq!(err.location, "frames[1].joints");
        assert!(err.problem.contains("1 values for 2 joints"), "{err}");
        let backwards = TWO_FRAMES.replace("\"t\": 0.02", "\"t\": 0");
        assert_eq!(Predicted::from_json_str(&backwards).unwrap_err().location, "frames[1].t");
        let gripper = TWO_FRAMES.replace("\"gripper\": 0.9", "\"gripper\": 1.5");
        assert_eq!(Predicted::from_json_str(&gripper).unwrap_err().location, "frames[1].gripper");
    }
}
