//! Training the SLAM's bag-of-words vocabulary on rendered frames (`vinebench vocabulary`).
//!
//! A DBoW2 vocabulary ([`Vocabulary`]) is trained once, offline, on many images of the kind
//! of place it will recognize. Here the images are the visual SLAM's keyframes in a
//! simulated vineyard: [`collect_keyframes`] runs a scenario with the SLAM on (no
//! baselines, no loop closure, no mapper, no expectations, nothing written) and takes every
//! keyframe's ORB descriptors, all cameras together, as one training image; [`train`]
//! builds the vocabulary on them; [`train_from_scenario`] does both. [`write_atomic`]
//! writes the vocabulary file through a temporary file, so a reader never sees half a
//! file.
//!
//! `scenarios/vocabularies/training.toml` is the training scenario of the shipped
//! `scenarios/vocabularies/vineyard.vbvoc`.

use std::path::Path;
use std::time::Instant;

use indicatif::ProgressBar;
use thiserror::Error;

use crate::runner::{self, RunError};
use crate::scenario::{LoadedScenario, ScenarioError};
use vinebench_onboard::slam::Descriptor;
use vinebench_onboard::slam::bow::{BowError, Vocabulary, VocabularyConfig};
use vinebench_onboard::slam::loop_closing::LoopMethod;

/// Default branching factor `k` of `vinebench vocabulary` (DBoW2's and ORB-SLAM's).
pub const DEFAULT_BRANCHING: usize = 10;

/// Default depth `L` of `vinebench vocabulary`: `10^4` words for a training set of some
/// 10^5 to 10^6 descriptors (a few hundred keyframes of about 2,000), tens of descriptors
/// per word and a file of about 0.5 MB. ORB-SLAM's `L = 6` needs millions of training
/// images' worth of descriptors.
pub const DEFAULT_DEPTH: usize = 4;

/// Why a vocabulary could not be trained or written.
#[derive(Debug, Error)]
pub enum VocabularyError {
    /// The scenario cannot train a vocabulary (located in the scenario file).
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    /// The scenario could not be simulated.
    #[error(transparent)]
    Run(#[from] RunError),
    /// The simulation ran, but the SLAM made no keyframe with a descriptor.
    #[error(
        "{file}: the visual SLAM made no keyframe with ORB features in {simulated_s:.1} s \
         simulated ({frames} rig frames), so there is nothing to train a vocabulary on; \
         expected a scenario whose stereo cameras (slam.cameras) see the vineyard while the \
         robot drives for at least a few seconds (max_duration_s, route)"
    )]
    NoKeyframes {
        /// The scenario file.
        file: String,
        /// Simulated time, s.
        simulated_s: f64,
        /// Rig frames the SLAM was given.
        frames: usize,
    },
    /// Training failed (a setting out of range, too many descriptors).
    #[error("vocabulary: {0}")]
    Bow(#[from] BowError),
    /// Writing the vocabulary file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file or folder.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
}

/// The training images a scenario gave: one per SLAM keyframe.
#[derive(Clone, Debug)]
pub struct TrainingSet {
    /// Every keyframe's descriptors, all cameras together, in keyframe order.
    pub images: Vec<Vec<Descriptor>>,
    /// Simulated time, s.
    pub simulated_s: f64,
    /// Wall-clock time of the simulation (rendering and SLAM included), s.
    pub simulation_wall_s: f64,
    /// Distance the robot drove, m.
    pub distance_m: f64,
    /// True when the robot completed its route (false: stopped by `max_duration_s` or
    /// stuck).
    pub route_completed: bool,
    /// Tracking losses of the SLAM (each followed by a new map, whose keyframes count too).
    pub tracking_losses: usize,
}

impl TrainingSet {
    /// Number of descriptors over all images.
    pub fn descriptors(&self) -> usize {
        self.images.iter().map(Vec::len).sum()
    }
}

/// What a training run produced, for the summary line.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainingSummary {
    /// Training images: the SLAM's keyframes.
    pub keyframes: usize,
    /// Descriptors over all keyframes.
    pub descriptors: usize,
    /// Words (leaves) of the vocabulary.
    pub words: usize,
    /// Simulated time, s.
    pub simulated_s: f64,
    /// Distance the robot drove, m.
    pub distance_m: f64,
    /// True when the robot completed its route.
    pub route_completed: bool,
    /// Tracking losses of the SLAM.
    pub tracking_losses: usize,
    /// Wall-clock time of the simulation, s.
    pub simulation_wall_s: f64,
    /// Wall-clock time of the training, s.
    pub training_wall_s: f64,
    /// Wall-clock time of both, s.
    pub wall_s: f64,
}

/// The scenario `sc` made into a training run: the SLAM on with its loop closure off and
/// no baselines; no mapper, no motion comparisons and no expectations (nothing is scored).
pub fn training_scenario(sc: &LoadedScenario) -> LoadedScenario {
    let mut t = sc.clone();
    let s = &mut t.scenario;
    s.slam.enabled = true;
    s.slam.baselines.clear();
    s.slam.loop_closure.method = LoopMethod::None;
    s.mapper.enabled = false;
    s.motion.compare_with.clear();
    s.expect.clear();
    t.expectations.clear();
    t
}

