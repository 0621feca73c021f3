//! Incremental voxel-grid downsampling: a hash map from voxel keys to running sums
//! (position, colour, count, last viewpoint), so memory grows with the mapped area and
//! not with the number of frames.
//!
//! A voxel takes a 40-byte slot in its shard's table ([`super::voxel_table`], at most
//! three quarters full): the key, the sum of its points' offsets from the voxel's corner
//! in `f32` (an offset is below one voxel edge, so the centroid is exact to about
//! `count · 1e-7` voxel edges), the colour sums, the count and the index of the batch
//! (frame) that saw it last; the batches' sensor positions are kept once, in a table. [`VoxelGrid::prune`] drops the voxels with too
//! few points that no recent batch touched: the depth noise of a far surface scatters
//! single points over many voxels that never see a second one.
//!
//! The map is split into [`SHARDS`] hash tables by a hash of the key. A batch of points
//! is keyed in parallel, moved into shard order (a counting sort that keeps input order),
//! and the shards are filled in parallel, each prefetching the slots of the points
//! ahead. Each shard sees its points in input order, so every sum is accumulated in the
//! same order whatever the thread count: results are bit-identical across runs and
//! machines. [`VoxelGrid::voxels`] returns the voxels sorted by key.

pub use super::voxel_table::VoxelAcc;
use super::voxel_table::{PREFETCH_AHEAD, VoxelTable};
use rayon::prelude::*;
use std::ops::Range;

/// Number of hash-map shards (a power of two).
pub const SHARDS: usize = 64;
/// Bits per axis in a packed voxel key.
pub const AXIS_BITS: u32 = 21;
/// Offset that makes axis indices non-negative.
const AXIS_OFFSET: i64 = 1 << (AXIS_BITS - 1);
/// Batches smaller than this are inserted on the calling thread.
const PARALLEL_MIN_POINTS: usize = 32_768;
/// Points per chunk of a large batch's parallel passes.
const CHUNK: usize = 16_384;
/// Marks a point that has no voxel (NaN, or beyond ±2²⁰ voxels from the origin).
const NO_KEY: u64 = u64::MAX;

/// One occupied voxel of the output: the centroid and mean colour of its points.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Voxel {
    /// Packed key (see [`VoxelGrid::index_of_key`]).
    pub key: u64,
    /// Centroid of the points, world frame, m.
    pub centroid: [f64; 3],
    /// Mean sRGB colour, rounded.
    pub rgb: [u8; 3],
    /// Number of points.
    pub count: u32,
    /// Sensor position that saw the voxel last, world frame.
    pub viewpoint: [f32; 3],
}

/// The occupied voxels as arrays, sorted by key (see [`VoxelGrid::into_points`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct VoxelPoints {
    /// Centroids of the voxels' points, world frame, m (`f32`: an 8 µm step at 100 m
    /// from the origin, a thousandth of a 1 cm voxel).
    pub centroids: Vec<[f32; 3]>,
    /// Mean sRGB colours, rounded.
    pub colors: Vec<[u8; 3]>,
    /// Sensor positions that saw each voxel last, world frame.
    pub viewpoints: Vec<[f32; 3]>,
}

/// The incremental voxel grid.
#[derive(Clone, Debug)]
pub struct VoxelGrid {
    voxel_m: f64,
    shards: Vec<VoxelTable>,
    /// Sensor position of every batch, world frame.
    viewpoints: Vec<[f32; 3]>,
    dropped: u64,
    inserted: u64,
    // Scratch reused between batches.
    keyed: Vec<Keyed>,
    sorted: Vec<Keyed>,
}

/// A point of a batch, keyed (see [`VoxelGrid::insert`]).
#[derive(Clone, Copy, Debug)]
struct Keyed {
    /// Packed voxel key, or [`NO_KEY`].
    key: u64,
    /// Offset from the voxel's lowest corner, m, rounded to `f32` as the sums take it.
    offset: [f32; 3],
    rgb: [u8; 3],
    /// The key's shard.
    shard: u8,
}

// A shard index fits `Keyed::shard`.
const _: () = assert!(SHARDS <= 256);

