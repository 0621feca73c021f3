//! Timing of the feature front-end, for `vinebench bench` (see `crate::bench`, which
//! feeds it a rendered vineyard pair) and for anyone with a pair of images.

use super::ConfigError;
use super::frontend::{FrontEndConfig, StereoFrame, StereoFrontEnd};
use super::image::GrayImage;
use super::orb::{Features, OrbExtractor};
use super::stereo::{StereoCamera, StereoMatcher, StereoMatches};
use std::hint::black_box;
use std::time::Instant;

/// Front-end figures on one stereo pair, best of the repeats.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrontEndTimings {
    /// ORB extraction of the left image (pyramid, FAST, SSC, orientation, descriptors),
    /// one thread, ms.
    pub extract_ms_per_image: f64,
    /// Stereo matching of the pair's features (given both extractions), ms.
    pub stereo_ms_per_pair: f64,
    /// The whole pair through [`StereoFrontEnd::process`] with the two extractions on two
    /// rayon tasks, ms.
    pub pair_ms: f64,
    /// The same, serial (`FrontEndConfig::serial`), ms.
    pub pair_ms_serial: f64,
    /// Keypoints of the left image.
    pub keypoints_left: usize,
    /// Left keypoints with a right match.
    pub stereo_matched: usize,
    /// Left keypoints with a depth (below the depth limit).
    pub stereo_depths: usize,
}

fn best_ms(repeats: usize, mut f: impl FnMut()) -> f64 {
    f(); // warm-up: buffers sized, caches filled
    let mut best = f64::INFINITY;
    for _ in 0..repeats.max(1) {
        let t0 = Instant::now();
        f();
        best = best.min(t0.elapsed().as_secs_f64() * 1e3);
    }
    best
}

/// Times the front-end with `cfg` on the rectified pair `left`/`right` of `cam`.
pub fn time_front_end(
    cfg: &FrontEndConfig,
    cam: &StereoCamera,
    left: &GrayImage,
    right: &GrayImage,
    repeats: usize,
) -> Result<FrontEndTimings, ConfigError> {
    let mut ex = OrbExtractor::new(cfg.orb.clone())?;
    let mut ex_r = OrbExtractor::new(cfg.orb.clone())?;
    let (mut fl, mut fr) = (Features::default(), Features::default());
    let extract_ms_per_image = best_ms(repeats, || {
        ex.extract(black_box(left), &mut fl);
    });
    ex_r.extract(right, &mut fr);
    let mut matcher = StereoMatcher::new(cfg.stereo.clone())?;
    let mut m = StereoMatches::default();
    let stereo_ms_per_pair = best_ms(repeats, || {
        matcher.match_pair(cam, &fl, ex.pyramid(), &fr, ex_r.pyramid(), &mut m);
    });
    let mut frame = StereoFrame::default();
    let mut fe = StereoFrontEnd::new(FrontEndConfig {
        serial: false,
        ..cfg.clone()
    })?;
    let pair_ms = best_ms(repeats, || {
        fe.process(cam, black_box(left), right, &mut frame)
    });
    let mut fe_serial = StereoFrontEnd::new(FrontEndConfig {
        serial: true,
        ..cfg.clone()
    })?;
    let mut frame_serial = StereoFrame::default();
    let pair_ms_serial = best_ms(repeats, || {
        fe_serial.process(cam, black_box(left), right, &mut frame_serial)
    });
    Ok(FrontEndTimings {
        extract_ms_per_image,
        stereo_ms_per_pair,
        pair_ms,
        pair_ms_serial,
        keypoints_left: frame.left.len(),
        stereo_matched: frame.stereo.n_matched(),
        stereo_depths: frame.stereo.n_with_depth(),
    })
}

/// Deterministic smooth value noise in `[0, 1)`: a hashed lattice of spacing `cell` px,
/// smoothstep-interpolated, at any real position.
pub fn value_noise(x: f64, y: f64, cell: f64, seed: u64) -> f64 {
    let hash = |ix: i64, iy: i64| -> f64 {
        let mut h = seed
            ^ (ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
        h ^= h >> 33;
        h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
        h ^= h >> 33;
        (h >> 11) as f64 / (1u64 << 53) as f64
    };
    let (u, v) = (x / cell, y / cell);
    let (ix, iy) = (u.floor(), v.floor());
    let (fx, fy) = (u - ix, v - iy);
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let (sx, sy) = (s(fx), s(fy));
    let (ix, iy) = (ix as i64, iy as i64);
    let top = hash(ix, iy) * (1.0 - sx) + hash(ix + 1, iy) * sx;
    let bottom = hash(ix, iy + 1) * (1.0 - sx) + hash(ix + 1, iy + 1) * sx;
    top * (1.0 - sy) + bottom * sy
}

/// A textured, rectified pair of a fronto-parallel plane: the right image is the left one
/// shifted left by `disparity_px` (sampled from the continuous texture, so subpixel
/// disparities are exact).
pub fn synthetic_pair(width: usize, height: usize, disparity_px: f64) -> (GrayImage, GrayImage) {
    let tex = |x: f64, y: f64| -> u8 {
        let t = 0.55 * value_noise(x, y, 7.0, 1) + 0.45 * value_noise(x, y, 2.5, 2);
        (30.0 + 200.0 * t).round() as u8
    };
    let left = GrayImage::from_fn(width, height, |x, y| tex(x as f64, y as f64));
    let right = GrayImage::from_fn(width, height, |x, y| tex(x as f64 + disparity_px, y as f64));
    (left, right)
}
