//! The robot's own run as an expectation source (`robot`) and a report section: a clean
//! run on a slope, and a run straight into a trellis post.

// Test helpers panic on failure by design.
#![allow(clippy::unwrap_used)]

use assert_cmd::Command;
use vinebench::runner::RobotOutcome;
use vinebench::runner::report::Report;
use vinebench::runner::{self, RunOptions};
use vinebench::scenario::LoadedScenario;
use vinebench_sim::physics::Obstacle;

/// Two 20 m rows, a loop around row 0 on a plane rising `slope_deg` along the rows (no
/// undulation, no roughness).
fn slope_scenario(slope_deg: f64) -> String {
    format!(
        r#"name = "robot-slope"
seed = 3
expect = [
    "route_completed.robot >= 1",
    "collisions.robot <= 0",
    "max_cross_track_m.robot < 0.2",
]

[world.rows]
count = 2
length_m = 20.0

[world.terrain]
slope_along_deg = {slope_deg}
undulation_m = 0.0
roughness_m = 0.0

[route.row_loop]
row = 0

[motion]
still_before_s = 2.0
still_after_s = 1.0
"#
    )
}

/// Rows along +x (yaw 0): row 0 runs from the origin with posts every 6 m at y = 0. The
/// route drives along row 0's centre line from x = -4 to x = 14, into the post at the
/// origin.
fn post_scenario(expect: &[&str]) -> String {
    let expect: Vec<String> = expect.iter().map(|e| format!("{e:?}")).collect();
    format!(
        r#"name = "robot-post"
seed = 4
expect = [{}]

[world.rows]
count = 2
length_m = 20.0
yaw_deg = 0.0

[world.posts]
spacing_m = 6.0

[physics]
stuck_timeout_s = 3.0

[route]
kind = "waypoints"

[route.waypoints]
points = [[-4.0, 0.0], [14.0, 0.0]]

[motion]
still_before_s = 1.0
still_after_s = 1.0
"#,
        expect.join(", ")
    )
}

fn run(text: &str) -> (Report, String) {
    let sc = LoadedScenario::from_str(text, "inline.toml").unwrap_or_else(|e| panic!("{e}"));
    let dir = tempfile::tempdir().unwrap();
    let opts = RunOptions {
        out_dir: Some(dir.path().join("run")),
        progress: false,
        ..RunOptions::default()
    };
    let out = runner::run(&sc, &opts).unwrap_or_else(|e| panic!("{e}"));
    let md = std::fs::read_to_string(out.dir.join("report.md")).unwrap();
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.dir.join("report.json")).unwrap())
            .unwrap();
    assert_eq!(
        json["robot"]["route_completed"],
        out.report.robot.route_completed
    );
    (out.report, md)
}

#[test]
fn a_loop_on_a_slope_completes_without_collisions_and_tilts_with_the_slope() {
    let (report, md) = run(&slope_scenario(6.0));
    let failed: Vec<String> = report
        .expectations
        .iter()
        .filter(|x| !x.holds)
        .map(|x| x.to_string())
        .collect();
    assert!(failed.is_empty(), "{}", failed.join("\n"));
    assert_eq!(report.expectations.len(), 3);

    let robot = &report.robot;
    let m = &robot.metrics;
    assert!(
        matches!(robot.outcome, RobotOutcome::Completed { .. }),
        "{robot:?}"
    );
    assert!(robot.collisions.is_empty(), "{:?}", robot.collisions);
    // Every value also answers its expectation name.
    assert_eq!(robot.metric("route_completed"), Some(1.0));
    assert_eq!(robot.metric("collisions"), Some(0.0));
    assert!(m.max_cross_track_m < 0.2, "{m:?}");
    // The ground is a plane whose normal is 6° from the vertical everywhere: a robot
    // standing on it is tilted 6°; driving adds pitch from braking and accelerating and
    // roll in the turns (at most 0.4 m/s² lateral, about 2.3°, of which the tracks'
    // springs let through a fraction), and the contact springs' uneven sinkage can take
    // a little off.
    assert!(
        (5.5..=7.0).contains(&m.max_tilt_deg),
        "tilt {} on a 6° slope",
        m.max_tilt_deg
    );
    // The whole route was followed: the progress reached its end, and the odometer is
    // the route's length give or take the corners cut and the ride's wobble.
    assert!(
        (m.progress_m - m.route_length_m).abs() < 0.1,
        "progress {} of {}",
        m.progress_m,
        m.route_length_m
    );
    assert!(
        (m.distance_m / m.route_length_m - 1.0).abs() < 0.02,
        "{} m driven on a {} m route",
        m.distance_m,
        m.route_length_m
    );
    // A tracked robot follows the route with its nose: the heading error stays small.
    assert!(m.max_heading_error_deg < 15.0, "{m:?}");
    assert!(md.contains("## Robot\n\n**completed at "), "{md}");
    assert!(md.contains("| `max_tilt_deg.robot` | "), "{md}");
    assert!(md.contains("\nNo collisions.\n"), "{md}");

    // The same loop on level ground tilts far less: the tilt above comes from the slope.
    let (flat, _) = run(&slope_scenario(0.0));
    let tilt = flat.robot.metrics.max_tilt_deg;
    assert!(tilt < 2.0, "tilt {tilt} on level ground");
}

