//! The workspace's layout rules, checked on the sources:
//! - nia-model has no import circle: the graph of its files, one edge where a file names
//!   another through a `crate::`, `super::` or `self::` path, has no cycle (the folders read
//!   as the forward pass does, each stage importing only earlier ones and the leaves);
//! - no source file of a crate is longer than [`MAX_LINES`] lines, except the file-format
//!   readers and writers (`formats/`), whose length is the format's.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Longest source file allowed outside tests and formats.
const MAX_LINES: usize = 600;

const CRATES: [&str; 5] = [
    "nia-data",
    "nia-model",
    "nia-eval",
    "nia-train",
    "nia-infer",
];

fn workspace() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Every `.rs` file under `dir`, as paths relative to it with `/` separators.
fn rust_files(dir: &Path) -> Vec<String> {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<String>) {
        let mut entries: Vec<_> = std::fs::read_dir(dir)
            .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
            .map(|e| e.unwrap().path())
            .collect();
        entries.sort();
        for path in entries {
            if path.is_dir() {
                walk(root, &path, out);
            } else if path.extension().is_some_and(|x| x == "rs") {
                let rel = path.strip_prefix(root).unwrap();
                out.push(rel.to_string_lossy().replace('\\', "/"));
            }
        }
    }
    let mut out = Vec::new();
    walk(dir, dir, &mut out);
    out
}

/// The module path of a source file: `field/query.rs` -> `[field, query]`, `field/mod.rs`
/// -> `[field]`, `lib.rs` -> `[]`.
fn module_of(file: &str) -> Vec<String> {
    let mut parts: Vec<String> = file
        .trim_end_matches(".rs")
        .split('/')
        .map(String::from)
        .collect();
    if matches!(parts.last().map(String::as_str), Some("mod" | "lib")) {
        parts.pop();
    }
    parts
}

/// The file that holds the longest prefix of `path` that is a module.
fn file_of(path: &[String], files: &BTreeSet<String>) -> Option<String> {
    (0..=path.len()).rev().find_map(|k| {
        let base = path[..k].join("/");
        let candidates = if base.is_empty() {
            vec!["lib.rs".to_string()]
        } else {
            vec![format!("{base}.rs"), format!("{base}/mod.rs")]
        };
        candidates.into_iter().find(|c| files.contains(c))
    })
}

