//! URDF parsing and validation: `roxmltree` for the XML checks ([`super::xml`]: limits,
//! located errors) and the `<gazebo>` extension blocks (which `urdf-rs` skips), `urdf-rs`
//! for the URDF elements.
//!
//! Loading is linear in the file: every link's pose is resolved once, from its parent's
//! (see [`resolve_tree`]).

use super::xml::{self, Positions};
use super::{
    CollisionShape, Drive, DriveJoint, FOOTPRINT_LINK, GroundContact, MAX_GYRATION_RADIUS_M,
    MAX_LINK_MASS_KG, MAX_ROBOT_EXTENT_M, MAX_ROBOT_MASS_KG, MECANUM_DRIVE_PLUGIN, MecanumDrive,
    MecanumWheel, RigidInertia, RobotError, RobotGeometry, RobotModel, Shape,
    TRACKED_VEHICLE_PLUGIN, Track, TrackedDrive,
};
use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};
use std::collections::{BTreeMap, BTreeSet};
use vinebench_msgs::StaticTransforms;
use vinebench_msgs::frames::names::BASE_LINK;

/// Plugin-block values must agree with the geometry to this, m.
const PLUGIN_TOLERANCE_M: f64 = 1e-3;

/// One `<gazebo reference="link">` block.
#[derive(Default, Debug)]
struct GazeboLink {
    mu1: Option<String>,
    mu2: Option<String>,
    fdir1: Option<String>,
    kp: Option<String>,
    kd: Option<String>,
}

/// One `<gazebo><plugin name=...>` block: child element name → its text, in order
/// (nested `<left_track><link>x</link></left_track>` is flattened to `left_track/link`).
#[derive(Debug)]
struct Plugin {
    name: String,
    values: Vec<(String, String)>,
}

impl Plugin {
    fn all(&self, key: &str) -> Vec<&str> {
        self.values
            .iter()
            .filter(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
            .collect()
    }
}

/// A `<transmission>` of one joint: gear reduction and motor rotor inertia.
#[derive(Debug)]
struct Transmission {
    element: String,
    reduction: Option<String>,
    rotor_inertia: Option<String>,
}

/// The `<gazebo>` and `<transmission>` extension blocks of a URDF.
struct Extensions {
    links: BTreeMap<String, GazeboLink>,
    plugins: Vec<Plugin>,
    /// By joint name.
    transmissions: BTreeMap<String, Transmission>,
}

/// Parent link, `parent_from_child` at zero angle, the joint.
type ParentOf<'a> = BTreeMap<&'a str, (&'a str, Isometry3<f64>, &'a urdf_rs::Joint)>;

struct Ctx<'a, 'input> {
    source: &'a str,
    doc: &'a roxmltree::Document<'input>,
    /// Where the named elements are.
    positions: Positions,
}

impl Ctx<'_, '_> {
    /// An error about `element`: located at the element when the file has it
    /// ([`RobotError::Located`]), else [`RobotError::Invalid`].
    fn invalid(&self, element: impl Into<String>, problem: impl Into<String>) -> RobotError {
        let element = element.into();
        match self.positions.get(&element) {
            Some(&at) => xml::located(self.doc, self.source, at, element, problem),
            None => RobotError::Invalid {
                file: self.source.to_string(),
                element,
                problem: problem.into(),
            },
        }
    }
}

fn link_el(name: &str) -> String {
    format!("<link name=\"{name}\">")
}

fn joint_el(name: &str) -> String {
    format!("<joint name=\"{name}\">")
}

fn pose_of(p: &urdf_rs::Pose) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(p.xyz[0], p.xyz[1], p.xyz[2]),
        UnitQuaternion::from_euler_angles(p.rpy[0], p.rpy[1], p.rpy[2]),
    )
}

fn finite3(v: &urdf_rs::Vec3) -> bool {
    v.iter().all(|c| c.is_finite())
}

/// The fixed joints of any robot's URDF as `(parent, child, parent_from_child)`: the
/// extrinsics a field recording may lack (`[[static_transforms]]` from the robot's own
/// description). Same XML limits and checks as [`parse`], but none of a vinebench robot's
/// requirements (drive, inertia, `base_link`): moving joints are skipped (not static).
pub(super) fn fixed_joints(
    text: &str,
    source: &str,
) -> Result<Vec<(String, String, Isometry3<f64>)>, RobotError> {
    let (doc, positions, robot) = read(text, source)?;
    let cx = Ctx {
        source,
        doc: &doc,
        positions,
    };
    let mut out = Vec::new();
    for j in robot
        .joints
        .iter()
        .filter(|j| j.joint_type == urdf_rs::JointType::Fixed)
    {
        check_origin(&cx, j)?;
        out.push((
            j.parent.link.clone(),
            j.child.link.clone(),
            pose_of(&j.origin),
        ));
    }
    Ok(out)
}

