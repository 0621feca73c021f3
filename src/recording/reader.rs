//! Reading an MCAP file front to back, recovering what a damaged one still holds.
//!
//! [`scan`] / [`scan_file`] walk the top-level records themselves (opcode, length, body)
//! through a window of [`WINDOW_BYTES`], so memory does not grow with the file and the byte
//! offset of every problem is known. Nothing a file says is trusted before it is checked:
//!
//! - every length is checked against the bytes left in the file and a stated limit
//!   ([`MAX_CHUNK_BYTES`], [`MAX_RECORD_BYTES`]) before anything is allocated for it, and
//!   every string or map inside a record against the record's own length;
//! - a chunk's claimed uncompressed size must be at most [`MAX_CHUNK_BYTES`] and at most
//!   what its compression can make of its compressed bytes ([`ZSTD_MAX_RATIO`],
//!   [`LZ4_MAX_RATIO`]); the chunk is decompressed here into a buffer of exactly that
//!   size, and its CRC is checked *before* any of its records is used: a chunk that fails
//!   is dropped whole and reported as a [`LostChunk`] (where, why, how many messages);
//! - the data-section CRC (DataEnd record), the summary CRC, the footer and the end magic
//!   are checked, and what does not match is reported;
//! - a record whose length cannot be right (past the end of the file) or a byte where no
//!   record can start is reported, and reading resumes at the next offset where a
//!   self-checking record (a chunk, a metadata record, ...) starts, so one lying length
//!   field costs one record, not the rest of the file.
//!
//! The summary section, read first when the footer is intact and its CRC matches, supplies
//! the channel definitions a lost chunk took with it, the expected message count, the
//! chunk index and the metadata index. A message is [`RawMessage::verified`] when its bytes
//! and its channel's definition passed a CRC; in a file with CRC-checked chunks, a message
//! record outside them is not used (no CRC covers it: it is misread damage). What was lost
//! is reported in [`Damage`] (at most [`MAX_REPORTED`] entries of each kind, the rest
//! counted); only a file that is not MCAP at all is an error.
//!
//! Memory: the window, one record's body (a chunk: at most [`MAX_CHUNK_BYTES`]), one
//! decompressed chunk (the same bound), the summary (at most [`MAX_RECORD_BYTES`]), and
//! the channels and metadata (at most 65 536 channels with names of [`MAX_NAME_BYTES`],
//! [`MAX_METADATA_RECORDS`] metadata records).

use super::RecordingError;
use mcap::records::op;
use std::collections::{BTreeMap, HashMap};
use std::io::{self, Read, Seek, SeekFrom};
use std::path::Path;
use std::sync::Arc;
use vinebench_msgs::Nanos;

/// The 8 bytes that open and close an MCAP file.
pub const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";
/// The largest chunk read, compressed or uncompressed (bytes, 1 GiB). vinebench writes
/// chunks of `[recording] chunk_size_mb` (at most 512 MiB) plus one message; a chunk that
/// claims more is damage and is skipped unread.
pub const MAX_CHUNK_BYTES: u64 = 1 << 30;
/// The largest record outside chunks read into memory (bytes, 256 MiB): a message,
/// schema, channel or metadata record, and the whole summary section. Larger records of
/// kinds vinebench does not use (attachments) are skipped without reading them in.
pub const MAX_RECORD_BYTES: u64 = 256 << 20;
/// The most bytes zstd can produce from one compressed byte: a 4-byte RLE block gives at
/// most 128 KiB. A chunk claiming more than this times its compressed size is damage.
pub const ZSTD_MAX_RATIO: u64 = 32 * 1024;
/// The most bytes an LZ4 frame can produce from one compressed byte (a match-length byte
/// adds at most 255).
pub const LZ4_MAX_RATIO: u64 = 256;
/// The longest name read: a topic, message encoding, schema name or encoding, metadata
/// record name (bytes; ROS names are far shorter). A longer one is damage.
pub const MAX_NAME_BYTES: u32 = 1024;
/// Metadata records kept (distinct names; vinebench writes two).
pub const MAX_METADATA_RECORDS: usize = 1024;
/// Problems, lost chunks and lost metadata described one by one in a [`Damage`]; the rest
/// are counted, so a file of a million broken records gives a report of bounded size.
pub const MAX_REPORTED: usize = 64;
/// Bytes read from the file at a time outside chunk bodies.
pub const WINDOW_BYTES: usize = 1 << 20;
/// Bytes ahead of an offset that resynchronization judges a candidate record on.
const LOOKAHEAD: usize = 64 * 1024 + 9;
/// Opcode, length, and the footer's three fields.
const FOOTER_RECORD: u64 = 9 + 20;

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
    /// True when the message's bytes and its channel's definition passed a CRC (its
    /// chunk's, the summary's). False for a chunk or summary written without CRCs and for
    /// messages outside chunks (covered only by the data-section CRC, known at the end).
    pub verified: bool,
}

/// A chunk whose messages were not used.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LostChunk {
    /// Byte offset of the chunk record.
    pub offset: u64,
    /// Its length in the file (opcode and length field included), as far as known.
    pub bytes: u64,
    /// Log times of its first and last message, when its header was readable.
    pub log_times: Option<(Nanos, Nanos)>,
    /// Why it was not used.
    pub reason: String,
    /// Messages it held by topic (from the message indexes after it), when known.
    pub messages: BTreeMap<String, u64>,
}

impl LostChunk {
    /// Messages it held, when the message indexes after it were readable.
    pub fn message_count(&self) -> Option<u64> {
        (!self.messages.is_empty()).then(|| self.messages.values().sum())
    }
}

impl std::fmt::Display for LostChunk {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "chunk at byte {} ({} bytes", self.offset, self.bytes)?;
        if let Some((a, b)) = self.log_times {
            write!(
                f,
                ", log times {:.3}..{:.3} s",
                a.as_secs_f64(),
                b.as_secs_f64()
            )?;
        }
        write!(f, ") lost: {}", self.reason)?;
        if let Some(n) = self.message_count() {
            let topics: Vec<String> = self
                .messages
                .iter()
                .map(|(t, n)| format!("{t} {n}"))
                .collect();
            write!(f, "; {n} message(s): {}", topics.join(", "))?;
        }
        Ok(())
    }
}

