//! Camera motion blur: the smear a moving camera records during its exposure.
//!
//! The vineyard is static, so all image motion comes from the camera's own twist. A
//! scene point at depth `Z` seen at normalized image coordinates `(x, y)` moves, for a
//! camera with linear velocity `v` and angular velocity `ω` (both in the optical frame),
//! at (Longuet-Higgins and Prazdny 1980)
//!
//! ```text
//! ẋ = (−v_x + x·v_z)/Z + x·y·ω_x − (1 + x²)·ω_y + y·ω_z
//! ẏ = (−v_y + y·v_z)/Z + (1 + y²)·ω_x − x·y·ω_y − x·ω_z
//! ```
//!
//! (sky pixels have `Z = ∞`: rotation only). Over an exposure `T` centred on the frame's
//! stamp a pixel integrates the scene along the segment `±T/2·(f_x ẋ, f_y ẏ)` pixels. The
//! blur gathers that integral from the sharp render: the average of bilinear samples along
//! the pixel's own flow segment. This is exact for a smooth depth field and motion that is
//! linear over the exposure; at depth edges it uses the pixel's own depth (the usual
//! gather approximation). Flow uses the pinhole focal lengths (lens distortion changes it
//! by well under a pixel for the modelled cameras). Depth images are not blurred (a
//! D435's infrared exposure is short).
//!
//! **Rolling shutter** ([`rolling_shutter`]) uses the same flow: a rolling-shutter sensor
//! exposes row `v` at `δt_v = (v − (H−1)/2)/H · t_readout` after the frame's stamp (the
//! stamp is the middle row's exposure centre), so the pixel shows what the global-shutter
//! image shows at `p − ṗ·δt_v` (the scene point that moves to `p` by then). A camera
//! yawing at `ω` skews a vertical edge by `f·ω·t_readout` pixels from top to bottom. The
//! depth image is not warped (the D435's depth imagers are global shutter).

use super::camera::RayTable;
use super::shade::Frame;
use nalgebra::Vector3;
use rayon::prelude::*;
use wide::{CmpGt, CmpLe, f32x4, f64x4};

/// Velocity of a camera during an exposure, in its optical frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraMotion {
    /// Velocity of the optical centre, optical frame, m/s.
    pub linear_mps: Vector3<f64>,
    /// Angular velocity, optical frame, rad/s.
    pub angular_radps: Vector3<f64>,
}

/// Most samples along one pixel's flow segment (longer smears are sampled sparser).
const MAX_SAMPLES: usize = 64;

/// Pixels of a row whose flows are computed together (four per SIMD step, into stack
/// buffers) before the gathers that use them.
const BLOCK: usize = 64;

/// Flow (pixels over the exposure) of the pixel whose ray is `dir` (optical frame) and
/// whose depth is `depth_m` (0 = nothing hit: infinitely far).
#[inline]
fn flow_px(
    dir: [f32; 3],
    depth_m: f32,
    m: &CameraMotion,
    exposure_s: f64,
    f: (f64, f64),
) -> [f64; 2] {
    let (dx, dy, dz) = (f64::from(dir[0]), f64::from(dir[1]), f64::from(dir[2]));
    if dz <= 0.0 {
        return [0.0, 0.0];
    }
    let (x, y) = (dx / dz, dy / dz);
    let inv_z = if depth_m > 0.0 && depth_m.is_finite() {
        1.0 / f64::from(depth_m)
    } else {
        0.0
    };
    let (v, w) = (&m.linear_mps, &m.angular_radps);
    let xd = (-v.x + x * v.z) * inv_z + x * y * w.x - (1.0 + x * x) * w.y + y * w.z;
    let yd = (-v.y + y * v.z) * inv_z + (1.0 + y * y) * w.x - x * y * w.y - x * w.z;
    [f.0 * xd * exposure_s, f.1 * yd * exposure_s]
}

