//! Incremental voxel-grid downsampling: a hash map from voxel keys to running sums
//! (position, colour, count, last viewpoint), so memory grows with the mapped area and
//! not with the number of frames.
//!
//! A voxel takes 40 bytes in its shard (before the hash table's slack): the key, the sum
//! of its points' offsets from the voxel's corner in `f32` (an offset is below one voxel
//! edge, so the centroid is exact to about `count · 1e-7` voxel edges), the colour sums,
//! the count and the index of the batch (frame) that saw it last; the batches' sensor
//! positions are kept once, in a table. [`VoxelGrid::prune`] drops the voxels with too
//! few points that no recent batch touched: the depth noise of a far surface scatters
//! single points over many voxels that never see a second one.
//!
//! The map is split into [`SHARDS`] hash maps by a hash of the key. A batch of points is
//! keyed in parallel, bucketed by shard (a counting sort that keeps input order), and the
//! shards are filled in parallel. Each shard sees its points in input order, so every sum
//! is accumulated in the same order whatever the thread count: results are bit-identical
//! across runs and machines. [`VoxelGrid::voxels`] returns the voxels sorted by key.

use rayon::prelude::*;
use rustc_hash::FxHashMap;

/// Number of hash-map shards (a power of two).
pub const SHARDS: usize = 64;
/// Bits per axis in a packed voxel key.
pub const AXIS_BITS: u32 = 21;
/// Offset that makes axis indices non-negative.
const AXIS_OFFSET: i64 = 1 << (AXIS_BITS - 1);
/// Batches smaller than this are inserted on the calling thread.
const PARALLEL_MIN_POINTS: usize = 32_768;
/// Marks a point that has no voxel (NaN, or beyond ±2²⁰ voxels from the origin).
const NO_KEY: u64 = u64::MAX;

/// Running sums of one voxel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VoxelAcc {
    /// Sum of the points' offsets from the voxel's lowest corner, m.
    pub offset_sum: [f32; 3],
    /// Sum of the sRGB colours.
    pub rgb: [u32; 3],
    /// Number of points.
    pub count: u32,
    /// The batch ([`VoxelGrid::insert`] call) that touched the voxel last.
    pub batch: u32,
}

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
    shards: Vec<FxHashMap<u64, VoxelAcc>>,
    /// Sensor position of every batch, world frame.
    viewpoints: Vec<[f32; 3]>,
    dropped: u64,
    inserted: u64,
    // Scratch reused between batches.
    keys: Vec<u64>,
    order: Vec<u32>,
}

/// `(x·K) >> 58` with a 64-bit odd constant: the top bits of a multiplicative hash.
#[inline]
fn shard_of(key: u64) -> usize {
    (key.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> (64 - SHARDS.trailing_zeros())) as usize
}

