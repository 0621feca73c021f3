//! Robot descriptions from URDF: sensor frames, mass properties, collision shapes and the
//! drive (tracks or mecanum wheels) with its motors and ground contact.
//!
//! Every extrinsic vinebench uses comes from the robot's URDF (`robot-models/`): the
//! sensors are links on fixed joints, and [`RobotModel::static_transforms`] resolves each
//! link to `body_from_<link>` (what `/tf_static` gives an algorithm on a real robot).
//!
//! The drive is declared the way Gazebo reads it, so the same file works there:
//! - a `gz::sim::systems::TrackedVehicle` plugin block names the two track links; each
//!   track link carries one `continuous` sprocket joint, whose `<limit effort velocity
//!   acceleration>` is its motor at the joint (URDF 1.2);
//! - a `gz::sim::systems::MecanumDrive` plugin block names the four `continuous` wheel
//!   joints; each wheel link's collision cylinder gives the rolling radius;
//! - a `<gazebo reference="<track or wheel link>">` block gives the ground contact:
//!   friction `mu1` along `fdir1` (for a mecanum wheel the axis of the rollers touching
//!   the ground, in the wheel link's frame), `mu2` across it, and the contact stiffness
//!   `kp` (N/m) and damping `kd` (N·s/m) of the whole track or wheel;
//! - a `<transmission>` per drive joint (ros_control style) gives the gear reduction
//!   `<mechanicalReduction>` and, as Drake reads it, the motor's `<drake:rotor_inertia
//!   value>`: the drive train's inertia about the axle is the link's plus `J_rotor·N²`.
//!
//!
//! # Limits
//! A URDF is read whole and checked before anything is built from it: at most
//! [`MAX_URDF_BYTES`], [`MAX_URDF_NODES`] XML nodes nested at most [`MAX_URDF_DEPTH`]
//! deep, [`MAX_URDF_LINKS`] links and [`MAX_URDF_JOINTS`] joints; loading costs time
//! linear in its size. Mass properties must be physical: every link at most
//! [`MAX_LINK_MASS_KG`], the robot at most [`MAX_ROBOT_MASS_KG`], and each link's
//! principal moments of inertia at most its mass times [`MAX_GYRATION_RADIUS_M`]²; every
//! link, centre of mass and collision shape lies within [`MAX_ROBOT_EXTENT_M`] of
//! `base_link`.
//! Errors name the file, the element (`<link name="...">`) and, where the XML says it, the
//! line and column.
//!
//! ```
//! use vinebench_sim::robot::{Drive, RobotModel};
//! let rover = RobotModel::builtin("mecanum-rover").expect("built-in");
//! let Drive::Mecanum(m) = &rover.drive else { panic!("a mecanum drive") };
//! assert!((m.wheels[0].joint.radius_m - 0.0508).abs() < 1e-12);
//! assert!((rover.inertia.mass_kg - 24.082).abs() < 1e-9);
//! ```

mod urdf;
mod xml;

use nalgebra::{Isometry3, Matrix3, Vector3};
use thiserror::Error;
use vinebench_msgs::StaticTransforms;

/// Robot models compiled into the binary, by name: `(name, file name, URDF text)`.
pub const BUILTIN_MODELS: &[(&str, &str, &str)] = &[
    (
        "tracked-sensorbox",
        "robot-models/tracked-sensorbox.urdf",
        include_str!("../../../robot-models/tracked-sensorbox.urdf"),
    ),
    (
        "mecanum-rover",
        "robot-models/mecanum-rover.urdf",
        include_str!("../../../robot-models/mecanum-rover.urdf"),
    ),
];

