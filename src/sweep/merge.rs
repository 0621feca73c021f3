//! `vinebench sweep merge`: the rows of every shard of a sweep, united into one table,
//! statistics per cell and metric, the sweep's expectations, plots, Markdown and JUnit.
//!
//! Merge needs only the sweep folders (their `sweep.json` and rows), not the scenario
//! files: shards' folders fetched as CI artifacts merge anywhere. Everything it writes is
//! a deterministic function of the rows, so a sweep split over any number of shards
//! merges to the same bytes as a single-process run; wall-clock times go to `timing.csv`
//! only.

use crate::scoring::expect::ExpectationResult;
use crate::sweep::aggregate::{AggregateExpectation, Sample, Scope};
use crate::sweep::junit::{self, TestCase, TestSuite, Verdict};
use crate::sweep::run::{self, JobStatus, ResultRow, SweepRunError};
use crate::sweep::spec::value_text;
use crate::sweep::stats;
use rayon::prelude::*;
use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::PathBuf;

pub use crate::sweep::summary::{AxisInfo, CellSummary, MergeSummary, SweepInfo};

/// The merged rows, one line per job, in job order (a sweep folder of its own).
pub const MERGED_ROWS: &str = "merged.jsonl";

/// Options of [`merge`].
#[derive(Clone, Debug, Default)]
pub struct MergeOptions {
    /// Where to write (created).
    pub out_dir: PathBuf,
    /// Merge even if jobs are missing.
    pub partial: bool,
    /// Also write JUnit XML here.
    pub junit: Option<PathBuf>,
}

/// The rows of the sweep folders `dirs` (all of one sweep), deduplicated, in job order.
pub fn collect(
    dirs: &[PathBuf],
) -> Result<(SweepInfo, Vec<ResultRow>, MergeSummary), SweepRunError> {
    let Some(first) = dirs.first() else {
        return Err(SweepRunError::Options(
            "expected at least one sweep folder".into(),
        ));
    };
    let info = SweepInfo::read(first)?;
    let mut all = Vec::new();
    let mut damaged = Vec::new();
    for d in dirs {
        let other = SweepInfo::read(d)?;
        if other.digest != info.digest {
            return Err(SweepRunError::OtherSweep {
                dir: d.display().to_string(),
                theirs: other.digest,
                ours: info.digest.clone(),
            });
        }
        let (rows, bad) = run::read_rows(d)?;
        all.extend(rows);
        damaged.extend(bad);
    }
    let n = info.job_count();
    let mut by_job: BTreeMap<usize, ResultRow> = BTreeMap::new();
    let (mut duplicates, mut conflicts) = (BTreeSet::new(), BTreeSet::new());
    for r in all {
        if r.sweep_digest != info.digest || r.job >= n {
            damaged.push(format!(
                "row of job {} ({}) belongs to another sweep",
                r.job, r.key
            ));
            continue;
        }
        // A row must say what its job number says (a hand-edited or damaged row must not
        // land in another cell).
        let (s, c, seed) = info.job(r.job);
        if info.scenarios[s] != r.scenario || c != r.cell || seed != r.seed {
            damaged.push(format!(
                "row of job {} ({}) does not match the sweep's job (scenario {}, cell {c}, seed {seed})",
                r.job, r.key, info.scenarios[s]
            ));
            continue;
        }
        match by_job.get(&r.job) {
            None => {
                by_job.insert(r.job, r);
            }
            Some(kept) => {
                let same = |a: &ResultRow, b: &ResultRow| {
                    a.status == b.status
                        && a.metrics == b.metrics
                        && a.failed == b.failed
                        && a.scenario_digest == b.scenario_digest
                };
                if same(kept, &r) {
                    duplicates.insert(r.key.clone());
                } else {
                    conflicts.insert(r.key.clone());
                }
            }
        }
    }
    let rows: Vec<ResultRow> = by_job.into_values().collect();
    let have: BTreeSet<usize> = rows.iter().map(|r| r.job).collect();
    let missing = (0..n)
        .filter(|j| !have.contains(j))
        .map(|j| {
            let (s, c, seed) = info.job(j);
            format!("{}/c{c}/s{seed}", info.scenarios[s])
        })
        .collect();
    let count = |s| rows.iter().filter(|r| r.status == s).count();
    let summary = MergeSummary {
        sweep: info.clone(),
        jobs: n,
        rows: rows.len(),
        missing,
        duplicates: duplicates.into_iter().collect(),
        conflicts: conflicts.into_iter().collect(),
        damaged,
        passed: count(JobStatus::Pass),
        failed: count(JobStatus::Fail),
        errors: count(JobStatus::Error),
        cells: Vec::new(),
        overall: Vec::new(),
        passed_all: false,
    };
    Ok((info, rows, summary))
}

