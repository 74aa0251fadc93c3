//! The crates' module layout, checked: no import cycle among the files of any folder (a
//! crate's top-level modules, and the modules inside each folder, through `crate::`,
//! `super::` and `self::` paths alike), and the tiers stay below what uses them (the renderer's `util/` imports nothing above it;
//! the coordinator's scheduler knows nothing of the gRPC, HTTP or store-writer layers above
//! it). A cycle means a type in the wrong file, and a newcomer who cannot read one module
//! without the other; this test names the files that make it.
//!
//! Imports are read from the source (`crate::`, `super::` and `self::` paths, in `use` lines
//! and in code), which is all a cycle needs: a module that names another depends on it.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Each top-level module of a crate, with the modules it names and the files that name them.
type Graph = BTreeMap<String, BTreeMap<String, BTreeSet<String>>>;

fn crates_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../crates")
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).expect("read_dir").flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The text without `//` comments, so that a doc link does not count as an import.
fn code(text: &str) -> String {
    text.lines()
        .map(|l| l.split_once("//").map_or(l, |(c, _)| c))
        .collect::<Vec<_>>()
        .join("\n")
}

/// The first path segment of every item a `crate::{a, b::c}` group names.
fn group_heads(group: &str) -> Vec<String> {
    let (mut depth, mut cur, mut out) = (0, String::new(), Vec::new());
    for ch in group.chars() {
        match ch {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => out.push(std::mem::take(&mut cur)),
            _ => {}
        }
        if !(ch == ',' && depth == 0) {
            cur.push(ch);
        }
    }
    out.push(cur);
    out.iter()
        .filter_map(|s| {
            let s = s.trim();
            let head: String = s
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            (!head.is_empty()).then_some(head)
        })
        .collect()
}

/// The top-level modules `text` names through `crate::`.
fn named(text: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let mut rest = text;
    while let Some(i) = rest.find("crate::") {
        let before = rest[..i].chars().last();
        rest = &rest[i + "crate::".len()..];
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
            continue; // `tessera_render::…` is another crate.
        }
        if let Some(group) = rest.strip_prefix('{') {
            let mut depth = 1;
            let end = group
                .char_indices()
                .find(|&(_, c)| {
                    depth += match c {
                        '{' => 1,
                        '}' => -1,
                        _ => 0,
                    };
                    depth == 0
                })
                .map_or(group.len(), |(j, _)| j);
            out.extend(group_heads(&group[..end]));
        } else {
            let head: String = rest
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            if !head.is_empty() {
                out.insert(head);
            }
        }
    }
    out
}

/// The import graph of one crate's top-level modules (`lib.rs` and `main.rs`, the roots, left
/// out: they name every module).
fn graph(krate: &str) -> Graph {
    let src = crates_dir().join(krate).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let module = |p: &Path| -> String {
        let rel = p.strip_prefix(&src).expect("under src");
        let first = rel.components().next().expect("a component");
        first
            .as_os_str()
            .to_string_lossy()
            .trim_end_matches(".rs")
            .to_string()
    };
    let modules: BTreeSet<String> = files.iter().map(|p| module(p)).collect();
    let mut g = Graph::new();
    for p in &files {
        let m = module(p);
        if m == "lib" || m == "main" {
            continue;
        }
        let entry = g.entry(m.clone()).or_default();
        let text = std::fs::read_to_string(p).expect("read");
        for n in named(&code(&text)) {
            if n != m && modules.contains(&n) && n != "lib" && n != "main" {
                entry.entry(n).or_default().insert(
                    p.strip_prefix(crates_dir())
                        .expect("in crates")
                        .display()
                        .to_string(),
                );
            }
        }
    }
    g
}

/// Every module from which `from` can be reached, `from` included.
fn reaches(g: &Graph, from: &str) -> BTreeSet<String> {
    let mut seen = BTreeSet::new();
    let mut stack = vec![from.to_string()];
    while let Some(m) = stack.pop() {
        if seen.insert(m.clone()) {
            stack.extend(g.get(&m).into_iter().flat_map(|e| e.keys().cloned()));
        }
    }
    seen
}

const CRATES: [&str; 5] = ["render", "proto", "coordinator", "worker", "cli"];

#[test]
fn no_crate_has_an_import_cycle_among_its_modules() {
    let mut cycles = Vec::new();
    for krate in CRATES {
        let g = graph(krate);
        // The graph itself, for `cargo test --test layout -- --nocapture`.
        eprintln!("{krate}:");
        for (m, edges) in &g {
            let names: Vec<&str> = edges.keys().map(String::as_str).collect();
            eprintln!("  {m} → {}", names.join(", "));
        }
        assert!(
            g.len() > 1 || krate == "worker" || krate == "proto",
            "{krate}: no modules read"
        );
        for (m, edges) in &g {
            for (n, files) in edges {
                if reaches(&g, n).contains(m) {
                    cycles.push(format!(
                        "{krate}: {m} → {n} (in {}), and {n} leads back to {m}",
                        files.iter().cloned().collect::<Vec<_>>().join(", ")
                    ));
                }
            }
        }
    }
    assert!(cycles.is_empty(), "import cycles:\n{}", cycles.join("\n"));
}

