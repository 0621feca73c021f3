//! Ground contact of tracks and mecanum wheels, and the motors that drive them.
//!
//! Pure functions of the body state, the ground surface and the drive joints: the rigid
//! body integrator (rapier3d, or any other backend) only receives the resulting force
//! and torque. The model is written out here because it is the part of the physics a
//! user of a vineyard test bench cares about: how tracks slip in a turn, how mecanum
//! rollers let the rover strafe, what the IMU feels on rough soil.
//!
//! # Probes
//! The running gear meets the ground at *probes*: spheres of radius `r` at fixed points of
//! the body. A track has `N` probes along its ground run (the road wheels, with the
//! sprocket and idler at the two ends; `r` = half the track height), a mecanum wheel one
//! probe at its centre (`r` = wheel radius). Each probe carries its share of the
//! track's or wheel's contact stiffness `kp` and damping `kd` (URDF `<gazebo>` block).
//!
//! # Normal force
//! At the probe centre `c` the ground (a C² [`Surface`]) gives height `h`, normal `n`;
//! the distance from `c` to the tangent plane is `d = n_z·(c_z − h)` and the
//! penetration is `δ = r_eff − d`, with `r_eff = r + a·cos(2π·(θ·R + x₀)/λ)` carrying
//! the ride ripple of the track links (`λ` = link pitch) or mecanum rollers
//! (`λ = 2πR/rollers`), `θ` the drive joint angle and `R` its rolling radius. While
//! `δ > 0` the normal force is the spring-damper `F_n = max(0, k·δ + c·δ̇)` at the contact
//! point `q = c − d·n`.
//!
//! # Tangential force: shear displacement with relaxation
//! The drive surface at the contact moves at `R·ω·t` relative to the body (`t` the
//! rolling direction projected on the ground plane), so the slip velocity of the drive
//! surface over the ground is `s = v_q − R·ω·t`. Soil (or tyre) shear builds up with slip
//! and relaxes as fresh ground enters the contact patch (Janosi-Hanamoto shear
//! displacement, written as a first-order relaxation model as used for tyres):
//!
//! `ξ̇ = s − (|v_t|/σ)·ξ`, `F_i = −μ_i·F_n·(ξ_i + τ_d·ξ̇_i)/K`, for the two contact axes
//! `e₁` (the URDF's `fdir1` on the ground plane) and `e₂ = n × e₁`,
//!
//! with `K` the soil's shear deformation modulus (`physics.shear_deformation_m`), `τ_d` a
//! damping time, `v_t` the speed over ground along the rolling direction, and `σ` the
//! relaxation length: for a track probe its distance from the track's leading edge
//! (soil under the rear of a track has been sheared longest: in steady state
//! `ξ = i·x`, Janosi's shear displacement at distance `x` behind the front for slip
//! ratio `i`), for a wheel half its radius. The force is limited to the friction ellipse
//! `(F₁/μ₁F_n)² + (F₂/μ₂F_n)² ≤ 1` (sliding: `ξ` is clamped to the ellipse). An axis with
//! `μ = 0` (a free mecanum roller) carries no force. So:
//! - at standstill the shear is an elastic spring: a parked robot holds on a slope and
//!   does not creep (static friction), unlike a regularised Coulomb model;
//! - in steady motion, traction grows with the slip ratio `i = s/v` with slope
//!   `μF_n·σ/K` and saturates at `μF_n`: tracks slip more the harder they pull, and
//!   skid-steer turns slide laterally, giving the physical ICR expansion;
//! - a mecanum wheel pushes only along its ground rollers' axis, so wheel speeds from the
//!   mecanum inverse kinematics move the rover sideways, and any mismatch slips.
//!
//! # Rolling resistance and motors
//! Soil compaction resists the motion: a force `c_rr·F_n·tanh(|v|/v_ε)` against the
//! probe's velocity over the ground plane. The tracks must pull against it through the shear, so they
//! slip a little even on flat ground at constant speed. (Losses inside the drive train
//! are the joint's `<dynamics>` friction below.) Each drive joint is a velocity servo:
//! `τ = clamp(k_p·(ω_ref − ω) + k_i·∫(ω_ref − ω), ±τ_max)` with gains from a bandwidth on
//! the load the joint moves, `J_load = I + (m/n)·R²`: `k_p = J_load·2πf`,
//! `k_i = k_p·2πf/4` (anti-windup: the integral stops while the torque saturates). The
//! joint obeys `I·ω̇ = τ − R·F_t − b·ω − τ_f·tanh(ω/ω_ε)`, with `F_t` the shear force
//! along the rolling direction, `I` the drive train's inertia (URDF), `b` and `τ_f` the
//! joint's `<dynamics damping friction>`.
//!
//! Everything is explicit at the physics step, except the relaxation, which is
//! integrated exactly over the step (`σ` may be short).

