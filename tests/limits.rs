//! Input-driven sizes have stated limits and named errors, and cost linear in the input:
//! routes ([`MAX_ROUTE_LENGTH_M`], [`MAX_ROUTE_SAMPLES`]), world sizes (rows, posts,
//! vines, tags, terrain and heightfield grids), URDF size (links, nesting) and loading
//! time (a 43,000-link chain). Every test runs under the bounded allocator of
//! `common/fuzz.rs`: an input that allocated its size before being checked would abort
//! the binary instead of passing.

#[path = "common/fuzz.rs"]
mod fuzz;

use vinebench::scenario::LoadedScenario;
use vinebench_sim::params::{
    HeadlandsParams, RouteKind, RouteParams, SerpentineParams, WaypointsParams, WorldParams,
};
use vinebench_sim::robot::{BUILTIN_MODELS, MAX_URDF_LINKS, RobotModel};
use vinebench_sim::route::{MAX_ROUTE_LENGTH_M, MAX_ROUTE_SAMPLES, ROUTE_SAMPLE_M, build_route};
use vinebench_sim::world::{RowLayout, World};

#[global_allocator]
static ALLOC: fuzz::LimitAlloc = fuzz::LimitAlloc;

fn waypoints(points: Vec<[f64; 2]>, there_and_back: bool) -> RouteParams {
    RouteParams {
        kind: RouteKind::Waypoints,
        waypoints: WaypointsParams {
            points,
            closed: false,
            there_and_back,
        },
        ..RouteParams::default()
    }
}

fn default_layout() -> (RowLayout, HeadlandsParams) {
    let w = WorldParams::default();
    (RowLayout::new(&w.rows), w.headlands)
}

#[test]
fn routes_beyond_the_limit_are_refused_before_sampling() {
    let (layout, headlands) = default_layout();
    // The finding: a route to x = 1e9 m grew to 24 GB; 1e6 m took 2 GB.
    for x in [1e9, 1e6, 1e300, f64::MAX] {
        let e = build_route(
            &waypoints(vec![[0.0, -1.25], [x, -1.25]], false),
            &layout,
            &headlands,
        )
        .expect_err("a route beyond the limit");
        assert_eq!(e.path, "route.waypoints.points", "{e}");
        assert!(
            e.expected.contains("MAX_ROUTE_LENGTH_M") && e.expected.contains("100000 m"),
            "{e}"
        );
    }
    // Both ways count: 60 km there and back is 120 km.
    let e = build_route(
        &waypoints(vec![[0.0, 0.0], [6e4, 0.0]], true),
        &layout,
        &headlands,
    )
    .expect_err("120 km there and back");
    assert_eq!(e.path, "route.waypoints.points");
    // Laps are checked before they are laid out.
    let mut laps = RouteParams::default();
    laps.row_loop.laps = u32::MAX;
    let e = build_route(&laps, &layout, &headlands).expect_err("4e9 laps");
    assert_eq!(e.path, "route.row_loop.laps", "{e}");
    // A serpentine over 1000 rows of 10 km.
    let big = RowLayout {
        count: 1000,
        length_m: 10_000.0,
        ..layout.clone()
    };
    let serpentine = RouteParams {
        kind: RouteKind::Serpentine,
        serpentine: SerpentineParams {
            first_row: 0,
            last_row: 999,
        },
        ..RouteParams::default()
    };
    let e = build_route(&serpentine, &big, &headlands).expect_err("10,000 km");
    assert_eq!(e.path, "route.serpentine.last_row", "{e}");
}

#[test]
fn a_route_within_the_limit_holds_its_dense_samples_only() {
    let (layout, headlands) = default_layout();
    let length = 0.99 * MAX_ROUTE_LENGTH_M;
    let route = build_route(
        &waypoints(vec![[0.0, 0.0], [length, 0.0]], false),
        &layout,
        &headlands,
    )
    .expect("99 km");
    let expected = (length / ROUTE_SAMPLE_M).ceil() as usize + 1;
    assert_eq!(route.len(), expected);
    assert!(route.len() <= MAX_ROUTE_SAMPLES);
    // Sampled into storage of exactly that size (no doubling growth).
    assert_eq!(route.points.capacity(), expected);
    assert!((route.total_length_m() - length).abs() < 1e-6 * length);
}

/// A scenario with `extra` TOML over the defaults.
fn scenario(extra: &str) -> LoadedScenario {
    LoadedScenario::from_str(extra, "limits.toml").unwrap_or_else(|e| panic!("{e}"))
}