/// Reads URDF text: the XML checks first (limits, located errors, and nothing that
/// urdf-rs's recursive tree could overflow the stack with), then urdf-rs.
fn read<'i>(
    text: &'i str,
    source: &str,
) -> Result<(roxmltree::Document<'i>, Positions, urdf_rs::Robot), RobotError> {
    let doc = xml::document(text, source)?;
    let positions = xml::check(&doc, source)?;
    let robot = urdf_rs::read_from_string(text).map_err(|e| RobotError::Parse {
        file: source.to_string(),
        message: e.to_string(),
    })?;
    Ok((doc, positions, robot))
}

/// A joint's `<origin>` must be finite.
fn check_origin(cx: &Ctx, j: &urdf_rs::Joint) -> Result<(), RobotError> {
    for (what, v) in [("xyz", &j.origin.xyz), ("rpy", &j.origin.rpy)] {
        if !finite3(v) {
            return Err(cx.invalid(
                joint_el(&j.name),
                format!(
                    "<origin {what}> must be three finite numbers, found {:?}",
                    v.0
                ),
            ));
        }
    }
    Ok(())
}

/// Parses and validates URDF text (see the module documentation of [`super`]).
pub(super) fn parse(text: &str, source: &str) -> Result<RobotModel, RobotError> {
    let (doc, positions, robot) = read(text, source)?;
    let cx = Ctx {
        source,
        doc: &doc,
        positions,
    };

    let links: BTreeSet<&str> = robot.links.iter().map(|l| l.name.as_str()).collect();
    if links.len() != robot.links.len() {
        return Err(cx.invalid("<link>", "two links share a name"));
    }
    let mut parent_of: ParentOf = BTreeMap::new();
    for j in &robot.joints {
        let el = joint_el(&j.name);
        check_origin(&cx, j)?;
        for (role, link) in [("parent", &j.parent.link), ("child", &j.child.link)] {
            if !links.contains(link.as_str()) {
                return Err(cx.invalid(el, format!("{role} link `{link}` is not defined")));
            }
        }
        match &j.joint_type {
            urdf_rs::JointType::Fixed | urdf_rs::JointType::Continuous => {}
            other => {
                return Err(cx.invalid(
                    el,
                    format!(
                        "type {other:?} is not supported: vinebench robots have fixed joints \
                         and continuous drive joints (sprockets, wheels)"
                    ),
                ));
            }
        }
        let pose = pose_of(&j.origin);
        if parent_of
            .insert(j.child.link.as_str(), (j.parent.link.as_str(), pose, j))
            .is_some()
        {
            return Err(cx.invalid(el, format!("link `{}` has two parent joints", j.child.link)));
        }
    }
    if !links.contains(BASE_LINK) {
        return Err(cx.invalid(
            link_el(BASE_LINK),
            "missing: every robot needs a base_link (REP-105 body frame)",
        ));
    }

    // root_from_link for every link (drive joints at zero angle), and whether the chain
    // to the root is fixed joints only.
    let tree = resolve_tree(&cx, &links, &parent_of)?;
    // Every link is resolved (resolve_tree covers `links`).
    let root_from = |link: &str| {
        tree.get(link)
            .copied()
            .unwrap_or(("", Isometry3::identity(), true))
    };
    let (base_root, root_from_base, base_fixed) = root_from(BASE_LINK);
    if !base_fixed {
        return Err(cx.invalid(
            link_el(BASE_LINK),
            "must be attached to its root by fixed joints only",
        ));
    }
    let mut body_from_link: BTreeMap<&str, Isometry3<f64>> = BTreeMap::new();
    let mut tf = StaticTransforms::new(BASE_LINK);
    for l in &links {
        let (root, root_from_link, fixed) = root_from(l);
        if root != base_root {
            return Err(cx.invalid(
                link_el(l),
                format!("not connected to {BASE_LINK} by joints (its tree's root is `{root}`)"),
            ));
        }
        let pose = root_from_base.inverse() * root_from_link;
        let reach = pose.translation.vector.norm();
        if reach.is_nan() || reach > MAX_ROBOT_EXTENT_M {
            return Err(cx.invalid(
                link_el(l),
                format!(
                    "lies {reach:e} m from {BASE_LINK}; every link must lie within \
                     {MAX_ROBOT_EXTENT_M} m (MAX_ROBOT_EXTENT_M)"
                ),
            ));
        }
        body_from_link.insert(l, pose);
        if *l != BASE_LINK && fixed {
            tf.insert(l, pose);
        }
    }

    let footprint = tf.body_from(FOOTPRINT_LINK).ok_or_else(|| {
        cx.invalid(
            link_el(FOOTPRINT_LINK),
            "missing: the ground contact below base_link (REP-120)",
        )
    })?;
    let ride_height_m = -footprint.translation.vector.z;
    if ride_height_m <= 0.0 {
        return Err(cx.invalid(
            link_el(FOOTPRINT_LINK),
            format!(
                "must lie below base_link (negative z), found z = {}",
                -ride_height_m
            ),
        ));
    }

    let link_of = |name: &str| robot.links.iter().find(|l| l.name == name);
    let collision_shapes = collision_shapes(&cx, &robot, &body_from_link)?;
    let inertia = rigid_inertia(&cx, &robot, &body_from_link)?;
    let Extensions {
        links: gazebo_links,
        plugins,
        transmissions,
    } = extension_blocks(cx.doc);

    let contact = |link: &str| -> Result<GroundContact, RobotError> {
        let el = format!("<gazebo reference=\"{link}\">");
        let g = gazebo_links.get(link).ok_or_else(|| {
            cx.invalid(
                el.clone(),
                "missing: the ground contact of a track or wheel needs <mu1>, <mu2>, <fdir1>, \
                 <kp> and <kd>",
            )
        })?;
        let number = |tag: &str, v: &Option<String>, min: f64| -> Result<f64, RobotError> {
            let s = v
                .as_deref()
                .ok_or_else(|| cx.invalid(el.clone(), format!("missing <{tag}>")))?;
            match s.trim().parse::<f64>() {
                Ok(x) if x.is_finite() && x >= min => Ok(x),
                _ => Err(cx.invalid(
                    el.clone(),
                    format!("<{tag}> must be a finite number >= {min}, found `{s}`"),
                )),
            }
        };
        let mu1 = number("mu1", &g.mu1, 0.0)?;
        let mu2 = number("mu2", &g.mu2, 0.0)?;
        let kp = number("kp", &g.kp, 0.0)?;
        let kd = number("kd", &g.kd, 0.0)?;
        if kp <= 0.0 {
            return Err(cx.invalid(el, "<kp> must be > 0 (contact stiffness, N/m)"));
        }
        let fdir = g
            .fdir1
            .as_deref()
            .ok_or_else(|| cx.invalid(el.clone(), "missing <fdir1>"))?;
        let parts: Vec<f64> = fdir
            .split_whitespace()
            .map(|p| p.parse::<f64>().unwrap_or(f64::NAN))
            .collect();
        let v = match parts.as_slice() {
            [x, y, z] => Vector3::new(*x, *y, *z),
            _ => Vector3::repeat(f64::NAN),
        };
        if !(v.iter().all(|c| c.is_finite()) && v.norm() > 1e-9) {
            return Err(cx.invalid(
                el,
                format!("<fdir1> must be three finite numbers, not all zero, found `{fdir}`"),
            ));
        }
        let rot = body_from_link
            .get(link)
            .map(|p| p.rotation)
            .unwrap_or_else(UnitQuaternion::identity);
        Ok(GroundContact {
            mu1,
            mu2,
            fdir1_in_body: rot * v.normalize(),
            stiffness_n_per_m: kp,
            damping_ns_per_m: kd,
        })
    };

    let drive_joint = |j: &urdf_rs::Joint| -> Result<DriveJoint, RobotError> {
        let el = joint_el(&j.name);
        if j.joint_type != urdf_rs::JointType::Continuous {
            return Err(cx.invalid(el, "a drive joint must be `continuous`"));
        }
        let axis = Vector3::new(j.axis.xyz[0], j.axis.xyz[1], j.axis.xyz[2]);
        if !(axis.iter().all(|c| c.is_finite()) && axis.norm() > 1e-9) {
            return Err(cx.invalid(el, "<axis xyz> must be a finite, non-zero vector"));
        }
        let body_from_joint = body_from_link
            .get(j.child.link.as_str())
            .copied()
            .unwrap_or_else(Isometry3::identity);
        let axis_in_body = body_from_joint.rotation * axis.normalize();
        let lim = &j.limit;
        let positive = |what: &str, v: f64, unit: &str| -> Result<f64, RobotError> {
            if v.is_finite() && v > 0.0 {
                Ok(v)
            } else {
                Err(cx.invalid(
                    el.clone(),
                    format!("<limit {what}> must be a finite number > 0 ({unit}), found {v}"),
                ))
            }
        };
        let max_torque_nm = positive("effort", lim.effort, "motor torque, N·m")?;
        let max_speed_radps = positive("velocity", lim.velocity, "rad/s")?;
        let max_accel_radps2 = if lim.acceleration == f64::INFINITY {
            f64::INFINITY
        } else {
            positive("acceleration", lim.acceleration, "rad/s²")?
        };
        let (damping_nms, friction_nm) = match &j.dynamics {
            Some(d) => (d.damping, d.friction),
            None => (0.0, 0.0),
        };
        if !(damping_nms.is_finite() && damping_nms >= 0.0 && friction_nm.is_finite())
            || friction_nm < 0.0
        {
            return Err(cx.invalid(
                el,
                "<dynamics damping friction> must be finite numbers >= 0",
            ));
        }
        let child = link_of(&j.child.link)
            .ok_or_else(|| cx.invalid(el.clone(), "child link is not defined"))?;
        let radius_m = child
            .collision
            .iter()
            .find_map(|c| match c.geometry {
                urdf_rs::Geometry::Cylinder { radius, .. } => Some(radius),
                _ => None,
            })
            .filter(|r| r.is_finite() && *r > 0.0)
            .ok_or_else(|| {
                cx.invalid(
                    link_el(&child.name),
                    "a drive link needs a <collision> <cylinder radius> (rolling radius)",
                )
            })?;
        // The child's inertia about the joint axis (in the joint frame).
        let i_link = inertia_tensor(&child.inertial);
        let r_joint_from_inertial = UnitQuaternion::from_euler_angles(
            child.inertial.origin.rpy[0],
            child.inertial.origin.rpy[1],
            child.inertial.origin.rpy[2],
        );
        let i_joint = r_joint_from_inertial.to_rotation_matrix().matrix()
            * i_link
            * r_joint_from_inertial
                .to_rotation_matrix()
                .matrix()
                .transpose();
        let a = axis.normalize();
        let link_inertia = (a.transpose() * i_joint * a)[0];
        if !(link_inertia.is_finite() && link_inertia > 0.0) {
            return Err(cx.invalid(
                link_el(&child.name),
                format!(
                    "its <inertial> must give a positive inertia about the joint axis, found \
                     {link_inertia}"
                ),
            ));
        }
        // The motor's rotor, reflected through the gear: J_rotor · N².
        let reflected = match transmissions.get(&j.name) {
            None => 0.0,
            Some(t) => {
                let value = |what: &str, v: &Option<String>| -> Result<f64, RobotError> {
                    let s = v
                        .as_deref()
                        .ok_or_else(|| cx.invalid(t.element.clone(), format!("missing {what}")))?;
                    match s.trim().parse::<f64>() {
                        Ok(x) if x.is_finite() && x > 0.0 => Ok(x),
                        _ => Err(cx.invalid(
                            t.element.clone(),
                            format!("{what} must be a finite number > 0, found `{s}`"),
                        )),
                    }
                };
                let n = value("<mechanicalReduction>", &t.reduction)?;
                let rotor = match &t.rotor_inertia {
                    None => 0.0,
                    some => value("<drake:rotor_inertia value>", some)?,
                };
                rotor * n * n
            }
        };
        let inertia_kgm2 = link_inertia + reflected;
        Ok(DriveJoint {
            name: j.name.clone(),
            link: j.child.link.clone(),
            body_from_joint,
            axis_in_body,
            radius_m,
            inertia_kgm2,
            reflected_inertia_kgm2: reflected,
            link_mass_kg: child.inertial.mass.value,
            max_torque_nm,
            max_speed_radps,
            max_accel_radps2,
            damping_nms,
            friction_nm,
        })
    };

    let tracked = plugins.iter().find(|p| p.name == TRACKED_VEHICLE_PLUGIN);
    let mecanum = plugins.iter().find(|p| p.name == MECANUM_DRIVE_PLUGIN);
    let drive = match (tracked, mecanum) {
        (Some(_), Some(_)) => {
            return Err(cx.invalid(
                "<gazebo> <plugin>",
                format!(
                    "two drives: keep one of {TRACKED_VEHICLE_PLUGIN} and {MECANUM_DRIVE_PLUGIN}"
                ),
            ));
        }
        (None, None) => {
            return Err(cx.invalid(
                "<gazebo> <plugin>",
                format!(
                    "missing: the drive is declared by a {TRACKED_VEHICLE_PLUGIN} plugin \
                     (<left_track><link>, <right_track><link>) or a {MECANUM_DRIVE_PLUGIN} \
                     plugin (<front_left_joint>, <front_right_joint>, <back_left_joint>, \
                     <back_right_joint>)"
                ),
            ));
        }
        (Some(p), None) => {
            let el = format!("<plugin name=\"{TRACKED_VEHICLE_PLUGIN}\">");
            let track = |side: &str| -> Result<Track, RobotError> {
                let key = format!("{side}_track/link");
                let names = p.all(&key);
                let name = match names.as_slice() {
                    [one] => *one,
                    [] => {
                        return Err(cx.invalid(el.clone(), format!("missing <{side}_track><link>")));
                    }
                    _ => {
                        return Err(cx.invalid(
                            el.clone(),
                            format!(
                                "several <{side}_track> links (flippers) are not supported; \
                                 found {}",
                                names.join(", ")
                            ),
                        ));
                    }
                };
                let link = link_of(name).ok_or_else(|| {
                    cx.invalid(
                        el.clone(),
                        format!("<{side}_track> link `{name}` is not defined"),
                    )
                })?;
                let (body_from_track, size) = link
                    .collision
                    .iter()
                    .find_map(|c| match c.geometry {
                        urdf_rs::Geometry::Box { size } => Some((pose_of(&c.origin), size.0)),
                        _ => None,
                    })
                    .filter(|(_, s)| s.iter().all(|c| c.is_finite() && *c > 0.0))
                    .ok_or_else(|| {
                        cx.invalid(
                            link_el(name),
                            "needs a <collision> <box size> with positive sizes (track length, \
                             width, height)",
                        )
                    })?;
                let body_from_link_pose = body_from_link
                    .get(name)
                    .copied()
                    .unwrap_or_else(Isometry3::identity);
                let sprockets: Vec<&urdf_rs::Joint> = robot
                    .joints
                    .iter()
                    .filter(|j| {
                        j.parent.link == name && j.joint_type == urdf_rs::JointType::Continuous
                    })
                    .collect();
                let sprocket = match sprockets.as_slice() {
                    [one] => drive_joint(one)?,
                    _ => {
                        return Err(cx.invalid(
                            link_el(name),
                            format!(
                                "a track needs exactly one continuous sprocket joint with \
                                 the track as parent, found {}",
                                sprockets.len()
                            ),
                        ));
                    }
                };
                if size[2] >= size[0] {
                    return Err(cx.invalid(
                        link_el(name),
                        "the track's collision box must be longer (x) than high (z)",
                    ));
                }
                Ok(Track {
                    link: name.to_string(),
                    body_from_track: body_from_link_pose * body_from_track,
                    length_m: size[0],
                    width_m: size[1],
                    height_m: size[2],
                    sprocket,
                    contact: contact(name)?,
                })
            };
            let (left, right) = (track("left")?, track("right")?);
            let width = left.body_from_track.translation.vector.y
                - right.body_from_track.translation.vector.y;
            if width < 0.05 {
                return Err(cx.invalid(
                    el,
                    format!(
                        "the left track must lie at least 5 cm left (+y) of the right one, \
                         found {width} m"
                    ),
                ));
            }
            if let Some(sep) = p.all("tracks_separation").first() {
                check_plugin_value(&cx, &el, "tracks_separation", sep, width)?;
            }
            Drive::Tracked(Box::new(TrackedDrive { left, right }))
        }
        (None, Some(p)) => {
            let el = format!("<plugin name=\"{MECANUM_DRIVE_PLUGIN}\">");
            let wheel = |tag: &str| -> Result<MecanumWheel, RobotError> {
                let name = *p
                    .all(tag)
                    .first()
                    .ok_or_else(|| cx.invalid(el.clone(), format!("missing <{tag}>")))?;
                let j = robot
                    .joints
                    .iter()
                    .find(|j| j.name == name)
                    .ok_or_else(|| {
                        cx.invalid(el.clone(), format!("<{tag}> joint `{name}` is not defined"))
                    })?;
                let joint = drive_joint(j)?;
                let width_m = link_of(&joint.link)
                    .and_then(|l| {
                        l.collision.iter().find_map(|c| match c.geometry {
                            urdf_rs::Geometry::Cylinder { length, .. } => Some(length),
                            _ => None,
                        })
                    })
                    .unwrap_or(0.0);
                let contact = contact(&joint.link)?;
                Ok(MecanumWheel {
                    joint,
                    width_m,
                    contact,
                })
            };
            let wheels = [
                wheel("front_left_joint")?,
                wheel("front_right_joint")?,
                wheel("back_left_joint")?,
                wheel("back_right_joint")?,
            ];
            let pos = |i: usize| wheels[i].joint.body_from_joint.translation.vector;
            let placed = pos(0).x > 0.0
                && pos(1).x > 0.0
                && pos(2).x < 0.0
                && pos(3).x < 0.0
                && pos(0).y > 0.0
                && pos(2).y > 0.0
                && pos(1).y < 0.0
                && pos(3).y < 0.0;
            if !placed {
                return Err(cx.invalid(
                    el,
                    "the wheels must sit front-left (+x, +y), front-right (+x, −y), back-left \
                     (−x, +y) and back-right (−x, −y) of base_link",
                ));
            }
            let m = MecanumDrive { wheels };
            if let super::DriveKinematics::Mecanum {
                half_wheelbase_m,
                half_separation_m,
                wheel_radius_m,
            } = Drive::Mecanum(Box::new(m.clone())).kinematics()
            {
                for (tag, value) in [
                    ("wheel_separation", 2.0 * half_separation_m),
                    ("wheelbase", 2.0 * half_wheelbase_m),
                    ("wheel_radius", wheel_radius_m),
                ] {
                    if let Some(v) = p.all(tag).first() {
                        check_plugin_value(&cx, &el, tag, v, value)?;
                    }
                }
            }
            Drive::Mecanum(Box::new(m))
        }
    };

    let kinematics = drive.kinematics();
    let geometry = match &drive {
        Drive::Tracked(t) => RobotGeometry {
            track_width_m: t.left.body_from_track.translation.vector.y
                - t.right.body_from_track.translation.vector.y,
            ride_height_m,
            footprint_length_m: t.left.length_m.max(t.right.length_m),
            footprint_width_m: t.left.body_from_track.translation.vector.y
                - t.right.body_from_track.translation.vector.y
                + (t.left.width_m + t.right.width_m) / 2.0,
            kinematics,
        },
        Drive::Mecanum(m) => {
            let p = |i: usize| m.wheels[i].joint.body_from_joint.translation.vector;
            let r = m.wheels[0].joint.radius_m;
            RobotGeometry {
                track_width_m: (p(0).y - p(1).y + p(2).y - p(3).y) / 2.0,
                ride_height_m,
                footprint_length_m: (p(0).x - p(2).x + p(1).x - p(3).x) / 2.0 + 2.0 * r,
                footprint_width_m: (p(0).y - p(1).y + p(2).y - p(3).y) / 2.0 + m.wheels[0].width_m,
                kinematics,
            }
        }
    };
    let running: BTreeSet<String> = match &drive {
        Drive::Tracked(t) => [&t.left, &t.right]
            .iter()
            .flat_map(|t| [t.link.clone(), t.sprocket.link.clone()])
            .collect(),
        Drive::Mecanum(m) => m.wheels.iter().map(|w| w.joint.link.clone()).collect(),
    };
    let collision_shapes = collision_shapes
        .into_iter()
        .map(|mut c| {
            c.running_gear = running.contains(&c.link);
            c
        })
        .collect();

    Ok(RobotModel {
        name: robot.name.clone(),
        source: source.to_string(),
        static_transforms: tf,
        geometry,
        drive,
        inertia,
        collision_shapes,
    })
}

