use super::*;
use crate::params::{HeadingMode, ImuParams, RouteKind, RouteParams, WorldParams};
use crate::physics::rapier::{HeightGrid, obstacles_of};
use crate::physics::{Obstacle, RapierPhysics, Scene};
use crate::route::build_route;
use crate::sensors::test_support::ctx_for;
use crate::sensors::{Imu, SensorModel};
use crate::world::{Terrain, World};
use vinebench_msgs::Message;

const G: f64 = 9.80;
const START: Nanos = Nanos(1_631_696_400_000_000_000);

/// A small vineyard: rows along +x (yaw 0) so waypoints are easy to write.
fn small_world(rows: u32, length_m: f64, f: impl FnOnce(&mut WorldParams)) -> World {
    let mut p = WorldParams::default();
    p.rows.count = rows;
    p.rows.length_m = length_m;
    p.rows.yaw_deg = 0.0;
    f(&mut p);
    World::generate(3, &p).unwrap()
}

fn dynamic(
    robot: &str,
    w: &World,
    route: Route,
    motion: &MotionParams,
    physics: &PhysicsParams,
) -> Dynamic<RapierPhysics<Terrain>> {
    let r = RobotModel::builtin(robot).unwrap();
    let (lo, hi) = w.terrain.domain();
    let grid = HeightGrid::sample(&w.terrain, lo, hi, physics.heightfield_cell_m);
    let obstacles = obstacles_of(w);
    Dynamic::new(motion, physics, route, &r, &w.terrain, G, START, |pose| {
        let scene = Scene {
            surface: w.terrain.clone(),
            obstacles: &obstacles,
            ground: Some(&grid),
        };
        RapierPhysics::new(&r, scene, physics, motion.step_hz, G, pose)
    })
    .unwrap()
}

/// A loop around row `row`.
fn row_loop(row: u32) -> RouteParams {
    let mut p = RouteParams::default();
    p.row_loop.row = row;
    p
}

fn motion_params() -> MotionParams {
    MotionParams {
        still_before_s: 2.0,
        still_after_s: 1.0,
        ..MotionParams::default()
    }
}

/// What a drive along a route looked like, sampled at 200 Hz.
struct Drive {
    max_cross_track_m: f64,
    end_error_m: f64,
    outcome: MotionOutcome,
    collisions: usize,
    samples: Vec<TruthSample>,
}

fn drive_route<P: Physics>(m: &mut Dynamic<P>, route: &Route) -> Drive {
    let mut t = START;
    let mut hint = 0.0;
    let mut max_ct = 0.0f64;
    let mut samples = Vec::new();
    while !m.finished() && t < START + Nanos::from_secs(1000) {
        let s = m.advance_to(t);
        let xy = s.world_from_body.translation.vector.xy();
        hint = route.closest_progress(&xy, hint, 1.0);
        let ct = (route.point_at(hint) - xy).norm();
        max_ct = max_ct.max(ct);
        if hint >= route.previous_cusp_at_or_before(hint).unwrap_or(0.0)
            && route.next_cusp_after(hint).is_some_and(|c| hint > c - 0.05)
            && s.velocity_in_world.norm() < 0.02
        {
            // At a cusp: move on to the next leg.
            hint = route.next_cusp_after(hint).unwrap_or(hint);
        }
        samples.push(s);
        t += Nanos::from_millis(5);
    }
    let last = samples
        .last()
        .map(|s| s.world_from_body.translation.vector.xy());
    Drive {
        max_cross_track_m: max_ct,
        end_error_m: last.map_or(f64::INFINITY, |p| {
            (p - route.points[route.len() - 1]).norm()
        }),
        outcome: m.outcome(),
        collisions: m.collisions().len(),
        samples,
    }
}

/// Prints how a drive went and asserts that it completed without collisions, at most
/// `max_cross_track_m` from the route and `max_end_error_m` from its end.
fn assert_drove(
    label: &str,
    route: &Route,
    d: &Drive,
    max_cross_track_m: f64,
    max_end_error_m: f64,
) {
    eprintln!(
        "{label} ({:.1} m): {:?}, cross-track {:.3} m, end {:.3} m from the route's end, {} collisions",
        route.total_length_m(),
        d.outcome,
        d.max_cross_track_m,
        d.end_error_m,
        d.collisions
    );
    assert_eq!(d.outcome, MotionOutcome::Completed, "{label}");
    assert_eq!(d.collisions, 0, "{label}");
    assert!(
        d.max_cross_track_m < max_cross_track_m,
        "{label}: cross-track {}",
        d.max_cross_track_m
    );
    assert!(
        d.end_error_m < max_end_error_m,
        "{label}: end {}",
        d.end_error_m
    );
}

