//! `vinebench sweep compare BASE NEW`: a regression gate between two sweeps of the same
//! experiment (main's stored results and a pull request's, say).
//!
//! Cells are matched by scenario and axis values, jobs within a cell by seed. For each
//! matched cell and metric column, the seeds both sweeps ran are *paired* (same world,
//! same noise) and tested with the Wilcoxon signed-rank test on the differences; a cell
//! without common seeds falls back to the Mann–Whitney U test on the two samples. A
//! metric **regresses** when it got worse by more than the allowance (relative to the
//! base mean, in the metric's bad direction) *and* the test rejects "no difference" at
//! `alpha`; an improvement is the same the other way. Metrics without a better direction
//! (`keyframes`, `distance_m`, ...) are listed but never flag.
//!
//! The gate makes one test per cell and metric, each at `alpha`: over many comparisons of
//! equal configurations about `alpha` of them would be significant by chance, and the
//! allowance removes those that are also small.

use crate::sweep::junit::{TestCase, TestSuite, Verdict};
use crate::sweep::merge::{self, SweepInfo};
use crate::sweep::run::{JobStatus, ResultRow, SweepRunError};
use crate::sweep::stats::{self, TestResult};
use serde::Serialize;
use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::PathBuf;

/// Which way a metric is better.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Better {
    /// Smaller values are better (errors, losses, collisions).
    Lower,
    /// Larger values are better (coverage, recall, F-score, completion).
    Higher,
}

/// The better direction of a metric, `None` for metrics that only describe a run.
pub fn better(metric: &str) -> Option<Better> {
    use Better::{Higher, Lower};
    Some(match metric {
        m if m.starts_with("ate_") || m.starts_with("rpe_") => Lower,
        "d_m" | "d_en_m" | "d_u_m" | "sigma_u_m" | "outage_max_error_m" => Lower,
        "map_accuracy_m" | "map_completeness_m" | "map_chamfer_m" => Lower,
        "tracking_losses" | "tracking_lost_s" | "maps_started" | "false_loops" => Lower,
        "collisions" | "max_cross_track_m" | "max_heading_error_deg" => Lower,
        "canopy_intrusion_s" | "canopy_intrusion_max_m" | "stopped_by_safety" => Lower,
        "min_clearance_m" => Higher,
        "compare_end_gap_m" | "compare_path_separation_m" => Lower,
        "coverage" | "route_completed" | "loop_recall" => Higher,
        m if m.starts_with("loop_precision") => Higher,
        m if m.starts_with("map_precision_")
            || m.starts_with("map_recall_")
            || m.starts_with("map_f_score_") =>
        {
            Higher
        }
        _ => return None,
    })
}

/// Options of [`compare`].
#[derive(Clone, Debug)]
pub struct CompareOptions {
    /// Metric names to gate (empty: every metric with a better direction).
    pub metrics: Vec<String>,
    /// Largest relative worsening allowed (0.05 = 5 %).
    pub max_worse: f64,
    /// Significance level of each test.
    pub alpha: f64,
}

impl Default for CompareOptions {
    fn default() -> Self {
        CompareOptions {
            metrics: Vec::new(),
            max_worse: 0.05,
            alpha: 0.05,
        }
    }
}

/// What a comparison found.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Finding {
    /// Worse beyond the allowance, and significant.
    Regression,
    /// Better beyond the allowance, and significant.
    Improvement,
    /// Neither.
    Unchanged,
    /// No better direction: listed only.
    NotGated,
    /// Too few values to test.
    Untestable,
}

/// One cell and metric column, compared.
#[derive(Clone, Debug, Serialize)]
pub struct Comparison {
    /// Scenario.
    pub scenario: String,
    /// Cell label (`key = value, ...`).
    pub cell: String,
    /// `metric.source`.
    pub column: String,
    /// Values in the base and the new sweep.
    pub n_base: usize,
    /// Values in the new sweep.
    pub n_new: usize,
    /// Seeds with values in both.
    pub n_paired: usize,
    /// Means.
    pub mean_base: f64,
    /// Mean of the new sweep.
    pub mean_new: f64,
    /// How much worse, relative to |base mean| (negative: better).
    pub worse_rel: f64,
    /// The test made (paired or not), if any.
    pub test: Option<TestResult>,
    /// Verdict.
    pub finding: Finding,
}

