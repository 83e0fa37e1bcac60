//! The state of one run that scripts act on: the clock, the devices, the handlers, records,
//! the log and the stop request. Its jobs live beside it: `registry` (devices by name and
//! index), `inputs` (lazy reads), `outputs` (what the script wants written), `safety`
//! (supervision), `registrations` and `events` (handlers and what fires them),
//! `invariant_checks`. The types it holds come from modules below it (`subscriptions`,
//! `invariants`), which never import it back.
//!
//! `H` is the script layer's handler type (a Rhai function pointer); nothing here knows Rhai.

use super::devices::links::TransactionCounter;
use super::devices::Device;
use super::events::Needs;
use super::forcing::Forces;
use super::invariants::InvariantCheck;
use super::log::Logger;
use super::observe::Events;
use super::records::Records;
use super::subscriptions::{Call, Subscriptions};
use crate::device::cancel::Cancel;
use crate::time::clock::SharedClock;
use crate::time::zone::Zone;
use std::rc::Rc;
use std::sync::atomic::Ordering;
use std::time::Duration;

/// The state of one run.
pub struct Runtime<H> {
    /// The one source of time.
    pub(super) clock: SharedClock,
    /// The zone of cron, `now()` and the log.
    pub(super) zone: Zone,
    /// The devices, in name order.
    pub(super) devices: Vec<Device>,
    /// The script's handlers and timers.
    pub(super) handlers: Subscriptions<H>,
    /// What the script states must hold after every tick (`invariants`).
    pub(super) invariants: Rc<Vec<InvariantCheck<H>>>,
    /// Whether the invariants read device inputs when last evaluated (or have not been yet):
    /// then every tick runs, so the inputs they read are read every tick.
    pub(super) invariants_read_inputs: bool,
    /// Accesses to device inputs so far (fresh readings or not), to tell what reads them.
    pub(super) input_accesses: u64,
    /// Records and measurements.
    pub(super) records: Records,
    /// The log.
    pub(super) log: Logger,
    /// The current tick (0 while the top level runs at start).
    pub(super) tick: u64,
    /// The period boundary the current tick runs for (at or before its start): timer
    /// deadlines are counted up to it, so one that passes while the tick runs falls to the
    /// next tick (see `Schedule::due_at_tick`).
    pub(super) tick_boundary: Option<Duration>,
    /// Monotonic time the run started.
    pub(super) started: Duration,
    /// The script asked to stop, with this exit status (`request_stop`).
    stop_request: Option<i64>,
    /// The handler running now, for the log lines of the outputs it changes.
    pub(super) cause: String,
    /// A device has been lost for longer than its grace time: every device is held at its
    /// safe state until all are back.
    pub(super) held_safe: bool,
    /// Requests sent on all links.
    pub(super) transactions: TransactionCounter,
    /// How long a device may be lost before everything goes safe.
    pub(super) grace: Duration,
    /// What cuts the devices' exchanges short (`set_cancel`): the run's stop flag while it
    /// runs; supervision also stops trying lost devices once it is set.
    pub(super) cancel: Cancel,
    /// Where what happens is told to whoever watches the run (`observe`).
    pub(super) events: Events,
    /// The operator's forces (`forcing`), when rig.toml allows them.
    pub(super) forces: Forces,
    /// `collect_calls`'s lists, kept between ticks: a tick builds its calls without
    /// allocating the lists.
    pub(super) needs: Vec<Needs>,
    pub(super) call_buffer: Vec<Call<H>>,
    /// When the links are next asked whether they ended (`safety::liveness`).
    pub(super) next_link_watch: Duration,
    /// Whether a device's link has a descriptor the OS tells its end on (until the first
    /// look, assumed so).
    pub(super) has_link_watch: bool,
}

impl<H: Clone> Runtime<H> {
    /// A run over `devices` (already opened) starting now.
    pub fn new(
        clock: SharedClock,
        zone: Zone,
        devices: Vec<Device>,
        records: Records,
        log: Logger,
        transactions: TransactionCounter,
        grace: Duration,
    ) -> Self {
        let started = clock.now();
        // The log's stream is the run's: its lines and everything else in one order.
        let events = log.events().clone();
        Self {
            clock,
            zone,
            devices,
            handlers: Subscriptions::new(zone),
            invariants: Rc::default(),
            invariants_read_inputs: true,
            input_accesses: 0,
            records,
            log,
            tick: 0,
            tick_boundary: None,
            started,
            stop_request: None,
            cause: "top level".into(),
            held_safe: false,
            transactions,
            grace,
            cancel: Cancel::never(),
            events,
            forces: Forces::default(),
            needs: Vec::new(),
            call_buffer: Vec::new(),
            next_link_watch: started,
            has_link_watch: true,
        }
    }

