//! Poisson-disk subsampling of a point cloud: a subset in which no two points are closer
//! than a radius, and every dropped point lies within the radius of a kept one.
//!
//! Greedy dart throwing over the cloud's own points in input order with a hash grid:
//! deterministic, O(n).

use super::grid::dist2;
use super::voxel::VoxelGrid;
use rustc_hash::FxHashMap;

/// Indices (ascending) of a Poisson-disk subset of `points` (`f64` or `f32`) with
/// minimum distance `radius_m` (> 0). Non-finite points are dropped.
///
/// Points are visited in input order (the mapper's voxels come sorted by key, so
/// neighbours are visited together and the cells stay in cache). Kept points go into a
/// hash grid of cell `2·radius`: the ball of radius `radius` around a point lies in the
/// 2 × 2 × 2 block of cells nearest to it, so 8 look-ups decide each point.
pub fn poisson_disk<T: Copy + Into<f64>>(points: &[[T; 3]], radius_m: f64) -> Vec<u32> {
    let cell_m = 2.0 * radius_m;
    let r2 = radius_m * radius_m;
    let at = |i: u32| points[i as usize].map(Into::into);
    // Cell → the last kept point in it; `next[k]`: the kept point before `k` in its cell
    // (a list per cell without an allocation per cell).
    let mut last: FxHashMap<u64, u32> = FxHashMap::default();
    let mut next: Vec<u32> = Vec::new();
    let mut kept: Vec<u32> = Vec::new();
    'points: for i in 0..points.len() as u32 {
        let p = &at(i);
        // Cell index and, per axis, the neighbour on the side of the point's nearer face.
        let mut c = [0i64; 3];
        let mut side = [0i64; 3];
        for k in 0..3 {
            let f = p[k] / cell_m;
            let fl = f.floor();
            if !(fl > -1_048_575.0 && fl < 1_048_574.0) {
                continue 'points;
            }
            c[k] = fl as i64;
            side[k] = if f - fl < 0.5 { -1 } else { 1 };
        }
        for mask in 0..8u8 {
            let idx = [0, 1, 2].map(|k| c[k] + if mask & (1 << k) != 0 { side[k] } else { 0 });
            let mut k = last
                .get(&VoxelGrid::key_of_index(idx))
                .copied()
                .unwrap_or(u32::MAX);
            while k != u32::MAX {
                if dist2(&at(kept[k as usize]), p) < r2 {
                    continue 'points;
                }
                k = next[k as usize];
            }
        }
        let k = kept.len() as u32;
        next.push(
            last.insert(VoxelGrid::key_of_index(c), k)
                .unwrap_or(u32::MAX),
        );
        kept.push(i);
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kept_points_are_apart_and_cover_the_rest() {
        let pts: Vec<[f64; 3]> = (0..5000)
            .map(|i| {
                let f = f64::from(i);
                [(f * 0.618_034).fract(), (f * 0.414_214).fract(), 0.0]
            })
            .collect();
        let r = 0.05;
        let kept = poisson_disk(&pts, r);
        for (a, &i) in kept.iter().enumerate() {
            for &j in &kept[a + 1..] {
                assert!(dist2(&pts[i as usize], &pts[j as usize]) >= r * r);
            }
        }
        for p in &pts {
            assert!(kept.iter().any(|&k| dist2(&pts[k as usize], p) < r * r));
        }
        assert_eq!(kept, poisson_disk(&pts, r), "deterministic");
    }
}
