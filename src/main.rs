//! The `vinebench` command line.

use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use vinebench::runner::{self, RunOptions};
use vinebench::scenario::LoadedScenario;
use vinebench::scoring::{self, metrics::PairsFrom};
use vinebench::{out, outln};
use vinebench_msgs::Nanos;

/// Exit code: every expectation holds.
const EXIT_PASS: u8 = 0;
/// Exit code: at least one expectation fails.
const EXIT_FAIL: u8 = 1;
/// Exit code: bad input (scenario, URDF, TUM file, arguments) or an I/O failure.
const EXIT_ERROR: u8 = 2;
/// Exit code: interrupted by Ctrl-C or SIGTERM (the recording so far is finalized).
const EXIT_INTERRUPTED: u8 = 130;
/// The most worker threads `--threads` accepts.
const MAX_THREADS: i64 = 1024;

#[derive(Parser)]
#[command(
    name = "vinebench",
    version,
    about = "Simulation-in-the-loop test bench for vineyard robots",
    long_about = "Simulation-in-the-loop test bench for vineyard robots.\n\n\
        A scenario file (TOML) names a procedural vineyard, a robot, a route, sensor noise \
        and faults, the estimators to run and what must hold. `vinebench run` simulates it, \
        runs the estimators on the sensor messages alone, scores them against ground truth \
        and writes a run folder. The exit code tells CI whether the expectations held: \
        0 all hold, 1 one fails, 2 bad input, 130 interrupted (Ctrl-C or SIGTERM; the run folder keeps \
        a finalized recording.mcap).",
    after_help = "Examples:\n  \
        vinebench run scenarios/row-loop-rtk.toml              run one scenario, folder in runs/\n  \
        vinebench run scenarios/poor-gnss.toml --out /tmp/r    choose the run folder\n  \
        vinebench check scenarios/                             run every scenario, CI-style\n  \
        vinebench check scenarios/ --shard 2/4                 this job's quarter of them\n  \
        vinebench sweep scenarios/sweeps/rtk-outage-length.toml  a scenario over seeds and values\n  \
        vinebench sweep merge runs/sweeps/a runs/sweeps/b       shards' rows → statistics, plots\n  \
        vinebench validate my-scenario.toml                    check a file without running it\n  \
        vinebench defaults > my-scenario.toml                  every key with its default\n  \
        vinebench score ape tum runs/x/ground_truth.tum runs/x/estimate_eif.tum -a   (= evo_ape)\n  \
        vinebench replay runs/x/recording.mcap                 estimators on a recording\n  \
        vinebench vocabulary scenarios/vocabularies/training.toml --out my.vbvoc\n  \
        vinebench bench                                        speed figures for docs/PERFORMANCE.md"
)]
struct Cli {
    /// Worker threads for parallel stages, 1 to 1024 (results do not depend on it).
    #[arg(long, global = true, value_name = "N",
          value_parser = clap::value_parser!(u16).range(1..=MAX_THREADS))]
    threads: Option<u16>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run one scenario end to end and write its run folder.
    #[command(after_help = "Examples:\n  \
        vinebench run scenarios/row-loop-rtk-outage.toml\n  \
        vinebench run scenarios/defaults.toml --out /tmp/defaults-run --quiet\n  \
        vinebench run scenarios/defaults.toml --out /tmp/defaults-run --replace   # run again there\n\n\
        The run folder holds recording.mcap (every message, ground truth and estimate; ROS 2 \
        MCAP for Foxglove and `ros2 bag play`), ground_truth.tum, estimate_<source>.tum, \
        report.json, report.md (with trajectories.svg, errors.svg, altitude.svg), \
        scenario.resolved.toml and timing.json. Ctrl-C stops the run and finalizes the \
        recording; so does SIGTERM (exit code 130).")]
    Run {
        /// Scenario file.
        scenario: PathBuf,
        /// Run folder (default: runs/<name>-<UTC stamp>/, made unique). It must be new or
        /// empty, and is locked while the run writes it.
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
        /// Reuse a non-empty --out: clear a previous run's files there first (other files
        /// are kept).
        #[arg(long, requires = "out")]
        replace: bool,
        /// No progress bar and no summary.
        #[arg(long)]
        quiet: bool,
    },
    /// Run many scenarios (files or folders of *.toml) and summarise, for CI.
    #[command(after_help = "Examples:\n  \
        vinebench check scenarios/\n  \
        vinebench check scenarios/row-loop-rtk.toml scenarios/poor-gnss.toml --runs /tmp/ci-runs\n  \
        vinebench check scenarios/ --shard 1/3      # jobs 1/3, 2/3, 3/3 together cover all\n\n\
        Folders contribute their *.toml files except defaults.toml. Each run gets its own \
        folder under --runs (scenarios sharing a name too). Exit code: 2 if any \
        scenario has bad input, else 1 if any expectation fails, else 0; a shard with \
        nothing to do (more shards than scenarios) is 0.")]
    Check {
        /// Scenario files or folders.
        #[arg(required = true)]
        paths: Vec<PathBuf>,
        /// Parent folder of the run folders.
        #[arg(long, value_name = "DIR", default_value = "runs")]
        runs: PathBuf,
        /// Run only shard I of N (1-based), over the sorted list of scenarios.
        #[arg(long, value_name = "I/N")]
        shard: Option<String>,
        /// Also write JUnit XML (a test suite per scenario, a test case per expectation).
        #[arg(long, value_name = "FILE")]
        junit: Option<PathBuf>,
    },
    /// Run a sweep: scenarios over seeds and parameter values, statistics over the runs.
    #[command(
        args_conflicts_with_subcommands = true,
        subcommand_negates_reqs = true,
        after_help = SWEEP_HELP
    )]
    Sweep(SweepArgs),
    /// Check scenario files (syntax, keys, values, world, robot, route, sensors) without
    /// running them.
    Validate {
        /// Scenario files.
        #[arg(required = true)]
        scenarios: Vec<PathBuf>,
    },
    /// Print scenarios/defaults.toml: every scenario key with its default and meaning.
    Defaults,
    /// Run the estimators on a recording (MCAP, rosbag2 folder, ROS 1 bag) and write the
    /// outputs of a run.
    #[command(after_help = "Examples:\n  \
        vinebench replay runs/row-loop-rtk-20260101-120000/recording.mcap\n  \
        vinebench replay field.mcap --config docs/field-topics.example.toml --out /tmp/field\n  \
        vinebench replay ~/bags/rosbag2_2026_09_14/ --config robot.toml   # .mcap or .db3 inside\n  \
        vinebench replay field_2019.bag --config robot.toml              # ROS 1 bag\n\n\
        A vinebench recording replays with the scenario it recorded (metadata) and gives the \
        live run's estimates bit for bit, and its SLAM and maps when the images were recorded. \
        A robot's recording needs a topic-mapping file (--config, see \
        docs/field-topics.example.toml): which topic is the IMU, GNSS fix, tracking camera, \
        wheel odometry, RGB-D cameras; frame renames; extrinsics the recording lacks (or the \
        robot's URDF); the IMU's axes, heading reference and noise profile; what the fixes' \
        covariance and altitude are worth; the map origin (default: the first fix); estimator \
        and [mapper] parameters. Unmapped topics and unsupported types are skipped and counted. \
        A damaged or truncated file replays what it still holds. The folder gets \
        estimate_<source>.tum, ground_truth.tum (from /ground_truth/odom, used for scoring), \
        loops.csv, map/, report.json, report.md; without ground truth the report compares \
        every source with the GNSS track and checks the EIF's GNSS NIS against its chi-square \
        band. Exit code: 0 expectations hold (or none) and every requested source produced \
        poses, 1 an expectation fails or a requested source produced none (named, with why), \
        2 nothing usable (no source produced a pose) or bad input.")]
    Replay {
        /// The recording: `.mcap`, a rosbag2 folder (`metadata.yaml` with `.mcap` or `.db3`)
        /// or a ROS 1 `.bag`.
        recording: PathBuf,
        /// Topic-mapping file (TOML) for recordings not made by vinebench.
        #[arg(long, value_name = "TOML")]
        config: Option<PathBuf>,
        /// Output folder (default: runs/replay-<name>-<UTC stamp>/, made unique). It must
        /// be new or empty, and is locked while the replay writes it.
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
        /// Reuse a non-empty --out: clear a previous run's files there first (other files
        /// are kept).
        #[arg(long, requires = "out")]
        replace: bool,
    },
    /// Score trajectories against a reference as evo_ape / evo_rpe do, with their options
    /// and numbers (TUM, KITTI, EuRoC, ROS 1 bags, ROS 2 MCAP and rosbag2 folders).
    #[command(after_help = "Examples (each equals the evo command after it):\n  \
        vinebench score ape tum ground_truth.tum estimate_eif.tum -a\n      \
        evo_ape tum ground_truth.tum estimate_eif.tum -a\n  \
        vinebench score ape kitti KITTI_00_gt.txt KITTI_00_ORB.txt -a -r angle_deg\n      \
        evo_ape kitti KITTI_00_gt.txt KITTI_00_ORB.txt -a -r angle_deg\n  \
        vinebench score ape euroc V102_groundtruth.csv V102.txt -as --save_results r.json\n      \
        evo_ape euroc V102_groundtruth.csv V102.txt -as --save_results r.zip\n  \
        vinebench score rpe tum gt.tum est.tum -d 10 -u m --all_pairs\n      \
        evo_rpe tum gt.tum est.tum -d 10 -u m --all_pairs\n  \
        vinebench score ape bag2 run.mcap /ground_truth/odom /estimate/eif/odom -a\n      \
        evo_ape bag2 run.mcap /ground_truth/odom /estimate/eif/odom -a\n  \
        vinebench score ape tum gt.tum eif.tum gnss.tum slam.tum -a   # one table of all three\n\n\
        The older form `vinebench score --ref REF EST [--align]` prints APE and RPE (translation) \
        as JSON.")]
    Score(ScoreCommand),
    /// Train the visual SLAM's bag-of-words vocabulary on the keyframes of a simulated
    /// scenario.
    #[command(after_help = "Examples:\n  \
        vinebench vocabulary scenarios/vocabularies/training.toml --out vineyard.vbvoc\n  \
        vinebench vocabulary scenarios/csl-box-occluder.toml --out /tmp/csl.vbvoc --depth 3 --quiet\n\n\
        The scenario runs with its visual SLAM on (the stereo cameras of slam.cameras; no \
        baselines, no loop closure, no mapper; nothing scored, no run folder). Every \
        keyframe's ORB descriptors, all cameras together, make one training image. The \
        vocabulary is DBoW2's: a k-medians tree of branching K and depth L (at most K^L \
        words; keep K^L well below the number of descriptors) with idf weights over the \
        keyframes. The file (format VBVOC1, read by slam::bow::Vocabulary::read) goes \
        through a temporary file beside it, so a reader never sees half a file; its folder \
        is created. Exit code: 0 written, 2 bad input or no keyframe.")]
    Vocabulary {
        /// Scenario file (with the stereo cameras of slam.cameras in [[sensors.cameras]]).
        scenario: PathBuf,
        /// Vocabulary file to write (`.vbvoc`).
        #[arg(long, value_name = "FILE")]
        out: PathBuf,
        /// Branching factor K: clusters per node of the tree.
        #[arg(long, value_name = "K", default_value_t = vinebench::vocabulary::DEFAULT_BRANCHING)]
        branching: usize,
        /// Depth L: levels of the tree below its root.
        #[arg(long, value_name = "L", default_value_t = vinebench::vocabulary::DEFAULT_DEPTH)]
        depth: usize,
        /// No progress bar and no summary.
        #[arg(long)]
        quiet: bool,
    },
    /// Measure speed: EIF, physics, ray casting, rendering and real-time factors.
    Bench {
        /// Fewer repetitions (a quick look, noisier figures).
        #[arg(long)]
        quick: bool,
        /// Which figures: `all`, `core` (estimator, physics, no-camera scenario),
        /// `render` (ray casting, shading, camera scenarios), `tracer` (ray casting only,
        /// built-in against Embree when built with `--features embree`), `recording` (MCAP write and
        /// read speed, a run's slowdown by its recording), `mapper` (voxel downsampling,
        /// Ball-Pivoting, memory of mapping a row loop) or `slam` (the whole visual SLAM
        /// on a rendered stream of the box-occluder scenario, rig frames per second) or
        /// `sweep` (sweep throughput with 1 and 2 jobs at once, overhead per job, merge of
        /// 10,000 rows).
        #[arg(long, default_value = "all", value_parser = ["all", "core", "render", "tracer", "recording", "mapper", "slam", "sweep"])]
        only: String,
    },
}

