//! The default ray caster: a two-level, 4-wide bounding volume hierarchy.
//!
//! - **Build.** One bottom-level BVH per [`MeshGeometry`] and one top-level BVH over the
//!   instances. Both come from the same top-down binned-SAH builder ([`WideBvh::build`]):
//!   each wide node is made by repeatedly splitting its largest child cluster with a
//!   16-bin SAH sweep over the three axes until it has four children (or every cluster
//!   fits a leaf). Large subtrees are built in parallel with rayon; the structure only
//!   depends on the input, never on the thread count. Nodes store their four child boxes
//!   structure-of-arrays ([`Node4`], 112 bytes); bottom-level leaves hold up to eight
//!   triangles as one or two SoA blocks of four ([`Tri4`], 160 bytes).
//! - **Triangle test.** Rays are intersected in the mesh frame with origin-relative
//!   vertices `A = v0 - o`, `B = v1 - o`, `C = v2 - o`. Inside test: the signs of the
//!   edge functions `det(d, B, C)`, `det(d, C, A)`, `det(d, A, B)` (equal signs: hit),
//!   evaluated as `d·(B×(C - B))` etc., which stays accurate for small distant
//!   triangles. Whenever one is within its rounding-error bound of zero its sign is
//!   recomputed exactly (from plain `f64` where that is beyond its own bound, else
//!   floating-point expansions), so the predicate is exact and rays through shared
//!   edges and vertices of a closed mesh never leak. `t` comes from the
//!   triangle's own normal, `t = N·A / N·d` with `N = (v1 - v0)×(v2 - v0)`, the
//!   barycentrics from the edge functions (`w1/Σw`, `w2/Σw`). Ties in `t` go to the
//!   smallest `(instance, triangle)`. Every path (packet, single ray, the brute-force
//!   [`brute_force_ray`]) does the same arithmetic and returns the same bits.
//! - **Packets.** A packet (common origin, 16 groups of 4 consecutive lanes, 4 quads of 4
//!   groups) is projected onto the plane perpendicular to its dominant axis: every ray
//!   becomes a point `(a, b) = (d_i, d_j) / |d_k|`, every group and quad a small
//!   rectangle. A node's children project to rectangles too (from their boxes' corners;
//!   boxes straddling the origin's depth plane to half-open ones), so one SIMD pass culls
//!   the four children against the packet's rectangle (its frustum) and its farthest hit;
//!   surviving children are then tested against the quads (inner children) or the groups
//!   (leaf children), including each group's current farthest hit, and visited front to
//!   back. Leaves do the same per triangle, then run the edge-function test for each
//!   remaining (triangle, group) pair, four rays per SIMD operation. Instances transform
//!   the packet into the mesh frame (direction lanes by the inverse linear part, not
//!   renormalised). Packets whose rays do not share a dominant half-space, or spread too
//!   far, fall back to single rays. Inside an instance, a node that at most
//!   [`NARROW_AT`] groups still reach is finished ray by ray (Embree's hybrid traversal:
//!   in the canopy a packet's rays end on different leaves, and the packet would walk the
//!   union of their paths).
//! - **Single rays.** Classic 4-wide traversal: SIMD slab test of the four children,
//!   front-to-back order, four triangles per SIMD test at leaves.
//! - **Memory.** Nodes, triangle blocks (the vertices are copied) and 56 bytes per
//!   instance; no per-ray or per-packet allocation (traversal stacks are per thread).

// SIMD-style code indexes parallel arrays by lane, axis or group.
#![allow(clippy::needless_range_loop)]

use std::cell::RefCell;

use rayon::prelude::*;
use wide::{CmpEq, CmpGe, CmpGt, CmpLe, CmpLt, CmpNe, f32x4};

use super::trace::{Hit, PACKET_SIZE, RayCaster, RayPacket};
use super::{Affine3, Instance, MeshGeometry, TraceScene};

/// Child slot holding nothing.
const EMPTY: u32 = u32::MAX;
/// Flag of a leaf child; the low 31 bits are the leaf's payload (bottom level:
/// `first_block << 2 | (blocks - 1)`, see [`leaf_blocks`]; top level: instance index).
const LEAF: u32 = 1 << 31;
/// Most triangles in a bottom-level leaf (up to four [`Tri4`] blocks; a leaf's payload is
/// `first_block << 2 | (blocks - 1)`).
const MAX_LEAF_TRIS: usize = 8;
/// Wide-node depth from which the builder uses median splits, bounding the tree depth
/// (and so the fixed traversal stacks).
const MEDIAN_DEPTH: u32 = 32;
/// Traversal stack entries: enough for `3 · depth + 4` with depth at most
/// `MEDIAN_DEPTH + 32`.
const STACK: usize = 256;
/// SAH bins per axis.
const BINS: usize = 16;
/// Primitive count from which binning and recursion run in parallel.
const PAR_MIN: usize = 16 * 1024;
/// Relative slack of bottom-level culling tests (rounding of box and ray quantities).
const ETA_BLAS: f32 = 1.0 / (1u32 << 18) as f32;
/// Relative slack of top-level culling tests (also covers the instance transforms).
const ETA_TLAS: f32 = 1.0 / (1u32 << 12) as f32;
/// Relative inflation of top-level (instance) boxes.
const INFLATE_TLAS: f32 = 1.0 / (1u32 << 12) as f32;
/// Relative inflation of bottom-level boxes (the tests are already conservative).
const INFLATE_BLAS: f32 = 1.0 / (1u32 << 22) as f32;
/// Bound factor of the edge-function rounding error, `8u` with `u = 2^-24`: the edge
/// function `w = d·(X×(Y - X))` of origin-relative vertices `X, Y` is within
/// `ERR_W · |d|_∞ · |X|_1 · |Y - X|_1` of the exact `det(d, X, Y)`.
const ERR_W: f32 = 1.0 / (1u32 << 21) as f32;
/// Packets whose rays span more than this in the projected plane (ratio units) are cast
/// as single rays.
const MAX_PACKET_SPAN: f32 = 1.0;
/// Bottom-level inner nodes reached by at most this many groups of four rays of a packet
/// are traversed ray by ray ([`TwoLevelBvh::narrow_rays`]). `vinebench bench --only
/// tracer` chose it (docs/PERFORMANCE.md, issue #35): on the 10-row × 120 m vineyard
/// 0 (packets all the way down) gave 5.5–6.8 Mrays/s, 6 gave 6.8–8.8 and 8 to 12 about
/// the same, 16 (single rays below the instance's root) 4.8; on the 4-row world the
/// choices up to 12 stay within its noise.
const NARROW_AT: u32 = 6;
/// Groups of four rays in a packet.
const GROUPS: usize = PACKET_SIZE / 4;
/// Vectors of four groups.
const QUADS: usize = GROUPS / 4;

// ---------------------------------------------------------------------------------------
// Boxes and the generic builder
// ---------------------------------------------------------------------------------------

/// An axis-aligned box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Minimum corner.
    pub lo: [f32; 3],
    /// Maximum corner.
    pub hi: [f32; 3],
}

impl Aabb {
    /// The empty box (grows to anything).
    pub const EMPTY: Aabb = Aabb {
        lo: [f32::INFINITY; 3],
        hi: [f32::NEG_INFINITY; 3],
    };

    /// Grows the box to contain `o`.
    pub fn grow(&mut self, o: &Aabb) {
        for a in 0..3 {
            self.lo[a] = self.lo[a].min(o.lo[a]);
            self.hi[a] = self.hi[a].max(o.hi[a]);
        }
    }

    /// Grows the box to contain `p`.
    pub fn grow_point(&mut self, p: [f32; 3]) {
        for (a, &x) in p.iter().enumerate() {
            self.lo[a] = self.lo[a].min(x);
            self.hi[a] = self.hi[a].max(x);
        }
    }

    /// Whether the box contains nothing.
    pub fn is_empty(&self) -> bool {
        (0..3).any(|a| self.lo[a] > self.hi[a])
    }

    /// Half the surface area (0 for an empty box).
    pub fn half_area(&self) -> f32 {
        if self.is_empty() {
            return 0.0;
        }
        let d = [
            self.hi[0] - self.lo[0],
            self.hi[1] - self.lo[1],
            self.hi[2] - self.lo[2],
        ];
        d[0] * d[1] + d[1] * d[2] + d[2] * d[0]
    }

    /// The box grown on every side by `rel` times its largest coordinate magnitude plus
    /// its largest extent.
    fn inflated(&self, rel: f32) -> Aabb {
        if self.is_empty() {
            return *self;
        }
        let mut mag = 0.0f32;
        for a in 0..3 {
            mag = mag
                .max(self.lo[a].abs())
                .max(self.hi[a].abs())
                .max(self.hi[a] - self.lo[a]);
        }
        let pad = rel * mag + f32::MIN_POSITIVE;
        Aabb {
            lo: self.lo.map(|x| x - pad),
            hi: self.hi.map(|x| x + pad),
        }
    }
}

/// A primitive as the builder sees it.
#[derive(Clone, Copy, Debug)]
struct PrimRef {
    lo: [f32; 3],
    hi: [f32; 3],
    id: u32,
}

impl PrimRef {
    /// Twice the centroid along `a`.
    #[inline]
    fn c2(&self, a: usize) -> f32 {
        self.lo[a] + self.hi[a]
    }

    fn aabb(&self) -> Aabb {
        Aabb {
            lo: self.lo,
            hi: self.hi,
        }
    }
}

/// One wide node: bounds of the four children, structure-of-arrays
/// (`b = [lo_x, hi_x, lo_y, hi_y, lo_z, hi_z]`, lane = child), and the children: an
/// inner node index, `LEAF | payload`, or `EMPTY` (whose bounds are the inverted infinite
/// box, so every test rejects it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Node4 {
    b: [f32x4; 6],
    child: [u32; 4],
}

impl Node4 {
    const EMPTY: Node4 = Node4 {
        b: [
            f32x4::new([f32::INFINITY; 4]),
            f32x4::new([f32::NEG_INFINITY; 4]),
            f32x4::new([f32::INFINITY; 4]),
            f32x4::new([f32::NEG_INFINITY; 4]),
            f32x4::new([f32::INFINITY; 4]),
            f32x4::new([f32::NEG_INFINITY; 4]),
        ],
        child: [EMPTY; 4],
    };

    fn set_bounds(&mut self, slot: usize, b: &Aabb) {
        for a in 0..3 {
            self.b[2 * a].as_array_mut()[slot] = b.lo[a];
            self.b[2 * a + 1].as_array_mut()[slot] = b.hi[a];
        }
    }

    /// Bounds of child `slot`.
    #[cfg(test)]
    fn bounds(&self, slot: usize) -> Aabb {
        Aabb {
            lo: std::array::from_fn(|a| self.b[2 * a].as_array_ref()[slot]),
            hi: std::array::from_fn(|a| self.b[2 * a + 1].as_array_ref()[slot]),
        }
    }
}

/// A built wide BVH: nodes in depth-first order (root first), leaves as ranges of
/// `order` (the primitive ids permuted so each leaf's are contiguous). A leaf child's
/// payload is its index in `leaves`.
#[derive(Clone, Debug, Default)]
pub struct WideBvh {
    nodes: Vec<Node4>,
    leaves: Vec<[u32; 2]>,
    order: Vec<u32>,
}

/// A child during the build.
enum Kid {
    Leaf { start: u32, count: u32 },
    Inner(Box<WNode>),
}

/// A wide node during the build.
struct WNode {
    kids: Vec<(Aabb, Kid)>,
}

/// Per-axis SAH bins.
#[derive(Clone, Copy)]
struct Bins {
    b: [[Aabb; BINS]; 3],
    n: [[u32; BINS]; 3],
}

impl Bins {
    const EMPTY: Bins = Bins {
        b: [[Aabb::EMPTY; BINS]; 3],
        n: [[0; BINS]; 3],
    };

    fn merge(mut self, o: Bins) -> Bins {
        for a in 0..3 {
            for k in 0..BINS {
                self.b[a][k].grow(&o.b[a][k]);
                self.n[a][k] += o.n[a][k];
            }
        }
        self
    }
}

/// Bin of a doubled centroid coordinate (`scale = BINS / extent`).
#[inline]
fn bin_of(c2: f32, lo: f32, scale: f32) -> usize {
    // `as` saturates (negative and NaN give 0).
    (((c2 - lo) * scale) as usize).min(BINS - 1)
}

