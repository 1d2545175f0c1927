//! The workspace's layout rules, checked on the sources:
//! - nia-model has no import circle: the graph of its files, one edge where a file names
//!   another through a `crate::`, `super::` or `self::` path, has no cycle (the folders read
//!   as the forward pass does, each stage importing only earlier ones and the leaves);
//! - no source file of a crate is longer than [`MAX_LINES`] lines, except the file-format
//!   readers and writers (`formats/`), whose length is the format's;
//! - no function in a crate's `src/` is longer than [`MAX_FN_LINES`] lines (a brace-matching
//!   scanner over the code without comments and literals);
//! - no test file (a crate's `tests/`, the root `tests/`) is longer than
//!   [`MAX_TEST_FILE_LINES`] lines;
//! - the crates depend downwards only, as their `Cargo.toml`s say: nia-data, nia-model,
//!   nia-eval, then the two binaries, neither on the other.

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

/// Longest function body allowed in a crate's `src/`, lines (from the line of its opening
/// brace to the line of its closing one).
const MAX_FN_LINES: usize = 150;

/// Functions over [`MAX_FN_LINES`] that are being rewritten, as `crate/src/file.rs: name`.
/// Each entry must still be over the limit (the check fails on a stale entry): remove it with
/// the split.
const LONG_FUNCTIONS_BEING_REWRITTEN: [&str; 0] = [];

/// Longest test file allowed, lines.
const MAX_TEST_FILE_LINES: usize = 1000;

/// `source` with its comments and the contents of its string and character literals blanked
/// (line breaks kept, so line numbers stay), for scanners that match braces.
fn without_comments_and_literals(source: &str) -> String {
    let chars: Vec<char> = source.chars().collect();
    let mut out = String::with_capacity(source.len());
    // What a skipped stretch leaves: its line breaks.
    let blank = |out: &mut String, skipped: &[char]| {
        out.extend(skipped.iter().filter(|&&c| c == '\n'));
    };
    let ident = |c: char| c.is_alphanumeric() || c == '_';
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        let next = chars.get(i + 1).copied();
        if c == '/' && next == Some('/') {
            let end = chars[i..]
                .iter()
                .position(|&c| c == '\n')
                .map_or(chars.len(), |p| i + p);
            i = end;
        } else if c == '/' && next == Some('*') {
            // Block comments nest.
            let (mut depth, mut j) = (1, i + 2);
            while j < chars.len() && depth > 0 {
                match (chars[j], chars.get(j + 1).copied()) {
                    ('/', Some('*')) => (depth, j) = (depth + 1, j + 2),
                    ('*', Some('/')) => (depth, j) = (depth - 1, j + 2),
                    _ => j += 1,
                }
            }
            blank(&mut out, &chars[i..j]);
            i = j;
        } else if (c == 'r' || (c == 'b' && next == Some('r')))
            && (i == 0 || !ident(chars[i - 1]))
            && {
                let start = if c == 'b' { i + 2 } else { i + 1 };
                let hashes = chars[start..].iter().take_while(|&&h| h == '#').count();
                chars.get(start + hashes) == Some(&'"')
            }
        {
            // A raw string: r"..", r#".."#, br"..".
            let start = if c == 'b' { i + 2 } else { i + 1 };
            let hashes = chars[start..].iter().take_while(|&&h| h == '#').count();
            let mut j = start + hashes + 1;
            while j < chars.len()
                && !(chars[j] == '"'
                    && chars[j + 1..]
                        .iter()
                        .take(hashes)
                        .filter(|&&h| h == '#')
                        .count()
                        == hashes)
            {
                j += 1;
            }
            let end = (j + 1 + hashes).min(chars.len());
            out.push_str("\"\"");
            blank(&mut out, &chars[i..end]);
            i = end;
        } else if c == '"' {
            let mut j = i + 1;
            while j < chars.len() && chars[j] != '"' {
                j += if chars[j] == '\\' { 2 } else { 1 };
            }
            let end = (j + 1).min(chars.len());
            out.push_str("\"\"");
            blank(&mut out, &chars[i..end]);
            i = end;
        } else if c == '\'' && next == Some('\\') {
            // An escaped character literal: '\n', '\'', '\u{..}'.
            let end = chars[i + 2..]
                .iter()
                .position(|&c| c == '\'')
                .map_or(chars.len(), |p| i + 2 + p + 1);
            out.push_str("' '");
            i = end;
        } else if c == '\'' && chars.get(i + 2) == Some(&'\'') {
            // A character literal ('{', '"'); a lifetime ('a) has no closing quote.
            out.push_str("' '");
            i += 3;
        } else {
            out.push(c);
            i += 1;
        }
    }
    out
}