/// Links whose pose [`resolve_tree`] multiplies out joint by joint from their root; deeper
/// links start from the pose of their ancestor this many joints up.
const POSE_WINDOW: usize = 16;

/// For every link: its tree's root, `root_from_link` (drive joints at zero angle) and
/// whether the chain to the root is fixed joints only.
type Resolved<'a> = BTreeMap<&'a str, (&'a str, Isometry3<f64>, bool)>;

/// Resolves every link of the joint tree in time linear in the links (a link is walked
/// from at most [`POSE_WINDOW`] joints below the nearest resolved ancestor), or names a
/// joint of a cycle.
///
/// A link at most [`POSE_WINDOW`] joints below its root gets `root_from_link` multiplied
/// out from the link up (`P₁·(P₂·(…·Pₙ))`), bit for bit as a walk to the root gives it;
/// a deeper one `root_from_ancestor · (…)` of the ancestor [`POSE_WINDOW`] joints up.
fn resolve_tree<'a>(
    cx: &Ctx,
    links: &BTreeSet<&'a str>,
    parent_of: &ParentOf<'a>,
) -> Result<Resolved<'a>, RobotError> {
    // Depth and root of every link; cycles found walking from base_link first, then from
    // each link in name order (each link is pushed at most once over all walks).
    let mut depth: BTreeMap<&'a str, (usize, &'a str)> = BTreeMap::new();
    for start in std::iter::once(BASE_LINK).chain(links.iter().copied()) {
        let Some(&start) = links.get(start) else {
            continue;
        };
        let mut walk: Vec<&'a str> = Vec::new();
        let mut on_walk: BTreeSet<&'a str> = BTreeSet::new();
        let mut link = start;
        let (mut d, root) = loop {
            if let Some(&known) = depth.get(link) {
                break known;
            }
            match parent_of.get(link) {
                None => {
                    depth.insert(link, (0, link));
                    break (0, link);
                }
                Some((parent, _, joint)) => {
                    if !on_walk.insert(link) {
                        return Err(cx.invalid(joint_el(&joint.name), "the joints form a cycle"));
                    }
                    walk.push(link);
                    link = parent;
                }
            }
        };
        while let Some(l) = walk.pop() {
            d += 1;
            depth.insert(l, (d, root));
        }
    }
    let mut order: Vec<(usize, &'a str)> = depth.iter().map(|(l, (d, _))| (*d, *l)).collect();
    order.sort_unstable();
    let mut resolved: Resolved<'a> = BTreeMap::new();
    for (d, start) in order {
        let root = depth.get(start).map_or(start, |&(_, r)| r);
        let mut pose = Isometry3::identity();
        let mut fixed = true;
        let mut link = start;
        for _ in 0..d.min(POSE_WINDOW) {
            let Some((parent, parent_from_child, joint)) = parent_of.get(link) else {
                break;
            };
            fixed &= joint.joint_type == urdf_rs::JointType::Fixed;
            pose = parent_from_child * pose;
            link = parent;
        }
        let entry = if d <= POSE_WINDOW {
            (root, pose, fixed)
        } else {
            // The ancestor is shallower: already resolved.
            let (_, above, above_fixed) =
                resolved
                    .get(link)
                    .copied()
                    .unwrap_or((root, Isometry3::identity(), true));
            (root, above * pose, above_fixed && fixed)
        };
        resolved.insert(start, entry);
    }
    Ok(resolved)
}

