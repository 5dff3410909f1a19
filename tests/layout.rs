//! The library's layout as DEVELOPERS.md draws it: the top-level modules form no cycle (the data
//! flows one way), the validator knows nothing of the decimator or its evaluators, the
//! evaluators read the decimator's round snapshot and never its state, and `gpu/` is the only
//! module that calls wgpu. Read from the sources: every `crate::name` a module's code
//! names (comments and `#[cfg(test)]` sections left out, since tests may reach across).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Every `.rs` file under `p` (or `p` itself).
fn rust_files(p: &Path, out: &mut Vec<PathBuf>) {
    if p.is_dir() {
        let mut entries: Vec<_> = std::fs::read_dir(p).unwrap().map(|e| e.unwrap().path()).collect();
        entries.sort();
        for e in entries {
            rust_files(&e, out);
        }
    } else if p.extension().is_some_and(|e| e == "rs") {
        out.push(p.to_path_buf());
    }
}

/// The code of a file: up to its first `#[cfg(test)]`, each line without its `//` comment.
fn code_of(text: &str) -> String {
    let mut out = String::new();
    for line in text.lines() {
        if line.trim_start().starts_with("#[cfg(test)]") {
            break;
        }
        out.push_str(line.split("//").next().unwrap_or(""));
        out.push('\n');
    }
    out
}

/// The names after `prefix` in `code` (`crate::` gives the modules a file names).
fn names_after(code: &str, prefix: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let mut rest = code;
    while let Some(i) = rest.find(prefix) {
        let before = rest[..i].chars().last();
        rest = &rest[i + prefix.len()..];
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
            continue; // `foo_crate::` is not `crate::`
        }
        let name: String = rest.chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '_').collect();
        out.insert(name);
    }
    out
}

/// Top-level module → (modules it names, whether it names wgpu), from `src/`.
fn module_graph() -> BTreeMap<String, (BTreeSet<String>, bool)> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut modules = BTreeMap::new();
    for entry in std::fs::read_dir(&src).unwrap() {
        let p = entry.unwrap().path();
        let name = p.file_stem().unwrap().to_string_lossy().into_owned();
        if name == "lib" || name == "main" || (p.is_file() && p.extension().is_none_or(|e| e != "rs")) {
            continue;
        }
        let mut files = Vec::new();
        rust_files(&p, &mut files);
        let (mut uses, mut wgpu) = (BTreeSet::new(), false);
        for f in files {
            let code = code_of(&std::fs::read_to_string(&f).unwrap());
            uses.extend(names_after(&code, "crate::"));
            wgpu |= code.contains("wgpu::");
        }
        modules.insert(name, (uses, wgpu));
    }
    let names: BTreeSet<String> = modules.keys().cloned().collect();
    for (name, (uses, _)) in modules.iter_mut() {
        uses.retain(|u| names.contains(u) && u != name);
    }
    modules
}

/// A cycle of the graph, if there is one (depth-first search, the path on the stack).
fn find_cycle(g: &BTreeMap<String, (BTreeSet<String>, bool)>) -> Option<Vec<String>> {
    fn visit(n: &str, g: &BTreeMap<String, (BTreeSet<String>, bool)>, state: &mut BTreeMap<String, u8>, path: &mut Vec<String>) -> Option<Vec<String>> {
        match state.get(n).copied().unwrap_or(0) {
            1 => {
                let from = path.iter().position(|p| p == n).unwrap();
                let mut cycle = path[from..].to_vec();
                cycle.push(n.to_string());
                return Some(cycle);
            }
            2 => return None,
            _ => {}
        }
        state.insert(n.to_string(), 1);
        path.push(n.to_string());
        for m in &g[n].0 {
            if let Some(c) = visit(m, g, state, path) {
                return Some(c);
            }
        }
        path.pop();
        state.insert(n.to_string(), 2);
        None
    }
    let mut state = BTreeMap::new();
    for n in g.keys() {
        if let Some(c) = visit(n, g, &mut state, &mut Vec::new()) {
            return Some(c);
        }
    }
    None
}

#[test]
fn the_modules_form_no_cycle() {
    let g = module_graph();
    // The graph is read, not empty: the decimator names the shared predicates.
    assert!(g["decimate"].0.contains("guarantee"), "{g:?}");
    if let Some(c) = find_cycle(&g) {
        panic!("module cycle {} (each names the next with crate::)", c.join(" → "));
    }
}

#[test]
fn the_validator_knows_nothing_of_the_decimator() {
    let g = module_graph();
    for m in ["decimate", "eval", "app"] {
        assert!(!g["validate"].0.contains(m), "validate names crate::{m}: {:?}", g["validate"].0);
    }
}

/// Whether `code` names `word` as a whole identifier.
fn names_word(code: &str, word: &str) -> bool {
    let ident = |c: char| c.is_ascii_alphanumeric() || c == '_';
    code.match_indices(word).any(|(i, _)| {
        !code[..i].chars().last().is_some_and(ident) && !code[i + word.len()..].chars().next().is_some_and(ident)
    })
}

/// SPEC §3: the evaluator takes the round, not the decimator. The evaluators (`eval/`, `gpu/`)
/// and the stages' own file (`decimate/local.rs`) name `Snapshot` (what a round's tests read:
/// the base, the dense mesh, the association, the settings) and never `State` (which adds the
/// queue, the fail memo and the counters), and the interface the rounds call takes a snapshot.
#[test]
fn the_evaluators_read_the_snapshot_not_the_state() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    for p in ["eval", "gpu", "decimate/local.rs"] {
        rust_files(&src.join(p), &mut files);
    }
    assert!(files.len() >= 5, "{files:?}");
    let mut snapshot = 0;
    for f in &files {
        let code = code_of(&std::fs::read_to_string(f).unwrap());
        assert!(!names_word(&code, "State"), "{} names the decimator's State", f.display());
        snapshot += usize::from(names_word(&code, "Snapshot"));
    }
    assert!(snapshot >= 3, "the evaluators name no Snapshot (the test reads nothing?)");
    let outcome = code_of(&std::fs::read_to_string(src.join("decimate/outcome.rs")).unwrap());
    assert!(outcome.contains("fn evaluate(&self, snap: &Snapshot, batch: &[Candidate])"), "Evaluator::evaluate's signature changed");
    assert!(names_word("a State b", "State") && !names_word("StateX Snapshots", "State"));
}

#[test]
fn only_gpu_calls_wgpu() {
    let g = module_graph();
    assert!(g["gpu"].1, "gpu/ names no wgpu:: path (the test reads nothing?)");
    let callers: Vec<&String> = g.iter().filter(|(n, (_, w))| *w && *n != "gpu").map(|(n, _)| n).collect();
    assert!(callers.is_empty(), "wgpu named outside gpu/: {callers:?}");
}

#[test]
fn the_reader_sees_through_comments_and_tests() {
    let text = "use crate::a::X; // crate::b\n/// see [`crate::c`]\nfn f() { my_crate::d(); }\n#[cfg(test)]\nmod t { use crate::e; }\n";
    let names = names_after(&code_of(text), "crate::");
    assert_eq!(names.into_iter().collect::<Vec<_>>(), vec!["a".to_string()]);
}
