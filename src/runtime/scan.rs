//! The scan loop. Each tick: (0) supervise devices (retry lost ones, hold outputs safe past
//! the grace time); (1) read the inputs the handlers wait for, lazily, once per device per
//! tick; (2) turn edges and due timers into handler calls; (3) run the handlers; (4) write
//! the outputs that changed, one transaction per device; (5) feed the host watchdogs (at a
//! quarter of their timeout) and, every few seconds, check the modules still drive what was
//! written; (6) sleep to the next deadline. Overruns are counted and the schedule skips to
//! the next period boundary, keeping its phase.
//!
//! All timing comes from the `Clock`; scenario tests drive the same loop in virtual time.

use super::error_log::ErrorLog;
use super::exit;
use super::invariants::{Check, Violation};
use super::observe::{Events, RunEvent};
use super::requests::{Answer, Request, Requests};
use super::safety::DeviceEnd;
use super::signals;
use super::snapshot::{
    micros, DeviceState, RigSnapshot, ScriptState, TickFigures, SNAPSHOT_VERSION,
};
use super::state::Runtime;
use super::stats::Stats;
use super::subscriptions::{Call, STOP_BUDGET};
use super::wake_latency;
use crate::config::{ErrorPolicy, WakeLatency};
use crate::device::cancel::Cancel;
use crate::time::clock::SharedClock;
use signal_hook::consts::SIGTERM;
use std::cell::RefCell;
use std::collections::BTreeSet;
use std::io::Write;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::rc::Rc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// How long the loop sleeps at most before it looks at the stop flag again, so that an ending
/// signal is handled promptly whatever the period.
pub const SLEEP_SLICE: Duration = Duration::from_millis(20);

/// How often each device is checked (`Runtime::check_devices`: a module reset, swapped or
/// changed behind the runner's back, or outputs that do not read as written, are set right
/// within this time) and the relays selected again.
pub const CHECK_INTERVAL: Duration = Duration::from_secs(5);

/// The first wait before a script is started again under policy `restart`; it doubles with
/// each failure in a row, up to `MAX_BACKOFF`.
pub const FIRST_BACKOFF: Duration = Duration::from_secs(1);

/// The longest wait before a restart.
pub const MAX_BACKOFF: Duration = Duration::from_secs(60);

/// A script that ran this long without failing starts its back-off afresh.
pub const BACKOFF_RESET: Duration = Duration::from_secs(60);

/// The runtime shared between the scan loop and the script's bindings.
pub type Shared<H> = Rc<RefCell<Runtime<H>>>;

/// Why a handler failed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Fault {
    /// `file:line:column` of the fault, when known.
    pub location: Option<String>,
    /// What went wrong.
    pub cause: String,
    /// The handler ran over a limit that running it again would hit again (operations or
    /// time per call, memory): a runaway, never skipped.
    pub over_budget: bool,
}

/// What bounds an `on_stop` call besides the script's limits per call.
#[derive(Debug, Clone)]
pub struct StopLimit {
    /// When the budget of all the stop's `on_stop` handlers runs out, on the run's clock.
    pub until: Duration,
    /// That budget (`subscriptions::STOP_BUDGET`), for the message.
    pub budget: Duration,
    /// The run's stop flag, cleared as the stop began: set again by another signal.
    pub signal: Arc<AtomicUsize>,
}

/// The script, as the scan loop sees it.
pub trait Program {
    /// The script's handler type.
    type Handler: Clone;
    /// Runs the script's top level from scratch (it adds handlers and timers).
    fn start(&mut self) -> Result<(), Fault>;
    /// Runs one handler.
    fn call(&mut self, call: &Call<Self::Handler>) -> Result<(), Fault>;
    /// Evaluates an invariant: whether it holds.
    fn holds(&mut self, check: &Check<Self::Handler>) -> Result<bool, Fault>;
    /// Runs an `on_stop` handler, stopped also once `limit` runs out or another signal
    /// comes; a program without a way to stop a call midway just runs it.
    fn call_in_stop(&mut self, call: &Call<Self::Handler>, limit: StopLimit) -> Result<(), Fault> {
        let _ = limit;
        self.call(call)
    }
}

/// How a run is driven.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Scan period.
    pub period: Duration,
    /// What a handler error does.
    pub policy: ErrorPolicy,
    /// End the run normally after this long (`--for`).
    pub end_after: Option<Duration>,
    /// The number of the signal that asks the run to stop (`signals::ENDING`; 0: none), set by
    /// the signal handler or a scenario test: stop at once, outputs safe. It also cuts the
    /// exchange under way short (`device::cancel`), within a `CANCEL_SLICE`.
    pub stop_flag: Arc<AtomicUsize>,
    /// What `run` asks of the CPUs' idle states while it runs in real time (`auto`: a 0 µs
    /// request while the loop ticks every 20 ms or faster, re-evaluated as handlers come
    /// and go).
    pub wake_latency: WakeLatency,
}

/// Why a run ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum EndReason {
    /// `--for` elapsed, or the script has nothing left to wait for.
    Finished(String),
    /// The script called `stop(code)`.
    Stopped(i64),
    /// An ending signal (`runtime::signals::ENDING`: the signal's number).
    Signal(i32),
    /// A script or runtime error (policy `stop`, or at the first start).
    Error(String),
    /// An invariant was found false (`runtime::invariants`).
    Violated(String),
    /// Someone asked for a stop through the control queue (`runtime::requests`): who.
    Requested(String),
}

impl std::fmt::Display for EndReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            EndReason::Finished(why) => write!(f, "{why}"),
            EndReason::Stopped(code) => write!(f, "the script called stop({code})"),
            EndReason::Signal(n) => write!(f, "{} received", signals::name(*n)),
            EndReason::Error(m) => write!(f, "script error: {m}"),
            EndReason::Violated(m) => write!(f, "{m}"),
            EndReason::Requested(by) => write!(f, "stop asked by {by}"),
        }
    }
}

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
    latency: LatencyRequest,
    /// What the loop measured.
    pub stats: Stats,
    /// The script errors so far.
    pub errors: ErrorLog,
    violation: Option<Violation>,
    /// How the end left each device (empty until the run has ended).
    end_report: Vec<DeviceEnd>,
    /// systemd's service watchdog, told at every turn of `run` that the loop still turns.
    pub service: Option<crate::service::notify::Notifier>,
    /// Where the loop tells what happens.
    events: Events,
    /// What is asked of the loop from outside, once `serve` attached it.
    served: Option<Served>,
    /// Times the script was started again.
    restarts: u64,
}

/// A run served to askers from outside the loop (`Runner::serve`).
struct Served {
    requests: Requests,
    /// The script's file, for the snapshot.
    script: String,
    /// The devices that are simulators.
    simulated: BTreeSet<String>,
    /// The snapshot last made, with the tick and the exchange count it was made at.
    made: Option<((u64, u64), Arc<RigSnapshot>)>,
}

