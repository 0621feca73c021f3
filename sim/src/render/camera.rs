//! Pinhole cameras with Brown-Conrady distortion, camera profiles, the D435 stereo depth
//! error model, image noise and free-running frame clocks.
//!
//! # Conventions
//!
//! - **Camera optical frame**: x right, y down, z forward (REP-103 `_optical` frames).
//! - **Pixel coordinates** follow OpenCV and ROS `sensor_msgs/CameraInfo`: the centre of
//!   pixel `(u, v)` (column `u`, row `v`, both from 0 at the top-left) lies at the
//!   continuous coordinates `(u, v)`; the image covers `[-0.5, width - 0.5] ×
//!   [-0.5, height - 0.5]`. A centred principal point is therefore at
//!   `((width - 1) / 2, (height - 1) / 2)`.
//! - **Distortion** is OpenCV's `plumb_bob` (Brown-Conrady) model with the ROS
//!   `CameraInfo.D` order `[k1, k2, p1, p2, k3]`, applied to normalised coordinates
//!   `(x, y) = (X/Z, Y/Z)`: see [`BrownConrady`].
//! - Time is [`Nanos`]; lengths in metres, angles in radians unless suffixed (`hfov_deg`).
//!
//! # What is here
//!
//! - [`Intrinsics`]: projection, distortion and its Newton inverse, ROS `K`/`P`/`D`, and
//!   [`Intrinsics::pixel_rays`], the per-pixel ray table the renderer reuses every frame.
//! - [`CameraSpec`] / [`CameraProfile`]: the D435, ZED 2i and ZED X Mini with datasheet
//!   numbers.
//! - [`StereoDepthNoise`]: the D435 depth error model (disparity noise, range limits,
//!   occlusion shadows, edge holes, millimetre quantisation).
//! - [`ImageNoise`] and [`linear_to_srgb_u8`]: sensor noise and 8-bit sRGB encoding.
//! - [`FrameClock`]: free-running, jittered, drifting exposure stamps.
//!
//! Every random draw comes from a `&mut impl Rng` owned by the caller (a seeded
//! [`crate::rng::stream`]); the number of draws per frame never depends on noise
//! parameters, so changing one σ does not shift the other noise sources.

use std::sync::{Arc, LazyLock};

use crate::rng::IndexedRng;
use nalgebra::{Matrix2, Vector2, Vector3};
use rand::Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use vinebench_msgs::{CameraInfoMsg, FrameId, Nanos};

use super::depth_light::SunlightStereo;
use super::trace::PACKET_SIZE;

// ---------------------------------------------------------------------------------------
// Distortion
// ---------------------------------------------------------------------------------------

/// Brown-Conrady (OpenCV `plumb_bob`) lens distortion of normalised image coordinates.
///
/// With `r² = x² + y²` and the radial factor `R = 1 + k1·r² + k2·r⁴ + k3·r⁶`, an ideal
/// (pinhole) normalised point `(x, y)` is imaged at
///
/// ```text
/// x_d = x·R + 2·p1·x·y + p2·(r² + 2·x²)
/// y_d = y·R + p1·(r² + 2·y²) + 2·p2·x·y
/// ```
///
/// and then at pixel `(fx·x_d + cx, fy·y_d + cy)`. Fields are in the ROS `CameraInfo.D`
/// order `[k1, k2, p1, p2, k3]` ([`BrownConrady::d`]).
///
/// The model is only physical where the radial map `r ↦ r·R(r)` is increasing; beyond its
/// first turning point (strong barrel distortion far outside the image) points would
/// fold back into the image. [`BrownConrady::radially_monotonic_to`] tells where it
/// holds, and [`Intrinsics::project`] refuses points beyond it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct BrownConrady {
    /// Radial coefficient of `r²`.
    pub k1: f64,
    /// Radial coefficient of `r⁴`.
    pub k2: f64,
    /// Tangential (decentring) coefficient `p1`.
    pub p1: f64,
    /// Tangential (decentring) coefficient `p2`.
    pub p2: f64,
    /// Radial coefficient of `r⁶`.
    pub k3: f64,
}

impl BrownConrady {
    /// No distortion (a rectified or ideal image).
    pub const NONE: BrownConrady = BrownConrady {
        k1: 0.0,
        k2: 0.0,
        p1: 0.0,
        p2: 0.0,
        k3: 0.0,
    };

    /// From a ROS `CameraInfo.D` vector `[k1, k2, p1, p2, k3]`.
    pub const fn from_d(d: [f64; 5]) -> BrownConrady {
        BrownConrady {
            k1: d[0],
            k2: d[1],
            p1: d[2],
            p2: d[3],
            k3: d[4],
        }
    }

    /// The ROS `CameraInfo.D` vector `[k1, k2, p1, p2, k3]`.
    pub const fn d(&self) -> [f64; 5] {
        [self.k1, self.k2, self.p1, self.p2, self.k3]
    }

    /// Whether all coefficients are zero.
    pub fn is_none(&self) -> bool {
        self.d().iter().all(|&c| c == 0.0)
    }

    /// The radial factor `R(r²) = 1 + k1·r² + k2·r⁴ + k3·r⁶`.
    pub fn radial(&self, r2: f64) -> f64 {
        1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
    }

    /// Distorts an ideal normalised point: `(x, y) ↦ (x_d, y_d)`.
    pub fn apply(&self, p: Vector2<f64>) -> Vector2<f64> {
        let (x, y) = (p.x, p.y);
        let r2 = x * x + y * y;
        let radial = self.radial(r2);
        Vector2::new(
            x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// Jacobian `∂(x_d, y_d)/∂(x, y)` of [`BrownConrady::apply`] at `p`.
    pub fn jacobian(&self, p: Vector2<f64>) -> Matrix2<f64> {
        let (x, y) = (p.x, p.y);
        let r2 = x * x + y * y;
        let radial = self.radial(r2);
        // dR/d(r²)
        let dr = self.k1 + r2 * (2.0 * self.k2 + 3.0 * self.k3 * r2);
        let (p1, p2) = (self.p1, self.p2);
        Matrix2::new(
            radial + 2.0 * x * x * dr + 2.0 * p1 * y + 6.0 * p2 * x,
            2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y,
            2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y,
            radial + 2.0 * y * y * dr + 6.0 * p1 * y + 2.0 * p2 * x,
        )
    }

    /// Whether the radial map `r ↦ r·R(r)` is strictly increasing on `[0, √r2]`, i.e.
    /// whether ideal points up to normalised radius² `r2` image without folding.
    ///
    /// `d(r·R)/dr = q(s) = 1 + 3·k1·s + 5·k2·s² + 7·k3·s³` with `s = r²`; the test checks
    /// `q > 0` at `s = r2` and at the interior critical points of `q` (closed form, no
    /// sampling). Tangential terms are ignored (they are tiny for real lenses).
    pub fn radially_monotonic_to(&self, r2: f64) -> bool {
        let q = |s: f64| 1.0 + s * (3.0 * self.k1 + s * (5.0 * self.k2 + s * 7.0 * self.k3));
        if r2.is_nan() || r2 < 0.0 || q(r2) <= 0.0 {
            return false;
        }
        // q'(s) = 3·k1 + 10·k2·s + 21·k3·s² = 0.
        let (a, b, c) = (21.0 * self.k3, 10.0 * self.k2, 3.0 * self.k1);
        let mut critical = [f64::NAN; 2];
        if a != 0.0 {
            let disc = b * b - 4.0 * a * c;
            if disc >= 0.0 {
                // Numerically stable roots.
                let t = -0.5 * (b + b.signum() * disc.sqrt());
                critical[0] = t / a;
                if t != 0.0 {
                    critical[1] = c / t;
                }
            }
        } else if b != 0.0 {
            critical[0] = -c / b;
        }
        critical
            .iter()
            .filter(|s| **s > 0.0 && **s < r2)
            .all(|&s| q(s) > 0.0)
    }

    /// Inverts the distortion: the ideal normalised point whose image is `pd`.
    ///
    /// Damped Newton iteration with the analytic Jacobian, started at `pd`, iterated to
    /// machine precision (residual below `1e-15`); the result is accepted when the
    /// residual is below `1e-12` and the point lies on the monotonic branch
    /// ([`BrownConrady::radially_monotonic_to`]). Returns `None` otherwise (a distorted
    /// point outside the lens's valid image circle).
    pub fn invert(&self, pd: Vector2<f64>) -> Option<Vector2<f64>> {
        if self.is_none() {
            return Some(pd);
        }
        if !(pd.x.is_finite() && pd.y.is_finite()) {
            return None;
        }
        let mut p = pd;
        let mut res = self.apply(p) - pd;
        let mut res_norm = res.norm();
        let tol = 1e-15 * (1.0 + pd.norm());
        for _ in 0..50 {
            if res_norm <= tol {
                break;
            }
            let j = self.jacobian(p);
            let det = j[(0, 0)] * j[(1, 1)] - j[(0, 1)] * j[(1, 0)];
            if det.abs() < 1e-300 || !det.is_finite() {
                return None;
            }
            let step = Vector2::new(
                (j[(1, 1)] * res.x - j[(0, 1)] * res.y) / det,
                (-j[(1, 0)] * res.x + j[(0, 0)] * res.y) / det,
            );
            // Backtracking: halve the step until the residual decreases.
            let mut t = 1.0;
            loop {
                let cand = p - step * t;
                let cand_res = self.apply(cand) - pd;
                let cand_norm = cand_res.norm();
                if cand_norm < res_norm || t < 1e-6 {
                    p = cand;
                    res = cand_res;
                    res_norm = cand_norm;
                    break;
                }
                t *= 0.5;
            }
            if step.norm() * t <= 1e-17 * (1.0 + p.norm()) {
                break;
            }
        }
        (res_norm <= 1e-12 && self.radially_monotonic_to(p.norm_squared())).then_some(p)
    }
}

// ---------------------------------------------------------------------------------------
// Intrinsics
// ---------------------------------------------------------------------------------------

/// The identity rectification rotation `R` of `sensor_msgs/CameraInfo`, row-major (our
/// images are rendered already rectified).
pub const CAMERA_INFO_R_IDENTITY: [f64; 9] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];

/// The ROS `distortion_model` name of [`BrownConrady`].
pub const DISTORTION_MODEL: &str = "plumb_bob";

/// Pinhole intrinsics with Brown-Conrady distortion.
///
/// Pixel convention: the centre of pixel `(u, v)` is at coordinates `(u, v)` (OpenCV,
/// ROS); see the [module docs](self).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
    /// Horizontal focal length, px.
    pub fx: f64,
    /// Vertical focal length, px.
    pub fy: f64,
    /// Principal point column, px.
    pub cx: f64,
    /// Principal point row, px.
    pub cy: f64,
    /// Lens distortion (zero for rectified images).
    pub distortion: BrownConrady,
}

impl Intrinsics {
    /// A camera of horizontal field of view `hfov_deg` with square pixels (`fy = fx`) and
    /// the principal point at the image centre `((width - 1)/2, (height - 1)/2)`.
    ///
    /// `hfov_deg` is the true angle between the rays through the left and right image
    /// edges (`u = -0.5` and `u = width - 0.5`) on the centre row, distortion included:
    /// with `t = tan(hfov/2)`, `fx = (width/2) / (t·R(t²))` where `R` is the radial factor
    /// of `distortion` (tangential terms are ignored for this; they are tiny). Without
    /// distortion this is the pinhole `fx = (width/2) / tan(hfov/2)`.
    pub fn from_hfov(width: u32, height: u32, hfov_deg: f64, distortion: BrownConrady) -> Self {
        let t = (0.5 * hfov_deg).to_radians().tan();
        let xd_edge = t * distortion.radial(t * t);
        let fx = 0.5 * f64::from(width) / xd_edge;
        Intrinsics {
            width,
            height,
            fx,
            fy: fx,
            cx: 0.5 * (f64::from(width) - 1.0),
            cy: 0.5 * (f64::from(height) - 1.0),
            distortion,
        }
    }

