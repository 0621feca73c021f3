//! Trajectory metrics: evo-compatible APE (ATE) and RPE, the closed-loop metrics of the
//! seed paper's Table 1, errors inside fault windows and coverage.
//!
//! APE and RPE follow evo 1.38 (`evo_ape` / `evo_rpe`, translation part): poses are
//! associated by time ([`associate`](super::align::associate)), optionally the estimate is aligned onto the
//! reference with SE(3) Umeyama (`-a`), then per-pose errors are reduced to [`Stats`] as
//! numpy does. Every failure (nothing associated, degenerate alignment, no RPE pair) is an
//! [`ScoreError`] value.

use super::ScoringParams;
use super::align::{AlignError, associate_poses, umeyama_passes};
use super::spool::Poses;
use nalgebra::{Isometry3, Vector3};
use serde::{Deserialize, Serialize};
use thiserror::Error;
use vinebench_msgs::Nanos;

/// A metric could not be computed.
#[derive(Clone, Debug, PartialEq, Error)]
pub enum ScoreError {
    /// No estimate pose lies within `max_diff` of a reference pose.
    #[error(
        "no matching stamps between the reference ({reference_poses} poses) and the estimate \
         ({estimate_poses} poses) within {max_diff}"
    )]
    NoAssociation {
        /// Poses in the reference.
        reference_poses: usize,
        /// Poses in the estimate.
        estimate_poses: usize,
        /// The association tolerance.
        max_diff: Nanos,
    },
    /// The trajectory has no pose.
    #[error("the trajectory has no pose")]
    Empty,
    /// SE(3) alignment failed.
    #[error("alignment failed: {0}")]
    Alignment(#[from] AlignError),
    /// The RPE distance is not a finite number ≥ 0.
    #[error("RPE delta must be a finite number >= 0 m, found {delta_m}")]
    InvalidDelta {
        /// The requested distance, m.
        delta_m: f64,
    },
    /// The associated poses never travel `delta_m` twice, so there is no RPE pair.
    #[error("RPE delta = {delta_m} m produced no pose pair among {matched} associated poses")]
    NoRpePairs {
        /// The requested distance, m.
        delta_m: f64,
        /// Number of associated poses.
        matched: usize,
    },
}

/// Summary statistics of a set of errors, computed as evo does with numpy.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Stats {
    /// `sqrt(mean(e²))`.
    pub rmse: f64,
    /// Arithmetic mean.
    pub mean: f64,
    /// Median (mean of the two middle values when `n` is even, like `numpy.median`).
    pub median: f64,
    /// Population standard deviation (`numpy.std`, ddof = 0).
    pub std: f64,
    /// Smallest error.
    pub min: f64,
    /// Largest error.
    pub max: f64,
    /// Sum of squared errors.
    pub sse: f64,
    /// Number of errors.
    pub n: usize,
}

impl Stats {
    /// The statistics of `errors`; `None` when empty.
    pub fn from_errors(errors: &[f64]) -> Option<Stats> {
        if errors.is_empty() {
            return None;
        }
        let n = errors.len() as f64;
        let sse: f64 = errors.iter().map(|e| e * e).sum();
        let mean = errors.iter().sum::<f64>() / n;
        let var = errors.iter().map(|e| (e - mean) * (e - mean)).sum::<f64>() / n;
        let mut sorted = errors.to_vec();
        sorted.sort_by(f64::total_cmp);
        let mid = sorted.len() / 2;
        let median = if sorted.len() % 2 == 1 {
            sorted[mid]
        } else {
            (sorted[mid - 1] + sorted[mid]) / 2.0
        };
        Some(Stats {
            rmse: (sse / n).sqrt(),
            mean,
            median,
            std: var.sqrt(),
            min: sorted[0],
            max: sorted[sorted.len() - 1],
            sse,
            n: errors.len(),
        })
    }
}

/// Absolute pose error, translation part (evo's `evo_ape`, `-r trans_part`).
#[derive(Clone, Debug, PartialEq)]
pub struct Ape {
    /// Statistics of the per-pose errors, m.
    pub stats: Stats,
    /// Per associated pose: (reference stamp, ‖p_est − p_ref‖ in m).
    pub errors: Vec<(Nanos, f64)>,
    /// With alignment: `world_from_estimate_world`, the SE(3) applied to the estimate.
    pub alignment: Option<Isometry3<f64>>,
    /// Number of associated pose pairs.
    pub matched: usize,
}

/// Relative pose error over a path distance, translation part (evo's
/// `evo_rpe --delta d --delta_unit m`, consecutive pairs).
#[derive(Clone, Debug, PartialEq)]
pub struct Rpe {
    /// Statistics of the per-pair errors, m.
    pub stats: Stats,
    /// Per pose pair (i, j): (reference stamp of pose j, ‖trans((Q_i⁻¹Q_j)⁻¹ P_i⁻¹P_j)‖ in m).
    pub errors: Vec<(Nanos, f64)>,
    /// With alignment: `world_from_estimate_world`, the SE(3) applied to the estimate.
    pub alignment: Option<Isometry3<f64>>,
    /// Number of associated pose pairs.
    pub matched: usize,
}