#[test]
fn driving_into_a_post_is_a_collision_and_the_robot_gets_stuck() {
    let (report, md) = run(&post_scenario(&[
        "collisions.robot <= 0",
        "route_completed.robot >= 1",
        "collisions.robot >= 1",
    ]));
    let robot = &report.robot;
    let post = robot
        .collisions
        .iter()
        .find(|c| matches!(c.obstacle, Obstacle::Post { row: 0, .. }))
        .unwrap_or_else(|| panic!("no post collision: {:?}", robot.collisions));
    // The post at the origin, met by the front of the robot: the body origin is behind
    // it, on the route's line, after the robot left its start at x = -4.
    let [x, y, _] = post.robot_position_m;
    assert!((-3.5..0.0).contains(&x) && y.abs() < 0.1, "{post:?}");
    let RobotOutcome::Stuck { at_s, progress_m } = robot.outcome else {
        panic!("not stuck: {:?}", robot.outcome)
    };
    // Stuck once no progress was made for physics.stuck_timeout_s = 3 s after the hit.
    assert!(
        at_s >= post.time_s + 3.0 && at_s < post.time_s + 6.0,
        "{robot:?}"
    );
    assert!((progress_m - (4.0 + x)).abs() < 0.1, "{robot:?}");
    assert!(!robot.route_completed);
    assert_eq!(robot.metric("route_completed"), Some(0.0));
    assert!(robot.metric("collisions").unwrap() >= 1.0);
    let holds: Vec<bool> = report.expectations.iter().map(|x| x.holds).collect();
    assert_eq!(holds, [false, false, true]);
    assert!(!report.passed);
    assert!(md.contains("**stuck at "), "{md}");
    assert!(md.contains("| post row 0 #"), "{md}");
    assert!(
        md.contains("| robot link | obstacle | robot position [m] |"),
        "{md}"
    );
}

#[test]
fn a_failing_robot_expectation_exits_1_through_the_cli() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("post.toml");
    std::fs::write(&scenario, post_scenario(&["collisions.robot <= 0"])).unwrap();
    let out = Command::cargo_bin("vinebench")
        .unwrap()
        .arg("run")
        .arg(&scenario)
        .arg("--out")
        .arg(dir.path().join("run"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(
        out.status.code(),
        Some(1),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("FAILS: collisions.robot <= 0"), "{stdout}");
    assert!(
        stdout.contains(&format!("\n{:<18} stuck at ", "robot")),
        "{stdout}"
    );

    // The same run asked to hit something passes.
    std::fs::write(
        &scenario,
        post_scenario(&["collisions.robot >= 1", "route_completed.robot <= 0"]),
    )
    .unwrap();
    Command::cargo_bin("vinebench")
        .unwrap()
        .args(["run", "--quiet"])
        .arg(&scenario)
        .arg("--out")
        .arg(dir.path().join("run2"))
        .assert()
        .code(0);
}
