//! Timing of the feature front-end, for `vinebench bench` (see `crate::bench`, which
//! feeds it a rendered vineyard pair) and for anyone with a pair of images.

use super::ConfigError;
use super::frontend::{FrontEndConfig, StereoFrame, StereoFrontEnd};
use super::image::GrayImage;
use super::motion_ba::{MotionBaConfig, Observation, RigCamera, optimize_pose, retract};
use super::orb::{Features, OrbExtractor};
use super::stereo::{StereoCamera, StereoMatcher, StereoMatches};
use nalgebra::{
    Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector2, Vector3, Vector6,
};
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

/// A rig of a front and a rear camera (752×480, about 93° HFOV, on the body's x axis
/// 0.35 m ahead and behind, 0.45 m up), as the rover's two ZED 2i-like pairs' left lenses.
pub fn synthetic_rig() -> Vec<RigCamera> {
    // Optical axes (x right, y down, z forward) as columns in the body frame.
    let front = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[
        -Vector3::y(),
        -Vector3::z(),
        Vector3::x(),
    ]));
    let rear = Rotation3::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI) * front;
    let camera = |x: f64, rotation: Rotation3<f64>| RigCamera {
        fx: 360.0,
        fy: 362.0,
        cx: 376.0,
        cy: 240.0,
        body_from_camera: Isometry3::from_parts(
            Translation3::new(x, 0.03, 0.45),
            UnitQuaternion::from_rotation_matrix(&rotation),
        ),
    };
    vec![camera(0.35, front), camera(-0.35, rear)]
}

/// Times motion-only BA on `n` observations of [`synthetic_rig`]'s two cameras (landmarks
/// 2-12 m away, pyramid levels 0-3, every fourth one 20-80 px wrong), from a guess 16 cm
/// and 2° off, with the default settings: best of `repeats`, ms, and the inliers found.
pub fn time_motion_ba(n: usize, repeats: usize) -> (f64, usize) {
    let rig = synthetic_rig();
    let truth = Isometry3::from_parts(
        Translation3::new(12.0, -3.5, 0.2),
        UnitQuaternion::from_euler_angles(0.02, -0.03, 0.7),
    );
    // Uniform [0, 1) draws from the noise lattice.
    let u = |i: usize, k: u64| value_noise(i as f64, 0.0, 1.0, k);
    let obs: Vec<Observation> = (0..n)
        .map(|i| {
            let camera = i % rig.len();
            let p_c =
                Vector3::new(1.6 * u(i, 1) - 0.8, u(i, 2) - 0.5, 1.0) * (2.0 + 10.0 * u(i, 3));
            let landmark = truth * (rig[camera].body_from_camera * Point3::from(p_c));
            let mut pixel = rig[camera].project(&p_c).unwrap_or_default();
            if i % 4 == 1 {
                let angle = std::f64::consts::TAU * u(i, 4);
                pixel += Vector2::new(angle.cos(), angle.sin()) * (20.0 + 60.0 * u(i, 5));
            }
            Observation {
                camera,
                landmark_in_world: landmark.coords,
                pixel,
                level: (4.0 * u(i, 6)) as u8,
            }
        })
        .collect();
    let guess = retract(&Vector6::new(0.02, -0.015, 0.03, 0.15, -0.1, 0.05), &truth);
    let cfg = MotionBaConfig::default();
    let mut inliers = 0;
    let ms = best_ms(repeats, || {
        inliers = optimize_pose(&rig, black_box(&obs), &guess, &cfg).map_or(0, |e| e.n_inliers);
    });
    (ms, inliers)
}

