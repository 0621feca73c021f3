//! Robot descriptions from URDF: sensor frames and drive geometry.
//!
//! Every extrinsic vinebench uses comes from the robot's URDF (`robot-models/`): the
//! sensors are links on fixed joints, and [`RobotModel::static_transforms`] resolves each
//! link to `body_from_<link>` (what `/tf_static` gives an algorithm on a real robot).

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use thiserror::Error;
use vinebench_msgs::StaticTransforms;
use vinebench_msgs::frames::names::BASE_LINK;

/// Robot models compiled into the binary, by name: `(name, file name, URDF text)`.
pub const BUILTIN_MODELS: &[(&str, &str, &str)] = &[(
    "tracked-sensorbox",
    "robot-models/tracked-sensorbox.urdf",
    include_str!("../../robot-models/tracked-sensorbox.urdf"),
)];

/// The ground-contact link below `base_link` (REP-120).
pub const FOOTPRINT_LINK: &str = "base_footprint";
/// The left track link of a tracked robot.
pub const LEFT_TRACK_LINK: &str = "left_track";
/// The right track link of a tracked robot.
pub const RIGHT_TRACK_LINK: &str = "right_track";

/// A robot description that cannot be used. Every variant names the file.
#[derive(Debug, Error)]
pub enum RobotError {
    /// The file could not be read.
    #[error("{file}: cannot read the URDF: {source}")]
    Io {
        /// The file.
        file: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The XML is not a URDF urdf-rs can read.
    #[error("{file}: not a valid URDF: {message}")]
    Parse {
        /// The file.
        file: String,
        /// The parser's message.
        message: String,
    },
    /// A URDF element is missing or wrong.
    #[error("{file}: {element}: {problem}")]
    Invalid {
        /// The file.
        file: String,
        /// The element, e.g. `<joint name="imu_joint">`.
        element: String,
        /// What was expected.
        problem: String,
    },
    /// No built-in model has this name.
    #[error("unknown robot model `{name}`; built-in models: {known}")]
    UnknownModel {
        /// The requested name.
        name: String,
        /// The built-in names.
        known: String,
    },
}

/// Drive geometry of a tracked (skid-steer) robot, derived from its URDF.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotGeometry {
    /// Distance between the track centre lines, m.
    pub track_width_m: f64,
    /// Height of `base_link` above the ground contact (`base_footprint`), m.
    pub ride_height_m: f64,
    /// Overall length of the ground footprint, m.
    pub footprint_length_m: f64,
    /// Overall width of the ground footprint, m.
    pub footprint_width_m: f64,
}

/// A parsed, validated robot.
#[derive(Clone, Debug)]
pub struct RobotModel {
    /// The robot's name (`<robot name>`).
    pub name: String,
    /// Where it was read from (a path or `robot-models/<name>.urdf` for built-ins).
    pub source: String,
    /// `body_from_<link>` for every link.
    pub static_transforms: StaticTransforms,
    /// Drive geometry.
    pub geometry: RobotGeometry,
}

impl RobotModel {
    /// A built-in model by name.
    pub fn builtin(name: &str) -> Result<RobotModel, RobotError> {
        let (_, file, text) = BUILTIN_MODELS
            .iter()
            .find(|(n, _, _)| *n == name)
            .ok_or_else(|| RobotError::UnknownModel {
                name: name.to_string(),
                known: BUILTIN_MODELS
                    .iter()
                    .map(|m| m.0)
                    .collect::<Vec<_>>()
                    .join(", "),
            })?;
        RobotModel::from_urdf_str(text, file)
    }

