//! Times the stages of rendering one camera view of the default vineyard.
//!
//! `cargo run --release -p vinebench-sim --example render_frame [rows] [frames]`
use nalgebra::{Isometry3, Rotation3, UnitQuaternion, Vector3};
use std::time::Instant;
use vinebench_sim::params::{RenderParams, WorldParams};
use vinebench_sim::render::camera::Intrinsics;
use vinebench_sim::render::shade::Frame;
use vinebench_sim::render::{build_renderer, scene};
use vinebench_sim::world::World;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let rows: u32 = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(6);
    let frames: usize = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(5);
    let mut p = WorldParams::default();
    p.rows.count = rows;
    p.rows.yaw_deg = 0.0;
    let world = World::generate(1, &p).expect("world");
    let t = Instant::now();
    let s = scene::build(
        &world,
        &scene::GeometryOptions {
            terrain_cell_m: 0.25,
        },
    );
    println!(
        "scene: {:.2} s, {} stored / {} instanced triangles, {} instances, {:.1} MB",
        t.elapsed().as_secs_f64(),
        s.stored_triangles(),
        s.instanced_triangles(),
        s.trace.instances.len(),
        s.memory_bytes() as f64 / 1e6
    );
    let t = Instant::now();
    let r = build_renderer(&world, &RenderParams::default()).expect("renderer");
    println!(
        "renderer (scene + bvh + textures + shadow map): {:.2} s, {:.1} MB",
        t.elapsed().as_secs_f64(),
        r.memory_bytes() as f64 / 1e6
    );
    let intr = Intrinsics::from_hfov(640, 480, 87.0, Default::default());
    let rays = intr.pixel_rays();
    let eye = Vector3::new(20.0, 3.75, 1.2);
    let z = Vector3::new(1.0, 0.0, -0.1).normalize();
    let x = z.cross(&Vector3::z()).normalize();
    let y = z.cross(&x);
    let pose = Isometry3::from_parts(
        eye.into(),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_basis_unchecked(&[x, y, z])),
    );
    let mut f = Frame::new(640, 480);
    let t = Instant::now();
    for _ in 0..frames {
        r.render(&rays, &pose, (1.0 / intr.fx) as f32, 200.0, &mut f);
    }
    let dt = t.elapsed().as_secs_f64() / frames as f64;
    println!(
        "render 640x480: {:.1} ms/frame, {:.1} Mrays/s (shaded)",
        dt * 1e3,
        640.0 * 480.0 / dt / 1e6
    );
    use vinebench_sim::render::trace::{Hit, PACKET_SIZE, RayPacket};
    let o = eye - r.scene().trace.origin_in_world;
    let rm = pose.rotation.to_rotation_matrix();
    let t = Instant::now();
    let mut hits_total = 0usize;
    for _ in 0..frames {
        for ty in 0..60u32 {
            for tx in 0..80u32 {
                let mut cam = [[0.0f32; PACKET_SIZE]; 3];
                let n = rays.fill_tile(tx * 8, ty * 8, 8, 8, &mut cam);
                let mut p = RayPacket {
                    origin: [o.x as f32, o.y as f32, o.z as f32],
                    dir: [[0.0; PACKET_SIZE]; 3],
                    len: n,
                    t_min: 0.0,
                    t_max: 200.0,
                };
                for l in 0..n {
                    let d = rm * Vector3::new(cam[0][l], cam[1][l], cam[2][l]).cast::<f64>();
                    p.dir[0][l] = d.x as f32;
                    p.dir[1][l] = d.y as f32;
                    p.dir[2][l] = d.z as f32;
                }
                let mut hits = [Hit::MISS; PACKET_SIZE];
                r.caster().cast_packet(&p, &mut hits);
                hits_total += hits[..n].iter().filter(|h| h.is_hit()).count();
            }
        }
    }
    let dt = t.elapsed().as_secs_f64() / frames as f64;
    println!(
        "cast only, 1 thread: {:.1} ms/frame, {:.1} Mrays/s, {:.0} % hit",
        dt * 1e3,
        640.0 * 480.0 / dt / 1e6,
        100.0 * hits_total as f64 / (frames as f64 * 640.0 * 480.0)
    );
}

/// Casts the same view without shading, to split tracing from shading.
#[allow(dead_code)]
fn cast_only() {}
