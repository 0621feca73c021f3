//! Statistics of sweep cells: summaries, bootstrap and Wilson intervals, and rank tests.
//!
//! Everything here is a pure function of its inputs (and of an explicit RNG seed where
//! resampling is involved), so the merge step and the regression gate are reproducible
//! bit for bit.
//!
//! # Conventions
//!
//! * Inputs are unsorted slices; nothing requires the caller to sort, and every sort uses
//!   [`f64::total_cmp`], so no input can make a function panic.
//! * Non-finite values: callers are expected to filter them out (a job that failed to
//!   produce a metric should not enter its cell's statistics). The functions treat the
//!   slice as given: a NaN anywhere makes every derived statistic NaN (like NumPy's and
//!   SciPy's default `nan_policy="propagate"`); infinities follow IEEE arithmetic (an
//!   infinite value has the largest rank in the rank tests, and may turn a mean into
//!   ±inf or a standard deviation into NaN).
//! * Estimators follow NumPy/SciPy defaults so results can be cross-checked there:
//!   [`quantile`] is `np.quantile(x, p)` (Hyndman–Fan type 7), [`std_dev`] is
//!   `np.std(x, ddof=1)`, [`wilcoxon_signed_rank`] is `scipy.stats.wilcoxon(d)` and
//!   [`mann_whitney_u`] is `scipy.stats.mannwhitneyu(a, b)` (SciPy 1.17 defaults; the few
//!   differences are listed on each function).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// Number of bootstrap resamples [`summarize`] uses for its confidence interval.
pub const BOOTSTRAP_RESAMPLES: usize = 2000;

/// The two-sided 95 % standard-normal quantile, Φ⁻¹(0.975).
pub const Z95: f64 = 1.959963984540054;

/// Arithmetic mean; NaN for an empty slice.
pub fn mean(xs: &[f64]) -> f64 {
    if xs.is_empty() {
        return f64::NAN;
    }
    xs.iter().sum::<f64>() / xs.len() as f64
}

/// Sample standard deviation with Bessel's correction (divisor n − 1, like
/// `np.std(x, ddof=1)`); NaN when fewer than two values are given.
pub fn std_dev(xs: &[f64]) -> f64 {
    if xs.len() < 2 {
        return f64::NAN;
    }
    let m = mean(xs);
    let ss: f64 = xs.iter().map(|x| (x - m) * (x - m)).sum();
    (ss / (xs.len() - 1) as f64).sqrt()
}

/// The `p`-quantile of `xs` by linear interpolation between order statistics
/// (Hyndman–Fan type 7, NumPy's default `np.quantile(x, p)`).
///
/// NaN when `xs` is empty, contains a NaN, or `p` is not in `[0, 1]` (NumPy raises there).
/// The slice need not be sorted; it is copied and sorted internally.
pub fn quantile(xs: &[f64], p: f64) -> f64 {
    if xs.is_empty() || has_nan(xs) || !(0.0..=1.0).contains(&p) {
        return f64::NAN;
    }
    quantile_sorted(&sorted_copy(xs), p)
}

/// The median, as the type-7 [`quantile`] at 0.5 (the midpoint of the two middle values
/// for an even count); NaN for an empty slice or one containing a NaN.
pub fn median(xs: &[f64]) -> f64 {
    quantile(xs, 0.5)
}

/// Summary of one metric over the seeds of a sweep cell.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Summary {
    /// Number of values summarised (including any NaN).
    pub n: usize,
    /// Arithmetic mean.
    pub mean: f64,
    /// Sample standard deviation (n − 1); NaN for n < 2.
    pub std: f64,
    /// Median (type-7 quantile at 0.5).
    pub median: f64,
    /// 5th percentile (type 7).
    pub p5: f64,
    /// 95th percentile (type 7).
    pub p95: f64,
    /// Smallest value.
    pub min: f64,
    /// Largest value.
    pub max: f64,
    /// 95 % percentile-bootstrap confidence interval of the mean, `(low, high)`;
    /// `(x, x)` for a single value.
    pub ci95: (f64, f64),
}

/// Summarises `xs`; the bootstrap interval draws [`BOOTSTRAP_RESAMPLES`] resamples from a
/// ChaCha8 generator seeded with `seed`, so the result is bit-identical for the same input
/// and seed.
///
/// An empty slice, or one containing a NaN, gives NaN in every field but `n`.
pub fn summarize(xs: &[f64], seed: u64) -> Summary {
    let n = xs.len();
    if n == 0 || has_nan(xs) {
        return Summary {
            n,
            mean: f64::NAN,
            std: f64::NAN,
            median: f64::NAN,
            p5: f64::NAN,
            p95: f64::NAN,
            min: f64::NAN,
            max: f64::NAN,
            ci95: (f64::NAN, f64::NAN),
        };
    }
    let sorted = sorted_copy(xs);
    Summary {
        n,
        mean: mean(xs),
        std: std_dev(xs),
        median: quantile_sorted(&sorted, 0.5),
        p5: quantile_sorted(&sorted, 0.05),
        p95: quantile_sorted(&sorted, 0.95),
        min: sorted[0],
        max: sorted[n - 1],
        ci95: bootstrap_mean_ci(xs, 0.95, BOOTSTRAP_RESAMPLES, seed),
    }
}

