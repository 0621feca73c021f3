//! Bag-of-words loop closure: the SLAM's place-recognition baseline (ORB-SLAM's loop
//! detection, which Kokas et al. compare their tag loops against).
//!
//! Every new keyframe becomes a bag of words of all its cameras' ORB descriptors
//! ([`Vocabulary::transform`]) and queries the keyframe [`Database`] through the
//! [`LoopDetector`] (DBoW2's normalized score against the previous keyframe, islands,
//! temporal consistency). Keyframes covisible with the query (sharing a landmark) and
//! those less than `loop_closure.min_path_m` of path back are never candidates, so a loop
//! means a return after travel, as for tags. A reported candidate must pass a **geometric
//! check** before it is applied:
//!
//! 1. the query keyframe's stereo points are matched to the candidate's landmarks by
//!    descriptor (Hamming distance under `max_hamming`, nearest/second-nearest ratio
//!    under `nn_ratio`, one match per landmark);
//! 2. RANSAC over 3-point rigid fits (Kabsch) of the two point sets, scored by the
//!    reprojection of the candidate's landmarks into the query's cameras (χ² 2 DOF, 95 %,
//!    scaled by the keypoint's pyramid level), needs `min_ransac_inliers`;
//! 3. motion-only BA of the query rig against the candidate's landmarks from that start
//!    ([`optimize_pose`]), needs `min_inliers`.
//!
//! The relative pose it gives is a loop edge with `sigma_m`/`sigma_rad` and is applied like
//! any loop ([`apply_loop`]). In a vineyard the rows look alike, so nothing here can tell
//! two rows apart: that is what the baseline shows, so it is tuned neither to fail nor to
//! succeed (ORB-SLAM2's thresholds).

use super::bow::{BowVector, Database, LoopDetector, LoopDetectorConfig, SplitMix64, Vocabulary};
use super::loop_closing::{LoopClosure, LoopConfig, LoopSource, apply_loop, info, path_length_to};
use super::motion_ba::{MotionBaConfig, Observation, RigCamera, optimize_pose};
use super::orb::hamming;
use super::tracking::Tracker;
use super::{ConfigError, check};
use nalgebra::{
    Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector2, Vector3,
};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// χ² of 2 DOF at 95 %: the reprojection inlier gate (σ units).
const CHI2_2DOF_95: f64 = 5.991;

/// `[slam.bow]` of a scenario: bag-of-words loop detection (`loop_closure.method = "bow"`).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct BowConfig {
    /// The vocabulary file (written by `vinebench vocabulary`), relative to the scenario
    /// file.
    pub vocabulary: String,
    /// Candidate selection: scores, islands, temporal consistency.
    pub detector: LoopDetectorConfig,
    /// Largest Hamming distance of a descriptor match (ORB-SLAM's `TH_LOW`).
    pub max_hamming: u32,
    /// A match's distance must be below this fraction of the second-nearest's.
    pub nn_ratio: f64,
    /// RANSAC hypotheses (3-point rigid fits) tried.
    pub ransac_iterations: usize,
    /// Fewest RANSAC inliers for the candidate to go on to motion-only BA.
    pub min_ransac_inliers: usize,
    /// Fewest inliers after motion-only BA for the loop to be accepted.
    pub min_inliers: usize,
    /// Standard deviation of the loop edge: translation, m.
    pub sigma_m: f64,
    /// The same, rotation, rad.
    pub sigma_rad: f64,
}

impl Default for BowConfig {
    fn default() -> Self {
        BowConfig {
            vocabulary: "vocabularies/vineyard.vbvoc".to_string(),
            // Recent keyframes are excluded by path and covisibility, not by id.
            detector: LoopDetectorConfig {
                min_gap: 1,
                ..LoopDetectorConfig::default()
            },
            max_hamming: 50,
            nn_ratio: 0.75,
            ransac_iterations: 200,
            min_ransac_inliers: 20,
            min_inliers: 40,
            sigma_m: 0.01,
            sigma_rad: 0.005,
        }
    }
}

