//! Writing `recording.mcap`: [`McapSink`] encodes and writes in the caller's thread;
//! [`Recorder`] runs a sink on a background thread so the simulation only hands messages
//! over (cheap: image pixels are shared, not copied) and finalizes the file when it is
//! finished or dropped (an error, a panic or an interrupt unwinding the runner).

use super::ros::{self, TransformStamped};
use super::schema::{self, RosType};
use super::topics;
use super::{RecordingError, RecordingStats};
use mcap::records::{MessageHeader, Metadata};
use mcap::{Compression, WriteOptions, Writer};
use nalgebra::{Matrix6, Vector3};
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufWriter, Seek, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::thread::JoinHandle;
use vinebench_msgs::frames::names;
use vinebench_msgs::{
    FrameId, Message, Nanos, OdometryMsg, StaticTransforms, TimedMessage, Trajectory,
};

/// Uncompressed chunk size: 4 MiB holds several VGA images, so chunk overhead stays small
/// and zstd sees enough data.
pub const CHUNK_SIZE_BYTES: u64 = 4 * 1024 * 1024;
/// zstd level: 1 (fastest) keeps writing well above camera data rates on one core.
pub const ZSTD_LEVEL: u32 = 1;
/// Items handed to the background writer at once: one hand-over per message would cost
/// a thread wake-up each, more than encoding and compressing a small message.
pub const BATCH_ITEMS: usize = 1024;
/// Batches the simulation may queue before it waits for the writer.
pub const QUEUE_DEPTH: usize = 8;

/// `offered_qos_profiles` of `/tf_static` as rosbag2 records it: reliable, transient
/// local, so `ros2 bag play` latches the transforms for late subscribers.
const QOS_TRANSIENT_LOCAL: &str = "- history: 3\n  depth: 0\n  reliability: 1\n  durability: 1\n  \
deadline:\n    sec: 2147483647\n    nsec: 4294967295\n  lifespan:\n    sec: 2147483647\n    \
nsec: 4294967295\n  liveliness: 1\n  liveliness_lease_duration:\n    sec: 2147483647\n    \
nsec: 4294967295\n  avoid_ros_namespace_conventions: false\n";
/// `offered_qos_profiles` of every other topic: reliable, volatile.
const QOS_VOLATILE: &str = "- history: 3\n  depth: 0\n  reliability: 1\n  durability: 2\n  \
deadline:\n    sec: 2147483647\n    nsec: 4294967295\n  lifespan:\n    sec: 2147483647\n    \
nsec: 4294967295\n  liveliness: 1\n  liveliness_lease_duration:\n    sec: 2147483647\n    \
nsec: 4294967295\n  avoid_ros_namespace_conventions: false\n";

/// How recordings are compressed.
#[derive(Clone, Debug, PartialEq)]
pub struct SinkOptions {
    /// zstd level (1 fastest … 19); `None`: no compression.
    pub zstd_level: Option<u32>,
    /// zstd worker threads (0: compress in the writing thread).
    pub zstd_threads: u32,
    /// Target uncompressed chunk size, bytes.
    pub chunk_size: u64,
    /// Topics not written: exact names, or prefixes ending in `*` (`/camera_left/*`).
    pub exclude_topics: Vec<String>,
}

impl SinkOptions {
    /// The options of a scenario's `[recording]` section.
    pub fn from_params(p: &super::RecordingParams) -> SinkOptions {
        SinkOptions {
            zstd_level: (p.zstd_level > 0).then_some(p.zstd_level),
            zstd_threads: 0,
            chunk_size: (p.chunk_size_mb * 1024.0 * 1024.0).round() as u64,
            exclude_topics: p.exclude_topics.clone(),
        }
    }

    /// Whether `topic` is excluded.
    pub fn excludes(&self, topic: &str) -> bool {
        self.exclude_topics
            .iter()
            .any(|pat| match pat.strip_suffix('*') {
                Some(prefix) => topic.starts_with(prefix),
                None => topic == pat,
            })
    }
}

impl Default for SinkOptions {
    fn default() -> Self {
        SinkOptions {
            zstd_level: Some(ZSTD_LEVEL),
            zstd_threads: 0,
            chunk_size: CHUNK_SIZE_BYTES,
            exclude_topics: Vec::new(),
        }
    }
}

