//! Sweeps end to end, on the CI-sized sweep (`tests/data/ci-sweep.toml`, jobs of half a
//! second): bad sweep files fail before anything runs, naming file, axis and value;
//! results do not depend on `--jobs` or the shard split; a rerun resumes; merge, JUnit
//! and the regression gate behave (both error rates).

// Test helpers panic on failure by design.
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use vinebench::sweep::compare::{self, CompareOptions, Finding};
use vinebench::sweep::merge::{self, MergeOptions};
use vinebench::sweep::run::{self, Keep, Shard, SweepOptions};
use vinebench::sweep::spec::Sweep;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn ci_sweep() -> Sweep {
    Sweep::load(&root().join("tests/data/ci-sweep.toml")).unwrap()
}

fn opts(out: &Path, jobs: usize, shard: Shard) -> SweepOptions {
    SweepOptions {
        out_dir: out.to_path_buf(),
        jobs,
        shard,
        keep: Keep::None,
        progress: false,
        stop: None,
    }
}

fn shard(i: usize, n: usize) -> Shard {
    Shard::from_args(Some(&format!("{i}/{n}")), |_| None).unwrap()
}

/// A sweep file in `dir` over the one-outage row loop (absolute path).
fn sweep_file(dir: &Path, name: &str, body: &str) -> PathBuf {
    let scenario = root().join("scenarios/sweeps/row-loop-one-outage.toml");
    let p = dir.join(format!("{name}.toml"));
    std::fs::write(
        &p,
        format!(
            "name = \"{name}\"\nscenario = {:?}\n{body}",
            scenario.display().to_string()
        ),
    )
    .unwrap();
    p
}

#[test]
fn bad_sweeps_fail_before_anything_runs_naming_file_axis_and_value() {
    let dir = tempfile::tempdir().unwrap();
    let load = |body: &str| {
        let p = sweep_file(dir.path(), "bad", body);
        Sweep::load(&p).map(|_| ()).unwrap_err().to_string()
    };
    // An unknown key, a wrong type, an index past the end, a bad seed range.
    let e = load("seeds = [1]\n[axes]\n\"world.rows.cuont\" = [3]\n");
    assert!(
        e.contains("bad.toml") && e.contains("world.rows.cuont") && e.contains("= 3"),
        "{e}"
    );
    let e = load("seeds = [1]\n[axes]\n\"world.rows.count\" = [\"three\"]\n");
    assert!(e.contains("axis \"world.rows.count\" = \"three\""), "{e}");
    let e = load("seeds = [1]\n[axes]\n\"faults.gnss[3].end_s\" = [60.0]\n");
    assert!(
        e.contains("faults.gnss") && e.contains("past its end"),
        "{e}"
    );
    let e = load("seeds = \"5-1\"\n");
    assert!(e.contains("`seeds`") && e.contains("a <= b"), "{e}");
    let e = load("seeds = [1]\nmetrics = [\"ate\"]\n");
    assert!(e.contains("unknown metric `ate`"), "{e}");
    let e = load("seeds = [1]\n[expect]\nper_cell = [\"avg(ate_rmse_m.eif) < 1\"]\n");
    assert!(
        e.contains("expect.per_cell[0]") && e.contains("unknown statistic"),
        "{e}"
    );
    let e = load("seeds = [1]\ncombine = \"zip\"\n[axes]\n\"a.b\" = [1, 2]\nc = [1]\n");
    assert!(e.contains("the same length"), "{e}");
    let e = load("seeds = [1]\n[axes]\nworld.rows.count = [2]\n");
    assert!(
        e.contains("must be quoted (`\"world.rows\" = [...]`)"),
        "{e}"
    );
    // A value of the right type but out of range: the cell's set-up fails before any
    // job runs, naming the axis.
    let p = sweep_file(
        dir.path(),
        "range",
        "seeds = [1]\n[axes]\n\"sensors.gnss.rate_hz\" = [10.0, -5.0]\n",
    );
    let s = Sweep::load(&p).unwrap();
    let out = dir.path().join("out");
    let e = run::run_shard(&s, &opts(&out, 1, Shard::all()))
        .unwrap_err()
        .to_string();
    assert!(e.contains("axis \"sensors.gnss.rate_hz\" = -5.0"), "{e}");
    assert!(!out.join("rows").exists(), "nothing may run or be written");
}

