//! `vinebench bench --only mapper`: mapper speed and memory figures (issue #6).
//!
//! - Voxel downsampling: 10 M points uniform in a 1 m cube (deterministic xorshift) at
//!   1 cm through [`VoxelGrid`] (insert, then the sorted centroids, as Open3D's
//!   `voxel_down_sample` returns a cloud); compared with Open3D 0.20 measured on this
//!   machine (3.6-4.1 s): target at least 5× faster.
//! - Ball-Pivoting: 200 k points (a 1 cm jittered grid on a wavy 4.5 m × 4.5 m surface,
//!   analytic normals) with radii 1, 2 and 4 cm; Open3D 0.20 took 3.2-3.7 s (one thread).
//! - Memory: the start of the default 120 m row loop ([`MEMORY_RUN_S`]) with the three
//!   D435 cameras of `scenarios/map-row.toml` (at a reduced rate and resolution so the
//!   bench ends in minutes; the map's size depends on the area seen, not on the frame
//!   count) mapped with the EIF estimate, mesh included: peak resident memory of the
//!   process over the run (`VmHWM`, reset through `/proc/self/clear_refs` before it),
//!   with and without mapping, and the map's size.

use crate::bench::{BenchError, Figure};
use crate::runner::{setup, simulate_setup};
use crate::scenario::LoadedScenario;
use std::hint::black_box;
use std::path::Path;
use std::time::Instant;
use vinebench_onboard::mapper::bpa;
use vinebench_onboard::mapper::voxel::VoxelGrid;

/// Open3D 0.20 `voxel_down_sample` of 10 M uniform points at 1 cm on this machine, s
/// (fastest of the measured 3.6-4.1 s).
pub const OPEN3D_VOXEL_S: f64 = 3.6;
/// Open3D 0.20 Ball-Pivoting of 200 k points, radii 1/2/4 cm, one thread, s (fastest of
/// the measured 3.2-3.7 s).
pub const OPEN3D_BPA_S: f64 = 3.2;
/// Target speed-up of voxel downsampling over Open3D.
pub const VOXEL_SPEEDUP_TARGET: f64 = 5.0;
/// Target of the issue for mapping a 120 m row loop, peak resident memory, MB.
pub const MEMORY_LIMIT_MB: f64 = 2000.0;
/// Simulated seconds of the row loop in the memory figure (the whole loop is 270 s).
pub const MEMORY_RUN_S: f64 = 60.0;

/// `n` points uniform in the unit cube and their colours (xorshift, no RNG crate).
pub fn uniform_cube(n: usize) -> (Vec<[f64; 3]>, Vec<[u8; 3]>) {
    let mut s: u64 = 0x2545_F491_4F6C_DD1D;
    let mut next = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    };
    let points: Vec<[f64; 3]> = (0..n).map(|_| [next(), next(), next()]).collect();
    let colors = points
        .iter()
        .map(|p| {
            [
                (p[0] * 255.0) as u8,
                (p[1] * 255.0) as u8,
                (p[2] * 255.0) as u8,
            ]
        })
        .collect();
    (points, colors)
}

/// Seconds to voxel-downsample `points` at `voxel_m` (insert and sorted output), best of
/// `repeats`; also the number of voxels.
pub fn voxel_seconds(
    points: &[[f64; 3]],
    colors: &[[u8; 3]],
    voxel_m: f64,
    repeats: usize,
) -> (f64, usize) {
    let mut best = f64::INFINITY;
    let mut voxels = 0;
    for _ in 0..repeats.max(1) {
        let t0 = Instant::now();
        let mut grid = VoxelGrid::new(voxel_m);
        grid.insert(points, colors, [0.0; 3]);
        let out = grid.voxels();
        best = best.min(t0.elapsed().as_secs_f64());
        voxels = out.len();
        black_box(out);
    }
    (best, voxels)
}