/// Percentile-bootstrap confidence interval of the mean of `xs` at confidence `level`
/// (e.g. 0.95): `resamples` resamples of size n drawn with replacement from a
/// [`ChaCha8Rng`] seeded with `seed` (indices by `random_range(0..n)`), and the type-7
/// quantiles of their means at `(1 − level)/2` and `(1 + level)/2`.
///
/// A single value gives `(x, x)`. `(NaN, NaN)` for an empty slice, a NaN in `xs`,
/// `resamples == 0`, or `level` outside the open interval (0, 1).
pub fn bootstrap_mean_ci(xs: &[f64], level: f64, resamples: usize, seed: u64) -> (f64, f64) {
    let n = xs.len();
    if n == 0 || resamples == 0 || !(level > 0.0 && level < 1.0) || has_nan(xs) {
        return (f64::NAN, f64::NAN);
    }
    if n == 1 {
        return (xs[0], xs[0]);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut means: Vec<f64> = (0..resamples)
        .map(|_| {
            let s: f64 = (0..n).map(|_| xs[rng.random_range(0..n)]).sum();
            s / n as f64
        })
        .collect();
    means.sort_by(f64::total_cmp);
    (
        quantile_sorted(&means, (1.0 - level) / 2.0),
        quantile_sorted(&means, (1.0 + level) / 2.0),
    )
}

/// Wilson score interval for a binomial proportion `successes / n` with normal quantile
/// `|z|` (use [`Z95`] for 95 %), clamped to `[0, 1]`.
///
/// `n == 0` gives the uninformative `(0, 1)`; `successes > n` gives `(NaN, NaN)`.
pub fn wilson_interval(successes: usize, n: usize, z: f64) -> (f64, f64) {
    if n == 0 {
        return (0.0, 1.0);
    }
    if successes > n {
        return (f64::NAN, f64::NAN);
    }
    let nf = n as f64;
    let p = successes as f64 / nf;
    let z = z.abs();
    let z2 = z * z;
    let denom = 1.0 + z2 / nf;
    let center = (p + z2 / (2.0 * nf)) / denom;
    let half = z / denom * (p * (1.0 - p) / nf + z2 / (4.0 * nf * nf)).sqrt();
    let low = if successes == 0 {
        0.0
    } else {
        (center - half).clamp(0.0, 1.0)
    };
    let high = if successes == n {
        1.0
    } else {
        (center + half).clamp(0.0, 1.0)
    };
    (low, high)
}

/// Result of a two-sided rank test.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TestResult {
    /// The test statistic (SciPy's convention; see the test function).
    pub statistic: f64,
    /// Two-sided p-value in `[0, 1]` (NaN when the input contained a NaN).
    pub p_value: f64,
    /// Number of observations the statistic is computed from.
    pub n: usize,
    /// How the p-value was obtained: `"wilcoxon-exact"`, `"wilcoxon-exact-ties"`,
    /// `"wilcoxon-normal"`, `"mann-whitney-exact"`, `"mann-whitney-normal"`, or `"nan"`.
    pub method: &'static str,
}

/// Wilcoxon signed-rank test of paired differences `diffs` (new − base) against a zero
/// median, two-sided; mirrors `scipy.stats.wilcoxon(diffs)` of SciPy 1.17
/// (`zero_method="wilcox"`, `correction=False`, `method="auto"`).
///
/// Zero differences are dropped (`n` in the result counts the nonzero ones). The |d| are
/// ranked with average ranks for ties; the statistic is `min(W+, W−)`. The p-value is
/// chosen as SciPy's `"auto"` does, where `len` counts all differences, zeros included:
///
/// * `len > 50`: normal approximation, tie-corrected variance, no continuity correction
///   (`"wilcoxon-normal"`);
/// * no zeros and no ties: exact null distribution of W+ (`"wilcoxon-exact"`);
/// * zeros or ties and `len <= 13`: exact distribution of W+ over all 2ⁿ sign patterns
///   of the (tied) ranks — what SciPy's exhaustive permutation test computes
///   (`"wilcoxon-exact-ties"`);
/// * otherwise the normal approximation.
///
/// Exact two-sided p = min(1, 2·min(P(W+ ≤ w), P(W+ ≥ w))).
///
/// `None` when no nonzero difference remains (SciPy reports statistic 0, p = 1 for up to
/// 50 zeros and NaN beyond). A NaN difference gives statistic and p-value NaN (method
/// `"nan"`), like SciPy's default `nan_policy="propagate"`.
pub fn wilcoxon_signed_rank(diffs: &[f64]) -> Option<TestResult> {
    let len = diffs.len();
    let nonzero: Vec<f64> = diffs.iter().copied().filter(|&d| d != 0.0).collect();
    let n = nonzero.len();
    if n == 0 {
        return None;
    }
    if has_nan(&nonzero) {
        return Some(nan_result(n));
    }
    let abs: Vec<f64> = nonzero.iter().map(|d| d.abs()).collect();
    let ranks = rank_doubled(&abs);
    let total2 = (n * (n + 1)) as u64; // sum of doubled ranks 1..=n
    let plus2: u64 = nonzero
        .iter()
        .zip(&ranks.doubled)
        .filter(|(d, _)| **d > 0.0)
        .map(|(_, r)| *r)
        .sum();
    let minus2 = total2 - plus2;
    let statistic = plus2.min(minus2) as f64 / 2.0;
    let has_zeros = n < len;

    let exact = if len > 50 {
        None
    } else if !ranks.has_ties && !has_zeros {
        Some("wilcoxon-exact")
    } else if len <= 13 {
        Some("wilcoxon-exact-ties")
    } else {
        None
    };
    let (p_value, method) = match exact {
        Some(method) => {
            let counts = subset_sum_counts(&ranks.doubled);
            let w = plus2 as usize;
            let le: u64 = counts.iter().take(w + 1).sum();
            let ge: u64 = counts.iter().skip(w).sum();
            let all = 2f64.powi(n as i32);
            ((2.0 * le.min(ge) as f64 / all).min(1.0), method)
        }
        None => {
            let nf = n as f64;
            let mn = nf * (nf + 1.0) / 4.0;
            let var = (nf * (nf + 1.0) * (2.0 * nf + 1.0) - ranks.tie_term / 2.0) / 24.0;
            let z = (plus2 as f64 / 2.0 - mn) / var.max(0.0).sqrt();
            ((2.0 * normal_cdf(-z.abs())).min(1.0), "wilcoxon-normal")
        }
    };
    Some(TestResult {
        statistic,
        p_value,
        n,
        method,
    })
}

