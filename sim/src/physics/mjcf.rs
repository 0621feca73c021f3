//! The robot and its scene as an MJCF model (MuJoCo's XML), generated from the parsed URDF.
//!
//! The same [`RobotModel`] the rapier backend integrates becomes a MuJoCo multibody:
//!
//! - `base_link` with a free joint carries the mass properties of the whole robot less
//!   the drive links, and every non-running-gear `<collision>` primitive (they collide
//!   with the terrain and obstacles);
//! - each drive joint is a hinge on a child body with its link's mass and its axle inertia;
//!   the rotor reflected through the gear is the joint's `armature`, the URDF
//!   `<dynamics damping friction>` its `damping` and `frictionloss`; a velocity actuator
//!   (`kv` = the servo's proportional gain, force range = `<limit effort>`) drives it;
//! - a mecanum wheel carries `mecanum_rollers` passive rollers: capsules on hinge joints
//!   along the URDF's ground-contact roller axis (`fdir1`) turned about the axle, sized so
//!   that neighbouring rollers meet and the wheel is round to `(1 - f)·r·(1/cos(π/n) - 1)`;
//! - a track is a conveyor: `road_wheels` spheres of the belt's end radius along its
//!   ground run, whose surface velocity (MuJoCo's `surfacevel`) the backend sets every
//!   step to the belt speed of its sprocket; the sprocket is the backend's drive-train
//!   model (the rapier backend's [`super::contact::Motor`]), loaded by the friction on the
//!   spheres. Track friction is anisotropic (`mu1` along the belt, `mu2` across it) and
//!   MuJoCo cannot orient a contact frame on a heightfield, so each sphere rolls sideways
//!   on a hinge along the belt: the backend sets, every step, the hinge's dry friction to
//!   the sideways part and the contact's coefficient to the whole of the elliptic Coulomb
//!   force for the sphere's load and slip direction (see [`super::mujoco`]). Tried and
//!   measured first: spinning road-wheel bodies (their light rims took little traction on
//!   soft contacts; the robot turned in place at a third of the Coulomb rate), isotropic
//!   `mu2` belts (turned 40 % slower than rapier's tracks, stuck in tight headland turns)
//!   and independent along/across limits (no skid at all when turning in place);
//! - the terrain is a heightfield (`hfield`) whose elevations are written after the model
//!   is compiled ([`Mjcf::hfield`]); posts, trunks and occluders are static geoms.
//!
//! Collision filtering: static geoms have `contype = 0`, robot geoms `conaffinity = 0`, so
//! only robot-versus-world pairs are tested; the bits pick which: [`GROUND_BIT`] (terrain)
//! and [`OBSTACLE_BIT`] (posts, trunks, boxes). Rollers and belt spheres touch the terrain
//! only, running-gear URDF shapes obstacles only, the chassis both (bottoming out).
//!
//! This module is pure text generation (no MuJoCo needed), so its output is tested in
//! every build; [`super::mujoco`] compiles it.

use super::contact::Motor;
use super::rapier::{HeightGrid, ObstacleShape};
use crate::params::MujocoParams;
use crate::robot::{Drive, DriveJoint, RobotModel, Shape};
use nalgebra::{Isometry3, Matrix3, UnitQuaternion, Vector3};
use std::fmt::Write;

/// `conaffinity` bit of the terrain.
pub const GROUND_BIT: u32 = 1;
/// `conaffinity` bit of posts, trunks and occluders.
pub const OBSTACLE_BIT: u32 = 2;
/// Share of a mecanum wheel link's mass in its rollers.
const ROLLER_MASS_SHARE: f64 = 0.3;

/// Armature of a belt sphere's sideways hinge, kg·m²: keeps the light sphere's dry
/// friction stable at millisecond steps.
const BELT_ARMATURE_KGM2: f64 = 1e-3;

/// `solreffriction` of a belt sphere's sideways dry friction: stiff (time constant of
/// two millisecond steps), so the belt does not creep sideways under a load below its
/// friction limit (with MuJoCo's default, 0.02 s, the tracked robot swung measurably
/// wider in headland turns).
const BELT_SOLREF_FRICTION: &str = "0.002 1";

