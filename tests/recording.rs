//! Recording and replay (issue #5): CDR bytes checked by hand, write-then-read round
//! trips of every message type, recovery of truncated and corrupted files, Ctrl-C
//! leaving a finalized file, and replay reproducing a live run's estimates bit for bit.

#![allow(clippy::unwrap_used)] // test helpers outside #[test] fns panic on bad data by design

use nalgebra::{Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion, Vector3};
use proptest::prelude::*;
use std::io::Cursor;
use std::path::Path;
use std::sync::Arc;
use vinebench::recording::reader::{self, scan};
use vinebench::recording::ros::{self, PointCloud2Msg, PointField, TransformStamped};
use vinebench::recording::{McapSink, SinkOptions, schema};
use vinebench::replay::{ReplayOptions, replay};
use vinebench::runner::{RunOptions, run};
use vinebench::scenario::LoadedScenario;
use vinebench_msgs::geodesy::Geodetic;
use vinebench_msgs::{
    CameraInfoMsg, FixStatus, FrameId, GnssFixMsg, GnssVelocityMsg, ImageEncoding, ImageMsg,
    ImuMsg, Message, Nanos, OdometryMsg, TimedMessage,
};

// ---- hand-built CDR ----------------------------------------------------------------------
// Every padding byte is written out explicitly below: these vectors are built from the
// CDR rules (4-byte header 00 01 00 00; each primitive aligned to its size relative to the
// byte after the header; strings = u32 length with NUL, bytes, NUL), not by the encoder.

#[derive(Default)]
struct Bytes(Vec<u8>);
impl Bytes {
    fn new() -> Bytes {
        Bytes(vec![0x00, 0x01, 0x00, 0x00])
    }
    fn pad(&mut self, n: usize) -> &mut Self {
        self.0.extend(std::iter::repeat_n(0u8, n));
        self
    }
    fn u8(&mut self, v: u8) -> &mut Self {
        self.0.push(v);
        self
    }
    fn u16(&mut self, v: u16) -> &mut Self {
        self.0.extend(v.to_le_bytes());
        self
    }
    fn u32(&mut self, v: u32) -> &mut Self {
        self.0.extend(v.to_le_bytes());
        self
    }
    fn i32(&mut self, v: i32) -> &mut Self {
        self.0.extend(v.to_le_bytes());
        self
    }
    fn f64(&mut self, v: f64) -> &mut Self {
        self.0.extend(v.to_le_bytes());
        self
    }
    fn f64s(&mut self, v: &[f64]) -> &mut Self {
        for x in v {
            self.f64(*x);
        }
        self
    }
    fn raw(&mut self, v: &[u8]) -> &mut Self {
        self.0.extend_from_slice(v);
        self
    }
    /// Offset after the encapsulation header (what alignment is relative to).
    fn offset(&self) -> usize {
        self.0.len() - 4
    }
}

/// Stamp 1.5 s + 7 ns: sec 1, nanosec 500000007.
const STAMP: Nanos = Nanos(1_500_000_007);

fn enc(f: impl FnOnce(&mut Vec<u8>)) -> Vec<u8> {
    let mut v = Vec::new();
    f(&mut v);
    v
}

#[test]
fn imu_bytes_by_hand() {
    let m = ImuMsg {
        stamp: STAMP,
        frame_id: FrameId::new("imu"),
        orientation: Some(UnitQuaternion::identity()),
        orientation_covariance: Matrix3::from_row_slice(&[
            1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0,
        ]),
        angular_velocity: Vector3::new(0.1, 0.2, 0.3),
        angular_velocity_covariance: Matrix3::identity(),
        linear_acceleration: Vector3::new(0.0, 0.0, 9.8),
        linear_acceleration_covariance: Matrix3::identity() * 2.0,
    };
    let mut b = Bytes::new();
    // header: stamp (sec 1, nanosec 500000007) at 0..8, "imu\0" with length 4 at 8..16.
    b.i32(1).u32(500_000_007).u32(4).raw(b"imu\0");
    assert_eq!(b.offset(), 16); // 8-aligned already: no padding before the quaternion
    b.f64s(&[0.0, 0.0, 0.0, 1.0]); // x, y, z, w
    b.f64s(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]); // row-major
    b.f64s(&[0.1, 0.2, 0.3]);
    b.f64s(&[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]);
    b.f64s(&[0.0, 0.0, 9.8]);
    b.f64s(&[2.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 2.0]);
    assert_eq!(enc(|v| ros::encode_imu(&m, v)), b.0);
    assert_eq!(ros::decode_imu(&b.0).unwrap(), m);

    // No orientation: orientation_covariance[0] = -1 (the ROS convention).
    let mut none = m.clone();
    none.orientation = None;
    none.orientation_covariance = Matrix3::zeros();
    let bytes = enc(|v| ros::encode_imu(&none, v));
    assert_eq!(&bytes[4 + 48..4 + 56], &(-1.0f64).to_le_bytes());
    assert_eq!(ros::decode_imu(&bytes).unwrap(), none);
}

#[test]
fn nav_sat_fix_bytes_by_hand() {
    let m = GnssFixMsg {
        stamp: STAMP,
        frame_id: FrameId::new("gnss_antenna"),
        status: FixStatus::RtkFloat,
        position: Geodetic {
            lat_deg: 40.5,
            lon_deg: 17.25,
            alt_m: 50.0,
        },
        position_covariance: Matrix3::from_diagonal(&Vector3::new(0.01, 0.02, 0.04)),
    };
    let mut b = Bytes::new();
    b.i32(1).u32(500_000_007);
    b.u32(13).raw(b"gnss_antenna\0"); // 8..25
    assert_eq!(b.offset(), 25);
    b.u8(2); // status.status = STATUS_GBAS_FIX (int8), offset 25
    b.u16(0x8000 | 11); // service at offset 26 (2-aligned): GPS|GLONASS|GALILEO + float bit
    assert_eq!(b.offset(), 28);
    b.pad(4); // latitude is 8-aligned: 28 → 32
    b.f64s(&[40.5, 17.25, 50.0]);
    b.f64s(&[0.01, 0.0, 0.0, 0.0, 0.02, 0.0, 0.0, 0.0, 0.04]);
    b.u8(3); // COVARIANCE_TYPE_KNOWN
    assert_eq!(enc(|v| ros::encode_nav_sat_fix(&m, v)), b.0);
    assert_eq!(ros::decode_nav_sat_fix(&b.0).unwrap(), m);
}

