//! A reload made ready off the scan loop: the script file read once it has stopped changing
//! (an editor's save can leave it empty or half written), refused empty, checked as `check`
//! does, and its scenario tests (`tests/NAME.test.rhai` beside it, or `run --reload-tests`)
//! run in virtual time; only then is the text handed to the loop (`Request::Reload`), which
//! compiles it again and swaps it in at a tick boundary.

use crate::config::RigConfig;
use crate::script::check::check;
use crate::script::scenario::run_file;
use crate::script::stack::on_script_stack;
use crate::text_file::{read_text, TextKind};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// How long the file must stay unchanged before it is taken.
pub const SETTLE: Duration = Duration::from_millis(300);

/// How long a file that keeps changing is waited for before the reload is refused.
pub const SETTLE_LIMIT: Duration = Duration::from_secs(10);

/// The most problems or failed tests a refusal lists.
const SHOWN: usize = 5;

/// What a reload needs to know of the run, shared with the control socket's threads.
#[derive(Debug, Clone)]
pub struct Reloader {
    /// The script the run was started with (the default of `reload RIG` with no script).
    pub script: PathBuf,
    /// The rig, which `check` checks a script against.
    pub config: RigConfig,
    /// The scenario tests a reload runs first, when not the ones beside the script.
    pub tests: Option<PathBuf>,
}

/// A script ready to swap in.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Prepared {
    /// Its text.
    pub source: String,
    /// Its file, as the log names it.
    pub file: String,
}

impl Reloader {
    /// Reads, checks and tests `script` (the run's own when none); refused with why.
    pub fn prepare(&self, script: Option<&Path>) -> Result<Prepared, String> {
        let path = script.unwrap_or(&self.script);
        let file = path.display().to_string();
        let source = settled(path, SETTLE, SETTLE_LIMIT)?;
        if source.trim().is_empty() {
            return Err(format!("{file} is empty"));
        }
        let problems = check(&source, &self.config);
        if !problems.is_empty() {
            let shown: Vec<String> = problems
                .iter()
                .take(SHOWN)
                .map(|p| format!("{file}:{p}"))
                .collect();
            return Err(format!(
                "{file} has {} problem(s) that `rigscript check` finds: {}",
                problems.len(),
                shown.join("; ")
            ));
        }
        let tests = match &self.tests {
            Some(t) if script.is_none() => Some(t.clone()),
            _ => tests_beside(path).filter(|t| t.is_file()),
        };
        if let Some(tests) = tests {
            let name = tests.display().to_string();
            let memory = self.config.limits.memory;
            let results = on_script_stack(memory, || run_file(&tests, &name, |_| {}));
            let failed: Vec<String> = results
                .iter()
                .filter_map(|r| r.failure.as_ref().map(|f| format!("{}: {f}", r.name)))
                .collect();
            if !failed.is_empty() {
                let shown: Vec<&str> = failed.iter().take(SHOWN).map(String::as_str).collect();
                return Err(format!(
                    "{} of {} scenario test(s) in {name} failed: {}",
                    failed.len(),
                    results.len(),
                    shown.join("; ")
                ));
            }
        }
        Ok(Prepared { source, file })
    }
}

/// `tests/NAME.test.rhai` beside the script `NAME.rhai`.
pub fn tests_beside(script: &Path) -> Option<PathBuf> {
    let stem = script.file_stem()?.to_str()?;
    let dir = script.parent().unwrap_or(Path::new(""));
    Some(dir.join("tests").join(format!("{stem}.test.rhai")))
}

/// The text of `path` once it has been the same for `settle`; refused if it keeps changing
/// past `limit`, or cannot be read.
pub fn settled(path: &Path, settle: Duration, limit: Duration) -> Result<String, String> {
    let read = || {
        read_text(path, TextKind::Script)
            .map_err(|e| format!("cannot read {}: {e}", path.display()))
    };
    let until = Instant::now() + limit;
    let mut last = read()?;
    loop {
        std::thread::sleep(settle);
        let now = read()?;
        if now == last {
            return Ok(now);
        }
        if Instant::now() >= until {
            return Err(format!(
                "{} kept changing for {}s; reload once it is saved",
                path.display(),
                limit.as_secs()
            ));
        }
        last = now;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reloader(dir: &Path) -> Reloader {
        Reloader {
            script: dir.join("a.rhai"),
            config: RigConfig::simulated_default(),
            tests: None,
        }
    }

    #[test]
    fn an_empty_a_broken_and_a_failing_script_are_refused_a_good_one_is_ready() {
        let dir = tempfile::tempdir().unwrap();
        let r = reloader(dir.path());
        let script = dir.path().join("a.rhai");
        std::fs::write(&script, "  \n").unwrap();
        assert!(r.prepare(None).unwrap_err().contains("is empty"));
        std::fs::write(&script, "let io = device(\"io\");\nio.outputs = ;\n").unwrap();
        assert!(r.prepare(None).unwrap_err().contains("rigscript check"));
        std::fs::write(&script, "let io = device(\"nope\");\n").unwrap();
        assert!(r.prepare(None).unwrap_err().contains("rigscript check"));
        let good = "let io = device(\"io\");\nevery(100, || { io.outputs = 1; });\n";
        std::fs::write(&script, good).unwrap();
        assert_eq!(r.prepare(None).unwrap().source, good);
        std::fs::create_dir(dir.path().join("tests")).unwrap();
        std::fs::write(
            dir.path().join("tests/a.test.rhai"),
            "fn test_fails() { let r = rig(\"../a.rhai\"); r.advance(200); \
             assert_eq(r.outputs(\"io\"), 7); }\n",
        )
        .unwrap();
        let e = r.prepare(None).unwrap_err();
        assert!(e.contains("1 of 1 scenario test(s)"), "{e}");
    }
}
