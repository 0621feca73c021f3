//! The module layout follows the data flow: within every module of every workspace crate,
//! the sibling modules import each other without a cycle.
//!
//! Each crate's sources are parsed with `syn`. Every path the shipped code names (`use`
//! items, and `crate::`/`super::`/`self::` paths in expressions and types) is resolved to
//! the module it lands in; a reference from module `a::x::..` to `a::y::..` is an edge
//! `x → y` among the children of `a`. References between a module and its own ancestors
//! or descendants are not sibling edges (a parent declares its children and re-exports;
//! children use the types their parent defines). Test code (`#[cfg(test)]` modules and
//! files) is exempt: a test may reach any module to set up its case, but what ships is
//! layered. Limits: paths inside macro invocations are not seen, and a name reached
//! through a parent's re-export counts as the parent's.

// Test helpers panic on failure by design.
#![allow(clippy::unwrap_used)]

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use syn::visit::Visit;

/// The crates of the workspace, by their source folders.
const CRATE_SOURCES: &[&str] = &["src", "msgs/src", "sim/src", "onboard/src"];

/// A module path inside one crate (`["render", "bvh"]`); the crate root is empty.
type ModPath = Vec<String>;

/// A reference from one module to another, with where it was written.
#[derive(Clone, Debug)]
struct Reference {
    from: ModPath,
    to: Vec<String>,
    file: PathBuf,
}

/// What one crate's sources declare and reference.
#[derive(Default)]
struct CrateModules {
    modules: BTreeSet<ModPath>,
    references: Vec<Reference>,
}

/// Walks one file, tracking inline modules and `#[cfg(test)]`.
struct FileVisitor<'a> {
    module: ModPath,
    in_test: u32,
    file: PathBuf,
    out: &'a mut CrateModules,
    test_children: &'a mut BTreeSet<ModPath>,
}

impl FileVisitor<'_> {
    fn record(&mut self, segments: Vec<String>) {
        if self.in_test > 0 || segments.is_empty() {
            return;
        }
        let mut base = self.module.clone();
        let mut rest = segments.as_slice();
        match rest[0].as_str() {
            "crate" => {
                base.clear();
                rest = &rest[1..];
            }
            "super" | "self" => {
                while let Some(s) = rest.first() {
                    match s.as_str() {
                        "super" => {
                            base.pop();
                        }
                        "self" => {}
                        _ => break,
                    }
                    rest = &rest[1..];
                }
            }
            // Other crates, and names brought in by `use` (whose `use` is recorded).
            _ => return,
        }
        base.extend(rest.iter().cloned());
        self.out.references.push(Reference {
            from: self.module.clone(),
            to: base,
            file: self.file.clone(),
        });
    }
}

