//! Timed pose sequences: estimates and ground truth alike.

use crate::Nanos;
use nalgebra::{Isometry3, Matrix6, Translation3, Vector3};

/// One pose of a trajectory.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseSample {
    /// Time of the pose.
    pub stamp: Nanos,
    /// `world_from_body`: maps body-frame points into the ENU world frame.
    pub world_from_body: Isometry3<f64>,
    /// Covariance of the pose error, when the source provides one: position error in the
    /// world frame (m) then orientation error as a small rotation about the world axes
    /// (rad), i.e. `world_from_body_true ≈ (Exp(δθ)·R, p + δp)`. Boxed: a sample without
    /// one (the 200 Hz ground truth) is 72 bytes instead of 360, which is most of a long
    /// run's memory.
    pub covariance: Option<Box<Matrix6<f64>>>,
}

/// A time-ordered sequence of poses of the body frame in the world frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trajectory {
    /// The poses, sorted by strictly increasing stamp.
    pub samples: Vec<PoseSample>,
}

impl Trajectory {
    /// An empty trajectory.
    pub fn new() -> Trajectory {
        Trajectory::default()
    }
    /// Appends a pose; poses whose stamp is not after the last one are ignored
    /// (returns `false`), so the trajectory stays strictly increasing.
    pub fn push(&mut self, sample: PoseSample) -> bool {
        if self.samples.last().is_some_and(|l| sample.stamp <= l.stamp) {
            return false;
        }
        self.samples.push(sample);
        true
    }
    /// Moves out every pose but the latest, which stays so that [`Trajectory::push`]
    /// keeps refusing stamps that do not increase: how a consumer streams a growing
    /// trajectory to disk without holding it.
    pub fn drain_settled(&mut self) -> std::vec::Drain<'_, PoseSample> {
        let keep = self.samples.len().saturating_sub(1);
        self.samples.drain(..keep)
    }
    /// Number of poses.
    pub fn len(&self) -> usize {
        self.samples.len()
    }
    /// True when there is no pose.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }
    /// The stamps.
    pub fn stamps(&self) -> impl Iterator<Item = Nanos> + '_ {
        self.samples.iter().map(|s| s.stamp)
    }
    /// Body-origin positions in the world frame.
    pub fn positions(&self) -> impl Iterator<Item = Vector3<f64>> + '_ {
        self.samples
            .iter()
            .map(|s| s.world_from_body.translation.vector)
    }
    /// Total path length (sum of distances between consecutive positions), metres.
    pub fn path_length_m(&self) -> f64 {
        self.samples
            .windows(2)
            .map(|w| {
                (w[1].world_from_body.translation.vector - w[0].world_from_body.translation.vector)
                    .norm()
            })
            .sum()
    }
    /// The pose at `t`, interpolated between the two neighbouring samples (linear in
    /// position, spherical-linear in rotation). `None` outside the trajectory's span.
    pub fn interpolate(&self, t: Nanos) -> Option<Isometry3<f64>> {
        let s = &self.samples;
        let i = s.partition_point(|p| p.stamp <= t);
        if i == 0 {
            return None;
        }
        let a = &s[i - 1];
        if a.stamp == t {
            return Some(a.world_from_body);
        }
        let b = s.get(i)?;
        let f = (t - a.stamp).as_secs_f64() / (b.stamp - a.stamp).as_secs_f64();
        let pa = a.world_from_body.translation.vector;
        let pb = b.world_from_body.translation.vector;
        let r = a
            .world_from_body
            .rotation
            .try_slerp(&b.world_from_body.rotation, f, 1e-12)
            .unwrap_or(a.world_from_body.rotation);
        Some(Isometry3::from_parts(
            Translation3::from(pa + (pb - pa) * f),
            r,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    #[test]
    fn draining_keeps_the_latest_pose_and_the_order_check() {
        let mut t = Trajectory::new();
        assert_eq!(t.drain_settled().count(), 0);
        for k in 1..=3 {
            assert!(t.push(pose(k, 0.0, 0.0)));
        }
        let out: Vec<i64> = t.drain_settled().map(|s| s.stamp.0).collect();
        assert_eq!(out, vec![1, 2]);
        assert_eq!(t.stamps().map(|s| s.0).collect::<Vec<_>>(), vec![3]);
        assert!(!t.push(pose(3, 0.0, 0.0)) && !t.push(pose(2, 0.0, 0.0)));
        assert!(t.push(pose(4, 0.0, 0.0)));
        assert_eq!(t.drain_settled().count(), 1);
        assert_eq!(t.drain_settled().count(), 0);
    }

    fn pose(t: i64, x: f64, yaw: f64) -> PoseSample {
        PoseSample {
            stamp: Nanos(t),
            world_from_body: Isometry3::from_parts(
                Translation3::new(x, 0.0, 0.0),
                UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
            ),
            covariance: None,
        }
    }

    #[test]
    fn interpolation_is_linear_and_slerped() {
        let mut t = Trajectory::new();
        assert!(t.push(pose(0, 0.0, 0.0)));
        assert!(t.push(pose(10, 2.0, 1.0)));
        assert!(!t.push(pose(10, 5.0, 0.0)), "equal stamp must be refused");
        let mid = t.interpolate(Nanos(5)).unwrap();
        assert!((mid.translation.x - 1.0).abs() < 1e-12);
        assert!((mid.rotation.euler_angles().2 - 0.5).abs() < 1e-12);
        assert_eq!(t.interpolate(Nanos(-1)), None);
        assert_eq!(t.interpolate(Nanos(11)), None);
        assert_eq!(t.interpolate(Nanos(10)).unwrap().translation.x, 2.0);
        assert!((t.path_length_m() - 2.0).abs() < 1e-12);
    }
}