/// Bounds of the primitives and of their doubled centroids.
fn ref_bounds(refs: &[PrimRef]) -> (Aabb, Aabb) {
    let seq = |refs: &[PrimRef]| {
        let mut b = Aabb::EMPTY;
        let mut c = Aabb::EMPTY;
        for r in refs {
            b.grow(&r.aabb());
            c.grow_point([r.c2(0), r.c2(1), r.c2(2)]);
        }
        (b, c)
    };
    if refs.len() < PAR_MIN {
        return seq(refs);
    }
    refs.par_chunks(PAR_MIN / 2).map(seq).reduce(
        || (Aabb::EMPTY, Aabb::EMPTY),
        |(mut b0, mut c0), (b1, c1)| {
            b0.grow(&b1);
            c0.grow(&c1);
            (b0, c0)
        },
    )
}

/// Splits `refs` in two (reordering it) and returns the split index and the two halves'
/// bounds. Binned SAH over the three axes; object median at depth `>= MEDIAN_DEPTH`;
/// middle by index when all centroids coincide.
fn split(refs: &mut [PrimRef], depth: u32) -> (usize, Aabb, Aabb) {
    let n = refs.len();
    let (_, cb) = ref_bounds(refs);
    let ext = [
        cb.hi[0] - cb.lo[0],
        cb.hi[1] - cb.lo[1],
        cb.hi[2] - cb.lo[2],
    ];
    let mut axis = 0;
    for a in 1..3 {
        if ext[a] > ext[axis] {
            axis = a;
        }
    }
    let halves = |refs: &[PrimRef], m: usize| {
        let (l, r) = refs.split_at(m);
        (m, ref_bounds(l).0, ref_bounds(r).0)
    };
    // (Bounds are finite: the builder only takes finite boxes.)
    if ext[axis] <= 0.0 {
        return halves(refs, n / 2);
    }
    if depth >= MEDIAN_DEPTH {
        refs.select_nth_unstable_by(n / 2, |p, q| {
            p.c2(axis).total_cmp(&q.c2(axis)).then(p.id.cmp(&q.id))
        });
        return halves(refs, n / 2);
    }
    let scale: [f32; 3] = std::array::from_fn(|a| {
        if ext[a] > 0.0 {
            BINS as f32 / ext[a]
        } else {
            0.0
        }
    });
    let bin_seq = |refs: &[PrimRef]| {
        let mut bins = Bins::EMPTY;
        for r in refs {
            for a in 0..3 {
                let k = bin_of(r.c2(a), cb.lo[a], scale[a]);
                bins.b[a][k].grow(&r.aabb());
                bins.n[a][k] += 1;
            }
        }
        bins
    };
    let bins = if n < PAR_MIN {
        bin_seq(refs)
    } else {
        refs.par_chunks(PAR_MIN / 2)
            .map(bin_seq)
            .reduce(|| Bins::EMPTY, Bins::merge)
    };
    // Sweep: cost of putting bins 0..=k left.
    let mut best: Option<(f32, usize, usize)> = None;
    for a in 0..3 {
        if ext[a] <= 0.0 {
            continue;
        }
        let mut right_area = [0.0f32; BINS];
        let mut right_n = [0u32; BINS];
        let mut acc = Aabb::EMPTY;
        let mut cnt = 0;
        for k in (1..BINS).rev() {
            acc.grow(&bins.b[a][k]);
            cnt += bins.n[a][k];
            right_area[k] = acc.half_area();
            right_n[k] = cnt;
        }
        let mut acc = Aabb::EMPTY;
        let mut cnt = 0;
        for k in 0..BINS - 1 {
            acc.grow(&bins.b[a][k]);
            cnt += bins.n[a][k];
            if cnt == 0 || right_n[k + 1] == 0 {
                continue;
            }
            let cost = acc.half_area() * cnt as f32 + right_area[k + 1] * right_n[k + 1] as f32;
            if best.is_none_or(|(c, _, _)| cost < c) {
                best = Some((cost, a, k));
            }
        }
    }
    let Some((_, a, k)) = best else {
        return halves(refs, n / 2);
    };
    // Partition (deterministic Hoare-style swaps).
    let (mut l, mut r) = (0, n);
    while l < r {
        if bin_of(refs[l].c2(a), cb.lo[a], scale[a]) <= k {
            l += 1;
        } else {
            r -= 1;
            refs.swap(l, r);
        }
    }
    let mut lb = Aabb::EMPTY;
    let mut rb = Aabb::EMPTY;
    for q in 0..BINS {
        if q <= k {
            lb.grow(&bins.b[a][q]);
        } else {
            rb.grow(&bins.b[a][q]);
        }
    }
    (l, lb, rb)
}

/// Builds the wide node over `refs` (which start at `offset` in the whole array).
fn build_wide(
    refs: &mut [PrimRef],
    offset: usize,
    bounds: Aabb,
    depth: u32,
    max_leaf: usize,
) -> WNode {
    // Clusters as (start, end, bounds) within `refs`, in spatial order.
    let mut cl: Vec<(usize, usize, Aabb)> = Vec::with_capacity(4);
    cl.push((0, refs.len(), bounds));
    while cl.len() < 4 {
        let mut pick: Option<usize> = None;
        for (i, c) in cl.iter().enumerate() {
            if c.1 - c.0 > max_leaf && pick.is_none_or(|p| c.2.half_area() > cl[p].2.half_area()) {
                pick = Some(i);
            }
        }
        let Some(i) = pick else { break };
        let (s, e, _) = cl[i];
        let (m, lb, rb) = split(&mut refs[s..e], depth);
        cl[i] = (s, s + m, lb);
        cl.insert(i + 1, (s + m, e, rb));
    }
    // Children: leaves directly, inner ones recursively (in parallel when large).
    let mut jobs: Vec<(usize, &mut [PrimRef], Aabb)> = Vec::new();
    let mut kids: Vec<Option<(Aabb, Kid)>> = Vec::with_capacity(cl.len());
    let mut rest = refs;
    let mut consumed = 0;
    for (i, &(s, e, b)) in cl.iter().enumerate() {
        let (head, tail) = std::mem::take(&mut rest).split_at_mut(e - consumed);
        rest = tail;
        consumed = e;
        if e - s <= max_leaf {
            kids.push(Some((
                b,
                Kid::Leaf {
                    start: (offset + s) as u32,
                    count: (e - s) as u32,
                },
            )));
        } else {
            kids.push(None);
            jobs.push((i, head, b));
        }
    }
    let total: usize = jobs.iter().map(|j| j.1.len()).sum();
    let build_job = |(i, sub, b): (usize, &mut [PrimRef], Aabb)| {
        let s = cl[i].0;
        (i, b, build_wide(sub, offset + s, b, depth + 1, max_leaf))
    };
    let built: Vec<(usize, Aabb, WNode)> = if total >= PAR_MIN && jobs.len() > 1 {
        jobs.into_par_iter().map(build_job).collect()
    } else {
        jobs.into_iter().map(build_job).collect()
    };
    for (i, b, w) in built {
        kids[i] = Some((b, Kid::Inner(Box::new(w))));
    }
    WNode {
        kids: kids.into_iter().flatten().collect(),
    }
}

impl WideBvh {
    /// Builds a BVH over primitive boxes with at most `max_leaf` primitives per leaf;
    /// child boxes are inflated by `inflate` times their coordinate magnitude. Empty
    /// boxes are left out. Deterministic: the same boxes give the same structure.
    pub fn build(prims: &[Aabb], max_leaf: usize, inflate: f32) -> WideBvh {
        let mut refs: Vec<PrimRef> = prims
            .iter()
            .enumerate()
            .filter(|(_, b)| !b.is_empty() && b.lo.iter().chain(&b.hi).all(|x| x.is_finite()))
            .map(|(i, b)| PrimRef {
                lo: b.lo,
                hi: b.hi,
                id: i as u32,
            })
            .collect();
        if refs.is_empty() {
            return WideBvh::default();
        }
        assert!(
            refs.len() < LEAF as usize,
            "too many primitives for one BVH"
        );
        let (bounds, _) = ref_bounds(&refs);
        let root = build_wide(&mut refs, 0, bounds, 0, max_leaf.max(1));
        let mut bvh = WideBvh {
            nodes: Vec::new(),
            leaves: Vec::new(),
            order: refs.iter().map(|r| r.id).collect(),
        };
        bvh.flatten(&root, inflate);
        bvh.nodes.shrink_to_fit();
        bvh.leaves.shrink_to_fit();
        bvh
    }

    fn flatten(&mut self, w: &WNode, inflate: f32) -> u32 {
        let idx = self.nodes.len();
        self.nodes.push(Node4::EMPTY);
        let mut node = Node4::EMPTY;
        for (slot, (b, kid)) in w.kids.iter().enumerate() {
            node.set_bounds(slot, &b.inflated(inflate));
            node.child[slot] = match kid {
                Kid::Leaf { start, count } => {
                    self.leaves.push([*start, *count]);
                    LEAF | (self.leaves.len() - 1) as u32
                }
                Kid::Inner(inner) => self.flatten(inner, inflate),
            };
        }
        self.nodes[idx] = node;
        idx as u32
    }

    /// Primitive ids of leaf `leaf`.
    fn leaf_prims(&self, leaf: usize) -> &[u32] {
        let [s, c] = self.leaves[leaf];
        &self.order[s as usize..(s + c) as usize]
    }
}

// ---------------------------------------------------------------------------------------
// Meshes and instances
// ---------------------------------------------------------------------------------------

/// Four triangles, structure-of-arrays: `v = [v0x, v0y, v0z, v1x, …, v2z]` (lane =
/// triangle), `prim` their indices in the mesh (`u32::MAX` and NaN vertices for unused
/// lanes).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tri4 {
    v: [f32x4; 9],
    prim: [u32; 4],
}

impl Tri4 {
    /// Vertices of lane `l`.
    fn lane(&self, l: usize) -> [[f32; 3]; 3] {
        std::array::from_fn(|k| std::array::from_fn(|a| self.v[3 * k + a].as_array_ref()[l]))
    }

    /// Bit mask of used lanes.
    fn valid(&self) -> u32 {
        (0..4).fold(0, |m, l| m | (u32::from(self.prim[l] != u32::MAX) << l))
    }
}

/// The triangle blocks of a bottom-level leaf payload.
#[inline(always)]
fn leaf_blocks(tris: &[Tri4], payload: u32) -> &[Tri4] {
    let first = (payload >> 2) as usize;
    &tris[first..first + (payload & 3) as usize + 1]
}

/// The bottom-level BVH of one mesh.
#[derive(Clone, Debug)]
struct MeshBvh {
    nodes: Vec<Node4>,
    tris: Vec<Tri4>,
    bounds: Aabb,
}

impl MeshBvh {
    fn build(mesh: &MeshGeometry) -> MeshBvh {
        let pos = &mesh.positions;
        let tri_verts = |t: &[u32; 3]| -> Option<[[f32; 3]; 3]> {
            let v = [
                *pos.get(t[0] as usize)?,
                *pos.get(t[1] as usize)?,
                *pos.get(t[2] as usize)?,
            ];
            v.iter().flatten().all(|x| x.is_finite()).then_some(v)
        };
        let boxes: Vec<Aabb> = mesh
            .indices
            .iter()
            .map(|t| match tri_verts(t) {
                Some(v) => {
                    let mut b = Aabb::EMPTY;
                    v.iter().for_each(|p| b.grow_point(*p));
                    b
                }
                None => Aabb::EMPTY,
            })
            .collect();
        let bvh = WideBvh::build(&boxes, MAX_LEAF_TRIS, INFLATE_BLAS);
        let mut bounds = Aabb::EMPTY;
        boxes.iter().for_each(|b| bounds.grow(b));
        let mut tris = Vec::new();
        let mut payload = Vec::with_capacity(bvh.leaves.len());
        for l in 0..bvh.leaves.len() {
            let prims = bvh.leaf_prims(l);
            assert!(tris.len() < 1 << 29, "too many triangle blocks in one mesh");
            payload.push((tris.len() as u32) << 2 | (prims.len().div_ceil(4) as u32 - 1));
            for chunk in prims.chunks(4) {
                let mut blk = Tri4 {
                    v: [f32x4::splat(f32::NAN); 9],
                    prim: [u32::MAX; 4],
                };
                for (lane, &p) in chunk.iter().enumerate() {
                    blk.prim[lane] = p;
                    if let Some(v) = tri_verts(&mesh.indices[p as usize]) {
                        for k in 0..3 {
                            for a in 0..3 {
                                blk.v[3 * k + a].as_array_mut()[lane] = v[k][a];
                            }
                        }
                    }
                }
                tris.push(blk);
            }
        }
        let mut nodes = bvh.nodes;
        for n in &mut nodes {
            for c in &mut n.child {
                if *c != EMPTY && *c & LEAF != 0 {
                    *c = LEAF | payload[(*c & !LEAF) as usize];
                }
            }
        }
        tris.shrink_to_fit();
        MeshBvh {
            nodes,
            tris,
            bounds,
        }
    }
}

