//! IMU with AHRS orientation output, Xsens MTi-300-like (`[sensors.imu]`).
//!
//! Truth: the rigid-body kinematics of the IMU mount ([`TruthSample::at_mount`]): its
//! world velocity `v` and rotation `R = world_from_imu` at every epoch.
//!
//! **Interval means, as the device's strapdown integration (SDI) gives them.** The
//! MTi-300 integrates its raw samples internally at a high rate and outputs, at the
//! output rate, the orientation increment `ΔR` and velocity increment `Δv` over each
//! output interval; its rate-of-turn and acceleration outputs are those increments
//! divided by the interval. The simulated IMU does the same with the truth at the two
//! ends of the interval `(t_{i−1}, t_i]`, `Δ = t_i − t_{i−1}` (s, from the integer
//! stamps):
//! - mean angular rate, IMU frame: `ω̄ = Log(R_{i−1}ᵀ R_i) / Δ` (the rotation vector of
//!   the relative rotation, which is expressed in the IMU frame; exact for any rate that
//!   turns less than π per interval);
//! - mean specific force, IMU frame: `f̄ = R_midᵀ ((v_i − v_{i−1})/Δ − g_w)` with the
//!   midpoint rotation `R_mid = R_{i−1}·Exp(½·Log(R_{i−1}ᵀ R_i))` and `g_w = (0, 0, −g)`
//!   (a level IMU at rest reads `+g` on z and zero rate);
//! - the first sample of a run (no previous epoch) is the instantaneous value at its
//!   stamp: `f = Rᵀ (a − g_w)` and the mount's angular velocity in the IMU frame.
//!
//! *Why.* A physics engine steps at a fixed 1 ms: its accelerations are piecewise
//! constant per step and carry contact vibration well above the 100 Hz Nyquist rate of a
//! 200 Hz output. Point-sampling them would alias that vibration into spurious
//! low-frequency motion (a 180 Hz vibration shows up at 20 Hz); the interval mean is the
//! device's anti-aliasing. Strapdown integration of these outputs with the midpoint
//! attitude (`v⁺ = v + (R_mid f̄ + g_w)Δ`, `R⁺ = R·Exp(ω̄Δ)`) reproduces the velocity change
//! and the orientation change over every interval exactly, whatever happened inside it.
//!
//! *Size of the change for smooth motion.* The mean over `(t_{i−1}, t_i]` belongs to the
//! interval's midpoint, so for a slowly varying signal it differs from the point sample at
//! the stamp by about `−ȧ·Δ/2` (a half-interval lag, 2.5 ms at 200 Hz) plus `O(Δ²)`
//! terms. For a constant rotation rate `ω` (a level body on a circle, at any lever arm) the
//! rate is exact and the horizontal specific force is the instantaneous one scaled by
//! `sinc(ωΔ/2) = sin(ωΔ/2)/(ωΔ/2)`: at ω = 0.6 rad/s and Δ = 5 ms the relative
//! difference is `1 − sinc(0.0015) = 3.75e-7` (3.4e-7 m/s² on 0.9 m/s² of centripetal
//! acceleration at 1.5 m/s), far below the white noise (8e-3 m/s² per sample).
//!
//! Noise, biases and the AHRS orientation (below) are applied to these noise-free interval
//! means exactly as they were to point samples. The orientation output stays the
//! instantaneous `world_from_imu` at the stamp plus its error.
//!
//! Errors, per axis and independent between axes:
//! - white noise with discrete σ = density·√rate (the density of a band-limited white
//!   noise sampled at `rate`);
//! - an in-run bias, `bias_model`: `"flicker"` (default), 1/f noise ([`Flicker3`]: a
//!   sum of Gauss-Markov processes with correlation times spread over `flicker_band_s`)
//!   whose Allan deviation is flat at the datasheet's bias instability, as the measured
//!   curve's floor is; or `"gauss_markov"`, one first-order process ([`GaussMarkov3`])
//!   with σ the instability and correlation time `bias_correlation_time_s`, whose Allan
//!   deviation has a **maximum** of 0.617·σ at 1.89·τ instead of a floor. Both start in
//!   their steady state;
//! - the Earth's rotation (`earth_rate`): `Ω_E = 7.292 115e-5 rad/s` about the Earth's
//!   axis, in the world (ENU) `Ω_E·(0, cos φ, sin φ)` at the origin's latitude φ, seen
//!   by the gyro as `Rᵀ·ω_ie`; the transport rate of a vehicle at a few m/s (1e-7 rad/s)
//!   is left out;
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

