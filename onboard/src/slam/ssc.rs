//! Suppression via Square Covering (SSC; Bailo et al., "Efficient adaptive non-maximal
//! suppression algorithms for homogeneous spatial keypoint distribution", Pattern
//! Recognition Letters 106, 2018).
//!
//! Keypoints sorted strongest first are visited in order; one is kept when its cell is
//! not yet covered, and then covers the cells within two cells of its own (cells of side
//! `w / 2`, so a square of about `2w` around it). A binary search over the integer square
//! side `w` finds a side for which the number kept is within `tolerance` of the target.
//!
//! What the covering guarantees (tested): any two kept points are more than `w` apart in
//! x or in y (Chebyshev distance > `w`), every dropped point lies within Chebyshev
//! distance `1.5·w` of a stronger kept one, and the strongest point is always kept.

/// Reusable buffers of [`ssc`].
#[derive(Clone, Debug, Default)]
pub struct SscScratch {
    covered: Vec<bool>,
    current: Vec<usize>,
}

/// The outcome of [`ssc`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SscOutcome {
    /// The square side `w` of the kept set, px (0 when every point was kept without a
    /// search because there were no more than the target).
    pub width_px: u32,
    /// Whether the kept count is within the tolerance of the target (the search can end
    /// on a neighbouring side when no integer side hits the band; that set is returned).
    pub within_tolerance: bool,
}

/// One covering pass with square side `width`: the indices kept, in order.
fn cover(points: &[[f32; 2]], width: u32, cols: f32, rows: f32, s: &mut SscScratch) {
    let c = f64::from(width) / 2.0;
    let n_cols = (f64::from(cols) / c).floor() as usize + 1;
    let n_rows = (f64::from(rows) / c).floor() as usize + 1;
    s.covered.clear();
    s.covered.resize(n_cols * n_rows, false);
    s.current.clear();
    // floor(width / c) = 2 cells either side.
    const REACH: usize = 2;
    for (i, p) in points.iter().enumerate() {
        // `as usize` truncates (= floor for x ≥ 0) and saturates negatives to 0.
        let col = ((f64::from(p[0]) / c) as usize).min(n_cols - 1);
        let row = ((f64::from(p[1]) / c) as usize).min(n_rows - 1);
        if s.covered[row * n_cols + col] {
            continue;
        }
        s.current.push(i);
        for r in row.saturating_sub(REACH)..=(row + REACH).min(n_rows - 1) {
            let line = &mut s.covered[r * n_cols..(r + 1) * n_cols];
            line[col.saturating_sub(REACH)..=(col + REACH).min(n_cols - 1)].fill(true);
        }
    }
}

/// Keeps about `target` of `points` (sorted strongest first, inside a `cols × rows`
/// image), strongest and evenly spread; their indices go to `out` in strength order.
///
/// `tolerance` is the accepted relative deviation from `target` (the paper uses 0.1).
/// With no more than `target` points all are kept.
pub fn ssc(
    points: &[[f32; 2]],
    target: usize,
    tolerance: f32,
    cols: f32,
    rows: f32,
    scratch: &mut SscScratch,
    out: &mut Vec<usize>,
) -> SscOutcome {
    out.clear();
    if points.len() <= target {
        out.extend(0..points.len());
        return SscOutcome {
            width_px: 0,
            within_tolerance: true,
        };
    }
    if target == 0 {
        return SscOutcome {
            width_px: 0,
            within_tolerance: true,
        };
    }
    let k = target as f64;
    let k_min = (k - k * f64::from(tolerance)).round().max(1.0) as usize;
    let k_max = (k + k * f64::from(tolerance)).round() as usize;
    // Initial search range (the paper's closed-form solution for the largest side that can
    // hold `target` squares in the image, and the side below which all points fit).
    let (c, r) = (f64::from(cols), f64::from(rows));
    let mut high = if target > 1 {
        let e1 = r + c + 2.0 * k;
        let e2 = 4.0 * c + 4.0 * k + 4.0 * r * k + r * r + c * c - 2.0 * r * c + 4.0 * r * c * k;
        let e3 = e2.max(0.0).sqrt();
        let e4 = k - 1.0;
        let s1 = -((e1 + e3) / e4).round();
        let s2 = -((e1 - e3) / e4).round();
        s1.max(s2).max(1.0) as i64
    } else {
        c.max(r).ceil() as i64 + 1
    };
    high = high.max(1);
    let mut low = ((points.len() as f64 / k).sqrt().floor() as i64).max(1);
    let mut prev = -1;
    let mut found = None;
    loop {
        let width = low + (high - low) / 2;
        if width == prev || low > high {
            break;
        }
        cover(points, width as u32, cols, rows, scratch);
        let n = scratch.current.len();
        prev = width;
        found = Some(width as u32);
        if (k_min..=k_max).contains(&n) {
            break;
        } else if n < k_min {
            high = width - 1;
        } else {
            low = width + 1;
        }
    }
    let n = scratch.current.len();
    out.extend_from_slice(&scratch.current);
    SscOutcome {
        width_px: found.unwrap_or(0),
        within_tolerance: (k_min..=k_max).contains(&n),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fewer_points_than_the_target_are_all_kept() {
        let pts = [[1.0, 1.0], [2.0, 2.0]];
        let mut out = Vec::new();
        let o = ssc(
            &pts,
            5,
            0.1,
            10.0,
            10.0,
            &mut SscScratch::default(),
            &mut out,
        );
        assert_eq!(out, vec![0, 1]);
        assert_eq!(o.width_px, 0);
    }

    #[test]
    fn a_single_target_keeps_the_strongest() {
        let pts = [[5.0, 5.0], [1.0, 1.0], [9.0, 9.0]];
        let mut out = Vec::new();
        ssc(
            &pts,
            1,
            0.0,
            10.0,
            10.0,
            &mut SscScratch::default(),
            &mut out,
        );
        assert_eq!(out, vec![0]);
    }
}
