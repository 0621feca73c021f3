//! Single-source trajectories, as the seed paper's Table 1 compares them with the EIF.
//!
//! - [`GnssOnly`] (`gnss`): eq. (1) per valid fix: the body pose from the antenna
//!   position and the AHRS orientation interpolated (slerp) at the fix stamp.
//! - [`TrackingCameraOnly`] (`tracking_camera`): eq. (2): the tracking camera's own
//!   odometry carried into the world from one GNSS + AHRS anchor pose.

use super::so3::skew;
use super::{Estimator, EstimatorError, EstimatorStats};
use nalgebra::{Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion};
use std::collections::VecDeque;
use vinebench_msgs::geodesy::LocalEnu;
use vinebench_msgs::{
    FixStatus, FrameId, GnssFixMsg, Message, Nanos, OdometryMsg, PoseSample, StaticTransforms,
    Trajectory,
};

/// Two AHRS samples further apart than this are not interpolated between.
pub const MAX_AHRS_GAP: Nanos = Nanos::from_millis(500);
/// How long after its first message the tracking-camera source waits for a GNSS pose at
/// or after that message to interpolate its anchor; then it anchors on the last GNSS pose
/// before it.
pub const ANCHOR_MAX_WAIT: Nanos = Nanos::from_secs(1);

/// An AHRS reading: `world_from_imu` and its error covariance about the world axes.
#[derive(Copy, Clone, Debug, PartialEq)]
struct Ahrs {
    t: Nanos,
    q: UnitQuaternion<f64>,
    cov: Matrix3<f64>,
}

/// Eq. (1) with AHRS orientation, shared by both sources: turns valid fixes into body
/// poses once the AHRS orientation at the fix stamp is known.
#[derive(Clone, Debug)]
pub(super) struct GnssAhrsPoser {
    transforms: StaticTransforms,
    enu: LocalEnu,
    /// The IMU frame and `imu_from_body`.
    imu: Option<(FrameId, Isometry3<f64>)>,
    prev: Option<Ahrs>,
    last: Option<Ahrs>,
    pending: VecDeque<GnssFixMsg>,
}

impl GnssAhrsPoser {
    pub(super) fn new(transforms: StaticTransforms, enu: LocalEnu) -> GnssAhrsPoser {
        GnssAhrsPoser {
            transforms,
            enu,
            imu: None,
            prev: None,
            last: None,
            pending: VecDeque::new(),
        }
    }

    /// Feeds one message; appends body poses (and counts) as fixes become computable.
    pub(super) fn handle(
        &mut self,
        msg: &Message,
        stats: &mut EstimatorStats,
        out: &mut Vec<PoseSample>,
    ) {
        match msg {
            Message::Imu(m) => {
                let Some(q) = m.orientation else {
                    return;
                };
                match &self.imu {
                    Some((f, _)) if *f == m.frame_id => {}
                    Some(_) => {
                        stats.count_rejected("imu_frame_changed");
                        return;
                    }
                    None => match self.transforms.body_from(m.frame_id.as_str()) {
                        Some(body_from_imu) => {
                            self.imu = Some((m.frame_id.clone(), body_from_imu.inverse()));
                        }
                        None => {
                            stats.count_rejected("unknown_frame");
                            return;
                        }
                    },
                }
                if self.last.is_some_and(|l| l.t >= m.stamp) {
                    return;
                }
                self.prev = self.last;
                self.last = Some(Ahrs {
                    t: m.stamp,
                    q,
                    cov: m.orientation_covariance,
                });
                self.resolve(stats, out);
            }
            Message::GnssFix(m) => {
                if m.status == FixStatus::NoFix {
                    stats.count_rejected("gnss_no_fix");
                    return;
                }
                self.pending.push_back(m.clone());
                self.resolve(stats, out);
            }
            _ => {}
        }
    }

