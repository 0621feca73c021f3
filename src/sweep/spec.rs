//! Sweep files: which scenarios, seeds and parameter values to run, and what must hold
//! over the results; expanded into jobs in a stable order.
//!
//! ```toml
//! name = "rtk-outage-length"
//! scenario = "../row-loop-rtk-outage.toml"   # or scenarios = ["a.toml", "b.toml"]
//! seeds = "1-10"                              # or [1, 2, 3]
//! combine = "grid"                            # grid | zip | random | latin_hypercube
//! metrics = ["outage_max_error_m", "ate_rmse_m"]   # default: every metric
//!
//! [axes]
//! "faults.gnss[0].end_s" = [70.0, 80.0, 100.0]
//!
//! [expect]
//! per_cell = ["p95(outage_max_error_m.eif) <= 0.4"]
//! overall = ["mean(ate_rmse_m.eif) < mean(ate_rmse_m.gnss)"]
//! ```
//!
//! A job is one scenario with one cell's axis values and one seed. Jobs are numbered
//! scenario by scenario, cell by cell (the last axis varying fastest in a grid), seed by
//! seed; a job's key (`<scenario>/c<cell>/s<seed>`) and the SHA-256 of its resolved
//! scenario identify its result row.

use crate::scenario::{LoadedScenario, Override, ScenarioError};
use crate::sweep::aggregate::{AggregateExpectation, Scope};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use thiserror::Error;

/// Most jobs a sweep may expand to (a sweep larger than this is a typo, not a plan).
pub const MAX_JOBS: usize = 1_000_000;
/// Most seeds a `"a-b"` range may hold.
pub const MAX_SEEDS: usize = 100_000;
/// Largest sweep file read, bytes.
pub const MAX_SWEEP_FILE_BYTES: u64 = 1 << 20;

/// A sweep file that cannot be used: the file, where, and what was expected.
#[derive(Debug, Error)]
pub enum SweepError {
    /// The file could not be read.
    #[error("{file}: cannot read the sweep: {message}")]
    Io {
        /// The file.
        file: String,
        /// What went wrong.
        message: String,
    },
    /// Not valid TOML, or a key of the wrong type.
    #[error("{file}: {message}")]
    Syntax {
        /// The file.
        file: String,
        /// The parser's message, with line and column.
        message: String,
    },
    /// A key has an unusable value.
    #[error("{file}: `{key}`: {message}")]
    Field {
        /// The file.
        file: String,
        /// The key.
        key: String,
        /// What is wrong and what was expected.
        message: String,
    },
    /// A cell's values cannot be applied to the scenario, or make it invalid.
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
}

/// How the axes' values combine into cells.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Combine {
    /// Every combination (the last axis varies fastest).
    #[default]
    Grid,
    /// The i-th values of every axis together (all axes the same length).
    Zip,
    /// `samples` cells, each axis drawn uniformly from its range (seeded).
    Random,
    /// `samples` cells, Latin-hypercube sampling over the ranges (seeded): each axis's
    /// range cut into `samples` strata, each stratum used once.
    LatinHypercube,
}

/// The sweep file as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SweepFile {
    name: String,
    #[serde(default)]
    description: String,
    scenario: Option<String>,
    scenarios: Option<Vec<String>>,
    seeds: toml::Value,
    #[serde(default)]
    combine: Combine,
    samples: Option<usize>,
    #[serde(default)]
    sample_seed: u64,
    #[serde(default)]
    metrics: Vec<String>,
    #[serde(default)]
    axes: toml::Table,
    #[serde(default)]
    expect: ExpectFile,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct ExpectFile {
    #[serde(default)]
    per_cell: Vec<String>,
    #[serde(default)]
    overall: Vec<String>,
}

