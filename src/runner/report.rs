//! The run report: `report.json` (for machines), `report.md` with plots (for people).
//!
//! Everything in the report is a deterministic function of the scenario: wall-clock
//! timing goes to `timing.json` instead, so two runs of a scenario give byte-identical
//! reports.

use super::outcome::{RobotReport, RunError, Simulation};
use crate::scenario::LoadedScenario;
use crate::scoring::Poses;
use crate::scoring::expect::{ExpectationResult, ROBOT_METRICS, ROBOT_SOURCE};
use crate::scoring::{self, ScoringParams, SourceScore, metrics};
use rayon::prelude::*;
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;
use vinebench_msgs::Nanos;
use vinebench_sim::physics::Obstacle;

/// Collisions listed in `report.md` (all of them are in `report.json`).
pub const MAX_COLLISION_ROWS: usize = 50;

/// The report of one run.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// vinebench version that produced it.
    pub vinebench_version: &'static str,
    /// Scenario identification.
    pub scenario: ScenarioInfo,
    /// What was simulated.
    pub run: RunInfo,
    /// How the metrics were computed.
    pub scoring: ScoringParams,
    /// Closed-loop metrics of the ground truth itself (reference for Table 1; absent for
    /// a trajectory too short to have them).
    pub ground_truth: Option<metrics::LoopMetrics>,
    /// The robot's own run (the expectations' pseudo-source `robot`).
    pub robot: RobotReport,
    /// One entry per estimator, in the order of `[estimators] run`.
    pub sources: Vec<SourceReport>,
    /// One entry per mapped source, in the order of `[mapper] sources` (absent when
    /// mapping is off).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub maps: Vec<crate::runner::mapping::MapReport>,
    /// The SLAM metrics of each SLAM source (absent when `[slam]` is off).
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub slam: BTreeMap<String, BTreeMap<String, f64>>,
    /// The loop closures of each SLAM source with their ground-truth check (also in
    /// `loops.csv`).
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub loops: BTreeMap<String, crate::scoring::loops::LoopScore>,
    /// Expectation outcomes, in file order.
    pub expectations: Vec<ExpectationResult>,
    /// True when every expectation holds.
    pub passed: bool,
}

/// Scenario identification in a report.
#[derive(Clone, Debug, Serialize)]
pub struct ScenarioInfo {
    /// Name.
    pub name: String,
    /// Description.
    pub description: String,
    /// File it was loaded from.
    pub file: String,
    /// Master seed.
    pub seed: u64,
    /// SHA-256 of the generated world.
    pub world_digest: String,
}

/// Facts about the simulation.
#[derive(Clone, Debug, Serialize)]
pub struct RunInfo {
    /// UTC time of the first sample.
    pub start_time_utc: String,
    /// Simulated duration, s.
    pub duration_s: f64,
    /// Distance travelled, m.
    pub distance_m: f64,
    /// Whether the route was completed.
    pub route_completed: bool,
    /// Messages produced per topic.
    pub messages: BTreeMap<String, u64>,
    /// Messages dropped before the estimators: late beyond the re-ordering window.
    pub late_dropped: u64,
    /// Messages dropped before the estimators because a field was NaN or invalid, by
    /// `topic field`.
    pub invalid_dropped: BTreeMap<String, u64>,
    /// Fault windows, s after the start.
    pub fault_windows_s: Vec<(f64, f64)>,
}

