//! The pure part of a run: [`setup`] builds the world, robot, route, motion model, sensors,
//! estimators, SLAM and mapper from a scenario; [`simulate`] steps them in time order.
//! Sensor messages reach the onboard algorithms in *arrival* order (stamp + latency), as
//! on a robot, and are handed to the recording (when one is open) in the same order.

use super::outcome::{
    Estimate, MotionComparison, RobotReport, RunError, Simulation, TimeLimit, io_err,
};
use crate::recording::{self, RecordItem, Recorder};
use crate::runner::steering::{self, SteeringLoop, SteeringSource};
use crate::scenario::{LoadedScenario, ScenarioError};
use crate::scoring::expect::ROBOT_METRICS;
use crate::scoring::{Poses, SpoolWriter};
use indicatif::ProgressBar;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use std::cmp::Reverse;
use std::collections::{BTreeMap, BinaryHeap};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use vinebench_msgs::geodesy::{LocalEnu, normal_gravity};
use vinebench_msgs::{Nanos, PoseSample, TimedMessage, Trajectory};
use vinebench_onboard::estimator::{EstimatorError, EstimatorSet, SensorFrames};
use vinebench_sim::control::heading_rad;
use vinebench_sim::motion::{
    Dynamic, KinematicSkidSteer, MotionModel, MotionOutcome, RouteTracking, RowClearance,
};
use vinebench_sim::params::{HeadingMode, MotionModelKind};
use vinebench_sim::physics::rapier::{HeightGrid, MIN_HEIGHTFIELD_CELL_M, obstacles_of};
use vinebench_sim::physics::{RapierPhysics, Scene};
use vinebench_sim::render::shade::Renderer;
use vinebench_sim::robot::RobotModel;
use vinebench_sim::route::build_route;
use vinebench_sim::sensors::sky::LineOfSight;
use vinebench_sim::sensors::{SensorContext, SensorModel, build_cameras, build_sensors};
use vinebench_sim::world::World;

/// Drives `motion` along its route like the main loop (ground-truth samples at
/// `gt_rate_hz` from `start` until it finishes, `hard_stop` passes or its own safety
/// limit does) and compares the result with the run's `truth`.
fn drive_comparison(
    model: MotionModelKind,
    motion: &mut dyn MotionModel,
    start: Nanos,
    gt_rate_hz: f64,
    hard_stop: Option<Nanos>,
    truth: &dyn Poses,
) -> MotionComparison {
    let safety_stop =
        start + Nanos(motion.expected_duration().0.saturating_mul(3)) + Nanos::from_secs(60);
    let mut theirs = Trajectory::new();
    let (mut last_t, mut odometer_m) = (start, 0.0);
    for i in 0_i64.. {
        let t = start + Nanos((i as f64 * 1e9 / gt_rate_hz).round() as i64);
        if hard_stop.is_some_and(|h| t > h) || t > safety_stop {
            break;
        }
        let state = motion.advance_to(t);
        theirs.push(PoseSample {
            stamp: t,
            world_from_body: state.world_from_body,
            covariance: None,
        });
        (last_t, odometer_m) = (t, state.odometer_m);
        if motion.finished() {
            break;
        }
    }
    let horizontal: Vec<[f64; 2]> = theirs.positions().map(|p| [p.x, p.y]).collect();
    let max_path_separation_m = if horizontal.is_empty() {
        f64::INFINITY
    } else {
        let tree: ImmutableKdTree<f64, 2> = ImmutableKdTree::new_from_slice(&horizontal);
        truth
            .poses()
            .map(|(_, p)| {
                let p = p.translation.vector;
                tree.nearest_one::<SquaredEuclidean>(&[p.x, p.y])
                    .distance
                    .sqrt()
            })
            .fold(0.0, f64::max)
    };
    let ends = truth.last().zip(theirs.samples.last());
    let (end_gap_m, end_heading_deg) = ends.map_or((f64::INFINITY, f64::NAN), |((_, a), b)| {
        let gap = (b.world_from_body.translation.vector - a.translation.vector)
            .xy()
            .norm();
        let d = heading_rad(&b.world_from_body) - heading_rad(&a);
        let wrapped =
            -(-d + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) + std::f64::consts::PI;
        (gap, wrapped.to_degrees())
    });
    MotionComparison {
        model,
        truth: theirs,
        outcome: motion.outcome(),
        duration_s: (last_t - start).as_secs_f64(),
        distance_m: odometer_m,
        end_gap_m,
        end_heading_deg,
        max_path_separation_m,
    }
}

/// A message between its production and its arrival at the estimators, ordered by
/// arrival time and then production order (deterministic ties).
struct InFlight {
    seq: u64,
    tm: TimedMessage,
}

impl InFlight {
    fn key(&self) -> (Nanos, u64) {
        (self.tm.arrival, self.seq)
    }
}
impl PartialEq for InFlight {
    fn eq(&self, other: &Self) -> bool {
        self.key() == other.key()
    }
}
impl Eq for InFlight {}
impl PartialOrd for InFlight {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for InFlight {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.key().cmp(&other.key())
    }
}