/// Names of the geoms the backend looks up after compiling.
pub mod names {
    /// The terrain heightfield (asset and geom).
    pub const TERRAIN: &str = "terrain";
    /// The free joint of `base_link`.
    pub const ROOT: &str = "root";
    /// Obstacle `i` of the scene.
    pub fn obstacle(i: usize) -> String {
        format!("obstacle_{i}")
    }
    /// The robot's collision shape `i` (index in `RobotModel::collision_shapes`).
    pub fn collision(i: usize) -> String {
        format!("collision_{i}")
    }
    /// The sideways hinge of the belt sphere (geom and body) named `sphere`.
    pub fn belt_roll(sphere: &str) -> String {
        format!("{sphere}_roll")
    }
}

/// The terrain elevations to write into the compiled model's `hfield_data`.
#[derive(Clone, Debug, PartialEq)]
pub struct HfieldData {
    /// Rows (along y, the first at the grid's smallest y).
    pub nrow: usize,
    /// Columns (along x).
    pub ncol: usize,
    /// `(h - min) / (max - min)` in `[0, 1]`, row-major.
    pub normalized: Vec<f32>,
}

/// A generated model.
#[derive(Clone, Debug, PartialEq)]
pub struct Mjcf {
    /// The MJCF text.
    pub xml: String,
    /// Elevations of the `terrain` hfield.
    pub hfield: HfieldData,
    /// What realizes each drive joint, in [`Drive::joints`] order.
    pub drives: Vec<DriveTrain>,
    /// Bodies of the robot with their mass, kg (for checks: they sum to the URDF's mass).
    pub body_masses_kg: Vec<(String, f64)>,
}

/// What realizes one URDF drive joint in the MuJoCo model.
#[derive(Clone, Debug, PartialEq)]
pub struct DriveTrain {
    /// A mecanum wheel: one hinge joint with a velocity actuator of the same name. A track:
    /// its belt geoms (conveyor spheres fixed to the chassis).
    pub members: Vec<String>,
}

/// Why a model could not be generated.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{what}")]
pub struct MjcfError {
    /// What is wrong.
    pub what: String,
}

fn v3(v: &Vector3<f64>) -> String {
    format!("{} {} {}", v.x, v.y, v.z)
}

fn quat(q: &UnitQuaternion<f64>) -> String {
    let q = q.quaternion();
    format!("{} {} {} {}", q.w, q.i, q.j, q.k)
}

fn full_inertia(m: &Matrix3<f64>) -> String {
    format!(
        "{} {} {} {} {} {}",
        m[(0, 0)],
        m[(1, 1)],
        m[(2, 2)],
        m[(0, 1)],
        m[(0, 2)],
        m[(1, 2)]
    )
}

/// `|d|²·E − d·dᵀ`: the parallel-axis term for a unit mass at offset `d`.
fn parallel_axis(d: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::identity() * d.norm_squared() - d * d.transpose()
}

/// Inertia of a wheel-like body about its centre: `axle` about the unit axis `a`, and
/// `0.6·axle` about every axis across it (a disc is 0.5; a little more keeps the tensor
/// strictly valid).
fn wheel_inertia(axle_kgm2: f64, a: &Vector3<f64>) -> Matrix3<f64> {
    let across = 0.6 * axle_kgm2;
    Matrix3::identity() * across + a * a.transpose() * (axle_kgm2 - across)
}

/// A rotation taking +z onto `axis` (unit).
fn z_onto(axis: &Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::rotation_between(&Vector3::z(), axis).unwrap_or_else(|| {
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
    })
}

/// A point mass or small body moved out of the chassis: mass, centre in the body frame,
/// inertia about its centre.
struct Part {
    mass_kg: f64,
    centre: Vector3<f64>,
    inertia: Matrix3<f64>,
}