#[test]
fn no_fix_nav_sat_fix_has_an_unknown_covariance() {
    // A no-fix epoch: status −1, position NaN, covariance zero and its type UNKNOWN (0),
    // not KNOWN with zeros (a consumer would read that as a perfect fix).
    let m = GnssFixMsg {
        stamp: STAMP,
        frame_id: FrameId::new("gnss_antenna"),
        status: FixStatus::NoFix,
        position: Geodetic {
            lat_deg: f64::NAN,
            lon_deg: f64::NAN,
            alt_m: f64::NAN,
        },
        position_covariance: Matrix3::zeros(),
    };
    let bytes = enc(|v| ros::encode_nav_sat_fix(&m, v));
    assert_eq!(bytes[4 + 25] as i8, -1); // status.status after the 4-byte CDR header
    assert_eq!(*bytes.last().unwrap(), 0, "position_covariance_type");
    // Read back as written (a no-fix covariance means nothing either way).
    let back = ros::decode_nav_sat_fix(&bytes).unwrap();
    assert_eq!(back.status, FixStatus::NoFix);
    assert_eq!(back.position_covariance, Matrix3::zeros());
}

#[test]
fn gps_fix_bytes_by_hand() {
    use vinebench_msgs::{Dop, GnssSatellite, GnssSkyMsg, GnssSystem};
    let sat = |system, prn, az, el, cn0: f64, tracked, used| GnssSatellite {
        system,
        prn,
        azimuth_deg: az,
        elevation_deg: el,
        cn0_dbhz: cn0,
        tracked,
        used,
        strong: false,
        leaves: 0,
        blocked: !tracked,
    };
    let dop = Dop {
        gdop: 1.5,
        pdop: 1.25,
        hdop: 0.75,
        vdop: 1.0,
        tdop: 0.5,
    };
    let m = GnssSkyMsg {
        stamp: STAMP,
        frame_id: FrameId::new("ab"),
        status: FixStatus::RtkFloat,
        position: Geodetic {
            lat_deg: 40.5,
            lon_deg: 17.25,
            alt_m: 50.0,
        },
        position_covariance: Matrix3::from_diagonal(&Vector3::new(0.04, 0.04, 0.09)),
        dop: Some(dop),
        corrections: true,
        satellites: vec![
            sat(GnssSystem::Gps, 5, 120.6, 45.4, 44.6, true, true),
            sat(GnssSystem::Galileo, 3, 299.8, 12.2, 31.2, true, false),
            sat(GnssSystem::Glonass, 7, 10.0, 5.0, f64::NAN, false, false),
        ],
    };
    let mut b = Bytes::new();
    b.i32(1).u32(500_000_007).u32(3).raw(b"ab\0"); // header, ends at 15
    b.pad(1).i32(1).u32(500_000_007).u32(3).raw(b"ab\0"); // status.header: 16..31
    b.pad(1).u16(1); // satellites_used at 32
    b.pad(2).u32(1).i32(5); // satellite_used_prn at 36: [5]
    b.u16(2); // satellites_visible at 44
    b.pad(2).u32(2).i32(5).i32(303); // visible PRNs at 48 (Galileo 3 → 303)
    b.u32(2).i32(45).i32(12); // elevations, whole degrees
    b.u32(2).i32(121).i32(300); // azimuths
    b.u32(2).i32(45).i32(31); // C/N0
    assert_eq!(b.offset(), 96);
    b.raw(&20i16.to_le_bytes()); // status = STATUS_RTK_FLOAT
    b.u16(0).u16(0).u16(1); // motion, orientation, position source (SOURCE_GPS)
    assert_eq!(b.offset(), 104);
    b.f64s(&[40.5, 17.25, 50.0]);
    b.f64s(&[f64::NAN; 7]); // track, speed, climb, pitch, roll, dip, time
    b.f64s(&[1.5, 1.25, 0.75, 1.0, 0.5]); // gdop, pdop, hdop, vdop, tdop
    // 95 % radii: 2.796·√(0.17/3), 2.448·√0.04, 1.960·√0.09.
    b.f64s(&[
        2.796 * ((0.04f64 + 0.04 + 0.09) / 3.0).sqrt(),
        2.448 * ((0.04f64 + 0.04) / 2.0).sqrt(),
        1.960 * 0.09f64.sqrt(),
    ]);
    b.f64s(&[f64::NAN; 7]);
    b.f64s(&[0.04, 0.0, 0.0, 0.0, 0.04, 0.0, 0.0, 0.0, 0.09]);
    b.u8(3);
    let got = enc(|v| ros::encode_gps_fix(&m, v));
    assert_eq!(got.len(), b.0.len());
    for (i, (x, y)) in got.iter().zip(&b.0).enumerate() {
        assert_eq!(x, y, "byte {i}");
    }
    let (status, used, visible, dops) = ros::decode_gps_fix_status(&got).unwrap();
    assert_eq!((status, used), (20, vec![5]));
    assert_eq!(visible[0], vec![5, 303]);
    assert_eq!(dops, [1.5, 1.25, 0.75, 1.0, 0.5]);
    assert_eq!(
        schema::GPS_FIX.full_definition().matches("MSG: ").count(),
        3,
        "GPSFix, its Header (and Time) and GPSStatus"
    );
}

#[test]
fn twist_with_covariance_stamped_bytes_by_hand() {
    let m = GnssVelocityMsg {
        stamp: STAMP,
        frame_id: FrameId::new("ab"),
        velocity_in_world: Vector3::new(1.0, -2.0, 0.5),
        covariance: Matrix3::from_row_slice(&[1.0, 0.1, 0.0, 0.1, 2.0, 0.0, 0.0, 0.0, 3.0]),
    };
    let mut b = Bytes::new();
    b.i32(1).u32(500_000_007).u32(3).raw(b"ab\0"); // ends at offset 15
    b.pad(1); // → 16
    b.f64s(&[1.0, -2.0, 0.5, 0.0, 0.0, 0.0]);
    let mut cov = [0.0; 36];
    cov[..3].copy_from_slice(&[1.0, 0.1, 0.0]);
    cov[6..9].copy_from_slice(&[0.1, 2.0, 0.0]);
    cov[12..15].copy_from_slice(&[0.0, 0.0, 3.0]);
    b.f64s(&cov);
    assert_eq!(enc(|v| ros::encode_gnss_velocity(&m, v)), b.0);
    assert_eq!(ros::decode_gnss_velocity(&b.0).unwrap(), m);
}

