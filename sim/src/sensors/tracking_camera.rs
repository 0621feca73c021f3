//! Visual-inertial tracking camera, Intel RealSense T265-like (`[sensors.tracking_camera]`).
//!
//! Output: [`Message::TrackingOdom`] with `frame_id` `tracking_odom`, `child_frame_id` the
//! camera frame (`frame`), pose `odom_from_cam` and the camera's twist in its own frame.
//!
//! **Epochs** are free-running: `ctx.start + offset + i/rate_hz`, with a fixed offset in
//! `[0, period)` drawn from the sensor's stream (the device is not synchronised to the
//! other sensors).
//!
//! **The odom frame** is the camera's start frame made gravity-aligned: its origin is the
//! camera's position at the first sample, its z axis is up and its x axis is the
//! horizontal heading of the camera's x axis. Without errors the first pose therefore has
//! the camera's true roll and pitch, zero yaw and zero position, and every later pose is
//! exactly `odom_from_cam = world_from_odom⁻¹ · world_from_cam`.
//!
//! **Errors**, accumulated like a real VIO:
//! - the true relative motion between consecutive samples, `Δ = cam_prev⁻¹ · cam_now`, is
//!   corrupted and integrated (`est_now = est_prev · Δ'`): its translation is scaled by
//!   `1 + s` (scale error `s`, drawn once, σ `scale_error_sigma`) plus N(0, σ_pos²·d) per
//!   axis, and its rotation is right-multiplied by `Exp(n)` with `n` ~ N(0, σ_rp²·d) about
//!   the camera x and y axes and N(0, σ_yaw²·d) about z, where `d = |Δp|` is the distance
//!   the camera moved (random walks per √metre, so the drift grows with distance and
//!   stops when the robot stands still);
//! - the gravity alignment is tilted by a constant pitch error `b` (drawn once, σ
//!   `pitch_bias_sigma_deg`) about the camera's lateral (y) axis at the start:
//!   `est_0 = world_from_odom⁻¹ · cam_0 · Ry(−b)`. Driving forward on level ground the
//!   estimate climbs by `d·sin b` and comes back down on the way back, which is what
//!   makes the T265's σ_U several times RTK's in the seed paper;
//! - the reported pose adds white jitter (σ `jitter_sigma_m` per axis, not integrated).
//!
//! **Twist**: the true linear and angular velocity of the camera in its own frame plus
//! white noise of `twist_linear_sigma_mps` and `twist_angular_sigma_radps`.
//!
//! **Covariances**: position `(σ_pos²·D + σ_jitter²)·I`, rotation
//! `diag(σ_rp²·D, σ_rp²·D, σ_yaw²·D)` with `D` the distance travelled since the first
//! sample — the variances of the random walks and the jitter. Like a real VIO, the
//! device does not know its scale and gravity-alignment errors, so they are not in the
//! covariance; nor is the position error that heading drift induces over later motion.
//! The rotation block treats the per-step noise as if it were about fixed axes (exact for
//! motion in a plane, since roll and pitch share one σ); the twist covariance is the
//! twist noise, `diag(σ_lin²·I, σ_ang²·I)`.

use super::noise::{standard_normal3, white3};
use super::{EpochClock, SensorContext, SensorModel, latency_from_ms, mount, require_rate};
use crate::params::{ParamError, TrackingCameraParams, require_non_negative};
use crate::rng;
use crate::truth::TruthSample;
use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use vinebench_msgs::{FrameId, Message, Nanos, OdometryMsg, TimedMessage};

/// The odometry frame of the tracking camera (its gravity-aligned start frame).
pub const TRACKING_ODOM_FRAME: &str = "tracking_odom";

/// The simulated tracking camera. Random stream `sensors.tracking_camera`.
#[derive(Clone, Debug)]
pub struct TrackingCamera {
    frame_id: FrameId,
    odom_frame_id: FrameId,
    body_from_cam: Isometry3<f64>,
    clock: EpochClock,
    latency: Nanos,
    rng: ChaCha8Rng,
    scale_error: f64,
    pitch_bias_rad: f64,
    position_rw: f64,
    roll_pitch_rw: f64,
    yaw_rw: f64,
    jitter_sigma: f64,
    twist_linear_sigma: f64,
    twist_angular_sigma: f64,
    state: Option<Track>,
}

