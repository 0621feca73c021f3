//! The rapier3d backend (f64, enhanced determinism).
//!
//! The robot is one dynamic rigid body with the mass properties of its URDF; its
//! `<collision>` primitives are colliders without mass. The ground contact of tracks and
//! wheels is [`super::contact`]'s model, applied as a force and torque each step. Rapier
//! integrates the body under gravity and that wrench and resolves contacts with the world:
//! trellis posts and trunks (vertical cylinders) and the terrain (a heightfield sampled
//! from the world's surface). Running gear (tracks, sprockets, wheels) collides with posts
//! and trunks only; the chassis collides with the terrain too, which happens only when the
//! robot bottoms out.
//!
//! rapier's types (glam) stay in this file: everything outside sees nalgebra.

use super::contact::{ContactModel, GroundProbe, JointKinematics, Motor, SoilParams};
use super::{BodyState, CollisionEvent, JointState, Obstacle, Physics};
use crate::params::{
    ParamError, PhysicsParams, require_count_in, require_in, require_non_negative, require_positive,
};
use crate::robot::{Drive, MAX_DRIVE_JOINTS, RobotModel, Shape};
use crate::world::{Surface, World};
use nalgebra::{Isometry3, Matrix3, Quaternion, Translation3, UnitQuaternion, Vector3};
use rapier3d_f64::prelude as rp;
use std::sync::Mutex;

/// `user_data` tag of robot colliders (low bits: index into the robot's links).
const ROBOT_TAG: u128 = 1 << 64;
/// `user_data` tag of obstacle colliders (low bits: index into the obstacle list).
const OBSTACLE_TAG: u128 = 2 << 64;
/// `user_data` of the terrain heightfield.
const GROUND_TAG: u128 = 3 << 64;

/// Finest accepted terrain heightfield cell, m (a 176 m × 55 m vineyard at 5 cm is 3.9 M
/// heights, 31 MB).
pub const MIN_HEIGHTFIELD_CELL_M: f64 = 0.05;
/// Most heights of a terrain heightfield ([`HeightGrid`]; 16 M heights are 128 MB).
pub const MAX_HEIGHTFIELD_POINTS: usize = 16_000_000;

const CHASSIS: rp::Group = rp::Group::GROUP_1;
const RUNNING_GEAR: rp::Group = rp::Group::GROUP_2;
const OBSTACLES: rp::Group = rp::Group::GROUP_3;
const GROUND: rp::Group = rp::Group::GROUP_4;

/// A vertical cylinder the robot can hit: a post or a trunk.
#[derive(Clone, Debug, PartialEq)]
pub struct ObstacleShape {
    /// What it is.
    pub obstacle: Obstacle,
    /// Centre of its base, world frame, m.
    pub base_in_world: Vector3<f64>,
    /// Radius, m.
    pub radius_m: f64,
    /// Height, m.
    pub height_m: f64,
    /// A box instead of a cylinder: length (along `yaw_rad`) and width, m; `radius_m` is
    /// then unused.
    pub box_footprint_m: Option<(f64, f64, f64)>,
}

/// Posts, trunks and occluder boxes of a world as obstacles.
pub fn obstacles_of(world: &World) -> Vec<ObstacleShape> {
    let posts = world
        .posts
        .iter()
        .enumerate()
        .map(|(index, p)| ObstacleShape {
            obstacle: Obstacle::Post { row: p.row, index },
            base_in_world: p.base_in_world,
            radius_m: p.diameter_m / 2.0,
            height_m: p.height_m,
            box_footprint_m: None,
        });
    let trunks = world.plants.iter().map(|p| ObstacleShape {
        obstacle: Obstacle::Trunk {
            row: p.row,
            slot: p.slot,
        },
        base_in_world: p.base_in_world,
        radius_m: p.trunk_diameter_m / 2.0,
        height_m: p.trunk_height_m,
        box_footprint_m: None,
    });
    let occluders = world.occluders.iter().enumerate().map(|(index, o)| {
        let x = o.world_from_box.rotation * Vector3::x();
        ObstacleShape {
            obstacle: Obstacle::Occluder { index },
            base_in_world: o.world_from_box.translation.vector,
            radius_m: 0.0,
            height_m: o.size_m.z,
            box_footprint_m: Some((o.size_m.x, o.size_m.y, x.y.atan2(x.x))),
        }
    });
    posts.chain(trunks).chain(occluders).collect()
}