#[test]
fn odometry_bytes_by_hand() {
    let pose_cov = Matrix6::from_fn(|r, c| (r * 6 + c) as f64);
    let m = OdometryMsg {
        stamp: STAMP,
        frame_id: FrameId::new("odom"),
        child_frame_id: FrameId::new("base"),
        pose: Isometry3::from_parts(
            Translation3::new(1.0, 2.0, 3.0),
            UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(0.0, 1.0, 0.0, 0.0)),
        ),
        pose_covariance: pose_cov,
        linear_velocity: Vector3::new(0.5, 0.0, 0.0),
        angular_velocity: Vector3::new(0.0, 0.0, 0.25),
        twist_covariance: Matrix6::identity(),
    };
    let mut b = Bytes::new();
    b.i32(1).u32(500_000_007).u32(5).raw(b"odom\0"); // 8..17
    b.pad(3).u32(5).raw(b"base\0"); // align 20, then 20..29
    b.pad(3); // 29 → 32 for the f64 position
    b.f64s(&[1.0, 2.0, 3.0, 1.0, 0.0, 0.0, 0.0]); // position, quaternion x y z w
    let rows: Vec<f64> = (0..36).map(|i| i as f64).collect(); // row-major = r*6+c
    b.f64s(&rows);
    b.f64s(&[0.5, 0.0, 0.0, 0.0, 0.0, 0.25]);
    let id: Vec<f64> = (0..36)
        .map(|i| if i % 7 == 0 { 1.0 } else { 0.0 })
        .collect();
    b.f64s(&id);
    assert_eq!(enc(|v| ros::encode_odometry(&m, v)), b.0);
    assert_eq!(ros::decode_odometry(&b.0).unwrap(), m);
}

#[test]
fn tf_message_bytes_by_hand() {
    let t = TransformStamped {
        stamp: STAMP,
        parent: FrameId::new("base_link"),
        child: FrameId::new("imu"),
        parent_from_child: Isometry3::translation(0.1, 0.0, 0.2),
    };
    let mut b = Bytes::new();
    b.u32(2); // two transforms
    // First transform, from offset 4.
    b.i32(1).u32(500_000_007).u32(10).raw(b"base_link\0"); // 4..26
    b.pad(2).u32(4).raw(b"imu\0"); // 28..36
    b.pad(4); // 36 → 40 for the f64 translation
    b.f64s(&[0.1, 0.0, 0.2, 0.0, 0.0, 0.0, 1.0]); // 40..96
    // Second transform, from offset 96: the same fields fall differently.
    b.i32(1).u32(500_000_007).u32(10).raw(b"base_link\0"); // 96..118
    b.pad(2).u32(4).raw(b"imu\0"); // 120..128, already 8-aligned
    b.f64s(&[0.1, 0.0, 0.2, 0.0, 0.0, 0.0, 1.0]);
    assert_eq!(b.offset(), 184);
    let ts = [t.clone(), t];
    assert_eq!(enc(|v| ros::encode_tf(&ts, v)), b.0);
    assert_eq!(ros::decode_tf(&b.0).unwrap(), ts);
}

#[test]
fn image_bytes_by_hand() {
    let topic: Arc<str> = Arc::from("/cam/image");
    let m = ImageMsg {
        stamp: STAMP,
        topic: topic.clone(),
        frame_id: FrameId::new("cam"),
        width: 2,
        height: 1,
        encoding: ImageEncoding::Depth16Mm,
        data: Arc::from(vec![1u8, 2, 3, 4]),
    };
    let mut b = Bytes::new();
    b.i32(1).u32(500_000_007).u32(4).raw(b"cam\0"); // 8..16
    b.u32(1).u32(2); // height, width
    b.u32(6).raw(b"16UC1\0"); // 24..34
    b.u8(0); // is_bigendian at 34
    b.pad(1).u32(4); // step at 36 = 2 px * 2 bytes
    b.u32(4).raw(&[1, 2, 3, 4]);
    assert_eq!(enc(|v| ros::encode_image(&m, v)), b.0);
    assert_eq!(ros::decode_image(&b.0, &topic).unwrap(), m);
}