impl VoxelGrid {
    /// An empty grid of voxel edge `voxel_m` (> 0).
    pub fn new(voxel_m: f64) -> VoxelGrid {
        VoxelGrid {
            voxel_m,
            shards: (0..SHARDS).map(|_| FxHashMap::default()).collect(),
            viewpoints: Vec::new(),
            dropped: 0,
            inserted: 0,
            keys: Vec::new(),
            order: Vec::new(),
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
        let entry = std::mem::size_of::<(u64, VoxelAcc)>() + 1;
        self.shards
            .iter()
            .map(|s| s.capacity() * entry)
            .sum::<usize>()
            + self.viewpoints.capacity() * std::mem::size_of::<[f32; 3]>()
    }

    /// Drops every voxel with fewer than `min_count` points that no batch from
    /// `before_batch` on has touched; returns how many. Sums of the voxels kept are
    /// untouched, and a dropped voxel that a later batch hits starts again from zero.
    pub fn prune(&mut self, min_count: u32, before_batch: u32) -> usize {
        self.shards
            .par_iter_mut()
            .map(|s| {
                let n = s.len();
                s.retain(|_, a| a.count >= min_count || a.batch >= before_batch);
                n - s.len()
            })
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

    #[inline]
    fn accumulate(
        shard: &mut FxHashMap<u64, VoxelAcc>,
        voxel_m: f64,
        key: u64,
        p: [f64; 3],
        c: [u8; 3],
        batch: u32,
    ) {
        let corner = Self::corner(key, voxel_m);
        let acc = shard.entry(key).or_insert(VoxelAcc {
            offset_sum: [0.0; 3],
            rgb: [0; 3],
            count: 0,
            batch,
        });
        for i in 0..3 {
            acc.offset_sum[i] += (p[i] - corner[i]) as f32;
            acc.rgb[i] += u32::from(c[i]);
        }
        acc.count += 1;
        acc.batch = batch;
    }

    /// Adds a batch of world points with their colours, all seen from `viewpoint` (the
    /// sensor position, world frame). `colors` must be as long as `points`.
    pub fn insert(&mut self, points: &[[f64; 3]], colors: &[[u8; 3]], viewpoint: [f32; 3]) {
        let n = points.len().min(colors.len());
        let (points, colors) = (&points[..n], &colors[..n]);
        let batch = self.viewpoints.len() as u32;
        self.viewpoints.push(viewpoint);
        let voxel_m = self.voxel_m;
        if n < PARALLEL_MIN_POINTS {
            for (p, c) in points.iter().zip(colors) {
                let key = self.key(*p);
                if key == NO_KEY {
                    self.dropped += 1;
                    continue;
                }
                self.inserted += 1;
                let shard = &mut self.shards[shard_of(key)];
                Self::accumulate(shard, voxel_m, key, *p, *c, batch);
            }
            return;
        }
        // Keys in parallel.
        let mut keys = std::mem::take(&mut self.keys);
        keys.clear();
        keys.resize(n, 0);
        let this = &*self;
        keys.par_chunks_mut(8192)
            .zip(points.par_chunks(8192))
            .for_each(|(k, p)| {
                for (k, p) in k.iter_mut().zip(p) {
                    *k = this.key(*p);
                }
            });
        // Counting sort of point indices by shard (stable: input order within a shard).
        let mut counts = [0usize; SHARDS + 1];
        let mut dropped = 0u64;
        for &k in &keys {
            if k == NO_KEY {
                dropped += 1;
            } else {
                counts[shard_of(k) + 1] += 1;
            }
        }
        for s in 0..SHARDS {
            counts[s + 1] += counts[s];
        }
        let mut order = std::mem::take(&mut self.order);
        order.clear();
        order.resize(counts[SHARDS], 0);
        let mut next = counts;
        for (i, &k) in keys.iter().enumerate() {
            if k != NO_KEY {
                let s = shard_of(k);
                order[next[s]] = i as u32;
                next[s] += 1;
            }
        }
        self.dropped += dropped;
        self.inserted += (n as u64) - dropped;
        let (keys_ref, order_ref) = (&keys, &order);
        self.shards
            .par_iter_mut()
            .enumerate()
            .for_each(|(s, shard)| {
                for &i in &order_ref[counts[s]..counts[s + 1]] {
                    let i = i as usize;
                    let (k, p, c) = (keys_ref[i], points[i], colors[i]);
                    Self::accumulate(shard, voxel_m, k, p, c, batch);
                }
            });
        self.keys = keys;
        self.order = order;
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
            .flat_map_iter(|s| s.iter().map(|(&key, a)| self.voxel(key, a)))
            .collect();
        out.par_sort_unstable_by_key(|v| v.key);
        out
    }

    /// The raw sums of the voxels with at least `min_count` points as one run per shard,
    /// each sorted by key. Each shard is freed, and its memory handed back to the system
    /// ([`release_freed_memory`]), as soon as it is read, so the grid and its runs are
    /// never both held whole.
    fn take_sorted_runs(&mut self, min_count: u32) -> Vec<Vec<(u64, VoxelAcc)>> {
        let shards = std::mem::take(&mut self.shards);
        let mut runs = Vec::with_capacity(shards.len());
        for shard in shards {
            let mut run =
                Vec::with_capacity(shard.values().filter(|a| a.count >= min_count).count());
            run.extend(shard.into_iter().filter(|(_, a)| a.count >= min_count));
            run.par_sort_unstable_by_key(|e| e.0);
            runs.push(run);
            release_freed_memory();
        }
        runs
    }

    /// Calls `f` on the voxels of `runs` in ascending key order (a k-way merge; keys are
    /// unique across shards), freeing each run once it is read.
    fn merge_runs(runs: Vec<Vec<(u64, VoxelAcc)>>, mut f: impl FnMut(u64, &VoxelAcc)) {
        use std::cmp::Reverse;
        use std::collections::BinaryHeap;
        let mut runs: Vec<std::vec::IntoIter<(u64, VoxelAcc)>> =
            runs.into_iter().map(Vec::into_iter).collect();
        let mut current: Vec<Option<VoxelAcc>> = vec![None; runs.len()];
        let mut heads = BinaryHeap::with_capacity(runs.len());
        for (r, run) in runs.iter_mut().enumerate() {
            if let Some((key, acc)) = run.next() {
                current[r] = Some(acc);
                heads.push(Reverse((key, r)));
            }
        }
        while let Some(Reverse((key, r))) = heads.pop() {
            if let Some(acc) = current[r].take() {
                f(key, &acc);
            }
            match runs[r].next() {
                Some((next, acc)) => {
                    current[r] = Some(acc);
                    heads.push(Reverse((next, r)));
                }
                // Frees the run's buffer.
                None => runs[r] = Vec::new().into_iter(),
            }
        }
    }

    /// The voxels with at least `min_count` points, sorted by key.
    pub fn into_voxels(mut self, min_count: u32) -> Vec<Voxel> {
        let runs = self.take_sorted_runs(min_count);
        let mut out = Vec::with_capacity(runs.iter().map(Vec::len).sum());
        Self::merge_runs(runs, |k, a| out.push(self.voxel(k, a)));
        out
    }

    /// [`VoxelGrid::into_voxels`] as separate arrays (centroids in `f32`, mean colours,
    /// viewpoints), for a large map: at the peak, the sorted runs of raw sums (40 bytes
    /// per voxel) and the arrays (27 bytes), the grid's memory handed back as it is read.
    pub fn into_points(mut self, min_count: u32) -> VoxelPoints {
        let runs = self.take_sorted_runs(min_count);
        let n = runs.iter().map(Vec::len).sum();
        let mut out = VoxelPoints {
            centroids: Vec::with_capacity(n),
            colors: Vec::with_capacity(n),
            viewpoints: Vec::with_capacity(n),
        };
        Self::merge_runs(runs, |k, a| {
            let v = self.voxel(k, a);
            out.centroids.push(v.centroid.map(|c| c as f32));
            out.colors.push(v.rgb);
            out.viewpoints.push(v.viewpoint);
        });
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
    fn points_are_the_voxels_as_arrays_in_key_order() {
        // 50 k uniform points (xorshift) in 8000 voxels: 6.25 per voxel on average.
        let mut state: u64 = 0x2545_F491_4F6C_DD1D;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let pts: Vec<[f64; 3]> = (0..50_000).map(|_| [next(), next(), next()]).collect();
        let cols = vec![[10, 20, 30]; pts.len()];
        let mut g = VoxelGrid::new(0.05);
        g.insert(&pts, &cols, [1.0, 2.0, 3.0]);
        let min = 6;
        let voxels = g.clone().into_voxels(min);
        assert!(voxels.windows(2).all(|w| w[0].key < w[1].key), "sorted");
        assert!(
            voxels.len() > 1000 && voxels.len() < g.len(),
            "{} of {} voxels at min {min}",
            voxels.len(),
            g.len()
        );
        let points = g.into_points(min);
        let expected = VoxelPoints {
            centroids: voxels
                .iter()
                .map(|v| v.centroid.map(|c| c as f32))
                .collect(),
            colors: voxels.iter().map(|v| v.rgb).collect(),
            viewpoints: voxels.iter().map(|v| v.viewpoint).collect(),
        };
        assert_eq!(points, expected);
    }
}