/// Mann–Whitney U test of two independent samples, two-sided; mirrors
/// `scipy.stats.mannwhitneyu(a, b)` of SciPy 1.17 (`use_continuity=True`,
/// `method="auto"`).
///
/// The statistic is U of `a`: `U1 = R1 − n1(n1+1)/2`, with `R1` the sum of `a`'s average
/// ranks in the pooled sample (`n` in the result is `n1 + n2`). SciPy's `"auto"` rule:
/// the exact null distribution of U (`"mann-whitney-exact"`) when there are no ties and
/// at least one sample has at most 8 values; otherwise the normal approximation with tie
/// correction and continuity correction (`"mann-whitney-normal"`). Exact two-sided
/// p = min(1, 2·P(U ≥ max(U1, U2))).
///
/// Difference from SciPy: when the exact distribution's counts would not fit in 128-bit
/// integers (C(n1+n2, min(n1, n2)) > 2¹²⁵, i.e. a sample of at most 8 against one of
/// roughly 10⁵ values or more) the normal approximation is used instead.
///
/// `None` if either sample is empty. A NaN in either sample gives statistic and p-value
/// NaN (method `"nan"`).
pub fn mann_whitney_u(a: &[f64], b: &[f64]) -> Option<TestResult> {
    if a.is_empty() || b.is_empty() {
        return None;
    }
    let (n1, n2) = (a.len(), b.len());
    let n = n1 + n2;
    if has_nan(a) || has_nan(b) {
        return Some(nan_result(n));
    }
    let pooled: Vec<f64> = a.iter().chain(b).copied().collect();
    let ranks = rank_doubled(&pooled);
    let r1_2: u64 = ranks.doubled[..n1].iter().sum();
    let (n1f, n2f, nf) = (n1 as f64, n2 as f64, n as f64);
    let u1 = r1_2 as f64 / 2.0 - n1f * (n1f + 1.0) / 2.0;
    let u2 = n1f * n2f - u1;
    let u = u1.max(u2);

    let exact = if (n1 > 8 && n2 > 8) || ranks.has_ties {
        None
    } else {
        // No ties: U1 and U2 are integers, and min(U1, U2) = n1·n2 − U.
        mwu_lower_tail(n1, n2, u1.min(u2) as u64)
    };
    let (p_value, method) = match exact {
        Some(tail) => ((2.0 * tail).min(1.0), "mann-whitney-exact"),
        None => {
            let mu = n1f * n2f / 2.0;
            let s = (n1f * n2f / 12.0 * ((nf + 1.0) - ranks.tie_term / (nf * (nf - 1.0))))
                .max(0.0)
                .sqrt();
            // All values tied: s = 0 and z = −inf, p = 1, as in SciPy.
            let z = (u - mu - 0.5) / s;
            (
                (2.0 * normal_cdf(-z)).clamp(0.0, 1.0),
                "mann-whitney-normal",
            )
        }
    };
    Some(TestResult {
        statistic: u1,
        p_value,
        n,
        method,
    })
}

// ---------------------------------------------------------------------------------------
// Internals.

fn has_nan(xs: &[f64]) -> bool {
    xs.iter().any(|x| x.is_nan())
}

fn nan_result(n: usize) -> TestResult {
    TestResult {
        statistic: f64::NAN,
        p_value: f64::NAN,
        n,
        method: "nan",
    }
}

fn sorted_copy(xs: &[f64]) -> Vec<f64> {
    let mut v = xs.to_vec();
    v.sort_by(f64::total_cmp);
    v
}

/// Type-7 quantile of an already sorted, non-empty, NaN-free slice, with NumPy's
/// interpolation formula (`_lerp`: from the lower neighbour when the weight is below 0.5,
/// from the upper one otherwise). Exact order statistics are returned as is, so an
/// infinite neighbour does not turn them into NaN.
fn quantile_sorted(sorted: &[f64], p: f64) -> f64 {
    let n = sorted.len();
    if n == 0 || !(0.0..=1.0).contains(&p) {
        return f64::NAN;
    }
    let virtual_index = (n - 1) as f64 * p;
    if virtual_index >= (n - 1) as f64 {
        return sorted[n - 1];
    }
    let lo = virtual_index.floor();
    let gamma = virtual_index - lo;
    let lo = lo as usize;
    let (a, b) = (sorted[lo], sorted[lo + 1]);
    if gamma == 0.0 {
        return a;
    }
    let diff = b - a;
    if gamma >= 0.5 {
        b - diff * (1.0 - gamma)
    } else {
        a + diff * gamma
    }
}

/// Average ranks (1-based) of NaN-free values, doubled so they are integers.
struct DoubledRanks {
    /// Twice the average rank of each value, in input order.
    doubled: Vec<u64>,
    /// Σ (t³ − t) over groups of t tied values.
    tie_term: f64,
    /// Whether any two values are equal.
    has_ties: bool,
}

fn rank_doubled(xs: &[f64]) -> DoubledRanks {
    let n = xs.len();
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&i, &j| xs[i].total_cmp(&xs[j]));
    let mut doubled = vec![0u64; n];
    let mut tie_term = 0.0;
    let mut has_ties = false;
    let mut start = 0;
    while start < n {
        // `==` (not total_cmp) groups −0.0 with 0.0, which sort next to each other.
        let mut end = start + 1;
        while end < n && xs[order[end]] == xs[order[start]] {
            end += 1;
        }
        // Positions start..end (0-based) share the rank ((start+1) + end) / 2.
        let r2 = (start + 1 + end) as u64;
        for &i in &order[start..end] {
            doubled[i] = r2;
        }
        let t = (end - start) as f64;
        if end - start > 1 {
            has_ties = true;
            tie_term += t * t * t - t;
        }
        start = end;
    }
    DoubledRanks {
        doubled,
        tie_term,
        has_ties,
    }
}

/// `counts[s]` = number of subsets of the multiset `values` whose sum is `s` — the null
/// distribution (times 2ⁿ) of the signed-rank statistic W+ when `values` are the (doubled)
/// ranks. Only called with n ≤ 50, so counts ≤ 2⁵⁰ and sums ≤ 2550.
fn subset_sum_counts(values: &[u64]) -> Vec<u64> {
    let total: u64 = values.iter().sum();
    let mut counts = vec![0u64; total as usize + 1];
    counts[0] = 1;
    let mut reach = 0usize;
    for &v in values {
        let v = v as usize;
        for s in (0..=reach).rev() {
            counts[s + v] += counts[s];
        }
        reach += v;
    }
    counts
}

