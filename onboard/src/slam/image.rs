//! Grey images, the conversion from camera messages, the scale pyramid and the 7×7
//! Gaussian blur the descriptors are computed on.
//!
//! Everything here writes into buffers the caller owns and reuses: once a [`Pyramid`] or
//! a blur scratch buffer has seen one frame of a given size, later frames allocate nothing.

use thiserror::Error;
use vinebench_msgs::{ImageEncoding, ImageMsg};

/// An image that cannot become a [`GrayImage`].
#[derive(Clone, Debug, Error, PartialEq, Eq)]
pub enum ImageError {
    /// Depth images carry no intensity.
    #[error("encoding {0:?} has no intensity to convert to grey")]
    UnsupportedEncoding(ImageEncoding),
    /// The pixel buffer does not match width × height × bytes per pixel.
    #[error("{width}x{height} {encoding:?} needs {expected} bytes, the buffer has {actual}")]
    SizeMismatch {
        /// Width, px.
        width: usize,
        /// Height, px.
        height: usize,
        /// Pixel layout.
        encoding: ImageEncoding,
        /// Bytes needed.
        expected: usize,
        /// Bytes present.
        actual: usize,
    },
}

/// An owned 8-bit grey image, rows top to bottom, no padding.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct GrayImage {
    width: usize,
    height: usize,
    data: Vec<u8>,
}

impl GrayImage {
    /// A black `width × height` image.
    pub fn new(width: usize, height: usize) -> GrayImage {
        GrayImage {
            width,
            height,
            data: vec![0; width * height],
        }
    }

    /// The image whose pixel `(x, y)` is `f(x, y)`.
    pub fn from_fn(width: usize, height: usize, mut f: impl FnMut(usize, usize) -> u8) -> Self {
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                data.push(f(x, y));
            }
        }
        GrayImage {
            width,
            height,
            data,
        }
    }

    /// Wraps row-major pixels; `None` when `data` is not `width × height` long.
    pub fn from_vec(width: usize, height: usize, data: Vec<u8>) -> Option<GrayImage> {
        (data.len() == width * height).then_some(GrayImage {
            width,
            height,
            data,
        })
    }

    /// The grey version of a camera image (see [`GrayImage::set_from_msg`]).
    pub fn from_msg(msg: &ImageMsg) -> Result<GrayImage, ImageError> {
        let mut g = GrayImage::default();
        g.set_from_msg(msg)?;
        Ok(g)
    }

    /// Overwrites `self` with the grey version of `msg`, reusing the allocation.
    ///
    /// `mono8` is copied; `rgb8` is converted with the ITU-R BT.601 luma weights in the
    /// fixed-point form OpenCV's `cvtColor(RGB2GRAY)` uses (`(4899 R + 9617 G + 1868 B +
    /// 2^13) >> 14`), applied to the encoded (sRGB) values as cameras and OpenCV do.
    pub fn set_from_msg(&mut self, msg: &ImageMsg) -> Result<(), ImageError> {
        let (w, h) = (msg.width as usize, msg.height as usize);
        let bpp = msg.encoding.bytes_per_pixel();
        if msg.encoding == ImageEncoding::Depth16Mm {
            return Err(ImageError::UnsupportedEncoding(msg.encoding));
        }
        let expected = w * h * bpp;
        if msg.data.len() != expected {
            return Err(ImageError::SizeMismatch {
                width: w,
                height: h,
                encoding: msg.encoding,
                expected,
                actual: msg.data.len(),
            });
        }
        self.resize(w, h);
        match msg.encoding {
            ImageEncoding::Mono8 => self.data.copy_from_slice(&msg.data),
            ImageEncoding::Rgb8 => {
                for (g, p) in self.data.iter_mut().zip(msg.data.chunks_exact(3)) {
                    let y =
                        4899 * u32::from(p[0]) + 9617 * u32::from(p[1]) + 1868 * u32::from(p[2]);
                    *g = ((y + (1 << 13)) >> 14) as u8;
                }
            }
            ImageEncoding::Depth16Mm => unreachable!("rejected above"),
        }
        Ok(())
    }

    /// Makes the image `width × height`, keeping the allocation; the pixels are
    /// unspecified afterwards unless the size was unchanged.
    pub fn resize(&mut self, width: usize, height: usize) {
        self.width = width;
        self.height = height;
        self.data.resize(width * height, 0);
    }

    /// Width, px.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height, px.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Row-major pixels.
    pub fn data(&self) -> &[u8] {
        &self.data
    }

    /// Row-major pixels, mutable.
    pub fn data_mut(&mut self) -> &mut [u8] {
        &mut self.data
    }

    /// Row `y`.
    pub fn row(&self, y: usize) -> &[u8] {
        &self.data[y * self.width..(y + 1) * self.width]
    }

    /// Row `y`, mutable.
    pub fn row_mut(&mut self, y: usize) -> &mut [u8] {
        &mut self.data[y * self.width..(y + 1) * self.width]
    }

    /// Pixel `(x, y)`.
    pub fn get(&self, x: usize, y: usize) -> u8 {
        self.data[y * self.width + x]
    }
}