const SWEEP_HELP: &str = "Examples:\n  \
    vinebench sweep scenarios/sweeps/rtk-outage-length.toml --jobs 2\n  \
    vinebench sweep scenarios/sweeps/occluder-width.toml --out /scratch/ow --shard 3/8\n  \
    vinebench sweep merge /scratch/ow --out results/ow --junit ow.xml\n  \
    vinebench sweep compare main-results/ pr-results/ --max-worse 5% --alpha 0.05\n\n\
    A sweep file names base scenarios, seeds (\"1-20\" or a list), axes of scenario keys \
    with their values (a grid by default; zip, random or latin_hypercube), the metrics to \
    tabulate and expectations over statistics (`p95(outage_max_error_m.eif) <= 0.4`, \
    `rate(tracking_losses.slam_single_camera > 0) >= 0.8`, `pass_rate >= 0.9`). Every job \
    (scenario x cell x seed) is an ordinary run; its result is a JSON line in \
    <out>/rows/, written as it finishes, so a rerun of the same command skips finished \
    jobs. Without a shard the whole sweep runs here and is merged into <out>. With \
    --shard I/N, or inside a Slurm job array (SLURM_ARRAY_TASK_ID/_MIN/_STEP/_COUNT) or a \
    Kubernetes Indexed Job (JOB_COMPLETION_INDEX with VINEBENCH_SHARD_COUNT), only that \
    shard runs; `sweep merge` then unites the shards' folders. Run folders are kept per \
    --keep (default: failed jobs'). Exit code of a shard: 0 every job has a row, 2 bad \
    input, 130 interrupted. Exit code of a whole sweep and of merge: 0 every expectation \
    holds, 1 one fails or a job could not run, 2 bad input or missing jobs. \
    Scripts for Slurm, GitHub Actions and Kubernetes: scripts/slurm/, scripts/ci/.";

