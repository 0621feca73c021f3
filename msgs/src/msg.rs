//! Sensor messages: the only input of the estimator, SLAM and mapper.
//!
//! The types mirror their ROS 2 counterparts (`sensor_msgs/Imu`, `sensor_msgs/NavSatFix`,
//! `geometry_msgs/TwistWithCovarianceStamped`, `nav_msgs/Odometry`) field for field, in SI
//! units, so that a field recording maps onto them without loss. Each message carries the
//! frame it was measured in; extrinsics come from [`crate::StaticTransforms`].

use crate::geodesy::Geodetic;
use crate::{FrameId, Nanos};
use nalgebra::{Isometry3, Matrix3, Matrix6, UnitQuaternion, Vector3};
use std::sync::Arc;
use thiserror::Error;

/// An IMU sample (`sensor_msgs/Imu`), in the IMU's own frame.
#[derive(Clone, Debug, PartialEq)]
pub struct ImuMsg {
    /// Sample time.
    pub stamp: Nanos,
    /// The IMU frame (a URDF link).
    pub frame_id: FrameId,
    /// AHRS orientation `world_from_imu` (ENU world), when the device provides one.
    pub orientation: Option<UnitQuaternion<f64>>,
    /// Covariance (rad²) of the orientation error as a small rotation about the **world**
    /// x (east), y (north), z (up) axes: `world_from_imu_true = Exp(e) * world_from_imu`.
    pub orientation_covariance: Matrix3<f64>,
    /// Angular rate of the IMU frame relative to the world, in the IMU frame (rad/s).
    pub angular_velocity: Vector3<f64>,
    /// Covariance of `angular_velocity` ((rad/s)²).
    pub angular_velocity_covariance: Matrix3<f64>,
    /// Specific force (acceleration minus gravity) in the IMU frame (m/s²);
    /// a level IMU at rest reads about +9.8 on z.
    pub linear_acceleration: Vector3<f64>,
    /// Covariance of `linear_acceleration` ((m/s²)²).
    pub linear_acceleration_covariance: Matrix3<f64>,
}

/// GNSS solution type, from best to none.
#[derive(Copy, Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum FixStatus {
    /// No position (under canopy, receiver lost lock). Position fields are NaN.
    NoFix,
    /// Stand-alone (single point) solution, metre level.
    Single,
    /// RTK with float ambiguities, decimetre level.
    RtkFloat,
    /// RTK with fixed ambiguities, centimetre level.
    RtkFixed,
}

impl FixStatus {
    /// `sensor_msgs/NavSatStatus.status`: -1 no fix, 0 fix, 2 ground-based augmentation
    /// (what RTK receivers' ROS drivers publish for float and fixed solutions).
    pub fn ros_status(self) -> i8 {
        match self {
            FixStatus::NoFix => -1,
            FixStatus::Single => 0,
            FixStatus::RtkFloat | FixStatus::RtkFixed => 2,
        }
    }
    /// Short lowercase name (`no_fix`, `single`, `rtk_float`, `rtk_fixed`).
    pub fn name(self) -> &'static str {
        match self {
            FixStatus::NoFix => "no_fix",
            FixStatus::Single => "single",
            FixStatus::RtkFloat => "rtk_float",
            FixStatus::RtkFixed => "rtk_fixed",
        }
    }
}

/// A GNSS position fix (`sensor_msgs/NavSatFix`) of the antenna phase centre.
#[derive(Clone, Debug, PartialEq)]
pub struct GnssFixMsg {
    /// Measurement epoch.
    pub stamp: Nanos,
    /// The antenna frame (a URDF link).
    pub frame_id: FrameId,
    /// Solution type.
    pub status: FixStatus,
    /// WGS84 position of the antenna (NaN when `status` is `NoFix`).
    pub position: Geodetic,
    /// Position covariance in the local ENU frame at the antenna (m²), as ROS defines it.
    pub position_covariance: Matrix3<f64>,
}

/// A GNSS velocity (`geometry_msgs/TwistWithCovarianceStamped` as u-blox drivers publish).
#[derive(Clone, Debug, PartialEq)]
pub struct GnssVelocityMsg {
    /// Measurement epoch.
    pub stamp: Nanos,
    /// The antenna frame.
    pub frame_id: FrameId,
    /// Antenna velocity in ENU (m/s).
    pub velocity_in_world: Vector3<f64>,
    /// Covariance of the velocity ((m/s)²).
    pub covariance: Matrix3<f64>,
}