impl Keyed {
    const NONE: Keyed = Keyed {
        key: NO_KEY,
        offset: [0.0; 3],
        rgb: [0; 3],
        shard: 0,
    };
}

/// The shard of a key: the top bits of a multiplicative hash (the bits below them pick
/// the slot in the shard's table).
#[inline]
fn shard_of(key: u64) -> usize {
    super::voxel_table::shard_of(key, SHARDS.trailing_zeros())
}

impl VoxelGrid {
    /// An empty grid of voxel edge `voxel_m` (> 0).
    pub fn new(voxel_m: f64) -> VoxelGrid {
        VoxelGrid {
            voxel_m,
            shards: (0..SHARDS)
                .map(|_| VoxelTable::new(SHARDS.trailing_zeros()))
                .collect(),
            viewpoints: Vec::new(),
            dropped: 0,
            inserted: 0,
            keyed: Vec::new(),
            sorted: Vec::new(),
        }
    }

    /// Voxel edge, m.
    pub fn voxel_m(&self) -> f64 {
        self.voxel_m
    }

    /// Number of occupied voxels.
    pub fn len(&self) -> usize {
        self.shards.iter().map(|s| s.len()).sum()
    }

    /// Whether no voxel is occupied.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Points accepted so far.
    pub fn inserted(&self) -> u64 {
        self.inserted
    }

    /// Points refused (non-finite, or more than 2²⁰ voxels from the origin).
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// Approximate heap bytes held by the voxels.
    pub fn memory_bytes(&self) -> usize {
        self.shards
            .iter()
            .map(VoxelTable::memory_bytes)
            .sum::<usize>()
            + self.viewpoints.capacity() * std::mem::size_of::<[f32; 3]>()
    }

    /// Drops every voxel with fewer than `min_count` points that no batch from
    /// `before_batch` on has touched; returns how many. Sums of the voxels kept are
    /// untouched, and a dropped voxel that a later batch hits starts again from zero.
    pub fn prune(&mut self, min_count: u32, before_batch: u32) -> usize {
        self.shards
            .par_iter_mut()
            .map(|s| s.retain(|a| a.count >= min_count || a.batch >= before_batch))
            .sum()
    }

    /// The integer voxel index `(i, j, k)` of a point: `floor(p / voxel_m)` (a true
    /// division: multiplying by a rounded reciprocal would put points that lie just below
    /// a voxel boundary, such as 0.03 at 1 cm, into the next voxel), or `None` when it is
    /// not finite or out of the key's range.
    #[inline]
    pub fn index_of(&self, p: [f64; 3]) -> Option<[i64; 3]> {
        let mut idx = [0i64; 3];
        for (i, c) in p.iter().enumerate() {
            let f = (c / self.voxel_m).floor();
            if !(f >= -(AXIS_OFFSET as f64) && f < AXIS_OFFSET as f64) {
                return None;
            }
            idx[i] = f as i64;
        }
        Some(idx)
    }

    /// Indices per axis run over `-AXIS_RANGE..AXIS_RANGE` (2^20).
    pub const AXIS_RANGE: f64 = AXIS_OFFSET as f64;

    /// The packed key of a voxel index: 21 bits per axis, x most significant, so keys
    /// sort as `(i, j, k)` lexicographically.
    #[inline]
    pub fn key_of_index(idx: [i64; 3]) -> u64 {
        let m = (1u64 << AXIS_BITS) - 1;
        let a = |v: i64| ((v + AXIS_OFFSET) as u64) & m;
        (a(idx[0]) << (2 * AXIS_BITS)) | (a(idx[1]) << AXIS_BITS) | a(idx[2])
    }

    /// The voxel index of a packed key.
    pub fn index_of_key(key: u64) -> [i64; 3] {
        let m = (1u64 << AXIS_BITS) - 1;
        let a = |v: u64| (v & m) as i64 - AXIS_OFFSET;
        [a(key >> (2 * AXIS_BITS)), a(key >> AXIS_BITS), a(key)]
    }

    #[inline]
    fn key(&self, p: [f64; 3]) -> u64 {
        self.index_of(p).map_or(NO_KEY, Self::key_of_index)
    }

