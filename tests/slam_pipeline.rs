//! The SLAM's pipeline (`slam.pipeline`: a rig frame tracked on another core while the
//! next image is processed) gives exactly the results of running every step in turn, on
//! any number of threads: the same frames, poses, keyframes, landmarks and tag loops, bit
//! for bit, on the first 7 s of the box-occluder scenario (rendered frames of both
//! stereo pairs and the tag camera, the IMU).

// Test helpers panic on failure by design.
#![allow(clippy::unwrap_used)]

use vinebench_msgs::{Message, StaticTransforms};
use vinebench_onboard::slam::{SlamConfig, SlamOutput, VisualSlam};

fn run(cfg: &SlamConfig, messages: &[Message], tf: &StaticTransforms) -> SlamOutput {
    let mut slam = VisualSlam::new("slam", cfg.clone(), tf.clone(), None).unwrap();
    for m in messages {
        slam.push(m).unwrap();
    }
    slam.finish()
}

/// Everything of an output that must not depend on how it was scheduled.
fn fingerprint(o: &SlamOutput) -> String {
    let poses: Vec<_> = o
        .trajectory
        .samples
        .iter()
        .map(|s| (s.stamp, s.world_from_body.to_homogeneous()))
        .collect();
    format!(
        "{poses:?}\n{:?}\n{:?}\n{:?}\n{}\n{:?}\n{:?}\n{}",
        o.frames, o.losses, o.pairs, o.landmarks, o.loops, o.keyframe_descriptors, o.tag_detections
    )
}

#[test]
fn the_pipelined_slam_gives_the_results_of_the_serial_one_on_any_thread_count() {
    let (messages, tf, cfg) = vinebench::bench::slam_bench_stream(7.0).unwrap();
    let pipelined = SlamConfig {
        pipeline: true,
        ..cfg.clone()
    };
    let serial = SlamConfig {
        pipeline: false,
        ..cfg
    };
    let reference = run(&serial, &messages, &tf);
    // The stream is long enough to track, make keyframes and see the tag.
    assert!(
        reference.trajectory.len() >= 40,
        "{}",
        reference.trajectory.len()
    );
    assert!(reference.keyframe_descriptors.len() >= 3);
    assert!(
        reference.tag_detections >= 1,
        "{}",
        reference.tag_detections
    );
    let want = fingerprint(&reference);
    assert_eq!(fingerprint(&run(&pipelined, &messages, &tf)), want);
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let got = pool.install(|| run(&pipelined, &messages, &tf));
        assert!(fingerprint(&got) == want, "{threads} threads");
    }
}
