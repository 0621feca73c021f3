//! Tracking and local mapping of a multi-camera stereo rig (Kokas et al., sections III-A
//! to III-C; the structure of ORB-SLAM's `Tracking` and `LocalMapping`).
//!
//! Per rig frame (the primary camera's stereo pair and the latest pair of every other
//! camera, each with its own stamp):
//!
//! 1. **Prediction**: constant velocity from the last two tracked poses. A camera whose
//!    image is stamped `Δt` away from the frame's stamp enters with the extrinsic
//!    `Exp(ξ·Δt) · body_from_camera` (`ξ` the body-frame velocity), so free-running
//!    cameras share one pose unknown. Where a gyro measured the body's rotation over
//!    `Δt` ([`CameraInput::rotation_from_frame`]) that rotation replaces `ξ`'s: turns
//!    and chassis vibration change the angular rate within a frame interval by far more
//!    than a constant velocity allows. Between the BAs, and once after them, the
//!    translation velocity is re-estimated from this frame's own motion.
//! 2. **Projection search**: the local map's landmarks are projected into every camera;
//!    each is matched to the keypoint of the best Hamming distance among those in a
//!    window around the projection at the predicted pyramid level ±1 (the grid of
//!    [`super::grid`]). With fewer than `widen_below` matches the window doubles, up to
//!    `max_widenings` times.
//! 3. **Motion-only BA** over the matches of all cameras ([`super::motion_ba`]), then a
//!    second, narrow search from the optimized pose and a second BA.
//! 4. **Keyframes** when the tracked landmarks drop below `keyframe_ratio` of the
//!    reference keyframe's, when few near points are tracked while many are not, or after
//!    `keyframe_max_interval_s`. A keyframe adds observations to the matched landmarks,
//!    creates landmarks from its unmatched stereo points, culls the recent ones
//!    ([`Map::cull_recent`]: kept when seen by ≥ 3 keyframes) and runs local BA over the
//!    last `local_ba_keyframes` keyframes and their landmarks (eqs. 4-5,
//!    [`super::bundle`]).
//!
//! Fewer than `min_tracked` inliers is a **tracking loss**, recorded with its time. The
//! tracker then predicts with the last velocity; each following frame first tries the
//! local map again (recovery) and otherwise, as soon as it has `init_min_points` stereo
//! points, starts a new keyframe at the predicted pose (reinitialization). Frame poses are
//! kept relative to their reference keyframe, so later BA corrections reach every frame.

use super::bundle::{BaKeyFrame, BaLandmark, BaObservation, BundleConfig, bundle_adjust};
use super::frontend::StereoFrame;
use super::map::{KeyFrame, KeyFrameCamera, KeyPointRef, Map};
use super::motion_ba::{MotionBaConfig, Observation, RigCamera, optimize_pose};
use super::orb::{OrbConfig, hamming};
use super::{ConfigError, check};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector2, Vector3};
use serde::{Deserialize, Serialize};
use vinebench_msgs::Nanos;

/// Tracking and local-mapping settings (`[slam.tracking]`; every key optional).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackingConfig {
    /// Half-size of the projection-search window at level 0, px (scaled by the level).
    pub search_radius_px: f64,
    /// Fewer matches than this widen the window (the 60).
    pub widen_below: usize,
    /// How many times the window may double.
    pub max_widenings: usize,
    /// Window of the second search, from the optimized pose, px.
    pub refine_radius_px: f64,
    /// Largest Hamming distance of a match (ORB-SLAM's `TH_HIGH` is 100).
    pub hamming_threshold: u32,
    /// A match must be better than this fraction of the second-best candidate's distance.
    pub ratio: f64,
    /// Fewer inliers than this after motion-only BA is a tracking loss.
    pub min_tracked: usize,
    /// Stereo points a frame needs to start (or restart) a map.
    pub init_min_points: usize,
    /// Keyframes whose landmarks form the local map searched by projection.
    pub local_keyframes: usize,
    /// A keyframe when the inliers fall below this fraction of the reference keyframe's.
    pub keyframe_ratio: f64,
    /// A keyframe at least this often while tracking, s.
    pub keyframe_max_interval_s: f64,
    /// Keyframes optimized by local BA (older ones that share landmarks are held fixed).
    pub local_ba_keyframes: usize,
    /// Levenberg-Marquardt iterations of local BA per round.
    pub local_ba_iterations: usize,
}

impl Default for TrackingConfig {
    fn default() -> Self {
        TrackingConfig {
            search_radius_px: 6.0,
            widen_below: 60,
            max_widenings: 3,
            refine_radius_px: 3.0,
            hamming_threshold: 80,
            ratio: 0.9,
            min_tracked: 25,
            init_min_points: 100,
            local_keyframes: 10,
            keyframe_ratio: 0.75,
            keyframe_max_interval_s: 1.0,
            local_ba_keyframes: 7,
            local_ba_iterations: 10,
        }
    }
}

impl TrackingConfig {
    /// Checks every range.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let pos = |v: f64| v.is_finite() && v > 0.0;
        check(
            pos(self.search_radius_px),
            "tracking.search_radius_px must be positive",
        )?;
        check(
            pos(self.refine_radius_px),
            "tracking.refine_radius_px must be positive",
        )?;
        check(
            self.max_widenings <= 6,
            "tracking.max_widenings must be at most 6",
        )?;
        check(
            (1..=256).contains(&self.hamming_threshold),
            "tracking.hamming_threshold must be in [1, 256]",
        )?;
        check(
            self.ratio > 0.0 && self.ratio <= 1.0,
            "tracking.ratio must be in (0, 1]",
        )?;
        check(
            self.min_tracked >= 6,
            "tracking.min_tracked must be at least 6",
        )?;
        check(
            self.init_min_points >= self.min_tracked,
            "tracking.init_min_points must be at least tracking.min_tracked",
        )?;
        check(
            self.local_keyframes >= 1,
            "tracking.local_keyframes must be at least 1",
        )?;
        check(
            self.keyframe_ratio > 0.0 && self.keyframe_ratio <= 1.0,
            "tracking.keyframe_ratio must be in (0, 1]",
        )?;
        check(
            pos(self.keyframe_max_interval_s),
            "tracking.keyframe_max_interval_s must be positive",
        )?;
        check(
            self.local_ba_keyframes >= 2,
            "tracking.local_ba_keyframes must be at least 2",
        )?;
        check(
            (1..=100).contains(&self.local_ba_iterations),
            "tracking.local_ba_iterations must be in [1, 100]",
        )
    }
}

/// One camera of the rig as the tracker sees it.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackerCamera {
    /// Rectified left-image intrinsics and the URDF extrinsic.
    pub camera: RigCamera,
    /// Stereo baseline, m.
    pub baseline_m: f64,
}

