//! The documentation holds together inside the repository: every Markdown link to
//! a file resolves to one in the repository (and a `#section` to a heading of it),
//! and no page or source sends a reader to documents the repository does not have.

mod common;

use std::path::{Component, Path, PathBuf};

use common::repo_root;

/// Folders that are not the project's own text.
const SKIPPED: &[&str] = &["target", ".git", "node_modules", ".venv", "pyenv", "nodeenv"];

fn files_with(dir: &Path, extensions: &[&str], out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let path = entry.path();
        let name = entry.file_name().to_string_lossy().into_owned();
        if path.is_dir() {
            if !SKIPPED.contains(&name.as_str()) {
                files_with(&path, extensions, out);
            }
        } else if extensions.iter().any(|e| name.ends_with(e)) {
            out.push(path);
        }
    }
}

/// The targets of the inline links `[text](target)` of a Markdown text, outside code.
fn links(text: &str) -> Vec<(usize, String)> {
    let mut found = Vec::new();
    let mut fenced = false;
    for (i, line) in text.lines().enumerate() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if fenced {
            continue;
        }
        // Inline code spans are not links.
        let mut plain = String::new();
        for (k, part) in line.split('`').enumerate() {
            if k % 2 == 0 {
                plain.push_str(part);
            }
        }
        let mut rest = plain.as_str();
        while let Some(at) = rest.find("](") {
            let after = &rest[at + 2..];
            let Some(end) = after.find(')') else { break };
            let target = after[..end].split_whitespace().next().unwrap_or("").to_string();
            found.push((i + 1, target));
            rest = &after[end..];
        }
    }
    found
}

/// GitHub's anchor of a heading: lower case, punctuation dropped, spaces as hyphens.
fn anchor(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter(|c| c.is_alphanumeric() || *c == ' ' || *c == '-' || *c == '_')
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

fn anchors(markdown: &str) -> Vec<String> {
    let mut fenced = false;
    let mut out = Vec::new();
    for line in markdown.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
        } else if !fenced && line.starts_with('#') {
            out.push(anchor(line.trim_start_matches('#')));
        }
    }
    out
}

/// `path` with `.` and `..` folded, without touching the file system.
fn normalise(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            other => out.push(other),
        }
    }
    out
}

#[test]
fn every_markdown_link_resolves_inside_the_repository() {
    let root = normalise(&repo_root());
    let mut pages = Vec::new();
    files_with(&root, &[".md"], &mut pages);
    assert!(pages.len() > 10, "found only {} Markdown files under {}", pages.len(), root.display());
    let mut broken = Vec::new();
    let mut checked = 0;
    for page in &pages {
        let text = std::fs::read_to_string(page).expect("read a page");
        let here = page.strip_prefix(&root).unwrap_or(page).display().to_string();
        for (line, target) in links(&text) {
            if target.is_empty() || target.contains("://") || target.starts_with("mailto:") {
                continue;
            }
            checked += 1;
            let (file, section) = match target.split_once('#') {
                Some((f, s)) => (f, Some(s)),
                None => (target.as_str(), None),
            };
            let resolved = if file.is_empty() { page.clone() } else { normalise(&page.parent().unwrap().join(file)) };
            if !resolved.starts_with(&root) {
                broken.push(format!("{here}:{line}: {target} leaves the repository"));
                continue;
            }
            if !resolved.exists() {
                broken.push(format!("{here}:{line}: {target} does not exist"));
                continue;
            }
            if let Some(section) = section {
                let is_markdown = resolved.extension().is_some_and(|e| e == "md");
                let headings = std::fs::read_to_string(&resolved).map(|t| anchors(&t)).unwrap_or_default();
                if is_markdown && !headings.iter().any(|h| h == section) {
                    broken.push(format!("{here}:{line}: {target}: no heading #{section} in {}", resolved.display()));
                }
            }
        }
    }
    assert!(checked > 20, "only {checked} links checked: is the link parser broken?");
    assert!(broken.is_empty(), "{} broken link(s):\n{}", broken.len(), broken.join("\n"));
}

/// Readers are never sent to documents that are not in the repository, nor told
/// about the way the project is organised rather than about the project.
#[test]
fn no_page_or_source_points_outside_the_repository() {
    let root = repo_root();
    let mut files = Vec::new();
    files_with(&root, &[".md", ".rs", ".toml", ".sh", ".py", ".mjs"], &mut files);
    let this_file = Path::new(file!()).file_name().expect("a file name").to_owned();
    // Spelled in pieces so that this file does not match itself.
    let words = [["design", ".md"].concat(), ["plant", ".md"].concat(), ["notes for this", " machine"].concat()];
    let mut found = Vec::new();
    for file in files.iter().filter(|f| f.file_name() != Some(this_file.as_os_str())) {
        let Ok(text) = std::fs::read_to_string(file) else { continue };
        let lower = text.to_lowercase();
        let here = file.strip_prefix(&root).unwrap_or(file).display().to_string();
        for word in &words {
            if lower.contains(word.as_str()) {
                found.push(format!("{here}: mentions {word}"));
            }
        }
        if lower.contains(&["..", "/shared/"].concat()) {
            found.push(format!("{here}: points into ../shared"));
        }
        // "issue 15": a tracker's numbering means nothing to a reader of the repository.
        let bytes = lower.as_bytes();
        for (at, _) in lower.match_indices("issue ") {
            if bytes.get(at + 6).is_some_and(u8::is_ascii_digit) {
                found.push(format!("{here}: mentions {}", &lower[at..(at + 9).min(lower.len())]));
            }
        }
    }
    assert!(found.is_empty(), "{}", found.join("\n"));
}

#[test]
fn the_link_parser_finds_links_and_skips_code() {
    let text = "see [a](docs/a.md) and `[b](no.md)`\n```\n[c](no.md)\n```\n[d](x.md#part) [e](https://x.org)";
    let got: Vec<String> = links(text).into_iter().map(|(_, t)| t).collect();
    assert_eq!(got, ["docs/a.md", "x.md#part", "https://x.org"]);
    assert_eq!(anchor(" What the data must be"), "what-the-data-must-be");
    assert_eq!(anchor(" Control: FBL, SMC and MPC"), "control-fbl-smc-and-mpc");
}
