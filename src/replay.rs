//! `vinebench replay`: the estimators on a recording instead of a simulation.
//!
//! A vinebench recording carries its resolved scenario ([`recording::META_SCENARIO`]):
//! the estimators are rebuilt from it, the static transforms from `/tf_static`, and the
//! messages are fed in their recorded arrival order (publish time, ties in file order),
//! so the estimates equal the live run's bit for bit. The recorded scenario's visual SLAM
//! (`[slam]` and its baselines) runs too, on the recorded images, IMU and `camera_info`
//! (a recording made with `[recording] exclude_topics` over the image topics has none to
//! give it): same trajectories, `loops.csv` and SLAM metrics as live. So does its `[mapper]`,
//! on the recorded RGB-D frames: the same maps as live, scored against the world generated
//! again from the recorded scenario. A field recording needs a
//! topic-mapping file ([`ReplayConfig`], `--config`): which topic is the IMU, the GNSS
//! fix, the tracking camera, ...; the map origin (or the first fix) and estimator
//! parameters, and `[mapper]` for maps (built and exported, not scored). Topics nobody
//! asked for and message types vinebench does not decode are skipped and counted, never
//! fatal; a damaged file gives what it still holds.
//!
//! Outputs: `estimate_<source>.tum`, `ground_truth.tum` (from `/ground_truth/odom` when
//! present, which scoring then uses), `loops.csv` (with a SLAM and ground truth), `map/`,
//! `report.json`, `report.md`, `trajectories.svg`.

use crate::recording::reader::{self, ChannelInfo, RawMessage};
use crate::recording::ros::{self, TransformStamped};
use crate::recording::{self, RecordingError, topics};
use crate::scenario::{LoadedScenario, ScenarioError};
use crate::scoring::expect::ExpectationResult;
use crate::scoring::{self, PoseSpool, Poses, SourceScore, SpoolWriter, metrics};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashMap, VecDeque};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use thiserror::Error;
use vinebench_msgs::frames::names;
use vinebench_msgs::geodesy::{Geodetic, LocalEnu};
use vinebench_msgs::{
    FixStatus, FrameId, Message, Nanos, PoseSample, StaticTransforms, TimedMessage, Trajectory,
};
use vinebench_onboard::estimator::EstimatorSet;

/// A replay that could not be carried out.
#[derive(Debug, Error)]
pub enum ReplayError {
    /// The recording is unreadable.
    #[error(transparent)]
    Recording(#[from] RecordingError),
    /// The topic-mapping file or the recorded scenario is unusable.
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    /// The mapping file or the recording lacks something replay needs (named).
    #[error("{file}: {problem}")]
    Input {
        /// The file at fault (recording or mapping file).
        file: String,
        /// What is missing or wrong, and what was expected.
        problem: String,
    },
    /// Writing an output failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The output folder is in use, not empty or cannot be made.
    #[error(transparent)]
    Folder(crate::runner::RunError),
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> ReplayError + '_ {
    move |source| ReplayError::Io {
        path: path.display().to_string(),
        source,
    }
}

/// Which recorded topic feeds which estimator input (`[topics]` of a mapping file).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TopicMap {
    /// `sensor_msgs/Imu`.
    pub imu: Option<String>,
    /// `sensor_msgs/NavSatFix`.
    pub gnss_fix: Option<String>,
    /// `geometry_msgs/TwistWithCovarianceStamped` (ENU velocity of the antenna).
    pub gnss_velocity: Option<String>,
    /// `nav_msgs/Odometry` of a tracking camera (visual-inertial odometry).
    pub tracking_odom: Option<String>,
    /// `nav_msgs/Odometry` of the wheels or tracks.
    pub wheel_odom: Option<String>,
    /// `sensor_msgs/Imu` whose orientation is a dual-antenna GNSS heading (u-blox
    /// `navheading`, Septentrio `heading`): its yaw, ENU (REP-103), plus
    /// `[gnss] heading_offset_deg`.
    pub gnss_heading: Option<String>,
    /// `sensor_msgs/Image` and `sensor_msgs/CameraInfo` topics to pass on.
    #[serde(default)]
    pub cameras: Vec<String>,
    /// `tf2_msgs/TFMessage` with the static transforms (default `/tf_static`).
    pub tf_static: Option<String>,
    /// `tf2_msgs/TFMessage` with the moving transforms (default `/tf`): ROS 1 robots
    /// often publish their extrinsics here, over and over; a transform that never
    /// changes in the recording is taken as static (and listed in the report).
    pub tf: Option<String>,
    /// `nav_msgs/Odometry` of the body in `world` to score against (default
    /// `/ground_truth/odom` when the recording has it).
    pub ground_truth: Option<String>,
}

/// Most notes of one source listed on the console and in `report.md` (all are in
/// `report.json`).
pub const NOTES_LISTED: usize = 10;

impl ReplayReport {
    /// What the estimators did not use and why, one line each: messages dropped before
    /// them (by recorded topic and reason), each source's rejected messages by reason and
    /// its first [`NOTES_LISTED`] notes. For the console and `report.md`.
    pub fn estimator_notes(&self) -> Vec<String> {
        let mut out: Vec<String> = self.urdf_transforms.iter().cloned().collect();
        if !self.tf_as_static.is_empty() {
            let pairs: Vec<&str> = self
                .tf_as_static
                .iter()
                .map(|t| t.split(" (").next().unwrap_or(t))
                .collect();
            out.push(format!(
                "{} static transform(s) taken from repeats that never changed (no /tf_static \
                 for them; report.json lists the counts): {}",
                pairs.len(),
                pairs.join(", ")
            ));
        }
        if self.late_dropped > 0 {
            out.push(format!(
                "{} message(s) dropped: later than the re-ordering window",
                self.late_dropped
            ));
        }
        for (k, n) in &self.invalid_dropped {
            out.push(format!("{n} message(s) dropped as invalid: {k}"));
        }
        out.extend(self.stage_notes.iter().cloned());
        for src in &self.sources {
            let rejected: Vec<String> = src
                .rejected
                .iter()
                .map(|(why, n)| format!("{n} {why}"))
                .collect();
            if !rejected.is_empty() {
                out.push(format!("{}: not used: {}", src.name, rejected.join(", ")));
            }
            for note in src.notes.iter().take(NOTES_LISTED) {
                out.push(format!("{}: {note}", src.name));
            }
            if src.notes.len() > NOTES_LISTED {
                out.push(format!(
                    "{}: {} more note(s) in report.json",
                    src.name,
                    src.notes.len() - NOTES_LISTED
                ));
            }
        }
        out
    }
}

impl TopicMap {
    /// The recorded topic that feeds the input of internal topic `internal` (the
    /// estimators name messages by their input: `/gnss/fix`, ...), so that reports name
    /// what is in the user's recording; `internal` itself when unmapped (a vinebench
    /// recording records them under those names).
    pub fn recorded<'a>(&'a self, internal: &'a str) -> &'a str {
        let mapped = match internal {
            "/imu/data" => &self.imu,
            "/gnss/fix" => &self.gnss_fix,
            "/gnss/fix_velocity" => &self.gnss_velocity,
            "/tracking_camera/odom/sample" => &self.tracking_odom,
            "/wheel/odom" => &self.wheel_odom,
            "/gnss/heading" => &self.gnss_heading,
            _ => &None,
        };
        mapped.as_deref().unwrap_or(internal)
    }

    /// A `"<internal topic> <field>"` key with the recorded topic instead.
    fn recorded_key(&self, key: &str) -> String {
        match key.split_once(' ') {
            Some((topic, field)) => format!("{} {field}", self.recorded(topic)),
            None => self.recorded(key).to_string(),
        }
    }
}

/// A topic-mapping file for `vinebench replay --config` (see
/// `docs/field-topics.example.toml`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReplayConfig {
    /// Name used in the output folder and report (default: the recording's file stem).
    pub name: Option<String>,
    /// The robot's body frame in `/tf_static` (default `base_link`).
    pub body_frame: Option<String>,
    /// Recorded topics per estimator input.
    #[serde(default)]
    pub topics: TopicMap,
    /// Frame renames: recorded frame name → the name the transforms use.
    #[serde(default)]
    pub frames: BTreeMap<String, String>,
    /// `[[static_transforms]]`: extrinsics the recording lacks (or overrides of its
    /// `/tf_static`), as `static_transform_publisher` takes them.
    #[serde(default)]
    pub static_transforms: Vec<StaticTransformEntry>,
    /// The robot's URDF (relative to the mapping file): its fixed joints supply the
    /// extrinsics that neither `[[static_transforms]]`, `/tf_static` nor unchanging `/tf`
    /// transforms give. Any robot's URDF (xacro expanded); moving joints are left out.
    pub urdf: Option<PathBuf>,
    /// `[imu]`: how the recorded IMU reports its orientation.
    #[serde(default)]
    pub imu: ImuConventions,
    /// `[gnss]`: what the recorded fixes' covariance and altitude are worth.
    #[serde(default)]
    pub gnss: GnssConventions,
    /// Geodetic origin of the ENU world frame (default: the first GNSS fix with a
    /// position).
    pub origin: Option<Geodetic>,
    /// `[estimators]` as in a scenario file, over `scenarios/defaults.toml`.
    pub estimators: Option<toml::Table>,
    /// `[scoring]` as in a scenario file, over `scenarios/defaults.toml`.
    pub scoring: Option<toml::Table>,
    /// `[mapper]` as in a scenario file, over `scenarios/defaults.toml`: maps from the
    /// recorded RGB-D topics (RealSense names: `<cam>/color/image_raw`,
    /// `<cam>/aligned_depth_to_color/image_raw`, `<cam>/color/camera_info`, listed in
    /// `topics.cameras`) and the estimates. A field recording's maps are not scored.
    pub mapper: Option<toml::Table>,
    /// Expectations in the scenario language, on the estimate sources.
    #[serde(default)]
    pub expect: Vec<String>,
}

/// The axes an IMU reports in (`[imu] axes`).
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ImuAxes {
    /// REP-103/145: orientation `enu_from_flu` (x forward, y left, z up), rates and
    /// accelerations in the FLU IMU frame.
    #[default]
    Enu,
    /// Aerospace: orientation `ned_from_frd` (x forward, y right, z down), rates and
    /// accelerations in FRD (how many IMUs report natively: VectorNav, PX4/ArduPilot logs).
    Ned,
}

/// `[imu]` of a mapping file: the recorded IMU's conventions, converted to vinebench's
/// (ENU, true north, REP-103 body) before the estimators see a message.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImuConventions {
    /// Axes of the orientation, rates and accelerations (`"enu"` or `"ned"`).
    #[serde(default)]
    pub axes: ImuAxes,
    /// Magnetic declination at the site, degrees east of true north, for an IMU whose
    /// heading is referenced to magnetic north (a magnetometer AHRS).
    #[serde(default)]
    pub declination_deg: f64,
    /// A known offset of the IMU's heading, degrees, counter-clockwise seen from above:
    /// added to the recorded heading (after the declination).
    #[serde(default)]
    pub yaw_offset_deg: f64,
    /// `"absolute"` or `"relative"` (an IMU whose heading is not to be trusted: only roll
    /// and pitch are used, the heading comes from the GNSS course): sets
    /// `[estimators.eif] orientation_yaw`.
    pub yaw: Option<vinebench_onboard::estimator::OrientationYaw>,
    /// The IMU's noise profile by datasheet (`"mti-300"`, `"bno055"`, `"mpu-9250"`, ...,
    /// listed in `scenarios/defaults.toml`): sets `[estimators.eif] imu_profile`.
    pub profile: Option<String>,
}

impl ImuConventions {
    fn check(&self) -> Result<(), String> {
        for (key, v) in [
            ("imu.declination_deg", self.declination_deg),
            ("imu.yaw_offset_deg", self.yaw_offset_deg),
        ] {
            if !(v.is_finite() && v.abs() <= 360.0) {
                return Err(format!(
                    "`{key}`: expected degrees in [-360, 360], found {v}"
                ));
            }
        }
        Ok(())
    }

    /// True when messages need converting.
    fn converts(&self) -> bool {
        self.axes != ImuAxes::Enu || self.declination_deg != 0.0 || self.yaw_offset_deg != 0.0
    }

