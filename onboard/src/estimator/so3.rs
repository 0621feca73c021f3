//! Rotation helpers on SO(3): the skew matrix, and the exponential and logarithm maps
//! written for accuracy at small angles (the filter's error states are small rotations).
//!
//! Conventions: a rotation vector `φ` (rad) maps to `Exp(φ)`, the rotation by `|φ|` about
//! `φ/|φ|`; `Log` is its inverse on angles in `[0, π]`.

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

/// Below this angle (rad) the exponential and logarithm use their Taylor series.
const SMALL_ANGLE_RAD: f64 = 1e-8;

/// The cross-product matrix: `skew(a) * b == a.cross(b)`.
#[inline]
pub fn skew(a: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -a.z, a.y, a.z, 0.0, -a.x, -a.y, a.x, 0.0)
}

/// `Exp(φ)` as a unit quaternion, exact (no first-order approximation).
#[inline]
pub fn exp(phi: &Vector3<f64>) -> UnitQuaternion<f64> {
    let theta2 = phi.norm_squared();
    let theta = theta2.sqrt();
    let (w, k) = if theta < SMALL_ANGLE_RAD {
        // cos(θ/2) ≈ 1 − θ²/8, sin(θ/2)/θ ≈ 1/2 − θ²/48.
        (1.0 - theta2 / 8.0, 0.5 - theta2 / 48.0)
    } else {
        let (s, c) = (0.5 * theta).sin_cos();
        (c, s / theta)
    };
    UnitQuaternion::new_unchecked(Quaternion::new(w, k * phi.x, k * phi.y, k * phi.z))
}

/// `Log(q)`: the rotation vector (rad, angle in `[0, π]`) of a unit quaternion. Uses
/// `atan2`, so it keeps full relative precision at small angles (unlike `acos`).
#[inline]
pub fn log(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let c = q.as_ref();
    // q and −q are the same rotation: take the representative with w ≥ 0.
    let (w, v) = if c.w < 0.0 {
        (-c.w, -c.imag())
    } else {
        (c.w, c.imag())
    };
    let n = v.norm();
    if n < SMALL_ANGLE_RAD {
        // θ = 2 atan(n / w) ≈ 2 n / w.
        return v * (2.0 / w);
    }
    v * (2.0 * n.atan2(w) / n)
}

/// Re-normalizes a unit quaternion that has accumulated rounding error.
#[inline]
pub fn renormalize(q: &UnitQuaternion<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::new_normalize(q.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn vec3() -> impl Strategy<Value = Vector3<f64>> {
        (-3.0f64..3.0, -3.0f64..3.0, -3.0f64..3.0).prop_map(|(x, y, z)| Vector3::new(x, y, z))
    }

    #[test]
    fn skew_is_the_cross_product() {
        let a = Vector3::new(0.3, -1.2, 2.0);
        let b = Vector3::new(-0.7, 0.1, 0.5);
        assert!((skew(&a) * b - a.cross(&b)).norm() < 1e-15);
    }

    #[test]
    fn small_angles_keep_precision() {
        // A rotation of 1e-9 rad about x: the log must return it to ~1e-24, not the
        // ~1e-8 an acos-based angle would give.
        let phi = Vector3::new(1e-9, 0.0, 0.0);
        let back = log(&exp(&phi));
        assert!((back - phi).norm() < 1e-22, "{back:?}");
        let phi = Vector3::new(3e-6, -2e-6, 1e-6);
        assert!((log(&exp(&phi)) - phi).norm() < 1e-20);
    }

    proptest! {
        #[test]
        fn exp_matches_nalgebra_and_log_inverts(phi in vec3()) {
            prop_assume!(phi.norm() < std::f64::consts::PI - 1e-6);
            let q = exp(&phi);
            let reference = UnitQuaternion::from_scaled_axis(phi);
            prop_assert!(q.angle_to(&reference) < 1e-12);
            prop_assert!((q.norm() - 1.0).abs() < 1e-14);
            prop_assert!((log(&q) - phi).norm() < 1e-12);
            // The double cover: −q has the same log.
            let neg = UnitQuaternion::new_unchecked(-q.into_inner());
            prop_assert!((log(&neg) - phi).norm() < 1e-12);
        }
    }
}
