//! Loop closure at AprilTags (Kokas et al., "Loop closure"): the side camera's tag
//! sightings, placed in the map through the tracked pose at their stamp.
//!
//! The first usable sighting of a tag **registers** it: its pose is stored relative to the
//! keyframe of that moment (`keyframe_from_tag`), so it moves with every later correction
//! of that keyframe, and so is every further sighting of that first visit (until the robot
//! has gone `min_path_m` on). A sighting after the robot has travelled at least
//! `min_path_m` (along the keyframes) since the registration, or since the last loop at
//! that tag, is a **loop** when the body pose it gives is within
//! `max_tag_loop_distance_m` of the body at a registering sighting: the nearest one and
//! the current view of the tag say where the current keyframe is, relative to that
//! sighting's keyframe (a tag seen again from across the headland is a valid constraint
//! too, but between poses whose views hardly overlap, and not the revisit a loop stands
//! for; such a sighting waits for a nearer one). That relative pose is a loop edge of a
//! pose graph over all keyframes (consecutive keyframes joined by their current relative
//! poses), whose solution moves every keyframe; each landmark moves with the keyframe that
//! created it; both keyframes of the loop are anchored; then global BA refines all
//! keyframes and landmarks, and tracking also searches the matched place's landmarks for
//! a while, so the two passes share landmarks. A tag's identity is unambiguous, so no
//! appearance check is needed: a sighting is only accepted when the tag is close enough
//! and its pose fits its corners ([`super::tags::TagConfig`]).
//!
//! A registered tag never fixes the SLAM's `world` to a surveyed one: the SLAM's world is
//! its first body pose, and tags with surveyed poses would need that alignment first.

use super::pose_graph::{PoseGraph, PoseGraphConfig, PoseGraphEdge, relative_error};
use super::tags::TagSighting;
use super::tracking::{BundleOutcome, Tracker};
use super::{ConfigError, check};
use nalgebra::{Isometry3, Matrix6, UnitQuaternion, Vector3, Vector6};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use vinebench_msgs::Nanos;

/// `[slam.loop_closure]` of a scenario.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct LoopConfig {
    /// How loops are found: `tags` (the side camera's AprilTags, see `[slam.tags]`),
    /// `bow` (bag-of-words place recognition, see `[slam.bow]`) or `none`.
    pub method: LoopMethod,
    /// Path length along the keyframes since a tag's registration (or its last loop)
    /// before a sighting of it closes a loop, m; bag-of-words candidates must lie at least
    /// this far back along the path.
    pub min_path_m: f64,
    /// A tag sighting closes a loop only when the body pose it gives lies within this
    /// distance of the body at one of the tag's registering sightings (every sighting of
    /// the first visit is kept, and the nearest one is the loop's other end), m: a loop
    /// joins two nearby poses, whose views overlap, as the scoring's
    /// `scoring.loop_distance_m` expects; a sighting from farther waits for a nearer one.
    pub max_tag_loop_distance_m: f64,
    /// Largest gap between the two tracked frames a sighting's stamp is interpolated
    /// between, s.
    pub max_pose_gap_s: f64,
    /// Standard deviation of the relative pose of consecutive keyframes in the pose
    /// graph: translation, m.
    pub odometry_sigma_m: f64,
    /// The same, rotation, rad.
    pub odometry_sigma_rad: f64,
    /// Corner noise of a tag sighting, px: the loop edge's information is propagated
    /// from both sightings' corner geometry with it.
    pub tag_corner_sigma_px: f64,
    /// Standard deviation added to a tag loop edge on top of the propagated one (tag
    /// placement, pose interpolation), or its whole uncertainty when none is known:
    /// translation, m.
    pub tag_sigma_m: f64,
    /// The same, rotation, rad.
    pub tag_sigma_rad: f64,
    /// Tags whose world pose is known (surveyed). The first sighting of any of them is the
    /// survey anchor; a later sighting of another one, after `min_path_m` of travel since
    /// the anchor (or the last such loop), is tied to the anchor through the two surveyed
    /// poses: a loop edge wherever the two tags stand, no return to a place needed (the
    /// paper's re-localization at a tag of known pose).
    pub surveyed_tags: Vec<SurveyedTag>,
    /// Fill `surveyed_tags` from the simulated world's tag boards, each pose perturbed by
    /// `survey_sigma_*` noise drawn from the scenario's seed (a simulated survey; the
    /// runner does it, the SLAM only sees the list).
    pub survey_world_tags: bool,
    /// Standard deviation of a surveyed tag position, m.
    pub survey_sigma_m: f64,
    /// The same, of its orientation, rad.
    pub survey_sigma_rad: f64,
    /// Run global BA after the pose graph.
    pub global_ba: bool,
    /// Iterations of its robust round.
    pub global_ba_iterations: usize,
}

impl Default for LoopConfig {
    fn default() -> Self {
        LoopConfig {
            method: LoopMethod::Tags,
            min_path_m: 5.0,
            max_tag_loop_distance_m: 1.0,
            max_pose_gap_s: 0.25,
            odometry_sigma_m: 0.01,
            odometry_sigma_rad: 0.005,
            tag_corner_sigma_px: 0.3,
            tag_sigma_m: 0.002,
            tag_sigma_rad: 0.002,
            surveyed_tags: Vec::new(),
            survey_world_tags: false,
            survey_sigma_m: 0.01,
            survey_sigma_rad: 0.005,
            global_ba: true,
            global_ba_iterations: 30,
        }
    }
}

