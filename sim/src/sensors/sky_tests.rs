use super::*;
use crate::params::GnssSkyParams;
use crate::render::scene::ShadingMesh;
use crate::render::{Affine3, Instance, MeshGeometry, SceneGeometry, TraceScene};
use nalgebra::DMatrix;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// The defaults' origin (scenarios/defaults.toml `[origin]`).
fn origin() -> Geodetic {
    Geodetic {
        lat_deg: 40.4545,
        lon_deg: 17.9085,
        alt_m: 55.0,
    }
}

/// 2021-09-15T09:00:00Z, the defaults' start.
const START_UNIX_S: f64 = 1_631_696_400.0;

#[test]
fn gmst_matches_the_almanac_at_known_epochs() {
    // GMST at 2000-01-01 0 h UT is 6 h 39 m 52.2719 s = 99.967 7966° (Astronomical
    // Almanac); at J2000 (12 h UT) 280.460 618 37° by definition of the formula.
    let at = |unix_s: f64| gmst_rad(unix_s).to_degrees();
    assert!((at(J2000_UNIX_S - 43_200.0) - 99.967_796_6).abs() < 1e-4);
    assert!((at(J2000_UNIX_S) - 280.460_618_37).abs() < 1e-9);
    // One sidereal day (86 164.0905 s) later the Earth has turned once.
    let d = (at(START_UNIX_S + 86_164.090_5) - at(START_UNIX_S)).rem_euclid(360.0);
    assert!(d.min(360.0 - d) < 1e-3, "{d}");
}

/// Two-body acceleration.
fn gravity(r: &Vector3<f64>) -> Vector3<f64> {
    -MU_EARTH * r / r.norm().powi(3)
}

#[test]
fn orbits_follow_the_two_body_equations() {
    // Second method: integrate r¨ = −μ r/|r|³ (RK4, 1 s steps) from each satellite's
    // state at the scenario's start for three hours; the closed-form circular orbit must
    // stay within 1 m (RK4's error here is millimetres).
    let sats = constellation(&[
        GnssSystem::Gps,
        GnssSystem::Galileo,
        GnssSystem::Glonass,
        GnssSystem::Beidou,
    ]);
    assert_eq!(sats.len(), 96);
    for s in sats.iter().step_by(7) {
        let o = &s.orbit;
        let t0 = START_UNIX_S;
        let mut r = o.position_eci(t0);
        // Circular-orbit velocity √(μ/a) along n̂ × r̂, the plane's normal n̂ taken from
        // two positions a quarter period apart.
        let n = r
            .cross(&o.position_eci(t0 + o.period_s() / 4.0))
            .normalize();
        let mut v = (MU_EARTH / o.a_m).sqrt() * n.cross(&r.normalize());
        assert!((r.norm() - o.a_m).abs() < 1e-6 * o.a_m);
        let fd = (o.position_eci(t0 + 1.0) - o.position_eci(t0 - 1.0)) / 2.0;
        assert!((fd - v).norm() < 1e-2, "{}", (fd - v).norm());
        let dt = 1.0;
        for _ in 0..10_800 {
            let k1v = gravity(&r);
            let k1r = v;
            let k2v = gravity(&(r + 0.5 * dt * k1r));
            let k2r = v + 0.5 * dt * k1v;
            let k3v = gravity(&(r + 0.5 * dt * k2r));
            let k3r = v + 0.5 * dt * k2v;
            let k4v = gravity(&(r + dt * k3r));
            let k4r = v + dt * k3v;
            r += dt / 6.0 * (k1r + 2.0 * k2r + 2.0 * k3r + k4r);
            v += dt / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
        }
        let closed = o.position_eci(t0 + 10_800.0);
        assert!(
            (r - closed).norm() < 1.0,
            "{:?} {}: {}",
            s.system,
            s.prn,
            (r - closed).norm()
        );
    }
    // Periods: GPS half a sidereal day to 0.02 %, Galileo 14 h 04 m 45 s to 0.01 %.
    let gps = sats.iter().find(|s| s.system == GnssSystem::Gps).unwrap();
    assert!((gps.orbit.period_s() / 43_082.045 - 1.0).abs() < 2e-4);
    let gal = sats
        .iter()
        .find(|s| s.system == GnssSystem::Galileo)
        .unwrap();
    assert!((gal.orbit.period_s() / 50_685.0 - 1.0).abs() < 1e-4);
    // ECEF: a GPS satellite's latitude never exceeds the inclination.
    let max_lat = (0..2000)
        .map(|i| {
            let p = gps.orbit.position_ecef(START_UNIX_S + 30.0 * f64::from(i));
            (p.z / p.norm()).asin().to_degrees()
        })
        .fold(0.0f64, f64::max);
    assert!(max_lat <= 55.0 + 1e-9 && max_lat > 54.5, "{max_lat}");
}