impl RobotReport {
    /// The Markdown section (`## Robot`).
    pub fn markdown(&self) -> String {
        let mut md = String::new();
        let m = &self.metrics;
        let _ = writeln!(
            md,
            "## Robot\n\n**{}** (route {:.1} m, {:.1} m driven).\n",
            self.outcome, m.route_length_m, m.distance_m
        );
        if self.steering != "truth" {
            let _ = writeln!(
                md,
                "Closed loop: the route follower steered on **{}** (`[control] \
                 localization`); trajectories.svg shows the path it believed beside the true \
                 one, with canopy intrusions marked.\n",
                self.steering
            );
        }
        let _ = writeln!(md, "| Metric | value | meaning |\n|---|---:|---|");
        for (name, meaning) in ROBOT_METRICS {
            let value = match (*name, self.metric(name)) {
                ("collisions" | "route_completed", Some(v)) => format!("{v:.0}"),
                (_, v) => fmt_opt(v, 3),
            };
            let _ = writeln!(md, "| `{name}.robot` | {value} | {meaning} |");
        }
        if !self.comparisons.is_empty() {
            let _ = writeln!(
                md,
                "\nThe same route on other motion models (`motion.compare_with`; their paths \
                 are on trajectories.svg, their ground truth in `ground_truth_<model>.tum`):\n\n\
                 | model | completed | duration [s] | driven [m] | end gap [m] | end heading [deg] | path separation [m] |\n\
                 |---|---|---:|---:|---:|---:|---:|"
            );
            for c in &self.comparisons {
                let _ = writeln!(
                    md,
                    "| {} | {} | {:.1} | {:.1} | {:.3} | {:.2} | {:.3} |",
                    c.model,
                    if c.completed { "yes" } else { "no" },
                    c.duration_s,
                    c.distance_m,
                    c.end_gap_m,
                    c.end_heading_deg,
                    c.max_path_separation_m
                );
            }
        }
        let c = &self.clearance;
        if !c.intrusions.is_empty() {
            let _ = writeln!(
                md,
                "\nCanopy intrusions ({}, {:.1} s in all; the footprint inside a leaf wall \
                 seen from above):\n\n| from [s] | to [s] | deepest [m] | at [s] | row | where (x, y) [m] |\n\
                 |---:|---:|---:|---:|---:|---|",
                c.intrusions.len(),
                c.canopy_intrusion_s
            );
            let t0 = self.start;
            for i in c.intrusions.iter().take(MAX_COLLISION_ROWS) {
                let _ = writeln!(
                    md,
                    "| {:.2} | {:.2} | {:.3} | {:.2} | {} | ({:.2}, {:.2}) |",
                    (i.start - t0).as_secs_f64(),
                    (i.end - t0).as_secs_f64(),
                    i.max_depth_m,
                    (i.deepest_at - t0).as_secs_f64(),
                    i.row,
                    i.deepest_xy[0],
                    i.deepest_xy[1]
                );
            }
            if c.intrusions.len() > MAX_COLLISION_ROWS {
                let _ = writeln!(
                    md,
                    "\n({} more in report.json.)",
                    c.intrusions.len() - MAX_COLLISION_ROWS
                );
            }
        }
        if self.collisions.is_empty() {
            let _ = writeln!(md, "\nNo collisions.");
            return md;
        }
        let _ = writeln!(
            md,
            "\nCollisions ({}; post #: index in the world's post list):\n\n\
             | time [s] | robot link | obstacle | robot position [m] |\n|---:|---|---|---|",
            self.collisions.len()
        );
        for c in self.collisions.iter().take(MAX_COLLISION_ROWS) {
            let obstacle = match &c.obstacle {
                Obstacle::Post { row, index } => format!("post row {row} #{index}"),
                Obstacle::Trunk { row, slot } => format!("trunk row {row} slot {slot}"),
                Obstacle::Occluder { index } => format!("occluder #{index}"),
                Obstacle::Ground => "ground".to_string(),
            };
            let [x, y, z] = c.robot_position_m.map(|v| {
                // No "-0.00".
                let s = format!("{v:.2}");
                if s == "-0.00" { "0.00".to_string() } else { s }
            });
            let _ = writeln!(
                md,
                "| {:.3} | `{}` | {obstacle} | ({x}, {y}, {z}) |",
                c.time_s, c.link
            );
        }
        if self.collisions.len() > MAX_COLLISION_ROWS {
            let _ = writeln!(
                md,
                "\n… and {} more (all in `report.json`).",
                self.collisions.len() - MAX_COLLISION_ROWS
            );
        }
        md
    }
}

