//! The estimation stage: validation → re-ordering → fan-out to the estimators.

use super::dead_reckoning::DeadReckoning;
use super::eif::Eif;
use super::params::{EstimatorKind, EstimatorsParams};
use super::reorder::ReorderBuffer;
use super::single_source::{GnssOnly, TrackingCameraOnly};
use super::{Estimator, EstimatorError, EstimatorStats};
use std::collections::BTreeMap;
use vinebench_msgs::geodesy::LocalEnu;
use vinebench_msgs::{Message, Nanos, PoseSample, StaticTransforms, TimedMessage, Trajectory};

/// Counters of the stage itself (before any estimator sees a message).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StageStats {
    /// Messages pushed.
    pub received: u64,
    /// Messages released to the estimators.
    pub released: u64,
    /// Messages dropped because they came later than the re-ordering window allows, by
    /// topic.
    pub late: BTreeMap<String, u64>,
    /// Messages dropped as invalid, by topic then field (`/imu/data` →
    /// `linear_acceleration`). A message whose frame is not in the static transforms
    /// counts under field `frame_id` (`child_frame_id` for odometry).
    pub invalid: BTreeMap<String, BTreeMap<String, u64>>,
    /// Notes (the first unknown frame of each topic, by name).
    pub notes: Vec<String>,
}

impl StageStats {
    /// All late messages.
    pub fn late_total(&self) -> u64 {
        self.late.values().sum()
    }
    /// All invalid messages.
    pub fn invalid_total(&self) -> u64 {
        self.invalid.values().flat_map(|m| m.values()).sum()
    }
    /// Invalid messages keyed `"<topic> <field>"` (as reports list them).
    pub fn invalid_by_topic_field(&self) -> BTreeMap<String, u64> {
        self.invalid
            .iter()
            .flat_map(|(topic, fields)| {
                fields
                    .iter()
                    .map(move |(field, n)| (format!("{topic} {field}"), *n))
            })
            .collect()
    }
    fn count_invalid(&mut self, topic: &str, field: &str) -> u64 {
        let c = self
            .invalid
            .entry(topic.to_string())
            .or_default()
            .entry(field.to_string())
            .or_default();
        *c += 1;
        *c
    }
}

/// The trajectory of one estimator.
#[derive(Clone, Debug, PartialEq)]
pub struct EstimatorOutput {
    /// Source name (`eif`, `gnss`, `tracking_camera`).
    pub name: &'static str,
    /// `world_from_body` poses (body = the static transforms' body frame).
    pub trajectory: Trajectory,
    /// Input counters.
    pub stats: EstimatorStats,
}

/// The frames of the sensors whose messages the estimators use, as the runner knows
/// them from the scenario (`sensors.<name>.frame`), for [`EstimatorSet::check_sensor_frames`].
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct SensorFrames<'a> {
    /// The IMU frame (`/imu/data` `frame_id`).
    pub imu: &'a str,
    /// The GNSS antenna frame (`/gnss/fix` `frame_id`).
    pub gnss_antenna: &'a str,
    /// The tracking camera frame (odometry `child_frame_id`).
    pub tracking_camera: &'a str,
}

/// Everything the stage produces.
#[derive(Clone, Debug, PartialEq)]
pub struct EstimationOutput {
    /// One entry per estimator, in the order of `[estimators] run`.
    pub estimators: Vec<EstimatorOutput>,
    /// Stage counters.
    pub stage: StageStats,
}

/// One estimator of the set (an enum, so the fan-out needs no `dyn`).
#[derive(Clone, Debug)]
enum AnyEstimator {
    Eif(Box<Eif>),
    Gnss(Box<GnssOnly>),
    TrackingCamera(Box<TrackingCameraOnly>),
    DeadReckoning(Box<DeadReckoning>),
}

