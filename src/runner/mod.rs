//! The scenario runner: world → motion → sensors → estimators → scoring → run folder.
//!
//! [`simulate`] is the pure part (no files): it builds the world, robot, route, motion
//! model, sensors and estimators from a scenario and steps them in time order. Sensor
//! messages reach the estimators in *arrival* order (stamp + latency), as on a robot.
//! [`run`] adds the outputs: the run folder with TUM files, report, plots and
//! `recording.mcap` (every message, ground truth and estimate; see [`crate::recording`]).

mod folder;
pub mod gnss_log;
pub mod images;
pub mod mapping;
mod outcome;
pub mod report;
mod simulate;
pub mod steering;

pub use folder::{LOCK_FILE, RunFolder, is_run_output};
pub(crate) use outcome::io_err;
pub use outcome::{
    ComparisonReport, Estimate, MotionComparison, RobotOutcome, RobotReport, RunError, Simulation,
    SteeringStop, TimeLimit,
};
pub use report::{Scores, evaluate, score};
pub(crate) use simulate::EstimateSpools;
pub use simulate::{
    Setup, load_world_mesh, setup, simulate, simulate_setup, slam_from_scenario, validate,
};

use crate::recording::{Recorder, SinkOptions};
use crate::scenario::LoadedScenario;
use crate::scoring::{self, Poses};
use indicatif::{ProgressBar, ProgressStyle};
use report::Report;
use std::io::IsTerminal;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Instant;
use vinebench_msgs::Nanos;

/// The recording in a run folder.
pub const RECORDING_FILE: &str = "recording.mcap";

/// Options of [`run`].
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// Output folder; `None` = `<runs_root>/<name>-<UTC stamp>/`.
    pub out_dir: Option<PathBuf>,
    /// Parent of default output folders.
    pub runs_root: PathBuf,
    /// Show a progress bar on stderr (only when it is a terminal).
    pub progress: bool,
    /// Set (by a Ctrl-C handler) to stop the run cleanly: the simulation ends at its next
    /// step and the recording is finalized.
    pub stop: Option<Arc<AtomicBool>>,
    /// An `out_dir` that already holds files is cleared of a run's outputs (else refused);
    /// see [`RunFolder`].
    pub replace: bool,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            out_dir: None,
            runs_root: PathBuf::from("runs"),
            progress: true,
            stop: None,
            replace: false,
        }
    }
}

/// The outcome of [`run`].
#[derive(Debug)]
pub struct RunOutcome {
    /// The run folder.
    pub dir: PathBuf,
    /// The report (also written as `report.json` and `report.md`).
    pub report: Report,
    /// Wall-clock seconds the simulation took.
    pub wall_s: f64,
}

impl RunOutcome {
    /// True when every expectation holds.
    pub fn passed(&self) -> bool {
        self.report.passed
    }
}

