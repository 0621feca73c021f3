//! Reading an MCAP file front to back, recovering what a damaged one still holds.
//!
//! [`scan`] walks the top-level records itself (opcode, length, body), so it needs no
//! summary section and knows the byte offset of every problem: a file cut short (a run
//! killed, a copy interrupted) yields every complete chunk before the cut; a chunk that
//! fails to decompress or its CRC is skipped by its length and reading goes on. What was
//! lost is reported in [`Damage`]; only a file with no readable start is an error.

use super::RecordingError;
use mcap::read::{ChunkReader, parse_record};
use mcap::records::{Record, op};
use std::collections::{BTreeMap, HashMap};
use std::path::Path;
use std::sync::Arc;
use vinebench_msgs::Nanos;

/// The 8 bytes that open and close an MCAP file.
pub const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

/// A channel (topic) of a recording.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ChannelInfo {
    /// Channel id in the file.
    pub id: u16,
    /// Topic name.
    pub topic: String,
    /// Message encoding (`cdr` for ROS 2).
    pub message_encoding: String,
    /// Schema name (`sensor_msgs/msg/Imu`); empty when the channel has no schema.
    pub schema_name: String,
    /// Schema encoding (`ros2msg`, `ros2idl`, ...).
    pub schema_encoding: String,
}

/// One message as stored: the payload is borrowed from the decompressed chunk.
#[derive(Debug)]
pub struct RawMessage<'a> {
    /// Per-channel sequence number.
    pub sequence: u32,
    /// Log time (vinebench: the stamp).
    pub log_time: Nanos,
    /// Publish time (vinebench: the arrival at the estimators).
    pub publish_time: Nanos,
    /// The encoded message.
    pub data: &'a [u8],
}

/// What a damaged file lost.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Damage {
    /// Each problem, with its byte offset.
    pub problems: Vec<String>,
    /// Chunks that could not be read (or only in part).
    pub chunks_lost: u64,
    /// Bytes at the end that were not read (a truncated file).
    pub bytes_unread: u64,
    /// True when the file has no footer (it was not finalized or was cut short).
    pub summary_missing: bool,
    /// Messages the summary says the file holds, when it has one.
    pub expected_messages: Option<u64>,
    /// Messages on channels whose definition was lost.
    pub orphan_messages: u64,
}

impl std::fmt::Display for Damage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut parts = Vec::new();
        if self.summary_missing {
            parts.push("no summary (the file was not finalized or was cut short)".to_string());
        }
        if self.bytes_unread > 0 {
            parts.push(format!("{} bytes at the end unreadable", self.bytes_unread));
        }
        if self.chunks_lost > 0 {
            parts.push(format!("{} chunk(s) lost", self.chunks_lost));
        }
        if self.orphan_messages > 0 {
            parts.push(format!(
                "{} message(s) on channels whose definition was lost",
                self.orphan_messages
            ));
        }
        parts.extend(self.problems.iter().cloned());
        f.write_str(&parts.join("; "))
    }
}

/// What [`scan`] found besides the messages.
#[derive(Clone, Debug, Default)]
pub struct McapSummary {
    /// The header's profile (`ros2`).
    pub profile: String,
    /// The header's library (the writer).
    pub library: String,
    /// Metadata records by name.
    pub metadata: BTreeMap<String, BTreeMap<String, String>>,
    /// Channels by id.
    pub channels: BTreeMap<u16, Arc<ChannelInfo>>,
    /// Messages delivered.
    pub messages: u64,
    /// Messages delivered per topic.
    pub messages_per_topic: BTreeMap<String, u64>,
    /// Chunks read.
    pub chunks: u64,
    /// File size, bytes.
    pub file_bytes: u64,
    /// What was lost; `None` for an intact file.
    pub damage: Option<Damage>,
}

struct Scanner<F> {
    schemas: HashMap<u16, (String, String)>,
    summary: McapSummary,
    damage: Damage,
    on_message: F,
}

