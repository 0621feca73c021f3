//! FAST-9 corners (Rosten & Drummond): the segment test on the 16-pixel Bresenham circle
//! of radius 3, a corner score, 3×3 non-maximum suppression, and the per-cell adaptive
//! threshold of the paper (ORB-SLAM's `iniThFAST` / `minThFAST`).
//!
//! A pixel `p` is a corner at threshold `t` when 9 contiguous circle pixels are all
//! brighter than `I(p) + t` or all darker than `I(p) − t`. Its **score** is the largest
//! `t` for which it is still a corner, so "corner at `t`" ⇔ "score ≥ `t`": the score map
//! of a threshold-`t` pass holds every stricter pass too.

use super::image::GrayImage;
use serde::{Deserialize, Serialize};

/// The circle, clockwise from the top, as `(dx, dy)` (OpenCV's order).
pub const CIRCLE: [(i32, i32); 16] = [
    (0, -3),
    (1, -3),
    (2, -2),
    (3, -1),
    (3, 0),
    (3, 1),
    (2, 2),
    (1, 3),
    (0, 3),
    (-1, 3),
    (-2, 2),
    (-3, 1),
    (-3, 0),
    (-3, -1),
    (-2, -2),
    (-1, -3),
];

/// Contiguous arc length of FAST-9.
pub const ARC: usize = 9;

/// Distance from the image border a pixel needs for its circle.
pub const RADIUS: usize = 3;

/// A detected corner in the pixel grid of the image it was found in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Corner {
    /// Column, px.
    pub x: u32,
    /// Row, px.
    pub y: u32,
    /// Largest threshold at which it is a corner.
    pub score: u8,
}

/// The 16 circle values of the pixel `x` of the row band `rows` (rows `y − 3 ..= y + 3`),
/// in [`CIRCLE`] order (one bounds check per row).
fn circle_values(rows: &[&[u8]; 7], x: usize) -> [i16; 16] {
    let r: [&[u8; 7]; 7] =
        std::array::from_fn(|k| rows[k][x - 3..x + 4].try_into().expect("7 px window"));
    [
        r[0][3], r[0][4], r[1][5], r[2][6], r[3][6], r[4][6], r[5][5], r[6][4], r[6][3], r[6][2],
        r[5][1], r[4][0], r[3][0], r[2][0], r[1][1], r[0][2],
    ]
    .map(i16::from)
}

/// The FAST-9 score of a pixel with centre value `c` and circle `v`: the largest `t`
/// with an arc all brighter than `c + t` or all darker than `c − t`, i.e. the max over
/// the 16 arcs of the arc's minimum difference (or of minus its maximum), minus one.
/// Sliding minima by doubling windows (2, 4, 8, 9) over fixed arrays, so it vectorizes.
fn arc_score(c: i16, v: &[i16; 16]) -> i16 {
    let mut d = [0i16; 32];
    for i in 0..16 {
        d[i] = v[i] - c;
        d[i + 16] = d[i];
    }
    let mut lo2 = [0i16; 30];
    let mut hi2 = [0i16; 30];
    for i in 0..30 {
        lo2[i] = d[i].min(d[i + 1]);
        hi2[i] = d[i].max(d[i + 1]);
    }
    let mut lo4 = [0i16; 26];
    let mut hi4 = [0i16; 26];
    for i in 0..26 {
        lo4[i] = lo2[i].min(lo2[i + 2]);
        hi4[i] = hi2[i].max(hi2[i + 2]);
    }
    let (mut bright, mut dark) = (i16::MIN, i16::MAX);
    for i in 0..16 {
        bright = bright.max(lo4[i].min(lo4[i + 4]).min(d[i + 8]));
        dark = dark.min(hi4[i].max(hi4[i + 4]).max(d[i + 8]));
    }
    bright.max(-dark) - 1
}

/// The FAST-9 score of a pixel with centre value `c` and circle `v`, if it is a corner
/// at `threshold`.
fn score_of(c: i16, v: &[i16; 16], threshold: u8) -> Option<u8> {
    let t = i16::from(threshold);
    let (mut bright, mut dark) = (0u16, 0u16);
    for (i, &p) in v.iter().enumerate() {
        bright |= u16::from(p > c + t) << i;
        dark |= u16::from(p < c - t) << i;
    }
    if !has_arc(bright) && !has_arc(dark) {
        return None;
    }
    Some(arc_score(c, v).clamp(t, 255) as u8)
}

