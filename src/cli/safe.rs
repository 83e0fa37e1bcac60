//! `rigscript safe --config rig.toml`: writes and confirms the safe state of every device in a
//! rig, by hand or from systemd's `ExecStopPost=`; the guardian does the same when a runner dies.

use crate::config::RigConfig;
use crate::guardian::safe::make_safe;
use crate::runtime::exit;
use crate::time::clock::SystemClock;
use clap::Args;
use std::path::PathBuf;

/// Options of `rigscript safe`.
#[derive(Debug, Args)]
#[command(after_help = "\
Exit status: 0 every device confirmed its safe state (a TRP-C29U's outputs read back, a \
TRC1000's relay confirmed); 3 a device could not be reached (missing, busy, no answer); 5 a \
device answered but did not apply its safe value; 2 a usage or rig.toml error.")]
pub struct SafeArgs {
    /// The rig whose devices to make safe: each TRP-C29U's `safe_value`, each TRC1000's
    /// `safe_relay`.
    #[arg(long)]
    pub config: PathBuf,
    /// Print nothing for devices that confirmed (only what went wrong).
    #[arg(short, long)]
    pub quiet: bool,
}

/// Runs `rigscript safe`; returns the exit status.
pub fn run(args: SafeArgs) -> i32 {
    let config = match RigConfig::load(&args.config) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("rigscript safe: {e}");
            return exit::USAGE;
        }
    };
    let outcomes = make_safe(&config, &SystemClock::shared());
    let mut status = exit::OK;
    for o in &outcomes {
        match &o.result {
            Ok(_) if args.quiet => {}
            Ok(_) => println!("{o}"),
            Err(e) => {
                eprintln!("rigscript safe: {o}");
                let this = if e.unreachable() {
                    exit::UNAVAILABLE
                } else {
                    exit::TROUBLE
                };
                status = status.max(this);
            }
        }
    }
    status
}
