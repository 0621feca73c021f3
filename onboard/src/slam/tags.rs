//! AprilTag (tag36h11) sightings for the SLAM's loop closure: the tags in a grey camera
//! image and the pose of each in the camera, solved through the lens distortion.
//!
//! # Pipeline ([`TagDetector::detect`])
//!
//! 1. AprilTag 3 (the C library behind the `apriltag` crate) finds quads and decodes ids
//!    on a copy of the raw, distorted image through a logarithmic tone curve
//!    (the tone curve `TONE_CURVE`: without it a shaded board against a bright sky loses its white
//!    border), with one detector thread (deterministic).
//! 2. Detections with more corrected bits than `max_hamming` or a decision margin below
//!    `min_decision_margin` are dropped; the corners move to our pixel convention.
//! 3. [`refine_corners`] (unless `refine_corners = false`): the corners are re-measured on
//!    the original image, from sub-pixel edge crossings in linear intensity along each
//!    side and straight lines fitted to them in undistorted coordinates (AprilTag fits
//!    straight lines in the distorted image, on the tone-mapped copy).
//! 4. [`solve_tag_pose`]: the corners are undistorted ([`TagCamera::undistort`]), the
//!    homography of the square is solved (DLT on the four points, normalised image
//!    coordinates) and decomposed into an initial `R, t` (`R` orthonormalised by SVD).
//!    A planar square seen from afar has two poses that image almost alike (the tag
//!    tilted either way about the line of sight); the second start is the first
//!    reflected about the line of sight ([`flipped_rotation`]). Both starts are refined by
//!    Levenberg-Marquardt on the pixel reprojection error of the four corners through the
//!    distortion model, and the one with the lower RMS wins. [`tag_pose_information`]
//!    gives the pose's first-order information for weighting it.
//! 5. Sightings farther than `max_distance_m` or with an RMS above `max_reprojection_px`
//!    are dropped; the rest come back sorted by id.
//!
//! AprilTag's own pose estimate is not used: it assumes a pinhole camera.
//!
//! # Tag frame
//!
//! AprilTag 3 / `apriltag_ros` convention, the same as the simulator's boards: origin at
//! the centre of the black square, `x` to the right and `y` down as printed, `z` into the
//! tag, so the printed face is the plane `z = 0` and looks along `-z` (towards a camera
//! that reads it). A tag seen upright and head-on by a camera has `camera_from_tag`
//! rotation identity and translation `(0, 0, distance)`. The corners, in AprilTag's order
//! ([`tag_corners`]), are `(−s/2, +s/2)` (printed bottom-left), `(+s/2, +s/2)`
//! (bottom-right), `(+s/2, −s/2)` (top-right) and `(−s/2, −s/2)` (top-left), `s` the tag
//! size (edge of the black square).
//!
//! # Pixel convention
//!
//! OpenCV / ROS `CameraInfo`: the centre of pixel `(u, v)` is at `(u, v)`. AprilTag puts
//! it at `(u + 0.5, v + 0.5)`; its corners are shifted by `−0.5` on the way in.
//!
//! # Threads
//!
//! The C detector (`apriltag::Detector`, and its image buffer) is neither `Send` nor
//! `Sync`. Rather than assert otherwise with `unsafe`, each thread that calls
//! [`TagDetector::detect`] keeps its own C detectors (one per `max_hamming`) and image
//! buffer in a thread-local cache, built on first use and reused for every later frame;
//! [`TagDetector`] itself holds only settings and is `Send + Sync`. The detection does not
//! depend on which thread runs it. Each cached C detector costs its quick-decode table
//! (about 28 kB at `max_hamming = 0`, 1 MB at 1, 37 MB at 2) and one tag-family struct that
//! the `apriltag` crate never frees (a few hundred bytes per thread and `max_hamming`).
//!
//! ```
//! use vinebench_onboard::slam::GrayImage;
//! use vinebench_onboard::slam::tags::{TagCamera, TagConfig, TagDetector};
//! let camera = TagCamera {
//!     fx: 400.0, fy: 400.0, cx: 319.5, cy: 239.5,
//!     d: [-0.05, 0.01, 0.0, 0.0, 0.0], width: 640, height: 480,
//! };
//! let mut detector = TagDetector::new(TagConfig::default()).expect("default config");
//! // A blank image holds no tag.
//! assert!(detector.detect(&GrayImage::new(640, 480), &camera).is_empty());
//! ```

use std::cell::RefCell;
use std::sync::LazyLock;

use nalgebra::{
    Isometry3, Matrix2, Matrix2x3, Matrix3, Matrix6, Point2, Point3, SMatrix, SVector,
    Translation3, UnitQuaternion, Vector2, Vector3, Vector6,
};
use serde::{Deserialize, Serialize};
use vinebench_msgs::CameraInfoMsg;

use super::image::GrayImage;
use super::{ConfigError, check};

/// The largest `max_hamming` accepted: AprilTag's quick-decode table of tag36h11 takes
/// about 37 MB at 2 bits and 1.2 GB at 3.
pub const MAX_HAMMING_LIMIT: u32 = 2;

/// Levenberg-Marquardt iterations of the pose refinement.
const LM_MAX_ITERATIONS: usize = 50;

/// Initial Levenberg-Marquardt damping (relative to the diagonal of `JᵀJ`).
const LM_INITIAL_DAMPING: f64 = 1e-3;

/// Damping above which a refinement stops (no step reduces the error any more).
const LM_MAX_DAMPING: f64 = 1e10;

/// A refinement stops when its step moves the pose by less than this (rad and m).
const LM_MIN_STEP: f64 = 1e-13;

/// Newton iterations of the inverse distortion.
const UNDISTORT_MAX_ITERATIONS: usize = 50;

/// The inverse distortion is accepted when it reproduces the distorted point to this
/// (normalised units).
const UNDISTORT_TOLERANCE: f64 = 1e-12;

/// `[slam.tags]`: AprilTag (tag36h11) sightings for loop closure.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct TagConfig {
    /// Whether tags are looked for at all.
    pub enabled: bool,
    /// The camera whose colour images are searched: `/<camera>/color/image_raw` with
    /// `/<camera>/color/camera_info`.
    pub camera: String,
    /// Edge of the black square (AprilTag's "tag size"), m; every tag has this size.
    pub size_m: f64,
    /// AprilTag's `quad_decimate`: quads are found on an image decimated by this factor
    /// (ids are decoded and edges refined at full resolution). 1 = full resolution.
    pub decimation: f32,
    /// Detections with more corrected bits than this are dropped (at most
    /// [`MAX_HAMMING_LIMIT`]); the detector corrects no more than this.
    pub max_hamming: u32,
    /// Detections with a lower AprilTag decision margin (the mean contrast of the data
    /// bits against the decoding threshold, grey levels) are dropped.
    pub min_decision_margin: f32,
    /// Sightings farther than this (camera to tag centre) are dropped: their pose is too
    /// uncertain, m.
    pub max_distance_m: f64,
    /// Sightings whose refined pose reprojects the corners with a larger RMS are dropped,
    /// px.
    pub max_reprojection_px: f64,
    /// Whether the corners are re-measured on the image itself ([`refine_corners`]:
    /// sub-pixel edges in linear intensity, straight lines fitted through the distortion)
    /// instead of taking AprilTag's, which it finds on a tone-mapped copy.
    pub refine_corners: bool,
}

impl Default for TagConfig {
    fn default() -> Self {
        TagConfig {
            enabled: true,
            camera: "side".to_string(),
            size_m: 0.3,
            decimation: 2.0,
            max_hamming: 0,
            min_decision_margin: 30.0,
            max_distance_m: 3.0,
            max_reprojection_px: 1.0,
            refine_corners: true,
        }
    }
}

impl TagConfig {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check(!self.camera.is_empty(), "tags.camera must not be empty")?;
        check(
            self.size_m.is_finite() && self.size_m > 0.0,
            "tags.size_m must be > 0",
        )?;
        check(
            self.decimation.is_finite() && self.decimation >= 1.0,
            "tags.decimation must be >= 1",
        )?;
        check(
            self.max_hamming <= MAX_HAMMING_LIMIT,
            "tags.max_hamming must be <= 2",
        )?;
        check(
            self.min_decision_margin.is_finite() && self.min_decision_margin >= 0.0,
            "tags.min_decision_margin must be >= 0",
        )?;
        check(
            self.max_distance_m.is_finite() && self.max_distance_m > 0.0,
            "tags.max_distance_m must be > 0",
        )?;
        check(
            self.max_reprojection_px.is_finite() && self.max_reprojection_px > 0.0,
            "tags.max_reprojection_px must be > 0",
        )
    }
}

