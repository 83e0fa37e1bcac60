//! Whether a counterexample's scenario test fails as its run did, through the same code as
//! `rigscript test` (`script::scenario`): shrinking keeps only candidates whose test fails
//! so, and `verify` runs the file it wrote before it says "reproduce:". A test that does not
//! fail naming the same check is a defect of `verify`, reported as such.

use super::checks::{Finding, Property, Watch};
use super::exec::{Step, Target};
use super::plan::StartPoint;
use super::testfile::{absolute, relative, TestFile};
use crate::script::scenario::{run_file, run_source, TestResult};
use std::path::{Path, PathBuf};

/// How a counterexample's test failed to reproduce its finding.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct NotReproduced(pub String);

/// What `rigscript test` shows when `check` fails in a written test.
pub fn failure_text(check: &Property) -> String {
    match check {
        Property::Invariant(name) => format!("invariant {name:?} is false"),
        other => other.to_string(),
    }
}

/// Whether `results` (one written test's) fail naming `check`.
pub fn judge(results: &[TestResult], check: &Property) -> Result<(), NotReproduced> {
    let _ends = crate::guardian::pulse::EndsLoop;
    let want = failure_text(check);
    match results {
        [r] => match &r.failure {
            Some(why) if why.contains(&want) => Ok(()),
            Some(why) => Err(NotReproduced(format!("it fails otherwise: {why}"))),
            None => Err(NotReproduced("it passes".into())),
        },
        _ => Err(NotReproduced(format!(
            "it ran {} test(s) instead of one",
            results.len()
        ))),
    }
}

/// The test a run's steps are written as, its paths relative to `dir`.
pub fn render(
    target: &Target,
    dir: &Path,
    start: &StartPoint,
    steps: &[Step],
    finding: &Finding,
    header: &[String],
) -> String {
    let script = relative(dir, &absolute(&target.script));
    let config = target
        .config_file
        .as_deref()
        .map(|c| relative(dir, &absolute(c)));
    TestFile {
        script: &script,
        config: config.as_deref(),
        start,
        steps,
        finding,
        safe_states: &Watch::new(&target.config).safe_states(),
        header,
    }
    .render()
}

/// The directory a test is run from in memory: the script's.
fn script_dir(target: &Target) -> PathBuf {
    absolute(&target.script)
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_default()
}

/// Runs the test the steps would be written as (in memory, beside the script) and checks
/// that it fails naming the finding's check.
pub fn check_steps(
    target: &Target,
    start: &StartPoint,
    steps: &[Step],
    finding: &Finding,
) -> Result<(), NotReproduced> {
    let dir = script_dir(target);
    let text = render(target, &dir, start, steps, finding, &[]);
    let results = run_source(&text, &dir, "(counterexample)", |_| {});
    judge(&results, &finding.check)
}

/// Runs the written test file at `path` as `rigscript test` does and checks that it fails
/// naming `check`.
pub fn check_file(path: &Path, check: &Property) -> Result<(), NotReproduced> {
    let results = run_file(path, &path.display().to_string(), |_| {});
    judge(&results, check)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn result(failure: Option<&str>) -> TestResult {
        TestResult {
            name: "f::test_x".into(),
            failure: failure.map(String::from),
        }
    }

    #[test]
    fn only_a_failure_naming_the_same_check_reproduces() {
        let inv = Property::Invariant("guards".into());
        let named = "invariant \"guards\" is false: io DI 0x00 (t=40ms) at f:3:5";
        assert_eq!(judge(&[result(Some(named))], &inv), Ok(()));
        assert_eq!(
            judge(&[result(None)], &inv),
            Err(NotReproduced("it passes".into()))
        );
        assert!(judge(&[result(Some("invariant \"other\" is false"))], &inv).is_err());
        let err = "assert_eq failed: built-in check \"no script error\": left [..], right []";
        assert_eq!(judge(&[result(Some(err))], &Property::ScriptError), Ok(()));
        assert!(judge(&[result(Some(err))], &Property::EndSafe).is_err());
    }
}
