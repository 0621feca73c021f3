//! ORB features (Rublee et al., ICCV 2011) as ORB-SLAM extracts them, with the paper's
//! distribution step: per pyramid level, adaptive per-cell FAST ([`super::fast`]), then
//! Suppression via Square Covering ([`super::ssc`]) instead of ORB-SLAM's octree; the
//! orientation by intensity centroid over a circular patch of radius 15 px and a steered
//! 256-bit BRIEF descriptor on the Gaussian-smoothed level.
//!
//! The BRIEF sampling pattern is generated deterministically, not the learned table of
//! OpenCV: 256 point pairs drawn from an isotropic Gaussian of σ = 31/5 px (BRIEF's
//! "G II" distribution for a 31 px patch; Calonder et al. 2010), each coordinate
//! approximated by the Irwin–Hall sum of 12 uniforms (pure integer/float arithmetic, so
//! the table is identical on every platform), rounded, rejected outside `[-13, 13]`
//! (ORB's patch bound, so a rotated sample stays within 19 px), and rejected when both
//! points coincide. The uniforms come from SplitMix64 seeded with [`PATTERN_SEED`].

use super::fast::{Corner, FastConfig, FastDetector};
use super::image::{BlurScratch, GrayImage, Pyramid, gaussian_blur7};
use super::ssc::{SscScratch, ssc};
use super::{ConfigError, check};
use serde::{Deserialize, Serialize};
use std::sync::OnceLock;

/// Radius of the orientation patch, px (ORB's `HALF_PATCH_SIZE`).
pub const HALF_PATCH: usize = 15;

/// Diameter of the descriptor patch, px, at level 0 (ORB's `PATCH_SIZE`).
pub const PATCH_SIZE: f32 = 31.0;

/// Keypoints keep this distance from each level's border so that the orientation patch
/// and every rotated BRIEF sample lie inside the image (ORB-SLAM's `EDGE_THRESHOLD`).
pub const EDGE: usize = 19;

/// Seed of the BRIEF pattern.
pub const PATTERN_SEED: u64 = 0x0B5E_55ED_F00D_B41E;

/// Largest coordinate of a BRIEF sample, px.
pub const PATTERN_BOUND: i32 = 13;

/// A 256-bit binary descriptor; bit `i` (word `i / 64`, bit `i % 64`) is
/// `I(p_i) < I(q_i)` for the `i`-th steered point pair.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Descriptor(pub [u64; 4]);

impl Descriptor {
    /// Hamming distance (0..=256).
    pub fn distance(&self, other: &Descriptor) -> u32 {
        hamming(self, other)
    }
}

/// Hamming distance between two descriptors (popcount of the XOR).
pub fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    a.0.iter()
        .zip(b.0.iter())
        .map(|(x, y)| (x ^ y).count_ones())
        .sum()
}

/// An ORB keypoint.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KeyPoint {
    /// Column in level-0 pixels (pixel centres at integers).
    pub x: f32,
    /// Row in level-0 pixels.
    pub y: f32,
    /// Pyramid level (octave) it was detected in.
    pub level: u8,
    /// Orientation, rad, in `(-π, π]`, measured from +x towards +y (image axes, y down).
    pub angle_rad: f32,
    /// FAST score (the largest threshold at which it is a corner).
    pub response: f32,
    /// Diameter of its patch in level-0 pixels (31 · scale of its level).
    pub size: f32,
}

/// Keypoints and their descriptors for one image (parallel arrays).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Features {
    /// Image width, px.
    pub width: usize,
    /// Image height, px.
    pub height: usize,
    /// Keypoints, level by level, strongest first within a level.
    pub keypoints: Vec<KeyPoint>,
    /// Descriptor of each keypoint.
    pub descriptors: Vec<Descriptor>,
}

impl Features {
    /// Number of keypoints.
    pub fn len(&self) -> usize {
        self.keypoints.len()
    }

    /// Whether there are no keypoints.
    pub fn is_empty(&self) -> bool {
        self.keypoints.is_empty()
    }

    fn clear(&mut self) {
        self.keypoints.clear();
        self.descriptors.clear();
    }
}

/// ORB extraction settings.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct OrbConfig {
    /// Keypoints wanted per image across all levels (SSC keeps about this many).
    pub n_features: usize,
    /// Pyramid levels.
    pub n_levels: usize,
    /// Scale factor between levels.
    pub scale_factor: f64,
    /// Relative tolerance of SSC's count (the paper's 0.1).
    pub ssc_tolerance: f32,
    /// Per-cell adaptive FAST.
    pub fast: FastConfig,
}

