//! `vinebench score ape|rpe`: evo 1.38.1's `evo_ape` / `evo_rpe` on the files and options
//! people use, with evo's numbers (checked against evo itself on evo's own test data by
//! `scripts/evo_check.sh`).
//!
//! The pipeline is evo's: read ([`read`]), associate by stamps ([`sync`]; KITTI files
//! without times are compared pose by pose), align the estimate (SE(3) `-a`, Sim(3)
//! `-as`, scale only `-s`, from the first `--n_to_align` poses, or `--align_origin`),
//! compute the error of each pose (APE) or pose pair (RPE, pairs from [`pairs`]) for the
//! pose relation (`-r`), then the statistics. Rotation arithmetic follows evo exactly
//! ([`lie`]). This is separate from the run's own scoring ([`crate::scoring::metrics`]),
//! which streams long trajectories from disk and gives the same translation numbers.

pub mod bag;
pub mod cli;
pub mod lie;
pub mod pairs;
pub mod plot;
pub mod read;
pub mod sync;
pub mod tf;
pub mod zip;

use lie::Pose;
use pairs::DeltaUnit;
use serde::Serialize;
use std::fmt;

/// A trajectory file format (evo's subcommands `tum`, `kitti`, `euroc`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// `t x y z qx qy qz qw`.
    Tum,
    /// 3×4 `[R|t]` per line, no stamps (unless a times file is given).
    Kitti,
    /// EuRoC ground-truth CSV.
    Euroc,
    /// A pose topic of a ROS 2 recording (MCAP).
    Mcap,
}

impl Format {
    /// The subcommand name.
    pub fn name(self) -> &'static str {
        match self {
            Format::Tum => "tum",
            Format::Kitti => "kitti",
            Format::Euroc => "euroc",
            Format::Mcap => "bag2",
        }
    }
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Format::Tum => "TUM",
            Format::Kitti => "KITTI",
            Format::Euroc => "EuRoC CSV",
            Format::Mcap => "ROS 2 MCAP",
        })
    }
}

/// A trajectory as read: poses in file order, stamps in seconds (`None`: a KITTI path).
#[derive(Clone, Debug)]
pub struct Traj {
    /// The file as named on the command line (evo's trajectory name).
    pub name: String,
    /// How it was read.
    pub format: Format,
    /// Stamps, s, in file order (may repeat or go backwards, as evo allows).
    pub stamps: Option<Vec<f64>>,
    /// Poses.
    pub poses: Vec<Pose>,
}

/// evo's pose relations (`-r/--pose_relation`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize)]
pub enum PoseRelation {
    /// `‖E − I‖` (Frobenius) of the whole 4×4 error.
    #[value(name = "full")]
    Full,
    /// Distance between the positions, m.
    #[value(name = "trans_part")]
    TransPart,
    /// `‖R_E − I‖` (Frobenius) of the rotation error.
    #[value(name = "rot_part")]
    RotPart,
    /// Rotation angle of the error, degrees.
    #[value(name = "angle_deg")]
    AngleDeg,
    /// Rotation angle of the error, radians.
    #[value(name = "angle_rad")]
    AngleRad,
    /// APE: as `trans_part`; RPE: the difference of the pair's straight-line distances.
    #[value(name = "point_distance")]
    PointDistance,
    /// RPE only: `point_distance` relative to the reference's distance, %.
    #[value(name = "point_distance_error_ratio")]
    PointDistanceErrorRatio,
}

impl PoseRelation {
    /// evo's description (in titles).
    pub fn evo_value(self) -> &'static str {
        match self {
            PoseRelation::Full => "full transformation",
            PoseRelation::TransPart => "translation part",
            PoseRelation::RotPart => "rotation part",
            PoseRelation::AngleDeg => "rotation angle in degrees",
            PoseRelation::AngleRad => "rotation angle in radians",
            PoseRelation::PointDistance => "point distance",
            PoseRelation::PointDistanceErrorRatio => "point distance error ratio",
        }
    }
    /// evo's unit of the errors.
    pub fn unit(self) -> &'static str {
        match self {
            PoseRelation::TransPart | PoseRelation::PointDistance => "m",
            PoseRelation::Full | PoseRelation::RotPart => "unit-less",
            PoseRelation::AngleDeg => "deg",
            PoseRelation::AngleRad => "rad",
            PoseRelation::PointDistanceErrorRatio => "%",
        }
    }
}

