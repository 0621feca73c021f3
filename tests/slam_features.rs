//! The SLAM feature front-end on synthetic images with known answers: FAST corners of
//! drawn squares, the adaptive threshold, SSC's covering guarantees, ORB orientation and
//! rotation invariance, stereo depth of a textured plane, the keypoint grid against brute
//! force, and thread-count independence.

// Test helpers panic on failure by design.
#![allow(clippy::unwrap_used)]

use proptest::prelude::*;
use vinebench_onboard::slam::bench::value_noise;
use vinebench_onboard::slam::fast::{self, FastConfig, FastDetector};
use vinebench_onboard::slam::image::{BlurScratch, gaussian_blur7};
use vinebench_onboard::slam::orb::{EDGE, KeyPoint, describe, ic_angle};
use vinebench_onboard::slam::ssc::{SscScratch, ssc};
use vinebench_onboard::slam::{
    FeatureGrid, FrontEndConfig, GrayImage, GridConfig, StereoCamera, StereoFrame, StereoFrontEnd,
    hamming,
};

/// ZED 2i-like rectified pair at 752×480 (93° HFOV), 12 cm baseline.
const FX: f64 = 356.81;
const BASELINE_M: f64 = 0.12;

/// A textured surface's intensity at a real position.
fn texture(x: f64, y: f64, seed: u64) -> u8 {
    let t = 0.6 * value_noise(x, y, 6.0, seed) + 0.4 * value_noise(x, y, 2.7, seed + 1);
    (25.0 + 210.0 * t).round() as u8
}

/// The rectified pair of a fronto-parallel textured plane at `depth_m`: the right image
/// is the left one shifted by the disparity `f·b / z`, sampled from the continuous texture.
fn plane_pair(depth_m: f64, seed: u64) -> (GrayImage, GrayImage) {
    let d = FX * BASELINE_M / depth_m;
    let l = GrayImage::from_fn(752, 480, |x, y| texture(x as f64, y as f64, seed));
    let r = GrayImage::from_fn(752, 480, |x, y| texture(x as f64 + d, y as f64, seed));
    (l, r)
}

fn cam() -> StereoCamera {
    StereoCamera {
        fx: FX,
        baseline_m: BASELINE_M,
    }
}

/// Axis-aligned squares `[x0, x1) × [y0, y1)` of `fg` on `bg`.
fn squares(w: usize, h: usize, bg: u8, boxes: &[([usize; 4], u8)]) -> GrayImage {
    GrayImage::from_fn(w, h, |x, y| {
        boxes
            .iter()
            .find(|(b, _)| (b[0]..b[2]).contains(&x) && (b[1]..b[3]).contains(&y))
            .map_or(bg, |(_, v)| *v)
    })
}

fn corners_of(b: [usize; 4]) -> [(f64, f64); 4] {
    let (x0, y0, x1, y1) = (
        b[0] as f64,
        b[1] as f64,
        b[2] as f64 - 1.0,
        b[3] as f64 - 1.0,
    );
    [(x0, y0), (x1, y0), (x0, y1), (x1, y1)]
}

fn near(p: (f64, f64), q: (f64, f64), tol: f64) -> bool {
    (p.0 - q.0).hypot(p.1 - q.1) <= tol
}

#[test]
fn fast_finds_the_corners_of_drawn_squares_and_nothing_else() {
    let boxes = [
        ([30, 40, 60, 70], 200u8),
        ([100, 30, 140, 52], 190),
        ([120, 90, 151, 131], 20), // a dark square on the grey background
    ];
    let img = squares(200, 150, 90, &boxes);
    let want: Vec<(f64, f64)> = boxes.iter().flat_map(|(b, _)| corners_of(*b)).collect();
    // On a binary image the score is flat along a couple of pixels of each edge next to
    // the corner (every difference is the same), so the kept maximum can sit 2 px from
    // the corner pixel.
    let got: Vec<(f64, f64)> = fast::detect(&img, 20)
        .iter()
        .map(|c| (f64::from(c.x), f64::from(c.y)))
        .collect();
    for w in &want {
        assert!(
            got.iter().any(|g| near(*g, *w, 2.0)),
            "corner {w:?} not found in {got:?}"
        );
    }
    for g in &got {
        assert!(
            want.iter().any(|w| near(*g, *w, 2.0)),
            "spurious corner {g:?}"
        );
    }
    // Straight edges are not corners, so each square yields only a few detections.
    assert!(got.len() <= 2 * want.len(), "{} detections", got.len());

    // A flat image and a smooth ramp (any slope: a line splits the circle in halves, so
    // no 9-arc) have none, even at the low threshold.
    let flat = GrayImage::from_fn(100, 80, |_, _| 128);
    assert!(fast::detect(&flat, 7).is_empty());
    let ramp = GrayImage::from_fn(200, 100, |x, y| {
        (20.0 + 0.9 * x as f64 + 0.4 * y as f64).round() as u8
    });
    let mut blurred = GrayImage::default();
    gaussian_blur7(&ramp, &mut blurred, &mut BlurScratch::default());
    assert!(fast::detect(&blurred, 7).is_empty());
}