/// About `n` points on the wavy surface `z = 0.1·sin(2x)·cos(3y)`: a 1 cm grid jittered
/// by up to ±3 mm, with unit normals (up).
pub fn wavy_surface(n: usize) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let side = (n as f64).sqrt().ceil() as usize;
    let mut s: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut jitter = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        ((s >> 11) as f64 * (1.0 / (1u64 << 53) as f64) - 0.5) * 0.006
    };
    let mut points = Vec::with_capacity(side * side);
    let mut normals = Vec::with_capacity(side * side);
    for i in 0..side {
        for j in 0..side {
            let x = i as f64 * 0.01 + jitter();
            let y = j as f64 * 0.01 + jitter();
            let z = 0.1 * (2.0 * x).sin() * (3.0 * y).cos();
            let (dzdx, dzdy) = (
                0.2 * (2.0 * x).cos() * (3.0 * y).cos(),
                -0.3 * (2.0 * x).sin() * (3.0 * y).sin(),
            );
            let nrm = nalgebra::Vector3::new(-dzdx, -dzdy, 1.0).normalize();
            points.push([x, y, z]);
            normals.push([nrm.x, nrm.y, nrm.z]);
        }
    }
    (points, normals)
}

/// Seconds of Ball-Pivoting on `points` with `radii`, best of `repeats`; also the
/// triangle count.
pub fn bpa_seconds(
    points: &[[f64; 3]],
    normals: &[[f64; 3]],
    radii: &[f64],
    repeats: usize,
) -> (f64, usize) {
    let mut best = f64::INFINITY;
    let mut triangles = 0;
    for _ in 0..repeats.max(1) {
        let t0 = Instant::now();
        let (tris, _) = bpa::ball_pivoting(points, normals, radii);
        best = best.min(t0.elapsed().as_secs_f64());
        triangles = tris.len();
        black_box(tris);
    }
    (best, triangles)
}

/// Best wall time of the map normals (k = 10) of `points` searched through the grid
/// (cells of 2 cm) and through kiddo's k-d tree alone (what the grid replaced), over
/// `repeats`, alternating; an error if the two ever differ.
pub fn normals_seconds(points: &[[f64; 3]], repeats: usize) -> Result<(f64, f64), BenchError> {
    use vinebench_onboard::mapper::normals::estimate_normals;
    let pts: Vec<[f32; 3]> = points.iter().map(|p| p.map(|c| c as f32)).collect();
    let vps: Vec<[f32; 3]> = pts.iter().map(|p| [p[0], p[1], p[2] + 1.5]).collect();
    let (mut grid, mut tree) = (f64::INFINITY, f64::INFINITY);
    for _ in 0..repeats.max(1) {
        let t0 = Instant::now();
        let a = estimate_normals(&pts, &vps, 10, 0.02);
        grid = grid.min(t0.elapsed().as_secs_f64());
        let t0 = Instant::now();
        // A cell edge that is not a length: the k-d tree for every point.
        let b = estimate_normals(&pts, &vps, 10, f64::NAN);
        tree = tree.min(t0.elapsed().as_secs_f64());
        if a != b {
            return Err(BenchError::Setup(
                "the grid's normals differ from the k-d tree's".into(),
            ));
        }
    }
    Ok((grid, tree))
}

/// A `/proc/self/status` value in kB (`VmRSS`, `VmHWM`), Linux only.
pub fn proc_status_kb(key: &str) -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    s.lines()
        .find_map(|l| l.strip_prefix(key)?.strip_prefix(':'))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
}

/// Resets the peak resident size (`VmHWM`) to the current one (Linux ≥ 4.0).
pub fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// What the memory figure measured.
#[derive(Clone, Debug)]
pub struct MappingMemory {
    /// Peak resident memory over the run (simulation, rendering, estimators, mapping), MB.
    pub peak_mb: f64,
    /// Resident memory before the run, MB.
    pub before_mb: f64,
    /// Peak over the same run without mapping, MB.
    pub peak_without_mb: f64,
    /// Map points (occupied 1 cm voxels) of the main map.
    pub voxels: u64,
    /// Frames integrated.
    pub frames: u64,
    /// Simulated seconds.
    pub simulated_s: f64,
    /// Wall seconds of the mapping stage.
    pub mapping_s: f64,
}

