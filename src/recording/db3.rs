//! rosbag2 folders with sqlite3 storage (`metadata.yaml` beside one or more `.db3` files),
//! read as a ROS 2 recording: each `.db3` (in name order, as rosbag2 splits them) is
//! opened read-only and its messages come in time order with their topic's type and
//! serialization format. The bundled SQLite bounds what a damaged file can do; its errors
//! name the file.

use super::RecordingError;
use super::reader::{ChannelInfo, McapSummary, RawMessage};
use rusqlite::{Connection, OpenFlags};
use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;
use vinebench_msgs::Nanos;

/// Every message of the `.db3` files `files` (a rosbag2 folder's), in order.
pub fn scan<F>(
    files: &[std::path::PathBuf],
    mut on_message: F,
) -> Result<McapSummary, RecordingError>
where
    F: FnMut(&ChannelInfo, &RawMessage<'_>),
{
    let mut summary = McapSummary {
        profile: "ros2".into(),
        library: "rosbag2 (sqlite3 storage)".into(),
        ..McapSummary::default()
    };
    // Channels by topic name across the files (ids are per file).
    let mut by_name: HashMap<String, Arc<ChannelInfo>> = HashMap::new();
    for file in files {
        let name = file.display().to_string();
        let err = |e: rusqlite::Error| RecordingError::Unusable {
            path: name.clone(),
            problem: format!("not a readable rosbag2 sqlite3 file: {e}"),
        };
        summary.file_bytes += std::fs::metadata(file).map(|m| m.len()).unwrap_or(0);
        let db = Connection::open_with_flags(
            file,
            OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )
        .map_err(err)?;
        let mut topics: HashMap<i64, Arc<ChannelInfo>> = HashMap::new();
        {
            let mut q = db
                .prepare("SELECT id, name, type, serialization_format FROM topics")
                .map_err(err)?;
            let rows = q
                .query_map([], |r| {
                    Ok((
                        r.get::<_, i64>(0)?,
                        r.get::<_, String>(1)?,
                        r.get::<_, String>(2)?,
                        r.get::<_, String>(3)?,
                    ))
                })
                .map_err(err)?;
            for row in rows {
                let (id, topic, ty, format) = row.map_err(err)?;
                let n = by_name.len();
                let info = by_name
                    .entry(topic.clone())
                    .or_insert_with(|| {
                        Arc::new(ChannelInfo {
                            id: u16::try_from(n).unwrap_or(u16::MAX),
                            topic,
                            message_encoding: format,
                            schema_name: ty,
                            schema_encoding: "ros2msg".into(),
                        })
                    })
                    .clone();
                topics.insert(id, info);
            }
        }
        if by_name.len() > usize::from(u16::MAX) {
            return Err(RecordingError::Unusable {
                path: name,
                problem: "more than 65535 topics".into(),
            });
        }
        let mut q = db
            .prepare("SELECT topic_id, timestamp, data FROM messages ORDER BY timestamp, id")
            .map_err(err)?;
        let mut rows = q.query([]).map_err(err)?;
        let mut sequence = 0u32;
        while let Some(row) = rows.next().map_err(err)? {
            let topic_id: i64 = row.get(0).map_err(err)?;
            let stamp: i64 = row.get(1).map_err(err)?;
            let data =
                row.get_ref(2)
                    .map_err(err)?
                    .as_blob()
                    .map_err(|e| RecordingError::Unusable {
                        path: name.clone(),
                        problem: format!("a message's data is not a blob: {e}"),
                    })?;
            let Some(info) = topics.get(&topic_id) else {
                let d = summary.damage.get_or_insert_with(Default::default);
                d.orphan_messages += 1;
                continue;
            };
            summary.deliver_unverified(&mut sequence, info, Nanos(stamp), data, &mut on_message);
        }
    }
    summary.channels = by_name.into_values().map(|c| (c.id, c)).collect();
    Ok(summary)
}

/// Whether `path` is an SQLite database (by its first bytes).
pub fn is_sqlite(path: &Path) -> bool {
    super::starts_with(path, b"SQLite format 3\0")
}
