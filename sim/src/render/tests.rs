//! End-to-end rendering tests: geometry, shading, cameras and noise together.

use super::camera::{CameraSpec, DepthScratch, Intrinsics, StereoDepthNoise, look_at};
use super::scene::{self, Material, RenderScene, ShadingMesh};
use super::shade::{Frame, Lighting, Renderer, ShadowMap};
use super::texture::grvi;
use super::{Affine3, Instance, MeshGeometry, TraceScene};
use crate::params::{RenderParams, RowPlacement, TagParams, WorldParams};
use crate::world::World;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn lighting() -> Lighting {
    Lighting {
        to_sun: Lighting::sun_direction(150.0, 50.0),
        sun: 0.8,
        sky: 0.3,
        exposure: 1.0,
        sun_glare: false,
    }
}

/// A single square `[-h, h]²` at height `z` in the scene frame, facing up, of `material`.
fn plane_scene(h: f32, z: f32, material: Material) -> RenderScene {
    let geo = MeshGeometry {
        positions: vec![[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]],
        indices: vec![[0, 1, 2], [0, 2, 3]],
    };
    let s = h / 2.0;
    let shade = ShadingMesh {
        normals: vec![[0.0, 0.0, 1.0]; 4],
        uvs: vec![[-s, -s], [s, -s], [s, s], [-s, s]],
        materials: vec![material; 2],
        colors: Vec::new(),
    };
    RenderScene {
        trace: TraceScene {
            origin_in_world: Vector3::zeros(),
            meshes: vec![geo],
            instances: vec![Instance {
                mesh: 0,
                scene_from_mesh: Affine3::IDENTITY,
            }],
        },
        shading: vec![shade],
        normal_from_mesh: vec![[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]],
        instance_tag: vec![u32::MAX],
        tag_ids: vec![],
        caster_bounds: ([-h, -h, z - 0.1], [h, h, z + 0.1]),
        grape: crate::params::GrapeColour::Red,
    }
}

fn renderer(scene: RenderScene) -> Renderer {
    let caster = crate::render::build_default(&scene.trace);
    Renderer::new(scene, caster, lighting(), 0.05, 7)
}

/// Camera looking straight down from `height` above the origin (optical z = world -z).
fn looking_down(height: f64) -> Isometry3<f64> {
    // Optical x right = world x, y down = world -y, z forward = world -z.
    let r = nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::new(
        1.0, 0.0, 0.0, //
        0.0, -1.0, 0.0, //
        0.0, 0.0, -1.0,
    ));
    Isometry3::from_parts(
        Translation3::new(0.0, 0.0, height),
        UnitQuaternion::from_rotation_matrix(&r),
    )
}

fn render(r: &Renderer, intr: &Intrinsics, pose: &Isometry3<f64>) -> Frame {
    let rays = intr.pixel_rays();
    let mut f = Frame::new(intr.width, intr.height);
    r.render(&rays, pose, (1.0 / intr.fx) as f32, 1000.0, &mut f);
    f
}

#[test]
fn a_plane_at_known_distance_gives_its_depth_and_the_d435_noise() {
    let z = 2.0;
    let r = renderer(plane_scene(50.0, 0.0, Material::Soil));
    let spec = CameraSpec::d435_depth(super::camera::D435DepthMode::W848H480, 15.0);
    let intr = spec.intrinsics;
    let f = render(&r, &intr, &looking_down(z));
    // Noise-free render: every pixel sees the plane at exactly depth z.
    let worst = f
        .depth_m
        .iter()
        .map(|d| (f64::from(*d) - z).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-4, "rendered depth off by {worst} m");
    // Through the D435 model: mean within 1 mm, RMS as z²·s/(f·b) within 10 %.
    let st = spec.stereo.expect("the D435 has a depth unit");
    let model = StereoDepthNoise::new(&intr, &st);
    let mut mm = vec![0u16; intr.pixel_count()];
    let mut scratch = DepthScratch::new();
    model.apply(
        intr.width,
        intr.height,
        &f.depth_m,
        &mut mm,
        &mut scratch,
        &mut ChaCha8Rng::seed_from_u64(3),
    );
    let valid: Vec<f64> = mm
        .iter()
        .filter(|&&d| d > 0)
        .map(|&d| f64::from(d) * 1e-3)
        .collect();
    assert!(
        valid.len() > intr.pixel_count() * 8 / 10,
        "{} valid",
        valid.len()
    );
    let mean = valid.iter().sum::<f64>() / valid.len() as f64;
    let rms = (valid.iter().map(|d| (d - z).powi(2)).sum::<f64>() / valid.len() as f64).sqrt();
    let expected = z * z * st.subpixel / (intr.fx * st.baseline_m);
    assert!((mean - z).abs() < 1e-3, "mean {mean}");
    assert!(
        (rms / expected - 1.0).abs() < 0.1,
        "rms {rms} vs z²·s/(f·b) = {expected}"
    );
}