/// A regular grid of ground heights (row-major along y, then x), for the heightfield
/// collider.
#[derive(Clone, Debug, PartialEq)]
pub struct HeightGrid {
    /// World x of the first column, m.
    pub origin_x_m: f64,
    /// World y of the first row, m.
    pub origin_y_m: f64,
    /// Grid spacing, m.
    pub cell_m: f64,
    /// Columns (along x).
    pub nx: usize,
    /// Rows (along y).
    pub ny: usize,
    /// `heights[iy * nx + ix]`, m.
    pub heights_m: Vec<f64>,
}

impl HeightGrid {
    /// Checks that a grid of `cell_m` over `[min, max]` holds at most
    /// [`MAX_HEIGHTFIELD_POINTS`] heights (and that `cell_m` is usable); `path` names the
    /// cell size's scenario key in the error. Allocates nothing.
    pub fn check_size(
        min: nalgebra::Vector2<f64>,
        max: nalgebra::Vector2<f64>,
        cell_m: f64,
        path: &str,
    ) -> Result<(), ParamError> {
        require_positive(path, cell_m)?;
        let points =
            (((max.x - min.x) / cell_m).ceil() + 2.0) * (((max.y - min.y) / cell_m).ceil() + 2.0);
        if points <= MAX_HEIGHTFIELD_POINTS as f64 {
            return Ok(());
        }
        Err(ParamError::new(
            path,
            format!(
                "a cell size giving at most {MAX_HEIGHTFIELD_POINTS} heights \
                 (MAX_HEIGHTFIELD_POINTS) over the terrain's {:.0} m × {:.0} m, i.e. at least \
                 {:.3} m",
                max.x - min.x,
                max.y - min.y,
                ((max.x - min.x) * (max.y - min.y) / MAX_HEIGHTFIELD_POINTS as f64).sqrt()
            ),
            format!("{cell_m} ({points:.0} heights)"),
        ))
    }

    /// Samples `surface` on a grid of `cell_m` covering `[min, max]` (x and y). Check the
    /// size first ([`HeightGrid::check_size`]) for a grid that input decides.
    pub fn sample<S: Surface>(
        surface: &S,
        min: nalgebra::Vector2<f64>,
        max: nalgebra::Vector2<f64>,
        cell_m: f64,
    ) -> HeightGrid {
        let nx = (((max.x - min.x) / cell_m).ceil() as usize).max(1) + 1;
        let ny = (((max.y - min.y) / cell_m).ceil() as usize).max(1) + 1;
        let mut heights_m = Vec::with_capacity(nx * ny);
        for iy in 0..ny {
            for ix in 0..nx {
                let (x, y) = (min.x + ix as f64 * cell_m, min.y + iy as f64 * cell_m);
                heights_m.push(surface.sample(x, y).height_m);
            }
        }
        HeightGrid {
            origin_x_m: min.x,
            origin_y_m: min.y,
            cell_m,
            nx,
            ny,
            heights_m,
        }
    }
}

/// What the robot drives on and can hit.
#[derive(Clone, Debug)]
pub struct Scene<'a, S: Surface> {
    /// The ground surface of the tracks' and wheels' contact model.
    pub surface: S,
    /// Posts and trunks.
    pub obstacles: &'a [ObstacleShape],
    /// The terrain as a heightfield for chassis collisions (none: the chassis never
    /// touches the ground).
    pub ground: Option<&'a HeightGrid>,
}

