//! Sensor models: each a pure function of ground truth and its own seeded random stream.
//!
//! A sensor samples at its own epochs ([`SensorModel::next_time`]); the runner advances
//! the motion model to that epoch and hands the truth to [`SensorModel::sample`], which
//! emits messages stamped with the epoch and delivered `latency` later.
//!
//! | sensor | module | stream | epochs | message |
//! |---|---|---|---|---|
//! | IMU + AHRS (Xsens MTi-300) | [`imu`] | `sensors.imu` | `start + i/rate` | [`Message::Imu`](vinebench_msgs::Message::Imu) |
//! | GNSS (u-blox ZED-F9P) | [`gnss`] | `sensors.gnss` | multiples of the period since the Unix epoch | `GnssFix`, `GnssVelocity` |
//! | tracking camera (T265) | [`tracking_camera`] | `sensors.tracking_camera` | `start + offset + i/rate` | `TrackingOdom` |
//! | track or wheel odometry | [`wheel_odom`] | `sensors.wheel_odom` | `start + i/rate` | `WheelOdom` |
//!
//! Shared noise processes live in [`noise`]; [`EpochClock`] gives drift-free sample times.

pub mod camera;
pub mod gnss;
pub mod imu;
pub mod noise;
pub mod sky;
pub mod tracking_camera;
pub mod wheel_odom;

pub use gnss::Gnss;
pub use imu::Imu;
pub use tracking_camera::TrackingCamera;
pub use wheel_odom::WheelOdom;

use crate::params::{FaultsParams, ParamError, SensorsParams};
use crate::robot::RobotGeometry;
use crate::truth::TruthSample;
use nalgebra::Isometry3;
use vinebench_msgs::geodesy::LocalEnu;
use vinebench_msgs::{Nanos, StaticTransforms, TimedMessage};

/// A simulated sensor.
pub trait SensorModel {
    /// Short name (`imu`, `gnss`, ...), also the name of its random stream `sensors.<name>`.
    fn name(&self) -> &'static str;
    /// The epoch of the next sample.
    fn next_time(&self) -> Nanos;
    /// Produces the sample(s) for epoch [`SensorModel::next_time`] from the truth at that
    /// epoch (`truth.stamp == self.next_time()`), appends them to `out`, and schedules
    /// the next epoch.
    fn sample(&mut self, truth: &TruthSample, out: &mut Vec<TimedMessage>);
}

/// What every sensor needs to know about the run.
#[derive(Clone, Debug)]
pub struct SensorContext {
    /// The scenario's master seed.
    pub master_seed: u64,
    /// Time of the first sample.
    pub start: Nanos,
    /// The world frame's geodetic origin.
    pub enu: LocalEnu,
    /// Magnitude of gravity in the world (WGS84 normal gravity at the origin), m/s².
    pub gravity_mps2: f64,
    /// The robot's sensor frames, from its URDF.
    pub static_transforms: StaticTransforms,
    /// The robot's drive geometry, from its URDF.
    pub geometry: RobotGeometry,
}

/// Builds every enabled sensor of `[sensors]`, with `[faults]` applied; `sight` is the
/// world the GNSS antenna looks through (needed with `[sensors.gnss.sky] enabled`).
///
/// The order is fixed: imu, gnss, tracking_camera, wheel_odom (disabled ones are left
/// out). Parameters of enabled sensors and every `[[faults.gnss]]` window are checked;
/// the first problem is returned as a [`ParamError`] with its scenario path
/// (`sensors.imu.rate_hz`, `faults.gnss[1].end_s`, ...).
pub fn build_sensors(
    params: &SensorsParams,
    faults: &FaultsParams,
    ctx: &SensorContext,
    sight: Option<std::sync::Arc<dyn sky::LineOfSight>>,
) -> Result<Vec<Box<dyn SensorModel>>, ParamError> {
    // Fault windows are checked even when the GNSS is disabled: a broken scenario file
    // should fail the same way whichever sensors it turns on.
    let windows = gnss::status_windows(&faults.gnss)?;
    let mut sensors: Vec<Box<dyn SensorModel>> = Vec::with_capacity(4);
    if params.imu.enabled {
        sensors.push(Box::new(Imu::new(&params.imu, ctx)?));
    }
    if params.gnss.enabled {
        sensors.push(Box::new(Gnss::with_windows(
            &params.gnss,
            windows,
            ctx,
            sight,
        )?));
    }
    if params.tracking_camera.enabled {
        sensors.push(Box::new(TrackingCamera::new(&params.tracking_camera, ctx)?));
    }
    if params.wheel_odom.enabled {
        sensors.push(Box::new(WheelOdom::new(&params.wheel_odom, ctx)?));
    }
    Ok(sensors)
}

