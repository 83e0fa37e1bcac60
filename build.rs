//! Build script: tells the crate which commit it is built from (`RIGSCRIPT_BUILT_FROM`, shown
//! by `rigscript --version`).

#[path = "build/commit.rs"]
mod commit;

use std::path::PathBuf;

/// What goes into the binary: a change to one of these makes the build `-dirty`.
const SOURCES: [&str; 5] = ["src", "build", "build.rs", "Cargo.toml", "Cargo.lock"];

fn main() {
    let dir = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("set by cargo"));
    let found = commit::built_from(&dir, &SOURCES);
    println!("cargo:rustc-env=RIGSCRIPT_BUILT_FROM={}", found.description);
    // Rerun on a new commit or checkout, and on a source change (which rebuilds the crate
    // anyway) for `-dirty`; nothing else, so tests, docs and git's own index do not rebuild it.
    for path in SOURCES.iter().map(|s| dir.join(s)).chain(found.git_files) {
        println!("cargo:rerun-if-changed={}", path.display());
    }
}