/// Checks `[physics.mujoco]` (errors carry the key path).
pub fn check(p: &MujocoParams) -> Result<(), crate::params::ParamError> {
    use crate::params::{require_count_in, require_in};
    let path = |k: &str| format!("physics.mujoco.{k}");
    require_in(&path("heightfield_cell_m"), p.heightfield_cell_m, 0.02, 1.0)?;
    require_count_in(&path("mecanum_rollers"), p.mecanum_rollers, 6, 64)?;
    require_in(
        &path("roller_radius_fraction"),
        p.roller_radius_fraction,
        0.2,
        0.9,
    )?;
    require_count_in(&path("road_wheels"), p.road_wheels, 2, 32)?;
    require_in(
        &path("contact_timeconst_s"),
        p.contact_timeconst_s,
        1e-4,
        0.1,
    )?;
    Ok(())
}

/// A drive joint's body: its link's mass (less `carried_kg`, which its children carry),
/// hinge, armature, damping and friction; records it in `parts` and `masses`.
fn drive_body(
    j: &DriveJoint,
    carried_kg: f64,
    children: &str,
    parts: &mut Vec<Part>,
    masses: &mut Vec<(String, f64)>,
) -> String {
    let a = j.axis_in_body.normalize();
    let axle = (j.inertia_kgm2 - j.reflected_inertia_kgm2).max(1e-6);
    let mass = (j.link_mass_kg - carried_kg).max(0.05);
    let inertia = wheel_inertia(axle, &a);
    let centre = j.body_from_joint.translation.vector;
    parts.push(Part {
        mass_kg: mass,
        centre,
        inertia,
    });
    masses.push((j.link.clone(), mass));
    format!(
        "      <body name=\"{link}\" pos=\"{pos}\">\n        <joint name=\"{name}\" type=\"hinge\" axis=\"{axis}\" armature=\"{arm}\" damping=\"{damp}\" frictionloss=\"{fric}\"/>\n        <inertial pos=\"0 0 0\" mass=\"{mass}\" fullinertia=\"{inertia}\"/>\n{children}      </body>\n",
        link = j.link,
        pos = v3(&centre),
        name = j.name,
        axis = v3(&a),
        arm = j.reflected_inertia_kgm2,
        damp = j.damping_nms,
        fric = j.friction_nm,
        inertia = full_inertia(&inertia),
    )
}

/// Everything [`generate`] needs besides the robot.
pub struct SceneSpec<'a> {
    /// The terrain grid (the wheels ride on it).
    pub ground: &'a HeightGrid,
    /// Posts, trunks and boxes.
    pub obstacles: &'a [ObstacleShape],
    /// `world_from_body` at the start.
    pub world_from_body: Isometry3<f64>,
    /// Step, s.
    pub dt_s: f64,
    /// Gravity along −z, m/s².
    pub gravity_mps2: f64,
    /// `[physics] friction_scale`.
    pub friction_scale: f64,
    /// `[physics] motor_bandwidth_hz`.
    pub motor_bandwidth_hz: f64,
    /// `[physics.mujoco]`.
    pub params: &'a MujocoParams,
}

