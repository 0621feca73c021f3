//! Fuzz target for the URDF reader (`RobotModel::from_urdf_file` / `from_urdf_str`).
//!
//! Seeds are `tests/fuzz/corpus/urdf/`: the shipped robots of `robot-models/` and every
//! reproducer found (an `<sdf>` root, `<mass value="heavy"/>`, `<mass/>`, a 1e30 kg
//! chassis, a truncated file, a 1000-link chain, 2000-deep nesting, a joint cycle).
//! Mutations are structure-aware: an attribute value replaced by an extreme (a word,
//! NaN, 1e30, an empty or over-long vector), an element or closing tag cut out, plus the
//! byte-level mutations of `common/fuzz.rs` (flips, truncations, length-field lies,
//! splices). The property: no panic, no abort, no allocation beyond the bound of
//! `common/fuzz.rs`, and either a robot with physical mass properties or an error that
//! names the file. `VINEBENCH_FUZZ_CASES` sets the number of cases (CI runs more).

#[path = "common/fuzz.rs"]
mod fuzz;

use fuzz::{Mutation, mutate, mutations, no_panic};
use proptest::prelude::*;
use std::path::PathBuf;
use vinebench_sim::robot::{MAX_ROBOT_MASS_KG, RobotModel};

#[global_allocator]
static ALLOC: fuzz::LimitAlloc = fuzz::LimitAlloc;

/// Values that break assumptions, for attribute values.
const EXTREMES: &[&str] = &[
    "heavy",
    "",
    "nan",
    "inf",
    "-inf",
    "-1",
    "0",
    "1e30",
    "1e-300",
    "1e308 1e308 1e308",
    "1 2",
    "1 2 3 4",
    "0 0 0",
    "1 heavy 2 3",
    "base_link",
    "chain_0",
    "continuous",
    "prismatic",
];

/// One structure-aware change to a URDF's text.
#[derive(Clone, Debug)]
enum Edit {
    /// The `k`-th attribute value (modulo their number) replaced by `EXTREMES[v]`.
    Attribute { k: usize, v: usize },
    /// The `k`-th element's tag (from `<` to `>`, modulo their number) removed.
    DropTag { k: usize },
    /// Byte-level mutations.
    Bytes(Vec<Mutation>),
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        3 => (any::<usize>(), 0..EXTREMES.len()).prop_map(|(k, v)| Edit::Attribute { k, v }),
        1 => any::<usize>().prop_map(|k| Edit::DropTag { k }),
        3 => mutations(4).prop_map(Edit::Bytes),
    ]
}

/// Byte ranges of every attribute value (between the quotes of `name="value"`).
fn attribute_values(text: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i + 1 < text.len() {
        if text[i] == b'=' && (text[i + 1] == b'"' || text[i + 1] == b'\'') {
            let q = text[i + 1];
            if let Some(len) = text[i + 2..].iter().position(|&c| c == q) {
                out.push((i + 2, i + 2 + len));
                i += 2 + len;
            }
        }
        i += 1;
    }
    out
}

/// Byte ranges of every tag (`<...>`).
fn tags(text: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = None;
    for (i, &c) in text.iter().enumerate() {
        match (c, start) {
            (b'<', _) => start = Some(i),
            (b'>', Some(s)) => {
                out.push((s, i + 1));
                start = None;
            }
            _ => {}
        }
    }
    out
}

fn apply(seed: &[u8], e: &Edit) -> Vec<u8> {
    match e {
        Edit::Attribute { k, v } => {
            let values = attribute_values(seed);
            if values.is_empty() {
                return seed.to_vec();
            }
            let (a, b) = values[k % values.len()];
            let mut out = seed[..a].to_vec();
            out.extend_from_slice(EXTREMES[*v].as_bytes());
            out.extend_from_slice(&seed[b..]);
            out
        }
        Edit::DropTag { k } => {
            let t = tags(seed);
            if t.is_empty() {
                return seed.to_vec();
            }
            let (a, b) = t[k % t.len()];
            let mut out = seed[..a].to_vec();
            out.extend_from_slice(&seed[b..]);
            out
        }
        Edit::Bytes(m) => mutate(seed, m),
    }
}

