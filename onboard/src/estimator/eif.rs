//! The Extended Information Filter of the seed paper (eqs. 1–3), in information form.
//!
//! - **State** ([`super::ins`]): the sensor box = IMU frame, `p, v, q = world_from_imu`,
//!   error state `[δp, δv, δθ]` with `q_true = q ⊗ Exp(δθ)`, plus a stochastic clone
//!   `[δp_c, δθ_c]` of the pose at the previous tracking-camera message.
//! - **Prediction**: eq. (3) per IMU sample, trapezoidal in the samples
//!   ([`InsCore::predict`]).
//! - **Corrections** ([`super::measurement`]): GNSS position (eq. 1, antenna lever arm),
//!   GNSS velocity, AHRS orientation, tracking-camera relative pose (eq. 2 between
//!   consecutive messages, against the clone), wheel odometry (`use_wheel_odometry`: the
//!   body-frame velocity with the non-holonomic constraint).
//!
//! ## Information form
//! After every correction the filter's canonical representation is the information pair
//! `(Λ, η)` of the error state ([`Eif::information`]). The EIF prediction
//! `Λ⁻ = (F Λ⁻¹ Fᵀ + Q)⁻¹` is applied by keeping the moment matrix `P = Λ⁻¹` between
//! corrections: `P` is formed once after a correction (Cholesky), propagated per IMU
//! sample as `P ← F P Fᵀ + Q` with `F`'s block structure, and inverted back to
//! `Λ⁻ = P⁻¹` only when the next correction arrives. Since
//! `(F₂(F₁ Λ⁻¹ F₁ᵀ + Q₁)F₂ᵀ + Q₂)⁻¹` is what two EIF predictions in a row produce, this
//! equals applying the EIF prediction at every step (exactly, in exact arithmetic) while
//! inverting once per correction instead of once per IMU sample. The error mean is zero
//! between corrections (it is injected into the nominal state), so `η⁻ = 0`.
//!
//! A correction is additive: `Λ⁺ = Λ⁻ + Σᵢ Hᵢᵀ Rᵢ⁻¹ Hᵢ`, `η⁺ = Σᵢ Hᵢᵀ Rᵢ⁻¹ yᵢ`, where the
//! sum runs over **all measurements with the same stamp** (GNSS position and velocity of
//! one epoch, the AHRS reading and a tracking message that share it); then one Cholesky
//! solve gives `δx = Λ⁺⁻¹ η⁺`, which is injected into the nominal state and clone, and
//! `η` is reset to 0.
//!
//! ## Timing
//! Messages must come in stamp order (the [`super::EstimatorSet`] re-orders them). The
//! filter state lives on the IMU time grid; a measurement between two IMU samples waits
//! for the later sample, then the state is propagated to the measurement's stamp with the
//! IMU sample interpolated linearly inside the interval, corrected, and propagated on.
//! Poses are written at `output_rate_hz` on IMU stamps, after the corrections of that
//! stamp.
//!
//! ## Initialisation
//! The filter starts at the first IMU sample that carries an AHRS orientation and comes
//! at most [`MAX_INIT_LAG`] after a valid (not `NoFix`) GNSS fix: `q` from the AHRS,
//! `p` from eq. (1) (antenna → IMU origin with `q`, extrapolated to the IMU stamp with
//! the velocity), `v` from the GNSS velocity of that epoch when there is one, else 0.
//! Messages before that are counted as `before_init`. Gravity is fixed then.
//!
//! ## Measurement noise
//! - GNSS position: the fix's ENU covariance (plus [`POSITION_FLOOR_M`]²), gated by
//!   `gnss_gate_chi2` on `yᵀS⁻¹y`, `S = HPHᵀ + R` (prior `P`, the fix's own `R`).
//! - GNSS velocity: the message covariance (plus [`VELOCITY_FLOOR_MPS`]²).
//! - AHRS: the message covariance is about the **world** axes; the filter's error is
//!   local, so `R = R̂ᵀ Σ_world R̂` (plus [`ROTATION_FLOOR_RAD`]²).
//! - Tracking camera: per axis `σ_p = max(floor, k_p·√d)`, `σ_θ = max(floor, k_θ·√d)`,
//!   `d = |Δp|` the measured displacement.
//! - Wheel odometry: the velocity of the odometry's moving frame in that frame. Forward
//!   (and, where the message measures it, as a mecanum drive's does, lateral) speed with
//!   variance `max(reported, σ_w² + (slip·v)²)`: a driver's zero or tiny covariance never
//!   makes the wheels more trusted than their slip allows. Unmeasured axes (variance
//!   ≥ [`WHEEL_UNMEASURED_VARIANCE`], NaN or ≤ 0) are the non-holonomic constraint:
//!   lateral 0 ± `wheel_lateral_sigma_mps`, vertical 0 ± `wheel_vertical_sigma_mps`.
//!   Slip-aware: a reading whose `yᵀS⁻¹y` exceeds `wheel_gate_chi2` (wheels spinning or
//!   sliding against what IMU and GNSS say) is rejected (`wheel_slip_gated`); after
//!   [`WHEEL_GATE_RECOVERY`] in a row the filter's velocity uncertainty is re-opened to
//!   the innovation and the reading used (`wheel_gate_recovered`). Slip is correlated
//!   along the track: `wheel_correlation_time_s` weights readings like the GNSS ones.
//!
//! GNSS position and AHRS errors wander slowly (Gauss-Markov), so consecutive readings
//! are not independent. With `gnss_correlation_time_s` / `orientation_correlation_time_s`
//! τ > 0, a reading taken `dt` after the previous one used gets its covariance inflated by
//! `(1 + r)/(1 − r)`, `r = exp(−dt/τ)`: the information per second no longer grows with
//! the message rate, and the covariance stays consistent (see the test
//! `correlated_gnss_errors_are_weighted_consistently`). With τ > 0 the AHRS is used at
//! most every [`ORIENTATION_MIN_INTERVAL`] (nothing is lost: the weighting makes the
//! information rate independent of the rate); with τ = 0 every reading is used.
//!
//! The output covariance ([`PoseSample::covariance`]) is the body pose's: position error
//! of the body origin in the world, then the world-axis rotation error,
//! `J P Jᵀ` with `J = [[I, 0, −R[t_ib]×], [0, 0, R]]` (`t_ib` = `imu_from_body`
//! translation).

use super::ins::{
    IDX_P, IDX_PC, IDX_TH, IDX_V, INACTIVE_CLONE_VARIANCE, InsCore, Mat15, NavState, ProcessNoise,
    STATE_DIM, Vec15,
};
use super::measurement::{self, Linearized};
use super::params::{EifParams, ImuSampleModel, OrientationYaw};
use super::so3::skew;
use super::{Estimator, EstimatorError, EstimatorStats};
use nalgebra::{
    Cholesky, Const, Isometry3, Matrix3, Matrix6, SMatrix, SVector, UnitQuaternion, Vector3,
};
use std::collections::VecDeque;
use vinebench_msgs::geodesy::{LocalEnu, normal_gravity};
use vinebench_msgs::{
    FixStatus, FrameId, GnssFixMsg, GnssVelocityMsg, ImuMsg, Message, Nanos, OdometryMsg,
    PoseSample, StaticTransforms, Trajectory,
};

/// IMU gaps longer than this are bridged by holding the last sample (and counted as
/// `imu_gap_bridged`).
pub const MAX_IMU_GAP: Nanos = Nanos::from_millis(100);
/// Step length used while bridging an IMU gap, s.
const GAP_SUBSTEP_S: f64 = 0.005;
/// Most sub-steps of one bridged gap (longer gaps use longer steps).
const MAX_GAP_SUBSTEPS: usize = 100_000;
/// Longest time between the initialising GNSS fix and the IMU sample the filter starts at.
pub const MAX_INIT_LAG: Nanos = Nanos::from_millis(250);
/// With a correlated AHRS error model, orientations are used at most this often (the
/// correlation weighting makes the information per second independent of the rate).
pub const ORIENTATION_MIN_INTERVAL: Nanos = Nanos::from_millis(100);
/// Standard deviation added in quadrature to every GNSS position covariance (and the
/// initial position), m: keeps `Λ` invertible when a driver publishes zero covariance.
pub const POSITION_FLOOR_M: f64 = 1e-4;
/// Same for GNSS velocity, m/s.
pub const VELOCITY_FLOOR_MPS: f64 = 1e-4;
/// Same for orientation, rad.
pub const ROTATION_FLOOR_RAD: f64 = 1e-5;
/// Shortest spacing used in the correlation weighting, s.
const MIN_CORRELATION_DT_S: f64 = 1e-3;
/// Consecutive GNSS fixes the gate may reject before the filter concludes that it, not
/// the receiver, is wrong (1 s at 10 Hz). The next fix is then accepted after the
/// position and velocity uncertainty are re-opened to the innovation (see
/// `gnss_gate_recovered` in the stats), so an overconfident filter can never lock
/// itself out of GNSS for good.
pub const GATE_RECOVERY_FIXES: u32 = 10;
/// A wheel-odometry twist variance at or above this (m²/s²) marks the axis as not
/// measured (ROS drivers report 1e3–1e6 there, as `diff_drive_controller` does).
pub const WHEEL_UNMEASURED_VARIANCE: f64 = 1e3;
/// Consecutive wheel readings the slip gate may reject before the filter re-opens its
/// velocity uncertainty (1 s at 50 Hz).
pub const WHEEL_GATE_RECOVERY: u32 = 50;

/// An IMU noise model by datasheet: white noise densities, and the extra process noise
/// for what the filter's model leaves out (bias drift, vibration) as white densities.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct ImuProfile {
    /// The `imu_profile` name.
    pub name: &'static str,
    /// What the numbers come from.
    pub grade: &'static str,
    /// Gyro angle random walk, °/s/√Hz.
    pub gyro_dps_rthz: f64,
    /// Extra gyro process noise, °/s/√Hz.
    pub gyro_extra_dps_rthz: f64,
    /// Accelerometer velocity random walk, µg/√Hz.
    pub accel_ug_rthz: f64,
    /// Extra accelerometer process noise, µg/√Hz.
    pub accel_extra_ug_rthz: f64,
}

/// The named IMU profiles (`[estimators.eif] imu_profile`). Noise densities are the
/// datasheets' typical values. The extra noise is the datasheet's in-run bias instability
/// taken over 1 s (°/h ÷ 3600 → °/s/√Hz, µg → µg/√Hz) where the datasheet gives it (the
/// Xsens parts: MTi-300 10 °/h and 15 µg give the defaults' 0.002-0.003 and 20), and for
/// consumer parts, whose datasheets give none, an assumed class value of 0.02 °/s/√Hz
/// (70 °/h) and 100-200 µg/√Hz: their bias wanders with temperature by more than any
/// instability figure says.
pub const IMU_PROFILES: &[ImuProfile] = &[
    ImuProfile {
        name: "mti-300",
        grade: "Xsens MTi-300 (industrial AHRS; the defaults)",
        gyro_dps_rthz: 0.01,
        gyro_extra_dps_rthz: 0.002,
        accel_ug_rthz: 60.0,
        accel_extra_ug_rthz: 20.0,
    },
    ImuProfile {
        name: "mti-3",
        grade: "Xsens MTi-1/2/3 (MEMS module, 10 °/h, 30 µg in-run)",
        gyro_dps_rthz: 0.007,
        gyro_extra_dps_rthz: 0.003,
        accel_ug_rthz: 120.0,
        accel_extra_ug_rthz: 30.0,
    },
    ImuProfile {
        name: "bmi055",
        grade: "Bosch BMI055 (consumer MEMS; RealSense D435i/T265)",
        gyro_dps_rthz: 0.014,
        gyro_extra_dps_rthz: 0.02,
        accel_ug_rthz: 150.0,
        accel_extra_ug_rthz: 100.0,
    },
    ImuProfile {
        name: "bno055",
        grade: "Bosch BNO055 (consumer MEMS AHRS; BMI055 inside)",
        gyro_dps_rthz: 0.014,
        gyro_extra_dps_rthz: 0.02,
        accel_ug_rthz: 150.0,
        accel_extra_ug_rthz: 100.0,
    },
    ImuProfile {
        name: "mpu-9250",
        grade: "InvenSense MPU-9250 (consumer MEMS)",
        gyro_dps_rthz: 0.01,
        gyro_extra_dps_rthz: 0.02,
        accel_ug_rthz: 300.0,
        accel_extra_ug_rthz: 200.0,
    },
    ImuProfile {
        name: "icm-20948",
        grade: "TDK InvenSense ICM-20948 (consumer MEMS)",
        gyro_dps_rthz: 0.015,
        gyro_extra_dps_rthz: 0.02,
        accel_ug_rthz: 230.0,
        accel_extra_ug_rthz: 200.0,
    },
];

