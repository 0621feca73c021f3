//! Trajectories from a ROS 2 recording, as `evo_ape bag2` reads them: an MCAP file (or a
//! rosbag2 folder with MCAP storage) and a topic of `nav_msgs/msg/Odometry`,
//! `geometry_msgs/msg/PoseStamped`, `PoseWithCovarianceStamped`, `TransformStamped` or
//! `PointStamped` (identity rotation, as evo). Each pose is stamped with its header stamp
//! (`sec + nanosec·1e-9`, as evo computes it), in the recording's order; the trajectory is
//! named by the topic.

use super::{Format, Traj, lie};
use crate::recording::cdr::{CdrError, CdrReader};
use crate::recording::reader::{self, ChannelInfo, RawMessage};
use nalgebra::Vector3;
use std::path::{Path, PathBuf};

/// Why a topic could not be read.
#[derive(Debug, thiserror::Error)]
pub enum BagError {
    /// The recording could not be read.
    #[error("{0}")]
    Recording(#[from] crate::recording::RecordingError),
    /// A folder without an MCAP file.
    #[error(
        "{path}: a rosbag2 folder whose storage is not MCAP ({found}); vinebench reads MCAP \
         (convert with `ros2 bag convert`)"
    )]
    Storage {
        /// The folder.
        path: String,
        /// What it holds.
        found: String,
    },
    /// No such topic.
    #[error("{path}: no messages for topic '{topic}' (topics with poses: {available})")]
    NoTopic {
        /// The recording.
        path: String,
        /// The topic asked for.
        topic: String,
        /// Topics of supported types.
        available: String,
    },
    /// A type evo does not read.
    #[error(
        "{path}: topic '{topic}' is {schema}; expected nav_msgs/msg/Odometry, \
         geometry_msgs/msg/PoseStamped, PoseWithCovarianceStamped, TransformStamped or \
         PointStamped"
    )]
    Type {
        /// The recording.
        path: String,
        /// The topic.
        topic: String,
        /// Its schema.
        schema: String,
    },
    /// A ROS 1 bag could not be read.
    #[error("{0}")]
    Bag1(String),
    /// A tf lookup failed.
    #[error("{path}: {id}: {problem}")]
    Tf {
        /// The recording.
        path: String,
        /// The tf identifier.
        id: String,
        /// What failed.
        problem: String,
    },
    /// A message that does not decode.
    #[error("{path}: topic '{topic}', message {index} (log time {log_time}): {source}")]
    Message {
        /// The recording.
        path: String,
        /// The topic.
        topic: String,
        /// 0-based message index on the topic.
        index: usize,
        /// Its log time.
        log_time: vinebench_msgs::Nanos,
        /// Why.
        source: CdrError,
    },
}

/// The supported message types.
const TYPES: [&str; 5] = [
    "nav_msgs/msg/Odometry",
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "geometry_msgs/msg/TransformStamped",
    "geometry_msgs/msg/PointStamped",
];

/// The MCAP file of `path` (itself, or the one of a rosbag2 folder).
pub fn mcap_file(path: &Path) -> Result<PathBuf, BagError> {
    if !path.is_dir() {
        return Ok(path.to_path_buf());
    }
    let mut found = Vec::new();
    let entries =
        std::fs::read_dir(path).map_err(|source| crate::recording::RecordingError::Io {
            path: path.display().to_string(),
            source,
        })?;
    for e in entries.flatten() {
        found.push(e.path());
    }
    found.sort();
    let mcaps: Vec<&PathBuf> = found
        .iter()
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    match mcaps.as_slice() {
        [one] => Ok((*one).clone()),
        _ => Err(BagError::Storage {
            path: path.display().to_string(),
            found: if mcaps.is_empty() {
                let names: Vec<String> = found
                    .iter()
                    .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
                    .collect();
                format!("files: {}", names.join(", "))
            } else {
                format!("{} MCAP files: split bags are not read yet", mcaps.len())
            },
        }),
    }
}