/// How an instance maps rays into its mesh frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum XformKind {
    /// `mesh_from_scene` is the identity: rays are used as they are.
    Identity,
    /// Only a translation: directions are used as they are.
    Translation,
    /// A general affine map.
    General,
}

/// An instance as the caster stores it.
#[derive(Clone, Copy, Debug)]
struct InstanceData {
    /// Mesh frame from the scene frame.
    inv: Affine3,
    kind: XformKind,
    mesh: u32,
}

impl InstanceData {
    /// The ray origin in the mesh frame.
    #[inline]
    fn origin(&self, o: [f32; 3]) -> [f32; 3] {
        match self.kind {
            XformKind::Identity => o,
            XformKind::Translation | XformKind::General => xform_point(&self.inv, o),
        }
    }

    /// A ray direction in the mesh frame.
    #[inline]
    fn dir(&self, d: [f32; 3]) -> [f32; 3] {
        match self.kind {
            XformKind::Identity | XformKind::Translation => d,
            XformKind::General => xform_vec(&self.inv, d),
        }
    }
}

/// `m·p + t` with a fixed operation order (shared by every path).
#[inline]
fn xform_point(m: &Affine3, p: [f32; 3]) -> [f32; 3] {
    let r = &m.rows;
    std::array::from_fn(|i| r[i][0] * p[0] + r[i][1] * p[1] + r[i][2] * p[2] + r[i][3])
}

/// `m·v` with a fixed operation order (shared by every path).
#[inline]
fn xform_vec(m: &Affine3, v: [f32; 3]) -> [f32; 3] {
    let r = &m.rows;
    std::array::from_fn(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2])
}

/// The default [`RayCaster`]: per-mesh 4-wide BVHs under a 4-wide BVH over instances
/// (see the [module documentation](self)).
#[derive(Clone, Debug)]
pub struct TwoLevelBvh {
    meshes: Vec<MeshBvh>,
    /// One per scene instance; `None` for instances that can never be hit (unknown mesh,
    /// singular transform).
    inst: Vec<Option<InstanceData>>,
    tlas: Vec<Node4>,
}

/// Build statistics of a [`TwoLevelBvh`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BvhStats {
    /// Bottom-level wide nodes, all meshes.
    pub blas_nodes: usize,
    /// Bottom-level triangle blocks (of four), all meshes.
    pub blas_blocks: usize,
    /// Triangles stored in the leaves (valid ones).
    pub triangles: usize,
    /// Top-level wide nodes.
    pub tlas_nodes: usize,
    /// Instances in the top level.
    pub instances: usize,
}

impl TwoLevelBvh {
    /// Builds the acceleration structure of a scene.
    pub fn build(scene: &TraceScene) -> TwoLevelBvh {
        let meshes: Vec<MeshBvh> = scene.meshes.par_iter().map(MeshBvh::build).collect();
        let inst: Vec<Option<InstanceData>> = scene
            .instances
            .iter()
            .map(|i| {
                instance_data(
                    i,
                    meshes
                        .get(i.mesh as usize)
                        .is_some_and(|m| !m.nodes.is_empty()),
                )
            })
            .collect();
        let boxes: Vec<Aabb> = scene
            .instances
            .iter()
            .zip(&inst)
            .map(|(i, d)| match d {
                None => Aabb::EMPTY,
                Some(d) => scene_box(&i.scene_from_mesh, &meshes[d.mesh as usize].bounds),
            })
            .collect();
        let tlas = WideBvh::build(&boxes, 1, INFLATE_TLAS);
        let mut nodes = tlas.nodes.clone();
        for n in &mut nodes {
            for c in &mut n.child {
                if *c != EMPTY && *c & LEAF != 0 {
                    let leaf = (*c & !LEAF) as usize;
                    *c = LEAF | tlas.leaf_prims(leaf)[0];
                }
            }
        }
        TwoLevelBvh {
            meshes,
            inst,
            tlas: nodes,
        }
    }

    /// Node and leaf counts.
    pub fn stats(&self) -> BvhStats {
        BvhStats {
            blas_nodes: self.meshes.iter().map(|m| m.nodes.len()).sum(),
            blas_blocks: self.meshes.iter().map(|m| m.tris.len()).sum(),
            triangles: self
                .meshes
                .iter()
                .flat_map(|m| &m.tris)
                .map(|t| t.valid().count_ones() as usize)
                .sum(),
            tlas_nodes: self.tlas.len(),
            instances: self.inst.iter().flatten().count(),
        }
    }
}

/// How the caster sees an instance: `None` when it can never be hit (`mesh_ok` false:
/// unknown or empty mesh; singular or non-finite transform).
fn instance_data(i: &Instance, mesh_ok: bool) -> Option<InstanceData> {
    if !mesh_ok {
        return None;
    }
    let inv = i.scene_from_mesh.inverse()?;
    let r = &inv.rows;
    if !r.iter().flatten().all(|x| x.is_finite()) {
        return None;
    }
    let linear_id = (0..3).all(|a| (0..3).all(|b| r[a][b] == if a == b { 1.0 } else { 0.0 }));
    let kind = if linear_id && (0..3).all(|a| r[a][3] == 0.0) {
        XformKind::Identity
    } else if linear_id {
        XformKind::Translation
    } else {
        XformKind::General
    };
    Some(InstanceData {
        inv,
        kind,
        mesh: i.mesh,
    })
}

/// First hit of a ray by testing every triangle of every instance: the reference the
/// BVH traversals reproduce bit for bit (same transforms, triangle test and tie rule).
/// Slow; for tests and checks.
pub fn brute_force_ray(
    scene: &TraceScene,
    o: [f32; 3],
    d: [f32; 3],
    t_min: f32,
    t_max: f32,
) -> Hit {
    let Some(t_max) = ray_range(t_min, t_max) else {
        return Hit::MISS;
    };
    if !o.iter().chain(&d).all(|x| x.is_finite()) {
        return Hit::MISS;
    }
    let mut best = RayBest::new(t_max);
    for (ii, inst) in scene.instances.iter().enumerate() {
        let Some(mesh) = scene.meshes.get(inst.mesh as usize) else {
            continue;
        };
        let Some(id) = instance_data(inst, true) else {
            continue;
        };
        let (om, dm) = (id.origin(o), id.dir(d));
        let pos = &mesh.positions;
        for (p, t) in mesh.indices.iter().enumerate() {
            let (Some(&a), Some(&b), Some(&c)) = (
                pos.get(t[0] as usize),
                pos.get(t[1] as usize),
                pos.get(t[2] as usize),
            ) else {
                continue;
            };
            if !a.iter().chain(&b).chain(&c).all(|x| x.is_finite()) {
                continue;
            }
            let Some((t, u, v)) = eval_tri(&[a, b, c], om, dm) else {
                continue;
            };
            if t >= t_min && t <= best.t && best.accepts(t, ii as u32, p as u32) {
                best = RayBest {
                    t,
                    inst: ii as u32,
                    prim: p as u32,
                    u,
                    v,
                };
            }
        }
    }
    best.hit()
}

/// Scene-frame box of a mesh-frame box (its eight corners mapped in `f64`).
fn scene_box(m: &Affine3, b: &Aabb) -> Aabb {
    let mut out = Aabb::EMPTY;
    for c in 0..8 {
        let p: [f64; 3] =
            std::array::from_fn(|a| f64::from(if c >> a & 1 == 0 { b.lo[a] } else { b.hi[a] }));
        let q: [f32; 3] = std::array::from_fn(|i| {
            let r = &m.rows[i];
            (f64::from(r[0]) * p[0]
                + f64::from(r[1]) * p[1]
                + f64::from(r[2]) * p[2]
                + f64::from(r[3])) as f32
        });
        out.grow_point(q);
    }
    out
}

// ---------------------------------------------------------------------------------------
// The triangle test
// ---------------------------------------------------------------------------------------

#[inline]
fn sub3(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline]
fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[inline]
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
fn norm1(a: [f32; 3]) -> f32 {
    a[0].abs() + a[1].abs() + a[2].abs()
}

#[inline]
fn norm_inf(a: [f32; 3]) -> f32 {
    a[0].abs().max(a[1].abs()).max(a[2].abs())
}

/// Edge normals `X×(Y - X)` of the edges `b→c`, `c→a`, `a→b` of a triangle with
/// origin-relative vertices `a, b, c`, and the factor bounding their rounding error (times
/// `|d|_∞`, see [`ERR_W`]).
#[inline]
fn edge_normals(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> ([[f32; 3]; 3], f32) {
    let (ebc, eca, eab) = (sub3(c, b), sub3(a, c), sub3(b, a));
    let n = [cross(b, ebc), cross(c, eca), cross(a, eab)];
    let err = ERR_W
        * (norm1(b) * norm1(ebc))
            .max(norm1(c) * norm1(eca))
            .max(norm1(a) * norm1(eab));
    (n, err)
}

/// One ray (origin `o`, direction `d`, mesh frame) against one triangle `v`: the ray
/// parameter where its line crosses the triangle and the barycentrics of the second and
/// third vertex, or `None`. Inside test: the signs of `det(d, X, Y)` for the edges `X→Y`
/// of the origin-relative vertices, evaluated as `w = d·(X×(Y - X))` (accurate for small
/// distant triangles) and recomputed exactly when within the rounding-error bound of
/// zero, so the test is exact: shared edges and vertices never leak. `t` comes from the
/// triangle's own normal, `t = N·(v0 - o) / N·d` with `N = (v1 - v0)×(v2 - v0)`; the
/// barycentrics are `w / Σw`. The reference every SIMD path reproduces bit for bit.
pub(crate) fn eval_tri(v: &[[f32; 3]; 3], o: [f32; 3], d: [f32; 3]) -> Option<(f32, f32, f32)> {
    let (a, b, c) = (sub3(v[0], o), sub3(v[1], o), sub3(v[2], o));
    let (n, err) = edge_normals(a, b, c);
    let mut w = [dot(d, n[0]), dot(d, n[1]), dot(d, n[2])];
    let bound = err * norm_inf(d);
    let edges = [(b, c), (c, a), (a, b)];
    for (wi, (x, y)) in w.iter_mut().zip(edges) {
        // Beyond its rounding bound an edge function's sign is already the exact one.
        if wi.abs().partial_cmp(&bound) != Some(std::cmp::Ordering::Greater) {
            *wi = exact_sign(*wi, d, x, y);
        }
    }
    let inside =
        (w[0] >= 0.0 && w[1] >= 0.0 && w[2] >= 0.0) || (w[0] <= 0.0 && w[1] <= 0.0 && w[2] <= 0.0);
    let sum = w[0] + w[1] + w[2];
    let nrm = cross(sub3(v[1], v[0]), sub3(v[2], v[0]));
    let den = dot(d, nrm);
    if !inside || den == 0.0 || sum == 0.0 {
        return None;
    }
    let inv = 1.0 / sum;
    Some((dot(nrm, a) / den, w[1] * inv, w[2] * inv))
}

/// `fix_sign(w, orient_exact(d, x, y))`: `w` if its sign is that of `det(d, x, y)`, else
/// the exact value rounded. The sign is first taken from a plain `f64` evaluation where
/// that is beyond its rounding bound (products of two `f32` are exact in `f64`; the
/// difference, the third factor and the sum round by at most `2⁻⁵³` each, so the
/// computed value is within `4·2⁻⁵³·Σ|d_c|(|x_a y_b| + |x_b y_a|)` of the exact one and
/// `2⁻⁵⁰` of that sum is a safe margin); only near zero, or where `w`'s sign is wrong and
/// the value is needed, the floating-point expansion computes it.
fn exact_sign(w: f32, d: [f32; 3], x: [f32; 3], y: [f32; 3]) -> f32 {
    let (approx, size) = orient_f64(d, x, y);
    if approx.abs() > size * F64_SIGN_MARGIN && sign_of(approx) == sign_of(f64::from(w)) {
        return w;
    }
    fix_sign(w, orient_exact(d, x, y))
}

/// Relative margin beyond which [`orient_f64`]'s value has the exact sign.
const F64_SIGN_MARGIN: f64 = 1.0 / (1u64 << 50) as f64;

/// `d·(x×y)` in plain `f64`, and `Σ|d_c|(|x_a y_b| + |x_b y_a|)`, which bounds its
/// rounding error (see [`exact_sign`]).
fn orient_f64(d: [f32; 3], x: [f32; 3], y: [f32; 3]) -> (f64, f64) {
    let (df, xf, yf) = (d.map(f64::from), x.map(f64::from), y.map(f64::from));
    let (mut value, mut size) = (0.0f64, 0.0f64);
    for (c, a, b) in [(0, 1, 2), (1, 2, 0), (2, 0, 1)] {
        let (p, q) = (xf[a] * yf[b], xf[b] * yf[a]);
        value += df[c] * (p - q);
        size += df[c].abs() * (p.abs() + q.abs());
    }
    (value, size)
}

/// −1, 0 or 1 by the sign of `x` (0 for zeros and NaN).
fn sign_of(x: f64) -> i32 {
    (x > 0.0) as i32 - (x < 0.0) as i32
}

/// `w` if its sign is right, else the exact value (rounded, never rounded to zero).
fn fix_sign(w: f32, exact: f64) -> f32 {
    if sign_of(f64::from(w)) == sign_of(exact) || exact.is_nan() {
        w
    } else if exact == 0.0 {
        0.0
    } else {
        let r = exact as f32;
        if r == 0.0 {
            f32::from_bits(1).copysign(exact as f32)
        } else {
            r
        }
    }
}

/// Error-free product `a·b = p + e` (Dekker).
#[inline]
fn two_prod(a: f64, b: f64) -> (f64, f64) {
    const SPLIT: f64 = 134_217_729.0; // 2^27 + 1
    let p = a * b;
    let split = |x: f64| {
        let c = SPLIT * x;
        let hi = c - (c - x);
        (hi, x - hi)
    };
    let (ah, al) = split(a);
    let (bh, bl) = split(b);
    let e = ((ah * bh - p) + ah * bl + al * bh) + al * bl;
    (p, e)
}

/// Error-free sum `a + b = s + e` (Knuth).
#[inline]
fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let bb = s - a;
    (s, (a - (s - bb)) + (b - bb))
}