/// Everything a simulation needs, built and validated from a scenario.
pub struct Setup {
    /// The generated vineyard.
    pub world: World,
    /// The robot description.
    pub robot: RobotModel,
    /// The motion model, at rest at the start of the route.
    pub motion: Box<dyn MotionModel>,
    /// Measures the robot's truth against the route it follows.
    pub tracking: RouteTracking,
    /// The enabled sensors.
    pub sensors: Vec<Box<dyn SensorModel>>,
    /// The renderer the cameras share (none without cameras).
    pub renderer: Option<Arc<Renderer>>,
    /// Where debug PNGs of camera images go (`[render] debug_png_every`); set by [`run`].
    pub png_dir: Option<PathBuf>,
    /// The estimation stage.
    pub estimators: EstimatorSet,
    /// Where every message, the ground truth and the estimates are recorded (MCAP); set
    /// by [`run`], `None` for a simulation without files.
    pub recorder: Option<Recorder>,
    /// When set, the simulation stops at its next step with [`RunError::Interrupted`].
    pub stop: Option<Arc<AtomicBool>>,
    /// The mappers of `[mapper]` (`None` when mapping is off).
    pub mapping: Option<crate::runner::mapping::MappingStage>,
    /// The other motion models of `motion.compare_with`, at rest at the start.
    pub comparisons: Vec<(MotionModelKind, Box<dyn MotionModel>)>,
    /// The visual SLAM of `[slam]` and its baselines (empty when it is off).
    pub slam: Vec<vinebench_onboard::slam::VisualSlam>,
    /// When set, every message is also sent here as it is delivered, in delivery order
    /// (`vinebench bench` feeds the same stream to the SLAM again); `None` from [`setup`].
    pub tap: Option<std::sync::mpsc::Sender<vinebench_msgs::Message>>,
    /// Where the ground truth and the estimates are spooled as the run goes (unnamed
    /// files, gone with the process; see [`crate::scoring::spool`]): the run folder, set
    /// by [`run`]; `None` = the system's temporary folder.
    pub spool_dir: Option<PathBuf>,
}

/// The scenario's `[world.mesh]` file (PLY or OBJ by its extension, relative to the
/// scenario file), read and checked as the render geometry it stands for (see
/// [`WorldMesh::validate`](vinebench_sim::render::scene::WorldMesh::validate)); `None`
/// when `world.mesh.file` is empty.
pub fn load_world_mesh(
    sc: &LoadedScenario,
) -> Result<Option<vinebench_sim::render::scene::WorldMesh>, ScenarioError> {
    let file = &sc.scenario.world.mesh.file;
    if file.is_empty() {
        return Ok(None);
    }
    let path = sc.base_dir.join(file);
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase());
    let read = match ext.as_deref() {
        Some("ply") => vinebench_onboard::mapper::ply::read_mesh,
        Some("obj") => vinebench_onboard::mapper::export::read_obj,
        _ => {
            return Err(sc.field_error(
                "world.mesh.file",
                format!("a .ply or .obj triangle mesh, found `{file}`"),
            ));
        }
    };
    // The parsers stream the file: what bounds it is its size, checked first.
    crate::fsio::check_input_file(&path, crate::fsio::MAX_MESH_BYTES).map_err(|e| {
        sc.field_error(
            "world.mesh.file",
            format!("a triangle mesh of at most 2 GiB in `{file}`: {e}"),
        )
    })?;
    let mesh = read(&path)
        .map_err(|e| sc.field_error("world.mesh.file", format!("a triangle mesh: {e}")))?;
    let mesh = vinebench_sim::render::scene::WorldMesh {
        vertices: mesh.vertices.iter().map(|v| v.map(f64::from)).collect(),
        colors: mesh.colors,
        triangles: mesh.triangles,
    };
    mesh.validate().map_err(|e| {
        sc.field_error(
            "world.mesh.file",
            format!("a valid triangle mesh in `{file}`: {e}"),
        )
    })?;
    Ok(Some(mesh))
}