/// P(U ≤ k) under the null for sample sizes `n1`, `n2` without ties, from the exact
/// counts (the coefficients of the Gaussian binomial [n1+n2 choose m]_q, m = min(n1, n2),
/// built as ∏ᵢ (1 − q^(n+i)) / (1 − q^i) truncated at degree k). `None` when the counts
/// might not fit in an `i128`.
fn mwu_lower_tail(n1: usize, n2: usize, k: u64) -> Option<f64> {
    let counts = mwu_counts(n1, n2, k)?;
    let (m, big) = (n1.min(n2) as i128, n1.max(n2) as i128);
    let mut total: i128 = 1;
    for i in 1..=m {
        total = total.checked_mul(big + i)? / i;
    }
    let below: i128 = counts.iter().sum();
    Some(below as f64 / total as f64)
}

/// Counts of U = 0..=k (k clamped to n1·n2) over the C(n1+n2, n1) equally likely
/// arrangements; `None` when C(n1+n2, n1) exceeds 2¹²⁵.
fn mwu_counts(n1: usize, n2: usize, k: u64) -> Option<Vec<i128>> {
    let (m, big) = (n1.min(n2), n1.max(n2));
    // C(m+big, m) bounds every coefficient; the intermediate products are at most twice
    // that in magnitude, so a bound of 2^125 leaves ample headroom.
    let mut total: i128 = 1;
    for i in 1..=m as i128 {
        total = total.checked_mul(big as i128 + i)? / i;
        if total > 1i128 << 125 {
            return None;
        }
    }
    let k = usize::try_from(k).ok()?.min(m * big);
    let mut c = vec![0i128; k + 1];
    c[0] = 1;
    for i in 1..=m {
        let a = big + i;
        for u in (a..=k).rev() {
            c[u] -= c[u - a];
        }
        for u in i..=k {
            c[u] += c[u - i];
        }
    }
    Some(c)
}

/// Standard normal CDF Φ(x), accurate to a few 1e-13 relative over the whole range,
/// far tails included (where the p-values of the rank tests live): checked against
/// `scipy.special.erfc` on 2500 points in [−6, 27].
fn normal_cdf(x: f64) -> f64 {
    0.5 * erfc(-x / std::f64::consts::SQRT_2)
}

/// Complementary error function: a positive-term series for erf below 2, Lentz's
/// continued fraction for the upper tail above.
fn erfc(x: f64) -> f64 {
    if x.is_nan() {
        return f64::NAN;
    }
    if x < 0.0 {
        return 2.0 - erfc(-x);
    }
    if x > 27.3 {
        return 0.0; // below the smallest subnormal
    }
    // exp(−x²) with x² split into hi + lo so that the rounding of x² does not cost
    // relative accuracy in the tail.
    let hi = x * x;
    let lo = x.mul_add(x, -hi);
    let gauss = (-hi).exp() * (-lo).exp();
    let frac_1_sqrt_pi = std::f64::consts::FRAC_2_SQRT_PI / 2.0;
    if x < 2.0 {
        // erf(x) = 2/√π · e^(−x²) · Σₙ (2x²)ⁿ x / (1·3·…·(2n+1)), all terms positive.
        let mut term = x;
        let mut sum = x;
        let mut k = 0.0;
        while term > sum * 1e-17 && k < 500.0 {
            k += 1.0;
            term *= 2.0 * hi / (2.0 * k + 1.0);
            sum += term;
        }
        1.0 - 2.0 * frac_1_sqrt_pi * gauss * sum
    } else {
        // erfc(x) = e^(−x²)/√π · 1/(x + (1/2)/(x + 1/(x + (3/2)/(x + …)))).
        let tiny = 1e-300;
        let mut f = x;
        let mut c = x;
        let mut d = 0.0;
        for n in 1..1000 {
            let a = f64::from(n) / 2.0;
            d = x + a * d;
            if d == 0.0 {
                d = tiny;
            }
            c = x + a / c;
            if c == 0.0 {
                c = tiny;
            }
            d = 1.0 / d;
            let delta = c * d;
            f *= delta;
            if (delta - 1.0).abs() < 1e-16 {
                break;
            }
        }
        frac_1_sqrt_pi * gauss / f
    }
}

