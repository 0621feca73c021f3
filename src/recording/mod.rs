//! Recordings: every stream of a run in an MCAP file that ROS 2 tools read, and back.
//!
//! A run writes `recording.mcap` (profile `ros2`): each sensor message CDR-encoded on
//! its ROS topic ([`vinebench_msgs::Message::topic`]) with the complete `ros2msg`
//! definition of its type ([`schema`]), `/tf_static` with every URDF frame, ground truth
//! under `/ground_truth/`, each estimate under `/estimate/<source>/` and the resolved
//! scenario as metadata ([`META_SCENARIO`]). Log time is the stamp, publish time the
//! arrival at the estimators, so [`crate::replay`] feeds the estimators in the live
//! order and reproduces the live estimates bit for bit.
//!
//! - [`cdr`]: the CDR primitives; [`ros`]: encoders and decoders of each message type;
//! - [`writer`]: [`McapSink`] (in the caller's thread) and [`Recorder`] (background
//!   thread, finalizes on drop);
//! - [`reader`]: a linear scan that recovers what a truncated or damaged file holds:
//!   every size a file states is bounded before it is allocated, every chunk's CRC is
//!   checked before its messages are used, and what was lost is reported.
//!
//! ```
//! use vinebench::recording::{McapSink, SinkOptions, reader};
//! use vinebench_msgs::{ImuMsg, Message, Nanos, TimedMessage, FrameId};
//! use nalgebra::{Matrix3, Vector3};
//! let imu = ImuMsg {
//!     stamp: Nanos(1_000),
//!     frame_id: FrameId::new("imu_link"),
//!     orientation: None,
//!     orientation_covariance: Matrix3::zeros(),
//!     angular_velocity: Vector3::new(0.0, 0.0, 0.1),
//!     angular_velocity_covariance: Matrix3::identity() * 1e-6,
//!     linear_acceleration: Vector3::new(0.0, 0.0, 9.8),
//!     linear_acceleration_covariance: Matrix3::identity() * 1e-4,
//! };
//! let mut file = std::io::Cursor::new(Vec::new());
//! let mut sink = McapSink::new(&mut file, &SinkOptions::default()).unwrap();
//! sink.write_message(&TimedMessage { arrival: Nanos(2_000), msg: Message::Imu(imu.clone()) })
//!     .unwrap();
//! sink.finish().unwrap();
//! let mut seen = Vec::new();
//! let summary = reader::scan(file.get_ref(), |ch, m| {
//!     seen.push((ch.topic.clone(), vinebench::recording::ros::decode_imu(m.data).unwrap()));
//! })
//! .unwrap();
//! assert!(summary.damage.is_none());
//! assert_eq!(seen, [("/imu/data".to_string(), imu)]);
//! ```

pub mod bag1;
pub mod cdr;
pub mod db3;
pub mod reader;
pub mod ros;
pub mod ros1;
pub mod schema;
pub mod writer;

pub use reader::{ChannelInfo, Damage, LostChunk, McapSummary, RawMessage};
pub use writer::{McapSink, RecordItem, Recorder, SinkOptions};

use std::path::Path;
use thiserror::Error;
use vinebench_msgs::Nanos;

/// Topic names vinebench writes besides the sensor topics.
pub mod topics {
    /// Static transforms (`tf2_msgs/TFMessage`), every URDF frame relative to the body.
    pub const TF_STATIC: &str = "/tf_static";
    /// Transforms over time (`world → base_link` of the first estimate).
    pub const TF: &str = "/tf";
    /// Ground truth of the body frame (`nav_msgs/Odometry` in `world`).
    pub const GROUND_TRUTH_ODOM: &str = "/ground_truth/odom";
    /// Prefix of every ground-truth topic; only scoring reads them.
    pub const GROUND_TRUTH_PREFIX: &str = "/ground_truth/";
    /// Prefix of the estimates: `/estimate/<source>/odom`.
    pub const ESTIMATE_PREFIX: &str = "/estimate/";

    /// The point-cloud map built with an estimate source: `/map/<source>/points`.
    pub fn map_points(source: &str) -> String {
        format!("/map/{source}/points")
    }

