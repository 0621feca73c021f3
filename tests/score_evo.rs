//! `vinebench score ape|rpe` (issue #31) through the command line: closed forms, evo's
//! association of repeated stamps, tables, saved results, bad input; and the same numbers
//! from a run's TUM files and from its recording's topics (two independent readers).
//! (The comparison with evo itself on evo's test data is scripts/evo_drop_in_check.sh.)
#![allow(clippy::unwrap_used)]

use assert_cmd::Command;
use std::path::Path;

fn vinebench() -> Command {
    Command::cargo_bin("vinebench").unwrap()
}

/// A TUM file of a circle of radius 5 m, 10 Hz, turning with the path, shifted by
/// `shift` (world frame).
fn circle(path: &Path, shift: [f64; 3], extra: &str) {
    let mut s = String::from("# t x y z qx qy qz qw\n");
    for i in 0..200 {
        let a = i as f64 * 0.05;
        let (x, y) = (5.0 * a.cos() + shift[0], 5.0 * a.sin() + shift[1]);
        let yaw = a + std::f64::consts::FRAC_PI_2;
        s.push_str(&format!(
            "{:.3} {x} {y} {} 0 0 {} {}\n",
            100.0 + i as f64 * 0.1,
            shift[2],
            (yaw / 2.0).sin(),
            (yaw / 2.0).cos()
        ));
    }
    s.push_str(extra);
    std::fs::write(path, s).unwrap();
}

fn stat(stdout: &str, name: &str) -> f64 {
    stdout
        .lines()
        .find_map(|l| {
            let (k, v) = l.split_once('\t')?;
            (k.trim() == name).then(|| v.trim().parse().unwrap())
        })
        .unwrap_or_else(|| panic!("{name} not in\n{stdout}"))
}

