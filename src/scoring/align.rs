//! Time association and Umeyama alignment, with evo's semantics.
//!
//! These reproduce `evo.core.sync.matching_time_indices` / `associate_trajectories` and
//! `evo.core.geometry.umeyama_alignment` of evo 1.38 (github.com/MichaelGrupp/evo), so
//! that metrics computed here on the trajectories we write as TUM files are the ones evo
//! computes on those files.

use crate::scoring::spool::{Pose, Poses};
use nalgebra::{Isometry3, Matrix3, Rotation3, Similarity3, Translation3, UnitQuaternion, Vector3};
use thiserror::Error;
use vinebench_msgs::{Nanos, Trajectory};

/// Umeyama alignment is not possible.
#[derive(Clone, Debug, PartialEq, Error)]
pub enum AlignError {
    /// The two point sets differ in length.
    #[error("cannot align {src} points onto {dst} points: the sets must have the same length")]
    LengthMismatch {
        /// Number of source points.
        src: usize,
        /// Number of destination points.
        dst: usize,
    },
    /// No point to align.
    #[error("cannot align an empty point set")]
    Empty,
    /// The cross-covariance has rank < 2 (all points collinear or coincident), so the
    /// rotation is not determined (evo: "Degenerate covariance rank").
    #[error(
        "degenerate covariance rank {rank} (< 2): points are collinear or coincident, Umeyama alignment is not possible"
    )]
    DegenerateRank {
        /// Number of singular values above machine epsilon.
        rank: usize,
    },
    /// A point has a NaN or infinite coordinate.
    #[error("point {index} has a non-finite coordinate")]
    NonFinite {
        /// Index of the first such point (in `src`, then `dst`).
        index: usize,
    },
    /// The SVD did not converge.
    #[error("the SVD of the cross-covariance did not converge")]
    SvdFailed,
}

/// The least-squares similarity `dst ≈ scale · rotation · src + translation` found by
/// [`umeyama`]. With `dst` the reference (world) positions and `src` the estimate's,
/// `rotation`/`translation` form `world_from_estimate_world`.
#[derive(Clone, Debug, PartialEq)]
pub struct Umeyama {
    /// Rotation of the source points into the destination frame.
    pub rotation: Rotation3<f64>,
    /// Translation, in the destination frame, m.
    pub translation: Vector3<f64>,
    /// Scale factor (1 when not estimated).
    pub scale: f64,
}

impl Umeyama {
    /// The rigid part (`rotation`, `translation`), ignoring `scale`.
    pub fn isometry(&self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(self.translation),
            UnitQuaternion::from_rotation_matrix(&self.rotation),
        )
    }
    /// The whole similarity: `p ↦ t + s·R·p`.
    pub fn similarity(&self) -> Similarity3<f64> {
        Similarity3::from_isometry(self.isometry(), self.scale)
    }
    /// Maps a source point into the destination frame: `s·R·p + t`.
    pub fn transform_point(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * p * self.scale + self.translation
    }
}

/// Iteration cap of the 3×3 SVD (it converges in a few dozen).
const SVD_MAX_ITERATIONS: usize = 10_000;

/// Least-squares similarity between corresponding point sets (Umeyama, PAMI 1991, as in
/// evo's `umeyama_alignment(x=src, y=dst)`): finds `R ∈ SO(3)`, `t` and (when
/// `with_scale`) `c > 0` minimising `Σ ‖dst_i − (c·R·src_i + t)‖²`; `c = 1` otherwise.
///
/// Errors like evo: the cross-covariance must have at least two singular values above
/// `f64::EPSILON` (otherwise the points are collinear or coincident and the rotation is not
/// determined). The threshold is absolute, as in evo, so points collinear only up to
/// rounding may pass; the rotation about their line is then arbitrary, but the aligned
/// positions, hence the aligned ATE, are still the least-squares ones.
pub fn umeyama(
    src: &[Vector3<f64>],
    dst: &[Vector3<f64>],
    with_scale: bool,
) -> Result<Umeyama, AlignError> {
    if src.len() != dst.len() {
        return Err(AlignError::LengthMismatch {
            src: src.len(),
            dst: dst.len(),
        });
    }
    umeyama_passes(|| src.iter().copied().zip(dst.iter().copied()), with_scale)
}

