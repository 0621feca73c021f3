//! Loop-closure scoring against ground truth: each accepted loop is true when the true
//! poses at its query and matched stamps are within `scoring.loop_distance_m` (and, for
//! the heading check, their yaws within `scoring.loop_heading_deg`); precision over the
//! accepted loops, recall over the ground-truth **revisits**. A loop through surveyed
//! tags (`tag_survey`) joins poses that may be far apart: it is true when the relative
//! pose it claims is within those thresholds of the true one.
//!
//! A revisit episode is a maximal stretch of ground-truth samples (every 0.2 s) each of
//! which is within `loop_distance_m` and `loop_heading_deg` of an earlier pose at least
//! `revisit_min_path_m` of travelled path before it: the robot is back at a place, facing
//! the way it did. An episode is recalled when a loop's query stamp falls inside it (with
//! 1 s of slack at either end, the sightings' pose interpolation window).

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};
use vinebench_msgs::{Nanos, Trajectory};
use vinebench_sim::control::heading_rad;

use vinebench_onboard::slam::loop_closing::{LoopClosure, LoopSource};

/// Ground-truth sampling step of the revisit search.
const REVISIT_STEP: Nanos = Nanos(200_000_000);
/// Slack around a revisit episode for a loop to recall it.
const RECALL_SLACK: Nanos = Nanos(1_000_000_000);

/// The loop thresholds of `[scoring]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopThresholds {
    /// Largest true distance between a loop's two poses, m.
    pub distance_m: f64,
    /// Largest true yaw difference for the heading check, deg.
    pub heading_deg: f64,
    /// Path travelled between two poses before being near again is a revisit, m.
    pub revisit_min_path_m: f64,
}

/// One accepted loop with its ground-truth check.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScoredLoop {
    /// Query stamp, ns.
    pub query_stamp: Nanos,
    /// Matched stamp, ns.
    pub matched_stamp: Nanos,
    /// `tag` or `bow`.
    pub method: String,
    /// The tag of a tag loop.
    pub tag_id: Option<u32>,
    /// True distance between the robot at the two stamps, m (NaN outside the truth).
    pub truth_distance_m: f64,
    /// True yaw difference, deg.
    pub truth_heading_deg: f64,
    /// How far the relative pose the loop claims is from the true one, m (NaN without a
    /// claim or outside the truth).
    pub claim_error_m: f64,
    /// The same, yaw, deg.
    pub claim_error_deg: f64,
    /// Within the distance threshold.
    pub correct: bool,
    /// Within the distance and the heading threshold.
    pub correct_with_heading: bool,
    /// How far the loop moved the current keyframe, m.
    pub correction_m: f64,
    /// How far it turned it, deg.
    pub correction_deg: f64,
}

/// Loop-closure scores of one SLAM source.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LoopScore {
    /// Every accepted loop, checked.
    pub loops: Vec<ScoredLoop>,
    /// Ground-truth revisit episodes, as (start, end) stamps.
    pub revisits: Vec<(Nanos, Nanos)>,
    /// Episodes with a loop.
    pub recalled: usize,
}

impl LoopScore {
    /// A loop metric by its expectation name (`loops`, `false_loops`, `loop_precision`,
    /// `loop_precision_heading`, `loop_recall`, `revisits`); precision is undefined
    /// without loops and recall without revisits.
    pub fn metric(&self, name: &str) -> Option<f64> {
        let n = self.loops.len();
        let correct = self.loops.iter().filter(|l| l.correct).count();
        let with_heading = self.loops.iter().filter(|l| l.correct_with_heading).count();
        Some(match name {
            "loops" => n as f64,
            "false_loops" => (n - correct) as f64,
            "loop_precision" if n > 0 => correct as f64 / n as f64,
            "loop_precision_heading" if n > 0 => with_heading as f64 / n as f64,
            "loop_recall" if !self.revisits.is_empty() => {
                self.recalled as f64 / self.revisits.len() as f64
            }
            "revisits" => self.revisits.len() as f64,
            _ => return None,
        })
    }
}

