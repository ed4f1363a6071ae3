//! End-effector trajectories: poses, the trajectory JSON file format of design.md, and its
//! validation with errors that name the frame and field.
//!
//! File format (seconds, metres, quaternion `[w, x, y, z]`, gripper 1 = open):
//! `{"fps": F, "frames": [{"t": s, "position": [x,y,z], "orientation": [w,x,y,z], "gripper": g}, ...]}`
//! plus any other top-level keys (metadata), which are kept as they are.

pub mod compare;
pub mod joints;
pub mod csv;
pub mod resample;
pub mod smooth;
pub mod so3;
pub mod summary;

use std::fmt;
use std::path::Path;

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use segmenter_bridge::TrajectoryArrays;
use segmenter_bridge::ndarray::{self, Array1, Array2};
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

/// How far a file's quaternion norm may be from 1 before it is rejected (files written with
/// 6 decimals are ~1e-6 off; anything beyond this is a bug upstream, not rounding).
pub const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;

/// A rigid pose: position (m, world frame) and orientation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub position: Vector3<f64>,
    pub orientation: UnitQuaternion<f64>,
}

/// One time step of an end-effector trajectory.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    /// Time since the start of the recording (s).
    pub t: f64,
    pub pose: Pose,
    /// Gripper opening in [0, 1], 1 = open.
    pub gripper: f64,
}

/// A validated trajectory: at least one frame, strictly increasing time, unit quaternions,
/// finite numbers, gripper in [0, 1].
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    /// Nominal sampling rate (Hz, > 0). Frame times are authoritative.
    pub fps: f64,
    pub frames: Vec<Frame>,
    /// Every other top-level key of the file, kept verbatim.
    pub metadata: Map<String, Value>,
}

/// Why a trajectory was rejected: where (`frames[3].orientation`, `fps`, `file`) and what.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TrajectoryError {
    pub location: String,
    pub problem: String,
}

impl TrajectoryError {
    pub fn new(location: impl Into<String>, problem: impl Into<String>) -> Self {
        TrajectoryError { location: location.into(), problem: problem.into() }
    }
}

impl fmt::Display for TrajectoryError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.location, self.problem)
    }
}

impl std::error::Error for TrajectoryError {}

/// The file layout, before validation (serde names them in its messages).
#[derive(Serialize, Deserialize)]
#[serde(rename = "frame")]
struct FileFrame {
    t: f64,
    position: [f64; 3],
    orientation: [f64; 4],
    gripper: f64,
}

#[derive(Serialize, Deserialize)]
#[serde(rename = "trajectory")]
struct FileTrajectory {
    fps: f64,
    frames: Vec<FileFrame>,
    #[serde(flatten)]
    metadata: Map<String, Value>,
}

impl Trajectory {
    /// Builds a trajectory from frames, checking every invariant.
    pub fn new(fps: f64, frames: Vec<Frame>, metadata: Map<String, Value>) -> Result<Self, TrajectoryError> {
        let trajectory = Trajectory { fps, frames, metadata };
        trajectory.validate()?;
        Ok(trajectory)
    }