#[cfg(test)]
mod tests {
    //! Reference values come from NumPy 2.4.6 / SciPy 1.17.1 (`pip install scipy numpy`),
    //! produced by this script (`python3 ref.py`):
    //!
    //! ```python
    //! import numpy as np, scipy
    //! from scipy import stats, special
    //! print("scipy", scipy.__version__, "numpy", np.__version__)  # 1.17.1, 2.4.6
    //! r = lambda v: repr(float(v))
    //! A = [3.1, -1.2, 4.7, 0.5, 2.2, 9.9, -3.3, 0.5]
    //! print("A mean", r(np.mean(A)), "std", r(np.std(A, ddof=1)), "median", r(np.median(A)))
    //! for p in [0.0, 0.025, 0.05, 0.25, 0.5, 0.75, 0.95, 0.975, 1.0]:
    //!     print("A q", p, r(np.quantile(A, p)))
    //! print("n2 q0.3", r(np.quantile([4.0, 1.0], 0.3)), "std", r(np.std([4.0, 1.0], ddof=1)),
    //!       "median", r(np.median([4.0, 1.0])))
    //! print("n1 q0.9", r(np.quantile([2.5], 0.9)))
    //! W = {
    //!  "five_pos": [1.0, 2.0, 3.0, 4.0, 5.0],
    //!  "exact12": [0.8, -0.3, 1.7, 2.2, -0.6, 1.1, 0.9, 2.9, -1.4, 0.2, 1.5, 0.45],
    //!  "exact30": [((i * 17) % 31) - 10.3 for i in range(1, 31)],
    //!  "ties30": [((i * 17) % 31) - 10.5 for i in range(1, 31)],
    //!  "zeros9": [0.0, 1.5, -0.5, 2.0, 0.0, 3.1, 0.7, -1.2, 2.4],
    //!  "ties10": [1.0, -1.0, 2.0, 2.0, 3.0, -0.5, 4.0, 1.0, 2.5, 3.0],
    //!  "ties20": [1.0, -2.0, 3.0, 1.0, 2.0, -1.0, 4.0, 2.0, 3.0, -3.0, 5.0, 1.0, 2.0, 6.0,
    //!             -1.0, 2.0, 4.0, 3.0, -2.0, 1.0],
    //!  "zeros16": [0.0, 0.3, -1.1, 2.5, 0.9, -0.2, 1.7, 3.3, 0.0, 1.2, -0.7, 2.1, 0.6, 1.4,
    //!              -1.9, 2.8],
    //!  "one": [2.0], "two": [1.0, -2.0], "neg_one": [-0.5],
    //!  "n60": [((i * 37) % 101) - 45.5 for i in range(1, 61)],
    //!  "pos60": [float(i) for i in range(1, 61)],
    //!  "ties_zeros60": [float((i % 7) - 2) for i in range(60)],
    //!  "inf7": [1.0, float('inf'), -2.0, 3.0, -float('inf'), 5.0, 6.0],
    //! }
    //! for k, d in W.items():
    //!     res = stats.wilcoxon(d); print("W", k, r(res.statistic), r(res.pvalue))
    //! M = {
    //!  "males_females": ([19., 22., 16., 29., 24.], [20., 11., 17., 12.]),
    //!  "three_vs_20": ([2.7, 7.1, 9.4], [1.0 + 0.5 * i for i in range(20)]),
    //!  "five_vs_15": ([10.2, 11.3, 12.9, 9.7, 13.4], [0.5 * i + 1.05 for i in range(15)]),
    //!  "ties_small": ([1., 2., 2., 3., 5.], [2., 3., 4., 4., 6., 7.]),
    //!  "ten_vs_twelve": ([0.1 * ((i * 13) % 23) for i in range(10)],
    //!                    [0.1 * ((i * 13) % 23) + 0.75 for i in range(10, 22)]),
    //!  "one_one": ([1.], [2.]), "one_three": ([5.], [1., 2., 3.]),
    //!  "all_equal": ([1., 1., 1.], [1., 1.]),
    //!  "nine_nine": ([float(i) for i in range(9)], [float(i) + 2.55 for i in range(9)]),
    //! }
    //! for k, (a, b) in M.items():
    //!     res = stats.mannwhitneyu(a, b); print("M", k, r(res.statistic), r(res.pvalue))
    //! for z in [0.0, 0.5, -1.5, 1.959963984540054, 3.0, 5.0, 8.0, 10.0, 20.0, 37.0]:
    //!     print("sf", z, r(special.ndtr(-z)))
    //! for x in [0.1, 0.5, 1.0, 1.999, 2.0, 2.9, 2.999, 3.0, 3.1, 4.0, 6.0, 10.0, 26.0, -1.0]:
    //!     print("erfc", x, r(special.erfc(x)))
    //! ```
    use super::*;
    use rand_distr::{Distribution, StandardNormal};

    /// Asserts `|got − want| ≤ rel·|want|` (exact equality for `want == 0`).
    #[track_caller]
    fn close(got: f64, want: f64, rel: f64) {
        assert!(
            (got - want).abs() <= rel * want.abs(),
            "got {got:e}, want {want:e} (rel tol {rel:e})"
        );
    }

    const EXACT: f64 = 1e-9;
    const NORMAL: f64 = 1e-6;

    #[track_caller]
    fn wilcoxon(d: &[f64], stat: f64, p: f64, method: &str) {
        let res = wilcoxon_signed_rank(d).expect("nonzero differences");
        assert_eq!(res.statistic, stat);
        assert_eq!(res.method, method);
        close(
            res.p_value,
            p,
            if method == "wilcoxon-normal" {
                NORMAL
            } else {
                EXACT
            },
        );
    }

    #[track_caller]
    fn mwu(a: &[f64], b: &[f64], stat: f64, p: f64, method: &str) {
        let res = mann_whitney_u(a, b).expect("non-empty samples");
        assert_eq!(res.statistic, stat);
        assert_eq!(res.n, a.len() + b.len());
        assert_eq!(res.method, method);
        close(
            res.p_value,
            p,
            if method == "mann-whitney-normal" {
                NORMAL
            } else {
                EXACT
            },
        );
    }

    const A: [f64; 8] = [3.1, -1.2, 4.7, 0.5, 2.2, 9.9, -3.3, 0.5];

    #[test]
    fn moments_and_quantiles_match_numpy() {
        close(mean(&A), 2.0500000000000003, 1e-12);
        close(std_dev(&A), 4.031306062733091, 1e-12);
        close(median(&A), 1.35, 1e-12);
        for (p, want) in [
            (0.0, -3.3),
            (0.025, -2.9324999999999997),
            (0.05, -2.565),
            (0.25, 0.07500000000000001),
            (0.5, 1.35),
            (0.75, 3.5),
            (0.95, 8.079999999999998),
            (0.975, 8.990000000000002),
            (1.0, 9.9),
        ] {
            close(quantile(&A, p), want, 1e-12);
        }
        // n = 2 and n = 1.
        close(quantile(&[4.0, 1.0], 0.3), 1.9, 1e-12);
        close(std_dev(&[4.0, 1.0]), 2.1213203435596424, 1e-12);
        close(median(&[4.0, 1.0]), 2.5, 1e-12);
        assert_eq!(quantile(&[2.5], 0.9), 2.5);
        assert!(std_dev(&[2.5]).is_nan());
        // Input order does not matter and the input is left untouched.
        let mut rev = A;
        rev.reverse();
        assert_eq!(quantile(&rev, 0.3).to_bits(), quantile(&A, 0.3).to_bits());
    }