/// One camera's stereo pair in a rig frame.
#[derive(Clone, Copy, Debug)]
pub struct CameraInput<'a> {
    /// Camera index in the rig.
    pub camera: usize,
    /// Exposure-centre stamp of the pair.
    pub stamp: Nanos,
    /// Its features.
    pub features: &'a StereoFrame,
    /// The body's rotation from the frame's stamp to this pair's,
    /// `body(frame stamp)_from_body(pair stamp)`, when a gyro measured it (`None`: the
    /// constant-velocity prediction is used).
    pub rotation_from_frame: Option<UnitQuaternion<f64>>,
}

/// What the tracker did with a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TrackingState {
    /// No map yet (too few stereo points so far).
    NotInitialized,
    /// Tracked against the map.
    Tracking,
    /// Tracking failed; the pose is a constant-velocity prediction.
    Lost,
}

/// The outcome of one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameResult {
    /// The frame's stamp.
    pub stamp: Nanos,
    /// What happened.
    pub state: TrackingState,
    /// The pose (tracked, or the start of a new map); `None` when lost or not started.
    pub world_from_body: Option<Isometry3<f64>>,
    /// Projection-search matches (all cameras).
    pub matches: usize,
    /// Inliers of motion-only BA.
    pub inliers: usize,
    /// A keyframe was inserted at this frame.
    pub keyframe: bool,
    /// The map was (re)started at this frame.
    pub initialized: bool,
}

/// A stretch of lost tracking.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TrackingLoss {
    /// The first frame that could not be tracked.
    pub start: Nanos,
    /// The frame that tracked again or restarted the map (`None`: still lost at the end).
    pub end: Option<Nanos>,
}

/// A tracked frame's pose, relative to its reference keyframe.
#[derive(Clone, Copy, Debug)]
struct FramePose {
    stamp: Nanos,
    keyframe: u32,
    keyframe_from_body: Isometry3<f64>,
}

/// A body-frame velocity: rotation vector and translation per second.
#[derive(Clone, Copy, Debug)]
struct Velocity {
    omega: Vector3<f64>,
    v: Vector3<f64>,
}

impl Velocity {
    /// `body(t)_from_body(t + dt)`.
    fn motion(&self, dt_s: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(self.v * dt_s),
            UnitQuaternion::from_scaled_axis(self.omega * dt_s),
        )
    }
}

/// Per camera slot of the current frame: keypoint → (landmark, Hamming distance).
type SlotMatches = Vec<Option<(u32, u32)>>;

/// A frame tracked against the local map.
struct Tracked {
    /// `world_from_body`.
    pose: Isometry3<f64>,
    /// The inlier matches per camera slot.
    matches: Vec<SlotMatches>,
    /// Their number.
    inliers: usize,
    /// The rig of the last motion-only BA (extrinsics shifted for the cameras' stamps).
    rig: Vec<RigCamera>,
}

/// Statistics of a tracker's run.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TrackerStats {
    /// Frames given to [`Tracker::track`].
    pub frames: usize,
    /// Frames tracked.
    pub tracked: usize,
    /// Keyframes inserted.
    pub keyframes: usize,
    /// Maps started (the first and every reinitialization).
    pub initializations: usize,
    /// Landmarks culled.
    pub culled: usize,
    /// Local BA runs.
    pub local_ba_runs: usize,
    /// Observations local BA rejected as outliers.
    pub local_ba_outliers: usize,
}

/// The tracker and local mapper (see the module docs).
#[derive(Clone, Debug)]
pub struct Tracker {
    cfg: TrackingConfig,
    /// Pyramid scale factor and levels of the features (the front-end's).
    scale_factor: f64,
    n_levels: usize,
    motion_cfg: MotionBaConfig,
    rig: Vec<TrackerCamera>,
    map: Map,
    state: TrackingState,
    last: Option<(Nanos, Isometry3<f64>)>,
    velocity: Option<Velocity>,
    ref_keyframe: u32,
    ref_inliers: usize,
    last_keyframe_stamp: Nanos,
    local_landmarks: Vec<u32>,
    recent_landmarks: Vec<u32>,
    frames: Vec<FramePose>,
    losses: Vec<TrackingLoss>,
    /// After a loss: the frame that tracked again (or restarted the map) and the frames
    /// tracked since. The loss ends there once `RECOVERY_FRAMES` frames in a row track;
    /// a failure before that continues the same loss.
    recovering: Option<(Nanos, usize)>,
    stats: TrackerStats,
    candidates: Vec<usize>,
    /// After a loop closure: keyframes `.0...1` join the local map until there are `.2`
    /// keyframes.
    loop_window: Option<(u32, u32, u32)>,
}

/// Largest stamp offset of a camera used before the velocity is known (1 ms).
const UNCOMPENSATED_OFFSET: Nanos = Nanos(1_000_000);

/// Frames in a row that must track after a loss for it to count as over (1 s at 15 Hz).
pub const RECOVERY_FRAMES: usize = 15;

impl Tracker {
    /// A tracker for `rig` with a validated `cfg`, for features extracted with `orb`.
    pub fn new(
        cfg: TrackingConfig,
        orb: &OrbConfig,
        rig: Vec<TrackerCamera>,
    ) -> Result<Tracker, ConfigError> {
        cfg.validate()?;
        orb.validate()?;
        check(!rig.is_empty(), "the SLAM rig needs at least one camera")?;
        for c in &rig {
            check(
                c.baseline_m.is_finite() && c.baseline_m > 0.0,
                "every SLAM camera needs a positive stereo baseline",
            )?;
            check(
                [c.camera.fx, c.camera.fy, c.camera.cx, c.camera.cy]
                    .iter()
                    .all(|v| v.is_finite())
                    && c.camera.fx > 0.0
                    && c.camera.fy > 0.0,
                "every SLAM camera needs finite, positive focal lengths",
            )?;
        }
        let motion_cfg = MotionBaConfig {
            scale_factor: orb.scale_factor,
            min_inliers: cfg.min_tracked,
            ..MotionBaConfig::default()
        };
        Ok(Tracker {
            cfg,
            scale_factor: orb.scale_factor,
            n_levels: orb.n_levels,
            motion_cfg,
            rig,
            map: Map::default(),
            state: TrackingState::NotInitialized,
            last: None,
            velocity: None,
            ref_keyframe: 0,
            ref_inliers: 0,
            last_keyframe_stamp: Nanos(0),
            local_landmarks: Vec::new(),
            recent_landmarks: Vec::new(),
            frames: Vec::new(),
            losses: Vec::new(),
            recovering: None,
            stats: TrackerStats::default(),
            candidates: Vec::new(),
            loop_window: None,
        })
    }

    /// The map.
    pub fn map(&self) -> &Map {
        &self.map
    }