/// `d·(x×y)` with its exact sign (the value is the exact one rounded to `f64`).
fn orient_exact(d: [f32; 3], x: [f32; 3], y: [f32; 3]) -> f64 {
    let (d, x, y) = (d.map(f64::from), x.map(f64::from), y.map(f64::from));
    // Products of two f32 are exact in f64; the third factor goes through two_prod.
    let mut terms = [0.0f64; 12];
    for (k, (c, a, b)) in [(0, 1, 2), (1, 2, 0), (2, 0, 1)].into_iter().enumerate() {
        let (p0, e0) = two_prod(d[c], x[a] * y[b]);
        let (p1, e1) = two_prod(d[c], x[b] * y[a]);
        terms[4 * k..4 * k + 4].copy_from_slice(&[p0, e0, -p1, -e1]);
    }
    // Shewchuk's grow-expansion: nonoverlapping components by increasing magnitude.
    let mut e = [0.0f64; 13];
    let mut len = 0;
    for &t in &terms {
        let mut q = t;
        for item in e.iter_mut().take(len) {
            let (s, h) = two_sum(q, *item);
            *item = h;
            q = s;
        }
        e[len] = q;
        len += 1;
    }
    e[..len].iter().sum()
}

// ---------------------------------------------------------------------------------------
// Single rays
// ---------------------------------------------------------------------------------------

/// The far end of a ray's `[t_min, t_max]` range, clamped to `f32::MAX` (a hit at `∞` is
/// no hit), or `None` for an empty or NaN range.
#[inline]
fn ray_range(t_min: f32, t_max: f32) -> Option<f32> {
    (t_min <= t_max).then_some(t_max.min(f32::MAX))
}

/// The best hit of one ray so far.
#[derive(Clone, Copy, Debug)]
struct RayBest {
    t: f32,
    inst: u32,
    prim: u32,
    u: f32,
    v: f32,
}

impl RayBest {
    fn new(t_max: f32) -> RayBest {
        RayBest {
            t: t_max,
            inst: Hit::NONE,
            prim: u32::MAX,
            u: 0.0,
            v: 0.0,
        }
    }

    /// The hit record ([`Hit::MISS`] when nothing was hit).
    fn hit(&self) -> Hit {
        if self.inst == Hit::NONE {
            Hit::MISS
        } else {
            Hit {
                t: self.t,
                instance: self.inst,
                prim: self.prim,
                u: self.u,
                v: self.v,
            }
        }
    }

    /// Whether a hit at `t` on `(inst, prim)` replaces this one (closest, ties to the
    /// smallest instance then triangle).
    #[inline]
    fn accepts(&self, t: f32, inst: u32, prim: u32) -> bool {
        t < self.t || (t == self.t && (inst, prim) < (self.inst, self.prim))
    }
}

/// A ray prepared for slab tests against [`Node4`]s.
struct RayPre {
    o: [f32x4; 3],
    inv: [f32x4; 3],
    near: [usize; 3],
    far: [usize; 3],
    lo: f32x4,
    hi: f32x4,
}

impl RayPre {
    fn new(o: [f32; 3], d: [f32; 3], eta: f32) -> RayPre {
        let mut near = [0; 3];
        let mut far = [0; 3];
        let inv = std::array::from_fn(|a| {
            let da = if d[a].abs() < 1e-30 {
                1e-30f32.copysign(d[a])
            } else {
                d[a]
            };
            let neg = usize::from(da < 0.0);
            near[a] = 2 * a + neg;
            far[a] = 2 * a + 1 - neg;
            f32x4::splat(1.0 / da)
        });
        RayPre {
            o: o.map(f32x4::splat),
            inv,
            near,
            far,
            lo: f32x4::splat(1.0 - eta),
            hi: f32x4::splat(1.0 + eta),
        }
    }
}

/// Front-to-back traversal of one ray from node code `root` (`0`: the whole tree; an
/// inner node index or `LEAF | payload`: that subtree) with `stack` (at least [`STACK`]
/// entries); `leaf(payload, best, rest)` tests a leaf, `rest` being the unused part of
/// the stack.
fn ray_traverse<F: FnMut(u32, &mut RayBest, &mut [(u32, f32)])>(
    nodes: &[Node4],
    root: u32,
    r: &RayPre,
    t_min: f32,
    best: &mut RayBest,
    stack: &mut [(u32, f32)],
    mut leaf: F,
) {
    if nodes.is_empty() {
        return;
    }
    let mut sp = 1;
    stack[0] = (root, f32::NEG_INFINITY);
    let tmin4 = f32x4::splat(t_min);
    while sp > 0 {
        sp -= 1;
        let (code, tn) = stack[sp];
        if tn > best.t {
            continue;
        }
        if code & LEAF != 0 {
            leaf(code & !LEAF, best, &mut stack[sp..]);
            continue;
        }
        let n = &nodes[code as usize];
        let tnx = (n.b[r.near[0]] - r.o[0]) * r.inv[0];
        let tny = (n.b[r.near[1]] - r.o[1]) * r.inv[1];
        let tnz = (n.b[r.near[2]] - r.o[2]) * r.inv[2];
        let tfx = (n.b[r.far[0]] - r.o[0]) * r.inv[0];
        let tfy = (n.b[r.far[1]] - r.o[1]) * r.inv[1];
        let tfz = (n.b[r.far[2]] - r.o[2]) * r.inv[2];
        let tn = tnx.fast_max(tny).fast_max(tnz).fast_max(tmin4);
        let tf = tfx
            .fast_min(tfy)
            .fast_min(tfz)
            .fast_min(f32x4::splat(best.t));
        let tn = (tn * r.lo).fast_min(tn * r.hi);
        let tf = (tf * r.lo).fast_max(tf * r.hi);
        let m = tn.cmp_le(tf).move_mask() as u32;
        if m == 0 {
            continue;
        }
        let keys = tn.to_array();
        // Farthest first so the nearest child is popped next.
        let mut ent = [(0.0f32, 0u32); 4];
        let mut cnt = 0;
        for c in 0..4 {
            if m >> c & 1 != 0 {
                let e = (keys[c], n.child[c]);
                let mut p = cnt;
                while p > 0 && ent[p - 1].0 < e.0 {
                    ent[p] = ent[p - 1];
                    p -= 1;
                }
                ent[p] = e;
                cnt += 1;
            }
        }
        for &(k, c) in &ent[..cnt] {
            stack[sp] = (c, k);
            sp += 1;
        }
    }
}

/// One ray against a leaf block (four triangles per SIMD test).
#[allow(clippy::too_many_arguments)]
fn ray_tri4(
    blk: &Tri4,
    o: [f32; 3],
    d: [f32; 3],
    dinf: f32,
    t_min: f32,
    inst: u32,
    best: &mut RayBest,
) {
    let o4 = o.map(f32x4::splat);
    let d4 = d.map(f32x4::splat);
    let s = TriEdges::new(blk, &TriRel::new(blk, &o4));
    let w0 = dot4(&d4, &s.n[0]);
    let w1 = dot4(&d4, &s.n[1]);
    let w2 = dot4(&d4, &s.n[2]);
    let zero = f32x4::ZERO;
    let mn = w0.fast_min(w1).fast_min(w2);
    let mx = w0.fast_max(w1).fast_max(w2);
    let den = dot4(&d4, &s.nrm);
    let t = s.num / den;
    let sum = w0 + w1 + w2;
    let cand = (mn.cmp_ge(zero) | mx.cmp_le(zero))
        & den.cmp_ne(zero)
        & sum.cmp_ne(zero)
        & t.cmp_ge(f32x4::splat(t_min))
        & t.cmp_le(f32x4::splat(best.t));
    let unc = w0
        .abs()
        .fast_min(w1.abs())
        .fast_min(w2.abs())
        .cmp_le(s.err * f32x4::splat(dinf));
    let lanes = (cand | unc).move_mask() as u32 & blk.valid();
    if lanes == 0 {
        return;
    }
    let (ta, sa, w1a, w2a) = (t.to_array(), sum.to_array(), w1.to_array(), w2.to_array());
    let ua = unc.move_mask() as u32;
    for l in 0..4 {
        if lanes >> l & 1 == 0 {
            continue;
        }
        let (tl, u, v) = if ua >> l & 1 != 0 {
            match eval_tri(&blk.lane(l), o, d) {
                Some(h) if h.0 >= t_min && h.0 <= best.t => h,
                _ => continue,
            }
        } else {
            let inv = 1.0 / sa[l];
            (ta[l], w1a[l] * inv, w2a[l] * inv)
        };
        let prim = blk.prim[l];
        if best.accepts(tl, inst, prim) {
            *best = RayBest {
                t: tl,
                inst,
                prim,
                u,
                v,
            };
        }
    }
}

/// Origin-relative vertices of four triangles.
struct TriRel {
    a: [f32x4; 3],
    b: [f32x4; 3],
    c: [f32x4; 3],
}

/// Edge normals, normal and error factor of four triangles (see [`eval_tri`]).
struct TriEdges {
    /// Edge normals `X×(Y - X)` of the edges `b→c`, `c→a`, `a→b`.
    n: [[f32x4; 3]; 3],
    /// Triangle normal `(v1 - v0)×(v2 - v0)`.
    nrm: [f32x4; 3],
    /// `nrm·(v0 - o)`: over `nrm·d` it is the hit's `t`.
    num: f32x4,
    /// `ERR_W · max(|B|₁|C - B|₁, …)`: times `|d|_∞` it bounds the edge functions'
    /// rounding error.
    err: f32x4,
}