    /// The lowest corner of a voxel, m.
    #[inline]
    fn corner(key: u64, voxel_m: f64) -> [f64; 3] {
        Self::index_of_key(key).map(|i| i as f64 * voxel_m)
    }

    /// A point keyed: its voxel and shard, its offset from the voxel's corner as the
    /// sums take it, its colour.
    #[inline]
    fn keyed(&self, p: [f64; 3], rgb: [u8; 3]) -> Keyed {
        let key = self.key(p);
        if key == NO_KEY {
            return Keyed::NONE;
        }
        let corner = Self::corner(key, self.voxel_m);
        Keyed {
            key,
            offset: [0, 1, 2].map(|i| (p[i] - corner[i]) as f32),
            rgb,
            shard: shard_of(key) as u8,
        }
    }

    /// Adds a run of points that share a key to its voxel, in order: one look-up for
    /// the run, the same sums, bit for bit, as one look-up per point (an `f32` sum
    /// depends on its order, which is the run's).
    #[inline]
    fn accumulate_run(shard: &mut VoxelTable, run: &[Keyed], batch: u32) {
        let acc = shard.entry(
            run[0].key,
            VoxelAcc {
                batch,
                ..VoxelAcc::ZERO
            },
        );
        for k in run {
            for i in 0..3 {
                acc.offset_sum[i] += k.offset[i];
                acc.rgb[i] += u32::from(k.rgb[i]);
            }
            acc.count += 1;
        }
        acc.batch = batch;
    }

    /// Adds a batch of world points with their colours, all seen from `viewpoint` (the
    /// sensor position, world frame). `colors` must be as long as `points`.
    ///
    /// A large batch goes in three parallel passes over fixed chunks (the same work
    /// whatever the thread count): the points keyed, with each chunk's count per shard;
    /// the keyed points moved into shard order (a counting sort that keeps input order
    /// within a shard), so each shard reads its points from one contiguous run; each
    /// shard's points added in order, runs of one voxel (neighbouring pixels) with one
    /// look-up, the table slots of the points ahead prefetched.
    pub fn insert(&mut self, points: &[[f64; 3]], colors: &[[u8; 3]], viewpoint: [f32; 3]) {
        let n = points.len().min(colors.len());
        let (points, colors) = (&points[..n], &colors[..n]);
        let batch = self.viewpoints.len() as u32;
        self.viewpoints.push(viewpoint);
        let mut keyed = std::mem::take(&mut self.keyed);
        keyed.clear();
        if n < PARALLEL_MIN_POINTS {
            keyed.extend(points.iter().zip(colors).map(|(p, c)| self.keyed(*p, *c)));
            for run in keyed.chunk_by(|a, b| a.key == b.key) {
                if run[0].key == NO_KEY {
                    self.dropped += run.len() as u64;
                } else {
                    self.inserted += run.len() as u64;
                    let shard = &mut self.shards[usize::from(run[0].shard)];
                    Self::accumulate_run(shard, run, batch);
                }
            }
            self.keyed = keyed;
            return;
        }
        // Keyed, and counted per chunk and shard (the last column: no voxel).
        keyed.resize(n, Keyed::NONE);
        let this = &*self;
        let counts: Vec<[usize; SHARDS + 1]> = keyed
            .par_chunks_mut(CHUNK)
            .zip(points.par_chunks(CHUNK).zip(colors.par_chunks(CHUNK)))
            .map(|(out, (p, c))| {
                let mut count = [0usize; SHARDS + 1];
                for (o, (p, c)) in out.iter_mut().zip(p.iter().zip(c)) {
                    *o = this.keyed(*p, *c);
                    let s = if o.key == NO_KEY {
                        SHARDS
                    } else {
                        usize::from(o.shard)
                    };
                    count[s] += 1;
                }
                count
            })
            .collect();
        let dropped: usize = counts.iter().map(|c| c[SHARDS]).sum();
        // Shard order: shard by shard, within a shard chunk by chunk.
        let mut sorted = std::mem::take(&mut self.sorted);
        sorted.clear();
        sorted.resize(n - dropped, Keyed::NONE);
        let mut to: Vec<Vec<&mut [Keyed]>> =
            counts.iter().map(|_| Vec::with_capacity(SHARDS)).collect();
        let mut shard_runs: Vec<&[Keyed]> = Vec::with_capacity(SHARDS);
        {
            let mut rest: &mut [Keyed] = &mut sorted;
            let mut shard_lens = [0usize; SHARDS];
            for (s, len) in shard_lens.iter_mut().enumerate() {
                for (c, count) in counts.iter().enumerate() {
                    let (head, tail) = std::mem::take(&mut rest).split_at_mut(count[s]);
                    to[c].push(head);
                    rest = tail;
                    *len += count[s];
                }
            }
            to.into_par_iter()
                .zip(keyed.par_chunks(CHUNK))
                .for_each(|(mut to, from)| {
                    let mut fill = [0usize; SHARDS];
                    for k in from.iter().filter(|k| k.key != NO_KEY) {
                        let s = usize::from(k.shard);
                        to[s][fill[s]] = *k;
                        fill[s] += 1;
                    }
                });
            let mut rest: &[Keyed] = &sorted;
            for len in shard_lens {
                let (head, tail) = rest.split_at(len);
                shard_runs.push(head);
                rest = tail;
            }
        }
        self.dropped += dropped as u64;
        self.inserted += (n - dropped) as u64;
        self.shards
            .par_iter_mut()
            .zip(shard_runs)
            .for_each(|(shard, list)| {
                let (mut start, mut fetched) = (0, 0);
                for run in list.chunk_by(|a, b| a.key == b.key) {
                    let ahead = (start + PREFETCH_AHEAD).min(list.len());
                    while fetched < ahead {
                        if fetched == 0 || list[fetched - 1].key != list[fetched].key {
                            shard.prefetch(list[fetched].key);
                        }
                        fetched += 1;
                    }
                    Self::accumulate_run(shard, run, batch);
                    start += run.len();
                }
            });
        self.keyed = keyed;
        self.sorted = sorted;
    }

