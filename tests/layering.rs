//! The module layout of docs/architecture.md, checked: data flows one way through the pipeline
//! (a module names only modules of its own layer or below) and no two modules import each other,
//! directly or around a circle, at any depth.
//!
//! It reads `src/` as text: every `crate::…` and `super::…` path outside comments, brace groups
//! included, resolved to the deepest module file that exists. A child naming its own ancestor
//! (`super::Item` of the parent's `mod.rs`) is Rust's ordinary module nesting, not an import
//! between modules, and is not counted.
#![allow(clippy::unwrap_used, clippy::items_after_statements)]

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Pipeline layers, lowest first (docs/architecture.md). `error` gathers every stage's error
/// type into `crate::Error` for the binary, so it is the one module that names all others.
const LAYERS: &[&[&str]] = &[
    &["crs", "raster", "tiling", "geom", "gpu"],
    &["tin", "codec", "lod"],
    &["store", "model"],
    &["formats", "bake", "heights"],
    &["server", "client"],
    &["eval"],
    &["cli", "main", "error", "lib"],
];

fn layer_of(top: &str) -> Option<usize> {
    LAYERS.iter().position(|l| l.contains(&top))
}

type Module = Vec<String>;

fn modules(src: &Path) -> BTreeMap<Module, PathBuf> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<Module, PathBuf>) {
        let mut entries: Vec<_> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).collect();
        entries.sort();
        for p in entries {
            if p.is_dir() {
                walk(root, &p, out);
            } else if p.extension().is_some_and(|e| e == "rs") {
                let rel = p.strip_prefix(root).unwrap().with_extension("");
                let mut parts: Module = rel.iter().map(|s| s.to_string_lossy().into_owned()).collect();
                if parts.last().is_some_and(|l| l == "mod") {
                    parts.pop();
                }
                out.insert(parts, p);
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(src, src, &mut out);
    out
}

/// The source without comments (line comments and doc comments; block comments are not used).
fn code(text: &str) -> String {
    text.lines()
        .map(|l| {
            // A `//` inside a string literal would cut a line short; only whole paths matter here
            // and the crate writes no `crate::` inside strings after a `//`.
            match l.find("//") {
                Some(i) => &l[..i],
                None => l,
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
}

fn ident(s: &[u8], mut i: usize) -> (String, usize) {
    let start = i;
    while i < s.len() && (s[i].is_ascii_alphanumeric() || s[i] == b'_') {
        i += 1;
    }
    (String::from_utf8_lossy(&s[start..i]).into_owned(), i)
}

/// Every path that follows `at` (just after a `crate::` or `super::`), with brace groups
/// expanded: `{a, b::{c, d}}` gives `a`, `b::c`, `b::d`.
fn paths_at(s: &[u8], mut i: usize, prefix: &[String], out: &mut Vec<Vec<String>>) -> usize {
    let mut path = prefix.to_vec();
    loop {
        while i < s.len() && s[i].is_ascii_whitespace() {
            i += 1;
        }
        if i < s.len() && s[i] == b'{' {
            i += 1;
            loop {
                while i < s.len() && (s[i].is_ascii_whitespace() || s[i] == b',') {
                    i += 1;
                }
                if i >= s.len() || s[i] == b'}' {
                    return i + 1;
                }
                let before = i;
                i = paths_at(s, i, &path, out);
                if i == before {
                    i += 1;
                }
            }
        }
        let (id, j) = ident(s, i);
        if id.is_empty() {
            out.push(path);
            return i;
        }
        path.push(id);
        i = j;
        if s.get(i..i + 2) == Some(b"::") {
            i += 2;
        } else {
            out.push(path);
            return i;
        }
    }
}

fn references(module: &Module, text: &str) -> Vec<Vec<String>> {
    let c = code(text);
    let s = c.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while i < s.len() {
        let boundary = i == 0 || !(s[i - 1].is_ascii_alphanumeric() || s[i - 1] == b'_' || s[i - 1] == b':');
        if boundary && s[i..].starts_with(b"crate::") {
            i = paths_at(s, i + 7, &[], &mut out);
        } else if boundary && s[i..].starts_with(b"super::") {
            // `super` of a module is its parent; chains of `super::super::` climb further.
            let mut base: Vec<String> = module[..module.len().saturating_sub(1)].to_vec();
            let mut j = i + 7;
            while s[j..].starts_with(b"super::") {
                base.pop();
                j += 7;
            }
            i = paths_at(s, j, &base, &mut out);
        } else {
            i += 1;
        }
    }
    out
}

fn resolve(all: &BTreeMap<Module, PathBuf>, path: &[String]) -> Option<Module> {
    (1..=path.len()).rev().map(|n| path[..n].to_vec()).find(|p| all.contains_key(p))
}

fn edges() -> BTreeMap<Module, BTreeSet<Module>> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let all = modules(&src);
    let mut edges: BTreeMap<Module, BTreeSet<Module>> = BTreeMap::new();
    for (m, file) in &all {
        let text = std::fs::read_to_string(file).unwrap();
        // `main.rs` is the binary's root: its `crate::` is the binary, whose modules live in cli/.
        let m = if m == &["main".to_string()] { vec!["cli".to_string()] } else { m.clone() };
        for p in references(&m, &text) {
            let Some(t) = resolve(&all, &p) else { continue };
            // Naming an ancestor (or itself) is nesting, not an import between modules.
            if m.starts_with(&t) {
                continue;
            }
            edges.entry(m.clone()).or_default().insert(t);
        }
    }
    edges
}

fn name(m: &Module) -> String {
    m.join("::")
}

#[test]
fn no_module_imports_one_above_it_in_the_pipeline() {
    let mut wrong = Vec::new();
    for (from, tos) in edges() {
        let Some(lf) = layer_of(&from[0]) else {
            wrong.push(format!("{} is in no layer of docs/architecture.md", name(&from)));
            continue;
        };
        if from[0] == "error" || from[0] == "lib" {
            continue;
        }
        for to in tos {
            match layer_of(&to[0]) {
                Some(lt) if lt > lf => {
                    wrong.push(format!("{} imports {} (a later stage)", name(&from), name(&to)));
                }
                None => wrong.push(format!("{} is in no layer of docs/architecture.md", name(&to))),
                _ => {}
            }
        }
    }
    wrong.sort();
    wrong.dedup();
    assert!(wrong.is_empty(), "imports against the pipeline:\n{}", wrong.join("\n"));
}

#[test]
fn no_import_circles() {
    let edges = edges();
    // Tarjan's strongly connected components over the module graph.
    struct T<'a> {
        edges: &'a BTreeMap<Module, BTreeSet<Module>>,
        index: BTreeMap<Module, usize>,
        low: BTreeMap<Module, usize>,
        stack: Vec<Module>,
        on: BTreeSet<Module>,
        next: usize,
        circles: Vec<Vec<String>>,
    }
    impl T<'_> {
        fn visit(&mut self, v: &Module) {
            self.index.insert(v.clone(), self.next);
            self.low.insert(v.clone(), self.next);
            self.next += 1;
            self.stack.push(v.clone());
            self.on.insert(v.clone());
            let empty = BTreeSet::new();
            for w in self.edges.get(v).unwrap_or(&empty) {
                if !self.index.contains_key(w) {
                    self.visit(w);
                    let lw = self.low[w];
                    let lv = self.low.get_mut(v).unwrap();
                    *lv = (*lv).min(lw);
                } else if self.on.contains(w) {
                    let iw = self.index[w];
                    let lv = self.low.get_mut(v).unwrap();
                    *lv = (*lv).min(iw);
                }
            }
            if self.low[v] == self.index[v] {
                let mut comp = Vec::new();
                loop {
                    let w = self.stack.pop().unwrap();
                    self.on.remove(&w);
                    comp.push(name(&w));
                    if &w == v {
                        break;
                    }
                }
                if comp.len() > 1 {
                    comp.sort();
                    self.circles.push(comp);
                }
            }
        }
    }
    let mut t = T {
        edges: &edges,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on: BTreeSet::new(),
        next: 0,
        circles: Vec::new(),
    };
    let nodes: BTreeSet<Module> =
        edges.iter().flat_map(|(k, v)| std::iter::once(k.clone()).chain(v.iter().cloned())).collect();
    for v in &nodes {
        if !t.index.contains_key(v) {
            t.visit(v);
        }
    }
    let lines: Vec<String> = t.circles.iter().map(|c| c.join(" <-> ")).collect();
    assert!(lines.is_empty(), "modules that import each other:\n{}", lines.join("\n"));
}

/// The checker itself: brace groups, `super` chains and comments.
#[test]
fn the_reader_finds_grouped_and_relative_paths() {
    let m: Module = vec!["server".into(), "http".into()];
    let refs = references(
        &m,
        "use crate::{codec, store::{Store, SUBTREE_LEVELS}};\n// crate::eval::x in a comment\nuse super::super::tiling::TileKey;\nlet a = super::cache::Entry;",
    );
    let got: BTreeSet<String> = refs.iter().map(|p| p.join("::")).collect();
    for want in ["codec", "store::Store", "store::SUBTREE_LEVELS", "tiling::TileKey", "server::cache::Entry"]
    {
        assert!(got.contains(want), "{want} not found in {got:?}");
    }
    assert!(!got.iter().any(|p| p.starts_with("eval")), "a comment was read: {got:?}");
}