/// A module's path in its crate: `scheduler/after.rs` is `[scheduler, after]`,
/// `scheduler/mod.rs` is `[scheduler]`, `lib.rs` and `main.rs` are `[]`.
type ModPath = Vec<String>;

fn module_path(rel: &Path) -> ModPath {
    let mut parts: Vec<String> = rel
        .components()
        .map(|c| {
            c.as_os_str()
                .to_string_lossy()
                .trim_end_matches(".rs")
                .to_string()
        })
        .collect();
    if matches!(
        parts.last().map(String::as_str),
        Some("mod" | "lib" | "main")
    ) {
        parts.pop();
    }
    parts
}

/// The end of the `{…}` group that `s` opens (the index of its `}`), or `s.len()`.
fn group_end(s: &str) -> usize {
    let mut depth = 0;
    for (i, c) in s.char_indices() {
        depth += match c {
            '{' => 1,
            '}' => -1,
            _ => 0,
        };
        if depth == 0 {
            return i;
        }
    }
    s.len()
}

/// The paths a path tree names, from its first segment: `a::{b, c::{d, e}}` is `[a, b]`,
/// `[a, c, d]` and `[a, c, e]`.
fn tree(s: &str) -> Vec<ModPath> {
    let s = s.trim_start();
    if s.starts_with('{') {
        let end = group_end(s);
        let inner = &s[1..end];
        let (mut depth, mut start, mut out) = (0, 0, Vec::new());
        for (i, c) in inner.char_indices() {
            match c {
                '{' => depth += 1,
                '}' => depth -= 1,
                ',' if depth == 0 => {
                    out.extend(tree(&inner[start..i]));
                    start = i + 1;
                }
                _ => {}
            }
        }
        out.extend(tree(&inner[start..]));
        return out;
    }
    let ident: String = s
        .chars()
        .take_while(|c| c.is_alphanumeric() || *c == '_')
        .collect();
    if ident.is_empty() {
        return vec![Vec::new()];
    }
    match s[ident.len()..].strip_prefix("::") {
        Some(rest) => tree(rest)
            .into_iter()
            .map(|mut p| {
                p.insert(0, ident.clone());
                p
            })
            .collect(),
        None => vec![vec![ident]],
    }
}

/// Every module path `text` names through `crate::`, `super::` or `self::`, resolved from the
/// module at `here`. An inline `mod tests` (whose `super` is the file's own module) is left
/// out.
fn resolved(text: &str, here: &[String]) -> Vec<ModPath> {
    let text = text.split("mod tests {").next().unwrap_or(text);
    let mut out = Vec::new();
    for (i, _) in text.match_indices("::") {
        let head_start = text[..i]
            .rfind(|c: char| !(c.is_alphanumeric() || c == '_'))
            .map_or(0, |j| j + 1);
        let head = &text[head_start..i];
        let before = text[..head_start].chars().last();
        if !matches!(head, "crate" | "super" | "self") || before == Some(':') {
            continue;
        }
        for p in tree(&text[head_start..]) {
            let mut at: ModPath = match head {
                "crate" => Vec::new(),
                _ => here.to_vec(),
            };
            let mut segs = p.into_iter().skip(1).peekable();
            if head == "super" {
                at.pop();
            }
            while segs.peek().is_some_and(|s| s == "super") {
                segs.next();
                at.pop();
            }
            at.extend(segs.filter(|s| s != "self"));
            out.push(at);
        }
    }
    out
}

/// The import graphs among the modules of each folder of a crate whose files are `files`
/// (path under `src`, text): folder → its graph.
fn folder_graphs(files: &[(PathBuf, String)]) -> BTreeMap<ModPath, Graph> {
    let mut children: BTreeSet<(ModPath, String)> = BTreeSet::new();
    for (rel, _) in files {
        let mut m = module_path(rel);
        if let Some(last) = m.pop() {
            children.insert((m, last));
        }
    }
    let mut graphs: BTreeMap<ModPath, Graph> = BTreeMap::new();
    for (rel, text) in files {
        let here = module_path(rel);
        for target in resolved(&code(text), &here) {
            let Some(i) = (0..here.len().min(target.len())).find(|&i| here[i] != target[i]) else {
                continue;
            };
            let folder = here[..i].to_vec();
            if !children.contains(&(folder.clone(), target[i].clone())) {
                continue;
            }
            graphs
                .entry(folder)
                .or_default()
                .entry(here[i].clone())
                .or_default()
                .entry(target[i].clone())
                .or_default()
                .insert(rel.display().to_string());
        }
    }
    graphs
}

/// Each edge of `g` that a path leads back over, as a line naming `folder` and the files.
fn cycles(folder: &str, g: &Graph) -> Vec<String> {
    let mut out = Vec::new();
    for (m, edges) in g {
        for (n, files) in edges {
            if reaches(g, n).contains(m) {
                out.push(format!(
                    "{folder}: {m} → {n} (in {}), and {n} leads back to {m}",
                    files.iter().cloned().collect::<Vec<_>>().join(", ")
                ));
            }
        }
    }
    out
}

