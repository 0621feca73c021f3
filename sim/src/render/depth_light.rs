//! Active stereo in daylight: where a D435 finds depth, and how well, from the texture
//! its infrared pair sees.
//!
//! A D435 measures depth by matching blocks of its two infrared images. Matching needs
//! texture: the surface's own (leaves against gaps, soil, bark) and the dot pattern of the
//! infrared projector. Indoors the pattern dominates and every surface in its range gets
//! depth ([`super::camera::StereoDepthNoise`] alone: the indoor case). Outdoors the
//! imagers' auto-exposure follows the sunlight, which is thousands of times brighter than
//! the projector: the pattern washes out, a textured vine still gives depth, a plain
//! carton in the sun gives holes and scattered speckle.
//!
//! Per pixel, with `E` the ambient irradiance on the surface (sun and sky, from the
//! render, W/m² in the imagers' band) and `P(z) = P_laser / (4·tan(h/2)·tan(v/2)·z²)` the
//! projector's mean irradiance at depth `z`:
//!
//! 1. **Surface texture** `c_p`: the coefficient of variation (σ/μ) of the infrared image
//!    without the dots (albedo and shading under sun, sky and the projector's mean light)
//!    over the matching window (`window_px²`).
//! 2. **Texture the matcher sees**: the dots add their own, independent contrast, diluted
//!    by the ambient light: `c = √(c_p² + (k_dot·P/(E+P))²)`, `k_dot` the pattern's
//!    contrast (σ/μ of its irradiance).
//! 3. **Noise**: the imagers' auto-exposure puts the frame's mean at `ae_level` of full
//!    scale; a pixel at level `s` has relative noise `σ_rel = √(read² + shot·s)/s`
//!    ([`super::camera::ImageNoise`]'s parameters).
//! 4. **Matching SNR** over the window's `N = window_px²` pixels:
//!    `SNR = c·√N/σ_rel`.
//! 5. **Validity**: a pixel is matched with probability
//!    `1/(1 + exp(−ln(SNR/snr_threshold)/snr_softness))` (holes where texture is
//!    missing, speckle where it is marginal), and its disparity noise is the datasheet
//!    subpixel times `max(1, snr_reference/SNR)` (disparity variance is inversely
//!    proportional to the texture energy under the window).
//!
//! The infrared image is approximated by the colour render's mean of R, G and B (the
//! D435's depth imagers have no infrared cut filter and see 400–1000 nm), brightened by
//! the projector's light on each pixel. The window straddling an edge sees the contrast
//! of the edge itself, so plain surfaces keep depth along their outline, as block matchers
//! do.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Parameters of the daylight stereo model (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SunlightStereo {
    /// Irradiance in the depth imagers' band, W/m², of one relative unit of the
    /// renderer's light (`[render] sun_irradiance` and `sky_irradiance`).
    pub ambient_w_m2: f64,
    /// Projector optical power, W (the D435's `laser_power`, default 150 mW of 360 mW).
    pub projector_power_w: f64,
    /// Projector field of projection, horizontal and vertical, degrees (D435: 86°×57°).
    pub projector_fov_deg: [f64; 2],
    /// Contrast of the dot pattern (σ/μ of its irradiance over a window).
    pub dot_contrast: f64,
    /// Edge of the square matching window, px (odd).
    pub window_px: u32,
    /// Mean level of the infrared frame under the imagers' auto-exposure, fraction of
    /// full scale.
    pub ae_level: f64,
    /// Matching SNR at which half the pixels are matched.
    pub snr_threshold: f64,
    /// Width of the validity's logistic in `ln SNR`.
    pub snr_softness: f64,
    /// Matching SNR from which the datasheet disparity noise holds.
    pub snr_reference: f64,
    /// Read-noise σ of the infrared imagers, linear units.
    pub read_noise: f64,
    /// Shot-noise variance per unit of linear signal.
    pub shot_gain: f64,
}

