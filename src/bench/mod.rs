//! `vinebench bench`: the speed figures kept in `docs/PERFORMANCE.md`.
//!
//! - EIF prediction throughput: [`InsCore::predict`] (nominal propagation and the
//!   block-structured covariance propagation with the tracking-camera clone active) on
//!   deterministic synthetic IMU samples, one core.
//! - Whole-simulation real-time factor: the default scenario (a closed loop around a
//!   120 m row, no cameras, rapier3d physics) simulated, estimated and scored, without
//!   writing files; and the same with no estimator (physics and the IMU, GNSS,
//!   tracking-camera and odometry sensors), to separate simulation from estimation cost.
//! - Physics step cost of each built-in robot on the default vineyard's terrain (rapier3d
//!   rigid body, ground-contact model, motors), driving forward.
//!
//! The criterion benches (`cargo bench`) measure the same things with statistics;
//! this command gives a quick table on any machine. [`mapper`] and [`recording`] add the
//! mapper's, the recording's and the sweeps' figures (`--only mapper`, `--only recording`,
//! `--only sweep`).

pub mod mapper;
pub mod recording;
pub mod sweep;

use crate::runner::{RunError, score, simulate};
use crate::scenario::{LoadedScenario, ScenarioError};
use nalgebra::{UnitQuaternion, Vector3};
use std::hint::black_box;
use std::time::Instant;
use thiserror::Error;
use vinebench_msgs::defaults::DEFAULTS_TOML;
use vinebench_onboard::estimator::ins::{InsCore, Mat15, NavState, ProcessNoise};

/// Physics steps per timed run: 10 s of driving straight at 0.8 m/s, open loop, before
/// the robot drifts into a row (contacts with trunks make steps about three times dearer).
pub const PHYSICS_BENCH_STEPS: usize = 10_000;

/// IMU period of the synthetic samples, s (200 Hz).
pub const SYNTHETIC_IMU_DT_S: f64 = 0.005;