    /// The same camera at another resolution: focal lengths scaled by
    /// `width / self.width` (horizontal field of view kept), principal point moved by the
    /// same scale about the image centre. A different aspect ratio crops or extends the
    /// image vertically, as sensor modes do. Distortion (in normalised coordinates) is
    /// unchanged.
    pub fn resized(&self, width: u32, height: u32) -> Intrinsics {
        let s = f64::from(width) / f64::from(self.width);
        let (ocx, ocy) = (
            0.5 * (f64::from(self.width) - 1.0),
            0.5 * (f64::from(self.height) - 1.0),
        );
        Intrinsics {
            width,
            height,
            fx: self.fx * s,
            fy: self.fy * s,
            cx: 0.5 * (f64::from(width) - 1.0) + (self.cx - ocx) * s,
            cy: 0.5 * (f64::from(height) - 1.0) + (self.cy - ocy) * s,
            distortion: self.distortion,
        }
    }

    /// Number of pixels.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Pixel coordinates of an ideal (undistorted) normalised point `(x_n, y_n) =
    /// (X/Z, Y/Z)`: distortion, then `K`. No visibility check.
    pub fn distort(&self, x_n: f64, y_n: f64) -> Vector2<f64> {
        let d = self.distortion.apply(Vector2::new(x_n, y_n));
        Vector2::new(self.fx * d.x + self.cx, self.fy * d.y + self.cy)
    }

    /// The ideal (undistorted) normalised point `(x, y)` seen at pixel coordinates
    /// `(u, v)`: the inverse of [`Intrinsics::distort`] (`K⁻¹`, then
    /// [`BrownConrady::invert`]). `None` outside the lens's valid image circle.
    pub fn undistort(&self, u: f64, v: f64) -> Option<Vector2<f64>> {
        let pd = Vector2::new((u - self.cx) / self.fx, (v - self.cy) / self.fy);
        self.distortion.invert(pd)
    }

    /// Pixel coordinates of a point in the camera optical frame, distortion included.
    ///
    /// `None` when the point is not in front of the camera (`z ≤ 0` or not finite) or
    /// lies beyond the distortion model's monotonic range (where it would fold back into
    /// the image). The result may lie outside the image; see [`Intrinsics::contains`].
    pub fn project(&self, p_cam: Vector3<f64>) -> Option<Vector2<f64>> {
        if p_cam.z.is_nan() || p_cam.z <= 0.0 || !p_cam.x.is_finite() || !p_cam.y.is_finite() {
            return None;
        }
        let (x, y) = (p_cam.x / p_cam.z, p_cam.y / p_cam.z);
        if !self.distortion.is_none() && !self.distortion.radially_monotonic_to(x * x + y * y) {
            return None;
        }
        Some(self.distort(x, y))
    }

    /// Unit ray direction (camera frame) through pixel coordinates `(u, v)`.
    pub fn ray(&self, u: f64, v: f64) -> Option<Vector3<f64>> {
        let n = self.undistort(u, v)?;
        Some(Vector3::new(n.x, n.y, 1.0).normalize())
    }

    /// Whether pixel coordinates lie on the image (`[-0.5, width - 0.5) × [-0.5,
    /// height - 0.5)`).
    pub fn contains(&self, px: Vector2<f64>) -> bool {
        px.x >= -0.5
            && px.y >= -0.5
            && px.x < f64::from(self.width) - 0.5
            && px.y < f64::from(self.height) - 0.5
    }

    /// Horizontal field of view, degrees: the angle between the rays through the left
    /// and right image edges on the principal row. `None` if an edge lies outside the
    /// lens's valid image circle.
    pub fn hfov_deg(&self) -> Option<f64> {
        let l = self.undistort(-0.5, self.cy)?;
        let r = self.undistort(f64::from(self.width) - 0.5, self.cy)?;
        Some((r.x.atan() - l.x.atan()).to_degrees())
    }

    /// Vertical field of view, degrees, on the principal column (as
    /// [`Intrinsics::hfov_deg`]).
    pub fn vfov_deg(&self) -> Option<f64> {
        let t = self.undistort(self.cx, -0.5)?;
        let b = self.undistort(self.cx, f64::from(self.height) - 0.5)?;
        Some((b.y.atan() - t.y.atan()).to_degrees())
    }

    /// Unit ray directions through every pixel centre, undistorted, as `f32`, computed
    /// once per camera; see [`RayTable`].
    pub fn pixel_rays(&self) -> RayTable {
        let n = self.pixel_count();
        let mut table = RayTable {
            width: self.width,
            height: self.height,
            x: Vec::with_capacity(n),
            y: Vec::with_capacity(n),
            z: Vec::with_capacity(n),
            invalid: 0,
        };
        for v in 0..self.height {
            for u in 0..self.width {
                match self.ray(f64::from(u), f64::from(v)) {
                    Some(d) => {
                        table.x.push(d.x as f32);
                        table.y.push(d.y as f32);
                        table.z.push(d.z as f32);
                    }
                    None => {
                        table.x.push(0.0);
                        table.y.push(0.0);
                        table.z.push(0.0);
                        table.invalid += 1;
                    }
                }
            }
        }
        table
    }

    /// The intrinsic matrix `K` of `sensor_msgs/CameraInfo`, row-major:
    /// `[fx, 0, cx, 0, fy, cy, 0, 0, 1]`.
    pub fn camera_info_k(&self) -> [f64; 9] {
        [self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0]
    }

    /// The projection matrix `P` of `sensor_msgs/CameraInfo`, row-major 3×4:
    /// `[fx, 0, cx, Tx, 0, fy, cy, 0, 0, 0, 1, 0]` with `Tx = -fx·right_baseline_m`.
    ///
    /// Pass `right_baseline_m = 0` for a monocular camera or the left camera of a stereo
    /// pair, and the baseline (m, positive) for the right camera of a rectified pair, as
    /// ROS defines it. For a distorted camera `P` describes the ideal (undistorted) image
    /// with the same `K`.
    pub fn camera_info_p(&self, right_baseline_m: f64) -> [f64; 12] {
        [
            self.fx,
            0.0,
            self.cx,
            -self.fx * right_baseline_m,
            0.0,
            self.fy,
            self.cy,
            0.0,
            0.0,
            0.0,
            1.0,
            0.0,
        ]
    }

    /// The distortion vector `D` of `sensor_msgs/CameraInfo` (`plumb_bob`).
    pub fn camera_info_d(&self) -> [f64; 5] {
        self.distortion.d()
    }

    /// A full `CameraInfo` message for an image of this camera.
    pub fn camera_info_msg(
        &self,
        stamp: Nanos,
        topic: Arc<str>,
        frame_id: FrameId,
        right_baseline_m: f64,
    ) -> CameraInfoMsg {
        CameraInfoMsg {
            stamp,
            topic,
            frame_id,
            width: self.width,
            height: self.height,
            d: self.camera_info_d(),
            k: self.camera_info_k(),
            r: CAMERA_INFO_R_IDENTITY,
            p: self.camera_info_p(right_baseline_m),
        }
    }
}

/// The optical frame (x right, y down, z forward) of a level camera at `eye` looking along
/// `forward` (world frame, z up; `forward` must not be vertical): `world_from_optical`.
pub fn look_at(eye: Vector3<f64>, forward: Vector3<f64>) -> nalgebra::Isometry3<f64> {
    let z = forward.normalize();
    let x = z.cross(&Vector3::z()).normalize();
    let y = z.cross(&x);
    let r = nalgebra::Rotation3::from_basis_unchecked(&[x, y, z]);
    nalgebra::Isometry3::from_parts(
        eye.into(),
        nalgebra::UnitQuaternion::from_rotation_matrix(&r),
    )
}

/// Unit ray directions through every pixel centre of a camera, camera optical frame,
/// `f32`, **structure of arrays**: `x[i]`, `y[i]`, `z[i]` with `i = v·width + u` (rows top
/// to bottom), matching [`super::RayPacket`]'s lanes.
///
/// Directions are unit length, so a hit parameter `t` is the range along the ray and the
/// depth (optical-axis distance, what depth cameras report) is `t·z[i]`. A pixel whose
/// ray could not be computed (outside the lens's valid image circle; never for a
/// realistic calibration) has the zero direction; [`RayTable::invalid`] counts them and
/// renderers must skip them.
#[derive(Clone, Debug, PartialEq)]
pub struct RayTable {
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
    /// Direction x components.
    pub x: Vec<f32>,
    /// Direction y components.
    pub y: Vec<f32>,
    /// Direction z components (depth = range·z).
    pub z: Vec<f32>,
    /// Number of pixels with the zero direction.
    pub invalid: usize,
}

impl RayTable {
    /// Number of pixels.
    pub fn len(&self) -> usize {
        self.z.len()
    }

    /// Whether the table has no pixels.
    pub fn is_empty(&self) -> bool {
        self.z.is_empty()
    }

    /// Index of pixel `(u, v)`.
    pub fn index(&self, u: u32, v: u32) -> usize {
        v as usize * self.width as usize + u as usize
    }

    /// Direction of pixel `(u, v)`.
    pub fn dir(&self, u: u32, v: u32) -> [f32; 3] {
        let i = self.index(u, v);
        [self.x[i], self.y[i], self.z[i]]
    }

    /// Copies the directions of the tile `[x0, x0 + tile_w) × [y0, y0 + tile_h)`, clipped
    /// to the image, into packet lanes in row-major tile order (lane `(v - y0)·w + (u -
    /// x0)` with `w` the clipped tile width); returns the number of lanes written. At
    /// most [`PACKET_SIZE`] lanes are written (an 8×8 tile fills a packet exactly).
    pub fn fill_tile(
        &self,
        x0: u32,
        y0: u32,
        tile_w: u32,
        tile_h: u32,
        dir: &mut [[f32; PACKET_SIZE]; 3],
    ) -> usize {
        let x1 = x0.saturating_add(tile_w).min(self.width);
        let y1 = y0.saturating_add(tile_h).min(self.height);
        let mut lane = 0;
        for v in y0..y1 {
            for u in x0..x1 {
                if lane == PACKET_SIZE {
                    return lane;
                }
                let i = self.index(u, v);
                dir[0][lane] = self.x[i];
                dir[1][lane] = self.y[i];
                dir[2][lane] = self.z[i];
                lane += 1;
            }
        }
        lane
    }
}

// ---------------------------------------------------------------------------------------
// Camera profiles
// ---------------------------------------------------------------------------------------

/// Stereo depth parameters of a camera.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct StereoSpec {
    /// Distance between the two imagers' optical centres, m.
    pub baseline_m: f64,
    /// Standard deviation of the stereo matcher's disparity error, px ("subpixel" in
    /// Intel's depth-RMS formula).
    pub subpixel: f64,
    /// Closest measurable depth at this resolution, m.
    pub min_range_m: f64,
    /// Farthest reported depth, m (a configurable threshold on real devices).
    pub max_range_m: f64,
}

/// A camera's image geometry, rate and (for depth cameras) stereo parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraSpec {
    /// Which device this models.
    pub profile: CameraProfile,
    /// Intrinsics of the published image.
    pub intrinsics: Intrinsics,
    /// Frame rate, Hz.
    pub rate_hz: f64,
    /// Stereo depth parameters (`None` for a camera without depth).
    pub stereo: Option<StereoSpec>,
}