#[test]
fn dop_of_a_known_geometry_is_the_closed_form() {
    // Zenith plus three satellites on the horizon 120° apart: GᵀG = diag(1.5, 1.5) ⊕
    // [[1, −1], [−1, 4]] (z, clock), so HDOP = VDOP = √(4/3), TDOP = √(1/3),
    // PDOP = √(8/3), GDOP = √3.
    let h = |az: f64| Vector3::new(az.to_radians().sin(), az.to_radians().cos(), 0.0);
    let los = [Vector3::z(), h(0.0), h(120.0), h(240.0)];
    let d = dop(&los).unwrap();
    let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
    assert!(close(d.hdop, (4.0f64 / 3.0).sqrt()), "{d:?}");
    assert!(close(d.vdop, (4.0f64 / 3.0).sqrt()));
    assert!(close(d.tdop, (1.0f64 / 3.0).sqrt()));
    assert!(close(d.pdop, (8.0f64 / 3.0).sqrt()));
    assert!(close(d.gdop, 3f64.sqrt()));
    // Three satellites, or four on one cone (all at the same elevation), give none.
    assert!(dop(&los[..3]).is_none());
    let cone: Vec<_> = (0..6)
        .map(|i| {
            let (az, el) = ((60.0 * f64::from(i)).to_radians(), 30f64.to_radians());
            Vector3::new(az.sin() * el.cos(), az.cos() * el.cos(), el.sin())
        })
        .collect();
    assert!(dop(&cone).is_none());
}

#[test]
fn dop_and_position_error_agree_with_a_pseudo_inverse() {
    // Second method: Q = G⁺G⁺ᵀ with G⁺ from nalgebra's SVD; a consistent set of range
    // errors b = G·x (x: position and clock) is explained exactly by x.
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for n in [4usize, 6, 12] {
        let los: Vec<Vector3<f64>> = (0..n)
            .map(|_| {
                let az = rng.random_range(0.0..std::f64::consts::TAU);
                let el = rng.random_range(0.1..1.5f64);
                Vector3::new(az.sin() * el.cos(), az.cos() * el.cos(), el.sin())
            })
            .collect();
        let g = DMatrix::from_fn(n, 4, |i, j| if j < 3 { -los[i][j] } else { 1.0 });
        let pinv = g.clone().pseudo_inverse(1e-12).unwrap();
        let q = &pinv * pinv.transpose();
        let d = dop(&los).unwrap();
        assert!((d.hdop - (q[(0, 0)] + q[(1, 1)]).sqrt()).abs() < 1e-9);
        assert!((d.vdop - q[(2, 2)].sqrt()).abs() < 1e-9);
        assert!((d.tdop - q[(3, 3)].sqrt()).abs() < 1e-9);
        let x = nalgebra::DVector::from_vec(vec![0.3, -1.2, 2.0, 5.0]);
        let b = &g * &x;
        let e = position_error(&los, b.as_slice()).unwrap();
        assert!((e - Vector3::new(0.3, -1.2, 2.0)).norm() < 1e-9, "{e:?}");
    }
}