/// The gate's result.
#[derive(Clone, Debug, Serialize)]
pub struct CompareReport {
    /// Base sweep name and folder.
    pub base: String,
    /// New sweep name and folder.
    pub new: String,
    /// Allowance.
    pub max_worse: f64,
    /// Significance level.
    pub alpha: f64,
    /// Every comparison.
    pub comparisons: Vec<Comparison>,
    /// Cells of one sweep without a match in the other.
    pub unmatched_cells: Vec<String>,
    /// Jobs that could not run, in either sweep.
    pub errors: usize,
}

impl CompareReport {
    /// Comparisons with the given finding.
    pub fn with(&self, f: Finding) -> impl Iterator<Item = &Comparison> {
        self.comparisons.iter().filter(move |c| c.finding == f)
    }

    /// Exit code: 1 on any regression, else 0.
    pub fn exit_code(&self) -> u8 {
        u8::from(self.with(Finding::Regression).next().is_some())
    }
}

/// Values of one column in one cell, by seed.
type CellValues = BTreeMap<u64, f64>;

/// (scenario, cell label) → column → seed → value.
fn by_cell(
    info: &SweepInfo,
    rows: &[ResultRow],
) -> BTreeMap<(String, String), BTreeMap<String, CellValues>> {
    let mut out: BTreeMap<(String, String), BTreeMap<String, CellValues>> = BTreeMap::new();
    for r in rows.iter().filter(|r| r.status != JobStatus::Error) {
        let cell = out
            .entry((r.scenario.clone(), info.cell_label(r.cell)))
            .or_default();
        for (c, v) in &r.metrics {
            if v.is_finite() {
                cell.entry(c.clone()).or_default().insert(r.seed, *v);
            }
        }
    }
    out
}

/// Compares one column's values.
pub fn compare_values(
    base: &CellValues,
    new: &CellValues,
    dir: Option<Better>,
    o: &CompareOptions,
) -> (usize, f64, f64, f64, Option<TestResult>, Finding) {
    let paired: Vec<(f64, f64)> = base
        .iter()
        .filter_map(|(s, b)| new.get(s).map(|n| (*b, *n)))
        .collect();
    let bv: Vec<f64> = base.values().copied().collect();
    let nv: Vec<f64> = new.values().copied().collect();
    let (mean_base, mean_new) = if paired.is_empty() {
        (stats::mean(&bv), stats::mean(&nv))
    } else {
        (
            stats::mean(&paired.iter().map(|p| p.0).collect::<Vec<_>>()),
            stats::mean(&paired.iter().map(|p| p.1).collect::<Vec<_>>()),
        )
    };
    let scale = mean_base.abs().max(f64::MIN_POSITIVE);
    let change = (mean_new - mean_base) / scale;
    let worse_rel = match dir {
        Some(Better::Higher) => -change,
        _ => change,
    };
    let Some(dir) = dir else {
        return (
            paired.len(),
            mean_base,
            mean_new,
            worse_rel,
            None,
            Finding::NotGated,
        );
    };
    let _ = dir;
    let test = if paired.is_empty() {
        stats::mann_whitney_u(&bv, &nv)
    } else {
        let d: Vec<f64> = paired.iter().map(|(b, n)| n - b).collect();
        // All differences zero: identical results, nothing to test.
        if d.iter().all(|x| *x == 0.0) {
            return (
                paired.len(),
                mean_base,
                mean_new,
                0.0,
                None,
                Finding::Unchanged,
            );
        }
        stats::wilcoxon_signed_rank(&d)
    };
    let finding = match &test {
        None => Finding::Untestable,
        Some(t) if !t.p_value.is_finite() => Finding::Untestable,
        Some(t) if t.p_value < o.alpha && worse_rel > o.max_worse => Finding::Regression,
        Some(t) if t.p_value < o.alpha && -worse_rel > o.max_worse => Finding::Improvement,
        Some(_) => Finding::Unchanged,
    };
    (paired.len(), mean_base, mean_new, worse_rel, test, finding)
}