fn small_world(tags: Vec<TagParams>) -> World {
    let mut p = WorldParams::default();
    p.rows.count = 2;
    p.rows.length_m = 12.0;
    p.rows.yaw_deg = 0.0;
    p.terrain.margin_m = 5.0;
    p.headlands.width_m = 3.0;
    p.canopy.leaves_per_plant = 400;
    p.tags = tags;
    World::generate(5, &p).expect("valid world")
}

fn world_renderer(world: &World) -> Renderer {
    let p = RenderParams::default();
    super::build_renderer(world, &p).expect("default render parameters are valid")
}

#[test]
fn grvi_separates_leaf_pixels_from_soil_pixels() {
    let world = small_world(vec![]);
    let r = world_renderer(&world);
    let intr = Intrinsics::from_hfov(320, 240, 87.0, Default::default());
    // In the lane between the rows, 1 m up, looking along it and slightly down.
    let pose = look_at(Vector3::new(1.0, 1.25, 1.0), Vector3::new(1.0, 0.0, -0.25));
    let f = render(&r, &intr, &pose);
    let rays = intr.pixel_rays();
    let o = pose.translation.vector - r.scene().trace.origin_in_world;
    let (mut leaf, mut soil) = (Vec::new(), Vec::new());
    for i in 0..intr.pixel_count() {
        let d_cam = Vector3::new(rays.x[i], rays.y[i], rays.z[i]).cast::<f64>();
        let d = pose.rotation * d_cam;
        let hit = r.caster().cast_ray(
            [o.x as f32, o.y as f32, o.z as f32],
            [d.x as f32, d.y as f32, d.z as f32],
            0.0,
            1000.0,
        );
        if !hit.is_hit() {
            continue;
        }
        let m = r.scene().material_of(&hit);
        let px = [f.linear[3 * i], f.linear[3 * i + 1], f.linear[3 * i + 2]];
        match m {
            Material::Leaf => leaf.push(grvi(px)),
            Material::Soil => soil.push(grvi(px)),
            _ => {}
        }
    }
    assert!(
        leaf.len() > 2000 && soil.len() > 2000,
        "{} leaf, {} soil",
        leaf.len(),
        soil.len()
    );
    // A single threshold classifies at least 95 % of each class.
    let t = 0.05;
    let leaf_ok = leaf.iter().filter(|&&g| g > t).count() as f64 / leaf.len() as f64;
    let soil_ok = soil.iter().filter(|&&g| g <= t).count() as f64 / soil.len() as f64;
    assert!(
        leaf_ok > 0.95 && soil_ok > 0.95,
        "leaf {leaf_ok}, soil {soil_ok}"
    );
}

#[test]
fn renders_are_identical_across_runs_and_thread_counts() {
    let world = small_world(vec![]);
    let r = world_renderer(&world);
    let intr = Intrinsics::from_hfov(200, 120, 90.0, Default::default());
    let pose = look_at(Vector3::new(0.5, 1.25, 1.0), Vector3::new(1.0, 0.2, -0.2));
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool")
        .install(|| render(&r, &intr, &pose));
    let two = render(&r, &intr, &pose);
    assert_eq!(one.linear, two.linear);
    assert_eq!(one.depth_m, two.depth_m);
    // A second renderer from the same world gives the same pixels.
    let again = render(&world_renderer(&world), &intr, &pose);
    assert_eq!(one.linear, again.linear);
}