fn validate_error(extra: &str) -> String {
    match vinebench::runner::validate(&scenario(extra)) {
        Ok(()) => panic!("validated: {extra}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn validate_names_the_route_and_world_keys() {
    // The finding's scenario: a 5-second run on a route to x = 1e9 m.
    let err = validate_error(
        "max_duration_s = 5.0\n[route]\nkind = \"waypoints\"\n[route.waypoints]\n\
         points = [[0.0, -1.25], [1e9, -1.25]]\n",
    );
    assert!(
        err.contains("route.waypoints.points") && err.contains("MAX_ROUTE_LENGTH_M"),
        "{err}"
    );
    // A huge row count names world.rows.count (it was blamed on world.terrain.cell_m).
    for count in ["4294967295", "100000", "1001"] {
        let err = validate_error(&format!("[world.rows]\ncount = {count}\n"));
        assert!(
            err.contains("world.rows.count") && err.contains("MAX_ROWS"),
            "{count}: {err}"
        );
        assert!(!err.contains("cell_m"), "{err}");
    }
}

#[test]
fn world_sizes_name_their_key() {
    let err = |edit: &dyn Fn(&mut WorldParams)| {
        let mut p = WorldParams::default();
        edit(&mut p);
        World::generate(1, &p).expect_err("over a limit").path
    };
    assert_eq!(err(&|p| p.rows.count = u32::MAX), "world.rows.count");
    assert_eq!(err(&|p| p.rows.length_m = 1e9), "world.rows.length_m");
    assert_eq!(err(&|p| p.rows.spacing_m = 1e9), "world.rows.spacing_m");
    assert_eq!(
        err(&|p| p.headlands.width_m = 1e9),
        "world.headlands.width_m"
    );
    assert_eq!(err(&|p| p.terrain.margin_m = 1e9), "world.terrain.margin_m");
    assert_eq!(err(&|p| p.posts.spacing_m = 1e-6), "world.posts.spacing_m");
    assert_eq!(
        err(&|p| p.plants.spacing_m = 1e-6),
        "world.plants.spacing_m"
    );
    assert_eq!(
        err(&|p| p.posts.wire_heights_m = vec![1.0; 100]),
        "world.posts.wire_heights_m"
    );
    assert_eq!(
        err(&|p| p.canopy.prototypes = u32::MAX),
        "world.canopy.prototypes"
    );
    assert_eq!(
        err(&|p| p.canopy.shoots_per_plant = u32::MAX),
        "world.canopy.shoots_per_plant"
    );
    assert_eq!(
        err(&|p| p.canopy.bunches_per_plant = u32::MAX),
        "world.canopy.bunches_per_plant"
    );
    // Many rows of 10 km: the terrain grid, now with the footprint in the message.
    let mut p = WorldParams::default();
    p.rows.count = 1000;
    p.rows.length_m = 10_000.0;
    p.plants.spacing_m = 100.0;
    p.posts.spacing_m = 100.0;
    let e = World::generate(1, &p).expect_err("a 10 km × 2.5 km terrain at 0.5 m");
    assert_eq!(e.path, "world.terrain.cell_m");
    assert!(e.expected.contains("world.rows.length_m"), "{e}");
}

#[test]
fn a_world_mesh_must_be_a_regular_file_within_its_bound() {
    // The mesh parsers stream their file: `/dev/zero` behind a `.ply` name would never
    // end; it is refused before reading, naming the key.
    let dir = tempfile::tempdir().unwrap();
    let zero = dir.path().join("zero.ply");
    std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
    let err = validate_error(&format!(
        "[world.mesh]\nfile = {:?}\n",
        zero.display().to_string()
    ));
    assert!(
        err.contains("world.mesh.file") && err.contains("expected a regular file"),
        "{err}"
    );
}

#[test]
fn heightfield_and_render_grids_are_bounded() {
    // Rows of 3 km at 5 cm: 86 M heights.
    let big = "[world.rows]\nlength_m = 3000.0\nyaw_deg = 0.0\n";
    let err = validate_error(&format!("{big}[physics]\nheightfield_cell_m = 0.05\n"));
    assert!(
        err.contains("physics.heightfield_cell_m") && err.contains("MAX_HEIGHTFIELD_POINTS"),
        "{err}"
    );
    // The rendered ground at 2 cm: 542 M vertices.
    let err = validate_error(&format!(
        "{big}[render]\nterrain_cell_m = 0.02\n[[sensors.cameras]]\nname = \"cam\"\n\
         profile = \"d435_color\"\nframe = \"camera_center_color_optical_frame\"\n"
    ));
    assert!(
        err.contains("render.terrain_cell_m") && err.contains("MAX_TERRAIN_VERTICES"),
        "{err}"
    );
}

/// The tracked robot with a chain of `n` fixed links hung from base_link, each 1 mm
/// ahead of its parent.
fn chain_urdf(n: usize) -> String {
    let text = BUILTIN_MODELS[0].2;
    let end = text.rfind("</robot>").expect("a URDF");
    let mut out = String::with_capacity(text.len() + n * 180);
    out.push_str(&text[..end]);
    let mut parent = "base_link".to_string();
    for i in 0..n {
        let child = format!("chain_{i}");
        out.push_str(&format!(
            "<link name=\"{child}\"/><joint name=\"chain_joint_{i}\" type=\"fixed\">\
             <parent link=\"{parent}\"/><child link=\"{child}\"/>\
             <origin xyz=\"0.001 0 0\" rpy=\"0 0 0\"/></joint>\n"
        ));
        parent = child;
    }
    out.push_str(&text[end..]);
    out
}

/// The finding: a 43,000-link chain did not load in 3 minutes (the pose of every link
/// was walked to the root: quadratic). Loading is linear now (about 2 s in release).
#[test]
fn a_43000_link_chain_loads() {
    let n = 43_000;
    let robot = RobotModel::from_urdf_str(&chain_urdf(n), "chain.urdf").expect("loads");
    let last = robot
        .body_from(&format!("chain_{}", n - 1))
        .expect("the last link");
    // 43,000 steps of 1 mm (summed in floating point).
    assert!(
        (last.translation.vector.x - n as f64 * 0.001).abs() < 1e-6,
        "{}",
        last.translation.vector.x
    );
    assert!(robot.static_transforms.body_from.len() > n);
}

#[test]
fn urdf_link_count_is_bounded() {
    let links: String = (0..=MAX_URDF_LINKS)
        .map(|i| format!("<link name=\"l{i}\"/>"))
        .collect();
    let text = format!("<robot name=\"many\">{links}</robot>");
    let err = RobotModel::from_urdf_str(&text, "many.urdf")
        .expect_err("too many links")
        .to_string();
    assert!(
        err.starts_with("many.urdf:1:") && err.contains("MAX_URDF_LINKS"),
        "{err}"
    );
}

/// The finding: a 12-tonne chassis flipped over and the run passed. Now the run ends
/// with `tipped_over` and fails whatever its expectations say; a 1e30 kg chassis is
/// refused when the URDF is read.
#[test]
fn a_robot_that_tips_over_fails_its_run() {
    let dir = tempfile::tempdir().expect("temporary folder");
    let text = BUILTIN_MODELS[0]
        .2
        .replacen(r#"<mass value="120.0"/>"#, r#"<mass value="12000"/>"#, 1)
        .replacen(
            r#"<inertia ixx="4.9" ixy="0" ixz="0" iyy="10.4" iyz="0" izz="12.1"/>"#,
            r#"<inertia ixx="490" ixy="0" ixz="0" iyy="1040" iyz="0" izz="1210"/>"#,
            1,
        );
    std::fs::write(dir.path().join("heavy.urdf"), &text).expect("write");
    let scenario = dir.path().join("heavy.toml");
    std::fs::write(
        &scenario,
        "name = \"heavy\"\nmax_duration_s = 20.0\nexpect = [\"collisions.robot <= 1000\"]\n\
         [robot]\nurdf = \"heavy.urdf\"\n",
    )
    .expect("write");
    let sc = LoadedScenario::load(&scenario).unwrap_or_else(|e| panic!("{e}"));
    let sim = vinebench::runner::simulate(&sc, None).unwrap_or_else(|e| panic!("{e}"));
    let scores = vinebench::runner::score(&sc, &sim).unwrap();
    let outcome = &scores.robot.outcome;
    assert_eq!(outcome.kind(), "tipped_over", "{outcome}");
    assert!(!sim.route_completed);
    let results = vinebench::runner::evaluate(&sc, &scores);
    assert!(results[0].holds, "the stated expectation holds");
    let failed: Vec<_> = results.iter().filter(|r| !r.holds).collect();
    assert_eq!(failed.len(), 1, "{results:?}");
    assert!(
        failed[0]
            .note
            .as_deref()
            .is_some_and(|n| n.contains("tipped_over")),
        "{failed:?}"
    );

    let huge =
        BUILTIN_MODELS[0]
            .2
            .replacen(r#"<mass value="120.0"/>"#, r#"<mass value="1e30"/>"#, 1);
    let err = RobotModel::from_urdf_str(&huge, "huge.urdf")
        .expect_err("1e30 kg")
        .to_string();
    assert!(
        err.starts_with("huge.urdf:38:") && err.contains("MAX_LINK_MASS_KG"),
        "{err}"
    );
}