    fn voxel(&self, key: u64, a: &VoxelAcc) -> Voxel {
        let n = f64::from(a.count);
        let mean = |v: u32| ((f64::from(v) / n).round()).min(255.0) as u8;
        let corner = Self::corner(key, self.voxel_m);
        Voxel {
            key,
            // Clamped: an offset a hair below the edge may round up to it in f32.
            centroid: [0, 1, 2]
                .map(|i| corner[i] + (f64::from(a.offset_sum[i]) / n).clamp(0.0, self.voxel_m)),
            rgb: a.rgb.map(mean),
            count: a.count,
            viewpoint: self.viewpoints[a.batch as usize],
        }
    }

    /// The occupied voxels, sorted by key: centroid, mean colour, count and viewpoint.
    pub fn voxels(&self) -> Vec<Voxel> {
        let mut out: Vec<Voxel> = self
            .shards
            .par_iter()
            .flat_map_iter(|s| s.iter().map(|(key, a)| self.voxel(key, a)))
            .collect();
        out.par_sort_unstable_by_key(|v| v.key);
        out
    }

    /// The raw sums of the voxels with at least `min_count` points as one run per shard,
    /// each sorted by key, shards in parallel. Each shard is freed, and its memory handed
    /// back to the system ([`release_freed_memory`]), as soon as it is read, so the grid
    /// and its runs are never both held whole.
    fn take_sorted_runs(&mut self, min_count: u32) -> Vec<Vec<(u64, VoxelAcc)>> {
        let shards = std::mem::take(&mut self.shards);
        shards
            .into_par_iter()
            .map(|shard| {
                let mut run =
                    Vec::with_capacity(shard.iter().filter(|(_, a)| a.count >= min_count).count());
                run.extend(shard.into_entries().filter(|(_, a)| a.count >= min_count));
                run.sort_unstable_by_key(|e| e.0);
                release_freed_memory();
                run
            })
            .collect()
    }