/// Compares two sweeps (each a sweep folder, merged or a shard's).
pub fn compare(
    base: &PathBuf,
    new: &PathBuf,
    o: &CompareOptions,
) -> Result<CompareReport, SweepRunError> {
    if !(o.alpha > 0.0 && o.alpha < 1.0) {
        return Err(SweepRunError::Options(format!(
            "--alpha {}: expected 0 < alpha < 1",
            o.alpha
        )));
    }
    if !(o.max_worse.is_finite() && o.max_worse >= 0.0) {
        return Err(SweepRunError::Options(format!(
            "--max-worse {}: expected a fraction >= 0",
            o.max_worse
        )));
    }
    for m in &o.metrics {
        if !crate::scoring::expect::is_known_metric(m) {
            return Err(SweepRunError::Options(format!(
                "--metrics: unknown metric `{m}`"
            )));
        }
    }
    let (bi, brows, bs) = merge::collect(std::slice::from_ref(base))?;
    let (ni, nrows, ns) = merge::collect(std::slice::from_ref(new))?;
    let (bc, nc) = (by_cell(&bi, &brows), by_cell(&ni, &nrows));
    let mut comparisons = Vec::new();
    let mut unmatched = Vec::new();
    for (key, bcols) in &bc {
        let Some(ncols) = nc.get(key) else {
            unmatched.push(format!("{} / {} (only in the base)", key.0, key.1));
            continue;
        };
        let cols: BTreeSet<&String> = bcols.keys().chain(ncols.keys()).collect();
        for col in cols {
            let metric = col.split('.').next().unwrap_or_default();
            if !o.metrics.is_empty() && !o.metrics.iter().any(|m| m == metric) {
                continue;
            }
            let empty = CellValues::new();
            let (b, n) = (
                bcols.get(col).unwrap_or(&empty),
                ncols.get(col).unwrap_or(&empty),
            );
            let (n_paired, mean_base, mean_new, worse_rel, test, finding) =
                compare_values(b, n, better(metric), o);
            comparisons.push(Comparison {
                scenario: key.0.clone(),
                cell: key.1.clone(),
                column: col.clone(),
                n_base: b.len(),
                n_new: n.len(),
                n_paired,
                mean_base,
                mean_new,
                worse_rel,
                test,
                finding,
            });
        }
    }
    for key in nc.keys().filter(|k| !bc.contains_key(*k)) {
        unmatched.push(format!("{} / {} (only in the new sweep)", key.0, key.1));
    }
    Ok(CompareReport {
        base: format!("{} ({})", bi.name, base.display()),
        new: format!("{} ({})", ni.name, new.display()),
        max_worse: o.max_worse,
        alpha: o.alpha,
        comparisons,
        unmatched_cells: unmatched,
        errors: bs.errors + ns.errors,
    })
}