/// Fixed-point bits of the bilinear weights.
const BILINEAR_BITS: u32 = 7;
const BILINEAR_ONE: u32 = 1 << BILINEAR_BITS;

/// One source column of a bilinear resampling: the two neighbours and the weight of the
/// right one (of [`BILINEAR_ONE`]).
#[derive(Clone, Copy, Debug, Default)]
struct Tap {
    i0: u32,
    i1: u32,
    w1: u32,
}

/// The bilinear taps of `dst_len` samples at `src = (dst + 0.5)·factor − 0.5` over a
/// source of `src_len` samples (edges clamped).
fn taps(dst_len: usize, src_len: usize, factor: f64, out: &mut Vec<Tap>) {
    out.clear();
    let last = src_len.saturating_sub(1);
    for d in 0..dst_len {
        let s = ((d as f64 + 0.5) * factor - 0.5).max(0.0);
        let i0 = (s.floor() as usize).min(last);
        let frac = s - i0 as f64;
        let w1 = ((frac * f64::from(BILINEAR_ONE)).round() as u32).min(BILINEAR_ONE);
        out.push(Tap {
            i0: i0 as u32,
            i1: (i0 + 1).min(last) as u32,
            w1: if i0 == last { 0 } else { w1 },
        });
    }
}

/// An image pyramid with a constant scale factor between levels (ORB-SLAM's layout).
///
/// Level `k` is `round(W / s^k) × round(H / s^k)` and is resampled bilinearly from level
/// `k − 1` with the pixel-centre convention, so a pixel `(x, y)` of level `k` lies at
/// `((x + 0.5)·s^k − 0.5, (y + 0.5)·s^k − 0.5)` in level 0 exactly (see
/// [`Pyramid::to_level0`]). Level 0 is a copy of the input.
#[derive(Clone, Debug)]
pub struct Pyramid {
    scale_factor: f64,
    scales: Vec<f64>,
    levels: Vec<GrayImage>,
    col_taps: Vec<Tap>,
    row_taps: Vec<Tap>,
    row_buf: Vec<u16>,
}

impl Pyramid {
    /// An empty pyramid of `n_levels` (≥ 1) levels with `scale_factor` (> 1) between them.
    pub fn new(n_levels: usize, scale_factor: f64) -> Pyramid {
        let n = n_levels.max(1);
        Pyramid {
            scale_factor,
            scales: (0..n).map(|k| scale_factor.powi(k as i32)).collect(),
            levels: vec![GrayImage::default(); n],
            col_taps: Vec::new(),
            row_taps: Vec::new(),
            row_buf: Vec::new(),
        }
    }