/// A benchmark that could not run.
#[derive(Debug, Error)]
pub enum BenchError {
    /// The embedded defaults did not load (a bug).
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    /// The simulation failed.
    #[error(transparent)]
    Run(#[from] RunError),
    /// A benchmark's world or robot could not be built (a bug).
    #[error("benchmark setup: {0}")]
    Setup(String),
}

/// Deterministic IMU samples `(specific force, angular rate)` in the IMU frame of a
/// gently turning, vibrating vehicle, at [`SYNTHETIC_IMU_DT_S`] (no RNG needed).
pub fn synthetic_imu(n: usize) -> Vec<(Vector3<f64>, Vector3<f64>)> {
    (0..n)
        .map(|k| {
            let t = k as f64 * SYNTHETIC_IMU_DT_S;
            let f = Vector3::new(0.3 * (0.7 * t).sin(), 0.2 * (1.3 * t).cos(), 9.81)
                + Vector3::new((37.0 * t).sin(), (41.0 * t).cos(), (43.0 * t).sin()) * 0.05;
            let w = Vector3::new(
                0.01 * (2.0 * t).sin(),
                0.02 * (3.0 * t).cos(),
                0.3 * (0.1 * t).sin(),
            );
            (f, w)
        })
        .collect()
}

/// An INS core at rest with a dense, positive-definite covariance and the clone active.
pub fn synthetic_core() -> InsCore {
    let nav = NavState::at_rest(
        Vector3::new(1.0, 2.0, 0.5),
        UnitQuaternion::from_euler_angles(0.01, 0.02, 0.3),
    );
    let a = Mat15::from_fn(|i, j| {
        if i == j {
            1e-2
        } else {
            1e-4 / (1.0 + (i + j) as f64)
        }
    });
    let mut core = InsCore::new(nav, a * a.transpose(), 9.80665);
    core.reclone();
    core
}

/// One figure of the bench.
#[derive(Clone, Debug)]
pub struct Figure {
    /// What was measured.
    pub name: &'static str,
    /// The value.
    pub value: f64,
    /// Its unit.
    pub unit: &'static str,
    /// The target from the issue tracker, if any (same unit, "at least").
    pub target: Option<f64>,
}

/// EIF predictions per second (best of `repeats` runs of `steps` predictions).
pub fn eif_predictions_per_second(steps: usize, repeats: usize) -> f64 {
    let data = synthetic_imu(steps);
    let noise = ProcessNoise::from_datasheet(0.01, 0.002, 60.0, 20.0);
    let mut best = f64::INFINITY;
    for _ in 0..repeats.max(1) {
        let mut core = synthetic_core();
        let t0 = Instant::now();
        for (f, w) in &data {
            core.predict(black_box(SYNTHETIC_IMU_DT_S), f, w, &noise);
        }
        black_box(&core.nav.p);
        best = best.min(t0.elapsed().as_secs_f64());
    }
    steps as f64 / best
}

/// Real-time factor of the default scenario (simulate + estimate + score), best of
/// `repeats`; with `estimators = false` the estimators are switched off.
pub fn row_loop_real_time_factor(estimators: bool, repeats: usize) -> Result<f64, BenchError> {
    let mut sc = LoadedScenario::from_str(DEFAULTS_TOML, "scenarios/defaults.toml")?;
    if !estimators {
        sc.scenario.estimators.run.clear();
    }
    let mut best = f64::INFINITY;
    let mut simulated = 0.0;
    for _ in 0..repeats.max(1) {
        let t0 = Instant::now();
        let sim = simulate(&sc, None)?;
        black_box(score(&sc, &sim)?);
        best = best.min(t0.elapsed().as_secs_f64());
        simulated = sim.duration_s;
    }
    Ok(simulated / best)
}

/// The scene of the physics benchmarks: the default vineyard (seed 1: terrain, posts and
/// trunks), the built-in robot `robot`, its pose standing in lane 2 along the rows with
/// `base_link` `sunk_m` below its ride height, and the joint speeds that drive it forward
/// at 0.8 m/s.
struct BenchScene {
    world: vinebench_sim::world::World,
    robot: vinebench_sim::robot::RobotModel,
    obstacles: Vec<vinebench_sim::physics::rapier::ObstacleShape>,
    pose: nalgebra::Isometry3<f64>,
    refs: [f64; vinebench_sim::robot::MAX_DRIVE_JOINTS],
}

/// Gravity of the physics benchmarks, m/s².
const BENCH_GRAVITY_MPS2: f64 = 9.80;

fn bench_scene(
    robot: &str,
    sunk_m: impl Fn(&vinebench_sim::robot::RobotModel) -> f64,
) -> Result<BenchScene, BenchError> {
    use vinebench_sim::motion::dynamic::standing_pose;
    use vinebench_sim::params::WorldParams;
    use vinebench_sim::physics::rapier::obstacles_of;
    use vinebench_sim::robot::RobotModel;
    use vinebench_sim::world::World;
    let invalid = |e: String| BenchError::Setup(e);
    let world = World::generate(1, &WorldParams::default()).map_err(|e| invalid(e.to_string()))?;
    let r = RobotModel::builtin(robot).map_err(|e| invalid(e.to_string()))?;
    let obstacles = obstacles_of(&world);
    // In lane 2, heading along the rows.
    let start = world.layout.point(world.layout.lane_offset_m(2), 2.0);
    let yaw = start.1.y.atan2(start.1.x);
    let pose = standing_pose(
        &world.terrain,
        start.0,
        yaw,
        r.geometry.ride_height_m - sunk_m(&r),
    );
    let refs = r.drive.kinematics().joint_speeds(0.8, 0.0, 0.0);
    Ok(BenchScene {
        world,
        robot: r,
        obstacles,
        pose,
        refs,
    })
}

/// The built-in robot `robot` at rest (at its static sinkage) in lane 2 of the default
/// vineyard (terrain, posts and trunks), 1 kHz rapier steps, with the joint speeds that
/// drive it forward at 0.8 m/s.
pub fn physics_bench_setup(
    robot: &str,
) -> Result<
    (
        vinebench_sim::physics::RapierPhysics<vinebench_sim::world::Terrain>,
        [f64; vinebench_sim::robot::MAX_DRIVE_JOINTS],
    ),
    BenchError,
> {
    use vinebench_sim::motion::dynamic::static_sinkage_m;
    use vinebench_sim::params::PhysicsParams;
    use vinebench_sim::physics::rapier::HeightGrid;
    use vinebench_sim::physics::{RapierPhysics, Scene};
    let b = bench_scene(robot, |r| static_sinkage_m(r, BENCH_GRAVITY_MPS2))?;
    let params = PhysicsParams::default();
    let (lo, hi) = b.world.terrain.domain();
    let grid = HeightGrid::sample(&b.world.terrain, lo, hi, params.heightfield_cell_m);
    let scene = Scene {
        surface: b.world.terrain.clone(),
        obstacles: &b.obstacles,
        ground: Some(&grid),
    };
    let p = RapierPhysics::new(
        &b.robot,
        scene,
        &params,
        1000.0,
        BENCH_GRAVITY_MPS2,
        &b.pose,
    )
    .map_err(|e| BenchError::Setup(e.to_string()))?;
    Ok((p, b.refs))
}

/// The same scene on MuJoCo (heightfield of `physics.mujoco.heightfield_cell_m`).
#[cfg(feature = "mujoco")]
pub fn mujoco_bench_setup(
    robot: &str,
) -> Result<
    (
        vinebench_sim::physics::MujocoPhysics,
        [f64; vinebench_sim::robot::MAX_DRIVE_JOINTS],
    ),
    BenchError,
> {
    use vinebench_sim::params::PhysicsParams;
    use vinebench_sim::physics::MujocoPhysics;
    use vinebench_sim::physics::rapier::HeightGrid;
    let b = bench_scene(robot, |_| 0.0)?;
    let params = PhysicsParams::default();
    let (lo, hi) = b.world.terrain.domain();
    let grid = HeightGrid::sample(&b.world.terrain, lo, hi, params.mujoco.heightfield_cell_m);
    let p = MujocoPhysics::new(
        &b.robot,
        &grid,
        &b.obstacles,
        &params,
        1000.0,
        BENCH_GRAVITY_MPS2,
        &b.pose,
    )
    .map_err(|e| BenchError::Setup(e.to_string()))?;
    Ok((p, b.refs))
}

/// Microseconds per physics step of a backend that `setup` builds (best of `repeats`
/// runs of `steps` steps; setting up is not timed).
pub fn physics_step_micros_of<P: vinebench_sim::physics::Physics>(
    setup: impl Fn() -> Result<(P, [f64; vinebench_sim::robot::MAX_DRIVE_JOINTS]), BenchError>,
    steps: usize,
    repeats: usize,
) -> Result<f64, BenchError> {
    let mut best = f64::INFINITY;
    for _ in 0..repeats.max(1) {
        let (mut p, refs) = setup()?;
        let t0 = Instant::now();
        for _ in 0..steps {
            p.step(black_box(&refs));
        }
        black_box(p.body());
        best = best.min(t0.elapsed().as_secs_f64());
    }
    Ok(best / steps as f64 * 1e6)
}

/// Microseconds per rapier step of the built-in robot `robot` driving forward on the
/// default vineyard's terrain among its posts and trunks (best of `repeats` runs of
/// `steps` steps at 1 kHz, after [`physics_bench_setup`]).
pub fn physics_step_micros(robot: &str, steps: usize, repeats: usize) -> Result<f64, BenchError> {
    physics_step_micros_of(|| physics_bench_setup(robot), steps, repeats)
}

/// Real-time factor of a camera scenario's first `seconds` simulated seconds
/// (simulation with rendering, noise and every sensor, estimation; no files), best of
/// `repeats`. The renderer's set-up (geometry, BVH, textures, shadow map) is not timed.
pub fn camera_scenario_real_time_factor(
    toml: &str,
    name: &str,
    seconds: f64,
    repeats: usize,
) -> Result<f64, BenchError> {
    use crate::runner::{setup, simulate_setup};
    let mut sc = LoadedScenario::from_str(toml, name)?;
    sc.scenario.max_duration_s = seconds;
    sc.scenario.render.debug_png_every = 0;
    let mut best = f64::INFINITY;
    let mut simulated = 0.0;
    for _ in 0..repeats.max(1) {
        let built = setup(&sc)?;
        let t0 = Instant::now();
        let sim = simulate_setup(&sc, built, None)?;
        best = best.min(t0.elapsed().as_secs_f64());
        simulated = sim.duration_s;
    }
    Ok(simulated / best)
}

/// The renderer of a `rows`-row default vineyard (rows along east, default row length)
/// with `backend`.
pub fn bench_renderer(
    rows: u32,
    backend: vinebench_sim::params::RenderBackend,
) -> Result<vinebench_sim::render::shade::Renderer, BenchError> {
    bench_renderer_sized(rows, None, backend)
}

/// The renderer of a default vineyard of `rows` rows along east, each `length_m` long
/// (`None`: the default length), with `backend`.
pub fn bench_renderer_sized(
    rows: u32,
    length_m: Option<f64>,
    backend: vinebench_sim::params::RenderBackend,
) -> Result<vinebench_sim::render::shade::Renderer, BenchError> {
    use vinebench_sim::params::{RenderParams, WorldParams};
    let mut p = WorldParams::default();
    p.rows.count = rows;
    p.rows.yaw_deg = 0.0;
    if let Some(l) = length_m {
        p.rows.length_m = l;
    }
    let world = vinebench_sim::world::World::generate(1, &p)
        .map_err(|e| BenchError::Setup(e.to_string()))?;
    let rp = RenderParams {
        backend,
        ..RenderParams::default()
    };
    vinebench_sim::render::build_renderer(&world, &rp).map_err(|e| BenchError::Setup(e.to_string()))
}

/// Camera poses of the render benchmarks: 1.2 m up in lanes of the vineyard, looking
/// along the rows, across them and obliquely.
pub fn bench_views() -> Vec<nalgebra::Isometry3<f64>> {
    use vinebench_sim::render::camera::look_at as view;
    vec![
        view(Vector3::new(10.0, 3.75, 1.2), Vector3::new(1.0, 0.0, -0.1)),
        view(Vector3::new(60.0, 6.25, 1.2), Vector3::new(0.0, 1.0, -0.2)),
        view(
            Vector3::new(90.0, 8.75, 1.2),
            Vector3::new(-1.0, 0.6, -0.15),
        ),
        view(
            Vector3::new(118.0, 1.25, 1.2),
            Vector3::new(-1.0, 0.0, 0.05),
        ),
    ]
}

/// Rows of the reference-size vineyard ([`reference_views`]).
pub const REFERENCE_ROWS: u32 = 4;
/// Row length of the reference-size vineyard, m: with [`REFERENCE_ROWS`] rows of default
/// vines about 1.9 M instanced triangles, the size of the 1.5 M-triangle vineyard on which
/// issue #4 measured Embree and set the default backend's target (≥ 50 % of Embree).
pub const REFERENCE_LENGTH_M: f64 = 30.0;

/// Camera poses in the reference-size vineyard ([`REFERENCE_ROWS`] rows of
/// [`REFERENCE_LENGTH_M`]): the same four kinds of view as [`bench_views`] (along a lane,
/// across the rows, obliquely, back along a lane), 1.2 m up in its lanes.
pub fn reference_views() -> Vec<nalgebra::Isometry3<f64>> {
    use vinebench_sim::render::camera::look_at as view;
    vec![
        view(Vector3::new(2.0, 3.75, 1.2), Vector3::new(1.0, 0.0, -0.1)),
        view(Vector3::new(12.0, 1.25, 1.2), Vector3::new(0.0, 1.0, -0.2)),
        view(
            Vector3::new(20.0, 6.25, 1.2),
            Vector3::new(-1.0, 0.6, -0.15),
        ),
        view(Vector3::new(28.0, 1.25, 1.2), Vector3::new(-1.0, 0.0, 0.05)),
    ]
}

/// Primary rays per second (millions) of `renderer`'s ray caster at 640×480 over
/// `views`, 8×8-tile packets on all rayon threads, first hit only; best of `repeats`.
pub fn cast_mrays(
    renderer: &vinebench_sim::render::shade::Renderer,
    views: &[nalgebra::Isometry3<f64>],
    repeats: usize,
) -> f64 {
    cast_mrays_with(
        renderer.caster(),
        renderer.scene().trace.origin_in_world,
        views,
        repeats,
    )
}

/// [`cast_mrays`] with `caster`, whose scene frame's origin is `origin` in the world.
pub fn cast_mrays_with(
    caster: &dyn vinebench_sim::render::trace::RayCaster,
    origin: Vector3<f64>,
    views: &[nalgebra::Isometry3<f64>],
    repeats: usize,
) -> f64 {
    use rayon::prelude::*;
    use vinebench_sim::render::camera::Intrinsics;
    use vinebench_sim::render::trace::{Hit, PACKET_SIZE, RayPacket};
    let intr = Intrinsics::from_hfov(640, 480, 87.0, Default::default());
    let rays = intr.pixel_rays();
    let mut best = f64::INFINITY;
    for _ in 0..repeats.max(1) {
        let t0 = Instant::now();
        for pose in views {
            let o = pose.translation.vector - origin;
            let r = pose.rotation.to_rotation_matrix();
            let hits: usize = (0..60u32)
                .into_par_iter()
                .map(|ty| {
                    let mut cam = [[0.0f32; PACKET_SIZE]; 3];
                    let mut p = RayPacket {
                        origin: [o.x as f32, o.y as f32, o.z as f32],
                        dir: [[0.0; PACKET_SIZE]; 3],
                        len: 0,
                        t_min: 0.0,
                        t_max: 200.0,
                    };
                    let mut hits = [Hit::MISS; PACKET_SIZE];
                    let mut n_hit = 0;
                    for tx in 0..80u32 {
                        let n = rays.fill_tile(tx * 8, ty * 8, 8, 8, &mut cam);
                        for (k, dir) in p.dir.iter_mut().enumerate() {
                            let row = [r[(k, 0)] as f32, r[(k, 1)] as f32, r[(k, 2)] as f32];
                            for (l, d) in dir[..n].iter_mut().enumerate() {
                                *d = row[0] * cam[0][l] + row[1] * cam[1][l] + row[2] * cam[2][l];
                            }
                        }
                        p.len = n;
                        caster.cast_packet(&p, &mut hits);
                        n_hit += hits[..n].iter().filter(|h| h.is_hit()).count();
                    }
                    n_hit
                })
                .sum();
            black_box(hits);
        }
        best = best.min(t0.elapsed().as_secs_f64());
    }
    (views.len() * 640 * 480) as f64 / best / 1e6
}

/// Shaded 640×480 frames per second of `renderer` over [`bench_views`] (ray casting,
/// textures, shadow map, sky; no noise or encoding), best of `repeats`.
pub fn shaded_frames_per_second(
    renderer: &vinebench_sim::render::shade::Renderer,
    repeats: usize,
) -> f64 {
    use vinebench_sim::render::camera::Intrinsics;
    use vinebench_sim::render::shade::Frame;
    let intr = Intrinsics::from_hfov(640, 480, 87.0, Default::default());
    let rays = intr.pixel_rays();
    let views = bench_views();
    let mut frame = Frame::new(640, 480);
    let mut best = f64::INFINITY;
    for _ in 0..repeats.max(1) {
        let t0 = Instant::now();
        for pose in &views {
            renderer.render(&rays, pose, (1.0 / intr.fx) as f32, 200.0, &mut frame);
        }
        best = best.min(t0.elapsed().as_secs_f64());
    }
    views.len() as f64 / best
}

/// Milliseconds of the D435 depth model ([`StereoDepthNoise`]: occlusion, edges, the
/// correlated disparity noise, range gates, millimetres) on one rendered 640×480 depth
/// frame of each of [`bench_views`] (the D435's 640×480 depth mode), all threads; best of
/// `repeats` rounds, mean over the views.
///
/// [`StereoDepthNoise`]: vinebench_sim::render::camera::StereoDepthNoise
pub fn depth_model_ms(renderer: &vinebench_sim::render::shade::Renderer, repeats: usize) -> f64 {
    use vinebench_sim::render::camera::{
        CameraSpec, D435DepthMode, DepthScratch, StereoDepthNoise,
    };
    use vinebench_sim::render::shade::Frame;
    let spec = CameraSpec::d435_depth(D435DepthMode::W640H480, 15.0);
    let Some(stereo) = spec.stereo else {
        return f64::NAN;
    };
    let intr = spec.intrinsics;
    let model = StereoDepthNoise::new(&intr, &stereo);
    let rays = intr.pixel_rays();
    let views = bench_views();
    let mut frame = Frame::new(intr.width, intr.height);
    let depths: Vec<Vec<f32>> = views
        .iter()
        .map(|pose| {
            renderer.render(&rays, pose, (1.0 / intr.fx) as f32, 200.0, &mut frame);
            frame.depth_m.clone()
        })
        .collect();
    let mut out = vec![0u16; depths.first().map_or(0, Vec::len)];
    let mut scratch = DepthScratch::new();
    let mut rng = vinebench_sim::rng::stream(35, "bench.depth");
    let mut best = f64::INFINITY;
    for _ in 0..repeats.max(1) {
        let t0 = Instant::now();
        for depth in &depths {
            model.apply(
                intr.width,
                intr.height,
                depth,
                &mut out,
                &mut scratch,
                &mut rng,
            );
        }
        best = best.min(t0.elapsed().as_secs_f64());
    }
    1e3 * best / depths.len().max(1) as f64
}

/// The camera motion the [`camera_motion_ms`] benchmark renders with: 1 m/s forward and
/// 0.3 rad/s of yaw (a robot turning into the next lane), in the optical frame.
pub fn bench_camera_motion() -> vinebench_sim::render::blur::CameraMotion {
    vinebench_sim::render::blur::CameraMotion {
        linear_mps: Vector3::new(0.0, 0.0, 1.0),
        angular_radps: Vector3::new(0.0, 0.3, 0.0),
    }
}

/// Milliseconds of a rolling-shutter camera's motion passes on one rendered 752×480 frame
/// (93° HFOV, the rover's ZED 2i-like cameras) at each of [`bench_views`], moving as
/// [`bench_camera_motion`]: the rolling shutter (18 ms readout, the ZED 2i's) and then the
/// motion blur (8 ms exposure), all threads; best of `repeats` rounds, mean over the views.
/// (The passes' bits are held by `render::blur`'s unit tests.)
pub fn camera_motion_ms(renderer: &vinebench_sim::render::shade::Renderer, repeats: usize) -> f64 {
    use vinebench_sim::render::blur::{motion_blur, rolling_shutter};
    use vinebench_sim::render::camera::Intrinsics;
    use vinebench_sim::render::shade::Frame;
    let intr = Intrinsics::from_hfov(752, 480, 93.0, Default::default());
    let rays = intr.pixel_rays();
    let motion = bench_camera_motion();
    let mut frame = Frame::new(intr.width, intr.height);
    let sharp: Vec<Frame> = bench_views()
        .iter()
        .map(|pose| {
            renderer.render(&rays, pose, (1.0 / intr.fx) as f32, 200.0, &mut frame);
            frame.clone()
        })
        .collect();
    let mut scratch = Vec::new();
    let mut best = f64::INFINITY;
    for _ in 0..repeats.max(1) {
        let mut elapsed = 0.0;
        for s in &sharp {
            frame.clone_from(s);
            let t0 = Instant::now();
            rolling_shutter(
                &mut frame,
                &mut scratch,
                &rays,
                intr.fx,
                intr.fy,
                &motion,
                0.018,
            );
            motion_blur(
                &mut frame,
                &mut scratch,
                &rays,
                intr.fx,
                intr.fy,
                &motion,
                0.008,
            );
            elapsed += t0.elapsed().as_secs_f64();
        }
        best = best.min(elapsed);
    }
    1e3 * best / sharp.len().max(1) as f64
}

/// The SLAM feature front-end ([`vinebench_onboard::slam::bench`]) on a rendered, rectified 752×480
/// stereo pair (93° HFOV, 12 cm baseline: the rover's ZED 2i-like cameras) at the first
/// of [`bench_views`]: ORB extraction of one image, stereo matching of the pair, and the
/// whole pair with the two extractions on two rayon tasks; best of `repeats`. Also the
/// tracking's motion-only BA on synthetic observations
/// ([`vinebench_onboard::slam::bench::time_motion_ba`]).
pub fn slam_feature_figures(
    renderer: &vinebench_sim::render::shade::Renderer,
    repeats: usize,
) -> Result<Vec<Figure>, BenchError> {
    use vinebench_onboard::slam::{FrontEndConfig, GrayImage, StereoCamera};
    use vinebench_sim::render::camera::{BrownConrady, Intrinsics, linear_to_srgb_u8};
    use vinebench_sim::render::shade::Frame;
    let intr = Intrinsics::from_hfov(752, 480, 93.0, BrownConrady::NONE);
    let rays = intr.pixel_rays();
    let left_pose = bench_views()[0];
    let cam = StereoCamera {
        fx: intr.fx,
        baseline_m: 0.12,
    };
    let grey = |pose: &nalgebra::Isometry3<f64>| {
        let mut f = Frame::new(752, 480);
        renderer.render(&rays, pose, (1.0 / intr.fx) as f32, 200.0, &mut f);
        let px = f.linear.chunks_exact(3);
        let luma = px.map(|c| linear_to_srgb_u8(0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]));
        GrayImage::from_vec(752, 480, luma.collect())
            .ok_or_else(|| BenchError::Setup("rendered frame size".into()))
    };
    let left = grey(&left_pose)?;
    let right = grey(&(left_pose * nalgebra::Translation3::new(cam.baseline_m, 0.0, 0.0)))?;
    let t = vinebench_onboard::slam::bench::time_front_end(
        &FrontEndConfig::default(),
        &cam,
        &left,
        &right,
        repeats * 10,
    )
    .map_err(|e| BenchError::Setup(e.to_string()))?;
    let (motion_ba_ms, motion_ba_inliers) =
        vinebench_onboard::slam::bench::time_motion_ba(200, repeats * 10);
    let fig = |name, value, unit, target| Figure {
        name,
        value,
        unit,
        target,
    };
    Ok(vec![
        fig(
            "slam tracking: motion-only BA of the rig pose, 200 observations from 2 cameras (a quarter wrong), 4 rounds",
            motion_ba_ms,
            "ms",
            None,
        ),
        fig(
            "slam tracking: inliers of those 200 (150 right)",
            motion_ba_inliers as f64,
            "",
            None,
        ),
        fig(
            "slam features: ORB extraction (pyramid, adaptive FAST, SSC, BRIEF) of one 752x480 image, one thread",
            t.extract_ms_per_image,
            "ms",
            None,
        ),
        fig(
            "slam features: stereo matching of one 752x480 pair",
            t.stereo_ms_per_pair,
            "ms",
            None,
        ),
        fig(
            "slam features: one 752x480 stereo pair, both extractions (2 rayon tasks) + stereo + grid",
            t.pair_ms,
            "ms",
            None,
        ),
        // 30 Hz tracking of two stereo pairs needs at least 60 pairs/s from the front-end.
        fig(
            "slam features: stereo pairs per second through the front-end",
            1e3 / t.pair_ms,
            "pairs/s",
            Some(60.0),
        ),
        fig(
            "slam features: keypoints of the left image",
            t.keypoints_left as f64,
            "",
            None,
        ),
        fig(
            "slam features: left keypoints with a stereo depth (< 40 baselines)",
            t.stereo_depths as f64,
            "",
            None,
        ),
    ])
}

