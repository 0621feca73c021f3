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
//! - [`recording`]: every stream of a run to MCAP (ROS 2 profile) and back.
//! - [`replay`]: the estimators on a recording (a vinebench run's or a robot's).
//! - [`mapper`]: geo-referenced RGB-D map, GRVI, elevation, Ball-Pivoting mesh, exports
//!   (behind the ground-truth firewall); [`mapping`] runs it in a scenario and scores it.
//! - [`slam`]: stereo visual SLAM, so far its ORB/SSC/stereo front-end (behind the firewall).
//! - [`vocabulary`]: the SLAM's bag-of-words vocabulary trained on the keyframes of a
//!   simulated scenario (`vinebench vocabulary`).

pub mod bench;
pub mod bench_mapper;
pub mod bench_recording;
pub mod estimator;
pub mod expect;
pub mod images;
pub mod mapper;
pub mod mapping;
pub mod recording;
pub mod replay;
pub mod report;
pub mod runner;
pub mod scenario;
pub mod scoring;
pub mod slam;
pub mod vocabulary;