#[derive(Args)]
struct SweepArgs {
    #[command(subcommand)]
    action: Option<SweepAction>,
    /// The sweep file.
    #[arg(required = true)]
    file: Option<PathBuf>,
    /// The sweep folder (default: runs/sweeps/<name>/); shards of one sweep share it or
    /// each write their own, to be merged.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Jobs at once on this machine (results do not depend on it).
    #[arg(long, value_name = "N", default_value_t = 1)]
    jobs: usize,
    /// Run only shard I of N (1-based); default: from the Slurm or Kubernetes
    /// environment, else the whole sweep.
    #[arg(long, value_name = "I/N")]
    shard: Option<String>,
    /// Run folders to keep.
    #[arg(long, default_value = "failed", value_parser = ["none", "failed", "all"])]
    keep: String,
    /// JUnit XML of the merged sweep (whole sweeps only).
    #[arg(long, value_name = "FILE")]
    junit: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

#[derive(Subcommand)]
enum SweepAction {
    /// Unite the rows of a sweep's shards: results.csv, summary.json, sweep.md with plots,
    /// JUnit; check the sweep's expectations.
    Merge {
        /// Sweep folders (each shard's, or one shared).
        #[arg(required = true)]
        dirs: Vec<PathBuf>,
        /// Where to write (default: the first folder).
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
        /// Merge even when jobs are missing: the statistics of what is there (exit code 1
        /// at best: an incomplete sweep never passes).
        #[arg(long)]
        partial: bool,
        /// Also write JUnit XML: a suite per cell, a case per job and per expectation.
        #[arg(long, value_name = "FILE")]
        junit: Option<PathBuf>,
    },
    /// Regression gate: compare a new sweep with a base one, cell by cell and metric by
    /// metric, paired by seed. Exit code 1 on any regression.
    Compare {
        /// The base sweep folder (main's results).
        base: PathBuf,
        /// The new sweep folder.
        new: PathBuf,
        /// Metrics to gate, comma-separated (default: every metric with a better direction).
        #[arg(long, value_delimiter = ',', value_name = "M,...")]
        metrics: Vec<String>,
        /// Allowed worsening before a significant change is a regression (`5%` or `0.05`).
        #[arg(long, default_value = "5%", value_name = "FRACTION")]
        max_worse: String,
        /// Significance level of each test.
        #[arg(long, default_value_t = 0.05)]
        alpha: f64,
        /// Also write the Markdown table here (it is printed either way).
        #[arg(long, value_name = "FILE")]
        out: Option<PathBuf>,
        /// Also write JUnit XML: a suite per cell, a case per gated metric.
        #[arg(long, value_name = "FILE")]
        junit: Option<PathBuf>,
    },
}

#[derive(Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
struct ScoreCommand {
    #[command(subcommand)]
    metric: Option<EvoMetric>,
    #[command(flatten)]
    legacy: ScoreArgs,
}

#[derive(Subcommand)]
enum EvoMetric {
    /// Absolute pose error of each estimate, as evo_ape (same options, same numbers).
    #[command(after_help = "Examples:\n  \
        vinebench score ape tum gt.tum est.tum -as --n_to_align 10\n  \
        vinebench score ape kitti KITTI_00_gt.txt KITTI_00_ORB.txt -r full --align_origin\n\n\
        Association (stamps within --t_max_diff, the shorter trajectory driving), alignment and \
        the pose relations are evo 1.38.1's; repeated or unsorted stamps are accepted as evo \
        accepts them, and a note on stderr says how many poses association left out.")]
    Ape(scoring::evo::cli::EvoArgs),
    /// Relative pose error of each estimate, as evo_rpe (same options, same numbers).
    #[command(after_help = "Examples:\n  \
        vinebench score rpe tum gt.tum est.tum                    # delta 1 frame\n  \
        vinebench score rpe kitti gt.txt est.txt -d 100 -u m --all_pairs\n  \
        vinebench score rpe tum gt.tum est.tum -d 5 -u d -r angle_deg")]
    Rpe {
        #[command(flatten)]
        args: scoring::evo::cli::EvoArgs,
        #[command(flatten)]
        rpe: scoring::evo::cli::RpeArgs,
    },
}

/// The older `vinebench score --ref REF EST`: APE and RPE (translation) as JSON.
#[derive(Args)]
struct ScoreArgs {
    /// Reference (ground-truth) TUM file.
    #[arg(long = "ref", value_name = "TUM", required = true)]
    reference: Option<PathBuf>,
    /// Estimated TUM file.
    #[arg(required = true)]
    estimate: Option<PathBuf>,
    /// Maximum stamp difference for association, s (evo's --t_max_diff; finite, >= 0).
    #[arg(long, default_value_t = 0.01, value_parser = non_negative_seconds)]
    t_max_diff: f64,
    /// RPE path distance, m (evo_rpe --delta D --delta_unit m; finite, > 0).
    #[arg(long, default_value_t = 1.0, value_parser = positive_metres)]
    delta: f64,
    /// Align with SE(3) Umeyama before computing errors (evo's -a).
    #[arg(long)]
    align: bool,
    /// Choose RPE pairs on the reference's path (evo_rpe --pairs_from_reference).
    #[arg(long)]
    pairs_from_reference: bool,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if let Some(n) = cli.threads
        && let Err(e) = rayon::ThreadPoolBuilder::new()
            .num_threads(usize::from(n))
            .build_global()
    {
        eprintln!("error: --threads {n}: {e}");
        return ExitCode::from(EXIT_ERROR);
    }
    let code = match dispatch(cli.command) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", error_chain(&e));
            EXIT_ERROR
        }
    };
    if let Some(e) = vinebench::output::error() {
        eprintln!("error: cannot write to standard output: {e}");
        return ExitCode::from(EXIT_ERROR);
    }
    ExitCode::from(code)
}