    /// Monotonic now.
    pub fn now(&self) -> Duration {
        self.clock.now()
    }

    /// Wall time now in the run's zone, as RFC 3339 with milliseconds.
    pub fn wall_text(&self) -> String {
        self.zone
            .at(self.clock.wall())
            .to_rfc3339_opts(chrono::SecondsFormat::Millis, false)
    }

    /// How long the run has been going.
    pub fn uptime(&self) -> Duration {
        self.now().saturating_sub(self.started)
    }

    /// Requests sent so far on all links.
    pub fn transaction_count(&self) -> u64 {
        self.transactions.load(Ordering::Relaxed)
    }

    /// The run's clock, for what measures time on it (the script's limits per call).
    pub fn clock(&self) -> &SharedClock {
        &self.clock
    }

    /// The counter of requests sent on all links, shared with what watches it (the script's
    /// limits read the clock again after each new request: an exchange takes time).
    pub fn transaction_counter(&self) -> &TransactionCounter {
        &self.transactions
    }

    /// Whether every device is held at its safe state: one has been lost for longer than its
    /// grace time and not all are back.
    pub fn held_safe(&self) -> bool {
        self.held_safe
    }

    /// When the next tick has something to do, if no handler polls inputs: the earliest
    /// timer or retry of a lost device, or now while outputs wait to be written (a refused
    /// write is tried again at the next tick; watchdogs are fed between ticks). `None` when every
    /// tick has work: a handler polls inputs, or an invariant read device inputs when last
    /// evaluated (an invariant that reads only outputs, script state or time can change only
    /// in a tick that runs anyway, and is checked in every tick that runs).
    pub fn idle_until(&self) -> Option<Duration> {
        let invariants_poll = !self.invariants.is_empty() && self.invariants_read_inputs;
        if self.handlers.polls_inputs() || invariants_poll {
            return None;
        }
        let now = self.now();
        if self.outputs_pending() {
            return Some(now);
        }
        let timer = self.handlers.next_timer(now, self.clock.wall());
        let upkeep = self.next_retry();
        let next = match (timer, upkeep) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        Some(next.unwrap_or(Duration::MAX))
    }

    /// How often the loop ticks while the script's handlers stay as they are: every `period`
    /// while a handler polls inputs, else at its fastest `every` (no faster than the period);
    /// `None` when only single timers, cron or upkeep wake it.
    pub fn tick_interval(&self, period: Duration) -> Option<Duration> {
        if self.handlers.polls_inputs() {
            return Some(period);
        }
        self.handlers.fastest_every().map(|every| every.max(period))
    }

    /// The log, to write a line to.
    pub fn log_mut(&mut self) -> &mut Logger {
        &mut self.log
    }

    /// The log lines kept (by a run that keeps them: tests, the JUnit report), oldest first.
    pub fn log_lines(&self) -> &[String] {
        self.log.lines()
    }

    /// Closes the log, with a bounded wait for its last lines; how many lines it dropped.
    pub fn close_log(&mut self) -> u64 {
        self.log.close();
        self.log.dropped()
    }

    /// The script's handlers and timers, to look at (`verify`'s coverage and profile).
    pub fn handlers(&self) -> &Subscriptions<H> {
        &self.handlers
    }

    /// The handler about to run is `label` (its buffer kept: this is every call).
    pub(super) fn set_cause(&mut self, label: &str) {
        self.cause.clear();
        self.cause.push_str(label);
        // What a watcher names if the loop stalls in it.
        crate::guardian::pulse::handler(label);
    }

    /// The invariants the script stated, in that order.
    pub fn invariants(&self) -> &[InvariantCheck<H>] {
        &self.invariants
    }

    /// Caps the timers the script may have at once (its limits).
    pub fn limit_timers(&mut self, max: usize) {
        self.handlers.set_max_timers(max);
    }

    /// Drops every handler, timer and invariant, and with them the script's closures that
    /// hold handles to this runtime (a cycle of `Rc`s otherwise).
    pub fn forget_handlers(&mut self) {
        self.handlers.clear();
        self.invariants = Rc::default();
    }

    /// Something that changes when handlers come or go (their count and the next id).
    pub fn handlers_signature(&self) -> (usize, u64) {
        self.handlers.signature()
    }

