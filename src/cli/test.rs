//! `rigscript test [PATH..]`: runs the scenario tests (`*.test.rhai`, default under
//! `scripts/tests/`) in virtual time against the simulators; one line per test, then
//! `N passed, N failed`. Exit status 0 when all pass, 1 when any fails (a file without tests
//! fails), 2 when no test file is found or the JUnit report cannot be written. `--junit FILE` also writes the results as
//! JUnit XML for CI: a suite per test file, a case per test function.

use crate::report::junit::{self, Outcome, TestCase, TestSuite};
use crate::script::scenario::{run_file, test_files, TestResult};
use clap::Args;
use std::path::PathBuf;
use std::time::Instant;

/// Where scenario tests live unless told otherwise.
pub const DEFAULT_PATH: &str = "scripts/tests";

/// Options of `rigscript test`.
#[derive(Debug, Args)]
pub struct TestArgs {
    /// Test files or directories of them (default scripts/tests).
    pub paths: Vec<PathBuf>,
    /// Also write the results as JUnit XML to FILE (Jenkins, GitLab): a suite per test file,
    /// a case per test, failures with their message.
    #[arg(long, value_name = "FILE")]
    pub junit: Option<PathBuf>,
}

/// Runs `rigscript test`; returns the exit status.
pub fn run(args: TestArgs) -> i32 {
    if let Some(path) = &args.junit {
        if let Err(e) = junit::check_path(path) {
            eprintln!("rigscript test: {e}");
            return 2;
        }
    }
    let paths = if args.paths.is_empty() {
        if !std::path::Path::new(DEFAULT_PATH).is_dir() {
            let here = std::env::current_dir()
                .map(|d| format!(" ({})", d.display()))
                .unwrap_or_default();
            eprintln!(
                "rigscript test: no test files given, and no {DEFAULT_PATH}/ in this directory{here}, \
                 where they are looked for by default; give the test files (*.test.rhai) or \
                 directories of them: rigscript test PATH.."
            );
            return 2;
        }
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
    let mut suites = Vec::new();
    for file in files {
        let name = file.display().to_string();
        let started = Instant::now();
        let mut suite = TestSuite {
            name: name.clone(),
            timestamp: junit::timestamp_now(),
            time: std::time::Duration::ZERO,
            properties: Vec::new(),
            cases: Vec::new(),
            notes: String::new(),
        };
        let mut last = Instant::now();
        run_file(&file, &name, |r: &TestResult| {
            match &r.failure {
                None => {
                    passed += 1;
                    println!("ok   {}", r.name);
                }
                Some(why) => {
                    failed += 1;
                    println!("FAIL {}: {why}", r.name);
                }
            }
            suite.cases.push(test_case(r, &name, last.elapsed()));
            last = Instant::now();
        });
        suite.time = started.elapsed();
        suites.push(suite);
    }
    println!("{passed} passed, {failed} failed");
    if let Some(path) = &args.junit {
        if let Err(e) = junit::write(path, &suites) {
            eprintln!(
                "rigscript test: cannot write the JUnit report {}: {e}",
                path.display()
            );
            return 2;
        }
    }
    i32::from(failed > 0)
}

/// A scenario test as a JUnit case: named by its function, grouped by its file.
fn test_case(r: &TestResult, file: &str, time: std::time::Duration) -> TestCase {
    let name = r
        .name
        .strip_prefix(file)
        .and_then(|n| n.strip_prefix("::"))
        .unwrap_or(&r.name);
    let mut case = TestCase::passed(name, file);
    case.time = time;
    if let Some(why) = &r.failure {
        case.outcome = Outcome::Failure {
            message: why.clone(),
            kind: "scenario".into(),
            detail: String::new(),
        };
    }
    case
}