/// The memory scenario: the default row loop with the three cameras of
/// `scenarios/map-row.toml` at `rate_hz` and `width`×`height`, mapped with the EIF
/// (`mapping`), stopped after `max_duration_s` (0 = the whole loop).
pub fn memory_scenario(
    rate_hz: f64,
    width: u32,
    height: u32,
    max_duration_s: f64,
    mapping: bool,
) -> Result<LoadedScenario, BenchError> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    let mut sc = LoadedScenario::load(&root.join("defaults.toml"))?;
    let cams = LoadedScenario::load(&root.join("map-row.toml"))?
        .scenario
        .sensors
        .cameras;
    sc.scenario.sensors.cameras = cams
        .into_iter()
        .map(|mut c| {
            c.rate_hz = Some(rate_hz);
            c.width = Some(width);
            c.height = Some(height);
            c
        })
        .collect();
    sc.scenario.max_duration_s = max_duration_s;
    sc.scenario.mapper.enabled = mapping;
    sc.scenario.mapper.sources = vec![vinebench_onboard::estimator::EstimatorKind::Eif];
    Ok(sc)
}

/// Runs the memory scenario once with and once without mapping (see the module docs).
pub fn mapping_memory(
    rate_hz: f64,
    width: u32,
    height: u32,
    max_duration_s: f64,
) -> Result<MappingMemory, BenchError> {
    let mb = |kb: Option<u64>| kb.map_or(f64::NAN, |k| k as f64 / 1024.0);
    let peak = |mapping: bool| -> Result<(f64, f64, Option<_>, f64), BenchError> {
        let sc = memory_scenario(rate_hz, width, height, max_duration_s, mapping)?;
        let built = setup(&sc)?;
        let before = mb(proc_status_kb("VmRSS"));
        if !reset_peak_rss() {
            return Err(BenchError::Setup(
                "cannot reset the peak resident size (/proc/self/clear_refs)".into(),
            ));
        }
        let sim = simulate_setup(&sc, built, None)?;
        let peak = mb(proc_status_kb("VmHWM"));
        let duration = sim.duration_s;
        Ok((peak, before, sim.mapping, duration))
    };
    let (peak_without_mb, _, _, _) = peak(false)?;
    let (peak_mb, before_mb, mapping, simulated_s) = peak(true)?;
    let mapping = mapping.ok_or_else(|| BenchError::Setup("the map is missing".into()))?;
    let main = mapping
        .maps
        .first()
        .ok_or_else(|| BenchError::Setup("the map is missing".into()))?;
    Ok(MappingMemory {
        peak_mb,
        before_mb,
        peak_without_mb,
        voxels: main.map.stats.voxels,
        frames: main.map.stats.frames_integrated,
        simulated_s,
        mapping_s: mapping.wall_s,
    })
}