/// One route of every type in a 3-row, 20 m vineyard: a row loop, a serpentine, a closed
/// polygon of waypoints and a there-and-back line.
fn every_route_type(w: &World) -> Vec<(&'static str, Route)> {
    let y0 = w.layout.lane_offset_m(0);
    let y1 = w.layout.lane_offset_m(1);
    let routes: Vec<(&'static str, RouteParams)> = vec![
        ("row_loop", RouteParams::default()),
        (
            "serpentine",
            RouteParams {
                kind: RouteKind::Serpentine,
                serpentine: crate::params::SerpentineParams {
                    first_row: 0,
                    last_row: 1,
                },
                ..RouteParams::default()
            },
        ),
        (
            "waypoints",
            RouteParams {
                kind: RouteKind::Waypoints,
                waypoints: crate::params::WaypointsParams {
                    points: vec![
                        [-3.0, y0],
                        [10.0, y0],
                        [10.0 + 0.01, y0 - 4.0],
                        [-3.0, y0 - 4.0],
                    ],
                    closed: true,
                    there_and_back: false,
                },
                ..RouteParams::default()
            },
        ),
        (
            "there_and_back",
            RouteParams {
                kind: RouteKind::Waypoints,
                waypoints: crate::params::WaypointsParams {
                    points: vec![[2.0, y1], [15.0, y1]],
                    closed: false,
                    there_and_back: true,
                },
                ..RouteParams::default()
            },
        ),
    ];
    routes
        .into_iter()
        .map(|(name, mut rp)| {
            rp.row_loop.row = 0;
            (
                name,
                build_route(&rp, &w.layout, &w.params.headlands).unwrap(),
            )
        })
        .collect()
}

#[test]
fn both_robots_drive_every_route_type() {
    let w = small_world(3, 20.0, |_| {});
    for (name, route) in every_route_type(&w) {
        for robot in ["tracked-sensorbox", "mecanum-rover"] {
            let mut m = dynamic(
                robot,
                &w,
                route.clone(),
                &motion_params(),
                &PhysicsParams::default(),
            );
            let d = drive_route(&mut m, &route);
            // The rover rides its 5 cm wheels on 2 cm rough soil with no suspension: wheels
            // lose load and traction over the bumps, and it wanders more than the tracks.
            let bound = if robot == "mecanum-rover" { 0.25 } else { 0.15 };
            assert_drove(&format!("{robot} {name}"), &route, &d, bound, 0.1);
        }
    }
}

#[test]
fn a_strafing_rover_keeps_its_heading_and_comes_back() {
    // The mecanum-strafe scenario's manoeuvre: face the row (heading offset 90°), strafe
    // 15 m along it and back without turning.
    let w = small_world(3, 30.0, |p| p.terrain.roughness_m = 0.005);
    let y = w.layout.lane_offset_m(2);
    let rp = RouteParams {
        kind: RouteKind::Waypoints,
        waypoints: crate::params::WaypointsParams {
            points: vec![[5.0, y], [20.0, y]],
            closed: false,
            there_and_back: true,
        },
        ..RouteParams::default()
    };
    let route = build_route(&rp, &w.layout, &w.params.headlands).unwrap();
    let mp = MotionParams {
        heading: HeadingMode::Fixed,
        heading_offset_deg: 90.0,
        cruise_speed_mps: 0.5,
        ..motion_params()
    };
    let mut m = dynamic(
        "mecanum-rover",
        &w,
        route.clone(),
        &mp,
        &PhysicsParams::default(),
    );
    let d = drive_route(&mut m, &route);
    let yaw_err = d
        .samples
        .iter()
        .map(|s| {
            (crate::control::heading_rad(&s.world_from_body) - std::f64::consts::FRAC_PI_2).abs()
        })
        .fold(0.0, f64::max);
    // Sideways all the way: the velocity is along body ±y.
    let sideways = d
        .samples
        .iter()
        .filter(|s| s.velocity_in_world.norm() > 0.3)
        .map(|s| {
            let v = s.world_from_body.rotation.inverse() * s.velocity_in_world;
            v.x.abs() / v.norm()
        })
        .fold(0.0, f64::max);
    eprintln!(
        "strafe: {:?}, cross-track {:.4} m, end {:.4} m, heading error {:.3}°, forward fraction {sideways:.4}",
        d.outcome,
        d.max_cross_track_m,
        d.end_error_m,
        yaw_err.to_degrees()
    );
    assert_eq!(d.outcome, MotionOutcome::Completed);
    assert!(yaw_err.to_degrees() < 1.0);
    assert!(
        sideways < 0.08,
        "moved {sideways} of its speed along body x"
    );
    assert!(d.max_cross_track_m < 0.05 && d.end_error_m < 0.05);
}

