//! Track odometry (`[sensors.wheel_odom]`): encoder speeds integrated with the nominal
//! skid-steer model.
//!
//! Each epoch (`ctx.start + i/rate_hz`) reads the left and right track speeds from the
//! truth (what the drive turns, [`TruthSample::track_speed_left_mps`]) plus white noise
//! of σ `speed_sigma_mps` each, and computes the nominal body speed and yaw rate
//! `v = (v_l + v_r)/2`, `ω = (v_r − v_l)/W` with `W` the URDF track width. The nominal
//! model has no ICR expansion and no slip, so, like a real skid-steer odometry, it
//! over-estimates distance (by `1/(1 − slip)`) and turns (by the ICR factor).
//!
//! The planar pose `(x, y, θ)` in frame `wheel_odom` (child `base_link`) starts at zero
//! at the first sample and is integrated with the midpoint rule between consecutive
//! samples: with `v̄`, `ω̄` the means of the two samples and `Δs = v̄·dt`, `Δθ = ω̄·dt`,
//! `x += Δs·cos(θ + Δθ/2)`, `y += Δs·sin(θ + Δθ/2)`, `θ += Δθ`.
//!
//! Covariances (documented choices; the estimator does not fuse this source):
//! - twist: `var(v) = σ²/2 + (SLIP·v)²`, `var(ω) = 2σ²/W² + (ICR·ω)²` — the encoder noise
//!   propagated exactly, plus the model's unknown slip ([`SLIP_SPEED_FRACTION`]) and
//!   ICR error ([`ICR_RATE_FRACTION`]) as relative 1σ terms; lateral velocity
//!   [`LATERAL_SKID_SIGMA_MPS`]² (the non-holonomic constraint is not exact on a
//!   skid-steer); `v_z`, `ω_x`, `ω_y` are not measured: [`UNMEASURED_VARIANCE`];
//! - pose: `(x, y, θ)` covariance propagated step by step with the midpoint model's
//!   Jacobians, from per-step variances `var(Δs) = (σ²/4)·dt² + SLIP_RW²·|Δs|` and
//!   `var(Δθ) = (σ²/W²)·dt² + ICR_RW²·|Δθ|` (encoder noise of the two-sample means, plus
//!   random walks [`SLIP_RANDOM_WALK_M_PER_RTM`] per √metre and
//!   [`ICR_RANDOM_WALK_RAD_PER_RTRAD`] per √radian turned for the unmodelled slip and
//!   skid); `z`, roll and pitch are not estimated by a planar odometry:
//!   [`UNMEASURED_VARIANCE`], as ROS `diff_drive_controller` configurations do.

use super::noise::standard_normal;
use super::{EpochClock, SensorContext, SensorModel, latency_from_ms, require_rate};
use crate::params::{ParamError, WheelOdomParams, require_non_negative};
use crate::rng;
use crate::truth::TruthSample;
use nalgebra::{Isometry3, Matrix2x3, Matrix3, Matrix3x2, Matrix6, Vector3, Vector6};
use rand_chacha::ChaCha8Rng;
use vinebench_msgs::frames::names::BASE_LINK;
use vinebench_msgs::{FrameId, Message, Nanos, OdometryMsg, TimedMessage};

/// The odometry frame of the track odometry (the robot's pose at the first sample).
pub const WHEEL_ODOM_FRAME: &str = "wheel_odom";
/// Variance reported for components a planar odometry does not measure.
pub const UNMEASURED_VARIANCE: f64 = 1e6;
/// Unknown longitudinal slip as a fraction of speed (1σ), for the twist covariance.
pub const SLIP_SPEED_FRACTION: f64 = 0.03;
/// Unknown ICR expansion as a fraction of yaw rate (1σ), for the twist covariance.
pub const ICR_RATE_FRACTION: f64 = 0.3;
/// Lateral skid velocity (1σ), m/s.
pub const LATERAL_SKID_SIGMA_MPS: f64 = 0.05;
/// Along-track random walk for unmodelled slip, m/√m.
pub const SLIP_RANDOM_WALK_M_PER_RTM: f64 = 0.05;
/// Heading random walk for unmodelled skid, per √radian turned (rad/√rad).
pub const ICR_RANDOM_WALK_RAD_PER_RTRAD: f64 = 0.3;

/// The simulated track odometry. Random stream `sensors.wheel_odom`.
#[derive(Clone, Debug)]
pub struct WheelOdom {
    frame_id: FrameId,
    child_frame_id: FrameId,
    clock: EpochClock,
    latency: Nanos,
    rng: ChaCha8Rng,
    speed_sigma: f64,
    track_width: f64,
    state: Option<Planar>,
}