/// One estimator's results.
#[derive(Clone, Debug, Serialize)]
pub struct SourceReport {
    /// Source name.
    pub name: String,
    /// Number of poses it produced.
    pub poses: usize,
    /// Metrics against ground truth.
    pub score: SourceScore,
    /// Messages used by kind.
    pub used: BTreeMap<String, u64>,
    /// Messages not used, by reason.
    pub rejected: BTreeMap<String, u64>,
    /// Other counted events (`imu_gap_bridged`; the SLAM's keyframes, tracking losses).
    pub events: BTreeMap<String, u64>,
    /// Notes (initialisation and the like).
    pub notes: Vec<String>,
}

impl Report {
    /// Every scalar metric of the run that has a finite value, keyed `metric.source` as
    /// expectations name them: each estimate source's scores, the SLAM sources' metrics,
    /// each map's scores and the robot's own run (`collisions.robot`, ...).
    pub fn metrics(&self) -> BTreeMap<String, f64> {
        let mut out = BTreeMap::new();
        let mut put = |metric: &str, source: &str, v: Option<f64>| {
            if let Some(v) = v.filter(|v| v.is_finite()) {
                out.insert(format!("{metric}.{source}"), v);
            }
        };
        for s in &self.sources {
            for m in SourceScore::METRIC_NAMES {
                put(m, &s.name, s.score.metric(m));
            }
        }
        for (source, metrics) in &self.slam {
            for (m, v) in metrics {
                put(m, source, Some(*v));
            }
        }
        for map in &self.maps {
            for m in crate::scoring::map::MapScore::METRIC_NAMES {
                put(m, &map.source, map.metric(m));
            }
        }
        for (m, _) in ROBOT_METRICS {
            put(m, ROBOT_SOURCE, self.robot.metric(m));
        }
        out
    }

    /// Assembles the report of a simulation.
    pub fn new(
        sc: &LoadedScenario,
        sim: &Simulation,
        scores: Scores,
        expectations: Vec<ExpectationResult>,
    ) -> Report {
        let s = &sc.scenario;
        let Scores {
            sources,
            robot,
            maps,
            slam,
            loops,
        } = scores;
        let sources = sim
            .estimates
            .iter()
            .zip(sources)
            .map(|(e, (name, score))| {
                let stats = &e.stats;
                SourceReport {
                    name,
                    poses: e.poses.len(),
                    score,
                    used: stats.used.clone(),
                    rejected: stats.rejected.clone(),
                    events: stats.events.clone(),
                    notes: stats.notes.clone(),
                }
            })
            .collect();
        let passed = expectations.iter().all(|x| x.holds);
        Report {
            vinebench_version: env!("CARGO_PKG_VERSION"),
            scenario: ScenarioInfo {
                name: s.name.clone(),
                description: s.description.clone(),
                file: sc.file.clone(),
                seed: s.seed,
                world_digest: sim.world_digest.clone(),
            },
            run: RunInfo {
                start_time_utc: s.start_time_utc.clone(),
                duration_s: sim.duration_s,
                distance_m: sim.distance_m,
                route_completed: sim.route_completed,
                messages: sim.messages.clone(),
                late_dropped: sim.stage.late_total(),
                invalid_dropped: sim.stage.invalid_by_topic_field(),
                fault_windows_s: s.faults.gnss.iter().map(|f| (f.start_s, f.end_s)).collect(),
            },
            scoring: s.scoring.clone(),
            ground_truth: metrics::closed_loop(&sim.truth).ok(),
            robot,
            sources,
            maps,
            slam: slam.into_iter().collect(),
            loops: loops.into_iter().collect(),
            expectations,
            passed,
        }
    }