#[inline(always)]
fn cross4(a: &[f32x4; 3], b: &[f32x4; 3]) -> [f32x4; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[inline(always)]
fn dot4(a: &[f32x4; 3], b: &[f32x4; 3]) -> f32x4 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

impl TriRel {
    #[inline(always)]
    fn new(blk: &Tri4, o: &[f32x4; 3]) -> TriRel {
        TriRel {
            a: [blk.v[0] - o[0], blk.v[1] - o[1], blk.v[2] - o[2]],
            b: [blk.v[3] - o[0], blk.v[4] - o[1], blk.v[5] - o[2]],
            c: [blk.v[6] - o[0], blk.v[7] - o[1], blk.v[8] - o[2]],
        }
    }
}

impl TriEdges {
    #[inline(always)]
    fn new(blk: &Tri4, r: &TriRel) -> TriEdges {
        let (a, b, c) = (&r.a, &r.b, &r.c);
        let ebc = [c[0] - b[0], c[1] - b[1], c[2] - b[2]];
        let eca = [a[0] - c[0], a[1] - c[1], a[2] - c[2]];
        let eab = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let n = [cross4(b, &ebc), cross4(c, &eca), cross4(a, &eab)];
        let e1 = [
            blk.v[3] - blk.v[0],
            blk.v[4] - blk.v[1],
            blk.v[5] - blk.v[2],
        ];
        let e2 = [
            blk.v[6] - blk.v[0],
            blk.v[7] - blk.v[1],
            blk.v[8] - blk.v[2],
        ];
        let nrm = cross4(&e1, &e2);
        let num = dot4(&nrm, a);
        let l1 = |x: &[f32x4; 3]| x[0].abs() + x[1].abs() + x[2].abs();
        let err = f32x4::splat(ERR_W)
            * (l1(b) * l1(&ebc))
                .fast_max(l1(c) * l1(&eca))
                .fast_max(l1(a) * l1(&eab));
        TriEdges { n, nrm, num, err }
    }
}

thread_local! {
    /// Per-thread traversal stack of single rays (top and bottom level).
    static RAY_STACK: RefCell<Vec<(u32, f32)>> = const { RefCell::new(Vec::new()) };
    /// Per-thread traversal stack of packets (top and bottom level).
    static PACKET_STACK: RefCell<Vec<PacketEntry>> = const { RefCell::new(Vec::new()) };
}

/// Runs `f` with a traversal stack of `2 · STACK` entries: the thread's (allocated once),
/// or a fresh one if that is in use.
fn with_stack<T: Copy + 'static, R>(
    key: &'static std::thread::LocalKey<RefCell<Vec<T>>>,
    fill: T,
    f: impl FnOnce(&mut [T]) -> R,
) -> R {
    key.with(|cell| match cell.try_borrow_mut() {
        Ok(mut v) => {
            if v.len() < 2 * STACK {
                v.resize(2 * STACK, fill);
            }
            f(&mut v)
        }
        Err(_) => f(&mut [fill; 2 * STACK]),
    })
}

impl TwoLevelBvh {
    fn cast_ray_impl(&self, o: [f32; 3], d: [f32; 3], t_min: f32, t_max: f32) -> Hit {
        let Some(t_max) = ray_range(t_min, t_max) else {
            return Hit::MISS;
        };
        if !o.iter().chain(&d).all(|x| x.is_finite()) {
            return Hit::MISS;
        }
        let mut best = RayBest::new(t_max);
        let pre = RayPre::new(o, d, ETA_TLAS);
        with_stack(&RAY_STACK, (0, 0.0), |stack| {
            ray_traverse(
                &self.tlas,
                0,
                &pre,
                t_min,
                &mut best,
                stack,
                |inst, best, rest| {
                    self.ray_instance(inst, o, d, t_min, best, rest);
                },
            );
        });
        best.hit()
    }

    /// One scene-frame ray against instance `inst`.
    #[allow(clippy::too_many_arguments)]
    fn ray_instance(
        &self,
        inst: u32,
        o: [f32; 3],
        d: [f32; 3],
        t_min: f32,
        best: &mut RayBest,
        stack: &mut [(u32, f32)],
    ) {
        let Some(id) = self.inst[inst as usize] else {
            return;
        };
        let (om, dm) = (id.origin(o), id.dir(d));
        ray_mesh(
            &self.meshes[id.mesh as usize],
            0,
            inst,
            om,
            dm,
            t_min,
            best,
            stack,
        );
    }
}

/// One mesh-frame ray against the subtree `root` (0: all) of `mesh` of instance `inst`.
#[allow(clippy::too_many_arguments)]
fn ray_mesh(
    mesh: &MeshBvh,
    root: u32,
    inst: u32,
    om: [f32; 3],
    dm: [f32; 3],
    t_min: f32,
    best: &mut RayBest,
    stack: &mut [(u32, f32)],
) {
    let pre = RayPre::new(om, dm, ETA_BLAS);
    let dinf = norm_inf(dm);
    ray_traverse(
        &mesh.nodes,
        root,
        &pre,
        t_min,
        best,
        stack,
        |leaf, best, _| {
            for blk in leaf_blocks(&mesh.tris, leaf) {
                ray_tri4(blk, om, dm, dinf, t_min, inst, best);
            }
        },
    );
}

// ---------------------------------------------------------------------------------------
// Packets
// ---------------------------------------------------------------------------------------

/// Horizontal minimum (NaN lanes give an unspecified result).
#[inline(always)]
fn hmin(v: f32x4) -> f32 {
    let a = v.to_array();
    let m = |x: f32, y: f32| if x < y { x } else { y };
    m(m(a[0], a[1]), m(a[2], a[3]))
}

/// Horizontal maximum (NaN lanes give an unspecified result).
#[inline(always)]
fn hmax(v: f32x4) -> f32 {
    let a = v.to_array();
    let m = |x: f32, y: f32| if x > y { x } else { y };
    m(m(a[0], a[1]), m(a[2], a[3]))
}

/// All-ones lanes where bit `l` of `bits` is set.
#[inline(always)]
fn lane_mask(bits: u32) -> f32x4 {
    let on = f32::from_bits(u32::MAX);
    f32x4::new(std::array::from_fn(|l| {
        if bits >> l & 1 != 0 { on } else { 0.0 }
    }))
}

/// The groups of the quads in a 4-bit quad mask.
const QUAD_GROUPS: [u32; 16] = {
    let mut t = [0u32; 16];
    let mut i = 0;
    while i < 16 {
        let mut q = 0;
        while q < 4 {
            if i >> q & 1 != 0 {
                t[i] |= 15 << (4 * q);
            }
            q += 1;
        }
        i += 1;
    }
    t
};

/// The quads (4-bit mask) holding groups of `m`.
#[inline(always)]
fn quads_of(m: u32) -> u32 {
    u32::from(m & 0xf != 0)
        | u32::from(m & 0xf0 != 0) << 1
        | u32::from(m & 0xf00 != 0) << 2
        | u32::from(m & 0xf000 != 0) << 3
}

/// A packet expressed in one frame (scene or a mesh's), with its projection: the dominant
/// axis `k` (sign `s`), the other two `i, j`, and the rectangles of the groups (four
/// rays) and quads (four groups) in the plane of ratios `(d_i, d_j) / (s·d_k)`.
#[derive(Clone)]
struct Frame<'a> {
    o: [f32; 3],
    d: &'a [[f32x4; GROUPS]; 3],
    k: usize,
    i: usize,
    j: usize,
    s: f32,
    /// Group rectangles (lane `g % 4` of vector `g / 4`), widened for rounding; empty for
    /// inactive groups.
    ga0: [f32x4; QUADS],
    ga1: [f32x4; QUADS],
    gb0: [f32x4; QUADS],
    gb1: [f32x4; QUADS],
    /// Per group `(1 - η) / max(s·d_k)`: a depth times this bounds `t` from below.
    ginv: [f32x4; QUADS],
    /// Quad rectangles (union of their groups') and `ginv` minima, lane = quad.
    qa0: f32x4,
    qa1: f32x4,
    qb0: f32x4,
    qb1: f32x4,
    qinv: f32x4,
    /// The packet's rectangle (union of the active groups').
    pa0: f32,
    pa1: f32,
    pb0: f32,
    pb1: f32,
    /// Minimum of `ginv` over active groups.
    pinv: f32,
    /// A bound of the packet's rays' `|d|_∞`.
    dinf: f32,
}

impl<'a> Frame<'a> {
    /// The frame of directions `d` from origin `o` for the groups in `mask`, or `None`
    /// when the rays do not all point into the same half-space of the dominant axis or
    /// spread too far for packet traversal.
    fn new(o: [f32; 3], d: &'a [[f32x4; GROUPS]; 3], mask: u32, eta: f32) -> Option<Frame<'a>> {
        let zero = f32x4::ZERO;
        let mut sum = [zero; 3];
        for g in 0..GROUPS {
            if mask >> g & 1 != 0 {
                for c in 0..3 {
                    sum[c] += d[c][g];
                }
            }
        }
        let m = sum.map(|v| v.reduce_add());
        let mut k = 0;
        for c in 1..3 {
            if m[c].abs() > m[k].abs() {
                k = c;
            }
        }
        if m[k] == 0.0 || m[k].is_nan() || !o.iter().all(|x| x.is_finite()) {
            return None;
        }
        let s = if m[k] > 0.0 { 1.0 } else { -1.0 };
        let (i, j) = ((k + 1) % 3, (k + 2) % 3);
        let inf = f32x4::splat(f32::INFINITY);
        let ninf = f32x4::splat(f32::NEG_INFINITY);
        let eta4 = f32x4::splat(eta);
        let tiny = f32x4::splat(1e-30);
        let sg = f32x4::splat(s);
        let mut fr = Frame {
            o,
            d,
            k,
            i,
            j,
            s,
            ga0: [inf; QUADS],
            ga1: [ninf; QUADS],
            gb0: [inf; QUADS],
            gb1: [ninf; QUADS],
            ginv: [zero; QUADS],
            qa0: inf,
            qa1: ninf,
            qb0: inf,
            qb1: ninf,
            qinv: inf,
            pa0: f32::INFINITY,
            pa1: f32::NEG_INFINITY,
            pb0: f32::INFINITY,
            pb1: f32::NEG_INFINITY,
            pinv: f32::INFINITY,
            dinf: 0.0,
        };
        let mut dk_max = zero;
        let mut quad = [[
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::INFINITY,
        ]; QUADS];
        for q in 0..QUADS {
            let qm = mask >> (4 * q) & 15;
            if qm == 0 {
                continue;
            }
            // Per group r of the quad: ratios and depth rates of its rays.
            let mut ra = [zero; 4];
            let mut rb = [zero; 4];
            let mut dk = [f32x4::ONE; 4];
            for r in 0..4 {
                let g = 4 * q + r;
                if qm >> r & 1 == 0 {
                    // Inactive group: a copy of an active one keeps the reductions finite.
                    continue;
                }
                let dkg = d[k][g] * sg;
                if dkg.cmp_gt(zero).move_mask() != 15 {
                    return None;
                }
                let rk = f32x4::ONE / dkg;
                ra[r] = d[i][g] * rk;
                rb[r] = d[j][g] * rk;
                dk[r] = dkg;
            }
            // Transposed, lane r of each row holds group r's values.
            let tr = |v: [f32x4; 4], f: fn(f32x4, f32x4) -> f32x4| {
                let t = f32x4::transpose(v);
                f(f(t[0], t[1]), f(t[2], t[3]))
            };
            let a0 = tr(ra, f32x4::fast_min);
            let a1 = tr(ra, f32x4::fast_max);
            let b0 = tr(rb, f32x4::fast_min);
            let b1 = tr(rb, f32x4::fast_max);
            let dmax = tr(dk, f32x4::fast_max);
            dk_max = dk_max.fast_max(dmax);
            let gi = f32x4::splat(1.0 - eta) / dmax;
            let (mut a0, mut a1) = (a0 - a0.abs() * eta4 - tiny, a1 + a1.abs() * eta4 + tiny);
            let (mut b0, mut b1) = (b0 - b0.abs() * eta4 - tiny, b1 + b1.abs() * eta4 + tiny);
            let (mut gi, mut gi_min) = (gi, gi);
            if qm != 15 {
                // Inactive groups: empty rectangles, no depth bound.
                let act = lane_mask(qm);
                (a0, a1, b0, b1) = (
                    act.blend(a0, inf),
                    act.blend(a1, ninf),
                    act.blend(b0, inf),
                    act.blend(b1, ninf),
                );
                (gi, gi_min) = (act.blend(gi, zero), act.blend(gi, inf));
            }
            (fr.ga0[q], fr.ga1[q], fr.gb0[q], fr.gb1[q], fr.ginv[q]) = (a0, a1, b0, b1, gi);
            quad[q] = [hmin(a0), hmax(a1), hmin(b0), hmax(b1), hmin(gi_min)];
        }
        let col = |k: usize| f32x4::new([quad[0][k], quad[1][k], quad[2][k], quad[3][k]]);
        (fr.qa0, fr.qa1, fr.qb0, fr.qb1, fr.qinv) = (col(0), col(1), col(2), col(3), col(4));
        (fr.pa0, fr.pa1, fr.pb0, fr.pb1, fr.pinv) = (
            hmin(fr.qa0),
            hmax(fr.qa1),
            hmin(fr.qb0),
            hmax(fr.qb1),
            hmin(fr.qinv),
        );
        // |d_i| = |a|·|d_k|: a bound of every ray's |d|_∞ from the rectangle and depth rates.
        let ratio = 1f32
            .max(fr.pa0.abs())
            .max(fr.pa1.abs())
            .max(fr.pb0.abs())
            .max(fr.pb1.abs());
        fr.dinf = hmax(dk_max) * ratio;
        let ok = fr.pa1 - fr.pa0 <= MAX_PACKET_SPAN
            && fr.pb1 - fr.pb0 <= MAX_PACKET_SPAN
            && fr.dinf.is_finite();
        ok.then_some(fr)
    }
}

/// Best hits of a packet's lanes so far (lane `l` of group `g` is ray `4g + l`).
struct PacketState {
    t: [f32x4; GROUPS],
    /// Instance index (bits).
    inst: [f32x4; GROUPS],
    /// Triangle index in the instance's mesh (bits).
    prim: [f32x4; GROUPS],
    u: [f32x4; GROUPS],
    v: [f32x4; GROUPS],
    /// Per group the largest best `t` (lane `g % 4` of vector `g / 4`), `-∞` for
    /// inactive groups.
    gmax: [f32x4; QUADS],
    /// Per quad (lane) the largest of its groups' `gmax`.
    qmax: f32x4,
    /// Largest of `gmax`.
    pmax: f32,
    t_min: f32,
}

impl PacketState {
    /// Groups of `m` in quads some of whose rays can still hit something at depth `depth`
    /// (along the frame's dominant axis).
    #[inline(always)]
    fn alive(&self, f: &Frame, depth: f32, m: u32) -> u32 {
        let q = (f32x4::splat(depth) * f.qinv).cmp_le(self.qmax).move_mask() as u32;
        m & QUAD_GROUPS[q as usize]
    }