#[test]
fn the_adaptive_threshold_finds_low_contrast_corners_where_the_high_one_finds_none() {
    let (w, h, border) = (256, 160, EDGE);
    let det = FastDetector::new(FastConfig::default());
    let cells = det.cells(w, h, border);
    assert!(cells.len() >= 4, "{cells:?}");
    // A strong square in the first cell and a faint one (contrast 12: between the low
    // threshold 7 and the high 20) in the last cell, well inside both.
    let inset = |c: [usize; 4]| [c[0] + 6, c[1] + 6, c[2] - 6, c[3] - 6];
    let (strong, faint) = (inset(cells[0]), inset(cells[cells.len() - 1]));
    // A second faint square shares the strong square's cell: that cell has corners at
    // the high threshold, so it is not searched again and the faint one stays unseen.
    let faint_beside = [strong[2] - 8, strong[3] - 8, strong[2] - 2, strong[3] - 2];
    let strong = [strong[0], strong[1], strong[0] + 12, strong[1] + 12];
    let img = squares(
        w,
        h,
        100,
        &[(strong, 200), (faint, 112), (faint_beside, 112)],
    );
    let run = |cfg: FastConfig| {
        let mut d = FastDetector::new(cfg);
        let mut out = Vec::new();
        d.detect(&img, border, &mut out);
        out.iter()
            .map(|c| (f64::from(c.x), f64::from(c.y)))
            .collect::<Vec<_>>()
    };
    let hits = |pts: &[(f64, f64)], b: [usize; 4]| {
        corners_of(b)
            .iter()
            .filter(|w| pts.iter().any(|p| near(*p, **w, 2.0)))
            .count()
    };
    let high_only = run(FastConfig {
        min_corners_per_cell: 0,
        ..FastConfig::default()
    });
    assert_eq!(hits(&high_only, strong), 4);
    assert_eq!(hits(&high_only, faint), 0, "{high_only:?}");
    let adaptive = run(FastConfig::default());
    assert_eq!(hits(&adaptive, strong), 4);
    assert_eq!(hits(&adaptive, faint), 4, "{adaptive:?}");
    assert_eq!(hits(&adaptive, faint_beside), 0, "{adaptive:?}");
}

