//! RPE pose pairs as evo 1.38.1 selects them (`evo.core.filters`): every `delta` frames,
//! metres of path or degrees/radians of rotation, consecutive (non-overlapping, the
//! accumulated step reset at each pick) or all pairs (within `delta · delta_tol`).

use super::lie::{self, AngleError, Pose};
use nalgebra::{Rotation3, UnitQuaternion};

/// The unit of RPE's `delta` (evo's `--delta_unit f|m|d|r`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
pub enum DeltaUnit {
    /// Frames (poses).
    #[value(name = "f")]
    Frames,
    /// Metres of path.
    #[value(name = "m")]
    Meters,
    /// Degrees of rotation.
    #[value(name = "d")]
    Degrees,
    /// Radians of rotation.
    #[value(name = "r")]
    Radians,
}

impl DeltaUnit {
    /// evo's name of the unit (`frames`, `m`, `deg`, `rad`).
    pub fn evo_name(self) -> &'static str {
        match self {
            DeltaUnit::Frames => "frames",
            DeltaUnit::Meters => "m",
            DeltaUnit::Degrees => "deg",
            DeltaUnit::Radians => "rad",
        }
    }
}

/// Why no pairs could be formed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PairsError {
    /// An angle between poses could not be computed.
    #[error(transparent)]
    Angle(#[from] AngleError),
    /// An angle delta outside [0, 180°] / [0, π].
    #[error("delta angle must be within [0, {max}] ({unit})")]
    AngleRange {
        /// The upper bound.
        max: f64,
        /// The unit.
        unit: &'static str,
    },
    /// All pairs within the angle tolerance would be too many.
    #[error(
        "more than {max} pose pairs within the angle tolerance: narrow -t/--delta_tol or use \
         consecutive pairs"
    )]
    TooManyPairs {
        /// The limit.
        max: usize,
    },
    /// A frame delta that is not a positive integer.
    #[error("delta must be a positive integer for delta unit frames, found {0}")]
    Frames(f64),
}

/// The pairs `(i, j)` of `poses` for `delta` in `unit` (tolerance `delta · rel_tol` in
/// all-pairs path and angle modes).
pub fn id_pairs(
    poses: &[Pose],
    delta: f64,
    unit: DeltaUnit,
    rel_tol: f64,
    all_pairs: bool,
) -> Result<Vec<(usize, usize)>, PairsError> {
    let tol = delta * rel_tol;
    match unit {
        DeltaUnit::Frames => {
            if !(delta >= 1.0 && delta.fract() == 0.0 && delta < 1e15) {
                return Err(PairsError::Frames(delta));
            }
            Ok(by_index(poses.len(), delta as usize, all_pairs))
        }
        DeltaUnit::Meters => Ok(by_path(poses, delta, tol, all_pairs)),
        DeltaUnit::Degrees | DeltaUnit::Radians => {
            let degrees = unit == DeltaUnit::Degrees;
            let max = if degrees { 180.0 } else { std::f64::consts::PI };
            if !(0.0..=max).contains(&delta) {
                return Err(PairsError::AngleRange {
                    max,
                    unit: unit.evo_name(),
                });
            }
            let (delta, tol) = if degrees {
                (delta.to_radians(), tol.to_radians())
            } else {
                (delta, tol)
            };
            by_angle(poses, delta, tol, all_pairs)
        }
    }
}

/// Every `delta` frames: `(0, d), (d, 2d), ...`, or all `(i, i + d)`.
pub fn by_index(n: usize, delta: usize, all_pairs: bool) -> Vec<(usize, usize)> {
    if all_pairs {
        (0..n)
            .filter(|i| i + delta < n)
            .map(|i| (i, i + delta))
            .collect()
    } else {
        let ids: Vec<usize> = (0..n).step_by(delta).collect();
        ids.windows(2).map(|w| (w[0], w[1])).collect()
    }
}

/// Every `delta` metres of path.
pub fn by_path(poses: &[Pose], delta: f64, tol: f64, all_pairs: bool) -> Vec<(usize, usize)> {
    let positions: Vec<_> = poses.iter().map(lie::translation).collect();
    if all_pairs {
        // evo: accumulated distances, then per start the nearest path length to delta.
        let mut distances = Vec::with_capacity(positions.len());
        let mut acc = 0.0;
        distances.push(0.0);
        for w in positions.windows(2) {
            acc += (w[0] - w[1]).norm();
            distances.push(acc);
        }
        let mut pairs = Vec::new();
        for i in 0..distances.len().saturating_sub(1) {
            let mut best: Option<(usize, f64)> = None;
            for (k, d) in distances[i + 1..].iter().enumerate() {
                let e = (d - distances[i] - delta).abs();
                if best.is_none_or(|(_, b)| e < b) {
                    best = Some((k, e));
                }
            }
            if let Some((k, e)) = best
                && e <= tol
            {
                pairs.push((i, i + 1 + k));
            }
        }
        pairs
    } else {
        let mut ids = vec![0];
        let mut current = 0.0;
        for i in 1..positions.len() {
            current += (positions[i] - positions[i - 1]).norm();
            if current >= delta {
                ids.push(i);
                current = 0.0;
            }
        }
        ids.windows(2).map(|w| (w[0], w[1])).collect()
    }
}

/// Most pairs of the all-pairs angle mode (the only one that can grow with the square of
/// the poses): 50 million, 800 MB.
pub const MAX_ANGLE_PAIRS: usize = 50_000_000;