/// `(stamp s, position, quaternion w x y z)` of one message of schema `schema`.
fn decode(schema: &str, data: &[u8]) -> Result<(f64, [f64; 3], [f64; 4]), CdrError> {
    let mut r = CdrReader::new(data)?;
    let sec = r.i32("header.stamp.sec")?;
    let nanosec = r.u32("header.stamp.nanosec")?;
    r.string("header.frame_id")?;
    let stamp = f64::from(sec) + f64::from(nanosec) * 1e-9;
    if schema.ends_with("/Odometry") || schema.ends_with("/TransformStamped") {
        r.string("child_frame_id")?;
    }
    let p = r.f64s::<3>("position")?;
    let q = if schema.ends_with("/PointStamped") {
        [1.0, 0.0, 0.0, 0.0]
    } else {
        let [x, y, z, w] = r.f64s::<4>("orientation")?;
        [w, x, y, z]
    };
    Ok((stamp, p, q))
}

/// The trajectory of `topic` in the recording at `path` (a pose topic, or a tf
/// identifier `/tf:parent.child`: see [`super::tf`]).
pub fn read_topic(path: &Path, topic: &str) -> Result<Traj, BagError> {
    if !path.is_dir() && is_bag1(path) {
        return read_topic_bag1(path, topic);
    }
    let file = mcap_file(path)?;
    if let Some(id) = super::tf::TfId::parse(topic) {
        return read_tf(&file, topic, &id);
    }
    let name = file.display().to_string();
    let mut stamps = Vec::new();
    let mut poses = Vec::new();
    let mut schema = None;
    let mut error = None;
    let mut index = 0usize;
    let summary = reader::scan_file(&file, |c: &ChannelInfo, m: &RawMessage<'_>| {
        if c.topic != topic || error.is_some() {
            return;
        }
        if !TYPES.contains(&c.schema_name.as_str()) {
            schema.get_or_insert_with(|| c.schema_name.clone());
            return;
        }
        match decode(&c.schema_name, m.data) {
            Ok((t, p, q)) => {
                stamps.push(t);
                let r = lie::quaternion_matrix(q[0], q[1], q[2], q[3]);
                poses.push(lie::se3(&r, &Vector3::from(p)));
            }
            Err(source) => {
                error = Some(BagError::Message {
                    path: name.clone(),
                    topic: topic.to_string(),
                    index,
                    log_time: m.log_time,
                    source,
                });
            }
        }
        index += 1;
    })?;
    if let Some(e) = error {
        return Err(e);
    }
    if let Some(schema) = schema {
        return Err(BagError::Type {
            path: name,
            topic: topic.to_string(),
            schema,
        });
    }
    if poses.is_empty() {
        let mut available: Vec<String> = summary
            .channels
            .values()
            .filter(|c| TYPES.contains(&c.schema_name.as_str()))
            .map(|c| format!("{} ({})", c.topic, c.schema_name))
            .collect();
        available.sort();
        available.dedup();
        return Err(BagError::NoTopic {
            path: name,
            topic: topic.to_string(),
            available: if available.is_empty() {
                "none".into()
            } else {
                available.join(", ")
            },
        });
    }
    Ok(Traj {
        name: topic.to_string(),
        format: Format::Mcap,
        stamps: Some(stamps),
        poses,
    })
}

/// Seconds as evo computes them from a ROS time: `sec + nanosec·1e-9`.
fn ros_seconds(t: vinebench_msgs::Nanos) -> f64 {
    let sec = t.0.div_euclid(1_000_000_000);
    let nanosec = t.0.rem_euclid(1_000_000_000);
    sec as f64 + nanosec as f64 * 1e-9
}

/// The trajectory of tf identifier `id` (see [`super::tf`]) in an MCAP file.
fn read_tf(file: &Path, name: &str, id: &super::tf::TfId) -> Result<Traj, BagError> {
    let path = file.display().to_string();
    let mut transforms = Vec::new();
    let mut error = None;
    let mut index = 0usize;
    reader::scan_file(file, |c: &ChannelInfo, m: &RawMessage<'_>| {
        let is_static = c.topic == id.static_topic;
        if !(c.topic == id.topic || is_static) || error.is_some() {
            return;
        }
        if c.schema_name != "tf2_msgs/msg/TFMessage" {
            error = Some(BagError::Type {
                path: path.clone(),
                topic: c.topic.clone(),
                schema: format!(
                    "{} (a tf topic must be tf2_msgs/msg/TFMessage)",
                    c.schema_name
                ),
            });
            return;
        }
        match crate::recording::ros::decode_tf(m.data) {
            Ok(ts) => transforms.extend(ts.into_iter().map(|t| (is_static, t))),
            Err(source) => {
                error = Some(BagError::Message {
                    path: path.clone(),
                    topic: c.topic.clone(),
                    index,
                    log_time: m.log_time,
                    source,
                });
            }
        }
        index += 1;
    })?;
    if let Some(e) = error {
        return Err(e);
    }
    tf_trajectory(&path, name, id, transforms)
}