/// What `ape` and `rpe` share (evo's options of the same names).
#[derive(Clone, Debug)]
pub struct Options {
    /// `--t_max_diff`, s.
    pub t_max_diff: f64,
    /// `--t_offset`, s (added to the estimate's stamps for association).
    pub t_offset: f64,
    /// `-a/--align`: SE(3) Umeyama (Sim(3) with `correct_scale`).
    pub align: bool,
    /// `-s/--correct_scale`: with `align` Sim(3); alone, only the scale is corrected.
    pub correct_scale: bool,
    /// `--n_to_align`: the first N poses determine the alignment (`None`: all).
    pub n_to_align: Option<usize>,
    /// `--align_origin`: the estimate's first pose moved onto the reference's.
    pub align_origin: bool,
    /// `-r/--pose_relation`.
    pub relation: PoseRelation,
}

/// What only `rpe` has.
#[derive(Clone, Debug)]
pub struct RpeOptions {
    /// `-d/--delta` (`None`: evo's default, the integer 1).
    pub delta: Option<f64>,
    /// `-u/--delta_unit`.
    pub delta_unit: DeltaUnit,
    /// `-t/--delta_tol`, relative.
    pub delta_tol: f64,
    /// `--all_pairs`.
    pub all_pairs: bool,
    /// `--pairs_from_reference`.
    pub pairs_from_reference: bool,
}

/// Why a score could not be computed (evo stops with the same reasons).
#[derive(Debug, thiserror::Error)]
pub enum EvoError {
    /// No stamps matched.
    #[error(
        "found no matching timestamps between {reference} and {estimate} with max. time diff \
         {max_diff} (s) and time offset {offset} (s)"
    )]
    NoMatches {
        /// Reference name.
        reference: String,
        /// Estimate name.
        estimate: String,
        /// `--t_max_diff`.
        max_diff: f64,
        /// `--t_offset`.
        offset: f64,
    },
    /// Trajectories without stamps of different lengths.
    #[error(
        "{reference} has {n_ref} poses and {estimate} {n_est}: trajectories without stamps \
         (KITTI) are compared pose by pose and must have as many (give both times files to \
         associate them by stamps)"
    )]
    Lengths {
        /// Reference name.
        reference: String,
        /// Its poses.
        n_ref: usize,
        /// Estimate name.
        estimate: String,
        /// Its poses.
        n_est: usize,
    },
    /// One has stamps, the other not.
    #[error("{0} has stamps and the other trajectory has none: give both or neither times file")]
    MixedStamps(String),
    /// `--align` with `--align_origin`.
    #[error("--align and --align_origin can't be used together (as in evo)")]
    AlignBoth,
    /// A relation only RPE has.
    #[error("pose relation point_distance_error_ratio is RPE only")]
    RpeOnlyRelation,
    /// The alignment failed.
    #[error("alignment: {0}")]
    Align(#[from] crate::scoring::align::AlignError),
    /// A rotation angle failed.
    #[error("{what}: {source}")]
    Angle {
        /// Which pose or pair.
        what: String,
        /// Why.
        source: lie::AngleError,
    },
    /// The RPE pairs.
    #[error(transparent)]
    Pairs(#[from] pairs::PairsError),
    /// No RPE pair.
    #[error(
        "delta = {delta} ({unit}) produced an empty index list - try lower values or a less \
         strict tolerance"
    )]
    NoPairs {
        /// The delta as evo prints it.
        delta: String,
        /// Its unit.
        unit: &'static str,
    },
}

/// evo's statistics of an error array, in evo's order.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Stats {
    /// Root mean square.
    pub rmse: f64,
    /// Mean.
    pub mean: f64,
    /// Median (mean of the middle two for an even count).
    pub median: f64,
    /// Population standard deviation.
    pub std: f64,
    /// Minimum.
    pub min: f64,
    /// Maximum.
    pub max: f64,
    /// Sum of squares.
    pub sse: f64,
}

impl Stats {
    /// The statistics of a non-empty error array (those of the run's scoring,
    /// [`crate::scoring::metrics::Stats`], in evo's keys).
    pub fn of(e: &[f64]) -> Option<Stats> {
        let s = crate::scoring::metrics::Stats::from_errors(e)?;
        Some(Stats {
            rmse: s.rmse,
            mean: s.mean,
            median: s.median,
            std: s.std,
            min: s.min,
            max: s.max,
            sse: s.sse,
        })
    }

