//! Housekeeping of the documentation: every link of `README.md`, `docs/**/*.md` and
//! `CITATION.cff` stays inside the repository and points at a committed file (and, into a
//! markdown file, at one of its headings); no machine-specific path; no placeholder repository
//! URL in any `Cargo.toml`; the README's exit codes are the ones the binary returns.

use needle_host::run::Outcome;
use std::collections::BTreeSet;
use std::path::{Component, Path, PathBuf};

/// The repository's root (this crate is `tests/`).
fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ has a parent")
        .to_path_buf()
}

/// The committed files (relative, `/`-separated) and their folders, when git is available.
fn tracked(root: &Path) -> Option<BTreeSet<String>> {
    let out = std::process::Command::new("git")
        .args(["ls-files", "-z"])
        .current_dir(root)
        .output()
        .ok()?;
    if !out.status.success() {
        return None;
    }
    let mut set = BTreeSet::new();
    for f in String::from_utf8_lossy(&out.stdout).split('\0') {
        if f.is_empty() {
            continue;
        }
        let mut p = f;
        set.insert(p.to_owned());
        while let Some(i) = p.rfind('/') {
            p = &p[..i];
            set.insert(p.to_owned());
        }
    }
    Some(set)
}

/// The documents checked: `README.md`, every `.md` under `docs/`, `CITATION.cff`.
fn documents(root: &Path) -> Vec<PathBuf> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                walk(&p, out);
            } else if p.extension().is_some_and(|x| x == "md") {
                out.push(p);
            }
        }
    }
    let mut v = vec![root.join("README.md"), root.join("CITATION.cff")];
    walk(&root.join("docs"), &mut v);
    v.sort();
    v
}

/// The text outside fenced code blocks, inline code spans removed (a link's text may be code:
/// `[`x`](y)` keeps its `(y)`), one entry per line with its number.
fn prose(text: &str) -> Vec<(usize, String)> {
    lines_outside_fences(text, false)
}

/// The lines outside fenced code blocks with their numbers; inline code spans removed, or with
/// `keep_code` only their backticks (a heading's anchor is made of its code too: ``## `[gel]` ``
/// is `#gel`).
fn lines_outside_fences(text: &str, keep_code: bool) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let mut fence: Option<&str> = None;
    for (i, line) in text.lines().enumerate() {
        let t = line.trim_start();
        let marker = if t.starts_with("```") {
            Some("```")
        } else if t.starts_with("~~~") {
            Some("~~~")
        } else {
            None
        };
        match (fence, marker) {
            (None, Some(m)) => {
                fence = Some(m);
                continue;
            }
            (Some(f), Some(m)) if f == m => {
                fence = None;
                continue;
            }
            (Some(_), _) => continue,
            (None, None) => {}
        }
        let mut s = String::new();
        let mut in_code = false;
        for c in line.chars() {
            if c == '`' {
                in_code = !in_code;
            } else if !in_code || keep_code {
                s.push(c);
            }
        }
        out.push((i + 1, s));
    }
    out
}

/// The link targets of a markdown line: `[text](target)`, `![alt](target "title")`,
/// `[label]: target`, `href="…"` and `src="…"`.
fn link_targets(line: &str) -> Vec<String> {
    let mut v = Vec::new();
    let mut rest = line;
    while let Some(i) = rest.find("](") {
        let after = &rest[i + 2..];
        // The target ends at the matching `)` (one level of parentheses inside it allowed).
        let mut depth = 0;
        let mut end = after.len();
        for (k, c) in after.char_indices() {
            match c {
                '(' => depth += 1,
                ')' if depth == 0 => {
                    end = k;
                    break;
                }
                ')' => depth -= 1,
                _ => {}
            }
        }
        let inner = after[..end].trim();
        let target = inner
            .strip_prefix('<')
            .and_then(|t| t.split('>').next())
            .unwrap_or_else(|| inner.split_whitespace().next().unwrap_or(""));
        v.push(target.to_owned());
        rest = &after[end.min(after.len())..];
    }
    let t = line.trim_start();
    if let Some(def) = t.strip_prefix('[')
        && let Some(j) = def.find("]:")
        && let Some(target) = def[j + 2..].split_whitespace().next()
    {
        v.push(target.to_owned());
    }
    for attr in ["href=\"", "src=\""] {
        let mut rest = line;
        while let Some(i) = rest.find(attr) {
            let after = &rest[i + attr.len()..];
            let end = after.find('"').unwrap_or(after.len());
            v.push(after[..end].to_owned());
            rest = &after[end..];
        }
    }
    v
}