    /// The runs cut into `parts` key ranges: for each part, the range of each run that
    /// it holds. The cuts are keys of the longest run at even steps, so the parts are
    /// about even; merged one by one and put end to end they are the whole merge, for
    /// any number of parts.
    fn merge_parts(runs: &[Vec<(u64, VoxelAcc)>], parts: usize) -> Vec<Vec<Range<usize>>> {
        let longest = runs
            .iter()
            .max_by_key(|r| r.len())
            .map_or(&[][..], |r| &r[..]);
        let mut cuts: Vec<u64> = (1..parts.max(1))
            .map(|j| j * longest.len() / parts)
            .filter(|&i| i > 0 && i < longest.len())
            .map(|i| longest[i].0)
            .collect();
        cuts.dedup();
        let mut from = vec![0usize; runs.len()];
        let mut out = Vec::with_capacity(cuts.len() + 1);
        for cut in cuts.iter().map(Some).chain([None]) {
            let to: Vec<usize> = runs
                .iter()
                .map(|r| cut.map_or(r.len(), |&c| r.partition_point(|e| e.0 < c)))
                .collect();
            out.push(from.iter().zip(&to).map(|(&a, &b)| a..b).collect());
            from = to;
        }
        out
    }

    /// Calls `f` on the voxels of the runs' `ranges` in ascending key order (a k-way
    /// merge; keys are unique across shards).
    fn merge_ranges(
        runs: &[Vec<(u64, VoxelAcc)>],
        ranges: &[Range<usize>],
        mut f: impl FnMut(u64, &VoxelAcc),
    ) {
        use std::cmp::Reverse;
        use std::collections::BinaryHeap;
        let mut next: Vec<usize> = ranges.iter().map(|r| r.start).collect();
        let mut heads = BinaryHeap::with_capacity(runs.len());
        for (r, range) in ranges.iter().enumerate() {
            if !range.is_empty() {
                heads.push(Reverse((runs[r][range.start].0, r)));
            }
        }
        while let Some(Reverse((key, r))) = heads.pop() {
            f(key, &runs[r][next[r]].1);
            next[r] += 1;
            if next[r] < ranges[r].end {
                heads.push(Reverse((runs[r][next[r]].0, r)));
            }
        }
    }

    /// The voxels with at least `min_count` points, sorted by key.
    pub fn into_voxels(mut self, min_count: u32) -> Vec<Voxel> {
        let runs = self.take_sorted_runs(min_count);
        let mut out = Vec::with_capacity(runs.iter().map(Vec::len).sum());
        let whole: Vec<Range<usize>> = runs.iter().map(|r| 0..r.len()).collect();
        Self::merge_ranges(&runs, &whole, |k, a| out.push(self.voxel(k, a)));
        out
    }

    /// [`VoxelGrid::into_voxels`] as separate arrays (centroids in `f32`, mean colours,
    /// viewpoints), for a large map: at the peak, the sorted runs of raw sums (40 bytes
    /// per voxel) and the arrays (27 bytes), the grid's memory handed back as it is read.
    /// The merge runs in key ranges side by side ([`rayon`]), each into its own slice of
    /// the arrays: the same arrays on any thread count.
    pub fn into_points(mut self, min_count: u32) -> VoxelPoints {
        let runs = self.take_sorted_runs(min_count);
        let n = runs.iter().map(Vec::len).sum();
        let parts = Self::merge_parts(&runs, 4 * rayon::current_num_threads());
        let mut out = VoxelPoints {
            centroids: vec![[0.0; 3]; n],
            colors: vec![[0; 3]; n],
            viewpoints: vec![[0.0; 3]; n],
        };
        // Each part's slices of the three arrays, in key order.
        let mut slices = Vec::with_capacity(parts.len());
        let (mut c, mut k, mut v) = (
            &mut out.centroids[..],
            &mut out.colors[..],
            &mut out.viewpoints[..],
        );
        for ranges in &parts {
            let len = ranges.iter().map(ExactSizeIterator::len).sum();
            let (c0, c1) = std::mem::take(&mut c).split_at_mut(len);
            let (k0, k1) = std::mem::take(&mut k).split_at_mut(len);
            let (v0, v1) = std::mem::take(&mut v).split_at_mut(len);
            slices.push((c0, k0, v0, ranges));
            (c, k, v) = (c1, k1, v1);
        }
        let this = &self;
        slices.into_par_iter().for_each(|(c, k, v, ranges)| {
            let mut i = 0;
            Self::merge_ranges(&runs, ranges, |key, a| {
                let voxel = this.voxel(key, a);
                c[i] = voxel.centroid.map(|x| x as f32);
                k[i] = voxel.rgb;
                v[i] = voxel.viewpoint;
                i += 1;
            });
        });
        drop(runs);
        release_freed_memory();
        out
    }
}