/// Odometry (`nav_msgs/Odometry`): the pose of `child_frame_id` in `frame_id` and its twist.
#[derive(Clone, Debug, PartialEq)]
pub struct OdometryMsg {
    /// Sample time.
    pub stamp: Nanos,
    /// The odometry's own fixed frame (its start frame, e.g. `tracking_odom`).
    pub frame_id: FrameId,
    /// The moving frame (e.g. `tracking_camera` or `base_link`).
    pub child_frame_id: FrameId,
    /// `odom_from_child`.
    pub pose: Isometry3<f64>,
    /// Pose covariance: translation x, y, z then rotation about x, y, z (ROS order).
    pub pose_covariance: Matrix6<f64>,
    /// Linear velocity of the child frame, in the child frame (m/s).
    pub linear_velocity: Vector3<f64>,
    /// Angular velocity of the child frame, in the child frame (rad/s).
    pub angular_velocity: Vector3<f64>,
    /// Twist covariance (linear then angular).
    pub twist_covariance: Matrix6<f64>,
}

/// Pixel layout of an [`ImageMsg`] (the `encoding` strings of `sensor_msgs/Image`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ImageEncoding {
    /// 8-bit sRGB colour, 3 bytes per pixel (`rgb8`).
    Rgb8,
    /// 8-bit grey (`mono8`).
    Mono8,
    /// Depth in millimetres, little-endian `u16`, 0 = no measurement (`16UC1`, the
    /// RealSense ROS convention).
    Depth16Mm,
}

impl ImageEncoding {
    /// Bytes per pixel.
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            ImageEncoding::Rgb8 => 3,
            ImageEncoding::Mono8 => 1,
            ImageEncoding::Depth16Mm => 2,
        }
    }

    /// The `sensor_msgs/Image` encoding string.
    pub fn ros_name(self) -> &'static str {
        match self {
            ImageEncoding::Rgb8 => "rgb8",
            ImageEncoding::Mono8 => "mono8",
            ImageEncoding::Depth16Mm => "16UC1",
        }
    }
}

/// A camera image (`sensor_msgs/Image`), rows top to bottom, no padding.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageMsg {
    /// Exposure-centre time.
    pub stamp: Nanos,
    /// Topic, e.g. `/front/left/image_rect` (a robot has several cameras).
    pub topic: Arc<str>,
    /// The camera's optical frame (x right, y down, z forward).
    pub frame_id: FrameId,
    /// Width, px.
    pub width: u32,
    /// Height, px.
    pub height: u32,
    /// Pixel layout.
    pub encoding: ImageEncoding,
    /// Pixels; shared, so passing the message on does not copy them.
    pub data: Arc<[u8]>,
}

/// Calibration of a camera (`sensor_msgs/CameraInfo`), plumb-bob distortion.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraInfoMsg {
    /// Stamp of the image it describes.
    pub stamp: Nanos,
    /// Topic, e.g. `/front/left/camera_info`.
    pub topic: Arc<str>,
    /// The camera's optical frame.
    pub frame_id: FrameId,
    /// Width, px.
    pub width: u32,
    /// Height, px.
    pub height: u32,
    /// Distortion coefficients `[k1, k2, p1, p2, k3]` (`plumb_bob`).
    pub d: [f64; 5],
    /// Intrinsic matrix, row-major.
    pub k: [f64; 9],
    /// Rectification rotation, row-major.
    pub r: [f64; 9],
    /// Projection matrix, row-major; `p[3] = -fx·baseline` for the right camera of a
    /// rectified stereo pair.
    pub p: [f64; 12],
}

/// Any message of the stream.
#[derive(Clone, Debug, PartialEq)]
pub enum Message {
    /// IMU sample with AHRS orientation.
    Imu(ImuMsg),
    /// GNSS position fix.
    GnssFix(GnssFixMsg),
    /// GNSS velocity.
    GnssVelocity(GnssVelocityMsg),
    /// Tracking-camera (visual-inertial) odometry.
    TrackingOdom(OdometryMsg),
    /// Wheel or track odometry.
    WheelOdom(OdometryMsg),
    /// A camera image (colour, grey or depth).
    Image(ImageMsg),
    /// A camera's calibration, published with each of its images.
    CameraInfo(CameraInfoMsg),
    /// A dual-antenna GNSS heading.
    GnssHeading(GnssHeadingMsg),
    /// The GNSS receiver's sky: satellites, signal strengths, DOP and solution type
    /// (diagnostics; recorded as `gps_msgs/GPSFix` on `/gnss/gpsfix`).
    GnssSky(GnssSkyMsg),
}

