//! The docs as a map (issue 47, item 6): docs/README.md indexes every doc, the repository paths
//! the docs, Cargo.toml and the code cite exist, the design notes outside the repository are
//! cited by one path, and the README installs with the lock file's versions.

use std::path::{Path, PathBuf};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn read(rel: &str) -> String {
    std::fs::read_to_string(root().join(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

/// Files under `dir` (relative to the root) whose names end with one of `exts`, recursively.
fn files(dir: &str, exts: &[&str]) -> Vec<String> {
    let mut out = Vec::new();
    let mut stack = vec![root().join(dir)];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else if exts.iter().any(|x| p.to_string_lossy().ends_with(x)) {
                let rel = p.strip_prefix(root()).unwrap();
                out.push(rel.to_string_lossy().into_owned());
            }
        }
    }
    out.sort();
    out
}

/// The text files that cite repository paths: the README, the docs, Cargo.toml, the code.
fn citing_files() -> Vec<String> {
    let mut v = vec!["README.md".to_string(), "Cargo.toml".to_string()];
    v.extend(files("docs", &[".md"]));
    v.extend(files("src", &[".rs"]));
    v
}

/// Repository paths cited in `text`: a top-level folder of the repository, then path characters,
/// ending in a file extension; not part of a longer path (`../shared/docs/…` is not `docs/…`).
fn cited_paths(text: &str) -> Vec<String> {
    const TOP: [&str; 9] = [
        "src/",
        "tests/",
        "tools/",
        "docs/",
        "fixtures/",
        "benches/",
        "examples/",
        "fuzz/",
        "python/",
    ];
    const EXTS: [&str; 7] = [".rs", ".md", ".py", ".sh", ".toml", ".yaml", ".bag"];
    let path_char = |c: char| c.is_ascii_alphanumeric() || "_./-".contains(c);
    let mut out = Vec::new();
    for (at, _) in text.char_indices() {
        let rest = &text[at..];
        if !TOP.iter().any(|t| rest.starts_with(t)) {
            continue;
        }
        if text[..at].chars().next_back().is_some_and(path_char) {
            continue;
        }
        let end = rest.find(|c: char| !path_char(c)).unwrap_or(rest.len());
        let path = rest[..end].trim_end_matches('.');
        if EXTS.iter().any(|x| path.ends_with(x)) {
            out.push(path.to_string());
        }
    }
    out
}

#[test]
fn cited_repository_paths_exist() {
    let mut missing = Vec::new();
    for file in citing_files() {
        for (n, line) in read(&file).lines().enumerate() {
            for path in cited_paths(line) {
                if !root().join(&path).exists() {
                    missing.push(format!("{file}:{}: {path}", n + 1));
                }
            }
        }
    }
    assert!(
        missing.is_empty(),
        "cited but absent:\n{}",
        missing.join("\n")
    );
}

#[test]
fn the_design_notes_are_cited_by_one_path() {
    let mut wrong = Vec::new();
    let mut files = citing_files();
    files.extend(files_of_tools_and_fixtures());
    for file in files {
        for (n, line) in read(&file).lines().enumerate() {
            for (at, _) in line.match_indices("DESIGN") {
                let cited =
                    line[at..].starts_with("DESIGN.md") || line[at..].starts_with("DESIGN §");
                if cited && !line[..at].ends_with("../shared/docs/") {
                    wrong.push(format!("{file}:{}: {line}", n + 1));
                }
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "cite ../shared/docs/DESIGN.md §N:\n{}",
        wrong.join("\n")
    );
}

fn files_of_tools_and_fixtures() -> Vec<String> {
    let mut v = files("tools", &[".py", ".sh", ".md"]);
    v.extend(files("fixtures", &[".md"]));
    v
}

#[test]
fn docs_readme_indexes_every_doc_and_its_links_resolve() {
    let index = read("docs/README.md");
    for doc in files("docs", &[".md"]) {
        let name = Path::new(&doc).file_name().unwrap().to_str().unwrap();
        if name == "README.md" {
            continue;
        }
        let entries = index
            .lines()
            .filter(|l| l.starts_with("- ") && l.contains(&format!("]({name})")))
            .count();
        assert!(entries >= 1, "docs/README.md does not index {name}");
    }
    for link in index.split("](").skip(1) {
        let target = link.split(')').next().unwrap();
        let target = target.split('#').next().unwrap();
        let p: PathBuf = root().join("docs").join(target);
        assert!(p.exists(), "docs/README.md links to {target}, absent");
    }
    assert!(
        read("README.md").contains("docs/README.md"),
        "the README points at the index"
    );
}

#[test]
fn the_readme_installs_with_the_lock_files_versions() {
    let readme = read("README.md");
    let installs: Vec<&str> = readme
        .lines()
        .filter(|l| l.contains("cargo install") && l.contains("--path"))
        .collect();
    assert!(!installs.is_empty());
    for line in installs {
        assert!(line.contains("--locked"), "{line}");
    }
}

#[test]
fn the_readme_states_one_fixture_ate() {
    let readme = read("README.md");
    let mut ates: Vec<&str> = readme
        .lines()
        .filter(|l| !l.contains("micro211"))
        .filter_map(|l| {
            l.split("ATE RMSE ")
                .nth(1)
                .or_else(|| l.split("ATE ").nth(1))
        })
        .filter_map(|rest| rest.split_whitespace().next())
        .filter(|v| v.starts_with(|c: char| c.is_ascii_digit()))
        .collect();
    ates.dedup();
    assert!(ates.len() <= 1, "fixture ATEs in the README: {ates:?}");
}
