//! `rigscript verify SCRIPT`: searches the script for a sequence of events on the simulated
//! rig that breaks one of its invariants or a built-in check, in many runs of virtual time
//! with a random but plausible field and faults; shrinks what it finds and writes it as a
//! scenario test; after a pass, reports what was exercised.
//!
//! Exit status: 0 nothing found, 1 a counterexample, 2 usage or config error (a script that
//! cannot run on the simulated rig says why, with the same messages as `check`), 70 a
//! counterexample whose written test does not fail as its run did (a defect of `verify`),
//! 130 (SIGINT, Ctrl-C) or 143 (SIGTERM) stopped before the runs were done and nothing found
//! so far: the summary of the runs played is printed, with the seed that repeats them. A
//! second signal ends it at once with the same status.

use super::check::fit_to_run;
use crate::config::RigConfig;
use crate::text_file::{read_text, TextKind};
use crate::time::duration::{format_duration, format_duration_exact, parse_duration};
use crate::verify::exec::Target;
use crate::verify::facts::Facts;
use crate::verify::horizon::Horizon;
use crate::verify::{report, reproduce, search, Options, SHRINK_BUDGET};
use clap::Args;
use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Where counterexamples go unless told otherwise.
pub const DEFAULT_OUT: &str = "verify-failures";

/// Options of `rigscript verify`.
#[derive(Debug, Args)]
pub struct VerifyArgs {
    /// The script to verify (.rhai).
    pub script: PathBuf,
    /// The rig (every device is simulated, as with `run --sim`; default: panel and io).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// How many runs at most.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u64).range(1..))]
    pub runs: u64,
    /// Virtual time each run lasts ("60s", "5m"; default: a minute, longer when the script's
    /// timers or cron schedule need it, up to 10 minutes).
    #[arg(long = "for", value_name = "DURATION", value_parser = run_for)]
    pub run_for: Option<Duration>,
    /// The seed of the search (printed; the same seed gives the same runs and result).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Worker threads (default: one per core).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=256))]
    pub jobs: Option<u64>,
    /// Play only the field: no lost devices, bad answers, stalls, clock steps or stop signals.
    #[arg(long)]
    pub no_faults: bool,
    /// Where the counterexample's test file is written.
    #[arg(long, default_value = DEFAULT_OUT)]
    pub out: PathBuf,
    /// Print one JSON document instead of text.
    #[arg(long)]
    pub json: bool,
    /// Operations each handler call (and invariant) may take (default: `operations` under
    /// `[limits]` in rig.toml, else 1000000). The other limits are rig.toml's.
    #[arg(long)]
    pub budget: Option<u64>,
    /// Explore every sequence of up to `--depth` choices (field events, faults, waits to the
    /// script's timer boundaries) instead of random runs: a shortest counterexample, or a
    /// bounded proof. Deterministic: no seed.
    #[arg(long, conflicts_with_all = ["runs", "seed", "run_for"])]
    pub exhaustive: bool,
    /// With `--exhaustive`: the most choices in a sequence (default 4).
    #[arg(long, requires = "exhaustive", value_parser = clap::value_parser!(u64).range(0..=32))]
    pub depth: Option<u64>,
}

fn run_for(text: &str) -> Result<Duration, String> {
    match parse_duration(text).map_err(|e| e.to_string())? {
        d if d.is_zero() => Err("a run needs some time: use \"60s\" or more".into()),
        d => Ok(d),
    }
}

/// The command that repeats this search, for the test file's header.
fn command(args: &VerifyArgs, seed: u64) -> String {
    let mut c = format!("rigscript verify {} --seed {seed}", args.script.display());
    if let Some(p) = &args.config {
        c.push_str(&format!(" --config {}", p.display()));
    }
    if let Some(d) = args.run_for {
        c.push_str(&format!(" --for {}", format_duration_exact(d)));
    }
    if args.no_faults {
        c.push_str(" --no-faults");
    }
    c
}

