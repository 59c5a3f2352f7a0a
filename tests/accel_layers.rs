//! `src/accel` reads top-down: its modules import each other without a cycle, so each
//! family's files and the dispatch above them can be read (and changed) one layer at a time.
//! Reads the sources, not the compiled crate: a module's dependencies are the
//! `crate::accel::<module>` paths (and a top-level file's `super::<module>`) in its code, doc
//! comments and tests left out.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The identifiers that follow `prefix` in `code`.
fn modules_after<'a>(code: &'a str, prefix: &'a str) -> impl Iterator<Item = &'a str> + 'a {
    code.match_indices(prefix)
        .map(move |(at, _)| {
            let rest = &code[at + prefix.len()..];
            let end = rest
                .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
                .unwrap_or(rest.len());
            &rest[..end]
        })
        .filter(|m| !m.is_empty())
}

/// The code of a file: comment lines and the unit tests' module left out.
fn code_of(source: &str) -> String {
    let body = match source.find("#[cfg(test)]\nmod tests") {
        Some(at) => &source[..at],
        None => source,
    };
    body.lines()
        .filter(|l| !l.trim_start().starts_with("//"))
        .collect::<Vec<_>>()
        .join("\n")
}

/// Module → the modules of `src/accel` it imports (by top-level name).
fn import_graph(root: &Path) -> BTreeMap<String, BTreeSet<String>> {
    let mut files = Vec::new();
    rust_files(root, &mut files);
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for file in files {
        let rel = file.strip_prefix(root).unwrap();
        let top = rel
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy()
            .trim_end_matches(".rs")
            .to_string();
        if top == "mod" {
            continue;
        }
        let code = code_of(&std::fs::read_to_string(&file).unwrap());
        let mut deps: BTreeSet<String> = modules_after(&code, "crate::accel::")
            .map(str::to_string)
            .collect();
        if rel.components().count() == 1 {
            deps.extend(modules_after(&code, "super::").map(str::to_string));
        }
        deps.remove(&top);
        graph.entry(top).or_default().extend(deps);
    }
    graph
}

/// A cycle through `start`, as the path that closes it, if there is one.
fn cycle_through(graph: &BTreeMap<String, BTreeSet<String>>, start: &str) -> Option<Vec<String>> {
    let mut stack = vec![(start.to_string(), vec![start.to_string()])];
    let mut seen = BTreeSet::new();
    while let Some((node, path)) = stack.pop() {
        for next in graph.get(&node).into_iter().flatten() {
            if next == start {
                let mut cycle = path.clone();
                cycle.push(start.to_string());
                return Some(cycle);
            }
            if seen.insert(next.clone()) {
                let mut p = path.clone();
                p.push(next.clone());
                stack.push((next.clone(), p));
            }
        }
    }
    None
}

#[test]
fn accel_modules_import_each_other_without_a_cycle() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/accel");
    let graph = import_graph(&root);
    assert!(
        graph.len() > 15,
        "read {} modules of src/accel",
        graph.len()
    );
    // The families sit below the dispatch: `device` imports them, never the reverse.
    for family in ["kdtree", "bvh", "driver"] {
        assert!(
            graph["device"].contains(family),
            "device does not import {family}"
        );
        assert!(!graph[family].contains("device"), "{family} imports device");
    }
    let cycles: Vec<String> = graph
        .keys()
        .filter_map(|m| cycle_through(&graph, m))
        .map(|c| c.join(" → "))
        .collect();
    assert!(
        cycles.is_empty(),
        "import cycles in src/accel:\n{}",
        cycles.join("\n")
    );
}

#[test]
fn the_cycle_check_finds_a_cycle() {
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    graph.entry("a".into()).or_default().insert("b".into());
    graph.entry("b".into()).or_default().insert("c".into());
    assert_eq!(cycle_through(&graph, "a"), None);
    graph.entry("c".into()).or_default().insert("a".into());
    assert_eq!(
        cycle_through(&graph, "a"),
        Some(vec!["a".into(), "b".into(), "c".into(), "a".into()])
    );
    let code =
        code_of("use crate::accel::walk::X;\n// crate::accel::device\nfn f() { super::bvh::g() }");
    assert_eq!(
        modules_after(&code, "crate::accel::").collect::<Vec<_>>(),
        ["walk"]
    );
    assert_eq!(modules_after(&code, "super::").collect::<Vec<_>>(), ["bvh"]);
}
