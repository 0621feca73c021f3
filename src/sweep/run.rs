//! Running a sweep's jobs, or one shard of them: each job an ordinary run, its result a
//! JSON line appended (and synced) as it finishes, so a killed shard loses at most the
//! jobs in flight and a rerun skips what is done.
//!
//! The output folder holds `sweep.json` (the expanded sweep, identical from every shard),
//! `rows/shard-<i>-of-<n>.jsonl` (one [`ResultRow`] per line) and `jobs/<key>/` (the run
//! folders kept by [`Keep`]). Jobs are dealt to shards round-robin over the stable job
//! order: job `j` belongs to shard `j mod n`.

use crate::runner::{self, RunError, RunOptions};
use crate::sweep::spec::{Job, Sweep, SweepError, cell_values, scenario_digest};
use indicatif::{ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::Instant;
use thiserror::Error;

/// The sweep description beside the rows.
pub const SWEEP_JSON: &str = "sweep.json";
/// The folder of the rows files.
pub const ROWS_DIR: &str = "rows";
/// The folder of the kept run folders.
pub const JOBS_DIR: &str = "jobs";
/// Largest rows file read back, bytes (about a million rows).
pub const MAX_ROWS_FILE_BYTES: u64 = 1 << 30;
/// Most parallel jobs on one machine.
pub const MAX_PARALLEL_JOBS: usize = 256;

/// A sweep run that could not be carried out.
#[derive(Debug, Error)]
pub enum SweepRunError {
    /// The sweep file or a cell's scenario is unusable.
    #[error(transparent)]
    Sweep(#[from] SweepError),
    /// A cell's scenario cannot be set up (world, robot, route, sensors).
    #[error("{key}: {error}")]
    Setup {
        /// The first job of the cell.
        key: String,
        /// Why.
        error: Box<RunError>,
    },
    /// An option is unusable.
    #[error("{0}")]
    Options(String),
    /// The output folder belongs to another sweep.
    #[error(
        "{dir}: holds the results of another sweep (digest {theirs}, this one {ours}); \
         use another --out folder"
    )]
    OtherSweep {
        /// The folder.
        dir: String,
        /// Its sweep digest.
        theirs: String,
        /// Ours.
        ours: String,
    },
    /// Reading or writing the output folder failed.
    #[error("{path}: {message}")]
    Io {
        /// The file or folder.
        path: String,
        /// What went wrong.
        message: String,
    },
    /// Ctrl-C: the rows of finished jobs are kept; rerun to resume.
    #[error("interrupted after {done} job(s); rerun the same command to resume")]
    Interrupted {
        /// Jobs finished in this invocation.
        done: usize,
    },
}

/// Maps an I/O error on `path` to [`SweepRunError::Io`] naming the file.
pub(crate) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> SweepRunError + '_ {
    move |e| SweepRunError::Io {
        path: path.display().to_string(),
        message: e.to_string(),
    }
}

/// Which run folders to keep.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Keep {
    /// None (only the rows).
    None,
    /// Those of jobs that failed or could not run: what a user opens next.
    #[default]
    Failed,
    /// All.
    All,
}

/// One shard of `count`, `index` 0-based, and where the choice came from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Shard {
    /// 0-based shard number.
    pub index: usize,
    /// Number of shards.
    pub count: usize,
    /// What chose it (`--shard 2/3`, `SLURM_ARRAY_TASK_ID=...`, ...).
    pub from: String,
}

impl Shard {
    /// The whole sweep.
    pub fn all() -> Shard {
        Shard {
            index: 0,
            count: 1,
            from: "no shard given: every job".into(),
        }
    }