#[test]
fn camera_info_bytes_by_hand() {
    let topic: Arc<str> = Arc::from("/cam/camera_info");
    let m = CameraInfoMsg {
        stamp: STAMP,
        topic: topic.clone(),
        frame_id: FrameId::new("cam"),
        width: 640,
        height: 480,
        d: [0.1, -0.2, 0.001, 0.002, 0.05],
        k: [500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [
            500.0, 0.0, 320.0, -25.0, 0.0, 500.0, 240.0, 0.0, 0.0, 0.0, 1.0, 0.0,
        ],
    };
    let mut b = Bytes::new();
    b.i32(1).u32(500_000_007).u32(4).raw(b"cam\0"); // 8..16
    b.u32(480).u32(640); // height, width
    b.u32(10).raw(b"plumb_bob\0"); // 24..38
    b.pad(2).u32(5); // d length at 40
    assert_eq!(b.offset(), 44);
    b.pad(4); // 44 → 48
    b.f64s(&m.d).f64s(&m.k).f64s(&m.r).f64s(&m.p);
    b.u32(0).u32(0); // binning
    b.u32(0).u32(0).u32(0).u32(0).u8(0); // roi
    assert_eq!(enc(|v| ros::encode_camera_info(&m, v)), b.0);
    assert_eq!(ros::decode_camera_info(&b.0, &topic).unwrap(), m);
}

#[test]
fn point_cloud2_bytes_by_hand() {
    let m = PointCloud2Msg {
        stamp: STAMP,
        frame_id: FrameId::new("map"),
        height: 1,
        width: 1,
        fields: vec![PointField {
            name: "x".into(),
            offset: 0,
            datatype: 7,
            count: 1,
        }],
        is_bigendian: false,
        point_step: 4,
        row_step: 4,
        data: Arc::from(1.5f32.to_le_bytes().to_vec()),
        is_dense: true,
    };
    let mut b = Bytes::new();
    b.i32(1).u32(500_000_007).u32(4).raw(b"map\0"); // 8..16
    b.u32(1).u32(1).u32(1); // height, width, fields length
    b.u32(2).raw(b"x\0"); // 28..34
    b.pad(2).u32(0).u8(7); // offset at 36, datatype at 40
    b.pad(3).u32(1); // count at 44
    b.u8(0); // is_bigendian at 48
    b.pad(3).u32(4).u32(4); // point_step at 52, row_step at 56
    b.u32(4).raw(&1.5f32.to_le_bytes()); // data
    b.u8(1); // is_dense
    assert_eq!(enc(|v| ros::encode_point_cloud2(&m, v)), b.0);
    assert_eq!(ros::decode_point_cloud2(&b.0).unwrap(), m);
}

// ---- round trip through an MCAP file -------------------------------------------------------

fn f() -> impl Strategy<Value = f64> {
    -1e6..1e6f64
}
fn v3() -> impl Strategy<Value = Vector3<f64>> {
    (f(), f(), f()).prop_map(|(x, y, z)| Vector3::new(x, y, z))
}
fn m3() -> impl Strategy<Value = Matrix3<f64>> {
    proptest::collection::vec(f(), 9).prop_map(|v| Matrix3::from_row_slice(&v))
}
fn m6() -> impl Strategy<Value = Matrix6<f64>> {
    proptest::collection::vec(f(), 36).prop_map(|v| Matrix6::from_row_slice(&v))
}
fn rot() -> impl Strategy<Value = UnitQuaternion<f64>> {
    (-3.0..3.0f64, -1.5..1.5f64, -3.0..3.0f64)
        .prop_map(|(r, p, y)| UnitQuaternion::from_euler_angles(r, p, y))
}
fn iso() -> impl Strategy<Value = Isometry3<f64>> {
    (v3(), rot()).prop_map(|(t, q)| Isometry3::from_parts(Translation3::from(t), q))
}
fn stamp() -> impl Strategy<Value = Nanos> {
    // builtin_interfaces/Time.sec is an int32: up to 2038.
    (0i64..2_000_000_000_000_000_000).prop_map(Nanos)
}
fn frame() -> impl Strategy<Value = FrameId> {
    "[a-z_]{0,12}".prop_map(|s| FrameId::new(&s))
}

fn message() -> impl Strategy<Value = Message> {
    let imu = (
        stamp(),
        frame(),
        proptest::option::of(rot()),
        m3(),
        v3(),
        m3(),
        v3(),
        m3(),
    )
        .prop_map(|(stamp, frame_id, o, oc, w, wc, a, ac)| {
            Message::Imu(ImuMsg {
                stamp,
                frame_id,
                orientation: o,
                orientation_covariance: if o.is_some() { oc } else { Matrix3::zeros() },
                angular_velocity: w,
                angular_velocity_covariance: wc,
                linear_acceleration: a,
                linear_acceleration_covariance: ac,
            })
        });
    let fix = (stamp(), frame(), 0usize..4, v3(), m3()).prop_map(|(stamp, frame_id, s, p, c)| {
        Message::GnssFix(GnssFixMsg {
            stamp,
            frame_id,
            status: [
                FixStatus::NoFix,
                FixStatus::Single,
                FixStatus::RtkFloat,
                FixStatus::RtkFixed,
            ][s],
            position: Geodetic {
                lat_deg: p.x,
                lon_deg: p.y,
                alt_m: p.z,
            },
            position_covariance: c,
        })
    });
    let vel = (stamp(), frame(), v3(), m3()).prop_map(|(stamp, frame_id, v, c)| {
        Message::GnssVelocity(GnssVelocityMsg {
            stamp,
            frame_id,
            velocity_in_world: v,
            covariance: c,
        })
    });
    let odom = (
        stamp(),
        frame(),
        frame(),
        iso(),
        m6(),
        v3(),
        v3(),
        m6(),
        any::<bool>(),
    )
        .prop_map(
            |(stamp, frame_id, child_frame_id, pose, pc, lv, av, tc, wheel)| {
                let o = OdometryMsg {
                    stamp,
                    frame_id,
                    child_frame_id,
                    pose,
                    pose_covariance: pc,
                    linear_velocity: lv,
                    angular_velocity: av,
                    twist_covariance: tc,
                };
                if wheel {
                    Message::WheelOdom(o)
                } else {
                    Message::TrackingOdom(o)
                }
            },
        );
    let image = (stamp(), frame(), 1u32..9, 1u32..7, 0usize..3, any::<u64>()).prop_map(
        |(stamp, frame_id, width, height, e, seed)| {
            let encoding = [
                ImageEncoding::Rgb8,
                ImageEncoding::Mono8,
                ImageEncoding::Depth16Mm,
            ][e];
            let n = (width * height) as usize * encoding.bytes_per_pixel();
            let data: Vec<u8> = (0..n).map(|i| (seed >> (i % 57)) as u8).collect();
            Message::Image(ImageMsg {
                stamp,
                topic: Arc::from(format!("/cam{e}/image").as_str()),
                frame_id,
                width,
                height,
                encoding,
                data: Arc::from(data),
            })
        },
    );
    let info = (
        stamp(),
        frame(),
        proptest::collection::vec(f(), 5 + 9 + 9 + 12),
    )
        .prop_map(|(stamp, frame_id, v)| {
            let mut d = [0.0; 5];
            let mut k = [0.0; 9];
            let mut r = [0.0; 9];
            let mut p = [0.0; 12];
            d.copy_from_slice(&v[..5]);
            k.copy_from_slice(&v[5..14]);
            r.copy_from_slice(&v[14..23]);
            p.copy_from_slice(&v[23..]);
            Message::CameraInfo(CameraInfoMsg {
                stamp,
                topic: Arc::from("/cam/camera_info"),
                frame_id,
                width: 640,
                height: 480,
                d,
                k,
                r,
                p,
            })
        });
    prop_oneof![imu, fix, vel, odom, image, info]
}

fn decode(schema_name: &str, topic: &str, data: &[u8]) -> Message {
    let t: Arc<str> = Arc::from(topic);
    match schema_name {
        "sensor_msgs/msg/Imu" => Message::Imu(ros::decode_imu(data).unwrap()),
        "sensor_msgs/msg/NavSatFix" => Message::GnssFix(ros::decode_nav_sat_fix(data).unwrap()),
        "geometry_msgs/msg/TwistWithCovarianceStamped" => {
            Message::GnssVelocity(ros::decode_gnss_velocity(data).unwrap())
        }
        "nav_msgs/msg/Odometry" if topic == "/wheel/odom" => {
            Message::WheelOdom(ros::decode_odometry(data).unwrap())
        }
        "nav_msgs/msg/Odometry" => Message::TrackingOdom(ros::decode_odometry(data).unwrap()),
        "sensor_msgs/msg/Image" => Message::Image(ros::decode_image(data, &t).unwrap()),
        "sensor_msgs/msg/CameraInfo" => {
            Message::CameraInfo(ros::decode_camera_info(data, &t).unwrap())
        }
        other => panic!("unexpected schema {other}"),
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn write_then_read_is_lossless(
        msgs in proptest::collection::vec((message(), 0i64..1_000_000), 1..12),
        tfs in proptest::collection::vec((frame(), frame(), iso()), 0..4),
        clouds in proptest::collection::vec((stamp(), 1u32..20, any::<u8>()), 0..3),
    ) {
        let mut file = Cursor::new(Vec::new());
        let opts = SinkOptions { chunk_size: 512, ..SinkOptions::default() };
        let mut sink = McapSink::new(&mut file, &opts).unwrap();
        let mut want = Vec::new();
        for (m, latency) in &msgs {
            let tm = TimedMessage { arrival: m.stamp() + Nanos(*latency), msg: m.clone() };
            sink.write_message(&tm).unwrap();
            want.push(tm);
        }
        let transforms: Vec<TransformStamped> = tfs
            .iter()
            .map(|(p, c, x)| TransformStamped {
                stamp: Nanos(5),
                parent: p.clone(),
                child: c.clone(),
                parent_from_child: *x,
            })
            .collect();
        sink.write_tf("/tf", &transforms, Nanos(5)).unwrap();
        let clouds: Vec<PointCloud2Msg> = clouds
            .iter()
            .map(|(stamp, n, fill)| PointCloud2Msg {
                stamp: *stamp,
                frame_id: FrameId::new("map"),
                height: 1,
                width: *n,
                fields: vec![
                    PointField { name: "x".into(), offset: 0, datatype: 7, count: 1 },
                    PointField { name: "rgb".into(), offset: 4, datatype: 6, count: 1 },
                ],
                is_bigendian: false,
                point_step: 8,
                row_step: 8 * n,
                data: Arc::from(vec![*fill; 8 * *n as usize]),
                is_dense: *fill % 2 == 0,
            })
            .collect();
        for c in &clouds {
            sink.write_point_cloud2("/map/points", c, c.stamp).unwrap();
        }
        sink.finish().unwrap();

        let mut got = Vec::new();
        let mut got_tf = Vec::new();
        let mut got_clouds = Vec::new();
        let summary = scan(file.get_ref(), |ch, m| match ch.schema_name.as_str() {
            "tf2_msgs/msg/TFMessage" => got_tf = ros::decode_tf(m.data).unwrap(),
            "sensor_msgs/msg/PointCloud2" => {
                got_clouds.push(ros::decode_point_cloud2(m.data).unwrap())
            }
            s => {
                let msg = decode(s, &ch.topic, m.data);
                assert_eq!(m.log_time, msg.stamp());
                got.push(TimedMessage { arrival: m.publish_time, msg });
            }
        })
        .unwrap();
        prop_assert!(summary.damage.is_none(), "{:?}", summary.damage);
        prop_assert_eq!(summary.profile.as_str(), "ros2");
        prop_assert_eq!(got, want);
        prop_assert_eq!(got_tf, transforms);
        prop_assert_eq!(got_clouds, clouds);
    }
}

#[test]
fn every_schema_is_a_complete_ros2msg_definition() {
    for ty in [
        &schema::IMU,
        &schema::NAV_SAT_FIX,
        &schema::TWIST_WITH_COVARIANCE_STAMPED,
        &schema::ODOMETRY,
        &schema::TF_MESSAGE,
        &schema::IMAGE,
        &schema::CAMERA_INFO,
        &schema::POINT_CLOUD2,
    ] {
        let def = ty.full_definition();
        // Every complex field type is defined in a `MSG:` section.
        let defined: Vec<String> = def
            .lines()
            .filter_map(|l| l.strip_prefix("MSG: ").map(str::to_string))
            .collect();
        let mut pkg = ty.short.split('/').next().unwrap().to_string();
        for line in def.lines() {
            if let Some(name) = line.strip_prefix("MSG: ") {
                pkg = name.split('/').next().unwrap().to_string();
                continue;
            }
            let Some(field_type) = line.split_whitespace().next() else {
                continue;
            };
            let base = field_type.split('[').next().unwrap();
            let primitive = [
                "bool", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64",
                "float32", "float64", "string", "byte", "char",
            ];
            if primitive.contains(&base) || line.starts_with('=') {
                continue;
            }
            let full = if base.contains('/') {
                base.to_string()
            } else {
                format!("{pkg}/{base}")
            };
            assert!(defined.contains(&full), "{}: {full} undefined", ty.short);
        }
    }
}

// ---- damaged files -----------------------------------------------------------------------

fn imu_at(k: i64) -> TimedMessage {
    TimedMessage {
        arrival: Nanos(1_000_000_000 + k * 5_000_000 + 1_000),
        msg: Message::Imu(ImuMsg {
            stamp: Nanos(1_000_000_000 + k * 5_000_000),
            frame_id: FrameId::new("imu_link"),
            orientation: None,
            orientation_covariance: Matrix3::zeros(),
            angular_velocity: Vector3::new(k as f64, 0.0, 0.0),
            angular_velocity_covariance: Matrix3::identity(),
            linear_acceleration: Vector3::new(0.0, 0.0, 9.8),
            linear_acceleration_covariance: Matrix3::identity(),
        }),
    }
}

/// 2000 IMU messages in chunks of about 16 KiB.
fn small_recording() -> (Vec<u8>, Vec<TimedMessage>) {
    let mut file = Cursor::new(Vec::new());
    let opts = SinkOptions {
        chunk_size: 16 * 1024,
        ..SinkOptions::default()
    };
    let mut sink = McapSink::new(&mut file, &opts).unwrap();
    let msgs: Vec<TimedMessage> = (0..2000).map(imu_at).collect();
    for m in &msgs {
        sink.write_message(m).unwrap();
    }
    sink.finish().unwrap();
    (file.into_inner(), msgs)
}

fn read_imu(bytes: &[u8]) -> (Vec<TimedMessage>, reader::McapSummary) {
    let mut got = Vec::new();
    let s = scan(bytes, |_, m| {
        got.push(TimedMessage {
            arrival: m.publish_time,
            msg: Message::Imu(ros::decode_imu(m.data).unwrap()),
        })
    })
    .unwrap();
    (got, s)
}

#[test]
fn truncated_files_give_every_complete_chunk() {
    let (bytes, msgs) = small_recording();
    let (all, s) = read_imu(&bytes);
    assert_eq!(all, msgs);
    assert!(s.damage.is_none());
    assert!(s.chunks > 10, "{} chunks", s.chunks);
    let mut last = 0;
    for frac in [0.1, 0.35, 0.5, 0.8, 0.97] {
        let cut = (bytes.len() as f64 * frac) as usize;
        let (got, s) = read_imu(&bytes[..cut]);
        let d = s.damage.expect("a cut file is damaged");
        assert!(d.summary_missing && d.bytes_unread > 0, "{d}");
        assert!(got.len() >= last, "later cuts recover at least as much");
        assert!(!got.is_empty(), "cut at {frac}: nothing recovered");
        assert_eq!(got[..], msgs[..got.len()], "a prefix, intact");
        last = got.len();
    }
    // Cut inside the summary: every message is still there.
    let (got, s) = read_imu(&bytes[..bytes.len() - 40]);
    assert_eq!(got.len(), msgs.len());
    assert!(s.damage.is_some_and(|d| d.summary_missing));
    // Nothing but the magic: no messages, still not an error.
    let (got, _) = read_imu(&bytes[..8]);
    assert!(got.is_empty());
    // Not an MCAP file at all: an error that says what was expected.
    let e = scan(b"PK\x03\x04 not mcap", |_, _| {})
        .unwrap_err()
        .to_string();
    assert!(e.contains("MCAP magic"), "{e}");
}

#[test]
fn a_corrupt_chunk_is_skipped_and_reported() {
    let (mut bytes, msgs) = small_recording();
    // Walk the top-level records (opcode u8, length u64, body) to the middle chunk and
    // flip bytes at the end of its compressed data.
    let mut pos = 8;
    let mut chunks = Vec::new();
    while pos + 9 <= bytes.len() {
        let len = u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().unwrap()) as usize;
        if bytes[pos] == 0x06 {
            chunks.push((pos, len));
        }
        pos += 9 + len;
    }
    let (at, len) = chunks[chunks.len() / 2];
    let end = at + 9 + len;
    for b in &mut bytes[end - 40..end - 8] {
        *b ^= 0xa5;
    }
    let (got, s) = read_imu(&bytes);
    let d = s.damage.expect("damage reported");
    assert!(d.chunks_lost >= 1, "{d}");
    assert!(d.to_string().contains("lost"), "{d}");
    assert!(got.len() < msgs.len() && got.len() > msgs.len() / 2);
    // What was recovered is intact and in order.
    for m in &got {
        assert!(msgs.contains(m));
    }
}

// ---- runs, replay, interrupt ---------------------------------------------------------------

const SHORT: &str =
    "name = \"rec-short\"\nmax_duration_s = 25.0\n[motion]\nmodel = \"kinematic\"\n";

/// Runs `sc` into `dir`.
fn run_into(sc: &LoadedScenario, dir: &Path) -> vinebench::runner::RunOutcome {
    let opts = RunOptions {
        out_dir: Some(dir.to_path_buf()),
        progress: false,
        ..RunOptions::default()
    };
    run(sc, &opts).unwrap()
}

fn live_run(dir: &Path) -> vinebench::runner::RunOutcome {
    run_into(&LoadedScenario::from_str(SHORT, "short.toml").unwrap(), dir)
}

/// Replays the recording of the run in `live` into `out`.
fn replay_run(live: &Path, out: &Path) -> vinebench::replay::ReplayOutcome {
    replay(
        &live.join("recording.mcap"),
        &ReplayOptions {
            out_dir: Some(out.to_path_buf()),
            ..ReplayOptions::default()
        },
    )
    .unwrap()
}

#[test]
fn replay_of_a_run_equals_the_live_run_bit_for_bit() {
    let tmp = tempfile::tempdir().unwrap();
    let live = tmp.path().join("live");
    let outcome = live_run(&live);
    let rep = tmp.path().join("replay");
    let r = replay_run(&live, &rep);
    assert!(r.report.damage.is_none());
    assert_eq!(r.report.sources.len(), outcome.report.sources.len());
    for s in &outcome.report.sources {
        let name = format!("estimate_{}.tum", s.name);
        let a = std::fs::read(live.join(&name)).unwrap();
        let b = std::fs::read(rep.join(&name)).unwrap();
        assert!(!a.is_empty());
        assert!(a == b, "{name} differs between live run and replay");
    }
    assert_eq!(
        std::fs::read(live.join("ground_truth.tum")).unwrap(),
        std::fs::read(rep.join("ground_truth.tum")).unwrap()
    );
    // Scoring used the recorded ground truth: the same ATE as live.
    for (a, b) in outcome.report.sources.iter().zip(&r.report.sources) {
        let live_ate = a.score.metric("ate_rmse_m");
        let replay_ate = b.score.as_ref().and_then(|s| s.metric("ate_rmse_m"));
        assert_eq!(live_ate, replay_ate, "{}", a.name);
    }
    assert_eq!(
        r.report.expectations.len(),
        outcome.report.expectations.len()
    );

    // The same recording, cut short, still replays (what it holds) and says so.
    let bytes = std::fs::read(live.join("recording.mcap")).unwrap();
    let cut = tmp.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let r = replay(
        &cut,
        &ReplayOptions {
            out_dir: Some(tmp.path().join("cut")),
            ..ReplayOptions::default()
        },
    )
    .unwrap();
    assert!(r.report.damage.is_some());
    assert!(r.report.sources.iter().any(|s| s.poses > 0));
    // Cut before the first message: nothing usable, an error naming the file.
    std::fs::write(&cut, &bytes[..200]).unwrap();
    let e = replay(&cut, &ReplayOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("cut.mcap"), "{e}");
}

/// A SLAM run's recording (images, camera_info, IMU, /tf_static) replays to the same
/// SLAM trajectories and loop file, bit for bit: the first seconds of the box-occluder
/// scenario (the tag seen once as the rover sets off).
#[test]
fn replay_runs_the_recorded_slam_to_the_same_trajectories() {
    let tmp = tempfile::tempdir().unwrap();
    let live = tmp.path().join("live");
    let mut sc = LoadedScenario::from_str(
        vinebench::bench::CSL_BOX_OCCLUDER_TOML,
        "csl-box-occluder.toml",
    )
    .unwrap();
    sc.scenario.max_duration_s = 7.0;
    let outcome = run_into(&sc, &live);
    let rep = tmp.path().join("replay");
    let r = replay_run(&live, &rep);
    for source in ["slam", "slam_single_camera", "slam_no_loops"] {
        let name = format!("estimate_{source}.tum");
        let a = std::fs::read(live.join(&name)).unwrap();
        let b = std::fs::read(rep.join(&name)).unwrap();
        assert!(a.len() > 1000, "{name}: {} bytes", a.len());
        assert!(a == b, "{name} differs between live run and replay");
        let replayed = r.report.sources.iter().find(|s| s.name == source).unwrap();
        let live_ate = outcome
            .report
            .sources
            .iter()
            .find(|s| s.name == source)
            .unwrap()
            .score
            .metric("ate_rmse_aligned_m");
        assert_eq!(
            replayed
                .score
                .as_ref()
                .unwrap()
                .metric("ate_rmse_aligned_m"),
            live_ate
        );
        assert_eq!(replayed.slam.get("tracking_losses"), Some(&0.0), "{source}");
    }
    assert_eq!(
        std::fs::read_to_string(live.join("loops.csv")).unwrap(),
        std::fs::read_to_string(rep.join("loops.csv")).unwrap()
    );
}

/// The first seconds of `scenarios/map-row.toml` at a lower resolution (the D435's
/// smallest depth mode) and rate.
fn short_map_row() -> LoadedScenario {
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/map-row.toml");
    let mut sc = LoadedScenario::load(&file).unwrap();
    sc.scenario.max_duration_s = 4.0;
    for c in &mut sc.scenario.sensors.cameras {
        c.width = Some(424);
        c.height = Some(240);
        c.rate_hz = Some(3.0);
    }
    // Written for the whole row: not what 4 s can show.
    sc.expectations.clear();
    sc
}

/// `vinebench replay` builds the recorded `[mapper]`'s maps from the recorded RGB-D
/// frames and estimates: the same files and scores as the live run; a field recording's
/// mapping file can ask for maps too (built and exported, not scored).
#[test]
fn replay_builds_the_recorded_maps_as_the_live_run_did() {
    let tmp = tempfile::tempdir().unwrap();
    let live = tmp.path().join("live");
    let outcome = run_into(&short_map_row(), &live);
    assert_eq!(outcome.report.maps.len(), 2);
    let rep = tmp.path().join("replay");
    let r = replay_run(&live, &rep);
    assert_eq!(r.report.maps.len(), 2);
    for (a, b) in outcome.report.maps.iter().zip(&r.report.maps) {
        assert_eq!(a.source, b.source);
        assert!(a.stats.frames_integrated >= 20, "{:?}", a.stats);
        assert_eq!(a.stats, b.stats);
        assert!(a.score.is_some());
        assert_eq!(a.score, b.score, "{}", a.source);
    }
    for f in ["map/map.ply", "map/mesh.ply", "map/gnss/map.ply"] {
        let a = std::fs::read(live.join(f)).unwrap();
        assert!(a.len() > 10_000, "{f}: {} bytes", a.len());
        assert!(a == std::fs::read(rep.join(f)).unwrap(), "{f} differs");
    }
    let md = std::fs::read_to_string(rep.join("report.md")).unwrap();
    assert!(md.contains("## Maps"), "{md}");

    // A mapping file over the same recording: topics by name, a map of the EIF.
    let cfg = tmp.path().join("topics.toml");
    let cams: Vec<String> = ["camera_center", "camera_left", "camera_right"]
        .iter()
        .flat_map(|c| {
            [
                "color/image_raw",
                "color/camera_info",
                "aligned_depth_to_color/image_raw",
            ]
            .map(|t| format!("\"/{c}/{t}\""))
        })
        .collect();
    std::fs::write(
        &cfg,
        format!(
            "[topics]\nimu = \"/imu/data\"\ngnss_fix = \"/gnss/fix\"\n\
             tracking_odom = \"/tracking_camera/odom/sample\"\ncameras = [{}]\n\
             [estimators]\nrun = [\"eif\"]\n\
             [mapper]\nenabled = true\nsources = [\"eif\"]\n[mapper.map]\nmesh = false\n",
            cams.join(", ")
        ),
    )
    .unwrap();
    let field = replay(
        &live.join("recording.mcap"),
        &ReplayOptions {
            config: Some(cfg.clone()),
            out_dir: Some(tmp.path().join("field")),
            ..ReplayOptions::default()
        },
    )
    .unwrap();
    assert_eq!(field.report.maps.len(), 1);
    let m = &field.report.maps[0];
    assert!(m.score.is_none());
    assert!(
        m.stats.frames_integrated >= 20 && m.stats.voxels > 10_000,
        "{:?}",
        m.stats
    );
    let ply =
        vinebench_onboard::mapper::ply::read_cloud(&tmp.path().join("field/map/map.ply")).unwrap();
    assert_eq!(ply.positions.len() as u64, m.stats.voxels);
    assert!(!tmp.path().join("field/map/mesh.ply").exists());

    // Without depth topics, a mapping file that asks for maps is told what is missing.
    std::fs::write(
        &cfg,
        "[topics]\nimu = \"/imu/data\"\ngnss_fix = \"/gnss/fix\"\n\
         cameras = [\"/camera_center/color/image_raw\"]\n\
         [estimators]\nrun = [\"eif\"]\n[mapper]\nenabled = true\nsources = [\"eif\"]\n",
    )
    .unwrap();
    let e = replay(
        &live.join("recording.mcap"),
        &ReplayOptions {
            config: Some(cfg.clone()),
            out_dir: Some(tmp.path().join("bad")),
            ..ReplayOptions::default()
        },
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("topics.toml") && e.contains("mapper.enabled") && e.contains("aligned_depth"),
        "{e}"
    );
}

#[test]
fn a_field_recording_replays_through_a_topic_mapping() {
    let tmp = tempfile::tempdir().unwrap();
    let live = tmp.path().join("live");
    live_run(&live);
    let map = tmp.path().join("topics.toml");
    std::fs::write(
        &map,
        "name = \"field\"\n\
         [topics]\nimu = \"/imu/data\"\ngnss_fix = \"/gnss/fix\"\n\
         tracking_odom = \"/tracking_camera/odom/sample\"\nwheel_odom = \"/odom/wheels\"\n\
         [estimators]\nrun = [\"eif\", \"gnss\"]\n",
    )
    .unwrap();
    let r = replay(
        &live.join("recording.mcap"),
        &ReplayOptions {
            config: Some(map.clone()),
            out_dir: Some(tmp.path().join("field")),
            ..ReplayOptions::default()
        },
    )
    .unwrap();
    let names: Vec<&str> = r.report.sources.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names, ["eif", "gnss"]);
    assert!(r.report.sources.iter().all(|s| s.poses > 10));
    assert_eq!(
        r.report.missing_topics,
        ["topics.wheel_odom = \"/odom/wheels\""]
    );
    assert!(
        r.report
            .skipped
            .keys()
            .any(|k| k.starts_with("/gnss/fix_velocity") && k.ends_with("topic not mapped")),
        "{:?}",
        r.report.skipped
    );
    // What the estimators did is said in report.md too, not only in report.json.
    let notes = r.report.estimator_notes();
    assert!(
        notes.iter().any(|n| n.starts_with("eif: initialized at")),
        "{notes:?}"
    );
    let md = std::fs::read_to_string(tmp.path().join("field/report.md")).unwrap();
    assert!(
        md.contains("## Estimator notes") && md.contains("- eif: initialized at"),
        "{md}"
    );

    // A topic of the wrong type is named, with what was expected.
    std::fs::write(&map, "[topics]\nimu = \"/gnss/fix\"\n").unwrap();
    let e = replay(
        &live.join("recording.mcap"),
        &ReplayOptions {
            config: Some(map.clone()),
            out_dir: Some(tmp.path().join("bad")),
            ..ReplayOptions::default()
        },
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("topics.imu") && e.contains("NavSatFix") && e.contains("sensor_msgs/Imu"),
        "{e}"
    );
}

