//! The SLAM as a message consumer: stereo image and `CameraInfo` messages in (plus
//! `/tf_static`), a trajectory, tracking losses and counters out. The same code runs on
//! a live simulation and on a recording.
//!
//! Each configured camera `<name>` publishes `/<name>/left/image_rect_color`,
//! `/<name>/right/image_rect_color` and their `camera_info` (the ZED and the simulator's
//! convention). A pair is complete when both images of one stamp have arrived; its
//! features are extracted at once ([`StereoFrontEnd`]). Cameras run free, so a **rig
//! frame** is formed whenever the *primary* camera (the first listed) completes a pair:
//! it takes the latest unused pair of every other camera stamped within
//! `max_camera_offset_s` and the tracker accounts for the time offsets
//! ([`super::tracking`]). Messages are processed in the order given, so a run and its
//! replay produce the same trajectory. With `pipeline`, a rig frame is tracked on another
//! core while the next image is processed, with the same results.

use super::bow::Vocabulary;
use super::frontend::{FrontEndConfig, StereoFrame, StereoFrontEnd};
use super::gyro::GyroBuffer;
use super::image::{GrayImage, ImageError};
use super::loop_closing::{LoopClosure, LoopConfig, LoopMethod, LoopStats, TagLoopCloser};
use super::motion_ba::RigCamera;
use super::place_recognition::{BowConfig, BowLoopCloser, BowStats};
use super::tags::{TagCamera, TagConfig, TagDetector, TagSighting, tag_pose_information};
use super::tracking::{
    CameraInput, FrameResult, Tracker, TrackerCamera, TrackerStats, TrackingConfig, TrackingLoss,
};
use super::{ConfigError, check};
use nalgebra::{Isometry3, UnitQuaternion};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::sync::{Arc, Mutex, PoisonError};
use vinebench_msgs::{
    CameraInfoMsg, ImageMsg, Message, Nanos, PoseSample, StaticTransforms, Trajectory,
};

/// `[slam]` of a scenario (every key documented in `scenarios/defaults.toml`).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct SlamConfig {
    /// Run the SLAM.
    pub enabled: bool,
    /// Stereo cameras by name; the first is the primary (its pairs make rig frames).
    pub cameras: Vec<String>,
    /// Pairs of other cameras stamped further than this from the primary's are not
    /// used with it, s.
    pub max_camera_offset_s: f64,
    /// Track each rig frame while the next image (pair or tag camera) is processed, on
    /// another core: the same results as one after the other (the frame's inputs are
    /// fixed when its primary pair is extracted, and everything the tracker does happens
    /// in the same order), faster on two or more cores.
    pub pipeline: bool,
    /// Turn the cameras stamped away from the primary's pair by the rotation the IMU's
    /// gyro (`/imu/data`) measured in between ([`GyroBuffer`]); without it (or before
    /// the first samples) a constant-velocity guess is used.
    pub use_gyro: bool,
    /// Feature extraction and stereo matching.
    pub features: FrontEndConfig,
    /// Tracking and local mapping.
    pub tracking: TrackingConfig,
    /// AprilTag detection on the tag camera.
    pub tags: TagConfig,
    /// Loop closure.
    pub loop_closure: LoopConfig,
    /// Bag-of-words loop detection (`loop_closure.method = "bow"`).
    pub bow: BowConfig,
    /// Baselines run on the same messages, each an estimate source of its own.
    pub baselines: Vec<SlamBaseline>,
}

/// A baseline configuration of the same SLAM (the paper's comparisons).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SlamBaseline {
    /// Only the first camera of `slam.cameras`, no tags (ORB-SLAM3-like stereo; source
    /// `slam_single_camera`).
    SingleCamera,
    /// Every camera, no loop closure (source `slam_no_loops`): the ATE without loops.
    NoLoops,
    /// Every camera, loops found by bag of words instead of tags (source `slam_bow`):
    /// ORB-SLAM's place recognition.
    Bow,
}

impl SlamBaseline {
    /// The estimate source it produces.
    pub fn source(self) -> &'static str {
        match self {
            SlamBaseline::SingleCamera => "slam_single_camera",
            SlamBaseline::NoLoops => "slam_no_loops",
            SlamBaseline::Bow => "slam_bow",
        }
    }

    /// `cfg` turned into this baseline.
    pub fn config(self, cfg: &SlamConfig) -> SlamConfig {
        let no_loops = SlamConfig {
            baselines: Vec::new(),
            loop_closure: LoopConfig {
                method: LoopMethod::None,
                ..cfg.loop_closure.clone()
            },
            ..cfg.clone()
        };
        match self {
            SlamBaseline::SingleCamera => SlamConfig {
                cameras: cfg.cameras.iter().take(1).cloned().collect(),
                ..no_loops
            },
            SlamBaseline::NoLoops => no_loops,
            SlamBaseline::Bow => SlamConfig {
                loop_closure: LoopConfig {
                    method: LoopMethod::Bow,
                    ..cfg.loop_closure.clone()
                },
                ..no_loops
            },
        }
    }
}

/// The left and right image topics of the stereo camera `name` that the SLAM reads.
pub fn stereo_image_topics(name: &str) -> [String; 2] {
    ["left", "right"].map(|side| format!("/{name}/{side}/image_rect_color"))
}