#[test]
fn a_differential_robot_cannot_hold_a_fixed_heading() {
    let w = small_world(2, 20.0, |_| {});
    let route = build_route(&row_loop(0), &w.layout, &w.params.headlands).unwrap();
    let r = RobotModel::builtin("tracked-sensorbox").unwrap();
    let mp = MotionParams {
        heading: HeadingMode::Fixed,
        ..motion_params()
    };
    let e = Dynamic::new(
        &mp,
        &PhysicsParams::default(),
        route,
        &r,
        &w.terrain,
        G,
        START,
        |_| Err::<RapierPhysics<Terrain>, _>(ParamError::new("unreachable", "", "")),
    )
    .err()
    .unwrap();
    assert_eq!(e.path, "motion.heading");
    assert!(e.expected.contains("mecanum"), "{e}");
}

#[test]
fn truth_does_not_depend_on_the_query_schedule() {
    let w = small_world(2, 20.0, |_| {});
    let route = build_route(&row_loop(0), &w.layout, &w.params.headlands).unwrap();
    let pp = PhysicsParams::default();
    let mut a = dynamic(
        "tracked-sensorbox",
        &w,
        route.clone(),
        &motion_params(),
        &pp,
    );
    let mut b = dynamic("tracked-sensorbox", &w, route, &motion_params(), &pp);
    let bits = |s: &TruthSample| -> Vec<u64> {
        s.world_from_body
            .to_homogeneous()
            .iter()
            .chain(s.velocity_in_world.iter())
            .chain(s.acceleration_in_world.iter())
            .chain(s.angular_velocity_in_body.iter())
            .chain(s.angular_acceleration_in_body.iter())
            .chain(s.drive_speeds_radps.iter())
            .map(|x| x.to_bits())
            .collect()
    };
    for k in 0..4000 {
        let t = START + Nanos::from_millis(5 * k);
        if k % 3 == 1 {
            b.advance_to(t - Nanos(1_234_567));
            b.advance_to(t - Nanos(400_001));
        }
        assert_eq!(
            bits(&a.advance_to(t)),
            bits(&b.advance_to(t)),
            "at step {k}"
        );
    }
}

#[test]
fn truth_acceleration_integrates_to_its_velocity() {
    // Between any two times, the integral of the piecewise-constant acceleration equals
    // the change of the piecewise-linear velocity: check over 1 ms pieces on an
    // off-grid schedule (what makes the interval-averaging IMU exact).
    let w = small_world(2, 20.0, |_| {});
    let route = build_route(&row_loop(0), &w.layout, &w.params.headlands).unwrap();
    let mut m = dynamic(
        "tracked-sensorbox",
        &w,
        route,
        &motion_params(),
        &PhysicsParams::default(),
    );
    let t0 = START + Nanos::from_millis(6_000) + Nanos(300_000);
    let mut v = m.advance_to(t0).velocity_in_world;
    let mut worst = 0.0f64;
    // Breakpoints of the acceleration are the half steps t_k + 0.5 ms: integrate exactly
    // by sampling the acceleration in the middle of each piece between breakpoints.
    let mut t = t0;
    let end = t0 + Nanos::from_secs(20);
    while t < end {
        let next_half = {
            let since = (t - START).0;
            let k = since.div_euclid(1_000_000);
            let half = START + Nanos(k * 1_000_000 + 500_000);
            if half > t {
                half
            } else {
                half + Nanos(1_000_000)
            }
        };
        let mid = t + Nanos((next_half - t).0 / 2);
        let a = m.advance_to(mid).acceleration_in_world;
        v += a * (next_half - t).as_secs_f64();
        t = next_half;
        let truth = m.advance_to(t).velocity_in_world;
        worst = worst.max((v - truth).norm());
    }
    eprintln!("velocity from integrated acceleration: worst error {worst:.2e} m/s over 20 s");
    assert!(worst < 1e-9, "{worst}");
}

