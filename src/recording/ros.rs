//! CDR encoders and decoders of the ROS 2 messages vinebench records, to and from
//! [`vinebench_msgs`] types.
//!
//! Conventions (each a ROS one unless said otherwise):
//! - covariances are row-major arrays; 3×3 blocks of 6×6 covariances are translation (or
//!   linear) then rotation (or angular);
//! - `sensor_msgs/Imu` without an orientation has `orientation_covariance[0] = -1`;
//! - `sensor_msgs/NavSatFix.status.status` is −1 no fix, 0 stand-alone, 2 RTK (ground-based
//!   augmentation, what RTK receivers' drivers publish for float and fixed solutions);
//!   `position_covariance_type` is `KNOWN` (3) for a fix whose covariance is finite,
//!   `UNKNOWN` (0) without a fix (status −1: position NaN, covariance zero) or with NaN;
//!   decoded, `UNKNOWN` (0) gives a fix a NaN covariance (whatever numbers a driver put
//!   there: many publish zeros; a no-fix message keeps its numbers) and `DIAGONAL_KNOWN`
//!   (2) keeps only the diagonal.
//!   vinebench keeps the float/fixed distinction in bit 15 of `status.service`
//!   ([`SERVICE_VINEBENCH_RTK_FLOAT`]; the standard bits 0–3 name constellations, readers
//!   ignore the rest); a field recording's status 2 reads as RTK fixed. RTK fixed and
//!   float are told apart as users of common drivers do: both are status 2, the fixed
//!   solution's covariance is centimetres (1σ), the float's decimetres; vinebench's
//!   `/gnss/gpsfix` (`gps_msgs/GPSFix`) says it outright: `status.status` 19
//!   (`STATUS_RTK_FIX`) or 20 (`STATUS_RTK_FLOAT`);
//! - `gps_msgs/GPSFix` ([`encode_gps_fix`]) carries the sky: satellites used and
//!   visible (gpsd numbering: GPS PRN as is, Galileo `300 + PRN`), elevation, azimuth and
//!   C/N0 (whole degrees and dB-Hz, as the message's `int32` fields hold them), the DOPs
//!   (−1: unknown) and the same position and covariance as `/gnss/fix`;
//! - a GNSS velocity is a `geometry_msgs/TwistWithCovarianceStamped` whose linear part is
//!   the ENU velocity (as u-blox drivers publish), angular part and its covariance zero.
//!
//! Decoding keeps every bit of every float, so a vinebench recording replays exactly.

use super::cdr::{CdrError, CdrReader, CdrWriter};
use nalgebra::{Isometry3, Matrix3, Matrix6, Quaternion, Translation3, UnitQuaternion, Vector3};
use std::sync::Arc;
use vinebench_msgs::geodesy::Geodetic;
use vinebench_msgs::{
    CameraInfoMsg, FixStatus, FrameId, GnssFixMsg, GnssVelocityMsg, ImageEncoding, ImageMsg,
    ImuMsg, Nanos, OdometryMsg,
};

/// `status.service` of fixes vinebench writes: GPS, GLONASS and Galileo.
pub const SERVICE_GNSS: u16 = 1 | 2 | 8;
/// vinebench's bit of `status.service` marking an RTK float solution (status 2).
pub const SERVICE_VINEBENCH_RTK_FLOAT: u16 = 0x8000;
/// `NavSatFix.position_covariance_type`: unknown.
pub const COVARIANCE_TYPE_UNKNOWN: u8 = 0;
/// `NavSatFix.position_covariance_type`: known, full matrix.
pub const COVARIANCE_TYPE_KNOWN: u8 = 3;
/// `NavSatFix.position_covariance_type`: only the diagonal is known.
pub const COVARIANCE_TYPE_DIAGONAL_KNOWN: u8 = 2;
/// `distortion_model` of [`CameraInfoMsg`]: Brown-Conrady with `[k1, k2, p1, p2, k3]`.
pub const PLUMB_BOB: &str = "plumb_bob";

/// One transform of a `tf2_msgs/TFMessage`: `parent_from_child` at `stamp`.
#[derive(Clone, Debug, PartialEq)]
pub struct TransformStamped {
    /// Time of the transform.
    pub stamp: Nanos,
    /// The parent frame (`header.frame_id`).
    pub parent: FrameId,
    /// The child frame (`child_frame_id`).
    pub child: FrameId,
    /// `parent_from_child`: maps points in the child frame into the parent frame.
    pub parent_from_child: Isometry3<f64>,
}

