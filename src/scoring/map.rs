//! Map scoring: a mapper's point cloud against the world's true surfaces.
//!
//! - **Truth** is the render geometry ([`vinebench_sim::render::scene::build`]): every
//!   instance's triangles, placed by its affine map and shifted by
//!   `origin_in_world`, sampled area-uniformly at `truth_samples_per_m2` with a fixed seed
//!   (per triangle: `⌊area·density + u⌋` points, `u` uniform, barycentric square-root
//!   sampling). Only triangles whose bounding box meets the map's bounding box grown by
//!   `margin_m` are sampled.
//! - **Accuracy** (map → truth): per map point (an evenly strided subset of at most
//!   `max_accuracy_points` for large maps), the exact distance to the closest true
//!   triangle among the triangles of its 8 nearest truth samples (so the sampling
//!   density does not bias it); mean and median.
//! - **Region the cameras saw**: the truth samples within `region_m` of some map point
//!   (the map's occupied space dilated by `region_m`). Holes smaller than that count
//!   against completeness; surfaces the cameras never came near do not.
//! - **Completeness** (truth → map): per truth sample in the region, the distance to the
//!   nearest map point; mean, median, and the fraction within each threshold (recall).
//! - **Chamfer** distance: the mean of the two mean distances.
//! - **F-score** at each threshold τ (1, 2, 5 cm by default): precision = fraction of map
//!   points with accuracy < τ, recall = fraction of region truth within τ of the map,
//!   F = 2PR/(P + R).
//!
//! Nearest neighbours come from kiddo k-d trees.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Vector3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::num::NonZero;
use vinebench_sim::render::TraceScene;

/// The F-score thresholds, m (1, 2 and 5 cm), and their names in metric names
/// (`map_f_score_2cm`).
pub const F_SCORE_THRESHOLDS: [(f64, &str); 3] = [(0.01, "1cm"), (0.02, "2cm"), (0.05, "5cm")];

/// Settings of the map score; `[mapper.scoring]` of a scenario, documented with their
/// defaults in `scenarios/defaults.toml`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MapScoreParams {
    /// Truth samples per square metre of true surface.
    pub truth_samples_per_m2: f64,
    /// Truth within this distance of a map point is the seen region, m.
    pub region_m: f64,
    /// Truth triangles are sampled within the map's bounding box grown by this, m.
    pub margin_m: f64,
    /// Seed of the truth sampling.
    pub seed: u64,
    /// Accuracy (and precision) is computed on at most this many map points, evenly
    /// strided over the map.
    pub max_accuracy_points: usize,
}

impl Default for MapScoreParams {
    /// The values of `[mapper.scoring]` in `scenarios/defaults.toml`.
    fn default() -> Self {
        vinebench_msgs::defaults::section("mapper.scoring")
            .expect("the embedded scenarios/defaults.toml is checked by tests")
    }
}

impl MapScoreParams {
    /// Checks the values; errors name the key as `mapper.scoring.<key>`.
    pub fn validate(&self) -> Result<(), vinebench_sim::params::ParamError> {
        let bad = |key: &str, expected: &str, found: f64| vinebench_sim::params::ParamError {
            path: format!("mapper.scoring.{key}"),
            expected: expected.to_string(),
            found: found.to_string(),
        };
        let d = self.truth_samples_per_m2;
        if !(d > 0.0 && d <= 1e7) {
            return Err(bad("truth_samples_per_m2", "in (0, 1e7]", d));
        }
        if !(self.region_m > 0.0 && self.region_m.is_finite()) {
            return Err(bad("region_m", "positive and finite", self.region_m));
        }
        if !(self.margin_m >= 0.0 && self.margin_m.is_finite()) {
            return Err(bad("margin_m", "non-negative and finite", self.margin_m));
        }
        Ok(())
    }
}

/// Precision, recall and F-score at one threshold.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FScore {
    /// Threshold, m.
    pub threshold_m: f64,
    /// Fraction of map points closer than the threshold to the truth.
    pub precision: f64,
    /// Fraction of seen truth closer than the threshold to the map (completeness).
    pub recall: f64,
    /// Harmonic mean of precision and recall (0 when both are 0).
    pub f_score: f64,
}

