//! Multi-camera stereo visual SLAM (issue #7; Kokas et al., "Multicamera Visual SLAM for
//! Vineyard Inspection").
//!
//! Behind the ground-truth firewall like the estimator and the mapper: it sees image,
//! `CameraInfo` and IMU messages and `/tf_static` only. In data-flow order:
//!
//! - [`image`]: [`GrayImage`] from an `ImageMsg`, the scale [`Pyramid`], the 7×7 blur.
//! - [`fast`]: FAST-9 with a score, non-maximum suppression, per-cell adaptive threshold.
//! - [`ssc`]: Suppression via Square Covering, the strongest evenly spread keypoints.
//! - [`orb`]: orientation, steered BRIEF, and the [`OrbExtractor`] tying it together.
//! - [`stereo`]: left/right matching along rectified rows, subpixel, depth below 40 b.
//! - [`grid`]: keypoints bucketed for projection search.
//! - [`frontend`]: all of it for one stereo pair ([`StereoFrontEnd`]).
//! - [`motion_ba`]: motion-only bundle adjustment of the rig pose over the observations
//!   of every camera through the rig extrinsics (eqs. 1-3), Huber kernel, level weights,
//!   ORB-SLAM-style outlier rounds.
//! - [`gyro`]: the body's rotation between two stamps from the IMU, for free-running
//!   cameras.
//! - [`tracking`] and [`map`]: constant-velocity tracking by projection search, keyframes,
//!   landmark culling, local BA.
//! - [`bundle`]: local and global bundle adjustment of keyframe poses and landmarks
//!   (eqs. 4-5), mono and stereo residuals, sparse Schur-complement Levenberg-Marquardt.
//! - [`tags`]: AprilTag (tag36h11) detection on the tag camera and the tag's pose from its
//!   corners through the lens model.
//! - [`pose_graph`]: SE(3) pose graph over the keyframes.
//! - [`block_cholesky`]: the sparse block Cholesky factorization that bundle adjustment
//!   and the pose graph solve their keyframe systems with.
//! - [`loop_closing`]: tags registered at their first sighting; a sighting after the
//!   robot went away closes a loop (pose graph, landmarks moved, global BA).
//! - [`bow`]: bag-of-words vocabulary, keyframe database and DBoW2-style loop detection
//!   (the baseline; not wired into the SLAM yet).
//! - [`system`]: the message-level [`VisualSlam`] tying it together.
//! - [`bench`](mod@bench): timing of the front-end for `vinebench bench`.
//!
//! ```
//! use vinebench_onboard::slam::{FrontEndConfig, GrayImage, StereoCamera, StereoFrame, StereoFrontEnd};
//! let img = GrayImage::from_fn(320, 240, |x, y| ((x * 7 + y * 13) % 31 * 8) as u8);
//! let mut fe = StereoFrontEnd::new(FrontEndConfig::default()).expect("default config");
//! let mut frame = StereoFrame::default();
//! let cam = StereoCamera { fx: 300.0, baseline_m: 0.12 };
//! fe.process(&cam, &img, &img, &mut frame);
//! assert_eq!(frame.stereo.right_x.len(), frame.left.len());
//! ```

pub mod bench;
pub mod block_cholesky;
pub mod bow;
pub mod bundle;
pub mod fast;
pub mod frontend;
pub mod grid;
pub mod gyro;
pub mod image;
pub mod loop_closing;
pub mod map;
pub mod motion_ba;
pub mod orb;
pub mod place_recognition;
pub mod pose_graph;
pub mod ssc;
pub mod stereo;
pub mod system;
pub mod tags;
pub mod tracking;

pub use frontend::{FrontEndConfig, StereoFrame, StereoFrontEnd};
pub use grid::{FeatureGrid, GridConfig};
pub use image::{GrayImage, ImageError, Pyramid};
pub use orb::{Descriptor, Features, KeyPoint, OrbConfig, OrbExtractor, hamming};
pub use stereo::{StereoCamera, StereoConfig, StereoMatcher, StereoMatches};
pub use system::{
    SLAM_SOURCE, SlamBaseline, SlamConfig, SlamError, SlamOutput, VisualSlam, share_front_ends,
};
pub use tracking::{Tracker, TrackingConfig, TrackingLoss, TrackingState};

use thiserror::Error;

/// A SLAM setting out of range.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
#[error("invalid SLAM configuration: {0}")]
pub struct ConfigError(pub String);

/// `Ok` when `ok`, else the error `what`.
fn check(ok: bool, what: &str) -> Result<(), ConfigError> {
    if ok {
        Ok(())
    } else {
        Err(ConfigError(what.to_string()))
    }
}

/// A SLAM's trajectory as an estimate source (`slam`, or a baseline's), with its counters (frames,
/// keyframes, maps started, tracking losses) and every loss's time in the notes.
pub fn estimator_output(out: &SlamOutput) -> crate::estimator::EstimatorOutput {
    let mut stats = crate::estimator::EstimatorStats::default();
    for (camera, n) in &out.pairs {
        stats
            .used
            .insert(format!("stereo_pair/{camera}"), *n as u64);
    }
    let s = &out.stats;
    for (k, v) in [
        ("frames", s.frames),
        ("frames_tracked", s.tracked),
        ("keyframes", s.keyframes),
        ("maps_started", s.initializations),
        ("tracking_losses", out.losses.len()),
        ("landmarks_culled", s.culled),
        ("local_ba_runs", s.local_ba_runs),
        ("local_ba_outliers", s.local_ba_outliers),
        ("landmarks_at_end", out.landmarks),
    ] {
        stats.events.insert(k.to_string(), v as u64);
    }
    for (k, v) in [
        ("tag_images", out.tag_images),
        ("tag_detections", out.tag_detections),
        ("tags_registered", out.loop_stats.tags_registered),
        (
            "tag_sightings_without_pose",
            out.loop_stats.sightings_without_pose,
        ),
        ("tag_sightings_too_far", out.loop_stats.sightings_too_far),
        ("loops", out.loops.len()),
    ] {
        if out.tag_images > 0 {
            stats.events.insert(k.to_string(), v as u64);
        }
    }
    for l in &out.loops {
        let ba = l.global_ba.map_or_else(
            || "no global BA".to_string(),
            |b| {
                format!(
                    "global BA over {} keyframes, {} landmarks, {} observations: {} iterations, \
                     cost {:.0} -> {:.0}, {} outliers",
                    b.keyframes,
                    b.landmarks,
                    b.observations,
                    b.iterations,
                    b.initial_cost,
                    b.final_cost,
                    b.outliers
                )
            },
        );
        stats.notes.push(format!(
            "loop ({}{}) at {} onto {}: keyframe {} corrected by {:.3} m, {:.2} deg; pose graph \
             cost {:.1} -> {:.1}; {ba}",
            l.source.name(),
            l.tag_id.map(|i| format!(" {i}")).unwrap_or_default(),
            l.query_stamp,
            l.matched_stamp,
            l.query_keyframe,
            l.correction_m,
            l.correction_deg,
            l.pose_graph_cost.0,
            l.pose_graph_cost.1,
        ));
    }
    for l in &out.losses {
        stats.notes.push(match l.end {
            Some(end) => format!(
                "tracking lost at {} for {:.2} s",
                l.start,
                (end - l.start).as_secs_f64()
            ),
            None => format!("tracking lost at {} until the end", l.start),
        });
    }
    crate::estimator::EstimatorOutput {
        name: out.source,
        trajectory: out.trajectory.clone(),
        stats,
    }
}