impl<P: Program> Runner<P> {
    /// A runner for `program` over `rt`; the first tick is due at once. From now on the stop
    /// flag cuts the devices' exchanges short.
    pub fn new(rt: Shared<P::Handler>, program: P, options: RunOptions) -> Self {
        rt.borrow_mut()
            .set_cancel(&Cancel::when_set(Arc::clone(&options.stop_flag)));
        let clock = Arc::clone(&rt.borrow().clock);
        let events = rt.borrow().events.clone();
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
            latency: LatencyRequest::default(),
            stats: Stats::default(),
            errors: ErrorLog::default(),
            violation: None,
            end_report: Vec::new(),
            service: None,
            events,
            served: None,
            restarts: 0,
        }
    }

    /// Answers `requests` from now on, at tick boundaries and in the sleep slices, for the run
    /// of `script` whose `simulated` devices are simulators.
    pub fn serve(&mut self, requests: Requests, script: &str, simulated: BTreeSet<String>) {
        self.served = Some(Served {
            requests,
            script: script.to_string(),
            simulated,
            made: None,
        });
    }

    /// The run's event stream, to attach consumers to.
    pub fn events(&self) -> &Events {
        &self.events
    }

    /// The run as it stands (see `runtime::snapshot`).
    pub fn snapshot(&self) -> RigSnapshot {
        let rt = self.rt.borrow();
        let now = rt.now();
        let (script, simulated) = match &self.served {
            Some(s) => (s.script.clone(), Some(&s.simulated)),
            None => (String::new(), None),
        };
        let state = match self.state {
            State::Running => "running",
            State::Restarting { .. } => "restarting",
            State::Stopped { .. } => "ended",
        };
        RigSnapshot {
            version: SNAPSHOT_VERSION,
            script: ScriptState {
                file: script,
                state: state.into(),
                uptime_ms: u64::try_from(rt.uptime().as_millis()).unwrap_or(u64::MAX),
                errors: self.errors.total(),
                last_error: self.errors.last().map(|e| e.message.clone()),
                restarts: self.restarts,
            },
            devices: rt
                .devices
                .iter()
                .map(|d| {
                    let sim = simulated.is_some_and(|s| s.contains(d.name()));
                    (d.name().to_string(), DeviceState::of(d, sim, now))
                })
                .collect(),
            held_safe: rt.held_safe,
            ticks: TickFigures {
                period_us: micros(self.options.period),
                count: self.stats.ticks,
                overruns: self.stats.overruns,
                jitter_p99_us: micros(self.stats.jitter.quantile(0.99)),
                work_p99_us: micros(self.stats.work.quantile(0.99)),
                transactions: self.stats.transactions,
            },
            dropped: self.events.dropped(),
            log_dropped: rt.log.dropped(),
        }
    }

    /// Answers what waits in the control queue (a snapshot made at most once a tick).
    fn answer_requests(&mut self) {
        let Some(served) = &self.served else {
            return;
        };
        // Between ticks only the devices' upkeep (feeds, retries) changes what is shown, and
        // each of its exchanges counts: a snapshot stands until the next tick or exchange.
        let tick = (self.stats.ticks, self.rt.borrow().transaction_count());
        let mut made = served.made.clone().filter(|(at, _)| *at == tick);
        let mut asked = false;
        // Made lazily, only if a request needs it: the closure cannot borrow `self` whole.
        let snapshot = std::cell::OnceCell::new();
        served.requests.drain(|request| match request {
            Request::Snapshot => {
                asked = true;
                let s = match &made {
                    Some((_, s)) => Arc::clone(s),
                    None => Arc::clone(snapshot.get_or_init(|| Arc::new(self.snapshot()))),
                };
                Answer::Snapshot(s)
            }
        });
        if asked && made.is_none() {
            made = snapshot.into_inner().map(|s| (tick, s));
        }
        if let Some(served) = &mut self.served {
            if made.is_some() {
                served.made = made;
            }
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
    /// policy (a script that cannot start is not restarted).
    pub fn start(&mut self) {
        self.guarded(Self::start_program);
    }

    fn start_program(&mut self) {
        self.rt.borrow_mut().cause = "top level".into();
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
        });
    }

    /// Counts a script error and tells the events of it.
    fn note_fault(&mut self, message: &str, over_budget: bool) {
        self.errors.push(message, over_budget);
        self.events.publish(|| RunEvent::ScriptFailed {
            message: message.to_string(),
        });
    }

    /// Runs until the run ends, sleeping between ticks; returns the exit status.
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

    /// Notes how the request to wake the loop promptly went (`time::clock::prefer_prompt_wakeups`,
    /// asked once a run). Without these hints a tick starts 100-150 µs late as a rule and
    /// milliseconds late when other processes keep the CPUs busy; they are hints only, so a
    /// refusal (an old kernel, a sandbox) is logged once and the run goes on.
    fn note_prompt_wakeups(&mut self, outcome: std::io::Result<()>) {
        let text = match outcome {
            Ok(()) => "granted".to_string(),
            Err(e) => {
                let text = format!("refused ({e})");
                self.rt.borrow_mut().log.notice(&format!(
                    "prompt wake-ups (1 ns timer slack, short scheduler slice) {text}: ticks \
                     may start later under load"
                ));
                text
            }
        };
        self.stats.prompt_wakeups = Some(text);
    }

    /// Holds the CPU wake-up latency the setting asks for while the loop ticks as fast as it
    /// does now, and lets it go when it no longer does (re-evaluated when handlers come or
    /// go); logs each change and notes what was held for `--stats`. A refusal only costs
    /// timing: the run goes on, and it is not asked again.
    fn update_wake_latency(&mut self) {
        let signature = self.rt.borrow().handlers_signature();
        if self.latency.seen == Some(signature) {
            return;
        }
        self.latency.seen = Some(signature);
        let tick = self.rt.borrow().tick_interval(self.options.period);
        let wanted = self.options.wake_latency.limit_for(tick);
        let held = self
            .latency
            .hold
            .as_ref()
            .map(wake_latency::LatencyHold::limit);
        if wanted == held || (wanted.is_some() && self.latency.refused) {
            return;
        }
        let mut rt = self.rt.borrow_mut();
        let Some(limit) = wanted else {
            self.latency.hold = None;
            rt.log.notice(
                "CPU wake-up latency released: no handler needs ticks of 20 ms or less now",
            );
            return;
        };
        self.latency.hold = None;
        let outcome = Some(wake_latency::hold(limit));
        let text = wake_latency::describe(&outcome);
        let every = tick.map_or(String::new(), |t| {
            format!(
                " (ticks every {})",
                crate::time::duration::format_duration(t)
            )
        });
        match outcome {
            Some(Ok(h)) => {
                rt.log.notice(&format!("CPU wake-up latency {text}{every}"));
                self.latency.hold = Some(h);
            }
            _ => {
                self.latency.refused = true;
                rt.log.notice(&format!(
                    "CPU wake-up latency {text}: ticks may start up to milliseconds late; \
                     give this user write access to it (packaging/udev/61-rigscript-wake-latency.rules) or set \
                     wake_latency = \"off\""
                ));
            }
        }
        self.stats.wake_latency = Some(text);
    }

    /// Sleeps to the next deadline in slices, waking early for the stop flag.
    fn sleep_to_deadline(&mut self) {
        self.wait_until(self.next_deadline, true);
    }

    /// Waits until `target`, feeding the host watchdogs as their feeds fall due and trying lost
    /// devices as their retries do (each keeps its own deadline whatever the period); with
    /// `watch_stop`, in slices that look at the stop flag.
    fn wait_until(&mut self, target: Duration, watch_stop: bool) {
        loop {
            let now = self.clock.now();
            if let Some(service) = &self.service {
                service.loop_alive(now);
            }
            if now >= target
                || (watch_stop && self.stop_signal().is_some())
                || self.status().is_some()
            {
                return;
            }
            let (feed, retry, grace, held) = {
                let rt = self.rt.borrow();
                // A retry already overdue waits for the tick (or was skipped while stopping).
                (
                    rt.next_feed(),
                    rt.next_retry().filter(|&due| due > now),
                    rt.grace_ends(),
                    rt.held_safe,
                )
            };
            let end = self.end_at();
            let mut until = target;
            if watch_stop {
                until = until.min(now.saturating_add(SLEEP_SLICE));
            }
            for due in [feed, retry, grace, end].into_iter().flatten() {
                until = until.min(due.max(now));
            }
            match &self.served {
                Some(s) => {
                    let bell = s.requests.bell().clone();
                    self.clock.sleep_until_rung(until, &bell);
                    self.answer_requests();
                }
                None => self.clock.sleep_until(until),
            }
            // A lost device is tried when its time comes, not at the next tick: with a long
            // period its watchdog would go unfed past its timeout.
            let retried = retry.is_some_and(|due| self.clock.now() >= due);
            if retried {
                self.guarded(|r| r.rt.borrow_mut().supervise());
            }
            // The end of a grace time holds the outputs safe at once, not at the next tick
            // (with only a slow timer, that was the next output check, 5 s on).
            if retried || grace.is_some_and(|due| self.clock.now() >= due) {
                self.guarded(|r| r.rt.borrow_mut().hold_safe_between_ticks(held));
            }
            if feed.is_some_and(|due| self.clock.now() >= due) {
                self.guarded(|r| r.rt.borrow_mut().feed_watchdogs());
            }
            // `--for` ends when it is over, not at the next period boundary.
            if end.is_some_and(|due| self.clock.now() >= due) {
                self.guarded(|r| {
                    r.end_if_over();
                });
            }
        }
    }

    /// When `--for` is over, if it was given.
    fn end_at(&self) -> Option<Duration> {
        let end = self.options.end_after?;
        Some(self.rt.borrow().started.saturating_add(end))
    }

    /// Ends the run if `--for` is over; true if it did.
    fn end_if_over(&mut self) -> bool {
        let Some(end) = self.options.end_after else {
            return false;
        };
        if self.status().is_some() || self.rt.borrow().uptime() < end {
            return false;
        }
        self.finish(EndReason::Finished(format!(
            "ran for {}",
            crate::time::duration::format_duration(end)
        )));
        true
    }

    /// Runs ticks until the clock has advanced by `by` (virtual time: scenario tests).
    pub fn advance(&mut self, by: Duration) {
        self.advance_while(by, || true);
    }

    /// As `advance`, asking `go_on` before each tick (a scenario test's wall-time budget);
    /// false when it said no, the clock left where that tick was due.
    pub fn advance_while(&mut self, by: Duration, mut go_on: impl FnMut() -> bool) -> bool {
        let target = self.clock.now().saturating_add(by);
        while self.status().is_none() && self.next_deadline <= target {
            if !go_on() {
                return false;
            }
            self.wait_until(self.next_deadline, false);
            self.tick();
        }
        self.wait_between_ticks(target);
        true
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
            self.wait_until(self.next_deadline, false);
            self.tick();
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

    /// One scan tick at the current time.
    pub fn tick(&mut self) {
        self.guarded(Self::scan_tick);
    }

    fn scan_tick(&mut self) {
        if self.status().is_some() {
            return;
        }
        let start = self.clock.now();
        let transactions_before = self.rt.borrow().transaction_count();
        self.stats.ticks = self.stats.ticks.saturating_add(1);
        self.stats
            .jitter
            .add(start.saturating_sub(self.next_deadline));
        {
            let mut rt = self.rt.borrow_mut();
            rt.tick = rt.tick.saturating_add(1);
            rt.tick_boundary = Some(self.next_deadline.min(start));
        }
        if self.ended_by_signal() {
            return;
        }
        if self.end_if_over() {
            return;
        }
        self.rt.borrow_mut().supervise();
        if self.ended_by_signal() {
            return;
        }
        match self.state {
            State::Restarting { at } if start >= at => self.restart(),
            State::Running => self.run_handlers(),
            _ => {}
        }
        // A signal that came during the handlers ends the run before the tick's writes: the
        // end writes the safe state anyway, and each exchange could be a silent module's.
        if self.status().is_some() || self.ended_by_signal() {
            return;
        }
        if self.state == State::Running && !self.check_invariants() {
            return;
        }
        let stop = self.rt.borrow().stop_request;
        if let Some(code) = stop {
            self.finish(EndReason::Stopped(code));
            return;
        }
        {
            let mut rt = self.rt.borrow_mut();
            rt.flush_outputs();
            rt.feed_watchdogs();
            let now = rt.now();
            if now.saturating_sub(self.last_check) >= CHECK_INTERVAL {
                self.last_check = now;
                rt.check_devices();
                rt.flush_outputs();
            }
        }
        if self.state == State::Running && !self.rt.borrow().has_work() {
            self.finish(EndReason::Finished(
                "the script has no handlers or timers left".into(),
            ));
            return;
        }
        let end = self.clock.now();
        self.stats.work.add(end.saturating_sub(start));
        let spent = self
            .rt
            .borrow()
            .transaction_count()
            .saturating_sub(transactions_before);
        self.stats.transactions = self.stats.transactions.saturating_add(spent);
        self.stats.max_transactions = self.stats.max_transactions.max(spent);
        let deadline = self.next_deadline;
        self.schedule_next(end);
        if self.events.watched() {
            let tick = self.stats.ticks;
            let overrun = end > deadline.saturating_add(self.options.period);
            self.events.publish(|| RunEvent::Tick {
                tick,
                late_us: micros(start.saturating_sub(deadline)),
                work_us: micros(end.saturating_sub(start)),
                overrun,
            });
        }
        self.answer_requests();
    }

    /// Moves the deadline one period on; past it already, counts an overrun and skips to the
    /// first period boundary after `now`. When no handler polls inputs, ticks that would have
    /// nothing to do are skipped too: the next deadline is the first period boundary at or
    /// after the next timer, watchdog feed, device check, retry, pending write or end (idle
    /// runs cost no CPU, and a day of a cron script in virtual time takes a moment).
    fn schedule_next(&mut self, now: Duration) {
        let period = self.options.period.max(Duration::from_micros(1));
        self.next_deadline = self.next_deadline.saturating_add(period);
        if now > self.next_deadline {
            self.stats.overruns = self.stats.overruns.saturating_add(1);
            // Already late: the next tick starts at once, on the last boundary passed.
            self.next_deadline =
                boundary_at_or_after(self.next_deadline, period, now).saturating_sub(period);
        }
        if let Some(idle) = self.idle_until() {
            if idle > self.next_deadline {
                self.next_deadline = boundary_at_or_after(self.next_deadline, period, idle);
            }
        }
    }

    /// When the next tick has work, if no handler polls inputs (see `schedule_next`).
    fn idle_until(&self) -> Option<Duration> {
        let mut next = self.rt.borrow().idle_until()?;
        next = next.min(self.last_check.saturating_add(CHECK_INTERVAL));
        if let State::Restarting { at } = self.state {
            next = next.min(at);
        }
        if let Some(end) = self.options.end_after {
            next = next.min(self.rt.borrow().started.saturating_add(end));
        }
        Some(next)
    }

    /// Runs the tick's handlers one by one; a signal that comes meanwhile ends the run before
    /// the next one (a tick with thousands of timers due must not delay SIGTERM).
    fn run_handlers(&mut self) {
        let calls = self.rt.borrow_mut().collect_calls();
        for call in calls {
            {
                let mut rt = self.rt.borrow_mut();
                // A handler's own work is not an exchange; feed what fell due meanwhile.
                rt.feed_watchdogs();
                rt.cause.clone_from(&call.label);
            }
            let result = self.program.call(&call);
            if let Err(f) = result {
                if self.stop_signal().is_some() {
                    // The signal came while the handler ran, and the run ends by it; the
                    // error is told (often of the same cause: an exchange the stop cut, a
                    // write past the file size limit as SIGXFSZ came).
                    let message = describe(&f, &call.label);
                    self.note_fault(&message, f.over_budget);
                    self.rt.borrow_mut().log.error(&message);
                    return;
                }
                if !self.handle_fault(&f, &call.label) {
                    return;
                }
            }
            if self.rt.borrow().stop_request.is_some() || self.stop_signal().is_some() {
                return;
            }
        }
    }

    /// Checks every invariant after the handlers, before the outputs are written; false if
    /// the run ended: an invariant found false (the safe state is written instead of this
    /// tick's outputs, status 1 whatever the policy), or one that could not be evaluated (a
    /// script error that is never skipped or restarted: it could not vouch for the outputs).
    fn check_invariants(&mut self) -> bool {
        let checks = self.rt.borrow().invariant_checks();
        let accesses = self.rt.borrow().input_accesses;
        for check in checks {
            self.rt.borrow_mut().cause.clone_from(&check.call.label);
            match self.program.holds(&check) {
                Ok(true) => {}
                Ok(false) => {
                    let violation = {
                        let rt = self.rt.borrow();
                        Violation {
                            name: check.name,
                            at: check.at,
                            uptime: rt.uptime(),
                            devices: rt.readings(),
                        }
                    };
                    self.rt.borrow_mut().report_violation(&violation);
                    let message = violation.to_string();
                    self.violation = Some(violation);
                    self.finish(EndReason::Violated(message));
                    return false;
                }
                Err(f) => {
                    let message = describe(&f, &check.call.label);
                    self.note_fault(&message, f.over_budget);
                    self.finish(EndReason::Error(message));
                    return false;
                }
            }
        }
        let mut rt = self.rt.borrow_mut();
        rt.invariants_read_inputs = rt.input_accesses != accesses;
        true
    }

    /// Applies the error policy to a failed handler; true if the tick goes on.
    fn handle_fault(&mut self, fault: &Fault, label: &str) -> bool {
        let message = describe(fault, label);
        self.note_fault(&message, fault.over_budget);
        let policy = match (self.options.policy, fault.over_budget) {
            // A runaway handler is never skipped: it would run away again.
            (ErrorPolicy::Skip, true) => ErrorPolicy::Stop,
            (p, _) => p,
        };
        match policy {
            ErrorPolicy::Stop => {
                self.finish(EndReason::Error(message));
                false
            }
            ErrorPolicy::Skip => {
                self.trouble.recovered_errors = self.trouble.recovered_errors.saturating_add(1);
                self.rt
                    .borrow_mut()
                    .log
                    .error(&format!("{message} (policy skip: going on)"));
                true
            }
            ErrorPolicy::Restart => {
                self.schedule_restart(&message);
                false
            }
        }
    }

    fn schedule_restart(&mut self, message: &str) {
        self.trouble.recovered_errors = self.trouble.recovered_errors.saturating_add(1);
        let now = self.clock.now();
        if now.saturating_sub(self.last_start) >= BACKOFF_RESET {
            self.failures_in_a_row = 0;
        }
        let wait = FIRST_BACKOFF
            .saturating_mul(1u32 << self.failures_in_a_row.min(6))
            .min(MAX_BACKOFF);
        self.failures_in_a_row = self.failures_in_a_row.saturating_add(1);
        let mut rt = self.rt.borrow_mut();
        rt.log.error(message);
        rt.write_safe_state("script error");
        rt.reset_program();
        rt.log.notice(&format!(
            "policy restart: starting the script again in {} (failure {} in a row); outputs \
             safe meanwhile",
            crate::time::duration::format_duration(wait),
            self.failures_in_a_row
        ));
        self.state = State::Restarting {
            at: now.saturating_add(wait),
        };
        drop(rt);
        self.events.publish(|| RunEvent::ScriptRestarting {
            after_ms: u64::try_from(wait.as_millis()).unwrap_or(u64::MAX),
        });
    }

    fn restart(&mut self) {
        self.state = State::Running;
        self.restarts = self.restarts.saturating_add(1);
        self.last_start = self.clock.now();
        {
            let mut rt = self.rt.borrow_mut();
            rt.reset_program();
            rt.cause = "top level".into();
            rt.log.notice("starting the script again");
        }
        match self.program.start() {
            Ok(()) => self.tell_started(),
            Err(f) => {
                let message = describe(&f, "top level");
                self.note_fault(&message, f.over_budget);
                self.schedule_restart(&message);
            }
        }
    }

    /// Ends the run: `on_stop` handlers, safe state, watchdogs released, exit status
    /// (`runtime::exit`).
    pub fn finish(&mut self, reason: EndReason) {
        if self.status().is_some() {
            return;
        }
        let was_running = self.state == State::Running;
        self.state = State::Stopped {
            status: exit::ERROR,
        };
        // The signal that stopped the run (if one did) has been seen: from here on the flag
        // tells of another one, which cuts the `on_stop` handlers short (their exchanges, the
        // handler under way, the ones left) and goes straight to the end's writes. Cleared
        // before anything is logged: a second signal sent on seeing "stopping" must not be
        // wiped out.
        let flag = Arc::clone(&self.options.stop_flag);
        flag.store(0, Ordering::SeqCst);
        {
            let mut rt = self.rt.borrow_mut();
            match &reason {
                EndReason::Error(m) => rt.log.error(m),
                EndReason::Signal(n) => {
                    rt.log.notice(&format!(
                        "stopping: {} received ({})",
                        signals::name(*n),
                        signals::likely_cause(*n)
                    ));
                }
                EndReason::Stopped(code) => {
                    rt.log
                        .notice(&format!("stopping: the script called stop({code})"));
                }
                EndReason::Finished(why) => rt.log.notice(&format!("stopping: {why}")),
                EndReason::Requested(by) => rt.log.notice(&format!("stopping: asked by {by}")),
                // Logged with the tick's readings by `report_violation`.
                EndReason::Violated(_) => {}
            }
        }
        self.rt
            .borrow_mut()
            .set_cancel(&Cancel::when_set(Arc::clone(&flag)));
        if was_running {
            self.run_stop_handlers(&flag);
        }
        // The end's writes are not cut: they come after the stop, with their own bounded tries.
        self.rt.borrow_mut().set_cancel(&Cancel::never());
        let mut rt = self.rt.borrow_mut();
        self.trouble.refused_writes = rt
            .devices
            .iter_mut()
            .filter_map(|d| d.as_c29u().map(|c| c.refused_writes))
            .sum();
        self.trouble.lost_at_end = rt
            .devices
            .iter()
            .filter(|d| !d.health().online())
            .map(|d| d.name().to_string())
            .collect();
        let why = match &reason {
            EndReason::Error(_) => "script error",
            EndReason::Violated(_) => "invariant false",
            EndReason::Signal(_) => "signal",
            EndReason::Stopped(_) => "stop()",
            EndReason::Finished(_) => "end of run",
            EndReason::Requested(_) => "stop requested",
        };
        self.end_report = rt.end_safe(why, true);
        self.trouble.unreached_at_end = self
            .end_report
            .iter()
            .filter(|d| d.needs_safe_state())
            .map(|d| d.device.clone())
            .collect();
        // After the safe state: the records file gets a bounded wait for what is queued.
        let r = &mut *rt;
        self.trouble.records_lost = r.records.close(&mut r.log);
        self.stats.records_lost = self.trouble.records_lost;
        let failed = rt.records.failed();
        let (status, because) = match reason {
            EndReason::Error(_) | EndReason::Violated(_) => (exit::ERROR, None),
            EndReason::Stopped(code) if code != 0 => (
                i32::try_from(code.clamp(1, 255)).unwrap_or(exit::ERROR),
                None,
            ),
            _ if !self.trouble.is_empty() => (exit::TROUBLE, Some(self.trouble.describe())),
            _ if failed > 0 => (
                exit::MEASUREMENT_FAILED,
                Some(format!("{failed} measurement(s) out of limits")),
            ),
            EndReason::Signal(n) => (exit::signal(n), None),
            // As for SIGTERM: whoever stops a rig by hand or by systemd sees one status.
            EndReason::Requested(_) => (exit::signal(SIGTERM), None),
            _ => (exit::OK, None),
        };
        match because {
            Some(why) => rt.log.warn(&format!("{why}: exit status {status}")),
            None => rt.log.notice(&format!("stopped; exit status {status}")),
        }
        drop(rt);
        self.state = State::Stopped { status };
        self.tell_end(status, &reason);
    }

    /// Tells the events how the run ended, answers the askers waiting with the final
    /// snapshot, and lets the control queue go (later askers are told the run has ended).
    fn tell_end(&mut self, status: i32, reason: &EndReason) {
        let (safe, unconfirmed): (Vec<_>, Vec<_>) =
            self.end_report.iter().partition(|d| !d.needs_safe_state());
        self.events.publish(|| RunEvent::Ended {
            status,
            reason: reason.to_string(),
            safe: safe.into_iter().map(|d| d.device.clone()).collect(),
            unconfirmed: unconfirmed.into_iter().map(|d| d.device.clone()).collect(),
        });
        self.answer_requests();
        self.served = None;
    }
}

