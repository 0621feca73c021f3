//! A uniform hash grid over a fixed point set for fixed-radius neighbour queries (the
//! inner loop of Poisson-disk sampling and Ball-Pivoting, where a k-d tree's generality
//! costs more than it gives).

use super::voxel::VoxelGrid;
use rayon::prelude::*;
use rustc_hash::FxHashMap;

/// Points bucketed by cell: `sorted` holds point indices ordered by cell key, `cells`
/// maps a key to its range in `sorted`.
#[derive(Clone, Debug)]
pub struct PointGrid {
    cell_m: f64,
    inv_cell: f64,
    cells: FxHashMap<u64, (u32, u32)>,
    sorted: Vec<u32>,
}

impl PointGrid {
    /// Buckets `points` into cubes of edge `cell_m`. Non-finite points are left out.
    pub fn new(points: &[[f64; 3]], cell_m: f64) -> PointGrid {
        let inv_cell = 1.0 / cell_m;
        let mut keyed: Vec<(u64, u32)> = points
            .par_iter()
            .enumerate()
            .filter_map(|(i, p)| Some((cell_key(p, inv_cell)?, i as u32)))
            .collect();
        keyed.par_sort_unstable();
        let mut cells = FxHashMap::default();
        cells.reserve(keyed.len() / 4 + 1);
        let mut start = 0usize;
        while start < keyed.len() {
            let key = keyed[start].0;
            let mut end = start + 1;
            while end < keyed.len() && keyed[end].0 == key {
                end += 1;
            }
            cells.insert(key, (start as u32, end as u32));
            start = end;
        }
        PointGrid {
            cell_m,
            inv_cell,
            cells,
            sorted: keyed.into_iter().map(|(_, i)| i).collect(),
        }
    }

    /// Cell edge, m.
    pub fn cell_m(&self) -> f64 {
        self.cell_m
    }

    /// Calls `f(index)` for every point in the 27 cells around `q` (a superset of the
    /// points within `cell_m` of `q`).
    #[inline]
    pub fn for_each_near(&self, q: &[f64; 3], mut f: impl FnMut(u32)) {
        self.any_near(q, |i| {
            f(i);
            false
        });
    }

    /// Whether `pred(index)` holds for any point in the 27 cells around `q` (stops at
    /// the first that does).
    #[inline]
    pub fn any_near(&self, q: &[f64; 3], mut pred: impl FnMut(u32) -> bool) -> bool {
        let Some(c) = index(q, self.inv_cell) else {
            return false;
        };
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let key = VoxelGrid::key_of_index([c[0] + dx, c[1] + dy, c[2] + dz]);
                    if let Some(&(a, b)) = self.cells.get(&key)
                        && self.sorted[a as usize..b as usize].iter().any(|&i| pred(i))
                    {
                        return true;
                    }
                }
            }
        }
        false
    }

    /// Indices of the points within `radius` (≤ `cell_m`) of `q`, appended to `out`.
    pub fn within(&self, points: &[[f64; 3]], q: &[f64; 3], radius: f64, out: &mut Vec<u32>) {
        let r2 = radius * radius;
        self.for_each_near(q, |i| {
            if dist2(&points[i as usize], q) <= r2 {
                out.push(i);
            }
        });
    }
}

#[inline]
fn index(p: &[f64; 3], inv_cell: f64) -> Option<[i64; 3]> {
    let mut idx = [0i64; 3];
    for (o, c) in idx.iter_mut().zip(p) {
        let f = (c * inv_cell).floor();
        // One cell of margin inside the key range so neighbours stay representable.
        if !(f > -1_048_575.0 && f < 1_048_574.0) {
            return None;
        }
        *o = f as i64;
    }
    Some(idx)
}

#[inline]
fn cell_key(p: &[f64; 3], inv_cell: f64) -> Option<u64> {
    index(p, inv_cell).map(VoxelGrid::key_of_index)
}

/// Squared distance.
#[inline]
pub fn dist2(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
}