#[test]
fn expansion_is_stable_and_complete() {
    let s = ci_sweep();
    // 1 scenario x 2 cells (one single-valued axis, one with two values) x 3 seeds.
    assert_eq!(s.job_count(), 6);
    let jobs = s.jobs();
    let keys: Vec<String> = jobs.iter().map(|j| s.job_key(j)).collect();
    assert_eq!(keys[0], "row-loop-one-outage/c0/s3");
    assert_eq!(keys[5], "row-loop-one-outage/c1/s2");
    // The cell's values reach the scenario.
    let sc = s.job_scenario(&jobs[4]).unwrap();
    assert_eq!(sc.scenario.seed, 1);
    assert_eq!(sc.scenario.faults.gnss[0].end_s, 60.0);
    assert_eq!(sc.scenario.max_duration_s, 70.0);
    // Latin hypercube: every stratum of every axis used once.
    let dir = tempfile::tempdir().unwrap();
    let p = sweep_file(
        dir.path(),
        "lhs",
        "seeds = [1]\ncombine = \"latin_hypercube\"\nsamples = 10\nsample_seed = 4\n\
         [axes]\n\"faults.gnss[0].end_s\" = { min = 60.0, max = 160.0 }\n\
         \"sensors.gnss.latency_ms\" = { min = 0.0, max = 100.0 }\n",
    );
    let s = Sweep::load(&p).unwrap();
    for (a, lo) in [(0, 60.0), (1, 0.0)] {
        let mut strata: Vec<usize> = s
            .cells
            .iter()
            .map(|c| ((c.values[a].as_float().unwrap() - lo) / 10.0).floor() as usize)
            .collect();
        strata.sort_unstable();
        assert_eq!(strata, (0..10).collect::<Vec<_>>(), "axis {a}");
    }
    assert_eq!(Sweep::load(&p).unwrap().cells, s.cells, "seeded");
}

#[test]
fn results_do_not_depend_on_jobs_or_shards_and_a_rerun_resumes() {
    let s = ci_sweep();
    let dir = tempfile::tempdir().unwrap();
    let single = dir.path().join("single");
    let o = run::run_shard(&s, &opts(&single, 1, Shard::all())).unwrap();
    assert_eq!((o.jobs, o.skipped, o.passed + o.failed), (6, 0, 6));
    // Three shards, each with two jobs at once, into separate folders (as CI artifacts).
    let shards: Vec<PathBuf> = (1..=3)
        .map(|i| {
            let d = dir.path().join(format!("shard{i}"));
            let o = run::run_shard(&s, &opts(&d, 2, shard(i, 3))).unwrap();
            assert_eq!(o.jobs, 2);
            d
        })
        .collect();
    let m1 = dir.path().join("m1");
    let m3 = dir.path().join("m3");
    merge::merge(
        std::slice::from_ref(&single),
        &MergeOptions {
            out_dir: m1.clone(),
            ..MergeOptions::default()
        },
    )
    .unwrap();
    let summary = merge::merge(
        &shards,
        &MergeOptions {
            out_dir: m3.clone(),
            junit: Some(m3.join("junit.xml")),
            ..MergeOptions::default()
        },
    )
    .unwrap();
    assert_eq!(summary.exit_code(false), 0, "{summary:#?}");
    // (The merged rows keep each job's wall time, so only the tables are compared.)
    for f in ["results.csv", "summary.json", "sweep.md"] {
        assert_eq!(
            std::fs::read(m1.join(f)).unwrap(),
            std::fs::read(m3.join(f)).unwrap(),
            "{f}"
        );
    }
    // The table has a row per job and a column per metric of every source.
    let csv = std::fs::read_to_string(m1.join("results.csv")).unwrap();
    assert_eq!(csv.lines().count(), 7);
    assert!(
        csv.lines()
            .next()
            .unwrap()
            .contains("outage_max_error_m.eif")
    );
    // JUnit: 2 cells x (3 jobs + 1 expectation) + 2 overall, read back.
    let xml = std::fs::read_to_string(m3.join("junit.xml")).unwrap();
    let doc = roxmltree::Document::parse(&xml).unwrap();
    assert_eq!(doc.root_element().attribute("tests"), Some("10"));

    // A rerun skips what is done; one lost row (a torn last line) is run again.
    let again = run::run_shard(&s, &opts(&single, 2, Shard::all())).unwrap();
    assert_eq!((again.skipped, again.passed + again.failed), (6, 0));
    let rows = single.join("rows/shard-1-of-1.jsonl");
    let text = std::fs::read_to_string(&rows).unwrap();
    let cut = text.trim_end().rfind('\n').unwrap() + 1;
    std::fs::write(&rows, format!("{}{{\"job\": 5, \"ke", &text[..cut])).unwrap();
    let resumed = run::run_shard(&s, &opts(&single, 1, Shard::all())).unwrap();
    assert_eq!((resumed.skipped, resumed.passed + resumed.failed), (5, 1));
    let m1b = dir.path().join("m1b");
    merge::merge(
        std::slice::from_ref(&single),
        &MergeOptions {
            out_dir: m1b.clone(),
            ..MergeOptions::default()
        },
    )
    .unwrap();
    assert_eq!(
        std::fs::read(m1.join("results.csv")).unwrap(),
        std::fs::read(m1b.join("results.csv")).unwrap()
    );

    // An incomplete set is reported, and is not a pass.
    let partial = merge::merge(
        &shards[..2],
        &MergeOptions {
            out_dir: dir.path().join("partial"),
            ..MergeOptions::default()
        },
    )
    .unwrap();
    assert_eq!(partial.missing.len(), 2);
    assert_eq!(partial.exit_code(false), 2);
    assert_ne!(partial.exit_code(true), 0, "missing jobs never pass");
    // Another sweep's folder is refused.
    let other = sweep_file(dir.path(), "other", "seeds = [1]\n");
    let e = run::run_shard(
        &Sweep::load(&other).unwrap(),
        &opts(&single, 1, Shard::all()),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("another sweep"), "{e}");
}