/// Prints a line on standard output; a reader that went away (`| head`) is no error.
pub(super) fn say(line: &str) {
    let _ = writeln!(std::io::stdout().lock(), "{line}");
}

/// Makes SIGINT and SIGTERM set `interrupt` to their number, so that the search stops and
/// reports; a second one while it is set ends the process at once (128 + its number).
pub(super) fn watch_signals(interrupt: &Arc<AtomicUsize>) -> std::io::Result<()> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let asked = Arc::new(AtomicBool::new(false));
    for signal in [SIGINT, SIGTERM] {
        signal_hook::flag::register_conditional_shutdown(
            signal,
            crate::runtime::exit::signal(signal),
            Arc::clone(&asked),
        )?;
        signal_hook::flag::register(signal, Arc::clone(&asked))?;
        let number = usize::try_from(signal).unwrap_or(1);
        signal_hook::flag::register_usize(signal, Arc::clone(interrupt), number)?;
    }
    Ok(())
}

/// Runs `rigscript verify`; returns the exit status.
pub fn run(args: VerifyArgs) -> i32 {
    let config = match &args.config {
        Some(path) => match RigConfig::load(path) {
            Ok(c) => c,
            Err(e) => {
                eprintln!("rigscript verify: {e}");
                return 2;
            }
        },
        None => RigConfig::simulated_default(),
    };
    // On a stack that holds whatever the script can build within its memory limit (the
    // shrinking replays run here; each worker gets one too).
    let memory = config.limits.memory;
    crate::script::stack::on_script_stack(memory, move || {
        crate::guardian::lone::watched("rigscript verify", || verify_configured(args, config))
    })
}

/// `verify` itself, once its rig is known.
fn verify_configured(args: VerifyArgs, config: RigConfig) -> i32 {
    let file = args.script.display().to_string();
    let source = match read_text(&args.script, TextKind::Script) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("rigscript verify: cannot read {file}: {e}");
            return 2;
        }
    };
    let checked = (&config, Some(config.period));
    if !fit_to_run("verify", &file, &source, checked, args.config.as_deref()) {
        return 2;
    }
    if args.exhaustive {
        return super::verify_exhaustive::run(&args, config, source);
    }
    let seed = args.seed.unwrap_or_else(|| fastrand::u64(..));
    let jobs = jobs(&args);
    let interrupt = interrupt_flag();
    let opts = Options {
        runs: args.runs,
        seed,
        jobs,
        faults: !args.no_faults,
        shrink: SHRINK_BUDGET,
        interrupt: Some(Arc::clone(&interrupt)),
    };
    let facts = Facts::read(&source);
    let horizon = Horizon::of(&facts, args.run_for);
    let target = target(&args, config, source, facts, horizon.run_for);
    if !args.json {
        say(&format!(
            "verify {file}: seed {seed}, up to {} runs of {} at {} per tick, faults {}, {jobs} \
             job(s)",
            args.runs,
            format_duration(horizon.run_for),
            format_duration(target.config.period),
            if args.no_faults { "off" } else { "on" }
        ));
        for line in horizon.notes() {
            say(&line);
        }
    }
    let total = args.runs;
    let searched = with_progress(&args, &file, |show| {
        search(&target, &opts, |done| show(format!("{done}/{total} runs")))
    });
    let Ok(summary) = searched else {
        return 2;
    };
    let (test, defect) = match &summary.counterexample {
        Some(c) => written_and_reproduced(
            &args,
            || report::write_test(&args.out, &target, &summary, c, &command(&args, seed)),
            &c.finding.check,
            |p, why| report::defect(p, c, why),
        ),
        None => (None, None),
    };
    if args.json {
        let doc = report::to_json(
            &summary,
            &opts,
            &horizon,
            test.as_deref(),
            defect.as_deref(),
        );
        say(&doc.to_string());
    } else {
        for line in report::human(&summary, &opts, test.as_deref()) {
            say(&line);
        }
        if summary.interrupted && summary.counterexample.is_none() {
            say(&format!(
                "to repeat these runs: {} --runs {}",
                command(&args, seed),
                summary.runs.max(1)
            ));
        }
    }
    exit_status(
        defect.as_deref(),
        summary.counterexample.is_some(),
        &interrupt,
        summary.interrupted,
    )
}

