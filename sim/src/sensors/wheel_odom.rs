//! Wheel and track odometry (`[sensors.wheel_odom]`): encoder speeds integrated with the
//! drive's nominal kinematics ([`DriveKinematics`]), skid-steer or mecanum.
//!
//! Each epoch (`ctx.start + i/rate_hz`) reads every drive joint's speed from the truth
//! ([`TruthSample::drive_speeds_radps`], what the motors turn) and adds white noise of
//! σ = `speed_sigma_mps` to each joint's *surface* speed `r·w` (one standard normal per
//! joint, drawn in joint order: tracked left, right; mecanum front-left, front-right,
//! rear-left, rear-right). The measured speeds give the body twist `(v_x, v_y, ω)`:
//! - **skid-steer** (tracks, surface speeds `v_l`, `v_r`, URDF track width `W`):
//!   `v_x = (v_l + v_r)/2`, `v_y = 0`, `ω = (v_r − v_l)/W`. The nominal model has no ICR
//!   expansion and no slip, so, like a real skid-steer odometry, it over-estimates
//!   distance (by `1/(1 − slip)`) and turns (by the ICR factor);
//! - **mecanum** (X configuration, wheel radius `r`, half wheelbase `l_x`, half separation
//!   `l_y`, `L = l_x + l_y`): the least-squares forward kinematics
//!   [`DriveKinematics::body_twist`], which in surface speeds `u_i = r·w_i` is
//!   `(v_x, v_y, ω) = J·u` with
//!   `J = ¼·[[1, 1, 1, 1], [−1, 1, 1, −1], [−1/L, 1/L, −1/L, 1/L]]` (exact inverse of
//!   [`DriveKinematics::joint_speeds`] on its range). Roller slip is not modelled.
//!
//! The planar pose `(x, y, θ)` in frame `wheel_odom` (child `base_link`) starts at zero
//! at the first sample and is integrated with the midpoint rule between consecutive
//! samples: with `v̄_x`, `v̄_y`, `ω̄` the means of the two samples, the body-frame
//! increments are `Δx_b = v̄_x·dt`, `Δy_b = v̄_y·dt`, `Δθ = ω̄·dt`, and with
//! `θ_m = θ + Δθ/2`:
//! `x += Δx_b·cos θ_m − Δy_b·sin θ_m`, `y += Δx_b·sin θ_m + Δy_b·cos θ_m`, `θ += Δθ`.
//! (A skid-steer has `Δy_b = 0`: `x += Δs·cos θ_m`, `y += Δs·sin θ_m`.) For a constant
//! twist this follows the true arc's chords exactly in direction and is longer by the
//! factor `(h/2)/sin(h/2) ≈ 1 + h²/24` with `h = ω·dt`.
//!
//! The message reports `linear_velocity = (v_x, v_y, 0)`, `angular_velocity = (0, 0, ω)`.
//!
//! Covariances (documented choices; the estimator does not fuse this source). `z`, roll,
//! pitch and `v_z`, `ω_x`, `ω_y` are not measured by a planar odometry:
//! [`UNMEASURED_VARIANCE`], as ROS `diff_drive_controller` configurations do.
//!
//! *Skid-steer*:
//! - twist: `var(v_x) = σ²/2 + (SLIP·v_x)²`, `var(ω) = 2σ²/W² + (ICR·ω)²` — the encoder
//!   noise propagated exactly, plus the model's unknown slip ([`SLIP_SPEED_FRACTION`]) and
//!   ICR error ([`ICR_RATE_FRACTION`]) as relative 1σ terms; lateral velocity
//!   [`LATERAL_SKID_SIGMA_MPS`]² (the non-holonomic constraint is not exact on a
//!   skid-steer);
//! - pose: `(x, y, θ)` covariance propagated step by step with the midpoint model's
//!   Jacobians, from per-step variances `var(Δs) = (σ²/4)·dt² + SLIP_RW²·|Δs|` and
//!   `var(Δθ) = (σ²/W²)·dt² + ICR_RW²·|Δθ|` (encoder noise of the two-sample means, plus
//!   random walks [`SLIP_RANDOM_WALK_M_PER_RTM`] per √metre and
//!   [`ICR_RANDOM_WALK_RAD_PER_RTRAD`] per √radian turned for the unmodelled slip and
//!   skid).
//!
//! *Mecanum*:
//! - twist: the encoder noise propagated exactly through the forward kinematics,
//!   `σ²·J·Jᵀ`. The rows of `J` are orthogonal (`(1,1,1,1)`, `(−1,1,1,−1)` and
//!   `(−1,1,−1,1)` have pairwise dot products 0) with squared norms `4/16`, `4/16` and
//!   `4/(16L²)`, so `σ²·J·Jᵀ = diag(σ²/4, σ²/4, σ²/(4L²))`: no cross terms. Added: the
//!   unknown roller slip as relative 1σ terms [`MECANUM_SLIP_FRACTION`] on `v_x` and on
//!   `v_y` and [`MECANUM_RATE_FRACTION`] on `ω`:
//!   `var(v_x) = σ²/4 + (SLIP_M·v_x)²`, `var(v_y) = σ²/4 + (SLIP_M·v_y)²`,
//!   `var(ω) = σ²/(4L²) + (RATE_M·ω)²`;
//! - pose: propagated like the skid-steer's, `P ← F·P·Fᵀ + G·Q·Gᵀ`, with the Jacobians of
//!   the midpoint step w.r.t. the state, `F = [[1, 0, −Δy_w], [0, 1, Δx_w], [0, 0, 1]]`
//!   (`(Δx_w, Δy_w)` the world-frame increment), and w.r.t. `(Δx_b, Δy_b, Δθ)`,
//!   `G = [[cos θ_m, −sin θ_m, −Δy_w/2], [sin θ_m, cos θ_m, Δx_w/2], [0, 0, 1]]`, and
//!   `Q = diag(var(Δx_b), var(Δy_b), var(Δθ))` with
//!   `var(Δx_b) = (σ²/4)·dt² + SLIP_RW_M²·|Δx_b|`,
//!   `var(Δy_b) = (σ²/4)·dt² + SLIP_RW_M²·|Δy_b|`,
//!   `var(Δθ) = (σ²/(4L²))·dt² + YAW_RW_M²·|Δθ|`. The encoder terms are the single-sample
//!   twist variances times `dt²`: consecutive midpoint increments share a sample, and over
//!   `n` steps the integrated noise `dt·(v_0/2 + v_1 + … + v_{n−1} + v_n/2)` has variance
//!   `(n − ½)·var(v)·dt²`, which the step-wise sum `n·var(v)·dt²` matches (the variance
//!   of one two-sample mean, `var(v)/2·dt²`, would give half of it). The random walks
//!   [`MECANUM_SLIP_RANDOM_WALK_M_PER_RTM`] (per √metre travelled along each body axis)
//!   and [`MECANUM_YAW_RANDOM_WALK_RAD_PER_RTRAD`] (per √radian turned) model the
//!   unmodelled roller slip.