/// The mapper figures.
pub fn mapper_figures(quick: bool) -> Result<Vec<Figure>, BenchError> {
    let repeats = if quick { 1 } else { 3 };
    let (points, colors) = uniform_cube(10_000_000);
    let (voxel_s, voxels) = voxel_seconds(&points, &colors, 0.01, repeats);
    drop((points, colors));
    let (points, normals) = wavy_surface(200_000);
    let (bpa_s, triangles) = bpa_seconds(&points, &normals, &[0.01, 0.02, 0.04], repeats);
    let (big, _) = wavy_surface(if quick { 250_000 } else { 1_000_000 });
    let (normals_grid_s, normals_tree_s) = normals_seconds(&big, repeats)?;
    drop(big);
    let single = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .map_err(|e| BenchError::Setup(e.to_string()))?
        .install(|| bpa_seconds(&points, &normals, &[0.01, 0.02, 0.04], 1).0);
    // Not the whole loop (about 15 minutes with its mapping on this machine; its figures
    // are in docs/PERFORMANCE.md); the first 20 s (quick) or 60 s show the growth.
    let seconds = if quick { 20.0 } else { MEMORY_RUN_S };
    let mem = mapping_memory(3.0, 424, 240, seconds)?;
    Ok(vec![
        Figure {
            name: "voxel downsampling, 10 M uniform points in 1 m³ at 1 cm, s",
            value: voxel_s,
            unit: "s",
            target: None,
        },
        Figure {
            name: "voxel downsampling speed-up over Open3D 0.20 (3.6 s)",
            value: OPEN3D_VOXEL_S / voxel_s,
            unit: "×",
            target: Some(VOXEL_SPEEDUP_TARGET),
        },
        Figure {
            name: "voxel downsampling, occupied voxels (1 M expected)",
            value: voxels as f64,
            unit: "voxels",
            target: None,
        },
        Figure {
            name: "normals (k = 10) of a 1 cm wavy surface, 1 M points (250 k quick): grid search, s",
            value: normals_grid_s,
            unit: "s",
            target: None,
        },
        Figure {
            name: "same, kiddo k-d tree for every point (the search before #35), s",
            value: normals_tree_s,
            unit: "s",
            target: None,
        },
        Figure {
            name: "normals: grid speed-up over the k-d tree (same normals, bit for bit)",
            value: normals_tree_s / normals_grid_s,
            unit: "×",
            target: None,
        },
        Figure {
            name: "Ball-Pivoting, 200 k points, radii 1/2/4 cm, s",
            value: bpa_s,
            unit: "s",
            target: None,
        },
        Figure {
            name: "Ball-Pivoting speed-up over Open3D 0.20 (3.2 s, one thread)",
            value: OPEN3D_BPA_S / bpa_s,
            unit: "×",
            target: Some(1.0),
        },
        Figure {
            name: "Ball-Pivoting, same, one thread, s",
            value: single,
            unit: "s",
            target: None,
        },
        Figure {
            name: "Ball-Pivoting, triangles",
            value: triangles as f64,
            unit: "triangles",
            target: None,
        },
        Figure {
            name: "row loop (first 20 s quick, 60 s full), 3 cameras (424×240, 3 Hz) + EIF map and mesh: peak RSS, MB",
            value: mem.peak_mb,
            unit: "MB",
            target: None,
        },
        Figure {
            name: "same run without mapping: peak RSS, MB",
            value: mem.peak_without_mb,
            unit: "MB",
            target: None,
        },
        Figure {
            name: "row loop map: occupied 1 cm voxels",
            value: mem.voxels as f64,
            unit: "voxels",
            target: None,
        },
        Figure {
            name: "row loop map: frames integrated",
            value: mem.frames as f64,
            unit: "frames",
            target: None,
        },
        Figure {
            name: "row loop: simulated s",
            value: mem.simulated_s,
            unit: "s",
            target: None,
        },
        Figure {
            name: "row loop: mapping stage wall s (integration + finish)",
            value: mem.mapping_s,
            unit: "s",
            target: None,
        },
        Figure {
            name: "resident before the run, MB",
            value: mem.before_mb,
            unit: "MB",
            target: None,
        },
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `cargo test --release --lib bench::mapper::tests::cpu_figures -- --ignored
    /// --nocapture`: the voxel and Ball-Pivoting figures alone.
    #[test]
    #[ignore]
    fn cpu_figures() {
        let (points, colors) = uniform_cube(10_000_000);
        let (s, n) = voxel_seconds(&points, &colors, 0.01, 3);
        eprintln!("voxel: {s:.3} s, {n} voxels");
        drop((points, colors));
        let (points, normals) = wavy_surface(200_000);
        let (s, n) = bpa_seconds(&points, &normals, &[0.01, 0.02, 0.04], 2);
        eprintln!("bpa: {s:.3} s, {n} triangles");
    }

    #[test]
    fn proc_status_reads_resident_memory() {
        if cfg!(target_os = "linux") {
            assert!(proc_status_kb("VmRSS").is_some_and(|k| k > 0));
            assert!(proc_status_kb("VmHWM").is_some_and(|k| k > 0));
        }
    }

    #[test]
    fn the_synthetic_inputs_are_what_the_figures_say() {
        let (p, c) = uniform_cube(1000);
        assert_eq!((p.len(), c.len()), (1000, 1000));
        assert!(p.iter().flatten().all(|x| (0.0..1.0).contains(x)));
        let (p, n) = wavy_surface(200_000);
        assert!(p.len() >= 200_000 && p.len() < 201_000);
        assert!(
            n.iter()
                .all(|v| ((v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() - 1.0).abs() < 1e-12)
        );
    }
}
