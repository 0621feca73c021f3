//! Trajectories from a robot's recording, as `evo_ape bag` / `bag2` read them: a ROS 1
//! bag, an MCAP file or a rosbag2 folder with MCAP storage
//! ([`crate::recording::scan_any`]), and a topic of `nav_msgs/Odometry`,
//! `geometry_msgs/PoseStamped`, `PoseWithCovarianceStamped`, `TransformStamped` or
//! `PointStamped` (identity rotation, as evo), or a transform between two frames
//! (`/tf:parent.child`, [`super::tf`]). Each pose is stamped with its header stamp
//! (`sec + nanosec·1e-9`, as evo computes it); poses come in record-time order, as
//! rosbags iterates them; the trajectory is named by the topic.

use super::{Format, Traj, lie};
use crate::recording::cdr::{CdrError, CdrReader};
use crate::recording::reader::{ChannelInfo, RawMessage};
use crate::recording::ros::TransformStamped;
use nalgebra::Vector3;
use std::path::Path;
use vinebench_msgs::Nanos;

/// Why a topic could not be read.
#[derive(Debug, thiserror::Error)]
pub enum BagError {
    /// The recording could not be read.
    #[error("{0}")]
    Recording(#[from] crate::recording::RecordingError),
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
        log_time: Nanos,
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
    let name = path.display().to_string();
    if let Some(id) = super::tf::TfId::parse(topic) {
        return read_tf(path, topic, &id);
    }
    // (log time, stamp, pose), sorted by log time at the end.
    let mut poses: Vec<(Nanos, f64, lie::Pose)> = Vec::new();
    let mut schema = None;
    let mut error = None;
    let mut index = 0usize;
    let summary = crate::recording::scan_any(path, |c: &ChannelInfo, m: &RawMessage<'_>| {
        if c.topic != topic || error.is_some() {
            return;
        }
        if !TYPES.contains(&c.schema_name.as_str()) {
            schema.get_or_insert_with(|| c.schema_name.clone());
            return;
        }
        match decode(&c.schema_name, m.data) {
            Ok((t, p, q)) => {
                let r = lie::quaternion_matrix(q[0], q[1], q[2], q[3]);
                poses.push((m.log_time, t, lie::se3(&r, &Vector3::from(p))));
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
    poses.sort_by_key(|p| p.0);
    Ok(Traj {
        name: topic.to_string(),
        format: Format::Mcap,
        stamps: Some(poses.iter().map(|p| p.1).collect()),
        poses: poses.into_iter().map(|p| p.2).collect(),
    })
}

/// Seconds as evo computes them from a ROS time: `sec + nanosec·1e-9`.
fn ros_seconds(t: Nanos) -> f64 {
    let sec = t.0.div_euclid(1_000_000_000);
    let nanosec = t.0.rem_euclid(1_000_000_000);
    sec as f64 + nanosec as f64 * 1e-9
}

/// A frame name as tf2 keys it (ROS 1's leading `/` dropped).
fn frame(name: &str) -> &str {
    name.strip_prefix('/').unwrap_or(name)
}

/// The trajectory of tf identifier `id` (see [`super::tf`]).
fn read_tf(path: &Path, name: &str, id: &super::tf::TfId) -> Result<Traj, BagError> {
    let file = path.display().to_string();
    // (log time, static?, transform), sorted by log time at the end.
    let mut transforms: Vec<(Nanos, bool, TransformStamped)> = Vec::new();
    let mut error = None;
    let mut index = 0usize;
    crate::recording::scan_any(path, |c: &ChannelInfo, m: &RawMessage<'_>| {
        let is_static = c.topic == id.static_topic;
        if !(c.topic == id.topic || is_static) || error.is_some() {
            return;
        }
        if c.schema_name != "tf2_msgs/msg/TFMessage" {
            error = Some(BagError::Type {
                path: file.clone(),
                topic: c.topic.clone(),
                schema: format!(
                    "{} (a tf topic must be tf2_msgs/msg/TFMessage)",
                    c.schema_name
                ),
            });
            return;
        }
        match crate::recording::ros::decode_tf(m.data) {
            Ok(ts) => transforms.extend(ts.into_iter().map(|t| (m.log_time, is_static, t))),
            Err(source) => {
                error = Some(BagError::Message {
                    path: file.clone(),
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
    transforms.sort_by_key(|t| t.0);
    use super::tf::{Buffer, TfError, grid};
    let tf_err = |problem: String| BagError::Tf {
        path: file.clone(),
        id: name.to_string(),
        problem,
    };
    let mut buffer = Buffer::default();
    let mut start = None;
    for (_, is_static, t) in transforms {
        if !is_static {
            start.get_or_insert(t.stamp);
        }
        buffer.insert(
            frame(t.parent.as_str()),
            frame(t.child.as_str()),
            t.stamp,
            t.parent_from_child,
            is_static,
        );
    }
    let Some(start) = start else {
        return Err(tf_err(format!("no messages for topic {}", id.topic)));
    };
    buffer.finish();
    let (parent, child) = (frame(&id.parent), frame(&id.child));
    let times = match buffer.latest_common_time(parent, child) {
        Some(latest) => grid(start, latest).ok_or_else(|| {
            tf_err(format!(
                "the transforms span {:.0} s: more than {} lookups at 10 Hz",
                (latest - start).as_secs_f64(),
                super::tf::MAX_SAMPLES
            ))
        })?,
        // A chain of static transforms only: tf2 answers time zero with them.
        None => vec![Nanos(0)],
    };
    let mut stamps = Vec::with_capacity(times.len());
    let mut poses = Vec::with_capacity(times.len());
    for t in times {
        match buffer.lookup(parent, child, t) {
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