#[test]
fn an_apriltag_board_is_detected_at_the_projected_corners() {
    let tag = TagParams {
        id: 7,
        size_m: 0.3,
        height_m: 0.8,
        at: RowPlacement {
            row: 0,
            s_m: 2.0,
            offset_m: 0.8,
            yaw_deg: 90.0,
        },
    };
    let world = small_world(vec![tag]);
    let board = &world.tags[0];
    let r = world_renderer(&world);
    // A distorted wide camera 1.5 m in front of the board, looking at it slightly off-axis.
    let spec = CameraSpec::zed_x_mini();
    let intr = spec.intrinsics.resized(960, 540);
    let centre = board.world_from_tag.translation.vector;
    let face = board.world_from_tag.rotation * -Vector3::z();
    let eye = centre + face * 1.5 + Vector3::new(0.3, 0.0, 0.1);
    let pose = look_at(eye, centre - eye);
    let f = render(&r, &intr, &pose);
    let gray: Vec<u8> = f
        .linear
        .chunks_exact(3)
        .map(|c| super::camera::linear_to_srgb_u8(0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]))
        .collect();
    let (w, h) = (intr.width as usize, intr.height as usize);
    let mut image = apriltag::Image::zeros_with_stride(w, h, w).expect("image");
    for y in 0..h {
        for x in 0..w {
            image[(x, y)] = gray[y * w + x];
        }
    }
    let mut detector = apriltag::DetectorBuilder::new()
        .add_family_bits(apriltag::Family::tag_36h11(), 1)
        .build()
        .expect("detector");
    // Full resolution: the tag's cells are about 8 px here.
    detector.set_decimation(1.0);
    let detections = detector.detect(&image);
    let det = detections.iter().find(|d| d.id() == 7).unwrap_or_else(|| {
        panic!(
            "tag 7 not detected; found {:?}",
            detections.iter().map(|d| d.id()).collect::<Vec<_>>()
        )
    });
    let camera_from_world = pose.inverse();
    for (k, c) in super::tag::tag_corners(board.size_m).iter().enumerate() {
        let p_world = board.world_from_tag * Point3::new(c[0], c[1], c[2]);
        let p_cam = camera_from_world * p_world;
        let px = intr.project(p_cam.coords).expect("corner in view");
        // AprilTag puts pixel centres at +0.5; our cameras at integers (OpenCV).
        let got = det.corners()[k];
        let (gx, gy) = (got[0] - 0.5, got[1] - 0.5);
        let err = ((px.x - gx).powi(2) + (px.y - gy).powi(2)).sqrt();
        assert!(err < 1.5, "corner {k}: detected {got:?}, projected {px:?}");
    }
}

#[test]
fn stereo_disparity_of_a_textured_plane_gives_its_depth() {
    // A textured ground plane seen straight down from 2.5 m by a rectified pair.
    let z = 2.5;
    let r = renderer(plane_scene(50.0, 0.0, Material::Soil));
    let intr = Intrinsics::from_hfov(376, 240, 90.0, Default::default());
    let baseline = 0.12;
    let left_pose = looking_down(z);
    let right_pose = left_pose * Isometry3::translation(baseline, 0.0, 0.0);
    let grey = |f: &Frame| -> Vec<f32> {
        f.linear
            .chunks_exact(3)
            .map(|c| 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2])
            .collect()
    };
    let l = grey(&render(&r, &intr, &left_pose));
    let rr = grey(&render(&r, &intr, &right_pose));
    let w = intr.width as usize;
    let expected = intr.fx * baseline / z;
    // Sum-of-absolute-differences block matching along the row, parabolic sub-pixel.
    let mut depths = Vec::new();
    for v in (40..200).step_by(20) {
        for u in (120..340).step_by(20) {
            let cost = |d: usize| -> f32 {
                let mut s = 0.0;
                for dv in -5i32..=5 {
                    for du in -5i32..=5 {
                        let row = (v + dv) as usize * w;
                        let a = l[row + (u + du) as usize];
                        let b = rr[row + (u + du) as usize - d];
                        s += (a - b).abs();
                    }
                }
                s
            };
            let costs: Vec<f32> = (1..100).map(cost).collect();
            let (i, _) = costs
                .iter()
                .enumerate()
                .min_by(|a, b| a.1.total_cmp(b.1))
                .expect("costs");
            if i == 0 || i + 1 >= costs.len() {
                continue;
            }
            let (a, b, c) = (costs[i - 1], costs[i], costs[i + 1]);
            let sub = 0.5 * (a - c) / (a - 2.0 * b + c);
            let d = (i + 1) as f64 + f64::from(sub);
            depths.push(intr.fx * baseline / d);
        }
    }
    assert!(depths.len() > 60, "{} matches", depths.len());
    depths.sort_by(f64::total_cmp);
    let median = depths[depths.len() / 2];
    assert!(
        (median - z).abs() < 0.02 * z,
        "median stereo depth {median} m (disparity {expected} px)"
    );
}