    /// Parses and validates trajectory JSON.
    pub fn from_json_str(text: &str) -> Result<Self, TrajectoryError> {
        let mut deserializer = serde_json::Deserializer::from_str(text);
        let file: FileTrajectory = serde_path_to_error::deserialize(&mut deserializer)
            .map_err(|err| parse_error(text, err))?;
        deserializer.end().map_err(|err| TrajectoryError::new("file", format!("not valid JSON: {err}")))?;

        let mut frames = Vec::with_capacity(file.frames.len());
        for (i, raw) in file.frames.iter().enumerate() {
            let field = |name: &str| format!("frames[{i}].{name}");
            check_finite(&field("t"), &[raw.t])?;
            check_finite(&field("position"), &raw.position)?;
            check_finite(&field("orientation"), &raw.orientation)?;
            check_finite(&field("gripper"), &[raw.gripper])?;
            let [w, x, y, z] = raw.orientation;
            let quaternion = Quaternion::new(w, x, y, z);
            let norm = quaternion.norm();
            if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
                return Err(TrajectoryError::new(
                    field("orientation"),
                    format!("quaternion [w,x,y,z] = {:?} has norm {norm:.6}, not 1 (tolerance {QUATERNION_NORM_TOLERANCE})", raw.orientation),
                ));
            }
            frames.push(Frame {
                t: raw.t,
                pose: Pose {
                    position: Vector3::from(raw.position),
                    orientation: UnitQuaternion::from_quaternion(quaternion),
                },
                gripper: raw.gripper,
            });
        }
        Trajectory::new(file.fps, frames, file.metadata)
    }

    /// Reads and validates a trajectory file. Errors name the file.
    pub fn load(path: &Path) -> Result<Self, TrajectoryError> {
        let text = std::fs::read_to_string(path)
            .map_err(|err| TrajectoryError::new(path.display().to_string(), format!("cannot read: {err}")))?;
        Trajectory::from_json_str(&text).map_err(|err| TrajectoryError {
            location: format!("{}: {}", path.display(), err.location),
            problem: err.problem,
        })
    }

    /// Serialises to the file format (full f64 precision, pretty-printed).
    pub fn to_json_string(&self) -> String {
        let file = FileTrajectory {
            fps: self.fps,
            frames: self
                .frames
                .iter()
                .map(|frame| {
                    let q = frame.pose.orientation.quaternion();
                    FileFrame {
                        t: frame.t,
                        position: frame.pose.position.into(),
                        orientation: [q.w, q.i, q.j, q.k],
                        gripper: frame.gripper,
                    }
                })
                .collect(),
            metadata: self.metadata.clone(),
        };
        // Serialising plain numbers and a JSON map cannot fail.
        serde_json::to_string_pretty(&file).expect("trajectory serialises") + "\n"
    }

    /// Checks every invariant; the error names the first offending frame and field.
    pub fn validate(&self) -> Result<(), TrajectoryError> {
        if !(self.fps.is_finite() && self.fps > 0.0) {
            return Err(TrajectoryError::new("fps", format!("must be a finite number > 0, got {}", self.fps)));
        }
        if self.frames.is_empty() {
            return Err(TrajectoryError::new("frames", "is empty; a trajectory needs at least one frame"));
        }
        for (i, frame) in self.frames.iter().enumerate() {
            let field = |name: &str| format!("frames[{i}].{name}");
            check_finite(&field("t"), &[frame.t])?;
            check_finite(&field("position"), frame.pose.position.as_slice())?;
            check_finite(&field("orientation"), frame.pose.orientation.coords.as_slice())?;
            check_gripper_and_time(i, frame.gripper, frame.t, i.checked_sub(1).map(|j| self.frames[j].t))?;
        }
        Ok(())
    }

    /// The frames as arrays for the bridge (positions, `[w, x, y, z]` quaternions, gripper).
    pub fn to_arrays(&self) -> TrajectoryArrays {
        let n = self.frames.len();
        let mut arrays = TrajectoryArrays {
            fps: self.fps,
            t: Array1::zeros(n),
            position: Array2::zeros((n, 3)),
            orientation: Array2::zeros((n, 4)),
            gripper: Array1::zeros(n),
        };
        for (i, frame) in self.frames.iter().enumerate() {
            let q = frame.pose.orientation.quaternion();
            arrays.t[i] = frame.t;
            arrays.position.row_mut(i).assign(&ndarray::arr1(frame.pose.position.as_slice()));
            arrays.orientation.row_mut(i).assign(&ndarray::arr1(&[q.w, q.i, q.j, q.k]));
            arrays.gripper[i] = frame.gripper;
        }
        arrays
    }

    /// Builds and validates a trajectory from bridge arrays (quaternions `[w, x, y, z]`, unit
    /// within [`QUATERNION_NORM_TOLERANCE`], renormalised).
    pub fn from_arrays(arrays: &TrajectoryArrays, metadata: Map<String, Value>) -> Result<Self, TrajectoryError> {
        let n = arrays.t.len();
        if arrays.position.dim() != (n, 3) || arrays.orientation.dim() != (n, 4) || arrays.gripper.len() != n {
            return Err(TrajectoryError::new(
                "arrays",
                format!("shapes t {:?}, position {:?}, orientation {:?}, gripper {:?} do not describe {n} frames", arrays.t.dim(), arrays.position.dim(), arrays.orientation.dim(), arrays.gripper.dim()),
            ));
        }
        let mut frames = Vec::with_capacity(n);
        for i in 0..n {
            let (p, q) = (arrays.position.row(i), arrays.orientation.row(i));
            let quaternion = Quaternion::new(q[0], q[1], q[2], q[3]);
            let norm = quaternion.norm();
            if norm.is_finite() && (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
                return Err(TrajectoryError::new(
                    format!("frames[{i}].orientation"),
                    format!("quaternion [w,x,y,z] = [{}, {}, {}, {}] has norm {norm:.6}, not 1 (tolerance {QUATERNION_NORM_TOLERANCE})", q[0], q[1], q[2], q[3]),
                ));
            }
            frames.push(Frame {
                t: arrays.t[i],
                pose: Pose {
                    position: Vector3::new(p[0], p[1], p[2]),
                    orientation: UnitQuaternion::from_quaternion(quaternion),
                },
                gripper: arrays.gripper[i],
            });
        }
        Trajectory::new(arrays.fps, frames, metadata)
    }

    /// Start time (s).
    pub fn start(&self) -> f64 {
        self.frames[0].t
    }

    /// Time from the first to the last frame (s).
    pub fn duration(&self) -> f64 {
        self.frames[self.frames.len() - 1].t - self.frames[0].t
    }
}

