//! The mapper (issue #6) against independent expectations: rendered geometry, brute-force
//! references, closed-form areas, topology, and file formats read back by other parsers.

// Test helpers panic on failure by design.
#![allow(clippy::unwrap_used)]

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;
use vinebench_msgs::{
    FrameId, ImageEncoding, ImageMsg, Message, Nanos, PoseSample, StaticTransforms, Trajectory,
};
use vinebench_onboard::mapper::voxel::VoxelGrid;
use vinebench_onboard::mapper::{
    Map, Mapper, MapperParams, MapperStats, PointCloud, RgbdFrame, TriangleMesh, bpa, export, ply,
    poisson,
};
use vinebench_sim::params::{RenderParams, WorldParams};
use vinebench_sim::render::camera::{BrownConrady, Intrinsics, look_at};
use vinebench_sim::render::scene::{Material, RenderScene, ShadingMesh};
use vinebench_sim::render::shade::{Frame, Lighting, Renderer};
use vinebench_sim::render::texture::encode_srgb;
use vinebench_sim::render::{Affine3, Instance, MeshGeometry, TraceScene};
use vinebench_sim::world::World;

const CAM_FRAME: &str = "cam_optical";

/// Colour and aligned-depth messages of a rendered frame (noise-free, depth rounded to
/// millimetres as a RealSense publishes it), with the camera's `CameraInfo`.
fn rgbd_frame(f: &Frame, intr: &Intrinsics, stamp: Nanos) -> RgbdFrame {
    let rgb: Vec<u8> = f.linear.iter().map(|c| encode_srgb(*c)).collect();
    let depth: Vec<u8> = f
        .depth_m
        .iter()
        .flat_map(|d| {
            let mm = if d.is_finite() && *d > 0.0 {
                (f64::from(*d) * 1000.0).round().min(65535.0) as u16
            } else {
                0
            };
            mm.to_le_bytes()
        })
        .collect();
    let image = |topic: &str, encoding, data: Vec<u8>| ImageMsg {
        stamp,
        topic: Arc::from(topic),
        frame_id: FrameId::new(CAM_FRAME),
        width: intr.width,
        height: intr.height,
        encoding,
        data: Arc::from(data),
    };
    RgbdFrame {
        camera: "cam".to_string(),
        color: image("/cam/color/image_raw", ImageEncoding::Rgb8, rgb),
        depth: image(
            "/cam/aligned_depth_to_color/image_raw",
            ImageEncoding::Depth16Mm,
            depth,
        ),
        info: intr.camera_info_msg(
            stamp,
            Arc::from("/cam/color/camera_info"),
            FrameId::new(CAM_FRAME),
            0.0,
        ),
    }
}

fn lighting() -> Lighting {
    Lighting {
        to_sun: Lighting::sun_direction(150.0, 50.0),
        sun: 0.8,
        sky: 0.3,
        exposure: 1.0,
        sun_glare: false,
    }
}

/// A 40 m square of soil in its own xy plane, placed in the world by `world_from_plane`
/// (scene frame = world frame).
fn plane_renderer(world_from_plane: &Isometry3<f64>) -> Renderer {
    let h = 20.0f32;
    let geo = MeshGeometry {
        positions: vec![[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]],
        indices: vec![[0, 1, 2], [0, 2, 3]],
    };
    let m = world_from_plane.to_homogeneous();
    let affine = Affine3 {
        rows: std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)] as f32)),
    };
    let r = world_from_plane.rotation.to_rotation_matrix();
    let scene = RenderScene {
        trace: TraceScene {
            origin_in_world: Vector3::zeros(),
            meshes: vec![geo],
            instances: vec![Instance {
                mesh: 0,
                scene_from_mesh: affine,
            }],
        },
        shading: vec![ShadingMesh {
            normals: vec![[0.0, 0.0, 1.0]; 4],
            uvs: vec![[-h, -h], [h, -h], [h, h], [-h, h]],
            materials: vec![Material::Soil; 2],
            colors: Vec::new(),
        }],
        normal_from_mesh: [std::array::from_fn(|i| {
            std::array::from_fn(|j| r[(i, j)] as f32)
        })]
        .to_vec(),
        instance_tag: vec![u32::MAX],
        tag_ids: vec![],
        caster_bounds: ([-30.0; 3], [30.0; 3]),
        grape: vinebench_sim::params::GrapeColour::Red,
    };
    let caster = vinebench_sim::render::build_default(&scene.trace);
    Renderer::new(scene, caster, lighting(), 0.05, 7)
}

fn render(r: &Renderer, intr: &Intrinsics, world_from_cam: &Isometry3<f64>) -> Frame {
    let rays = intr.pixel_rays();
    let mut f = Frame::new(intr.width, intr.height);
    r.render(
        &rays,
        world_from_cam,
        (1.0 / intr.fx) as f32,
        1000.0,
        &mut f,
    );
    f
}

/// Mapper settings of the single-frame tests: every occupied voxel kept (one frame
/// gives most voxels a single point).
fn params(voxel_m: f64) -> MapperParams {
    MapperParams {
        voxel_m,
        min_points_per_voxel: 1,
        mesh: false,
        ..MapperParams::default()
    }
}

