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

/// AHRS roll and pitch only (`yaw = "relative"`): the measured `world_from_imu` `z` is used
/// through the up direction it gives in the IMU frame, `zᵀ e_z`, which does not depend on
/// its yaw (so an arbitrarily offset heading reference changes nothing). With
/// `u = R̂ zᵀ e_z` the residual is `[u_y, −u_x]`: the world-x and world-y components of the
/// rotation from the estimate to the measurement (rad, to first order), and
/// `H = [0, 0, rows 0–1 of R̂, 0]`.
pub fn tilt(x: &NavState, z: &UnitQuaternion<f64>) -> Linearized<2> {
    let r = x.q.to_rotation_matrix().into_inner();
    let u = x.q * (z.inverse() * Vector3::z());
    let mut h = SMatrix::<f64, 2, STATE_DIM>::zeros();
    h.fixed_view_mut::<2, 3>(0, IDX_TH)
        .copy_from(&r.fixed_rows::<2>(0));
    Linearized {
        residual: SVector::<f64, 2>::new(u.y, -u.x),
        h,
    }
}

/// The heading of the body's forward axis in the world (rad, counter-clockwise from east):
/// the yaw of `R e_f`, `R` = `world_from_imu`, `e_f` the body x axis in the IMU frame.
pub fn heading_model(world_from_imu: &UnitQuaternion<f64>, forward_in_imu: &Vector3<f64>) -> f64 {
    let f = world_from_imu * forward_in_imu;
    f.y.atan2(f.x)
}

/// Heading from the course over ground (`yaw = "relative"`): `z` the direction of the
/// horizontal GNSS velocity (rad, counter-clockwise from east), taken as the heading of the
/// body's forward axis `e_f` (IMU frame). Residual `wrap(z − ψ̂)`; with `f = R̂ e_f`,
/// `H_θ = (−f_y, f_x, 0)/(f_x² + f_y²) · (−R̂ [e_f]×)`.
pub fn course(x: &NavState, forward_in_imu: &Vector3<f64>, z: f64) -> Linearized<1> {
    let r = x.q.to_rotation_matrix().into_inner();
    let f = r * forward_in_imu;
    let n = (f.x * f.x + f.y * f.y).max(1e-12);
    let dpsi_df = nalgebra::RowVector3::new(-f.y / n, f.x / n, 0.0);
    let mut h = SMatrix::<f64, 1, STATE_DIM>::zeros();
    h.fixed_view_mut::<1, 3>(0, IDX_TH)
        .copy_from(&(dpsi_df * (-(r * skew(forward_in_imu)))));
    Linearized {
        residual: SVector::<f64, 1>::new(wrap_pi(z - heading_model(&x.q, forward_in_imu))),
        h,
    }
}

/// `a` wrapped into `(−π, π]`.
pub fn wrap_pi(a: f64) -> f64 {
    let w = a.rem_euclid(std::f64::consts::TAU);
    if w > std::f64::consts::PI {
        w - std::f64::consts::TAU
    } else {
        w
    }
}

/// Predicted wheel-odometry velocity: the velocity of the odometry's moving frame `o`
/// (usually `base_link`) in that frame, `R_ioᵀ(Rᵀv + ω × r_io)`, with `imu_from_o =
/// (R_io, r_io)` and `ω` the IMU's angular rate in the IMU frame (rad/s).
pub fn body_velocity_model(
    x: &NavState,
    imu_from_o: &nalgebra::Isometry3<f64>,
    omega: &Vector3<f64>,
) -> Vector3<f64> {
    let v_imu = x.q.inverse() * x.v;
    imu_from_o.rotation.inverse() * (v_imu + omega.cross(&imu_from_o.translation.vector))
}