/// Builds the `[[sensors.cameras]]`, rendering with `renderer`; camera `i`'s problems
/// are reported as `sensors.cameras[i].<key>`.
pub fn build_cameras(
    sensors: &crate::params::SensorsParams,
    render: &crate::params::RenderParams,
    ctx: &SensorContext,
    renderer: &std::sync::Arc<crate::render::shade::Renderer>,
) -> Result<Vec<Box<dyn SensorModel>>, ParamError> {
    let cameras = &sensors.cameras;
    camera::check_light(&sensors.stereo_depth, &sensors.camera_exposure)?;
    if cameras.len() > MAX_CAMERAS {
        return Err(ParamError::new(
            "sensors.cameras",
            format!("at most {MAX_CAMERAS} cameras (MAX_CAMERAS)"),
            format!("{} cameras", cameras.len()),
        ));
    }
    let mut names = std::collections::BTreeSet::new();
    let mut out: Vec<Box<dyn SensorModel>> = Vec::with_capacity(cameras.len());
    for (i, p) in cameras.iter().enumerate() {
        if !names.insert(p.name.as_str()) {
            return Err(ParamError::new(
                format!("sensors.cameras[{i}].name"),
                "a name no other camera has",
                format!("`{}`", p.name),
            ));
        }
        out.push(Box::new(camera::Camera::new(
            p,
            i,
            render,
            (&sensors.stereo_depth, &sensors.camera_exposure),
            ctx,
            renderer.clone(),
        )?));
    }
    Ok(out)
}

/// Lowest accepted sensor rate, Hz (keeps the exact epoch arithmetic within `i128`).
pub const MIN_RATE_HZ: f64 = 1e-6;
/// Highest accepted sensor rate, Hz (a period of at least 1 µs).
pub const MAX_RATE_HZ: f64 = 1e6;
/// Longest accepted latency, ms.
pub const MAX_LATENCY_MS: f64 = 3_600_000.0;
/// Most messages of one sensor in flight at once (`rate_hz · latency`): they wait in
/// memory between their stamp and their arrival.
pub const MAX_IN_FLIGHT_MESSAGES: f64 = 100_000.0;
/// Most image pixels of one camera in flight at once (`rate_hz · latency · width ·
/// height`; about 1 GB of images).
pub const MAX_IN_FLIGHT_PIXELS: f64 = 2e8;
/// Most `[[sensors.cameras]]`.
pub const MAX_CAMERAS: usize = 16;

/// Checks a sample rate: finite, in [[`MIN_RATE_HZ`], [`MAX_RATE_HZ`]].
pub(crate) fn require_rate(path: &str, rate_hz: f64) -> Result<f64, ParamError> {
    if rate_hz.is_finite() && (MIN_RATE_HZ..=MAX_RATE_HZ).contains(&rate_hz) {
        Ok(rate_hz)
    } else {
        Err(ParamError::new(
            path,
            format!("a rate in [{MIN_RATE_HZ}, {MAX_RATE_HZ}] Hz"),
            rate_hz,
        ))
    }
}

/// Checks a latency in ms (finite, in [0, [`MAX_LATENCY_MS`]], and at most
/// [`MAX_IN_FLIGHT_MESSAGES`] samples at `rate_hz` in flight) and converts it.
pub(crate) fn latency_from_ms(
    path: &str,
    latency_ms: f64,
    rate_hz: f64,
) -> Result<Nanos, ParamError> {
    crate::params::require_in(path, latency_ms, 0.0, MAX_LATENCY_MS)?;
    let in_flight = rate_hz * latency_ms * 1e-3;
    if in_flight > MAX_IN_FLIGHT_MESSAGES {
        return Err(ParamError::new(
            path,
            format!(
                "a latency keeping at most {MAX_IN_FLIGHT_MESSAGES} messages in flight at \
                 {rate_hz} Hz (MAX_IN_FLIGHT_MESSAGES), i.e. at most {} ms",
                MAX_IN_FLIGHT_MESSAGES / rate_hz * 1e3
            ),
            latency_ms,
        ));
    }
    Ok(Nanos::from_secs_f64(latency_ms * 1e-3))
}