use super::noise::{Flicker3, GaussMarkov3, white3};
use super::{EpochClock, SensorContext, SensorModel, latency_from_ms, mount, require_rate};
use crate::params::{ImuBiasModel, ImuParams, ParamError, require_non_negative, require_positive};
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
/// The Earth's rotation rate, rad/s (WGS84).
pub const EARTH_RATE_RADPS: f64 = 7.292_115e-5;

/// The Earth's rotation in the ENU frame at geodetic latitude `lat_deg`, rad/s.
pub fn earth_rate_in_enu(lat_deg: f64) -> Vector3<f64> {
    let (s, c) = lat_deg.to_radians().sin_cos();
    Vector3::new(0.0, EARTH_RATE_RADPS * c, EARTH_RATE_RADPS * s)
}

/// An in-run bias process.
#[derive(Clone, Debug)]
enum Bias {
    GaussMarkov(GaussMarkov3),
    Flicker(Flicker3),
}

impl Bias {
    fn value(&self) -> &Vector3<f64> {
        match self {
            Bias::GaussMarkov(b) => b.value(),
            Bias::Flicker(b) => b.value(),
        }
    }
    fn step(&mut self, rng: &mut ChaCha8Rng) {
        match self {
            Bias::GaussMarkov(b) => b.step(rng),
            Bias::Flicker(b) => b.step(rng),
        }
    }
}

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
    gyro_bias: Bias,
    accel_bias: Bias,
    earth_rate_in_world: Vector3<f64>,
    orientation_error: GaussMarkov3,
    orientation_covariance: Matrix3<f64>,
    angular_velocity_covariance: Matrix3<f64>,
    linear_acceleration_covariance: Matrix3<f64>,
    previous: Option<MountAtEpoch>,
}

/// The mount kinematics the interval means need, kept from the previous epoch.
#[derive(Clone, Debug)]
struct MountAtEpoch {
    stamp: Nanos,
    velocity_in_world: Vector3<f64>,
    world_from_imu: UnitQuaternion<f64>,
}

impl MountAtEpoch {
    /// Mean angular rate and mean specific force (IMU frame) over the interval from
    /// `self` to `now`: `ω̄ = Log(R₀ᵀR₁)/Δ`, `f̄ = R_midᵀ((v₁ − v₀)/Δ − g_w)` with
    /// `R_mid = R₀·Exp(½·Log(R₀ᵀR₁))`. `None` unless `now` is later than `self`.
    fn interval_means(
        &self,
        now: &MountAtEpoch,
        gravity_in_world: &Vector3<f64>,
    ) -> Option<(Vector3<f64>, Vector3<f64>)> {
        if now.stamp <= self.stamp {
            return None;
        }
        let dt = (now.stamp - self.stamp).as_secs_f64();
        let rotation_vector = (self.world_from_imu.inverse() * now.world_from_imu).scaled_axis();
        let world_from_mid =
            self.world_from_imu * UnitQuaternion::from_scaled_axis(rotation_vector * 0.5);
        let mean_acceleration = (now.velocity_in_world - self.velocity_in_world) / dt;
        let specific_force =
            world_from_mid.inverse_transform_vector(&(mean_acceleration - gravity_in_world));
        Some((rotation_vector / dt, specific_force))
    }
}

