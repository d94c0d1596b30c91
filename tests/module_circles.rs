//! Modules inside a crate do not import each other in circles: for every folder of modules
//! (`src/` of each crate and plugin, and their subfolders), the `crate::` paths of each module's
//! code (comments and `#[cfg(test)]` modules left out) are its edges, a folder module counting
//! the paths of every file inside it, and every strongly connected component of more than one
//! module is a circle, and fails the test.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The module names a module's code reaches through `crate::`: `crate::a::…`, and each first
/// segment of a `use crate::{a, b::c}` group.
fn edges_of(code: &str) -> BTreeSet<String> {
    let code: String = code
        .split("#[cfg(test)]")
        .next()
        .unwrap_or("")
        .lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n");
    let ident = |s: &str| -> String { s.chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '_').collect() };
    let mut out = BTreeSet::new();
    for (i, _) in code.match_indices("crate::") {
        let before = code[..i].chars().last();
        if before.is_some_and(|c| c.is_ascii_alphanumeric() || c == '_') {
            continue; // `hilo_crate::`, not `crate::`
        }
        let rest = &code[i + "crate::".len()..];
        if let Some(group) = rest.strip_prefix('{') {
            let body = &group[..group.find('}').unwrap_or(group.len())];
            out.extend(body.split(',').map(|p| ident(p.trim())).filter(|s| !s.is_empty()));
        } else {
            let m = ident(rest);
            if !m.is_empty() {
                out.insert(m);
            }
        }
    }
    out
}

/// Module name → the modules of the same folder it reaches. A folder module (a subfolder with a
/// `mod.rs`) is one node whose edges are those of every file inside it, at any depth: a file
/// deep in `validation/` that reaches `crate::study` is an edge of `validation`.
fn graph(dir: &Path) -> BTreeMap<String, BTreeSet<String>> {
    fn edges_below(d: &Path) -> BTreeSet<String> {
        let mut out = BTreeSet::new();
        for e in std::fs::read_dir(d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                out.extend(edges_below(&p));
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.extend(edges_of(&std::fs::read_to_string(&p).unwrap()));
            }
        }
        out
    }
    let mut nodes: Vec<(String, BTreeSet<String>)> = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "rs") {
            let name = p.file_stem().unwrap().to_string_lossy().into_owned();
            nodes.push((name, edges_of(&std::fs::read_to_string(&p).unwrap())));
        } else if p.is_dir() && p.join("mod.rs").is_file() {
            nodes.push((p.file_name().unwrap().to_string_lossy().into_owned(), edges_below(&p)));
        }
    }
    let names: BTreeSet<String> = nodes.iter().map(|(n, _)| n.clone()).collect();
    nodes
        .into_iter()
        .map(|(name, edges)| {
            let e = edges.into_iter().filter(|m| names.contains(m) && *m != name).collect();
            (name, e)
        })
        .collect()
}

/// Strongly connected components of more than one module (Tarjan), each sorted.
fn circles(g: &BTreeMap<String, BTreeSet<String>>) -> BTreeSet<Vec<String>> {
    struct T<'a> {
        g: &'a BTreeMap<String, BTreeSet<String>>,
        index: BTreeMap<&'a str, usize>,
        low: BTreeMap<&'a str, usize>,
        stack: Vec<&'a str>,
        on: BTreeSet<&'a str>,
        out: BTreeSet<Vec<String>>,
    }
    fn visit<'a>(t: &mut T<'a>, v: &'a str) {
        let i = t.index.len();
        t.index.insert(v, i);
        t.low.insert(v, i);
        t.stack.push(v);
        t.on.insert(v);
        for w in t.g[v].iter().map(String::as_str) {
            if !t.index.contains_key(w) {
                visit(t, w);
                let lw = t.low[w];
                let lv = t.low.get_mut(v).unwrap();
                *lv = (*lv).min(lw);
            } else if t.on.contains(w) {
                let iw = t.index[w];
                let lv = t.low.get_mut(v).unwrap();
                *lv = (*lv).min(iw);
            }
        }
        if t.low[v] == t.index[v] {
            let mut comp = Vec::new();
            while let Some(w) = t.stack.pop() {
                t.on.remove(w);
                comp.push(w.to_owned());
                if w == v {
                    break;
                }
            }
            if comp.len() > 1 {
                comp.sort();
                t.out.insert(comp);
            }
        }
    }
    let mut t = T {
        g,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on: BTreeSet::new(),
        out: BTreeSet::new(),
    };
    for v in g.keys() {
        if !t.index.contains_key(v.as_str()) {
            visit(&mut t, v);
        }
    }
    t.out
}

/// Every folder of modules in the workspace.
fn module_dirs(root: &Path) -> Vec<PathBuf> {
    fn walk(d: &Path, out: &mut Vec<PathBuf>) {
        if std::fs::read_dir(d).unwrap().any(|e| e.unwrap().path().extension().is_some_and(|x| x == "rs")) {
            out.push(d.to_path_buf());
        }
        for e in std::fs::read_dir(d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(&p, out);
            }
        }
    }
    let mut out = Vec::new();
    for top in ["crates", "plugins"] {
        for c in std::fs::read_dir(root.join(top)).unwrap() {
            let src = c.unwrap().path().join("src");
            if src.is_dir() {
                walk(&src, &mut out);
            }
        }
    }
    walk(&root.join("src"), &mut out);
    out.sort();
    out
}

#[test]
fn no_module_imports_another_in_a_circle() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dirs = module_dirs(root);
    assert!(dirs.len() >= 14, "found only {} module folders", dirs.len());
    let mut found = Vec::new();
    for d in &dirs {
        let rel = d.strip_prefix(root).unwrap().to_string_lossy().into_owned();
        for c in circles(&graph(d)) {
            found.push(format!("{rel}: {}", c.join(" ↔ ")));
        }
    }
    assert!(found.is_empty(), "modules importing each other in a circle:\n{}", found.join("\n"));
}

