//! A trajectory between two frames of a recording's `/tf` tree, as `evo_ape bag2 FILE
//! /tf:parent.child ...` looks it up through tf2: every transform of the tf topic (and of
//! `/tf_static`) goes into a buffer; the pose of `child` in `parent` is looked up every
//! 0.1 s from the stamp of the first transform on the tf topic up to the newest time the
//! whole chain has, each moving link interpolated between its two samples around the time
//! (position linearly, rotation by slerp); a time outside a link's samples is skipped, as
//! tf2's extrapolation error makes evo skip it.
//!
//! Identifier syntax (evo's): `<tf topic>:<parent>.<child>[:<static topic>]`; the parent
//! ends at the first `.`.

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::collections::HashMap;
use vinebench_msgs::Nanos;

/// A parsed tf identifier.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TfId {
    /// The tf topic.
    pub topic: String,
    /// The parent (target) frame.
    pub parent: String,
    /// The child (source) frame.
    pub child: String,
    /// The static tf topic.
    pub static_topic: String,
}

impl TfId {
    /// Parses `topic:parent.child[:static_topic]`; `None` when `id` is not a tf
    /// identifier (a plain topic).
    pub fn parse(id: &str) -> Option<TfId> {
        let (topic, rest) = id.split_once(':')?;
        let (ids, static_topic) = match rest.rsplit_once(':') {
            Some((ids, s)) => (ids, s.to_string()),
            None => (rest, "/tf_static".to_string()),
        };
        let (parent, child) = ids.split_once('.')?;
        let name_ok = |s: &str| {
            let mut c = s.chars();
            c.next()
                .is_some_and(|f| f == '/' || f == '|' || f.is_ascii_alphabetic())
                && c.next()
                    .is_some_and(|f| "/|_".contains(f) || f.is_ascii_alphanumeric())
        };
        (name_ok(topic) && !parent.is_empty() && !child.is_empty() && name_ok(&static_topic)).then(
            || TfId {
                topic: topic.to_string(),
                parent: parent.to_string(),
                child: child.to_string(),
                static_topic,
            },
        )
    }
}

/// One link of the tree: the child's parent and the child's poses in it.
#[derive(Debug, Default)]
struct Link {
    parent: String,
    /// `(stamp, parent_from_child)`, sorted by stamp, one per stamp (the first given).
    samples: Vec<(Nanos, Isometry3<f64>)>,
    is_static: bool,
}

/// Why a lookup failed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum TfError {
    /// The frames are not connected.
    #[error("frames '{parent}' and '{child}' are not connected in the tf tree")]
    NotConnected {
        /// The parent frame.
        parent: String,
        /// The child frame.
        child: String,
    },
    /// A time outside a link's samples (tf2's extrapolation: the time is skipped).
    #[error("extrapolation")]
    Extrapolation,
}

/// The transforms of a recording, by child frame.
#[derive(Debug, Default)]
pub struct Buffer {
    links: HashMap<String, Link>,
}

/// The longest chain followed (a loop in the tree ends there).
const MAX_DEPTH: usize = 1000;

impl Buffer {
    /// Adds a transform (static ones hold at every time).
    pub fn insert(
        &mut self,
        parent: &str,
        child: &str,
        stamp: Nanos,
        pose: Isometry3<f64>,
        is_static: bool,
    ) {
        let link = self.links.entry(child.to_string()).or_default();
        link.parent = parent.to_string();
        if is_static {
            link.is_static = true;
            link.samples.clear();
        }
        link.samples.push((stamp, pose));
    }

    /// Sorts each link's samples (call after the last insert).
    pub fn finish(&mut self) {
        for l in self.links.values_mut() {
            l.samples.sort_by_key(|s| s.0);
            l.samples.dedup_by_key(|s| s.0);
        }
    }

    /// The frames from `frame` up to its root: `(frame, its link)`.
    fn chain<'a>(&'a self, frame: &'a str) -> Vec<(&'a str, &'a Link)> {
        let mut out = Vec::new();
        let mut f = frame;
        while let Some(l) = self.links.get(f) {
            out.push((f, l));
            f = &l.parent;
            if out.len() > MAX_DEPTH {
                break;
            }
        }
        out
    }

    /// tf2's latest common time of the chain between the frames (`None`: all static).
    pub fn latest_common_time(&self, parent: &str, child: &str) -> Option<Nanos> {
        let (pc, cc) = (self.chain(parent), self.chain(child));
        let common = common_ancestor(parent, &pc, child, &cc)?;
        pc.iter()
            .take_while(|(f, _)| *f != common)
            .chain(cc.iter().take_while(|(f, _)| *f != common))
            .filter(|(_, l)| !l.is_static)
            .filter_map(|(_, l)| l.samples.last().map(|s| s.0))
            .min()
    }

    /// `parent_from_child` at `t`.
    pub fn lookup(&self, parent: &str, child: &str, t: Nanos) -> Result<Isometry3<f64>, TfError> {
        let (pc, cc) = (self.chain(parent), self.chain(child));
        let common =
            common_ancestor(parent, &pc, child, &cc).ok_or_else(|| TfError::NotConnected {
                parent: parent.to_string(),
                child: child.to_string(),
            })?;
        let up = |chain: &[(&str, &Link)]| -> Result<Isometry3<f64>, TfError> {
            // common_from_frame, composed from the frame upwards.
            let mut acc = Isometry3::identity();
            for (f, l) in chain {
                if *f == common {
                    break;
                }
                acc = at(l, t)? * acc;
            }
            Ok(acc)
        };
        let common_from_parent = up(&pc)?;
        let common_from_child = up(&cc)?;
        Ok(common_from_parent.inverse() * common_from_child)
    }
}

