//! `rigscript check SCRIPT`: compiles a script and checks what can be checked without
//! running it (unknown functions, methods and properties and wrong argument counts, at the top
//! level and in every handler and function; device names against the rig, switch and rotary
//! names, channels, durations, cron expressions, handler parameters); each problem as
//! `file:line:column: message`. Then what runs but may not be meant (`script::lint`: a timer
//! shorter than the period, nothing to run), each as `file:line:column: warning: message`.
//! Exit status 0 when there is no problem (warnings or not), 1 otherwise (2 for an unreadable
//! file or config).

use crate::config::RigConfig;
use crate::script::check::check;
use crate::script::lint::warnings;
use crate::text_file::{read_text, TextKind};
use clap::Args;
use std::path::Path;
use std::path::PathBuf;
use std::time::Duration;

/// Options of `rigscript check`.
#[derive(Debug, Args)]
pub struct CheckArgs {
    /// The script to check (.rhai).
    pub script: PathBuf,
    /// The rig whose device names the script may use (default: the --sim rig, panel and io).
    #[arg(long)]
    pub config: Option<PathBuf>,
}

/// Runs `rigscript check`; returns the exit status.
pub fn run(args: CheckArgs) -> i32 {
    let config = match &args.config {
        Some(path) => match RigConfig::load(path) {
            Ok(c) => c,
            Err(e) => {
                eprintln!("rigscript check: {e}");
                return 2;
            }
        },
        None => RigConfig::simulated_default(),
    };
    let file = args.script.display().to_string();
    let source = match read_text(&args.script, TextKind::Script) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("rigscript check: cannot read {file}: {e}");
            return 2;
        }
    };
    let problems = check(&source, &config);
    for p in &problems {
        println!("{file}:{p}");
    }
    if problems.is_empty() {
        let warned = warnings(&source, config.period);
        for w in &warned {
            println!("{}", w.for_file(&file));
        }
        match warned.len() {
            0 => println!("{file}: ok"),
            n => println!("{file}: ok, with {n} warning(s)"),
        }
        0
    } else {
        eprintln!("{file}: {} problem(s)", problems.len());
        1
    }
}

/// For the commands that run a script (`run`, `verify`): whether `check` finds nothing wrong
/// with `source`. If it does, its problems go to stderr as `check` prints them, then why
/// `command` does not run the script: a script `check` rejects would fail where it is wrong,
/// maybe in the handler that makes the rig safe, so fixing it is the only way on. If not,
/// its warnings at the scan `period` the run uses go to stderr (`None`: the caller tells
/// them itself, as `run` does in its log's format), and it runs.
pub fn fit_to_run(
    command: &str,
    file: &str,
    source: &str,
    (config, period): (&RigConfig, Option<Duration>),
    config_path: Option<&Path>,
) -> bool {
    let problems = check(source, config);
    if problems.is_empty() {
        for w in period.map(|p| warnings(source, p)).unwrap_or_default() {
            eprintln!("{}", w.for_file(file));
        }
        return true;
    }
    for p in &problems {
        eprintln!("{file}:{p}");
    }
    let with_config =
        config_path.map_or_else(String::new, |c| format!(" --config {}", c.display()));
    eprintln!(
        "rigscript {command}: {file} has {} problem(s) that `rigscript check{with_config} {file}` \
         finds; fix them first: a script check rejects does not run",
        problems.len()
    );
    false
}