    /// The Markdown report.
    pub fn markdown(&self) -> String {
        let mut md = String::new();
        let s = &self.scenario;
        let held = self.expectations.iter().filter(|x| x.holds).count();
        let _ = writeln!(md, "# vinebench run: {}\n", s.name);
        if !s.description.is_empty() {
            let _ = writeln!(md, "{}\n", s.description);
        }
        let verdict = if self.passed { "PASS" } else { "FAIL" };
        let _ = writeln!(
            md,
            "**{verdict}**: {held} of {} expectations hold.\n",
            self.expectations.len()
        );
        let r = &self.run;
        let _ = writeln!(
            md,
            "Scenario `{}`, seed {}, start {}, {:.1} s simulated, {:.1} m driven{}. World digest `{}`.\n",
            s.file,
            s.seed,
            r.start_time_utc,
            r.duration_s,
            r.distance_m,
            if r.route_completed {
                ""
            } else {
                " (route NOT completed)"
            },
            &s.world_digest[..s.world_digest.len().min(16)]
        );
        if !r.fault_windows_s.is_empty() {
            let w: Vec<String> = r
                .fault_windows_s
                .iter()
                .map(|(a, b)| format!("{a:.0}–{b:.0} s"))
                .collect();
            let _ = writeln!(md, "GNSS fault windows: {}.\n", w.join(", "));
        }

        let _ = writeln!(md, "## Expectations\n");
        if self.expectations.is_empty() {
            let _ = writeln!(md, "None stated.\n");
        }
        for x in &self.expectations {
            let mark = if x.holds { "✅" } else { "❌" };
            let detail = match (x.lhs, x.margin) {
                (Some(l), Some(m)) => format!(
                    "{l:.4} ({} {:.4})",
                    if m >= 0.0 { "margin" } else { "off by" },
                    m.abs()
                ),
                _ => x.note.clone().unwrap_or_default(),
            };
            let _ = writeln!(md, "- {mark} `{}`: {detail}", x.text);
        }
        md.push('\n');
        md.push_str(&self.robot.markdown());
        if let Some(g) = self.robot.gnss.as_ref().filter(|g| g.epochs > 0) {
            md.push_str(&g.markdown());
        }

        let _ = writeln!(
            md,
            "\n## Closed-loop discrepancy (Table 1 of Vulpi et al. 2022)\n\n\
             Start-to-end distance in 3D (D), in the East-North plane (D_EN), in altitude (D_U), \
             and the standard deviation of the altitude along the path (σ_U).\n\n\
             | Source | D [m] | D_EN [m] | D_U [m] | σ_U [m] |\n|---|---:|---:|---:|---:|"
        );
        if let Some(g) = &self.ground_truth {
            let _ = writeln!(
                md,
                "| ground truth | {:.3} | {:.3} | {:.3} | {:.3} |",
                g.d_m, g.d_en_m, g.d_u_m, g.sigma_u_m
            );
        }
        for src in &self.sources {
            let m = |k: &str| fmt_opt(src.score.metric(k), 3);
            let _ = writeln!(
                md,
                "| {} | {} | {} | {} | {} |",
                src.name,
                m("d_m"),
                m("d_en_m"),
                m("d_u_m"),
                m("sigma_u_m")
            );
        }

        let _ = writeln!(
            md,
            "\n## Accuracy against ground truth\n\n\
             ATE as `evo_ape tum ground_truth.tum estimate_<source>.tum --t_max_diff <tol>` \
             (translation part; \"aligned\" adds `-a`), RPE as `evo_rpe ... --delta <d> --delta_unit m`.\n\n\
             | Source | poses | coverage | ATE RMSE [m] | ATE RMSE aligned [m] | ATE max [m] | RPE RMSE [m] | max error in faults [m] |\n\
             |---|---:|---:|---:|---:|---:|---:|---:|"
        );
        for src in &self.sources {
            let m = |k: &str| fmt_opt(src.score.metric(k), 4);
            let _ = writeln!(
                md,
                "| {} | {} | {} | {} | {} | {} | {} | {} |",
                src.name,
                src.poses,
                fmt_opt(src.score.metric("coverage"), 3),
                m("ate_rmse_m"),
                m("ate_rmse_aligned_m"),
                m("ate_max_m"),
                m("rpe_rmse_m"),
                m("outage_max_error_m")
            );
        }

        if !self.maps.is_empty() {
            md.push_str(&maps_markdown(&self.maps));
        }
        if !self.slam.is_empty() {
            md.push_str(&slam_markdown(&self.slam, &self.loops));
        }

        let _ = writeln!(
            md,
            "\n## Plots\n\n![Trajectories, top view](trajectories.svg)\n\n\
             ![Position error over time](errors.svg)\n\n![Altitude over time](altitude.svg)\n"
        );

        let _ = writeln!(md, "## Inputs\n\n| Topic | messages |\n|---|---:|");
        for (t, n) in &r.messages {
            let _ = writeln!(md, "| `{t}` | {n} |");
        }
        if r.late_dropped > 0 || !r.invalid_dropped.is_empty() {
            let _ = writeln!(
                md,
                "\nDropped before the estimators: {} late beyond the re-ordering window; invalid: {:?}.",
                r.late_dropped, r.invalid_dropped
            );
        }
        for src in &self.sources {
            let _ = writeln!(
                md,
                "\n**{}**: used {}; not used {}.",
                src.name,
                fmt_counts(&src.used),
                fmt_counts(&src.rejected)
            );
            if !src.events.is_empty() {
                let _ = writeln!(md, "- events: {}", fmt_counts(&src.events));
            }
            for n in &src.notes {
                let _ = writeln!(md, "- {n}");
            }
        }
        let _ = writeln!(
            md,
            "\n## Reproduce\n\n```sh\nvinebench run {file}\n# the same numbers with evo (pip install evo):\n\
             evo_ape tum ground_truth.tum estimate_eif.tum --t_max_diff {t} [-a]\n\
             evo_rpe tum ground_truth.tum estimate_eif.tum --t_max_diff {t} --delta {d} --delta_unit m{pairs}\n```\n\n\
             `scenario.resolved.toml` in this folder holds every parameter of this run.\n",
            file = s.file,
            t = self.scoring.t_max_diff_s,
            d = self.scoring.rpe_delta_m,
            pairs = if self.scoring.rpe_pairs_from_reference {
                " --pairs_from_reference"
            } else {
                ""
            },
        );
        md
    }
}