    /// The map, for the loop closer (keyframe poses and landmarks it corrects).
    pub fn map_mut(&mut self) -> &mut Map {
        &mut self.map
    }

    /// The current state.
    pub fn state(&self) -> TrackingState {
        self.state
    }

    /// The rig.
    pub fn rig(&self) -> &[TrackerCamera] {
        &self.rig
    }

    /// Tracking losses so far.
    pub fn losses(&self) -> &[TrackingLoss] {
        &self.losses
    }

    /// Counters.
    pub fn stats(&self) -> &TrackerStats {
        &self.stats
    }

    /// Every tracked frame's `world_from_body`, through its reference keyframe's current
    /// pose (so BA and loop corrections apply).
    pub fn trajectory(&self) -> Vec<(Nanos, Isometry3<f64>)> {
        self.frames
            .iter()
            .map(|f| {
                let kf = &self.map.keyframes[f.keyframe as usize];
                (f.stamp, kf.world_from_body * f.keyframe_from_body)
            })
            .collect()
    }

    /// After a loop closure onto keyframe `matched`: tracking searches the landmarks of
    /// the keyframes around it too, until `local_keyframes` more keyframes are inserted.
    pub fn open_loop_window(&mut self, matched: u32) {
        let n = self.map.keyframes.len() as u32;
        let half = (self.cfg.local_keyframes / 2) as u32;
        let first = matched.saturating_sub(half);
        let end = (matched + half + 1).min(n);
        self.loop_window = Some((first, end, n + self.cfg.local_keyframes as u32));
        self.update_local_map();
    }

    /// The body pose at `t` between the two tracked frames around it (each pose through
    /// its keyframe's current pose, interpolated on SE(3)), as `(keyframe,
    /// keyframe_from_body)` relative to the later frame's keyframe; `None` unless both
    /// frames exist, belong to one map and lie within `max_gap` of each other.
    pub fn pose_at(&self, t: Nanos, max_gap: Nanos) -> Option<(u32, Isometry3<f64>)> {
        let i = self.frames.partition_point(|f| f.stamp < t);
        let f1 = self.frames.get(i)?;
        let world = |f: &FramePose| {
            self.map.keyframes[f.keyframe as usize].world_from_body * f.keyframe_from_body
        };
        let kf1 = &self.map.keyframes[f1.keyframe as usize];
        if f1.stamp == t {
            return Some((f1.keyframe, f1.keyframe_from_body));
        }
        let f0 = self.frames.get(i.checked_sub(1)?)?;
        if f1.stamp - f0.stamp > max_gap || self.map_of(f0.keyframe) != self.map_of(f1.keyframe) {
            return None;
        }
        let (p0, p1) = (world(f0), world(f1));
        let a = (t - f0.stamp).as_secs_f64() / (f1.stamp - f0.stamp).as_secs_f64();
        let delta = p0.inverse() * p1;
        let step = Isometry3::from_parts(
            (delta.translation.vector * a).into(),
            UnitQuaternion::from_scaled_axis(delta.rotation.scaled_axis() * a),
        );
        Some((f1.keyframe, kf1.world_from_body.inverse() * (p0 * step)))
    }

    /// The first keyframe of the map keyframe `k` belongs to.
    fn map_of(&self, k: u32) -> u32 {
        (0..=k)
            .rev()
            .find(|&i| self.map.keyframes[i as usize].map_start)
            .unwrap_or(0)
    }

    /// Moves the pose of the last frame along with a correction of its reference keyframe
    /// (after the keyframes were changed from outside, e.g. by a loop closure).
    pub fn refresh_last_pose(&mut self) {
        if let (Some(f), Some(last)) = (self.frames.last(), self.last.as_mut()) {
            let kf = &self.map.keyframes[f.keyframe as usize];
            last.1 = kf.world_from_body * f.keyframe_from_body;
        }
    }

    /// The constant-velocity prediction of the pose at `t`.
    fn predict(&self, t: Nanos) -> Option<Isometry3<f64>> {
        let (t0, pose) = self.last?;
        Some(match self.velocity {
            Some(v) => pose * v.motion((t - t0).as_secs_f64()),
            None => pose,
        })
    }

    /// The rig cameras of `inputs` as seen from the body at `stamp`, the body moving at
    /// `velocity` (`None`: as mounted), turning as the gyro says where it measured.
    fn effective_rig(
        &self,
        inputs: &[CameraInput],
        stamp: Nanos,
        velocity: Option<Velocity>,
    ) -> Vec<RigCamera> {
        inputs
            .iter()
            .map(|input| {
                let mut cam = self.rig[input.camera].camera.clone();
                let dt = (input.stamp - stamp).as_secs_f64();
                let motion = match (velocity, input.rotation_from_frame) {
                    (Some(v), Some(q)) => {
                        Some(Isometry3::from_parts(Translation3::from(v.v * dt), q))
                    }
                    (None, Some(q)) => Some(Isometry3::from_parts(Translation3::identity(), q)),
                    (Some(v), None) => Some(v.motion(dt)),
                    (None, None) => None,
                };
                if let Some(m) = motion {
                    cam.body_from_camera = m * cam.body_from_camera;
                }
                cam
            })
            .collect()
    }

    /// The constant velocity from the last tracked pose to `pose` at `stamp` (`None`
    /// before a first pose or without time between them).
    fn velocity_to(&self, stamp: Nanos, pose: &Isometry3<f64>) -> Option<Velocity> {
        let (t0, last) = self.last?;
        let dt = (stamp - t0).as_secs_f64();
        (dt > 0.0).then(|| {
            let delta = last.inverse() * pose;
            Velocity {
                omega: delta.rotation.scaled_axis() / dt,
                v: delta.translation.vector / dt,
            }
        })
    }

