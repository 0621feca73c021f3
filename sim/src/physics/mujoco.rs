//! The MuJoCo backend (cargo feature `mujoco`): MuJoCo 3.17 through mujoco-rs 7.0.0.
//!
//! The robot is the multibody of [`super::mjcf`]: a free-floating chassis; mecanum wheels
//! as hinges with velocity actuators and passive rollers; tracks as conveyor belts (geoms
//! with a surface velocity) driven by sprocket models; all on a terrain heightfield with
//! posts, trunks and boxes as static geoms. MuJoCo's soft contacts with Coulomb friction
//! (elliptic cones) replace the rapier backend's probe model of [`super::contact`]: the
//! two engines share the URDF, the servo law and the controller above them, and differ in
//! how the ground pushes back.
//!
//! The drive joints' speed servos are the PI law of [`super::contact::Motor`] (same
//! gains, torque limit and anti-windup):
//! - a mecanum wheel's servo is MuJoCo's velocity actuator for the proportional part,
//!   integrated implicitly (`implicitfast`) so the stiff servo on a light wheel stays
//!   stable, plus the integral part as an offset on its control;
//! - a track's sprocket is a [`Motor`] stepped here, loaded by the ground's friction on its
//!   belt (the contact forces of the previous step), and its speed sets the belt's surface
//!   velocity for the next;
//! - a belt sphere's friction is elliptic anisotropic Coulomb friction (maximum
//!   dissipation): slipping by `(s_l, s_t)` along and across the belt, the ground pushes
//!   back with `N·(mu1·c_l, mu2·c_t)`, `(c_l, c_t) = (mu1·|s_l|, mu2·|s_t|) / norm`
//!   (regularized below 1 cm/s of slip, where both grip fully). MuJoCo's contacts are
//!   isotropic, so the sideways part is the dry friction of the sphere's sideways hinge
//!   and the contact's coefficient is the whole, `hypot(mu1·c_l, mu2·c_t)`; both are set
//!   before each step from the sphere's normal force of the step before and its slip at
//!   the start of the step.
//!
//! The library is `libmujoco.so.3.17.0` from the PyPI wheel (`scripts/install-mujoco.sh`).
//! mujoco-rs's types stay in this file.

use super::contact::Motor;
use super::mjcf::{self, Mjcf, SceneSpec, names};
use super::rapier::{HeightGrid, ObstacleShape};
use super::{BodyState, CollisionEvent, JointState, Obstacle, Physics};
use crate::params::{ParamError, PhysicsParams, require_in};
use crate::robot::{MAX_DRIVE_JOINTS, RobotModel};
use mujoco_rs::prelude::{MjData, MjModel, MjtObjBase};
use nalgebra::{Isometry3, Matrix3, Quaternion, Translation3, UnitQuaternion, Vector3};

/// Slip speed below which a belt point grips fully both ways, m/s.
const SLIP_SCALE_MPS: f64 = 0.01;

/// A robot-obstacle contact that has been apart this long begins anew, s.
const RECONTACT_S: f64 = 0.1;

/// What a geom of the compiled model is, for collision reports.
#[derive(Clone, Debug, PartialEq)]
enum GeomRole {
    /// A robot collision shape of this link that reports what it hits.
    Robot(String),
    /// An obstacle.
    Obstacle(Obstacle),
    /// The terrain.
    Terrain,
    /// Rollers, belts: their ground contact is the drive, not a collision.
    Other,
}

