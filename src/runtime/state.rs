//! The state of one run, composed of parts that keep their fields private: `Cycle` (the clock
//! and the tick), `Devices` (`registry`), `ProgramState` (what the script set up), `Figures`
//! (log, records, events), `Safety` (`safety::hold`) and `Forces` (`forcing`). Within
//! runtime/ the parts are reached as fields; the jobs that span them live beside this file
//! (`inputs`, `outputs`, `safety`, `triggers`, `registrations`, `invariant_checks`). The
//! script reaches it only through `script_context`.
//!
//! `H` is the script layer's handler type (a Rhai function pointer); nothing here knows Rhai.

use super::cycle::Cycle;
use super::devices::links::TransactionCounter;
use super::devices::Device;
use super::figures::Figures;
use super::forcing::Forces;
use super::handlers::Handlers;
use super::invariants::InvariantCheck;
use super::log::Logger;
use super::observe::Events;
use super::program_state::ProgramState;
use super::records::Records;
use super::registry::Devices;
use super::safety::Safety;
use super::watched_image::WatchedImage;
use crate::time::clock::SharedClock;
use crate::time::zone::Zone;
use std::time::Duration;

/// The state of one run.
pub struct Runtime<H> {
    /// The clock and the tick.
    pub(super) cycle: Cycle,
    /// The devices, in name order, and what reads them (`registry`).
    pub(super) devices: Devices,
    /// What the script set up: handlers, timers, invariants, its stop request.
    pub(super) program: ProgramState<H>,
    /// The log, the records and the event stream.
    pub(super) figures: Figures,
    /// Held safe, the grace time, the stop's cancel, the link watch (`safety`).
    pub(super) safety: Safety,
    /// The operator's forces (`forcing`), when rig.toml allows them.
    pub(super) forces: Forces,
    /// Who watches, and the image read for them (`watched_image`).
    pub(super) image: WatchedImage,
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
        let cycle = Cycle::new(clock, zone);
        let started = cycle.started();
        Self {
            cycle,
            devices: Devices::new(devices, transactions),
            program: ProgramState::new(zone),
            figures: Figures::new(records, log),
            safety: Safety::new(grace, started),
            forces: Forces::default(),
            image: WatchedImage::default(),
        }
    }

    /// Monotonic now.
    pub fn now(&self) -> Duration {
        self.cycle.now()
    }

    /// The run's clock and tick.
    pub fn cycle(&self) -> &Cycle {
        &self.cycle
    }

    /// The devices, in name order, and what reads them.
    pub fn devices(&self) -> &Devices {
        &self.devices
    }

    /// Takes the modules not under control yet out of the run (`Devices::take_out_uncontrolled`).
    pub fn take_out_uncontrolled(&mut self) -> Vec<Device> {
        self.devices.take_out_uncontrolled()
    }

    /// Whether every device is held at its safe state: one has been lost for longer than its
    /// grace time and not all are back.
    pub fn held_safe(&self) -> bool {
        self.safety.held()
    }

    /// When the next tick has something to do, if no handler polls inputs: the earliest
    /// timer or retry of a lost device, or now while outputs wait to be written (a refused
    /// write is tried again at the next tick; watchdogs are fed between ticks). `None` when every
    /// tick has work: a handler polls inputs, or an invariant read device inputs when last
    /// evaluated (an invariant that reads only outputs, script state or time can change only
    /// in a tick that runs anyway, and is checked in every tick that runs). The script's own
    /// schedule: the reads for those watching the rig are the runner's to add.
    pub fn idle_until(&self) -> Option<Duration> {
        if self.program.polls_inputs() {
            return None;
        }
        let now = self.now();
        if self.outputs_pending() {
            return Some(now);
        }
        let timer = self.program.handlers().next_timer(now, self.cycle.wall());
        let upkeep = self.next_retry();
        let next = [timer, upkeep].into_iter().flatten().min();
        Some(next.unwrap_or(Duration::MAX))
    }

    /// How often the loop ticks while the script's handlers stay as they are: every `period`
    /// while a handler polls inputs, else at its fastest `every` (no faster than the period);
    /// `None` when only single timers, cron or upkeep wake it.
    pub fn tick_interval(&self, period: Duration) -> Option<Duration> {
        let handlers = self.program.handlers();
        if handlers.polls_inputs() {
            return Some(period);
        }
        handlers.fastest_every().map(|every| every.max(period))
    }

    /// The log, to write a line to.
    pub fn log_mut(&mut self) -> &mut Logger {
        self.figures.log_mut()
    }

    /// The run's event stream.
    pub fn events(&self) -> &Events {
        self.figures.events()
    }

    /// The log lines kept (by a run that keeps them: tests, the JUnit report), oldest first.
    pub fn log_lines(&self) -> &[String] {
        self.figures.log().lines()
    }

    /// Closes the log, with a bounded wait for its last lines; how many lines it dropped.
    pub fn close_log(&mut self) -> u64 {
        self.figures.close_log()
    }

    /// The script's handlers and timers, to look at (`verify`'s coverage and profile).
    pub fn handlers(&self) -> &Handlers<H> {
        self.program.handlers()
    }

    /// What the script set up.
    pub fn program(&self) -> &ProgramState<H> {
        &self.program
    }

    /// The handler about to run is `label` (its buffer kept: this is every call).
    pub(super) fn set_cause(&mut self, label: &str) {
        self.program.set_cause(label);
        // What a watcher names if the loop stalls in it.
        crate::guardian::pulse::handler(label);
    }

    /// The invariants the script stated, in that order.
    pub fn invariants(&self) -> &[InvariantCheck<H>] {
        self.program.invariants()
    }

    /// Caps the timers the script may have at once (its limits).
    pub fn limit_timers(&mut self, max: usize) {
        self.program.handlers_mut().set_max_timers(max);
    }

    /// Drops every handler, timer and invariant, and with them the script's closures that
    /// hold handles to this runtime (a cycle of `Rc`s otherwise).
    pub fn forget_handlers(&mut self) {
        self.program.forget();
    }

    /// Something that changes when handlers come or go (their count and the next id).
    pub fn handlers_signature(&self) -> (usize, u64) {
        self.program.handlers().signature()
    }

    /// The script's `stop(code)`: the run ends at the end of this tick with `code`; the first
    /// request made stands.
    pub fn request_stop(&mut self, code: i64) {
        self.program.request_stop(code);
    }

    /// The exit status the script asked to stop with, if it did.
    pub fn stop_requested(&self) -> Option<i64> {
        self.program.stop_requested()
    }

    /// What the script wants of each device's outputs: a C29U's byte, a TRC1000's relay (a
    /// reload that fails puts it back).
    pub fn wanted_outputs(&self) -> Vec<u8> {
        self.devices
            .iter()
            .map(|d| match d {
                super::devices::Device::Trc(t) => t.wanted_relay(),
                super::devices::Device::C29u(c) => c.wanted_outputs(),
            })
            .collect()
    }

    /// Wants `wanted` again (from `wanted_outputs`).
    pub fn want_outputs(&mut self, wanted: &[u8]) {
        for (idx, value) in wanted.iter().enumerate() {
            match self.devices.get(idx) {
                Some(super::devices::Device::Trc(_)) => self.set_relay(idx, *value),
                Some(super::devices::Device::C29u(_)) => self.set_outputs(idx, *value),
                None => {}
            }
        }
    }

    /// Forgets every handler and timer and the script's outputs (back to the safe values),
    /// before the script is started again.
    pub fn reset_program(&mut self) {
        self.program.reset();
        self.reset_outputs();
    }
}

#[cfg(test)]
mod tests {
    use crate::runtime::handlers::Source;
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
        r.rt.cycle.next_tick();
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
        assert!(r.rt.handlers().is_empty());
        assert!(!r.rt.has_work());
        assert_eq!(r.rt.stop_requested(), None);
        assert_eq!(r.rt.devices.c29u(IO).unwrap().wanted_outputs(), 0x05);
        assert_eq!(r.rt.devices.trc(PANEL).unwrap().wanted_relay(), 3);
    }

    #[test]
    fn uptime_and_wall_time_come_from_the_runs_clock() {
        let r = TestRig::started();
        r.clock.advance(Duration::from_millis(1500));
        assert_eq!(r.rt.cycle().uptime(), Duration::from_millis(1500));
        assert_eq!(r.rt.cycle().wall_text(), "1970-01-01T00:00:01.500+00:00");
    }
}