/// A pinhole camera with Brown-Conrady (OpenCV `plumb_bob`) distortion, as a
/// `CameraInfo` describes it.
///
/// An ideal normalised point `(x, y) = (X/Z, Y/Z)` of the optical frame (x right, y down,
/// z forward), with `r² = x² + y²` and `R = 1 + k1·r² + k2·r⁴ + k3·r⁶`, is imaged at
/// `x_d = x·R + 2·p1·x·y + p2·(r² + 2·x²)`, `y_d = y·R + p1·(r² + 2·y²) + 2·p2·x·y` and
/// then at pixel `(fx·x_d + cx, fy·y_d + cy)`; pixel centres are at integer coordinates.
/// The model holds only where the radial map `r ↦ r·R` increases
/// ([`TagCamera::radially_monotonic_to`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TagCamera {
    /// Horizontal focal length, px.
    pub fx: f64,
    /// Vertical focal length, px.
    pub fy: f64,
    /// Principal point column, px.
    pub cx: f64,
    /// Principal point row, px.
    pub cy: f64,
    /// Distortion `[k1, k2, p1, p2, k3]` (the `CameraInfo.D` order).
    pub d: [f64; 5],
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
}

impl TagCamera {
    /// The camera of a `CameraInfo` (`K` and `D`; the skew `K[1]`, `R` and `P` are
    /// ignored: our images are not rectified).
    pub fn from_info(info: &CameraInfoMsg) -> TagCamera {
        TagCamera {
            fx: info.k[0],
            fy: info.k[4],
            cx: info.k[2],
            cy: info.k[5],
            d: info.d,
            width: info.width,
            height: info.height,
        }
    }

    /// Whether every distortion coefficient is zero.
    fn undistorted(&self) -> bool {
        self.d.iter().all(|&c| c == 0.0)
    }

    /// The radial factor `R(r²)`.
    fn radial(&self, r2: f64) -> f64 {
        let [k1, k2, _, _, k3] = self.d;
        1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    }

    /// Distorts an ideal normalised point: `(x, y) ↦ (x_d, y_d)` (the mapper's plumb-bob
    /// model, [`crate::mapper::camera::distort`]).
    pub fn distort(&self, p: &Vector2<f64>) -> Vector2<f64> {
        let (x, y) = crate::mapper::camera::distort(&self.d, p.x, p.y);
        Vector2::new(x, y)
    }

    /// Jacobian `∂(x_d, y_d)/∂(x, y)` of [`TagCamera::distort`] at `p`.
    pub fn distortion_jacobian(&self, p: &Vector2<f64>) -> Matrix2<f64> {
        let [k1, k2, p1, p2, k3] = self.d;
        let (x, y) = (p.x, p.y);
        let r2 = x * x + y * y;
        let radial = self.radial(r2);
        // dR/d(r²)
        let dr = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
        let off = 2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y;
        Matrix2::new(
            radial + 2.0 * x * x * dr + 2.0 * p1 * y + 6.0 * p2 * x,
            off,
            off,
            radial + 2.0 * y * y * dr + 6.0 * p1 * y + 2.0 * p2 * x,
        )
    }

    /// Whether the radial map `r ↦ r·R(r²)` is strictly increasing on `[0, √r2]`, i.e.
    /// whether ideal points up to normalised radius² `r2` image without folding back.
    ///
    /// Its derivative is `q(s) = 1 + 3·k1·s + 5·k2·s² + 7·k3·s³` with `s = r²`; `q` is
    /// checked at `r2` and at its interior critical points (closed form). Tangential
    /// terms are ignored (tiny for real lenses).
    pub fn radially_monotonic_to(&self, r2: f64) -> bool {
        let [k1, k2, _, _, k3] = self.d;
        let q = |s: f64| 1.0 + s * (3.0 * k1 + s * (5.0 * k2 + s * 7.0 * k3));
        if r2.is_nan() || r2 < 0.0 || q(r2) <= 0.0 {
            return false;
        }
        // q'(s) = 3·k1 + 10·k2·s + 21·k3·s² = 0.
        let (a, b, c) = (21.0 * k3, 10.0 * k2, 3.0 * k1);
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

    /// Pixel coordinates of a point of the optical frame, distortion included.
    ///
    /// `None` when the point is not in front of the camera (`z ≤ 0` or not finite) or
    /// lies beyond the distortion's monotonic range. The result may lie outside the image.
    pub fn project(&self, p_cam: &Vector3<f64>) -> Option<Point2<f64>> {
        let n = self.normalised(p_cam)?;
        let d = self.distort(&n);
        Some(Point2::new(
            self.fx * d.x + self.cx,
            self.fy * d.y + self.cy,
        ))
    }

    /// The ideal normalised point of `p_cam`, `None` where [`TagCamera::project`] fails.
    fn normalised(&self, p_cam: &Vector3<f64>) -> Option<Vector2<f64>> {
        if !(p_cam.z > 0.0 && p_cam.x.is_finite() && p_cam.y.is_finite() && p_cam.z.is_finite()) {
            return None;
        }
        let n = Vector2::new(p_cam.x / p_cam.z, p_cam.y / p_cam.z);
        (self.undistorted() || self.radially_monotonic_to(n.norm_squared())).then_some(n)
    }

    /// [`TagCamera::project`] and its Jacobian `∂(u, v)/∂p_cam`.
    fn project_with_jacobian(
        &self,
        p_cam: &Vector3<f64>,
    ) -> Option<(Vector2<f64>, Matrix2x3<f64>)> {
        let n = self.normalised(p_cam)?;
        let d = self.distort(&n);
        let px = Vector2::new(self.fx * d.x + self.cx, self.fy * d.y + self.cy);
        let iz = 1.0 / p_cam.z;
        let dn_dp = Matrix2x3::new(iz, 0.0, -n.x * iz, 0.0, iz, -n.y * iz);
        let k = Matrix2::new(self.fx, 0.0, 0.0, self.fy);
        Some((px, k * self.distortion_jacobian(&n) * dn_dp))
    }

    /// The ideal normalised point `(X/Z, Y/Z)` seen at pixel `(u, v)`: the inverse of
    /// [`TagCamera::project`] up to depth.
    ///
    /// Damped Newton iteration on the distortion with its analytic Jacobian, started at the
    /// distorted point, to machine precision. `None` when it does not reproduce the pixel
    /// (to `1e-12` normalised) or the solution lies beyond the monotonic range (a pixel
    /// outside the lens's valid image circle).
    pub fn undistort(&self, u: f64, v: f64) -> Option<Vector2<f64>> {
        let pd = Vector2::new((u - self.cx) / self.fx, (v - self.cy) / self.fy);
        if !(pd.x.is_finite() && pd.y.is_finite()) {
            return None;
        }
        if self.undistorted() {
            return Some(pd);
        }
        let mut p = pd;
        let mut res = self.distort(&p) - pd;
        let mut res_norm = res.norm();
        let tol = 1e-15 * (1.0 + pd.norm());
        for _ in 0..UNDISTORT_MAX_ITERATIONS {
            if res_norm <= tol {
                break;
            }
            let step = self.distortion_jacobian(&p).lu().solve(&res)?;
            if !(step.x.is_finite() && step.y.is_finite()) {
                return None;
            }
            // Backtracking: halve the step until the residual decreases.
            let mut t = 1.0;
            loop {
                let cand = p - step * t;
                let cand_res = self.distort(&cand) - pd;
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
        (res_norm <= UNDISTORT_TOLERANCE && self.radially_monotonic_to(p.norm_squared()))
            .then_some(p)
    }
}

/// One tag seen in one image.
#[derive(Clone, Debug, PartialEq)]
pub struct TagSighting {
    /// Tag id in the tag36h11 family (0..=586).
    pub id: u32,
    /// Pose of the tag frame in the camera's optical frame (x right, y down, z forward):
    /// `p_cam = camera_from_tag * p_tag`. The tag frame is the AprilTag 3 one (origin at
    /// the centre of the black square, x right and y down as printed, z into the tag; see
    /// the [module docs](self)).
    pub camera_from_tag: Isometry3<f64>,
    /// The detected corners of the black square in AprilTag's order (see
    /// [`tag_corners`]), pixel coordinates with pixel centres at integers.
    pub corners_px: [[f64; 2]; 4],
    /// RMS over the four corners of the distance between each detected corner and its
    /// reprojection at `camera_from_tag`, px.
    pub reprojection_rms_px: f64,
    /// AprilTag's decision margin (mean contrast of the data bits against the decoding
    /// threshold; higher is more certain).
    pub decision_margin: f32,
    /// Bits AprilTag corrected to decode the id.
    pub hamming: u32,
}

/// A tag pose solved from its four corners ([`solve_tag_pose`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TagPose {
    /// Pose of the tag frame in the camera's optical frame: `p_cam = camera_from_tag *
    /// p_tag`.
    pub camera_from_tag: Isometry3<f64>,
    /// RMS over the four corners of the reprojection error, px.
    pub reprojection_rms_px: f64,
}

/// The four corners of the black square of a tag of size `size_m` in the tag frame, in
/// AprilTag's detection order: printed bottom-left `(−s/2, +s/2, 0)`, bottom-right
/// `(+s/2, +s/2, 0)`, top-right `(+s/2, −s/2, 0)`, top-left `(−s/2, −s/2, 0)`.
pub fn tag_corners(size_m: f64) -> [Point3<f64>; 4] {
    let h = 0.5 * size_m;
    [
        Point3::new(-h, h, 0.0),
        Point3::new(h, h, 0.0),
        Point3::new(h, -h, 0.0),
        Point3::new(-h, -h, 0.0),
    ]
}

/// The pose of a tag of size `size_m` whose corners (AprilTag's order, pixel centres at
/// integers) are seen at `corners_px` by `camera`: homography start, its flipped twin,
/// Levenberg-Marquardt through the distortion, the lower RMS of the two (see the
/// [module docs](self)). `None` when a corner cannot be undistorted or the undistorted
/// corners are not a convex quadrilateral wound as a tag seen from the front.
pub fn solve_tag_pose(
    camera: &TagCamera,
    size_m: f64,
    corners_px: &[[f64; 2]; 4],
) -> Option<TagPose> {
    let mut normalised = [Vector2::zeros(); 4];
    for (n, c) in normalised.iter_mut().zip(corners_px) {
        *n = camera.undistort(c[0], c[1])?;
    }
    if !is_front_facing_convex(&normalised) {
        return None;
    }
    let (rotation, translation) = homography_pose(&normalised, size_m)?;
    let object = tag_corners(size_m);
    let first = refine_pose(camera, &object, corners_px, rotation, translation);
    let flipped = flipped_rotation(&rotation, &translation)
        .and_then(|r| refine_pose(camera, &object, corners_px, r, translation));
    match (first, flipped) {
        (Some(a), Some(b)) if b.reprojection_rms_px < a.reprojection_rms_px => Some(b),
        (Some(a), _) => Some(a),
        (None, b) => b,
    }
}

/// Whether the undistorted corners form a strictly convex quadrilateral wound as a tag's
/// printed face seen from the front: in [`tag_corners`] order (bottom-left, bottom-right,
/// top-right, top-left) they run counter-clockwise as the image is viewed, so in image
/// coordinates (x right, y down) `e_k × e_(k+1) < 0` for consecutive edges.
fn is_front_facing_convex(normalised: &[Vector2<f64>; 4]) -> bool {
    (0..4).all(|k| {
        let e1 = normalised[(k + 1) % 4] - normalised[k];
        let e2 = normalised[(k + 2) % 4] - normalised[(k + 1) % 4];
        e1.perp(&e2) < -1e-9 * e1.norm() * e2.norm()
    })
}

/// The pose from the homography of the square: DLT of the map from the unit square
/// (corners `(∓1, ±1)` in [`tag_corners`] order) to the normalised corners with `H₃₃ = 1`
/// (exact for four points), then `H ∝ [r1·s/2, r2·s/2, t]`, `r3 = r1 × r2` and the nearest
/// rotation by SVD.
fn homography_pose(
    normalised: &[Vector2<f64>; 4],
    size_m: f64,
) -> Option<(UnitQuaternion<f64>, Vector3<f64>)> {
    const UNIT: [[f64; 2]; 4] = [[-1.0, 1.0], [1.0, 1.0], [1.0, -1.0], [-1.0, -1.0]];
    let mut a = SMatrix::<f64, 8, 8>::zeros();
    let mut b = SVector::<f64, 8>::zeros();
    for (k, ([x, y], n)) in UNIT.iter().zip(normalised).enumerate() {
        let (u, v) = (n.x, n.y);
        a.row_mut(2 * k)
            .copy_from_slice(&[*x, *y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y]);
        a.row_mut(2 * k + 1)
            .copy_from_slice(&[0.0, 0.0, 0.0, *x, *y, 1.0, -v * x, -v * y]);
        b[2 * k] = u;
        b[2 * k + 1] = v;
    }
    let h = a.lu().solve(&b)?;
    let hm = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], 1.0);
    // H = λ·[r1·s/2, r2·s/2, t] with λ·t_z = H₃₃ = 1 > 0, so λ > 0 for a tag in front.
    let (h1, h2, h3) = (hm.column(0), hm.column(1), hm.column(2));
    let scale = (h1.norm() * h2.norm()).sqrt();
    if !(scale.is_finite() && scale > 0.0) {
        return None;
    }
    let (r1, r2) = (h1 / scale, h2 / scale);
    let translation = h3 * (0.5 * size_m / scale);
    let m = Matrix3::from_columns(&[r1, r2, r1.cross(&r2)]);
    Some((nearest_rotation(&m)?, translation))
}

