//! The hash table of one shard of the voxel grid (`voxel::VoxelGrid`): open addressing
//! with linear probing over one array of `(key, sums)` slots, so a batch can *prefetch*
//! the slot of a point several points ahead while it adds the current one.
//!
//! A map of millions of 1 cm voxels is hundreds of megabytes: nearly every look-up
//! misses the caches, and one point at a time waits for each miss in turn (a profile of
//! `map-row` before this table: nine tenths of the time adding points was spent waiting
//! on the table's memory). With the home slots of the next [`PREFETCH_AHEAD`] points
//! already on their way, the misses overlap.
//!
//! Keys are packed voxel keys (63 bits at most), so two values above them mark an empty
//! slot and a deleted one (a tombstone: [`VoxelTable::retain`] leaves them, look-ups step
//! over them, insertions reuse them, and a tombstone with an empty slot after it becomes
//! empty itself). The table doubles when live and deleted slots pass three quarters of
//! it, and is rebuilt at its size when tombstones alone would make it grow.

/// Running sums of one voxel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VoxelAcc {
    /// Sum of the points' offsets from the voxel's lowest corner, m.
    pub offset_sum: [f32; 3],
    /// Sum of the sRGB colours.
    pub rgb: [u32; 3],
    /// Number of points.
    pub count: u32,
    /// The batch (`VoxelGrid::insert` call) that touched the voxel last.
    pub batch: u32,
}

impl VoxelAcc {
    /// No points yet (batch 0).
    pub const ZERO: VoxelAcc = VoxelAcc {
        offset_sum: [0.0; 3],
        rgb: [0; 3],
        count: 0,
        batch: 0,
    };
}

/// An empty slot (no packed key reaches it: keys have 63 bits).
const EMPTY: u64 = u64::MAX;
/// A deleted slot.
const DELETED: u64 = u64::MAX - 1;
/// Points looked ahead to prefetch.
pub const PREFETCH_AHEAD: usize = 12;
/// Smallest number of slots (a power of two).
const MIN_SLOTS: usize = 16;

/// Fibonacci hashing's multiplier (2⁶⁴ / φ, odd).
const MUL: u64 = 0x9E37_79B9_7F4A_7C15;

/// The shard of a key among `1 << shard_bits`: the product's top bits.
#[inline]
pub fn shard_of(key: u64, shard_bits: u32) -> usize {
    (key.wrapping_mul(MUL) >> (64 - shard_bits)) as usize
}

#[derive(Clone, Copy, Debug)]
struct Slot {
    key: u64,
    acc: VoxelAcc,
}

const VACANT: Slot = Slot {
    key: EMPTY,
    acc: VoxelAcc::ZERO,
};

/// One shard's voxels: packed key → running sums.
#[derive(Clone, Debug)]
pub struct VoxelTable {
    slots: Vec<Slot>,
    /// Live entries.
    len: usize,
    /// Tombstones.
    deleted: usize,
    /// The bits of the hash below the shard's that pick the home slot.
    shard_bits: u32,
}