/// A 2 × 2 m roof 1 m above 8 × 8 m of ground, sun from the south-east at 50°: ground
/// points whose sun ray passes through the roof (closed form: the ray reaches z = 1 at
/// `p + s / s_z`) are in shadow, the others and the roof itself are lit. Points within
/// three 7 cm cells of the shadow's edge (the 2 × 2 filter's penumbra) are skipped.
#[test]
fn the_shadow_map_darkens_exactly_the_ground_under_the_roof() {
    let ground = plane_scene(4.0, 0.0, Material::Soil);
    let roof = MeshGeometry {
        positions: vec![
            [-1.0, -1.0, 1.0],
            [1.0, -1.0, 1.0],
            [1.0, 1.0, 1.0],
            [-1.0, 1.0, 1.0],
        ],
        indices: vec![[0, 1, 2], [0, 2, 3]],
    };
    let mut sc = ground;
    sc.trace.meshes.push(roof);
    sc.trace.instances.push(Instance {
        mesh: 1,
        scene_from_mesh: Affine3::IDENTITY,
    });
    sc.shading.push(sc.shading[0].clone());
    sc.normal_from_mesh.push(sc.normal_from_mesh[0]);
    sc.instance_tag.push(u32::MAX);
    sc.caster_bounds = ([-4.0, -4.0, -0.1], [4.0, 4.0, 1.1]);
    let caster = crate::render::build_default(&sc.trace);
    let to_sun = Lighting::sun_direction(135.0, 50.0);
    let cell = 0.07;
    let map = ShadowMap::bake(&sc, caster.as_ref(), to_sun, cell);
    let s = to_sun.normalize();
    let bias = (0.03 + 2.0 * cell) as f32;
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let (mut shadowed, mut lit) = (0, 0);
    for _ in 0..4000 {
        use rand::Rng;
        let (x, y) = (rng.random_range(-3.5..3.5), rng.random_range(-3.5..3.5));
        let at_roof = Vector3::new(x, y, 0.0) + s / s.z;
        // Distance of the sun ray's crossing of z = 1 from the roof's edge.
        let inside = (1.0 - at_roof.x.abs()).min(1.0 - at_roof.y.abs());
        if inside.abs() < 3.0 * cell {
            continue; // penumbra of the 2 × 2 filter
        }
        let v = map.visibility([x as f32, y as f32, 0.0], bias);
        if inside > 0.0 {
            assert_eq!(v, 0.0, "({x:.3}, {y:.3}) is under the roof");
            shadowed += 1;
        } else {
            assert_eq!(v, 1.0, "({x:.3}, {y:.3}) sees the sun");
            lit += 1;
        }
    }
    assert!(
        shadowed > 150 && lit > 2000,
        "{shadowed} shadowed, {lit} lit"
    );
    for (x, y) in [(0.0, 0.0), (0.9, -0.9), (-0.5, 0.7)] {
        assert_eq!(map.visibility([x, y, 1.0], bias), 1.0, "roof ({x}, {y})");
    }
}

#[test]
fn render_scene_of_a_default_world_fits_the_memory_budget() {
    let mut p = WorldParams::default();
    p.rows.count = 10;
    let world = World::generate(1, &p).expect("valid world");
    let s = scene::build(
        &world,
        &scene::GeometryOptions {
            terrain_cell_m: 0.25,
        },
    );
    assert!(
        s.instanced_triangles() > 5_000_000,
        "{}",
        s.instanced_triangles()
    );
    // Scene data alone well under the 500 MB budget (the BVH is measured by the bench).
    assert!(s.memory_bytes() < 150_000_000, "{} bytes", s.memory_bytes());
}

/// Two views of `small_world`: along the lane from its start, and across the rows.
fn lane_views() -> [Isometry3<f64>; 2] {
    [
        look_at(Vector3::new(1.0, 1.25, 1.0), Vector3::new(1.0, 0.0, -0.25)),
        look_at(Vector3::new(6.0, 1.25, 1.2), Vector3::new(0.2, 1.0, -0.1)),
    ]
}

/// The two depth images agree within 1 mm on at least 99.9 % of the pixels.
fn assert_same_depth(a: &Frame, b: &Frame) {
    let same = a
        .depth_m
        .iter()
        .zip(&b.depth_m)
        .filter(|(x, y)| (*x - *y).abs() <= 1e-3)
        .count();
    let frac = same as f64 / a.depth_m.len() as f64;
    assert!(frac >= 0.999, "{:.4} % of depths within 1 mm", 100.0 * frac);
}

#[cfg(feature = "embree")]
#[test]
fn embree_and_the_builtin_bvh_render_the_same_depth_image() {
    use crate::params::RenderBackend;
    let world = small_world(vec![]);
    let bvh = world_renderer(&world);
    let p = RenderParams {
        backend: RenderBackend::Embree,
        ..RenderParams::default()
    };
    let embree = super::build_renderer(&world, &p).expect("embree builds the scene");
    let intr = Intrinsics::from_hfov(640, 480, 87.0, Default::default());
    for pose in lane_views() {
        let a = render(&bvh, &intr, &pose);
        let b = render(&embree, &intr, &pose);
        assert_same_depth(&a, &b);
    }
}