/// Which trajectory's travelled path chooses the RPE pose pairs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum PairsFrom {
    /// The estimate's path (evo's default).
    Estimate,
    /// The reference's path (evo's `--pairs_from_reference`).
    Reference,
}

/// The SE(3) Umeyama alignment `world_from_estimate_world` of the associated positions
/// (estimate onto reference), read in two passes over the association.
fn alignment(
    reference: &dyn Poses,
    estimate: &dyn Poses,
    max_diff: Nanos,
) -> Result<Isometry3<f64>, ScoreError> {
    let pairs = || {
        associate_poses(reference, estimate, max_diff)
            .map(|(r, e)| (e.1.translation.vector, r.1.translation.vector))
    };
    match umeyama_passes(pairs, false) {
        Ok(u) => Ok(u.isometry()),
        Err(AlignError::Empty) => Err(no_association(reference, estimate, max_diff)),
        Err(e) => Err(e.into()),
    }
}

fn no_association(reference: &dyn Poses, estimate: &dyn Poses, max_diff: Nanos) -> ScoreError {
    ScoreError::NoAssociation {
        reference_poses: reference.len(),
        estimate_poses: estimate.len(),
        max_diff,
    }
}

/// The associated `(stamp, reference pose, estimate pose)` triples, the estimate's
/// moved by `alignment` when given: one pass over each trajectory.
fn associated<'a>(
    reference: &'a dyn Poses,
    estimate: &'a dyn Poses,
    max_diff: Nanos,
    alignment: Option<Isometry3<f64>>,
) -> impl Iterator<Item = (Nanos, Isometry3<f64>, Isometry3<f64>)> + 'a {
    associate_poses(reference, estimate, max_diff).map(move |(r, e)| {
        let est = match alignment {
            Some(a) => a * e.1,
            None => e.1,
        };
        (r.0, r.1, est)
    })
}

/// APE, translation part: poses associated by time ([`associate`](super::align::associate), `max_diff`), the
/// estimate aligned onto the reference with SE(3) Umeyama when `align` (evo's `-a`), and
/// the error of each pair is `‖p_est − p_ref‖`. Reads the trajectories in passes (one,
/// three with alignment); holds the per-pair errors.
pub fn ape(
    reference: &dyn Poses,
    estimate: &dyn Poses,
    max_diff: Nanos,
    align: bool,
) -> Result<Ape, ScoreError> {
    let alignment = if align {
        Some(alignment(reference, estimate, max_diff)?)
    } else {
        None
    };
    let errors: Vec<(Nanos, f64)> = associated(reference, estimate, max_diff, alignment)
        .map(|(t, r, e)| (t, (e.translation.vector - r.translation.vector).norm()))
        .collect();
    let values: Vec<f64> = errors.iter().map(|e| e.1).collect();
    let stats =
        Stats::from_errors(&values).ok_or_else(|| no_association(reference, estimate, max_diff))?;
    Ok(Ape {
        stats,
        matched: errors.len(),
        errors,
        alignment,
    })
}

/// evo's `filter_pairs_by_path` (consecutive pairs): the first pose starts the first
/// pair; the path is summed pose to pose and each time it reaches `delta_m` (`≥`) the pose
/// closes the pair, opens the next and the sum restarts from zero.
pub fn pairs_by_path(positions: &[Vector3<f64>], delta_m: f64) -> Vec<(usize, usize)> {
    let mut pairs = Vec::new();
    let mut walk = PathPairs::new(delta_m);
    for (i, p) in positions.iter().enumerate() {
        if let Some(first) = walk.push(i, p) {
            pairs.push((first, i));
        }
    }
    pairs
}

/// [`pairs_by_path`] one position at a time: holds the open pair's first item and the
/// path summed since.
struct PathPairs<T> {
    delta_m: f64,
    open: Option<T>,
    last: Option<Vector3<f64>>,
    path: f64,
}

impl<T: Copy> PathPairs<T> {
    fn new(delta_m: f64) -> Self {
        PathPairs {
            delta_m,
            open: None,
            last: None,
            path: 0.0,
        }
    }
    /// Takes the next item at position `p`; returns the first item of the pair it closes.
    fn push(&mut self, item: T, p: &Vector3<f64>) -> Option<T> {
        let Some(last) = self.last.replace(*p) else {
            self.open = Some(item);
            return None;
        };
        self.path += (p - last).norm();
        if self.path >= self.delta_m {
            self.path = 0.0;
            return self.open.replace(item);
        }
        None
    }
}

