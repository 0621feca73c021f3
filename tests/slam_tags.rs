//! AprilTag sightings on simulator renders: a tag36h11 board in a small vineyard, seen by
//! the ZED X Mini's distorted wide lens through the full camera path (render, sensor
//! noise, sRGB `rgb8` message, grey conversion, `CameraInfo`), must come back with its id
//! and its true `camera_from_tag`.

// Test helpers panic on failure by design.
#![allow(clippy::unwrap_used)]

use std::sync::{Arc, LazyLock};
use std::time::Instant;

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use vinebench_msgs::{FrameId, ImageEncoding, ImageMsg, Nanos};
use vinebench_onboard::slam::GrayImage;
use vinebench_onboard::slam::tags::{TagCamera, TagConfig, TagDetector, tag_corners};
use vinebench_sim::params::{RenderParams, RowPlacement, TagParams, WorldParams};
use vinebench_sim::render::camera::{CameraSpec, ImageNoise, Intrinsics, RayTable, look_at};
use vinebench_sim::render::shade::{Frame, Renderer};
use vinebench_sim::world::{TagBoard, World};

/// The tag's id.
const TAG_ID: u32 = 7;

/// The tag size, m.
const TAG_SIZE_M: f64 = 0.3;

/// Two short rows with one board in the headland before row 0, mid-lane, its printed face
/// looking back along the rows (away from them) so the cameras stand in the open headland.
struct Scene {
    board: TagBoard,
    renderer: Renderer,
}

static SCENE: LazyLock<Scene> = LazyLock::new(|| {
    let mut p = WorldParams::default();
    p.rows.count = 2;
    p.rows.length_m = 12.0;
    p.rows.yaw_deg = 0.0;
    p.terrain.margin_m = 5.0;
    p.headlands.width_m = 4.0;
    p.canopy.leaves_per_plant = 400;
    p.tags = vec![TagParams {
        id: TAG_ID,
        size_m: TAG_SIZE_M,
        height_m: 0.9,
        at: RowPlacement {
            row: 0,
            s_m: -1.0,
            offset_m: 1.25,
            yaw_deg: 180.0,
        },
    }];
    let world = World::generate(5, &p).expect("valid world");
    let renderer = vinebench_sim::render::build_renderer(&world, &RenderParams::default())
        .expect("default render parameters");
    Scene {
        board: world.tags[0].clone(),
        renderer,
    }
});

/// The optical frame of a camera `distance_m` from the tag centre, `yaw_deg` around the
/// vertical off the tag's normal and `rise_m` above the centre, looking at the centre,
/// rolled by `roll_deg` about its optical axis: `world_from_camera`.
fn viewpoint(
    board: &TagBoard,
    distance_m: f64,
    yaw_deg: f64,
    rise_m: f64,
    roll_deg: f64,
) -> Isometry3<f64> {
    let centre = board.world_from_tag.translation.vector;
    let face = board.world_from_tag.rotation * -Vector3::z();
    let dir = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_deg.to_radians()) * face;
    let horizontal = (distance_m * distance_m - rise_m * rise_m).sqrt();
    let eye = centre + dir * horizontal + Vector3::new(0.0, 0.0, rise_m);
    look_at(eye, centre - eye) * Isometry3::rotation(Vector3::z() * roll_deg.to_radians())
}

/// The ZED X Mini at its full 1920×1080: 110° HFOV, k1 = −0.05, k2 = 0.01, with its
/// per-pixel rays (computed once).
static CAMERA: LazyLock<(Intrinsics, RayTable)> = LazyLock::new(|| {
    let intr = CameraSpec::zed_x_mini().intrinsics;
    let rays = intr.pixel_rays();
    (intr, rays)
});

