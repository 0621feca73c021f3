//! The expectation language of sweeps: the scenario language
//! ([`crate::scoring::expect`]) over statistics of many runs.
//!
//! ```text
//! p95(outage_max_error_m.eif) <= 0.4
//! mean(ate_rmse_m.eif) < mean(ate_rmse_m.gnss)
//! median(ate_rmse_m.eif) < 0.5 * median(ate_rmse_m.tracking_camera)
//! rate(tracking_losses.slam_single_camera > 0) >= 0.8
//! pass_rate >= 0.9
//! ```
//!
//! Aggregates: `mean`, `median`, `std` (sample, n − 1), `min`, `max` and percentiles
//! `p1` … `p99` (linear interpolation, as NumPy's default) of a `metric.source` over the
//! jobs in scope; `rate(metric.source op value)`, the fraction of those jobs whose value
//! satisfies the comparison (a job without the value counts as not satisfying it);
//! `pass_rate`, the fraction of jobs whose own scenario expectations held (a job that
//! failed to run counts as not passing). An expectation is evaluated per cell
//! (`[expect] per_cell`) or over every job of the sweep (`[expect] overall`).
//!
//! ```
//! use vinebench::sweep::aggregate::{AggregateExpectation, Scope};
//! let x = AggregateExpectation::parse("p95(ate_rmse_m.eif) <= 0.4", Scope::Cell).unwrap();
//! let r = x.evaluate(&[0.1, 0.2, 0.3].map(|v| vinebench::sweep::aggregate::Sample {
//!     value: move |_: &str| Some(v),
//!     passed: true,
//! }));
//! assert!(r.holds);
//! ```

use crate::scoring::expect::{ExpectationResult, Op, is_known_metric, judge};
use crate::sweep::stats;
use serde::Serialize;

/// Where an expectation is evaluated.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Scope {
    /// Over the jobs of each cell (all seeds of one scenario and one set of axis values).
    Cell,
    /// Over every job of the sweep.
    Overall,
}

/// A statistic of one metric over jobs.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub enum Statistic {
    /// Arithmetic mean.
    Mean,
    /// Median.
    Median,
    /// Sample standard deviation.
    Std,
    /// Smallest value.
    Min,
    /// Largest value.
    Max,
    /// Percentile (1 to 99).
    Percentile(u8),
}

impl Statistic {
    fn parse(name: &str) -> Option<Statistic> {
        Some(match name {
            "mean" => Statistic::Mean,
            "median" => Statistic::Median,
            "std" => Statistic::Std,
            "min" => Statistic::Min,
            "max" => Statistic::Max,
            p => {
                let n: u8 = p.strip_prefix('p')?.parse().ok()?;
                if !(1..=99).contains(&n) {
                    return None;
                }
                Statistic::Percentile(n)
            }
        })
    }

    /// The statistic of `xs` (NaN when there are too few values).
    pub fn of(&self, xs: &[f64]) -> f64 {
        match self {
            Statistic::Mean => stats::mean(xs),
            Statistic::Median => stats::median(xs),
            Statistic::Std => stats::std_dev(xs),
            Statistic::Min => xs.iter().copied().reduce(f64::min).unwrap_or(f64::NAN),
            Statistic::Max => xs.iter().copied().reduce(f64::max).unwrap_or(f64::NAN),
            Statistic::Percentile(p) => stats::quantile(xs, f64::from(*p) / 100.0),
        }
    }
}

/// One side of an aggregate expectation.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub enum Term {
    /// A number.
    Number(f64),
    /// `factor * statistic(metric.source)`.
    Stat {
        /// Scale factor (1 when not written).
        factor: f64,
        /// Which statistic.
        stat: Statistic,
        /// `metric.source`.
        column: String,
    },
    /// `factor * rate(metric.source op value)`.
    Rate {
        /// Scale factor.
        factor: f64,
        /// `metric.source`.
        column: String,
        /// The comparison each job's value must satisfy.
        op: Op,
        /// Its bound.
        bound: f64,
    },
    /// `factor * pass_rate`.
    PassRate {
        /// Scale factor.
        factor: f64,
    },
}