/// RPE over `delta_m` of travelled path, translation part: poses associated by time,
/// optionally aligned (SE(3) alignment does not change relative poses, so the result is
/// the same up to rounding), consecutive pairs (i, j) by [`pairs_by_path`] on the
/// `pairs_from` trajectory's associated positions, and for each pair
/// `E = (Q_i⁻¹Q_j)⁻¹ (P_i⁻¹P_j)` (Q reference, P estimate), error `‖trans(E)‖`. Streams
/// the association, holding the open pair only.
pub fn rpe(
    reference: &dyn Poses,
    estimate: &dyn Poses,
    max_diff: Nanos,
    delta_m: f64,
    align: bool,
    pairs_from: PairsFrom,
) -> Result<Rpe, ScoreError> {
    if !(delta_m.is_finite() && delta_m >= 0.0) {
        return Err(ScoreError::InvalidDelta { delta_m });
    }
    let alignment = if align {
        Some(alignment(reference, estimate, max_diff)?)
    } else {
        None
    };
    let mut walk = PathPairs::new(delta_m);
    let mut errors: Vec<(Nanos, f64)> = Vec::new();
    let mut matched = 0;
    for (t, r, e) in associated(reference, estimate, max_diff, alignment) {
        matched += 1;
        let p = match pairs_from {
            PairsFrom::Estimate => e.translation.vector,
            PairsFrom::Reference => r.translation.vector,
        };
        if let Some((_, ri, ei)) = walk.push((t, r, e), &p) {
            let q_rel = ri.inverse() * r;
            let p_rel = ei.inverse() * e;
            let err = q_rel.inverse() * p_rel;
            errors.push((t, err.translation.vector.norm()));
        }
    }
    if matched == 0 {
        return Err(no_association(reference, estimate, max_diff));
    }
    let values: Vec<f64> = errors.iter().map(|e| e.1).collect();
    let stats = Stats::from_errors(&values).ok_or(ScoreError::NoRpePairs { delta_m, matched })?;
    Ok(Rpe {
        stats,
        errors,
        alignment,
        matched,
    })
}

/// The closed-loop metrics of the seed paper's Table 1 for one trajectory, in the ENU
/// world frame (x East, y North, z Up).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LoopMetrics {
    /// D: 3D distance between the first and the last position, m.
    pub d_m: f64,
    /// D_EN: distance between first and last position in the East-North plane, m.
    pub d_en_m: f64,
    /// D_U: |U_last − U_first|, m.
    pub d_u_m: f64,
    /// σ_U: population standard deviation of the altitude U over all poses, m.
    pub sigma_u_m: f64,
}

/// Table 1's D, D_EN, D_U and σ_U of `traj` (start-to-end discrepancy of a closed loop
/// and spread of the altitude). Two passes (mean, then spread).
pub fn closed_loop(traj: &dyn Poses) -> Result<LoopMetrics, ScoreError> {
    let (Some(first), Some(last)) = (traj.first(), traj.last()) else {
        return Err(ScoreError::Empty);
    };
    let d = last.1.translation.vector - first.1.translation.vector;
    let n = traj.len() as f64;
    let mean_u = traj.poses().map(|p| p.1.translation.z).sum::<f64>() / n;
    let var_u = traj
        .poses()
        .map(|p| (p.1.translation.z - mean_u).powi(2))
        .sum::<f64>()
        / n;
    Ok(LoopMetrics {
        d_m: d.norm(),
        d_en_m: d.x.hypot(d.y),
        d_u_m: d.z.abs(),
        sigma_u_m: var_u.sqrt(),
    })
}

/// The largest unaligned translation error `‖p_est − p_ref‖` over the associated pose
/// pairs whose reference stamp lies in one of the half-open `windows` `[start, end)`;
/// `None` when there is no such pair.
pub fn max_error_in_windows(
    reference: &dyn Poses,
    estimate: &dyn Poses,
    max_diff: Nanos,
    windows: &[(Nanos, Nanos)],
) -> Option<f64> {
    associated(reference, estimate, max_diff, None)
        .filter(|&(t, _, _)| windows.iter().any(|&(start, end)| start <= t && t < end))
        .map(|(_, r, e)| (e.translation.vector - r.translation.vector).norm())
        .reduce(f64::max)
}

/// Median spacing of a trajectory's stamps (zero with fewer than two poses).
fn median_period(traj: &dyn Poses) -> Nanos {
    let mut dts: Vec<i64> = Vec::with_capacity(traj.len().saturating_sub(1));
    let mut last = None;
    for (t, _) in traj.poses() {
        if let Some(l) = last.replace(t) {
            dts.push((t - l).0);
        }
    }
    if dts.is_empty() {
        return Nanos::ZERO;
    }
    dts.sort_unstable();
    let mid = dts.len() / 2;
    Nanos(if dts.len() % 2 == 1 {
        dts[mid]
    } else {
        dts[mid - 1] + (dts[mid] - dts[mid - 1]) / 2
    })
}