/// The ground-contact link below `base_link` (REP-120).
pub const FOOTPRINT_LINK: &str = "base_footprint";
/// Name of the gz-sim tracked-vehicle system (`<plugin name>`).
pub const TRACKED_VEHICLE_PLUGIN: &str = "gz::sim::systems::TrackedVehicle";
/// Name of the gz-sim mecanum-drive system (`<plugin name>`).
pub const MECANUM_DRIVE_PLUGIN: &str = "gz::sim::systems::MecanumDrive";
/// Most drive joints a robot may have (four mecanum wheels).
pub const MAX_DRIVE_JOINTS: usize = 4;
/// Largest URDF file vinebench reads, bytes (32 MiB).
pub const MAX_URDF_BYTES: usize = 32 << 20;
/// Most XML nodes (elements, text, comments) of a URDF.
pub const MAX_URDF_NODES: u32 = 4_000_000;
/// Deepest element nesting of a URDF (a URDF needs about 6 levels).
pub const MAX_URDF_DEPTH: usize = 64;
/// Most `<link>` elements of a URDF.
pub const MAX_URDF_LINKS: usize = 100_000;
/// Most `<joint>` elements of a URDF.
pub const MAX_URDF_JOINTS: usize = 100_000;
/// Heaviest link (`<inertial><mass value>`), kg.
pub const MAX_LINK_MASS_KG: f64 = 20_000.0;
/// Heaviest robot (all links together), kg: a large straddle tractor.
pub const MAX_ROBOT_MASS_KG: f64 = 20_000.0;
/// Largest radius of gyration of a link, m: each principal moment of inertia must be at
/// most `mass · MAX_GYRATION_RADIUS_M²`.
pub const MAX_GYRATION_RADIUS_M: f64 = 10.0;
/// Farthest any link frame, centre of mass or collision shape may reach from
/// `base_link`, m.
pub const MAX_ROBOT_EXTENT_M: f64 = 100.0;

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
    /// A URDF element or attribute is missing or wrong, at a known place in the file.
    #[error("{file}:{line}:{column}: {element}: {problem}")]
    Located {
        /// The file.
        file: String,
        /// Line of the element or attribute (1-based).
        line: u32,
        /// Column (1-based).
        column: u32,
        /// The element, e.g. `<link name="base_link">`.
        element: String,
        /// What is wrong and what was expected.
        problem: String,
    },
    /// A URDF element is missing or wrong (where the file has no place for it, e.g. a
    /// missing element).
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

/// Overall drive geometry, for planar models and odometry.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotGeometry {
    /// Distance between the left and right ground contacts: track centre lines, or
    /// left and right wheel centres, m.
    pub track_width_m: f64,
    /// Height of `base_link` above the ground contact (`base_footprint`), m.
    pub ride_height_m: f64,
    /// Overall length of the ground footprint, m.
    pub footprint_length_m: f64,
    /// Overall width of the ground footprint, m.
    pub footprint_width_m: f64,
    /// The drive's nominal kinematics (what an odometry uses).
    pub kinematics: DriveKinematics,
}

/// Mass properties of the whole robot as one rigid body (every link's `<inertial>`).
#[derive(Clone, Debug, PartialEq)]
pub struct RigidInertia {
    /// Total mass, kg.
    pub mass_kg: f64,
    /// Centre of mass in the body frame, m.
    pub com_in_body: Vector3<f64>,
    /// Inertia tensor about the centre of mass, body axes, kg·m².
    pub inertia_about_com_in_body: Matrix3<f64>,
}

/// A primitive collision shape.
#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    /// A box with these half extents along its x, y, z axes, m.
    Box {
        /// Half extents, m.
        half_extents_m: Vector3<f64>,
    },
    /// A cylinder along its z axis (URDF convention).
    Cylinder {
        /// Radius, m.
        radius_m: f64,
        /// Half the length, m.
        half_length_m: f64,
    },
    /// A sphere.
    Sphere {
        /// Radius, m.
        radius_m: f64,
    },
}

/// One `<collision>` element, placed in the body frame (drive joints at zero angle).
#[derive(Clone, Debug, PartialEq)]
pub struct CollisionShape {
    /// The link it belongs to.
    pub link: String,
    /// `body_from_shape`.
    pub body_from_shape: Isometry3<f64>,
    /// The primitive.
    pub shape: Shape,
    /// True for tracks, sprockets and wheels: their contact with the ground is the
    /// drive's contact model, not a collision (they still collide with obstacles).
    pub running_gear: bool,
}

