//! Closed loop (issue #29): the robot steers on its own estimate.
//!
//! - A constant offset added to the steering estimate moves the true path by minus that
//!   offset (closed form: the follower puts the *estimate* on the route).
//! - A steering source that goes silent stops the robot within the stated age.
//! - Runs with an estimate in the loop are bit-identical across thread counts, the
//!   pipelined visual SLAM in the loop included; a SLAM that loses track stops the robot
//!   once its lost frame is available (arrival + latency).
//!
//! (The default, `localization = "truth"`, keeps today's trajectories: the golden digest
//! of tests/determinism.rs.)
#![allow(clippy::unwrap_used)]

use assert_cmd::Command;
use std::path::Path;
use vinebench::runner::{RobotOutcome, RobotReport, simulate};
use vinebench::scenario::LoadedScenario;
use vinebench_sim::world::RowLayout;

fn short_loop(extra: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/short-loop.toml");
    format!("{}\n{extra}", std::fs::read_to_string(path).unwrap())
}

/// Mean offset across the rows of the true positions in the middle of the rows.
fn mean_lane_offset(text: &str) -> f64 {
    let sc = LoadedScenario::from_str(text, "closed-loop.toml").unwrap_or_else(|e| panic!("{e}"));
    let sim = simulate(&sc, None).unwrap_or_else(|e| panic!("{e}"));
    assert!(sim.route_completed, "{:?}", sim.outcome);
    let layout = RowLayout::new(&sc.scenario.world.rows);
    let truth = sim.truth.to_trajectory().unwrap();
    let offsets: Vec<f64> = truth
        .positions()
        .map(|p| layout.row_coords(&p.xy()))
        .filter(|&(_, s)| (5.0..15.0).contains(&s))
        .map(|(o, _)| o)
        .collect();
    assert!(offsets.len() > 1000, "{} samples mid-row", offsets.len());
    offsets.iter().sum::<f64>() / offsets.len() as f64
}

#[test]
fn an_offset_estimate_moves_the_true_path_by_minus_the_offset() {
    let base = short_loop("[control]\nlocalization = \"eif\"\n");
    let offset = base.replace(
        "localization = \"eif\"\n",
        "localization = \"eif\"\nestimate_offset_m = [0.0, 0.2]\n",
    );
    let without = mean_lane_offset(&base);
    let with = mean_lane_offset(&offset);
    // The rows run at yaw 25°: their normal is (−sin 25°, cos 25°), so a 0.2 m north
    // offset of the estimate is 0.2·cos 25° across the rows, and the truth moves by minus
    // that.
    let expected = -0.2 * 25f64.to_radians().cos();
    let shift = with - without;
    assert!(
        (shift - expected).abs() < 0.01,
        "the true path moved {shift:.4} m across the rows, expected {expected:.4} m"
    );
}

#[test]
fn a_silent_steering_source_stops_the_robot_within_the_stated_age() {
    // GNSS alone steers; from 15 s the receiver has no fix, so GNSS-only gives nothing.
    let text = short_loop("[control]\nlocalization = \"gnss\"\nmax_estimate_age_ms = 500.0\n")
        .replace("status = \"single\"", "status = \"no_fix\"");
    let sc = LoadedScenario::from_str(&text, "closed-loop.toml").unwrap_or_else(|e| panic!("{e}"));
    let sim = simulate(&sc, None).unwrap_or_else(|e| panic!("{e}"));
    let robot = RobotReport::new(&sim);
    let RobotOutcome::StoppedEstimateLost {
        at_s,
        stopped_at_s,
        age_s,
        ..
    } = robot.outcome
    else {
        panic!("expected stopped_estimate_lost, got {}", robot.outcome);
    };
    // The last fix is stamped within one GNSS period (0.1 s) before 15 s; the stop comes
    // at the first step after it is 0.5 s old (steps are ≤ 5 ms apart here).
    assert!((0.5..0.51).contains(&age_s), "age {age_s}");
    assert!(
        (15.4..15.51).contains(&stopped_at_s),
        "stopped at {stopped_at_s}"
    );
    // The run ended with the robot standing, a few seconds later at most.
    assert!(at_s > stopped_at_s && at_s < stopped_at_s + 10.0, "{at_s}");
    assert!(!sim.route_completed);
    assert_eq!(robot.metric("stopped_by_safety"), Some(1.0));
    assert_eq!(robot.metric("route_completed"), Some(0.0));
}

