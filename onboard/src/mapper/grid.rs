//! A uniform hash grid over a fixed point set for fixed-radius neighbour queries (the
//! inner loop of Poisson-disk sampling and Ball-Pivoting, where a k-d tree's generality
//! costs more than it gives).

use super::voxel::{AXIS_BITS, VoxelGrid};
use rayon::prelude::*;
use rustc_hash::FxHashMap;

/// Points bucketed by cell and stored in cell order: the cells of one xy column are
/// adjacent, ascending in z, so the three cells of a column that a query needs are one
/// contiguous run of points, found with one look-up of the column and a search of its
/// few cells (9 look-ups for the 27 cells around a point, and no jump from an index to
/// its point).
#[derive(Clone, Debug)]
pub struct PointGrid {
    cell_m: f64,
    inv_cell: f64,
    /// Column key (the cell key without its z bits) → its cells' range in `cell_z`.
    columns: FxHashMap<u64, (u32, u32)>,
    /// Each occupied cell's z index, column by column, ascending in z.
    cell_z: Vec<i32>,
    /// Where each cell's points start in `sorted` and `pos`, and one more entry: the end.
    cell_start: Vec<u32>,
    /// Point indices in cell order.
    sorted: Vec<u32>,
    /// Their positions.
    pos: Vec<[f64; 3]>,
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
        let mut columns = FxHashMap::default();
        columns.reserve(keyed.len() / 16 + 1);
        let (mut cell_z, mut cell_start) = (Vec::new(), Vec::new());
        let z_mask = (1u64 << AXIS_BITS) - 1;
        let mut column: Option<(u64, u32)> = None;
        let mut start = 0usize;
        while start < keyed.len() {
            let key = keyed[start].0;
            let mut end = start + 1;
            while end < keyed.len() && keyed[end].0 == key {
                end += 1;
            }
            let col = key >> AXIS_BITS;
            match column {
                Some((c, _)) if c == col => {}
                _ => {
                    if let Some((c, first)) = column {
                        columns.insert(c, (first, cell_z.len() as u32));
                    }
                    column = Some((col, cell_z.len() as u32));
                }
            }
            cell_z.push(VoxelGrid::index_of_key(key & z_mask)[2] as i32);
            cell_start.push(start as u32);
            start = end;
        }
        if let Some((c, first)) = column {
            columns.insert(c, (first, cell_z.len() as u32));
        }
        cell_start.push(keyed.len() as u32);
        PointGrid {
            cell_m,
            inv_cell,
            columns,
            cell_z,
            cell_start,
            pos: keyed.iter().map(|&(_, i)| points[i as usize]).collect(),
            sorted: keyed.into_iter().map(|(_, i)| i).collect(),
        }
    }

    /// Cell edge, m.
    pub fn cell_m(&self) -> f64 {
        self.cell_m
    }

    /// Calls `f(index, position)` for every point in the 27 cells around `q` (a superset
    /// of the points within `cell_m` of `q`).
    #[inline]
    pub fn for_each_near(&self, q: &[f64; 3], mut f: impl FnMut(u32, &[f64; 3])) {
        self.any_near(q, |i, p| {
            f(i, p);
            false
        });
    }

    /// Whether `pred(index, position)` holds for any point in the 27 cells around `q`
    /// (stops at the first that does).
    #[inline]
    pub fn any_near(&self, q: &[f64; 3], mut pred: impl FnMut(u32, &[f64; 3]) -> bool) -> bool {
        let Some(c) = index(q, self.inv_cell) else {
            return false;
        };
        let z = c[2] as i32;
        for dx in -1..=1 {
            for dy in -1..=1 {
                let col = VoxelGrid::key_of_index([c[0] + dx, c[1] + dy, 0]) >> AXIS_BITS;
                let Some(&(a, b)) = self.columns.get(&col) else {
                    continue;
                };
                let zs = &self.cell_z[a as usize..b as usize];
                let lo = a as usize + zs.partition_point(|&cz| cz < z - 1);
                let hi = a as usize + zs.partition_point(|&cz| cz <= z + 1);
                if lo == hi {
                    continue;
                }
                let run = self.cell_start[lo] as usize..self.cell_start[hi] as usize;
                if self.sorted[run.clone()]
                    .iter()
                    .zip(&self.pos[run])
                    .any(|(&i, p)| pred(i, p))
                {
                    return true;
                }
            }
        }
        false
    }

    /// The points within `radius` (≤ `cell_m`) of `q`, appended to `out` as (index,
    /// position).
    pub fn within(&self, q: &[f64; 3], radius: f64, out: &mut Vec<(u32, [f64; 3])>) {
        let r2 = radius * radius;
        self.for_each_near(q, |i, p| {
            if dist2(p, q) <= r2 {
                out.push((i, *p));
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn within_finds_exactly_the_points_a_scan_finds() {
        // A second method: every point tested. Clustered points (many per cell, tall
        // columns), points on cell faces, negative coordinates, a NaN left out.
        let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut next = || crate::mapper::test_rng::next_unit(&mut state);
        let mut pts: Vec<[f64; 3]> = (0..20_000)
            .map(|_| [next() * 0.3 - 0.1, next() * 0.2 - 0.15, next() * 1.5 - 0.5])
            .collect();
        pts.extend((0..200).map(|i| [0.02 * f64::from(i % 10), -0.04, 0.02 * f64::from(i / 10)]));
        pts.push([f64::NAN, 0.0, 0.0]);
        let cell = 0.02;
        let grid = PointGrid::new(&pts, cell);
        for q in pts
            .iter()
            .take(3000)
            .chain(&[[0.04, -0.04, 0.1], [5.0, 5.0, 5.0]])
        {
            for radius in [cell, 0.7 * cell] {
                let mut got = Vec::new();
                grid.within(q, radius, &mut got);
                let mut got: Vec<u32> = got
                    .iter()
                    .map(|&(i, p)| {
                        assert_eq!(p, pts[i as usize]);
                        i
                    })
                    .collect();
                got.sort_unstable();
                let want: Vec<u32> = (0..pts.len() as u32)
                    .filter(|&i| dist2(&pts[i as usize], q) <= radius * radius)
                    .collect();
                assert_eq!(got, want, "query {q:?}");
            }
        }
    }
}