#[test]
fn the_imu_feels_a_10_degree_slope_and_the_track_vibration() {
    // A straight climb up a 10° slope (no undulation or roughness): the mean specific
    // force at constant speed is gravity seen from the tilted IMU, 10° from its z axis;
    // the track links make it vibrate at v/pitch = 8 Hz.
    let w = small_world(2, 40.0, |p| {
        p.terrain.slope_along_deg = 10.0;
        p.terrain.undulation_m = 0.0;
        p.terrain.roughness_m = 0.0;
    });
    let y = w.layout.lane_offset_m(0);
    let rp = RouteParams {
        kind: RouteKind::Waypoints,
        waypoints: crate::params::WaypointsParams {
            points: vec![[0.0, y], [30.0, y]],
            closed: false,
            there_and_back: false,
        },
        ..RouteParams::default()
    };
    let route = build_route(&rp, &w.layout, &w.params.headlands).unwrap();
    let mp = MotionParams {
        cruise_speed_mps: 0.8,
        ..motion_params()
    };
    let mut m = dynamic(
        "tracked-sensorbox",
        &w,
        route,
        &mp,
        &PhysicsParams::default(),
    );
    let quiet = ImuParams {
        gyro_noise_density_dps_rthz: 0.0,
        gyro_bias_instability_dph: 0.0,
        accel_noise_density_ug_rthz: 0.0,
        accel_bias_instability_ug: 0.0,
        orientation_roll_pitch_sigma_deg: 0.0,
        orientation_yaw_sigma_deg: 0.0,
        ..ImuParams::default()
    };
    let mut ctx = ctx_for("tracked-sensorbox", 1);
    ctx.start = START;
    ctx.gravity_mps2 = G;
    let mut imu = Imu::new(&quiet, &ctx).unwrap();
    let mut out = Vec::new();
    let mut speeds = Vec::new();
    while imu.next_time() < START + Nanos::from_secs(40) {
        let s = m.advance_to(imu.next_time());
        speeds.push(s.velocity_in_world.norm());
        imu.sample(&s, &mut out);
    }
    let forces: Vec<Vector3<f64>> = out
        .iter()
        .filter_map(|m| match &m.msg {
            Message::Imu(i) => Some(i.linear_acceleration),
            _ => None,
        })
        .collect();
    // Cruising: 15 s to 35 s (speed within 2 % of 0.8 m/s the whole time).
    let cruise: Vec<usize> = (15 * 200..35 * 200).collect();
    assert!(
        cruise.iter().all(|&i| (speeds[i] - 0.8).abs() < 0.02),
        "not cruising"
    );
    let mean = cruise.iter().fold(Vector3::zeros(), |a, &i| a + forces[i]) / cruise.len() as f64;
    let tilt = (mean.z / mean.norm()).acos().to_degrees();
    let sd_z = (cruise
        .iter()
        .map(|&i| (forces[i].z - mean.z).powi(2))
        .sum::<f64>()
        / cruise.len() as f64)
        .sqrt();
    // Parked before the start: the same tilt, and no vibration.
    let parked: Vec<usize> = (200..300).collect();
    let p_mean = parked.iter().fold(Vector3::zeros(), |a, &i| a + forces[i]) / parked.len() as f64;
    let p_sd = (parked
        .iter()
        .map(|&i| (forces[i] - p_mean).norm_squared())
        .sum::<f64>()
        / parked.len() as f64)
        .sqrt();
    eprintln!(
        "climbing: |f| {:.4} m/s², tilt {tilt:.3}°, vertical vibration {sd_z:.3} m/s² RMS; parked: tilt {:.3}°, {p_sd:.2e} m/s² RMS",
        mean.norm(),
        (p_mean.z / p_mean.norm()).acos().to_degrees()
    );
    assert!((tilt - 10.0).abs() < 0.3, "tilt {tilt}°");
    assert!((mean.norm() - G).abs() < 0.02, "|f| {}", mean.norm());
    assert!((0.05..3.0).contains(&sd_z), "vibration {sd_z}");
    assert!(p_sd < 0.05 * sd_z, "parked robot vibrates: {p_sd}");
}