    /// Computes the poses of pending fixes whose stamp the AHRS has reached.
    fn resolve(&mut self, stats: &mut EstimatorStats, out: &mut Vec<PoseSample>) {
        let Some(last) = self.last else {
            return;
        };
        while let Some(fix) = self.pending.front() {
            if fix.stamp > last.t {
                break;
            }
            let ahrs = if fix.stamp == last.t {
                Some(last)
            } else {
                self.prev
                    .filter(|p| p.t <= fix.stamp && last.t - p.t <= MAX_AHRS_GAP)
                    .map(|p| interpolate(&p, &last, fix.stamp))
            };
            if let Some(fix) = self.pending.pop_front() {
                match ahrs.and_then(|a| self.pose(&fix, &a)) {
                    Some(pose) => {
                        stats.count_used("gnss_fix");
                        out.push(pose);
                    }
                    None => stats.count_rejected("no_orientation"),
                }
            }
        }
    }

    /// Eq. (1): `world_from_body` from the antenna position and the AHRS orientation,
    /// with covariance (position error of the body origin, world-axis rotation error).
    fn pose(&self, fix: &GnssFixMsg, ahrs: &Ahrs) -> Option<PoseSample> {
        let (_, imu_from_body) = self.imu.as_ref()?;
        let body_from_antenna = self.transforms.body_from(fix.frame_id.as_str())?;
        let rot = ahrs.q * imu_from_body.rotation;
        let t_ba = body_from_antenna.translation.vector;
        let p_ant = self.enu.enu_from_geodetic(&fix.position);
        let lever = rot * t_ba;
        let p_body = p_ant - lever;
        // p_body_true = p_ant + n − Exp(e)·lever ≈ p_body + n + [lever]× e.
        let a = skew(&lever);
        let mut cov = Matrix6::zeros();
        cov.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(fix.position_covariance + a * ahrs.cov * a.transpose()));
        cov.fixed_view_mut::<3, 3>(0, 3).copy_from(&(a * ahrs.cov));
        cov.fixed_view_mut::<3, 3>(3, 0)
            .copy_from(&(a * ahrs.cov).transpose());
        cov.fixed_view_mut::<3, 3>(3, 3).copy_from(&ahrs.cov);
        let world_from_body = Isometry3::from_parts(Translation3::from(p_body), rot);
        let finite = p_body.iter().chain(cov.iter()).all(|c| c.is_finite());
        finite.then_some(PoseSample {
            stamp: fix.stamp,
            world_from_body,
            covariance: Some(Box::new(cov)),
        })
    }

    /// Fixes still waiting for an AHRS sample at or after their stamp.
    fn drop_pending(&mut self, stats: &mut EstimatorStats) {
        while self.pending.pop_front().is_some() {
            stats.count_rejected("no_orientation");
        }
    }
}

/// The AHRS reading at `t` between `a` and `b`: slerp of the orientation, linear
/// interpolation of the covariance.
fn interpolate(a: &Ahrs, b: &Ahrs, t: Nanos) -> Ahrs {
    let s = if b.t > a.t {
        (t - a.t).as_nanos() as f64 / (b.t - a.t).as_nanos() as f64
    } else {
        0.0
    };
    Ahrs {
        t,
        q: a.q.try_slerp(&b.q, s, 1e-12).unwrap_or(a.q),
        cov: a.cov + (b.cov - a.cov) * s,
    }
}

/// GNSS position with AHRS orientation, per valid fix (source name `gnss`).
#[derive(Clone, Debug)]
pub struct GnssOnly {
    poser: GnssAhrsPoser,
    stats: EstimatorStats,
    trajectory: Trajectory,
    scratch: Vec<PoseSample>,
}

impl GnssOnly {
    /// A GNSS-only source. Errors when the static transforms have no body frame.
    pub fn new(transforms: StaticTransforms, enu: LocalEnu) -> Result<GnssOnly, EstimatorError> {
        super::require_body_frame(&transforms, "gnss")?;
        Ok(GnssOnly {
            poser: GnssAhrsPoser::new(transforms, enu),
            stats: EstimatorStats::default(),
            trajectory: Trajectory::new(),
            scratch: Vec::new(),
        })
    }