use super::BodyState;
use crate::robot::DriveJoint;
use crate::world::Surface;
use nalgebra::{Vector2, Vector3};

/// Drive joints beyond this speed count as turning for the joint friction and rolling
/// resistance (`tanh(ω/ω_ε)`), rad/s.
pub const JOINT_SPEED_EPS_RADPS: f64 = 0.05;
/// Speed over ground below which rolling resistance fades out (`tanh(v/v_ε)`), m/s.
pub const ROLLING_SPEED_EPS_MPS: f64 = 0.01;
/// Shortest relaxation length of a probe, m (the front probe of a track).
pub const MIN_RELAXATION_M: f64 = 0.05;

/// Where and how one part of the running gear touches the ground.
#[derive(Clone, Debug, PartialEq)]
pub struct GroundProbe {
    /// The drive joint whose surface rolls on the ground here (index in
    /// [`crate::robot::Drive::joints`]).
    pub joint: usize,
    /// Probe sphere centre in the body frame, m.
    pub centre_in_body: Vector3<f64>,
    /// Probe sphere radius, m.
    pub radius_m: f64,
    /// Contact stiffness of this probe, N/m.
    pub stiffness_n_per_m: f64,
    /// Contact damping of this probe, N·s/m.
    pub damping_ns_per_m: f64,
    /// Friction coefficients along `fdir1` and across it.
    pub mu: [f64; 2],
    /// First friction direction in the body frame (unit).
    pub fdir1_in_body: Vector3<f64>,
    /// Direction the drive surface pushes the robot when the joint turns forward (unit,
    /// body frame).
    pub roll_in_body: Vector3<f64>,
    /// Position of the probe along the rolling direction from the track's centre, m
    /// (0 for a wheel).
    pub along_m: f64,
    /// Half the ground run of the track, m; for a wheel, its relaxation length.
    pub half_run_m: f64,
    /// Ripple wavelength along the drive surface, m (0: no ripple).
    pub ripple_wavelength_m: f64,
    /// Where along the drive surface this probe's ripple starts, m (tracks: the probe's
    /// position along the track; wheels: staggered so that the wheels' rollers are not in
    /// step).
    pub ripple_phase_m: f64,
}

impl GroundProbe {
    /// Relaxation length `σ` for motion at `v_along` along the rolling direction: the
    /// distance from the leading edge of the track (a wheel: `half_run_m`).
    fn relaxation_m(&self, v_along: f64) -> f64 {
        if self.along_m == 0.0 {
            self.half_run_m.max(MIN_RELAXATION_M)
        } else {
            (self.half_run_m - v_along.signum() * self.along_m).max(MIN_RELAXATION_M)
        }
    }
}

/// Soil and drive-train parameters shared by every probe.
#[derive(Clone, Debug, PartialEq)]
pub struct SoilParams {
    /// Multiplies every friction coefficient (wet or dry ground).
    pub friction_scale: f64,
    /// Shear deformation modulus `K`, m.
    pub shear_deformation_m: f64,
    /// Damping time `τ_d` of the shear, s.
    pub shear_damping_s: f64,
    /// Rolling-resistance coefficient `c_rr`.
    pub rolling_resistance: f64,
    /// Ride ripple amplitude `a`, m.
    pub ripple_m: f64,
}

