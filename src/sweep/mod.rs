//! Experiments: a scenario over seeds and parameters, run on one machine or sharded over
//! a cluster's job array, merged into statistics, plots, JUnit, and compared with a
//! baseline (`vinebench sweep`).
//!
//! - [`spec`]: sweep files, validated and expanded into jobs in a stable order.
//! - [`aggregate`]: the expectation language over statistics (`p95(...) <= 0.4`).
//! - [`run`]: a shard's jobs, each an ordinary run, one JSON row per job, resumable.
//! - [`summary`]: what a merged sweep is (the sweep's description, statistics per cell).
//! - [`merge`]: rows of all shards → `results.csv`, `summary.json`, `sweep.md`, JUnit.
//! - [`plots`]: metric against axis with confidence bands; heat maps for two axes.
//! - [`compare`]: the regression gate: two sweeps, paired by seed, rank tests.
//! - [`junit`]: JUnit XML (also for `vinebench check`).
//! - [`stats`]: summaries, bootstrap and Wilson intervals, rank tests (pure functions).

pub mod aggregate;
pub mod compare;
pub mod junit;
pub mod merge;
pub mod plots;
pub mod run;
pub mod spec;
pub mod stats;
pub mod summary;