/// What a damaged file lost.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Damage {
    /// Each problem, with its byte offset (the first [`MAX_REPORTED`]).
    pub problems: Vec<String>,
    /// Problems beyond the first [`MAX_REPORTED`], counted only.
    pub problems_not_listed: u64,
    /// Chunks that could not be read (or only in part).
    pub chunks_lost: u64,
    /// The chunks lost, where and why (a chunk inside a stretch of skipped bytes is known
    /// only from the summary's chunk index); the first [`MAX_REPORTED`] of
    /// [`Damage::chunks_lost`].
    pub lost_chunks: Vec<LostChunk>,
    /// Messages the message indexes after the lost chunks list (all of them, listed or
    /// not).
    pub messages_in_lost_chunks: u64,
    /// Bytes at the end that were not read (a truncated file).
    pub bytes_unread: u64,
    /// Bytes skipped between records that could not be read (resynchronization).
    pub bytes_skipped: u64,
    /// True when the file has no footer (it was not finalized or was cut short).
    pub summary_missing: bool,
    /// True when the file does not end with the MCAP magic.
    pub end_magic_missing: bool,
    /// True when the data-section CRC (DataEnd record) does not match: bytes were altered
    /// somewhere, possibly in records outside chunks (header, metadata) that no other CRC
    /// covers.
    pub data_crc_mismatch: bool,
    /// True when the header record (profile, library) was unreadable.
    pub header_damaged: bool,
    /// Byte offsets of metadata records that were unreadable.
    pub damaged_metadata: Vec<u64>,
    /// Names of metadata records the summary's index lists that were not read.
    pub lost_metadata: Vec<String>,
    /// Messages the summary says the file holds, when it has one.
    pub expected_messages: Option<u64>,
    /// Messages known lost: the summary's count less those delivered, or else the sum of
    /// the lost chunks' message indexes.
    pub messages_lost: Option<u64>,
    /// Messages on channels whose definition was lost.
    pub orphan_messages: u64,
}

impl Damage {
    fn is_empty(&self) -> bool {
        *self == Damage::default()
    }
}

impl std::fmt::Display for Damage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut parts = Vec::new();
        if self.chunks_lost > 0 {
            parts.push(format!("{} chunk(s) lost", self.chunks_lost));
        }
        match (self.messages_lost, self.expected_messages) {
            (Some(n), Some(of)) => parts.push(format!("{n} of {of} messages lost")),
            (Some(n), None) => parts.push(format!("at least {n} message(s) lost")),
            _ => {}
        }
        if self.bytes_unread > 0 {
            parts.push(format!(
                "cut short: the last {} bytes unreadable",
                self.bytes_unread
            ));
        }
        if self.bytes_skipped > 0 {
            parts.push(format!("{} damaged bytes skipped", self.bytes_skipped));
        }
        if self.header_damaged {
            parts.push("header record damaged".to_string());
        }
        if !self.lost_metadata.is_empty() {
            parts.push(format!("metadata lost: {}", self.lost_metadata.join(", ")));
        }
        if self.summary_missing {
            parts.push("no footer (the file was not finalized or was cut short)".to_string());
        }
        if self.orphan_messages > 0 {
            parts.push(format!(
                "{} message(s) on channels whose definition was lost",
                self.orphan_messages
            ));
        }
        parts.extend(self.lost_chunks.iter().map(LostChunk::to_string));
        if self.chunks_lost > self.lost_chunks.len() as u64 {
            parts.push(format!(
                "{} more chunk(s) lost",
                self.chunks_lost - self.lost_chunks.len() as u64
            ));
        }
        parts.extend(self.problems.iter().cloned());
        if self.problems_not_listed > 0 {
            parts.push(format!("{} more problem(s)", self.problems_not_listed));
        }
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
    /// Messages delivered that no CRC covered ([`RawMessage::verified`] false).
    pub unverified_messages: u64,
    /// Messages delivered per topic.
    pub messages_per_topic: BTreeMap<String, u64>,
    /// Chunks read.
    pub chunks: u64,
    /// File size, bytes.
    pub file_bytes: u64,
    /// Names of the metadata records the summary's index lists (empty without a summary).
    pub metadata_index: Vec<String>,
    /// What was lost; `None` for an intact file.
    pub damage: Option<Damage>,
}

impl McapSummary {
    /// Hands on one message that no CRC covered, stamped `time` (log and publish time
    /// alike), and counts it: how the readers of the other storages, ROS 1 bags and
    /// `.db3`, deliver. `sequence` numbers the file's messages from 1.
    pub fn deliver_unverified<F>(
        &mut self,
        sequence: &mut u32,
        info: &ChannelInfo,
        time: Nanos,
        data: &[u8],
        on_message: &mut F,
    ) where
        F: FnMut(&ChannelInfo, &RawMessage<'_>),
    {
        *sequence = sequence.wrapping_add(1);
        self.messages += 1;
        self.unverified_messages += 1;
        *self
            .messages_per_topic
            .entry(info.topic.clone())
            .or_default() += 1;
        on_message(
            info,
            &RawMessage {
                sequence: *sequence,
                log_time: time,
                publish_time: time,
                data,
                verified: false,
            },
        );
    }
}

// ---- parsing record bodies ----------------------------------------------------------

/// A bounds-checked little-endian cursor over a record body; errors name the field.
struct Cur<'a> {
    b: &'a [u8],
    at: usize,
}

impl<'a> Cur<'a> {
    fn new(b: &'a [u8]) -> Cur<'a> {
        Cur { b, at: 0 }
    }
    fn left(&self) -> usize {
        self.b.len() - self.at
    }
    fn take(&mut self, n: u64, field: &str) -> Result<&'a [u8], String> {
        let left = self.left();
        if n > left as u64 {
            return Err(format!(
                "`{field}` needs {n} bytes, {left} are left in the record"
            ));
        }
        let s = &self.b[self.at..self.at + n as usize];
        self.at += n as usize;
        Ok(s)
    }
    fn array<const N: usize>(&mut self, field: &str) -> Result<[u8; N], String> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N as u64, field)?);
        Ok(a)
    }
    fn u16(&mut self, field: &str) -> Result<u16, String> {
        self.array(field).map(u16::from_le_bytes)
    }
    fn u32(&mut self, field: &str) -> Result<u32, String> {
        self.array(field).map(u32::from_le_bytes)
    }
    fn u64(&mut self, field: &str) -> Result<u64, String> {
        self.array(field).map(u64::from_le_bytes)
    }
    fn string(&mut self, field: &str) -> Result<&'a str, String> {
        let n = self.u32(field)?;
        let s = self.take(u64::from(n), field)?;
        std::str::from_utf8(s).map_err(|_| format!("`{field}` is not UTF-8"))
    }
    /// A string that names something: at most [`MAX_NAME_BYTES`].
    fn name(&mut self, field: &str) -> Result<&'a str, String> {
        let n = self.u32(field)?;
        if n > MAX_NAME_BYTES {
            return Err(format!(
                "`{field}` of {n} bytes, over the limit of {MAX_NAME_BYTES} (MAX_NAME_BYTES)"
            ));
        }
        let s = self.take(u64::from(n), field)?;
        std::str::from_utf8(s).map_err(|_| format!("`{field}` is not UTF-8"))
    }
    fn string_map(&mut self, field: &str) -> Result<BTreeMap<String, String>, String> {
        let n = self.u32(field)?;
        let mut c = Cur::new(self.take(u64::from(n), field)?);
        let mut m = BTreeMap::new();
        while c.left() > 0 {
            let k = c.string(field)?;
            let v = c.string(field)?;
            m.insert(k.to_string(), v.to_string());
        }
        Ok(m)
    }
}

