//! The MuJoCo backend end to end (cargo feature `mujoco`): its scenarios meet their
//! expectations, the robot drives the same route on both engines (`motion.compare_with`),
//! and a build without the feature refuses `motion.model = "mujoco"` with a message that
//! says how to get it.

// Test helpers panic on failure by design.
#![allow(clippy::unwrap_used)]

use std::path::Path;
use vinebench::runner::simulate;
#[cfg(feature = "mujoco")]
use vinebench::runner::{evaluate, score};
use vinebench::scenario::LoadedScenario;

fn load(file: &str) -> LoadedScenario {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenarios")
        .join(file);
    LoadedScenario::load(&path).unwrap_or_else(|e| panic!("{e}"))
}

#[cfg(feature = "mujoco")]
#[test]
fn slope_row_on_mujoco_meets_its_expectations_and_follows_rapier() {
    let sc = load("slope-row-mujoco.toml");
    let sim = simulate(&sc, None).unwrap_or_else(|e| panic!("{e}"));
    assert!(sim.route_completed, "the route was not completed");
    let failed: Vec<String> = evaluate(&sc, &score(&sc, &sim).unwrap())
        .iter()
        .filter(|r| !r.holds)
        .map(|r| r.to_string())
        .collect();
    assert!(failed.is_empty(), "{}", failed.join("\n"));

    // The same route on rapier (`compare_with`), with the same controller: it takes as
    // long within 5 %, and the paths and ends agree (the scenario's expectations bound
    // them; printed here).
    let [c] = sim.comparisons.as_slice() else {
        panic!("expected one comparison, found {}", sim.comparisons.len());
    };
    assert_eq!(c.model, vinebench_sim::params::MotionModelKind::Rapier);
    assert_eq!(c.outcome, vinebench_sim::motion::MotionOutcome::Completed);
    let ratio = sim.duration_s / c.duration_s;
    eprintln!(
        "MuJoCo {:.1} s, {:.1} m; rapier {:.1} s, {:.1} m; ends {:.3} m and {:.2}° apart, paths at most {:.3} m apart",
        sim.duration_s,
        sim.distance_m,
        c.duration_s,
        c.distance_m,
        c.end_gap_m,
        c.end_heading_deg,
        c.max_path_separation_m
    );
    assert!((ratio - 1.0).abs() < 0.05, "durations differ by {ratio}");
    // The separation against an independent brute-force nearest-point search.
    let theirs: Vec<_> = c.truth.positions().collect();
    let brute = sim
        .truth
        .to_trajectory()
        .unwrap()
        .positions()
        .map(|p| {
            theirs
                .iter()
                .map(|q| (p - q).xy().norm())
                .fold(f64::INFINITY, f64::min)
        })
        .fold(0.0, f64::max);
    assert!((brute - c.max_path_separation_m).abs() < 1e-9);
}

#[cfg(not(feature = "mujoco"))]
#[test]
fn without_the_feature_mujoco_is_a_clear_error() {
    let sc = load("slope-row-mujoco.toml");
    let e = simulate(&sc, None).err().unwrap().to_string();
    assert!(e.contains("motion.model"), "{e}");
    assert!(e.contains("--features mujoco"), "{e}");
    assert!(e.contains("slope-row-mujoco.toml"), "{e}");
}