/// The rotation nearest to `m` (Frobenius norm): `U·diag(1, 1, det(U·Vᵀ))·Vᵀ`.
fn nearest_rotation(m: &Matrix3<f64>) -> Option<UnitQuaternion<f64>> {
    let svd = m.svd(true, true);
    let (mut u, v_t) = (svd.u?, svd.v_t?);
    if (u * v_t).determinant() < 0.0 {
        u.column_mut(2).neg_mut();
    }
    let r = u * v_t;
    r.iter().all(|x| x.is_finite()).then(|| {
        UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix_unchecked(r))
    })
}

/// The other pose of the two-fold ambiguity of a planar target: every tag point's offset
/// from the tag centre mirrored along the line of sight `v = t/|t|`, `R·p ↦ (I − 2·v·vᵀ)·R·p`
/// for `p` in the tag plane, i.e. `R' = (I − 2·v·vᵀ)·R·diag(1, 1, −1)` (a proper rotation;
/// its normal is the old one reflected about `v`). The points move only along the line
/// of sight, so under weak perspective both poses image the tag alike, which is why both
/// are local minima at distance. `None` when `t` is zero.
pub fn flipped_rotation(
    rotation: &UnitQuaternion<f64>,
    translation: &Vector3<f64>,
) -> Option<UnitQuaternion<f64>> {
    let v = translation.try_normalize(f64::MIN_POSITIVE)?;
    let mirror = Matrix3::identity() - 2.0 * v * v.transpose();
    let flip = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
    let r = mirror * rotation.to_rotation_matrix().matrix() * flip;
    Some(UnitQuaternion::from_rotation_matrix(
        &nalgebra::Rotation3::from_matrix_unchecked(r),
    ))
}

/// Sum over the corners of the squared pixel reprojection error of the pose, `None`
/// when a corner cannot be projected.
fn reprojection_cost(
    camera: &TagCamera,
    object: &[Point3<f64>; 4],
    corners_px: &[[f64; 2]; 4],
    rotation: &UnitQuaternion<f64>,
    translation: &Vector3<f64>,
) -> Option<f64> {
    let mut cost = 0.0;
    for (p, c) in object.iter().zip(corners_px) {
        let px = camera.project(&(rotation * p.coords + translation))?;
        cost += (px.x - c[0]).powi(2) + (px.y - c[1]).powi(2);
    }
    Some(cost)
}

/// The Gauss-Newton normal equations `(JᵀJ, Jᵀr)` of the corner reprojection errors
/// `r` (px) at the pose `p_cam = R·p_tag + t`, over the update `(δω, δt)` of
/// `p_cam = exp(δω)·R·p_tag + t + δt`; `r = 0` without `corners_px`. `None` when a corner
/// cannot be projected.
fn normal_equations(
    camera: &TagCamera,
    object: &[Point3<f64>; 4],
    corners_px: Option<&[[f64; 2]; 4]>,
    rotation: &UnitQuaternion<f64>,
    translation: &Vector3<f64>,
) -> Option<(Matrix6<f64>, Vector6<f64>)> {
    let mut jtj = Matrix6::<f64>::zeros();
    let mut jtr = Vector6::<f64>::zeros();
    for (k, p) in object.iter().enumerate() {
        let rp = rotation * p.coords;
        let (px, j_proj) = camera.project_with_jacobian(&(rp + translation))?;
        // ∂p_cam/∂δω = −[R·p]×, ∂p_cam/∂δt = I.
        let mut j = SMatrix::<f64, 2, 6>::zeros();
        j.fixed_view_mut::<2, 3>(0, 0)
            .copy_from(&(j_proj * -rp.cross_matrix()));
        j.fixed_view_mut::<2, 3>(0, 3).copy_from(&j_proj);
        jtj += j.transpose() * j;
        if let Some(c) = corners_px {
            jtr += j.transpose() * (px - Vector2::new(c[k][0], c[k][1]));
        }
    }
    Some((jtj, jtr))
}