/// One field of a point cloud's points (`sensor_msgs/PointField`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PointField {
    /// Name (`x`, `y`, `z`, `rgb`, ...).
    pub name: String,
    /// Byte offset in a point.
    pub offset: u32,
    /// Type code (1 `INT8` … 7 `FLOAT32`, 8 `FLOAT64`).
    pub datatype: u8,
    /// Elements in the field.
    pub count: u32,
}

/// A point cloud (`sensor_msgs/PointCloud2`), points packed `point_step` bytes apart.
#[derive(Clone, Debug, PartialEq)]
pub struct PointCloud2Msg {
    /// Acquisition time.
    pub stamp: Nanos,
    /// The frame the points are in.
    pub frame_id: FrameId,
    /// Rows (1 for an unordered cloud).
    pub height: u32,
    /// Points per row.
    pub width: u32,
    /// Layout of a point.
    pub fields: Vec<PointField>,
    /// Byte order of the data.
    pub is_bigendian: bool,
    /// Bytes per point.
    pub point_step: u32,
    /// Bytes per row.
    pub row_step: u32,
    /// The points.
    pub data: Arc<[u8]>,
    /// True when no point is invalid (NaN).
    pub is_dense: bool,
}

impl PointCloud2Msg {
    /// An unordered cloud in `frame_id` with the fields `x y z` (`FLOAT32`), `rgb`
    /// (`FLOAT32` holding `0x00RRGGBB` little-endian, the PCL/RViz convention) and, when
    /// given, one more `FLOAT32` field per `(name, values)` of `extra` (one value per
    /// point).
    pub fn xyz_rgb(
        stamp: Nanos,
        frame_id: FrameId,
        positions: &[[f32; 3]],
        colors: &[[u8; 3]],
        extra: &[(&str, &[f32])],
    ) -> PointCloud2Msg {
        const FLOAT32: u8 = 7;
        let mut fields: Vec<PointField> = ["x", "y", "z", "rgb"]
            .iter()
            .enumerate()
            .map(|(i, name)| PointField {
                name: (*name).to_string(),
                offset: 4 * i as u32,
                datatype: FLOAT32,
                count: 1,
            })
            .collect();
        for (i, (name, _)) in extra.iter().enumerate() {
            fields.push(PointField {
                name: (*name).to_string(),
                offset: 16 + 4 * i as u32,
                datatype: FLOAT32,
                count: 1,
            });
        }
        let step = 16 + 4 * extra.len();
        let n = positions.len();
        let mut data = vec![0u8; n * step];
        for (i, point) in data.chunks_exact_mut(step).enumerate() {
            for (k, v) in positions[i].iter().enumerate() {
                point[4 * k..4 * k + 4].copy_from_slice(&v.to_le_bytes());
            }
            let [r, g, b] = colors.get(i).copied().unwrap_or([0, 0, 0]);
            point[12..16].copy_from_slice(&[b, g, r, 0]);
            for (e, (_, values)) in extra.iter().enumerate() {
                let v = values.get(i).copied().unwrap_or(f32::NAN);
                point[16 + 4 * e..20 + 4 * e].copy_from_slice(&v.to_le_bytes());
            }
        }
        PointCloud2Msg {
            stamp,
            frame_id,
            height: 1,
            width: n as u32,
            fields,
            is_bigendian: false,
            point_step: step as u32,
            row_step: (n * step) as u32,
            data: data.into(),
            is_dense: positions.iter().all(|p| p.iter().all(|v| v.is_finite())),
        }
    }
}

// ---- shared pieces ----------------------------------------------------------------------

fn header(w: &mut CdrWriter<'_>, stamp: Nanos, frame: &str) {
    w.time(stamp);
    w.string(frame);
}

fn read_header(r: &mut CdrReader<'_>) -> Result<(Nanos, FrameId), CdrError> {
    let stamp = r.time("header.stamp")?;
    let frame = r.string("header.frame_id")?;
    Ok((stamp, FrameId::new(frame)))
}

fn vector3(w: &mut CdrWriter<'_>, v: &Vector3<f64>) {
    w.f64s(v.as_slice());
}

fn read_vector3(r: &mut CdrReader<'_>, field: &'static str) -> Result<Vector3<f64>, CdrError> {
    Ok(Vector3::from(r.f64s::<3>(field)?))
}

fn quaternion(w: &mut CdrWriter<'_>, q: &UnitQuaternion<f64>) {
    let c = q.coords; // x, y, z, w
    w.f64s(c.as_slice());
}

