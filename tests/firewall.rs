//! The ground-truth firewall: the algorithms see only sensor messages.
//!
//! Every Rust file under `src/estimator/` and `src/mapper/` is parsed with `syn`, and
//! every path it names (in `use` items, expressions, types, macros' paths) must start
//! with an allowed root: the message crate, nalgebra, serde, thiserror, pure computation
//! crates (rayon, kiddo, rustc_hash), libc's allocator, the standard library, or the algorithm modules
//! themselves. Anything that could reach simulator truth (`vinebench_sim`, or
//! `crate::runner`, `crate::scoring`, ...) fails the test, naming file and path.

// Test helpers panic on failure by design.
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use syn::visit::Visit;

/// The algorithm folders behind the firewall (SLAM joins this list).
const ALGORITHM_DIRS: &[&str] = &["src/estimator", "src/mapper", "src/slam"];

/// Path roots an algorithm may name.
const ALLOWED_ROOTS: &[&str] = &[
    "vinebench_msgs",
    "nalgebra",
    "serde",
    "thiserror",
    // Pure computation crates (threads, k-d trees, hashing): they reach no truth.
    "rayon",
    "kiddo",
    "rustc_hash",
    // A tag detector on image pixels (AprilTag 3, for loop closure): it reaches no truth.
    "apriltag",
    // A Wavefront OBJ parser (the mapper reads meshes back): it reaches no truth.
    "tobj",
    // The C library's allocator (the mapper hands freed memory back with malloc_trim).
    "libc",
    "std",
    "core",
    "alloc",
    "self",
    "super",
    "Self",
    // Primitive types and the prelude (`f64::EPSILON`, `Option::Some`, `Vec::new`).
    "f64",
    "f32",
    "i8",
    "i16",
    "i32",
    "i64",
    "i128",
    "isize",
    "u8",
    "u16",
    "u32",
    "u64",
    "u128",
    "usize",
    "bool",
    "char",
    "str",
    "Option",
    "Result",
    "Vec",
    "Box",
    "String",
    "Default",
    "Iterator",
    "IntoIterator",
    "From",
    "Into",
    "Clone",
    "PartialEq",
    "PartialOrd",
    "Ord",
    "Eq",
];

/// Within `crate::`, only the algorithm modules themselves.
const ALLOWED_CRATE_MODULES: &[&str] = &["estimator", "mapper", "slam"];

/// Crates that must never appear, even in test code.
const FORBIDDEN_ANYWHERE: &[&str] = &["vinebench_sim"];

struct PathCollector {
    in_test: u32,
    found: Vec<(String, bool)>,
}

impl<'ast> Visit<'ast> for PathCollector {
    fn visit_item_mod(&mut self, m: &'ast syn::ItemMod) {
        let is_test = is_cfg_test(&m.attrs);
        if is_test {
            self.in_test += 1;
        }
        syn::visit::visit_item_mod(self, m);
        if is_test {
            self.in_test -= 1;
        }
    }
    fn visit_path(&mut self, p: &'ast syn::Path) {
        let s: Vec<String> = p.segments.iter().map(|s| s.ident.to_string()).collect();
        self.found.push((s.join("::"), self.in_test > 0));
        syn::visit::visit_path(self, p);
    }
    fn visit_use_tree(&mut self, t: &'ast syn::UseTree) {
        fn flatten(t: &syn::UseTree, prefix: &str, out: &mut Vec<String>) {
            match t {
                syn::UseTree::Path(p) => flatten(&p.tree, &format!("{prefix}{}::", p.ident), out),
                syn::UseTree::Name(n) => out.push(format!("{prefix}{}", n.ident)),
                syn::UseTree::Rename(r) => out.push(format!("{prefix}{}", r.ident)),
                syn::UseTree::Glob(_) => out.push(format!("{prefix}*")),
                syn::UseTree::Group(g) => g.items.iter().for_each(|i| flatten(i, prefix, out)),
            }
        }
        let mut out = Vec::new();
        flatten(t, "", &mut out);
        for p in out {
            self.found.push((p, self.in_test > 0));
        }
    }
}