/// The integration state after the first sample.
#[derive(Clone, Debug)]
struct Track {
    /// True `world_from_cam` at the previous sample.
    world_from_cam_prev: Isometry3<f64>,
    /// The estimate `odom_from_cam` (without jitter).
    odom_from_cam: Isometry3<f64>,
    /// Camera path length since the first sample, m.
    distance_m: f64,
}

impl TrackingCamera {
    /// Checks `[sensors.tracking_camera]` and builds the sensor.
    pub fn new(
        p: &TrackingCameraParams,
        ctx: &SensorContext,
    ) -> Result<TrackingCamera, ParamError> {
        let path = |k: &str| format!("sensors.tracking_camera.{k}");
        let rate_hz = require_rate(&path("rate_hz"), p.rate_hz)?;
        let latency = latency_from_ms(&path("latency_ms"), p.latency_ms, rate_hz)?;
        let nn = |k: &str, v: f64| require_non_negative(&path(k), v);
        let scale_sigma = nn("scale_error_sigma", p.scale_error_sigma)?;
        let pitch_sigma = nn("pitch_bias_sigma_deg", p.pitch_bias_sigma_deg)?.to_radians();
        let yaw_rw = nn("yaw_random_walk_deg_per_rtm", p.yaw_random_walk_deg_per_rtm)?.to_radians();
        let roll_pitch_rw = nn(
            "roll_pitch_random_walk_deg_per_rtm",
            p.roll_pitch_random_walk_deg_per_rtm,
        )?
        .to_radians();
        let position_rw = nn(
            "position_random_walk_m_per_rtm",
            p.position_random_walk_m_per_rtm,
        )?;
        let jitter_sigma = nn("jitter_sigma_m", p.jitter_sigma_m)?;
        let twist_linear_sigma = nn("twist_linear_sigma_mps", p.twist_linear_sigma_mps)?;
        let twist_angular_sigma = nn("twist_angular_sigma_radps", p.twist_angular_sigma_radps)?;
        let body_from_cam = mount(ctx, "tracking_camera", &p.frame)?;

        let mut rng = rng::stream(ctx.master_seed, "sensors.tracking_camera");
        // Draw order (fixed): epoch offset, scale error, pitch bias.
        let unaligned = EpochClock::new(ctx.start, rate_hz);
        let period_ns = (unaligned.time_at(1) - ctx.start).0.max(1);
        let offset = Nanos(rng.random_range(0..period_ns));
        let scale_error = scale_sigma * super::noise::standard_normal(&mut rng);
        let pitch_bias_rad = pitch_sigma * super::noise::standard_normal(&mut rng);
        Ok(TrackingCamera {
            frame_id: FrameId::new(&p.frame),
            odom_frame_id: FrameId::new(TRACKING_ODOM_FRAME),
            body_from_cam,
            clock: EpochClock::new(ctx.start + offset, rate_hz),
            latency,
            rng,
            scale_error,
            pitch_bias_rad,
            position_rw,
            roll_pitch_rw,
            yaw_rw,
            jitter_sigma,
            twist_linear_sigma,
            twist_angular_sigma,
            state: None,
        })
    }

    /// The scale error drawn for this run (estimated distance = (1 + s) · true distance).
    pub fn scale_error(&self) -> f64 {
        self.scale_error
    }

    /// The gravity-alignment pitch error drawn for this run, rad (positive: the estimate
    /// climbs when the camera moves forward).
    pub fn pitch_bias_rad(&self) -> f64 {
        self.pitch_bias_rad
    }

    /// `body_from_cam`, from the robot's URDF.
    pub fn body_from_cam(&self) -> &Isometry3<f64> {
        &self.body_from_cam
    }
}

/// `world_from_odom` for a camera at `world_from_cam`: origin at the camera, z up, x along
/// the horizontal heading of the camera's x axis (yaw 0 if that axis is vertical).
pub fn gravity_aligned_frame(world_from_cam: &Isometry3<f64>) -> Isometry3<f64> {
    let x = world_from_cam.rotation * Vector3::x();
    let yaw = if x.x == 0.0 && x.y == 0.0 {
        0.0
    } else {
        x.y.atan2(x.x)
    };
    Isometry3::from_parts(
        world_from_cam.translation,
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
    )
}