/// A quad `[x0, x1] × [y0, y1]` at height `z` (two triangles).
fn quad(m: &mut MeshGeometry, x: [f32; 2], y: [f32; 2], z: f32) {
    let b = m.positions.len() as u32;
    m.positions.extend([
        [x[0], y[0], z],
        [x[1], y[0], z],
        [x[1], y[1], z],
        [x[0], y[1], z],
    ]);
    m.indices.extend([[b, b + 1, b + 2], [b, b + 2, b + 3]]);
}

/// An axis-aligned box (12 triangles).
fn cuboid(lo: [f32; 3], hi: [f32; 3]) -> MeshGeometry {
    let mut m = MeshGeometry::default();
    for i in 0..8u32 {
        m.positions.push([
            if i & 1 == 0 { lo[0] } else { hi[0] },
            if i & 2 == 0 { lo[1] } else { hi[1] },
            if i & 4 == 0 { lo[2] } else { hi[2] },
        ]);
    }
    for [a, b, c, d] in [
        [0, 1, 3, 2],
        [4, 6, 7, 5],
        [0, 4, 5, 1],
        [2, 3, 7, 6],
        [0, 2, 6, 4],
        [1, 5, 7, 3],
    ] {
        m.indices.push([a, b, c]);
        m.indices.push([a, c, d]);
    }
    m
}

/// World offset of the test scene's frame (exercises the world → scene conversion).
const SCENE_ORIGIN: [f64; 3] = [10.0, -5.0, 0.5];
/// The carton (world frame): x 3..5, y −1..2, z 0..4.
const BOX: ([f64; 3], [f64; 3]) = ([3.0, -1.0, 0.0], [5.0, 2.0, 4.0]);
/// Leaf layers (world frame): x −20..−4, y −20..20, at these heights.
const LEAF_Z: [f64; 3] = [3.0, 3.3, 3.6];

/// A scene of one carton and three horizontal leaf layers, as [`SceneGeometry`].
fn test_geometry() -> SceneGeometry {
    let o = Vector3::from(SCENE_ORIGIN);
    let s = |v: [f64; 3]| -> [f32; 3] { std::array::from_fn(|i| (v[i] - o[i]) as f32) };
    let carton = cuboid(s(BOX.0), s(BOX.1));
    let mut leaves = MeshGeometry::default();
    for z in LEAF_Z {
        let c = s([-20.0, -20.0, z]);
        let d = s([-4.0, 20.0, z]);
        quad(&mut leaves, [c[0], d[0]], [c[1], d[1]], c[2]);
    }
    let trace = TraceScene {
        origin_in_world: o,
        meshes: vec![carton, leaves],
        instances: vec![
            Instance {
                mesh: 0,
                scene_from_mesh: Affine3::IDENTITY,
            },
            Instance {
                mesh: 1,
                scene_from_mesh: Affine3::IDENTITY,
            },
        ],
    };
    let shading = |n: usize, m: Material| ShadingMesh {
        materials: vec![m; n],
        ..ShadingMesh::default()
    };
    let scene = RenderScene {
        shading: vec![shading(12, Material::Carton), shading(6, Material::Leaf)],
        normal_from_mesh: vec![[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]; 2],
        instance_tag: vec![u32::MAX; 2],
        tag_ids: vec![],
        caster_bounds: ([0.0; 3], [0.0; 3]),
        grape: crate::params::GrapeColour::Red,
        trace,
    };
    let caster = crate::render::build_default(&scene.trace);
    SceneGeometry { scene, caster }
}

