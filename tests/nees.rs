//! Filter consistency: the EIF's reported covariance matches its actual errors.
//!
//! Normalized estimation error squared (NEES, Bar-Shalom et al., "Estimation with
//! Applications to Tracking and Navigation", §5.4): for each output pose,
//! ε = eᵀ P⁻¹ e with e the error of the estimate against ground truth and P the
//! covariance the filter reports. For a consistent filter ε ~ χ²(n). Over a Monte Carlo
//! of N independent runs, N·ε̄ₖ (the average over runs at time k) ~ χ²(N·n), which gives a
//! two-sided 95 % acceptance interval for ε̄ₖ at every time step.
//!
//! The textbook test needs the filter's model to match the simulated sensors, so the
//! first test configures the simulator with the error processes the filter models (white
//! GNSS and AHRS errors, tracking-camera random walks without scale or tilt errors, no
//! IMU bias drift) and demands the χ² interval at ≥ 90 % of time steps. The second runs
//! the realistic defaults (correlated GNSS and AHRS errors, tracking-camera scale and
//! tilt errors, IMU bias drift, all of which the filter only approximates) and bounds
//! the time-averaged NEES, so a regression towards overconfidence is caught.

// Test helpers panic on failure by design.
#![allow(clippy::unwrap_used)]

use nalgebra::{Matrix3, Matrix6, Vector6};
use vinebench::runner::simulate;
use vinebench::scenario::LoadedScenario;
use vinebench_msgs::Trajectory;

/// Monte Carlo runs.
const RUNS: u64 = 12;

/// Two-sided 95 % interval of χ²(k)/RUNS for k = RUNS·dof, by the Wilson-Hilferty
/// approximation (accurate to < 0.5 % for k ≥ 30).
fn chi2_interval(dof: usize) -> (f64, f64) {
    let k = (RUNS as usize * dof) as f64;
    let z = 1.959_963_984_540_054;
    let q = |z: f64| k * (1.0 - 2.0 / (9.0 * k) + z * (2.0 / (9.0 * k)).sqrt()).powi(3);
    (q(-z) / RUNS as f64, q(z) / RUNS as f64)
}

/// Position (3-dof) and pose (6-dof) NEES of every EIF output pose, at its stamp.
fn nees_series(truth: &Trajectory, eif: &Trajectory) -> Vec<(i64, f64, f64)> {
    let mut out = Vec::new();
    for s in &eif.samples {
        let Some(cov) = s.covariance.as_deref().copied() else {
            continue;
        };
        let Some(t) = truth.interpolate(s.stamp) else {
            continue;
        };
        let dp = t.translation.vector - s.world_from_body.translation.vector;
        // PoseSample convention: world_from_body_true ≈ (Exp(δθ)·R, p + δp).
        let dtheta = (t.rotation * s.world_from_body.rotation.inverse()).scaled_axis();
        let p3: Matrix3<f64> = cov.fixed_view::<3, 3>(0, 0).into_owned();
        let e6 = Vector6::new(dp.x, dp.y, dp.z, dtheta.x, dtheta.y, dtheta.z);
        let pos = p3.try_inverse().map(|i| (dp.transpose() * i * dp)[0]);
        let pose = Matrix6::from(cov)
            .try_inverse()
            .map(|i| (e6.transpose() * i * e6)[0]);
        if let (Some(a), Some(b)) = (pos, pose) {
            out.push((s.stamp.0, a, b));
        }
    }
    out
}

