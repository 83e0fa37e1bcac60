//! The scan loop. Each tick: (0) supervise devices (retry lost ones, hold outputs safe past
//! the grace time); (1) read the inputs the handlers wait for, lazily, once per device per
//! tick; (2) turn edges and due timers into handler calls; (3) run the handlers, then what
//! waits from outside (at most one command and a few watched messages, `remote`); (4) write
//! the outputs that changed, one transaction per device; (5) feed the host watchdogs (at a
//! quarter of their timeout) and, every few seconds, check the modules still drive what was
//! written; (6) sleep to the next deadline. Overruns are counted and the schedule skips to
//! the next period boundary, keeping its phase.
//!
//! All timing comes from the `Clock`; scenario tests drive the same loop in virtual time.

mod contract;
mod end;
mod force;
mod reload;
mod remote;
mod restart;
mod serve;
#[cfg(test)]
mod tests;
mod tick;
mod wait;

pub use contract::{EndReason, HandlerFault, Program, RunOptions, Shared, StopLimit};
pub use end::{panic_message, safe_after_panic, Trouble};

use crate::device::cancel::Cancel;
use crate::runtime::error_log::ErrorLog;
use crate::runtime::exit;
use crate::runtime::invariants::Violation;
use crate::runtime::observe::{Events, RunEvent};
use crate::runtime::safety::DeviceEnd;
use crate::runtime::stats::Stats;
use crate::runtime::wake_latency;
use crate::time::clock::SharedClock;
use contract::describe;
use signal_hook::consts::SIGTERM;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

#[derive(Debug, Clone, PartialEq, Eq)]
enum State {
    Running,
    Restarting { at: Duration },
    Stopped { status: i32 },
}

/// One run of a script over its devices.
pub struct Runner<P: Program> {
    rt: Shared<P::Handler>,
    program: P,
    clock: SharedClock,
    options: RunOptions,
    state: State,
    next_deadline: Duration,
    last_check: Duration,
    failures_in_a_row: u32,
    last_start: Duration,
    /// What went wrong on the way.
    pub trouble: Trouble,
    latency: wait::LatencyRequest,
    /// What the loop measured (`stats`, and the snapshot's figures).
    stats: Stats,
    /// The script errors so far.
    pub errors: ErrorLog,
    violation: Option<Violation>,
    /// How the end left each device (empty until the run has ended).
    end_report: Vec<DeviceEnd>,
    /// Where the loop tells what happens.
    events: Events,
    /// What is asked of the loop from outside, once `serve` attached it.
    served: Option<serve::Served>,
    /// Times the script was started again.
    restarts: u64,
    /// Which script runs, and its reloads.
    identity: reload::ScriptIdentity,
    /// `--rollback`: how long a reload may still be undone.
    rollback: Option<Duration>,
    /// The way back from the last reload, within its rollback window.
    undo: Option<reload::Undo<P::Handler>>,
    /// Reloads a replay asks for at the next tick (`reload_at_next_tick`): text and file.
    replayed_reloads: Vec<(String, String)>,
    /// The next tick was brought sooner than the script's schedule for someone outside, this
    /// many periods after the last tick's boundary: told as it starts (`RunEvent::Woken`).
    woken: Option<u64>,
    /// When each invariant was last found false (the run's uptime), by name.
    invariants_failed: std::collections::BTreeMap<String, Duration>,
    /// The invariants false on the outputs written now, each allowed by a force held.
    overridden: Vec<String>,
}

impl<P: Program> Runner<P> {
    /// A runner for `program` over `rt`; the first tick is due at once. From now on the stop
    /// flag cuts the devices' exchanges short.
    pub fn new(rt: Shared<P::Handler>, program: P, options: RunOptions) -> Self {
        rt.borrow_mut()
            .set_cancel(&Cancel::when_set(Arc::clone(&options.stop_flag)));
        let clock = Arc::clone(rt.borrow().cycle().clock());
        let events = rt.borrow().events().clone();
        let now = clock.now();
        Self {
            rt,
            program,
            clock,
            options,
            state: State::Running,
            next_deadline: now,
            last_check: now,
            failures_in_a_row: 0,
            last_start: now,
            trouble: Trouble::default(),
            latency: wait::LatencyRequest::default(),
            stats: Stats::default(),
            errors: ErrorLog::default(),
            violation: None,
            end_report: Vec::new(),
            events,
            served: None,
            restarts: 0,
            identity: reload::ScriptIdentity::default(),
            rollback: None,
            undo: None,
            replayed_reloads: Vec::new(),
            woken: None,
            invariants_failed: std::collections::BTreeMap::new(),
            overridden: Vec::new(),
        }
    }

    /// The runtime.
    pub fn runtime(&self) -> &Shared<P::Handler> {
        &self.rt
    }

    /// The program.
    pub fn program(&self) -> &P {
        &self.program
    }

    /// The exit status once the run has ended.
    pub fn status(&self) -> Option<i32> {
        match self.state {
            State::Stopped { status } => Some(status),
            _ => None,
        }
    }

    /// How the end left each device: its safe state confirmed or not, and why (empty until
    /// the run has ended). Whoever finishes the job reads it.
    pub fn end_report(&self) -> &[DeviceEnd] {
        &self.end_report
    }

    /// The invariant found false, if one was (the run then ended).
    pub fn violation(&self) -> Option<&Violation> {
        self.violation.as_ref()
    }

    /// When the next tick is due.
    pub fn next_deadline(&self) -> Duration {
        self.next_deadline
    }