/// Checked `[physics]` values (paths for errors).
fn check(p: &PhysicsParams) -> Result<(), ParamError> {
    let path = |k: &str| format!("physics.{k}");
    require_positive(&path("friction_scale"), p.friction_scale)?;
    require_in(
        &path("shear_deformation_m"),
        p.shear_deformation_m,
        1e-4,
        1.0,
    )?;
    require_non_negative(&path("shear_damping_s"), p.shear_damping_s)?;
    require_in(&path("rolling_resistance"), p.rolling_resistance, 0.0, 1.0)?;
    require_count_in(&path("track_probes"), p.track_probes, 2, 64)?;
    require_positive(&path("track_link_pitch_m"), p.track_link_pitch_m)?;
    require_count_in(&path("mecanum_rollers"), p.mecanum_rollers, 3, 64)?;
    require_in(&path("ripple_m"), p.ripple_m, 0.0, 0.02)?;
    require_in(
        &path("motor_bandwidth_hz"),
        p.motor_bandwidth_hz,
        0.1,
        100.0,
    )?;
    require_non_negative(&path("yaw_rate_gain_per_s"), p.yaw_rate_gain_per_s)?;
    require_in(
        &path("heightfield_cell_m"),
        p.heightfield_cell_m,
        MIN_HEIGHTFIELD_CELL_M,
        10.0,
    )?;
    require_positive(&path("stuck_timeout_s"), p.stuck_timeout_s)?;
    Ok(())
}

/// The ground probes of a robot's drive (see [`super::contact`]).
pub fn ground_probes(robot: &RobotModel, p: &PhysicsParams) -> Vec<GroundProbe> {
    match &robot.drive {
        Drive::Tracked(t) => {
            let n = p.track_probes as usize;
            let mut probes = Vec::with_capacity(2 * n);
            for (joint, track) in [&t.left, &t.right].into_iter().enumerate() {
                let r = track.height_m / 2.0;
                let run = track.length_m - track.height_m;
                let centre = track.body_from_track.translation.vector;
                let fwd = track.body_from_track.rotation * Vector3::x();
                for i in 0..n {
                    let along = -run / 2.0 + run * i as f64 / (n - 1) as f64;
                    probes.push(GroundProbe {
                        joint,
                        centre_in_body: centre + fwd * along,
                        radius_m: r,
                        stiffness_n_per_m: track.contact.stiffness_n_per_m / n as f64,
                        damping_ns_per_m: track.contact.damping_ns_per_m / n as f64,
                        mu: [track.contact.mu1, track.contact.mu2],
                        fdir1_in_body: track.contact.fdir1_in_body,
                        roll_in_body: fwd,
                        along_m: along,
                        half_run_m: run / 2.0,
                        ripple_wavelength_m: p.track_link_pitch_m,
                        ripple_phase_m: along,
                    });
                }
            }
            probes
        }
        Drive::Mecanum(m) => m
            .wheels
            .iter()
            .enumerate()
            .map(|(joint, w)| {
                let r = w.joint.radius_m;
                let wavelength = std::f64::consts::TAU * r / p.mecanum_rollers as f64;
                // Forward rolling direction: axis × up (for the y axle, +x).
                let roll = w.joint.axis_in_body.cross(&Vector3::z());
                GroundProbe {
                    joint,
                    centre_in_body: w.joint.body_from_joint.translation.vector,
                    radius_m: r,
                    stiffness_n_per_m: w.contact.stiffness_n_per_m,
                    damping_ns_per_m: w.contact.damping_ns_per_m,
                    mu: [w.contact.mu1, w.contact.mu2],
                    fdir1_in_body: w.contact.fdir1_in_body,
                    roll_in_body: roll.normalize(),
                    along_m: 0.0,
                    half_run_m: r / 2.0,
                    ripple_wavelength_m: wavelength,
                    // Quarter-period steps: the four wheels' rollers out of step.
                    ripple_phase_m: wavelength * joint as f64 / 4.0,
                }
            })
            .collect(),
    }
}