impl BowConfig {
    /// Checks every range.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.detector.validate()?;
        check(
            !self.vocabulary.is_empty(),
            "slam.bow.vocabulary must name a vocabulary file",
        )?;
        check(
            (1..=256).contains(&self.max_hamming),
            "slam.bow.max_hamming must be in [1, 256]",
        )?;
        check(
            self.nn_ratio > 0.0 && self.nn_ratio <= 1.0,
            "slam.bow.nn_ratio must be in (0, 1]",
        )?;
        check(
            (1..=100_000).contains(&self.ransac_iterations),
            "slam.bow.ransac_iterations must be in [1, 100000]",
        )?;
        check(
            self.min_ransac_inliers >= 3,
            "slam.bow.min_ransac_inliers must be at least 3",
        )?;
        check(
            self.min_inliers >= 3,
            "slam.bow.min_inliers must be at least 3",
        )?;
        check(
            self.sigma_m.is_finite() && self.sigma_m > 0.0,
            "slam.bow.sigma_m must be positive",
        )?;
        check(
            self.sigma_rad.is_finite() && self.sigma_rad > 0.0,
            "slam.bow.sigma_rad must be positive",
        )
    }
}

/// Counters of the bag-of-words loop closer.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct BowStats {
    /// Keyframes queried.
    pub queries: usize,
    /// Candidates the detector reported.
    pub candidates: usize,
    /// Candidates with too few descriptor matches or RANSAC inliers.
    pub rejected_ransac: usize,
    /// Candidates with too few inliers after motion-only BA.
    pub rejected_ba: usize,
}

/// The geometric check's verdict on a candidate.
#[derive(Clone, Debug, PartialEq)]
pub struct GeometricMatch {
    /// The candidate keyframe's body from the query keyframe's body.
    pub a_from_b: Isometry3<f64>,
    /// Descriptor matches.
    pub matches: usize,
    /// RANSAC inliers.
    pub ransac_inliers: usize,
    /// Inliers after motion-only BA.
    pub inliers: usize,
}

/// Finds loops by bag of words and closes them (see the module docs).
#[derive(Clone, Debug)]
pub struct BowLoopCloser {
    cfg: BowConfig,
    loop_cfg: LoopConfig,
    max_depth_baselines: f64,
    motion: MotionBaConfig,
    vocabulary: Arc<Vocabulary>,
    db: Database,
    detector: LoopDetector,
    bows: Vec<BowVector>,
    loops: Vec<LoopClosure>,
    stats: BowStats,
}

impl BowLoopCloser {
    /// A loop closer with validated configurations; `max_depth_baselines` and
    /// `scale_factor` are the front end's (stereo depth limit, pyramid scale).
    pub fn new(
        cfg: BowConfig,
        loop_cfg: LoopConfig,
        max_depth_baselines: f64,
        scale_factor: f64,
        vocabulary: Arc<Vocabulary>,
    ) -> Result<BowLoopCloser, ConfigError> {
        cfg.validate()?;
        loop_cfg.validate()?;
        let motion = MotionBaConfig {
            scale_factor,
            min_inliers: cfg.min_inliers,
            ..MotionBaConfig::default()
        };
        motion.validate()?;
        Ok(BowLoopCloser {
            detector: LoopDetector::new(cfg.detector.clone())?,
            cfg,
            loop_cfg,
            max_depth_baselines,
            motion,
            vocabulary,
            db: Database::new(),
            bows: Vec::new(),
            loops: Vec::new(),
            stats: BowStats::default(),
        })
    }

    /// Accepted loops so far.
    pub fn loops(&self) -> &[LoopClosure] {
        &self.loops
    }

    /// Counters.
    pub fn stats(&self) -> &BowStats {
        &self.stats
    }

