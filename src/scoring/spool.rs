//! Trajectories that scoring reads in passes, from memory or from disk.
//!
//! A long run cannot keep its trajectories in memory: ground truth at 200 Hz and three
//! estimates grow by about 50 kB per simulated second, 1.4 GB over an 8-hour shift. The
//! runner therefore appends every pose to a [`PoseSpool`], a binary file in the run
//! folder (unnamed: it disappears with the process), and scoring reads it back in
//! sequential passes through [`Poses`]: association is a merge of two sorted streams,
//! Umeyama is built from sums, RPE keeps one pose pair, plots thin as they read. What
//! stays in memory is per *associated pose* (8 bytes of error per pose for exact
//! medians), not per sample.
//!
//! Records are fixed-layout little-endian and lossless (the `f64`s and stamps written
//! are the ones read back, bit for bit), so a run scores the same from its spool as from
//! memory.

use nalgebra::{Isometry3, Matrix6, Quaternion, Translation3, UnitQuaternion};
use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::Path;
use std::sync::Mutex;
use vinebench_msgs::{Nanos, PoseSample, Trajectory};

/// A pose of a trajectory: stamp and `world_from_body`.
pub type Pose = (Nanos, Isometry3<f64>);

/// A time-ordered pose sequence scoring can read any number of times, front to back.
///
/// Implemented by [`Trajectory`] (in memory) and [`PoseSpool`] (on disk). Stamps are
/// strictly increasing.
pub trait Poses: Sync {
    /// Number of poses.
    fn len(&self) -> usize;
    /// True when there is no pose.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// The poses, in time order (a new pass from the start on every call).
    fn poses(&self) -> Box<dyn Iterator<Item = Pose> + '_>;
    /// The first pose.
    fn first(&self) -> Option<Pose>;
    /// The last pose.
    fn last(&self) -> Option<Pose>;
    /// The first error that ended a pass early (a read error of a file on disk; never for
    /// memory). A caller that must not use a partial result checks it after its passes.
    fn check(&self) -> io::Result<()> {
        Ok(())
    }
}

impl Poses for Trajectory {
    fn len(&self) -> usize {
        self.samples.len()
    }
    fn poses(&self) -> Box<dyn Iterator<Item = Pose> + '_> {
        Box::new(self.samples.iter().map(|s| (s.stamp, s.world_from_body)))
    }
    fn first(&self) -> Option<Pose> {
        self.samples.first().map(|s| (s.stamp, s.world_from_body))
    }
    fn last(&self) -> Option<Pose> {
        self.samples.last().map(|s| (s.stamp, s.world_from_body))
    }
}

/// Poses seen through a fixed transform: `(stamp, world_from_map · map_from_body)` for
/// each pose of `poses` (e.g. a SLAM trajectory put in the world by its known start).
pub struct Moved<'a> {
    /// The poses, in their own frame.
    pub poses: &'a dyn Poses,
    /// The transform applied on the left of each.
    pub world_from_map: nalgebra::Isometry3<f64>,
}

impl Poses for Moved<'_> {
    fn len(&self) -> usize {
        self.poses.len()
    }
    fn poses(&self) -> Box<dyn Iterator<Item = Pose> + '_> {
        Box::new(
            self.poses
                .poses()
                .map(|(t, p)| (t, self.world_from_map * p)),
        )
    }
    fn first(&self) -> Option<Pose> {
        self.poses
            .first()
            .map(|(t, p)| (t, self.world_from_map * p))
    }
    fn last(&self) -> Option<Pose> {
        self.poses.last().map(|(t, p)| (t, self.world_from_map * p))
    }
    fn check(&self) -> io::Result<()> {
        self.poses.check()
    }
}

/// Bytes of a record without covariance: tag, stamp, translation, quaternion.
const BASE_BYTES: usize = 1 + 8 + 7 * 8;
/// Bytes of a record with covariance (36 `f64`, column-major).
const COV_BYTES: usize = BASE_BYTES + 36 * 8;
/// Read buffer of a pass.
const READ_BUFFER: usize = 64 * 1024;