    /// `(name, value)` in evo's order.
    pub fn named(&self) -> [(&'static str, f64); 7] {
        [
            ("rmse", self.rmse),
            ("mean", self.mean),
            ("median", self.median),
            ("std", self.std),
            ("min", self.min),
            ("max", self.max),
            ("sse", self.sse),
        ]
    }

    /// evo's console block: the statistics in alphabetical order, `{name:>10}\t{value:.6f}`.
    pub fn pretty(&self) -> String {
        let mut named = self.named();
        named.sort_by_key(|(n, _)| *n);
        named
            .iter()
            .map(|(n, v)| format!("{n:>10}\t{v:.6}\n"))
            .collect()
    }
}

/// evo's result of one estimate (what `--save_results` holds).
#[derive(Clone, Debug, Serialize)]
pub struct EvoResult {
    /// evo's `info`: title, ref_name, est_name, label.
    pub info: Info,
    /// The statistics.
    pub stats: Stats,
    /// Per-error arrays (evo's `np_arrays`).
    pub np_arrays: Arrays,
    /// What association left out, and other notes (not in evo's results).
    pub notes: Vec<String>,
    /// Positions for the plot (not saved).
    #[serde(skip)]
    pub plot: PlotData,
}

impl EvoResult {
    /// The result's name in tables and plots: the estimate file's name (evo_res uses the
    /// basename), or the topic.
    pub fn label(&self) -> String {
        std::path::Path::new(&self.info.est_name)
            .file_name()
            .map_or_else(
                || self.info.est_name.clone(),
                |f| f.to_string_lossy().into_owned(),
            )
    }
}

/// What the plot draws of a result.
#[derive(Clone, Debug, Default)]
pub struct PlotData {
    /// The associated reference positions.
    pub reference: Vec<nalgebra::Vector3<f64>>,
    /// The (aligned) estimate position of each error (RPE: the pair's second pose).
    pub estimate: Vec<nalgebra::Vector3<f64>>,
}

/// evo's `info.json`.
#[derive(Clone, Debug, Serialize)]
pub struct Info {
    /// The title (metric, relation, unit, delta, alignment).
    pub title: String,
    /// The reference's name.
    pub ref_name: String,
    /// The estimate's name.
    pub est_name: String,
    /// `APE (m)`, `RPE (deg)`, ...
    pub label: String,
}

/// evo's arrays: the errors, and for trajectories with stamps where they were measured.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Arrays {
    /// The error of each pose (APE) or pair (RPE).
    pub error_array: Vec<f64>,
    /// Seconds from the estimate's first (associated) stamp.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub seconds_from_start: Option<Vec<f64>>,
    /// The estimate's stamps, s.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub timestamps: Option<Vec<f64>>,
    /// The reference's path length from the start, m.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub distances_from_start: Option<Vec<f64>>,
    /// The (aligned) estimate's path length from the start, m.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub distances: Option<Vec<f64>>,
    /// The alignment applied, a 4×4 `[[s·R, t], [0, 1]]` row by row.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub alignment_transformation_sim3: Option<[[f64; 4]; 4]>,
}

/// The associated, aligned pair of trajectories.
struct Prepared {
    reference: Vec<Pose>,
    estimate: Vec<Pose>,
    /// The estimate's stamps of the associated poses.
    stamps: Option<Vec<f64>>,
    alignment: Option<Pose>,
    notes: Vec<String>,
}