/// [`umeyama`] over `(src, dst)` point pairs read in two passes (means, then centred
/// sums): `pairs` gives a fresh pass on every call. The arithmetic is that of
/// [`umeyama`] on slices, in the same order, so the result is identical; nothing is
/// held per point (what scoring uses on a long run's trajectories on disk).
pub fn umeyama_passes<I>(pairs: impl Fn() -> I, with_scale: bool) -> Result<Umeyama, AlignError>
where
    I: Iterator<Item = (Vector3<f64>, Vector3<f64>)>,
{
    let finite = |p: &Vector3<f64>| p.iter().all(|x| x.is_finite());
    let (mut count, mut bad_src, mut bad_dst) = (0_usize, None, None);
    let mut sum_src = Vector3::zeros();
    let mut sum_dst = Vector3::zeros();
    for (x, y) in pairs() {
        if bad_src.is_none() && !finite(&x) {
            bad_src = Some(count);
        }
        if bad_dst.is_none() && !finite(&y) {
            bad_dst = Some(count);
        }
        sum_src += x;
        sum_dst += y;
        count += 1;
    }
    if count == 0 {
        return Err(AlignError::Empty);
    }
    if let Some(index) = bad_src.or(bad_dst) {
        return Err(AlignError::NonFinite { index });
    }
    let n = count as f64;
    let mean_src = sum_src / n;
    let mean_dst = sum_dst / n;
    let mut sigma_src = 0.0;
    let mut cov = Matrix3::zeros();
    for (x, y) in pairs() {
        let dx = x - mean_src;
        let dy = y - mean_dst;
        sigma_src += dx.norm_squared();
        cov += dy * dx.transpose();
    }
    sigma_src /= n;
    cov /= n;
    // Sorted (descending) singular values, like numpy.
    let svd = nalgebra::SVD::try_new(cov, true, true, f64::EPSILON, SVD_MAX_ITERATIONS)
        .ok_or(AlignError::SvdFailed)?;
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err(AlignError::SvdFailed);
    };
    let d = svd.singular_values;
    let rank = d.iter().filter(|&&x| x > f64::EPSILON).count();
    if rank < 2 {
        return Err(AlignError::DegenerateRank { rank });
    }
    let mut s = Matrix3::identity();
    if u.determinant() * v_t.determinant() < 0.0 {
        // Keep a right-handed frame (Kabsch): flip the axis of the smallest singular value.
        s[(2, 2)] = -1.0;
    }
    let r = u * s * v_t;
    let scale = if with_scale {
        (d[0] * s[(0, 0)] + d[1] * s[(1, 1)] + d[2] * s[(2, 2)]) / sigma_src
    } else {
        1.0
    };
    let translation = mean_dst - r * mean_src * scale;
    Ok(Umeyama {
        rotation: Rotation3::from_matrix_unchecked(r),
        translation,
        scale,
    })
}

/// A stamp as evo sees it in our TUM file: the `f64` nearest to the exact decimal
/// seconds we write (Python's `float()` and Rust's `parse` both round correctly).
pub fn evo_seconds(t: Nanos) -> f64 {
    t.to_secs_string()
        .parse()
        .unwrap_or_else(|_| t.as_secs_f64())
}

/// Associates the poses of two trajectories by time, like evo's
/// `sync.associate_trajectories(reference, estimate, max_diff)` (nearest-time method, no
/// offset). Returns `(reference index, estimate index)` pairs.
///
/// The trajectory with fewer poses drives the association (the estimate when both have
/// the same number): for each of its stamps, the other trajectory's stamp nearest in time
/// is taken (the earlier one on a tie) and kept when `|Δt| ≤ max_diff`. Pairs come in the
/// order of the driving trajectory; the other side's indices are non-decreasing and may
/// repeat.
///
/// Decided in evo's arithmetic (see [`matching_time_indices`]): stamps and `max_diff` are
/// the `f64` seconds evo reads from our TUM files, so even ties and `|Δt| = max_diff` that
/// float rounding decides are decided as in evo.
pub fn associate(
    reference: &Trajectory,
    estimate: &Trajectory,
    max_diff: Nanos,
) -> Vec<(usize, usize)> {
    let max_diff = evo_seconds(max_diff);
    let ref_s: Vec<f64> = reference.stamps().map(evo_seconds).collect();
    let est_s: Vec<f64> = estimate.stamps().map(evo_seconds).collect();
    let estimate_longer = est_s.len() > ref_s.len();
    if estimate_longer {
        matching_time_indices(&ref_s, &est_s, max_diff)
    } else {
        matching_time_indices(&est_s, &ref_s, max_diff)
            .into_iter()
            .map(|(e, r)| (r, e))
            .collect()
    }
}