/// Flows ([`flow_px`]) over `time_s` of the `n ≤ BLOCK` pixels from index `i0` into `fu`
/// and `fv`, four pixels per SIMD step (each lane the scalar formula's operations in its
/// order, so the same bits), the remainder one by one.
#[allow(clippy::too_many_arguments)]
#[inline]
fn flow_block(
    rays: &RayTable,
    depth: &[f32],
    (i0, n): (usize, usize),
    m: &CameraMotion,
    time_s: f64,
    f: (f64, f64),
    fu: &mut [f64; BLOCK],
    fv: &mut [f64; BLOCK],
) {
    let (x, y, z) = (
        &rays.x[i0..i0 + n],
        &rays.y[i0..i0 + n],
        &rays.z[i0..i0 + n],
    );
    let d = &depth[i0..i0 + n];
    let (v, w) = (&m.linear_mps, &m.angular_radps);
    let s = f64x4::splat;
    let (one, zero) = (s(1.0), f64x4::ZERO);
    let widen = |a: &[f32]| f64x4::from([a[0], a[1], a[2], a[3]].map(f64::from));
    let lanes = n - n % 4;
    for j in (0..lanes).step_by(4) {
        let (dx, dy, dz) = (widen(&x[j..]), widen(&y[j..]), widen(&z[j..]));
        let dm = widen(&d[j..]);
        let (x, y) = (dx / dz, dy / dz);
        let inv_z = (dm.cmp_gt(zero) & dm.is_finite()).blend(one / dm, zero);
        let xd =
            (s(-v.x) + x * s(v.z)) * inv_z + x * y * s(w.x) - (one + x * x) * s(w.y) + y * s(w.z);
        let yd =
            (s(-v.y) + y * s(v.z)) * inv_z + (one + y * y) * s(w.x) - x * y * s(w.y) - x * s(w.z);
        let behind = dz.cmp_le(zero);
        let u = behind.blend(zero, s(f.0) * xd * s(time_s)).to_array();
        let v = behind.blend(zero, s(f.1) * yd * s(time_s)).to_array();
        fu[j..j + 4].copy_from_slice(&u);
        fv[j..j + 4].copy_from_slice(&v);
    }
    for j in lanes..n {
        [fu[j], fv[j]] = flow_px([x[j], y[j], z[j]], d[j], m, time_s, f);
    }
}

/// The sharp image a warp gathers from while it rewrites the frame: `w × h` pixels of
/// four values (RGB and an unused one, so that a pixel is one SIMD vector).
struct Sharp<'a> {
    image: &'a [[f32; 4]],
    w: usize,
    h: usize,
}

impl Sharp<'_> {
    /// The RGB value at `(px, py)`: bilinear, clamped to the image (what the sensor saw
    /// just outside its edge is unknown; the edge pixel stands in for it). Each lane is
    /// computed as the scalar formula would (the fourth is ignored by callers).
    #[inline(always)]
    fn at(&self, px: f64, py: f64) -> f32x4 {
        let (w, h) = (self.w, self.h);
        let px = px.clamp(0.0, (w - 1) as f64);
        let py = py.clamp(0.0, (h - 1) as f64);
        // Non-negative (or NaN, which both casts make 0): the signed cast is the unsigned
        // one.
        let (x0, y0) = (px as i64 as usize, py as i64 as usize);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let fx = f32x4::splat((px - x0 as f64) as f32);
        let fy = f32x4::splat((py - y0 as f64) as f32);
        let at = |x: usize, y: usize| f32x4::from(self.image[y * w + x]);
        let (a, b) = (at(x0, y0), at(x1, y0));
        let (c, d) = (at(x0, y1), at(x1, y1));
        let top = a + (b - a) * fx;
        let bottom = c + (d - c) * fx;
        top + (bottom - top) * fy
    }
}

/// `⌈len⌉ + 1` samples, at most [`MAX_SAMPLES`], for a flow of `len ≥ 0` pixels (NaN: 1);
/// `f64::ceil` without the library call the baseline x86-64 target makes of it.
#[inline]
fn sample_count(len: f64) -> usize {
    let t = len as usize;
    let ceil = if (t as f64) < len {
        t.saturating_add(1)
    } else {
        t
    };
    ceil.min(MAX_SAMPLES - 1) + 1
}

/// Offsets along the flow segment of the `n` samples, `(k + ½)/n − ½` for `k < n`, for
/// every `n ≤ MAX_SAMPLES` (the samples of `n` start at `n (n − 1) / 2`).
fn sample_offsets() -> &'static [f64] {
    static OFFSETS: std::sync::LazyLock<Vec<f64>> = std::sync::LazyLock::new(|| {
        (1..=MAX_SAMPLES)
            .flat_map(|n| (0..n).map(move |k| (k as f64 + 0.5) / n as f64 - 0.5))
            .collect()
    });
    &OFFSETS
}

