//! The EIF's inertial core: nominal state, error state, and the IMU prediction of
//! eq. (3) of the seed paper with its block-structured covariance propagation.
//!
//! **Nominal state** (the paper's sensor box "sb" = the IMU frame): `p` the world (ENU)
//! position of the IMU origin (m), `v` its world velocity (m/s), `q = world_from_imu`;
//! plus a stochastic clone `(p_clone, q_clone)` of the pose at the previous
//! tracking-camera message.
//!
//! **Error state** `δx ∈ R¹⁵ = [δp, δv, δθ, δp_c, δθ_c]` with the local (right)
//! perturbation `q_true = q ⊗ Exp(δθ)`, `p_true = p + δp` (see [`NavState::boxplus`]).
//! While the clone is inactive its rows and columns are decoupled (zero cross
//! covariance, unit variance) and no measurement touches them.

use super::so3::{exp, renormalize, skew};
use nalgebra::{Isometry3, Matrix3, SMatrix, SVector, Translation3, UnitQuaternion, Vector3};

/// Dimension of the error state (9 navigation + 6 clone).
pub const STATE_DIM: usize = 15;
/// Offset of `δp` in the error state.
pub const IDX_P: usize = 0;
/// Offset of `δv`.
pub const IDX_V: usize = 3;
/// Offset of `δθ`.
pub const IDX_TH: usize = 6;
/// Offset of the clone's `δp_c`.
pub const IDX_PC: usize = 9;
/// Offset of the clone's `δθ_c`.
pub const IDX_THC: usize = 12;
/// Variance given to the clone's rows while the clone is inactive (decoupled, unused).
pub const INACTIVE_CLONE_VARIANCE: f64 = 1.0;

/// A 15×15 matrix over the error state (covariance or information).
pub type Mat15 = SMatrix<f64, STATE_DIM, STATE_DIM>;
/// A vector over the error state.
pub type Vec15 = SVector<f64, STATE_DIM>;

/// The nominal navigation state of the IMU frame, plus the tracking-camera clone.
#[derive(Clone, Debug, PartialEq)]
pub struct NavState {
    /// World (ENU) position of the IMU origin, m.
    pub p: Vector3<f64>,
    /// World velocity of the IMU origin, m/s.
    pub v: Vector3<f64>,
    /// `world_from_imu` orientation.
    pub q: UnitQuaternion<f64>,
    /// Clone of `p` at the previous tracking-camera message, m.
    pub p_clone: Vector3<f64>,
    /// Clone of `q` (`world_from_imu`) at the previous tracking-camera message.
    pub q_clone: UnitQuaternion<f64>,
}

impl NavState {
    /// A state at rest at `p` with orientation `q` (clone = the same pose).
    pub fn at_rest(p: Vector3<f64>, q: UnitQuaternion<f64>) -> NavState {
        NavState {
            p,
            v: Vector3::zeros(),
            q,
            p_clone: p,
            q_clone: q,
        }
    }

    /// `x ⊞ δx`: `p + δp`, `v + δv`, `q ⊗ Exp(δθ)`, `p_c + δp_c`, `q_c ⊗ Exp(δθ_c)`.
    pub fn boxplus(&self, dx: &Vec15) -> NavState {
        let d = |i: usize| Vector3::new(dx[i], dx[i + 1], dx[i + 2]);
        NavState {
            p: self.p + d(IDX_P),
            v: self.v + d(IDX_V),
            q: renormalize(&(self.q * exp(&d(IDX_TH)))),
            p_clone: self.p_clone + d(IDX_PC),
            q_clone: renormalize(&(self.q_clone * exp(&d(IDX_THC)))),
        }
    }

    /// `world_from_imu` as an isometry.
    pub fn world_from_imu(&self) -> Isometry3<f64> {
        Isometry3::from_parts(Translation3::from(self.p), self.q)
    }
}

/// White process-noise densities of the prediction, SI.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct ProcessNoise {
    /// Accelerometer white-noise variance density, (m/s²)²/Hz: `Q_v = accel · Δt · I`.
    pub accel_var_per_hz: f64,
    /// Gyro white-noise variance density, (rad/s)²/Hz: `Q_θ = gyro · Δt · I`.
    pub gyro_var_per_hz: f64,
}

/// One standard g in m/s², the unit of accelerometer datasheets (1 µg = 9.80665e-6 m/s²).
pub const STANDARD_GRAVITY: f64 = 9.806_65;