/// `body_from_<frame>` of a sensor's mount, or a [`ParamError`] on
/// `sensors.<sensor>.frame` listing the robot's links.
pub(crate) fn mount(
    ctx: &SensorContext,
    sensor: &str,
    frame: &str,
) -> Result<Isometry3<f64>, ParamError> {
    ctx.static_transforms.body_from(frame).ok_or_else(|| {
        let mut links: Vec<&str> = ctx
            .static_transforms
            .body_from
            .keys()
            .map(|k| k.as_str())
            .collect();
        if let Some(b) = &ctx.static_transforms.body_frame {
            links.insert(0, b.as_str());
        }
        ParamError::new(
            format!("sensors.{sensor}.frame"),
            format!("a link of the robot's URDF ({})", links.join(", ")),
            format!("`{frame}`"),
        )
    })
}

/// Drift-free sample times of a fixed rate: epoch `i` is `base + round(i·1e9/rate_hz)` ns.
///
/// The product is evaluated exactly in integers from the binary value of `rate_hz`
/// (`rate_hz = m·2^e`), so epochs never accumulate rounding and a clock aligned to the
/// Unix epoch ([`EpochClock::aligned`]) lands on the same instants whatever its start.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct EpochClock {
    base: Nanos,
    index: i64,
    /// `rate_hz = mantissa · 2^exponent`, mantissa odd.
    mantissa: i128,
    exponent: i32,
}

impl EpochClock {
    /// Epochs `base + round(i·1e9/rate_hz)` for i = 0, 1, ...; the current epoch is
    /// `base`. `rate_hz` must be finite and > 0 (see [`MIN_RATE_HZ`], [`MAX_RATE_HZ`]).
    pub fn new(base: Nanos, rate_hz: f64) -> EpochClock {
        let (mantissa, exponent) = decompose(rate_hz);
        EpochClock {
            base,
            index: 0,
            mantissa,
            exponent,
        }
    }

    /// Epochs at the multiples of the period since the Unix epoch (`round(k·1e9/rate_hz)`
    /// ns), like a receiver aligned to GPS time; the current epoch is the first one at or
    /// after `not_before`.
    pub fn aligned(rate_hz: f64, not_before: Nanos) -> EpochClock {
        let mut c = EpochClock::new(Nanos::ZERO, rate_hz);
        let guess = (not_before.0 as f64 * 1e-9 * rate_hz).ceil();
        c.index = if guess.is_finite() { guess as i64 } else { 0 };
        while c.time_at(c.index) < not_before {
            c.index += 1;
        }
        while c.index > i64::MIN && c.time_at(c.index - 1) >= not_before {
            c.index -= 1;
        }
        c
    }

    /// The current epoch.
    pub fn time(&self) -> Nanos {
        self.time_at(self.index)
    }

    /// The epoch with index `i`.
    pub fn time_at(&self, i: i64) -> Nanos {
        Nanos(self.base.0.saturating_add(self.offset_ns(i)))
    }

    /// The index of the current epoch.
    pub fn index(&self) -> i64 {
        self.index
    }

    /// Moves to the next epoch.
    pub fn advance(&mut self) {
        self.index += 1;
    }

    /// The nominal period, s.
    pub fn period_s(&self) -> f64 {
        1.0 / self.rate_hz()
    }

    /// The rate, Hz.
    pub fn rate_hz(&self) -> f64 {
        self.mantissa as f64 * 2f64.powi(self.exponent)
    }

    /// `round(i·1e9/rate)` ns, exact; falls back to floating point only where the exact
    /// product would overflow `i128` (rates far outside the accepted range).
    fn offset_ns(&self, i: i64) -> i64 {
        self.exact_offset_ns(i)
            .unwrap_or_else(|| (i as f64 * 1e9 / self.rate_hz()).round() as i64)
    }