/// The MJCF model of `robot` in `scene`.
pub fn generate(robot: &RobotModel, scene: &SceneSpec<'_>) -> Result<Mjcf, MjcfError> {
    let p = scene.params;
    let g = scene.ground;
    if g.nx < 2 || g.ny < 2 || g.heights_m.len() != g.nx * g.ny {
        return Err(MjcfError {
            what: format!(
                "the terrain grid must be at least 2 × 2 with nx·ny heights, found {} × {} with {}",
                g.nx,
                g.ny,
                g.heights_m.len()
            ),
        });
    }
    let mut x = String::with_capacity(64 * 1024);
    let solref = format!("{} 1", p.contact_timeconst_s);
    let _ = writeln!(x, "<mujoco model=\"vinebench-{}\">", robot.name);
    let _ = writeln!(x, "  <compiler angle=\"radian\" autolimits=\"true\"/>");
    let _ = writeln!(
        x,
        "  <option timestep=\"{}\" gravity=\"0 0 {}\" integrator=\"implicitfast\" cone=\"elliptic\" impratio=\"10\">",
        scene.dt_s, -scene.gravity_mps2
    );
    let _ = writeln!(x, "    <flag energy=\"enable\"/>");
    let _ = writeln!(x, "  </option>");

    // Terrain.
    let (lo, hi) = g
        .heights_m
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &h| {
            (lo.min(h), hi.max(h))
        });
    if !(lo.is_finite() && hi.is_finite()) {
        return Err(MjcfError {
            what: "the terrain grid holds a non-finite height".into(),
        });
    }
    let elevation = (hi - lo).max(1e-3);
    let size_x = (g.nx - 1) as f64 * g.cell_m;
    let size_y = (g.ny - 1) as f64 * g.cell_m;
    let _ = writeln!(x, "  <asset>");
    let _ = writeln!(
        x,
        "    <hfield name=\"{}\" nrow=\"{}\" ncol=\"{}\" size=\"{} {} {} 1\"/>",
        names::TERRAIN,
        g.ny,
        g.nx,
        size_x / 2.0,
        size_y / 2.0,
        elevation
    );
    let _ = writeln!(x, "  </asset>");
    let _ = writeln!(x, "  <worldbody>");
    let _ = writeln!(
        x,
        "    <geom name=\"{}\" type=\"hfield\" hfield=\"{}\" pos=\"{} {} {}\" contype=\"0\" conaffinity=\"{GROUND_BIT}\" solref=\"{solref}\"/>",
        names::TERRAIN,
        names::TERRAIN,
        g.origin_x_m + size_x / 2.0,
        g.origin_y_m + size_y / 2.0,
        lo
    );
    for (i, o) in scene.obstacles.iter().enumerate() {
        let centre = o.base_in_world + Vector3::z() * (o.height_m / 2.0);
        let (kind, size, q) = match o.box_footprint_m {
            None => (
                "cylinder",
                format!("{} {}", o.radius_m, o.height_m / 2.0),
                UnitQuaternion::identity(),
            ),
            Some((length, width, yaw)) => (
                "box",
                format!("{} {} {}", length / 2.0, width / 2.0, o.height_m / 2.0),
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
            ),
        };
        let _ = writeln!(
            x,
            "    <geom name=\"{}\" type=\"{kind}\" size=\"{size}\" pos=\"{}\" quat=\"{}\" contype=\"0\" conaffinity=\"{OBSTACLE_BIT}\" friction=\"0.5\"/>",
            names::obstacle(i),
            v3(&centre),
            quat(&q)
        );
    }

    // The robot.
    let mut parts: Vec<Part> = Vec::new();
    let mut bodies = String::new();
    let mut drives: Vec<Vec<String>> = Vec::new();
    let mut belts = String::new();
    let mut body_masses_kg = Vec::new();
    let joints = robot.drive.joints();
    let share = robot.inertia.mass_kg / joints.len() as f64;
    let ground_geom = |name: &str, mu: f64| {
        format!(
            "contype=\"{GROUND_BIT}\" conaffinity=\"0\" condim=\"3\" priority=\"1\" friction=\"{} 0.005 0.0001\" solref=\"{solref}\" name=\"{name}\"",
            mu * scene.friction_scale
        )
    };
    match &robot.drive {
        Drive::Mecanum(m) => {
            let n = p.mecanum_rollers as usize;
            for w in m.wheels.iter() {
                let j = &w.joint;
                let a = j.axis_in_body.normalize();
                let r = j.radius_m;
                let rho = p.roller_radius_fraction * r;
                let rc = r - rho;
                // The ground-contact roller axis, across the radius (at the bottom).
                let down = {
                    let d = -Vector3::z() + a * a.z;
                    d.normalize()
                };
                let u0 = {
                    let f = w.contact.fdir1_in_body;
                    (f - down * f.dot(&down)).normalize()
                };
                let tangent = a.cross(&down).normalize();
                let along_tangent = u0.dot(&tangent).abs().max(0.3);
                // Neighbouring rollers' ends meet at the seam between them.
                let half_length = rc * (std::f64::consts::PI / n as f64).tan() / along_tangent;
                let roller_mass = ROLLER_MASS_SHARE * j.link_mass_kg / n as f64;
                let mut children = String::new();
                for k in 0..n {
                    let turn = UnitQuaternion::from_axis_angle(
                        &nalgebra::Unit::new_normalize(a),
                        std::f64::consts::TAU * k as f64 / n as f64,
                    );
                    let centre = turn * (down * rc);
                    let axis = turn * u0;
                    let name = format!("{}_roller_{k}", j.link);
                    let _ = writeln!(
                        children,
                        "        <body name=\"{name}\" pos=\"{}\" quat=\"{}\">\n          <joint name=\"{name}\" type=\"hinge\" axis=\"0 0 1\" damping=\"1e-4\" armature=\"1e-6\"/>\n          <geom type=\"capsule\" size=\"{rho} {half_length}\" mass=\"{roller_mass}\" {}/>\n        </body>",
                        v3(&centre),
                        quat(&z_onto(&axis)),
                        ground_geom(&format!("{name}_geom"), w.contact.mu1),
                    );
                    body_masses_kg.push((name, roller_mass));
                }
                // The rollers' mass sits on a ring of radius rc about the axle.
                let ring = n as f64 * roller_mass;
                let aa = a * a.transpose();
                parts.push(Part {
                    mass_kg: ring,
                    centre: j.body_from_joint.translation.vector,
                    inertia: (aa + (Matrix3::identity() - aa) * 0.5) * (ring * rc * rc),
                });
                bodies.push_str(&drive_body(
                    j,
                    ring,
                    &children,
                    &mut parts,
                    &mut body_masses_kg,
                ));
                drives.push(vec![j.name.clone()]);
            }
        }
        Drive::Tracked(t) => {
            // A track is a conveyor: spheres of the belt's end radius along its ground run
            // whose surface moves backwards at the belt's speed (MuJoCo's geom surface
            // velocity, set every step from the sprocket's speed). The sprocket is the
            // backend's drive-train model, loaded by the friction the ground exerts on
            // these spheres.
            //
            // Each sphere rolls sideways on a hinge along the belt, held by dry friction
            // (`frictionloss`, torque = force × radius). Written here for mu2 at the
            // sphere's share of the robot's weight on level ground, mu1 on the contact;
            // the backend rewrites both every step from the sphere's load and slip.
            let n = p.road_wheels as usize;
            let weight_n = robot.inertia.mass_kg * scene.gravity_mps2 / (2 * n) as f64;
            for track in [&t.left, &t.right] {
                let rr = track.height_m / 2.0;
                let run = track.length_m - track.height_m;
                let centre = track.body_from_track.translation.vector;
                let rotation = track.body_from_track.rotation;
                let fwd = rotation * Vector3::x();
                let mu1 = track.contact.mu1;
                let lateral_nm = track.contact.mu2 * scene.friction_scale * weight_n * rr;
                let mass = ROLLER_MASS_SHARE * track.sprocket.link_mass_kg / n as f64;
                let mut members = Vec::with_capacity(n);
                for i in 0..n {
                    let along = -run / 2.0 + run * i as f64 / (n - 1) as f64;
                    let pos = centre + fwd * along;
                    let name = format!("{}_belt_{i}", track.link);
                    // The geom's surface velocity is nonzero at compile time, so that the
                    // model's `flg_surfacevel` (some geom has a surface velocity) is set;
                    // the backend rewrites the values every step.
                    let _ = writeln!(
                        belts,
                        "      <body name=\"{name}\" pos=\"{}\" quat=\"{}\">\n        <joint name=\"{}\" type=\"hinge\" axis=\"1 0 0\" frictionloss=\"{lateral_nm}\" solreffriction=\"{BELT_SOLREF_FRICTION}\" armature=\"{BELT_ARMATURE_KGM2}\"/>\n        <geom type=\"sphere\" size=\"{rr}\" mass=\"{mass}\" surfacevel=\"1e-12 0 0 0 0 0\" {}/>\n      </body>",
                        v3(&pos),
                        quat(&rotation),
                        names::belt_roll(&name),
                        ground_geom(&name, mu1),
                    );
                    parts.push(Part {
                        mass_kg: mass,
                        centre: pos,
                        inertia: Matrix3::identity() * (0.4 * mass * rr * rr),
                    });
                    body_masses_kg.push((name.clone(), mass));
                    members.push(name);
                }
                drives.push(members);
            }
        }
    }

    // The chassis: the whole robot less the parts above (parallel-axis theorem).
    let total = &robot.inertia;
    let moved: f64 = parts.iter().map(|q| q.mass_kg).sum();
    let base_mass = total.mass_kg - moved;
    if base_mass <= 0.1 * total.mass_kg {
        return Err(MjcfError {
            what: format!(
                "the drive links and running gear ({moved:.3} kg) leave too little of the robot's {:.3} kg for the chassis",
                total.mass_kg
            ),
        });
    }
    let c = total.com_in_body;
    let base_com = (c * total.mass_kg
        - parts
            .iter()
            .map(|q| q.centre * q.mass_kg)
            .fold(Vector3::zeros(), |s, v| s + v))
        / base_mass;
    let mut base_inertia = total.inertia_about_com_in_body;
    for q in &parts {
        base_inertia -= q.inertia + parallel_axis(&(q.centre - c)) * q.mass_kg;
    }
    base_inertia -= parallel_axis(&(base_com - c)) * base_mass;
    base_inertia = (base_inertia + base_inertia.transpose()) / 2.0;
    let eig = base_inertia.symmetric_eigenvalues();
    if eig.iter().any(|&e| e <= 0.0) {
        return Err(MjcfError {
            what: format!(
                "the chassis inertia left after the running gear is not positive definite (eigenvalues {eig:?})"
            ),
        });
    }
    body_masses_kg.insert(0, ("base_link".to_string(), base_mass));

    let pose = &scene.world_from_body;
    let _ = writeln!(
        x,
        "    <body name=\"base_link\" pos=\"{}\" quat=\"{}\">",
        v3(&pose.translation.vector),
        quat(&pose.rotation)
    );
    let _ = writeln!(x, "      <freejoint name=\"{}\"/>", names::ROOT);
    let _ = writeln!(
        x,
        "      <inertial pos=\"{}\" mass=\"{base_mass}\" fullinertia=\"{}\"/>",
        v3(&base_com),
        full_inertia(&base_inertia)
    );
    for (i, s) in robot.collision_shapes.iter().enumerate() {
        let (kind, size) = match s.shape {
            Shape::Box { half_extents_m: h } => ("box", v3(&h)),
            Shape::Cylinder {
                radius_m,
                half_length_m,
            } => ("cylinder", format!("{radius_m} {half_length_m}")),
            Shape::Sphere { radius_m } => ("sphere", format!("{radius_m}")),
        };
        let contype = if s.running_gear {
            OBSTACLE_BIT
        } else {
            OBSTACLE_BIT | GROUND_BIT
        };
        let _ = writeln!(
            x,
            "      <geom name=\"{}\" type=\"{kind}\" size=\"{size}\" pos=\"{}\" quat=\"{}\" mass=\"0\" contype=\"{contype}\" conaffinity=\"0\" friction=\"0.5\"/>",
            names::collision(i),
            v3(&s.body_from_shape.translation.vector),
            quat(&s.body_from_shape.rotation)
        );
    }
    x.push_str(&belts);
    x.push_str(&bodies);
    let _ = writeln!(x, "    </body>");
    let _ = writeln!(x, "  </worldbody>");
    let _ = writeln!(x, "  <actuator>");
    if let Drive::Mecanum(_) = &robot.drive {
        for j in &joints {
            // The servo's proportional part is the actuator's (implicit) gain.
            let kp = Motor::for_joint(j, share, scene.motor_bandwidth_hz).kp;
            let _ = writeln!(
                x,
                "    <velocity name=\"{}\" joint=\"{}\" kv=\"{kp}\" forcerange=\"{} {}\"/>",
                j.name, j.name, -j.max_torque_nm, j.max_torque_nm
            );
        }
    }
    let _ = writeln!(x, "  </actuator>");
    let _ = writeln!(x, "</mujoco>");

    let normalized = g
        .heights_m
        .iter()
        .map(|h| ((h - lo) / elevation) as f32)
        .collect();
    Ok(Mjcf {
        xml: x,
        hfield: HfieldData {
            nrow: g.ny,
            ncol: g.nx,
            normalized,
        },
        drives: drives
            .into_iter()
            .map(|members| DriveTrain { members })
            .collect(),
        body_masses_kg,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::PhysicsParams;
    use crate::world::PlaneSurface;
    use nalgebra::Vector2;

    fn model(name: &str, params: &MujocoParams) -> (RobotModel, Mjcf) {
        let robot = RobotModel::builtin(name).unwrap();
        let surface = PlaneSurface {
            z0_m: 0.0,
            gradient: Vector2::new(0.1, 0.0),
        };
        let ground = HeightGrid::sample(
            &surface,
            Vector2::new(-2.0, -1.0),
            Vector2::new(2.0, 1.0),
            0.5,
        );
        let obstacles = [ObstacleShape {
            obstacle: crate::physics::Obstacle::Post { row: 0, index: 0 },
            base_in_world: Vector3::new(1.0, 0.5, 0.0),
            radius_m: 0.05,
            height_m: 1.8,
            box_footprint_m: None,
        }];
        let spec = SceneSpec {
            ground: &ground,
            obstacles: &obstacles,
            world_from_body: Isometry3::translation(0.0, 0.0, 0.3),
            dt_s: 0.001,
            gravity_mps2: spec_gravity(),
            friction_scale: 1.0,
            motor_bandwidth_hz: 8.0,
            params,
        };
        let m = generate(&robot, &spec).unwrap();
        (robot, m)
    }

    fn spec_gravity() -> f64 {
        9.8
    }

    #[test]
    fn the_model_is_well_formed_and_keeps_the_urdf_mass() {
        let p = PhysicsParams::default().mujoco;
        for name in ["tracked-sensorbox", "mecanum-rover"] {
            let (robot, m) = model(name, &p);
            let doc = roxmltree::Document::parse(&m.xml).unwrap();
            let count = |tag: &str| doc.descendants().filter(|n| n.has_tag_name(tag)).count();
            // Every body's mass adds up to the URDF's total.
            let total: f64 = m.body_masses_kg.iter().map(|(_, kg)| kg).sum();
            assert!(
                (total - robot.inertia.mass_kg).abs() < 1e-9,
                "{name}: {total} kg vs {}",
                robot.inertia.mass_kg
            );
            assert_eq!(count("freejoint"), 1);
            let (bodies, actuators) = match name {
                // base + 4 hubs + their rollers.
                "mecanum-rover" => (1 + 4 + 4 * p.mecanum_rollers as usize, 4),
                // base + the belt spheres, driven by the backend.
                _ => (1 + 2 * p.road_wheels as usize, 0),
            };
            assert_eq!(count("body"), bodies, "{name}");
            assert_eq!(count("velocity"), actuators, "{name}");
            assert_eq!(m.drives.len(), robot.drive.joints().len());
            // Tracks: the sideways dry friction of all belt spheres is mu2 times the
            // robot's weight (torque = force × sphere radius).
            if let crate::robot::Drive::Tracked(t) = &robot.drive {
                let radius_m = t.left.height_m / 2.0;
                let sideways_n: f64 = doc
                    .descendants()
                    .filter(|n| n.has_tag_name("joint") && n.attribute("type") == Some("hinge"))
                    .filter_map(|n| n.attribute("frictionloss"))
                    .map(|f| f.parse::<f64>().unwrap() / radius_m)
                    .sum();
                let expected = t.left.contact.mu2 * robot.inertia.mass_kg * spec_gravity();
                assert!(
                    (sideways_n - expected).abs() < 1e-9 * expected,
                    "{sideways_n} N vs {expected} N"
                );
            }
            // The heightfield matches the grid (4 m × 2 m at 0.5 m) and spans [0, 1].
            assert_eq!((m.hfield.nrow, m.hfield.ncol), (5, 9));
            let (lo, hi) = m
                .hfield
                .normalized
                .iter()
                .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
            assert_eq!((lo, hi), (0.0, 1.0));
            // A column further east (x) is higher on this slope; rows do not change.
            assert!(m.hfield.normalized[1] > m.hfield.normalized[0]);
            assert_eq!(m.hfield.normalized[0], m.hfield.normalized[9]);
        }
    }

    #[test]
    fn mecanum_rollers_make_a_round_wheel_along_the_urdf_roller_axis() {
        let p = PhysicsParams::default().mujoco;
        let (robot, m) = model("mecanum-rover", &p);
        let crate::robot::Drive::Mecanum(drive) = &robot.drive else {
            panic!("not mecanum");
        };
        let doc = roxmltree::Document::parse(&m.xml).unwrap();
        let w = &drive.wheels[0];
        let r = w.joint.radius_m;
        let parse = |s: &str| -> Vec<f64> { s.split(' ').map(|v| v.parse().unwrap()).collect() };
        let rollers: Vec<_> = doc
            .descendants()
            .filter(|n| {
                n.has_tag_name("body")
                    && n.attribute("name")
                        .is_some_and(|s| s.starts_with(&format!("{}_roller_", w.joint.link)))
            })
            .collect();
        assert_eq!(rollers.len(), p.mecanum_rollers as usize);
        // Sample the wheel's outline below the hub (the lowest capsule point over every
        // roller) as the wheel turns: its radius stays within the stated ripple.
        let ripple = (1.0 - p.roller_radius_fraction)
            * r
            * (1.0 / (std::f64::consts::PI / p.mecanum_rollers as f64).cos() - 1.0);
        let a = w.joint.axis_in_body.normalize();
        let mut lowest = Vec::new();
        for step in 0..360 {
            let turn = UnitQuaternion::from_axis_angle(
                &nalgebra::Unit::new_normalize(a),
                (step as f64).to_radians(),
            );
            let mut min_z = f64::INFINITY;
            for b in &rollers {
                let pos = Vector3::from_vec(parse(b.attribute("pos").unwrap()));
                let q = parse(b.attribute("quat").unwrap());
                let rot = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
                    q[0], q[1], q[2], q[3],
                ));
                let geom = b.children().find(|n| n.has_tag_name("geom")).unwrap();
                let size = parse(geom.attribute("size").unwrap());
                let (rho, half) = (size[0], size[1]);
                let axis = turn * (rot * Vector3::z());
                let centre = turn * pos;
                // The capsule's lowest point: its segment's lowest end, minus its radius.
                let z = (centre.z - half * axis.z.abs()) - rho;
                min_z = min_z.min(z);
            }
            lowest.push(-min_z);
        }
        let (lo, hi) = lowest
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        assert!((lo - r).abs() < 1e-9, "smallest radius {lo} vs {r}");
        assert!(hi - lo <= ripple + 1e-9, "ripple {} > {ripple}", hi - lo);
        // The ground-contact roller (at the bottom) lies along the URDF's fdir1.
        let bottom = rollers[0];
        let q = parse(bottom.attribute("quat").unwrap());
        let axis =
            UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]))
                * Vector3::z();
        assert!(axis.cross(&w.contact.fdir1_in_body.normalize()).norm() < 1e-9);
        assert!(Vector3::from_vec(parse(bottom.attribute("pos").unwrap())).z < 0.0);
    }

    #[test]
    fn out_of_range_parameters_name_their_key() {
        let mut p = PhysicsParams::default().mujoco;
        p.mecanum_rollers = 3;
        assert_eq!(
            check(&p).unwrap_err().path,
            "physics.mujoco.mecanum_rollers"
        );
        let mut p = PhysicsParams::default().mujoco;
        p.heightfield_cell_m = 0.0;
        assert_eq!(
            check(&p).unwrap_err().path,
            "physics.mujoco.heightfield_cell_m"
        );
        assert!(check(&PhysicsParams::default().mujoco).is_ok());
    }
}