impl ProcessNoise {
    /// From datasheet densities (°/s/√Hz and µg/√Hz), each with an extra density added
    /// in quadrature.
    pub fn from_datasheet(
        gyro_dps_rthz: f64,
        gyro_extra_dps_rthz: f64,
        accel_ug_rthz: f64,
        accel_extra_ug_rthz: f64,
    ) -> ProcessNoise {
        let g = gyro_dps_rthz.to_radians();
        let ge = gyro_extra_dps_rthz.to_radians();
        let a = accel_ug_rthz * 1e-6 * STANDARD_GRAVITY;
        let ae = accel_extra_ug_rthz * 1e-6 * STANDARD_GRAVITY;
        ProcessNoise {
            accel_var_per_hz: a * a + ae * ae,
            gyro_var_per_hz: g * g + ge * ge,
        }
    }
}

/// The moment-form part of the filter that runs between corrections: the nominal state
/// and the error covariance `P` (`Λ⁻¹`).
#[derive(Clone, Debug, PartialEq)]
pub struct InsCore {
    /// The nominal state.
    pub nav: NavState,
    /// Error covariance over `[δp, δv, δθ, δp_c, δθ_c]`.
    pub cov: Mat15,
    /// Gravity magnitude, m/s² (world acceleration of gravity is `−g e_z`).
    pub gravity: f64,
    /// Whether the clone holds a real earlier pose (cross-covariances are propagated).
    pub clone_active: bool,
}

/// The quantities of one prediction step that the covariance propagation needs.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct StepJacobian {
    /// Step length, s.
    pub dt: f64,
    /// `∂δv⁺/∂δθ = −R [Exp(ω̄Δt/2) f̄]× Δt` (the (p, θ) block is half of it times `Δt`).
    pub b: Matrix3<f64>,
    /// `∂δθ⁺/∂δθ = Exp(ω̄Δt)ᵀ`.
    pub g: Matrix3<f64>,
}

impl InsCore {
    /// A core at `nav` with covariance `cov`, clone inactive.
    pub fn new(nav: NavState, cov: Mat15, gravity: f64) -> InsCore {
        InsCore {
            nav,
            cov,
            gravity,
            clone_active: false,
        }
    }

    /// One IMU prediction step of eq. (3) over `dt` seconds with the interval's mean
    /// specific force `f_mean` (m/s², IMU frame) and rate `w_mean` (rad/s, IMU frame).
    ///
    /// The nominal update uses the exact exponential `q⁺ = q ⊗ Exp(ω̄Δt)` instead of the
    /// paper's first-order quaternion step `‖q + Δt/2 · q ⊗ [ω, 0]‖`, and rotates the
    /// specific force with the mid-interval attitude `R_m = R·Exp(ω̄Δt/2)`:
    /// `a = R_m f̄ − g e_z`, `v⁺ = v + aΔt`, `p⁺ = p + vΔt + ½aΔt²` (second-order
    /// accurate when the body turns; with `R` at the interval start a turning body picks
    /// up a spurious along-track acceleration of `ω|a|Δt/2`).
    ///
    /// The error covariance is propagated as `P ← F P Fᵀ + Q` with
    /// `F = [[I, IΔt, ½BΔt, 0], [0, I, B, 0], [0, 0, G, 0], [0, 0, 0, I]]`,
    /// `B = −R [Exp(ω̄Δt/2) f̄]× Δt`, `G = Exp(ω̄Δt)ᵀ` (see [`StepJacobian`]), and
    /// `Q = diag(0, σ_a²Δt·I, σ_g²Δt·I, 0)`,
    /// written block by block (no dense 15×15 product). `F` is the exact Jacobian of the
    /// nominal step, including the `½BΔt` position–attitude term.
    #[inline]
    pub fn predict(
        &mut self,
        dt: f64,
        f_mean: &Vector3<f64>,
        w_mean: &Vector3<f64>,
        noise: &ProcessNoise,
    ) {
        let jac = self.predict_nominal(dt, f_mean, w_mean);
        propagate_covariance(
            &mut self.cov,
            &jac,
            noise.accel_var_per_hz * dt,
            noise.gyro_var_per_hz * dt,
            self.clone_active,
        );
    }