/// A unit quaternion from `x, y, z, w`: kept bit for bit when its norm is within 1e-9 of
/// one (ours), normalized otherwise (a field recording's float32 round trips).
fn read_quaternion(
    r: &mut CdrReader<'_>,
    field: &'static str,
) -> Result<UnitQuaternion<f64>, CdrError> {
    unit_quaternion(r.f64s::<4>(field)?, field)
}

pub(crate) fn unit_quaternion(
    [x, y, z, w]: [f64; 4],
    field: &'static str,
) -> Result<UnitQuaternion<f64>, CdrError> {
    let q = Quaternion::new(w, x, y, z);
    let n = q.norm();
    if !(n.is_finite() && n > 0.0) {
        return Err(CdrError::Invalid {
            field,
            problem: format!("({x}, {y}, {z}, {w}) is not a rotation"),
        });
    }
    Ok(if (n - 1.0).abs() <= 1e-9 {
        UnitQuaternion::new_unchecked(q)
    } else {
        UnitQuaternion::from_quaternion(q)
    })
}

fn cov3(w: &mut CdrWriter<'_>, m: &Matrix3<f64>) {
    for r in 0..3 {
        for c in 0..3 {
            w.f64(m[(r, c)]);
        }
    }
}

fn read_cov3(r: &mut CdrReader<'_>, field: &'static str) -> Result<Matrix3<f64>, CdrError> {
    let a = r.f64s::<9>(field)?;
    Ok(Matrix3::from_row_slice(&a))
}

fn cov6(w: &mut CdrWriter<'_>, m: &Matrix6<f64>) {
    for r in 0..6 {
        for c in 0..6 {
            w.f64(m[(r, c)]);
        }
    }
}

fn read_cov6(r: &mut CdrReader<'_>, field: &'static str) -> Result<Matrix6<f64>, CdrError> {
    let a = r.f64s::<36>(field)?;
    Ok(Matrix6::from_row_slice(&a))
}

fn pose(w: &mut CdrWriter<'_>, p: &Isometry3<f64>) {
    vector3(w, &p.translation.vector);
    quaternion(w, &p.rotation);
}

fn read_pose(r: &mut CdrReader<'_>, field: &'static str) -> Result<Isometry3<f64>, CdrError> {
    let t = read_vector3(r, field)?;
    let q = read_quaternion(r, field)?;
    Ok(Isometry3::from_parts(Translation3::from(t), q))
}

fn finish(r: &CdrReader<'_>) -> Result<(), CdrError> {
    // CDR payloads may carry up to 3 bytes of trailing padding; more is a wrong type.
    if r.remaining() > 3 {
        return Err(CdrError::Invalid {
            field: "(end)",
            problem: format!(
                "{} bytes left over: a different message type?",
                r.remaining()
            ),
        });
    }
    Ok(())
}

// ---- sensor_msgs/Imu --------------------------------------------------------------------

/// Encodes an IMU sample as `sensor_msgs/Imu` into `buf` (cleared first).
pub fn encode_imu(m: &ImuMsg, buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    header(&mut w, m.stamp, m.frame_id.as_str());
    match &m.orientation {
        Some(q) => {
            quaternion(&mut w, q);
            cov3(&mut w, &m.orientation_covariance);
        }
        None => {
            quaternion(&mut w, &UnitQuaternion::identity());
            let mut c = Matrix3::zeros();
            c[(0, 0)] = -1.0;
            cov3(&mut w, &c);
        }
    }
    vector3(&mut w, &m.angular_velocity);
    cov3(&mut w, &m.angular_velocity_covariance);
    vector3(&mut w, &m.linear_acceleration);
    cov3(&mut w, &m.linear_acceleration_covariance);
}

/// A dual-antenna heading as `sensor_msgs/Imu` (how u-blox and Septentrio drivers publish
/// one): orientation = the yaw about world z, roll and pitch unknown (variance 1e6), no
/// rates or accelerations (covariance element 0 = −1, REP-145).
pub fn imu_of_heading(m: &vinebench_msgs::GnssHeadingMsg) -> ImuMsg {
    let mut no_data = Matrix3::zeros();
    no_data[(0, 0)] = -1.0;
    ImuMsg {
        stamp: m.stamp,
        frame_id: m.frame_id.clone(),
        orientation: Some(UnitQuaternion::from_axis_angle(
            &Vector3::z_axis(),
            m.heading_rad,
        )),
        orientation_covariance: Matrix3::from_diagonal(&Vector3::new(1e6, 1e6, m.variance_rad2)),
        angular_velocity: Vector3::zeros(),
        angular_velocity_covariance: no_data,
        linear_acceleration: Vector3::zeros(),
        linear_acceleration_covariance: no_data,
    }
}