/// The state of one probe between steps.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ProbeState {
    /// Shear displacement `ξ` along `e₁`, `e₂`, m.
    pub shear_m: Vector2<f64>,
    /// Normal force at the last step, N.
    pub normal_force_n: f64,
    /// Penetration at the last step, m (≤ 0: no contact).
    pub penetration_m: f64,
}

/// Drive joint kinematics (angle, speed) and rolling radius, per joint.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct JointKinematics {
    /// Angle, rad.
    pub angle_rad: f64,
    /// Speed, rad/s.
    pub speed_radps: f64,
    /// Rolling radius, m.
    pub radius_m: f64,
}

/// The ground's push on the robot over one step.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ContactWrench {
    /// Total force, world frame, N.
    pub force_in_world: Vector3<f64>,
    /// Total torque about the centre of mass, world frame, N·m.
    pub torque_about_com_in_world: Vector3<f64>,
    /// Torque of the ground (traction reaction and rolling resistance) on each drive
    /// joint, N·m.
    pub joint_torque_nm: [f64; crate::robot::MAX_DRIVE_JOINTS],
}

/// All probes of a robot with their states.
#[derive(Clone, Debug)]
pub struct ContactModel {
    probes: Vec<GroundProbe>,
    state: Vec<ProbeState>,
    soil: SoilParams,
}

impl ContactModel {
    /// A model with every probe out of contact and unsheared.
    pub fn new(probes: Vec<GroundProbe>, soil: SoilParams) -> ContactModel {
        let state = vec![ProbeState::default(); probes.len()];
        ContactModel {
            probes,
            state,
            soil,
        }
    }

    /// The probes.
    pub fn probes(&self) -> &[GroundProbe] {
        &self.probes
    }

    /// The probe states after the last step.
    pub fn states(&self) -> &[ProbeState] {
        &self.state
    }

    /// Potential energy stored in the normal springs and in the shear springs (with the
    /// shear stiffness `μF_n/K` of the last step), J.
    pub fn spring_energy_j(&self) -> f64 {
        let k_shear = |mu: f64, s: &ProbeState| {
            mu * self.soil.friction_scale * s.normal_force_n / self.soil.shear_deformation_m
        };
        self.probes
            .iter()
            .zip(&self.state)
            .map(|(p, s)| {
                0.5 * p.stiffness_n_per_m * s.penetration_m.max(0.0).powi(2)
                    + 0.5 * k_shear(p.mu[0], s) * s.shear_m[0].powi(2)
                    + 0.5 * k_shear(p.mu[1], s) * s.shear_m[1].powi(2)
            })
            .sum()
    }

