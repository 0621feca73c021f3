//! Same scenario, same seed → identical outputs, on every run and thread count.
//!
//! The golden digest pins the short fixture's outputs. When a change alters results on
//! purpose, regenerate it with
//! `UPDATE_GOLDEN=1 cargo test --release --test determinism` and say why in the commit.

// Test helpers panic on failure by design.
#![allow(clippy::unwrap_used)]

use assert_cmd::Command;
use sha2::{Digest, Sha256};
use std::path::Path;

/// Files that must be identical across runs (timing.json holds wall-clock time).
const DETERMINISTIC: &[&str] = &[
    "ground_truth.tum",
    "estimate_eif.tum",
    "estimate_gnss.tum",
    "estimate_tracking_camera.tum",
    "report.json",
    "report.md",
    "scenario.resolved.toml",
    "trajectories.svg",
    "errors.svg",
    "altitude.svg",
];

/// Runs `scenario` on `threads` worker threads into `out`; it must pass.
fn run_scenario(scenario: &Path, threads: &str, out: &Path) {
    Command::cargo_bin("vinebench")
        .unwrap()
        .args(["--threads", threads, "run", "--quiet", "--out"])
        .arg(out)
        .arg(scenario)
        .assert()
        .code(0);
}

fn run(threads: &str, out: &Path) {
    let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/short-loop.toml");
    run_scenario(&scenario, threads, out);
}

#[test]
fn runs_are_bit_identical_across_repeats_and_thread_counts() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b, c) = (
        dir.path().join("a"),
        dir.path().join("b"),
        dir.path().join("c"),
    );
    run("1", &a);
    run("2", &b);
    run("2", &c);
    for f in DETERMINISTIC {
        let fa = std::fs::read(a.join(f)).unwrap();
        assert_eq!(
            fa,
            std::fs::read(b.join(f)).unwrap(),
            "{f} differs between 1 and 2 threads"
        );
        assert_eq!(
            fa,
            std::fs::read(c.join(f)).unwrap(),
            "{f} differs between two runs"
        );
    }

    // Golden digest over the trajectories (ground truth and every estimate).
    let mut h = Sha256::new();
    for f in &DETERMINISTIC[..4] {
        h.update(std::fs::read(a.join(f)).unwrap());
    }
    let digest: String = h.finalize().iter().map(|b| format!("{b:02x}")).collect();
    let golden = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden/short-loop.sha256");
    if std::env::var_os("UPDATE_GOLDEN").is_some() {
        std::fs::write(&golden, format!("{digest}\n")).unwrap();
    }
    let want = std::fs::read_to_string(&golden).unwrap_or_default();
    assert_eq!(
        want.trim(),
        digest,
        "outputs of tests/data/short-loop.toml changed; if intended, run \
         UPDATE_GOLDEN=1 cargo test --release --test determinism"
    );
}

/// The SLAM (and its baselines) on the first 14 s of the box-occluder scenario, which
/// registers the tag: identical trajectories and reports on 1 and 2 threads.
#[test]
fn slam_runs_are_bit_identical_across_thread_counts() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("scenarios/csl-box-occluder.toml")).unwrap();
    let start = text.find("expect = [").unwrap();
    let end = start + text[start..].find("]\n").unwrap() + 2;
    // Images are not recorded (half a gigabyte per run otherwise).
    let short = format!(
        "{}max_duration_s = 14.0\nexpect = [\"keyframes.slam >= 1\"]\n{}\n[recording]\n\
         exclude_topics = [\"/front/*\", \"/rear/*\", \"/side/*\"]\n",
        &text[..start],
        &text[end..]
    );
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("csl-short.toml");
    std::fs::write(&scenario, short).unwrap();
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    run_scenario(&scenario, "1", &a);
    run_scenario(&scenario, "2", &b);
    for f in [
        "estimate_slam.tum",
        "estimate_slam_single_camera.tum",
        "estimate_slam_no_loops.tum",
        "loops.csv",
        "report.json",
    ] {
        assert_eq!(
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
            "{f} differs between 1 and 2 threads"
        );
    }
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(a.join("report.json")).unwrap()).unwrap();
    let slam = report["sources"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["name"] == "slam")
        .unwrap();
    assert_eq!(slam["events"]["tags_registered"], 1, "{slam}");
}