/// A crate's files: path under `src` and text.
fn sources(krate: &str) -> Vec<(PathBuf, String)> {
    let src = crates_dir().join(krate).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files
        .into_iter()
        .map(|p| {
            let text = std::fs::read_to_string(&p).expect("read");
            (p.strip_prefix(&src).expect("under src").to_path_buf(), text)
        })
        .collect()
}

#[test]
fn no_folder_has_an_import_cycle_among_its_files() {
    let mut found = Vec::new();
    for krate in CRATES {
        for (folder, g) in folder_graphs(&sources(krate)) {
            let name = format!("{krate}/src/{}", folder.join("/"));
            found.extend(cycles(&name, &g));
        }
    }
    assert!(found.is_empty(), "import cycles:\n{}", found.join("\n"));
}

/// The checker on a planted cycle: `x/a.rs` names its sibling through `super::`, and `x/b.rs`
/// names `a` back through a `crate::` group; a three-file loop through `self::` from a
/// `mod.rs`'s child; neither is missed, and a parent naming its children is no cycle.
#[test]
fn a_planted_cycle_between_sibling_files_is_caught() {
    let files: Vec<(PathBuf, String)> = [
        ("lib.rs", "mod x; use crate::x::a;"),
        (
            "x/mod.rs",
            "mod a; mod b; mod y; use self::a::T; use self::y::z;",
        ),
        (
            "x/a.rs",
            "use super::b::U;\nfn f() { super::super::x::Thing::new(); }",
        ),
        ("x/b.rs", "use crate::{x::{a::T, mod_item}, other};"),
        ("x/y/mod.rs", "mod p; mod q; mod z;"),
        ("x/y/p.rs", "use super::q::A;"),
        ("x/y/q.rs", "fn g() { crate::x::y::z::h(); }"),
        (
            "x/y/z.rs",
            "use super::super::y::p::B;\n#[cfg(test)]\nmod tests { use super::q; }",
        ),
    ]
    .iter()
    .map(|(p, t)| (PathBuf::from(p), t.to_string()))
    .collect();
    let graphs = folder_graphs(&files);
    let found: Vec<String> = graphs
        .iter()
        .flat_map(|(f, g)| cycles(&f.join("/"), g))
        .collect();
    assert_eq!(
        found,
        [
            "x: a → b (in x/a.rs), and b leads back to a",
            "x: b → a (in x/b.rs), and a leads back to b",
            "x/y: p → q (in x/y/p.rs), and q leads back to p",
            "x/y: q → z (in x/y/q.rs), and z leads back to q",
            "x/y: z → p (in x/y/z.rs), and p leads back to z",
        ],
        "{graphs:?}"
    );
}

#[test]
fn the_lower_tiers_import_nothing_above_them() {
    let render = graph("render");
    let up: Vec<_> = render
        .get("util")
        .into_iter()
        .flat_map(|e| e.keys())
        .collect();
    assert!(up.is_empty(), "render's util/ imports {up:?}");
    let accel = reaches(&render, "accel");
    assert!(
        accel
            .iter()
            .all(|m| ["accel", "util"].contains(&m.as_str())),
        "render's accel/ reaches {accel:?}"
    );
    let coordinator = graph("coordinator");
    let below = reaches(&coordinator, "scheduler");
    for layer in [
        "service", "http", "server", "shared", "output", "referee", "conn",
    ] {
        assert!(
            !below.contains(layer),
            "the scheduler reaches {layer}: {below:?}"
        );
    }
}

/// The reader itself: a cycle it cannot see is a cycle this test cannot catch.
#[test]
fn imports_are_read_from_groups_paths_and_code_but_not_comments() {
    let text = code(
        "use crate::a::{X, Y};\nuse crate::{b, c::{D, E}};\nfn f() { crate::d::g(); }\n\
         // crate::e::h\nuse tessera_render::f::G;\n",
    );
    let got: Vec<String> = named(&text).into_iter().collect();
    assert_eq!(got, ["a", "b", "c", "d"]);
}

/// `unsafe_code` is denied workspace-wide and allowed in one file, the binding of Open Image
/// Denoise's C API: an `allow` anywhere else (or `unsafe` in a crate that has no such file)
/// would let unchecked memory access in unseen.
#[test]
fn only_the_denoiser_binding_allows_unsafe_code() {
    let mut files = Vec::new();
    rust_files(&crates_dir(), &mut files);
    let allowing: Vec<String> = files
        .iter()
        .filter(|f| {
            let text = std::fs::read_to_string(f).expect("read");
            code(&text).contains("allow(unsafe_code)")
        })
        .map(|f| {
            f.strip_prefix(crates_dir())
                .expect("under crates/")
                .display()
                .to_string()
        })
        .collect();
    assert_eq!(allowing, ["denoise/src/ffi.rs"]);
    let manifest = std::fs::read_to_string(crates_dir().join("../Cargo.toml")).expect("read");
    assert!(
        manifest.contains("unsafe_code = \"deny\""),
        "the workspace must deny unsafe code"
    );
}
