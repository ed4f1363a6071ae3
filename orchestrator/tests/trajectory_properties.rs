//! Property tests of the trajectory math: SO(3) exp/log round trips, tangent-space round
//! trips, resampling up then down, and smoothing invariants.

use std::f64::consts::PI;

use cnfmp::trajectory::resample::{ResampleTarget, resample};
use cnfmp::trajectory::smooth::smooth;
use cnfmp::trajectory::{Frame, Pose, Trajectory, so3};
use nalgebra::{UnitQuaternion, Vector3};
use proptest::prelude::*;

fn vector(max: f64) -> impl Strategy<Value = Vector3<f64>> {
    (-max..max, -max..max, -max..max).prop_map(|(x, y, z)| Vector3::new(x, y, z))
}

fn rotation() -> impl Strategy<Value = UnitQuaternion<f64>> {
    (vector(1.0), 0.0..PI).prop_filter_map("non-zero axis", |(axis, angle)| {
        (axis.norm() > 1e-3).then(|| UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle))
    })
}

/// A trajectory of `n` frames at `fps` Hz whose rotations stay within a few radians.
fn trajectory(max_frames: usize) -> impl Strategy<Value = Trajectory> {
    (2..max_frames, 1.0..60.0_f64, rotation(), 0.0..1.0_f64).prop_flat_map(|(n, fps, start, t0)| {
        prop::collection::vec((vector(0.5), vector(0.4), 0.0..=1.0_f64), n).prop_map(move |steps| {
            let mut orientation = start;
            let frames = steps
                .iter()
                .enumerate()
                .map(|(k, (position, turn, gripper))| {
                    orientation *= so3::exp(turn);
                    Frame { t: t0 + k as f64 / fps, pose: Pose { position: *position, orientation }, gripper: *gripper }
                })
                .collect();
            Trajectory::new(fps, frames, Default::default()).unwrap()
        })
    })
}

fn same_rotation(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>) -> f64 {
    so3::angle_between(a, b)
}

proptest! {
    // Cheap cases: run four times proptest's default.
    #![proptest_config(ProptestConfig::with_cases(1024))]

    #[test]
    fn log_inverts_exp_within_pi(v in vector(1.8)) {
        prop_assume!(v.norm() < PI - 1e-6);
        prop_assert!((so3::log(&so3::exp(&v)) - v).norm() < 1e-12);
    }

    #[test]
    fn exp_inverts_log(q in rotation()) {
        prop_assert!(same_rotation(&so3::exp(&so3::log(&q)), &q) < 1e-12);
        prop_assert!(so3::log(&q).norm() <= PI + 1e-12);
    }

    #[test]
    fn tangent_round_trip(q in rotation(), reference in rotation()) {
        let back = so3::from_tangent(&so3::to_tangent(&q, &reference), &reference);
        prop_assert!(same_rotation(&back, &q) < 1e-12);
    }

    #[test]
    fn slerp_hits_its_ends_and_halves_the_angle(a in rotation(), b in rotation()) {
        prop_assert!(same_rotation(&so3::slerp(&a, &b, 0.0), &a) < 1e-12);
        prop_assert!(same_rotation(&so3::slerp(&a, &b, 1.0), &b) < 1e-9);
        let mid = so3::slerp(&a, &b, 0.5);
        let total = so3::angle_between(&a, &b);
        prop_assert!((so3::angle_between(&a, &mid) - total / 2.0).abs() < 1e-9);
    }

    #[test]
    fn resampling_up_then_down_returns_the_original(trajectory in trajectory(40), factor in 2..5usize) {
        let up = resample(&trajectory, ResampleTarget::Fps(trajectory.fps * factor as f64)).unwrap();
        prop_assert_eq!(up.frames.len(), (trajectory.frames.len() - 1) * factor + 1);
        let down = resample(&up, ResampleTarget::Fps(trajectory.fps)).unwrap();
        prop_assert_eq!(down.frames.len(), trajectory.frames.len());
        for (a, b) in trajectory.frames.iter().zip(&down.frames) {
            prop_assert!((a.t - b.t).abs() < 1e-9);
            prop_assert!((a.pose.position - b.pose.position).norm() < 1e-6);
            prop_assert!(same_rotation(&a.pose.orientation, &b.pose.orientation) < 1e-6);
            prop_assert!((a.gripper - b.gripper).abs() < 1e-6);
        }
    }

    #[test]
    fn resampling_to_steps_keeps_both_ends(trajectory in trajectory(30), steps in 2..100usize) {
        let out = resample(&trajectory, ResampleTarget::Steps(steps)).unwrap();
        prop_assert_eq!(out.frames.len(), steps);
        let (first, last) = (&trajectory.frames[0], trajectory.frames.last().unwrap());
        prop_assert!((out.frames[0].pose.position - first.pose.position).norm() < 1e-12);
        prop_assert!((out.frames[steps - 1].pose.position - last.pose.position).norm() < 1e-9);
        prop_assert!((out.frames[steps - 1].t - last.t).abs() < 1e-9);
    }

    #[test]
    fn smoothing_pins_the_ends_and_keeps_times(trajectory in trajectory(30), sigma in 0.01..1.0_f64) {
        let out = smooth(&trajectory, sigma).unwrap();
        prop_assert_eq!(out.frames.len(), trajectory.frames.len());
        for end in [0, trajectory.frames.len() - 1] {
            prop_assert!((out.frames[end].pose.position - trajectory.frames[end].pose.position).norm() < 1e-9);
            prop_assert!(same_rotation(&out.frames[end].pose.orientation, &trajectory.frames[end].pose.orientation) < 1e-9);
        }
        for (a, b) in trajectory.frames.iter().zip(&out.frames) {
            prop_assert_eq!(a.t, b.t);
            prop_assert_eq!(a.gripper, b.gripper);
        }
    }
}