impl LoopConfig {
    /// Checks every range.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let positive = |v: f64| v.is_finite() && v > 0.0;
        check(
            self.min_path_m.is_finite() && self.min_path_m >= 0.0,
            "slam.loop_closure.min_path_m must be a non-negative number",
        )?;
        check(
            positive(self.max_tag_loop_distance_m),
            "slam.loop_closure.max_tag_loop_distance_m must be positive",
        )?;
        check(
            positive(self.max_pose_gap_s),
            "slam.loop_closure.max_pose_gap_s must be positive",
        )?;
        for (v, name) in [
            (self.odometry_sigma_m, "odometry_sigma_m"),
            (self.odometry_sigma_rad, "odometry_sigma_rad"),
            (self.tag_sigma_m, "tag_sigma_m"),
            (self.tag_corner_sigma_px, "tag_corner_sigma_px"),
            (self.tag_sigma_rad, "tag_sigma_rad"),
            (self.survey_sigma_m, "survey_sigma_m"),
            (self.survey_sigma_rad, "survey_sigma_rad"),
        ] {
            check(
                positive(v),
                &format!("slam.loop_closure.{name} must be positive"),
            )?;
        }
        for (i, t) in self.surveyed_tags.iter().enumerate() {
            check(
                t.position_m.iter().chain(&t.rpy_deg).all(|v| v.is_finite()),
                &format!(
                    "slam.loop_closure.surveyed_tags[{i}]: position_m and rpy_deg must be \
                     finite numbers"
                ),
            )?;
            check(
                !self.surveyed_tags[..i].iter().any(|o| o.id == t.id),
                &format!(
                    "slam.loop_closure.surveyed_tags[{i}]: tag {} is surveyed twice",
                    t.id
                ),
            )?;
        }
        check(
            (1..=500).contains(&self.global_ba_iterations),
            "slam.loop_closure.global_ba_iterations must be in [1, 500]",
        )
    }
}

/// A tag of known world pose (`[[slam.loop_closure.surveyed_tags]]`).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SurveyedTag {
    /// Tag id (tag36h11).
    pub id: u32,
    /// The tag centre in `world` (local East-North-Up), m.
    pub position_m: [f64; 3],
    /// The tag frame's orientation in `world` (AprilTag convention: x right and y down
    /// as printed, z into the board) as roll, pitch, yaw about world x, y, z, deg.
    pub rpy_deg: [f64; 3],
}

impl SurveyedTag {
    /// `world_from_tag`.
    pub fn world_from_tag(&self) -> Isometry3<f64> {
        let [x, y, z] = self.position_m;
        let [r, p, w] = self.rpy_deg.map(f64::to_radians);
        Isometry3::from_parts(
            nalgebra::Translation3::new(x, y, z),
            UnitQuaternion::from_euler_angles(r, p, w),
        )
    }

    /// The entry of tag `id` at `world_from_tag`.
    pub fn from_pose(id: u32, world_from_tag: &Isometry3<f64>) -> SurveyedTag {
        let (r, p, w) = world_from_tag.rotation.euler_angles();
        let t = world_from_tag.translation.vector;
        SurveyedTag {
            id,
            position_m: [t.x, t.y, t.z],
            rpy_deg: [r, p, w].map(f64::to_degrees),
        }
    }
}

/// How a SLAM finds loops.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LoopMethod {
    /// No loop closure (odometry only).
    None,
    /// AprilTags seen again by the tag camera.
    Tags,
    /// Bag-of-words place recognition with a geometric check
    /// ([`super::place_recognition`]).
    Bow,
}

/// What found a loop.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LoopSource {
    /// A registered AprilTag seen again.
    Tag,
    /// A surveyed AprilTag tied to the survey anchor through their known poses.
    TagSurvey,
    /// Bag-of-words place recognition.
    Bow,
}

impl LoopSource {
    /// Its name in `loops.csv`.
    pub fn name(self) -> &'static str {
        match self {
            LoopSource::Tag => "tag",
            LoopSource::TagSurvey => "tag_survey",
            LoopSource::Bow => "bow",
        }
    }
}

/// One accepted loop closure.
#[derive(Clone, Debug, PartialEq)]
pub struct LoopClosure {
    /// When the place was recognized (the sighting's stamp).
    pub query_stamp: Nanos,
    /// When the matched place was seen before (the registering sighting's stamp).
    pub matched_stamp: Nanos,
    /// What found it.
    pub source: LoopSource,
    /// The tag, for a tag loop.
    pub tag_id: Option<u32>,
    /// The current keyframe and the matched one.
    pub query_keyframe: u32,
    /// The keyframe of the matched place.
    pub matched_keyframe: u32,
    /// The loop's claim: the body at `query_stamp` relative to the body at
    /// `matched_stamp` (`body(matched)_from_body(query)`), when the loop gives one
    /// between those stamps (tag loops).
    pub matched_from_query: Option<Isometry3<f64>>,
    /// How far the loop moved the current keyframe, m.
    pub correction_m: f64,
    /// How far it turned it, deg.
    pub correction_deg: f64,
    /// Pose-graph cost before and after.
    pub pose_graph_cost: (f64, f64),
    /// The global BA that followed, if any ran.
    pub global_ba: Option<BundleOutcome>,
    /// Wall-clock seconds spent closing it (for the report, never for results).
    pub wall_s: f64,
}

/// A registered tag.
#[derive(Clone, Debug)]
struct TagRecord {
    /// The sightings of the first visit (up to [`MAX_REGISTERED_SIGHTINGS`]).
    sightings: Vec<StoredSighting>,
    /// Path length at the registration, m.
    registered_path_m: f64,
    /// Path length at the registration or the last loop, m.
    path_m: f64,
}

/// A sighting kept relative to its keyframe.
#[derive(Clone, Debug)]
struct StoredSighting {
    keyframe: u32,
    keyframe_from_body: Isometry3<f64>,
    keyframe_from_camera: Isometry3<f64>,
    camera_from_tag: Isometry3<f64>,
    /// Covariance of the sighting's `camera_from_tag` over `(δω, δt)`, if known.
    covariance: Option<Matrix6<f64>>,
    stamp: Nanos,
}