/// Runs `sc` as a training run ([`training_scenario`]) and returns every keyframe of the
/// SLAM as a training image. `progress` follows the simulated seconds.
///
/// Errors: a located one when the scenario has no stereo camera; the runner's (located)
/// ones, among them a `slam.cameras` entry that is not a stereo camera; [`NoKeyframes`]
/// when the SLAM never made a keyframe.
///
/// [`NoKeyframes`]: VocabularyError::NoKeyframes
pub fn collect_keyframes(
    sc: &LoadedScenario,
    progress: Option<&ProgressBar>,
) -> Result<TrainingSet, VocabularyError> {
    if !sc
        .scenario
        .sensors
        .cameras
        .iter()
        .any(|c| c.right_frame.is_some())
    {
        return Err(sc
            .field_error(
                "sensors.cameras",
                "a vocabulary is trained on the visual SLAM's keyframes: expected at least one \
                 stereo camera (with `right_frame`) in [[sensors.cameras]], named in \
                 slam.cameras, found none (see scenarios/vocabularies/training.toml)",
            )
            .into());
    }
    let training = training_scenario(sc);
    let t0 = Instant::now();
    let sim = runner::simulate(&training, progress)?;
    let simulation_wall_s = t0.elapsed().as_secs_f64();
    // The SLAM itself comes first in `sim.slam`; a training run has no baselines.
    let (frames, tracking_losses, images) = sim
        .slam
        .into_iter()
        .next()
        .map(|o| (o.stats.frames, o.losses.len(), o.keyframe_descriptors))
        .unwrap_or_default();
    if images.iter().all(Vec::is_empty) {
        return Err(VocabularyError::NoKeyframes {
            file: sc.file.clone(),
            simulated_s: sim.duration_s,
            frames,
        });
    }
    Ok(TrainingSet {
        images,
        simulated_s: sim.duration_s,
        simulation_wall_s,
        distance_m: sim.distance_m,
        route_completed: sim.route_completed,
        tracking_losses,
    })
}

/// Trains a vocabulary on `set` (one document per keyframe).
pub fn train(
    set: &TrainingSet,
    cfg: &VocabularyConfig,
) -> Result<(Vocabulary, TrainingSummary), VocabularyError> {
    let t0 = Instant::now();
    let voc = Vocabulary::train(&set.images, cfg)?;
    let training_wall_s = t0.elapsed().as_secs_f64();
    let summary = TrainingSummary {
        keyframes: set.images.len(),
        descriptors: set.descriptors(),
        words: voc.n_words(),
        simulated_s: set.simulated_s,
        distance_m: set.distance_m,
        route_completed: set.route_completed,
        tracking_losses: set.tracking_losses,
        simulation_wall_s: set.simulation_wall_s,
        training_wall_s,
        wall_s: set.simulation_wall_s + training_wall_s,
    };
    Ok((voc, summary))
}

/// [`collect_keyframes`], then [`train`]: a vocabulary trained on the SLAM's keyframes of
/// scenario `sc`.
///
/// ```no_run
/// use vinebench::scenario::LoadedScenario;
/// use vinebench_onboard::slam::bow::VocabularyConfig;
/// let sc = LoadedScenario::load("scenarios/vocabularies/training.toml".as_ref())?;
/// let cfg = VocabularyConfig { branching: 10, depth: 4, ..VocabularyConfig::default() };
/// let (voc, summary) = vinebench::vocabulary::train_from_scenario(&sc, &cfg, None)?;
/// assert_eq!(voc.training_images() as usize, summary.keyframes);
/// vinebench::vocabulary::write_atomic(&voc, "/tmp/vineyard.vbvoc".as_ref())?;
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn train_from_scenario(
    sc: &LoadedScenario,
    cfg: &VocabularyConfig,
    progress: Option<&ProgressBar>,
) -> Result<(Vocabulary, TrainingSummary), VocabularyError> {
    // Settings are checked before minutes of simulation.
    cfg.validate().map_err(BowError::from)?;
    let set = collect_keyframes(sc, progress)?;
    train(&set, cfg)
}

/// Writes `voc` to `path` atomically: its parent folder is created, the bytes go to a
/// temporary file beside it, which is synced and renamed over `path` (on failure it is
/// removed and `path` is left as it was). Returns the file's size in bytes.
pub fn write_atomic(voc: &Vocabulary, path: &Path) -> Result<u64, VocabularyError> {
    let bytes = voc.to_bytes();
    crate::fsio::write_atomic(path, &bytes).map_err(|source| VocabularyError::Io {
        path: path.display().to_string(),
        source,
    })?;
    Ok(bytes.len() as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn training_scenario_turns_the_slam_on_alone() {
        let sc = LoadedScenario::from_str(
            "expect = [\"route_completed.robot >= 1\"]\n[slam]\nbaselines = [\"no_loops\"]\n\
             [mapper]\nenabled = true\n",
            "inline.toml",
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let t = training_scenario(&sc);
        assert!(t.scenario.slam.enabled);
        assert!(t.scenario.slam.baselines.is_empty());
        assert_eq!(t.scenario.slam.loop_closure.method, LoopMethod::None);
        assert!(!t.scenario.mapper.enabled);
        assert!(t.expectations.is_empty() && t.scenario.expect.is_empty());
        // Everything else is the scenario's.
        assert_eq!(t.scenario.world, sc.scenario.world);
        assert_eq!(t.scenario.sensors, sc.scenario.sensors);
    }

    #[test]
    fn a_scenario_without_stereo_cameras_is_a_located_error() {
        let sc = LoadedScenario::from_str("name = \"x\"\n", "plain.toml")
            .unwrap_or_else(|e| panic!("{e}"));
        let e = collect_keyframes(&sc, None).expect_err("no cameras");
        let msg = e.to_string();
        assert!(matches!(e, VocabularyError::Scenario(_)), "{msg}");
        assert!(msg.starts_with("plain.toml"), "{msg}");
        assert!(
            msg.contains("sensors.cameras") && msg.contains("stereo"),
            "{msg}"
        );
    }
}