/// evo's `matching_time_indices(stamps_1, stamps_2, max_diff)` for sorted `stamps_2`,
/// in evo's float arithmetic: for each `stamps_1[i]` inside
/// `[stamps_2[0] − max_diff, stamps_2[last] + max_diff]`, the neighbours of its insertion
/// point in `stamps_2` are compared; the later one wins only when strictly nearer. Returns
/// `(index in stamps_1, index in stamps_2)` pairs with `|Δt| ≤ max_diff`.
pub fn matching_time_indices(
    stamps_1: &[f64],
    stamps_2: &[f64],
    max_diff: f64,
) -> Vec<(usize, usize)> {
    let mut pairs = Vec::new();
    let (Some(&first), Some(&last)) = (stamps_2.first(), stamps_2.last()) else {
        return pairs;
    };
    for (i1, &t1) in stamps_1.iter().enumerate() {
        if t1 < first - max_diff || t1 > last + max_diff {
            continue;
        }
        // numpy.searchsorted(side="right"): first index with stamps_2[i] > t1, clamped.
        let i2 = stamps_2
            .partition_point(|&t2| t2 <= t1)
            .min(stamps_2.len() - 1);
        let diff_ub = stamps_2[i2] - t1;
        let diff_lb = if i2 > 0 {
            t1 - stamps_2[i2 - 1]
        } else {
            f64::INFINITY
        };
        let best = if diff_ub <= max_diff && diff_ub < diff_lb {
            i2
        } else if diff_lb <= max_diff && diff_lb <= diff_ub {
            i2 - 1
        } else {
            continue;
        };
        pairs.push((i1, best));
    }
    pairs
}

/// [`matching_time_indices`] as a merge of two sorted streams: `driving` (evo's
/// `stamps_1`) and `other` (`stamps_2`, whose first and last stamps are `other_span`),
/// each item an evo-seconds stamp with a payload. For each driving item inside the span
/// (± `max_diff`), the neighbours of its insertion point in `other` are compared exactly
/// as there; yields `(driving payload, other payload)`. With sorted (non-decreasing)
/// driving stamps the pairs are the ones [`matching_time_indices`] finds, in its order,
/// while only two items of `other` are held.
pub struct MatchStream<T, D, O>
where
    D: Iterator<Item = (f64, T)>,
    O: Iterator<Item = (f64, T)>,
{
    driving: D,
    other: O,
    span: Option<(f64, f64)>,
    max_diff: f64,
    prev: Option<(f64, T)>,
    cur: Option<(f64, T)>,
    other_done: bool,
}

impl<T: Copy, D, O> MatchStream<T, D, O>
where
    D: Iterator<Item = (f64, T)>,
    O: Iterator<Item = (f64, T)>,
{
    /// The merge of `driving` onto `other` (see [`MatchStream`]); `other_span` is `None`
    /// when `other` is empty.
    pub fn new(driving: D, mut other: O, other_span: Option<(f64, f64)>, max_diff: f64) -> Self {
        let cur = other.next();
        MatchStream {
            driving,
            other,
            span: other_span,
            max_diff,
            prev: None,
            other_done: cur.is_none(),
            cur,
        }
    }
}

impl<T: Copy, D, O> Iterator for MatchStream<T, D, O>
where
    D: Iterator<Item = (f64, T)>,
    O: Iterator<Item = (f64, T)>,
{
    type Item = (T, T);
    fn next(&mut self) -> Option<(T, T)> {
        let (first, last) = self.span?;
        for (t1, a) in self.driving.by_ref() {
            if t1 < first - self.max_diff || t1 > last + self.max_diff {
                continue;
            }
            // The insertion point (numpy.searchsorted, side="right", clamped to the last
            // item): advance while the current item is not after t1 and another follows.
            while let Some(c) = self.cur {
                if c.0 > t1 || self.other_done {
                    break;
                }
                match self.other.next() {
                    Some(n) => {
                        self.prev = Some(c);
                        self.cur = Some(n);
                    }
                    None => self.other_done = true,
                }
            }
            let (t_ub, b_ub) = self.cur?;
            let diff_ub = t_ub - t1;
            let diff_lb = self.prev.map_or(f64::INFINITY, |(t, _)| t1 - t);
            if diff_ub <= self.max_diff && diff_ub < diff_lb {
                return Some((a, b_ub));
            }
            if diff_lb <= self.max_diff && diff_lb <= diff_ub {
                if let Some((_, b_lb)) = self.prev {
                    return Some((a, b_lb));
                }
            }
        }
        None
    }
}