/// GitHub's anchor of a heading: lower case, spaces to `-`, punctuation dropped.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c),
            _ => None,
        })
        .collect()
}

/// The anchors of a markdown file's headings (`#`… lines outside code blocks; a repeated
/// heading gets `-1`, `-2`, … as on GitHub).
fn anchors(text: &str) -> BTreeSet<String> {
    let mut set = BTreeSet::new();
    for (_, line) in lines_outside_fences(text, true) {
        let t = line.trim_start();
        let level = t.chars().take_while(|c| *c == '#').count();
        if (1..=6).contains(&level) && t[level..].starts_with(' ') {
            let base = slug(&t[level..]);
            let mut a = base.clone();
            let mut k = 0;
            while set.contains(&a) {
                k += 1;
                a = format!("{base}-{k}");
            }
            set.insert(a);
        }
    }
    set
}

/// Whether a URL looks like a placeholder (`https://github.com/OWNER/REPO`, example.com, …).
fn placeholder_url(url: &str) -> bool {
    let l = url.to_lowercase();
    [
        "example.com",
        "example.org",
        "example.net",
        "your-",
        "your_",
        "yourname",
        "yourorg",
        "youruser",
        "username",
        "owner/",
        "user/repo",
        "org/repo",
        "todo",
        "fixme",
        "xxx",
        "placeholder",
        "<",
        ">",
        "changeme",
    ]
    .iter()
    .any(|p| l.contains(p))
}

/// `path` with `.` and `..` resolved, relative to the repository (none when it leaves it).
fn inside(root: &Path, path: &Path) -> Option<String> {
    let rel = path.strip_prefix(root).ok()?;
    let mut parts: Vec<String> = Vec::new();
    for c in rel.components() {
        match c {
            Component::Normal(s) => parts.push(s.to_string_lossy().into_owned()),
            Component::CurDir => {}
            Component::ParentDir => {
                parts.pop()?;
            }
            Component::RootDir | Component::Prefix(_) => return None,
        }
    }
    Some(parts.join("/"))
}