/// The Markdown a person reads in a CI log or a pull-request comment.
pub fn markdown(r: &CompareReport) -> String {
    let regressions: Vec<&Comparison> = r.with(Finding::Regression).collect();
    let improvements: Vec<&Comparison> = r.with(Finding::Improvement).collect();
    let mut md = format!(
        "## Sweep comparison: {} → {}\n\n{} regression(s), {} improvement(s) over {} comparison(s) \
         (allowance {:.1} %, α = {}; paired Wilcoxon signed-rank by seed, Mann–Whitney U where \
         no seed is shared).\n",
        r.base,
        r.new,
        regressions.len(),
        improvements.len(),
        r.comparisons.len(),
        r.max_worse * 100.0,
        r.alpha
    );
    let table = |md: &mut String, title: &str, list: &[&Comparison]| {
        if list.is_empty() {
            return;
        }
        let _ = writeln!(
            md,
            "\n### {title}\n\n| scenario | cell | metric | base mean | new mean | change | p | n (paired) |\n|---|---|---|---:|---:|---:|---:|---:|"
        );
        for c in list {
            let _ = writeln!(
                md,
                "| {} | {} | `{}` | {:.4} | {:.4} | {:+.1} % | {} | {} ({}) |",
                c.scenario,
                c.cell,
                c.column,
                c.mean_base,
                c.mean_new,
                (c.mean_new - c.mean_base) / c.mean_base.abs().max(f64::MIN_POSITIVE) * 100.0,
                c.test
                    .as_ref()
                    .map_or("–".into(), |t| format!("{:.2e}", t.p_value)),
                c.n_base.max(c.n_new),
                c.n_paired
            );
        }
    };
    table(&mut md, "Regressions", &regressions);
    table(&mut md, "Improvements", &improvements);
    if !r.unmatched_cells.is_empty() {
        let _ = writeln!(
            md,
            "\nCells without a match: {}",
            r.unmatched_cells.join("; ")
        );
    }
    if r.errors > 0 {
        let _ = writeln!(md, "\n{} job(s) could not run (not compared).", r.errors);
    }
    let _ = writeln!(
        md,
        "\n**{}**",
        if regressions.is_empty() {
            "no regression"
        } else {
            "REGRESSION"
        }
    );
    md
}