/// Builds the world, robot, route, motion model, sensors and estimators of a scenario;
/// every parameter problem comes back located in the scenario file.
pub fn setup(sc: &LoadedScenario) -> Result<Setup, RunError> {
    let s = &sc.scenario;
    let world = World::generate(s.seed, &s.world).map_err(|e| sc.param_error(e))?;
    let robot = if s.robot.urdf.is_empty() {
        RobotModel::builtin(&s.robot.model)
            .map_err(|e| sc.field_error("robot.model", e.to_string()))?
    } else {
        RobotModel::from_urdf_file(&sc.base_dir.join(&s.robot.urdf))?
    };
    let route =
        build_route(&s.route, &world.layout, &s.world.headlands).map_err(|e| sc.param_error(e))?;
    let gravity_mps2 = normal_gravity(s.origin.lat_deg, s.origin.alt_m);
    // The heading policy the motion model applies: the kinematic skid-steer always drives
    // along the route; the dynamic model's follower applies `motion.heading` (and rejects
    // anything but `path` with no offset for robots that cannot move sideways).
    let tracking = match s.motion.model {
        MotionModelKind::Kinematic => RouteTracking::new(route.clone(), HeadingMode::Path, 0.0),
        MotionModelKind::Rapier | MotionModelKind::Mujoco => {
            RouteTracking::new(route.clone(), s.motion.heading, s.motion.heading_offset_deg)
        }
    };
    let motion = motion_model(
        s.motion.model,
        "motion.model",
        s,
        &route,
        &robot,
        &world,
        gravity_mps2,
        sc,
    )?;
    if s.control.source().is_some() && !motion.supports_steering() {
        return Err(sc
            .field_error(
                "control.localization",
                format!(
                    "\"truth\" with motion.model = \"{}\" (its controller steers on the truth \
                     only): closed-loop runs need motion.model = \"rapier\" or \"mujoco\"",
                    s.motion.model.name()
                ),
            )
            .into());
    }
    let mut comparisons = Vec::new();
    for (i, &kind) in s.motion.compare_with.iter().enumerate() {
        let field = format!("motion.compare_with[{i}]");
        if kind == s.motion.model || s.motion.compare_with[..i].contains(&kind) {
            return Err(sc
                .field_error(
                    &field,
                    format!(
                        "expected motion models other than `motion.model` (\"{}\"), each once; found \"{}\" twice",
                        s.motion.model.name(),
                        kind.name()
                    ),
                )
                .into());
        }
        comparisons.push((
            kind,
            motion_model(kind, &field, s, &route, &robot, &world, gravity_mps2, sc)?,
        ));
    }

    let enu = LocalEnu::new(s.origin);
    let ctx = SensorContext {
        master_seed: s.seed,
        start: sc.start,
        enu: enu.clone(),
        gravity_mps2,
        static_transforms: robot.static_transforms.clone(),
        geometry: robot.geometry.clone(),
    };
    vinebench_sim::render::validate(&s.render).map_err(|e| sc.param_error(e))?;
    // Read even when no camera draws it: a wrong path fails here, not in a later run.
    let mesh = load_world_mesh(sc)?;
    let renderer = if s.sensors.cameras.is_empty() {
        None
    } else {
        Some(Arc::new(
            vinebench_sim::render::build_renderer_with_mesh(&world, &s.render, mesh.as_ref())
                .map_err(|e| sc.param_error(e))?,
        ))
    };
    // The GNSS sky looks through the cameras' geometry, or its own without cameras.
    let sight: Option<Arc<dyn LineOfSight>> =
        if s.sensors.gnss.enabled && s.sensors.gnss.sky.enabled {
            Some(match &renderer {
                Some(r) => r.clone(),
                None => Arc::new(
                    vinebench_sim::render::build_geometry(&world, &s.render, mesh.as_ref())
                        .map_err(|e| sc.param_error(e))?,
                ),
            })
        } else {
            None
        };
    let mut sensors =
        build_sensors(&s.sensors, &s.faults, &ctx, sight).map_err(|e| sc.param_error(e))?;
    if let Some(r) = &renderer {
        sensors
            .extend(build_cameras(&s.sensors, &s.render, &ctx, r).map_err(|e| sc.param_error(e))?);
    }
    let estimator_error = |e: EstimatorError| match e {
        EstimatorError::InvalidParam {
            path,
            expected,
            found,
        } => sc.field_error(&path, format!("expected {expected}, found {found}")),
        EstimatorError::MissingFrame { frame, estimator } => sc.field_error(
            "estimators.run",
            format!(
                "estimator `{estimator}` needs frame `{frame}`, which {} does not define",
                robot.source
            ),
        ),
    };
    let estimators = EstimatorSet::new(&s.estimators, robot.static_transforms.clone(), enu)
        .map_err(estimator_error)?;
    estimators
        .check_sensor_frames(&SensorFrames {
            imu: &s.sensors.imu.frame,
            gnss_antenna: &s.sensors.gnss.frame,
            tracking_camera: &s.sensors.tracking_camera.frame,
        })
        .map_err(estimator_error)?;
    let mapping =
        crate::runner::mapping::MappingStage::from_scenario(sc, &robot.static_transforms, None)?;
    let slam = slam_from_scenario(sc, &robot.static_transforms, Some(&world))?;
    Ok(Setup {
        world,
        robot,
        motion,
        tracking,
        sensors,
        renderer,
        png_dir: None,
        estimators,
        recorder: None,
        stop: None,
        mapping,
        comparisons,
        slam,
        tap: None,
        spool_dir: None,
    })
}

