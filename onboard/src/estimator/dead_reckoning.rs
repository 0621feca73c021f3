//! Dead reckoning (`dead_reckoning`): wheel speed turned into the world by the IMU's
//! orientation, as robot_localization's `odom`-frame filter gives a robot without GNSS.
//!
//! Each wheel-odometry message gives the velocity of its moving frame `o` in `o`
//! (`linear_velocity`; a skid-steer's lateral component is 0). It is carried into the
//! body frame by the static `body_from_o` rotation and into the world by the AHRS
//! orientation at the message's stamp (slerp between the IMU samples around it), and the
//! position is integrated with the trapezoid rule between consecutive messages:
//! `p_k = p_{k−1} + ½(R_{k−1}v_{k−1} + R_k v_k)·dt`. The orientation of each pose is the
//! AHRS's (`world_from_imu · imu_from_body`). Nothing else corrects it: its error grows
//! with the distance (wheel slip, the IMU's heading error), which is what it is for, a
//! GNSS-free baseline for the EIF.
//!
//! **Start.** The source needs no GNSS: its first pose is the GNSS + AHRS pose of eq. (1)
//! when a valid fix comes within [`ANCHOR_MAX_WAIT`] of the first wheel message (then it
//! is drawn on the map where the robot is), else the world origin with the AHRS
//! orientation (a note says so; compare it with the aligned metrics). Wheel messages
//! before the start are counted as `before_anchor`. No covariance (unbounded drift).

use super::single_source::{ANCHOR_MAX_WAIT, GnssAhrsPoser, MAX_AHRS_GAP};
use super::{Estimator, EstimatorError, EstimatorStats};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use std::collections::VecDeque;
use vinebench_msgs::geodesy::LocalEnu;
use vinebench_msgs::{
    FrameId, Message, Nanos, OdometryMsg, PoseSample, StaticTransforms, Trajectory,
};

/// How far back AHRS samples are kept: twice the longest a wheel message waits.
const AHRS_KEPT: Nanos = Nanos(2 * ANCHOR_MAX_WAIT.0);

/// The integrator's last step: stamp, body position in the world, world velocity of the
/// body.
#[derive(Copy, Clone, Debug)]
struct Step {
    t: Nanos,
    p: Vector3<f64>,
    v_world: Vector3<f64>,
}

/// Wheel odometry with AHRS heading, integrated (source name `dead_reckoning`).
#[derive(Clone, Debug)]
pub struct DeadReckoning {
    transforms: StaticTransforms,
    poser: GnssAhrsPoser,
    /// The IMU frame and `imu_from_body`.
    imu: Option<(FrameId, Isometry3<f64>)>,
    /// AHRS orientations (`world_from_imu`) with their stamps, the last
    /// [`AHRS_KEPT`] of them (the waiting wheel messages are within that).
    ahrs: VecDeque<(Nanos, UnitQuaternion<f64>)>,
    /// Wheel messages waiting for the AHRS to reach their stamp.
    waiting: Vec<OdometryMsg>,
    /// The first wheel message's stamp (for the anchor's wait).
    first_wheel: Option<Nanos>,
    /// The start position, once known.
    anchor: Option<(Nanos, Vector3<f64>)>,
    /// The wheel odometry's moving frame and `body_from_o`'s rotation.
    child: Option<(FrameId, UnitQuaternion<f64>)>,
    last: Option<Step>,
    stats: EstimatorStats,
    trajectory: Trajectory,
}

impl DeadReckoning {
    /// A dead-reckoning source. Errors when the static transforms have no body frame.
    pub fn new(
        transforms: StaticTransforms,
        enu: LocalEnu,
    ) -> Result<DeadReckoning, EstimatorError> {
        super::require_body_frame(&transforms, "dead_reckoning")?;
        Ok(DeadReckoning {
            poser: GnssAhrsPoser::new(transforms.clone(), enu),
            transforms,
            imu: None,
            ahrs: VecDeque::new(),
            waiting: Vec::new(),
            first_wheel: None,
            anchor: None,
            child: None,
            last: None,
            stats: EstimatorStats::default(),
            trajectory: Trajectory::new(),
        })
    }