    /// Runs the script's top level; on failure the run ends with status 1 whatever the
    /// policy (a script that cannot start is not restarted). The first tick is due as it
    /// ends: the ticks' phase starts there, after the timers the top level made (each due a
    /// little before a boundary, not a little after one: which tick fires it does not hang on
    /// how long the top level's exchanges took, or on how late a tick woke), and the top
    /// level's time is not counted as the first tick's lateness.
    pub fn start(&mut self) {
        self.guarded(Self::start_program);
        self.next_deadline = self.next_deadline.max(self.clock.now());
    }

    fn start_program(&mut self) {
        self.rt.borrow_mut().set_cause("top level");
        self.last_start = self.clock.now();
        match self.program.start() {
            Ok(()) => self.tell_started(),
            Err(f) => {
                let message = describe(&f, "top level");
                self.note_fault(&message, f.over_budget);
                self.finish(EndReason::Error(message));
            }
        }
    }

    /// Tells the events the script's top level ran.
    fn tell_started(&self) {
        let restarts = self.restarts;
        self.events.publish(|| RunEvent::ScriptStarted {
            script: self
                .served
                .as_ref()
                .map_or_else(String::new, |s| s.script.clone()),
            restarts,
            since: {
                let rt = self.rt.borrow();
                let cycle = rt.cycle();
                let up = chrono::TimeDelta::from_std(cycle.uptime()).unwrap_or_default();
                cycle.wall() - up
            },
        });
    }

    /// Counts a script error and tells the events of it.
    fn note_fault(&mut self, message: &str, over_budget: bool) {
        self.errors.push(message, over_budget);
        self.events.publish(|| RunEvent::ScriptFailed {
            message: message.to_string(),
        });
    }

    /// Runs until the run ends, sleeping between ticks; returns the exit status. Kept out of
    /// line: benches/tick_instructions.sh finds the loop's thread by this function's symbol.
    #[inline(never)]
    pub fn run(&mut self) -> i32 {
        self.note_prompt_wakeups(crate::time::clock::prefer_prompt_wakeups());
        self.stats.wake_latency = Some(wake_latency::describe(&None));
        loop {
            if let Some(status) = self.status() {
                self.latency.hold = None;
                return status;
            }
            self.update_wake_latency();
            self.sleep_to_deadline();
            self.tick();
        }
    }

    /// Runs ticks until the clock has advanced by `by` (virtual time).
    pub fn advance(&mut self, by: Duration) {
        let target = self.clock.now().saturating_add(by);
        while self.step_toward(target).is_some() {}
    }

    /// Whether a tick is due at or before `target` (the run still going).
    pub fn tick_due_by(&self, target: Duration) -> bool {
        self.status().is_none() && self.next_deadline <= target
    }

    /// The one step of the loop in virtual time, which `advance`, scenario tests and `verify`
    /// drive (each looks at the run between steps): runs the next tick due at or before
    /// `target` and returns when it was due; when none is (or the run has ended), lets time
    /// reach `target` between ticks and returns `None`.
    pub fn step_toward(&mut self, target: Duration) -> Option<Duration> {
        if !self.tick_due_by(target) {
            self.wait_between_ticks(target);
            return None;
        }
        let due = self.next_deadline;
        self.wait_until(due, false);
        self.tick();
        Some(due)
    }

    /// Lets virtual time reach `target` without a tick, doing what falls due between ticks
    /// on the way (feeds, retries, a grace time's end, the end of `--for`), as `advance`
    /// does after its last tick.
    pub fn wait_between_ticks(&mut self, target: Duration) {
        self.wait_until(target, false);
        self.clock.sleep_until(target);
    }

    /// Waits for the next deadline and runs one tick.
    pub fn step(&mut self) {
        if self.status().is_none() {
            self.step_toward(self.next_deadline);
        }
    }

    /// Stops at once as SIGTERM would (outputs safe, on_stop handlers run).
    pub fn signal_stop(&mut self) {
        self.options
            .stop_flag
            .store(SIGTERM as usize, Ordering::SeqCst);
        self.guarded(|r| r.finish(EndReason::Signal(SIGTERM)));
    }

    /// Runs `step` of the run; a panic in it (a bug) still ends the run safe
    /// (`safe_after_panic`), with exit status 70. Borrows of the runtime held when it
    /// panicked are released by the unwinding.
    fn guarded(&mut self, step: impl FnOnce(&mut Self)) {
        if let Err(payload) = catch_unwind(AssertUnwindSafe(|| step(&mut *self))) {
            self.state = State::Stopped {
                status: exit::INTERNAL,
            };
            safe_after_panic(&self.rt, &panic_message(payload.as_ref()));
        }
    }

    /// Ends the run if a signal asked it to stop; true if it did.
    fn ended_by_signal(&mut self) -> bool {
        let Some(signal) = self.stop_signal() else {
            return false;
        };
        let asked = self.served.as_ref().and_then(|s| s.requests.stopped_by());
        match asked {
            Some(by) if signal == SIGTERM => self.finish(EndReason::Requested(by)),
            _ => self.finish(EndReason::Signal(signal)),
        }
        true
    }

    /// The signal that asked the run to stop, if one did.
    fn stop_signal(&self) -> Option<i32> {
        match self.options.stop_flag.load(Ordering::SeqCst) {
            0 => None,
            n => Some(i32::try_from(n).unwrap_or(SIGTERM)),
        }
    }
}