use super::noise::standard_normal;
use super::{EpochClock, SensorContext, SensorModel, latency_from_ms, require_rate};
use crate::params::{ParamError, WheelOdomParams, require_non_negative};
use crate::rng;
use crate::robot::{DriveKinematics, MAX_DRIVE_JOINTS};
use crate::truth::TruthSample;
use nalgebra::{Isometry3, Matrix2, Matrix2x3, Matrix3, Matrix3x2, Matrix6, Vector3, Vector6};
use rand_chacha::ChaCha8Rng;
use vinebench_msgs::frames::names::BASE_LINK;
use vinebench_msgs::{FrameId, Message, Nanos, OdometryMsg, TimedMessage};

/// The odometry frame of the wheel odometry (the robot's pose at the first sample).
pub const WHEEL_ODOM_FRAME: &str = "wheel_odom";
/// Variance reported for components a planar odometry does not measure.
pub const UNMEASURED_VARIANCE: f64 = 1e6;
/// Unknown longitudinal slip as a fraction of speed (1σ), for the skid-steer twist
/// covariance.
pub const SLIP_SPEED_FRACTION: f64 = 0.03;
/// Unknown ICR expansion as a fraction of yaw rate (1σ), for the skid-steer twist
/// covariance.
pub const ICR_RATE_FRACTION: f64 = 0.3;
/// Lateral skid velocity of a skid-steer (1σ), m/s.
pub const LATERAL_SKID_SIGMA_MPS: f64 = 0.05;
/// Along-track random walk for a skid-steer's unmodelled slip, m/√m.
pub const SLIP_RANDOM_WALK_M_PER_RTM: f64 = 0.05;
/// Heading random walk for a skid-steer's unmodelled skid, per √radian turned (rad/√rad).
pub const ICR_RANDOM_WALK_RAD_PER_RTRAD: f64 = 0.3;
/// Unknown mecanum roller slip as a fraction of `v_x` and of `v_y` (1σ each), for the
/// twist covariance. Larger than a track's [`SLIP_SPEED_FRACTION`]: a mecanum wheel
/// drives through free rollers at 45°, whose slip (and, sideways, the roller-to-roller
/// bumps of the contact) commonly costs mecanum odometry several per cent of distance.
pub const MECANUM_SLIP_FRACTION: f64 = 0.05;
/// Unknown mecanum yaw-rate error as a fraction of yaw rate (1σ), for the twist
/// covariance. A mecanum drive has no ICR expansion; its yaw error comes from the
/// effective lever `l_x + l_y`, which moves with the contact point across the wheel's
/// width (±0.025 m of 0.42 m on the built-in rover, ≈ 6 %), and from roller slip.
pub const MECANUM_RATE_FRACTION: f64 = 0.1;
/// Random walk for a mecanum drive's unmodelled roller slip, per √metre travelled along
/// each body axis (m/√m): [`MECANUM_SLIP_FRACTION`]·√(2.8 m), the correlation length
/// implied by the skid-steer pair ([`SLIP_RANDOM_WALK_M_PER_RTM`] =
/// [`SLIP_SPEED_FRACTION`]·√(2.8 m)), rounded.
pub const MECANUM_SLIP_RANDOM_WALK_M_PER_RTM: f64 = 0.08;
/// Heading random walk for a mecanum drive's unmodelled slip, per √radian turned
/// (rad/√rad): [`MECANUM_RATE_FRACTION`]·√(1 rad), the correlation angle implied by the
/// skid-steer pair ([`ICR_RANDOM_WALK_RAD_PER_RTRAD`] = [`ICR_RATE_FRACTION`]·√(1 rad)).
pub const MECANUM_YAW_RANDOM_WALK_RAD_PER_RTRAD: f64 = 0.1;

/// The simulated wheel or track odometry. Random stream `sensors.wheel_odom`.
#[derive(Clone, Debug)]
pub struct WheelOdom {
    frame_id: FrameId,
    child_frame_id: FrameId,
    clock: EpochClock,
    latency: Nanos,
    rng: ChaCha8Rng,
    speed_sigma: f64,
    encoders: Encoders,
    state: Option<Planar>,
}

/// How the measured joint speeds become a body twist.
#[derive(Clone, Debug)]
enum Encoders {
    /// Two tracks.
    SkidSteer {
        /// Track width `W`, m.
        track_width: f64,
        /// Sprocket pitch radii (left, right), m.
        radii: [f64; 2],
    },
    /// Four mecanum wheels.
    Mecanum {
        /// The nominal kinematics (its least-squares forward kinematics).
        kinematics: DriveKinematics,
        /// Wheel radius `r`, m.
        radius: f64,
        /// `L = l_x + l_y`, m.
        lever: f64,
    },
}

