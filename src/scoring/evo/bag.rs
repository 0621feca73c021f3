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
    let entries = std::fs::read_dir(path).map_err(|source| {
        crate::recording::RecordingError::Io {
            path: path.display().to_string(),
            source,
        }
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

/// The trajectory of `topic` in the recording at `path`.
pub fn read_topic(path: &Path, topic: &str) -> Result<Traj, BagError> {
    let file = mcap_file(path)?;
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