    /// The odometry topic of an estimate source.
    pub fn estimate_odom(source: &str) -> String {
        format!("{ESTIMATE_PREFIX}{source}/odom")
    }
}

/// Metadata record with the run's resolved scenario: keys [`META_KEY_TOML`] (the
/// resolved TOML), `file`, `origin_lat_deg`, `origin_lon_deg`, `origin_alt_m`,
/// `start_ns`, `vinebench_version`.
pub const META_SCENARIO: &str = "vinebench.scenario";
/// Key of the resolved scenario TOML in [`META_SCENARIO`].
pub const META_KEY_TOML: &str = "resolved_toml";
/// Metadata record written at the end of a run: the robot's truth-only metrics (one key
/// per metric of the expectations' pseudo-source `robot`, decimal text), and `outcome`.
pub const META_RUN: &str = "vinebench.run";

/// What a finished recording holds.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RecordingStats {
    /// Messages written.
    pub messages: u64,
    /// Their CDR payload bytes (before compression).
    pub payload_bytes: u64,
    /// Channels (topics).
    pub channels: usize,
    /// Messages not written because their topic is excluded (`[recording]
    /// exclude_topics`).
    pub excluded_messages: u64,
}

/// `[recording]` (documented with its defaults in `scenarios/defaults.toml`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordingParams {
    /// zstd level of the chunks, 1 (fastest) to 19; 0: uncompressed.
    pub zstd_level: u32,
    /// Uncompressed chunk size, MiB.
    pub chunk_size_mb: f64,
    /// Topics not recorded: exact names or prefixes ending in `*`.
    pub exclude_topics: Vec<String>,
}

impl RecordingParams {
    /// Checks the values; errors name the key as `recording.<key>`.
    pub fn validate(&self) -> Result<(), vinebench_sim::params::ParamError> {
        vinebench_sim::params::require_in(
            "recording.zstd_level",
            f64::from(self.zstd_level),
            0.0,
            19.0,
        )?;
        vinebench_sim::params::require_in(
            "recording.chunk_size_mb",
            self.chunk_size_mb,
            0.01,
            // A chunk is this plus one message; the reader refuses chunks over
            // `reader::MAX_CHUNK_BYTES` (1 GiB).
            512.0,
        )?;
        for (i, t) in self.exclude_topics.iter().enumerate() {
            if !t.starts_with('/') || t.trim_end_matches('*').contains('*') {
                return Err(vinebench_sim::params::ParamError::new(
                    format!("recording.exclude_topics[{i}]"),
                    "a topic name starting with `/`, or a prefix of one ending in `*`",
                    format!("{t:?}"),
                ));
            }
        }
        Ok(())
    }
}

impl Default for RecordingParams {
    /// The values of `[recording]` in `scenarios/defaults.toml`.
    fn default() -> Self {
        vinebench_msgs::defaults::section("recording")
            .expect("the embedded scenarios/defaults.toml is checked by tests")
    }
}

/// A recording that could not be written or read.
#[derive(Debug, Error)]
pub enum RecordingError {
    /// A file could not be created, read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The MCAP library refused an operation.
    #[error("MCAP {doing}: {source}")]
    Mcap {
        /// What was being done.
        doing: &'static str,
        /// The library's error.
        source: mcap::McapError,
    },
    /// A stamp that MCAP cannot store (before 1970).
    #[error("{topic}: stamp {stamp} is before 1970; MCAP log times are unsigned")]
    Time {
        /// The topic.
        topic: String,
        /// The stamp.
        stamp: Nanos,
    },
    /// Nothing usable in a file (not MCAP, or damaged before the first message).
    #[error("{path}: {problem}")]
    Unusable {
        /// The file.
        path: String,
        /// What was found and what was expected.
        problem: String,
    },
    /// The same error, in a named file.
    #[error("{path}: {source}")]
    InFile {
        /// The file.
        path: String,
        /// The error.
        source: Box<RecordingError>,
    },
    /// A bug: a state the writer should never reach.
    #[error("recording: internal error: {0}")]
    Internal(String),
}