/// Worker threads: `--jobs`, or one a core.
pub(super) fn jobs(args: &VerifyArgs) -> usize {
    args.jobs.map_or_else(
        || std::thread::available_parallelism().map_or(1, usize::from),
        |j| usize::try_from(j).unwrap_or(1),
    )
}

/// The flag Ctrl-C and SIGTERM set (the signal's number), watched from now on.
pub(super) fn interrupt_flag() -> Arc<AtomicUsize> {
    let interrupt = Arc::new(AtomicUsize::new(0));
    if let Err(e) = watch_signals(&interrupt) {
        eprintln!("rigscript verify: cannot watch for Ctrl-C: {e}");
    }
    interrupt
}

/// The script and its rig as the runs play them, for `run_for` each.
pub(super) fn target(
    args: &VerifyArgs,
    config: RigConfig,
    source: String,
    facts: Facts,
    run_for: Duration,
) -> Target {
    Target {
        source,
        file: args.script.display().to_string(),
        script: args.script.clone(),
        config_file: args.config.clone(),
        budget: args.budget.unwrap_or(config.limits.operations),
        config,
        run_for,
        compared: facts.compared,
    }
}

/// Runs `work`, which may show progress on a terminal's stderr (one line, rewritten); a
/// failure to play on the simulated rig is said, and is the caller's exit 2.
pub(super) fn with_progress<T, E: std::fmt::Display>(
    args: &VerifyArgs,
    file: &str,
    work: impl FnOnce(&dyn Fn(String)) -> Result<T, E>,
) -> Result<T, ()> {
    let show_progress = !args.json && std::io::stderr().is_terminal();
    let show = |line: String| {
        if show_progress {
            eprint!("\r{line}");
        }
    };
    let result = work(&show);
    if show_progress {
        eprintln!();
    }
    result.map_err(|e| eprintln!("rigscript verify: {file} cannot run on the simulated rig: {e}"))
}

/// Writes the counterexample's test (`write`) and runs it through the same code as
/// `rigscript test`: only a test that fails naming `check` is offered as the reproduction;
/// one that does not is a defect of verify's (`defect` says it). The test, or the defect.
pub(super) fn written_and_reproduced<E: std::fmt::Display>(
    args: &VerifyArgs,
    write: impl FnOnce() -> Result<PathBuf, E>,
    check: &crate::verify::checks::Property,
    defect: impl FnOnce(&std::path::Path, &reproduce::NotReproduced) -> String,
) -> (Option<PathBuf>, Option<String>) {
    match write() {
        Ok(p) => match reproduce::check_file(&p, check) {
            Ok(()) => (Some(p), None),
            Err(why) => {
                let d = defect(&p, &why);
                (None, Some(d))
            }
        },
        Err(e) => {
            eprintln!(
                "rigscript verify: cannot write the counterexample's test under {}: {e}",
                args.out.display()
            );
            (None, None)
        }
    }
}

/// The exit status: 70 for a defect of verify's, 1 for a finding, 128 + the signal for an
/// interrupted search that found nothing, else 0.
pub(super) fn exit_status(
    defect: Option<&str>,
    found: bool,
    interrupt: &AtomicUsize,
    interrupted: bool,
) -> i32 {
    if let Some(d) = defect {
        eprintln!("rigscript verify: {d}");
        return crate::runtime::exit::INTERNAL;
    }
    if found {
        return 1;
    }
    match i32::try_from(interrupt.load(Ordering::Relaxed)) {
        Ok(signal) if signal > 0 && interrupted => crate::runtime::exit::signal(signal),
        _ => 0,
    }
}