    /// The shard from `--shard I/N` (1-based), else from the engine's environment:
    /// Slurm job arrays (`SLURM_ARRAY_TASK_ID`, `SLURM_ARRAY_TASK_MIN`,
    /// `SLURM_ARRAY_TASK_STEP`, `SLURM_ARRAY_TASK_COUNT`: the task's position in the
    /// array, so `--array=0-3`, `1-4` and `0-6:2` all work), Kubernetes Indexed Jobs
    /// (`JOB_COMPLETION_INDEX`, 0-based, with the count in `VINEBENCH_SHARD_COUNT`, which
    /// the manifest sets to `completions`); else the whole sweep.
    pub fn from_args(
        arg: Option<&str>,
        env: impl Fn(&str) -> Option<String>,
    ) -> Result<Shard, String> {
        if let Some(s) = arg {
            let bad = || format!("--shard {s}: expected I/N with 1 <= I <= N, such as 2/4");
            let (i, n) = s.split_once('/').ok_or_else(bad)?;
            let (i, n): (usize, usize) = (
                i.trim().parse().map_err(|_| bad())?,
                n.trim().parse().map_err(|_| bad())?,
            );
            if n == 0 || i == 0 || i > n {
                return Err(bad());
            }
            return Ok(Shard {
                index: i - 1,
                count: n,
                from: format!("--shard {s}"),
            });
        }
        let num = |name: &str| -> Result<Option<usize>, String> {
            env(name)
                .map(|v| {
                    v.trim()
                        .parse::<usize>()
                        .map_err(|_| format!("{name}={v}: expected a whole number"))
                })
                .transpose()
        };
        if let Some(id) = num("SLURM_ARRAY_TASK_ID")? {
            let count = num("SLURM_ARRAY_TASK_COUNT")?.ok_or_else(|| {
                "SLURM_ARRAY_TASK_ID is set but SLURM_ARRAY_TASK_COUNT is not".to_string()
            })?;
            let min = num("SLURM_ARRAY_TASK_MIN")?.unwrap_or(0);
            let step = num("SLURM_ARRAY_TASK_STEP")?.unwrap_or(1).max(1);
            if id < min || (id - min) % step != 0 || (id - min) / step >= count || count == 0 {
                return Err(format!(
                    "SLURM_ARRAY_TASK_ID={id} is not one of {count} tasks from {min} in steps \
                     of {step}; vinebench needs a regular array such as --array=0-{}",
                    count.saturating_sub(1)
                ));
            }
            return Ok(Shard {
                index: (id - min) / step,
                count,
                from: format!("Slurm array task {id} (min {min}, step {step}, count {count})"),
            });
        }
        if let Some(index) = num("JOB_COMPLETION_INDEX")? {
            let count = num("VINEBENCH_SHARD_COUNT")?.ok_or_else(|| {
                "JOB_COMPLETION_INDEX is set (a Kubernetes Indexed Job) but \
                 VINEBENCH_SHARD_COUNT is not: set it to the Job's `completions`"
                    .to_string()
            })?;
            if index >= count {
                return Err(format!(
                    "JOB_COMPLETION_INDEX={index} is not below VINEBENCH_SHARD_COUNT={count}"
                ));
            }
            return Ok(Shard {
                index,
                count,
                from: format!("Kubernetes completion index {index} of {count}"),
            });
        }
        Ok(Shard::all())
    }

    /// Whether job `j` is this shard's.
    pub fn owns(&self, j: &Job) -> bool {
        j.index % self.count == self.index
    }

    /// The rows file name: `shard-<i>-of-<n>.jsonl`, 1-based.
    pub fn rows_file(&self) -> String {
        format!("shard-{}-of-{}.jsonl", self.index + 1, self.count)
    }
}

/// How a job ended.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum JobStatus {
    /// Ran; every expectation of its scenario held.
    Pass,
    /// Ran; an expectation failed.
    Fail,
    /// Could not run to the end (the message says why).
    Error,
}

/// One job's result: a line of a rows file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ResultRow {
    /// Job number in the sweep's stable order.
    pub job: usize,
    /// `<scenario>/c<cell>/s<seed>`.
    pub key: String,
    /// Scenario name.
    pub scenario: String,
    /// Cell number.
    pub cell: usize,
    /// The cell's value per axis key.
    pub axes: BTreeMap<String, toml::Value>,
    /// The scenario's seed.
    pub seed: u64,
    /// How it ended.
    pub status: JobStatus,
    /// Why it could not run, for [`JobStatus::Error`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// Every scalar metric with a value, `metric.source` → value.
    pub metrics: BTreeMap<String, f64>,
    /// The scenario's expectations that failed, as printed.
    #[serde(default)]
    pub failed: Vec<String>,
    /// SHA-256 of the job's resolved scenario.
    pub scenario_digest: String,
    /// The sweep's digest.
    pub sweep_digest: String,
    /// vinebench version that ran it.
    pub version: String,
    /// Wall-clock seconds (not part of the results' comparison).
    pub wall_s: f64,
    /// The kept run folder, relative to the sweep folder.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub run_dir: Option<String>,
}

