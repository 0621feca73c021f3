//! vinebench: a simulation-in-the-loop test bench for vineyard robots.
//!
//! The root crate holds the algorithms (which see only [`vinebench_msgs`] messages),
//! scoring (the only place ground truth meets estimates) and the scenario runner.
//!
//! - [`scenario`]: scenario files, merged over `scenarios/defaults.toml`, validated.
//! - [`estimator`]: the EIF and the single-source trajectories (behind the ground-truth
//!   firewall: messages in, trajectories out).
//! - [`scoring`]: TUM files, evo-compatible ATE/RPE, the closed-loop metrics of the seed
//!   paper's Table 1, plots.
//! - [`expect`]: the expectation language of scenario files.
//! - [`runner`]: world → motion → sensors → estimators → scoring → run folder.
//! - [`report`]: `report.json` and `report.md`.

pub mod bench;
pub mod estimator;
pub mod expect;
pub mod images;
pub mod report;
pub mod runner;
pub mod scenario;
pub mod scoring;