#[test]
fn a_planted_circle_is_found() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("a.rs"), "use crate::b::B;\n// crate::c in a comment is no edge\npub struct A;\n")
        .unwrap();
    std::fs::write(d.path().join("b.rs"), "use crate::{error::Result, c};\npub struct B;\n").unwrap();
    std::fs::write(
        d.path().join("c.rs"),
        "pub fn f() -> crate::a::A { crate::a::A }\n#[cfg(test)]\nmod tests { use crate::error; }\n",
    )
    .unwrap();
    std::fs::write(d.path().join("error.rs"), "pub type Result = ();\nuse hilo_crate::a;\n").unwrap();
    let g = graph(d.path());
    assert_eq!(g["error"], BTreeSet::new(), "a test module and a longer crate name are no edges");
    assert_eq!(circles(&g), BTreeSet::from([vec!["a".to_owned(), "b".to_owned(), "c".to_owned()]]));
    // Cut one edge: no circle.
    std::fs::write(d.path().join("c.rs"), "pub fn f() {}\n").unwrap();
    assert!(circles(&graph(d.path())).is_empty());
    // Through a folder module: a file deep inside `v/` reaches `a`, and `a` reaches `v`.
    std::fs::create_dir_all(d.path().join("v/deep")).unwrap();
    std::fs::write(d.path().join("v/mod.rs"), "pub mod deep;\npub struct X;\n").unwrap();
    std::fs::write(d.path().join("v/deep/mod.rs"), "pub fn g() -> crate::a::A { crate::a::A }\n").unwrap();
    std::fs::write(d.path().join("c.rs"), "pub fn f() -> crate::v::X { crate::v::X }\n").unwrap();
    assert_eq!(
        circles(&graph(d.path())),
        BTreeSet::from([vec!["a".to_owned(), "b".to_owned(), "c".to_owned(), "v".to_owned()]])
    );
    // A folder's own paths to itself are no edge.
    std::fs::write(d.path().join("v/deep/mod.rs"), "pub fn g() -> crate::v::X { crate::v::X }\n").unwrap();
    assert!(circles(&graph(d.path())).is_empty());
}

/// Plugins are written against the fusion crate alone: no plugin depends (normally, as a build
/// or as a dev dependency) on the detector runtime, the dataset or the study, nor on another
/// plugin.
#[test]
fn plugins_depend_on_the_fusion_crate_only() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut seen = 0;
    for p in std::fs::read_dir(root.join("plugins")).unwrap() {
        let manifest = p.unwrap().path().join("Cargo.toml");
        let Ok(text) = std::fs::read_to_string(&manifest) else { continue };
        let doc: toml::Table = text.parse().unwrap();
        for section in ["dependencies", "dev-dependencies", "build-dependencies"] {
            let Some(deps) = doc.get(section).and_then(|d| d.as_table()) else { continue };
            let hilo: Vec<&String> = deps.keys().filter(|k| k.starts_with("hilo")).collect();
            assert!(
                hilo.iter().all(|k| *k == "hilo-fusion" || *k == "hilo-core"),
                "{}: [{section}] names {hilo:?}; a plugin depends on hilo-fusion (and hilo-core) only",
                manifest.display()
            );
        }
        seen += 1;
    }
    assert!(seen >= 4, "found {seen} plugin crates");
}

/// The lines of each function of `code` (outside `#[cfg(test)]` modules): from its `fn` line to
/// the closing brace at the same indentation.
fn function_lengths(code: &str) -> Vec<(String, usize)> {
    let code = code.split("#[cfg(test)]").next().unwrap_or("");
    let lines: Vec<&str> = code.lines().collect();
    let mut out = Vec::new();
    for (i, l) in lines.iter().enumerate() {
        let t = l.trim_start();
        let indent = &l[..l.len() - t.len()];
        let sig = t.strip_prefix("pub ").or_else(|| t.strip_prefix("pub(crate) ")).unwrap_or(t);
        let Some(rest) = sig.strip_prefix("fn ") else { continue };
        if l.trim_end().ends_with(';') {
            continue;
        }
        let name: String = rest.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
        let close = format!("{indent}}}");
        if let Some(end) = lines[i + 1..].iter().position(|x| *x == close) {
            out.push((name, end + 2));
        }
    }
    out
}

/// No function of the libraries, plugins or command line is longer than 150 lines (tests
/// aside): a longer one is several steps that deserve names.
#[test]
fn no_function_is_longer_than_150_lines() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut long = Vec::new();
    for d in module_dirs(root) {
        for f in std::fs::read_dir(&d).unwrap() {
            let p = f.unwrap().path();
            if p.extension().is_some_and(|e| e == "rs") {
                for (name, n) in function_lengths(&std::fs::read_to_string(&p).unwrap()) {
                    if n > 150 {
                        long.push(format!("{}: fn {name}, {n} lines", p.strip_prefix(root).unwrap().display()));
                    }
                }
            }
        }
    }
    assert!(long.is_empty(), "functions over 150 lines:\n{}", long.join("\n"));
}

#[test]
fn function_lengths_are_counted_from_fn_to_its_brace() {
    let code = "fn a() {\n    1;\n}\n\n    pub fn b(x: u8) -> u8 {\n        if x > 0 {\n        }\n        x\n    }\nfn c();\n";
    assert_eq!(function_lengths(code), vec![("a".to_string(), 3), ("b".to_string(), 5)]);
}