/// Options of [`run_shard`].
#[derive(Clone, Debug)]
pub struct SweepOptions {
    /// The sweep folder.
    pub out_dir: PathBuf,
    /// Jobs at once on this machine.
    pub jobs: usize,
    /// This invocation's share.
    pub shard: Shard,
    /// Run folders to keep.
    pub keep: Keep,
    /// Progress bar on stderr (when it is a terminal).
    pub progress: bool,
    /// Set by Ctrl-C: running jobs stop, no new job starts.
    pub stop: Option<Arc<AtomicBool>>,
}

/// What a shard did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ShardOutcome {
    /// Jobs of the shard.
    pub jobs: usize,
    /// Jobs skipped because their rows exist.
    pub skipped: usize,
    /// Jobs run now, by status.
    pub passed: usize,
    /// Jobs whose expectations failed.
    pub failed: usize,
    /// Jobs that could not run.
    pub errors: usize,
}

/// The sweep folder's `sweep.json`: a folder holds one sweep (its digest: scenarios,
/// axes, cells, seeds); what does not change the jobs (expectations, metrics to
/// tabulate, the description) is updated from the latest sweep file.
fn claim_folder(sweep: &Sweep, dir: &Path) -> Result<(), SweepRunError> {
    std::fs::create_dir_all(dir.join(ROWS_DIR)).map_err(io_err(dir))?;
    let path = dir.join(SWEEP_JSON);
    let ours = sweep.digest();
    if path.exists() {
        let theirs = read_sweep_digest(&path)?;
        if theirs != ours {
            return Err(SweepRunError::OtherSweep {
                dir: dir.display().to_string(),
                theirs,
                ours,
            });
        }
    }
    let json = serde_json::json!({ "digest": ours, "sweep": sweep });
    let text = serde_json::to_string_pretty(&json).map_err(|e| SweepRunError::Io {
        path: path.display().to_string(),
        message: e.to_string(),
    })? + "\n";
    if std::fs::read_to_string(&path).is_ok_and(|t| t == text) {
        return Ok(());
    }
    write_file(&path, text.as_bytes())
}

/// The digest recorded in a `sweep.json`.
pub fn read_sweep_digest(path: &Path) -> Result<String, SweepRunError> {
    Ok(read_sweep_json(path)?.0)
}

/// A `sweep.json` (size bounded) parsed, with the digest it records.
pub fn read_sweep_json(path: &Path) -> Result<(String, serde_json::Value), SweepRunError> {
    let bad = |message: String| SweepRunError::Io {
        path: path.display().to_string(),
        message,
    };
    let meta = std::fs::metadata(path).map_err(io_err(path))?;
    if meta.len() > MAX_ROWS_FILE_BYTES {
        return Err(bad("too large for a sweep description".into()));
    }
    let text = std::fs::read_to_string(path).map_err(io_err(path))?;
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| bad(format!("not a sweep description: {e}")))?;
    let digest = v
        .get("digest")
        .and_then(|d| d.as_str())
        .map(str::to_string)
        .ok_or_else(|| bad("no `digest` in the sweep description".into()))?;
    Ok((digest, v))
}

/// Writes a file of the sweep folder whole or not at all ([`crate::fsio::write_atomic`]).
pub(crate) fn write_file(path: &Path, bytes: &[u8]) -> Result<(), SweepRunError> {
    crate::fsio::write_atomic(path, bytes).map_err(io_err(path))
}

/// Reads every rows file of a sweep folder. A line that does not parse (a shard killed
/// while writing it) is reported in `damaged` and otherwise ignored.
pub fn read_rows(dir: &Path) -> Result<(Vec<ResultRow>, Vec<String>), SweepRunError> {
    let rows_dir = dir.join(ROWS_DIR);
    let mut files: Vec<PathBuf> = match std::fs::read_dir(&rows_dir) {
        Ok(entries) => entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "jsonl"))
            .collect(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
        Err(e) => return Err(io_err(&rows_dir)(e)),
    };
    files.sort();
    let mut rows = Vec::new();
    let mut damaged = Vec::new();
    for f in files {
        let len = std::fs::metadata(&f).map_err(io_err(&f))?.len();
        if len > MAX_ROWS_FILE_BYTES {
            return Err(SweepRunError::Io {
                path: f.display().to_string(),
                message: format!("{len} bytes; a rows file is at most {MAX_ROWS_FILE_BYTES}"),
            });
        }
        let text = std::fs::read(&f).map_err(io_err(&f))?;
        for (n, line) in text.split(|b| *b == b'\n').enumerate() {
            if line.iter().all(u8::is_ascii_whitespace) {
                continue;
            }
            match serde_json::from_slice::<ResultRow>(line) {
                Ok(r) => rows.push(r),
                Err(e) => damaged.push(format!("{}:{}: {e}", f.display(), n + 1)),
            }
        }
    }
    Ok((rows, damaged))
}

