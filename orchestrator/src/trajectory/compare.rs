//! Comparing two trajectories: the mean Euclidean distance (MED) of paper Table I.

use super::Trajectory;

/// Mean over time steps of the distance (cm) between the positions of `predicted` and
/// `reference`, frame by frame. Both must be sampled at the same rate; when one is shorter
/// it is held at its last pose (a robot that has finished stays where it stopped), so a
/// trajectory that ends early or late is charged for it.
///
/// Errors when the rates differ by more than 1e-9 Hz (resample first).
pub fn mean_euclidean_distance_cm(
    predicted: &Trajectory,
    reference: &Trajectory,
) -> Result<f64, String> {
    if (predicted.fps - reference.fps).abs() > 1e-9 {
        return Err(format!(
            "MED needs equal rates; got {} Hz and {} Hz (resample first)",
            predicted.fps, reference.fps
        ));
    }
    let steps = predicted.frames.len().max(reference.frames.len());
    let at = |trajectory: &Trajectory, k: usize| {
        trajectory.frames[k.min(trajectory.frames.len() - 1)]
            .pose
            .position
    };
    let total: f64 = (0..steps)
        .map(|k| (at(predicted, k) - at(reference, k)).norm())
        .sum();
    Ok(100.0 * total / steps as f64)
}

#[cfg(test)]
mod tests {
    use nalgebra::{UnitQuaternion, Vector3};
    use serde_json::Map;

    use super::*;
    use crate::trajectory::{Frame, Pose};

    fn line(fps: f64, xs: &[f64]) -> Trajectory {
        let frames = xs
            .iter()
            .enumerate()
            .map(|(k, &x)| Frame {
                t: k as f64 / fps,
                pose: Pose {
                    position: Vector3::new(x, 0.0, 0.0),
                    orientation: UnitQuaternion::identity(),
                },
                gripper: 1.0,
            })
            .collect();
        Trajectory::new(fps, frames, Map::new()).unwrap()
    }

    #[test]
    fn identical_trajectories_are_zero_apart() {
        let a = line(10.0, &[0.0, 0.1, 0.2]);
        assert_eq!(mean_euclidean_distance_cm(&a, &a).unwrap(), 0.0);
    }

    #[test]
    fn constant_offset_is_the_distance_in_cm() {
        let a = line(10.0, &[0.0, 0.1, 0.2]);
        let b = line(10.0, &[0.01, 0.11, 0.21]);
        assert!((mean_euclidean_distance_cm(&a, &b).unwrap() - 1.0).abs() < 1e-9);
    }

    #[test]
    fn the_shorter_trajectory_is_held_at_its_end() {
        let a = line(10.0, &[0.0, 0.0]);
        let b = line(10.0, &[0.0, 0.0, 0.04, 0.04]);
        // Distances 0, 0, 4, 4 cm over four steps.
        assert!((mean_euclidean_distance_cm(&a, &b).unwrap() - 2.0).abs() < 1e-9);
    }

    #[test]
    fn different_rates_are_refused() {
        assert!(
            mean_euclidean_distance_cm(&line(10.0, &[0.0, 1.0]), &line(50.0, &[0.0, 1.0])).is_err()
        );
    }
}
