//! Point normals by principal component analysis of the k nearest neighbours, oriented
//! towards the sensor that saw each point.
//!
//! The neighbour search is a uniform grid over the map's voxel centroids (`KnnGrid`):
//! a column of cells is walked bottom to top, the points of each cell's block of 27 are
//! gathered once, and every point of the cell picks its nearest from them with a proof
//! that nothing outside the block is nearer (else the search widens ring by ring, and past
//! [`MAX_RING`] rings asks a kiddo k-d tree). The answer is kiddo's `nearest_n`, bit for
//! bit: the grid computes the same `f32` distances, and where two of the k + 1 nearest lie
//! at exactly the same distance (kiddo's order among them depends on its tree) kiddo is
//! asked. On `map-row`'s 6.8 M-point map that is 3 of them, and the search a third of
//! kiddo's time (docs/PERFORMANCE.md).

use super::voxel::{AXIS_BITS, VoxelGrid};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;
use rustc_hash::FxHashMap;
use std::num::NonZero;
use std::sync::OnceLock;

/// Rings of cells the grid search widens to before it hands a point to the k-d tree.
pub const MAX_RING: i64 = 4;

/// Unit normals of `points`: the eigenvector of the smallest eigenvalue of the covariance
/// of each point's `k` nearest neighbours (the point included), flipped to face its
/// `viewpoint` (the camera centre that saw it). Where the neighbourhood is degenerate
/// (fewer than 3 points) the normal is the unit vector towards the viewpoint.
///
/// Neighbours are searched in a grid of cells of edge `cell_m` (about twice the spacing
/// of the points is right); `cell_m` changes the speed, never the result. Distances are
/// compared as `f32` (as the points are stored); the covariance is accumulated in `f64`
/// about the neighbourhood's mean, nearest neighbour first.
pub fn estimate_normals(
    points: &[[f32; 3]],
    viewpoints: &[[f32; 3]],
    k: usize,
    cell_m: f64,
) -> Vec<[f32; 3]> {
    let k = k.max(3);
    let Some(grid) = KnnGrid::new(points, cell_m) else {
        // A point the grid cannot key (non-finite, or millions of cells away): the k-d
        // tree serves them all.
        let tree = ImmutableKdTree::new_from_slice(points);
        return points
            .par_iter()
            .zip(viewpoints.par_iter())
            .map(|(p, vp)| {
                let mut nn = Vec::with_capacity(k);
                kiddo_nearest(&tree, p, k, &mut nn);
                normal_of(points, &nn, p, vp)
            })
            .collect();
    };
    let mut out = vec![[0f32; 3]; points.len()];
    let per_column: Vec<Vec<(u32, [f32; 3])>> = (0..grid.columns.len())
        .into_par_iter()
        .map_init(Scratch::default, |s, col| {
            let mut res = Vec::new();
            grid.for_each_cell_of_column(col, s, |s, key, range| {
                for q in range {
                    let (p, i) = (grid.spts[q], grid.sorted[q]);
                    // One more than needed: where the k + 1 nearest are at k + 1 different
                    // distances the k nearest and their order are unique, and so what
                    // kiddo would answer; else kiddo answers.
                    grid.nearest(&p, key, k + 1, s);
                    if s.nn.windows(2).any(|w| w[0].0 == w[1].0) {
                        kiddo_nearest(grid.tree(), &p, k, &mut s.nn);
                    }
                    s.nn.truncate(k);
                    res.push((i, normal_of(points, &s.nn, &p, &viewpoints[i as usize])));
                }
            });
            res
        })
        .collect();
    for column in per_column {
        for (i, n) in column {
            out[i as usize] = n;
        }
    }
    out
}

