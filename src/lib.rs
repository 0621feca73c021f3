//! vinebench: a simulation-in-the-loop test bench for vineyard robots.
//!
//! This crate is the bench around the onboard algorithms: it reads scenarios, drives the
//! simulator (`vinebench-sim`), feeds the messages to the onboard estimator, SLAM and
//! mapper (`vinebench-onboard`, which sees only `vinebench-msgs` messages), records
//! everything, and is the only place where ground truth meets estimates. Its modules
//! follow the data flow:
//!
//! - [`scenario`]: scenario files, merged over `scenarios/defaults.toml`, validated.
//! - [`runner`]: one run: world → motion → sensors → onboard algorithms (and the mapping
//!   stage) → scoring → report and run folder.
//! - [`recording`]: every stream of a run to MCAP (ROS 2 profile) and back.
//! - [`replay`]: the onboard algorithms on a recording (a vinebench run's or a robot's).
//! - [`scoring`]: TUM files, evo-compatible ATE/RPE, the closed-loop metrics of the seed
//!   paper's Table 1, loop closures, maps, plots, and the expectation language.
//! - [`sweep`]: experiments: a scenario over seeds and parameters, sharded across
//!   machines, merged into statistics, plots, JUnit and a regression gate.
//! - [`bench`]: `vinebench bench`, the speed and memory figures of `docs/PERFORMANCE.md`.
//! - [`fsio`]: whole-or-nothing file writes and bounded reads.
//! - [`output`]: standard output that survives a closed pipe or a full disk.
//! - [`vocabulary`]: the SLAM's bag-of-words vocabulary trained on the keyframes of a
//!   simulated scenario (`vinebench vocabulary`).

pub mod bench;
pub mod fsio;
pub mod output;
pub mod recording;
pub mod replay;
pub mod runner;
pub mod scenario;
pub mod scoring;
pub mod sweep;
pub mod vocabulary;