/// Fraction (0..=1) of the reference poses the estimate covers: a reference pose at `t`
/// is covered when an estimate stamp lies within `max(max_diff, P)` of `t`, `P` being the
/// estimate's median stamp spacing. This does not depend on the estimate's rate (a 10 Hz
/// source with no gap covers a 200 Hz reference fully), and a gap of `g > 2P` in the
/// estimate leaves `g − 2P` of reference time uncovered. Zero when the reference is empty.
pub fn coverage(reference: &dyn Poses, estimate: &dyn Poses, max_diff: Nanos) -> f64 {
    if reference.is_empty() {
        return 0.0;
    }
    let reach = max_diff.max(median_period(estimate));
    // A merge: `before` is the last estimate stamp < t, `after` the first ≥ t.
    let mut est = estimate.poses().map(|p| p.0);
    let (mut before, mut after) = (None, est.next());
    let covered = reference
        .poses()
        .filter(|&(t, _)| {
            while let Some(a) = after {
                if a >= t {
                    break;
                }
                before = Some(a);
                after = est.next();
            }
            after.is_some_and(|a| a - t <= reach) || before.is_some_and(|b| t - b <= reach)
        })
        .count();
    covered as f64 / reference.len() as f64
}

/// Every metric of one estimate source against the ground truth, for `report.json` and
/// the scenario expectations. A metric that cannot be computed is `None` (JSON `null`),
/// with the reason in `problems`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SourceScore {
    /// Poses in the reference (ground truth).
    pub reference_poses: usize,
    /// Poses in the estimate.
    pub estimate_poses: usize,
    /// Associated pose pairs (evo's "found N of max. M possible matching timestamps").
    pub matched: usize,
    /// ATE RMSE without alignment, m.
    pub ate_rmse_m: Option<f64>,
    /// ATE mean without alignment, m.
    pub ate_mean_m: Option<f64>,
    /// ATE maximum without alignment, m.
    pub ate_max_m: Option<f64>,
    /// ATE RMSE after SE(3) Umeyama alignment (evo's `-a`), m.
    pub ate_rmse_aligned_m: Option<f64>,
    /// RPE RMSE over `rpe_delta_m` of path, translation part, unaligned, m.
    pub rpe_rmse_m: Option<f64>,
    /// RPE pose pairs used.
    pub rpe_pairs: usize,
    /// Table 1's D of the estimate, m.
    pub d_m: Option<f64>,
    /// Table 1's D_EN of the estimate, m.
    pub d_en_m: Option<f64>,
    /// Table 1's D_U of the estimate, m.
    pub d_u_m: Option<f64>,
    /// Table 1's σ_U of the estimate, m.
    pub sigma_u_m: Option<f64>,
    /// Largest unaligned translation error inside the fault windows, m (`None` without
    /// windows or without an associated pose inside them).
    pub outage_max_error_m: Option<f64>,
    /// Fraction of ground-truth poses the estimate covers (see [`coverage`]).
    pub coverage: f64,
    /// Full statistics of the unaligned APE, m.
    pub ape: Option<Stats>,
    /// Full statistics of the aligned APE, m.
    pub ape_aligned: Option<Stats>,
    /// Full statistics of the RPE, m.
    pub rpe: Option<Stats>,
    /// Why metrics are missing.
    pub problems: Vec<String>,
    /// (reference stamp, unaligned translation error in m) of every associated pose, for
    /// plots (a run keeps only what they draw: [`crate::scoring::plots::thin_errors`]);
    /// not serialized.
    #[serde(skip)]
    pub ate_errors: Vec<(Nanos, f64)>,
}

impl SourceScore {
    /// The metric names [`SourceScore::metric`] knows, as scenario expectations spell them.
    pub const METRIC_NAMES: [&'static str; 11] = [
        "ate_rmse_m",
        "ate_mean_m",
        "ate_max_m",
        "ate_rmse_aligned_m",
        "rpe_rmse_m",
        "d_m",
        "d_en_m",
        "d_u_m",
        "sigma_u_m",
        "outage_max_error_m",
        "coverage",
    ];

    /// A metric by its expectation name (`ate_rmse_m`, ...; see [`Self::METRIC_NAMES`]);
    /// `None` for an unknown name or a metric that could not be computed.
    pub fn metric(&self, name: &str) -> Option<f64> {
        match name {
            "ate_rmse_m" => self.ate_rmse_m,
            "ate_mean_m" => self.ate_mean_m,
            "ate_max_m" => self.ate_max_m,
            "ate_rmse_aligned_m" => self.ate_rmse_aligned_m,
            "rpe_rmse_m" => self.rpe_rmse_m,
            "d_m" => self.d_m,
            "d_en_m" => self.d_en_m,
            "d_u_m" => self.d_u_m,
            "sigma_u_m" => self.sigma_u_m,
            "outage_max_error_m" => self.outage_max_error_m,
            "coverage" => Some(self.coverage),
            _ => None,
        }
    }
}