/// The information `JᵀJ` (px⁻², to be divided by the corner noise variance σ²) of a tag
/// pose solved from its four corners, over the perturbation `(δω, δt)` (rad, m) of
/// `p_cam = exp(δω)·R·p_tag + t + δt` where `camera_from_tag = (R, t)`: to first order
/// the pose's covariance is `σ²·(JᵀJ)⁻¹` (the Cramér-Rao bound, which
/// [`solve_tag_pose`] attains in the tests). Head-on tags have a weak tilt (large
/// rotation variance about the tag's x and y axes). `None` when a corner does not project.
pub fn tag_pose_information(
    camera: &TagCamera,
    size_m: f64,
    camera_from_tag: &Isometry3<f64>,
) -> Option<Matrix6<f64>> {
    let (jtj, _) = normal_equations(
        camera,
        &tag_corners(size_m),
        None,
        &camera_from_tag.rotation,
        &camera_from_tag.translation.vector,
    )?;
    Some(jtj)
}

/// Levenberg-Marquardt (Marquardt's diagonal scaling) on the pixel reprojection error of
/// the four corners through the distortion, over the pose `p_cam = R·p_tag + t` with the
/// update `R ← exp(δω)·R`, `t ← t + δt`. Returns the best pose reached; `None` when the
/// start itself does not project.
fn refine_pose(
    camera: &TagCamera,
    object: &[Point3<f64>; 4],
    corners_px: &[[f64; 2]; 4],
    mut rotation: UnitQuaternion<f64>,
    mut translation: Vector3<f64>,
) -> Option<TagPose> {
    let mut cost = reprojection_cost(camera, object, corners_px, &rotation, &translation)?;
    let mut damping = LM_INITIAL_DAMPING;
    for _ in 0..LM_MAX_ITERATIONS {
        let (jtj, jtr) =
            normal_equations(camera, object, Some(corners_px), &rotation, &translation)?;
        let mut improved = false;
        let mut step_norm = f64::INFINITY;
        while damping <= LM_MAX_DAMPING {
            let mut a = jtj;
            for i in 0..6 {
                a[(i, i)] += damping * jtj[(i, i)].max(f64::MIN_POSITIVE);
            }
            let Some(delta) = a.cholesky().map(|ch| ch.solve(&-jtr)) else {
                damping *= 10.0;
                continue;
            };
            let d_omega = Vector3::new(delta[0], delta[1], delta[2]);
            let d_t = Vector3::new(delta[3], delta[4], delta[5]);
            let cand_rotation = UnitQuaternion::from_scaled_axis(d_omega) * rotation;
            let cand_translation = translation + d_t;
            match reprojection_cost(
                camera,
                object,
                corners_px,
                &cand_rotation,
                &cand_translation,
            ) {
                Some(c) if c < cost => {
                    rotation = cand_rotation;
                    translation = cand_translation;
                    cost = c;
                    damping = (damping * 0.1).max(1e-12);
                    improved = true;
                    step_norm = delta.norm();
                    break;
                }
                _ => damping *= 10.0,
            }
        }
        if !improved || step_norm < LM_MIN_STEP || cost == 0.0 {
            break;
        }
    }
    Some(TagPose {
        camera_from_tag: Isometry3::from_parts(Translation3::from(translation), rotation),
        reprojection_rms_px: (cost / 4.0).sqrt(),
    })
}

/// Offset of the logarithmic tone curve AprilTag sees (`TONE_CURVE`), grey levels.
const TONE_CURVE_OFFSET: f64 = 8.0;

/// The tone curve applied to the image AprilTag sees: `g ↦ 255·ln(1 + g/8)/ln(1 + 255/8)`.
///
/// AprilTag classifies each pixel as black or white against the midpoint of the darkest
/// and brightest grey within a few pixels (its 4×4-pixel tiles and their neighbours, in
/// the decimated image). A shaded board against a bright sky then loses its white
/// border to "black" wherever the sky is within reach (white 110, black 24, sky 212 in
/// the simulator's back-lit boards: threshold 118), and the tag is missed unless its
/// border is wider than that reach. The log curve compresses the highlights, so the
/// midpoint falls below the white of the border (4.77 > 4.52 on `ln(g + 8)` even against
/// a saturated sky). It moves blurred edges towards their dark side, which is why
/// [`refine_corners`] re-measures them on the original image.
static TONE_CURVE: LazyLock<[u8; 256]> = LazyLock::new(|| {
    let scale = 255.0 / (255.0 / TONE_CURVE_OFFSET).ln_1p();
    std::array::from_fn(|g| ((g as f64 / TONE_CURVE_OFFSET).ln_1p() * scale).round() as u8)
});

/// sRGB-encoded grey level → linear intensity (IEC 61966-2-1), for edge positions that
/// do not depend on the encoding.
static SRGB_TO_LINEAR: LazyLock<[f32; 256]> = LazyLock::new(|| {
    std::array::from_fn(|g| {
        let c = g as f64 / 255.0;
        let linear = if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        };
        linear as f32
    })
});

/// Half-width of the search for an edge across a detected tag edge, px (at most half a
/// cell of the tag, so neither the data cells nor the board's outer edge are reached).
const EDGE_SEARCH_PX: f64 = 2.0;

/// Step of the edge profile, px.
const EDGE_STEP_PX: f64 = 0.25;

/// Part of each edge left out at either end (the corners, where two edges meet).
const EDGE_END_MARGIN: f64 = 0.12;

/// An edge sample is used when its contrast is at least this fraction of the median
/// contrast of its edge (occluders, glare).
const EDGE_MIN_RELATIVE_CONTRAST: f64 = 0.5;

/// Fewest edge samples a fitted line needs.
const EDGE_MIN_SAMPLES: usize = 5;

/// A re-measured corner farther than this from AprilTag's means a failed refinement, px.
const MAX_CORNER_SHIFT_PX: f64 = 1.5;

/// Grey level at `(x, y)` (pixel centres at integers), bilinear, through `lut`; `None`
/// outside the image.
fn bilinear(image: &GrayImage, lut: &[f32; 256], x: f64, y: f64) -> Option<f64> {
    let (x0, y0) = (x.floor(), y.floor());
    if !(x0 >= 0.0 && y0 >= 0.0) {
        return None;
    }
    let (ix, iy) = (x0 as usize, y0 as usize);
    if ix + 1 >= image.width() || iy + 1 >= image.height() {
        return None;
    }
    let (fx, fy) = (x - x0, y - y0);
    let at = |dx: usize, dy: usize| f64::from(lut[usize::from(image.get(ix + dx, iy + dy))]);
    let top = at(0, 0) + fx * (at(1, 0) - at(0, 0));
    let bottom = at(0, 1) + fx * (at(1, 1) - at(0, 1));
    Some(top + fy * (bottom - top))
}

/// Where the edge crosses the normal through `p` (`n` pointing from the black square
/// out to the white border): the centroid of the positive intensity gradient along
/// `p + t·n`, `|t| ≤ range`, re-centred once. Returns `(t, contrast)`, `None` when no
/// gradient rises outwards or the profile leaves the image.
fn edge_crossing(
    image: &GrayImage,
    lut: &[f32; 256],
    p: &Vector2<f64>,
    n: &Vector2<f64>,
    range: f64,
) -> Option<(f64, f64)> {
    let mut centre = 0.0;
    let mut result = None;
    for _ in 0..2 {
        let (mut sum_g, mut sum_gt) = (0.0, 0.0);
        let steps = (range / EDGE_STEP_PX).round() as i32;
        for k in -steps..=steps {
            let t = centre + f64::from(k) * EDGE_STEP_PX;
            let out = p + n * (t + 0.5);
            let inside = p + n * (t - 0.5);
            let g = bilinear(image, lut, out.x, out.y)? - bilinear(image, lut, inside.x, inside.y)?;
            if g > 0.0 {
                sum_g += g;
                sum_gt += g * t;
            }
        }
        if sum_g.is_nan() || sum_g <= 0.0 {
            return None;
        }
        centre = sum_gt / sum_g;
        if centre.abs() > range {
            return None;
        }
        result = Some((centre, sum_g * EDGE_STEP_PX));
    }
    result
}

/// The straight line `l·(x, y, 1) = 0`, `|(l₀, l₁)| = 1`, through normalised points by
/// total least squares; `None` for fewer than two distinct points.
fn fit_line(points: &[Vector2<f64>]) -> Option<Vector3<f64>> {
    let n = points.len() as f64;
    let mean = points.iter().sum::<Vector2<f64>>() / n;
    let scatter = points
        .iter()
        .map(|p| (p - mean) * (p - mean).transpose())
        .sum::<Matrix2<f64>>();
    let eig = scatter.symmetric_eigen();
    // The normal is the direction of least spread.
    let k = if eig.eigenvalues[0] <= eig.eigenvalues[1] {
        0
    } else {
        1
    };
    let normal = eig.eigenvectors.column(k).into_owned();
    (normal.norm() > 0.5 && eig.eigenvalues[1 - k] > 0.0)
        .then(|| Vector3::new(normal.x, normal.y, -normal.dot(&mean)))
}

