//! What a run produced: the [`Simulation`] (truth, estimates, what the robot did), the
//! robot's run as the report and the expectations see it ([`RobotReport`]), and the
//! run's error type ([`RunError`]).

use crate::recording::RecordingError;
use crate::scenario::ScenarioError;
use crate::scoring::PoseSpool;
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;
use thiserror::Error;
use vinebench_msgs::{FixStatus, Nanos, Trajectory};
use vinebench_onboard::estimator::{EstimatorStats, StageStats};
use vinebench_sim::motion::{MotionOutcome, RobotMetrics};
use vinebench_sim::params::MotionModelKind;
use vinebench_sim::physics::CollisionEvent;
use vinebench_sim::robot::RobotError;

/// A run that could not be carried out.
#[derive(Debug, Error)]
pub enum RunError {
    /// The scenario asks for something impossible (located in the scenario file).
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    /// The robot description is unusable.
    #[error(transparent)]
    Robot(#[from] RobotError),
    /// The recording could not be written.
    #[error(transparent)]
    Recording(#[from] RecordingError),
    /// The mapper could not build or write a map.
    #[error("mapper: {0}")]
    Mapper(#[from] vinebench_onboard::mapper::MapperError),
    /// The visual SLAM could not use its input.
    #[error("visual SLAM: {0}")]
    Slam(#[from] vinebench_onboard::slam::SlamError),
    /// The run was interrupted (Ctrl-C); the recording so far is finalized.
    #[error("interrupted after {simulated_s:.1} s simulated")]
    Interrupted {
        /// Simulated time when the run stopped, s.
        simulated_s: f64,
    },
    /// Another run (alive) writes the folder.
    #[error(
        "{path}: the folder is in use by another run ({owner}); wait for it or choose another --out"
    )]
    FolderInUse {
        /// The folder.
        path: String,
        /// Who holds it (`pid N on HOST`).
        owner: String,
    },
    /// The folder holds files and the caller did not ask to replace them.
    #[error(
        "{path}: the folder is not empty ({entries} entries: {first}); choose another --out, \
         or pass --replace to clear the files of a previous run there (others are kept)"
    )]
    FolderNotEmpty {
        /// The folder.
        path: String,
        /// How many entries it holds.
        entries: usize,
        /// The first few names.
        first: String,
    },
    /// Writing the run folder failed.
    #[error("{path}: {source}")]
    Io {
        /// The file or folder.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
}

/// Maps an I/O error on `path` to [`RunError::Io`] naming the file.
pub(crate) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> RunError + '_ {
    move |source| RunError::Io {
        path: path.display().to_string(),
        source,
    }
}

/// The trajectory of one estimate source, on disk, with its input counters.
#[derive(Debug)]
pub struct Estimate {
    /// Source name (`eif`, `gnss`, `tracking_camera`, `slam`, ...).
    pub name: &'static str,
    /// Its poses (`world_from_body`, with covariance where the source gives one), spooled
    /// to the run folder as they were produced (see [`crate::scoring::spool`]).
    pub poses: PoseSpool,
    /// Input counters.
    pub stats: EstimatorStats,
}