/// Associates and aligns as evo does before its metrics.
fn prepare(reference: &Traj, estimate: &Traj, o: &Options) -> Result<Prepared, EvoError> {
    if o.align && o.align_origin {
        return Err(EvoError::AlignBoth);
    }
    let mut notes = Vec::new();
    let (r, mut e, stamps) = match (&reference.stamps, &estimate.stamps) {
        (Some(rs), Some(es)) => {
            let a = sync::associate(rs, es, o.t_max_diff, o.t_offset);
            if a.reference.is_empty() {
                return Err(EvoError::NoMatches {
                    reference: reference.name.clone(),
                    estimate: estimate.name.clone(),
                    max_diff: o.t_max_diff,
                    offset: o.t_offset,
                });
            }
            for (traj, stamps, used) in [(reference, rs, &a.reference), (estimate, es, &a.estimate)]
            {
                let mut distinct = used.clone();
                distinct.sort_unstable();
                distinct.dedup();
                let mut dup = 0;
                let mut sorted = stamps.clone();
                sorted.sort_by(f64::total_cmp);
                for w in sorted.windows(2) {
                    if w[0] == w[1] {
                        dup += 1;
                    }
                }
                let unused = stamps.len() - distinct.len();
                let mut n = format!(
                    "{}: {} of {} poses associated",
                    traj.name,
                    distinct.len(),
                    stamps.len()
                );
                if unused > 0 {
                    n.push_str(&format!(
                        " ({unused} left out: no stamp within --t_max_diff)"
                    ));
                }
                if dup > 0 {
                    n.push_str(&format!(
                        "; {dup} repeated stamp(s), kept as evo keeps them (the nearest of a run \
                         is matched by evo's rule, the others left out)"
                    ));
                }
                if distinct.len() < used.len() {
                    n.push_str(&format!(
                        "; {} pose(s) matched more than once (evo's association is not \
                         one-to-one)",
                        used.len() - distinct.len()
                    ));
                }
                notes.push(n);
            }
            if a.unsorted {
                notes.push("Timestamps aren't sorted, using slower linear matching.".into());
            }
            let r: Vec<Pose> = a.reference.iter().map(|&i| reference.poses[i]).collect();
            let e: Vec<Pose> = a.estimate.iter().map(|&i| estimate.poses[i]).collect();
            let st: Vec<f64> = a.estimate.iter().map(|&i| es[i]).collect();
            (r, e, Some(st))
        }
        (None, None) => {
            if reference.poses.len() != estimate.poses.len() {
                return Err(EvoError::Lengths {
                    reference: reference.name.clone(),
                    n_ref: reference.poses.len(),
                    estimate: estimate.name.clone(),
                    n_est: estimate.poses.len(),
                });
            }
            (reference.poses.clone(), estimate.poses.clone(), None)
        }
        (Some(_), None) => return Err(EvoError::MixedStamps(reference.name.clone())),
        (None, Some(_)) => return Err(EvoError::MixedStamps(estimate.name.clone())),
    };
    let mut alignment = None;
    if o.align || o.correct_scale {
        let n = o.n_to_align.unwrap_or(usize::MAX).min(e.len());
        let src: Vec<_> = e[..n].iter().map(lie::translation).collect();
        let dst: Vec<_> = r[..n].iter().map(lie::translation).collect();
        let u = crate::scoring::align::umeyama(&src, &dst, o.correct_scale)?;
        let rot = *u.rotation.matrix();
        let t = lie::se3(&rot, &u.translation);
        if o.correct_scale {
            for p in &mut e {
                let scaled = lie::translation(p) * u.scale;
                p.fixed_view_mut::<3, 1>(0, 3).copy_from(&scaled);
            }
        }
        if o.align {
            for p in &mut e {
                *p = t * *p;
            }
        }
        let mut sim3 = t;
        sim3.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(rot * u.scale));
        alignment = Some(sim3);
    }
    if o.align_origin {
        let to_ref_origin = r[0] * lie::se3_inverse(&e[0]);
        for p in &mut e {
            *p = to_ref_origin * *p;
        }
        alignment = Some(to_ref_origin);
    }
    Ok(Prepared {
        reference: r,
        estimate: e,
        stamps,
        alignment,
        notes,
    })
}

/// evo's title suffixes for the alignment.
fn alignment_title(o: &Options) -> String {
    let mut t = String::new();
    let only_scale = o.correct_scale && !o.align;
    if o.align && !o.correct_scale {
        t.push_str("\n(with SE(3) Umeyama alignment)");
    } else if o.align && o.correct_scale {
        t.push_str("\n(with Sim(3) Umeyama alignment)");
    } else if only_scale {
        t.push_str("\n(scale corrected)");
    } else if !o.align_origin {
        t.push_str("\n(not aligned)");
    }
    if let (true, Some(n)) = (o.align || o.correct_scale, o.n_to_align) {
        t.push_str(&format!(" (aligned poses: {n})"));
    }
    if o.align_origin {
        t.push_str("\n(with origin alignment)");
    }
    t
}