/// JUnit: a suite per cell, a case per gated metric (failure on regression).
pub fn junit_suites(r: &CompareReport) -> Vec<TestSuite> {
    let mut suites: BTreeMap<(String, String), Vec<TestCase>> = BTreeMap::new();
    for c in r
        .comparisons
        .iter()
        .filter(|c| c.finding != Finding::NotGated)
    {
        let detail = format!(
            "base mean {:.6}, new mean {:.6}, worse by {:+.2} %, p = {}",
            c.mean_base,
            c.mean_new,
            c.worse_rel * 100.0,
            c.test.as_ref().map_or("–".into(), |t| format!(
                "{:.3e} ({})",
                t.p_value, t.method
            ))
        );
        suites
            .entry((c.scenario.clone(), c.cell.clone()))
            .or_default()
            .push(TestCase {
                name: c.column.clone(),
                classname: format!("compare.{}", c.scenario),
                time_s: 0.0,
                verdict: if c.finding == Finding::Regression {
                    Verdict::Failure {
                        message: format!("{} regressed", c.column),
                        details: detail.clone(),
                    }
                } else {
                    Verdict::Pass
                },
                system_out: Some(detail),
            });
    }
    suites
        .into_iter()
        .map(|((s, cell), cases)| TestSuite {
            name: format!("compare / {s} / {cell}"),
            cases,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    fn values(seeds: std::ops::Range<u64>, f: impl Fn(u64) -> f64) -> CellValues {
        seeds.map(|s| (s, f(s))).collect()
    }

    #[test]
    fn identical_results_never_flag_and_a_worse_one_does() {
        let o = CompareOptions::default();
        let base = values(1..21, |s| 0.1 + 0.01 * (s % 7) as f64);
        let same = compare_values(&base, &base.clone(), Some(Better::Lower), &o);
        assert_eq!(same.5, Finding::Unchanged);
        // 20 % worse on every seed: significant and beyond the allowance.
        let worse = values(1..21, |s| base[&s] * 1.2);
        assert_eq!(
            compare_values(&base, &worse, Some(Better::Lower), &o).5,
            Finding::Regression
        );
        // The same change on a higher-is-better metric is an improvement.
        assert_eq!(
            compare_values(&base, &worse, Some(Better::Higher), &o).5,
            Finding::Improvement
        );
        // 2 % worse on every seed: significant but within the allowance.
        let slightly = values(1..21, |s| base[&s] * 1.02);
        assert_eq!(
            compare_values(&base, &slightly, Some(Better::Lower), &o).5,
            Finding::Unchanged
        );
        // No direction: never gated.
        assert_eq!(compare_values(&base, &worse, None, &o).5, Finding::NotGated);
        // Disjoint seeds: the unpaired test.
        let shifted = values(101..121, |s| base[&(s - 100)] * 1.5);
        let r = compare_values(&base, &shifted, Some(Better::Lower), &o);
        assert_eq!((r.0, r.5), (0, Finding::Regression));
        assert!(r.4.unwrap().method.starts_with("mann-whitney"));
    }

    /// Equal configurations on disjoint seed sets: over many comparisons the gate flags
    /// no more often than `alpha` (here with no allowance, the test alone).
    #[test]
    fn false_alarm_rate_is_at_most_alpha() {
        let o = CompareOptions {
            max_worse: 0.0,
            ..CompareOptions::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let noise = Normal::new(1.0, 0.2).unwrap();
        let trials = 2000;
        let (mut paired_flags, mut unpaired_flags) = (0, 0);
        for _ in 0..trials {
            // Paired: per-seed world effect shared, run noise independent.
            let world: Vec<f64> = (0..10).map(|_| noise.sample(&mut rng)).collect();
            let run_a: Vec<f64> = (0..10).map(|_| 0.1 * noise.sample(&mut rng)).collect();
            let run_b: Vec<f64> = (0..10).map(|_| 0.1 * noise.sample(&mut rng)).collect();
            let a = values(0..10, |s| world[s as usize] + run_a[s as usize]);
            let b = values(0..10, |s| world[s as usize] + run_b[s as usize]);
            paired_flags += usize::from(
                compare_values(&a, &b, Some(Better::Lower), &o).5 == Finding::Regression,
            );
            // Unpaired: disjoint seeds.
            let c: CellValues = (0..10).map(|s| (s, noise.sample(&mut rng))).collect();
            let d: CellValues = (10..20).map(|s| (s, noise.sample(&mut rng))).collect();
            unpaired_flags += usize::from(
                compare_values(&c, &d, Some(Better::Lower), &o).5 == Finding::Regression,
            );
        }
        // One-sided: a regression is half of the two-sided rejections, so at most alpha/2
        // in expectation; allow three binomial standard deviations above alpha/2.
        let p = o.alpha / 2.0;
        let bound = p + 3.0 * (p * (1.0 - p) / trials as f64).sqrt();
        for (name, flags) in [("paired", paired_flags), ("unpaired", unpaired_flags)] {
            let rate = flags as f64 / trials as f64;
            assert!(rate <= bound, "{name}: {rate} > {bound}");
        }
    }

    #[test]
    fn directions_cover_the_gated_metrics() {
        assert_eq!(better("ate_rmse_m"), Some(Better::Lower));
        assert_eq!(better("map_f_score_2cm"), Some(Better::Higher));
        assert_eq!(better("loop_precision_heading"), Some(Better::Higher));
        assert_eq!(better("keyframes"), None);
        // Every metric an expectation may name is either gated or knowingly not.
        let neutral = [
            "keyframes",
            "loops",
            "revisits",
            "bow_candidates",
            "bow_rejected",
            "distance_m",
            "max_tilt_deg",
            // What the receiver got describes the world (the canopy, the sky), not the
            // software under test.
            "gnss_fixed_share",
            "gnss_no_fix_share",
            "gnss_fix_losses",
            "gnss_refix_max_s",
            "gnss_mean_satellites",
        ];
        for list in [
            crate::scoring::expect::METRICS,
            crate::scoring::expect::ROBOT_METRICS,
            crate::scoring::expect::SLAM_METRICS,
            crate::scoring::expect::MAP_METRICS,
        ] {
            for (m, _) in list {
                assert!(
                    better(m).is_some() || neutral.contains(m),
                    "{m} has no direction"
                );
            }
        }
    }
}