/// A dual-antenna heading recorded as `sensor_msgs/Imu`: the yaw of its orientation (ENU,
/// counter-clockwise from east) and the yaw variance (NaN when the message gives none).
pub fn decode_heading(payload: &[u8]) -> Result<vinebench_msgs::GnssHeadingMsg, CdrError> {
    let imu = decode_imu(payload)?;
    let Some(q) = imu.orientation else {
        return Err(CdrError::Invalid {
            field: "orientation",
            problem: "orientation_covariance[0] is -1 (no orientation): no heading".into(),
        });
    };
    let x = q * Vector3::x();
    let var = imu.orientation_covariance[(2, 2)];
    Ok(vinebench_msgs::GnssHeadingMsg {
        stamp: imu.stamp,
        frame_id: imu.frame_id,
        heading_rad: x.y.atan2(x.x),
        variance_rad2: if var.is_finite() && var > 0.0 {
            var
        } else {
            f64::NAN
        },
    })
}

/// Decodes a `sensor_msgs/Imu`. `orientation_covariance[0] = -1` means no orientation
/// (and a zero covariance).
pub fn decode_imu(payload: &[u8]) -> Result<ImuMsg, CdrError> {
    let mut r = CdrReader::new(payload)?;
    let (stamp, frame_id) = read_header(&mut r)?;
    let [x, y, z, qw] = r.f64s::<4>("orientation")?;
    let ocov = read_cov3(&mut r, "orientation_covariance")?;
    let (orientation, orientation_covariance) = if ocov[(0, 0)] == -1.0 {
        (None, Matrix3::zeros())
    } else {
        (Some(unit_quaternion([x, y, z, qw], "orientation")?), ocov)
    };
    let angular_velocity = read_vector3(&mut r, "angular_velocity")?;
    let angular_velocity_covariance = read_cov3(&mut r, "angular_velocity_covariance")?;
    let linear_acceleration = read_vector3(&mut r, "linear_acceleration")?;
    let linear_acceleration_covariance = read_cov3(&mut r, "linear_acceleration_covariance")?;
    finish(&r)?;
    Ok(ImuMsg {
        stamp,
        frame_id,
        orientation,
        orientation_covariance,
        angular_velocity,
        angular_velocity_covariance,
        linear_acceleration,
        linear_acceleration_covariance,
    })
}

// ---- sensor_msgs/NavSatFix --------------------------------------------------------------

/// Encodes a GNSS fix as `sensor_msgs/NavSatFix`.
pub fn encode_nav_sat_fix(m: &GnssFixMsg, buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    header(&mut w, m.stamp, m.frame_id.as_str());
    w.i8(m.status.ros_status());
    w.u16(match m.status {
        FixStatus::RtkFloat => SERVICE_GNSS | SERVICE_VINEBENCH_RTK_FLOAT,
        _ => SERVICE_GNSS,
    });
    w.f64(m.position.lat_deg);
    w.f64(m.position.lon_deg);
    w.f64(m.position.alt_m);
    cov3(&mut w, &m.position_covariance);
    w.u8(
        if m.status != FixStatus::NoFix && m.position_covariance.iter().all(|c| c.is_finite()) {
            COVARIANCE_TYPE_KNOWN
        } else {
            COVARIANCE_TYPE_UNKNOWN
        },
    );
}

/// `gps_msgs/GPSStatus.status` of a solution type.
pub fn gps_status(status: FixStatus) -> i16 {
    match status {
        FixStatus::NoFix => -1,
        FixStatus::Single => 0,
        FixStatus::RtkFloat => 20,
        FixStatus::RtkFixed => 19,
    }
}

