//! How a colour camera exposes: auto-exposure with a time constant, the split of the
//! exposure into time and analog gain, and residual vignetting.
//!
//! **Auto-exposure.** The renderer's image is radiance × `[render] exposure`: what the
//! sensor records over the reference exposure time `t_ref` at unity gain. A camera
//! exposes frame `k` with total gain `G_k` (relative to that), chosen from frame `k−1`'s
//! meter `m_{k−1}` (the mean over the image of `min(1, G·Y)`, `Y` the mean of R, G and B:
//! what the sensor recorded, clipped at full scale):
//!
//! ```text
//! ln G_k = ln G_{k−1} + (1 − e^{−Δt/τ})·(ln target − ln m_{k−1})
//! ```
//!
//! a first-order response of time constant `τ` in exposure value, the way camera AE loops
//! are tuned; the first frame is exposed from its own meter (a camera that has been
//! running). `G` is split into exposure time `t = clamp(G·t_ref, t_min, t_max)` first and
//! analog gain `A = clamp(G·t_ref/t, 1, A_max)` after, as sensors do to keep noise low;
//! beyond those limits the image is under- or over-exposed (`G` is what was achieved,
//! so the loop does not wind up). The analog gain amplifies read noise by `A` and the
//! shot-noise variance per unit signal by `A` (fewer photons per code); the exposure
//! time sets the motion blur ([`super::blur::motion_blur`]).
//!
//! **Vignetting.** Lenses darken off-axis as `cos⁴θ`; cameras correct most of it
//! (lens-shading correction). The residual is modelled as
//! `V(θ) = 1 − s·(1 − cos⁴θ)`, `s` the uncorrected share.

use super::camera::{ImageNoise, RayTable};
use super::shade::Frame;
use rayon::prelude::*;

/// Auto-exposure and lens-shading parameters of a camera (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExposureLimits {
    /// Mean clipped linear level the loop holds.
    pub target_level: f64,
    /// Time constant of the loop, s.
    pub time_constant_s: f64,
    /// Exposure time of unit gain, s.
    pub reference_s: f64,
    /// Shortest exposure, s.
    pub min_s: f64,
    /// Longest exposure, s.
    pub max_s: f64,
    /// Largest analog gain.
    pub max_gain: f64,
}

/// One frame's exposure.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Exposure {
    /// Exposure time, s.
    pub time_s: f64,
    /// Analog gain (≥ 1).
    pub analog_gain: f64,
    /// Total gain relative to the render: `time_s / reference_s · analog_gain`.
    pub gain: f64,
}

/// The auto-exposure loop of one camera (shared by the eyes of a stereo pair).
#[derive(Clone, Debug)]
pub struct AutoExposure {
    limits: ExposureLimits,
    /// Gain and meter of the last exposed frame, and its time (s).
    last: Option<(f64, f64, f64)>,
}

impl AutoExposure {
    /// A loop that has not exposed a frame yet.
    pub fn new(limits: ExposureLimits) -> AutoExposure {
        AutoExposure { limits, last: None }
    }

    /// Splits a wanted total gain into time and analog gain within the limits.
    pub fn split(&self, wanted_gain: f64) -> Exposure {
        let l = &self.limits;
        let wanted = if wanted_gain.is_finite() && wanted_gain > 0.0 {
            wanted_gain
        } else {
            1.0
        };
        let time_s = (wanted * l.reference_s).clamp(l.min_s, l.max_s.max(l.min_s));
        let analog_gain = (wanted * l.reference_s / time_s).clamp(1.0, l.max_gain.max(1.0));
        Exposure {
            time_s,
            analog_gain,
            gain: time_s / l.reference_s * analog_gain,
        }
    }

    /// The exposure of a frame at `t_s` whose unexposed render is `frame`: from the
    /// previous frame's meter, or (the first frame) from this frame's own. Call
    /// [`AutoExposure::metered`] with the result once the frame is exposed.
    pub fn choose(&self, t_s: f64, frame: &Frame) -> Exposure {
        let target = self.limits.target_level;
        match self.last {
            Some((gain, meter, t_prev)) => {
                let dt = (t_s - t_prev).max(0.0);
                let alpha = 1.0 - (-dt / self.limits.time_constant_s.max(1e-9)).exp();
                let step = alpha * (target.ln() - meter.max(1e-6).ln());
                self.split(gain * step.exp())
            }
            None => {
                // Settle on the frame itself: a few fixed-point steps (clipping makes
                // the meter nonlinear in the gain).
                let mut e = self.split(1.0);
                for _ in 0..8 {
                    let m = meter(frame, e.gain);
                    e = self.split(e.gain * target / m.max(1e-6));
                }
                e
            }
        }
    }

    /// Records frame `t_s`, exposed with `exposure`, whose unexposed render is `frame`.
    pub fn metered(&mut self, t_s: f64, exposure: Exposure, frame: &Frame) {
        self.last = Some((exposure.gain, meter(frame, exposure.gain), t_s));
    }
}

/// The mean of `min(1, gain·Y)` over the image, `Y` the mean of R, G and B (sequential:
/// the same sum on any thread count).
pub fn meter(frame: &Frame, gain: f64) -> f64 {
    let n = frame.linear.len() / 3;
    if n == 0 {
        return 0.0;
    }
    let g = gain as f32;
    let sum: f64 = frame
        .linear
        .chunks_exact(3)
        .map(|c| f64::from((g * (c[0] + c[1] + c[2]) / 3.0).min(1.0)))
        .sum();
    sum / n as f64
}