/// Collects rapier's collision events (it needs `&self` access from the pipeline).
#[derive(Default)]
struct EventSink(Mutex<Vec<(rp::ColliderHandle, rp::ColliderHandle)>>);

impl rp::EventHandler for EventSink {
    fn handle_collision_event(
        &self,
        _bodies: &rp::RigidBodySet,
        _colliders: &rp::ColliderSet,
        event: rp::CollisionEvent,
        _contact_pair: Option<&rp::ContactPair>,
    ) {
        if let rp::CollisionEvent::Started(a, b, _) = event
            && let Ok(mut v) = self.0.lock()
        {
            v.push((a, b));
        }
    }

    fn handle_contact_force_event(
        &self,
        _dt: f64,
        _bodies: &rp::RigidBodySet,
        _colliders: &rp::ColliderSet,
        _contact_pair: &rp::ContactPair,
        _total_force_magnitude: f64,
    ) {
    }

    fn handle_soft_body_tear_event(
        &self,
        _soft_bodies: &rp::SoftBodySet,
        _event: &rp::SoftBodyTearEvent,
    ) {
    }
}

fn to_glam(v: &Vector3<f64>) -> rp::Vector {
    rp::Vector::new(v.x, v.y, v.z)
}

fn from_glam(v: rp::Vector) -> Vector3<f64> {
    Vector3::new(v.x, v.y, v.z)
}

fn pose_to_glam(p: &Isometry3<f64>) -> rp::Pose {
    let q = p.rotation.quaternion();
    rp::Pose::from_parts(
        to_glam(&p.translation.vector),
        rp::Rotation::from_xyzw(q.i, q.j, q.k, q.w),
    )
}

fn pose_from_glam(p: &rp::Pose) -> Isometry3<f64> {
    let q = p.rotation;
    Isometry3::from_parts(
        Translation3::from(from_glam(p.translation)),
        UnitQuaternion::from_quaternion(Quaternion::new(q.w, q.x, q.y, q.z)),
    )
}

/// Rotates parry's y-axis shapes (cylinders, heightfields) onto the world's z axis.
fn y_to_z() -> UnitQuaternion<f64> {
    UnitQuaternion::from_euler_angles(std::f64::consts::FRAC_PI_2, 0.0, 0.0)
}

/// The robot in a rapier3d world.
pub struct RapierPhysics<S: Surface> {
    surface: S,
    world: rp::PhysicsWorld,
    body: rp::RigidBodyHandle,
    contact: ContactModel,
    motors: Vec<Motor>,
    radii: [f64; MAX_DRIVE_JOINTS],
    dt: f64,
    mass_kg: f64,
    com_in_body: Vector3<f64>,
    inertia_about_com_in_body: Matrix3<f64>,
    gravity_mps2: f64,
    events: EventSink,
    links: Vec<String>,
    obstacles: Vec<Obstacle>,
    pending: Vec<CollisionEvent>,
}