/// The estimate source of the SLAM itself.
pub const SLAM_SOURCE: &str = "slam";

impl Default for SlamConfig {
    fn default() -> Self {
        SlamConfig {
            enabled: false,
            cameras: vec!["front".to_string(), "rear".to_string()],
            max_camera_offset_s: 0.1,
            pipeline: true,
            use_gyro: true,
            features: FrontEndConfig::default(),
            tracking: TrackingConfig::default(),
            tags: TagConfig::default(),
            loop_closure: LoopConfig::default(),
            bow: BowConfig::default(),
            baselines: Vec::new(),
        }
    }
}

impl SlamConfig {
    /// Checks every range.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check(
            !self.cameras.is_empty(),
            "slam.cameras must name at least one stereo camera",
        )?;
        for (i, a) in self.cameras.iter().enumerate() {
            check(
                !self.cameras[..i].contains(a),
                "slam.cameras must not name a camera twice",
            )?;
        }
        check(
            self.max_camera_offset_s.is_finite() && self.max_camera_offset_s >= 0.0,
            "slam.max_camera_offset_s must be a non-negative number",
        )?;
        for (i, b) in self.baselines.iter().enumerate() {
            check(
                !self.baselines[..i].contains(b),
                "slam.baselines must not name a baseline twice",
            )?;
        }
        self.features.validate()?;
        self.tracking.validate()?;
        self.tags.validate()?;
        self.loop_closure.validate()?;
        self.bow.validate()
    }

    /// Whether this SLAM reads the tag camera.
    pub fn uses_tags(&self) -> bool {
        self.loop_closure.method == LoopMethod::Tags
    }

    /// Whether this SLAM, or one of its baselines, needs the bag-of-words vocabulary.
    pub fn needs_vocabulary(&self) -> bool {
        self.runs()
            .iter()
            .any(|(_, c)| c.loop_closure.method == LoopMethod::Bow)
    }

    /// Every SLAM a scenario runs: the SLAM itself, then each baseline, with the source
    /// names of their trajectories.
    pub fn runs(&self) -> Vec<(&'static str, SlamConfig)> {
        std::iter::once((SLAM_SOURCE, self.clone()))
            .chain(self.baselines.iter().map(|b| (b.source(), b.config(self))))
            .collect()
    }
}

