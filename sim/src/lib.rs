//! The vinebench simulator: everything that knows the truth.
//!
//! Data flows world → motion → sensors:
//! - [`world`]: a procedural vineyard from a seed ([`world::World::generate`]): row layout,
//!   posts, plants and a C²-smooth terrain surface.
//! - [`robot`]: the robot's URDF: sensor frames ([`vinebench_msgs::StaticTransforms`]),
//!   track geometry.
//! - [`route`] and [`motion`]: the path to follow and a [`motion::MotionModel`] that drives
//!   the robot along it, producing [`truth::TruthSample`]s.
//! - [`sensors`]: each sensor is a pure function of truth and its own seeded random
//!   stream ([`rng::stream`]), emitting [`vinebench_msgs::TimedMessage`]s.
//!
//! Nothing in the algorithms (`vinebench::estimator`, ...) may use this crate: they see
//! only the messages.

pub mod control;
pub mod motion;
pub mod params;
pub mod physics;
pub mod render;
pub mod rng;
pub mod robot;
pub mod route;
pub mod sensors;
pub mod truth;
pub mod world;