    /// Rebuilds every level from `base` (no allocation once the size is known).
    pub fn build(&mut self, base: &GrayImage) {
        let l0 = &mut self.levels[0];
        l0.resize(base.width, base.height);
        l0.data.copy_from_slice(&base.data);
        for k in 1..self.levels.len() {
            let w = ((base.width as f64 / self.scales[k]).round() as usize).max(1);
            let h = ((base.height as f64 / self.scales[k]).round() as usize).max(1);
            let (done, rest) = self.levels.split_at_mut(k);
            let src = &done[k - 1];
            let dst = &mut rest[0];
            dst.resize(w, h);
            taps(w, src.width, self.scale_factor, &mut self.col_taps);
            taps(h, src.height, self.scale_factor, &mut self.row_taps);
            self.row_buf.resize(src.width, 0);
            for (y, rt) in self.row_taps.iter().enumerate() {
                // Vertical interpolation of the whole source row (vectorizes), then the
                // horizontal taps.
                let a = src.row(rt.i0 as usize);
                let b = src.row(rt.i1 as usize);
                let (wa, wb) = ((BILINEAR_ONE - rt.w1) as u16, rt.w1 as u16);
                for ((o, &pa), &pb) in self.row_buf.iter_mut().zip(a).zip(b) {
                    *o = u16::from(pa) * wa + u16::from(pb) * wb;
                }
                let out = dst.row_mut(y);
                for (o, ct) in out.iter_mut().zip(&self.col_taps) {
                    let v = u32::from(self.row_buf[ct.i0 as usize]) * (BILINEAR_ONE - ct.w1)
                        + u32::from(self.row_buf[ct.i1 as usize]) * ct.w1;
                    *o = ((v + (1 << (2 * BILINEAR_BITS - 1))) >> (2 * BILINEAR_BITS)) as u8;
                }
            }
        }
    }

    /// Number of levels.
    pub fn n_levels(&self) -> usize {
        self.levels.len()
    }

    /// Level `k` (level 0 is the input).
    pub fn level(&self, k: usize) -> &GrayImage {
        &self.levels[k]
    }

    /// All levels, finest first.
    pub fn levels(&self) -> &[GrayImage] {
        &self.levels
    }

    /// Scale of level `k` relative to level 0 (`s^k`).
    pub fn scale(&self, k: usize) -> f64 {
        self.scales[k]
    }

    /// Scale factor between consecutive levels.
    pub fn scale_factor(&self) -> f64 {
        self.scale_factor
    }

    /// A level-`k` pixel coordinate in level-0 pixels.
    pub fn to_level0(&self, k: usize, v: f64) -> f64 {
        (v + 0.5) * self.scales[k] - 0.5
    }

    /// A level-0 pixel coordinate in level-`k` pixels.
    pub fn from_level0(&self, k: usize, v: f64) -> f64 {
        (v + 0.5) / self.scales[k] - 0.5
    }
}

/// The 7-tap Gaussian (σ = 2 px, ORB-SLAM's `GaussianBlur(7×7, 2)`) in 1/256: the exact
/// weights are 0.0702, 0.1311, 0.1907, 0.2161, rounded so that they sum to 256.
pub const GAUSS7: [u16; 7] = [18, 34, 49, 54, 49, 34, 18];

/// Reflect-101 index (`-1 → 1`, `n → n − 2`) for `i` in `[-3, n + 3)`, `n ≥ 4`.
fn reflect101(i: isize, n: usize) -> usize {
    let n = n as isize;
    let r = if i < 0 {
        -i
    } else if i >= n {
        2 * n - 2 - i
    } else {
        i
    };
    r.clamp(0, n - 1) as usize
}

/// Scratch rows of [`gaussian_blur7`].
#[derive(Clone, Debug, Default)]
pub struct BlurScratch {
    horizontal: GrayImage,
    padded: Vec<u8>,
    acc: Vec<u16>,
}