fn check_plugin_value(
    cx: &Ctx,
    el: &str,
    tag: &str,
    text: &str,
    geometry: f64,
) -> Result<(), RobotError> {
    match text.trim().parse::<f64>() {
        Ok(v) if (v - geometry).abs() <= PLUGIN_TOLERANCE_M => Ok(()),
        _ => Err(cx.invalid(
            el,
            format!(
                "<{tag}> is `{text}` but the joints and links say {geometry:.4} m; they must \
                 agree within {PLUGIN_TOLERANCE_M} m"
            ),
        )),
    }
}

fn inertia_tensor(i: &urdf_rs::Inertial) -> Matrix3<f64> {
    let t = &i.inertia;
    Matrix3::new(
        t.ixx, t.ixy, t.ixz, //
        t.ixy, t.iyy, t.iyz, //
        t.ixz, t.iyz, t.izz,
    )
}

/// The whole robot's mass, centre of mass and inertia about it (parallel-axis sum of
/// every link's `<inertial>`).
fn rigid_inertia(
    cx: &Ctx,
    robot: &urdf_rs::Robot,
    body_from_link: &BTreeMap<&str, Isometry3<f64>>,
) -> Result<RigidInertia, RobotError> {
    let mut parts = Vec::new();
    for l in &robot.links {
        let m = l.inertial.mass.value;
        let tensor = inertia_tensor(&l.inertial);
        let el = || link_el(&l.name);
        if !(m.is_finite() && m >= 0.0) {
            return Err(cx.invalid(
                el(),
                format!("<mass value> must be a finite number >= 0, found {m}"),
            ));
        }
        if m > MAX_LINK_MASS_KG {
            return Err(cx.invalid(
                el(),
                format!(
                    "<mass value> must be at most {MAX_LINK_MASS_KG} kg (MAX_LINK_MASS_KG), \
                     found {m:e} kg"
                ),
            ));
        }
        if !tensor.iter().all(|c| c.is_finite())
            || !finite3(&l.inertial.origin.xyz)
            || !finite3(&l.inertial.origin.rpy)
        {
            return Err(cx.invalid(el(), "<inertial> must hold finite numbers"));
        }
        if m == 0.0 {
            continue;
        }
        let eig = tensor.symmetric_eigenvalues();
        let (a, b, c) = (eig[0], eig[1], eig[2]);
        if a < 0.0 || b < 0.0 || c < 0.0 || a + b < c || b + c < a || a + c < b {
            return Err(cx.invalid(
                el(),
                format!(
                    "<inertia> is not a physical inertia tensor (principal moments {a:.4}, \
                     {b:.4}, {c:.4} must be >= 0 and satisfy the triangle inequality)"
                ),
            ));
        }
        let largest = a.max(b).max(c);
        let bound = m * MAX_GYRATION_RADIUS_M * MAX_GYRATION_RADIUS_M;
        if largest > bound {
            return Err(cx.invalid(
                el(),
                format!(
                    "<inertia> is too large for the link's {m} kg: principal moments must be at \
                     most mass · ({MAX_GYRATION_RADIUS_M} m)² = {bound:.4e} kg·m² \
                     (MAX_GYRATION_RADIUS_M), found {largest:.4e} kg·m²"
                ),
            ));
        }
        let body_from_inertial = body_from_link
            .get(l.name.as_str())
            .copied()
            .unwrap_or_else(Isometry3::identity)
            * pose_of(&l.inertial.origin);
        let reach = body_from_inertial.translation.vector.norm();
        if reach.is_nan() || reach > MAX_ROBOT_EXTENT_M {
            return Err(cx.invalid(
                el(),
                format!(
                    "its centre of mass lies {reach:e} m from {BASE_LINK}; it must lie within \
                     {MAX_ROBOT_EXTENT_M} m (MAX_ROBOT_EXTENT_M)"
                ),
            ));
        }
        let r = body_from_inertial.rotation.to_rotation_matrix();
        parts.push((
            m,
            body_from_inertial.translation.vector,
            r.matrix() * tensor * r.matrix().transpose(),
        ));
    }
    let mass: f64 = parts.iter().map(|p| p.0).sum();
    if mass.is_nan() || mass <= 0.0 {
        return Err(cx.invalid(
            "<inertial>",
            "the links' masses must add up to more than 0 kg",
        ));
    }
    if mass > MAX_ROBOT_MASS_KG {
        return Err(cx.invalid(
            "<inertial>",
            format!(
                "the links' masses must add up to at most {MAX_ROBOT_MASS_KG} kg \
                 (MAX_ROBOT_MASS_KG), found {mass:e} kg"
            ),
        ));
    }
    let com = parts.iter().fold(Vector3::zeros(), |a, p| a + p.1 * p.0) / mass;
    let inertia = parts.iter().fold(Matrix3::zeros(), |acc, (m, c, i)| {
        let d = c - com;
        acc + i + (Matrix3::identity() * d.norm_squared() - d * d.transpose()) * *m
    });
    // Bounded masses, moments and distances keep these finite; a last check all the same.
    if !(com.iter().all(|c| c.is_finite()) && inertia.iter().all(|c| c.is_finite())) {
        return Err(cx.invalid(
            "<inertial>",
            "the links' mass properties do not add up to a finite centre of mass and inertia",
        ));
    }
    Ok(RigidInertia {
        mass_kg: mass,
        com_in_body: com,
        inertia_about_com_in_body: inertia,
    })
}