/// A satellite system.
#[derive(Copy, Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum GnssSystem {
    /// GPS (NAVSTAR).
    Gps,
    /// Galileo.
    Galileo,
    /// GLONASS.
    Glonass,
    /// BeiDou.
    Beidou,
}

impl GnssSystem {
    /// The satellite's number in gpsd's numbering, as `gps_msgs` carries it: GPS PRN
    /// 1–63 as is, GLONASS slot `n` as `64 + n`, Galileo PRN `n` as `300 + n`, BeiDou PRN
    /// `n` as `400 + n`.
    pub fn gpsd_prn(self, prn: u16) -> i32 {
        match self {
            GnssSystem::Gps => i32::from(prn),
            GnssSystem::Glonass => 64 + i32::from(prn),
            GnssSystem::Galileo => 300 + i32::from(prn),
            GnssSystem::Beidou => 400 + i32::from(prn),
        }
    }

    /// Lowercase name (`gps`, `galileo`, `glonass`, `beidou`).
    pub fn name(self) -> &'static str {
        match self {
            GnssSystem::Gps => "gps",
            GnssSystem::Galileo => "galileo",
            GnssSystem::Glonass => "glonass",
            GnssSystem::Beidou => "beidou",
        }
    }
}

/// One satellite above the horizon, as the receiver sees it at an epoch.
#[derive(Clone, Debug, PartialEq)]
pub struct GnssSatellite {
    /// Its system.
    pub system: GnssSystem,
    /// PRN within the system.
    pub prn: u16,
    /// Azimuth, degrees clockwise from north.
    pub azimuth_deg: f64,
    /// Elevation above the horizon, degrees.
    pub elevation_deg: f64,
    /// Carrier-to-noise density, dB-Hz (NaN when blocked).
    pub cn0_dbhz: f64,
    /// Tracked: its signal is strong enough to track (and it is above the mask).
    pub tracked: bool,
    /// Used in the position solution.
    pub used: bool,
    /// Strong enough to help fix RTK ambiguities.
    pub strong: bool,
    /// Leaves its line of sight crosses (0: clear or blocked by something solid).
    pub leaves: u16,
    /// Line of sight blocked by something solid (post, board, occluder, ground).
    pub blocked: bool,
}

/// Dilutions of precision of a solution (single receiver clock).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Dop {
    /// Geometric (position and time).
    pub gdop: f64,
    /// Position (3D).
    pub pdop: f64,
    /// Horizontal.
    pub hdop: f64,
    /// Vertical.
    pub vdop: f64,
    /// Time.
    pub tdop: f64,
}

/// The sky of a GNSS receiver at one epoch: what `/gnss/fix` does not say.
#[derive(Clone, Debug, PartialEq)]
pub struct GnssSkyMsg {
    /// Epoch.
    pub stamp: Nanos,
    /// The receiver's frame (the antenna).
    pub frame_id: FrameId,
    /// Solution type of the epoch's fix.
    pub status: FixStatus,
    /// The fix (NaN without one).
    pub position: crate::geodesy::Geodetic,
    /// Its reported covariance, ENU, m² (as on `/gnss/fix`).
    pub position_covariance: Matrix3<f64>,
    /// DOP of the used satellites (None with fewer than four).
    pub dop: Option<Dop>,
    /// Whether RTK corrections are arriving.
    pub corrections: bool,
    /// Every satellite above the horizon.
    pub satellites: Vec<GnssSatellite>,
}

impl GnssSkyMsg {
    /// Satellites used in the solution.
    pub fn used(&self) -> usize {
        self.satellites.iter().filter(|s| s.used).count()
    }
    /// Satellites tracked.
    pub fn tracked(&self) -> usize {
        self.satellites.iter().filter(|s| s.tracked).count()
    }
}

/// A dual-antenna (moving-baseline) GNSS heading, converted to the body: the yaw of the
/// body's forward axis in the world (ENU), counter-clockwise from east (the receiver's
/// baseline direction plus the mounting offset between baseline and body).
#[derive(Clone, Debug, PartialEq)]
pub struct GnssHeadingMsg {
    /// Sample time.
    pub stamp: Nanos,
    /// The receiver's frame (the main antenna).
    pub frame_id: FrameId,
    /// Heading of the body's forward axis, rad counter-clockwise from east.
    pub heading_rad: f64,
    /// Its variance, rad².
    pub variance_rad2: f64,
}