impl Imu {
    /// Checks `[sensors.imu]` and builds the sensor. Epochs: `ctx.start + i/rate_hz`.
    pub fn new(p: &ImuParams, ctx: &SensorContext) -> Result<Imu, ParamError> {
        let path = |k: &str| format!("sensors.imu.{k}");
        let rate_hz = require_rate(&path("rate_hz"), p.rate_hz)?;
        let latency = latency_from_ms(&path("latency_ms"), p.latency_ms, rate_hz)?;
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
        let [band_lo, band_hi] = p.flicker_band_s;
        if p.bias_model == ImuBiasModel::Flicker
            && !(band_lo.is_finite()
                && band_lo >= dt
                && band_hi.is_finite()
                && band_hi >= band_lo
                && band_hi <= 1e9)
        {
            return Err(ParamError::new(
                path("flicker_band_s"),
                format!(
                    "[shortest, longest] correlation times with the sample period ({dt} s)                      <= shortest <= longest <= 1e9 s"
                ),
                format!("[{band_lo}, {band_hi}]"),
            ));
        }
        let bias = |instability: f64, rng: &mut ChaCha8Rng| match p.bias_model {
            ImuBiasModel::GaussMarkov => Bias::GaussMarkov(GaussMarkov3::stationary(
                Vector3::repeat(instability),
                bias_tau,
                dt,
                rng,
            )),
            ImuBiasModel::Flicker => {
                Bias::Flicker(Flicker3::from_turn_on(instability, band_lo, band_hi, dt))
            }
        };
        let gyro_bias = bias(gyro_instab * DEG_PER_HOUR_RADPS, &mut rng);
        let accel_bias = bias(accel_instab * MICRO_G_MPS2, &mut rng);
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
            earth_rate_in_world: if p.earth_rate {
                earth_rate_in_enu(ctx.enu.origin().lat_deg)
            } else {
                Vector3::zeros()
            },
            orientation_error,
            orientation_covariance: Matrix3::from_diagonal(&orientation_sigma.map(|s| s * s)),
            angular_velocity_covariance: Matrix3::identity() * (gyro_white * gyro_white),
            linear_acceleration_covariance: Matrix3::identity() * (accel_white * accel_white),
            previous: None,
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
        let now = MountAtEpoch {
            stamp,
            velocity_in_world: k.velocity_in_world,
            world_from_imu,
        };
        // Interval means since the previous epoch; the first sample is instantaneous.
        let (rate, specific_force) = self
            .previous
            .as_ref()
            .and_then(|prev| prev.interval_means(&now, &self.gravity_in_world))
            .unwrap_or_else(|| {
                (
                    k.angular_velocity_in_sensor,
                    world_from_imu.inverse_transform_vector(
                        &(k.acceleration_in_world - self.gravity_in_world),
                    ),
                )
            });
        self.previous = Some(now);

        // Draw order per epoch (fixed): gyro white, accel white, then the bias and
        // orientation processes step to the next epoch.
        let gyro_noise = white3(&mut self.rng, &self.gyro_white_sigma);
        let accel_noise = white3(&mut self.rng, &self.accel_white_sigma);
        let angular_velocity = rate
            + world_from_imu.inverse_transform_vector(&self.earth_rate_in_world)
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
            earth_rate: false,
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
        // IMU mounted at r = (0.26, 0.02, 0.77), rotated here by yaw 90° and roll 180° so
        // that the frame change is exercised. On the circle (radius R, speed v, ω = v/R
        // about z, level, yaw θ = ωt) the mount's world velocity is R_z(θ)·u with the
        // body-frame constant u = (v, 0, 0) + ω ẑ×r = (v − ω r_y, ω r_x, 0).
        // - First sample (instantaneous): body-frame acceleration ω ẑ×u =
        //   (−ω² r_x, v²/R − ω² r_y, 0), plus g on z.
        // - Later samples (interval means over Δ = 5 ms): R_mid = R_z(θ_mid)·R_bi, and
        //   R_z(θ_mid)ᵀ(R_z(θ_i) − R_z(θ_{i−1}))·u = (R_z(ωΔ/2) − R_z(−ωΔ/2))·u =
        //   2 sin(ωΔ/2)·ẑ×u, so f̄ = R_biᵀ((sin(ωΔ/2)/(Δ/2))·ẑ×u + g ẑ), i.e. the
        //   instantaneous horizontal part scaled by sinc(ωΔ/2) (1 − 9.4e-8 here, 4e-8 m/s²,
        //   far above the tolerance). The rate is exactly R_biᵀ(0, 0, ω) in both cases.
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
        let f_first = r_bi.inverse()
            * Vector3::new(
                -omega * omega * lever.x,
                speed * speed / radius - omega * omega * lever.y,
                g,
            );
        let u = Vector3::new(speed - omega * lever.y, omega * lever.x, 0.0);
        let dt = 0.005;
        let f_mean = r_bi.inverse()
            * ((omega * dt / 2.0).sin() / (dt / 2.0) * Vector3::z().cross(&u)
                + Vector3::new(0.0, 0.0, g));
        assert!((f_mean - f_first).norm() > 3e-8);
        let w_expected = r_bi.inverse() * Vector3::new(0.0, 0.0, omega);
        let msgs = imu_msgs(&out);
        let (mut worst_f, mut worst_w) = (0.0f64, 0.0f64);
        for (i, m) in msgs.iter().enumerate() {
            let f_expected = if i == 0 { f_first } else { f_mean };
            worst_f = worst_f.max((m.linear_acceleration - f_expected).norm());
            worst_w = worst_w.max((m.angular_velocity - w_expected).norm());
            // Orientation: the instantaneous world_from_imu = Rz(ωt)·R_bi.
            let th = omega * secs(m.stamp);
            let q = UnitQuaternion::from_euler_angles(0.0, 0.0, th) * r_bi;
            assert!(m.orientation.unwrap().angle_to(&q) < 1e-9, "{i}");
            assert_eq!(m.orientation_covariance, Matrix3::zeros());
        }
        println!("circle: worst |f − f̄| {worst_f:e} m/s², |ω − ω̄| {worst_w:e} rad/s");
        assert!(worst_f < 1e-12, "{worst_f}");
        assert!(worst_w < 1e-12, "{worst_w}");
        // Epochs: start + i·5 ms exactly, arrival 2 ms later.
        for (i, m) in out.iter().enumerate() {
            let t = START + Nanos(5_000_000 * i as i64);
            assert_eq!(m.msg.stamp(), t);
            assert_eq!(m.arrival, t + Nanos(2_000_000));
        }
    }