/// Runs the Monte Carlo and returns, per time step present in every run, the run-average
/// position and pose NEES.
fn monte_carlo(scenario: &str) -> Vec<(f64, f64)> {
    let mut per_run = Vec::new();
    for seed in 1..=RUNS {
        let text = format!("seed = {seed}\n{scenario}");
        let sc = LoadedScenario::from_str(&text, "nees.toml").expect("scenario is valid");
        let sim = simulate(&sc, None).expect("simulation runs");
        let eif = sim
            .estimates
            .iter()
            .find(|e| e.name == "eif")
            .expect("eif runs");
        let truth = sim.truth.to_trajectory().unwrap();
        per_run.push(nees_series(&truth, &eif.poses.to_trajectory().unwrap()));
    }
    // Output stamps are on the same grid in every run (the IMU grid from the start).
    let n = per_run.iter().map(Vec::len).min().unwrap_or(0);
    assert!(n > 1000, "too few EIF poses with covariance: {n}");
    (0..n)
        .map(|k| {
            let stamp = per_run[0][k].0;
            assert!(
                per_run.iter().all(|r| r[k].0 == stamp),
                "output grids differ between runs"
            );
            let pos = per_run.iter().map(|r| r[k].1).sum::<f64>() / RUNS as f64;
            let pose = per_run.iter().map(|r| r[k].2).sum::<f64>() / RUNS as f64;
            (pos, pose)
        })
        .collect()
}

const SHORT_LOOP: &str = r#"
name = "nees"
[world.rows]
count = 2
length_m = 30.0
[route.row_loop]
row = 0
[motion]
still_before_s = 3.0
still_after_s = 1.0
[[faults.gnss]]
start_s = 20.0
end_s = 35.0
status = "single"
"#;

#[test]
fn eif_is_consistent_when_its_model_matches_the_sensors() {
    let matched = format!(
        "{SHORT_LOOP}
[sensors.imu]
gyro_bias_instability_dph = 0.0
accel_bias_instability_ug = 0.0
orientation_correlation_time_s = 0.0
[sensors.gnss.rtk_fixed]
correlation_time_s = 0.0
[sensors.gnss.single]
correlation_time_s = 0.0
[sensors.tracking_camera]
scale_error_sigma = 0.0
pitch_bias_sigma_deg = 0.0
[estimators.eif]
gnss_correlation_time_s = 0.0
orientation_correlation_time_s = 0.0
"
    );
    let series = monte_carlo(&matched);
    for (dof, idx, name) in [(3usize, 0usize, "position"), (6, 1, "pose")] {
        let (lo, hi) = chi2_interval(dof);
        let vals: Vec<f64> = series
            .iter()
            .map(|s| if idx == 0 { s.0 } else { s.1 })
            .collect();
        let inside =
            vals.iter().filter(|v| **v >= lo && **v <= hi).count() as f64 / vals.len() as f64;
        let mean = vals.iter().sum::<f64>() / vals.len() as f64;
        eprintln!(
            "{name}: {:.1} % of steps in [{lo:.2}, {hi:.2}], ANEES {mean:.2} (dof {dof})",
            inside * 100.0
        );
        assert!(
            inside >= 0.90,
            "{name} NEES inside its 95 % χ² interval at only {:.1} % of steps (ANEES {mean:.2}, dof {dof})",
            inside * 100.0
        );
    }
}

#[test]
fn eif_is_not_overconfident_with_the_realistic_sensor_models() {
    let series = monte_carlo(SHORT_LOOP);
    let mean = |f: fn(&(f64, f64)) -> f64| series.iter().map(f).sum::<f64>() / series.len() as f64;
    let (pos, pose) = (mean(|s| s.0), mean(|s| s.1));
    eprintln!("realistic models: ANEES position {pos:.2} (dof 3), pose {pose:.2} (dof 6)");
    // The filter approximates correlated and systematic errors; allow a factor of two
    // beyond the dimension before calling it overconfident.
    assert!(
        pos <= 6.0,
        "position ANEES {pos:.2} > 6: the EIF is overconfident"
    );
    assert!(
        pose <= 12.0,
        "pose ANEES {pose:.2} > 12: the EIF is overconfident"
    );
}

#[test]
fn chi2_interval_matches_tabulated_values() {
    // χ²(36) 2.5 % and 97.5 % quantiles: 21.336, 54.437 (tables); divided by 12 runs.
    let (lo, hi) = chi2_interval(3);
    assert!((lo * 12.0 - 21.336).abs() < 0.1, "{lo}");
    assert!((hi * 12.0 - 54.437).abs() < 0.1, "{hi}");
}
