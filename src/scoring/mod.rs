//! Scoring: the only place where ground truth meets the estimates.
//!
//! - [`tum`]: lossless TUM trajectory files (what evo and other tools read).
//! - [`align`]: evo's time association and Umeyama alignment.
//! - [`metrics`]: evo-compatible ATE/RPE, the seed paper's closed-loop metrics (Table 1),
//!   errors in fault windows, coverage, and [`metrics::score_source`] bundling them.
//! - [`map`]: a mapper's cloud against the world's true surfaces (accuracy, completeness,
//!   chamfer, F-score).
//! - [`spool`]: trajectories read in passes, from memory or from a file on disk (so a
//!   long run's memory does not grow with its length).
//! - [`plots`]: SVG plots of trajectories, errors over time and altitude.
//! - [`expect`]: the expectation language of scenario files (what must hold for a pass).
//!
//! `scripts/evo_crosscheck.py` prints evo's numbers for two TUM files, to compare.

pub mod align;
pub mod evo;
pub mod expect;
pub mod loops;
pub mod map;
pub mod metrics;
pub mod plots;
pub mod spool;
pub mod tum;

pub use metrics::{SourceScore, score_source};
pub use spool::{Pose, PoseSpool, Poses, SpoolWriter};

use serde::{Deserialize, Serialize};
use vinebench_sim::params::{ParamError, require_non_negative, require_positive};

/// `[scoring]` (documented with its defaults in `scenarios/defaults.toml`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScoringParams {
    /// Association tolerance, s (evo's `--t_max_diff`).
    pub t_max_diff_s: f64,
    /// RPE path distance, m.
    pub rpe_delta_m: f64,
    /// RPE pairs from the ground truth's path (evo's `--pairs_from_reference`) rather than
    /// the estimate's (evo's default).
    pub rpe_pairs_from_reference: bool,
    /// Ground-truth output rate, Hz.
    pub ground_truth_rate_hz: f64,
    /// A loop closure is true when the true poses at its two stamps are this close, m.
    pub loop_distance_m: f64,
    /// The heading check of a loop, and of a ground-truth revisit, deg.
    pub loop_heading_deg: f64,
    /// Path travelled before being near an earlier pose again is a revisit, m.
    pub revisit_min_path_m: f64,
}

impl ScoringParams {
    /// Checks the values; errors name the key as `scoring.<key>`.
    pub fn validate(&self) -> Result<(), ParamError> {
        require_non_negative("scoring.t_max_diff_s", self.t_max_diff_s)?;
        require_positive("scoring.rpe_delta_m", self.rpe_delta_m)?;
        require_positive("scoring.ground_truth_rate_hz", self.ground_truth_rate_hz)?;
        require_positive("scoring.loop_distance_m", self.loop_distance_m)?;
        require_positive("scoring.loop_heading_deg", self.loop_heading_deg)?;
        require_non_negative("scoring.revisit_min_path_m", self.revisit_min_path_m)?;
        Ok(())
    }

    /// The loop-closure thresholds.
    pub fn loop_thresholds(&self) -> loops::LoopThresholds {
        loops::LoopThresholds {
            distance_m: self.loop_distance_m,
            heading_deg: self.loop_heading_deg,
            revisit_min_path_m: self.revisit_min_path_m,
        }
    }
}

