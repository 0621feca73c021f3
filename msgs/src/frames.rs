//! Frame names and the static transforms of a robot (what `/tf_static` carries).

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt;
use std::sync::Arc;

/// The name of a coordinate frame (`base_link`, `imu_link`, ...). Cheap to clone.
#[derive(Clone, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct FrameId(Arc<str>);

impl FrameId {
    /// A frame id from a name.
    pub fn new(name: &str) -> FrameId {
        FrameId(Arc::from(name))
    }
    /// The name.
    pub fn as_str(&self) -> &str {
        &self.0
    }
}
impl fmt::Debug for FrameId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:?}", &*self.0)
    }
}
impl fmt::Display for FrameId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}
impl std::borrow::Borrow<str> for FrameId {
    fn borrow(&self) -> &str {
        &self.0
    }
}
impl From<&str> for FrameId {
    fn from(s: &str) -> FrameId {
        FrameId::new(s)
    }
}

/// Well-known frame names.
pub mod names {
    /// The robot body frame (REP-103: x forward, y left, z up).
    pub const BASE_LINK: &str = "base_link";
    /// The local ENU world frame.
    pub const WORLD: &str = "world";
}

/// Every sensor frame of a robot expressed in its body frame: `body_from_<frame>`.
///
/// This is what an algorithm learns from `/tf_static` on a real robot; in vinebench the
/// simulator builds it from the robot's URDF. Algorithms take extrinsics from here and
/// nowhere else.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StaticTransforms {
    /// The body frame every entry is relative to (normally `base_link`).
    pub body_frame: Option<FrameId>,
    /// `body_from_frame` for each named frame.
    pub body_from: BTreeMap<FrameId, Isometry3<f64>>,
}

impl StaticTransforms {
    /// Empty set with the given body frame name.
    pub fn new(body_frame: &str) -> StaticTransforms {
        StaticTransforms {
            body_frame: Some(FrameId::new(body_frame)),
            body_from: BTreeMap::new(),
        }
    }
    /// Adds or replaces `body_from_<frame>`.
    pub fn insert(&mut self, frame: &str, body_from_frame: Isometry3<f64>) {
        self.body_from.insert(FrameId::new(frame), body_from_frame);
    }
    /// `body_from_<frame>`: the identity for the body frame itself, `None` when unknown.
    pub fn body_from(&self, frame: &str) -> Option<Isometry3<f64>> {
        if self
            .body_frame
            .as_ref()
            .is_some_and(|b| b.as_str() == frame)
        {
            return Some(Isometry3::identity());
        }
        self.body_from.get(frame).copied()
    }
    /// `a_from_b` between two known frames.
    pub fn between(&self, a: &str, b: &str) -> Option<Isometry3<f64>> {
        Some(self.body_from(a)?.inverse() * self.body_from(b)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    #[test]
    fn between_composes_through_body() {
        let mut tf = StaticTransforms::new("base_link");
        let body_from_a = Isometry3::from_parts(
            Translation3::new(0.1, 0.2, 0.3),
            UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3),
        );
        let body_from_b = Isometry3::from_parts(
            Translation3::new(-0.5, 0.0, 1.0),
            UnitQuaternion::from_euler_angles(0.0, 0.4, -1.0),
        );
        tf.insert("a", body_from_a);
        tf.insert("b", body_from_b);
        let a_from_b = tf.between("a", "b").unwrap();
        let p_in_b = Vector3::new(1.0, 2.0, 3.0);
        let via_body = body_from_a.inverse() * (body_from_b * nalgebra::Point3::from(p_in_b));
        assert!((a_from_b * nalgebra::Point3::from(p_in_b) - via_body).norm() < 1e-12);
        assert_eq!(tf.body_from("base_link"), Some(Isometry3::identity()));
        assert_eq!(tf.body_from("nope"), None);
    }
}