/// [`associate`] on two pose sequences read as streams: yields `(reference pose,
/// estimate pose)` pairs in the same order and with the same choices, holding nothing
/// per pose (trajectories on disk are associated in one pass over each).
pub fn associate_poses<'a>(
    reference: &'a dyn Poses,
    estimate: &'a dyn Poses,
    max_diff: Nanos,
) -> Box<dyn Iterator<Item = (Pose, Pose)> + 'a> {
    let max_diff = evo_seconds(max_diff);
    let span = |p: &dyn Poses| {
        p.first()
            .zip(p.last())
            .map(|(a, b)| (evo_seconds(a.0), evo_seconds(b.0)))
    };
    let stream = |p: &'a dyn Poses| p.poses().map(|x| (evo_seconds(x.0), x));
    if estimate.len() > reference.len() {
        Box::new(MatchStream::new(
            stream(reference),
            stream(estimate),
            span(estimate),
            max_diff,
        ))
    } else {
        Box::new(
            MatchStream::new(
                stream(estimate),
                stream(reference),
                span(reference),
                max_diff,
            )
            .map(|(e, r)| (r, e)),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use vinebench_msgs::PoseSample;

    fn random_points(rng: &mut ChaCha8Rng, n: usize) -> Vec<Vector3<f64>> {
        (0..n)
            .map(|_| {
                Vector3::new(
                    rng.random_range(-50.0..50.0),
                    rng.random_range(-50.0..50.0),
                    rng.random_range(-5.0..5.0),
                )
            })
            .collect()
    }

    fn random_rotation(rng: &mut ChaCha8Rng) -> Rotation3<f64> {
        let axis = Vector3::new(
            rng.random::<f64>() - 0.5,
            rng.random::<f64>() - 0.5,
            rng.random::<f64>() - 0.5,
        );
        Rotation3::new(axis.normalize() * rng.random_range(-3.0..3.0))
    }

    #[test]
    fn umeyama_recovers_a_known_rigid_motion() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for _ in 0..20 {
            let r = random_rotation(&mut rng);
            let t = Vector3::new(
                rng.random_range(-100.0..100.0),
                rng.random_range(-100.0..100.0),
                rng.random_range(-10.0..10.0),
            );
            let src = random_points(&mut rng, 30);
            let dst: Vec<_> = src.iter().map(|p| r * p + t).collect();
            let a = umeyama(&src, &dst, false).unwrap();
            assert!((a.rotation.matrix() - r.matrix()).amax() < 1e-12);
            assert!((a.translation - t).amax() < 1e-10);
            assert_eq!(a.scale, 1.0);
            // Consistency of the convenience views.
            let p = src[3];
            assert!(
                (a.isometry() * nalgebra::Point3::from(p) - nalgebra::Point3::from(dst[3])).norm()
                    < 1e-10
            );
        }
    }

    #[test]
    fn umeyama_recovers_scale_when_asked() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let r = random_rotation(&mut rng);
        let t = Vector3::new(3.0, -4.0, 0.5);
        let c = 2.75;
        let src = random_points(&mut rng, 25);
        let dst: Vec<_> = src.iter().map(|p| r * p * c + t).collect();
        let a = umeyama(&src, &dst, true).unwrap();
        assert!((a.scale - c).abs() < 1e-12);
        assert!((a.rotation.matrix() - r.matrix()).amax() < 1e-12);
        assert!((a.translation - t).amax() < 1e-10);
        let sim = a.similarity();
        let q = sim * nalgebra::Point3::from(src[0]);
        assert!((q.coords - dst[0]).norm() < 1e-10);
        assert!((a.transform_point(&src[1]) - dst[1]).norm() < 1e-10);
        // Without scale the best rotation is still found, but the residual is not zero.
        let b = umeyama(&src, &dst, false).unwrap();
        assert!((b.rotation.matrix() - r.matrix()).amax() < 1e-12);
    }

    #[test]
    fn umeyama_handles_reflection_case_with_a_proper_rotation() {
        // Planar points (rank 2): the SVD is free to return det(U)·det(V) = −1; the result
        // must still be a rotation and fit exactly.
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let r = random_rotation(&mut rng);
        let src: Vec<_> = (0..12)
            .map(|_| {
                Vector3::new(
                    rng.random_range(-5.0..5.0),
                    rng.random_range(-5.0..5.0),
                    0.0,
                )
            })
            .collect();
        let dst: Vec<_> = src.iter().map(|p| r * p).collect();
        let a = umeyama(&src, &dst, false).unwrap();
        assert!((a.rotation.matrix().determinant() - 1.0).abs() < 1e-12);
        assert!((a.rotation.matrix() - r.matrix()).amax() < 1e-10);
    }

    #[test]
    fn umeyama_rejects_degenerate_input() {
        // Exactly collinear (integer coordinates along x: the covariance is exact and has
        // one non-zero singular value).
        let line: Vec<_> = (0..10).map(|i| Vector3::new(i as f64, 0.0, 0.0)).collect();
        let moved: Vec<_> = line
            .iter()
            .map(|p| p + Vector3::new(1.0, 2.0, 3.0))
            .collect();
        assert_eq!(
            umeyama(&line, &moved, false),
            Err(AlignError::DegenerateRank { rank: 1 })
        );
        let same = vec![Vector3::new(1.0, 1.0, 1.0); 5];
        assert!(matches!(
            umeyama(&same, &same, true),
            Err(AlignError::DegenerateRank { rank: 0 })
        ));
        assert_eq!(umeyama(&[], &[], false), Err(AlignError::Empty));
        assert_eq!(
            umeyama(&line[..3], &line[..2], false),
            Err(AlignError::LengthMismatch { src: 3, dst: 2 })
        );
        let mut bad = line.clone();
        bad[2].x = f64::NAN;
        assert_eq!(
            umeyama(&bad, &moved, false),
            Err(AlignError::NonFinite { index: 2 })
        );
    }

    fn traj(stamps_ns: &[i64]) -> Trajectory {
        let mut t = Trajectory::new();
        for &s in stamps_ns {
            assert!(t.push(PoseSample {
                stamp: Nanos(s),
                world_from_body: Isometry3::identity(),
                covariance: None,
            }));
        }
        t
    }

    /// A direct transcription of the definition (exact integer arithmetic): for each stamp
    /// of the shorter trajectory (the estimate when equal), the argmin of |Δt| over the
    /// other (first index on ties), kept when |Δt| ≤ max_diff.
    fn brute_force(reference: &[i64], estimate: &[i64], max_diff: i64) -> Vec<(usize, usize)> {
        let est_short = estimate.len() <= reference.len();
        let (short, long) = if est_short {
            (estimate, reference)
        } else {
            (reference, estimate)
        };
        let mut out = Vec::new();
        for (i, &s) in short.iter().enumerate() {
            let Some((j, d)) = long.iter().map(|&l| (l - s).abs()).enumerate().fold(
                None,
                |best: Option<(usize, i64)>, (j, d)| match best {
                    Some((_, bd)) if bd <= d => best,
                    _ => Some((j, d)),
                },
            ) else {
                continue;
            };
            if d <= max_diff {
                out.push(if est_short { (j, i) } else { (i, j) });
            }
        }
        out
    }

    // Stamps that are multiples of 1/1024 s (976_562.5 ns → use 2^-7 s = 7_812_500 ns) are
    // exact in binary, so float ties and boundaries are real ties and boundaries.
    const Q: i64 = 7_812_500;

    #[test]
    fn association_shorter_drives_and_ties_take_the_earlier() {
        // Reference (longer) at 0, 2Q, 4Q, ...; estimate at odd multiples: every estimate
        // stamp is exactly halfway between two reference stamps.
        let reference: Vec<i64> = (0..10).map(|k| 2 * k * Q).collect();
        let estimate: Vec<i64> = (0..4).map(|k| (2 * k + 1) * Q).collect();
        let pairs = associate(&traj(&reference), &traj(&estimate), Nanos(Q));
        assert_eq!(pairs, vec![(0, 0), (1, 1), (2, 2), (3, 3)]);
        assert_eq!(pairs, brute_force(&reference, &estimate, Q));
        // Just below the tie distance nothing matches.
        assert!(associate(&traj(&reference), &traj(&estimate), Nanos(Q - 1)).is_empty());
    }

    #[test]
    fn association_max_diff_is_inclusive() {
        let reference = vec![0, 8 * Q, 16 * Q];
        let estimate = vec![Q, 10 * Q];
        // |Δt| = Q and 2Q.
        assert_eq!(
            associate(&traj(&reference), &traj(&estimate), Nanos(2 * Q)),
            vec![(0, 0), (1, 1)]
        );
        assert_eq!(
            associate(&traj(&reference), &traj(&estimate), Nanos(Q)),
            vec![(0, 0)]
        );
    }

    #[test]
    fn association_equal_lengths_iterate_the_estimate_and_may_repeat() {
        // Equal lengths: the estimate drives, so two estimate stamps may map to the same
        // reference pose (and a reference pose may stay unmatched).
        let reference = vec![0, 4 * Q, 100 * Q];
        let estimate = vec![Q, 2 * Q, 3 * Q];
        let pairs = associate(&traj(&reference), &traj(&estimate), Nanos(3 * Q));
        assert_eq!(pairs, vec![(0, 0), (0, 1), (1, 2)]);
        assert_eq!(pairs, brute_force(&reference, &estimate, 3 * Q));
        // Swapping the roles (reference now drives, being shorter by one) changes the pairs.
        let pairs = associate(&traj(&estimate[..2]), &traj(&reference), Nanos(3 * Q));
        assert_eq!(pairs, brute_force(&estimate[..2], &reference, 3 * Q));
        assert_eq!(pairs, vec![(0, 0), (1, 0)]);
    }

    #[test]
    fn association_matches_brute_force_on_random_stamps() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for _ in 0..200 {
            let make = |rng: &mut ChaCha8Rng, step: i64| {
                let n = rng.random_range(0..30);
                let mut t = rng.random_range(-5..5) * Q;
                (0..n)
                    .map(|_| {
                        t += rng.random_range(1..=step) * Q;
                        t
                    })
                    .collect::<Vec<i64>>()
            };
            let a = make(&mut rng, 4);
            let b = make(&mut rng, 4);
            let max_diff = rng.random_range(0..4) * Q;
            assert_eq!(
                associate(&traj(&a), &traj(&b), Nanos(max_diff)),
                brute_force(&a, &b, max_diff),
                "{a:?} {b:?} {max_diff}"
            );
        }
    }

    #[test]
    fn streamed_association_equals_the_indexed_one() {
        // Stamps close enough (tens of ns at 1.7e9 s) that evo's f64 seconds tie or
        // collapse, plus the ordinary cases.
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        for case in 0..400 {
            let base = if case % 2 == 0 {
                0
            } else {
                1_700_000_000_000_000_000
            };
            let make = |rng: &mut ChaCha8Rng| {
                let step = if case % 4 < 2 { Q } else { 97 };
                let n = rng.random_range(0..40);
                let mut t = base + rng.random_range(-5..5) * step;
                (0..n)
                    .map(|_| {
                        t += rng.random_range(1..=4) * step;
                        t
                    })
                    .collect::<Vec<i64>>()
            };
            let (a, b) = (traj(&make(&mut rng)), traj(&make(&mut rng)));
            let max_diff = Nanos(rng.random_range(0..4) * if case % 4 < 2 { Q } else { 97 });
            let indexed: Vec<(i64, i64)> = associate(&a, &b, max_diff)
                .into_iter()
                .map(|(r, e)| (a.samples[r].stamp.0, b.samples[e].stamp.0))
                .collect();
            let streamed: Vec<(i64, i64)> = associate_poses(&a, &b, max_diff)
                .map(|(r, e)| (r.0.0, e.0.0))
                .collect();
            assert_eq!(streamed, indexed, "case {case}");
        }
    }

    #[test]
    fn umeyama_from_passes_is_bit_identical_to_slices() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let src = random_points(&mut rng, 500);
        let dst = random_points(&mut rng, 500);
        let a = umeyama(&src, &dst, true).unwrap();
        let b = umeyama_passes(|| src.iter().copied().zip(dst.iter().copied()), true).unwrap();
        assert_eq!(a, b);
        assert_eq!(
            umeyama_passes(std::iter::empty, false),
            Err(AlignError::Empty)
        );
    }

    #[test]
    fn evo_seconds_is_correctly_rounded() {
        assert_eq!(evo_seconds(Nanos(10_000_000)), 0.01);
        assert_eq!(
            evo_seconds(Nanos(1_631_696_400_005_000_000)),
            1631696400.005
        );
        assert_eq!(evo_seconds(Nanos(-1_500_000_000)), -1.5);
    }
}