/// The `metric.source` columns of the table: every metric some row reports, restricted
/// to the sweep's `metrics` when it names some, in name order.
pub fn columns(info: &SweepInfo, rows: &[ResultRow]) -> Vec<String> {
    let mut cols: BTreeSet<String> = BTreeSet::new();
    for r in rows {
        for k in r.metrics.keys() {
            let metric = k.split('.').next().unwrap_or_default();
            if info.metrics.is_empty() || info.metrics.iter().any(|m| m == metric) {
                cols.insert(k.clone());
            }
        }
    }
    cols.into_iter().collect()
}

/// A deterministic bootstrap seed per cell and column (FNV-1a).
fn seed_of(scenario: &str, cell: usize, column: &str) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in scenario
        .bytes()
        .chain(cell.to_le_bytes())
        .chain(column.bytes())
    {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

fn samples<'a>(rows: &[&'a ResultRow]) -> Vec<Sample<impl Fn(&str) -> Option<f64> + 'a>> {
    rows.iter()
        .map(|&r| Sample {
            value: move |c: &str| r.metrics.get(c).copied(),
            passed: r.status == JobStatus::Pass,
        })
        .collect()
}

/// Statistics, expectations and the verdict of merged rows.
pub fn summarize(
    info: &SweepInfo,
    rows: &[ResultRow],
    mut summary: MergeSummary,
) -> Result<MergeSummary, SweepRunError> {
    let parse = |texts: &[String], scope| {
        texts
            .iter()
            .map(|t| AggregateExpectation::parse(t, scope).map_err(SweepRunError::Options))
            .collect::<Result<Vec<_>, _>>()
    };
    let per_cell = parse(&info.per_cell, Scope::Cell)?;
    let overall = parse(&info.overall, Scope::Overall)?;
    let cols = columns(info, rows);
    // Rows by (scenario, cell); cells summarized in parallel (each bootstrap has its own
    // seed, so the result does not depend on the thread count).
    let mut groups: BTreeMap<(&str, usize), Vec<&ResultRow>> = BTreeMap::new();
    for r in rows {
        groups
            .entry((r.scenario.as_str(), r.cell))
            .or_default()
            .push(r);
    }
    let keys: Vec<(&String, usize)> = info
        .scenarios
        .iter()
        .flat_map(|s| (0..info.cells.len()).map(move |c| (s, c)))
        .collect();
    summary.cells = keys
        .par_iter()
        .map(|&(scenario, cell)| {
            let in_cell: &[&ResultRow] = groups
                .get(&(scenario.as_str(), cell))
                .map_or(&[], Vec::as_slice);
            let passed = in_cell
                .iter()
                .filter(|r| r.status == JobStatus::Pass)
                .count();
            let metrics = cols
                .iter()
                .filter_map(|c| {
                    let xs: Vec<f64> = in_cell
                        .iter()
                        .filter_map(|r| r.metrics.get(c).copied())
                        .filter(|v| v.is_finite())
                        .collect();
                    (!xs.is_empty())
                        .then(|| (c.clone(), stats::summarize(&xs, seed_of(scenario, cell, c))))
                })
                .collect();
            let s = samples(in_cell);
            CellSummary {
                scenario: scenario.clone(),
                cell,
                label: info.cell_label(cell),
                jobs: in_cell.len(),
                errors: in_cell
                    .iter()
                    .filter(|r| r.status == JobStatus::Error)
                    .count(),
                pass_rate: if in_cell.is_empty() {
                    f64::NAN
                } else {
                    passed as f64 / in_cell.len() as f64
                },
                pass_rate_ci95: stats::wilson_interval(passed, in_cell.len(), stats::Z95),
                metrics,
                expectations: per_cell.iter().map(|x| x.evaluate(&s)).collect(),
            }
        })
        .collect();
    let all: Vec<&ResultRow> = rows.iter().collect();
    let s = samples(&all);
    summary.overall = overall.iter().map(|x| x.evaluate(&s)).collect();
    summary.passed_all = summary.missing.is_empty()
        && summary.conflicts.is_empty()
        && summary.errors == 0
        && summary.overall.iter().all(|x| x.holds)
        && summary
            .cells
            .iter()
            .all(|c| c.expectations.iter().all(|x| x.holds));
    Ok(summary)
}