    /// The ground's force and torque (about the centre of mass `com_in_world`) on the
    /// body and its torques on the drive joints, from the state at the start of a step of
    /// `dt` seconds; advances the shear states.
    pub fn step<S: Surface>(
        &mut self,
        surface: &S,
        body: &BodyState,
        com_in_world: &Vector3<f64>,
        joints: &[JointKinematics],
        dt: f64,
    ) -> ContactWrench {
        let mut out = ContactWrench::default();
        let rot = body.world_from_body.rotation;
        let origin = body.world_from_body.translation.vector;
        let soil = &self.soil;
        for (probe, st) in self.probes.iter().zip(self.state.iter_mut()) {
            let joint = joints.get(probe.joint).copied().unwrap_or_default();
            let c = body.world_from_body * nalgebra::Point3::from(probe.centre_in_body);
            let g = surface.sample(c.x, c.y);
            let n = g.normal();
            let d = n.z * (c.z - g.height_m);
            let travel = joint.angle_rad * joint.radius_m;
            let (ripple, ripple_rate) = if probe.ripple_wavelength_m > 0.0 && soil.ripple_m > 0.0 {
                let k = std::f64::consts::TAU / probe.ripple_wavelength_m;
                let ph = k * (travel + probe.ripple_phase_m);
                (
                    soil.ripple_m * ph.cos(),
                    -soil.ripple_m * ph.sin() * k * joint.speed_radps * joint.radius_m,
                )
            } else {
                (0.0, 0.0)
            };
            let penetration = probe.radius_m + ripple - d;
            st.penetration_m = penetration;
            if penetration <= 0.0 {
                st.shear_m = Vector2::zeros();
                st.normal_force_n = 0.0;
                continue;
            }
            let q = c.coords - n * d;
            let v_q = body.velocity_in_world + body.angular_velocity_in_world.cross(&(q - origin));
            let penetration_rate = -n.dot(&v_q) + ripple_rate;
            let f_n = (probe.stiffness_n_per_m * penetration
                + probe.damping_ns_per_m * penetration_rate)
                .max(0.0);
            st.normal_force_n = f_n;
            if f_n == 0.0 {
                st.shear_m = Vector2::zeros();
                continue;
            }
            let on_plane = |v: Vector3<f64>| {
                let p = v - n * n.dot(&v);
                let norm = p.norm();
                if norm > 1e-12 { p / norm } else { p }
            };
            let e1 = on_plane(rot * probe.fdir1_in_body);
            let e2 = n.cross(&e1);
            let t = on_plane(rot * probe.roll_in_body);
            let slip = v_q - t * (joint.radius_m * joint.speed_radps);
            let s = Vector2::new(slip.dot(&e1), slip.dot(&e2));
            let v_along = v_q.dot(&t);
            let sigma = probe.relaxation_m(v_along);
            let lambda = v_along.abs() / sigma;
            let x = lambda * dt;
            // Exact over the step: ξ(dt) = ξ·e^{−λdt} + s·(1 − e^{−λdt})/λ.
            let decay = (-x).exp();
            let gain = if x > 1e-9 { (1.0 - decay) / lambda } else { dt };
            let old = st.shear_m;
            let mut shear = old * decay + s * gain;
            let rate = (shear - old) / dt;
            let mu = [
                probe.mu[0] * soil.friction_scale,
                probe.mu[1] * soil.friction_scale,
            ];
            let mut f = Vector2::zeros();
            let mut ellipse = 0.0;
            for i in 0..2 {
                if mu[i] <= 0.0 {
                    shear[i] = 0.0;
                    continue;
                }
                let limit = mu[i] * f_n;
                f[i] =
                    -limit * (shear[i] + soil.shear_damping_s * rate[i]) / soil.shear_deformation_m;
                ellipse += (f[i] / limit).powi(2);
            }
            if ellipse > 1.0 {
                // Sliding: the force on the ellipse, the shear at the matching deflection.
                let scale = 1.0 / ellipse.sqrt();
                f *= scale;
                for i in 0..2 {
                    if mu[i] > 0.0 {
                        shear[i] = -f[i] * soil.shear_deformation_m / (mu[i] * f_n);
                    }
                }
            }
            st.shear_m = shear;
            // Soil compaction: a force against the motion over the ground.
            let v_ground = v_q - n * n.dot(&v_q);
            let speed = v_ground.norm();
            let rolling = if speed > 0.0 {
                v_ground
                    * (-soil.rolling_resistance * f_n * (speed / ROLLING_SPEED_EPS_MPS).tanh()
                        / speed)
            } else {
                Vector3::zeros()
            };
            let force = n * f_n + e1 * f[0] + e2 * f[1] + rolling;
            out.force_in_world += force;
            out.torque_about_com_in_world += (q - com_in_world).cross(&force);
            if let Some(tau) = out.joint_torque_nm.get_mut(probe.joint) {
                // The shear force along the rolling direction loads the drive.
                *tau -= joint.radius_m * (e1 * f[0] + e2 * f[1]).dot(&t);
            }
        }
        out
    }
}