    /// Rewrites an IMU message into ENU, true north, REP-103 body axes.
    pub fn convert(&self, m: &mut vinebench_msgs::ImuMsg) {
        use nalgebra::{Matrix3, Vector3};
        let heading = UnitQuaternion::from_axis_angle(
            &Vector3::z_axis(),
            (self.yaw_offset_deg - self.declination_deg).to_radians(),
        );
        let (world, body) = match self.axes {
            ImuAxes::Enu => (heading, UnitQuaternion::identity()),
            ImuAxes::Ned => {
                // enu_from_ned swaps x and y and flips z; frd_from_flu flips y and z.
                let enu_from_ned = UnitQuaternion::from_matrix(&Matrix3::new(
                    0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0,
                ));
                let frd_from_flu =
                    UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
                (heading * enu_from_ned, frd_from_flu)
            }
        };
        m.orientation = m.orientation.map(|q| world * q * body);
        let (w, b) = (
            world.to_rotation_matrix().into_inner(),
            body.to_rotation_matrix().into_inner(),
        );
        // Orientation covariance is about the world axes; rates and accelerations are in
        // the body frame (flu_from_frd = frd_from_fluᵀ).
        m.orientation_covariance = w * m.orientation_covariance * w.transpose();
        m.angular_velocity = b.transpose() * m.angular_velocity;
        m.linear_acceleration = b.transpose() * m.linear_acceleration;
        m.angular_velocity_covariance = b.transpose() * m.angular_velocity_covariance * b;
        m.linear_acceleration_covariance = b.transpose() * m.linear_acceleration_covariance * b;
    }
}

/// `[gnss]` of a mapping file: fixes whose driver does not know their covariance
/// (`position_covariance_type` 0), and receivers whose altitude is poor or absent.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GnssConventions {
    /// `[horizontal, vertical]` 1σ, m, assumed for a fix of unknown covariance, by
    /// solution: stand-alone (NavSatFix status 0 or 1).
    #[serde(default = "GnssConventions::default_single")]
    pub unknown_sigma_single_m: [f64; 2],
    /// The same for RTK (NavSatFix status 2).
    #[serde(default = "GnssConventions::default_rtk")]
    pub unknown_sigma_rtk_m: [f64; 2],
    /// `"use"` the recorded altitude, or `"ignore"` it (receivers with a poor altitude,
    /// recordings without one): the fix's altitude is replaced by the map origin's with
    /// [`IGNORED_ALTITUDE_SIGMA_M`], so the horizontal estimate does not depend on it and
    /// the vertical is only held loosely.
    #[serde(default)]
    pub altitude: AltitudeUse,
    /// A dual-antenna heading's offset to the body's forward axis, degrees
    /// counter-clockwise: the mounting of the baseline (0 = main → aux antenna points
    /// forward; 90 = it points to the left).
    #[serde(default)]
    pub heading_offset_deg: f64,
    /// 1σ of a dual-antenna heading whose message gives no yaw variance, degrees.
    #[serde(default = "GnssConventions::default_heading_sigma")]
    pub heading_sigma_deg: f64,
}

/// Whether fix altitudes are used (`[gnss] altitude`).
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AltitudeUse {
    /// The recorded altitude and its variance.
    #[default]
    Use,
    /// The origin's altitude with [`IGNORED_ALTITUDE_SIGMA_M`].
    Ignore,
}

/// Vertical 1σ of a fix whose altitude is ignored, m.
pub const IGNORED_ALTITUDE_SIGMA_M: f64 = 30.0;

impl Default for GnssConventions {
    fn default() -> Self {
        GnssConventions {
            unknown_sigma_single_m: Self::default_single(),
            unknown_sigma_rtk_m: Self::default_rtk(),
            altitude: AltitudeUse::Use,
            heading_offset_deg: 0.0,
            heading_sigma_deg: Self::default_heading_sigma(),
        }
    }
}

impl GnssConventions {
    /// A dual-antenna heading over a 1 m baseline with RTK: about 0.3°; 1° leaves room.
    fn default_heading_sigma() -> f64 {
        1.0
    }

    /// A dual-antenna heading turned to the body (`heading_offset_deg`), with
    /// `heading_sigma_deg` where the message has no variance.
    pub fn apply_heading(&self, m: &mut vinebench_msgs::GnssHeadingMsg) {
        m.heading_rad += self.heading_offset_deg.to_radians();
        if !(m.variance_rad2.is_finite() && m.variance_rad2 > 0.0) {
            m.variance_rad2 = self.heading_sigma_deg.to_radians().powi(2);
        }
    }

    /// A consumer single-frequency receiver's stand-alone fix (u-blox M8: 2.5 m CEP).
    fn default_single() -> [f64; 2] {
        [2.5, 5.0]
    }
    /// An RTK solution (float and fixed alike, as a driver's status 2 does not say).
    fn default_rtk() -> [f64; 2] {
        [0.05, 0.1]
    }

    fn check(&self) -> Result<(), String> {
        for (key, v) in [
            ("gnss.unknown_sigma_single_m", self.unknown_sigma_single_m),
            ("gnss.unknown_sigma_rtk_m", self.unknown_sigma_rtk_m),
        ] {
            if !v.iter().all(|x| x.is_finite() && *x > 0.0) {
                return Err(format!(
                    "`{key}`: expected [horizontal, vertical] > 0 m, found {v:?}"
                ));
            }
        }
        if !(self.heading_offset_deg.is_finite() && self.heading_offset_deg.abs() <= 360.0) {
            return Err(format!(
                "`gnss.heading_offset_deg`: expected degrees in [-360, 360], found {}",
                self.heading_offset_deg
            ));
        }
        let s = self.heading_sigma_deg;
        if !(s.is_finite() && s > 0.0 && s <= 180.0) {
            return Err(format!(
                "`gnss.heading_sigma_deg`: expected degrees in (0, 180], found {s}"
            ));
        }
        Ok(())
    }

    /// Fills in an unknown covariance and applies `altitude`; `origin_alt_m` is the map
    /// origin's altitude.
    pub fn apply(&self, m: &mut vinebench_msgs::GnssFixMsg, origin_alt_m: f64) {
        use nalgebra::{Matrix3, Vector3};
        if m.status == FixStatus::NoFix {
            return;
        }
        if !m.position_covariance.iter().all(|c| c.is_finite()) {
            let [h, v] = match m.status {
                FixStatus::Single => self.unknown_sigma_single_m,
                _ => self.unknown_sigma_rtk_m,
            };
            m.position_covariance = Matrix3::from_diagonal(&Vector3::new(h * h, h * h, v * v));
        }
        if self.altitude == AltitudeUse::Ignore {
            m.position.alt_m = origin_alt_m;
            for k in 0..3 {
                m.position_covariance[(2, k)] = 0.0;
                m.position_covariance[(k, 2)] = 0.0;
            }
            m.position_covariance[(2, 2)] = IGNORED_ALTITUDE_SIGMA_M * IGNORED_ALTITUDE_SIGMA_M;
        }
    }
}

/// One `[[static_transforms]]` entry: `parent_from_child` as translation and either
/// roll-pitch-yaw (rad, fixed axes x-y-z as ROS's `rpy`) or a quaternion `[x, y, z, w]`
/// (neither: no rotation).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StaticTransformEntry {
    /// Parent frame.
    pub parent: String,
    /// Child frame.
    pub child: String,
    /// Translation of the child in the parent frame, m.
    #[serde(default)]
    pub xyz: [f64; 3],
    /// Roll, pitch, yaw, rad.
    pub rpy: Option<[f64; 3]>,
    /// Quaternion `[x, y, z, w]`.
    pub quaternion: Option<[f64; 4]>,
}

impl StaticTransformEntry {
    /// The transform, or what is wrong with the entry.
    fn transform(&self) -> Result<TransformStamped, String> {
        if self.parent.trim().is_empty() || self.child.trim().is_empty() {
            return Err("expected non-empty `parent` and `child` frames".into());
        }
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        if !finite(&self.xyz) {
            return Err(format!("`xyz` {:?} is not finite", self.xyz));
        }
        let rotation = match (self.rpy, self.quaternion) {
            (Some(_), Some(_)) => return Err("give `rpy` or `quaternion`, not both".into()),
            (Some(r), None) if finite(&r) => UnitQuaternion::from_euler_angles(r[0], r[1], r[2]),
            (None, Some(q)) if finite(&q) && q.iter().any(|x| *x != 0.0) => {
                // As a recorded /tf_static quaternion is read (kept bit for bit when unit).
                ros::unit_quaternion(q, "quaternion").map_err(|e| e.to_string())?
            }
            (None, None) => UnitQuaternion::identity(),
            (r, q) => {
                return Err(format!(
                    "expected a finite `rpy` (rad) or a non-zero `quaternion` [x, y, z, w], found \
                     rpy {r:?}, quaternion {q:?}"
                ));
            }
        };
        Ok(TransformStamped {
            stamp: Nanos(0),
            parent: FrameId::new(&self.parent),
            child: FrameId::new(&self.child),
            parent_from_child: Isometry3::from_parts(
                Translation3::new(self.xyz[0], self.xyz[1], self.xyz[2]),
                rotation,
            ),
        })
    }
}

/// The largest topic-mapping file read (bytes); a larger one (or `/dev/zero`) is refused.
pub const MAX_MAPPING_BYTES: u64 = 1 << 20;

impl ReplayConfig {
    /// Reads a mapping file (at most [`MAX_MAPPING_BYTES`]); errors name the file, the key
    /// and what was expected.
    pub fn load(path: &Path) -> Result<ReplayConfig, ReplayError> {
        let file = path.display().to_string();
        let text = crate::fsio::read_text_bounded(path, MAX_MAPPING_BYTES).map_err(|e| {
            match e.kind() {
                // Too large or not text: the file is there but is no mapping file.
                std::io::ErrorKind::FileTooLarge | std::io::ErrorKind::InvalidData => {
                    ReplayError::Input {
                        file: file.clone(),
                        problem: format!(
                            "{e}: expected a topic-mapping TOML file \
                             (see docs/field-topics.example.toml)"
                        ),
                    }
                }
                _ => io_err(path)(e),
            }
        })?;
        ReplayConfig::from_str(&text, &file)
    }

    /// Parses a mapping file's text; errors name `file`, the key and what was expected.
    #[allow(clippy::should_implement_trait)]
    pub fn from_str(text: &str, file: &str) -> Result<ReplayConfig, ReplayError> {
        let de = toml::Deserializer::parse(text).map_err(|e| ReplayError::Input {
            file: file.to_string(),
            problem: format!("TOML syntax error: {}", e.message().trim()),
        })?;
        let cfg: ReplayConfig =
            serde_path_to_error::deserialize(de).map_err(|e| ReplayError::Input {
                file: file.to_string(),
                problem: format!("`{}`: {}", e.path(), e.inner().message().trim()),
            })?;
        cfg.imu
            .check()
            .and_then(|()| cfg.gnss.check())
            .map_err(|problem| ReplayError::Input {
                file: file.to_string(),
                problem,
            })?;
        for (i, t) in cfg.static_transforms.iter().enumerate() {
            t.transform().map_err(|problem| ReplayError::Input {
                file: file.to_string(),
                problem: format!("`static_transforms[{i}]`: {problem}"),
            })?;
        }
        Ok(cfg)
    }

    /// The mapping of a vinebench recording: vinebench's own topic names, every camera.
    fn vinebench() -> ReplayConfig {
        ReplayConfig {
            topics: TopicMap {
                imu: Some("/imu/data".into()),
                gnss_fix: Some("/gnss/fix".into()),
                gnss_velocity: Some("/gnss/fix_velocity".into()),
                tracking_odom: Some("/tracking_camera/odom/sample".into()),
                wheel_odom: Some("/wheel/odom".into()),
                ..TopicMap::default()
            },
            ..ReplayConfig::default()
        }
    }
}

/// Options of [`replay`].
#[derive(Clone, Debug, Default)]
pub struct ReplayOptions {
    /// Topic-mapping file (required for recordings not made by vinebench).
    pub config: Option<PathBuf>,
    /// Output folder (default `<runs_root>/replay-<name>-<UTC stamp>/`).
    pub out_dir: Option<PathBuf>,
    /// Parent of default output folders.
    pub runs_root: PathBuf,
    /// An `out_dir` that already holds files is cleared of a run's outputs (else refused);
    /// see [`crate::runner::RunFolder`].
    pub replace: bool,
}

/// One estimate source of a replay.
#[derive(Clone, Debug, Serialize)]
pub struct ReplaySource {
    /// Source name.
    pub name: String,
    /// Poses produced.
    pub poses: usize,
    /// Metrics against ground truth, when the recording has it.
    pub score: Option<SourceScore>,
    /// Messages used by kind.
    pub used: BTreeMap<String, u64>,
    /// Messages not used, by reason.
    pub rejected: BTreeMap<String, u64>,
    /// Notes.
    pub notes: Vec<String>,
    /// The SLAM's own metrics (tracking losses, loops and, with ground truth, their
    /// correctness; see `crate::scoring::expect::SLAM_METRICS`); empty for other sources.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub slam: BTreeMap<String, f64>,
    /// Without ground truth: the source against the GNSS track (the `gnss` source).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vs_gnss: Option<GnssResiduals>,
    /// The filter's GNSS position NIS against its chi-square band (EIF).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gnss_nis: Option<NisSummary>,
}