/// What a simulation produced, before scoring.
#[derive(Debug)]
pub struct Simulation {
    /// Ground truth of the body frame at the scenario's ground-truth rate, spooled to the
    /// run folder as the run went (see [`crate::scoring::spool`]).
    pub truth: PoseSpool,
    /// One output per estimator, in the order of `[estimators] run`, then `slam` when
    /// `[slam]` runs.
    pub estimates: Vec<Estimate>,
    /// What the visual SLAM and its baselines produced (their trajectories are also in
    /// `estimates`).
    pub slam: Vec<vinebench_onboard::slam::SlamOutput>,
    /// Counters of the estimation stage (late and invalid messages).
    pub stage: StageStats,
    /// Messages produced, per topic.
    pub messages: BTreeMap<String, u64>,
    /// SHA-256 of the generated world.
    pub world_digest: String,
    /// Distance travelled by the robot, m.
    pub distance_m: f64,
    /// Simulated duration, s.
    pub duration_s: f64,
    /// True when the route was completed (false: stopped by `max_duration_s`, the safety
    /// limit, or because the robot got stuck).
    pub route_completed: bool,
    /// How the motion ended.
    pub outcome: MotionOutcome,
    /// Contacts of the robot with posts, trunks or the ground (chassis).
    pub collisions: Vec<CollisionEvent>,
    /// The time limit that ended the run before the motion finished (`None`: the motion
    /// finished, completed or stuck).
    pub stopped_by: Option<TimeLimit>,
    /// Truth-only metrics of the robot's run against its route, from every ground-truth
    /// sample.
    pub robot: RobotMetrics,
    /// Fault windows in absolute time.
    pub fault_windows: Vec<(Nanos, Nanos)>,
    /// The maps of `[mapper]` with what scoring needs (`None` when mapping is off).
    pub mapping: Option<crate::runner::mapping::MappingOutput>,
    /// The same route on the motion models of `motion.compare_with`.
    pub comparisons: Vec<MotionComparison>,
    /// What the route follower steered on: `truth` or an estimate source
    /// (`[control] localization`).
    pub steering: String,
    /// When the safety layer of a closed-loop run stopped the robot, and why.
    pub steering_stop: Option<SteeringStop>,
    /// A steering SLAM's map in the world (`world_from_map`, from the start pose): the
    /// path the robot believed is the SLAM's trajectory through it.
    pub steering_world_from_map: Option<nalgebra::Isometry3<f64>>,
    /// Canopy intrusion and clearance to posts and trunks, from the truth.
    pub clearance: vinebench_sim::motion::ClearanceMetrics,
    /// Start of the run.
    pub start: Nanos,
    /// Centre lines of the vine rows (world x, y every metre), for the closed-loop plot.
    pub row_lines: Vec<Vec<(f64, f64)>>,
    /// What the GNSS receiver delivered (none when it is off).
    pub gnss: Option<crate::runner::gnss_log::GnssLog>,
}

/// Why and when the safety layer of a closed-loop run (`[control]`) stopped the robot.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum SteeringStop {
    /// The steering source had given nothing newer than `max_estimate_age_ms`, or (with
    /// `stop_on_tracking_lost`) reported tracking lost.
    EstimateLost {
        /// When the stop was decided, s after the start.
        at_s: f64,
        /// Age of the newest estimate (or lost report) then, s (infinite: none at all).
        age_s: f64,
        /// The source reported tracking lost.
        tracking_lost: bool,
    },
    /// The steering estimate's horizontal position σ exceeded `max_position_sigma_m`.
    Uncertain {
        /// When the stop was decided, s after the start.
        at_s: f64,
        /// The estimate's horizontal position σ then (largest axis), m.
        sigma_m: f64,
    },
}

/// The run's route driven by another motion model (`motion.compare_with`, e.g. the other
/// physics engine): same robot, world, start, controller and stop rules, no sensors.
#[derive(Clone, Debug, Serialize)]
pub struct MotionComparison {
    /// The other motion model.
    pub model: MotionModelKind,
    /// Its ground truth, at the scenario's ground-truth rate.
    #[serde(skip)]
    pub truth: Trajectory,
    /// How its motion ended.
    pub outcome: MotionOutcome,
    /// Its simulated duration, s.
    pub duration_s: f64,
    /// Distance it travelled, m.
    pub distance_m: f64,
    /// Horizontal distance between its end position and the run's, m.
    pub end_gap_m: f64,
    /// Its end heading minus the run's, wrapped to (-180, 180], degrees.
    pub end_heading_deg: f64,
    /// The farthest any position of the run lies from this model's path (nearest of its
    /// positions, horizontal), m.
    pub max_path_separation_m: f64,
}

/// A time limit that ends a simulation whose motion has not finished.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TimeLimit {
    /// The scenario's `max_duration_s`.
    MaxDuration,
    /// The safety limit: three times the expected duration plus 60 s.
    Safety,
}

