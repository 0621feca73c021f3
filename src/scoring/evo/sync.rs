//! Association by stamps exactly as evo 1.38.1 does it (`evo.core.sync`): the trajectory
//! with fewer poses drives (the estimate when both have as many), each of its poses is
//! matched on its own to the nearest pose of the other within `max_diff` (so a pose of the
//! longer one may be used twice), ties go to the earlier pose, the offset is added to the
//! longer one's stamps inside the matching only, and an unsorted longer trajectory is
//! searched linearly (with evo's warning).

/// The matched indices `(into stamps_1, into stamps_2)` and whether `stamps_2` (after
/// the offset) was sorted.
pub fn matching_time_indices(
    stamps_1: &[f64],
    stamps_2: &[f64],
    max_diff: f64,
    offset_2: f64,
) -> (Vec<usize>, Vec<usize>, bool) {
    let s2: Vec<f64> = stamps_2.iter().map(|s| s + offset_2).collect();
    let (mut m1, mut m2) = (Vec::new(), Vec::new());
    // numpy's `np.all(np.diff(s2) >= 0)`: a NaN makes it unsorted.
    let sorted = s2.windows(2).all(|w| w[1] - w[0] >= 0.0);
    if !sorted {
        for (i1, &t1) in stamps_1.iter().enumerate() {
            let mut best: Option<(usize, f64)> = None;
            for (i2, &t2) in s2.iter().enumerate() {
                let d = (t2 - t1).abs();
                // argmin: the first minimum (a NaN is the minimum in numpy; none here).
                if best.is_none_or(|(_, b)| d < b) {
                    best = Some((i2, d));
                }
            }
            if let Some((i2, d)) = best
                && d <= max_diff
            {
                m1.push(i1);
                m2.push(i2);
            }
        }
        return (m1, m2, false);
    }
    let (m1, m2) = crate::scoring::align::matching_time_indices(stamps_1, &s2, max_diff)
        .into_iter()
        .unzip();
    (m1, m2, true)
}

/// The association of a reference and an estimate.
#[derive(Clone, Debug, PartialEq)]
pub struct Association {
    /// Matched reference indices, one per matched pair.
    pub reference: Vec<usize>,
    /// Matched estimate indices.
    pub estimate: Vec<usize>,
    /// The longer trajectory's stamps were not sorted (evo warns and searches linearly).
    pub unsorted: bool,
}

/// Associates `reference` and `estimate` stamps as evo's `associate_trajectories`
/// (`offset` is `--t_offset`, added to the estimate's stamps).
pub fn associate(reference: &[f64], estimate: &[f64], max_diff: f64, offset: f64) -> Association {
    let second_longer = estimate.len() > reference.len();
    if second_longer {
        let (r, e, sorted) = matching_time_indices(reference, estimate, max_diff, offset);
        Association {
            reference: r,
            estimate: e,
            unsorted: !sorted,
        }
    } else {
        let (e, r, sorted) = matching_time_indices(estimate, reference, max_diff, -offset);
        Association {
            reference: r,
            estimate: e,
            unsorted: !sorted,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn evo_unit_test_cases() {
        // From evo's test_sync.py and the 1.38.1 behaviour on duplicates.
        assert_eq!(
            matching_time_indices(&[0.005], &[0.0, 0.01], 0.006, 0.0),
            (vec![0], vec![0], true)
        );
        assert_eq!(
            matching_time_indices(&[0.0], &[1.0, 0.0, 2.0], 0.01, 0.0),
            (vec![0], vec![1], false)
        );
        assert_eq!(
            matching_time_indices(&[1.0, 2.0], &[1.0, 1.0, 2.0], 0.01, 0.0),
            (vec![0, 1], vec![1, 2], true)
        );
        assert_eq!(
            matching_time_indices(&[1.0, 2.0, 3.0], &[1.0, 1.0, 2.0, 3.0, 3.0], 0.01, 0.0),
            (vec![0, 1, 2], vec![1, 2, 3], true)
        );
        assert_eq!(
            matching_time_indices(&[1.0, 2.0, 3.0], &[3.0, 1.0, 1.0, 2.0], 0.01, 0.0),
            (vec![0, 1, 2], vec![1, 3, 0], false)
        );
    }

    #[test]
    fn the_shorter_trajectory_drives_and_the_offset_moves_the_estimate() {
        let reference = [0.0, 1.0, 2.0, 3.0];
        let estimate = [1.2, 2.2];
        let a = associate(&reference, &estimate, 0.01, -0.2);
        assert_eq!((a.reference, a.estimate), (vec![1, 2], vec![0, 1]));
        // The estimate longer: the offset is added to its stamps.
        let a = associate(&[1.0], &[0.0, 0.8, 2.0], 0.01, 0.2);
        assert_eq!((a.reference, a.estimate), (vec![0], vec![1]));
        // Not one-to-one: two short poses on one long pose.
        let a = associate(&[0.0, 1.0, 3.0, 4.0], &[0.998, 1.003], 0.01, 0.0);
        assert_eq!((a.reference, a.estimate), (vec![1, 1], vec![0, 1]));
        // The nearer of the two neighbours; on an exact tie the earlier.
        let a = associate(&[1.0, 1.009], &[1.005], 0.01, 0.0);
        assert_eq!((a.reference, a.estimate), (vec![1], vec![0]));
        let a = associate(&[1.0, 1.5], &[1.25], 0.5, 0.0);
        assert_eq!((a.reference, a.estimate), (vec![0], vec![0]));
    }
}