/// Sightings kept from a tag's first visit.
const MAX_REGISTERED_SIGHTINGS: usize = 64;

/// Counters of the tag loop closer.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct LoopStats {
    /// Sightings used (tracked pose available).
    pub sightings: usize,
    /// Sightings dropped because no tracked pose was known at their stamp.
    pub sightings_without_pose: usize,
    /// Tags registered.
    pub tags_registered: usize,
    /// Sightings that would have closed a loop but gave a pose farther than
    /// `max_tag_loop_distance_m` from every registering sighting.
    pub sightings_too_far: usize,
    /// Loops through the survey (`surveyed_tags`).
    pub survey_loops: usize,
}

/// Registers tags and closes loops at them (see the module docs).
#[derive(Clone, Debug)]
pub struct TagLoopCloser {
    cfg: LoopConfig,
    /// `world_from_tag` of the surveyed tags.
    surveyed: BTreeMap<u32, Isometry3<f64>>,
    /// The first surveyed tag seen (its id), and the path length at its first sighting
    /// or at the last survey loop, m.
    anchor: Option<(u32, f64)>,
    /// The nearest sighting so far of the surveyed tag being passed, waiting for the
    /// robot to pass its closest approach: the sighting, as stored, its distance to the
    /// tag (m) and the path length at it (m).
    survey_candidate: Option<(TagSighting, StoredSighting, f64, f64)>,
    tags: BTreeMap<u32, TagRecord>,
    loops: Vec<LoopClosure>,
    stats: LoopStats,
}

impl TagLoopCloser {
    /// A loop closer with a validated `cfg`.
    pub fn new(cfg: LoopConfig) -> Result<TagLoopCloser, ConfigError> {
        cfg.validate()?;
        Ok(TagLoopCloser {
            surveyed: cfg
                .surveyed_tags
                .iter()
                .map(|t| (t.id, t.world_from_tag()))
                .collect(),
            anchor: None,
            survey_candidate: None,
            cfg,
            tags: BTreeMap::new(),
            loops: Vec::new(),
            stats: LoopStats::default(),
        })
    }

    /// Accepted loops so far.
    pub fn loops(&self) -> &[LoopClosure] {
        &self.loops
    }

    /// Counters.
    pub fn stats(&self) -> &LoopStats {
        &self.stats
    }

    /// Takes a sighting made at `stamp` by a camera at `body_from_camera`; registers the
    /// tag, closes a loop (returning it) or does nothing. The tracker must have tracked
    /// past `stamp`. `covariance` is that of the sighting's `camera_from_tag` over the
    /// perturbation `(δω, δt)` of [`super::tags::tag_pose_information`]; with it the loop
    /// edge's information is propagated from both sightings (plus `tag_sigma_*` as a
    /// floor), without it the edge has `tag_sigma_*` alone.
    pub fn on_sighting(
        &mut self,
        tracker: &mut Tracker,
        stamp: Nanos,
        sighting: &TagSighting,
        body_from_camera: &Isometry3<f64>,
        covariance: Option<Matrix6<f64>>,
    ) -> Option<&LoopClosure> {
        let gap = Nanos::from_secs_f64(self.cfg.max_pose_gap_s);
        let Some((keyframe, keyframe_from_body)) = tracker.pose_at(stamp, gap) else {
            self.stats.sightings_without_pose += 1;
            return None;
        };
        self.stats.sightings += 1;
        let keyframe_from_camera = keyframe_from_body * body_from_camera;
        let path_m = path_length_to(tracker, keyframe);
        let stored = StoredSighting {
            keyframe,
            keyframe_from_body,
            keyframe_from_camera,
            camera_from_tag: sighting.camera_from_tag,
            covariance,
            stamp,
        };
        if self.surveyed.contains_key(&sighting.id) {
            match self.anchor {
                None => self.anchor = Some((sighting.id, path_m)),
                Some((id, at_m)) if id != sighting.id && path_m - at_m >= self.cfg.min_path_m => {
                    // The sighting nearest the tag: the loop waits until the robot has
                    // passed its closest approach (the first sightings are oblique and
                    // far, at the edge of the view).
                    let distance = sighting.camera_from_tag.translation.vector.norm();
                    match &self.survey_candidate {
                        Some((c, _, d, _)) if c.id == sighting.id && distance >= *d => {
                            let (c, stored, _, path_m) = self.survey_candidate.take()?;
                            return self.survey_loop(tracker, &c, stored, path_m);
                        }
                        _ => {
                            self.survey_candidate =
                                Some((sighting.clone(), stored.clone(), distance, path_m));
                        }
                    }
                }
                _ => {}
            }
        }
        let Some(record) = self.tags.get_mut(&sighting.id) else {
            self.tags.insert(
                sighting.id,
                TagRecord {
                    sightings: vec![stored],
                    registered_path_m: path_m,
                    path_m,
                },
            );
            self.stats.tags_registered += 1;
            return None;
        };
        if path_m - record.path_m < self.cfg.min_path_m {
            if path_m - record.registered_path_m < self.cfg.min_path_m
                && record.sightings.len() < MAX_REGISTERED_SIGHTINGS
            {
                record.sightings.push(stored);
            }
            return None;
        }
        // The registering sighting nearest to where this one puts the body.
        let body_a_from_body_b = |r: &StoredSighting| {
            r.keyframe_from_body.inverse()
                * r.keyframe_from_camera
                * r.camera_from_tag
                * (keyframe_from_camera * sighting.camera_from_tag).inverse()
                * keyframe_from_body
        };
        let (distance, record) = record
            .sightings
            .iter()
            .map(|r| (body_a_from_body_b(r).translation.vector.norm(), r))
            .min_by(|x, y| x.0.total_cmp(&y.0))?;
        if distance > self.cfg.max_tag_loop_distance_m {
            self.stats.sightings_too_far += 1;
            return None;
        }
        let started = std::time::Instant::now();
        let (a, b) = (record.keyframe, keyframe);
        // Where the registered tag says keyframe b is, relative to keyframe a.
        let edge = |n1: &Vector6<f64>, n2: &Vector6<f64>| {
            (record.keyframe_from_camera * perturbed(&record.camera_from_tag, n1))
                * (keyframe_from_camera * perturbed(&sighting.camera_from_tag, n2)).inverse()
        };
        let a_from_b = edge(&Vector6::zeros(), &Vector6::zeros());
        let floor = info(self.cfg.tag_sigma_m, self.cfg.tag_sigma_rad)
            .try_inverse()
            .unwrap_or_else(Matrix6::zeros);
        let tag_information = match (record.covariance, covariance) {
            (Some(c1), Some(c2)) => edge_information(&edge, &a_from_b, &c1, &c2, &floor),
            _ => None,
        }
        .unwrap_or_else(|| info(self.cfg.tag_sigma_m, self.cfg.tag_sigma_rad));
        let matched_stamp = record.stamp;
        let matched_from_query = body_a_from_body_b(record);
        let applied = apply_loop(tracker, &self.cfg, a, b, a_from_b, tag_information)?;
        if let Some(r) = self.tags.get_mut(&sighting.id) {
            r.path_m = path_m;
        }
        self.loops.push(applied.record(
            LoopSource::Tag,
            Some(sighting.id),
            (stamp, b),
            (matched_stamp, a),
            Some(matched_from_query),
            started,
        ));
        self.loops.last()
    }

