//! GNSS from the sky (issue #32) end to end: the tall-canopy scenario's receiver fixes in
//! the headlands and loses the fix in the lanes, its recording carries the sky on
//! `/gnss/gpsfix` (`gps_msgs/GPSFix`) agreeing with `/gnss/fix`, and the report shows it.

#![allow(clippy::unwrap_used)] // test helpers panic on bad data by design

use std::collections::BTreeMap;
use std::path::Path;
use vinebench::recording::reader::scan_file;
use vinebench::recording::ros;
use vinebench::runner::{RunOptions, run};
use vinebench::scenario::LoadedScenario;
use vinebench_msgs::FixStatus;
use vinebench_msgs::geodesy::LocalEnu;

#[test]
fn fix_quality_follows_the_robot_in_and_out_of_the_rows() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/tall-canopy-gnss.toml");
    let sc = LoadedScenario::load(&path).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("run");
    let outcome = run(
        &sc,
        &RunOptions {
            out_dir: Some(dir.clone()),
            progress: false,
            ..RunOptions::default()
        },
    )
    .unwrap();
    assert!(outcome.report.passed, "the scenario's own expectations");

    // Every fix and its sky, by stamp.
    let mut fixes = BTreeMap::new();
    let mut skies = BTreeMap::new();
    let mut schemas = BTreeMap::new();
    scan_file(&dir.join("recording.mcap"), |ch, m| {
        match ch.topic.as_str() {
            "/gnss/fix" => {
                fixes.insert(m.log_time, ros::decode_nav_sat_fix(m.data).unwrap());
            }
            "/gnss/gpsfix" => {
                schemas.insert(ch.topic.clone(), ch.schema_name.clone());
                skies.insert(m.log_time, ros::decode_gps_fix_status(m.data).unwrap());
            }
            _ => {}
        }
    })
    .unwrap();
    assert_eq!(schemas["/gnss/gpsfix"], "gps_msgs/msg/GPSFix");
    assert_eq!(fixes.len(), skies.len());
    assert!(fixes.len() > 2000);

    // The rows run along yaw 25° from the world origin, 120 m long (defaults.toml): a
    // fix's position along the rows says whether the robot is in a lane (5–115 m) or in
    // a headland (beyond the row ends). Fix positions are good to a metre or two.
    let enu = LocalEnu::new(sc.scenario.origin);
    let (c, s) = (25f64.to_radians().cos(), 25f64.to_radians().sin());
    // (fixed epochs, epochs, satellites tracked) in the lanes and in the headlands.
    let (mut lane, mut headland) = ((0usize, 0usize, 0usize), (0usize, 0usize, 0usize));
    for (t, f) in &fixes {
        let (status, used, visible, dop) = &skies[t];
        // /gnss/gpsfix says what /gnss/fix says, more precisely.
        let want: i16 = match f.status {
            FixStatus::RtkFixed => 19,
            FixStatus::RtkFloat => 20,
            FixStatus::Single => 0,
            FixStatus::NoFix => -1,
        };
        assert_eq!(*status, want);
        assert!(
            used.len() <= visible[0].len() && used.len() >= 5,
            "{used:?}"
        );
        assert!(dop[2] > 0.0 && dop[2] < 2.0, "hdop {}", dop[2]);
        if f.status == FixStatus::NoFix {
            continue;
        }
        let p = enu.enu_from_geodetic(&f.position);
        let along = p.x * c + p.y * s;
        let fixed = usize::from(f.status == FixStatus::RtkFixed);
        let tracked = visible[0].len();
        if (5.0..115.0).contains(&along) {
            lane = (lane.0 + fixed, lane.1 + 1, lane.2 + tracked);
        } else if !(-1.0..121.0).contains(&along) {
            headland = (headland.0 + fixed, headland.1 + 1, headland.2 + tracked);
        }
    }
    let share = |(f, n, _): (usize, usize, usize)| f as f64 / n as f64;
    let mean = |(_, n, k): (usize, usize, usize)| k as f64 / n as f64;
    assert!(headland.1 > 100 && lane.1 > 1000, "{headland:?} {lane:?}");
    // Out of the rows the whole sky is there (open sky: about 27 above the mask); in
    // the lanes the leaf walls hide several. The fix follows: lost in the lanes, back
    // after a re-convergence (about 8 s: a short headland turn is not all fixed, as it
    // often follows a loss).
    assert!(
        mean(headland) >= mean(lane) + 3.0,
        "{} {}",
        mean(headland),
        mean(lane)
    );
    assert!(share(lane) <= 0.9, "lanes fixed {}", share(lane));
    // Every loss of the fix happens in a row, none in a headland.
    let mut prev: Option<(FixStatus, f64)> = None;
    let mut losses = 0;
    for f in fixes.values().filter(|f| f.status != FixStatus::NoFix) {
        let p = enu.enu_from_geodetic(&f.position);
        let along = p.x * c + p.y * s;
        if let Some((FixStatus::RtkFixed, _)) = prev
            && f.status != FixStatus::RtkFixed
        {
            losses += 1;
            assert!(
                (0.0..120.0).contains(&along),
                "fix lost at {along:.1} m along"
            );
        }
        prev = Some((f.status, along));
    }
    assert!(losses >= 2);

    // The report says it and draws it.
    let g = outcome.report.robot.gnss.as_ref().unwrap();
    assert!(g.sky_model && g.fix_losses >= 2);
    let fixed_share = fixes
        .values()
        .filter(|f| f.status == FixStatus::RtkFixed)
        .count() as f64
        / fixes.len() as f64;
    assert!((g.share_of(FixStatus::RtkFixed) - fixed_share).abs() < 1e-12);
    let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
    assert!(md.contains("## GNSS receiver") && md.contains("gnss_fix_map.svg"));
    for svg in ["gnss.svg", "gnss_fix_map.svg"] {
        let text = std::fs::read_to_string(dir.join(svg)).unwrap();
        assert!(
            text.contains("rtk_float") && text.contains("rtk_fixed"),
            "{svg}"
        );
    }
}