/// The regression gate: identical runs give no flag; a configuration with doubled GNSS
/// noise in stand-alone mode is flagged on GNSS-only's errors.
#[test]
fn the_gate_flags_a_worse_configuration_and_not_an_identical_one() {
    let dir = tempfile::tempdir().unwrap();
    let base_scenario = root().join("scenarios/sweeps/row-loop-one-outage.toml");
    let noisy = dir.path().join("noisy.toml");
    std::fs::write(
        &noisy,
        std::fs::read_to_string(&base_scenario).unwrap()
            + "\n[sensors.gnss.single]\nsigma_horizontal_m = 2.4\nsigma_vertical_m = 5.0\n",
    )
    .unwrap();
    let body = "seeds = \"1-8\"\n[axes]\nmax_duration_s = [70.0]\n";
    let write = |name: &str, scenario: &Path| {
        let p = dir.path().join(format!("{name}.toml"));
        std::fs::write(
            &p,
            format!(
                "name = \"gate\"\nscenario = {:?}\n{body}",
                scenario.display().to_string()
            ),
        )
        .unwrap();
        p
    };
    let run_to = |file: &Path, out: &str| {
        let out = dir.path().join(out);
        run::run_shard(&Sweep::load(file).unwrap(), &opts(&out, 2, Shard::all())).unwrap();
        out
    };
    let base_file = write("base", &base_scenario);
    let (a, b) = (run_to(&base_file, "a"), run_to(&base_file, "b"));
    let worse = run_to(&write("worse", &noisy), "worse");
    let o = CompareOptions::default();
    let same = compare::compare(&a, &b, &o).unwrap();
    assert!(!same.comparisons.is_empty());
    assert_eq!(same.exit_code(), 0);
    assert_eq!(same.with(Finding::Improvement).count(), 0);
    let r = compare::compare(&a, &worse, &o).unwrap();
    let flagged: Vec<&str> = r
        .with(Finding::Regression)
        .map(|c| c.column.as_str())
        .collect();
    assert!(
        flagged.contains(&"ate_rmse_m.gnss"),
        "{flagged:?}\n{}",
        compare::markdown(&r)
    );
    assert!(flagged.contains(&"outage_max_error_m.gnss"), "{flagged:?}");
    assert_eq!(r.exit_code(), 1);
    assert!(compare::markdown(&r).contains("REGRESSION"));

    // The same code on disjoint seeds: every comparison is unpaired, and flags come only
    // by chance (one-sided, so at most alpha / 2 of them in expectation; three binomial
    // standard deviations of room).
    let other_seeds = dir.path().join("disjoint.toml");
    std::fs::write(
        &other_seeds,
        format!(
            "name = \"gate\"\nscenario = {:?}\nseeds = \"9-16\"\n[axes]\nmax_duration_s = [70.0]\n",
            base_scenario.display().to_string()
        ),
    )
    .unwrap();
    let disjoint = run_to(&other_seeds, "disjoint");
    let r = compare::compare(&a, &disjoint, &o).unwrap();
    let gated: Vec<_> = r
        .comparisons
        .iter()
        .filter(|c| c.finding != Finding::NotGated && c.finding != Finding::Untestable)
        .collect();
    assert!(gated.len() >= 20, "{}", gated.len());
    assert!(gated.iter().all(|c| c.n_paired == 0));
    let p = o.alpha / 2.0;
    let bound = gated.len() as f64 * p + 3.0 * (gated.len() as f64 * p * (1.0 - p)).sqrt();
    let flags = gated
        .iter()
        .filter(|c| c.finding == Finding::Regression)
        .count();
    assert!(
        flags as f64 <= bound,
        "{flags} of {} flagged\n{}",
        gated.len(),
        compare::markdown(&r)
    );
}