fn le_u64(b: &[u8]) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[..8]);
    u64::from_le_bytes(a)
}

struct ChunkHeader<'a> {
    start: u64,
    end: u64,
    uncompressed_size: u64,
    crc: u32,
    compression: &'a str,
    compressed_size: u64,
    /// Bytes of the body before the compressed data.
    header_len: usize,
}

fn chunk_header(body: &[u8]) -> Result<ChunkHeader<'_>, String> {
    let mut c = Cur::new(body);
    Ok(ChunkHeader {
        start: c.u64("message_start_time")?,
        end: c.u64("message_end_time")?,
        uncompressed_size: c.u64("uncompressed_size")?,
        crc: c.u32("uncompressed_crc")?,
        compression: c.name("compression")?,
        compressed_size: c.u64("compressed_size")?,
        header_len: c.at,
    })
}

struct ChannelRecord<'a> {
    id: u16,
    schema_id: u16,
    topic: &'a str,
    encoding: &'a str,
}

fn channel_record(body: &[u8]) -> Result<ChannelRecord<'_>, String> {
    let mut c = Cur::new(body);
    let r = ChannelRecord {
        id: c.u16("channel id")?,
        schema_id: c.u16("schema id")?,
        topic: c.name("topic")?,
        encoding: c.name("message_encoding")?,
    };
    c.string_map("channel metadata")?;
    Ok(r)
}

fn schema_record(body: &[u8]) -> Result<(u16, &str, &str), String> {
    let mut c = Cur::new(body);
    let id = c.u16("schema id")?;
    let name = c.name("schema name")?;
    let encoding = c.name("schema encoding")?;
    let n = c.u32("schema data")?;
    c.take(u64::from(n), "schema data")?;
    Ok((id, name, encoding))
}

fn metadata_record(body: &[u8]) -> Result<(String, BTreeMap<String, String>, usize), String> {
    let mut c = Cur::new(body);
    let name = c.name("metadata name")?.to_string();
    let map = c.string_map("metadata")?;
    Ok((name, map, c.at))
}

/// What a record of `opcode` is, for reports.
fn kind(opcode: u8) -> String {
    match opcode {
        op::HEADER => "header record".into(),
        op::FOOTER => "footer".into(),
        op::SCHEMA => "schema record".into(),
        op::CHANNEL => "channel record".into(),
        op::MESSAGE => "message record".into(),
        op::CHUNK => "chunk".into(),
        op::MESSAGE_INDEX => "message index".into(),
        op::CHUNK_INDEX => "chunk index".into(),
        op::ATTACHMENT => "attachment".into(),
        op::ATTACHMENT_INDEX => "attachment index".into(),
        op::STATISTICS => "statistics record".into(),
        op::METADATA => "metadata record".into(),
        op::METADATA_INDEX => "metadata index".into(),
        op::SUMMARY_OFFSET => "summary offset".into(),
        op::DATA_END => "DataEnd record".into(),
        _ => format!("record (opcode {opcode:#04x})"),
    }
}

fn time(t: u64) -> Nanos {
    Nanos(i64::try_from(t).unwrap_or(i64::MAX))
}

// ---- the file, a window at a time --------------------------------------------------

/// The file read front to back through a window; every byte consumed goes through the
/// data-section CRC while that is being computed.
struct Source<R> {
    inner: R,
    win: Box<[u8]>,
    start: usize,
    end: usize,
    /// File offset of `win[start]`.
    pos: u64,
    /// File length.
    len: u64,
    crc: Option<crc32fast::Hasher>,
}

impl<R: Read + Seek> Source<R> {
    /// Up to `n` bytes at file offset `at`, leaving the current position as it is.
    fn peek_at(&mut self, at: u64, n: usize) -> io::Result<Vec<u8>> {
        let resume = self.pos + (self.end - self.start) as u64;
        self.inner.seek(SeekFrom::Start(at))?;
        let mut out = Vec::new();
        let n = (n as u64).min(self.len.saturating_sub(at));
        let r = (&mut self.inner).take(n).read_to_end(&mut out);
        self.inner.seek(SeekFrom::Start(resume))?;
        r.map(|_| out)
    }
}

impl<R: Read> Source<R> {
    fn new(inner: R, len: u64) -> Source<R> {
        Source {
            inner,
            win: vec![0u8; WINDOW_BYTES].into_boxed_slice(),
            start: 0,
            end: 0,
            pos: 0,
            len,
            crc: Some(crc32fast::Hasher::new()),
        }
    }

    fn remaining(&self) -> u64 {
        self.len.saturating_sub(self.pos)
    }

    /// Up to `n` bytes (at most [`WINDOW_BYTES`]) from the current offset, not consumed;
    /// fewer only at the end of the file.
    fn peek(&mut self, n: usize) -> io::Result<&[u8]> {
        let want = (n.min(WINDOW_BYTES) as u64).min(self.remaining()) as usize;
        if self.end - self.start < want {
            self.win.copy_within(self.start..self.end, 0);
            self.end -= self.start;
            self.start = 0;
            while self.end < want {
                match self.inner.read(&mut self.win[self.end..want]) {
                    Ok(0) => break,
                    Ok(k) => self.end += k,
                    Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                    Err(e) => return Err(e),
                }
            }
        }
        let n = want.min(self.end - self.start);
        Ok(&self.win[self.start..self.start + n])
    }

    /// Moves on by `n` buffered bytes (see [`Source::peek`]).
    fn consume(&mut self, n: usize) {
        let n = n.min(self.end - self.start);
        if let Some(h) = &mut self.crc {
            h.update(&self.win[self.start..self.start + n]);
        }
        self.start += n;
        self.pos += n as u64;
    }

    /// Reads the next `n` bytes into `out` (the caller has checked `n` against the bytes
    /// left and a limit).
    fn read_into(&mut self, n: u64, out: &mut Vec<u8>) -> io::Result<()> {
        out.clear();
        let n_usize = usize::try_from(n).map_err(io::Error::other)?;
        out.reserve_exact(n_usize);
        let buffered = (self.end - self.start).min(n_usize);
        out.extend_from_slice(&self.win[self.start..self.start + buffered]);
        self.start += buffered;
        let rest = n - buffered as u64;
        if rest > 0 {
            let got = (&mut self.inner).take(rest).read_to_end(out)?;
            if got as u64 != rest {
                return Err(io::Error::new(
                    io::ErrorKind::UnexpectedEof,
                    format!("the file ended {} bytes early", rest - got as u64),
                ));
            }
        }
        if let Some(h) = &mut self.crc {
            h.update(out);
        }
        self.pos += n;
        Ok(())
    }