/// Most iterations of the SVD in [`by_angle`] (a 3×3 converges in a handful).
const SVD_MAX_ITER: usize = 1000;

/// Every `delta` radians of rotation.
pub fn by_angle(
    poses: &[Pose],
    delta: f64,
    tol: f64,
    all_pairs: bool,
) -> Result<Vec<(usize, usize)>, PairsError> {
    let mut pairs = Vec::new();
    if all_pairs {
        // scipy's Rotation.from_matrix of each pose (orthogonalised as in
        // lie::rotation_angle), then the angle of q_i⁻¹·q_j.
        let quats: Vec<[f64; 4]> = poses
            .iter()
            .map(|p| {
                // The nearest rotation (polar factor U·Vᵀ, as scipy orthogonalises), by an
                // SVD with bounded iterations: nalgebra's iterative `from_matrix` never
                // returns for some damaged poses (a zero or overflowing rotation block:
                // its perturbation loop compares equal norms for ever). A pose without a
                // proper nearest rotation gets no angle (NaN: it pairs with nothing).
                let r = lie::rotation(p);
                let polar = r
                    .norm_squared()
                    .is_finite()
                    .then(|| nalgebra::SVD::try_new(r, true, true, f64::EPSILON, SVD_MAX_ITER))
                    .flatten()
                    .and_then(|svd| Some(svd.u? * svd.v_t?))
                    .filter(|m| m.determinant() > 0.0);
                let Some(polar) = polar else {
                    return [f64::NAN; 4];
                };
                let q =
                    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(polar));
                [q.w, q.i, q.j, q.k]
            })
            .collect();
        let (lo, hi) = (delta - tol, delta + tol);
        for i in 0..quats.len().saturating_sub(1) {
            for (j, qj) in quats.iter().enumerate().skip(i + 1) {
                let a = lie::quaternion_delta_angle(quats[i], *qj);
                if lo <= a && a <= hi {
                    if pairs.len() == MAX_ANGLE_PAIRS {
                        return Err(PairsError::TooManyPairs {
                            max: MAX_ANGLE_PAIRS,
                        });
                    }
                    pairs.push((i, j));
                }
            }
        }
    } else {
        let mut acc = 0.0;
        let mut start = 0;
        for i in 0..poses.len().saturating_sub(1) {
            let r = lie::rotation(&poses[i]).transpose() * lie::rotation(&poses[i + 1]);
            acc += lie::rotation_angle(&r)?;
            if acc >= delta {
                pairs.push((start, i + 1));
                acc = 0.0;
                start = i + 1;
            }
        }
    }
    Ok(pairs)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, Vector3};

    fn at_z(z: &[f64]) -> Vec<Pose> {
        z.iter()
            .map(|&z| lie::se3(&Matrix3::identity(), &Vector3::new(0.0, 0.0, z)))
            .collect()
    }

    #[test]
    fn extreme_poses_do_not_hang_the_angle_pairs() {
        // A damaged file's pose (entries near f64::MAX or infinite, or a zero rotation
        // block) once kept `Rotation3::from_matrix` iterating for ever (found by
        // tests/fuzz_inputs.rs).
        let mut poses = at_z(&[0.0, 1.0, 2.0, 3.0]);
        for (k, v) in [f64::MAX, f64::INFINITY, -1e300].into_iter().enumerate() {
            poses[k][(0, 1)] = v;
            poses[k][(1, 0)] = -v;
        }
        for i in 0..3 {
            for j in 0..3 {
                poses[3][(i, j)] = 0.0;
            }
        }
        for all in [true, false] {
            let _ = by_angle(&poses, 0.1, 0.05, all);
        }
    }

    #[test]
    fn evo_filter_test_cases() {
        // evo's test_filters.py.
        let poses = at_z(&[0.0, 1.0, 2.0, 3.0, 4.0]);
        assert_eq!(by_path(&poses, 2.0, 0.0, false), vec![(0, 2), (2, 4)]);
        let poses = at_z(&[0.0, 0.5, 0.0, 1.0]);
        assert_eq!(by_path(&poses, 1.0, 0.0, true), vec![(0, 2), (2, 3)]);
        assert_eq!(by_index(7, 3, false), vec![(0, 3), (3, 6)]);
        assert_eq!(by_index(5, 3, true), vec![(0, 3), (1, 4)]);
    }

    #[test]
    fn angle_pairs_every_delta_of_rotation() {
        // 10° steps about z: consecutive 25° picks after 3 steps; all pairs with 20° ± 1°
        // are those two steps apart.
        let poses: Vec<Pose> = (0..7)
            .map(|k| {
                let r =
                    Rotation3::from_axis_angle(&Vector3::z_axis(), (10.0 * k as f64).to_radians());
                lie::se3(r.matrix(), &Vector3::zeros())
            })
            .collect();
        let c = id_pairs(&poses, 25.0, DeltaUnit::Degrees, 0.1, false).unwrap();
        assert_eq!(c, vec![(0, 3), (3, 6)]);
        let a = id_pairs(&poses, 20.0, DeltaUnit::Degrees, 0.05, true).unwrap();
        assert_eq!(a, vec![(0, 2), (1, 3), (2, 4), (3, 5), (4, 6)]);
        assert!(id_pairs(&poses, 200.0, DeltaUnit::Degrees, 0.1, false).is_err());
        assert!(id_pairs(&poses, 1.5, DeltaUnit::Frames, 0.1, false).is_err());
    }
}
