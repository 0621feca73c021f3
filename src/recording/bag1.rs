//! ROS 1 bag files (format 2.0, <http://wiki.ros.org/Bags/Format/2.0>), read record by
//! record: the bag header, chunks (uncompressed, `bz2` or `lz4`) with the connection and
//! message records inside, and the index records after them (skipped: the messages are
//! read from the chunks, in file order). Every length is checked against what is left of
//! the file or the chunk, and a chunk's uncompressed size against [`MAX_CHUNK_BYTES`], so
//! a damaged or hostile file is an error naming the byte offset, never a huge allocation.
//! Messages come out in file order with their record times.
//!
//! [`scan_as_cdr`] turns the messages into ROS 2 CDR ([`super::ros1`]), so that a ROS 1
//! bag reads like a ROS 2 recording.

use std::collections::HashMap;
use std::io::Read;
use std::path::Path;
use vinebench_msgs::Nanos;

/// Largest uncompressed chunk accepted.
pub const MAX_CHUNK_BYTES: u64 = 1 << 30;
/// Largest record header accepted.
const MAX_HEADER_BYTES: u32 = 1 << 20;
const MAGIC: &[u8] = b"#ROSBAG V2.0\n";

/// Why a bag could not be read.
#[derive(Debug, thiserror::Error)]
pub enum Bag1Error {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// Not a ROS 1 bag, or damaged.
    #[error("{path}: {problem}")]
    Format {
        /// The file.
        path: String,
        /// What is wrong, with the byte offset.
        problem: String,
    },
}

/// A connection (topic) of a bag.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Connection {
    /// Connection id.
    pub id: u32,
    /// Topic.
    pub topic: String,
    /// Message type (`geometry_msgs/PoseStamped`).
    pub msg_type: String,
    /// The full message definition (`message_definition`), nested types included.
    pub definition: String,
}

/// The fields of a record header.
fn fields(h: &[u8]) -> Option<HashMap<&str, &[u8]>> {
    let mut out = HashMap::new();
    let mut rest = h;
    while !rest.is_empty() {
        let len = u32::from_le_bytes(rest.get(..4)?.try_into().ok()?) as usize;
        let f = rest.get(4..4usize.checked_add(len)?)?;
        rest = &rest[4 + len..];
        let eq = f.iter().position(|&b| b == b'=')?;
        out.insert(std::str::from_utf8(&f[..eq]).ok()?, &f[eq + 1..]);
    }
    Some(out)
}

fn u32_field(f: &HashMap<&str, &[u8]>, k: &str) -> Option<u32> {
    Some(u32::from_le_bytes(f.get(k)?.get(..4)?.try_into().ok()?))
}

fn time_field(f: &HashMap<&str, &[u8]>, k: &str) -> Option<Nanos> {
    let v = f.get(k)?;
    let sec = u32::from_le_bytes(v.get(..4)?.try_into().ok()?);
    let nsec = u32::from_le_bytes(v.get(4..8)?.try_into().ok()?);
    Some(Nanos(i64::from(sec) * 1_000_000_000 + i64::from(nsec)))
}

fn str_field(f: &HashMap<&str, &[u8]>, k: &str) -> Option<String> {
    Some(String::from_utf8_lossy(f.get(k)?).into_owned())
}

/// Records of a byte slice: `(offset, header, data)`.
fn records(bytes: &[u8], base: u64) -> impl Iterator<Item = Result<(u64, &[u8], &[u8]), String>> {
    let mut pos = 0usize;
    std::iter::from_fn(move || {
        if pos >= bytes.len() {
            return None;
        }
        let at = base + pos as u64;
        let read_u32 = |p: usize| -> Option<u32> {
            Some(u32::from_le_bytes(bytes.get(p..p + 4)?.try_into().ok()?))
        };
        let r = (|| {
            let hl = read_u32(pos).ok_or("record header length cut off")?;
            if hl > MAX_HEADER_BYTES {
                return Err(format!("record header of {hl} bytes"));
            }
            let h0 = pos + 4;
            let h1 = h0 + hl as usize;
            let header = bytes.get(h0..h1).ok_or("record header cut off")?;
            let dl = read_u32(h1).ok_or("record data length cut off")? as usize;
            let data = bytes.get(h1 + 4..h1 + 4 + dl).ok_or_else(|| {
                format!(
                    "record data of {dl} bytes, {} left",
                    bytes.len().saturating_sub(h1 + 4)
                )
            })?;
            pos = h1 + 4 + dl;
            Ok((at, header, data))
        })();
        if r.is_err() {
            pos = bytes.len();
        }
        Some(r.map_err(|e: String| format!("at byte {at}: {e}")))
    })
}

