//! The SLAM's pipeline (`slam.pipeline`: a rig frame tracked on another core while the
//! next image is processed) gives exactly the results of running every step in turn, on
//! any number of threads: the same frames, poses, keyframes, landmarks and tag loops, bit
//! for bit, on the first 7 s of the box-occluder scenario (rendered frames of both
//! stereo pairs and the tag camera, the IMU).

// Test helpers panic on failure by design.
#![allow(clippy::unwrap_used)]

use vinebench_msgs::{Message, StaticTransforms};
use vinebench_onboard::slam::{SlamBaseline, SlamConfig, SlamOutput, VisualSlam, share_front_ends};

fn run(cfg: &SlamConfig, messages: &[Message], tf: &StaticTransforms) -> SlamOutput {
    run_as("slam", cfg, messages, tf)
}

fn run_as(
    source: &'static str,
    cfg: &SlamConfig,
    messages: &[Message],
    tf: &StaticTransforms,
) -> SlamOutput {
    let mut slam = VisualSlam::new(source, cfg.clone(), tf.clone(), None).unwrap();
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

#[test]
fn slams_sharing_their_stereo_pairs_give_what_each_gives_alone() {
    // The SLAM and two baselines on the same messages, as a scenario runs them: each
    // alone, then together with shared pairs (the first extracts, the others copy).
    let (messages, tf, cfg) = vinebench::bench::slam_bench_stream(7.0).unwrap();
    let cfg = SlamConfig {
        baselines: vec![SlamBaseline::NoLoops, SlamBaseline::SingleCamera],
        ..cfg
    };
    let runs = cfg.runs();
    let alone: Vec<String> = runs
        .iter()
        .map(|(source, c)| fingerprint(&run_as(source, c, &messages, &tf)))
        .collect();
    let mut slams: Vec<VisualSlam> = runs
        .iter()
        .map(|(source, c)| VisualSlam::new(source, c.clone(), tf.clone(), None).unwrap())
        .collect();
    share_front_ends(&mut slams);
    for m in &messages {
        for s in &mut slams {
            s.push(m).unwrap();
        }
    }
    let outs: Vec<SlamOutput> = slams.into_iter().map(VisualSlam::finish).collect();
    let pairs = |o: &SlamOutput| o.pairs.iter().map(|p| p.1).sum::<usize>();
    // The SLAM extracts every pair; the baseline with the same cameras copies every one,
    // the single-camera one copies its camera's.
    assert_eq!(outs[0].shared_pairs, 0);
    assert!(pairs(&outs[1]) >= 100, "{:?}", outs[1].pairs);
    assert_eq!(outs[1].shared_pairs, pairs(&outs[1]));
    assert!(outs[2].shared_pairs > 0 && outs[2].shared_pairs <= pairs(&outs[2]));
    for (o, want) in outs.iter().zip(&alone) {
        assert!(fingerprint(o) == *want, "{}", o.source);
    }
}