/// Absolute difference of two angles, deg in [0, 180].
fn angle_diff_deg(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(std::f64::consts::TAU);
    d.min(std::f64::consts::TAU - d).to_degrees()
}

/// The ground-truth revisit episodes of `truth` (see the module docs).
pub fn revisits(truth: &Trajectory, th: &LoopThresholds) -> Vec<(Nanos, Nanos)> {
    let (Some(first), Some(last)) = (truth.samples.first(), truth.samples.last()) else {
        return Vec::new();
    };
    let mut samples: Vec<(Nanos, Isometry3<f64>, f64)> = Vec::new();
    let mut t = first.stamp;
    let mut path = 0.0;
    while t <= last.stamp {
        if let Some(p) = truth.interpolate(t) {
            if let Some((_, q, _)) = samples.last() {
                path += (p.translation.vector - q.translation.vector).norm();
            }
            samples.push((t, p, path));
        }
        t += REVISIT_STEP;
    }
    let mut episodes: Vec<(Nanos, Nanos)> = Vec::new();
    let mut open: Option<(Nanos, Nanos)> = None;
    for (i, (t, p, s)) in samples.iter().enumerate() {
        let revisit = samples[..i].iter().any(|(_, q, sq)| {
            s - sq >= th.revisit_min_path_m
                && (p.translation.vector - q.translation.vector).norm() <= th.distance_m
                && angle_diff_deg(heading_rad(p), heading_rad(q)) <= th.heading_deg
        });
        open = match (open, revisit) {
            (None, true) => Some((*t, *t)),
            (Some((a, _)), true) => Some((a, *t)),
            (Some(e), false) => {
                episodes.push(e);
                None
            }
            (None, false) => None,
        };
    }
    episodes.extend(open);
    episodes
}

/// Scores `loops` against `truth`.
pub fn score_loops(loops: &[LoopClosure], truth: &Trajectory, th: &LoopThresholds) -> LoopScore {
    let scored: Vec<ScoredLoop> = loops
        .iter()
        .map(|l| {
            let poses = (
                truth.interpolate(l.query_stamp),
                truth.interpolate(l.matched_stamp),
            );
            let (d, h) = match poses {
                (Some(a), Some(b)) => (
                    (a.translation.vector - b.translation.vector).norm(),
                    angle_diff_deg(heading_rad(&a), heading_rad(&b)),
                ),
                _ => (f64::NAN, f64::NAN),
            };
            let (ce, ch) = match (poses, l.matched_from_query) {
                ((Some(q), Some(m)), Some(claim)) => {
                    let error = claim.inverse() * (m.inverse() * q);
                    (
                        error.translation.vector.norm(),
                        angle_diff_deg(heading_rad(&error), 0.0),
                    )
                }
                _ => (f64::NAN, f64::NAN),
            };
            let (correct, heading_ok) = if l.source == LoopSource::TagSurvey {
                (ce <= th.distance_m, ch <= th.heading_deg)
            } else {
                (d <= th.distance_m, h <= th.heading_deg)
            };
            ScoredLoop {
                query_stamp: l.query_stamp,
                matched_stamp: l.matched_stamp,
                method: l.source.name().to_string(),
                tag_id: l.tag_id,
                truth_distance_m: d,
                truth_heading_deg: h,
                claim_error_m: ce,
                claim_error_deg: ch,
                correct,
                correct_with_heading: correct && heading_ok,
                correction_m: l.correction_m,
                correction_deg: l.correction_deg,
            }
        })
        .collect();
    let episodes = revisits(truth, th);
    let recalled = episodes
        .iter()
        .filter(|(a, b)| {
            loops
                .iter()
                .any(|l| l.query_stamp + RECALL_SLACK >= *a && l.query_stamp <= *b + RECALL_SLACK)
        })
        .count();
    LoopScore {
        loops: scored,
        revisits: episodes,
        recalled,
    }
}