impl AnyEstimator {
    fn as_dyn(&mut self) -> &mut dyn Estimator {
        match self {
            AnyEstimator::Eif(e) => e.as_mut(),
            AnyEstimator::Gnss(e) => e.as_mut(),
            AnyEstimator::TrackingCamera(e) => e.as_mut(),
            AnyEstimator::DeadReckoning(e) => e.as_mut(),
        }
    }
    fn handle(&mut self, msg: &Message) {
        match self {
            AnyEstimator::Eif(e) => e.handle(msg),
            AnyEstimator::Gnss(e) => e.handle(msg),
            AnyEstimator::TrackingCamera(e) => e.handle(msg),
            AnyEstimator::DeadReckoning(e) => e.handle(msg),
        }
    }
    fn into_output(mut self) -> EstimatorOutput {
        let e = self.as_dyn();
        e.finish();
        let name = e.name();
        let stats = e.stats();
        let trajectory = match self {
            AnyEstimator::Eif(e) => e.into_trajectory(),
            AnyEstimator::Gnss(e) => e.into_trajectory(),
            AnyEstimator::TrackingCamera(e) => e.into_trajectory(),
            AnyEstimator::DeadReckoning(e) => e.into_trajectory(),
        };
        EstimatorOutput {
            name,
            trajectory,
            stats,
        }
    }
}

/// The estimation stage the runner calls: validate, re-order by stamp, fan out.
///
/// ```
/// use vinebench_onboard::estimator::{EstimatorSet, EstimatorsParams};
/// use vinebench_msgs::{geodesy::{Geodetic, LocalEnu}, StaticTransforms};
/// let enu = LocalEnu::new(Geodetic { lat_deg: 40.4545, lon_deg: 17.9085, alt_m: 55.0 });
/// let set = EstimatorSet::new(&EstimatorsParams::default(), StaticTransforms::new("base_link"), enu)
///     .expect("valid defaults");
/// let out = set.finish();
/// assert_eq!(out.estimators.len(), 3); // eif, gnss, tracking_camera
/// assert!(out.estimators.iter().all(|e| e.trajectory.is_empty()));
/// ```
#[derive(Debug)]
pub struct EstimatorSet {
    reorder: ReorderBuffer,
    estimators: Vec<AnyEstimator>,
    transforms: StaticTransforms,
    stage: StageStats,
    run: Vec<EstimatorKind>,
    eif_uses_tracking: bool,
}

impl EstimatorSet {
    /// Builds the estimators of `params.run` (in that order). `static_transforms` are the
    /// robot's `body_from_<frame>` (from `/tf_static`); `enu` is the world frame's
    /// geodetic origin (the map origin a user chooses).
    ///
    /// Errors: a parameter out of range, a kind listed twice in `run`, or static
    /// transforms without a body frame. Sensor frames are named by the messages
    /// themselves (`frame_id`), so they are checked per message: a message whose frame is
    /// unknown is counted as invalid (field `frame_id`) and a note names the frame.
    pub fn new(
        params: &EstimatorsParams,
        static_transforms: StaticTransforms,
        enu: LocalEnu,
    ) -> Result<EstimatorSet, EstimatorError> {
        let w = params.reorder_window_ms;
        if !(w.is_finite() && w >= 0.0) {
            return Err(EstimatorError::invalid(
                "estimators.reorder_window_ms",
                "a finite number >= 0",
                w,
            ));
        }
        let mut estimators = Vec::with_capacity(params.run.len());
        for (i, kind) in params.run.iter().enumerate() {
            if params.run[..i].contains(kind) {
                return Err(EstimatorError::invalid(
                    "estimators.run",
                    "each estimator at most once",
                    format!("`{}` twice", kind.name()),
                ));
            }
            let t = static_transforms.clone();
            estimators.push(match kind {
                EstimatorKind::Eif => {
                    AnyEstimator::Eif(Box::new(Eif::new(&params.eif, t, enu.clone())?))
                }
                EstimatorKind::Gnss => AnyEstimator::Gnss(Box::new(GnssOnly::new(t, enu.clone())?)),
                EstimatorKind::TrackingCamera => {
                    AnyEstimator::TrackingCamera(Box::new(TrackingCameraOnly::new(t, enu.clone())?))
                }
                EstimatorKind::DeadReckoning => {
                    AnyEstimator::DeadReckoning(Box::new(DeadReckoning::new(t, enu.clone())?))
                }
            });
        }
        Ok(EstimatorSet {
            reorder: ReorderBuffer::new(Nanos::from_secs_f64(w * 1e-3)),
            estimators,
            transforms: static_transforms,
            stage: StageStats::default(),
            run: params.run.clone(),
            eif_uses_tracking: params.eif.use_tracking_camera,
        })
    }

