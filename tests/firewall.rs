//! The ground-truth firewall: the onboard algorithms see only sensor messages.
//!
//! The estimator, SLAM and mapper live in the crate `vinebench-onboard` (`onboard/`), and
//! the compiler lets a crate use only what its `Cargo.toml` lists. So the firewall is that
//! list: this test reads `onboard/Cargo.toml` and accepts only the message crate and pure
//! computation crates, each with the reason it cannot reach simulator truth. Adding
//! `vinebench-sim` (or the bench crate `vinebench`, which holds the runner and scoring)
//! fails here with the reason, before anything else.

// Test helpers panic on failure by design.
#![allow(clippy::unwrap_used)]

use std::path::Path;

/// What the onboard crate may depend on, and why each reaches no truth.
const ALLOWED: &[(&str, &str)] = &[
    (
        "vinebench-msgs",
        "the message, time and frame types: what a robot records",
    ),
    ("nalgebra", "linear algebra"),
    ("serde", "configuration structs"),
    ("thiserror", "error types"),
    ("rayon", "threads"),
    ("kiddo", "k-d trees"),
    ("rustc-hash", "hashing"),
    ("apriltag", "a tag detector on image pixels"),
    ("tobj", "a Wavefront OBJ parser (meshes read back)"),
    (
        "libc",
        "the C allocator (malloc_trim hands freed map memory back)",
    ),
];

/// Allowed in tests only: seeded noise for synthetic inputs, property tests, TOML parsing
/// of configuration snippets, temporary folders.
const ALLOWED_IN_TESTS: &[&str] = &[
    "proptest",
    "rand",
    "rand_chacha",
    "rand_distr",
    "toml",
    "tempfile",
];

/// Crates that would open the firewall, and why.
const FORBIDDEN: &[(&str, &str)] = &[
    (
        "vinebench-sim",
        "the simulator: world, physics, sensors and the ground truth they are computed from",
    ),
    (
        "vinebench",
        "the bench: runner, scoring and recordings' truth topics (and it depends on the \
         simulator)",
    ),
];

/// Checks an onboard manifest; returns one line per dependency that is not allowed.
fn firewall_violations(manifest: &str) -> Vec<String> {
    let doc: toml::Table = match toml::from_str(manifest) {
        Ok(d) => d,
        Err(e) => return vec![format!("Cargo.toml does not parse: {e}")],
    };
    let mut tables: Vec<(String, &toml::Value)> = Vec::new();
    for key in ["dependencies", "dev-dependencies", "build-dependencies"] {
        if let Some(t) = doc.get(key) {
            tables.push((key.to_string(), t));
        }
    }
    // Platform-specific tables: [target.'cfg(..)'.dependencies] and friends.
    if let Some(targets) = doc.get("target").and_then(toml::Value::as_table) {
        for (cfg, t) in targets {
            for key in ["dependencies", "dev-dependencies", "build-dependencies"] {
                if let Some(d) = t.get(key) {
                    tables.push((format!("target.{cfg}.{key}"), d));
                }
            }
        }
    }
    let mut bad = Vec::new();
    for (section, deps) in tables {
        let Some(deps) = deps.as_table() else {
            bad.push(format!("[{section}] is not a table"));
            continue;
        };
        let tests_only = section.ends_with("dev-dependencies");
        for (name, spec) in deps {
            // `foo = { package = "vinebench-sim" }` renames: judge the real package.
            let package = spec
                .get("package")
                .and_then(toml::Value::as_str)
                .unwrap_or(name);
            if let Some((_, why)) = FORBIDDEN.iter().find(|(f, _)| *f == package) {
                bad.push(format!(
                    "[{section}] {name}: `{package}` is {why}; the onboard code must see only \
                     messages"
                ));
            } else if ALLOWED.iter().any(|(a, _)| *a == package)
                || (tests_only && ALLOWED_IN_TESTS.contains(&package))
            {
                // A path dependency must be the message crate itself.
                if let Some(path) = spec.get("path").and_then(toml::Value::as_str) {
                    if package != "vinebench-msgs" || !path.trim_end_matches('/').ends_with("msgs")
                    {
                        bad.push(format!("[{section}] {name}: path `{path}` is not ../msgs"));
                    }
                }
            } else {
                bad.push(format!(
                    "[{section}] {name}: `{package}` is not on the firewall's list; add it to \
                     ALLOWED in tests/firewall.rs with the reason it cannot reach simulator \
                     truth"
                ));
            }
        }
    }
    bad
}

#[test]
fn onboard_crate_cannot_reach_simulator_truth() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let manifest = std::fs::read_to_string(root.join("onboard/Cargo.toml")).unwrap();
    let bad = firewall_violations(&manifest);
    assert!(
        bad.is_empty(),
        "the ground-truth firewall is breached in onboard/Cargo.toml:\n{}",
        bad.join("\n")
    );
    // The workspace uses it as a crate of its own, and the bench depends on it, not the
    // other way round.
    let workspace = std::fs::read_to_string(root.join("Cargo.toml")).unwrap();
    assert!(
        workspace.contains("\"onboard\""),
        "onboard is not a workspace member"
    );
}

/// The algorithm sources are where the crate says, and nowhere in the bench crate.
#[test]
fn algorithms_live_in_the_onboard_crate() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    for m in ["estimator", "slam", "mapper"] {
        assert!(
            root.join("onboard/src").join(m).join("mod.rs").is_file(),
            "{m}"
        );
        assert!(
            !root.join("src").join(m).exists(),
            "src/{m} is back in the bench crate"
        );
    }
}

/// The check itself must catch what it is meant to catch.
#[test]
fn the_firewall_check_rejects_forbidden_dependencies() {
    let base = "[package]\nname = \"vinebench-onboard\"\n\n[dependencies]\n\
                vinebench-msgs = { path = \"../msgs\" }\nnalgebra = \"0.34\"\n";
    assert!(firewall_violations(base).is_empty());
    for (extra, must_name) in [
        ("vinebench-sim = { path = \"../sim\" }\n", "vinebench-sim"),
        ("vinebench-sim.workspace = true\n", "vinebench-sim"),
        (
            "truth = { package = \"vinebench-sim\", path = \"../sim\" }\n",
            "vinebench-sim",
        ),
        ("vinebench = { path = \"..\" }\n", "the bench"),
        ("rapier3d-f64 = \"0.36\"\n", "not on the firewall's list"),
        ("rand = \"0.9\"\n", "not on the firewall's list"),
        (
            "vinebench-msgs2 = { path = \"../sim\" }\n",
            "not on the firewall's list",
        ),
    ] {
        let bad = firewall_violations(&format!("{base}{extra}"));
        assert!(
            bad.iter().any(|b| b.contains(must_name)),
            "not caught: {extra} ({bad:?})"
        );
    }
    // Dev, build and platform tables are checked too; test-only crates only as dev deps.
    for text in [
        format!("{base}\n[dev-dependencies]\nvinebench-sim = {{ path = \"../sim\" }}\n"),
        format!("{base}\n[build-dependencies]\nrand = \"0.9\"\n"),
        format!("{base}\n[target.'cfg(unix)'.dependencies]\nvinebench-sim = \"0.1\"\n"),
    ] {
        assert!(!firewall_violations(&text).is_empty(), "not caught: {text}");
    }
    let dev = format!("{base}\n[dev-dependencies]\nrand = \"0.9\"\nproptest = \"1\"\n");
    assert!(
        firewall_violations(&dev).is_empty(),
        "{:?}",
        firewall_violations(&dev)
    );
}