    /// Truth of a level robot (yaw 0.4 rad) moving along its x axis with a velocity
    /// sampled, like a 1 ms physics step, on a 1 kHz grid `START + 0.3 ms + k·1 ms`:
    /// `v_k = v0 + A·sin(2π·f·t_k)`, linear between grid points, so the acceleration is
    /// piecewise constant, `(v_{k+1} − v_k)/1 ms` on `[t_k, t_{k+1})`, and the position
    /// piecewise quadratic.
    fn vibrating(t: Nanos, v0: f64, amp: f64, freq_hz: f64) -> TruthSample {
        const STEP_NS: i64 = 1_000_000;
        const OFFSET_NS: i64 = 300_000;
        let h = STEP_NS as f64 * 1e-9;
        let speed_at = |k: i64| {
            v0 + amp
                * (std::f64::consts::TAU * freq_hz * (OFFSET_NS + k * STEP_NS) as f64 * 1e-9).sin()
        };
        let since = (t - START).0 - OFFSET_NS;
        let k = since.div_euclid(STEP_NS);
        let tau = since.rem_euclid(STEP_NS) as f64 * 1e-9;
        let accel = (speed_at(k + 1) - speed_at(k)) / h;
        let speed = speed_at(k) + accel * tau;
        // Distance since the grid point before START (k = −1).
        let distance = (-1..k)
            .map(|j| 0.5 * (speed_at(j) + speed_at(j + 1)) * h)
            .sum::<f64>()
            + speed_at(k) * tau
            + 0.5 * accel * tau * tau;
        let yaw: f64 = 0.4;
        let dir = Vector3::new(yaw.cos(), yaw.sin(), 0.0);
        TruthSample {
            stamp: t,
            world_from_body: Isometry3::from_parts(
                Translation3::from(dir * distance),
                UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
            ),
            velocity_in_world: dir * speed,
            acceleration_in_world: dir * accel,
            angular_velocity_in_body: Vector3::zeros(),
            angular_acceleration_in_body: Vector3::zeros(),
            drive_speeds_radps: [speed / SPROCKET_M, speed / SPROCKET_M, 0.0, 0.0],
            odometer_m: distance,
        }
    }

