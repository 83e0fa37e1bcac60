//! The script's side of its handlers: what `on`, `every`, `after`, `cron`, `on_stop` and
//! `cancel` do to the run (the handlers themselves are kept in `handlers`; the script asks
//! through `script_context`).

use super::handlers::{Call, Source, TooManyStopHandlers, MAX_STOP_HANDLERS};
use super::schedule::ScheduleError;
use super::state::Runtime;
use std::time::Duration;

/// The script's side: what its registrations do to the run's handlers.
impl<H: Clone> Runtime<H> {
    /// `on_stop(fn)`; refused past `MAX_STOP_HANDLERS`.
    pub fn on_stop(&mut self, handler: H) -> Result<u64, TooManyStopHandlers> {
        if self.handlers().stop_count() >= MAX_STOP_HANDLERS {
            return Err(TooManyStopHandlers);
        }
        Ok(self
            .program
            .handlers_mut()
            .add(Source::Stop, handler, "on_stop".into()))
    }

    /// Adds a handler; returns its id.
    pub fn subscribe(&mut self, source: Source, handler: H, label: String) -> u64 {
        self.program.handlers_mut().add(source, handler, label)
    }

    /// `every(period, fn)`.
    pub fn every(&mut self, period: Duration, handler: H) -> Result<u64, ScheduleError> {
        let now = self.now();
        self.program.handlers_mut().every(period, now, handler)
    }

    /// `after(delay, fn)`.
    pub fn after(&mut self, delay: Duration, handler: H) -> Result<u64, ScheduleError> {
        let now = self.now();
        self.program.handlers_mut().after(delay, now, handler)
    }

    /// `cron(expr, fn)`.
    pub fn cron(&mut self, expr: &str, handler: H) -> Result<u64, ScheduleError> {
        let wall = self.cycle().wall();
        self.program.handlers_mut().cron(expr, wall, handler)
    }

    /// Removes a handler or timer; false if there is none with that id.
    pub fn cancel(&mut self, id: u64) -> bool {
        self.program.handlers_mut().cancel(id)
    }

    /// Whether the script still waits for anything (handlers other than `on_stop`, timers).
    pub fn has_work(&self) -> bool {
        self.handlers().has_work()
    }

    /// The `on_stop` handlers, in the order they were added.
    pub fn stop_calls(&self) -> Vec<Call<H>> {
        self.handlers().stop_calls()
    }
}
