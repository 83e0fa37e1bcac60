//! `rigscript check SCRIPT`: compiles a script and checks what can be checked without
//! running it (unknown functions, methods and properties and wrong argument counts, at the top
//! level and in every handler and function; device names against the rig, switch and rotary
//! names, channels, durations, cron expressions, handler parameters); each problem as
//! `file:line:column: message`.
//! Exit status 0 when there is none, 1 otherwise (2 for an unreadable file or config).

use crate::config::RigConfig;
use crate::script::check::check;
use clap::Args;
use std::path::PathBuf;

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
    let source = match std::fs::read_to_string(&args.script) {
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
        println!("{file}: ok");
        0
    } else {
        eprintln!("{file}: {} problem(s)", problems.len());
        1
    }
}