/// Two 12 m rows along x with a 0.6 × 0.4 × 0.5 m carton box in the lane beside row 0
/// (centre (6, 1.25)), and `tags`.
fn box_world(tags: Vec<TagParams>) -> World {
    let mut p = WorldParams::default();
    p.rows.count = 2;
    p.rows.length_m = 12.0;
    p.rows.yaw_deg = 0.0;
    p.terrain.margin_m = 5.0;
    p.headlands.width_m = 3.0;
    p.occluders = vec![crate::params::OccluderParams {
        size_m: [0.6, 0.4, 0.5],
        at: RowPlacement {
            row: 0,
            s_m: 6.0,
            offset_m: 1.25,
            yaw_deg: 0.0,
        },
    }];
    p.tags = tags;
    World::generate(2, &p).expect("valid world")
}

#[test]
fn occluder_boxes_and_tag_boards_stand_where_the_scenario_puts_them() {
    let world = box_world(vec![TagParams {
        id: 3,
        size_m: 0.2,
        height_m: 0.7,
        at: RowPlacement {
            row: 0,
            s_m: 2.0,
            offset_m: 1.0,
            yaw_deg: 90.0,
        },
    }]);
    let s = scene::build(
        &world,
        &scene::GeometryOptions {
            terrain_cell_m: 0.25,
        },
    );
    let caster = crate::render::build_default(&s.trace);
    let material_hit = |from: Vector3<f64>, dir: Vector3<f64>| {
        let o = from - s.trace.origin_in_world;
        let hit = caster.cast_ray(
            [o.x as f32, o.y as f32, o.z as f32],
            [dir.x as f32, dir.y as f32, dir.z as f32],
            0.0,
            100.0,
        );
        assert!(hit.is_hit(), "{from} {dir}");
        (s.material_of(&hit), f64::from(hit.t))
    };
    // The box: centre (6, 1.25), 0.6 m long along x; a level ray from x = 3 at mid-height
    // meets its face at x = 5.7.
    let ground = world.terrain.height_at(6.0, 1.25);
    let (m, t) = material_hit(Vector3::new(3.0, 1.25, ground + 0.25), Vector3::x());
    assert_eq!(m, Material::Carton);
    assert!((t - 2.7).abs() < 0.01, "box face at {t} m");
    // The tag board at (2, 1.0), face towards +y, centre 0.7 m above ground: a ray from
    // y = 2 towards -y meets the printed face at y = 1.0.
    let ground = world.terrain.height_at(2.0, 1.0);
    let (m, t) = material_hit(Vector3::new(2.0, 2.0, ground + 0.7), -Vector3::y());
    assert_eq!(m, Material::Tag);
    assert!((t - 1.0).abs() < 0.005, "tag face at {t} m");
}

#[test]
fn motion_blur_matches_the_average_of_renders_over_the_exposure() {
    use super::blur::{CameraMotion, motion_blur};
    use super::camera::BrownConrady;
    // A textured ground 2 m below a camera that moves sideways, forwards and turns during
    // a long exposure: the post-process blur must match the exposure integral, i.e. the
    // mean of many sharp renders at poses spread over the exposure.
    let r = renderer(plane_scene(50.0, 0.0, Material::Soil));
    let intr = Intrinsics::from_hfov(200, 150, 70.0, BrownConrady::NONE);
    let rays = intr.pixel_rays();
    let pose = looking_down(2.0);
    let motion = CameraMotion {
        linear_mps: Vector3::new(1.2, -0.4, 0.3),
        angular_radps: Vector3::new(0.2, 0.3, 0.9),
    };
    let exposure_s = 0.05;
    let render_at = |t: f64| {
        let step = Isometry3::new(motion.linear_mps * t, motion.angular_radps * t);
        let mut f = Frame::new(intr.width, intr.height);
        r.render(
            &rays,
            &(pose * step),
            (1.0 / intr.fx) as f32,
            1000.0,
            &mut f,
        );
        f
    };
    let k = 48;
    let mut reference = vec![0.0f32; 3 * intr.pixel_count()];
    for j in 0..k {
        let t = ((j as f64 + 0.5) / k as f64 - 0.5) * exposure_s;
        for (a, x) in reference.iter_mut().zip(&render_at(t).linear) {
            *a += x / k as f32;
        }
    }
    let sharp = render_at(0.0);
    let mut blurred = sharp.clone();
    let mut scratch = Vec::new();
    motion_blur(
        &mut blurred,
        &mut scratch,
        &rays,
        intr.fx,
        intr.fy,
        &motion,
        exposure_s,
    );
    // Compare away from the border (the blur clamps at the image edge).
    let (w, h) = (intr.width as usize, intr.height as usize);
    let err = |img: &[f32]| {
        let mut s = 0.0f64;
        let mut n = 0usize;
        for v in 12..h - 12 {
            for u in 12..w - 12 {
                for c in 0..3 {
                    let i = 3 * (v * w + u) + c;
                    s += f64::from((img[i] - reference[i]).abs());
                    n += 1;
                }
            }
        }
        s / n as f64
    };
    let (e_blur, e_sharp) = (err(&blurred.linear), err(&sharp.linear));
    // The smear is several pixels long (translation ≈ 1.2·fx·T/Z ≈ 4.3 px, rotation
    // ≈ 0.9·T·r ≈ 3 px at the corners), so the sharp image is far from the integral.
    assert!(
        e_blur < 0.25 * e_sharp,
        "mean |blurred − integral| = {e_blur}, |sharp − integral| = {e_sharp}"
    );
    // Blurring the other way round (wrong sign) must be worse than the right one.
    let mut wrong = sharp.clone();
    let reversed = CameraMotion {
        linear_mps: -motion.linear_mps,
        angular_radps: motion.angular_radps,
    };
    motion_blur(
        &mut wrong,
        &mut scratch,
        &rays,
        intr.fx,
        intr.fy,
        &reversed,
        exposure_s,
    );
    assert!(err(&wrong.linear) > 2.0 * e_blur);
}

