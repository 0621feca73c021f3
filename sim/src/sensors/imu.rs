//! IMU with AHRS orientation output, Xsens MTi-300-like (`[sensors.imu]`).
//!
//! Truth: the rigid-body kinematics of the IMU mount ([`TruthSample::at_mount`]). The
//! specific force is `f = R_wiᵀ (a_i − g_w)` with `g_w = (0, 0, −g)` (a level IMU at rest
//! reads `+g` on z) and the angular rate is the mount's angular velocity in the IMU frame.
//!
//! Errors, per axis and independent between axes:
//! - white noise with discrete σ = density·√rate (the density of a band-limited white
//!   noise sampled at `rate`);
//! - an in-run bias: a first-order Gauss-Markov process ([`GaussMarkov3`], exact
//!   discretisation, started in its steady state) with steady-state σ equal to the
//!   datasheet's bias instability and correlation time `bias_correlation_time_s`.
//!   *This is an approximation*: the datasheet value is the minimum of the measured
//!   Allan-deviation curve (the flicker floor), while a Gauss-Markov process of σ has an
//!   Allan-deviation **maximum** of 0.617·σ at an averaging time of 1.89·τ. Using the
//!   instability directly as σ is the usual simple choice; it slightly overstates the
//!   drift near 1.89·τ and does not reproduce the flat flicker floor;
//! - a constant turn-on bias, drawn once per run (σ `*_turn_on_bias_*`).
//!
//! AHRS orientation: `q_meas = Exp(e_world) · q_true` with `q_true = world_from_imu` and
//! `e_world` a three-axis Gauss-Markov process on the world axes: σ roll/pitch on east
//! and north, σ yaw on up, correlation time `orientation_correlation_time_s` (0 = white).
//! The reported orientation covariance is `diag(σ_rp², σ_rp², σ_yaw²)` rad², the
//! steady-state covariance of `e_world` (the message's error `e` with
//! `true = Exp(e)·reported` is `−e_world`, which has the same covariance). Angular
//! velocity and acceleration covariances are the white-noise variances `σ²·I`; they
//! leave out the (much smaller, slowly varying) biases, as a datasheet-driven driver does.

use super::noise::{GaussMarkov3, white3};
use super::{EpochClock, SensorContext, SensorModel, latency_from_ms, mount, require_rate};
use crate::params::{ImuParams, ParamError, require_non_negative, require_positive};
use crate::rng;
use crate::truth::TruthSample;
use nalgebra::{Isometry3, Matrix3, UnitQuaternion, Vector3};
use rand_chacha::ChaCha8Rng;
use vinebench_msgs::{FrameId, ImuMsg, Message, Nanos, TimedMessage};

/// Standard gravity: 1 g in m/s² (the unit of µg accelerometer specifications).
pub const STANDARD_GRAVITY_MPS2: f64 = 9.806_65;
/// One µg in m/s².
pub const MICRO_G_MPS2: f64 = 1e-6 * STANDARD_GRAVITY_MPS2;
/// One degree per hour in rad/s.
pub const DEG_PER_HOUR_RADPS: f64 = std::f64::consts::PI / 180.0 / 3600.0;

/// The simulated IMU. Random stream `sensors.imu`.
#[derive(Clone, Debug)]
pub struct Imu {
    frame_id: FrameId,
    body_from_imu: Isometry3<f64>,
    clock: EpochClock,
    latency: Nanos,
    gravity_in_world: Vector3<f64>,
    rng: ChaCha8Rng,
    gyro_white_sigma: Vector3<f64>,
    accel_white_sigma: Vector3<f64>,
    gyro_turn_on_bias: Vector3<f64>,
    accel_turn_on_bias: Vector3<f64>,
    gyro_bias: GaussMarkov3,
    accel_bias: GaussMarkov3,
    orientation_error: GaussMarkov3,
    orientation_covariance: Matrix3<f64>,
    angular_velocity_covariance: Matrix3<f64>,
    linear_acceleration_covariance: Matrix3<f64>,
}