#[test]
fn a_robot_driving_into_a_post_is_stuck_and_the_collision_recorded() {
    // Row 0 runs along +x from the origin with its end post at x = 0: drive from the
    // headland along the row's centre line into it.
    let w = small_world(2, 24.0, |_| {});
    let rp = RouteParams {
        kind: RouteKind::Waypoints,
        waypoints: crate::params::WaypointsParams {
            points: vec![[-5.0, 0.0], [3.0, 0.0]],
            closed: false,
            there_and_back: false,
        },
        ..RouteParams::default()
    };
    let route = build_route(&rp, &w.layout, &w.params.headlands).unwrap();
    let pp = PhysicsParams {
        stuck_timeout_s: 3.0,
        ..PhysicsParams::default()
    };
    let mut m = dynamic(
        "tracked-sensorbox",
        &w,
        route.clone(),
        &motion_params(),
        &pp,
    );
    let d = drive_route(&mut m, &route);
    let hit = m.collisions().first().cloned();
    eprintln!("{:?}; first collision {hit:?}", d.outcome);
    let MotionOutcome::Stuck { at_s, progress_m } = d.outcome else {
        panic!("not stuck: {:?}", d.outcome)
    };
    assert!(matches!(
        hit,
        Some(CollisionEvent {
            obstacle: Obstacle::Post { row: 0, .. },
            ..
        })
    ));
    // Stopped with the chassis front (0.5 m ahead of base_link) at the post's surface
    // (x = −0.04), and given up after the timeout.
    assert!(
        (-5.0 + progress_m + 0.5 + 0.04).abs() < 0.1,
        "progress {progress_m}"
    );
    assert!(at_s > 3.0 && at_s < 30.0, "{at_s}");
    // The collision stays far inside the divergence bounds.
    let max_accel = d
        .samples
        .iter()
        .map(|s| s.acceleration_in_world.norm())
        .fold(0.0, f64::max);
    eprintln!("largest acceleration in the collision {max_accel:.1} m/s²");
    assert!(max_accel < MAX_BODY_ACCEL_MPS2 / 10.0, "{max_accel}");
}

/// A backend that behaves until step `bad_step`, then returns `velocity` (a blow-up).
struct Exploding {
    pose: Isometry3<f64>,
    steps: u64,
    bad_step: u64,
    velocity: Vector3<f64>,
}

impl Physics for Exploding {
    fn step_s(&self) -> f64 {
        1e-3
    }
    fn step(&mut self, _refs: &[f64; MAX_DRIVE_JOINTS]) {
        self.steps += 1;
    }
    fn body(&self) -> crate::physics::BodyState {
        let v = if self.steps >= self.bad_step {
            self.velocity
        } else {
            Vector3::zeros()
        };
        crate::physics::BodyState {
            world_from_body: self.pose,
            velocity_in_world: v,
            angular_velocity_in_world: Vector3::zeros(),
        }
    }
    fn joints(&self) -> [crate::physics::JointState; MAX_DRIVE_JOINTS] {
        Default::default()
    }
    fn take_collisions(&mut self, _out: &mut Vec<CollisionEvent>) {}
    fn energy_j(&self) -> f64 {
        0.0
    }
}

#[test]
fn a_diverging_backend_ends_the_run_with_physics_diverged() {
    let w = small_world(2, 24.0, |_| {});
    let route = build_route(&row_loop(0), &w.layout, &w.params.headlands).unwrap();
    let r = RobotModel::builtin("tracked-sensorbox").unwrap();
    for (velocity, needle) in [
        (Vector3::new(1e40, 0.0, 0.0), "MAX_BODY_SPEED_MPS"),
        (Vector3::new(f64::NAN, 0.0, 0.0), "not finite"),
        (Vector3::new(0.0, 0.0, -30.0), "MAX_BODY_ACCEL_MPS2"),
    ] {
        let mut m = Dynamic::new(
            &motion_params(),
            &PhysicsParams::default(),
            route.clone(),
            &r,
            &w.terrain,
            G,
            START,
            |pose| {
                Ok(Exploding {
                    pose: *pose,
                    steps: 0,
                    bad_step: 2500,
                    velocity,
                })
            },
        )
        .unwrap();
        let d = drive_route(&mut m, &route);
        let MotionOutcome::PhysicsDiverged { at_s, reason } = &d.outcome else {
            panic!("not diverged: {:?}", d.outcome)
        };
        assert!((at_s - 2.5).abs() < 1e-9, "{at_s}");
        assert!(reason.contains(needle), "{reason}");
        assert!(d.outcome.is_failure());
        // Nothing non-finite or huge reached the truth; the run ended right there.
        let last = d.samples.last().unwrap();
        assert!((last.stamp - START).as_secs_f64() <= 2.5 + 0.005);
        for s in &d.samples {
            assert!(
                s.velocity_in_world.norm() < 1.0 && s.acceleration_in_world.norm() < 1e3,
                "{s:?}"
            );
            assert!(
                s.world_from_body
                    .translation
                    .vector
                    .iter()
                    .all(|c| c.is_finite())
            );
        }
    }
}