    /// Tracks one rig frame stamped `stamp` (normally the primary camera's stamp), whose
    /// cameras are `inputs` (each at most once, any order).
    pub fn track(&mut self, stamp: Nanos, inputs: &[CameraInput]) -> FrameResult {
        self.stats.frames += 1;
        // Without a velocity the time offset of another camera cannot be compensated:
        // only the pairs exposed with the frame's stamp are used (until two frames
        // tracked).
        let synchronous: Vec<CameraInput>;
        let inputs = if self.velocity.is_none() {
            synchronous = inputs
                .iter()
                .filter(|i| (i.stamp - stamp).0.abs() <= UNCOMPENSATED_OFFSET.0)
                .copied()
                .collect();
            &synchronous[..]
        } else {
            inputs
        };
        let rig = self.effective_rig(inputs, stamp, self.velocity);
        let mut result = FrameResult {
            stamp,
            state: self.state,
            world_from_body: None,
            matches: 0,
            inliers: 0,
            keyframe: false,
            initialized: false,
        };
        let stereo_points: usize = inputs
            .iter()
            .map(|i| i.features.stereo.n_with_depth())
            .sum();
        if self.state == TrackingState::NotInitialized {
            if stereo_points >= self.cfg.init_min_points {
                let start = Isometry3::identity();
                self.start_map(stamp, inputs, &rig, start);
                result.state = TrackingState::Tracking;
                result.world_from_body = Some(start);
                result.initialized = true;
                result.keyframe = true;
            }
            return result;
        }
        let predicted = self.predict(stamp).unwrap_or_else(Isometry3::identity);
        match self.track_local_map(stamp, inputs, rig.clone(), &predicted) {
            Some(Tracked {
                pose,
                matches,
                inliers,
                rig,
            }) => {
                result.matches = matches.iter().flatten().flatten().count();
                result.inliers = inliers;
                if self.state == TrackingState::Lost {
                    self.recovering = Some((stamp, 0));
                }
                self.confirm_recovery();
                self.state = TrackingState::Tracking;
                self.stats.tracked += 1;
                self.update_velocity(stamp, &pose);
                let need_keyframe = self.need_keyframe(stamp, inputs, &matches, inliers);
                let mut pose = pose;
                if need_keyframe {
                    let kf = self.insert_keyframe(stamp, inputs, &rig, pose, &matches, false);
                    self.ref_inliers = inliers;
                    pose = self.map.keyframes[kf as usize].world_from_body;
                    self.last = Some((stamp, pose));
                    result.keyframe = true;
                }
                self.push_frame(stamp, &pose);
                result.state = TrackingState::Tracking;
                result.world_from_body = Some(pose);
            }
            None => {
                if self.state == TrackingState::Tracking && self.recovering.take().is_none() {
                    self.losses.push(TrackingLoss {
                        start: stamp,
                        end: None,
                    });
                }
                self.recovering = None;
                self.state = TrackingState::Lost;
                if stereo_points >= self.cfg.init_min_points {
                    // Reinitialize at the dead-reckoned pose.
                    self.recovering = Some((stamp, 0));
                    self.start_map(stamp, inputs, &rig, predicted);
                    result.state = TrackingState::Tracking;
                    result.world_from_body = Some(predicted);
                    result.initialized = true;
                    result.keyframe = true;
                } else {
                    // Keep dead-reckoning from the prediction.
                    if let Some(last) = self.last.as_mut() {
                        *last = (stamp, predicted);
                    }
                    result.state = TrackingState::Lost;
                }
            }
        }
        result
    }

    /// Counts a tracked frame after a loss; ends the loss after `RECOVERY_FRAMES`.
    fn confirm_recovery(&mut self) {
        let Some((since, n)) = self.recovering.as_mut() else {
            return;
        };
        *n += 1;
        if *n >= RECOVERY_FRAMES {
            let since = *since;
            self.recovering = None;
            if let Some(l) = self.losses.last_mut()
                && l.end.is_none()
            {
                l.end = Some(since);
            }
        }
    }

    fn update_velocity(&mut self, stamp: Nanos, pose: &Isometry3<f64>) {
        if let Some(v) = self.velocity_to(stamp, pose) {
            self.velocity = Some(v);
        }
        self.last = Some((stamp, *pose));
    }

    fn push_frame(&mut self, stamp: Nanos, pose: &Isometry3<f64>) {
        let kf = &self.map.keyframes[self.ref_keyframe as usize];
        self.frames.push(FramePose {
            stamp,
            keyframe: self.ref_keyframe,
            keyframe_from_body: kf.world_from_body.inverse() * pose,
        });
    }

    /// Starts a (new) map at `pose`: a keyframe whose stereo points all become landmarks.
    fn start_map(
        &mut self,
        stamp: Nanos,
        inputs: &[CameraInput],
        rig: &[RigCamera],
        pose: Isometry3<f64>,
    ) {
        let empty: Vec<SlotMatches> = inputs
            .iter()
            .map(|i| vec![None; i.features.left.len()])
            .collect();
        let kf = self.insert_keyframe(stamp, inputs, rig, pose, &empty, true);
        self.ref_inliers = self.map.keyframes[kf as usize].landmarks().count();
        self.state = TrackingState::Tracking;
        self.stats.initializations += 1;
        self.stats.tracked += 1;
        self.last = Some((stamp, pose));
        self.push_frame(stamp, &pose);
    }

    /// The pyramid level at which landmark `l` should appear at `distance_m`.
    fn predict_level(&self, ref_distance_m: f64, ref_level: u8, distance_m: f64) -> u8 {
        if self.scale_factor <= 1.0 {
            return ref_level;
        }
        let ratio = (ref_distance_m / distance_m.max(1e-6)).ln() / self.scale_factor.ln();
        let level = f64::from(ref_level) + ratio.round();
        level.clamp(0.0, (self.n_levels - 1) as f64) as u8
    }

    /// Projection search of the local map into every camera from `body_from_world`.
    /// Returns per slot the best landmark of each keypoint; counts `visible` when
    /// `count_visible`.
    fn search(
        &mut self,
        inputs: &[CameraInput],
        rig: &[RigCamera],
        body_from_world: &Isometry3<f64>,
        radius_px: f64,
        count_visible: bool,
    ) -> Vec<SlotMatches> {
        let mut out = Vec::with_capacity(inputs.len());
        let mut candidates = std::mem::take(&mut self.candidates);
        for (input, cam) in inputs.iter().zip(rig) {
            let f = input.features;
            let mut best: SlotMatches = vec![None; f.left.len()];
            let camera_from_world = cam.body_from_camera.inverse() * body_from_world;
            let (w, h) = (f.left.width as f64, f.left.height as f64);
            for &id in &self.local_landmarks {
                let l = &self.map.landmarks[id as usize];
                if l.dead {
                    continue;
                }
                let p_c = (camera_from_world * Point3::from(l.position)).coords;
                let Some(px) = cam.project(&p_c).filter(|_| p_c.z > 0.1) else {
                    continue;
                };
                if !(px.x >= 0.0 && px.y >= 0.0 && px.x <= w - 1.0 && px.y <= h - 1.0) {
                    continue;
                }
                let level = self.predict_level(l.ref_distance_m, l.ref_level, p_c.norm());
                let r = radius_px * self.scale_factor.powi(i32::from(level));
                f.grid.features_in_area_into(
                    px.x as f32,
                    px.y as f32,
                    r as f32,
                    level.saturating_sub(1),
                    level.saturating_add(1),
                    &mut candidates,
                );
                let (mut d1, mut d2, mut i1) = (u32::MAX, u32::MAX, usize::MAX);
                for &i in &candidates {
                    let d = hamming(&l.descriptor, &f.left.descriptors[i]);
                    if d < d1 {
                        (d2, d1, i1) = (d1, d, i);
                    } else if d < d2 {
                        d2 = d;
                    }
                }
                if count_visible {
                    self.map.landmarks[id as usize].visible += 1;
                }
                if d1 > self.cfg.hamming_threshold
                    || (d2 != u32::MAX && f64::from(d1) > self.cfg.ratio * f64::from(d2))
                {
                    continue;
                }
                match best[i1] {
                    Some((_, d)) if d <= d1 => {}
                    _ => best[i1] = Some((id, d1)),
                }
            }
            out.push(best);
        }
        self.candidates = candidates;
        out
    }

