//! Scoring: the only place where ground truth meets the estimates.

pub mod align;
pub mod metrics;
pub mod plots;
pub mod tum;

use serde::{Deserialize, Serialize};

/// `[scoring]` (documented with its defaults in `scenarios/defaults.toml`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScoringParams {
    /// Association tolerance, s (evo's `--t_max_diff`).
    pub t_max_diff_s: f64,
    /// RPE path distance, m.
    pub rpe_delta_m: f64,
    /// Ground-truth output rate, Hz.
    pub ground_truth_rate_hz: f64,
}

impl Default for ScoringParams {
    /// The values of `[scoring]` in `scenarios/defaults.toml`.
    fn default() -> Self {
        vinebench_msgs::defaults::section("scoring")
            .expect("the embedded scenarios/defaults.toml is checked by tests")
    }
}
