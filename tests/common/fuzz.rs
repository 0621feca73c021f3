//! The fuzz harness shared by `tests/fuzz_*.rs`: structure-aware mutations of real input
//! files driven by proptest (stable Rust), a checked-in corpus replayed on every run, and
//! an allocator that refuses any single allocation above [`MAX_ALLOC_BYTES`] and any live
//! total above [`MAX_LIVE_BYTES`] (the process then aborts naming the size: a finding).
//!
//! Each fuzz test binary installs the allocator with
//! `#[global_allocator] static A: common::fuzz::LimitAlloc = common::fuzz::LimitAlloc;`
//!
//! Budget: `VINEBENCH_FUZZ_CASES` mutated inputs per target (default [`DEFAULT_CASES`]),
//! set higher by `.ci/run`'s fuzz stage and by anyone hunting. Each target's corpus lives in
//! `tests/fuzz/corpus/<target>/`: every file there must give a named error or a result.
#![allow(unsafe_code, dead_code)]

use proptest::prelude::*;
use std::alloc::{GlobalAlloc, Layout, System};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

/// The largest single allocation any input may cause (bytes).
pub const MAX_ALLOC_BYTES: usize = 1 << 30;
/// The most memory live at once in a fuzz binary (bytes; all threads together).
pub const MAX_LIVE_BYTES: usize = 6 << 30;
/// Mutated inputs per target when `VINEBENCH_FUZZ_CASES` is not set.
pub const DEFAULT_CASES: u32 = 64;

static LIVE: AtomicUsize = AtomicUsize::new(0);

/// The bounded allocator (see the module documentation).
pub struct LimitAlloc;

fn refuse(size: usize) -> bool {
    size > MAX_ALLOC_BYTES || LIVE.load(Ordering::Relaxed).saturating_add(size) > MAX_LIVE_BYTES
}

// SAFETY: every method forwards to `System` with the caller's layout; refusing returns null,
// which the `GlobalAlloc` contract allows.
unsafe impl GlobalAlloc for LimitAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if refuse(layout.size()) {
            return std::ptr::null_mut();
        }
        // SAFETY: forwarded as is.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            LIVE.fetch_add(layout.size(), Ordering::Relaxed);
        }
        p
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if refuse(layout.size()) {
            return std::ptr::null_mut();
        }
        // SAFETY: forwarded as is.
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            LIVE.fetch_add(layout.size(), Ordering::Relaxed);
        }
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded as is.
        unsafe { System.dealloc(ptr, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if new_size > layout.size() && refuse(new_size - layout.size())
            || new_size > MAX_ALLOC_BYTES
        {
            return std::ptr::null_mut();
        }
        // SAFETY: forwarded as is.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            LIVE.fetch_add(new_size, Ordering::Relaxed);
            LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        }
        p
    }
}