    /// Checks that the static transforms hold every sensor frame the estimators of `run`
    /// need (all need the IMU and the GNSS antenna; the tracking-camera source, and the
    /// EIF when it uses the tracking camera, need the camera). The error names the first
    /// missing frame and the estimator that needs it. Optional: without this check,
    /// messages from unknown frames are dropped and counted by [`EstimatorSet::push`].
    pub fn check_sensor_frames(&self, frames: &SensorFrames<'_>) -> Result<(), EstimatorError> {
        for kind in &self.run {
            let tracking = match kind {
                EstimatorKind::Eif => self.eif_uses_tracking,
                EstimatorKind::Gnss => false,
                EstimatorKind::TrackingCamera => true,
                EstimatorKind::DeadReckoning => false,
            };
            let needed = [
                Some(frames.imu),
                Some(frames.gnss_antenna),
                tracking.then_some(frames.tracking_camera),
            ];
            for frame in needed.into_iter().flatten() {
                if self.transforms.body_from(frame).is_none() {
                    return Err(EstimatorError::MissingFrame {
                        frame: frame.to_string(),
                        estimator: kind.name(),
                    });
                }
            }
        }
        Ok(())
    }

    /// Takes one message in arrival order. Invalid messages (NaN fields, bad covariances,
    /// unknown frames) and messages too late for the re-ordering window are dropped and
    /// counted; never panics.
    pub fn push(&mut self, tm: &TimedMessage) {
        self.stage.received += 1;
        if let Err(e) = tm.msg.validate() {
            self.stage.count_invalid(&e.topic, e.field);
            return;
        }
        if let Some((field, frame)) = checked_frame(&tm.msg)
            && self.transforms.body_from(frame).is_none()
        {
            let topic = tm.msg.topic();
            if self.stage.count_invalid(topic, field) == 1 {
                self.stage.notes.push(format!(
                    "{topic}: {field} `{frame}` is not in the static transforms; \
                     its messages are dropped"
                ));
            }
            return;
        }
        let EstimatorSet {
            reorder,
            estimators,
            stage,
            ..
        } = self;
        let accepted = reorder.push(tm, |m| {
            stage.released += 1;
            for e in estimators.iter_mut() {
                e.handle(&m);
            }
        });
        if !accepted {
            stage.late = reorder.late().clone();
        }
    }

    /// The trajectory so far of estimator `kind`, if it runs: what the messages released
    /// so far have produced (a mapper places camera frames with it as the run goes on).
    pub fn trajectory(&self, kind: EstimatorKind) -> Option<&Trajectory> {
        let i = self.run.iter().position(|k| *k == kind)?;
        Some(match self.estimators.get(i)? {
            AnyEstimator::Eif(e) => e.trajectory(),
            AnyEstimator::Gnss(e) => e.trajectory(),
            AnyEstimator::TrackingCamera(e) => e.trajectory(),
            AnyEstimator::DeadReckoning(e) => e.trajectory(),
        })
    }

    /// The names of the estimators, in run order (as [`EstimatorSet::finish`] returns
    /// their outputs).
    pub fn names(&self) -> Vec<&'static str> {
        self.estimators
            .iter()
            .map(|e| match e {
                AnyEstimator::Eif(e) => e.name(),
                AnyEstimator::Gnss(e) => e.name(),
                AnyEstimator::TrackingCamera(e) => e.name(),
                AnyEstimator::DeadReckoning(e) => e.name(),
            })
            .collect()
    }

    /// Hands every pose the estimators have output so far, except each one's latest, to
    /// `sink(index in run order, pose)` and forgets them: a runner that streams the
    /// trajectories to disk calls this as the run goes, so they are not held here. The
    /// latest pose stays (stamps keep increasing); [`EstimatorSet::finish`] returns the
    /// rest. A consumer of [`EstimatorSet::trajectory`] (the mapper) must not drain.
    pub fn drain_poses(&mut self, mut sink: impl FnMut(usize, PoseSample)) {
        for (i, e) in self.estimators.iter_mut().enumerate() {
            let t = match e {
                AnyEstimator::Eif(e) => e.trajectory_mut(),
                AnyEstimator::Gnss(e) => e.trajectory_mut(),
                AnyEstimator::TrackingCamera(e) => e.trajectory_mut(),
                AnyEstimator::DeadReckoning(e) => e.trajectory_mut(),
            };
            for s in t.drain_settled() {
                sink(i, s);
            }
        }
    }

    /// The stage counters so far.
    pub fn stage_stats(&self) -> &StageStats {
        &self.stage
    }

    /// Releases the messages still held, finishes every estimator and returns their
    /// trajectories (in `run` order) with the stage counters.
    pub fn finish(self) -> EstimationOutput {
        let EstimatorSet {
            mut reorder,
            mut estimators,
            mut stage,
            ..
        } = self;
        reorder.flush(|m| {
            stage.released += 1;
            for e in estimators.iter_mut() {
                e.handle(&m);
            }
        });
        stage.late = reorder.late().clone();
        EstimationOutput {
            estimators: estimators
                .into_iter()
                .map(AnyEstimator::into_output)
                .collect(),
            stage,
        }
    }
}

