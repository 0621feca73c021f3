//! Re-ordering of messages by stamp.
//!
//! Messages reach the computer in arrival order; sensors have different latencies, so
//! stamps go backwards across sensors. [`ReorderBuffer`] holds messages in a min-heap
//! keyed by `(stamp, arrival sequence)` and releases every message whose stamp is at
//! least `window` behind the newest arrival, in stamp order (ties in arrival order, so
//! the output is deterministic). A message whose stamp is before the last released stamp
//! can no longer be put in order: it is dropped and counted as late.

use std::cmp::{Ordering, Reverse};
use std::collections::{BTreeMap, BinaryHeap};
use vinebench_msgs::{Message, Nanos, TimedMessage};

/// One held message; ordered by `(stamp, seq)` only.
#[derive(Debug)]
struct Held {
    key: Reverse<(Nanos, u64)>,
    msg: Message,
}

impl PartialEq for Held {
    fn eq(&self, other: &Self) -> bool {
        self.key == other.key
    }
}
impl Eq for Held {}
impl PartialOrd for Held {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Held {
    fn cmp(&self, other: &Self) -> Ordering {
        self.key.cmp(&other.key)
    }
}

/// A stamp-ordering window over an arrival-ordered message stream.
#[derive(Debug)]
pub struct ReorderBuffer {
    window: Nanos,
    heap: BinaryHeap<Held>,
    seq: u64,
    newest_arrival: Option<Nanos>,
    last_released: Option<Nanos>,
    late: BTreeMap<String, u64>,
}

impl ReorderBuffer {
    /// A buffer that holds messages until their stamp is `window` behind the newest
    /// arrival.
    pub fn new(window: Nanos) -> ReorderBuffer {
        ReorderBuffer {
            window,
            heap: BinaryHeap::new(),
            seq: 0,
            newest_arrival: None,
            last_released: None,
            late: BTreeMap::new(),
        }
    }

    /// Takes one message in arrival order and passes every message that is now due to
    /// `emit`, in stamp order. Returns `false` when the message was late (its stamp is
    /// before the last released stamp) and was dropped.
    pub fn push(&mut self, tm: &TimedMessage, mut emit: impl FnMut(Message)) -> bool {
        let stamp = tm.msg.stamp();
        let accepted = if self.last_released.is_some_and(|last| stamp < last) {
            *self.late.entry(tm.msg.topic().to_string()).or_default() += 1;
            false
        } else {
            self.heap.push(Held {
                key: Reverse((stamp, self.seq)),
                msg: tm.msg.clone(),
            });
            self.seq += 1;
            true
        };
        let newest = self
            .newest_arrival
            .map_or(tm.arrival, |n| if tm.arrival > n { tm.arrival } else { n });
        self.newest_arrival = Some(newest);
        let horizon = newest - self.window;
        while self.heap.peek().is_some_and(|h| h.key.0.0 <= horizon) {
            if let Some(h) = self.heap.pop() {
                self.last_released = Some(h.key.0.0);
                emit(h.msg);
            }
        }
        accepted
    }

    /// Releases everything still held, in stamp order (end of stream).
    pub fn flush(&mut self, mut emit: impl FnMut(Message)) {
        while let Some(h) = self.heap.pop() {
            self.last_released = Some(h.key.0.0);
            emit(h.msg);
        }
    }

    /// Messages dropped as late, by topic.
    pub fn late(&self) -> &BTreeMap<String, u64> {
        &self.late
    }

    /// Number of messages currently held.
    pub fn held(&self) -> usize {
        self.heap.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, Vector3};
    use proptest::prelude::*;
    use vinebench_msgs::{FrameId, GnssVelocityMsg};

    fn msg(stamp: i64, arrival: i64, tag: f64) -> TimedMessage {
        TimedMessage {
            arrival: Nanos(arrival),
            msg: Message::GnssVelocity(GnssVelocityMsg {
                stamp: Nanos(stamp),
                frame_id: FrameId::new("gnss_antenna"),
                velocity_in_world: Vector3::new(tag, 0.0, 0.0),
                covariance: Matrix3::identity(),
            }),
        }
    }

    fn tag(m: &Message) -> f64 {
        match m {
            Message::GnssVelocity(v) => v.velocity_in_world.x,
            _ => f64::NAN,
        }
    }

    #[test]
    fn releases_in_stamp_order_behind_the_window() {
        let mut b = ReorderBuffer::new(Nanos(10));
        let mut out = Vec::new();
        // Arrivals 0, 5, 12: stamps 0, -3 (came with latency), 2.
        assert!(b.push(&msg(0, 0, 0.0), |m| out.push(m)));
        assert!(b.push(&msg(-3, 5, 1.0), |m| out.push(m)));
        assert!(out.is_empty(), "nothing is 10 ns behind arrival 5 yet");
        assert!(b.push(&msg(2, 12, 2.0), |m| out.push(m)));
        // Horizon 12 - 10 = 2: stamps -3, 0, 2 are due.
        let stamps: Vec<i64> = out.iter().map(|m| m.stamp().0).collect();
        assert_eq!(stamps, vec![-3, 0, 2]);
        // A message stamped before the last released stamp is late.
        assert!(!b.push(&msg(1, 13, 3.0), |m| out.push(m)));
        assert_eq!(b.late().get("/gnss/fix_velocity"), Some(&1));
        // Equal to the last released stamp is still in order.
        assert!(b.push(&msg(2, 13, 4.0), |m| out.push(m)));
        assert_eq!(out.len(), 4);
        assert_eq!(b.held(), 0);
    }

    proptest! {
        /// Whatever the arrival order, the output is sorted by stamp with ties in arrival
        /// order, and every message is either released or counted late.
        #[test]
        fn output_is_sorted_and_complete(
            items in proptest::collection::vec((0i64..1000, 0i64..200), 1..200),
            window in 0i64..300,
        ) {
            // Arrivals are non-decreasing: sort by stamp + latency.
            let mut input: Vec<(i64, i64)> = items.iter().map(|&(s, l)| (s, s + l)).collect();
            input.sort_by_key(|&(s, a)| (a, s));
            let mut b = ReorderBuffer::new(Nanos(window));
            let mut out = Vec::new();
            for (i, &(s, a)) in input.iter().enumerate() {
                b.push(&msg(s, a, i as f64), |m| out.push(m));
            }
            b.flush(|m| out.push(m));
            let late: u64 = b.late().values().sum();
            prop_assert_eq!(out.len() as u64 + late, input.len() as u64);
            for w in out.windows(2) {
                let (s0, s1) = (w[0].stamp(), w[1].stamp());
                prop_assert!(s0 < s1 || (s0 == s1 && tag(&w[0]) < tag(&w[1])));
            }
            // With a window at least the largest latency nothing is late.
            if window >= 200 {
                prop_assert_eq!(late, 0);
            }
        }
    }
}