/// Reads a bag record by record in file order (records not needed are skipped, so memory
/// holds one chunk), calling `on_message` with each message of a connection `keep`
/// accepts; returns the connections.
pub fn scan(
    path: &Path,
    keep: impl Fn(&Connection) -> bool,
    mut on_message: impl FnMut(&Connection, Nanos, &[u8]),
) -> Result<HashMap<u32, Connection>, Bag1Error> {
    use std::io::{BufReader, Seek, SeekFrom};
    let name = path.display().to_string();
    let io = |source| Bag1Error::Io {
        path: name.clone(),
        source,
    };
    let err = |problem: String| Bag1Error::Format {
        path: name.clone(),
        problem,
    };
    let file = std::fs::File::open(path).map_err(io)?;
    let len = file.metadata().map_err(io)?.len();
    let mut r = BufReader::new(file);
    let mut magic = [0u8; 13];
    let got = r.read(&mut magic).map_err(io)?;
    if got < MAGIC.len() || magic != MAGIC {
        return Err(err(format!(
            "not a ROS 1 bag (format 2.0): it starts with {:?}, expected \"#ROSBAG V2.0\"",
            String::from_utf8_lossy(&magic[..got])
        )));
    }
    let mut connections: HashMap<u32, Connection> = HashMap::new();
    let mut kept: HashMap<u32, bool> = HashMap::new();
    let mut chunk = Vec::new();
    let mut data = Vec::new();
    let mut pos = MAGIC.len() as u64;
    let mut on_record = |connections: &mut HashMap<u32, Connection>,
                         kept: &mut HashMap<u32, bool>,
                         at: u64,
                         f: &HashMap<&str, &[u8]>,
                         data: &[u8]|
     -> Result<(), String> {
        match f.get("op").and_then(|o| o.first()) {
            Some(0x07) => {
                let id =
                    u32_field(f, "conn").ok_or(format!("at byte {at}: connection without conn"))?;
                let topic = str_field(f, "topic").unwrap_or_default();
                let inner = fields(data).ok_or(format!("at byte {at}: bad connection header"))?;
                let msg_type = str_field(&inner, "type").unwrap_or_default();
                let definition = str_field(&inner, "message_definition").unwrap_or_default();
                let c = Connection {
                    id,
                    topic,
                    msg_type,
                    definition,
                };
                kept.insert(id, keep(&c));
                connections.insert(id, c);
            }
            Some(0x02) => {
                let conn =
                    u32_field(f, "conn").ok_or(format!("at byte {at}: message without conn"))?;
                let time =
                    time_field(f, "time").ok_or(format!("at byte {at}: message without time"))?;
                if kept.get(&conn).copied().unwrap_or(false)
                    && let Some(c) = connections.get(&conn)
                {
                    on_message(c, time, data);
                }
            }
            _ => {}
        }
        Ok(())
    };
    while pos < len {
        let at = pos;
        let mut word = [0u8; 4];
        let cut = |what: &str| {
            err(format!(
                "at byte {at}: {what} cut off (the file ends at byte {len})"
            ))
        };
        r.read_exact(&mut word)
            .map_err(|_| cut("record header length"))?;
        let hl = u64::from(u32::from_le_bytes(word));
        if hl > u64::from(MAX_HEADER_BYTES) || pos + 8 + hl > len {
            return Err(err(format!("at byte {at}: a record header of {hl} bytes")));
        }
        let mut header = vec![0u8; hl as usize];
        r.read_exact(&mut header)
            .map_err(|_| cut("record header"))?;
        r.read_exact(&mut word)
            .map_err(|_| cut("record data length"))?;
        let dl = u64::from(u32::from_le_bytes(word));
        if pos + 8 + hl + dl > len {
            return Err(cut(&format!("record data of {dl} bytes")));
        }
        pos += 8 + hl + dl;
        let f = fields(&header).ok_or_else(|| err(format!("at byte {at}: bad record header")))?;
        let op = f.get("op").and_then(|o| o.first()).copied();
        if !matches!(op, Some(0x02 | 0x05 | 0x07)) {
            // Bag header, index and chunk-info records: not needed.
            r.seek(SeekFrom::Start(pos)).map_err(io)?;
            continue;
        }
        if dl > MAX_CHUNK_BYTES {
            return Err(err(format!(
                "at byte {at}: a record of {dl} bytes (at most {MAX_CHUNK_BYTES})"
            )));
        }
        data.clear();
        (&mut r).take(dl).read_to_end(&mut data).map_err(io)?;
        if op != Some(0x05) {
            on_record(&mut connections, &mut kept, at, &f, &data).map_err(&err)?;
            continue;
        }
        let compression = str_field(&f, "compression").unwrap_or_default();
        let size = u64::from(u32_field(&f, "size").unwrap_or(0));
        if size > MAX_CHUNK_BYTES {
            return Err(err(format!(
                "at byte {at}: a chunk of {size} bytes uncompressed (at most {MAX_CHUNK_BYTES})"
            )));
        }
        chunk.clear();
        let inner: &[u8] = match compression.as_str() {
            "none" => &data,
            "bz2" | "lz4" => {
                let take = size + 1;
                let res = if compression == "bz2" {
                    bzip2::read::BzDecoder::new(&data[..])
                        .take(take)
                        .read_to_end(&mut chunk)
                } else {
                    lz4::Decoder::new(&data[..]).and_then(|d| d.take(take).read_to_end(&mut chunk))
                };
                res.map_err(|e| err(format!("at byte {at}: {compression} chunk: {e}")))?;
                if chunk.len() as u64 != size {
                    return Err(err(format!(
                        "at byte {at}: {compression} chunk gives {} bytes, its header says {size}",
                        chunk.len()
                    )));
                }
                &chunk
            }
            other => {
                return Err(err(format!(
                    "at byte {at}: chunk compression {other:?} (expected none, bz2 or lz4)"
                )));
            }
        };
        for ir in records(inner, 0) {
            let (iat, ih, id) = ir.map_err(|e| err(format!("in the chunk at byte {at}, {e}")))?;
            let fi = fields(ih).ok_or_else(|| {
                err(format!(
                    "in the chunk at byte {at}, at byte {iat}: bad record header"
                ))
            })?;
            on_record(&mut connections, &mut kept, iat, &fi, id)
                .map_err(|e| err(format!("in the chunk at byte {at}, {e}")))?;
        }
    }
    Ok(connections)
}