impl ImuProfile {
    /// The profile named `name`.
    pub fn find(name: &str) -> Option<&'static ImuProfile> {
        IMU_PROFILES.iter().find(|p| p.name == name)
    }
}

/// Measured IMU noise factor (against the profile's density) above which the filter
/// warns: its process noise is then too small and its covariance over-confident.
pub const IMU_NOISE_WARN_FACTOR: f64 = 3.0;
/// Length of one still window of [`StillMeter`].
const STILL_WINDOW: Nanos = Nanos::from_secs(1);
/// The robot counts as still while the filter's speed stays below this, m/s.
const STILL_SPEED_MPS: f64 = 0.05;
/// ... and the window's mean angular rate below this, rad/s.
const STILL_RATE_RADPS: f64 = 0.02;

/// The IMU's white noise measured from the samples of still stretches: per 1 s window
/// with the robot standing (filter speed below [`STILL_SPEED_MPS`] throughout, mean rate
/// below [`STILL_RATE_RADPS`]), the per-axis sample variance about the window's mean (so
/// gravity, earth rate and bias drop out), pooled over windows. The density is
/// `σ·√dt` (an IMU's white noise of density `N` has `σ = N·√rate` per sample).
#[derive(Clone, Debug, Default)]
struct StillMeter {
    start: Option<Nanos>,
    moved: bool,
    n: f64,
    dt_sum: f64,
    last_t: Option<Nanos>,
    w_sum: Vector3<f64>,
    w_sq: Vector3<f64>,
    a_sum: Vector3<f64>,
    a_sq: Vector3<f64>,
    /// Pooled over still windows: Σ(n−1)·var per axis, Σ(n−1), Σdt, samples.
    w_pooled: Vector3<f64>,
    a_pooled: Vector3<f64>,
    dof: f64,
    dt_pooled: f64,
    samples: f64,
    windows: u32,
}

impl StillMeter {
    fn push(&mut self, t: Nanos, w: &Vector3<f64>, a: &Vector3<f64>, speed: f64) {
        let start = *self.start.get_or_insert(t);
        if let Some(l) = self.last_t
            && t > l
        {
            self.dt_sum += (t - l).as_secs_f64();
        }
        self.last_t = Some(t);
        self.moved |= speed > STILL_SPEED_MPS;
        self.n += 1.0;
        self.w_sum += w;
        self.w_sq += w.component_mul(w);
        self.a_sum += a;
        self.a_sq += a.component_mul(a);
        if t - start < STILL_WINDOW {
            return;
        }
        let n = self.n;
        if !self.moved && n >= 10.0 && (self.w_sum / n).norm() < STILL_RATE_RADPS {
            let var = |sum: &Vector3<f64>, sq: &Vector3<f64>| {
                (sq - sum.component_mul(sum) / n).map(|v| v.max(0.0))
            };
            self.w_pooled += var(&self.w_sum, &self.w_sq);
            self.a_pooled += var(&self.a_sum, &self.a_sq);
            self.dof += n - 1.0;
            self.dt_pooled += self.dt_sum;
            self.samples += n - 1.0;
            self.windows += 1;
        }
        *self = StillMeter {
            w_pooled: self.w_pooled,
            a_pooled: self.a_pooled,
            dof: self.dof,
            dt_pooled: self.dt_pooled,
            samples: self.samples,
            windows: self.windows,
            ..StillMeter::default()
        };
    }

    /// Measured (gyro °/s/√Hz, accel µg/√Hz), RMS over the axes, after at least two
    /// still windows.
    fn densities(&self) -> Option<(f64, f64)> {
        if self.windows < 2 || self.dof <= 0.0 || self.samples <= 0.0 {
            return None;
        }
        let dt = self.dt_pooled / self.samples;
        let rms = |v: &Vector3<f64>| (v.sum() / (3.0 * self.dof)).sqrt();
        Some((
            rms(&self.w_pooled).to_degrees() * dt.sqrt(),
            rms(&self.a_pooled) * dt.sqrt() / (1e-6 * super::ins::STANDARD_GRAVITY),
        ))
    }
}

/// The EIF's parameters in SI units.
#[derive(Clone, Debug, PartialEq)]
struct Config {
    noise: ProcessNoise,
    /// The IMU noise model in datasheet units (named profile or the densities given).
    imu: ImuProfile,
    gravity: f64,
    use_gnss_position: bool,
    use_gnss_velocity: bool,
    use_imu_orientation: bool,
    use_tracking_camera: bool,
    tracking_pos_per_rtm: f64,
    tracking_rot_per_rtm: f64,
    tracking_pos_floor: f64,
    tracking_rot_floor: f64,
    gate_chi2: f64,
    sigma_v0: f64,
    output_period: Nanos,
    gnss_tau: f64,
    orientation_tau: f64,
    imu_interval_mean: bool,
    /// `orientation_yaw = "relative"`: AHRS roll/pitch only, heading from the course.
    relative_yaw: bool,
    course_min_speed: f64,
    course_min_baseline: f64,
    /// rad.
    course_floor: f64,
    use_wheel: bool,
    use_gnss_heading: bool,
    wheel_speed_sigma: f64,
    wheel_slip: f64,
    wheel_lateral_sigma: f64,
    wheel_vertical_sigma: f64,
    wheel_gate_chi2: f64,
    wheel_tau: f64,
    /// m; 0 = no scale calibration.
    wheel_calibration_length: f64,
}

impl Config {
    fn from_params(p: &EifParams) -> Result<Config, EstimatorError> {
        let nonneg = |name: &str, v: f64| -> Result<f64, EstimatorError> {
            if v.is_finite() && v >= 0.0 {
                Ok(v)
            } else {
                Err(EstimatorError::invalid(
                    &format!("estimators.eif.{name}"),
                    "a finite number >= 0",
                    v,
                ))
            }
        };
        let positive = |name: &str, v: f64| -> Result<f64, EstimatorError> {
            if v.is_finite() && v > 0.0 {
                Ok(v)
            } else {
                Err(EstimatorError::invalid(
                    &format!("estimators.eif.{name}"),
                    "a finite number > 0",
                    v,
                ))
            }
        };
        let rate = positive("output_rate_hz", p.output_rate_hz)?;
        let imu = if p.imu_profile.is_empty() {
            ImuProfile {
                name: "",
                grade: "",
                gyro_dps_rthz: nonneg(
                    "gyro_noise_density_dps_rthz",
                    p.gyro_noise_density_dps_rthz,
                )?,
                gyro_extra_dps_rthz: nonneg(
                    "gyro_extra_noise_dps_rthz",
                    p.gyro_extra_noise_dps_rthz,
                )?,
                accel_ug_rthz: nonneg(
                    "accel_noise_density_ug_rthz",
                    p.accel_noise_density_ug_rthz,
                )?,
                accel_extra_ug_rthz: nonneg(
                    "accel_extra_noise_ug_rthz",
                    p.accel_extra_noise_ug_rthz,
                )?,
            }
        } else {
            *ImuProfile::find(&p.imu_profile).ok_or_else(|| {
                EstimatorError::invalid(
                    "estimators.eif.imu_profile",
                    &format!(
                        "\"\" (the densities given) or one of {}",
                        IMU_PROFILES
                            .iter()
                            .map(|x| format!("\"{}\"", x.name))
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                    format!("{:?}", p.imu_profile),
                )
            })?
        };
        Ok(Config {
            noise: ProcessNoise::from_datasheet(
                imu.gyro_dps_rthz,
                imu.gyro_extra_dps_rthz,
                imu.accel_ug_rthz,
                imu.accel_extra_ug_rthz,
            ),
            imu,
            gravity: nonneg("gravity_mps2", p.gravity_mps2)?,
            use_gnss_position: p.use_gnss_position,
            use_gnss_velocity: p.use_gnss_velocity,
            use_imu_orientation: p.use_imu_orientation,
            use_tracking_camera: p.use_tracking_camera,
            tracking_pos_per_rtm: nonneg(
                "tracking_position_sigma_m_per_rtm",
                p.tracking_position_sigma_m_per_rtm,
            )?,
            tracking_rot_per_rtm: nonneg(
                "tracking_rotation_sigma_deg_per_rtm",
                p.tracking_rotation_sigma_deg_per_rtm,
            )?
            .to_radians(),
            tracking_pos_floor: positive(
                "tracking_position_sigma_floor_m",
                p.tracking_position_sigma_floor_m,
            )?,
            tracking_rot_floor: positive(
                "tracking_rotation_sigma_floor_deg",
                p.tracking_rotation_sigma_floor_deg,
            )?
            .to_radians(),
            gate_chi2: nonneg("gnss_gate_chi2", p.gnss_gate_chi2)?,
            sigma_v0: positive("initial_velocity_sigma_mps", p.initial_velocity_sigma_mps)?,
            output_period: Nanos::period_of_hz(rate).max(Nanos(1)),
            gnss_tau: nonneg("gnss_correlation_time_s", p.gnss_correlation_time_s)?,
            orientation_tau: nonneg(
                "orientation_correlation_time_s",
                p.orientation_correlation_time_s,
            )?,
            imu_interval_mean: p.imu_sample_model == ImuSampleModel::IntervalMean,
            relative_yaw: p.orientation_yaw == OrientationYaw::Relative,
            course_min_speed: positive("course_min_speed_mps", p.course_min_speed_mps)?,
            course_min_baseline: positive("course_min_baseline_m", p.course_min_baseline_m)?,
            course_floor: positive("course_sigma_floor_deg", p.course_sigma_floor_deg)?
                .to_radians(),
            use_wheel: p.use_wheel_odometry,
            use_gnss_heading: p.use_gnss_heading,
            wheel_speed_sigma: positive("wheel_speed_sigma_mps", p.wheel_speed_sigma_mps)?,
            wheel_slip: nonneg("wheel_slip_fraction", p.wheel_slip_fraction)?,
            wheel_lateral_sigma: positive("wheel_lateral_sigma_mps", p.wheel_lateral_sigma_mps)?,
            wheel_vertical_sigma: positive("wheel_vertical_sigma_mps", p.wheel_vertical_sigma_mps)?,
            wheel_gate_chi2: nonneg("wheel_gate_chi2", p.wheel_gate_chi2)?,
            wheel_tau: nonneg("wheel_correlation_time_s", p.wheel_correlation_time_s)?,
            wheel_calibration_length: nonneg(
                "wheel_calibration_length_m",
                p.wheel_calibration_length_m,
            )?,
        })
    }
}

/// One IMU sample in SI units, IMU frame.
#[derive(Copy, Clone, Debug, PartialEq)]
struct ImuSample {
    t: Nanos,
    /// Specific force, m/s².
    f: Vector3<f64>,
    /// Angular rate, rad/s.
    w: Vector3<f64>,
}

impl ImuSample {
    fn from_msg(m: &ImuMsg) -> ImuSample {
        ImuSample {
            t: m.stamp,
            f: m.linear_acceleration,
            w: m.angular_velocity,
        }
    }
}

/// The IMU input between two samples: the second sample held (interval means), linear
/// interpolation (point samples), or the first sample held across a gap.
struct Interval {
    a: ImuSample,
    b: ImuSample,
    hold: bool,
    mean: bool,
}

impl Interval {
    fn at(&self, t: Nanos) -> (Vector3<f64>, Vector3<f64>) {
        if self.hold || self.b.t <= self.a.t {
            return (self.a.f, self.a.w);
        }
        if self.mean {
            return (self.b.f, self.b.w);
        }
        let s = ((t - self.a.t).as_nanos() as f64 / (self.b.t - self.a.t).as_nanos() as f64)
            .clamp(0.0, 1.0);
        (
            self.a.f + (self.b.f - self.a.f) * s,
            self.a.w + (self.b.w - self.a.w) * s,
        )
    }
}

/// A measurement waiting for its stamp's group to be complete.
#[derive(Clone, Debug)]
enum Pending {
    GnssPosition {
        /// Antenna ENU position, m.
        z: Vector3<f64>,
        cov: Matrix3<f64>,
        /// Antenna in the IMU frame, m.
        r_ia: Vector3<f64>,
    },
    GnssVelocity {
        z: Vector3<f64>,
        cov: Matrix3<f64>,
        r_ia: Vector3<f64>,
    },
    Orientation {
        /// Measured `world_from_imu`.
        q: UnitQuaternion<f64>,
        /// Error covariance about the world axes, rad².
        cov_world: Matrix3<f64>,
    },
    /// A heading from the course over ground (`yaw = "relative"`, kind 4) or a
    /// dual-antenna receiver (kind 6).
    Course {
        /// Heading of the body's forward axis, rad counter-clockwise from east.
        z: f64,
        /// Its variance, rad².
        var: f64,
        /// Index in [`KIND_NAMES`].
        kind: usize,
    },
    Tracking {
        /// The moving frame of the odometry.
        child: FrameId,
        imu_from_cam: Isometry3<f64>,
        odom_from_cam: Isometry3<f64>,
    },
    /// Wheel odometry: the velocity of its moving frame `o` in `o`.
    Wheel {
        z: Vector3<f64>,
        /// Per-axis variance, m²/s².
        var: Vector3<f64>,
        imu_from_o: Isometry3<f64>,
    },
}

/// The previous tracking-camera message, the one the clone was taken at.
#[derive(Clone, Debug)]
struct PrevTracking {
    t: Nanos,
    child: FrameId,
    odom_from_cam: Isometry3<f64>,
}

/// The running filter.
#[derive(Clone, Debug)]
struct Filter {
    /// Time of the state.
    t: Nanos,
    core: InsCore,
    /// Information matrix after the last correction.
    info: Mat15,
    /// Information vector after the last correction (0 after the injection).
    info_vec: Vec15,
    last_imu: ImuSample,
    /// Angular rate at `t`, rad/s (for the GNSS velocity lever arm).
    omega: Vector3<f64>,
    prev_tracking: Option<PrevTracking>,
    last_fix_used: Nanos,
    /// GNSS fixes rejected by the gate since the last accepted one.
    gated_in_a_row: u32,
    last_wheel_used: Nanos,
    /// Online wheel scale calibration ([`calibrate_wheel_scale`]).
    wheel_scale: WheelScale,
    /// Wheel readings rejected by the slip gate since the last accepted one.
    wheel_gated_in_a_row: u32,
    last_orientation_used: Nanos,
    last_orientation_queued: Option<Nanos>,
    next_output: Nanos,
    output_due: bool,
}

/// What the filter remembers before it can start.
#[derive(Clone, Debug, Default)]
struct PreInit {
    imu: Option<(ImuSample, UnitQuaternion<f64>, Matrix3<f64>)>,
    fix: Option<GnssFixMsg>,
    vel: Option<GnssVelocityMsg>,
    /// The newest course over ground or dual-antenna heading: stamp, heading (rad),
    /// variance (rad²), which of the two.
    course: Option<(Nanos, f64, f64, &'static str)>,
    last_stamp: Option<Nanos>,
}

/// Longest time between the two fixes of a course chord.
const MAX_CHORD_TIME: Nanos = Nanos::from_secs(10);

/// The course over ground from the GNSS track (`orientation_yaw = "relative"`): from
/// GNSS velocity, or from the chord between two fixes, corrected to the heading at the
/// chord's end with the yaw the gyro turned through meanwhile (half of it: the chord of
/// a steady turn points along the mean heading).
#[derive(Clone, Debug, Default)]
struct CourseTracker {
    /// World yaw the gyro turned through since the start, rad (the world z component of
    /// the rate: independent of the heading, so the AHRS's tilt is enough before the
    /// filter starts).
    yaw_turned: f64,
    last_imu: Option<Nanos>,
    /// Where the next chord starts: stamp, antenna ENU x/y, horizontal variance per axis
    /// (m²), `yaw_turned` then.
    anchor: Option<(Nanos, [f64; 2], f64, f64)>,
    /// A GNSS velocity message has been seen: chords are not used.
    velocity_seen: bool,
}

impl CourseTracker {
    fn on_imu(&mut self, t: Nanos, w: &Vector3<f64>, world_from_imu: &UnitQuaternion<f64>) {
        if let Some(l) = self.last_imu
            && t > l
            && t - l <= MAX_IMU_GAP
        {
            self.yaw_turned += (world_from_imu * w).z * (t - l).as_secs_f64();
        }
        self.last_imu = Some(t);
    }

