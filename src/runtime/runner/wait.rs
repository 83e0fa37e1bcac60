//! The waits between ticks: in slices that look at the stop flag and the control queue, doing
//! what falls due meanwhile (feeds, retries, a look at the links and idle devices, a grace
//! time's end, the end of `--for`); and the CPU wake-up latency asked for while the loop ticks
//! fast.

use super::contract::Program;
use super::Runner;
use crate::guardian::pulse::{self, Phase};
use crate::runtime::wake_latency;
use std::time::Duration;

/// How long the loop sleeps at most before it looks at the stop flag again, so that an ending
/// signal is handled promptly whatever the period.
pub const SLEEP_SLICE: Duration = Duration::from_millis(20);

impl<P: Program> Runner<P> {
    /// Notes how the request to wake the loop promptly went (`time::clock::prefer_prompt_wakeups`,
    /// asked once a run). Without these hints a tick starts 100-150 µs late as a rule and
    /// milliseconds late when other processes keep the CPUs busy; they are hints only, so a
    /// refusal (an old kernel, a sandbox) is logged once and the run goes on.
    pub(super) fn note_prompt_wakeups(&mut self, outcome: std::io::Result<()>) {
        let text = match outcome {
            Ok(()) => "granted".to_string(),
            Err(e) => {
                let text = format!("refused ({e})");
                self.rt.borrow_mut().log_mut().notice(&format!(
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
    pub(super) fn update_wake_latency(&mut self) {
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
            rt.log_mut().notice(
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
                rt.log_mut()
                    .notice(&format!("CPU wake-up latency {text}{every}"));
                self.latency.hold = Some(h);
            }
            _ => {
                self.latency.refused = true;
                rt.log_mut().notice(&format!(
                    "CPU wake-up latency {text}: ticks may start up to milliseconds late; \
                     give this user write access to it (packaging/udev/61-rigscript-wake-latency.rules) or set \
                     wake_latency = \"off\""
                ));
            }
        }
        self.stats.wake_latency = Some(text);
    }

    /// Sleeps to the next deadline in slices, waking early for the stop flag.
    pub(super) fn sleep_to_deadline(&mut self) {
        self.wait_until(self.next_deadline, true);
    }

    /// Waits until `target`, feeding the host watchdogs as their feeds fall due and trying lost
    /// devices as their retries do (each keeps its own deadline whatever the period); with
    /// `watch_stop`, in slices that look at the stop flag.
    pub(super) fn wait_until(&mut self, target: Duration, watch_stop: bool) {
        // A wait for the next tick follows it when a request's handler brings it nearer
        // (`tick_soon`); a wait for another time keeps to that time.
        let to_deadline = target == self.next_deadline;
        loop {
            let now = self.clock.now();
            self.events.turned();
            let target = if to_deadline {
                target.min(self.next_deadline)
            } else {
                target
            };
            if now >= target
                || (watch_stop && self.stop_signal().is_some())
                || self.status().is_some()
            {
                return;
            }
            let (feed, retry, grace, held, expiry, liveness) = {
                let rt = self.rt.borrow();
                // A retry already overdue waits for the tick (or was skipped while stopping).
                (
                    rt.next_feed(),
                    rt.next_retry().filter(|&due| due > now),
                    rt.grace_ends(),
                    rt.held_safe(),
                    rt.next_force_expiry(),
                    rt.next_liveness(self.next_deadline),
                )
            };
            let end = self.end_at();
            let mut until = target;
            if watch_stop {
                until = until.min(now.saturating_add(SLEEP_SLICE));
            }
            for due in [feed, retry, grace, end, expiry, liveness]
                .into_iter()
                .flatten()
            {
                until = until.min(due.max(now));
            }
            pulse::enter(Phase::Waiting);
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
            // A link the OS says has ended, or an idle device that no longer answers, is lost
            // now, not at the next device check (`safety::liveness`).
            let looked = liveness.is_some_and(|due| self.clock.now() >= due);
            if looked {
                self.guarded(|r| {
                    let now = r.clock.now();
                    let next_tick = r.next_deadline;
                    r.rt.borrow_mut().watch_liveness(now, next_tick);
                });
            }
            // The end of a grace time holds the outputs safe at once, not at the next tick
            // (with only a slow timer, that was the next output check, 5 s on).
            if retried || looked || grace.is_some_and(|due| self.clock.now() >= due) {
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
        Some(self.rt.borrow().cycle().started().saturating_add(end))
    }
}

/// The CPU wake-up latency request of a run, as it stands.
#[derive(Debug, Default)]
pub(super) struct LatencyRequest {
    /// The request held now.
    pub(super) hold: Option<wake_latency::LatencyHold>,
    /// The OS refused it once: not asked again.
    refused: bool,
    /// The handlers it was last worked out for.
    seen: Option<(usize, u64)>,
}