/// The residual vignetting factor of every pixel of `rays`: `1 − s·(1 − cos⁴θ)`.
pub fn vignetting(rays: &RayTable, share: f64) -> Vec<f32> {
    (0..rays.len())
        .map(|i| {
            let (x, y, z) = (
                f64::from(rays.x[i]),
                f64::from(rays.y[i]),
                f64::from(rays.z[i]),
            );
            let c2 = z * z / (x * x + y * y + z * z).max(1e-30);
            (1.0 - share * (1.0 - c2 * c2)) as f32
        })
        .collect()
}

/// Exposes `frame.linear` in place: each pixel times `gain` and its vignetting factor
/// (`vignette`, one per pixel, or empty for none).
pub fn apply_gain(frame: &mut Frame, gain: f64, vignette: &[f32]) {
    let g = gain as f32;
    if vignette.is_empty() {
        frame.linear.par_iter_mut().for_each(|x| *x *= g);
    } else {
        frame
            .linear
            .par_chunks_mut(3)
            .zip(vignette.par_iter())
            .for_each(|(c, v)| c.iter_mut().for_each(|x| *x *= g * v));
    }
}

/// The image noise of a sensor at analog gain `analog_gain`: read noise ×A, shot-noise
/// variance per unit signal ×A.
pub fn noise_at_gain(base: &ImageNoise, analog_gain: f64) -> ImageNoise {
    let a = analog_gain as f32;
    ImageNoise {
        read_noise: base.read_noise * a,
        shot_gain: base.shot_gain * a,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits() -> ExposureLimits {
        ExposureLimits {
            target_level: 0.18,
            time_constant_s: 0.25,
            reference_s: 0.15e-3,
            min_s: 0.02e-3,
            max_s: 33e-3,
            max_gain: 16.0,
        }
    }

    /// A uniform grey frame of linear level `y`.
    fn grey(y: f32) -> Frame {
        let mut f = Frame::new(8, 8);
        f.linear.fill(y);
        f
    }

    #[test]
    fn the_first_frame_is_exposed_to_the_target() {
        let ae = AutoExposure::new(limits());
        let e = ae.choose(0.0, &grey(0.05));
        // The meter sums f32 pixels.
        assert!((e.gain - 0.18 / 0.05).abs() < 1e-6, "{e:?}");
        assert!((e.time_s - 0.15e-3 * 3.6).abs() < 1e-9);
        assert_eq!(e.analog_gain, 1.0);
    }

    #[test]
    fn time_first_then_gain_then_limits() {
        let ae = AutoExposure::new(limits());
        // 1000× the reference: 33 ms, then gain 150/33·… capped at 16.
        let e = ae.split(1000.0);
        assert!((e.time_s - 33e-3).abs() < 1e-12);
        assert!((e.analog_gain - 1000.0 * 0.15 / 33.0).abs() < 1e-9);
        let e = ae.split(1e6);
        assert_eq!(e.analog_gain, 16.0);
        assert!((e.gain - 33.0 / 0.15 * 16.0).abs() < 1e-6);
        let e = ae.split(0.01);
        assert!((e.time_s - 0.02e-3).abs() < 1e-15, "shortest exposure");
        assert!((e.gain - 0.02 / 0.15).abs() < 1e-9);
    }

    /// A step in scene brightness: the log-error decays as exp(−t/τ), frame by frame.
    #[test]
    fn a_brightness_step_recovers_with_the_time_constant() {
        let mut ae = AutoExposure::new(limits());
        let dt = 1.0 / 15.0;
        let bright = grey(0.18);
        let e0 = ae.choose(0.0, &bright);
        ae.metered(0.0, e0, &bright);
        assert!((e0.gain - 1.0).abs() < 1e-6);
        // Into the canopy: 6× darker.
        let dark = grey(0.03);
        let mut t = 0.0;
        let mut gain = e0.gain;
        for _ in 0..30 {
            t += dt;
            let e = ae.choose(t, &dark);
            ae.metered(t, e, &dark);
            gain = e.gain;
            // Frame k (at t = k·dt) is exposed from frame k−1's meter: the first dark
            // frame keeps the bright exposure, then the error in ln(level) decays as
            // exp(−(t − dt)/τ).
            let expected_err = 6f64.ln() * (-(t - dt) / 0.25).exp();
            let err = (0.18f64).ln() - (0.03 * gain).ln();
            assert!(
                (err - expected_err).abs() < 1e-5,
                "t {t}: {err} vs {expected_err}"
            );
        }
        assert!((gain - 6.0).abs() < 0.01, "{gain}");
    }

    #[test]
    fn vignetting_follows_cos4_share() {
        use crate::render::camera::{BrownConrady, Intrinsics};
        let intr = Intrinsics::from_hfov(64, 48, 90.0, BrownConrady::default());
        let rays = intr.pixel_rays();
        let v = vignetting(&rays, 0.5);
        // Corner pixel (0, 0): θ from the pinhole.
        let (x, y) = (-intr.cx / intr.fx, -intr.cy / intr.fy);
        let c = 1.0 / (1.0 + x * x + y * y).sqrt();
        let expected = 1.0 - 0.5 * (1.0 - c.powi(4));
        assert!(
            (f64::from(v[0]) - expected).abs() < 1e-5,
            "{} {expected}",
            v[0]
        );
        assert!(vignetting(&rays, 0.0).iter().all(|&x| x == 1.0));
    }
}