    /// The script's `stop(code)`: the run ends at the end of this tick with `code`; the first
    /// request made stands.
    pub fn request_stop(&mut self, code: i64) {
        self.stop_request.get_or_insert(code);
    }

    /// The exit status the script asked to stop with, if it did.
    pub fn stop_requested(&self) -> Option<i64> {
        self.stop_request
    }

    /// Forgets every handler and timer and the script's outputs (back to the safe values),
    /// before the script is started again.
    pub fn reset_program(&mut self) {
        self.forget_handlers();
        self.invariants_read_inputs = true;
        self.stop_request = None;
        self.reset_outputs();
    }
}

#[cfg(test)]
mod tests {
    use crate::runtime::subscriptions::Source;
    use crate::runtime::testing::{TestRig, IO, PANEL};
    use std::time::Duration;

    #[test]
    fn idle_until_is_none_while_a_handler_polls_inputs() {
        let mut r = TestRig::started();
        r.rt.subscribe(Source::Rise { dev: IO, ch: 0 }, "rise", "rise".into());
        assert_eq!(r.rt.idle_until(), None);
    }

    #[test]
    fn idle_until_is_the_earliest_timer_or_retry() {
        let mut r = TestRig::started();
        assert_eq!(
            r.rt.idle_until(),
            Some(Duration::MAX),
            "nothing to do: watchdogs are fed between ticks"
        );
        r.rt.after(Duration::from_millis(100), "soon").unwrap();
        assert_eq!(
            r.rt.idle_until(),
            Some(Duration::from_millis(100)),
            "the timer"
        );
        r.rt.reset_program();
        r.sim.set_gone("panel", true).unwrap();
        r.rt.tick += 1;
        r.rt.switches(PANEL);
        let lost_at = r.rt.now();
        assert_eq!(
            r.rt.idle_until(),
            Some(lost_at + Duration::from_secs(1)),
            "the retry"
        );
    }

    #[test]
    fn the_tick_interval_follows_input_polls_and_the_fastest_every() {
        let mut r = TestRig::started();
        let period = Duration::from_millis(20);
        assert_eq!(r.rt.tick_interval(period), None, "nothing to do");
        r.rt.cron("0 0 * * * *", "hourly").unwrap();
        r.rt.after(Duration::from_millis(5), "once").unwrap();
        assert_eq!(r.rt.tick_interval(period), None, "only now and then");
        let slow = r.rt.every(Duration::from_secs(1), "slow").unwrap();
        assert_eq!(r.rt.tick_interval(period), Some(Duration::from_secs(1)));
        let before = r.rt.handlers_signature();
        let fast = r.rt.every(Duration::from_millis(5), "fast").unwrap();
        assert_ne!(r.rt.handlers_signature(), before);
        assert_eq!(
            r.rt.tick_interval(period),
            Some(period),
            "no faster than a period"
        );
        r.rt.cancel(fast);
        assert_eq!(r.rt.tick_interval(period), Some(Duration::from_secs(1)));
        r.rt.cancel(slow);
        r.rt.subscribe(Source::Rise { dev: IO, ch: 0 }, "rise", "rise".into());
        assert_eq!(
            r.rt.tick_interval(period),
            Some(period),
            "inputs polled every tick"
        );
    }

    #[test]
    fn reset_program_forgets_handlers_the_stop_request_and_the_scripts_outputs() {
        let mut r = TestRig::started();
        r.rt.every(Duration::from_secs(1), "t").unwrap();
        r.rt.subscribe(Source::Stop, "s", "on_stop".into());
        r.rt.request_stop(3);
        r.rt.set_outputs(IO, 0x99);
        r.rt.set_relay(PANEL, 7);
        r.rt.reset_program();
        assert!(r.rt.handlers.is_empty());
        assert!(!r.rt.has_work());
        assert_eq!(r.rt.stop_requested(), None);
        assert_eq!(r.rt.c29u(IO).unwrap().wanted_outputs(), 0x05);
        assert_eq!(r.rt.trc(PANEL).unwrap().wanted_relay(), 3);
    }

    #[test]
    fn uptime_and_wall_time_come_from_the_runs_clock() {
        let r = TestRig::started();
        r.clock.advance(Duration::from_millis(1500));
        assert_eq!(r.rt.uptime(), Duration::from_millis(1500));
        assert_eq!(r.rt.wall_text(), "1970-01-01T00:00:01.500+00:00");
    }
}