/// The error of pose relation `rel` for an error pose `e` (not the distance relations).
fn relation_error(rel: PoseRelation, e: &Pose, what: impl Fn() -> String) -> Result<f64, EvoError> {
    let angle = |e: &Pose| {
        lie::rotation_angle(&lie::rotation(e)).map_err(|source| EvoError::Angle {
            what: what(),
            source,
        })
    };
    Ok(match rel {
        PoseRelation::Full => (e - Pose::identity()).norm(),
        PoseRelation::RotPart => (lie::rotation(e) - nalgebra::Matrix3::identity()).norm(),
        PoseRelation::AngleRad => angle(e)?.abs(),
        PoseRelation::AngleDeg => angle(e)?.abs().to_degrees(),
        PoseRelation::TransPart | PoseRelation::PointDistance => lie::translation(e).norm(),
        PoseRelation::PointDistanceErrorRatio => return Err(EvoError::RpeOnlyRelation),
    })
}

/// Accumulated straight-line distances along `poses`.
fn accumulated(poses: &[Pose]) -> Vec<f64> {
    let mut out = Vec::with_capacity(poses.len());
    let mut acc = 0.0;
    out.push(0.0);
    for w in poses.windows(2) {
        acc += (lie::translation(&w[0]) - lie::translation(&w[1])).norm();
        out.push(acc);
    }
    out
}

fn matrix_rows(m: &Pose) -> [[f64; 4]; 4] {
    let mut out = [[0.0; 4]; 4];
    for (i, row) in out.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = m[(i, j)];
        }
    }
    out
}

/// evo_ape.
pub fn ape(reference: &Traj, estimate: &Traj, o: &Options) -> Result<EvoResult, EvoError> {
    if o.relation == PoseRelation::PointDistanceErrorRatio {
        return Err(EvoError::RpeOnlyRelation);
    }
    let p = prepare(reference, estimate, o)?;
    let mut error = Vec::with_capacity(p.estimate.len());
    for (k, (r, e)) in p.reference.iter().zip(&p.estimate).enumerate() {
        error.push(match o.relation {
            PoseRelation::TransPart | PoseRelation::PointDistance => {
                (lie::translation(e) - lie::translation(r)).norm()
            }
            rel => relation_error(rel, &lie::relative_se3(e, r), || {
                format!("APE of associated pose {k}")
            })?,
        });
    }
    let mut arrays = Arrays::default();
    if let Some(st) = &p.stamps {
        let t0 = st[0];
        arrays.seconds_from_start = Some(st.iter().map(|t| t - t0).collect());
        arrays.timestamps = Some(st.clone());
        arrays.distances_from_start = Some(accumulated(&p.reference));
        arrays.distances = Some(accumulated(&p.estimate));
    }
    arrays.alignment_transformation_sim3 = p.alignment.as_ref().map(matrix_rows);
    let stats = Stats::of(&error).expect("association gave at least one pair");
    arrays.error_array = error;
    let plot = PlotData {
        reference: p.reference.iter().map(lie::translation).collect(),
        estimate: p.estimate.iter().map(lie::translation).collect(),
    };
    let title = format!(
        "APE w.r.t. {} ({}){}",
        o.relation.evo_value(),
        o.relation.unit(),
        alignment_title(o)
    );
    Ok(EvoResult {
        info: Info {
            title,
            ref_name: reference.name.clone(),
            est_name: estimate.name.clone(),
            label: format!("APE ({})", o.relation.unit()),
        },
        stats,
        np_arrays: arrays,
        notes: p.notes,
        plot,
    })
}