impl<S: Surface> RapierPhysics<S> {
    /// The robot at `world_from_body` (at rest, drive joints at zero) in `scene`, stepped
    /// at `step_hz` under gravity `gravity_mps2` (along −z).
    ///
    /// Fails with a `physics.*` path for unusable parameters.
    pub fn new(
        robot: &RobotModel,
        scene: Scene<'_, S>,
        params: &PhysicsParams,
        step_hz: f64,
        gravity_mps2: f64,
        world_from_body: &Isometry3<f64>,
    ) -> Result<RapierPhysics<S>, ParamError> {
        let Scene {
            surface,
            obstacles,
            ground,
        } = scene;
        check(params)?;
        require_in("motion.step_hz", step_hz, 100.0, 100_000.0)?;
        let dt = 1.0 / step_hz;
        let mut world = rp::PhysicsWorld::new();
        world.gravity = rp::Vector::new(0.0, 0.0, -gravity_mps2);
        world.integration_parameters.dt = dt;

        let inertia = &robot.inertia;
        let m = &inertia.inertia_about_com_in_body;
        let mprops = rp::MassProperties::with_inertia_matrix(
            to_glam(&inertia.com_in_body),
            inertia.mass_kg,
            rp::Matrix::from_cols(
                to_glam(&m.column(0).into_owned()),
                to_glam(&m.column(1).into_owned()),
                to_glam(&m.column(2).into_owned()),
            ),
        );
        let rb = rp::RigidBodyBuilder::dynamic()
            .pose(pose_to_glam(world_from_body))
            .additional_mass_properties(mprops)
            .gyroscopic_forces_enabled(true)
            .can_sleep(false)
            .build();
        let body = world.insert_body(rb);
        let mut links = Vec::new();
        for (i, c) in robot.collision_shapes.iter().enumerate() {
            let (builder, extra) = match c.shape {
                Shape::Box { half_extents_m: h } => (
                    rp::ColliderBuilder::cuboid(h.x, h.y, h.z),
                    UnitQuaternion::identity(),
                ),
                Shape::Cylinder {
                    radius_m,
                    half_length_m,
                } => (
                    rp::ColliderBuilder::cylinder(half_length_m, radius_m),
                    y_to_z(),
                ),
                Shape::Sphere { radius_m } => (
                    rp::ColliderBuilder::ball(radius_m),
                    UnitQuaternion::identity(),
                ),
            };
            let (member, filter) = if c.running_gear {
                (RUNNING_GEAR, OBSTACLES)
            } else {
                (CHASSIS, OBSTACLES | GROUND)
            };
            let pose = Isometry3::from_parts(
                c.body_from_shape.translation,
                c.body_from_shape.rotation * extra,
            );
            let collider = builder
                .position(pose_to_glam(&pose))
                .density(0.0)
                .friction(0.5)
                .restitution(0.0)
                .collision_groups(rp::InteractionGroups::new(
                    member,
                    filter,
                    rp::InteractionTestMode::And,
                ))
                .active_events(rp::ActiveEvents::COLLISION_EVENTS)
                .user_data(ROBOT_TAG | i as u128)
                .build();
            world.insert_collider(collider, Some(body));
            links.push(c.link.clone());
        }
        let static_groups = |member| {
            rp::InteractionGroups::new(member, CHASSIS | RUNNING_GEAR, rp::InteractionTestMode::And)
        };
        for (i, o) in obstacles.iter().enumerate() {
            let centre = o.base_in_world + Vector3::z() * (o.height_m / 2.0);
            let (builder, rotation) = match o.box_footprint_m {
                None => (
                    rp::ColliderBuilder::cylinder(o.height_m / 2.0, o.radius_m),
                    y_to_z(),
                ),
                Some((length, width, yaw)) => (
                    rp::ColliderBuilder::cuboid(length / 2.0, width / 2.0, o.height_m / 2.0),
                    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
                ),
            };
            let collider = builder
                .position(pose_to_glam(&Isometry3::from_parts(
                    Translation3::from(centre),
                    rotation,
                )))
                .friction(0.5)
                .collision_groups(static_groups(OBSTACLES))
                .user_data(OBSTACLE_TAG | i as u128)
                .build();
            world.insert_collider(collider, None);
        }
        if let Some(g) = ground {
            // parry: rows along local z, columns along local x, heights along local y,
            // centred on the origin. Rotated by +90° about x, local z is world −y, so row
            // i is world y = y_max − i·cell.
            let (nrows, ncols) = (g.ny, g.nx);
            let mut data = vec![0.0; nrows * ncols];
            for i in 0..nrows {
                for j in 0..ncols {
                    data[i + j * nrows] = g.heights_m[(g.ny - 1 - i) * g.nx + j];
                }
            }
            let size_x = (g.nx - 1) as f64 * g.cell_m;
            let size_y = (g.ny - 1) as f64 * g.cell_m;
            let centre = Vector3::new(
                g.origin_x_m + size_x / 2.0,
                g.origin_y_m + size_y / 2.0,
                0.0,
            );
            let collider = rp::ColliderBuilder::heightfield(
                rp::Array2::new(nrows, ncols, data),
                rp::Vector::new(size_x, 1.0, size_y),
            )
            .position(pose_to_glam(&Isometry3::from_parts(
                Translation3::from(centre),
                y_to_z(),
            )))
            .friction(0.5)
            .collision_groups(static_groups(GROUND))
            .user_data(GROUND_TAG)
            .build();
            world.insert_collider(collider, None);
        }

        let soil = SoilParams {
            friction_scale: params.friction_scale,
            shear_deformation_m: params.shear_deformation_m,
            shear_damping_s: params.shear_damping_s,
            rolling_resistance: params.rolling_resistance,
            ripple_m: params.ripple_m,
        };
        let joints = robot.drive.joints();
        let share = inertia.mass_kg / joints.len() as f64;
        let mut radii = [0.0; MAX_DRIVE_JOINTS];
        let motors = joints
            .iter()
            .enumerate()
            .map(|(i, j)| {
                radii[i] = j.radius_m;
                Motor::for_joint(j, share, params.motor_bandwidth_hz)
            })
            .collect();
        Ok(RapierPhysics {
            surface,
            world,
            body,
            contact: ContactModel::new(ground_probes(robot, params), soil),
            motors,
            radii,
            dt,
            mass_kg: inertia.mass_kg,
            com_in_body: inertia.com_in_body,
            inertia_about_com_in_body: inertia.inertia_about_com_in_body,
            gravity_mps2,
            events: EventSink::default(),
            links,
            obstacles: obstacles.iter().map(|o| o.obstacle.clone()).collect(),
            pending: Vec::new(),
        })
    }