/// The `## Visual SLAM` section: one row per SLAM source.
fn slam_markdown(
    slam: &BTreeMap<String, BTreeMap<String, f64>>,
    loops: &BTreeMap<String, crate::scoring::loops::LoopScore>,
) -> String {
    let mut md = String::from(
        "\n## Visual SLAM (Kokas et al.)\n\n\
         Loops: accepted loop closures (`loops.csv`), false = true poses farther apart than \
         `scoring.loop_distance_m` (for a loop through surveyed tags: its claimed relative \
         pose that far from the true one); recall over ground-truth revisits.\n\n\
         | source | tracking losses | time lost [s] | keyframes | maps started | loops | false loops | precision | recall |\n\
         |---|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    let get = |m: &BTreeMap<String, f64>, k: &str| m.get(k).copied().unwrap_or(f64::NAN);
    let opt = |m: &BTreeMap<String, f64>, k: &str| fmt_opt(m.get(k).copied(), 2);
    for (source, m) in slam {
        let _ = writeln!(
            md,
            "| {source} | {} | {:.2} | {} | {} | {} | {} | {} | {} |",
            get(m, "tracking_losses"),
            get(m, "tracking_lost_s"),
            get(m, "keyframes"),
            get(m, "maps_started"),
            get(m, "loops"),
            get(m, "false_loops"),
            opt(m, "loop_precision"),
            opt(m, "loop_recall"),
        );
    }
    for (source, m) in slam {
        if let (Some(c), Some(r)) = (m.get("bow_candidates"), m.get("bow_rejected")) {
            let _ = writeln!(
                md,
                "\n`{source}`: bag of words reported {c} loop candidates; the geometric check \
                 rejected {r}."
            );
        }
    }
    let rows: Vec<_> = loops
        .iter()
        .flat_map(|(s, l)| l.loops.iter().map(move |x| (s, x)))
        .collect();
    if !rows.is_empty() {
        md.push_str(
            "\n| source | query stamp [ns] | matched stamp [ns] | method | tag | true distance [m] | correct | correction [m] | correction [deg] |\n\
             |---|---:|---:|---|---:|---:|---|---:|---:|\n",
        );
        for (s, l) in rows {
            let _ = writeln!(
                md,
                "| {s} | {} | {} | {} | {} | {:.3} | {} | {:.3} | {:.2} |",
                l.query_stamp.0,
                l.matched_stamp.0,
                l.method,
                l.tag_id.map(|i| i.to_string()).unwrap_or_default(),
                l.truth_distance_m,
                if l.correct_with_heading {
                    "yes"
                } else if l.correct {
                    "yes (heading off)"
                } else {
                    "**no**"
                },
                l.correction_m,
                l.correction_deg,
            );
        }
    }
    md
}

/// The `## Maps` section: one row per mapped source.
pub(crate) fn maps_markdown(maps: &[crate::runner::mapping::MapReport]) -> String {
    let mut md = String::new();
    let _ = writeln!(
        md,
        "\n## Maps (seed paper sections 4-5)\n\n\
         Each map is built from the RGB-D frames placed with one source's estimated poses, \
         and scored against the true surfaces of the render geometry: accuracy = map → truth \
         distance, completeness = truth the cameras came near → map distance (means), \
         F-score at 1/2/5 cm. Files: `map.ply` (colour, normals, GRVI, elevation), \
         `map_grvi.ply`, `map_elevation.ply`; the main map also `mesh.ply`, `mesh.obj`, \
         the Gazebo model `vinebench_map/` and `vinebench_map.mjcf.xml`.\n\n\
         | Source | folder | frames | points | vegetation | triangles | accuracy [m] | completeness [m] | chamfer [m] | F@1cm | F@2cm | F@5cm |\n\
         |---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    for m in maps {
        let v = |k: &str| fmt_opt(m.metric(k), 4);
        let st = &m.stats;
        let _ = writeln!(
            md,
            "| {} | `{}/` | {} | {} | {:.0} % | {} | {} | {} | {} | {} | {} | {} |",
            m.source,
            m.folder,
            st.frames_integrated,
            st.voxels,
            100.0 * st.vegetation_points as f64 / st.voxels.max(1) as f64,
            st.mesh_triangles,
            v("map_accuracy_m"),
            v("map_completeness_m"),
            v("map_chamfer_m"),
            fmt_opt(m.metric("map_f_score_1cm"), 3),
            fmt_opt(m.metric("map_f_score_2cm"), 3),
            fmt_opt(m.metric("map_f_score_5cm"), 3),
        );
    }
    let skipped: Vec<String> = maps
        .iter()
        .filter(|m| {
            let s = &m.stats;
            s.frames_outside_trajectory + s.frames_incomplete + s.frames_unposed > 0
        })
        .map(|m| {
            let s = &m.stats;
            format!(
                "{}: {} outside the trajectory, {} incomplete, {} without a pose in time",
                m.source, s.frames_outside_trajectory, s.frames_incomplete, s.frames_unposed
            )
        })
        .collect();
    if !skipped.is_empty() {
        let _ = writeln!(md, "\nFrames not mapped: {}.", skipped.join("; "));
    }
    md
}

fn fmt_opt(v: Option<f64>, digits: usize) -> String {
    match v {
        Some(x) if x.is_finite() => format!("{x:.digits$}"),
        _ => "–".to_string(),
    }
}

fn fmt_counts(m: &BTreeMap<String, u64>) -> String {
    if m.is_empty() {
        return "nothing".to_string();
    }
    m.iter()
        .map(|(k, v)| format!("{v} {k}"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Writes `report.json`, `report.md` and the plots into `dir`.
pub fn write(dir: &Path, sim: &Simulation, report: &Report) -> Result<(), RunError> {
    let jp = dir.join("report.json");
    let json =
        serde_json::to_string_pretty(report).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"));
    super::write_file(&jp, (json + "\n").as_bytes())?;

    let t0 = sim.truth.first().map(|s| s.0).unwrap_or(Nanos(0));
    let named: Vec<(&str, &dyn Poses)> = sim
        .estimates
        .iter()
        .map(|e| (e.name, &e.poses as &dyn Poses))
        .collect();
    // Closed loop: the steering source is the path the robot believed it drove (a
    // SLAM's in the world through its known start pose).
    let believed = format!("{} (steered on)", sim.steering);
    let moved = named
        .iter()
        .find(|(n, _)| *n == sim.steering)
        .zip(sim.steering_world_from_map)
        .map(|(&(_, poses), world_from_map)| scoring::spool::Moved {
            poses,
            world_from_map,
        });
    let top_named: Vec<(&str, &dyn Poses)> = named
        .iter()
        .map(|&(n, p)| {
            if n == sim.steering {
                (
                    believed.as_str(),
                    moved.as_ref().map_or(p, |m| m as &dyn Poses),
                )
            } else {
                (n, p)
            }
        })
        .collect();
    let marks: Vec<(f64, f64)> = sim
        .clearance
        .intrusions
        .iter()
        .map(|i| (i.deepest_xy[0], i.deepest_xy[1]))
        .collect();
    let compared: Vec<String> = sim
        .comparisons
        .iter()
        .map(|c| format!("truth ({})", c.model.name()))
        .collect();
    let top_view: Vec<(&str, &dyn Poses)> = top_named
        .iter()
        .copied()
        .chain(
            compared
                .iter()
                .zip(&sim.comparisons)
                .map(|(n, c)| (n.as_str(), &c.truth as &dyn Poses)),
        )
        .collect();
    let series: Vec<(&str, &[(Nanos, f64)])> = report
        .sources
        .iter()
        .map(|s| (s.name.as_str(), s.score.ate_errors.as_slice()))
        .collect();
    // Plots are an aid: a plotting failure is reported in the Markdown, not fatal.
    let mut notes = Vec::new();
    if let Err(e) = scoring::plots::plot_trajectories_marked_svg(
        dir.join("trajectories.svg"),
        &sim.truth,
        &top_view,
        if sim.steering == "truth" {
            &[]
        } else {
            &sim.row_lines
        },
        &marks,
    ) {
        notes.push(format!("trajectories.svg: {e}"));
    }
    if let Err(e) =
        scoring::plots::plot_errors_svg(dir.join("errors.svg"), &series, t0, &sim.fault_windows)
    {
        notes.push(format!("errors.svg: {e}"));
    }
    if let Err(e) =
        scoring::plots::plot_altitude_svg(dir.join("altitude.svg"), &sim.truth, &named, t0)
    {
        notes.push(format!("altitude.svg: {e}"));
    }
    if let Some(g) = sim.gnss.as_ref().filter(|g| !g.is_empty())
        && let Err(e) = g.plot(dir, t0, &sim.fault_windows, &sim.row_lines)
    {
        notes.push(format!("gnss.svg, gnss_fix_map.svg: {e}"));
    }
    let mut md = report.markdown();
    if !notes.is_empty() {
        md.push_str("\n## Plot errors\n\n");
        for n in notes {
            md.push_str(&format!("- {n}\n"));
        }
    }
    let mp = dir.join("report.md");
    super::write_file(&mp, md.as_bytes())
}

/// What a run is judged on: the scores of the estimate sources and the robot's own run.
#[derive(Clone, Debug)]
pub struct Scores {
    /// One score per estimate source, in the order of `[estimators] run`.
    pub sources: Vec<(String, SourceScore)>,
    /// The robot's own run (the expectations' pseudo-source `robot`).
    pub robot: RobotReport,
    /// One map score per mapped source (empty when `[mapper]` is off).
    pub maps: Vec<crate::runner::mapping::MapReport>,
    /// The SLAM metrics of each SLAM source (empty when `[slam]` is off).
    pub slam: Vec<(String, BTreeMap<String, f64>)>,
    /// The loop closures of each SLAM source, checked against ground truth.
    pub loops: Vec<(String, scoring::loops::LoopScore)>,
}

impl Scores {
    /// The value of `metric` of `source` (an estimate source or `robot`), if it has one.
    pub fn metric(&self, metric: &str, source: &str) -> Option<f64> {
        if source == ROBOT_SOURCE {
            return self.robot.metric(metric);
        }
        if crate::scoring::expect::SLAM_METRICS
            .iter()
            .any(|(m, _)| *m == metric)
        {
            return self
                .slam
                .iter()
                .find(|(n, _)| n == source)
                .and_then(|(_, m)| m.get(metric).copied());
        }
        if crate::runner::mapping::is_map_metric(metric) {
            return self
                .maps
                .iter()
                .find(|m| m.source == source)
                .and_then(|m| m.metric(metric));
        }
        self.sources
            .iter()
            .find(|(n, _)| n == source)
            .and_then(|(_, s)| s.metric(metric))
    }
}

/// Scores every estimate against the truth (in parallel; each source is independent,
/// so the result does not depend on the thread count), and the robot's own run.
///
/// The trajectories are read from their spools in passes; an error reading one back is
/// [`RunError::Io`] (a score from part of a trajectory is never returned).
pub fn score(sc: &LoadedScenario, sim: &Simulation) -> Result<Scores, RunError> {
    let sources = sim
        .estimates
        .par_iter()
        .map(|e| {
            let mut s = scoring::score_source(
                &sim.truth,
                &e.poses,
                &sc.scenario.scoring,
                &sim.fault_windows,
            );
            // Only what the error plot draws is kept (a long run has millions of poses).
            s.ate_errors = scoring::plots::thin_errors(std::mem::take(&mut s.ate_errors));
            (e.name.to_string(), s)
        })
        .collect();
    let spool_err = |p: &dyn Poses| {
        p.check().map_err(|source| RunError::Io {
            path: "scoring".to_string(),
            source,
        })
    };
    spool_err(&sim.truth)?;
    for e in &sim.estimates {
        spool_err(&e.poses)?;
    }
    let th = sc.scenario.scoring.loop_thresholds();
    // Loop scoring looks the truth up at the loops' stamps: with a SLAM (which holds its
    // keyframes in memory anyway), the truth is read into memory for it.
    let truth = if sim.slam.is_empty() {
        None
    } else {
        Some(sim.truth.to_trajectory().map_err(|source| RunError::Io {
            path: "scoring".to_string(),
            source,
        })?)
    };
    let loops: Vec<(String, scoring::loops::LoopScore)> = sim
        .slam
        .iter()
        .zip(std::iter::repeat(truth.as_ref()))
        .filter_map(|(o, t)| {
            Some((
                o.source.to_string(),
                scoring::loops::score_loops(&o.loops, t?, &th),
            ))
        })
        .collect();
    Ok(Scores {
        sources,
        robot: RobotReport::new(sim),
        maps: sim
            .mapping
            .as_ref()
            .map(crate::runner::mapping::score)
            .unwrap_or_default(),
        slam: sim
            .slam
            .iter()
            .zip(&loops)
            .map(|(o, (_, l))| {
                let metrics = crate::scoring::expect::SLAM_METRICS
                    .iter()
                    .filter_map(|(m, _)| {
                        o.metric(m)
                            .or_else(|| l.metric(m))
                            .map(|v| (m.to_string(), v))
                    })
                    .collect();
                (o.source.to_string(), metrics)
            })
            .collect(),
        loops,
    })
}

/// Evaluates the scenario's expectations on the scores of the estimate sources and the
/// robot's own run. A run whose physics diverged or whose robot tipped over
/// ([`RobotOutcome::failure`](super::outcome::RobotOutcome::failure)) gets one more,
/// failing, result that says so: such a run never passes.
pub fn evaluate(sc: &LoadedScenario, scores: &Scores) -> Vec<ExpectationResult> {
    let mut results: Vec<ExpectationResult> = sc
        .expectations
        .iter()
        .map(|x| x.evaluate(|metric, source| scores.metric(metric, source)))
        .collect();
    if let Some(why) = scores.robot.outcome.failure() {
        results.push(ExpectationResult {
            text: format!("robot outcome is not {}", scores.robot.outcome.kind()),
            holds: false,
            lhs: None,
            rhs: None,
            margin: None,
            note: Some(why),
        });
    }
    results
}