/// A motor-driven `continuous` joint: a track sprocket or a wheel.
#[derive(Clone, Debug, PartialEq)]
pub struct DriveJoint {
    /// The joint's name.
    pub name: String,
    /// The driven (child) link.
    pub link: String,
    /// `body_from_joint` at zero angle.
    pub body_from_joint: Isometry3<f64>,
    /// Unit rotation axis in the body frame; positive rotation drives the robot forward
    /// (the URDFs use `0 1 0`: the right-hand rule about +y rolls a wheel towards +x).
    pub axis_in_body: Vector3<f64>,
    /// Rolling radius: the wheel's radius or the sprocket's pitch radius, m (the child
    /// link's collision cylinder).
    pub radius_m: f64,
    /// Drive-train inertia about the axle: the child link's inertia about the joint axis
    /// plus the motor rotor's reflected through the gear (`J_rotor·N²`, from the joint's
    /// `<transmission>`), kg·m².
    pub inertia_kgm2: f64,
    /// The part of [`DriveJoint::inertia_kgm2`] that is the motor's rotor reflected through
    /// the gear (`J_rotor·N²`; MuJoCo's joint `armature`), kg·m².
    pub reflected_inertia_kgm2: f64,
    /// Mass of the child link (`<inertial><mass>`), kg.
    pub link_mass_kg: f64,
    /// Motor torque limit at the joint (`<limit effort>`), N·m.
    pub max_torque_nm: f64,
    /// Speed limit (`<limit velocity>`), rad/s.
    pub max_speed_radps: f64,
    /// Acceleration limit of the speed reference (`<limit acceleration>`, URDF 1.2;
    /// infinite when absent), rad/s².
    pub max_accel_radps2: f64,
    /// Viscous friction (`<dynamics damping>`), N·m·s/rad.
    pub damping_nms: f64,
    /// Coulomb friction (`<dynamics friction>`), N·m.
    pub friction_nm: f64,
}

/// How a track or wheel meets the ground (its `<gazebo reference>` block).
#[derive(Clone, Debug, PartialEq)]
pub struct GroundContact {
    /// Friction coefficient along `fdir1` (`<mu1>`).
    pub mu1: f64,
    /// Friction coefficient across `fdir1` (`<mu2>`; 0 for free mecanum rollers).
    pub mu2: f64,
    /// The first friction direction in the body frame, unit (`<fdir1>` rotated from the
    /// link frame at zero joint angle).
    pub fdir1_in_body: Vector3<f64>,
    /// Contact stiffness of the whole track or wheel (`<kp>`), N/m.
    pub stiffness_n_per_m: f64,
    /// Contact damping of the whole track or wheel (`<kd>`), N·s/m.
    pub damping_ns_per_m: f64,
}

/// One track of a tracked robot.
#[derive(Clone, Debug, PartialEq)]
pub struct Track {
    /// The track link.
    pub link: String,
    /// `body_from_track`: the centre of the track's collision box.
    pub body_from_track: Isometry3<f64>,
    /// Overall length of the track (collision box x size), m.
    pub length_m: f64,
    /// Belt width (box y size), m.
    pub width_m: f64,
    /// Height from the belt's ground run to its top run (box z size), m; the ends are
    /// rounded with half this radius (sprocket and idler), so the ground run is
    /// `length - height` long.
    pub height_m: f64,
    /// The sprocket that drives it.
    pub sprocket: DriveJoint,
    /// Track-ground contact.
    pub contact: GroundContact,
}

/// Two tracks (skid steering).
#[derive(Clone, Debug, PartialEq)]
pub struct TrackedDrive {
    /// The left track (+y).
    pub left: Track,
    /// The right track (−y).
    pub right: Track,
}

/// One mecanum wheel.
#[derive(Clone, Debug, PartialEq)]
pub struct MecanumWheel {
    /// The wheel joint (its child link is the wheel).
    pub joint: DriveJoint,
    /// Wheel width (collision cylinder length), m.
    pub width_m: f64,
    /// Wheel-ground contact (`fdir1`: the ground-contact rollers' axis).
    pub contact: GroundContact,
}

/// Four mecanum wheels, in the order front-left, front-right, rear-left, rear-right.
#[derive(Clone, Debug, PartialEq)]
pub struct MecanumDrive {
    /// The wheels.
    pub wheels: [MecanumWheel; 4],
}

/// What moves the robot.
#[derive(Clone, Debug, PartialEq)]
pub enum Drive {
    /// Skid-steered tracks.
    Tracked(Box<TrackedDrive>),
    /// Four mecanum wheels (holonomic).
    Mecanum(Box<MecanumDrive>),
}

impl Drive {
    /// The drive joints in their fixed order (tracked: left, right sprocket; mecanum:
    /// front-left, front-right, rear-left, rear-right wheel). Motor commands, joint states
    /// and [`crate::truth::TruthSample::drive_speeds_radps`] use this order.
    pub fn joints(&self) -> Vec<&DriveJoint> {
        match self {
            Drive::Tracked(t) => vec![&t.left.sprocket, &t.right.sprocket],
            Drive::Mecanum(m) => m.wheels.iter().map(|w| &w.joint).collect(),
        }
    }