/// Why the SLAM could not use its input.
#[derive(Debug, thiserror::Error)]
pub enum SlamError {
    /// An image that cannot be read.
    #[error("SLAM input {topic} at {stamp}: {source}")]
    Image {
        /// Its topic.
        topic: String,
        /// Its stamp.
        stamp: Nanos,
        /// What is wrong.
        source: ImageError,
    },
    /// A `CameraInfo` that does not describe a rectified stereo camera.
    #[error("SLAM input {topic} at {stamp}: {problem}")]
    CameraInfo {
        /// Its topic.
        topic: String,
        /// Its stamp.
        stamp: Nanos,
        /// What is wrong.
        problem: String,
    },
    /// An IMU message with a field that is not usable.
    #[error("SLAM input {0}")]
    Imu(#[from] vinebench_msgs::msg::InvalidMessage),
    /// The IMU's frame missing from `/tf_static`.
    #[error("SLAM IMU (slam.use_gyro): frame `{0}` is not in /tf_static")]
    UnknownImuFrame(String),
    /// A camera frame missing from `/tf_static`.
    #[error("SLAM camera {camera}: frame `{frame}` is not in /tf_static")]
    UnknownFrame {
        /// The camera.
        camera: String,
        /// The frame.
        frame: String,
    },
    /// Invalid settings.
    #[error(transparent)]
    Config(#[from] ConfigError),
}

/// One configured camera's inputs.
#[derive(Debug)]
struct CameraSlot {
    name: String,
    left_topic: String,
    right_topic: String,
    left_info_topic: String,
    right_info_topic: String,
    front_end: StereoFrontEnd,
    left: Option<ImageMsg>,
    right: Option<ImageMsg>,
    left_info: Option<CameraInfoMsg>,
    right_info: Option<CameraInfoMsg>,
    gray: (GrayImage, GrayImage),
    /// The latest extracted pair and whether a rig frame used it (a used pair's
    /// features have moved to its rig frame).
    latest: Option<(Nanos, StereoFrame, bool)>,
    /// A tracked pair's features, handed back for the next extraction (no allocation).
    spare: Option<StereoFrame>,
    pairs: usize,
}

/// What [`VisualSlam::finish`] hands over.
#[derive(Clone, Debug)]
pub struct SlamOutput {
    /// The estimate source (`slam`, `slam_single_camera`).
    pub source: &'static str,
    /// Every tracked frame's `world_from_body` (keyframe-relative, after the final BA).
    pub trajectory: Trajectory,
    /// Per-frame outcomes, in order.
    pub frames: Vec<FrameResult>,
    /// Tracking losses.
    pub losses: Vec<TrackingLoss>,
    /// Tracker counters.
    pub stats: TrackerStats,
    /// Stereo pairs extracted per camera (name, count).
    pub pairs: Vec<(String, usize)>,
    /// Of those pairs, how many were copied from another SLAM of the run that had
    /// extracted the same images ([`share_front_ends`]).
    pub shared_pairs: usize,
    /// Live landmarks at the end.
    pub landmarks: usize,
    /// Accepted loop closures, in order.
    pub loops: Vec<LoopClosure>,
    /// Loop-closer counters.
    pub loop_stats: LoopStats,
    /// Tag-camera images searched for tags.
    pub tag_images: usize,
    /// Tag detections accepted.
    pub tag_detections: usize,
    /// Bag-of-words loop-closer counters (with `loop_closure.method = "bow"`).
    pub bow_stats: Option<BowStats>,
    /// Every keyframe's descriptors, all cameras together (the training images of a
    /// bag-of-words vocabulary, `vinebench vocabulary`).
    pub keyframe_descriptors: Vec<Vec<super::Descriptor>>,
    /// Wall-clock seconds spent in the SLAM (feature extraction, tracking, local BA); for
    /// `timing.json`, never for results.
    pub wall_s: f64,
}

/// The visual SLAM fed by messages (see the module docs).
#[derive(Debug)]
pub struct VisualSlam {
    source: &'static str,
    cfg: SlamConfig,
    static_transforms: StaticTransforms,
    slots: Vec<CameraSlot>,
    tracker: Option<Tracker>,
    frames: Vec<FrameResult>,
    busy_s: f64,
    tags: Option<TagSlot>,
    bow: Option<BowLoopCloser>,
    /// Body-frame angular rates (with `use_gyro`).
    gyro: GyroBuffer,
    /// `body_from_imu`'s rotation, once the first IMU message named its frame.
    body_from_imu: Option<UnitQuaternion<f64>>,
    /// The rig frame waiting to be tracked alongside the next image (with `pipeline`).
    pending: Option<RigFrame>,
    /// Pairs extracted by the other SLAMs of the run ([`share_front_ends`]).
    shared: Option<SharedFrontEnd>,
    /// Pairs copied from `shared`.
    shared_pairs: usize,
}

/// Stereo pairs that one SLAM of a run has extracted, kept for the others that read the
/// same cameras with the same front-end settings (a scenario's baselines run on the very
/// same messages). A pair whose two images are the same buffers (the same `Arc`, which
/// the entry holds, so no other image can take its address) with the same size,
/// encoding and stereo calibration is copied instead of extracted again. Extraction is a
/// function of the images, the calibration and the settings alone, so the copy is what
/// the SLAM would have computed, bit for bit. Set up by [`share_front_ends`].
#[derive(Clone, Debug)]
struct SharedFrontEnd {
    /// The latest extracted pair of each camera.
    pairs: Arc<Mutex<Vec<SharedPair>>>,
}

/// One extracted pair in a [`SharedFrontEnd`].
#[derive(Debug)]
struct SharedPair {
    camera: String,
    left: ImageMsg,
    right: ImageMsg,
    stereo: super::StereoCamera,
    frame: StereoFrame,
}

/// Whether `a` and `b` are the same image: the same pixel buffer, size, encoding and
/// stamp.
fn same_image(a: &ImageMsg, b: &ImageMsg) -> bool {
    Arc::ptr_eq(&a.data, &b.data)
        && a.data.len() == b.data.len()
        && (a.stamp, a.width, a.height, a.encoding) == (b.stamp, b.width, b.height, b.encoding)
}

impl SharedFrontEnd {
    /// The pair of slot `s`'s camera extracted from `left` and `right` with `stereo`, if
    /// one is kept: copied into the slot's next frame ([`take_frame`]).
    fn copy(
        &self,
        s: &mut CameraSlot,
        left: &ImageMsg,
        right: &ImageMsg,
        stereo: &super::StereoCamera,
    ) -> Option<StereoFrame> {
        let pairs = self.pairs.lock().unwrap_or_else(PoisonError::into_inner);
        let p = pairs.iter().find(|p| {
            p.camera == s.name
                && p.stereo == *stereo
                && same_image(&p.left, left)
                && same_image(&p.right, right)
        })?;
        let mut frame = take_frame(s);
        frame.clone_from(&p.frame);
        Some(frame)
    }

    /// Keeps `frame`, extracted from `left` and `right` of `camera` with `stereo`, in
    /// place of that camera's previous pair.
    fn keep(
        &self,
        camera: &str,
        left: &ImageMsg,
        right: &ImageMsg,
        stereo: super::StereoCamera,
        frame: &StereoFrame,
    ) {
        let mut pairs = self.pairs.lock().unwrap_or_else(PoisonError::into_inner);
        match pairs.iter_mut().find(|p| p.camera == camera) {
            Some(p) => {
                p.left = left.clone();
                p.right = right.clone();
                p.stereo = stereo;
                p.frame.clone_from(frame);
            }
            None => pairs.push(SharedPair {
                camera: camera.to_string(),
                left: left.clone(),
                right: right.clone(),
                stereo,
                frame: frame.clone(),
            }),
        }
    }
}

/// Lets the SLAMs of one run (the SLAM and its baselines, [`SlamConfig::runs`]) that use
/// the same front-end settings share their stereo pairs: a pair one of them has
/// extracted is copied by the others that are given the same images (see
/// `SharedFrontEnd`), which saves the feature extraction and stereo matching of every
/// SLAM but the first. Their results are the same, bit for bit, as each extracting its
/// own.
pub fn share_front_ends(slams: &mut [VisualSlam]) {
    for i in 0..slams.len() {
        if slams[i].shared.is_some() {
            continue;
        }
        let features = slams[i].cfg.features.clone();
        let group: Vec<usize> = (i..slams.len())
            .filter(|&j| slams[j].shared.is_none() && slams[j].cfg.features == features)
            .collect();
        if group.len() < 2 {
            continue;
        }
        let shared = SharedFrontEnd {
            pairs: Arc::default(),
        };
        for j in group {
            slams[j].shared = Some(shared.clone());
        }
    }
}

/// A rig frame with its inputs fixed: the pairs it uses (moved out of their slots) and
/// their gyro rotations.
#[derive(Debug)]
struct RigFrame {
    stamp: Nanos,
    /// `(camera, pair stamp, features, rotation_from_frame)`.
    pairs: Vec<(usize, Nanos, StereoFrame, Option<UnitQuaternion<f64>>)>,
}

/// Tracks `frame` (if any) on `tracker` while `work` runs on the calling thread; both
/// are done when it returns. The frame's result comes back with the frame (for its
/// buffers).
fn track_during<R>(
    tracker: Option<&mut Tracker>,
    frame: Option<RigFrame>,
    work: impl FnOnce() -> R,
) -> (Option<(RigFrame, FrameResult)>, R) {
    let (Some(tracker), Some(frame)) = (tracker, frame) else {
        return (None, work());
    };
    let mut tracked = None;
    let r = rayon::in_place_scope(|scope| {
        scope.spawn(|_| {
            let result = track_frame(tracker, &frame);
            tracked = Some((frame, result));
        });
        work()
    });
    (tracked, r)
}

fn track_frame(tracker: &mut Tracker, frame: &RigFrame) -> FrameResult {
    let inputs: Vec<CameraInput> = frame
        .pairs
        .iter()
        .map(
            |(camera, stamp, features, rotation_from_frame)| CameraInput {
                camera: *camera,
                stamp: *stamp,
                features,
                rotation_from_frame: *rotation_from_frame,
            },
        )
        .collect();
    tracker.track(frame.stamp, &inputs)
}

/// The tag camera's input and the loop closer.
#[derive(Debug)]
struct TagSlot {
    image_topic: String,
    info_topic: String,
    info: Option<(TagCamera, Isometry3<f64>)>,
    detector: TagDetector,
    gray: GrayImage,
    /// Sightings waiting for the tracker to pass their stamp.
    pending: VecDeque<(Nanos, Vec<TagSighting>)>,
    closer: TagLoopCloser,
    images: usize,
    detections: usize,
}

impl VisualSlam {
    /// A SLAM over the cameras of `cfg`, with the robot's `/tf_static`, producing the
    /// estimate source `source`. `vocabulary` is needed (only) with
    /// `loop_closure.method = "bow"`.
    pub fn new(
        source: &'static str,
        cfg: SlamConfig,
        static_transforms: StaticTransforms,
        vocabulary: Option<Arc<Vocabulary>>,
    ) -> Result<Self, SlamError> {
        cfg.validate()?;
        let bow = if cfg.loop_closure.method == LoopMethod::Bow {
            let Some(vocabulary) = vocabulary else {
                return Err(ConfigError(
                    "slam.loop_closure.method = \"bow\" needs a vocabulary (slam.bow.vocabulary)"
                        .to_string(),
                )
                .into());
            };
            Some(BowLoopCloser::new(
                cfg.bow.clone(),
                cfg.loop_closure.clone(),
                cfg.features.stereo.max_depth_baselines,
                cfg.features.orb.scale_factor,
                vocabulary,
            )?)
        } else {
            None
        };
        let mut slots = Vec::with_capacity(cfg.cameras.len());
        for name in &cfg.cameras {
            let [left_topic, right_topic] = stereo_image_topics(name);
            slots.push(CameraSlot {
                name: name.clone(),
                left_topic,
                right_topic,
                left_info_topic: format!("/{name}/left/camera_info"),
                right_info_topic: format!("/{name}/right/camera_info"),
                front_end: StereoFrontEnd::new(cfg.features.clone())?,
                left: None,
                right: None,
                left_info: None,
                right_info: None,
                gray: (GrayImage::default(), GrayImage::default()),
                latest: None,
                spare: None,
                pairs: 0,
            });
        }
        let tags = if cfg.uses_tags() {
            let name = &cfg.tags.camera;
            Some(TagSlot {
                image_topic: format!("/{name}/color/image_raw"),
                info_topic: format!("/{name}/color/camera_info"),
                info: None,
                detector: TagDetector::new(cfg.tags.clone())?,
                gray: GrayImage::default(),
                pending: VecDeque::new(),
                closer: TagLoopCloser::new(cfg.loop_closure.clone())?,
                images: 0,
                detections: 0,
            })
        } else {
            None
        };
        Ok(VisualSlam {
            source,
            cfg,
            static_transforms,
            slots,
            tracker: None,
            frames: Vec::new(),
            busy_s: 0.0,
            tags,
            bow,
            gyro: GyroBuffer::default(),
            body_from_imu: None,
            pending: None,
            shared: None,
            shared_pairs: 0,
        })
    }

    /// The tracker, once every camera's calibration has been seen. With
    /// [`SlamConfig::pipeline`] the latest rig frame may still wait to be tracked (until
    /// the next image or [`VisualSlam::finish`]).
    pub fn tracker(&self) -> Option<&Tracker> {
        self.tracker.as_ref()
    }

    /// The estimate source this SLAM produces (`slam`, `slam_single_camera`, ...).
    pub fn source(&self) -> &'static str {
        self.source
    }

    /// The outcome of the newest tracked rig frame (its pose as tracked then, before any
    /// later optimisation), if any.
    pub fn last_frame(&self) -> Option<&FrameResult> {
        self.frames.last()
    }

    /// Takes one delivered message (others than the SLAM's are ignored).
    pub fn push(&mut self, msg: &Message) -> Result<(), SlamError> {
        match msg {
            Message::Image(img) => {
                let topic = img.topic.as_ref();
                if self.tags.as_ref().is_some_and(|t| topic == t.image_topic) {
                    let started = std::time::Instant::now();
                    let r = self.detect_tags(img);
                    self.busy_s += started.elapsed().as_secs_f64();
                    return r;
                }
                let Some((i, left)) = self.slots.iter().enumerate().find_map(|(i, s)| {
                    if topic == s.left_topic {
                        Some((i, true))
                    } else if topic == s.right_topic {
                        Some((i, false))
                    } else {
                        None
                    }
                }) else {
                    return Ok(());
                };
                let s = &mut self.slots[i];
                if left {
                    s.left = Some(img.clone());
                } else {
                    s.right = Some(img.clone());
                }
                let started = std::time::Instant::now();
                let r = self.try_pair(i);
                self.busy_s += started.elapsed().as_secs_f64();
                r
            }
            Message::CameraInfo(info) => {
                let topic = info.topic.as_ref();
                for s in &mut self.slots {
                    if topic == s.left_info_topic {
                        s.left_info = Some(info.clone());
                    } else if topic == s.right_info_topic {
                        s.right_info = Some(info.clone());
                    }
                }
                if let Some(t) = self.tags.as_mut()
                    && topic == t.info_topic
                    && t.info.is_none()
                {
                    let body_from_camera = self
                        .static_transforms
                        .body_from(info.frame_id.as_str())
                        .ok_or_else(|| SlamError::UnknownFrame {
                            camera: self.cfg.tags.camera.clone(),
                            frame: info.frame_id.as_str().to_string(),
                        })?;
                    let camera = TagCamera::from_info(info);
                    if !(camera.fx > 0.0 && camera.fy > 0.0) {
                        return Err(SlamError::CameraInfo {
                            topic: t.info_topic.clone(),
                            stamp: info.stamp,
                            problem: format!(
                                "field `k` = {:?} has no positive focal lengths",
                                info.k
                            ),
                        });
                    }
                    t.info = Some((camera, body_from_camera));
                }
                Ok(())
            }
            Message::Imu(imu) if self.cfg.use_gyro => {
                msg.validate()?;
                let body_from_imu = match self.body_from_imu {
                    Some(r) => r,
                    None => {
                        let frame = imu.frame_id.as_str();
                        let r = self
                            .static_transforms
                            .body_from(frame)
                            .ok_or_else(|| SlamError::UnknownImuFrame(frame.to_string()))?
                            .rotation;
                        *self.body_from_imu.insert(r)
                    }
                };
                self.gyro
                    .push(imu.stamp, body_from_imu * imu.angular_velocity);
                Ok(())
            }
            _ => Ok(()),
        }
    }

    /// Extracts camera `i`'s pair when both images of one stamp are in, and tracks a rig
    /// frame when `i` is the primary.
    fn try_pair(&mut self, i: usize) -> Result<(), SlamError> {
        let s = &mut self.slots[i];
        let (Some(l), Some(r)) = (&s.left, &s.right) else {
            return Ok(());
        };
        if l.stamp != r.stamp {
            // Keep the newer image; its partner is still on its way.
            if l.stamp < r.stamp {
                s.left = None;
            } else {
                s.right = None;
            }
            return Ok(());
        }
        let (Some(l), Some(r)) = (s.left.take(), s.right.take()) else {
            return Ok(());
        };
        if self.tracker.is_none() && !self.build_tracker()? {
            return Ok(());
        }
        let s = &mut self.slots[i];
        let stereo = stereo_camera(s);
        // Another SLAM of the run may have extracted these very images already.
        let copied = match (&self.shared, &stereo) {
            (Some(shared), Ok(stereo)) => shared.copy(s, &l, &r, stereo),
            _ => None,
        };
        let frame = match copied {
            Some(frame) => {
                self.shared_pairs += 1;
                self.track_waiting();
                frame
            }
            None => {
                let image_err = |m: &ImageMsg| {
                    let (topic, stamp) = (m.topic.to_string(), m.stamp);
                    move |source| SlamError::Image {
                        topic,
                        stamp,
                        source,
                    }
                };
                s.gray.0.set_from_msg(&l).map_err(image_err(&l))?;
                s.gray.1.set_from_msg(&r).map_err(image_err(&r))?;
                let stereo = stereo?;
                let mut frame = take_frame(s);
                let (front_end, gray) = (&mut s.front_end, &s.gray);
                let (tracked, ()) =
                    track_during(self.tracker.as_mut(), self.pending.take(), || {
                        front_end.process(&stereo, &gray.0, &gray.1, &mut frame)
                    });
                if let Some(shared) = &self.shared {
                    shared.keep(&s.name, &l, &r, stereo, &frame);
                }
                self.tracked(tracked);
                frame
            }
        };
        let s = &mut self.slots[i];
        s.latest = Some((l.stamp, frame, false));
        s.pairs += 1;
        if i == 0 {
            self.form_rig_frame(l.stamp);
        }
        Ok(())
    }

    /// Records a tracked rig frame's result, hands the tracker's news to the loop closers
    /// and gives the frame's buffers back to their slots.
    fn tracked(&mut self, tracked: Option<(RigFrame, FrameResult)>) {
        let Some((frame, result)) = tracked else {
            return;
        };
        self.frames.push(result);
        self.close_loops(frame.stamp);
        if let (Some(bow), Some(tracker)) = (self.bow.as_mut(), self.tracker.as_mut()) {
            bow.on_keyframes(tracker);
        }
        for (camera, _, features, _) in frame.pairs {
            self.slots[camera].spare.get_or_insert(features);
        }
    }

    /// Tracks the rig frame waiting in the pipeline now, if any (with
    /// [`SlamConfig::pipeline`] it would otherwise be tracked alongside the next image).
    /// The results are the same either way: only the overlap with the next image's
    /// feature extraction is lost. A closed loop steering on this SLAM calls it after
    /// every delivery, so that a frame's pose exists when its images have arrived.
    pub fn track_waiting(&mut self) {
        let (tracked, ()) = track_during(self.tracker.as_mut(), self.pending.take(), || ());
        self.tracked(tracked);
    }

    /// Builds the tracker once every camera's two `CameraInfo`s are known; `false` while
    /// some are missing.
    fn build_tracker(&mut self) -> Result<bool, SlamError> {
        let mut rig = Vec::with_capacity(self.slots.len());
        for s in &self.slots {
            let (Some(li), Some(_)) = (&s.left_info, &s.right_info) else {
                return Ok(false);
            };
            let body_from_camera = self
                .static_transforms
                .body_from(li.frame_id.as_str())
                .ok_or_else(|| SlamError::UnknownFrame {
                    camera: s.name.clone(),
                    frame: li.frame_id.as_str().to_string(),
                })?;
            let stereo = stereo_camera(s)?;
            let k = &li.k;
            if li.d.iter().any(|&d| d != 0.0) {
                return Err(SlamError::CameraInfo {
                    topic: s.left_info_topic.clone(),
                    stamp: li.stamp,
                    problem: format!(
                        "field `d` is {:?}; the SLAM needs rectified images (all zero)",
                        li.d
                    ),
                });
            }
            rig.push(TrackerCamera {
                camera: RigCamera {
                    fx: k[0],
                    fy: k[4],
                    cx: k[2],
                    cy: k[5],
                    body_from_camera,
                },
                baseline_m: stereo.baseline_m,
            });
        }
        self.tracker = Some(Tracker::new(
            self.cfg.tracking.clone(),
            &self.cfg.features.orb,
            rig,
        )?);
        Ok(true)
    }

    /// Forms the rig frame of the primary's pair at `stamp` and queues it for tracking
    /// (tracked at once without `pipeline`).
    fn form_rig_frame(&mut self, stamp: Nanos) {
        if self.tracker.is_none() {
            return;
        }
        let max_offset = Nanos::from_secs_f64(self.cfg.max_camera_offset_s);
        let mut pairs = Vec::with_capacity(self.slots.len());
        for (camera, s) in self.slots.iter_mut().enumerate() {
            if let Some((t, frame, used)) = s.latest.as_mut()
                && !*used
                && Nanos((*t - stamp).0.abs()) <= max_offset
            {
                *used = true;
                let rotation_from_frame = (self.cfg.use_gyro && *t != stamp)
                    .then(|| self.gyro.rotation(stamp, *t))
                    .flatten();
                pairs.push((camera, *t, std::mem::take(frame), rotation_from_frame));
            }
        }
        // The previous frame is always tracked by now (every image tracks it alongside).
        self.track_waiting();
        self.pending = Some(RigFrame { stamp, pairs });
        if !self.cfg.pipeline {
            self.track_waiting();
        }
    }

    /// Detects tags in a tag-camera image; the sightings wait for the tracker to pass
    /// their stamp.
    fn detect_tags(&mut self, img: &ImageMsg) -> Result<(), SlamError> {
        let Some(t) = self.tags.as_mut() else {
            return Ok(());
        };
        let Some((camera, _)) = &t.info else {
            return Ok(());
        };
        t.gray
            .set_from_msg(img)
            .map_err(|source| SlamError::Image {
                topic: img.topic.to_string(),
                stamp: img.stamp,
                source,
            })?;
        let (detector, gray) = (&mut t.detector, &t.gray);
        let (tracked, sightings) = track_during(self.tracker.as_mut(), self.pending.take(), || {
            detector.detect(gray, camera)
        });
        // The tracked frame's loops first: these sightings come after it.
        self.tracked(tracked);
        let Some(t) = self.tags.as_mut() else {
            return Ok(());
        };
        t.images += 1;
        t.detections += sightings.len();
        if !sightings.is_empty() {
            t.pending.push_back((img.stamp, sightings));
        }
        Ok(())
    }

    /// Hands the pending sightings stamped up to `tracked` to the loop closer.
    fn close_loops(&mut self, tracked: Nanos) {
        let (Some(t), Some(tracker)) = (self.tags.as_mut(), self.tracker.as_mut()) else {
            return;
        };
        let Some((camera, body_from_camera)) = t.info else {
            return;
        };
        let size_m = self.cfg.tags.size_m;
        let var = self.cfg.loop_closure.tag_corner_sigma_px.powi(2);
        while let Some((stamp, _)) = t.pending.front() {
            if *stamp > tracked {
                break;
            }
            let Some((stamp, sightings)) = t.pending.pop_front() else {
                break;
            };
            for s in &sightings {
                let covariance = tag_pose_information(&camera, size_m, &s.camera_from_tag)
                    .and_then(|m| m.try_inverse())
                    .map(|c| c * var);
                t.closer
                    .on_sighting(tracker, stamp, s, &body_from_camera, covariance);
            }
        }
    }

    /// The run's trajectory, losses and counters.
    pub fn finish(mut self) -> SlamOutput {
        self.track_waiting();
        let pairs = self
            .slots
            .iter()
            .map(|s| (s.name.clone(), s.pairs))
            .collect();
        let Some(tracker) = self.tracker else {
            return SlamOutput {
                source: self.source,
                trajectory: Trajectory::new(),
                frames: self.frames,
                losses: Vec::new(),
                stats: TrackerStats::default(),
                pairs,
                shared_pairs: self.shared_pairs,
                landmarks: 0,
                loops: Vec::new(),
                loop_stats: LoopStats::default(),
                tag_images: self.tags.as_ref().map_or(0, |t| t.images),
                tag_detections: self.tags.as_ref().map_or(0, |t| t.detections),
                bow_stats: self.bow.as_ref().map(|b| b.stats().clone()),
                keyframe_descriptors: Vec::new(),
                wall_s: self.busy_s,
            };
        };
        let mut trajectory = Trajectory::new();
        for (stamp, world_from_body) in tracker.trajectory() {
            trajectory.push(PoseSample {
                stamp,
                world_from_body,
                covariance: None,
            });
        }
        SlamOutput {
            source: self.source,
            trajectory,
            frames: self.frames,
            losses: tracker.losses().to_vec(),
            stats: tracker.stats().clone(),
            pairs,
            shared_pairs: self.shared_pairs,
            landmarks: tracker.map().n_live_landmarks(),
            loops: match (&self.tags, &self.bow) {
                (Some(t), _) => t.closer.loops().to_vec(),
                (None, Some(b)) => b.loops().to_vec(),
                (None, None) => Vec::new(),
            },
            loop_stats: self
                .tags
                .as_ref()
                .map(|t| t.closer.stats().clone())
                .unwrap_or_default(),
            tag_images: self.tags.as_ref().map_or(0, |t| t.images),
            tag_detections: self.tags.as_ref().map_or(0, |t| t.detections),
            bow_stats: self.bow.as_ref().map(|b| b.stats().clone()),
            keyframe_descriptors: tracker
                .map()
                .keyframes
                .iter()
                .map(|k| k.descriptors().collect())
                .collect(),
            wall_s: self.busy_s,
        }
    }
}

/// A frame to extract camera slot `s`'s next pair into: the latest pair's if no rig frame
/// used it (it is replaced), else the spare one.
fn take_frame(s: &mut CameraSlot) -> StereoFrame {
    match s.latest.take() {
        Some((_, f, false)) => f,
        _ => s.spare.take().unwrap_or_default(),
    }
}

/// The rectified stereo geometry of a slot from its right `CameraInfo`.
fn stereo_camera(s: &CameraSlot) -> Result<super::StereoCamera, SlamError> {
    let Some(ri) = &s.right_info else {
        return Err(SlamError::CameraInfo {
            topic: s.right_info_topic.clone(),
            stamp: Nanos(0),
            problem: "no right camera_info received".to_string(),
        });
    };
    super::StereoCamera::from_right_info(ri)
        .filter(|c| c.baseline_m > 0.0 && c.fx > 0.0)
        .ok_or_else(|| SlamError::CameraInfo {
            topic: s.right_info_topic.clone(),
            stamp: ri.stamp,
            problem: format!(
                "field `p` = {:?} gives no positive baseline (expected p[3] = -fx·baseline)",
                ri.p
            ),
        })
}

impl SlamOutput {
    /// A SLAM metric by its expectation name (see `crate::expect::SLAM_METRICS`).
    pub fn metric(&self, name: &str) -> Option<f64> {
        let end = self.frames.last().map(|f| f.stamp);
        Some(match name {
            "tracking_losses" => self.losses.len() as f64,
            "tracking_lost_s" => {
                self.losses
                    .iter()
                    .map(|l| match l.end.or(end) {
                        Some(e) => (e - l.start).as_secs_f64().max(0.0),
                        None => 0.0,
                    })
                    // An empty f64 sum is -0.0; + 0.0 makes it 0.0.
                    .sum::<f64>()
                    + 0.0
            }
            "keyframes" => self.stats.keyframes as f64,
            "maps_started" => self.stats.initializations as f64,
            "bow_candidates" => self.bow_stats.as_ref()?.candidates as f64,
            "bow_rejected" => {
                let b = self.bow_stats.as_ref()?;
                (b.rejected_ransac + b.rejected_ba) as f64
            }
            _ => return None,
        })
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use nalgebra::Isometry3;
    use std::sync::Arc;
    use vinebench_msgs::{FrameId, ImageEncoding};

    const FX: f64 = 300.0;

    fn info(topic: &str, frame: &str, p3: f64) -> Message {
        Message::CameraInfo(CameraInfoMsg {
            stamp: Nanos(5),
            topic: Arc::from(topic),
            frame_id: FrameId::new(frame),
            width: 64,
            height: 48,
            d: [0.0; 5],
            k: [FX, 0.0, 32.0, 0.0, FX, 24.0, 0.0, 0.0, 1.0],
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: [FX, 0.0, 32.0, p3, 0.0, FX, 24.0, 0.0, 0.0, 0.0, 1.0, 0.0],
        })
    }

    fn image(topic: &str, stamp: i64, len: usize) -> Message {
        Message::Image(ImageMsg {
            stamp: Nanos(stamp),
            topic: Arc::from(topic),
            frame_id: FrameId::new("front_left"),
            width: 64,
            height: 48,
            encoding: ImageEncoding::Mono8,
            data: vec![128u8; len].into(),
        })
    }

    fn slam() -> VisualSlam {
        let mut tf = StaticTransforms::new("base_link");
        tf.insert("front_left", Isometry3::identity());
        let cfg = SlamConfig {
            enabled: true,
            cameras: vec!["front".to_string()],
            ..SlamConfig::default()
        };
        VisualSlam::new(SLAM_SOURCE, cfg, tf, None).unwrap()
    }

    #[test]
    fn defaults_toml_documents_the_default_config() {
        // `[slam]` of scenarios/defaults.toml and `SlamConfig::default()` say the same.
        let from_file: SlamConfig = vinebench_msgs::defaults::section("slam").unwrap();
        assert_eq!(from_file, SlamConfig::default());
    }

    #[test]
    fn a_right_camera_info_without_a_baseline_is_an_error_naming_topic_and_field() {
        let mut v = slam();
        v.push(&info("/front/left/camera_info", "front_left", 0.0))
            .unwrap();
        v.push(&info("/front/right/camera_info", "front_right", 0.0))
            .unwrap();
        v.push(&image("/front/left/image_rect_color", 7, 64 * 48))
            .unwrap();
        let e = v
            .push(&image("/front/right/image_rect_color", 7, 64 * 48))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("/front/right/camera_info") && e.contains("field `p`"),
            "{e}"
        );
    }