/// Encodes a receiver's sky ([`vinebench_msgs::GnssSkyMsg`]) as `gps_msgs/GPSFix`:
/// tracked satellites are the visible ones, `position_source` is `SOURCE_GPS` with a fix.
pub fn encode_gps_fix(m: &vinebench_msgs::GnssSkyMsg, buf: &mut Vec<u8>) {
    let cov = &m.position_covariance;
    let mut w = CdrWriter::new(buf);
    header(&mut w, m.stamp, m.frame_id.as_str());
    // GPSStatus
    header(&mut w, m.stamp, m.frame_id.as_str());
    let used: Vec<_> = m.satellites.iter().filter(|s| s.used).collect();
    let visible: Vec<_> = m.satellites.iter().filter(|s| s.tracked).collect();
    let prn = |s: &vinebench_msgs::GnssSatellite| s.system.gpsd_prn(s.prn);
    w.u16(used.len() as u16);
    w.seq_len(used.len());
    for s in &used {
        w.i32(prn(s));
    }
    w.u16(visible.len() as u16);
    let ints = |w: &mut CdrWriter<'_>, f: &dyn Fn(&vinebench_msgs::GnssSatellite) -> i32| {
        w.seq_len(visible.len());
        for s in &visible {
            w.i32(f(s));
        }
    };
    ints(&mut w, &prn);
    ints(&mut w, &|s| s.elevation_deg.round() as i32);
    ints(&mut w, &|s| s.azimuth_deg.round() as i32);
    ints(&mut w, &|s| s.cn0_dbhz.round() as i32);
    w.i16(gps_status(m.status));
    let has_fix = m.status != FixStatus::NoFix;
    w.u16(0); // motion_source
    w.u16(0); // orientation_source
    w.u16(u16::from(has_fix)); // position_source: SOURCE_GPS
    // GPSFix
    w.f64(m.position.lat_deg);
    w.f64(m.position.lon_deg);
    w.f64(m.position.alt_m);
    for _ in 0..7 {
        w.f64(f64::NAN); // track, speed, climb, pitch, roll, dip, time: not given here
    }
    let d = m.dop;
    for v in [
        d.map(|d| d.gdop),
        d.map(|d| d.pdop),
        d.map(|d| d.hdop),
        d.map(|d| d.vdop),
        d.map(|d| d.tdop),
    ] {
        w.f64(v.unwrap_or(-1.0));
    }
    // 95 % radii from the covariance, each with the RMS σ per axis: spherical (χ²₃:
    // 2.796σ), horizontal (χ²₂: 2.448σ), vertical (1.960σ).
    let known = has_fix && cov.iter().all(|c| c.is_finite());
    let (err, err_horz, err_vert) = if known {
        (
            2.796 * (cov.trace() / 3.0).sqrt(),
            2.448 * ((cov[(0, 0)] + cov[(1, 1)]) / 2.0).sqrt(),
            1.960 * cov[(2, 2)].sqrt(),
        )
    } else {
        (f64::NAN, f64::NAN, f64::NAN)
    };
    w.f64(err);
    w.f64(err_horz);
    w.f64(err_vert);
    for _ in 0..7 {
        w.f64(f64::NAN); // err_track .. err_dip
    }
    cov3(&mut w, cov);
    w.u8(if known {
        COVARIANCE_TYPE_KNOWN
    } else {
        COVARIANCE_TYPE_UNKNOWN
    });
}

/// Decodes a `gps_msgs/GPSFix`'s status: (`status.status`, used PRNs, visible PRNs,
/// their elevations, azimuths and C/N0, `[gdop, pdop, hdop, vdop, tdop]`).
#[allow(clippy::type_complexity)]
pub fn decode_gps_fix_status(
    payload: &[u8],
) -> Result<(i16, Vec<i32>, [Vec<i32>; 4], [f64; 5]), CdrError> {
    let mut r = CdrReader::new(payload)?;
    read_header(&mut r)?;
    read_header(&mut r)?;
    let ints = |r: &mut CdrReader<'_>, field| -> Result<Vec<i32>, CdrError> {
        let n = r.seq_len(field, 4)?;
        (0..n).map(|_| r.i32(field)).collect()
    };
    let n_used = r.u16("status.satellites_used")?;
    let used = ints(&mut r, "status.satellite_used_prn")?;
    let n_visible = r.u16("status.satellites_visible")?;
    let visible = [
        ints(&mut r, "status.satellite_visible_prn")?,
        ints(&mut r, "status.satellite_visible_z")?,
        ints(&mut r, "status.satellite_visible_azimuth")?,
        ints(&mut r, "status.satellite_visible_snr")?,
    ];
    if usize::from(n_used) != used.len() || usize::from(n_visible) != visible[0].len() {
        return Err(CdrError::Invalid {
            field: "status.satellites_used",
            problem: "counts differ from the PRN lists".into(),
        });
    }
    let status = r.i16("status.status")?;
    r.u16("status.motion_source")?;
    r.u16("status.orientation_source")?;
    r.u16("status.position_source")?;
    let _position_and_motion = r.f64s::<10>("latitude..time")?;
    let dop = r.f64s::<5>("gdop..tdop")?;
    let _err = r.f64s::<10>("err..err_dip")?;
    let _cov = read_cov3(&mut r, "position_covariance")?;
    r.u8("position_covariance_type")?;
    finish(&r)?;
    Ok((status, used, visible, dop))
}

