//! `rigscript verify`: looks hard for a sequence of events that makes a script break one of its
//! invariants or a built-in check, before the script is trusted with a rig.
//!
//! Each run starts the script on the simulated rig in virtual time and plays a field at it:
//! first the runs every seed plays (`systematic`), then random but plausible ones (`field`),
//! with faults (`faults`), watching every tick (`checks`).
//! Runs go in batches; after each batch the field leans further toward what the script was
//! seen to read (`profile`). Runs are spread over worker threads, each with its own runtime,
//! simulators and Rhai engine; run `i` always plays the plan made from the seed and `i`, and
//! the counterexample reported is the one of the lowest run that failed, so the same seed
//! gives the same result whatever the number of threads. It is shrunk (`shrink`) and written
//! as a scenario test (`testfile`); a pass reports what was exercised (`coverage`).

pub mod checks;
pub mod coverage;
pub mod exec;
pub mod exhaustive;
pub mod facts;
pub mod faults;
pub mod field;
pub mod horizon;
pub mod plan;
pub mod profile;
pub mod proof_report;
pub mod report;
pub mod reproduce;
pub mod shrink;
pub mod systematic;
pub mod testfile;

use checks::Finding;
use coverage::Coverage;
use exec::{execute, ExecError, Keep, Outcome, Step, Target};
use plan::{Event, Plan, StartPoint};
use profile::{Observed, Profile};
use shrink::{shrink, Budget, Candidate, Replay};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// How a search is run.
#[derive(Debug, Clone)]
pub struct Options {
    /// Runs at most.
    pub runs: u64,
    /// The seed every run's plan comes from.
    pub seed: u64,
    /// Worker threads.
    pub jobs: usize,
    /// Play faults as well as the field.
    pub faults: bool,
    /// What shrinking may cost.
    pub shrink: Budget,
    /// Set (to a signal's number) to stop early: no run is begun after it, and shrinking stops
    /// at the next candidate; the summary says how far the search got.
    pub interrupt: Option<Arc<AtomicUsize>>,
}

impl Options {
    /// Whether the search was asked to stop.
    pub fn interrupted(&self) -> bool {
        self.interrupt
            .as_ref()
            .is_some_and(|i| i.load(Ordering::Relaxed) != 0)
    }
}

/// The budget shrinking gets unless told otherwise.
pub const SHRINK_BUDGET: Budget = Budget {
    replays: 3000,
    time: Duration::from_secs(120),
};

/// A failing run, shrunk.
#[derive(Debug, Clone)]
pub struct Counterexample {
    /// The run (0-based) that failed first.
    pub run: u64,
    /// What it found, before shrinking.
    pub found: Finding,
    /// Events it played up to then.
    pub original_events: usize,
    /// What the shrunk run finds.
    pub finding: Finding,
    /// Where the shrunk run starts.
    pub start: StartPoint,
    /// Its events.
    pub events: Vec<Event>,
    /// Its steps, for the test file.
    pub steps: Vec<Step>,
    /// Replays shrinking took.
    pub replays: usize,
    /// Shrinking stopped at its budget.
    pub exhausted: bool,
    /// Wall time shrinking took.
    pub shrink_time: Duration,
    /// Candidates that failed in replay but whose written test did not (each a defect of
    /// `verify`; none is kept).
    pub not_reproduced: usize,
    /// How the first of them failed to.
    pub first_not_reproduced: Option<reproduce::NotReproduced>,
    /// Shrinking was cut short by `Options::interrupt`.
    pub interrupted: bool,
}

/// What a search came to.
#[derive(Debug, Clone)]
pub struct Summary {
    /// The seed.
    pub seed: u64,
    /// Runs played (up to and including the failing one, when one failed).
    pub runs: u64,
    /// Virtual time each run lasts.
    pub run_for: Duration,
    /// Events played in all.
    pub events: u64,
    /// Faults among them.
    pub faults: u64,
    /// Wall time of the search (before shrinking).
    pub search_time: Duration,
    /// The counterexample, if a run failed.
    pub counterexample: Option<Counterexample>,
    /// What the runs exercised.
    pub coverage: Coverage,
    /// The search stopped early (`Options::interrupt`); `runs` counts the runs played whole.
    pub interrupted: bool,
    /// How many of the first runs were the systematic ones (`systematic::plans`).
    pub systematic: u64,
}