/// The visual SLAM of `[slam]` and its baselines (none when off); its cameras must be
/// stereo cameras of `[[sensors.cameras]]` (located errors). With
/// `slam.loop_closure.survey_world_tags`, `world` (generated from the scenario when not
/// given) supplies the surveyed tag poses.
pub fn slam_from_scenario(
    sc: &LoadedScenario,
    static_transforms: &vinebench_msgs::StaticTransforms,
    world: Option<&World>,
) -> Result<Vec<vinebench_onboard::slam::VisualSlam>, RunError> {
    let s = &sc.scenario;
    if !s.slam.enabled {
        return Ok(Vec::new());
    }
    for (i, name) in s.slam.cameras.iter().enumerate() {
        let stereo = s
            .sensors
            .cameras
            .iter()
            .find(|c| &c.name == name)
            .map(|c| c.right_frame.is_some());
        if stereo != Some(true) {
            let found = match stereo {
                None => "no camera of that name",
                Some(_) => "a camera without `right_frame`",
            };
            return Err(sc
                .field_error(
                    &format!("slam.cameras[{i}]"),
                    format!(
                        "expected the name of a stereo camera of [[sensors.cameras]], found \"{name}\" ({found})"
                    ),
                )
                .into());
        }
    }
    let tag_camera = &s.slam.tags.camera;
    if s.slam.uses_tags()
        && s.slam.tags.enabled
        && !s.sensors.cameras.iter().any(|c| &c.name == tag_camera)
    {
        return Err(sc
            .field_error(
                "slam.tags.camera",
                format!(
                    "expected the name of a camera of [[sensors.cameras]] (the tag camera), found \
                     \"{tag_camera}\" (no camera of that name); add it, or set \
                     slam.loop_closure.method = \"none\""
                ),
            )
            .into());
    }
    let vocabulary = if s.slam.needs_vocabulary() {
        let path = sc.base_dir.join(&s.slam.bow.vocabulary);
        let read = std::fs::File::open(&path)
            .map_err(|e| e.to_string())
            .and_then(|f| {
                vinebench_onboard::slam::bow::Vocabulary::read(std::io::BufReader::new(f))
                    .map_err(|e| e.to_string())
            });
        match read {
            Ok(v) => Some(std::sync::Arc::new(v)),
            Err(e) => {
                return Err(sc
                    .field_error(
                        "slam.bow.vocabulary",
                        format!(
                            "expected a bag-of-words vocabulary file (relative to the scenario \
                             file), {}: {e}; train one with `vinebench vocabulary <scenario> \
                             --out {}`",
                            path.display(),
                            path.display()
                        ),
                    )
                    .into());
            }
        }
    } else {
        None
    };
    let mut slam_cfg = s.slam.clone();
    if slam_cfg.loop_closure.survey_world_tags {
        let generated;
        let world = match world {
            Some(w) => w,
            None => {
                generated = World::generate(s.seed, &s.world).map_err(|e| sc.param_error(e))?;
                &generated
            }
        };
        survey_tags(&mut slam_cfg.loop_closure, world, s.seed);
    }
    slam_cfg
        .runs()
        .into_iter()
        .map(|(source, cfg)| {
            vinebench_onboard::slam::VisualSlam::new(
                source,
                cfg,
                static_transforms.clone(),
                vocabulary.clone(),
            )
            .map_err(|e| sc.field_error("slam", e.to_string()).into())
        })
        .collect::<Result<Vec<_>, RunError>>()
        .map(|mut slams| {
            vinebench_onboard::slam::share_front_ends(&mut slams);
            slams
        })
}

/// A simulated survey of `world`'s tag boards into `cfg.surveyed_tags` (entries the
/// scenario lists keep their poses): each pose perturbed by `survey_sigma_m` and
/// `survey_sigma_rad` (per axis) drawn from the stream `tag_survey` of `seed`.
fn survey_tags(
    cfg: &mut vinebench_onboard::slam::loop_closing::LoopConfig,
    world: &World,
    seed: u64,
) {
    use rand_distr::{Distribution, StandardNormal};
    let mut rng = vinebench_sim::rng::stream(seed, "tag_survey");
    for board in &world.tags {
        let mut n = || -> f64 { StandardNormal.sample(&mut rng) };
        let dt = nalgebra::Vector3::new(n(), n(), n()) * cfg.survey_sigma_m;
        let dr = nalgebra::Vector3::new(n(), n(), n()) * cfg.survey_sigma_rad;
        if cfg.surveyed_tags.iter().any(|t| t.id == board.id) {
            continue;
        }
        let surveyed = nalgebra::Isometry3::from_parts(
            nalgebra::Translation3::from(board.world_from_tag.translation.vector + dt),
            nalgebra::UnitQuaternion::from_scaled_axis(dr) * board.world_from_tag.rotation,
        );
        cfg.surveyed_tags.push(
            vinebench_onboard::slam::loop_closing::SurveyedTag::from_pose(board.id, &surveyed),
        );
    }
}

/// The motion model `kind` of a scenario, on its route from its start; `field` names the
/// key that chose it in errors.
#[allow(clippy::too_many_arguments)]
fn motion_model(
    kind: MotionModelKind,
    field: &str,
    s: &crate::scenario::Scenario,
    route: &vinebench_sim::route::Route,
    robot: &RobotModel,
    world: &World,
    gravity_mps2: f64,
    sc: &LoadedScenario,
) -> Result<Box<dyn MotionModel>, RunError> {
    Ok(match kind {
        MotionModelKind::Kinematic => Box::new(
            KinematicSkidSteer::new(
                &s.motion,
                route.clone(),
                world.terrain.clone(),
                &robot.geometry,
                sc.start,
            )
            .map_err(|e| sc.param_error(e))?,
        ),
        MotionModelKind::Rapier => {
            let (lo, hi) = world.terrain.domain();
            let cell = s.physics.heightfield_cell_m;
            // An unusable cell size is reported by the backend's parameter check; do not
            // sample a grid of it first, nor one too large.
            let grid = if cell.is_finite() && cell >= MIN_HEIGHTFIELD_CELL_M {
                HeightGrid::check_size(lo, hi, cell, "physics.heightfield_cell_m")
                    .map_err(|e| sc.param_error(e))?;
                Some(HeightGrid::sample(&world.terrain, lo, hi, cell))
            } else {
                None
            };
            let obstacles = obstacles_of(world);
            Box::new(
                Dynamic::new(
                    &s.motion,
                    &s.physics,
                    route.clone(),
                    robot,
                    &world.terrain,
                    gravity_mps2,
                    sc.start,
                    |pose| {
                        RapierPhysics::new(
                            robot,
                            Scene {
                                surface: world.terrain.clone(),
                                obstacles: &obstacles,
                                ground: grid.as_ref(),
                            },
                            &s.physics,
                            s.motion.step_hz,
                            gravity_mps2,
                            pose,
                        )
                    },
                )
                .map_err(|e| sc.param_error(e))?,
            )
        }
        MotionModelKind::Mujoco => {
            mujoco_motion(field, s, route.clone(), robot, world, gravity_mps2, sc)?
        }
    })
}

