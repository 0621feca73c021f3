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

    /// Whether `pred(indices, positions)` holds for any of the runs of points (up to
    /// nine, one per column of three cells) that make the 27 cells around `q`.
    #[inline]
    fn any_run_near(&self, q: &[f64; 3], pred: impl FnMut(&[u32], &[[f64; 3]]) -> bool) -> bool {
        let Some(c) = index(q, self.inv_cell) else {
            return false;
        };
        self.any_run_in(c.map(|x| x - 1), c.map(|x| x + 1), pred)
    }

    /// Whether `pred(index, position)` holds for any point in the cells that meet the
    /// box from `lo` to `hi` (stops at the first that does). Where a corner has no cell
    /// (beyond the grid's range), the 27 cells around the box's centre are searched
    /// (none if the centre has no cell either). Meant for boxes a few cells wide: every
    /// column the box meets is looked up.
    #[inline]
    pub fn any_in_box(
        &self,
        lo: &[f64; 3],
        hi: &[f64; 3],
        mut pred: impl FnMut(u32, &[f64; 3]) -> bool,
    ) -> bool {
        let pred_run =
            |idx: &[u32], pos: &[[f64; 3]]| idx.iter().zip(pos).any(|(&i, p)| pred(i, p));
        match (index(lo, self.inv_cell), index(hi, self.inv_cell)) {
            (Some(a), Some(b)) => self.any_run_in(a, b, pred_run),
            _ => {
                let mid = [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k]));
                self.any_run_near(&mid, pred_run)
            }
        }
    }

    /// Whether `pred(indices, positions)` holds for any run of points of the cells from
    /// `lo` to `hi` (cell indices, inclusive): one run per column.
    #[inline]
    fn any_run_in(
        &self,
        lo: [i64; 3],
        hi: [i64; 3],
        mut pred: impl FnMut(&[u32], &[[f64; 3]]) -> bool,
    ) -> bool {
        let (z0, z1) = (lo[2] as i32, hi[2] as i32);
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                let col = VoxelGrid::key_of_index([x, y, 0]) >> AXIS_BITS;
                let Some(&(a, b)) = self.columns.get(&col) else {
                    continue;
                };
                let zs = &self.cell_z[a as usize..b as usize];
                let from = a as usize + zs.partition_point(|&cz| cz < z0);
                let to = a as usize + zs.partition_point(|&cz| cz <= z1);
                if from == to {
                    continue;
                }
                let run = self.cell_start[from] as usize..self.cell_start[to] as usize;
                if pred(&self.sorted[run.clone()], &self.pos[run]) {
                    return true;
                }
            }
        }
        false
    }

    /// The points within `radius` (≤ `cell_m`) of `q`, appended to `out` in the order
    /// of the grid.
    pub fn within(&self, q: &[f64; 3], radius: f64, out: &mut Near) {
        let r2 = radius * radius;
        self.any_run_near(q, |idx, pos| {
            let (from, to) = (out.len, out.len + idx.len());
            if out.idx.len() < to {
                let grown = to.max(2 * out.idx.len());
                out.idx.resize(grown, 0);
                out.pos.resize(grown, [0.0; 3]);
            }
            // Every point is written and the end advances over those within: about a
            // third of them are, so a branch on it would often be mispredicted.
            let (oi, op) = (&mut out.idx[from..to], &mut out.pos[from..to]);
            let mut n = 0;
            for (&i, p) in idx.iter().zip(pos) {
                oi[n] = i;
                op[n] = *p;
                n += usize::from(dist2(p, q) <= r2);
            }
            out.len += n;
            false
        });
    }
}

/// Points found near a query ([`PointGrid::within`]): their indices and positions, side
/// by side. The buffers only grow, so a query writes every point it looks at and keeps
/// those within without a branch.
#[derive(Clone, Debug, Default)]
pub struct Near {
    idx: Vec<u32>,
    pos: Vec<[f64; 3]>,
    len: usize,
}

impl Near {
    /// Forgets the points (keeps the buffers).
    pub fn clear(&mut self) {
        self.len = 0;
    }

    /// The points' indices.
    pub fn indices(&self) -> &[u32] {
        &self.idx[..self.len]
    }

    /// The points' positions, in the order of [`Near::indices`].
    pub fn positions(&self) -> &[[f64; 3]] {
        &self.pos[..self.len]
    }

    /// The points as (index, position).
    pub fn iter(&self) -> impl Iterator<Item = (u32, &[f64; 3])> {
        self.indices().iter().copied().zip(self.positions())
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
    fn any_in_box_visits_every_point_of_the_box_and_only_the_cells_it_meets() {
        // A second method: every point tested against the box; the cells visited
        // computed from each visited point's coordinates.
        let mut state: u64 = 0x2545_F491_4F6C_DD1D;
        let mut next = || crate::mapper::test_rng::next_unit(&mut state);
        let pts: Vec<[f64; 3]> = (0..20_000)
            .map(|_| [next() * 0.3 - 0.1, next() * 0.2 - 0.15, next() * 0.6 - 0.3])
            .collect();
        let cell = 0.02;
        let grid = PointGrid::new(&pts, cell);
        // As the grid keys them: times the inverse cell, floored.
        let cells = |p: &[f64; 3]| p.map(|x| (x * (1.0 / cell)).floor() as i64);
        let boxes: Vec<([f64; 3], f64)> = (0..3000)
            .map(|i| {
                let c = pts[i * 5];
                // Half-widths up to a cell, centres on points and on cell faces.
                let c = if i % 7 == 0 {
                    c.map(|x| (x / cell).round() * cell)
                } else {
                    c
                };
                (c, next() * cell)
            })
            .collect();
        for (c, h) in boxes {
            let (lo, hi) = (c.map(|x| x - h), c.map(|x| x + h));
            let mut seen = Vec::new();
            grid.any_in_box(&lo, &hi, |i, p| {
                assert_eq!(*p, pts[i as usize]);
                seen.push(i);
                false
            });
            seen.sort_unstable();
            assert!(
                seen.windows(2).all(|w| w[0] < w[1]),
                "a point visited twice"
            );
            let (clo, chi) = (cells(&lo), cells(&hi));
            for i in 0..pts.len() as u32 {
                let p = &pts[i as usize];
                let in_box = (0..3).all(|k| p[k] >= lo[k] && p[k] <= hi[k]);
                let in_cells = (0..3).all(|k| (clo[k]..=chi[k]).contains(&cells(p)[k]));
                let visited = seen.binary_search(&i).is_ok();
                assert!(!in_box || visited, "point {i} in the box was not visited");
                assert_eq!(
                    visited, in_cells,
                    "point {i}: visited iff its cell meets the box"
                );
            }
        }
        // A corner beyond the grid's keys: the 27 cells around the centre.
        let mut a = Vec::new();
        grid.any_in_box(&[-1e9, -0.005, -0.005], &[1e9, 0.005, 0.005], |i, _| {
            a.push(i);
            false
        });
        a.sort_unstable();
        let b: Vec<u32> = (0..pts.len() as u32)
            .filter(|&i| cells(&pts[i as usize]).iter().all(|c| (-1..=1).contains(c)))
            .collect();
        assert!(!b.is_empty());
        assert_eq!(a, b);
    }

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
                let mut near = Near::default();
                // Left-overs of an earlier query must not show.
                grid.within(&[0.0; 3], cell, &mut near);
                near.clear();
                grid.within(q, radius, &mut near);
                assert_eq!(near.indices().len(), near.positions().len());
                let mut got: Vec<u32> = near
                    .iter()
                    .map(|(i, p)| {
                        assert_eq!(*p, pts[i as usize]);
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