/// The trajectory of `id` from the transforms of its tf topics (`(static?, transform)`
/// in the recording's order).
fn tf_trajectory(
    path: &str,
    name: &str,
    id: &super::tf::TfId,
    transforms: Vec<(bool, crate::recording::ros::TransformStamped)>,
) -> Result<Traj, BagError> {
    use super::tf::{Buffer, TfError, grid};
    let tf_err = |problem: String| BagError::Tf {
        path: path.to_string(),
        id: name.to_string(),
        problem,
    };
    let mut buffer = Buffer::default();
    let mut start = None;
    for (is_static, t) in transforms {
        if !is_static {
            start.get_or_insert(t.stamp);
        }
        buffer.insert(
            t.parent.as_str(),
            t.child.as_str(),
            t.stamp,
            t.parent_from_child,
            is_static,
        );
    }
    let Some(start) = start else {
        return Err(tf_err(format!("no messages for topic {}", id.topic)));
    };
    buffer.finish();
    let times = match buffer.latest_common_time(&id.parent, &id.child) {
        Some(latest) => grid(start, latest).ok_or_else(|| {
            tf_err(format!(
                "the transforms span {:.0} s: more than {} lookups at 10 Hz",
                (latest - start).as_secs_f64(),
                super::tf::MAX_SAMPLES
            ))
        })?,
        // A chain of static transforms only: tf2 answers time zero with them.
        None => vec![vinebench_msgs::Nanos(0)],
    };
    let mut stamps = Vec::with_capacity(times.len());
    let mut poses = Vec::with_capacity(times.len());
    for t in times {
        match buffer.lookup(&id.parent, &id.child, t) {
            Ok(p) => {
                stamps.push(ros_seconds(t));
                poses.push(p.to_homogeneous());
            }
            Err(TfError::Extrapolation) => {}
            Err(e) => return Err(tf_err(e.to_string())),
        }
    }
    if poses.is_empty() {
        return Err(tf_err(
            "no time at which every transform of the chain is known (tf2 extrapolation at \
             every 0.1 s step)"
                .into(),
        ));
    }
    Ok(Traj {
        name: name.to_string(),
        format: Format::Mcap,
        stamps: Some(stamps),
        poses,
    })
}

/// Whether `path` is a ROS 1 bag (its magic).
pub fn is_bag1(path: &Path) -> bool {
    let mut magic = [0u8; 13];
    std::fs::File::open(path)
        .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut magic))
        .is_ok()
        && magic.starts_with(b"#ROSBAG V")
}

/// `(stamp s, position, quaternion w x y z)` of a ROS 1 message of type `ty`.
fn decode_ros1(ty: &str, data: &[u8]) -> Result<(f64, [f64; 3], [f64; 4]), String> {
    use crate::recording::bag1::Ros1Reader;
    let mut r = Ros1Reader::new(data);
    let (sec, nsec, _) = r.header()?;
    let stamp = f64::from(sec) + f64::from(nsec) * 1e-9;
    if ty.ends_with("/Odometry") || ty.ends_with("/TransformStamped") {
        r.string("child_frame_id")?;
    }
    let p = r.f64s::<3>("position")?;
    let q = if ty.ends_with("/PointStamped") {
        [1.0, 0.0, 0.0, 0.0]
    } else {
        let [x, y, z, w] = r.f64s::<4>("orientation")?;
        [w, x, y, z]
    };
    Ok((stamp, p, q))
}