/// The FAST-9 score of pixel `(x, y)` of `img` at `threshold`, `None` if it is not a
/// corner (or too close to the border for its circle).
pub fn corner_score(img: &GrayImage, x: usize, y: usize, threshold: u8) -> Option<u8> {
    if x < RADIUS || y < RADIUS || x + RADIUS >= img.width() || y + RADIUS >= img.height() {
        return None;
    }
    let rows: [&[u8]; 7] = std::array::from_fn(|k| img.row(y + k - RADIUS));
    score_of(
        i16::from(img.get(x, y)),
        &circle_values(&rows, x),
        threshold,
    )
}

/// Pixels per chunk of the row loops (the masks of a chunk stay in registers).
const LANES: usize = 16;

/// Whether a 16-bit circular mask has [`ARC`] (9) contiguous set bits (runs of 2, 4, 8
/// by rotations, then the ninth bit).
fn has_arc(m: u16) -> bool {
    let r2 = m & m.rotate_right(1);
    let r4 = r2 & r2.rotate_right(2);
    let r8 = r4 & r4.rotate_right(4);
    (r8 & m.rotate_right(8)) != 0
}

/// [`has_arc`] on a doubled 32-bit mask with plain shifts, which vectorize on any x86-64
/// (16-bit rotations do not).
#[inline(always)]
fn has_arc32(m: u16) -> bool {
    let m = u32::from(m) * 0x1_0001;
    let r2 = m & (m >> 1);
    let r4 = r2 & (r2 >> 2);
    let r8 = r4 & (r4 >> 4);
    (r8 & (m >> 8)) != 0
}

/// Corner flags of the [`LANES`] pixels `x0 + i` of the row band `rows` at `threshold`.
///
/// First a cheap necessary condition in byte lanes (16 per register): a 9-arc contains a
/// pixel of each opposite pair `(k, k + 8)`, so a corner has, in each of the pairs 0/8,
/// 4/12, 2/10, 6/14, a brighter pixel (or in each a darker one); a chunk with no lane
/// left stops there (flat and smooth areas). Otherwise the full 16-bit masks and the arc
/// test for all lanes.
#[inline(always)]
fn chunk_flags(rows: &[&[u8]; 7], x0: usize, threshold: u8) -> [bool; LANES] {
    let c: [u8; LANES] = rows[3][x0..x0 + LANES].try_into().expect("chunk in row");
    let hi = c.map(|v| v.saturating_add(threshold));
    let lo = c.map(|v| v.saturating_sub(threshold));
    // The 16 circle pixels of every lane, in CIRCLE order: `at!(row, dx + 3)`.
    macro_rules! at {
        ($r:literal, $o:literal) => {{
            let start = x0 + $o - RADIUS;
            let a: [u8; LANES] = rows[$r][start..start + LANES]
                .try_into()
                .expect("chunk in row");
            a
        }};
    }
    let circle: [[u8; LANES]; 16] = [
        at!(0, 3),
        at!(0, 4),
        at!(1, 5),
        at!(2, 6),
        at!(3, 6),
        at!(4, 6),
        at!(5, 5),
        at!(6, 4),
        at!(6, 3),
        at!(6, 2),
        at!(5, 1),
        at!(4, 0),
        at!(3, 0),
        at!(2, 0),
        at!(1, 1),
        at!(0, 2),
    ];
    let at = |k: usize| &circle[k];
    let mut b = [true; LANES];
    let mut d = [true; LANES];
    for (round, &k) in [0usize, 4, 2, 6].iter().enumerate() {
        let (p, q) = (at(k), at(k + 8));
        for j in 0..LANES {
            b[j] &= (p[j] > hi[j]) | (q[j] > hi[j]);
            d[j] &= (p[j] < lo[j]) | (q[j] < lo[j]);
        }
        if round % 2 == 1 && !(0..LANES).any(|j| b[j] | d[j]) {
            return [false; LANES];
        }
    }
    // Some lane may be a corner: the full brighter/darker masks and the arc test, still
    // across the lanes.
    let mut bm = [0u16; LANES];
    let mut dm = [0u16; LANES];
    for k in 0..16 {
        let p = at(k);
        for j in 0..LANES {
            bm[j] |= u16::from(p[j] > hi[j]) << k;
            dm[j] |= u16::from(p[j] < lo[j]) << k;
        }
    }
    let mut out = [false; LANES];
    for j in 0..LANES {
        out[j] = has_arc32(bm[j]) | has_arc32(dm[j]);
    }
    out
}