/// Opens a shard's rows file for appending, cutting a last line that a killed writer
/// left without its newline.
fn open_rows(path: &Path) -> Result<std::fs::File, SweepRunError> {
    if let Ok(bytes) = std::fs::read(path)
        && !bytes.is_empty()
        && bytes.last() != Some(&b'\n')
    {
        let keep = bytes.iter().rposition(|b| *b == b'\n').map_or(0, |i| i + 1);
        let f = std::fs::OpenOptions::new()
            .write(true)
            .open(path)
            .map_err(io_err(path))?;
        f.set_len(keep as u64).map_err(io_err(path))?;
    }
    std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .map_err(io_err(path))
}

/// Runs this shard's jobs that have no row yet, `opts.jobs` at a time. Every cell of the
/// shard is set up once (world, robot, route, sensors) before any job runs, so bad
/// values fail at once.
pub fn run_shard(sweep: &Sweep, opts: &SweepOptions) -> Result<ShardOutcome, SweepRunError> {
    if !(1..=MAX_PARALLEL_JOBS).contains(&opts.jobs) {
        return Err(SweepRunError::Options(format!(
            "--jobs {}: expected 1 to {MAX_PARALLEL_JOBS}",
            opts.jobs
        )));
    }
    let mine: Vec<Job> = sweep
        .jobs()
        .into_iter()
        .filter(|j| opts.shard.owns(j))
        .collect();
    // Validate each (scenario, cell) of the shard once.
    let mut seen = BTreeSet::new();
    for j in &mine {
        if seen.insert((j.scenario, j.cell)) {
            let sc = sweep.job_scenario(j)?;
            runner::validate(&sc).map_err(|e| SweepRunError::Setup {
                key: sweep.job_key(j),
                error: Box::new(e),
            })?;
        }
    }
    claim_folder(sweep, &opts.out_dir)?;
    let sweep_digest = sweep.digest();
    let version = env!("CARGO_PKG_VERSION");
    let (existing, _) = read_rows(&opts.out_dir)?;
    let done: BTreeSet<(String, String)> = existing
        .iter()
        .filter(|r| r.version == version && r.sweep_digest == sweep_digest)
        .map(|r| (r.key.clone(), r.scenario_digest.clone()))
        .collect();
    let mut pending = Vec::new();
    let mut outcome = ShardOutcome {
        jobs: mine.len(),
        ..ShardOutcome::default()
    };
    for j in mine {
        let digest = scenario_digest(&sweep.job_scenario(&j)?);
        if done.contains(&(sweep.job_key(&j), digest.clone())) {
            outcome.skipped += 1;
        } else {
            pending.push((j, digest));
        }
    }
    let rows_path = opts.out_dir.join(ROWS_DIR).join(opts.shard.rows_file());
    let mut rows_file = open_rows(&rows_path)?;
    let bar = (opts.progress && std::io::stderr().is_terminal()).then(|| {
        let pb = ProgressBar::new(pending.len() as u64);
        pb.set_style(
            ProgressStyle::with_template(
                "{prefix} [{bar:40.green/dim}] {pos}/{len} jobs ({elapsed}, eta {eta}) {msg}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
        );
        pb.set_prefix(sweep.name.clone());
        pb
    });
    let next = AtomicUsize::new(0);
    let stop = opts.stop.clone().unwrap_or_default();
    let (tx, rx) = std::sync::mpsc::channel::<ResultRow>();
    let mut write_error = None;
    std::thread::scope(|scope| {
        for _ in 0..opts.jobs.min(pending.len()) {
            let tx = tx.clone();
            let (pending, next, stop) = (&pending, &next, &stop);
            let sweep_digest = sweep_digest.clone();
            scope.spawn(move || {
                loop {
                    if stop.load(Ordering::SeqCst) {
                        break;
                    }
                    let i = next.fetch_add(1, Ordering::SeqCst);
                    let Some((job, digest)) = pending.get(i) else {
                        break;
                    };
                    let row = run_job(sweep, job, digest, &sweep_digest, opts, stop);
                    match row {
                        Some(r) => {
                            if tx.send(r).is_err() {
                                break;
                            }
                        }
                        // Interrupted: no row, the job reruns on resume.
                        None => break,
                    }
                }
            });
        }
        drop(tx);
        for row in rx {
            match row.status {
                JobStatus::Pass => outcome.passed += 1,
                JobStatus::Fail => outcome.failed += 1,
                JobStatus::Error => outcome.errors += 1,
            }
            if row.status != JobStatus::Pass {
                let line = format!(
                    "{} {}: {}",
                    if row.status == JobStatus::Fail {
                        "FAIL "
                    } else {
                        "ERROR"
                    },
                    row.key,
                    row.error.clone().unwrap_or_else(|| row.failed.join("; "))
                );
                match &bar {
                    Some(pb) => pb.println(line),
                    None => eprintln!("{line}"),
                }
            }
            if write_error.is_none()
                && let Err(e) = append_row(&mut rows_file, &row)
            {
                // Stop the workers: rows that cannot be written are lost work.
                stop.store(true, Ordering::SeqCst);
                write_error = Some(io_err(&rows_path)(e));
            }
            if let Some(pb) = &bar {
                pb.inc(1);
            }
        }
    });
    if let Some(pb) = &bar {
        pb.finish_and_clear();
    }
    if let Some(e) = write_error {
        return Err(e);
    }
    let ran = outcome.passed + outcome.failed + outcome.errors;
    if ran < pending.len() {
        return Err(SweepRunError::Interrupted { done: ran });
    }
    Ok(outcome)
}

fn append_row(f: &mut std::fs::File, row: &ResultRow) -> std::io::Result<()> {
    let mut line = serde_json::to_vec(row).map_err(std::io::Error::other)?;
    line.push(b'\n');
    f.write_all(&line)?;
    f.sync_data()
}

/// Removes a job's run folder and the folders above it that it leaves empty (up to
/// `jobs/`, which stays).
fn remove_job_dir(sweep_dir: &Path, dir: &Path) {
    let _ = std::fs::remove_dir_all(dir);
    let stop = sweep_dir.join(JOBS_DIR);
    let mut d = dir.parent();
    while let Some(p) = d {
        // remove_dir fails on a folder that is not empty: another job's is still there.
        if p == stop || !p.starts_with(&stop) || std::fs::remove_dir(p).is_err() {
            break;
        }
        d = p.parent();
    }
}

/// Runs one job; `None` when it was interrupted.
fn run_job(
    sweep: &Sweep,
    job: &Job,
    digest: &str,
    sweep_digest: &str,
    opts: &SweepOptions,
    stop: &Arc<AtomicBool>,
) -> Option<ResultRow> {
    let key = sweep.job_key(job);
    let rel = PathBuf::from(JOBS_DIR).join(&key);
    let dir = opts.out_dir.join(&rel);
    // A folder left by an interrupted attempt is this job's to replace.
    let _ = std::fs::remove_dir_all(&dir);
    let t0 = Instant::now();
    let result = sweep
        .job_scenario(job)
        .map_err(|e| e.to_string())
        .and_then(|sc| {
            let o = RunOptions {
                out_dir: Some(dir.clone()),
                progress: false,
                stop: Some(stop.clone()),
                ..RunOptions::default()
            };
            match runner::run(&sc, &o) {
                Ok(out) => Ok(Some(out)),
                Err(RunError::Interrupted { .. }) => Ok(None),
                Err(e) => Err(e.to_string()),
            }
        });
    let wall_s = t0.elapsed().as_secs_f64();
    let mut row = ResultRow {
        job: job.index,
        key,
        scenario: sweep.scenarios[job.scenario].name.clone(),
        cell: job.cell,
        axes: cell_values(sweep, job.cell),
        seed: job.seed,
        status: JobStatus::Error,
        error: None,
        metrics: BTreeMap::new(),
        failed: Vec::new(),
        scenario_digest: digest.to_string(),
        sweep_digest: sweep_digest.to_string(),
        version: env!("CARGO_PKG_VERSION").to_string(),
        wall_s,
        run_dir: None,
    };
    match result {
        Ok(None) => {
            remove_job_dir(&opts.out_dir, &dir);
            return None;
        }
        Ok(Some(out)) => {
            row.status = if out.passed() {
                JobStatus::Pass
            } else {
                JobStatus::Fail
            };
            row.metrics = out.report.metrics();
            row.failed = out
                .report
                .expectations
                .iter()
                .filter(|x| !x.holds)
                .map(|x| x.to_string())
                .collect();
        }
        Err(e) => row.error = Some(e),
    }
    let keep = match opts.keep {
        Keep::All => true,
        Keep::Failed => row.status != JobStatus::Pass,
        Keep::None => false,
    };
    if keep && dir.exists() {
        row.run_dir = Some(rel.display().to_string());
    } else {
        remove_job_dir(&opts.out_dir, &dir);
    }
    Some(row)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env(pairs: &[(&str, &str)]) -> impl Fn(&str) -> Option<String> {
        let m: BTreeMap<String, String> = pairs
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        move |k| m.get(k).cloned()
    }

    #[test]
    fn shards_come_from_the_flag_or_the_engine() {
        let s = Shard::from_args(Some("2/3"), env(&[])).unwrap();
        assert_eq!((s.index, s.count), (1, 3));
        // The flag wins over the environment.
        let s = Shard::from_args(Some("1/2"), env(&[("SLURM_ARRAY_TASK_ID", "5")])).unwrap();
        assert_eq!((s.index, s.count), (0, 2));
        for bad in ["0/3", "4/3", "1/0", "a/b", "3"] {
            assert!(Shard::from_args(Some(bad), env(&[])).is_err(), "{bad}");
        }
        // Slurm arrays: --array=0-2, 1-3, 10-14:2.
        let slurm = |id, min, step, count| {
            Shard::from_args(
                None,
                env(&[
                    ("SLURM_ARRAY_TASK_ID", id),
                    ("SLURM_ARRAY_TASK_MIN", min),
                    ("SLURM_ARRAY_TASK_STEP", step),
                    ("SLURM_ARRAY_TASK_COUNT", count),
                ]),
            )
        };
        let s = slurm("2", "0", "1", "3").unwrap();
        assert_eq!((s.index, s.count), (2, 3));
        let s = slurm("1", "1", "1", "3").unwrap();
        assert_eq!((s.index, s.count), (0, 3));
        let s = slurm("14", "10", "2", "3").unwrap();
        assert_eq!((s.index, s.count), (2, 3));
        assert!(slurm("11", "10", "2", "3").is_err());
        assert!(slurm("16", "10", "2", "3").is_err());
        assert!(Shard::from_args(None, env(&[("SLURM_ARRAY_TASK_ID", "1")])).is_err());
        // Kubernetes Indexed Jobs.
        let k8s = |i, n: Option<&str>| {
            let mut p = vec![("JOB_COMPLETION_INDEX", i)];
            p.extend(n.map(|n| ("VINEBENCH_SHARD_COUNT", n)));
            Shard::from_args(None, env(&p))
        };
        let s = k8s("3", Some("4")).unwrap();
        assert_eq!((s.index, s.count), (3, 4));
        assert!(k8s("4", Some("4")).is_err());
        assert!(
            k8s("0", None)
                .unwrap_err()
                .contains("VINEBENCH_SHARD_COUNT")
        );
        assert_eq!(Shard::from_args(None, env(&[])).unwrap().count, 1);
    }

    #[test]
    fn shards_partition_the_jobs() {
        for n in 1..6 {
            let mut owners = vec![0; 23];
            for i in 0..n {
                let s = Shard {
                    index: i,
                    count: n,
                    from: String::new(),
                };
                for (j, o) in owners.iter_mut().enumerate() {
                    let job = Job {
                        index: j,
                        scenario: 0,
                        cell: 0,
                        seed: 0,
                    };
                    *o += usize::from(s.owns(&job));
                }
            }
            assert!(owners.iter().all(|o| *o == 1), "{n}: {owners:?}");
        }
    }

    #[test]
    fn a_torn_last_line_is_cut_before_appending() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("rows.jsonl");
        std::fs::write(&p, b"{\"a\":1}\n{\"b\":").unwrap();
        let mut f = open_rows(&p).unwrap();
        f.write_all(b"{\"c\":3}\n").unwrap();
        drop(f);
        assert_eq!(std::fs::read(&p).unwrap(), b"{\"a\":1}\n{\"c\":3}\n");
    }
}