/// Decodes a `sensor_msgs/NavSatFix` (status −1 or below: no fix; 0 and 1: stand-alone;
/// 2: RTK fixed, or float with [`SERVICE_VINEBENCH_RTK_FLOAT`]).
pub fn decode_nav_sat_fix(payload: &[u8]) -> Result<GnssFixMsg, CdrError> {
    let mut r = CdrReader::new(payload)?;
    let (stamp, frame_id) = read_header(&mut r)?;
    let status = r.i8("status.status")?;
    let service = r.u16("status.service")?;
    let status = match status {
        s if s < 0 => FixStatus::NoFix,
        0 | 1 => FixStatus::Single,
        2 if service & SERVICE_VINEBENCH_RTK_FLOAT != 0 => FixStatus::RtkFloat,
        2 => FixStatus::RtkFixed,
        s => {
            return Err(CdrError::Invalid {
                field: "status.status",
                problem: format!("{s}: expected -1, 0, 1 or 2"),
            });
        }
    };
    let position = Geodetic {
        lat_deg: r.f64("latitude")?,
        lon_deg: r.f64("longitude")?,
        alt_m: r.f64("altitude")?,
    };
    let mut position_covariance = read_cov3(&mut r, "position_covariance")?;
    match r.u8("position_covariance_type")? {
        // Without a fix the covariance means nothing either way: kept as written, so a
        // recording reads back bit for bit.
        COVARIANCE_TYPE_UNKNOWN if status == FixStatus::NoFix => {}
        COVARIANCE_TYPE_UNKNOWN => position_covariance.fill(f64::NAN),
        COVARIANCE_TYPE_DIAGONAL_KNOWN => {
            position_covariance = Matrix3::from_diagonal(&position_covariance.diagonal());
        }
        _ => {}
    }
    finish(&r)?;
    Ok(GnssFixMsg {
        stamp,
        frame_id,
        status,
        position,
        position_covariance,
    })
}

// ---- geometry_msgs/TwistWithCovarianceStamped -------------------------------------------

/// Encodes a GNSS velocity as `geometry_msgs/TwistWithCovarianceStamped`.
pub fn encode_gnss_velocity(m: &GnssVelocityMsg, buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    header(&mut w, m.stamp, m.frame_id.as_str());
    vector3(&mut w, &m.velocity_in_world);
    vector3(&mut w, &Vector3::zeros());
    let mut c = Matrix6::zeros();
    c.fixed_view_mut::<3, 3>(0, 0).copy_from(&m.covariance);
    cov6(&mut w, &c);
}

/// Decodes a `geometry_msgs/TwistWithCovarianceStamped` as a GNSS velocity (the linear
/// part and its covariance block).
pub fn decode_gnss_velocity(payload: &[u8]) -> Result<GnssVelocityMsg, CdrError> {
    let mut r = CdrReader::new(payload)?;
    let (stamp, frame_id) = read_header(&mut r)?;
    let velocity_in_world = read_vector3(&mut r, "twist.twist.linear")?;
    let _angular = read_vector3(&mut r, "twist.twist.angular")?;
    let c = read_cov6(&mut r, "twist.covariance")?;
    finish(&r)?;
    Ok(GnssVelocityMsg {
        stamp,
        frame_id,
        velocity_in_world,
        covariance: c.fixed_view::<3, 3>(0, 0).into_owned(),
    })
}

// ---- nav_msgs/Odometry ------------------------------------------------------------------

/// Encodes odometry as `nav_msgs/Odometry`.
pub fn encode_odometry(m: &OdometryMsg, buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    header(&mut w, m.stamp, m.frame_id.as_str());
    w.string(m.child_frame_id.as_str());
    pose(&mut w, &m.pose);
    cov6(&mut w, &m.pose_covariance);
    vector3(&mut w, &m.linear_velocity);
    vector3(&mut w, &m.angular_velocity);
    cov6(&mut w, &m.twist_covariance);
}

