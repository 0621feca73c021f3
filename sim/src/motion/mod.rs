//! Motion models: what moves the robot along its route and produces ground truth.
//!
//! A [`MotionModel`] is queried at increasing times; the truth it returns at a time does
//! not depend on which other times were queried (the integrator steps on its own fixed
//! grid), so adding or removing a sensor never changes the trajectory.
//!
//! Models:
//! - [`Dynamic`] (default): a [`crate::physics::Physics`] backend (rapier3d) driven by the
//!   route follower of [`crate::control`]: rigid-body dynamics with track and mecanum
//!   ground contact, slip, vibration and collisions.
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

pub mod clearance;
pub mod dynamic;
pub mod kinematic;
pub mod tracking;

pub use clearance::{ClearanceMetrics, Intrusion, RowClearance};
pub use dynamic::Dynamic;
pub use kinematic::KinematicSkidSteer;
pub use tracking::{RobotMetrics, RouteTracking};

use crate::physics::CollisionEvent;
use crate::truth::TruthSample;
use serde::Serialize;
use vinebench_msgs::Nanos;

/// Steps per controller tick: `motion.step_hz / motion.controller_hz`, which must be a
/// whole number (commands change only on the integration grid).
pub fn steps_per_tick(step_hz: f64, controller_hz: f64) -> Result<u64, crate::params::ParamError> {
    let controller_hz = crate::params::require_positive("motion.controller_hz", controller_hz)?;
    let ratio = step_hz / controller_hz;
    let every = ratio.round();
    if !(every >= 1.0 && (ratio - every).abs() <= 1e-9 * ratio) {
        return Err(crate::params::ParamError::new(
            "motion.controller_hz",
            format!("a rate that divides motion.step_hz = {step_hz} Hz (whole steps per tick)"),
            controller_hz,
        ));
    }
    Ok(every as u64)
}

/// How a run's motion ended, as of the latest [`MotionModel::advance_to`].
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum MotionOutcome {
    /// Still going.
    Running,
    /// The route is complete and the robot stood still for the final stand-still.
    Completed,
    /// The robot made no progress along its route for `physics.stuck_timeout_s` while it
    /// should have been driving.
    Stuck {
        /// When the run gave up, s after the start.
        at_s: f64,
        /// Arc length reached along the route, m.
        progress_m: f64,
    },
    /// The physics state became non-finite or physically impossible for the robot (beyond
    /// the bounds of [`dynamic`]: [`dynamic::MAX_BODY_SPEED_MPS`],
    /// [`dynamic::MAX_BODY_RATE_RADPS`], [`dynamic::MAX_BODY_ACCEL_MPS2`]): the simulation
    /// cannot be trusted from there on, and the run ends.
    PhysicsDiverged {
        /// Time of the first bad physics step, s after the start.
        at_s: f64,
        /// What was wrong, with the value and the bound.
        reason: String,
    },
    /// The robot tipped over: its body z axis stayed more than
    /// [`dynamic::TIP_OVER_TILT_DEG`] from the vertical for [`dynamic::TIP_OVER_HOLD_S`].
    TippedOver {
        /// When the run ended, s after the start.
        at_s: f64,
        /// When the tilt first went beyond the bound, s after the start.
        tilted_at_s: f64,
        /// The tilt when the run ended, degrees.
        tilt_deg: f64,
    },
}

impl MotionOutcome {
    /// True for an outcome that makes the run invalid (physics diverged, robot tipped
    /// over): such a run must not pass whatever its expectations say.
    pub fn is_failure(&self) -> bool {
        matches!(
            self,
            MotionOutcome::PhysicsDiverged { .. } | MotionOutcome::TippedOver { .. }
        )
    }
}

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
    /// How the motion ended (or [`MotionOutcome::Running`]).
    fn outcome(&self) -> MotionOutcome {
        if self.finished() {
            MotionOutcome::Completed
        } else {
            MotionOutcome::Running
        }
    }
    /// Contacts with obstacles so far (none for models without collision geometry).
    fn collisions(&self) -> &[CollisionEvent] {
        &[]
    }
    /// True when the model's controller can steer on something other than the truth
    /// ([`MotionModel::set_steering`]).
    fn supports_steering(&self) -> bool {
        false
    }
    /// What the controller steers on from the next controller tick on (closed loop). A
    /// model that does not support it ([`MotionModel::supports_steering`]) ignores it.
    fn set_steering(&mut self, _steering: Steering) {}
}

/// What a motion model's route follower steers on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Steering {
    /// The true planar state (the oracle; the default).
    Truth,
    /// An estimate: the latest the robot has, or `None` before the first (the robot then
    /// waits where it is). The follower predicts it forward to each controller tick
    /// ([`SteeringFix::at`]).
    Estimate(Option<SteeringFix>),
    /// The safety layer stopped the robot: zero command from now on.
    Stop,
}

/// A planar pose estimate with its rates, as the follower steers on it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SteeringFix {
    /// Stamp of the estimate.
    pub stamp: Nanos,
    /// Position, heading and horizontal velocity (world).
    pub state: crate::control::PlanarState,
    /// Yaw rate, rad/s.
    pub yaw_rate_radps: f64,
}

impl SteeringFix {
    /// The estimate predicted to `t` with constant velocity and yaw rate (what a robot's
    /// controller does with a pose that is `t − stamp` old).
    pub fn at(&self, t: Nanos) -> crate::control::PlanarState {
        let dt = (t - self.stamp).as_secs_f64();
        let s = &self.state;
        crate::control::PlanarState {
            xy: s.xy + s.velocity * dt,
            yaw_rad: s.yaw_rad + self.yaw_rate_radps * dt,
            velocity: s.velocity,
        }
    }
}
