//! Build provenance for the run summaries: the commit (`git rev-parse`, "-dirty" with uncommitted
//! changes to tracked files) and the compiler (`rustc --version`), as `NEEDLE_COMMIT` and
//! `NEEDLE_RUSTC`. Outside a git checkout the commit is "unknown".

use std::path::Path;
use std::process::Command;

fn output(cmd: &str, args: &[&str]) -> Option<String> {
    let o = Command::new(cmd).args(args).output().ok()?;
    o.status
        .success()
        .then(|| String::from_utf8_lossy(&o.stdout).trim().to_owned())
        .filter(|s| !s.is_empty())
}

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let git = root.join(".git");
    // Rebuild when HEAD moves: HEAD itself, and the branch it names (loose or packed).
    println!("cargo:rerun-if-changed={}", git.join("HEAD").display());
    if let Ok(head) = std::fs::read_to_string(git.join("HEAD"))
        && let Some(r) = head.trim().strip_prefix("ref: ")
    {
        let loose = git.join(r);
        let watched = if loose.exists() {
            loose
        } else {
            git.join("packed-refs")
        };
        println!("cargo:rerun-if-changed={}", watched.display());
    }
    let dir = root.display().to_string();
    let commit = output("git", &["-C", &dir, "rev-parse", "--short=12", "HEAD"]).map_or_else(
        || "unknown".to_owned(),
        |c| {
            let dirty = output(
                "git",
                &["-C", &dir, "status", "--porcelain", "--untracked-files=no"],
            )
            .is_some();
            if dirty { format!("{c}-dirty") } else { c }
        },
    );
    let rustc = std::env::var("RUSTC").unwrap_or_else(|_| "rustc".to_owned());
    let version = output(&rustc, &["--version"]).unwrap_or_else(|| "unknown".to_owned());
    println!("cargo:rustc-env=NEEDLE_COMMIT={commit}");
    println!("cargo:rustc-env=NEEDLE_RUSTC={version}");
}