/// Appends poses to a spool file; [`SpoolWriter::finish`] makes it readable.
pub struct SpoolWriter {
    out: BufWriter<File>,
    len: usize,
    bytes: u64,
    first: Option<Pose>,
    last: Option<Pose>,
    label: String,
}

impl SpoolWriter {
    /// A new spool in `dir` (an unnamed file that the OS removes when it is closed), or
    /// in the system's temporary folder without `dir`. `label` names it in errors.
    pub fn create(dir: Option<&Path>, label: impl Into<String>) -> io::Result<SpoolWriter> {
        let file = match dir {
            Some(d) => tempfile::tempfile_in(d)?,
            None => tempfile::tempfile()?,
        };
        Ok(SpoolWriter {
            out: BufWriter::with_capacity(READ_BUFFER, file),
            len: 0,
            bytes: 0,
            first: None,
            last: None,
            label: label.into(),
        })
    }

    /// Appends a pose; a pose whose stamp is not after the last one is ignored (returns
    /// `false`), as [`Trajectory::push`] does.
    pub fn push(&mut self, s: &PoseSample) -> io::Result<bool> {
        if self.last.is_some_and(|(t, _)| s.stamp <= t) {
            return Ok(false);
        }
        let mut rec = [0u8; COV_BYTES];
        rec[0] = u8::from(s.covariance.is_some());
        rec[1..9].copy_from_slice(&s.stamp.0.to_le_bytes());
        let p = &s.world_from_body;
        let q = p.rotation.coords;
        let values = p.translation.vector.iter().chain(q.iter());
        for (i, v) in values.enumerate() {
            rec[9 + 8 * i..17 + 8 * i].copy_from_slice(&v.to_le_bytes());
        }
        let n = if let Some(c) = &s.covariance {
            for (i, v) in c.iter().enumerate() {
                rec[BASE_BYTES + 8 * i..BASE_BYTES + 8 + 8 * i].copy_from_slice(&v.to_le_bytes());
            }
            COV_BYTES
        } else {
            BASE_BYTES
        };
        self.out.write_all(&rec[..n])?;
        self.bytes += n as u64;
        self.len += 1;
        let pose = (s.stamp, s.world_from_body);
        self.first.get_or_insert(pose);
        self.last = Some(pose);
        Ok(true)
    }

    /// Number of poses so far.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when no pose was pushed.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Flushes the file and returns the readable spool.
    pub fn finish(self) -> io::Result<PoseSpool> {
        let file = self.out.into_inner().map_err(|e| e.into_error())?;
        Ok(PoseSpool {
            file,
            len: self.len,
            bytes: self.bytes,
            first: self.first,
            last: self.last,
            label: self.label,
            error: Mutex::new(None),
        })
    }
}

impl std::fmt::Debug for SpoolWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "SpoolWriter({}, {} poses)", self.label, self.len)
    }
}

/// A finished spool: poses on disk, read in passes.
///
/// A read error ends the pass early and is kept: [`PoseSpool::check`] returns it, so a
/// caller that scored from the spool can tell that what it computed is incomplete.
pub struct PoseSpool {
    file: File,
    len: usize,
    bytes: u64,
    first: Option<Pose>,
    last: Option<Pose>,
    label: String,
    error: Mutex<Option<io::Error>>,
}

impl std::fmt::Debug for PoseSpool {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "PoseSpool({}, {} poses)", self.label, self.len)
    }
}

impl PoseSpool {
    /// A spool of an in-memory trajectory (tests, and sources that finish in memory).
    pub fn from_trajectory(
        dir: Option<&Path>,
        label: impl Into<String>,
        traj: &Trajectory,
    ) -> io::Result<PoseSpool> {
        let mut w = SpoolWriter::create(dir, label)?;
        for s in &traj.samples {
            w.push(s)?;
        }
        w.finish()
    }

    /// What the spool holds, for error messages.
    pub fn label(&self) -> &str {
        &self.label
    }