/// One axis: a scenario key and the values it takes.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Axis {
    /// Dotted scenario key (`world.occluders[0].s_m`).
    pub key: String,
    /// Values (`grid`/`zip`), or the sampled values of each cell (`random`, LHS).
    pub values: Vec<toml::Value>,
    /// What the plots call it (`outage length (s)`); default: the key.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub label: Option<String>,
    /// Where each value goes on the plots' x axis (`outage length` 10, 20, ... for
    /// `end_s` values 60, 70, ...); default: the values themselves.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub x: Option<Vec<f64>>,
}

/// An axis written as a table: `{ values = [...], label = "...", x = [...] }`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct AxisTable {
    values: Vec<toml::Value>,
    label: Option<String>,
    x: Option<Vec<f64>>,
}

/// One cell: a value per axis.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Cell {
    /// 0-based cell number.
    pub index: usize,
    /// One value per axis, in axis order.
    pub values: Vec<toml::Value>,
}

/// One job: a scenario, a cell and a seed.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Job {
    /// 0-based job number in the sweep's stable order.
    pub index: usize,
    /// Index into [`Sweep::scenarios`].
    pub scenario: usize,
    /// Index into [`Sweep::cells`].
    pub cell: usize,
    /// The scenario's seed for this job.
    pub seed: u64,
}

/// A base scenario of the sweep.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ScenarioRef {
    /// Path as written in the sweep file.
    pub path: String,
    /// Path resolved from the sweep file's folder.
    #[serde(skip)]
    pub resolved: PathBuf,
    /// Its `name` (the scenario's own).
    pub name: String,
}

/// A validated sweep, expanded.
#[derive(Clone, Debug, Serialize)]
pub struct Sweep {
    /// The sweep's name.
    pub name: String,
    /// What it is for.
    pub description: String,
    /// The sweep file as given.
    pub file: String,
    /// The base scenarios.
    pub scenarios: Vec<ScenarioRef>,
    /// The seeds, in order.
    pub seeds: Vec<u64>,
    /// How the axes combined.
    pub combine: Combine,
    /// The axes.
    pub axes: Vec<Axis>,
    /// The cells.
    pub cells: Vec<Cell>,
    /// Metric names to tabulate (empty: every metric the runs report).
    pub metrics: Vec<String>,
    /// Expectations evaluated in every cell (and scenario).
    #[serde(serialize_with = "texts")]
    pub per_cell: Vec<AggregateExpectation>,
    /// Expectations over all jobs together.
    #[serde(serialize_with = "texts")]
    pub overall: Vec<AggregateExpectation>,
}

fn texts<S: serde::Serializer>(x: &[AggregateExpectation], s: S) -> Result<S::Ok, S::Error> {
    s.collect_seq(x.iter().map(|e| e.text.as_str()))
}

impl Sweep {
    /// Reads, validates and expands a sweep file. Every cell's values are applied to
    /// every base scenario and the result validated like a scenario file (keys, types,
    /// ranges) before anything runs.
    pub fn load(path: &Path) -> Result<Sweep, SweepError> {
        let file = path.display().to_string();
        let io = |message: String| SweepError::Io {
            file: file.clone(),
            message,
        };
        let meta = std::fs::metadata(path).map_err(|e| io(e.to_string()))?;
        if !meta.is_file() {
            return Err(io("not a regular file".into()));
        }
        if meta.len() > MAX_SWEEP_FILE_BYTES {
            return Err(io(format!(
                "{} bytes; a sweep file is at most {MAX_SWEEP_FILE_BYTES}",
                meta.len()
            )));
        }
        // Bounded: the file may grow (or be a device) after the size check.
        let text = crate::fsio::read_text_bounded(path, MAX_SWEEP_FILE_BYTES)
            .map_err(|e| io(e.to_string()))?;
        let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Sweep::from_str(&text, &file, &base)
    }

