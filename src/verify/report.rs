//! What `verify` tells people: the counterexample as one readable line and as a scenario test
//! written to a file, or, after a pass, what was exercised and the warnings; or all of it as
//! one JSON document.

use super::exec::Target;
use super::horizon::Horizon;
use super::plan::{time_text, trace};
use super::reproduce::{failure_text, render, NotReproduced};
use super::testfile::absolute;
use super::{Counterexample, Options, Summary};
use crate::time::duration::format_duration;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};

/// The one-line story of a counterexample: its events, then what failed.
pub fn story(c: &Counterexample) -> String {
    let events = trace(&c.events);
    let failed = format!(
        "{} false at {}: {}",
        c.finding.check,
        time_text(c.finding.at),
        c.finding.detail
    );
    if events.is_empty() {
        failed
    } else {
        format!("{events} → {failed}")
    }
}

/// Where the counterexample's test goes: `DIR/<script>-<check>-seed<S>-run<N>.test.rhai`.
pub fn test_path(out: &Path, script: &Path, seed: u64, c: &Counterexample) -> PathBuf {
    let stem = script
        .file_stem()
        .map_or_else(|| "script".into(), |s| s.to_string_lossy().into_owned());
    out.join(format!(
        "{stem}-{}-seed{seed}-run{}.test.rhai",
        c.finding.check.slug(),
        c.run + 1
    ))
}

/// Writes the counterexample's scenario test under `out` (created if missing); its path.
pub fn write_test(
    out: &Path,
    target: &Target,
    summary: &Summary,
    c: &Counterexample,
    command: &str,
) -> std::io::Result<PathBuf> {
    std::fs::create_dir_all(out)?;
    let path = test_path(out, &target.script, summary.seed, c);
    let dir = absolute(out);
    let header = vec![
        format!(
            "Found by `{command}` (seed {}, run {} of {}): {} event(s), shrunk from {}.",
            summary.seed,
            c.run + 1,
            summary.runs,
            c.events.len(),
            c.original_events
        ),
        story(c),
        format!("Run it: rigscript test {}", path.display()),
    ];
    let text = render(target, &dir, &c.start, &c.steps, &c.finding, &header);
    std::fs::write(&path, text)?;
    Ok(path)
}

/// What is said when the written test does not fail as the run did: a defect of `verify`,
/// never a reproduction.
pub fn defect(test: &Path, c: &Counterexample, why: &NotReproduced) -> String {
    format!(
        "defect of verify, not of the script: the test written to {} does not reproduce the \
         counterexample ({} expected; {why}); the finding may still be real, but this test \
         cannot show it: please report it with the command in the test's header",
        test.display(),
        failure_text(&c.finding.check)
    )
}

/// The lines for people.
pub fn human(summary: &Summary, opts: &Options, test: Option<&Path>) -> Vec<String> {
    let mut out = Vec::new();
    match &summary.counterexample {
        Some(c) => {
            out.push(format!(
                "counterexample in run {} of seed {} (found after {:.1} s): {}",
                c.run + 1,
                summary.seed,
                summary.search_time.as_secs_f64(),
                c.found.check
            ));
            out.push(format!(
                "shrunk from {} to {} event(s) in {} replays ({:.1} s){}:",
                c.original_events,
                c.events.len(),
                c.replays,
                c.shrink_time.as_secs_f64(),
                if c.interrupted {
                    ", cut short by a signal"
                } else if c.exhausted {
                    ", stopped at the shrinking budget"
                } else {
                    ""
                }
            ));
            out.push(format!("  {}", story(c)));
            if let Some(why) = &c.first_not_reproduced {
                out.push(format!(
                    "warning: {} shrinking candidate(s) failed when played but not as written \
                     tests (a defect of verify; none was kept); the first: {why}",
                    c.not_reproduced
                ));
            }
            if let Some(p) = test {
                out.push(format!("written to {}", p.display()));
                out.push(format!("reproduce: rigscript test {}", p.display()));
            }
        }
        None => {
            if summary.interrupted {
                out.push(format!(
                    "interrupted: {} of up to {} runs played whole before the signal",
                    summary.runs, opts.runs
                ));
            }
            out.push(format!(
                "no counterexample in {} runs of {} ({} ticks, {} events, {} of them faults) \
                 in {:.1} s; seed {}",
                summary.runs,
                format_duration(summary.run_for),
                summary.coverage.ticks,
                summary.events,
                summary.faults,
                summary.search_time.as_secs_f64(),
                summary.seed
            ));
            if summary.systematic > 0 {
                out.push(format!(
                    "the first {} run(s) were the same at every seed: each count the script \
                     compares landed on, one above and stepped over in one scan, each input, \
                     switch and rotary it reads worked each way{}",
                    summary.systematic,
                    if opts.faults {
                        ", each device lost past its grace time and back"
                    } else {
                        ""
                    }
                ));
            }
            if !opts.faults {
                out.push("faults were off (--no-faults)".into());
            }
            out.extend(summary.coverage.lines());
            for w in summary.coverage.warnings() {
                out.push(format!("warning: {w}"));
            }
        }
    }
    out
}

/// The JSON document.
pub fn to_json(
    summary: &Summary,
    opts: &Options,
    horizon: &Horizon,
    test: Option<&Path>,
    defect: Option<&str>,
) -> Value {
    let counterexample = summary.counterexample.as_ref().map(|c| {
        let events: Vec<Value> = c
            .events
            .iter()
            .map(|e| json!({"at_ms": e.at.as_secs_f64() * 1000.0, "event": e.action.to_string()}))
            .collect();
        json!({
            "run": c.run + 1,
            "check": c.finding.check.to_string(),
            "name": c.finding.check.name(),
            "at_ms": c.finding.at.as_secs_f64() * 1000.0,
            "detail": c.finding.detail,
            "events": events,
            "story": story(c),
            "shrunk_from": c.original_events,
            "replays": c.replays,
            "shrink_exhausted": c.exhausted,
            "start": c.start.wall_text(),
            "zone": c.start.zone,
            "test_file": test.map(|p| p.display().to_string()),
            "reproduced": defect.is_none() && test.is_some(),
            "defect": defect,
            "candidates_not_reproduced": c.not_reproduced,
            "shrink_interrupted": c.interrupted,
        })
    });
    let passed = summary.counterexample.is_none();
    json!({
        "seed": summary.seed,
        "runs": summary.runs,
        "run_for_ms": summary.run_for.as_secs_f64() * 1000.0,
        "run_for_stretched_for": horizon.stretched_for,
        "run_for_short_of": horizon.short_of,
        "faults": opts.faults,
        "systematic_runs": summary.systematic,
        "search_s": summary.search_time.as_secs_f64(),
        "result": match (&counterexample, summary.interrupted) {
            (Some(_), _) => "counterexample",
            (None, true) => "interrupted",
            (None, false) => "pass",
        },
        "counterexample": counterexample,
        // Totals and coverage only after a pass: when a run failed, runs after it may or may
        // not have finished, so they would differ between invocations.
        "events": if passed { json!(summary.events) } else { Value::Null },
        "fault_events": if passed { json!(summary.faults) } else { Value::Null },
        "coverage": if passed { summary.coverage.to_json() } else { Value::Null },
    })
}