/// `#[cfg(test)]` (or `#![cfg(test)]` at the top of a file) among the attributes.
fn is_cfg_test(attrs: &[syn::Attribute]) -> bool {
    attrs.iter().any(|a| {
        a.path().is_ident("cfg")
            && a.meta
                .require_list()
                .is_ok_and(|l| l.tokens.to_string().trim() == "test")
    })
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// Checks one file's source; returns the violations.
fn violations(src: &str, local_items: &[String]) -> Vec<String> {
    let file = syn::parse_file(src).expect("algorithm sources parse");
    // A file that is test-only as a whole (`#![cfg(test)]`) is test code throughout.
    let mut c = PathCollector {
        in_test: u32::from(is_cfg_test(&file.attrs)),
        found: Vec::new(),
    };
    c.visit_file(&file);
    let mut bad = Vec::new();
    for (path, in_test) in c.found {
        let root = path.split("::").next().unwrap_or_default();
        if FORBIDDEN_ANYWHERE.contains(&root) {
            bad.push(path);
            continue;
        }
        if root == "crate" {
            let module = path.split("::").nth(1).unwrap_or_default();
            if !ALLOWED_CRATE_MODULES.contains(&module) {
                bad.push(path);
            }
            continue;
        }
        // Multi-segment paths must start at an allowed crate; single identifiers are
        // local names (variables, types, functions, prelude items).
        let external = path.contains("::") && !local_items.iter().any(|l| l == root);
        if external && !ALLOWED_ROOTS.contains(&root) && !in_test {
            bad.push(path);
        }
    }
    bad
}

/// Names that may start a path because the algorithm files define or import them
/// (`Eif::new`, `FixStatus::RtkFixed`, ...): every identifier brought into scope by a
/// `use` or defined at item level is a local root.
fn local_roots(src: &str) -> Vec<String> {
    let file = syn::parse_file(src).expect("algorithm sources parse");
    struct Items(Vec<String>);
    impl<'ast> Visit<'ast> for Items {
        fn visit_item(&mut self, i: &'ast syn::Item) {
            let name = match i {
                syn::Item::Struct(s) => Some(s.ident.to_string()),
                syn::Item::Enum(s) => Some(s.ident.to_string()),
                syn::Item::Fn(s) => Some(s.sig.ident.to_string()),
                syn::Item::Mod(s) => Some(s.ident.to_string()),
                syn::Item::Trait(s) => Some(s.ident.to_string()),
                syn::Item::Type(s) => Some(s.ident.to_string()),
                syn::Item::Const(s) => Some(s.ident.to_string()),
                syn::Item::Static(s) => Some(s.ident.to_string()),
                _ => None,
            };
            self.0.extend(name);
            syn::visit::visit_item(self, i);
        }
        fn visit_use_tree(&mut self, t: &'ast syn::UseTree) {
            match t {
                syn::UseTree::Name(n) => self.0.push(n.ident.to_string()),
                syn::UseTree::Rename(r) => self.0.push(r.rename.to_string()),
                _ => {}
            }
            syn::visit::visit_use_tree(self, t);
        }
        fn visit_generics(&mut self, g: &'ast syn::Generics) {
            for p in g.type_params() {
                self.0.push(p.ident.to_string());
            }
            syn::visit::visit_generics(self, g);
        }
    }
    let mut v = Items(Vec::new());
    v.visit_file(&file);
    v.0
}

#[test]
fn algorithms_cannot_reach_simulator_truth() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    for d in ALGORITHM_DIRS {
        rust_files(&root.join(d), &mut files);
    }
    assert!(!files.is_empty(), "no algorithm sources found");
    // Names defined anywhere behind the firewall count as local for every file.
    let mut locals = Vec::new();
    for f in &files {
        locals.extend(local_roots(&std::fs::read_to_string(f).unwrap()));
    }
    let mut report = Vec::new();
    for f in &files {
        for v in violations(&std::fs::read_to_string(f).unwrap(), &locals) {
            report.push(format!(
                "{}: `{v}`",
                f.strip_prefix(root).unwrap_or(f).display()
            ));
        }
    }
    assert!(
        report.is_empty(),
        "the ground-truth firewall is breached (algorithms may use only vinebench_msgs, \
         nalgebra, serde, thiserror, rayon, kiddo, rustc_hash, std and their own modules):\n{}",
        report.join("\n")
    );
}

/// The check itself must catch what it is meant to catch.
#[test]
fn the_firewall_check_rejects_forbidden_paths() {
    let locals = vec!["Eif".to_string()];
    for src in [
        "use vinebench_sim::truth::TruthSample;",
        "fn f() { let _ = vinebench_sim::rng::stream(1, \"x\"); }",
        "use crate::runner::simulate;",
        "fn f() -> crate::scoring::ScoringParams { todo!() }",
        "use rand::Rng;",
        "#[cfg(test)] mod tests { use vinebench_sim::world::World; }",
        "#![cfg(test)]\nuse vinebench_sim::world::World;",
        "#[cfg(not(test))] mod m { use rand::Rng; }",
        "fn f() { ::vinebench_sim::rng::stream(1, \"x\"); }",
    ] {
        assert!(!violations(src, &locals).is_empty(), "not caught: {src}");
    }
    for src in [
        "use vinebench_msgs::{Message, Nanos};",
        "use nalgebra::Matrix3; use crate::estimator::EstimatorStats;",
        "fn f() { let _ = Eif::new(); let _ = std::f64::consts::PI; }",
        "#[cfg(test)] mod tests { use rand::Rng; }",
        "#![cfg(test)]\nuse rand::Rng;",
    ] {
        assert!(violations(src, &locals).is_empty(), "false alarm: {src}");
    }
}