    #[test]
    fn degenerate_inputs_are_defined() {
        assert!(mean(&[]).is_nan());
        assert!(std_dev(&[]).is_nan());
        assert!(quantile(&[], 0.5).is_nan());
        assert!(median(&[]).is_nan());
        assert!(quantile(&A, 1.5).is_nan());
        assert!(quantile(&A, -0.1).is_nan());
        assert!(quantile(&A, f64::NAN).is_nan());
        let with_nan = [1.0, f64::NAN, 3.0];
        assert!(mean(&with_nan).is_nan());
        assert!(std_dev(&with_nan).is_nan());
        assert!(median(&with_nan).is_nan());
        assert!(quantile(&[-f64::NAN, 1.0], 0.0).is_nan());
        // Infinities: order statistics stay exact.
        assert_eq!(quantile(&[1.0, f64::INFINITY, 0.0], 0.5), 1.0);
        assert_eq!(quantile(&[1.0, f64::INFINITY, 0.0], 1.0), f64::INFINITY);

        let s = summarize(&[], 1);
        assert_eq!(s.n, 0);
        assert!(s.mean.is_nan() && s.min.is_nan() && s.ci95.0.is_nan() && s.ci95.1.is_nan());
        let s = summarize(&with_nan, 1);
        assert_eq!(s.n, 3);
        assert!(s.mean.is_nan() && s.median.is_nan() && s.max.is_nan() && s.ci95.0.is_nan());
        let s = summarize(&[4.25], 1);
        assert_eq!(
            (s.n, s.mean, s.median, s.min, s.max),
            (1, 4.25, 4.25, 4.25, 4.25)
        );
        assert_eq!(s.ci95, (4.25, 4.25));
        assert!(s.std.is_nan());
        let s = summarize(&[7.0; 5], 1);
        assert_eq!(
            (s.mean, s.std, s.p5, s.p95, s.ci95),
            (7.0, 0.0, 7.0, 7.0, (7.0, 7.0))
        );

        assert!(bootstrap_mean_ci(&A, 0.95, 0, 1).0.is_nan());
        assert!(bootstrap_mean_ci(&A, 1.0, 100, 1).1.is_nan());
        assert!(bootstrap_mean_ci(&A, f64::NAN, 100, 1).1.is_nan());
        assert!(bootstrap_mean_ci(&[], 0.95, 100, 1).0.is_nan());

        assert_eq!(wilcoxon_signed_rank(&[]), None);
        assert_eq!(wilcoxon_signed_rank(&[0.0, -0.0, 0.0]), None);
        let r = wilcoxon_signed_rank(&[1.0, f64::NAN, 0.0]).expect("some");
        assert!(r.statistic.is_nan() && r.p_value.is_nan());
        assert_eq!((r.n, r.method), (2, "nan"));
        assert_eq!(mann_whitney_u(&[], &[1.0]), None);
        assert_eq!(mann_whitney_u(&[1.0], &[]), None);
        let r = mann_whitney_u(&[1.0, 2.0], &[f64::NAN]).expect("some");
        assert!(r.statistic.is_nan() && r.p_value.is_nan());
        // All-equal differences: ties everywhere, still defined.
        let r = wilcoxon_signed_rank(&[2.0; 20]).expect("some");
        assert_eq!(r.statistic, 0.0);
        assert!(r.p_value > 0.0 && r.p_value < 1e-3);
        let r = wilcoxon_signed_rank(&[2.0; 60]).expect("some");
        assert!(r.p_value > 0.0 && r.p_value < 1e-6);
        let r = mann_whitney_u(&[3.0; 30], &[3.0; 40]).expect("some");
        assert_eq!((r.statistic, r.p_value), (600.0, 1.0));

        assert_eq!(wilson_interval(0, 0, Z95), (0.0, 1.0));
        assert!(wilson_interval(11, 10, Z95).0.is_nan());
    }

    #[test]
    fn wilcoxon_matches_scipy() {
        // scipy.stats.wilcoxon(d), SciPy 1.17.1; see the module comment for the data.
        wilcoxon(&[1.0, 2.0, 3.0, 4.0, 5.0], 0.0, 0.0625, "wilcoxon-exact");
        let exact12 = [
            0.8, -0.3, 1.7, 2.2, -0.6, 1.1, 0.9, 2.9, -1.4, 0.2, 1.5, 0.45,
        ];
        wilcoxon(&exact12, 14.0, 0.05224609375, "wilcoxon-exact");
        let exact30: Vec<f64> = (1..=30).map(|i| ((i * 17) % 31) as f64 - 10.3).collect();
        wilcoxon(&exact30, 100.0, 0.005382779985666275, "wilcoxon-exact");
        // Same shape but |d| pairs up (x.5 both sides of 0): ties, n = 30 → normal.
        let ties30: Vec<f64> = (1..=30).map(|i| ((i * 17) % 31) as f64 - 10.5).collect();
        wilcoxon(&ties30, 105.0, 0.008711912962379593, "wilcoxon-normal");
        // Zeros, n ≤ 13: SciPy's exhaustive permutation test.
        let zeros9 = [0.0, 1.5, -0.5, 2.0, 0.0, 3.1, 0.7, -1.2, 2.4];
        wilcoxon(&zeros9, 4.0, 0.109375, "wilcoxon-exact-ties");
        // Ties, n ≤ 13: the same.
        let ties10 = [1.0, -1.0, 2.0, 2.0, 3.0, -0.5, 4.0, 1.0, 2.5, 3.0];
        wilcoxon(&ties10, 4.0, 0.015625, "wilcoxon-exact-ties");
        let inf7 = [1.0, f64::INFINITY, -2.0, 3.0, f64::NEG_INFINITY, 5.0, 6.0];
        wilcoxon(&inf7, 8.5, 0.390625, "wilcoxon-exact-ties");
        // Ties / zeros with 13 < n ≤ 50: normal approximation.
        let ties20 = [
            1.0, -2.0, 3.0, 1.0, 2.0, -1.0, 4.0, 2.0, 3.0, -3.0, 5.0, 1.0, 2.0, 6.0, -1.0, 2.0,
            4.0, 3.0, -2.0, 1.0,
        ];
        wilcoxon(&ties20, 40.5, 0.015302944184111409, "wilcoxon-normal");
        let zeros16 = [
            0.0, 0.3, -1.1, 2.5, 0.9, -0.2, 1.7, 3.3, 0.0, 1.2, -0.7, 2.1, 0.6, 1.4, -1.9, 2.8,
        ];
        wilcoxon(&zeros16, 21.0, 0.04798974969495946, "wilcoxon-normal");
        // n = 1, n = 2.
        wilcoxon(&[2.0], 0.0, 1.0, "wilcoxon-exact");
        wilcoxon(&[-0.5], 0.0, 1.0, "wilcoxon-exact");
        wilcoxon(&[1.0, -2.0], 1.0, 1.0, "wilcoxon-exact");
        // n > 50: normal approximation (p in (0.01, 0.2), far tail, ties and zeros).
        let n60: Vec<f64> = (1..=60).map(|i| ((i * 37) % 101) as f64 - 45.5).collect();
        wilcoxon(&n60, 720.0, 0.15112723925892457, "wilcoxon-normal");
        let pos60: Vec<f64> = (1..=60).map(f64::from).collect();
        wilcoxon(&pos60, 0.0, 1.6295557943119345e-11, "wilcoxon-normal");
        let tz60: Vec<f64> = (0..60).map(|i| ((i % 7) - 2) as f64).collect();
        wilcoxon(&tz60, 328.5, 0.0015264799104482217, "wilcoxon-normal");
        assert_eq!(wilcoxon_signed_rank(&tz60).map(|r| r.n), Some(51));
    }