    /// Moves on by `n` bytes without keeping them.
    fn skip(&mut self, n: u64) -> io::Result<()> {
        let mut left = n;
        while left > 0 {
            let k = self.peek(left.min(WINDOW_BYTES as u64) as usize)?.len();
            if k == 0 {
                break;
            }
            self.consume(k);
            left -= k as u64;
        }
        Ok(())
    }
}

/// Whether a record that checks itself starts at `w[0]` (`rest`: bytes left in the file
/// from there): a chunk whose header adds up to its length, a DataEnd, a message index,
/// a metadata record that parses to exactly its length, the footer before the end magic.
fn candidate(w: &[u8], rest: u64) -> bool {
    if w.len() < 9 || rest < 9 {
        return false;
    }
    let opcode = w[0];
    if !matches!(
        opcode,
        op::CHUNK | op::DATA_END | op::MESSAGE_INDEX | op::METADATA | op::FOOTER
    ) {
        return false;
    }
    let len = le_u64(&w[1..9]);
    if len > rest - 9 {
        return false;
    }
    let body = &w[9..];
    match opcode {
        op::CHUNK => chunk_header(body).is_ok_and(|h| {
            h.header_len as u64 + h.compressed_size == len
                && matches!(h.compression, "" | "zstd" | "lz4")
                && h.uncompressed_size <= MAX_CHUNK_BYTES
                && h.start <= h.end
        }),
        op::DATA_END => len == 4,
        op::MESSAGE_INDEX => {
            body.len() >= 6
                && len >= 6
                && u64::from(u32::from_le_bytes([body[2], body[3], body[4], body[5]])) + 6 == len
                && (len - 6).is_multiple_of(16)
        }
        op::METADATA => {
            (len as usize) <= body.len()
                && metadata_record(&body[..len as usize])
                    .is_ok_and(|(_, _, used)| used == len as usize)
        }
        op::FOOTER => len == 20 && rest == FOOTER_RECORD + 8 && w.get(29..37) == Some(&MAGIC[..]),
        _ => false,
    }
}

/// Moves past the byte at the current offset to the next offset where [`candidate`]
/// holds; `None` when the file ends first (everything consumed).
fn resync<R: Read>(src: &mut Source<R>) -> io::Result<Option<u64>> {
    src.peek(1)?;
    src.consume(1);
    loop {
        let rest = src.remaining();
        if rest == 0 {
            return Ok(None);
        }
        let w = src.peek(WINDOW_BYTES)?;
        let n = w.len();
        if n == 0 {
            return Ok(None);
        }
        let whole = n as u64 >= rest;
        let judged = if whole { n } else { n - LOOKAHEAD.min(n - 1) };
        if let Some(i) = (0..judged).find(|&i| candidate(&w[i..], rest - i as u64)) {
            src.consume(i);
            return Ok(Some(src.pos));
        }
        src.consume(judged);
        if whole {
            return Ok(None);
        }
    }
}

// ---- the summary section, read first -------------------------------------------------

/// What the summary section holds, read before the data section.
#[derive(Default)]
struct SummaryInfo {
    /// Offset of the footer record, when one was found at the end.
    footer_at: Option<u64>,
    /// The CRC matched (a summary without a CRC is used but not trusted as verified).
    verified: bool,
    problem: Option<String>,
    schemas: HashMap<u16, (String, String)>,
    channels: HashMap<u16, Arc<ChannelInfo>>,
    message_count: Option<u64>,
    /// Chunk offsets and lengths.
    chunks: Vec<(u64, u64, Nanos, Nanos)>,
    /// Metadata names and offsets.
    metadata: Vec<(String, u64)>,
}

fn read_summary<R: Read + Seek>(r: &mut R, len: u64) -> io::Result<SummaryInfo> {
    let mut info = SummaryInfo::default();
    let tail_len = FOOTER_RECORD + 8;
    if len < 8 + tail_len {
        return Ok(info);
    }
    r.seek(SeekFrom::Start(len - tail_len))?;
    let mut tail = [0u8; 37];
    r.read_exact(&mut tail)?;
    let is_footer = |b: &[u8]| b[0] == op::FOOTER && le_u64(&b[1..9]) == 20;
    // The footer before the end magic, or (magic cut off) at the very end.
    let (footer_at, f) = if is_footer(&tail[..29]) {
        (len - tail_len, &tail[..29])
    } else if is_footer(&tail[8..]) {
        (len - FOOTER_RECORD, &tail[8..])
    } else {
        return Ok(info);
    };
    info.footer_at = Some(footer_at);
    let summary_start = le_u64(&f[9..17]);
    let crc = u32::from_le_bytes([f[25], f[26], f[27], f[28]]);
    if summary_start == 0 {
        return Ok(info);
    }
    if summary_start < 8
        || summary_start > footer_at
        || footer_at - summary_start > MAX_RECORD_BYTES
    {
        info.problem = Some(format!(
            "the footer at byte {footer_at} puts the summary at byte {summary_start}, outside \
             the file's {len} bytes (or over {MAX_RECORD_BYTES}): summary not used"
        ));
        return Ok(info);
    }
    r.seek(SeekFrom::Start(summary_start))?;
    let mut buf = Vec::new();
    r.by_ref()
        .take(footer_at - summary_start)
        .read_to_end(&mut buf)?;
    if crc != 0 {
        let mut h = crc32fast::Hasher::new();
        h.update(&buf);
        h.update(&f[..25]);
        let got = h.finalize();
        if got != crc {
            info.problem = Some(format!(
                "summary CRC mismatch (stored {crc:#010x}, computed {got:#010x}): the summary \
                 at byte {summary_start} is not used"
            ));
            return Ok(info);
        }
        info.verified = true;
    }
    let mut pos = 0usize;
    let mut channels = Vec::new();
    while pos < buf.len() {
        let at = summary_start + pos as u64;
        if buf.len() - pos < 9 || le_u64(&buf[pos + 1..pos + 9]) > (buf.len() - pos - 9) as u64 {
            info.problem = Some(format!("summary record at byte {at} runs past the footer"));
            break;
        }
        let opcode = buf[pos];
        let n = le_u64(&buf[pos + 1..pos + 9]) as usize;
        let body = &buf[pos + 9..pos + 9 + n];
        pos += 9 + n;
        let mut c = Cur::new(body);
        let parsed: Result<(), String> = (|| {
            match opcode {
                op::SCHEMA => {
                    let (id, name, enc) = schema_record(body)?;
                    info.schemas.insert(id, (name.to_string(), enc.to_string()));
                }
                op::CHANNEL => {
                    let ch = channel_record(body)?;
                    channels.push((
                        ch.id,
                        ch.schema_id,
                        ch.topic.to_string(),
                        ch.encoding.to_string(),
                    ));
                }
                op::STATISTICS => info.message_count = Some(c.u64("message_count")?),
                op::CHUNK_INDEX => {
                    let start = c.u64("message_start_time")?;
                    let end = c.u64("message_end_time")?;
                    let offset = c.u64("chunk_start_offset")?;
                    let length = c.u64("chunk_length")?;
                    info.chunks.push((offset, length, time(start), time(end)));
                }
                op::METADATA_INDEX => {
                    let offset = c.u64("offset")?;
                    c.u64("length")?;
                    info.metadata
                        .push((c.name("metadata name")?.to_string(), offset));
                }
                _ => {}
            }
            Ok(())
        })();
        if let Err(e) = parsed {
            info.problem = Some(format!("summary record at byte {at}: {e}"));
        }
    }
    info.chunks.sort_unstable_by_key(|c| c.0);
    info.metadata.sort_unstable_by_key(|m| m.1);
    for (id, schema_id, topic, message_encoding) in channels {
        let (schema_name, schema_encoding) =
            info.schemas.get(&schema_id).cloned().unwrap_or_default();
        info.channels.insert(
            id,
            Arc::new(ChannelInfo {
                id,
                topic,
                message_encoding,
                schema_name,
                schema_encoding,
            }),
        );
    }
    Ok(info)
}