/// The code of a file without comments and without its `#[cfg(test)]` module (tests may
/// reach anywhere).
fn code_of(source: &str) -> String {
    let source = match source.find("#[cfg(test)]\nmod ") {
        Some(i) => &source[..i],
        None => source,
    };
    source
        .lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

/// The module paths a file names: `crate::a::b`, `super::a`, `self::a`, and each item of a
/// `{..}` group after one of them.
fn named_paths(code: &str, module: &[String]) -> Vec<Vec<String>> {
    let ident = |c: char| c.is_ascii_alphanumeric() || c == '_';
    let mut out = Vec::new();
    for head in ["crate::", "super::", "self::"] {
        let mut from = 0;
        while let Some(i) = code[from..].find(head) {
            let start = from + i;
            from = start + head.len();
            if start > 0 && code[..start].chars().next_back().is_some_and(ident) {
                continue;
            }
            let base: Vec<String> = match head {
                "crate::" => Vec::new(),
                "self::" => module.to_vec(),
                _ => module[..module.len().saturating_sub(1)].to_vec(),
            };
            let rest = &code[from..];
            let end = rest
                .find(|c: char| !(ident(c) || c == ':'))
                .unwrap_or(rest.len());
            let segments: Vec<String> = rest[..end]
                .split("::")
                .filter(|s| !s.is_empty())
                .map(String::from)
                .collect();
            let mut path = base.clone();
            path.extend(segments.iter().cloned());
            out.push(path.clone());
            if rest[end..].starts_with('{') {
                let group = &rest[end + 1..rest[end..].find('}').map_or(end + 1, |j| end + j)];
                for item in group.split(',') {
                    let item = item.split(" as ").next().unwrap_or("").trim();
                    let mut p = path.clone();
                    p.extend(item.split("::").filter(|s| !s.is_empty()).map(String::from));
                    out.push(p);
                }
            }
        }
    }
    out
}

/// The file-level import graph of the crate at `src`.
fn import_graph(src: &Path) -> BTreeMap<String, BTreeSet<String>> {
    let files: BTreeSet<String> = rust_files(src).into_iter().collect();
    files
        .iter()
        .map(|file| {
            let source = std::fs::read_to_string(src.join(file)).unwrap();
            let module = module_of(file);
            let edges = named_paths(&code_of(&source), &module)
                .iter()
                .filter_map(|p| file_of(p, &files))
                .filter(|target| target != file)
                .collect();
            (file.clone(), edges)
        })
        .collect()
}

/// A cycle of `graph` (as the files along it, first repeated at the end), if there is one.
fn find_cycle(graph: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    #[derive(Clone, Copy, PartialEq)]
    enum Mark {
        New,
        Open,
        Done,
    }
    fn visit(
        node: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        marks: &mut BTreeMap<String, Mark>,
        stack: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        marks.insert(node.to_string(), Mark::Open);
        stack.push(node.to_string());
        for next in &graph[node] {
            match marks[next] {
                Mark::Open => {
                    let at = stack.iter().position(|s| s == next).unwrap();
                    let mut cycle = stack[at..].to_vec();
                    cycle.push(next.clone());
                    return Some(cycle);
                }
                Mark::New => {
                    if let Some(c) = visit(next, graph, marks, stack) {
                        return Some(c);
                    }
                }
                Mark::Done => {}
            }
        }
        stack.pop();
        marks.insert(node.to_string(), Mark::Done);
        None
    }
    let mut marks: BTreeMap<String, Mark> = graph.keys().map(|k| (k.clone(), Mark::New)).collect();
    let nodes: Vec<String> = graph.keys().cloned().collect();
    for node in nodes {
        if marks[&node] == Mark::New {
            if let Some(c) = visit(&node, graph, &mut marks, &mut Vec::new()) {
                return Some(c);
            }
        }
    }
    None
}

#[test]
fn nia_model_has_no_import_circle() {
    let graph = import_graph(&workspace().join("nia-model/src"));
    // The check sees the edges it must: the forward pass imports the model and its stages.
    assert!(graph["renderer/forward.rs"].contains("model.rs"));
    assert!(graph["renderer/forward.rs"].contains("sampler/mod.rs"));
    assert!(graph["model.rs"].contains("config.rs"));
    if let Some(cycle) = find_cycle(&graph) {
        panic!("nia-model has an import circle: {}", cycle.join(" -> "));
    }
}

/// The cycle finder finds a planted circle (and the path reader resolves groups, `super::`
/// and `self::`), so a pass above means something.
#[test]
fn the_cycle_check_finds_a_planted_circle() {
    let module = vec!["field".to_string(), "query".to_string()];
    let paths = named_paths(
        "use super::{heads::view_mean, PointOutput};\nuse crate::model::NiaModel;\nlet x = self::inner::f();",
        &module,
    );
    assert!(paths.contains(&vec!["field".into(), "heads".into(), "view_mean".into()]));
    assert!(paths.contains(&vec!["model".into(), "NiaModel".into()]));
    assert!(paths.contains(&vec![
        "field".into(),
        "query".into(),
        "inner".into(),
        "f".into()
    ]));
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    graph.insert("a.rs".into(), ["b/mod.rs".to_string()].into());
    graph.insert("b/mod.rs".into(), ["c.rs".to_string()].into());
    graph.insert("c.rs".into(), BTreeSet::new());
    assert_eq!(find_cycle(&graph), None);
    graph.get_mut("c.rs").unwrap().insert("a.rs".into());
    let cycle = find_cycle(&graph).expect("the planted circle");
    assert_eq!(cycle.first(), cycle.last());
    assert_eq!(cycle.len(), 4, "{cycle:?}");
}

#[test]
fn no_source_file_is_over_the_line_limit() {
    let mut long = Vec::new();
    for krate in CRATES {
        let src = workspace().join(krate).join("src");
        for file in rust_files(&src) {
            if file.starts_with("formats/") {
                continue;
            }
            let lines = std::fs::read_to_string(src.join(&file))
                .unwrap()
                .lines()
                .count();
            if lines > MAX_LINES {
                long.push(format!("{krate}/src/{file}: {lines} lines"));
            }
        }
    }
    assert!(
        long.is_empty(),
        "source files over {MAX_LINES} lines (split them by concept):\n{}",
        long.join("\n")
    );
}