/// A tilted plane rendered by the simulator through a distorted camera on a moving body
/// is back-projected (through `CameraInfo`, `/tf_static` and a trajectory interpolated
/// at the frame's stamp) onto that plane, at the pixels' true intersections.
#[test]
fn a_rendered_plane_back_projects_onto_the_plane_at_its_pose() {
    // The plane: tilted 25° about x and 10° about y, 0.3 m up.
    let world_from_plane = Isometry3::from_parts(
        Translation3::new(1.0, 2.0, 0.3),
        UnitQuaternion::from_euler_angles(25f64.to_radians(), -10f64.to_radians(), 0.4),
    );
    let normal = world_from_plane.rotation * Vector3::z();
    let origin = world_from_plane.translation.vector;
    let r = plane_renderer(&world_from_plane);

    // Body 2.2 m above the plane origin, turned; camera on it looking down and forward.
    let world_from_body = Isometry3::from_parts(
        Translation3::new(0.6, 1.5, 2.5),
        UnitQuaternion::from_euler_angles(0.03, -0.02, 0.7),
    );
    let body_from_cam = look_at(Vector3::new(0.3, -0.1, 0.2), Vector3::new(1.0, 0.2, -1.6));
    let mut tf = StaticTransforms::new("base_link");
    tf.insert(CAM_FRAME, body_from_cam);
    let intr = Intrinsics::from_hfov(
        320,
        240,
        87.0,
        BrownConrady {
            k1: -0.06,
            k2: 0.01,
            p1: 0.0008,
            p2: -0.0005,
            k3: 0.0,
        },
    );
    let world_from_cam = world_from_body * body_from_cam;
    let stamp = Nanos::from_secs(1_000);
    let frame = rgbd_frame(&render(&r, &intr, &world_from_cam), &intr, stamp);

    // The trajectory brackets the stamp (±50 ms, moving 0.2 m between samples along x,
    // turning 0.1 rad); interpolation at the stamp gives the render pose exactly, the
    // nearest sample would be 0.1 m and 0.05 rad off.
    let mut trajectory = Trajectory::new();
    for (dt, sign) in [(-50, -1.0), (50, 1.0)] {
        let pose = Isometry3::from_parts(
            Translation3::from(world_from_body.translation.vector + Vector3::x() * 0.1 * sign),
            world_from_body.rotation * UnitQuaternion::from_euler_angles(0.0, 0.0, 0.05 * sign),
        );
        trajectory.push(PoseSample {
            stamp: stamp + Nanos::from_millis(dt),
            world_from_body: pose,
            covariance: None,
        });
    }
    // A 1 mm voxel keeps every pixel's point on its own; no depth limit.
    let p = MapperParams {
        max_depth_m: 60.0,
        ..params(0.001)
    };
    let mut mapper = Mapper::new(p, tf).unwrap();
    for m in [
        Message::Image(frame.color.clone()),
        Message::Image(frame.depth.clone()),
        Message::CameraInfo(frame.info.clone()),
    ] {
        mapper.push(&m);
    }
    assert_eq!(mapper.pending_frames(), 1);
    let map = mapper.finish(&trajectory).unwrap();
    let valid = frame
        .depth
        .data
        .chunks_exact(2)
        .filter(|b| b != &[0, 0])
        .count();
    assert!(valid > 320 * 240 * 9 / 10, "{valid} valid depth pixels");
    assert_eq!(map.stats.frames_integrated, 1);
    assert_eq!(map.stats.points_integrated, valid as u64);
    assert_eq!(map.cloud.positions.len(), valid, "one point per pixel");

    // Every point on the plane: depth is rounded to 1 mm, so within 1 mm along the ray.
    let dist = |p: &[f32; 3]| (Vector3::new(p[0], p[1], p[2]).cast::<f64>() - origin).dot(&normal);
    let worst = map
        .cloud
        .positions
        .iter()
        .map(|p| dist(p).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1.0e-3, "a point is {worst} m off the plane");

    // At the right place in the plane: the true intersections of a few pixels' rays
    // (from the simulator's own camera model) each have a map point within 1.5 mm.
    let eye = world_from_cam.translation.vector;
    for (u, v) in [
        (0.0, 0.0),
        (319.0, 0.0),
        (160.0, 120.0),
        (20.0, 230.0),
        (300.0, 200.0),
    ] {
        let ray = world_from_cam.rotation * intr.ray(u, v).unwrap();
        let s = (origin - eye).dot(&normal) / ray.dot(&normal);
        let hit = eye + ray * s;
        let nearest = map
            .cloud
            .positions
            .iter()
            .map(|p| (Vector3::new(p[0], p[1], p[2]).cast::<f64>() - hit).norm())
            .fold(f64::INFINITY, f64::min);
        assert!(
            nearest < 1.5e-3,
            "pixel ({u}, {v}): nearest point {nearest} m"
        );
    }

    // Normals: the plane's, facing the camera.
    let toward_camera = if (eye - origin).dot(&normal) > 0.0 {
        normal
    } else {
        -normal
    };
    let aligned = map
        .cloud
        .normals
        .iter()
        .filter(|n| {
            Vector3::new(n[0], n[1], n[2])
                .cast::<f64>()
                .dot(&toward_camera)
                > 0.999
        })
        .count();
    assert!(
        aligned as f64 > 0.99 * valid as f64,
        "{aligned} of {valid} normals"
    );
}