/// Re-measures the corners of a detected tag on `image` itself: across each edge of the
/// quad `corners_px` (AprilTag's order, our pixel convention), the sub-pixel crossing of
/// the black-to-white edge at regularly spaced points (centroid of the gradient, on linear
/// intensities: the grey levels are taken as sRGB-encoded, as cameras deliver them, so
/// the midpoint of a blurred edge does not move with the encoding); the crossings are
/// undistorted and a straight line is fitted through each edge's crossings (the tag's
/// edges are straight in space, so straight in the pinhole image, curved in the
/// distorted one); neighbouring lines meet at the corners, which are distorted back.
///
/// `None` (keep the detector's corners) when an edge is shorter than 8 px, has too few
/// clear crossings, or a corner moves farther than 1.5 px (`MAX_CORNER_SHIFT_PX`).
pub fn refine_corners(
    image: &GrayImage,
    camera: &TagCamera,
    corners_px: &[[f64; 2]; 4],
) -> Option<[[f64; 2]; 4]> {
    let lut = &*SRGB_TO_LINEAR;
    let corners = corners_px.map(|[u, v]| Vector2::new(u, v));
    let mut lines = [Vector3::zeros(); 4];
    let mut crossings: Vec<(Vector2<f64>, f64)> = Vec::new();
    let mut normalised = Vec::new();
    for (k, line) in lines.iter_mut().enumerate() {
        let (a, b) = (corners[k], corners[(k + 1) % 4]);
        let length = (b - a).norm();
        if length.is_nan() || length < 8.0 {
            return None;
        }
        let along = (b - a) / length;
        // Outwards: the corners run counter-clockwise as the image is viewed (y down).
        let normal = Vector2::new(-along.y, along.x);
        // Half a cell at most (the black square is 8 cells across).
        let range = EDGE_SEARCH_PX.min(length / 16.0);
        let samples = (length / 2.0).clamp(8.0, 64.0) as usize;
        crossings.clear();
        for i in 0..samples {
            let alpha =
                EDGE_END_MARGIN + (1.0 - 2.0 * EDGE_END_MARGIN) * (i as f64 + 0.5) / samples as f64;
            let p = a + (b - a) * alpha;
            if let Some((t, contrast)) = edge_crossing(image, lut, &p, &normal, range) {
                crossings.push((p + normal * t, contrast));
            }
        }
        let mut contrasts: Vec<f64> = crossings.iter().map(|c| c.1).collect();
        contrasts.sort_by(f64::total_cmp);
        let median = *contrasts.get(contrasts.len() / 2)?;
        normalised.clear();
        for (p, contrast) in &crossings {
            if *contrast >= EDGE_MIN_RELATIVE_CONTRAST * median {
                normalised.push(camera.undistort(p.x, p.y)?);
            }
        }
        if normalised.len() < EDGE_MIN_SAMPLES {
            return None;
        }
        *line = fit_line(&normalised)?;
    }
    let mut refined = [[0.0; 2]; 4];
    for (k, out) in refined.iter_mut().enumerate() {
        // Corner k ends edge k − 1 and starts edge k.
        let h = lines[(k + 3) % 4].cross(&lines[k]);
        if h.z.is_nan() || h.z.abs() <= f64::MIN_POSITIVE {
            return None;
        }
        let px = camera.project(&Vector3::new(h.x / h.z, h.y / h.z, 1.0))?;
        let shift = (px.coords - corners[k]).norm();
        if shift.is_nan() || shift > MAX_CORNER_SHIFT_PX {
            return None;
        }
        *out = [px.x, px.y];
    }
    Some(refined)
}

/// What AprilTag reports of one detection, corners still in its pixel convention.
#[derive(Clone, Copy, Debug)]
struct RawDetection {
    id: u32,
    hamming: u32,
    decision_margin: f32,
    corners: [[f64; 2]; 4],
}

/// Finds tag36h11 tags in grey images and solves their poses ([`TagDetector::detect`]).
///
/// Holds only its settings and a scratch list; the C detector lives in a per-thread cache
/// (see the [module docs](self)), so this type is `Send + Sync`.
#[derive(Clone, Debug)]
pub struct TagDetector {
    cfg: TagConfig,
    raw: Vec<RawDetection>,
}

impl TagDetector {
    /// A detector with the checked settings `cfg`.
    pub fn new(cfg: TagConfig) -> Result<TagDetector, ConfigError> {
        cfg.validate()?;
        Ok(TagDetector {
            cfg,
            raw: Vec::new(),
        })
    }

    /// The settings.
    pub fn config(&self) -> &TagConfig {
        &self.cfg
    }

    /// Every accepted sighting in `image` seen by `camera`, sorted by id (sightings of one
    /// id in AprilTag's order); the same image always gives the same sightings.
    ///
    /// Nothing is found when tags are disabled or when the image size differs from the
    /// camera's.
    pub fn detect(&mut self, image: &GrayImage, camera: &TagCamera) -> Vec<TagSighting> {
        let mut out = Vec::new();
        let (w, h) = (image.width(), image.height());
        if !self.cfg.enabled
            || w == 0
            || h == 0
            || w != camera.width as usize
            || h != camera.height as usize
        {
            return out;
        }
        self.raw.clear();
        APRILTAG.with_borrow_mut(|cache| cache.detect(&self.cfg, image, &mut self.raw));
        for d in &self.raw {
            if d.hamming > self.cfg.max_hamming
                || d.decision_margin.is_nan()
                || d.decision_margin < self.cfg.min_decision_margin
            {
                continue;
            }
            let apriltag_px = d.corners.map(|[u, v]| [u - 0.5, v - 0.5]);
            let corners_px = match self.cfg.refine_corners {
                true => refine_corners(image, camera, &apriltag_px).unwrap_or(apriltag_px),
                false => apriltag_px,
            };
            let Some(pose) = solve_tag_pose(camera, self.cfg.size_m, &corners_px) else {
                continue;
            };
            if pose.camera_from_tag.translation.vector.norm() > self.cfg.max_distance_m
                || pose.reprojection_rms_px.is_nan()
                || pose.reprojection_rms_px > self.cfg.max_reprojection_px
            {
                continue;
            }
            out.push(TagSighting {
                id: d.id,
                camera_from_tag: pose.camera_from_tag,
                corners_px,
                reprojection_rms_px: pose.reprojection_rms_px,
                decision_margin: d.decision_margin,
                hamming: d.hamming,
            });
        }
        out.sort_by_key(|s| s.id);
        out
    }
}

/// Alignment of the rows of AprilTag's image buffer (its `image_u8_create` default).
const APRILTAG_ROW_ALIGNMENT: usize = 96;

thread_local! {
    /// This thread's AprilTag detectors and image buffer (see the module docs).
    static APRILTAG: RefCell<AprilTagCache> = const {
        RefCell::new(AprilTagCache { detectors: Vec::new(), image: None })
    };
}

/// One thread's C detectors, one per number of correctable bits, and the image buffer
/// they read.
struct AprilTagCache {
    detectors: Vec<(u32, apriltag::Detector)>,
    image: Option<apriltag::Image>,
}