    /// Validates sweep text; `file` names it in errors, scenario paths are relative to
    /// `base_dir`.
    pub fn from_str(text: &str, file: &str, base_dir: &Path) -> Result<Sweep, SweepError> {
        let f: SweepFile = toml::from_str(text).map_err(|e| SweepError::Syntax {
            file: file.to_string(),
            message: syntax_message(text, &e),
        })?;
        let field = |key: &str, message: String| SweepError::Field {
            file: file.to_string(),
            key: key.to_string(),
            message,
        };
        if f.name.is_empty()
            || !f
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
        {
            return Err(field(
                "name",
                format!(
                    "expected a non-empty name of letters, digits, '-', '_' or '.', found {:?}",
                    f.name
                ),
            ));
        }
        let paths = match (f.scenario, f.scenarios) {
            (Some(s), None) => vec![s],
            (None, Some(v)) if !v.is_empty() => v,
            (None, Some(_)) => {
                return Err(field("scenarios", "expected at least one scenario".into()));
            }
            (None, None) => {
                return Err(field(
                    "scenario",
                    "expected `scenario = \"file.toml\"` or `scenarios = [...]`".into(),
                ));
            }
            (Some(_), Some(_)) => {
                return Err(field(
                    "scenarios",
                    "expected either `scenario` or `scenarios`, not both".into(),
                ));
            }
        };
        let seeds = parse_seeds(&f.seeds).map_err(|m| field("seeds", m))?;
        for (i, m) in f.metrics.iter().enumerate() {
            if !crate::scoring::expect::is_known_metric(m) {
                return Err(field(
                    &format!("metrics[{i}]"),
                    format!(
                        "unknown metric `{m}` (metric names as in expectations, without the source)"
                    ),
                ));
            }
        }
        let mut axes = Vec::new();
        for (key, v) in &f.axes {
            axes.push((key.clone(), v.clone()));
        }
        let (axes, cells) = expand_axes(&axes, f.combine, f.samples, f.sample_seed)
            .map_err(|(k, m)| field(&k, m))?;
        let jobs = paths.len() * cells.len().max(1) * seeds.len();
        if jobs > MAX_JOBS {
            return Err(field(
                "seeds",
                format!("the sweep expands to {jobs} jobs; at most {MAX_JOBS}"),
            ));
        }
        // Every cell on every scenario, before anything runs.
        let mut scenarios = Vec::new();
        for (i, p) in paths.iter().enumerate() {
            let resolved = base_dir.join(p);
            let key = format!("scenarios[{i}]");
            if !resolved.is_file() {
                return Err(field(
                    &key,
                    format!("{}: no such scenario file", resolved.display()),
                ));
            }
            let mut name = None;
            for cell in &cells {
                let sc = load_job_scenario(&resolved, file, &axes, cell, seeds[0])?;
                name.get_or_insert(sc.scenario.name.clone());
            }
            let name = match name {
                Some(n) => n,
                None => LoadedScenario::load(&resolved)?.scenario.name,
            };
            scenarios.push(ScenarioRef {
                path: p.clone(),
                resolved,
                name,
            });
        }
        for (i, s) in scenarios.iter().enumerate() {
            if scenarios[..i].iter().any(|o| o.name == s.name) {
                return Err(field(
                    &format!("scenarios[{i}]"),
                    format!("two scenarios are named `{}`: job keys would clash", s.name),
                ));
            }
        }
        let parse = |list: &[String], key: &str, scope| {
            list.iter()
                .enumerate()
                .map(|(i, t)| {
                    AggregateExpectation::parse(t, scope)
                        .map_err(|m| field(&format!("expect.{key}[{i}]"), m))
                })
                .collect::<Result<Vec<_>, _>>()
        };
        let per_cell = parse(&f.expect.per_cell, "per_cell", Scope::Cell)?;
        let overall = parse(&f.expect.overall, "overall", Scope::Overall)?;
        Ok(Sweep {
            name: f.name,
            description: f.description,
            file: file.to_string(),
            scenarios,
            seeds,
            combine: f.combine,
            axes,
            cells,
            metrics: f.metrics,
            per_cell,
            overall,
        })
    }

