//! The command line: argument parsing (clap) and one module per subcommand.

use clap::{CommandFactory, Parser, Subcommand};

pub mod api;
pub mod c29;
pub mod check;
pub mod completions;
pub mod drive;
pub mod force;
pub mod lab;
pub mod man;
pub mod output;
pub mod reload;
pub mod replay;
pub mod run;
pub mod run_outputs;
pub mod safe;
pub mod scan;
pub mod sim;
pub mod status;
pub mod test;
pub mod trc;
pub mod verify;
pub mod verify_exhaustive;

/// What `rigscript --version` prints after the name: the version and the commit built from
/// (build.rs asks git; `unknown commit` outside a checkout).
pub const VERSION: &str = concat!(
    env!("CARGO_PKG_VERSION"),
    " (",
    env!("RIGSCRIPT_BUILT_FROM"),
    ")"
);

/// rigscript: scripted, supervised, fail-safe control of TRC1000 panels and TRP-C29U modules.
#[derive(Debug, Parser)]
#[command(name = "rigscript", version = VERSION, about)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run a script on the rig's devices (or --sim) in the supervised scan loop
    Run(run::RunArgs),
    /// Write and confirm the safe state of every device in a rig (by hand, or systemd's ExecStopPost=)
    Safe(safe::SafeArgs),
    /// Show a running rig: devices, inputs and outputs, the script's state, tick figures
    Status(status::StatusArgs),
    /// List the rigs running on this machine
    #[command(visible_alias = "ps")]
    List(status::ListArgs),
    /// Stop a running rig as SIGTERM would: on_stop, the safe state, exit status 143
    Stop(status::StopArgs),
    /// Swap a running rig's script without dropping its outputs (checked and tested first; systemd's ExecReload=)
    Reload(reload::ReloadArgs),
    /// Act on a running rig's simulated devices: press, turn, set inputs, pulse, fail, restore
    Drive(drive::DriveArgs),
    /// Show every rig an MQTT broker knows, from its retained topics: status, devices, last record
    Lab(lab::LabArgs),
    /// Force an output or input of a running rig for a while (commissioning; rig.toml's force = true)
    Force(force::ForceArgs),
    /// End a force before it expires
    Unforce(force::UnforceArgs),
    /// Show the script API: every function, method and property, or one in full (`api every`)
    Api(api::ApiArgs),
    /// Check a script without running it: syntax, unknown functions, methods and argument counts (in handlers too), device names, handler parameters
    Check(check::CheckArgs),
    /// Run scenario tests (*.test.rhai) in virtual time against the simulators
    Test(test::TestArgs),
    /// Search a script for events that break its invariants, on the simulators in virtual time
    Verify(verify::VerifyArgs),
    /// Replay a run's journal in virtual time against its script or an edited one; the first tick whose outputs differ
    Replay(replay::ReplayArgs),
    /// Find TRC1000 boards and TRP-C29U modules on this machine
    Scan(scan::ScanArgs),
    /// Talk to a TRP-C29U module: I/O, counters, latches, watchdog, presets, identity, config
    C29(c29::C29Args),
    /// Talk to a TRC1000 panel board: list, relay, inputs, rotaries, monitor
    Trc(trc::TrcArgs),
    /// Serve a simulated device on a pseudo-terminal for any serial program
    Sim {
        /// Which device to simulate.
        #[command(subcommand)]
        device: sim::SimCommand,
    },
    /// Print the completion script for a shell (bash, zsh, fish, elvish, powershell)
    Completions(completions::CompletionsArgs),
    /// Print the manual page, or write every page into a directory (--out)
    Man(man::ManArgs),
}

/// A usage error found after parsing (a value valid alone but not with another option),
/// printed as clap prints its own: `error: invalid value ...`, status 2.
pub fn usage_error(message: String) -> clap::Error {
    clap::Error::raw(
        clap::error::ErrorKind::ValueValidation,
        format!("{message}\n\nFor more information, try '--help'.\n"),
    )
    .with_cmd(&Cli::command())
}

/// Whether `command` only reports (its output may go to `head` or `grep -q`), so it may end the
/// moment its reader goes away. `run` and `sim` end their own way whatever happens to standard
/// output: a run writes the safe state, a simulator removes its link.
fn reports_only(command: &Command) -> bool {
    !matches!(command, Command::Run(_) | Command::Sim { .. })
}

/// Ends the process as `cat` or `grep` end when the reader of their output goes away (SIGPIPE,
/// status 141 in the shell) instead of a panic in the middle of printing: Rust ignores SIGPIPE
/// by default.
fn die_quietly_when_stdout_closes() {
    // libc's, as `runtime::signals::watch`'s "ignore".
    // SAFETY: setting a signal's disposition to its default touches no Rust state.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// Runs the command line and returns the process exit status.
pub fn main() -> i32 {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            let _ = e.print();
            return if e.use_stderr() { 2 } else { 0 };
        }
    };
    if reports_only(&cli.command) {
        die_quietly_when_stdout_closes();
    }
    match cli.command {
        Command::Run(args) => run::run(args),
        Command::Safe(args) => safe::run(args),
        Command::Status(args) => status::status(args),
        Command::List(args) => status::list(&args),
        Command::Stop(args) => status::stop(&args),
        Command::Reload(args) => reload::run(&args),
        Command::Drive(args) => drive::run(args),
        Command::Lab(args) => lab::run(args),
        Command::Force(args) => force::force(args),
        Command::Unforce(args) => force::unforce(args),
        Command::Api(args) => api::run(args),
        Command::Check(args) => check::run(args),
        // Each test's rig has the default limits; its scripts get the stack those call for.
        Command::Test(args) => crate::script::stack::on_script_stack(
            crate::config::ScriptLimits::default().memory,
            || crate::guardian::lone::watched("rigscript test", || test::run(args)),
        ),
        Command::Verify(args) => verify::run(args),
        Command::Replay(args) => crate::script::stack::on_script_stack(
            crate::config::ScriptLimits::default().memory,
            || crate::guardian::lone::watched("rigscript replay", || replay::run(args)),
        ),
        Command::Scan(args) => scan::run(args),
        Command::C29(args) => c29::run(args),
        Command::Trc(args) => trc::run(args),
        Command::Sim { device } => sim::run(device),
        Command::Completions(args) => completions::run(args),
        Command::Man(args) => man::run(args),
    }
}