    /// A course from a valid fix's chord: heading (rad) and variance (rad²).
    fn chord(
        &mut self,
        cfg: &Config,
        t: Nanos,
        p: &Vector3<f64>,
        cov: &Matrix3<f64>,
    ) -> Option<(f64, f64)> {
        if self.velocity_seen {
            return None;
        }
        let var = (0.5 * (cov[(0, 0)] + cov[(1, 1)])).max(POSITION_FLOOR_M * POSITION_FLOOR_M);
        let here = ([p.x, p.y], var, self.yaw_turned);
        let Some((ta, a, var_a, yaw_a)) = self.anchor else {
            self.anchor = Some((t, here.0, here.1, here.2));
            return None;
        };
        if t <= ta || t - ta > MAX_CHORD_TIME || !var.is_finite() {
            self.anchor = Some((t, here.0, here.1, here.2));
            return None;
        }
        let (dx, dy) = (p.x - a[0], p.y - a[1]);
        let d = dx.hypot(dy);
        let chord_var = (var + var_a) / (d * d);
        if d < cfg.course_min_baseline || chord_var > 1.0 / 36.0 {
            return None;
        }
        self.anchor = Some((t, here.0, here.1, here.2));
        let turned = self.yaw_turned - yaw_a;
        Some((
            dy.atan2(dx) + 0.5 * turned,
            chord_var + cfg.course_floor * cfg.course_floor + (0.25 * turned).powi(2),
        ))
    }

    /// A course from a GNSS velocity: heading (rad) and variance (rad²).
    fn velocity(&mut self, cfg: &Config, m: &GnssVelocityMsg) -> Option<(f64, f64)> {
        self.velocity_seen = true;
        let v = m.velocity_in_world;
        let speed = v.x.hypot(v.y);
        let var_v = 0.5 * (m.covariance[(0, 0)] + m.covariance[(1, 1)]);
        if speed.is_nan() || speed < cfg.course_min_speed || !var_v.is_finite() || var_v < 0.0 {
            return None;
        }
        Some((
            v.y.atan2(v.x),
            (var_v + VELOCITY_FLOOR_MPS * VELOCITY_FLOOR_MPS) / (speed * speed)
                + cfg.course_floor * cfg.course_floor,
        ))
    }
}

/// The Extended Information Filter (source name `eif`).
#[derive(Clone, Debug)]
pub struct Eif {
    cfg: Config,
    transforms: StaticTransforms,
    enu: LocalEnu,
    /// The Earth's rotation in the world frame, rad/s (zero without `earth_rate`).
    earth_rate_in_world: Vector3<f64>,
    imu_frame: Option<FrameId>,
    /// `imu_from_body`, m.
    imu_from_body: Isometry3<f64>,
    /// `imu_from_<frame>` for frames seen so far.
    frame_cache: Vec<(FrameId, Isometry3<f64>)>,
    pre: PreInit,
    course: CourseTracker,
    /// The IMU's noise measured while standing.
    still: StillMeter,
    filter: Option<Filter>,
    pending: VecDeque<(Nanos, Pending)>,
    group: Vec<Pending>,
    stats: EstimatorStats,
    trajectory: Trajectory,
}

/// Weight of a correlated reading relative to an independent one is `(1 − r)/(1 + r)`
/// with `r = exp(−dt/τ)` (first-order Gauss-Markov error sampled `dt` after the
/// previous reading used); the covariance is inflated by the inverse.
fn correlation_inflation(tau_s: f64, dt: Nanos) -> f64 {
    if tau_s <= 0.0 {
        return 1.0;
    }
    let dt_s = dt.as_secs_f64().max(MIN_CORRELATION_DT_S);
    let r = (-dt_s / tau_s).exp();
    (1.0 + r) / (1.0 - r)
}

/// The squared Mahalanobis distance `yᵀS⁻¹y` of a measurement's residual, `S = HPHᵀ + R`
/// (the NIS); `None` when `S` is not positive definite or the result is NaN.
fn mahalanobis2<const M: usize>(
    lin: &Linearized<M>,
    p: &Mat15,
    r: &SMatrix<f64, M, M>,
) -> Option<f64> {
    let s = lin.h * p * lin.h.transpose() + r;
    let c = Cholesky::new(s)?;
    let d2 = lin.residual.dot(&c.solve(&lin.residual));
    (!d2.is_nan()).then_some(d2)
}

/// Adds `Hᵀ R⁻¹ H` and `Hᵀ R⁻¹ y` to the information sums; `None` when `R` is not
/// positive definite.
fn add_information<const M: usize>(
    lambda: &mut Mat15,
    eta: &mut Vec15,
    lin: &Linearized<M>,
    r: &SMatrix<f64, M, M>,
) -> Option<()> {
    let r_inv = Cholesky::<f64, Const<M>>::new(*r)?.inverse();
    let ht_rinv = lin.h.transpose() * r_inv;
    let add = ht_rinv * lin.h;
    let add_eta = ht_rinv * lin.residual;
    if !add.iter().chain(add_eta.iter()).all(|c| c.is_finite()) {
        return None;
    }
    *lambda += add;
    *eta += add_eta;
    Some(())
}

fn symmetrize(m: &mut Mat15) {
    for i in 0..STATE_DIM {
        for j in (i + 1)..STATE_DIM {
            let a = 0.5 * (m[(i, j)] + m[(j, i)]);
            m[(i, j)] = a;
            m[(j, i)] = a;
        }
    }
}

/// Per-kind counts of one correction group.
#[derive(Default)]
struct GroupCounts {
    kinds: [u64; 7],
}
const KIND_NAMES: [&str; 7] = [
    "gnss_fix",
    "gnss_velocity",
    "imu_orientation",
    "tracking_odom",
    "gnss_course",
    "wheel_odom",
    "gnss_heading",
];
/// The Earth's rotation rate, rad/s (WGS84).
pub const EARTH_RATE_RADPS: f64 = 7.292_115e-5;
/// What a heading before the start came from (init note).
const COURSE: &str = "course over ground";
/// See [`COURSE`].
const HEADING: &str = "dual-antenna heading";

impl Eif {
    /// A filter with `[estimators.eif]` parameters, the robot's static transforms and the
    /// world frame's geodetic origin. Errors on a parameter out of range or a static
    /// transform set without a body frame.
    pub fn new(
        params: &EifParams,
        transforms: StaticTransforms,
        enu: LocalEnu,
    ) -> Result<Eif, EstimatorError> {
        let cfg = Config::from_params(params)?;
        super::require_body_frame(&transforms, "eif")?;
        // Ω_E·(0, cos φ, sin φ) in ENU at the origin's latitude φ (WGS84 Ω_E).
        let earth_rate_in_world = if params.earth_rate {
            let (s, c) = enu.origin().lat_deg.to_radians().sin_cos();
            Vector3::new(0.0, c, s) * EARTH_RATE_RADPS
        } else {
            Vector3::zeros()
        };
        Ok(Eif {
            cfg,
            transforms,
            enu,
            earth_rate_in_world,
            imu_frame: None,
            imu_from_body: Isometry3::identity(),
            frame_cache: Vec::new(),
            pre: PreInit::default(),
            course: CourseTracker::default(),
            still: StillMeter::default(),
            filter: None,
            pending: VecDeque::new(),
            group: Vec::new(),
            stats: EstimatorStats::default(),
            trajectory: Trajectory::new(),
        })
    }

    /// True once the filter has started.
    pub fn is_initialized(&self) -> bool {
        self.filter.is_some()
    }

    /// The nominal state (IMU frame) and its time, once initialised.
    pub fn state(&self) -> Option<(Nanos, &NavState)> {
        self.filter.as_ref().map(|f| (f.t, &f.core.nav))
    }

    /// The current error covariance `P` (moment form, as propagated since the last
    /// correction), once initialised.
    pub fn covariance(&self) -> Option<&Mat15> {
        self.filter.as_ref().map(|f| &f.core.cov)
    }

    /// The information pair `(Λ, η)` after the last correction (`η = 0` after the
    /// injection), once a correction has happened.
    pub fn information(&self) -> Option<(&Mat15, &Vec15)> {
        self.filter.as_ref().map(|f| (&f.info, &f.info_vec))
    }

    /// The output trajectory, consumed.
    pub fn into_trajectory(self) -> Trajectory {
        self.trajectory
    }

    /// `imu_from_<frame>`; `None` (counted as `unknown_frame`) when the frame or the IMU
    /// frame is not known.
    fn imu_from(&mut self, frame: &FrameId) -> Option<Isometry3<f64>> {
        if let Some((_, iso)) = self.frame_cache.iter().find(|(f, _)| f == frame) {
            return Some(*iso);
        }
        let imu = self.imu_frame.as_ref()?;
        let iso = self.transforms.between(imu.as_str(), frame.as_str());
        match iso {
            Some(iso) => {
                self.frame_cache.push((frame.clone(), iso));
                Some(iso)
            }
            None => {
                self.stats.count_rejected("unknown_frame");
                None
            }
        }
    }