/// Writes the FAST-9 score at `threshold` (0 = not a corner) of every pixel of the
/// rectangle `[x0, x1) × [y0, y1)` into `scores` (row-major, the image's size). The
/// rectangle must keep [`RADIUS`] px from the border.
///
/// Chunks of 16 pixels get the segment test in vector registers (a cheap necessary
/// condition first, then the full masks); only corners get the score. A row's tail is
/// done by an overlapping chunk when the image is wide enough, else pixel by pixel.
pub fn score_rect(img: &GrayImage, rect: [usize; 4], threshold: u8, scores: &mut [u8]) {
    let [x0, y0, x1, y1] = rect;
    let w = img.width();
    debug_assert!(x0 >= RADIUS && y0 >= RADIUS && x1 + RADIUS <= w && y1 + RADIUS <= img.height());
    if x1 <= x0 || y1 <= y0 {
        return;
    }
    let t = i16::from(threshold);
    for y in y0..y1 {
        let rows: [&[u8]; 7] = std::array::from_fn(|k| img.row(y + k - RADIUS));
        let out = &mut scores[y * w..(y + 1) * w];
        out[x0..x1].fill(0);
        let mut x = x0;
        while x < x1 {
            // A full chunk inside the image's valid band, shifted left at the tail.
            let start = if x + LANES <= w - RADIUS {
                x
            } else if w - RADIUS >= RADIUS + LANES {
                w - RADIUS - LANES
            } else {
                // Narrow image: scalar.
                for xx in x..x1 {
                    out[xx] =
                        score_of(i16::from(rows[3][xx]), &circle_values(&rows, xx), threshold)
                            .unwrap_or(0);
                }
                break;
            };
            let flags = chunk_flags(&rows, start, threshold);
            let end = (start + LANES).min(x1);
            if flags.contains(&true) {
                for xx in x..end {
                    if flags[xx - start] {
                        let v = circle_values(&rows, xx);
                        out[xx] = arc_score(i16::from(rows[3][xx]), &v).clamp(t, 255) as u8;
                    }
                }
            }
            x = end;
        }
    }
}

/// The non-maximum-suppression flags of row `y`, columns `[x0, x1)` (see
/// [`is_local_max`]), into `keep` (vectorizes).
fn nms_row<'k>(
    scores: &[u8],
    width: usize,
    y: usize,
    x0: usize,
    x1: usize,
    keep: &'k mut Vec<bool>,
) -> &'k [bool] {
    let n = x1 - x0;
    if keep.len() < n {
        keep.resize(n, false);
    }
    let keep = &mut keep[..n];
    let at = |dy: isize, dx: isize| {
        let start = ((y as isize + dy) as usize) * width + (x0 as isize + dx) as usize;
        &scores[start..start + n]
    };
    let (s, ul, u, ur, l) = (at(0, 0), at(-1, -1), at(-1, 0), at(-1, 1), at(0, -1));
    let (r, dl, d, dr) = (at(0, 1), at(1, -1), at(1, 0), at(1, 1));
    for i in 0..n {
        let before = ul[i].max(u[i]).max(ur[i]).max(l[i]);
        let after = r[i].max(dl[i]).max(d[i]).max(dr[i]);
        keep[i] = s[i] != 0 && s[i] > before && s[i] >= after;
    }
    keep
}

/// Whether the non-zero score at `(x, y)` survives 3×3 non-maximum suppression: it must
/// beat the neighbours before it in raster order and at least tie those after it (so of
/// two equal neighbours exactly one is kept). `(x, y)` must not be on the border.
pub fn is_local_max(scores: &[u8], width: usize, x: usize, y: usize) -> bool {
    let i = y * width + x;
    let s = scores[i];
    let up = &scores[i - width - 1..i - width + 2];
    let down = &scores[i + width - 1..i + width + 2];
    s > up[0]
        && s > up[1]
        && s > up[2]
        && s > scores[i - 1]
        && s >= scores[i + 1]
        && s >= down[0]
        && s >= down[1]
        && s >= down[2]
}

/// FAST-9 at one `threshold` over a whole image (3 px border), with non-maximum
/// suppression, in raster order. Allocates; the extractor uses [`FastDetector`].
pub fn detect(img: &GrayImage, threshold: u8) -> Vec<Corner> {
    let (w, h) = (img.width(), img.height());
    let mut out = Vec::new();
    if w < 2 * RADIUS + 3 || h < 2 * RADIUS + 3 {
        return out;
    }
    let mut scores = vec![0u8; w * h];
    let rect = [RADIUS, RADIUS, w - RADIUS, h - RADIUS];
    score_rect(img, rect, threshold, &mut scores);
    collect_maxima(&scores, w, rect, &mut Vec::new(), &mut out);
    out
}