impl RecordingError {
    fn mcap(doing: &'static str) -> impl FnOnce(mcap::McapError) -> RecordingError {
        move |source| RecordingError::Mcap { doing, source }
    }

    /// This error, naming `path` unless it already names a file.
    pub fn in_file(self, path: &str) -> RecordingError {
        match self {
            e @ (RecordingError::Io { .. }
            | RecordingError::Unusable { .. }
            | RecordingError::InFile { .. }) => e,
            e => RecordingError::InFile {
                path: path.to_string(),
                source: Box::new(e),
            },
        }
    }
}

/// What a recording path holds.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Storage {
    /// An MCAP file (also the one of a rosbag2 folder with MCAP storage).
    Mcap(std::path::PathBuf),
    /// A ROS 1 bag.
    Ros1(std::path::PathBuf),
    /// The `.db3` files of a rosbag2 folder with sqlite3 storage, in name order.
    Sqlite(Vec<std::path::PathBuf>),
}

/// What `path` is: a ROS 1 bag, an MCAP file, a `.db3`, or a rosbag2 folder (its `.mcap`
/// or `.db3` files).
pub fn storage(path: &Path) -> Result<Storage, RecordingError> {
    if !path.is_dir() {
        return Ok(if is_ros1_bag(path) {
            Storage::Ros1(path.to_path_buf())
        } else if db3::is_sqlite(path) {
            Storage::Sqlite(vec![path.to_path_buf()])
        } else {
            Storage::Mcap(path.to_path_buf())
        });
    }
    let name = path.display().to_string();
    let mut found: Vec<std::path::PathBuf> = std::fs::read_dir(path)
        .map_err(|source| RecordingError::Io {
            path: name.clone(),
            source,
        })?
        .flatten()
        .map(|e| e.path())
        .collect();
    found.sort();
    let with = |ext: &str| -> Vec<std::path::PathBuf> {
        found
            .iter()
            .filter(|p| p.extension().is_some_and(|e| e == ext))
            .cloned()
            .collect()
    };
    let (mcaps, db3s) = (with("mcap"), with("db3"));
    match (mcaps.as_slice(), db3s.is_empty()) {
        ([one], _) => Ok(Storage::Mcap(one.clone())),
        ([], false) => Ok(Storage::Sqlite(db3s)),
        ([], true) => {
            let names: Vec<String> = found
                .iter()
                .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
                .collect();
            Err(RecordingError::Unusable {
                path: name,
                problem: format!(
                    "a folder without a recording ({}): expected a rosbag2 folder with .mcap \
                     or .db3 storage",
                    names.join(", ")
                ),
            })
        }
        _ => Err(RecordingError::Unusable {
            path: name,
            problem: format!(
                "{} MCAP files: split MCAP bags are not read yet",
                mcaps.len()
            ),
        }),
    }
}

/// Whether `path` is a ROS 1 bag (by its first bytes).
pub fn is_ros1_bag(path: &Path) -> bool {
    starts_with(path, b"#ROSBAG V")
}

/// Whether the file at `path` begins with the bytes `magic`.
pub(crate) fn starts_with(path: &Path, magic: &[u8]) -> bool {
    let mut head = vec![0u8; magic.len()];
    std::fs::File::open(path)
        .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut head))
        .is_ok()
        && head == magic
}

/// Every message of a recording, whatever robots record: an MCAP file, a rosbag2 folder
/// (MCAP or sqlite3 storage, [`db3`]), or a ROS 1 bag (transcoded to CDR,
/// [`bag1::scan_as_cdr`]); see [`reader::scan_file`].
pub fn scan_any<F>(path: &Path, on_message: F) -> Result<reader::McapSummary, RecordingError>
where
    F: FnMut(&reader::ChannelInfo, &reader::RawMessage<'_>),
{
    match storage(path)? {
        Storage::Ros1(f) => bag1::scan_as_cdr(&f, on_message),
        Storage::Sqlite(files) => db3::scan(&files, on_message),
        Storage::Mcap(f) => reader::scan_file(&f, on_message),
    }
}