/// The images of a rendered frame [`SunlightStereo::snr`] reads (the fields of
/// [`super::shade::Frame`]).
#[derive(Clone, Copy, Debug)]
pub struct FrameView<'a> {
    /// Width, px.
    pub width: u32,
    /// Height, px.
    pub height: u32,
    /// Linear RGB, 3 values per pixel.
    pub linear: &'a [f32],
    /// Optical-axis depth, m (0: no hit).
    pub depth_m: &'a [f32],
    /// Irradiance on the surface, relative units.
    pub irradiance: &'a [f32],
}

/// Scratch of [`SunlightStereo::snr`]: integral images and the infrared frame.
#[derive(Clone, Debug, Default)]
pub struct SnrScratch {
    ir: Vec<f64>,
    sum: Vec<f64>,
    sum_sq: Vec<f64>,
}

impl SunlightStereo {
    /// The model of a scenario's `[sensors.stereo_depth]`, with the `[render]` image
    /// noise.
    pub fn from_params(
        depth: &crate::params::StereoDepthParams,
        render: &crate::params::RenderParams,
    ) -> SunlightStereo {
        SunlightStereo {
            ambient_w_m2: depth.ambient_w_m2,
            projector_power_w: depth.projector_power_mw * 1e-3,
            projector_fov_deg: depth.projector_fov_deg,
            dot_contrast: depth.dot_contrast,
            window_px: depth.window_px,
            ae_level: depth.ae_level,
            snr_threshold: depth.snr_threshold,
            snr_softness: depth.snr_softness,
            snr_reference: depth.snr_reference,
            read_noise: render.read_noise,
            shot_gain: render.shot_gain,
        }
    }

    /// Mean projector irradiance at depth `z_m`, W/m².
    pub fn projector_w_m2(&self, z_m: f64) -> f64 {
        self.projector_at(self.projector_area_1m(), z_m)
    }

    /// Area the projector lights at 1 m, m²: `4·tan(h/2)·tan(v/2)`.
    fn projector_area_1m(&self) -> f64 {
        let [h, v] = self.projector_fov_deg;
        4.0 * (h.to_radians() / 2.0).tan() * (v.to_radians() / 2.0).tan()
    }

    /// [`Self::projector_w_m2`] with the lit area at 1 m given (`snr` computes it once per
    /// frame, where each pixel took four tangents).
    #[inline]
    fn projector_at(&self, area_1m: f64, z_m: f64) -> f64 {
        self.projector_power_w / area_1m / (z_m * z_m).max(1e-6)
    }

    /// Texture contrast the matcher sees on a surface with texture contrast `c_p` under
    /// ambient `e_w_m2` at depth `z_m` (step 2).
    pub fn contrast(&self, c_p: f64, e_w_m2: f64, z_m: f64) -> f64 {
        self.contrast_under(c_p, e_w_m2, self.projector_w_m2(z_m))
    }

    /// [`Self::contrast`] with the projector's irradiance `p_w_m2` given.
    #[inline]
    fn contrast_under(&self, c_p: f64, e_w_m2: f64, p_w_m2: f64) -> f64 {
        let total = (e_w_m2.max(0.0) + p_w_m2).max(1e-12);
        c_p.hypot(self.dot_contrast * p_w_m2 / total)
    }

    /// Relative noise σ/s of a pixel at level `s` (fraction of full scale; step 3).
    pub fn relative_noise(&self, s: f64) -> f64 {
        let s = s.clamp(1e-4, 1.0);
        (self.read_noise * self.read_noise + self.shot_gain * s).sqrt() / s
    }

    /// Matching SNR from the texture contrast and the pixel's level (step 4).
    pub fn snr_of(&self, contrast: f64, level: f64) -> f64 {
        contrast * f64::from(self.window_px) / self.relative_noise(level)
    }

    /// Probability that a pixel of matching SNR `snr` gets depth (step 5).
    pub fn valid_probability(&self, snr: f64) -> f64 {
        if snr <= 0.0 || snr.is_nan() {
            return 0.0;
        }
        let x = (snr / self.snr_threshold).ln() / self.snr_softness.max(1e-9);
        1.0 / (1.0 + (-x).exp())
    }

    /// Factor on the datasheet disparity noise at matching SNR `snr` (step 5).
    pub fn noise_factor(&self, snr: f64) -> f64 {
        (self.snr_reference / snr.max(1e-9)).max(1.0)
    }