/// An error and its causes joined by `: `, leaving out a cause whose text the message
/// already holds (`file: No such file or directory (os error 2)` said once, not twice).
fn error_chain(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let c = cause.to_string();
        if text.contains(&c) {
            continue;
        }
        if !text.is_empty() {
            text.push_str(": ");
        }
        text.push_str(&c);
    }
    text
}

fn dispatch(cmd: Command) -> Result<u8> {
    match cmd {
        Command::Run {
            scenario,
            out,
            replace,
            quiet,
        } => {
            let sc = LoadedScenario::load(&scenario)?;
            let opts = RunOptions {
                out_dir: out,
                progress: !quiet,
                stop: Some(interrupt_flag()),
                replace,
                ..RunOptions::default()
            };
            let outcome = match runner::run(&sc, &opts) {
                Err(e @ runner::RunError::Interrupted { .. }) => {
                    eprintln!("{e}; the recording so far is finalized in the run folder");
                    return Ok(EXIT_INTERRUPTED);
                }
                r => r?,
            };
            if !quiet {
                print_summary(&outcome);
            }
            Ok(if outcome.passed() {
                EXIT_PASS
            } else {
                EXIT_FAIL
            })
        }
        Command::Check {
            paths,
            runs,
            shard,
            junit,
        } => check(&paths, &runs, shard.as_deref(), junit.as_deref()),
        Command::Sweep(a) => sweep_cmd(a),
        Command::Validate { scenarios } => {
            let mut code = EXIT_PASS;
            for p in scenarios {
                match LoadedScenario::load(&p)
                    .map_err(anyhow::Error::from)
                    .and_then(|sc| {
                        runner::validate(&sc)?;
                        Ok(sc)
                    }) {
                    Ok(sc) => outln!("ok: {} ({})", p.display(), sc.scenario.name),
                    Err(e) => {
                        eprintln!("error: {}", error_chain(&e));
                        code = EXIT_ERROR;
                    }
                }
            }
            Ok(code)
        }
        Command::Defaults => {
            out!("{}", vinebench_msgs::defaults::DEFAULTS_TOML);
            Ok(EXIT_PASS)
        }
        Command::Score(c) => match &c.metric {
            Some(EvoMetric::Ape(a)) => scoring::evo::cli::run(a, None).map(|()| EXIT_PASS),
            Some(EvoMetric::Rpe { args, rpe }) => {
                scoring::evo::cli::run(args, Some(rpe)).map(|()| EXIT_PASS)
            }
            None => score(&c.legacy),
        },
        Command::Replay {
            recording,
            config,
            out,
            replace,
        } => {
            let opts = vinebench::replay::ReplayOptions {
                config,
                out_dir: out,
                runs_root: PathBuf::from("runs"),
                replace,
            };
            let o = vinebench::replay::replay(&recording, &opts)?;
            let r = &o.report;
            if let Some(d) = &r.damage {
                eprintln!("warning: {}: damaged recording: {d}", recording.display());
            }
            let skipped: u64 = r.skipped.values().sum();
            let replayed: u64 = r.replayed.values().sum();
            outln!(
                "{}: {replayed} messages replayed, {skipped} skipped, {} did not decode",
                r.name,
                r.decode_errors.values().map(|(n, _)| n).sum::<u64>()
            );
            for s in &r.sources {
                let ate = s
                    .score
                    .as_ref()
                    .and_then(|x| x.metric("ate_rmse_m"))
                    .map(|v| format!("ATE {v:.3} m"))
                    .or_else(|| {
                        s.vs_gnss.as_ref().map(|g| {
                            format!(
                                "to the GNSS track: horizontal RMS {:.3} m, p95 {:.3} m",
                                g.horizontal_rmse_m, g.horizontal_p95_m
                            )
                        })
                    })
                    .unwrap_or_else(|| "no ground truth".into());
                outln!("{:<16} {:>7} poses  {ate}", s.name, s.poses);
                if s.score.is_none()
                    && let Some(nis) = &s.gnss_nis
                {
                    outln!("  {}", nis.verdict());
                }
            }
            for n in r.estimator_notes() {
                outln!("  note: {n}");
            }
            for m in &r.maps {
                let score = m
                    .metric("map_accuracy_m")
                    .zip(m.metric("map_f_score_2cm"))
                    .map(|(a, f)| format!("accuracy {a:.4} m, F@2cm {f:.3}"))
                    .unwrap_or_else(|| "not scored".into());
                outln!(
                    "map {:<12} {:>9} points  {score}  ({}/)",
                    m.source,
                    m.stats.voxels,
                    m.folder
                );
            }
            if let Some(why) = &r.nothing_usable {
                // Estimators that produced nothing are not a pass: exit 2 as promised.
                eprintln!(
                    "error: {why} (report: {})",
                    o.dir.join("report.md").display()
                );
                return Ok(EXIT_ERROR);
            }
            for w in &r.without_poses {
                outln!("FAIL: {w}");
            }
            print_verdict(&r.expectations, r.passed, &o.dir);
            Ok(if r.passed { EXIT_PASS } else { EXIT_FAIL })
        }
        Command::Vocabulary {
            scenario,
            out,
            branching,
            depth,
            quiet,
        } => vocabulary(&scenario, &out, branching, depth, quiet),
        Command::Bench { quick, only } => {
            // `tracer` alone: about 10 s (4 s quick) on the 2-core machine of
            // docs/PERFORMANCE.md; everything about 240 s (60 s quick), other subsets less.
            let about_s = match (only.as_str(), quick) {
                ("tracer", true) => 4,
                ("tracer", false) => 10,
                (_, true) => 60,
                (_, false) => 240,
            };
            eprintln!("measuring (about {about_s} s)...");
            let mut figures = Vec::new();
            if only == "all" || only == "core" {
                figures.extend(vinebench::bench::run_all(quick)?);
            }
            if only == "all" || only == "render" || only == "tracer" {
                figures.extend(vinebench::bench::render_figures(quick, only == "tracer")?);
            }
            if only == "all" || only == "recording" {
                figures.extend(vinebench::bench::recording::recording_figures(quick)?);
            }
            if only == "all" || only == "mapper" {
                figures.extend(vinebench::bench::mapper::mapper_figures(quick)?);
            }
            if only == "all" || only == "slam" {
                figures.extend(vinebench::bench::slam_tracking_figures(quick)?);
            }
            if only == "all" || only == "sweep" {
                figures.extend(vinebench::bench::sweep::sweep_figures(quick)?);
            }
            outln!("| figure | value | target |\n|---|---:|---:|");
            for f in figures {
                let target = f
                    .target
                    .map(|t| format!(">= {t:.0} {}", f.unit))
                    .unwrap_or_default();
                // Three significant digits.
                let digits = (2 - f.value.abs().max(1e-12).log10().floor() as i32).max(0) as usize;
                outln!(
                    "| {} | {:.*} {} | {target} |",
                    f.name,
                    digits,
                    f.value,
                    f.unit
                );
            }
            outln!(
                "\n{} threads available; vinebench {} ({} build)",
                std::thread::available_parallelism()
                    .map(|n| n.get())
                    .unwrap_or(1),
                env!("CARGO_PKG_VERSION"),
                if cfg!(debug_assertions) {
                    "debug"
                } else {
                    "release"
                }
            );
            Ok(EXIT_PASS)
        }
    }
}