/// The frame a message must have in the static transforms, with the field naming it.
/// Wheel odometry is used by no estimator and is not checked.
fn checked_frame(msg: &Message) -> Option<(&'static str, &str)> {
    match msg {
        Message::Imu(m) => Some(("frame_id", m.frame_id.as_str())),
        Message::GnssFix(m) => Some(("frame_id", m.frame_id.as_str())),
        Message::GnssVelocity(m) => Some(("frame_id", m.frame_id.as_str())),
        Message::TrackingOdom(m) => Some(("child_frame_id", m.child_frame_id.as_str())),
        Message::GnssHeading(m) => Some(("/gnss/heading", m.frame_id.as_str())),
        Message::WheelOdom(_)
        | Message::Image(_)
        | Message::CameraInfo(_)
        | Message::GnssSky(_) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::super::synthetic::{self, Circle, Noise, Setup};
    use super::*;
    use nalgebra::Vector3;
    use vinebench_msgs::FrameId;

    fn params() -> EstimatorsParams {
        let mut p = EstimatorsParams::default();
        p.eif.gravity_mps2 = synthetic::GRAVITY;
        // The synthetic gyros do not sense the Earth's rotation.
        p.eif.earth_rate = false;
        p
    }

    /// Noise-free circle in arrival order (IMU 2 ms, GNSS 60 ms, tracking 5 ms latency:
    /// stamps go backwards), with a NaN IMU sample, a NaN RTK fix, a fix from an unknown
    /// frame and an IMU sample delivered 1 s late: the bad ones are counted, nothing
    /// panics, no NaN comes out, and all three sources follow the truth.
    #[test]
    fn stage_reorders_validates_and_fans_out() {
        let motion = Circle {
            center: Vector3::new(-3.0, 2.0, 0.5),
            radius: 5.0,
            speed: 1.0,
        };
        let mut msgs = synthetic::generate(&motion, &Setup::new(30.0, Noise::none(), 21));
        // Arrival order really differs from stamp order.
        assert!(msgs.windows(2).any(|w| w[1].msg.stamp() < w[0].msg.stamp()));
        let t = |s: f64| synthetic::T0 + Nanos::from_secs_f64(s);
        let find = |msgs: &[TimedMessage], topic: &str, stamp: Nanos| {
            msgs.iter()
                .position(|m| m.msg.topic() == topic && m.msg.stamp() == stamp)
                .unwrap()
        };
        // An IMU sample with a NaN, next to the good one.
        let i = find(&msgs, "/imu/data", t(5.0));
        let mut bad = msgs[i].clone();
        if let Message::Imu(m) = &mut bad.msg {
            m.linear_acceleration.x = f64::NAN;
        }
        msgs.insert(i + 1, bad);
        // An RTK fix with a NaN position.
        let i = find(&msgs, "/gnss/fix", t(6.0));
        let mut bad = msgs[i].clone();
        if let Message::GnssFix(m) = &mut bad.msg {
            m.position.lat_deg = f64::NAN;
        }
        msgs[i] = bad;
        // A fix from a frame the robot does not have.
        let i = find(&msgs, "/gnss/fix", t(7.0));
        if let Message::GnssFix(m) = &mut msgs[i].msg {
            m.frame_id = FrameId::new("mystery_antenna");
        }
        // An IMU sample that arrives 1 s after its stamp (the window is 150 ms).
        let i = find(&msgs, "/imu/data", t(8.0));
        let mut late = msgs.remove(i);
        late.arrival = late.msg.stamp() + Nanos::from_secs(1);
        let j = msgs.iter().position(|m| m.arrival > late.arrival).unwrap();
        msgs.insert(j, late);

        let mut set =
            EstimatorSet::new(&params(), synthetic::transforms(), synthetic::origin()).unwrap();
        for m in &msgs {
            set.push(m);
        }
        let out = set.finish();
        let st = &out.stage;
        assert_eq!(st.received, msgs.len() as u64);
        assert_eq!(st.invalid["/imu/data"]["linear_acceleration"], 1);
        assert_eq!(st.invalid["/gnss/fix"]["position"], 1);
        assert_eq!(st.invalid["/gnss/fix"]["frame_id"], 1);
        assert!(st.notes[0].contains("mystery_antenna"), "{:?}", st.notes);
        assert_eq!(st.late.get("/imu/data"), Some(&1));
        assert_eq!(st.late_total(), 1);
        assert_eq!(
            st.released + st.invalid_total() + st.late_total(),
            st.received
        );

        let names: Vec<_> = out.estimators.iter().map(|e| e.name).collect();
        assert_eq!(names, vec!["eif", "gnss", "tracking_camera"]);
        for e in &out.estimators {
            assert!(!e.trajectory.is_empty(), "{}", e.name);
            for s in &e.trajectory.samples {
                assert!(
                    s.world_from_body
                        .translation
                        .vector
                        .iter()
                        .all(|c| c.is_finite())
                );
                assert!(
                    s.covariance
                        .iter()
                        .flat_map(|c| c.iter())
                        .all(|c| c.is_finite())
                );
            }
            let (mp, mr) = synthetic::max_error(&e.trajectory, &motion);
            assert!(mp < 1e-4 && mr < 1e-5, "{}: {mp} m {mr} rad", e.name);
        }
        let eif = &out.estimators[0];
        assert_eq!(eif.trajectory.len(), 1501, "50 Hz over 30 s");
        // 301 fixes minus the NaN one and the unknown-frame one; the EIF started from the
        // first (counted as before_init) and corrected with the others.
        assert_eq!(eif.stats.used["gnss_fix"], 298);
        assert_eq!(out.estimators[1].trajectory.len(), 299);
        // Same input, same output, bit for bit.
        let mut again =
            EstimatorSet::new(&params(), synthetic::transforms(), synthetic::origin()).unwrap();
        for m in &msgs {
            again.push(m);
        }
        assert_eq!(again.finish(), out);
    }

    #[test]
    fn construction_errors_name_the_problem() {
        let mut p = params();
        p.run = vec![EstimatorKind::Gnss, EstimatorKind::Gnss];
        let err = EstimatorSet::new(&p, synthetic::transforms(), synthetic::origin()).unwrap_err();
        assert!(err.to_string().contains("estimators.run"), "{err}");
        let mut p = params();
        p.reorder_window_ms = -1.0;
        let err = EstimatorSet::new(&p, synthetic::transforms(), synthetic::origin()).unwrap_err();
        assert!(err.to_string().contains("reorder_window_ms"), "{err}");
        let err = EstimatorSet::new(&params(), StaticTransforms::default(), synthetic::origin())
            .unwrap_err();
        assert!(
            matches!(
                err,
                EstimatorError::MissingFrame {
                    estimator: "eif",
                    ..
                }
            ),
            "{err}"
        );
        // Sensor frames, checked against the static transforms, name the missing frame.
        let set =
            EstimatorSet::new(&params(), synthetic::transforms(), synthetic::origin()).unwrap();
        let mut frames = SensorFrames {
            imu: synthetic::IMU_FRAME,
            gnss_antenna: synthetic::ANTENNA_FRAME,
            tracking_camera: synthetic::CAMERA_FRAME,
        };
        assert_eq!(set.check_sensor_frames(&frames), Ok(()));
        frames.tracking_camera = "t265_pose_frame";
        let err = set.check_sensor_frames(&frames).unwrap_err();
        assert!(err.to_string().contains("`t265_pose_frame`"), "{err}");
        assert!(err.to_string().contains("`eif`"), "{err}");
        let mut p = params();
        p.run = vec![EstimatorKind::Gnss];
        let gnss_only =
            EstimatorSet::new(&p, synthetic::transforms(), synthetic::origin()).unwrap();
        assert_eq!(
            gnss_only.check_sensor_frames(&frames),
            Ok(()),
            "gnss needs no camera"
        );
        // Only the listed estimators run, in the listed order.
        let mut p = params();
        p.run = vec![EstimatorKind::TrackingCamera, EstimatorKind::Eif];
        let set = EstimatorSet::new(&p, synthetic::transforms(), synthetic::origin()).unwrap();
        let names: Vec<_> = set.finish().estimators.iter().map(|e| e.name).collect();
        assert_eq!(names, vec!["tracking_camera", "eif"]);
    }
}