/// Closed form: the ray `p + t·d` (t > 0) meets the box; None when it passes within
/// `margin` of an edge (too close to call in f32).
fn meets_box(p: &Vector3<f64>, d: &Vector3<f64>, margin: f64) -> Option<bool> {
    let (lo, hi) = (Vector3::from(BOX.0), Vector3::from(BOX.1));
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for i in 0..3 {
        if d[i].abs() < 1e-12 {
            if p[i] < lo[i] || p[i] > hi[i] {
                return Some(false);
            }
            continue;
        }
        let (a, b) = ((lo[i] - p[i]) / d[i], (hi[i] - p[i]) / d[i]);
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    if (t1 - t0).abs() * d.norm() < margin {
        return None;
    }
    Some(t0 < t1)
}

#[test]
fn visibility_through_a_known_box_and_leaves_is_the_closed_form() {
    // From an antenna at (0, 0, 1.2), every direction on a 2°×2° grid of the upper
    // hemisphere: blocked exactly when the ray meets the carton (slab test), and the
    // leaves crossed are the layers the ray reaches inside their footprint (plane
    // intersections) unless the carton stops it first.
    let g = test_geometry();
    let p = Vector3::new(0.0, 0.0, 1.2);
    let (mut blocked, mut leafy, mut checked) = (0, 0, 0);
    for el in (1..90).step_by(2) {
        for az in (0..360).step_by(2) {
            let (a, e) = (f64::from(az).to_radians(), f64::from(el).to_radians());
            let d = Vector3::new(a.sin() * e.cos(), a.cos() * e.cos(), e.sin());
            let Some(hit_box) = meets_box(&p, &d, 0.02) else {
                continue;
            };
            let layers: Vec<f64> = LEAF_Z
                .iter()
                .filter_map(|&z| {
                    let t = (z - p.z) / d.z;
                    let q = p + t * d;
                    let inside = (-20.0..=-4.0).contains(&q.x) && (-20.0..=20.0).contains(&q.y);
                    let edge = (q.x + 4.0)
                        .abs()
                        .min((q.x + 20.0).abs())
                        .min((q.y.abs() - 20.0).abs());
                    (inside && edge > 0.02).then_some(t)
                })
                .collect();
            let near_edge = LEAF_Z.iter().any(|&z| {
                let q = p + (z - p.z) / d.z * d;
                (q.x + 4.0).abs() < 0.02 && q.y.abs() < 20.0
            });
            if near_edge {
                continue;
            }
            let s = g.sight(&p, &d);
            checked += 1;
            assert_eq!(s.blocked, hit_box, "az {az} el {el}");
            if !hit_box {
                assert_eq!(usize::from(s.leaves), layers.len(), "az {az} el {el}");
            }
            blocked += usize::from(s.blocked);
            leafy += usize::from(s.leaves > 0);
        }
    }
    assert!(
        checked > 7000 && blocked > 100 && leafy > 500,
        "{checked} {blocked} {leafy}"
    );
}

fn sky_params() -> GnssSkyParams {
    GnssSkyParams {
        enabled: true,
        ..GnssSkyParams::default()
    }
}

/// Open sky.
struct Clear;
impl LineOfSight for Clear {
    fn sight(&self, _: &Vector3<f64>, _: &Vector3<f64>) -> Sight {
        Sight::default()
    }
}

/// Independent expectation of the long-run mean number of satellites of one circular
/// constellation above `mask_deg` from latitude `lat_deg` (spherical Earth): the
/// satellites' phases and the Earth's rotation make the argument of latitude and the
/// node's longitude relative to the receiver uniform, so the mean is `count` times the
/// fraction of that torus above the mask (midpoint rule, 360 × 360).
fn mean_visible(count: f64, a_m: f64, inc_deg: f64, lat_deg: f64, mask_deg: f64) -> f64 {
    let (r, n) = (6_371_000.0, 360);
    let (inc, lat) = (inc_deg.to_radians(), lat_deg.to_radians());
    let up = Vector3::new(lat.cos(), 0.0, lat.sin());
    let mut seen = 0usize;
    for i in 0..n {
        let u = std::f64::consts::TAU * (i as f64 + 0.5) / n as f64;
        for j in 0..n {
            let node = std::f64::consts::TAU * (j as f64 + 0.5) / n as f64;
            let (su, cu) = u.sin_cos();
            let (so, co) = node.sin_cos();
            let sat = a_m
                * Vector3::new(
                    co * cu - so * su * inc.cos(),
                    so * cu + co * su * inc.cos(),
                    su * inc.sin(),
                );
            let d = (sat - r * up).normalize();
            seen += usize::from(d.dot(&up) >= mask_deg.to_radians().sin());
        }
    }
    count * seen as f64 / (n * n) as f64
}

#[test]
fn open_sky_at_the_origin_sees_what_the_orbits_allow() {
    // Over a day at 40.45° N with a 10° mask, the mean number of satellites tracked
    // matches the long-run expectation of the four reference constellations (GPS 6.7,
    // Galileo 7.0, GLONASS and BeiDou from the same integral) within 4 %; at least 20 at
    // any time, HDOP below 0.8 throughout; every epoch RTK fixed (the receiver was on
    // before the run).
    let cfg = SkyConfig::new(&sky_params()).unwrap();
    let mut sky = SkyState::new(cfg, 60.0, ChaCha8Rng::seed_from_u64(1));
    let (mut counts, mut hdops) = (Vec::new(), Vec::new());
    for i in 0..1440 {
        let t = Nanos::from_secs_f64(START_UNIX_S + 60.0 * f64::from(i));
        let e = sky.epoch(t, &origin(), &Vector3::zeros(), &Clear, FixStatus::RtkFixed);
        counts.push(e.satellites.iter().filter(|s| s.used).count());
        hdops.push(e.dop.unwrap().hdop);
        assert_eq!(e.status, FixStatus::RtkFixed, "minute {i}");
        assert_eq!(e.multipath, Vector3::zeros());
        for s in &e.satellites {
            assert_eq!(s.tracked, s.elevation_deg >= 10.0, "{s:?}");
        }
    }
    let min = *counts.iter().min().unwrap();
    let mean = counts.iter().sum::<usize>() as f64 / counts.len() as f64;
    let lat = 40.4545;
    let expected = mean_visible(24.0, 26_559_700.0, 55.0, lat, 10.0)
        + mean_visible(24.0, 29_600_318.0, 56.0, lat, 10.0)
        + mean_visible(24.0, 25_508_200.0, 64.8, lat, 10.0)
        + mean_visible(24.0, 27_906_100.0, 55.0, lat, 10.0);
    assert!((mean / expected - 1.0).abs() < 0.04, "{mean} vs {expected}");
    assert!(min >= 20, "{min}");
    let worst = hdops.iter().cloned().fold(0.0, f64::max);
    assert!(worst < 0.8, "{worst}");
}

/// Epochs from the end of a forced outage until the solution is RTK fixed again.
fn recovery_epochs(sky: &mut SkyState, t: &mut f64, dt: f64) -> usize {
    let mut step = |forced| {
        *t += dt;
        sky.epoch(
            Nanos::from_secs_f64(*t),
            &origin(),
            &Vector3::zeros(),
            &Clear,
            forced,
        )
    };
    // An outage longer than the hold.
    for _ in 0..20 {
        assert_eq!(step(FixStatus::NoFix).status, FixStatus::NoFix);
    }
    let mut n = 0;
    loop {
        n += 1;
        let s = step(FixStatus::RtkFixed).status;
        if s == FixStatus::RtkFixed {
            return n;
        }
        // Never from no fix straight to fixed: float while converging.
        assert_eq!(s, FixStatus::RtkFloat);
        assert!(n < 100_000);
    }
}

#[test]
fn time_to_fix_is_log_normal_with_the_configured_median_and_spread() {
    // 1000 outages at 10 Hz: the epochs until fixed (the first epoch with the conditions
    // counts as zero elapsed) are ⌈ttf/dt⌉ + 1, so ln((n − 1)·dt) estimates ln(ttf) to
    // within one epoch. Mean of ln(ttf) = ln(8) with std 0.5/√1000 = 0.016 (tolerance
    // 0.06), standard deviation 0.5 (tolerance 0.05).
    let p = GnssSkyParams {
        cn0_sigma_db: 0.0,
        ..sky_params()
    };
    let cfg = SkyConfig::new(&p).unwrap();
    let dt = 0.1;
    let mut sky = SkyState::new(cfg, dt, ChaCha8Rng::seed_from_u64(7));
    let mut t = START_UNIX_S;
    let logs: Vec<f64> = (0..1000)
        .map(|_| {
            let n = recovery_epochs(&mut sky, &mut t, dt);
            ((n as f64 - 0.5) * dt).ln()
        })
        .collect();
    let mean = logs.iter().sum::<f64>() / logs.len() as f64;
    let sd =
        (logs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (logs.len() - 1) as f64).sqrt();
    assert!(
        (mean - 8f64.ln()).abs() < 0.06,
        "mean ln {mean} vs {}",
        8f64.ln()
    );
    assert!((sd - 0.5).abs() < 0.05, "sd {sd}");
}

/// Open sky, or every line of sight behind five leaves (−7.7 dB: most satellites stay
/// tracked but too few are strong enough to fix).
struct Canopy(std::sync::atomic::AtomicBool);
impl LineOfSight for Canopy {
    fn sight(&self, _: &Vector3<f64>, _: &Vector3<f64>) -> Sight {
        let dense = self.0.load(std::sync::atomic::Ordering::Relaxed);
        Sight {
            leaves: if dense { 5 } else { 0 },
            blocked: false,
        }
    }
}

#[test]
fn a_fix_survives_sky_gaps_shorter_than_the_hold_and_no_forced_cap() {
    // 10 Hz, hold 1 s, time to fix exactly 3 s: the first epoch with the conditions
    // counts as 0 s, so the fix comes at the 31st.
    let p = GnssSkyParams {
        time_to_fix_spread: 0.0,
        time_to_fix_s: 3.0,
        cn0_sigma_db: 0.0,
        ..sky_params()
    };
    let mut sky = SkyState::new(
        SkyConfig::new(&p).unwrap(),
        0.1,
        ChaCha8Rng::seed_from_u64(2),
    );
    let canopy = Canopy(std::sync::atomic::AtomicBool::new(false));
    let mut t = Nanos::from_secs_f64(START_UNIX_S);
    let mut step = |forced, dense: bool| {
        canopy.0.store(dense, std::sync::atomic::Ordering::Relaxed);
        t += Nanos(100_000_000);
        sky.epoch(t, &origin(), &Vector3::zeros(), &canopy, forced)
    };
    let fixed_after = |step: &mut dyn FnMut(FixStatus, bool) -> Epoch| {
        (1..1000).find(|_| step(FixStatus::RtkFixed, false).status == FixStatus::RtkFixed)
    };
    // Fixed from the first epoch (the receiver was on before the run); a forced outage
    // of one epoch, then 3 s to fix.
    assert_eq!(fixed_after(&mut step), Some(1));
    assert_eq!(step(FixStatus::NoFix, false).status, FixStatus::NoFix);
    assert_eq!(fixed_after(&mut step), Some(31));
    // Under the dense canopy the satellites stay tracked (RTK possible) but too few can
    // fix: 0.5 s is held, fixed throughout and after.
    let e = step(FixStatus::RtkFixed, true);
    let strong = e.satellites.iter().filter(|s| s.cn0_dbhz >= 38.0).count();
    assert!(e.satellites.iter().filter(|s| s.used).count() >= 5 && strong < 8);
    for _ in 0..4 {
        assert_eq!(step(FixStatus::RtkFixed, true).status, FixStatus::RtkFixed);
    }
    assert_eq!(step(FixStatus::RtkFixed, false).status, FixStatus::RtkFixed);
    // 2 s of it: fixed for the hold (1 s), then float; clear again, 3 s to fix.
    let under: Vec<FixStatus> = (0..20)
        .map(|_| step(FixStatus::RtkFixed, true).status)
        .collect();
    assert!(
        under[..10].iter().all(|s| *s == FixStatus::RtkFixed),
        "{under:?}"
    );
    assert!(
        under[10..].iter().all(|s| *s == FixStatus::RtkFloat),
        "{under:?}"
    );
    assert_eq!(fixed_after(&mut step), Some(31));
    // A forced cap (a fault window) of one epoch ends the fix at once.
    assert_eq!(step(FixStatus::RtkFloat, false).status, FixStatus::RtkFloat);
    assert_eq!(fixed_after(&mut step), Some(31));
}

#[test]
fn foliage_lowers_cn0_and_adds_multipath_the_covariance_does_not_know() {
    // Every satellite behind two leaves: C/N0 drops by 2 × 1.55 dB, and the solution
    // carries a multipath error, the least-squares projection of the satellites' biases.
    struct TwoLeaves;
    impl LineOfSight for TwoLeaves {
        fn sight(&self, _: &Vector3<f64>, _: &Vector3<f64>) -> Sight {
            Sight {
                leaves: 2,
                blocked: false,
            }
        }
    }
    let p = GnssSkyParams {
        cn0_sigma_db: 0.0,
        ..sky_params()
    };
    let cfg = SkyConfig::new(&p).unwrap();
    let loss = cfg.leaf_loss_db();
    assert!((loss - 1.549).abs() < 1e-3);
    let mut a = SkyState::new(cfg.clone(), 0.1, ChaCha8Rng::seed_from_u64(4));
    let mut b = SkyState::new(cfg, 0.1, ChaCha8Rng::seed_from_u64(4));
    let mut errs = Vec::new();
    for i in 0..600 {
        let t = Nanos::from_secs_f64(START_UNIX_S + 0.1 * f64::from(i));
        let ea = a.epoch(t, &origin(), &Vector3::zeros(), &Clear, FixStatus::Single);
        let eb = b.epoch(
            t,
            &origin(),
            &Vector3::zeros(),
            &TwoLeaves,
            FixStatus::Single,
        );
        for (x, y) in ea.satellites.iter().zip(&eb.satellites) {
            assert!((x.cn0_dbhz - y.cn0_dbhz - 2.0 * loss).abs() < 1e-9);
        }
        assert_eq!(ea.multipath, Vector3::zeros());
        errs.push(eb.multipath);
    }
    // 1 m per satellite projects to about HDOP·1 m horizontally: RMS 0.3–1.5 m.
    let rms = (errs.iter().map(|e| e.xy().norm_squared()).sum::<f64>() / errs.len() as f64).sqrt();
    assert!((0.3..1.5).contains(&rms), "{rms}");
}

#[test]
fn bad_sky_parameters_are_named() {
    let err = |f: &dyn Fn(&mut GnssSkyParams)| {
        let mut p = sky_params();
        f(&mut p);
        SkyConfig::new(&p).unwrap_err().path
    };
    assert_eq!(
        err(&|p| p.systems = vec!["qzss".into()]),
        "sensors.gnss.sky.systems[0]"
    );
    assert_eq!(
        err(&|p| p.systems = vec!["gps".into(), "gps".into()]),
        "sensors.gnss.sky.systems[1]"
    );
    assert_eq!(err(&|p| p.systems.clear()), "sensors.gnss.sky.systems");
    assert_eq!(
        err(&|p| p.leaf_transmission = 0.0),
        "sensors.gnss.sky.leaf_transmission"
    );
    assert_eq!(
        err(&|p| p.elevation_mask_deg = 95.0),
        "sensors.gnss.sky.elevation_mask_deg"
    );
    assert_eq!(
        err(&|p| p.fix_min_satellites = 2),
        "sensors.gnss.sky.fix_min_satellites"
    );
    assert_eq!(
        err(&|p| p.time_to_fix_s = f64::NAN),
        "sensors.gnss.sky.time_to_fix_s"
    );
    assert_eq!(
        err(&|p| p.cn0_zenith_dbhz = f64::INFINITY),
        "sensors.gnss.sky.cn0_zenith_dbhz"
    );
}