/// A flag that the first Ctrl-C (SIGINT), SIGTERM (what CI cancellations, `timeout` and
/// Slurm send) or SIGHUP sets, so a run stops cleanly and finalizes its recording; a second
/// signal exits at once. Installed once per process.
fn interrupt_flag() -> Arc<AtomicBool> {
    static FLAG: std::sync::OnceLock<Arc<AtomicBool>> = std::sync::OnceLock::new();
    FLAG.get_or_init(|| {
        let flag = Arc::new(AtomicBool::new(false));
        let f = flag.clone();
        if let Err(e) = ctrlc::set_handler(move || {
            if f.swap(true, Ordering::SeqCst) {
                std::process::exit(i32::from(EXIT_INTERRUPTED));
            }
            eprintln!(
                "\ninterrupted: stopping the run and finalizing its recording (Ctrl-C again to quit now)"
            );
        }) {
            eprintln!("warning: cannot handle Ctrl-C ({e}); an interrupted run's recording may be unfinished");
        }
        flag
    })
    .clone()
}

fn print_summary(o: &runner::RunOutcome) {
    let r = &o.report;
    outln!(
        "{}: {:.0} s simulated in {:.2} s ({:.2}x real time), {:.1} m driven",
        r.scenario.name,
        r.run.duration_s,
        o.wall_s,
        r.run.duration_s / o.wall_s.max(1e-9),
        r.run.distance_m
    );
    outln!(
        "{:<18} {:>9} {:>9} {:>9} {:>9} {:>9} {:>12}",
        "source",
        "D [m]",
        "D_EN [m]",
        "D_U [m]",
        "σ_U [m]",
        "ATE [m]",
        "ATE al. [m]"
    );
    if let Some(g) = &r.ground_truth {
        outln!(
            "{:<18} {:>9.3} {:>9.3} {:>9.3} {:>9.3} {:>9} {:>12}",
            "ground truth",
            g.d_m,
            g.d_en_m,
            g.d_u_m,
            g.sigma_u_m,
            "",
            ""
        );
    }
    for s in &r.sources {
        let m = |k: &str| {
            s.score
                .metric(k)
                .map(|v| format!("{v:.3}"))
                .unwrap_or_else(|| "–".into())
        };
        outln!(
            "{:<18} {:>9} {:>9} {:>9} {:>9} {:>9} {:>12}",
            s.name,
            m("d_m"),
            m("d_en_m"),
            m("d_u_m"),
            m("sigma_u_m"),
            m("ate_rmse_m"),
            m("ate_rmse_aligned_m")
        );
    }
    let robot = &r.robot;
    outln!(
        "{:<18} {}; {} collision(s); max cross-track {:.3} m, heading error {:.1}°, tilt {:.1}°",
        "robot",
        robot.outcome,
        robot.collisions.len(),
        robot.metrics.max_cross_track_m,
        robot.metrics.max_heading_error_deg,
        robot.metrics.max_tilt_deg
    );
    print_verdict(&r.expectations, r.passed, &o.dir);
}

