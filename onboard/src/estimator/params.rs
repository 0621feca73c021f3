//! Parameter types of the estimators (`[estimators]` in `scenarios/defaults.toml`, where
//! every field is documented with its default).

use serde::{Deserialize, Serialize};

/// A trajectory source.
#[derive(Copy, Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EstimatorKind {
    /// The Extended Information Filter.
    Eif,
    /// GNSS position with IMU orientation (eq. 1).
    Gnss,
    /// Tracking-camera pose mapped into the world (eq. 2).
    TrackingCamera,
    /// Wheel odometry with the IMU's heading, integrated (no GNSS after the start).
    DeadReckoning,
}

impl EstimatorKind {
    /// The source name (`eif`, `gnss`, `tracking_camera`, `dead_reckoning`).
    pub fn name(self) -> &'static str {
        match self {
            EstimatorKind::Eif => "eif",
            EstimatorKind::Gnss => "gnss",
            EstimatorKind::TrackingCamera => "tracking_camera",
            EstimatorKind::DeadReckoning => "dead_reckoning",
        }
    }
}

/// What an IMU message's angular velocity and acceleration stand for.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ImuSampleModel {
    /// The mean over the interval since the previous message (IMUs that output
    /// strapdown-integrated increments, as the Xsens MTi family): held constant over it.
    IntervalMean,
    /// The value at the message's stamp: interpolated linearly between messages.
    Point,
}

/// What the AHRS orientation's yaw is trusted for (`orientation_yaw`).
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OrientationYaw {
    /// Roll, pitch and yaw (a true-north ENU heading).
    Absolute,
    /// Roll and pitch only; the heading comes from the GNSS course over ground.
    Relative,
}

/// `[estimators]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EstimatorsParams {
    /// Which sources run.
    pub run: Vec<EstimatorKind>,
    /// Re-ordering window, ms.
    pub reorder_window_ms: f64,
    /// `[estimators.eif]`.
    pub eif: EifParams,
}

/// `[estimators.eif]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EifParams {
    /// Output rate, Hz.
    pub output_rate_hz: f64,
    /// Use GNSS position fixes.
    pub use_gnss_position: bool,
    /// Use GNSS velocity.
    pub use_gnss_velocity: bool,
    /// Use the IMU's AHRS orientation.
    pub use_imu_orientation: bool,
    /// Use the tracking camera's relative pose.
    pub use_tracking_camera: bool,
    /// A named IMU noise profile (`mti-300`, `mti-3`, `bmi055`, `bno055`, `mpu-9250`,
    /// `icm-20948`) that replaces the four densities; empty = the densities given.
    pub imu_profile: String,
    /// Gyro white noise density, °/s/√Hz.
    pub gyro_noise_density_dps_rthz: f64,
    /// Accelerometer white noise density, µg/√Hz.
    pub accel_noise_density_ug_rthz: f64,
    /// Extra gyro process noise, °/s/√Hz.
    pub gyro_extra_noise_dps_rthz: f64,
    /// Extra accelerometer process noise, µg/√Hz.
    pub accel_extra_noise_ug_rthz: f64,
    /// Gravity, m/s² (0 = normal gravity at the first fix).
    pub gravity_mps2: f64,
    /// Tracking-camera position noise, m/√m.
    pub tracking_position_sigma_m_per_rtm: f64,
    /// Tracking-camera rotation noise, °/√m.
    pub tracking_rotation_sigma_deg_per_rtm: f64,
    /// Tracking-camera position noise floor, m.
    pub tracking_position_sigma_floor_m: f64,
    /// Tracking-camera rotation noise floor, degrees.
    pub tracking_rotation_sigma_floor_deg: f64,
    /// GNSS Mahalanobis gate (0 = none).
    pub gnss_gate_chi2: f64,
    /// Correlation time the filter assumes for GNSS position errors, s (0 = white).
    pub gnss_correlation_time_s: f64,
    /// Correlation time the filter assumes for AHRS orientation errors, s (0 = white).
    pub orientation_correlation_time_s: f64,
    /// Initial velocity uncertainty, m/s.
    pub initial_velocity_sigma_mps: f64,
    /// How IMU samples are integrated between messages.
    pub imu_sample_model: ImuSampleModel,
    /// Take the Earth's rotation (15.04 °/h about its axis, from the origin's latitude)
    /// out of the gyro before integrating it.
    pub earth_rate: bool,
    /// What the AHRS yaw is trusted for.
    pub orientation_yaw: OrientationYaw,
    /// Slowest horizontal GNSS speed used as a course over ground, m/s.
    pub course_min_speed_mps: f64,
    /// Shortest fix-to-fix chord used as a course over ground, m.
    pub course_min_baseline_m: f64,
    /// Noise floor of a course-over-ground heading, degrees.
    pub course_sigma_floor_deg: f64,
    /// Use a dual-antenna GNSS heading (`/gnss/heading`) as a heading correction.
    pub use_gnss_heading: bool,
    /// Use the wheel odometry's body-frame velocity (with the non-holonomic constraint).
    pub use_wheel_odometry: bool,
    /// Wheel speed white noise (1σ), m/s.
    pub wheel_speed_sigma_mps: f64,
    /// Unknown wheel slip as a fraction of speed (1σ).
    pub wheel_slip_fraction: f64,
    /// Lateral velocity allowed by the non-holonomic constraint (1σ), m/s.
    pub wheel_lateral_sigma_mps: f64,
    /// Vertical velocity allowed by the non-holonomic constraint (1σ), m/s.
    pub wheel_vertical_sigma_mps: f64,
    /// Slip gate on the wheel velocity innovation (squared Mahalanobis, 3 dof; 0 = none).
    pub wheel_gate_chi2: f64,
    /// Correlation time the filter assumes for wheel slip errors, s (0 = white).
    pub wheel_correlation_time_s: f64,
    /// Forgetting length of the online wheel scale calibration, m (0 = off).
    pub wheel_calibration_length_m: f64,
}

impl Default for EstimatorsParams {
    /// The values of `[estimators]` in `scenarios/defaults.toml`.
    fn default() -> Self {
        vinebench_msgs::defaults::section("estimators")
            .expect("the embedded scenarios/defaults.toml is checked by tests")
    }
}

impl Default for EifParams {
    /// The values of `[estimators.eif]` in `scenarios/defaults.toml`.
    fn default() -> Self {
        vinebench_msgs::defaults::section("estimators.eif")
            .expect("the embedded scenarios/defaults.toml is checked by tests")
    }
}