    /// Bytes on disk.
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// Every sample with its covariance, in time order.
    pub fn samples(&self) -> impl Iterator<Item = PoseSample> + '_ {
        Records::new(self).map(|r| r.sample())
    }

    /// The whole spool in memory (what a consumer that needs random access uses).
    pub fn to_trajectory(&self) -> io::Result<Trajectory> {
        let t = Trajectory {
            samples: self.samples().collect(),
        };
        self.check()?;
        Ok(t)
    }

    fn fail(&self, e: io::Error) {
        if let Ok(mut slot) = self.error.lock() {
            slot.get_or_insert(e);
        }
    }
}

impl Poses for PoseSpool {
    fn len(&self) -> usize {
        self.len
    }
    fn poses(&self) -> Box<dyn Iterator<Item = Pose> + '_> {
        Box::new(Records::new(self).map(|r| (r.stamp, r.pose)))
    }
    fn first(&self) -> Option<Pose> {
        self.first
    }
    fn last(&self) -> Option<Pose> {
        self.last
    }
    fn check(&self) -> io::Result<()> {
        match self.error.lock() {
            Ok(e) => match e.as_ref() {
                None => Ok(()),
                Some(e) => Err(io::Error::new(e.kind(), format!("{}: {e}", self.label))),
            },
            Err(_) => Err(io::Error::other(format!(
                "{}: a reader of it panicked",
                self.label
            ))),
        }
    }
}

/// One decoded record.
struct Record {
    stamp: Nanos,
    pose: Isometry3<f64>,
    covariance: Option<Box<Matrix6<f64>>>,
}

impl Record {
    fn sample(self) -> PoseSample {
        PoseSample {
            stamp: self.stamp,
            world_from_body: self.pose,
            covariance: self.covariance,
        }
    }
}

/// A pass over a spool: positioned reads (`pread`), so passes run side by side.
struct Records<'a> {
    spool: &'a PoseSpool,
    offset: u64,
    buf: Vec<u8>,
    start: usize,
    end: usize,
    done: bool,
}

impl<'a> Records<'a> {
    fn new(spool: &'a PoseSpool) -> Records<'a> {
        Records {
            spool,
            offset: 0,
            buf: vec![0; READ_BUFFER],
            start: 0,
            end: 0,
            done: spool.len == 0,
        }
    }

    /// Makes at least `n` bytes available from `start` (fewer only at the end of file).
    fn fill(&mut self, n: usize) -> io::Result<()> {
        if self.end - self.start >= n {
            return Ok(());
        }
        self.buf.copy_within(self.start..self.end, 0);
        self.end -= self.start;
        self.start = 0;
        while self.end < n && self.offset < self.spool.bytes {
            let want = (self.buf.len() - self.end).min((self.spool.bytes - self.offset) as usize);
            let got = read_at(
                &self.spool.file,
                &mut self.buf[self.end..self.end + want],
                self.offset,
            )?;
            if got == 0 {
                return Err(io::Error::new(
                    io::ErrorKind::UnexpectedEof,
                    format!("{} ends early", self.spool.label),
                ));
            }
            self.end += got;
            self.offset += got as u64;
        }
        Ok(())
    }

    fn read(&mut self) -> io::Result<Option<Record>> {
        self.fill(BASE_BYTES)?;
        if self.end == self.start {
            return Ok(None);
        }
        let tag = self.buf[self.start];
        let n = if tag == 1 { COV_BYTES } else { BASE_BYTES };
        self.fill(n)?;
        if self.end - self.start < n || tag > 1 {
            return Err(io::Error::new(
                io::ErrorKind::InvalidData,
                format!("{}: damaged record", self.spool.label),
            ));
        }
        let b = &self.buf[self.start..self.start + n];
        let f = |i: usize| {
            let mut a = [0u8; 8];
            a.copy_from_slice(&b[9 + 8 * i..17 + 8 * i]);
            f64::from_le_bytes(a)
        };
        let mut st = [0u8; 8];
        st.copy_from_slice(&b[1..9]);
        let pose = Isometry3::from_parts(
            Translation3::new(f(0), f(1), f(2)),
            UnitQuaternion::new_unchecked(Quaternion::new(f(6), f(3), f(4), f(5))),
        );
        let covariance =
            (tag == 1).then(|| Box::new(Matrix6::from_iterator((0..36).map(|i| f(7 + i)))));
        self.start += n;
        Ok(Some(Record {
            stamp: Nanos(i64::from_le_bytes(st)),
            pose,
            covariance,
        }))
    }
}

impl Iterator for Records<'_> {
    type Item = Record;
    fn next(&mut self) -> Option<Record> {
        if self.done {
            return None;
        }
        match self.read() {
            Ok(Some(r)) => Some(r),
            Ok(None) => {
                self.done = true;
                None
            }
            Err(e) => {
                self.done = true;
                self.spool.fail(e);
                None
            }
        }
    }
}