    /// Queries every keyframe the tracker inserted since the last call, in order, and
    /// closes the loops that pass the geometric check.
    pub fn on_keyframes(&mut self, tracker: &mut Tracker) {
        while self.bows.len() < tracker.map().keyframes.len() {
            let k = self.bows.len() as u32;
            self.query(tracker, k);
        }
    }

    /// Queries keyframe `k` (the newest) and adds it to the database.
    fn query(&mut self, tracker: &mut Tracker, k: u32) {
        let map = tracker.map();
        let kf = &map.keyframes[k as usize];
        let descriptors: Vec<_> = kf.descriptors().collect();
        let bow = self.vocabulary.transform(&descriptors);
        let normalizer = match k.checked_sub(1) {
            Some(prev) => super::bow::score(&bow, &self.bows[prev as usize]),
            None => 0.0,
        };
        // Covisible keyframes (sharing a landmark with k) and those less than
        // `min_path_m` of path back are never candidates.
        let mut excluded = vec![false; k as usize];
        for lm in kf.landmarks() {
            for o in &map.landmarks[lm as usize].observations {
                if o.keyframe < k {
                    excluded[o.keyframe as usize] = true;
                }
            }
        }
        let path_k = path_length_to(tracker, k);
        let mut path = 0.0;
        for (i, e) in excluded.iter_mut().enumerate() {
            if i > 0 {
                path += (map.keyframes[i].world_from_body.translation.vector
                    - map.keyframes[i - 1].world_from_body.translation.vector)
                    .norm();
            }
            if path_k - path < self.loop_cfg.min_path_m {
                *e = true;
            }
        }
        self.stats.queries += 1;
        let candidate = self
            .detector
            .detect_excluding(&self.db, k, &bow, normalizer, |id| excluded[id as usize]);
        // Ids are the keyframe indices, added in order: `add` cannot see a duplicate.
        let _ = self.db.add(k, bow.clone());
        self.bows.push(bow);
        let Some(candidate) = candidate else {
            return;
        };
        self.stats.candidates += 1;
        let started = std::time::Instant::now();
        let a = candidate.matched_id;
        let Some(found) = self.geometric_check(tracker, a, k) else {
            return;
        };
        let information = info(self.cfg.sigma_m, self.cfg.sigma_rad);
        let Some(applied) = apply_loop(tracker, &self.loop_cfg, a, k, found.a_from_b, information)
        else {
            return;
        };
        self.detector.reset();
        let keyframes = &tracker.map().keyframes;
        // The keyframes' own stamps: the geometric check's pose is the claim.
        self.loops.push(applied.record(
            LoopSource::Bow,
            None,
            (keyframes[k as usize].stamp, k),
            (keyframes[a as usize].stamp, a),
            Some(found.a_from_b),
            started,
        ));
    }

    /// The relative pose of keyframes `a` (candidate) and `b` (query) from `b`'s stereo
    /// points matched to `a`'s landmarks, or `None` when too few agree (counted).
    pub fn geometric_check(&mut self, tracker: &Tracker, a: u32, b: u32) -> Option<GeometricMatch> {
        let result = geometric_check(
            tracker,
            a,
            b,
            &self.cfg,
            &self.motion,
            self.max_depth_baselines,
        );
        match &result {
            Err(Rejection::Ransac) => self.stats.rejected_ransac += 1,
            Err(Rejection::Ba) => self.stats.rejected_ba += 1,
            Ok(_) => {}
        }
        result.ok()
    }
}

/// Which step of the geometric check rejected a candidate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Rejection {
    Ransac,
    Ba,
}

/// A landmark of the candidate keyframe matched to a stereo point of the query.
#[derive(Clone, Copy, Debug)]
struct Match {
    /// The landmark in the candidate's body frame.
    p_a: Vector3<f64>,
    /// The stereo point in the query's body frame.
    p_b: Vector3<f64>,
    /// Query camera slot, keypoint pixel and level.
    slot: usize,
    pixel: Vector2<f64>,
    level: u8,
}