impl VoxelTable {
    /// An empty table for the keys of one shard of `1 << shard_bits`.
    pub fn new(shard_bits: u32) -> VoxelTable {
        VoxelTable {
            slots: Vec::new(),
            len: 0,
            deleted: 0,
            shard_bits,
        }
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the table holds no voxel.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Heap bytes held.
    pub fn memory_bytes(&self) -> usize {
        self.slots.capacity() * std::mem::size_of::<Slot>()
    }

    /// The home slot of `key`: the product's bits just below the shard's.
    #[inline]
    fn home(&self, key: u64) -> usize {
        let bits = self.slots.len().trailing_zeros();
        ((key.wrapping_mul(MUL) << self.shard_bits) >> (64 - bits)) as usize
    }

    /// Starts loading the home slot of `key` into the caches (a hint: no effect on
    /// results).
    #[inline]
    pub fn prefetch(&self, key: u64) {
        if self.slots.is_empty() {
            return;
        }
        let slot = &self.slots[self.home(key)];
        let first: *const Slot = slot;
        prefetch_bytes(first.cast::<u8>());
        // A 40-byte slot may reach into the next cache line.
        prefetch_bytes(
            first
                .cast::<u8>()
                .wrapping_add(std::mem::size_of::<Slot>() - 1),
        );
    }

    /// The sums of `key`, inserted as `fresh` if absent.
    #[inline]
    pub fn entry(&mut self, key: u64, fresh: VoxelAcc) -> &mut VoxelAcc {
        debug_assert!(key < DELETED);
        if (self.len + self.deleted + 1) * 4 > self.slots.len() * 3 {
            self.grow();
        }
        let mask = self.slots.len() - 1;
        let mut i = self.home(key);
        let mut reuse = None;
        loop {
            let k = self.slots[i].key;
            if k == key {
                return &mut self.slots[i].acc;
            }
            if k == EMPTY {
                break;
            }
            if k == DELETED && reuse.is_none() {
                reuse = Some(i);
            }
            i = (i + 1) & mask;
        }
        if let Some(r) = reuse {
            i = r;
            self.deleted -= 1;
        }
        self.len += 1;
        self.slots[i] = Slot { key, acc: fresh };
        &mut self.slots[i].acc
    }

    /// The sums of `key`, if present.
    pub fn get(&self, key: u64) -> Option<&VoxelAcc> {
        if self.slots.is_empty() {
            return None;
        }
        let mask = self.slots.len() - 1;
        let mut i = self.home(key);
        loop {
            let k = self.slots[i].key;
            if k == key {
                return Some(&self.slots[i].acc);
            }
            if k == EMPTY {
                return None;
            }
            i = (i + 1) & mask;
        }
    }

    /// Doubles the table, or rebuilds it at its size when tombstones fill it.
    fn grow(&mut self) {
        let slots = if self.slots.is_empty() {
            MIN_SLOTS
        } else if (self.len + 1) * 8 > self.slots.len() * 3 {
            self.slots.len() * 2
        } else {
            self.slots.len()
        };
        let old = std::mem::replace(&mut self.slots, vec![VACANT; slots]);
        self.deleted = 0;
        let mask = slots - 1;
        for s in old.into_iter().filter(|s| s.key < DELETED) {
            let mut i = self.home(s.key);
            while self.slots[i].key != EMPTY {
                i = (i + 1) & mask;
            }
            self.slots[i] = s;
        }
    }

    /// Keeps the voxels for which `keep` holds; returns how many were dropped.
    pub fn retain(&mut self, mut keep: impl FnMut(&VoxelAcc) -> bool) -> usize {
        let before = self.len;
        for s in &mut self.slots {
            if s.key < DELETED && !keep(&s.acc) {
                s.key = DELETED;
                self.len -= 1;
                self.deleted += 1;
            }
        }
        self.clear_tombstones_before_empty();
        before - self.len
    }

    /// Empties every tombstone that an empty slot follows (no probe needs to step over
    /// it: it would stop at the empty slot next), walking the ring backwards from an
    /// empty slot so runs of tombstones clear at once.
    fn clear_tombstones_before_empty(&mut self) {
        let n = self.slots.len();
        let Some(start) = self.slots.iter().position(|s| s.key == EMPTY) else {
            return;
        };
        let mut next_empty = true;
        for step in 1..n {
            let i = (start + n - step) % n;
            let s = &mut self.slots[i];
            if s.key == DELETED && next_empty {
                s.key = EMPTY;
                self.deleted -= 1;
            }
            next_empty = s.key == EMPTY;
        }
    }

    /// The voxels, in slot order.
    pub fn iter(&self) -> impl Iterator<Item = (u64, &VoxelAcc)> {
        self.slots
            .iter()
            .filter(|s| s.key < DELETED)
            .map(|s| (s.key, &s.acc))
    }

    /// The voxels, in slot order, the table consumed.
    pub fn into_entries(self) -> impl Iterator<Item = (u64, VoxelAcc)> {
        self.slots
            .into_iter()
            .filter(|s| s.key < DELETED)
            .map(|s| (s.key, s.acc))
    }
}

/// Starts loading the cache line at `p` (x86-64 `prefetcht0`; nothing elsewhere).
#[inline]
fn prefetch_bytes(p: *const u8) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch is a hint: it never faults and reads nothing the program sees,
    // whatever the address; `p` points into (or one line past the start of) a live slot.
    #[allow(unsafe_code)]
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(p.cast::<i8>());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    #[test]
    fn behaves_as_a_hash_map_through_inserts_deletes_and_growth() {
        // A second method: std's HashMap, driven by the same random operations.
        let mut state: u64 = 0x1234_5678_9ABC_DEF1;
        let mut next = || crate::mapper::test_rng::next_u64(&mut state);
        for shard_bits in [0, 6] {
            let mut t = VoxelTable::new(shard_bits);
            let mut reference: HashMap<u64, u32> = HashMap::new();
            for round in 0..40 {
                for _ in 0..2000 {
                    // Keys from a small range (many repeats) and spread over 63 bits.
                    let r = next();
                    let key = if r & 1 == 0 { r % 5000 } else { r >> 1 };
                    if shard_bits > 0 && shard_of(key, shard_bits) != 0 {
                        continue;
                    }
                    t.prefetch(key);
                    t.entry(key, VoxelAcc::ZERO).count += 1;
                    *reference.entry(key).or_default() += 1;
                }
                // Drop about half, as the grid's prune does.
                let parity = round % 2;
                let dropped = t.retain(|a| a.count % 2 == parity);
                let before = reference.len();
                reference.retain(|_, c| *c % 2 == parity);
                assert_eq!(dropped, before - reference.len());
                assert_eq!(t.len(), reference.len());
                for (k, c) in &reference {
                    assert_eq!(t.get(*k).map(|a| a.count), Some(*c), "key {k}");
                }
                let mut seen: Vec<(u64, u32)> = t.iter().map(|(k, a)| (k, a.count)).collect();
                seen.sort_unstable();
                let mut want: Vec<(u64, u32)> = reference.iter().map(|(k, c)| (*k, *c)).collect();
                want.sort_unstable();
                assert_eq!(seen, want);
                assert!(t.get(EMPTY - 7).is_none());
                // Live and deleted slots stay under three quarters of the table.
                assert!((t.len + t.deleted) * 4 <= t.slots.len() * 3);
            }
            assert!(!reference.is_empty());
        }
    }
}