impl Default for ScoringParams {
    /// The values of `[scoring]` in `scenarios/defaults.toml`.
    fn default() -> Self {
        vinebench_msgs::defaults::section("scoring")
            .expect("the embedded scenarios/defaults.toml is checked by tests")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_bad_values_name_their_key() {
        let p = ScoringParams::default();
        p.validate().unwrap();
        assert_eq!(p.t_max_diff_s, 0.01);
        let bad = ScoringParams {
            rpe_delta_m: 0.0,
            ..p.clone()
        };
        assert_eq!(bad.validate().unwrap_err().path, "scoring.rpe_delta_m");
        let bad = ScoringParams {
            t_max_diff_s: f64::NAN,
            ..p
        };
        assert_eq!(bad.validate().unwrap_err().path, "scoring.t_max_diff_s");
    }
}

/// Cross-check against evo. Ignored by default (it needs evo); run with
///
/// ```text
/// python3 -m venv /tmp/evo && /tmp/evo/bin/pip install evo
/// EVO_PYTHON=/tmp/evo/bin/python cargo test --release --lib evo_crosscheck -- --ignored --nocapture
/// ```
///
/// It writes synthetic ground-truth/estimate TUM pairs (time offsets, jitter, ties at
/// epoch-sized stamps, |Δt| = max_diff, other rates, noise, drift, a rotated frame, gaps)
/// under `target/evo_crosscheck/<case>/` (or `$VINEBENCH_CROSSCHECK_DIR`), reads them back
/// like evo does, scores them, runs `scripts/evo_crosscheck.py` on the same files and
/// fails if any statistic differs by more than 1e-6 relative. Without `EVO_PYTHON` it only
/// writes the files and our numbers (`vinebench.json`).
#[cfg(test)]
mod evo_crosscheck {
    use super::metrics::{PairsFrom, Stats, ape, rpe};
    use super::plots;
    use super::tum::{read_tum, write_tum};
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};
    use serde_json::{Value, json};
    use std::path::{Path, PathBuf};
    use vinebench_msgs::{Nanos, PoseSample, Trajectory};

    const EPOCH: i64 = 1_631_696_400_000_000_000;
    const MAX_DIFF: Nanos = Nanos(10_000_000);
    const ROW_M: f64 = 30.0;
    const TURN_R: f64 = 2.5;
    const SPEED: f64 = 1.0;

