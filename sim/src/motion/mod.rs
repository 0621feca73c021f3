//! Motion models: what moves the robot along its route and produces ground truth.
//!
//! A [`MotionModel`] is queried at increasing times; the truth it returns at a time does
//! not depend on which other times were queried (the integrator steps on its own fixed
//! grid), so adding or removing a sensor never changes the trajectory.
//!
//! Models so far:
//! - [`KinematicSkidSteer`]: a terrain-following tracked robot (pitch and roll from the
//!   ground under its footprint) following a [`crate::route::Route`] with pure pursuit.
//!   Its velocity, acceleration and angular velocity are the exact derivatives of its
//!   pose, so noise-free IMU samples integrate back to the trajectory.
//!
//! ```
//! use vinebench_msgs::Nanos;
//! use vinebench_sim::motion::{KinematicSkidSteer, MotionModel};
//! use vinebench_sim::params::{MotionParams, RouteParams, WorldParams};
//! use vinebench_sim::robot::RobotModel;
//! use vinebench_sim::route::build_route;
//! use vinebench_sim::world::{PlaneSurface, RowLayout};
//!
//! let world = WorldParams::default();
//! let layout = RowLayout::new(&world.rows);
//! let route = build_route(&RouteParams::default(), &layout, &world.headlands)?;
//! let robot = RobotModel::builtin("tracked-sensorbox").expect("built-in model");
//! let ground = PlaneSurface { z0_m: 0.0, gradient: [0.0, 0.0].into() };
//! let start = Nanos::from_secs(1_631_696_400);
//! let mut motion =
//!     KinematicSkidSteer::new(&MotionParams::default(), route, ground, &robot.geometry, start)?;
//! let truth = motion.advance_to(start + Nanos::from_secs(10));
//! assert!(truth.velocity_in_world.norm() > 0.5 && !motion.finished());
//! # Ok::<(), vinebench_sim::params::ParamError>(())
//! ```

pub mod kinematic;

pub use kinematic::KinematicSkidSteer;

use crate::truth::TruthSample;
use vinebench_msgs::Nanos;

/// Something that moves the robot and knows its true state.
pub trait MotionModel {
    /// The true state at `t`. Calls must come with non-decreasing `t` (not before
    /// [`MotionModel::start_time`]); the same `t` may be queried again.
    fn advance_to(&mut self, t: Nanos) -> TruthSample;
    /// Time of the first state.
    fn start_time(&self) -> Nanos;
    /// True once the route is complete and the robot has stood still for the final
    /// stand-still time, as of the latest [`MotionModel::advance_to`].
    fn finished(&self) -> bool;
    /// Expected total duration of the run (route plus stand-stills), for progress bars.
    fn expected_duration(&self) -> Nanos;
}