/// Mutated inputs per target: `VINEBENCH_FUZZ_CASES` or [`DEFAULT_CASES`].
pub fn cases() -> u32 {
    std::env::var("VINEBENCH_FUZZ_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(DEFAULT_CASES)
}

/// The proptest configuration of a fuzz target: [`cases`] cases, failures persisted beside
/// the test file (`tests/fuzz_<x>.proptest-regressions`, replayed first on every run).
pub fn config() -> ProptestConfig {
    ProptestConfig {
        cases: cases(),
        max_shrink_iters: 256,
        ..ProptestConfig::default()
    }
}

/// One structure-aware change to a file's bytes.
#[derive(Clone, Debug)]
pub enum Mutation {
    /// XOR the byte at `at` (fraction of the length) with `mask` (never 0).
    Flip { at: f64, mask: u8 },
    /// Keep only the first `keep` (fraction) of the bytes.
    Truncate { keep: f64 },
    /// Overwrite the little-endian u32 or u64 at `at` with a lie (huge, zero, off by one,
    /// just past the end).
    LengthLie { at: f64, wide: bool, lie: Lie },
    /// Remove `len` bytes at `at`.
    Delete { at: f64, len: usize },
    /// Insert `bytes` at `at`.
    Insert { at: f64, bytes: Vec<u8> },
    /// Copy `len` bytes from `from` over `to` (a record's bytes where another's were).
    Splice { from: f64, to: f64, len: usize },
}

/// What a [`Mutation::LengthLie`] writes.
#[derive(Clone, Copy, Debug)]
pub enum Lie {
    /// All ones.
    Max,
    /// Zero.
    Zero,
    /// The value there plus one.
    PlusOne,
    /// The value there minus one.
    MinusOne,
    /// The remaining length of the file plus `n`.
    PastEnd(u16),
    /// 2^k.
    Pow2(u8),
}

fn index(len: usize, at: f64) -> usize {
    ((len as f64 * at) as usize).min(len.saturating_sub(1))
}

impl Mutation {
    /// Applies the mutation to `bytes`.
    pub fn apply(&self, bytes: &mut Vec<u8>) {
        if bytes.is_empty() {
            return;
        }
        let n = bytes.len();
        match self {
            Mutation::Flip { at, mask } => bytes[index(n, *at)] ^= mask,
            Mutation::Truncate { keep } => bytes.truncate((n as f64 * keep) as usize),
            Mutation::LengthLie { at, wide, lie } => {
                let w = if *wide { 8 } else { 4 };
                if n < w {
                    return;
                }
                let i = index(n - w + 1, *at);
                let mut cur = [0u8; 8];
                cur[..w].copy_from_slice(&bytes[i..i + w]);
                let cur = u64::from_le_bytes(cur);
                let max = if *wide { u64::MAX } else { u64::from(u32::MAX) };
                let v = match lie {
                    Lie::Max => max,
                    Lie::Zero => 0,
                    Lie::PlusOne => cur.wrapping_add(1) & max,
                    Lie::MinusOne => cur.wrapping_sub(1) & max,
                    Lie::PastEnd(k) => ((n - i) as u64 + u64::from(*k)) & max,
                    Lie::Pow2(k) => (1u64 << (k % if *wide { 64 } else { 32 })) & max,
                };
                bytes[i..i + w].copy_from_slice(&v.to_le_bytes()[..w]);
            }
            Mutation::Delete { at, len } => {
                let i = index(n, *at);
                let end = (i + len).min(n);
                bytes.drain(i..end);
            }
            Mutation::Insert { at, bytes: ins } => {
                let i = index(n, *at);
                bytes.splice(i..i, ins.iter().copied());
            }
            Mutation::Splice { from, to, len } => {
                let f = index(n, *from);
                let t = index(n, *to);
                let l = (*len).min(n - f).min(n - t);
                let src = bytes[f..f + l].to_vec();
                bytes[t..t + l].copy_from_slice(&src);
            }
        }
    }
}

fn lie() -> impl Strategy<Value = Lie> {
    prop_oneof![
        Just(Lie::Max),
        Just(Lie::Zero),
        Just(Lie::PlusOne),
        Just(Lie::MinusOne),
        any::<u16>().prop_map(Lie::PastEnd),
        any::<u8>().prop_map(Lie::Pow2),
    ]
}

/// Any one mutation.
pub fn mutation() -> impl Strategy<Value = Mutation> {
    let at = 0.0..1.0f64;
    prop_oneof![
        4 => (at.clone(), 1..=255u8).prop_map(|(at, mask)| Mutation::Flip { at, mask }),
        2 => (0.0..1.0f64).prop_map(|keep| Mutation::Truncate { keep }),
        3 => (at.clone(), any::<bool>(), lie())
            .prop_map(|(at, wide, lie)| Mutation::LengthLie { at, wide, lie }),
        1 => (at.clone(), 1..64usize).prop_map(|(at, len)| Mutation::Delete { at, len }),
        1 => (at.clone(), proptest::collection::vec(any::<u8>(), 1..16))
            .prop_map(|(at, bytes)| Mutation::Insert { at, bytes }),
        1 => (at.clone(), at, 1..256usize)
            .prop_map(|(from, to, len)| Mutation::Splice { from, to, len }),
    ]
}

/// One to `max` mutations applied in order.
pub fn mutations(max: usize) -> impl Strategy<Value = Vec<Mutation>> {
    proptest::collection::vec(mutation(), 1..=max)
}

/// `seed` with `muts` applied.
pub fn mutate(seed: &[u8], muts: &[Mutation]) -> Vec<u8> {
    let mut b = seed.to_vec();
    for m in muts {
        m.apply(&mut b);
    }
    b
}

/// The corpus folder of a target.
pub fn corpus_dir(target: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fuzz/corpus")
        .join(target)
}

/// Every file of a target's corpus (sorted), with its bytes. Panics when the folder is
/// missing or empty: a target without a corpus is not fuzzed from real files.
pub fn corpus(target: &str) -> Vec<(PathBuf, Vec<u8>)> {
    let dir = corpus_dir(target);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    assert!(!files.is_empty(), "{}: empty corpus", dir.display());
    files
        .into_iter()
        .map(|p| {
            let b = std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            (p, b)
        })
        .collect()
}

/// Runs `f` and turns a panic into a test failure naming `what` (the input) and the panic
/// message, so a finding says which corpus file or mutation caused it.
pub fn no_panic<R>(what: &str, f: impl FnOnce() -> R) -> R {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)) {
        Ok(r) => r,
        Err(e) => {
            let msg = e
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| e.downcast_ref::<&str>().map(|s| (*s).to_string()))
                .unwrap_or_default();
            panic!("{what}: panicked: {msg}");
        }
    }
}
