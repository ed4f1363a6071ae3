//! Trajectories as CSV (the raw dataset format's alternative to trajectory JSON): a header
//! naming the columns `t,x,y,z,qw,qx,qy,qz,gripper` in any order (extra columns are
//! ignored), then one frame per line. Units as in the JSON file: s, m, quaternion, [0, 1].

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use serde_json::Map;

use super::{Frame, Pose, QUATERNION_NORM_TOLERANCE, Trajectory, TrajectoryError};

/// The columns a trajectory CSV must have.
pub const COLUMNS: [&str; 9] = ["t", "x", "y", "z", "qw", "qx", "qy", "qz", "gripper"];

/// Parses and validates CSV text recorded at `fps` (Hz). Errors name the line and column.
pub fn from_csv_str(text: &str, fps: f64) -> Result<Trajectory, TrajectoryError> {
    let mut lines = text.lines().enumerate().filter(|(_, line)| !line.trim().is_empty());
    let (_, header) = lines.next().ok_or_else(|| TrajectoryError::new("file", "is empty; expected a header line"))?;
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    let mut index = [0usize; 9];
    for (slot, column) in COLUMNS.iter().enumerate() {
        index[slot] = names.iter().position(|name| name == column).ok_or_else(|| {
            TrajectoryError::new("line 1", format!("the header has no `{column}` column (needs {})", COLUMNS.join(",")))
        })?;
    }
    let mut frames = Vec::new();
    for (number, line) in lines {
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        let location = format!("line {}", number + 1);
        let mut values = [0.0_f64; 9];
        for (slot, &column) in index.iter().enumerate() {
            let cell = cells.get(column).ok_or_else(|| {
                TrajectoryError::new(&location, format!("has {} cells, the header {}", cells.len(), names.len()))
            })?;
            values[slot] = cell.parse().map_err(|_| {
                TrajectoryError::new(format!("{location}, column {}", COLUMNS[slot]), format!("`{cell}` is not a number"))
            })?;
        }
        let [t, x, y, z, qw, qx, qy, qz, gripper] = values;
        let quaternion = Quaternion::new(qw, qx, qy, qz);
        if quaternion.norm().is_finite() && (quaternion.norm() - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
            return Err(TrajectoryError::new(location, format!("quaternion [w,x,y,z] = [{qw}, {qx}, {qy}, {qz}] has norm {:.6}, not 1", quaternion.norm())));
        }
        // A non-finite quaternion is kept as it is, for Trajectory::new to report.
        let orientation = if quaternion.norm().is_finite() { UnitQuaternion::new_normalize(quaternion) } else { UnitQuaternion::new_unchecked(quaternion) };
        frames.push(Frame { t, pose: Pose { position: Vector3::new(x, y, z), orientation }, gripper });
    }
    // Frame-level invariants (finite values, increasing time, gripper range) are checked once,
    // by Trajectory::new; its messages index frames from 0 (frame k is CSV data row k + 1).
    Trajectory::new(fps, frames, Map::new())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_in_any_order() {
        let text = "gripper,t,x,y,z,qw,qx,qy,qz,note\n1,0,0.1,0.2,0.3,1,0,0,0,a\n0.5,0.1,0.2,0.2,0.3,1,0,0,0,b\n";
        let trajectory = from_csv_str(text, 10.0).unwrap();
        assert_eq!(trajectory.frames.len(), 2);
        assert_eq!(trajectory.frames[1].gripper, 0.5);
        assert_eq!(trajectory.frames[1].pose.position.x, 0.2);
    }

    #[test]
    fn errors_name_line_and_column() {
        let missing = from_csv_str("t,x,y,z,qw,qx,qy,qz\n", 10.0).unwrap_err();
        assert!(missing.problem.contains("`gripper`"), "{missing}");
        let bad = from_csv_str("t,x,y,z,qw,qx,qy,qz,gripper\n0,0,0,0,1,0,0,0,1\n0.1,abc,0,0,1,0,0,0,1\n", 10.0).unwrap_err();
        assert_eq!(bad.location, "line 3, column x");
        let backwards = from_csv_str("t,x,y,z,qw,qx,qy,qz,gripper\n0.2,0,0,0,1,0,0,0,1\n0.1,0,0,0,1,0,0,0,1\n", 10.0).unwrap_err();
        assert!(backwards.problem.contains("does not increase"), "{backwards}");
        let nan = from_csv_str("t,x,y,z,qw,qx,qy,qz,gripper\n0,NaN,0,0,1,0,0,0,1\n", 10.0).unwrap_err();
        assert!(nan.problem.contains("not a finite number"), "{nan}");
    }
}
