//! `vinebench bench --only sweep`: what running a sweep costs besides its runs (issue #28).
//!
//! - Throughput: a sweep of [`SWEEP_JOBS`] no-camera jobs (the one-outage row loop cut to
//!   100 s, two cells, seeds 1–10) with `--jobs 1` and `--jobs 2`, in jobs per minute;
//!   with one job at a time, the sweep's own overhead per job (its wall time less the sum
//!   of the runs' wall times: expansion, validation, rows written and synced).
//! - Merge: [`MERGE_ROWS`] synthetic rows (100 cells × 100 seeds, 12 metric columns)
//!   merged into every output (CSV, statistics with bootstrap intervals, Markdown, plots,
//!   JUnit), wall seconds (target: under one second).

use crate::bench::{BenchError, Figure};
use crate::sweep::merge::{self, MergeOptions};
use crate::sweep::run::{self, JobStatus, Keep, ResultRow, Shard, SweepOptions};
use crate::sweep::spec::Sweep;
use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

/// Jobs of the throughput sweep.
pub const SWEEP_JOBS: usize = 20;
/// Rows of the merge benchmark.
pub const MERGE_ROWS: usize = 10_000;
/// The base scenario of the throughput sweep.
const BASE_TOML: &str = include_str!("../../scenarios/sweeps/row-loop-one-outage.toml");

fn setup(e: impl std::fmt::Display) -> BenchError {
    BenchError::Setup(e.to_string())
}

/// The sweep figures.
pub fn sweep_figures(quick: bool) -> Result<Vec<Figure>, BenchError> {
    let dir = tempfile_dir("sweep")?;
    let result = (|| {
        std::fs::write(dir.join("base.toml"), BASE_TOML).map_err(setup)?;
        let seeds = if quick { "1-5" } else { "1-10" };
        std::fs::write(
            dir.join("bench.toml"),
            format!(
                "name = \"bench\"\nscenario = \"base.toml\"\nseeds = \"{seeds}\"\n\
                 [axes]\nmax_duration_s = [100.0]\n\"faults.gnss[0].end_s\" = [70.0, 90.0]\n"
            ),
        )
        .map_err(setup)?;
        let sweep = Sweep::load(&dir.join("bench.toml")).map_err(setup)?;
        let jobs = sweep.job_count();
        let mut figures = Vec::new();
        for parallel in [1, 2] {
            let out = dir.join(format!("out{parallel}"));
            let t0 = Instant::now();
            run::run_shard(
                &sweep,
                &SweepOptions {
                    out_dir: out.clone(),
                    jobs: parallel,
                    shard: Shard::all(),
                    keep: Keep::None,
                    progress: false,
                    stop: None,
                },
            )
            .map_err(setup)?;
            let wall = t0.elapsed().as_secs_f64();
            figures.push(Figure {
                name: if parallel == 1 {
                    "sweep of no-camera jobs, --jobs 1, jobs per minute"
                } else {
                    "sweep of no-camera jobs, --jobs 2, jobs per minute"
                },
                value: jobs as f64 / wall * 60.0,
                unit: "jobs/min",
                target: None,
            });
            if parallel == 1 {
                let (rows, _) = run::read_rows(&out).map_err(setup)?;
                let runs: f64 = rows.iter().map(|r| r.wall_s).sum();
                figures.push(Figure {
                    name: "sweep overhead per job beside its run (--jobs 1), ms",
                    value: (wall - runs).max(0.0) / jobs as f64 * 1e3,
                    unit: "ms",
                    target: None,
                });
            }
        }
        let merge_s = merge_seconds(&dir.join("merge"))?;
        figures.push(Figure {
            name: "merge of 10,000 rows (CSV, statistics, Markdown, plots, JUnit), s",
            value: merge_s,
            unit: "s",
            target: None,
        });
        Ok(figures)
    })();
    let _ = std::fs::remove_dir_all(&dir);
    result
}

fn tempfile_dir(tag: &str) -> Result<std::path::PathBuf, BenchError> {
    let d = std::env::temp_dir().join(format!("vinebench-bench-{}-{tag}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).map_err(setup)?;
    Ok(d)
}

/// Writes a sweep folder of [`MERGE_ROWS`] deterministic rows and times their merge.
fn merge_seconds(dir: &Path) -> Result<f64, BenchError> {
    let (cells, seeds) = (100usize, MERGE_ROWS / 100);
    let sweep = serde_json::json!({
        "digest": "bench",
        "sweep": {
            "name": "merge-bench",
            "description": "",
            "scenarios": [{"path": "x.toml", "name": "x"}],
            "seeds": (1..=seeds).collect::<Vec<_>>(),
            "axes": [{"key": "world.occluders[0].s_m",
                      "values": (0..cells).map(|c| c as f64 * 0.1).collect::<Vec<_>>()}],
            "cells": (0..cells).map(|c| serde_json::json!({"index": c, "values": [c as f64 * 0.1]})).collect::<Vec<_>>(),
            "metrics": [],
            "per_cell": ["p95(ate_rmse_m.eif) <= 10"],
            "overall": ["mean(ate_rmse_m.eif) < mean(ate_rmse_m.gnss)", "pass_rate >= 0"],
        }
    });
    std::fs::create_dir_all(dir.join(run::ROWS_DIR)).map_err(setup)?;
    std::fs::write(dir.join(run::SWEEP_JSON), sweep.to_string()).map_err(setup)?;
    let mut text = String::new();
    let metrics = ["ate_rmse_m", "ate_max_m", "d_m", "sigma_u_m"];
    let sources = ["eif", "gnss", "tracking_camera"];
    for job in 0..MERGE_ROWS {
        let (cell, seed) = (job / seeds, job % seeds + 1);
        // A cheap deterministic spread.
        let v = |k: usize| ((job * 7919 + k * 104_729) % 1000) as f64 / 1000.0;
        let mut m = BTreeMap::new();
        for (i, metric) in metrics.iter().enumerate() {
            for (j, s) in sources.iter().enumerate() {
                m.insert(format!("{metric}.{s}"), v(i * 3 + j) * (1 + j) as f64);
            }
        }
        let row = ResultRow {
            job,
            key: format!("x/c{cell}/s{seed}"),
            scenario: "x".into(),
            cell,
            axes: BTreeMap::from([(
                "world.occluders[0].s_m".to_string(),
                toml::Value::Float(cell as f64 * 0.1),
            )]),
            seed: seed as u64,
            status: JobStatus::Pass,
            error: None,
            metrics: m,
            failed: Vec::new(),
            scenario_digest: String::new(),
            sweep_digest: "bench".into(),
            version: env!("CARGO_PKG_VERSION").into(),
            wall_s: 1.0,
            run_dir: None,
        };
        text += &serde_json::to_string(&row).map_err(setup)?;
        text.push('\n');
    }
    std::fs::write(dir.join(run::ROWS_DIR).join("shard-1-of-1.jsonl"), text).map_err(setup)?;
    let t0 = Instant::now();
    let s = merge::merge(
        &[dir.to_path_buf()],
        &MergeOptions {
            out_dir: dir.join("merged"),
            partial: false,
            junit: Some(dir.join("merged/junit.xml")),
        },
    )
    .map_err(setup)?;
    let secs = t0.elapsed().as_secs_f64();
    if s.rows != MERGE_ROWS {
        return Err(setup(format!("merged {} rows of {MERGE_ROWS}", s.rows)));
    }
    Ok(secs)
}