/// Decodes a `nav_msgs/Odometry`.
pub fn decode_odometry(payload: &[u8]) -> Result<OdometryMsg, CdrError> {
    let mut r = CdrReader::new(payload)?;
    let (stamp, frame_id) = read_header(&mut r)?;
    let child_frame_id = FrameId::new(r.string("child_frame_id")?);
    let pose = read_pose(&mut r, "pose.pose")?;
    let pose_covariance = read_cov6(&mut r, "pose.covariance")?;
    let linear_velocity = read_vector3(&mut r, "twist.twist.linear")?;
    let angular_velocity = read_vector3(&mut r, "twist.twist.angular")?;
    let twist_covariance = read_cov6(&mut r, "twist.covariance")?;
    finish(&r)?;
    Ok(OdometryMsg {
        stamp,
        frame_id,
        child_frame_id,
        pose,
        pose_covariance,
        linear_velocity,
        angular_velocity,
        twist_covariance,
    })
}

// ---- tf2_msgs/TFMessage -----------------------------------------------------------------

/// Encodes transforms as `tf2_msgs/TFMessage`.
pub fn encode_tf(transforms: &[TransformStamped], buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    w.seq_len(transforms.len());
    for t in transforms {
        header(&mut w, t.stamp, t.parent.as_str());
        w.string(t.child.as_str());
        pose(&mut w, &t.parent_from_child);
    }
}

/// Decodes a `tf2_msgs/TFMessage`.
pub fn decode_tf(payload: &[u8]) -> Result<Vec<TransformStamped>, CdrError> {
    let mut r = CdrReader::new(payload)?;
    // A transform takes at least 8 (stamp) + 4 + 4 (two empty strings' lengths) + 56 bytes.
    let n = r.seq_len("transforms", 72)?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let (stamp, parent) = read_header(&mut r)?;
        let child = FrameId::new(r.string("transforms.child_frame_id")?);
        let parent_from_child = read_pose(&mut r, "transforms.transform")?;
        out.push(TransformStamped {
            stamp,
            parent,
            child,
            parent_from_child,
        });
    }
    finish(&r)?;
    Ok(out)
}

// ---- sensor_msgs/Image ------------------------------------------------------------------

/// Encodes an image as `sensor_msgs/Image` (little-endian, rows without padding).
pub fn encode_image(m: &ImageMsg, buf: &mut Vec<u8>) {
    buf.reserve(m.data.len() + 64 + m.frame_id.as_str().len());
    let mut w = CdrWriter::new(buf);
    header(&mut w, m.stamp, m.frame_id.as_str());
    w.u32(m.height);
    w.u32(m.width);
    w.string(m.encoding.ros_name());
    w.u8(0);
    w.u32(m.width * m.encoding.bytes_per_pixel() as u32);
    w.bytes(&m.data);
}

/// The [`ImageEncoding`] of a `sensor_msgs/Image.encoding` string.
pub fn image_encoding(name: &str) -> Option<ImageEncoding> {
    [
        ImageEncoding::Rgb8,
        ImageEncoding::Mono8,
        ImageEncoding::Depth16Mm,
    ]
    .into_iter()
    .find(|e| e.ros_name() == name)
}

/// Decodes a `sensor_msgs/Image` published on `topic`. Encodings other than `rgb8`,
/// `mono8` and `16UC1`, big-endian data and padded rows are refused (named).
pub fn decode_image(payload: &[u8], topic: &Arc<str>) -> Result<ImageMsg, CdrError> {
    let mut r = CdrReader::new(payload)?;
    let (stamp, frame_id) = read_header(&mut r)?;
    let height = r.u32("height")?;
    let width = r.u32("width")?;
    let name = r.string("encoding")?;
    let encoding = image_encoding(name).ok_or_else(|| CdrError::Invalid {
        field: "encoding",
        problem: format!("`{name}`: expected rgb8, mono8 or 16UC1"),
    })?;
    let big = r.u8("is_bigendian")?;
    let step = r.u32("step")?;
    let expected_step = width as usize * encoding.bytes_per_pixel();
    if step as usize != expected_step {
        return Err(CdrError::Invalid {
            field: "step",
            problem: format!("{step}: expected {expected_step} (rows without padding)"),
        });
    }
    if big != 0 && encoding == ImageEncoding::Depth16Mm {
        return Err(CdrError::Invalid {
            field: "is_bigendian",
            problem: "big-endian 16UC1: expected little-endian".into(),
        });
    }
    let data = r.bytes("data")?;
    if data.len() != expected_step * height as usize {
        return Err(CdrError::Invalid {
            field: "data",
            problem: format!(
                "{} bytes: expected step·height = {}",
                data.len(),
                expected_step * height as usize
            ),
        });
    }
    let data: Arc<[u8]> = Arc::from(data);
    finish(&r)?;
    Ok(ImageMsg {
        stamp,
        topic: topic.clone(),
        frame_id,
        width,
        height,
        encoding,
        data,
    })
}

