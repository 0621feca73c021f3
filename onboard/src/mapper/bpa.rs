//! Ball-Pivoting surface reconstruction (Bernardini, Mittleman, Rushmeier, Silva and
//! Taubin, "The Ball-Pivoting Algorithm for Surface Reconstruction", IEEE TVCG 1999).
//!
//! A ball of radius ρ that touches three points without containing any other forms a
//! triangle. Starting from a seed triangle, the ball pivots around each edge of the
//! *front* (the boundary of the mesh so far) until it touches a new point; that point and
//! the edge make the next triangle. Edges where the ball touches nothing (or only a point
//! that would break the manifold) become *boundary* edges. When the front is exhausted a
//! new seed is searched among the unused points. With several radii (ascending), each
//! later pass re-activates the boundary edges whose triangle admits an empty ball of the
//! new radius and goes on pivoting, which closes holes left by sparse sampling.
//!
//! Orientation: triangles are counter-clockwise seen from the side the point normals
//! point to; the ball centre lies on that side. Every directed edge belongs to at most one
//! triangle and every undirected edge to at most two, so the output is an oriented,
//! edge-manifold mesh.
//!
//! Neighbour queries use a uniform hash grid of cell 2ρ ([`PointGrid`]): every point a
//! ball of radius ρ can touch while pivoting about an edge lies within 2ρ of the edge's
//! midpoint. The pivoting itself is sequential (each step depends on the front); the
//! grids are built in parallel.
//!
//! A large map is meshed in square xy tiles ([`ball_pivoting_tiled`]), so memory follows
//! the tile, not the map, and tiles run in parallel. Each tile meshes its points and
//! those within a margin of [`TILE_MARGIN_RADII`] largest radii around it, and keeps the
//! triangles whose centroid lies in the tile. Ball-Pivoting is local (a triangle exists
//! where an empty ball touches its three points, and the front reaches it from either
//! side), so two neighbouring tiles build the same triangles along their common side and
//! the seam closes; where a noisy neighbourhood (foliage) makes the front's order matter,
//! a seam may keep a few open or doubled edges.

use super::grid::{Near, PointGrid, dist2};
use rayon::prelude::*;
use rustc_hash::FxHashMap;
use std::collections::VecDeque;

/// Relative tolerance of the empty-ball test (points this close to the sphere count as
/// on it, not inside).
const EMPTY_BALL_TOLERANCE: f64 = 1e-9;
/// Seed search looks at this many nearest unused neighbours of a candidate vertex.
const SEED_NEIGHBOURS: usize = 12;
/// How far (relative to ρ) a ball's centre may lie beyond ρ from a point on its sphere
/// for [`Bpa::ball_is_empty_near`] to answer: far above the rounding of the centre, well
/// below the 5e-10 of [`EMPTY_BALL_TOLERANCE`].
const CENTRE_SLACK: f64 = 1e-10;
/// How far (relative to ρ) [`Bpa::ball_is_empty`] widens the ball's bounding box: a point
/// strictly inside lies more than 5e-10 ρ ([`EMPTY_BALL_TOLERANCE`]) within it, far more
/// than the rounding of a coordinate, so the box holds every such point.
const BOX_SLACK: f64 = 1e-6;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum EdgeState {
    /// On the front, to be pivoted.
    Active,
    /// On the front; pivoting found nothing (with the current radius).
    Boundary,
    /// Shared by two triangles.
    Inner,
}

/// A directed edge `s → t` of the triangle `(s, t, o)` (counter-clockwise).
#[derive(Clone, Copy, Debug)]
struct Edge {
    s: u32,
    t: u32,
    o: u32,
    /// Centre of the ball that made the triangle.
    center: [f64; 3],
    state: EdgeState,
}

/// Counters of one reconstruction.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BpaStats {
    /// Seed triangles found.
    pub seeds: usize,
    /// Pivots that produced a triangle.
    pub pivots: usize,
    /// Edges left on the boundary at the end.
    pub boundary_edges: usize,
}

struct Bpa<'a> {
    p: &'a [[f64; 3]],
    n: &'a [[f64; 3]],
    edges: Vec<Edge>,
    directed: FxHashMap<u64, u32>,
    used: Vec<bool>,
    front_deg: Vec<u32>,
    queue: VecDeque<u32>,
    triangles: Vec<[u32; 3]>,
    stats: BpaStats,
}