/// Constant velocity and constant angular velocity must survive smoothing unchanged
/// (odd reflection at the ends does not bend straight lines).
#[test]
fn smoothing_leaves_uniform_motion_alone() {
    let spin = Vector3::new(0.1, -0.2, 0.3);
    let frames = (0..50)
        .map(|k| {
            let t = k as f64 * 0.05;
            Frame { t, pose: Pose { position: Vector3::new(0.1, 0.2, 0.3) * t, orientation: so3::exp(&(spin * t)) }, gripper: 1.0 }
        })
        .collect();
    let trajectory = Trajectory::new(20.0, frames, Default::default()).unwrap();
    let out = smooth(&trajectory, 0.2).unwrap();
    for (a, b) in trajectory.frames.iter().zip(&out.frames) {
        assert!((a.pose.position - b.pose.position).norm() < 1e-12, "{a:?} vs {b:?}");
        assert!(same_rotation(&a.pose.orientation, &b.pose.orientation) < 1e-9);
    }
}

/// Smoothing must reduce frame-to-frame jitter (the reason it exists: contact grasps break
/// on 1 cm per-step jitter, facts.md).
#[test]
fn smoothing_reduces_jitter() {
    let frames = (0..100)
        .map(|k| {
            let jitter = if k % 2 == 0 { 0.01 } else { -0.01 };
            Frame { t: k as f64 * 0.02, pose: Pose { position: Vector3::new(0.3, jitter, 0.2), orientation: UnitQuaternion::identity() }, gripper: 1.0 }
        })
        .collect();
    let trajectory = Trajectory::new(50.0, frames, Default::default()).unwrap();
    let out = smooth(&trajectory, 0.05).unwrap();
    let roughness = |tr: &Trajectory| tr.frames.windows(2).map(|w| (w[1].pose.position - w[0].pose.position).norm()).sum::<f64>();
    assert!(roughness(&out) < 0.1 * roughness(&trajectory), "{} vs {}", roughness(&out), roughness(&trajectory));
}