    /// Observations for motion-only BA from `matches`, with their (slot, keypoint).
    fn observations(
        &self,
        inputs: &[CameraInput],
        matches: &[SlotMatches],
    ) -> (Vec<Observation>, Vec<(usize, usize, u32)>) {
        let mut obs = Vec::new();
        let mut refs = Vec::new();
        for (slot, (input, m)) in inputs.iter().zip(matches).enumerate() {
            for (k, entry) in m.iter().enumerate() {
                if let Some((id, _)) = *entry {
                    let kp = &input.features.left.keypoints[k];
                    obs.push(Observation {
                        camera: slot,
                        landmark_in_world: self.map.landmarks[id as usize].position,
                        pixel: Vector2::new(f64::from(kp.x), f64::from(kp.y)),
                        level: kp.level,
                    });
                    refs.push((slot, k, id));
                }
            }
        }
        (obs, refs)
    }

    /// Projection search, motion-only BA, a narrow search from its pose and a second BA
    /// (see the module docs). Cameras stamped away from `stamp` enter through `rig`
    /// (extrinsics shifted by the predicted velocity); between the BAs the velocity is
    /// re-estimated from the last tracked pose to the first BA's, and after the second BA
    /// once more, with a last BA over the same matches, so that a camera's time offset is
    /// compensated with the motion of this very interval, not the previous one's. `None`
    /// when lost.
    fn track_local_map(
        &mut self,
        stamp: Nanos,
        inputs: &[CameraInput],
        rig: Vec<RigCamera>,
        predicted: &Isometry3<f64>,
    ) -> Option<Tracked> {
        let offset = inputs
            .iter()
            .any(|i| (i.stamp - stamp).0.abs() > UNCOMPENSATED_OFFSET.0);
        let refined_rig = |tracker: &Self, pose: &Isometry3<f64>, rig: Vec<RigCamera>| match (
            offset,
            tracker.velocity_to(stamp, pose),
        ) {
            (true, Some(v)) => tracker.effective_rig(inputs, stamp, Some(v)),
            _ => rig,
        };
        let body_from_world = predicted.inverse();
        let mut radius = self.cfg.search_radius_px;
        let mut matches = self.search(inputs, &rig, &body_from_world, radius, false);
        for _ in 0..self.cfg.max_widenings {
            if matches.iter().flatten().flatten().count() >= self.cfg.widen_below {
                break;
            }
            radius *= 2.0;
            matches = self.search(inputs, &rig, &body_from_world, radius, false);
        }
        let (obs, _) = self.observations(inputs, &matches);
        let first = optimize_pose(&rig, &obs, predicted, &self.motion_cfg).ok()?;
        let rig = refined_rig(self, &first.world_from_body, rig);
        let refined_from_world = first.world_from_body.inverse();
        let matches = self.search(
            inputs,
            &rig,
            &refined_from_world,
            self.cfg.refine_radius_px,
            true,
        );
        let (obs, refs) = self.observations(inputs, &matches);
        let mut second =
            optimize_pose(&rig, &obs, &first.world_from_body, &self.motion_cfg).ok()?;
        let rig = if offset {
            let refined = refined_rig(self, &second.world_from_body, rig.clone());
            match optimize_pose(&refined, &obs, &second.world_from_body, &self.motion_cfg) {
                Ok(third) => {
                    second = third;
                    refined
                }
                Err(_) => rig,
            }
        } else {
            rig
        };
        let mut inlier_matches: Vec<SlotMatches> =
            matches.iter().map(|m| vec![None; m.len()]).collect();
        for (&(slot, k, id), &inlier) in refs.iter().zip(&second.inliers) {
            if inlier {
                inlier_matches[slot][k] = matches[slot][k];
                self.map.landmarks[id as usize].found += 1;
            }
        }
        Some(Tracked {
            pose: second.world_from_body,
            matches: inlier_matches,
            inliers: second.n_inliers,
            rig,
        })
    }

    /// ORB-SLAM's keyframe decision (see the module docs).
    fn need_keyframe(
        &self,
        stamp: Nanos,
        inputs: &[CameraInput],
        matches: &[SlotMatches],
        inliers: usize,
    ) -> bool {
        if (stamp - self.last_keyframe_stamp).as_secs_f64() >= self.cfg.keyframe_max_interval_s {
            return true;
        }
        if (inliers as f64) < self.cfg.keyframe_ratio * self.ref_inliers as f64 {
            return true;
        }
        let (mut tracked_close, mut untracked_close) = (0, 0);
        for (input, m) in inputs.iter().zip(matches) {
            for (d, entry) in input.features.stereo.depth_m.iter().zip(m) {
                if d.is_some() {
                    if entry.is_some() {
                        tracked_close += 1;
                    } else {
                        untracked_close += 1;
                    }
                }
            }
        }
        tracked_close < 100 && untracked_close > 70
    }

    /// Inserts a keyframe at `pose`, links its matches, creates landmarks from its other
    /// stereo points, culls recent landmarks and runs local BA. Returns its index.
    fn insert_keyframe(
        &mut self,
        stamp: Nanos,
        inputs: &[CameraInput],
        rig: &[RigCamera],
        pose: Isometry3<f64>,
        matches: &[SlotMatches],
        map_start: bool,
    ) -> u32 {
        let id = self.map.keyframes.len() as u32;
        let cameras = inputs
            .iter()
            .zip(rig)
            .map(|(input, cam)| KeyFrameCamera {
                camera: input.camera,
                stamp: input.stamp,
                body_from_camera: cam.body_from_camera,
                keypoints: input.features.left.keypoints.clone(),
                descriptors: input.features.left.descriptors.clone(),
                right_x: input.features.stereo.right_x.clone(),
                landmarks: vec![None; input.features.left.len()],
            })
            .collect();
        self.map.keyframes.push(KeyFrame {
            stamp,
            world_from_body: pose,
            cameras,
            anchored: false,
            map_start,
        });
        for (slot, m) in matches.iter().enumerate() {
            for (k, entry) in m.iter().enumerate() {
                if let Some((lm, _)) = *entry {
                    self.map.add_observation(lm, id, slot as u16, k as u32);
                }
            }
        }
        for (slot, (input, cam)) in inputs.iter().zip(rig).enumerate() {
            let world_from_camera = pose * cam.body_from_camera;
            for (k, depth) in input.features.stereo.depth_m.iter().enumerate() {
                let Some(z) = *depth else { continue };
                if self.map.keyframes[id as usize].cameras[slot].landmarks[k].is_some() {
                    continue;
                }
                let kp = &input.features.left.keypoints[k];
                let z = f64::from(z);
                let p_c = Point3::new(
                    (f64::from(kp.x) - cam.cx) * z / cam.fx,
                    (f64::from(kp.y) - cam.cy) * z / cam.fy,
                    z,
                );
                let p_w = world_from_camera * p_c;
                let lm = self.map.add_landmark(p_w.coords, id, slot as u16, k as u32);
                self.recent_landmarks.push(lm);
            }
        }
        self.stats.culled += self.map.cull_recent(id, &mut self.recent_landmarks);
        self.stats.keyframes += 1;
        self.ref_keyframe = id;
        self.last_keyframe_stamp = stamp;
        if !map_start {
            self.local_bundle_adjustment(id);
        }
        self.update_local_map();
        id
    }