    /// The loop from the survey anchor to `current`, a sighting of a surveyed tag (see
    /// [`LoopConfig::surveyed_tags`]); the anchor's end is its tag's first-visit sighting
    /// nearest the tag.
    fn survey_loop(
        &mut self,
        tracker: &mut Tracker,
        sighting: &TagSighting,
        current: StoredSighting,
        path_m: f64,
    ) -> Option<&LoopClosure> {
        let (anchor_id, _) = self.anchor?;
        let world_from_anchor_tag = *self.surveyed.get(&anchor_id)?;
        let world_from_tag = *self.surveyed.get(&sighting.id)?;
        let anchor = self
            .tags
            .get(&anchor_id)?
            .sightings
            .iter()
            .min_by(|a, b| {
                let d = |s: &StoredSighting| s.camera_from_tag.translation.vector.norm();
                d(a).total_cmp(&d(b))
            })?
            .clone();
        let started = std::time::Instant::now();
        let anchor_tag_from_tag = world_from_anchor_tag.inverse() * world_from_tag;
        // Where the two surveyed tags say keyframe b is, relative to keyframe a.
        let edge = |n1: &Vector6<f64>, n2: &Vector6<f64>| {
            (anchor.keyframe_from_camera * perturbed(&anchor.camera_from_tag, n1))
                * anchor_tag_from_tag
                * (current.keyframe_from_camera * perturbed(&current.camera_from_tag, n2)).inverse()
        };
        let a_from_b = edge(&Vector6::zeros(), &Vector6::zeros());
        let (a, b) = (anchor.keyframe, current.keyframe);
        // Both surveyed poses' uncertainty on top of the sightings': a surveyed
        // orientation error turns the vector between the tags, so it also moves the far
        // end by the angle times that lever.
        let (sm, sr) = (self.cfg.survey_sigma_m, self.cfg.survey_sigma_rad);
        let lever_m = anchor_tag_from_tag.translation.vector.norm();
        let survey_sigma_m = (2.0 * (sm * sm + (sr * lever_m).powi(2))).sqrt();
        let floor = (info(self.cfg.tag_sigma_m, self.cfg.tag_sigma_rad)
            .try_inverse()
            .unwrap_or_else(Matrix6::zeros))
            + info(survey_sigma_m, std::f64::consts::SQRT_2 * sr)
                .try_inverse()
                .unwrap_or_else(Matrix6::zeros);
        let information = match (anchor.covariance, current.covariance) {
            (Some(c1), Some(c2)) => edge_information(&edge, &a_from_b, &c1, &c2, &floor),
            _ => None,
        }
        .or_else(|| floor.try_inverse())?;
        let query_stamp = current.stamp;
        let matched_from_query =
            anchor.keyframe_from_body.inverse() * a_from_b * current.keyframe_from_body;
        let applied = apply_loop(tracker, &self.cfg, a, b, a_from_b, information)?;
        if let Some(x) = self.anchor.as_mut() {
            x.1 = path_m;
        }
        // The tag is registered too (for its own revisits), from this sighting.
        self.tags.entry(sighting.id).or_insert(TagRecord {
            sightings: vec![current],
            registered_path_m: path_m,
            path_m,
        });
        self.stats.survey_loops += 1;
        self.loops.push(applied.record(
            LoopSource::TagSurvey,
            Some(sighting.id),
            (query_stamp, b),
            (anchor.stamp, a),
            Some(matched_from_query),
            started,
        ));
        self.loops.last()
    }
}

/// What [`apply_loop`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct AppliedLoop {
    /// How far the loop moved keyframe `b`, m.
    pub correction_m: f64,
    /// How far it turned it, deg.
    pub correction_deg: f64,
    /// Pose-graph cost before and after.
    pub pose_graph_cost: (f64, f64),
    /// The global BA that followed, if any ran.
    pub global_ba: Option<BundleOutcome>,
}