    /// Sets the IMU frame from the first IMU message; false if it is unknown or differs.
    fn check_imu_frame(&mut self, frame: &FrameId) -> bool {
        match &self.imu_frame {
            Some(f) if f == frame => true,
            Some(_) => {
                self.stats.count_rejected("imu_frame_changed");
                false
            }
            None => match self.transforms.body_from(frame.as_str()) {
                Some(body_from_imu) => {
                    self.imu_frame = Some(frame.clone());
                    self.imu_from_body = body_from_imu.inverse();
                    true
                }
                None => {
                    self.stats.count_rejected("unknown_frame");
                    false
                }
            },
        }
    }

    fn pre_init(&mut self, msg: &Message) {
        match msg {
            Message::Imu(m) => {
                if self.check_imu_frame(&m.frame_id) {
                    self.pre.imu = m
                        .orientation
                        .map(|q| (ImuSample::from_msg(m), q, m.orientation_covariance));
                    if let Some(q) = m.orientation {
                        self.course.on_imu(m.stamp, &m.angular_velocity, &q);
                    }
                }
                self.stats.count_rejected("before_init");
            }
            Message::GnssFix(m) => {
                if m.status == FixStatus::NoFix {
                    self.stats.count_rejected("gnss_no_fix");
                } else {
                    if self.cfg.relative_yaw {
                        let p = self.enu.enu_from_geodetic(&m.position);
                        if let Some((z, var)) =
                            self.course
                                .chord(&self.cfg, m.stamp, &p, &m.position_covariance)
                        {
                            self.pre.course = Some((m.stamp, z, var, COURSE));
                        }
                    }
                    self.pre.fix = Some(m.clone());
                    self.stats.count_rejected("before_init");
                }
            }
            Message::GnssVelocity(m) => {
                if self.cfg.relative_yaw
                    && let Some((z, var)) = self.course.velocity(&self.cfg, m)
                {
                    self.pre.course = Some((m.stamp, z, var, COURSE));
                }
                self.pre.vel = Some(m.clone());
                self.stats.count_rejected("before_init");
            }
            Message::TrackingOdom(_) => self.stats.count_rejected("before_init"),
            Message::GnssHeading(m) => {
                if self.cfg.use_gnss_heading {
                    // A dual-antenna heading is better than a course: it holds standing.
                    self.pre.course = Some((m.stamp, m.heading_rad, m.variance_rad2, HEADING));
                    self.stats.count_rejected("before_init");
                }
            }
            Message::WheelOdom(_) if self.cfg.use_wheel => self.stats.count_rejected("before_init"),
            Message::WheelOdom(_)
            | Message::Image(_)
            | Message::CameraInfo(_)
            | Message::GnssSky(_) => {}
        }
    }

    /// Starts the filter at the latest AHRS sample if a recent valid fix is known.
    fn try_init(&mut self) {
        let (Some((imu, mut q, mut q_cov)), Some(fix)) = (self.pre.imu, self.pre.fix.clone())
        else {
            return;
        };
        if fix.stamp > imu.t || imu.t - fix.stamp > MAX_INIT_LAG {
            return;
        }
        let Some(imu_from_antenna) = self.imu_from(&fix.frame_id) else {
            return;
        };
        let r_ia = imu_from_antenna.translation.vector;
        let mut heading_note = String::new();
        if self.cfg.relative_yaw {
            // The heading from the course over ground of the same epoch; roll and pitch
            // from the AHRS (a rotation about world z changes neither).
            let Some((tc, z, var, what)) = self.pre.course else {
                return;
            };
            if (tc - fix.stamp).as_nanos().abs() > MAX_INIT_LAG.as_nanos() || tc > imu.t {
                return;
            }
            let forward = self.imu_from_body.rotation * Vector3::x();
            let psi = measurement::heading_model(&q, &forward);
            q = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), z - psi) * q;
            for k in 0..3 {
                q_cov[(2, k)] = 0.0;
                q_cov[(k, 2)] = 0.0;
            }
            q_cov[(2, 2)] = var;
            heading_note = format!(
                ", heading {:.1}° from the {what} (±{:.1}°)",
                z.to_degrees(),
                var.sqrt().to_degrees()
            );
        }
        let rot = q.to_rotation_matrix().into_inner();
        let p_ant = self.enu.enu_from_geodetic(&fix.position);
        let mut v = Vector3::zeros();
        if let Some(vel) = self.pre.vel.clone()
            && vel.stamp <= imu.t
            && (vel.stamp - fix.stamp).as_nanos().abs() <= MAX_INIT_LAG.as_nanos()
            && let Some(imu_from_vel) = self.imu_from(&vel.frame_id)
        {
            v = vel.velocity_in_world - rot * imu.w.cross(&imu_from_vel.translation.vector);
        }
        let lag = (imu.t - fix.stamp).as_secs_f64();
        let p = p_ant - rot * r_ia + v * lag;
        let gravity = if self.cfg.gravity > 0.0 {
            self.cfg.gravity
        } else {
            normal_gravity(fix.position.lat_deg, fix.position.alt_m)
        };
        // P0: δθ from the AHRS (world axes → local), δp from the fix and the lever arm
        // (δp = n_fix + R[r_ia]×δθ + lag·δv), δv from the configured sigma.
        let s_th = rot.transpose() * q_cov * rot
            + Matrix3::identity() * (ROTATION_FLOOR_RAD * ROTATION_FLOOR_RAD);
        let a = rot * skew(&r_ia);
        let s_v = Matrix3::identity() * (self.cfg.sigma_v0 * self.cfg.sigma_v0);
        let s_p = fix.position_covariance
            + Matrix3::identity() * (POSITION_FLOOR_M * POSITION_FLOOR_M)
            + a * s_th * a.transpose()
            + s_v * (lag * lag);
        let mut cov = Mat15::zeros();
        cov.fixed_view_mut::<3, 3>(IDX_P, IDX_P).copy_from(&s_p);
        cov.fixed_view_mut::<3, 3>(IDX_V, IDX_V).copy_from(&s_v);
        cov.fixed_view_mut::<3, 3>(IDX_TH, IDX_TH).copy_from(&s_th);
        cov.fixed_view_mut::<3, 3>(IDX_P, IDX_TH)
            .copy_from(&(a * s_th));
        cov.fixed_view_mut::<3, 3>(IDX_TH, IDX_P)
            .copy_from(&(a * s_th).transpose());
        cov.fixed_view_mut::<3, 3>(IDX_P, IDX_V)
            .copy_from(&(s_v * lag));
        cov.fixed_view_mut::<3, 3>(IDX_V, IDX_P)
            .copy_from(&(s_v * lag));
        for i in IDX_PC..STATE_DIM {
            cov[(i, i)] = INACTIVE_CLONE_VARIANCE;
        }
        let Some(info) = Cholesky::new(cov).map(|c| c.inverse()) else {
            self.stats.count_rejected("numerical_skip");
            return;
        };
        let nav = NavState {
            p,
            v,
            q,
            p_clone: p,
            q_clone: q,
        };
        self.filter = Some(Filter {
            t: imu.t,
            core: InsCore::new(nav, cov, gravity),
            info,
            info_vec: Vec15::zeros(),
            last_imu: imu,
            omega: imu.w,
            prev_tracking: None,
            last_fix_used: fix.stamp,
            gated_in_a_row: 0,
            last_wheel_used: fix.stamp,
            wheel_scale: WheelScale::default(),
            wheel_gated_in_a_row: 0,
            last_orientation_used: imu.t,
            last_orientation_queued: Some(imu.t),
            next_output: imu.t + self.cfg.output_period,
            output_due: true,
        });
        self.stats.notes.push(format!(
            "initialized at {} from a {} fix at {} (gravity {gravity:.6} m/s²){heading_note}",
            imu.t,
            fix.status.name(),
            fix.stamp
        ));
    }

    /// Applies the group of measurements at the filter's time and writes the pose if an
    /// output is due there.
    fn settle(&mut self) {
        let Some(t) = self.filter.as_ref().map(|f| f.t) else {
            return;
        };
        if self.pending.front().is_some_and(|(s, _)| *s == t) {
            self.apply_group_at(t);
        }
        if self.filter.as_ref().is_some_and(|f| f.output_due) {
            self.emit();
        }
    }

    /// Moves the pending measurements stamped `t` into the group buffer and applies them.
    fn apply_group_at(&mut self, t: Nanos) {
        self.group.clear();
        while self.pending.front().is_some_and(|(s, _)| *s == t) {
            if let Some((_, m)) = self.pending.pop_front() {
                self.group.push(m);
            }
        }
        let group = std::mem::take(&mut self.group);
        self.apply_group(&group);
        self.group = group;
    }