    /// The nominal part of [`InsCore::predict`]; returns the step's Jacobian blocks.
    #[inline]
    pub fn predict_nominal(
        &mut self,
        dt: f64,
        f_mean: &Vector3<f64>,
        w_mean: &Vector3<f64>,
    ) -> StepJacobian {
        let half = exp(&(w_mean * (0.5 * dt)));
        let dq = half * half;
        let r = self.nav.q.to_rotation_matrix().into_inner();
        let f_mid = half.transform_vector(f_mean);
        let rf = r * f_mid;
        let acc = Vector3::new(rf.x, rf.y, rf.z - self.gravity);
        let nav = &mut self.nav;
        nav.p += nav.v * dt + acc * (0.5 * dt * dt);
        nav.v += acc * dt;
        nav.q = renormalize(&(nav.q * dq));
        StepJacobian {
            dt,
            b: -(r * skew(&f_mid)) * dt,
            g: dq.to_rotation_matrix().into_inner().transpose(),
        }
    }

    /// Copies the current pose into the clone: `P ← J P Jᵀ` with `J` the map that copies
    /// `(δp, δθ)` into `(δp_c, δθ_c)`. Activates the clone.
    pub fn reclone(&mut self) {
        self.nav.p_clone = self.nav.p;
        self.nav.q_clone = self.nav.q;
        let old = self.cov;
        let src = |i: usize| -> usize {
            if i < IDX_PC {
                i
            } else if i < IDX_THC {
                IDX_P + (i - IDX_PC)
            } else {
                IDX_TH + (i - IDX_THC)
            }
        };
        for i in 0..STATE_DIM {
            for j in 0..STATE_DIM {
                self.cov[(i, j)] = old[(src(i), src(j))];
            }
        }
        self.clone_active = true;
    }
}

#[inline]
fn block(m: &Mat15, i: usize, j: usize) -> Matrix3<f64> {
    m.fixed_view::<3, 3>(3 * i, 3 * j).into_owned()
}

#[inline]
fn set_sym(m: &mut Mat15, i: usize, j: usize, b: &Matrix3<f64>) {
    m.fixed_view_mut::<3, 3>(3 * i, 3 * j).copy_from(b);
    if i != j {
        m.fixed_view_mut::<3, 3>(3 * j, 3 * i)
            .copy_from(&b.transpose());
    }
}

/// `P ← F P Fᵀ + Q` for the transition of [`InsCore::predict`], written with the 3×3
/// blocks of `F` (identity, `Δt·I`, `B`, `½BΔt`, `G`): nine 3×3 products for the
/// navigation block and two 3×6 products for the clone cross-covariance, instead of two
/// dense 15×15 products. `qa`, `qg` are the velocity and attitude noise variances of the
/// step. With `clone_active == false` the clone rows are left as they are (decoupled).
///
/// Block algebra (indices 0 = p, 1 = v, 2 = θ; `M = F P`, `a = Δt`):
/// `M₁ⱼ = P₁ⱼ + B P₂ⱼ`, `M₀ⱼ = P₀ⱼ + a/2 (P₁ⱼ + M₁ⱼ)`, `M₂ⱼ = G P₂ⱼ`;
/// `P'ᵢ₁ = Mᵢ₁ + Mᵢ₂ Bᵀ`, `P'ᵢ₀ = Mᵢ₀ + a/2 (Mᵢ₁ + P'ᵢ₁)`, `P'ᵢ₂ = Mᵢ₂ Gᵀ`
/// (the `½BΔt` terms are recovered from `B P` products already formed).
#[inline]
pub fn propagate_covariance(p: &mut Mat15, jac: &StepJacobian, qa: f64, qg: f64, clone: bool) {
    let (b, g) = (&jac.b, &jac.g);
    let h = 0.5 * jac.dt;
    let p00 = block(p, 0, 0);
    let p01 = block(p, 0, 1);
    let p02 = block(p, 0, 2);
    let p11 = block(p, 1, 1);
    let p12 = block(p, 1, 2);
    let p22 = block(p, 2, 2);
    let p10 = p01.transpose();
    let p20 = p02.transpose();
    let p21 = p12.transpose();
    // M = F P (rows p, v, θ), only the blocks needed for the upper triangle of P'.
    let m10 = p10 + b * p20;
    let m11 = p11 + b * p21;
    let m12 = p12 + b * p22;
    let m00 = p00 + (p10 + m10) * h;
    let m01 = p01 + (p11 + m11) * h;
    let m02 = p02 + (p12 + m12) * h;
    let m22 = g * p22;
    // P' = M Fᵀ + Q.
    let bt = b.transpose();
    let gt = g.transpose();
    let n01 = m01 + m02 * bt;
    let n00 = m00 + (m01 + n01) * h;
    let n02 = m02 * gt;
    let mut n11 = m11 + m12 * bt;
    let n12 = m12 * gt;
    let mut n22 = m22 * gt;
    for k in 0..3 {
        n11[(k, k)] += qa;
        n22[(k, k)] += qg;
    }
    set_sym(p, 0, 0, &n00);
    set_sym(p, 0, 1, &n01);
    set_sym(p, 0, 2, &n02);
    set_sym(p, 1, 1, &n11);
    set_sym(p, 1, 2, &n12);
    set_sym(p, 2, 2, &n22);
    if clone {
        // Cross-covariance with the clone: C' = F_nav C (clone rows of F are identity).
        let c0 = p.fixed_view::<3, 6>(IDX_P, IDX_PC).into_owned();
        let c1 = p.fixed_view::<3, 6>(IDX_V, IDX_PC).into_owned();
        let c2 = p.fixed_view::<3, 6>(IDX_TH, IDX_PC).into_owned();
        let d1 = c1 + b * c2;
        let d0 = c0 + (c1 + d1) * h;
        let d2 = g * c2;
        p.fixed_view_mut::<3, 6>(IDX_P, IDX_PC).copy_from(&d0);
        p.fixed_view_mut::<3, 6>(IDX_V, IDX_PC).copy_from(&d1);
        p.fixed_view_mut::<3, 6>(IDX_TH, IDX_PC).copy_from(&d2);
        p.fixed_view_mut::<6, 3>(IDX_PC, IDX_P)
            .copy_from(&d0.transpose());
        p.fixed_view_mut::<6, 3>(IDX_PC, IDX_V)
            .copy_from(&d1.transpose());
        p.fixed_view_mut::<6, 3>(IDX_PC, IDX_TH)
            .copy_from(&d2.transpose());
    }
}