// ---- the scan ----------------------------------------------------------------------

struct Scanner<F> {
    /// Schemas of the data section: id → (name, encoding, verified).
    schemas: HashMap<u16, (String, String, bool)>,
    /// Channels of the data section and whether a CRC covered their definition.
    channels: HashMap<u16, (Arc<ChannelInfo>, bool)>,
    pre: SummaryInfo,
    summary: McapSummary,
    damage: Damage,
    on_message: F,
    /// The decompressed chunk (kept between chunks).
    chunk_buf: Vec<u8>,
    zstd: Option<zstd::bulk::Decompressor<'static>>,
    /// Index in `damage.lost_chunks` of the chunk just lost: the message indexes after it
    /// say what it held.
    last_lost: Option<usize>,
    /// Whether the chunk just read was lost (listed or not).
    last_chunk_lost: bool,
    /// Entries of the summary's chunk and metadata indexes (sorted by offset) before
    /// these were met or passed.
    chunk_cursor: usize,
    metadata_cursor: usize,
    /// Chunks read that carry a CRC: the file is chunked, and a message record outside
    /// its chunks (no CRC of its own) is not trusted.
    crc_chunks: u64,
}

impl<F: FnMut(&ChannelInfo, &RawMessage<'_>)> Scanner<F> {
    fn problem(&mut self, p: String) {
        if self.damage.problems.len() < MAX_REPORTED {
            self.damage.problems.push(p);
        } else {
            self.damage.problems_not_listed += 1;
        }
    }

    fn lose_chunk(&mut self, chunk: LostChunk) {
        self.seen_chunk(chunk.offset);
        self.push_lost(chunk);
    }

    fn push_lost(&mut self, chunk: LostChunk) {
        self.damage.chunks_lost += 1;
        self.last_chunk_lost = true;
        self.last_lost = None;
        if self.damage.lost_chunks.len() < MAX_REPORTED {
            self.last_lost = Some(self.damage.lost_chunks.len());
            self.damage.lost_chunks.push(chunk);
        }
    }

    /// A chunk met at `offset`: the summary's chunk index entries before it were not.
    fn seen_chunk(&mut self, offset: u64) {
        while let Some(&(o, bytes, t0, t1)) = self.pre.chunks.get(self.chunk_cursor) {
            if o > offset {
                break;
            }
            self.chunk_cursor += 1;
            if o < offset {
                self.push_lost(LostChunk {
                    offset: o,
                    bytes,
                    log_times: Some((t0, t1)),
                    reason: "not found where the summary's chunk index puts it (in bytes \
                             that were skipped or cut off)"
                        .to_string(),
                    ..LostChunk::default()
                });
            }
        }
    }

    /// A metadata record met at `offset` (`read`: and parsed): the summary's metadata
    /// index entries before it, and this one unless read, were lost.
    fn seen_metadata(&mut self, offset: u64, read: bool) {
        while let Some((name, o)) = self.pre.metadata.get(self.metadata_cursor) {
            if *o > offset {
                break;
            }
            if *o < offset || !read {
                let lost = format!("{name} (byte {o})");
                if self.damage.lost_metadata.len() < MAX_REPORTED {
                    self.damage.lost_metadata.push(lost);
                }
            }
            self.metadata_cursor += 1;
        }
    }

    /// A chunk record's body; its messages are delivered only if it decompresses to its
    /// claimed size within the limits and its CRC matches.
    fn chunk(&mut self, at: u64, body: &[u8]) {
        self.summary.chunks += 1;
        self.seen_chunk(at);
        self.last_lost = None;
        self.last_chunk_lost = false;
        let mut lost = LostChunk {
            offset: at,
            bytes: body.len() as u64 + 9,
            ..LostChunk::default()
        };
        let h = match chunk_header(body) {
            Ok(h) => h,
            Err(e) => {
                lost.reason = format!("chunk header unreadable: {e}");
                return self.lose_chunk(lost);
            }
        };
        lost.log_times = Some((time(h.start), time(h.end)));
        // The record's framing was checked against what follows it: its bytes are the
        // compressed data, whatever `compressed_size` says (the CRC has the last word).
        let data = &body[h.header_len..];
        if h.compressed_size != data.len() as u64 {
            self.problem(format!(
                "chunk at byte {at}: compressed_size says {} bytes, the record holds {}; \
                 those were used",
                h.compressed_size,
                data.len()
            ));
        }
        let ratio = match h.compression {
            "" => 1,
            "zstd" => ZSTD_MAX_RATIO,
            "lz4" => LZ4_MAX_RATIO,
            other => {
                lost.reason =
                    format!("unknown compression {other:?} (expected \"zstd\", \"lz4\" or \"\")");
                return self.lose_chunk(lost);
            }
        };
        let most = (data.len() as u64)
            .saturating_mul(ratio)
            .min(MAX_CHUNK_BYTES);
        let claimed = h.uncompressed_size;
        if claimed > most || (h.compression.is_empty() && claimed != data.len() as u64) {
            lost.reason = if claimed > MAX_CHUNK_BYTES {
                format!(
                    "claims {claimed} bytes uncompressed, over the limit of {MAX_CHUNK_BYTES} \
                     (reader::MAX_CHUNK_BYTES)"
                )
            } else {
                format!(
                    "claims {claimed} bytes uncompressed from {} {} bytes, which give at most \
                     {most}",
                    data.len(),
                    if h.compression.is_empty() {
                        "uncompressed"
                    } else {
                        h.compression
                    }
                )
            };
            return self.lose_chunk(lost);
        }
        // A zstd frame that states its size must state the claimed one.
        if h.compression == "zstd"
            && let Ok(Some(size)) = zstd::zstd_safe::get_frame_content_size(data)
            && size != claimed
        {
            lost.reason =
                format!("claims {claimed} bytes uncompressed, its zstd frame says {size}");
            return self.lose_chunk(lost);
        }
        let mut out = std::mem::take(&mut self.chunk_buf);
        let inflated = match h.compression {
            "" => Ok(data),
            "zstd" => self
                .unzstd(data, claimed as usize, &mut out)
                .map(|()| &out[..]),
            _ => unlz4(data, claimed as usize, &mut out).map(|()| &out[..]),
        };
        let records = match inflated {
            Ok(r) if r.len() as u64 == claimed => r,
            Ok(r) => {
                lost.reason = format!(
                    "decompresses to {} bytes, its header claims {claimed}",
                    r.len()
                );
                self.keep_buffer(out);
                return self.lose_chunk(lost);
            }
            Err(e) => {
                lost.reason = format!("{} data does not decompress: {e}", h.compression);
                self.keep_buffer(out);
                return self.lose_chunk(lost);
            }
        };
        let verified = h.crc != 0;
        if verified {
            self.crc_chunks += 1;
            let got = crc32fast::hash(records);
            if got != h.crc {
                lost.reason = format!(
                    "CRC mismatch (stored {:#010x}, computed {got:#010x})",
                    h.crc
                );
                self.keep_buffer(out);
                return self.lose_chunk(lost);
            }
        }
        let mut pos = 0usize;
        while pos < records.len() {
            let left = records.len() - pos;
            let len = if left >= 9 {
                le_u64(&records[pos + 1..pos + 9])
            } else {
                u64::MAX
            };
            if len > (left as u64).saturating_sub(9) {
                let p = format!(
                    "chunk at byte {at}: the record at offset {pos} of its {} uncompressed \
                     bytes runs past the chunk's end; the rest of the chunk is not used",
                    records.len()
                );
                self.problem(p);
                break;
            }
            let body = &records[pos + 9..pos + 9 + len as usize];
            let inner = pos;
            pos += 9 + len as usize;
            let r = match records[inner] {
                op::SCHEMA => self.schema(body, verified),
                op::CHANNEL => self.channel(body, verified),
                op::MESSAGE => self.message(body, verified),
                _ => Ok(()),
            };
            if let Err(e) = r {
                self.problem(format!(
                    "chunk at byte {at}: {} at offset {inner} of its uncompressed data: {e}",
                    kind(records[inner])
                ));
            }
        }
        self.keep_buffer(out);
    }

    fn keep_buffer(&mut self, mut out: Vec<u8>) {
        // A buffer grown for one huge chunk is not kept for the rest of the file.
        if out.capacity() > 64 << 20 {
            out = Vec::new();
        }
        self.chunk_buf = out;
    }

    fn unzstd(&mut self, data: &[u8], size: usize, out: &mut Vec<u8>) -> io::Result<()> {
        out.clear();
        out.reserve_exact(size);
        let d = match &mut self.zstd {
            Some(d) => d,
            None => self.zstd.insert(zstd::bulk::Decompressor::new()?),
        };
        d.decompress_to_buffer(data, out)?;
        Ok(())
    }

    fn schema(&mut self, body: &[u8], verified: bool) -> Result<(), String> {
        let (id, name, encoding) = schema_record(body)?;
        let known = self.schemas.get(&id).is_some_and(|s| s.2);
        if !known || verified {
            self.schemas
                .insert(id, (name.to_string(), encoding.to_string(), verified));
        }
        Ok(())
    }

    fn channel(&mut self, body: &[u8], verified: bool) -> Result<(), String> {
        let c = channel_record(body)?;
        let (schema_name, schema_encoding, schema_ok) = if c.schema_id == 0 {
            (String::new(), String::new(), true)
        } else if let Some((n, e, v)) = self.schemas.get(&c.schema_id) {
            (n.clone(), e.clone(), *v)
        } else if let Some((n, e)) = self.pre.schemas.get(&c.schema_id) {
            (n.clone(), e.clone(), self.pre.verified)
        } else {
            (String::new(), String::new(), false)
        };
        let info = ChannelInfo {
            id: c.id,
            topic: c.topic.to_string(),
            message_encoding: c.encoding.to_string(),
            schema_name,
            schema_encoding,
        };
        let verified = verified && schema_ok;
        if let Some((old, old_verified)) = self.channels.get(&c.id) {
            if **old == info || (*old_verified && !verified) {
                if **old != info {
                    return Err(format!(
                        "channel {} redefined as {:?} by an unverified record; the first \
                         definition ({:?}) is kept",
                        c.id, info.topic, old.topic
                    ));
                }
                return Ok(());
            }
        }
        let info = Arc::new(info);
        self.summary.channels.insert(c.id, info.clone());
        self.channels.insert(c.id, (info, verified));
        Ok(())
    }

    /// The channel of a message: a CRC-covered definition from the data section, else the
    /// summary's, else an unverified one.
    fn resolve(&self, id: u16) -> Option<(Arc<ChannelInfo>, bool)> {
        match (self.channels.get(&id), self.pre.channels.get(&id)) {
            (Some((c, true)), _) => Some((c.clone(), true)),
            (_, Some(c)) => Some((c.clone(), self.pre.verified)),
            (Some((c, false)), None) => Some((c.clone(), false)),
            (None, None) => None,
        }
    }

    fn message(&mut self, body: &[u8], verified: bool) -> Result<(), String> {
        let mut c = Cur::new(body);
        let channel_id = c.u16("channel id")?;
        let sequence = c.u32("sequence")?;
        let log_time = c.u64("log_time")?;
        let publish_time = c.u64("publish_time")?;
        let data = &body[c.at..];
        let Some((ch, ch_verified)) = self.resolve(channel_id) else {
            self.damage.orphan_messages += 1;
            return Ok(());
        };
        let m = RawMessage {
            sequence,
            log_time: time(log_time),
            publish_time: time(publish_time),
            data,
            verified: verified && ch_verified,
        };
        (self.on_message)(&ch, &m);
        self.summary.messages += 1;
        if !m.verified {
            self.summary.unverified_messages += 1;
        }
        match self.summary.messages_per_topic.get_mut(&ch.topic) {
            Some(n) => *n += 1,
            None => {
                self.summary.messages_per_topic.insert(ch.topic.clone(), 1);
            }
        }
        Ok(())
    }

    /// A message index after a chunk: what a lost chunk held.
    fn message_index(&mut self, body: &[u8]) -> Result<(), String> {
        if !self.last_chunk_lost {
            return Ok(());
        }
        let mut c = Cur::new(body);
        let id = c.u16("channel id")?;
        let n = c.u32("message index entries")?;
        let entries = u64::from(n).min(c.left() as u64) / 16;
        self.damage.messages_in_lost_chunks += entries;
        let Some(i) = self.last_lost else {
            return Ok(());
        };
        let topic = self
            .resolve(id)
            .map_or_else(|| format!("channel {id}"), |(ch, _)| ch.topic.clone());
        if let Some(l) = self.damage.lost_chunks.get_mut(i) {
            *l.messages.entry(topic).or_insert(0) += entries;
        }
        Ok(())
    }

    /// A record outside chunks (other than a chunk).
    fn top_level(&mut self, opcode: u8, at: u64, body: &[u8]) {
        let r = match opcode {
            op::HEADER => {
                let mut c = Cur::new(body);
                let h = c.name("profile").and_then(|p| Ok((p, c.name("library")?)));
                match h {
                    Ok((p, l)) => {
                        self.summary.profile = p.to_string();
                        self.summary.library = l.to_string();
                        Ok(())
                    }
                    Err(e) => {
                        self.damage.header_damaged = true;
                        Err(e)
                    }
                }
            }
            op::SCHEMA => self.schema(body, false),
            op::CHANNEL => self.channel(body, false),
            op::MESSAGE if self.crc_chunks > 0 => Err(
                "a message record outside the chunks of a chunked file (no CRC covers it, \
                 it is likely misread damage): not used"
                    .to_string(),
            ),
            op::MESSAGE => self.message(body, false),
            op::MESSAGE_INDEX => self.message_index(body),
            op::METADATA => match metadata_record(body) {
                Ok((name, map, _)) => {
                    self.seen_metadata(at, true);
                    if self.summary.metadata.len() < MAX_METADATA_RECORDS
                        || self.summary.metadata.contains_key(&name)
                    {
                        self.summary.metadata.insert(name, map);
                        Ok(())
                    } else {
                        Err(format!(
                            "{name:?} not kept: over {MAX_METADATA_RECORDS} metadata records"
                        ))
                    }
                }
                Err(e) => {
                    self.seen_metadata(at, false);
                    if self.damage.damaged_metadata.len() < MAX_REPORTED {
                        self.damage.damaged_metadata.push(at);
                    }
                    Err(e)
                }
            },
            _ => Ok(()),
        };
        if let Err(e) = r {
            self.problem(format!("{} at byte {at}: {e}", kind(opcode)));
        }
    }
}