/// A frame the trajectory does not cover is not placed (never the nearest pose), and a
/// frame left behind by an estimate that stopped is dropped after `max_pose_wait_s`.
#[test]
fn frames_outside_the_trajectory_are_counted_not_placed() {
    let intr = Intrinsics::from_hfov(32, 24, 80.0, BrownConrady::NONE);
    let r = plane_renderer(&Isometry3::identity());
    let mut tf = StaticTransforms::new("base_link");
    tf.insert(
        CAM_FRAME,
        look_at(Vector3::zeros(), Vector3::new(1.0, 0.0, -1.0)),
    );
    let pose = Isometry3::translation(0.0, 0.0, 1.5);
    let cam = pose * tf.body_from(CAM_FRAME).unwrap();
    let f = render(&r, &intr, &cam);
    let mut trajectory = Trajectory::new();
    for t in [10, 11] {
        trajectory.push(PoseSample {
            stamp: Nanos::from_secs(t),
            world_from_body: pose,
            covariance: None,
        });
    }
    let mut mapper = Mapper::new(
        MapperParams {
            max_pose_wait_s: 2.0,
            ..params(0.01)
        },
        tf,
    )
    .unwrap();
    // Before the trajectory, inside it, after it (waits), and long after it.
    for ms in [9_500, 10_500, 11_500, 20_000] {
        let fr = rgbd_frame(&f, &intr, Nanos::from_millis(ms));
        for m in [
            Message::Image(fr.color),
            Message::Image(fr.depth),
            Message::CameraInfo(fr.info),
        ] {
            mapper.push(&m);
        }
    }
    assert_eq!(mapper.integrate(&trajectory).unwrap(), 1);
    let s: MapperStats = mapper.stats();
    assert_eq!(s.frames_integrated, 1);
    assert_eq!(
        s.frames_outside_trajectory, 1,
        "the one before the first pose"
    );
    assert_eq!(
        s.frames_unposed, 1,
        "11.5 s waited more than 2 s behind 20 s"
    );
    assert_eq!(mapper.pending_frames(), 1, "20 s still waits for a pose");
    let map = mapper.finish(&trajectory).unwrap();
    assert_eq!(map.stats.frames_integrated, 1);
    assert_eq!(map.stats.frames_outside_trajectory, 2);
}

/// Brute-force voxel downsampling: per voxel `floor(p / v)`, the mean of its points.
fn brute_force(points: &[[f64; 3]], voxel: f64) -> BTreeMap<[i64; 3], ([f64; 3], u32)> {
    let mut groups: BTreeMap<[i64; 3], Vec<[f64; 3]>> = BTreeMap::new();
    for p in points {
        let key = p.map(|c| (c / voxel).floor() as i64);
        groups.entry(key).or_default().push(*p);
    }
    groups
        .into_iter()
        .map(|(k, ps)| {
            let n = ps.len() as f64;
            let c = [0, 1, 2].map(|i| ps.iter().map(|p| p[i]).sum::<f64>() / n);
            (k, (c, ps.len() as u32))
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    /// One point per occupied voxel, at the centroid of the voxel's points, whatever the
    /// batches the points come in.
    #[test]
    fn voxel_downsampling_keeps_one_centroid_per_occupied_voxel(
        seed in any::<u64>(),
        n in 1usize..60_000,
        voxel in 0.005f64..0.5,
        extent in 0.01f64..3.0,
        batches in 1usize..5,
    ) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        // Clustered points (so voxels hold many) plus points exactly on voxel faces.
        let points: Vec<[f64; 3]> = (0..n)
            .map(|i| {
                if i % 7 == 0 {
                    [0, 1, 2].map(|_| f64::from(rng.random_range(-20..20)) * voxel)
                } else {
                    [0, 1, 2].map(|_| rng.random_range(-extent..extent))
                }
            })
            .collect();
        let colors: Vec<[u8; 3]> = (0..n).map(|_| [rng.random(), rng.random(), rng.random()]).collect();
        let mut grid = VoxelGrid::new(voxel);
        let chunk = n.div_ceil(batches);
        for (p, c) in points.chunks(chunk).zip(colors.chunks(chunk)) {
            grid.insert(p, c, [0.0; 3]);
        }
        let reference = brute_force(&points, voxel);
        let voxels = grid.voxels();
        prop_assert_eq!(voxels.len(), reference.len());
        prop_assert_eq!(grid.inserted(), n as u64);
        for v in &voxels {
            let key = VoxelGrid::index_of_key(v.key);
            let (centroid, count) = reference.get(&key).copied().unwrap();
            prop_assert_eq!(v.count, count);
            // Offsets from the corner are summed in f32: each addition rounds by at most
            // ε times a sum below count · voxel.
            let tol = f64::from(count) * f64::from(f32::EPSILON) * voxel + 1e-12 * (1.0 + extent);
            for (got, want) in v.centroid.iter().zip(&centroid) {
                prop_assert!((got - want).abs() <= tol, "{} vs {}, {} points", got, want, count);
            }
            // The centroid lies in its voxel.
            for (i, k) in key.iter().enumerate() {
                let lo = *k as f64 * voxel;
                prop_assert!(v.centroid[i] >= lo - 1e-12 && v.centroid[i] <= lo + voxel + 1e-12);
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]
    /// Pruning drops exactly the voxels with fewer than `min` points whose last point came
    /// before batch `before` (a brute-force replay of the batches), and a pruned voxel hit
    /// again starts from zero; `into_voxels(min)` is `voxels()` without the sparse ones.
    #[test]
    fn pruning_drops_exactly_the_sparse_voxels_not_seen_lately(
        seed in any::<u64>(),
        batches in 2usize..8,
        per_batch in 1usize..3000,
        min in 1u32..4,
        prune_at in 1usize..8,
        before in 0u32..8,
    ) {
        let voxel = 0.1;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let data: Vec<Vec<[f64; 3]>> = (0..batches)
            .map(|_| (0..per_batch).map(|_| [0, 1, 2].map(|_| rng.random_range(0.0..1.0))).collect())
            .collect();
        let prune_at = prune_at.min(batches);
        let before = before.min(prune_at as u32);
        let mut grid = VoxelGrid::new(voxel);
        // Reference: per voxel index, (count, last batch).
        let mut reference: BTreeMap<[i64; 3], (u32, u32)> = BTreeMap::new();
        for (b, pts) in data.iter().enumerate() {
            if b == prune_at {
                let removed = grid.prune(min, before);
                let n = reference.len();
                reference.retain(|_, (c, last)| *c >= min || *last >= before);
                prop_assert_eq!(removed, n - reference.len());
            }
            grid.insert(pts, &vec![[1, 2, 3]; pts.len()], [b as f32, 0.0, 0.0]);
            for p in pts {
                let e = reference.entry(p.map(|c| (c / voxel).floor() as i64)).or_insert((0, 0));
                e.0 += 1;
                e.1 = b as u32;
            }
        }
        let all = grid.voxels();
        prop_assert_eq!(all.len(), reference.len());
        for v in &all {
            let (count, last) = reference[&VoxelGrid::index_of_key(v.key)];
            prop_assert_eq!(v.count, count);
            // The viewpoint is the last batch's.
            prop_assert_eq!(v.viewpoint[0], last as f32);
        }
        let kept: Vec<_> = all.iter().copied().filter(|v| v.count >= min).collect();
        prop_assert_eq!(grid.into_voxels(min), kept);
    }
}

#[test]
fn voxel_downsampling_is_identical_for_any_thread_count() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let points: Vec<[f64; 3]> = (0..200_000)
        .map(|_| [0, 1, 2].map(|_| rng.random_range(0.0..0.5)))
        .collect();
    let colors = vec![[10u8, 200, 30]; points.len()];
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let mut g = VoxelGrid::new(0.01);
                g.insert(&points, &colors, [0.0; 3]);
                g.voxels()
            })
    };
    assert_eq!(run(1), run(3));
}