impl<P: Program> Runner<P> {
    /// Runs the `on_stop` handlers in the order they were added, all of them together within
    /// `STOP_BUDGET` (each also within the script's limits per call); skips the rest once the
    /// budget is spent or another signal sets `flag`. A handler the budget cuts off, and each
    /// one skipped for it, is a failed one; another signal's cut is what its sender asked for.
    fn run_stop_handlers(&mut self, flag: &Arc<AtomicUsize>) {
        let calls = self.rt.borrow().stop_calls();
        let until = self.clock.now().saturating_add(STOP_BUDGET);
        let count = calls.len();
        for (done, call) in calls.iter().enumerate() {
            let signal = flag.load(Ordering::SeqCst);
            let over = self.clock.now() >= until;
            if signal != 0 || over {
                let left = count - done;
                let why = match i32::try_from(signal) {
                    Ok(n) if n != 0 => format!("{} received while stopping", signals::name(n)),
                    _ => format!(
                        "the on_stop handlers' {} are spent",
                        crate::time::duration::format_duration(STOP_BUDGET)
                    ),
                };
                self.rt.borrow_mut().log.warn(&format!(
                    "{why}: {left} on_stop handler(s) skipped, straight to the safe state"
                ));
                if signal == 0 {
                    self.trouble.on_stop_failed =
                        self.trouble.on_stop_failed.saturating_add(left as u64);
                }
                return;
            }
            self.rt.borrow_mut().cause.clone_from(&call.label);
            let limit = StopLimit {
                until,
                budget: STOP_BUDGET,
                signal: Arc::clone(flag),
            };
            let result = self.program.call_in_stop(call, limit);
            let cut_by = flag.load(Ordering::SeqCst);
            match result {
                // Asked for by whoever sent the signal: no failure of the script's.
                Err(_) if cut_by != 0 => {
                    let signal = i32::try_from(cut_by).unwrap_or(SIGTERM);
                    self.rt.borrow_mut().log.warn(&format!(
                        "{}: cut off by {} while stopping",
                        call.label,
                        signals::name(signal)
                    ));
                }
                Err(f) => {
                    let message = describe(&f, &call.label);
                    self.note_fault(&message, f.over_budget);
                    self.rt.borrow_mut().log.error(&message);
                    self.trouble.on_stop_failed = self.trouble.on_stop_failed.saturating_add(1);
                }
                Ok(()) => {}
            }
        }
    }
}