/// Why a search could not be made.
#[derive(Debug, thiserror::Error)]
pub enum VerifyError {
    /// A run could not be played on the simulated rig.
    #[error("run {run}: {source}")]
    Run {
        /// Which.
        run: u64,
        /// Why.
        #[source]
        source: ExecError,
    },
}

/// The seed of run `i`: the search's seed and the run number mixed (splitmix64).
pub fn run_seed(seed: u64, run: u64) -> u64 {
    let mix = |mut z: u64| {
        z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    };
    mix(seed ^ mix(run))
}

/// Where batch boundaries fall: the field is re-weighted after 4, 16 and 64 runs, then
/// every 256.
fn batch_end(start: u64, runs: u64) -> u64 {
    let end = match start {
        0..=3 => 4,
        4..=15 => 16,
        16..=63 => 64,
        s => s + 256,
    };
    end.min(runs)
}

impl Replay for Outcome {
    fn at(&self) -> Duration {
        self.finding.as_ref().map_or(Duration::ZERO, |f| f.at)
    }
    fn played(&self) -> usize {
        self.played
    }
}

/// What the runs of a batch brought back.
#[derive(Default)]
struct Batch {
    /// Runs played whole.
    done: u64,
    coverage: Coverage,
    observed: Observed,
    events: u64,
    faults: u64,
    failures: Vec<(u64, Plan, Outcome, Finding)>,
    error: Option<(u64, ExecError)>,
}

fn play_batch(
    target: &Target,
    (profile, first): (&Profile, &[Plan]),
    opts: &Options,
    range: std::ops::Range<u64>,
) -> Batch {
    let next = AtomicU64::new(range.start);
    let lowest_failure = AtomicU64::new(u64::MAX);
    let result = Mutex::new(Batch::default());
    let work = || {
        let mut mine = Batch::default();
        loop {
            let i = next.fetch_add(1, Ordering::SeqCst);
            if i >= range.end || i > lowest_failure.load(Ordering::SeqCst) || opts.interrupted() {
                break;
            }
            let plan = usize::try_from(i)
                .ok()
                .and_then(|i| first.get(i).cloned())
                .unwrap_or_else(|| field::generate(profile, run_seed(opts.seed, i), opts.faults));
            let keep = Keep {
                coverage: true,
                observe: true,
            };
            match execute(target, &plan, keep) {
                Ok(outcome) => {
                    mine.done += 1;
                    let played = plan.events.get(..outcome.played).unwrap_or(&[]);
                    mine.events += played.len() as u64;
                    mine.faults += played.iter().filter(|e| e.action.is_fault()).count() as u64;
                    mine.observed.merge(&outcome.observed);
                    if let Some(c) = &outcome.coverage {
                        mine.coverage.merge(c);
                    }
                    if let Some(f) = outcome.finding.clone() {
                        lowest_failure.fetch_min(i, Ordering::SeqCst);
                        mine.failures.push((i, plan, outcome, f));
                    }
                }
                Err(e) => {
                    lowest_failure.fetch_min(i, Ordering::SeqCst);
                    mine.error = Some((i, e));
                }
            }
        }
        let mut all = crate::sync::lock(&result);
        all.coverage.merge(&mine.coverage);
        all.observed.merge(&mine.observed);
        all.done += mine.done;
        all.events += mine.events;
        all.faults += mine.faults;
        all.failures.append(&mut mine.failures);
        if let Some((i, e)) = mine.error {
            if all.error.as_ref().map_or(true, |(j, _)| i < *j) {
                all.error = Some((i, e));
            }
        }
    };
    // Each worker on a stack that holds whatever a script can build within its memory limit;
    // where the system refuses one, this thread does the work.
    let stack = crate::script::stack::size_for(target.config.limits.memory);
    std::thread::scope(|s| {
        for _ in 0..opts.jobs.max(1) {
            let worker = std::thread::Builder::new().stack_size(stack);
            let watched = || crate::guardian::lone::watched("rigscript verify", work);
            if worker.spawn_scoped(s, watched).is_err() {
                work();
            }
        }
    });
    result.into_inner().unwrap_or_else(|e| e.into_inner())
}

