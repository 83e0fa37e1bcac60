//! `rigscript reload RIG [SCRIPT]`: swaps a running rig's script (its own file again, or
//! SCRIPT) without dropping its outputs, through its control socket; says whether it was
//! reloaded, or refused and why (the old script then runs on). systemd's `ExecReload=` calls
//! it. Only the rig's user (and root) may, as for `stop`.
//!
//! Exit statuses: 0 reloaded; 1 refused or no answer; 2 usage; 3 no such rig running.

use super::output::say;
use super::status::find;
use crate::runtime::exit;
use crate::service::control_protocol::ClientRequest;
use clap::Args;
use std::path::PathBuf;
use std::time::Duration;

/// How long the answer is waited for: the file settling, `check`, the scenario tests, the
/// swap at the next tick boundary.
const RELOAD_ANSWER: Duration = Duration::from_secs(120);

/// `rigscript reload`'s arguments.
#[derive(Debug, Args)]
pub struct ReloadArgs {
    /// The rig's name (as `rigscript list` shows it)
    pub rig: String,
    /// The script to swap in (default: the run's own script file, read again)
    pub script: Option<PathBuf>,
}

/// Runs `rigscript reload`.
pub fn run(args: &ReloadArgs) -> i32 {
    let script = match &args.script {
        // The run reads it: a path that means the same from its directory.
        Some(p) => match std::path::absolute(p) {
            Ok(abs) => Some(abs.display().to_string()),
            Err(e) => {
                say(&format!("rigscript reload: {}: {e}", p.display()));
                return exit::USAGE;
            }
        },
        None => None,
    };
    let mut c = match find(Some(&args.rig), None) {
        Ok(c) => c,
        Err(e) => return e.say("reload"),
    };
    if let Err(e) = c.set_read_wait(Some(RELOAD_ANSWER)) {
        say(&format!("rigscript reload: {}: {e}", args.rig));
        return exit::ERROR;
    }
    match c.ask(&ClientRequest::Reload { script }) {
        Ok(_) => {
            println!("rig {} reloaded", args.rig);
            exit::OK
        }
        Err(e) => {
            say(&format!("rigscript reload: {}: {e}", args.rig));
            exit::ERROR
        }
    }
}