#[inline]
fn dkey(s: u32, t: u32) -> u64 {
    (u64::from(s) << 32) | u64::from(t)
}
#[inline]
fn sub(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline]
fn cross(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
#[inline]
fn dot(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Centre of the ball of radius `rho` through `a`, `b`, `c` on the side of the
/// counter-clockwise normal `(b − a) × (c − a)`, with that (unnormalised) normal; `None`
/// for a degenerate triangle or a circumradius above `rho`.
#[inline]
fn ball_center(a: &[f64; 3], b: &[f64; 3], c: &[f64; 3], rho: f64) -> Option<([f64; 3], [f64; 3])> {
    let ab = sub(b, a);
    let ac = sub(c, a);
    ball_center_of(a, &ab, &ac, cross(&ab, &ac), rho)
}

/// [`ball_center`] from `ab` = b − a, `ac` = c − a and their cross product `nrm`, where
/// the caller has them already.
#[inline]
fn ball_center_of(
    a: &[f64; 3],
    ab: &[f64; 3],
    ac: &[f64; 3],
    nrm: [f64; 3],
    rho: f64,
) -> Option<([f64; 3], [f64; 3])> {
    let (ab, ac) = (*ab, *ac);
    let l2 = dot(&nrm, &nrm);
    let scale = dot(&ab, &ab) * dot(&ac, &ac);
    if l2.is_nan() || l2 <= 1e-12 * scale || l2 <= 0.0 {
        return None;
    }
    let t1 = cross(&nrm, &ab);
    let t2 = cross(&ac, &nrm);
    let (wa, wb) = (dot(&ac, &ac), dot(&ab, &ab));
    let inv = 0.5 / l2;
    let off = [
        (wa * t1[0] + wb * t2[0]) * inv,
        (wa * t1[1] + wb * t2[1]) * inv,
        (wa * t1[2] + wb * t2[2]) * inv,
    ];
    let h2 = rho * rho - dot(&off, &off);
    if h2 < 0.0 {
        return None;
    }
    let h = (h2 / l2).sqrt();
    Some((
        [
            a[0] + off[0] + nrm[0] * h,
            a[1] + off[1] + nrm[1] * h,
            a[2] + off[2] + nrm[2] * h,
        ],
        nrm,
    ))
}

impl Bpa<'_> {
    /// Whether a vertex may join a new triangle: unused, or on the front.
    fn available(&self, v: u32) -> bool {
        !self.used[v as usize] || self.front_deg[v as usize] > 0
    }

    /// Adds triangle `(a, b, c)` if it keeps the mesh oriented and edge-manifold.
    fn add_triangle(&mut self, tri: [u32; 3], center: [f64; 3]) -> bool {
        let [a, b, c] = tri;
        if a == b
            || b == c
            || a == c
            || !self.available(a)
            || !self.available(b)
            || !self.available(c)
        {
            return false;
        }
        let sides = [(a, b, c), (b, c, a), (c, a, b)];
        if sides
            .iter()
            .any(|&(x, y, _)| self.directed.contains_key(&dkey(x, y)))
        {
            return false;
        }
        self.triangles.push(tri);
        for &(x, y, o) in &sides {
            let id = self.edges.len() as u32;
            let state = match self.directed.get(&dkey(y, x)) {
                Some(&twin) => {
                    let tw = &mut self.edges[twin as usize];
                    if tw.state != EdgeState::Inner {
                        tw.state = EdgeState::Inner;
                        self.front_deg[x as usize] -= 1;
                        self.front_deg[y as usize] -= 1;
                    }
                    EdgeState::Inner
                }
                None => {
                    self.front_deg[x as usize] += 1;
                    self.front_deg[y as usize] += 1;
                    self.queue.push_back(id);
                    EdgeState::Active
                }
            };
            self.edges.push(Edge {
                s: x,
                t: y,
                o,
                center,
                state,
            });
            self.directed.insert(dkey(x, y), id);
        }
        for v in tri {
            self.used[v as usize] = true;
        }
        true
    }

    fn normals_agree(&self, nrm: &[f64; 3], vs: [u32; 3]) -> bool {
        vs.iter().all(|&v| dot(nrm, &self.n[v as usize]) > 0.0)
    }

    /// Pivots the ball about front edge `id`; adds the triangle or marks the edge
    /// boundary. `near` is a buffer.
    fn pivot(&mut self, id: u32, grid: &PointGrid, rho: f64, near: &mut Near) {
        let e = self.edges[id as usize];
        let (ps, pt) = (&self.p[e.s as usize], &self.p[e.t as usize]);
        let m = [
            0.5 * (ps[0] + pt[0]),
            0.5 * (ps[1] + pt[1]),
            0.5 * (ps[2] + pt[2]),
        ];
        let axis = sub(pt, ps);
        let u0 = sub(&e.center, &m);
        let mut best: Option<(f64, u32, [f64; 3])> = None;
        near.clear();
        grid.within(&m, 2.0 * rho, near);
        let ts = sub(ps, pt);
        for (k, pk) in near.iter() {
            if k == e.s || k == e.t || k == e.o {
                continue;
            }
            // The new triangle (t, s, k) shares the edge reversed. Its normal is checked
            // first, for a fraction of the ball's cost, and the ball is computed from it.
            let tk = sub(pk, pt);
            let nrm = cross(&ts, &tk);
            if !self.normals_agree(&nrm, [e.s, e.t, k]) {
                continue;
            }
            let Some((c, _)) = ball_center_of(pt, &ts, &tk, nrm, rho) else {
                continue;
            };
            let u1 = sub(&c, &m);
            let mut angle = dot(&axis, &cross(&u0, &u1)).atan2(dot(&u0, &u1));
            if angle < 0.0 {
                angle += std::f64::consts::TAU;
            }
            if best.is_none_or(|(a, bk, _)| angle < a || (angle == a && k < bk)) {
                best = Some((angle, k, c));
            }
        }
        // A vertex already in the mesh may only close the front locally: it must share a
        // front edge with `s` or `t`. Joining a distant part of the front would pinch the
        // surface at that vertex (not manifold) and, in noisy volumetric clouds such as
        // foliage, lets triangles multiply without bound.
        let added = match best {
            Some((_, k, c)) => {
                let local = !self.used[k as usize]
                    || self.directed.contains_key(&dkey(k, e.s))
                    || self.directed.contains_key(&dkey(e.t, k));
                local && self.add_triangle([e.t, e.s, k], c)
            }
            None => false,
        };
        if added {
            self.stats.pivots += 1;
        } else if self.edges[id as usize].state == EdgeState::Active {
            self.edges[id as usize].state = EdgeState::Boundary;
        }
    }

    /// Whether point `q`, not one of `skip`, lies strictly inside the ball (radius `rho`
    /// less [`EMPTY_BALL_TOLERANCE`]).
    #[inline]
    fn inside(q: u32, pq: &[f64; 3], center: &[f64; 3], rho: f64, skip: [u32; 3]) -> bool {
        !skip.contains(&q) && dist2(pq, center) < rho * rho * (1.0 - EMPTY_BALL_TOLERANCE)
    }

    /// Whether no point other than `skip` lies strictly inside the ball.
    ///
    /// A point inside is within ρ of the centre on every axis, so only the cells that
    /// meet the ball's bounding box (widened by [`BOX_SLACK`] against rounding) can hold
    /// one: with cells of 2ρ, usually 8 of them, where the 27 around the centre were
    /// searched before.
    fn ball_is_empty(&self, grid: &PointGrid, center: &[f64; 3], rho: f64, skip: [u32; 3]) -> bool {
        let r = rho * (1.0 + BOX_SLACK);
        let (lo, hi) = (center.map(|c| c - r), center.map(|c| c + r));
        !grid.any_in_box(&lo, &hi, |q, pq| Self::inside(q, pq, center, rho, skip))
    }

    /// [`Bpa::ball_is_empty`] for a ball through `pv`, looking only at `near` (every
    /// point within 2ρ of `pv`). A point strictly inside the ball (radius ρ·(1 − 5e-10),
    /// [`EMPTY_BALL_TOLERANCE`]) is nearer `pv` than 2ρ when the centre is within
    /// ρ·(1 + [`CENTRE_SLACK`]) of `pv`, as a ball through `pv` is up to rounding; a
    /// centre farther than that takes the grid, so the answer is the same either way.
    fn ball_is_empty_near(
        &self,
        near: &Near,
        pv: &[f64; 3],
        grid: &PointGrid,
        center: &[f64; 3],
        rho: f64,
        skip: [u32; 3],
    ) -> bool {
        let lim = rho * (1.0 + CENTRE_SLACK);
        if dist2(center, pv) > lim * lim {
            return self.ball_is_empty(grid, center, rho, skip);
        }
        !near
            .iter()
            .any(|(q, pq)| Self::inside(q, pq, center, rho, skip))
    }

    /// Tries to start a new triangle at unused vertex `v`.
    ///
    /// `near` and `scratch` are buffers. A ball through `v` lies within 2ρ of it, so the
    /// points within 2ρ (gathered once) are all its emptiness tests have to look at.
    fn seed(
        &mut self,
        v: u32,
        grid: &PointGrid,
        rho: f64,
        near: &mut Near,
        scratch: &mut Vec<(u64, u32)>,
    ) -> bool {
        let pv = self.p[v as usize];
        near.clear();
        grid.within(&pv, 2.0 * rho, near);
        // Each candidate's squared distance, computed once, as its bits: a sum of squares
        // is never negative nor -0, so the bits order as the distances do (`total_cmp`).
        scratch.clear();
        scratch.extend(
            near.iter()
                .filter(|&(q, _)| q != v && !self.used[q as usize])
                .map(|(q, pq)| (dist2(pq, &pv).to_bits(), q)),
        );
        // The SEED_NEIGHBOURS nearest, in order (a total order: ties by index).
        if scratch.len() > SEED_NEIGHBOURS {
            scratch.select_nth_unstable(SEED_NEIGHBOURS);
            scratch.truncate(SEED_NEIGHBOURS);
        }
        scratch.sort_unstable();
        for i in 0..scratch.len() {
            for j in i + 1..scratch.len() {
                let (mut a, mut b) = (scratch[i].1, scratch[j].1);
                let ab = cross(
                    &sub(&self.p[a as usize], &pv),
                    &sub(&self.p[b as usize], &pv),
                );
                let flip = dot(&ab, &self.n[v as usize]) < 0.0;
                if flip {
                    std::mem::swap(&mut a, &mut b);
                }
                // The normals are checked first: they reject most pairs (at least 46 M
                // of `map-row`'s 100 M), for a fraction of `ball_center`'s cost. Its
                // normal is `ab`, or `ab` negated where a and b were swapped (exactly: a
                // difference of the same two products, the other way round; a zero may
                // change sign, which no `> 0` test below can tell).
                let nrm = if flip { ab.map(|x| -x) } else { ab };
                if !self.normals_agree(&nrm, [v, a, b]) {
                    continue;
                }
                let (pa, pb) = (&self.p[a as usize], &self.p[b as usize]);
                let Some((c, _)) = ball_center(&pv, pa, pb, rho) else {
                    continue;
                };
                if !self.ball_is_empty_near(near, &pv, grid, &c, rho, [v, a, b]) {
                    continue;
                }
                if self.add_triangle([v, a, b], c) {
                    self.stats.seeds += 1;
                    return true;
                }
            }
        }
        false
    }

    fn expand(&mut self, grid: &PointGrid, rho: f64, near: &mut Near) {
        while let Some(id) = self.queue.pop_front() {
            if self.edges[id as usize].state == EdgeState::Active {
                self.pivot(id, grid, rho, near);
            }
        }
    }

    /// Re-activates boundary edges whose triangle admits an empty ball of radius `rho`.
    fn reactivate(&mut self, grid: &PointGrid, rho: f64) {
        for id in 0..self.edges.len() {
            let e = self.edges[id];
            if e.state != EdgeState::Boundary {
                continue;
            }
            let (ps, pt, po) = (
                &self.p[e.s as usize],
                &self.p[e.t as usize],
                &self.p[e.o as usize],
            );
            if let Some((c, _)) = ball_center(ps, pt, po, rho)
                && self.ball_is_empty(grid, &c, rho, [e.s, e.t, e.o])
            {
                let edge = &mut self.edges[id];
                edge.center = c;
                edge.state = EdgeState::Active;
                self.queue.push_back(id as u32);
            }
        }
    }
}

/// Reconstructs a triangle mesh from oriented points (`normals` unit length, pointing
/// out of the surface) with balls of the given radii (m, tried in ascending order).
/// Returns counter-clockwise triangles as indices into `points`, and counters.
pub fn ball_pivoting(
    points: &[[f64; 3]],
    normals: &[[f64; 3]],
    radii: &[f64],
) -> (Vec<[u32; 3]>, BpaStats) {
    let n = points.len().min(normals.len());
    let mut radii: Vec<f64> = radii.iter().copied().filter(|r| *r > 0.0).collect();
    radii.sort_by(f64::total_cmp);
    let mut bpa = Bpa {
        p: &points[..n],
        n: &normals[..n],
        edges: Vec::new(),
        directed: FxHashMap::default(),
        used: vec![false; n],
        front_deg: vec![0; n],
        queue: VecDeque::new(),
        triangles: Vec::new(),
        stats: BpaStats::default(),
    };
    // The grids of all radii are independent: build them in parallel.
    let grids: Vec<PointGrid> = radii
        .par_iter()
        .map(|r| PointGrid::new(&points[..n], 2.0 * r))
        .collect();
    let (mut near, mut scratch) = (Near::default(), Vec::new());
    for (pass, (&rho, grid)) in radii.iter().zip(&grids).enumerate() {
        if pass > 0 {
            bpa.reactivate(grid, rho);
            bpa.expand(grid, rho, &mut near);
        }
        for v in 0..n as u32 {
            if bpa.used[v as usize] {
                continue;
            }
            if bpa.seed(v, grid, rho, &mut near, &mut scratch) {
                bpa.expand(grid, rho, &mut near);
            }
        }
    }
    bpa.stats.boundary_edges = bpa
        .edges
        .iter()
        .filter(|e| e.state != EdgeState::Inner)
        .count();
    (bpa.triangles, bpa.stats)
}

/// Margin around a tile, in units of the largest ball radius.
pub const TILE_MARGIN_RADII: f64 = 5.0;

/// [`ball_pivoting`] in square xy tiles of edge `tile_m` (see the [module docs](self)):
/// the same triangles as one run over the whole cloud away from the tiles' sides, the
/// tiles meshed in parallel, the result in tile order whatever the thread count. A cloud
/// whose xy extent fits in one tile is meshed in one run, exactly as [`ball_pivoting`].
/// Points and normals are `f32` (the mapper's cloud); each tile is converted to `f64`.
pub fn ball_pivoting_tiled(
    points: &[[f32; 3]],
    normals: &[[f32; 3]],
    radii: &[f64],
    tile_m: f64,
) -> Vec<[u32; 3]> {
    let n = points.len().min(normals.len());
    let wide = |p: &[f32; 3]| p.map(f64::from);
    let finite: Vec<u32> = (0..n as u32)
        .filter(|&i| points[i as usize].iter().all(|c| c.is_finite()))
        .collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for &i in &finite {
        let p = wide(&points[i as usize]);
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let run = |idx: &[u32]| {
        let p: Vec<[f64; 3]> = idx.iter().map(|&i| wide(&points[i as usize])).collect();
        let q: Vec<[f64; 3]> = idx.iter().map(|&i| wide(&normals[i as usize])).collect();
        ball_pivoting(&p, &q, radii).0
    };
    let tile_m = if tile_m > 0.0 { tile_m } else { f64::INFINITY };
    let count = |k: usize| ((hi[k] - lo[k]) / tile_m).floor().max(0.0) as usize + 1;
    if finite.is_empty() || (count(0) == 1 && count(1) == 1) {
        let tris = run(&finite);
        return tris
            .into_iter()
            .map(|t| t.map(|i| finite[i as usize]))
            .collect();
    }
    let (nx, ny) = (count(0), count(1));
    let tile_of = |p: &[f64; 3]| {
        let t =
            |k: usize, m: usize| (((p[k] - lo[k]) / tile_m).floor().max(0.0) as usize).min(m - 1);
        (t(0, nx), t(1, ny))
    };
    // Points bucketed by tile (ascending index within a tile).
    let mut start = vec![0u32; nx * ny + 1];
    for &i in &finite {
        let (tx, ty) = tile_of(&wide(&points[i as usize]));
        start[ty * nx + tx + 1] += 1;
    }
    for t in 0..nx * ny {
        start[t + 1] += start[t];
    }
    let mut fill = start.clone();
    let mut bucketed = vec![0u32; finite.len()];
    for &i in &finite {
        let (tx, ty) = tile_of(&wide(&points[i as usize]));
        let slot = &mut fill[ty * nx + tx];
        bucketed[*slot as usize] = i;
        *slot += 1;
    }
    let margin = TILE_MARGIN_RADII * radii.iter().copied().fold(0.0, f64::max);
    let reach = (margin / tile_m).ceil() as usize;
    let occupied: Vec<usize> = (0..nx * ny).filter(|&t| start[t + 1] > start[t]).collect();
    let tiles: Vec<Vec<[u32; 3]>> = occupied
        .par_iter()
        .map(|&t| {
            let (tx, ty) = (t % nx, t / nx);
            let (x0, y0) = (
                lo[0] + tx as f64 * tile_m - margin,
                lo[1] + ty as f64 * tile_m - margin,
            );
            let (x1, y1) = (x0 + tile_m + 2.0 * margin, y0 + tile_m + 2.0 * margin);
            let mut idx = Vec::new();
            for uy in ty.saturating_sub(reach)..(ty + reach + 1).min(ny) {
                for ux in tx.saturating_sub(reach)..(tx + reach + 1).min(nx) {
                    let u = uy * nx + ux;
                    idx.extend(
                        bucketed[start[u] as usize..start[u + 1] as usize]
                            .iter()
                            .copied()
                            .filter(|&i| {
                                let p = wide(&points[i as usize]);
                                p[0] >= x0 && p[0] < x1 && p[1] >= y0 && p[1] < y1
                            }),
                    );
                }
            }
            // Global index order: the seeds are tried in the same order in every tile.
            idx.sort_unstable();
            run(&idx)
                .into_iter()
                .map(|tri| tri.map(|i| idx[i as usize]))
                .filter(|tri| {
                    let c = [0, 1, 2].map(|k| {
                        tri.iter()
                            .map(|&i| f64::from(points[i as usize][k]))
                            .sum::<f64>()
                            / 3.0
                    });
                    tile_of(&c) == (tx, ty)
                })
                .collect()
        })
        .collect();
    // Each tile's list is freed as it is copied.
    let mut out = Vec::with_capacity(tiles.iter().map(Vec::len).sum());
    for t in tiles {
        out.extend(t);
    }
    out
}

/// Edges of `triangles` that belong to exactly one of them (the mesh's boundary).
pub fn boundary_edges(triangles: &[[u32; 3]]) -> usize {
    let mut edges: Vec<u64> = triangles
        .iter()
        .flat_map(|t| {
            (0..3).map(move |k| {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                (u64::from(a.min(b)) << 32) | u64::from(a.max(b))
            })
        })
        .collect();
    edges.par_sort_unstable();
    edges
        .chunk_by(|a, b| a == b)
        .filter(|run| run.len() == 1)
        .count()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ball_center_is_at_rho_from_the_three_points_on_the_normal_side() {
        let a = [0.0, 0.0, 0.0];
        let b = [1.0, 0.0, 0.0];
        let c = [0.0, 1.0, 0.0];
        let (center, nrm) = ball_center(&a, &b, &c, 1.0).expect("fits");
        for p in [a, b, c] {
            assert!((dist2(&center, &p) - 1.0).abs() < 1e-12);
        }
        assert!(center[2] > 0.0 && nrm[2] > 0.0);
        assert!(
            ball_center(&a, &b, &c, 0.5).is_none(),
            "circumradius √2/2 > 0.5"
        );
    }

    #[test]
    fn a_flat_grid_becomes_a_strip_of_triangles() {
        // 5×5 points, spacing 1, normals up: 32 triangles, all facing up.
        let pts: Vec<[f64; 3]> = (0..25)
            .map(|i| {
                [
                    f64::from(i % 5),
                    f64::from(i / 5) + 0.01 * f64::from(i % 3),
                    0.0,
                ]
            })
            .collect();
        let nrm = vec![[0.0, 0.0, 1.0]; 25];
        let (tris, _) = ball_pivoting(&pts, &nrm, &[0.9]);
        assert_eq!(tris.len(), 32);
        for t in &tris {
            let (_, n) = ball_center(
                &pts[t[0] as usize],
                &pts[t[1] as usize],
                &pts[t[2] as usize],
                0.9,
            )
            .expect("every triangle has its ball");
            assert!(n[2] > 0.0);
        }
    }
}
