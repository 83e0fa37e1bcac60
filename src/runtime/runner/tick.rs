//! One scan tick: supervision, handlers, invariants, the writes and feeds, the next deadline.

use super::contract::{describe, EndReason, Program};
use super::{Runner, State};
use crate::guardian::pulse::{self, Phase};
use crate::runtime::handlers::Call;
use crate::runtime::invariants::{InvariantCheck, Violation, MAX_INVARIANTS};
use crate::runtime::observe::{EventKind, RunEvent};
use crate::runtime::snapshot::micros;
use std::time::Duration;

/// How often each device is checked (`Runtime::check_devices`: a module reset, swapped or
/// changed behind the runner's back, or outputs that do not read as written, are set right
/// within this time) and the relays selected again.
pub const CHECK_INTERVAL: Duration = Duration::from_secs(5);

impl<P: Program> Runner<P> {
    /// One scan tick at the current time.
    pub fn tick(&mut self) {
        self.guarded(Self::scan_tick);
    }

    fn scan_tick(&mut self) {
        if self.status().is_some() {
            return;
        }
        pulse::enter(Phase::Tick);
        let start = self.clock.now();
        let transactions_before = self.rt.borrow().devices.transaction_count();
        self.stats.ticks = self.stats.ticks.saturating_add(1);
        self.stats
            .jitter
            .add(start.saturating_sub(self.next_deadline));
        {
            self.rt
                .borrow_mut()
                .cycle
                .begin_tick(self.next_deadline.min(start));
        }
        if let Some(periods) = self.woken.take() {
            self.tell_woken(periods, start.saturating_sub(self.next_deadline));
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
        // A reload swaps at this tick boundary (refused unless the script runs); the new
        // script's handlers run at once.
        self.reload_waiting();
        match self.state {
            State::Restarting { at } if start >= at => self.restart(),
            State::Running if self.status().is_none() => self.run_handlers(),
            _ => {}
        }
        // A command or a watched message waiting from outside runs after the tick's own
        // handlers, one command a tick: this tick's invariants and writes follow it.
        if self.status().is_none() && self.stop_signal().is_none() {
            self.run_waiting();
        }
        // A signal that came during the handlers ends the run before the tick's writes: the
        // end writes the safe state anyway, and each exchange could be a silent module's.
        if self.status().is_some() || self.ended_by_signal() {
            return;
        }
        if self.state == State::Running && !self.check_invariants() {
            return;
        }
        let stop = self.rt.borrow().stop_requested();
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
            // Last, in what the tick leaves of its period: the inputs the script did not read,
            // for whoever watches (`watched_image`).
            let period = self.options.period;
            rt.read_for_watchers(self.next_deadline.saturating_add(period), period);
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
            .devices
            .transaction_count()
            .saturating_sub(transactions_before);
        self.stats.transactions = self.stats.transactions.saturating_add(spent);
        self.stats.max_transactions = self.stats.max_transactions.max(spent);
        let deadline = self.next_deadline;
        let woken = self.schedule_next(end);
        self.woken = woken.map(|at| self.periods_after_last(at));
        let tick = self.stats.ticks;
        let overrun = end > deadline.saturating_add(self.options.period);
        let late_us = || micros(start.saturating_sub(deadline));
        let work_us = || micros(end.saturating_sub(start));
        if self.events.wants(EventKind::Tick) {
            self.events.publish(|| RunEvent::Tick {
                tick,
                late_us: late_us(),
                work_us: work_us(),
                overrun,
            });
        }
        if overrun && self.events.wants(EventKind::Overrun) {
            self.events.publish(|| RunEvent::Overrun {
                tick,
                late_us: late_us(),
                work_us: work_us(),
            });
        }
        // What comes from here on (requests, the wait's upkeep) belongs to the next tick.
        self.events.in_tick(tick.saturating_add(1));
        self.answer_requests();
    }

    /// Moves the deadline one period on; past it already, counts an overrun and skips to the
    /// first period boundary after `now`. When no handler polls inputs, ticks that would have
    /// nothing to do are skipped too: the next deadline is the first period boundary at or
    /// after the next timer, watchdog feed, device check, retry, pending write, end, or read
    /// for those watching the rig (idle runs cost no CPU, and a day of a cron script in virtual
    /// time takes a moment). Returns the deadline when it is sooner than the script's own
    /// schedule has one, for the watchers alone (told as `RunEvent::Woken`).
    fn schedule_next(&mut self, now: Duration) -> Option<Duration> {
        let period = self.options.period.max(Duration::from_micros(1));
        self.next_deadline = self.next_deadline.saturating_add(period);
        if now > self.next_deadline {
            self.stats.overruns = self.stats.overruns.saturating_add(1);
            // Already late: the next tick starts at once, on the last boundary passed.
            self.next_deadline =
                boundary_at_or_after(self.next_deadline, period, now).saturating_sub(period);
        }
        let (idle, own) = self.idle_until()?;
        let deadline = self.next_deadline;
        let after = |t: Duration| {
            if t > deadline {
                boundary_at_or_after(deadline, period, t)
            } else {
                deadline
            }
        };
        self.next_deadline = after(idle);
        (self.next_deadline < after(own)).then_some(self.next_deadline)
    }

    /// When the next tick has work, if no handler polls inputs (see `schedule_next`): with
    /// the reads for those watching the rig, and without them (the script's own schedule).
    fn idle_until(&self) -> Option<(Duration, Duration)> {
        let rt = self.rt.borrow();
        let mut own = rt.idle_until()?;
        own = own.min(self.last_check.saturating_add(CHECK_INTERVAL));
        if let State::Restarting { at } = self.state {
            own = own.min(at);
        }
        if let Some(end) = self.options.end_after {
            own = own.min(rt.cycle().started().saturating_add(end));
        }
        let watched = rt.next_watched_read(rt.now());
        Some((watched.map_or(own, |w| w.min(own)), own))
    }

    /// Periods from the last tick's boundary to `at`: a replay's ticks keep their own phase
    /// (from when its top level ended), not the run's, so a tick is placed from the one before.
    pub(super) fn periods_after_last(&self, at: Duration) -> u64 {
        let last = self.rt.borrow().cycle().boundary().unwrap_or(at);
        let period = self.options.period.max(Duration::from_micros(1));
        let periods = at.saturating_sub(last).as_nanos() / period.as_nanos();
        u64::try_from(periods).unwrap_or(u64::MAX)
    }

    /// Tells that this tick was brought sooner than the script's schedule had one, for
    /// someone outside the loop, and how late it started (`RunEvent::Woken`: a journal keeps
    /// it so that its replay makes the same tick, timers due by its start firing in it).
    fn tell_woken(&self, periods: u64, late: Duration) {
        if self.events.wants(EventKind::Woken) {
            self.events.publish(|| RunEvent::Woken {
                periods,
                late_us: micros(late),
            });
        }
    }

    /// Runs the tick's handlers one by one; a signal that comes meanwhile ends the run before
    /// the next one (a tick with thousands of timers due must not delay SIGTERM).
    fn run_handlers(&mut self) {
        let mut calls = self.rt.borrow_mut().collect_calls();
        let any = !calls.is_empty();
        self.run_calls(&mut calls);
        if any {
            pulse::enter(Phase::Tick);
        }
        self.rt.borrow_mut().reuse_calls(calls);
    }

    /// Makes the tick's calls, in order (see `run_handlers`).
    fn run_calls(&mut self, calls: &mut Vec<Call<P::Handler>>) {
        for call in calls.drain(..) {
            {
                let mut rt = self.rt.borrow_mut();
                // A handler's own work is not an exchange; feed what fell due meanwhile.
                rt.feed_watchdogs();
                rt.set_cause(&call.label);
            }
            let result = self.program.call(&call);
            if let Err(f) = result {
                if self.stop_signal().is_some() {
                    // The signal came while the handler ran, and the run ends by it; the
                    // error is told (often of the same cause: an exchange the stop cut, a
                    // write past the file size limit as SIGXFSZ came).
                    let message = describe(&f, &call.label);
                    self.note_fault(&message, f.over_budget);
                    self.rt.borrow_mut().log_mut().error(&message);
                    return;
                }
                if !self.handle_fault(&f, &call.label) {
                    return;
                }
            }
            if self.rt.borrow().stop_requested().is_some() || self.stop_signal().is_some() {
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
        let accesses = self.rt.borrow().devices.input_accesses();
        for check in checks.iter() {
            self.rt.borrow_mut().set_cause(&check.call.label);
            match self.program.holds(check) {
                Ok(true) => {}
                Ok(false) => {
                    let violation = {
                        let rt = self.rt.borrow();
                        Violation {
                            name: check.name.clone(),
                            at: check.at.clone(),
                            uptime: rt.cycle().uptime(),
                            devices: rt.readings(),
                        }
                    };
                    let message = violation.to_string();
                    self.note_invariant_failed(&violation.name, violation.uptime, &checks);
                    // Within a reload's rollback window: the old script, its invariants
                    // checked instead, and the outputs it wanted.
                    if self.roll_back(&message) {
                        return self.check_invariants();
                    }
                    self.rt.borrow_mut().report_violation(&violation);
                    self.violation = Some(violation);
                    self.finish(EndReason::Violated(message));
                    return false;
                }
                Err(f) => {
                    let message = describe(&f, &check.call.label);
                    self.note_fault(&message, f.over_budget);
                    if self.roll_back(&message) {
                        return self.check_invariants();
                    }
                    self.finish(EndReason::Error(message));
                    return false;
                }
            }
        }
        {
            let mut rt = self.rt.borrow_mut();
            let read = rt.devices.input_accesses() != accesses;
            rt.program.note_invariants_read_inputs(read);
        }
        // The script's outputs keep its promises; so must the outputs written with forces.
        self.judge_forces();
        true
    }
}

impl<P: Program> Runner<P> {
    /// Keeps when the invariant `name` was last found false (`at`, the run's uptime) for the
    /// snapshot; names no invariant of `checks` states go once there are too many (reloads).
    fn note_invariant_failed(
        &mut self,
        name: &str,
        at: Duration,
        checks: &[InvariantCheck<P::Handler>],
    ) {
        let failed = &mut self.invariants_failed;
        failed.insert(name.to_string(), at);
        if failed.len() > MAX_INVARIANTS {
            failed.retain(|n, _| checks.iter().any(|c| c.name == *n));
        }
    }
}

/// The first of the deadlines `start + k * period` that is at or after `t`.
pub(super) fn boundary_at_or_after(start: Duration, period: Duration, t: Duration) -> Duration {
    if t <= start {
        return start;
    }
    let behind = t.saturating_sub(start).as_nanos();
    let periods = behind.div_ceil(period.as_nanos().max(1));
    let skip = u32::try_from(periods).unwrap_or(u32::MAX);
    start.saturating_add(period.saturating_mul(skip))
}