fn check_finite(location: &str, values: &[f64]) -> Result<(), TrajectoryError> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(k) if values.len() == 1 => Err(TrajectoryError::new(location, format!("{} is not a finite number", values[k]))),
        Some(k) => Err(TrajectoryError::new(format!("{location}[{k}]"), format!("{} is not a finite number", values[k]))),
    }
}

/// Frame `i`'s gripper (finite, in [0, 1]) and time `t` (s, after the previous frame's).
fn check_gripper_and_time(i: usize, gripper: f64, t: f64, previous_t: Option<f64>) -> Result<(), TrajectoryError> {
    let field = |name: &str| format!("frames[{i}].{name}");
    check_finite(&field("gripper"), &[gripper])?;
    if !(0.0..=1.0).contains(&gripper) {
        return Err(TrajectoryError::new(field("gripper"), format!("{gripper} is outside [0, 1] (1 = open)")));
    }
    match previous_t {
        Some(previous) if t <= previous => Err(TrajectoryError::new(
            field("t"),
            format!("time {t} s does not increase (frames[{}].t = {previous} s)", i - 1),
        )),
        _ => Ok(()),
    }
}

/// Turns a serde error into one that names the field (`frames[2].gripper`) and, for the
/// non-JSON tokens some writers emit for non-finite floats (`NaN`, `Infinity`), says so.
fn parse_error(text: &str, err: serde_path_to_error::Error<serde_json::Error>) -> TrajectoryError {
    let path = err.path().to_string();
    let inner = err.into_inner();
    let location = if path.is_empty() || path == "." { "file".to_owned() } else { path };
    if inner.is_syntax() || inner.is_eof() {
        let token = token_at(text, inner.line(), inner.column());
        if let Some(bad) = ["NaN", "-NaN", "Infinity", "-Infinity", "inf", "-inf", "nan"].iter().find(|t| token.starts_with(**t)) {
            return TrajectoryError::new(
                location,
                format!("non-finite number `{bad}` at line {} column {}; trajectory files must hold finite numbers", inner.line(), inner.column()),
            );
        }
        return TrajectoryError::new("file", format!("not valid JSON: {inner}"));
    }
    TrajectoryError::new(location, inner.to_string())
}

/// The token around (1-based line, 1-based column), where serde_json stopped; it may stop
/// inside the token, so back up to its first character.
fn token_at(text: &str, line: usize, column: usize) -> &str {
    let Some(line_text) = text.lines().nth(line.saturating_sub(1)) else { return "" };
    let bytes = line_text.as_bytes();
    let mut start = column.saturating_sub(1).min(bytes.len());
    while start > 0 && (bytes[start - 1].is_ascii_alphanumeric() || bytes[start - 1] == b'-') {
        start -= 1;
    }
    line_text.get(start..).unwrap_or("")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame_json(t: f64) -> String {
        format!(r#"{{"t": {t}, "position": [0.1, 0.2, 0.3], "orientation": [1, 0, 0, 0], "gripper": 1}}"#)
    }

    #[test]
    fn parses_and_keeps_metadata() {
        let text = format!(r#"{{"fps": 10, "frames": [{}, {}], "task": "wall_avoidance"}}"#, frame_json(0.0), frame_json(0.1));
        let trajectory = Trajectory::from_json_str(&text).unwrap();
        assert_eq!(trajectory.frames.len(), 2);
        assert_eq!(trajectory.metadata["task"], "wall_avoidance");
        let again = Trajectory::from_json_str(&trajectory.to_json_string()).unwrap();
        assert_eq!(again, trajectory);
    }

    #[test]
    fn nan_token_is_named() {
        let text = r#"{"fps": 10, "frames": [{"t": 0, "position": [NaN, 0, 0], "orientation": [1,0,0,0], "gripper": 1}]}"#;
        let err = Trajectory::from_json_str(text).unwrap_err();
        assert!(err.problem.contains("non-finite number `NaN`"), "{err}");
        assert!(err.location.contains("frames[0].position"), "{err}");
    }

    #[test]
    fn empty_frames_rejected() {
        let err = Trajectory::from_json_str(r#"{"fps": 10, "frames": []}"#).unwrap_err();
        assert_eq!(err.location, "frames");
    }

    #[test]
    fn trailing_garbage_rejected() {
        let text = format!(r#"{{"fps": 10, "frames": [{}]}} extra"#, frame_json(0.0));
        let err = Trajectory::from_json_str(&text).unwrap_err();
        assert!(err.problem.starts_with("not valid JSON"), "{err}");
    }
}