/// See [`BowLoopCloser::geometric_check`].
fn geometric_check(
    tracker: &Tracker,
    a: u32,
    b: u32,
    cfg: &BowConfig,
    motion: &MotionBaConfig,
    max_depth_baselines: f64,
) -> Result<GeometricMatch, Rejection> {
    let map = tracker.map();
    let (kf_a, kf_b) = (&map.keyframes[a as usize], &map.keyframes[b as usize]);
    let body_a_from_world = kf_a.world_from_body.inverse();
    // The candidate's landmarks, once each, in its body frame, with its keypoints'
    // descriptors.
    let mut targets: Vec<(u32, Vector3<f64>, super::Descriptor)> = Vec::new();
    for c in &kf_a.cameras {
        for (k, lm) in c.landmarks.iter().enumerate() {
            let Some(lm) = *lm else { continue };
            let l = &map.landmarks[lm as usize];
            if l.dead {
                continue;
            }
            targets.push((
                lm,
                (body_a_from_world * Point3::from(l.position)).coords,
                c.descriptors[k],
            ));
        }
    }
    targets.sort_by_key(|t| t.0);
    targets.dedup_by_key(|t| t.0);
    // The query's cameras as a rig, and its stereo points matched to the targets.
    let rig: Vec<RigCamera> = kf_b
        .cameras
        .iter()
        .map(|c| RigCamera {
            body_from_camera: c.body_from_camera,
            ..tracker.rig()[c.camera].camera.clone()
        })
        .collect();
    let mut best_for_target: Vec<Option<(u32, Match)>> = vec![None; targets.len()];
    for (slot, c) in kf_b.cameras.iter().enumerate() {
        let cam = &rig[slot];
        let baseline = tracker.rig()[c.camera].baseline_m;
        for (k, kp) in c.keypoints.iter().enumerate() {
            let Some(xr) = c.right_x[k] else { continue };
            let disparity = f64::from(kp.x - xr);
            if disparity <= 0.0 {
                continue;
            }
            let z = cam.fx * baseline / disparity;
            if z > max_depth_baselines * baseline {
                continue;
            }
            let d = &c.descriptors[k];
            let (mut best, mut second, mut best_i) = (u32::MAX, u32::MAX, usize::MAX);
            for (i, t) in targets.iter().enumerate() {
                let h = hamming(d, &t.2);
                if h < best {
                    second = best;
                    best = h;
                    best_i = i;
                } else if h < second {
                    second = h;
                }
            }
            if best > cfg.max_hamming || f64::from(best) >= cfg.nn_ratio * f64::from(second) {
                continue;
            }
            let pixel = Vector2::new(f64::from(kp.x), f64::from(kp.y));
            let p_c = Point3::new(
                (pixel.x - cam.cx) * z / cam.fx,
                (pixel.y - cam.cy) * z / cam.fy,
                z,
            );
            let m = Match {
                p_a: targets[best_i].1,
                p_b: (cam.body_from_camera * p_c).coords,
                slot,
                pixel,
                level: kp.level,
            };
            if best_for_target[best_i].is_none_or(|(h, _)| best < h) {
                best_for_target[best_i] = Some((best, m));
            }
        }
    }
    let matches: Vec<Match> = best_for_target.into_iter().flatten().map(|x| x.1).collect();
    if matches.len() < cfg.min_ransac_inliers {
        return Err(Rejection::Ransac);
    }
    // RANSAC over 3-point rigid fits, scored by reprojection into the query's cameras.
    let is_inlier = |a_from_b: &Isometry3<f64>, m: &Match| {
        let p_b = a_from_b.inverse_transform_point(&Point3::from(m.p_a));
        let cam = &rig[m.slot];
        let p_c = cam.body_from_camera.inverse_transform_point(&p_b);
        cam.project(&p_c.coords).is_some_and(|px| {
            let sigma2 = motion.scale_factor.powi(2 * i32::from(m.level));
            (px - m.pixel).norm_squared() / sigma2 < CHI2_2DOF_95
        })
    };
    let mut rng = SplitMix64(u64::from(a) << 32 | u64::from(b));
    let n = matches.len() as u64;
    let mut best: Option<(usize, Isometry3<f64>)> = None;
    for _ in 0..cfg.ransac_iterations {
        let i = rng.below(n) as usize;
        let j = rng.below(n) as usize;
        let l = rng.below(n) as usize;
        if i == j || j == l || i == l {
            continue;
        }
        let sample = [&matches[i], &matches[j], &matches[l]];
        let Some(model) = rigid_fit(sample.iter().map(|m| (m.p_a, m.p_b))) else {
            continue;
        };
        let count = matches.iter().filter(|m| is_inlier(&model, m)).count();
        if best.as_ref().is_none_or(|(c, _)| count > *c) {
            best = Some((count, model));
        }
    }
    let Some((ransac_inliers, model)) = best else {
        return Err(Rejection::Ransac);
    };
    if ransac_inliers < cfg.min_ransac_inliers {
        return Err(Rejection::Ransac);
    }
    let observations: Vec<Observation> = matches
        .iter()
        .map(|m| Observation {
            camera: m.slot,
            landmark_in_world: m.p_a,
            pixel: m.pixel,
            level: m.level,
        })
        .collect();
    let estimate = optimize_pose(&rig, &observations, &model, motion).map_err(|_| Rejection::Ba)?;
    Ok(GeometricMatch {
        a_from_b: estimate.world_from_body,
        matches: matches.len(),
        ransac_inliers,
        inliers: estimate.n_inliers,
    })
}