/// Every `fn` with a body in `code` (from [`without_comments_and_literals`]): its name, the
/// line of the `fn` (from 1) and the lines its body spans, braces included.
fn function_lengths(code: &str) -> Vec<(String, usize, usize)> {
    let bytes = code.as_bytes();
    let ident = |b: u8| b.is_ascii_alphanumeric() || b == b'_';
    let line_of = |at: usize| code[..at].matches('\n').count() + 1;
    let mut found = Vec::new();
    let mut from = 0;
    while let Some(p) = code[from..].find("fn") {
        let at = from + p;
        from = at + 2;
        let before_ok = at == 0 || !ident(bytes[at - 1]);
        let after = &code[at + 2..];
        let name_start = after.len() - after.trim_start().len();
        if !before_ok || name_start == 0 {
            continue;
        }
        let name: String = after[name_start..]
            .chars()
            .take_while(|&c| c.is_alphanumeric() || c == '_')
            .collect();
        if name.is_empty() {
            continue;
        }
        // The body's opening brace: the first `{` outside the signature's brackets, unless a
        // `;` ends a declaration first.
        let mut depth = 0i32;
        let mut open = None;
        for (k, &b) in bytes.iter().enumerate().skip(at + 2) {
            match b {
                b'(' | b'[' => depth += 1,
                b')' | b']' => depth -= 1,
                b';' if depth == 0 => break,
                b'{' if depth == 0 => {
                    open = Some(k);
                    break;
                }
                _ => {}
            }
        }
        let Some(open) = open else { continue };
        let mut braces = 0i32;
        let close = (open..bytes.len()).find(|&k| {
            match bytes[k] {
                b'{' => braces += 1,
                b'}' => braces -= 1,
                _ => {}
            }
            braces == 0
        });
        let Some(close) = close else { continue };
        found.push((name, line_of(at), line_of(close) - line_of(open) + 1));
    }
    found
}

#[test]
fn no_function_is_over_the_line_limit() {
    let mut long = Vec::new();
    for krate in CRATES {
        let src = workspace().join(krate).join("src");
        for file in rust_files(&src) {
            let source = std::fs::read_to_string(src.join(&file)).unwrap();
            let code = without_comments_and_literals(&source);
            for (name, line, lines) in function_lengths(&code) {
                if lines > MAX_FN_LINES {
                    long.push((format!("{krate}/src/{file}: {name}"), line, lines));
                }
            }
        }
    }
    for known in LONG_FUNCTIONS_BEING_REWRITTEN {
        assert!(
            long.iter().any(|(at, _, _)| at == known),
            "{known} is no longer over {MAX_FN_LINES} lines: remove it from \
             LONG_FUNCTIONS_BEING_REWRITTEN"
        );
    }
    let listed: Vec<String> = long
        .iter()
        .filter(|(at, _, _)| !LONG_FUNCTIONS_BEING_REWRITTEN.contains(&at.as_str()))
        .map(|(at, line, lines)| format!("{at} (line {line}): {lines} lines"))
        .collect();
    assert!(
        listed.is_empty(),
        "functions over {MAX_FN_LINES} lines (split them into named steps):\n{}",
        listed.join("\n")
    );
}

/// The function scanner measures a planted long function, ignores braces in comments, strings
/// and character literals, skips declarations without a body, and keeps line numbers.
#[test]
fn the_function_scanner_measures_a_planted_function() {
    let long_body = "    let x = 1;\n".repeat(MAX_FN_LINES);
    let source = format!(
        "// fn commented() {{\n\
         /* fn block() {{ /* nested }} */ }} */\n\
         trait T {{ fn declared(&self) -> u8; }}\n\
         fn short<'a>(s: &'a str) -> char {{\n    let _ = \"}}\";\n    let _ = r#\"{{\"#;\n    '{{'\n}}\n\
         pub fn planted() {{\n{long_body}}}\n\
         fn after() {{ let _ = '\\''; }}\n"
    );
    let code = without_comments_and_literals(&source);
    assert_eq!(code.lines().count(), source.lines().count());
    let found = function_lengths(&code);
    let names: Vec<&str> = found.iter().map(|(n, _, _)| n.as_str()).collect();
    assert_eq!(names, ["short", "planted", "after"], "{found:?}");
    assert_eq!(found[0], ("short".to_string(), 4, 5));
    assert_eq!(found[1], ("planted".to_string(), 9, MAX_FN_LINES + 2));
    assert_eq!(found[2].2, 1);
}