/// `[world.mesh]`: the generated vineyard flattened into one world-frame triangle mesh
/// (every instance's triangles placed by its transform) and drawn as a loaded mesh gives
/// the depth image of the generated scene itself; its vertex colours are its albedo.
#[test]
fn a_loaded_world_mesh_renders_as_the_geometry_it_was_taken_from() {
    let world = small_world(vec![]);
    let generated = world_renderer(&world);
    let trace = &generated.scene().trace;
    let mut mesh = scene::WorldMesh::default();
    for inst in &trace.instances {
        let m = &trace.meshes[inst.mesh as usize];
        let first = mesh.vertices.len() as u32;
        for p in &m.positions {
            let a = &inst.scene_from_mesh.rows;
            let q: [f64; 3] = std::array::from_fn(|i| {
                f64::from(a[i][0] * p[0] + a[i][1] * p[1] + a[i][2] * p[2] + a[i][3])
            });
            mesh.vertices
                .push([0, 1, 2].map(|i| q[i] + trace.origin_in_world[i]));
        }
        mesh.triangles
            .extend(m.indices.iter().map(|t| t.map(|i| i + first)));
    }
    // A red vertex colour on everything.
    mesh.colors = vec![[200, 30, 30]; mesh.vertices.len()];
    let mut p = world.params.clone();
    p.mesh.keep_ground = false;
    let mesh_world = World {
        params: p,
        ..world.clone()
    };
    let loaded =
        super::build_renderer_with_mesh(&mesh_world, &RenderParams::default(), Some(&mesh))
            .expect("a valid mesh");
    assert_eq!(
        loaded.scene().trace.instances.len(),
        1,
        "one mesh, no ground"
    );
    let intr = Intrinsics::from_hfov(320, 240, 87.0, Default::default());
    for pose in lane_views() {
        let a = render(&generated, &intr, &pose);
        let b = render(&loaded, &intr, &pose);
        assert_same_depth(&a, &b);
        let hit: Vec<&[f32]> = b
            .linear
            .chunks_exact(3)
            .zip(&b.depth_m)
            .filter(|(_, d)| **d > 0.0)
            .map(|(c, _)| c)
            .collect();
        assert!(hit.len() > 1000);
        let red = hit
            .iter()
            .filter(|c| c[0] > 3.0 * c[1] && c[0] > 3.0 * c[2])
            .count();
        assert!(
            red * 100 >= hit.len() * 99,
            "{red} of {} hit pixels red",
            hit.len()
        );
    }
    let bad = scene::WorldMesh {
        triangles: vec![[0, 1, 7]],
        vertices: vec![[0.0; 3]; 3],
        colors: Vec::new(),
    };
    let e = super::build_renderer_with_mesh(&mesh_world, &RenderParams::default(), Some(&bad))
        .map(|_| ())
        .expect_err("an index past the vertices");
    assert_eq!(e.path, "world.mesh.file");
    assert!(e.to_string().contains("triangle 0"), "{e}");
}

/// The daylight model of the defaults (`[sensors.stereo_depth]`, `[render]` noise).
fn sunlight_model() -> super::depth_light::SunlightStereo {
    super::depth_light::SunlightStereo::from_params(
        &crate::params::StereoDepthParams::default(),
        &RenderParams::default(),
    )
}