    /// The output trajectory, consumed.
    pub fn into_trajectory(self) -> Trajectory {
        self.trajectory
    }

    /// `world_from_imu` at `t`, if the AHRS samples around it allow.
    fn orientation_at(&self, t: Nanos) -> Option<UnitQuaternion<f64>> {
        let i = self.ahrs.partition_point(|(s, _)| *s < t);
        let (tb, qb) = *self.ahrs.get(i)?;
        if tb == t {
            return Some(qb);
        }
        let (ta, qa) = *self.ahrs.get(i.checked_sub(1)?)?;
        if tb - ta > MAX_AHRS_GAP {
            return None;
        }
        let s = (t - ta).as_nanos() as f64 / (tb - ta).as_nanos().max(1) as f64;
        Some(qa.try_slerp(&qb, s, 1e-12).unwrap_or(qa))
    }

    fn on_imu(&mut self, m: &vinebench_msgs::ImuMsg) {
        let Some(q) = m.orientation else {
            return;
        };
        match &self.imu {
            Some((f, _)) if *f == m.frame_id => {}
            Some(_) => {
                self.stats.count_rejected("imu_frame_changed");
                return;
            }
            None => match self.transforms.body_from(m.frame_id.as_str()) {
                Some(body_from_imu) => {
                    self.imu = Some((m.frame_id.clone(), body_from_imu.inverse()))
                }
                None => {
                    self.stats.count_rejected("unknown_frame");
                    return;
                }
            },
        }
        if self.ahrs.back().is_some_and(|(t, _)| m.stamp <= *t) {
            return;
        }
        self.ahrs.push_back((m.stamp, q));
        while self
            .ahrs
            .front()
            .is_some_and(|(t, _)| m.stamp - *t > AHRS_KEPT)
        {
            self.ahrs.pop_front();
        }
        self.drain(false);
    }

    /// Integrates the waiting wheel messages the AHRS has reached (all of them, dropping
    /// what cannot be had, when `force`).
    fn drain(&mut self, force: bool) {
        if self.anchor.is_none() {
            return;
        }
        let reached = self.ahrs.back().map(|(t, _)| *t);
        let waiting = std::mem::take(&mut self.waiting);
        let mut keep = Vec::new();
        for m in waiting {
            if !keep.is_empty() || reached.is_none_or(|t| m.stamp > t) {
                if force {
                    self.stats.count_rejected("no_orientation");
                } else {
                    keep.push(m);
                }
                continue;
            }
            self.integrate(&m);
        }
        self.waiting = keep;
    }

    fn integrate(&mut self, m: &OdometryMsg) {
        let Some((_, imu_from_body)) = self.imu.clone() else {
            self.stats.count_rejected("no_orientation");
            return;
        };
        let body_from_o = match &self.child {
            Some((f, r)) if *f == m.child_frame_id => *r,
            Some(_) => {
                self.stats.count_rejected("child_frame_changed");
                return;
            }
            None => match self.transforms.body_from(m.child_frame_id.as_str()) {
                Some(iso) => {
                    self.child = Some((m.child_frame_id.clone(), iso.rotation));
                    iso.rotation
                }
                None => {
                    self.stats.count_rejected("unknown_frame");
                    return;
                }
            },
        };
        let Some(world_from_imu) = self.orientation_at(m.stamp) else {
            self.stats.count_rejected("no_orientation");
            return;
        };
        let world_from_body_rot = world_from_imu * imu_from_body.rotation;
        let v_world = world_from_body_rot * (body_from_o * m.linear_velocity);
        let p = match (self.last, self.anchor) {
            (Some(prev), _) => {
                let dt = (m.stamp - prev.t).as_secs_f64();
                prev.p + (prev.v_world + v_world) * (0.5 * dt)
            }
            // The first step: from the anchor's stamp with this message's velocity.
            (None, Some((ta, pa))) => pa + v_world * (m.stamp - ta).as_secs_f64(),
            (None, None) => return,
        };
        if !p.iter().all(|c| c.is_finite()) {
            self.stats.count_rejected("numerical_skip");
            return;
        }
        self.last = Some(Step {
            t: m.stamp,
            p,
            v_world,
        });
        let pushed = self.trajectory.push(PoseSample {
            stamp: m.stamp,
            world_from_body: Isometry3::from_parts(Translation3::from(p), world_from_body_rot),
            covariance: None,
        });
        if pushed {
            self.stats.count_used("wheel_odom");
        } else {
            self.stats.count_rejected("duplicate_stamp");
        }
    }