/// Replays `plan` until `horizon`; the outcome if it fails `check` again and so does the test it
/// would be written as (one that does not is noted in `not_reproduced`).
fn replay(
    target: &Target,
    c: &Candidate,
    check: &checks::Property,
    not_reproduced: &mut Vec<reproduce::NotReproduced>,
) -> Option<Outcome> {
    let t = Target {
        run_for: c.horizon,
        ..target.clone()
    };
    let keep = Keep {
        coverage: false,
        observe: false,
    };
    let outcome = execute(&t, &c.plan, keep).ok()?;
    let finding = outcome.finding.as_ref().filter(|f| f.check == *check)?;
    // A candidate counts only if its written test fails so too.
    if let Err(e) = reproduce::check_steps(target, &c.plan.start, &outcome.steps, finding) {
        not_reproduced.push(e);
        return None;
    }
    Some(outcome)
}

/// Shrinks the failing run `run`.
fn minimise(
    target: &Target,
    opts: &Options,
    period: Duration,
    run: u64,
    plan: Plan,
    outcome: Outcome,
    found: Finding,
) -> Counterexample {
    let began = Instant::now();
    let original_events = outcome.played;
    let check = found.check.clone();
    let candidate = Candidate {
        plan,
        horizon: target.run_for,
    };
    let mut not_reproduced = Vec::new();
    let s = shrink(
        candidate,
        outcome,
        |c| {
            // Stopped: every candidate fails to help, so shrinking ends within a pass.
            if opts.interrupted() {
                return None;
            }
            replay(target, c, &check, &mut not_reproduced)
        },
        opts.shrink,
        period.saturating_mul(2),
        field::quantum(period),
    );
    Counterexample {
        run,
        found: found.clone(),
        original_events,
        finding: s.replay.finding.clone().unwrap_or(found),
        start: s.candidate.plan.start.clone(),
        events: s.candidate.plan.events.clone(),
        steps: s.replay.steps.clone(),
        replays: s.replays,
        exhausted: s.exhausted,
        shrink_time: began.elapsed(),
        not_reproduced: not_reproduced.len(),
        first_not_reproduced: not_reproduced.into_iter().next(),
        interrupted: opts.interrupted(),
    }
}

/// Searches `target` with `opts`; `progress` hears how many runs are done after each batch.
pub fn search(
    target: &Target,
    opts: &Options,
    mut progress: impl FnMut(u64),
) -> Result<Summary, VerifyError> {
    let began = Instant::now();
    let period = target.config.period;
    let mut profile = Profile::new(&target.config, &target.source, period, target.run_for);
    // What the script reads, learned from a run with no events (its top level, its
    // handlers' waits, its polling), so the systematic runs work what it reads.
    let probe = Plan {
        start: field::Gen::new(&profile, run_seed(opts.seed, 0)).start,
        events: Vec::new(),
    };
    let quiet = Keep {
        coverage: false,
        observe: true,
    };
    if let Ok(seen) = execute(target, &probe, quiet) {
        profile.learn(&seen.observed);
    }
    let first = systematic::plans(&profile, opts.seed, opts.faults);
    let mut summary = Summary {
        seed: opts.seed,
        runs: 0,
        run_for: target.run_for,
        events: 0,
        faults: 0,
        search_time: Duration::ZERO,
        counterexample: None,
        coverage: Coverage::default(),
        interrupted: false,
        systematic: (first.len() as u64).min(opts.runs),
    };
    let mut start = 0;
    while start < opts.runs {
        let end = batch_end(start, opts.runs);
        let mut batch = play_batch(target, (&profile, &first), opts, start..end);
        if let Some((run, source)) = batch.error.take() {
            let first_failure = batch.failures.iter().map(|f| f.0).min();
            if first_failure.map_or(true, |f| run < f) {
                return Err(VerifyError::Run { run, source });
            }
        }
        summary.events += batch.events;
        summary.faults += batch.faults;
        summary.coverage.merge(&batch.coverage);
        profile.learn(&batch.observed);
        batch.failures.sort_by_key(|f| f.0);
        let done = summary.runs + batch.done;
        if let Some((run, plan, outcome, found)) = batch.failures.into_iter().next() {
            summary.runs = run + 1;
            summary.search_time = began.elapsed();
            progress(summary.runs);
            summary.counterexample =
                Some(minimise(target, opts, period, run, plan, outcome, found));
            return Ok(summary);
        }
        if opts.interrupted() {
            summary.runs = done;
            summary.interrupted = true;
            break;
        }
        summary.runs = end;
        progress(end);
        start = end;
    }
    summary.search_time = began.elapsed();
    summary.coverage.compared = profile.facts.compared.clone();
    Ok(summary)
}