/// Checks that a scenario can be set up (world, robot, route, sensors, estimators)
/// without running it.
pub fn validate(sc: &LoadedScenario) -> Result<(), RunError> {
    setup(sc).map(|_| ())
}

/// Runs the simulation of a scenario (no files written).
pub fn simulate(
    sc: &LoadedScenario,
    progress: Option<&ProgressBar>,
) -> Result<Simulation, RunError> {
    simulate_setup(sc, setup(sc)?, progress)
}

/// Delivers one message that has arrived: to the estimators, the mapper, the visual SLAM
/// systems, the live tap and the recording, in that order. The recording is written in
/// delivery order, so a replay restores it exactly.
fn deliver(
    tm: TimedMessage,
    estimators: &mut EstimatorSet,
    mapping: &mut Option<crate::runner::mapping::MappingStage>,
    slam: &mut [vinebench_onboard::slam::VisualSlam],
    tap: Option<&std::sync::mpsc::Sender<vinebench_msgs::Message>>,
    recorder: &mut Option<Recorder>,
) -> Result<(), RunError> {
    estimators.push(&tm);
    if let Some(m) = mapping {
        m.push(&tm.msg, estimators)?;
    }
    for v in slam {
        v.push(&tm.msg)?;
    }
    if let Some(tx) = tap {
        // A receiver gone only means nobody listens any more.
        let _ = tx.send(tm.msg.clone());
    }
    if let Some(rec) = recorder {
        rec.send(RecordItem::Message(tm));
    }
    Ok(())
}