/// The normal of `p` from its neighbours `nn` (indices into `points`, nearest first).
fn normal_of(points: &[[f32; 3]], nn: &[(f32, u32)], p: &[f32; 3], vp: &[f32; 3]) -> [f32; 3] {
    let at = |i: u32| {
        let p = points[i as usize];
        Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
    };
    let pv = Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
    let to_view = Vector3::new(f64::from(vp[0]), f64::from(vp[1]), f64::from(vp[2])) - pv;
    let fallback = to_view.try_normalize(1e-12).unwrap_or_else(Vector3::z);
    let normal = if nn.len() < 3 {
        fallback
    } else {
        let mut mean = Vector3::zeros();
        for q in nn {
            mean += at(q.1);
        }
        mean /= nn.len() as f64;
        let mut cov = Matrix3::zeros();
        for q in nn {
            let d = at(q.1) - mean;
            cov += d * d.transpose();
        }
        let eig = SymmetricEigen::new(cov);
        let (mut imin, mut vmin) = (0, f64::INFINITY);
        for (i, v) in eig.eigenvalues.iter().enumerate() {
            if *v < vmin {
                (imin, vmin) = (i, *v);
            }
        }
        let n = eig.eigenvectors.column(imin).into_owned();
        match n.try_normalize(1e-12) {
            Some(n) if n.dot(&to_view) < 0.0 => -n,
            Some(n) => n,
            None => fallback,
        }
    };
    [normal.x as f32, normal.y as f32, normal.z as f32]
}

/// Squared distance in `f32` as kiddo's `SquaredEuclidean` computes it (same order of
/// operations, so the same bits).
#[inline]
fn dist2(a: &[f32; 3], b: &[f32; 3]) -> f32 {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    0.0 + d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
}

/// Keeps the `k` nearest of `nn` (squared distance, index), sorted by distance, then
/// index.
#[inline]
fn keep_nearest(nn: &mut Vec<(f32, u32)>, k: usize) {
    let by = |a: &(f32, u32), b: &(f32, u32)| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1));
    if nn.len() > 4 * k {
        nn.select_nth_unstable_by(k - 1, by);
        nn.truncate(k);
    }
    nn.sort_unstable_by(by);
    nn.truncate(k);
}

/// The `k` nearest points of `p` as kiddo's `nearest_n` answers (nearest first; points
/// at the same distance in the order its tree meets them).
fn kiddo_nearest(tree: &ImmutableKdTree<f32, 3>, p: &[f32; 3], k: usize, nn: &mut Vec<(f32, u32)>) {
    nn.clear();
    let n = NonZero::new(k).unwrap_or(NonZero::<usize>::MIN);
    let found = tree.nearest_n::<SquaredEuclidean>(p, n);
    nn.extend(found.iter().map(|q| (q.distance, q.item as u32)));
}

/// Per-thread buffers of the grid search.
#[derive(Default)]
struct Scratch {
    /// Candidate points: the block of 27 cells around the current cell, then the shells
    /// of a widened search (coordinates and index).
    cand: Vec<([f32; 3], u32)>,
    /// Squared distances of the block's candidates to the current point.
    dist: Vec<f32>,
    /// The current best (squared distance, index), nearest first.
    nn: Vec<(f32, u32)>,
    /// Candidates of the block as `(distance bits << 32) | index`.
    packed: Vec<u64>,
}

/// The z bits of a cell key (the rest is its column).
const Z_MASK: u64 = (1 << AXIS_BITS) - 1;

/// Points bucketed by cells of a uniform grid, for exact k-nearest-neighbour queries.
/// Cell keys sort by (x, y, z), so a column of cells (one x, y) is a range of `runs`, and
/// the three cells z − 1, z, z + 1 of a column are consecutive there.
struct KnnGrid<'a> {
    points: &'a [[f32; 3]],
    cell_m: f64,
    /// Point indices ordered by (cell key, index).
    sorted: Vec<u32>,
    /// The points in that order.
    spts: Vec<[f32; 3]>,
    /// (key, start, end) of each occupied cell's range in `sorted`, by key.
    runs: Vec<(u64, u32, u32)>,
    /// The range in `runs` of each occupied column, by key.
    columns: Vec<(u32, u32)>,
    /// Column key (cell key without its z bits) to its index in `columns`.
    column_of: FxHashMap<u64, u32>,
    /// Cell key to its range in `sorted` (for the shells of a widened search).
    cells: FxHashMap<u64, (u32, u32)>,
    /// The fallback for points whose neighbours lie beyond [`MAX_RING`] rings.
    tree: OnceLock<ImmutableKdTree<f32, 3>>,
}

