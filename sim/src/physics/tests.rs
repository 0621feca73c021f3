//! Physics of the rapier backend against closed forms and physical properties.

use super::rapier::{HeightGrid, ObstacleShape, RapierPhysics};
use super::{Obstacle, Physics, Scene};
use crate::control::TwistCommand;
use crate::motion::dynamic::{DriveController, standing_pose, static_sinkage_m};
use crate::params::PhysicsParams;
use crate::robot::{MAX_DRIVE_JOINTS, RobotModel};
use crate::world::{PlaneSurface, Surface, SurfacePoint};
use nalgebra::{Isometry3, Matrix2, Vector2, Vector3};

pub(super) const G: f64 = 9.80;
pub(super) const TRACKED: &str = "tracked-sensorbox";
pub(super) const ROVER: &str = "mecanum-rover";

pub(super) fn robot(name: &str) -> RobotModel {
    RobotModel::builtin(name).unwrap()
}

pub(super) fn plane(slope_x_deg: f64) -> PlaneSurface {
    PlaneSurface {
        z0_m: 0.0,
        gradient: Vector2::new(slope_x_deg.to_radians().tan(), 0.0),
    }
}

fn sim<S: Surface>(
    name: &str,
    surface: S,
    obstacles: &[ObstacleShape],
    yaw: f64,
) -> RapierPhysics<S> {
    sim_with(name, surface, obstacles, yaw, &PhysicsParams::default())
}

fn sim_with<S: Surface>(
    name: &str,
    surface: S,
    obstacles: &[ObstacleShape],
    yaw: f64,
    params: &PhysicsParams,
) -> RapierPhysics<S> {
    let r = robot(name);
    let pose = standing_pose(
        &surface,
        Vector2::zeros(),
        yaw,
        r.geometry.ride_height_m - static_sinkage_m(&r, G),
    );
    let scene = Scene {
        surface,
        obstacles,
        ground: None,
    };
    RapierPhysics::new(&r, scene, params, 1000.0, G, &pose).unwrap()
}

fn run<S: Surface>(p: &mut RapierPhysics<S>, refs: [f64; MAX_DRIVE_JOINTS], seconds: f64) {
    let n = (seconds / p.step_s()).round() as usize;
    for _ in 0..n {
        p.step(&refs);
    }
}

pub(super) fn yaw_of(p: &Isometry3<f64>) -> f64 {
    let x = p.rotation * Vector3::x();
    x.y.atan2(x.x)
}

fn position<S: Surface>(p: &RapierPhysics<S>) -> Vector3<f64> {
    p.body().world_from_body.translation.vector
}

#[test]
fn parked_robots_settle_to_their_static_sinkage() {
    // Weight shared by the contact springs: sinkage = m·g / Σk.
    for (name, k_total) in [(TRACKED, 2.0 * 80_000.0), (ROVER, 4.0 * 37_000.0)] {
        // Without the ride ripple, which offsets each probe's radius.
        let params = PhysicsParams {
            ripple_m: 0.0,
            ..PhysicsParams::default()
        };
        let mut p = sim_with(name, plane(0.0), &[], 0.0, &params);
        run(&mut p, [0.0; 4], 3.0);
        let r = robot(name);
        let sinkage = r.inertia.mass_kg * G / k_total;
        let b = p.body();
        let z = b.world_from_body.translation.vector.z;
        // The probes share the load unevenly (the centre of mass is not above the
        // centre of the probes), but a rigid body on springs sinks by m·g/Σk at the
        // stiffness-weighted centre: exact for the uniform tracks and wheels here.
        assert!(
            (r.geometry.ride_height_m - z - sinkage).abs() < 0.02 * sinkage,
            "{name}: base_link at {z}, sinkage {sinkage}"
        );
        assert!(
            b.velocity_in_world.norm() < 1e-4,
            "{name}: {:?}",
            b.velocity_in_world
        );
        let forces: f64 = p.contact().states().iter().map(|s| s.normal_force_n).sum();
        assert!(
            (forces - r.inertia.mass_kg * G).abs() < 1e-3 * forces,
            "{name}: {forces} N"
        );
    }
}