impl<F: FnMut(&ChannelInfo, &RawMessage<'_>)> Scanner<F> {
    fn record(&mut self, rec: Record<'_>, at: usize) {
        match rec {
            Record::Header(h) => {
                self.summary.profile = h.profile;
                self.summary.library = h.library;
            }
            Record::Schema { header, .. } => {
                self.schemas
                    .insert(header.id, (header.name, header.encoding));
            }
            Record::Channel(c) => {
                let (schema_name, schema_encoding) =
                    self.schemas.get(&c.schema_id).cloned().unwrap_or_default();
                self.summary.channels.insert(
                    c.id,
                    Arc::new(ChannelInfo {
                        id: c.id,
                        topic: c.topic,
                        message_encoding: c.message_encoding,
                        schema_name,
                        schema_encoding,
                    }),
                );
            }
            Record::Message { header, data } => {
                let Some(ch) = self.summary.channels.get(&header.channel_id).cloned() else {
                    self.damage.orphan_messages += 1;
                    return;
                };
                let time = |t: u64| Nanos(i64::try_from(t).unwrap_or(i64::MAX));
                let m = RawMessage {
                    sequence: header.sequence,
                    log_time: time(header.log_time),
                    publish_time: time(header.publish_time),
                    data: &data,
                };
                (self.on_message)(&ch, &m);
                self.summary.messages += 1;
                match self.summary.messages_per_topic.get_mut(&ch.topic) {
                    Some(n) => *n += 1,
                    None => {
                        self.summary.messages_per_topic.insert(ch.topic.clone(), 1);
                    }
                }
            }
            Record::Chunk { header, data } => {
                self.summary.chunks += 1;
                let reader = match ChunkReader::new(header, &data) {
                    Ok(r) => r,
                    Err(e) => {
                        self.chunk_lost(at, &e.to_string());
                        return;
                    }
                };
                for r in reader {
                    match r {
                        Ok(rec) => self.record(rec, at),
                        Err(e) => {
                            self.chunk_lost(at, &e.to_string());
                            return;
                        }
                    }
                }
            }
            Record::Metadata(m) => {
                self.summary.metadata.insert(m.name, m.metadata);
            }
            Record::Statistics(s) => self.damage.expected_messages = Some(s.message_count),
            _ => {}
        }
    }

    fn chunk_lost(&mut self, at: usize, why: &str) {
        self.damage.chunks_lost += 1;
        self.damage
            .problems
            .push(format!("chunk at byte {at}: {why}"));
    }
}

/// Reads every message of an MCAP file in file order, calling `on_message` for each;
/// returns channels, metadata and what was lost. Errors only when the bytes are not an
/// MCAP file at all.
pub fn scan<F>(bytes: &[u8], on_message: F) -> Result<McapSummary, RecordingError>
where
    F: FnMut(&ChannelInfo, &RawMessage<'_>),
{
    if bytes.len() < MAGIC.len() || &bytes[..MAGIC.len()] != MAGIC {
        return Err(RecordingError::Unusable {
            path: String::new(),
            problem: format!(
                "not an MCAP file: starts with {:02x?}, expected the MCAP magic {MAGIC:02x?}",
                &bytes[..bytes.len().min(8)]
            ),
        });
    }
    let mut s = Scanner {
        schemas: HashMap::new(),
        summary: McapSummary {
            file_bytes: bytes.len() as u64,
            ..McapSummary::default()
        },
        damage: Damage::default(),
        on_message,
    };
    let mut pos = MAGIC.len();
    let mut footer = false;
    while pos < bytes.len() {
        let rest = bytes.len() - pos;
        if rest < 9 {
            s.damage.bytes_unread = rest as u64;
            s.damage.problems.push(format!(
                "file ends at byte {} inside a record header",
                bytes.len()
            ));
            break;
        }
        let opcode = bytes[pos];
        let mut len = [0u8; 8];
        len.copy_from_slice(&bytes[pos + 1..pos + 9]);
        let len = u64::from_le_bytes(len);
        let body_start = pos + 9;
        if len > (bytes.len() - body_start) as u64 {
            s.damage.bytes_unread = rest as u64;
            if opcode == op::CHUNK {
                s.damage.chunks_lost += 1;
            }
            s.damage.problems.push(format!(
                "file ends at byte {} inside a record (opcode {opcode:#04x}) that starts at \
                 byte {pos} and needs {len} bytes",
                bytes.len()
            ));
            break;
        }
        let body = &bytes[body_start..body_start + len as usize];
        match parse_record(opcode, body) {
            Ok(Record::Footer(_)) => {
                footer = true;
                break;
            }
            Ok(rec) => s.record(rec, pos),
            Err(e) => {
                if opcode == op::CHUNK {
                    s.chunk_lost(pos, &e.to_string());
                } else {
                    s.damage
                        .problems
                        .push(format!("record at byte {pos} (opcode {opcode:#04x}): {e}"));
                }
            }
        }
        pos = body_start + len as usize;
    }
    s.damage.summary_missing = !footer;
    let mut summary = s.summary;
    let d = s.damage;
    if let Some(n) = d.expected_messages
        && n > summary.messages + d.orphan_messages
    {
        summary.damage = Some(Damage {
            problems: [
                d.problems.clone(),
                vec![format!(
                    "{} of {n} messages lost",
                    n - summary.messages - d.orphan_messages
                )],
            ]
            .concat(),
            ..d
        });
    } else if d.summary_missing
        || d.chunks_lost > 0
        || d.bytes_unread > 0
        || d.orphan_messages > 0
        || !d.problems.is_empty()
    {
        summary.damage = Some(d);
    }
    Ok(summary)
}

/// [`scan`] of a file; errors name the file.
pub fn scan_file<F>(path: &Path, on_message: F) -> Result<McapSummary, RecordingError>
where
    F: FnMut(&ChannelInfo, &RawMessage<'_>),
{
    let bytes = std::fs::read(path).map_err(|source| RecordingError::Io {
        path: path.display().to_string(),
        source,
    })?;
    scan(&bytes, on_message).map_err(|e| match e {
        RecordingError::Unusable { problem, .. } => RecordingError::Unusable {
            path: path.display().to_string(),
            problem,
        },
        e => e.in_file(&path.display().to_string()),
    })
}