/// Default pyramid depth: 1.2^5 ≈ 2.5× scale range. ORB-SLAM's 8 levels (3.6×) serve
/// relocalisation after large viewpoint changes; along a vineyard row frame-to-frame scale
/// changes are small and loops close on tags, not on feature matches. 6 levels cost about
/// 10 % less pixel work than 8 (Σ 1.44^-k = 2.89 vs 3.10 of level 0) and about half
/// the keypoints of the two coarsest levels, whose 210×134 images are mostly border.
pub const DEFAULT_LEVELS: usize = 6;

impl Default for OrbConfig {
    fn default() -> Self {
        OrbConfig {
            n_features: 1000,
            n_levels: DEFAULT_LEVELS,
            scale_factor: 1.2,
            ssc_tolerance: 0.1,
            fast: FastConfig::default(),
        }
    }
}

impl OrbConfig {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check(self.n_features > 0, "orb.n_features must be > 0")?;
        check(
            (1..=16).contains(&self.n_levels),
            "orb.n_levels must be in 1..=16",
        )?;
        check(
            self.scale_factor > 1.0 && self.scale_factor <= 2.0,
            "orb.scale_factor must be in (1, 2]",
        )?;
        check(
            (0.0..1.0).contains(&self.ssc_tolerance),
            "orb.ssc_tolerance must be in [0, 1)",
        )?;
        let f = &self.fast;
        check(
            f.low_threshold >= 1 && f.low_threshold <= f.high_threshold,
            "orb.fast: need 1 <= low_threshold <= high_threshold",
        )?;
        check(f.cell_size_px >= 8, "orb.fast.cell_size_px must be >= 8")?;
        Ok(())
    }

    /// Keypoints wanted at each level: a geometric series of ratio `1 / scale_factor`
    /// summing to `n_features` (ORB-SLAM's `mnFeaturesPerLevel`).
    pub fn features_per_level(&self) -> Vec<usize> {
        let n = self.n_levels.max(1);
        let f = 1.0 / self.scale_factor;
        let mut wanted = self.n_features as f64 * (1.0 - f) / (1.0 - f.powi(n as i32));
        let mut out = Vec::with_capacity(n);
        let mut sum = 0;
        for _ in 0..n - 1 {
            let k = wanted.round() as usize;
            out.push(k);
            sum += k;
            wanted *= f;
        }
        out.push(self.n_features.saturating_sub(sum));
        out
    }
}

/// SplitMix64 (Steele, Lea & Flood 2014).
fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The BRIEF point pairs `[x_p, y_p, x_q, y_q]` (see the module docs).
pub fn brief_pattern() -> &'static [[i8; 4]; 256] {
    static PATTERN: OnceLock<[[i8; 4]; 256]> = OnceLock::new();
    PATTERN.get_or_init(|| {
        let mut state = PATTERN_SEED;
        let sigma = f64::from(PATCH_SIZE) / 5.0;
        let mut coord = || loop {
            // Irwin–Hall: 12 uniforms on [0, 1) sum to mean 6, variance 1.
            let s: f64 = (0..12)
                .map(|_| (splitmix64(&mut state) >> 11) as f64 / (1u64 << 53) as f64)
                .sum();
            let v = ((s - 6.0) * sigma).round() as i32;
            if v.abs() <= PATTERN_BOUND {
                return v as i8;
            }
        };
        let mut out = [[0i8; 4]; 256];
        for pair in out.iter_mut() {
            loop {
                let p = [coord(), coord(), coord(), coord()];
                if p[0] != p[2] || p[1] != p[3] {
                    *pair = p;
                    break;
                }
            }
        }
        out
    })
}

/// The points of [`brief_pattern`] as coordinate arrays `(x, y)`: point `2k` is pair
/// `k`'s first, `2k + 1` its second.
fn brief_points() -> &'static ([i32; 512], [i32; 512]) {
    static POINTS: OnceLock<([i32; 512], [i32; 512])> = OnceLock::new();
    POINTS.get_or_init(|| {
        let pattern = brief_pattern();
        let (mut xs, mut ys) = ([0i32; 512], [0i32; 512]);
        for (k, p) in pattern.iter().enumerate() {
            xs[2 * k] = i32::from(p[0]);
            ys[2 * k] = i32::from(p[1]);
            xs[2 * k + 1] = i32::from(p[2]);
            ys[2 * k + 1] = i32::from(p[3]);
        }
        (xs, ys)
    })
}