#[test]
fn parked_on_a_10_degree_slope_it_holds_and_energy_does_not_grow() {
    for name in [TRACKED, ROVER] {
        // Facing uphill and across the slope.
        for yaw in [0.0, std::f64::consts::FRAC_PI_2] {
            let mut p = sim(name, plane(10.0), &[], yaw);
            run(&mut p, [0.0; 4], 5.0);
            let settled = position(&p);
            let mut e_prev = p.energy_j();
            let e0 = e_prev;
            let mut max_rise = 0.0f64;
            for _ in 0..55 {
                run(&mut p, [0.0; 4], 1.0);
                let e = p.energy_j();
                max_rise = max_rise.max(e - e_prev);
                e_prev = e;
            }
            let drift = (position(&p) - settled).norm();
            eprintln!(
                "{name} yaw {yaw:.2}: drift {drift:.2e} m in 55 s, energy change {:.2e} J, largest 1 s rise {max_rise:.2e} J",
                e_prev - e0
            );
            // No creep: the shear springs hold the robot (a regularised Coulomb model would
            // creep at v_ε·tan θ/μ ≈ cm/s). Energy: kinetic + gravitational + contact
            // springs, where the shear springs' stiffness μF_n/K varies with the load, so
            // it is conserved only to ~1e-6 J between samples. 1e-4 J is what the 166 kg
            // robot gains by rising 60 nm: a growing oscillation or a creep uphill would
            // exceed it by orders of magnitude.
            assert!(drift < 1e-3, "{name} crept {drift} m");
            assert!(
                max_rise < 1e-4,
                "{name}: energy rose by {max_rise} J in 1 s"
            );
            assert!(
                e_prev - e0 < 1e-4,
                "{name}: energy rose by {} J in 55 s",
                e_prev - e0
            );
        }
    }
}

#[test]
fn mecanum_pure_strafe_moves_sideways_without_turning() {
    // Open loop: the wheels turn at the inverse kinematics of (0, 0.5 m/s, 0) for 10 s,
    // i.e. 5 m commanded to the left, with no heading feedback at all.
    let r = robot(ROVER);
    let k = r.drive.kinematics();
    for (vx, vy) in [(0.0, 0.5), (0.0, -0.5), (0.35, 0.35)] {
        let mut p = sim(ROVER, plane(0.0), &[], 0.0);
        run(&mut p, [0.0; 4], 1.0);
        let start = position(&p);
        let w = k.joint_speeds(vx, vy, 0.0);
        run(&mut p, w, 10.0);
        let moved = position(&p) - start;
        let commanded = Vector3::new(vx, vy, 0.0) * 10.0;
        let along = moved.dot(&commanded) / commanded.norm();
        let across = (moved - commanded.normalize() * along).xy().norm();
        let drift_deg = yaw_of(&p.body().world_from_body).to_degrees();
        eprintln!(
            "twist ({vx}, {vy}): moved {along:.3} m of {:.3} commanded, {across:.3} m off line, heading drift {drift_deg:.3}°",
            commanded.norm()
        );
        assert!(
            along >= 0.9 * commanded.norm(),
            "moved {along} of {}",
            commanded.norm()
        );
        assert!(
            across < 0.05 * commanded.norm(),
            "{across} m off the commanded direction"
        );
        assert!(drift_deg.abs() < 2.0, "heading drifted {drift_deg}°");
    }
}

/// Runs the drive controller (yaw-rate loop at 50 Hz) on a twist command for `seconds`,
/// returning the measured yaw rates (body z, per 20 ms tick).
pub(super) fn drive<P: Physics>(
    p: &mut P,
    c: &mut DriveController,
    cmd: &TwistCommand,
    seconds: f64,
) -> Vec<f64> {
    let ticks = (seconds * 50.0).round() as usize;
    let mut rates = Vec::with_capacity(ticks);
    for _ in 0..ticks {
        let b = p.body();
        let rate = (b.world_from_body.rotation.inverse() * b.angular_velocity_in_world).z;
        rates.push(rate);
        c.command(cmd, rate, 0.02);
        for _ in 0..20 {
            let refs = c.references(p.step_s());
            p.step(&refs);
        }
    }
    rates
}

