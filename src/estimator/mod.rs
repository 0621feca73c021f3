//! Estimators: trajectories from sensor messages alone.
//!
//! **Ground-truth firewall.** This module and its children may use only
//! `vinebench_msgs` (messages, frames, time, geodesy, trajectories), `nalgebra`, `serde`
//! and the standard library. They must run unchanged on a recording from a real robot.
//! `tests/firewall.rs` enforces this by parsing every file under `src/estimator/`.

pub mod eif;
pub mod params;
pub mod reorder;
pub mod single_source;

pub use params::{EifParams, EstimatorKind, EstimatorsParams};

use std::collections::BTreeMap;
use vinebench_msgs::{Message, Trajectory};

/// Counters an estimator keeps about its input, for the report.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EstimatorStats {
    /// Messages used, by kind (`imu`, `gnss_fix`, `gnss_velocity`, `tracking_odom`, ...).
    pub used: BTreeMap<String, u64>,
    /// Messages not used, by reason (`gnss_no_fix`, `gnss_gated`, `before_init`, ...).
    pub rejected: BTreeMap<String, u64>,
    /// Free-form notes for the report (e.g. "initialized at t = ... from RTK fix").
    pub notes: Vec<String>,
}

impl EstimatorStats {
    /// Increments `used[kind]`.
    pub fn count_used(&mut self, kind: &str) {
        *self.used.entry(kind.to_string()).or_default() += 1;
    }
    /// Increments `rejected[reason]`.
    pub fn count_rejected(&mut self, reason: &str) {
        *self.rejected.entry(reason.to_string()).or_default() += 1;
    }
}

/// A trajectory source driven by messages in stamp order.
pub trait Estimator {
    /// The source name used in file names and reports (`eif`, `gnss`, `tracking_camera`).
    fn name(&self) -> &'static str;
    /// Consumes one message. Messages arrive with non-decreasing stamps and have passed
    /// [`Message::validate`].
    fn handle(&mut self, msg: &Message);
    /// Called once after the last message.
    fn finish(&mut self);
    /// The trajectory so far (`world_from_body`, body = `base_link`).
    fn trajectory(&self) -> &Trajectory;
    /// Input counters.
    fn stats(&self) -> EstimatorStats;
}