#[cfg(unix)]
fn read_at(file: &File, buf: &mut [u8], offset: u64) -> io::Result<usize> {
    std::os::unix::fs::FileExt::read_at(file, buf, offset)
}

#[cfg(windows)]
fn read_at(file: &File, buf: &mut [u8], offset: u64) -> io::Result<usize> {
    std::os::windows::fs::FileExt::seek_read(file, buf, offset)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_trajectory(n: usize, rng: &mut ChaCha8Rng) -> Trajectory {
        let mut t = Trajectory::new();
        let mut stamp = 1_700_000_000_000_000_000_i64;
        for i in 0..n {
            stamp += rng.random_range(1..10_000_000);
            let q = UnitQuaternion::from_euler_angles(
                rng.random_range(-3.0..3.0),
                rng.random_range(-1.5..1.5),
                rng.random_range(-3.0..3.0),
            );
            let covariance = (i % 3 == 0).then(|| {
                Box::new(Matrix6::from_fn(|r, c| {
                    (r * 6 + c) as f64 * rng.random_range(-1.0..1.0)
                }))
            });
            t.push(PoseSample {
                stamp: Nanos(stamp),
                world_from_body: Isometry3::from_parts(
                    Translation3::new(
                        rng.random_range(-1e4..1e4),
                        rng.random_range(-1e4..1e4),
                        rng.random_range(-10.0..10.0),
                    ),
                    q,
                ),
                covariance,
            });
        }
        t
    }

    #[test]
    fn a_spool_gives_back_every_sample_bit_for_bit_in_any_number_of_passes() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        // More than one read buffer, records of both sizes straddling its boundary.
        let traj = random_trajectory(5000, &mut rng);
        let spool = PoseSpool::from_trajectory(None, "test", &traj).unwrap();
        assert_eq!(spool.len(), 5000);
        assert_eq!(spool.to_trajectory().unwrap(), traj);
        // Two passes side by side.
        let a: Vec<Pose> = spool.poses().collect();
        let b: Vec<Pose> = spool.poses().zip(traj.poses()).map(|(x, _)| x).collect();
        assert_eq!(a, b);
        assert_eq!(a, traj.poses().collect::<Vec<_>>());
        assert_eq!(spool.first(), traj.first());
        assert_eq!(spool.last(), traj.last());
        spool.check().unwrap();
    }

    #[test]
    fn a_spool_refuses_stamps_that_do_not_increase_like_a_trajectory() {
        let mut w = SpoolWriter::create(None, "test").unwrap();
        let s = |t: i64| PoseSample {
            stamp: Nanos(t),
            world_from_body: Isometry3::identity(),
            covariance: None,
        };
        assert!(w.push(&s(5)).unwrap());
        assert!(!w.push(&s(5)).unwrap());
        assert!(!w.push(&s(4)).unwrap());
        assert!(w.push(&s(6)).unwrap());
        let spool = w.finish().unwrap();
        assert_eq!(spool.poses().map(|p| p.0.0).collect::<Vec<_>>(), vec![5, 6]);
        let empty = SpoolWriter::create(None, "empty")
            .unwrap()
            .finish()
            .unwrap();
        assert!(empty.is_empty() && empty.poses().next().is_none() && empty.first().is_none());
    }
}