/// The camera's image at `world_from_camera` as the sensor publishes it (noise, sRGB
/// `rgb8`), converted to grey, with the camera from its `CameraInfo`.
fn shoot(world_from_camera: &Isometry3<f64>, seed: u64) -> (GrayImage, TagCamera) {
    let (intr, rays) = &*CAMERA;
    let mut frame = Frame::new(intr.width, intr.height);
    SCENE.renderer.render(
        rays,
        world_from_camera,
        (1.0 / intr.fx) as f32,
        1000.0,
        &mut frame,
    );
    let mut rgb = vec![0u8; frame.linear.len()];
    ImageNoise::default().apply_encode_srgb(
        &frame.linear,
        &mut rgb,
        &mut ChaCha8Rng::seed_from_u64(seed),
    );
    let frame_id = FrameId::new("side_color_optical_frame");
    let msg = ImageMsg {
        stamp: Nanos(0),
        topic: Arc::from("/side/color/image_raw"),
        frame_id: frame_id.clone(),
        width: intr.width,
        height: intr.height,
        encoding: ImageEncoding::Rgb8,
        data: Arc::from(rgb),
    };
    let info = intr.camera_info_msg(
        Nanos(0),
        Arc::from("/side/color/camera_info"),
        frame_id,
        0.0,
    );
    (
        GrayImage::from_msg(&msg).unwrap(),
        TagCamera::from_info(&info),
    )
}

/// The true `camera_from_tag` of a camera at `world_from_camera`.
fn truth(world_from_camera: &Isometry3<f64>) -> Isometry3<f64> {
    world_from_camera.inverse() * SCENE.board.world_from_tag
}

#[test]
fn a_rendered_tag_is_found_at_its_true_pose_through_the_distorted_lens() {
    assert!(CAMERA.0.distortion.k1 != 0.0 && CAMERA.0.distortion.k2 != 0.0);
    let mut detector = TagDetector::new(TagConfig::default()).unwrap();
    // (distance m, yaw deg, rise m, roll deg): head-on, oblique, oblique from above and
    // rolled. The board is back-lit against the sky (its white border darker than the
    // sky): AprilTag alone misses it at the default decimation (see the tone curve).
    for (k, view) in [
        (1.2, 0.0, 0.0, 0.0),
        (1.5, 40.0, 0.0, 0.0),
        (1.3, -40.0, 0.4, 20.0),
    ]
    .into_iter()
    .enumerate()
    {
        let pose = viewpoint(&SCENE.board, view.0, view.1, view.2, view.3);
        let (image, camera) = shoot(&pose, k as u64);
        let sightings = detector.detect(&image, &camera);
        assert_eq!(
            sightings.iter().map(|s| s.id).collect::<Vec<_>>(),
            vec![TAG_ID],
            "view {view:?}: {sightings:?}"
        );
        let s = &sightings[0];
        let truth = truth(&pose);
        let dt = (s.camera_from_tag.translation.vector - truth.translation.vector).norm();
        let dr = s
            .camera_from_tag
            .rotation
            .angle_to(&truth.rotation)
            .to_degrees();
        // The corners against the true corners through the camera model.
        let corner_px = tag_corners(TAG_SIZE_M)
            .iter()
            .zip(&s.corners_px)
            .map(|(p, c)| {
                let px = camera.project(&(truth * p).coords).unwrap();
                (px.x - c[0]).hypot(px.y - c[1])
            })
            .fold(0.0, f64::max);
        println!(
            "view {view:?}: {:.1} mm, {dr:.3} deg, corners within {corner_px:.2} px, \
             RMS {:.3} px, margin {:.0}",
            dt * 1e3,
            s.reprojection_rms_px,
            s.decision_margin
        );
        // The renderer point-samples the board (no anti-aliasing), so a head-on tag's
        // edges sit on pixel boundaries: up to 0.5 px per edge, a few mm of range.
        assert!(dt < 0.01 && dr < 0.5, "view {view:?}: {dt} m, {dr} deg");
        assert!(
            corner_px < 0.6,
            "view {view:?}: corners off by {corner_px} px"
        );
        assert!(s.reprojection_rms_px < 0.5 && s.hamming == 0);
    }
}

#[test]
fn a_tag_beyond_max_distance_is_dropped() {
    let pose = viewpoint(&SCENE.board, 2.5, 20.0, 0.0, 0.0);
    let (image, camera) = shoot(&pose, 9);
    let near = TagConfig {
        max_distance_m: 2.0,
        ..TagConfig::default()
    };
    assert!(
        TagDetector::new(near)
            .unwrap()
            .detect(&image, &camera)
            .is_empty()
    );
    let sightings = TagDetector::new(TagConfig::default())
        .unwrap()
        .detect(&image, &camera);
    assert_eq!(sightings.len(), 1);
    let range = sightings[0].camera_from_tag.translation.vector.norm();
    assert!((range - 2.5).abs() < 0.02, "range {range} m");
}

