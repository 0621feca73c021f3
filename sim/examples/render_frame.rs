//! Times the stages of rendering one camera view of the default vineyard (the ray-casting
//! figures of both backends come from `vinebench bench --only render`).
//!
//! `cargo run --release -p vinebench-sim --example render_frame [rows] [frames]`
use nalgebra::Vector3;
use std::time::Instant;
use vinebench_sim::params::{RenderParams, WorldParams};
use vinebench_sim::render::camera::{Intrinsics, look_at};
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
    let pose = look_at(Vector3::new(20.0, 3.75, 1.2), Vector3::new(1.0, 0.0, -0.1));
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
}