/// Points sampled uniformly on a sphere, thinned by Poisson-disk sampling as the mapper
/// does, with exact outward normals.
fn sphere_points(radius: f64, spacing: f64, seed: u64) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let dense =
        (40.0 * 4.0 * std::f64::consts::PI * radius * radius / (spacing * spacing)) as usize;
    let raw: Vec<[f64; 3]> = (0..dense)
        .map(|_| {
            loop {
                let v = Vector3::<f64>::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                );
                let n = v.norm();
                if n > 0.1 && n <= 1.0 {
                    break (v / n * radius).into();
                }
            }
        })
        .collect();
    let keep = poisson::poisson_disk(&raw, spacing);
    let points: Vec<[f64; 3]> = keep.iter().map(|&i| raw[i as usize]).collect();
    let normals = points
        .iter()
        .map(|p| (Vector3::from(*p) / radius).into())
        .collect();
    (points, normals)
}

/// Edge → number of triangles using it, and the vertices used.
fn edge_use(tris: &[[u32; 3]]) -> HashMap<(u32, u32), usize> {
    let mut edges = HashMap::new();
    for t in tris {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
        }
    }
    edges
}

/// Ball-Pivoting on points of a sphere gives a closed, oriented 2-manifold of genus 0
/// (every edge in exactly two triangles, once in each direction; V − E + F = 2; each
/// vertex's triangles form one fan) whose area is that of the sphere.
#[test]
fn ball_pivoting_closes_a_sphere() {
    let radius = 0.25;
    let spacing = 0.01;
    let (points, normals) = sphere_points(radius, spacing, 11);
    let (tris, stats) = bpa::ball_pivoting(&points, &normals, &[0.01, 0.02, 0.04]);
    let edges = edge_use(&tris);
    let open: Vec<_> = edges.iter().filter(|(_, n)| **n != 2).collect();
    assert!(
        open.is_empty(),
        "{} of {} edges not shared by exactly two triangles (e.g. {:?}); {stats:?}",
        open.len(),
        edges.len(),
        open.iter().take(5).collect::<Vec<_>>()
    );
    // Oriented: each directed edge once.
    let mut directed = std::collections::HashSet::new();
    for t in &tris {
        for k in 0..3 {
            assert!(
                directed.insert((t[k], t[(k + 1) % 3])),
                "directed edge twice"
            );
        }
    }
    let used: std::collections::BTreeSet<u32> = tris.iter().flatten().copied().collect();
    let euler = used.len() as i64 - edges.len() as i64 + tris.len() as i64;
    assert_eq!(
        euler,
        2,
        "V {} E {} F {}",
        used.len(),
        edges.len(),
        tris.len()
    );
    assert_eq!(used.len(), points.len(), "every sample is a vertex");
    // Vertex manifold: the triangles around each vertex form a single cycle.
    let mut around: HashMap<u32, Vec<(u32, u32)>> = HashMap::new();
    for t in &tris {
        for k in 0..3 {
            around
                .entry(t[k])
                .or_default()
                .push((t[(k + 1) % 3], t[(k + 2) % 3]));
        }
    }
    for (v, fan) in &around {
        let next: HashMap<u32, u32> = fan.iter().copied().collect();
        let (start, mut at, mut steps) = (fan[0].0, fan[0].1, 1);
        while at != start {
            at = next[&at];
            steps += 1;
            assert!(steps <= fan.len(), "vertex {v}: fan does not close");
        }
        assert_eq!(steps, fan.len(), "vertex {v}: more than one fan");
    }
    // Outward: every triangle's normal agrees with the radial direction.
    let mesh = TriangleMesh {
        vertices: points.iter().map(|p| p.map(|c| c as f32)).collect(),
        normals: Vec::new(),
        colors: Vec::new(),
        triangles: tris.clone(),
    };
    for t in &tris {
        let [a, b, c] = t.map(|i| Vector3::from(points[i as usize]));
        assert!(
            (b - a).cross(&(c - a)).dot(&(a + b + c)) > 0.0,
            "inward triangle"
        );
    }
    // Area: an inscribed polyhedron with ~1 cm edges on a 25 cm sphere loses about
    // (edge/radius)²/12 ≈ 0.01 % per flat facet; allow 1 %.
    let sphere = 4.0 * std::f64::consts::PI * radius * radius;
    let area = mesh.area_m2();
    assert!(
        area < sphere && area > 0.99 * sphere,
        "area {area} vs 4πr² = {sphere}"
    );
}

/// The same input gives the same mesh whatever the thread count.
#[test]
fn ball_pivoting_is_deterministic() {
    let (points, normals) = sphere_points(0.1, 0.01, 3);
    let a = bpa::ball_pivoting(&points, &normals, &[0.01, 0.02]);
    let b = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| bpa::ball_pivoting(&points, &normals, &[0.01, 0.02]));
    assert_eq!(a, b);
}