/// The map score.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MapScore {
    /// Map points scored.
    pub map_points: usize,
    /// Truth samples in the seen region.
    pub truth_points: usize,
    /// Mean map → truth distance, m.
    pub accuracy_mean_m: f64,
    /// Median map → truth distance, m.
    pub accuracy_median_m: f64,
    /// Mean truth → map distance over the seen region, m.
    pub completeness_mean_m: f64,
    /// Median truth → map distance over the seen region, m.
    pub completeness_median_m: f64,
    /// (accuracy mean + completeness mean) / 2, m.
    pub chamfer_m: f64,
    /// Per threshold.
    pub f_scores: Vec<FScore>,
}

impl MapScore {
    /// The names of the map metrics of a source (what expectations may use, as
    /// `map_f_score_2cm.eif`).
    pub const METRIC_NAMES: [&'static str; 12] = [
        "map_accuracy_m",
        "map_completeness_m",
        "map_chamfer_m",
        "map_precision_1cm",
        "map_precision_2cm",
        "map_precision_5cm",
        "map_recall_1cm",
        "map_recall_2cm",
        "map_recall_5cm",
        "map_f_score_1cm",
        "map_f_score_2cm",
        "map_f_score_5cm",
    ];

    /// The value of one of [`MapScore::METRIC_NAMES`]: accuracy and completeness are the
    /// means, precision, recall and F-score those at the named threshold.
    pub fn metric(&self, name: &str) -> Option<f64> {
        match name {
            "map_accuracy_m" => return Some(self.accuracy_mean_m),
            "map_completeness_m" => return Some(self.completeness_mean_m),
            "map_chamfer_m" => return Some(self.chamfer_m),
            _ => {}
        }
        let (kind, at) = name.strip_prefix("map_")?.rsplit_once('_')?;
        let threshold = F_SCORE_THRESHOLDS.iter().find(|t| t.1 == at)?.0;
        let f = self
            .f_scores
            .iter()
            .find(|f| (f.threshold_m - threshold).abs() < 1e-12)?;
        match kind {
            "precision" => Some(f.precision),
            "recall" => Some(f.recall),
            "f_score" => Some(f.f_score),
            _ => None,
        }
    }
}

/// Area-uniform samples of true surfaces with the triangle each came from.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TruthSamples {
    /// Sample positions, world frame, m.
    pub points: Vec<[f64; 3]>,
    /// Index into `triangles` per sample.
    pub triangle_of: Vec<u32>,
    /// The sampled triangles, world frame.
    pub triangles: Vec<[[f64; 3]; 3]>,
}