#[test]
fn extrinsics_from_the_mapping_file_replay_as_the_recorded_tf_static() {
    // A robot without /tf_static: its extrinsics in `[[static_transforms]]` (here the
    // recorded ones written out exactly) give the same estimates, bit for bit.
    let tmp = tempfile::tempdir().unwrap();
    let live = tmp.path().join("live");
    live_run(&live);
    let mut tf: Vec<TransformStamped> = Vec::new();
    reader::scan_file(&live.join("recording.mcap"), |c, m| {
        if c.topic == "/tf_static" {
            tf.extend(ros::decode_tf(m.data).unwrap());
        }
    })
    .unwrap();
    assert!(tf.len() > 3);
    let topics = "name = \"field\"\n[topics]\nimu = \"/imu/data\"\ngnss_fix = \"/gnss/fix\"\n\
                  tracking_odom = \"/tracking_camera/odom/sample\"\n";
    let mut from_file = format!("{topics}tf_static = \"/robot_has_none\"\n");
    for t in &tf {
        let (p, q) = (
            t.parent_from_child.translation.vector,
            t.parent_from_child.rotation.coords,
        );
        from_file.push_str(&format!(
            "[[static_transforms]]\nparent = \"/{}\"\nchild = \"{}\"\nxyz = [{:?}, {:?}, {:?}]\n\
             quaternion = [{:?}, {:?}, {:?}, {:?}]\n",
            t.parent.as_str(),
            t.child.as_str(),
            p.x,
            p.y,
            p.z,
            q.x,
            q.y,
            q.z,
            q.w
        ));
    }
    let mut outs = Vec::new();
    for (name, text) in [("recorded", topics.to_string()), ("file", from_file)] {
        let map = tmp.path().join(format!("{name}.toml"));
        std::fs::write(&map, text).unwrap();
        let out = tmp.path().join(name);
        replay(
            &live.join("recording.mcap"),
            &ReplayOptions {
                config: Some(map),
                out_dir: Some(out.clone()),
                ..ReplayOptions::default()
            },
        )
        .unwrap_or_else(|e| panic!("{name}: {e}"));
        outs.push(out);
    }
    for f in ["estimate_eif.tum", "estimate_tracking_camera.tum"] {
        assert_eq!(
            std::fs::read(outs[0].join(f)).unwrap(),
            std::fs::read(outs[1].join(f)).unwrap(),
            "{f}"
        );
    }
}