    /// `round(i·1e9 / (m·2^e))` in integers, rounding half away from zero; `None` on
    /// overflow.
    fn exact_offset_ns(&self, i: i64) -> Option<i64> {
        let ns = i128::from(i).checked_mul(1_000_000_000)?;
        let (num, den) = if self.exponent >= 0 {
            let pow = 1i128.checked_shl(u32::try_from(self.exponent).ok()?)?;
            (ns, self.mantissa.checked_mul(pow)?)
        } else {
            let shift = self.exponent.unsigned_abs();
            if shift >= 126 {
                return None;
            }
            (ns.checked_mul(1i128 << shift)?, self.mantissa)
        };
        if den <= 0 {
            return None;
        }
        let (n, d) = (num.unsigned_abs(), den.unsigned_abs());
        let q = n.checked_mul(2)?.checked_add(d)? / d.checked_mul(2)?;
        let q = i64::try_from(q).ok()?;
        Some(if num < 0 { -q } else { q })
    }
}

/// `x = m·2^e` with `m` odd (or zero).
fn decompose(x: f64) -> (i128, i32) {
    let bits = x.to_bits();
    let exp_bits = ((bits >> 52) & 0x7ff) as i32;
    let frac = bits & ((1u64 << 52) - 1);
    let (mut m, mut e) = if exp_bits == 0 {
        (frac, -1074)
    } else {
        (frac | (1u64 << 52), exp_bits - 1075)
    };
    if m == 0 {
        return (0, 0);
    }
    let tz = m.trailing_zeros();
    m >>= tz;
    e += tz as i32;
    (i128::from(m), e)
}

#[cfg(test)]
pub(crate) mod test_support {
    //! Synthetic truth and a minimal runner for the sensor tests.