impl AppliedLoop {
    /// The record of this loop, found by `source` (`tag_id` for a tag loop): `query` and
    /// `matched` are the stamps and keyframes of its two ends, `matched_from_query` its
    /// claim (see [`LoopClosure`]), `started` when closing it began.
    pub fn record(
        self,
        source: LoopSource,
        tag_id: Option<u32>,
        query: (Nanos, u32),
        matched: (Nanos, u32),
        matched_from_query: Option<Isometry3<f64>>,
        started: std::time::Instant,
    ) -> LoopClosure {
        LoopClosure {
            query_stamp: query.0,
            matched_stamp: matched.0,
            source,
            tag_id,
            query_keyframe: query.1,
            matched_keyframe: matched.1,
            matched_from_query,
            correction_m: self.correction_m,
            correction_deg: self.correction_deg,
            pose_graph_cost: self.pose_graph_cost,
            global_ba: self.global_ba,
            wall_s: started.elapsed().as_secs_f64(),
        }
    }
}

/// Closes a loop whatever found it: the measured `a_from_b` between keyframes `a` and
/// `b` (with its `information`, translation then rotation) joins a pose graph over all
/// keyframes (the first fixed, consecutive ones joined by their current relative poses
/// with the `odometry_sigma_*` of `cfg`); its solution moves every keyframe, each
/// landmark moves with the keyframe that created it, both keyframes are anchored, global
/// BA runs (if configured) and tracking searches the landmarks around `a` for a while.
/// `None` (and nothing changed) when the pose graph cannot be solved.
pub fn apply_loop(
    tracker: &mut Tracker,
    cfg: &LoopConfig,
    a: u32,
    b: u32,
    a_from_b: Isometry3<f64>,
    information: Matrix6<f64>,
) -> Option<AppliedLoop> {
    let map = tracker.map_mut();
    let before: Vec<Isometry3<f64>> = map.keyframes.iter().map(|k| k.world_from_body).collect();
    let mut graph = PoseGraph::new(before.clone());
    graph.fixed[0] = true;
    let odometry = info(cfg.odometry_sigma_m, cfg.odometry_sigma_rad);
    for i in 1..before.len() {
        graph.add_current_edge(i - 1, i, odometry).ok()?;
    }
    graph.edges.push(PoseGraphEdge {
        a: a as usize,
        b: b as usize,
        a_from_b,
        information,
    });
    let result = graph.optimize(&PoseGraphConfig::default()).ok()?;
    for (kf, new) in map.keyframes.iter_mut().zip(&graph.poses) {
        kf.world_from_body = *new;
    }
    for lm in map.landmarks.iter_mut().filter(|l| !l.dead) {
        let k = lm.created_by as usize;
        let correction = graph.poses[k] * before[k].inverse();
        lm.position = (correction * nalgebra::Point3::from(lm.position)).coords;
    }
    map.keyframes[a as usize].anchored = true;
    map.keyframes[b as usize].anchored = true;
    let (old_b, new_b) = (before[b as usize], graph.poses[b as usize]);
    let correction_m = (new_b.translation.vector - old_b.translation.vector).norm();
    let correction_deg = (new_b * old_b.inverse()).rotation.angle().to_degrees();
    tracker.refresh_last_pose();
    let global_ba = if cfg.global_ba {
        tracker.global_bundle_adjustment(cfg.global_ba_iterations)
    } else {
        None
    };
    tracker.open_loop_window(a);
    Some(AppliedLoop {
        correction_m,
        correction_deg,
        pose_graph_cost: (result.initial_cost, result.final_cost),
        global_ba,
    })
}

/// A diagonal information matrix (translation, then rotation) from standard deviations.
pub fn info(sigma_m: f64, sigma_rad: f64) -> Matrix6<f64> {
    let t = 1.0 / (sigma_m * sigma_m);
    let r = 1.0 / (sigma_rad * sigma_rad);
    Matrix6::from_diagonal(&Vector6::new(t, t, t, r, r, r))
}

/// `camera_from_tag` perturbed by `n = (δω, δt)` as in
/// [`super::tags::tag_pose_information`]: `(Exp(δω)·R, t + δt)`.
fn perturbed(camera_from_tag: &Isometry3<f64>, n: &Vector6<f64>) -> Isometry3<f64> {
    let dw = Vector3::new(n[0], n[1], n[2]);
    let dt = Vector3::new(n[3], n[4], n[5]);
    Isometry3::from_parts(
        (camera_from_tag.translation.vector + dt).into(),
        UnitQuaternion::from_scaled_axis(dw) * camera_from_tag.rotation,
    )
}

/// The information of a loop edge `edge(n1, n2)` (nominal `z`) over the pose graph's
/// error `(t_E, Log R_E)` of `E = z⁻¹·edge(n1, n2)`, from the covariances of the two
/// sightings' noises `n1`, `n2` (first order, central differences), plus `floor`.
fn edge_information(
    edge: &impl Fn(&Vector6<f64>, &Vector6<f64>) -> Isometry3<f64>,
    z: &Isometry3<f64>,
    c1: &Matrix6<f64>,
    c2: &Matrix6<f64>,
    floor: &Matrix6<f64>,
) -> Option<Matrix6<f64>> {
    let error = |e: Isometry3<f64>| relative_error(z, &e);
    let h = 1e-6;
    let mut j1 = Matrix6::zeros();
    let mut j2 = Matrix6::zeros();
    for k in 0..6 {
        let mut n = Vector6::zeros();
        n[k] = h;
        let z0 = Vector6::zeros();
        j1.set_column(
            k,
            &((error(edge(&n, &z0)) - error(edge(&(-n), &z0))) / (2.0 * h)),
        );
        j2.set_column(
            k,
            &((error(edge(&z0, &n)) - error(edge(&z0, &(-n)))) / (2.0 * h)),
        );
    }
    let cov = j1 * c1 * j1.transpose() + j2 * c2 * j2.transpose() + floor;
    let cov = (cov + cov.transpose()) * 0.5;
    cov.try_inverse()
        .filter(|m| m.iter().all(|v| v.is_finite()))
}

