//! Resampling a trajectory onto a new time grid: positions and gripper linearly, rotations
//! along the geodesic (slerp). Where a new sample time coincides with an old frame the old
//! frame comes back unchanged, so resampling up and then down again is lossless there.

use super::{Frame, Pose, Trajectory, TrajectoryError, so3};

/// The new time grid, spanning the same start and end times as the input.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ResampleTarget {
    /// Frames every 1/fps s from the first frame; the last one at or before the end.
    Fps(f64),
    /// Exactly this many evenly spaced frames (>= 2), first and last on the input's ends.
    Steps(usize),
}

/// Relative slack (of one new period) when deciding whether the end time falls on the grid,
/// so 2.9999999999 periods count as 3.
const GRID_SLACK: f64 = 1e-6;

/// Resamples `trajectory` onto `target`'s grid. Metadata is kept.
///
/// Errors: fewer than two frames, a non-positive or non-finite fps, fewer than two steps.
pub fn resample(trajectory: &Trajectory, target: ResampleTarget) -> Result<Trajectory, TrajectoryError> {
    if trajectory.frames.len() < 2 {
        return Err(TrajectoryError::new("frames", "resampling needs at least two frames"));
    }
    let (start, duration) = (trajectory.start(), trajectory.duration());
    let (fps, times): (f64, Vec<f64>) = match target {
        ResampleTarget::Fps(fps) => {
            if !(fps.is_finite() && fps > 0.0) {
                return Err(TrajectoryError::new("--fps", format!("must be a finite number > 0, got {fps}")));
            }
            let count = (duration * fps + GRID_SLACK).floor() as usize + 1;
            (fps, (0..count).map(|k| (start + k as f64 / fps).min(start + duration)).collect())
        }
        ResampleTarget::Steps(steps) => {
            if steps < 2 {
                return Err(TrajectoryError::new("--steps", format!("must be at least 2, got {steps}")));
            }
            let last = (steps - 1) as f64;
            ((steps - 1) as f64 / duration, (0..steps).map(|k| start + duration * k as f64 / last).collect())
        }
    };
    let frames = times.iter().map(|&t| sample(trajectory, t)).collect();
    Trajectory::new(fps, frames, trajectory.metadata.clone())
}

/// The trajectory's state at time `t` (s), clamped to its time span.
pub fn sample(trajectory: &Trajectory, t: f64) -> Frame {
    let frames = &trajectory.frames;
    // Index of the first frame strictly after t; the segment is [after - 1, after].
    let after = frames.partition_point(|frame| frame.t <= t);
    if after == 0 {
        return Frame { t, ..frames[0] };
    }
    if after == frames.len() {
        return Frame { t, ..frames[frames.len() - 1] };
    }
    let (a, b) = (&frames[after - 1], &frames[after]);
    let s = (t - a.t) / (b.t - a.t);
    if s == 0.0 {
        return *a;
    }
    Frame {
        t,
        pose: Pose {
            position: a.pose.position.lerp(&b.pose.position, s),
            orientation: so3::slerp(&a.pose.orientation, &b.pose.orientation, s),
        },
        gripper: a.gripper + (b.gripper - a.gripper) * s,
    }
}
