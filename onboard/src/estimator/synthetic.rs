//! Synthetic message streams for the estimator tests: closed-form motions, sensors
//! written from the same frame conventions the messages document, seeded noise.

#![cfg(test)]

use nalgebra::{Isometry3, Matrix3, Matrix6, Point3, Translation3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use vinebench_msgs::geodesy::{Geodetic, LocalEnu};
use vinebench_msgs::{
    FixStatus, FrameId, GnssFixMsg, GnssVelocityMsg, ImuMsg, Message, Nanos, OdometryMsg,
    StaticTransforms, TimedMessage,
};

/// Start of the synthetic runs (2021-09-15T09:00:00Z).
pub const T0: Nanos = Nanos(1_631_696_400_000_000_000);
pub const GRAVITY: f64 = 9.80665;
pub const IMU_FRAME: &str = "imu_link";
pub const ANTENNA_FRAME: &str = "gnss_antenna";
pub const CAMERA_FRAME: &str = "tracking_camera";

pub fn origin() -> LocalEnu {
    LocalEnu::new(Geodetic {
        lat_deg: 40.4545,
        lon_deg: 17.9085,
        alt_m: 55.0,
    })
}

/// A robot whose sensor frames are rotated and offset, so that every frame
/// transformation in the estimators is exercised.
pub fn transforms() -> StaticTransforms {
    let mut t = StaticTransforms::new("base_link");
    t.insert(
        IMU_FRAME,
        Isometry3::from_parts(
            Translation3::new(0.26, 0.02, 0.77),
            UnitQuaternion::from_euler_angles(
                std::f64::consts::PI,
                0.0,
                std::f64::consts::FRAC_PI_2,
            ),
        ),
    );
    t.insert(
        ANTENNA_FRAME,
        Isometry3::from_parts(
            Translation3::new(0.22, 0.0, 1.12),
            UnitQuaternion::identity(),
        ),
    );
    t.insert(
        CAMERA_FRAME,
        Isometry3::from_parts(
            Translation3::new(0.41, 0.0, 0.74),
            UnitQuaternion::from_euler_angles(0.0, 0.2, 0.0),
        ),
    );
    t
}

/// [`transforms`] with the IMU moved to the body origin (its orientation kept): a body
/// that turns about a vertical axis through its origin then leaves the IMU in place.
pub fn transforms_imu_at_origin() -> StaticTransforms {
    let mut t = transforms();
    let rotation = t.body_from(IMU_FRAME).expect("test frame").rotation;
    t.insert(
        IMU_FRAME,
        Isometry3::from_parts(Translation3::identity(), rotation),
    );
    t
}

/// A noise-free IMU message in [`IMU_FRAME`]: angular velocity `w` (rad/s) and specific
/// force `f` (m/s²) in the IMU frame, an optional AHRS `world_from_imu`; the covariances
/// are those [`Noise::mti300_rtk`] reports.
pub fn imu_msg(
    stamp: Nanos,
    w: Vector3<f64>,
    f: Vector3<f64>,
    orientation: Option<UnitQuaternion<f64>>,
) -> ImuMsg {
    let rep = Noise::mti300_rtk();
    ImuMsg {
        stamp,
        frame_id: FrameId::new(IMU_FRAME),
        orientation,
        orientation_covariance: diag(&rep.ahrs),
        angular_velocity: w,
        angular_velocity_covariance: Matrix3::identity() * rep.gyro_per_sample.powi(2),
        linear_acceleration: f,
        linear_acceleration_covariance: Matrix3::identity() * rep.accel_per_sample.powi(2),
    }
}

/// A noise-free RTK fix in [`ANTENNA_FRAME`] at the ENU position `p_ant` (m), with the
/// covariance [`Noise::mti300_rtk`] reports.
pub fn gnss_fix(stamp: Nanos, p_ant: &Vector3<f64>) -> GnssFixMsg {
    let rep = Noise::mti300_rtk();
    GnssFixMsg {
        stamp,
        frame_id: FrameId::new(ANTENNA_FRAME),
        status: FixStatus::RtkFixed,
        position: origin().geodetic_from_enu(p_ant),
        position_covariance: diag(&Vector3::new(rep.gnss_h, rep.gnss_h, rep.gnss_v)),
    }
}

/// Body kinematics at one instant, world frame.
#[derive(Clone, Debug)]
pub struct Kin {
    pub world_from_body: Isometry3<f64>,
    /// Velocity of the body origin, m/s.
    pub v: Vector3<f64>,
    /// Acceleration of the body origin, m/s².
    pub a: Vector3<f64>,
    /// Angular velocity, world frame, rad/s (constant in the motions here).
    pub w: Vector3<f64>,
}

/// A closed-form motion.
pub trait Motion {
    fn at(&self, t: f64) -> Kin;
}

/// At rest.
pub struct Still {
    pub pose: Isometry3<f64>,
}
impl Motion for Still {
    fn at(&self, _t: f64) -> Kin {
        Kin {
            world_from_body: self.pose,
            v: Vector3::zeros(),
            a: Vector3::zeros(),
            w: Vector3::zeros(),
        }
    }
}

/// Constant-speed circle, counterclockwise, body x along the velocity, level.
pub struct Circle {
    pub center: Vector3<f64>,
    pub radius: f64,
    pub speed: f64,
}
impl Motion for Circle {
    fn at(&self, t: f64) -> Kin {
        let om = self.speed / self.radius;
        let ang = om * t;
        let (s, c) = ang.sin_cos();
        let p = self.center + Vector3::new(c, s, 0.0) * self.radius;
        Kin {
            world_from_body: Isometry3::from_parts(
                Translation3::from(p),
                UnitQuaternion::from_euler_angles(0.0, 0.0, ang + std::f64::consts::FRAC_PI_2),
            ),
            v: Vector3::new(-s, c, 0.0) * self.speed,
            a: Vector3::new(-c, -s, 0.0) * (self.speed * om),
            w: Vector3::new(0.0, 0.0, om),
        }
    }
}

/// Constant velocity along a line, constant orientation.
pub struct Line {
    pub start: Isometry3<f64>,
    pub v: Vector3<f64>,
}
impl Motion for Line {
    fn at(&self, t: f64) -> Kin {
        let mut pose = self.start;
        pose.translation.vector += self.v * t;
        Kin {
            world_from_body: pose,
            v: self.v,
            a: Vector3::zeros(),
            w: Vector3::zeros(),
        }
    }
}

/// Sensor noise (1σ, white) and rates.
#[derive(Clone, Debug)]
pub struct Noise {
    pub accel_per_sample: f64,
    pub gyro_per_sample: f64,
    /// AHRS error about world x, y, z, rad.
    pub ahrs: Vector3<f64>,
    pub gnss_h: f64,
    pub gnss_v: f64,
    pub gnss_vel: f64,
    pub track_pos: f64,
    pub track_rot: f64,
}

impl Noise {
    /// No noise; the covariances still report the `reported` noise.
    pub fn none() -> Noise {
        Noise {
            accel_per_sample: 0.0,
            gyro_per_sample: 0.0,
            ahrs: Vector3::zeros(),
            gnss_h: 0.0,
            gnss_v: 0.0,
            gnss_vel: 0.0,
            track_pos: 0.0,
            track_rot: 0.0,
        }
    }
    /// Xsens MTi-300 at 200 Hz (60 µg/√Hz, 0.01 °/s/√Hz; AHRS 0.2° roll/pitch, 1° yaw),
    /// RTK 1 cm horizontal / 2 cm vertical, GNSS velocity 3 cm/s, tracking-camera jitter
    /// 1 mm and 0.02°.
    pub fn mti300_rtk() -> Noise {
        let rate: f64 = 200.0;
        Noise {
            accel_per_sample: 60e-6 * GRAVITY * rate.sqrt(),
            gyro_per_sample: 0.01f64.to_radians() * rate.sqrt(),
            ahrs: Vector3::new(
                0.2f64.to_radians(),
                0.2f64.to_radians(),
                1.0f64.to_radians(),
            ),
            gnss_h: 0.01,
            gnss_v: 0.02,
            gnss_vel: 0.03,
            track_pos: 0.001,
            track_rot: 0.02f64.to_radians(),
        }
    }
}

/// What to generate.
#[derive(Clone, Debug)]
pub struct Setup {
    pub duration_s: f64,
    pub imu_hz: f64,
    pub gnss_hz: f64,
    pub tracking_hz: f64,
    /// Noise actually added.
    pub noise: Noise,
    /// Noise reported in the covariances.
    pub reported: Noise,
    /// GNSS outage `[start, end)`, seconds after T0: fixes are `NoFix`.
    pub outage: Option<(f64, f64)>,
    /// Correlation time of the GNSS position error (first-order Gauss-Markov), s; 0 =
    /// white.
    pub gnss_tau_s: f64,
    pub seed: u64,
    /// `odom_from_world` of the tracking camera's start frame.
    pub odom_from_world: Isometry3<f64>,
}

impl Setup {
    pub fn new(duration_s: f64, noise: Noise, seed: u64) -> Setup {
        Setup {
            duration_s,
            imu_hz: 200.0,
            gnss_hz: 10.0,
            tracking_hz: 30.0,
            reported: Noise::mti300_rtk(),
            noise,
            outage: None,
            gnss_tau_s: 0.0,
            seed,
            odom_from_world: Isometry3::from_parts(
                Translation3::new(3.0, -1.0, 0.5),
                UnitQuaternion::from_euler_angles(0.01, -0.02, 1.1),
            ),
        }
    }
}

fn gauss3(rng: &mut ChaCha8Rng, s: &Vector3<f64>) -> Vector3<f64> {
    let mut n = || -> f64 { StandardNormal.sample(rng) };
    Vector3::new(n() * s.x, n() * s.y, n() * s.z)
}

fn diag(s: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::from_diagonal(&s.component_mul(s))
}

/// Sensor outputs of a motion, as timed messages in arrival order (IMU latency 2 ms,
/// GNSS 60 ms, tracking camera 5 ms).
pub fn generate(motion: &dyn Motion, setup: &Setup) -> Vec<TimedMessage> {
    let tf = transforms();
    let enu = origin();
    let body_from_imu = tf.body_from(IMU_FRAME).expect("test frame");
    let body_from_ant = tf.body_from(ANTENNA_FRAME).expect("test frame");
    let body_from_cam = tf.body_from(CAMERA_FRAME).expect("test frame");
    let mut rng_imu = ChaCha8Rng::seed_from_u64(setup.seed);
    let mut rng_gnss = ChaCha8Rng::seed_from_u64(setup.seed ^ 0x9e37);
    let mut rng_cam = ChaCha8Rng::seed_from_u64(setup.seed ^ 0x51ed);
    let n = &setup.noise;
    let rep = &setup.reported;
    let mut out: Vec<TimedMessage> = Vec::new();
    let push = |out: &mut Vec<TimedMessage>, latency_ms: i64, msg: Message| {
        out.push(TimedMessage {
            arrival: msg.stamp() + Nanos::from_millis(latency_ms),
            msg,
        });
    };
    let stamps = |hz: f64| {
        let count = (setup.duration_s * hz).floor() as i64;
        (0..=count).map(move |k| Nanos((k as f64 * 1e9 / hz).round() as i64))
    };
    for dt in stamps(setup.imu_hz) {
        let k = motion.at(dt.as_secs_f64());
        let world_from_imu = k.world_from_body * body_from_imu;
        let r_wi = world_from_imu.rotation;
        let lever = k.world_from_body.rotation * body_from_imu.translation.vector;
        // Rigid body at constant angular rate: a_imu = a + ω × (ω × r).
        let a_imu = k.a + k.w.cross(&k.w.cross(&lever));
        let f = r_wi.inverse() * (a_imu + Vector3::new(0.0, 0.0, GRAVITY))
            + gauss3(&mut rng_imu, &Vector3::repeat(n.accel_per_sample));
        let w = r_wi.inverse() * k.w + gauss3(&mut rng_imu, &Vector3::repeat(n.gyro_per_sample));
        // AHRS: world_from_imu_true = Exp(e) · reported.
        let e = gauss3(&mut rng_imu, &n.ahrs);
        let q = UnitQuaternion::from_scaled_axis(-e) * r_wi;
        push(
            &mut out,
            2,
            Message::Imu(ImuMsg {
                stamp: T0 + dt,
                frame_id: FrameId::new(IMU_FRAME),
                orientation: Some(q),
                orientation_covariance: diag(&rep.ahrs),
                angular_velocity: w,
                angular_velocity_covariance: Matrix3::identity() * rep.gyro_per_sample.powi(2),
                linear_acceleration: f,
                linear_acceleration_covariance: Matrix3::identity() * rep.accel_per_sample.powi(2),
            }),
        );
    }
    let rho = if setup.gnss_tau_s > 0.0 {
        (-1.0 / (setup.gnss_hz * setup.gnss_tau_s)).exp()
    } else {
        0.0
    };
    let sig = Vector3::new(n.gnss_h, n.gnss_h, n.gnss_v);
    let mut gnss_err = gauss3(&mut rng_gnss, &sig);
    for dt in stamps(setup.gnss_hz) {
        let ts = dt.as_secs_f64();
        let k = motion.at(ts);
        let p_ant = k.world_from_body * Point3::from(body_from_ant.translation.vector);
        let lever = k.world_from_body.rotation * body_from_ant.translation.vector;
        let v_ant = k.v + k.w.cross(&lever);
        let rep_sig = Vector3::new(rep.gnss_h, rep.gnss_h, rep.gnss_v);
        let noisy = p_ant.coords + gnss_err;
        gnss_err = gnss_err * rho + gauss3(&mut rng_gnss, &sig) * (1.0 - rho * rho).sqrt();
        let in_outage = setup.outage.is_some_and(|(a, b)| ts >= a && ts < b);
        let (status, position) = if in_outage {
            (
                FixStatus::NoFix,
                Geodetic {
                    lat_deg: f64::NAN,
                    lon_deg: f64::NAN,
                    alt_m: f64::NAN,
                },
            )
        } else {
            (FixStatus::RtkFixed, enu.geodetic_from_enu(&noisy))
        };
        push(
            &mut out,
            60,
            Message::GnssFix(GnssFixMsg {
                stamp: T0 + dt,
                frame_id: FrameId::new(ANTENNA_FRAME),
                status,
                position,
                position_covariance: diag(&rep_sig),
            }),
        );
        if !in_outage {
            let vel = v_ant + gauss3(&mut rng_gnss, &Vector3::repeat(n.gnss_vel));
            push(
                &mut out,
                60,
                Message::GnssVelocity(GnssVelocityMsg {
                    stamp: T0 + dt,
                    frame_id: FrameId::new(ANTENNA_FRAME),
                    velocity_in_world: vel,
                    covariance: Matrix3::identity() * rep.gnss_vel.powi(2),
                }),
            );
        }
    }
    for dt in stamps(setup.tracking_hz) {
        let k = motion.at(dt.as_secs_f64());
        let odom_from_cam = setup.odom_from_world * k.world_from_body * body_from_cam;
        let dp = gauss3(&mut rng_cam, &Vector3::repeat(n.track_pos));
        let dr = gauss3(&mut rng_cam, &Vector3::repeat(n.track_rot));
        let pose = Isometry3::from_parts(
            Translation3::from(odom_from_cam.translation.vector + dp),
            UnitQuaternion::from_scaled_axis(dr) * odom_from_cam.rotation,
        );
        push(
            &mut out,
            5,
            Message::TrackingOdom(OdometryMsg {
                stamp: T0 + dt,
                frame_id: FrameId::new("tracking_odom"),
                child_frame_id: FrameId::new(CAMERA_FRAME),
                pose,
                pose_covariance: Matrix6::identity() * 1e-6,
                linear_velocity: Vector3::zeros(),
                angular_velocity: Vector3::zeros(),
                twist_covariance: Matrix6::identity() * 1e-6,
            }),
        );
    }
    // Arrival order; ties by stamp (a stable sort keeps generation order after that).
    out.sort_by_key(|m| (m.arrival, m.msg.stamp()));
    out
}

/// The same messages in stamp order (ties: IMU first, then GNSS, then tracking).
/// Largest position (m) and rotation (rad) error of a trajectory against `motion`.
pub fn max_error(traj: &vinebench_msgs::Trajectory, motion: &dyn Motion) -> (f64, f64) {
    traj.samples.iter().fold((0.0, 0.0), |(mp, mr), s| {
        let truth = motion.at((s.stamp - T0).as_secs_f64()).world_from_body;
        let dp = (s.world_from_body.translation.vector - truth.translation.vector).norm();
        let dr = s.world_from_body.rotation.angle_to(&truth.rotation);
        (f64::max(mp, dp), f64::max(mr, dr))
    })
}

pub fn in_stamp_order(mut msgs: Vec<TimedMessage>) -> Vec<Message> {
    let rank = |m: &Message| match m {
        Message::Imu(_) => 0,
        Message::GnssFix(_) => 1,
        Message::GnssVelocity(_) => 2,
        _ => 3,
    };
    msgs.sort_by_key(|m| (m.msg.stamp(), rank(&m.msg)));
    msgs.into_iter().map(|m| m.msg).collect()
}
