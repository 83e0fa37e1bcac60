//! Which commit a build comes from, for `rigscript --version`: asked of git by build.rs, and
//! tested on scratch repositories by tests/version.rs.

use std::path::{Path, PathBuf};
use std::process::Command;

/// What `--version` says when the sources are not a git checkout (a crate tarball, a copy).
pub const UNKNOWN: &str = "unknown commit";

/// Where the sources in `dir` come from, and the files whose change can alter that answer.
pub struct BuiltFrom {
    /// `commit 1a2b3c4`, `commit 1a2b3c4-dirty` (a source path differs from it) or [`UNKNOWN`].
    pub description: String,
    /// The repository files to watch: HEAD, the branch it points to, packed refs.
    pub git_files: Vec<PathBuf>,
}

fn git(dir: &Path, args: &[&str]) -> Option<String> {
    // No optional locks: `git status` from a build must not take the index from a git
    // command the developer runs meanwhile.
    let out = Command::new("git")
        .env("GIT_OPTIONAL_LOCKS", "0")
        .arg("-C")
        .arg(dir)
        .args(args)
        .output()
        .ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
}

/// Asks git about `dir`; `sources` are the paths (relative to `dir`) that go into the build,
/// which make the commit `-dirty` when changed or added and not committed.
pub fn built_from(dir: &Path, sources: &[&str]) -> BuiltFrom {
    let unknown = BuiltFrom {
        description: UNKNOWN.to_string(),
        git_files: Vec::new(),
    };
    // Only a checkout of these sources counts: a crate unpacked inside another repository
    // would otherwise be given that repository's commit.
    let top = match git(dir, &["rev-parse", "--show-toplevel"]) {
        Some(top) => PathBuf::from(top),
        None => return unknown,
    };
    if top.canonicalize().ok() != dir.canonicalize().ok() {
        return unknown;
    }
    let Some(hash) = git(dir, &["rev-parse", "--short", "HEAD"]) else {
        return unknown;
    };
    let mut status = vec!["status", "--porcelain", "--"];
    status.extend_from_slice(sources);
    let dirty = match git(dir, &status) {
        Some(changes) => !changes.is_empty(),
        None => return unknown,
    };
    let git_path = |p: &str| git(dir, &["rev-parse", "--git-path", p]).map(|g| dir.join(g));
    let mut git_files: Vec<PathBuf> = ["HEAD", "packed-refs"]
        .into_iter()
        .filter_map(git_path)
        .collect();
    if let Some(branch) = git(dir, &["symbolic-ref", "-q", "HEAD"]) {
        // A branch whose ref is packed has no file yet: its directory shows the first commit.
        if let Some(file) = git_path(&branch) {
            let dir_of = file.parent().map(Path::to_path_buf);
            git_files.extend(if file.exists() { Some(file) } else { dir_of });
        }
    }
    // Cargo reruns the script at every build for a watched path that does not exist.
    git_files.retain(|p| p.exists());
    BuiltFrom {
        description: format!("commit {hash}{}", if dirty { "-dirty" } else { "" }),
        git_files,
    }
}