struct ChannelState {
    /// `None`: the topic is excluded.
    id: Option<u16>,
    next_sequence: u32,
}

/// Encodes messages as ROS 2 CDR and writes them to an MCAP file (profile `ros2`,
/// schemas `ros2msg`, chunked, zstd, with message indexes and a summary).
///
/// Log time is the message stamp, publish time its arrival (so a replay restores the
/// arrival order); each channel numbers its messages from 0.
pub struct McapSink<W: Write + Seek> {
    writer: Writer<W>,
    schemas: HashMap<&'static str, u16>,
    channels: HashMap<String, ChannelState>,
    buf: Vec<u8>,
    stats: RecordingStats,
    exclude_topics: SinkOptions,
}

impl<W: Write + Seek> McapSink<W> {
    /// Starts an MCAP file on `w`.
    pub fn new(w: W, opts: &SinkOptions) -> Result<McapSink<W>, RecordingError> {
        let mut o = WriteOptions::new()
            .profile("ros2")
            .library(concat!("vinebench ", env!("CARGO_PKG_VERSION")))
            .chunk_size(Some(opts.chunk_size))
            .compression(opts.zstd_level.map(|_| Compression::Zstd));
        if let Some(level) = opts.zstd_level {
            o = o
                .compression_level(level)
                .compression_threads(opts.zstd_threads);
        }
        Ok(McapSink {
            writer: o
                .create(w)
                .map_err(RecordingError::mcap("starting the file"))?,
            schemas: HashMap::new(),
            channels: HashMap::new(),
            buf: Vec::new(),
            stats: RecordingStats::default(),
            exclude_topics: SinkOptions {
                exclude_topics: opts.exclude_topics.clone(),
                ..SinkOptions::default()
            },
        })
    }

    /// The channel of `topic`, created on first use; `None` when the topic is excluded.
    fn channel(
        &mut self,
        topic: &str,
        ty: &'static RosType,
    ) -> Result<Option<u16>, RecordingError> {
        if let Some(c) = self.channels.get(topic) {
            return Ok(c.id);
        }
        if self.exclude_topics.excludes(topic) {
            self.channels.insert(
                topic.to_string(),
                ChannelState {
                    id: None,
                    next_sequence: 0,
                },
            );
            return Ok(None);
        }
        let schema_id = match self.schemas.get(ty.short) {
            Some(&id) => id,
            None => {
                let id = self
                    .writer
                    .add_schema(
                        &ty.schema_name(),
                        "ros2msg",
                        ty.full_definition().as_bytes(),
                    )
                    .map_err(RecordingError::mcap("adding a schema"))?;
                self.schemas.insert(ty.short, id);
                id
            }
        };
        let qos = if topic == topics::TF_STATIC {
            QOS_TRANSIENT_LOCAL
        } else {
            QOS_VOLATILE
        };
        let meta = BTreeMap::from([("offered_qos_profiles".to_string(), qos.to_string())]);
        let id = self
            .writer
            .add_channel(schema_id, topic, "cdr", &meta)
            .map_err(RecordingError::mcap("adding a channel"))?;
        self.channels.insert(
            topic.to_string(),
            ChannelState {
                id: Some(id),
                next_sequence: 0,
            },
        );
        Ok(Some(id))
    }

    /// Writes an encoded payload on `topic`.
    pub fn write_payload(
        &mut self,
        topic: &str,
        ty: &'static RosType,
        stamp: Nanos,
        arrival: Nanos,
        payload: &[u8],
    ) -> Result<(), RecordingError> {
        let Some(channel_id) = self.channel(topic, ty)? else {
            self.stats.excluded_messages += 1;
            return Ok(());
        };
        let time = |t: Nanos| {
            u64::try_from(t.0).map_err(|_| RecordingError::Time {
                topic: topic.to_string(),
                stamp: t,
            })
        };
        let (log_time, publish_time) = (time(stamp)?, time(arrival)?);
        let c = self
            .channels
            .get_mut(topic)
            .ok_or_else(|| RecordingError::Internal(format!("channel {topic} vanished")))?;
        let sequence = c.next_sequence;
        c.next_sequence = c.next_sequence.wrapping_add(1);
        self.writer
            .write_to_known_channel(
                &MessageHeader {
                    channel_id,
                    sequence,
                    log_time,
                    publish_time,
                },
                payload,
            )
            .map_err(RecordingError::mcap("writing a message"))?;
        self.stats.messages += 1;
        self.stats.payload_bytes += payload.len() as u64;
        Ok(())
    }