    /// Every job, in the stable order.
    pub fn jobs(&self) -> Vec<Job> {
        let mut jobs = Vec::with_capacity(self.job_count());
        for scenario in 0..self.scenarios.len() {
            for cell in 0..self.cells.len() {
                for &seed in &self.seeds {
                    jobs.push(Job {
                        index: jobs.len(),
                        scenario,
                        cell,
                        seed,
                    });
                }
            }
        }
        jobs
    }

    /// Number of jobs.
    pub fn job_count(&self) -> usize {
        self.scenarios.len() * self.cells.len() * self.seeds.len()
    }

    /// A job's key: `<scenario name>/c<cell>/s<seed>`.
    pub fn job_key(&self, job: &Job) -> String {
        format!(
            "{}/c{}/s{}",
            self.scenarios[job.scenario].name, job.cell, job.seed
        )
    }

    /// The job's scenario: the base scenario with the cell's values and the seed.
    pub fn job_scenario(&self, job: &Job) -> Result<LoadedScenario, SweepError> {
        load_job_scenario(
            &self.scenarios[job.scenario].resolved,
            &self.file,
            &self.axes,
            &self.cells[job.cell],
            job.seed,
        )
    }

    /// SHA-256 of what defines the sweep's jobs (scenarios resolved, axes, cells, seeds):
    /// shards of one sweep agree on it, and merge refuses to mix two.
    pub fn digest(&self) -> String {
        let v = serde_json::json!({
            "name": self.name,
            "scenarios": self.scenarios.iter().map(|s| &s.name).collect::<Vec<_>>(),
            "seeds": self.seeds,
            "axes": self.axes.iter().map(|a| &a.key).collect::<Vec<_>>(),
            "cells": self.cells,
        });
        hex(&Sha256::digest(v.to_string().as_bytes()))
    }
}

/// SHA-256 of a job's resolved scenario (what its result depends on).
pub fn scenario_digest(sc: &LoadedScenario) -> String {
    hex(&Sha256::digest(sc.resolved_toml().as_bytes()))
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn load_job_scenario(
    path: &Path,
    sweep_file: &str,
    axes: &[Axis],
    cell: &Cell,
    seed: u64,
) -> Result<LoadedScenario, SweepError> {
    let mut overrides: Vec<Override> = axes
        .iter()
        .zip(&cell.values)
        .map(|(a, v)| Override {
            path: a.key.clone(),
            value: v.clone(),
            by: format!("{sweep_file}: axis \"{}\" = {}", a.key, value_text(v)),
        })
        .collect();
    overrides.push(Override {
        path: "seed".into(),
        value: toml::Value::Integer(i64::try_from(seed).unwrap_or(i64::MAX)),
        by: format!("{sweep_file}: seeds ({seed})"),
    });
    Ok(LoadedScenario::load_with(path, &overrides)?)
}

/// A TOML value as written in a file (`[0.4, 0.3, 1.0]`, `4.8`, `"eif"`).
pub fn value_text(v: &toml::Value) -> String {
    match v {
        toml::Value::String(s) => format!("{s:?}"),
        toml::Value::Array(a) => format!(
            "[{}]",
            a.iter().map(value_text).collect::<Vec<_>>().join(", ")
        ),
        other => other.to_string(),
    }
}

fn syntax_message(text: &str, e: &toml::de::Error) -> String {
    match e.span() {
        Some(span) => {
            let before = &text[..span.start.min(text.len())];
            let line = before.matches('\n').count() + 1;
            let col = before.len() - before.rfind('\n').map_or(0, |i| i + 1) + 1;
            format!("{line}:{col}: {}", e.message().trim())
        }
        None => e.message().trim().to_string(),
    }
}

/// `seeds = [1, 2, 3]` or `seeds = "1-20"` (inclusive), or a mix: `["1-5", 9]`.
fn parse_seeds(v: &toml::Value) -> Result<Vec<u64>, String> {
    let expected = "expected a list of seeds, a range such as \"1-20\", or a list of both";
    let mut out = Vec::new();
    let mut one = |v: &toml::Value| -> Result<(), String> {
        match v {
            toml::Value::Integer(i) => {
                out.push(u64::try_from(*i).map_err(|_| format!("{expected}; found {i} < 0"))?);
            }
            toml::Value::String(s) => {
                let (a, b) = s
                    .split_once('-')
                    .ok_or_else(|| format!("{expected}; found {s:?}"))?;
                let (a, b): (u64, u64) = (
                    a.trim()
                        .parse()
                        .map_err(|_| format!("{expected}; found {s:?}"))?,
                    b.trim()
                        .parse()
                        .map_err(|_| format!("{expected}; found {s:?}"))?,
                );
                if b < a || b - a >= MAX_SEEDS as u64 {
                    return Err(format!(
                        "range {s:?}: expected a <= b and at most {MAX_SEEDS} seeds"
                    ));
                }
                out.extend(a..=b);
            }
            other => return Err(format!("{expected}; found {other}")),
        }
        if out.len() > MAX_SEEDS {
            return Err(format!("at most {MAX_SEEDS} seeds"));
        }
        Ok(())
    };
    match v {
        toml::Value::Array(a) => a.iter().try_for_each(&mut one)?,
        other => one(other)?,
    }
    if out.is_empty() {
        return Err(format!("{expected}; found none"));
    }
    for (i, s) in out.iter().enumerate() {
        if out[..i].contains(s) {
            return Err(format!("seed {s} is listed twice"));
        }
    }
    Ok(out)
}

/// A sampled axis's range: `{ min = 10.0, max = 120.0 }`, integers with `integer = true`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Range {
    min: f64,
    max: f64,
    #[serde(default)]
    integer: bool,
}