/// Most transcoding problems listed in a scan's damage report (the rest are counted).
const MAX_LISTED: usize = 20;

/// [`scan`] as a ROS 2 recording: each connection becomes a CDR channel of its ROS 2 type
/// name, each message is transcoded ([`super::ros1::Definitions`]) and delivered with its
/// record time as log and publish time (what the robot's recorder saw: the arrival). A
/// message that its definition does not describe is left out and listed in the summary's
/// damage. This is how `vinebench replay` and `vinebench score bag` read ROS 1 bags.
pub fn scan_as_cdr<F>(
    path: &Path,
    mut on_message: F,
) -> Result<super::reader::McapSummary, super::RecordingError>
where
    F: FnMut(&super::reader::ChannelInfo, &super::reader::RawMessage<'_>),
{
    use super::reader::{ChannelInfo, Damage, McapSummary};
    use std::sync::Arc;
    let mut channels: HashMap<u32, (Arc<ChannelInfo>, Result<super::ros1::Definitions, String>)> =
        HashMap::new();
    let mut summary = McapSummary {
        profile: "ros1".into(),
        library: "rosbag (ROS 1 bag 2.0)".into(),
        file_bytes: std::fs::metadata(path).map(|m| m.len()).unwrap_or(0),
        ..McapSummary::default()
    };
    let mut damage = Damage::default();
    let mut sequence = 0u32;
    let mut too_many = false;
    let result = scan(
        path,
        |_| true,
        |c, time, data| {
            let n = channels.len();
            let (info, defs) = channels.entry(c.id).or_insert_with(|| {
                let id = u16::try_from(n).unwrap_or(u16::MAX);
                too_many |= n > usize::from(u16::MAX);
                let info = Arc::new(ChannelInfo {
                    id,
                    topic: c.topic.clone(),
                    message_encoding: "cdr".into(),
                    schema_name: super::ros1::ros2_type_name(&c.msg_type),
                    schema_encoding: "ros1msg".into(),
                });
                (
                    info,
                    super::ros1::Definitions::parse(&c.msg_type, &c.definition),
                )
            });
            let cdr = defs
                .as_ref()
                .map_err(Clone::clone)
                .and_then(|d| d.transcode(data));
            match cdr {
                Ok(cdr) => {
                    summary.deliver_unverified(&mut sequence, info, time, &cdr, &mut on_message)
                }
                Err(e) => {
                    if damage.problems.len() < MAX_LISTED {
                        damage.problems.push(format!(
                            "{} ({}) at record time {time}: {e}",
                            info.topic, c.msg_type
                        ));
                    } else {
                        damage.problems_not_listed += 1;
                    }
                    damage.messages_lost = Some(damage.messages_lost.unwrap_or(0) + 1);
                }
            }
        },
    );
    let name = path.display().to_string();
    result.map_err(|e| match e {
        Bag1Error::Io { source, .. } => super::RecordingError::Io {
            path: name.clone(),
            source,
        },
        Bag1Error::Format { problem, .. } => super::RecordingError::Unusable {
            path: name.clone(),
            problem,
        },
    })?;
    if too_many {
        return Err(super::RecordingError::Unusable {
            path: name,
            problem: "more than 65536 connections".into(),
        });
    }
    summary.channels = channels
        .into_values()
        .map(|(info, _)| (info.id, info))
        .collect();
    if damage != Damage::default() {
        summary.damage = Some(damage);
    }
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn field(k: &str, v: &[u8]) -> Vec<u8> {
        let mut f = k.as_bytes().to_vec();
        f.push(b'=');
        f.extend_from_slice(v);
        let mut out = (f.len() as u32).to_le_bytes().to_vec();
        out.extend(f);
        out
    }

    fn record(header: &[Vec<u8>], data: &[u8]) -> Vec<u8> {
        let h: Vec<u8> = header.concat();
        let mut out = (h.len() as u32).to_le_bytes().to_vec();
        out.extend(h);
        out.extend((data.len() as u32).to_le_bytes());
        out.extend_from_slice(data);
        out
    }

    /// A bag with one connection and two messages (written out of time order), in a
    /// chunk compressed with `compression`.
    fn bag(compression: &str) -> Vec<u8> {
        let conn = record(
            &[
                field("op", &[7]),
                field("conn", &0u32.to_le_bytes()),
                field("topic", b"/pose"),
            ],
            &[
                field("type", b"geometry_msgs/PoseStamped"),
                field("md5sum", b"x"),
            ]
            .concat(),
        );
        let msg = |t: u32, v: u8| {
            let mut time = t.to_le_bytes().to_vec();
            time.extend(0u32.to_le_bytes());
            record(
                &[
                    field("op", &[2]),
                    field("conn", &0u32.to_le_bytes()),
                    field("time", &time),
                ],
                &[v],
            )
        };
        let inner = [conn, msg(20, 2), msg(10, 1)].concat();
        let data = match compression {
            "bz2" => {
                let mut e = bzip2::read::BzEncoder::new(&inner[..], bzip2::Compression::fast());
                let mut out = Vec::new();
                e.read_to_end(&mut out).unwrap();
                out
            }
            _ => inner.clone(),
        };
        let chunk = record(
            &[
                field("op", &[5]),
                field("compression", compression.as_bytes()),
                field("size", &(inner.len() as u32).to_le_bytes()),
            ],
            &data,
        );
        [MAGIC.to_vec(), chunk].concat()
    }

    #[test]
    fn chunks_plain_and_bz2_give_the_messages_in_file_order() {
        for c in ["none", "bz2"] {
            let f = tempfile::NamedTempFile::new().unwrap();
            std::fs::write(f.path(), bag(c)).unwrap();
            let mut got = Vec::new();
            let conns = scan(f.path(), |_| true, |_, t, d| got.push((t.0, d[0]))).unwrap();
            assert_eq!(conns[&0].msg_type, "geometry_msgs/PoseStamped");
            assert_eq!(got, vec![(20_000_000_000, 2), (10_000_000_000, 1)], "{c}");
        }
    }

    #[test]
    fn damage_is_an_error_with_the_offset() {
        let mut b = bag("none");
        let n = b.len();
        b.truncate(n - 3);
        let f = tempfile::NamedTempFile::new().unwrap();
        std::fs::write(f.path(), &b).unwrap();
        let e = scan(f.path(), |_| true, |_, _, _| {})
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("at byte 13") && e.contains("cut off") || e.contains("left"),
            "{e}"
        );
        std::fs::write(f.path(), b"#ROSBAG V1.2\nxx").unwrap();
        let e = scan(f.path(), |_| true, |_, _, _| {})
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a ROS 1 bag"), "{e}");
    }
}