/// The dense transition matrix `F` of a step (for tests and documentation; the filter
/// never forms it).
pub fn dense_transition(jac: &StepJacobian) -> Mat15 {
    let mut f = Mat15::identity();
    f.fixed_view_mut::<3, 3>(IDX_P, IDX_V)
        .copy_from(&(Matrix3::identity() * jac.dt));
    f.fixed_view_mut::<3, 3>(IDX_P, IDX_TH)
        .copy_from(&(jac.b * (0.5 * jac.dt)));
    f.fixed_view_mut::<3, 3>(IDX_V, IDX_TH).copy_from(&jac.b);
    f.fixed_view_mut::<3, 3>(IDX_TH, IDX_TH).copy_from(&jac.g);
    f
}

#[cfg(test)]
mod tests {
    use super::super::so3::log;
    use super::*;
    use proptest::prelude::*;

    fn vec3(r: f64) -> impl Strategy<Value = Vector3<f64>> {
        (-r..r, -r..r, -r..r).prop_map(|(x, y, z)| Vector3::new(x, y, z))
    }

    fn spd15() -> impl Strategy<Value = Mat15> {
        proptest::collection::vec(-1.0f64..1.0, STATE_DIM * STATE_DIM).prop_map(|v| {
            let a = Mat15::from_column_slice(&v);
            a * a.transpose() + Mat15::identity() * 0.1
        })
    }

    fn state(p: Vector3<f64>, v: Vector3<f64>, th: Vector3<f64>) -> NavState {
        NavState {
            p,
            v,
            q: exp(&th),
            p_clone: p * 0.5,
            q_clone: exp(&(th * -0.3)),
        }
    }