impl<'a> KnnGrid<'a> {
    /// `None` when a point has no cell (non-finite, or beyond the keys' range with a
    /// margin of [`MAX_RING`] + 1 cells), or the cell edge is not a positive length.
    fn new(points: &'a [[f32; 3]], cell_m: f64) -> Option<KnnGrid<'a>> {
        if !(cell_m.is_finite() && cell_m > 0.0) || points.len() >= u32::MAX as usize {
            return None;
        }
        let inv_cell = 1.0 / cell_m;
        let mut keyed: Vec<(u64, u32)> = points
            .par_iter()
            .enumerate()
            .map(|(i, p)| Some((VoxelGrid::key_of_index(cell_index(p, inv_cell)?), i as u32)))
            .collect::<Option<_>>()?;
        keyed.par_sort_unstable();
        let mut runs: Vec<(u64, u32, u32)> = Vec::new();
        let mut columns: Vec<(u32, u32)> = Vec::new();
        let mut column_of = FxHashMap::default();
        for (at, &(key, _)) in keyed.iter().enumerate() {
            match runs.last_mut() {
                Some(r) if r.0 == key => r.2 += 1,
                _ => {
                    let col = key >> AXIS_BITS;
                    if runs.last().is_none_or(|r| r.0 >> AXIS_BITS != col) {
                        column_of.insert(col, columns.len() as u32);
                        columns.push((runs.len() as u32, runs.len() as u32));
                    }
                    runs.push((key, at as u32, at as u32 + 1));
                    if let Some(c) = columns.last_mut() {
                        c.1 += 1;
                    }
                }
            }
        }
        let cells = runs.iter().map(|&(k, a, b)| (k, (a, b))).collect();
        let sorted: Vec<u32> = keyed.into_iter().map(|(_, i)| i).collect();
        let spts = sorted.iter().map(|&i| points[i as usize]).collect();
        Some(KnnGrid {
            points,
            cell_m,
            sorted,
            spts,
            runs,
            columns,
            column_of,
            cells,
            tree: OnceLock::new(),
        })
    }

    /// The k-d tree, built on first use.
    fn tree(&self) -> &ImmutableKdTree<f32, 3> {
        self.tree
            .get_or_init(|| ImmutableKdTree::new_from_slice(self.points))
    }

    /// Calls `f(scratch, key, range in sorted)` for each cell of column `col`, bottom to
    /// top, with the points of the cell's block of 27 in `s.cand`.
    fn for_each_cell_of_column(
        &self,
        col: usize,
        s: &mut Scratch,
        mut f: impl FnMut(&mut Scratch, u64, std::ops::Range<usize>),
    ) {
        let (ra, rb) = self.columns[col];
        let c = VoxelGrid::index_of_key(self.runs[ra as usize].0);
        // The nine columns around this one: (next run to look at, end).
        let mut near = [(0u32, 0u32); 9];
        for (slot, (dx, dy)) in near
            .iter_mut()
            .zip((-1..=1).flat_map(|dx| (-1..=1).map(move |dy| (dx, dy))))
        {
            let key = VoxelGrid::key_of_index([c[0] + dx, c[1] + dy, 0]) >> AXIS_BITS;
            if let Some(&j) = self.column_of.get(&key) {
                *slot = self.columns[j as usize];
            }
        }
        for r in ra..rb {
            let (key, a, b) = self.runs[r as usize];
            let z = key & Z_MASK;
            s.cand.clear();
            for (next, end) in &mut near {
                while *next < *end && self.runs[*next as usize].0 & Z_MASK < z - 1 {
                    *next += 1;
                }
                let mut last = *next;
                while last < *end && self.runs[last as usize].0 & Z_MASK <= z + 1 {
                    last += 1;
                }
                if last > *next {
                    let from = self.runs[*next as usize].1;
                    self.gather(from, self.runs[last as usize - 1].2, s);
                }
            }
            f(s, key, a as usize..b as usize);
        }
    }

    /// Appends the points `from..to` of the sorted order to `s.cand`.
    #[inline]
    fn gather(&self, from: u32, to: u32, s: &mut Scratch) {
        let r = from as usize..to as usize;
        s.cand.extend(
            self.spts[r.clone()]
                .iter()
                .copied()
                .zip(self.sorted[r].iter().copied()),
        );
    }

    /// Appends the points of the cells at Chebyshev distance exactly `ring` (≥ 2) from
    /// cell `key` to `s.cand`.
    fn gather_shell(&self, key: u64, ring: i64, s: &mut Scratch) {
        let c = VoxelGrid::index_of_key(key);
        for dx in -ring..=ring {
            for dy in -ring..=ring {
                let inner = dx.abs() < ring && dy.abs() < ring;
                let mut dz = -ring;
                while dz <= ring {
                    let key = VoxelGrid::key_of_index([c[0] + dx, c[1] + dy, c[2] + dz]);
                    if let Some(&(a, b)) = self.cells.get(&key) {
                        self.gather(a, b, s);
                    }
                    // Inside the shell only its two z faces are new.
                    dz += if inner && dz == -ring { 2 * ring } else { 1 };
                }
            }
        }
    }

    /// The `k` nearest points of `p` (in cell `key`; its block in `s.cand`) into `s.nn`,
    /// nearest first, ties by index.
    fn nearest(&self, p: &[f32; 3], key: u64, k: usize, s: &mut Scratch) {
        let c = VoxelGrid::index_of_key(key);
        // Usually `k` points of the block are nearer than anything outside it: those are
        // the only ones worth sorting.
        let bound = self.clearance(p, c, 1);
        let limit = bound * bound / (1.0 + MARGIN);
        // The largest f32 at most `limit`.
        let mut lim = limit as f32;
        if f64::from(lim) > limit {
            lim = f32::from_bits(lim.to_bits() - 1);
        }
        s.dist.clear();
        s.dist.extend(s.cand.iter().map(|(q, _)| dist2(p, q)));
        // Those nearer than `lim` as (distance bits, index) in one integer: a squared
        // distance is never negative (nor -0: `dist2` starts from +0), so integer order
        // is the order by distance, then index, and sorting takes integer compares.
        s.packed.clear();
        s.packed.resize(s.cand.len(), 0);
        let mut n = 0;
        for (d, (_, i)) in s.dist.iter().zip(&s.cand) {
            s.packed[n] = (u64::from(d.to_bits()) << 32) | u64::from(*i);
            n += usize::from(*d < lim);
        }
        s.packed.truncate(n);
        if n >= k {
            if n > 4 * k {
                s.packed.select_nth_unstable(k - 1);
                s.packed.truncate(k);
            }
            s.packed.sort_unstable();
            s.nn.clear();
            s.nn.extend(
                s.packed[..k]
                    .iter()
                    .map(|&e| (f32::from_bits((e >> 32) as u32), e as u32)),
            );
            return;
        }
        // Fewer than k within the proof's reach: all of the block, then shells.
        s.nn.clear();
        s.nn.extend(s.dist.iter().copied().zip(s.cand.iter().map(|(_, i)| *i)));
        keep_nearest(&mut s.nn, k);
        // The shells of a widened search go after the block and are dropped again for
        // the cell's next point.
        let block = s.cand.len();
        let mut ring = 1;
        while !(s.nn.len() == k && self.proven(p, c, ring, s.nn[k - 1].0)) {
            if ring == MAX_RING {
                kiddo_nearest(self.tree(), p, k, &mut s.nn);
                break;
            }
            ring += 1;
            let seen = s.cand.len();
            self.gather_shell(key, ring, s);
            s.nn.extend(s.cand[seen..].iter().map(|(q, i)| (dist2(p, q), *i)));
            keep_nearest(&mut s.nn, k);
        }
        s.cand.truncate(block);
    }

    /// The distance from `p` to the outside of the `ring` block around its cell `c`.
    fn clearance(&self, p: &[f32; 3], c: [i64; 3], ring: i64) -> f64 {
        let mut clear = f64::INFINITY;
        for a in 0..3 {
            let x = f64::from(p[a]);
            let lo = (c[a] - ring) as f64 * self.cell_m;
            let hi = (c[a] + ring + 1) as f64 * self.cell_m;
            clear = clear.min(x - lo).min(hi - x);
        }
        clear.max(0.0)
    }

    /// Whether no point outside the `ring` block around cell `c` can be as near to `p`
    /// as squared distance `kth` (with a margin well above `f32` rounding).
    fn proven(&self, p: &[f32; 3], c: [i64; 3], ring: i64, kth: f32) -> bool {
        let clear = self.clearance(p, c, ring);
        f64::from(kth) * (1.0 + MARGIN) < clear * clear
    }
}

/// Relative margin on squared distances in the proofs: far above the few `f32` roundings
/// of [`dist2`] (about 1e-7 each).
const MARGIN: f64 = 1e-5;

/// The cell of `p`, `None` where it or its [`MAX_RING`] + 1 neighbouring cells would fall
/// outside the keys' range.
fn cell_index(p: &[f32; 3], inv_cell: f64) -> Option<[i64; 3]> {
    let lim = VoxelGrid::AXIS_RANGE - (MAX_RING + 2) as f64;
    let mut idx = [0i64; 3];
    for (o, c) in idx.iter_mut().zip(p) {
        let f = (f64::from(*c) * inv_cell).floor();
        if !(f > -lim && f < lim) {
            return None;
        }
        *o = f as i64;
    }
    Some(idx)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normals_of_a_tilted_plane_face_the_viewpoint() {
        // Plane z = 0.5·x, seen from above.
        let pts: Vec<[f32; 3]> = (0..400u16)
            .map(|i| {
                let (x, y) = (f32::from(i % 20) * 0.01, f32::from(i / 20) * 0.01);
                [x, y, 0.5 * x]
            })
            .collect();
        let vps = vec![[0.1f32, 0.1, 2.0]; pts.len()];
        let n = estimate_normals(&pts, &vps, 10, 0.02);
        assert_eq!(n, reference(&pts, &vps, 10));
        let expected = Vector3::new(-0.5, 0.0, 1.0).normalize();
        for v in &n {
            let v = Vector3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]));
            assert!(v.dot(&expected) > 0.9999, "{v:?}");
        }
    }

    /// The search this module replaced: kiddo's `nearest_n` for every point.
    fn reference(points: &[[f32; 3]], viewpoints: &[[f32; 3]], k: usize) -> Vec<[f32; 3]> {
        let k = k.max(3);
        let tree = ImmutableKdTree::new_from_slice(points);
        let nk = NonZero::new(k).unwrap();
        points
            .iter()
            .zip(viewpoints)
            .map(|(p, vp)| {
                let nn: Vec<(f32, u32)> = tree
                    .nearest_n::<SquaredEuclidean>(p, nk)
                    .iter()
                    .map(|q| (q.distance, q.item as u32))
                    .collect();
                normal_of(points, &nn, p, vp)
            })
            .collect()
    }

    fn lcg(state: &mut u64) -> f32 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*state >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Bit for bit what kiddo's neighbours give, on whatever the grid meets: a noisy
    /// surface far from the origin (no ties), a lattice (ties everywhere), a wire of
    /// points (widened searches), a few points far from the rest (beyond the widest
    /// search), fewer points than neighbours, and for any cell size.
    #[test]
    fn the_grid_finds_the_neighbours_kiddo_finds() {
        let mut st = 7u64;
        let mut pts: Vec<[f32; 3]> = Vec::new();
        for _ in 0..6000 {
            let (x, y) = (lcg(&mut st) * 0.6, lcg(&mut st) * 0.4);
            pts.push([
                120.0 + x,
                -35.0 + y,
                0.3 + 0.1 * (x * 9.0).sin() + 0.004 * lcg(&mut st),
            ]);
        }
        for i in 0..8 {
            for j in 0..8 {
                for l in 0..4 {
                    pts.push([
                        121.0 + 0.01 * i as f32,
                        -35.0 + 0.01 * j as f32,
                        0.01 * l as f32,
                    ]);
                }
            }
        }
        for i in 0..200 {
            pts.push([119.0 + 0.004 * i as f32, -34.0, 1.0 + 0.001 * lcg(&mut st)]);
        }
        pts.extend([
            [130.0, -30.0, 2.0],
            [130.5, -30.0, 2.0],
            [100.0, -50.0, -3.0],
        ]);
        let vps: Vec<[f32; 3]> = pts
            .iter()
            .map(|p| [p[0] + 0.3, p[1] - 0.2, p[2] + 2.0])
            .collect();
        let want = reference(&pts, &vps, 10);
        for cell in [0.005, 0.02, 0.1] {
            assert!(
                estimate_normals(&pts, &vps, 10, cell) == want,
                "cell {cell} m"
            );
        }
        let few = &pts[..7];
        assert_eq!(
            estimate_normals(few, &vps[..7], 10, 0.02),
            reference(few, &vps[..7], 10)
        );
        // Not a length: the k-d tree alone, the same answer.
        assert!(estimate_normals(&pts, &vps, 10, f64::NAN) == want);
    }
}