/// Depth of `frame` through the D435 model, indoors (`None`) or in daylight.
fn measure_depth(
    frame: &Frame,
    intr: &Intrinsics,
    model: &StereoDepthNoise,
    light: Option<&super::depth_light::SunlightStereo>,
    seed: u64,
) -> Vec<u16> {
    let mut snr = vec![0.0f32; intr.pixel_count()];
    if let Some(l) = light {
        l.snr(
            frame.view(),
            &mut snr,
            &mut super::depth_light::SnrScratch::default(),
        );
    }
    let mut mm = vec![0u16; intr.pixel_count()];
    model.apply_in_light(
        intr.width,
        intr.height,
        &frame.depth_m,
        light.map(|l| (l, &snr[..])),
        &mut mm,
        &mut DepthScratch::new(),
        &mut ChaCha8Rng::seed_from_u64(seed),
    );
    mm
}

/// A plain carton plane seen straight on: no texture of its own, so the share of pixels
/// with depth is the closed-form probability of the projector's dots alone against the
/// ambient light (irradiance on the plane from the lighting's formula), at three
/// distances; its depth noise is the datasheet's times the SNR factor.
#[test]
fn a_plain_surface_gets_depth_with_the_closed_form_probability_of_the_projector() {
    let model_light = sunlight_model();
    let spec = CameraSpec::d435_depth(super::camera::D435DepthMode::W848H480, 15.0);
    let intr = spec.intrinsics;
    let st = spec.stereo.expect("the D435 has a depth unit");
    let model = StereoDepthNoise::new(&intr, &st);
    // Dusk: no sun, a dim sky, so the projector decides within a couple of metres.
    let dusk = Lighting {
        sun: 0.0,
        sky: 0.01,
        ..lighting()
    };
    let scene = plane_scene(50.0, 0.0, Material::Carton);
    let caster = crate::render::build_default(&scene.trace);
    let r = Renderer::new(scene, caster, dusk, 0.05, 7);
    // Sky on an upward surface: sky·(0.6 + 0.4·n_z) = 0.01.
    let e_w_m2 = 0.01 * model_light.ambient_w_m2;
    let mut seen = Vec::new();
    for z in [1.0, 1.5, 2.0] {
        let f = render(&r, &intr, &looking_down(z));
        let indoor = measure_depth(&f, &intr, &model, None, 11);
        let day = measure_depth(&f, &intr, &model, Some(&model_light), 11);
        // The pixels the indoor model keeps (it drops only the left invalid band here).
        let kept: Vec<usize> = (0..indoor.len()).filter(|&i| indoor[i] > 0).collect();
        let valid = kept.iter().filter(|&&i| day[i] > 0).count();
        let share = valid as f64 / kept.len() as f64;
        // Closed form: uniform albedo and light, every pixel at the mean level.
        let snr = model_light.snr_of(model_light.contrast(0.0, e_w_m2, z), model_light.ae_level);
        let p = model_light.valid_probability(snr);
        // Binomial 5σ (the draws are independent per pixel), plus range-gate losses
        // at low SNR where the noise is large.
        let sigma = (p * (1.0 - p) / kept.len() as f64).sqrt();
        assert!(
            (share - p).abs() < 5.0 * sigma + 0.01,
            "z {z} m: {share:.4} of pixels with depth, closed form {p:.4} (SNR {snr:.2})"
        );
        seen.push(p);
        if z == 1.0 {
            let rms = (kept
                .iter()
                .filter(|&&i| day[i] > 0)
                .map(|&i| (f64::from(day[i]) * 1e-3 - z).powi(2))
                .sum::<f64>()
                / valid as f64)
                .sqrt();
            let expected = model.rms_m(z) * model_light.noise_factor(snr);
            assert!(
                (rms / expected - 1.0).abs() < 0.1,
                "RMS {rms} m, expected {expected} m"
            );
        }
    }
    // The projector's range: most pixels at 1 m, few at 2 m.
    assert!(seen[0] > 0.8 && seen[2] < 0.3, "{seen:?}");
}