/// The axes and their cells. Errors name the axis key.
fn expand_axes(
    raw: &[(String, toml::Value)],
    combine: Combine,
    samples: Option<usize>,
    sample_seed: u64,
) -> Result<(Vec<Axis>, Vec<Cell>), (String, String)> {
    let axis_key = |k: &str| format!("axes.\"{k}\"");
    match combine {
        Combine::Grid | Combine::Zip => {
            if samples.is_some() {
                return Err((
                    "samples".into(),
                    "only `random` and `latin_hypercube` sweeps take `samples`".into(),
                ));
            }
            let mut axes = Vec::new();
            for (k, v) in raw {
                let t = match v {
                    toml::Value::Array(values) => AxisTable {
                        values: values.clone(),
                        label: None,
                        x: None,
                    },
                    toml::Value::Table(t) if !t.contains_key("values") => {
                        let inner = t.keys().next().cloned().unwrap_or_default();
                        return Err((
                            axis_key(k),
                            format!(
                                "expected a list of values; a dotted scenario key must be quoted \
                                 (`\"{k}.{inner}\" = [...]`): unquoted dots make nested tables"
                            ),
                        ));
                    }
                    toml::Value::Table(_) => v.clone().try_into().map_err(|e: toml::de::Error| {
                        (
                            axis_key(k),
                            format!(
                                "expected a list of values or {{ values = [...], label = \"...\", x = [...] }}: {}",
                                e.message().trim()
                            ),
                        )
                    })?,
                    _ => {
                        return Err((
                            axis_key(k),
                            format!("expected a list of values, found {}", value_text(v)),
                        ));
                    }
                };
                if t.values.is_empty() {
                    return Err((axis_key(k), "expected at least one value".into()));
                }
                if let Some(x) = &t.x
                    && (x.len() != t.values.len() || x.iter().any(|v| !v.is_finite()))
                {
                    return Err((
                        axis_key(k),
                        format!(
                            "expected `x` to give a finite number for each of the {} values",
                            t.values.len()
                        ),
                    ));
                }
                axes.push(Axis {
                    key: k.clone(),
                    values: t.values,
                    label: t.label,
                    x: t.x,
                });
            }
            let cells = if combine == Combine::Grid {
                let total = axes
                    .iter()
                    .try_fold(1usize, |n, a| n.checked_mul(a.values.len()));
                let total = total
                    .filter(|n| *n <= MAX_JOBS)
                    .ok_or_else(|| ("axes".to_string(), format!("more than {MAX_JOBS} cells")))?;
                (0..total)
                    .map(|index| {
                        let mut rest = index;
                        let mut values = vec![toml::Value::Boolean(false); axes.len()];
                        for (a, slot) in axes.iter().zip(values.iter_mut()).rev() {
                            *slot = a.values[rest % a.values.len()].clone();
                            rest /= a.values.len();
                        }
                        Cell { index, values }
                    })
                    .collect()
            } else {
                let n = axes.first().map_or(1, |a| a.values.len());
                if let Some(a) = axes.iter().find(|a| a.values.len() != n) {
                    return Err((
                        axis_key(&a.key),
                        format!(
                            "`zip` needs every axis the same length: {} has {}, {} has {n}",
                            a.key,
                            a.values.len(),
                            axes[0].key
                        ),
                    ));
                }
                (0..n)
                    .map(|index| Cell {
                        index,
                        values: axes.iter().map(|a| a.values[index].clone()).collect(),
                    })
                    .collect()
            };
            Ok((axes, cells))
        }
        Combine::Random | Combine::LatinHypercube => {
            let n = samples
                .filter(|n| (1..=MAX_JOBS).contains(n))
                .ok_or_else(|| {
                    (
                        "samples".to_string(),
                        format!("expected the number of cells to sample, 1 to {MAX_JOBS}"),
                    )
                })?;
            let mut ranges = Vec::new();
            for (k, v) in raw {
                let r: Range = v.clone().try_into().map_err(|e: toml::de::Error| {
                    (
                        axis_key(k),
                        format!(
                            "expected a range {{ min = .., max = .. }} (optionally integer = true): {}",
                            e.message().trim()
                        ),
                    )
                })?;
                if !(r.min.is_finite() && r.max.is_finite() && r.min <= r.max) {
                    return Err((axis_key(k), "expected finite min <= max".into()));
                }
                ranges.push((k.clone(), r));
            }
            let mut rng = ChaCha8Rng::seed_from_u64(sample_seed);
            // Unit-cube coordinates per axis and cell.
            let mut unit: Vec<Vec<f64>> = Vec::with_capacity(ranges.len());
            for _ in &ranges {
                let u: Vec<f64> = if combine == Combine::Random {
                    (0..n).map(|_| rng.random::<f64>()).collect()
                } else {
                    let mut strata: Vec<usize> = (0..n).collect();
                    // Fisher-Yates with the seeded stream.
                    for i in (1..n).rev() {
                        strata.swap(i, rng.random_range(0..=i));
                    }
                    strata
                        .into_iter()
                        .map(|s| (s as f64 + rng.random::<f64>()) / n as f64)
                        .collect()
                };
                unit.push(u);
            }
            let value = |r: &Range, u: f64| {
                let x = r.min + (r.max - r.min) * u;
                if r.integer {
                    toml::Value::Integer(x.floor().clamp(r.min, r.max) as i64)
                } else {
                    toml::Value::Float(x)
                }
            };
            let cells: Vec<Cell> = (0..n)
                .map(|index| Cell {
                    index,
                    values: ranges
                        .iter()
                        .zip(&unit)
                        .map(|((_, r), u)| value(r, u[index]))
                        .collect(),
                })
                .collect();
            let axes = ranges
                .iter()
                .enumerate()
                .map(|(i, (k, _))| Axis {
                    key: k.clone(),
                    values: cells.iter().map(|c| c.values[i].clone()).collect(),
                    label: None,
                    x: None,
                })
                .collect();
            Ok((axes, cells))
        }
    }
}

/// The axis values of a cell by key (for result rows).
pub fn cell_values(sweep: &Sweep, cell: usize) -> BTreeMap<String, toml::Value> {
    sweep
        .axes
        .iter()
        .zip(&sweep.cells[cell].values)
        .map(|(a, v)| (a.key.clone(), v.clone()))
        .collect()
}