/// `%20` and the like decoded.
fn percent_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%'
            && i + 2 < b.len()
            && let Some(x) = std::str::from_utf8(&b[i + 1..i + 3])
                .ok()
                .and_then(|h| u8::from_str_radix(h, 16).ok())
        {
            out.push(x);
            i += 3;
            continue;
        }
        out.push(b[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// What is wrong with one link of `doc` (none when it is fine).
fn check_link(
    root: &Path,
    tracked: Option<&BTreeSet<String>>,
    doc: &Path,
    target: &str,
) -> Option<String> {
    let t = target.trim();
    if t.is_empty() {
        return Some("an empty link".into());
    }
    let lower = t.to_lowercase();
    if lower.starts_with("http://") || lower.starts_with("https://") {
        return placeholder_url(t).then(|| format!("`{t}` looks like a placeholder URL"));
    }
    if lower.starts_with("mailto:") {
        return None;
    }
    if lower.starts_with("file:") {
        return Some(format!("`{t}` links to a file on one machine"));
    }
    if t.contains("://") {
        return Some(format!("`{t}`: an unexpected scheme"));
    }
    let (path, anchor) = match t.split_once('#') {
        Some((p, a)) => (p, Some(a)),
        None => (t, None),
    };
    let path = percent_decode(path.split('?').next().unwrap_or(path));
    if path.starts_with('/') || path.starts_with('\\') || path.chars().nth(1) == Some(':') {
        return Some(format!(
            "`{t}` is an absolute path (outside the repository)"
        ));
    }
    let file = if path.is_empty() {
        doc.to_path_buf()
    } else {
        doc.parent().unwrap_or(root).join(&path)
    };
    let Some(rel) = inside(root, &file) else {
        return Some(format!("`{t}` leads outside the repository"));
    };
    if !file.exists() {
        return Some(format!("`{t}`: `{rel}` does not exist"));
    }
    if let Some(tr) = tracked
        && !rel.is_empty()
        && !tr.contains(&rel)
    {
        return Some(format!(
            "`{t}`: `{rel}` is not committed (a fresh clone lacks it)"
        ));
    }
    if let Some(a) = anchor.filter(|a| !a.is_empty())
        && file.extension().is_some_and(|x| x == "md")
    {
        let text = std::fs::read_to_string(&file).unwrap_or_default();
        if !anchors(&text).contains(&a.to_lowercase()) {
            return Some(format!("`{t}`: no heading `#{a}` in `{rel}`"));
        }
    }
    None
}

#[test]
fn docs_link_only_to_committed_files_inside_the_repository() {
    let root = root();
    let tracked = tracked(&root);
    if tracked.is_none() {
        eprintln!("no git: checking the links against the files on disk only");
    }
    let mut problems = Vec::new();
    let mut links = 0;
    for doc in documents(&root) {
        let name = doc
            .strip_prefix(&root)
            .unwrap_or(&doc)
            .display()
            .to_string();
        let Ok(text) = std::fs::read_to_string(&doc) else {
            problems.push(format!("{name}: cannot be read"));
            continue;
        };
        // Machine-specific paths, anywhere (code blocks included).
        for (i, line) in text.lines().enumerate() {
            for p in ["/work/", "/home/", "/Users/", "/root/", "C:\\"] {
                if line.contains(p) {
                    problems.push(format!("{name}:{}: a path of one machine ({p})", i + 1));
                }
            }
        }
        if doc.extension().is_some_and(|x| x == "cff") {
            // CITATION.cff: its URLs (url, repository-code, repository-artifact, value).
            for (i, line) in text.lines().enumerate() {
                let t = line.trim_start().trim_start_matches("- ");
                let Some((key, value)) = t.split_once(':') else {
                    continue;
                };
                let value = value.trim().trim_matches('"').trim_matches('\'');
                let key = key.trim();
                let url_key = key == "url" || key.starts_with("repository");
                if url_key || value.starts_with("http") {
                    links += 1;
                    if url_key && !value.starts_with("https://") && !value.starts_with("http://") {
                        problems.push(format!("{name}:{}: `{key}` is not a URL", i + 1));
                    } else if placeholder_url(value) {
                        problems.push(format!("{name}:{}: placeholder URL `{value}`", i + 1));
                    }
                }
            }
            continue;
        }
        for (n, line) in prose(&text) {
            for target in link_targets(&line) {
                links += 1;
                if let Some(p) = check_link(&root, tracked.as_ref(), &doc, &target) {
                    problems.push(format!("{name}:{n}: {p}"));
                }
            }
        }
    }
    assert!(
        links > 20,
        "only {links} links found: is the scanner broken?"
    );
    assert!(
        problems.is_empty(),
        "{} documentation link problem(s):\n  {}",
        problems.len(),
        problems.join("\n  ")
    );
}

#[test]
fn no_placeholder_repository_url_in_any_cargo_toml() {
    let root = root();
    let mut manifests = vec![root.join("Cargo.toml")];
    for member in ["core", "host", "sim-bridge", "tests"] {
        manifests.push(root.join(member).join("Cargo.toml"));
    }
    let mut problems = Vec::new();
    for m in &manifests {
        let text = std::fs::read_to_string(m).unwrap_or_else(|e| panic!("{}: {e}", m.display()));
        for (i, line) in text.lines().enumerate() {
            let t = line.trim();
            if t.starts_with('#') {
                continue;
            }
            for key in ["repository", "homepage", "documentation"] {
                let Some(rest) = t.strip_prefix(key) else {
                    continue;
                };
                let Some(value) = rest.trim_start().strip_prefix('=') else {
                    continue;
                };
                let v = value.trim().trim_matches('"');
                if v == "true" || v.starts_with('{') {
                    continue; // `repository.workspace = true` and the like
                }
                if !v.starts_with("https://") || placeholder_url(v) {
                    problems.push(format!(
                        "{}:{}: {key} = {v} (a real URL or none)",
                        m.display(),
                        i + 1
                    ));
                }
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn the_readme_lists_every_exit_code_of_a_run() {
    let readme = std::fs::read_to_string(root().join("README.md")).expect("README.md");
    let section = readme
        .split("\n## ")
        .find(|s| s.starts_with("Exit codes"))
        .expect("README.md has a section \"Exit codes\"");
    let listed: BTreeSet<u8> = section
        .lines()
        .filter_map(|l| l.strip_prefix('|'))
        .filter_map(|l| l.split('|').next()?.trim().parse().ok())
        .collect();
    // Usage and refusal, and every outcome of a run.
    let mut expected: BTreeSet<u8> = [1, 2].into();
    for o in [
        Outcome::Reached,
        Outcome::MissedTarget,
        Outcome::ObstacleHit,
        Outcome::Diverged,
        Outcome::LeftPath,
    ] {
        expected.insert(o.exit_code());
    }
    assert_eq!(listed, expected, "the README's exit codes");
}

#[test]
fn the_link_scanner_finds_and_judges_links() {
    let line = "see [`a`](docs/a.md#x-y), ![img](img/p.png \"t\"), [w](https://x.org/(b)) and \
                <img src=\"s.png\">";
    assert_eq!(
        link_targets(line),
        ["docs/a.md#x-y", "img/p.png", "https://x.org/(b)", "s.png"]
    );
    assert_eq!(link_targets("[ref]: ../up.md"), ["../up.md"]);
    let p = prose("a `[x](no)` b\n```\n[y](no)\n```\n[z](yes)");
    let found: Vec<String> = p.iter().flat_map(|(_, l)| link_targets(l)).collect();
    assert_eq!(found, ["yes"]);
    assert_eq!(
        slug("Background factorisation of the gel"),
        "background-factorisation-of-the-gel"
    );
    assert_eq!(slug("Run metrics and outcome"), "run-metrics-and-outcome");
    assert_eq!(
        slug("Two processes: host and core"),
        "two-processes-host-and-core"
    );
    // A heading's code is part of its anchor (it used to be dropped, and such a heading had
    // none).
    let a = anchors("## `[insertion]`\n### Moving tissue (`[gel.support_motion]`)\n");
    assert!(
        a.contains("insertion") && a.contains("moving-tissue-gelsupport_motion"),
        "{a:?}"
    );
    let root = root();
    let doc = root.join("docs").join("benchmark.md");
    for bad in [
        "/etc/passwd",
        "../../outside.md",
        "file:///tmp/x",
        "missing.md",
        "https://github.com/OWNER/needle",
        "architecture.md#no-such-heading",
    ] {
        assert!(check_link(&root, None, &doc, bad).is_some(), "{bad} passed");
    }
    for good in [
        "../README.md",
        "architecture.md",
        "../scenes",
        "https://hal.science/hal-01353925",
    ] {
        assert_eq!(check_link(&root, None, &doc, good), None, "{good}");
    }
    assert!(placeholder_url("https://github.com/your-org/needle"));
    assert!(!placeholder_url(
        "https://github.com/eclipse-iceoryx/iceoryx2"
    ));
    assert_eq!(percent_decode("a%20b"), "a b");
}