/// Each expectation's outcome, then PASS/FAIL and where the report is.
fn print_verdict(
    expectations: &[vinebench::scoring::expect::ExpectationResult],
    passed: bool,
    dir: &Path,
) {
    for x in expectations {
        outln!("{x}");
    }
    outln!(
        "{} — report: {}",
        if passed { "PASS" } else { "FAIL" },
        dir.join("report.md").display()
    );
}

fn collect_scenarios(paths: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for p in paths {
        if p.is_dir() {
            let mut in_dir: Vec<PathBuf> = std::fs::read_dir(p)
                .with_context(|| format!("{}: cannot list the folder", p.display()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|f| {
                    f.extension().is_some_and(|x| x == "toml")
                        && f.file_name().is_some_and(|n| n != "defaults.toml")
                })
                .collect();
            in_dir.sort();
            files.extend(in_dir);
        } else if p.exists() {
            files.push(p.clone());
        } else {
            bail!("{}: no such file or folder", p.display());
        }
    }
    Ok(files)
}

fn parse_shard(s: &str) -> Result<(usize, usize)> {
    let (i, n) = s
        .split_once('/')
        .with_context(|| format!("--shard {s}: expected I/N such as 2/4"))?;
    let (i, n): (usize, usize) = (
        i.trim()
            .parse()
            .with_context(|| format!("--shard {s}: I is not a number"))?,
        n.trim()
            .parse()
            .with_context(|| format!("--shard {s}: N is not a number"))?,
    );
    if n == 0 || i == 0 || i > n {
        bail!("--shard {s}: expected 1 <= I <= N");
    }
    Ok((i, n))
}

/// `vinebench sweep ...`.
fn sweep_cmd(a: SweepArgs) -> Result<u8> {
    use vinebench::sweep::{merge, run, spec::Sweep};
    if let Some(SweepAction::Merge {
        dirs,
        out,
        partial,
        junit,
    }) = a.action
    {
        let out = out.unwrap_or_else(|| dirs[0].clone());
        let opts = merge::MergeOptions {
            out_dir: out.clone(),
            partial,
            junit,
        };
        let s = merge::merge(&dirs, &opts)?;
        print_merge(&s, &out);
        return Ok(s.exit_code(partial));
    }
    if let Some(SweepAction::Compare {
        base,
        new,
        metrics,
        max_worse,
        alpha,
        out,
        junit,
    }) = a.action
    {
        use vinebench::sweep::compare;
        let t = max_worse.trim();
        let max_worse = match t.strip_suffix('%') {
            Some(p) => p.trim().parse::<f64>().map(|v| v / 100.0),
            None => t.parse::<f64>(),
        }
        .ok()
        .filter(|v| v.is_finite() && *v >= 0.0)
        .with_context(|| format!("--max-worse {t}: expected a fraction such as 5% or 0.05"))?;
        let o = compare::CompareOptions {
            metrics,
            max_worse,
            alpha,
        };
        let r = compare::compare(&base, &new, &o)?;
        let md = compare::markdown(&r);
        out!("{md}");
        if let Some(p) = out {
            vinebench::fsio::write_atomic(&p, md.as_bytes())
                .with_context(|| format!("{}: cannot write", p.display()))?;
        }
        if let Some(j) = junit {
            let xml = vinebench::sweep::junit::to_xml("sweep compare", &compare::junit_suites(&r));
            vinebench::fsio::write_atomic(&j, xml.as_bytes())
                .with_context(|| format!("{}: cannot write", j.display()))?;
        }
        return Ok(r.exit_code());
    }
    let Some(file) = a.file else {
        bail!("expected a sweep file, `merge` or `compare`");
    };
    let sweep = Sweep::load(&file)?;
    let shard = run::Shard::from_args(a.shard.as_deref(), |k| std::env::var(k).ok())
        .map_err(anyhow::Error::msg)?;
    let out = a
        .out
        .unwrap_or_else(|| PathBuf::from("runs/sweeps").join(&sweep.name));
    let keep = match a.keep.as_str() {
        "none" => run::Keep::None,
        "all" => run::Keep::All,
        _ => run::Keep::Failed,
    };
    let whole = shard.count == 1;
    eprintln!(
        "{}: {} job(s) ({} scenario(s) x {} cell(s) x {} seed(s)); {}; {} at once -> {}",
        sweep.name,
        sweep.job_count(),
        sweep.scenarios.len(),
        sweep.cells.len(),
        sweep.seeds.len(),
        shard.from,
        a.jobs,
        out.display()
    );
    let opts = run::SweepOptions {
        out_dir: out.clone(),
        jobs: a.jobs,
        shard,
        keep,
        progress: !a.quiet,
        stop: Some(interrupt_flag()),
    };
    let o = match run::run_shard(&sweep, &opts) {
        Err(e @ run::SweepRunError::Interrupted { .. }) => {
            eprintln!("{e}");
            return Ok(EXIT_INTERRUPTED);
        }
        r => r?,
    };
    eprintln!(
        "{} job(s) in this shard: {} already done, {} pass, {} fail, {} error",
        o.jobs, o.skipped, o.passed, o.failed, o.errors
    );
    if !whole {
        eprintln!(
            "shard done; when every shard is, merge: vinebench sweep merge {}",
            out.display()
        );
        return Ok(EXIT_PASS);
    }
    let mopts = merge::MergeOptions {
        out_dir: out.clone(),
        partial: false,
        junit: a.junit,
    };
    let s = merge::merge(std::slice::from_ref(&out), &mopts)?;
    print_merge(&s, &out);
    Ok(s.exit_code(false))
}

fn print_merge(s: &vinebench::sweep::merge::MergeSummary, out: &Path) {
    outln!(
        "{}: {}{}",
        s.sweep.name,
        s.counts(),
        if s.missing.is_empty() {
            String::new()
        } else {
            format!(", {} MISSING (first: {})", s.missing.len(), s.missing[0])
        }
    );
    for d in s.damaged.iter().chain(&s.conflicts) {
        eprintln!("warning: {d}");
    }
    for c in &s.cells {
        for x in &c.expectations {
            outln!("{} / {}: {x}", c.scenario, c.label);
        }
    }
    for x in &s.overall {
        outln!("all jobs: {x}");
    }
    outln!(
        "{} — {}",
        if s.passed_all { "PASS" } else { "FAIL" },
        out.join("sweep.md").display()
    );
}

fn check(paths: &[PathBuf], runs: &Path, shard: Option<&str>, junit: Option<&Path>) -> Result<u8> {
    let mut files = collect_scenarios(paths)?;
    if files.is_empty() {
        bail!("no scenario files found in {:?}", paths);
    }
    if let Some(s) = shard {
        let (i, n) = parse_shard(s)?;
        let all = files.len();
        files = files
            .into_iter()
            .enumerate()
            .filter(|(k, _)| k % n == i - 1)
            .map(|(_, f)| f)
            .collect();
        if files.is_empty() {
            // A CI matrix wider than the scenario list: this job has nothing to do, which
            // is a success (the other shards cover every scenario).
            eprintln!("shard {i}/{n}: nothing to do ({all} scenario(s) over {n} shards)");
        }
    }
    let mut worst = EXIT_PASS;
    let mut rows = Vec::new();
    let mut suites = Vec::new();
    for f in &files {
        let result = LoadedScenario::load(f)
            .map_err(anyhow::Error::from)
            .and_then(|sc| {
                let opts = RunOptions {
                    runs_root: runs.to_path_buf(),
                    stop: Some(interrupt_flag()),
                    ..RunOptions::default()
                };
                Ok(runner::run(&sc, &opts)?)
            });
        suites.push(check_suite(f, &result));
        match result {
            Ok(o) => {
                let held = o.report.expectations.iter().filter(|x| x.holds).count();
                let verdict = if o.passed() { "PASS" } else { "FAIL" };
                if !o.passed() {
                    worst = worst.max(EXIT_FAIL);
                    for x in o.report.expectations.iter().filter(|x| !x.holds) {
                        eprintln!("{}: {x}", f.display());
                    }
                }
                rows.push(format!(
                    "{verdict:<5} {:<40} {held}/{} expectations  {:.1}s wall  {}",
                    f.display(),
                    o.report.expectations.len(),
                    o.wall_s,
                    o.dir.display()
                ));
            }
            Err(e) => {
                eprintln!("error: {}", error_chain(&e));
                worst = EXIT_ERROR;
                rows.push(format!("ERROR {:<40} see above", f.display()));
            }
        }
    }
    outln!("\n{} scenario(s):", files.len());
    for r in rows {
        outln!("{r}");
    }
    if let Some(j) = junit {
        let xml = vinebench::sweep::junit::to_xml("vinebench check", &suites);
        vinebench::fsio::write_atomic(j, xml.as_bytes())
            .with_context(|| format!("{}: cannot write the JUnit file", j.display()))?;
    }
    Ok(worst)
}

/// A scenario's JUnit suite: a case per expectation, or one error case.
fn check_suite(
    file: &Path,
    result: &Result<runner::RunOutcome>,
) -> vinebench::sweep::junit::TestSuite {
    use vinebench::sweep::junit::{TestCase, TestSuite, Verdict};
    let name = file.display().to_string();
    let classname = format!(
        "check.{}",
        file.file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default()
    );
    let cases = match result {
        Ok(o) => {
            let n = o.report.expectations.len().max(1) as f64;
            let out = format!("run folder: {}", o.dir.display());
            let mut cases: Vec<TestCase> = o
                .report
                .expectations
                .iter()
                .map(|x| TestCase {
                    name: x.text.clone(),
                    classname: classname.clone(),
                    time_s: o.wall_s / n,
                    verdict: if x.holds {
                        Verdict::Pass
                    } else {
                        Verdict::Failure {
                            message: x.text.clone(),
                            details: x.to_string(),
                        }
                    },
                    system_out: Some(format!("{x}\n{out}")),
                })
                .collect();
            if cases.is_empty() {
                // A scenario without expectations still ran: one case for the run.
                cases.push(TestCase {
                    name: "runs".into(),
                    classname: classname.clone(),
                    time_s: o.wall_s,
                    verdict: Verdict::Pass,
                    system_out: Some(out),
                });
            }
            cases
        }
        Err(e) => vec![TestCase {
            name: "runs".into(),
            classname,
            time_s: 0.0,
            verdict: Verdict::Error {
                message: format!("{e}"),
                details: error_chain(e),
            },
            system_out: None,
        }],
    };
    TestSuite { name, cases }
}

/// `vinebench vocabulary`: simulate, train, write atomically, summarise.
fn vocabulary(
    scenario: &Path,
    out: &Path,
    branching: usize,
    depth: usize,
    quiet: bool,
) -> Result<u8> {
    use vinebench::vocabulary as voc;
    use vinebench_onboard::slam::bow::VocabularyConfig;
    let cfg = VocabularyConfig {
        branching,
        depth,
        ..VocabularyConfig::default()
    };
    // Bad settings fail before minutes of simulation.
    cfg.validate().context("--branching/--depth")?;
    let sc = LoadedScenario::load(scenario)?;
    let bar = runner::progress_bar(&sc, !quiet);
    let set = voc::collect_keyframes(&sc, bar.as_ref());
    if let Some(pb) = &bar {
        pb.finish_and_clear();
    }
    let set = set?;
    let max_words = (branching as f64).powi(depth as i32);
    if max_words > set.descriptors() as f64 {
        eprintln!(
            "warning: k^L = {max_words:.0} possible words for {} descriptors: most words will \
             hold one descriptor (lower --depth or --branching, or train on a longer scenario)",
            set.descriptors()
        );
    }
    if !quiet {
        eprintln!(
            "training: {} keyframes, {} descriptors, k = {branching}, L = {depth}...",
            set.images.len(),
            set.descriptors()
        );
    }
    let (vocabulary, s) = voc::train(&set, &cfg)?;
    let bytes = voc::write_atomic(&vocabulary, out)?;
    if !quiet {
        outln!(
            "{}: {} words (k = {branching}, L = {depth}) from {} keyframes, {} descriptors; {} bytes ({:.2} MB)",
            out.display(),
            s.words,
            s.keyframes,
            s.descriptors,
            bytes,
            bytes as f64 / 1e6
        );
        outln!(
            "{}: {:.1} s simulated ({:.1} m driven, route {}, {} tracking loss(es)) in {:.1} s, \
             trained in {:.1} s; {:.1} s wall",
            sc.scenario.name,
            s.simulated_s,
            s.distance_m,
            if s.route_completed {
                "completed"
            } else {
                "not completed"
            },
            s.tracking_losses,
            s.simulation_wall_s,
            s.training_wall_s,
            s.wall_s
        );
    }
    Ok(EXIT_PASS)
}

/// `--t_max_diff`: a finite number of seconds, at least 0 and at most a day (a stamp
/// difference beyond that associates unrelated poses).
fn non_negative_seconds(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .parse()
        .map_err(|_| format!("expected seconds such as 0.01, found `{s}`"))?;
    if !(v.is_finite() && (0.0..=86_400.0).contains(&v)) {
        return Err(format!(
            "expected finite seconds in [0, 86400], found `{s}`"
        ));
    }
    Ok(v)
}

/// `--delta`: a finite positive distance in metres.
fn positive_metres(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .parse()
        .map_err(|_| format!("expected metres such as 1.0, found `{s}`"))?;
    if !(v.is_finite() && v > 0.0) {
        return Err(format!("expected a finite distance > 0 m, found `{s}`"));
    }
    Ok(v)
}

fn score(a: &ScoreArgs) -> Result<u8> {
    let (Some(reference_path), Some(estimate_path)) = (&a.reference, &a.estimate) else {
        bail!("give --ref REF and an estimate (or use `vinebench score ape|rpe`)");
    };
    let reference = scoring::tum::read_tum(reference_path)?;
    let estimate = scoring::tum::read_tum(estimate_path)?;
    let max_diff = Nanos::from_secs_f64(a.t_max_diff);
    let pairs = if a.pairs_from_reference {
        PairsFrom::Reference
    } else {
        PairsFrom::Estimate
    };
    let ape = scoring::metrics::ape(&reference, &estimate, max_diff, a.align)?;
    let rpe = scoring::metrics::rpe(&reference, &estimate, max_diff, a.delta, a.align, pairs)?;
    let out = serde_json::json!({
        "reference": reference_path.display().to_string(),
        "estimate": estimate_path.display().to_string(),
        "t_max_diff_s": a.t_max_diff,
        "aligned": a.align,
        "matched_poses": ape.matched,
        "ape_translation_m": ape.stats,
        "rpe_translation_m": {
            "delta_m": a.delta,
            "pairs_from": if a.pairs_from_reference { "reference" } else { "estimate" },
            "stats": rpe.stats,
        },
    });
    outln!("{out:#}");
    Ok(EXIT_PASS)
}