impl Imu {
    /// Checks `[sensors.imu]` and builds the sensor. Epochs: `ctx.start + i/rate_hz`.
    pub fn new(p: &ImuParams, ctx: &SensorContext) -> Result<Imu, ParamError> {
        let path = |k: &str| format!("sensors.imu.{k}");
        let rate_hz = require_rate(&path("rate_hz"), p.rate_hz)?;
        let latency = latency_from_ms(&path("latency_ms"), p.latency_ms)?;
        let nn = |k: &str, v: f64| require_non_negative(&path(k), v);
        let gyro_density = nn("gyro_noise_density_dps_rthz", p.gyro_noise_density_dps_rthz)?;
        let gyro_instab = nn("gyro_bias_instability_dph", p.gyro_bias_instability_dph)?;
        let accel_density = nn("accel_noise_density_ug_rthz", p.accel_noise_density_ug_rthz)?;
        let accel_instab = nn("accel_bias_instability_ug", p.accel_bias_instability_ug)?;
        let bias_tau =
            require_positive(&path("bias_correlation_time_s"), p.bias_correlation_time_s)?;
        let gyro_turn_on = nn("gyro_turn_on_bias_dph", p.gyro_turn_on_bias_dph)?;
        let accel_turn_on = nn("accel_turn_on_bias_ug", p.accel_turn_on_bias_ug)?;
        let rp_sigma = nn(
            "orientation_roll_pitch_sigma_deg",
            p.orientation_roll_pitch_sigma_deg,
        )?
        .to_radians();
        let yaw_sigma = nn("orientation_yaw_sigma_deg", p.orientation_yaw_sigma_deg)?.to_radians();
        let orient_tau = nn(
            "orientation_correlation_time_s",
            p.orientation_correlation_time_s,
        )?;
        let body_from_imu = mount(ctx, "imu", &p.frame)?;
        if !(ctx.gravity_mps2.is_finite() && ctx.gravity_mps2 > 0.0) {
            return Err(ParamError::new(
                "origin",
                "an origin with finite, positive normal gravity",
                ctx.gravity_mps2,
            ));
        }

        let dt = 1.0 / rate_hz;
        let gyro_white = gyro_density.to_radians() * rate_hz.sqrt();
        let accel_white = accel_density * MICRO_G_MPS2 * rate_hz.sqrt();
        let mut rng = rng::stream(ctx.master_seed, "sensors.imu");
        // Draw order (fixed): turn-on biases gyro, accel; initial bias states gyro,
        // accel; initial orientation error.
        let gyro_turn_on_bias = white3(
            &mut rng,
            &Vector3::repeat(gyro_turn_on * DEG_PER_HOUR_RADPS),
        );
        let accel_turn_on_bias = white3(&mut rng, &Vector3::repeat(accel_turn_on * MICRO_G_MPS2));
        let gyro_bias = GaussMarkov3::stationary(
            Vector3::repeat(gyro_instab * DEG_PER_HOUR_RADPS),
            bias_tau,
            dt,
            &mut rng,
        );
        let accel_bias = GaussMarkov3::stationary(
            Vector3::repeat(accel_instab * MICRO_G_MPS2),
            bias_tau,
            dt,
            &mut rng,
        );
        let orientation_sigma = Vector3::new(rp_sigma, rp_sigma, yaw_sigma);
        let orientation_error =
            GaussMarkov3::stationary(orientation_sigma, orient_tau, dt, &mut rng);
        Ok(Imu {
            frame_id: FrameId::new(&p.frame),
            body_from_imu,
            clock: EpochClock::new(ctx.start, rate_hz),
            latency,
            gravity_in_world: Vector3::new(0.0, 0.0, -ctx.gravity_mps2),
            rng,
            gyro_white_sigma: Vector3::repeat(gyro_white),
            accel_white_sigma: Vector3::repeat(accel_white),
            gyro_turn_on_bias,
            accel_turn_on_bias,
            gyro_bias,
            accel_bias,
            orientation_error,
            orientation_covariance: Matrix3::from_diagonal(&orientation_sigma.map(|s| s * s)),
            angular_velocity_covariance: Matrix3::identity() * (gyro_white * gyro_white),
            linear_acceleration_covariance: Matrix3::identity() * (accel_white * accel_white),
        })
    }