/// Runs the simulation of a scenario that [`setup`] has already built.
pub fn simulate_setup(
    sc: &LoadedScenario,
    built: Setup,
    progress: Option<&ProgressBar>,
) -> Result<Simulation, RunError> {
    let s = &sc.scenario;
    let Setup {
        world,
        robot,
        mut motion,
        mut tracking,
        mut sensors,
        mut estimators,
        png_dir,
        mut recorder,
        stop,
        mut mapping,
        renderer,
        mut comparisons,
        mut slam,
        tap,
        spool_dir,
        ..
    } = built;
    let mut png =
        png_dir.map(|d| crate::runner::images::PngDump::new(&d, s.render.debug_png_every));
    let start = sc.start;
    let mut gnss_log = s.sensors.gnss.enabled.then(|| {
        crate::runner::gnss_log::GnssLog::new(
            vinebench_msgs::geodesy::LocalEnu::new(s.origin),
            s.sensors.gnss.sky.enabled,
        )
    });
    // Closed loop (`[control] localization`): the follower steers on an estimate.
    let mut steering = match s.control.source() {
        None => None,
        Some(src) => {
            let source = match s.estimators.run.iter().copied().find(|k| k.name() == src) {
                Some(kind) => SteeringSource::Estimator(kind),
                None => {
                    SteeringSource::Slam(slam.iter().position(|v| v.source() == src).ok_or_else(
                        || sc.field_error("control.localization", "an estimate source of the run"),
                    )?)
                }
            };
            let drive_start = start + Nanos::from_secs_f64(s.motion.still_before_s);
            Some(SteeringLoop::new(&s.control, source, start, drive_start))
        }
    };
    let mut steering_stop = None;
    let mut clearance = RowClearance::new(
        &world,
        robot.geometry.footprint_length_m,
        robot.geometry.footprint_width_m,
    );

    // Stop conditions: the route's end, the scenario's hard stop, or a safety limit of
    // three times the expected duration (a controller that never reaches the end).
    let expected = motion.expected_duration();
    let hard_stop = if s.max_duration_s > 0.0 {
        Some(start + Nanos::from_secs_f64(s.max_duration_s))
    } else {
        None
    };
    let safety_stop = start + Nanos(expected.0.saturating_mul(3)) + Nanos::from_secs(60);
    if let Some(pb) = progress {
        pb.set_length(expected.as_secs_f64().ceil() as u64);
    }

    let gt_rate = s.scoring.ground_truth_rate_hz;
    let mut gt_index: i64 = 0;
    let gt_time = |i: i64| start + Nanos((i as f64 * 1e9 / gt_rate).round() as i64);
    // Truth and estimates go to disk as they are produced, so memory does not grow with
    // the run's length. A mapper reads the estimates as they grow: then they stay in
    // memory until the end (mapping holds its frames anyway).
    let spool_dir = spool_dir.as_deref();
    let spool_err = |label: &str| {
        let path = format!(
            "{} spool in {}",
            label,
            spool_dir
                .map_or_else(std::env::temp_dir, Path::to_path_buf)
                .display()
        );
        move |source| RunError::Io { path, source }
    };
    let mut truth =
        SpoolWriter::create(spool_dir, "ground-truth").map_err(spool_err("ground-truth"))?;
    let drain_estimates = mapping.is_none();
    let mut estimate_spools =
        EstimateSpools::new(spool_dir, &estimators).map_err(spool_err("estimate"))?;
    let mut messages: BTreeMap<String, u64> = BTreeMap::new();
    let mut pending: BinaryHeap<Reverse<InFlight>> = BinaryHeap::new();
    let mut seq: u64 = 0;
    let mut out: Vec<TimedMessage> = Vec::new();
    let mut last_t = start;
    let mut last_odometer = 0.0;
    let mut route_completed = false;
    let mut stopped_by = None;
    if let Some(rec) = &mut recorder {
        rec.send(RecordItem::Metadata(
            recording::META_SCENARIO.to_string(),
            scenario_metadata(sc),
        ));
        rec.send(RecordItem::StaticTransforms(
            robot.static_transforms.clone(),
            start,
        ));
    }

    loop {
        if stop.as_ref().is_some_and(|f| f.load(Ordering::Relaxed)) {
            // Dropping the recorder on the way out finalizes the file.
            return Err(RunError::Interrupted {
                simulated_s: (last_t - start).as_secs_f64(),
            });
        }
        if recorder.as_ref().is_some_and(Recorder::failed)
            && let Some(rec) = recorder.take()
        {
            // A failed write (a full disk): stop now and say why, rather than simulate on
            // for a recording that cannot be written.
            rec.finish()?;
        }
        let next_sensor = sensors.iter().map(|x| x.next_time()).min();
        let t = match next_sensor {
            Some(ts) => ts.min(gt_time(gt_index)),
            None => gt_time(gt_index),
        };
        if hard_stop.is_some_and(|h| t > h) {
            stopped_by = Some(TimeLimit::MaxDuration);
            break;
        }
        if t > safety_stop {
            stopped_by = Some(TimeLimit::Safety);
            break;
        }
        if let Some(st) = &mut steering
            && let Some(stop) = st.steer(t, motion.as_mut())
        {
            steering_stop = Some(stop);
        }
        let state = motion.advance_to(t);
        if let Some(st) = &mut steering {
            // Where the robot was placed (the first call counts): a SLAM's map is
            // anchored there.
            st.place(&state.world_from_body);
        }
        last_t = t;
        last_odometer = state.odometer_m;
        if t == gt_time(gt_index) {
            tracking.push(&state);
            clearance.push(t, &state.world_from_body);
            let sample = PoseSample {
                stamp: t,
                world_from_body: state.world_from_body,
                covariance: None,
            };
            truth.push(&sample).map_err(spool_err("ground-truth"))?;
            if let Some(rec) = &mut recorder {
                rec.send(RecordItem::Truth(sample));
            }
            gt_index += 1;
            if drain_estimates && gt_index % SPOOL_EVERY_TRUTH_SAMPLES == 0 {
                estimate_spools
                    .drain(&mut estimators)
                    .map_err(spool_err("estimate"))?;
            }
        }
        for sensor in sensors.iter_mut() {
            if sensor.next_time() == t {
                sensor.sample(&state, &mut out);
            }
        }
        for tm in out.drain(..) {
            *messages.entry(tm.msg.topic().to_string()).or_default() += 1;
            if let (Some(dump), vinebench_msgs::Message::Image(img)) = (png.as_mut(), &tm.msg) {
                dump.push(img).map_err(io_err(&img_dir(dump)))?;
            }
            pending.push(Reverse(InFlight { seq, tm }));
            seq += 1;
        }
        while pending.peek().is_some_and(|p| p.0.tm.arrival <= t) {
            if let Some(Reverse(p)) = pending.pop() {
                if let Some(g) = &mut gnss_log {
                    g.push(&p.tm.msg);
                }
                deliver(
                    p.tm,
                    &mut estimators,
                    &mut mapping,
                    &mut slam,
                    tap.as_ref(),
                    &mut recorder,
                )?;
            }
        }
        if let Some(st) = &mut steering {
            st.observe(t, &estimators, &mut slam);
            // After a safety stop the run ends once the robot stands.
            if let Some(at) = st.stopped_at() {
                let v = state.velocity_in_world;
                if v.x.hypot(v.y) < steering::STANDING_MPS
                    || (t - at).as_secs_f64() > steering::STOP_SETTLE_S
                {
                    break;
                }
            }
        }
        if let Some(pb) = progress {
            pb.set_position((t - start).as_secs_f64() as u64);
        }
        if motion.finished() {
            route_completed = motion.outcome() == MotionOutcome::Completed;
            break;
        }
    }
    // Deliver what is still in flight, in arrival order.
    while let Some(Reverse(p)) = pending.pop() {
        if let Some(g) = &mut gnss_log {
            g.push(&p.tm.msg);
        }
        deliver(
            p.tm,
            &mut estimators,
            &mut mapping,
            &mut slam,
            tap.as_ref(),
            &mut recorder,
        )?;
    }
    let out = estimators.finish();
    let (mut outputs, stage) = (out.estimators, out.stage);
    let slam: Vec<vinebench_onboard::slam::SlamOutput> =
        slam.into_iter().map(|v| v.finish()).collect();
    outputs.extend(slam.iter().map(vinebench_onboard::slam::estimator_output));
    let mapping = match (mapping, renderer) {
        (Some(m), Some(truth)) => Some(m.finish(&outputs, Some(truth))?),
        _ => None,
    };
    let estimates = estimate_spools
        .finish(outputs)
        .map_err(spool_err("estimate"))?;
    let truth = truth.finish().map_err(spool_err("ground-truth"))?;
    let fault_windows = s
        .faults
        .gnss
        .iter()
        .map(|f| {
            (
                start + Nanos::from_secs_f64(f.start_s),
                start + Nanos::from_secs_f64(f.end_s),
            )
        })
        .collect();
    let comparisons = comparisons
        .iter_mut()
        .map(|(kind, m)| drive_comparison(*kind, m.as_mut(), start, gt_rate, hard_stop, &truth))
        .collect();
    let sim = Simulation {
        comparisons,
        truth,
        estimates,
        slam,
        stage,
        messages,
        world_digest: world.digest(),
        distance_m: last_odometer,
        duration_s: (last_t - start).as_secs_f64(),
        route_completed,
        outcome: motion.outcome(),
        collisions: motion.collisions().to_vec(),
        stopped_by,
        robot: tracking.metrics(),
        fault_windows,
        mapping,
        steering: s.control.localization.clone(),
        steering_stop,
        steering_world_from_map: steering.as_ref().and_then(SteeringLoop::world_from_map),
        start,
        row_lines: (0..world.layout.count)
            .map(|r| {
                let l = &world.layout;
                let n = l.length_m.ceil() as usize;
                (0..=n)
                    .map(|k| {
                        let (p, _) = l.point(l.row_offset_m(r), (k as f64).min(l.length_m));
                        (p.x, p.y)
                    })
                    .collect()
            })
            .collect(),
        clearance: clearance.metrics().clone(),
        gnss: gnss_log,
    };
    if let Some(mut rec) = recorder {
        if let Some(m) = &sim.mapping {
            // Each map as a cloud in `world`, stamped at the end of the run.
            for sm in &m.maps {
                let c = &sm.map.cloud;
                rec.send(RecordItem::PointCloud2(
                    recording::topics::map_points(&sm.source),
                    recording::ros::PointCloud2Msg::xyz_rgb(
                        last_t,
                        vinebench_msgs::FrameId::new(vinebench_msgs::frames::names::WORLD),
                        &c.positions,
                        &c.colors,
                        &[("grvi", &c.grvi), ("elevation", &c.elevation)],
                    ),
                ));
            }
        }
        for (i, e) in sim.estimates.iter().enumerate() {
            // One pose per item: the recorder's queue holds a bounded number of items, so
            // the spool is never read into memory whole.
            for sample in e.poses.samples() {
                rec.send(RecordItem::Trajectory {
                    topic: recording::topics::estimate_odom(e.name),
                    tf_topic: (i == 0).then(|| recording::topics::TF.to_string()),
                    trajectory: Trajectory {
                        samples: vec![sample],
                    },
                });
            }
            e.poses.check().map_err(spool_err(e.name))?;
        }
        rec.send(RecordItem::Metadata(
            recording::META_RUN.to_string(),
            run_metadata(&sim),
        ));
        rec.finish()?;
    }
    Ok(sim)
}