// ---- sensor_msgs/CameraInfo -------------------------------------------------------------

/// Encodes a calibration as `sensor_msgs/CameraInfo` (`plumb_bob`, no binning, full ROI).
pub fn encode_camera_info(m: &CameraInfoMsg, buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    header(&mut w, m.stamp, m.frame_id.as_str());
    w.u32(m.height);
    w.u32(m.width);
    w.string(PLUMB_BOB);
    w.seq_len(m.d.len());
    w.f64s(&m.d);
    w.f64s(&m.k);
    w.f64s(&m.r);
    w.f64s(&m.p);
    w.u32(0); // binning_x
    w.u32(0); // binning_y
    for _ in 0..4 {
        w.u32(0); // roi x_offset, y_offset, height, width: the full image
    }
    w.bool(false); // roi.do_rectify
}

/// Decodes a `sensor_msgs/CameraInfo` published on `topic`: `plumb_bob` (or an empty
/// model with no coefficients) with at most 5 coefficients, missing ones zero.
pub fn decode_camera_info(payload: &[u8], topic: &Arc<str>) -> Result<CameraInfoMsg, CdrError> {
    let mut r = CdrReader::new(payload)?;
    let (stamp, frame_id) = read_header(&mut r)?;
    let height = r.u32("height")?;
    let width = r.u32("width")?;
    let model = r.string("distortion_model")?;
    let n = r.seq_len("d", 8)?;
    if !(model == PLUMB_BOB || (model.is_empty() && n == 0)) || n > 5 {
        return Err(CdrError::Invalid {
            field: "distortion_model",
            problem: format!("`{model}` with {n} coefficients: expected plumb_bob with up to 5"),
        });
    }
    let mut d = [0.0; 5];
    for x in d.iter_mut().take(n) {
        *x = r.f64("d")?;
    }
    let k = r.f64s::<9>("k")?;
    let rr = r.f64s::<9>("r")?;
    let p = r.f64s::<12>("p")?;
    let _binning = (r.u32("binning_x")?, r.u32("binning_y")?);
    for _ in 0..4 {
        r.u32("roi")?;
    }
    r.bool("roi.do_rectify")?;
    finish(&r)?;
    Ok(CameraInfoMsg {
        stamp,
        topic: topic.clone(),
        frame_id,
        width,
        height,
        d,
        k,
        r: rr,
        p,
    })
}

// ---- sensor_msgs/PointCloud2 ------------------------------------------------------------

/// Encodes a point cloud as `sensor_msgs/PointCloud2`.
pub fn encode_point_cloud2(m: &PointCloud2Msg, buf: &mut Vec<u8>) {
    buf.reserve(m.data.len() + 64 + 24 * m.fields.len());
    let mut w = CdrWriter::new(buf);
    header(&mut w, m.stamp, m.frame_id.as_str());
    w.u32(m.height);
    w.u32(m.width);
    w.seq_len(m.fields.len());
    for f in &m.fields {
        w.string(&f.name);
        w.u32(f.offset);
        w.u8(f.datatype);
        w.u32(f.count);
    }
    w.bool(m.is_bigendian);
    w.u32(m.point_step);
    w.u32(m.row_step);
    w.bytes(&m.data);
    w.bool(m.is_dense);
}

/// Decodes a `sensor_msgs/PointCloud2`.
pub fn decode_point_cloud2(payload: &[u8]) -> Result<PointCloud2Msg, CdrError> {
    let mut r = CdrReader::new(payload)?;
    let (stamp, frame_id) = read_header(&mut r)?;
    let height = r.u32("height")?;
    let width = r.u32("width")?;
    let n = r.seq_len("fields", 13)?;
    let mut fields = Vec::with_capacity(n);
    for _ in 0..n {
        fields.push(PointField {
            name: r.string("fields.name")?.to_string(),
            offset: r.u32("fields.offset")?,
            datatype: r.u8("fields.datatype")?,
            count: r.u32("fields.count")?,
        });
    }
    let is_bigendian = r.bool("is_bigendian")?;
    let point_step = r.u32("point_step")?;
    let row_step = r.u32("row_step")?;
    let data: Arc<[u8]> = Arc::from(r.bytes("data")?);
    let is_dense = r.bool("is_dense")?;
    finish(&r)?;
    Ok(PointCloud2Msg {
        stamp,
        frame_id,
        height,
        width,
        fields,
        is_bigendian,
        point_step,
        row_step,
        data,
        is_dense,
    })
}