/// Rewrites every pixel of `frame.linear` from a sharp copy of it, rows in parallel (the
/// result does not depend on the thread count): `pixel(sharp, u, v, flow)` gives pixel
/// `(u, v)`'s new value, or `None` to keep it, where `flow` is its flow ([`flow_px`])
/// over `time_of_row(v)`. `scratch` holds the sharp copy (grown on first use, then
/// reused).
fn warp(
    frame: &mut Frame,
    scratch: &mut Vec<[f32; 4]>,
    rays: &RayTable,
    f: (f64, f64),
    motion: &CameraMotion,
    time_of_row: impl Fn(usize) -> f64 + Sync,
    pixel: impl Fn(&Sharp, usize, usize, [f64; 2]) -> Option<f32x4> + Sync,
) {
    let (w, h) = (frame.width as usize, frame.height as usize);
    assert_eq!(
        (w, h),
        (rays.width as usize, rays.height as usize),
        "frame and ray table sizes"
    );
    scratch.clear();
    scratch.extend(
        frame
            .linear
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2], 0.0]),
    );
    let sharp = Sharp {
        image: scratch,
        w,
        h,
    };
    let depth = &frame.depth_m;
    frame
        .linear
        .par_chunks_mut(3 * w)
        .enumerate()
        .for_each(|(v, row)| {
            let time_s = time_of_row(v);
            let (mut fu, mut fv) = ([0.0; BLOCK], [0.0; BLOCK]);
            for u0 in (0..w).step_by(BLOCK) {
                let n = BLOCK.min(w - u0);
                flow_block(
                    rays,
                    depth,
                    (v * w + u0, n),
                    motion,
                    time_s,
                    f,
                    &mut fu,
                    &mut fv,
                );
                for j in 0..n {
                    let u = u0 + j;
                    if let Some(c) = pixel(&sharp, u, v, [fu[j], fv[j]]) {
                        row[3 * u..3 * u + 3].copy_from_slice(&c.to_array()[..3]);
                    }
                }
            }
        });
}

/// Blurs `frame.linear` in place for a camera moving with `motion` during an exposure of
/// `exposure_s` centred on the frame's time; `rays` are the frame's pixel rays, `fx_px`
/// and `fy_px` the focal lengths. `scratch` holds the sharp image meanwhile (grown on
/// first use, then reused). Rows in parallel; the result does not depend on the thread
/// count. No-op for a non-positive exposure.
pub fn motion_blur(
    frame: &mut Frame,
    scratch: &mut Vec<[f32; 4]>,
    rays: &RayTable,
    fx_px: f64,
    fy_px: f64,
    motion: &CameraMotion,
    exposure_s: f64,
) {
    // Written so NaN exposures are no-ops too.
    if exposure_s.is_nan() || exposure_s <= 0.0 {
        return;
    }
    let offsets = sample_offsets();
    let time_of_row = |_| exposure_s;
    warp(
        frame,
        scratch,
        rays,
        (fx_px, fy_px),
        motion,
        time_of_row,
        |sharp, u, v, [fu, fv]| {
            let len = fu.abs().max(fv.abs());
            if len < 0.25 {
                return None;
            }
            let n = sample_count(len);
            let mut acc = f32x4::ZERO;
            for &s in &offsets[n * (n - 1) / 2..][..n] {
                acc += sharp.at(u as f64 + s * fu, v as f64 + s * fv);
            }
            Some(acc * f32x4::splat(1.0 / n as f32))
        },
    );
}