/// A message as it reached the computer: `arrival` is at or after the message's stamp
/// (sensor latency), and streams are delivered in arrival order, so stamps may go
/// backwards across sensors.
#[derive(Clone, Debug, PartialEq)]
pub struct TimedMessage {
    /// Reception time.
    pub arrival: Nanos,
    /// The message.
    pub msg: Message,
}

/// A message field that is not usable (NaN, infinite, not a covariance).
#[derive(Clone, Debug, Error, PartialEq)]
#[error("{topic} at {stamp}: field `{field}` {problem}")]
pub struct InvalidMessage {
    /// The message's topic.
    pub topic: String,
    /// The message's stamp.
    pub stamp: Nanos,
    /// The field.
    pub field: &'static str,
    /// What is wrong with it.
    pub problem: &'static str,
}

impl Message {
    /// The measurement time.
    pub fn stamp(&self) -> Nanos {
        match self {
            Message::Imu(m) => m.stamp,
            Message::GnssFix(m) => m.stamp,
            Message::GnssVelocity(m) => m.stamp,
            Message::TrackingOdom(m) | Message::WheelOdom(m) => m.stamp,
            Message::Image(m) => m.stamp,
            Message::CameraInfo(m) => m.stamp,
            Message::GnssHeading(m) => m.stamp,
            Message::GnssSky(m) => m.stamp,
        }
    }

    /// The ROS 2 topic vinebench publishes this message on.
    pub fn topic(&self) -> &str {
        match self {
            Message::Imu(_) => "/imu/data",
            Message::GnssFix(_) => "/gnss/fix",
            Message::GnssVelocity(_) => "/gnss/fix_velocity",
            Message::TrackingOdom(_) => "/tracking_camera/odom/sample",
            Message::WheelOdom(_) => "/wheel/odom",
            Message::Image(m) => &m.topic,
            Message::CameraInfo(m) => &m.topic,
            Message::GnssHeading(_) => "/gnss/heading",
            Message::GnssSky(_) => "/gnss/gpsfix",
        }
    }

    /// Checks that every field an algorithm would use is finite and every covariance is
    /// symmetric with a non-negative diagonal. A `NoFix` GNSS fix may carry NaN position.
    pub fn validate(&self) -> Result<(), InvalidMessage> {
        let bad = |field, problem| InvalidMessage {
            topic: self.topic().to_string(),
            stamp: self.stamp(),
            field,
            problem,
        };
        const NOT_FINITE: &str = "is NaN or infinite";
        const NOT_COV: &str = "is not a covariance (asymmetric, negative or NaN diagonal)";
        match self {
            Message::Imu(m) => {
                if let Some(q) = &m.orientation
                    && !q.coords.iter().all(|c| c.is_finite())
                {
                    return Err(bad("orientation", NOT_FINITE));
                }
                if !finite3(&m.angular_velocity) {
                    return Err(bad("angular_velocity", NOT_FINITE));
                }
                if !finite3(&m.linear_acceleration) {
                    return Err(bad("linear_acceleration", NOT_FINITE));
                }
                if m.orientation.is_some() && !is_cov3(&m.orientation_covariance) {
                    return Err(bad("orientation_covariance", NOT_COV));
                }
                if !is_cov3(&m.angular_velocity_covariance) {
                    return Err(bad("angular_velocity_covariance", NOT_COV));
                }
                if !is_cov3(&m.linear_acceleration_covariance) {
                    return Err(bad("linear_acceleration_covariance", NOT_COV));
                }
            }
            Message::GnssFix(m) => {
                if m.status != FixStatus::NoFix {
                    if !m.position.is_valid() {
                        return Err(bad("position", "is NaN, infinite or out of range"));
                    }
                    if !is_cov3(&m.position_covariance) {
                        return Err(bad("position_covariance", NOT_COV));
                    }
                }
            }
            Message::GnssVelocity(m) => {
                if !finite3(&m.velocity_in_world) {
                    return Err(bad("velocity_in_world", NOT_FINITE));
                }
                if !is_cov3(&m.covariance) {
                    return Err(bad("covariance", NOT_COV));
                }
            }
            Message::TrackingOdom(m) | Message::WheelOdom(m) => {
                let p = &m.pose;
                if !finite3(&p.translation.vector)
                    || !p.rotation.coords.iter().all(|c| c.is_finite())
                {
                    return Err(bad("pose", NOT_FINITE));
                }
                if !finite3(&m.linear_velocity) {
                    return Err(bad("linear_velocity", NOT_FINITE));
                }
                if !finite3(&m.angular_velocity) {
                    return Err(bad("angular_velocity", NOT_FINITE));
                }
                if !is_cov6(&m.pose_covariance) {
                    return Err(bad("pose_covariance", NOT_COV));
                }
                if !is_cov6(&m.twist_covariance) {
                    return Err(bad("twist_covariance", NOT_COV));
                }
            }
            Message::Image(m) => {
                let expected = m.width as usize * m.height as usize * m.encoding.bytes_per_pixel();
                if m.data.len() != expected {
                    return Err(bad(
                        "data",
                        "has a length other than width·height·bytes per pixel",
                    ));
                }
            }
            Message::CameraInfo(m) => {
                if !(m.d.iter().chain(&m.k).chain(&m.r).chain(&m.p)).all(|c| c.is_finite()) {
                    return Err(bad("k, d, r or p", NOT_FINITE));
                }
            }
            Message::GnssHeading(m) => {
                if !m.heading_rad.is_finite() {
                    return Err(bad("heading_rad", NOT_FINITE));
                }
                if !(m.variance_rad2.is_finite() && m.variance_rad2 > 0.0) {
                    return Err(bad("variance_rad2", "is not a positive finite variance"));
                }
            }
            Message::GnssSky(m) => {
                let ok = |s: &GnssSatellite| {
                    s.azimuth_deg.is_finite()
                        && (-90.0..=90.0).contains(&s.elevation_deg)
                        && (s.cn0_dbhz.is_finite() || !s.tracked)
                };
                if !m.satellites.iter().all(ok) {
                    return Err(bad(
                        "satellites",
                        "has a non-finite azimuth, elevation or C/N0",
                    ));
                }
            }
        }
        Ok(())
    }
}

