//! Ground truth: the true kinematic state of the robot body.

use crate::robot::MAX_DRIVE_JOINTS;
use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use vinebench_msgs::Nanos;

/// The true state of the body frame (`base_link`) at one instant.
///
/// Every field is the exact value at `stamp` (not an average over a step): motion models
/// keep position, velocity, acceleration and angular rate continuous in time so that an
/// IMU derived from them is physically consistent (strapdown integration of noise-free
/// IMU samples reproduces the trajectory).
#[derive(Clone, Debug, PartialEq)]
pub struct TruthSample {
    /// Time of the state.
    pub stamp: Nanos,
    /// `world_from_body`.
    pub world_from_body: Isometry3<f64>,
    /// Velocity of the body origin, world frame, m/s.
    pub velocity_in_world: Vector3<f64>,
    /// Acceleration of the body origin, world frame, m/s² (kinematic; gravity not included).
    pub acceleration_in_world: Vector3<f64>,
    /// Angular velocity of the body relative to the world, in the body frame, rad/s.
    pub angular_velocity_in_body: Vector3<f64>,
    /// Time derivative of `angular_velocity_in_body`, rad/s².
    pub angular_acceleration_in_body: Vector3<f64>,
    /// Drive joint speeds as the motors turn them (what the encoders see), rad/s, in
    /// [`crate::robot::Drive::joints`] order (tracked: left, right sprocket; mecanum:
    /// front-left, front-right, rear-left, rear-right wheel); unused entries 0.
    pub drive_speeds_radps: [f64; MAX_DRIVE_JOINTS],
    /// Distance travelled by the body origin since the start, m.
    pub odometer_m: f64,
}

/// Kinematics of a frame rigidly mounted on the body (a sensor).
#[derive(Clone, Debug, PartialEq)]
pub struct MountKinematics {
    /// `world_from_sensor`.
    pub world_from_sensor: Isometry3<f64>,
    /// Velocity of the sensor origin, world frame, m/s.
    pub velocity_in_world: Vector3<f64>,
    /// Acceleration of the sensor origin, world frame, m/s² (gravity not included).
    pub acceleration_in_world: Vector3<f64>,
    /// Angular velocity of the sensor relative to the world, in the sensor frame, rad/s.
    pub angular_velocity_in_sensor: Vector3<f64>,
}

impl TruthSample {
    /// Rigid-body kinematics of a frame mounted at `body_from_sensor`:
    /// `v_s = v + ω × r`, `a_s = a + α × r + ω × (ω × r)` with `r` the lever arm in world.
    pub fn at_mount(&self, body_from_sensor: &Isometry3<f64>) -> MountKinematics {
        let r_wb: &UnitQuaternion<f64> = &self.world_from_body.rotation;
        let lever_in_world = r_wb * body_from_sensor.translation.vector;
        let omega_w = r_wb * self.angular_velocity_in_body;
        let alpha_w = r_wb * self.angular_acceleration_in_body;
        MountKinematics {
            world_from_sensor: self.world_from_body * body_from_sensor,
            velocity_in_world: self.velocity_in_world + omega_w.cross(&lever_in_world),
            acceleration_in_world: self.acceleration_in_world
                + alpha_w.cross(&lever_in_world)
                + omega_w.cross(&omega_w.cross(&lever_in_world)),
            angular_velocity_in_sensor: body_from_sensor.rotation.inverse()
                * self.angular_velocity_in_body,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Translation3;

    #[test]
    fn mount_on_spinning_body_has_centripetal_acceleration() {
        // Body spinning at ω about z at the origin; a sensor 0.5 m ahead moves at ω·r
        // sideways and accelerates at ω²·r towards the axis.
        let w = 2.0;
        let truth = TruthSample {
            stamp: Nanos(0),
            world_from_body: Isometry3::identity(),
            velocity_in_world: Vector3::zeros(),
            acceleration_in_world: Vector3::zeros(),
            angular_velocity_in_body: Vector3::new(0.0, 0.0, w),
            angular_acceleration_in_body: Vector3::zeros(),
            drive_speeds_radps: [0.0; MAX_DRIVE_JOINTS],
            odometer_m: 0.0,
        };
        let body_from_sensor = Isometry3::from_parts(
            Translation3::new(0.5, 0.0, 0.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2),
        );
        let k = truth.at_mount(&body_from_sensor);
        assert!((k.velocity_in_world - Vector3::new(0.0, 1.0, 0.0)).norm() < 1e-12);
        assert!((k.acceleration_in_world - Vector3::new(-2.0, 0.0, 0.0)).norm() < 1e-12);
        assert!((k.angular_velocity_in_sensor - Vector3::new(0.0, 0.0, w)).norm() < 1e-12);
    }
}