/// Estimates move from the estimators to their spools every this many ground-truth
/// samples (0.32 s at 200 Hz).
const SPOOL_EVERY_TRUTH_SAMPLES: i64 = 64;

/// The estimates of a run or replay on their way to disk: one spool per estimator of
/// the set, filled from [`EstimatorSet::drain_poses`] as the run goes.
pub(crate) struct EstimateSpools<'a> {
    dir: Option<&'a Path>,
    writers: Vec<SpoolWriter>,
}

impl<'a> EstimateSpools<'a> {
    /// One spool per estimator of `estimators`, in `dir` (`None`: the system's temporary
    /// folder).
    pub(crate) fn new(
        dir: Option<&'a Path>,
        estimators: &EstimatorSet,
    ) -> std::io::Result<EstimateSpools<'a>> {
        let writers = estimators
            .names()
            .into_iter()
            .map(|name| SpoolWriter::create(dir, format!("{name} estimate")))
            .collect::<std::io::Result<_>>()?;
        Ok(EstimateSpools { dir, writers })
    }

    /// Moves the estimators' settled poses to their spools.
    pub(crate) fn drain(&mut self, estimators: &mut EstimatorSet) -> std::io::Result<()> {
        let mut result = Ok(());
        estimators.drain_poses(|i, sample| {
            if result.is_ok()
                && let Some(w) = self.writers.get_mut(i)
            {
                result = w.push(&sample).map(|_| ());
            }
        });
        result
    }

    /// The finished estimates: what is still in memory (each estimator's latest poses,
    /// all of them when nothing was drained, the SLAM sources after the estimators)
    /// joins the spools, in `outputs` order.
    pub(crate) fn finish(
        self,
        outputs: Vec<vinebench_onboard::estimator::EstimatorOutput>,
    ) -> std::io::Result<Vec<Estimate>> {
        let mut writers = self.writers.into_iter();
        let mut estimates = Vec::with_capacity(outputs.len());
        for o in outputs {
            let mut w = match writers.next() {
                Some(w) => w,
                None => SpoolWriter::create(self.dir, format!("{} estimate", o.name))?,
            };
            for sample in &o.trajectory.samples {
                w.push(sample)?;
            }
            estimates.push(Estimate {
                name: o.name,
                poses: w.finish()?,
                stats: o.stats,
            });
        }
        Ok(estimates)
    }
}