    #[test]
    fn wilcoxon_closed_forms() {
        // n = 5, all positive: W− = 0 is reached by 1 of 2⁵ sign patterns, so
        // p = 2 · 1/32.
        let r = wilcoxon_signed_rank(&[0.3, 1.1, 2.0, 0.7, 5.0]).expect("some");
        assert_eq!((r.statistic, r.p_value, r.n), (0.0, 2.0 / 32.0, 5));
        // Symmetric result for all negative.
        let r = wilcoxon_signed_rank(&[-0.3, -1.1, -2.0, -0.7, -5.0]).expect("some");
        assert_eq!((r.statistic, r.p_value), (0.0, 2.0 / 32.0));
        // Exact null distribution of W+ for n = 3, by hand: the subsets of {1, 2, 3} are
        // {} → 0, {1} → 1, {2} → 2, {3} → 3, {1,2} → 3, {1,3} → 4, {2,3} → 5,
        // {1,2,3} → 6; so the counts for W = 0..=6 are 1, 1, 1, 2, 1, 1, 1.
        let counts = subset_sum_counts(&[2, 4, 6]); // doubled ranks
        let by_w: Vec<u64> = counts.iter().step_by(2).copied().collect();
        assert_eq!(by_w, vec![1, 1, 1, 2, 1, 1, 1]);
        assert!(counts.iter().skip(1).step_by(2).all(|&c| c == 0));
        // Mann–Whitney, n1 = n2 = 2, by hand: the C(4, 2) = 6 placements of `a` among
        // the pooled order give U = 0, 1, 2, 2, 3, 4.
        assert_eq!(mwu_counts(2, 2, 4), Some(vec![1, 1, 2, 1, 1]));
        assert_eq!(mwu_lower_tail(2, 2, 1), Some(2.0 / 6.0));
        // n1 = 1, n2 = 3: U uniform on 0..=3.
        assert_eq!(mwu_counts(1, 3, 10), Some(vec![1, 1, 1, 1]));
        // Too large for exact counts: falls back rather than overflowing.
        assert_eq!(mwu_counts(8, 10_000_000, 5), None);
    }

    #[test]
    fn mann_whitney_matches_scipy() {
        // scipy.stats.mannwhitneyu(a, b), SciPy 1.17.1; see the module comment.
        let (males, females) = ([19., 22., 16., 29., 24.], [20., 11., 17., 12.]);
        mwu(
            &males,
            &females,
            17.0,
            0.1111111111111111,
            "mann-whitney-exact",
        );
        let b20: Vec<f64> = (0..20).map(|i| 1.0 + 0.5 * f64::from(i)).collect();
        mwu(
            &[2.7, 7.1, 9.4],
            &b20,
            34.0,
            0.7634105025409372,
            "mann-whitney-exact",
        );
        let b15: Vec<f64> = (0..15).map(|i| 0.5 * f64::from(i) + 1.05).collect();
        let a5 = [10.2, 11.3, 12.9, 9.7, 13.4];
        mwu(
            &a5,
            &b15,
            75.0,
            0.00012899896800825592,
            "mann-whitney-exact",
        );
        mwu(&[1.], &[2.], 0.0, 1.0, "mann-whitney-exact");
        mwu(&[5.], &[1., 2., 3.], 3.0, 0.5, "mann-whitney-exact");
        // Ties → normal approximation with tie and continuity corrections.
        let (a, b) = ([1., 2., 2., 3., 5.], [2., 3., 4., 4., 6., 7.]);
        mwu(&a, &b, 6.5, 0.13862587987892763, "mann-whitney-normal");
        mwu(&[1., 1., 1.], &[1., 1.], 3.0, 1.0, "mann-whitney-normal");
        // Both samples > 8 → normal approximation.
        let a10: Vec<f64> = (0..10).map(|i| 0.1 * ((i * 13) % 23) as f64).collect();
        let b12: Vec<f64> = (10..22)
            .map(|i| 0.1 * ((i * 13) % 23) as f64 + 0.75)
            .collect();
        mwu(
            &a10,
            &b12,
            24.0,
            0.019242436939707945,
            "mann-whitney-normal",
        );
        let a9: Vec<f64> = (0..9).map(f64::from).collect();
        let b9: Vec<f64> = (0..9).map(|i| f64::from(i) + 2.55).collect();
        mwu(&a9, &b9, 21.0, 0.0933976745287926, "mann-whitney-normal");
    }

    #[test]
    fn normal_tail_matches_scipy() {
        // scipy.special.ndtr(-z) and scipy.special.erfc(x), SciPy 1.17.1.
        for (z, sf) in [
            (0.0, 0.5),
            (0.5, 0.3085375387259869),
            (-1.5, 0.9331927987311419),
            (Z95, 0.025),
            (3.0, 0.0013498980316300933),
            (5.0, 2.866515718791933e-07),
            (8.0, 6.22096057427174e-16),
            (10.0, 7.61985302416047e-24),
            (20.0, 2.7536241186061556e-89),
            (37.0, 5.7255712225239266e-300),
        ] {
            close(normal_cdf(-z), sf, 1e-12);
        }
        for (x, want) in ERFC_REF {
            close(erfc(x), want, 1e-13);
        }
        assert_eq!(normal_cdf(f64::INFINITY), 1.0);
        assert_eq!(normal_cdf(f64::NEG_INFINITY), 0.0);
        assert!(normal_cdf(f64::NAN).is_nan());
    }

