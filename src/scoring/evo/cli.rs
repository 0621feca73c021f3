//! The arguments of `vinebench score ape|rpe` (evo's names and defaults) and what the
//! command prints and saves.

use super::pairs::DeltaUnit;
use super::{EvoResult, Format, Options, PoseRelation, RpeOptions, Traj};
use crate::outln;
use anyhow::{Context, Result, bail};
use std::path::{Path, PathBuf};

/// A file format argument (evo's subcommand).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum FormatArg {
    /// TUM: `t x y z qx qy qz qw` per line.
    Tum,
    /// KITTI poses: a row-major 3×4 `[R|t]` per line (no stamps: compared pose by pose,
    /// unless both times files are given).
    Kitti,
    /// The reference a EuRoC ground-truth CSV, the estimates TUM files (as evo_ape euroc).
    Euroc,
    /// A ROS 1 bag, then the reference topic and the estimate topics (as evo_ape bag).
    Bag,
    /// A ROS 2 recording (MCAP file or rosbag2 folder), then the reference topic and the
    /// estimate topics (as evo_ape bag2).
    #[value(alias = "mcap")]
    Bag2,
}

/// What `ape` and `rpe` take (evo_ape's options of the same names; see `--help`).
#[derive(clap::Args, Debug, Clone)]
pub struct EvoArgs {
    /// File format: tum, kitti, euroc (EuRoC CSV reference, TUM estimates), bag (a ROS 1
    /// bag and topics) or bag2 (alias mcap: a ROS 2 recording and topics).
    #[arg(value_enum)]
    pub format: FormatArg,
    /// Reference trajectory (bag, bag2: the recording).
    pub reference: PathBuf,
    /// Estimated trajectories (several: each against the reference, then a table of all,
    /// as evo_res shows). bag, bag2: the reference topic, then the estimate topics (a topic
    /// or a transform `/tf:parent.child`).
    #[arg(required = true)]
    pub estimates: Vec<PathBuf>,
    /// Pose relation of the error.
    #[arg(
        short = 'r',
        long = "pose_relation",
        value_enum,
        default_value = "trans_part"
    )]
    pub pose_relation: PoseRelation,
    /// Align the estimate to the reference with SE(3) Umeyama (Sim(3) with -s: `-as`).
    #[arg(short = 'a', long = "align")]
    pub align: bool,
    /// Correct the scale (with -a: Sim(3) Umeyama; alone: only the scale is applied).
    #[arg(short = 's', long = "correct_scale")]
    pub correct_scale: bool,
    /// Align with the first N associated poses only (-1: all).
    #[arg(long = "n_to_align", value_name = "N", default_value_t = -1,
          allow_negative_numbers = true, value_parser = n_to_align)]
    pub n_to_align: i64,
    /// Move the estimate so that its first pose is the reference's (not with -a).
    #[arg(long = "align_origin", conflicts_with = "align")]
    pub align_origin: bool,
    /// Largest stamp difference of an associated pair, s.
    #[arg(long = "t_max_diff", default_value_t = 0.01, value_parser = seconds_non_negative)]
    pub t_max_diff: f64,
    /// Added to the estimate's stamps for association, s.
    #[arg(long = "t_offset", default_value_t = 0.0, allow_negative_numbers = true,
          value_parser = seconds_finite)]
    pub t_offset: f64,
    /// KITTI: the reference's times file (one stamp per pose; with --est_times the poses
    /// are associated by stamps).
    #[arg(long = "ref_times", value_name = "FILE")]
    pub ref_times: Option<PathBuf>,
    /// KITTI: the estimate's times file.
    #[arg(long = "est_times", value_name = "FILE")]
    pub est_times: Option<PathBuf>,
    /// Save the result: FILE.zip in evo's format (evo_res reads it; one estimate), any
    /// other name as JSON with the same info, stats and arrays (error_array, timestamps,
    /// seconds_from_start, distances, alignment_transformation_sim3; a list of them with
    /// several estimates).
    #[arg(long = "save_results", value_name = "FILE")]
    pub save_results: Option<PathBuf>,
    /// Save the statistics of every estimate as CSV (evo_res --save_table).
    #[arg(long = "save_table", value_name = "FILE")]
    pub save_table: Option<PathBuf>,
    /// Save a plot (SVG): the error along the trajectory beside the trajectories, the
    /// estimate coloured by its error.
    #[arg(long = "save_plot", value_name = "FILE")]
    pub save_plot: Option<PathBuf>,
    /// The plane of the trajectory view (xyz: drawn as xy).
    #[arg(long = "plot_mode", value_enum, default_value = "xy")]
    pub plot_mode: super::plot::PlotMode,
    /// Accepted for evo compatibility (vinebench never prompts).
    #[arg(long = "no_warnings")]
    pub no_warnings: bool,
    /// Print only errors and the statistics (no association notes).
    #[arg(long = "silent")]
    pub silent: bool,
    /// Accepted for evo compatibility.
    #[arg(short = 'v', long = "verbose")]
    pub verbose: bool,
}

