//! `cnfmp dataset validate DIR`: is this a LeRobot dataset cnfmp (and lerobot) can use?
//! Three layers: lerobot's own `LeRobotDataset` reads it back (through the bridge), our
//! checks of the annotations and of every episode's trajectory (the Rust trajectory code),
//! and lerobot-doctor's diagnostics when it is installed in the venv.

use std::path::Path;
use std::process::Command;

use segmenter_bridge::{Bridge, DatasetCheck, InspectedEpisode, TrajectoryArrays};
use segmenter_bridge::ndarray::{Array1, Array2};
use serde::Serialize;
use serde_json::{Map, Value};

use crate::failure::Failure;
use crate::trajectory::joints::{JointFrame, JointTrajectory};
use crate::trajectory::{Trajectory, TrajectoryError};

/// lerobot-doctor checks we run: all but `anomalies`, which crashes on 2-D features such as
/// our masks (facts.md).
const DOCTOR_CHECKS: &str = "metadata,temporal,actions,videos,statistics,episodes,consistency,training,portability,per_episode";

/// How far a frame's timestamp may be from frame_index / fps (s); lerobot stores float32.
const TIMESTAMP_TOLERANCE: f64 = 1e-4;

/// The validation result.
#[derive(Debug, Clone, Serialize)]
pub struct ValidationReport {
    pub dataset: String,
    pub passed: bool,
    pub checks: Vec<DatasetCheck>,
}

/// Validates the dataset at `dir`. A dataset that fails is a report with `passed: false`,
/// not an error; errors are for a missing directory or a broken installation.
pub fn validate(dir: &Path) -> Result<ValidationReport, Failure> {
    if !dir.join("meta").join("info.json").is_file() {
        return Err(Failure::BadInput(format!("{} is not a LeRobot dataset (no meta/info.json)", dir.display())));
    }
    let bridge = Bridge::start_default()?;
    let mut inspection = bridge.inspect_dataset(dir)?;
    let mut checks = std::mem::take(&mut inspection.checks);
    if !inspection.episodes.is_empty() {
        checks.push(trajectory_check(&inspection));
    }
    checks.extend(doctor_checks(&bridge.prefix().join("bin").join("python"), dir));
    Ok(ValidationReport { dataset: dir.display().to_string(), passed: checks.iter().all(|check| check.ok), checks })
}

/// Every episode's `observation.state` must be a valid trajectory on the dataset's frame grid:
/// finite values and gripper in [0, 1]; unit quaternions for poses, one value per named joint
/// for a joint-space recording.
fn trajectory_check(inspection: &segmenter_bridge::DatasetInspection) -> DatasetCheck {
    let fps = inspection.fps;
    let mut problems = Vec::new();
    let mut frames = 0;
    for episode in &inspection.episodes {
        frames += episode.state.len();
        let checked = match &inspection.joint_names {
            Some(names) => joint_trajectory(fps, names, episode).validate(),
            None => pose_arrays(fps, episode).and_then(|arrays| Trajectory::from_arrays(&arrays, Map::new()).map(|_| ())),
        };
        if let Err(err) = checked {
            problems.push(format!("episode {}: {err}", episode.index));
        } else if let Some(k) = (0..episode.state.len()).find(|&k| (episode.timestamps[k] - k as f64 / fps).abs() > TIMESTAMP_TOLERANCE) {
            problems.push(format!("episode {}: frame {k} at {} s, not on the {fps} fps grid", episode.index, episode.timestamps[k]));
        }
    }
    let form = if inspection.joint_names.is_some() { "finite joint values" } else { "finite poses, unit quaternions" };
    DatasetCheck {
        name: "trajectories".into(),
        ok: problems.is_empty(),
        detail: if problems.is_empty() {
            format!("{} episodes, {frames} frames: {form}, gripper in [0, 1], timestamps on the fps grid", inspection.episodes.len())
        } else {
            format!("{} bad episode(s): {}", problems.len(), problems.iter().take(5).cloned().collect::<Vec<_>>().join("; "))
        },
    }
}