    /// True for a drive that can move sideways.
    pub fn is_holonomic(&self) -> bool {
        matches!(self, Drive::Mecanum(_))
    }

    /// `tracked` or `mecanum`.
    pub fn kind_name(&self) -> &'static str {
        match self {
            Drive::Tracked(_) => "tracked",
            Drive::Mecanum(_) => "mecanum",
        }
    }

    /// The nominal (slip-free) kinematics an odometry uses.
    pub fn kinematics(&self) -> DriveKinematics {
        match self {
            Drive::Tracked(t) => DriveKinematics::SkidSteer {
                track_width_m: (t.left.body_from_track.translation.vector.y
                    - t.right.body_from_track.translation.vector.y)
                    .abs(),
                left_radius_m: t.left.sprocket.radius_m,
                right_radius_m: t.right.sprocket.radius_m,
            },
            Drive::Mecanum(m) => {
                let p = |i: usize| m.wheels[i].joint.body_from_joint.translation.vector;
                let lx = (p(0).x - p(2).x + p(1).x - p(3).x).abs() / 4.0;
                let ly = (p(0).y - p(1).y + p(2).y - p(3).y).abs() / 4.0;
                DriveKinematics::Mecanum {
                    half_wheelbase_m: lx,
                    half_separation_m: ly,
                    wheel_radius_m: m.wheels.iter().map(|w| w.joint.radius_m).sum::<f64>() / 4.0,
                }
            }
        }
    }
}

/// Nominal drive kinematics: how joint speeds map to a body twist without slip.
#[derive(Clone, Debug, PartialEq)]
pub enum DriveKinematics {
    /// Differential tracks: `v = (r_l·w_l + r_r·w_r)/2`, `ω = (r_r·w_r − r_l·w_l)/W`.
    SkidSteer {
        /// Distance between the track centre lines `W`, m.
        track_width_m: f64,
        /// Left sprocket pitch radius, m.
        left_radius_m: f64,
        /// Right sprocket pitch radius, m.
        right_radius_m: f64,
    },
    /// Mecanum X configuration (wheels front-left, front-right, rear-left, rear-right):
    /// `w_fl = (vx − vy − (lx+ly)·ω)/r`, `w_fr = (vx + vy + (lx+ly)·ω)/r`,
    /// `w_rl = (vx + vy − (lx+ly)·ω)/r`, `w_rr = (vx − vy + (lx+ly)·ω)/r`.
    Mecanum {
        /// Half the distance between front and rear axles `lx`, m.
        half_wheelbase_m: f64,
        /// Half the distance between left and right wheel centres `ly`, m.
        half_separation_m: f64,
        /// Wheel radius `r`, m.
        wheel_radius_m: f64,
    },
}

impl DriveKinematics {
    /// Joint speeds (rad/s, in [`Drive::joints`] order) for a body twist: forward `vx`,
    /// left `vy` (m/s) and yaw rate `wz` (rad/s). A skid-steer ignores `vy`.
    pub fn joint_speeds(&self, vx: f64, vy: f64, wz: f64) -> [f64; MAX_DRIVE_JOINTS] {
        match *self {
            DriveKinematics::SkidSteer {
                track_width_m,
                left_radius_m,
                right_radius_m,
            } => [
                (vx - wz * track_width_m / 2.0) / left_radius_m,
                (vx + wz * track_width_m / 2.0) / right_radius_m,
                0.0,
                0.0,
            ],
            DriveKinematics::Mecanum {
                half_wheelbase_m,
                half_separation_m,
                wheel_radius_m,
            } => {
                let k = (half_wheelbase_m + half_separation_m) * wz;
                [
                    (vx - vy - k) / wheel_radius_m,
                    (vx + vy + k) / wheel_radius_m,
                    (vx + vy - k) / wheel_radius_m,
                    (vx - vy + k) / wheel_radius_m,
                ]
            }
        }
    }