/// Meshing in tiles gives the mesh of one run over the whole cloud: on a wavy sheet
/// 1.2 m × 0.9 m cut into 0.3 m tiles (4 × 3, seams 1.5 m long in all) nearly every
/// triangle is one the single run makes too (measured 99.4 %), the seams add almost no
/// open or doubled edges, and the area is the sheet's (numerical integral). The tiles run in parallel;
/// the result does not depend on the thread count.
#[test]
fn ball_pivoting_in_tiles_matches_one_run_and_closes_its_seams() {
    let height = |x: f64, y: f64| 0.05 * (3.0 * x).sin() * (2.0 * y).cos();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let raw: Vec<[f64; 3]> = (0..120_000)
        .map(|_| {
            let (x, y) = (rng.random_range(0.0..1.2), rng.random_range(0.0..0.9));
            [x, y, height(x, y)]
        })
        .collect();
    let keep = poisson::poisson_disk(&raw, 0.01);
    let points: Vec<[f64; 3]> = keep.iter().map(|&i| raw[i as usize]).collect();
    let normals: Vec<[f64; 3]> = points
        .iter()
        .map(|p| {
            let (dx, dy) = (
                0.15 * (3.0 * p[0]).cos() * (2.0 * p[1]).cos(),
                -0.1 * (3.0 * p[0]).sin() * (2.0 * p[1]).sin(),
            );
            Vector3::new(-dx, -dy, 1.0).normalize().into()
        })
        .collect();
    let narrow =
        |v: &[[f64; 3]]| -> Vec<[f32; 3]> { v.iter().map(|p| p.map(|c| c as f32)).collect() };
    let (p32, n32) = (narrow(&points), narrow(&normals));
    let radii = [0.01, 0.02, 0.04];
    let widen = |v: &[[f32; 3]]| -> Vec<[f64; 3]> { v.iter().map(|p| p.map(f64::from)).collect() };
    let (whole, _) = bpa::ball_pivoting(&widen(&p32), &widen(&n32), &radii);
    let tiled = bpa::ball_pivoting_tiled(&p32, &n32, &radii, 0.3);
    let one_tile = bpa::ball_pivoting_tiled(&p32, &n32, &radii, 2.0);
    assert_eq!(
        one_tile, whole,
        "a cloud inside one tile is meshed in one run"
    );

    let canon = |t: &[u32; 3]| {
        let mut s = *t;
        s.sort_unstable();
        s
    };
    let whole_set: std::collections::HashSet<[u32; 3]> = whole.iter().map(canon).collect();
    let shared = tiled
        .iter()
        .filter(|t| whole_set.contains(&canon(t)))
        .count();
    assert!(
        shared as f64 > 0.985 * tiled.len() as f64
            && (tiled.len() as f64 - whole.len() as f64).abs() < 0.01 * whole.len() as f64,
        "{shared} of {} tiled triangles in the single run's {}",
        tiled.len(),
        whole.len()
    );
    let (e_whole, e_tiled) = (edge_use(&whole), edge_use(&tiled));
    let doubled = e_tiled.values().filter(|n| **n > 2).count();
    let open = |e: &HashMap<(u32, u32), usize>| e.values().filter(|n| **n == 1).count();
    assert!(
        doubled * 1000 < e_tiled.len(),
        "{doubled} of {} edges in more than two triangles",
        e_tiled.len()
    );
    assert!(
        open(&e_tiled) <= open(&e_whole) + e_tiled.len() / 500,
        "open edges: {} tiled, {} in one run (of {})",
        open(&e_tiled),
        open(&e_whole),
        e_tiled.len()
    );
    assert_eq!(bpa::boundary_edges(&tiled), open(&e_tiled));
    // The sheet's area by the midpoint rule on a 1 mm grid.
    let mut sheet = 0.0;
    let h = 0.001;
    for i in 0..1200 {
        for j in 0..900 {
            let (x, y) = ((f64::from(i) + 0.5) * h, (f64::from(j) + 0.5) * h);
            let (dx, dy) = (
                0.15 * (3.0 * x).cos() * (2.0 * y).cos(),
                -0.1 * (3.0 * x).sin() * (2.0 * y).sin(),
            );
            sheet += (1.0 + dx * dx + dy * dy).sqrt() * h * h;
        }
    }
    let mesh = |tris: &[[u32; 3]]| TriangleMesh {
        vertices: p32.clone(),
        normals: Vec::new(),
        colors: Vec::new(),
        triangles: tris.to_vec(),
    };
    let area = mesh(&tiled).area_m2();
    // The mesh stops up to about one sample spacing inside the sheet's border.
    assert!(
        area < sheet && area > 0.97 * sheet,
        "tiled mesh {area} m² vs the sheet's {sheet} m²"
    );
    // (Measured: 0.984 of the sheet tiled, 0.979 in one run, whose seeds in one order
    // leave a few more holes.)
    assert!((area - mesh(&whole).area_m2()).abs() < 0.01 * sheet);
    let serial = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| bpa::ball_pivoting_tiled(&p32, &n32, &radii, 0.3));
    assert_eq!(serial, tiled, "independent of the thread count");
}

fn random_cloud(n: usize, seed: u64) -> PointCloud {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut f3 = |s: f32| [0, 1, 2].map(|_| rng.random_range(-s..s));
    let positions = (0..n).map(|_| f3(50.0)).collect();
    let normals = (0..n).map(|_| f3(1.0)).collect();
    let mut rng = ChaCha8Rng::seed_from_u64(seed + 1);
    PointCloud {
        positions,
        colors: (0..n)
            .map(|_| [rng.random(), rng.random(), rng.random()])
            .collect(),
        normals,
        grvi: (0..n).map(|_| rng.random_range(-1.0..1.0)).collect(),
        elevation: (0..n).map(|_| rng.random_range(-0.5..3.0)).collect(),
    }
}

