//! The MuJoCo backend against physical properties, and cross-checked against the rapier
//! backend on the same manoeuvres (cargo feature `mujoco`).

use super::mujoco::MujocoPhysics;
use super::rapier::{HeightGrid, ObstacleShape, RapierPhysics};
use super::tests::{G, ROVER, TRACKED, drive, plane, robot, yaw_of};
use super::{CollisionEvent, Obstacle, Physics, Scene};
use crate::control::TwistCommand;
use crate::motion::dynamic::{DriveController, standing_pose, static_sinkage_m};
use crate::params::PhysicsParams;
use crate::robot::{MAX_DRIVE_JOINTS, RobotModel};
use crate::world::{PlaneSurface, Surface};
use nalgebra::{Isometry3, Vector2, Vector3};

fn start_pose<S: Surface>(r: &RobotModel, surface: &S, yaw: f64) -> Isometry3<f64> {
    standing_pose(
        surface,
        Vector2::zeros(),
        yaw,
        r.geometry.ride_height_m - static_sinkage_m(r, G),
    )
}

fn grid<S: Surface>(surface: &S) -> HeightGrid {
    HeightGrid::sample(
        surface,
        Vector2::new(-12.0, -12.0),
        Vector2::new(12.0, 12.0),
        PhysicsParams::default().mujoco.heightfield_cell_m,
    )
}

fn mujoco<S: Surface>(
    name: &str,
    surface: &S,
    obstacles: &[ObstacleShape],
    yaw: f64,
) -> MujocoPhysics {
    let r = robot(name);
    MujocoPhysics::new(
        &r,
        &grid(surface),
        obstacles,
        &PhysicsParams::default(),
        1000.0,
        G,
        &start_pose(&r, surface, yaw),
    )
    .unwrap()
}

fn rapier<S: Surface + Clone>(name: &str, surface: &S, yaw: f64) -> RapierPhysics<S> {
    rapier_with(name, surface, yaw, &PhysicsParams::default())
}

/// Hard ground for the rapier backend: no soil shear, no ride ripple (Coulomb contact, as
/// MuJoCo's).
fn hard_ground() -> PhysicsParams {
    PhysicsParams {
        shear_deformation_m: 1e-3,
        ripple_m: 0.0,
        ..PhysicsParams::default()
    }
}

fn rapier_with<S: Surface + Clone>(
    name: &str,
    surface: &S,
    yaw: f64,
    params: &PhysicsParams,
) -> RapierPhysics<S> {
    let r = robot(name);
    let scene = Scene {
        surface: surface.clone(),
        obstacles: &[],
        ground: None,
    };
    RapierPhysics::new(&r, scene, params, 1000.0, G, &start_pose(&r, surface, yaw)).unwrap()
}

/// The pose after a manoeuvre and what it took.
#[derive(Debug)]
struct Outcome {
    end: Isometry3<f64>,
    /// Unwrapped heading change, rad.
    turned_rad: f64,
    /// Path length of base_link in the plane, m.
    path_m: f64,
    /// Seconds of driving until the target was reached.
    drive_s: f64,
}

/// What a manoeuvre drives until.
#[derive(Clone, Copy, Debug)]
enum Target {
    /// Distance along the start heading, m.
    Forward(f64),
    /// Distance to the left of the start heading, m.
    Left(f64),
    /// Heading change, rad (counter-clockwise; negative: clockwise).
    Turn(f64),
}