#[test]
fn closed_loop_runs_are_bit_identical_across_thread_counts() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("closed-loop.toml");
    std::fs::write(&scenario, short_loop("[control]\nlocalization = \"eif\"\n")).unwrap();
    for threads in ["1", "2"] {
        Command::cargo_bin("vinebench")
            .unwrap()
            .args(["--threads", threads, "run", "--quiet", "--out"])
            .arg(dir.path().join(threads))
            .arg(&scenario)
            .assert()
            .code(0);
    }
    for f in [
        "ground_truth.tum",
        "estimate_eif.tum",
        "estimate_gnss.tum",
        "report.json",
    ] {
        assert_eq!(
            std::fs::read(dir.path().join("1").join(f)).unwrap(),
            std::fs::read(dir.path().join("2").join(f)).unwrap(),
            "{f} differs between 1 and 2 threads"
        );
    }
}

#[test]
fn closed_loop_needs_a_physics_model_and_a_source_of_the_run() {
    let kinematic = short_loop("[control]\nlocalization = \"eif\"\n")
        .replace("[motion]\n", "[motion]\nmodel = \"kinematic\"\n");
    let sc = LoadedScenario::from_str(&kinematic, "k.toml").unwrap();
    let e = vinebench::runner::validate(&sc).unwrap_err().to_string();
    assert!(
        e.contains("control.localization") && e.contains("rapier"),
        "{e}"
    );
    let e = LoadedScenario::from_str(
        &short_loop("[control]\nlocalization = \"slam\"\n"),
        "s.toml",
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("control.localization") && e.contains("SLAM"),
        "{e}"
    );
    // With [slam] on, its sources steer, but only those the run has.
    let e = LoadedScenario::from_str(
        &short_loop("[control]\nlocalization = \"slam_single_camera\"\n[slam]\nenabled = true\n"),
        "s.toml",
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("control.localization") && e.contains("\"slam\""),
        "{e}"
    );
}

#[test]
fn slam_in_the_loop_is_bit_identical_across_thread_counts_and_stops_when_lost() {
    // The rover steered on the single-camera SLAM loses track as the carton box fills
    // its view; the multi-camera SLAM runs beside it (pipelined, with tag loops).
    let scenario = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenarios/closed-loop-box-occluder-single.toml");
    let dir = tempfile::tempdir().unwrap();
    for threads in ["1", "2"] {
        // Exit 0: the scenario's own expectations hold (it stops, no collision).
        Command::cargo_bin("vinebench")
            .unwrap()
            .args(["--threads", threads, "run", "--quiet", "--out"])
            .arg(dir.path().join(threads))
            .arg(&scenario)
            .assert()
            .code(0);
    }
    for f in [
        "ground_truth.tum",
        "estimate_slam_single_camera.tum",
        "estimate_slam.tum",
        "report.json",
    ] {
        assert_eq!(
            std::fs::read(dir.path().join("1").join(f)).unwrap(),
            std::fs::read(dir.path().join("2").join(f)).unwrap(),
            "{f} differs between 1 and 2 threads"
        );
    }
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("1").join("report.json")).unwrap())
            .unwrap();
    let outcome = &report["robot"]["outcome"];
    assert_eq!(outcome["kind"], "stopped_estimate_lost", "{outcome}");
    assert_eq!(outcome["tracking_lost"], true, "{outcome}");
    // The lost frame's images arrive 30 ms after their stamp (the cameras' latency_ms),
    // the robot has the report 20 ms later (estimate_latency_ms), and the stop comes at
    // the first step after that (steps are at most 5 ms apart).
    let age_s = outcome["age_s"].as_f64().unwrap();
    assert!((0.05..0.055).contains(&age_s), "{outcome}");
}