    /// Encodes with `encode` into the sink's buffer and writes it.
    fn write_with(
        &mut self,
        topic: &str,
        ty: &'static RosType,
        stamp: Nanos,
        arrival: Nanos,
        encode: impl FnOnce(&mut Vec<u8>),
    ) -> Result<(), RecordingError> {
        let mut buf = std::mem::take(&mut self.buf);
        encode(&mut buf);
        let r = self.write_payload(topic, ty, stamp, arrival, &buf);
        self.buf = buf;
        r
    }

    /// Writes a sensor message on its topic ([`Message::topic`]).
    pub fn write_message(&mut self, tm: &TimedMessage) -> Result<(), RecordingError> {
        let (stamp, arrival, topic) = (tm.msg.stamp(), tm.arrival, tm.msg.topic());
        match &tm.msg {
            Message::Imu(m) => self.write_with(topic, &schema::IMU, stamp, arrival, |b| {
                ros::encode_imu(m, b)
            }),
            Message::GnssFix(m) => {
                self.write_with(topic, &schema::NAV_SAT_FIX, stamp, arrival, |b| {
                    ros::encode_nav_sat_fix(m, b)
                })
            }
            Message::GnssVelocity(m) => self.write_with(
                topic,
                &schema::TWIST_WITH_COVARIANCE_STAMPED,
                stamp,
                arrival,
                |b| ros::encode_gnss_velocity(m, b),
            ),
            Message::TrackingOdom(m) | Message::WheelOdom(m) => {
                self.write_with(topic, &schema::ODOMETRY, stamp, arrival, |b| {
                    ros::encode_odometry(m, b)
                })
            }
            Message::Image(m) => self.write_with(topic, &schema::IMAGE, stamp, arrival, |b| {
                ros::encode_image(m, b)
            }),
            Message::CameraInfo(m) => {
                self.write_with(topic, &schema::CAMERA_INFO, stamp, arrival, |b| {
                    ros::encode_camera_info(m, b)
                })
            }
            Message::GnssHeading(m) => self.write_with(topic, &schema::IMU, stamp, arrival, |b| {
                ros::encode_imu(&ros::imu_of_heading(m), b)
            }),
            Message::GnssSky(m) => self.write_with(topic, &schema::GPS_FIX, stamp, arrival, |b| {
                ros::encode_gps_fix(m, b)
            }),
        }
    }

    /// Writes `/tf_static`: `body_frame → frame` for every frame of `tf`, at `stamp`.
    pub fn write_static_transforms(
        &mut self,
        tf: &StaticTransforms,
        stamp: Nanos,
    ) -> Result<(), RecordingError> {
        let parent = tf
            .body_frame
            .clone()
            .unwrap_or_else(|| FrameId::new(names::BASE_LINK));
        let transforms: Vec<TransformStamped> = tf
            .body_from
            .iter()
            .map(|(child, body_from)| TransformStamped {
                stamp,
                parent: parent.clone(),
                child: child.clone(),
                parent_from_child: *body_from,
            })
            .collect();
        self.write_with(topics::TF_STATIC, &schema::TF_MESSAGE, stamp, stamp, |b| {
            ros::encode_tf(&transforms, b)
        })
    }

    /// Writes transforms on a `tf2_msgs/TFMessage` topic.
    pub fn write_tf(
        &mut self,
        topic: &str,
        transforms: &[TransformStamped],
        stamp: Nanos,
    ) -> Result<(), RecordingError> {
        self.write_with(topic, &schema::TF_MESSAGE, stamp, stamp, |b| {
            ros::encode_tf(transforms, b)
        })
    }

    /// Writes a `nav_msgs/Odometry` on `topic`.
    pub fn write_odometry(
        &mut self,
        topic: &str,
        m: &OdometryMsg,
        arrival: Nanos,
    ) -> Result<(), RecordingError> {
        self.write_with(topic, &schema::ODOMETRY, m.stamp, arrival, |b| {
            ros::encode_odometry(m, b)
        })
    }

    /// Writes a `sensor_msgs/PointCloud2` on `topic`.
    pub fn write_point_cloud2(
        &mut self,
        topic: &str,
        m: &ros::PointCloud2Msg,
        arrival: Nanos,
    ) -> Result<(), RecordingError> {
        self.write_with(topic, &schema::POINT_CLOUD2, m.stamp, arrival, |b| {
            ros::encode_point_cloud2(m, b)
        })
    }