impl<'ast> Visit<'ast> for FileVisitor<'_> {
    fn visit_item_mod(&mut self, m: &'ast syn::ItemMod) {
        let test = is_cfg_test(&m.attrs);
        let mut child = self.module.clone();
        child.push(m.ident.to_string());
        if test {
            self.test_children.insert(child.clone());
        }
        if m.content.is_none() {
            return;
        }
        self.out.modules.insert(child.clone());
        let saved = std::mem::replace(&mut self.module, child);
        self.in_test += u32::from(test);
        syn::visit::visit_item_mod(self, m);
        self.in_test -= u32::from(test);
        self.module = saved;
    }
    fn visit_path(&mut self, p: &'ast syn::Path) {
        let segments = p.segments.iter().map(|s| s.ident.to_string()).collect();
        self.record(segments);
        syn::visit::visit_path(self, p);
    }
    fn visit_item_use(&mut self, u: &'ast syn::ItemUse) {
        fn flatten(t: &syn::UseTree, prefix: &[String], out: &mut Vec<Vec<String>>) {
            let with = |name: String| {
                let mut v = prefix.to_vec();
                v.push(name);
                v
            };
            match t {
                syn::UseTree::Path(p) => flatten(&p.tree, &with(p.ident.to_string()), out),
                syn::UseTree::Name(n) if n.ident == "self" => out.push(prefix.to_vec()),
                syn::UseTree::Name(n) => out.push(with(n.ident.to_string())),
                syn::UseTree::Rename(r) => out.push(with(r.ident.to_string())),
                syn::UseTree::Glob(_) => out.push(prefix.to_vec()),
                syn::UseTree::Group(g) => g.items.iter().for_each(|i| flatten(i, prefix, out)),
            }
        }
        let mut paths = Vec::new();
        flatten(&u.tree, &[], &mut paths);
        for p in paths {
            self.record(p);
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
            // `src/bin/*` are separate crates.
            if p.file_name().is_some_and(|n| n != "bin") {
                rust_files(&p, out);
            }
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The module a file defines: `lib.rs` the root, `a/mod.rs` and `a.rs` module `a`.
fn module_of(src: &Path, file: &Path) -> ModPath {
    let rel = file.strip_prefix(src).unwrap().with_extension("");
    let mut parts: Vec<String> = rel
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    if matches!(parts.last().map(String::as_str), Some("lib" | "mod")) {
        parts.pop();
    }
    parts
}

/// Parses a crate's library sources (`main.rs` is its own crate and not looked at).
fn read_crate(src: &Path) -> CrateModules {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    files.retain(|f| f != &src.join("main.rs"));
    files.sort();
    let mut out = CrateModules::default();
    let mut test_modules = BTreeSet::new();
    let mut parsed = Vec::new();
    for f in files {
        let module = module_of(src, &f);
        let text = std::fs::read_to_string(&f).unwrap();
        let file = syn::parse_file(&text).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
        out.modules.insert(module.clone());
        if is_cfg_test(&file.attrs) {
            test_modules.insert(module.clone());
        }
        parsed.push((f, module, file));
    }
    for (f, module, file) in &parsed {
        let mut v = FileVisitor {
            module: module.clone(),
            in_test: 0,
            file: f.clone(),
            out: &mut out,
            test_children: &mut test_modules,
        };
        v.visit_file(file);
    }
    // Drop what test-only modules (and everything below them) reference.
    out.references.retain(|r| {
        !test_modules
            .iter()
            .any(|t| r.from.len() >= t.len() && r.from[..t.len()] == t[..])
    });
    out
}

/// The sibling edges among the children of each module: parent → (from, to) → evidence.
type SiblingEdges = BTreeMap<ModPath, BTreeMap<(String, String), String>>;

fn sibling_edges(c: &CrateModules) -> SiblingEdges {
    let mut edges = SiblingEdges::new();
    for r in &c.references {
        // The longest prefix of the path that is a module.
        let mut target = r.to.clone();
        while !target.is_empty() && !c.modules.contains(&target) {
            target.pop();
        }
        let common = r
            .from
            .iter()
            .zip(&target)
            .take_while(|(a, b)| a == b)
            .count();
        if common < r.from.len() && common < target.len() {
            let parent = r.from[..common].to_vec();
            edges
                .entry(parent)
                .or_default()
                .entry((r.from[common].clone(), target[common].clone()))
                .or_insert_with(|| {
                    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
                    let file = r.file.strip_prefix(root).unwrap_or(&r.file);
                    format!("{}: {}", file.display(), r.to.join("::"))
                });
        }
    }
    edges
}

/// Every import cycle among sibling modules, each as `parent: a → b → … → a` with the
/// reference that makes each edge.
fn cycles(c: &CrateModules) -> Vec<String> {
    let mut found = Vec::new();
    for (parent, edges) in sibling_edges(c) {
        let nodes: BTreeSet<&String> = edges.keys().flat_map(|(a, b)| [a, b]).collect();
        // Depth-first search for a back edge; one cycle per strongly connected tangle is
        // enough to name the problem.
        let mut state: BTreeMap<&String, u8> = nodes.iter().map(|n| (*n, 0)).collect();
        fn dfs<'a>(
            n: &'a String,
            edges: &'a BTreeMap<(String, String), String>,
            state: &mut BTreeMap<&'a String, u8>,
            stack: &mut Vec<&'a String>,
            found: &mut Vec<Vec<&'a String>>,
        ) {
            state.insert(n, 1);
            stack.push(n);
            for (a, b) in edges.keys() {
                if a != n {
                    continue;
                }
                match state.get(b).copied().unwrap_or(0) {
                    0 => dfs(b, edges, state, stack, found),
                    1 => {
                        let at = stack.iter().position(|s| *s == b).unwrap();
                        found.push(stack[at..].to_vec());
                    }
                    _ => {}
                }
            }
            stack.pop();
            state.insert(n, 2);
        }
        let mut loops = Vec::new();
        for n in &nodes {
            if state[*n] == 0 {
                dfs(n, &edges, &mut state, &mut Vec::new(), &mut loops);
            }
        }
        for l in loops {
            let mut text = format!(
                "in `{}`:",
                if parent.is_empty() {
                    "crate".to_string()
                } else {
                    parent.join("::")
                }
            );
            for (i, a) in l.iter().enumerate() {
                let b = l[(i + 1) % l.len()];
                let why = &edges[&((*a).clone(), b.clone())];
                text.push_str(&format!("\n    {a} → {b}  ({why})"));
            }
            found.push(text);
        }
    }
    found
}

#[test]
fn no_module_imports_its_sibling_back() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut report = Vec::new();
    for src in CRATE_SOURCES {
        let c = read_crate(&root.join(src));
        assert!(c.modules.len() > 1, "{src}: no modules found");
        assert!(!c.references.is_empty(), "{src}: no references found");
        for cycle in cycles(&c) {
            report.push(format!("{src} {cycle}"));
        }
    }
    assert!(
        report.is_empty(),
        "modules import each other (move the shared item to the lower module, or to \
         vinebench-msgs):\n{}",
        report.join("\n")
    );
}