    /// Refreshes the farthest-hit bounds after group `g` changed.
    #[inline(always)]
    fn refresh(&mut self, g: usize) {
        let q = g / 4;
        self.gmax[q].as_array_mut()[g % 4] = hmax(self.t[g]);
        self.qmax.as_array_mut()[q] = hmax(self.gmax[q]);
        self.pmax = hmax(self.qmax);
    }

    /// Lane `l` of group `g` as a single-ray best hit.
    fn lane(&self, g: usize, l: usize) -> RayBest {
        RayBest {
            t: self.t[g].as_array_ref()[l],
            inst: self.inst[g].as_array_ref()[l].to_bits(),
            prim: self.prim[g].as_array_ref()[l].to_bits(),
            u: self.u[g].as_array_ref()[l],
            v: self.v[g].as_array_ref()[l],
        }
    }

    /// Stores a single-ray best hit into lane `l` of group `g`.
    fn set_lane(&mut self, g: usize, l: usize, b: &RayBest) {
        self.t[g].as_array_mut()[l] = b.t;
        self.inst[g].as_array_mut()[l] = f32::from_bits(b.inst);
        self.prim[g].as_array_mut()[l] = f32::from_bits(b.prim);
        self.u[g].as_array_mut()[l] = b.u;
        self.v[g].as_array_mut()[l] = b.v;
    }
}

/// Children (or triangles) of a node as rectangles in a frame's ratio plane, with their
/// nearest depth; `ok` has the lanes that can be hit at all (overlapping the packet's
/// rectangle, not behind the origin nor beyond every ray's current hit).
struct Rects {
    a0: f32x4,
    a1: f32x4,
    b0: f32x4,
    b1: f32x4,
    near: f32x4,
    ok: u32,
}

impl Rects {
    /// Groups of `m` (whose quads are `quads`) whose rays can reach lane `c`: tested per
    /// quad, then, when `fine`, per group.
    #[inline(always)]
    fn groups(&self, c: usize, f: &Frame, st: &PacketState, m: u32, quads: u32, fine: bool) -> u32 {
        let a0 = f32x4::splat(self.a0.as_array_ref()[c]);
        let a1 = f32x4::splat(self.a1.as_array_ref()[c]);
        let b0 = f32x4::splat(self.b0.as_array_ref()[c]);
        let b1 = f32x4::splat(self.b1.as_array_ref()[c]);
        let near = f32x4::splat(self.near.as_array_ref()[c]);
        let hit = a1.cmp_ge(f.qa0)
            & a0.cmp_le(f.qa1)
            & b1.cmp_ge(f.qb0)
            & b0.cmp_le(f.qb1)
            & (near * f.qinv).cmp_le(st.qmax);
        let qm = hit.move_mask() as u32 & quads;
        if qm == 0 {
            return 0;
        }
        if !fine {
            return m & QUAD_GROUPS[qm as usize];
        }
        let mut gm = 0;
        let mut rest = qm;
        while rest != 0 {
            let q = rest.trailing_zeros() as usize & (QUADS - 1);
            rest &= rest - 1;
            let hit = a1.cmp_ge(f.ga0[q])
                & a0.cmp_le(f.ga1[q])
                & b1.cmp_ge(f.gb0[q])
                & b0.cmp_le(f.gb1[q])
                & (near * f.ginv[q]).cmp_le(st.gmax[q]);
            gm |= (hit.move_mask() as u32) << (4 * q);
        }
        gm & m
    }

    /// Rectangles and the lanes that can be hit from the in-front rectangles
    /// (`front_rect`, valid where `front`: everything at positive depth) and, for lanes
    /// that straddle the depth plane of the origin (`live` but not `front`), the lateral
    /// bounds (`lateral`: `[il, ih, jl, jh]`) and the largest depth `d1`: at depths in
    /// `(0, d1]` the ratio `p / depth` of `p` in `[lo, hi]` is at least `lo / d1` when
    /// `lo >= 0` (else unbounded) and at most `hi / d1` when `hi <= 0`.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn finish(
        front_rect: [f32x4; 4],
        lateral: [f32x4; 4],
        d1: f32x4,
        front: f32x4,
        near: f32x4,
        live: f32x4,
        f: &Frame,
        st: &PacketState,
    ) -> Rects {
        let [mut a0, mut a1, mut b0, mut b1] = front_rect;
        let zero = f32x4::ZERO;
        let near = front.blend(near, zero);
        if live.move_mask() & !front.move_mask() != 0 {
            let inf = f32x4::splat(f32::INFINITY);
            let ninf = f32x4::splat(f32::NEG_INFINITY);
            let pos = d1.cmp_gt(zero);
            let inv1 = f32x4::ONE / d1;
            let [il, ih, jl, jh] = lateral;
            a0 = front.blend(a0, (il.cmp_ge(zero) & pos).blend(il * inv1, ninf));
            a1 = front.blend(a1, (ih.cmp_le(zero) & pos).blend(ih * inv1, inf));
            b0 = front.blend(b0, (jl.cmp_ge(zero) & pos).blend(jl * inv1, ninf));
            b1 = front.blend(b1, (jh.cmp_le(zero) & pos).blend(jh * inv1, inf));
        }
        let ok = live
            & a1.cmp_ge(f32x4::splat(f.pa0))
            & a0.cmp_le(f32x4::splat(f.pa1))
            & b1.cmp_ge(f32x4::splat(f.pb0))
            & b0.cmp_le(f32x4::splat(f.pb1))
            & (near * f32x4::splat(f.pinv)).cmp_le(f32x4::splat(st.pmax));
        Rects {
            a0,
            a1,
            b0,
            b1,
            near,
            ok: ok.move_mask() as u32,
        }
    }

    /// The four children of a node.
    #[inline(always)]
    fn of_node(n: &Node4, f: &Frame, st: &PacketState) -> Rects {
        let ok = f32x4::splat(f.o[f.k]);
        let (d0, d1) = if f.s > 0.0 {
            (n.b[2 * f.k] - ok, n.b[2 * f.k + 1] - ok)
        } else {
            (ok - n.b[2 * f.k + 1], ok - n.b[2 * f.k])
        };
        let zero = f32x4::ZERO;
        let front = d0.cmp_gt(zero);
        let live = d1.cmp_ge(zero);
        let inv0 = f32x4::ONE / d0;
        let inv1 = f32x4::ONE / d1;
        let oi = f32x4::splat(f.o[f.i]);
        let oj = f32x4::splat(f.o[f.j]);
        let il = n.b[2 * f.i] - oi;
        let ih = n.b[2 * f.i + 1] - oi;
        let jl = n.b[2 * f.j] - oj;
        let jh = n.b[2 * f.j + 1] - oj;
        Rects::finish(
            [
                (il * inv0).fast_min(il * inv1),
                (ih * inv0).fast_max(ih * inv1),
                (jl * inv0).fast_min(jl * inv1),
                (jh * inv0).fast_max(jh * inv1),
            ],
            [il, ih, jl, jh],
            d1,
            front,
            d0,
            live,
            f,
            st,
        )
    }

    /// The four triangles of a leaf block (origin-relative vertices `s`; unused lanes
    /// have NaN vertices and fail every test).
    #[inline(always)]
    fn of_tris(s: &TriRel, f: &Frame, st: &PacketState) -> Rects {
        let sg = f32x4::splat(f.s);
        let (da, db, dc) = (s.a[f.k] * sg, s.b[f.k] * sg, s.c[f.k] * sg);
        let near = da.fast_min(db).fast_min(dc);
        let far = da.fast_max(db).fast_max(dc);
        let zero = f32x4::ZERO;
        let front = near.cmp_gt(zero);
        let live = far.cmp_ge(zero);
        let (ia, ib, ic) = (f32x4::ONE / da, f32x4::ONE / db, f32x4::ONE / dc);
        let (ai, bi, ci) = (s.a[f.i] * ia, s.b[f.i] * ib, s.c[f.i] * ic);
        let (aj, bj, cj) = (s.a[f.j] * ia, s.b[f.j] * ib, s.c[f.j] * ic);
        let (pi, pj) = (
            [s.a[f.i], s.b[f.i], s.c[f.i]],
            [s.a[f.j], s.b[f.j], s.c[f.j]],
        );
        Rects::finish(
            [
                ai.fast_min(bi).fast_min(ci),
                ai.fast_max(bi).fast_max(ci),
                aj.fast_min(bj).fast_min(cj),
                aj.fast_max(bj).fast_max(cj),
            ],
            [
                pi[0].fast_min(pi[1]).fast_min(pi[2]),
                pi[0].fast_max(pi[1]).fast_max(pi[2]),
                pj[0].fast_min(pj[1]).fast_min(pj[2]),
                pj[0].fast_max(pj[1]).fast_max(pj[2]),
            ],
            far,
            front,
            near,
            live,
            f,
            st,
        )
    }
}

/// A packet traversal stack entry: node code, groups, depth of the node.
type PacketEntry = (u32, u32, f32);