    /// Writes a body trajectory (`world_from_body`) as `nav_msgs/Odometry` on `topic`
    /// (frame `world`, child `base_link`, zero twist; pose covariance when known, else
    /// zero), and with `tf_topic` also as `world → base_link` transforms there.
    pub fn write_trajectory(
        &mut self,
        topic: &str,
        traj: &Trajectory,
        tf_topic: Option<&str>,
    ) -> Result<(), RecordingError> {
        for s in &traj.samples {
            self.write_odometry(topic, &body_odometry(s), s.stamp)?;
            if let Some(tf) = tf_topic {
                self.write_tf(
                    tf,
                    &[TransformStamped {
                        stamp: s.stamp,
                        parent: FrameId::new(names::WORLD),
                        child: FrameId::new(names::BASE_LINK),
                        parent_from_child: s.world_from_body,
                    }],
                    s.stamp,
                )?;
            }
        }
        Ok(())
    }

    /// Writes a metadata record (`name` → key/value strings).
    pub fn write_metadata(
        &mut self,
        name: &str,
        entries: BTreeMap<String, String>,
    ) -> Result<(), RecordingError> {
        self.writer
            .write_metadata(&Metadata {
                name: name.to_string(),
                metadata: entries,
            })
            .map_err(RecordingError::mcap("writing metadata"))
    }

    /// Writes the summary and footer; returns what was written.
    pub fn finish(mut self) -> Result<RecordingStats, RecordingError> {
        self.writer
            .finish()
            .map_err(RecordingError::mcap("writing the summary"))?;
        self.stats.channels = self.channels.values().filter(|c| c.id.is_some()).count();
        // The buffered tail reaches the file here, where its error is seen (a drop would
        // swallow it and leave a file without its footer, reported as finished).
        let McapSink { writer, stats, .. } = self;
        writer
            .into_inner()
            .flush()
            .map_err(|e| RecordingError::mcap("writing the summary")(e.into()))?;
        Ok(stats)
    }
}

/// A body pose sample as `nav_msgs/Odometry` in `world` (no twist).
pub fn body_odometry(s: &vinebench_msgs::PoseSample) -> OdometryMsg {
    OdometryMsg {
        stamp: s.stamp,
        frame_id: FrameId::new(names::WORLD),
        child_frame_id: FrameId::new(names::BASE_LINK),
        pose: s.world_from_body,
        pose_covariance: s
            .covariance
            .as_deref()
            .copied()
            .unwrap_or_else(Matrix6::zeros),
        linear_velocity: Vector3::zeros(),
        angular_velocity: Vector3::zeros(),
        twist_covariance: Matrix6::zeros(),
    }
}

/// What the simulation hands the background writer.
// Items travel by value in batches (`Vec<RecordItem>`); boxing the large message variant
// would add an allocation per message on the simulation's thread.
#[allow(clippy::large_enum_variant)]
#[derive(Debug)]
pub enum RecordItem {
    /// `/tf_static` from the robot's static transforms.
    StaticTransforms(StaticTransforms, Nanos),
    /// A sensor message, at its arrival.
    Message(TimedMessage),
    /// A ground-truth body pose (`/ground_truth/odom` and `/ground_truth/tf`).
    Truth(vinebench_msgs::PoseSample),
    /// A whole trajectory on a topic (an estimate, written after the run), with an
    /// optional `tf2_msgs/TFMessage` topic for `world → base_link`.
    Trajectory {
        /// `nav_msgs/Odometry` topic.
        topic: String,
        /// Also as transforms on this topic.
        tf_topic: Option<String>,
        /// The poses.
        trajectory: Trajectory,
    },
    /// A metadata record.
    Metadata(String, BTreeMap<String, String>),
    /// A point cloud (`sensor_msgs/PointCloud2`) on a topic, at its stamp.
    PointCloud2(String, ros::PointCloud2Msg),
}

/// An MCAP file written on a background thread. Dropping it (also while unwinding)
/// finalizes the file; [`Recorder::finish`] does so and reports errors.
pub struct Recorder {
    /// Set by the writer thread at its first failed write.
    failed: Arc<AtomicBool>,
    tx: Option<SyncSender<Vec<RecordItem>>>,
    batch: Vec<RecordItem>,
    thread: Option<JoinHandle<Result<RecordingStats, RecordingError>>>,
    path: PathBuf,
}

