//! SO(3) exponential and logarithm on unit quaternions, and the tangent-space (rotation
//! vector) representation relative to a reference orientation that the models use
//! (design.md: files carry quaternions, models carry axis-angle relative to a task reference).
//! This is the one place these conversions live on the Rust side.

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

/// Below this rotation angle (rad) the series expansions are used; they are exact to f64
/// precision there and avoid 0/0.
const SMALL_ANGLE: f64 = 1e-6;

/// Rotation vector (axis * angle, rad) -> unit quaternion. Any vector is valid; angles above
/// pi wrap around as rotations do.
pub fn exp(rotation_vector: &Vector3<f64>) -> UnitQuaternion<f64> {
    let angle = rotation_vector.norm();
    let half = 0.5 * angle;
    // sin(angle/2)/angle, with its Taylor series near zero.
    let scale = if angle < SMALL_ANGLE { 0.5 - angle * angle / 48.0 } else { half.sin() / angle };
    let v = rotation_vector * scale;
    UnitQuaternion::new_unchecked(Quaternion::new(half.cos(), v.x, v.y, v.z))
}

/// Unit quaternion -> rotation vector with angle in [0, pi] (the shortest rotation; q and -q
/// give the same vector).
pub fn log(rotation: &UnitQuaternion<f64>) -> Vector3<f64> {
    let q = rotation.quaternion();
    let (w, v) = if q.w < 0.0 { (-q.w, -q.imag()) } else { (q.w, q.imag()) };
    let sin_half = v.norm();
    if sin_half < SMALL_ANGLE {
        // angle = 2 asin(|v|) ~ 2|v|; dividing by w keeps precision as w -> 1.
        return v * (2.0 / w);
    }
    let angle = 2.0 * sin_half.atan2(w);
    v * (angle / sin_half)
}

/// Rotation vector of `rotation` relative to `reference`: log(reference^-1 * rotation), i.e.
/// expressed in the reference's body frame.
pub fn to_tangent(rotation: &UnitQuaternion<f64>, reference: &UnitQuaternion<f64>) -> Vector3<f64> {
    log(&(reference.inverse() * rotation))
}

/// Inverse of [`to_tangent`]: reference * exp(tangent).
pub fn from_tangent(tangent: &Vector3<f64>, reference: &UnitQuaternion<f64>) -> UnitQuaternion<f64> {
    reference * exp(tangent)
}

/// Geodesic interpolation between `from` (s = 0) and `to` (s = 1) along the shortest arc.
pub fn slerp(from: &UnitQuaternion<f64>, to: &UnitQuaternion<f64>, s: f64) -> UnitQuaternion<f64> {
    from_tangent(&(to_tangent(to, from) * s), from)
}

/// Angle (rad, in [0, pi]) of the rotation taking `a` to `b`.
pub fn angle_between(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>) -> f64 {
    to_tangent(b, a).norm()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn exp_of_quarter_turn_about_z() {
        let q = exp(&Vector3::new(0.0, 0.0, PI / 2.0));
        let expected = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), PI / 2.0);
        assert!(q.angle_to(&expected) < 1e-12);
    }

    #[test]
    fn log_of_identity_and_half_turn() {
        assert_eq!(log(&UnitQuaternion::identity()), Vector3::zeros());
        let half_turn = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), PI);
        assert!((log(&half_turn).norm() - PI).abs() < 1e-12);
    }

    #[test]
    fn log_is_sign_invariant() {
        let q = exp(&Vector3::new(0.3, -0.2, 0.9));
        let negated = UnitQuaternion::new_unchecked(-q.into_inner());
        assert!((log(&q) - log(&negated)).norm() < 1e-15);
    }

    #[test]
    fn tiny_rotations_keep_full_precision() {
        let v = Vector3::new(3e-9, -1e-9, 2e-9);
        assert!((log(&exp(&v)) - v).norm() < 1e-22);
    }

    #[test]
    fn slerp_takes_the_short_way() {
        let a = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.1);
        // Same rotation as angle 0.3 but with the opposite quaternion sign.
        let b = UnitQuaternion::new_unchecked(-UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.3).into_inner());
        let mid = slerp(&a, &b, 0.5);
        assert!((log(&mid) - Vector3::new(0.0, 0.0, 0.2)).norm() < 1e-12);
    }
}