/// Resolution modes of the D435 depth stream (Intel RealSense D400 Series Datasheet,
/// "Depth stream" resolutions of the D435). The depth imagers are 1280×800; the 16:9
/// modes are the 1280×720 crop scaled down (the same 87° × 58° field), the 4:3 mode is
/// the full sensor scaled by 0.6 and cropped to 640 columns (a narrower, taller field).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum D435DepthMode {
    /// 1280×720, the native 16:9 field (Min-Z ≈ 0.28 m).
    W1280H720,
    /// 848×480 (16:9), the native field scaled by 2/3 (cropped from 853 to 848 columns);
    /// Intel's recommended depth mode.
    W848H480,
    /// 640×480 (4:3): the 1280×800 sensor scaled by 0.6 and cropped to 640 columns, a
    /// narrower horizontal field of view (≈ 77°) and a taller vertical one (≈ 61°).
    W640H480,
    /// 640×360 (16:9), the native field scaled by 1/2.
    W640H360,
    /// 480×270 (16:9), the native field scaled by 3/8.
    W480H270,
    /// 424×240 (16:9), the native field scaled by 1/3 (cropped from 427 to 424 columns).
    W424H240,
}

impl D435DepthMode {
    /// Every mode, largest first.
    pub const ALL: [D435DepthMode; 6] = [
        D435DepthMode::W1280H720,
        D435DepthMode::W848H480,
        D435DepthMode::W640H480,
        D435DepthMode::W640H360,
        D435DepthMode::W480H270,
        D435DepthMode::W424H240,
    ];

    /// Width, height and the focal length's scale against the 1280-column mode.
    pub fn geometry(self) -> (u32, u32, f64) {
        match self {
            D435DepthMode::W1280H720 => (1280, 720, 1.0),
            D435DepthMode::W848H480 => (848, 480, 2.0 / 3.0),
            D435DepthMode::W640H480 => (640, 480, 0.6),
            D435DepthMode::W640H360 => (640, 360, 0.5),
            D435DepthMode::W480H270 => (480, 270, 0.375),
            D435DepthMode::W424H240 => (424, 240, 1.0 / 3.0),
        }
    }

    /// The mode of a `width × height` image, if the D435 has one.
    pub fn of_size(width: u32, height: u32) -> Option<D435DepthMode> {
        D435DepthMode::ALL.into_iter().find(|m| {
            let (w, h, _) = m.geometry();
            (w, h) == (width, height)
        })
    }
}

/// Colour-stream modes of the D435 (OV2740, 1920×1080, HFOV 69.4°): the 16:9 modes scale
/// the full field (focal length `f_1920·width/1920`), the 4:3 modes are the 1280×720
/// mode cropped to 960×720 and scaled (`f = f_1920·(2/3)·width/960`). Width, height and
/// focal length in px.
pub fn d435_color_modes() -> [(u32, u32, f64); 9] {
    let f1920 = 960.0 / 34.7_f64.to_radians().tan();
    let wide = |w: u32, h: u32| (w, h, f1920 * f64::from(w) / 1920.0);
    let four_three = |w: u32, h: u32| (w, h, f1920 * (2.0 / 3.0) * f64::from(w) / 960.0);
    [
        wide(1920, 1080),
        wide(1280, 720),
        wide(960, 540),
        wide(848, 480),
        four_three(640, 480),
        wide(640, 360),
        wide(424, 240),
        four_three(320, 240),
        wide(320, 180),
    ]
}

pub use crate::params::CameraProfile;

/// The datasheet geometry of each named camera device.
impl CameraProfile {
    /// Rolling-shutter readout time of a whole frame, ms (0: a global shutter). The D435's
    /// depth imagers (whose left image the `d435_depth` profile's colour companion is) and
    /// the ZED X Mini are global shutter; the D435 colour imager (OV2740) and the ZED 2i
    /// are rolling shutter. Their readout times are not published: 16 ms (D435 colour)
    /// and 18 ms (ZED 2i) are assumptions of the order such sensors read a frame in.
    pub fn readout_ms(self) -> f64 {
        match self {
            CameraProfile::D435Depth | CameraProfile::ZedXMini => 0.0,
            CameraProfile::D435Color => 16.0,
            CameraProfile::Zed2i => 18.0,
        }
    }

    /// The profile's default mode; see the [`CameraSpec`] constructors for the numbers and
    /// their sources.
    pub fn spec(self) -> CameraSpec {
        match self {
            CameraProfile::D435Depth => CameraSpec::d435_depth(D435DepthMode::W848H480, 15.0),
            CameraProfile::D435Color => CameraSpec::d435_color(15.0),
            CameraProfile::Zed2i => CameraSpec::zed2i(),
            CameraProfile::ZedXMini => CameraSpec::zed_x_mini(),
        }
    }
}

/// D435 depth focal length at the native 1280×720 mode, px, from the datasheet depth
/// field of view 87° × 58° (±3°) (Intel RealSense D400 Series Datasheet, "Depth Field of
/// View (FOV)", for the 16:9 modes): `640 / tan(43.5°)` ≈ 674 px. (Intel's "Tuning depth
/// cameras" white paper quotes f ≈ 645 px, i.e. ≈ 90°; individual units vary within the
/// ±3°.)
fn d435_depth_f_1280() -> f64 {
    640.0 / 43.5_f64.to_radians().tan()
}

/// Illustrative mild barrel distortion of a ≈110° wide lens modelled with plumb-bob
/// coefficients: −6 % radial at the horizontal edge. (Real wide ZED lenses are calibrated
/// with richer models; this keeps the distortion code paths exercised.)
const WIDE_LENS_DISTORTION: BrownConrady = BrownConrady {
    k1: -0.05,
    k2: 0.01,
    p1: 0.0,
    p2: 0.0,
    k3: 0.0,
};

impl CameraSpec {
    /// Intel RealSense D435 depth stream.
    ///
    /// Sources (Intel RealSense D400 Series Datasheet, rev. 2017-2023):
    /// - depth FOV 87° × 58° (±3°) at the 16:9 modes → `f_1280 ≈ 674` px (see
    ///   [`D435DepthMode`] for the other modes: `f = (2/3)·f_1280 ≈ 450` px at 848×480,
    ///   HFOV ≈ 86.6°; `f = 0.6·f_1280 ≈ 405` px at 640×480, HFOV ≈ 77°);
    /// - baseline 50 mm;
    /// - frame rates 6/15/30/60/90 fps at these resolutions (`rate_hz`, 15 or 30 typical);
    /// - Min-Z ≈ 0.28 m at the maximum resolution 1280×720; the minimum depth is set by
    ///   the fixed disparity search range in pixels, so it scales with the focal length:
    ///   ≈ 0.19 m at 848×480, ≈ 0.17 m at 640×480;
    /// - max range "up to 10 m" (depends on scene and light; here a configurable cut-off);
    /// - subpixel 0.08 px: the typical value in Intel's depth RMS error formula
    ///   `RMS = z²·subpixel/(f·b)` (datasheet "Depth RMS error", white paper "Tuning depth
    ///   cameras for best performance").
    ///
    /// The depth output is rectified: zero distortion. **Rig choice**: vinebench renders
    /// the D435 with this depth geometry for both the depth image and its grey/colour-like
    /// companion image, so they are pixel-aligned (as the left IR image `infra1` is on the
    /// real device, or as RealSense's align-to-depth output); the narrower colour imager
    /// is available as [`CameraSpec::d435_color`].
    pub fn d435_depth(mode: D435DepthMode, rate_hz: f64) -> CameraSpec {
        let (width, height, scale) = mode.geometry();
        let f = d435_depth_f_1280() * scale;
        let intrinsics = Intrinsics {
            width,
            height,
            fx: f,
            fy: f,
            cx: 0.5 * (f64::from(width) - 1.0),
            cy: 0.5 * (f64::from(height) - 1.0),
            distortion: BrownConrady::NONE,
        };
        CameraSpec {
            profile: CameraProfile::D435Depth,
            intrinsics,
            rate_hz,
            stereo: Some(StereoSpec {
                baseline_m: 0.050,
                subpixel: 0.08,
                min_range_m: 0.28 * scale,
                max_range_m: 10.0,
            }),
        }
    }

    /// Intel RealSense D435 colour stream at 640×480.
    ///
    /// Sources: OmniVision OV2740, 1920×1080, HFOV 69.4° × VFOV 42.5°, distortion ≤ 1.5 %
    /// (D435 datasheet, colour sensor table) → `f_1920 = 960/tan(34.7°)` ≈ 1386 px. The
    /// 640×480 mode is the 1280×720 mode (2/3 scale) cropped to 4:3 and scaled by 2/3
    /// again: `f = (4/9)·f_1920` ≈ 616 px (factory calibrations report ≈ 615 px), HFOV
    /// ≈ 55°. Distortion: `k1 = -0.024`, i.e. −1.5 % at the full sensor's corner, the
    /// datasheet bound. No depth.
    pub fn d435_color(rate_hz: f64) -> CameraSpec {
        CameraSpec::d435_color_mode(640, 480, rate_hz).expect("640×480 is a D435 colour mode")
    }

    /// The D435 colour stream in one of its modes ([`d435_color_modes`]); `None` for a
    /// size the camera does not have.
    pub fn d435_color_mode(width: u32, height: u32, rate_hz: f64) -> Option<CameraSpec> {
        let (_, _, f) = d435_color_modes()
            .into_iter()
            .find(|m| (m.0, m.1) == (width, height))?;
        Some(CameraSpec {
            profile: CameraProfile::D435Color,
            intrinsics: Intrinsics {
                width,
                height,
                fx: f,
                fy: f,
                cx: 0.5 * (f64::from(width) - 1.0),
                cy: 0.5 * (f64::from(height) - 1.0),
                distortion: BrownConrady {
                    k1: -0.024,
                    ..BrownConrady::NONE
                },
            },
            rate_hz,
            stereo: None,
        })
    }

