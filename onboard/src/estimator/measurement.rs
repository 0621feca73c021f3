//! Measurement models of the EIF and their Jacobians with respect to the error state
//! `[δp, δv, δθ, δp_c, δθ_c]` under the ⊞ of [`NavState::boxplus`].
//!
//! Each model returns the residual `y = z ⊟ h(x̂)` and `H = ∂(h(x̂ ⊞ δx) ⊟ h(x̂))/∂δx`
//! at `δx = 0`, so that `y ≈ H δx + noise`.

use super::ins::{IDX_P, IDX_PC, IDX_TH, IDX_THC, IDX_V, NavState, STATE_DIM};
use super::so3::{log, skew};
use nalgebra::{Matrix3, SMatrix, SVector, UnitQuaternion, Vector3};

/// A linearized measurement with `M` rows.
#[derive(Clone, Debug, PartialEq)]
pub struct Linearized<const M: usize> {
    /// Residual `z ⊟ h(x̂)`.
    pub residual: SVector<f64, M>,
    /// Jacobian of `h(x̂ ⊞ δx) ⊟ h(x̂)` at `δx = 0`.
    pub h: SMatrix<f64, M, STATE_DIM>,
}

/// Eq. (1) predicted: the world position of the GNSS antenna, `p + R r_ia`, with `r_ia`
/// the antenna position in the IMU frame (`imu_from_antenna` translation), m.
pub fn gnss_position_model(x: &NavState, r_ia: &Vector3<f64>) -> Vector3<f64> {
    x.p + x.q * r_ia
}

/// GNSS position: `z` the antenna's ENU position, m. `H = [I, 0, −R[r_ia]×, 0]`.
pub fn gnss_position(x: &NavState, r_ia: &Vector3<f64>, z: &Vector3<f64>) -> Linearized<3> {
    let r = x.q.to_rotation_matrix().into_inner();
    let mut h = SMatrix::<f64, 3, STATE_DIM>::zeros();
    h.fixed_view_mut::<3, 3>(0, IDX_P)
        .copy_from(&Matrix3::identity());
    h.fixed_view_mut::<3, 3>(0, IDX_TH)
        .copy_from(&(-(r * skew(r_ia))));
    Linearized {
        residual: z - gnss_position_model(x, r_ia),
        h,
    }
}

/// Predicted antenna velocity in the world: `v + R(ω × r_ia)`, with `ω` the IMU's
/// angular rate in the IMU frame (rad/s).
pub fn gnss_velocity_model(
    x: &NavState,
    r_ia: &Vector3<f64>,
    omega: &Vector3<f64>,
) -> Vector3<f64> {
    x.v + x.q * omega.cross(r_ia)
}

/// GNSS velocity: `z` the antenna's ENU velocity, m/s. `H = [0, I, −R[ω × r_ia]×, 0]`.
pub fn gnss_velocity(
    x: &NavState,
    r_ia: &Vector3<f64>,
    omega: &Vector3<f64>,
    z: &Vector3<f64>,
) -> Linearized<3> {
    let r = x.q.to_rotation_matrix().into_inner();
    let mut h = SMatrix::<f64, 3, STATE_DIM>::zeros();
    h.fixed_view_mut::<3, 3>(0, IDX_V)
        .copy_from(&Matrix3::identity());
    h.fixed_view_mut::<3, 3>(0, IDX_TH)
        .copy_from(&(-(r * skew(&omega.cross(r_ia)))));
    Linearized {
        residual: z - gnss_velocity_model(x, r_ia, omega),
        h,
    }
}

/// AHRS orientation: `z = world_from_imu` measured; residual `Log(q̂⁻¹ ⊗ z)` (a local
/// rotation vector, rad), `H = [0, 0, I, 0]`.
pub fn orientation(x: &NavState, z: &UnitQuaternion<f64>) -> Linearized<3> {
    let mut h = SMatrix::<f64, 3, STATE_DIM>::zeros();
    h.fixed_view_mut::<3, 3>(0, IDX_TH)
        .copy_from(&Matrix3::identity());
    Linearized {
        residual: log(&(x.q.inverse() * z)),
        h,
    }
}

/// Eq. (2) predicted, relative: the motion of the IMU frame since the clone,
/// `imu_c_from_imu = (R_cᵀ(p − p_c), R_cᵀ R)`.
pub fn relative_pose_model(x: &NavState) -> (Vector3<f64>, UnitQuaternion<f64>) {
    let qc_inv = x.q_clone.inverse();
    (qc_inv * (x.p - x.p_clone), qc_inv * x.q)
}

/// Tracking-camera relative pose: `dp` (m) and `dq` the measured `imu_{k−1}_from_imu_k`.
/// Residual `[dp − Δp̂; Log(ΔR̂ᵀ dq)]`; Jacobian blocks
/// `∂Δp/∂δp = R_cᵀ`, `∂Δp/∂δp_c = −R_cᵀ`, `∂Δp/∂δθ_c = [Δp̂]×`,
/// `∂Δθ/∂δθ = I`, `∂Δθ/∂δθ_c = −ΔR̂ᵀ`.
pub fn tracking_relative(
    x: &NavState,
    dp: &Vector3<f64>,
    dq: &UnitQuaternion<f64>,
) -> Linearized<6> {
    let (dp_hat, dq_hat) = relative_pose_model(x);
    let rct = x.q_clone.to_rotation_matrix().into_inner().transpose();
    let drt = dq_hat.to_rotation_matrix().into_inner().transpose();
    let mut h = SMatrix::<f64, 6, STATE_DIM>::zeros();
    h.fixed_view_mut::<3, 3>(0, IDX_P).copy_from(&rct);
    h.fixed_view_mut::<3, 3>(0, IDX_PC).copy_from(&(-rct));
    h.fixed_view_mut::<3, 3>(0, IDX_THC)
        .copy_from(&skew(&dp_hat));
    h.fixed_view_mut::<3, 3>(3, IDX_TH)
        .copy_from(&Matrix3::identity());
    h.fixed_view_mut::<3, 3>(3, IDX_THC).copy_from(&(-drt));
    let mut residual = SVector::<f64, 6>::zeros();
    residual.fixed_rows_mut::<3>(0).copy_from(&(dp - dp_hat));
    residual
        .fixed_rows_mut::<3>(3)
        .copy_from(&log(&(dq_hat.inverse() * dq)));
    Linearized { residual, h }
}