/// A number as it goes into a table: shortest round-trip form, empty for none.
fn num(v: Option<f64>) -> String {
    v.filter(|v| v.is_finite())
        .map(|v| v.to_string())
        .unwrap_or_default()
}

/// CSV field quoting (RFC 4180).
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// `results.csv`: one row per job (axes, seed, status, every metric column).
pub fn results_csv(info: &SweepInfo, rows: &[ResultRow], cols: &[String]) -> String {
    let mut head: Vec<String> = ["job", "key", "scenario", "cell"]
        .map(String::from)
        .to_vec();
    head.extend(info.axes.iter().map(|a| a.key.clone()));
    head.extend(["seed", "status"].map(String::from));
    head.extend(cols.iter().cloned());
    let mut out = head
        .iter()
        .map(|h| csv_field(h))
        .collect::<Vec<_>>()
        .join(",")
        + "\n";
    for r in rows {
        let mut f = vec![
            r.job.to_string(),
            r.key.clone(),
            r.scenario.clone(),
            r.cell.to_string(),
        ];
        for a in &info.axes {
            f.push(r.axes.get(&a.key).map(value_text).unwrap_or_default());
        }
        f.push(r.seed.to_string());
        f.push(
            match r.status {
                JobStatus::Pass => "pass",
                JobStatus::Fail => "fail",
                JobStatus::Error => "error",
            }
            .into(),
        );
        for c in cols {
            f.push(num(r.metrics.get(c).copied()));
        }
        out += &(f.iter().map(|x| csv_field(x)).collect::<Vec<_>>().join(",") + "\n");
    }
    out
}

/// `timing.csv`: wall-clock seconds per job (varies run to run; kept apart).
pub fn timing_csv(rows: &[ResultRow]) -> String {
    let mut out = String::from("job,key,wall_s\n");
    for r in rows {
        let _ = writeln!(out, "{},{},{:.3}", r.job, csv_field(&r.key), r.wall_s);
    }
    out
}