/// Settles for 1 s, drives the controller (yaw-rate loop at 50 Hz, the `[physics]` gain)
/// on `cmd` until `target` is reached (at most 60 s), then stands still for 2 s.
fn manoeuvre<P: Physics>(p: &mut P, name: &str, cmd: &TwistCommand, target: Target) -> Outcome {
    let r = robot(name);
    let params = PhysicsParams::default();
    let mut c = DriveController::new(&r, params.yaw_rate_gain_per_s, 0.6);
    let still = TwistCommand::default();
    let tick = |p: &mut P, c: &mut DriveController, command: &TwistCommand| {
        let b = p.body();
        let rate = (b.world_from_body.rotation.inverse() * b.angular_velocity_in_world).z;
        c.command(command, rate, 0.02);
        for _ in 0..20 {
            let refs = c.references(p.step_s());
            p.step(&refs);
        }
    };
    for _ in 0..50 {
        tick(p, &mut c, &still);
    }
    let start = p.body().world_from_body;
    let mut last = start;
    let (mut path_m, mut turned_rad) = (0.0, 0.0);
    let advance = |p: &P, last: &mut Isometry3<f64>, path_m: &mut f64, turned_rad: &mut f64| {
        let now = p.body().world_from_body;
        *path_m += (now.translation.vector - last.translation.vector)
            .xy()
            .norm();
        let d = yaw_of(&now) - yaw_of(last);
        *turned_rad +=
            (d + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
        *last = now;
    };
    let mut drive_s = 0.0;
    loop {
        let offset = start.inverse() * last.translation.vector.xyz();
        let done = match target {
            Target::Forward(d) => offset.x >= d,
            Target::Left(d) => offset.y >= d,
            Target::Turn(a) => turned_rad * a.signum() >= a.abs(),
        };
        if done || drive_s > 60.0 {
            break;
        }
        tick(p, &mut c, cmd);
        drive_s += 0.02;
        advance(p, &mut last, &mut path_m, &mut turned_rad);
    }
    for _ in 0..100 {
        tick(p, &mut c, &still);
        advance(p, &mut last, &mut path_m, &mut turned_rad);
    }
    Outcome {
        end: last,
        turned_rad,
        path_m,
        drive_s,
    }
}

fn cmd(vx: f64, vy: f64, wz: f64) -> TwistCommand {
    TwistCommand {
        vx_mps: vx,
        vy_mps: vy,
        wz_radps: wz,
    }
}

#[test]
fn parked_robots_settle_at_ride_height_and_stay_put() {
    for name in [TRACKED, ROVER] {
        let r = robot(name);
        let surface = plane(0.0);
        let mut m = mujoco(name, &surface, &[], 0.3);
        for _ in 0..1000 {
            m.step(&[0.0; MAX_DRIVE_JOINTS]);
        }
        let settled = m.body().world_from_body;
        let e0 = m.energy_j();
        for _ in 0..2000 {
            m.step(&[0.0; MAX_DRIVE_JOINTS]);
        }
        let end = m.body().world_from_body;
        let drift = (end.translation.vector - settled.translation.vector).norm();
        let z = end.translation.z;
        eprintln!(
            "{name}: z {z:.4} m (ride height {:.4}), drift {drift:.2e} m, energy {e0:.3} → {:.3} J",
            r.geometry.ride_height_m,
            m.energy_j()
        );
        // Soft contacts sink by millimetres at most.
        assert!(
            (z - r.geometry.ride_height_m).abs() < 0.005,
            "{name}: z {z}"
        );
        assert!(drift < 1e-3, "{name}: crept {drift} m");
        assert!((yaw_of(&end) - 0.3).abs() < 1e-3, "{name}: heading moved");
        assert!(m.energy_j() <= e0 + 1e-3, "{name}: energy grew");
    }
}

#[test]
fn the_terrain_heightfield_is_oriented_like_the_surface() {
    // Tilted along x and y: a robot parked away from the origin sits at the surface height
    // there (a heightfield with rows and columns swapped, or y flipped, would not).
    let surface = PlaneSurface {
        z0_m: 0.2,
        gradient: Vector2::new(0.08, -0.05),
    };
    for name in [TRACKED, ROVER] {
        let r = robot(name);
        let xy = Vector2::new(4.0, -3.0);
        let pose = standing_pose(&surface, xy, 0.0, r.geometry.ride_height_m);
        let mut m = MujocoPhysics::new(
            &r,
            &grid(&surface),
            &[],
            &PhysicsParams::default(),
            1000.0,
            G,
            &pose,
        )
        .unwrap();
        for _ in 0..1500 {
            m.step(&[0.0; MAX_DRIVE_JOINTS]);
        }
        let b = m.body().world_from_body;
        let up = b.rotation * Vector3::z();
        let ground = surface.sample(b.translation.x, b.translation.y).height_m;
        let expected_z = ground + r.geometry.ride_height_m * up.z.recip();
        let n = surface.sample(b.translation.x, b.translation.y).normal();
        eprintln!(
            "{name}: z {:.4} expected {expected_z:.4}; up {up:?} normal {n:?}",
            b.translation.z
        );
        assert!(
            (b.translation.z - expected_z).abs() < 0.01,
            "{name}: z {} vs {expected_z}",
            b.translation.z
        );
        assert!(
            up.angle(&n).to_degrees() < 1.0,
            "{name}: tilted {}° off the ground normal",
            up.angle(&n).to_degrees()
        );
    }
}

#[test]
fn driving_into_a_post_is_a_collision_and_stops_the_robot() {
    let surface = plane(0.0);
    let post = ObstacleShape {
        obstacle: Obstacle::Post { row: 0, index: 0 },
        base_in_world: Vector3::new(1.5, 0.0, 0.0),
        radius_m: 0.05,
        height_m: 1.8,
        box_footprint_m: None,
    };
    for name in [TRACKED, ROVER] {
        let mut m = mujoco(name, &surface, std::slice::from_ref(&post), 0.0);
        let o = manoeuvre(&mut m, name, &cmd(0.5, 0.0, 0.0), Target::Forward(3.0));
        let mut events: Vec<CollisionEvent> = Vec::new();
        m.take_collisions(&mut events);
        eprintln!(
            "{name}: stopped at {:.3} m; {events:?}",
            o.end.translation.x
        );
        assert!(
            events.iter().any(|e| e.obstacle == post.obstacle),
            "{name}: no post collision"
        );
        // Pushing against the post is one collision, not one per contact flicker.
        assert!(
            events.len() <= 2,
            "{name}: {} collision events",
            events.len()
        );
        // It stopped in front of the post (its front half is well over 10 cm long).
        assert!(
            o.end.translation.x < 1.5 - 0.1,
            "{name}: went through the post to x = {}",
            o.end.translation.x
        );
    }
}

#[test]
fn same_inputs_give_bit_identical_states() {
    let run = || {
        let surface = plane(3.0);
        let mut m = mujoco(ROVER, &surface, &[], 0.0);
        manoeuvre(&mut m, ROVER, &cmd(0.3, 0.2, 0.1), Target::Forward(1.0)).end
    };
    assert_eq!(run(), run());
}

/// The cross-check: the same manoeuvre on MuJoCo and on rapier with hard ground (no soil
/// shear, no ride ripple: Coulomb contact, as MuJoCo's). Both must end at the same pose:
/// position within 5 % of the path driven (plus 2 cm), heading within 3°.
fn crosscheck(name: &str, slope_deg: f64, command: TwistCommand, target: Target) {
    let surface = plane(slope_deg);
    let t0 = std::time::Instant::now();
    let mut m = mujoco(name, &surface, &[], 0.0);
    let om = manoeuvre(&mut m, name, &command, target);
    let mujoco_us = t0.elapsed().as_secs_f64() * 1e6 / ((om.drive_s + 3.0) * 1000.0);
    let mut h = rapier_with(name, &surface, 0.0, &hard_ground());
    let oh = manoeuvre(&mut h, name, &command, target);
    let mut d = rapier(name, &surface, 0.0);
    let od = manoeuvre(&mut d, name, &command, target);
    let gap = (om.end.translation.vector - oh.end.translation.vector)
        .xy()
        .norm();
    let heading = (om.turned_rad - oh.turned_rad).to_degrees();
    let tolerance = 0.05 * oh.path_m.max(om.path_m) + 0.02;
    eprintln!(
        "{name} {target:?} on {slope_deg}°: MuJoCo {:.3} m path, {:.2}° in {:.2} s | rapier (hard) {:.3} m, {:.2}° in {:.2} s | rapier (soil) {:.3} m, {:.2}° in {:.2} s, end {:.3} m from MuJoCo's | gap {gap:.3} m (tolerance {tolerance:.3}), heading {heading:.2}° | MuJoCo {mujoco_us:.0} µs/step",
        om.path_m,
        om.turned_rad.to_degrees(),
        om.drive_s,
        oh.path_m,
        oh.turned_rad.to_degrees(),
        oh.drive_s,
        od.path_m,
        od.turned_rad.to_degrees(),
        od.drive_s,
        (om.end.translation.vector - od.end.translation.vector)
            .xy()
            .norm(),
    );
    assert!(om.drive_s < 60.0, "MuJoCo never reached {target:?}");
    assert!(oh.drive_s < 60.0, "rapier never reached {target:?}");
    assert!(
        gap < tolerance,
        "{name} {target:?}: ends {gap:.3} m apart (tolerance {tolerance:.3})"
    );
    assert!(
        heading.abs() < 3.0,
        "{name} {target:?}: headings {heading:.2}° apart"
    );
}

#[test]
fn crosscheck_straight_line() {
    crosscheck(TRACKED, 0.0, cmd(0.5, 0.0, 0.0), Target::Forward(5.0));
    crosscheck(ROVER, 0.0, cmd(0.5, 0.0, 0.0), Target::Forward(5.0));
}

#[test]
fn crosscheck_turn_in_place() {
    let turn = Target::Turn(std::f64::consts::TAU);
    crosscheck(TRACKED, 0.0, cmd(0.0, 0.0, 0.5), turn);
    crosscheck(ROVER, 0.0, cmd(0.0, 0.0, 0.5), turn);
}

#[test]
fn crosscheck_mecanum_strafe() {
    crosscheck(ROVER, 0.0, cmd(0.0, 0.3, 0.0), Target::Left(3.0));
}

#[test]
fn crosscheck_slope_climb() {
    crosscheck(TRACKED, 10.0, cmd(0.5, 0.0, 0.0), Target::Forward(4.0));
    crosscheck(ROVER, 10.0, cmd(0.5, 0.0, 0.0), Target::Forward(4.0));
}

/// Open loop (no gyro feedback), on the same track speeds, turning in place and on an
/// arc, either way: the skid (elliptic Coulomb friction, mu1 along the belt, mu2 across
/// it) makes the robot turn slower than the slip-free kinematics say on both engines, by
/// rates that agree within 20 % (measured: MuJoCo 0.41-0.43 rad/s, rapier 0.35-0.37 for
/// 0.5 commanded; MuJoCo's belts turned at 0.21 with isotropic friction and at 0.50 with
/// independent along/across limits, both outside).
#[test]
fn open_loop_skid_turn_rate_matches_rapier() {
    let r = robot(TRACKED);
    let surface = plane(0.0);
    let mean = |rates: Vec<f64>| rates[150..].iter().sum::<f64>() / (rates.len() - 150) as f64;
    let mut failures = Vec::new();
    for (vx, wz) in [(0.0, 0.5), (0.0, -0.5), (0.7, 0.5), (0.7, -0.5)] {
        let command = cmd(vx, 0.0, wz);
        let mut m = mujoco(TRACKED, &surface, &[], 0.0);
        let open = &mut DriveController::new(&r, 0.0, 0.6);
        let mujoco_rate = mean(drive(&mut m, open, &command, 8.0));
        let mut h = rapier_with(TRACKED, &surface, 0.0, &hard_ground());
        let open = &mut DriveController::new(&r, 0.0, 0.6);
        let rapier_rate = mean(drive(&mut h, open, &command, 8.0));
        eprintln!(
            "open-loop yaw rate at {vx} m/s, {wz} rad/s: MuJoCo {mujoco_rate:.4} rad/s, rapier (hard) {rapier_rate:.4} rad/s"
        );
        let skid = wz / mujoco_rate;
        if (mujoco_rate / rapier_rate - 1.0).abs() >= 0.2 || skid < 1.1 {
            failures.push(format!(
                "at {vx} m/s, {wz} rad/s: MuJoCo {mujoco_rate} rad/s vs rapier {rapier_rate} rad/s"
            ));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

#[test]
fn crosscheck_arc_either_way() {
    // About a 1.2 m radius, as a headland turn.
    for wz in [0.58_f64, -0.58] {
        let half_turn = Target::Turn(wz.signum() * std::f64::consts::PI);
        crosscheck(TRACKED, 0.0, cmd(0.7, 0.0, wz), half_turn);
        crosscheck(ROVER, 0.0, cmd(0.7, 0.0, wz), half_turn);
    }
}