#[test]
fn a_12_tonne_chassis_tips_over() {
    // The finding: a 12-tonne chassis (100 times the built-in's) on the built-in's
    // ground contact springs flips over, and the run passed.
    let text = crate::robot::BUILTIN_MODELS[0]
        .2
        .replacen(r#"<mass value="120.0"/>"#, r#"<mass value="12000"/>"#, 1)
        .replacen(
            r#"<inertia ixx="4.9" ixy="0" ixz="0" iyy="10.4" iyz="0" izz="12.1"/>"#,
            r#"<inertia ixx="490" ixy="0" ixz="0" iyy="1040" iyz="0" izz="1210"/>"#,
            1,
        );
    let r = RobotModel::from_urdf_str(&text, "heavy.urdf").unwrap();
    assert!(r.inertia.mass_kg > 12_000.0);
    let w = small_world(2, 24.0, |_| {});
    let route = build_route(&row_loop(0), &w.layout, &w.params.headlands).unwrap();
    let physics = PhysicsParams::default();
    let motion = motion_params();
    let (lo, hi) = w.terrain.domain();
    let grid = HeightGrid::sample(&w.terrain, lo, hi, physics.heightfield_cell_m);
    let obstacles = obstacles_of(&w);
    let mut m = Dynamic::new(
        &motion,
        &physics,
        route.clone(),
        &r,
        &w.terrain,
        G,
        START,
        |pose| {
            let scene = Scene {
                surface: w.terrain.clone(),
                obstacles: &obstacles,
                ground: Some(&grid),
            };
            RapierPhysics::new(&r, scene, &physics, motion.step_hz, G, pose)
        },
    )
    .unwrap();
    let d = drive_route(&mut m, &route);
    eprintln!("{:?}", d.outcome);
    let MotionOutcome::TippedOver {
        at_s,
        tilted_at_s,
        tilt_deg,
    } = d.outcome
    else {
        panic!("did not tip over: {:?}", d.outcome)
    };
    assert!(tilt_deg > TIP_OVER_TILT_DEG);
    assert!(
        (at_s - tilted_at_s - TIP_OVER_HOLD_S).abs() < 2e-3,
        "{at_s} {tilted_at_s}"
    );
    assert!(at_s < 30.0 && d.outcome.is_failure());
}

/// Both robots drive every route type on MuJoCo, through this small vineyard's tight
/// headland turns, on rough ground (2 cm), within 0.3 m of the route (on rapier: 0.15 m
/// for the tracks, 0.25 m for the rover; measured on MuJoCo: 0.25 m and 0.27 m).
#[cfg(feature = "mujoco")]
#[test]
fn every_route_type_on_mujoco() {
    use crate::physics::MujocoPhysics;
    let w = small_world(3, 20.0, |_| {});
    let physics = PhysicsParams::default();
    let motion = motion_params();
    let (lo, hi) = w.terrain.domain();
    let grid = HeightGrid::sample(&w.terrain, lo, hi, physics.mujoco.heightfield_cell_m);
    let obstacles = obstacles_of(&w);
    for (name, route) in every_route_type(&w) {
        for robot in ["tracked-sensorbox", "mecanum-rover"] {
            let r = RobotModel::builtin(robot).unwrap();
            let mut m = Dynamic::new(
                &motion,
                &physics,
                route.clone(),
                &r,
                &w.terrain,
                G,
                START,
                |pose| {
                    MujocoPhysics::new(&r, &grid, &obstacles, &physics, motion.step_hz, G, pose)
                        .map_err(Into::into)
                },
            )
            .unwrap();
            let d = drive_route(&mut m, &route);
            assert_drove(&format!("MuJoCo {robot} {name}"), &route, &d, 0.3, 0.15);
        }
    }
}
