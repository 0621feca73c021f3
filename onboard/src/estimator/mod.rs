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
    /// The normalized innovation squared of the GNSS position fixes (EIF), if any.
    pub gnss_nis: Option<NisSeries>,
}

/// Most points a [`NisSeries`] keeps for plotting (the counts cover every value).
pub const NIS_POINTS: usize = 4096;

/// The normalized innovation squared `yᵀS⁻¹y` of a filter's measurements of one kind:
/// exact counts against the chi-square band, and a thinned series for a plot. For a
/// consistent filter the NIS of an `m`-dimensional measurement follows χ²(m): mean `m`,
/// 95 % of the values inside the band.
#[derive(Clone, Debug, PartialEq)]
pub struct NisSeries {
    /// Degrees of freedom (the measurement's dimension).
    pub dof: u32,
    /// The two-sided 95 % band of χ²(dof): 2.5 % and 97.5 % quantiles.
    pub band: (f64, f64),
    /// Values seen.
    pub n: u64,
    /// Their sum.
    pub sum: f64,
    /// Values below the band (the filter is under-confident) and above it (over-confident
    /// or an outlier).
    pub below: u64,
    /// See `below`.
    pub above: u64,
    /// (stamp, NIS): every `stride`-th value, at most [`NIS_POINTS`].
    pub points: Vec<(vinebench_msgs::Nanos, f64)>,
    stride: u64,
}

impl NisSeries {
    /// An empty series of `dof` (1 to 3) degrees of freedom.
    pub fn new(dof: u32) -> NisSeries {
        // χ² quantiles, 2.5 % and 97.5 % (tables: 0.000982/5.024, 0.0506/7.378,
        // 0.2158/9.348).
        let band = match dof {
            1 => (0.000_982, 5.024),
            2 => (0.050_6, 7.378),
            _ => (0.215_8, 9.348),
        };
        NisSeries {
            dof,
            band,
            n: 0,
            sum: 0.0,
            below: 0,
            above: 0,
            points: Vec::new(),
            stride: 1,
        }
    }

    /// Adds one value.
    pub fn push(&mut self, t: vinebench_msgs::Nanos, nis: f64) {
        if !nis.is_finite() {
            return;
        }
        if self.n.is_multiple_of(self.stride) {
            if self.points.len() == NIS_POINTS {
                // Keep every other point and take half as many from now on.
                let mut i = 0;
                self.points.retain(|_| {
                    i += 1;
                    i % 2 == 1
                });
                self.stride *= 2;
            }
            if self.n.is_multiple_of(self.stride) {
                self.points.push((t, nis));
            }
        }
        self.n += 1;
        self.sum += nis;
        if nis < self.band.0 {
            self.below += 1;
        } else if nis > self.band.1 {
            self.above += 1;
        }
    }

    /// The mean NIS (the dof for a consistent filter).
    pub fn mean(&self) -> f64 {
        self.sum / self.n.max(1) as f64
    }

    /// The fraction of values inside the band (0.95 for a consistent filter).
    pub fn in_band(&self) -> f64 {
        (self.n - self.below - self.above) as f64 / self.n.max(1) as f64
    }
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

/// The error every estimator gives for static transforms without a body frame.
fn require_body_frame(
    transforms: &vinebench_msgs::StaticTransforms,
    estimator: &'static str,
) -> Result<(), EstimatorError> {
    if transforms.body_frame.is_none() {
        return Err(EstimatorError::MissingFrame {
            frame: "<body frame>".to_string(),
            estimator,
        });
    }
    Ok(())
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