/// Appends the corners of `rect` that survive non-maximum suppression, in raster order.
fn collect_maxima(
    scores: &[u8],
    width: usize,
    rect: [usize; 4],
    keep: &mut Vec<bool>,
    out: &mut Vec<Corner>,
) {
    let [x0, y0, x1, y1] = rect;
    for y in y0..y1 {
        let row = nms_row(scores, width, y, x0, x1, keep);
        for (i, _) in row.iter().enumerate().filter(|(_, k)| **k) {
            out.push(Corner {
                x: (x0 + i) as u32,
                y: y as u32,
                score: scores[y * width + x0 + i],
            });
        }
    }
}

/// Counts the corners of `rect` (before non-maximum suppression).
fn count_corners(scores: &[u8], width: usize, rect: [usize; 4]) -> usize {
    let [x0, y0, x1, y1] = rect;
    (y0..y1)
        .map(|y| {
            scores[y * width + x0..y * width + x1]
                .iter()
                .map(|&s| usize::from(s != 0))
                .sum::<usize>()
        })
        .sum()
}

/// The adaptive, per-cell FAST detection.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct FastConfig {
    /// Threshold of the first pass over every cell (ORB-SLAM's `iniThFAST`).
    pub high_threshold: u8,
    /// Threshold of the second pass over cells the first left short (`minThFAST`).
    pub low_threshold: u8,
    /// Side of the detection cells, px of each pyramid level.
    pub cell_size_px: usize,
    /// A cell with fewer corners than this after the high-threshold pass (counted before
    /// non-maximum suppression) is searched again at the low threshold (1: only empty
    /// cells, ORB-SLAM's rule).
    pub min_corners_per_cell: usize,
}

impl Default for FastConfig {
    fn default() -> Self {
        FastConfig {
            high_threshold: 20,
            low_threshold: 7,
            cell_size_px: 32,
            min_corners_per_cell: 1,
        }
    }
}

/// Per-cell adaptive FAST with reusable buffers.
///
/// The detection area `[border, W − border) × [border, H − border)` is split into
/// near-square cells of about [`FastConfig::cell_size_px`]. One high-threshold pass scores
/// the whole area; every cell with fewer than `min_corners_per_cell` corners is then
/// rescored at the low threshold; finally the maxima of all cells are collected
/// (non-maximum suppression sees across cell borders). The result does not depend on the
/// order cells are visited in.
#[derive(Clone, Debug, Default)]
pub struct FastDetector {
    cfg: FastConfig,
    scores: Vec<u8>,
    keep: Vec<bool>,
    low_cells: Vec<[usize; 4]>,
    size: (usize, usize),
}

impl FastDetector {
    /// A detector with `cfg`.
    pub fn new(cfg: FastConfig) -> FastDetector {
        FastDetector {
            cfg,
            ..FastDetector::default()
        }
    }

    /// The configuration.
    pub fn config(&self) -> &FastConfig {
        &self.cfg
    }

    /// The cells of the detection area of a `w × h` image, row-major.
    pub fn cells(&self, w: usize, h: usize, border: usize) -> Vec<[usize; 4]> {
        let mut v = Vec::new();
        self.for_each_cell(w, h, border, |c| v.push(c));
        v
    }

    fn for_each_cell(&self, w: usize, h: usize, border: usize, mut f: impl FnMut([usize; 4])) {
        let border = border.max(RADIUS);
        if w <= 2 * border || h <= 2 * border {
            return;
        }
        let (aw, ah) = (w - 2 * border, h - 2 * border);
        let cell = self.cfg.cell_size_px.max(1);
        let (nx, ny) = ((aw / cell).max(1), (ah / cell).max(1));
        let (cw, ch) = (aw.div_ceil(nx), ah.div_ceil(ny));
        for j in 0..ny {
            let y0 = border + j * ch;
            let y1 = (y0 + ch).min(h - border);
            for i in 0..nx {
                let x0 = border + i * cw;
                let x1 = (x0 + cw).min(w - border);
                if x1 > x0 && y1 > y0 {
                    f([x0, y0, x1, y1]);
                }
            }
        }
    }