/// The integration state after the first sample.
#[derive(Clone, Debug)]
struct Planar {
    stamp: Nanos,
    v: f64,
    omega: f64,
    x: f64,
    y: f64,
    /// Unwrapped heading, rad.
    theta: f64,
    /// Covariance of (x, y, θ).
    cov: Matrix3<f64>,
}

impl WheelOdom {
    /// Checks `[sensors.wheel_odom]` and builds the sensor; the track width comes from
    /// `ctx.geometry`.
    pub fn new(p: &WheelOdomParams, ctx: &SensorContext) -> Result<WheelOdom, ParamError> {
        let path = |k: &str| format!("sensors.wheel_odom.{k}");
        let rate_hz = require_rate(&path("rate_hz"), p.rate_hz)?;
        let latency = latency_from_ms(&path("latency_ms"), p.latency_ms)?;
        let speed_sigma = require_non_negative(&path("speed_sigma_mps"), p.speed_sigma_mps)?;
        let w = ctx.geometry.track_width_m;
        if !(w.is_finite() && w > 0.0) {
            return Err(ParamError::new(
                "robot",
                "a URDF with a track width > 0 m",
                w,
            ));
        }
        Ok(WheelOdom {
            frame_id: FrameId::new(WHEEL_ODOM_FRAME),
            child_frame_id: FrameId::new(BASE_LINK),
            clock: EpochClock::new(ctx.start, rate_hz),
            latency,
            rng: rng::stream(ctx.master_seed, "sensors.wheel_odom"),
            speed_sigma,
            track_width: w,
            state: None,
        })
    }

    /// The unwrapped heading integrated so far, rad (0 before the first sample).
    pub fn heading_rad(&self) -> f64 {
        self.state.as_ref().map_or(0.0, |s| s.theta)
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
        // Draw order per epoch (fixed): left, right.
        let v_l = truth.track_speed_left_mps + self.speed_sigma * standard_normal(&mut self.rng);
        let v_r = truth.track_speed_right_mps + self.speed_sigma * standard_normal(&mut self.rng);
        let w = self.track_width;
        let v = 0.5 * (v_l + v_r);
        let omega = (v_r - v_l) / w;
        let s2 = self.speed_sigma * self.speed_sigma;

        let state = match self.state.take() {
            None => Planar {
                stamp,
                v,
                omega,
                x: 0.0,
                y: 0.0,
                theta: 0.0,
                cov: Matrix3::zeros(),
            },
            Some(prev) => {
                let dt = (stamp - prev.stamp).as_secs_f64();
                let ds = 0.5 * (prev.v + v) * dt;
                let dth = 0.5 * (prev.omega + omega) * dt;
                let th_mid = prev.theta + 0.5 * dth;
                let (sn, cs) = th_mid.sin_cos();
                let f = Matrix3::new(1.0, 0.0, -ds * sn, 0.0, 1.0, ds * cs, 0.0, 0.0, 1.0);
                let g = Matrix3x2::new(cs, -0.5 * ds * sn, sn, 0.5 * ds * cs, 0.0, 1.0);
                let var_ds = 0.25 * s2 * dt * dt + SLIP_RANDOM_WALK_M_PER_RTM.powi(2) * ds.abs();
                let var_dth =
                    s2 / (w * w) * dt * dt + ICR_RANDOM_WALK_RAD_PER_RTRAD.powi(2) * dth.abs();
                let q = nalgebra::Matrix2::new(var_ds, 0.0, 0.0, var_dth);
                let gt: Matrix2x3<f64> = g.transpose();
                let cov = f * prev.cov * f.transpose() + g * q * gt;
                Planar {
                    stamp,
                    v,
                    omega,
                    x: prev.x + ds * cs,
                    y: prev.y + ds * sn,
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
        let twist_covariance = Matrix6::from_diagonal(&Vector6::new(
            0.5 * s2 + (SLIP_SPEED_FRACTION * v).powi(2),
            LATERAL_SKID_SIGMA_MPS.powi(2),
            UNMEASURED_VARIANCE,
            UNMEASURED_VARIANCE,
            UNMEASURED_VARIANCE,
            2.0 * s2 / (w * w) + (ICR_RATE_FRACTION * omega).powi(2),
        ));
        out.push(TimedMessage {
            arrival: stamp + self.latency,
            msg: Message::WheelOdom(OdometryMsg {
                stamp,
                frame_id: self.frame_id.clone(),
                child_frame_id: self.child_frame_id.clone(),
                pose,
                pose_covariance,
                linear_velocity: Vector3::new(v, 0.0, 0.0),
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
            tr.track_speed_left_mps = -0.3;
            tr.track_speed_right_mps = 0.3;
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
}
