//! The command line: exit codes, located errors, run folders.

// Test helpers panic on failure by design.
#![allow(clippy::unwrap_used)]

use assert_cmd::Command;
use std::path::Path;

fn vinebench() -> Command {
    Command::cargo_bin("vinebench").expect("the vinebench binary is built for tests")
}

fn fixture(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
        .display()
        .to_string()
}

fn write(dir: &Path, name: &str, text: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p.display().to_string()
}

fn stderr_of(out: &std::process::Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn malformed_scenarios_exit_2_with_file_line_column_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (
            "type.toml",
            "[world.rows]\ncount = \"six\"\n",
            "type.toml:2:9: `world.rows.count`",
        ),
        (
            "unknown.toml",
            "[sensors.imu]\nrate = 100\n",
            "unknown.toml:2:1: `sensors.imu.rate`",
        ),
        ("syntax.toml", "[route\nkind = 1\n", "syntax.toml:1:"),
        (
            "enum.toml",
            "[route]\nkind = \"spiral\"\n",
            "enum.toml:2:8: `route.kind`",
        ),
        (
            "range.toml",
            "[world.rows]\nspacing_m = -2.5\n",
            "range.toml:2:13: `world.rows.spacing_m`",
        ),
        (
            "row.toml",
            "[route.row_loop]\nrow = 40\n",
            "row.toml:2:7: `route.row_loop.row`",
        ),
        (
            "expect.toml",
            "expect = [\"ate.eif < 1\"]\n",
            "expect.toml:1:11: `expect[0]`",
        ),
        (
            "robot-metric.toml",
            "expect = [\"max_tilt_deg.eif < 5\"]\n",
            "robot-metric.toml:1:11: `expect[0]`: `max_tilt_deg` is a metric of `robot`",
        ),
        (
            "frame.toml",
            "[sensors.imu]\nframe = \"lidar\"\n",
            "frame.toml:2:9: `sensors.imu.frame`",
        ),
        (
            "physics.toml",
            "[physics]\nripple_m = 0.5\n",
            "physics.toml:2:12: `physics.ripple_m`: expected a number in [0, 0.02]",
        ),
        (
            "kinematic-rover.toml",
            "[robot]\nmodel = \"mecanum-rover\"\n[motion]\nmodel = \"kinematic\"\n",
            "kinematic-rover.toml:4:9: `motion.model`: expected `rapier` for a robot that is not skid-steered",
        ),
        (
            "heading.toml",
            "[motion]\nheading = \"fixed\"\n",
            "heading.toml:2:11: `motion.heading`",
        ),
        (
            "urdf.toml",
            "[robot]\nurdf = \"nowhere.urdf\"\n",
            "nowhere.urdf: cannot read the URDF",
        ),
    ];
    for (name, text, want) in cases {
        let path = write(dir.path(), name, text);
        let out = vinebench().args(["validate", &path]).output().unwrap();
        assert_eq!(out.status.code(), Some(2), "{name}: {}", stderr_of(&out));
        let err = stderr_of(&out);
        assert!(err.contains(want), "{name}: expected `{want}` in:\n{err}");
    }
}

#[test]
fn missing_files_exit_2_and_name_the_file() {
    let out = vinebench()
        .args(["run", "no/such/scenario.toml"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr_of(&out).contains("no/such/scenario.toml"),
        "{}",
        stderr_of(&out)
    );

    let dir = tempfile::tempdir().unwrap();
    let urdf = write(dir.path(), "s.toml", "[robot]\nurdf = \"missing.urdf\"\n");
    let out = vinebench().args(["validate", &urdf]).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr_of(&out).contains("missing.urdf"),
        "{}",
        stderr_of(&out)
    );
}

#[test]
fn malformed_tum_files_exit_2_with_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let good = write(
        dir.path(),
        "a.tum",
        "0.0 0 0 0 0 0 0 1\n1.0 1 0 0 0 0 0 1\n",
    );
    let bad = write(
        dir.path(),
        "b.tum",
        "0.0 0 0 0 0 0 0 1\n1.0 1 0 nan 0 0 0 1\n",
    );
    let out = vinebench()
        .args(["score", "--ref", &good, &bad])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr_of(&out).contains("b.tum:2"), "{}", stderr_of(&out));
}

#[test]
fn defaults_prints_a_complete_valid_scenario() {
    let out = vinebench().arg("defaults").output().unwrap();
    assert!(out.status.success());
    let dir = tempfile::tempdir().unwrap();
    let p = write(
        dir.path(),
        "d.toml",
        &String::from_utf8(out.stdout).unwrap(),
    );
    vinebench().args(["validate", &p]).assert().success();
}

#[test]
fn run_passes_fails_and_writes_the_run_folder() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("pass");
    vinebench()
        .args(["run", &fixture("short-loop.toml"), "--quiet", "--out"])
        .arg(&out_dir)
        .assert()
        .code(0);
    for f in [
        "ground_truth.tum",
        "estimate_eif.tum",
        "estimate_gnss.tum",
        "estimate_tracking_camera.tum",
        "report.json",
        "report.md",
        "trajectories.svg",
        "errors.svg",
        "altitude.svg",
        "scenario.resolved.toml",
        "timing.json",
    ] {
        assert!(out_dir.join(f).is_file(), "missing {f}");
    }
    // The resolved scenario reproduces the run's parameters on its own.
    vinebench()
        .args(["validate"])
        .arg(out_dir.join("scenario.resolved.toml"))
        .assert()
        .success();

    // The same scenario with an expectation that cannot hold exits 1 and says why.
    let text = std::fs::read_to_string(fixture("short-loop.toml")).unwrap();
    let strict = text.replace(
        "\"ate_rmse_m.eif <= 0.1\"",
        "\"ate_rmse_m.eif <= 0.000001\"",
    );
    assert_ne!(strict, text);
    let p = write(dir.path(), "strict.toml", &strict);
    let out = vinebench()
        .args(["run", &p, "--out"])
        .arg(dir.path().join("fail"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1), "{}", stderr_of(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("FAILS: ate_rmse_m.eif <= 0.000001"),
        "{stdout}"
    );
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("fail/report.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(report["passed"], false);
}