    #[test]
    fn interval_means_integrate_to_the_velocity_change_under_vibration() {
        // A 1 kHz physics-like truth with a 180 Hz velocity vibration of A = 1 cm/s
        // (piecewise-constant acceleration of amplitude 2A·sin(πf·1 ms)/1 ms = 10.7 m/s²)
        // on top of 1 m/s, sampled by the IMU at 200 Hz; no epoch falls on a grid point.
        // Strapdown-integrating the outputs, Σ (R f̄ − g ẑ)·Δ over epochs 1..n, must give
        // v(t_n) − v(t_0) to rounding at every n (each term is exactly the interval's Δv).
        // Point-sampling the acceleration at the epochs instead aliases the 180 Hz
        // vibration to |200 − 180| = 20 Hz: the running sum swings with amplitude
        // ≈ 10.7 m/s²·Δ/(2 sin(π·20 Hz·Δ)) = 0.087 m/s, against a true swing of A = 0.01 m/s,
        // so its error spans 2·(0.087 ± 0.01) m/s peak to peak, less at most a factor
        // cos(π/10) = 0.95 because only 10 phases of the 20 Hz swing are sampled:
        // [0.146, 0.193] m/s.
        let (v0, amp, freq) = (1.0, 0.01, 180.0);
        let truth = |t| vibrating(t, v0, amp, freq);
        let c = ctx(3);
        let mut imu = Imu::new(&quiet(), &c).unwrap();
        let n = 400;
        let out = run_n(&mut imu, &truth, n + 1);
        let msgs = imu_msgs(&out);
        let g_up = Vector3::new(0.0, 0.0, c.gravity_mps2);
        let v_start = truth(msgs[0].stamp).velocity_in_world;
        let (mut sum_mean, mut sum_point) = (Vector3::zeros(), Vector3::zeros());
        let mut worst_mean = 0.0f64;
        let (mut point_min, mut point_max) = (f64::INFINITY, f64::NEG_INFINITY);
        for w in msgs.windows(2) {
            let dt = (w[1].stamp - w[0].stamp).as_secs_f64();
            // The body does not turn, so the reported (instantaneous) orientation is R_mid.
            let world_from_imu = w[1].orientation.unwrap();
            sum_mean += (world_from_imu * w[1].linear_acceleration - g_up) * dt;
            let tr = truth(w[1].stamp);
            sum_point += tr.acceleration_in_world * dt;
            let dv = tr.velocity_in_world - v_start;
            worst_mean = worst_mean.max((sum_mean - dv).norm());
            // Along-track error of the point-sampled sum (it has no other component).
            let e = (sum_point - dv).dot(&tr.velocity_in_world.normalize());
            point_min = point_min.min(e);
            point_max = point_max.max(e);
            // The interval-mean rate of a non-rotating body is exactly zero.
            assert_eq!(w[1].angular_velocity, Vector3::zeros());
        }
        let point_span = point_max - point_min;
        println!(
            "vibration: interval-mean worst error {worst_mean:e} m/s, point-sampled error \
             span {point_span:.4} m/s ({point_min:.4} .. {point_max:.4})"
        );
        assert!(worst_mean < 1e-12, "{worst_mean}");
        assert!(
            point_span > 0.14 && point_span < 0.2,
            "point-sampled error span {point_span}"
        );
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
            bias_model: crate::params::ImuBiasModel::GaussMarkov,
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

    #[test]
    fn a_still_gyro_reads_the_earth_rate_in_its_own_frame() {
        // Noise-free, standing tilted and turned: ω = Rᵀ·Ω_E(0, cos φ, sin φ) exactly
        // (φ = 40.4545°: 11.44 °/h north, 9.76 °/h up, 15.04 °/h in all).
        let p = ImuParams {
            earth_rate: true,
            ..quiet()
        };
        let c = ctx(3);
        let pose = Isometry3::from_parts(
            Translation3::new(5.0, -2.0, 0.3),
            UnitQuaternion::from_euler_angles(0.1, -0.2, 2.0),
        );
        let mut imu = Imu::new(&p, &c).unwrap();
        let out = run_n(&mut imu, &|t| stationary(t, pose), 50);
        let world_from_imu = (pose * imu.body_from_imu()).rotation;
        let phi = 40.4545f64.to_radians();
        let omega = Vector3::new(0.0, phi.cos(), phi.sin()) * 7.292_115e-5;
        for m in imu_msgs(&out) {
            let want = world_from_imu.inverse_transform_vector(&omega);
            assert!(
                (m.angular_velocity - want).norm() < 1e-15,
                "{:?}",
                m.angular_velocity
            );
        }
        assert!((omega.norm() / DEG_PER_HOUR_RADPS - 15.041).abs() < 1e-3);
    }

    #[test]
    fn still_run_allan_floor_is_flat_and_the_mean_is_the_earth_rate() {
        // A navigation-grade gyro (0.001 °/s/√Hz, bias instability 0.5 °/h, flicker),
        // level with x east, 2 h at 100 Hz standing still. Allan deviation at 30, 100 and
        // 300 s: the model's, √(flicker² + N²/T), within 20 % (estimator spread at 300 s
        // over 2 h: about 10 %). The 2 h mean of each axis is the Earth rate there
        // (0, 11.44, 9.76 °/h) within 2 °/h (the flicker floor moves a 2 h mean by about
        // its 0.5 °/h; white noise by 0.04 °/h).
        let p = ImuParams {
            rate_hz: 100.0,
            gyro_noise_density_dps_rthz: 0.001,
            gyro_bias_instability_dph: 0.5,
            bias_model: crate::params::ImuBiasModel::Flicker,
            earth_rate: true,
            ..quiet()
        };
        let c = ctx(21);
        // The IMU's mount is level with x forward: a body yaw of 0 has x east.
        let mut imu = Imu::new(&p, &c).unwrap();
        let level = Isometry3::identity();
        let out = run_n(&mut imu, &|t| stationary(t, level), 720_000);
        let world_from_imu = imu.body_from_imu().rotation;
        let msgs = imu_msgs(&out);
        let phi = 40.4545f64.to_radians();
        let earth = world_from_imu
            .inverse_transform_vector(&(Vector3::new(0.0, phi.cos(), phi.sin()) * 7.292_115e-5));
        let n_white = 0.001f64.to_radians();
        let floor = 0.5 * DEG_PER_HOUR_RADPS;
        for axis in 0..3 {
            let x: Vec<f64> = msgs.iter().map(|m| m.angular_velocity[axis]).collect();
            let m = mean(&x);
            assert!(
                (m - earth[axis]).abs() < 2.0 * DEG_PER_HOUR_RADPS,
                "axis {axis}: mean {} °/h vs {} °/h",
                m / DEG_PER_HOUR_RADPS,
                earth[axis] / DEG_PER_HOUR_RADPS
            );
            for t in [30.0, 100.0, 300.0] {
                let a =
                    crate::sensors::noise::stats::allan_deviation(&x, 0.01, (t * 100.0) as usize);
                let model = (Flicker3::allan_deviation(floor, 1.0, 10_000.0, t).powi(2)
                    + n_white * n_white / t)
                    .sqrt();
                assert!(
                    (a / model - 1.0).abs() < 0.2,
                    "axis {axis} T {t}: {a} vs {model}"
                );
            }
        }
    }
}