    /// Reads a URDF file.
    pub fn from_urdf_file(path: &Path) -> Result<RobotModel, RobotError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| RobotError::Io {
            file: file.clone(),
            source,
        })?;
        RobotModel::from_urdf_str(&text, &file)
    }

    /// Parses URDF text; `source` names it in errors.
    pub fn from_urdf_str(text: &str, source: &str) -> Result<RobotModel, RobotError> {
        let robot = urdf_rs::read_from_string(text).map_err(|e| RobotError::Parse {
            file: source.to_string(),
            message: e.to_string(),
        })?;
        let invalid = |element: String, problem: String| RobotError::Invalid {
            file: source.to_string(),
            element,
            problem,
        };

        let links: BTreeSet<&str> = robot.links.iter().map(|l| l.name.as_str()).collect();
        if links.len() != robot.links.len() {
            return Err(invalid("<link>".into(), "two links share a name".into()));
        }
        // parent_of[child] = (parent, parent_from_child, joint name)
        let mut parent_of: BTreeMap<&str, (&str, Isometry3<f64>, &str)> = BTreeMap::new();
        for j in &robot.joints {
            let el = format!("<joint name=\"{}\">", j.name);
            for (what, v) in [("xyz", &j.origin.xyz), ("rpy", &j.origin.rpy)] {
                if !v.iter().all(|c| c.is_finite()) {
                    return Err(invalid(
                        el,
                        format!(
                            "<origin {what}> must be three finite numbers, found {:?}",
                            v.0
                        ),
                    ));
                }
            }
            for (role, link) in [("parent", &j.parent.link), ("child", &j.child.link)] {
                if !links.contains(link.as_str()) {
                    return Err(invalid(el, format!("{role} link `{link}` is not defined")));
                }
            }
            let pose = Isometry3::from_parts(
                Translation3::new(j.origin.xyz[0], j.origin.xyz[1], j.origin.xyz[2]),
                UnitQuaternion::from_euler_angles(
                    j.origin.rpy[0],
                    j.origin.rpy[1],
                    j.origin.rpy[2],
                ),
            );
            if parent_of
                .insert(
                    j.child.link.as_str(),
                    (j.parent.link.as_str(), pose, j.name.as_str()),
                )
                .is_some()
            {
                return Err(invalid(
                    el,
                    format!("link `{}` has two parent joints", j.child.link),
                ));
            }
        }
        if !links.contains(BASE_LINK) {
            return Err(invalid(
                format!("<link name=\"{BASE_LINK}\">"),
                "missing: every robot needs a base_link (REP-105 body frame)".into(),
            ));
        }

        // root_from_link for every link, walking up to the root (cycles are errors).
        let root_from = |start: &str| -> Result<(String, Isometry3<f64>), RobotError> {
            let mut pose = Isometry3::identity();
            let mut link = start;
            let mut seen = BTreeSet::new();
            while let Some((parent, parent_from_child, joint)) = parent_of.get(link) {
                if !seen.insert(link) {
                    return Err(invalid(
                        format!("<joint name=\"{joint}\">"),
                        "the joints form a cycle".into(),
                    ));
                }
                pose = parent_from_child * pose;
                link = parent;
            }
            Ok((link.to_string(), pose))
        };
        let (base_root, root_from_base) = root_from(BASE_LINK)?;
        let mut tf = StaticTransforms::new(BASE_LINK);
        for l in &links {
            let (root, root_from_link) = root_from(l)?;
            if root != base_root {
                return Err(invalid(
                    format!("<link name=\"{l}\">"),
                    format!("not connected to {BASE_LINK} by joints (its tree's root is `{root}`)"),
                ));
            }
            if *l != BASE_LINK {
                tf.insert(l, root_from_base.inverse() * root_from_link);
            }
        }

        let need = |name: &str, why: &str| {
            tf.body_from(name).ok_or_else(|| {
                invalid(format!("<link name=\"{name}\">"), format!("missing: {why}"))
            })
        };
        let footprint = need(
            FOOTPRINT_LINK,
            "the ground contact below base_link (REP-120)",
        )?;
        let left = need(
            LEFT_TRACK_LINK,
            "a tracked robot needs left_track and right_track links",
        )?;
        let right = need(
            RIGHT_TRACK_LINK,
            "a tracked robot needs left_track and right_track links",
        )?;
        let track_width_m = (left.translation.vector.y - right.translation.vector.y).abs();
        if track_width_m < 0.05 {
            return Err(invalid(
                "<joint name=\"left_track_joint\">".into(),
                format!("tracks must be at least 5 cm apart in y, found {track_width_m} m"),
            ));
        }
        let ride_height_m = -footprint.translation.vector.z;
        if ride_height_m <= 0.0 {
            return Err(invalid(
                format!("<link name=\"{FOOTPRINT_LINK}\">"),
                format!(
                    "must lie below base_link (negative z), found z = {}",
                    -ride_height_m
                ),
            ));
        }
        let track_box = |name: &str| -> Option<[f64; 3]> {
            robot
                .links
                .iter()
                .find(|l| l.name == name)?
                .collision
                .iter()
                .find_map(|c| match &c.geometry {
                    urdf_rs::Geometry::Box { size } => Some(size.0),
                    _ => None,
                })
        };
        let (len, wid) = match track_box(LEFT_TRACK_LINK) {
            Some(s) if s.iter().all(|c| c.is_finite() && *c > 0.0) => (s[0], s[1]),
            _ => {
                return Err(invalid(
                    format!("<link name=\"{LEFT_TRACK_LINK}\">"),
                    "needs a <collision> <box size> with positive sizes (track length, width, height)"
                        .into(),
                ));
            }
        };
        Ok(RobotModel {
            name: robot.name.clone(),
            source: source.to_string(),
            static_transforms: tf,
            geometry: RobotGeometry {
                track_width_m,
                ride_height_m,
                footprint_length_m: len,
                footprint_width_m: track_width_m + wid,
            },
        })
    }

    /// `body_from_<frame>`, or an error naming the file and listing the known links.
    pub fn body_from(&self, frame: &str) -> Result<Isometry3<f64>, RobotError> {
        self.static_transforms
            .body_from(frame)
            .ok_or_else(|| RobotError::Invalid {
                file: self.source.clone(),
                element: format!("<link name=\"{frame}\">"),
                problem: format!(
                    "missing: the scenario mounts a sensor on it; links are: {}",
                    self.static_transforms
                        .body_from
                        .keys()
                        .map(|k| k.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn builtin_tracked_robot_resolves_sensor_frames() {
        let r = RobotModel::builtin("tracked-sensorbox").unwrap();
        assert!((r.geometry.track_width_m - 0.6).abs() < 1e-12);
        assert!((r.geometry.ride_height_m - 0.18).abs() < 1e-12);
        assert!((r.geometry.footprint_length_m - 1.1).abs() < 1e-12);
        assert!((r.geometry.footprint_width_m - 0.8).abs() < 1e-12);
        // imu_link = sensor_frame (0.30, 0, 0.18) + sensor_box (0, 0, 0.62) + (-0.04, 0.02, -0.03)
        let imu = r.body_from("imu_link").unwrap();
        assert!((imu.translation.vector - Vector3::new(0.26, 0.02, 0.77)).norm() < 1e-12);
        // The optical frame looks forward (z) with x to the right (-y of the body).
        let opt = r.body_from("camera_center_color_optical_frame").unwrap();
        assert!((opt.rotation * Vector3::z() - Vector3::x()).norm() < 1e-12);
        assert!((opt.rotation * Vector3::x() + Vector3::y()).norm() < 1e-12);
        // The side cameras are yawed by ±30.5°.
        let left = r.body_from("camera_left_link").unwrap();
        assert!(
            ((left.rotation * Vector3::x())
                .y
                .atan2((left.rotation * Vector3::x()).x)
                .to_degrees()
                - 30.5)
                .abs()
                < 1e-9
        );
    }

    fn with(replace: &str, by: &str) -> String {
        let text = BUILTIN_MODELS[0].2;
        assert!(text.contains(replace), "fixture text not found: {replace}");
        text.replacen(replace, by, 1)
    }

    #[test]
    fn malformed_urdfs_name_file_element_and_expectation() {
        let err = RobotModel::from_urdf_str(
            &with(
                r#"<origin xyz="-0.04 0.02 -0.03""#,
                r#"<origin xyz="nan 0.02 -0.03""#,
            ),
            "bad.urdf",
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("bad.urdf") && err.contains("imu_joint") && err.contains("finite"),
            "{err}"
        );

        let err = RobotModel::from_urdf_str(
            &with(
                r#"<parent link="sensor_box"/>
    <child link="imu_link"/>"#,
                r#"<parent link="sensor_boxx"/>
    <child link="imu_link"/>"#,
            ),
            "bad.urdf",
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("sensor_boxx") && err.contains("not defined"),
            "{err}"
        );

        let err = RobotModel::from_urdf_str(
            &with(r#"<link name="left_track">"#, r#"<link name="left_trak">"#),
            "bad.urdf",
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("bad.urdf"), "{err}");

        let err = RobotModel::from_urdf_str("<robot name='x'><link name=", "trunc.urdf")
            .unwrap_err()
            .to_string();
        assert!(err.starts_with("trunc.urdf: not a valid URDF"), "{err}");

        let r = RobotModel::builtin("tracked-sensorbox").unwrap();
        let err = r.body_from("lidar_link").unwrap_err().to_string();
        assert!(
            err.contains("lidar_link") && err.contains("imu_link"),
            "{err}"
        );
        assert!(
            RobotModel::builtin("tank")
                .unwrap_err()
                .to_string()
                .contains("tracked-sensorbox")
        );
    }
}