/// Path length along the keyframe positions from the first keyframe to `k`, m.
pub fn path_length_to(tracker: &Tracker, k: u32) -> f64 {
    tracker.map().keyframes[..=k as usize]
        .windows(2)
        .map(|w| {
            (w[1].world_from_body.translation.vector - w[0].world_from_body.translation.vector)
                .norm()
        })
        .sum()
}

#[cfg(test)]
pub(super) mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::slam::bench::synthetic_rig;
    use crate::slam::frontend::StereoFrame;
    use crate::slam::motion_ba::RigCamera;
    use crate::slam::orb::OrbConfig;
    use crate::slam::tracking::tests::{BASELINE_M, observe, world};
    use crate::slam::tracking::{CameraInput, TrackerCamera, TrackingConfig};
    use nalgebra::{Point3, Translation3, UnitQuaternion};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    const RATE_HZ: f64 = 15.0;

    /// 0.5 m/s forward along x for `turn_s`, then backward to the start (same heading).
    pub fn out_and_back(t: f64, turn_s: f64) -> Isometry3<f64> {
        let x = if t <= turn_s {
            0.5 * t
        } else {
            0.5 * turn_s - 0.5 * (t - turn_s)
        };
        Isometry3::from_parts(
            Translation3::new(x, 0.05 * (0.5 * t).sin(), 0.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.03 * (0.5 * t).cos()),
        )
    }

    /// This test's run: out for 8 s and back.
    fn truth(t: f64) -> Isometry3<f64> {
        out_and_back(t, 8.0)
    }

    /// `truth` in the SLAM's world (the body at the first frame).
    pub fn in_slam_world(truth: impl Fn(f64) -> Isometry3<f64>, t: f64) -> Isometry3<f64> {
        truth(0.0).inverse() * truth(t)
    }

    fn slam_truth(t: f64) -> Isometry3<f64> {
        in_slam_world(truth, t)
    }

    /// A tracker of the synthetic rig's front and rear pairs, and the rig.
    pub fn front_rear_tracker() -> (Tracker, Vec<RigCamera>) {
        let full = synthetic_rig();
        let rig: Vec<TrackerCamera> = (0..2)
            .map(|c| TrackerCamera {
                camera: full[c].clone(),
                baseline_m: BASELINE_M,
            })
            .collect();
        let tracker = Tracker::new(TrackingConfig::default(), &OrbConfig::default(), rig).unwrap();
        (tracker, full)
    }

    /// Tracks the synchronous front and rear pairs seen from `world_from_body` at `t`.
    pub fn track_front_rear(
        tracker: &mut Tracker,
        full: &[RigCamera],
        landmarks: &[(Vector3<f64>, crate::slam::Descriptor)],
        rng: &mut ChaCha8Rng,
        world_from_body: &Isometry3<f64>,
        t: f64,
    ) {
        let frames: Vec<StereoFrame> = (0..2)
            .map(|c| observe(&full[c], world_from_body, landmarks, rng))
            .collect();
        let inputs: Vec<CameraInput> = frames
            .iter()
            .enumerate()
            .map(|(camera, features)| CameraInput {
                camera,
                stamp: Nanos::from_secs_f64(t),
                features,
                rotation_from_frame: None,
            })
            .collect();
        tracker.track(Nanos::from_secs_f64(t), &inputs);
    }

    /// Drift injected into the map, growing along the keyframes up to 8 cm and 1.5° of
    /// yaw at the end; each landmark drifts with the keyframe that created it.
    pub fn inject_drift(tracker: &mut Tracker) {
        let map = tracker.map_mut();
        let n_kf = map.keyframes.len();
        let drift = |k: usize| {
            let f = k as f64 / (n_kf - 1) as f64;
            Isometry3::from_parts(
                Translation3::new(0.03 * f, 0.07 * f, 0.01 * f),
                UnitQuaternion::from_euler_angles(0.0, 0.0, 0.026 * f),
            )
        };
        for (k, kf) in map.keyframes.iter_mut().enumerate() {
            kf.world_from_body = drift(k) * kf.world_from_body;
        }
        for lm in map.landmarks.iter_mut() {
            lm.position = (drift(lm.created_by as usize) * Point3::from(lm.position)).coords;
        }
        tracker.refresh_last_pose();
    }

    /// RMS position error of the tracker's trajectory against `truth`, m.
    pub fn rmse_against(tracker: &Tracker, truth: impl Fn(f64) -> Isometry3<f64>) -> f64 {
        let traj = tracker.trajectory();
        let se: f64 = traj
            .iter()
            .map(|(t, p)| {
                let e = in_slam_world(&truth, t.as_secs_f64()).translation.vector
                    - p.translation.vector;
                e.norm_squared()
            })
            .sum();
        (se / traj.len() as f64).sqrt()
    }

    /// A side camera looking right (body -y), optical frame x right, y down, z forward.
    fn body_from_side_camera() -> Isometry3<f64> {
        let r = nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::new(
            -1.0, 0.0, 0.0, //
            0.0, 0.0, -1.0, //
            0.0, -1.0, 0.0,
        ));
        Isometry3::from_parts(
            Translation3::new(0.0, -0.2, 0.3),
            UnitQuaternion::from_rotation_matrix(&r),
        )
    }

    /// The tag 1 m to the right of the path at x = 0.5, facing the path.
    fn world_from_tag() -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(0.5, -1.0, 0.6),
            UnitQuaternion::from_euler_angles(-std::f64::consts::FRAC_PI_2, 0.0, 0.0),
        )
    }

    fn sighting(t: f64) -> TagSighting {
        let camera_from_tag = (truth(t) * body_from_side_camera()).inverse() * world_from_tag();
        TagSighting {
            id: 3,
            camera_from_tag,
            corners_px: [[0.0; 2]; 4],
            reprojection_rms_px: 0.1,
            decision_margin: 100.0,
            hamming: 0,
        }
    }

    /// The side camera's sighting of the tag at `t` (true pose), handed to `closer`.
    fn see(closer: &mut TagLoopCloser, tracker: &mut Tracker, t: f64) -> Option<LoopClosure> {
        let stamp = Nanos::from_secs_f64(t);
        closer
            .on_sighting(tracker, stamp, &sighting(t), &body_from_side_camera(), None)
            .cloned()
    }

    fn rmse(tracker: &Tracker) -> f64 {
        rmse_against(tracker, truth)
    }

    #[test]
    fn a_tag_seen_again_takes_out_an_injected_drift() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let landmarks = world(&mut rng);
        let (mut tracker, full) = front_rear_tracker();
        let mut closer = TagLoopCloser::new(LoopConfig::default()).unwrap();
        // The first visit: three sightings; the return: one from 1.15 m past the nearest
        // registering pose (too far), then one from where the second was made.
        let first_visit = [0.6, 1.0, 1.4];
        let (t_first, t_far, t_again) = (1.0, 12.3, 15.0);
        let n = (15.2 * RATE_HZ) as i64;
        for i in 0..n {
            let t = i as f64 / RATE_HZ;
            track_front_rear(&mut tracker, &full, &landmarks, &mut rng, &truth(t), t);
            for ts in first_visit {
                if (t - (ts + 0.1)).abs() < 0.5 / RATE_HZ {
                    let r = see(&mut closer, &mut tracker, ts);
                    assert!(r.is_none(), "the first visit registers the tag");
                }
            }
        }
        assert_eq!(closer.stats().tags_registered, 1);
        assert_eq!(closer.stats().sightings, 3);
        // 12.3 s: x = 1.85 m, 1.15 m from the nearest registering pose (x = 0.7 m).
        let far = see(&mut closer, &mut tracker, t_far);
        assert!(far.is_none(), "a sighting 1.15 m away closes no loop");
        assert_eq!(closer.stats().sightings_too_far, 1);
        let clean = rmse(&tracker);
        inject_drift(&mut tracker);
        let drifted = rmse(&tracker);
        let end = Nanos::from_secs_f64(t_again);
        let end_error = |tracker: &Tracker| {
            let (k, kf_from_body) = tracker.pose_at(end, Nanos::from_secs_f64(0.2)).unwrap();
            let p = tracker.map().keyframes[k as usize].world_from_body * kf_from_body;
            (p.translation.vector - slam_truth(t_again).translation.vector).norm()
        };
        let end_before = end_error(&tracker);
        let closure =
            see(&mut closer, &mut tracker, t_again).expect("a loop at the tag seen again");
        let end_after = end_error(&tracker);
        let corrected = rmse(&tracker);
        println!(
            "rmse clean {clean:.4} m, drifted {drifted:.4}, corrected {corrected:.4}; end error \
             {end_before:.4} -> {end_after:.4} m; {closure:?}"
        );
        assert_eq!(closure.source, LoopSource::Tag);
        assert_eq!(closure.tag_id, Some(3));
        assert_eq!(closure.matched_stamp, Nanos::from_secs_f64(t_first));
        assert!(end_before > 0.06, "{end_before}");
        assert!(end_after < 0.01, "end error after the loop {end_after}");
        assert!(corrected < 0.25 * drifted, "rmse {drifted} -> {corrected}");
        assert!(closure.global_ba.is_some());
        // A second sighting right after is no new loop (not min_path_m travelled).
        assert!(see(&mut closer, &mut tracker, t_again).is_none());
        assert_eq!(closer.loops().len(), 1);
    }

    #[test]
    fn surveyed_tags_far_apart_take_out_an_injected_drift_without_a_revisit() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let landmarks = world(&mut rng);
        let (mut tracker, full) = front_rear_tracker();
        // Tag 3 at x = 0.5 m, tag 4 at x = 3.2 m, both surveyed (true world poses); tag 5
        // is not. The robot drives out once: no place is visited twice.
        let world_from_tag4 = Translation3::new(2.7, 0.0, 0.0) * world_from_tag();
        // An exact survey, weighted as one.
        let cfg = LoopConfig {
            min_path_m: 2.0,
            survey_sigma_m: 0.001,
            survey_sigma_rad: 0.0005,
            surveyed_tags: vec![
                SurveyedTag::from_pose(3, &world_from_tag()),
                SurveyedTag::from_pose(4, &world_from_tag4),
            ],
            ..LoopConfig::default()
        };
        // The survey entry gives the pose back.
        let back = cfg.surveyed_tags[1].world_from_tag();
        assert!((back.translation.vector - world_from_tag4.translation.vector).norm() < 1e-12);
        assert!(back.rotation.angle_to(&world_from_tag4.rotation) < 1e-12);
        let mut closer = TagLoopCloser::new(cfg).unwrap();
        let sighting_of = |id: u32, world_from_tag: &Isometry3<f64>, t: f64| TagSighting {
            id,
            camera_from_tag: (truth(t) * body_from_side_camera()).inverse() * world_from_tag,
            ..sighting(t)
        };
        let (t_anchor, t_other, t_far) = (1.0, 3.0, 6.4);
        let n = (6.9 * RATE_HZ) as i64;
        for i in 0..n {
            let t = i as f64 / RATE_HZ;
            track_front_rear(&mut tracker, &full, &landmarks, &mut rng, &truth(t), t);
            if (t - (t_anchor + 0.1)).abs() < 0.5 / RATE_HZ {
                let s = sighting_of(3, &world_from_tag(), t_anchor);
                let stamp = Nanos::from_secs_f64(t_anchor);
                let r = closer.on_sighting(&mut tracker, stamp, &s, &body_from_side_camera(), None);
                assert!(r.is_none(), "the first surveyed sighting is the anchor");
            }
            if (t - (t_other + 0.1)).abs() < 0.5 / RATE_HZ {
                // An unsurveyed tag only registers.
                let other = Translation3::new(1.0, 0.0, 0.0) * world_from_tag();
                let s = sighting_of(5, &other, t_other);
                let stamp = Nanos::from_secs_f64(t_other);
                let r = closer.on_sighting(&mut tracker, stamp, &s, &body_from_side_camera(), None);
                assert!(r.is_none());
            }
        }
        assert_eq!(closer.stats().tags_registered, 2);
        inject_drift(&mut tracker);
        // The far pose relative to the anchor's, against the truth (the anchor's own drift
        // is what a relative constraint cannot see).
        let end_error = |tracker: &Tracker| {
            let at = |t: f64| {
                let (k, kf_from_body) = tracker
                    .pose_at(Nanos::from_secs_f64(t), Nanos::from_secs_f64(0.2))
                    .unwrap();
                tracker.map().keyframes[k as usize].world_from_body * kf_from_body
            };
            let est = at(t_anchor).inverse() * at(t_far);
            let true_rel = truth(t_anchor).inverse() * truth(t_far);
            (est.translation.vector - true_rel.translation.vector).norm()
        };
        let before = end_error(&tracker);
        // Tag 4 abeam (closest), then 0.15 m past it: the loop uses the closest sighting.
        let mut see4 = |t: f64| {
            let s = sighting_of(4, &world_from_tag4, t);
            let stamp = Nanos::from_secs_f64(t);
            closer
                .on_sighting(&mut tracker, stamp, &s, &body_from_side_camera(), None)
                .cloned()
        };
        assert!(see4(t_far).is_none(), "waits for the closest approach");
        let closure = see4(t_far + 0.3).expect("a loop through the survey");
        let after = end_error(&tracker);
        println!("relative error anchor -> far pose: {before:.4} -> {after:.4} m");
        assert_eq!(closure.source, LoopSource::TagSurvey);
        assert_eq!(closure.tag_id, Some(4));
        assert_eq!(closure.matched_stamp, Nanos::from_secs_f64(t_anchor));
        assert_eq!(closer.stats().survey_loops, 1);
        // The claim is the true relative pose of the two bodies, 2.7 m apart.
        let true_rel = truth(t_anchor).inverse() * truth(t_far);
        let claim = closure.matched_from_query.unwrap();
        assert!(true_rel.translation.vector.norm() > 2.6);
        assert!((claim.translation.vector - true_rel.translation.vector).norm() < 1e-9);
        assert!(before > 0.06, "{before}");
        assert!(after < 0.01, "end error {before} -> {after} m");
    }

    #[test]
    fn loop_edge_information_matches_a_monte_carlo_covariance() {
        use rand_distr::{Distribution, StandardNormal};
        let kf_a_from_cam = Isometry3::from_parts(
            Translation3::new(0.1, -0.2, 0.3),
            UnitQuaternion::from_euler_angles(-1.5, 0.1, -1.6),
        );
        let kf_b_from_cam = Isometry3::from_parts(
            Translation3::new(-0.2, 0.1, 0.35),
            UnitQuaternion::from_euler_angles(-1.6, -0.05, -1.5),
        );
        let cam1_from_tag = Isometry3::from_parts(
            Translation3::new(0.1, 0.05, 0.9),
            UnitQuaternion::from_euler_angles(0.2, -0.3, 0.1),
        );
        let cam2_from_tag = Isometry3::from_parts(
            Translation3::new(-0.2, 0.0, 1.3),
            UnitQuaternion::from_euler_angles(-0.1, 0.4, 0.05),
        );
        let edge = |n1: &Vector6<f64>, n2: &Vector6<f64>| {
            (kf_a_from_cam * perturbed(&cam1_from_tag, n1))
                * (kf_b_from_cam * perturbed(&cam2_from_tag, n2)).inverse()
        };
        let z = edge(&Vector6::zeros(), &Vector6::zeros());
        // Sighting covariances: a few mrad and mm, correlated.
        let l1 = nalgebra::Matrix6::from_fn(|i, j| {
            if i == j {
                [3e-3, 2e-3, 1e-3, 2e-3, 1e-3, 4e-3][i]
            } else if i > j {
                5e-4
            } else {
                0.0
            }
        });
        let l2 = l1 * 1.5;
        let (c1, c2) = (l1 * l1.transpose(), l2 * l2.transpose());
        let information =
            edge_information(&edge, &z, &c1, &c2, &Matrix6::zeros()).expect("invertible");
        let predicted = information.try_inverse().unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut draw = |l: &Matrix6<f64>| {
            let g = Vector6::from_fn(|_, _| StandardNormal.sample(&mut rng));
            l * g
        };
        let n = 40_000;
        let mut cov = Matrix6::zeros();
        for _ in 0..n {
            let (n1, n2) = (draw(&l1), draw(&l2));
            let e = relative_error(&z, &edge(&n1, &n2));
            cov += e * e.transpose();
        }
        cov /= n as f64;
        let rel = (cov - predicted).norm() / predicted.norm();
        assert!(rel < 0.05, "relative difference {rel}\n{cov}\n{predicted}");
    }
}