/// PLY files read back identically; the header is what other tools expect.
#[test]
fn ply_written_is_read_back_identically() {
    let dir = tempfile::tempdir().unwrap();
    let cloud = random_cloud(10_007, 5);
    let path = dir.path().join("cloud.ply");
    ply::write_cloud(&cloud, &path).unwrap();
    assert_eq!(ply::read_cloud(&path).unwrap(), cloud);
    // Header and size: binary little-endian, 35 bytes per vertex after `end_header\n`.
    let bytes = std::fs::read(&path).unwrap();
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let header = std::str::from_utf8(&bytes[..end]).unwrap();
    assert!(header.starts_with("ply\nformat binary_little_endian 1.0\n"));
    assert!(header.contains("element vertex 10007\n"));
    assert_eq!(bytes.len() - end, 10_007 * 35);
    // First vertex's x, read by hand.
    let x = f32::from_le_bytes(bytes[end..end + 4].try_into().unwrap());
    assert_eq!(x, cloud.positions[0][0]);

    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let mesh = TriangleMesh {
        vertices: cloud.positions[..500].to_vec(),
        normals: cloud.normals[..500].to_vec(),
        colors: cloud.colors[..500].to_vec(),
        triangles: (0..900)
            .map(|_| [0, 1, 2].map(|_| rng.random_range(0..500u32)))
            .collect(),
    };
    let path = dir.path().join("mesh.ply");
    ply::write_mesh(&mesh, &path).unwrap();
    assert_eq!(ply::read_mesh(&path).unwrap(), mesh);
}

#[test]
fn a_damaged_ply_is_refused_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cut.ply");
    ply::write_cloud(&random_cloud(100, 1), &path).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() - 10]).unwrap();
    let e = ply::read_cloud(&path).unwrap_err().to_string();
    assert!(e.contains("cut.ply"), "{e}");
}

fn small_world() -> World {
    let mut p = WorldParams::default();
    p.rows.count = 2;
    p.rows.length_m = 12.0;
    p.rows.yaw_deg = 0.0;
    p.terrain.margin_m = 5.0;
    p.headlands.width_m = 3.0;
    p.canopy.leaves_per_plant = 400;
    World::generate(5, &p).unwrap()
}

/// The vegetation mask (GRVI above the threshold) of a mapped vineyard view separates
/// leaf points from soil points, each labelled by the material the simulator's ray
/// caster finds at the point.
#[test]
fn grvi_mask_separates_leaf_and_soil() {
    let world = small_world();
    let r = vinebench_sim::render::build_renderer(&world, &RenderParams::default()).unwrap();
    let intr = Intrinsics::from_hfov(320, 240, 87.0, BrownConrady::NONE);
    // In the lane between the two rows, 1 m up, looking along it and slightly down.
    let world_from_cam = look_at(Vector3::new(1.0, 1.25, 1.0), Vector3::new(1.0, 0.0, -0.25));
    let mut tf = StaticTransforms::new("base_link");
    tf.insert(CAM_FRAME, Isometry3::identity());
    let frame = rgbd_frame(&render(&r, &intr, &world_from_cam), &intr, Nanos(0));
    let mut mapper = Mapper::new(params(0.01), tf).unwrap();
    mapper.add_frame(&frame, &world_from_cam).unwrap();
    let map: Map = mapper.finish(&Trajectory::new()).unwrap();
    let veg = map.vegetation();
    let eye = world_from_cam.translation.vector;
    let o = eye - r.scene().trace.origin_in_world;
    let (mut leaf, mut soil) = ((0usize, 0usize), (0usize, 0usize));
    for (p, is_veg) in map.cloud.positions.iter().zip(&veg) {
        let p = Vector3::new(p[0], p[1], p[2]).cast::<f64>();
        let d = (p - eye).normalize();
        let hit = r.caster().cast_ray(
            [o.x as f32, o.y as f32, o.z as f32],
            [d.x as f32, d.y as f32, d.z as f32],
            0.0,
            1000.0,
        );
        // Only points on the surface the ray meets first (voxel centroids at edges can
        // fall between surfaces).
        if !hit.is_hit() || (f64::from(hit.t) - (p - eye).norm()).abs() > 0.01 {
            continue;
        }
        match r.scene().material_of(&hit) {
            Material::Leaf => {
                leaf.0 += 1;
                leaf.1 += usize::from(*is_veg);
            }
            Material::Soil => {
                soil.0 += 1;
                soil.1 += usize::from(!*is_veg);
            }
            _ => {}
        }
    }
    assert!(
        leaf.0 > 1000 && soil.0 > 1000,
        "{leaf:?} leaf, {soil:?} soil"
    );
    let (leaf_ok, soil_ok) = (leaf.1 as f64 / leaf.0 as f64, soil.1 as f64 / soil.0 as f64);
    assert!(
        leaf_ok > 0.95 && soil_ok > 0.95,
        "vegetation mask right for {leaf_ok} of leaf and {soil_ok} of soil points"
    );
}