#[test]
fn closed_forms_alignment_tables_and_saved_results() {
    let dir = tempfile::tempdir().unwrap();
    let (gt, est, est2) = (
        dir.path().join("gt.tum"),
        dir.path().join("est.tum"),
        dir.path().join("est2.tum"),
    );
    circle(&gt, [0.0; 3], "");
    // The estimate shifted by (0.3, 0, 0.4): APE 0.5 m everywhere; a repeated stamp at
    // the end is accepted as evo accepts it.
    circle(&est, [0.3, 0.0, 0.4], "119.900 9 9 9 0 0 0 1\n");
    circle(&est2, [0.0, 0.1, 0.0], "");
    let out = vinebench()
        .args(["score", "ape", "tum"])
        .args([&gt, &est])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8(out.stdout).unwrap();
    assert!(
        stdout.starts_with("APE w.r.t. translation part (m)\n(not aligned)\n\n"),
        "{stdout}"
    );
    assert!(
        (stat(&stdout, "rmse") - 0.5).abs() < 1e-6 && (stat(&stdout, "max") - 0.5).abs() < 1e-6
    );
    let stderr = String::from_utf8(out.stderr).unwrap();
    assert!(stderr.contains("1 repeated stamp(s)"), "{stderr}");
    // SE(3) alignment removes a shift; a pure translation leaves RPE at zero.
    let out = vinebench()
        .args(["score", "ape", "tum"])
        .args([&gt, &est])
        .arg("-a")
        .output()
        .unwrap();
    assert!(stat(&String::from_utf8(out.stdout).unwrap(), "max") < 1e-6);
    let out = vinebench()
        .args(["score", "rpe", "tum"])
        .args([&gt, &est, &est2])
        .args(["-d", "1", "-u", "m", "--save_results"])
        .arg(dir.path().join("r.json"))
        .arg("--save_table")
        .arg(dir.path().join("t.csv"))
        .arg("--save_plot")
        .arg(dir.path().join("p.svg"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8(out.stdout).unwrap();
    assert!(
        stdout.contains("for delta = 1.0 (m) using consecutive pairs"),
        "{stdout}"
    );
    // The table of both estimates.
    assert!(
        stdout.lines().any(|l| l.starts_with("est2.tum")),
        "{stdout}"
    );
    let csv = std::fs::read_to_string(dir.path().join("t.csv")).unwrap();
    assert!(
        csv.starts_with(",rmse,mean,median,std,min,max,sse\nest.tum,"),
        "{csv}"
    );
    let text = std::fs::read_to_string(dir.path().join("r.json")).unwrap();
    // The statistics in evo's order.
    let at: Vec<usize> = [
        "\"rmse\"",
        "\"mean\"",
        "\"median\"",
        "\"std\"",
        "\"min\"",
        "\"max\"",
        "\"sse\"",
    ]
    .iter()
    .map(|k| text.find(k).unwrap())
    .collect();
    assert!(at.windows(2).all(|w| w[0] < w[1]), "{text}");
    let saved: serde_json::Value = serde_json::from_str(&text).unwrap();
    let first = &saved[0];
    assert_eq!(first["info"]["label"], "RPE (m)");
    let n = first["np_arrays"]["error_array"].as_array().unwrap().len();
    assert!(n > 20 && first["np_arrays"]["timestamps"].as_array().unwrap().len() == n);
    assert!(first["stats"]["max"].as_f64().unwrap() < 1e-9);
    let svg = std::fs::read_to_string(dir.path().join("p.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("est2.tum"));
    // evo's zip format holds one result (scripts/evo_drop_in_check.sh reads ours with evo).
    let zip = dir.path().join("r.zip");
    let one = vinebench()
        .args(["score", "ape", "tum"])
        .args([&gt, &est])
        .arg("--save_results")
        .arg(&zip)
        .output()
        .unwrap();
    assert!(one.status.success());
    let bytes = std::fs::read(&zip).unwrap();
    assert!(bytes.starts_with(b"PK\x03\x04") && bytes.windows(9).any(|w| w == b"info.json"));
    let two = vinebench()
        .args(["score", "ape", "tum"])
        .args([&gt, &est, &est2])
        .arg("--save_results")
        .arg(&zip)
        .output()
        .unwrap();
    assert_eq!(two.status.code(), Some(2));
}

#[test]
fn bad_input_names_file_line_and_format() {
    let dir = tempfile::tempdir().unwrap();
    let gt = dir.path().join("gt.tum");
    circle(&gt, [0.0; 3], "");
    let kitti = dir.path().join("kitti.txt");
    std::fs::write(&kitti, "1 0 0 0 0 1 0 0 0 0 1 0\n").unwrap();
    let out = vinebench()
        .args(["score", "ape", "tum"])
        .args([&gt, &kitti])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let e = String::from_utf8(out.stderr).unwrap();
    assert!(
        e.contains("kitti.txt:1: 12 fields") && e.contains("looks like a KITTI"),
        "{e}"
    );
    // Nothing associated is an error, not an empty pass.
    let late = dir.path().join("late.tum");
    std::fs::write(&late, "900 0 0 0 0 0 0 1\n").unwrap();
    let out = vinebench()
        .args(["score", "ape", "tum"])
        .args([&gt, &late])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let e = String::from_utf8(out.stderr).unwrap();
    assert!(e.contains("found no matching timestamps"), "{e}");
    // KITTI paths of different lengths.
    let out = vinebench()
        .args(["score", "ape", "kitti"])
        .args([&kitti, &kitti])
        .output()
        .unwrap();
    assert!(out.status.success());
    let out = vinebench()
        .args(["score", "ape", "tum"])
        .args([&gt, &gt])
        .args(["-a", "--align_origin"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
}

#[test]
fn a_runs_tum_files_and_its_recording_give_the_same_scores() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("s.toml");
    let base = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/short-loop.toml"),
    )
    .unwrap();
    std::fs::write(&scenario, format!("max_duration_s = 30.0\n{base}")).unwrap();
    let run = dir.path().join("run");
    let status = vinebench()
        .args(["run", "--quiet", "--out"])
        .arg(&run)
        .arg(&scenario)
        .output()
        .unwrap()
        .status;
    assert!(matches!(status.code(), Some(0 | 1)), "{status:?}");
    for extra in [&[][..], &["-a", "-r", "angle_deg"][..]] {
        let from_tum = vinebench()
            .args(["score", "ape", "tum"])
            .arg(run.join("ground_truth.tum"))
            .arg(run.join("estimate_eif.tum"))
            .args(extra)
            .output()
            .unwrap();
        let from_mcap = vinebench()
            .args(["score", "ape", "bag2"])
            .arg(run.join("recording.mcap"))
            .args(["/ground_truth/odom", "/estimate/eif/odom"])
            .args(extra)
            .output()
            .unwrap();
        assert!(
            from_mcap.status.success(),
            "{}",
            String::from_utf8_lossy(&from_mcap.stderr)
        );
        let (a, b) = (
            String::from_utf8(from_tum.stdout).unwrap(),
            String::from_utf8(from_mcap.stdout).unwrap(),
        );
        for k in ["rmse", "mean", "max", "min"] {
            let (x, y) = (stat(&a, k), stat(&b, k));
            assert!(
                (x - y).abs() <= 1e-6 * y.abs().max(1e-3),
                "{extra:?} {k}: {x} vs {y}"
            );
        }
    }
}