    /// One information-form correction with every measurement of the group.
    fn apply_group(&mut self, group: &[Pending]) {
        let cfg = &self.cfg;
        let stats = &mut self.stats;
        let imu_from_body_rot = self.imu_from_body.rotation;
        let Some(f) = self.filter.as_mut() else {
            return;
        };
        let mut lambda_add = Mat15::zeros();
        let mut eta = Vec15::zeros();
        let mut counts = GroupCounts::default();
        let mut n_info = 0usize;
        let mut recovered = 0u32;
        let mut wheel_recovered = 0u32;
        let mut nis: Vec<f64> = Vec::new();
        let mut reject = |why: &str| stats.count_rejected(why);
        let mut reclone_with: Option<PrevTracking> = None;
        let nav = f.core.nav.clone();
        let rot = nav.q.to_rotation_matrix().into_inner();
        for m in group {
            match m {
                Pending::GnssPosition { z, cov, r_ia } => {
                    let lin = measurement::gnss_position(&nav, r_ia, z);
                    let r = cov + Matrix3::identity() * (POSITION_FLOOR_M * POSITION_FLOOR_M);
                    let Some(d2) = mahalanobis2(&lin, &f.core.cov, &r) else {
                        reject("numerical_skip");
                        continue;
                    };
                    // The consistency record: every fix's NIS against the receiver's and
                    // the filter's claimed uncertainty, gated or not.
                    nis.push(d2);
                    if cfg.gate_chi2 > 0.0 {
                        if d2 > cfg.gate_chi2 {
                            f.gated_in_a_row += 1;
                            if f.gated_in_a_row <= GATE_RECOVERY_FIXES {
                                reject("gnss_gated");
                                continue;
                            }
                            // Every fix for a while disagreed: the filter is lost.
                            // Re-open its position uncertainty to the innovation
                            // and its velocity to the drift rate that explains it.
                            let y = lin.residual;
                            let yy = y * y.transpose();
                            let dt = (f.t - f.last_fix_used).as_secs_f64().max(1.0);
                            let mut pp = f.core.cov.fixed_view_mut::<3, 3>(IDX_P, IDX_P);
                            pp += yy;
                            let mut vv = f.core.cov.fixed_view_mut::<3, 3>(IDX_V, IDX_V);
                            vv += yy / (dt * dt);
                            recovered += 1;
                        }
                        f.gated_in_a_row = 0;
                    }
                    let r_eff = r * correlation_inflation(cfg.gnss_tau, f.t - f.last_fix_used);
                    if add_information(&mut lambda_add, &mut eta, &lin, &r_eff).is_some() {
                        counts.kinds[0] += 1;
                        n_info += 1;
                    } else {
                        reject("numerical_skip");
                    }
                }
                Pending::GnssVelocity { z, cov, r_ia } => {
                    let lin = measurement::gnss_velocity(&nav, r_ia, &f.omega, z);
                    let r = cov + Matrix3::identity() * (VELOCITY_FLOOR_MPS * VELOCITY_FLOOR_MPS);
                    if add_information(&mut lambda_add, &mut eta, &lin, &r).is_some() {
                        counts.kinds[1] += 1;
                        n_info += 1;
                    } else {
                        reject("numerical_skip");
                    }
                }
                Pending::Orientation { q, cov_world } if cfg.relative_yaw => {
                    // Roll and pitch: the world x/y block of the AHRS covariance.
                    let lin = measurement::tilt(&nav, q);
                    let r = (cov_world.fixed_view::<2, 2>(0, 0).into_owned()
                        + nalgebra::Matrix2::identity()
                            * (ROTATION_FLOOR_RAD * ROTATION_FLOOR_RAD))
                        * correlation_inflation(cfg.orientation_tau, f.t - f.last_orientation_used);
                    if add_information(&mut lambda_add, &mut eta, &lin, &r).is_some() {
                        counts.kinds[2] += 1;
                        n_info += 1;
                    } else {
                        reject("numerical_skip");
                    }
                }
                Pending::Orientation { q, cov_world } => {
                    let lin = measurement::orientation(&nav, q);
                    let r = (rot.transpose() * cov_world * rot
                        + Matrix3::identity() * (ROTATION_FLOOR_RAD * ROTATION_FLOOR_RAD))
                        * correlation_inflation(cfg.orientation_tau, f.t - f.last_orientation_used);
                    if add_information(&mut lambda_add, &mut eta, &lin, &r).is_some() {
                        counts.kinds[2] += 1;
                        n_info += 1;
                    } else {
                        reject("numerical_skip");
                    }
                }
                Pending::Course { z, var, kind } => {
                    let forward = imu_from_body_rot * Vector3::x();
                    // Driving backwards: the track points the other way.
                    let mut z = *z;
                    if measurement::wrap_pi(z - measurement::heading_model(&nav.q, &forward)).abs()
                        > std::f64::consts::FRAC_PI_2
                    {
                        z += std::f64::consts::PI;
                    }
                    let lin = measurement::course(&nav, &forward, z);
                    let r = SMatrix::<f64, 1, 1>::new(*var);
                    if add_information(&mut lambda_add, &mut eta, &lin, &r).is_some() {
                        counts.kinds[*kind] += 1;
                        n_info += 1;
                    } else {
                        reject("numerical_skip");
                    }
                }
                Pending::Wheel { z, var, imu_from_o } => {
                    let z = if cfg.wheel_calibration_length > 0.0 {
                        calibrate_wheel_scale(f, &nav, imu_from_o, z, cfg.wheel_calibration_length)
                    } else {
                        *z
                    };
                    let lin = measurement::body_velocity(&nav, imu_from_o, &f.omega, &z);
                    let r = Matrix3::from_diagonal(var)
                        * correlation_inflation(cfg.wheel_tau, f.t - f.last_wheel_used);
                    if cfg.wheel_gate_chi2 > 0.0 {
                        let Some(d2) = mahalanobis2(&lin, &f.core.cov, &r) else {
                            reject("numerical_skip");
                            continue;
                        };
                        if d2 > cfg.wheel_gate_chi2 {
                            f.wheel_gated_in_a_row += 1;
                            if f.wheel_gated_in_a_row <= WHEEL_GATE_RECOVERY {
                                reject("wheel_slip_gated");
                                continue;
                            }
                            // A second of wheels disagreeing: the filter's velocity, not
                            // the wheels, is off. Re-open it to the innovation (in world).
                            let to_world = rot * imu_from_o.rotation.to_rotation_matrix();
                            let y = to_world * lin.residual;
                            let mut vv = f.core.cov.fixed_view_mut::<3, 3>(IDX_V, IDX_V);
                            vv += y * y.transpose();
                            wheel_recovered += 1;
                        }
                        f.wheel_gated_in_a_row = 0;
                    }
                    if add_information(&mut lambda_add, &mut eta, &lin, &r).is_some() {
                        counts.kinds[5] += 1;
                        n_info += 1;
                    } else {
                        reject("numerical_skip");
                    }
                }
                Pending::Tracking {
                    child,
                    imu_from_cam,
                    odom_from_cam,
                } => {
                    let this = PrevTracking {
                        t: f.t,
                        child: child.clone(),
                        odom_from_cam: *odom_from_cam,
                    };
                    let prev = reclone_with.as_ref().or(f.prev_tracking.as_ref());
                    match prev {
                        Some(prev) if prev.t == f.t => {
                            reject("tracking_duplicate_stamp");
                            continue;
                        }
                        Some(prev) if f.core.clone_active && prev.child == *child => {
                            // imu_{k-1}_from_imu_k; the odom frame and its world anchor cancel.
                            let delta = imu_from_cam
                                * prev.odom_from_cam.inverse()
                                * odom_from_cam
                                * imu_from_cam.inverse();
                            let dp = delta.translation.vector;
                            let d = dp.norm().sqrt();
                            let sp = cfg.tracking_pos_floor.max(cfg.tracking_pos_per_rtm * d);
                            let sr = cfg.tracking_rot_floor.max(cfg.tracking_rot_per_rtm * d);
                            let r = Matrix6::from_diagonal(&SVector::<f64, 6>::from([
                                sp * sp,
                                sp * sp,
                                sp * sp,
                                sr * sr,
                                sr * sr,
                                sr * sr,
                            ]));
                            let lin = measurement::tracking_relative(&nav, &dp, &delta.rotation);
                            if add_information(&mut lambda_add, &mut eta, &lin, &r).is_some() {
                                counts.kinds[3] += 1;
                                n_info += 1;
                            } else {
                                reject("numerical_skip");
                            }
                        }
                        _ => {
                            // First message of a chain: only the clone is taken.
                            counts.kinds[3] += 1;
                        }
                    }
                    reclone_with = Some(this);
                }
            }
        }
        let mut ok = true;
        if n_info > 0 {
            ok = correct(f, &lambda_add, &eta);
        }
        if ok {
            if counts.kinds[0] > 0 {
                f.last_fix_used = f.t;
            }
            if counts.kinds[2] > 0 {
                f.last_orientation_used = f.t;
            }
            if counts.kinds[5] > 0 {
                f.last_wheel_used = f.t;
            }
        }
        if let Some(prev) = reclone_with {
            f.core.reclone();
            f.prev_tracking = Some(prev);
        }
        for _ in 0..recovered {
            self.stats.count_event("gnss_gate_recovered");
        }
        for _ in 0..wheel_recovered {
            self.stats.count_event("wheel_gate_recovered");
        }
        if !nis.is_empty() {
            let t = self.filter.as_ref().map_or(Nanos(0), |f| f.t);
            let series = self
                .stats
                .gnss_nis
                .get_or_insert_with(|| super::NisSeries::new(3));
            for d2 in nis {
                series.push(t, d2);
            }
        }
        for (k, name) in KIND_NAMES.iter().enumerate() {
            for _ in 0..counts.kinds[k] {
                if ok {
                    self.stats.count_used(name);
                } else {
                    self.stats.count_rejected("numerical_skip");
                }
            }
        }
    }

    /// Appends the body pose at the filter's time, with its covariance.
    fn emit(&mut self) {
        let Some(f) = self.filter.as_mut() else {
            return;
        };
        f.output_due = false;
        let nav = &f.core.nav;
        let world_from_body = nav.world_from_imu() * self.imu_from_body;
        let rot = nav.q.to_rotation_matrix().into_inner();
        // δp_body = δp − R[t_ib]×δθ, world rotation error = R δθ.
        let mut j = SMatrix::<f64, 6, 9>::zeros();
        j.fixed_view_mut::<3, 3>(0, IDX_P)
            .copy_from(&Matrix3::identity());
        j.fixed_view_mut::<3, 3>(0, IDX_TH)
            .copy_from(&(-(rot * skew(&self.imu_from_body.translation.vector))));
        j.fixed_view_mut::<3, 3>(3, IDX_TH).copy_from(&rot);
        let p9 = f.core.cov.fixed_view::<9, 9>(0, 0).into_owned();
        let mut cov = j * p9 * j.transpose();
        cov = (cov + cov.transpose()) * 0.5;
        let finite = cov.iter().all(|c| c.is_finite())
            && world_from_body
                .translation
                .vector
                .iter()
                .all(|c| c.is_finite())
            && world_from_body
                .rotation
                .coords
                .iter()
                .all(|c| c.is_finite());
        if !finite {
            self.stats.count_rejected("non_finite_output");
            return;
        }
        self.trajectory.push(PoseSample {
            stamp: f.t,
            world_from_body,
            covariance: Some(Box::new(cov)),
        });
    }

    fn on_imu(&mut self, m: &ImuMsg) {
        if !self.check_imu_frame(&m.frame_id) {
            return;
        }
        let noise = self.cfg.noise;
        let Some(f) = self.filter.as_mut() else {
            return;
        };
        let mut sample = ImuSample::from_msg(m);
        // What the gyro senses of the Earth's rotation is not the body turning.
        sample.w -= f
            .core
            .nav
            .q
            .inverse_transform_vector(&self.earth_rate_in_world);
        if sample.t <= f.last_imu.t {
            self.stats.count_rejected("imu_duplicate_stamp");
            return;
        }
        let hold = sample.t - f.last_imu.t > MAX_IMU_GAP;
        if hold {
            self.stats.count_event("imu_gap_bridged");
        }
        let interval = Interval {
            a: f.last_imu,
            b: sample,
            hold,
            mean: self.cfg.imu_interval_mean,
        };
        // Measurements inside the interval: propagate to each, correct, go on.
        while let Some(s) = self.pending.front().map(|(s, _)| *s)
            && s < sample.t
        {
            if let Some(f) = self.filter.as_mut() {
                propagate_to(f, s, &interval, &noise);
            }
            self.apply_group_at(s);
        }
        let Some(f) = self.filter.as_mut() else {
            return;
        };
        propagate_to(f, sample.t, &interval, &noise);
        self.still
            .push(sample.t, &sample.w, &sample.f, f.core.nav.v.norm());
        if self.cfg.relative_yaw {
            self.course.on_imu(sample.t, &sample.w, &f.core.nav.q);
        }
        let half_step = Nanos((sample.t - f.last_imu.t).as_nanos() / 2);
        f.last_imu = sample;
        if sample.t + half_step >= f.next_output {
            f.output_due = true;
            while f.next_output <= sample.t + half_step {
                f.next_output += self.cfg.output_period;
            }
        }
        self.stats.count_used("imu");
        if self.cfg.use_imu_orientation
            && let Some(q) = m.orientation
        {
            let tol = Nanos::MILLISECOND;
            let decimate = self.cfg.orientation_tau > 0.0
                && f.last_orientation_queued
                    .is_some_and(|l| sample.t - l + tol < ORIENTATION_MIN_INTERVAL);
            if decimate {
                self.stats.count_rejected("imu_orientation_decimated");
            } else {
                f.last_orientation_queued = Some(sample.t);
                self.pending.push_back((
                    sample.t,
                    Pending::Orientation {
                        q,
                        cov_world: m.orientation_covariance,
                    },
                ));
            }
        }
    }

    fn on_fix(&mut self, m: &GnssFixMsg) {
        if m.status == FixStatus::NoFix {
            self.stats.count_rejected("gnss_no_fix");
            return;
        }
        if self.cfg.relative_yaw {
            let p = self.enu.enu_from_geodetic(&m.position);
            if let Some((z, var)) =
                self.course
                    .chord(&self.cfg, m.stamp, &p, &m.position_covariance)
            {
                self.pending
                    .push_back((m.stamp, Pending::Course { z, var, kind: 4 }));
            }
        }
        if !self.cfg.use_gnss_position {
            return;
        }
        let Some(iso) = self.imu_from(&m.frame_id) else {
            return;
        };
        self.pending.push_back((
            m.stamp,
            Pending::GnssPosition {
                z: self.enu.enu_from_geodetic(&m.position),
                cov: m.position_covariance,
                r_ia: iso.translation.vector,
            },
        ));
    }

    fn on_velocity(&mut self, m: &GnssVelocityMsg) {
        if self.cfg.relative_yaw
            && let Some((z, var)) = self.course.velocity(&self.cfg, m)
        {
            self.pending
                .push_back((m.stamp, Pending::Course { z, var, kind: 4 }));
        }
        if !self.cfg.use_gnss_velocity {
            return;
        }
        let Some(iso) = self.imu_from(&m.frame_id) else {
            return;
        };
        self.pending.push_back((
            m.stamp,
            Pending::GnssVelocity {
                z: m.velocity_in_world,
                cov: m.covariance,
                r_ia: iso.translation.vector,
            },
        ));
    }

    fn on_wheel(&mut self, m: &OdometryMsg) {
        if !self.cfg.use_wheel {
            return;
        }
        let Some(imu_from_o) = self.imu_from(&m.child_frame_id) else {
            return;
        };
        let cfg = &self.cfg;
        let measured = |i: usize| {
            let v = m.twist_covariance[(i, i)];
            (v.is_finite() && v > 0.0 && v < WHEEL_UNMEASURED_VARIANCE).then_some(v)
        };
        let speed_var = |v: f64, reported: Option<f64>| {
            let model = cfg.wheel_speed_sigma.powi(2) + (cfg.wheel_slip * v).powi(2);
            reported.map_or(model, |r| r.max(model))
        };
        let vx = m.linear_velocity.x;
        let (zy, var_y) = match measured(1) {
            Some(r) => (m.linear_velocity.y, speed_var(m.linear_velocity.y, Some(r))),
            None => (0.0, cfg.wheel_lateral_sigma.powi(2)),
        };
        let z = Vector3::new(vx, zy, 0.0);
        let var = Vector3::new(
            speed_var(vx, measured(0)),
            var_y,
            cfg.wheel_vertical_sigma.powi(2),
        );
        self.pending
            .push_back((m.stamp, Pending::Wheel { z, var, imu_from_o }));
    }