/// The CPU wake-up latency request of a run, as it stands.
#[derive(Debug, Default)]
struct LatencyRequest {
    /// The request held now.
    hold: Option<wake_latency::LatencyHold>,
    /// The OS refused it once: not asked again.
    refused: bool,
    /// The handlers it was last worked out for.
    seen: Option<(usize, u64)>,
}

/// What went wrong during a run that still went on to its end (exit status 5).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Trouble {
    /// Script errors recovered from under policy restart or skip.
    pub recovered_errors: u64,
    /// `on_stop` handlers that failed.
    pub on_stop_failed: u64,
    /// Devices lost and not back when the run ended.
    pub lost_at_end: Vec<String>,
    /// Output writes the modules refused during the run.
    pub refused_writes: u64,
    /// Devices the end's safe state did not reach (not confirmed: no answer, or the read-back
    /// showed another value).
    pub unreached_at_end: Vec<String>,
    /// Records the records file did not take (dropped, refused, or still queued at the end).
    pub records_lost: u64,
}

impl Trouble {
    /// Whether nothing went wrong.
    pub fn is_empty(&self) -> bool {
        self.recovered_errors == 0
            && self.on_stop_failed == 0
            && self.lost_at_end.is_empty()
            && self.refused_writes == 0
            && self.unreached_at_end.is_empty()
            && self.records_lost == 0
    }