/// The first frame both chains reach (the frames themselves count).
fn common_ancestor<'a>(
    parent: &'a str,
    pc: &[(&'a str, &'a Link)],
    child: &'a str,
    cc: &[(&'a str, &'a Link)],
) -> Option<&'a str> {
    let pu: Vec<&str> = std::iter::once(parent)
        .chain(pc.iter().map(|(_, l)| l.parent.as_str()))
        .collect();
    std::iter::once(child)
        .chain(cc.iter().map(|(_, l)| l.parent.as_str()))
        .find(|f| pu.contains(f))
}

/// A link's pose at `t`.
fn at(l: &Link, t: Nanos) -> Result<Isometry3<f64>, TfError> {
    if l.is_static {
        return l.samples.first().map(|s| s.1).ok_or(TfError::Extrapolation);
    }
    let i = l.samples.partition_point(|s| s.0 < t);
    match (
        l.samples.get(i),
        i.checked_sub(1).and_then(|k| l.samples.get(k)),
    ) {
        (Some(s1), _) if s1.0 == t => Ok(s1.1),
        (Some(s1), Some(s0)) => {
            let ratio = (t - s0.0).as_secs_f64() / (s1.0 - s0.0).as_secs_f64();
            let p =
                s0.1.translation
                    .vector
                    .lerp(&s1.1.translation.vector, ratio);
            let q: UnitQuaternion<f64> = s0.1.rotation.slerp(&s1.1.rotation, ratio);
            Ok(Isometry3::from_parts(Translation3::from(p), q))
        }
        _ => Err(TfError::Extrapolation),
    }
}

/// Most lookup times of one tf trajectory: a week at 10 Hz. Each lookup keeps a 4 × 4
/// pose (128 bytes), so the trajectory stays under 1 GiB in one allocation (a month would
/// ask for 3.3 GB: a single mutated stamp in a bag reaches that).
pub const MAX_SAMPLES: i64 = 6_048_000;

/// The sample times evo looks up: every 0.1 s from `start` up to `latest` (inclusive);
/// only `latest` when it is earlier than `start`. `None` beyond [`MAX_SAMPLES`] (stamps
/// that far apart are a damaged or hostile recording).
pub fn grid(start: Nanos, latest: Nanos) -> Option<Vec<Nanos>> {
    if latest < start {
        return Some(vec![latest]);
    }
    let step = 100_000_000_i64;
    let n = (latest.0 - start.0) / step;
    (n < MAX_SAMPLES).then(|| (0..=n).map(|k| Nanos(start.0 + k * step)).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn ids_parse_as_evo_splits_them() {
        let id = TfId::parse("/tf:map.base_link").unwrap();
        assert_eq!((id.topic.as_str(), id.parent.as_str()), ("/tf", "map"));
        assert_eq!(
            (id.child.as_str(), id.static_topic.as_str()),
            ("base_link", "/tf_static")
        );
        let id = TfId::parse("/tf:odom.base.footprint:/tf_static_2").unwrap();
        assert_eq!(
            (id.child.as_str(), id.static_topic.as_str()),
            ("base.footprint", "/tf_static_2")
        );
        assert!(TfId::parse("/odom").is_none());
        assert!(TfId::parse("/tf:.base").is_none());
        assert!(TfId::parse("/tf:map.").is_none());
    }

    #[test]
    fn a_chain_is_composed_and_interpolated() {
        // map -> odom (static, 1 m east), odom -> base moving 1 m/s north between 0 and 2 s
        // while turning 90°: at 1 s, base is at (1, 1) turned 45°.
        let mut b = Buffer::default();
        let iso = |x: f64, y: f64, yaw: f64| {
            Isometry3::new(Vector3::new(x, y, 0.0), Vector3::new(0.0, 0.0, yaw))
        };
        b.insert("map", "odom", Nanos(0), iso(1.0, 0.0, 0.0), true);
        b.insert("odom", "base", Nanos(0), iso(0.0, 0.0, 0.0), false);
        b.insert(
            "odom",
            "base",
            Nanos::from_secs(2),
            iso(0.0, 2.0, std::f64::consts::FRAC_PI_2),
            false,
        );
        b.finish();
        let p = b.lookup("map", "base", Nanos::from_secs(1)).unwrap();
        assert!((p.translation.vector - Vector3::new(1.0, 1.0, 0.0)).norm() < 1e-12);
        assert!((p.rotation.angle() - std::f64::consts::FRAC_PI_4).abs() < 1e-12);
        // The inverse direction, and a time beyond the samples.
        let q = b.lookup("base", "map", Nanos::from_secs(1)).unwrap();
        assert!((q * p).translation.vector.norm() < 1e-12);
        assert_eq!(
            b.lookup("map", "base", Nanos::from_secs(3)),
            Err(TfError::Extrapolation)
        );
        assert_eq!(
            b.latest_common_time("map", "base"),
            Some(Nanos::from_secs(2))
        );
        assert_eq!(b.latest_common_time("map", "odom"), None);
        assert!(matches!(
            b.lookup("map", "elsewhere", Nanos(0)),
            Err(TfError::NotConnected { .. })
        ));
        assert_eq!(grid(Nanos(5), Nanos(250_000_005)).map(|g| g.len()), Some(3));
        assert!(grid(Nanos(0), Nanos(i64::MAX)).is_none());
    }
}