/// The integration state after the first sample.
#[derive(Clone, Debug)]
struct Planar {
    stamp: Nanos,
    /// Measured body twist of the last sample: forward, left (m/s), yaw rate (rad/s).
    vx: f64,
    vy: f64,
    omega: f64,
    x: f64,
    y: f64,
    /// Unwrapped heading, rad.
    theta: f64,
    /// Covariance of (x, y, θ).
    cov: Matrix3<f64>,
}

impl WheelOdom {
    /// Checks `[sensors.wheel_odom]` and builds the sensor; the drive kinematics come from
    /// `ctx.geometry` (a skid-steer uses its track width `track_width_m`).
    pub fn new(p: &WheelOdomParams, ctx: &SensorContext) -> Result<WheelOdom, ParamError> {
        let path = |k: &str| format!("sensors.wheel_odom.{k}");
        let rate_hz = require_rate(&path("rate_hz"), p.rate_hz)?;
        let latency = latency_from_ms(&path("latency_ms"), p.latency_ms, rate_hz)?;
        let speed_sigma = require_non_negative(&path("speed_sigma_mps"), p.speed_sigma_mps)?;
        let positive = |x: f64| x.is_finite() && x > 0.0;
        let encoders = match ctx.geometry.kinematics {
            DriveKinematics::SkidSteer {
                left_radius_m,
                right_radius_m,
                ..
            } => {
                let w = ctx.geometry.track_width_m;
                if !positive(w) {
                    return Err(ParamError::new(
                        "robot",
                        "a URDF with a track width > 0 m",
                        w,
                    ));
                }
                Encoders::SkidSteer {
                    track_width: w,
                    radii: [left_radius_m, right_radius_m],
                }
            }
            DriveKinematics::Mecanum {
                half_wheelbase_m,
                half_separation_m,
                wheel_radius_m,
            } => {
                let lever = half_wheelbase_m + half_separation_m;
                if !(positive(lever) && positive(wheel_radius_m)) {
                    return Err(ParamError::new(
                        "robot",
                        "a mecanum URDF with a wheel radius > 0 m and wheels off the centre \
                         (l_x + l_y > 0 m)",
                        format!("r = {wheel_radius_m} m, l_x + l_y = {lever} m"),
                    ));
                }
                Encoders::Mecanum {
                    kinematics: ctx.geometry.kinematics.clone(),
                    radius: wheel_radius_m,
                    lever,
                }
            }
        };
        Ok(WheelOdom {
            frame_id: FrameId::new(WHEEL_ODOM_FRAME),
            child_frame_id: FrameId::new(BASE_LINK),
            clock: EpochClock::new(ctx.start, rate_hz),
            latency,
            rng: rng::stream(ctx.master_seed, "sensors.wheel_odom"),
            speed_sigma,
            encoders,
            state: None,
        })
    }

    /// The unwrapped heading integrated so far, rad (0 before the first sample).
    pub fn heading_rad(&self) -> f64 {
        self.state.as_ref().map_or(0.0, |s| s.theta)
    }

    /// The measured body twist `(v_x, v_y, ω)` of one sample; draws one standard normal
    /// per drive joint, in joint order.
    fn measure(&mut self, truth: &TruthSample) -> (f64, f64, f64) {
        let sigma = self.speed_sigma;
        match &self.encoders {
            Encoders::SkidSteer { track_width, radii } => {
                // Draw order per epoch (fixed): left, right.
                let v_l =
                    truth.drive_speeds_radps[0] * radii[0] + sigma * standard_normal(&mut self.rng);
                let v_r =
                    truth.drive_speeds_radps[1] * radii[1] + sigma * standard_normal(&mut self.rng);
                (0.5 * (v_l + v_r), 0.0, (v_r - v_l) / track_width)
            }
            Encoders::Mecanum {
                kinematics, radius, ..
            } => {
                // Draw order per epoch (fixed): front-left, front-right, rear-left,
                // rear-right. σ is on the surface speed r·w, so σ/r on the joint speed.
                let mut w = [0.0; MAX_DRIVE_JOINTS];
                let joints = kinematics.joint_count();
                for (wi, truth_w) in w.iter_mut().zip(truth.drive_speeds_radps).take(joints) {
                    *wi = truth_w + sigma / radius * standard_normal(&mut self.rng);
                }
                kinematics.body_twist(&w)
            }
        }
    }
}