/// How the robot's run ended.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum RobotOutcome {
    /// Closed loop: the safety layer stopped the robot because its steering estimate was
    /// older than `[control] max_estimate_age_ms` (or there was none), or because the
    /// source reported tracking lost (`[control] stop_on_tracking_lost`).
    StoppedEstimateLost {
        /// End of the run (the robot standing), s after the start.
        at_s: f64,
        /// When the stop was decided, s after the start.
        stopped_at_s: f64,
        /// Arc length reached along the route, m.
        progress_m: f64,
        /// Age of the newest estimate (or lost report) at the stop, s.
        age_s: f64,
        /// The source reported tracking lost.
        tracking_lost: bool,
    },
    /// Closed loop: the safety layer stopped the robot because its steering estimate's
    /// position σ exceeded `[control] max_position_sigma_m`.
    StoppedUncertain {
        /// End of the run (the robot standing), s after the start.
        at_s: f64,
        /// When the stop was decided, s after the start.
        stopped_at_s: f64,
        /// Arc length reached along the route, m.
        progress_m: f64,
        /// The estimate's horizontal position σ at the stop, m.
        sigma_m: f64,
    },
    /// The route was completed (and the final stand-still held).
    Completed {
        /// End of the run, s after the start.
        at_s: f64,
    },
    /// The robot made no progress along its route for `physics.stuck_timeout_s` while it
    /// should have been driving.
    Stuck {
        /// When the run gave up, s after the start.
        at_s: f64,
        /// Arc length reached along the route, m.
        progress_m: f64,
    },
    /// The scenario's `max_duration_s` ended the run before the route was completed.
    MaxDuration {
        /// End of the run, s after the start.
        at_s: f64,
        /// Arc length reached along the route, m.
        progress_m: f64,
    },
    /// The safety limit (three times the expected duration plus 60 s) ended the run
    /// before the route was completed.
    SafetyLimit {
        /// End of the run, s after the start.
        at_s: f64,
        /// Arc length reached along the route, m.
        progress_m: f64,
    },
    /// The physics state became non-finite or physically impossible
    /// ([`MotionOutcome::PhysicsDiverged`]): the run ended there and fails.
    PhysicsDiverged {
        /// Time of the first bad physics step, s after the start.
        at_s: f64,
        /// What was wrong, with the value and the bound.
        reason: String,
        /// Arc length reached along the route, m.
        progress_m: f64,
    },
    /// The robot tipped over ([`MotionOutcome::TippedOver`]): the run ended and fails.
    TippedOver {
        /// When the run ended, s after the start.
        at_s: f64,
        /// When the tilt first went beyond the bound, s after the start.
        tilted_at_s: f64,
        /// The tilt when the run ended, degrees.
        tilt_deg: f64,
        /// Arc length reached along the route, m.
        progress_m: f64,
    },
}

impl RobotOutcome {
    /// Why the run fails whatever its expectations say (the physics diverged or the robot
    /// tipped over), or `None` for an outcome the expectations judge.
    pub fn failure(&self) -> Option<String> {
        match self {
            RobotOutcome::PhysicsDiverged { .. } | RobotOutcome::TippedOver { .. } => {
                Some(self.to_string())
            }
            _ => None,
        }
    }

    /// The outcome's kind as in `report.json` (`completed`, `stuck`, `physics_diverged`,
    /// `tipped_over`, ...).
    pub fn kind(&self) -> &'static str {
        match self {
            RobotOutcome::Completed { .. } => "completed",
            RobotOutcome::Stuck { .. } => "stuck",
            RobotOutcome::MaxDuration { .. } => "max_duration",
            RobotOutcome::SafetyLimit { .. } => "safety_limit",
            RobotOutcome::PhysicsDiverged { .. } => "physics_diverged",
            RobotOutcome::TippedOver { .. } => "tipped_over",
            RobotOutcome::StoppedEstimateLost { .. } => "stopped_estimate_lost",
            RobotOutcome::StoppedUncertain { .. } => "stopped_uncertain",
        }
    }
}