    /// Starts at the GNSS pose if one came in time, else (after [`ANCHOR_MAX_WAIT`] of
    /// wheel messages, or when `force`) at the world origin.
    fn try_anchor(&mut self, gnss: Option<&PoseSample>, now: Nanos, force: bool) {
        if self.anchor.is_some() {
            return;
        }
        if let Some(pose) = gnss {
            // Wheel messages older than the anchor cannot be placed.
            let before = self.waiting.iter().filter(|m| m.stamp < pose.stamp).count();
            self.waiting.retain(|m| m.stamp >= pose.stamp);
            for _ in 0..before {
                self.stats.count_rejected("before_anchor");
            }
            self.anchor = Some((pose.stamp, pose.world_from_body.translation.vector));
            self.stats.notes.push(format!(
                "started at {} on the GNSS pose (eq. 1)",
                pose.stamp
            ));
            return;
        }
        let Some(first) = self.first_wheel else {
            return;
        };
        if force || now - first > ANCHOR_MAX_WAIT {
            self.anchor = Some((first, Vector3::zeros()));
            self.stats.notes.push(format!(
                "no valid GNSS fix within {} s of the first wheel message: started at the world \
                 origin at {first} (compare with the aligned metrics)",
                ANCHOR_MAX_WAIT.as_secs_f64()
            ));
        }
    }
}