fn finite3(v: &Vector3<f64>) -> bool {
    v.iter().all(|c| c.is_finite())
}

fn is_cov3(m: &Matrix3<f64>) -> bool {
    m.iter().all(|c| c.is_finite())
        && (0..3).all(|i| m[(i, i)] >= 0.0)
        && (m - m.transpose()).amax() <= 1e-9 * m.amax().max(1e-300)
}

fn is_cov6(m: &Matrix6<f64>) -> bool {
    m.iter().all(|c| c.is_finite())
        && (0..6).all(|i| m[(i, i)] >= 0.0)
        && (m - m.transpose()).amax() <= 1e-9 * m.amax().max(1e-300)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn imu() -> ImuMsg {
        ImuMsg {
            stamp: Nanos(5),
            frame_id: FrameId::new("imu_link"),
            orientation: Some(UnitQuaternion::identity()),
            orientation_covariance: Matrix3::identity() * 1e-4,
            angular_velocity: Vector3::zeros(),
            angular_velocity_covariance: Matrix3::identity() * 1e-6,
            linear_acceleration: Vector3::new(0.0, 0.0, 9.8),
            linear_acceleration_covariance: Matrix3::identity() * 1e-4,
        }
    }

    #[test]
    fn nan_fields_are_named() {
        assert_eq!(Message::Imu(imu()).validate(), Ok(()));
        let mut m = imu();
        m.linear_acceleration.y = f64::NAN;
        let err = Message::Imu(m).validate().unwrap_err();
        assert_eq!(err.field, "linear_acceleration");
        assert!(err.to_string().contains("/imu/data"));
        let mut m = imu();
        m.orientation_covariance[(0, 1)] = 1.0;
        assert_eq!(
            Message::Imu(m).validate().unwrap_err().field,
            "orientation_covariance"
        );
    }

    #[test]
    fn no_fix_may_carry_nan_position() {
        let nan = Geodetic {
            lat_deg: f64::NAN,
            lon_deg: f64::NAN,
            alt_m: f64::NAN,
        };
        let mut fix = GnssFixMsg {
            stamp: Nanos(0),
            frame_id: FrameId::new("gnss_antenna"),
            status: FixStatus::NoFix,
            position: nan,
            position_covariance: Matrix3::from_element(f64::NAN),
        };
        assert!(Message::GnssFix(fix.clone()).validate().is_ok());
        fix.status = FixStatus::RtkFixed;
        assert_eq!(
            Message::GnssFix(fix).validate().unwrap_err().field,
            "position"
        );
    }
}