/// `dst = src` blurred with the separable [`GAUSS7`] kernel, reflect-101 borders,
/// rounding after each pass. Images narrower or shorter than 4 px are copied.
pub fn gaussian_blur7(src: &GrayImage, dst: &mut GrayImage, scratch: &mut BlurScratch) {
    let (w, h) = (src.width, src.height);
    dst.resize(w, h);
    if w < 4 || h < 4 {
        dst.data.copy_from_slice(&src.data);
        return;
    }
    let BlurScratch {
        horizontal,
        padded,
        acc,
    } = scratch;
    horizontal.resize(w, h);
    padded.resize(w + 6, 0);
    acc.resize(w, 0);
    for y in 0..h {
        let row = src.row(y);
        padded[3..3 + w].copy_from_slice(row);
        for k in 0..3 {
            padded[k] = row[reflect101(k as isize - 3, w)];
            padded[w + 3 + k] = row[reflect101((w + k) as isize, w)];
        }
        acc.fill(128);
        for (k, &g) in GAUSS7.iter().enumerate() {
            for (a, &v) in acc.iter_mut().zip(&padded[k..k + w]) {
                *a += g * u16::from(v);
            }
        }
        for (o, &a) in horizontal.row_mut(y).iter_mut().zip(acc.iter()) {
            *o = (a >> 8) as u8;
        }
    }
    for y in 0..h {
        acc.fill(128);
        for (k, &g) in GAUSS7.iter().enumerate() {
            let r = horizontal.row(reflect101(y as isize + k as isize - 3, h));
            for (a, &v) in acc.iter_mut().zip(r) {
                *a += g * u16::from(v);
            }
        }
        for (o, &a) in dst.row_mut(y).iter_mut().zip(acc.iter()) {
            *o = (a >> 8) as u8;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use vinebench_msgs::{FrameId, Nanos};

    fn msg(encoding: ImageEncoding, w: u32, h: u32, data: Vec<u8>) -> ImageMsg {
        ImageMsg {
            stamp: Nanos(0),
            topic: Arc::from("/t"),
            frame_id: FrameId::from("cam"),
            width: w,
            height: h,
            encoding,
            data: data.into(),
        }
    }

    #[test]
    fn rgb_converts_with_bt601_weights_and_mono_copies() {
        let m = msg(
            ImageEncoding::Rgb8,
            3,
            1,
            vec![255, 0, 0, 0, 255, 0, 10, 20, 30],
        );
        let g = GrayImage::from_msg(&m).unwrap();
        // 0.299·255 = 76.2, 0.587·255 = 149.7, 0.299·10 + 0.587·20 + 0.114·30 = 18.1.
        assert_eq!(g.data(), &[76, 150, 18]);
        let m = msg(ImageEncoding::Mono8, 2, 1, vec![7, 9]);
        assert_eq!(GrayImage::from_msg(&m).unwrap().data(), &[7, 9]);
        let m = msg(ImageEncoding::Depth16Mm, 1, 1, vec![0, 0]);
        assert!(GrayImage::from_msg(&m).is_err());
        let m = msg(ImageEncoding::Rgb8, 2, 1, vec![0; 5]);
        assert!(matches!(
            GrayImage::from_msg(&m),
            Err(ImageError::SizeMismatch { expected: 6, .. })
        ));
    }

    #[test]
    fn pyramid_levels_shrink_by_the_factor_and_keep_a_ramp_aligned() {
        // A horizontal ramp v = x: level k must read (x + 0.5)·s^k − 0.5 at column x.
        let base = GrayImage::from_fn(200, 100, |x, _| x as u8);
        let mut p = Pyramid::new(5, 1.2);
        p.build(&base);
        for k in 0..5 {
            let l = p.level(k);
            let s = 1.2f64.powi(k as i32);
            assert_eq!(l.width(), (200.0 / s).round() as usize);
            assert_eq!(l.height(), (100.0 / s).round() as usize);
            // Clamping at the edges bends the ramp there, by about a pixel per level.
            for x in 2 + k..l.width() - 3 - k {
                let want = p.to_level0(k, x as f64);
                let got = f64::from(l.get(x, l.height() / 2));
                // Each level rounds to integers: up to 0.5 px of value error per level.
                let tol = 0.5 * k as f64 + 0.05;
                assert!(
                    (got - want).abs() <= tol,
                    "level {k} x {x}: {got} vs {want}"
                );
            }
        }
    }

    #[test]
    fn blur_keeps_flat_images_and_spreads_an_impulse_like_the_kernel() {
        let flat = GrayImage::from_fn(20, 20, |_, _| 77);
        let mut out = GrayImage::default();
        let mut s = BlurScratch::default();
        gaussian_blur7(&flat, &mut out, &mut s);
        assert!(out.data().iter().all(|&v| v == 77));
        let imp = GrayImage::from_fn(21, 21, |x, y| if x == 10 && y == 10 { 255 } else { 0 });
        gaussian_blur7(&imp, &mut out, &mut s);
        // Centre: 255·54/256 = 53.8 → 54 after the first pass, 54·54/256 = 11.4.
        assert_eq!(out.get(10, 10), 11);
        assert_eq!(out.get(10, 9), out.get(9, 10));
        assert!(out.get(10, 9) < out.get(10, 10) && out.get(10, 14) == 0);
    }
}