/// A source against the GNSS track (`gnss`: eq. (1) per fix) in a recording without
/// ground truth: the residual between the GNSS pose and the source's pose interpolated at
/// the fix's stamp. With RTK fixes it bounds the source's error by the fixes' own
/// centimetres; with single fixes it is mostly the receiver's metres.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GnssResiduals {
    /// GNSS poses compared (the source has poses within [`RESIDUAL_MAX_GAP`] around them).
    pub n: usize,
    /// Horizontal residual: RMS, median, 95th percentile and largest, m.
    pub horizontal_rmse_m: f64,
    /// See `horizontal_rmse_m`.
    pub horizontal_median_m: f64,
    /// See `horizontal_rmse_m`.
    pub horizontal_p95_m: f64,
    /// See `horizontal_rmse_m`.
    pub horizontal_max_m: f64,
    /// Vertical residual RMS, m.
    pub vertical_rmse_m: f64,
}

/// The normalized innovation squared of a filter's GNSS position fixes: a consistency
/// check that needs no ground truth. For a consistent filter fed independent fixes its
/// mean is `dof` and 95 % of the values fall inside `band`; a mean far above says the
/// filter (or the receiver's covariance) is over-confident, the failure that matters. Far
/// below is what correlated receiver errors give (consecutive RTK fixes wander together
/// and the filter follows them, so each new fix agrees with it better than its σ says) or
/// a pessimistic covariance.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct NisSummary {
    /// Degrees of freedom (3: east, north, up).
    pub dof: u32,
    /// Fixes.
    pub n: u64,
    /// Mean NIS.
    pub mean: f64,
    /// The χ²(dof) 95 % band.
    pub band: (f64, f64),
    /// Fraction inside the band.
    pub in_band: f64,
    /// Fraction above it.
    pub above: f64,
    /// Fraction below it.
    pub below: f64,
}

impl NisSummary {
    fn of(s: &vinebench_onboard::estimator::NisSeries) -> NisSummary {
        let n = s.n.max(1) as f64;
        NisSummary {
            dof: s.dof,
            n: s.n,
            mean: s.mean(),
            band: s.band,
            in_band: s.in_band(),
            above: s.above as f64 / n,
            below: s.below as f64 / n,
        }
    }

    /// One line for people: the numbers and what they mean.
    pub fn verdict(&self) -> String {
        let what = if self.mean > 2.0 * f64::from(self.dof) {
            "over-confident: its covariance (or the receiver's) is too small for the errors"
        } else if self.mean < 0.5 * f64::from(self.dof) {
            "below χ²: the fixes agree with the filter better than their σ says (a \
             receiver's slowly wandering error, which the filter follows, does this; so does a \
             pessimistic receiver covariance): no sign of overconfidence"
        } else {
            "consistent with its covariance"
        };
        format!(
            "GNSS NIS mean {:.2} (χ²({}) expects {}), {:.1} % inside its 95 % band [{:.3}, \
             {:.2}], {:.1} % above: {what}",
            self.mean,
            self.dof,
            self.dof,
            100.0 * self.in_band,
            self.band.0,
            self.band.1,
            100.0 * self.above
        )
    }
}

/// A source's pose is interpolated at a GNSS stamp only between poses at most this far
/// apart.
pub const RESIDUAL_MAX_GAP: Nanos = Nanos::from_secs(1);

/// `(stamp, horizontal, vertical)` residuals of `est` against the poses of `reference`,
/// with `est`'s position interpolated linearly at each reference stamp (both in time
/// order, one pass each).
fn residuals_against(
    reference: &dyn scoring::Poses,
    est: &dyn scoring::Poses,
) -> Vec<(Nanos, f64, f64)> {
    let mut out = Vec::new();
    let mut it = est.poses().peekable();
    let mut prev: Option<scoring::spool::Pose> = None;
    for (t, r) in reference.poses() {
        while let Some(p) = it.peek() {
            if p.0 > t {
                break;
            }
            prev = it.next();
        }
        let p = match (prev, it.peek()) {
            (Some(a), _) if a.0 == t => a.1.translation.vector,
            (Some(a), Some(b)) if b.0 - a.0 <= RESIDUAL_MAX_GAP => {
                let s = (t - a.0).as_nanos() as f64 / (b.0 - a.0).as_nanos() as f64;
                a.1.translation.vector.lerp(&b.1.translation.vector, s)
            }
            _ => continue,
        };
        let d = p - r.translation.vector;
        out.push((t, d.x.hypot(d.y), d.z));
    }
    out
}

/// The summary of [`residuals_against`].
fn summarize_residuals(res: &[(Nanos, f64, f64)]) -> Option<GnssResiduals> {
    if res.is_empty() {
        return None;
    }
    let n = res.len();
    let mut h: Vec<f64> = res.iter().map(|r| r.1).collect();
    h.sort_by(f64::total_cmp);
    let q = |p: f64| h[((p * (n - 1) as f64).round() as usize).min(n - 1)];
    let rms = |f: &dyn Fn(&(Nanos, f64, f64)) -> f64| {
        (res.iter().map(|r| f(r).powi(2)).sum::<f64>() / n as f64).sqrt()
    };
    Some(GnssResiduals {
        n,
        horizontal_rmse_m: rms(&|r| r.1),
        horizontal_median_m: q(0.5),
        horizontal_p95_m: q(0.95),
        horizontal_max_m: h[n - 1],
        vertical_rmse_m: rms(&|r| r.2),
    })
}

/// The report of a replay (`report.json`; `report.md` for people).
#[derive(Clone, Debug, Serialize)]
pub struct ReplayReport {
    /// vinebench version that produced it.
    pub vinebench_version: &'static str,
    /// The recording.
    pub recording: String,
    /// The mapping file, if one was given.
    pub config: Option<String>,
    /// Name (scenario name, or the mapping's, or the file stem).
    pub name: String,
    /// What the recording lost (a damaged or truncated file), if anything.
    pub damage: Option<String>,
    /// Messages fed to the estimators, per recorded topic.
    pub replayed: BTreeMap<String, u64>,
    /// Messages not fed, by `topic (type): reason`.
    pub skipped: BTreeMap<String, u64>,
    /// Messages that did not decode, by topic, with the first error.
    pub decode_errors: BTreeMap<String, (u64, String)>,
    /// Mapped topics the recording does not have.
    pub missing_topics: Vec<String>,
    /// Messages that came in the file after one published more than
    /// [`FILE_REORDER_WINDOW`] later (fed late, in file order).
    pub late_in_file: u64,
    /// Messages dropped before the estimators: late beyond the re-ordering window.
    pub late_dropped: u64,
    /// Messages dropped as invalid, by `topic field`.
    pub invalid_dropped: BTreeMap<String, u64>,
    /// Notes of the estimation stage (unknown frames).
    pub stage_notes: Vec<String>,
    /// Transforms taken as static because `/tf` repeated them unchanged (a ROS 1 robot
    /// without `/tf_static`), one line each.
    pub tf_as_static: Vec<String>,
    /// What the mapping file's `urdf` supplied, if it names one.
    pub urdf_transforms: Option<String>,
    /// Ground-truth poses (0 without `/ground_truth/odom`).
    pub ground_truth_poses: usize,
    /// Closed-loop metrics of the ground truth itself.
    pub ground_truth: Option<metrics::LoopMetrics>,
    /// One entry per estimator.
    pub sources: Vec<ReplaySource>,
    /// The maps of `[mapper]` (recorded scenario or mapping file), scored when the
    /// recording is a vinebench run (its world is generated again from the recorded
    /// scenario for the true surfaces).
    pub maps: Vec<crate::runner::mapping::MapReport>,
    /// Expectation outcomes (with ground truth only).
    pub expectations: Vec<ExpectationResult>,
    /// Why the replay gave nothing usable (no estimate source produced a pose), if so:
    /// `vinebench replay` then exits 2.
    pub nothing_usable: Option<String>,
    /// Requested sources that produced no pose while others did, each with why: the
    /// replay fails (exit 1).
    pub without_poses: Vec<String>,
    /// True when every expectation holds and every requested source produced poses.
    pub passed: bool,
}

/// The outcome of [`replay`].
#[derive(Debug)]
pub struct ReplayOutcome {
    /// The output folder.
    pub dir: PathBuf,
    /// The report.
    pub report: ReplayReport,
}

/// The role a mapped topic plays.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
enum Role {
    Imu,
    GnssFix,
    GnssVelocity,
    TrackingOdom,
    WheelOdom,
    GnssHeading,
    Camera,
    TfStatic,
    Tf,
    GroundTruth,
}

impl Role {
    fn expected_types(self) -> &'static [&'static str] {
        match self {
            Role::Imu | Role::GnssHeading => &["sensor_msgs/Imu"],
            Role::GnssFix => &["sensor_msgs/NavSatFix"],
            Role::GnssVelocity => &["geometry_msgs/TwistWithCovarianceStamped"],
            Role::TrackingOdom | Role::WheelOdom | Role::GroundTruth => &["nav_msgs/Odometry"],
            Role::Camera => &["sensor_msgs/Image", "sensor_msgs/CameraInfo"],
            Role::TfStatic | Role::Tf => &["tf2_msgs/TFMessage"],
        }
    }
    fn key(self) -> &'static str {
        match self {
            Role::Imu => "topics.imu",
            Role::GnssFix => "topics.gnss_fix",
            Role::GnssVelocity => "topics.gnss_velocity",
            Role::TrackingOdom => "topics.tracking_odom",
            Role::WheelOdom => "topics.wheel_odom",
            Role::GnssHeading => "topics.gnss_heading",
            Role::Camera => "topics.cameras",
            Role::TfStatic => "topics.tf_static",
            Role::Tf => "topics.tf",
            Role::GroundTruth => "topics.ground_truth",
        }
    }
}

/// `sensor_msgs/msg/Imu` and `sensor_msgs/Imu` → `sensor_msgs/Imu`.
fn short_type(schema_name: &str) -> String {
    schema_name.replace("/msg/", "/")
}

// Short-lived (one message at a time); boxing would allocate per message.
#[allow(clippy::large_enum_variant)]
enum Decoded {
    Sensor(Message),
    Tf(Vec<TransformStamped>),
    Truth(PoseSample),
}

/// What the scans collect. The first scan keeps the transforms, the ground truth and
/// the first GNSS fix, and checks every mapped topic's type; the second decodes the
/// sensor messages and feeds them on, so memory does not grow with the recording.
#[derive(Default)]
struct Collected {
    /// Transforms (first scan).
    entries: Vec<Decoded>,
    /// What `/tf` holds, per parent → child (first scan).
    repeated_tf: RepeatedTf,
    /// Ground truth (first scan), on its way to disk.
    truth: TruthSpool,
    /// The first GNSS fix with a position (first scan): the default map origin.
    first_fix: Option<Geodetic>,
    /// Sensor messages of a mapped topic with a supported type (first scan).
    sensor_messages: u64,
    replayed: BTreeMap<String, u64>,
    skipped: BTreeMap<String, u64>,
    decode_errors: BTreeMap<String, (u64, String)>,
    wrong_type: Vec<String>,
}

/// Most distinct parent → child pairs [`RepeatedTf`] follows (a tf tree has tens).
pub const MAX_TF_PAIRS: usize = 4096;

/// The transforms of `/tf`, per parent → child: the first one, how often it came and
/// whether it ever changed (by more than 1 µm or 1 µrad). Memory grows with the number of
/// distinct pairs only (at most [`MAX_TF_PAIRS`]).
#[derive(Default)]
struct RepeatedTf {
    pairs: BTreeMap<(String, String), (TransformStamped, u64, bool)>,
    /// Pairs beyond [`MAX_TF_PAIRS`], not followed.
    overflow: u64,
}

impl RepeatedTf {
    fn observe(&mut self, ts: Vec<TransformStamped>) {
        for t in ts {
            let key = (
                bare_frame(t.parent.as_str()).to_string(),
                bare_frame(t.child.as_str()).to_string(),
            );
            match self.pairs.get_mut(&key) {
                Some((first, n, changed)) => {
                    *n += 1;
                    let d = first.parent_from_child.inverse() * t.parent_from_child;
                    if d.translation.vector.norm() > 1e-6 || d.rotation.angle() > 1e-6 {
                        *changed = true;
                    }
                }
                None => {
                    if self.pairs.len() < MAX_TF_PAIRS {
                        self.pairs.insert(key, (t, 1, false));
                    } else {
                        self.overflow += 1;
                    }
                }
            }
        }
    }