    /// The camera of `profile` at `width × height`: a D435 takes the datasheet mode of
    /// that size (its own intrinsics, field of view and minimum depth); other profiles
    /// are resized ([`CameraSpec::with_resolution`]). Errors (for a D435 size it does not
    /// have) list the modes.
    pub fn of_profile(
        profile: CameraProfile,
        width: u32,
        height: u32,
    ) -> Result<CameraSpec, String> {
        let list = |modes: Vec<(u32, u32)>| {
            modes
                .iter()
                .map(|(w, h)| format!("{w}×{h}"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        match profile {
            CameraProfile::D435Depth => D435DepthMode::of_size(width, height)
                .map(|m| CameraSpec::d435_depth(m, profile.spec().rate_hz))
                .ok_or_else(|| {
                    format!(
                        "a D435 depth mode: {}",
                        list(
                            D435DepthMode::ALL
                                .iter()
                                .map(|m| (m.geometry().0, m.geometry().1))
                                .collect()
                        )
                    )
                }),
            CameraProfile::D435Color => {
                CameraSpec::d435_color_mode(width, height, profile.spec().rate_hz).ok_or_else(
                    || {
                        format!(
                            "a D435 colour mode: {}",
                            list(d435_color_modes().iter().map(|m| (m.0, m.1)).collect())
                        )
                    },
                )
            }
            _ => Ok(profile.spec().with_resolution(width, height)),
        }
    }

    /// Stereolabs ZED 2i with the 2.1 mm lenses, **rectified** left image (what the ZED
    /// SDK delivers): zero distortion.
    ///
    /// Sources: ZED 2i datasheet: 2.1 mm optics, raw FOV 110° (H) × 70° (V) × 120° (D),
    /// baseline 120 mm, depth range 0.3–20 m (Stereolabs "Depth Settings" docs), video
    /// modes 2208×1242@15, 1920×1080@30, 1280×720@60 and WVGA 672×376@15–100 fps.
    /// Rectification crops the field of view: Stereolabs support quotes ≈ 93° horizontal
    /// for a rectified 2.1 mm ZED 2i image (community.stereolabs.com, "Zed2i fov - exact
    /// values"), which we use → `f ≈ 319` px at 672×376.
    ///
    /// Resolution: WVGA 672×376 at 15 fps (the ZED has no 752×480 mode; use
    /// [`CameraSpec::with_resolution`] for another size). The subpixel σ 0.1 px is an
    /// assumption that reproduces the "< 1 % up to 3 m" depth accuracy Stereolabs quotes,
    /// at this resolution.
    pub fn zed2i() -> CameraSpec {
        CameraSpec {
            profile: CameraProfile::Zed2i,
            intrinsics: Intrinsics::from_hfov(672, 376, 93.0, BrownConrady::NONE),
            rate_hz: 15.0,
            stereo: Some(StereoSpec {
                baseline_m: 0.120,
                subpixel: 0.1,
                min_range_m: 0.3,
                max_range_m: 20.0,
            }),
        }
    }

    /// Stereolabs ZED 2i raw (unrectified) left image, 2.1 mm lens: the datasheet's full
    /// 110° HFOV at 672×376 with illustrative mild barrel distortion (`k1 = -0.05`,
    /// `k2 = 0.01`) → `f ≈ 250` px (ZED 2 factory files give ≈ 264 px at VGA).
    pub fn zed2i_raw() -> CameraSpec {
        CameraSpec {
            intrinsics: Intrinsics::from_hfov(672, 376, 110.0, WIDE_LENS_DISTORTION),
            ..CameraSpec::zed2i()
        }
    }

    /// Stereolabs ZED X Mini, 2.2 mm lenses, raw left image, used as the tag camera.
    ///
    /// Sources (Stereolabs ZED X Mini datasheet/product page): 2.2 mm optics, FOV 110° (H) ×
    /// 80° (V) × 120° (D) on the 1920×1200 global-shutter sensor (3 µm pixels: 2.2 mm / 3 µm
    /// ≈ 733 px focal, consistent with the ≈ 715 px that 110° gives with the distortion
    /// below), baseline 50 mm, depth range 0.1–8 m ("Depth Settings" docs). HD1080
    /// (1920×1080, a crop of 1200 rows) with the same horizontal field; illustrative mild
    /// barrel distortion (`k1 = -0.05`, `k2 = 0.01`). Rate 5 fps: the rig processes tags
    /// at 5 Hz (the camera itself runs at 15–60 fps).
    pub fn zed_x_mini() -> CameraSpec {
        CameraSpec {
            profile: CameraProfile::ZedXMini,
            intrinsics: Intrinsics::from_hfov(1920, 1080, 110.0, WIDE_LENS_DISTORTION),
            rate_hz: 5.0,
            stereo: Some(StereoSpec {
                baseline_m: 0.050,
                subpixel: 0.1,
                min_range_m: 0.1,
                max_range_m: 8.0,
            }),
        }
    }

    /// The same camera at another resolution ([`Intrinsics::resized`]: horizontal field
    /// kept); the stereo minimum range scales with the focal length (fixed disparity
    /// search range in pixels).
    pub fn with_resolution(&self, width: u32, height: u32) -> CameraSpec {
        let intrinsics = self.intrinsics.resized(width, height);
        let s = intrinsics.fx / self.intrinsics.fx;
        CameraSpec {
            intrinsics,
            stereo: self.stereo.map(|st| StereoSpec {
                min_range_m: st.min_range_m * s,
                ..st
            }),
            ..*self
        }
    }

    /// The frame period.
    pub fn period(&self) -> Nanos {
        Nanos::period_of_hz(self.rate_hz)
    }
}

// ---------------------------------------------------------------------------------------
// Stereo depth error model
// ---------------------------------------------------------------------------------------

/// RMS depth error of a stereo camera at depth `z` (m): `z²·subpixel / (f_px·baseline)`
/// (Intel's D400 formula; first-order propagation of a disparity error of σ = `subpixel`
/// px through `z = f·b/d`).
pub fn depth_rms_m(z: f64, f_px: f64, baseline_m: f64, subpixel: f64) -> f64 {
    z * z * subpixel / (f_px * baseline_m)
}

/// Scratch buffers of [`StereoDepthNoise::apply`]; keep one per camera so frames do not
/// allocate (buffers grow on the first frame only).
#[derive(Clone, Debug, Default)]
pub struct DepthScratch {
    noise: Vec<f32>,
    tmp: Vec<f32>,
    suffix_min: Vec<f64>,
    /// Per pixel: the true depth if valid (else NaN) and its edge threshold `thr·z`.
    edge_keys: Vec<[f32; 2]>,
}

impl DepthScratch {
    /// Empty scratch; sized on first use.
    pub fn new() -> DepthScratch {
        DepthScratch::default()
    }
}

/// The D435-like stereo depth error model: turns a true depth image into the `u16`
/// millimetre image the camera would publish.
///
/// Per pixel, with `d = f·b/z` the true disparity:
/// 1. **No return** (truth 0, NaN or ∞) → 0.
/// 2. **Occlusion** (`occlusion`): the depth image is referenced to the left imager and
///    the right imager sits `baseline` to its right (+x). A pixel whose right-image column
///    `u − d` lies left of the image (`< −0.5`) is invalid: the D435's invalid band on the
///    left edge, `≈ f·b/z` px wide. A pixel hidden from the right imager by a nearer
///    surface further right on the same row (some `u' > u` with `u' − d(u') < u − d(u)`)
///    is invalid: the shadow left of near objects, `d_near − d_far` px wide.
/// 3. **Edges**: a pixel whose 3×3 neighbourhood holds a nearer surface by more than
///    `edge_threshold` of its depth is on the far side of a discontinuity → invalid; a
///    pixel next to a farther surface (by more than `edge_threshold` of that depth) or
///    next to a no-return pixel is on the near side → invalid with probability
///    `edge_dropout` (ragged silhouettes).
/// 4. **Noise in disparity**: `d_m = d + subpixel·n`, where `n` is a unit-variance
///    Gaussian field, white or box-correlated over `(2·correlation_radius_px + 1)²` pixels
///    like a block matcher's aggregation window; `z_m = f·b/d_m`. To first order this
///    is exactly [`depth_rms_m`]; the second-order bias `z·σ_d²/d²` is well under a
///    millimetre at the D435's working ranges.
/// 5. **Range gates** on the measurement: `z_m` outside `[min_range_m, max_range_m]` (or
///    `d_m ≤ 0`) → 0.
/// 6. **Quantisation**: round to whole millimetres (values beyond 65535 mm → 0).
///
/// Draws per frame: `width·height` normals (the noise field) then `width·height` `u32`
/// (edge dropout), in raster order, whatever the scene and parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct StereoDepthNoise {
    /// Focal length of the depth image, px.
    pub focal_px: f64,
    /// Stereo baseline, m.
    pub baseline_m: f64,
    /// Disparity error σ, px.
    pub subpixel: f64,
    /// Measurements closer than this are invalid, m.
    pub min_range_m: f64,
    /// Measurements farther than this are invalid, m.
    pub max_range_m: f64,
    /// Relative depth jump that makes a depth discontinuity (0.05 = 5 %).
    pub edge_threshold: f64,
    /// Probability that a near-side edge pixel is dropped.
    pub edge_dropout: f64,
    /// Whether to invalidate pixels the right imager cannot see (occlusion shadows and
    /// the left invalid band).
    pub occlusion: bool,
    /// Radius of the box window correlating the disparity noise, px (0 = white).
    pub correlation_radius_px: u32,
}

impl StereoDepthNoise {
    /// The model for a camera: its focal length and stereo parameters, 5 % edge
    /// threshold, 30 % near-edge dropout, occlusion on, noise correlated over 3×3 pixels.
    /// The last three are assumptions tuned by eye to D435 footage, not datasheet values.
    pub fn new(intrinsics: &Intrinsics, stereo: &StereoSpec) -> StereoDepthNoise {
        StereoDepthNoise {
            focal_px: intrinsics.fx,
            baseline_m: stereo.baseline_m,
            subpixel: stereo.subpixel,
            min_range_m: stereo.min_range_m,
            max_range_m: stereo.max_range_m,
            edge_threshold: 0.05,
            edge_dropout: 0.3,
            occlusion: true,
            correlation_radius_px: 1,
        }
    }

    /// RMS depth error at depth `z`, m ([`depth_rms_m`]).
    pub fn rms_m(&self, z: f64) -> f64 {
        depth_rms_m(z, self.focal_px, self.baseline_m, self.subpixel)
    }

    /// Width of the left invalid band for a scene at depth `z`, px: `f·b/z`.
    pub fn invalid_band_px(&self, z: f64) -> f64 {
        self.focal_px * self.baseline_m / z
    }

    /// Measures a true depth image (`truth_m`: optical-axis depth per pixel, m, row-major
    /// `width × height`; 0 or non-finite = no return) into `out_mm` (millimetres, 0 =
    /// invalid). See the type's docs for the steps. Allocates nothing once `scratch` has
    /// seen a frame of this size.
    ///
    /// # Panics
    ///
    /// If `truth_m` or `out_mm` does not hold `width·height` pixels.
    pub fn apply<R: Rng + ?Sized>(
        &self,
        width: u32,
        height: u32,
        truth_m: &[f32],
        out_mm: &mut [u16],
        scratch: &mut DepthScratch,
        rng: &mut R,
    ) {
        self.apply_in_light(width, height, truth_m, None, out_mm, scratch, rng);
    }

    /// As [`StereoDepthNoise::apply`], in daylight: `light` is the daylight model and
    /// the matching SNR of every pixel ([`SunlightStereo::snr`]), which decides whether
    /// the pixel is matched and scales its disparity noise (see
    /// [`super::depth_light`]). `None` is the indoor case ([`StereoDepthNoise::apply`]):
    /// the projector's texture everywhere. With `light`, one more `u64` is drawn per
    /// frame (the key of the matching draws), after the others.
    ///
    /// # Panics
    ///
    /// If `truth_m`, `out_mm` or the SNR image does not hold `width·height` pixels.
    #[allow(clippy::too_many_arguments)]
    pub fn apply_in_light<R: Rng + ?Sized>(
        &self,
        width: u32,
        height: u32,
        truth_m: &[f32],
        light: Option<(&SunlightStereo, &[f32])>,
        out_mm: &mut [u16],
        scratch: &mut DepthScratch,
        rng: &mut R,
    ) {
        let (w, h) = (width as usize, height as usize);
        let n = w * h;
        assert_eq!(truth_m.len(), n, "truth image size");
        assert_eq!(out_mm.len(), n, "output image size");
        if let Some((_, snr)) = light {
            assert_eq!(snr.len(), n, "SNR image size");
        }

        // 1. The unit-variance disparity noise field, and the keys of the per-pixel
        //    dropout draws: by index, in parallel (thread-count independent).
        let normals = IndexedRng::new(rng.random());
        let dropout = IndexedRng::new(rng.random());
        let matching = light.map(|_| IndexedRng::new(rng.random()));
        scratch.noise.resize(n, 0.0);
        scratch
            .noise
            .par_chunks_mut(NOISE_CHUNK)
            .enumerate()
            .for_each(|(c, chunk)| {
                for (q, xs) in chunk.chunks_mut(4).enumerate() {
                    let g = normals.normals4(((c * NOISE_CHUNK) / 4 + q) as u64);
                    xs.copy_from_slice(&g[..xs.len()]);
                }
            });
        let r = self.correlation_radius_px as usize;
        if r > 0 {
            scratch.tmp.resize(n, 0.0);
            box_unit_variance(&scratch.noise, &mut scratch.tmp, w, h, r, true);
            box_unit_variance(&scratch.tmp, &mut scratch.noise, w, h, r, false);
        }
        scratch.suffix_min.resize(n, f64::INFINITY);

        let fb = self.focal_px * self.baseline_m;
        let thr = self.edge_threshold;
        let dropout_below = (self.edge_dropout.clamp(0.0, 1.0) * 4_294_967_296.0) as u64;
        scratch.edge_keys.resize(n, [0.0; 2]);
        edge_keys(truth_m, w, thr, &mut scratch.edge_keys);
        let keys = &scratch.edge_keys;
        let noise = &scratch.noise;

        out_mm
            .par_chunks_mut(w)
            .zip(scratch.suffix_min.par_chunks_mut(w))
            .enumerate()
            .for_each(|(v, (out_row, suffix_min))| {
                let row = &truth_m[v * w..(v + 1) * w];
                // Suffix minimum of u' − d(u') over valid pixels right of u.
                if self.occlusion {
                    let mut m = f64::INFINITY;
                    for u in (0..w).rev() {
                        suffix_min[u] = m;
                        let z = row[u];
                        if is_return(z) {
                            m = m.min(u as f64 - fb / f64::from(z));
                        }
                    }
                }
                for u in 0..w {
                    let i = v * w + u;
                    let z = row[u];
                    out_row[u] = 0;
                    if !is_return(z) {
                        continue;
                    }
                    let zf = f64::from(z);
                    let d = fb / zf;
                    if self.occlusion {
                        let ur = u as f64 - d;
                        if ur < -0.5 || suffix_min[u] < ur {
                            continue;
                        }
                    }
                    // Edges in the 3×3 neighbourhood.
                    let (far_side, near_side) = edge_sides(keys, w, h, u, v);
                    if far_side || (near_side && (dropout.bits(i as u64) >> 32) < dropout_below) {
                        continue;
                    }
                    let mut subpixel = self.subpixel;
                    if let (Some((model, snr)), Some(keys)) = (light, &matching) {
                        let s = f64::from(snr[i]);
                        let u01 = (keys.bits(i as u64) >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
                        if u01 >= model.valid_probability(s) {
                            continue;
                        }
                        subpixel *= model.noise_factor(s);
                    }
                    let dm = d + subpixel * f64::from(noise[i]);
                    if dm.is_nan() || dm <= 0.0 {
                        continue;
                    }
                    let zm = fb / dm;
                    if zm < self.min_range_m || zm > self.max_range_m {
                        continue;
                    }
                    // Nearest millimetre (zm > 0: adding ½ and truncating rounds, without
                    // a libm call).
                    let mm = (zm * 1000.0 + 0.5) as u32;
                    if (1..=65535).contains(&mm) {
                        out_row[u] = mm as u16;
                    }
                }
            });
    }
}

/// Whether a true depth is a return: positive and finite (0, NaN and ∞ are none).
#[inline(always)]
fn is_return(z: f32) -> bool {
    z.is_finite() && z > 0.0
}

/// Each pixel's depth (NaN where it is no return: 0, negative or not finite) and its
/// edge threshold `thr·z` (a nearer neighbour must be nearer by more than the pixel's
/// own; a farther one farther by more than that neighbour's), computed once per pixel
/// for [`edge_sides`] (rows in parallel).
fn edge_keys(truth_m: &[f32], w: usize, thr: f64, keys: &mut [[f32; 2]]) {
    keys.par_chunks_mut(w)
        .zip(truth_m.par_chunks(w))
        .for_each(|(keys, row)| {
            for (k, &z) in keys.iter_mut().zip(row) {
                *k = if is_return(z) {
                    [z, (thr * f64::from(z)) as f32]
                } else {
                    [f32::NAN, 0.0]
                };
            }
        });
}

/// The edge step of [`StereoDepthNoise`] at pixel `(u, v)` (a valid depth `z`), on
/// [`edge_keys`]: whether its 3×3 neighbourhood holds a nearer surface by more than
/// `thr·z` (far side of a discontinuity), and whether it holds a
/// farther surface by more than `thr` of that one's depth or a no-return pixel (near
/// side). NaN keys compare false, so a no-return neighbour counts only as near. Where
/// the far side holds, the near side is not needed (the pixel is dropped either way) and
/// may be either.
#[inline(always)]
fn edge_sides(keys: &[[f32; 2]], w: usize, h: usize, u: usize, v: usize) -> (bool, bool) {
    let i = v * w + u;
    let [z, tz] = keys[i];
    let (mut far, mut near) = (false, false);
    let mut look = |j: usize| {
        let [zq, tq] = keys[j];
        far |= z - zq > tz;
        near |= zq.is_nan() | (zq - z > tq);
    };
    if u >= 1 && u + 1 < w && v >= 1 && v + 1 < h {
        for j in [
            i - w - 1,
            i - w,
            i - w + 1,
            i - 1,
            i,
            i + 1,
            i + w - 1,
            i + w,
            i + w + 1,
        ] {
            look(j);
        }
    } else {
        for vv in v.saturating_sub(1)..(v + 2).min(h) {
            for uu in u.saturating_sub(1)..(u + 2).min(w) {
                look(vv * w + uu);
            }
        }
    }
    (far, near)
}

/// Box filter of radius `r` along rows (`horizontal`) or columns, each output divided by
/// the square root of its (border-clipped) window size, so i.i.d. unit-variance input
/// stays unit-variance.
///
/// Each output is the window's samples added in index order onto `-0.0` (what
/// `Iterator::sum` does), one window offset at a time over the whole row, so the adds
/// run over contiguous slices (vector instructions) with the same bits as a sum per
/// pixel.
fn box_unit_variance(src: &[f32], dst: &mut [f32], w: usize, h: usize, r: usize, horizontal: bool) {
    let divisor = |count: usize| (count as f32).sqrt();
    dst.par_chunks_mut(w).enumerate().for_each(|(v, out)| {
        out.fill(-0.0);
        if horizontal {
            let row = &src[v * w..(v + 1) * w];
            // Offset k = j − r of the window: out[u] += row[u + k] where it exists.
            for j in 0..=2 * r {
                let (first_out, first_in) = if j < r { (r - j, 0) } else { (0, j - r) };
                if first_out >= w || first_in >= w {
                    continue;
                }
                let len = (w - first_out).min(w - first_in);
                for (o, x) in out[first_out..first_out + len]
                    .iter_mut()
                    .zip(&row[first_in..first_in + len])
                {
                    *o += x;
                }
            }
            let inner = divisor(2 * r + 1);
            for (u, o) in out.iter_mut().enumerate() {
                let (lo, hi) = (u.saturating_sub(r), (u + r + 1).min(w));
                let d = if hi - lo == 2 * r + 1 {
                    inner
                } else {
                    divisor(hi - lo)
                };
                *o /= d;
            }
        } else {
            let (lo, hi) = (v.saturating_sub(r), (v + r + 1).min(h));
            for vv in lo..hi {
                for (o, x) in out.iter_mut().zip(&src[vv * w..(vv + 1) * w]) {
                    *o += x;
                }
            }
            let d = divisor(hi - lo);
            for o in out.iter_mut() {
                *o /= d;
            }
        }
    });
}

// ---------------------------------------------------------------------------------------
// Image noise and sRGB encoding
// ---------------------------------------------------------------------------------------

/// Sensor noise of grey or colour images, in linear intensity (0 = black, 1 = the
/// sensor's full scale).
///
/// Each sample (pixel, or channel of a pixel) gets Gaussian noise of variance
/// `read_noise² + shot_gain·signal`: read noise plus shot noise, whose Poisson variance is
/// proportional to the signal (the Gaussian approximation is excellent above a few tens
/// of electrons). With a full scale of `N` electrons, `shot_gain = 1/N`.
///
/// Defaults: `shot_gain = 1/4000` (a ≈ 4000 e⁻ full well, small-pixel CMOS like the D435's
/// OV2740 or the ZED's sensors at unity gain), `read_noise = 0.001` (≈ 4 e⁻). Mid grey
/// (0.18) then has σ ≈ 0.0067, about 2 codes of 8-bit sRGB; black has σ ≈ 3 codes.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImageNoise {
    /// Read-noise σ, linear units (0..1).
    pub read_noise: f32,
    /// Shot-noise variance per unit of linear signal.
    pub shot_gain: f32,
}

impl Default for ImageNoise {
    fn default() -> Self {
        ImageNoise {
            read_noise: 0.001,
            shot_gain: 1.0 / 4000.0,
        }
    }
}

impl ImageNoise {
    /// No noise.
    pub const NONE: ImageNoise = ImageNoise {
        read_noise: 0.0,
        shot_gain: 0.0,
    };

    /// Noise σ at a linear signal level (negative signals count as 0).
    pub fn sigma(&self, signal: f32) -> f32 {
        (self.read_noise * self.read_noise + self.shot_gain * signal.max(0.0)).sqrt()
    }

    /// Adds noise in place to linear samples (no clamping). One key drawn from `rng`;
    /// the samples' normals come from it by index ([`IndexedRng`]), in parallel.
    pub fn apply<R: Rng + ?Sized>(&self, linear: &mut [f32], rng: &mut R) {
        let normals = IndexedRng::new(rng.random());
        linear
            .par_chunks_mut(NOISE_CHUNK)
            .enumerate()
            .for_each(|(c, chunk)| {
                for (q, xs) in chunk.chunks_mut(4).enumerate() {
                    let n = normals.normals4(((c * NOISE_CHUNK) / 4 + q) as u64);
                    for (x, n) in xs.iter_mut().zip(n) {
                        *x += self.sigma(*x) * n;
                    }
                }
            });
    }

    /// Adds noise to linear samples and encodes them as 8-bit sRGB (clamped to [0, 1],
    /// rounded to the nearest code), without touching the input. One key drawn from
    /// `rng`; the samples' normals come from it by index ([`IndexedRng`]), in parallel,
    /// so the result does not depend on the thread count.
    ///
    /// # Panics
    ///
    /// If `out` and `linear` differ in length.
    pub fn apply_encode_srgb<R: Rng + ?Sized>(&self, linear: &[f32], out: &mut [u8], rng: &mut R) {
        assert_eq!(linear.len(), out.len(), "image sizes");
        let normals = IndexedRng::new(rng.random());
        let (r2, gain) = (self.read_noise * self.read_noise, self.shot_gain);
        let table: &SrgbTable = &SRGB;
        out.par_chunks_mut(NOISE_CHUNK)
            .zip(linear.par_chunks(NOISE_CHUNK))
            .enumerate()
            .for_each(|(c, (out, linear))| {
                for (q, (o4, x4)) in out.chunks_mut(4).zip(linear.chunks(4)).enumerate() {
                    let n = normals.normals4(((c * NOISE_CHUNK) / 4 + q) as u64);
                    for ((o, x), n) in o4.iter_mut().zip(x4).zip(n) {
                        let sigma = (r2 + gain * x.max(0.0)).sqrt();
                        *o = table.encode(*x + sigma * n);
                    }
                }
            });
    }
}

/// Samples per parallel task of the noise passes (a multiple of 4: four normals per
/// random index).
const NOISE_CHUNK: usize = 16 * 1024;

/// The sRGB transfer function (IEC 61966-2-1), linear → encoded, both in [0, 1].
pub fn linear_to_srgb(x: f64) -> f64 {
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// The inverse sRGB transfer function, encoded → linear, both in [0, 1].
pub fn srgb_to_linear(s: f64) -> f64 {
    if s <= 0.040_45 {
        s / 12.92
    } else {
        ((s + 0.055) / 1.055).powf(2.4)
    }
}

/// Bins of the coarse lookup table of [`linear_to_srgb_u8`]. Fine enough that a bin
/// holds at most one code threshold: the steepest code step of sRGB is the linear
/// segment's, `1/(12.92·255)` = 1/3295 of full scale, wider than a bin.
const SRGB_LUT_BINS: usize = 4096;

struct SrgbTable {
    /// `thresholds[c]`: the linear value where code `c + 1` starts (sRGB midpoint
    /// `(c + 0.5)/255` decoded), `c` in 0..255; `thresholds[255]` is `+∞`.
    thresholds: [f32; 256],
    /// Code at the lower end of each linear bin `[k, k + 1)/SRGB_LUT_BINS`.
    coarse: [u8; SRGB_LUT_BINS],
    /// Decoded linear value of each code.
    decode: [f32; 256],
}

impl SrgbTable {
    /// [`linear_to_srgb_u8`] without branches: the bin's code, plus one when `x` lies
    /// past the single threshold a bin can hold. NaN and `x ≤ 0` fall in bin 0 below its
    /// threshold (code 0); `x ≥ 1` falls in the last bin, whose code is 255.
    #[inline(always)]
    fn encode(&self, x: f32) -> u8 {
        // `as` saturates: NaN and negatives give bin 0, large values the last bin.
        let k = ((x * SRGB_LUT_BINS as f32) as usize).min(SRGB_LUT_BINS - 1);
        let c = self.coarse[k] as usize;
        (c + usize::from(x >= self.thresholds[c])).min(255) as u8
    }
}

static SRGB: LazyLock<SrgbTable> = LazyLock::new(|| {
    let thresholds: [f32; 256] = std::array::from_fn(|c| {
        if c < 255 {
            srgb_to_linear((c as f64 + 0.5) / 255.0) as f32
        } else {
            f32::INFINITY
        }
    });
    let coarse = std::array::from_fn(|k| {
        let x = k as f32 / SRGB_LUT_BINS as f32;
        thresholds.iter().take_while(|&&t| x >= t).count() as u8
    });
    let decode = std::array::from_fn(|c| srgb_to_linear(c as f64 / 255.0) as f32);
    SrgbTable {
        thresholds,
        coarse,
        decode,
    }
});

/// Encodes a linear intensity as the nearest 8-bit sRGB code (clamped to [0, 1]; NaN →
/// 0). A 4 KiB coarse table gives the code at the bin's lower end and the exact code
/// thresholds finish the job, so the result equals rounding the exact transfer function
/// (up to `f32` rounding at the thresholds).
pub fn linear_to_srgb_u8(x: f32) -> u8 {
    SRGB.encode(x)
}

/// Decodes an 8-bit sRGB code to linear intensity (table lookup).
pub fn srgb_u8_to_linear(c: u8) -> f32 {
    SRGB.decode[c as usize]
}

// ---------------------------------------------------------------------------------------
// Frame timing
// ---------------------------------------------------------------------------------------

/// Exposure-centre stamps of a free-running camera.
///
/// Stamp 0 is `start + offset`, with `offset` drawn uniformly in `[0, period)` from the
/// camera's own stream when the clock is made. Each following interval is
/// `period·(1 + drift_ppm·10⁻⁶) + σ_jitter·n_k` with `n_k` i.i.d. N(0, 1) (white period
/// jitter), accumulated in nanoseconds with the sub-nanosecond remainder carried, and at
/// least 1 ns, so stamps strictly increase.
///
/// **Unsynchronised cameras**: give each camera its own [`crate::rng::stream`] and, for
/// realism, its own crystal error (`drift_ppm`, ±20–50 ppm is typical of camera
/// oscillators). Their start phases are then independent and uniform, and their relative
/// phase walks (jitter) and slides (drift difference) over time, as for real free-running
/// devices: frames of two cameras never share a stamp except by chance, and a consumer
/// must interpolate or pick nearest stamps, as on a robot.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameClock {
    period: Nanos,
    jitter_ns: f64,
    drift_ppm: f64,
    offset: Nanos,
    next_stamp: Nanos,
    carry_ns: f64,
}

impl FrameClock {
    /// A clock starting at `start` plus a random offset in `[0, period)` (one draw from
    /// `rng`).
    ///
    /// `period` is the nominal frame period (at least 1 ns is used), `jitter_ns` the
    /// per-interval jitter σ (ns) and `drift_ppm` the clock-rate error (positive = slow
    /// camera clock, longer periods).
    pub fn new<R: Rng + ?Sized>(
        start: Nanos,
        period: Nanos,
        jitter_ns: f64,
        drift_ppm: f64,
        rng: &mut R,
    ) -> FrameClock {
        let period = Nanos(period.0.max(1));
        let offset = Nanos(rng.random_range(0..period.0));
        FrameClock {
            period,
            jitter_ns: jitter_ns.max(0.0),
            drift_ppm,
            offset,
            next_stamp: start + offset,
            carry_ns: 0.0,
        }
    }

    /// As [`FrameClock::new`] with the period of `rate_hz`.
    pub fn from_rate_hz<R: Rng + ?Sized>(
        start: Nanos,
        rate_hz: f64,
        jitter_ns: f64,
        drift_ppm: f64,
        rng: &mut R,
    ) -> FrameClock {
        FrameClock::new(
            start,
            Nanos::period_of_hz(rate_hz),
            jitter_ns,
            drift_ppm,
            rng,
        )
    }

    /// The nominal period.
    pub fn period(&self) -> Nanos {
        self.period
    }

    /// The start offset drawn at construction, in `[0, period)`.
    pub fn offset(&self) -> Nanos {
        self.offset
    }

    /// The stamp the next call of [`FrameClock::next`] returns.
    pub fn peek(&self) -> Nanos {
        self.next_stamp
    }

    /// The next exposure-centre stamp. One normal draw per call.
    pub fn next<R: Rng + ?Sized>(&mut self, rng: &mut R) -> Nanos {
        let stamp = self.next_stamp;
        let n: f64 = rng.sample(rand_distr::StandardNormal);
        let interval = self.period.0 as f64 * (1.0 + self.drift_ppm * 1e-6)
            + self.jitter_ns * n
            + self.carry_ns;
        let whole = interval.round();
        self.carry_ns = interval - whole;
        self.next_stamp = Nanos(stamp.0 + (whole as i64).max(1));
        stamp
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::stream;

    fn distorted_640() -> Intrinsics {
        Intrinsics {
            width: 640,
            height: 480,
            fx: 500.0,
            fy: 510.0,
            cx: 319.5,
            cy: 239.5,
            distortion: BrownConrady::from_d([-0.1, 0.02, 0.001, -0.0005, 0.001]),
        }
    }

    #[test]
    fn projects_like_the_closed_form() {
        let mut cam = distorted_640();
        let p = Vector3::new(0.3, -0.2, 2.0);
        // Pinhole: x = 0.15, y = -0.1 → (500·0.15 + 319.5, 510·(−0.1) + 239.5).
        cam.distortion = BrownConrady::NONE;
        let px = cam.project(p).unwrap();
        assert!((px - Vector2::new(394.5, 188.5)).norm() < 1e-12, "{px}");
        // Distorted: r² = 0.0325, R = 1 − 0.1·r² + 0.02·r⁴ + 0.001·r⁶ = 0.996771159…,
        // x_d = 0.15·R + 2·0.001·0.15·(−0.1) − 0.0005·(r² + 2·0.0225),
        // y_d = −0.1·R + 0.001·(r² + 2·0.01) + 2·(−0.0005)·0.15·(−0.1);
        // evaluated independently (Python, f64).
        cam.distortion = distorted_640().distortion;
        let px = cam.project(p).unwrap();
        let expected = Vector2::new(394.223_461_949_609_4, 188.699_095_874_265_6);
        assert!((px - expected).norm() < 1e-9, "{px} vs {expected}");
        // Behind the camera.
        assert!(cam.project(Vector3::new(0.0, 0.0, -1.0)).is_none());
        assert!(cam.project(Vector3::new(0.0, 0.0, 0.0)).is_none());
    }

    #[test]
    fn undistort_inverts_distort_over_a_grid() {
        let cam = distorted_640();
        // Normalised grid covering the image and a margin.
        for i in 0..=40 {
            for j in 0..=30 {
                let x = -0.8 + 1.6 * f64::from(i) / 40.0;
                let y = -0.6 + 1.2 * f64::from(j) / 30.0;
                let px = cam.distort(x, y);
                let back = cam.undistort(px.x, px.y).unwrap();
                assert!(
                    (back - Vector2::new(x, y)).norm() < 1e-9,
                    "({x}, {y}) → {back}"
                );
            }
        }
    }

    #[test]
    fn distort_inverts_undistort_over_whole_images() {
        for cam in [
            distorted_640(),
            CameraSpec::zed_x_mini().intrinsics,
            CameraSpec::zed2i_raw().intrinsics,
            CameraSpec::d435_color(30.0).intrinsics,
        ] {
            let mut worst = 0.0f64;
            for v in (0..cam.height).step_by(3) {
                for u in (0..cam.width).step_by(3) {
                    let (uf, vf) = (f64::from(u), f64::from(v));
                    let n = cam.undistort(uf, vf).unwrap();
                    let px = cam.distort(n.x, n.y);
                    worst = worst.max((px - Vector2::new(uf, vf)).norm());
                }
            }
            assert!(worst < 1e-9, "{cam:?}: {worst}");
        }
    }

    #[test]
    fn strong_distortion_refuses_folded_points() {
        // k1 = −0.3: r·(1 − 0.3·r²) turns at r² = 1/0.9.
        let d = BrownConrady {
            k1: -0.3,
            ..BrownConrady::NONE
        };
        assert!(d.radially_monotonic_to(1.0));
        assert!(!d.radially_monotonic_to(1.2));
        let cam = Intrinsics {
            distortion: d,
            ..distorted_640()
        };
        // Normalised radius 1.5 (r² = 2.25) would fold back into the image.
        assert!(cam.project(Vector3::new(1.5, 0.0, 1.0)).is_none());
        assert!(cam.project(Vector3::new(0.9, 0.0, 1.0)).is_some());
        // A dip between two positive ends: k1 = −0.3, k2 = 0.1: q(s) = 1 − 0.9s + 0.5s²
        // has no real root (disc < 0) → monotonic everywhere; k2 = 0.03: q = 1 − 0.9s +
        // 0.15s² has roots at s ≈ 1.47 and 4.53 (dips below 0 around s = 3), positive again beyond.
        let d2 = BrownConrady {
            k1: -0.3,
            k2: 0.1,
            ..BrownConrady::NONE
        };
        assert!(d2.radially_monotonic_to(100.0));
        let d3 = BrownConrady {
            k1: -0.3,
            k2: 0.03,
            ..BrownConrady::NONE
        };
        assert!(d3.radially_monotonic_to(1.4));
        assert!(!d3.radially_monotonic_to(10.0));
    }

    #[test]
    fn pixel_rays_project_back_to_their_pixels() {
        let cam = distorted_640();
        let rays = cam.pixel_rays();
        assert_eq!(rays.invalid, 0);
        assert_eq!(rays.len(), 640 * 480);
        let mut worst = 0.0f64;
        for v in 0..cam.height {
            for u in 0..cam.width {
                let d = rays.dir(u, v);
                let d = Vector3::new(f64::from(d[0]), f64::from(d[1]), f64::from(d[2]));
                assert!((d.norm() - 1.0).abs() < 1e-6);
                let px = cam.project(d).unwrap();
                worst = worst.max((px - Vector2::new(f64::from(u), f64::from(v))).norm());
            }
        }
        assert!(worst < 1e-4, "worst {worst} px");
        // The wide ZED X Mini too, with a tolerance for f32 directions at 1920 px.
        let cam = CameraSpec::zed_x_mini().intrinsics;
        let rays = cam.pixel_rays();
        assert_eq!(rays.invalid, 0);
        let mut worst = 0.0f64;
        for v in (0..cam.height).step_by(7) {
            for u in (0..cam.width).step_by(7) {
                let d = rays.dir(u, v);
                let d = Vector3::new(f64::from(d[0]), f64::from(d[1]), f64::from(d[2]));
                let px = cam.project(d).unwrap();
                worst = worst.max((px - Vector2::new(f64::from(u), f64::from(v))).norm());
            }
        }
        assert!(worst < 1e-3, "worst {worst} px");
    }

    #[test]
    fn ray_table_tiles_fill_packets() {
        let cam = Intrinsics::from_hfov(20, 10, 90.0, BrownConrady::NONE);
        let rays = cam.pixel_rays();
        let mut dir = [[0.0f32; PACKET_SIZE]; 3];
        assert_eq!(rays.fill_tile(0, 0, 8, 8, &mut dir), 64);
        assert_eq!(dir[0][9], rays.dir(1, 1)[0]);
        // Clipped corner tile: columns 16..20, rows 8..10.
        assert_eq!(rays.fill_tile(16, 8, 8, 8, &mut dir), 8);
        assert_eq!(dir[1][5], rays.dir(17, 9)[1]);
        // Centre pixel of an odd-sized pinhole looks straight ahead.
        let odd = Intrinsics::from_hfov(21, 11, 90.0, BrownConrady::NONE).pixel_rays();
        assert_eq!(odd.dir(10, 5), [0.0, 0.0, 1.0]);
    }

    #[test]
    fn from_hfov_puts_the_edges_at_half_the_field() {
        let pin = Intrinsics::from_hfov(640, 480, 90.0, BrownConrady::NONE);
        // tan(45°) = 1 → fx = 320.
        assert!((pin.fx - 320.0).abs() < 1e-9);
        assert_eq!((pin.cx, pin.cy), (319.5, 239.5));
        for spec in [CameraSpec::zed_x_mini(), CameraSpec::zed2i_raw()] {
            let h = spec.intrinsics.hfov_deg().unwrap();
            assert!((h - 110.0).abs() < 1e-6, "{h}");
        }
    }

    #[test]
    fn camera_info_matrices_have_the_ros_layout() {
        let cam = distorted_640();
        assert_eq!(
            cam.camera_info_k(),
            [500.0, 0.0, 319.5, 0.0, 510.0, 239.5, 0.0, 0.0, 1.0]
        );
        assert_eq!(
            cam.camera_info_p(0.0),
            [
                500.0, 0.0, 319.5, 0.0, 0.0, 510.0, 239.5, 0.0, 0.0, 0.0, 1.0, 0.0
            ]
        );
        // Right camera of a 120 mm pair: Tx = −500·0.12 = −60.
        let p = cam.camera_info_p(0.12);
        assert!((p[3] + 60.0).abs() < 1e-12);
        assert_eq!(cam.camera_info_d(), [-0.1, 0.02, 0.001, -0.0005, 0.001]);
        let msg = cam.camera_info_msg(
            Nanos(5),
            Arc::from("/cam/camera_info"),
            FrameId::new("cam_optical"),
            0.0,
        );
        assert_eq!(msg.r, CAMERA_INFO_R_IDENTITY);
        assert_eq!((msg.width, msg.height), (640, 480));
    }

    #[test]
    fn profiles_match_their_datasheets() {
        let d = CameraSpec::d435_depth(D435DepthMode::W848H480, 30.0);
        let st = d.stereo.unwrap();
        let h = d.intrinsics.hfov_deg().unwrap();
        assert!((84.0..=90.0).contains(&h), "{h}");
        assert_eq!(st.baseline_m, 0.05);
        assert!(
            (st.min_range_m - 0.28 * 2.0 / 3.0).abs() < 1e-9,
            "{}",
            st.min_range_m
        );
        let d640 = CameraSpec::d435_depth(D435DepthMode::W640H480, 15.0);
        assert!((d640.stereo.unwrap().min_range_m - 0.28 * 0.6).abs() < 1e-9);
        assert!((d640.intrinsics.fx - 0.9 * d.intrinsics.fx).abs() < 1e-9);
        let c = CameraSpec::d435_color(30.0).intrinsics;
        assert!((c.fx - 616.0).abs() < 2.0, "{}", c.fx);
        let z = CameraSpec::zed2i();
        assert!(z.intrinsics.distortion.is_none());
        assert!((z.intrinsics.hfov_deg().unwrap() - 93.0).abs() < 1e-9);
        assert_eq!(z.stereo.unwrap().baseline_m, 0.12);
        assert_eq!(z.period(), Nanos(66_666_667));
        let x = CameraSpec::zed_x_mini();
        assert_eq!((x.intrinsics.width, x.intrinsics.height), (1920, 1080));
        // 2.2 mm / 3 µm ≈ 733 px.
        assert!(
            (x.intrinsics.fx - 733.0).abs() < 30.0,
            "{}",
            x.intrinsics.fx
        );
        // Resizing keeps the horizontal field and scales min range.
        let r = d.with_resolution(424, 240);
        assert!((r.intrinsics.hfov_deg().unwrap() - h).abs() < 1e-9);
        assert!((r.stereo.unwrap().min_range_m - st.min_range_m / 2.0).abs() < 1e-9);
        for p in [
            CameraProfile::D435Depth,
            CameraProfile::D435Color,
            CameraProfile::Zed2i,
            CameraProfile::ZedXMini,
        ] {
            assert_eq!(p.spec().profile, p);
        }
    }

    #[test]
    fn d435_sizes_are_its_datasheet_modes() {
        // Depth: the 16:9 modes show the datasheet's 87° × 58° (±3°) field; 640×480 is
        // the 1280×800 sensor at 0.6 (f = 0.6·674 = 404.6 px: 76.7° × 61.3°), not the
        // 848×480 field squeezed into 640 columns (f = 339 px, 70.5° vertical) that a
        // plain resize gave. Min-Z scales with f (fixed disparity search): 0.28 m at
        // 1280×720.
        for m in D435DepthMode::ALL {
            let (w, h, scale) = m.geometry();
            let spec = CameraSpec::of_profile(CameraProfile::D435Depth, w, h).unwrap();
            let i = spec.intrinsics;
            assert_eq!((i.width, i.height), (w, h));
            let (hf, vf) = (i.hfov_deg().unwrap(), i.vfov_deg().unwrap());
            if m == D435DepthMode::W640H480 {
                assert!(
                    (hf - 76.7).abs() < 0.1 && (vf - 61.3).abs() < 0.1,
                    "{hf} {vf}"
                );
            } else {
                assert!(
                    (hf - 87.0).abs() <= 3.0 && (vf - 58.0).abs() <= 3.0,
                    "{m:?}: {hf} {vf}"
                );
            }
            assert!((i.fx - 674.3 * scale).abs() < 0.5, "{m:?}: {}", i.fx);
            let min = spec.stereo.unwrap().min_range_m;
            assert!((min - 0.28 * scale).abs() < 1e-12, "{m:?}: {min}");
        }
        let e = CameraSpec::of_profile(CameraProfile::D435Depth, 800, 600).unwrap_err();
        for mode in [
            "1280×720",
            "848×480",
            "640×480",
            "640×360",
            "480×270",
            "424×240",
        ] {
            assert!(e.contains(mode), "{e}");
        }
        // Colour: 69.4° horizontal at every 16:9 mode (up to 0.7° more with the lens's
        // barrel distortion, −1.5 % at the corner); the 4:3 modes ≈ 55°; 640×480 f ≈ 616
        // px (factory calibrations report ≈ 615 px).
        for (w, h, _) in d435_color_modes() {
            let i = CameraSpec::of_profile(CameraProfile::D435Color, w, h)
                .unwrap()
                .intrinsics;
            let hf = i.hfov_deg().unwrap();
            let want = if w * 3 == h * 4 { 54.9 } else { 69.4 };
            assert!((0.0..0.8).contains(&(hf - want)), "{w}×{h}: {hf}");
        }
        assert!(CameraSpec::of_profile(CameraProfile::D435Color, 752, 480).is_err());
        // Other cameras are resized freely.
        let z = CameraSpec::of_profile(CameraProfile::Zed2i, 752, 480).unwrap();
        assert!((z.intrinsics.hfov_deg().unwrap() - 93.0).abs() < 1e-9);
    }

    fn plane_model() -> StereoDepthNoise {
        StereoDepthNoise {
            focal_px: 380.0,
            baseline_m: 0.05,
            subpixel: 0.08,
            min_range_m: 0.3,
            max_range_m: 10.0,
            edge_threshold: 0.05,
            edge_dropout: 0.3,
            occlusion: true,
            correlation_radius_px: 1,
        }
    }

    #[test]
    fn depth_rms_formula() {
        // 2² · 0.08 / (380 · 0.05) = 0.32 / 19.
        assert!((depth_rms_m(2.0, 380.0, 0.05, 0.08) - 0.32 / 19.0).abs() < 1e-15);
    }

    #[test]
    fn depth_noise_on_a_plane_matches_the_rms_formula() {
        let model = plane_model();
        let (w, h) = (640u32, 480u32);
        let truth = vec![2.0f32; (w * h) as usize];
        let mut out = vec![0u16; truth.len()];
        let mut scratch = DepthScratch::new();
        let mut rng = stream(1, "test.depth");
        model.apply(w, h, &truth, &mut out, &mut scratch, &mut rng);
        // Left band: u − 9.5 < −0.5 ⇔ u < 9 invalid, everything else valid.
        let band = 9;
        let (mut n, mut sum, mut sum2) = (0usize, 0.0f64, 0.0f64);
        for v in 0..h as usize {
            for u in 0..w as usize {
                let mm = out[v * w as usize + u];
                if u < band {
                    assert_eq!(mm, 0, "band pixel ({u}, {v})");
                    continue;
                }
                assert_ne!(mm, 0, "pixel ({u}, {v})");
                let e = f64::from(mm) / 1000.0 - 2.0;
                n += 1;
                sum += e;
                sum2 += e * e;
            }
        }
        let mean = sum / n as f64;
        let rms = (sum2 / n as f64 - mean * mean).sqrt();
        let expected = 4.0 * 0.08 / (380.0 * 0.05);
        assert!(
            (rms / expected - 1.0).abs() < 0.05,
            "rms {rms} vs {expected}"
        );
        assert!(mean.abs() < 1e-3, "bias {mean}");

        // Neighbouring pixels are correlated as the 3×3 box predicts: 2/3 horizontally.
        let (mut c01, mut c00) = (0.0f64, 0.0f64);
        for v in 1..h as usize - 1 {
            for u in band + 1..w as usize - 2 {
                let a = f64::from(out[v * w as usize + u]) - 2000.0;
                let b = f64::from(out[v * w as usize + u + 1]) - 2000.0;
                c00 += a * a;
                c01 += a * b;
            }
        }
        let rho = c01 / c00;
        assert!((rho - 2.0 / 3.0).abs() < 0.03, "lag-1 correlation {rho}");

        // Same stream, same image; the scratch is reused.
        let mut again = vec![0u16; truth.len()];
        model.apply(
            w,
            h,
            &truth,
            &mut again,
            &mut scratch,
            &mut stream(1, "test.depth"),
        );
        assert_eq!(out, again);
    }

    #[test]
    fn depth_outside_the_range_gates_is_invalid() {
        let mut model = plane_model();
        model.occlusion = false;
        let (w, h) = (64u32, 48u32);
        let mut out = vec![0u16; (w * h) as usize];
        let mut scratch = DepthScratch::new();
        let mut rng = stream(2, "test.depth");
        for z in [0.1f32, 0.25, 12.0, 40.0, 0.0, f32::NAN, f32::INFINITY] {
            let truth = vec![z; out.len()];
            model.apply(w, h, &truth, &mut out, &mut scratch, &mut rng);
            assert!(out.iter().all(|&mm| mm == 0), "z = {z}");
        }
        // Ramp from 0.1 to 12 m: every reading lies within the gates.
        let truth: Vec<f32> = (0..out.len())
            .map(|i| 0.1 + 11.9 * i as f32 / out.len() as f32)
            .collect();
        model.edge_threshold = 1.0;
        model.apply(w, h, &truth, &mut out, &mut scratch, &mut rng);
        let valid: Vec<u16> = out.iter().copied().filter(|&mm| mm != 0).collect();
        assert!(valid.len() > out.len() / 2);
        assert!(valid.iter().all(|&mm| (300..=10_000).contains(&mm)));
    }

    #[test]
    fn edge_sides_follow_the_rule_on_every_pixel() {
        // The rule as written (the model's docs, step 3), one neighbour at a time, on
        // images of steps, slopes, no-return pixels (0, NaN, ∞, negative) and ties.
        let reference = |truth: &[f32], w: usize, h: usize, u: usize, v: usize, thr: f64| {
            let valid = |z: f32| z.is_finite() && z > 0.0;
            let z = truth[v * w + u];
            let zf = f64::from(z);
            let (mut far, mut near) = (false, false);
            for vv in v.saturating_sub(1)..(v + 2).min(h) {
                for uu in u.saturating_sub(1)..(u + 2).min(w) {
                    let zq = truth[vv * w + uu];
                    if !valid(zq) {
                        near = true;
                    } else if z - zq > (thr * zf) as f32 {
                        far = true;
                    } else if zq - z > (thr * f64::from(zq)) as f32 {
                        near = true;
                    }
                }
            }
            (far, near)
        };
        let mut rng = stream(5, "test.edges");
        let mut checked = 0;
        for (w, h) in [(1, 1), (1, 7), (7, 1), (2, 2), (13, 9), (64, 48)] {
            for thr in [0.0, 0.05, 0.3] {
                let truth: Vec<f32> = (0..w * h)
                    .map(|_| match rng.random_range(0..12) {
                        0 => 0.0,
                        1 => f32::NAN,
                        2 => f32::INFINITY,
                        3 => -1.0,
                        4 => 2.0,
                        5 => 2.1,
                        _ => rng.random_range(0.3f32..6.0),
                    })
                    .collect();
                let mut keys = vec![[0.0; 2]; w * h];
                edge_keys(&truth, w, thr, &mut keys);
                for v in 0..h {
                    for u in 0..w {
                        let z = truth[v * w + u];
                        if !is_return(z) {
                            continue;
                        }
                        let (far, near) = reference(&truth, w, h, u, v, thr);
                        let (got_far, got_near) = edge_sides(&keys, w, h, u, v);
                        assert_eq!(got_far, far, "far side at ({u}, {v}), {w}×{h}, thr {thr}");
                        if !far {
                            assert_eq!(got_near, near, "near side at ({u}, {v}), {w}×{h}");
                        }
                        checked += 1;
                    }
                }
            }
        }
        assert!(checked > 5000, "{checked} pixels checked");
    }

    #[test]
    fn box_filter_sums_each_window_as_one_sum_does() {
        // A second method: each output's window summed on its own (`Iterator::sum`),
        // borders clipped, divided by the square root of the window's size.
        let mut rng = stream(6, "test.box");
        for (w, h) in [(1, 1), (1, 5), (5, 1), (3, 4), (17, 11), (64, 9)] {
            let src: Vec<f32> = (0..w * h)
                .map(|i| {
                    if i % 7 == 3 {
                        -0.0
                    } else {
                        rng.random_range(-3.0f32..3.0)
                    }
                })
                .collect();
            for r in [0, 1, 2, 5] {
                for horizontal in [true, false] {
                    let mut got = vec![f32::NAN; w * h];
                    box_unit_variance(&src, &mut got, w, h, r, horizontal);
                    for v in 0..h {
                        for u in 0..w {
                            let (sum, count) = if horizontal {
                                let (lo, hi) = (u.saturating_sub(r), (u + r + 1).min(w));
                                (src[v * w + lo..v * w + hi].iter().sum::<f32>(), hi - lo)
                            } else {
                                let (lo, hi) = (v.saturating_sub(r), (v + r + 1).min(h));
                                ((lo..hi).map(|vv| src[vv * w + u]).sum::<f32>(), hi - lo)
                            };
                            let want = sum / (count as f32).sqrt();
                            assert_eq!(
                                got[v * w + u].to_bits(),
                                want.to_bits(),
                                "({u}, {v}) of {w}×{h}, r {r}, horizontal {horizontal}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn a_vertical_step_edge_makes_holes_only_near_the_edge() {
        // Far wall (3 m) left of column 320, near wall (1.5 m) from it: f·b = 19 px·m.
        let model = plane_model();
        let (w, h) = (640usize, 120usize);
        let edge = 320usize;
        let truth: Vec<f32> = (0..w * h)
            .map(|i| if i % w < edge { 3.0 } else { 1.5 })
            .collect();
        let mut out = vec![0u16; w * h];
        model.apply(
            w as u32,
            h as u32,
            &truth,
            &mut out,
            &mut DepthScratch::new(),
            &mut stream(3, "t"),
        );
        let (d_far, d_near) = (19.0 / 3.0, 19.0 / 1.5);
        // Shadow: far pixels with u − d_far > edge − d_near, i.e. u > 313.67; the band:
        // u − d_far < −0.5, i.e. u ≤ 5.
        let shadow_start = (edge as f64 - (d_near - d_far)).floor() as usize + 1;
        assert_eq!(shadow_start, 314);
        let band_end = (d_far - 0.5).ceil() as usize;
        assert_eq!(band_end, 6);
        let mut dropped_near = 0;
        for v in 0..h {
            for u in 0..w {
                let mm = out[v * w + u];
                if u < band_end || (shadow_start..edge).contains(&u) {
                    assert_eq!(mm, 0, "({u}, {v}) should be a hole");
                } else if u == edge {
                    dropped_near += usize::from(mm == 0);
                } else {
                    assert_ne!(mm, 0, "({u}, {v}) should be valid");
                }
            }
        }
        // Near-side edge column: dropout probability 0.3 over 120 rows.
        assert!((15..=60).contains(&dropped_near), "{dropped_near}");
    }

    #[test]
    fn a_horizontal_step_edge_holes_the_far_side_row() {
        // Far (3 m) above row 60, near (1.5 m) below: no occlusion along rows, so the
        // 3×3 rule alone acts: row 59 (far side) all holes, row 60 (near side) dropout.
        let mut model = plane_model();
        model.occlusion = false;
        let (w, h) = (200usize, 120usize);
        let truth: Vec<f32> = (0..w * h)
            .map(|i| if i / w < 60 { 3.0 } else { 1.5 })
            .collect();
        let mut out = vec![0u16; w * h];
        model.apply(
            w as u32,
            h as u32,
            &truth,
            &mut out,
            &mut DepthScratch::new(),
            &mut stream(4, "t"),
        );
        let mut dropped = 0;
        for v in 0..h {
            for u in 0..w {
                let mm = out[v * w + u];
                match v {
                    59 => assert_eq!(mm, 0),
                    60 => dropped += usize::from(mm == 0),
                    _ => assert_ne!(mm, 0, "({u}, {v})"),
                }
            }
        }
        let frac = dropped as f64 / w as f64;
        assert!((0.15..=0.45).contains(&frac), "{frac}");
    }

    #[test]
    fn image_noise_variance_matches_read_plus_shot() {
        let noise = ImageNoise {
            read_noise: 0.01,
            shot_gain: 0.002,
        };
        let mut rng = stream(5, "test.image");
        for signal in [0.0f32, 0.25, 0.8] {
            let mut img = vec![signal; 200_000];
            noise.apply(&mut img, &mut rng);
            let n = img.len() as f64;
            let mean = img.iter().map(|&x| f64::from(x)).sum::<f64>() / n;
            let var = img
                .iter()
                .map(|&x| (f64::from(x) - mean).powi(2))
                .sum::<f64>()
                / (n - 1.0);
            let expected = 0.01f64.powi(2) + 0.002 * f64::from(signal);
            assert!(
                (var / expected - 1.0).abs() < 0.05,
                "{signal}: {var} vs {expected}"
            );
            assert!((mean - f64::from(signal)).abs() < 1e-3);
        }
        // Deterministic for a given stream.
        let src = vec![0.3f32; 1000];
        let mut a = vec![0u8; 1000];
        let mut b = vec![0u8; 1000];
        ImageNoise::default().apply_encode_srgb(&src, &mut a, &mut stream(6, "x"));
        ImageNoise::default().apply_encode_srgb(&src, &mut b, &mut stream(6, "x"));
        assert_eq!(a, b);
        assert!(a.iter().any(|&c| c != a[0]));
    }

    #[test]
    fn srgb_lookup_matches_the_transfer_function() {
        assert_eq!(linear_to_srgb_u8(0.0), 0);
        assert_eq!(linear_to_srgb_u8(-1.0), 0);
        assert_eq!(linear_to_srgb_u8(f32::NAN), 0);
        assert_eq!(linear_to_srgb_u8(1.0), 255);
        assert_eq!(linear_to_srgb_u8(7.0), 255);
        // 18 % grey encodes to sRGB 0.4613… → code 118 (117.6 rounded).
        assert_eq!(linear_to_srgb_u8(0.18), 118);
        let mut checked = 0;
        for k in 0..=200_000 {
            let x = k as f64 / 200_000.0;
            let s = linear_to_srgb(x) * 255.0;
            if (s - s.floor() - 0.5).abs() < 1e-3 {
                continue; // too close to a rounding threshold for f32
            }
            assert_eq!(linear_to_srgb_u8(x as f32), s.round() as u8, "x = {x}");
            checked += 1;
        }
        assert!(checked > 199_000);
        for c in 0..=255u8 {
            assert_eq!(linear_to_srgb_u8(srgb_u8_to_linear(c)), c);
        }
        for x in [
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MAX,
            f32::MIN_POSITIVE,
            1e-30,
        ] {
            let want = if x >= 1.0 { 255 } else { 0 };
            assert_eq!(linear_to_srgb_u8(x), want, "x = {x}");
        }
        // The one-step lookup is exact only if no bin holds two thresholds: the threshold
        // after the bin's first one lies at or past the bin's upper end.
        let t = &*SRGB;
        for k in 0..SRGB_LUT_BINS {
            let c = t.coarse[k] as usize;
            let upper = (k + 1) as f32 / SRGB_LUT_BINS as f32;
            assert!(c == 255 || t.thresholds[c + 1] >= upper, "bin {k}");
        }
    }

    #[test]
    fn frame_clock_is_free_running_with_jitter() {
        let period = Nanos::period_of_hz(30.0);
        let sigma = 200_000.0; // 0.2 ms
        let start = Nanos::from_secs(1_700_000_000);
        let mut rng = stream(7, "sensors.cam_a");
        let mut clock = FrameClock::new(start, period, sigma, 0.0, &mut rng);
        assert!((0..period.0).contains(&clock.offset().0));
        assert_eq!(clock.peek(), start + clock.offset());
        let stamps: Vec<Nanos> = (0..10_000).map(|_| clock.next(&mut rng)).collect();
        assert_eq!(stamps[0], start + clock.offset());
        let intervals: Vec<f64> = stamps.windows(2).map(|s| (s[1] - s[0]).0 as f64).collect();
        assert!(intervals.iter().all(|&d| d > 0.0));
        let n = intervals.len() as f64;
        let mean = intervals.iter().sum::<f64>() / n;
        assert!((mean / period.0 as f64 - 1.0).abs() < 1e-3, "mean {mean}");
        let std = (intervals.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        assert!((std / sigma - 1.0).abs() < 0.05, "std {std}");

        // Drift: +100 ppm lengthens the mean period by 1e-4, exactly in the long run.
        let mut drifting = FrameClock::new(start, period, 0.0, 100.0, &mut rng);
        let first = drifting.next(&mut rng);
        let mut last = first;
        for _ in 0..10_000 {
            last = drifting.next(&mut rng);
        }
        let mean = (last - first).0 as f64 / 10_000.0;
        assert!((mean - period.0 as f64 * 1.0001).abs() < 0.01, "{mean}");

        // Extreme jitter still gives strictly increasing stamps.
        let mut wild = FrameClock::new(start, Nanos(1000), 5000.0, 0.0, &mut rng);
        let mut prev = wild.next(&mut rng);
        for _ in 0..1000 {
            let t = wild.next(&mut rng);
            assert!(t > prev);
            prev = t;
        }

        // Two cameras on different streams start at different phases.
        let a = FrameClock::new(start, period, sigma, 0.0, &mut stream(7, "sensors.cam_a"));
        let b = FrameClock::new(start, period, sigma, 0.0, &mut stream(7, "sensors.cam_b"));
        assert_ne!(a.offset(), b.offset());
        let a2 = FrameClock::new(start, period, sigma, 0.0, &mut stream(7, "sensors.cam_a"));
        assert_eq!(a.offset(), a2.offset());
    }
}