/// The exported Gazebo model and MJCF parse as XML, reference the mesh file that was
/// written, and the OBJ holds the mesh.
#[test]
fn exported_gazebo_model_and_mjcf_parse() {
    let dir = tempfile::tempdir().unwrap();
    let (points, normals) = sphere_points(0.1, 0.01, 2);
    let (tris, _) = bpa::ball_pivoting(&points, &normals, &[0.01, 0.02]);
    let mesh = TriangleMesh {
        vertices: points.iter().map(|p| p.map(|c| c as f32)).collect(),
        normals: normals.iter().map(|p| p.map(|c| c as f32)).collect(),
        colors: vec![[90, 140, 60]; points.len()],
        triangles: tris,
    };
    let model = export::write_gazebo_model(&mesh, dir.path(), "vine & row").unwrap();
    export::write_mjcf(dir.path(), "vine & row", "vine & row/meshes/mesh.obj").unwrap();

    let sdf = std::fs::read_to_string(model.join("model.sdf")).unwrap();
    let doc = roxmltree::Document::parse(&sdf).unwrap();
    let root = doc.root_element();
    assert_eq!(root.tag_name().name(), "sdf");
    let m = root.children().find(|n| n.has_tag_name("model")).unwrap();
    assert_eq!(m.attribute("name"), Some("vine & row"));
    let uris: Vec<&str> = m
        .descendants()
        .filter(|n| n.has_tag_name("uri"))
        .filter_map(|n| n.text())
        .collect();
    assert_eq!(uris.len(), 2, "visual and collision");
    for kind in ["visual", "collision"] {
        assert!(m.descendants().any(|n| n.has_tag_name(kind)), "{kind}");
    }
    let rel = uris[0].strip_prefix("model://").unwrap();
    let obj = dir.path().join(rel);
    assert!(obj.is_file(), "{} missing", obj.display());

    let config = std::fs::read_to_string(model.join("model.config")).unwrap();
    let doc = roxmltree::Document::parse(&config).unwrap();
    let sdf_ref = doc
        .descendants()
        .find(|n| n.has_tag_name("sdf"))
        .and_then(|n| n.text())
        .unwrap();
    assert!(model.join(sdf_ref).is_file());

    let mjcf = std::fs::read_to_string(dir.path().join("vine & row.mjcf.xml")).unwrap();
    let doc = roxmltree::Document::parse(&mjcf).unwrap();
    let file = doc
        .descendants()
        .find(|n| n.has_tag_name("mesh"))
        .and_then(|n| n.attribute("file"))
        .unwrap();
    assert!(dir.path().join(file).is_file());

    // The OBJ: one `v` per vertex, one `f` per triangle, 1-based and in range.
    let text = std::fs::read_to_string(&obj).unwrap();
    let v = text.lines().filter(|l| l.starts_with("v ")).count();
    let faces: Vec<&str> = text.lines().filter(|l| l.starts_with("f ")).collect();
    assert_eq!(v, mesh.vertices.len());
    assert_eq!(faces.len(), mesh.triangles.len());
    for f in faces {
        for idx in f.split_whitespace().skip(1) {
            let i: usize = idx.split('/').next().unwrap().parse().unwrap();
            assert!((1..=v).contains(&i));
        }
    }
}

/// Elevation is the height above the local ground: a flat floor with a post on it.
#[test]
fn elevation_is_height_above_the_local_ground() {
    let mut pts = Vec::new();
    for i in 0..200 {
        for j in 0..200 {
            let (x, y) = (f64::from(i) * 0.01, f64::from(j) * 0.01);
            pts.push([x, y, 0.2 + 0.05 * x]); // gently sloped ground
        }
    }
    for k in 0..100 {
        pts.push([1.0, 1.0, 0.25 + f64::from(k) * 0.01]); // post, 0.25-1.24 m
    }
    let e = vinebench_onboard::mapper::elevation(&pts, 0.5, 0.05);
    for (p, e) in pts.iter().zip(&e) {
        let ground = 0.2 + 0.05 * p[0];
        // The ground of a 0.5 m cell is its low quantile lowered to the lowest of its
        // neighbourhood: at most one cell (0.5 m at 5 % slope, 2.5 cm) and the cell's
        // own width (2.5 cm) below the true ground under the point.
        let truth = p[2] - ground;
        let e = f64::from(*e);
        assert!(
            e > truth - 0.002 && e < truth + 0.051,
            "{p:?}: {e} vs {truth}"
        );
    }
}

/// Mapping the same frames twice (once per thread count) gives bit-identical maps, mesh
/// included.
#[test]
fn mapping_is_identical_for_any_thread_count() {
    let world = small_world();
    let r = vinebench_sim::render::build_renderer(&world, &RenderParams::default()).unwrap();
    let intr = Intrinsics::from_hfov(160, 120, 87.0, BrownConrady::NONE);
    let mut tf = StaticTransforms::new("base_link");
    tf.insert(CAM_FRAME, Isometry3::identity());
    let frames: Vec<(RgbdFrame, Isometry3<f64>)> = (0..3)
        .map(|i| {
            let pose = look_at(
                Vector3::new(1.0 + 0.3 * f64::from(i), 1.25, 1.0),
                Vector3::new(0.3, -1.0, -0.3),
            );
            (
                rgbd_frame(&render(&r, &intr, &pose), &intr, Nanos(i64::from(i))),
                pose,
            )
        })
        .collect();
    let build = || {
        let mut m = Mapper::new(MapperParams::default(), tf.clone()).unwrap();
        for (f, pose) in &frames {
            m.add_frame(f, pose).unwrap();
        }
        m.finish(&Trajectory::new()).unwrap()
    };
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(build);
    let two = build();
    assert!(one.mesh.as_ref().is_some_and(|m| !m.triangles.is_empty()));
    assert_eq!(one, two);
}