impl SensorModel for TrackingCamera {
    fn name(&self) -> &'static str {
        "tracking_camera"
    }

    fn next_time(&self) -> Nanos {
        self.clock.time()
    }

    fn sample(&mut self, truth: &TruthSample, out: &mut Vec<TimedMessage>) {
        let stamp = self.clock.time();
        debug_assert_eq!(truth.stamp, stamp, "the runner must sample at next_time()");
        let k = truth.at_mount(&self.body_from_cam);
        let world_from_cam = k.world_from_sensor;

        // Draw order per epoch (fixed): position walk, rotation walk, jitter, twist
        // linear, twist angular (also on the first sample, where the walks are unused).
        let n_pos = standard_normal3(&mut self.rng);
        let n_rot = standard_normal3(&mut self.rng);
        let jitter = white3(&mut self.rng, &Vector3::repeat(self.jitter_sigma));
        let n_lin = white3(&mut self.rng, &Vector3::repeat(self.twist_linear_sigma));
        let n_ang = white3(&mut self.rng, &Vector3::repeat(self.twist_angular_sigma));

        let track = match self.state.take() {
            None => {
                let odom_from_cam = gravity_aligned_frame(&world_from_cam).inverse()
                    * world_from_cam
                    * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -self.pitch_bias_rad);
                Track {
                    world_from_cam_prev: world_from_cam,
                    odom_from_cam,
                    distance_m: 0.0,
                }
            }
            Some(mut t) => {
                let delta = t.world_from_cam_prev.inverse() * world_from_cam;
                let d = delta.translation.vector.norm();
                let rd = d.sqrt();
                let translation = delta.translation.vector * (1.0 + self.scale_error)
                    + n_pos * (self.position_rw * rd);
                let rot_noise = Vector3::new(
                    n_rot.x * self.roll_pitch_rw * rd,
                    n_rot.y * self.roll_pitch_rw * rd,
                    n_rot.z * self.yaw_rw * rd,
                );
                let rotation = delta.rotation * UnitQuaternion::from_scaled_axis(rot_noise);
                let mut next = t.odom_from_cam
                    * Isometry3::from_parts(Translation3::from(translation), rotation);
                next.rotation.renormalize_fast();
                t.odom_from_cam = next;
                t.world_from_cam_prev = world_from_cam;
                t.distance_m += d;
                t
            }
        };

        let mut pose = track.odom_from_cam;
        pose.translation.vector += jitter;
        let dist = track.distance_m;
        let pos_var = self.position_rw.powi(2) * dist + self.jitter_sigma.powi(2);
        let rp_var = self.roll_pitch_rw.powi(2) * dist;
        let yaw_var = self.yaw_rw.powi(2) * dist;
        let pose_covariance = Matrix6::from_diagonal(&Vector6::new(
            pos_var, pos_var, pos_var, rp_var, rp_var, yaw_var,
        ));
        let lin_var = self.twist_linear_sigma.powi(2);
        let ang_var = self.twist_angular_sigma.powi(2);
        let twist_covariance = Matrix6::from_diagonal(&Vector6::new(
            lin_var, lin_var, lin_var, ang_var, ang_var, ang_var,
        ));
        out.push(TimedMessage {
            arrival: stamp + self.latency,
            msg: Message::TrackingOdom(OdometryMsg {
                stamp,
                frame_id: self.odom_frame_id.clone(),
                child_frame_id: self.frame_id.clone(),
                pose,
                pose_covariance,
                linear_velocity: world_from_cam
                    .rotation
                    .inverse_transform_vector(&k.velocity_in_world)
                    + n_lin,
                angular_velocity: k.angular_velocity_in_sensor + n_ang,
                twist_covariance,
            }),
        });
        self.state = Some(track);
        self.clock.advance();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensors::test_support::*;

    fn quiet() -> TrackingCameraParams {
        TrackingCameraParams {
            scale_error_sigma: 0.0,
            pitch_bias_sigma_deg: 0.0,
            yaw_random_walk_deg_per_rtm: 0.0,
            roll_pitch_random_walk_deg_per_rtm: 0.0,
            position_random_walk_m_per_rtm: 0.0,
            jitter_sigma_m: 0.0,
            ..TrackingCameraParams::default()
        }
    }

    fn odoms(out: &[TimedMessage]) -> Vec<&OdometryMsg> {
        out.iter()
            .map(|m| match &m.msg {
                Message::TrackingOdom(o) => o,
                other => panic!("unexpected {other:?}"),
            })
            .collect()
    }

    /// A tilted, accelerating, turning truth: the body follows a circle but carries a
    /// time-varying roll and pitch (poses need not be dynamically consistent here).
    fn wobbly(t: Nanos) -> TruthSample {
        let mut tr = circle(t, 7.0, 1.3, Drive::IDEAL);
        let s = secs(t);
        tr.world_from_body.translation.vector.z = 0.3 * (0.2 * s).sin();
        tr.world_from_body.rotation *= UnitQuaternion::from_euler_angles(
            0.1 * (0.7 * s).sin(),
            0.15 + 0.05 * (0.3 * s).cos(),
            0.0,
        );
        tr
    }

    #[test]
    fn noise_free_pose_is_the_exact_truth_relation() {
        // Expected: world_from_odom built here from the first true camera pose (origin at
        // the camera, yaw of its x axis, z up), then odom_from_cam = world_from_odom⁻¹ ·
        // world_from_cam at every sample, to 1e-9 over 60 s (1800 samples).
        let c = ctx(2);
        let mut cam = TrackingCamera::new(&quiet(), &c).unwrap();
        let out = run_n(&mut cam, &wobbly, 1800);
        let o = odoms(&out);
        let body_from_cam = *cam.body_from_cam();
        let cam0 = wobbly(o[0].stamp).world_from_body * body_from_cam;
        let (_, _, yaw0) = cam0.rotation.euler_angles();
        let world_from_odom = Isometry3::from_parts(
            cam0.translation,
            UnitQuaternion::from_euler_angles(0.0, 0.0, yaw0),
        );
        // First pose: true roll and pitch, zero yaw, zero position.
        let (r0, p0, y0) = o[0].pose.rotation.euler_angles();
        let (tr0, tp0, _) = cam0.rotation.euler_angles();
        assert!((r0 - tr0).abs() < 1e-12 && (p0 - tp0).abs() < 1e-12 && y0.abs() < 1e-12);
        assert!(o[0].pose.translation.vector.norm() < 1e-12);
        for m in &o {
            let expected =
                world_from_odom.inverse() * wobbly(m.stamp).world_from_body * body_from_cam;
            let dp = (m.pose.translation.vector - expected.translation.vector).norm();
            let dr = m.pose.rotation.angle_to(&expected.rotation);
            assert!(dp < 1e-9 && dr < 1e-9, "at {}: {dp} m, {dr} rad", m.stamp);
            assert_eq!(m.frame_id.as_str(), "tracking_odom");
            assert_eq!(m.child_frame_id.as_str(), "tracking_camera");
            Message::TrackingOdom((*m).clone()).validate().unwrap();
        }
    }

    #[test]
    fn epochs_are_free_running_with_a_random_offset() {
        // Offset in [0, period) and different between seeds; then exactly 1/30 s apart
        // (round(i·1e9/30) ns after the first).
        let mut offsets = Vec::new();
        for seed in 0..20 {
            let cam = TrackingCamera::new(&TrackingCameraParams::default(), &ctx(seed)).unwrap();
            let off = (cam.next_time() - START).0;
            assert!((0..33_333_333).contains(&off));
            offsets.push(off);
        }
        offsets.sort();
        offsets.dedup();
        assert!(offsets.len() > 15);
        let mut cam = TrackingCamera::new(&TrackingCameraParams::default(), &ctx(1)).unwrap();
        let first = cam.next_time();
        let out = run_n(&mut cam, &wobbly, 100);
        for (i, m) in out.iter().enumerate() {
            let i = i as i64;
            assert_eq!(m.msg.stamp(), first + Nanos((i * 1_000_000_000 + 15) / 30));
            assert_eq!(m.arrival, m.msg.stamp() + Nanos(5_000_000));
        }
    }

    #[test]
    fn pitch_bias_makes_altitude_climb_by_distance_times_sine() {
        // Level straight line at 1 m/s along ENU yaw 0.4: after d metres the estimate is
        // at (d·cos b, 0, d·sin b) in the odom frame (closed form of a tilted alignment),
        // and its first orientation is pitched nose-up by b.
        let p = TrackingCameraParams {
            pitch_bias_sigma_deg: 0.8,
            ..quiet()
        };
        let c = ctx(3);
        let mut cam = TrackingCamera::new(&p, &c).unwrap();
        let b = cam.pitch_bias_rad();
        assert!(b.abs() > 1e-4, "seed gives a usable bias: {b}");
        let truth = |t| straight(t, 0.4, 1.0, Drive::IDEAL);
        let out = run_n(&mut cam, &truth, 3000);
        let o = odoms(&out);
        let (_, pitch0, _) = o[0].pose.rotation.euler_angles();
        assert!(
            (pitch0 + b).abs() < 1e-12,
            "REP-103 pitch of a nose-up tilt is −b"
        );
        let x0 = truth(o[0].stamp).world_from_body.translation.vector;
        for m in &o {
            let d = (truth(m.stamp).world_from_body.translation.vector - x0).norm();
            let e = m.pose.translation.vector;
            assert!(
                (e.z - d * b.sin()).abs() < 1e-9,
                "d = {d}: z {} vs {}",
                e.z,
                d * b.sin()
            );
            assert!((e.x - d * b.cos()).abs() < 1e-9 && e.y.abs() < 1e-9);
        }
        // Out and back around a closed circle: the altitude error is sin(b) times the
        // distance along the initial heading, so it returns to zero at the end of a lap.
        let mut cam = TrackingCamera::new(&p, &c).unwrap();
        let (radius, speed) = (10.0, 1.0);
        let lap = 2.0 * std::f64::consts::PI * radius / speed;
        let truth = |t| circle(t, radius, speed, Drive::IDEAL);
        let out = run_n(&mut cam, &truth, (lap * 30.0) as usize);
        let cam0 = truth(odoms(&out)[0].stamp).world_from_body * cam.body_from_cam();
        let odom = gravity_aligned_frame(&cam0);
        let mut max_z: f64 = 0.0;
        for m in odoms(&out) {
            let x_along = (odom.inverse() * truth(m.stamp).world_from_body * cam.body_from_cam())
                .translation
                .vector
                .x;
            assert!((m.pose.translation.vector.z - x_along * b.sin()).abs() < 1e-9);
            max_z = max_z.max(m.pose.translation.vector.z.abs());
        }
        let last = odoms(&out).last().unwrap().pose.translation.vector.z;
        assert!(last.abs() < 0.02 * max_z, "end {last}, max {max_z}");
    }

    #[test]
    fn scale_error_scales_distance() {
        let p = TrackingCameraParams {
            scale_error_sigma: 0.01,
            ..quiet()
        };
        let mut cam = TrackingCamera::new(&p, &ctx(4)).unwrap();
        let s = cam.scale_error();
        assert!(s != 0.0);
        let out = run_n(&mut cam, &|t| straight(t, -1.0, 1.0, Drive::IDEAL), 1501);
        let last = odoms(&out).last().unwrap().pose.translation.vector;
        let d = 1500.0 / 30.0;
        assert!((last.x - d * (1.0 + s)).abs() < 1e-9 && last.yz().norm() < 1e-9);
    }

    /// Position and yaw errors (in the odom frame) and the message at sample indices
    /// `at` of one run on a straight line at 1 m/s (30 Hz: index 750 is 25 m from the
    /// first sample, 3000 is 100 m).
    fn straight_run(
        p: &TrackingCameraParams,
        seed: u64,
        at: &[usize],
    ) -> Vec<(Vector3<f64>, f64, OdometryMsg)> {
        let mut cam = TrackingCamera::new(p, &ctx(seed)).unwrap();
        let truth = |t| straight(t, 0.0, 1.0, Drive::IDEAL);
        let n = at.iter().max().unwrap() + 1;
        let out = run_n(&mut cam, &truth, n);
        let o = odoms(&out);
        let x0 = truth(o[0].stamp).world_from_body.translation.vector;
        at.iter()
            .map(|&i| {
                let m = o[i];
                let d = (truth(m.stamp).world_from_body.translation.vector - x0).norm();
                let e = m.pose.translation.vector - Vector3::new(d, 0.0, 0.0);
                let (_, _, yaw) = m.pose.rotation.euler_angles();
                (e, yaw, m.clone())
            })
            .collect()
    }

    #[test]
    fn position_random_walk_matches_its_variance() {
        // Position random walk only: the end error after d metres is a sum of independent
        // N(0, σ²·d_i) steps per axis, so E|e|² = 3σ²d, and the reported variance is σ²d.
        // Over 300 seeds the mean of |e|²/(σ²d) (χ²₃: mean 3, std √6/√300 = 0.14) must be
        // within 0.5 of 3 at both distances.
        let sigma = 0.005f64;
        let p = TrackingCameraParams {
            position_random_walk_m_per_rtm: sigma,
            ..quiet()
        };
        let mut sums = [0.0; 2];
        for seed in 0..300u64 {
            let r = straight_run(&p, seed, &[750, 3000]);
            for (k, (d, (e, _, m))) in [25.0f64, 100.0].iter().zip(&r).enumerate() {
                assert!((m.pose_covariance[(0, 0)] - sigma * sigma * d).abs() < 1e-9);
                sums[k] += e.norm_squared() / (sigma * sigma * d);
            }
        }
        for (d, s) in [25.0, 100.0].iter().zip(sums) {
            let m = s / 300.0;
            assert!(
                (m - 3.0).abs() < 0.5,
                "d = {d}: mean normalised squared error {m}"
            );
        }
    }

    #[test]
    fn drift_grows_with_distance_and_yaw_matches_reported_variance() {
        // All default random walks and jitter, no scale or pitch bias. The yaw walk
        // dominates: the lateral error grows like σ_yaw·d^{3/2}/√3, so the RMS end error
        // at 100 m must exceed that at 25 m by at least √4 = 2 (with 0.1 slack for the
        // 200-seed Monte Carlo; the expected ratio is ≈ 7.8).
        // Yaw error variance is σ_yaw²·d, as reported: the mean of yaw²/reported over 200
        // seeds is 1 with std √2/√200 = 0.1; tolerance 0.35.
        let p = TrackingCameraParams {
            scale_error_sigma: 0.0,
            pitch_bias_sigma_deg: 0.0,
            ..TrackingCameraParams::default()
        };
        let (mut sq25, mut sq100, mut yaw_ratio) = (0.0, 0.0, 0.0);
        for seed in 0..200u64 {
            let r = straight_run(&p, seed, &[750, 3000]);
            sq25 += r[0].0.norm_squared();
            sq100 += r[1].0.norm_squared();
            yaw_ratio += r[1].1 * r[1].1 / r[1].2.pose_covariance[(5, 5)];
        }
        let (r25, r100) = ((sq25 / 200.0).sqrt(), (sq100 / 200.0).sqrt());
        assert!(r100 > 1.9 * r25, "rms 25 m {r25}, 100 m {r100}");
        yaw_ratio /= 200.0;
        assert!(
            (yaw_ratio - 1.0).abs() < 0.35,
            "yaw error / reported variance {yaw_ratio}"
        );
    }

    #[test]
    fn twist_is_the_camera_velocity_in_its_frame() {
        // On the circle the camera (lever r in the body) moves at v + ω×r; in the camera
        // frame (= body axes for this URDF): (v − ω r_y, ω r_x, 0). The noise is
        // 0.01 m/s and 0.005 rad/s: 10σ bounds.
        let c = ctx(5);
        let mut cam = TrackingCamera::new(&quiet(), &c).unwrap();
        let r = cam.body_from_cam().translation.vector;
        let (radius, speed) = (4.0, 1.0);
        let w = speed / radius;
        let out = run_n(&mut cam, &|t| circle(t, radius, speed, Drive::IDEAL), 30);
        for m in odoms(&out) {
            let expected = Vector3::new(speed - w * r.y, w * r.x, 0.0);
            assert!((m.linear_velocity - expected).amax() < 0.1);
            assert!((m.angular_velocity - Vector3::new(0.0, 0.0, w)).amax() < 0.05);
            assert_eq!(
                m.twist_covariance[(0, 0)],
                TrackingCameraParams::default()
                    .twist_linear_sigma_mps
                    .powi(2)
            );
        }
    }
}