    /// The body twist `(vx, vy, wz)` of joint speeds (the least-squares inverse of
    /// [`DriveKinematics::joint_speeds`]; exact for a skid-steer, which reports `vy = 0`).
    pub fn body_twist(&self, w: &[f64; MAX_DRIVE_JOINTS]) -> (f64, f64, f64) {
        match *self {
            DriveKinematics::SkidSteer {
                track_width_m,
                left_radius_m,
                right_radius_m,
            } => {
                let (l, r) = (w[0] * left_radius_m, w[1] * right_radius_m);
                ((l + r) / 2.0, 0.0, (r - l) / track_width_m)
            }
            DriveKinematics::Mecanum {
                half_wheelbase_m,
                half_separation_m,
                wheel_radius_m,
            } => {
                let r = wheel_radius_m / 4.0;
                (
                    r * (w[0] + w[1] + w[2] + w[3]),
                    r * (-w[0] + w[1] + w[2] - w[3]),
                    r * (-w[0] + w[1] - w[2] + w[3]) / (half_wheelbase_m + half_separation_m),
                )
            }
        }
    }

    /// Number of drive joints.
    pub fn joint_count(&self) -> usize {
        match self {
            DriveKinematics::SkidSteer { .. } => 2,
            DriveKinematics::Mecanum { .. } => 4,
        }
    }
}

/// A parsed, validated robot.
#[derive(Clone, Debug)]
pub struct RobotModel {
    /// The robot's name (`<robot name>`).
    pub name: String,
    /// Where it was read from (a path or `robot-models/<name>.urdf` for built-ins).
    pub source: String,
    /// `body_from_<link>` for every link attached to `base_link` by fixed joints (what
    /// `/tf_static` carries; links behind moving joints are left out).
    pub static_transforms: StaticTransforms,
    /// Overall drive geometry.
    pub geometry: RobotGeometry,
    /// The drive: tracks or mecanum wheels, motors and ground contact.
    pub drive: Drive,
    /// Mass properties of the whole robot.
    pub inertia: RigidInertia,
    /// Every `<collision>` primitive.
    pub collision_shapes: Vec<CollisionShape>,
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

    /// Reads a URDF file (at most [`MAX_URDF_BYTES`]: a longer file, or an endless one
    /// such as `/dev/zero`, is refused after reading one byte more).
    pub fn from_urdf_file(path: &std::path::Path) -> Result<RobotModel, RobotError> {
        use std::io::Read;
        let file = path.display().to_string();
        let io = |source| RobotError::Io {
            file: file.clone(),
            source,
        };
        let mut bytes = Vec::new();
        std::fs::File::open(path)
            .and_then(|f| f.take(MAX_URDF_BYTES as u64 + 1).read_to_end(&mut bytes))
            .map_err(io)?;
        if bytes.len() > MAX_URDF_BYTES {
            return Err(RobotError::Parse {
                file,
                message: format!("the file is larger than {MAX_URDF_BYTES} bytes (MAX_URDF_BYTES)"),
            });
        }
        let text = String::from_utf8(bytes).map_err(|e| {
            io(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!(
                    "not UTF-8 text (invalid byte at offset {})",
                    e.utf8_error().valid_up_to()
                ),
            ))
        })?;
        RobotModel::from_urdf_str(&text, &file)
    }

    /// The fixed joints of any robot's URDF file (at most [`MAX_URDF_BYTES`]) as
    /// `(parent, child, parent_from_child)`: the extrinsics, for a field recording that
    /// lacks them. Unlike [`RobotModel::from_urdf_file`] the robot need not be one
    /// vinebench can simulate; moving joints are left out.
    pub fn fixed_joints_of_file(
        path: &std::path::Path,
    ) -> Result<Vec<(String, String, Isometry3<f64>)>, RobotError> {
        use std::io::Read;
        let file = path.display().to_string();
        let mut bytes = Vec::new();
        std::fs::File::open(path)
            .and_then(|f| f.take(MAX_URDF_BYTES as u64 + 1).read_to_end(&mut bytes))
            .map_err(|source| RobotError::Io {
                file: file.clone(),
                source,
            })?;
        if bytes.len() > MAX_URDF_BYTES {
            return Err(RobotError::Parse {
                file,
                message: format!("the file is larger than {MAX_URDF_BYTES} bytes (MAX_URDF_BYTES)"),
            });
        }
        let text = String::from_utf8(bytes).map_err(|e| RobotError::Parse {
            file: file.clone(),
            message: format!(
                "not UTF-8 text (invalid byte at offset {})",
                e.utf8_error().valid_up_to()
            ),
        })?;
        urdf::fixed_joints(&text, &file)
    }

    /// Parses URDF text; `source` names it in errors.
    pub fn from_urdf_str(text: &str, source: &str) -> Result<RobotModel, RobotError> {
        urdf::parse(text, source)
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
mod tests;
