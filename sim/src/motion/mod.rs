//! Motion models: what moves the robot along its route and produces ground truth.
//!
//! A [`MotionModel`] is queried at increasing times; the truth it returns at a time does
//! not depend on which other times were queried (the integrator steps on its own fixed
//! grid), so adding or removing a sensor never changes the trajectory.

pub mod kinematic;

pub use kinematic::KinematicSkidSteer;

use crate::truth::TruthSample;
use vinebench_msgs::Nanos;

/// Something that moves the robot and knows its true state.
pub trait MotionModel {
    /// The true state at `t`. Calls must come with non-decreasing `t` (not before
    /// [`MotionModel::start_time`]).
    fn advance_to(&mut self, t: Nanos) -> TruthSample;
    /// Time of the first state.
    fn start_time(&self) -> Nanos;
    /// True once the route is complete and the robot has stood still for the final
    /// stand-still time, as of the latest [`MotionModel::advance_to`].
    fn finished(&self) -> bool;
    /// Expected total duration of the run (route plus stand-stills), for progress bars.
    fn expected_duration(&self) -> Nanos;
}
