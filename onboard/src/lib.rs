//! vinebench-onboard: the code that runs *on the robot*, behind the ground-truth firewall.
//!
//! Everything here takes only the message stream of [`vinebench_msgs`] (sensor messages,
//! static transforms, time) and computes estimates from it, exactly as it would on a real
//! robot's recording. The firewall is this crate's dependency list: `Cargo.toml` names the
//! message crate and pure computation crates only, so no code here can reach the
//! simulator's truth (`vinebench-sim`) or the bench around it (runner, scoring); the
//! workspace test `tests/firewall.rs` checks that list and says why.
//!
//! - [`estimator`]: the EIF of the seed paper (IMU prediction; RTK-GNSS, IMU orientation,
//!   tracking-camera and wheel-odometry corrections) and the single-source trajectories.
//! - [`slam`]: multi-camera stereo visual SLAM (grid ORB, SSC, motion-only and local BA,
//!   AprilTag and bag-of-words loop closure, global BA) and its single-camera baseline.
//! - [`mapper`]: the geo-referenced RGB-D map (1 cm voxels, GRVI, elevation, Poisson-disk
//!   sampling, normals, Ball-Pivoting mesh) and its PLY/OBJ/SDF exports.
//!
//! ```
//! // The EIF's defaults are the `[estimators.eif]` table of scenarios/defaults.toml.
//! let p = vinebench_onboard::estimator::params::EifParams::default();
//! assert!(p.output_rate_hz > 0.0);
//! ```

pub mod estimator;
pub mod mapper;
pub mod slam;