    fn on_tracking(&mut self, m: &OdometryMsg) {
        if !self.cfg.use_tracking_camera {
            return;
        }
        let Some(imu_from_cam) = self.imu_from(&m.child_frame_id) else {
            return;
        };
        self.pending.push_back((
            m.stamp,
            Pending::Tracking {
                child: m.child_frame_id.clone(),
                imu_from_cam,
                odom_from_cam: m.pose,
            },
        ));
    }
}

/// Wheel speeds are scaled by [`calibrate_wheel_scale`] only once this many metres of
/// calibration have been collected, and never by more than this range.
const WHEEL_SCALE_MIN_M: f64 = 5.0;
/// The range of the wheel scale factor (a skid-steer over-reads by slip, a few per cent;
/// tyre wear or a wrong radius by a few more).
const WHEEL_SCALE_RANGE: (f64, f64) = (0.8, 1.25);
/// The filter's velocity must be known this well (largest 1σ, m/s) for a wheel reading
/// to calibrate the scale.
const WHEEL_SCALE_MAX_SIGMA_MPS: f64 = 0.05;
/// Slowest wheel speed that calibrates the scale, m/s.
const WHEEL_SCALE_MIN_SPEED_MPS: f64 = 0.3;

/// The wheel reading `z` with its measured speeds scaled by the online scale factor, and
/// the factor's sums updated. While the filter's velocity is well known (GNSS), each
/// reading adds its forward speed `z_x` and the filter's predicted one `v̂_x` to
/// distance-forgetting least squares `k = Σ v̂_x z_x / Σ z_x²` (each reading's weight
/// decays by `exp(−d/L)` over the `d` metres driven after it; `L` =
/// `wheel_calibration_length_m`); once [`WHEEL_SCALE_MIN_M`] of driving have been
/// collected, `z` is multiplied by `k` (clamped to [`WHEEL_SCALE_RANGE`]). A skid-steer's
/// encoders over-read the distance by the tracks' slip, a bias that no amount of white
/// noise in the model absorbs: through a GNSS outage the scaled speeds hold the track.
fn calibrate_wheel_scale(
    f: &mut Filter,
    nav: &NavState,
    imu_from_o: &Isometry3<f64>,
    z: &Vector3<f64>,
    length_m: f64,
) -> Vector3<f64> {
    let w = &mut f.wheel_scale;
    let dt = w.last_t.map_or(0.0, |t| (f.t - t).as_secs_f64());
    w.last_t = Some(f.t);
    let sigma_v = f
        .core
        .cov
        .fixed_view::<3, 3>(IDX_V, IDX_V)
        .diagonal()
        .max()
        .max(0.0)
        .sqrt();
    if sigma_v <= WHEEL_SCALE_MAX_SIGMA_MPS && z.x.abs() >= WHEEL_SCALE_MIN_SPEED_MPS {
        let v_hat = measurement::body_velocity_model(nav, imu_from_o, &f.omega).x;
        let d = (z.x.abs() * dt).min(length_m);
        let keep = (-d / length_m).exp();
        w.num = w.num * keep + v_hat * z.x;
        w.den = w.den * keep + z.x * z.x;
        w.dist = w.dist * keep + d;
        if w.dist >= WHEEL_SCALE_MIN_M {
            w.ready = true;
        }
    }
    if !(w.ready && w.den > 0.0 && w.num.is_finite()) {
        return *z;
    }
    let k = (w.num / w.den).clamp(WHEEL_SCALE_RANGE.0, WHEEL_SCALE_RANGE.1);
    w.k = k;
    Vector3::new(z.x * k, z.y * k, z.z)
}

/// The state of [`calibrate_wheel_scale`].
#[derive(Clone, Debug, Default)]
struct WheelScale {
    /// Forgetting sums of `v̂_x·z_x` and `z_x²`.
    num: f64,
    den: f64,
    /// Forgetting sum of the distance calibrated on, m.
    dist: f64,
    last_t: Option<Nanos>,
    /// Once [`WHEEL_SCALE_MIN_M`] have been collected.
    ready: bool,
    /// The factor last applied.
    k: f64,
}

/// Propagates the filter from its time to `t` (inside `interval`).
fn propagate_to(f: &mut Filter, t: Nanos, interval: &Interval, noise: &ProcessNoise) {
    if t <= f.t {
        return;
    }
    let total = (t - f.t).as_secs_f64();
    if interval.hold {
        let n = ((total / GAP_SUBSTEP_S).ceil() as usize).clamp(1, MAX_GAP_SUBSTEPS);
        let dt = total / n as f64;
        for _ in 0..n {
            f.core.predict(dt, &interval.a.f, &interval.a.w, noise);
        }
    } else {
        let (fa, wa) = interval.at(f.t);
        let (fb, wb) = interval.at(t);
        f.core
            .predict(total, &((fa + fb) * 0.5), &((wa + wb) * 0.5), noise);
    }
    f.omega = interval.at(t).1;
    f.t = t;
}

/// The information-form correction: `Λ⁺ = P⁻¹ + ΣHᵀR⁻¹H`, `δx = Λ⁺⁻¹ η⁺`, inject, `P =
/// Λ⁺⁻¹`. Returns false (state untouched) when a factorisation fails.
fn correct(f: &mut Filter, lambda_add: &Mat15, eta: &Vec15) -> bool {
    let Some(prior) = Cholesky::new(f.core.cov) else {
        return false;
    };
    let lambda = prior.inverse() + lambda_add;
    let Some(chol) = Cholesky::new(lambda) else {
        return false;
    };
    let mut dx = chol.solve(eta);
    let mut cov = chol.inverse();
    if !dx.iter().chain(cov.iter()).all(|c| c.is_finite()) {
        return false;
    }
    if !f.core.clone_active {
        dx.fixed_rows_mut::<6>(IDX_PC).fill(0.0);
    }
    symmetrize(&mut cov);
    f.core.nav = f.core.nav.boxplus(&dx);
    f.core.cov = cov;
    f.info = lambda;
    // The error mean has been injected: η = Λ δx − Λ δx = 0.
    f.info_vec = Vec15::zeros();
    true
}

