//! `rigscript verify SCRIPT --exhaustive [--depth K]`: every sequence of up to K choices,
//! breadth first, equal states explored once; prints "no violation in any sequence of up to K
//! events (N states)" with what the abstraction leaves out, or the shortest counterexample,
//! written as a scenario test that `rigscript test` fails with. Exit status as `verify`'s.

use super::verify::{
    exit_status, interrupt_flag, jobs, say, target, with_progress, written_and_reproduced,
    VerifyArgs,
};
use crate::config::RigConfig;
use crate::time::duration::format_duration;
use crate::verify::exhaustive::{explore, Options, DEFAULT_DEPTH};
use crate::verify::facts::Facts;
use crate::verify::horizon::Horizon;
use crate::verify::proof_report;
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
    let jobs = jobs(args);
    let interrupt = interrupt_flag();
    let facts = Facts::read(&source);
    let run_for = Horizon::of(&facts, None).run_for;
    let target = target(args, config, source, facts, run_for);
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
    let explored = with_progress(args, &file, |show| {
        explore(&target, &opts, |d, states| {
            show(format!("depth {d} done: {states} states"));
        })
    });
    let Ok(summary) = explored else {
        return 2;
    };
    let (test, defect) = match &summary.found {
        Some(f) => written_and_reproduced(
            args,
            || proof_report::write_test(&args.out, &target, &summary, f, &command(args, depth)),
            &f.finding.check,
            |p, why| {
                format!(
                    "defect of verify, not of the script: the test written to {} does not \
                     reproduce the counterexample ({why})",
                    p.display()
                )
            },
        ),
        None => (None, None),
    };
    if args.json {
        let doc = proof_report::to_json(&summary, opts.faults, test.as_deref(), defect.as_deref());
        say(&doc.to_string());
    } else {
        for line in proof_report::human(&summary, test.as_deref()) {
            say(&line);
        }
    }
    exit_status(
        defect.as_deref(),
        summary.found.is_some(),
        &interrupt,
        summary.interrupted,
    )
}