    /// The landmarks of the last `local_keyframes` keyframes, sorted and unique.
    /// After a loop closure, also those of the keyframes around the matched place, for
    /// the next `local_keyframes` keyframes: the frames that follow match the old map's
    /// landmarks, and local BA ties the two passes together.
    fn update_local_map(&mut self) {
        let n = self.map.keyframes.len();
        if self.loop_window.is_some_and(|w| n >= w.2 as usize) {
            self.loop_window = None;
        }
        let from = n.saturating_sub(self.cfg.local_keyframes);
        let window = self
            .loop_window
            .map(|w| w.0 as usize..(w.1 as usize).min(from))
            .unwrap_or(0..0);
        let mut ids: Vec<u32> = self.map.keyframes[window]
            .iter()
            .chain(&self.map.keyframes[from..])
            .flat_map(|kf| kf.landmarks())
            .filter(|&id| !self.map.landmarks[id as usize].dead)
            .collect();
        ids.sort_unstable();
        ids.dedup();
        self.local_landmarks = ids;
    }

    /// Local BA (eqs. 4-5) after keyframe `newest`: the last `local_ba_keyframes`
    /// keyframes and their landmarks are optimized, the other keyframes observing those
    /// landmarks are held fixed; outlier observations are unlinked.
    fn local_bundle_adjustment(&mut self, newest: u32) {
        let n = newest as usize + 1;
        let first_free = n.saturating_sub(self.cfg.local_ba_keyframes);
        let cfg = BundleConfig {
            iterations_per_round: self.cfg.local_ba_iterations,
            scale_factor: self.scale_factor,
            ..BundleConfig::default()
        };
        if let Some(out) = self.bundle_adjust_keyframes(first_free as u32, n as u32, &cfg) {
            self.stats.local_ba_runs += 1;
            self.stats.local_ba_outliers += out.outliers;
        }
    }

    /// Global BA (eq. 5, after a loop closure): every keyframe and live landmark; map
    /// starts and anchored keyframes are held fixed. Returns the BA's outcome (`None`
    /// when there was nothing to adjust or the problem was degenerate).
    pub fn global_bundle_adjustment(&mut self, iterations: usize) -> Option<BundleOutcome> {
        let cfg = BundleConfig {
            iterations_per_round: iterations,
            scale_factor: self.scale_factor,
            ..BundleConfig::global()
        };
        let n = self.map.keyframes.len() as u32;
        let out = self.bundle_adjust_keyframes(0, n, &cfg);
        self.refresh_last_pose();
        out
    }

    /// BA of keyframes `first_free..end` and their landmarks; the other keyframes
    /// observing those landmarks, map starts and anchored keyframes are held fixed;
    /// outlier observations are unlinked.
    fn bundle_adjust_keyframes(
        &mut self,
        first_free: u32,
        end: u32,
        cfg: &BundleConfig,
    ) -> Option<BundleOutcome> {
        let (first_free, n) = (first_free as usize, end as usize);
        // Landmarks of the free keyframes.
        let mut lms: Vec<u32> = self.map.keyframes[first_free..n]
            .iter()
            .flat_map(|kf| kf.landmarks())
            .filter(|&id| !self.map.landmarks[id as usize].dead)
            .collect();
        lms.sort_unstable();
        lms.dedup();
        if lms.is_empty() {
            return None;
        }
        // Keyframes in the problem: free ones and those observing the landmarks.
        let mut kf_ids: Vec<u32> = (first_free as u32..n as u32).collect();
        for &id in &lms {
            kf_ids.extend(
                self.map.landmarks[id as usize]
                    .observations
                    .iter()
                    .map(|o| o.keyframe),
            );
        }
        kf_ids.sort_unstable();
        kf_ids.dedup();
        let kf_index = |k: u32| kf_ids.binary_search(&k).ok();
        let mut keyframes: Vec<BaKeyFrame> = kf_ids
            .iter()
            .map(|&k| {
                let kf = &self.map.keyframes[k as usize];
                BaKeyFrame {
                    world_from_body: kf.world_from_body,
                    fixed: (k as usize) < first_free
                        || (k as usize) >= n
                        || kf.map_start
                        || kf.anchored,
                }
            })
            .collect();
        if keyframes.iter().all(|k| !k.fixed) {
            // Cannot happen (a map starts with a fixed keyframe), but BA needs a gauge.
            keyframes[0].fixed = true;
        }
        // One camera per (keyframe, slot).
        let mut cameras = Vec::new();
        let mut camera_of: Vec<Vec<usize>> = Vec::with_capacity(kf_ids.len());
        for &k in &kf_ids {
            let kf = &self.map.keyframes[k as usize];
            camera_of.push(
                kf.cameras
                    .iter()
                    .map(|c| {
                        let mut cam = self.rig[c.camera].camera.clone();
                        cam.body_from_camera = c.body_from_camera;
                        cameras.push(cam);
                        cameras.len() - 1
                    })
                    .collect(),
            );
        }
        let landmarks: Vec<BaLandmark> = lms
            .iter()
            .map(|&id| BaLandmark {
                position: self.map.landmarks[id as usize].position,
                fixed: false,
            })
            .collect();
        let mut observations = Vec::new();
        let mut obs_refs: Vec<(u32, KeyPointRef)> = Vec::new();
        for (li, &id) in lms.iter().enumerate() {
            for o in &self.map.landmarks[id as usize].observations {
                let Some(ki) = kf_index(o.keyframe) else {
                    continue;
                };
                let kc = &self.map.keyframes[o.keyframe as usize].cameras[o.slot as usize];
                let kp = &kc.keypoints[o.keypoint as usize];
                observations.push(BaObservation {
                    keyframe: ki,
                    landmark: li,
                    camera: camera_of[ki][o.slot as usize],
                    pixel: Vector2::new(f64::from(kp.x), f64::from(kp.y)),
                    level: kp.level,
                    right_x: kc.right_x[o.keypoint as usize].map(f64::from),
                    baseline_m: self.rig[kc.camera].baseline_m,
                });
                obs_refs.push((id, *o));
            }
        }
        let Ok(result) = bundle_adjust(&cameras, &keyframes, &landmarks, &observations, cfg) else {
            return None;
        };
        let mut outcome = BundleOutcome {
            keyframes: keyframes.iter().filter(|k| !k.fixed).count(),
            landmarks: lms.len(),
            observations: observations.len(),
            outliers: 0,
            initial_cost: result.initial_cost,
            final_cost: result.final_cost,
            iterations: result.iterations,
        };
        for (ki, &k) in kf_ids.iter().enumerate() {
            if !keyframes[ki].fixed {
                self.map.keyframes[k as usize].world_from_body = result.keyframes[ki];
            }
        }
        for (li, &id) in lms.iter().enumerate() {
            self.map.landmarks[id as usize].position = result.landmarks[li];
        }
        for (&(id, at), &outlier) in obs_refs.iter().zip(&result.outliers) {
            if outlier {
                self.map.remove_observation(id, at);
                outcome.outliers += 1;
            }
        }
        Some(outcome)
    }
}