    /// The output trajectory, consumed.
    pub fn into_trajectory(self) -> Trajectory {
        self.trajectory
    }
}

impl Estimator for GnssOnly {
    fn name(&self) -> &'static str {
        "gnss"
    }
    fn handle(&mut self, msg: &Message) {
        self.poser.handle(msg, &mut self.stats, &mut self.scratch);
        for pose in self.scratch.drain(..) {
            if !self.trajectory.push(pose) {
                self.stats.count_rejected("duplicate_stamp");
            }
        }
    }
    fn finish(&mut self) {
        self.poser.drop_pending(&mut self.stats);
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

/// `world_from_body(t) = anchor · odom_from_cam(t) · cam_from_body` with
/// `anchor = world_from_body₀ · body_from_cam · odom_from_cam(t₀)⁻¹`.
#[derive(Clone, Debug)]
struct Anchor {
    child: FrameId,
    left: Isometry3<f64>,
    cam_from_body: Isometry3<f64>,
}

/// The tracking camera's odometry mapped into the world by eq. (2) (source name
/// `tracking_camera`).
///
/// `world_from_body₀` is the GNSS + AHRS pose (as [`GnssOnly`] computes it) at `t₀`, the
/// first tracking-camera message at or after the first valid fix, interpolated between
/// the GNSS poses around `t₀` (what a user does to put the track on the map). Messages
/// before `t₀` are counted as `before_anchor`. No covariance (the odometry's drift is
/// unbounded).
#[derive(Clone, Debug)]
pub struct TrackingCameraOnly {
    poser: GnssAhrsPoser,
    gnss_poses: Vec<PoseSample>,
    first_fix: Option<Nanos>,
    /// The last tracking message before the first fix was seen (it may share its stamp).
    before_fix: Option<OdometryMsg>,
    waiting: Vec<OdometryMsg>,
    anchor: Option<Anchor>,
    transforms: StaticTransforms,
    stats: EstimatorStats,
    trajectory: Trajectory,
}

impl TrackingCameraOnly {
    /// A tracking-camera-only source. Errors when the static transforms have no body
    /// frame.
    pub fn new(
        transforms: StaticTransforms,
        enu: LocalEnu,
    ) -> Result<TrackingCameraOnly, EstimatorError> {
        super::require_body_frame(&transforms, "tracking_camera")?;
        Ok(TrackingCameraOnly {
            poser: GnssAhrsPoser::new(transforms.clone(), enu),
            gnss_poses: Vec::new(),
            first_fix: None,
            before_fix: None,
            waiting: Vec::new(),
            anchor: None,
            transforms,
            stats: EstimatorStats::default(),
            trajectory: Trajectory::new(),
        })
    }

    /// The output trajectory, consumed.
    pub fn into_trajectory(self) -> Trajectory {
        self.trajectory
    }

    fn emit(&mut self, m: &OdometryMsg) {
        let Some(anchor) = &self.anchor else {
            return;
        };
        if m.child_frame_id != anchor.child {
            self.stats.count_rejected("child_frame_changed");
            return;
        }
        let world_from_body = anchor.left * m.pose * anchor.cam_from_body;
        let pushed = self.trajectory.push(PoseSample {
            stamp: m.stamp,
            world_from_body,
            covariance: None,
        });
        if pushed {
            self.stats.count_used("tracking_odom");
        } else {
            self.stats.count_rejected("duplicate_stamp");
        }
    }

    /// Anchors on the GNSS pose at the first waiting message's stamp, if it can be had:
    /// interpolated between GNSS poses around it, or (when `force` or no later pose came
    /// within [`ANCHOR_MAX_WAIT`]) the last GNSS pose before it.
    fn try_anchor(&mut self, now: Nanos, force: bool) {
        let Some(first) = self.waiting.first() else {
            return;
        };
        let t0 = first.stamp;
        let before = self.gnss_poses.iter().rev().find(|p| p.stamp <= t0);
        let after = self.gnss_poses.iter().find(|p| p.stamp >= t0);
        let world_from_body0 = match (before, after) {
            (Some(a), Some(b)) => {
                let mut tr = Trajectory::new();
                tr.push(a.clone());
                tr.push(b.clone());
                tr.interpolate(t0)
            }
            (Some(a), None) if force || now - t0 > ANCHOR_MAX_WAIT => {
                self.stats.notes.push(format!(
                    "anchored at {t0} on the GNSS pose of {} (no later fix to interpolate)",
                    a.stamp
                ));
                Some(a.world_from_body)
            }
            _ => None,
        };
        let Some(world_from_body0) = world_from_body0 else {
            if force {
                for _ in self.waiting.drain(..) {
                    self.stats.count_rejected("no_anchor");
                }
            }
            return;
        };
        let Some(body_from_cam) = self.transforms.body_from(first.child_frame_id.as_str()) else {
            for _ in self.waiting.drain(..) {
                self.stats.count_rejected("unknown_frame");
            }
            return;
        };
        self.anchor = Some(Anchor {
            child: first.child_frame_id.clone(),
            left: world_from_body0 * body_from_cam * first.pose.inverse(),
            cam_from_body: body_from_cam.inverse(),
        });
        self.gnss_poses.clear();
        for m in std::mem::take(&mut self.waiting) {
            self.emit(&m);
        }
    }
}

impl Estimator for TrackingCameraOnly {
    fn name(&self) -> &'static str {
        "tracking_camera"
    }

    fn handle(&mut self, msg: &Message) {
        if self.anchor.is_none() {
            let mut scratch = Vec::new();
            let mut poser_stats = EstimatorStats::default();
            self.poser.handle(msg, &mut poser_stats, &mut scratch);
            self.gnss_poses.extend(scratch);
            if self.first_fix.is_none()
                && let Message::GnssFix(f) = msg
                && f.status != FixStatus::NoFix
            {
                self.first_fix = Some(f.stamp);
                if let Some(m) = self.before_fix.take() {
                    if m.stamp == f.stamp {
                        self.waiting.push(m);
                    } else {
                        self.stats.count_rejected("before_anchor");
                    }
                }
            }
        }
        if let Message::TrackingOdom(m) = msg {
            if self.anchor.is_some() {
                self.emit(m);
            } else if self.first_fix.is_some() {
                self.waiting.push(m.clone());
            } else {
                if self.before_fix.replace(m.clone()).is_some() {
                    self.stats.count_rejected("before_anchor");
                }
                return;
            }
        }
        if self.anchor.is_none() {
            self.try_anchor(msg.stamp(), false);
        }
    }

    fn finish(&mut self) {
        if self.before_fix.take().is_some() {
            self.stats.count_rejected("before_anchor");
        }
        if self.anchor.is_none() {
            self.try_anchor(Nanos(i64::MAX), true);
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
    use super::super::synthetic::{self, Circle, Line, Noise, Setup};
    use super::*;
    use nalgebra::{Matrix3, Vector3};
    use std::f64::consts::FRAC_PI_2;
    use vinebench_msgs::ImuMsg;
    use vinebench_msgs::geodesy::Geodetic;

    fn imu(t: Nanos, q: UnitQuaternion<f64>, cov: Matrix3<f64>) -> Message {
        Message::Imu(ImuMsg {
            stamp: t,
            frame_id: FrameId::new("imu"),
            orientation: Some(q),
            orientation_covariance: cov,
            angular_velocity: Vector3::zeros(),
            angular_velocity_covariance: Matrix3::zeros(),
            linear_acceleration: Vector3::zeros(),
            linear_acceleration_covariance: Matrix3::zeros(),
        })
    }

    fn fix(t: Nanos, position: Geodetic, cov: Matrix3<f64>) -> Message {
        Message::GnssFix(GnssFixMsg {
            stamp: t,
            frame_id: FrameId::new("antenna"),
            status: FixStatus::RtkFixed,
            position,
            position_covariance: cov,
        })
    }

    /// Closed form: the body lies on its side (rolled +90° about east) and the antenna is
    /// 1 m above the body origin along body z, so with heading ψ the antenna is at
    /// R_z(ψ)·(0, −1, 0) = (sin ψ, −cos ψ, 0) from the body origin. The IMU is mounted
    /// yawed 90° in the body, and the AHRS turns from ψ = 0 to 0.4 rad between two
    /// samples around the fix: at the middle ψ = 0.2, so a fix at (10, 20, 3) puts the
    /// body at (10 − sin 0.2, 20 + cos 0.2, 3) with orientation R_z(0.2)·R_x(90°).
    #[test]
    fn gnss_only_applies_the_lever_arm() {
        let mut tf = StaticTransforms::new("base_link");
        let body_from_imu = Isometry3::from_parts(
            Translation3::new(0.3, 0.1, 0.2),
            UnitQuaternion::from_euler_angles(0.0, 0.0, FRAC_PI_2),
        );
        tf.insert("imu", body_from_imu);
        tf.insert(
            "antenna",
            Isometry3::from_parts(Translation3::new(0.0, 0.0, 1.0), UnitQuaternion::identity()),
        );
        let enu = synthetic::origin();
        let tilt = UnitQuaternion::from_euler_angles(FRAC_PI_2, 0.0, 0.0);
        let yaw = |a: f64| UnitQuaternion::from_euler_angles(0.0, 0.0, a);
        let sigma: f64 = 0.01;
        let ahrs_cov = Matrix3::from_diagonal(&Vector3::new(sigma * sigma, 0.0, 0.0));
        let mut g = GnssOnly::new(tf, enu.clone()).unwrap();
        let t0 = synthetic::T0;
        let p_fix = enu.geodetic_from_enu(&Vector3::new(10.0, 20.0, 3.0));
        g.handle(&imu(t0, yaw(0.0) * tilt * body_from_imu.rotation, ahrs_cov));
        g.handle(&fix(t0 + Nanos(50), p_fix, Matrix3::zeros()));
        assert!(
            g.trajectory().is_empty(),
            "waits for the AHRS after the fix"
        );
        g.handle(&imu(
            t0 + Nanos(100),
            yaw(0.4) * tilt * body_from_imu.rotation,
            ahrs_cov,
        ));
        let s = &g.trajectory().samples[0];
        assert_eq!(s.stamp, t0 + Nanos(50));
        let expected_p = Vector3::new(10.0 - 0.2f64.sin(), 20.0 + 0.2f64.cos(), 3.0);
        assert!((s.world_from_body.translation.vector - expected_p).norm() < 1e-6);
        assert!(s.world_from_body.rotation.angle_to(&(yaw(0.2) * tilt)) < 1e-9);
        // A rotation error e about east turns the lever (sin ψ, −cos ψ, 0) into
        // (sin ψ, −cos ψ, −e·cos ψ); the body origin is the fix minus the lever, so
        // δz = +e·cos ψ: var(z) = cos²ψ σ², cov(z, e_x) = cos ψ σ², var(e_x) = σ².
        let c = *s.covariance.as_deref().unwrap();
        let cp = 0.2f64.cos();
        let mut expected = Matrix6::zeros();
        expected[(2, 2)] = cp * cp * sigma * sigma;
        expected[(2, 3)] = cp * sigma * sigma;
        expected[(3, 2)] = cp * sigma * sigma;
        expected[(3, 3)] = sigma * sigma;
        assert!((c - expected).amax() < 1e-9 * sigma * sigma, "{c}");
        g.handle(&Message::GnssFix(GnssFixMsg {
            stamp: t0 + Nanos(200),
            frame_id: FrameId::new("antenna"),
            status: FixStatus::NoFix,
            position: Geodetic {
                lat_deg: f64::NAN,
                lon_deg: f64::NAN,
                alt_m: f64::NAN,
            },
            position_covariance: Matrix3::zeros(),
        }));
        g.handle(&fix(t0 + Nanos(300), p_fix, Matrix3::zeros()));
        g.finish();
        let st = g.stats();
        assert_eq!(st.used["gnss_fix"], 1);
        assert_eq!(st.rejected["gnss_no_fix"], 1);
        assert_eq!(
            st.rejected["no_orientation"], 1,
            "the last fix had no AHRS after it"
        );
        assert_eq!(g.trajectory().len(), 1);
    }

    fn run<E: Estimator>(mut e: E, msgs: &[Message]) -> E {
        for m in msgs {
            e.handle(m);
        }
        e.finish();
        e
    }

    /// A perfect tracking camera (and perfect GNSS/AHRS for the anchor) reproduces the
    /// truth exactly on a circle; the anchor is the first tracking message, which shares
    /// the first fix's stamp.
    #[test]
    fn tracking_camera_only_is_exact_with_a_perfect_camera() {
        let motion = Circle {
            center: Vector3::new(2.0, -7.0, 0.0),
            radius: 5.0,
            speed: 1.5,
        };
        let msgs = synthetic::in_stamp_order(synthetic::generate(
            &motion,
            &Setup::new(20.0, Noise::none(), 31),
        ));
        let tc = run(
            TrackingCameraOnly::new(synthetic::transforms(), synthetic::origin()).unwrap(),
            &msgs,
        );
        assert_eq!(tc.trajectory().len(), 601);
        let (mp, mr) = synthetic::max_error(tc.trajectory(), &motion);
        assert!(mp < 1e-6 && mr < 1e-9, "{mp} {mr}");
        assert!(
            tc.trajectory()
                .samples
                .iter()
                .all(|s| s.covariance.is_none())
        );
        let g = run(
            GnssOnly::new(synthetic::transforms(), synthetic::origin()).unwrap(),
            &msgs,
        );
        assert_eq!(g.trajectory().len(), 201);
        let (mp, mr) = synthetic::max_error(g.trajectory(), &motion);
        assert!(mp < 1e-6 && mr < 1e-9, "{mp} {mr}");
    }

    /// When the first valid fix is not at a tracking stamp, the anchor is the GNSS pose
    /// interpolated at the next tracking message (exact on a straight line), and earlier
    /// tracking messages are counted as before the anchor.
    #[test]
    fn tracking_camera_anchor_is_interpolated() {
        let motion = Line {
            start: Isometry3::from_parts(
                Translation3::new(1.0, 2.0, 0.3),
                UnitQuaternion::from_euler_angles(0.05, -0.02, 0.9),
            ),
            v: Vector3::new(0.7, 0.9, 0.01),
        };
        let mut setup = Setup::new(10.0, Noise::none(), 32);
        setup.tracking_hz = 29.0; // off the GNSS grid
        setup.outage = Some((0.0, 0.25)); // first valid fix at 0.3 s
        let msgs = synthetic::in_stamp_order(synthetic::generate(&motion, &setup));
        let tc = run(
            TrackingCameraOnly::new(synthetic::transforms(), synthetic::origin()).unwrap(),
            &msgs,
        );
        let first = tc.trajectory().samples[0].stamp;
        // Tracking stamps k/29 s: k = 9 (0.3103 s) is the first at or after 0.3 s.
        assert_eq!(
            first,
            synthetic::T0 + Nanos((9.0f64 * 1e9 / 29.0).round() as i64)
        );
        assert_eq!(tc.stats().rejected["before_anchor"], 9);
        let (mp, mr) = synthetic::max_error(tc.trajectory(), &motion);
        assert!(mp < 1e-6 && mr < 1e-9, "{mp} {mr}");
    }
}