/// The rigid transform `T` minimizing `Σ |a - T·b|²` over the pairs `(a, b)` (Kabsch /
/// Horn, no scale); `None` for degenerate (collinear) points.
pub fn rigid_fit(
    pairs: impl Iterator<Item = (Vector3<f64>, Vector3<f64>)> + Clone,
) -> Option<Isometry3<f64>> {
    let n = pairs.clone().count();
    if n < 3 {
        return None;
    }
    let (sa, sb) = pairs
        .clone()
        .fold((Vector3::zeros(), Vector3::zeros()), |(sa, sb), (a, b)| {
            (sa + a, sb + b)
        });
    let (ca, cb) = (sa / n as f64, sb / n as f64);
    let h: Matrix3<f64> = pairs.fold(Matrix3::zeros(), |h, (a, b)| {
        h + (b - cb) * (a - ca).transpose()
    });
    let svd = h.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let s = svd.singular_values;
    if s[1] < 1e-9 * s[0].max(1e-300) {
        return None;
    }
    let mut d = Matrix3::identity();
    if (v_t.transpose() * u.transpose()).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = v_t.transpose() * d * u.transpose();
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let t = ca - rotation * cb;
    Some(Isometry3::from_parts(Translation3::from(t), rotation))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::slam::bow::VocabularyConfig;
    use crate::slam::loop_closing::tests::{
        front_rear_tracker, in_slam_world, inject_drift, out_and_back, rmse_against,
        track_front_rear,
    };
    use crate::slam::tracking::tests::world;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    const RATE_HZ: f64 = 15.0;

    /// Out for 16 s and back: the cameras see the first metres again at the end, long
    /// after the local map has dropped the keyframes that saw them.
    fn truth(t: f64) -> Isometry3<f64> {
        out_and_back(t, 16.0)
    }

    fn slam_truth(t: f64) -> Isometry3<f64> {
        in_slam_world(truth, t)
    }

    fn rmse(tracker: &Tracker) -> f64 {
        rmse_against(tracker, truth)
    }

    #[test]
    fn a_revisit_found_by_bag_of_words_takes_out_an_injected_drift() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let landmarks = world(&mut rng);
        let (mut tracker, full) = front_rear_tracker();
        let end_s = 32.0;
        for i in 0..=(end_s * RATE_HZ) as i64 {
            let t = i as f64 / RATE_HZ;
            track_front_rear(&mut tracker, &full, &landmarks, &mut rng, &truth(t), t);
        }
        // A vocabulary of this world's appearance: the keyframes' descriptors.
        let images: Vec<Vec<crate::slam::Descriptor>> = tracker
            .map()
            .keyframes
            .iter()
            .map(|k| k.descriptors().collect())
            .collect();
        let cfg = VocabularyConfig {
            branching: 10,
            depth: 3,
            ..VocabularyConfig::default()
        };
        let vocabulary = Arc::new(Vocabulary::train(&images, &cfg).unwrap());
        // Drift growing along the keyframes up to 8 cm and 1.5 deg of yaw at the end; each
        // landmark drifts with the keyframe that created it.
        let clean = rmse(&tracker);
        inject_drift(&mut tracker);
        let drifted = rmse(&tracker);
        let end_error = |tracker: &Tracker| {
            let p = tracker.trajectory().last().unwrap().1;
            (p.translation.vector - slam_truth(end_s).translation.vector).norm()
        };
        let end_before = end_error(&tracker);
        let loop_cfg = LoopConfig::default();
        let mut closer = BowLoopCloser::new(
            BowConfig::default(),
            loop_cfg.clone(),
            40.0,
            1.2,
            vocabulary,
        )
        .unwrap();
        closer.on_keyframes(&mut tracker);
        let end_after = end_error(&tracker);
        let corrected = rmse(&tracker);
        println!(
            "rmse clean {clean:.4} m, drifted {drifted:.4}, corrected {corrected:.4}; end \
             error {end_before:.4} -> {end_after:.4} m; {:?}",
            closer.stats(),
        );
        for l in closer.loops() {
            println!(
                "loop {} -> {} ({:?} -> {:?}): {:.3} m {:.2} deg",
                l.query_keyframe,
                l.matched_keyframe,
                l.query_stamp,
                l.matched_stamp,
                l.correction_m,
                l.correction_deg
            );
        }
        assert!(!closer.loops().is_empty(), "{:?}", closer.stats());
        for l in closer.loops() {
            assert_eq!(l.source, LoopSource::Bow);
            // A return: the query on the way back, the match on the way out, at least
            // min_path_m back along the path. (This world has no occlusion, so places a
            // few metres apart along x see the same landmarks: the edge's accuracy shows in
            // the end error below.)
            let (tq, tm) = (l.query_stamp.as_secs_f64(), l.matched_stamp.as_secs_f64());
            assert!(tq > 16.0 && tm < 16.0, "{l:?}");
            let path = (16.0 - tm) * 0.5 + (tq - 16.0) * 0.5;
            assert!(path >= loop_cfg.min_path_m, "{l:?}");
        }
        assert!(end_before > 0.06, "{end_before}");
        assert!(end_after < 0.02, "end error after the loops {end_after}");
        assert!(corrected < 0.5 * drifted, "rmse {drifted} -> {corrected}");
    }

    #[test]
    fn rigid_fit_recovers_a_known_transform() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let truth = Isometry3::from_parts(
            Translation3::new(1.5, -0.3, 0.2),
            UnitQuaternion::from_euler_angles(0.1, -0.2, 2.5),
        );
        let pairs: Vec<(Vector3<f64>, Vector3<f64>)> = (0..20)
            .map(|_| {
                let b = Vector3::new(
                    rng.random_range(-5.0..5.0),
                    rng.random_range(-5.0..5.0),
                    rng.random_range(0.0..3.0),
                );
                ((truth * Point3::from(b)).coords, b)
            })
            .collect();
        let fit = rigid_fit(pairs.iter().copied()).unwrap();
        assert!((fit.translation.vector - truth.translation.vector).norm() < 1e-9);
        assert!(fit.rotation.angle_to(&truth.rotation) < 1e-9);
        // Collinear points fix no rotation about their line.
        let line = (0..5).map(|i| {
            let b = Vector3::new(f64::from(i), 0.0, 0.0);
            (b, b)
        });
        assert!(rigid_fit(line).is_none());
    }
}