/// Random points, strongest first, in a 640×480 image.
fn random_points(n: usize, seed: u64) -> Vec<[f32; 2]> {
    (0..n as u64)
        .map(|i| {
            [
                (value_noise(i as f64 * 7.3, 0.5, 1.0, seed) * 640.0) as f32,
                (value_noise(0.5, i as f64 * 5.1, 1.0, seed + 9) * 480.0) as f32,
            ]
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn ssc_keeps_about_the_target_strongest_first_evenly_spread(
        n in 400usize..3000,
        target in 20usize..400,
        seed in 0u64..1000,
    ) {
        let pts = random_points(n, seed);
        let mut kept = Vec::new();
        let o = ssc(&pts, target, 0.1, 640.0, 480.0, &mut SscScratch::default(), &mut kept);
        // Size within the tolerance band (±10 %, at least ±1).
        let tol = (target as f64 * 0.1).round().max(1.0) as usize;
        prop_assert!(o.within_tolerance);
        prop_assert!(kept.len().abs_diff(target) <= tol, "{} kept of {target}", kept.len());
        // The strongest point is always kept; the order is by strength.
        prop_assert_eq!(kept[0], 0);
        prop_assert!(kept.windows(2).all(|w| w[0] < w[1]));
        // Spread: kept points are more than the square side apart (Chebyshev) ...
        let w = o.width_px as f32;
        let cheb = |a: [f32; 2], b: [f32; 2]| (a[0] - b[0]).abs().max((a[1] - b[1]).abs());
        for (i, &a) in kept.iter().enumerate() {
            for &b in &kept[i + 1..] {
                prop_assert!(cheb(pts[a], pts[b]) > w, "{:?} {:?} w {w}", pts[a], pts[b]);
            }
        }
        // ... and every dropped point is covered by a stronger kept one within 1.5 sides.
        let mut is_kept = vec![false; n];
        kept.iter().for_each(|&k| is_kept[k] = true);
        for d in (0..n).filter(|&d| !is_kept[d]) {
            prop_assert!(
                kept.iter().any(|&k| k < d && cheb(pts[k], pts[d]) < 1.5 * w),
                "dropped {:?} uncovered (w {w})", pts[d]
            );
        }
    }
}

/// A textured patch centred in a 101×101 image, rotated by `theta` (rad, image axes):
/// `I(p) = T(R(−θ)(p − c))`, sampled from the continuous texture (no resampling loss).
/// A bright off-centre blob (its place depends on the seed) gives the patch a clear
/// intensity centroid.
fn rotated_patch(theta: f64, seed: u64, blob_amplitude: f64) -> GrayImage {
    let (s, c) = theta.sin_cos();
    let (bx, by) = (
        6.0 * (seed as f64 * 1.7).cos(),
        6.0 * (seed as f64 * 1.7).sin(),
    );
    GrayImage::from_fn(101, 101, |x, y| {
        let (dx, dy) = (x as f64 - 50.0, y as f64 - 50.0);
        let (u, v) = (c * dx + s * dy, -s * dx + c * dy);
        let blob = blob_amplitude * (-((u - bx).powi(2) + (v - by).powi(2)) / 40.0).exp();
        (f64::from(texture(u + 300.0, v + 300.0, seed)) * 0.8 + blob).min(255.0) as u8
    })
}

fn angle_diff(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(std::f64::consts::TAU);
    d.min(std::f64::consts::TAU - d)
}

#[test]
fn orientation_follows_the_rotation_and_steered_brief_is_rotation_invariant() {
    let mut scratch = BlurScratch::default();
    let mut describe_at_centre = |img: &GrayImage| {
        let angle = ic_angle(img, 50, 50);
        let mut b = GrayImage::default();
        gaussian_blur7(img, &mut b, &mut scratch);
        (f64::from(angle), describe(&b, 50, 50, angle))
    };
    let (a0, d0) = describe_at_centre(&rotated_patch(0.0, 3, 50.0));
    for deg in [30.0f64, 90.0, 135.0, -60.0] {
        let (a, d) = describe_at_centre(&rotated_patch(deg.to_radians(), 3, 50.0));
        let turned = angle_diff(a, a0 + deg.to_radians()).to_degrees();
        assert!(turned < 3.0, "{deg}°: orientation off by {turned:.2}°");
        let dist = hamming(&d0, &d);
        let limit = if deg % 90.0 == 0.0 { 4 } else { 30 };
        assert!(dist <= limit, "{deg}°: Hamming {dist}");
        // Without steering the descriptor would not survive the rotation.
        let mut b = GrayImage::default();
        gaussian_blur7(
            &rotated_patch(deg.to_radians(), 3, 50.0),
            &mut b,
            &mut BlurScratch::default(),
        );
        let unsteered = hamming(&d0, &describe(&b, 50, 50, a0 as f32));
        assert!(
            unsteered > dist + 20,
            "{deg}°: unsteered {unsteered} vs {dist}"
        );
    }
    // Different textures (without the shared blob, which steering would bring to the same
    // place): about half of the bits differ.
    for seed in [11, 12, 13] {
        let (_, d) = describe_at_centre(&rotated_patch(0.0, seed, 0.0));
        let dist = hamming(&d0, &d);
        assert!(dist >= 80, "seed {seed}: Hamming {dist}");
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

#[test]
fn stereo_recovers_the_depth_of_a_textured_plane_and_rejects_far_points() {
    let mut fe = StereoFrontEnd::new(FrontEndConfig::default()).unwrap();
    let mut frame = StereoFrame::default();
    // Within 40 baselines (4.8 m): depths to 1 %.
    for (z, seed) in [(1.7, 5), (3.1, 6)] {
        let (l, r) = plane_pair(z, seed);
        fe.process(&cam(), &l, &r, &mut frame);
        let depths: Vec<f64> = frame
            .stereo
            .depth_m
            .iter()
            .flatten()
            .map(|&d| f64::from(d))
            .collect();
        let n = frame.left.len();
        assert!(n >= 800, "{n} keypoints");
        // SSC picks its points in each image independently, so only about 60 % of the
        // left keypoints have a right counterpart at all.
        assert!(
            depths.len() * 5 >= n * 2,
            "{} depths of {n} keypoints",
            depths.len()
        );
        let m = median(depths.clone());
        eprintln!(
            "z {z}: {} keypoints, {} depths, median {m:.4} m",
            n,
            depths.len()
        );
        assert!((m / z - 1.0).abs() < 0.01, "z {z}: median depth {m}");
        let good = depths
            .iter()
            .filter(|&&d| (d / z - 1.0).abs() < 0.03)
            .count();
        assert!(
            good * 10 >= depths.len() * 8,
            "z {z}: {good} of {} within 3 %",
            depths.len()
        );
    }
    // Beyond 40 baselines: matched (the disparity is right) but given no depth.
    let z = 6.0;
    let (l, r) = plane_pair(z, 7);
    fe.process(&cam(), &l, &r, &mut frame);
    assert_eq!(frame.stereo.n_with_depth(), 0);
    let disparities: Vec<f64> = frame
        .left
        .keypoints
        .iter()
        .zip(&frame.stereo.right_x)
        .filter_map(|(k, r)| r.map(|r| f64::from(k.x - r)))
        .collect();
    assert!(
        disparities.len() * 5 >= frame.left.len() * 2,
        "{} matched",
        disparities.len()
    );
    let want = FX * BASELINE_M / z;
    let m = median(disparities);
    assert!((m / want - 1.0).abs() < 0.01, "disparity {m} vs {want}");
}

#[test]
fn extraction_and_matching_do_not_depend_on_the_thread_count_or_mode() {
    let (l, r) = plane_pair(2.3, 21);
    let run = |threads: usize, serial: bool| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut fe = StereoFrontEnd::new(FrontEndConfig {
                serial,
                ..FrontEndConfig::default()
            })
            .unwrap();
            let mut f = StereoFrame::default();
            fe.process(&cam(), &l, &r, &mut f);
            // Twice: reused buffers must not leak state between frames.
            fe.process(&cam(), &l, &r, &mut f);
            f
        })
    };
    let a = run(1, false);
    assert!(!a.left.is_empty());
    for (threads, serial) in [(2, false), (4, false), (2, true)] {
        let b = run(threads, serial);
        assert_eq!(a.left, b.left);
        assert_eq!(a.right, b.right);
        assert_eq!(a.stereo, b.stereo);
    }
}

#[test]
fn config_tables_reject_unknown_keys_and_fill_defaults() {
    let c: FrontEndConfig =
        toml::from_str("[orb]\nn_levels = 4\n[orb.fast]\nlow_threshold = 5\n").unwrap();
    assert_eq!(c.orb.n_levels, 4);
    assert_eq!(c.orb.fast.low_threshold, 5);
    assert_eq!(c.orb.fast.high_threshold, 20);
    assert_eq!(c.stereo.max_depth_baselines, 40.0);
    assert!(toml::from_str::<FrontEndConfig>("[orb]\nn_level = 4\n").is_err());
    let bad = FrontEndConfig {
        orb: vinebench_onboard::slam::OrbConfig {
            scale_factor: 1.0,
            ..Default::default()
        },
        ..Default::default()
    };
    assert!(StereoFrontEnd::new(bad).is_err());
}

fn kp(x: f32, y: f32, level: u8) -> KeyPoint {
    KeyPoint {
        x,
        y,
        level,
        angle_rad: 0.0,
        response: 1.0,
        size: 31.0,
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    #[test]
    fn grid_queries_equal_a_brute_force_filter(
        pts in prop::collection::vec((-30.0f32..790.0, -30.0f32..520.0, 0u8..8), 0..300),
        queries in prop::collection::vec(
            (-50.0f32..800.0, -50.0f32..530.0, 0.0f32..120.0, 0u8..8, 0u8..8), 1..20),
    ) {
        let kps: Vec<KeyPoint> = pts.iter().map(|&(x, y, l)| kp(x, y, l)).collect();
        let grid = FeatureGrid::build(&GridConfig::default(), 752, 480, &kps);
        for (x, y, r, lo, hi) in queries {
            let want: Vec<usize> = (0..kps.len())
                .filter(|&i| {
                    let k = &kps[i];
                    (k.x - x).abs() < r && (k.y - y).abs() < r && k.level >= lo && k.level <= hi
                })
                .collect();
            prop_assert_eq!(grid.features_in_area(x, y, r, lo, hi), want);
        }
    }
}

/// A rendered vineyard frame pair (the simulator's ray caster, two cameras 12 cm apart
/// along the left camera's x axis): the stereo depths agree with the renderer's depth
/// buffer at the left keypoints.
#[test]
fn stereo_depths_on_a_rendered_vineyard_agree_with_the_depth_buffer() {
    use vinebench_sim::params::RenderBackend;
    use vinebench_sim::render::camera::{BrownConrady, Intrinsics, linear_to_srgb_u8, look_at};
    use vinebench_sim::render::shade::Frame;
    let renderer = vinebench::bench::bench_renderer(4, RenderBackend::Bvh).unwrap();
    let intr = Intrinsics::from_hfov(752, 480, 93.0, BrownConrady::NONE);
    let rays = intr.pixel_rays();
    let left_pose = look_at(
        nalgebra::Vector3::new(10.0, 3.75, 0.7),
        nalgebra::Vector3::new(1.0, 0.2, -0.08),
    );
    let right_pose = left_pose * nalgebra::Translation3::new(BASELINE_M, 0.0, 0.0);
    let render = |pose| {
        let mut f = Frame::new(752, 480);
        renderer.render(&rays, &pose, (1.0 / intr.fx) as f32, 200.0, &mut f);
        let g = f
            .linear
            .chunks_exact(3)
            .map(|c| linear_to_srgb_u8(0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]))
            .collect();
        (GrayImage::from_vec(752, 480, g).unwrap(), f.depth_m)
    };
    let ((left, depth), (right, _)) = (render(left_pose), render(right_pose));
    let cam = StereoCamera {
        fx: intr.fx,
        baseline_m: BASELINE_M,
    };
    let mut fe = StereoFrontEnd::new(FrontEndConfig::default()).unwrap();
    let mut frame = StereoFrame::default();
    fe.process(&cam, &left, &right, &mut frame);
    let mut rel = Vec::new();
    for (k, d) in frame.left.keypoints.iter().zip(&frame.stereo.depth_m) {
        let Some(d) = d else { continue };
        // A corner often sits on a depth edge: compare with the nearest depth of the 3×3
        // neighbourhood (the surface the corner's texture belongs to is in it).
        let (x, y) = (k.x.round() as usize, k.y.round() as usize);
        let truth = (y.saturating_sub(1)..=(y + 1).min(479))
            .flat_map(|yy| (x.saturating_sub(1)..=(x + 1).min(751)).map(move |xx| (xx, yy)))
            .map(|(xx, yy)| f64::from(depth[yy * 752 + xx]))
            .filter(|&t| t > 0.0)
            .map(|t| (f64::from(*d) / t - 1.0).abs())
            .fold(f64::INFINITY, f64::min);
        rel.push(truth);
    }
    let n = frame.left.len();
    let m = median(rel.clone());
    let within = rel.iter().filter(|&&e| e < 0.05).count();
    eprintln!(
        "rendered pair: {n} keypoints, {} depths, median |error| {:.2} %, {within} within 5 %",
        rel.len(),
        100.0 * m
    );
    assert!(n >= 800, "{n} keypoints");
    assert!(rel.len() * 4 >= n, "{} depths of {n}", rel.len());
    assert!(m < 0.01, "median relative depth error {m}");
    assert!(
        within * 10 >= rel.len() * 8,
        "{within} of {} within 5 %",
        rel.len()
    );
}
