//! `rigscript --version` names the version and the commit the binary was built from; the
//! build script's git questions (build/commit.rs) on scratch repositories: a commit, a changed
//! source, no checkout at all, a crate inside someone else's repository.

#[path = "../build/commit.rs"]
mod commit;

use crate::common::{require_tool, rigscript, stderr, stdout, TempDir};
use std::path::Path;
use std::process::Command;

fn git(dir: &Path, args: &[&str]) -> String {
    let out = Command::new("git")
        .arg("-C")
        .arg(dir)
        .args(["-c", "user.name=t", "-c", "user.email=t@example.com"])
        .args(args)
        .output()
        .unwrap();
    assert!(out.status.success(), "git {args:?}: {}", stderr(&out));
    stdout(&out).trim().to_string()
}

/// A repository in `dir` with one commit holding src/lib.rs and README.
fn repository(dir: &Path) -> String {
    std::fs::create_dir_all(dir.join("src")).unwrap();
    std::fs::write(dir.join("src/lib.rs"), "// one\n").unwrap();
    std::fs::write(dir.join("README"), "read me\n").unwrap();
    git(dir, &["init", "-q"]);
    git(dir, &["add", "."]);
    git(dir, &["commit", "-q", "-m", "first"]);
    git(dir, &["rev-parse", "--short", "HEAD"])
}

#[test]
fn the_version_names_the_release_and_the_commit_built_from() {
    require_tool("git", "git");
    let out = Command::new(rigscript()).arg("--version").output().unwrap();
    assert!(out.status.success());
    let said = String::from_utf8(out.stdout).unwrap();
    let head = git(
        Path::new(env!("CARGO_MANIFEST_DIR")),
        &["rev-parse", "--short", "HEAD"],
    );
    let clean = format!("rigscript {} (commit {head})\n", env!("CARGO_PKG_VERSION"));
    let dirty = format!(
        "rigscript {} (commit {head}-dirty)\n",
        env!("CARGO_PKG_VERSION")
    );
    assert!(said == clean || said == dirty, "{said:?}, not {clean:?}");
}

#[test]
fn a_checkout_gives_its_commit_and_dirty_once_a_source_differs_from_it() {
    require_tool("git", "git");
    let d = TempDir::new("version-checkout");
    let head = repository(d.root());
    let found = commit::built_from(d.root(), &["src"]);
    assert_eq!(found.description, format!("commit {head}"));
    // HEAD and the branch's ref: a new commit or checkout reruns the build script.
    assert!(found.git_files.iter().any(|p| p.ends_with(".git/HEAD")));
    assert!(found.git_files.len() >= 2, "{:?}", found.git_files);

    std::fs::write(d.path("README"), "changed\n").unwrap();
    assert_eq!(
        commit::built_from(d.root(), &["src"]).description,
        format!("commit {head}"),
        "a file outside the sources does not change the binary"
    );
    std::fs::write(d.path("src/new.rs"), "// new\n").unwrap();
    assert_eq!(
        commit::built_from(d.root(), &["src"]).description,
        format!("commit {head}-dirty"),
        "a source not committed yet"
    );
    std::fs::remove_file(d.path("src/new.rs")).unwrap();
    std::fs::write(d.path("src/lib.rs"), "// two\n").unwrap();
    assert_eq!(
        commit::built_from(d.root(), &["src"]).description,
        format!("commit {head}-dirty")
    );
}

#[test]
fn outside_a_checkout_of_its_own_the_commit_is_unknown() {
    require_tool("git", "git");
    let d = TempDir::new("version-tarball");
    std::fs::create_dir_all(d.path("src")).unwrap();
    assert_eq!(
        commit::built_from(d.root(), &["src"]).description,
        commit::UNKNOWN
    );
    // Unpacked inside another repository (a vendored crate): that repository's commit is not
    // this crate's.
    let outer = TempDir::new("version-outer");
    repository(outer.root());
    let inner = outer.path("vendor/rigscript");
    std::fs::create_dir_all(inner.join("src")).unwrap();
    let found = commit::built_from(&inner, &["src"]);
    assert_eq!(found.description, commit::UNKNOWN);
    assert!(found.git_files.is_empty());
}
