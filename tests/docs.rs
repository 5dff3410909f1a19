//! The README and the pages of `docs/` link to each other's sections and to files of the
//! repository: every such link must resolve — the file exists, and an anchor (`#…`) is the
//! GitHub slug of one of that page's headings. (The measurement logs moved from the README to
//! `docs/`; a section renamed or moved again would otherwise leave links that go nowhere.)

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// GitHub's anchor of a heading: lower case, punctuation other than `-` and `_` dropped,
/// spaces to hyphens.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter(|c| c.is_alphanumeric() || *c == '-' || *c == '_' || *c == ' ')
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

/// The page's lines outside fenced code blocks.
fn prose(text: &str) -> Vec<&str> {
    let mut fenced = false;
    text.lines()
        .filter(|l| {
            if l.trim_start().starts_with("```") {
                fenced = !fenced;
                return false;
            }
            !fenced
        })
        .collect()
}

fn anchors(text: &str) -> BTreeSet<String> {
    prose(text)
        .into_iter()
        .filter_map(|l| {
            let h = l.trim_start_matches('#');
            (h.len() < l.len() && h.starts_with(' ')).then(|| slug(h))
        })
        .collect()
}

/// The targets of the page's inline links `[text](target)` (outside code spans).
fn links(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    for line in prose(text) {
        // Drop code spans: a `](` inside backticks is not a link.
        let mut plain = String::new();
        for (k, part) in line.split('`').enumerate() {
            if k % 2 == 0 {
                plain.push_str(part);
            }
        }
        let mut rest = plain.as_str();
        while let Some(i) = rest.find("](") {
            rest = &rest[i + 2..];
            if let Some(j) = rest.find(')') {
                out.push(rest[..j].to_string());
                rest = &rest[j..];
            }
        }
    }
    out
}

fn pages(root: &Path) -> Vec<PathBuf> {
    let mut p = vec![root.join("README.md")];
    let mut docs: Vec<PathBuf> = std::fs::read_dir(root.join("docs"))
        .expect("docs/ exists")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    docs.sort();
    assert!(!docs.is_empty(), "docs/ holds the measurement pages");
    p.extend(docs);
    p
}

#[test]
fn every_link_between_the_readme_and_docs_resolves() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    // Each page read once: its text and its headings' anchors.
    let texts: BTreeMap<PathBuf, (String, BTreeSet<String>)> = pages(root)
        .into_iter()
        .map(|p| {
            let text = std::fs::read_to_string(&p).unwrap();
            let a = anchors(&text);
            (p.canonicalize().unwrap(), (text, a))
        })
        .collect();
    let mut broken = Vec::new();
    let mut checked = 0;
    for (page, (text, _)) in &texts {
        let dir = page.parent().unwrap();
        for target in links(text) {
            if target.starts_with("http://") || target.starts_with("https://") || target.starts_with("mailto:") {
                continue;
            }
            checked += 1;
            let (file, anchor) = match target.split_once('#') {
                Some((f, a)) => (f, Some(a)),
                None => (target.as_str(), None),
            };
            let dest = if file.is_empty() { page.clone() } else { dir.join(file) };
            let Ok(dest) = dest.canonicalize() else {
                broken.push(format!("{}: {target} (no such file)", page.display()));
                continue;
            };
            if let Some(a) = anchor {
                let found = match texts.get(&dest) {
                    Some((_, known)) => known.contains(a),
                    None => anchors(&std::fs::read_to_string(&dest).unwrap_or_default()).contains(a),
                };
                if !found {
                    broken.push(format!("{}: {target} (no heading with that anchor)", page.display()));
                }
            }
        }
    }
    assert!(broken.is_empty(), "{} of {checked} links do not resolve:\n{}", broken.len(), broken.join("\n"));
    // The README links to its sections and to every page of docs/: far more than a handful.
    assert!(checked > 60, "only {checked} links found: the parser lost them");
}

#[test]
fn slugs_are_githubs() {
    assert_eq!(slug("In your own tools: Blender, glTF viewers, engines"), "in-your-own-tools-blender-gltf-viewers-engines");
    assert_eq!(slug("Issue 10's bench at other hours"), "issue-10s-bench-at-other-hours");
    assert_eq!(slug("The ~1M-face sample's bench"), "the-1m-face-samples-bench");
    assert_eq!(links("see [a](#b) and `[c](d)` and [e](f.md#g)"), vec!["#b".to_string(), "f.md#g".to_string()]);
}