/// What only `rpe` takes.
#[derive(clap::Args, Debug, Clone)]
pub struct RpeArgs {
    /// Distance between the poses of a pair, in --delta_unit (default 1).
    #[arg(short = 'd', long = "delta", value_parser = positive_finite)]
    pub delta: Option<f64>,
    /// Unit of --delta: f frames, m metres of path, d degrees, r radians.
    #[arg(short = 'u', long = "delta_unit", value_enum, default_value = "f")]
    pub delta_unit: DeltaUnit,
    /// Relative tolerance of --delta with --all_pairs (metres and angles).
    #[arg(short = 't', long = "delta_tol", default_value_t = 0.1, value_parser = non_negative_finite)]
    pub delta_tol: f64,
    /// Use every pair delta apart, not only consecutive ones.
    #[arg(long = "all_pairs")]
    pub all_pairs: bool,
    /// Choose the pairs on the reference's path (default: the aligned estimate's, as evo).
    #[arg(long = "pairs_from_reference")]
    pub pairs_from_reference: bool,
}

/// A finite number that `ok` accepts, or an error saying `what` was expected.
fn number(s: &str, what: &str, ok: fn(f64) -> bool) -> Result<f64, String> {
    s.parse::<f64>()
        .ok()
        .filter(|v| v.is_finite() && ok(*v))
        .ok_or_else(|| format!("expected {what}, found `{s}`"))
}

fn seconds_non_negative(s: &str) -> Result<f64, String> {
    number(s, "seconds >= 0 such as 0.01", |v| v >= 0.0)
}

fn seconds_finite(s: &str) -> Result<f64, String> {
    number(s, "seconds such as -1.2", |_| true)
}

fn positive_finite(s: &str) -> Result<f64, String> {
    number(s, "a number > 0", |v| v > 0.0)
}

fn non_negative_finite(s: &str) -> Result<f64, String> {
    number(s, "a number >= 0", |v| v >= 0.0)
}

fn n_to_align(s: &str) -> Result<i64, String> {
    match s.parse::<i64>() {
        Ok(-1) => Ok(-1),
        Ok(n) if n >= 1 => Ok(n),
        _ => Err(format!(
            "expected a pose count >= 1 or -1 (all), found `{s}`"
        )),
    }
}

impl EvoArgs {
    fn options(&self) -> Options {
        Options {
            t_max_diff: self.t_max_diff,
            t_offset: self.t_offset,
            align: self.align,
            correct_scale: self.correct_scale,
            n_to_align: usize::try_from(self.n_to_align).ok(),
            align_origin: self.align_origin,
            relation: self.pose_relation,
        }
    }

    /// Reads the reference and each estimate.
    fn read(&self) -> Result<(Traj, Vec<Traj>)> {
        if self.format != FormatArg::Kitti && (self.ref_times.is_some() || self.est_times.is_some())
        {
            bail!("--ref_times and --est_times are for KITTI pose files (format `kitti`)");
        }
        if self.estimates.len() > 1 && self.est_times.is_some() {
            bail!("--est_times takes one estimate (the times file belongs to one pose file)");
        }
        let (rf, ef) = match self.format {
            FormatArg::Tum => (Format::Tum, Format::Tum),
            FormatArg::Kitti => (Format::Kitti, Format::Kitti),
            FormatArg::Euroc => (Format::Euroc, Format::Tum),
            FormatArg::Bag | FormatArg::Bag2 => {
                let Some((ref_topic, est_topics)) = self
                    .estimates
                    .split_first()
                    .filter(|(_, est)| !est.is_empty())
                else {
                    bail!("bag/bag2: give the recording, the reference topic and estimate topics");
                };
                let topic = |p: &PathBuf| p.to_string_lossy().into_owned();
                let reference = super::bag::read_topic(&self.reference, &topic(ref_topic))?;
                let estimates = est_topics
                    .iter()
                    .map(|t| super::bag::read_topic(&self.reference, &topic(t)))
                    .collect::<Result<Vec<_>, _>>()?;
                return Ok((reference, estimates));
            }
        };
        let reference = super::read::read(&self.reference, rf, self.ref_times.as_deref())?;
        let estimates = self
            .estimates
            .iter()
            .map(|e| super::read::read(e, ef, self.est_times.as_deref()))
            .collect::<Result<Vec<_>, _>>()?;
        Ok((reference, estimates))
    }
}