/// What the evaluation needs of one job.
pub struct Sample<F: Fn(&str) -> Option<f64>> {
    /// The job's value of a `metric.source` column.
    pub value: F,
    /// Whether the job's own scenario expectations held.
    pub passed: bool,
}

impl Term {
    fn value<F: Fn(&str) -> Option<f64>>(&self, jobs: &[Sample<F>]) -> Option<f64> {
        match self {
            Term::Number(v) => Some(*v),
            Term::Stat {
                factor,
                stat,
                column,
            } => {
                let xs: Vec<f64> = jobs
                    .iter()
                    .filter_map(|j| (j.value)(column))
                    .filter(|v| v.is_finite())
                    .collect();
                if xs.is_empty() {
                    return None;
                }
                Some(factor * stat.of(&xs))
            }
            Term::Rate {
                factor,
                column,
                op,
                bound,
            } => {
                if jobs.is_empty() {
                    return None;
                }
                let hits = jobs
                    .iter()
                    .filter(|j| {
                        (j.value)(column)
                            .is_some_and(|v| judge("", *op, (Some(v), ""), Some(*bound)).holds)
                    })
                    .count();
                Some(factor * hits as f64 / jobs.len() as f64)
            }
            Term::PassRate { factor } => {
                if jobs.is_empty() {
                    return None;
                }
                let passed = jobs.iter().filter(|j| j.passed).count();
                Some(factor * passed as f64 / jobs.len() as f64)
            }
        }
    }

    /// The `metric.source` columns it reads.
    pub fn column(&self) -> Option<&str> {
        match self {
            Term::Stat { column, .. } | Term::Rate { column, .. } => Some(column),
            Term::Number(_) | Term::PassRate { .. } => None,
        }
    }
}

/// A parsed sweep expectation.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct AggregateExpectation {
    /// The text as written.
    pub text: String,
    /// Where it is evaluated.
    pub scope: Scope,
    /// Left-hand side.
    pub lhs: Term,
    /// Operator.
    pub op: Op,
    /// Right-hand side.
    pub rhs: Term,
}

impl AggregateExpectation {
    /// Parses `text`; the message of an error says what was expected.
    pub fn parse(text: &str, scope: Scope) -> Result<AggregateExpectation, String> {
        let t = text.trim();
        let (pos, sym, op) = top_level_op(t).ok_or_else(|| {
            format!(
                "expected `<statistic>(<metric>.<source>) <op> <value>` with op one of \
                 < <= > >=, found {t:?}"
            )
        })?;
        let lhs = parse_term(t[..pos].trim())?;
        let rhs = parse_term(t[pos + sym.len()..].trim())?;
        if matches!(lhs, Term::Number(_)) {
            return Err(format!(
                "the left-hand side must be a statistic, found {:?}",
                t[..pos].trim()
            ));
        }
        Ok(AggregateExpectation {
            text: t.to_string(),
            scope,
            lhs,
            op,
            rhs,
        })
    }

    /// Evaluates over `jobs` (those of one cell, or all).
    pub fn evaluate<F: Fn(&str) -> Option<f64>>(&self, jobs: &[Sample<F>]) -> ExpectationResult {
        let name = match &self.lhs {
            Term::Stat { column, .. } | Term::Rate { column, .. } => column.clone(),
            _ => "pass_rate".to_string(),
        };
        let lhs = self.lhs.value(jobs);
        let rhs = self.rhs.value(jobs);
        let mut r = judge(&self.text, self.op, (lhs, &name), rhs);
        if jobs.is_empty() {
            r.note = Some("no jobs".into());
        } else if lhs.is_none() {
            r.note = Some(format!("no job reported {name}"));
        }
        r
    }

    /// The `metric.source` columns it reads.
    pub fn columns(&self) -> impl Iterator<Item = &str> {
        self.lhs.column().into_iter().chain(self.rhs.column())
    }
}