/// Why the MuJoCo backend could not be built.
#[derive(Debug, thiserror::Error)]
pub enum MujocoError {
    /// A parameter is out of range.
    #[error(transparent)]
    Param(#[from] ParamError),
    /// The generated model is unusable (robot or scene).
    #[error("MuJoCo model of robot `{robot}`: {what}")]
    Model {
        /// The robot's name.
        robot: String,
        /// What went wrong, with MuJoCo's message where it gave one.
        what: String,
    },
}

impl From<MujocoError> for ParamError {
    fn from(e: MujocoError) -> ParamError {
        match e {
            MujocoError::Param(p) => p,
            MujocoError::Model { robot, what } => ParamError::new(
                "motion.model",
                format!("a robot MuJoCo can simulate (robot `{robot}`)"),
                what,
            ),
        }
    }
}

/// A mecanum wheel: a hinge with a velocity actuator.
#[derive(Clone, Debug)]
struct Wheel {
    qpos_adr: usize,
    dof_adr: usize,
    actuator: usize,
    kp: f64,
    ki: f64,
    max_torque_nm: f64,
    integral_rad: f64,
    inertia_kgm2: f64,
}

/// A track: the sprocket's drive train and the belt geoms it moves.
#[derive(Clone, Debug)]
struct Belt {
    motor: Motor,
    geoms: Vec<usize>,
    /// The `qvel` address of each belt sphere's sideways hinge (same order as `geoms`).
    roll_dofs: Vec<usize>,
    /// Each belt sphere's normal force in the last step, N (same order as `geoms`).
    normal_n: Vec<f64>,
    /// Each belt sphere's centre in the body frame (same order as `geoms`).
    centres_in_body: Vec<Vector3<f64>>,
    /// Friction coefficients along the belt and across it (`friction_scale` applied).
    mu: [f64; 2],
    /// Belt sphere radius, m.
    sphere_radius_m: f64,
    /// Sprocket pitch radius, m.
    radius_m: f64,
    /// The belt's forward direction in the body frame.
    forward_in_body: Vector3<f64>,
    /// Ground torque on the sprocket from the last step's contacts, N·m.
    load_torque_nm: f64,
}

impl Belt {
    /// Elliptic anisotropic Coulomb friction (maximum dissipation) of belt sphere `k` for
    /// the body's velocity (`lin`, `ang`, body frame): a belt point slipping by
    /// `(s_l, s_t)` along and across the belt is pushed back by `N·(mu1·c_l, mu2·c_t)`,
    /// `(c_l, c_t) = (mu1·|s_l|, mu2·|s_t|) / norm`. Returns the sideways hinge's dry
    /// friction torque (`mu2·c_t·N·r`) and the contact's isotropic coefficient, the whole
    /// `hypot(mu1·c_l, mu2·c_t)`.
    fn friction(&self, k: usize, lin: &Vector3<f64>, ang: &Vector3<f64>) -> (f64, f64) {
        let point = lin + ang.cross(&self.centres_in_body[k]);
        let across = Vector3::z().cross(&self.forward_in_body);
        let s_l = point.dot(&self.forward_in_body) - self.motor.speed_radps * self.radius_m;
        let s_t = point.dot(&across);
        let (a, t) = ((self.mu[0] * s_l).abs(), (self.mu[1] * s_t).abs());
        let e2 = (self.mu[1] * SLIP_SCALE_MPS).powi(2);
        let norm = (a * a + t * t + e2).sqrt();
        let (c_l, c_t) = ((a * a + e2).sqrt() / norm, (t * t + e2).sqrt() / norm);
        (
            self.mu[1] * c_t * self.normal_n[k] * self.sphere_radius_m,
            (self.mu[0] * c_l).hypot(self.mu[1] * c_t),
        )
    }
}

/// One drive joint.
#[derive(Clone, Debug)]
enum Drive {
    Wheel(Wheel),
    Belt(Belt),
}

/// The robot in a MuJoCo world.
pub struct MujocoPhysics {
    data: MjData<Box<MjModel>>,
    /// A copy of the model: belt surface velocities are written into it and the two are
    /// swapped each step (mujoco-rs allows changing a model in use only unsafely).
    spare: Option<Box<MjModel>>,
    dt: f64,
    drives: Vec<Drive>,
    geoms: Vec<GeomRole>,
    /// Robot-versus-world geom pairs in contact lately, with the step they were last seen
    /// (sorted by pair).
    touching: Vec<((usize, usize), u64)>,
    /// Steps taken.
    steps: u64,
    pending: Vec<CollisionEvent>,
    mass_kg: f64,
    com_in_body: Vector3<f64>,
    inertia_about_com_in_body: Matrix3<f64>,
    gravity_mps2: f64,
    /// The generated model, for `vinebench` to save next to a run.
    mjcf: Mjcf,
}

impl MujocoPhysics {
    /// The robot at `world_from_body` (at rest) on `ground` among `obstacles`, stepped at
    /// `step_hz` under gravity `gravity_mps2` (along −z).
    pub fn new(
        robot: &RobotModel,
        ground: &HeightGrid,
        obstacles: &[ObstacleShape],
        params: &PhysicsParams,
        step_hz: f64,
        gravity_mps2: f64,
        world_from_body: &Isometry3<f64>,
    ) -> Result<MujocoPhysics, MujocoError> {
        require_in("motion.step_hz", step_hz, 100.0, 100_000.0)?;
        require_in(
            "physics.motor_bandwidth_hz",
            params.motor_bandwidth_hz,
            0.1,
            100.0,
        )?;
        require_in("physics.friction_scale", params.friction_scale, 1e-3, 10.0)?;
        mjcf::check(&params.mujoco)?;
        let model_error = |what: String| MujocoError::Model {
            robot: robot.name.clone(),
            what,
        };
        let dt = 1.0 / step_hz;
        let spec = SceneSpec {
            ground,
            obstacles,
            world_from_body: *world_from_body,
            dt_s: dt,
            gravity_mps2,
            friction_scale: params.friction_scale,
            motor_bandwidth_hz: params.motor_bandwidth_hz,
            params: &params.mujoco,
        };
        let mjcf = mjcf::generate(robot, &spec).map_err(|e| model_error(e.what))?;
        let mut model = MjModel::from_xml_string(&mjcf.xml)
            .map_err(|e| model_error(format!("MuJoCo rejected the generated MJCF: {e}")))?;
        {
            let data = model.hfield_data_mut();
            if data.len() != mjcf.hfield.normalized.len() {
                return Err(model_error(format!(
                    "heightfield of {} values, MuJoCo allocated {}",
                    mjcf.hfield.normalized.len(),
                    data.len()
                )));
            }
            data.copy_from_slice(&mjcf.hfield.normalized);
        }
        let id = |kind: MjtObjBase, name: &str| {
            model
                .name_to_id(kind, name)
                .ok_or_else(|| model_error(format!("the compiled model has no `{name}`")))
        };
        let share = robot.inertia.mass_kg / robot.drive.joints().len() as f64;
        let mut drives = Vec::new();
        let tracks = match &robot.drive {
            crate::robot::Drive::Tracked(t) => vec![&t.left, &t.right],
            crate::robot::Drive::Mecanum(_) => Vec::new(),
        };
        for (i, (j, train)) in robot.drive.joints().iter().zip(&mjcf.drives).enumerate() {
            match tracks.get(i) {
                None => {
                    let jid = id(MjtObjBase::mjOBJ_JOINT, &j.name)?;
                    let servo = Motor::for_joint(j, share, params.motor_bandwidth_hz);
                    drives.push(Drive::Wheel(Wheel {
                        qpos_adr: model.jnt_qposadr()[jid] as usize,
                        dof_adr: model.jnt_dofadr()[jid] as usize,
                        actuator: id(MjtObjBase::mjOBJ_ACTUATOR, &j.name)?,
                        kp: servo.kp,
                        ki: servo.ki,
                        max_torque_nm: j.max_torque_nm,
                        integral_rad: 0.0,
                        inertia_kgm2: j.inertia_kgm2,
                    }));
                }
                Some(track) => {
                    let geoms = train
                        .members
                        .iter()
                        .map(|name| id(MjtObjBase::mjOBJ_GEOM, name))
                        .collect::<Result<Vec<_>, _>>()?;
                    let roll_dofs = train
                        .members
                        .iter()
                        .map(|name| {
                            let joint = id(MjtObjBase::mjOBJ_JOINT, &names::belt_roll(name))?;
                            Ok(model.jnt_dofadr()[joint] as usize)
                        })
                        .collect::<Result<Vec<_>, MujocoError>>()?;
                    drives.push(Drive::Belt(Belt {
                        motor: Motor::for_joint(j, share, params.motor_bandwidth_hz),
                        normal_n: vec![0.0; geoms.len()],
                        centres_in_body: geoms
                            .iter()
                            .map(|&g| {
                                let body = model.geom_bodyid()[g] as usize;
                                Vector3::from(model.body_pos()[body])
                            })
                            .collect(),
                        mu: [
                            track.contact.mu1 * params.friction_scale,
                            track.contact.mu2 * params.friction_scale,
                        ],
                        sphere_radius_m: track.height_m / 2.0,
                        roll_dofs,
                        geoms,
                        radius_m: j.radius_m,
                        forward_in_body: track.body_from_track.rotation * Vector3::x(),
                        load_torque_nm: 0.0,
                    }));
                }
            }
        }
        let ngeom = model.ffi().ngeom as usize;
        let mut geoms = vec![GeomRole::Other; ngeom];
        let terrain = id(MjtObjBase::mjOBJ_GEOM, names::TERRAIN)?;
        geoms[terrain] = GeomRole::Terrain;
        for (i, o) in obstacles.iter().enumerate() {
            geoms[id(MjtObjBase::mjOBJ_GEOM, &names::obstacle(i))?] =
                GeomRole::Obstacle(o.obstacle.clone());
        }
        for (i, s) in robot.collision_shapes.iter().enumerate() {
            geoms[id(MjtObjBase::mjOBJ_GEOM, &names::collision(i))?] =
                GeomRole::Robot(s.link.clone());
        }
        let has_belts = drives.iter().any(|d| matches!(d, Drive::Belt(_)));
        let spare = has_belts.then(|| Box::new(model.clone()));
        let data = MjData::new(Box::new(model));
        Ok(MujocoPhysics {
            data,
            spare,
            dt,
            drives,
            geoms,
            touching: Vec::new(),
            steps: 0,
            pending: Vec::new(),
            mass_kg: robot.inertia.mass_kg,
            com_in_body: robot.inertia.com_in_body,
            inertia_about_com_in_body: robot.inertia.inertia_about_com_in_body,
            gravity_mps2,
            mjcf,
        })
    }