    use super::*;
    use crate::robot::RobotModel;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};
    use vinebench_msgs::geodesy::{Geodetic, normal_gravity};

    /// 2021-09-15T09:00:00Z plus 37 ms (deliberately not on a 100 ms boundary).
    pub const START: Nanos = Nanos(1_631_696_400_037_000_000);

    /// The built-in tracked robot at the defaults' origin.
    pub fn ctx(seed: u64) -> SensorContext {
        ctx_for("tracked-sensorbox", seed)
    }

    /// A built-in robot (`tracked-sensorbox`, `mecanum-rover`) at the defaults' origin.
    pub fn ctx_for(robot: &str, seed: u64) -> SensorContext {
        let robot = RobotModel::builtin(robot).unwrap();
        let origin = Geodetic {
            lat_deg: 40.4545,
            lon_deg: 17.9085,
            alt_m: 55.0,
        };
        SensorContext {
            master_seed: seed,
            start: START,
            enu: LocalEnu::new(origin),
            gravity_mps2: normal_gravity(origin.lat_deg, origin.alt_m),
            static_transforms: robot.static_transforms,
            geometry: robot.geometry,
        }
    }

    /// Seconds since [`START`].
    pub fn secs(t: Nanos) -> f64 {
        (t - START).as_secs_f64()
    }

    /// A robot standing still at `world_from_body`.
    pub fn stationary(t: Nanos, world_from_body: Isometry3<f64>) -> TruthSample {
        TruthSample {
            stamp: t,
            world_from_body,
            velocity_in_world: Vector3::zeros(),
            acceleration_in_world: Vector3::zeros(),
            angular_velocity_in_body: Vector3::zeros(),
            angular_acceleration_in_body: Vector3::zeros(),
            drive_speeds_radps: [0.0; crate::robot::MAX_DRIVE_JOINTS],
            odometer_m: 0.0,
        }
    }

    /// Sprocket pitch radius of the built-in tracked robot, m.
    pub const SPROCKET_M: f64 = 0.1;

    /// Drive parameters of the synthetic truth: what the encoders see for a body motion.
    #[derive(Clone, Copy)]
    pub struct Drive {
        /// Skid-steer ICR expansion (true yaw rate = Δv_track / (icr · width)).
        pub icr: f64,
        /// Longitudinal slip (body speed = (1 − slip) · mean track speed).
        pub slip: f64,
        /// Track width, m.
        pub width: f64,
    }

    impl Drive {
        /// No slip, no skid, the built-in robot's track width.
        pub const IDEAL: Drive = Drive {
            icr: 1.0,
            slip: 0.0,
            width: 0.6,
        };

        fn track_speeds(&self, v: f64, omega: f64) -> (f64, f64) {
            let mean = v / (1.0 - self.slip);
            let diff = self.icr * self.width * omega;
            (mean - diff / 2.0, mean + diff / 2.0)
        }
    }

    /// A level robot driving counterclockwise at `speed` on a horizontal circle of
    /// `radius`, starting at the world origin heading east (centre (0, radius, 0)).
    /// Closed form: yaw θ = ωt with ω = v/R, position R(sin θ, 1 − cos θ, 0), velocity
    /// v(cos θ, sin θ, 0), acceleration v²/R (−sin θ, cos θ, 0) towards the centre.
    pub fn circle(t: Nanos, radius: f64, speed: f64, drive: Drive) -> TruthSample {
        let s = secs(t);
        let omega = speed / radius;
        let th = omega * s;
        let (sn, cs) = th.sin_cos();
        let (l, r) = drive.track_speeds(speed, omega);
        TruthSample {
            stamp: t,
            world_from_body: Isometry3::from_parts(
                Translation3::new(radius * sn, radius * (1.0 - cs), 0.0),
                UnitQuaternion::from_euler_angles(0.0, 0.0, th),
            ),
            velocity_in_world: speed * Vector3::new(cs, sn, 0.0),
            acceleration_in_world: speed * speed / radius * Vector3::new(-sn, cs, 0.0),
            angular_velocity_in_body: Vector3::new(0.0, 0.0, omega),
            angular_acceleration_in_body: Vector3::zeros(),
            drive_speeds_radps: [l / SPROCKET_M, r / SPROCKET_M, 0.0, 0.0],
            odometer_m: speed * s,
        }
    }

    /// A level robot driving straight at constant `speed` from the origin along the ENU
    /// heading `yaw`.
    pub fn straight(t: Nanos, yaw: f64, speed: f64, drive: Drive) -> TruthSample {
        let s = secs(t);
        let dir = Vector3::new(yaw.cos(), yaw.sin(), 0.0);
        let (l, r) = drive.track_speeds(speed, 0.0);
        TruthSample {
            stamp: t,
            world_from_body: Isometry3::from_parts(
                Translation3::from(dir * speed * s),
                UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
            ),
            velocity_in_world: dir * speed,
            acceleration_in_world: Vector3::zeros(),
            angular_velocity_in_body: Vector3::zeros(),
            angular_acceleration_in_body: Vector3::zeros(),
            drive_speeds_radps: [l / SPROCKET_M, r / SPROCKET_M, 0.0, 0.0],
            odometer_m: speed * s,
        }
    }

    /// Runs sensors like the runner does (earliest epoch first, ties in list order) on a
    /// truth function until `end` (inclusive).
    pub fn run(
        sensors: &mut [Box<dyn SensorModel>],
        truth: &dyn Fn(Nanos) -> TruthSample,
        end: Nanos,
    ) -> Vec<TimedMessage> {
        let mut out = Vec::new();
        loop {
            let Some((i, t)) = sensors
                .iter()
                .enumerate()
                .map(|(i, s)| (i, s.next_time()))
                .min_by_key(|&(i, t)| (t, i))
            else {
                return out;
            };
            if t > end {
                return out;
            }
            let tr = truth(t);
            assert_eq!(tr.stamp, t);
            sensors[i].sample(&tr, &mut out);
        }
    }

    /// Runs one sensor for `n` epochs.
    pub fn run_n<S: SensorModel>(
        sensor: &mut S,
        truth: &dyn Fn(Nanos) -> TruthSample,
        n: usize,
    ) -> Vec<TimedMessage> {
        let mut out = Vec::new();
        for _ in 0..n {
            let t = sensor.next_time();
            sensor.sample(&truth(t), &mut out);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::test_support::*;
    use super::*;
    use crate::params::{GnssFault, GnssStatusParam};
    use vinebench_msgs::Message;

    #[test]
    fn epoch_clock_has_no_accumulated_rounding() {
        // 3 Hz: 1e9/3 is not an integer number of ns. Epoch i must be
        // round(i·333 333 333.33…) = (i·1e9 + 1)/3 in integers (remainder 0, 1 or 2 → the
        // nearest), so every third epoch is exact and no drift builds up.
        let c = EpochClock::new(Nanos(123), 3.0);
        for i in (0..10_000i64)
            .chain(999_999_000..1_000_000_000)
            .chain([9_000_000_000])
        {
            assert_eq!(
                c.time_at(i),
                Nanos(123 + (i * 1_000_000_000 + 1) / 3),
                "epoch {i}"
            );
        }
        let mut c = c;
        for i in 0..10 {
            assert_eq!((c.index(), c.time()), (i, c.time_at(i)));
            c.advance();
        }
        // 200 Hz: exact multiples of 5 ms.
        let c = EpochClock::new(Nanos::ZERO, 200.0);
        assert_eq!(c.time_at(1_000_000_007), Nanos(5_000_000_035_000_000));
        // A rate that is not a nice binary number: 0.1 Hz → 10 s exactly.
        assert_eq!(
            EpochClock::new(Nanos::ZERO, 0.1).time_at(7),
            Nanos::from_secs(70)
        );
    }

    #[test]
    fn aligned_clock_starts_at_first_multiple_not_before() {
        // 10 Hz: multiples of 100 ms since the Unix epoch.
        let c = EpochClock::aligned(10.0, START);
        assert_eq!(c.time(), Nanos(1_631_696_400_100_000_000));
        let exact = Nanos(1_631_696_400_100_000_000);
        assert_eq!(EpochClock::aligned(10.0, exact).time(), exact);
        assert_eq!(
            EpochClock::aligned(10.0, exact + Nanos(1)).time(),
            exact + Nanos(100_000_000)
        );
        // 3 Hz: whole seconds are epochs (k multiple of 3), others at thirds.
        let c = EpochClock::aligned(3.0, Nanos::from_secs(1_631_696_400) + Nanos(1));
        assert_eq!(
            c.time(),
            Nanos::from_secs(1_631_696_400) + Nanos(333_333_333)
        );
    }

    fn all_enabled() -> SensorsParams {
        SensorsParams::default()
    }

    fn faults() -> FaultsParams {
        FaultsParams {
            gnss: vec![GnssFault {
                start_s: 2.0,
                end_s: 4.0,
                status: GnssStatusParam::NoFix,
            }],
        }
    }

    fn circle_truth(t: Nanos) -> crate::truth::TruthSample {
        circle(
            t,
            8.0,
            1.0,
            Drive {
                icr: 1.3,
                slip: 0.02,
                width: 0.6,
            },
        )
    }

    #[test]
    fn builds_enabled_sensors_in_fixed_order() {
        let c = ctx(1);
        let s = build_sensors(&all_enabled(), &faults(), &c, None).unwrap();
        let names: Vec<_> = s.iter().map(|s| s.name()).collect();
        assert_eq!(names, ["imu", "gnss", "tracking_camera", "wheel_odom"]);
        let mut p = all_enabled();
        p.imu.enabled = false;
        p.tracking_camera.enabled = false;
        let s = build_sensors(&p, &faults(), &c, None).unwrap();
        let names: Vec<_> = s.iter().map(|s| s.name()).collect();
        assert_eq!(names, ["gnss", "wheel_odom"]);
    }

    #[test]
    fn bad_parameters_name_their_path() {
        let c = ctx(1);
        let err =
            |p: SensorsParams, f: FaultsParams| build_sensors(&p, &f, &c, None).err().unwrap();

        let mut p = all_enabled();
        p.imu.rate_hz = 0.0;
        assert_eq!(err(p, faults()).path, "sensors.imu.rate_hz");

        let mut p = all_enabled();
        p.gnss.frame = "lidar_link".into();
        let e = err(p, faults());
        assert_eq!(e.path, "sensors.gnss.frame");
        assert!(
            e.expected.contains("gnss_antenna") && e.expected.contains("imu_link"),
            "{e}"
        );
        assert!(e.found.contains("lidar_link"));

        let mut p = all_enabled();
        p.gnss.rtk_float.sigma_vertical_m = -1.0;
        assert_eq!(
            err(p, faults()).path,
            "sensors.gnss.rtk_float.sigma_vertical_m"
        );

        let mut p = all_enabled();
        p.gnss.reported_variance_scale = 0.0;
        assert_eq!(
            err(p, faults()).path,
            "sensors.gnss.reported_variance_scale"
        );

        let mut p = all_enabled();
        p.imu.bias_correlation_time_s = f64::NAN;
        assert_eq!(err(p, faults()).path, "sensors.imu.bias_correlation_time_s");

        let mut p = all_enabled();
        p.tracking_camera.yaw_random_walk_deg_per_rtm = -0.1;
        assert_eq!(
            err(p, faults()).path,
            "sensors.tracking_camera.yaw_random_walk_deg_per_rtm"
        );

        let mut p = all_enabled();
        p.wheel_odom.latency_ms = -1.0;
        assert_eq!(err(p, faults()).path, "sensors.wheel_odom.latency_ms");

        let mut f = faults();
        f.gnss.push(GnssFault {
            start_s: 10.0,
            end_s: 10.0,
            status: GnssStatusParam::Single,
        });
        let e = err(all_enabled(), f);
        assert_eq!(e.path, "faults.gnss[1].end_s");
        assert!(e.expected.contains("10"), "{e}");

        // A disabled sensor is not built, so its parameters are not checked; fault windows
        // always are.
        let mut p = all_enabled();
        p.imu.enabled = false;
        p.imu.rate_hz = -5.0;
        assert!(build_sensors(&p, &faults(), &c, None).is_ok());
        let mut f = faults();
        f.gnss[0].start_s = f64::INFINITY;
        p.gnss.enabled = false;
        assert_eq!(err(p, f).path, "faults.gnss[0].start_s");
    }

    fn debug_strings(msgs: &[TimedMessage]) -> Vec<String> {
        // Debug formatting, because NoFix positions are NaN (NaN != NaN under PartialEq);
        // `{:?}` of f64 is the shortest string that round-trips, so equal strings mean
        // bit-identical values.
        msgs.iter().map(|m| format!("{m:?}")).collect()
    }

    #[test]
    fn same_seed_gives_identical_messages_and_other_seed_differs() {
        let end = START + Nanos::from_secs(6);
        let go = |seed| {
            let mut s = build_sensors(&all_enabled(), &faults(), &ctx(seed), None).unwrap();
            run(&mut s, &circle_truth, end)
        };
        let a = go(7);
        let b = go(7);
        assert!(a.len() > 1000);
        assert_eq!(debug_strings(&a), debug_strings(&b));
        let c = go(8);
        assert_ne!(debug_strings(&a), debug_strings(&c));
        for m in &a {
            m.msg.validate().unwrap();
            assert!(m.arrival >= m.msg.stamp());
        }
        // Every kind of message is there.
        let has = |f: fn(&Message) -> bool| a.iter().any(|m| f(&m.msg));
        assert!(has(|m| matches!(m, Message::Imu(_))));
        assert!(has(|m| matches!(m, Message::GnssFix(_))));
        assert!(has(|m| matches!(m, Message::GnssVelocity(_))));
        assert!(has(|m| matches!(m, Message::TrackingOdom(_))));
        assert!(has(|m| matches!(m, Message::WheelOdom(_))));
    }

    #[test]
    fn a_sensor_does_not_change_when_others_are_toggled() {
        let end = START + Nanos::from_secs(6);
        let topic_msgs = |p: &SensorsParams, topic: &str| {
            let mut s = build_sensors(p, &faults(), &ctx(11), None).unwrap();
            let all = run(&mut s, &circle_truth, end);
            debug_strings(
                &all.into_iter()
                    .filter(|m| m.msg.topic() == topic)
                    .collect::<Vec<_>>(),
            )
        };
        let every = all_enabled();
        for (name, topic) in [
            ("imu", "/imu/data"),
            ("gnss", "/gnss/fix"),
            ("tracking_camera", "/tracking_camera/odom/sample"),
            ("wheel_odom", "/wheel/odom"),
        ] {
            let mut alone = SensorsParams::default();
            alone.imu.enabled = name == "imu";
            alone.gnss.enabled = name == "gnss";
            alone.tracking_camera.enabled = name == "tracking_camera";
            alone.wheel_odom.enabled = name == "wheel_odom";
            let a = topic_msgs(&every, topic);
            assert!(!a.is_empty(), "{name}");
            assert_eq!(
                a,
                topic_msgs(&alone, topic),
                "{name} changed with the others"
            );
        }
    }
}
