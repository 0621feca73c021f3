//! Whole-simulation speed: the default scenario (closed loop around a 120 m row, no
//! cameras: rapier3d physics, IMU, GNSS, tracking camera, wheel odometry, EIF and the
//! single-source estimators, scoring) without writing files; and the physics step of
//! each built-in robot.
//!
//! Targets: ≥ 100× real time end to end, ≥ 50× for physics and sensors alone
//! (`cargo bench --bench pipeline`; the real-time factor is the simulated duration,
//! printed first, over the measured time).

// criterion's `criterion_group!` generates an undocumented public function.
#![allow(missing_docs)]

use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use vinebench::runner::{score, simulate};
use vinebench::scenario::LoadedScenario;
use vinebench_msgs::defaults::DEFAULTS_TOML;
use vinebench_sim::physics::Physics;

fn bench_row_loop(c: &mut Criterion) {
    let sc = LoadedScenario::from_str(DEFAULTS_TOML, "scenarios/defaults.toml")
        .expect("the embedded defaults are a valid scenario");
    let simulated = simulate(&sc, None)
        .expect("the default scenario runs")
        .duration_s;
    eprintln!("default scenario: {simulated:.1} s simulated per iteration");
    let mut group = c.benchmark_group("row_loop_120m");
    group.sample_size(10);
    group.bench_function("simulate_estimate_score", |b| {
        b.iter(|| {
            let sim = simulate(&sc, None).expect("runs");
            black_box(score(&sc, &sim))
        })
    });
    let mut no_est = sc.clone();
    no_est.scenario.estimators.run.clear();
    group.bench_function("simulate_only", |b| {
        b.iter(|| black_box(simulate(&no_est, None).expect("runs")))
    });
    group.finish();
}

fn bench_physics_step(c: &mut Criterion) {
    let mut group = c.benchmark_group("physics_step_1000");
    group.sample_size(10);
    for robot in ["tracked-sensorbox", "mecanum-rover"] {
        group.bench_function(robot, |b| {
            b.iter_batched(
                || vinebench::bench::physics_bench_setup(robot).expect("bench setup"),
                |(mut p, refs)| {
                    for _ in 0..1000 {
                        p.step(black_box(&refs));
                    }
                    black_box(p.body())
                },
                criterion::BatchSize::LargeInput,
            )
        });
    }
    group.finish();
}

criterion_group!(benches, bench_row_loop, bench_physics_step);
criterion_main!(benches);