/// `loops.csv` of a run: one row per accepted loop of every SLAM source; stamps in ns and
/// in seconds after `t0`.
pub fn loops_csv(sources: &[(&str, &LoopScore)], t0: Nanos) -> String {
    let mut out = String::from(
        "source,query_stamp_ns,matched_stamp_ns,query_t_s,matched_t_s,method,tag_id,\
         truth_distance_m,truth_heading_deg,claim_error_m,claim_error_deg,correct,\
         correct_with_heading,correction_m,correction_deg\n",
    );
    for (source, score) in sources {
        for l in &score.loops {
            out.push_str(&format!(
                "{source},{},{},{:.3},{:.3},{},{},{:.4},{:.2},{:.4},{:.2},{},{},{:.4},{:.3}\n",
                l.query_stamp.0,
                l.matched_stamp.0,
                (l.query_stamp - t0).as_secs_f64(),
                (l.matched_stamp - t0).as_secs_f64(),
                l.method,
                l.tag_id.map(|i| i.to_string()).unwrap_or_default(),
                l.truth_distance_m,
                l.truth_heading_deg,
                l.claim_error_m,
                l.claim_error_deg,
                l.correct,
                l.correct_with_heading,
                l.correction_m,
                l.correction_deg,
            ));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};
    use vinebench_msgs::PoseSample;
    use vinebench_onboard::slam::loop_closing::LoopSource;

    /// A 1 m/s drive: east 10 m, north 4 m, west 10 m, south 4 m, then east 3 m again
    /// (the start revisited facing the same way), sampled at 10 Hz.
    fn square_loop() -> Trajectory {
        let legs: [(Vector3<f64>, f64); 5] = [
            (Vector3::x(), 10.0),
            (Vector3::y(), 4.0),
            (-Vector3::x(), 10.0),
            (-Vector3::y(), 4.0),
            (Vector3::x(), 3.0),
        ];
        let mut traj = Trajectory::new();
        let mut p = Vector3::zeros();
        let mut t = 0u64;
        for (dir, len) in legs {
            let yaw = dir.y.atan2(dir.x);
            for _ in 0..(len * 10.0) as usize {
                traj.push(PoseSample {
                    stamp: Nanos(t as i64),
                    world_from_body: Isometry3::from_parts(
                        Translation3::from(p),
                        UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
                    ),
                    covariance: None,
                });
                p += dir * 0.1;
                t += 100_000_000;
            }
        }
        traj
    }

    fn closure(query_s: f64, matched_s: f64) -> LoopClosure {
        LoopClosure {
            query_stamp: Nanos::from_secs_f64(query_s),
            matched_stamp: Nanos::from_secs_f64(matched_s),
            source: LoopSource::Tag,
            tag_id: Some(0),
            query_keyframe: 0,
            matched_keyframe: 0,
            matched_from_query: None,
            correction_m: 0.0,
            correction_deg: 0.0,
            pose_graph_cost: (0.0, 0.0),
            global_ba: None,
            wall_s: 0.0,
        }
    }

    const TH: LoopThresholds = LoopThresholds {
        distance_m: 1.0,
        heading_deg: 30.0,
        revisit_min_path_m: 5.0,
    };

    #[test]
    fn the_closing_leg_is_the_only_revisit() {
        let ep = revisits(&square_loop(), &TH);
        assert_eq!(ep.len(), 1, "{ep:?}");
        // Back at the start facing east at t = 28 s (at 27 s it is 1 m away but faces
        // south), a revisit to the last 0.2 s sample (30.8 s).
        let (a, b) = ep[0];
        assert!((a.as_secs_f64() - 28.0).abs() <= 0.01, "{a:?}");
        assert!((b.as_secs_f64() - 30.8).abs() <= 0.21, "{b:?}");
    }

    #[test]
    fn loops_are_checked_against_the_true_poses() {
        let truth = square_loop();
        // At 29 s the robot is at (1, 0) facing east, as at 1 s: a true loop. At 12 s it
        // is at (10, 2): 10.2 m from the start, false. At 22 s it is at (2, 4), 4 m from
        // (2, 0) at 2 s: false.
        let loops = [closure(29.0, 1.0), closure(12.0, 0.0), closure(22.0, 2.0)];
        let s = score_loops(&loops, &truth, &TH);
        let d: Vec<f64> = s.loops.iter().map(|l| l.truth_distance_m).collect();
        assert!(d[0] < 1e-9, "{d:?}");
        assert!((d[1] - (100.0f64 + 4.0).sqrt()).abs() < 1e-9, "{d:?}");
        assert!((d[2] - 4.0).abs() < 1e-9, "{d:?}");
        assert_eq!(s.metric("loops"), Some(3.0));
        assert_eq!(s.metric("false_loops"), Some(2.0));
        assert!((s.metric("loop_precision").unwrap() - 1.0 / 3.0).abs() < 1e-12);
        assert_eq!(s.metric("loop_recall"), Some(1.0));
        // Heading: the true loop faces east both times.
        assert!(s.loops[0].correct_with_heading);
        assert!(s.loops[0].truth_heading_deg < 1e-6);
    }

    #[test]
    fn a_survey_loop_is_judged_by_the_relative_pose_it_claims() {
        let truth = square_loop();
        // 12 s at (10, 2) facing north onto 1 s at (1, 0) facing east: 9.2 m apart, so a
        // revisit loop there is false, but a survey loop claiming the true relative pose
        // is right; one claiming it 1.5 m off is not; one turned 45 deg fails the heading.
        let at = |t: f64| truth.interpolate(Nanos::from_secs_f64(t)).unwrap();
        let true_rel = at(1.0).inverse() * at(12.0);
        let survey = |claim: Isometry3<f64>| LoopClosure {
            source: LoopSource::TagSurvey,
            matched_from_query: Some(claim),
            ..closure(12.0, 1.0)
        };
        let off = Isometry3::translation(0.0, 1.5, 0.0) * true_rel;
        let turned = true_rel * UnitQuaternion::from_euler_angles(0.0, 0.0, 0.785);
        let loops = [
            closure(12.0, 1.0),
            survey(true_rel),
            survey(off),
            survey(turned),
        ];
        let s = score_loops(&loops, &truth, &TH);
        let correct: Vec<bool> = s.loops.iter().map(|l| l.correct).collect();
        assert_eq!(correct, [false, true, false, true]);
        assert!(s.loops[1].claim_error_m < 1e-9);
        assert!((s.loops[2].claim_error_m - 1.5).abs() < 1e-9);
        assert!(s.loops[1].correct_with_heading);
        assert!(!s.loops[3].correct_with_heading);
        assert!((s.loops[3].claim_error_deg - 45.0).abs() < 0.1);
        assert_eq!(s.loops[1].method, "tag_survey");
        assert!(s.loops[0].claim_error_m.is_nan());
    }

    #[test]
    fn a_loop_at_the_same_place_facing_the_other_way_fails_the_heading_check() {
        let truth = square_loop();
        // At 23.5 s the robot is at (0.5, 4) facing west, at 24.5 s at (0, 3.5) facing
        // south: 0.71 m and 90 deg apart.
        let loops = [closure(24.5, 23.5)];
        let s = score_loops(&loops, &truth, &TH);
        let l = &s.loops[0];
        assert!((l.truth_distance_m - 0.5f64.sqrt()).abs() < 1e-9, "{l:?}");
        assert!((l.truth_heading_deg - 90.0).abs() < 1e-6, "{l:?}");
        assert!(l.correct && !l.correct_with_heading);
        assert_eq!(s.metric("loop_precision_heading"), Some(0.0));
        // No loop in the revisit episode: recall 0.
        assert_eq!(s.metric("loop_recall"), Some(0.0));
    }

    #[test]
    fn no_loops_has_no_precision_and_csv_has_a_header() {
        let s = score_loops(&[], &square_loop(), &TH);
        assert_eq!(s.metric("loop_precision"), None);
        assert_eq!(s.metric("loops"), Some(0.0));
        let csv = loops_csv(&[("slam", &s)], Nanos(0));
        assert_eq!(csv.lines().count(), 1);
        let s = score_loops(&[closure(29.0, 1.0)], &square_loop(), &TH);
        let csv = loops_csv(&[("slam", &s)], Nanos(0));
        let row = csv.lines().nth(1).unwrap();
        assert!(
            row.starts_with("slam,29000000000,1000000000,29.000,1.000,tag,0,"),
            "{row}"
        );
    }
}