    /// The generated MJCF model (its heightfield is written after compiling).
    pub fn mjcf(&self) -> &Mjcf {
        &self.mjcf
    }

    /// Degrees of freedom of the compiled model.
    pub fn dofs(&self) -> usize {
        self.data.qvel().len()
    }

    /// Contacts MuJoCo found in the last step.
    pub fn contact_count(&self) -> usize {
        self.data.contact().len()
    }

    fn pose(&self) -> Isometry3<f64> {
        let q = self.data.qpos();
        Isometry3::from_parts(
            Translation3::new(q[0], q[1], q[2]),
            UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[4], q[5], q[6])),
        )
    }

    /// From the contacts of the last step: the ground's torque on each belt's sprocket
    /// (minus the pitch radius times the friction along the belt) and each belt sphere's
    /// normal force.
    fn update_belt_loads(&mut self) {
        let rotation = self.pose().rotation;
        for d in &mut self.drives {
            if let Drive::Belt(b) = d {
                b.load_torque_nm = 0.0;
                b.normal_n.fill(0.0);
            }
        }
        for (i, c) in self.data.contact().iter().enumerate() {
            let (g1, g2) = (c.geom1 as usize, c.geom2 as usize);
            for d in &mut self.drives {
                let Drive::Belt(b) = d else { continue };
                // mj_contactForce: the force in the contact frame (normal from geom1 to
                // geom2, then two tangents) that geom1 exerts on geom2.
                let (sign, k) = if let Some(k) = b.geoms.iter().position(|&g| g == g2) {
                    (1.0, k)
                } else if let Some(k) = b.geoms.iter().position(|&g| g == g1) {
                    (-1.0, k)
                } else {
                    continue;
                };
                let f = self.data.contact_force(i);
                b.normal_n[k] += f[0].max(0.0);
                let frame = &c.frame;
                let on_belt = Vector3::new(
                    f[0] * frame[0] + f[1] * frame[3] + f[2] * frame[6],
                    f[0] * frame[1] + f[1] * frame[4] + f[2] * frame[7],
                    f[0] * frame[2] + f[1] * frame[5] + f[2] * frame[8],
                ) * sign;
                b.load_torque_nm -= b.radius_m * on_belt.dot(&(rotation * b.forward_in_body));
            }
        }
    }
}

