//! `cnfmp dataset validate DIR`: is this a LeRobot dataset cnfmp (and lerobot) can use?
//! Three layers: lerobot's own `LeRobotDataset` reads it back (through the bridge), our
//! checks of the annotations and of every episode's trajectory (the Rust trajectory code),
//! and lerobot-doctor's diagnostics when it is installed in the venv.

use std::path::Path;
use std::process::Command;

use segmenter_bridge::{Bridge, DatasetCheck, TrajectoryArrays};
use segmenter_bridge::ndarray::{Array1, Array2};
use serde::Serialize;
use serde_json::{Map, Value};

use crate::failure::Failure;
use crate::trajectory::Trajectory;

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
    let inspection = bridge.inspect_dataset(dir)?;
    let mut checks = inspection.checks;
    if !inspection.episodes.is_empty() {
        checks.push(trajectory_check(inspection.fps, &inspection.episodes));
    }
    checks.extend(doctor_checks(&bridge.prefix().join("bin").join("python"), dir));
    Ok(ValidationReport { dataset: dir.display().to_string(), passed: checks.iter().all(|check| check.ok), checks })
}

/// Every episode's `observation.state` must be a valid trajectory (finite, unit quaternions,
/// gripper in [0, 1]) on the dataset's frame grid.
fn trajectory_check(fps: f64, episodes: &[segmenter_bridge::InspectedEpisode]) -> DatasetCheck {
    let mut problems = Vec::new();
    let mut frames = 0;
    for episode in episodes {
        let n = episode.state.len();
        frames += n;
        let column = |range: std::ops::Range<usize>| Array2::from_shape_fn((n, range.len()), |(i, j)| episode.state[i][range.start + j]);
        let arrays = TrajectoryArrays {
            fps,
            t: Array1::from(episode.timestamps.clone()),
            position: column(0..3),
            orientation: column(3..7),
            gripper: Array1::from_iter(episode.state.iter().map(|s| s[7])),
        };
        if let Err(err) = Trajectory::from_arrays(&arrays, Map::new()) {
            problems.push(format!("episode {}: {err}", episode.index));
        } else if let Some(k) = (0..n).find(|&k| (episode.timestamps[k] - k as f64 / fps).abs() > TIMESTAMP_TOLERANCE) {
            problems.push(format!("episode {}: frame {k} at {} s, not on the {fps} fps grid", episode.index, episode.timestamps[k]));
        }
    }
    DatasetCheck {
        name: "trajectories".into(),
        ok: problems.is_empty(),
        detail: if problems.is_empty() {
            format!("{} episodes, {frames} frames: finite poses, unit quaternions, gripper in [0, 1], timestamps on the fps grid", episodes.len())
        } else {
            format!("{} bad episode(s): {}", problems.len(), problems.iter().take(5).cloned().collect::<Vec<_>>().join("; "))
        },
    }
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
