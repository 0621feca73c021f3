//! A long run's memory does not grow with its length (issue #33).
//!
//! A counting allocator measures the peak of live heap bytes while a whole run (simulate,
//! recording, TUM files, scoring, report) executes, once for one lap of the default row
//! loop and once for four laps. Holding the 200 Hz ground truth alone would add 72 bytes
//! × 200 Hz = 14.4 kB per simulated second (about 11 MB for the three extra laps), the
//! estimates another 30 kB/s; what may grow is the route sampled up front and the
//! per-pose error values scoring keeps for exact medians (16 bytes per associated pose),
//! together well below [`MAX_GROWTH_BYTES_PER_S`]. `/usr/bin/time` figures of an 8-hour shift
//! are in docs/PERFORMANCE.md.
#![allow(unsafe_code, clippy::unwrap_used)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};
use vinebench::runner::{RunOptions, run};
use vinebench::scenario::LoadedScenario;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

/// Counts live bytes and their peak.
struct Counting;

fn grew(size: usize) {
    let now = LIVE.fetch_add(size, Ordering::Relaxed) + size;
    PEAK.fetch_max(now, Ordering::Relaxed);
}

// SAFETY: every method forwards to `System` with the caller's layout.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded as is.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded as is.
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded as is.
        unsafe { System.dealloc(ptr, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: forwarded as is.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
            grew(new_size);
        }
        p
    }
}

#[global_allocator]
static A: Counting = Counting;

/// The most the peak may grow per extra simulated second (bytes): a third of what the
/// ground truth alone would need if it were held (the estimates with their covariances
/// would need more still). Measured: about 1.7 kB/s (the longer route, and scoring's
/// per-pose errors; which sources' scoring overlaps on the two threads moves it by up to
/// 1 kB/s).
const MAX_GROWTH_BYTES_PER_S: f64 = 14_400.0 / 3.0;

/// Peak live heap bytes of a whole run of the default scenario with `laps` laps, and its
/// simulated duration.
fn peak_of_run(laps: u32) -> (usize, f64) {
    let sc = LoadedScenario::from_str(
        &format!("name = \"mem\"\n[route.row_loop]\nlaps = {laps}\n"),
        "memory.toml",
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let dir = tempfile::tempdir().unwrap();
    let opts = RunOptions {
        out_dir: Some(dir.path().join("run")),
        progress: false,
        ..RunOptions::default()
    };
    PEAK.store(LIVE.load(Ordering::Relaxed), Ordering::Relaxed);
    let before = LIVE.load(Ordering::Relaxed);
    let out = run(&sc, &opts).unwrap_or_else(|e| panic!("{e}"));
    let peak = PEAK.load(Ordering::Relaxed) - before;
    let simulated = out.report.run.duration_s;
    assert!(
        out.report.sources.iter().all(|s| s.poses > 1000),
        "the estimators ran"
    );
    (peak, simulated)
}

#[test]
fn a_runs_peak_memory_does_not_grow_with_its_length() {
    let (short_peak, short_s) = peak_of_run(1);
    let (long_peak, long_s) = peak_of_run(4);
    assert!(long_s > 3.5 * short_s, "{short_s} s vs {long_s} s");
    let growth = long_peak.saturating_sub(short_peak) as f64 / (long_s - short_s);
    eprintln!(
        "peak {:.1} MB for {short_s:.0} s, {:.1} MB for {long_s:.0} s: {growth:.0} B per simulated second",
        short_peak as f64 / 1e6,
        long_peak as f64 / 1e6
    );
    assert!(
        growth < MAX_GROWTH_BYTES_PER_S,
        "the peak grew by {growth:.0} bytes per simulated second (at most \
         {MAX_GROWTH_BYTES_PER_S} allowed): something holds the run's trajectories"
    );
}