/// The first comparison operator outside parentheses.
fn top_level_op(t: &str) -> Option<(usize, &'static str, Op)> {
    let mut depth = 0i32;
    let bytes = t.as_bytes();
    for (i, &b) in bytes.iter().enumerate() {
        match b {
            b'(' => depth += 1,
            b')' => depth -= 1,
            b'<' | b'>' if depth == 0 => {
                return Op::ALL
                    .iter()
                    .find(|(s, _)| t[i..].starts_with(s))
                    .map(|(s, o)| (i, *s, *o));
            }
            _ => {}
        }
    }
    None
}

fn parse_term(s: &str) -> Result<Term, String> {
    if let Ok(v) = s.parse::<f64>() {
        if !v.is_finite() {
            return Err(format!("a bound must be finite, found {s}"));
        }
        return Ok(Term::Number(v));
    }
    // `factor * term`, the factor a number before the first `*` outside parentheses.
    let (factor, body) = match s.split_once('*') {
        Some((f, b)) if !f.contains('(') => (
            f.trim()
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| format!("expected `<number> * <statistic>(...)`, found {s:?}"))?,
            b.trim(),
        ),
        _ => (1.0, s),
    };
    if body == "pass_rate" {
        return Ok(Term::PassRate { factor });
    }
    let (name, inner) = body
        .strip_suffix(')')
        .and_then(|b| b.split_once('('))
        .ok_or_else(|| {
            format!(
                "expected a number, `pass_rate`, `rate(<metric>.<source> <op> <value>)` or \
                 `<statistic>(<metric>.<source>)` with statistic one of mean, median, std, \
                 min, max, p1..p99; found {s:?}"
            )
        })?;
    let name = name.trim();
    if name == "rate" {
        let (pos, sym, op) = top_level_op(inner).ok_or_else(|| {
            format!("expected `rate(<metric>.<source> <op> <value>)`, found {s:?}")
        })?;
        let column = parse_column(inner[..pos].trim())?;
        let bound: f64 = inner[pos + sym.len()..]
            .trim()
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite())
            .ok_or_else(|| format!("expected a finite number as the bound in {s:?}"))?;
        return Ok(Term::Rate {
            factor,
            column,
            op,
            bound,
        });
    }
    let stat = Statistic::parse(name).ok_or_else(|| {
        format!(
            "unknown statistic `{name}` in {s:?}: expected mean, median, std, min, max, \
             p1..p99, rate or pass_rate"
        )
    })?;
    Ok(Term::Stat {
        factor,
        stat,
        column: parse_column(inner.trim())?,
    })
}