    /// The transforms that came at least twice and never changed.
    fn unchanging(&self) -> impl Iterator<Item = (&TransformStamped, u64)> {
        self.pairs
            .values()
            .filter(|(_, n, changed)| *n >= 2 && !changed)
            .map(|(t, n, _)| (t, *n))
    }
}

/// A recording's ground truth on its way to a spool (in the system's temporary folder:
/// the replay's folder is claimed only once the recording has been read), so memory does
/// not grow with the recording. Samples in stamp order (a vinebench recording's) go
/// straight to disk; one that is not after the last is set aside and merged at the end
/// as a stable sort by stamp that keeps the first recorded of equal stamps.
#[derive(Default)]
struct TruthSpool {
    writer: Option<SpoolWriter>,
    stragglers: Vec<PoseSample>,
    error: Option<std::io::Error>,
}

impl TruthSpool {
    fn push(&mut self, s: PoseSample) {
        if self.error.is_some() {
            return;
        }
        let w = match &mut self.writer {
            Some(w) => w,
            None => match SpoolWriter::create(None, "ground-truth") {
                Ok(w) => self.writer.insert(w),
                Err(e) => {
                    self.error = Some(e);
                    return;
                }
            },
        };
        match w.push(&s) {
            Ok(true) => {}
            Ok(false) => self.stragglers.push(s),
            Err(e) => self.error = Some(e),
        }
    }

    fn finish(self) -> std::io::Result<PoseSpool> {
        if let Some(e) = self.error {
            return Err(e);
        }
        let spool = match self.writer {
            Some(w) => w.finish()?,
            None => SpoolWriter::create(None, "ground-truth")?.finish()?,
        };
        if self.stragglers.is_empty() {
            return Ok(spool);
        }
        let mut all = spool.to_trajectory()?.samples;
        all.extend(self.stragglers);
        all.sort_by_key(|s| s.stamp);
        all.dedup_by_key(|s| s.stamp);
        PoseSpool::from_trajectory(None, "ground-truth", &Trajectory { samples: all })
    }
}

/// Messages fed between two moves of the estimates to their spools.
const DRAIN_EVERY_MESSAGES: u64 = 256;

/// [`ReplayError::Io`] of a spool in the system's temporary folder.
fn spool_err(label: &str) -> impl FnOnce(std::io::Error) -> ReplayError + '_ {
    move |source| ReplayError::Io {
        path: format!("{label} spool in {}", std::env::temp_dir().display()),
        source,
    }
}

fn bump(map: &mut BTreeMap<String, u64>, key: &str) {
    match map.get_mut(key) {
        Some(n) => *n += 1,
        None => {
            map.insert(key.to_string(), 1);
        }
    }
}

/// Which of the two scans is running.
#[derive(Copy, Clone, PartialEq, Eq)]
enum Scan {
    /// Roles, types, transforms, ground truth, the first fix; counts what is skipped.
    Index,
    /// Sensor messages decoded and returned; counts what is replayed or undecodable.
    Sensors,
}

/// Looks at one message by its role. [`Scan::Index`] counts unmapped topics and
/// unsupported types and keeps transforms and ground truth; [`Scan::Sensors`] decodes
/// sensor messages and returns them.
fn collect(
    scan: Scan,
    roles: &HashMap<String, Role>,
    camera_topics: &mut HashMap<String, Arc<str>>,
    out: &mut Collected,
    ch: &ChannelInfo,
    m: &RawMessage<'_>,
) -> Option<Message> {
    let ty = short_type(&ch.schema_name);
    let Some(&role) = roles.get(&ch.topic) else {
        if scan == Scan::Index {
            let why = if ch.topic.starts_with(topics::ESTIMATE_PREFIX) || ch.topic == topics::TF {
                "recorded estimate, not replayed"
            } else {
                "topic not mapped"
            };
            bump(&mut out.skipped, &format!("{} ({ty}): {why}", ch.topic));
        }
        return None;
    };
    if ch.message_encoding != "cdr" || !role.expected_types().contains(&ty.as_str()) {
        if scan == Scan::Sensors {
            return None;
        }
        let key = format!(
            "{} ({ty}, {}): unsupported type for {}",
            ch.topic,
            ch.message_encoding,
            role.key()
        );
        if !out.skipped.contains_key(&key) {
            out.wrong_type.push(format!(
                "`{}` = {:?} carries {ty} ({}), expected {}",
                role.key(),
                ch.topic,
                ch.message_encoding,
                role.expected_types().join(" or ")
            ));
        }
        bump(&mut out.skipped, &key);
        return None;
    }
    if role == Role::Tf {
        if scan == Scan::Index {
            match ros::decode_tf(m.data) {
                Ok(ts) => out.repeated_tf.observe(ts),
                Err(e) => {
                    out.decode_errors
                        .entry(ch.topic.clone())
                        .or_insert_with(|| (0, format!("{ty} #{}: {e}", m.sequence)))
                        .0 += 1;
                }
            }
        }
        return None;
    }
    let is_sensor = !matches!(role, Role::GroundTruth | Role::TfStatic);
    match scan {
        Scan::Index if is_sensor => {
            out.sensor_messages += 1;
            if role == Role::GnssFix && out.first_fix.is_none() {
                // A fix without altitude (NaN: `[gnss] altitude = "ignore"` recordings)
                // still places the origin, at altitude 0.
                out.first_fix = ros::decode_nav_sat_fix(m.data)
                    .ok()
                    .filter(|f| f.status != FixStatus::NoFix)
                    .map(|f| Geodetic {
                        alt_m: if f.position.alt_m.is_finite() {
                            f.position.alt_m
                        } else {
                            0.0
                        },
                        ..f.position
                    })
                    .filter(Geodetic::is_valid);
            }
            return None;
        }
        Scan::Sensors if !is_sensor => return None,
        _ => {}
    }
    let decoded = match role {
        Role::Imu => ros::decode_imu(m.data).map(|x| Decoded::Sensor(Message::Imu(x))),
        Role::GnssFix => {
            ros::decode_nav_sat_fix(m.data).map(|x| Decoded::Sensor(Message::GnssFix(x)))
        }
        Role::GnssVelocity => {
            ros::decode_gnss_velocity(m.data).map(|x| Decoded::Sensor(Message::GnssVelocity(x)))
        }
        Role::TrackingOdom => {
            ros::decode_odometry(m.data).map(|x| Decoded::Sensor(Message::TrackingOdom(x)))
        }
        Role::WheelOdom => {
            ros::decode_odometry(m.data).map(|x| Decoded::Sensor(Message::WheelOdom(x)))
        }
        Role::GnssHeading => {
            ros::decode_heading(m.data).map(|x| Decoded::Sensor(Message::GnssHeading(x)))
        }
        Role::GroundTruth => ros::decode_odometry(m.data).map(|x| {
            Decoded::Truth(PoseSample {
                stamp: x.stamp,
                world_from_body: x.pose,
                covariance: None,
            })
        }),
        Role::TfStatic => ros::decode_tf(m.data).map(Decoded::Tf),
        Role::Tf => return None,
        Role::Camera => {
            let topic = camera_topics
                .entry(ch.topic.clone())
                .or_insert_with(|| Arc::from(ch.topic.as_str()))
                .clone();
            if ty == "sensor_msgs/Image" {
                ros::decode_image(m.data, &topic).map(|x| Decoded::Sensor(Message::Image(x)))
            } else {
                ros::decode_camera_info(m.data, &topic)
                    .map(|x| Decoded::Sensor(Message::CameraInfo(x)))
            }
        }
    };
    match decoded {
        Ok(Decoded::Sensor(msg)) => {
            bump(&mut out.replayed, &ch.topic);
            Some(msg)
        }
        Ok(Decoded::Truth(sample)) => {
            out.truth.push(sample);
            None
        }
        Ok(msg) => {
            out.entries.push(msg);
            None
        }
        Err(e) => {
            out.decode_errors
                .entry(ch.topic.clone())
                .or_insert_with(|| (0, format!("{ty} #{}: {e}", m.sequence)))
                .0 += 1;
            None
        }
    }
}

/// How far (publish time) a message may come after a later-published one in the file
/// and still be fed in publish-time order. vinebench writes messages in delivery order
/// (none is late); a robot's recorder writes them as they arrive.
pub const FILE_REORDER_WINDOW: Nanos = Nanos(1_000_000_000);

/// Orders decoded messages by publish time (ties in file order) within
/// [`FILE_REORDER_WINDOW`], handing them on as soon as no earlier one can follow.
struct PublishOrder<T> {
    heap: std::collections::BinaryHeap<std::cmp::Reverse<(Nanos, u64, Ordered<T>)>>,
    seq: u64,
    newest: Option<Nanos>,
    released: Option<Nanos>,
    /// Messages older than one already handed on (fed late, in file order).
    late: u64,
}

/// A message in [`PublishOrder`], ordered by `(publish, seq)` only.
struct Ordered<T>(T);

impl<T> PartialEq for Ordered<T> {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}
impl<T> Eq for Ordered<T> {}
impl<T> PartialOrd for Ordered<T> {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl<T> Ord for Ordered<T> {
    fn cmp(&self, _: &Self) -> std::cmp::Ordering {
        std::cmp::Ordering::Equal
    }
}

impl<T> PublishOrder<T> {
    fn new() -> PublishOrder<T> {
        PublishOrder {
            heap: std::collections::BinaryHeap::new(),
            seq: 0,
            newest: None,
            released: None,
            late: 0,
        }
    }

    /// Adds a message; `feed` gets every message that can no longer be preceded.
    fn push(&mut self, publish: Nanos, msg: T, feed: &mut impl FnMut(Nanos, T)) {
        if self.released.is_some_and(|r| publish < r) {
            self.late += 1;
            feed(publish, msg);
            return;
        }
        self.heap
            .push(std::cmp::Reverse((publish, self.seq, Ordered(msg))));
        self.seq += 1;
        let newest = self.newest.map_or(publish, |n| n.max(publish));
        self.newest = Some(newest);
        while let Some(std::cmp::Reverse((p, _, _))) = self.heap.peek() {
            if *p + FILE_REORDER_WINDOW > newest {
                break;
            }
            self.pop(feed);
        }
    }

    fn pop(&mut self, feed: &mut impl FnMut(Nanos, T)) {
        if let Some(std::cmp::Reverse((p, _, Ordered(m)))) = self.heap.pop() {
            self.released = Some(p);
            feed(p, m);
        }
    }