    /// Height of the terrain heightfield collider at `(x, y)` (a ray cast straight down),
    /// or `None` outside it or without one.
    pub fn heightfield_at(&self, x: f64, y: f64) -> Option<f64> {
        let ground = self
            .world
            .colliders
            .iter()
            .find(|(_, c)| c.user_data == GROUND_TAG)?
            .1;
        let top = ground.compute_aabb().maxs.z + 1.0;
        // parry 0.31 misses heightfields with rays exactly along their height axis, so
        // tilt the ray by 1e-9 rad (a horizontal offset of nanometres).
        let dir = rp::Vector::new(1e-9, 1e-9, -1.0).normalize();
        let ray = rp::Ray::new(rp::Vector::new(x, y, top), dir);
        let only_ground = |_: rp::ColliderHandle, c: &rp::Collider| c.user_data == GROUND_TAG;
        let filter = rp::QueryFilter::only_fixed().predicate(&only_ground);
        self.world
            .cast_ray(&ray, 1e6, true, filter)
            .map(|(_, toi)| top + dir.z * toi)
    }

    /// The contact model (probe states), for diagnostics and tests.
    pub fn contact(&self) -> &ContactModel {
        &self.contact
    }

    fn rigid_body(&self) -> Option<&rp::RigidBody> {
        self.world.bodies.get(self.body)
    }

    /// Pose, centre of mass and velocities of the body (centre-of-mass velocity).
    fn kinematics(&self) -> (Isometry3<f64>, Vector3<f64>, Vector3<f64>, Vector3<f64>) {
        match self.rigid_body() {
            Some(b) => (
                pose_from_glam(b.position()),
                from_glam(b.center_of_mass()),
                from_glam(b.linvel()),
                from_glam(b.angvel()),
            ),
            None => (
                Isometry3::identity(),
                self.com_in_body,
                Vector3::zeros(),
                Vector3::zeros(),
            ),
        }
    }
}

impl<S: Surface> Physics for RapierPhysics<S> {
    fn step_s(&self) -> f64 {
        self.dt
    }