fn parse_column(s: &str) -> Result<String, String> {
    let (metric, source) = s
        .split_once('.')
        .filter(|(m, src)| !m.is_empty() && !src.is_empty())
        .ok_or_else(|| {
            format!("expected `<metric>.<source>` such as `ate_rmse_m.eif`, found {s:?}")
        })?;
    if !is_known_metric(metric) {
        return Err(format!(
            "unknown metric `{metric}` (see `vinebench defaults`, [expect] section, for the metrics)"
        ));
    }
    if !source
        .chars()
        .all(|c| c.is_ascii_alphanumeric() || c == '_')
    {
        return Err(format!(
            "expected a source name such as `eif`, found {source:?}"
        ));
    }
    Ok(format!("{metric}.{source}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn jobs(values: &[(Option<f64>, bool)]) -> Vec<Sample<impl Fn(&str) -> Option<f64>>> {
        values
            .iter()
            .map(|&(v, passed)| Sample {
                value: move |c: &str| {
                    if c == "ate_rmse_m.eif" {
                        v
                    } else {
                        v.map(|x| 2.0 * x)
                    }
                },
                passed,
            })
            .collect()
    }

    #[test]
    fn statistics_match_their_definitions() {
        let j = jobs(&[
            (Some(1.0), true),
            (Some(2.0), true),
            (Some(3.0), false),
            (Some(4.0), true),
        ]);
        let eval = |t: &str| {
            AggregateExpectation::parse(t, Scope::Cell)
                .unwrap()
                .evaluate(&j)
        };
        // mean 2.5, median 2.5, sample std sqrt(5/3), p95 = 3 + 0.85 = 3.85 (type 7).
        assert_eq!(eval("mean(ate_rmse_m.eif) <= 2.5").lhs, Some(2.5));
        assert_eq!(eval("median(ate_rmse_m.eif) <= 2.5").lhs, Some(2.5));
        let s = eval("std(ate_rmse_m.eif) <= 2").lhs.unwrap();
        assert!((s - (5.0_f64 / 3.0).sqrt()).abs() < 1e-12);
        let p = eval("p95(ate_rmse_m.eif) <= 4").lhs.unwrap();
        assert!((p - 3.85).abs() < 1e-12, "{p}");
        assert_eq!(eval("max(ate_rmse_m.eif) <= 4").lhs, Some(4.0));
        assert_eq!(eval("min(ate_rmse_m.eif) <= 4").lhs, Some(1.0));
        // The other column is twice as large: 2.5 < 0.6 * 5.
        let r = eval("mean(ate_rmse_m.eif) < 0.6 * mean(ate_rmse_m.gnss)");
        assert!(r.holds && (r.margin.unwrap() - 0.5).abs() < 1e-12, "{r:?}");
        // rate: 2 of 4 values > 2; pass_rate: 3 of 4.
        assert_eq!(eval("rate(ate_rmse_m.eif > 2) >= 0.5").lhs, Some(0.5));
        assert!(eval("rate(ate_rmse_m.eif > 2) >= 0.5").holds);
        assert_eq!(eval("pass_rate >= 0.75").lhs, Some(0.75));
        assert!(!eval("pass_rate > 0.75").holds);
    }

    #[test]
    fn missing_values_and_failed_jobs() {
        // A job that failed to run has no values and did not pass.
        let j = jobs(&[(Some(1.0), true), (None, false)]);
        let eval = |t: &str| {
            AggregateExpectation::parse(t, Scope::Cell)
                .unwrap()
                .evaluate(&j)
        };
        assert_eq!(eval("mean(ate_rmse_m.eif) < 2").lhs, Some(1.0));
        assert_eq!(eval("rate(ate_rmse_m.eif < 2) >= 1").lhs, Some(0.5));
        assert_eq!(eval("pass_rate >= 1").lhs, Some(0.5));
        let none = jobs(&[(None, false)]);
        let r = AggregateExpectation::parse("mean(ate_rmse_m.eif) < 2", Scope::Cell)
            .unwrap()
            .evaluate(&none);
        assert!(
            !r.holds && r.note.as_deref() == Some("no job reported ate_rmse_m.eif"),
            "{r:?}"
        );
        let empty = jobs(&[]);
        let r = AggregateExpectation::parse("pass_rate >= 0", Scope::Cell)
            .unwrap()
            .evaluate(&empty);
        assert!(!r.holds, "nothing usable is never a pass");
    }

    #[test]
    fn parse_errors_say_what_was_expected() {
        for (text, want) in [
            ("mean(ate_rmse_m.eif)", "with op one of"),
            ("avg(ate_rmse_m.eif) < 1", "unknown statistic `avg`"),
            ("p100(ate_rmse_m.eif) < 1", "unknown statistic `p100`"),
            ("mean(ate.eif) < 1", "unknown metric `ate`"),
            ("mean(ate_rmse_m) < 1", "expected `<metric>.<source>`"),
            (
                "rate(ate_rmse_m.eif) > 0.5",
                "expected `rate(<metric>.<source> <op> <value>)`",
            ),
            ("rate(ate_rmse_m.eif > x) > 0.5", "finite number"),
            (
                "0.4 >= p95(ate_rmse_m.eif)",
                "left-hand side must be a statistic",
            ),
            ("mean(ate_rmse_m.eif) < inf", "finite"),
            ("x * mean(ate_rmse_m.eif) < 1", "expected `<number> *"),
        ] {
            let e = AggregateExpectation::parse(text, Scope::Overall).unwrap_err();
            assert!(e.contains(want), "{text}: {e}");
        }
    }
}