/// `vinebench score ape` (`rpe` with `rpe`): prints evo's title and statistics per
/// estimate, a table of all, and saves what was asked.
pub fn run(args: &EvoArgs, rpe: Option<&RpeArgs>) -> Result<()> {
    let (reference, estimates) = args.read()?;
    let o = args.options();
    let mut results = Vec::with_capacity(estimates.len());
    for e in &estimates {
        let r = match rpe {
            None => super::ape(&reference, e, &o),
            Some(r) => super::rpe(
                &reference,
                e,
                &o,
                &RpeOptions {
                    delta: r.delta,
                    delta_unit: r.delta_unit,
                    delta_tol: r.delta_tol,
                    all_pairs: r.all_pairs,
                    pairs_from_reference: r.pairs_from_reference,
                },
            ),
        }
        .with_context(|| format!("{} against {}", e.name, reference.name))?;
        if !args.silent {
            for n in &r.notes {
                eprintln!("note: {n}");
            }
        }
        outln!("{}\n\n{}", r.info.title, r.stats.pretty());
        results.push(r);
    }
    if results.len() > 1 {
        outln!("{}", table(&results));
    }
    if let Some(path) = args
        .save_results
        .as_ref()
        .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("zip")))
    {
        // evo's own format (evo_res reads it): one result per zip.
        let [r] = results.as_slice() else {
            bail!(
                "--save_results {}: a .zip holds one result, as evo's; give one estimate or a \
                 .json file",
                path.display()
            );
        };
        write(path, &super::zip::zip(r).context("encoding the results")?)?;
    } else if let Some(path) = &args.save_results {
        let json = if results.len() == 1 {
            serde_json::to_string_pretty(&results[0])
        } else {
            serde_json::to_string_pretty(&results)
        }
        .context("encoding the results")?;
        write(path, (json + "\n").as_bytes())?;
    }
    if let Some(path) = &args.save_plot {
        let svg = super::plot::svg(&results, args.plot_mode).context("drawing the plot")?;
        write(path, svg.as_bytes())?;
    }
    if let Some(path) = &args.save_table {
        write(path, csv_table(&results).as_bytes())?;
    }
    Ok(())
}

fn write(path: &Path, bytes: &[u8]) -> Result<()> {
    crate::fsio::write_atomic(path, bytes).with_context(|| format!("writing {}", path.display()))
}

/// evo_res's table: one row per estimate, the statistics as columns.
pub fn table(results: &[EvoResult]) -> String {
    let labels: Vec<String> = results.iter().map(EvoResult::label).collect();
    let w = labels.iter().map(String::len).max().unwrap_or(0).max(8);
    let mut s = format!("{:w$}", "");
    for (n, _) in results[0].stats.named() {
        s.push_str(&format!(" {n:>12}"));
    }
    s.push('\n');
    for (l, r) in labels.iter().zip(results) {
        s.push_str(&format!("{l:w$}"));
        for (_, v) in r.stats.named() {
            s.push_str(&format!(" {:>12}", format_g6(v)));
        }
        s.push('\n');
    }
    s
}

/// Six significant digits, as pandas prints a table.
fn format_g6(v: f64) -> String {
    if v == 0.0 || (1e-4..1e6).contains(&v.abs()) {
        let digits = if v == 0.0 {
            5
        } else {
            (5 - v.abs().log10().floor() as i32).max(0) as usize
        };
        format!("{v:.digits$}")
    } else {
        format!("{v:.5e}")
    }
}

/// evo_res `--save_table` CSV: `,rmse,mean,median,std,min,max,sse`, a row per estimate
/// (values with full precision).
pub fn csv_table(results: &[EvoResult]) -> String {
    let mut s = String::new();
    for (n, _) in results.first().map(|r| r.stats.named()).unwrap_or_default() {
        s.push(',');
        s.push_str(n);
    }
    s.push('\n');
    for r in results {
        s.push_str(&r.label().replace(',', "_"));
        for (_, v) in r.stats.named() {
            s.push_str(&format!(",{v:?}"));
        }
        s.push('\n');
    }
    s
}