/// The JUnit suites: one per scenario and cell (a case per job and per per-cell
/// expectation), and one for the overall expectations.
pub fn junit_suites(
    info: &SweepInfo,
    rows: &[ResultRow],
    summary: &MergeSummary,
) -> Vec<TestSuite> {
    let expectation_case = |classname: &str, x: &ExpectationResult| TestCase {
        name: format!("expect: {}", x.text),
        classname: classname.to_string(),
        time_s: 0.0,
        verdict: if x.holds {
            Verdict::Pass
        } else {
            Verdict::Failure {
                message: x.text.clone(),
                details: x.to_string(),
            }
        },
        system_out: Some(x.to_string()),
    };
    let mut suites = Vec::new();
    for c in &summary.cells {
        let classname = format!("sweep.{}.{}.c{}", info.name, c.scenario, c.cell);
        let mut cases: Vec<TestCase> = rows
            .iter()
            .filter(|r| r.scenario == c.scenario && r.cell == c.cell)
            .map(|r| TestCase {
                name: format!("seed {}", r.seed),
                classname: classname.clone(),
                time_s: r.wall_s,
                verdict: match r.status {
                    JobStatus::Pass => Verdict::Pass,
                    JobStatus::Fail => Verdict::Failure {
                        message: format!("{} expectation(s) failed", r.failed.len()),
                        details: r.failed.join("\n"),
                    },
                    JobStatus::Error => Verdict::Error {
                        message: r.error.clone().unwrap_or_default(),
                        details: r.error.clone().unwrap_or_default(),
                    },
                },
                system_out: r.run_dir.as_ref().map(|d| format!("run folder: {d}")),
            })
            .collect();
        // Jobs without a row are errors too: nothing usable is never a pass.
        for key in summary
            .missing
            .iter()
            .filter(|k| k.starts_with(&format!("{}/c{}/", c.scenario, c.cell)))
        {
            cases.push(TestCase {
                name: key
                    .rsplit('/')
                    .next()
                    .unwrap_or(key)
                    .replacen('s', "seed ", 1),
                classname: classname.clone(),
                time_s: 0.0,
                verdict: Verdict::Error {
                    message: "no result row (the job did not run or its shard is missing)".into(),
                    details: key.clone(),
                },
                system_out: None,
            });
        }
        cases.extend(
            c.expectations
                .iter()
                .map(|x| expectation_case(&classname, x)),
        );
        suites.push(TestSuite {
            name: format!("{} / {} / {}", info.name, c.scenario, c.label),
            cases,
        });
    }
    if !summary.overall.is_empty() {
        let classname = format!("sweep.{}.overall", info.name);
        suites.push(TestSuite {
            name: format!("{} / overall", info.name),
            cases: summary
                .overall
                .iter()
                .map(|x| expectation_case(&classname, x))
                .collect(),
        });
    }
    suites
}

/// Merges sweep folders into `opts.out_dir`: `results.csv`, `timing.csv`,
/// `summary.json`, `sweep.md` with `plots/*.svg`, the merged rows (a sweep folder
/// `compare` reads), and JUnit when asked. Every file is written whole or not at all.
pub fn merge(dirs: &[PathBuf], opts: &MergeOptions) -> Result<MergeSummary, SweepRunError> {
    let (info, rows, summary) = collect(dirs)?;
    let summary = summarize(&info, &rows, summary)?;
    let out = &opts.out_dir;
    let write = |name: &str, bytes: &[u8]| run::write_file(&out.join(name), bytes);
    let cols = columns(&info, &rows);
    write("results.csv", results_csv(&info, &rows, &cols).as_bytes())?;
    write("timing.csv", timing_csv(&rows).as_bytes())?;
    let json = serde_json::to_string_pretty(&summary).map_err(|e| SweepRunError::Io {
        path: out.join("summary.json").display().to_string(),
        message: e.to_string(),
    })?;
    write("summary.json", (json + "\n").as_bytes())?;
    // The merged folder is a sweep folder too (compare reads it; merging it again gives
    // the same), unless it is one of the inputs, whose rows are already there.
    let same = |d: &PathBuf| match (d.canonicalize(), out.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    };
    if !dirs.iter().any(same) {
        let src = dirs[0].join(run::SWEEP_JSON);
        let sweep_json = std::fs::read(&src).map_err(run::io_err(&src))?;
        write(run::SWEEP_JSON, &sweep_json)?;
        let mut merged = Vec::new();
        for r in &rows {
            let mut r = r.clone();
            r.run_dir = None;
            merged.extend(serde_json::to_vec(&r).map_err(|e| SweepRunError::Io {
                path: MERGED_ROWS.into(),
                message: e.to_string(),
            })?);
            merged.push(b'\n');
        }
        write(&format!("{}/{MERGED_ROWS}", run::ROWS_DIR), &merged)?;
    }
    let plots = crate::sweep::plots::write_plots(&info, &summary, &out.join("plots"))?;
    write("sweep.md", markdown(&info, &summary, &plots).as_bytes())?;
    if let Some(j) = &opts.junit {
        let xml = junit::to_xml(
            &format!("sweep {}", info.name),
            &junit_suites(&info, &rows, &summary),
        );
        run::write_file(j, xml.as_bytes())?;
    }
    Ok(summary)
}