/// A drive joint's motor: a speed servo with a torque limit, and the joint's inertia and
/// friction.
#[derive(Clone, Debug, PartialEq)]
pub struct Motor {
    /// Drive-train inertia about the axle, kg·m².
    pub inertia_kgm2: f64,
    /// Torque limit, N·m.
    pub max_torque_nm: f64,
    /// Viscous friction, N·m·s/rad.
    pub damping_nms: f64,
    /// Coulomb friction, N·m.
    pub friction_nm: f64,
    /// Proportional gain, N·m·s/rad.
    pub kp: f64,
    /// Integral gain, N·m/rad.
    pub ki: f64,
    /// Integral of the speed error, rad.
    pub integral_rad: f64,
    /// Joint angle, rad.
    pub angle_rad: f64,
    /// Joint speed, rad/s.
    pub speed_radps: f64,
    /// Motor torque of the last step, N·m.
    pub torque_nm: f64,
}

impl Motor {
    /// A motor at rest with servo gains for a bandwidth `bandwidth_hz` on a load inertia
    /// `load_inertia_kgm2` (the drive train plus its share of the robot's mass).
    pub fn new(
        inertia_kgm2: f64,
        max_torque_nm: f64,
        damping_nms: f64,
        friction_nm: f64,
        load_inertia_kgm2: f64,
        bandwidth_hz: f64,
    ) -> Motor {
        let w = std::f64::consts::TAU * bandwidth_hz;
        let kp = load_inertia_kgm2 * w;
        Motor {
            inertia_kgm2,
            max_torque_nm,
            damping_nms,
            friction_nm,
            kp,
            ki: kp * w / 4.0,
            integral_rad: 0.0,
            angle_rad: 0.0,
            speed_radps: 0.0,
            torque_nm: 0.0,
        }
    }

    /// The servo of drive joint `j` carrying `share_kg` of the robot's mass at its rolling
    /// radius, with a bandwidth of `bandwidth_hz`.
    pub fn for_joint(j: &DriveJoint, share_kg: f64, bandwidth_hz: f64) -> Motor {
        Motor::new(
            j.inertia_kgm2,
            j.max_torque_nm,
            j.damping_nms,
            j.friction_nm,
            j.inertia_kgm2 + share_kg * j.radius_m * j.radius_m,
            bandwidth_hz,
        )
    }