/// The box-occluder scene in the sun: the plain carton box gets (almost) no depth, the
/// textured vines and soil around it keep theirs; indoors the box has depth.
#[test]
fn a_plain_carton_in_sunlight_has_holes_where_the_vines_keep_depth() {
    let world = box_world(Vec::new());
    let r = world_renderer(&world);
    let spec = CameraSpec::d435_depth(super::camera::D435DepthMode::W848H480, 15.0);
    let intr = spec.intrinsics;
    let st = spec.stereo.expect("the D435 has a depth unit");
    let model = StereoDepthNoise::new(&intr, &st);
    let light = sunlight_model();
    let rays = intr.pixel_rays();
    // Two views of the box, 1.5 to 2.5 m away: from the lane (its shaded end face) and
    // from beside the row (its sunlit long face, the sun in the south-south-east).
    let g = world.terrain.height_at(4.0, 1.25);
    let views = [
        look_at(Vector3::new(4.0, 1.25, g + 0.5), Vector3::x()),
        look_at(
            Vector3::new(5.2, -0.2, g + 0.6),
            Vector3::new(0.8, 1.45, 0.0),
        ),
    ];
    let (mut carton, mut carton_day, mut carton_indoor) = (0usize, 0usize, 0usize);
    let (mut carton_sunlit, mut carton_sunlit_day) = (0usize, 0usize);
    let (mut textured, mut textured_day, mut textured_indoor) = (0usize, 0usize, 0usize);
    for (k, pose) in views.iter().enumerate() {
        let f = render(&r, &intr, pose);
        let indoor = measure_depth(&f, &intr, &model, None, 5 + k as u64);
        let day = measure_depth(&f, &intr, &model, Some(&light), 5 + k as u64);
        {
            // The matching SNR over the view's surfaces (docs/PERFORMANCE.md quotes it).
            let mut snr = vec![0.0f32; intr.pixel_count()];
            light.snr(
                f.view(),
                &mut snr,
                &mut super::depth_light::SnrScratch::default(),
            );
            let mut v: Vec<f32> = snr.iter().copied().filter(|&x| x > 0.0).collect();
            v.sort_by(f32::total_cmp);
            let q = |p: f64| v[((v.len() - 1) as f64 * p) as usize];
            eprintln!(
                "view {k}: matching SNR quantiles 5/25/50/75/95 %: {:.0} {:.0} {:.0} {:.0} {:.0}",
                q(0.05),
                q(0.25),
                q(0.5),
                q(0.75),
                q(0.95)
            );
        }
        let o = pose.translation.vector - r.scene().trace.origin_in_world;
        let origin = [o.x as f32, o.y as f32, o.z as f32];
        let rot = pose.rotation;
        // Pixels whose whole 7×7 matching window sees one material (the window
        // straddling an outline sees the outline's contrast, and matches).
        let w = intr.width as usize;
        let mut material = vec![None; intr.pixel_count()];
        for v in 0..intr.height {
            for u in 0..intr.width {
                let d = rays.dir(u, v);
                let dw = rot * Vector3::new(f64::from(d[0]), f64::from(d[1]), f64::from(d[2]));
                let hit =
                    r.caster()
                        .cast_ray(origin, [dw.x as f32, dw.y as f32, dw.z as f32], 0.0, 50.0);
                material[v as usize * w + u as usize] =
                    hit.is_hit().then(|| r.scene().material_of(&hit));
            }
        }
        for v in 3..intr.height as usize - 3 {
            for u in 3..w - 3 {
                let i = v * w + u;
                let Some(m) = material[i] else { continue };
                let uniform = (v - 3..=v + 3)
                    .all(|vv| (u - 3..=u + 3).all(|uu| material[vv * w + uu] == Some(m)));
                if !uniform {
                    continue;
                }
                match m {
                    // Inside one face (the window across the edge between two faces, lit
                    // differently, sees that edge's contrast, as a matcher does).
                    Material::Carton
                        if (v - 3..=v + 3).all(|vv| {
                            (u - 3..=u + 3).all(|uu| f.irradiance[vv * w + uu] == f.irradiance[i])
                        }) =>
                    {
                        carton += 1;
                        carton_day += usize::from(day[i] > 0);
                        carton_indoor += usize::from(indoor[i] > 0);
                        if f.irradiance[i] > 0.5 {
                            carton_sunlit += 1;
                            carton_sunlit_day += usize::from(day[i] > 0);
                        }
                    }
                    Material::Leaf | Material::Soil => {
                        textured += 1;
                        textured_day += usize::from(day[i] > 0);
                        textured_indoor += usize::from(indoor[i] > 0);
                    }
                    _ => {}
                }
            }
        }
    }
    let share = |a: usize, b: usize| a as f64 / b.max(1) as f64;
    eprintln!(
        "carton {carton} px: depth indoors {:.3}, in sun {:.3} (sunlit faces {carton_sunlit} px: {:.3}); \
         vines and soil {textured} px: indoors {:.3}, in sun {:.3}",
        share(carton_indoor, carton),
        share(carton_day, carton),
        share(carton_sunlit_day, carton_sunlit),
        share(textured_indoor, textured),
        share(textured_day, textured)
    );
    assert!(carton > 3000 && carton_sunlit > 1000 && textured > 20_000);
    assert!(
        share(carton_indoor, carton) > 0.9,
        "indoors the box has depth"
    );
    assert!(
        share(carton_day, carton) < 0.1,
        "in the sun the box has holes"
    );
    assert!(
        share(carton_sunlit_day, carton_sunlit) < 0.02,
        "sunlit carton"
    );
    assert!(
        share(textured_day, textured) > 0.9 * share(textured_indoor, textured),
        "vines and soil keep their depth in the sun"
    );
}