/// Writes a small crate into a temporary folder and reads it.
fn crate_of(files: &[(&str, &str)]) -> (tempfile::TempDir, CrateModules) {
    let dir = tempfile::tempdir().unwrap();
    for (name, text) in files {
        let p = dir.path().join(name);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, text).unwrap();
    }
    let c = read_crate(dir.path());
    (dir, c)
}

/// The check itself must catch what it is meant to catch, and nothing else.
#[test]
fn the_cycle_check_finds_mutual_imports() {
    let lib = "pub mod a;\npub mod b;\npub mod c;\n";
    // Direct, through a `use` group, through `super::`, and a three-module ring.
    for files in [
        vec![
            ("a.rs", "use crate::b::B; pub struct A;"),
            (
                "b.rs",
                "pub struct B; fn f() -> crate::a::A { crate::a::A }",
            ),
        ],
        vec![
            ("a.rs", "use crate::{b::{B}, c}; pub struct A;"),
            ("b.rs", "use super::a::A; pub struct B;"),
        ],
        vec![
            ("a.rs", "use crate::b::B;"),
            ("b.rs", "pub struct B; use crate::c::C;"),
            ("c.rs", "pub struct C; use crate::a;"),
        ],
        // Inside a nested module folder, and an inline module reaching out.
        vec![
            ("a/mod.rs", "pub mod x; pub mod y;"),
            ("a/x.rs", "use super::y::Y; pub struct X;"),
            ("a/y.rs", "pub struct Y; mod inner { use crate::a::x::X; }"),
        ],
    ] {
        let mut all = vec![("lib.rs", lib)];
        all.extend(files.iter().copied());
        let (_d, c) = crate_of(&all);
        assert!(!cycles(&c).is_empty(), "not caught: {files:?}");
    }
    for files in [
        // A layered chain, a child using its parent's types, a parent re-exporting.
        vec![
            ("a.rs", "use crate::b::B; use crate::c::C;"),
            ("b.rs", "pub struct B; use crate::c::C;"),
            ("c.rs", "pub struct C; use std::fmt;"),
        ],
        vec![
            ("a/mod.rs", "pub mod x; pub use x::X; pub struct P;"),
            ("a/x.rs", "pub struct X; use super::P;"),
        ],
        // Test code may reach up.
        vec![
            ("a.rs", "use crate::b::B;"),
            (
                "b.rs",
                "pub struct B;\n#[cfg(test)]\nmod tests { use crate::a; }",
            ),
            ("c.rs", "#![cfg(test)]\nuse crate::a;"),
        ],
    ] {
        let mut all = vec![("lib.rs", lib)];
        all.extend(files.iter().copied());
        let (_d, c) = crate_of(&all);
        assert!(cycles(&c).is_empty(), "false alarm: {:?}", cycles(&c));
    }
}