    /// Hands on what is left.
    fn finish(&mut self, feed: &mut impl FnMut(Nanos, T)) {
        while !self.heap.is_empty() {
            self.pop(feed);
        }
    }
}

/// `body_from_<frame>` for every frame connected to `body` in the transforms (edges
/// used in either direction); direct children of the body keep their transform exactly.
fn static_transforms(body: &str, tf: &[TransformStamped]) -> StaticTransforms {
    let mut out = StaticTransforms::new(body);
    let mut queue: VecDeque<(FrameId, Isometry3<f64>)> =
        VecDeque::from([(FrameId::new(body), Isometry3::identity())]);
    let mut seen = vec![FrameId::new(body)];
    while let Some((frame, body_from_frame)) = queue.pop_front() {
        for t in tf {
            let (next, frame_from_next) = if t.parent == frame {
                (&t.child, t.parent_from_child)
            } else if t.child == frame {
                (&t.parent, t.parent_from_child.inverse())
            } else {
                continue;
            };
            if seen.contains(next) {
                continue;
            }
            seen.push(next.clone());
            let body_from_next = if frame.as_str() == body {
                frame_from_next
            } else {
                body_from_frame * frame_from_next
            };
            out.insert(next.as_str(), body_from_next);
            queue.push_back((next.clone(), body_from_next));
        }
    }
    out
}

/// A frame name as tf keys it: ROS 1's leading `/` dropped (as tf2 does, so `"/gps"`
/// needs no rename), then renamed by the mapping's `[frames]` (given with or without the
/// slash).
fn rename(frames: &BTreeMap<String, String>, f: &mut FrameId) {
    let name = f.as_str();
    let bare = bare_frame(name);
    let to = frames.get(name).or_else(|| {
        frames
            .iter()
            .find(|(k, _)| bare_frame(k) == bare)
            .map(|(_, v)| v)
    });
    if let Some(to) = to {
        *f = FrameId::new(bare_frame(to));
    } else if bare.len() != name.len() {
        *f = FrameId::new(bare);
    }
}

/// `name` without a leading `/`.
fn bare_frame(name: &str) -> &str {
    name.strip_prefix('/').unwrap_or(name)
}

fn rename_message(frames: &BTreeMap<String, String>, m: &mut Message) {
    match m {
        Message::Imu(x) => rename(frames, &mut x.frame_id),
        Message::GnssFix(x) => rename(frames, &mut x.frame_id),
        Message::GnssVelocity(x) => rename(frames, &mut x.frame_id),
        Message::TrackingOdom(x) | Message::WheelOdom(x) => {
            rename(frames, &mut x.frame_id);
            rename(frames, &mut x.child_frame_id);
        }
        Message::Image(x) => rename(frames, &mut x.frame_id),
        Message::CameraInfo(x) => rename(frames, &mut x.frame_id),
        Message::GnssHeading(x) => rename(frames, &mut x.frame_id),
        Message::GnssSky(x) => rename(frames, &mut x.frame_id),
    }
}

/// Sets `[estimators.eif] key = value` for the mapping file's `from` key, refusing a
/// different value given there too.
fn set_eif(
    estimators: &mut toml::Table,
    key: &str,
    value: toml::Value,
    from: &str,
    file: &str,
) -> Result<(), ReplayError> {
    let eif = estimators
        .entry("eif")
        .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    if let toml::Value::Table(eif) = eif {
        match eif.get(key) {
            Some(v) if *v != value => {
                return Err(ReplayError::Input {
                    file: file.to_string(),
                    problem: format!(
                        "`{from}` = {value} and `estimators.eif.{key}` = {v} disagree: give one \
                         of them"
                    ),
                });
            }
            _ => {
                eif.insert(key.into(), value);
            }
        }
    }
    Ok(())
}

/// The scenario a mapping file implies: its `[estimators]`, `[scoring]`, `expect` and
/// origin over the defaults.
fn scenario_of_config(
    cfg: &ReplayConfig,
    file: &str,
    name: &str,
    origin: Geodetic,
) -> Result<LoadedScenario, ReplayError> {
    let mut t = toml::Table::new();
    t.insert("name".into(), toml::Value::String(name.to_string()));
    let origin_value = toml::Value::try_from(origin).map_err(|e| ReplayError::Input {
        file: file.to_string(),
        problem: format!("origin: {e}"),
    })?;
    t.insert("origin".into(), origin_value);
    let mut estimators = cfg.estimators.clone().unwrap_or_default();
    if let Some(yaw) = cfg.imu.yaw {
        let value = toml::Value::try_from(yaw).map_err(|e| ReplayError::Input {
            file: file.to_string(),
            problem: format!("imu.yaw: {e}"),
        })?;
        set_eif(&mut estimators, "orientation_yaw", value, "imu.yaw", file)?;
    }
    if let Some(profile) = &cfg.imu.profile {
        let value = toml::Value::String(profile.clone());
        set_eif(&mut estimators, "imu_profile", value, "imu.profile", file)?;
    }
    // What the mapped topics can feed, where the mapping file does not say: wheel
    // odometry into the EIF, and the sources whose input is recorded.
    if cfg.topics.wheel_odom.is_some()
        && let toml::Value::Table(eif) = estimators
            .entry("eif")
            .or_insert_with(|| toml::Value::Table(toml::Table::new()))
    {
        eif.entry("use_wheel_odometry")
            .or_insert(toml::Value::Boolean(true));
    }
    if !estimators.contains_key("run") {
        let run: Vec<toml::Value> = [
            Some("eif"),
            Some("gnss"),
            cfg.topics.tracking_odom.as_ref().map(|_| "tracking_camera"),
            cfg.topics.wheel_odom.as_ref().map(|_| "dead_reckoning"),
        ]
        .into_iter()
        .flatten()
        .map(|k| toml::Value::String(k.into()))
        .collect();
        estimators.insert("run".into(), toml::Value::Array(run));
    }
    if let Some(toml::Value::Table(eif)) = estimators.get("eif")
        && eif.is_empty()
    {
        estimators.remove("eif");
    }
    if !estimators.is_empty() {
        t.insert("estimators".into(), toml::Value::Table(estimators));
    }
    if let Some(s) = &cfg.scoring {
        t.insert("scoring".into(), toml::Value::Table(s.clone()));
    }
    if let Some(m) = &cfg.mapper {
        t.insert("mapper".into(), toml::Value::Table(m.clone()));
    }
    t.insert(
        "expect".into(),
        toml::Value::Array(
            cfg.expect
                .iter()
                .cloned()
                .map(toml::Value::String)
                .collect(),
        ),
    );
    let text = toml::to_string(&t).map_err(|e| ReplayError::Input {
        file: file.to_string(),
        problem: e.to_string(),
    })?;
    LoadedScenario::from_str(&text, file).map_err(|e| match e {
        // Locations would point into the generated text: name the key only.
        ScenarioError::Field { path, message, .. } => ReplayError::Input {
            file: file.to_string(),
            problem: format!("`{path}`: {message}"),
        },
        e => ReplayError::Scenario(e),
    })
}

/// The render geometry of a recorded vinebench scenario: its world generated again from
/// the recorded seed and `[world]` (the same bits as the live run's), with its
/// `[world.mesh]` file if it has one, for map scoring.
fn truth_renderer(sc: &LoadedScenario) -> Result<vinebench_sim::render::shade::Renderer, String> {
    let s = &sc.scenario;
    let world =
        vinebench_sim::world::World::generate(s.seed, &s.world).map_err(|e| e.to_string())?;
    let mesh = crate::runner::load_world_mesh(sc).map_err(|e| e.to_string())?;
    vinebench_sim::render::build_renderer_with_mesh(&world, &s.render, mesh.as_ref())
        .map_err(|e| e.to_string())
}

/// Whether a recording whose scenario metadata is missing says it was made by vinebench:
/// its header names vinebench, or its summary indexes a scenario metadata record.
fn vinebench_made(summary: &reader::McapSummary) -> bool {
    summary.library.starts_with("vinebench")
        || summary
            .metadata_index
            .iter()
            .any(|n| n == recording::META_SCENARIO)
}

fn safe_name(s: &str) -> String {
    let n: String = s
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.') {
                c
            } else {
                '-'
            }
        })
        .collect();
    if n.is_empty() { "recording".into() } else { n }
}