/// The property for one input: no panic (no abort: the allocator bounds every
/// allocation), and a robot with physical mass or an error naming the file.
fn check(what: &str, bytes: &[u8]) {
    let dir = tempfile::tempdir().expect("temporary folder");
    let path = dir.path().join("robot.urdf");
    std::fs::write(&path, bytes).expect("write the input");
    let file = path.display().to_string();
    let results = no_panic(what, || {
        let from_file = RobotModel::from_urdf_file(&path);
        let from_str = RobotModel::from_urdf_str(&String::from_utf8_lossy(bytes), &file);
        [from_file, from_str]
    });
    for r in results {
        match r {
            Ok(robot) => {
                let m = robot.inertia.mass_kg;
                assert!(
                    m.is_finite() && m > 0.0 && m <= MAX_ROBOT_MASS_KG,
                    "{what}: loaded with mass {m}"
                );
                assert!(
                    robot
                        .inertia
                        .inertia_about_com_in_body
                        .iter()
                        .all(|c| c.is_finite()),
                    "{what}: non-finite inertia"
                );
            }
            Err(e) => {
                let msg = e.to_string();
                assert!(
                    msg.starts_with(&file) && msg.len() > file.len() + 10,
                    "{what}: the error does not name the file: {msg}"
                );
            }
        }
    }
}

/// The corpus, read once.
fn seeds() -> &'static [(PathBuf, Vec<u8>)] {
    static SEEDS: std::sync::OnceLock<Vec<(PathBuf, Vec<u8>)>> = std::sync::OnceLock::new();
    SEEDS.get_or_init(|| fuzz::corpus("urdf"))
}

/// Every corpus file loads or gives its named error; the reproducers give theirs.
#[test]
fn corpus_files_load_or_name_their_error() {
    // File name → what its error must say (None: it loads).
    let expect: &[(&str, Option<&[&str]>)] = &[
        ("tracked-sensorbox.urdf", None),
        ("mecanum-rover.urdf", None),
        ("deep-chain-1000.urdf", None),
        (
            "mass-heavy.urdf",
            Some(&[
                ":41:13: ",
                "<link name=\"base_link\">",
                "<mass value>",
                "heavy",
            ]),
        ),
        (
            "mass-missing.urdf",
            Some(&[":41:7: ", "<link name=\"base_link\">", "<mass>", "missing"]),
        ),
        (
            "mass-1e30.urdf",
            Some(&["<link name=\"base_link\">", "MAX_LINK_MASS_KG"]),
        ),
        ("sdf-root.urdf", Some(&[":2:1: <sdf>", "SDF", "URDF"])),
        ("truncated.urdf", Some(&["not a valid URDF", "truncated"])),
        ("deep-nesting.urdf", Some(&["MAX_URDF_DEPTH"])),
        ("joint-cycle.urdf", Some(&["cycle", "loop_"])),
    ];
    let corpus = seeds();
    for (path, bytes) in corpus {
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        check(&name, bytes);
        let Some((_, want)) = expect.iter().find(|(n, _)| *n == name) else {
            panic!("{name}: a corpus file without an expectation in this test");
        };
        let r = RobotModel::from_urdf_file(path);
        match (want, r) {
            (None, Ok(_)) => {}
            (None, Err(e)) => panic!("{name}: {e}"),
            (Some(_), Ok(_)) => panic!("{name}: loaded, but an error was expected"),
            (Some(needles), Err(e)) => {
                let msg = e.to_string();
                for n in *needles {
                    assert!(msg.contains(n), "{name}: `{n}` not in: {msg}");
                }
            }
        }
    }
    assert_eq!(corpus.len(), expect.len(), "every expectation has its file");
}

proptest! {
    #![proptest_config(fuzz::config())]

    /// Mutated corpus files: no panic, no abort, a robot or a named error.
    #[test]
    fn mutated_urdfs_load_or_name_their_error(seed in any::<prop::sample::Index>(), e in edit()) {
        let corpus = seeds();
        let (path, bytes) = &corpus[seed.index(corpus.len())];
        let input = apply(bytes, &e);
        check(&format!("{} with {e:?}", path.display()), &input);
    }
}