impl fmt::Display for RobotOutcome {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RobotOutcome::StoppedEstimateLost {
                at_s,
                stopped_at_s,
                progress_m,
                age_s,
                tracking_lost,
            } => {
                if *tracking_lost {
                    write!(
                        f,
                        "stopped_estimate_lost at {stopped_at_s:.1} s after {progress_m:.1} m: \
                         the steering source reported tracking lost {age_s:.2} s before (run \
                         ended at {at_s:.1} s)"
                    )
                } else {
                    write!(
                        f,
                        "stopped_estimate_lost at {stopped_at_s:.1} s after {progress_m:.1} m: \
                         the steering estimate was {age_s:.2} s old (run ended at {at_s:.1} s)"
                    )
                }
            }
            RobotOutcome::StoppedUncertain {
                at_s,
                stopped_at_s,
                progress_m,
                sigma_m,
            } => write!(
                f,
                "stopped_uncertain at {stopped_at_s:.1} s after {progress_m:.1} m: the \
                 steering estimate's position σ was {sigma_m:.3} m (run ended at {at_s:.1} s)"
            ),
            RobotOutcome::Completed { at_s } => write!(f, "completed at {at_s:.1} s"),
            RobotOutcome::Stuck { at_s, progress_m } => {
                write!(f, "stuck at {at_s:.1} s after {progress_m:.1} m")
            }
            RobotOutcome::MaxDuration { at_s, progress_m } => write!(
                f,
                "stopped by max_duration_s at {at_s:.1} s after {progress_m:.1} m"
            ),
            RobotOutcome::SafetyLimit { at_s, progress_m } => write!(
                f,
                "stopped by the safety limit at {at_s:.1} s after {progress_m:.1} m"
            ),
            RobotOutcome::PhysicsDiverged {
                at_s,
                reason,
                progress_m,
            } => write!(
                f,
                "physics_diverged at {at_s:.3} s after {progress_m:.1} m: {reason}"
            ),
            RobotOutcome::TippedOver {
                at_s,
                tilted_at_s,
                tilt_deg,
                progress_m,
            } => write!(
                f,
                "tipped_over at {at_s:.1} s after {progress_m:.1} m: tilted {tilt_deg:.0}° from \
                 the vertical since {tilted_at_s:.1} s (bound {:.0}° for {:.1} s)",
                vinebench_sim::motion::dynamic::TIP_OVER_TILT_DEG,
                vinebench_sim::motion::dynamic::TIP_OVER_HOLD_S
            ),
        }
    }
}

/// The robot's own run: how it ended, what it hit and how closely it followed its route,
/// all from ground truth. Answers the expectations' pseudo-source `robot`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RobotReport {
    /// How the run ended.
    pub outcome: RobotOutcome,
    /// Whether the route was completed.
    pub route_completed: bool,
    /// Truth-only metrics against the route
    /// ([`vinebench_sim::motion::tracking`] defines them).
    pub metrics: RobotMetrics,
    /// Contacts with posts, trunks or the ground (chassis), in time order.
    pub collisions: Vec<CollisionEvent>,
    /// The same route on the motion models of `motion.compare_with`.
    pub comparisons: Vec<ComparisonReport>,
    /// What the route follower steered on (`truth` or an estimate source).
    pub steering: String,
    /// Canopy intrusion (time, depth, each stretch) and clearance to posts and trunks
    /// ([`vinebench_sim::motion::clearance`] defines them).
    pub clearance: vinebench_sim::motion::ClearanceMetrics,
    /// Start of the run (intrusion times are relative to it in the Markdown).
    #[serde(skip)]
    pub start: Nanos,
    /// What the GNSS receiver delivered: solution types, fix losses, satellites and DOP
    /// (none when the receiver is off).
    pub gnss: Option<crate::runner::gnss_log::GnssSummary>,
}

/// The route driven by another motion model (`motion.compare_with`), against the run.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ComparisonReport {
    /// The other motion model (`motion.model` name).
    pub model: String,
    /// Whether it completed the route.
    pub completed: bool,
    /// Its simulated duration, s.
    pub duration_s: f64,
    /// Distance it travelled, m.
    pub distance_m: f64,
    /// Horizontal distance between its end position and the run's, m.
    pub end_gap_m: f64,
    /// Its end heading minus the run's, degrees.
    pub end_heading_deg: f64,
    /// The farthest a position of the run lies from its path, m.
    pub max_path_separation_m: f64,
}