/// Front-to-back packet traversal of `nodes` for the groups in `mask` with `stack` (at
/// least [`STACK`] entries); `leaf(state, payload, groups, rest)` handles a leaf, `rest`
/// being the unused part of the stack. An inner node reached by at most `narrow_at`
/// groups goes to `narrow(state, node, groups)` instead (the packet has diverged: its
/// remaining rays are cheaper one by one, as in Embree's hybrid traversal); `narrow_at`
/// 0 never does.
#[allow(clippy::too_many_arguments)]
fn packet_traverse<F, N>(
    nodes: &[Node4],
    f: &Frame,
    mask: u32,
    st: &mut PacketState,
    stack: &mut [PacketEntry],
    narrow_at: u32,
    mut leaf: F,
    mut narrow: N,
) where
    F: FnMut(&mut PacketState, u32, u32, &mut [PacketEntry]),
    N: FnMut(&mut PacketState, u32, u32),
{
    if nodes.is_empty() || mask == 0 {
        return;
    }
    let mut sp = 1;
    stack[0] = (0, mask, 0.0);
    while sp > 0 {
        sp -= 1;
        let (code, mut m, depth) = stack[sp];
        if depth > 0.0 {
            m = st.alive(f, depth, m);
            if m == 0 {
                continue;
            }
        }
        if code & LEAF != 0 {
            leaf(st, code & !LEAF, m, &mut stack[sp..]);
            continue;
        }
        if m.count_ones() <= narrow_at {
            narrow(st, code, m);
            continue;
        }
        let n = &nodes[code as usize];
        let r = Rects::of_node(n, f, st);
        if r.ok == 0 {
            continue;
        }
        let quads = quads_of(m);
        let near = r.near.to_array();
        let mut ent = [(0.0f32, 0u32, 0u32); 4];
        let mut cnt = 0;
        let mut rest = r.ok;
        while rest != 0 {
            let c = rest.trailing_zeros() as usize & 3;
            rest &= rest - 1;
            // Leaves are worth the finer test of the single groups.
            let gm = if n.child[c] & LEAF != 0 {
                r.groups(c, f, st, m, quads, true)
            } else {
                m
            };
            if gm == 0 {
                continue;
            }
            let e = (near[c], n.child[c], gm);
            let mut p = cnt;
            while p > 0 && ent[p - 1].0 < e.0 {
                ent[p] = ent[p - 1];
                p -= 1;
            }
            ent[p] = e;
            cnt += 1;
        }
        for &(k, c, gm) in &ent[..cnt] {
            stack[sp] = (c, gm, k);
            sp += 1;
        }
    }
}

impl TwoLevelBvh {
    fn cast_packet_impl(&self, p: &RayPacket, hits: &mut [Hit; PACKET_SIZE]) {
        let len = p.len.min(PACKET_SIZE);
        if len == 0 {
            return;
        }
        let single = |hits: &mut [Hit; PACKET_SIZE]| {
            for (l, h) in hits.iter_mut().enumerate().take(len) {
                *h = self.cast_ray_impl(
                    p.origin,
                    [p.dir[0][l], p.dir[1][l], p.dir[2][l]],
                    p.t_min,
                    p.t_max,
                );
            }
        };
        // Negative t_min (hits behind the origin) is outside the packet path's projection;
        // empty ranges and scenes miss.
        let Some(t_max) = ray_range(p.t_min, p.t_max) else {
            return single(hits);
        };
        if p.t_min < 0.0 || self.tlas.is_empty() {
            return single(hits);
        }
        // Directions by group (four consecutive lanes: rows of 4 pixels of an 8×8 tile,
        // whose rectangles are thinner than 2×2 blocks'); lanes past `len` repeat their
        // group's first lane.
        let mut d = [[f32x4::ZERO; GROUPS]; 3];
        for (dc, pc) in d.iter_mut().zip(&p.dir) {
            for (g, v) in dc.iter_mut().enumerate() {
                let lanes: [f32; 4] = if 4 * g + 4 <= len {
                    [pc[4 * g], pc[4 * g + 1], pc[4 * g + 2], pc[4 * g + 3]]
                } else {
                    let first = (4 * g).min(len - 1);
                    std::array::from_fn(|l| pc[if 4 * g + l < len { 4 * g + l } else { first }])
                };
                *v = f32x4::new(lanes);
            }
        }
        let groups = len.div_ceil(4);
        let mask = if groups == GROUPS {
            0xffff
        } else {
            (1u32 << groups) - 1
        };
        let Some(frame) = Frame::new(p.origin, &d, mask, ETA_TLAS) else {
            return single(hits);
        };
        let none = f32x4::splat(f32::from_bits(Hit::NONE));
        let gmax: [f32x4; QUADS] = std::array::from_fn(|q| {
            lane_mask(mask >> (4 * q) & 15)
                .blend(f32x4::splat(t_max), f32x4::splat(f32::NEG_INFINITY))
        });
        let mut st = PacketState {
            t: [f32x4::splat(t_max); GROUPS],
            inst: [none; GROUPS],
            prim: [f32x4::splat(f32::from_bits(u32::MAX)); GROUPS],
            u: [f32x4::ZERO; GROUPS],
            v: [f32x4::ZERO; GROUPS],
            gmax,
            qmax: f32x4::new(gmax.map(hmax)),
            pmax: t_max,
            t_min: p.t_min,
        };
        with_stack(&PACKET_STACK, (0, 0, 0.0), |stack| {
            packet_traverse(
                &self.tlas,
                &frame,
                mask,
                &mut st,
                stack,
                0,
                |st, inst, m, rest| {
                    self.packet_instance(inst, &frame, m, st, rest);
                },
                |_, _, _| {},
            );
        });
        for (g, out) in hits[..len].chunks_mut(4).enumerate() {
            let (t, inst, prim) = (
                st.t[g].to_array(),
                st.inst[g].to_array(),
                st.prim[g].to_array(),
            );
            let (u, v) = (st.u[g].to_array(), st.v[g].to_array());
            for (l, h) in out.iter_mut().enumerate() {
                *h = if inst[l].to_bits() == Hit::NONE {
                    Hit::MISS
                } else {
                    Hit {
                        t: t[l],
                        instance: inst[l].to_bits(),
                        prim: prim[l].to_bits(),
                        u: u[l],
                        v: v[l],
                    }
                };
            }
        }
    }

    /// The packet (groups `m` of the scene frame `sf`) against instance `inst`.
    fn packet_instance(
        &self,
        inst: u32,
        sf: &Frame,
        m: u32,
        st: &mut PacketState,
        stack: &mut [PacketEntry],
    ) {
        let Some(id) = self.inst[inst as usize] else {
            return;
        };
        let mesh = &self.meshes[id.mesh as usize];
        match id.kind {
            XformKind::Identity => self.packet_mesh(mesh, inst, sf, m, st, stack),
            XformKind::Translation => {
                let mf = Frame {
                    o: id.origin(sf.o),
                    ..sf.clone()
                };
                self.packet_mesh(mesh, inst, &mf, m, st, stack);
            }
            XformKind::General => {
                let r = &id.inv.rows;
                let mut d = [[f32x4::ZERO; GROUPS]; 3];
                for g in 0..GROUPS {
                    if m >> g & 1 == 0 {
                        continue;
                    }
                    for (c, dc) in d.iter_mut().enumerate() {
                        dc[g] = f32x4::splat(r[c][0]) * sf.d[0][g]
                            + f32x4::splat(r[c][1]) * sf.d[1][g]
                            + f32x4::splat(r[c][2]) * sf.d[2][g];
                    }
                }
                let om = id.origin(sf.o);
                match Frame::new(om, &d, m, ETA_BLAS) {
                    Some(mf) => self.packet_mesh(mesh, inst, &mf, m, st, stack),
                    // Incoherent in this frame: single rays.
                    None => self.narrow_rays(mesh, inst, 0, om, &d, m, st),
                }
            }
        }
    }

    /// The packet (groups `m` of mesh frame `f`) through `mesh` of instance `inst`:
    /// packet traversal, diverged nodes ray by ray ([`NARROW_AT`]).
    fn packet_mesh(
        &self,
        mesh: &MeshBvh,
        inst: u32,
        f: &Frame,
        m: u32,
        st: &mut PacketState,
        stack: &mut [PacketEntry],
    ) {
        packet_traverse(
            &mesh.nodes,
            f,
            m,
            st,
            stack,
            NARROW_AT,
            |st, blk, gm, _| {
                for blk in leaf_blocks(&mesh.tris, blk) {
                    self.packet_leaf(blk, inst, f, gm, st);
                }
            },
            |st, node, gm| self.narrow_rays(mesh, inst, node, f.o, f.d, gm, st),
        );
    }

    /// The rays of groups `m` (origin `o`, directions `d`, mesh frame) one by one through
    /// the subtree `node` (0: all) of `mesh` of instance `inst`: the same triangle
    /// arithmetic as the packet path, so the same bits.
    #[allow(clippy::too_many_arguments)]
    fn narrow_rays(
        &self,
        mesh: &MeshBvh,
        inst: u32,
        node: u32,
        o: [f32; 3],
        d: &[[f32x4; GROUPS]; 3],
        m: u32,
        st: &mut PacketState,
    ) {
        with_stack(&RAY_STACK, (0, 0.0), |stack| {
            let mut rest = m;
            while rest != 0 {
                let g = rest.trailing_zeros() as usize;
                rest &= rest - 1;
                for l in 0..4 {
                    let dm = [
                        d[0][g].as_array_ref()[l],
                        d[1][g].as_array_ref()[l],
                        d[2][g].as_array_ref()[l],
                    ];
                    let mut best = st.lane(g, l);
                    ray_mesh(mesh, node, inst, o, dm, st.t_min, &mut best, stack);
                    st.set_lane(g, l, &best);
                }
                st.refresh(g);
            }
        });
    }

    /// The packet (groups `m` of mesh frame `f`) against one leaf block.
    fn packet_leaf(&self, blk: &Tri4, inst: u32, f: &Frame, m: u32, st: &mut PacketState) {
        let o4 = [
            f32x4::splat(f.o[0]),
            f32x4::splat(f.o[1]),
            f32x4::splat(f.o[2]),
        ];
        let rel = TriRel::new(blk, &o4);
        let r = Rects::of_tris(&rel, f, st);
        if r.ok == 0 {
            return;
        }
        let quads = quads_of(m);
        let mut gms = [0u32; 4];
        let mut any = 0;
        let mut rest = r.ok;
        while rest != 0 {
            let c = rest.trailing_zeros() as usize & 3;
            rest &= rest - 1;
            gms[c] = r.groups(c, f, st, m, quads, true);
            any |= gms[c];
        }
        if any == 0 {
            return;
        }
        let s = TriEdges::new(blk, &rel);
        let zero = f32x4::ZERO;
        let tmin = f32x4::splat(st.t_min);
        let inst_bits = f32x4::splat(f32::from_bits(inst));
        let n = s.n.map(|e| e.map(f32x4::to_array));
        let nrm = s.nrm.map(f32x4::to_array);
        let num = s.num.to_array();
        let err = (s.err * f32x4::splat(f.dinf)).to_array();
        for (c, &gm) in gms.iter().enumerate() {
            if gm == 0 {
                continue;
            }
            let n0 = [
                f32x4::splat(n[0][0][c]),
                f32x4::splat(n[0][1][c]),
                f32x4::splat(n[0][2][c]),
            ];
            let n1 = [
                f32x4::splat(n[1][0][c]),
                f32x4::splat(n[1][1][c]),
                f32x4::splat(n[1][2][c]),
            ];
            let n2 = [
                f32x4::splat(n[2][0][c]),
                f32x4::splat(n[2][1][c]),
                f32x4::splat(n[2][2][c]),
            ];
            let nr = [
                f32x4::splat(nrm[0][c]),
                f32x4::splat(nrm[1][c]),
                f32x4::splat(nrm[2][c]),
            ];
            let nu = f32x4::splat(num[c]);
            let e = f32x4::splat(err[c]);
            let prim = f32x4::splat(f32::from_bits(blk.prim[c]));
            let mut rest = gm;
            while rest != 0 {
                let g = rest.trailing_zeros() as usize;
                rest &= rest - 1;
                let d = [f.d[0][g], f.d[1][g], f.d[2][g]];
                let w0 = dot4(&d, &n0);
                let w1 = dot4(&d, &n1);
                let w2 = dot4(&d, &n2);
                let mn = w0.fast_min(w1).fast_min(w2);
                let mx = w0.fast_max(w1).fast_max(w2);
                // nrm·d == 0 gives t = ±∞ or NaN, rejected below (t_min >= 0, best < ∞).
                // Lanes with an edge function near zero (Σw == 0 among them) are special.
                let t = nu / dot4(&d, &nr);
                let best = st.t[g];
                let cand = (mn.cmp_ge(zero) | mx.cmp_le(zero)) & t.cmp_ge(tmin);
                let better = cand & t.cmp_lt(best);
                let uncertain = w0.abs().fast_min(w1.abs()).fast_min(w2.abs()).cmp_le(e);
                if ((cand & t.cmp_eq(best)) | uncertain).move_mask() != 0 {
                    let w = [w0, w1, w2];
                    let lanes = SlowLanes {
                        uncertain: uncertain.move_mask() as u32,
                        cand: cand.move_mask() as u32,
                        t,
                        w,
                    };
                    self.packet_lanes_slow(blk, c, inst, f, g, &lanes, st);
                } else if better.move_mask() != 0 {
                    let inv = f32x4::ONE / (w0 + w1 + w2);
                    st.t[g] = better.blend(t, best);
                    st.inst[g] = better.blend(inst_bits, st.inst[g]);
                    st.prim[g] = better.blend(prim, st.prim[g]);
                    st.u[g] = better.blend(w1 * inv, st.u[g]);
                    st.v[g] = better.blend(w2 * inv, st.v[g]);
                    st.refresh(g);
                }
            }
        }
    }