    /// Appends to `out` the corners of `img` at least `border` (≥ 3) px from its edges,
    /// cell by cell (row-major), raster order within a cell.
    pub fn detect(&mut self, img: &GrayImage, border: usize, out: &mut Vec<Corner>) {
        let (w, h) = (img.width(), img.height());
        let border = border.max(RADIUS);
        if self.size != (w, h) {
            // Pixels outside the detection area are never written and stay 0.
            self.scores.clear();
            self.scores.resize(w * h, 0);
            self.size = (w, h);
        }
        if w <= 2 * border || h <= 2 * border {
            return;
        }
        let area = [border, border, w - border, h - border];
        let mut scores = std::mem::take(&mut self.scores);
        let mut keep = std::mem::take(&mut self.keep);
        let mut low = std::mem::take(&mut self.low_cells);
        low.clear();
        score_rect(img, area, self.cfg.high_threshold, &mut scores);
        let (min, lt, ht) = (
            self.cfg.min_corners_per_cell,
            self.cfg.low_threshold,
            self.cfg.high_threshold,
        );
        if min > 0 && lt < ht {
            self.for_each_cell(w, h, border, |c| {
                if count_corners(&scores, w, c) < min {
                    low.push(c);
                }
            });
            for &c in &low {
                score_rect(img, c, lt, &mut scores);
            }
        }
        self.for_each_cell(w, h, border, |c| {
            collect_maxima(&scores, w, c, &mut keep, out)
        });
        self.scores = scores;
        self.keep = keep;
        self.low_cells = low;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arcs_of_nine_are_found_across_the_wrap() {
        assert!(has_arc(0b1_1111_1111));
        assert!(!has_arc(0b1111_1111));
        assert!(has_arc(0xE03F)); // bits 13..15 and 0..5: 9 across the wrap
        assert!(!has_arc(0xE01F));
        for m in 0..=u16::MAX {
            let naive = (0..16).any(|k| (0..ARC).all(|j| m >> ((k + j) % 16) & 1 == 1));
            assert_eq!(has_arc(m), naive, "{m:#x}");
            assert_eq!(has_arc32(m), naive, "{m:#x}");
        }
    }

    #[test]
    fn score_is_the_largest_threshold_that_still_detects() {
        // A bright 9-arc 40 above the centre, one of its pixels only 25 above.
        let c = 100;
        let mut v = [100i16; 16];
        for (i, p) in v.iter_mut().enumerate().take(9) {
            *p = if i == 4 { 125 } else { 140 };
        }
        let s = score_of(c, &v, 5).unwrap();
        assert_eq!(s, 24);
        assert!(score_of(c, &v, 24).is_some());
        assert!(score_of(c, &v, 25).is_none());
    }

    /// The definition, literally: the largest `t` for which 9 contiguous circle pixels
    /// are all `> c + t` or all `< c − t`.
    fn naive_score(img: &GrayImage, x: usize, y: usize) -> u8 {
        let c = i32::from(img.get(x, y));
        let v: Vec<i32> = CIRCLE
            .iter()
            .map(|&(dx, dy)| i32::from(img.get((x as i32 + dx) as usize, (y as i32 + dy) as usize)))
            .collect();
        for t in (1..=255).rev() {
            let corner = (0..16).any(|k| {
                (0..ARC).all(|j| v[(k + j) % 16] > c + t)
                    || (0..ARC).all(|j| v[(k + j) % 16] < c - t)
            });
            if corner {
                return t as u8;
            }
        }
        0
    }

    #[test]
    fn row_scoring_matches_the_definition_at_every_pixel() {
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut rnd = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let mut corners = 0;
        for round in 0..30 {
            let levels = if round % 2 == 0 { 4 } else { 256 };
            // Wide (chunks and an overlapping tail chunk) and narrow (scalar) rows.
            let w = [40, 20, 23][round % 3];
            let img = GrayImage::from_fn(w, 30, |_, _| (rnd() % levels * (256 / levels)) as u8);
            let mut scores = vec![0u8; w * 30];
            score_rect(&img, [3, 3, w - 3, 27], 10, &mut scores);
            for y in 3..27 {
                for x in 3..w - 3 {
                    let want = naive_score(&img, x, y);
                    let want = if want >= 10 { want } else { 0 };
                    assert_eq!(scores[y * w + x], want, "({x}, {y})");
                    corners += usize::from(want > 0);
                }
            }
        }
        assert!(corners > 100, "{corners} corners: the test tests nothing");
    }
}