impl Estimator for DeadReckoning {
    fn name(&self) -> &'static str {
        "dead_reckoning"
    }

    fn handle(&mut self, msg: &Message) {
        if self.anchor.is_none() {
            let mut poses = Vec::new();
            let mut scratch = EstimatorStats::default();
            self.poser.handle(msg, &mut scratch, &mut poses);
            if let Some(p) = poses.first() {
                self.try_anchor(Some(p), msg.stamp(), false);
            }
        }
        match msg {
            Message::Imu(m) => self.on_imu(m),
            Message::WheelOdom(m) => {
                self.first_wheel.get_or_insert(m.stamp);
                self.waiting.push(m.clone());
                // Before the start at most ANCHOR_MAX_WAIT of messages wait (then it
                // starts at the origin); after it, a message the AHRS has not reached
                // within ANCHOR_MAX_WAIT (an IMU without orientation) is given up.
                self.try_anchor(None, m.stamp, false);
                self.drain(false);
                if self.anchor.is_some() {
                    let stale = self
                        .waiting
                        .iter()
                        .take_while(|w| m.stamp - w.stamp > ANCHOR_MAX_WAIT)
                        .count();
                    for _ in self.waiting.drain(..stale) {
                        self.stats.count_rejected("no_orientation");
                    }
                }
            }
            _ => {}
        }
        if self.anchor.is_none() {
            self.try_anchor(None, msg.stamp(), false);
        }
    }

    fn finish(&mut self) {
        if self.anchor.is_none() && self.first_wheel.is_some() {
            self.try_anchor(None, Nanos(i64::MAX), true);
        }
        self.drain(true);
        if self.first_wheel.is_none() {
            self.stats
                .notes
                .push("no wheel odometry: nothing to integrate (map topics.wheel_odom)".into());
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
    use super::*;
    use nalgebra::{Matrix3, Matrix6};
    use vinebench_msgs::geodesy::Geodetic;
    use vinebench_msgs::{FixStatus, GnssFixMsg, ImuMsg};

    fn enu() -> LocalEnu {
        LocalEnu::new(Geodetic {
            lat_deg: 40.45,
            lon_deg: 17.9,
            alt_m: 50.0,
        })
    }

    fn transforms() -> StaticTransforms {
        let mut t = StaticTransforms::new("base_link");
        t.insert("imu", Isometry3::translation(0.1, 0.0, 0.3));
        t.insert("gps", Isometry3::translation(-0.2, 0.0, 0.8));
        t
    }

    fn imu(t: Nanos, yaw: f64) -> Message {
        Message::Imu(ImuMsg {
            stamp: t,
            frame_id: FrameId::new("imu"),
            orientation: Some(UnitQuaternion::from_euler_angles(0.0, 0.0, yaw)),
            orientation_covariance: Matrix3::identity() * 1e-4,
            angular_velocity: Vector3::zeros(),
            angular_velocity_covariance: Matrix3::identity() * 1e-6,
            linear_acceleration: Vector3::new(0.0, 0.0, 9.81),
            linear_acceleration_covariance: Matrix3::identity() * 1e-4,
        })
    }

    fn wheel(t: Nanos, vx: f64) -> Message {
        Message::WheelOdom(OdometryMsg {
            stamp: t,
            frame_id: FrameId::new("wheel_odom"),
            child_frame_id: FrameId::new("base_link"),
            pose: Isometry3::identity(),
            pose_covariance: Matrix6::identity(),
            linear_velocity: Vector3::new(vx, 0.0, 0.0),
            angular_velocity: Vector3::zeros(),
            twist_covariance: Matrix6::identity() * 1e-4,
        })
    }

    /// A circle of radius r at speed v (yaw rate v/r) starting at the origin heading
    /// east: the trapezoid integration of the exact heading follows the arc to second
    /// order in the step.
    fn circle(r: f64, v: f64, seconds: f64, with_fix: Option<Vector3<f64>>) -> DeadReckoning {
        let mut d = DeadReckoning::new(transforms(), enu()).unwrap();
        let dt = 0.01;
        let n = (seconds / dt) as i64;
        if let Some(p) = with_fix {
            d.handle(&imu(Nanos(0), 0.0));
            let fix = Message::GnssFix(GnssFixMsg {
                stamp: Nanos(0),
                frame_id: FrameId::new("gps"),
                status: FixStatus::RtkFixed,
                position: enu().geodetic_from_enu(&(p + Vector3::new(-0.2, 0.0, 0.8))),
                position_covariance: Matrix3::identity() * 1e-4,
            });
            d.handle(&fix);
        }
        for i in 0..=n {
            let t = i as f64 * dt;
            let stamp = Nanos::from_secs_f64(t);
            d.handle(&imu(stamp, v / r * t));
            if i % 2 == 0 {
                d.handle(&wheel(stamp, v));
            }
        }
        d.finish();
        d
    }

    #[test]
    fn integrates_a_circle_from_the_world_origin_without_gnss() {
        let (r, v) = (5.0, 1.0);
        let d = circle(r, v, 20.0, None);
        let last = d.trajectory.samples.last().unwrap();
        let t = last.stamp.as_secs_f64();
        let th = v / r * t;
        // Closed form: (r sin θ, r(1 − cos θ)).
        let want = Vector3::new(r * th.sin(), r * (1.0 - th.cos()), 0.0);
        let err = (last.world_from_body.translation.vector - want).norm();
        assert!(err < 2e-3, "end error {err} m");
        assert!(
            d.stats.notes.iter().any(|n| n.contains("world origin")),
            "{:?}",
            d.stats.notes
        );
        assert_eq!(
            d.stats.used["wheel_odom"],
            d.trajectory.samples.len() as u64
        );
    }

    #[test]
    fn starts_on_the_gnss_pose_when_a_fix_comes() {
        let start = Vector3::new(30.0, -12.0, 1.5);
        let d = circle(5.0, 1.0, 5.0, Some(start));
        let first = &d.trajectory.samples[0];
        assert!((first.world_from_body.translation.vector - start).norm() < 1e-6);
        let last = d.trajectory.samples.last().unwrap();
        let th = 0.2 * last.stamp.as_secs_f64();
        let want = start + Vector3::new(5.0 * th.sin(), 5.0 * (1.0 - th.cos()), 0.0);
        assert!((last.world_from_body.translation.vector - want).norm() < 2e-3);
    }
}