/// The progress bar of a scenario's simulation (seconds simulated), on a terminal and when
/// `enabled`.
pub fn progress_bar(sc: &LoadedScenario, enabled: bool) -> Option<ProgressBar> {
    (enabled && std::io::stderr().is_terminal()).then(|| {
        let pb = ProgressBar::new(1);
        pb.set_style(
            ProgressStyle::with_template(
                "{prefix} [{bar:40.green/dim}] {pos}/{len} s simulated ({per_sec}, eta {eta})",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
        );
        pb.set_prefix(sc.scenario.name.clone());
        pb
    })
}

/// Runs a scenario end to end and writes its run folder.
pub fn run(sc: &LoadedScenario, opts: &RunOptions) -> Result<RunOutcome, RunError> {
    // Every parameter is checked before anything is written.
    let mut built = setup(sc)?;
    // The folder is this run's until it returns (see `RunFolder`).
    let folder = RunFolder::claim(
        opts.out_dir.as_deref(),
        &opts.runs_root,
        &sc.scenario.name,
        &utc_stamp(),
        opts.replace,
    )?;
    let dir = folder.path().to_path_buf();
    if sc.scenario.render.debug_png_every > 0 && built.renderer.is_some() {
        built.png_dir = Some(dir.join("images"));
    }
    let resolved = dir.join("scenario.resolved.toml");
    write_file(&resolved, sc.resolved_toml().as_bytes())?;
    built.recorder = Some(Recorder::create(
        &dir.join(RECORDING_FILE),
        &SinkOptions::from_params(&sc.scenario.recording),
    )?);
    built.stop = opts.stop.clone();
    built.spool_dir = Some(dir.clone());

    let bar = progress_bar(sc, opts.progress);
    let t0 = Instant::now();
    let sim = simulate_setup(sc, built, bar.as_ref());
    let wall_s = t0.elapsed().as_secs_f64();
    if let Some(pb) = &bar {
        pb.finish_and_clear();
    }
    let sim = sim?;

    let gt_path = dir.join("ground_truth.tum");
    scoring::tum::write_tum(&gt_path, &sim.truth).map_err(io_err(&gt_path))?;
    for e in &sim.estimates {
        let p = dir.join(format!("estimate_{}.tum", e.name));
        scoring::tum::write_tum(&p, &e.poses).map_err(io_err(&p))?;
    }
    for c in &sim.comparisons {
        let p = dir.join(format!("ground_truth_{}.tum", c.model.name()));
        scoring::tum::write_tum(&p, &c.truth).map_err(io_err(&p))?;
    }
    let scoring_started = Instant::now();
    let scores = score(sc, &sim)?;
    let scoring_s = scoring_started.elapsed().as_secs_f64();
    if !sim.slam.is_empty() {
        let t0 = sim.truth.first().map_or(Nanos(0), |s| s.0);
        let named: Vec<(&str, &scoring::loops::LoopScore)> =
            scores.loops.iter().map(|(n, l)| (n.as_str(), l)).collect();
        let p = dir.join("loops.csv");
        write_file(&p, scoring::loops::loops_csv(&named, t0).as_bytes())?;
    }
    let expectations = evaluate(sc, &scores);
    let report = Report::new(sc, &sim, scores, expectations);
    report::write(&dir, &sim, &report)?;
    let export_started = Instant::now();
    if let Some(m) = &sim.mapping {
        crate::runner::mapping::export(&dir, m)?;
    }
    let map_export_s = export_started.elapsed().as_secs_f64();
    let mut timing = serde_json::json!({
        "wall_s": wall_s,
        "simulated_s": sim.duration_s,
        "real_time_factor": if wall_s > 0.0 { sim.duration_s / wall_s } else { f64::INFINITY },
        "threads": rayon::current_num_threads(),
    });
    // After wall_s (which ends with the simulation and the maps' finishing): scoring
    // trajectories and maps (map scoring dominates where maps are built).
    timing["scoring_s"] = serde_json::json!(scoring_s);
    if let Some(m) = &sim.mapping {
        // Part of wall_s: integrating frames during the run and finishing the maps; of
        // it, the integration during the run and each map's finishing steps.
        timing["mapping_s"] = serde_json::json!(m.wall_s);
        timing["mapping_during_run_s"] = serde_json::json!(m.during_run_s);
        // After scoring: writing the maps, meshes and model exports (`map/`).
        timing["map_export_s"] = serde_json::json!(map_export_s);
        for sm in &m.maps {
            timing[format!("mapping_finish_{}", sm.source)] = serde_json::json!(sm.timing);
        }
    }
    for o in &sim.slam {
        // Part of wall_s: feature extraction, tracking and local BA of each SLAM.
        timing[format!("{}_s", o.source)] = serde_json::json!(o.wall_s);
        timing[format!("{}_frames_per_s", o.source)] =
            serde_json::json!(o.stats.frames as f64 / o.wall_s.max(1e-9));
        if !o.loops.is_empty() {
            // Part of <source>_s: pose graph and global BA of each loop.
            timing[format!("{}_loop_closing_s", o.source)] =
                serde_json::json!(o.loops.iter().map(|l| l.wall_s).collect::<Vec<_>>());
        }
    }
    let tp = dir.join("timing.json");
    write_file(&tp, format!("{timing:#}\n").as_bytes())?;
    drop(folder);
    Ok(RunOutcome {
        dir,
        report,
        wall_s,
    })
}

/// Writes a run-folder file whole or not at all ([`crate::fsio::write_atomic`]).
pub(crate) fn write_file(path: &std::path::Path, bytes: &[u8]) -> Result<(), RunError> {
    crate::fsio::write_atomic(path, bytes).map_err(io_err(path))
}

/// `YYYYMMDD-HHMMSS` of the current UTC time (names default run folders).
pub(crate) fn utc_stamp() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs() as i64)
        .unwrap_or(0);
    let days = secs.div_euclid(86_400);
    let rem = secs.rem_euclid(86_400);
    // Civil from days (Howard Hinnant).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}{m:02}{d:02}-{:02}{:02}{:02}",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}