impl Estimator for Eif {
    fn name(&self) -> &'static str {
        "eif"
    }

    fn handle(&mut self, msg: &Message) {
        let s = msg.stamp();
        if self.filter.is_none() {
            if self.pre.last_stamp.is_some_and(|l| s > l) {
                self.try_init();
            }
            if self.filter.is_none() {
                self.pre_init(msg);
                self.pre.last_stamp = Some(s);
                return;
            }
        }
        let Some(t) = self.filter.as_ref().map(|f| f.t) else {
            return;
        };
        if s < t {
            self.stats.count_rejected("out_of_order");
            return;
        }
        if s > t {
            self.settle();
        }
        match msg {
            Message::Imu(m) => self.on_imu(m),
            Message::GnssFix(m) => self.on_fix(m),
            Message::GnssVelocity(m) => self.on_velocity(m),
            Message::TrackingOdom(m) => self.on_tracking(m),
            Message::WheelOdom(m) => self.on_wheel(m),
            Message::GnssHeading(m) => {
                if self.cfg.use_gnss_heading {
                    self.pending.push_back((
                        m.stamp,
                        Pending::Course {
                            z: m.heading_rad,
                            var: m.variance_rad2,
                            kind: 6,
                        },
                    ));
                }
            }
            Message::Image(_) | Message::CameraInfo(_) | Message::GnssSky(_) => {}
        }
    }

    fn finish(&mut self) {
        if self.filter.is_none() {
            self.try_init();
        }
        self.settle();
        while self.pending.pop_front().is_some() {
            self.stats.count_rejected("after_last_imu");
        }
        if let Some((g, a)) = self.still.densities() {
            let p = &self.cfg.imu;
            let profile = if p.name.is_empty() {
                "the densities given".to_string()
            } else {
                format!("imu_profile \"{}\" ({})", p.name, p.grade)
            };
            self.stats.notes.push(format!(
                "IMU noise measured over {} s standing still: gyro {g:.4} °/s/√Hz, accel \
                 {a:.0} µg/√Hz ({profile}: {} °/s/√Hz, {} µg/√Hz)",
                self.still.windows, p.gyro_dps_rthz, p.accel_ug_rthz
            ));
            let far = |measured: f64, model: f64| measured > IMU_NOISE_WARN_FACTOR * model;
            if far(g, p.gyro_dps_rthz) || far(a, p.accel_ug_rthz) {
                let suggest: Vec<&str> = IMU_PROFILES
                    .iter()
                    .filter(|x| !far(g, x.gyro_dps_rthz) && !far(a, x.accel_ug_rthz))
                    .map(|x| x.name)
                    .collect();
                self.stats.notes.push(format!(
                    "warning: the IMU is noisier than {profile} by more than {}× (the filter is \
                     over-confident): set [estimators.eif] imu_profile to the IMU's datasheet{}",
                    IMU_NOISE_WARN_FACTOR,
                    if suggest.is_empty() {
                        " or its measured densities".to_string()
                    } else {
                        format!(" (these fit the measurement: {})", suggest.join(", "))
                    }
                ));
            }
        }
        if let Some(f) = &self.filter
            && f.wheel_scale.ready
        {
            self.stats.notes.push(format!(
                "wheel speeds scaled by {:.4} (online calibration against GNSS; {:.1} m in \
                 its window at the end)",
                f.wheel_scale.k, f.wheel_scale.dist
            ));
        }
        if self.filter.is_none() {
            self.stats.notes.push(if self.cfg.relative_yaw {
                format!(
                    "never initialized: no valid GNSS fix with an AHRS orientation and a course \
                     over ground (GNSS speed >= {} m/s or fixes >= {} m apart: \
                     orientation_yaw = \"relative\" needs the robot to drive)",
                    self.cfg.course_min_speed, self.cfg.course_min_baseline
                )
            } else {
                "never initialized: no valid GNSS fix with an AHRS orientation".into()
            });
        }
    }

    fn trajectory(&self) -> &Trajectory {
        &self.trajectory
    }
    fn trajectory_mut(&mut self) -> &mut Trajectory {
        &mut self.trajectory
    }

    fn stats(&self) -> EstimatorStats {
        self.stats.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::super::synthetic::{self, Circle, Motion, Noise, Setup, Still};
    use super::*;
    use nalgebra::Translation3;

    fn params() -> EifParams {
        EifParams {
            gravity_mps2: synthetic::GRAVITY,
            // The synthetic GNSS and AHRS errors are white.
            gnss_correlation_time_s: 0.0,
            orientation_correlation_time_s: 0.0,
            // The synthetic gyros do not sense the Earth's rotation.
            earth_rate: false,
            ..EifParams::default()
        }
    }

    fn run(params: &EifParams, msgs: &[Message]) -> Eif {
        let mut eif = Eif::new(params, synthetic::transforms(), synthetic::origin()).unwrap();
        for m in msgs {
            eif.handle(m);
        }
        eif.finish();
        eif
    }

    /// Per output pose: (seconds after T0, position error m, rotation error rad,
    /// position σ (rms over axes) m, position NEES).
    fn errors(traj: &Trajectory, motion: &dyn Motion) -> Vec<(f64, f64, f64, f64, f64)> {
        traj.samples
            .iter()
            .map(|s| {
                let t = (s.stamp - synthetic::T0).as_secs_f64();
                let truth = motion.at(t).world_from_body;
                let dp = s.world_from_body.translation.vector - truth.translation.vector;
                let dr = s.world_from_body.rotation.angle_to(&truth.rotation);
                let cov = *s.covariance.as_deref().unwrap();
                let pc = cov.fixed_view::<3, 3>(0, 0).into_owned();
                let nees = dp.dot(&(pc.try_inverse().unwrap() * dp));
                (t, dp.norm(), dr, (pc.trace() / 3.0).sqrt(), nees)
            })
            .collect()
    }

    fn still() -> Still {
        Still {
            pose: Isometry3::from_parts(
                Translation3::new(12.0, -4.0, 0.3),
                UnitQuaternion::from_euler_angles(0.02, -0.03, 0.7),
            ),
        }
    }

    fn summary(e: &[(f64, f64, f64, f64, f64)], from: f64, to: f64) -> (f64, f64, f64, f64, f64) {
        let w: Vec<_> = e.iter().filter(|x| x.0 >= from && x.0 < to).collect();
        let n = w.len() as f64;
        (
            w.iter().map(|x| x.1).fold(0.0, f64::max),
            (w.iter().map(|x| x.1 * x.1).sum::<f64>() / n).sqrt(),
            w.iter().map(|x| x.2).fold(0.0, f64::max),
            w.iter().map(|x| x.3).fold(0.0, f64::max),
            w.iter().map(|x| x.4).sum::<f64>() / n,
        )
    }

    /// 120 s at rest with MTi-300 IMU/AHRS noise, RTK fixes (1 cm / 2 cm), tracking
    /// camera jitter 1 mm: the estimate is better than a single fix and its covariance
    /// settles and stays settled.
    #[test]
    fn stationary_robot_stays_put() {
        let motion = still();
        let setup = Setup::new(120.0, Noise::mti300_rtk(), 7);
        let msgs = synthetic::in_stamp_order(synthetic::generate(&motion, &setup));
        let eif = run(&params(), &msgs);
        let e = errors(eif.trajectory(), &motion);
        assert_eq!(e.len(), 6001, "50 Hz output over 120 s");
        let (max_p, rms_p, max_r, _, nees) = summary(&e, 0.0, 121.0);
        // Started from one fix (σ 1/1/2 cm), the error can only shrink: 3σ of the vertical
        // axis bounds every sample; the RMS must beat a single fix's 3-D RMS (2.45 cm).
        assert!(max_p < 0.06, "max position error {max_p}");
        assert!(rms_p < 0.0245 / 2.0, "rms position error {rms_p}");
        // Rotation: the AHRS's 1° yaw σ, averaged, bounds the error.
        assert!(max_r < 1f64.to_radians(), "max rotation error {max_r}");
        // Consistency: the mean position NEES of a consistent filter is 3 (3 dof).
        assert!((1.0..5.0).contains(&nees), "mean NEES {nees}");
        // The covariance settles below a single fix's σ and does not grow afterwards.
        let (_, _, _, s_mid, _) = summary(&e, 20.0, 30.0);
        let (_, _, _, s_end, _) = summary(&e, 110.0, 121.0);
        assert!(
            s_mid < 0.01 && s_end <= s_mid * 1.05,
            "σ {s_mid} then {s_end}"
        );
        let st = eif.stats();
        assert_eq!(st.used["gnss_fix"], 1200);
        assert_eq!(st.used["tracking_odom"], 3600);
        assert!(!st.rejected.contains_key("numerical_skip"));
    }

    /// The same with a 60 s GNSS outage (30 s to 90 s): tracking camera, AHRS and IMU
    /// carry the estimate and the covariance grows, then shrinks when fixes return.
    ///
    /// Bound: without fixes the position is held by the tracking camera's relative poses,
    /// which the filter is told carry at most σ_f = 3 mm (the floor) per message per axis;
    /// N messages at 30 Hz random-walk by σ_f·√N. So each axis error must stay below
    /// e₀ + 3·σ_f·√N(t), with e₀ = 2 cm (the vertical fix σ bounding the error at the
    /// outage start); and within 3σ of what the filter itself reports.
    #[test]
    fn stationary_robot_through_a_gnss_outage() {
        let motion = still();
        let mut setup = Setup::new(120.0, Noise::mti300_rtk(), 8);
        setup.outage = Some((30.0, 90.0));
        let msgs = synthetic::in_stamp_order(synthetic::generate(&motion, &setup));
        let eif = run(&params(), &msgs);
        let truth = motion.at(0.0).world_from_body.translation.vector;
        for s in &eif.trajectory().samples {
            let t = (s.stamp - synthetic::T0).as_secs_f64();
            let err = s.world_from_body.translation.vector - truth;
            let n = (30.0 * (t - 30.0).clamp(0.0, 60.0)).max(1.0);
            let bound = 0.02 + 3.0 * 0.003 * n.sqrt();
            assert!(err.amax() < bound, "t {t}: error {err} bound {bound}");
            let cov = *s.covariance.as_deref().unwrap();
            for k in 0..3 {
                assert!(
                    err[k].abs() < 3.0 * cov[(k, k)].sqrt() + 0.005,
                    "t {t} axis {k}: {err} {cov}"
                );
            }
        }
        let e = errors(eif.trajectory(), &motion);
        let (_, _, _, s_before, _) = summary(&e, 25.0, 30.0);
        let (max_out, _, max_r, s_out, _) = summary(&e, 30.0, 90.0);
        let (_, _, _, s_after, _) = summary(&e, 100.0, 121.0);
        assert!(max_out < 0.2, "outage error {max_out}");
        assert!(max_r < 1f64.to_radians());
        assert!(
            s_out > 5.0 * s_before,
            "σ must grow in the outage: {s_before} → {s_out}"
        );
        assert!(
            s_after < 2.0 * s_before,
            "σ must recover: {s_after} vs {s_before}"
        );
        assert_eq!(eif.stats().rejected["gnss_no_fix"], 600);
    }

    /// `orientation_yaw = "relative"`: an AHRS whose yaw is off by any angle (magnetic,
    /// unreferenced) changes nothing. The filter starts with the heading of the course over
    /// ground, from GNSS velocity or, without it, from the chord between fixes, keeps it
    /// right from the course, and is about as good as with a true-north AHRS; the same
    /// input with `"absolute"` is off by the offset.
    #[test]
    fn relative_yaw_starts_and_stays_right_with_any_heading_offset() {
        let motion = Circle {
            center: Vector3::new(5.0, -3.0, 0.2),
            radius: 10.0,
            speed: 1.0,
        };
        let setup = Setup::new(60.0, Noise::mti300_rtk(), 21);
        let msgs = synthetic::in_stamp_order(synthetic::generate(&motion, &setup));
        let (_, reference_rms, reference_rot, _, _) = summary(
            &errors(run(&params(), &msgs).trajectory(), &motion),
            5.0,
            61.0,
        );
        let relative = EifParams {
            orientation_yaw: OrientationYaw::Relative,
            ..params()
        };
        for offset_deg in [0.0f64, 37.0, 120.0, -179.0] {
            let off = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), offset_deg.to_radians());
            let shifted: Vec<Message> = msgs
                .iter()
                .map(|m| match m {
                    Message::Imu(i) => {
                        let mut i = i.clone();
                        i.orientation = i.orientation.map(|q| off * q);
                        Message::Imu(i)
                    }
                    m => m.clone(),
                })
                .collect();
            for with_velocity in [true, false] {
                let input: Vec<Message> = shifted
                    .iter()
                    .filter(|m| with_velocity || !matches!(m, Message::GnssVelocity(_)))
                    .cloned()
                    .collect();
                let eif = run(&relative, &input);
                let first = eif.trajectory().samples[0].stamp - synthetic::T0;
                assert!(first < Nanos::from_secs(2), "started at {first}");
                let (max_p, rms_p, max_r, _, _) =
                    summary(&errors(eif.trajectory(), &motion), 5.0, 61.0);
                eprintln!(
                    "offset {offset_deg}°, velocity {with_velocity}: started {first}, position \
                     rms {rms_p:.4} m (max {max_p:.4}), rotation max {:.3}° (true-north AHRS: \
                     {reference_rms:.4} m, {:.3}°)",
                    max_r.to_degrees(),
                    reference_rot.to_degrees()
                );
                assert!(max_r < 1.5f64.to_radians(), "{}°", max_r.to_degrees());
                assert!(
                    rms_p < 2.0 * reference_rms + 0.005,
                    "{rms_p} vs {reference_rms}"
                );
                assert!(eif.stats().used["gnss_course"] > 100);
                if offset_deg.abs() > 90.0 {
                    let absolute = run(&params(), &input);
                    let (_, _, max_r, _, _) =
                        summary(&errors(absolute.trajectory(), &motion), 5.0, 61.0);
                    assert!(max_r > 1.0, "absolute yaw: {}°", max_r.to_degrees());
                }
            }
        }
    }

    /// GNSS errors that wander with a 10 s correlation time: a filter that takes each fix
    /// as independent is overconfident (position NEES far above 3), the correlation
    /// weighting of `gnss_correlation_time_s` keeps it consistent (NEES at most about 3).
    #[test]
    fn correlated_gnss_errors_are_weighted_consistently() {
        let motion = still();
        let mut nees = [0.0; 2];
        let mut count = 0.0;
        for seed in 0..6 {
            let mut setup = Setup::new(60.0, Noise::mti300_rtk(), 100 + seed);
            setup.gnss_tau_s = 10.0;
            let msgs = synthetic::in_stamp_order(synthetic::generate(&motion, &setup));
            for (k, tau) in [0.0, 10.0].into_iter().enumerate() {
                let mut p = params();
                p.gnss_correlation_time_s = tau;
                // AHRS at 10 Hz (decimated with a correlated-error model) to keep this
                // test fast; it does not change what is measured here.
                p.orientation_correlation_time_s = 1.0;
                let e = errors(run(&p, &msgs).trajectory(), &motion);
                nees[k] += summary(&e, 20.0, 61.0).4;
            }
            count += 1.0;
        }
        let (white, weighted) = (nees[0] / count, nees[1] / count);
        assert!(white > 10.0, "white-noise assumption NEES {white}");
        assert!((0.3..4.0).contains(&weighted), "weighted NEES {weighted}");
    }

    /// Noise-free messages of a constant-speed circle: the filter reproduces the truth to
    /// well below a millimetre (the prediction is second-order accurate, the corrections
    /// see zero residuals).
    #[test]
    fn noise_free_circle_is_reproduced() {
        let motion = Circle {
            center: Vector3::new(5.0, 8.0, 1.0),
            radius: 6.0,
            speed: 1.2,
        };
        let setup = Setup::new(60.0, Noise::none(), 9);
        let msgs = synthetic::in_stamp_order(synthetic::generate(&motion, &setup));
        let eif = run(&params(), &msgs);
        let e = errors(eif.trajectory(), &motion);
        assert_eq!(e.len(), 3001);
        let (max_p, _, max_r, _, _) = summary(&e, 0.0, 61.0);
        assert!(max_p < 1e-4, "max position error {max_p}");
        assert!(max_r < 1e-6, "max rotation error {max_r}");
        // The information pair after the last correction: η reset, Λ = P⁻¹ at that time.
        let (lambda, eta) = eif.information().unwrap();
        assert_eq!(eta.amax(), 0.0);
        assert!(lambda.iter().all(|c| c.is_finite()) && lambda[(0, 0)] > 0.0);
    }

    /// Without the IMU's orientation and GNSS velocity, at a GNSS rate that is not on the
    /// IMU grid, measurements between IMU samples are applied at their own stamps.
    #[test]
    fn measurements_between_imu_samples_use_their_stamp() {
        let motion = Circle {
            center: Vector3::new(0.0, 0.0, 0.0),
            radius: 4.0,
            speed: 1.0,
        };
        let mut setup = Setup::new(30.0, Noise::none(), 10);
        setup.gnss_hz = 7.0; // 142.857 ms: off the 5 ms grid
        setup.tracking_hz = 29.0;
        let msgs = synthetic::in_stamp_order(synthetic::generate(&motion, &setup));
        let mut p = params();
        p.use_imu_orientation = false;
        p.use_gnss_velocity = false;
        let eif = run(&p, &msgs);
        let e = errors(eif.trajectory(), &motion);
        let (max_p, _, max_r, _, _) = summary(&e, 1.0, 31.0);
        assert!(max_p < 1e-4 && max_r < 1e-5, "{max_p} {max_r}");
        assert!(eif.stats().used["gnss_fix"] >= 200);
    }

    /// An IMU gap of 0.5 s is bridged by holding the last sample and counted; at rest
    /// holding is exact, so the estimate is undisturbed.
    #[test]
    fn imu_gap_is_bridged() {
        let motion = still();
        let setup = Setup::new(20.0, Noise::none(), 11);
        let msgs: Vec<Message> = synthetic::in_stamp_order(synthetic::generate(&motion, &setup))
            .into_iter()
            .filter(|m| {
                let t = (m.stamp() - synthetic::T0).as_secs_f64();
                !(matches!(m, Message::Imu(_)) && (10.0..10.5).contains(&t))
            })
            .collect();
        let eif = run(&params(), &msgs);
        assert_eq!(eif.stats().events["imu_gap_bridged"], 1);
        let e = errors(eif.trajectory(), &motion);
        let (max_p, _, _, _, _) = summary(&e, 0.0, 21.0);
        assert!(max_p < 1e-6, "{max_p}");
        // No output inside the gap (outputs are on IMU stamps).
        assert!(e.iter().all(|x| !(10.0..10.5).contains(&x.0)));
    }

    /// A GNSS fix far from the estimate is rejected by the Mahalanobis gate.
    #[test]
    fn gate_rejects_an_outlier_fix() {
        let motion = still();
        let setup = Setup::new(20.0, Noise::none(), 12);
        let enu = synthetic::origin();
        let msgs: Vec<Message> = synthetic::in_stamp_order(synthetic::generate(&motion, &setup))
            .into_iter()
            .map(|m| match m {
                Message::GnssFix(mut f) if f.stamp == synthetic::T0 + Nanos::from_secs(10) => {
                    let p = enu.enu_from_geodetic(&f.position) + Vector3::new(3.0, 0.0, 0.0);
                    f.position = enu.geodetic_from_enu(&p);
                    Message::GnssFix(f)
                }
                m => m,
            })
            .collect();
        let eif = run(&params(), &msgs);
        assert_eq!(eif.stats().rejected["gnss_gated"], 1);
        let e = errors(eif.trajectory(), &motion);
        assert!(summary(&e, 0.0, 21.0).0 < 1e-6);
        // Without the gate the 3 m jump pulls the estimate.
        let mut p = params();
        p.gnss_gate_chi2 = 0.0;
        let eif = run(&p, &msgs);
        let e = errors(eif.trajectory(), &motion);
        assert!(summary(&e, 10.0, 10.1).0 > 0.01);
    }

    /// Yaw oscillation of the IMU-sample-model tests: the body (IMU at its origin, see
    /// [`synthetic::transforms_imu_at_origin`]) turns about the world z axis through its
    /// origin with `ω(t) = A sin(a t)`, `a = 2π·15 Hz`, `A = 0.5 rad/s`, from rest, so
    /// `ψ(t) = A (1 − cos a t) / a`; 200 Hz IMU for 2 s.
    const WOBBLE_A: f64 = 0.5;
    const WOBBLE_HZ: f64 = 15.0;
    const WOBBLE_STEP: Nanos = Nanos::from_millis(5);
    const WOBBLE_SAMPLES: i64 = 400;

    fn wobble_a() -> f64 {
        std::f64::consts::TAU * WOBBLE_HZ
    }

    /// `ψ(t)`, rad (0 before the start: at rest).
    fn wobble_yaw(t: f64) -> f64 {
        if t <= 0.0 {
            return 0.0;
        }
        WOBBLE_A * (1.0 - (wobble_a() * t).cos()) / wobble_a()
    }

    /// `ω(t) = ψ'(t)`, rad/s.
    fn wobble_rate(t: f64) -> f64 {
        if t <= 0.0 {
            return 0.0;
        }
        WOBBLE_A * (wobble_a() * t).sin()
    }

    /// `world_from_body` at the start: level, yawed.
    fn wobble_start() -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(12.0, -4.0, 0.3),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.7),
        )
    }

    /// One RTK fix at T0 (to start the filter; none after it, and no AHRS after the first
    /// sample), and the IMU messages: rates that are the exact means over (t_{i−1}, t_i]
    /// (`interval_mean`) or the values at t_i; specific force `+g` along world z
    /// throughout (the IMU does not move).
    fn wobble_msgs(interval_mean: bool) -> Vec<Message> {
        let tf = synthetic::transforms_imu_at_origin();
        let body_from_imu = tf.body_from(synthetic::IMU_FRAME).unwrap();
        let body_from_ant = tf.body_from(synthetic::ANTENNA_FRAME).unwrap();
        let start = wobble_start();
        let q0 = (start * body_from_imu).rotation;
        // A turn about world z leaves the world z axis fixed in the IMU frame.
        let z_imu = q0.inverse() * Vector3::z();
        let dt = WOBBLE_STEP.as_secs_f64();
        let mut msgs = Vec::new();
        for i in 0..=WOBBLE_SAMPLES {
            let stamp = synthetic::T0 + Nanos(i * WOBBLE_STEP.as_nanos());
            let t = (stamp - synthetic::T0).as_secs_f64();
            let rate = if interval_mean {
                (wobble_yaw(t) - wobble_yaw(t - dt)) / dt
            } else {
                wobble_rate(t)
            };
            msgs.push(Message::Imu(synthetic::imu_msg(
                stamp,
                z_imu * rate,
                z_imu * synthetic::GRAVITY,
                (i == 0).then_some(q0),
            )));
            if i == 0 {
                let p_ant = start * nalgebra::Point3::from(body_from_ant.translation.vector);
                msgs.push(Message::GnssFix(synthetic::gnss_fix(stamp, &p_ant.coords)));
            }
        }
        msgs
    }

    /// Runs the EIF with `model` on the wobble messages, gyro integration only (no AHRS,
    /// GNSS velocity or tracking camera; the single fix only starts it). Per output
    /// (every IMU sample): (sample index n, signed yaw error ψ̂ − ψ about world z rad,
    /// position error m). Checks on the way that the error is a rotation about world z
    /// only and that the velocity ends at zero.
    fn wobble_errors(model: ImuSampleModel, msgs: &[Message]) -> Vec<(i64, f64, f64)> {
        let mut p = params();
        p.imu_sample_model = model;
        p.use_imu_orientation = false;
        p.use_gnss_velocity = false;
        p.use_tracking_camera = false;
        p.output_rate_hz = 200.0;
        let mut eif = Eif::new(
            &p,
            synthetic::transforms_imu_at_origin(),
            synthetic::origin(),
        )
        .unwrap();
        for m in msgs {
            eif.handle(m);
        }
        eif.finish();
        let v = eif.state().unwrap().1.v;
        assert!(v.norm() < 1e-9, "{model:?}: final velocity {v}");
        let start = wobble_start();
        let out: Vec<_> = eif
            .trajectory()
            .samples
            .iter()
            .map(|s| {
                let k = (s.stamp - synthetic::T0).as_nanos();
                assert_eq!(k % WOBBLE_STEP.as_nanos(), 0, "output off the IMU grid");
                let n = k / WOBBLE_STEP.as_nanos();
                let psi = wobble_yaw((s.stamp - synthetic::T0).as_secs_f64());
                let truth =
                    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), psi) * start.rotation;
                let e = (s.world_from_body.rotation * truth.inverse()).scaled_axis();
                assert!(e.xy().norm() < 1e-12, "{model:?} n {n}: tilt error {e}");
                let dp = s.world_from_body.translation.vector - start.translation.vector;
                (n, e.z, dp.norm())
            })
            .collect();
        assert_eq!(
            out.len(),
            WOBBLE_SAMPLES as usize + 1,
            "{model:?}: one output per sample"
        );
        assert!(
            !eif.stats().used.contains_key("gnss_fix"),
            "the fix only starts the filter"
        );
        out
    }

    fn max_abs(e: &[(i64, f64, f64)]) -> (f64, f64) {
        e.iter().fold((0.0, 0.0), |(y, p), x| {
            (f64::max(y, x.1.abs()), f64::max(p, x.2))
        })
    }

    /// Interval-mean IMU data `ω̄_i = (ψ(t_i) − ψ(t_{i−1}))/Δ`:
    /// - `interval_mean` holds ω̄_i over the interval; about a fixed axis the rotation
    ///   increments `Exp(ω̄_i Δ)` telescope to `ψ(t_n)` exactly, so the yaw error is
    ///   rounding only.
    /// - `point` uses the trapezoid `(ω̄_{i−1} + ω̄_i)Δ/2` (ω̄_0 = 0, at rest before), which
    ///   sums to `(ψ_n + ψ_{n−1})/2`: a half-sample lag, error `−(ψ_n − ψ_{n−1})/2 =
    ///   −(A/a)·sin(aΔ/2)·sin(a(n − ½)Δ)`, largest near `AΔ/2 ≈ 1.24e-3 rad`.
    ///
    /// Either way the IMU stays where it started: the specific force `+g` along world z,
    /// rotated about that same axis, cancels gravity exactly (the ~1e-9 m left is the
    /// fix's geodetic round trip at initialisation).
    #[test]
    fn interval_mean_model_is_exact_on_interval_mean_imu_data() {
        let msgs = wobble_msgs(true);
        let exact = wobble_errors(ImuSampleModel::IntervalMean, &msgs);
        let (yaw, pos) = max_abs(&exact);
        assert!(
            yaw < 1e-9,
            "interval_mean on interval means: yaw error {yaw}"
        );
        assert!(
            pos < 1e-8,
            "interval_mean on interval means: position error {pos}"
        );

        let lagged = wobble_errors(ImuSampleModel::Point, &msgs);
        let dt = WOBBLE_STEP.as_secs_f64();
        for &(n, e, _) in &lagged {
            let t = n as f64 * dt;
            let expected = -(wobble_yaw(t) - wobble_yaw(t - dt)) / 2.0;
            assert!(
                (e - expected).abs() < 1e-9,
                "point on interval means, n {n}: yaw error {e}, half-sample lag {expected}"
            );
        }
        let (yaw, pos) = max_abs(&lagged);
        assert!(yaw > 1e-3, "point on interval means: yaw error only {yaw}");
        assert!(pos < 1e-8, "point on interval means: position error {pos}");
    }

    /// Point IMU data `ω_i = ω(t_i)`, θ = aΔ/2:
    /// - `point` is the composite trapezoid rule; for a sine it sums in closed form to
    ///   `ψ̂_n = ψ_n · θ cot θ`, error `−ψ_n (1 − θ cot θ)`, bounded by
    ///   `B = (2A/a)(1 − θ cot θ) ≈ 1.97e-4 rad`, reached where ψ peaks (t = 0.1 s, …;
    ///   Euler–Maclaurin's leading term is `Δ²/6·A·a ≈ 1.96e-4`), and at every stamp by
    ///   the textbook `Δ²/12 · max|ω̈| · t_n` with `max|ω̈| = A a²`.
    /// - `interval_mean` holds ω_i over (t_{i−1}, t_i]: the right Riemann sum,
    ///   `ψ̂_n = AΔ sin(nθ) sin((n+1)θ)/sin θ`, error ≈ `Δ/2 · ω(t_n)` (first order, up to
    ///   ≈ 1.35e-3 rad), more than 5·B.
    #[test]
    fn point_model_is_trapezoidal_on_point_imu_data() {
        let msgs = wobble_msgs(false);
        let dt = WOBBLE_STEP.as_secs_f64();
        let a = wobble_a();
        let th = a * dt / 2.0;
        let cot_ratio = th / th.tan();
        let bound = 2.0 * WOBBLE_A / a * (1.0 - cot_ratio);

        let trapezoid = wobble_errors(ImuSampleModel::Point, &msgs);
        for &(n, e, _) in &trapezoid {
            let t = n as f64 * dt;
            let expected = -wobble_yaw(t) * (1.0 - cot_ratio);
            assert!(
                (e - expected).abs() < 1e-9,
                "point on point samples, n {n}: yaw error {e}, trapezoid {expected}"
            );
            let textbook = dt * dt / 12.0 * WOBBLE_A * a * a * t;
            assert!(e.abs() <= textbook + 1e-12, "n {n}: {e} above {textbook}");
        }
        let (yaw, pos) = max_abs(&trapezoid);
        assert!(
            yaw <= bound + 1e-12,
            "point on point samples: yaw error {yaw}, bound {bound}"
        );
        assert!(pos < 1e-8, "point on point samples: position error {pos}");

        let riemann = wobble_errors(ImuSampleModel::IntervalMean, &msgs);
        for &(n, e, _) in &riemann {
            let nf = n as f64;
            let sum = WOBBLE_A * dt * (nf * th).sin() * ((nf + 1.0) * th).sin() / th.sin();
            let expected = sum - wobble_yaw(nf * dt);
            assert!(
                (e - expected).abs() < 1e-9,
                "interval_mean on point samples, n {n}: yaw error {e}, Riemann {expected}"
            );
        }
        let (yaw, pos) = max_abs(&riemann);
        assert!(
            yaw > 5.0 * bound,
            "interval_mean on point samples: yaw error {yaw} ≤ 5·{bound}"
        );
        assert!(
            pos < 1e-8,
            "interval_mean on point samples: position error {pos}"
        );
    }

    #[test]
    fn parameters_are_checked() {
        let mut p = params();
        p.output_rate_hz = 0.0;
        let err = Eif::new(&p, synthetic::transforms(), synthetic::origin()).unwrap_err();
        assert!(
            err.to_string().contains("estimators.eif.output_rate_hz"),
            "{err}"
        );
        let mut p = params();
        p.accel_noise_density_ug_rthz = f64::NAN;
        assert!(Eif::new(&p, synthetic::transforms(), synthetic::origin()).is_err());
        let no_body = StaticTransforms::default();
        assert!(matches!(
            Eif::new(&params(), no_body, synthetic::origin()),
            Err(EstimatorError::MissingFrame { .. })
        ));
    }
}