#[test]
fn tracked_turn_in_place_follows_the_commanded_rate_with_its_centre_still() {
    let r = robot(TRACKED);
    let params = PhysicsParams::default();
    let cmd = TwistCommand {
        vx_mps: 0.0,
        vy_mps: 0.0,
        wz_radps: 0.5,
    };
    // Open loop (no gyro feedback): lateral skid makes the robot turn slower than the
    // slip-free kinematics say (the ICR expansion of skid-steer robots).
    let mut p = sim(TRACKED, plane(0.0), &[], 0.0);
    let mut open = DriveController::new(&r, 0.0, 0.6);
    let rates = drive(&mut p, &mut open, &cmd, 8.0);
    let open_rate = rates[150..].iter().sum::<f64>() / (rates.len() - 150) as f64;
    let icr = cmd.wz_radps / open_rate;
    // Closed loop: the controller's yaw-rate integrator makes up for the skid.
    let mut p = sim(TRACKED, plane(0.0), &[], 0.0);
    let start = position(&p);
    let mut closed = DriveController::new(&r, params.yaw_rate_gain_per_s, 0.6);
    let rates = drive(
        &mut p,
        &mut closed,
        &cmd,
        2.0 * std::f64::consts::PI / 0.5 + 2.0,
    );
    let steady = &rates[150..];
    let mean = steady.iter().sum::<f64>() / steady.len() as f64;
    let worst = steady.iter().map(|r| (r - 0.5).abs()).fold(0.0, f64::max);
    let drift = (position(&p) - start).xy().norm();
    eprintln!(
        "open loop: {open_rate:.4} rad/s (ICR expansion {icr:.2}); closed loop: mean {mean:.4} rad/s, worst {worst:.4}; centre drift {drift:.4} m"
    );
    assert!((1.05..2.5).contains(&icr), "ICR expansion {icr}");
    assert!((mean - 0.5).abs() < 0.01, "mean yaw rate {mean}");
    assert!(worst < 0.05, "yaw rate off by up to {worst} rad/s");
    // The centre of mass lies 3.4 cm ahead of the tracks' centre, loading their front
    // halves more, so the body turns about a point a few cm ahead of base_link.
    assert!(drift < 0.1, "centre drifted {drift} m in a full turn");
}

#[test]
fn tracks_slip_more_when_they_pull_harder() {
    // Track slip ratio i = 1 − v/(r·ω) at 0.8 m/s on flat ground and up a 10° slope:
    // the steady traction needed uphill (m·g·sin θ more) needs more shear, so more slip
    // (brush model: i ∝ force at small slip).
    let mut slips = Vec::new();
    for slope in [0.0, 10.0] {
        let mut p = sim(TRACKED, plane(slope), &[], 0.0);
        run(&mut p, [8.0, 8.0, 0.0, 0.0], 8.0);
        let a = position(&p);
        let ja = p.joints()[0].angle_rad;
        run(&mut p, [8.0, 8.0, 0.0, 0.0], 4.0);
        let ground = (position(&p) - a).norm();
        let belt = (p.joints()[0].angle_rad - ja) * 0.1;
        slips.push(1.0 - ground / belt);
    }
    eprintln!(
        "slip ratio: flat {:.4}, 10° uphill {:.4}",
        slips[0], slips[1]
    );
    assert!(slips[0] > 0.0 && slips[0] < 0.02, "flat slip {}", slips[0]);
    assert!(
        slips[1] > 2.0 * slips[0],
        "uphill slip {} vs flat {}",
        slips[1],
        slips[0]
    );
}