    /// `scipy.special.erfc(x)`, SciPy 1.17.1 (either side of the series / continued
    /// fraction switch at 2, and deep in the tail).
    const ERFC_REF: [(f64, f64); 14] = [
        (0.1, 0.8875370839817152),
        (0.5, 0.4795001221869535),
        (1.0, 0.15729920705028516),
        (1.999, 0.0046984433486294865),
        (2.0, 0.004677734981047266),
        (2.9, 4.109787809945884e-05),
        (2.999, 2.223016859983406e-05),
        (3.0, 2.2090496998585445e-05),
        (3.1, 1.1648657367199584e-05),
        (4.0, 1.541725790028002e-08),
        (6.0, 2.1519736712498913e-17),
        (10.0, 2.0884875837625446e-45),
        (26.0, 5.663192408856145e-296),
        (-1.0, 1.8427007929497148),
    ];

    #[test]
    fn wilson_closed_forms() {
        let z = Z95;
        let z2 = z * z;
        // 0/10: p̂ = 0, so centre = (z²/20)/(1 + z²/10) equals the half-width and
        // the interval is [0, z²/(10 + z²)].
        let (lo, hi) = wilson_interval(0, 10, z);
        assert_eq!(lo, 0.0);
        close(hi, z2 / (10.0 + z2), 1e-14);
        // 10/10: the mirror image, [10/(10 + z²), 1].
        let (lo, hi) = wilson_interval(10, 10, z);
        close(lo, 10.0 / (10.0 + z2), 1e-14);
        assert_eq!(hi, 1.0);
        // 5/10: centre 0.5, half-width z/(1 + z²/10) · √(0.25/10 + z²/400).
        let half = z / (1.0 + z2 / 10.0) * (0.025 + z2 / 400.0).sqrt();
        let (lo, hi) = wilson_interval(5, 10, z);
        close(lo, 0.5 - half, 1e-14);
        close(hi, 0.5 + half, 1e-14);
        // Numerically: 0.2365931..., 0.7634068... (the textbook values).
        assert!((lo - 0.236_593).abs() < 1e-6 && (hi - 0.763_407).abs() < 1e-6);
    }

    fn normals(rng: &mut ChaCha8Rng, n: usize, shift: f64) -> Vec<f64> {
        (0..n)
            .map(|_| {
                let x: f64 = StandardNormal.sample(rng);
                x + shift
            })
            .collect()
    }

    #[test]
    fn summarize_is_deterministic_and_ci_behaves() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let xs = normals(&mut rng, 40, 3.0);
        let a = summarize(&xs, 42);
        let b = summarize(&xs, 42);
        assert_eq!(a, b);
        assert_eq!(a.ci95.0.to_bits(), b.ci95.0.to_bits());
        assert_eq!(a.ci95.1.to_bits(), b.ci95.1.to_bits());
        assert_ne!(summarize(&xs, 43).ci95, a.ci95);
        assert_eq!(a.n, 40);
        assert!(a.min <= a.p5 && a.p5 <= a.median && a.median <= a.p95 && a.p95 <= a.max);

        // Symmetric data: the interval contains the mean.
        let sym: Vec<f64> = (-10..=10).map(f64::from).collect();
        let s = summarize(&sym, 1);
        assert_eq!(s.mean, 0.0);
        assert!(s.ci95.0 < 0.0 && s.ci95.1 > 0.0, "{:?}", s.ci95);
        // And it is roughly mean ± 1.96·σ/√n (σ = √38.5, n = 21 → ±2.6).
        assert!(
            (s.ci95.1 - s.ci95.0 - 2.0 * 2.6).abs() < 1.0,
            "{:?}",
            s.ci95
        );

        // Width shrinks like 1/√n: 4× the data → about half the width.
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let small = normals(&mut rng, 20, 0.0);
        let large = normals(&mut rng, 80, 0.0);
        let w = |xs: &[f64]| {
            let (lo, hi) = bootstrap_mean_ci(xs, 0.95, BOOTSTRAP_RESAMPLES, 5);
            assert!(lo < mean(xs) && mean(xs) < hi);
            hi - lo
        };
        let ratio = w(&small) / w(&large);
        assert!((1.5..2.7).contains(&ratio), "width ratio {ratio}");
    }

    /// Rejection rate at α = 0.05 over `reps` seeded repetitions.
    fn rejection_rate(reps: usize, mut test: impl FnMut(&mut ChaCha8Rng) -> f64) -> f64 {
        let mut rng = ChaCha8Rng::seed_from_u64(2024);
        let rejected = (0..reps).filter(|_| test(&mut rng) < 0.05).count();
        rejected as f64 / reps as f64
    }

    #[test]
    fn rank_tests_keep_their_level_and_have_power() {
        let reps = 2000;
        let bound = 0.05 + 3.0 * (0.05 * 0.95 / reps as f64).sqrt();
        let paired_p = |n: usize, shift: f64| {
            move |rng: &mut ChaCha8Rng| {
                let base = normals(rng, n, 0.0);
                let new = normals(rng, n, shift);
                let d: Vec<f64> = new.iter().zip(&base).map(|(x, y)| x - y).collect();
                wilcoxon_signed_rank(&d).map_or(1.0, |r| r.p_value)
            }
        };
        let unpaired_p = |n: usize, shift: f64| {
            move |rng: &mut ChaCha8Rng| {
                let base = normals(rng, n, 0.0);
                let new = normals(rng, n, shift);
                mann_whitney_u(&new, &base).map_or(1.0, |r| r.p_value)
            }
        };
        let size = rejection_rate(reps, paired_p(10, 0.0));
        assert!(size <= bound, "wilcoxon size {size}");
        let size = rejection_rate(reps, unpaired_p(10, 0.0));
        assert!(size <= bound, "mann-whitney size {size}");
        // A shift of one standard deviation, n = 20 (pairs / per sample).
        let power = rejection_rate(reps, paired_p(20, 1.0));
        assert!(power > 0.8, "wilcoxon power {power}");
        let power = rejection_rate(reps, unpaired_p(20, 1.0));
        assert!(power > 0.8, "mann-whitney power {power}");
    }
}