/// evo_rpe.
pub fn rpe(
    reference: &Traj,
    estimate: &Traj,
    o: &Options,
    r: &RpeOptions,
) -> Result<EvoResult, EvoError> {
    let p = prepare(reference, estimate, o)?;
    let mut notes = p.notes.clone();
    let delta = r.delta.unwrap_or(1.0);
    let delta_text = match (r.delta_unit, r.delta) {
        (DeltaUnit::Frames, _) | (_, None) => format!("{}", delta as i64),
        (_, Some(d)) => format!("{d:?}"),
    };
    let on = if r.pairs_from_reference {
        &p.reference
    } else {
        &p.estimate
    };
    let mut ids = pairs::id_pairs(on, delta, r.delta_unit, r.delta_tol, r.all_pairs)?;
    if ids.is_empty() {
        return Err(EvoError::NoPairs {
            delta: delta_text,
            unit: r.delta_unit.evo_name(),
        });
    }
    let t = |v: &Vec<Pose>, i: usize| lie::translation(&v[i]);
    let mut error = Vec::with_capacity(ids.len());
    match o.relation {
        PoseRelation::PointDistance | PoseRelation::PointDistanceErrorRatio => {
            let mut kept = Vec::with_capacity(ids.len());
            for &(i, j) in &ids {
                let dr = (t(&p.reference, i) - t(&p.reference, j)).norm();
                let de = (t(&p.estimate, i) - t(&p.estimate, j)).norm();
                let e = (dr - de).abs();
                if o.relation == PoseRelation::PointDistance {
                    error.push(e);
                    kept.push((i, j));
                } else if dr != 0.0 {
                    error.push(e / dr * 100.0);
                    kept.push((i, j));
                }
            }
            if kept.len() < ids.len() {
                notes.push(format!(
                    "Ignoring {} zero divisions in ratio calculations.",
                    ids.len() - kept.len()
                ));
            }
            ids = kept;
        }
        rel => {
            for &(i, j) in &ids {
                let q_rel = lie::relative_se3(&p.reference[i], &p.reference[j]);
                let p_rel = lie::relative_se3(&p.estimate[i], &p.estimate[j]);
                let e = lie::relative_se3(&q_rel, &p_rel);
                error.push(relation_error(rel, &e, || {
                    format!("RPE of associated poses {i} and {j}")
                })?);
            }
        }
    }
    if ids.is_empty() {
        return Err(EvoError::NoPairs {
            delta: delta_text,
            unit: r.delta_unit.evo_name(),
        });
    }
    let mut arrays = Arrays::default();
    if let Some(st) = &p.stamps {
        // evo reduces both trajectories to [0, j_1, j_2, ...] and measures along them.
        let reduced: Vec<usize> = std::iter::once(0)
            .chain(ids.iter().map(|&(_, j)| j))
            .collect();
        let pick = |v: &Vec<Pose>| reduced.iter().map(|&k| v[k]).collect::<Vec<Pose>>();
        let t0 = st[0];
        arrays.seconds_from_start = Some(ids.iter().map(|&(_, j)| st[j] - t0).collect());
        arrays.timestamps = Some(ids.iter().map(|&(_, j)| st[j]).collect());
        arrays.distances_from_start = Some(accumulated(&pick(&p.reference))[1..].to_vec());
        arrays.distances = Some(accumulated(&pick(&p.estimate))[1..].to_vec());
    }
    arrays.alignment_transformation_sim3 = p.alignment.as_ref().map(matrix_rows);
    let stats = Stats::of(&error).expect("at least one pair");
    arrays.error_array = error;
    let plot = PlotData {
        reference: p.reference.iter().map(lie::translation).collect(),
        estimate: ids
            .iter()
            .map(|&(_, j)| lie::translation(&p.estimate[j]))
            .collect(),
    };
    let mut title = format!(
        "RPE w.r.t. {} ({})\nfor delta = {} ({})",
        o.relation.evo_value(),
        o.relation.unit(),
        delta_text,
        r.delta_unit.evo_name()
    );
    title.push_str(if r.all_pairs {
        " using all pairs"
    } else {
        " using consecutive pairs"
    });
    title.push_str(&alignment_title(o));
    Ok(EvoResult {
        info: Info {
            title,
            ref_name: reference.name.clone(),
            est_name: estimate.name.clone(),
            label: format!("RPE ({})", o.relation.unit()),
        },
        stats,
        np_arrays: arrays,
        notes,
        plot,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector3};

    fn traj(poses: Vec<Pose>) -> Traj {
        Traj {
            name: "t".into(),
            format: Format::Tum,
            stamps: Some((0..poses.len()).map(|i| i as f64 * 0.1).collect()),
            poses,
        }
    }

    fn pose(yaw: f64, t: [f64; 3]) -> Pose {
        lie::se3(
            Rotation3::from_euler_angles(0.1 * yaw, -0.05, yaw).matrix(),
            &Vector3::from(t),
        )
    }

    /// A curvy reference trajectory.
    fn reference() -> Vec<Pose> {
        (0..50)
            .map(|i| {
                let s = i as f64 * 0.2;
                pose(0.3 * s, [s, (0.5 * s).sin() * 2.0, 0.1 * s])
            })
            .collect()
    }

    fn options(relation: PoseRelation) -> Options {
        Options {
            t_max_diff: 0.01,
            t_offset: 0.0,
            align: false,
            correct_scale: false,
            n_to_align: None,
            align_origin: false,
            relation,
        }
    }

    #[test]
    fn each_ape_relation_against_its_closed_form() {
        // est_i = ref_i · D with D a rotation θ about z and a translation d: the error
        // pose is E = est⁻¹·ref = D⁻¹ for every pose.
        let (theta, d) = (0.3_f64, Vector3::new(0.2, -0.1, 0.05));
        let delta = lie::se3(
            Rotation3::from_axis_angle(&Vector3::z_axis(), theta).matrix(),
            &d,
        );
        let r = reference();
        let e: Vec<Pose> = r.iter().map(|p| p * delta).collect();
        let (r, e) = (traj(r), traj(e));
        let rot_part = (4.0 * (1.0 - theta.cos())).sqrt();
        for (rel, expected) in [
            (PoseRelation::TransPart, d.norm()),
            (PoseRelation::PointDistance, d.norm()),
            (PoseRelation::AngleRad, theta),
            (PoseRelation::AngleDeg, theta.to_degrees()),
            (PoseRelation::RotPart, rot_part),
            (
                PoseRelation::Full,
                (rot_part * rot_part + d.norm_squared()).sqrt(),
            ),
        ] {
            let res = ape(&r, &e, &options(rel)).unwrap();
            assert_eq!(res.np_arrays.error_array.len(), 50);
            for v in [res.stats.min, res.stats.max, res.stats.rmse] {
                assert!((v - expected).abs() < 1e-12, "{rel:?}: {v} vs {expected}");
            }
            assert!(res.stats.std < 1e-12);
            assert!((res.stats.sse - 50.0 * expected * expected).abs() < 1e-9);
        }
        assert!(ape(&r, &e, &options(PoseRelation::PointDistanceErrorRatio)).is_err());
    }

    #[test]
    fn alignment_recovers_what_it_models_and_no_more() {
        // The estimate in another frame (a rigid transform T) and scaled by 2 about the
        // origin: Sim(3) alignment removes both, SE(3) not the scale.
        let t = lie::se3(
            Rotation3::from_euler_angles(0.2, 0.1, 1.0).matrix(),
            &Vector3::new(5.0, -3.0, 1.0),
        );
        let r = reference();
        let e: Vec<Pose> = r
            .iter()
            .map(|p| {
                let mut q = t * p;
                let scaled = lie::translation(&q) * 2.0;
                q.fixed_view_mut::<3, 1>(0, 3).copy_from(&scaled);
                q
            })
            .collect();
        let (r, e) = (traj(r), traj(e));
        let mut o = options(PoseRelation::TransPart);
        o.align = true;
        o.correct_scale = true;
        let sim3 = ape(&r, &e, &o).unwrap();
        assert!(sim3.stats.max < 1e-9, "{:?}", sim3.stats);
        // Rotations are aligned too (the alignment's rotation is the inverse of T's).
        o.relation = PoseRelation::AngleDeg;
        assert!(ape(&r, &e, &o).unwrap().stats.max < 1e-6);
        o.relation = PoseRelation::TransPart;
        o.correct_scale = false;
        assert!(ape(&r, &e, &o).unwrap().stats.rmse > 0.1);
        // Only the first 10 poses for the alignment: still exact on noise-free data.
        o.correct_scale = true;
        o.n_to_align = Some(10);
        assert!(ape(&r, &e, &o).unwrap().stats.max < 1e-9);
        // Origin alignment: the first pose's error is zero, the rest is not.
        let mut o = options(PoseRelation::TransPart);
        o.align_origin = true;
        let res = ape(&r, &e, &o).unwrap();
        assert!(res.np_arrays.error_array[0] < 1e-12);
        assert!(res.stats.max > 1.0);
        o.align = true;
        assert!(matches!(ape(&r, &e, &o), Err(EvoError::AlignBoth)));
    }

    #[test]
    fn rpe_relations_against_closed_forms() {
        // Steps of 1 m along x; the estimate's steps are 1.1 m and turn by ε more each.
        let eps = 0.01_f64;
        let r: Vec<Pose> = (0..20).map(|i| pose(0.0, [i as f64, 0.0, 0.0])).collect();
        let mut e = vec![Pose::identity()];
        for _ in 1..20 {
            let step = lie::se3(
                Rotation3::from_axis_angle(&Vector3::z_axis(), eps).matrix(),
                &Vector3::new(1.1, 0.0, 0.0),
            );
            let last = *e.last().unwrap();
            e.push(last * step);
        }
        let r: Vec<Pose> = r
            .iter()
            .map(|p| lie::se3(&nalgebra::Matrix3::identity(), &lie::translation(p)))
            .collect();
        let (r, e) = (traj(r), traj(e));
        let rpe_o = RpeOptions {
            delta: None,
            delta_unit: DeltaUnit::Frames,
            delta_tol: 0.1,
            all_pairs: false,
            pairs_from_reference: false,
        };
        // E = Q_rel⁻¹·P_rel = [Rz(ε), (0.1, 0, 0)].
        for (rel, expected) in [
            (PoseRelation::TransPart, 0.1),
            (PoseRelation::AngleRad, eps),
            (PoseRelation::PointDistance, 0.1),
            (PoseRelation::PointDistanceErrorRatio, 10.0),
        ] {
            let res = rpe(&r, &e, &options(rel), &rpe_o).unwrap();
            assert_eq!(res.np_arrays.error_array.len(), 19);
            assert!(
                (res.stats.min - expected).abs() < 1e-9 && (res.stats.max - expected).abs() < 1e-9,
                "{rel:?}: {:?}",
                res.stats
            );
        }
        // Every 2 frames: the turn and the extra length compose.
        let two = RpeOptions {
            delta: Some(2.0),
            ..rpe_o.clone()
        };
        let res = rpe(&r, &e, &options(PoseRelation::AngleDeg), &two).unwrap();
        assert_eq!(res.np_arrays.error_array.len(), 9);
        assert!((res.stats.mean - (2.0 * eps).to_degrees()).abs() < 1e-9);
        assert!(
            res.info
                .title
                .contains("for delta = 2 (frames) using consecutive pairs")
        );
        // A global transform of the estimate changes no relative error.
        let t = lie::se3(
            Rotation3::from_euler_angles(0.3, -0.2, 2.0).matrix(),
            &Vector3::new(10.0, 20.0, -5.0),
        );
        let moved = Traj {
            poses: e.poses.iter().map(|p| t * p).collect(),
            ..e.clone()
        };
        let a = rpe(&r, &e, &options(PoseRelation::Full), &rpe_o).unwrap();
        let b = rpe(&r, &moved, &options(PoseRelation::Full), &rpe_o).unwrap();
        assert!((a.stats.rmse - b.stats.rmse).abs() < 1e-9);
    }

    #[test]
    fn stats_are_evos() {
        let s = Stats::of(&[1.0, 2.0, 3.0, 4.0]).unwrap();
        assert_eq!(
            (s.mean, s.median, s.min, s.max, s.sse),
            (2.5, 2.5, 1.0, 4.0, 30.0)
        );
        assert!((s.std - 1.25f64.sqrt()).abs() < 1e-15);
        assert!((s.rmse - 7.5f64.sqrt()).abs() < 1e-15);
        assert!(
            s.pretty()
                .starts_with("       max\t4.000000\n      mean\t2.500000\n")
        );
        assert!(Stats::of(&[]).is_none());
    }

    #[test]
    fn kitti_paths_are_compared_pose_by_pose_and_need_as_many() {
        let r = Traj {
            stamps: None,
            format: Format::Kitti,
            ..traj(reference())
        };
        let mut e = r.clone();
        e.poses.pop();
        let err = ape(&r, &e, &options(PoseRelation::TransPart)).unwrap_err();
        assert!(err.to_string().contains("has 50 poses"), "{err}");
        let res = ape(&r, &r, &options(PoseRelation::TransPart)).unwrap();
        assert_eq!(res.stats.max, 0.0);
        assert!(res.np_arrays.timestamps.is_none());
    }
}