/// The transforms of a ROS 1 `tf2_msgs/TFMessage` (or `tf/tfMessage`).
fn decode_ros1_tf(data: &[u8]) -> Result<Vec<crate::recording::ros::TransformStamped>, String> {
    use crate::recording::bag1::Ros1Reader;
    use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
    let mut r = Ros1Reader::new(data);
    let n = r.u32("transforms")? as usize;
    // A transform takes at least 12 + 4 + 4 + 56 bytes.
    if n > data.len() / 76 {
        return Err(format!("{n} transforms in {} bytes", data.len()));
    }
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let (sec, nsec, parent) = r.header()?;
        let child = r.string("child_frame_id")?;
        let t = r.f64s::<3>("transform.translation")?;
        let [x, y, z, w] = r.f64s::<4>("transform.rotation")?;
        // ROS 1 tf names may start with '/'; tf2 strips it.
        let strip = |s: &str| s.strip_prefix('/').unwrap_or(s).to_string();
        out.push(crate::recording::ros::TransformStamped {
            stamp: vinebench_msgs::Nanos(i64::from(sec) * 1_000_000_000 + i64::from(nsec)),
            parent: vinebench_msgs::FrameId::new(&strip(parent)),
            child: vinebench_msgs::FrameId::new(&strip(child)),
            parent_from_child: Isometry3::from_parts(
                Translation3::new(t[0], t[1], t[2]),
                UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)),
            ),
        });
    }
    Ok(out)
}

/// The trajectory of `topic` (or tf identifier) in a ROS 1 bag.
pub fn read_topic_bag1(path: &Path, topic: &str) -> Result<Traj, BagError> {
    use crate::recording::bag1;
    let name = path.display().to_string();
    let id = super::tf::TfId::parse(topic);
    let bag = bag1::read(path, |c| match &id {
        Some(id) => c.topic == id.topic || c.topic == id.static_topic,
        None => c.topic == topic,
    })
    .map_err(|e| BagError::Bag1(e.to_string()))?;
    let msg_err = |index: usize, m: &bag1::Message, problem: String| {
        BagError::Bag1(format!(
            "{name}: topic '{}', message {index} (record time {}): {problem}",
            bag.connections
                .get(&m.conn)
                .map_or("?", |c| c.topic.as_str()),
            m.time
        ))
    };
    if let Some(id) = id {
        let mut transforms = Vec::new();
        for (i, m) in bag.messages.iter().enumerate() {
            let c = &bag.connections[&m.conn];
            let ty = c.msg_type.as_str();
            if ty != "tf2_msgs/TFMessage" && ty != "tf/tfMessage" {
                return Err(BagError::Type {
                    path: name,
                    topic: c.topic.clone(),
                    schema: format!("{ty} (a tf topic must be tf2_msgs/TFMessage)"),
                });
            }
            let is_static = c.topic == id.static_topic;
            let ts = decode_ros1_tf(&m.data).map_err(|e| msg_err(i, m, e))?;
            transforms.extend(ts.into_iter().map(|t| (is_static, t)));
        }
        return tf_trajectory(&name, topic, &id, transforms);
    }
    let mut stamps = Vec::new();
    let mut poses = Vec::new();
    for (i, m) in bag.messages.iter().enumerate() {
        let c = &bag.connections[&m.conn];
        let ros2 = c.msg_type.replacen('/', "/msg/", 1);
        if !TYPES.contains(&ros2.as_str()) {
            return Err(BagError::Type {
                path: name,
                topic: topic.to_string(),
                schema: c.msg_type.clone(),
            });
        }
        let (t, p, q) = decode_ros1(&c.msg_type, &m.data).map_err(|e| msg_err(i, m, e))?;
        stamps.push(t);
        let r = lie::quaternion_matrix(q[0], q[1], q[2], q[3]);
        poses.push(lie::se3(&r, &Vector3::from(p)));
    }
    if poses.is_empty() {
        let mut available: Vec<String> = bag
            .connections
            .values()
            .filter(|c| TYPES.contains(&c.msg_type.replacen('/', "/msg/", 1).as_str()))
            .map(|c| format!("{} ({})", c.topic, c.msg_type))
            .collect();
        available.sort();
        available.dedup();
        return Err(BagError::NoTopic {
            path: name,
            topic: topic.to_string(),
            available: if available.is_empty() {
                "none".into()
            } else {
                available.join(", ")
            },
        });
    }
    Ok(Traj {
        name: topic.to_string(),
        format: Format::Mcap,
        stamps: Some(stamps),
        poses,
    })
}