fn collision_shapes(
    cx: &Ctx,
    robot: &urdf_rs::Robot,
    body_from_link: &BTreeMap<&str, Isometry3<f64>>,
) -> Result<Vec<CollisionShape>, RobotError> {
    let mut out = Vec::new();
    for l in &robot.links {
        for c in &l.collision {
            let el = || link_el(&l.name);
            if !finite3(&c.origin.xyz) || !finite3(&c.origin.rpy) {
                return Err(cx.invalid(el(), "<collision> <origin> must hold finite numbers"));
            }
            let ok = |v: f64| v.is_finite() && v > 0.0;
            let shape = match &c.geometry {
                urdf_rs::Geometry::Box { size } if size.iter().all(|s| ok(*s)) => Shape::Box {
                    half_extents_m: Vector3::new(size[0], size[1], size[2]) / 2.0,
                },
                urdf_rs::Geometry::Cylinder { radius, length } if ok(*radius) && ok(*length) => {
                    Shape::Cylinder {
                        radius_m: *radius,
                        half_length_m: length / 2.0,
                    }
                }
                urdf_rs::Geometry::Sphere { radius } if ok(*radius) => {
                    Shape::Sphere { radius_m: *radius }
                }
                urdf_rs::Geometry::Mesh { filename, .. } => {
                    return Err(cx.invalid(
                        el(),
                        format!(
                            "<collision> <mesh filename=\"{filename}\"> is not supported: use \
                             box, cylinder or sphere primitives for collisions (meshes are \
                             fine in <visual>)"
                        ),
                    ));
                }
                other => {
                    return Err(cx.invalid(
                        el(),
                        format!(
                            "<collision> geometry must be a box, cylinder or sphere with \
                             positive finite sizes, found {other:?}"
                        ),
                    ));
                }
            };
            let body_from_shape = body_from_link
                .get(l.name.as_str())
                .copied()
                .unwrap_or_else(Isometry3::identity)
                * pose_of(&c.origin);
            let size = match &shape {
                Shape::Box { half_extents_m } => half_extents_m.norm(),
                Shape::Cylinder {
                    radius_m,
                    half_length_m,
                } => radius_m.hypot(*half_length_m),
                Shape::Sphere { radius_m } => *radius_m,
            };
            let reach = body_from_shape.translation.vector.norm() + size;
            if reach.is_nan() || reach > MAX_ROBOT_EXTENT_M {
                return Err(cx.invalid(
                    el(),
                    format!(
                        "a <collision> shape reaches {reach:e} m from {BASE_LINK}; shapes must \
                         stay within {MAX_ROBOT_EXTENT_M} m (MAX_ROBOT_EXTENT_M)"
                    ),
                ));
            }
            out.push(CollisionShape {
                link: l.name.clone(),
                body_from_shape,
                shape,
                running_gear: false,
            });
        }
    }
    Ok(out)
}