/// Hands the memory freed to the allocator back to the system. glibc keeps freed blocks
/// below its (adaptive, up to 32 MB) mmap threshold in its arenas, where they still count
/// as resident: a drained voxel grid's hash-table shards would stay resident while the
/// map's arrays are filled. No-op elsewhere.
pub fn release_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim has no preconditions; it only returns free pages of the
    // allocator's own arenas to the kernel.
    #[allow(unsafe_code)]
    unsafe {
        libc::malloc_trim(0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_round_trip_and_sort_lexicographically() {
        for idx in [[0, 0, 0], [-1, 5, -7], [1_048_575, -1_048_576, 3]] {
            assert_eq!(VoxelGrid::index_of_key(VoxelGrid::key_of_index(idx)), idx);
        }
        let a = VoxelGrid::key_of_index([-1, 100, 100]);
        let b = VoxelGrid::key_of_index([0, -100, -100]);
        assert!(a < b);
        let g = VoxelGrid::new(0.01);
        assert_eq!(g.index_of([0.005, -0.005, 0.0199]), Some([0, -1, 1]));
        assert_eq!(g.index_of([f64::NAN, 0.0, 0.0]), None);
        assert_eq!(g.index_of([1e5, 0.0, 0.0]), None);
    }

    #[test]
    fn parallel_and_serial_batches_agree_bitwise() {
        // Same points inserted as one large batch and as many small ones.
        let pts: Vec<[f64; 3]> = (0..100_000)
            .map(|i| {
                let f = f64::from(i);
                [
                    (f * 0.618).fract(),
                    (f * 0.414).fract(),
                    (f * 0.732).fract(),
                ]
            })
            .collect();
        let cols: Vec<[u8; 3]> = (0..100_000).map(|i| [(i % 251) as u8, 7, 9]).collect();
        let mut big = VoxelGrid::new(0.05);
        big.insert(&pts, &cols, [0.0; 3]);
        let mut small = VoxelGrid::new(0.05);
        for (p, c) in pts.chunks(1000).zip(cols.chunks(1000)) {
            small.insert(p, c, [0.0; 3]);
        }
        assert_eq!(big.voxels(), small.voxels());
        assert_eq!(big.inserted(), 100_000);
    }

    #[test]
    fn sums_are_those_of_one_point_at_a_time_in_input_order() {
        // Rows of a "depth image": runs of neighbouring points in one voxel, runs
        // interleaved with other voxels, a NaN and an out-of-range point among them.
        let mut pts: Vec<[f64; 3]> = Vec::new();
        for v in 0..300 {
            for u in 0..400 {
                let (x, y) = (f64::from(u) * 0.0031, f64::from(v) * 0.0027);
                pts.push([x, y, 0.5 + 0.01 * (x * 7.0).sin() + 0.003 * y]);
            }
        }
        pts[777] = [f64::NAN, 0.0, 0.0];
        pts[778] = [1e9, 0.0, 0.0];
        let cols: Vec<[u8; 3]> = (0..pts.len()).map(|i| [(i % 256) as u8, 1, 2]).collect();
        for batch in [pts.len(), 1000] {
            let mut g = VoxelGrid::new(0.01);
            for (p, c) in pts.chunks(batch).zip(cols.chunks(batch)) {
                g.insert(p, c, [0.0; 3]);
            }
            // The reference: one point at a time, a map look-up each, in input order.
            let mut sums: std::collections::BTreeMap<u64, ([f32; 3], [u32; 3], u32)> =
                Default::default();
            for (p, c) in pts.iter().zip(&cols) {
                let Some(idx) = g.index_of(*p) else { continue };
                let corner = idx.map(|i| i as f64 * 0.01);
                let e = sums.entry(VoxelGrid::key_of_index(idx)).or_default();
                for i in 0..3 {
                    e.0[i] += (p[i] - corner[i]) as f32;
                    e.1[i] += u32::from(c[i]);
                }
                e.2 += 1;
            }
            let voxels = g.voxels();
            assert_eq!(voxels.len(), sums.len());
            assert_eq!(g.dropped(), 2);
            let mut runs = 0;
            for (v, (key, (off, rgb, count))) in voxels.iter().zip(&sums) {
                assert_eq!((v.key, v.count), (*key, *count));
                let shard = &g.shards[shard_of(*key)];
                let acc = *shard.get(*key).expect("the voxel is in its shard");
                assert_eq!((acc.offset_sum, acc.rgb), (*off, *rgb), "voxel {key}");
                runs += usize::from(*count > 1);
            }
            assert!(runs > voxels.len() / 2, "most voxels take several points");
        }
    }

    #[test]
    fn points_are_the_voxels_as_arrays_in_key_order() {
        // 50 k uniform points (xorshift) in 8000 voxels, 6.25 per voxel on average, in
        // five batches (viewpoints). The second method: every voxel (`voxels`, collected
        // and sorted), the sparse ones left out.
        let mut state: u64 = 0x2545_F491_4F6C_DD1D;
        let mut next = || crate::mapper::test_rng::next_unit(&mut state);
        let pts: Vec<[f64; 3]> = (0..50_000).map(|_| [next(), next(), next()]).collect();
        let cols: Vec<[u8; 3]> = (0..pts.len()).map(|i| [(i % 251) as u8, 20, 30]).collect();
        let mut g = VoxelGrid::new(0.05);
        for (b, (p, c)) in pts.chunks(10_000).zip(cols.chunks(10_000)).enumerate() {
            g.insert(p, c, [1.0, 2.0, b as f32]);
        }
        let min = 6;
        let voxels: Vec<Voxel> = g.voxels().into_iter().filter(|v| v.count >= min).collect();
        assert!(
            voxels.len() > 1000 && voxels.len() < g.len(),
            "{} of {} voxels at min {min}",
            voxels.len(),
            g.len()
        );
        let expected = VoxelPoints {
            centroids: voxels
                .iter()
                .map(|v| v.centroid.map(|c| c as f32))
                .collect(),
            colors: voxels.iter().map(|v| v.rgb).collect(),
            viewpoints: voxels.iter().map(|v| v.viewpoint).collect(),
        };
        assert_eq!(g.clone().into_voxels(min), voxels);
        // Any number of threads, so of key ranges merged side by side.
        for threads in [1, 2, 3, 8] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("a thread pool");
            assert_eq!(pool.install(|| g.clone().into_points(min)), expected);
        }
        // The parts tile every run, in key order, for any count: more parts than voxels
        // included, and an empty grid.
        let runs = g.clone().take_sorted_runs(min);
        for parts in [1, 2, 7, 64, 100_000] {
            let cut = VoxelGrid::merge_parts(&runs, parts);
            assert!(!cut.is_empty() && cut.len() <= parts);
            for (r, run) in runs.iter().enumerate() {
                assert_eq!(cut[0][r].start, 0);
                assert_eq!(cut[cut.len() - 1][r].end, run.len());
                for w in cut.windows(2) {
                    assert_eq!(w[0][r].end, w[1][r].start);
                }
            }
            for w in cut.windows(2) {
                let last = w[0]
                    .iter()
                    .zip(&runs)
                    .filter_map(|(x, run)| x.clone().last().map(|i| run[i].0))
                    .max();
                let first = w[1]
                    .iter()
                    .zip(&runs)
                    .filter_map(|(x, run)| run.get(x.start).filter(|_| !x.is_empty()).map(|e| e.0))
                    .min();
                if let (Some(a), Some(b)) = (last, first) {
                    assert!(a < b, "parts overlap in keys");
                }
            }
        }
        let empty = VoxelGrid::new(0.05);
        assert_eq!(empty.clone().into_points(1), VoxelPoints::default());
        assert_eq!(
            VoxelGrid::merge_parts(&empty.clone().take_sorted_runs(1), 8).len(),
            1
        );
    }
}