#[cfg(unix)]
#[test]
fn ctrl_c_leaves_a_finalized_recording() {
    use std::process::Command;
    use std::time::{Duration, Instant};
    let tmp = tempfile::tempdir().unwrap();
    // The full default loop (rapier): several seconds, long enough to interrupt.
    let scenario = tmp.path().join("long.toml");
    std::fs::write(&scenario, "name = \"interrupted\"\n").unwrap();
    let out = tmp.path().join("run");
    let mut child = Command::new(env!("CARGO_BIN_EXE_vinebench"))
        .args(["run", "--quiet", "--out"])
        .arg(&out)
        .arg(&scenario)
        .spawn()
        .unwrap();
    let rec = out.join("recording.mcap");
    let t0 = Instant::now();
    while !rec.exists() {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "no recording started"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(300));
    let killed = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130), "interrupted runs exit with 130");
    let bytes = std::fs::read(&rec).unwrap();
    let mut n = 0;
    let s = scan(&bytes, |_, _| n += 1).unwrap();
    assert!(s.damage.is_none(), "finalized: {:?}", s.damage);
    assert!(n > 100, "{n} messages");
    assert!(s.messages_per_topic.contains_key("/tf_static"));
    assert!(s.metadata.contains_key(vinebench::recording::META_SCENARIO));
    // The run did not complete: no report.
    assert!(!out.join("report.json").exists());
}