impl SensorModel for WheelOdom {
    fn name(&self) -> &'static str {
        "wheel_odom"
    }

    fn next_time(&self) -> Nanos {
        self.clock.time()
    }

    fn sample(&mut self, truth: &TruthSample, out: &mut Vec<TimedMessage>) {
        let stamp = self.clock.time();
        debug_assert_eq!(truth.stamp, stamp, "the runner must sample at next_time()");
        let (vx, vy, omega) = self.measure(truth);
        let s2 = self.speed_sigma * self.speed_sigma;

        let state = match self.state.take() {
            None => Planar {
                stamp,
                vx,
                vy,
                omega,
                x: 0.0,
                y: 0.0,
                theta: 0.0,
                cov: Matrix3::zeros(),
            },
            Some(prev) => {
                let dt = (stamp - prev.stamp).as_secs_f64();
                let dxb = 0.5 * (prev.vx + vx) * dt;
                let dyb = 0.5 * (prev.vy + vy) * dt;
                let dth = 0.5 * (prev.omega + omega) * dt;
                let th_mid = prev.theta + 0.5 * dth;
                let (sn, cs) = th_mid.sin_cos();
                // World-frame increment and G·Q·Gᵀ. The skid-steer arm leaves the lateral
                // terms out (rather than multiplying zeros) so that tracked runs stay
                // bit-identical to the skid-steer-only model, signed zeros included.
                let (dxw, dyw, gqg) = match &self.encoders {
                    Encoders::SkidSteer { track_width, .. } => {
                        let w = *track_width;
                        let g = Matrix3x2::new(cs, -0.5 * dxb * sn, sn, 0.5 * dxb * cs, 0.0, 1.0);
                        let var_ds =
                            0.25 * s2 * dt * dt + SLIP_RANDOM_WALK_M_PER_RTM.powi(2) * dxb.abs();
                        let var_dth = s2 / (w * w) * dt * dt
                            + ICR_RANDOM_WALK_RAD_PER_RTRAD.powi(2) * dth.abs();
                        let q = Matrix2::new(var_ds, 0.0, 0.0, var_dth);
                        let gt: Matrix2x3<f64> = g.transpose();
                        (dxb * cs, dxb * sn, g * q * gt)
                    }
                    Encoders::Mecanum { lever, .. } => {
                        let (dxw, dyw) = (dxb * cs - dyb * sn, dxb * sn + dyb * cs);
                        let g = Matrix3::new(cs, -sn, -0.5 * dyw, sn, cs, 0.5 * dxw, 0.0, 0.0, 1.0);
                        let enc_xy = 0.25 * s2 * dt * dt;
                        let enc_th = 0.25 * s2 / (lever * lever) * dt * dt;
                        let rw_xy = MECANUM_SLIP_RANDOM_WALK_M_PER_RTM.powi(2);
                        let q = Matrix3::from_diagonal(&Vector3::new(
                            enc_xy + rw_xy * dxb.abs(),
                            enc_xy + rw_xy * dyb.abs(),
                            enc_th + MECANUM_YAW_RANDOM_WALK_RAD_PER_RTRAD.powi(2) * dth.abs(),
                        ));
                        (dxw, dyw, g * q * g.transpose())
                    }
                };
                let f = Matrix3::new(1.0, 0.0, -dyw, 0.0, 1.0, dxw, 0.0, 0.0, 1.0);
                let cov = f * prev.cov * f.transpose() + gqg;
                Planar {
                    stamp,
                    vx,
                    vy,
                    omega,
                    x: prev.x + dxw,
                    y: prev.y + dyw,
                    theta: prev.theta + dth,
                    cov: 0.5 * (cov + cov.transpose()),
                }
            }
        };

        let pose = Isometry3::new(
            Vector3::new(state.x, state.y, 0.0),
            Vector3::new(0.0, 0.0, state.theta),
        );
        let mut pose_covariance = Matrix6::from_diagonal(&Vector6::new(
            0.0,
            0.0,
            UNMEASURED_VARIANCE,
            UNMEASURED_VARIANCE,
            UNMEASURED_VARIANCE,
            0.0,
        ));
        for (i, pi) in [0usize, 1, 5].into_iter().enumerate() {
            for (j, pj) in [0usize, 1, 5].into_iter().enumerate() {
                pose_covariance[(pi, pj)] = state.cov[(i, j)];
            }
        }
        let (var_vx, var_vy, var_omega) = match &self.encoders {
            Encoders::SkidSteer { track_width, .. } => {
                let w = *track_width;
                (
                    0.5 * s2 + (SLIP_SPEED_FRACTION * vx).powi(2),
                    LATERAL_SKID_SIGMA_MPS.powi(2),
                    2.0 * s2 / (w * w) + (ICR_RATE_FRACTION * omega).powi(2),
                )
            }
            Encoders::Mecanum { lever, .. } => (
                0.25 * s2 + (MECANUM_SLIP_FRACTION * vx).powi(2),
                0.25 * s2 + (MECANUM_SLIP_FRACTION * vy).powi(2),
                0.25 * s2 / (lever * lever) + (MECANUM_RATE_FRACTION * omega).powi(2),
            ),
        };
        let twist_covariance = Matrix6::from_diagonal(&Vector6::new(
            var_vx,
            var_vy,
            UNMEASURED_VARIANCE,
            UNMEASURED_VARIANCE,
            UNMEASURED_VARIANCE,
            var_omega,
        ));
        out.push(TimedMessage {
            arrival: stamp + self.latency,
            msg: Message::WheelOdom(OdometryMsg {
                stamp,
                frame_id: self.frame_id.clone(),
                child_frame_id: self.child_frame_id.clone(),
                pose,
                pose_covariance,
                linear_velocity: Vector3::new(vx, vy, 0.0),
                angular_velocity: Vector3::new(0.0, 0.0, omega),
                twist_covariance,
            }),
        });
        self.state = Some(state);
        self.clock.advance();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensors::noise::stats::{mean, std};
    use crate::sensors::test_support::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn odoms(out: &[TimedMessage]) -> Vec<&OdometryMsg> {
        out.iter()
            .map(|m| match &m.msg {
                Message::WheelOdom(o) => o,
                other => panic!("unexpected {other:?}"),
            })
            .collect()
    }

    fn noise_free() -> WheelOdomParams {
        WheelOdomParams {
            speed_sigma_mps: 0.0,
            ..WheelOdomParams::default()
        }
    }

    #[test]
    fn straight_line_distance_is_overestimated_by_slip() {
        // Body speed 1 m/s with 2 % slip: the tracks turn at 1/0.98 m/s, so after 60 s
        // (60 m) the odometry reads 60/0.98 m straight ahead (whatever the world heading).
        let c = ctx(1);
        let mut o = WheelOdom::new(&noise_free(), &c).unwrap();
        let drive = Drive {
            icr: 1.3,
            slip: 0.02,
            width: 0.6,
        };
        let truth = |t| straight(t, 2.0, 1.0, drive);
        let out = run_n(&mut o, &truth, 3001);
        let msgs = odoms(&out);
        let last = msgs.last().unwrap();
        let true_distance = truth(last.stamp).odometer_m - truth(msgs[0].stamp).odometer_m;
        assert!((true_distance - 60.0).abs() < 1e-9);
        let p = last.pose.translation.vector;
        assert!((p.x - true_distance / 0.98).abs() < 1e-9, "{p:?}");
        assert!(p.y.abs() < 1e-12 && p.z == 0.0);
        assert!((last.linear_velocity.x - 1.0 / 0.98).abs() < 1e-12);
        assert_eq!(last.frame_id.as_str(), "wheel_odom");
        assert_eq!(last.child_frame_id.as_str(), "base_link");
        // Epochs every 20 ms from the start, arrival 2 ms later.
        for (i, m) in out.iter().enumerate() {
            assert_eq!(m.msg.stamp(), START + Nanos(20_000_000 * i as i64));
            assert_eq!(m.arrival, m.msg.stamp() + Nanos(2_000_000));
            m.msg.validate().unwrap();
        }
    }

    #[test]
    fn turns_are_overestimated_by_the_icr_factor() {
        // True yaw rate ω = v/R; the drive turns its tracks with v_r − v_l = icr·W·ω, and
        // the nominal model reads (v_r − v_l)/W = icr·ω. After T seconds the heading is
        // icr·ω·T, and the path is a circle of radius v/(icr·ω) = R/icr (the midpoint rule
        // follows a constant-curvature arc by chords, radius larger by a relative
        // (ω·dt)²/24 ≈ 1e-6).
        let c = ctx(1);
        let (radius, speed, icr) = (5.0, 1.0, 1.3);
        let drive = Drive {
            icr,
            slip: 0.0,
            width: c.geometry.track_width_m,
        };
        let mut o = WheelOdom::new(&noise_free(), &c).unwrap();
        let truth = |t| circle(t, radius, speed, drive);
        let n = 2001;
        let out = run_n(&mut o, &truth, n);
        let t = (n - 1) as f64 / 50.0;
        let omega = speed / radius;
        assert!(
            (o.heading_rad() - icr * omega * t).abs() < 1e-9,
            "{}",
            o.heading_rad()
        );
        let r_odom = radius / icr;
        for m in odoms(&out) {
            let p = m.pose.translation.vector;
            let from_centre = (p - Vector3::new(0.0, r_odom, 0.0)).norm();
            assert!(
                (from_centre - r_odom).abs() < 1e-5 * r_odom,
                "{from_centre}"
            );
            assert!((m.angular_velocity.z - icr * omega).abs() < 1e-12);
        }
        // The reported yaw matches the integrated heading (mod 2π).
        let last = odoms(&out).last().unwrap().pose.rotation;
        let d = last.euler_angles().2 - o.heading_rad();
        assert!((d - (d / std::f64::consts::TAU).round() * std::f64::consts::TAU).abs() < 1e-9);
    }

    #[test]
    fn encoder_noise_gives_reported_twist_variance_at_rest() {
        // At rest: v = (n_l + n_r)/2 has variance σ²/2, ω = (n_r − n_l)/W has 2σ²/W²,
        // exactly what is reported (no slip or ICR terms at zero speed). 20 000 samples:
        // sample std relative error 0.5 %; tolerance 3 %.
        let c = ctx(6);
        let p = WheelOdomParams::default();
        let mut o = WheelOdom::new(&p, &c).unwrap();
        let out = run_n(&mut o, &|t| stationary(t, Isometry3::identity()), 20_000);
        let msgs = odoms(&out);
        let v: Vec<f64> = msgs.iter().map(|m| m.linear_velocity.x).collect();
        let w: Vec<f64> = msgs.iter().map(|m| m.angular_velocity.z).collect();
        let s = p.speed_sigma_mps;
        let width = c.geometry.track_width_m;
        assert!((std(&v) / (s / 2f64.sqrt()) - 1.0).abs() < 0.03);
        assert!((std(&w) / (s * 2f64.sqrt() / width) - 1.0).abs() < 0.03);
        assert!(mean(&v).abs() < 5.0 * s / 200.0);
        // Reported twist variance: the at-rest formula (the relative terms vanish only at
        // exact zero, so compare with the formula including them).
        for m in msgs.iter().take(100) {
            let vv = m.linear_velocity.x;
            let ww = m.angular_velocity.z;
            assert!(
                (m.twist_covariance[(0, 0)] - (s * s / 2.0 + (0.03 * vv).powi(2))).abs() < 1e-15
            );
            assert!(
                (m.twist_covariance[(5, 5)] - (2.0 * s * s / (width * width) + (0.3 * ww).powi(2)))
                    .abs()
                    < 1e-15
            );
        }
        // The pose covariance grows (random walk of the integrated noise) and stays a
        // covariance.
        let last = msgs.last().unwrap();
        assert!(last.pose_covariance[(0, 0)] > msgs[1].pose_covariance[(0, 0)]);
        Message::WheelOdom((*last).clone()).validate().unwrap();
    }

    #[test]
    fn pose_covariance_grows_with_distance_and_turn() {
        // Noise-free encoders: the only covariance is the documented slip/skid random
        // walk. On a straight line the along-track variance is SLIP_RW²·d (closed form of
        // the propagation with θ = 0), the heading variance stays 0.
        let c = ctx(1);
        let mut o = WheelOdom::new(&noise_free(), &c).unwrap();
        let out = run_n(&mut o, &|t| straight(t, 0.0, 1.0, Drive::IDEAL), 1001);
        let last = (*odoms(&out).last().unwrap()).clone();
        assert!(
            (last.pose_covariance[(0, 0)] - SLIP_RANDOM_WALK_M_PER_RTM.powi(2) * 20.0).abs() < 1e-9
        );
        assert!(last.pose_covariance[(5, 5)].abs() < 1e-15);
        // Turning in place through θ: heading variance ICR_RW²·θ.
        let mut o = WheelOdom::new(&noise_free(), &c).unwrap();
        let spin = |t: Nanos| {
            let mut tr = stationary(t, Isometry3::identity());
            tr.drive_speeds_radps[0] = -0.3 / SPROCKET_M;
            tr.drive_speeds_radps[1] = 0.3 / SPROCKET_M;
            tr
        };
        let out = run_n(&mut o, &spin, 501);
        let turned = 0.6 / c.geometry.track_width_m * 10.0;
        let last = (*odoms(&out).last().unwrap()).clone();
        assert!((o.heading_rad() - turned).abs() < 1e-9);
        assert!(
            (last.pose_covariance[(5, 5)] - ICR_RANDOM_WALK_RAD_PER_RTRAD.powi(2) * turned).abs()
                < 1e-9
        );
    }

    /// The mecanum rover's context, its nominal kinematics and `L = l_x + l_y`.
    fn rover(seed: u64) -> (SensorContext, DriveKinematics, f64) {
        let c = ctx_for("mecanum-rover", seed);
        let kin = c.geometry.kinematics.clone();
        let DriveKinematics::Mecanum {
            half_wheelbase_m,
            half_separation_m,
            ..
        } = kin
        else {
            panic!("the rover is a mecanum robot: {kin:?}")
        };
        (c, kin, half_wheelbase_m + half_separation_m)
    }

    /// Pose `(x, y, θ)` at `t` s of a level robot starting at the origin heading east
    /// with the constant body twist `(vx, vy, wz)`: `θ = wz·t`; for `wz ≠ 0`
    /// `p = [sin θ, −(1 − cos θ); 1 − cos θ, sin θ]·(vx, vy)/wz`, else `(vx, vy)·t`.
    fn twist_pose(t: f64, (vx, vy, wz): (f64, f64, f64)) -> (f64, f64, f64) {
        if wz == 0.0 {
            return (vx * t, vy * t, 0.0);
        }
        let th = wz * t;
        let (sn, cs) = th.sin_cos();
        (
            (sn * vx - (1.0 - cs) * vy) / wz,
            ((1.0 - cs) * vx + sn * vy) / wz,
            th,
        )
    }

    /// Truth for [`twist_pose`]: velocity `R(θ)·(vx, vy)`, acceleration
    /// `wz·R(θ)·(−vy, vx)`, wheels turning at the nominal kinematics' speeds.
    fn body_twist_truth(t: Nanos, kin: &DriveKinematics, twist: (f64, f64, f64)) -> TruthSample {
        let (vx, vy, wz) = twist;
        let s = secs(t);
        let (x, y, th) = twist_pose(s, twist);
        let rot = UnitQuaternion::from_euler_angles(0.0, 0.0, th);
        TruthSample {
            stamp: t,
            world_from_body: Isometry3::from_parts(Translation3::new(x, y, 0.0), rot),
            velocity_in_world: rot * Vector3::new(vx, vy, 0.0),
            acceleration_in_world: rot * Vector3::new(-wz * vy, wz * vx, 0.0),
            angular_velocity_in_body: Vector3::new(0.0, 0.0, wz),
            angular_acceleration_in_body: Vector3::zeros(),
            drive_speeds_radps: kin.joint_speeds(vx, vy, wz),
            odometer_m: vx.hypot(vy) * s,
        }
    }

    /// `a − b` wrapped to (−π, π].
    fn angle_diff(a: f64, b: f64) -> f64 {
        let d = a - b;
        d - (d / std::f64::consts::TAU).round() * std::f64::consts::TAU
    }

    #[test]
    fn tracked_messages_are_pinned_to_the_skid_steer_model() {
        // Regression: a noisy tracked run gives, bit for bit, the values the skid-steer-only
        // model produced before the mecanum generalisation (captured from it; they also
        // pin the random stream, so a rand/rand_distr upgrade changes them).
        let drive = Drive {
            icr: 1.3,
            slip: 0.02,
            width: 0.6,
        };
        let mut o = WheelOdom::new(&WheelOdomParams::default(), &ctx(42)).unwrap();
        let out = run_n(&mut o, &|t| circle(t, 8.0, 1.0, drive), 500);
        let m = odoms(&out)[499];
        let p = m.pose.translation.vector;
        let got = [
            p.x,
            p.y,
            o.heading_rad(),
            m.linear_velocity.x,
            m.linear_velocity.y,
            m.angular_velocity.z,
            m.pose_covariance[(0, 0)],
            m.pose_covariance[(0, 1)],
            m.pose_covariance[(1, 1)],
            m.pose_covariance[(0, 5)],
            m.pose_covariance[(1, 5)],
            m.pose_covariance[(5, 5)],
            m.twist_covariance[(0, 0)],
            m.twist_covariance[(1, 1)],
            m.twist_covariance[(5, 5)],
        ];
        let pinned: [f64; 15] = [
            6.093832788776056,
            6.72240927485202,
            1.6485768700810908,
            1.0187751318746758,
            0.0,
            0.17259541853515137,
            3.3722281926174595,
            -1.8777219609735205,
            1.222252876609629,
            -0.6350996841602604,
            0.3158861644869565,
            0.14842736275174237,
            0.0009841124923936366,
            0.0025000000000000005,
            0.003236581620494722,
        ];
        for (i, (g, w)) in got.iter().zip(pinned).enumerate() {
            assert_eq!(g.to_bits(), w.to_bits(), "value {i}: {g:?} != {w:?}");
        }
    }

    #[test]
    fn mecanum_pure_strafe_moves_sideways() {
        // Wheel speeds of the body twist (0, 0.5 m/s, 0), i.e. (−1, 1, 1, −1)·0.5/r: the
        // forward kinematics reads v_y = 0.5 m/s (to rounding), and after 10 s the
        // odometry stands at (0, 5 m) with yaw 0.
        let (c, kin, _) = rover(1);
        let mut o = WheelOdom::new(&noise_free(), &c).unwrap();
        let twist = (0.0, 0.5, 0.0);
        let out = run_n(&mut o, &|t| body_twist_truth(t, &kin, twist), 501);
        let msgs = odoms(&out);
        let last = msgs.last().unwrap();
        assert_eq!(last.stamp, START + Nanos::from_secs(10));
        let p = last.pose.translation.vector;
        assert!((p - Vector3::new(0.0, 5.0, 0.0)).norm() < 1e-9, "{p:?}");
        assert!(last.pose.rotation.angle() < 1e-9);
        assert!(o.heading_rad().abs() < 1e-9);
        for m in &msgs {
            assert!(
                (m.linear_velocity - Vector3::new(0.0, 0.5, 0.0)).norm() < 1e-12,
                "{:?}",
                m.linear_velocity
            );
            assert!(m.angular_velocity.norm() < 1e-12);
            Message::WheelOdom((*m).clone()).validate().unwrap();
        }
    }

    #[test]
    fn mecanum_constant_twist_follows_the_closed_form_arc() {
        // Constant body twist (0.3, 0.2, 0.1) for 60 s (6 rad of turn). With a constant
        // measured twist the midpoint step is R(θ_k + h/2)·v·dt (h = ω·dt), while the
        // exact step is R(θ_k)·∫R(ωs)ds·v = R(θ_k + h/2)·(2 sin(h/2)/ω)·v: the same
        // direction, shorter by c = (h/2)/sin(h/2). The headings are exact, so the
        // odometry path is the closed-form path scaled by c about the start:
        // p_odom = c·p up to rounding, and |p_odom − p| = (c − 1)·|p| with
        // c − 1 ≈ h²/24 = 1.7e-7 (|p| ≤ 2|v|/ω = 7.2 m: at most 1.2e-6 m).
        let (c, kin, _) = rover(1);
        let mut o = WheelOdom::new(&noise_free(), &c).unwrap();
        let twist = (0.3, 0.2, 0.1);
        let n = 3001;
        let out = run_n(&mut o, &|t| body_twist_truth(t, &kin, twist), n);
        let h = twist.2 * 0.02;
        let scale = (h / 2.0) / (h / 2.0).sin();
        assert!(scale - 1.0 > 1e-7 && scale - 1.0 < 1.7e-7);
        let mut worst: f64 = 0.0;
        for m in odoms(&out) {
            let (x, y, th) = twist_pose(secs(m.stamp), twist);
            let exact = Vector3::new(x, y, 0.0);
            let p = m.pose.translation.vector;
            assert!((p - scale * exact).norm() < 1e-9, "{p:?} vs {exact:?}");
            let err = (p - exact).norm();
            assert!(err <= (scale - 1.0) * exact.norm() + 1e-9, "{err}");
            worst = worst.max(err);
            assert!(angle_diff(m.pose.rotation.euler_angles().2, th).abs() < 1e-9);
            assert!((m.linear_velocity - Vector3::new(0.3, 0.2, 0.0)).norm() < 1e-12);
            assert!((m.angular_velocity - Vector3::new(0.0, 0.0, 0.1)).norm() < 1e-12);
        }
        assert!(worst > 1e-7 && worst < 1.3e-6, "{worst}");
        assert!((o.heading_rad() - 6.0).abs() < 1e-9);
    }

    #[test]
    fn mecanum_encoder_noise_gives_reported_twist_variance() {
        // σ = 0.01 m/s on each wheel's surface speed, rover at the constant twist
        // (0.4, −0.3, 0.2). The forward kinematics J = ¼[[1,1,1,1], [−1,1,1,−1],
        // [−1,1,−1,1]/L] has orthogonal rows, so the measured twist has covariance
        // σ²·J·Jᵀ = diag(σ²/4, σ²/4, σ²/(4L²)), uncorrelated. 20 000 samples: relative
        // std of a sample std 1/√(2N) = 0.5 %, tolerance 3 %; sample correlations have
        // std 1/√N = 0.7 %, tolerance 3 %; means within 5 standard errors of the truth.
        let (c, kin, lever) = rover(6);
        let p = WheelOdomParams {
            speed_sigma_mps: 0.01,
            ..WheelOdomParams::default()
        };
        let s = p.speed_sigma_mps;
        let mut o = WheelOdom::new(&p, &c).unwrap();
        let twist = (0.4, -0.3, 0.2);
        let n = 20_000;
        let out = run_n(&mut o, &|t| body_twist_truth(t, &kin, twist), n);
        let msgs = odoms(&out);
        let ex: Vec<f64> = msgs.iter().map(|m| m.linear_velocity.x - twist.0).collect();
        let ey: Vec<f64> = msgs.iter().map(|m| m.linear_velocity.y - twist.1).collect();
        let ew: Vec<f64> = msgs
            .iter()
            .map(|m| m.angular_velocity.z - twist.2)
            .collect();
        let expected = [s / 2.0, s / 2.0, s / (2.0 * lever)];
        for (e, sd) in [&ex, &ey, &ew].into_iter().zip(expected) {
            assert!((std(e) / sd - 1.0).abs() < 0.03, "{} vs {sd}", std(e));
            assert!(mean(e).abs() < 5.0 * sd / (n as f64).sqrt(), "{}", mean(e));
        }
        let corr = |a: &[f64], b: &[f64]| {
            let (ma, mb) = (mean(a), mean(b));
            let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
            cov / ((a.len() - 1) as f64 * std(a) * std(b))
        };
        for (a, b) in [(&ex, &ey), (&ex, &ew), (&ey, &ew)] {
            assert!(corr(a, b).abs() < 0.03, "{}", corr(a, b));
        }
        // Reported: σ²·J·Jᵀ (computed here from J) plus the slip terms of the measured
        // twist; off-diagonal entries 0.
        let j = nalgebra::Matrix3x4::new(
            1.0,
            1.0,
            1.0,
            1.0,
            -1.0,
            1.0,
            1.0,
            -1.0,
            -1.0 / lever,
            1.0 / lever,
            -1.0 / lever,
            1.0 / lever,
        ) / 4.0;
        let enc = s * s * j * j.transpose();
        for m in msgs.iter().take(200) {
            let slip = [
                (MECANUM_SLIP_FRACTION * m.linear_velocity.x).powi(2),
                (MECANUM_SLIP_FRACTION * m.linear_velocity.y).powi(2),
                (MECANUM_RATE_FRACTION * m.angular_velocity.z).powi(2),
            ];
            for (a, ia) in [0usize, 1, 5].into_iter().enumerate() {
                for (b, ib) in [0usize, 1, 5].into_iter().enumerate() {
                    let want = enc[(a, b)] + if a == b { slip[a] } else { 0.0 };
                    assert!(
                        (m.twist_covariance[(ia, ib)] - want).abs() < 1e-15,
                        "({ia}, {ib}): {} vs {want}",
                        m.twist_covariance[(ia, ib)]
                    );
                }
            }
            for i in 2..5 {
                assert_eq!(m.twist_covariance[(i, i)], UNMEASURED_VARIANCE);
            }
            Message::WheelOdom((*m).clone()).validate().unwrap();
        }
    }

    #[test]
    fn mecanum_pose_covariance_grows_with_slip_random_walks() {
        // Noise-free encoders: only the documented slip random walks. Pure strafe at
        // 0.5 m/s for 10 s at θ = 0: var(y) = SLIP_RW_M²·5 m, nothing along x or in θ.
        let (c, kin, _) = rover(1);
        let mut o = WheelOdom::new(&noise_free(), &c).unwrap();
        let out = run_n(&mut o, &|t| body_twist_truth(t, &kin, (0.0, 0.5, 0.0)), 501);
        let last = odoms(&out)[500];
        let rw = MECANUM_SLIP_RANDOM_WALK_M_PER_RTM.powi(2);
        assert!((last.pose_covariance[(1, 1)] - rw * 5.0).abs() < 1e-12);
        assert!(last.pose_covariance[(0, 0)].abs() < 1e-15);
        assert!(last.pose_covariance[(5, 5)].abs() < 1e-15);
        // Spinning in place at 0.5 rad/s for 10 s: var(θ) = YAW_RW_M²·5 rad.
        let mut o = WheelOdom::new(&noise_free(), &c).unwrap();
        let out = run_n(&mut o, &|t| body_twist_truth(t, &kin, (0.0, 0.0, 0.5)), 501);
        let last = odoms(&out)[500];
        assert!((o.heading_rad() - 5.0).abs() < 1e-9);
        let rw = MECANUM_YAW_RANDOM_WALK_RAD_PER_RTRAD.powi(2);
        assert!((last.pose_covariance[(5, 5)] - rw * 5.0).abs() < 1e-12);
        assert!(last.pose_covariance[(0, 0)].abs() < 1e-15);
    }

    #[test]
    fn mecanum_pose_covariance_matches_integrated_encoder_noise() {
        // Parked rover, σ = 0.01 m/s, 100 steps of 20 ms, 2000 seeds. The integrated
        // noise x = dt·(v_0/2 + v_1 + … + v_99 + v_100/2) has variance
        // (100 − ½)·(σ²/4)·dt² (θ stays ~1e-3 rad, so rotation mixes in ~1e-6), and θ
        // likewise with σ²/(4L²). The reported covariance's encoder part is
        // 100·(σ²/4)·dt² and 100·σ²/(4L²)·dt²: recovered by subtracting the slip random
        // walks, SLIP_RW_M²·Σ|Δx_b| from var(x) (up to the rotation mixing) and
        // YAW_RW_M²·Σ|Δθ| from var(θ) (exact: θ's rows of F and G are (0, 0, 1)), with the
        // increments recomputed from the reported twists. 2000 runs: relative std of the
        // sample variance √(2/2000) = 3.2 %, tolerance 15 % (a per-step variance of one
        // two-sample mean, σ²/8·dt², would be 50 % off).
        let (base, _, lever) = rover(0);
        let p = WheelOdomParams {
            speed_sigma_mps: 0.01,
            ..WheelOdomParams::default()
        };
        let (s, dt, steps) = (p.speed_sigma_mps, 0.02, 100);
        let enc_xy = steps as f64 * s * s / 4.0 * dt * dt;
        let enc_th = steps as f64 * s * s / (4.0 * lever * lever) * dt * dt;
        let runs = 2000;
        let (mut sx, mut sy, mut sth) = (0.0, 0.0, 0.0);
        for seed in 0..runs {
            let mut c = base.clone();
            c.master_seed = 1000 + seed;
            let mut o = WheelOdom::new(&p, &c).unwrap();
            let out = run_n(&mut o, &|t| stationary(t, Isometry3::identity()), steps + 1);
            let msgs = odoms(&out);
            let last = msgs[steps];
            let q = last.pose.translation.vector;
            sx += q.x * q.x;
            sy += q.y * q.y;
            sth += o.heading_rad().powi(2);
            if seed < 20 {
                let sum_abs = |f: fn(&OdometryMsg) -> f64| -> f64 {
                    msgs.windows(2)
                        .map(|w| (0.5 * (f(w[0]) + f(w[1])) * dt).abs())
                        .sum()
                };
                let ax = sum_abs(|m| m.linear_velocity.x);
                let ay = sum_abs(|m| m.linear_velocity.y);
                let ath = sum_abs(|m| m.angular_velocity.z);
                let rw_xy = MECANUM_SLIP_RANDOM_WALK_M_PER_RTM.powi(2);
                let rw_th = MECANUM_YAW_RANDOM_WALK_RAD_PER_RTRAD.powi(2);
                let px = last.pose_covariance[(0, 0)] - rw_xy * ax;
                let py = last.pose_covariance[(1, 1)] - rw_xy * ay;
                let pth = last.pose_covariance[(5, 5)] - rw_th * ath;
                assert!((px / enc_xy - 1.0).abs() < 0.01, "{px} vs {enc_xy}");
                assert!((py / enc_xy - 1.0).abs() < 0.01, "{py} vs {enc_xy}");
                assert!((pth / enc_th - 1.0).abs() < 1e-6, "{pth} vs {enc_th}");
            }
        }
        let m = runs as f64;
        let spread = (steps as f64 - 0.5) / steps as f64;
        for (v, enc) in [(sx / m, enc_xy), (sy / m, enc_xy), (sth / m, enc_th)] {
            assert!((v / (spread * enc) - 1.0).abs() < 0.15, "{v} vs {enc}");
        }
    }
}