/// A scenario run with `[mapper]` on writes the maps, the mesh, the Gazebo model and the
/// MJCF, and puts the map scores into `report.json` and `report.md` (the first 3 s of
/// `scenarios/map-row.toml`).
#[test]
fn a_mapping_run_writes_map_mesh_model_and_scores() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/map-row.toml");
    let mut sc = vinebench::scenario::LoadedScenario::load(&path).unwrap();
    sc.scenario.max_duration_s = 3.0;
    sc.expectations.clear();
    let dir = tempfile::tempdir().unwrap();
    let opts = vinebench::runner::RunOptions {
        out_dir: Some(dir.path().join("run")),
        progress: false,
        ..Default::default()
    };
    let out = vinebench::runner::run(&sc, &opts).unwrap();
    let run = &out.dir;
    for f in [
        "map/map.ply",
        "map/map_grvi.ply",
        "map/map_elevation.ply",
        "map/mesh.ply",
        "map/mesh.obj",
        "map/vinebench_map/model.sdf",
        "map/vinebench_map/model.config",
        "map/vinebench_map/meshes/mesh.obj",
        "map/vinebench_map.mjcf.xml",
        "map/gnss/map.ply",
    ] {
        assert!(run.join(f).is_file(), "{f} missing");
    }
    let cloud = ply::read_cloud(&run.join("map/map.ply")).unwrap();
    let mesh = ply::read_mesh(&run.join("map/mesh.ply")).unwrap();
    assert!(
        cloud.positions.len() > 100_000,
        "{} points",
        cloud.positions.len()
    );
    assert!(!mesh.triangles.is_empty());
    roxmltree::Document::parse(
        &std::fs::read_to_string(run.join("map/vinebench_map/model.sdf")).unwrap(),
    )
    .unwrap();
    // Scores in the report, per source, in [0, 1] where fractions.
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("report.json")).unwrap()).unwrap();
    let maps = report["maps"].as_array().unwrap();
    assert_eq!(maps.len(), 2);
    assert_eq!(maps[0]["source"], "eif");
    assert_eq!(maps[1]["source"], "gnss");
    assert_eq!(
        maps[0]["score"]["map_points"].as_u64(),
        Some(cloud.positions.len() as u64)
    );
    for m in maps {
        let f = m["score"]["f_scores"].as_array().unwrap();
        assert_eq!(f.len(), 3);
        for x in f {
            let v = x["f_score"].as_f64().unwrap();
            assert!((0.0..=1.0).contains(&v), "{v}");
        }
        assert!(m["score"]["accuracy_mean_m"].as_f64().unwrap() < 0.05);
    }
    let md = std::fs::read_to_string(run.join("report.md")).unwrap();
    assert!(md.contains("## Maps"));
    // The expectation language reads the scores.
    let scores = vinebench::runner::Scores {
        sources: Vec::new(),
        robot: out.report.robot.clone(),
        slam: Vec::new(),
        maps: out.report.maps.clone(),
        loops: Vec::new(),
    };
    let f = scores.metric("map_f_score_5cm", "eif").unwrap();
    assert_eq!(Some(f), maps[0]["score"]["f_scores"][2]["f_score"].as_f64());
    // Each map is in the recording as a PointCloud2 in `world`, point for point.
    let bytes = std::fs::read(run.join("recording.mcap")).unwrap();
    let mut clouds = std::collections::BTreeMap::new();
    vinebench::recording::reader::scan(&bytes, |ch, m| {
        if ch.topic.starts_with("/map/") {
            let c = vinebench::recording::ros::decode_point_cloud2(m.data).unwrap();
            clouds.insert(ch.topic.clone(), c);
        }
    })
    .unwrap();
    let eif = &clouds["/map/eif/points"];
    assert!(clouds.contains_key("/map/gnss/points"));
    assert_eq!(eif.frame_id.as_str(), "world");
    assert_eq!(eif.width as usize, cloud.positions.len());
    let step = eif.point_step as usize;
    for (i, p) in cloud.positions.iter().enumerate().step_by(9973) {
        let x = f32::from_le_bytes(eif.data[i * step..i * step + 4].try_into().unwrap());
        assert_eq!(x, p[0]);
    }
    // `[world.mesh]`: the mesh just written becomes the world the cameras see (and the
    // maps' truth); the generated ground stays under it by default.
    let mut again = sc.clone();
    again.scenario.world.mesh.file = run.join("map/mesh.ply").display().to_string();
    let built = vinebench::runner::setup(&again).unwrap();
    let scene = built.renderer.as_ref().unwrap().scene();
    assert_eq!(scene.trace.instances.len(), 2, "ground and mesh");
    assert_eq!(scene.trace.meshes[1].indices, mesh.triangles);
    // The OBJ export reads back as the same triangles, corner by corner (positions and
    // colours; the OBJ reader numbers vertices in the order the faces use them), and
    // loads as the world too.
    let obj = vinebench_onboard::mapper::export::read_obj(&run.join("map/mesh.obj")).unwrap();
    assert_eq!(obj.triangles.len(), mesh.triangles.len());
    assert_eq!(mesh.colors.len(), mesh.vertices.len());
    assert_eq!(obj.colors.len(), obj.vertices.len());
    for (a, b) in obj.triangles.iter().zip(&mesh.triangles) {
        for (&i, &j) in a.iter().zip(b) {
            assert_eq!(obj.vertices[i as usize], mesh.vertices[j as usize]);
            assert_eq!(obj.colors[i as usize], mesh.colors[j as usize]);
        }
    }
    again.scenario.world.mesh.file = run.join("map/mesh.obj").display().to_string();
    let built = vinebench::runner::setup(&again).unwrap();
    let scene = built.renderer.as_ref().unwrap().scene();
    assert_eq!(scene.trace.meshes[1].indices, obj.triangles);
    // Another format is refused by name.
    again.scenario.world.mesh.file = "mesh.stl".into();
    let e = vinebench::runner::setup(&again)
        .map(|_| ())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("world.mesh.file") && e.contains(".ply or .obj"),
        "{e}"
    );
    // A missing file fails, naming the field and the path, also when no camera would
    // draw it.
    again.scenario.world.mesh.file = "no-such-mesh.ply".into();
    let mut no_cameras = again.clone();
    no_cameras.scenario.sensors.cameras.clear();
    for sc in [&again, &no_cameras] {
        let e = vinebench::runner::setup(sc)
            .map(|_| ())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("world.mesh.file") && e.contains("no-such-mesh.ply"),
            "{e}"
        );
    }
}
