//! Estimators: trajectories from sensor messages alone.
//!
//! **Ground-truth firewall.** Like all of `vinebench-onboard`, the estimators see only
//! `vinebench_msgs` messages (the crate's dependency list allows nothing that reaches
//! truth; `tests/firewall.rs` checks it), so they run unchanged on a real robot's
//! recording.
//!
//! The stage the runner calls is [`EstimatorSet`]: messages in arrival order go in
//! ([`EstimatorSet::push`]); each is validated, re-ordered by stamp ([`reorder`]) and fanned
//! out to the estimators of `[estimators] run`: the EIF ([`eif`]) and the single-source
//! trajectories of the seed paper's Table 1 ([`single_source`]), and wheel dead reckoning
//! ([`dead_reckoning`]).

pub mod dead_reckoning;
pub mod eif;
pub mod ins;
mod linear;
pub mod measurement;
pub mod params;
pub mod reorder;
mod set;
pub mod single_source;
pub mod so3;
mod synthetic;

pub use dead_reckoning::DeadReckoning;
pub use eif::Eif;
pub use params::{EifParams, EstimatorKind, EstimatorsParams, ImuSampleModel, OrientationYaw};
pub use set::{EstimationOutput, EstimatorOutput, EstimatorSet, SensorFrames, StageStats};
pub use single_source::{GnssOnly, TrackingCameraOnly};

use std::collections::BTreeMap;
use std::fmt::Display;
use thiserror::Error;
use vinebench_msgs::{Message, Trajectory};

/// Counters an estimator keeps about its input, for the report.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EstimatorStats {
    /// Messages used, by kind (`imu`, `gnss_fix`, `gnss_velocity`, `tracking_odom`, ...).
    pub used: BTreeMap<String, u64>,
    /// Messages not used, by reason (`gnss_no_fix`, `gnss_gated`, `before_init`, ...).
    pub rejected: BTreeMap<String, u64>,
    /// Other counted events that are not about one message (`imu_gap_bridged`, ...).
    pub events: BTreeMap<String, u64>,
    /// Free-form notes for the report (e.g. "initialized at t = ... from RTK fix").
    pub notes: Vec<String>,
}

/// Increments `map[key]`, allocating the key only the first time (counters are bumped
/// once per IMU sample).
fn bump(map: &mut BTreeMap<String, u64>, key: &str) {
    match map.get_mut(key) {
        Some(c) => *c += 1,
        None => {
            map.insert(key.to_string(), 1);
        }
    }
}

impl EstimatorStats {
    /// Increments `used[kind]`.
    pub fn count_used(&mut self, kind: &str) {
        bump(&mut self.used, kind);
    }
    /// Increments `rejected[reason]`.
    pub fn count_rejected(&mut self, reason: &str) {
        bump(&mut self.rejected, reason);
    }
    /// Increments `events[event]`.
    pub fn count_event(&mut self, event: &str) {
        bump(&mut self.events, event);
    }
}

/// Why an estimator (or the estimation stage) cannot be built.
#[derive(Clone, Debug, Error, PartialEq)]
pub enum EstimatorError {
    /// A frame the estimator needs is not in the static transforms.
    #[error("static transforms: frame `{frame}` needed by estimator `{estimator}` is missing")]
    MissingFrame {
        /// The frame name.
        frame: String,
        /// The estimator that needs it.
        estimator: &'static str,
    },
    /// A parameter is out of range.
    #[error("{path}: expected {expected}, found {found}")]
    InvalidParam {
        /// Dotted scenario path (`estimators.eif.output_rate_hz`).
        path: String,
        /// What is allowed.
        expected: String,
        /// What was given.
        found: String,
    },
}

impl EstimatorError {
    /// An [`EstimatorError::InvalidParam`].
    pub fn invalid(path: &str, expected: &str, found: impl Display) -> EstimatorError {
        EstimatorError::InvalidParam {
            path: path.to_string(),
            expected: expected.to_string(),
            found: found.to_string(),
        }
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
    /// The trajectory, for a consumer that moves settled poses out of it
    /// ([`Trajectory::drain_settled`]); the estimator reads nothing from it.
    fn trajectory_mut(&mut self) -> &mut Trajectory;
    /// Input counters.
    fn stats(&self) -> EstimatorStats;
}
