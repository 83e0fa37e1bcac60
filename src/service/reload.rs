//! A reload made ready off the scan loop: the script file read once it has stopped changing
//! (an editor's save can leave it empty or half written), refused empty, checked as `check`
//! does, and its scenario tests (`tests/NAME.test.rhai` beside it, or `run --reload-tests`)
//! run in virtual time; only then is the text handed to the loop (`Request::Reload`), which
//! compiles it again and swaps it in at a tick boundary.

use crate::config::RigConfig;
use crate::runtime::log::Level;
use crate::runtime::remote::Remote;
use crate::runtime::requests::{Answer, Request, Requester};
use crate::script::check::check;
use crate::script::scenario::run_file;
use crate::script::stack::on_script_stack;
use crate::text_file::{read_text, TextKind};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
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

/// How long the loop may take to swap a ready script in (the next tick boundary).
pub const SWAP_WAIT: Duration = Duration::from_secs(10);

/// How long a refusal's log line may wait for the loop.
const LOG_WAIT: Duration = Duration::from_secs(2);

/// A reload from start to end: made ready here (off the loop) by `reloader`, swapped in by
/// the loop through `ask`; asked by `by`. A refusal made here is told to the run's log too.
pub fn reload(
    reloader: &Reloader,
    ask: &Requester,
    script: Option<&Path>,
    by: String,
) -> Result<(), String> {
    let swapped = match reloader.prepare(script) {
        Ok(ready) => {
            let request = Request::Reload {
                source: ready.source,
                file: ready.file,
                by,
            };
            return match ask.ask(request, SWAP_WAIT) {
                Ok(Answer::Accepted) => Ok(()),
                Ok(Answer::Refused(why)) => Err(why),
                Ok(Answer::Snapshot(_)) => Err("the run answered with a snapshot".into()),
                Err(e) => Err(e.to_string()),
            };
        }
        Err(why) => format!("reload refused: {why}; the old script runs on"),
    };
    // The loop logs its own refusals; one made off the loop never reaches the log else.
    let line = Remote::Log {
        level: Level::Error,
        message: format!("{swapped} (asked by {by})"),
    };
    let _ = ask.ask(Request::Remote(line), LOG_WAIT);
    Err(swapped)
}

/// How often `run --watch` looks at the script file.
pub const WATCH_EVERY: Duration = Duration::from_millis(250);

/// `run --watch`: a thread that reloads the run's script whenever its file changes (once it
/// has settled); told to stop when dropped (not waited for: a reload under way ends by
/// itself, the run having ended).
pub struct Watcher {
    stop: Arc<AtomicBool>,
}

impl Watcher {
    /// Watches `reloader.script`, whose text the run started with is `started`.
    pub fn start(reloader: Reloader, ask: Requester, started: String) -> std::io::Result<Self> {
        let stop = Arc::new(AtomicBool::new(false));
        let stopping = Arc::clone(&stop);
        std::thread::Builder::new()
            .name("rigscript-watch".into())
            .spawn(move || watch(&reloader, &ask, started, &stopping))?;
        Ok(Self { stop })
    }
}

impl Drop for Watcher {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
    }
}

/// Reloads each new text of the script until `stop`; a version refused is not tried again
/// until the file changes once more.
fn watch(reloader: &Reloader, ask: &Requester, mut known: String, stop: &AtomicBool) {
    while !stop.load(Ordering::SeqCst) {
        std::thread::sleep(WATCH_EVERY);
        // Unreadable for a moment (an editor replacing it): looked at again next time.
        match read_text(&reloader.script, TextKind::Script) {
            Ok(text) if text != known => known = text,
            _ => continue,
        }
        if stop.load(Ordering::SeqCst) {
            return;
        }
        // The text the reload took, settled, is the one known from now on.
        if let Ok(settled) = settled(&reloader.script, SETTLE, SETTLE_LIMIT) {
            known = settled;
        }
        let _ = reload(reloader, ask, None, "run --watch".into());
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