/// What one bundle adjustment of the map did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BundleOutcome {
    /// Keyframes optimized (not held fixed).
    pub keyframes: usize,
    /// Landmarks optimized.
    pub landmarks: usize,
    /// Observations in the problem.
    pub observations: usize,
    /// Observations unlinked as outliers.
    pub outliers: usize,
    /// Cost before and after.
    pub initial_cost: f64,
    /// Cost after.
    pub final_cost: f64,
    /// Iterations run.
    pub iterations: usize,
}

#[cfg(test)]
pub(super) mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::slam::bench::synthetic_rig;
    use crate::slam::grid::{FeatureGrid, GridConfig};
    use crate::slam::orb::{Descriptor, Features, KeyPoint};
    use crate::slam::stereo::StereoMatches;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    pub const BASELINE_M: f64 = 0.12;
    const RATE_HZ: f64 = 15.0;

    /// Landmarks on two canopy walls 1.25 m either side of the path and on the ground,
    /// each with a random descriptor.
    pub fn world(rng: &mut ChaCha8Rng) -> Vec<(Vector3<f64>, Descriptor)> {
        (0..6000)
            .map(|i| {
                let x = rng.random_range(-8.0..30.0);
                let p = match i % 3 {
                    0 => Vector3::new(
                        x,
                        1.25 + rng.random_range(-0.2..0.2),
                        rng.random_range(0.3..1.8),
                    ),
                    1 => Vector3::new(
                        x,
                        -1.25 + rng.random_range(-0.2..0.2),
                        rng.random_range(0.3..1.8),
                    ),
                    _ => Vector3::new(x, rng.random_range(-1.0..1.0), 0.0),
                };
                (
                    p,
                    Descriptor([rng.random(), rng.random(), rng.random(), rng.random()]),
                )
            })
            .collect()
    }

    /// The truth at `t` s: 0.5 m/s along x with a gentle weave in y and yaw.
    fn truth(t: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(0.5 * t, 0.1 * (0.4 * t).sin(), 0.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.05 * (0.4 * t).cos()),
        )
    }

    /// What camera `cam` sees from `world_from_body`: keypoints at the projections (with
    /// pixel noise and a few flipped descriptor bits), stereo matches below 40 baselines.
    pub fn observe(
        cam: &RigCamera,
        world_from_body: &Isometry3<f64>,
        landmarks: &[(Vector3<f64>, Descriptor)],
        rng: &mut ChaCha8Rng,
    ) -> StereoFrame {
        let (w, h) = (752usize, 480usize);
        let camera_from_world = (world_from_body * cam.body_from_camera).inverse();
        let mut f = Features {
            width: w,
            height: h,
            ..Features::default()
        };
        let mut stereo = StereoMatches::default();
        for (p, d) in landmarks {
            let p_c = camera_from_world * Point3::from(*p);
            if p_c.z < 0.5 || p_c.z > 15.0 {
                continue;
            }
            let Some(px) = cam.project(&p_c.coords) else {
                continue;
            };
            let px = px + Vector2::new(rng.random_range(-0.3..0.3), rng.random_range(-0.3..0.3));
            if px.x < 0.0 || px.y < 0.0 || px.x > (w - 1) as f64 || px.y > (h - 1) as f64 {
                continue;
            }
            let level = ((p_c.z / 4.0).log(1.2).max(0.0) as u8).min(5);
            let mut d = *d;
            d.0[rng.random_range(0..4)] ^= 1 << rng.random_range(0..64);
            f.keypoints.push(KeyPoint {
                x: px.x as f32,
                y: px.y as f32,
                level,
                angle_rad: 0.0,
                response: 10.0,
                size: 31.0,
            });
            f.descriptors.push(d);
            let z = p_c.z;
            let disparity = cam.fx * BASELINE_M / z;
            stereo.right_x.push(Some((px.x - disparity) as f32));
            stereo
                .depth_m
                .push((z < 40.0 * BASELINE_M).then_some(z as f32));
        }
        let grid = FeatureGrid::build(&GridConfig::default(), w, h, &f.keypoints);
        StereoFrame {
            left: f,
            right: Features::default(),
            stereo,
            grid,
        }
    }

    struct Run {
        errors_m: Vec<f64>,
        losses: Vec<TrackingLoss>,
        results: Vec<FrameResult>,
        stats: TrackerStats,
    }

    /// Tracks 12 s of the synthetic run with `cameras` of the synthetic rig; the front
    /// camera sees nothing (a featureless box) between `blind_s`.
    fn run(cameras: &[usize], blind_s: (f64, f64), rear_offset_s: f64) -> Run {
        run_shaken(cameras, blind_s, rear_offset_s, 0.0, false)
    }

    /// [`truth`] with the chassis shaken: pitch and roll of `amplitude_deg` at 5.3 and
    /// 3.7 Hz (the rover's rollers on rough ground).
    fn shaken(t: f64, amplitude_deg: f64) -> Isometry3<f64> {
        let a = amplitude_deg.to_radians();
        let tau = std::f64::consts::TAU;
        let shake = UnitQuaternion::from_euler_angles(
            a * (tau * 3.7 * t).sin(),
            a * (tau * 5.3 * t).sin(),
            0.0,
        );
        truth(t) * Isometry3::from_parts(Translation3::identity(), shake)
    }

    /// [`run`] on the [`shaken`] chassis; with `gyro`, the rear pair comes with the true
    /// rotation between the two stamps (an ideal gyro).
    fn run_shaken(
        cameras: &[usize],
        blind_s: (f64, f64),
        rear_offset_s: f64,
        shake_deg: f64,
        gyro: bool,
    ) -> Run {
        let truth = |t: f64| shaken(t, shake_deg);
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let landmarks = world(&mut rng);
        let full = synthetic_rig();
        let rig: Vec<TrackerCamera> = cameras
            .iter()
            .map(|&c| TrackerCamera {
                camera: full[c].clone(),
                baseline_m: BASELINE_M,
            })
            .collect();
        let mut tracker =
            Tracker::new(TrackingConfig::default(), &OrbConfig::default(), rig).unwrap();
        let start = truth(0.0);
        let mut results = Vec::new();
        let mut errors_m = Vec::new();
        for i in 0..(12.0 * RATE_HZ) as i64 {
            let t = i as f64 / RATE_HZ;
            let frames: Vec<(Nanos, StereoFrame)> = cameras
                .iter()
                .map(|&c| {
                    let tc = if c == 1 { t + rear_offset_s } else { t };
                    let blind = c == 0 && (blind_s.0..blind_s.1).contains(&t);
                    let frame = if blind {
                        StereoFrame::default()
                    } else {
                        observe(&full[c], &truth(tc), &landmarks, &mut rng)
                    };
                    (Nanos::from_secs_f64(tc), frame)
                })
                .collect();
            let inputs: Vec<CameraInput> = frames
                .iter()
                .enumerate()
                .map(|(k, (stamp, f))| CameraInput {
                    camera: k,
                    stamp: *stamp,
                    features: f,
                    rotation_from_frame: (gyro && *stamp != Nanos::from_secs_f64(t))
                        .then(|| truth(t).rotation.inverse() * truth(stamp.as_secs_f64()).rotation),
                })
                .collect();
            let r = tracker.track(Nanos::from_secs_f64(t), &inputs);
            if let Some(p) = r.world_from_body {
                // The SLAM's world is the body at its first frame.
                let expected = start.inverse() * truth(t);
                errors_m.push((p.translation.vector - expected.translation.vector).norm());
            }
            results.push(r);
        }
        Run {
            errors_m,
            losses: tracker.losses().to_vec(),
            results,
            stats: tracker.stats().clone(),
        }
    }

    #[test]
    fn rig_tracks_a_synthetic_run_to_millimetres() {
        let r = run(&[0, 1], (0.0, 0.0), 0.0);
        assert!(r.losses.is_empty(), "{:?}", r.losses);
        assert_eq!(r.stats.initializations, 1);
        assert_eq!(r.errors_m.len(), r.results.len());
        let rmse = (r.errors_m.iter().map(|e| e * e).sum::<f64>() / r.errors_m.len() as f64).sqrt();
        let max = r.errors_m.iter().copied().fold(0.0, f64::max);
        println!(
            "rig: rmse {rmse:.4} m, max {max:.4} m over 6 m, {} keyframes",
            r.stats.keyframes
        );
        assert!(rmse < 0.01 && max < 0.02, "rmse {rmse} max {max}");
        assert!(r.stats.keyframes >= 6, "{:?}", r.stats);
        assert!(r.stats.local_ba_runs >= 5, "{:?}", r.stats);
        // Tracking matched most of what each frame saw.
        let inliers: usize = r.results.iter().map(|x| x.inliers).sum();
        assert!(inliers as f64 / r.results.len() as f64 > 200.0, "{inliers}");
    }

    #[test]
    fn free_running_rear_camera_is_compensated() {
        // The rear pair is exposed 30 ms after the front pair; the constant-velocity
        // extrinsic shift keeps both in one pose.
        let r = run(&[0, 1], (0.0, 0.0), 0.030);
        assert!(r.losses.is_empty(), "{:?}", r.losses);
        let rmse = (r.errors_m.iter().map(|e| e * e).sum::<f64>() / r.errors_m.len() as f64).sqrt();
        println!("rig with a 30 ms rear offset: rmse {rmse:.4} m");
        // Uncompensated, the rear landmarks would sit 1.5 cm off (0.5 m/s · 30 ms).
        assert!(rmse < 0.005, "rmse {rmse}");
    }

    #[test]
    fn a_free_running_rear_camera_is_compensated_on_a_shaking_chassis() {
        // The chassis pitches and rolls by 0.3° at a few hertz: the velocity of the
        // previous frame interval says little about this one's, and the rear pair is
        // exposed 30 ms after the front one.
        let rmse = |r: &Run| {
            (r.errors_m.iter().map(|e| e * e).sum::<f64>() / r.errors_m.len() as f64).sqrt()
        };
        let synchronous = run_shaken(&[0, 1], (0.0, 0.0), 0.0, 0.3, false);
        let guessed = run_shaken(&[0, 1], (0.0, 0.0), 0.030, 0.3, false);
        let measured = run_shaken(&[0, 1], (0.0, 0.0), 0.030, 0.3, true);
        for r in [&synchronous, &guessed, &measured] {
            assert!(r.losses.is_empty(), "{:?}", r.losses);
        }
        let (a, b, c) = (rmse(&synchronous), rmse(&guessed), rmse(&measured));
        println!(
            "shaking chassis: rmse {a:.4} m synchronous; 30 ms rear offset: {b:.4} m with \
             constant velocity, {c:.4} m with the gyro's rotation"
        );
        // With the gyro's rotation the offset rear pair tracks the shaking run about as
        // well as an offset pair tracks the smooth one (1.9 mm,
        // `free_running_rear_camera_is_compensated`); a constant velocity cannot follow
        // the shaking.
        assert!(c < 0.0025, "synchronous {a} m, with the gyro {c} m");
        assert!(b > 3.0 * c, "constant velocity {b} m, with the gyro {c} m");
    }

    #[test]
    fn blind_front_camera_loses_the_single_camera_not_the_rig() {
        let blind = (4.0, 6.0);
        let rig = run(&[0, 1], blind, 0.0);
        assert!(rig.losses.is_empty(), "{:?}", rig.losses);
        let rmse =
            (rig.errors_m.iter().map(|e| e * e).sum::<f64>() / rig.errors_m.len() as f64).sqrt();
        assert!(rmse < 0.02, "rig rmse {rmse}");
        let single = run(&[0], blind, 0.0);
        println!("single camera losses: {:?}", single.losses);
        assert_eq!(single.losses.len(), 1, "{:?}", single.losses);
        let loss = single.losses[0];
        assert_eq!(loss.start, Nanos::from_secs_f64(4.0));
        // The first frame with points again ends it (recovered against the old map from
        // the dead-reckoned pose, or a restarted map).
        assert_eq!(loss.end, Some(Nanos::from_secs_f64(6.0)));
        let lost = single
            .results
            .iter()
            .filter(|x| x.state == TrackingState::Lost)
            .count();
        assert_eq!(lost, 30, "two seconds at 15 Hz");
    }
}