/// Detection time per 1920×1080 frame at the default settings (AprilTag on one thread,
/// corner refinement and pose included): `cargo test --release --test slam_tags --
/// --ignored --nocapture`.
#[test]
#[ignore = "timing, not a check"]
fn detection_time_per_1080p_frame() {
    let pose = viewpoint(&SCENE.board, 2.0, 30.0, 0.0, 0.0);
    let (image, camera) = shoot(&pose, 3);
    for decimation in [1.0, 1.5, 2.0, 3.0] {
        let mut detector = TagDetector::new(TagConfig {
            decimation,
            ..TagConfig::default()
        })
        .unwrap();
        let mut ms: Vec<f64> = (0..10)
            .map(|_| {
                let t0 = Instant::now();
                assert_eq!(detector.detect(&image, &camera).len(), 1);
                t0.elapsed().as_secs_f64() * 1e3
            })
            .collect();
        ms.sort_by(f64::total_cmp);
        println!(
            "decimation {decimation}: {:.1} ms min, {:.1} ms median per 1920x1080 frame",
            ms[0], ms[5]
        );
    }
}

/// A scenario whose SLAM closes loops at tags needs its tag camera; without it, the error
/// names the key and the way out.
#[test]
fn a_missing_tag_camera_is_an_error_naming_the_key() {
    let scenario = |extra: &str| {
        format!(
            "[world.rows]\ncount = 3\nlength_m = 4.0\n[robot]\nmodel = \"mecanum-rover\"\n[sensors.tracking_camera]\nframe = \"front_camera_link\"\n\
             [slam]\nenabled = true\ncameras = [\"front\"]\n{extra}\n\
             [[sensors.cameras]]\nname = \"front\"\nprofile = \"zed2i\"\n\
             frame = \"front_camera_left_optical_frame\"\n\
             right_frame = \"front_camera_right_optical_frame\"\nwidth = 376\nheight = 240\n"
        )
    };
    let sc = vinebench::scenario::LoadedScenario::from_str(&scenario(""), "x.toml").unwrap();
    let e = vinebench::runner::setup(&sc)
        .err()
        .expect("no side camera")
        .to_string();
    assert!(
        e.contains("slam.tags.camera") && e.contains("\"side\"") && e.contains("method"),
        "{e}"
    );
    let sc = vinebench::scenario::LoadedScenario::from_str(
        &scenario("[slam.loop_closure]\nmethod = \"none\"\n"),
        "x.toml",
    )
    .unwrap();
    assert!(vinebench::runner::setup(&sc).is_ok());
}

/// The bag-of-words baseline needs its vocabulary file: a missing one is an error naming
/// the key, the file and how to train one; the shipped one loads.
#[test]
fn a_missing_vocabulary_is_an_error_naming_the_key_and_the_command() {
    let scenario = |extra: &str| {
        format!(
            "[world.rows]\ncount = 3\nlength_m = 4.0\n[robot]\nmodel = \"mecanum-rover\"\n[sensors.tracking_camera]\nframe = \"front_camera_link\"\n\
             [slam]\nenabled = true\ncameras = [\"front\"]\nbaselines = [\"bow\"]\n\
             [slam.loop_closure]\nmethod = \"none\"\n{extra}\n\
             [[sensors.cameras]]\nname = \"front\"\nprofile = \"zed2i\"\n\
             frame = \"front_camera_left_optical_frame\"\n\
             right_frame = \"front_camera_right_optical_frame\"\nwidth = 376\nheight = 240\n"
        )
    };
    let text = scenario("[slam.bow]\nvocabulary = \"no/such.vbvoc\"\n");
    let sc = vinebench::scenario::LoadedScenario::from_str(&text, "x.toml").unwrap();
    let e = vinebench::runner::setup(&sc)
        .err()
        .expect("no vocabulary file")
        .to_string();
    assert!(
        e.contains("slam.bow.vocabulary")
            && e.contains("no/such.vbvoc")
            && e.contains("vinebench vocabulary"),
        "{e}"
    );
    // The default path, relative to a scenario in scenarios/, is the shipped vocabulary.
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/x.toml");
    let mut sc = vinebench::scenario::LoadedScenario::from_str(&scenario(""), "x.toml").unwrap();
    sc.base_dir = path.parent().unwrap().to_path_buf();
    assert!(vinebench::runner::setup(&sc).is_ok());
}