    /// What went wrong, in words.
    pub fn describe(&self) -> String {
        let mut parts = Vec::new();
        if self.recovered_errors > 0 {
            parts.push(format!(
                "{} script error(s) recovered from",
                self.recovered_errors
            ));
        }
        if self.on_stop_failed > 0 {
            parts.push(format!("{} on_stop handler(s) failed", self.on_stop_failed));
        }
        if !self.lost_at_end.is_empty() {
            parts.push(format!(
                "{} lost and not back at the end",
                self.lost_at_end.join(", ")
            ));
        }
        if self.refused_writes > 0 {
            parts.push(format!("{} output write(s) refused", self.refused_writes));
        }
        if !self.unreached_at_end.is_empty() {
            parts.push(format!(
                "the safe state did not reach {}",
                self.unreached_at_end.join(", ")
            ));
        }
        if self.records_lost > 0 {
            parts.push(format!(
                "{} record(s) not written to the records file",
                self.records_lost
            ));
        }
        parts.join("; ")
    }
}

/// After a panic (a bug) in the runner: the safe state written through the drivers to every
/// device that answers, logged with `message`; the host watchdogs are left on, so a module the
/// write did not reach goes safe by itself. Says so on stderr if even that fails.
pub fn safe_after_panic<H: Clone>(rt: &Shared<H>, message: &str) {
    let ended = catch_unwind(AssertUnwindSafe(|| {
        let Ok(mut rt) = rt.try_borrow_mut() else {
            return false;
        };
        // The writes first: the log is the part most likely to have broken.
        rt.end_safe("internal error", false);
        rt.log.error(&format!(
            "internal error (a bug in rigscript; please report it with this log): {message}; \
             host watchdogs left on; exit status {}",
            exit::INTERNAL
        ));
        true
    }));
    if !matches!(ended, Ok(true)) {
        // A closed stderr loses this line rather than panic again.
        let _ = writeln!(
            std::io::stderr(),
            "rigscript: internal error ({message}) and the safe state could not be written after \
             it; the modules' host watchdogs, where on, drive their outputs safe"
        );
    }
}

/// What a panic said.
pub fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| (*s).to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".into())
}

