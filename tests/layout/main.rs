//! The crates' module layout, checked: no import cycle among a crate's top-level modules,
//! and the tiers stay below what uses them (the renderer's `util/` imports nothing above it;
//! the coordinator's scheduler knows nothing of the gRPC, HTTP or store-writer layers above
//! it). A cycle means a type in the wrong file, and a newcomer who cannot read one module
//! without the other; this test names the files that make it.
//!
//! Imports are read from the source (`crate::NAME` paths, in `use` lines and in code), which
//! is all a cycle needs: a module that names another depends on it.

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
