//! Ending a run: `on_stop` handlers within their budget, the safe state, the exit status and
//! what went wrong on the way; the safe state after a panic.

use super::contract::{describe, EndReason, Program, Shared, StopLimit};
use super::{Runner, State};
use crate::device::cancel::Cancel;
use crate::runtime::exit;
use crate::runtime::handlers::STOP_BUDGET;
use crate::runtime::observe::RunEvent;
use crate::runtime::signals;
use signal_hook::consts::SIGTERM;
use std::io::Write;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

impl<P: Program> Runner<P> {
    /// Ends the run if `--for` is over; true if it did.
    pub(super) fn end_if_over(&mut self) -> bool {
        let Some(end) = self.options.end_after else {
            return false;
        };
        if self.status().is_some() || self.rt.borrow().cycle().uptime() < end {
            return false;
        }
        self.finish(EndReason::Finished(format!(
            "ran for {}",
            crate::time::duration::format_duration(end)
        )));
        true
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
                EndReason::Error(m) => rt.log_mut().error(m),
                EndReason::Signal(n) => {
                    rt.log_mut().notice(&format!(
                        "stopping: {} received ({})",
                        signals::name(*n),
                        signals::likely_cause(*n)
                    ));
                }
                EndReason::Stopped(code) => {
                    rt.log_mut()
                        .notice(&format!("stopping: the script called stop({code})"));
                }
                EndReason::Finished(why) => rt.log_mut().notice(&format!("stopping: {why}")),
                EndReason::Requested(by) => {
                    rt.log_mut().notice(&format!("stopping: asked by {by}"))
                }
                // Logged with the tick's readings by `report_violation`.
                EndReason::Violated(_) => {}
            }
        }
        // Before on_stop: its handlers read the real inputs, and nothing forced is written.
        self.rt.borrow_mut().cancel_forces("the run is ending");
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
            .filter_map(|d| d.as_c29u().map(|c| c.refused_writes()))
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
        self.trouble.records_lost = r.figures.close_records();
        let failed = rt.figures.records().failed();
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
            Some(why) => rt.log_mut().warn(&format!("{why}: exit status {status}")),
            None => rt
                .log_mut()
                .notice(&format!("stopped; exit status {status}")),
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
        self.refuse_waiting();
        self.served = None;
    }

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
                self.rt.borrow_mut().log_mut().warn(&format!(
                    "{why}: {left} on_stop handler(s) skipped, straight to the safe state"
                ));
                if signal == 0 {
                    self.trouble.on_stop_failed =
                        self.trouble.on_stop_failed.saturating_add(left as u64);
                }
                return;
            }
            self.rt.borrow_mut().set_cause(&call.label);
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
                    self.rt.borrow_mut().log_mut().warn(&format!(
                        "{}: cut off by {} while stopping",
                        call.label,
                        signals::name(signal)
                    ));
                }
                Err(f) => {
                    let message = describe(&f, &call.label);
                    self.note_fault(&message, f.over_budget);
                    self.rt.borrow_mut().log_mut().error(&message);
                    self.trouble.on_stop_failed = self.trouble.on_stop_failed.saturating_add(1);
                }
                Ok(()) => {}
            }
        }
    }
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
        rt.log_mut().error(&format!(
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