    /// Per-lane test of triangle `c` of a block for the four rays of group `g` (when some
    /// lane's edge function is within its rounding bound of zero, or ties): those lanes
    /// exactly, the other candidates with the SIMD results, both with the tie rule.
    #[allow(clippy::too_many_arguments)]
    fn packet_lanes_slow(
        &self,
        blk: &Tri4,
        c: usize,
        inst: u32,
        f: &Frame,
        g: usize,
        lanes: &SlowLanes,
        st: &mut PacketState,
    ) {
        let prim = blk.prim[c];
        let (ta, wa) = (lanes.t.to_array(), lanes.w.map(f32x4::to_array));
        for l in 0..4 {
            let (t, u, v) = if lanes.uncertain >> l & 1 != 0 {
                let d = [
                    f.d[0][g].as_array_ref()[l],
                    f.d[1][g].as_array_ref()[l],
                    f.d[2][g].as_array_ref()[l],
                ];
                match eval_tri(&blk.lane(c), f.o, d) {
                    Some(h) => h,
                    None => continue,
                }
            } else if lanes.cand >> l & 1 != 0 {
                let inv = 1.0 / (wa[0][l] + wa[1][l] + wa[2][l]);
                (ta[l], wa[1][l] * inv, wa[2][l] * inv)
            } else {
                continue;
            };
            if t >= st.t_min && st.lane(g, l).accepts(t, inst, prim) {
                st.set_lane(
                    g,
                    l,
                    &RayBest {
                        t,
                        inst,
                        prim,
                        u,
                        v,
                    },
                );
            }
        }
        st.refresh(g);
    }
}

/// What [`TwoLevelBvh::packet_lanes_slow`] needs of the SIMD test: lanes to redo exactly,
/// candidate lanes, their `t` and edge functions.
struct SlowLanes {
    uncertain: u32,
    cand: u32,
    t: f32x4,
    w: [f32x4; 3],
}

impl RayCaster for TwoLevelBvh {
    fn name(&self) -> &'static str {
        "bvh"
    }

    fn cast_packet(&self, packet: &RayPacket, hits: &mut [Hit; PACKET_SIZE]) {
        self.cast_packet_impl(packet, hits);
    }

    fn cast_ray(&self, origin: [f32; 3], dir: [f32; 3], t_min: f32, t_max: f32) -> Hit {
        self.cast_ray_impl(origin, dir, t_min, t_max)
    }

    fn memory_bytes(&self) -> usize {
        let meshes: usize = self
            .meshes
            .iter()
            .map(|m| {
                m.nodes.capacity() * size_of::<Node4>()
                    + m.tris.capacity() * size_of::<Tri4>()
                    + size_of::<MeshBvh>()
            })
            .sum();
        meshes
            + self.inst.capacity() * size_of::<Option<InstanceData>>()
            + self.tlas.capacity() * size_of::<Node4>()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn random_boxes(n: usize, seed: u64) -> Vec<Aabb> {
        let mut s = seed;
        let mut rnd = move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 40) as f32) / (1u64 << 24) as f32
        };
        (0..n)
            .map(|_| {
                let c = [rnd() * 10.0, rnd() * 10.0, rnd() * 10.0];
                let e = [rnd() * 0.3, rnd() * 0.3, rnd() * 0.3];
                Aabb {
                    lo: std::array::from_fn(|a| c[a] - e[a]),
                    hi: std::array::from_fn(|a| c[a] + e[a]),
                }
            })
            .collect()
    }

    /// Walks the tree checking containment; returns the primitives reached.
    fn walk(
        bvh: &WideBvh,
        node: usize,
        parent: &Aabb,
        boxes: &[Aabb],
        seen: &mut [u32],
        depth: usize,
    ) -> usize {
        let n = &bvh.nodes[node];
        let mut max_depth = depth;
        for slot in 0..4 {
            let c = n.child[slot];
            if c == EMPTY {
                continue;
            }
            let b = n.bounds(slot);
            for a in 0..3 {
                assert!(b.lo[a] >= parent.lo[a] && b.hi[a] <= parent.hi[a] || depth == 0);
            }
            if c & LEAF != 0 {
                for &p in bvh.leaf_prims((c & !LEAF) as usize) {
                    seen[p as usize] += 1;
                    for a in 0..3 {
                        assert!(
                            boxes[p as usize].lo[a] >= b.lo[a]
                                && boxes[p as usize].hi[a] <= b.hi[a]
                        );
                    }
                }
            } else {
                max_depth = max_depth.max(walk(
                    bvh,
                    c as usize,
                    &b.inflated(1e-3),
                    boxes,
                    seen,
                    depth + 1,
                ));
            }
        }
        max_depth
    }

    #[test]
    fn build_covers_every_primitive_once_and_nests_bounds() {
        for (n, leaf) in [(1, 4), (3, 4), (5, 4), (1000, 4), (50_000, 4), (777, 1)] {
            let boxes = random_boxes(n, n as u64);
            let bvh = WideBvh::build(&boxes, leaf, INFLATE_BLAS);
            let mut seen = vec![0u32; n];
            let depth = walk(&bvh, 0, &Aabb::EMPTY, &boxes, &mut seen, 0);
            assert!(seen.iter().all(|&s| s == 1), "n = {n}");
            assert!(bvh.leaves.iter().all(|l| l[1] as usize <= leaf && l[1] > 0));
            assert!(depth < (MEDIAN_DEPTH + 32) as usize);
        }
    }

    #[test]
    fn build_is_deterministic() {
        let boxes = random_boxes(60_000, 7);
        let a = WideBvh::build(&boxes, 4, INFLATE_BLAS);
        let b = WideBvh::build(&boxes, 4, INFLATE_BLAS);
        let c = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .expect("a one-thread pool")
            .install(|| WideBvh::build(&boxes, 4, INFLATE_BLAS));
        for x in [&b, &c] {
            assert_eq!(a.order, x.order);
            assert_eq!(a.leaves, x.leaves);
            assert_eq!(a.nodes.len(), x.nodes.len());
            for (p, q) in a.nodes.iter().zip(&x.nodes) {
                assert_eq!(p.child, q.child);
                for k in 0..6 {
                    assert_eq!(
                        p.b[k].to_array().map(f32::to_bits),
                        q.b[k].to_array().map(f32::to_bits)
                    );
                }
            }
        }
    }

    #[test]
    fn build_handles_degenerate_inputs() {
        // All boxes identical: splits by index, depth stays bounded.
        let boxes = vec![
            Aabb {
                lo: [1.0; 3],
                hi: [1.0; 3]
            };
            10_000
        ];
        let bvh = WideBvh::build(&boxes, 4, 0.0);
        let mut seen = vec![0u32; boxes.len()];
        walk(&bvh, 0, &Aabb::EMPTY, &boxes, &mut seen, 0);
        assert!(seen.iter().all(|&s| s == 1));
        // Empty and non-finite boxes are left out.
        let mut boxes = random_boxes(10, 3);
        boxes[2] = Aabb::EMPTY;
        boxes[5].lo[1] = f32::NAN;
        let bvh = WideBvh::build(&boxes, 4, 0.0);
        assert_eq!(bvh.order.len(), 8);
        assert!(WideBvh::build(&[], 4, 0.0).nodes.is_empty());
    }

    #[test]
    fn exact_orientation_matches_float_when_far_from_zero_and_is_exact_near_zero() {
        let d = [0.3f32, -1.7, 2.2];
        let x = [1.25f32, 0.5, -3.0];
        let y = [-0.75f32, 2.0, 0.125];
        let w = dot(d, cross(x, y));
        let e = orient_exact(d, x, y);
        assert!((f64::from(w) - e).abs() < 1e-5 * e.abs());
        // d = x exactly: the determinant is exactly zero.
        assert_eq!(orient_exact(x, x, y), 0.0);
        // Tiny perturbation keeps its sign.
        let xp = [x[0], x[1], f32::from_bits(x[2].to_bits() + 1)];
        let s = orient_exact(xp, x, y);
        assert!(s != 0.0);
        assert_eq!(s > 0.0, orient_exact(xp, x, y) > 0.0);
        assert_eq!(fix_sign(0.0, 0.0), 0.0);
        assert_eq!(fix_sign(1e-9, -2.0), -2.0);
        assert_eq!(fix_sign(3.0, 2.5), 3.0);
        assert!(fix_sign(-1e-9, 1e-300) > 0.0);
    }

    /// The `f64` sign filter gives what the expansion gives, bit for bit, on random
    /// orientations of every scale and on coplanar and nearly coplanar ones (where the
    /// filter must give way), for the computed edge function, its negation and zero.
    #[test]
    fn sign_filter_answers_as_the_expansion_does() {
        let mut s = 7u64;
        let mut rnd = move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 40) as f32) / (1u64 << 23) as f32 - 1.0
        };
        let (mut filtered, mut expanded) = (0, 0);
        for k in 0..20_000 {
            let scale = [1.0 / 1024.0, 1.0, 128.0, 32768.0f32][k % 4];
            let x: [f32; 3] = std::array::from_fn(|_| rnd() * scale);
            let mut y: [f32; 3] = std::array::from_fn(|_| rnd() * scale);
            let mut d: [f32; 3] = std::array::from_fn(|_| rnd());
            match k % 3 {
                // d along x or y (exactly coplanar), then moved by 0 to 4 ulps.
                0 => {
                    let from = if k % 2 == 0 { x } else { y };
                    d = from.map(|v| v / scale);
                    let i = k % 7 % 3;
                    d[i] = f32::from_bits(d[i].to_bits().wrapping_add((k % 5) as u32));
                }
                // y nearly along x: a short edge seen almost end on.
                1 => y = std::array::from_fn(|i| x[i] * 1.5 + rnd() * scale * 1e-6),
                _ => {}
            }
            let w = dot(d, cross(x, sub3(y, x)));
            for w in [w, -w, 0.0] {
                let want = fix_sign(w, orient_exact(d, x, y));
                assert_eq!(
                    exact_sign(w, d, x, y).to_bits(),
                    want.to_bits(),
                    "{d:?} {x:?} {y:?} {w}"
                );
            }
            let (approx, size) = orient_f64(d, x, y);
            if approx.abs() > size * F64_SIGN_MARGIN {
                filtered += 1;
            } else {
                expanded += 1;
            }
        }
        // Both paths were taken.
        assert!(
            filtered > 10_000 && expanded > 1_000,
            "{filtered} {expanded}"
        );
    }

    #[test]
    fn two_product_is_exact() {
        let (p, e) = two_prod(1.0 + f64::EPSILON, 1.0 - f64::EPSILON);
        assert_eq!(p, 1.0);
        assert_eq!(e, -f64::EPSILON * f64::EPSILON);
        let (s, e) = two_sum(1e16, 1.0);
        assert_eq!(s + e, 1e16 + 1.0);
        assert_eq!(e, 1.0 - (s - 1e16));
    }
}