impl Recorder {
    /// Creates `path` and starts the writer thread.
    pub fn create(path: &Path, opts: &SinkOptions) -> Result<Recorder, RecordingError> {
        let file = File::create(path).map_err(|source| RecordingError::Io {
            path: path.display().to_string(),
            source,
        })?;
        let sink = McapSink::new(BufWriter::with_capacity(1 << 20, file), opts)?;
        let (tx, rx) = sync_channel(QUEUE_DEPTH);
        let failed = Arc::new(AtomicBool::new(false));
        let flag = failed.clone();
        let thread = std::thread::Builder::new()
            .name("recording".into())
            .spawn(move || write_loop(sink, rx, &flag))
            .map_err(|source| RecordingError::Io {
                path: path.display().to_string(),
                source,
            })?;
        Ok(Recorder {
            failed,
            tx: Some(tx),
            batch: Vec::with_capacity(BATCH_ITEMS),
            thread: Some(thread),
            path: path.to_path_buf(),
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// True once a write has failed (a full disk, an I/O error): the run should stop and
    /// [`Recorder::finish`] says why, instead of simulating on for nothing.
    pub fn failed(&self) -> bool {
        self.failed.load(Ordering::Relaxed)
    }

    /// Queues an item for the writer, handing over [`BATCH_ITEMS`] at a time (waits
    /// while [`QUEUE_DEPTH`] batches are pending). A writer that failed drops items;
    /// [`Recorder::finish`] reports its error.
    pub fn send(&mut self, item: RecordItem) {
        self.batch.push(item);
        if self.batch.len() >= BATCH_ITEMS {
            self.flush();
        }
    }

    fn flush(&mut self) {
        if self.batch.is_empty() {
            return;
        }
        let batch = std::mem::replace(&mut self.batch, Vec::with_capacity(BATCH_ITEMS));
        if let Some(tx) = &self.tx {
            let _ = tx.send(batch);
        }
    }

    fn close(&mut self) -> Result<RecordingStats, RecordingError> {
        self.flush();
        drop(self.tx.take());
        match self.thread.take() {
            Some(t) => t
                .join()
                .map_err(|_| RecordingError::Internal("the recording thread panicked".into()))?,
            None => Err(RecordingError::Internal("recorder already closed".into())),
        }
    }

    /// Writes what is queued, the summary and the footer, and closes the file.
    pub fn finish(mut self) -> Result<RecordingStats, RecordingError> {
        let path = self.path.display().to_string();
        self.close().map_err(|e| e.in_file(&path))
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        if self.thread.is_some() {
            let _ = self.close();
        }
    }
}

fn write_loop<W: Write + Seek>(
    mut sink: McapSink<W>,
    rx: Receiver<Vec<RecordItem>>,
    failed: &AtomicBool,
) -> Result<RecordingStats, RecordingError> {
    let mut first_error = None;
    for item in rx.into_iter().flatten() {
        if first_error.is_some() {
            continue; // keep draining so the simulation never blocks on a dead writer
        }
        let r = match item {
            RecordItem::StaticTransforms(tf, stamp) => sink.write_static_transforms(&tf, stamp),
            RecordItem::Message(tm) => sink.write_message(&tm),
            RecordItem::Truth(s) => {
                sink.write_odometry(topics::GROUND_TRUTH_ODOM, &body_odometry(&s), s.stamp)
            }
            RecordItem::Trajectory {
                topic,
                tf_topic,
                trajectory,
            } => sink.write_trajectory(&topic, &trajectory, tf_topic.as_deref()),
            RecordItem::Metadata(name, entries) => sink.write_metadata(&name, entries),
            RecordItem::PointCloud2(topic, cloud) => {
                sink.write_point_cloud2(&topic, &cloud, cloud.stamp)
            }
        };
        if let Err(e) = r {
            failed.store(true, Ordering::Relaxed);
            first_error = Some(e);
        }
    }
    // The first error is the cause ("No space left on device"); finishing after it can
    // only add "attempted another write after a write method failed".
    let finished = sink.finish();
    match (first_error, finished) {
        (Some(e), _) => Err(e),
        (None, r) => r,
    }
}