/// Half-widths of the circular orientation patch per row offset `v = 0..=15` (ORB's
/// `umax`, made symmetric under swapping x and y so that a 90° rotation of the image
/// rotates the centroid exactly).
fn umax() -> &'static [usize; HALF_PATCH + 1] {
    static UMAX: OnceLock<[usize; HALF_PATCH + 1]> = OnceLock::new();
    UMAX.get_or_init(|| {
        let mut u = [0usize; HALF_PATCH + 1];
        let r = HALF_PATCH as f64;
        let vmax = (r * std::f64::consts::SQRT_2 / 2.0 + 1.0).floor() as usize;
        let vmin = (r * std::f64::consts::SQRT_2 / 2.0).ceil() as usize;
        for (v, item) in u.iter_mut().enumerate().take(vmax + 1) {
            *item = (r * r - (v * v) as f64).sqrt().round() as usize;
        }
        let mut v0 = 0;
        for v in (vmin..=HALF_PATCH).rev() {
            while u[v0] == u[v0 + 1] {
                v0 += 1;
            }
            u[v] = v0;
            v0 += 1;
        }
        u
    })
}

/// Orientation of the patch around `(x, y)` (≥ 15 px from the border): the angle of the
/// vector from the centre to the intensity centroid of the radius-15 disc, rad.
pub fn ic_angle(img: &GrayImage, x: usize, y: usize) -> f32 {
    let u = umax();
    let r = HALF_PATCH;
    let (mut m01, mut m10) = (0i64, 0i64);
    let centre = img.row(y);
    for dx in 0..=2 * r {
        m10 += (dx as i64 - r as i64) * i64::from(centre[x + dx - r]);
    }
    for (v, &d) in u.iter().enumerate().skip(1) {
        let below = img.row(y + v);
        let above = img.row(y - v);
        let mut v_sum = 0i64;
        for xx in x - d..=x + d {
            let (p, m) = (i64::from(below[xx]), i64::from(above[xx]));
            v_sum += p - m;
            m10 += (xx as i64 - x as i64) * (p + m);
        }
        m01 += v as i64 * v_sum;
    }
    (m01 as f32).atan2(m10 as f32)
}

/// The steered BRIEF descriptor of `(x, y)` (≥ [`EDGE`] px from the border) with
/// orientation `angle_rad`, sampled on the smoothed image `blurred`.
pub fn describe(blurred: &GrayImage, x: usize, y: usize, angle_rad: f32) -> Descriptor {
    // Fixed point (12 fractional bits): the rotated offsets of all 512 samples are integer
    // arithmetic (vectorizes), rounded half up; exact for multiples of 90°.
    const ONE: f32 = 4096.0;
    let (s, c) = angle_rad.sin_cos();
    let (s, c) = ((s * ONE).round() as i32, (c * ONE).round() as i32);
    let w = blurred.width() as isize;
    let data = blurred.data();
    let centre = y as isize * w + x as isize;
    let (xs, ys) = brief_points();
    // Offsets from the centre in i32 over separate coordinate arrays, so the rotation
    // runs in vector lanes.
    let w32 = w as i32;
    let mut offsets = [0i32; 512];
    for (i, o) in offsets.iter_mut().enumerate() {
        let rx = (xs[i] * c - ys[i] * s + 2048) >> 12;
        let ry = (xs[i] * s + ys[i] * c + 2048) >> 12;
        *o = ry * w32 + rx;
    }
    let mut d = [0u64; 4];
    for (word, pairs) in d.iter_mut().zip(offsets.chunks_exact(128)) {
        let mut bits = 0u64;
        for (j, pair) in pairs.chunks_exact(2).enumerate() {
            let a = data[(centre + pair[0] as isize) as usize];
            let b = data[(centre + pair[1] as isize) as usize];
            bits |= u64::from(a < b) << j;
        }
        *word = bits;
    }
    Descriptor(d)
}

/// Sorts `corners` by descending score, stably, through `scratch` (counting sort).
fn counting_sort_by_score(
    corners: &mut Vec<Corner>,
    scratch: &mut Vec<Corner>,
    hist: &mut Vec<usize>,
) {
    hist.clear();
    hist.resize(257, 0);
    for c in corners.iter() {
        hist[usize::from(255 - c.score) + 1] += 1;
    }
    for i in 1..257 {
        hist[i] += hist[i - 1];
    }
    scratch.clear();
    scratch.resize(
        corners.len(),
        Corner {
            x: 0,
            y: 0,
            score: 0,
        },
    );
    for c in corners.iter() {
        let slot = &mut hist[usize::from(255 - c.score)];
        scratch[*slot] = *c;
        *slot += 1;
    }
    std::mem::swap(corners, scratch);
}