/// Scores one estimate source against the ground truth `reference` with `params`
/// (association tolerance, RPE distance and pairing); `fault_windows` are absolute
/// `[start, end)` stamps of injected faults (for `outage_max_error_m`). Never fails:
/// metrics that cannot be computed are `None` and explained in `problems`.
pub fn score_source(
    reference: &dyn Poses,
    estimate: &dyn Poses,
    params: &ScoringParams,
    fault_windows: &[(Nanos, Nanos)],
) -> SourceScore {
    let max_diff = Nanos::from_secs_f64(params.t_max_diff_s);
    let mut s = SourceScore {
        reference_poses: reference.len(),
        estimate_poses: estimate.len(),
        coverage: coverage(reference, estimate, max_diff),
        ..SourceScore::default()
    };
    match ape(reference, estimate, max_diff, false) {
        Ok(a) => {
            s.matched = a.matched;
            s.ate_rmse_m = Some(a.stats.rmse);
            s.ate_mean_m = Some(a.stats.mean);
            s.ate_max_m = Some(a.stats.max);
            s.ape = Some(a.stats);
            s.ate_errors = a.errors;
        }
        Err(e) => s.problems.push(format!("ate: {e}")),
    }
    if s.matched > 0 {
        match ape(reference, estimate, max_diff, true) {
            Ok(a) => {
                s.ate_rmse_aligned_m = Some(a.stats.rmse);
                s.ape_aligned = Some(a.stats);
            }
            Err(e) => s.problems.push(format!("ate_aligned: {e}")),
        }
        let pairs_from = if params.rpe_pairs_from_reference {
            PairsFrom::Reference
        } else {
            PairsFrom::Estimate
        };
        match rpe(
            reference,
            estimate,
            max_diff,
            params.rpe_delta_m,
            false,
            pairs_from,
        ) {
            Ok(r) => {
                s.rpe_rmse_m = Some(r.stats.rmse);
                s.rpe_pairs = r.stats.n;
                s.rpe = Some(r.stats);
            }
            Err(e) => s.problems.push(format!("rpe: {e}")),
        }
    }
    match closed_loop(estimate) {
        Ok(l) => {
            s.d_m = Some(l.d_m);
            s.d_en_m = Some(l.d_en_m);
            s.d_u_m = Some(l.d_u_m);
            s.sigma_u_m = Some(l.sigma_u_m);
        }
        Err(e) => s.problems.push(format!("closed loop: {e}")),
    }
    if !fault_windows.is_empty() {
        s.outage_max_error_m = max_error_in_windows(reference, estimate, max_diff, fault_windows);
        if s.outage_max_error_m.is_none() {
            s.problems
                .push("outage: no associated pose inside the fault windows".to_string());
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};
    use vinebench_msgs::{PoseSample, Trajectory};

    const MS: i64 = 1_000_000;

    fn pose(x: f64, y: f64, z: f64, yaw: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
        )
    }

    fn traj_from(samples: impl IntoIterator<Item = (i64, Isometry3<f64>)>) -> Trajectory {
        let mut t = Trajectory::new();
        for (ns, p) in samples {
            assert!(t.push(PoseSample {
                stamp: Nanos(ns),
                world_from_body: p,
                covariance: None,
            }));
        }
        t
    }

    /// A helix of radius `r` about the z axis (non-planar, so alignment is well posed),
    /// 200 poses at 10 ms, heading along the tangent.
    fn helix(r: f64) -> Trajectory {
        traj_from((0..200).map(|k| {
            let phi = k as f64 * 0.03;
            (
                1_600_000_000_000_000_000 + k * 10 * MS,
                pose(
                    r * phi.cos(),
                    r * phi.sin(),
                    0.2 * phi,
                    phi + std::f64::consts::FRAC_PI_2,
                ),
            )
        }))
    }

    fn approx(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol * (1.0 + b.abs())
    }

    #[test]
    fn stats_match_closed_form() {
        let s = Stats::from_errors(&[4.0, 1.0, 3.0, 2.0]).unwrap();
        assert_eq!(s.n, 4);
        assert_eq!(s.mean, 2.5);
        assert_eq!(s.median, 2.5);
        assert_eq!(s.sse, 30.0);
        assert!(approx(s.rmse, 7.5f64.sqrt(), 1e-15));
        assert!(approx(s.std, 1.25f64.sqrt(), 1e-15));
        assert_eq!((s.min, s.max), (1.0, 4.0));
        // The textbook population std example: 2, 4, 4, 4, 5, 5, 7, 9 → mean 5, std 2.
        let s = Stats::from_errors(&[2.0, 4.0, 4.0, 4.0, 5.0, 5.0, 7.0, 9.0]).unwrap();
        assert_eq!((s.mean, s.std, s.median), (5.0, 2.0, 4.5));
        assert_eq!(Stats::from_errors(&[5.0, 1.0, 3.0]).unwrap().median, 3.0);
        assert_eq!(Stats::from_errors(&[]), None);
    }

    #[test]
    fn ape_of_a_rigidly_moved_copy() {
        // estimate = T · reference with T a rotation θ about z plus a lift h: every point of
        // the helix (radius r) moves by a chord 2r·sin(θ/2) horizontally and h vertically.
        let (r, theta, h) = (5.0, 0.3, 0.4);
        let reference = helix(r);
        let t = Isometry3::from_parts(
            Translation3::new(0.0, 0.0, h),
            UnitQuaternion::from_euler_angles(0.0, 0.0, theta),
        );
        let mut estimate = reference.clone();
        for s in &mut estimate.samples {
            s.world_from_body = t * s.world_from_body;
        }
        let expected = (2.0 * r * (theta / 2.0).sin()).hypot(h);
        let a = ape(&reference, &estimate, Nanos(10 * MS), false).unwrap();
        assert_eq!(a.matched, 200);
        assert!(
            approx(a.stats.rmse, expected, 1e-12),
            "{} vs {expected}",
            a.stats.rmse
        );
        assert!(approx(a.stats.max, expected, 1e-12) && approx(a.stats.min, expected, 1e-12));
        assert!(a.stats.std < 1e-12);
        assert_eq!(a.alignment, None);
        // Aligned: zero error, and the alignment is T⁻¹.
        let a = ape(&reference, &estimate, Nanos(10 * MS), true).unwrap();
        assert!(a.stats.max < 1e-9, "{}", a.stats.max);
        let al = a.alignment.unwrap();
        assert!((al * t).translation.vector.norm() < 1e-9);
        assert!((al * t).rotation.angle() < 1e-9);
    }

    #[test]
    fn ape_with_known_offsets_over_time_association() {
        // Reference at 10 ms; estimate at every other reference stamp + 3 ms (a different
        // rate and a constant lag within max_diff), displaced by 0.1·k m in a fixed
        // direction: errors 0.1, 0.2, ..., 0.1·n.
        let reference = helix(3.0);
        let dir = Vector3::new(1.0, -2.0, 2.0) / 3.0;
        let estimate = traj_from(
            reference
                .samples
                .iter()
                .step_by(2)
                .enumerate()
                .map(|(k, s)| {
                    let mut p = s.world_from_body;
                    p.translation.vector += dir * (0.1 * (k + 1) as f64);
                    (s.stamp.0 + 3 * MS, p)
                }),
        );
        let n = estimate.len() as f64;
        let a = ape(&reference, &estimate, Nanos(10 * MS), false).unwrap();
        assert_eq!(a.matched, estimate.len());
        assert!(approx(a.stats.mean, 0.1 * (n + 1.0) / 2.0, 1e-12));
        assert!(approx(a.stats.median, 0.1 * (n + 1.0) / 2.0, 1e-12));
        assert!(approx(
            a.stats.rmse,
            0.1 * ((n + 1.0) * (2.0 * n + 1.0) / 6.0).sqrt(),
            1e-12
        ));
        assert!(approx(
            a.stats.std,
            0.1 * ((n * n - 1.0) / 12.0).sqrt(),
            1e-12
        ));
        assert!(approx(a.stats.max, 0.1 * n, 1e-12) && approx(a.stats.min, 0.1, 1e-12));
        // Errors are reported at the reference stamps.
        assert_eq!(a.errors[1].0, reference.samples[2].stamp);
        // 3 ms lag with a 2 ms tolerance: nothing associates.
        assert!(matches!(
            ape(&reference, &estimate, Nanos(2 * MS), false),
            Err(ScoreError::NoAssociation { .. })
        ));
    }

    #[test]
    fn ape_alignment_of_a_straight_line_is_an_error_value() {
        let reference = traj_from((0..20).map(|k| (k * 10 * MS, pose(k as f64, 0.0, 0.0, 0.0))));
        let r = ape(&reference, &reference, Nanos(10 * MS), true);
        assert!(matches!(
            r,
            Err(ScoreError::Alignment(AlignError::DegenerateRank {
                rank: 1
            }))
        ));
        assert!(ape(&reference, &reference, Nanos(10 * MS), false).is_ok());
    }

    /// A straight run along East with the body turned by `yaw` (crabbing, so relative
    /// translations are not along the body x axis), steps of `step` m (0.125: exact in
    /// binary, so path sums hit 1 m exactly), 81 poses at 10 ms.
    fn straight(yaw: f64, step: f64) -> Trajectory {
        traj_from((0..81).map(|k| (k * 10 * MS, pose(step * k as f64, 0.0, 0.0, yaw))))
    }

    #[test]
    fn rpe_of_a_constant_scale_drift() {
        // The estimate travels (1 + k) m per true metre. With pairs on the reference path
        // every 8 steps = 1 m, each relative error is k·1 m. With pairs on the estimate's
        // path (steps of 0.15625 m): 7 steps reach 1.09375 ≥ 1, so pairs span 0.875 m of
        // reference and the error is k·0.875.
        let k = 0.25;
        let reference = straight(0.5, 0.125);
        let estimate = straight(0.5, 0.125 * (1.0 + k));
        let r = rpe(
            &reference,
            &estimate,
            Nanos(MS),
            1.0,
            false,
            PairsFrom::Reference,
        )
        .unwrap();
        assert_eq!(r.stats.n, 10);
        assert!(
            approx(r.stats.rmse, k, 1e-12) && r.stats.std < 1e-12,
            "{:?}",
            r.stats
        );
        assert_eq!(r.errors[0].0, reference.samples[8].stamp);
        let r = rpe(
            &reference,
            &estimate,
            Nanos(MS),
            1.0,
            false,
            PairsFrom::Estimate,
        )
        .unwrap();
        assert_eq!(r.stats.n, 80 / 7);
        assert!(approx(r.stats.rmse, k * 0.875, 1e-12), "{:?}", r.stats);
        // SE(3) alignment does not change relative poses.
        let ra = rpe(
            &reference,
            &estimate,
            Nanos(MS),
            1.0,
            true,
            PairsFrom::Estimate,
        );
        // (a straight line cannot be aligned)
        assert!(matches!(ra, Err(ScoreError::Alignment(_))));
    }

    #[test]
    fn rpe_of_a_heading_drift() {
        // Same positions, but the estimate's heading drifts by c rad per metre travelled.
        // For a pair starting at path s (1 m apart), the reference sees Δp = 1 m straight
        // ahead, the estimate sees the same world displacement in a frame turned by c·s:
        // error = ‖R(c·s)ᵀ·Δ − Δ‖ = 2·sin(c·s/2).
        let c = 0.05;
        let reference = straight(0.0, 0.125);
        let estimate = traj_from(reference.samples.iter().map(|s| {
            let x = s.world_from_body.translation.x;
            (s.stamp.0, pose(x, 0.0, 0.0, c * x))
        }));
        let r = rpe(
            &reference,
            &estimate,
            Nanos(MS),
            1.0,
            false,
            PairsFrom::Reference,
        )
        .unwrap();
        assert_eq!(r.errors.len(), 10);
        for (m, &(_, e)) in r.errors.iter().enumerate() {
            let expected = 2.0 * (c * m as f64 / 2.0).sin();
            assert!(approx(e, expected, 1e-12), "pair {m}: {e} vs {expected}");
        }
        assert!(matches!(
            rpe(
                &reference,
                &estimate,
                Nanos(MS),
                100.0,
                false,
                PairsFrom::Reference
            ),
            Err(ScoreError::NoRpePairs { .. })
        ));
        assert!(matches!(
            rpe(
                &reference,
                &estimate,
                Nanos(MS),
                f64::NAN,
                false,
                PairsFrom::Reference
            ),
            Err(ScoreError::InvalidDelta { .. })
        ));
    }

    #[test]
    fn pairs_by_path_starts_at_the_first_pose() {
        let p: Vec<_> = [0.0, 0.5, 1.0, 1.25, 2.5, 2.75, 3.0]
            .iter()
            .map(|&x| Vector3::new(x, 0.0, 0.0))
            .collect();
        // Path reaches 1 at index 2, restarts: 0.25, 1.5 → index 4, then 0.25, 0.5.
        assert_eq!(pairs_by_path(&p, 1.0), vec![(0, 2), (2, 4)]);
        assert_eq!(pairs_by_path(&p[..1], 1.0), vec![]);
    }

    #[test]
    fn closed_loop_matches_table_1_definitions() {
        // Altitudes 2, 4, 4, 4, 5, 5, 7, 9: population std 2 (mean 5). Start (0, 0, 2),
        // end (3, 4, 9): D_EN = 5, D_U = 7, D = √74.
        let z = [2.0, 4.0, 4.0, 4.0, 5.0, 5.0, 7.0, 9.0];
        let traj = traj_from(z.iter().enumerate().map(|(k, &u)| {
            let (x, y) = if k == 7 {
                (3.0, 4.0)
            } else {
                (k as f64 * 10.0, (k as f64).sin())
            };
            (k as i64 * MS, pose(x, y, u, 0.0))
        }));
        let l = closed_loop(&traj).unwrap();
        assert!(approx(l.d_en_m, 5.0, 1e-15));
        assert!(approx(l.d_u_m, 7.0, 1e-15));
        assert!(approx(l.d_m, 74f64.sqrt(), 1e-15));
        assert!(approx(l.sigma_u_m, 2.0, 1e-15));
        assert_eq!(closed_loop(&Trajectory::new()), Err(ScoreError::Empty));
    }

    #[test]
    fn window_errors_and_coverage() {
        // Reference at 5 ms for 2 s; estimate at 100 ms with a 1 s gap; error grows with t.
        let reference =
            traj_from((0..400).map(|k| (k * 5 * MS, pose(k as f64 * 0.01, 0.0, 0.0, 0.0))));
        let estimate = traj_from(reference.samples.iter().step_by(20).filter_map(|s| {
            let t = s.stamp.0;
            (!(500 * MS..1500 * MS).contains(&t)).then(|| {
                let mut p = s.world_from_body;
                p.translation.y += t as f64 * 1e-9; // error = t in seconds
                (t, p)
            })
        }));
        // Window [0.3 s, 0.45 s): estimate poses at 0.3 and 0.4 s → max error 0.4.
        let w = [(Nanos(300 * MS), Nanos(450 * MS))];
        let m = max_error_in_windows(&reference, &estimate, Nanos(10 * MS), &w).unwrap();
        assert!(approx(m, 0.4, 1e-12), "{m}");
        // End is exclusive.
        let w = [(Nanos(300 * MS), Nanos(400 * MS))];
        let m = max_error_in_windows(&reference, &estimate, Nanos(10 * MS), &w).unwrap();
        assert!(approx(m, 0.3, 1e-12), "{m}");
        // A window inside the gap has no pose.
        let w = [(Nanos(700 * MS), Nanos(1200 * MS))];
        assert_eq!(
            max_error_in_windows(&reference, &estimate, Nanos(10 * MS), &w),
            None
        );
        // Coverage: P = 100 ms, so reference stamps within 100 ms of an estimate count.
        // Estimate at 0..0.4 s and 1.5..1.9 s; covered: [0, 0.5] ∪ [1.4, 1.995] → 101 + 120
        // reference poses of 400.
        let c = coverage(&reference, &estimate, Nanos(10 * MS));
        assert!(approx(c, 221.0 / 400.0, 1e-15), "{c}");
        assert_eq!(coverage(&reference, &reference, Nanos(10 * MS)), 1.0);
        assert_eq!(
            coverage(&reference, &Trajectory::new(), Nanos(10 * MS)),
            0.0
        );
        assert_eq!(coverage(&Trajectory::new(), &estimate, Nanos(10 * MS)), 0.0);
    }

    #[test]
    fn score_source_exposes_every_metric_by_name() {
        let reference = helix(4.0);
        let mut estimate = reference.clone();
        for (k, s) in estimate.samples.iter_mut().enumerate() {
            s.world_from_body.translation.z += 0.01 * (k % 7) as f64;
        }
        let params = ScoringParams::default();
        let w = [(reference.samples[50].stamp, reference.samples[60].stamp)];
        let s = score_source(&reference, &estimate, &params, &w);
        assert!(s.problems.is_empty(), "{:?}", s.problems);
        for name in SourceScore::METRIC_NAMES {
            assert!(s.metric(name).is_some_and(f64::is_finite), "{name}");
        }
        assert_eq!(s.metric("nonsense"), None);
        let a = ape(&reference, &estimate, Nanos(10 * MS), false).unwrap();
        assert_eq!(s.metric("ate_rmse_m"), Some(a.stats.rmse));
        assert!(approx(s.metric("ate_max_m").unwrap(), 0.06, 1e-12));
        assert_eq!(s.metric("coverage"), Some(1.0));
        assert_eq!(s.matched, 200);
        let l = closed_loop(&estimate).unwrap();
        assert_eq!(s.metric("sigma_u_m"), Some(l.sigma_u_m));
        // JSON round trip (per-pose errors are not serialized).
        let json = serde_json::to_string(&s).unwrap();
        let back: SourceScore = serde_json::from_str(&json).unwrap();
        assert!(back.ate_errors.is_empty() && !s.ate_errors.is_empty());
        assert_eq!((back.matched, back.rpe_pairs), (s.matched, s.rpe_pairs));
        for name in SourceScore::METRIC_NAMES {
            assert!(
                approx(back.metric(name).unwrap(), s.metric(name).unwrap(), 1e-15),
                "{name}"
            );
        }

        // No overlap in time: metrics are None with reasons, never a panic.
        let late = traj_from(
            estimate
                .samples
                .iter()
                .map(|p| (p.stamp.0 + 10_000 * MS, p.world_from_body)),
        );
        let s = score_source(&reference, &late, &params, &w);
        assert_eq!(s.ate_rmse_m, None);
        assert_eq!(s.metric("rpe_rmse_m"), None);
        assert!(s.d_m.is_some());
        assert!(
            s.problems
                .iter()
                .any(|p| p.starts_with("ate: no matching stamps")),
            "{:?}",
            s.problems
        );
        let s = score_source(&reference, &Trajectory::new(), &params, &[]);
        assert_eq!(s.metric("d_m"), None);
        assert_eq!(s.coverage, 0.0);
    }
}