fn unlz4(data: &[u8], size: usize, out: &mut Vec<u8>) -> io::Result<()> {
    out.clear();
    out.reserve_exact(size);
    let d = lz4::Decoder::new(data)?;
    // One byte more than claimed shows a chunk that decompresses to more.
    d.take(size as u64 + 1).read_to_end(out)?;
    Ok(())
}

/// Reads every message of an MCAP file in file order, calling `on_message` for each;
/// returns channels, metadata and what was lost. Errors only when the bytes are not an
/// MCAP file at all.
pub fn scan<F>(bytes: &[u8], on_message: F) -> Result<McapSummary, RecordingError>
where
    F: FnMut(&ChannelInfo, &RawMessage<'_>),
{
    scan_reader(io::Cursor::new(bytes), on_message)
}

/// [`scan`] of a file, read through a window (memory does not grow with the file); errors
/// name the file.
pub fn scan_file<F>(path: &Path, on_message: F) -> Result<McapSummary, RecordingError>
where
    F: FnMut(&ChannelInfo, &RawMessage<'_>),
{
    let name = path.display().to_string();
    let file = std::fs::File::open(path).map_err(|source| RecordingError::Io {
        path: name.clone(),
        source,
    })?;
    scan_reader(file, on_message).map_err(|e| match e {
        RecordingError::Unusable { problem, .. } => RecordingError::Unusable {
            path: name.clone(),
            problem,
        },
        RecordingError::Io { source, .. } => RecordingError::Io {
            path: name.clone(),
            source,
        },
        e => e.in_file(&name),
    })
}

/// [`scan`] of anything that reads and seeks (the summary section is read first).
pub fn scan_reader<R, F>(mut r: R, on_message: F) -> Result<McapSummary, RecordingError>
where
    R: Read + Seek,
    F: FnMut(&ChannelInfo, &RawMessage<'_>),
{
    let io_err = |source| RecordingError::Io {
        path: String::new(),
        source,
    };
    let len = r.seek(SeekFrom::End(0)).map_err(io_err)?;
    let pre = read_summary(&mut r, len).map_err(io_err)?;
    r.seek(SeekFrom::Start(0)).map_err(io_err)?;
    let mut src = Source::new(r, len);
    let head = src.peek(MAGIC.len()).map_err(io_err)?.to_vec();
    let mut damage = Damage::default();
    if head != MAGIC {
        let close = head.len() == MAGIC.len()
            && head.iter().zip(MAGIC).filter(|(a, b)| a != b).count() <= 2;
        if !close && pre.footer_at.is_none() {
            return Err(RecordingError::Unusable {
                path: String::new(),
                problem: format!(
                    "not an MCAP file: starts with {head:02x?}, expected the MCAP magic \
                     {MAGIC:02x?}"
                ),
            });
        }
        damage.problems.push(format!(
            "the MCAP magic at byte 0 is damaged ({head:02x?}); read as MCAP"
        ));
    }
    src.consume(head.len());
    if let Some(p) = &pre.problem {
        damage.problems.push(p.clone());
    }
    let mut s = Scanner {
        schemas: HashMap::new(),
        channels: HashMap::new(),
        pre,
        summary: McapSummary {
            file_bytes: len,
            ..McapSummary::default()
        },
        damage,
        on_message,
        chunk_buf: Vec::new(),
        zstd: None,
        last_lost: None,
        last_chunk_lost: false,
        chunk_cursor: 0,
        metadata_cursor: 0,
        crc_chunks: 0,
    };
    s.summary.metadata_index = s.pre.metadata.iter().map(|(n, _)| n.clone()).collect();
    let mut body = Vec::new();
    let mut first = true;
    let mut in_summary = false;
    let mut footer = false;
    loop {
        let at = src.pos;
        let rest = src.remaining();
        if rest == 0 {
            break;
        }
        let (opcode, claimed, implied) = {
            let w = src.peek(LOOKAHEAD).map_err(io_err)?;
            if w.len() < 9 {
                s.damage.bytes_unread += rest;
                s.problem(format!(
                    "the file ends at byte {len} inside the record that starts at byte {at}"
                ));
                break;
            }
            let implied = (w[0] == op::CHUNK)
                .then(|| chunk_header(&w[9..]).ok())
                .flatten()
                .map(|h| h.header_len as u64 + h.compressed_size);
            (w[0], le_u64(&w[1..9]), implied)
        };
        let room = rest - 9;
        let mut rlen = claimed;
        if let Some(l) = implied
            && l != claimed
            && l <= room
        {
            // The record's length field and its chunk header disagree: one of them lies.
            // The one after which a record starts wins (the header's when neither).
            let starts = |src: &mut Source<R>, l: u64| -> io::Result<bool> {
                if l > room {
                    return Ok(false);
                }
                let next = at + 9 + l;
                Ok(next == len || candidate(&src.peek_at(next, LOOKAHEAD)?, len - next))
            };
            let by_field = starts(&mut src, claimed).map_err(io_err)?;
            let by_header = starts(&mut src, l).map_err(io_err)?;
            if by_header || !by_field {
                rlen = l;
            }
            s.problem(format!(
                "chunk record at byte {at}: its length field says {claimed} bytes, its header \
                 {l}; read as {rlen}"
            ));
        }
        let known = matches!(opcode, 0x01..=0x0F | 0x80..=0xFF);
        let framed = known && rlen <= room && !(opcode == op::FOOTER && rlen != 20);
        if in_summary && !framed {
            if known && rlen > room {
                s.damage.bytes_unread += rest;
                s.problem(format!(
                    "the file ends at byte {len} inside the summary record at byte {at} \
                     (opcode {opcode:#04x}, {claimed} bytes)"
                ));
            } else {
                s.problem(format!(
                    "summary section damaged at byte {at} (opcode {opcode:#04x}, length \
                     {claimed})"
                ));
            }
            break;
        }
        if !framed {
            let why = if known {
                format!(
                    "the {} at byte {at} claims {claimed} bytes, only {room} are left in \
                     the file",
                    kind(opcode)
                )
            } else {
                format!("no record starts at byte {at} (opcode {opcode:#04x})")
            };
            if first {
                s.damage.header_damaged = true;
            }
            first = false;
            match resync(&mut src).map_err(io_err)? {
                Some(next) => {
                    s.damage.bytes_skipped += next - at;
                    s.problem(format!(
                        "{why}: bytes {at}..{next} skipped, reading resumed at byte {next}"
                    ));
                }
                None => {
                    s.damage.bytes_unread += rest;
                    if opcode == op::CHUNK {
                        s.lose_chunk(LostChunk {
                            offset: at,
                            bytes: rest,
                            reason: format!(
                                "the file ends at byte {len}, the chunk needs {claimed} bytes \
                                 after its length field"
                            ),
                            ..LostChunk::default()
                        });
                    } else {
                        s.problem(format!(
                            "{why}: no readable record after it, the last {rest} bytes are lost"
                        ));
                    }
                    break;
                }
            }
            continue;
        }
        if first && opcode != op::HEADER {
            s.damage.header_damaged = true;
            s.problem(format!(
                "no header record at byte {at} (opcode {opcode:#04x})"
            ));
        }
        first = false;
        let limit = if opcode == op::CHUNK {
            MAX_CHUNK_BYTES + 4096
        } else {
            MAX_RECORD_BYTES
        };
        let wanted = matches!(
            opcode,
            op::HEADER
                | op::FOOTER
                | op::SCHEMA
                | op::CHANNEL
                | op::MESSAGE
                | op::CHUNK
                | op::MESSAGE_INDEX
                | op::METADATA
                | op::DATA_END
        ) && !(in_summary && opcode != op::FOOTER);
        if !wanted || rlen > limit {
            if wanted {
                s.problem(format!(
                    "{} at byte {at} of {rlen} bytes is over the limit of {limit}: skipped",
                    kind(opcode)
                ));
                if opcode == op::CHUNK {
                    s.lose_chunk(LostChunk {
                        offset: at,
                        bytes: rlen + 9,
                        reason: format!("{rlen} bytes, over the limit of {limit}"),
                        ..LostChunk::default()
                    });
                }
            }
            src.skip(9 + rlen).map_err(io_err)?;
            continue;
        }
        // The data-section CRC covers every byte before the DataEnd record.
        let data_crc = if opcode == op::DATA_END {
            in_summary = true;
            src.crc.take().map(crc32fast::Hasher::finalize)
        } else {
            None
        };
        src.skip(9).map_err(io_err)?;
        src.read_into(rlen, &mut body).map_err(io_err)?;
        match opcode {
            op::CHUNK => s.chunk(at, &body),
            op::DATA_END => {
                let stored = Cur::new(&body).u32("data_section_crc").unwrap_or(0);
                if let Some(computed) = data_crc
                    && stored != 0
                    && stored != computed
                {
                    s.damage.data_crc_mismatch = true;
                    s.problem(format!(
                        "data-section CRC mismatch at the DataEnd record at byte {at} (stored \
                         {stored:#010x}, computed {computed:#010x} over bytes 0..{at}): bytes \
                         were altered, possibly outside the chunks' own CRCs (header, metadata)"
                    ));
                }
            }
            op::FOOTER => {
                footer = true;
                let end = src.peek(MAGIC.len() + 1).map_err(io_err)?;
                if end.is_empty() {
                    s.damage.end_magic_missing = true;
                    s.problem(format!(
                        "no end magic: the file ends right after the footer at byte {at}"
                    ));
                } else if end.len() < MAGIC.len() || &end[..MAGIC.len()] != MAGIC {
                    s.damage.end_magic_missing = true;
                    s.problem(format!(
                        "no end magic after the footer at byte {at}: the file's last {} \
                         bytes are {:02x?}",
                        end.len().min(MAGIC.len()),
                        &end[..end.len().min(MAGIC.len())]
                    ));
                } else if src.remaining() > MAGIC.len() as u64 {
                    let extra = src.remaining() - MAGIC.len() as u64;
                    s.problem(format!("{extra} bytes after the end magic"));
                }
                break;
            }
            _ => s.top_level(opcode, at, &body),
        }
    }
    if first {
        s.damage.header_damaged = true;
        s.problem(format!(
            "the file ends at byte {len}, before its header record"
        ));
    }
    if !footer {
        s.damage.summary_missing = true;
        s.damage.end_magic_missing = true;
    }
    finish(s)
}

/// The damage report: what the summary's indexes list that was not read, the message
/// count against the summary's.
fn finish<F>(mut s: Scanner<F>) -> Result<McapSummary, RecordingError>
where
    F: FnMut(&ChannelInfo, &RawMessage<'_>),
{
    s.seen_chunk(u64::MAX);
    s.seen_metadata(u64::MAX, true);
    let mut d = s.damage;
    if d.is_empty() {
        return Ok(s.summary);
    }
    let delivered = s.summary.messages;
    match s.pre.message_count {
        Some(n) => {
            d.expected_messages = Some(n);
            d.messages_lost = (n > delivered).then(|| n - delivered);
        }
        None => {
            let known = d.messages_in_lost_chunks;
            d.messages_lost = (known > 0).then_some(known);
        }
    }
    s.summary.damage = Some(d);
    Ok(s.summary)
}