/// Warps `frame.linear` in place to what a rolling-shutter sensor with a frame readout
/// time `readout_s` records while the camera moves with `motion` (see the module
/// documentation); arguments as for [`motion_blur`]. Bilinear gather, rows in parallel;
/// no-op for a non-positive readout.
pub fn rolling_shutter(
    frame: &mut Frame,
    scratch: &mut Vec<[f32; 4]>,
    rays: &RayTable,
    fx_px: f64,
    fy_px: f64,
    motion: &CameraMotion,
    readout_s: f64,
) {
    if readout_s.is_nan() || readout_s <= 0.0 {
        return;
    }
    let h = frame.height as f64;
    let centre = (h - 1.0) / 2.0;
    // Row v is exposed dt after the stamp; a pixel shows what the stamp's image shows
    // where the scene point it sees was then (it moved by the flow over dt since).
    let time_of_row = |v: usize| (v as f64 - centre) / h * readout_s;
    warp(
        frame,
        scratch,
        rays,
        (fx_px, fy_px),
        motion,
        time_of_row,
        |sharp, u, v, [fu, fv]| {
            if fu.abs().max(fv.abs()) < 1e-3 {
                None
            } else {
                Some(sharp.at(u as f64 - fu, v as f64 - fv))
            }
        },
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rolling_shutter_skews_a_vertical_edge_by_f_omega_readout() {
        // A far vertical edge (depth 0 = infinitely far: rotation only) at the image
        // centre, black left, white right; the camera yaws at ω = 0.5 rad/s about its
        // optical y axis; readout 30 ms; f = 300 px. Closed form: at x ≈ 0 the image moves
        // at ẋ = −(1 + x²)·ω_y, so row v (exposed δt_v after the stamp) shows the edge at
        // u_c − f·ω·δt_v: a slope of f·ω·t_readout / H px per row, 4.5 px from top to
        // bottom. Measured: the edge position in each row from the row's sum (a unit-wide
        // ramp at a contributes (w − 1) − a exactly), against the closed form within
        // 0.01 px.
        let (w, h) = (160u32, 200u32);
        let intr = crate::render::camera::Intrinsics {
            width: w,
            height: h,
            fx: 300.0,
            fy: 300.0,
            cx: 79.5,
            cy: 99.5,
            distortion: crate::render::camera::BrownConrady::NONE,
        };
        let rays = intr.pixel_rays();
        let mut frame = Frame::new(w, h);
        let edge = 79.5; // between columns 79 and 80
        for v in 0..h as usize {
            for u in 0..w as usize {
                let c = if (u as f64) < edge { 0.0 } else { 1.0 };
                frame.linear[3 * (v * w as usize + u)..][..3].fill(c);
            }
        }
        let motion = CameraMotion {
            linear_mps: Vector3::zeros(),
            angular_radps: Vector3::new(0.0, 0.5, 0.0),
        };
        let (readout, omega, f) = (0.030, 0.5, 300.0);
        let mut scratch = Vec::new();
        let sharp = frame.linear.clone();
        rolling_shutter(&mut frame, &mut scratch, &rays, 300.0, 300.0, &motion, 0.0);
        assert_eq!(frame.linear, sharp, "no readout time: unchanged");
        rolling_shutter(
            &mut frame,
            &mut scratch,
            &rays,
            300.0,
            300.0,
            &motion,
            readout,
        );
        for v in 0..h as usize {
            let row: Vec<f32> = (0..w as usize)
                .map(|u| frame.linear[3 * (v * w as usize + u)])
                .collect();
            let sum: f64 = row.iter().map(|&x| f64::from(x)).sum();
            let crossing = f64::from(w - 1) - sum + 0.5;
            let dt = (v as f64 - 99.5) / f64::from(h) * readout;
            // The sharp edge's 0.5 crossing lies halfway between columns 79 and 80.
            let want = edge - f * omega * dt;
            assert!(
                (crossing - want).abs() < 0.01,
                "row {v}: {crossing} vs {want}"
            );
        }
    }

    #[test]
    fn flow_matches_finite_differences_of_the_projection() {
        // A point at depth 3 m seen through pixel ray `dir`; move the camera by the twist
        // for a tiny time and project again.
        let m = CameraMotion {
            linear_mps: Vector3::new(0.7, -0.2, 1.1),
            angular_radps: Vector3::new(0.3, -0.5, 0.8),
        };
        let dir = [0.2f32, -0.15, 1.0];
        let z = 3.0;
        let p = Vector3::new(0.2 * z, -0.15 * z, z);
        let dt = 1e-6;
        // Camera pose after dt: optical centre at v·dt, rotated by ω·dt; the point in the
        // new frame is R(ω dt)ᵀ (p − v dt).
        let rot = nalgebra::Rotation3::new(m.angular_radps * dt);
        let q = rot.inverse() * (p - m.linear_mps * dt);
        let (x0, y0) = (p.x / p.z, p.y / p.z);
        let (x1, y1) = (q.x / q.z, q.y / q.z);
        let expect = [(x1 - x0) / dt, (y1 - y0) / dt];
        let got = flow_px(dir, z as f32, &m, 1.0, (1.0, 1.0));
        for k in 0..2 {
            assert!(
                (got[k] - expect[k]).abs() < 1e-4 * (1.0 + expect[k].abs()),
                "flow {got:?} vs finite differences {expect:?}"
            );
        }
    }

    /// The passes as first written (scalar flow per pixel, three-value bilinear, the
    /// sample offsets and counts computed in place): the bits the faster passes must keep.
    mod reference {
        use super::super::{CameraMotion, Frame, RayTable, flow_px};
        fn bilinear(image: &[f32], w: usize, h: usize, px: f64, py: f64) -> [f32; 3] {
            let px = px.clamp(0.0, (w - 1) as f64);
            let py = py.clamp(0.0, (h - 1) as f64);
            let (x0, y0) = (px as usize, py as usize);
            let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
            let (fx, fy) = ((px - x0 as f64) as f32, (py - y0 as f64) as f32);
            let at = |x: usize, y: usize, c: usize| image[3 * (y * w + x) + c];
            std::array::from_fn(|c| {
                let top = at(x0, y0, c) + (at(x1, y0, c) - at(x0, y0, c)) * fx;
                let bottom = at(x0, y1, c) + (at(x1, y1, c) - at(x0, y1, c)) * fx;
                top + (bottom - top) * fy
            })
        }

        fn dir(rays: &RayTable, i: usize) -> [f32; 3] {
            [rays.x[i], rays.y[i], rays.z[i]]
        }

        pub fn motion_blur(
            frame: &mut Frame,
            rays: &RayTable,
            f: (f64, f64),
            m: &CameraMotion,
            t: f64,
        ) {
            let (w, h) = (frame.width as usize, frame.height as usize);
            let sharp = frame.linear.clone();
            for v in 0..h {
                for u in 0..w {
                    let i = v * w + u;
                    let [fu, fv] = flow_px(dir(rays, i), frame.depth_m[i], m, t, f);
                    let len = fu.abs().max(fv.abs());
                    if len < 0.25 {
                        continue;
                    }
                    // As first written but saturating: the first version's `+ 1` wrapped
                    // to 0 samples (a NaN pixel) for a flow past 2⁶⁴ pixels.
                    let n = (len.ceil() as usize).saturating_add(1).min(64);
                    let mut acc = [0.0f32; 3];
                    for k in 0..n {
                        let s = (k as f64 + 0.5) / n as f64 - 0.5;
                        let c = bilinear(&sharp, w, h, u as f64 + s * fu, v as f64 + s * fv);
                        for (a, c) in acc.iter_mut().zip(c) {
                            *a += c;
                        }
                    }
                    let inv = 1.0 / n as f32;
                    for (o, a) in frame.linear[3 * i..3 * i + 3].iter_mut().zip(acc) {
                        *o = a * inv;
                    }
                }
            }
        }

        pub fn rolling_shutter(
            frame: &mut Frame,
            rays: &RayTable,
            f: (f64, f64),
            m: &CameraMotion,
            readout_s: f64,
        ) {
            let (w, h) = (frame.width as usize, frame.height as usize);
            let sharp = frame.linear.clone();
            let centre = (h as f64 - 1.0) / 2.0;
            for v in 0..h {
                let dt = (v as f64 - centre) / h as f64 * readout_s;
                for u in 0..w {
                    let i = v * w + u;
                    let [fu, fv] = flow_px(dir(rays, i), frame.depth_m[i], m, dt, f);
                    if fu.abs().max(fv.abs()) < 1e-3 {
                        continue;
                    }
                    let c = bilinear(&sharp, w, h, u as f64 - fu, v as f64 - fv);
                    frame.linear[3 * i..3 * i + 3].copy_from_slice(&c);
                }
            }
        }
    }

    /// Rays, depths and motions that reach every branch: rays behind the camera and
    /// zero rays, depths of 0, negative, NaN, infinite and tiny, flows from none to far
    /// beyond the sample cap.
    fn awkward_inputs(seed: u64, w: u32, h: u32) -> (RayTable, Vec<f32>, Vec<f32>) {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let intr = crate::render::camera::Intrinsics::from_hfov(
            w,
            h,
            100.0,
            crate::render::camera::BrownConrady::NONE,
        );
        let mut rays = intr.pixel_rays();
        let n = rays.len();
        for i in 0..n {
            match rng.random_range(0..20) {
                0 => rays.z[i] = -rays.z[i],
                1 => (rays.x[i], rays.y[i], rays.z[i]) = (0.0, 0.0, 0.0),
                _ => {}
            }
        }
        let depth = (0..n)
            .map(|_| match rng.random_range(0..30) {
                0 => 0.0,
                1 => -1.0,
                2 => f32::NAN,
                3 => f32::INFINITY,
                4 => 1e-30,
                5 => 0.01,
                _ => rng.random_range(0.3..40.0),
            })
            .collect();
        let linear = (0..3 * n).map(|_| rng.random_range(0.0..1.0)).collect();
        (rays, depth, linear)
    }

    #[test]
    fn flow_blocks_are_the_scalar_flows_bit_for_bit() {
        let (rays, depth, _) = awkward_inputs(1, 97, 41);
        let m = CameraMotion {
            linear_mps: Vector3::new(0.4, -0.3, 1.7),
            angular_radps: Vector3::new(-0.2, 0.6, 0.35),
        };
        let (mut fu, mut fv) = ([0.0; BLOCK], [0.0; BLOCK]);
        // Every block length, at every offset modulo 4 (the SIMD steps and the tail), then
        // the whole table in blocks.
        let lengths = (0..=BLOCK).flat_map(|n| (0..4).map(move |o| (o + 3 * n, n)));
        let whole = (0..rays.len())
            .step_by(BLOCK)
            .map(|i0| (i0, BLOCK.min(rays.len() - i0)));
        for (i0, n) in lengths.chain(whole) {
            flow_block(
                &rays,
                &depth,
                (i0, n),
                &m,
                0.013,
                (310.0, 290.0),
                &mut fu,
                &mut fv,
            );
            for j in 0..n {
                let i = i0 + j;
                let dir = [rays.x[i], rays.y[i], rays.z[i]];
                let want = flow_px(dir, depth[i], &m, 0.013, (310.0, 290.0));
                assert_eq!(
                    [fu[j].to_bits(), fv[j].to_bits()],
                    want.map(f64::to_bits),
                    "pixel {i}: {:?} against {want:?}",
                    [fu[j], fv[j]]
                );
            }
        }
    }

    #[test]
    fn the_passes_give_the_scalar_references_bits() {
        // Odd sizes (rows that end in a partial block and a partial SIMD step), motions
        // from gentle to a smear longer than the sample cap.
        let (w, h) = (151u32, 37u32);
        let (rays, depth, linear) = awkward_inputs(2, w, h);
        let f = (120.0, 125.0);
        let mut scratch = Vec::new();
        for (k, scale) in [0.05, 1.0, 40.0].into_iter().enumerate() {
            let m = CameraMotion {
                linear_mps: Vector3::new(0.3, 0.1, 1.2) * scale,
                angular_radps: Vector3::new(0.1, -0.4, 0.2) * scale,
            };
            let mut frame = Frame::new(w, h);
            frame.linear.clone_from(&linear);
            frame.depth_m.clone_from(&depth);
            let mut want = frame.clone();
            rolling_shutter(&mut frame, &mut scratch, &rays, f.0, f.1, &m, 0.02);
            reference::rolling_shutter(&mut want, &rays, f, &m, 0.02);
            let bits = |f: &Frame| f.linear.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&frame), bits(&want), "rolling shutter, motion {k}");
            motion_blur(&mut frame, &mut scratch, &rays, f.0, f.1, &m, 0.01);
            reference::motion_blur(&mut want, &rays, f, &m, 0.01);
            assert_eq!(bits(&frame), bits(&want), "motion blur, motion {k}");
            assert_ne!(frame.linear, linear, "motion {k} changed nothing");
        }
    }
}
