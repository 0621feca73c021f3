//! Stereo matching of ORB keypoints in a rectified pair (ORB-SLAM2's
//! `Frame::ComputeStereoMatches`), with the paper's depth limit.
//!
//! For each left keypoint: the right keypoints whose row band (±2 px × level scale)
//! contains its row, within one pyramid level of it and with a disparity in
//! `[0, f·b / z_min]`, are compared by Hamming distance; the best one below the threshold
//! is refined to subpixel precision by sum-of-absolute-differences correlation of an
//! 11×11 window (intensities taken relative to the window centre) at the left keypoint's
//! level, ±5 px along the row, and a parabola through the best three costs. Matches whose
//! correlation cost exceeds 2.1 × the median are dropped as outliers. The depth
//! `z = f·b / d` is reported only below 40 baselines (the paper, after Paz et al. 2008);
//! farther matches keep their right-image column without a depth.

use super::image::Pyramid;
use super::orb::{Features, hamming};
use super::{ConfigError, check};
use serde::{Deserialize, Serialize};
use vinebench_msgs::CameraInfoMsg;

/// Geometry of a rectified stereo pair.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StereoCamera {
    /// Focal length of the rectified images, px.
    pub fx: f64,
    /// Distance between the optical centres, m.
    pub baseline_m: f64,
}

impl StereoCamera {
    /// From the right camera's `CameraInfo`: `P[3] = −fx·b` (ROS convention).
    pub fn from_right_info(right: &CameraInfoMsg) -> Option<StereoCamera> {
        let fx = right.p[0];
        let baseline_m = -right.p[3] / fx;
        (fx > 0.0 && baseline_m > 0.0).then_some(StereoCamera { fx, baseline_m })
    }

    /// `f·b`, px·m.
    pub fn fb(&self) -> f64 {
        self.fx * self.baseline_m
    }
}

/// Stereo matching settings.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct StereoConfig {
    /// A descriptor match is tried only when its Hamming distance is below this
    /// (ORB-SLAM's `(TH_HIGH + TH_LOW) / 2 = 75`).
    pub hamming_threshold: u32,
    /// Half-height of the row band searched in the right image at level 0, px (scaled by
    /// the keypoint's level scale).
    pub row_band_px: f32,
    /// Closest depth searched, in baselines (ORB-SLAM: 1, so `d_max = f`).
    pub min_depth_baselines: f64,
    /// Depths are reported only below this many baselines (the paper: 40).
    pub max_depth_baselines: f64,
    /// Half-size of the correlation window, px of the level (5: 11×11).
    pub sad_half_window: usize,
    /// Correlation search ±px around the descriptor match, px of the level.
    pub sad_search_px: usize,
    /// Matches whose correlation cost exceeds this times the median are dropped
    /// (ORB-SLAM: 1.5 · 1.4).
    pub outlier_factor: f32,
}

impl Default for StereoConfig {
    fn default() -> Self {
        StereoConfig {
            hamming_threshold: 75,
            row_band_px: 2.0,
            min_depth_baselines: 1.0,
            max_depth_baselines: 40.0,
            sad_half_window: 5,
            sad_search_px: 5,
            outlier_factor: 2.1,
        }
    }
}

impl StereoConfig {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check(
            self.hamming_threshold <= 256,
            "stereo.hamming_threshold must be <= 256",
        )?;
        check(self.row_band_px >= 0.0, "stereo.row_band_px must be >= 0")?;
        check(
            self.min_depth_baselines > 0.0 && self.max_depth_baselines > self.min_depth_baselines,
            "stereo: need 0 < min_depth_baselines < max_depth_baselines",
        )?;
        check(
            (1..=15).contains(&self.sad_half_window) && (1..=32).contains(&self.sad_search_px),
            "stereo: sad_half_window in 1..=15, sad_search_px in 1..=32",
        )?;
        check(
            self.outlier_factor > 0.0,
            "stereo.outlier_factor must be > 0",
        )
    }
}

/// Stereo result per left keypoint (parallel to the left [`Features`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StereoMatches {
    /// Subpixel column of the match in the right image, level-0 px (`None`: unmatched).
    pub right_x: Vec<Option<f32>>,
    /// Depth `f·b / (x_left − x_right)`, m, when matched and below the depth limit.
    pub depth_m: Vec<Option<f32>>,
}

impl StereoMatches {
    /// Left keypoints with a right match.
    pub fn n_matched(&self) -> usize {
        self.right_x.iter().flatten().count()
    }

    /// Left keypoints with a depth.
    pub fn n_with_depth(&self) -> usize {
        self.depth_m.iter().flatten().count()
    }
}

/// A match before outlier rejection.
#[derive(Clone, Copy, Debug)]
struct Candidate {
    cost: u32,
    left: u32,
    right_x: f32,
    disparity: f32,
}

/// Stereo matcher with reusable buffers.
#[derive(Clone, Debug, Default)]
pub struct StereoMatcher {
    cfg: StereoConfig,
    rows: Vec<Vec<u32>>,
    costs: Vec<u32>,
    found: Vec<Candidate>,
}

impl StereoMatcher {
    /// A matcher with a validated `cfg`.
    pub fn new(cfg: StereoConfig) -> Result<StereoMatcher, ConfigError> {
        cfg.validate()?;
        Ok(StereoMatcher {
            cfg,
            ..StereoMatcher::default()
        })
    }

    /// The configuration.
    pub fn config(&self) -> &StereoConfig {
        &self.cfg
    }

