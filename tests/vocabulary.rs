//! `vinebench vocabulary` and the shipped vocabulary: the committed file reads back bit for
//! bit, the command's errors name what is wrong, and a short scenario trains end to end.

// Test helpers panic on failure by design.
#![allow(clippy::unwrap_used)]

use assert_cmd::Command;
use std::path::{Path, PathBuf};
use vinebench::scenario::LoadedScenario;
use vinebench::vocabulary::{self, DEFAULT_BRANCHING, DEFAULT_DEPTH};
use vinebench_onboard::slam::bow::{Database, Vocabulary, VocabularyConfig, score};

fn vinebench() -> Command {
    Command::cargo_bin("vinebench").expect("the vinebench binary is built for tests")
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn stderr_of(out: &std::process::Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Two 4 m rows, the rover's front and rear stereo pairs at a quarter of the ZED2i's
/// pixels, 2.5 s: a handful of keyframes in a few seconds.
const SHORT: &str = r#"
name = "vocabulary-short"
seed = 41
max_duration_s = 2.5

[world.rows]
count = 2
length_m = 4.0

[world.headlands]
width_m = 4.0

[robot]
model = "mecanum-rover"

[motion]
cruise_speed_mps = 0.8
still_before_s = 0.2

[route]
kind = "waypoints"

[route.waypoints]
points = [[-1.0, 1.25], [5.0, 1.25]]

[sensors.tracking_camera]
frame = "front_camera_link"

[[sensors.cameras]]
name = "front"
profile = "zed2i"
frame = "front_camera_left_optical_frame"
right_frame = "front_camera_right_optical_frame"
width = 376
height = 240

[[sensors.cameras]]
name = "rear"
profile = "zed2i"
frame = "rear_camera_left_optical_frame"
right_frame = "rear_camera_right_optical_frame"
width = 376
height = 240
"#;

#[test]
fn the_shipped_vocabulary_reads_back_bit_for_bit() {
    let path = root().join("scenarios/vocabularies/vineyard.vbvoc");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(bytes.len() < 2_000_000, "{} bytes", bytes.len());
    let voc = Vocabulary::read(bytes.as_slice()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(voc.branching(), DEFAULT_BRANCHING);
    assert_eq!(voc.depth(), DEFAULT_DEPTH);
    // k^L = 10^4 leaves at most; a vineyard's descriptors fill most of them.
    let max_words = DEFAULT_BRANCHING.pow(DEFAULT_DEPTH as u32);
    assert!(
        (max_words / 2..=max_words).contains(&voc.n_words()),
        "{} words",
        voc.n_words()
    );
    assert!(voc.training_images() >= 50, "{}", voc.training_images());
    assert_eq!(voc.to_bytes(), bytes);
}

#[test]
fn the_command_names_a_missing_scenario_and_bad_settings() {
    let dir = tempfile::tempdir().unwrap();
    let out_file = dir.path().join("v.vbvoc");
    let out = vinebench()
        .args(["vocabulary", "no-such-scenario.toml", "--out"])
        .arg(&out_file)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = stderr_of(&out);
    assert!(
        err.contains("no-such-scenario.toml: cannot read the scenario"),
        "{err}"
    );

    let training = root().join("scenarios/vocabularies/training.toml");
    let out = vinebench()
        .args(["vocabulary", "--depth", "0", "--out"])
        .arg(&out_file)
        .arg(&training)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = stderr_of(&out);
    assert!(
        err.contains("--branching/--depth") && err.contains("depth"),
        "{err}"
    );
    assert!(!out_file.exists());
}

#[test]
fn a_scenario_without_stereo_cameras_is_refused_before_simulating() {
    let dir = tempfile::tempdir().unwrap();
    let sc = dir.path().join("no-cameras.toml");
    std::fs::write(&sc, "name = \"no-cameras\"\n").unwrap();
    let out_file = dir.path().join("v.vbvoc");
    let out = vinebench()
        .arg("vocabulary")
        .arg(&sc)
        .arg("--out")
        .arg(&out_file)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = stderr_of(&out);
    assert!(
        err.contains("no-cameras.toml") && err.contains("`sensors.cameras`"),
        "{err}"
    );
    assert!(err.contains("stereo camera"), "{err}");
    assert!(!out_file.exists());
}

#[test]
fn the_training_scenario_validates() {
    let out = vinebench()
        .arg("validate")
        .arg(root().join("scenarios/vocabularies/training.toml"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0), "{}", stderr_of(&out));
}

#[test]
fn a_short_scenario_trains_a_vocabulary_of_its_keyframes() {
    let sc = LoadedScenario::from_str(SHORT, "short.toml").unwrap_or_else(|e| panic!("{e}"));
    let set = vocabulary::collect_keyframes(&sc, None).unwrap_or_else(|e| panic!("{e}"));
    assert!(set.images.len() >= 2, "{} keyframes", set.images.len());
    assert!(set.images.iter().all(|img| !img.is_empty()));
    let cfg = VocabularyConfig {
        branching: 6,
        depth: 3,
        ..VocabularyConfig::default()
    };
    let (voc, summary) = vocabulary::train(&set, &cfg).unwrap_or_else(|e| panic!("{e}"));
    eprintln!("{summary:?}");
    assert_eq!(voc.training_images() as usize, summary.keyframes);
    assert_eq!(summary.keyframes, set.images.len());
    assert_eq!(summary.descriptors, set.descriptors());
    assert_eq!(summary.words, voc.n_words());
    assert!(
        (100..=216).contains(&voc.n_words()),
        "{} words",
        voc.n_words()
    );
    assert!(summary.simulated_s > 2.0 && summary.simulated_s <= 2.5 + 1e-9);

    // Every keyframe is most like itself among the training keyframes.
    let mut db = Database::new();
    for (id, img) in set.images.iter().enumerate() {
        db.add(id as u32, voc.transform(img)).unwrap();
    }
    for (id, img) in set.images.iter().enumerate() {
        let v = voc.transform(img);
        assert!((score(&v, &v) - 1.0).abs() < 1e-12);
        let best = db.query(&v, 2, |_| false);
        assert_eq!(best[0].0, id as u32, "{best:?}");
        assert!(best.len() < 2 || best[1].1 < 1.0 - 1e-9, "{best:?}");
    }

    // Written atomically into a new folder, read back identical.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sub/short.vbvoc");
    let n = vocabulary::write_atomic(&voc, &path).unwrap_or_else(|e| panic!("{e}"));
    let bytes = std::fs::read(&path).unwrap();
    assert_eq!(n as usize, bytes.len());
    assert_eq!(Vocabulary::read(bytes.as_slice()).unwrap(), voc);
    let leftovers: Vec<_> = std::fs::read_dir(path.parent().unwrap_or(Path::new(".")))
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(leftovers.len(), 1, "{leftovers:?}");
}
