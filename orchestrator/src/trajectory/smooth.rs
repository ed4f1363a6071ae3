//! Gaussian smoothing of positions and rotations over time (the gripper is left alone: its
//! open/close steps are commands, not noise).
//!
//! Rotations are averaged in the tangent space of each frame's own orientation, which is
//! exact for small spreads and needs no global reference. Both ends are padded by odd
//! reflection (x(-k) = 2 x(0) - x(k), and its rotation analogue), which keeps the first and
//! last pose exactly where they were and does not bend straight-line motion near the ends:
//! a robot must start where it is.

use nalgebra::{UnitQuaternion, Vector3};

use super::{Frame, Pose, Trajectory, TrajectoryError, so3};

/// Kernel support in standard deviations.
const SUPPORT_SIGMAS: f64 = 3.0;

/// Gaussian weight at `dt` standard deviations, shifted down so it reaches zero at `half`
/// (the window's half-width, also in standard deviations): a frame right at the edge weighs
/// ~0 whether rounding puts it inside or outside, which keeps the kernel symmetric (and the
/// ends pinned) on any time grid.
fn kernel(dt: f64, half: f64) -> f64 {
    ((-0.5 * dt * dt).exp() - (-0.5 * half * half).exp()).max(0.0)
}

/// Smooths with a Gaussian kernel of standard deviation `sigma_s` seconds (> 0). Frame times,
/// gripper values and metadata are kept.
pub fn smooth(trajectory: &Trajectory, sigma_s: f64) -> Result<Trajectory, TrajectoryError> {
    if !(sigma_s.is_finite() && sigma_s > 0.0) {
        return Err(TrajectoryError::new("--sigma", format!("must be a finite number of seconds > 0, got {sigma_s}")));
    }
    let reach = SUPPORT_SIGMAS * sigma_s;
    let padded = reflect_ends(&trajectory.frames, reach);
    let (padded_start, padded_end) = (padded[0].t, padded[padded.len() - 1].t);
    let frames = trajectory
        .frames
        .iter()
        .map(|frame| {
            // Near an end of a short trajectory the padding may not reach a full window; a
            // window kept symmetric about the frame keeps the odd reflection exact.
            let half = reach.min(frame.t - padded_start).min(padded_end - frame.t);
            let window = &padded[padded.partition_point(|o| o.t < frame.t - half)..padded.partition_point(|o| o.t <= frame.t + half)];
            let mut weight_sum = 0.0;
            let mut position = Vector3::zeros();
            let mut tangent = Vector3::zeros();
            for other in window {
                let weight = kernel((other.t - frame.t) / sigma_s, half / sigma_s);
                weight_sum += weight;
                position += other.pose.position * weight;
                tangent += so3::to_tangent(&other.pose.orientation, &frame.pose.orientation) * weight;
            }
            if weight_sum == 0.0 {
                return *frame; // a window too narrow to hold any neighbour (one frame)
            }
            Frame {
                pose: Pose {
                    position: position / weight_sum,
                    orientation: so3::from_tangent(&(tangent / weight_sum), &frame.pose.orientation),
                },
                ..*frame
            }
        })
        .collect();
    Trajectory::new(trajectory.fps, frames, trajectory.metadata.clone())
}

/// The frames with mirror images of those within `reach` seconds of either end prepended and
/// appended, mirrored in time and (odd reflection) in pose about the end frame.
fn reflect_ends(frames: &[Frame], reach: f64) -> Vec<Frame> {
    let mirror = |end: &Frame, other: &Frame| Frame {
        t: 2.0 * end.t - other.t,
        pose: Pose {
            position: end.pose.position * 2.0 - other.pose.position,
            orientation: reflect_rotation(&end.pose.orientation, &other.pose.orientation),
        },
        gripper: other.gripper,
    };
    let (first, last) = (&frames[0], &frames[frames.len() - 1]);
    let mut padded: Vec<Frame> = frames[1..].iter().take_while(|f| f.t - first.t <= reach).map(|f| mirror(first, f)).collect();
    padded.reverse();
    padded.extend_from_slice(frames);
    padded.extend(frames[..frames.len() - 1].iter().rev().take_while(|f| last.t - f.t <= reach).map(|f| mirror(last, f)));
    padded
}

/// The rotation as far from `end` as `other`, in the opposite direction.
fn reflect_rotation(end: &UnitQuaternion<f64>, other: &UnitQuaternion<f64>) -> UnitQuaternion<f64> {
    so3::from_tangent(&-so3::to_tangent(other, end), end)
}