    fn step(&mut self, speed_refs_radps: &[f64; MAX_DRIVE_JOINTS]) {
        let body = self.body();
        let com = self.kinematics().1;
        let mut joints = [JointKinematics::default(); MAX_DRIVE_JOINTS];
        for (i, m) in self.motors.iter().enumerate() {
            joints[i] = JointKinematics {
                angle_rad: m.angle_rad,
                speed_radps: m.speed_radps,
                radius_m: self.radii[i],
            };
        }
        let wrench = self.contact.step(
            &self.surface,
            &body,
            &com,
            &joints[..self.motors.len()],
            self.dt,
        );
        for (i, m) in self.motors.iter_mut().enumerate() {
            m.step(speed_refs_radps[i], wrench.joint_torque_nm[i], self.dt);
        }
        if let Some(b) = self.world.bodies.get_mut(self.body) {
            b.reset_forces(false);
            b.reset_torques(false);
            b.add_force(to_glam(&wrench.force_in_world), true);
            b.add_torque(to_glam(&wrench.torque_about_com_in_world), true);
        }
        self.world.step_with_events(&(), &self.events);
        let started = match self.events.0.lock() {
            Ok(mut v) => std::mem::take(&mut *v),
            Err(_) => Vec::new(),
        };
        let robot_position = self
            .rigid_body()
            .map(|b| from_glam(b.translation()))
            .unwrap_or_default();
        for (a, b) in started {
            let tag = |h| self.world.colliders.get(h).map(|c| c.user_data);
            let (Some(ta), Some(tb)) = (tag(a), tag(b)) else {
                continue;
            };
            let (robot, other) = if ta >> 64 == ROBOT_TAG >> 64 {
                (ta, tb)
            } else {
                (tb, ta)
            };
            if robot >> 64 != ROBOT_TAG >> 64 {
                continue;
            }
            let low = |t: u128| (t & u128::from(u64::MAX)) as usize;
            let obstacle = if other >> 64 == GROUND_TAG >> 64 {
                Obstacle::Ground
            } else if other >> 64 == OBSTACLE_TAG >> 64 {
                match self.obstacles.get(low(other)) {
                    Some(o) => o.clone(),
                    None => continue,
                }
            } else {
                continue;
            };
            self.pending.push(CollisionEvent {
                time_s: 0.0,
                link: self.links.get(low(robot)).cloned().unwrap_or_default(),
                obstacle,
                robot_position_m: [robot_position.x, robot_position.y, robot_position.z],
            });
        }
    }

    fn body(&self) -> BodyState {
        let (pose, com, v_com, omega) = self.kinematics();
        BodyState {
            velocity_in_world: v_com + omega.cross(&(pose.translation.vector - com)),
            world_from_body: pose,
            angular_velocity_in_world: omega,
        }
    }

    fn joints(&self) -> [JointState; MAX_DRIVE_JOINTS] {
        let mut out = [JointState::default(); MAX_DRIVE_JOINTS];
        for (o, m) in out.iter_mut().zip(&self.motors) {
            *o = JointState {
                angle_rad: m.angle_rad,
                speed_radps: m.speed_radps,
                effort_nm: m.torque_nm,
            };
        }
        out
    }

    fn take_collisions(&mut self, out: &mut Vec<CollisionEvent>) {
        out.append(&mut self.pending);
    }

    fn energy_j(&self) -> f64 {
        let (pose, com, v_com, omega) = self.kinematics();
        let r = pose.rotation.to_rotation_matrix();
        let i_world = r.matrix() * self.inertia_about_com_in_body * r.matrix().transpose();
        let kinetic = 0.5 * self.mass_kg * v_com.norm_squared()
            + 0.5 * omega.dot(&(i_world * omega))
            + self
                .motors
                .iter()
                .map(|m| 0.5 * m.inertia_kgm2 * m.speed_radps * m.speed_radps)
                .sum::<f64>();
        kinetic + self.mass_kg * self.gravity_mps2 * com.z + self.contact.spring_energy_j()
    }
}
