//! A trajectory at a glance (`cnfmp trajectory inspect`): duration, path length, speeds,
//! rotation, gripper events, workspace bounds.

use serde::Serialize;

use super::{Trajectory, so3};

/// Gripper openings cross this value when they open or close.
const GRIPPER_THRESHOLD: f64 = 0.5;

/// Summary figures; units in the field names.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Summary {
    pub frames: usize,
    /// Nominal rate from the file (Hz).
    pub fps: f64,
    /// Rate implied by the frame times, (frames - 1) / duration (Hz); 0 for one frame.
    pub measured_fps: f64,
    pub duration_s: f64,
    /// Sum of straight-line distances between consecutive positions (m).
    pub path_length_m: f64,
    pub max_speed_m_per_s: f64,
    /// Sum of rotation angles between consecutive orientations (rad).
    pub rotation_rad: f64,
    pub max_angular_speed_rad_per_s: f64,
    /// Times (s) the gripper went from open (>= 0.5) to closed.
    pub gripper_closes_at_s: Vec<f64>,
    /// Times (s) the gripper went from closed to open.
    pub gripper_opens_at_s: Vec<f64>,
    pub start_position_m: [f64; 3],
    pub end_position_m: [f64; 3],
    /// Axis-aligned bounds of all positions: [[min x, min y, min z], [max x, max y, max z]] (m).
    pub bounds_m: [[f64; 3]; 2],
}

/// Computes the [`Summary`] of a validated trajectory.
pub fn summarize(trajectory: &Trajectory) -> Summary {
    let frames = &trajectory.frames;
    let (mut path, mut max_speed, mut rotation, mut max_angular) = (0.0_f64, 0.0_f64, 0.0_f64, 0.0_f64);
    let (mut closes, mut opens) = (Vec::new(), Vec::new());
    for pair in frames.windows(2) {
        let (a, b) = (&pair[0], &pair[1]);
        let dt = b.t - a.t;
        let step = (b.pose.position - a.pose.position).norm();
        let turn = so3::angle_between(&a.pose.orientation, &b.pose.orientation);
        path += step;
        rotation += turn;
        max_speed = max_speed.max(step / dt);
        max_angular = max_angular.max(turn / dt);
        match (a.gripper >= GRIPPER_THRESHOLD, b.gripper >= GRIPPER_THRESHOLD) {
            (true, false) => closes.push(b.t),
            (false, true) => opens.push(b.t),
            _ => {}
        }
    }
    let (mut low, mut high) = (frames[0].pose.position, frames[0].pose.position);
    for frame in frames {
        low = low.inf(&frame.pose.position);
        high = high.sup(&frame.pose.position);
    }
    let bounds = [low.into(), high.into()];
    let duration = trajectory.duration();
    Summary {
        frames: frames.len(),
        fps: trajectory.fps,
        measured_fps: if frames.len() > 1 { (frames.len() - 1) as f64 / duration } else { 0.0 },
        duration_s: duration,
        path_length_m: path,
        max_speed_m_per_s: max_speed,
        rotation_rad: rotation,
        max_angular_speed_rad_per_s: max_angular,
        gripper_closes_at_s: closes,
        gripper_opens_at_s: opens,
        start_position_m: frames[0].pose.position.into(),
        end_position_m: frames[frames.len() - 1].pose.position.into(),
        bounds_m: bounds,
    }
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let xyz = |p: &[f64; 3]| format!("({:.4}, {:.4}, {:.4})", p[0], p[1], p[2]);
        let times = |ts: &[f64]| if ts.is_empty() { "never".to_owned() } else { ts.iter().map(|t| format!("{t:.3} s")).collect::<Vec<_>>().join(", ") };
        writeln!(f, "frames          {} ({} Hz nominal, {:.3} Hz measured)", self.frames, self.fps, self.measured_fps)?;
        writeln!(f, "duration        {:.3} s", self.duration_s)?;
        writeln!(f, "path length     {:.4} m", self.path_length_m)?;
        writeln!(f, "max speed       {:.4} m/s", self.max_speed_m_per_s)?;
        writeln!(f, "rotation        {:.4} rad ({:.1} deg)", self.rotation_rad, self.rotation_rad.to_degrees())?;
        writeln!(f, "max ang. speed  {:.4} rad/s", self.max_angular_speed_rad_per_s)?;
        writeln!(f, "gripper closes  {}", times(&self.gripper_closes_at_s))?;
        writeln!(f, "gripper opens   {}", times(&self.gripper_opens_at_s))?;
        writeln!(f, "start position  {} m", xyz(&self.start_position_m))?;
        writeln!(f, "end position    {} m", xyz(&self.end_position_m))?;
        write!(f, "bounds          {} .. {} m", xyz(&self.bounds_m[0]), xyz(&self.bounds_m[1]))
    }
}