#[test]
fn driving_into_a_post_is_a_collision_and_stops_the_robot() {
    // A trellis post 3 m ahead on the robot's centre line; the tracked robot drives at it
    // at 0.8 m/s with its motors at full torque if needed.
    let post = ObstacleShape {
        obstacle: Obstacle::Post { row: 0, index: 7 },
        base_in_world: Vector3::new(3.0, 0.0, 0.0),
        radius_m: 0.04,
        height_m: 1.9,
        box_footprint_m: None,
    };
    let mut p = sim(TRACKED, plane(0.0), std::slice::from_ref(&post), 0.0);
    run(&mut p, [8.0, 8.0, 0.0, 0.0], 8.0);
    let mut hits = Vec::new();
    p.take_collisions(&mut hits);
    assert!(!hits.is_empty(), "no collision recorded");
    assert_eq!(hits[0].obstacle, Obstacle::Post { row: 0, index: 7 });
    assert_eq!(hits[0].link, "base_link", "the chassis box is in front");
    // Stopped at the post: the chassis box's front (x = 0.5 m from base_link) at the
    // post's surface (x = 2.96 m).
    let b = p.body();
    let x = b.world_from_body.translation.vector.x;
    eprintln!(
        "stopped at x = {x:.4} m, speed {:.2e} m/s",
        b.velocity_in_world.norm()
    );
    assert!(
        b.velocity_in_world.norm() < 0.02,
        "still moving: {:?}",
        b.velocity_in_world
    );
    assert!((x + 0.5 - 2.96).abs() < 0.02, "front at {}", x + 0.5);
    // No second Started event while it keeps pushing.
    p.take_collisions(&mut hits);
    run(&mut p, [8.0, 8.0, 0.0, 0.0], 1.0);
    let mut more = Vec::new();
    p.take_collisions(&mut more);
    assert!(more.is_empty(), "{more:?}");
}

#[test]
fn same_inputs_give_bit_identical_states() {
    let go = || {
        let mut p = sim(TRACKED, plane(4.0), &[], 0.3);
        run(&mut p, [6.0, 9.0, 0.0, 0.0], 3.0);
        run(&mut p, [9.0, 4.0, 0.0, 0.0], 2.0);
        let b = p.body();
        let mut bits: Vec<u64> = b
            .world_from_body
            .to_homogeneous()
            .iter()
            .chain(b.velocity_in_world.iter())
            .chain(b.angular_velocity_in_world.iter())
            .map(|x| x.to_bits())
            .collect();
        bits.extend(p.joints().iter().map(|j| j.speed_radps.to_bits()));
        bits
    };
    assert_eq!(go(), go());
}

/// A gently undulating surface.
#[derive(Clone, Copy)]
struct Waves;

impl Surface for Waves {
    fn sample(&self, x: f64, y: f64) -> SurfacePoint {
        let (a, k) = (0.3, 0.2);
        SurfacePoint {
            height_m: 1.0 + a * (k * x).sin() * (k * y).cos(),
            gradient: Vector2::new(
                a * k * (k * x).cos() * (k * y).cos(),
                -a * k * (k * x).sin() * (k * y).sin(),
            ),
            hessian: Matrix2::zeros(),
        }
    }
}

#[test]
fn terrain_heightfield_matches_the_surface() {
    // The chassis collides with a heightfield sampled from the surface: equal to it at
    // the grid nodes, within the linear interpolation error between them
    // (cell²/8·max|h''| = 0.25²/8·(0.3·0.2²·2)).
    let r = robot(TRACKED);
    let grid = HeightGrid::sample(
        &Waves,
        Vector2::new(-10.0, -5.0),
        Vector2::new(10.0, 5.0),
        0.25,
    );
    let pose = standing_pose(&Waves, Vector2::zeros(), 0.0, 0.2);
    let mut p = RapierPhysics::new(
        &r,
        Scene {
            surface: Waves,
            obstacles: &[],
            ground: Some(&grid),
        },
        &PhysicsParams::default(),
        1000.0,
        G,
        &pose,
    )
    .unwrap();
    // The broad phase of the query pipeline is built by the first step.
    p.step(&[0.0; MAX_DRIVE_JOINTS]);
    let bound = 0.25f64.powi(2) / 8.0 * (0.3 * 0.2 * 0.2 * 2.0);
    for (x, y) in [
        (-9.75, -4.75),
        (0.0, 0.0),
        (3.25, -1.5),
        (9.75, 4.75),
        (-6.5, 2.25),
    ] {
        let h = p.heightfield_at(x, y).unwrap();
        assert!(
            (h - Waves.sample(x, y).height_m).abs() < 1e-9,
            "node ({x}, {y}): {h}"
        );
    }
    for (x, y) in [(0.1, 0.13), (-7.37, 3.91), (4.44, -2.22)] {
        let h = p.heightfield_at(x, y).unwrap();
        let e = (h - Waves.sample(x, y).height_m).abs();
        assert!(e <= bound, "({x}, {y}): {e} > {bound}");
    }
    assert_eq!(p.heightfield_at(30.0, 0.0), None);
}
