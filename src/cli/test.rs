//! `rigscript test [PATH..]`: runs the scenario tests (`*.test.rhai`, default under
//! `scripts/tests/`) in virtual time against the simulators; one line per test, then
//! `N passed, N failed`. Exit status 0 when all pass, 1 when any fails, 2 when no test file
//! is found.

use crate::script::scenario::{run_file, test_files, TestResult};
use clap::Args;
use std::path::PathBuf;

/// Where scenario tests live unless told otherwise.
pub const DEFAULT_PATH: &str = "scripts/tests";

/// Options of `rigscript test`.
#[derive(Debug, Args)]
pub struct TestArgs {
    /// Test files or directories of them (default scripts/tests).
    pub paths: Vec<PathBuf>,
}

/// Runs `rigscript test`; returns the exit status.
pub fn run(args: TestArgs) -> i32 {
    let paths = if args.paths.is_empty() {
        vec![PathBuf::from(DEFAULT_PATH)]
    } else {
        args.paths
    };
    let mut files = Vec::new();
    for p in &paths {
        match test_files(p) {
            Ok(found) => files.extend(found),
            Err(e) => {
                eprintln!("rigscript test: {}: {e}", p.display());
                return 2;
            }
        }
    }
    if files.is_empty() {
        eprintln!(
            "rigscript test: no *.test.rhai files under {}",
            paths
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        );
        return 2;
    }
    let (mut passed, mut failed) = (0usize, 0usize);
    for file in files {
        let name = file.display().to_string();
        run_file(&file, &name, |r: &TestResult| match &r.failure {
            None => {
                passed += 1;
                println!("ok   {}", r.name);
            }
            Some(why) => {
                failed += 1;
                println!("FAIL {}: {why}", r.name);
            }
        });
    }
    println!("{passed} passed, {failed} failed");
    i32::from(failed > 0)
}