impl Physics for MujocoPhysics {
    fn step_s(&self) -> f64 {
        self.dt
    }

    fn step(&mut self, speed_refs_radps: &[f64; MAX_DRIVE_JOINTS]) {
        let dt = self.dt;
        // Sprockets: one step of their drive trains; the belts' surfaces move backwards at
        // the new pitch speed. Each belt sphere's sideways friction follows its load.
        if let Some(mut spare) = self.spare.take() {
            {
                let surface = spare.geom_surfacevel_mut();
                for (i, d) in self.drives.iter_mut().enumerate() {
                    let Drive::Belt(b) = d else { continue };
                    b.motor.step(speed_refs_radps[i], b.load_torque_nm, dt);
                    let v = -b.motor.speed_radps * b.radius_m;
                    for &g in &b.geoms {
                        surface[g] = [v, 0.0, 0.0, 0.0, 0.0, 0.0];
                    }
                }
            }
            // Elliptic belt friction from the slip at the start of the step.
            let v = self.data.qvel();
            let lin = self.pose().rotation.inverse() * Vector3::new(v[0], v[1], v[2]);
            let ang = Vector3::new(v[3], v[4], v[5]);
            let belts = self.drives.iter().filter_map(|d| match d {
                Drive::Belt(b) => Some(b),
                Drive::Wheel(_) => None,
            });
            {
                let hinge = spare.dof_frictionloss_mut();
                for b in belts.clone() {
                    for k in 0..b.geoms.len() {
                        hinge[b.roll_dofs[k]] = b.friction(k, &lin, &ang).0;
                    }
                }
            }
            {
                let contact = spare.geom_friction_mut();
                for b in belts {
                    for k in 0..b.geoms.len() {
                        contact[b.geoms[k]][0] = b.friction(k, &lin, &ang).1;
                    }
                }
            }
            self.spare = Some(self.data.swap_model(spare));
        }
        // Wheels: the PI servo on MuJoCo's velocity actuators.
        let mut ctrl = [(usize::MAX, 0.0); MAX_DRIVE_JOINTS];
        {
            let qvel = self.data.qvel();
            for (i, d) in self.drives.iter_mut().enumerate() {
                let Drive::Wheel(s) = d else { continue };
                let error = speed_refs_radps[i] - qvel[s.dof_adr];
                let unclamped = s.kp * error + s.ki * (s.integral_rad + error * dt);
                let torque = unclamped.clamp(-s.max_torque_nm, s.max_torque_nm);
                if torque == unclamped || error.signum() != unclamped.signum() {
                    s.integral_rad += error * dt;
                }
                // The actuator's force is kv·(ctrl − speed): the reference plus the integral
                // term as a speed offset (clamped by its force range).
                ctrl[i] = (
                    s.actuator,
                    speed_refs_radps[i] + s.ki * s.integral_rad / s.kp,
                );
            }
        }
        {
            let c = self.data.ctrl_mut();
            for &(a, v) in ctrl.iter().filter(|(a, _)| *a != usize::MAX) {
                c[a] = v;
            }
        }
        self.data.step();
        if self.spare.is_some() {
            self.update_belt_loads();
        }

        // Contacts that began: robot shapes against obstacles or the terrain.
        let mut now: Vec<(usize, usize)> = Vec::new();
        for c in self.data.contact() {
            let (a, b) = (c.geom1 as usize, c.geom2 as usize);
            let (robot, other) = match (self.geoms.get(a), self.geoms.get(b)) {
                (Some(GeomRole::Robot(_)), Some(GeomRole::Obstacle(_) | GeomRole::Terrain)) => {
                    (a, b)
                }
                (Some(GeomRole::Obstacle(_) | GeomRole::Terrain), Some(GeomRole::Robot(_))) => {
                    (b, a)
                }
                _ => continue,
            };
            now.push((robot, other));
        }
        now.sort_unstable();
        now.dedup();
        self.steps += 1;
        let q = self.data.qpos();
        let position = [q[0], q[1], q[2]];
        // A contact that flickers (soft contacts against a post while pushing) is one
        // collision: a pair begins again only after RECONTACT_S without touching.
        let forget = (RECONTACT_S / self.dt).ceil() as u64;
        let steps = self.steps;
        self.touching
            .retain(|(_, seen)| steps.saturating_sub(*seen) <= forget);
        for pair in now {
            match self.touching.binary_search_by_key(&pair, |(p, _)| *p) {
                Ok(i) => self.touching[i].1 = steps,
                Err(i) => {
                    self.touching.insert(i, (pair, steps));
                    let (GeomRole::Robot(link), other) = (&self.geoms[pair.0], &self.geoms[pair.1])
                    else {
                        continue;
                    };
                    let obstacle = match other {
                        GeomRole::Obstacle(o) => o.clone(),
                        _ => Obstacle::Ground,
                    };
                    self.pending.push(CollisionEvent {
                        time_s: 0.0,
                        link: link.clone(),
                        obstacle,
                        robot_position_m: position,
                    });
                }
            }
        }
    }