    /// Matches the `left` keypoints to the `right` ones; the pyramids are those the
    /// features were extracted from (same level count and scale factor).
    pub fn match_pair(
        &mut self,
        cam: &StereoCamera,
        left: &Features,
        left_pyr: &Pyramid,
        right: &Features,
        right_pyr: &Pyramid,
        out: &mut StereoMatches,
    ) {
        let n = left.keypoints.len();
        out.right_x.clear();
        out.right_x.resize(n, None);
        out.depth_m.clear();
        out.depth_m.resize(n, None);
        let height = right.height;
        if height == 0 || n == 0 || right.keypoints.is_empty() {
            return;
        }
        // Right keypoints by the rows their band covers.
        self.rows.resize_with(height, Vec::new);
        self.rows.iter_mut().for_each(Vec::clear);
        for (j, k) in right.keypoints.iter().enumerate() {
            let r = self.cfg.row_band_px * right_pyr.scale(usize::from(k.level)) as f32;
            let y0 = (k.y - r).floor().max(0.0) as usize;
            let y1 = ((k.y + r).ceil().max(0.0) as usize).min(height - 1);
            for row in &mut self.rows[y0.min(height)..=y1] {
                row.push(j as u32);
            }
        }
        let fb = cam.fb() as f32;
        let min_d = 0.0f32;
        let max_d = fb / (self.cfg.min_depth_baselines * cam.baseline_m) as f32;
        let (w, l) = (
            self.cfg.sad_half_window as isize,
            self.cfg.sad_search_px as isize,
        );
        self.found.clear();
        for (i, kl) in left.keypoints.iter().enumerate() {
            let row = kl.y.round();
            if row < 0.0 || row as usize >= height {
                continue;
            }
            let (ul, level) = (kl.x, kl.level);
            let (min_u, max_u) = (ul - max_d, ul - min_d);
            if max_u < 0.0 {
                continue;
            }
            let dl = &left.descriptors[i];
            let mut best = (u32::MAX, usize::MAX);
            for &j in &self.rows[row as usize] {
                let kr = &right.keypoints[j as usize];
                if kr.level + 1 < level || kr.level > level + 1 || kr.x < min_u || kr.x > max_u {
                    continue;
                }
                let d = hamming(dl, &right.descriptors[j as usize]);
                if d < best.0 {
                    best = (d, j as usize);
                }
            }
            if best.0 >= self.cfg.hamming_threshold {
                continue;
            }
            // Correlation at the left keypoint's level.
            let lvl = usize::from(level);
            let (il, ir) = (left_pyr.level(lvl), right_pyr.level(lvl));
            let xl = left_pyr.from_level0(lvl, f64::from(ul)).round() as isize;
            let yl = left_pyr.from_level0(lvl, f64::from(kl.y)).round() as isize;
            let ur0 = right.keypoints[best.1].x;
            let xr0 = right_pyr.from_level0(lvl, f64::from(ur0)).round() as isize;
            let inside = |x: isize, y: isize, img: &super::image::GrayImage, m: isize| {
                x - m >= 0
                    && y - w >= 0
                    && x + m < img.width() as isize
                    && y + w < img.height() as isize
            };
            if !inside(xl, yl, il, w) || !inside(xr0, yl, ir, l + w) {
                continue;
            }
            let centre_l = i32::from(il.get(xl as usize, yl as usize));
            self.costs.clear();
            for inc in -l..=l {
                let xr = xr0 + inc;
                let centre_r = i32::from(ir.get(xr as usize, yl as usize));
                let mut sad = 0u32;
                for dy in -w..=w {
                    let y = (yl + dy) as usize;
                    let a = &il.row(y)[(xl - w) as usize..=(xl + w) as usize];
                    let b = &ir.row(y)[(xr - w) as usize..=(xr + w) as usize];
                    for (&pa, &pb) in a.iter().zip(b) {
                        sad += ((i32::from(pa) - centre_l) - (i32::from(pb) - centre_r))
                            .unsigned_abs();
                    }
                }
                self.costs.push(sad);
            }
            let (mut best_k, mut best_cost) = (0usize, u32::MAX);
            for (k, &c) in self.costs.iter().enumerate() {
                if c < best_cost {
                    (best_k, best_cost) = (k, c);
                }
            }
            if best_k == 0 || best_k + 1 == self.costs.len() {
                continue;
            }
            let (d1, d2, d3) = (
                self.costs[best_k - 1] as f32,
                self.costs[best_k] as f32,
                self.costs[best_k + 1] as f32,
            );
            let denom = 2.0 * (d1 + d3 - 2.0 * d2);
            if denom <= 0.0 {
                continue;
            }
            let delta = (d1 - d3) / denom;
            if delta.abs() > 1.0 {
                continue;
            }
            let xr_level = (xr0 + best_k as isize - l) as f64 + f64::from(delta);
            let mut ur = right_pyr.to_level0(lvl, xr_level) as f32;
            let mut disparity = ul - ur;
            if disparity >= min_d && disparity < max_d {
                if disparity <= 0.0 {
                    disparity = 0.01;
                    ur = ul - 0.01;
                }
                self.found.push(Candidate {
                    cost: best_cost,
                    left: i as u32,
                    right_x: ur,
                    disparity,
                });
            }
        }
        if self.found.is_empty() {
            return;
        }
        self.found.sort_unstable_by_key(|c| (c.cost, c.left));
        let median = self.found[self.found.len() / 2].cost as f32;
        let limit = self.cfg.outlier_factor * median;
        let max_depth = (self.cfg.max_depth_baselines * cam.baseline_m) as f32;
        for c in &self.found {
            if c.cost as f32 > limit {
                break;
            }
            let i = c.left as usize;
            out.right_x[i] = Some(c.right_x);
            let z = fb / c.disparity;
            if z < max_depth {
                out.depth_m[i] = Some(z);
            }
        }
    }
}