/// Names of the figures [`cast_pair`] pushes for one world.
struct PairNames {
    /// Built-in, Mrays/s.
    bvh: &'static str,
    /// Embree at this CPU's widest instruction set, Mrays/s.
    embree: &'static str,
    /// Built-in / Embree, per cent (the target's figure).
    ratio: &'static str,
    /// Per entry of [`EMBREE_LIMITED_ISAS`]: Embree limited to it, Mrays/s, and the
    /// built-in's per cent of that.
    limited: [[&'static str; 2]; EMBREE_LIMITED_ISAS.len()],
}

/// Instruction sets the tracer bench also limits Embree to (`max_isa`), widest first:
/// the built-in caster's SIMD is 4-wide (SSE), and Embree's speed, so the ratio, depends
/// on the vector width it runs (8-wide with AVX2, 16-wide with AVX-512). Where the CPU
/// lacks one, Embree runs the widest it has below it.
#[cfg_attr(not(feature = "embree"), allow(dead_code))]
const EMBREE_LIMITED_ISAS: [&str; 2] = ["avx2", "sse4.2"];

/// Primary-ray speed of the built-in `bvh` renderer on `views` and, with the `embree`
/// feature, of Embree on the same scene: at this CPU's widest instruction set and limited
/// to each of [`EMBREE_LIMITED_ISAS`]; rounds interleaved, best round of each. Pushes the
/// speeds and the built-in's per cent of each Embree's, the first with its target.
fn cast_pair(
    bvh: &vinebench_sim::render::shade::Renderer,
    views: &[nalgebra::Isometry3<f64>],
    rounds: usize,
    out: &mut Vec<Figure>,
    names: &PairNames,
    target_pct: f64,
) -> Result<(), BenchError> {
    let origin = bvh.scene().trace.origin_in_world;
    // Embree's casters of the same scene (the one `[render] backend = "embree"` builds):
    // at its default (this CPU's widest instruction set), then limited.
    #[cfg_attr(not(feature = "embree"), allow(unused_mut))]
    let mut embree: Vec<Box<dyn vinebench_sim::render::trace::RayCaster>> = Vec::new();
    #[cfg(feature = "embree")]
    for device_config in std::iter::once(String::new())
        .chain(EMBREE_LIMITED_ISAS.map(|isa| format!("max_isa={isa}")))
    {
        use vinebench_sim::render::embree::{EmbreeCaster, EmbreeOptions};
        let options = EmbreeOptions {
            device_config,
            ..EmbreeOptions::default()
        };
        let caster = EmbreeCaster::with_options(&bvh.scene().trace, &options)
            .map_err(|e| BenchError::Setup(e.to_string()))?;
        embree.push(Box::new(caster));
    }
    let mut best_bvh = 0.0f64;
    let mut best_embree = vec![0.0f64; embree.len()];
    for _ in 0..rounds.max(1) {
        best_bvh = best_bvh.max(cast_mrays(bvh, views, 1));
        for (e, best) in embree.iter().zip(&mut best_embree) {
            *best = best.max(cast_mrays_with(e.as_ref(), origin, views, 1));
        }
    }
    out.push(Figure {
        name: names.bvh,
        value: best_bvh,
        unit: "Mrays/s",
        target: None,
    });
    let labels = std::iter::once([names.embree, names.ratio]).chain(names.limited);
    for (i, (&best, [speed, ratio])) in best_embree.iter().zip(labels).enumerate() {
        if best <= 0.0 {
            continue;
        }
        out.push(Figure {
            name: speed,
            value: best,
            unit: "Mrays/s",
            target: None,
        });
        out.push(Figure {
            name: ratio,
            value: 100.0 * best_bvh / best,
            unit: "%",
            target: (i == 0).then_some(target_pct),
        });
    }
    Ok(())
}

/// The tracked camera scenario (three RGB-D cameras), embedded.
pub const CAMERA_ROW_TOML: &str = include_str!("../../scenarios/camera-row.toml");
/// The rover camera scenario (two stereo pairs and a tag camera), embedded.
pub const ROVER_OCCLUDER_TOML: &str = include_str!("../../scenarios/rover-occluder.toml");

/// The rendering figures: ray casting and shading speed on a 10-row × 120 m vineyard,
/// renderer memory, and the real-time factor of both camera rigs; with `tracer_only`
/// just the ray casting (built-in and, with the `embree` feature, Embree on the same
/// rays in the same run).
pub fn render_figures(quick: bool, tracer_only: bool) -> Result<Vec<Figure>, BenchError> {
    use vinebench_sim::params::RenderBackend;
    let repeats = if quick { 1 } else { 3 };
    let seconds = if quick { 4.0 } else { 10.0 };
    let mut out = Vec::new();
    let t0 = Instant::now();
    let bvh = bench_renderer(10, RenderBackend::Bvh)?;
    let build_s = t0.elapsed().as_secs_f64();
    out.push(Figure {
        name: "render: 10-row x 120 m vineyard, renderer build (geometry, BVH, textures, shadow map)",
        value: build_s,
        unit: "s",
        target: None,
    });
    out.push(Figure {
        name: "render: 10-row x 120 m vineyard, renderer memory (scene, BVH, textures, shadow map)",
        value: bvh.memory_bytes() as f64 / 1e6,
        unit: "MB",
        target: None,
    });
    // Built-in and Embree on the same rays, rounds interleaved (best round of each): this
    // machine's speed drifts by tens of per cent within a minute, the ratio much less.
    let rounds = if quick { 3 } else { 10 };
    cast_pair(
        &bvh,
        &bench_views(),
        rounds,
        &mut out,
        &PairNames {
            bvh: "render: primary rays, built-in BVH, 640x480 first hit, all threads",
            embree: "render: primary rays, Embree 3, same rays, same run",
            ratio: "render: primary rays, built-in BVH / Embree 3 (10-row x 120 m vineyard)",
            limited: [
                [
                    "render: primary rays, Embree 3 limited to AVX2 (8-wide)",
                    "render: primary rays, built-in BVH / Embree 3 at AVX2 (10-row)",
                ],
                [
                    "render: primary rays, Embree 3 limited to SSE4.2 (4-wide, as the built-in)",
                    "render: primary rays, built-in BVH / Embree 3 at SSE4.2 (10-row)",
                ],
            ],
        },
        90.0,
    )?;
    // The same on a vineyard of the size issue #4 measured Embree on.
    let small = bench_renderer_sized(REFERENCE_ROWS, Some(REFERENCE_LENGTH_M), RenderBackend::Bvh)?;
    out.push(Figure {
        name: "render: 4-row x 30 m vineyard, instanced triangles",
        value: small.scene().instanced_triangles() as f64 / 1e6,
        unit: "M",
        target: None,
    });
    cast_pair(
        &small,
        &reference_views(),
        rounds,
        &mut out,
        &PairNames {
            bvh: "render: 4-row x 30 m vineyard, primary rays, built-in BVH",
            embree: "render: 4-row x 30 m vineyard, primary rays, Embree 3",
            ratio: "render: 4-row x 30 m vineyard, primary rays, built-in BVH / Embree 3",
            limited: [
                [
                    "render: 4-row x 30 m vineyard, primary rays, Embree 3 limited to AVX2",
                    "render: 4-row x 30 m vineyard, built-in BVH / Embree 3 at AVX2",
                ],
                [
                    "render: 4-row x 30 m vineyard, primary rays, Embree 3 limited to SSE4.2",
                    "render: 4-row x 30 m vineyard, built-in BVH / Embree 3 at SSE4.2",
                ],
            ],
        },
        100.0,
    )?;
    drop(small);
    if tracer_only {
        return Ok(out);
    }
    out.push(Figure {
        name: "render: shaded 640x480 frames (cast + textures + shadows), all threads",
        value: shaded_frames_per_second(&bvh, repeats),
        unit: "frames/s",
        target: None,
    });
    out.push(Figure {
        name: "render: D435 depth model (occlusion, edges, noise) of one 640x480 frame, all threads",
        value: depth_model_ms(&bvh, repeats),
        unit: "ms",
        target: None,
    });
    out.push(Figure {
        name: "render: rolling shutter + motion blur of one 752x480 frame (1 m/s, 0.3 rad/s), all threads",
        value: camera_motion_ms(&bvh, repeats),
        unit: "ms",
        target: None,
    });
    out.extend(slam_feature_figures(&bvh, repeats)?);
    drop(bvh);
    // Issue #4's absolute real-time targets (2× and 1×) are retired: on 2 cores even
    // Embree's casting alone stays below them (docs/PERFORMANCE.md); issue #35 measures
    // the runs against their casting-only bound instead.
    out.push(Figure {
        name: "camera-row: tracked rig, 3 RGB-D 640x480 at 15 Hz + IMU/GNSS/physics, real-time factor",
        value: camera_scenario_real_time_factor(
            CAMERA_ROW_TOML,
            "scenarios/camera-row.toml",
            seconds,
            1,
        )?,
        unit: "x",
        target: None,
    });
    out.push(Figure {
        name: "rover-occluder: 2 stereo pairs 752x480 at 15 Hz + 1920x1080 tag camera at 5 Hz, real-time factor",
        value: camera_scenario_real_time_factor(
            ROVER_OCCLUDER_TOML,
            "scenarios/rover-occluder.toml",
            seconds,
            1,
        )?,
        unit: "x",
        target: None,
    });
    Ok(out)
}

/// The box-occluder SLAM scenario (two stereo pairs, a tag camera), embedded.
pub const CSL_BOX_OCCLUDER_TOML: &str = include_str!("../../scenarios/csl-box-occluder.toml");

/// The stream a SLAM benchmark feeds: the first `seconds` of `scenarios/csl-box-occluder.toml`
/// simulated once (without its SLAM), every delivered message kept in delivery order,
/// with the robot's static transforms and the scenario's SLAM configuration.
pub fn slam_bench_stream(
    seconds: f64,
) -> Result<
    (
        Vec<vinebench_msgs::Message>,
        vinebench_msgs::StaticTransforms,
        vinebench_onboard::slam::SlamConfig,
    ),
    BenchError,
> {
    use crate::runner::{setup, simulate_setup};
    let mut sc =
        LoadedScenario::from_str(CSL_BOX_OCCLUDER_TOML, "scenarios/csl-box-occluder.toml")?;
    sc.scenario.max_duration_s = seconds;
    sc.scenario.render.debug_png_every = 0;
    let mut built = setup(&sc)?;
    // The SLAMs run on the kept stream, not during the simulation.
    built.slam.clear();
    let (tx, rx) = std::sync::mpsc::channel();
    built.tap = Some(tx);
    let static_transforms = built.robot.static_transforms.clone();
    simulate_setup(&sc, built, None)?;
    Ok((
        rx.try_iter().collect(),
        static_transforms,
        sc.scenario.slam.clone(),
    ))
}

/// Rig frames per second of the SLAM `cfg` over `messages` (every message pushed in
/// order: feature extraction, stereo, tracking, keyframes, local BA, tags and loops
/// included; the final `finish` not), best of `repeats`, and the frames tracked.
pub fn slam_frames_per_second(
    cfg: &vinebench_onboard::slam::SlamConfig,
    messages: &[vinebench_msgs::Message],
    static_transforms: &vinebench_msgs::StaticTransforms,
    repeats: usize,
) -> Result<(f64, usize), BenchError> {
    let mut best = f64::INFINITY;
    let mut frames = 0;
    for _ in 0..repeats.max(1) {
        let mut slam = vinebench_onboard::slam::VisualSlam::new(
            vinebench_onboard::slam::SLAM_SOURCE,
            cfg.clone(),
            static_transforms.clone(),
            None,
        )
        .map_err(|e| BenchError::Setup(e.to_string()))?;
        let t0 = Instant::now();
        for m in messages {
            slam.push(m)
                .map_err(|e| BenchError::Setup(format!("slam on the benchmark stream: {e}")))?;
        }
        best = best.min(t0.elapsed().as_secs_f64());
        frames = slam.finish().frames.len();
    }
    Ok((frames as f64 / best, frames))
}

/// The whole SLAM's speed on rendered frames of the box-occluder scenario (see
/// [`slam_bench_stream`]): the two-pair rig with tags on all threads and on one, and the
/// single-camera baseline. The renderer does not share the cores: the stream is rendered
/// first.
pub fn slam_tracking_figures(quick: bool) -> Result<Vec<Figure>, BenchError> {
    let (seconds, repeats) = if quick { (6.0, 1) } else { (15.0, 3) };
    let (messages, tf, cfg) = slam_bench_stream(seconds)?;
    let rig = &cfg;
    let single = vinebench_onboard::slam::SlamBaseline::SingleCamera.config(&cfg);
    let (rig_fps, frames) = slam_frames_per_second(rig, &messages, &tf, repeats)?;
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .map_err(|e| BenchError::Setup(e.to_string()))?;
    let (rig_fps_1, _) = one.install(|| slam_frames_per_second(rig, &messages, &tf, repeats))?;
    let (single_fps, _) = slam_frames_per_second(&single, &messages, &tf, repeats)?;
    Ok(vec![
        Figure {
            name: "slam: front+rear 752x480 stereo pairs + side tag camera, whole SLAM on the box-occluder stream, rig frames/s, all threads",
            value: rig_fps,
            unit: "frames/s",
            target: Some(30.0),
        },
        Figure {
            name: "slam: the same, one thread",
            value: rig_fps_1,
            unit: "frames/s",
            target: None,
        },
        Figure {
            name: "slam: single-camera baseline (front pair only, no tags), frames/s, all threads",
            value: single_fps,
            unit: "frames/s",
            target: None,
        },
        Figure {
            name: "slam: rig frames in the stream",
            value: frames as f64,
            unit: "frames",
            target: None,
        },
    ])
}

/// Runs every figure.
pub fn run_all(quick: bool) -> Result<Vec<Figure>, BenchError> {
    let (steps, repeats) = if quick { (200_000, 2) } else { (2_000_000, 5) };
    Ok(vec![
        Figure {
            name: "EIF IMU predictions per second (15-state clone active, one core)",
            value: eif_predictions_per_second(steps, repeats),
            unit: "1/s",
            target: Some(1e6),
        },
        Figure {
            name: "120 m row loop, simulation + EIF + single-source + scoring, real-time factor",
            value: row_loop_real_time_factor(true, repeats.min(3))?,
            unit: "x",
            target: Some(100.0),
        },
        Figure {
            name: "120 m row loop, physics + IMU/GNSS/tracking camera/odometry sensors only, real-time factor",
            value: row_loop_real_time_factor(false, repeats.min(3))?,
            unit: "x",
            target: Some(50.0),
        },
        Figure {
            name: "physics step, tracked-sensorbox (rapier3d, 16 track probes, 2 motors)",
            value: physics_step_micros("tracked-sensorbox", PHYSICS_BENCH_STEPS, repeats)?,
            unit: "us",
            target: None,
        },
        Figure {
            name: "physics step, mecanum-rover (rapier3d, 4 wheel probes, 4 motors)",
            value: physics_step_micros("mecanum-rover", PHYSICS_BENCH_STEPS, repeats)?,
            unit: "us",
            target: None,
        },
    ]
    .into_iter()
    .chain(mujoco_figures(repeats)?)
    .collect())
}

/// The MuJoCo backend's step on the same robots and terrain (with the `mujoco` feature).
#[cfg(feature = "mujoco")]
fn mujoco_figures(repeats: usize) -> Result<Vec<Figure>, BenchError> {
    Ok(vec![
        Figure {
            name: "physics step, tracked-sensorbox (MuJoCo 3.17, 2 belts of 8 spheres, heightfield 0.1 m)",
            value: physics_step_micros_of(
                || mujoco_bench_setup("tracked-sensorbox"),
                PHYSICS_BENCH_STEPS,
                repeats,
            )?,
            unit: "us",
            target: None,
        },
        Figure {
            name: "physics step, mecanum-rover (MuJoCo 3.17, 4 wheels of 16 rollers, heightfield 0.1 m)",
            value: physics_step_micros_of(
                || mujoco_bench_setup("mecanum-rover"),
                PHYSICS_BENCH_STEPS,
                repeats,
            )?,
            unit: "us",
            target: None,
        },
    ])
}

/// Without the `mujoco` feature there is no MuJoCo figure.
#[cfg(not(feature = "mujoco"))]
fn mujoco_figures(_repeats: usize) -> Result<Vec<Figure>, BenchError> {
    Ok(Vec::new())
}