    fn body(&self) -> BodyState {
        let pose = self.pose();
        let v = self.data.qvel();
        // Free joint: linear velocity of the body origin in the world frame, angular
        // velocity in the body frame.
        let omega_body = Vector3::new(v[3], v[4], v[5]);
        BodyState {
            world_from_body: pose,
            velocity_in_world: Vector3::new(v[0], v[1], v[2]),
            angular_velocity_in_world: pose.rotation * omega_body,
        }
    }

    fn joints(&self) -> [JointState; MAX_DRIVE_JOINTS] {
        let mut out = [JointState::default(); MAX_DRIVE_JOINTS];
        let (q, v, f) = (
            self.data.qpos(),
            self.data.qvel(),
            self.data.actuator_force(),
        );
        for (o, d) in out.iter_mut().zip(&self.drives) {
            *o = match d {
                Drive::Wheel(s) => JointState {
                    angle_rad: q[s.qpos_adr],
                    speed_radps: v[s.dof_adr],
                    effort_nm: f[s.actuator],
                },
                Drive::Belt(b) => JointState {
                    angle_rad: b.motor.angle_rad,
                    speed_radps: b.motor.speed_radps,
                    effort_nm: b.motor.torque_nm,
                },
            };
        }
        out
    }

    fn take_collisions(&mut self, out: &mut Vec<CollisionEvent>) {
        out.append(&mut self.pending);
    }

    fn energy_j(&self) -> f64 {
        // The robot as one rigid body plus its drive trains, as the rapier backend counts
        // it (MuJoCo's soft contacts store no energy).
        let b = self.body();
        let r = b.world_from_body.rotation.to_rotation_matrix();
        let com = b.world_from_body * nalgebra::Point3::from(self.com_in_body);
        let v_com = b.velocity_in_world
            + b.angular_velocity_in_world
                .cross(&(com.coords - b.world_from_body.translation.vector));
        let i_world = r.matrix() * self.inertia_about_com_in_body * r.matrix().transpose();
        let omega = b.angular_velocity_in_world;
        let v = self.data.qvel();
        let spin: f64 = self
            .drives
            .iter()
            .map(|d| match d {
                Drive::Wheel(s) => 0.5 * s.inertia_kgm2 * v[s.dof_adr] * v[s.dof_adr],
                Drive::Belt(b) => {
                    0.5 * b.motor.inertia_kgm2 * b.motor.speed_radps * b.motor.speed_radps
                }
            })
            .sum();
        0.5 * self.mass_kg * v_com.norm_squared()
            + 0.5 * omega.dot(&(i_world * omega))
            + spin
            + self.mass_kg * self.gravity_mps2 * com.z
    }
}