/// SplitMix64: a deterministic stream without the simulator's RNG plumbing.
struct SplitMix(u64);
impl SplitMix {
    fn next_f64(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

/// Samples every triangle of `scene` whose bounding box meets `[lo, hi]` (world frame).
pub fn sample_truth(
    scene: &TraceScene,
    lo: [f64; 3],
    hi: [f64; 3],
    samples_per_m2: f64,
    seed: u64,
) -> TruthSamples {
    let o = scene.origin_in_world;
    let per_instance: Vec<TruthSamples> = scene
        .instances
        .par_iter()
        .enumerate()
        .map(|(ii, inst)| {
            let mut out = TruthSamples::default();
            let Some(mesh) = scene.meshes.get(inst.mesh as usize) else {
                return out;
            };
            let world: Vec<Vector3<f64>> = mesh
                .positions
                .iter()
                .map(|p| {
                    let s = inst.scene_from_mesh.point(*p);
                    Vector3::new(f64::from(s[0]), f64::from(s[1]), f64::from(s[2])) + o
                })
                .collect();
            let mut rng = SplitMix(seed ^ (ii as u64).wrapping_mul(0xD1B5_4A32_D192_ED03));
            for idx in &mesh.indices {
                let [a, b, c] = idx.map(|i| world[i as usize]);
                let inside = (0..3).all(|k| {
                    a[k].min(b[k]).min(c[k]) <= hi[k] && a[k].max(b[k]).max(c[k]) >= lo[k]
                });
                // Draw the count's uniform for every triangle so sampling one region does
                // not shift another's samples.
                let u = rng.next_f64();
                if !inside {
                    continue;
                }
                let area = 0.5 * (b - a).cross(&(c - a)).norm();
                let n = (area * samples_per_m2 + u).floor() as usize;
                if n == 0 {
                    continue;
                }
                let t = out.triangles.len() as u32;
                out.triangles.push([a.into(), b.into(), c.into()]);
                for _ in 0..n {
                    let (r1, r2) = (rng.next_f64().sqrt(), rng.next_f64());
                    let p = a * (1.0 - r1) + b * (r1 * (1.0 - r2)) + c * (r1 * r2);
                    out.points.push(p.into());
                    out.triangle_of.push(t);
                }
            }
            out
        })
        .collect();
    let mut all = TruthSamples::default();
    for s in per_instance {
        let base = all.triangles.len() as u32;
        all.points.extend(s.points);
        all.triangle_of
            .extend(s.triangle_of.iter().map(|t| t + base));
        all.triangles.extend(s.triangles);
    }
    all
}

/// Closest point of triangle `abc` to `p` (Ericson, Real-Time Collision Detection 5.1.5).
pub fn closest_on_triangle(
    p: &Vector3<f64>,
    a: &Vector3<f64>,
    b: &Vector3<f64>,
    c: &Vector3<f64>,
) -> Vector3<f64> {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(&ap), ac.dot(&ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return *a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(&bp), ac.dot(&bp));
    if d3 >= 0.0 && d4 <= d3 {
        return *b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(&cp), ac.dot(&cp));
    if d6 >= 0.0 && d5 <= d6 {
        return *c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        f64::NAN
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let m = v.len() / 2;
    let (_, x, _) = v.select_nth_unstable_by(m, f64::total_cmp);
    *x
}

/// The cells of a grid of side a little over `radius` that hold map points. A point
/// within `radius` of a map point has that map point in its own or a neighbouring cell
/// (per axis the two differ by at most `radius` < the side), so a point whose 3 × 3 × 3
/// block of cells is empty is farther than `radius` from the map: most truth samples are
/// (leaves inside the canopy, the far sides of posts) and skip the nearest-neighbour
/// query, which gives the same distances for the others.
struct OccupiedCells {
    inv_side: f64,
    cells: rustc_hash::FxHashSet<[i64; 3]>,
}

impl OccupiedCells {
    fn new(points: &[[f64; 3]], radius: f64) -> OccupiedCells {
        // 0.1 % over the radius covers the rounding of the divisions and floors.
        let inv_side = 1.0 / (radius.max(1e-9) * 1.001);
        let mut cells = rustc_hash::FxHashSet::default();
        for q in points {
            cells.insert(Self::cell(q, inv_side));
        }
        OccupiedCells { inv_side, cells }
    }

    fn cell(q: &[f64; 3], inv_side: f64) -> [i64; 3] {
        // `as` saturates (and maps NaN to 0): far or non-finite points land in edge cells,
        // and the exact test decides them.
        q.map(|x| (x * inv_side).floor() as i64)
    }

    /// Whether a map point may lie within the radius of `t` (false: it does not).
    fn near(&self, t: &[f64; 3]) -> bool {
        if !t.iter().all(|x| x.is_finite()) {
            return true;
        }
        let c = Self::cell(t, self.inv_side);
        (-1..=1).any(|dx| {
            (-1..=1).any(|dy| {
                (-1..=1).any(|dz| {
                    self.cells.contains(&[
                        c[0].saturating_add(dx),
                        c[1].saturating_add(dy),
                        c[2].saturating_add(dz),
                    ])
                })
            })
        })
    }
}

/// Scores `map` (world-frame points) against `truth`, with F-scores at `thresholds_m`.
pub fn score_points(
    map: &[[f64; 3]],
    truth: &TruthSamples,
    p: &MapScoreParams,
    thresholds_m: &[f64],
) -> MapScore {
    let empty = MapScore {
        map_points: map.len(),
        truth_points: 0,
        accuracy_mean_m: f64::NAN,
        accuracy_median_m: f64::NAN,
        completeness_mean_m: f64::NAN,
        completeness_median_m: f64::NAN,
        chamfer_m: f64::NAN,
        f_scores: thresholds_m
            .iter()
            .map(|&t| FScore {
                threshold_m: t,
                precision: 0.0,
                recall: 0.0,
                f_score: 0.0,
            })
            .collect(),
    };
    if map.is_empty() || truth.points.is_empty() {
        return empty;
    }
    let truth_tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&truth.points);
    let k = NonZero::new(8).unwrap_or(NonZero::<usize>::MIN);
    // Accuracy on an evenly strided subset of at most `max_accuracy_points` (the map
    // comes sorted by voxel key, so the stride spreads over the whole map).
    let stride = map.len().div_ceil(p.max_accuracy_points.max(1)).max(1);
    let mut accuracy: Vec<f64> = map
        .par_iter()
        .step_by(stride)
        .map(|q| {
            let pq = Vector3::from(*q);
            let mut best = f64::INFINITY;
            let mut seen = [u32::MAX; 8];
            for (i, nn) in truth_tree
                .nearest_n::<SquaredEuclidean>(q, k)
                .iter()
                .enumerate()
            {
                let t = truth.triangle_of[nn.item as usize];
                if seen[..i].contains(&t) {
                    continue;
                }
                seen[i] = t;
                let [a, b, c] = truth.triangles[t as usize].map(Vector3::from);
                best = best.min((closest_on_triangle(&pq, &a, &b, &c) - pq).norm());
            }
            best
        })
        .collect();
    drop(truth_tree);
    let map_tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(map);
    let region2 = p.region_m * p.region_m;
    let occupied = OccupiedCells::new(map, p.region_m);
    let mut completeness: Vec<f64> = truth
        .points
        .par_iter()
        .filter_map(|t| {
            if !occupied.near(t) {
                return None;
            }
            let d2 = map_tree.nearest_one::<SquaredEuclidean>(t).distance;
            (d2 <= region2).then(|| d2.sqrt())
        })
        .collect();
    let f_scores = thresholds_m
        .iter()
        .map(|&t| {
            let precision =
                accuracy.iter().filter(|d| **d < t).count() as f64 / accuracy.len() as f64;
            let recall = if completeness.is_empty() {
                0.0
            } else {
                completeness.iter().filter(|d| **d < t).count() as f64 / completeness.len() as f64
            };
            let f_score = if precision + recall > 0.0 {
                2.0 * precision * recall / (precision + recall)
            } else {
                0.0
            };
            FScore {
                threshold_m: t,
                precision,
                recall,
                f_score,
            }
        })
        .collect();
    let (am, cm) = (mean(&accuracy), mean(&completeness));
    MapScore {
        map_points: map.len(),
        truth_points: completeness.len(),
        accuracy_mean_m: am,
        accuracy_median_m: median(&mut accuracy),
        completeness_mean_m: cm,
        completeness_median_m: median(&mut completeness),
        chamfer_m: 0.5 * (am + cm),
        f_scores,
    }
}

/// Scores a map cloud against a scene's true surfaces (samples the truth around the map
/// first), with F-scores at [`F_SCORE_THRESHOLDS`].
pub fn score_map(map: &[[f32; 3]], scene: &TraceScene, p: &MapScoreParams) -> MapScore {
    let pts: Vec<[f64; 3]> = map
        .iter()
        .map(|q| q.map(f64::from))
        .filter(|q| q.iter().all(|c| c.is_finite()))
        .collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for q in &pts {
        for k in 0..3 {
            lo[k] = lo[k].min(q[k] - p.margin_m);
            hi[k] = hi[k].max(q[k] + p.margin_m);
        }
    }
    let truth = sample_truth(scene, lo, hi, p.truth_samples_per_m2, p.seed);
    let thresholds: Vec<f64> = F_SCORE_THRESHOLDS.iter().map(|t| t.0).collect();
    score_points(&pts, &truth, p, &thresholds)
}

/// Scores a map cloud against the true surfaces of `world` (render geometry with the
/// given ground triangulation step).
pub fn score_map_in_world(
    map: &[[f32; 3]],
    world: &vinebench_sim::world::World,
    terrain_cell_m: f64,
    p: &MapScoreParams,
) -> MapScore {
    let scene = vinebench_sim::render::scene::build(
        world,
        &vinebench_sim::render::scene::GeometryOptions { terrain_cell_m },
    );
    score_map(map, &scene.trace, p)
}

#[cfg(test)]
mod tests {
    use super::*;
    use vinebench_sim::render::{Affine3, Instance, MeshGeometry};

    /// The cell pre-filter never drops a point within the radius of the map (brute force
    /// over random clouds, with points placed at exactly the radius along each axis and
    /// diagonal), and drops most points far from it.
    #[test]
    fn occupied_cells_never_drop_a_point_within_the_radius() {
        let dist2 = |a: &[f64; 3], b: &[f64; 3]| (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>();
        let mut rng = SplitMix(7);
        let mut u = || rng.next_f64();
        let r = 0.1;
        let map: Vec<[f64; 3]> = (0..300)
            .map(|_| [u() * 2.0 - 1.0, u() * 2.0 - 1.0, u() * 0.2])
            .collect();
        let cells = OccupiedCells::new(&map, r);
        let mut probes: Vec<[f64; 3]> = (0..20_000)
            .map(|_| [u() * 3.0 - 1.5, u() * 3.0 - 1.5, u() * 1.0 - 0.4])
            .collect();
        for q in &map {
            for (k, s) in [(0, 1.0), (1, -1.0), (2, 1.0), (0, -1.0)] {
                let mut p = *q;
                p[k] += s * r;
                probes.push(p);
            }
            let d = r / 3f64.sqrt();
            probes.push([q[0] + d, q[1] - d, q[2] + d]);
        }
        let (mut dropped, mut far) = (0, 0);
        for p in &probes {
            let within = map.iter().any(|q| dist2(p, q) <= r * r);
            if within {
                assert!(
                    cells.near(p),
                    "{p:?} is within {r} of the map but was dropped"
                );
            } else {
                far += 1;
                dropped += usize::from(!cells.near(p));
            }
        }
        assert!(
            dropped * 2 > far,
            "only {dropped} of {far} far points dropped"
        );
    }

    fn square(z: f32) -> TraceScene {
        TraceScene {
            origin_in_world: Vector3::new(10.0, 0.0, 0.0),
            meshes: vec![MeshGeometry {
                positions: vec![[0.0, 0.0, z], [1.0, 0.0, z], [1.0, 1.0, z], [0.0, 1.0, z]],
                indices: vec![[0, 1, 2], [0, 2, 3]],
            }],
            instances: vec![Instance {
                mesh: 0,
                scene_from_mesh: Affine3::IDENTITY,
            }],
        }
    }

    #[test]
    fn every_metric_name_has_a_value() {
        let scene = square(0.0);
        let map: Vec<[f32; 3]> = (0..100)
            .map(|i| {
                [
                    10.3 + 0.01 * (i % 10) as f32,
                    0.3 + 0.01 * (i / 10) as f32,
                    0.0,
                ]
            })
            .collect();
        let s = score_map(&map, &scene, &MapScoreParams::default());
        for name in MapScore::METRIC_NAMES {
            assert!(s.metric(name).is_some_and(f64::is_finite), "{name}");
        }
        assert_eq!(s.metric("map_f_score_3cm"), None);
        assert_eq!(s.metric("map_precision_1cm"), Some(1.0));
    }

    #[test]
    fn sampling_is_area_uniform_and_in_world() {
        let s = sample_truth(&square(0.0), [-1e9; 3], [1e9; 3], 10_000.0, 3);
        let n = s.points.len() as f64;
        assert!((n - 10_000.0).abs() < 3.0, "{n}");
        // Each half of the square gets half of the samples (area-uniform).
        let left = s.points.iter().filter(|p| p[0] < 10.5).count() as f64;
        assert!((left / n - 0.5).abs() < 0.02, "{left}");
        assert!(s.points.iter().all(|p| (10.0..=11.0).contains(&p[0])));
    }

    #[test]
    fn a_map_offset_by_one_cm_scores_as_such() {
        let scene = square(0.0);
        // Map: 1 cm grid over the inner half of the square, 1 cm above it.
        let map: Vec<[f32; 3]> = (0..2500)
            .map(|i| {
                [
                    10.25 + 0.01 * (i % 50) as f32,
                    0.25 + 0.01 * (i / 50) as f32,
                    0.01,
                ]
            })
            .collect();
        let p = MapScoreParams::default();
        let pts: Vec<[f64; 3]> = map.iter().map(|q| q.map(f64::from)).collect();
        let truth = sample_truth(&scene, [-1e9; 3], [1e9; 3], p.truth_samples_per_m2, p.seed);
        let s = score_points(&pts, &truth, &p, &[0.005, 0.02]);
        assert!(
            (s.accuracy_mean_m - 0.01).abs() < 1e-6,
            "{}",
            s.accuracy_mean_m
        );
        assert!((s.accuracy_median_m - 0.01).abs() < 1e-6);
        assert_eq!(s.f_scores[0].precision, 0.0);
        assert_eq!(s.f_scores[1].precision, 1.0);
        // Completeness only over the region near the map: the 0.5 × 0.5 m patch grown
        // by 10 cm (a 0.69 m-wide rounded square), all within 2 cm? No: truth 10 cm
        // outside the patch is up to 10 cm away. Recall at 2 cm is the patch (grown by
        // √(2² − 1²) cm) over the region.
        let r = s.f_scores[1].recall;
        let patch = (0.49 + 2.0 * 0.0173_f64).powi(2);
        let region =
            0.49f64.powi(2) + 4.0 * 0.49 * 0.0995 + std::f64::consts::PI * 0.0995f64.powi(2);
        assert!(
            (r - patch / region).abs() < 0.03,
            "recall {r} vs {}",
            patch / region
        );
    }
}