    #[test]
    fn a_truncated_image_is_an_error_naming_its_topic() {
        let mut v = slam();
        v.push(&info("/front/left/camera_info", "front_left", -FX * 0.12))
            .unwrap();
        v.push(&info("/front/right/camera_info", "front_right", -FX * 0.12))
            .unwrap();
        v.push(&image("/front/left/image_rect_color", 7, 10))
            .unwrap();
        let e = v
            .push(&image("/front/right/image_rect_color", 7, 64 * 48))
            .unwrap_err()
            .to_string();
        assert!(e.contains("/front/left/image_rect_color"), "{e}");
    }

    #[test]
    fn pairs_are_made_by_stamp_and_other_topics_ignored() {
        let mut v = slam();
        v.push(&info("/front/left/camera_info", "front_left", -FX * 0.12))
            .unwrap();
        v.push(&info("/front/right/camera_info", "front_right", -FX * 0.12))
            .unwrap();
        v.push(&image("/rear/left/image_rect_color", 7, 3)).unwrap();
        v.push(&image("/front/left/image_rect_color", 7, 64 * 48))
            .unwrap();
        // A right image of another stamp does not pair; the newer one waits.
        v.push(&image("/front/right/image_rect_color", 9, 64 * 48))
            .unwrap();
        v.push(&image("/front/left/image_rect_color", 9, 64 * 48))
            .unwrap();
        let out = v.finish();
        assert_eq!(out.pairs, vec![("front".to_string(), 1)]);
        // A flat image has no features: no map yet, no pose.
        assert_eq!(out.frames.len(), 1);
        assert!(out.trajectory.samples.is_empty());
        assert_eq!(
            out.frames[0].state,
            super::super::TrackingState::NotInitialized
        );
    }

    #[test]
    fn an_unknown_camera_frame_is_an_error() {
        let mut v = slam();
        v.push(&info("/front/left/camera_info", "nowhere", -FX * 0.12))
            .unwrap();
        v.push(&info("/front/right/camera_info", "front_right", -FX * 0.12))
            .unwrap();
        v.push(&image("/front/left/image_rect_color", 7, 64 * 48))
            .unwrap();
        let e = v
            .push(&image("/front/right/image_rect_color", 7, 64 * 48))
            .unwrap_err()
            .to_string();
        assert!(e.contains("`nowhere`") && e.contains("/tf_static"), "{e}");
    }
}
