//! What a merged sweep is: the sweep as its folder describes it ([`SweepInfo`], read
//! from `sweep.json`), and the statistics and verdict per cell ([`MergeSummary`], written
//! as `summary.json`). [`crate::sweep::merge`] computes them; the plots read them.

use crate::scoring::expect::ExpectationResult;
use crate::sweep::run::{self, SweepRunError};
use crate::sweep::spec::value_text;
use crate::sweep::stats::Summary;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// What `sweep.json` says of the sweep (all that merge needs).
#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct SweepInfo {
    /// Name.
    pub name: String,
    /// Description.
    #[serde(default)]
    pub description: String,
    /// The base scenarios' names, in order.
    pub scenarios: Vec<String>,
    /// Seeds.
    pub seeds: Vec<u64>,
    /// The axes.
    pub axes: Vec<AxisInfo>,
    /// Cells: a value per axis.
    pub cells: Vec<Vec<toml::Value>>,
    /// Metric names to tabulate (empty: all).
    pub metrics: Vec<String>,
    /// Per-cell expectations.
    pub per_cell: Vec<String>,
    /// Overall expectations.
    pub overall: Vec<String>,
    /// The sweep's digest.
    pub digest: String,
}

impl SweepInfo {
    /// Reads a sweep folder's `sweep.json`.
    pub fn read(dir: &Path) -> Result<SweepInfo, SweepRunError> {
        let path = dir.join(run::SWEEP_JSON);
        let bad = |message: String| SweepRunError::Io {
            path: path.display().to_string(),
            message,
        };
        let (digest, v) = run::read_sweep_json(&path)?;
        let s = v.get("sweep").ok_or_else(|| bad("no `sweep`".into()))?;
        let get = |k: &str| s.get(k).cloned().unwrap_or(serde_json::Value::Null);
        let from = |k: &str| -> Result<serde_json::Value, SweepRunError> {
            let x = get(k);
            if x.is_null() {
                return Err(bad(format!("no `sweep.{k}`")));
            }
            Ok(x)
        };
        let parse = |k: &'static str, x: serde_json::Value| {
            move |e: serde_json::Error| bad(format!("`sweep.{k}` ({x}): {e}"))
        };
        let scenarios: Vec<String> = from("scenarios")?
            .as_array()
            .map(|a| {
                a.iter()
                    .filter_map(|s| s.get("name").and_then(|n| n.as_str()).map(str::to_string))
                    .collect()
            })
            .unwrap_or_default();
        let axes: Vec<AxisInfo> =
            serde_json::from_value(from("axes")?).map_err(parse("axes", get("axes")))?;
        let cells: Vec<Vec<toml::Value>> = from("cells")?
            .as_array()
            .ok_or_else(|| bad("`sweep.cells` is not a list".into()))?
            .iter()
            .map(|c| {
                serde_json::from_value(c.get("values").cloned().unwrap_or_default())
                    .map_err(parse("cells", c.clone()))
            })
            .collect::<Result<_, _>>()?;
        let texts = |k: &'static str| -> Result<Vec<String>, SweepRunError> {
            serde_json::from_value(get(k)).map_err(parse(k, get(k)))
        };
        let info = SweepInfo {
            name: from("name")?.as_str().unwrap_or_default().to_string(),
            description: get("description").as_str().unwrap_or_default().to_string(),
            scenarios,
            seeds: serde_json::from_value(from("seeds")?).map_err(parse("seeds", get("seeds")))?,
            axes,
            cells,
            metrics: texts("metrics")?,
            per_cell: texts("per_cell")?,
            overall: texts("overall")?,
            digest,
        };
        if info.scenarios.is_empty() || info.seeds.is_empty() || info.cells.is_empty() {
            return Err(bad("a sweep has scenarios, seeds and cells".into()));
        }
        if let Some(c) = info.cells.iter().position(|c| c.len() != info.axes.len()) {
            return Err(bad(format!(
                "cell {c} has {} values for {} axes",
                info.cells[c].len(),
                info.axes.len()
            )));
        }
        if info
            .job_count_checked()
            .is_none_or(|n| n > crate::sweep::spec::MAX_JOBS)
        {
            return Err(bad(format!(
                "more than {} jobs",
                crate::sweep::spec::MAX_JOBS
            )));
        }
        Ok(info)
    }

    /// Number of jobs.
    pub fn job_count(&self) -> usize {
        self.scenarios.len() * self.cells.len() * self.seeds.len()
    }

    fn job_count_checked(&self) -> Option<usize> {
        self.scenarios
            .len()
            .checked_mul(self.cells.len())?
            .checked_mul(self.seeds.len())
    }

    /// Job `j`'s (scenario, cell, seed) in the stable order.
    pub fn job(&self, j: usize) -> (usize, usize, u64) {
        let per_scenario = self.cells.len() * self.seeds.len();
        let (s, rest) = (j / per_scenario, j % per_scenario);
        (
            s,
            rest / self.seeds.len(),
            self.seeds[rest % self.seeds.len()],
        )
    }

    /// A cell's label: `key = value, ...` of the axes that vary (`all` without any).
    pub fn cell_label(&self, cell: usize) -> String {
        let label = (0..self.axes.len())
            .filter(|&a| self.varies(a))
            .map(|a| {
                format!(
                    "{} = {}",
                    self.axes[a].key,
                    value_text(&self.cells[cell][a])
                )
            })
            .collect::<Vec<_>>()
            .join(", ");
        if label.is_empty() {
            "all".into()
        } else {
            label
        }
    }

    /// Whether axis `a` takes more than one value over the cells (a single-valued axis
    /// only sets a constant: labels and plots leave it out).
    pub fn varies(&self, a: usize) -> bool {
        let first = &self.cells[0][a];
        self.cells.iter().any(|c| &c[a] != first)
    }
}