/// The [`recording::META_SCENARIO`] record of a run: what a replay needs to rebuild the
/// estimators exactly.
fn scenario_metadata(sc: &LoadedScenario) -> BTreeMap<String, String> {
    let o = &sc.scenario.origin;
    BTreeMap::from([
        (recording::META_KEY_TOML.to_string(), sc.resolved_toml()),
        ("file".to_string(), sc.file.clone()),
        ("origin_lat_deg".to_string(), format!("{:?}", o.lat_deg)),
        ("origin_lon_deg".to_string(), format!("{:?}", o.lon_deg)),
        ("origin_alt_m".to_string(), format!("{:?}", o.alt_m)),
        ("start_ns".to_string(), sc.start.0.to_string()),
        (
            "vinebench_version".to_string(),
            env!("CARGO_PKG_VERSION").to_string(),
        ),
    ])
}

/// The [`recording::META_RUN`] record: the robot's truth-only metrics (what the
/// expectations' pseudo-source `robot` answers) and how the run ended.
fn run_metadata(sim: &Simulation) -> BTreeMap<String, String> {
    let robot = RobotReport::new(sim);
    let mut m: BTreeMap<String, String> = ROBOT_METRICS
        .iter()
        .filter_map(|(name, _)| Some((name.to_string(), format!("{:?}", robot.metric(name)?))))
        .collect();
    m.insert("outcome".to_string(), robot.outcome.to_string());
    // What the robot steered on and when it was in the leaf walls (closed loop).
    m.insert("steering".to_string(), sim.steering.clone());
    m.insert(
        "canopy_intrusions".to_string(),
        serde_json::to_string(&sim.clearance.intrusions).unwrap_or_default(),
    );
    m.insert("world_digest".to_string(), sim.world_digest.clone());
    m.insert("distance_m".to_string(), format!("{:?}", sim.distance_m));
    m.insert("duration_s".to_string(), format!("{:?}", sim.duration_s));
    m
}

fn img_dir(d: &crate::runner::images::PngDump) -> PathBuf {
    d.dir().to_path_buf()
}

/// The MuJoCo motion model (`motion.model = "mujoco"`): the route follower of
/// [`Dynamic`] on [`vinebench_sim::physics::MujocoPhysics`], with the terrain as a
/// heightfield of `physics.mujoco.heightfield_cell_m`.
#[cfg(feature = "mujoco")]
fn mujoco_motion(
    _field: &str,
    s: &crate::scenario::Scenario,
    route: vinebench_sim::route::Route,
    robot: &RobotModel,
    world: &World,
    gravity_mps2: f64,
    sc: &LoadedScenario,
) -> Result<Box<dyn MotionModel>, RunError> {
    use vinebench_sim::physics::MujocoPhysics;
    vinebench_sim::physics::mjcf::check(&s.physics.mujoco).map_err(|e| sc.param_error(e))?;
    let (lo, hi) = world.terrain.domain();
    let cell = s.physics.mujoco.heightfield_cell_m;
    HeightGrid::check_size(lo, hi, cell, "physics.mujoco.heightfield_cell_m")
        .map_err(|e| sc.param_error(e))?;
    let grid = HeightGrid::sample(&world.terrain, lo, hi, cell);
    let obstacles = obstacles_of(world);
    let motion = Dynamic::new(
        &s.motion,
        &s.physics,
        route,
        robot,
        &world.terrain,
        gravity_mps2,
        sc.start,
        |pose| {
            MujocoPhysics::new(
                robot,
                &grid,
                &obstacles,
                &s.physics,
                s.motion.step_hz,
                gravity_mps2,
                pose,
            )
            .map_err(Into::into)
        },
    )
    .map_err(|e| sc.param_error(e))?;
    Ok(Box::new(motion))
}

/// Without the `mujoco` feature, `motion.model = "mujoco"` is an error that says how to
/// get it.
#[cfg(not(feature = "mujoco"))]
fn mujoco_motion(
    field: &str,
    _s: &crate::scenario::Scenario,
    _route: vinebench_sim::route::Route,
    _robot: &RobotModel,
    _world: &World,
    _gravity_mps2: f64,
    sc: &LoadedScenario,
) -> Result<Box<dyn MotionModel>, RunError> {
    Err(sc
        .field_error(
            field,
            "\"mujoco\" needs a vinebench built with the `mujoco` feature: run \
             `bash scripts/install-mujoco.sh`, then `cargo run --release --features mujoco -- run ...`",
        )
        .into())
}