/// The first of the deadlines `start + k * period` that is at or after `t`.
fn boundary_at_or_after(start: Duration, period: Duration, t: Duration) -> Duration {
    if t <= start {
        return start;
    }
    let behind = t.saturating_sub(start).as_nanos();
    let periods = behind.div_ceil(period.as_nanos().max(1));
    let skip = u32::try_from(periods).unwrap_or(u32::MAX);
    start.saturating_add(period.saturating_mul(skip))
}

/// `file:line:col: in handler: cause` (a limit's cause says which limit and how to raise it).
fn describe(fault: &Fault, label: &str) -> String {
    match &fault.location {
        Some(at) => format!("{at}: in {label}: {}", fault.cause),
        None => format!("in {label}: {}", fault.cause),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device::cancel::CANCEL_SLICE;
    use crate::runtime::devices::links::TransactionCounter;
    use crate::runtime::log::Logger;
    use crate::runtime::records::Records;
    use crate::runtime::safety::END_TRIES;
    use crate::time::clock::{Clock, VirtualClock};
    use crate::time::zone::Zone;

    /// A program with one `every` timer whose handler takes `burn` of (virtual) time.
    struct Burner {
        rt: Shared<()>,
        clock: VirtualClock,
        every: Duration,
        burn: Duration,
        calls: u32,
        fail_at: Option<u32>,
    }

    impl Program for Burner {
        type Handler = ();
        fn start(&mut self) -> Result<(), Fault> {
            self.rt.borrow_mut().every(self.every, ()).unwrap();
            Ok(())
        }
        fn holds(&mut self, _check: &Check<()>) -> Result<bool, Fault> {
            // This program states no invariants.
            Ok(true)
        }
        fn call(&mut self, _call: &Call<()>) -> Result<(), Fault> {
            self.calls += 1;
            self.clock.advance(self.burn);
            if self.fail_at == Some(self.calls) {
                return Err(Fault {
                    location: Some("x.rhai:1:1".into()),
                    cause: "boom".into(),
                    over_budget: false,
                });
            }
            Ok(())
        }
    }

    fn runner(
        every: Duration,
        burn: Duration,
        policy: ErrorPolicy,
    ) -> (Runner<Burner>, VirtualClock) {
        let clock = VirtualClock::at_epoch();
        let shared: SharedClock = Arc::new(clock.clone());
        let rt = Rc::new(RefCell::new(Runtime::new(
            Arc::clone(&shared),
            Zone::utc(),
            Vec::new(),
            Records::in_memory(),
            Logger::new(Arc::clone(&shared), Zone::utc(), false),
            TransactionCounter::default(),
            Duration::from_secs(1),
        )));
        rt.borrow_mut().log.keep_lines();
        let program = Burner {
            rt: Rc::clone(&rt),
            clock: clock.clone(),
            every,
            burn,
            calls: 0,
            fail_at: None,
        };
        let options = RunOptions {
            period: Duration::from_millis(20),
            policy,
            end_after: None,
            stop_flag: Arc::default(),
            wake_latency: WakeLatency::Off,
        };
        let mut r = Runner::new(rt, program, options);
        r.start();
        (r, clock)
    }

    #[test]
    fn overruns_are_counted_and_the_loop_keeps_its_phase() {
        let (mut r, clock) = runner(
            Duration::from_millis(20),
            Duration::from_millis(50),
            ErrorPolicy::Stop,
        );
        r.advance(Duration::from_millis(400));
        assert!(r.stats.overruns > 0);
        assert_eq!(
            r.next_deadline().as_nanos() % Duration::from_millis(20).as_nanos(),
            0,
            "deadlines stay on the 20 ms grid"
        );
        assert!(r.next_deadline() > clock.now().saturating_sub(Duration::from_millis(20)));
        assert!(r.stats.work.max() >= Duration::from_millis(50));
    }

    #[test]
    fn after_an_overrun_the_next_tick_starts_at_once() {
        let (mut r, clock) = runner(
            Duration::from_millis(20),
            Duration::from_millis(50),
            ErrorPolicy::Stop,
        );
        r.advance(Duration::from_millis(100));
        assert!(r.stats.overruns > 0);
        assert!(
            r.next_deadline() <= clock.now(),
            "no sleep to the next boundary after a tick that ran late"
        );
    }

    #[test]
    fn idle_ticks_are_skipped_when_no_handler_polls_inputs() {
        let (mut r, _clock) = runner(Duration::from_secs(1), Duration::ZERO, ErrorPolicy::Stop);
        r.advance(Duration::from_secs(10));
        assert_eq!(r.program().calls, 10);
        assert!(r.stats.ticks <= 13, "{} ticks for 10 s", r.stats.ticks);
        assert_eq!(r.stats.overruns, 0);
    }

    #[test]
    fn restart_backs_off_doubling() {
        let (mut r, clock) = runner(
            Duration::from_millis(100),
            Duration::ZERO,
            ErrorPolicy::Restart,
        );
        r.program.fail_at = Some(1);
        r.advance(Duration::from_millis(100));
        assert_eq!(r.program().calls, 1);
        r.program.fail_at = Some(2);
        // Restarted after 1 s; its timer fires 100 ms later and fails again.
        r.advance(Duration::from_millis(1100));
        assert_eq!(r.program().calls, 2);
        r.advance(Duration::from_millis(1900));
        assert_eq!(r.program().calls, 2, "the second wait is 2 s");
        r.advance(Duration::from_millis(200));
        assert_eq!(r.program().calls, 3);
        assert!(r.status().is_none());
        let log = r.runtime().borrow().log.lines().join("\n");
        assert!(log.contains("x.rhai:1:1: in every 100ms: boom"), "{log}");
        assert!(clock.now() >= Duration::from_millis(3300));
    }

    /// A program with `timers` timers all due at 1 s, whose third call "receives" SIGTERM.
    struct Signalled {
        rt: Shared<()>,
        timers: usize,
        flag: Arc<AtomicUsize>,
        calls: usize,
    }

    impl Program for Signalled {
        type Handler = ();
        fn start(&mut self) -> Result<(), Fault> {
            let mut rt = self.rt.borrow_mut();
            rt.handlers.set_max_timers(self.timers + 1);
            for _ in 0..self.timers {
                rt.every(Duration::from_secs(1), ()).unwrap();
            }
            Ok(())
        }
        fn holds(&mut self, _check: &Check<()>) -> Result<bool, Fault> {
            // This program states no invariants.
            Ok(true)
        }
        fn call(&mut self, _call: &Call<()>) -> Result<(), Fault> {
            self.calls += 1;
            if self.calls == 3 {
                self.flag.store(SIGTERM as usize, Ordering::SeqCst);
            }
            Ok(())
        }
    }

    #[test]
    fn a_signal_during_a_tick_of_many_timers_ends_the_run_before_the_next_handler() {
        let (r, _clock) = runner(Duration::from_secs(3600), Duration::ZERO, ErrorPolicy::Stop);
        let rt = Rc::clone(r.runtime());
        let flag: Arc<AtomicUsize> = Arc::default();
        let program = Signalled {
            rt: Rc::clone(&rt),
            timers: 10_000,
            flag: Arc::clone(&flag),
            calls: 0,
        };
        let options = RunOptions {
            period: Duration::from_millis(20),
            policy: ErrorPolicy::Stop,
            end_after: None,
            stop_flag: flag,
            wake_latency: WakeLatency::Off,
        };
        let mut r = Runner::new(rt, program, options);
        r.start();
        r.advance(Duration::from_secs(2));
        assert_eq!(r.program().calls, 3, "no handler after the signal");
        assert_eq!(r.status(), Some(exit::signal(SIGTERM)));
        let log = r.runtime().borrow().log.lines().join("\n");
        assert!(log.contains("stopping: SIGTERM received"), "{log}");
    }

    #[test]
    fn a_refused_prompt_wakeup_request_is_logged_once_and_shown_by_stats() {
        let (mut r, _clock) = runner(Duration::from_secs(3600), Duration::ZERO, ErrorPolicy::Stop);
        let denied = std::io::Error::from_raw_os_error(libc::EPERM);
        r.note_prompt_wakeups(Err(denied));
        r.advance(Duration::from_secs(2));
        let log = r.runtime().borrow().log.lines().join("\n");
        assert_eq!(
            log.matches("prompt wake-ups (1 ns timer slack, short scheduler slice) refused (")
                .count(),
            1,
            "{log}"
        );
        let stats = r.stats.prompt_wakeups.clone().unwrap_or_default();
        assert!(stats.starts_with("refused ("), "{stats}");
    }

    #[test]
    fn a_limits_cause_is_not_repeated_by_the_message() {
        let fault = Fault {
            location: Some("s.rhai:3:5".into()),
            cause: "ran over its operation budget of 10 operations in one call (a runaway \
                    loop?); a call that needs more can have it with --budget"
                .into(),
            over_budget: true,
        };
        let message = describe(&fault, "every 1s");
        assert!(
            message.starts_with("s.rhai:3:5: in every 1s: ran over"),
            "{message}"
        );
        assert_eq!(message.matches("budget").count(), 2, "{message}");
    }

    #[test]
    fn boundaries() {
        let ms = Duration::from_millis;
        assert_eq!(boundary_at_or_after(ms(100), ms(20), ms(50)), ms(100));
        assert_eq!(boundary_at_or_after(ms(100), ms(20), ms(100)), ms(100));
        assert_eq!(boundary_at_or_after(ms(100), ms(20), ms(101)), ms(120));
        assert_eq!(boundary_at_or_after(ms(100), ms(20), ms(140)), ms(140));
    }

    /// A program that sets outputs, then panics in its handler (holding a borrow of the
    /// runtime, as a binding would) or at its top level.
    struct Panicker {
        rt: Shared<&'static str>,
        at_start: bool,
    }

    impl Program for Panicker {
        type Handler = &'static str;
        fn start(&mut self) -> Result<(), Fault> {
            let mut rt = self.rt.borrow_mut();
            rt.set_outputs(crate::runtime::testing::IO, 0xF0);
            rt.every(Duration::from_millis(100), "boom").unwrap();
            rt.flush_outputs();
            assert!(!self.at_start, "a bug at the top level");
            Ok(())
        }
        fn holds(&mut self, _check: &Check<&'static str>) -> Result<bool, Fault> {
            // This program states no invariants.
            Ok(true)
        }
        fn call(&mut self, _call: &Call<&'static str>) -> Result<(), Fault> {
            let _held = self.rt.borrow_mut();
            panic!("a bug in a binding");
        }
    }

    fn panicking(at_start: bool) -> (Runner<Panicker>, crate::runtime::testing::TestRig) {
        let mut r = crate::runtime::testing::TestRig::started();
        let rt = r.shared_runtime();
        let program = Panicker {
            rt: Rc::clone(&rt),
            at_start,
        };
        let options = RunOptions {
            period: Duration::from_millis(20),
            policy: ErrorPolicy::Restart,
            end_after: None,
            stop_flag: Arc::default(),
            wake_latency: WakeLatency::Off,
        };
        let mut runner = Runner::new(rt, program, options);
        runner.start();
        (runner, r)
    }

    #[test]
    fn a_panic_in_a_handler_writes_the_safe_state_and_ends_with_70() {
        let (mut runner, r) = panicking(false);
        runner.advance(Duration::from_millis(60));
        assert_eq!(r.sim.outputs("io").unwrap(), 0xF0, "at work");
        runner.advance(Duration::from_millis(100));
        assert_eq!(runner.status(), Some(exit::INTERNAL));
        assert_eq!(r.sim.outputs("io").unwrap(), 0x05, "the safe value");
        assert_eq!(r.sim.relay("panel").unwrap(), 3, "the safe relay");
        assert!(
            r.sim.watchdog("io").unwrap().enabled,
            "the watchdog is left on"
        );
        let log = runner.runtime().borrow().log.lines().join("\n");
        assert!(
            log.contains("safe state (internal error): io outputs 0x05, panel relay 3"),
            "{log}"
        );
        assert!(
            log.contains("internal error (a bug in rigscript; please report it with this log): a bug in a binding; host watchdogs left on; exit status 70"),
            "{log}"
        );
    }

    #[test]
    fn a_panic_at_the_top_level_ends_safe_too() {
        let (runner, r) = panicking(true);
        assert_eq!(runner.status(), Some(exit::INTERNAL));
        let log = runner.runtime().borrow().log.lines().join("\n");
        assert!(log.contains("io: outputs 0x05 -> 0xf0"), "{log}");
        assert_eq!(r.sim.outputs("io").unwrap(), 0x05);
    }

    /// A program whose timer reads a module's inputs.
    struct Reader {
        rt: Shared<&'static str>,
    }

    impl Program for Reader {
        type Handler = &'static str;
        fn start(&mut self) -> Result<(), Fault> {
            self.rt
                .borrow_mut()
                .every(Duration::from_millis(100), "read")
                .unwrap();
            Ok(())
        }
        fn holds(&mut self, _check: &Check<&'static str>) -> Result<bool, Fault> {
            // This program states no invariants.
            Ok(true)
        }
        fn call(&mut self, _call: &Call<&'static str>) -> Result<(), Fault> {
            self.rt.borrow_mut().inputs(crate::runtime::testing::IO);
            Ok(())
        }
    }

    #[test]
    fn a_sigterm_while_a_silent_module_is_waited_for_is_honoured_within_a_slice() {
        // A module that waits 1 s for each answer and tries 11 times: each exchange with it,
        // silent, would take 21 s (every try after the first waits out a settling second).
        let rig = crate::runtime::testing::RIG
            .replace("watchdog = \"1s\"\n", "timeout = \"1s\"\nretries = 10\n");
        let mut r = crate::runtime::testing::TestRig::new(&rig);
        r.rt.start_devices().unwrap();
        let rt = r.shared_runtime();
        let flag: Arc<AtomicUsize> = Arc::default();
        let program = Reader { rt: Rc::clone(&rt) };
        let options = RunOptions {
            period: Duration::from_millis(20),
            policy: ErrorPolicy::Stop,
            end_after: None,
            stop_flag: Arc::clone(&flag),
            wake_latency: WakeLatency::Off,
        };
        let mut runner = Runner::new(rt, program, options);
        runner.start();
        r.sim.set_gone("io", true).unwrap();
        // The first read starts at 100 ms; the signal comes 350 ms into its first wait.
        let signalled = Duration::from_millis(450);
        r.clock.set_at(signalled, flag, SIGTERM as usize);
        runner.advance(Duration::from_secs(1));
        // Stopped by the signal, and the safe state did not reach the silent module.
        assert_eq!(runner.status(), Some(exit::TROUBLE));
        // The wait is cut within a slice; then only the end's writes: END_TRIES tries of 1 s
        // with the silent module, each after the line has been silent a timeout more (the
        // cut request's answer could still come). The exchange it cut would have gone on for
        // 20 s more.
        let took = r.clock.now() - signalled;
        let tries = END_TRIES * 2;
        let bound = CANCEL_SLICE + Duration::from_secs(1) * tries;
        assert!(took <= bound, "{took:?}, more than {bound:?}");
        let log = runner.runtime().borrow().log.lines().join("\n");
        assert!(log.contains("stopping: SIGTERM received"), "{log}");
        assert!(log.contains("io: the safe state did not reach it"), "{log}");
        assert!(
            !log.contains("io: lost"),
            "a cut exchange is no loss: {log}"
        );
        assert!(
            log.contains("the safe state did not reach io: exit status 5"),
            "{log}"
        );
        assert_eq!(r.sim.relay("panel").unwrap(), 3, "the others get theirs");
    }

    /// A program that turns the panel's relay off its safe position and then has only a slow
    /// timer: nothing in it makes the loop tick before that timer.
    struct SlowTimer {
        rt: Shared<&'static str>,
    }

    impl Program for SlowTimer {
        type Handler = &'static str;
        fn start(&mut self) -> Result<(), Fault> {
            let mut rt = self.rt.borrow_mut();
            rt.set_relay(crate::runtime::testing::PANEL, 5);
            rt.every(Duration::from_secs(30), "slow").unwrap();
            Ok(())
        }
        fn holds(&mut self, _check: &Check<&'static str>) -> Result<bool, Fault> {
            // This program states no invariants.
            Ok(true)
        }
        fn call(&mut self, _call: &Call<&'static str>) -> Result<(), Fault> {
            Ok(())
        }
    }

    fn slow_timer(
        period: Duration,
        end_after: Option<Duration>,
    ) -> (Runner<SlowTimer>, crate::runtime::testing::TestRig) {
        let mut r = crate::runtime::testing::TestRig::started();
        let rt = r.shared_runtime();
        let program = SlowTimer { rt: Rc::clone(&rt) };
        let options = RunOptions {
            period,
            policy: ErrorPolicy::Stop,
            end_after,
            stop_flag: Arc::default(),
            wake_latency: WakeLatency::Off,
        };
        let mut runner = Runner::new(rt, program, options);
        runner.start();
        (runner, r)
    }

    #[test]
    fn a_lost_devices_grace_end_holds_every_output_safe_at_once_whatever_the_period() {
        for period in [Duration::from_millis(20), Duration::from_secs(10)] {
            let (mut runner, r) = slow_timer(period, None);
            runner.advance(Duration::from_millis(100));
            assert_eq!(r.sim.relay("panel").unwrap(), 5, "at work");
            r.sim.set_gone("io", true).unwrap();
            // Lost at its next watchdog feed; held safe once lost for longer than grace (1 s).
            let step = Duration::from_millis(10);
            let started = r.clock.now();
            while r.sim.relay("panel").unwrap() != 3
                && r.clock.now() - started < Duration::from_secs(20)
            {
                runner.advance(step);
            }
            let held_at = r.clock.now();
            let lost_at = runner.runtime().borrow().devices[crate::runtime::testing::IO]
                .health()
                .lost_at
                .expect("io is lost");
            let log = runner.runtime().borrow().log.lines().join("\n");
            assert_eq!(r.sim.relay("panel").unwrap(), 3, "{period:?}: {log}");
            let grace = Duration::from_secs(1);
            assert!(
                held_at <= lost_at + grace + step,
                "{period:?}: lost at {lost_at:?}, the panel safe at {held_at:?}: {log}"
            );
            assert!(
                log.contains("every output is held at its safe state"),
                "{log}"
            );
        }
    }

    #[test]
    fn the_end_of_for_is_honoured_to_the_sleep_slice_not_the_period() {
        let (mut runner, r) = slow_timer(Duration::from_secs(10), Some(Duration::from_secs(2)));
        let status = runner.run();
        assert_eq!(status, exit::OK);
        let ended = r.clock.now();
        assert!(
            ended >= Duration::from_secs(2) && ended <= Duration::from_secs(2) + SLEEP_SLICE,
            "ended at {ended:?}"
        );
        let log = runner.runtime().borrow().log.lines().join("\n");
        assert!(log.contains("stopping: ran for 2s"), "{log}");
    }

    /// A program with `handlers` on_stop handlers, each taking `burn` of virtual time; the
    /// one numbered `signal_in` (if any) "receives" SIGINT meanwhile.
    struct StopBurner {
        rt: Shared<()>,
        clock: VirtualClock,
        handlers: usize,
        burn: Duration,
        signal_in: Option<usize>,
        flag: Arc<AtomicUsize>,
        calls: usize,
    }

    impl Program for StopBurner {
        type Handler = ();
        fn start(&mut self) -> Result<(), Fault> {
            let mut rt = self.rt.borrow_mut();
            for _ in 0..self.handlers {
                rt.on_stop(()).unwrap();
            }
            rt.every(Duration::from_secs(1), ()).unwrap();
            Ok(())
        }
        fn holds(&mut self, _check: &Check<()>) -> Result<bool, Fault> {
            // This program states no invariants.
            Ok(true)
        }
        fn call(&mut self, _call: &Call<()>) -> Result<(), Fault> {
            self.calls += 1;
            self.clock.advance(self.burn);
            if self.signal_in == Some(self.calls) {
                self.flag.store(libc::SIGINT as usize, Ordering::SeqCst);
            }
            Ok(())
        }
    }

    fn stop_burner(
        handlers: usize,
        burn: Duration,
        signal_in: Option<usize>,
    ) -> (Runner<StopBurner>, VirtualClock) {
        let (r, clock) = runner(Duration::from_secs(3600), Duration::ZERO, ErrorPolicy::Stop);
        let rt = Rc::clone(r.runtime());
        let flag: Arc<AtomicUsize> = Arc::default();
        let program = StopBurner {
            rt: Rc::clone(&rt),
            clock: clock.clone(),
            handlers,
            burn,
            signal_in,
            flag: Arc::clone(&flag),
            calls: 0,
        };
        let options = RunOptions {
            period: Duration::from_millis(20),
            policy: ErrorPolicy::Stop,
            end_after: None,
            stop_flag: flag,
            wake_latency: WakeLatency::Off,
        };
        let mut r = Runner::new(rt, program, options);
        r.start();
        (r, clock)
    }

    #[test]
    fn on_stop_handlers_share_one_budget_and_the_rest_are_skipped() {
        let (mut r, clock) = stop_burner(100, Duration::from_millis(300), None);
        r.advance(Duration::from_millis(100));
        let stopped_at = clock.now();
        r.signal_stop();
        // 300 ms each: the seventh starts before 2 s are spent and ends past them.
        assert_eq!(r.program().calls, 7);
        assert!(clock.now() - stopped_at <= STOP_BUDGET + Duration::from_millis(300));
        let log = r.runtime().borrow().log.lines().join("\n");
        assert!(
            log.contains("the on_stop handlers' 2s are spent: 93 on_stop handler(s) skipped, straight to the safe state"),
            "{log}"
        );
        assert_eq!(
            r.status(),
            Some(exit::TROUBLE),
            "skipped handlers are failed ones"
        );
    }

    #[test]
    fn a_second_signal_while_stopping_skips_the_remaining_on_stop_handlers() {
        let (mut r, _clock) = stop_burner(5, Duration::from_millis(10), Some(2));
        r.advance(Duration::from_millis(100));
        r.signal_stop();
        assert_eq!(r.program().calls, 2, "none after the second signal");
        let log = r.runtime().borrow().log.lines().join("\n");
        let skipped = log
            .find("SIGINT received while stopping: 3 on_stop handler(s) skipped, straight to the safe state")
            .unwrap_or_else(|| panic!("{log}"));
        let end = log
            .find("stopped; exit status 143")
            .unwrap_or_else(|| panic!("{log}"));
        assert!(skipped < end, "{log}");
        assert_eq!(r.status(), Some(exit::signal(SIGTERM)));
    }
}