/// The `<gazebo reference>` blocks by link, the `<gazebo><plugin>` blocks and the
/// `<transmission>` blocks by joint.
fn extension_blocks(doc: &roxmltree::Document) -> Extensions {
    let mut links: BTreeMap<String, GazeboLink> = BTreeMap::new();
    let mut plugins = Vec::new();
    let mut transmissions = BTreeMap::new();
    for t in doc
        .root_element()
        .children()
        .filter(|n| n.has_tag_name("transmission"))
    {
        let element = format!(
            "<transmission name=\"{}\">",
            t.attribute("name").unwrap_or("")
        );
        let actuator = t.children().find(|c| c.has_tag_name("actuator"));
        let child_text = |name: &str| {
            actuator
                .and_then(|a| a.children().find(|c| c.tag_name().name() == name))
                .and_then(|c| c.text())
                .map(|s| s.trim().to_string())
        };
        let rotor_inertia = actuator
            .and_then(|a| {
                a.children()
                    .find(|c| c.tag_name().name() == "rotor_inertia")
            })
            .map(|c| c.attribute("value").unwrap_or("").to_string());
        for j in t.children().filter(|c| c.has_tag_name("joint")) {
            if let Some(name) = j.attribute("name") {
                transmissions.insert(
                    name.to_string(),
                    Transmission {
                        element: element.clone(),
                        reduction: child_text("mechanicalReduction"),
                        rotor_inertia: rotor_inertia.clone(),
                    },
                );
            }
        }
    }
    for g in doc
        .root_element()
        .children()
        .filter(|n| n.has_tag_name("gazebo"))
    {
        if let Some(reference) = g.attribute("reference") {
            let entry = links.entry(reference.to_string()).or_default();
            for c in g.children().filter(|c| c.is_element()) {
                let value = c.text().map(|t| t.trim().to_string());
                match c.tag_name().name() {
                    "mu1" => entry.mu1 = value,
                    "mu2" => entry.mu2 = value,
                    "fdir1" => entry.fdir1 = value,
                    "kp" => entry.kp = value,
                    "kd" => entry.kd = value,
                    _ => {}
                }
            }
        } else {
            for p in g.children().filter(|c| c.has_tag_name("plugin")) {
                let mut values = Vec::new();
                for c in p.children().filter(|c| c.is_element()) {
                    let key = c.tag_name().name().to_string();
                    let nested: Vec<_> = c.children().filter(|n| n.is_element()).collect();
                    if nested.is_empty() {
                        values.push((key, c.text().unwrap_or("").trim().to_string()));
                    } else {
                        for n in nested {
                            values.push((
                                format!("{key}/{}", n.tag_name().name()),
                                n.text().unwrap_or("").trim().to_string(),
                            ));
                        }
                    }
                }
                plugins.push(Plugin {
                    name: p.attribute("name").unwrap_or("").to_string(),
                    values,
                });
            }
        }
    }
    Extensions {
        links,
        plugins,
        transmissions,
    }
}