    /// Ground truth of a row loop: east along a row, a U-turn, west along the next row,
    /// a U-turn back to the start; undulating terrain. `world_from_body` at time `t` s.
    fn truth_at(t: f64) -> Isometry3<f64> {
        use std::f64::consts::PI;
        let turn = PI * TURN_R;
        let lap = 2.0 * ROW_M + 2.0 * turn;
        let s = (t * SPEED).rem_euclid(lap);
        let (x, y, yaw) = if s < ROW_M {
            (s, 0.0, 0.0)
        } else if s < ROW_M + turn {
            let a = (s - ROW_M) / TURN_R;
            (ROW_M + TURN_R * a.sin(), TURN_R * (1.0 - a.cos()), a)
        } else if s < 2.0 * ROW_M + turn {
            (ROW_M - (s - ROW_M - turn), 2.0 * TURN_R, PI)
        } else {
            let a = (s - 2.0 * ROW_M - turn) / TURN_R;
            (-TURN_R * a.sin(), TURN_R * (1.0 + a.cos()), PI + a)
        };
        let z = 0.3 * (x * 2.0 * PI / 17.0).sin() + 0.1 * (y * 2.0 * PI / 5.0).sin();
        let pitch = -0.3 * 2.0 * PI / 17.0 * (x * 2.0 * PI / 17.0).cos() * yaw.cos();
        Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_euler_angles(0.02 * (t * 0.7).sin(), pitch, yaw),
        )
    }

    fn traj(samples: impl IntoIterator<Item = (i64, Isometry3<f64>)>) -> Trajectory {
        let mut t = Trajectory::new();
        for (ns, p) in samples {
            t.push(PoseSample {
                stamp: Nanos(ns),
                world_from_body: p,
                covariance: None,
            });
        }
        t
    }

    fn ground_truth(rate_hz: i64, duration_s: i64) -> Trajectory {
        let period = 1_000_000_000 / rate_hz;
        traj((0..rate_hz * duration_s).map(|k| {
            let ns = k * period;
            (EPOCH + ns, truth_at(ns as f64 * 1e-9))
        }))
    }

    fn gauss(rng: &mut ChaCha8Rng) -> f64 {
        StandardNormal.sample(rng)
    }

    fn noisy(
        rng: &mut ChaCha8Rng,
        p: Isometry3<f64>,
        sigma_m: f64,
        sigma_rad: f64,
    ) -> Isometry3<f64> {
        let dp = Vector3::new(gauss(rng), gauss(rng), gauss(rng)) * sigma_m;
        let dr = Vector3::new(gauss(rng), gauss(rng), gauss(rng)) * sigma_rad;
        Isometry3::from_parts(
            Translation3::from(p.translation.vector + dp),
            UnitQuaternion::from_scaled_axis(dr) * p.rotation,
        )
    }

    /// Estimate stamps: every `period_ns` from `offset_ns`, each jittered uniformly by
    /// ±`jitter_ns`, skipping `[gap.0, gap.1)` s.
    fn stamps(
        period_ns: i64,
        offset_ns: i64,
        jitter_ns: i64,
        duration_s: i64,
        gap: (f64, f64),
        rng: &mut ChaCha8Rng,
    ) -> Vec<i64> {
        (0..)
            .map(|k| k * period_ns + offset_ns)
            .take_while(|&ns| ns < duration_s * 1_000_000_000)
            .filter(|&ns| !(gap.0..gap.1).contains(&(ns as f64 * 1e-9)))
            .map(|ns| {
                ns + if jitter_ns > 0 {
                    rng.random_range(-jitter_ns..=jitter_ns)
                } else {
                    0
                }
            })
            .collect()
    }

    /// Dead reckoning of the truth's increments with a scale error and a heading drift per
    /// metre, expressed in a frame rotated and shifted from the world (so alignment matters).
    fn drifting(ts: &[i64], scale: f64, yaw_drift_per_m: f64, rng: &mut ChaCha8Rng) -> Trajectory {
        let frame = Isometry3::from_parts(
            Translation3::new(5.0, -3.0, 1.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.35),
        );
        let mut out = Vec::with_capacity(ts.len());
        let mut pose = truth_at(ts[0] as f64 * 1e-9);
        let mut prev = pose;
        for &ns in ts {
            let now = truth_at(ns as f64 * 1e-9);
            let mut step = prev.inverse() * now;
            step.translation.vector *= scale;
            let drift = UnitQuaternion::from_euler_angles(
                0.0,
                0.0,
                yaw_drift_per_m * step.translation.vector.norm(),
            );
            pose *= step;
            pose.rotation = drift * pose.rotation;
            prev = now;
            out.push((EPOCH + ns, noisy(rng, frame * pose, 0.002, 0.0005)));
        }
        traj(out)
    }

    fn cases() -> Vec<(&'static str, Trajectory, Trajectory)> {
        let mut rng = ChaCha8Rng::seed_from_u64(20_250_101);
        let duration = 60;
        let gt = ground_truth(200, duration);
        let mut out = Vec::new();

        // EIF-like: 100 Hz, +1 ms lag with ±1 ms jitter, 3 cm noise plus a slow wander.
        let ts = stamps(
            10_000_000,
            1_000_000,
            1_000_000,
            duration,
            (0.0, 0.0),
            &mut rng,
        );
        let mut wander = Vector3::zeros();
        let est = traj(ts.iter().map(|&ns| {
            wander += Vector3::new(gauss(&mut rng), gauss(&mut rng), gauss(&mut rng)) * 0.002;
            let mut p = noisy(&mut rng, truth_at(ns as f64 * 1e-9), 0.03, 0.005);
            p.translation.vector += wander;
            (EPOCH + ns, p)
        }));
        out.push(("eif_like_100hz_jitter", gt.clone(), est));

        // GNSS-like: 10 Hz ±4 ms, identity orientation, 1 m noise in [20, 30) s, a gap.
        let ts = stamps(
            100_000_000,
            3_000_000,
            4_000_000,
            duration,
            (40.0, 43.0),
            &mut rng,
        );
        let est = traj(ts.iter().map(|&ns| {
            let t = ns as f64 * 1e-9;
            let sigma = if (20.0..30.0).contains(&t) { 1.0 } else { 0.02 };
            let p = truth_at(t).translation.vector
                + Vector3::new(
                    gauss(&mut rng) * sigma,
                    gauss(&mut rng) * sigma,
                    gauss(&mut rng) * 2.0 * sigma,
                );
            (
                EPOCH + ns,
                Isometry3::from_parts(Translation3::from(p), UnitQuaternion::identity()),
            )
        }));
        out.push(("gnss_like_10hz_gap", gt.clone(), est));

        // VIO-like: 200 Hz, every stamp exactly halfway between two ground-truth stamps
        // (ties decided by float rounding at epoch-sized stamps), scale and heading drift,
        // in a rotated frame.
        let ts = stamps(5_000_000, 2_500_000, 0, duration, (0.0, 0.0), &mut rng);
        out.push((
            "vio_like_ties_drift",
            gt.clone(),
            drifting(&ts, 1.015, 0.5f64.to_radians(), &mut rng),
        ));

        // |Δt| at max_diff: 20 Hz reference, 20 Hz estimate lagging 10 ms ± 1 ns (float
        // rounding of epoch-sized stamps decides which are kept).
        let gt20 = traj(
            gt.samples
                .iter()
                .step_by(10)
                .map(|s| (s.stamp.0, s.world_from_body)),
        );
        let ts = stamps(50_000_000, 10_000_000, 1, duration, (0.0, 0.0), &mut rng);
        let est = traj(ts.iter().map(|&ns| {
            (
                EPOCH + ns,
                noisy(&mut rng, truth_at(ns as f64 * 1e-9), 0.05, 0.01),
            )
        }));
        out.push(("boundary_max_diff", gt20.clone(), est));

        // Estimate denser than the reference (the reference drives the association),
        // starting before and ending after it is cut.
        let gt50 = traj(
            gt.samples
                .iter()
                .step_by(4)
                .skip(250)
                .take(1500)
                .map(|s| (s.stamp.0, s.world_from_body)),
        );
        let ts = stamps(2_500_000, 700_000, 300_000, duration, (0.0, 0.0), &mut rng);
        out.push((
            "dense_estimate_400hz",
            gt50,
            drifting(&ts, 0.99, -0.3f64.to_radians(), &mut rng),
        ));

        // Small stamps (from 0 s), same count both sides, random stamps.
        let small_gt = traj(
            gt.samples
                .iter()
                .step_by(8)
                .map(|s| (s.stamp.0 - EPOCH, s.world_from_body)),
        );
        let ts = stamps(40_000_000, 0, 9_000_000, duration, (0.0, 0.0), &mut rng);
        let est = traj(
            ts.iter()
                .map(|&ns| (ns, noisy(&mut rng, truth_at(ns as f64 * 1e-9), 0.1, 0.02))),
        );
        out.push(("small_stamps_equal_rate", small_gt, est));
        out
    }

    fn stats_json(s: &Stats) -> Value {
        json!({"rmse": s.rmse, "mean": s.mean, "median": s.median, "std": s.std,
               "min": s.min, "max": s.max, "sse": s.sse, "n": s.n})
    }

    fn ours(reference: &Trajectory, estimate: &Trajectory) -> Value {
        let a = ape(reference, estimate, MAX_DIFF, false).unwrap();
        let aa = ape(reference, estimate, MAX_DIFF, true).unwrap();
        let r = rpe(
            reference,
            estimate,
            MAX_DIFF,
            1.0,
            false,
            PairsFrom::Estimate,
        )
        .unwrap();
        let rr = rpe(
            reference,
            estimate,
            MAX_DIFF,
            1.0,
            false,
            PairsFrom::Reference,
        )
        .unwrap();
        json!({"matched": a.matched, "ape": stats_json(&a.stats), "ape_aligned": stats_json(&aa.stats),
               "rpe": stats_json(&r.stats), "rpe_pairs_from_reference": stats_json(&rr.stats)})
    }

    fn out_dir() -> PathBuf {
        std::env::var_os("VINEBENCH_CROSSCHECK_DIR")
            .map(PathBuf::from)
            .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("target/evo_crosscheck"))
    }

    #[test]
    #[ignore = "needs evo: EVO_PYTHON=/path/to/python-with-evo"]
    fn evo_crosscheck() {
        let root = out_dir();
        let evo_python = std::env::var_os("EVO_PYTHON");
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/evo_crosscheck.py");
        let metrics = ["ape", "ape_aligned", "rpe", "rpe_pairs_from_reference"];
        let fields = ["rmse", "mean", "median", "std", "min", "max", "sse"];
        let mut worst: Vec<(String, f64)> = Vec::new();
        for (name, gt, est) in cases() {
            let dir = root.join(name);
            std::fs::create_dir_all(&dir).unwrap();
            let (gt_path, est_path) = (dir.join("reference.tum"), dir.join("estimate.tum"));
            write_tum(&gt_path, &gt).unwrap();
            write_tum(&est_path, &est).unwrap();
            // Score what evo reads: the files.
            let (gt, est) = (read_tum(&gt_path).unwrap(), read_tum(&est_path).unwrap());
            let ours = ours(&gt, &est);
            std::fs::write(
                dir.join("vinebench.json"),
                serde_json::to_string_pretty(&ours).unwrap(),
            )
            .unwrap();
            let t0 = gt.samples[0].stamp;
            let a = ape(&gt, &est, MAX_DIFF, false).unwrap();
            plots::plot_trajectories_svg(dir.join("top.svg"), &gt, &[(name, &est)]).unwrap();
            plots::plot_errors_svg(
                dir.join("errors.svg"),
                &[(name, &a.errors)],
                t0,
                &[(t0 + Nanos::from_secs(20), t0 + Nanos::from_secs(30))],
            )
            .unwrap();
            plots::plot_altitude_svg(dir.join("altitude.svg"), &gt, &[(name, &est)], t0).unwrap();
            let Some(py) = &evo_python else {
                println!(
                    "{name}: wrote {} (set EVO_PYTHON to compare)",
                    dir.display()
                );
                continue;
            };
            let output = std::process::Command::new(py)
                .arg(&script)
                .arg(&gt_path)
                .arg(&est_path)
                .args(["--t_max_diff", "0.01", "--delta", "1.0"])
                .output()
                .unwrap();
            assert!(
                output.status.success(),
                "{}",
                String::from_utf8_lossy(&output.stderr)
            );
            std::fs::write(dir.join("evo.json"), &output.stdout).unwrap();
            let evo: Value = serde_json::from_slice(&output.stdout).unwrap();
            assert_eq!(evo["matched"], ours["matched"], "{name}: matched");
            for m in metrics {
                assert_eq!(evo[m]["n"], ours[m]["n"], "{name}: {m}.n ({})", evo[m]);
                for f in fields {
                    let (e, o) = (evo[m][f].as_f64().unwrap(), ours[m][f].as_f64().unwrap());
                    let rel = (o - e).abs() / e.abs().max(f64::MIN_POSITIVE);
                    let key = format!("{m}.{f}");
                    match worst.iter_mut().find(|(k, _)| *k == key) {
                        Some(w) => w.1 = w.1.max(rel),
                        None => worst.push((key, rel)),
                    }
                    assert!(
                        rel <= 1e-6,
                        "{name}: {m}.{f}: ours {o} evo {e} (rel {rel:e})"
                    );
                }
            }
            println!(
                "{name}: matched {} — ape rmse {:.6} m, aligned {:.6} m, rpe rmse {:.6} m (evo {})",
                ours["matched"],
                ours["ape"]["rmse"],
                ours["ape_aligned"]["rmse"],
                ours["rpe"]["rmse"],
                evo["evo_version"]
            );
        }
        for (k, rel) in &worst {
            println!("max relative difference {k}: {rel:.3e}");
        }
    }
}