/// Wheel odometry with the non-holonomic constraint: `z` the velocity of frame `o` in
/// `o` (forward speed from the wheels, lateral and vertical 0 for a vehicle that does
/// not slide sideways or leave the ground), m/s. With `Rᵀ` of the perturbed state
/// `≈ (I − [δθ]×)Rᵀ`: `H = [0, R_ioᵀRᵀ, R_ioᵀ[Rᵀv]×, 0]`.
pub fn body_velocity(
    x: &NavState,
    imu_from_o: &nalgebra::Isometry3<f64>,
    omega: &Vector3<f64>,
    z: &Vector3<f64>,
) -> Linearized<3> {
    let r = x.q.to_rotation_matrix().into_inner();
    let r_io = imu_from_o.rotation.to_rotation_matrix().into_inner();
    let mut h = SMatrix::<f64, 3, STATE_DIM>::zeros();
    h.fixed_view_mut::<3, 3>(0, IDX_V)
        .copy_from(&(r_io.transpose() * r.transpose()));
    h.fixed_view_mut::<3, 3>(0, IDX_TH)
        .copy_from(&(r_io.transpose() * skew(&(r.transpose() * x.v))));
    Linearized {
        residual: z - body_velocity_model(x, imu_from_o, omega),
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
    fn body_velocity_jacobian_is_numeric_derivative() {
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        for _ in 0..50 {
            let x = random_state(&mut rng);
            let omega = v3(&mut rng, 2.0);
            let imu_from_o = nalgebra::Isometry3::new(v3(&mut rng, 1.0), v3(&mut rng, 1.0));
            // Independent: the velocity of o's origin, w = v + R(ω × r), seen in o.
            let world_from_o = x.world_from_imu() * imu_from_o;
            let w = x.v + x.q * omega.cross(&imu_from_o.translation.vector);
            let direct = world_from_o.rotation.inverse() * w;
            assert!((body_velocity_model(&x, &imu_from_o, &omega) - direct).norm() < 1e-12);
            let lin = body_velocity(&x, &imu_from_o, &omega, &Vector3::zeros());
            let num = numeric(&x, |y| body_velocity_model(y, &imu_from_o, &omega));
            check("body velocity", &lin.h, &num);
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
    fn tilt_ignores_yaw_and_its_jacobian_is_numeric_derivative() {
        let mut rng = ChaCha8Rng::seed_from_u64(15);
        for _ in 0..50 {
            let x = random_state(&mut rng);
            // Any heading offset of the reference leaves the residual at zero.
            let yaw =
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), rng.random_range(-3.1..3.1));
            let lin = tilt(&x, &(yaw * x.q));
            assert!(lin.residual.norm() < 1e-12);
            let num = numeric(&x, |y| tilt(&x, &y.q).residual);
            check("tilt", &lin.h, &num);
            // A known small world-axis tilt error is the residual (first order).
            let e = Vector3::new(
                rng.random_range(-1e-4..1e-4),
                rng.random_range(-1e-4..1e-4),
                0.0,
            );
            let lin = tilt(&x, &(exp(&e) * x.q));
            assert!(
                (lin.residual - e.xy()).norm() < 1e-7,
                "{} vs {}",
                lin.residual,
                e.xy()
            );
        }
    }

    #[test]
    fn course_jacobian_is_numeric_derivative_and_wraps() {
        let mut rng = ChaCha8Rng::seed_from_u64(16);
        for _ in 0..50 {
            let x = random_state(&mut rng);
            let ef = exp(&v3(&mut rng, 0.3)) * Vector3::x();
            let psi = heading_model(&x.q, &ef);
            let lin = course(&x, &ef, psi);
            assert!(lin.residual[0].abs() < 1e-12);
            let num = numeric(&x, |y| {
                SVector::<f64, 1>::new(wrap_pi(heading_model(&y.q, &ef) - psi))
            });
            check("course", &lin.h, &num);
            // Across ±π the residual is the short way round.
            let lin = course(&x, &ef, psi + std::f64::consts::TAU + 0.01);
            assert!((lin.residual[0] - 0.01).abs() < 1e-9);
        }
        assert_eq!(wrap_pi(std::f64::consts::PI), std::f64::consts::PI);
        assert!((wrap_pi(-std::f64::consts::PI) - std::f64::consts::PI).abs() < 1e-15);
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