/// An episode's `[x y z qw qx qy qz gripper]` rows as trajectory arrays.
fn pose_arrays(fps: f64, episode: &InspectedEpisode) -> Result<TrajectoryArrays, TrajectoryError> {
    let n = episode.state.len();
    if let Some(i) = episode.state.iter().position(|row| row.len() != 8) {
        return Err(TrajectoryError::new(format!("frames[{i}]"), format!("has {} values, not x y z qw qx qy qz gripper", episode.state[i].len())));
    }
    let column = |range: std::ops::Range<usize>| Array2::from_shape_fn((n, range.len()), |(i, j)| episode.state[i][range.start + j]);
    Ok(TrajectoryArrays {
        fps,
        t: Array1::from(episode.timestamps.clone()),
        position: column(0..3),
        orientation: column(3..7),
        gripper: Array1::from_iter(episode.state.iter().map(|s| s[7])),
    })
}

/// An episode's joint rows (joints then gripper) as a joint-space trajectory.
fn joint_trajectory(fps: f64, names: &[String], episode: &InspectedEpisode) -> JointTrajectory {
    let frames = episode
        .state
        .iter()
        .zip(&episode.timestamps)
        .map(|(row, &t)| {
            let (joints, gripper) = row.split_at(row.len().saturating_sub(1));
            JointFrame { t, joints: joints.to_vec(), gripper: gripper.first().copied().unwrap_or(f64::NAN) }
        })
        .collect();
    JointTrajectory { fps, joint_names: names.to_vec(), frames, metadata: Map::new() }
}

/// lerobot-doctor's checks as ours: FAIL fails, WARN passes with the warning shown.
fn doctor_checks(python: &Path, dir: &Path) -> Vec<DatasetCheck> {
    let output = Command::new(python)
        .args(["-c", "import sys; from lerobot_doctor.cli import main; sys.exit(main())", "check"])
        .arg(dir)
        .args(["--json", "--checks", DOCTOR_CHECKS])
        .env("HF_HUB_OFFLINE", "1")
        .output();
    let output = match output {
        Ok(output) => output,
        Err(err) => return vec![DatasetCheck { name: "lerobot-doctor".into(), ok: true, detail: format!("not run ({err})") }],
    };
    let stderr = String::from_utf8_lossy(&output.stderr);
    if stderr.contains("No module named 'lerobot_doctor'") {
        return vec![DatasetCheck { name: "lerobot-doctor".into(), ok: true, detail: "not installed; skipped (pip install lerobot-doctor)".into() }];
    }
    let report: Value = match serde_json::from_slice(&output.stdout) {
        Ok(report) => report,
        Err(_) => {
            let tail: String = stderr.lines().last().unwrap_or("no output").to_owned();
            return vec![DatasetCheck { name: "lerobot-doctor".into(), ok: false, detail: format!("could not check the dataset: {tail}") }];
        }
    };
    let Some(results) = report["checks"].as_array() else {
        return vec![DatasetCheck { name: "lerobot-doctor".into(), ok: false, detail: "its report has no checks".into() }];
    };
    results
        .iter()
        .map(|check| {
            let severity = check["severity"].as_str().unwrap_or("?");
            let notes: Vec<&str> = check["messages"]
                .as_array()
                .map(|messages| messages.iter().filter(|m| m["severity"] != "PASS").filter_map(|m| m["message"].as_str()).take(2).collect())
                .unwrap_or_default();
            DatasetCheck {
                name: format!("lerobot-doctor: {}", check["name"].as_str().unwrap_or("?")),
                ok: severity != "FAIL",
                detail: if notes.is_empty() { severity.to_owned() } else { format!("{severity}: {}", notes.join("; ")) },
            }
        })
        .collect()
}
