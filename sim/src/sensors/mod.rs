//! Sensor models: each a pure function of ground truth and its own seeded random stream.
//!
//! A sensor samples at its own epochs ([`SensorModel::next_time`]); the runner advances
//! the motion model to that epoch and hands the truth to [`SensorModel::sample`], which
//! emits messages stamped with the epoch and delivered `latency` later.

pub mod gnss;
pub mod imu;
pub mod tracking_camera;
pub mod wheel_odom;

use crate::params::{FaultsParams, ParamError, SensorsParams};
use crate::robot::RobotGeometry;
use crate::truth::TruthSample;
use vinebench_msgs::geodesy::LocalEnu;
use vinebench_msgs::{Nanos, StaticTransforms, TimedMessage};

/// A simulated sensor.
pub trait SensorModel {
    /// Short name (`imu`, `gnss`, ...), also the name of its random stream `sensors.<name>`.
    fn name(&self) -> &'static str;
    /// The epoch of the next sample.
    fn next_time(&self) -> Nanos;
    /// Produces the sample(s) for epoch [`SensorModel::next_time`] from the truth at that
    /// epoch (`truth.stamp == self.next_time()`), appends them to `out`, and schedules
    /// the next epoch.
    fn sample(&mut self, truth: &TruthSample, out: &mut Vec<TimedMessage>);
}

/// What every sensor needs to know about the run.
#[derive(Clone, Debug)]
pub struct SensorContext {
    /// The scenario's master seed.
    pub master_seed: u64,
    /// Time of the first sample.
    pub start: Nanos,
    /// The world frame's geodetic origin.
    pub enu: LocalEnu,
    /// Magnitude of gravity in the world (WGS84 normal gravity at the origin), m/s².
    pub gravity_mps2: f64,
    /// The robot's sensor frames, from its URDF.
    pub static_transforms: StaticTransforms,
    /// The robot's drive geometry, from its URDF.
    pub geometry: RobotGeometry,
}

/// Builds every enabled sensor of `[sensors]`, with `[faults]` applied.
pub fn build_sensors(
    _params: &SensorsParams,
    _faults: &FaultsParams,
    _ctx: &SensorContext,
) -> Result<Vec<Box<dyn SensorModel>>, ParamError> {
    todo!("sensor construction")
}
