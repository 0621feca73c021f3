//! Rigid-body dynamics of the robot on the vineyard ground.
//!
//! A [`Physics`] backend advances the robot by fixed steps under drive-joint speed
//! references and reports its state: the pose and velocity of the body, the drive joints
//! (what the encoders see) and the contacts with obstacles. [`crate::motion::Dynamic`]
//! turns a backend into a [`crate::motion::MotionModel`] (route follower, ground truth at
//! any time).
//!
//! Backends:
//! - [`RapierPhysics`] (default): rapier3d (f64) integrates the robot as one rigid body
//!   with the mass properties of its URDF, and resolves contacts of its collision shapes
//!   with trellis posts, trunks and the terrain (as a heightfield). The tracks' and
//!   wheels' contact with the ground is the model of [`contact`]: probe spheres with a
//!   spring-damper normal force and a shear-displacement friction with relaxation on the
//!   analytic C² terrain surface, and a speed servo per drive joint.
//! - `MujocoPhysics` (cargo feature `mujoco`): MuJoCo 3.17 integrates the same URDF robot
//!   as a multibody with real running gear (passive mecanum rollers, conveyor-belt tracks
//!   driven by the sprockets) on a terrain heightfield; [`mjcf`] generates its model. It
//!   is the cross-check of the rapier backend's contact model.
//!
//! Velocities follow the symplectic-Euler convention of rapier3d and MuJoCo: the
//! velocities after a step are the mean velocities over that step
//! (`x_k = x_{k−1} + dt·v_k`).

pub mod contact;
pub mod mjcf;
#[cfg(feature = "mujoco")]
pub mod mujoco;
pub mod rapier;

#[cfg(feature = "mujoco")]
pub use mujoco::MujocoPhysics;
pub use rapier::{RapierPhysics, Scene};

use crate::robot::MAX_DRIVE_JOINTS;
use nalgebra::{Isometry3, Vector3};
use serde::Serialize;

/// The state of the robot body after a step.
#[derive(Clone, Debug, PartialEq)]
pub struct BodyState {
    /// `world_from_body` (`base_link`).
    pub world_from_body: Isometry3<f64>,
    /// Velocity of the `base_link` origin over the last step, world frame, m/s.
    pub velocity_in_world: Vector3<f64>,
    /// Angular velocity over the last step, world frame, rad/s.
    pub angular_velocity_in_world: Vector3<f64>,
}

/// One drive joint (sprocket or wheel) after a step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct JointState {
    /// Angle, rad (unwrapped).
    pub angle_rad: f64,
    /// Speed over the last step, rad/s.
    pub speed_radps: f64,
    /// Motor torque, N·m.
    pub effort_nm: f64,
}

/// What the robot hit.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Obstacle {
    /// A trellis post (index in [`crate::world::World::posts`]).
    Post {
        /// Row of the post.
        row: u32,
        /// Index in the world's post list.
        index: usize,
    },
    /// A vine trunk (index in [`crate::world::World::plants`]).
    Trunk {
        /// Row of the vine.
        row: u32,
        /// Planting slot along the row.
        slot: u32,
    },
    /// A featureless box (index in [`crate::world::World::occluders`]).
    Occluder {
        /// Index in the world's occluder list.
        index: usize,
    },
    /// The ground, touched by the chassis (not the tracks or wheels): the robot bottomed
    /// out.
    Ground,
}

/// A contact between the robot and an obstacle that began during a step.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CollisionEvent {
    /// Simulated seconds since the start of the run.
    pub time_s: f64,
    /// The robot link whose collision shape touched it.
    pub link: String,
    /// The obstacle.
    pub obstacle: Obstacle,
    /// World position of the robot body origin at the time, m.
    pub robot_position_m: [f64; 3],
}

/// A fixed-step rigid-body simulation of one robot.
pub trait Physics {
    /// The fixed step, s.
    fn step_s(&self) -> f64;
    /// Advances one step, with the drive joints' speed servos tracking
    /// `speed_refs_radps` (in [`crate::robot::Drive::joints`] order).
    fn step(&mut self, speed_refs_radps: &[f64; MAX_DRIVE_JOINTS]);
    /// The body after the last step.
    fn body(&self) -> BodyState;
    /// The drive joints after the last step (unused entries zero).
    fn joints(&self) -> [JointState; MAX_DRIVE_JOINTS];
    /// Appends the obstacle contacts that began since the last call (`time_s` left 0:
    /// the caller knows the time) and clears them.
    fn take_collisions(&mut self, out: &mut Vec<CollisionEvent>);
    /// Mechanical energy of the robot: kinetic, gravitational (relative to z = 0) and
    /// stored in the ground contact springs, J. Drive-train kinetic energy included.
    fn energy_j(&self) -> f64;
}

#[cfg(test)]
mod tests;

#[cfg(test)]
#[cfg(feature = "mujoco")]
mod mujoco_tests;