/// Times global bundle adjustment ([`bundle_adjust`](super::bundle::bundle_adjust) with
/// [`BundleConfig::global`](super::bundle::BundleConfig::global)) after a loop closure:
/// `n_keyframes` keyframes of [`synthetic_rig`] 0.5 m apart along a vine row, each
/// adding `landmarks_per_keyframe` landmarks on the row's walls (±1.2 m) 1.5-6.5 m ahead,
/// observed by every keyframe camera that sees them within 6 m (stereo within 5 m, 0.12 m
/// baseline; ±0.5 px of pixel noise). The map starts drifted as a visual odometry leaves
/// it (0.1°/m of heading, 1 % of scale, 1 cm/m sideways: 5° of heading and 1.25 m RMS of
/// position after 100 keyframes; each landmark placed by the keyframe that created it),
/// with the first and last keyframes fixed at their true poses, as a tag loop closure
/// provides. Returns the seconds of one run and the number of observations.
pub fn time_global_ba(n_keyframes: usize, landmarks_per_keyframe: usize) -> (f64, usize) {
    use super::bundle::{BaKeyFrame, BaLandmark, BaObservation, BundleConfig, bundle_adjust};
    let rig = synthetic_rig();
    let n = n_keyframes.max(2);
    let spacing = 0.5;
    let truth: Vec<Isometry3<f64>> = (0..n)
        .map(|k| {
            let s = spacing * k as f64;
            Isometry3::from_parts(
                Translation3::new(s, 0.05 * (0.35 * s).sin(), 0.0),
                UnitQuaternion::from_euler_angles(0.0, 0.0, 0.03 * (0.25 * s).sin()),
            )
        })
        .collect();
    let u = |i: usize, k: u64| value_noise(i as f64, 0.0, 1.0, k);
    let mut points = Vec::with_capacity(n * landmarks_per_keyframe);
    let mut creator = Vec::with_capacity(n * landmarks_per_keyframe);
    for (k, pose) in truth.iter().enumerate() {
        for m in 0..landmarks_per_keyframe {
            let i = points.len();
            let side = if m % 2 == 0 { 1.0 } else { -1.0 };
            let p_b = Vector3::new(
                1.5 + 5.0 * u(i, 11),
                side * (1.2 + 0.3 * u(i, 12) - 0.15),
                0.2 + 1.6 * u(i, 13) - 0.45,
            );
            points.push((pose * Point3::from(p_b)).coords);
            creator.push(k);
        }
    }
    let mut observations = Vec::new();
    for (keyframe, pose) in truth.iter().enumerate() {
        for (camera, cam) in rig.iter().enumerate() {
            let camera_from_world = (pose * cam.body_from_camera).inverse();
            for (landmark, x) in points.iter().enumerate() {
                let p_c = (camera_from_world * Point3::from(*x)).coords;
                if !(0.5..6.0).contains(&p_c.z) {
                    continue;
                }
                let Some(px) = cam.project(&p_c) else {
                    continue;
                };
                if !(0.0..752.0).contains(&px.x) || !(0.0..480.0).contains(&px.y) {
                    continue;
                }
                let j = observations.len();
                let noise = |k: u64| u(j, k) - 0.5;
                observations.push(BaObservation {
                    keyframe,
                    landmark,
                    camera,
                    pixel: px + Vector2::new(noise(21), noise(22)),
                    level: (4.0 * u(j, 23)) as u8,
                    right_x: (p_c.z < 5.0).then(|| px.x - cam.fx * 0.12 / p_c.z + noise(24)),
                    baseline_m: 0.12,
                });
            }
        }
    }
    // The drifted odometry.
    let mut drifted = vec![truth[0]];
    for k in 1..n {
        let step = truth[k - 1].inverse() * truth[k];
        let len = step.translation.vector.norm();
        let mut bad = step;
        bad.translation.vector =
            step.translation.vector * 1.01 + Vector3::new(0.0, 0.01 * len, 0.0);
        let turn = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.1f64.to_radians() * len);
        drifted.push(drifted[k - 1] * bad * Isometry3::from_parts(Translation3::identity(), turn));
    }
    let keyframes: Vec<BaKeyFrame> = (0..n)
        .map(|k| {
            let fixed = k == 0 || k + 1 == n;
            BaKeyFrame {
                world_from_body: if fixed { truth[k] } else { drifted[k] },
                fixed,
            }
        })
        .collect();
    let landmarks: Vec<BaLandmark> = points
        .iter()
        .zip(&creator)
        .map(|(x, &k)| BaLandmark {
            position: (drifted[k] * truth[k].inverse() * Point3::from(*x)).coords,
            fixed: false,
        })
        .collect();
    let t0 = Instant::now();
    let result = bundle_adjust(
        &rig,
        &keyframes,
        &landmarks,
        black_box(&observations),
        &BundleConfig::global(),
    );
    let secs = t0.elapsed().as_secs_f64();
    black_box(result.is_ok());
    (secs, observations.len())
}
