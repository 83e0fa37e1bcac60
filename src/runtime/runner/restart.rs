//! The error policy applied to a failed handler, and the script started again with back-off.

use super::contract::{describe, EndReason, HandlerFault, Program};
use super::{Runner, State};
use crate::config::ErrorPolicy;
use crate::runtime::observe::RunEvent;
use std::time::Duration;

/// The first wait before a script is started again under policy `restart`; it doubles with
/// each failure in a row, up to `MAX_BACKOFF`.
pub const FIRST_BACKOFF: Duration = Duration::from_secs(1);

/// The longest wait before a restart.
pub const MAX_BACKOFF: Duration = Duration::from_secs(60);

/// A script that ran this long without failing starts its back-off afresh.
pub const BACKOFF_RESET: Duration = Duration::from_secs(60);

impl<P: Program> Runner<P> {
    /// Applies the error policy to a failed handler; true if the tick goes on.
    pub(super) fn handle_fault(&mut self, fault: &HandlerFault, label: &str) -> bool {
        let message = describe(fault, label);
        self.note_fault(&message, fault.over_budget);
        // Within a reload's rollback window, the old script takes over again; this tick's
        // other calls were the failed script's.
        if self.roll_back(&message) {
            return false;
        }
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
                    .log_mut()
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
        rt.log_mut().error(message);
        rt.write_safe_state("script error");
        rt.reset_program();
        rt.log_mut().notice(&format!(
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
            after_ms: crate::runtime::snapshot::millis(wait),
        });
    }

    pub(super) fn restart(&mut self) {
        self.state = State::Running;
        self.restarts = self.restarts.saturating_add(1);
        self.last_start = self.clock.now();
        {
            let mut rt = self.rt.borrow_mut();
            rt.reset_program();
            rt.set_cause("top level");
            rt.log_mut().notice("starting the script again");
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
}