    /// The matching SNR of every pixel of a rendered frame (`width × height`, its sharp
    /// linear colour image, depth and irradiance as in [`super::shade::Frame`]), into
    /// `out` (row-major; 0 where nothing is hit). Deterministic and independent of the
    /// thread count.
    ///
    /// # Panics
    ///
    /// If an image does not hold one value (colour: three) per pixel.
    pub fn snr(&self, frame: FrameView<'_>, out: &mut [f32], scratch: &mut SnrScratch) {
        let (w, h) = (frame.width as usize, frame.height as usize);
        let n = w * h;
        assert_eq!(out.len(), n, "SNR image size");
        assert_eq!(frame.linear.len(), 3 * n, "colour image size");
        assert_eq!(frame.depth_m.len(), n, "depth image size");
        assert_eq!(frame.irradiance.len(), n, "irradiance image size");
        // The infrared image: ambient light plus the projector's on each surface.
        let area_1m = self.projector_area_1m();
        scratch.ir.resize(n, 0.0);
        scratch
            .ir
            .par_chunks_mut(w.max(1))
            .enumerate()
            .for_each(|(v, row)| {
                for (u, ir) in row.iter_mut().enumerate() {
                    let i = v * w + u;
                    let rgb = &frame.linear[3 * i..3 * i + 3];
                    let y = f64::from(rgb[0] + rgb[1] + rgb[2]) / 3.0;
                    let z = f64::from(frame.depth_m[i]);
                    let e = f64::from(frame.irradiance[i]) * self.ambient_w_m2;
                    *ir = if z > 0.0 && z.is_finite() && e > 0.0 {
                        y * (e + self.projector_at(area_1m, z)) / e
                    } else {
                        y
                    };
                }
            });
        let mean = scratch.ir.iter().sum::<f64>() / n.max(1) as f64;
        // Integral images of the infrared image and its square, (w+1)×(h+1).
        let iw = w + 1;
        scratch.sum.clear();
        scratch.sum.resize(iw * (h + 1), 0.0);
        scratch.sum_sq.clear();
        scratch.sum_sq.resize(iw * (h + 1), 0.0);
        for v in 0..h {
            let (mut row, mut row_sq) = (0.0, 0.0);
            for u in 0..w {
                let x = scratch.ir[v * w + u];
                row += x;
                row_sq += x * x;
                scratch.sum[(v + 1) * iw + u + 1] = scratch.sum[v * iw + u + 1] + row;
                scratch.sum_sq[(v + 1) * iw + u + 1] = scratch.sum_sq[v * iw + u + 1] + row_sq;
            }
        }
        let r = (self.window_px / 2) as usize;
        let (sum, sum_sq, ir) = (&scratch.sum, &scratch.sum_sq, &scratch.ir);
        out.par_chunks_mut(w.max(1))
            .enumerate()
            .for_each(|(v, row)| {
                let (v0, v1) = (v.saturating_sub(r), (v + r + 1).min(h));
                for (u, o) in row.iter_mut().enumerate() {
                    let i = v * w + u;
                    let z = f64::from(frame.depth_m[i]);
                    if !(z > 0.0 && z.is_finite()) {
                        *o = 0.0;
                        continue;
                    }
                    let (u0, u1) = (u.saturating_sub(r), (u + r + 1).min(w));
                    let count = ((v1 - v0) * (u1 - u0)) as f64;
                    let rect = |s: &[f64]| {
                        s[v1 * iw + u1] - s[v0 * iw + u1] - s[v1 * iw + u0] + s[v0 * iw + u0]
                    };
                    let m = rect(sum) / count;
                    let var = (rect(sum_sq) / count - m * m).max(0.0);
                    let c_p = if m > 0.0 { var.sqrt() / m } else { 0.0 };
                    let e = f64::from(frame.irradiance[i]) * self.ambient_w_m2;
                    let c = self.contrast_under(c_p, e, self.projector_at(area_1m, z));
                    let level = if mean > 0.0 {
                        self.ae_level * ir[i] / mean
                    } else {
                        0.0
                    };
                    *o = self.snr_of(c, level) as f32;
                }
            });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::{RenderParams, StereoDepthParams};
    use crate::render::shade::Frame;

    fn defaults() -> SunlightStereo {
        SunlightStereo::from_params(&StereoDepthParams::default(), &RenderParams::default())
    }

    /// The numbers `scenarios/defaults.toml` derives its SNR settings from: a plain wall
    /// at 2 m indoors (2 W/m² in the band) is the datasheet's measurement (SNR ≈ 3.9 =
    /// `snr_reference`), and such a wall keeps depth to about 2.8 m (`snr_threshold`).
    #[test]
    fn the_defaults_put_the_datasheet_wall_at_the_reference_snr() {
        let m = defaults();
        // 150 mW over 86° × 57°: 2.03 m² at 1 m.
        assert!((m.projector_w_m2(1.0) - 0.15 / 2.0254).abs() < 1e-4);
        assert!((m.projector_w_m2(2.0) * 4.0 - m.projector_w_m2(1.0)).abs() < 1e-12);
        let wall = |z: f64| m.snr_of(m.contrast(0.0, 2.0, z), m.ae_level);
        assert!((wall(2.0) - m.snr_reference).abs() < 0.15, "{}", wall(2.0));
        // Half the pixels at 2.8 m ± 0.1.
        assert!(wall(2.7) > m.snr_threshold && wall(2.9) < m.snr_threshold);
        assert!((m.valid_probability(m.snr_threshold) - 0.5).abs() < 1e-12);
        // In full sun (0.8 + 0.3 relative on a level surface) the dots are gone: a plain
        // surface at 1 m has no chance, a leaf-textured one (σ/μ 0.3) every chance.
        let sun = 1.0 * m.ambient_w_m2;
        assert!(m.valid_probability(m.snr_of(m.contrast(0.0, sun, 1.0), m.ae_level)) < 1e-3);
        assert!(m.valid_probability(m.snr_of(m.contrast(0.3, sun, 1.0), m.ae_level)) > 0.999);
        assert_eq!(m.noise_factor(2.0 * m.snr_reference), 1.0);
        assert!((m.noise_factor(m.snr_reference / 3.0) - 3.0).abs() < 1e-12);
    }

    /// A frame with a known texture: two albedos in a checkerboard of 1-px squares has
    /// σ/μ = (a − b)/(a + b) over any window of even pixel count; the SNR image gives
    /// the closed form inside.
    #[test]
    fn the_snr_image_follows_the_closed_form_on_a_checkerboard() {
        let m = defaults();
        let (w, h) = (40u32, 30u32);
        let mut f = Frame::new(w, h);
        let (a, b) = (0.3f32, 0.1f32);
        let e = 0.5f32;
        for v in 0..h as usize {
            for u in 0..w as usize {
                let i = v * w as usize + u;
                let y = if (u + v) % 2 == 0 { a } else { b } * e;
                f.linear[3 * i..3 * i + 3].fill(y);
                f.depth_m[i] = 3.0;
                f.irradiance[i] = e;
            }
        }
        let mut snr = vec![0.0f32; (w * h) as usize];
        m.snr(f.view(), &mut snr, &mut SnrScratch::default());
        // A 7×7 window holds 25 of one and 24 of the other: σ/μ from those counts.
        let (na, nb) = (25.0f64, 24.0f64);
        let (fa, fb) = (f64::from(a), f64::from(b));
        let mean = (na * fa + nb * fb) / 49.0;
        let var = (na * fa * fa + nb * fb * fb) / 49.0 - mean * mean;
        let c_p = var.sqrt() / mean;
        let ew = f64::from(e) * m.ambient_w_m2;
        // The pixel's level: its infrared value over the frame's mean, times ae_level.
        let i = 16 * w as usize + 20;
        let frame_mean = (fa + fb) / 2.0;
        let level = m.ae_level * fa / frame_mean;
        let expected = m.snr_of(m.contrast(c_p, ew, 3.0), level);
        assert!(
            (f64::from(snr[i]) / expected - 1.0).abs() < 1e-4,
            "{} vs {expected}",
            snr[i]
        );
    }
}
