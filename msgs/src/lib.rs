//! Message, time, frame and geodesy types shared by the vinebench simulator and algorithms.
//!
//! This crate is the **ground-truth firewall**'s gate: the estimator, SLAM and mapper
//! see the world only through the types defined here (sensor messages, static
//! transforms, trajectories), exactly as they would on a recording from a real robot.
//! It depends on nothing of the simulator.
//!
//! Conventions (used everywhere in vinebench):
//! - time is [`Nanos`], integer nanoseconds since the Unix epoch;
//! - `world` is a local East-North-Up frame anchored at a geodetic origin
//!   ([`geodesy::LocalEnu`]); latitude/longitude exist only at the GNSS boundary;
//! - `body` (`base_link`) is x forward, y left, z up (REP-103);
//! - poses are named `a_from_b`: `p_in_a = a_from_b * p_in_b`.
//!
//! ```
//! use vinebench_msgs::{geodesy::{Geodetic, LocalEnu}, Nanos};
//! let origin = Geodetic { lat_deg: 40.4545, lon_deg: 17.9085, alt_m: 50.0 };
//! let enu = LocalEnu::new(origin);
//! let p_in_world = enu.enu_from_geodetic(&enu.geodetic_from_enu(&[10.0, 20.0, 1.0].into()));
//! assert!((p_in_world - nalgebra::Vector3::new(10.0, 20.0, 1.0)).norm() < 1e-6);
//! assert_eq!(Nanos::from_secs_f64(1.5), Nanos(1_500_000_000));
//! ```

pub mod defaults;
pub mod frames;
pub mod geodesy;
pub mod msg;
pub mod time;
pub mod trajectory;

pub use frames::{FrameId, StaticTransforms};
pub use msg::{
    CameraInfoMsg, Dop, FixStatus, GnssFixMsg, GnssHeadingMsg, GnssSatellite, GnssSkyMsg,
    GnssSystem, GnssVelocityMsg, ImageEncoding, ImageMsg, ImuMsg, Message, OdometryMsg,
    TimedMessage,
};
pub use time::Nanos;
pub use trajectory::{PoseSample, Trajectory};
