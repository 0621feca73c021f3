//! `vinebench bench --only recording`: recording speed figures (issue #5).
//!
//! - Write: VGA colour images (deterministic gradient plus per-pixel noise, about as
//!   compressible as rendered camera images) through [`Recorder`] (CDR encoding, zstd
//!   level [`crate::recording::writer::ZSTD_LEVEL`], chunking on the recording thread)
//!   into a file; MB/s of CDR payload from the first hand-over to the finished file.
//! - Read: the same file scanned and every image decoded, MB/s of payload.
//! - Run cost: `scenarios/row-loop-rtk-outage.toml` simulated with and without its
//!   recording (best of the repeats each), as a slowdown in percent.

use crate::bench::{BenchError, Figure};
use crate::recording::{RecordItem, Recorder, SinkOptions, reader, ros};
use crate::runner::{setup, simulate_setup};
use crate::scenario::LoadedScenario;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;
use vinebench_msgs::{FrameId, ImageEncoding, ImageMsg, Message, Nanos, TimedMessage};

/// Width of the benchmark images, px.
pub const IMAGE_WIDTH: u32 = 640;
/// Height of the benchmark images, px.
pub const IMAGE_HEIGHT: u32 = 480;

/// Target of the issue: writing image-sized messages with zstd, MB/s.
pub const WRITE_TARGET_MB_S: f64 = 200.0;
/// Target of the issue: reading for replay, MB/s.
pub const READ_TARGET_MB_S: f64 = 500.0;
/// Target of the issue: slowdown of a run by its recording, percent (at most).
pub const SLOWDOWN_LIMIT_PERCENT: f64 = 10.0;

/// `n` distinct VGA `rgb8` images: a gradient with ±6 levels of per-pixel noise
/// (a xorshift stream, no RNG crate needed).
pub fn synthetic_images(n: usize) -> Vec<ImageMsg> {
    let topic: Arc<str> = Arc::from("/front/left/image_rect");
    let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
    (0..n)
        .map(|k| {
            let (w, h) = (IMAGE_WIDTH as usize, IMAGE_HEIGHT as usize);
            let mut data = Vec::with_capacity(w * h * 3);
            for y in 0..h {
                for x in 0..w {
                    for c in 0..3 {
                        state ^= state << 13;
                        state ^= state >> 7;
                        state ^= state << 17;
                        let base = ((x * (c + 1) + y * 2 + k * 5) / 3) % 200 + 20;
                        let noise = (state % 13) as usize;
                        data.push((base + noise) as u8);
                    }
                }
            }
            ImageMsg {
                stamp: Nanos::from_secs(1_700_000_000) + Nanos::from_millis(33 * k as i64),
                topic: topic.clone(),
                frame_id: FrameId::new("front_left_optical"),
                width: IMAGE_WIDTH,
                height: IMAGE_HEIGHT,
                encoding: ImageEncoding::Rgb8,
                data: Arc::from(data),
            }
        })
        .collect()
}

fn bench_path(tag: &str) -> PathBuf {
    std::env::temp_dir().join(format!("vinebench-bench-{}-{tag}.mcap", std::process::id()))
}

fn io(path: &Path) -> impl FnOnce(crate::recording::RecordingError) -> BenchError + '_ {
    move |e| BenchError::Setup(format!("{}: {e}", path.display()))
}

/// Writes `images` (repeated `rounds` times) to `path` through a [`Recorder`]; MB/s of
/// CDR payload.
pub fn write_mb_per_s(images: &[ImageMsg], rounds: usize, path: &Path) -> Result<f64, BenchError> {
    let t0 = Instant::now();
    let mut rec = Recorder::create(path, &SinkOptions::default()).map_err(io(path))?;
    for r in 0..rounds {
        for (i, img) in images.iter().enumerate() {
            let mut img = img.clone();
            img.stamp += Nanos::from_millis((r * images.len() + i) as i64);
            rec.send(RecordItem::Message(TimedMessage {
                arrival: img.stamp,
                msg: Message::Image(img),
            }));
        }
    }
    let stats = rec.finish().map_err(io(path))?;
    Ok(stats.payload_bytes as f64 / 1e6 / t0.elapsed().as_secs_f64())
}

/// Reads `path` and decodes every image; MB/s of CDR payload.
pub fn read_mb_per_s(path: &Path) -> Result<f64, BenchError> {
    let t0 = Instant::now();
    let mut bytes = 0u64;
    let mut bad = 0u64;
    let mut topic: Option<Arc<str>> = None;
    let summary = reader::scan_file(path, |ch, m| {
        bytes += m.data.len() as u64;
        let t = topic.get_or_insert_with(|| Arc::from(ch.topic.as_str()));
        match ros::decode_image(m.data, t) {
            Ok(img) => {
                std::hint::black_box(img);
            }
            Err(_) => bad += 1,
        }
    })
    .map_err(io(path))?;
    let s = t0.elapsed().as_secs_f64();
    if bad > 0 || summary.damage.is_some() {
        return Err(BenchError::Setup(format!(
            "{}: {bad} images did not decode; damage: {:?}",
            path.display(),
            summary.damage
        )));
    }
    Ok(bytes as f64 / 1e6 / s)
}

/// Wall seconds of `scenarios/row-loop-rtk-outage.toml` (simulate, estimate; no scoring),
/// best of `repeats`, with or without its recording.
pub fn run_seconds(recording: bool, repeats: usize) -> Result<f64, BenchError> {
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/row-loop-rtk-outage.toml");
    let sc = LoadedScenario::load(&file)?;
    let path = bench_path("run");
    let mut best = f64::INFINITY;
    for _ in 0..repeats.max(1) {
        let mut built = setup(&sc)?;
        let t0 = Instant::now();
        if recording {
            built.recorder =
                Some(Recorder::create(&path, &SinkOptions::default()).map_err(io(&path))?);
        }
        std::hint::black_box(simulate_setup(&sc, built, None)?);
        best = best.min(t0.elapsed().as_secs_f64());
    }
    let _ = std::fs::remove_file(&path);
    Ok(best)
}

/// The recording figures.
pub fn recording_figures(quick: bool) -> Result<Vec<Figure>, BenchError> {
    let images = synthetic_images(30);
    let (rounds, repeats) = if quick { (2, 1) } else { (10, 3) };
    let path = bench_path("images");
    let mut write = 0.0f64;
    let mut read = 0.0f64;
    for _ in 0..repeats {
        write = write.max(write_mb_per_s(&images, rounds, &path)?);
        read = read.max(read_mb_per_s(&path)?);
    }
    let _ = std::fs::remove_file(&path);
    let without = run_seconds(false, repeats)?;
    let with = run_seconds(true, repeats)?;
    Ok(vec![
        Figure {
            name: "recording write, VGA rgb8 images, zstd (background thread), MB/s of CDR",
            value: write,
            unit: "MB/s",
            target: Some(WRITE_TARGET_MB_S),
        },
        Figure {
            name: "recording read + decode, VGA rgb8 images, MB/s of CDR",
            value: read,
            unit: "MB/s",
            target: Some(READ_TARGET_MB_S),
        },
        Figure {
            name: "row-loop-rtk-outage without recording, wall s",
            value: without,
            unit: "s",
            target: None,
        },
        Figure {
            name: "row-loop-rtk-outage with recording, wall s",
            value: with,
            unit: "s",
            target: None,
        },
        Figure {
            name: "slowdown of a run by its recording (limit 10 %)",
            value: (with / without - 1.0) * 100.0,
            unit: "%",
            target: None,
        },
    ])
}