#[test]
fn excluded_topics_are_not_recorded_and_bad_patterns_name_the_key() {
    let tmp = tempfile::tempdir().unwrap();
    let toml = format!(
        "{SHORT}[recording]\nzstd_level = 3\nexclude_topics = [\"/wheel/odom\", \"/ground_truth/*\"]\n"
    );
    let sc = LoadedScenario::from_str(&toml, "excluded.toml").unwrap();
    let opts = RunOptions {
        out_dir: Some(tmp.path().to_path_buf()),
        progress: false,
        ..RunOptions::default()
    };
    run(&sc, &opts).unwrap();
    let bytes = std::fs::read(tmp.path().join("recording.mcap")).unwrap();
    let s = scan(&bytes, |_, _| {}).unwrap();
    assert!(s.damage.is_none());
    let topics: Vec<&String> = s.messages_per_topic.keys().collect();
    assert!(
        !topics
            .iter()
            .any(|t| *t == "/wheel/odom" || t.starts_with("/ground_truth/")),
        "{topics:?}"
    );
    for kept in [
        "/imu/data",
        "/gnss/fix",
        "/tf_static",
        "/tracking_camera/odom/sample",
    ] {
        assert!(
            s.messages_per_topic.contains_key(kept),
            "{kept} missing from {topics:?}"
        );
    }
    for (bad, key) in [
        ("exclude_topics = [\"imu\"]", "recording.exclude_topics[0]"),
        (
            "exclude_topics = [\"/a*b*\"]",
            "recording.exclude_topics[0]",
        ),
        ("zstd_level = 25", "recording.zstd_level"),
    ] {
        let err = LoadedScenario::from_str(&format!("{SHORT}[recording]\n{bad}\n"), "bad.toml")
            .expect_err(bad)
            .to_string();
        assert!(err.contains(key), "{bad}: {err}");
    }
}