impl AprilTagCache {
    /// Runs AprilTag with `cfg` on `image`, appending what it reports to `out`. Reports
    /// nothing if the C library cannot allocate its detector or buffer.
    fn detect(&mut self, cfg: &TagConfig, image: &GrayImage, out: &mut Vec<RawDetection>) {
        let index = match self
            .detectors
            .iter()
            .position(|(bits, _)| *bits == cfg.max_hamming)
        {
            Some(i) => i,
            None => {
                let Ok(mut detector) = apriltag::DetectorBuilder::new()
                    .add_family_bits(apriltag::Family::tag_36h11(), cfg.max_hamming as usize)
                    .build()
                else {
                    return;
                };
                // One thread: no worker pool, and the same result on every run.
                detector.set_thread_number(1);
                self.detectors.push((cfg.max_hamming, detector));
                self.detectors.len() - 1
            }
        };
        let (w, h) = (image.width(), image.height());
        if self
            .image
            .as_ref()
            .is_none_or(|im| im.width() != w || im.height() != h)
        {
            self.image = apriltag::Image::zeros_with_alignment(w, h, APRILTAG_ROW_ALIGNMENT).ok();
        }
        let Some(buffer) = self.image.as_mut() else {
            return;
        };
        let stride = buffer.stride();
        let tone = &*TONE_CURVE;
        for (y, row) in buffer.as_slice_mut().chunks_exact_mut(stride).enumerate() {
            for (out, &g) in row[..w].iter_mut().zip(image.row(y)) {
                *out = tone[usize::from(g)];
            }
        }
        let (_, detector) = &mut self.detectors[index];
        detector.set_decimation(cfg.decimation);
        out.extend(detector.detect(buffer).iter().map(|d| RawDetection {
            id: d.id() as u32,
            hamming: d.hamming() as u32,
            decision_margin: d.decision_margin(),
            corners: d.corners(),
        }));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// A ZED X Mini-like wide camera at 960×540 (110° HFOV, k1 = −0.05, k2 = 0.01) with a
    /// little decentring so every term is exercised.
    fn camera() -> TagCamera {
        TagCamera {
            fx: 357.8,
            fy: 357.8,
            cx: 479.5,
            cy: 269.5,
            d: [-0.05, 0.01, 2e-4, -1e-4, 1e-3],
            width: 960,
            height: 540,
        }
    }

    /// A camera at `distance_m` from the tag centre, `yaw_deg` around the tag's vertical
    /// axis off its normal and `pitch_deg` above it, looking at the centre, rolled by
    /// `roll_deg` about its optical axis; returns `camera_from_tag`.
    fn viewpoint(distance_m: f64, yaw_deg: f64, pitch_deg: f64, roll_deg: f64) -> Isometry3<f64> {
        // Tag frame: x right, y down, z into the tag; the viewer is at −z.
        let (yaw, pitch) = (yaw_deg.to_radians(), pitch_deg.to_radians());
        let eye = Vector3::new(
            -distance_m * pitch.cos() * yaw.sin(),
            -distance_m * pitch.sin(),
            -distance_m * pitch.cos() * yaw.cos(),
        );
        // Optical axes in the tag frame: z towards the centre, x level (⟂ tag y), y down.
        let z = (-eye).normalize();
        let x = Vector3::y().cross(&z).normalize();
        let y = z.cross(&x);
        let r = nalgebra::Rotation3::from_basis_unchecked(&[x, y, z]);
        let tag_from_camera = Isometry3::from_parts(
            Translation3::from(eye),
            UnitQuaternion::from_rotation_matrix(&r),
        ) * Isometry3::rotation(Vector3::z() * roll_deg.to_radians());
        tag_from_camera.inverse()
    }

    fn corners_seen(
        cam: &TagCamera,
        camera_from_tag: &Isometry3<f64>,
        size_m: f64,
    ) -> [[f64; 2]; 4] {
        tag_corners(size_m).map(|p| {
            let px = cam
                .project(&(camera_from_tag * p).coords)
                .expect("corner in front");
            [px.x, px.y]
        })
    }

    /// Position error (m) and rotation error (rad) of `got` against `truth`.
    fn pose_error(got: &Isometry3<f64>, truth: &Isometry3<f64>) -> (f64, f64) {
        (
            (got.translation.vector - truth.translation.vector).norm(),
            got.rotation.angle_to(&truth.rotation),
        )
    }

    #[test]
    fn undistort_inverts_the_projection() {
        let cam = camera();
        for i in 0..=20 {
            for j in 0..=12 {
                // Normalised points across and a little beyond the image.
                let n = Vector2::new(-1.5 + 0.15 * f64::from(i), -0.9 + 0.15 * f64::from(j));
                let px = cam
                    .project(&(Vector3::new(n.x, n.y, 1.0) * 2.0))
                    .expect("in the monotonic range");
                let back = cam.undistort(px.x, px.y).expect("invertible");
                assert!((back - n).norm() < 1e-12, "{n:?} -> {px:?} -> {back:?}");
            }
        }
        // Without distortion the inverse is K⁻¹.
        let pinhole = TagCamera {
            d: [0.0; 5],
            ..camera()
        };
        let n = pinhole.undistort(100.0, 50.0).expect("pinhole");
        assert!((n - Vector2::new((100.0 - 479.5) / 357.8, (50.0 - 269.5) / 357.8)).norm() < 1e-15);
        // Strong barrel distortion folds back beyond its turning point (r = 1.054, where
        // r·R = 0.703): refused both ways.
        let barrel = TagCamera {
            d: [-0.3, 0.0, 0.0, 0.0, 0.0],
            ..camera()
        };
        assert!(barrel.radially_monotonic_to(1.0) && !barrel.radially_monotonic_to(1.2));
        assert!(barrel.project(&Vector3::new(1.2, 0.0, 1.0)).is_none());
        assert!(
            barrel
                .undistort(barrel.cx + 0.75 * barrel.fx, barrel.cy)
                .is_none()
        );
        assert!(cam.project(&Vector3::new(0.0, 0.0, -1.0)).is_none());
    }

    #[test]
    fn projection_jacobian_matches_finite_differences() {
        let cam = camera();
        for p in [
            Vector3::new(0.3, -0.2, 1.5),
            Vector3::new(-1.0, 0.4, 1.1),
            Vector3::new(0.05, 0.6, 0.7),
        ] {
            let (px, j) = cam.project_with_jacobian(&p).expect("in front");
            assert_eq!(px, cam.project(&p).expect("in front").coords);
            let h = 1e-6;
            for k in 0..3 {
                let mut dp = Vector3::zeros();
                dp[k] = h;
                let plus = cam.project(&(p + dp)).expect("in front").coords;
                let minus = cam.project(&(p - dp)).expect("in front").coords;
                let numeric = (plus - minus) / (2.0 * h);
                let analytic = j.column(k);
                assert!(
                    (numeric - analytic).norm() < 1e-5 * (1.0 + analytic.norm()),
                    "column {k} at {p:?}: {numeric:?} vs {analytic:?}"
                );
            }
        }
    }

    /// Frontal, oblique (40° and 60°), from above and rolled, near and far.
    const VIEWS: [(f64, f64, f64, f64); 7] = [
        (1.5, 0.0, 0.0, 0.0),
        (1.2, 40.0, 0.0, 0.0),
        (1.5, -40.0, 10.0, 15.0),
        (2.5, 60.0, -20.0, -30.0),
        (0.8, 20.0, 30.0, 170.0),
        (3.0, 5.0, 5.0, 90.0),
        (1.0, 0.0, 50.0, 0.0),
    ];

    #[test]
    fn the_pose_is_recovered_exactly_from_noise_free_corners() {
        let cam = camera();
        let size = 0.3;
        for &(d, yaw, pitch, roll) in &VIEWS {
            let truth = viewpoint(d, yaw, pitch, roll);
            let corners = corners_seen(&cam, &truth, size);
            let pose = solve_tag_pose(&cam, size, &corners).expect("solved");
            let (dt, dr) = pose_error(&pose.camera_from_tag, &truth);
            assert!(
                dt < 1e-9 && dr < 1e-9 && pose.reprojection_rms_px < 1e-9,
                "view {:?}: {dt:e} m, {dr:e} rad, rms {:e} px",
                (d, yaw, pitch, roll),
                pose.reprojection_rms_px
            );
        }
    }

    /// The RMS position (m) and rotation (rad) errors that corner noise `sigma_px` causes
    /// to first order: `σ²·(JᵀJ)⁻¹` at the true pose (the Cramér-Rao bound).
    fn predicted_rms(
        cam: &TagCamera,
        truth: &Isometry3<f64>,
        size_m: f64,
        sigma_px: f64,
    ) -> (f64, f64) {
        let information = tag_pose_information(cam, size_m, truth).expect("in front");
        let cov = information.try_inverse().expect("observable") * sigma_px.powi(2);
        let rot: f64 = (0..3).map(|i| cov[(i, i)]).sum();
        let pos: f64 = (3..6).map(|i| cov[(i, i)]).sum();
        (pos.sqrt(), rot.sqrt())
    }

    #[test]
    fn the_pose_from_corners_with_0_3_px_noise_is_within_its_expected_error() {
        let cam = camera();
        let size = 0.3;
        let sigma = 0.3;
        let noise = Normal::new(0.0, sigma).expect("valid σ");
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        for view in [
            (1.0, 0.0, 0.0, 0.0),
            (1.5, 0.0, 0.0, 0.0),
            (2.5, 0.0, 0.0, 0.0),
            (1.5, 20.0, 0.0, 0.0),
            (1.2, 40.0, 0.0, 0.0),
            (2.5, 30.0, 10.0, 20.0),
            (3.0, 40.0, 0.0, 0.0),
        ] {
            let truth = viewpoint(view.0, view.1, view.2, view.3);
            let clean = corners_seen(&cam, &truth, size);
            let trials = 400;
            let (mut sum_dt2, mut sum_dr2, mut sum_rms2) = (0.0, 0.0, 0.0);
            for _ in 0..trials {
                let noisy =
                    clean.map(|[u, v]| [u + noise.sample(&mut rng), v + noise.sample(&mut rng)]);
                let pose = solve_tag_pose(&cam, size, &noisy).expect("solved");
                let (dt, dr) = pose_error(&pose.camera_from_tag, &truth);
                sum_dt2 += dt * dt;
                sum_dr2 += dr * dr;
                sum_rms2 += pose.reprojection_rms_px.powi(2);
            }
            let n = f64::from(trials);
            let (dt, dr, rms) = (
                (sum_dt2 / n).sqrt(),
                (sum_dr2 / n).sqrt(),
                (sum_rms2 / n).sqrt(),
            );
            let (dt_bound, dr_bound) = predicted_rms(&cam, &truth, size, sigma);
            println!(
                "view {view:?}: RMS {dt:.4} m ({dt_bound:.4} predicted), {:.3} deg ({:.3}), \
                 reprojection {rms:.3} px",
                dr.to_degrees(),
                dr_bound.to_degrees()
            );
            // First order holds up to a few degrees; beyond it (a head-on tag at 2.5 m
            // here) the error grows faster than predicted.
            let slack = if dr_bound < 5f64.to_radians() {
                1.2
            } else {
                1.6
            };
            assert!(
                dt < slack * dt_bound && dr < slack * dr_bound,
                "view {view:?}: {dt} m, {dr} rad; predicted {dt_bound} m, {dr_bound} rad"
            );
            // 8 residuals, 6 parameters: E[Σ|r|²] = 2σ², so the RMS over 4 corners is σ/√2.
            assert!(
                (rms - sigma / 2f64.sqrt()).abs() < 0.06,
                "view {view:?}: reprojection RMS {rms} px"
            );
        }
    }

    #[test]
    fn the_flipped_rotation_images_like_the_original_at_distance() {
        let cam = camera();
        let size = 0.3;
        let truth = viewpoint(3.0, 25.0, 10.0, 0.0);
        let (r, t) = (truth.rotation, truth.translation.vector);
        let flipped = flipped_rotation(&r, &t).expect("t ≠ 0");
        // A proper rotation, tilted the other way about the line of sight.
        let v = t.normalize();
        let (n, n_flipped) = (r * Vector3::z(), flipped * Vector3::z());
        assert!((n_flipped - (2.0 * n.dot(&v) * v - n)).norm() < 1e-12);
        assert!(flipped.angle_to(&r) > 0.5);
        // Both image the corners within a pixel of each other at 3 m.
        let other = Isometry3::from_parts(truth.translation, flipped);
        for (a, b) in corners_seen(&cam, &truth, size)
            .iter()
            .zip(corners_seen(&cam, &other, size))
        {
            assert!((a[0] - b[0]).hypot(a[1] - b[1]) < 1.5, "{a:?} vs {b:?}");
        }
        // Head-on, there is no second pose.
        let frontal = viewpoint(2.0, 0.0, 0.0, 0.0);
        let same = flipped_rotation(&frontal.rotation, &frontal.translation.vector).expect("t ≠ 0");
        assert!(same.angle_to(&frontal.rotation) < 1e-12);
        // Started at the wrong twin, the solver still ends at the truth.
        let corners = corners_seen(&cam, &truth, size);
        let object = tag_corners(size);
        let wrong = refine_pose(&cam, &object, &corners, flipped, t).expect("refined");
        let right = solve_tag_pose(&cam, size, &corners).expect("solved");
        assert!(right.reprojection_rms_px <= wrong.reprojection_rms_px);
        assert!(pose_error(&right.camera_from_tag, &truth).1 < 1e-9);
    }

    #[test]
    fn degenerate_corners_give_no_pose() {
        let cam = camera();
        let line = [
            [100.0, 100.0],
            [200.0, 100.0],
            [300.0, 100.0],
            [400.0, 100.0],
        ];
        assert!(solve_tag_pose(&cam, 0.3, &line).is_none());
        let nan = [[f64::NAN, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
        assert!(solve_tag_pose(&cam, 0.3, &nan).is_none());
        // The back of a tag (mirrored corners) and a self-crossing quad.
        let truth = viewpoint(1.5, 20.0, 0.0, 0.0);
        let c = corners_seen(&cam, &truth, 0.3);
        assert!(solve_tag_pose(&cam, 0.3, &c).is_some());
        assert!(solve_tag_pose(&cam, 0.3, &[c[1], c[0], c[3], c[2]]).is_none());
        assert!(solve_tag_pose(&cam, 0.3, &[c[0], c[2], c[1], c[3]]).is_none());
    }

    #[test]
    fn the_camera_comes_from_camera_info() {
        let info = CameraInfoMsg {
            stamp: vinebench_msgs::Nanos(0),
            topic: "/side/color/camera_info".into(),
            frame_id: vinebench_msgs::FrameId::new("side_color_optical_frame"),
            width: 640,
            height: 480,
            d: [-0.05, 0.01, 0.001, 0.002, 0.003],
            k: [400.0, 0.0, 319.5, 0.0, 401.0, 239.5, 0.0, 0.0, 1.0],
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: [0.0; 12],
        };
        let cam = TagCamera::from_info(&info);
        assert_eq!(
            cam,
            TagCamera {
                fx: 400.0,
                fy: 401.0,
                cx: 319.5,
                cy: 239.5,
                d: [-0.05, 0.01, 0.001, 0.002, 0.003],
                width: 640,
                height: 480,
            }
        );
    }

    #[test]
    fn config_ranges_are_checked() {
        assert_eq!(TagConfig::default().validate(), Ok(()));
        let bad = [
            TagConfig {
                camera: String::new(),
                ..TagConfig::default()
            },
            TagConfig {
                size_m: 0.0,
                ..TagConfig::default()
            },
            TagConfig {
                size_m: f64::NAN,
                ..TagConfig::default()
            },
            TagConfig {
                decimation: 0.5,
                ..TagConfig::default()
            },
            TagConfig {
                max_hamming: 3,
                ..TagConfig::default()
            },
            TagConfig {
                min_decision_margin: -1.0,
                ..TagConfig::default()
            },
            TagConfig {
                max_distance_m: 0.0,
                ..TagConfig::default()
            },
            TagConfig {
                max_reprojection_px: f64::INFINITY,
                ..TagConfig::default()
            },
        ];
        for cfg in bad {
            assert!(cfg.validate().is_err(), "{cfg:?} accepted");
            assert!(TagDetector::new(cfg).is_err());
        }
        // `[slam.tags]` as TOML: defaults fill what is missing, unknown keys fail.
        let cfg: TagConfig = toml::from_str("size_m = 0.2\ndecimation = 1.0").expect("valid");
        assert_eq!(
            cfg,
            TagConfig {
                size_m: 0.2,
                decimation: 1.0,
                ..TagConfig::default()
            }
        );
        assert!(toml::from_str::<TagConfig>("tag_size = 0.2").is_err());
    }

    #[test]
    fn nothing_is_found_when_disabled_or_the_sizes_differ() {
        let cam = camera();
        let image = GrayImage::new(960, 540);
        let mut off = TagDetector::new(TagConfig {
            enabled: false,
            ..TagConfig::default()
        })
        .expect("valid");
        assert!(off.detect(&image, &cam).is_empty());
        let mut on = TagDetector::new(TagConfig::default()).expect("valid");
        assert!(on.detect(&image, &cam).is_empty());
        assert!(on.detect(&GrayImage::new(640, 480), &cam).is_empty());
    }

    /// Column of each tag36h11 data bit in the 8×8 black-square grid, most significant
    /// bit first (AprilTag 3 `tag36h11_create`).
    const TAG36H11_BIT_X: [usize; 36] = [
        1, 2, 3, 4, 5, 2, 3, 4, 3, 6, 6, 6, 6, 6, 5, 5, 5, 4, 6, 5, 4, 3, 2, 5, 4, 3, 4, 1, 1, 1,
        1, 1, 2, 2, 2, 3,
    ];
    /// Row of each data bit, as [`TAG36H11_BIT_X`].
    const TAG36H11_BIT_Y: [usize; 36] = [
        1, 1, 1, 1, 1, 2, 2, 2, 3, 1, 2, 3, 4, 5, 2, 3, 4, 3, 6, 6, 6, 6, 6, 5, 5, 5, 4, 6, 5, 4,
        3, 2, 5, 4, 3, 4,
    ];
    /// Codes of tag36h11 ids 0 and 1 (AprilTag 3 `tag36h11.c`).
    const TAG36H11_CODES: [u64; 2] = [0x0000000d7e00984b, 0x0000000dda664ca7];

    /// The printed 10×10 cells (`true` = white, `[row][col]` from the top-left) of a
    /// tag36h11 code: white outer ring, black ring, data bits inside.
    fn tag_cells(code: u64) -> [[bool; 10]; 10] {
        let mut cells = [[false; 10]; 10];
        for (r, row) in cells.iter_mut().enumerate() {
            for (c, cell) in row.iter_mut().enumerate() {
                *cell = r == 0 || c == 0 || r == 9 || c == 9;
            }
        }
        for i in 0..36 {
            cells[TAG36H11_BIT_Y[i] + 1][TAG36H11_BIT_X[i] + 1] = (code >> (35 - i)) & 1 == 1;
        }
        cells
    }

    /// Linear intensities of a drawn scene.
    #[derive(Clone, Copy, Debug)]
    struct Shades {
        white: f64,
        black: f64,
        background: f64,
    }

    /// A lit board on a darker background.
    const FRONT_LIT: Shades = Shades {
        white: 0.7,
        black: 0.04,
        background: 0.2,
    };

    /// A board in its own shade against a bright sky (the simulator's back-lit boards:
    /// grey levels 110, 24 and 212).
    const BACK_LIT: Shades = Shades {
        white: 0.155,
        black: 0.009,
        background: 0.66,
    };

    /// sRGB encoding of a linear intensity, as a camera delivers it.
    fn linear_to_srgb(x: f64) -> u8 {
        let c = if x <= 0.0031308 {
            12.92 * x
        } else {
            1.055 * x.powf(1.0 / 2.4) - 0.055
        };
        (c.clamp(0.0, 1.0) * 255.0).round() as u8
    }

    /// A grey image of a tag board (black square `size_m`, one white cell of border) seen
    /// by `cam` at `camera_from_tag`: each pixel near the board integrates 8×8 rays through
    /// the distortion in linear intensity, then is sRGB-encoded.
    fn draw_tag(
        cam: &TagCamera,
        camera_from_tag: &Isometry3<f64>,
        size_m: f64,
        code: u64,
        shades: Shades,
    ) -> GrayImage {
        const SUB: usize = 8;
        let cells = tag_cells(code);
        let tag_from_camera = camera_from_tag.inverse();
        let origin = tag_from_camera.translation.vector;
        let board_m = 1.25 * size_m;
        // Only pixels near the board's projection see it (3 px for the edges' curvature).
        let board_px = tag_corners(board_m).map(|p| {
            cam.project(&(camera_from_tag * p).coords)
                .expect("board in front")
        });
        let lo = board_px
            .iter()
            .fold(Vector2::repeat(f64::INFINITY), |m, p| m.inf(&p.coords))
            - Vector2::repeat(3.0);
        let hi = board_px
            .iter()
            .fold(Vector2::repeat(f64::NEG_INFINITY), |m, p| m.sup(&p.coords))
            + Vector2::repeat(3.0);
        let background = linear_to_srgb(shades.background);
        GrayImage::from_fn(cam.width as usize, cam.height as usize, |x, y| {
            let (xf, yf) = (x as f64, y as f64);
            if xf < lo.x || xf > hi.x || yf < lo.y || yf > hi.y {
                return background;
            }
            let mut sum = 0.0;
            for i in 0..SUB {
                for j in 0..SUB {
                    let u = xf + (i as f64 + 0.5) / SUB as f64 - 0.5;
                    let v = yf + (j as f64 + 0.5) / SUB as f64 - 0.5;
                    let n = cam.undistort(u, v).expect("inside the lens's image circle");
                    let d = tag_from_camera.rotation * Vector3::new(n.x, n.y, 1.0);
                    let t = -origin.z / d.z;
                    let p = origin + d * t;
                    // Board cell of the hit; the background elsewhere.
                    let (bu, bv) = (p.x / board_m + 0.5, p.y / board_m + 0.5);
                    sum += if t > 0.0 && (0.0..1.0).contains(&bu) && (0.0..1.0).contains(&bv) {
                        if cells[(bv * 10.0) as usize][(bu * 10.0) as usize] {
                            shades.white
                        } else {
                            shades.black
                        }
                    } else {
                        shades.background
                    };
                }
            }
            linear_to_srgb(sum / (SUB * SUB) as f64)
        })
    }

    /// The largest distance between `got` and `expected` corners, px.
    fn corner_error(got: &[[f64; 2]; 4], expected: &[[f64; 2]; 4]) -> f64 {
        got.iter()
            .zip(expected)
            .map(|(a, b)| (a[0] - b[0]).hypot(a[1] - b[1]))
            .fold(0.0, f64::max)
    }

    #[test]
    fn a_drawn_tag_is_detected_at_its_pose() {
        let cam = camera();
        let size = 0.3;
        let mut detector = TagDetector::new(TagConfig::default()).expect("valid");
        for (id, view, shades) in [
            (0u32, (1.2, 0.0, 0.0, 0.0), FRONT_LIT),
            (1, (1.5, 35.0, -10.0, 160.0), FRONT_LIT),
            (0, (2.0, 0.0, 0.0, 0.0), BACK_LIT),
            (1, (2.5, 40.0, 10.0, 5.0), BACK_LIT),
        ] {
            let truth = viewpoint(view.0, view.1, view.2, view.3);
            let image = draw_tag(&cam, &truth, size, TAG36H11_CODES[id as usize], shades);
            let sightings = detector.detect(&image, &cam);
            assert_eq!(
                sightings.iter().map(|s| s.id).collect::<Vec<_>>(),
                vec![id],
                "view {view:?}, {shades:?}"
            );
            let s = &sightings[0];
            let (dt, dr) = pose_error(&s.camera_from_tag, &truth);
            let corner_err = corner_error(&s.corners_px, &corners_seen(&cam, &truth, size));
            println!(
                "id {id} view {view:?}: {:.2} mm, {:.3} deg, corners within {corner_err:.3} px, \
                 RMS {:.3} px, margin {}",
                dt * 1e3,
                dr.to_degrees(),
                s.reprojection_rms_px,
                s.decision_margin
            );
            assert!(
                corner_err < 0.1,
                "view {view:?}: corners off by {corner_err} px"
            );
            assert!(
                dt < 0.005 && dr < 0.2f64.to_radians(),
                "view {view:?}: {dt} m, {dr} rad"
            );
            assert_eq!(s.hamming, 0);
        }
    }

    #[test]
    fn refined_corners_land_on_the_drawn_edges() {
        let cam = camera();
        let size = 0.3;
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let offset = Normal::new(0.0, 0.4).expect("valid σ");
        for (view, shades) in [
            ((1.0, -50.0, 20.0, 30.0), FRONT_LIT),
            ((2.5, 40.0, 10.0, 5.0), BACK_LIT),
        ] {
            let truth = viewpoint(view.0, view.1, view.2, view.3);
            let image = draw_tag(&cam, &truth, size, TAG36H11_CODES[0], shades);
            let exact = corners_seen(&cam, &truth, size);
            // Corners off by about 0.4 px, as a detector's may be.
            let rough =
                exact.map(|[u, v]| [u + offset.sample(&mut rng), v + offset.sample(&mut rng)]);
            let refined = refine_corners(&image, &cam, &rough).expect("clear edges");
            let err = corner_error(&refined, &exact);
            assert!(
                err < 0.05,
                "view {view:?}: {err} px (from {} px)",
                corner_error(&rough, &exact)
            );
        }
        // Nothing to refine on a blank image or a tiny quad.
        let blank = GrayImage::new(960, 540);
        let quad = [
            [400.0, 300.0],
            [500.0, 300.0],
            [500.0, 200.0],
            [400.0, 200.0],
        ];
        assert!(refine_corners(&blank, &cam, &quad).is_none());
        let tiny = [
            [400.0, 300.0],
            [405.0, 300.0],
            [405.0, 295.0],
            [400.0, 295.0],
        ];
        assert!(refine_corners(&blank, &cam, &tiny).is_none());
    }

    #[test]
    fn the_tone_curve_keeps_a_back_lit_border_white() {
        let tone = &*TONE_CURVE;
        assert_eq!((tone[0], tone[255]), (0, 255));
        assert!(tone.windows(2).all(|w| w[0] <= w[1]));
        // White border 110 and black 24 next to a saturated sky: the border stays above
        // AprilTag's midpoint threshold, which it does not on the raw grey levels.
        let mid = |black: u8, sky: u8| (u16::from(black) + u16::from(sky)) / 2;
        assert!(110 < mid(24, 255));
        assert!(u16::from(tone[110]) > mid(tone[24], tone[255]));
    }

    #[test]
    fn the_detector_can_move_between_threads() {
        fn send_sync<T: Send + Sync>() {}
        send_sync::<TagDetector>();
    }
}