impl ComparisonReport {
    fn new(c: &crate::runner::MotionComparison) -> ComparisonReport {
        ComparisonReport {
            model: c.model.name().to_string(),
            completed: c.outcome == MotionOutcome::Completed,
            duration_s: c.duration_s,
            distance_m: c.distance_m,
            end_gap_m: c.end_gap_m,
            end_heading_deg: c.end_heading_deg,
            max_path_separation_m: c.max_path_separation_m,
        }
    }
}

impl RobotReport {
    /// The robot section of a simulation.
    pub fn new(sim: &Simulation) -> RobotReport {
        let at_s = sim.duration_s;
        let progress_m = sim.robot.progress_m;
        let outcome = match &sim.outcome {
            MotionOutcome::Completed => RobotOutcome::Completed { at_s },
            MotionOutcome::Stuck { at_s, progress_m } => RobotOutcome::Stuck {
                at_s: *at_s,
                progress_m: *progress_m,
            },
            MotionOutcome::PhysicsDiverged { at_s, reason } => RobotOutcome::PhysicsDiverged {
                at_s: *at_s,
                reason: reason.clone(),
                progress_m,
            },
            MotionOutcome::TippedOver {
                at_s,
                tilted_at_s,
                tilt_deg,
            } => RobotOutcome::TippedOver {
                at_s: *at_s,
                tilted_at_s: *tilted_at_s,
                tilt_deg: *tilt_deg,
                progress_m,
            },
            MotionOutcome::Running => match (&sim.steering_stop, sim.stopped_by) {
                (
                    Some(SteeringStop::EstimateLost {
                        at_s: t,
                        age_s,
                        tracking_lost,
                    }),
                    _,
                ) => RobotOutcome::StoppedEstimateLost {
                    at_s,
                    stopped_at_s: *t,
                    progress_m,
                    age_s: *age_s,
                    tracking_lost: *tracking_lost,
                },
                (Some(SteeringStop::Uncertain { at_s: t, sigma_m }), _) => {
                    RobotOutcome::StoppedUncertain {
                        at_s,
                        stopped_at_s: *t,
                        progress_m,
                        sigma_m: *sigma_m,
                    }
                }
                (None, Some(TimeLimit::MaxDuration)) => {
                    RobotOutcome::MaxDuration { at_s, progress_m }
                }
                (None, Some(TimeLimit::Safety) | None) => {
                    RobotOutcome::SafetyLimit { at_s, progress_m }
                }
            },
        };
        RobotReport {
            outcome,
            route_completed: sim.route_completed,
            metrics: sim.robot.clone(),
            collisions: sim.collisions.clone(),
            comparisons: sim.comparisons.iter().map(ComparisonReport::new).collect(),
            steering: sim.steering.clone(),
            clearance: sim.clearance.clone(),
            start: sim.start,
            gnss: sim.gnss.as_ref().map(|g| g.summary()),
        }
    }

    /// A metric by its expectation name (one of
    /// [`ROBOT_METRICS`](crate::scoring::expect::ROBOT_METRICS)); `None` for other
    /// names.
    pub fn metric(&self, name: &str) -> Option<f64> {
        let m = &self.metrics;
        match name {
            "collisions" => Some(self.collisions.len() as f64),
            "route_completed" => Some(if self.route_completed { 1.0 } else { 0.0 }),
            "max_cross_track_m" => Some(m.max_cross_track_m),
            "max_heading_error_deg" => Some(m.max_heading_error_deg),
            "max_tilt_deg" => Some(m.max_tilt_deg),
            "distance_m" => Some(m.distance_m),
            "canopy_intrusion_s" => Some(self.clearance.canopy_intrusion_s),
            "canopy_intrusion_max_m" => Some(self.clearance.canopy_intrusion_max_m),
            "min_clearance_m" => self.clearance.min_clearance_m,
            "stopped_by_safety" => Some(match self.outcome {
                RobotOutcome::StoppedEstimateLost { .. }
                | RobotOutcome::StoppedUncertain { .. } => 1.0,
                _ => 0.0,
            }),
            "gnss_fixed_share" => self.gnss.as_ref().map(|g| g.share_of(FixStatus::RtkFixed)),
            "gnss_no_fix_share" => self.gnss.as_ref().map(|g| g.share_of(FixStatus::NoFix)),
            "gnss_fix_losses" => self.gnss.as_ref().map(|g| g.fix_losses as f64),
            "gnss_refix_max_s" => self.gnss.as_ref().and_then(|g| g.refix_max_s),
            "gnss_mean_satellites" => self.gnss.as_ref().and_then(|g| g.mean_satellites_used),
            "compare_end_gap_m" => self.largest(|c| c.end_gap_m),
            "compare_path_separation_m" => self.largest(|c| c.max_path_separation_m),
            _ => None,
        }
    }