/// What merge knows of an axis.
#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct AxisInfo {
    /// Dotted scenario key.
    pub key: String,
    /// Its values (in the sweep file's order).
    pub values: Vec<toml::Value>,
    /// Plot label.
    #[serde(default)]
    pub label: Option<String>,
    /// Plot positions of the values.
    #[serde(default)]
    pub x: Option<Vec<f64>>,
}

/// One cell of one scenario.
#[derive(Clone, Debug, Serialize)]
pub struct CellSummary {
    /// Scenario name.
    pub scenario: String,
    /// Cell number.
    pub cell: usize,
    /// `key = value, ...`.
    pub label: String,
    /// Jobs with a row.
    pub jobs: usize,
    /// Jobs that could not run.
    pub errors: usize,
    /// Fraction of jobs whose scenario expectations held.
    pub pass_rate: f64,
    /// Its 95 % Wilson interval.
    pub pass_rate_ci95: (f64, f64),
    /// Statistics per `metric.source`.
    pub metrics: BTreeMap<String, Summary>,
    /// The per-cell expectations.
    pub expectations: Vec<ExpectationResult>,
}

/// The merged sweep (`summary.json`).
#[derive(Clone, Debug, Serialize)]
pub struct MergeSummary {
    /// The sweep.
    pub sweep: SweepInfo,
    /// Jobs the sweep has.
    pub jobs: usize,
    /// Jobs with a row.
    pub rows: usize,
    /// Keys of jobs without a row.
    pub missing: Vec<String>,
    /// Keys of jobs with more than one row (identical results: kept once).
    pub duplicates: Vec<String>,
    /// Keys of jobs whose rows disagree (the first is kept).
    pub conflicts: Vec<String>,
    /// Rows that did not parse.
    pub damaged: Vec<String>,
    /// Jobs by status.
    pub passed: usize,
    /// Jobs whose scenario expectations failed.
    pub failed: usize,
    /// Jobs that could not run.
    pub errors: usize,
    /// Per scenario and cell.
    pub cells: Vec<CellSummary>,
    /// The overall expectations.
    pub overall: Vec<ExpectationResult>,
    /// Whether every job has a row, none errored, and every expectation holds.
    pub passed_all: bool,
}

impl MergeSummary {
    /// `12/15 job(s) with results (10 pass, 1 fail, 1 error)`.
    pub fn counts(&self) -> String {
        format!(
            "{}/{} job(s) with results ({} pass, {} fail, {} error)",
            self.rows, self.jobs, self.passed, self.failed, self.errors
        )
    }

    /// Exit code: 0 everything holds, 1 an expectation fails or a job could not run, 2 the
    /// results are incomplete.
    pub fn exit_code(&self, partial: bool) -> u8 {
        if (!self.missing.is_empty() && !partial) || !self.conflicts.is_empty() {
            2
        } else if self.passed_all {
            0
        } else {
            1
        }
    }
}