/// ORB extraction with reusable buffers: after the first frame of a size, extracting
/// allocates nothing unless a level yields more corners than ever before.
#[derive(Clone, Debug)]
pub struct OrbExtractor {
    cfg: OrbConfig,
    per_level: Vec<usize>,
    pyramid: Pyramid,
    fast: FastDetector,
    corners: Vec<Corner>,
    sorted: Vec<Corner>,
    histogram: Vec<usize>,
    points: Vec<[f32; 2]>,
    kept: Vec<usize>,
    ssc: SscScratch,
    blurred: GrayImage,
    blur: BlurScratch,
}

impl OrbExtractor {
    /// An extractor with a validated `cfg`.
    pub fn new(cfg: OrbConfig) -> Result<OrbExtractor, ConfigError> {
        cfg.validate()?;
        Ok(OrbExtractor {
            per_level: cfg.features_per_level(),
            pyramid: Pyramid::new(cfg.n_levels, cfg.scale_factor),
            fast: FastDetector::new(cfg.fast.clone()),
            cfg,
            corners: Vec::new(),
            sorted: Vec::new(),
            histogram: Vec::new(),
            points: Vec::new(),
            kept: Vec::new(),
            ssc: SscScratch::default(),
            blurred: GrayImage::default(),
            blur: BlurScratch::default(),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &OrbConfig {
        &self.cfg
    }

    /// The pyramid of the last extracted image (stereo matching reads its levels).
    pub fn pyramid(&self) -> &Pyramid {
        &self.pyramid
    }

    /// Extracts the ORB features of `img` into `out` (cleared first).
    pub fn extract(&mut self, img: &GrayImage, out: &mut Features) {
        out.clear();
        out.width = img.width();
        out.height = img.height();
        self.pyramid.build(img);
        for k in 0..self.pyramid.n_levels() {
            let level = self.pyramid.level(k);
            self.corners.clear();
            self.fast.detect(level, EDGE, &mut self.corners);
            if self.corners.is_empty() {
                continue;
            }
            // Strongest first; equal scores keep the detection order (cell by cell, raster
            // order within a cell): a stable counting sort on the 8-bit score.
            counting_sort_by_score(&mut self.corners, &mut self.sorted, &mut self.histogram);
            self.points.clear();
            self.points
                .extend(self.corners.iter().map(|c| [c.x as f32, c.y as f32]));
            ssc(
                &self.points,
                self.per_level[k],
                self.cfg.ssc_tolerance,
                level.width() as f32,
                level.height() as f32,
                &mut self.ssc,
                &mut self.kept,
            );
            gaussian_blur7(level, &mut self.blurred, &mut self.blur);
            let scale = self.pyramid.scale(k);
            for &i in &self.kept {
                let c = self.corners[i];
                let (x, y) = (c.x as usize, c.y as usize);
                let angle = ic_angle(level, x, y);
                out.keypoints.push(KeyPoint {
                    x: self.pyramid.to_level0(k, x as f64) as f32,
                    y: self.pyramid.to_level0(k, y as f64) as f32,
                    level: k as u8,
                    angle_rad: angle,
                    response: f32::from(c.score),
                    size: PATCH_SIZE * scale as f32,
                });
                out.descriptors.push(describe(&self.blurred, x, y, angle));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pattern_is_deterministic_bounded_and_spread() {
        let p = brief_pattern();
        assert!(
            p.iter()
                .flatten()
                .all(|&v| i32::from(v).abs() <= PATTERN_BOUND)
        );
        assert!(p.iter().all(|q| q[0] != q[2] || q[1] != q[3]));
        // σ = 6.2 clipped at 13: the sample standard deviation is about 5.5–6.
        let n = (256 * 4) as f64;
        let var = p
            .iter()
            .flatten()
            .map(|&v| f64::from(v).powi(2))
            .sum::<f64>()
            / n;
        assert!((4.5..6.5).contains(&var.sqrt()), "σ = {}", var.sqrt());
    }

    #[test]
    fn umax_is_symmetric() {
        let u = umax();
        // The disc's extent along x at row v equals its extent along y at column v.
        for v in 0..=HALF_PATCH {
            let along_y = (0..=HALF_PATCH).filter(|&w| u[w] >= v).count() - 1;
            assert_eq!(u[v], along_y, "v = {v}");
        }
    }

    #[test]
    fn features_per_level_sum_to_the_target() {
        let c = OrbConfig::default();
        let v = c.features_per_level();
        assert_eq!(v.iter().sum::<usize>(), c.n_features);
        assert!(v.windows(2).all(|w| w[0] >= w[1]));
    }
}