/// Replays a recording through the estimators and writes the outputs.
pub fn replay(file: &Path, opts: &ReplayOptions) -> Result<ReplayOutcome, ReplayError> {
    let file_name = file.display().to_string();
    let user_cfg = opts.config.as_deref().map(ReplayConfig::load).transpose()?;
    let cfg_file = opts.config.as_ref().map(|p| p.display().to_string());
    let cfg = user_cfg.clone().unwrap_or_else(ReplayConfig::vinebench);
    let t = &cfg.topics;
    let mut roles: HashMap<String, Role> = HashMap::new();
    let mapped = [
        (&t.imu, Role::Imu),
        (&t.gnss_fix, Role::GnssFix),
        (&t.gnss_velocity, Role::GnssVelocity),
        (&t.tracking_odom, Role::TrackingOdom),
        (&t.wheel_odom, Role::WheelOdom),
        (&t.gnss_heading, Role::GnssHeading),
    ];
    // The roles the mapping names, each topic at most once; then the default topics of
    // the static transforms and the ground truth, where the mapping did not use them.
    let mapping_file = cfg_file.clone().unwrap_or_else(|| file_name.clone());
    let explicit: Vec<(Role, &String)> = mapped
        .iter()
        .filter_map(|(topic, role)| Some((*role, topic.as_ref()?)))
        .chain(t.cameras.iter().map(|c| (Role::Camera, c)))
        .chain(t.tf_static.iter().map(|x| (Role::TfStatic, x)))
        .chain(t.tf.iter().map(|x| (Role::Tf, x)))
        .chain(t.ground_truth.iter().map(|x| (Role::GroundTruth, x)))
        .collect();
    for (role, topic) in &explicit {
        if let Some(&other) = roles.get(topic.as_str())
            && other != *role
        {
            return Err(ReplayError::Input {
                file: mapping_file,
                problem: format!(
                    "`{}` and `{}` both name {topic:?}: each recorded topic feeds one input",
                    other.key(),
                    role.key()
                ),
            });
        }
        roles.insert(topic.to_string(), *role);
    }
    let tf_static_topic = t
        .tf_static
        .clone()
        .unwrap_or_else(|| topics::TF_STATIC.to_string());
    roles
        .entry(tf_static_topic.clone())
        .or_insert(Role::TfStatic);
    // `/tf`, where the mapping did not use it: scanned for transforms that never change.
    // (A vinebench recording has `/tf_static`; its `/tf` holds the recorded estimates.)
    let tf_topic = t.tf.clone().unwrap_or_else(|| topics::TF.to_string());
    if user_cfg.is_some() {
        roles.entry(tf_topic.clone()).or_insert(Role::Tf);
    }
    let truth_topic = t
        .ground_truth
        .clone()
        .unwrap_or_else(|| topics::GROUND_TRUTH_ODOM.to_string());
    roles
        .entry(truth_topic.clone())
        .or_insert(Role::GroundTruth);
    let all_cameras = user_cfg.is_none();

    let mut got = Collected::default();
    let mut camera_topics = HashMap::new();
    let summary = crate::recording::scan_any(file, |ch, m| {
        // A vinebench recording passes every camera on.
        if all_cameras
            && !roles.contains_key(&ch.topic)
            && matches!(
                short_type(&ch.schema_name).as_str(),
                "sensor_msgs/Image" | "sensor_msgs/CameraInfo"
            )
        {
            roles.insert(ch.topic.clone(), Role::Camera);
        }
        collect(Scan::Index, &roles, &mut camera_topics, &mut got, ch, m);
    })?;
    let damage = summary.damage.as_ref().map(|d| d.to_string());
    // Every topic a mapping file names must be recorded with a type its input accepts (a
    // channel whose schema was lost with a damaged chunk has no type to check).
    for (role, topic) in explicit.iter().filter(|_| user_cfg.is_some()) {
        for ch in summary.channels.values() {
            let ty = short_type(&ch.schema_name);
            if &&ch.topic != topic
                || ch.schema_name.is_empty()
                || (ch.message_encoding == "cdr" && role.expected_types().contains(&ty.as_str()))
            {
                continue;
            }
            return Err(ReplayError::Input {
                file: mapping_file,
                problem: format!(
                    "`{key}` = {topic:?}: {file_name} records {topic} as {ty} ({enc}); \
                     `{key}` accepts {want} (cdr)",
                    key = role.key(),
                    enc = ch.message_encoding,
                    want = role.expected_types().join(" or "),
                ),
            });
        }
    }
    // What a missing piece says when the file is damaged: the cause, not only the symptom.
    let because = damage
        .as_deref()
        .map(|d| format!(" — the recording is damaged: {d}"))
        .unwrap_or_default();
    if let Some(e) = got.wrong_type.first() {
        return Err(ReplayError::Input {
            file: cfg_file.clone().unwrap_or_else(|| file_name.clone()),
            problem: format!("{e} (in {file_name})"),
        });
    }
    let present: Vec<&str> = summary
        .channels
        .values()
        .map(|c| c.topic.as_str())
        .collect();
    let missing_topics: Vec<String> = mapped
        .iter()
        .filter_map(|(topic, role)| {
            let topic = topic.as_ref()?;
            (!present.contains(&topic.as_str())).then(|| format!("{} = {topic:?}", role.key()))
        })
        .chain(
            t.cameras
                .iter()
                .filter(|c| !present.contains(&c.as_str()))
                .map(|c| format!("topics.cameras: {c:?}")),
        )
        .collect();
    let topic_list = {
        let mut p = present.clone();
        p.sort_unstable();
        p.dedup();
        p.join(", ")
    };
    if user_cfg.is_some() {
        for m in &missing_topics {
            eprintln!("warning: {file_name} has no topic {m} (its topics: {topic_list})");
        }
    }

    // The scenario: recorded (vinebench) or from the mapping file.
    let meta = summary.metadata.get(recording::META_SCENARIO);
    let stem = file
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_else(|| "recording".into());
    let mut sc = match (
        &user_cfg,
        meta.and_then(|m| m.get(recording::META_KEY_TOML)),
    ) {
        (None, Some(toml_text)) => {
            LoadedScenario::from_str(toml_text, &format!("{file_name} (recorded scenario)"))
                .map_err(|e| match &summary.damage {
                    Some(_) => ReplayError::Input {
                        file: file_name.clone(),
                        problem: format!("recorded scenario unusable: {e}{because}"),
                    },
                    None => ReplayError::Scenario(e),
                })?
        }
        (None, None) if vinebench_made(&summary) => {
            return Err(ReplayError::Input {
                file: file_name,
                problem: format!(
                    "a vinebench recording whose scenario metadata (`{}`) is damaged or lost, \
                     so the estimators cannot be rebuilt from it{because}; replay its sensors \
                     with --config and a topic-mapping file (see \
                     docs/field-topics.example.toml)",
                    recording::META_SCENARIO
                ),
            });
        }
        (None, None) if summary.damage.is_some() => {
            return Err(ReplayError::Input {
                file: file_name,
                problem: format!(
                    "no `{}` metadata{because}: if vinebench \
                     made it, its scenario is among what was lost; otherwise pass --config \
                     with a topic-mapping file (see docs/field-topics.example.toml); its \
                     topics: {topic_list}",
                    recording::META_SCENARIO
                ),
            });
        }
        (None, None) => {
            return Err(ReplayError::Input {
                file: file_name,
                problem: format!(
                    "not a vinebench recording (no `{}` metadata): pass --config with a \
                     topic-mapping file (see docs/field-topics.example.toml); its topics: \
                     {topic_list}",
                    recording::META_SCENARIO
                ),
            });
        }
        (Some(c), _) => {
            let cf = cfg_file.clone().unwrap_or_default();
            let origin = match c.origin {
                Some(o) => o,
                None => got.first_fix.ok_or_else(|| ReplayError::Input {
                    file: cf.clone(),
                    problem: format!(
                        "no `origin` and no GNSS fix with a position on {:?} in {file_name}: \
                         expected [origin] lat_deg, lon_deg, alt_m",
                        t.gnss_fix.as_deref().unwrap_or("(topics.gnss_fix not set)")
                    ),
                })?,
            };
            let name = safe_name(c.name.as_deref().unwrap_or(&stem));
            scenario_of_config(c, &cf, &name, origin)?
        }
    };

    if user_cfg.is_none()
        && let Some(f) = meta.and_then(|m| m.get("file"))
    {
        // Files the recorded scenario names (the SLAM's vocabulary) are relative to it.
        sc.base_dir = Path::new(f)
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_default();
    }

    // Static transforms.
    let body = bare_frame(cfg.body_frame.as_deref().unwrap_or(names::BASE_LINK));
    // The mapping file's transforms first: they take precedence over the recorded ones.
    let mut tf: Vec<TransformStamped> = cfg
        .static_transforms
        .iter()
        .filter_map(|t| t.transform().ok())
        .map(|mut t| {
            rename(&cfg.frames, &mut t.parent);
            rename(&cfg.frames, &mut t.child);
            t
        })
        .collect();
    for e in std::mem::take(&mut got.entries) {
        match e {
            Decoded::Tf(mut ts) => {
                for x in &mut ts {
                    rename(&cfg.frames, &mut x.parent);
                    rename(&cfg.frames, &mut x.child);
                }
                tf.extend(ts);
            }
            Decoded::Truth(_) | Decoded::Sensor(_) => {}
        }
    }
    // Transforms that `/tf` repeated unchanged, for frames the mapping and `/tf_static`
    // do not place.
    let mut tf_as_static = Vec::new();
    for (t, n) in got.repeated_tf.unchanging() {
        let mut t = t.clone();
        rename(&cfg.frames, &mut t.parent);
        rename(&cfg.frames, &mut t.child);
        if tf.iter().any(|x| x.child == t.child) {
            continue;
        }
        tf_as_static.push(format!(
            "{} → {} ({n} messages on {tf_topic}, never changed)",
            t.parent.as_str(),
            t.child.as_str()
        ));
        tf.push(t);
    }
    let mut urdf_transforms = None;
    if let Some(urdf) = &cfg.urdf {
        let path = match opts.config.as_deref().and_then(Path::parent) {
            Some(base) if urdf.is_relative() => base.join(urdf),
            _ => urdf.clone(),
        };
        let joints =
            vinebench_sim::robot::RobotModel::fixed_joints_of_file(&path).map_err(|e| {
                ReplayError::Input {
                    file: cfg_file.clone().unwrap_or_else(|| file_name.clone()),
                    problem: format!("`urdf` = {:?}: {e}", urdf.display().to_string()),
                }
            })?;
        let mut added = 0;
        for (parent, child, iso) in joints {
            let mut t = TransformStamped {
                stamp: Nanos(0),
                parent: FrameId::new(&parent),
                child: FrameId::new(&child),
                parent_from_child: iso,
            };
            rename(&cfg.frames, &mut t.parent);
            rename(&cfg.frames, &mut t.child);
            if !tf.iter().any(|x| x.child == t.child) {
                tf.push(t);
                added += 1;
            }
        }
        urdf_transforms = Some(format!(
            "{added} fixed joint(s) of {} used for frames the recording does not place",
            path.display()
        ));
    }
    if got.repeated_tf.overflow > 0 {
        tf_as_static.push(format!(
            "{} transform(s) on {tf_topic} beyond {MAX_TF_PAIRS} frame pairs not examined",
            got.repeated_tf.overflow
        ));
    }
    if tf.is_empty() {
        return Err(ReplayError::Input {
            file: file_name,
            problem: format!(
                "no static transforms on {tf_static_topic:?} (nor unchanging ones on \
                 {tf_topic:?}) and no `[[static_transforms]]` in \
                 a mapping file: the estimators need body_from_<sensor frame> for every sensor \
                 (its topics: {topic_list}){because}"
            ),
        });
    }
    let static_tf = static_transforms(body, &tf);
    if static_tf.body_from.is_empty() {
        return Err(ReplayError::Input {
            file: cfg_file.unwrap_or(file_name),
            problem: format!(
                "body frame `{body}` is not in {tf_static_topic}: expected `body_frame` to name \
                 one of {:?}",
                tf.iter().map(|t| t.parent.as_str()).collect::<Vec<_>>()
            ),
        });
    }
    if got.sensor_messages == 0 {
        return Err(ReplayError::Input {
            file: file_name,
            problem: format!(
                "no usable sensor message (mapped: {}; its topics: {topic_list}){because}",
                roles.keys().cloned().collect::<Vec<_>>().join(", ")
            ),
        });
    }
    let truth = std::mem::take(&mut got.truth)
        .finish()
        .map_err(spool_err("ground-truth"))?;

    let s = &sc.scenario;
    // The visual SLAM of a vinebench recording's `[slam]` (it needs the image topics).
    let slam_topics: Vec<String> = s
        .slam
        .cameras
        .iter()
        .flat_map(|c| vinebench_onboard::slam::system::stereo_image_topics(c))
        .collect();
    let unrecorded: Vec<&String> = slam_topics
        .iter()
        .filter(|t| !present.contains(&t.as_str()))
        .collect();
    let mut missing_topics = missing_topics;
    if user_cfg.is_none() && s.slam.enabled && !unrecorded.is_empty() {
        // A run recorded with its images excluded: nothing for the SLAM to see.
        missing_topics.push(format!(
            "slam: {} not recorded (excluded by [recording] exclude_topics?), SLAM not replayed",
            unrecorded
                .iter()
                .map(|t| t.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    let mut slam = if user_cfg.is_none() && unrecorded.is_empty() {
        crate::runner::slam_from_scenario(&sc, &static_tf, None).map_err(|e| {
            ReplayError::Input {
                file: file_name.clone(),
                problem: format!("recorded scenario: {e}"),
            }
        })?
    } else {
        Vec::new()
    };
    // The maps of `[mapper]`: a vinebench run recorded without its depth images is noted
    // and replayed without maps; a mapping file that asks for maps needs the depth topics.
    let camera_topics_present: Vec<&str> = present
        .iter()
        .copied()
        .filter(|t| roles.get(*t) == Some(&Role::Camera))
        .collect();
    let depth_recorded = camera_topics_present
        .iter()
        .any(|t| t.ends_with(vinebench_onboard::mapper::DEPTH_SUFFIX));
    let mut mapping = if s.mapper.enabled && user_cfg.is_none() && !depth_recorded {
        missing_topics.push(
            "mapper: no depth images recorded (excluded by [recording] exclude_topics?), maps \
             not built"
                .to_string(),
        );
        None
    } else {
        crate::runner::mapping::MappingStage::from_scenario(
            &sc,
            &static_tf,
            Some(&camera_topics_present),
        )
        .map_err(|e| ReplayError::Input {
            file: cfg_file.clone().unwrap_or_else(|| file_name.clone()),
            problem: e.to_string(),
        })?
    };
    let mut map_error: Option<vinebench_onboard::mapper::MapperError> = None;
    let mut slam_error: Option<vinebench_onboard::slam::SlamError> = None;
    let mut estimators =
        EstimatorSet::new(&s.estimators, static_tf.clone(), LocalEnu::new(s.origin)).map_err(
            |e| ReplayError::Input {
                file: sc.file.clone(),
                problem: e.to_string(),
            },
        )?;
    // The estimates go to disk as they are produced (a mapper reads them as they grow:
    // then they stay in memory).
    let mut spools =
        crate::runner::EstimateSpools::new(None, &estimators).map_err(spool_err("estimate"))?;
    let drain = mapping.is_none();
    let mut fed: u64 = 0;
    let mut spool_error: Option<std::io::Error> = None;
    // Second scan: sensor messages in arrival (publish-time) order, ties in the recorded
    // (delivery) order, straight into the estimators.
    let mut order = PublishOrder::new();
    let mut feed = |arrival: Nanos, msg: Message| {
        if slam_error.is_none() {
            for v in &mut slam {
                if let Err(e) = v.push(&msg) {
                    slam_error = Some(e);
                    break;
                }
            }
        }
        let tm = TimedMessage { arrival, msg };
        estimators.push(&tm);
        fed += 1;
        if drain
            && fed.is_multiple_of(DRAIN_EVERY_MESSAGES)
            && spool_error.is_none()
            && let Err(e) = spools.drain(&mut estimators)
        {
            spool_error = Some(e);
        }
        // After the estimators, as in a live run: the mappers integrate what the
        // estimates now cover.
        if map_error.is_none()
            && let Some(m) = &mut mapping
            && let Err(e) = m.push(&tm.msg, &estimators)
        {
            map_error = Some(e);
        }
    };
    let origin_alt_m = sc.scenario.origin.alt_m;
    crate::recording::scan_any(file, |ch, m| {
        if let Some(mut msg) = collect(Scan::Sensors, &roles, &mut camera_topics, &mut got, ch, m) {
            rename_message(&cfg.frames, &mut msg);
            match &mut msg {
                Message::Imu(imu) if cfg.imu.converts() => cfg.imu.convert(imu),
                Message::GnssFix(fix) => cfg.gnss.apply(fix, origin_alt_m),
                Message::GnssHeading(h) => cfg.gnss.apply_heading(h),
                _ => {}
            }
            order.push(m.publish_time, msg, &mut feed);
        }
    })?;
    order.finish(&mut feed);
    if let Some(e) = spool_error {
        return Err(spool_err("estimate")(e));
    }
    if let Some(e) = slam_error {
        return Err(ReplayError::Input {
            file: file_name,
            problem: e.to_string(),
        });
    }
    if let Some(e) = map_error {
        return Err(ReplayError::Input {
            file: file_name,
            problem: format!("mapper: {e}"),
        });
    }
    if got.replayed.is_empty() {
        return Err(ReplayError::Input {
            file: file_name,
            problem: format!(
                "no sensor message decodes ({}){because}",
                got.decode_errors
                    .iter()
                    .map(|(t, (n, e))| format!("{t}: {n} × {e}"))
                    .collect::<Vec<_>>()
                    .join("; ")
            ),
        });
    }
    let mut out = estimators.finish();
    let slam: Vec<vinebench_onboard::slam::SlamOutput> =
        slam.into_iter().map(|v| v.finish()).collect();
    out.estimators
        .extend(slam.iter().map(vinebench_onboard::slam::estimator_output));
    let mapping = match mapping {
        Some(m) => {
            // The true surfaces of a vinebench run: its world, generated again.
            let truth = if user_cfg.is_none() {
                Some(Arc::new(truth_renderer(&sc).map_err(|e| {
                    ReplayError::Input {
                        file: file_name.clone(),
                        problem: format!("recorded scenario: {e}"),
                    }
                })?))
            } else {
                None
            };
            Some(
                m.finish(&out.estimators, truth)
                    .map_err(|e| ReplayError::Input {
                        file: file_name.clone(),
                        problem: format!("mapper: {e}"),
                    })?,
            )
        }
        None => None,
    };
    let maps = mapping
        .as_ref()
        .map(crate::runner::mapping::score)
        .unwrap_or_default();
    let estimates = spools
        .finish(std::mem::take(&mut out.estimators))
        .map_err(spool_err("estimate"))?;

    // Outputs.
    let name = safe_name(&s.name);
    // The folder is this replay's until it returns, as a run's (see `RunFolder`).
    let folder = crate::runner::RunFolder::claim(
        opts.out_dir.as_deref(),
        &opts.runs_root,
        &format!("replay-{name}"),
        &crate::runner::utc_stamp(),
        opts.replace,
    )
    .map_err(ReplayError::Folder)?;
    let dir = folder.path().to_path_buf();
    if let Some(m) = &mapping {
        crate::runner::mapping::export(&dir, m).map_err(|e| ReplayError::Io {
            path: dir
                .join(crate::runner::mapping::MAP_DIR)
                .display()
                .to_string(),
            source: std::io::Error::other(e.to_string()),
        })?;
    }
    for e in &estimates {
        let p = dir.join(format!("estimate_{}.tum", e.name));
        scoring::tum::write_tum(&p, &e.poses).map_err(io_err(&p))?;
    }
    let have_truth = !truth.is_empty();
    if have_truth {
        let p = dir.join("ground_truth.tum");
        scoring::tum::write_tum(&p, &truth).map_err(io_err(&p))?;
    }
    let fault_windows: Vec<(Nanos, Nanos)> = if user_cfg.is_none() {
        s.faults
            .gnss
            .iter()
            .map(|f| {
                (
                    sc.start + Nanos::from_secs_f64(f.start_s),
                    sc.start + Nanos::from_secs_f64(f.end_s),
                )
            })
            .collect()
    } else {
        Vec::new()
    };
    // The SLAM's loops against the recorded truth (`loops.csv`, as a live run writes).
    let th = s.scoring.loop_thresholds();
    // Loop scoring looks the truth up at the loops' stamps: with a SLAM (which holds its
    // keyframes in memory anyway) the truth is read into memory for it.
    let truth_in_memory = if slam.is_empty() {
        Trajectory::new()
    } else {
        truth.to_trajectory().map_err(spool_err("ground-truth"))?
    };
    let loop_scores: Vec<scoring::loops::LoopScore> = slam
        .iter()
        .map(|o| scoring::loops::score_loops(&o.loops, &truth_in_memory, &th))
        .collect();
    drop(truth_in_memory);
    if !slam.is_empty() && have_truth {
        let t0 = truth.first().map_or(Nanos(0), |s| s.0);
        let named: Vec<(&str, &scoring::loops::LoopScore)> =
            slam.iter().map(|o| o.source).zip(&loop_scores).collect();
        let p = dir.join("loops.csv");
        crate::fsio::write_atomic(&p, scoring::loops::loops_csv(&named, t0).as_bytes())
            .map_err(io_err(&p))?;
    }
    let slam_metrics = |name: &str| -> BTreeMap<String, f64> {
        let Some((o, l)) = slam
            .iter()
            .zip(&loop_scores)
            .find(|(o, _)| o.source == name)
        else {
            return BTreeMap::new();
        };
        crate::scoring::expect::SLAM_METRICS
            .iter()
            .filter_map(|(m, _)| {
                let v = o.metric(m).or_else(|| l.metric(m).filter(|_| have_truth))?;
                Some((m.to_string(), v))
            })
            .collect()
    };
    // Without ground truth: every source against the GNSS track, and the EIF's NIS.
    let gnss_track = estimates
        .iter()
        .find(|e| e.name == "gnss" && !e.poses.is_empty());
    let mut residual_series: Vec<(&'static str, Vec<(Nanos, f64)>)> = Vec::new();
    let mut vs_gnss: BTreeMap<&str, GnssResiduals> = BTreeMap::new();
    if let Some(g) = gnss_track.filter(|_| !have_truth) {
        for e in estimates.iter().filter(|e| e.name != "gnss") {
            let res = residuals_against(&g.poses, &e.poses);
            if let Some(summary) = summarize_residuals(&res) {
                vs_gnss.insert(e.name, summary);
                residual_series.push((
                    e.name,
                    scoring::plots::thin_errors(res.iter().map(|r| (r.0, r.1)).collect()),
                ));
            }
        }
        g.poses.check().map_err(spool_err("estimate"))?;
    }
    let sources: Vec<ReplaySource> = estimates
        .iter()
        .map(|e| ReplaySource {
            vs_gnss: vs_gnss.get(e.name).cloned(),
            gnss_nis: e.stats.gnss_nis.as_ref().map(NisSummary::of),
            slam: slam_metrics(e.name),
            name: e.name.to_string(),
            poses: e.poses.len(),
            score: have_truth.then(|| {
                let mut score = scoring::score_source(&truth, &e.poses, &s.scoring, &fault_windows);
                // Only what an error plot would draw is kept (millions of poses otherwise).
                score.ate_errors =
                    scoring::plots::thin_errors(std::mem::take(&mut score.ate_errors));
                score
            }),
            used: e.stats.used.clone(),
            rejected: e.stats.rejected.clone(),
            notes: e.stats.notes.clone(),
        })
        .collect();
    // A score from part of a trajectory (a spool that could not be read back) is never
    // reported.
    truth.check().map_err(spool_err("ground-truth"))?;
    for e in &estimates {
        e.poses.check().map_err(spool_err("estimate"))?;
    }
    let robot: BTreeMap<String, f64> = summary
        .metadata
        .get(recording::META_RUN)
        .map(|m| {
            m.iter()
                .filter_map(|(k, v)| Some((k.clone(), v.parse::<f64>().ok()?)))
                .collect()
        })
        .unwrap_or_default();
    let expectations: Vec<ExpectationResult> = if have_truth {
        sc.expectations
            .iter()
            .map(|x| {
                x.evaluate(|metric, source| {
                    if source == crate::scoring::expect::ROBOT_SOURCE {
                        return robot.get(metric).copied();
                    }
                    if crate::runner::mapping::is_map_metric(metric) {
                        return maps.iter().find(|m| m.source == source)?.metric(metric);
                    }
                    let r = sources.iter().find(|r| r.name == source)?;
                    r.score
                        .as_ref()
                        .and_then(|x| x.metric(metric))
                        .or_else(|| r.slam.get(metric).copied())
                })
            })
            .collect()
    } else {
        Vec::new()
    };
    let nothing_usable = sources.iter().all(|s| s.poses == 0).then(|| {
        let per_source: Vec<String> = sources
            .iter()
            .map(|s| {
                let used: u64 = s.used.values().sum();
                let rejected: u64 = s.rejected.values().sum();
                format!(
                    "{} 0 poses ({used} messages used, {rejected} rejected)",
                    s.name
                )
            })
            .collect();
        format!(
            "{file_name}: no estimate source produced a pose ({}; {} messages replayed){}: \
             nothing usable",
            if per_source.is_empty() {
                "no estimator configured".to_string()
            } else {
                per_source.join(", ")
            },
            got.replayed.values().sum::<u64>(),
            damage
                .as_deref()
                .map(|d| format!("; the recording is damaged: {d}"))
                .unwrap_or_default()
        )
    });
    // A source the mapping file requests that produced nothing fails the replay (exit 1)
    // even when others did: each is named with why (its first note, or what it lacked).
    // (A vinebench recording replays its scenario as the live run did: its expectations
    // decide, and a SLAM without recorded images has nothing to run on.)
    let without_poses: Vec<String> = if nothing_usable.is_some() || user_cfg.is_none() {
        Vec::new()
    } else {
        sources
            .iter()
            .filter(|s| s.poses == 0)
            .map(|s| {
                let used: u64 = s.used.values().sum();
                let why = s.notes.first().cloned().unwrap_or_else(|| {
                    let needs = match s.name.as_str() {
                        "eif" | "gnss" => "topics.imu (with orientation) and topics.gnss_fix",
                        "tracking_camera" => "topics.tracking_odom and a GNSS fix to anchor on",
                        "dead_reckoning" => "topics.wheel_odom and topics.imu (with orientation)",
                        _ => "its input topics",
                    };
                    if used == 0 && s.rejected.is_empty() {
                        format!("it received no input: it needs {needs}")
                    } else {
                        format!("{used} messages used, rejected: {:?}", s.rejected)
                    }
                });
                format!("{} produced no pose: {why}", s.name)
            })
            .collect()
    };
    let passed = expectations.iter().all(|x| x.holds)
        && nothing_usable.is_none()
        && without_poses.is_empty();
    let report = ReplayReport {
        vinebench_version: env!("CARGO_PKG_VERSION"),
        recording: file_name,
        config: cfg_file,
        name: s.name.clone(),
        damage,
        replayed: got.replayed,
        skipped: got.skipped,
        decode_errors: got.decode_errors,
        missing_topics,
        late_in_file: order.late,
        late_dropped: out.stage.late_total(),
        invalid_dropped: out
            .stage
            .invalid_by_topic_field()
            .into_iter()
            .map(|(k, n)| (cfg.topics.recorded_key(&k), n))
            .collect(),
        stage_notes: out.stage.notes.clone(),
        tf_as_static,
        urdf_transforms,
        ground_truth_poses: truth.len(),
        ground_truth: metrics::closed_loop(&truth).ok(),
        sources,
        maps,
        expectations,
        nothing_usable,
        without_poses,
        passed,
    };
    write_report(&dir, &report, &truth, &estimates, &residual_series)?;
    Ok(ReplayOutcome { dir, report })
}

/// `report.md`'s section for a recording without ground truth: the sources against the
/// GNSS track (table, top view, residuals over time) and the EIF's NIS (with its plot).
fn no_truth_section(
    md: &mut String,
    dir: &Path,
    report: &ReplayReport,
    estimates: &[crate::runner::Estimate],
    residual_series: &[(&str, Vec<(Nanos, f64)>)],
) {
    let with_residuals: Vec<&ReplaySource> = report
        .sources
        .iter()
        .filter(|s| s.vs_gnss.is_some())
        .collect();
    let gnss = estimates
        .iter()
        .find(|e| e.name == "gnss" && !e.poses.is_empty());
    let _ = writeln!(md, "\n## Against the GNSS track (no ground truth)\n");
    let Some(gnss) = gnss else {
        let _ = writeln!(
            md,
            "No `gnss` source ran (add \"gnss\" to `[estimators] run`): nothing to compare with."
        );
        return;
    };
    let _ = writeln!(
        md,
        "Each source's position at the GNSS poses (eq. 1: antenna fix and AHRS orientation), \
         interpolated. With RTK fixes the residual bounds the source's error to a few \
         centimetres more than the receiver's; with single fixes it is mostly the receiver's.\n\n\
         | source | fixes | horizontal RMS [m] | median [m] | p95 [m] | max [m] | vertical RMS [m] |\n\
         |---|---:|---:|---:|---:|---:|---:|"
    );
    for s in &with_residuals {
        if let Some(r) = &s.vs_gnss {
            let _ = writeln!(
                md,
                "| {} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} |",
                s.name,
                r.n,
                r.horizontal_rmse_m,
                r.horizontal_median_m,
                r.horizontal_p95_m,
                r.horizontal_max_m,
                r.vertical_rmse_m
            );
        }
    }
    let named: Vec<(&str, &dyn scoring::Poses)> = estimates
        .iter()
        .filter(|e| e.name != "gnss")
        .map(|e| (e.name, &e.poses as &dyn scoring::Poses))
        .collect();
    let t0 = gnss.poses.first().map_or(Nanos(0), |p| p.0);
    fn plot(md: &mut String, file: &str, title: &str, r: Result<(), scoring::plots::PlotError>) {
        match r {
            Ok(()) => {
                let _ = writeln!(md, "\n![{title}]({file})");
            }
            Err(e) => {
                let _ = writeln!(md, "\n{file}: {e}");
            }
        }
    }
    plot(
        md,
        "trajectories.svg",
        "trajectories against the GNSS track",
        scoring::plots::plot_trajectories_against_svg(
            dir.join("trajectories.svg"),
            "GNSS (eq. 1)",
            &gnss.poses,
            &named,
        ),
    );
    let series: Vec<(&str, &[(Nanos, f64)])> = residual_series
        .iter()
        .map(|(n, s)| (*n, s.as_slice()))
        .collect();
    if !series.is_empty() {
        plot(
            md,
            "gnss_residuals.svg",
            "horizontal residual to the GNSS track",
            scoring::plots::plot_series_svg(
                dir.join("gnss_residuals.svg"),
                "Horizontal distance to the GNSS track",
                "horizontal residual (m)",
                &series,
                t0,
                &[],
            ),
        );
    }
    for (s, e) in report.sources.iter().zip(estimates) {
        let (Some(nis), Some(points)) = (&s.gnss_nis, &e.stats.gnss_nis) else {
            continue;
        };
        let _ = writeln!(md, "\n**{}**: {}.", s.name, nis.verdict());
        let file = format!("nis_{}.svg", s.name);
        plot(
            md,
            &file,
            "GNSS NIS",
            scoring::plots::plot_series_svg(
                dir.join(&file),
                &format!("{}: GNSS position NIS (χ²(3) if consistent)", s.name),
                "normalized innovation squared",
                &[(s.name.as_str(), points.points.as_slice())],
                t0,
                &[(nis.band.0, "χ²(3) 2.5 %"), (nis.band.1, "χ²(3) 97.5 %")],
            ),
        );
    }
}

fn write_report(
    dir: &Path,
    report: &ReplayReport,
    truth: &dyn scoring::Poses,
    estimates: &[crate::runner::Estimate],
    residual_series: &[(&str, Vec<(Nanos, f64)>)],
) -> Result<(), ReplayError> {
    let jp = dir.join("report.json");
    let json =
        serde_json::to_string_pretty(report).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"));
    crate::fsio::write_atomic(&jp, (json + "\n").as_bytes()).map_err(io_err(&jp))?;
    let mut md = String::new();
    let _ = writeln!(md, "# vinebench replay: {}\n", report.name);
    let _ = writeln!(md, "Recording: `{}`", report.recording);
    if let Some(c) = &report.config {
        let _ = writeln!(md, "Topic mapping: `{c}`");
    }
    if let Some(d) = &report.damage {
        let _ = writeln!(md, "\n**Damaged recording**: {d}.");
    }
    if let Some(why) = &report.nothing_usable {
        let _ = writeln!(md, "\n**Nothing usable**: {why}.");
    }
    for w in &report.without_poses {
        let _ = writeln!(md, "\n**Failed**: {w}.");
    }
    let _ = writeln!(md, "\n## Messages\n\n| topic | replayed |\n|---|---:|");
    for (t, n) in &report.replayed {
        let _ = writeln!(md, "| `{t}` | {n} |");
    }
    if !report.skipped.is_empty() {
        let _ = writeln!(md, "\n| skipped | messages |\n|---|---:|");
        for (t, n) in &report.skipped {
            let _ = writeln!(md, "| {t} | {n} |");
        }
    }
    for (t, (n, e)) in &report.decode_errors {
        let _ = writeln!(md, "\n- `{t}`: {n} message(s) did not decode, first: {e}");
    }
    for m in &report.missing_topics {
        let _ = writeln!(md, "- missing topic: {m}");
    }
    let notes = report.estimator_notes();
    if !notes.is_empty() {
        let _ = writeln!(md, "\n## Estimator notes\n");
        for n in &notes {
            let _ = writeln!(md, "- {n}");
        }
    }
    let _ = writeln!(
        md,
        "\n## Estimates\n\n| source | poses | ATE [m] | ATE al. [m] | D [m] |\n|---|---:|---:|---:|---:|"
    );
    for s in &report.sources {
        let m = |k: &str| {
            s.score
                .as_ref()
                .and_then(|x| x.metric(k))
                .map(|v| format!("{v:.3}"))
                .unwrap_or_else(|| "–".into())
        };
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} |",
            s.name,
            s.poses,
            m("ate_rmse_m"),
            m("ate_rmse_aligned_m"),
            m("d_m")
        );
    }
    let slam: Vec<&ReplaySource> = report
        .sources
        .iter()
        .filter(|s| !s.slam.is_empty())
        .collect();
    if !slam.is_empty() {
        let _ = writeln!(
            md,
            "\n## Visual SLAM\n\n| source | metric | value |\n|---|---|---:|"
        );
        for s in slam {
            for (k, v) in &s.slam {
                let _ = writeln!(md, "| {} | {k} | {v} |", s.name);
            }
        }
        if report.ground_truth_poses > 0 {
            let _ = writeln!(md, "\nLoop closures: `loops.csv`.");
        }
    }
    if !report.maps.is_empty() {
        md.push_str(&crate::runner::report::maps_markdown(&report.maps));
    }
    if !report.expectations.is_empty() {
        let _ = writeln!(md, "\n## Expectations\n");
        for x in &report.expectations {
            let _ = writeln!(md, "- {x}");
        }
    }
    if truth.is_empty() {
        no_truth_section(&mut md, dir, report, estimates, residual_series);
    }
    if !truth.is_empty() {
        let named: Vec<(&str, &dyn scoring::Poses)> = estimates
            .iter()
            .map(|e| (e.name, &e.poses as &dyn scoring::Poses))
            .collect();
        match scoring::plots::plot_trajectories_svg(dir.join("trajectories.svg"), truth, &named) {
            Ok(()) => {
                let _ = writeln!(md, "\n![trajectories](trajectories.svg)");
            }
            Err(e) => {
                let _ = writeln!(md, "\ntrajectories.svg: {e}");
            }
        }
    }
    let mp = dir.join("report.md");
    crate::fsio::write_atomic(&mp, md.as_bytes()).map_err(io_err(&mp))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};
    use proptest::prelude::*;

    proptest! {
        /// Messages out of order by less than the window come out as a stable sort by
        /// publish time would give them; later ones come out at once and are counted.
        #[test]
        fn publish_order_is_a_stable_sort_within_the_window(
            steps in proptest::collection::vec((0i64..400_000_000, 0i64..1_800_000_000), 1..300),
        ) {
            // A clock that advances, each message published up to `lag` before it.
            let mut clock = 0i64;
            let msgs: Vec<(Nanos, usize)> = steps
                .iter()
                .enumerate()
                .map(|(i, (advance, lag))| {
                    clock += advance;
                    (Nanos(clock - lag), i)
                })
                .collect();
            let mut order = PublishOrder::new();
            let mut out = Vec::new();
            let mut feed = |p: Nanos, i: usize| out.push((p, i));
            for (p, i) in &msgs {
                order.push(*p, *i, &mut feed);
            }
            order.finish(&mut feed);
            let late = order.late;
            prop_assert_eq!(out.len(), msgs.len());
            if msgs.iter().enumerate().all(|(k, (p, _))| {
                msgs[..k].iter().all(|(q, _)| q.0 - p.0 < FILE_REORDER_WINDOW.0)
            }) {
                let mut want = msgs.clone();
                want.sort_by_key(|(p, _)| *p);
                prop_assert_eq!(late, 0);
                prop_assert_eq!(out, want);
            } else {
                // Whatever came late, the rest is in publish order.
                let on_time: Vec<Nanos> = out.iter().map(|(p, _)| *p).collect();
                let inversions = on_time.windows(2).filter(|w| w[1] < w[0]).count() as u64;
                prop_assert!(inversions <= late, "{} inversions, {} late", inversions, late);
            }
        }
    }

    fn t(parent: &str, child: &str, x: f64, yaw: f64) -> TransformStamped {
        TransformStamped {
            stamp: Nanos(0),
            parent: FrameId::new(parent),
            child: FrameId::new(child),
            parent_from_child: Isometry3::from_parts(
                Translation3::new(x, 0.0, 0.0),
                UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
            ),
        }
    }

    #[test]
    fn static_transforms_chain_and_invert_edges() {
        let tf = [
            t("base_link", "mast", 1.0, 0.5),
            t("mast", "gnss", 0.2, 0.0),
            t("imu_link", "base_link", -0.3, 0.0),
        ];
        let st = static_transforms("base_link", &tf);
        assert_eq!(st.body_from("mast"), Some(tf[0].parent_from_child));
        let want = tf[0].parent_from_child * tf[1].parent_from_child;
        let got = st.body_from("gnss").unwrap();
        assert!((got.translation.vector - want.translation.vector).norm() < 1e-12);
        let imu = st.body_from("imu_link").unwrap();
        assert!((imu.translation.x - 0.3).abs() < 1e-12);
        assert!(static_transforms("nowhere", &tf).body_from.is_empty());
    }

    #[test]
    fn static_transforms_of_the_mapping_file() {
        let cfg = ReplayConfig::from_str(
            "[[static_transforms]]\nparent = \"base_link\"\nchild = \"gps\"\nxyz = [0.1, 0, 1.2]\n\
             rpy = [0, 0, 1.5707963267948966]\n\
             [[static_transforms]]\nparent = \"base_link\"\nchild = \"imu\"\n\
             quaternion = [0, 0, 0.7071067811865476, 0.7071067811865476]\n",
            "m.toml",
        )
        .unwrap();
        let t: Vec<TransformStamped> = cfg
            .static_transforms
            .iter()
            .map(|e| e.transform().unwrap())
            .collect();
        // Both: 90° about z; the GNSS antenna 1.2 m up.
        for x in &t {
            assert!(
                (x.parent_from_child.rotation.angle() - std::f64::consts::FRAC_PI_2).abs() < 1e-12
            );
            assert!((x.parent_from_child.rotation.axis().unwrap().z - 1.0).abs() < 1e-12);
        }
        assert_eq!(t[0].parent_from_child.translation.vector.z, 1.2);
        for (bad, why) in [
            ("rpy = [0, 0, 1]\nquaternion = [0, 0, 0, 1]", "not both"),
            ("quaternion = [0, 0, 0, 0]", "non-zero"),
            ("xyz = [0, 0, nan]", "not finite"),
        ] {
            let e = ReplayConfig::from_str(
                &format!("[[static_transforms]]\nparent = \"a\"\nchild = \"b\"\n{bad}\n"),
                "m.toml",
            )
            .unwrap_err()
            .to_string();
            assert!(e.contains("static_transforms[0]") && e.contains(why), "{e}");
        }
    }

    #[test]
    fn bad_imu_and_gnss_conventions_name_their_key() {
        for (bad, key) in [
            ("[imu]\ndeclination_deg = nan", "imu.declination_deg"),
            ("[imu]\nyaw_offset_deg = 400.0", "imu.yaw_offset_deg"),
            ("[imu]\naxes = \"nwu\"", "imu.axes"),
            (
                "[gnss]\nunknown_sigma_rtk_m = [0.05, 0.0]",
                "gnss.unknown_sigma_rtk_m",
            ),
            (
                "[gnss]\nunknown_sigma_single_m = [2.5]",
                "gnss.unknown_sigma_single_m",
            ),
            ("[gnss]\naltitude = \"maybe\"", "gnss.altitude"),
        ] {
            let e = ReplayConfig::from_str(bad, "m.toml")
                .unwrap_err()
                .to_string();
            assert!(e.contains("m.toml") && e.contains(key), "{bad}: {e}");
        }
        let ok =
            ReplayConfig::from_str("[imu]\naxes = \"ned\"\ndeclination_deg = -12.5\n", "m.toml")
                .unwrap();
        assert_eq!(ok.imu.axes, ImuAxes::Ned);
        assert_eq!(ok.gnss, GnssConventions::default());
    }

    #[test]
    fn reports_name_the_recorded_topics() {
        let t = TopicMap {
            gnss_fix: Some("/fix".into()),
            imu: Some("/imu/raw".into()),
            ..TopicMap::default()
        };
        assert_eq!(t.recorded_key("/gnss/fix latitude"), "/fix latitude");
        assert_eq!(t.recorded("/imu/data"), "/imu/raw");
        assert_eq!(t.recorded("/wheel/odom"), "/wheel/odom");
    }

    #[test]
    fn leading_slashes_are_dropped_as_tf2_drops_them() {
        let frames = BTreeMap::from([("/camera".to_string(), "cam_link".to_string())]);
        let mut tf = [
            t("/base_link", "/gps", 1.0, 0.0),
            t("base_link", "camera", 0.5, 0.0),
        ];
        for x in &mut tf {
            rename(&frames, &mut x.parent);
            rename(&frames, &mut x.child);
        }
        let st = static_transforms("base_link", &tf);
        assert!(st.body_from("gps").is_some());
        // The mapping's key matches with or without the slash.
        assert!(st.body_from("cam_link").is_some());
        assert_eq!(bare_frame("/a/b"), "a/b");
    }

    #[test]
    fn mapping_errors_name_the_key() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("m.toml");
        std::fs::write(&p, "[topics]\nimu = 3\n").unwrap();
        let e = ReplayConfig::load(&p).unwrap_err().to_string();
        assert!(e.contains("m.toml") && e.contains("topics.imu"), "{e}");
        std::fs::write(&p, "[topics]\ngps = \"/gps/fix\"\n").unwrap();
        let e = ReplayConfig::load(&p).unwrap_err().to_string();
        assert!(e.contains("gps") && e.contains("expected"), "{e}");
    }
}