    /// One step of `dt` towards `speed_ref_radps` with the ground's torque
    /// `load_torque_nm` on the joint.
    pub fn step(&mut self, speed_ref_radps: f64, load_torque_nm: f64, dt: f64) {
        let error = speed_ref_radps - self.speed_radps;
        let unclamped = self.kp * error + self.ki * (self.integral_rad + error * dt);
        let torque = unclamped.clamp(-self.max_torque_nm, self.max_torque_nm);
        // Anti-windup: integrate only while the torque is not limited, or when the error
        // pulls it back from the limit.
        if torque == unclamped || error.signum() != unclamped.signum() {
            self.integral_rad += error * dt;
        }
        self.torque_nm = torque;
        let friction = self.damping_nms * self.speed_radps
            + self.friction_nm * (self.speed_radps / JOINT_SPEED_EPS_RADPS).tanh();
        let accel = (torque + load_torque_nm - friction) / self.inertia_kgm2;
        self.speed_radps += accel * dt;
        self.angle_rad += self.speed_radps * dt;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::PlaneSurface;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    fn soil() -> SoilParams {
        SoilParams {
            friction_scale: 1.0,
            shear_deformation_m: 0.025,
            shear_damping_s: 0.0,
            rolling_resistance: 0.0,
            ripple_m: 0.0,
        }
    }

    fn wheel_probe(mu: [f64; 2], fdir: Vector3<f64>) -> GroundProbe {
        GroundProbe {
            joint: 0,
            centre_in_body: Vector3::zeros(),
            radius_m: 0.1,
            stiffness_n_per_m: 10_000.0,
            damping_ns_per_m: 0.0,
            mu,
            fdir1_in_body: fdir,
            roll_in_body: Vector3::x(),
            along_m: 0.0,
            half_run_m: 0.05,
            ripple_wavelength_m: 0.0,
            ripple_phase_m: 0.0,
        }
    }

    fn flat() -> PlaneSurface {
        PlaneSurface {
            z0_m: 0.0,
            gradient: Vector2::zeros(),
        }
    }

    fn body_at(z: f64, v: Vector3<f64>) -> BodyState {
        BodyState {
            world_from_body: Isometry3::translation(0.0, 0.0, z),
            velocity_in_world: v,
            angular_velocity_in_world: Vector3::zeros(),
        }
    }

    /// One step of `m` for `body`, centre of mass at the body origin.
    fn step_at<S: Surface>(
        m: &mut ContactModel,
        ground: &S,
        body: &BodyState,
        joints: &[JointKinematics],
    ) -> ContactWrench {
        let com = body.world_from_body.translation.vector;
        m.step(ground, body, &com, joints, 1e-3)
    }

    #[test]
    fn normal_force_is_the_spring_on_flat_and_sloped_ground() {
        let mut m = ContactModel::new(vec![wheel_probe([0.8, 0.8], Vector3::x())], soil());
        // 5 mm into flat ground: 50 N straight up.
        let w = step_at(
            &mut m,
            &flat(),
            &body_at(0.095, Vector3::zeros()),
            &[JointKinematics::default()],
        );
        assert!((w.force_in_world - Vector3::new(0.0, 0.0, 50.0)).norm() < 1e-9);
        // On a 10° slope the force is along the surface normal, and the penetration is
        // measured along it: a centre `r − 5 mm` from the plane gives 50 N.
        let slope = 10f64.to_radians();
        let ground = PlaneSurface {
            z0_m: 0.0,
            gradient: Vector2::new(slope.tan(), 0.0),
        };
        let n = Vector3::new(-slope.sin(), 0.0, slope.cos());
        let c = n * 0.095;
        let mut m = ContactModel::new(vec![wheel_probe([0.8, 0.8], Vector3::x())], soil());
        let body = BodyState {
            world_from_body: Isometry3::from_parts(
                Translation3::from(c),
                UnitQuaternion::identity(),
            ),
            velocity_in_world: Vector3::zeros(),
            angular_velocity_in_world: Vector3::zeros(),
        };
        let w = step_at(&mut m, &ground, &body, &[JointKinematics::default()]);
        assert!(
            (w.force_in_world - n * 50.0).norm() < 1e-9,
            "{:?}",
            w.force_in_world
        );
    }

    #[test]
    fn shear_is_elastic_at_rest_and_saturates_at_the_friction_limit() {
        // The body slides along x at 1 mm/s with the wheel locked: the shear grows by
        // 1 µm per 1 ms step, so after n steps F = −μF_n·ξ/K, until it reaches μF_n.
        let mut m = ContactModel::new(vec![wheel_probe([0.8, 0.5], Vector3::x())], soil());
        let body = body_at(0.095, Vector3::new(1e-3, 0.0, 0.0));
        let joints = [JointKinematics {
            radius_m: 0.1,
            ..Default::default()
        }];
        // λ = |v|/σ = 0.02/s: relaxation over 100 steps shrinks ξ by 0.2 %.
        let mut f = 0.0;
        for _ in 0..100 {
            f = step_at(&mut m, &flat(), &body, &joints).force_in_world.x;
        }
        let sigma: f64 = 0.05;
        let lambda = 1e-3 / sigma;
        let xi = 1e-3 / lambda * (1.0 - (-lambda * 0.1).exp());
        let expected = -0.8 * 50.0 * xi / 0.025;
        assert!((f - expected).abs() < 1e-9, "{f} vs {expected}");
        // Sliding fast: the force saturates at μ₁F_n = 40 N.
        let fast = body_at(0.095, Vector3::new(0.5, 0.0, 0.0));
        for _ in 0..200 {
            f = step_at(&mut m, &flat(), &fast, &joints).force_in_world.x;
        }
        assert!((f + 40.0).abs() < 1e-9, "{f}");
        // Sideways, μ₂F_n = 25 N; diagonally, on the ellipse.
        let side = body_at(0.095, Vector3::new(0.0, -0.5, 0.0));
        let mut fy = 0.0;
        for _ in 0..1000 {
            fy = step_at(&mut m, &flat(), &side, &joints).force_in_world.y;
        }
        assert!((fy - 25.0).abs() < 1e-9, "{fy}");
        let diag = body_at(0.095, Vector3::new(0.5, 0.5, 0.0));
        let mut w = ContactWrench::default();
        for _ in 0..400 {
            w = step_at(&mut m, &flat(), &diag, &joints);
        }
        let e = (w.force_in_world.x / 40.0).powi(2) + (w.force_in_world.y / 25.0).powi(2);
        assert!((e - 1.0).abs() < 1e-9, "ellipse {e}");
    }

    #[test]
    fn steady_slip_gives_the_brush_model_traction() {
        // A wheel driven at R·ω = v·(1 + i) over ground at v: steady shear ξ = s·σ/v, so
        // F = μF_n·σ·i/K (i small), while the joint sees −R·F.
        let (v, i) = (1.0, 0.002);
        let probe = wheel_probe([0.8, 0.8], Vector3::x());
        let mut m = ContactModel::new(vec![probe], soil());
        let body = body_at(0.095, Vector3::new(v, 0.0, 0.0));
        let joints = [JointKinematics {
            angle_rad: 0.0,
            speed_radps: v * (1.0 + i) / 0.1,
            radius_m: 0.1,
        }];
        let mut w = ContactWrench::default();
        for _ in 0..2000 {
            w = step_at(&mut m, &flat(), &body, &joints);
        }
        let expected = 0.8 * 50.0 * 0.05 * i / 0.025;
        assert!((w.force_in_world.x - expected).abs() < 1e-6 * expected.abs().max(1.0));
        assert!((w.joint_torque_nm[0] + 0.1 * expected).abs() < 1e-6);
    }

    #[test]
    fn free_rollers_push_only_along_their_axis() {
        // μ₂ = 0: a roller axis at 45° with the body sliding across it (along e₂) feels no
        // force; sliding along the axis it does.
        let u = Vector3::new(1.0, -1.0, 0.0).normalize();
        let mut m = ContactModel::new(vec![wheel_probe([0.9, 0.0], u)], soil());
        let joints = [JointKinematics {
            radius_m: 0.1,
            ..Default::default()
        }];
        let across = Vector3::new(1.0, 1.0, 0.0).normalize() * 0.3;
        for _ in 0..100 {
            let w = step_at(&mut m, &flat(), &body_at(0.095, across), &joints);
            assert!(w.force_in_world.xy().norm() < 1e-12);
        }
        let mut w = ContactWrench::default();
        for _ in 0..500 {
            w = step_at(&mut m, &flat(), &body_at(0.095, u * 0.3), &joints);
        }
        let f = w.force_in_world.xy();
        assert!((f.normalize() + u.xy()).norm() < 1e-9 && (f.norm() - 45.0).abs() < 1e-9);
    }

    #[test]
    fn motor_tracks_its_reference_and_saturates() {
        // Free joint (no load): reaches the reference with the PI's zero steady error.
        let mut m = Motor::new(0.01, 2.0, 0.0, 0.0, 0.01, 8.0);
        for _ in 0..3000 {
            m.step(10.0, 0.0, 1e-3);
        }
        assert!((m.speed_radps - 10.0).abs() < 1e-6, "{}", m.speed_radps);
        // A load above the torque limit stalls it: it decelerates at (τ_max − load)/I.
        let mut m = Motor::new(0.01, 2.0, 0.0, 0.0, 0.01, 8.0);
        for _ in 0..100 {
            m.step(10.0, -3.0, 1e-3);
        }
        assert_eq!(m.torque_nm, 2.0);
        assert!(
            (m.speed_radps - (-1.0 / 0.01 * 0.1)).abs() < 1e-9,
            "{}",
            m.speed_radps
        );
    }
}