#[test]
fn map_clouds_pack_rgb_as_pcl_does() {
    let positions = [[1.0f32, -2.0, 0.5], [0.25, 0.0, 3.0]];
    let colors = [[200u8, 100, 50], [0, 255, 1]];
    let grvi = [-0.5f32, 0.9];
    let m = PointCloud2Msg::xyz_rgb(
        Nanos(7),
        FrameId::new("world"),
        &positions,
        &colors,
        &[("grvi", &grvi)],
    );
    let names: Vec<(&str, u32)> = m
        .fields
        .iter()
        .map(|f| (f.name.as_str(), f.offset))
        .collect();
    assert_eq!(
        names,
        [("x", 0), ("y", 4), ("z", 8), ("rgb", 12), ("grvi", 16)]
    );
    assert_eq!((m.point_step, m.width, m.row_step), (20, 2, 40));
    // Back through CDR, then read the bytes as PCL would: rgb is a u32 0x00RRGGBB.
    let back = ros::decode_point_cloud2(&enc(|b| ros::encode_point_cloud2(&m, b))).unwrap();
    assert_eq!(back, m);
    for i in 0..2 {
        let p = &back.data[20 * i..20 * (i + 1)];
        let f = |o: usize| f32::from_le_bytes(p[o..o + 4].try_into().unwrap());
        assert_eq!([f(0), f(4), f(8)], positions[i]);
        let rgb = u32::from_le_bytes(p[12..16].try_into().unwrap());
        let [r, g, b] = colors[i];
        assert_eq!(
            rgb,
            (u32::from(r) << 16) | (u32::from(g) << 8) | u32::from(b)
        );
        assert_eq!(f(16), grvi[i]);
    }
}