    /// `body_from_imu`, from the robot's URDF.
    pub fn body_from_imu(&self) -> &Isometry3<f64> {
        &self.body_from_imu
    }
}

impl SensorModel for Imu {
    fn name(&self) -> &'static str {
        "imu"
    }

    fn next_time(&self) -> Nanos {
        self.clock.time()
    }

    fn sample(&mut self, truth: &TruthSample, out: &mut Vec<TimedMessage>) {
        let stamp = self.clock.time();
        debug_assert_eq!(truth.stamp, stamp, "the runner must sample at next_time()");
        let k = truth.at_mount(&self.body_from_imu);
        let world_from_imu: UnitQuaternion<f64> = k.world_from_sensor.rotation;
        let specific_force = world_from_imu
            .inverse_transform_vector(&(k.acceleration_in_world - self.gravity_in_world));

        // Draw order per epoch (fixed): gyro white, accel white, then the bias and
        // orientation processes step to the next epoch.
        let gyro_noise = white3(&mut self.rng, &self.gyro_white_sigma);
        let accel_noise = white3(&mut self.rng, &self.accel_white_sigma);
        let angular_velocity = k.angular_velocity_in_sensor
            + self.gyro_turn_on_bias
            + self.gyro_bias.value()
            + gyro_noise;
        let linear_acceleration =
            specific_force + self.accel_turn_on_bias + self.accel_bias.value() + accel_noise;
        let orientation =
            UnitQuaternion::from_scaled_axis(*self.orientation_error.value()) * world_from_imu;
        self.gyro_bias.step(&mut self.rng);
        self.accel_bias.step(&mut self.rng);
        self.orientation_error.step(&mut self.rng);

        out.push(TimedMessage {
            arrival: stamp + self.latency,
            msg: Message::Imu(ImuMsg {
                stamp,
                frame_id: self.frame_id.clone(),
                orientation: Some(orientation),
                orientation_covariance: self.orientation_covariance,
                angular_velocity,
                angular_velocity_covariance: self.angular_velocity_covariance,
                linear_acceleration,
                linear_acceleration_covariance: self.linear_acceleration_covariance,
            }),
        });
        self.clock.advance();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensors::noise::stats::{autocorrelation, mean, std};
    use crate::sensors::test_support::*;
    use nalgebra::Translation3;

    fn quiet() -> ImuParams {
        ImuParams {
            gyro_noise_density_dps_rthz: 0.0,
            gyro_bias_instability_dph: 0.0,
            accel_noise_density_ug_rthz: 0.0,
            accel_bias_instability_ug: 0.0,
            gyro_turn_on_bias_dph: 0.0,
            accel_turn_on_bias_ug: 0.0,
            orientation_roll_pitch_sigma_deg: 0.0,
            orientation_yaw_sigma_deg: 0.0,
            ..ImuParams::default()
        }
    }

    fn imu_msgs(out: &[TimedMessage]) -> Vec<&ImuMsg> {
        out.iter()
            .map(|m| match &m.msg {
                Message::Imu(i) => i,
                other => panic!("unexpected {other:?}"),
            })
            .collect()
    }

    fn channels(msgs: &[&ImuMsg], f: impl Fn(&ImuMsg) -> Vector3<f64>) -> [Vec<f64>; 3] {
        let v: Vec<Vector3<f64>> = msgs.iter().map(|m| f(m)).collect();
        [0, 1, 2].map(|i| v.iter().map(|x| x[i]).collect())
    }

    #[test]
    fn noise_free_on_a_circle_matches_closed_form_at_the_lever_arm() {
        // IMU mounted at r = (0.26, 0.02, 0.77) (builtin URDF), rotated here by yaw 90°
        // and roll 180° so that the frame change is exercised. On the circle (radius R,
        // speed v, ω = v/R about z, level), the body-frame acceleration of the mount is
        // (0, v²/R, 0) + ω×(ω×r) = (−ω² r_x, v²/R − ω² r_y, 0); specific force adds +g
        // on z. In the IMU frame: R_biᵀ·(that), rate R_biᵀ·(0, 0, ω).
        let mut c = ctx(1);
        let lever = Vector3::new(0.26, 0.02, 0.77);
        let r_bi = UnitQuaternion::from_euler_angles(std::f64::consts::PI, 0.0, 0.0)
            * UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2);
        c.static_transforms.insert(
            "imu_link",
            Isometry3::from_parts(Translation3::from(lever), r_bi),
        );
        let (radius, speed) = (5.0, 1.5);
        let omega = speed / radius;
        let mut imu = Imu::new(&quiet(), &c).unwrap();
        let truth = |t| circle(t, radius, speed, Drive::IDEAL);
        let out = run_n(&mut imu, &truth, 2000);
        let g = c.gravity_mps2;
        let f_body = Vector3::new(
            -omega * omega * lever.x,
            speed * speed / radius - omega * omega * lever.y,
            g,
        );
        let f_expected = r_bi.inverse() * f_body;
        let w_expected = r_bi.inverse() * Vector3::new(0.0, 0.0, omega);
        for (i, m) in imu_msgs(&out).iter().enumerate() {
            assert!((m.linear_acceleration - f_expected).norm() < 1e-12, "{i}");
            assert!((m.angular_velocity - w_expected).norm() < 1e-12, "{i}");
            // Orientation: world_from_imu = Rz(ωt)·R_bi.
            let th = omega * secs(m.stamp);
            let q = UnitQuaternion::from_euler_angles(0.0, 0.0, th) * r_bi;
            assert!(m.orientation.unwrap().angle_to(&q) < 1e-9, "{i}");
            assert_eq!(m.orientation_covariance, Matrix3::zeros());
        }
        // Epochs: start + i·5 ms exactly, arrival 2 ms later.
        for (i, m) in out.iter().enumerate() {
            let t = START + Nanos(5_000_000 * i as i64);
            assert_eq!(m.msg.stamp(), t);
            assert_eq!(m.arrival, t + Nanos(2_000_000));
        }
    }

    #[test]
    fn level_at_rest_reads_plus_g() {
        let c = ctx(1);
        let mut imu = Imu::new(&quiet(), &c).unwrap();
        let pose = Isometry3::translation(3.0, -2.0, 1.0);
        let out = run_n(&mut imu, &|t| stationary(t, pose), 10);
        for m in imu_msgs(&out) {
            assert!(
                (m.linear_acceleration - Vector3::new(0.0, 0.0, c.gravity_mps2)).norm() < 1e-12
            );
            assert!(m.angular_velocity.norm() < 1e-15);
        }
    }

    #[test]
    fn white_noise_at_rest_matches_density_times_sqrt_rate() {
        // Datasheet defaults, 20 000 samples (100 s at 200 Hz). Expected σ: gyro
        // 0.01 °/s/√Hz·√200 = 2.47e-3 rad/s, accel 60 µg/√Hz·√200 = 8.32e-3 m/s². The
        // sample std of N independent normals has a relative standard error 1/√(2N) =
        // 0.5 %, so 5 % is a 10σ bound (a unit slip — degrees vs radians, µg vs m/s², a
        // missing √rate — is off by far more). The biases (10 °/h = 4.8e-5 rad/s,
        // 15 µg) vary by less than their σ over 100 s and add < 0.1 % to the variance.
        let p = ImuParams::default();
        let c = ctx(21);
        let mut imu = Imu::new(&p, &c).unwrap();
        let out = run_n(&mut imu, &|t| stationary(t, Isometry3::identity()), 20_000);
        let msgs = imu_msgs(&out);
        let gyro_sigma = p.gyro_noise_density_dps_rthz.to_radians() * p.rate_hz.sqrt();
        let accel_sigma = p.accel_noise_density_ug_rthz * 9.80665e-6 * p.rate_hz.sqrt();
        for (what, ch, sigma) in [
            ("gyro", channels(&msgs, |m| m.angular_velocity), gyro_sigma),
            (
                "accel",
                channels(&msgs, |m| m.linear_acceleration),
                accel_sigma,
            ),
        ] {
            for (i, x) in ch.iter().enumerate() {
                let s = std(x);
                assert!(
                    (s / sigma - 1.0).abs() < 0.05,
                    "{what}[{i}]: std {s}, expected {sigma}"
                );
            }
        }
        // The reported covariances are exactly these white-noise variances.
        assert!(
            (msgs[0].angular_velocity_covariance - Matrix3::identity() * gyro_sigma.powi(2)).norm()
                < 1e-18
        );
        assert!(
            (msgs[0].linear_acceleration_covariance - Matrix3::identity() * accel_sigma.powi(2))
                .norm()
                < 1e-15
        );
    }

    #[test]
    fn bias_is_gauss_markov_with_instability_sigma_and_correlation_time() {
        // Only the in-run bias (no white noise, no turn-on bias), τ shortened to 0.5 s so
        // that 200 000 samples (1000 s) hold 2000 correlation times. AR(1) with
        // φ = e^{−dt/τ} = e^{−0.01}: the lag-1 autocorrelation estimate has std
        // √((1−φ²)/N) = 3.2e-4 (tolerance 0.002); at lag 100 (= τ, expected e^{−1}) the
        // Bartlett std is ≈ 0.017 (tolerance 0.07); the sample std has relative std
        // √((1+φ²)/(2N(1−φ²))) ≈ 1.6 % (tolerance 7 %).
        let p = ImuParams {
            gyro_bias_instability_dph: 10.0,
            accel_bias_instability_ug: 15.0,
            bias_correlation_time_s: 0.5,
            ..quiet()
        };
        let c = ctx(5);
        let mut imu = Imu::new(&p, &c).unwrap();
        let out = run_n(&mut imu, &|t| stationary(t, Isometry3::identity()), 200_000);
        let msgs = imu_msgs(&out);
        let g = Vector3::new(0.0, 0.0, c.gravity_mps2);
        let phi = (-1.0f64 / 200.0 / 0.5).exp();
        for (what, ch, sigma) in [
            (
                "gyro",
                channels(&msgs, |m| m.angular_velocity),
                10.0 * DEG_PER_HOUR_RADPS,
            ),
            (
                "accel",
                channels(&msgs, |m| m.linear_acceleration - g),
                15.0 * 9.80665e-6,
            ),
        ] {
            for (i, x) in ch.iter().enumerate() {
                let r1 = autocorrelation(x, 1);
                assert!((r1 - phi).abs() < 0.002, "{what}[{i}] lag-1 {r1} vs {phi}");
                let r100 = autocorrelation(x, 100);
                assert!(
                    (r100 - (-1.0f64).exp()).abs() < 0.07,
                    "{what}[{i}] lag-τ {r100}"
                );
                let s = std(x);
                assert!(
                    (s / sigma - 1.0).abs() < 0.07,
                    "{what}[{i}] std {s} vs {sigma}"
                );
            }
        }
    }

    #[test]
    fn turn_on_bias_is_constant_within_a_run_and_has_its_sigma_across_runs() {
        // 400 seeds: sample std of a N(0, σ²) draw has relative std 1/√800 = 3.5 %;
        // tolerance 15 %. Within a run the value never changes (no other noise).
        let p = ImuParams {
            gyro_turn_on_bias_dph: 50.0,
            accel_turn_on_bias_ug: 200.0,
            ..quiet()
        };
        let mut gyro_x = Vec::new();
        let mut accel_y = Vec::new();
        for seed in 0..400 {
            let c = ctx(seed);
            let mut imu = Imu::new(&p, &c).unwrap();
            let out = run_n(&mut imu, &|t| stationary(t, Isometry3::identity()), 5);
            let msgs = imu_msgs(&out);
            for m in &msgs[1..] {
                assert_eq!(m.angular_velocity, msgs[0].angular_velocity);
                assert_eq!(m.linear_acceleration, msgs[0].linear_acceleration);
            }
            gyro_x.push(msgs[0].angular_velocity.x);
            accel_y.push(msgs[0].linear_acceleration.y);
        }
        assert!((std(&gyro_x) / (50.0 * DEG_PER_HOUR_RADPS) - 1.0).abs() < 0.15);
        assert!((std(&accel_y) / (200.0 * 9.80665e-6) - 1.0).abs() < 0.15);
        assert!(mean(&gyro_x).abs() < 4.0 * 50.0 * DEG_PER_HOUR_RADPS / 20.0);
    }

    #[test]
    fn ahrs_error_is_about_world_axes_and_matches_reported_covariance() {
        // A tilted robot at rest (roll 0.6, pitch −0.4, yaw 1.0 rad): if the error were
        // applied about the IMU axes instead of east/north/up, the 1° yaw σ would leak
        // into east and north. τ = 0.05 s, 40 000 samples: φ = e^{−0.1}, effective
        // sample count N(1−φ)/(1+φ) ≈ 2000, so the sample variance has relative std
        // ≈ √(2/2000) = 3.2 %; tolerance 15 %. Mean NEES (3 dof) ≈ 3 with std
        // ≈ √(6/2000) = 0.055; tolerance 0.3. Cross-correlations: std 1/√2000 = 0.022;
        // tolerance 0.1.
        let p = ImuParams {
            orientation_correlation_time_s: 0.05,
            ..ImuParams::default()
        };
        let c = ctx(9);
        let pose = Isometry3::from_parts(
            Translation3::new(1.0, 2.0, 0.5),
            UnitQuaternion::from_euler_angles(0.6, -0.4, 1.0),
        );
        let mut imu = Imu::new(&p, &c).unwrap();
        let out = run_n(&mut imu, &|t| stationary(t, pose), 40_000);
        let msgs = imu_msgs(&out);
        let q_true = pose.rotation * imu.body_from_imu().rotation;
        let errs: Vec<Vector3<f64>> = msgs
            .iter()
            .map(|m| (m.orientation.unwrap() * q_true.inverse()).scaled_axis())
            .collect();
        let cov = msgs[0].orientation_covariance;
        let (rp, yaw) = (0.2f64.to_radians(), 1.0f64.to_radians());
        assert!(
            (cov - Matrix3::from_diagonal(&Vector3::new(rp * rp, rp * rp, yaw * yaw))).norm()
                < 1e-18
        );
        let n = errs.len() as f64;
        let sample_cov = errs
            .iter()
            .fold(Matrix3::zeros(), |a, e| a + e * e.transpose())
            / n;
        for i in 0..3 {
            let ratio = sample_cov[(i, i)] / cov[(i, i)];
            assert!(
                (ratio - 1.0).abs() < 0.15,
                "axis {i}: variance ratio {ratio}"
            );
            for j in 0..i {
                let rho = sample_cov[(i, j)] / (sample_cov[(i, i)] * sample_cov[(j, j)]).sqrt();
                assert!(rho.abs() < 0.1, "axes {i},{j}: correlation {rho}");
            }
        }
        let inv = cov.try_inverse().unwrap();
        let nees = errs
            .iter()
            .map(|e| (e.transpose() * inv * e)[0])
            .sum::<f64>()
            / n;
        assert!((nees - 3.0).abs() < 0.3, "mean NEES {nees}");
    }
}
