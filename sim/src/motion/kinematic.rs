//! Terrain-following kinematic skid-steer driven by pure pursuit. (Implementation pending.)

use super::MotionModel;
use crate::params::{MotionParams, ParamError};
use crate::robot::RobotGeometry;
use crate::route::Route;
use crate::truth::TruthSample;
use crate::world::Surface;
use vinebench_msgs::Nanos;

/// A tracked robot that follows its route with pure pursuit, with ground contact from a
/// [`Surface`].
pub struct KinematicSkidSteer<S: Surface> {
    _surface: S,
}

impl<S: Surface> KinematicSkidSteer<S> {
    /// A robot at the start of `route`, at rest, from time `start`.
    pub fn new(
        _params: &MotionParams,
        _route: Route,
        _surface: S,
        _geometry: &RobotGeometry,
        _start: Nanos,
    ) -> Result<Self, ParamError> {
        todo!("kinematic model")
    }
}

impl<S: Surface> MotionModel for KinematicSkidSteer<S> {
    fn advance_to(&mut self, _t: Nanos) -> TruthSample {
        todo!()
    }
    fn start_time(&self) -> Nanos {
        todo!()
    }
    fn finished(&self) -> bool {
        todo!()
    }
    fn expected_duration(&self) -> Nanos {
        todo!()
    }
}