    /// The largest `f` over the comparisons (`None` without any).
    fn largest(&self, f: impl Fn(&ComparisonReport) -> f64) -> Option<f64> {
        self.comparisons.iter().map(f).reduce(f64::max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scoring::expect::{Expectation, METRICS, ROBOT_METRICS, ROBOT_SOURCE};

    const SRC: &[&str] = &["eif", "gnss", "tracking_camera"];

    /// A robot section with distinct values per metric and `collisions` post contacts.
    fn robot(collisions: usize, completed: bool) -> RobotReport {
        use vinebench_sim::motion::RobotMetrics;
        use vinebench_sim::physics::{CollisionEvent, Obstacle};
        RobotReport {
            outcome: if completed {
                RobotOutcome::Completed { at_s: 40.0 }
            } else {
                RobotOutcome::Stuck {
                    at_s: 20.0,
                    progress_m: 9.0,
                }
            },
            route_completed: completed,
            metrics: RobotMetrics {
                max_cross_track_m: 0.12,
                max_heading_error_deg: 3.5,
                max_tilt_deg: 6.25,
                distance_m: 41.5,
                progress_m: 40.0,
                route_length_m: 40.0,
                cusps_passed: 0,
                samples: 8000,
            },
            collisions: (0..collisions)
                .map(|i| CollisionEvent {
                    time_s: 10.0 + i as f64,
                    link: "base_link".into(),
                    obstacle: Obstacle::Post { row: 0, index: i },
                    robot_position_m: [5.5, 0.0, 0.2],
                })
                .collect(),
            // The largest of two comparisons counts.
            comparisons: [(0.25, 0.375), (0.125, 0.5)]
                .into_iter()
                .map(|(gap, separation)| ComparisonReport {
                    model: "rapier".into(),
                    completed: true,
                    duration_s: 40.0,
                    distance_m: 41.0,
                    end_gap_m: gap,
                    end_heading_deg: 1.0,
                    max_path_separation_m: separation,
                })
                .collect(),
            steering: "truth".into(),
            clearance: vinebench_sim::motion::ClearanceMetrics {
                canopy_intrusion_s: 1.5,
                canopy_intrusion_max_m: 0.0625,
                min_clearance_m: Some(0.3125),
                intrusions: Vec::new(),
            },
            start: Nanos(0),
            gnss: Some(crate::runner::gnss_log::GnssSummary {
                epochs: 400,
                share: [("rtk_fixed", 0.75), ("rtk_float", 0.125), ("no_fix", 0.125)]
                    .into_iter()
                    .map(|(k, v)| (k.to_string(), v))
                    .collect(),
                fix_losses: 3,
                refixes: 2,
                refix_median_s: Some(8.0),
                refix_max_s: Some(12.5),
                sky_model: true,
                mean_satellites_used: Some(11.5),
                min_satellites_used: Some(4),
                mean_hdop: Some(0.9),
                max_hdop: Some(3.0),
            }),
        }
    }

    #[test]
    fn every_robot_metric_has_a_value_in_the_robot_report() {
        let r = robot(2, true);
        let want = [
            ("collisions", 2.0),
            ("route_completed", 1.0),
            ("max_cross_track_m", 0.12),
            ("max_heading_error_deg", 3.5),
            ("max_tilt_deg", 6.25),
            ("distance_m", 41.5),
            ("canopy_intrusion_s", 1.5),
            ("canopy_intrusion_max_m", 0.0625),
            ("min_clearance_m", 0.3125),
            ("stopped_by_safety", 0.0),
            ("compare_end_gap_m", 0.25),
            ("compare_path_separation_m", 0.5),
            ("gnss_fixed_share", 0.75),
            ("gnss_no_fix_share", 0.125),
            ("gnss_fix_losses", 3.0),
            ("gnss_refix_max_s", 12.5),
            ("gnss_mean_satellites", 11.5),
        ];
        let mut names: Vec<&str> = ROBOT_METRICS.iter().map(|m| m.0).collect();
        let mut wanted: Vec<&str> = want.iter().map(|w| w.0).collect();
        names.sort_unstable();
        wanted.sort_unstable();
        assert_eq!(names, wanted);
        for (name, v) in want {
            assert_eq!(r.metric(name), Some(v), "{name}");
        }
        assert_eq!(robot(0, false).metric("route_completed"), Some(0.0));
        // Without `motion.compare_with` the comparison metrics have no value.
        let alone = RobotReport {
            comparisons: Vec::new(),
            ..robot(0, true)
        };
        assert_eq!(alone.metric("compare_end_gap_m"), None);
        assert_eq!(r.metric("ate_rmse_m"), None);
        // No name is both a robot and an estimate metric.
        for (m, _) in ROBOT_METRICS {
            assert!(!METRICS.iter().any(|(e, _)| e == m), "{m}");
        }
    }

    #[test]
    fn physics_failures_are_named_outcomes_that_fail_the_run() {
        let diverged = RobotOutcome::PhysicsDiverged {
            at_s: 3.25,
            reason: "body speed 1e40 m/s above MAX_BODY_SPEED_MPS = 50 m/s".into(),
            progress_m: 2.0,
        };
        let tipped = RobotOutcome::TippedOver {
            at_s: 2.6,
            tilted_at_s: 1.6,
            tilt_deg: 134.0,
            progress_m: 0.0,
        };
        for (o, kind) in [(&diverged, "physics_diverged"), (&tipped, "tipped_over")] {
            assert_eq!(o.kind(), kind);
            let why = o.failure().expect("a failure");
            assert!(why.starts_with(kind), "{why}");
            let json = serde_json::to_value(o).unwrap();
            assert_eq!(json["kind"], kind);
        }
        assert!(diverged.to_string().contains("3.250 s") && diverged.to_string().contains("1e40"));
        assert!(RobotOutcome::Completed { at_s: 1.0 }.failure().is_none());
        assert!(
            RobotOutcome::Stuck {
                at_s: 1.0,
                progress_m: 0.0
            }
            .failure()
            .is_none()
        );
    }

    #[test]
    fn robot_expectations_evaluate_on_the_robot_report() {
        let eval = |text: &str, r: &RobotReport| {
            Expectation::parse(text, SRC)
                .unwrap()
                .evaluate(|m, s| match s {
                    ROBOT_SOURCE => r.metric(m),
                    "eif" if m == "ate_rmse_m" => Some(0.05),
                    _ => None,
                })
        };
        let (ok, bad) = (robot(0, true), robot(3, false));
        let r = eval("collisions.robot <= 0", &ok);
        assert!(r.holds && r.margin == Some(0.0), "{r:?}");
        let r = eval("collisions.robot <= 0", &bad);
        assert!(
            !r.holds && r.lhs == Some(3.0) && r.margin == Some(-3.0),
            "{r:?}"
        );
        assert!(eval("route_completed.robot >= 1", &ok).holds);
        assert!(!eval("route_completed.robot >= 1", &bad).holds);
        let r = eval("max_cross_track_m.robot < 0.2", &ok);
        assert!(r.holds && (r.margin.unwrap() - 0.08).abs() < 1e-12, "{r:?}");
        assert!(!eval("max_tilt_deg.robot < 6", &ok).holds);
        assert!(eval("max_heading_error_deg.robot <= 3.5", &ok).holds);
        // 41.5 > 100 * 0.05.
        let r = eval("distance_m.robot > 100 * ate_rmse_m.eif", &ok);
        assert!(r.holds && (r.margin.unwrap() - 36.5).abs() < 1e-12, "{r:?}");
    }
}