#[test]
fn no_test_file_is_over_the_line_limit() {
    let mut folders: Vec<PathBuf> = CRATES
        .iter()
        .map(|krate| workspace().join(krate).join("tests"))
        .collect();
    folders.push(workspace().join("tests"));
    let mut long = Vec::new();
    for tests in folders {
        for file in rust_files(&tests) {
            let lines = std::fs::read_to_string(tests.join(&file))
                .unwrap()
                .lines()
                .count();
            if lines > MAX_TEST_FILE_LINES {
                long.push(format!("{}/{file}: {lines} lines", tests.display()));
            }
        }
    }
    assert!(
        long.is_empty(),
        "test files over {MAX_TEST_FILE_LINES} lines (split them by concept):\n{}",
        long.join("\n")
    );
}

/// Our crates among the entries of a `Cargo.toml`: (its `[dependencies]`, including
/// target-specific ones, and its `[dev-dependencies]`).
fn our_dependencies(manifest: &str) -> (BTreeSet<String>, BTreeSet<String>) {
    let (mut normal, mut dev) = (BTreeSet::new(), BTreeSet::new());
    let mut section = String::new();
    for line in manifest
        .lines()
        .map(|l| l.split('#').next().unwrap_or("").trim())
    {
        if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            section = name.trim().to_string();
            continue;
        }
        let key = line
            .split(['=', '.'])
            .next()
            .unwrap_or("")
            .trim()
            .trim_matches('"');
        if !key.starts_with("nia-") {
            continue;
        }
        if section == "dependencies" || section.ends_with(".dependencies") {
            normal.insert(key.to_string());
        } else if section == "dev-dependencies" || section.ends_with(".dev-dependencies") {
            dev.insert(key.to_string());
        }
    }
    (normal, dev)
}

/// The crates depend downwards only: nia-data on none of ours, nia-model on nia-data, nia-eval
/// on those two, the binaries (nia-train, nia-infer) on those three; neither binary depends
/// on the other, except nia-infer's tests on nia-train (they train tiny models in-process).
#[test]
fn crates_depend_only_downwards() {
    let below: [(&str, &[&str], &[&str]); 5] = [
        ("nia-data", &[], &[]),
        ("nia-model", &["nia-data"], &[]),
        ("nia-eval", &["nia-data", "nia-model"], &[]),
        ("nia-train", &["nia-data", "nia-model", "nia-eval"], &[]),
        (
            "nia-infer",
            &["nia-data", "nia-model", "nia-eval"],
            &["nia-train"],
        ),
    ];
    let mut wrong = Vec::new();
    for (krate, allowed, dev_only) in below {
        let manifest = std::fs::read_to_string(workspace().join(krate).join("Cargo.toml")).unwrap();
        let (normal, dev) = our_dependencies(&manifest);
        for dep in &normal {
            if !allowed.contains(&dep.as_str()) {
                wrong.push(format!("{krate} depends on {dep}"));
            }
        }
        for dep in &dev {
            if !allowed.contains(&dep.as_str()) && !dev_only.contains(&dep.as_str()) {
                wrong.push(format!("{krate}'s tests depend on {dep}"));
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "dependencies that point up or sideways:\n{}",
        wrong.join("\n")
    );
}

/// The manifest reader finds our crates in every dependency section, and nothing else.
#[test]
fn the_dependency_reader_reads_a_planted_manifest() {
    let manifest = "[package]\nname = \"nia-x\"\n\n[dependencies]\nnia-data.workspace = true\n\
                    nia-model = { path = \"../nia-model\" }\nglam.workspace = true\n\
                    # nia-train.workspace = true\n\n[target.'cfg(unix)'.dependencies]\n\
                    nia-eval.workspace = true\n\n[dev-dependencies]\nnia-train.workspace = true\n\
                    \n[features]\nwgpu = [\"nia-model/wgpu\"]\n";
    let (normal, dev) = our_dependencies(manifest);
    assert_eq!(
        normal.into_iter().collect::<Vec<_>>(),
        ["nia-data", "nia-eval", "nia-model"]
    );
    assert_eq!(dev.into_iter().collect::<Vec<_>>(), ["nia-train"]);
}
