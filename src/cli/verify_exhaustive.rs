//! `rigscript verify SCRIPT --exhaustive [--depth K]`: every sequence of up to K choices,
//! breadth first, equal states explored once; prints "no violation in any sequence of up to K
//! events (N states)" with what the abstraction leaves out, or the shortest counterexample,
//! written as a scenario test that `rigscript test` fails with. Exit status as `verify`'s.

use super::verify::{say, watch_signals, VerifyArgs};
use crate::config::RigConfig;
use crate::time::duration::format_duration;
use crate::verify::exec::Target;
use crate::verify::exhaustive::{explore, Options, DEFAULT_DEPTH};
use crate::verify::facts::Facts;
use crate::verify::horizon::Horizon;
use crate::verify::{proof_report, reproduce};
use std::io::IsTerminal;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

/// The command that repeats this exploration, for the test file's header.
fn command(args: &VerifyArgs, depth: usize) -> String {
    let mut c = format!(
        "rigscript verify {} --exhaustive --depth {depth}",
        args.script.display()
    );
    if let Some(p) = &args.config {
        c.push_str(&format!(" --config {}", p.display()));
    }
    if args.no_faults {
        c.push_str(" --no-faults");
    }
    c
}

/// Runs the exhaustive mode on a script that `check` found fit to run; the exit status.
pub fn run(args: &VerifyArgs, config: RigConfig, source: String) -> i32 {
    let file = args.script.display().to_string();
    let depth = args
        .depth
        .and_then(|d| usize::try_from(d).ok())
        .unwrap_or(DEFAULT_DEPTH);
    let jobs = args.jobs.map_or_else(
        || std::thread::available_parallelism().map_or(1, usize::from),
        |j| usize::try_from(j).unwrap_or(1),
    );
    let interrupt = Arc::new(AtomicUsize::new(0));
    if let Err(e) = watch_signals(&interrupt) {
        eprintln!("rigscript verify: cannot watch for Ctrl-C: {e}");
    }
    let facts = Facts::read(&source);
    let target = Target {
        source,
        file: file.clone(),
        script: args.script.clone(),
        config_file: args.config.clone(),
        budget: args.budget.unwrap_or(config.limits.operations),
        config,
        run_for: Horizon::of(&facts, None).run_for,
        compared: facts.compared,
    };
    let opts = Options {
        depth,
        jobs,
        faults: !args.no_faults,
        interrupt: Some(Arc::clone(&interrupt)),
    };
    if !args.json {
        say(&format!(
            "verify {file}: exhaustive to depth {depth} at {} per tick, faults {}, {jobs} \
             job(s); no seed (the same result every time)",
            format_duration(target.config.period),
            if args.no_faults { "off" } else { "on" }
        ));
    }
    let show_progress = !args.json && std::io::stderr().is_terminal();
    let summary = match explore(&target, &opts, |d, states| {
        if show_progress {
            eprint!("\rdepth {d} done: {states} states");
        }
    }) {
        Ok(s) => s,
        Err(e) => {
            if show_progress {
                eprintln!();
            }
            eprintln!("rigscript verify: {file} cannot run on the simulated rig: {e}");
            return 2;
        }
    };
    if show_progress {
        eprintln!();
    }
    let (mut test, mut defect) = (None, None);
    if let Some(f) = &summary.found {
        match proof_report::write_test(&args.out, &target, &summary, f, &command(args, depth)) {
            Ok(p) => match reproduce::check_file(&p, &f.finding.check) {
                Ok(()) => test = Some(p),
                Err(why) => {
                    defect = Some(format!(
                        "defect of verify, not of the script: the test written to {} does not \
                         reproduce the counterexample ({why})",
                        p.display()
                    ));
                }
            },
            Err(e) => eprintln!(
                "rigscript verify: cannot write the counterexample's test under {}: {e}",
                args.out.display()
            ),
        }
    }
    if args.json {
        let doc = proof_report::to_json(&summary, opts.faults, test.as_deref(), defect.as_deref());
        say(&doc.to_string());
    } else {
        for line in proof_report::human(&summary, test.as_deref()) {
            say(&line);
        }
    }
    if let Some(d) = &defect {
        eprintln!("rigscript verify: {d}");
        return crate::runtime::exit::INTERNAL;
    }
    if summary.found.is_some() {
        return 1;
    }
    match i32::try_from(interrupt.load(Ordering::Relaxed)) {
        Ok(signal) if signal > 0 && summary.interrupted => crate::runtime::exit::signal(signal),
        _ => 0,
    }
}