fn fmt3(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.4}")
    } else {
        "–".into()
    }
}

/// `sweep.md`: what ran, the expectations, a table per metric, the plots.
pub fn markdown(info: &SweepInfo, s: &MergeSummary, plots: &[(String, String)]) -> String {
    let mut md = format!("# Sweep `{}`\n\n", info.name);
    if !info.description.is_empty() {
        let _ = writeln!(md, "{}\n", info.description.trim());
    }
    let _ = writeln!(
        md,
        "{} scenario(s) × {} cell(s) × {} seed(s); {}{}.\n\n**{}**\n",
        info.scenarios.len(),
        info.cells.len(),
        info.seeds.len(),
        s.counts(),
        if s.missing.is_empty() {
            String::new()
        } else {
            format!("; **{} missing**", s.missing.len())
        },
        if s.passed_all { "PASS" } else { "FAIL" }
    );
    let expectation_rows: Vec<(String, &ExpectationResult)> = s
        .cells
        .iter()
        .flat_map(|c| {
            c.expectations
                .iter()
                .map(move |x| (format!("{} / {}", c.scenario, c.label), x))
        })
        .chain(s.overall.iter().map(|x| ("all jobs".to_string(), x)))
        .collect();
    if !expectation_rows.is_empty() {
        md.push_str("## Expectations\n\n| where | expectation | value | bound | margin | |\n|---|---|---:|---:|---:|---|\n");
        for (where_, x) in expectation_rows {
            let _ = writeln!(
                md,
                "| {where_} | `{}` | {} | {} | {} | {} |",
                x.text,
                x.lhs.map(fmt3).unwrap_or_else(|| "–".into()),
                x.rhs.map(fmt3).unwrap_or_else(|| "–".into()),
                x.margin
                    .map(fmt3)
                    .unwrap_or_else(|| x.note.clone().unwrap_or_default()),
                if x.holds { "holds" } else { "**FAILS**" }
            );
        }
        md.push('\n');
    }
    md.push_str(
        "## Cells\n\n| scenario | cell | jobs | pass rate (95 % CI) |\n|---|---|---:|---|\n",
    );
    for c in &s.cells {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {:.2} ({:.2}–{:.2}){} |",
            c.scenario,
            c.label,
            c.jobs,
            c.pass_rate,
            c.pass_rate_ci95.0,
            c.pass_rate_ci95.1,
            if c.errors > 0 {
                format!(", {} error(s)", c.errors)
            } else {
                String::new()
            }
        );
    }
    let cols: BTreeSet<&String> = s.cells.iter().flat_map(|c| c.metrics.keys()).collect();
    if !cols.is_empty() {
        md.push_str("\n## Metrics\n\nMean with its 95 % bootstrap interval, median, 5th and 95th percentile, over the seeds of each cell.\n");
        for col in cols {
            let _ = writeln!(
                md,
                "\n### `{col}`\n\n| scenario | cell | n | mean (95 % CI) | std | median | p5 | p95 | min | max |\n|---|---|---:|---|---:|---:|---:|---:|---:|---:|"
            );
            for c in &s.cells {
                if let Some(m) = c.metrics.get(col) {
                    let _ = writeln!(
                        md,
                        "| {} | {} | {} | {} ({}–{}) | {} | {} | {} | {} | {} | {} |",
                        c.scenario,
                        c.label,
                        m.n,
                        fmt3(m.mean),
                        fmt3(m.ci95.0),
                        fmt3(m.ci95.1),
                        fmt3(m.std),
                        fmt3(m.median),
                        fmt3(m.p5),
                        fmt3(m.p95),
                        fmt3(m.min),
                        fmt3(m.max)
                    );
                }
            }
        }
    }
    if !plots.is_empty() {
        md.push_str("\n## Plots\n\n");
        for (title, file) in plots {
            let _ = writeln!(md, "![{title}]({file})\n");
        }
    }
    if !s.missing.is_empty() {
        let _ = writeln!(
            md,
            "\n## Missing jobs\n\n{}",
            s.missing
                .iter()
                .take(50)
                .map(|k| format!("- `{k}`"))
                .collect::<Vec<_>>()
                .join("\n")
        );
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sweep folder of one scenario, two cells, two seeds, with `rows` as its rows file.
    fn folder(rows: &str) -> tempfile::TempDir {
        let d = tempfile::tempdir().unwrap();
        let sweep = serde_json::json!({"digest": "D", "sweep": {
            "name": "t", "scenarios": [{"name": "s"}], "seeds": [1, 2],
            "axes": [{"key": "k", "values": [1, 2]}],
            "cells": [{"values": [1]}, {"values": [2]}],
            "metrics": [], "per_cell": ["mean(ate_rmse_m.eif) < 1"], "overall": []}});
        std::fs::create_dir_all(d.path().join(run::ROWS_DIR)).unwrap();
        std::fs::write(d.path().join(run::SWEEP_JSON), sweep.to_string()).unwrap();
        std::fs::write(d.path().join(run::ROWS_DIR).join("a.jsonl"), rows).unwrap();
        d
    }

    fn row(job: usize, cell: usize, seed: u64, ate: f64) -> String {
        serde_json::json!({"job": job, "key": format!("s/c{cell}/s{seed}"), "scenario": "s",
            "cell": cell, "axes": {"k": cell + 1}, "seed": seed, "status": "pass",
            "metrics": {"ate_rmse_m.eif": ate}, "scenario_digest": "x", "sweep_digest": "D",
            "version": "0", "wall_s": 1.0})
        .to_string()
            + "\n"
    }

    #[test]
    fn damaged_duplicated_conflicting_and_missing_rows_are_reported() {
        let rows = [
            row(0, 0, 1, 0.5),
            row(0, 0, 1, 0.5), // duplicate, identical
            row(1, 0, 2, 0.7),
            row(1, 0, 2, 0.9), // conflict
            row(2, 0, 1, 0.1), // says cell 0 seed 1, but job 2 is cell 1 seed 1
            "{\"job\": 3, garbage\n".to_string(),
            row(7, 1, 2, 0.1), // no such job
        ]
        .concat();
        let d = folder(&rows);
        let (info, got, s) = collect(&[d.path().to_path_buf()]).unwrap();
        assert_eq!(got.len(), 2);
        assert_eq!(s.duplicates, vec!["s/c0/s1"]);
        assert_eq!(s.conflicts, vec!["s/c0/s2"]);
        assert_eq!(s.missing, vec!["s/c1/s1", "s/c1/s2"]);
        assert_eq!(s.damaged.len(), 3, "{:?}", s.damaged);
        let s = summarize(&info, &got, s).unwrap();
        assert_eq!(s.exit_code(true), 2, "conflicting results are never usable");
        // Cell 0: mean 0.6 < 1 holds; cell 1 has no values: its expectation fails.
        assert!(s.cells[0].expectations[0].holds);
        assert!(!s.cells[1].expectations[0].holds);
    }

    #[test]
    fn a_sweep_description_that_does_not_add_up_is_refused() {
        let d = folder("");
        let p = d.path().join(run::SWEEP_JSON);
        let text = std::fs::read_to_string(&p).unwrap();
        for (from, to) in [
            ("{\"values\":[2]}", "{\"values\":[]}"),
            ("\"seeds\":[1,2]", "\"seeds\":[]"),
            ("\"seeds\":[1,2]", "\"seeds\":\"x\""),
        ] {
            assert!(text.contains(from), "{from} in {text}");
            std::fs::write(&p, text.replace(from, to)).unwrap();
            assert!(SweepInfo::read(d.path()).is_err(), "{to}");
        }
    }

    #[test]
    fn csv_fields_are_quoted_as_rfc_4180_says() {
        assert_eq!(csv_field("a"), "a");
        assert_eq!(csv_field("[0.4, 0.3]"), "\"[0.4, 0.3]\"");
        assert_eq!(csv_field("say \"hi\""), "\"say \"\"hi\"\"\"");
    }
}