    proptest! {
        /// The block-structured propagation equals the dense `F P Fᵀ + Q`.
        #[test]
        fn block_propagation_equals_dense(
            p in spd15(),
            f in vec3(20.0), w in vec3(3.0), th in vec3(3.0),
            dt in 1e-4f64..0.1, qa in 0.0f64..1.0, qg in 0.0f64..1.0,
        ) {
            let mut core = InsCore::new(state(Vector3::zeros(), Vector3::zeros(), th), p, 9.8);
            let jac = core.predict_nominal(dt, &f, &w);
            let f_dense = dense_transition(&jac);
            let mut q = Mat15::zeros();
            for k in 0..3 {
                q[(IDX_V + k, IDX_V + k)] = qa;
                q[(IDX_TH + k, IDX_TH + k)] = qg;
            }
            let dense = f_dense * p * f_dense.transpose() + q;
            let mut blocked = p;
            propagate_covariance(&mut blocked, &jac, qa, qg, true);
            let scale = dense.amax();
            prop_assert!((blocked - dense).amax() <= 1e-12 * scale, "{}", (blocked - dense).amax());
            // Without the clone, only the navigation block moves.
            let mut nav_only = p;
            propagate_covariance(&mut nav_only, &jac, qa, qg, false);
            let nav = |m: &Mat15| m.fixed_view::<9, 9>(0, 0).into_owned();
            prop_assert!((nav(&nav_only) - nav(&dense)).amax() <= 1e-12 * scale);
            prop_assert_eq!(nav_only.fixed_view::<15, 6>(0, 9).into_owned(),
                            p.fixed_view::<15, 6>(0, 9).into_owned());
        }

        /// `F` is the Jacobian of the nominal step: stepping a perturbed state equals
        /// perturbing the stepped state by `F δx` to first order (central differences).
        #[test]
        fn transition_is_the_jacobian_of_the_nominal_step(
            p0 in vec3(10.0), v0 in vec3(3.0), th in vec3(3.0),
            f in vec3(20.0), w in vec3(3.0), dt in 1e-3f64..0.1,
        ) {
            let x = state(p0, v0, th);
            let mut base = InsCore::new(x.clone(), Mat15::identity(), 9.8);
            let jac = base.predict_nominal(dt, &f, &w);
            let f_dense = dense_transition(&jac);
            let eps = 1e-6;
            for i in 0..9 {
                let mut d = Vec15::zeros();
                d[i] = eps;
                let step = |x: NavState| {
                    let mut c = InsCore::new(x, Mat15::identity(), 9.8);
                    c.predict_nominal(dt, &f, &w);
                    c.nav
                };
                let plus = step(x.boxplus(&d));
                let minus = step(x.boxplus(&(-d)));
                // ⊟ relative to the stepped nominal state.
                let diff = |y: &NavState| {
                    let mut out = SVector::<f64, 9>::zeros();
                    out.fixed_rows_mut::<3>(0).copy_from(&(y.p - base.nav.p));
                    out.fixed_rows_mut::<3>(3).copy_from(&(y.v - base.nav.v));
                    out.fixed_rows_mut::<3>(6).copy_from(&log(&(base.nav.q.inverse() * y.q)));
                    out
                };
                let numeric = (diff(&plus) - diff(&minus)) / (2.0 * eps);
                let analytic = f_dense.fixed_view::<9, 1>(0, i).into_owned();
                prop_assert!((numeric - analytic).amax() < 1e-6,
                    "column {}: {} vs {}", i, numeric, analytic);
            }
        }
    }

    #[test]
    fn process_noise_units() {
        // 60 µg/√Hz → 5.88e-4 m/s²/√Hz; 0.01 °/s/√Hz → 1.745e-4 rad/s/√Hz.
        let n = ProcessNoise::from_datasheet(0.01, 0.0, 60.0, 0.0);
        assert!((n.accel_var_per_hz.sqrt() - 60e-6 * 9.80665).abs() < 1e-15);
        assert!((n.gyro_var_per_hz.sqrt() - 0.01 * std::f64::consts::PI / 180.0).abs() < 1e-15);
        // Extra densities add in quadrature: 3-4-5.
        let n = ProcessNoise::from_datasheet(0.03, 0.04, 30.0, 40.0);
        assert!((n.accel_var_per_hz.sqrt() - 50e-6 * 9.80665).abs() < 1e-15);
        assert!((n.gyro_var_per_hz.sqrt() - 0.05f64.to_radians()).abs() < 1e-15);
    }

    #[test]
    fn reclone_copies_pose_rows() {
        let a =
            Mat15::from_fn(|i, j| ((i * 7 + j * 3) % 11) as f64 + if i == j { 20.0 } else { 0.0 });
        let p = a * a.transpose();
        let mut core = InsCore::new(state(Vector3::x(), Vector3::y(), Vector3::z()), p, 9.8);
        core.reclone();
        assert_eq!(core.nav.p_clone, core.nav.p);
        assert_eq!(core.nav.q_clone, core.nav.q);
        // Clone-clone block equals the (p, θ) block; clone-velocity equals pose-velocity.
        for (ci, si) in [(IDX_PC, IDX_P), (IDX_THC, IDX_TH)] {
            for (cj, sj) in [(IDX_PC, IDX_P), (IDX_THC, IDX_TH)] {
                assert_eq!(
                    core.cov.fixed_view::<3, 3>(ci, cj).into_owned(),
                    p.fixed_view::<3, 3>(si, sj).into_owned()
                );
            }
            assert_eq!(
                core.cov.fixed_view::<3, 3>(ci, IDX_V).into_owned(),
                p.fixed_view::<3, 3>(si, IDX_V).into_owned()
            );
        }
        assert!(core.clone_active);
    }
}