#[cfg(test)]
mod tests {
    use super::super::ins::Vec15;
    use super::super::so3::exp;
    use super::*;
    use nalgebra::{Isometry3, Translation3};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    const EPS: f64 = 1e-6;
    const TOL: f64 = 1e-6;

    fn v3(rng: &mut ChaCha8Rng, r: f64) -> Vector3<f64> {
        Vector3::new(
            rng.random_range(-r..r),
            rng.random_range(-r..r),
            rng.random_range(-r..r),
        )
    }

    fn random_state(rng: &mut ChaCha8Rng) -> NavState {
        NavState {
            p: v3(rng, 50.0),
            v: v3(rng, 3.0),
            q: exp(&v3(rng, 3.0)),
            p_clone: v3(rng, 50.0),
            q_clone: exp(&v3(rng, 3.0)),
        }
    }

    /// Central numeric Jacobian of `f(x ⊞ δ) ⊟ f(x)` where `minus` is the measurement
    /// space's ⊟.
    fn numeric<const M: usize>(
        x: &NavState,
        f: impl Fn(&NavState) -> SVector<f64, M>,
    ) -> SMatrix<f64, M, STATE_DIM> {
        let mut j = SMatrix::<f64, M, STATE_DIM>::zeros();
        for i in 0..STATE_DIM {
            let mut d = Vec15::zeros();
            d[i] = EPS;
            let col = (f(&x.boxplus(&d)) - f(&x.boxplus(&(-d)))) / (2.0 * EPS);
            j.set_column(i, &col);
        }
        j
    }

    fn check<const M: usize>(
        name: &str,
        analytic: &SMatrix<f64, M, STATE_DIM>,
        num: &SMatrix<f64, M, STATE_DIM>,
    ) {
        let err = (analytic - num).amax();
        assert!(
            err < TOL * (1.0 + num.amax()),
            "{name}: max error {err}\n{analytic}\n{num}"
        );
    }

    #[test]
    fn gnss_position_jacobian_is_numeric_derivative() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for _ in 0..50 {
            let x = random_state(&mut rng);
            let r_ia = v3(&mut rng, 1.0);
            // The model is eq. (1): the antenna point mapped by world_from_imu.
            let iso = x.world_from_imu() * nalgebra::Point3::from(r_ia);
            assert!((gnss_position_model(&x, &r_ia) - iso.coords).norm() < 1e-12);
            let lin = gnss_position(&x, &r_ia, &Vector3::zeros());
            let num = numeric(&x, |y| gnss_position_model(y, &r_ia));
            check("gnss position", &lin.h, &num);
        }
    }

    #[test]
    fn gnss_velocity_jacobian_is_numeric_derivative() {
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        for _ in 0..50 {
            let x = random_state(&mut rng);
            let r_ia = v3(&mut rng, 1.0);
            let omega = v3(&mut rng, 2.0);
            let lin = gnss_velocity(&x, &r_ia, &omega, &Vector3::zeros());
            let num = numeric(&x, |y| gnss_velocity_model(y, &r_ia, &omega));
            check("gnss velocity", &lin.h, &num);
        }
    }

    #[test]
    fn orientation_jacobian_is_numeric_derivative() {
        let mut rng = ChaCha8Rng::seed_from_u64(13);
        for _ in 0..50 {
            let x = random_state(&mut rng);
            let lin = orientation(&x, &x.q);
            assert!(lin.residual.norm() < 1e-12);
            // Measurement-space ⊟ on SO(3): Log(h(x̂)⁻¹ h(x)).
            let num = numeric(&x, |y| log(&(x.q.inverse() * y.q)));
            check("orientation", &lin.h, &num);
            // The residual of a known local error is that error.
            let e = v3(&mut rng, 0.1);
            let lin = orientation(&x, &(x.q * exp(&e)));
            assert!((lin.residual - e).norm() < 1e-12);
        }
    }

    #[test]
    fn tracking_relative_jacobian_is_numeric_derivative() {
        let mut rng = ChaCha8Rng::seed_from_u64(14);
        for _ in 0..50 {
            let x = random_state(&mut rng);
            // The model is clone⁻¹ · current, as isometries.
            let (dp_hat, dq_hat) = relative_pose_model(&x);
            let clone = Isometry3::from_parts(Translation3::from(x.p_clone), x.q_clone);
            let rel = clone.inverse() * x.world_from_imu();
            assert!((rel.translation.vector - dp_hat).norm() < 1e-10);
            assert!(rel.rotation.angle_to(&dq_hat) < 1e-12);
            let lin = tracking_relative(&x, &dp_hat, &dq_hat);
            assert!(lin.residual.norm() < 1e-10);
            let num = numeric(&x, |y| {
                let (dp, dq) = relative_pose_model(y);
                let mut out = SVector::<f64, 6>::zeros();
                out.fixed_rows_mut::<3>(0).copy_from(&(dp - dp_hat));
                out.fixed_rows_mut::<3>(3)
                    .copy_from(&log(&(dq_hat.inverse() * dq)));
                out
            });
            check("tracking relative", &lin.h, &num);
        }
    }
}
