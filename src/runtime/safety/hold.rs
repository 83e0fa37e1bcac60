//! The run's safety state, kept next to the policy that changes it: whether every output is
//! held safe, the grace time, what cuts exchanges short once the run stops, and when the
//! links are next asked whether they ended.

use super::liveness::{LEAST_PROBE_INTERVAL, LINK_WATCH_INTERVAL};
use crate::device::cancel::Cancel;
use std::time::Duration;

/// The run's safety state (a part of `Runtime`).
pub struct Safety {
    /// A device has been lost for longer than its grace time: every device is held at its
    /// safe state until all are back.
    held: bool,
    /// How long a device may be lost before everything goes safe.
    grace: Duration,
    /// What cuts the devices' exchanges short: the run's stop flag while it runs;
    /// supervision also stops trying lost devices once it is set.
    cancel: Cancel,
    /// When the links are next asked whether they ended (`liveness`).
    next_link_watch: Duration,
    /// Whether a device's link has a descriptor the OS tells its end on (until the first
    /// look, assumed so).
    has_link_watch: bool,
}

impl Safety {
    /// Nothing held, with `grace`, the links first asked at `started`.
    pub fn new(grace: Duration, started: Duration) -> Self {
        Self {
            held: false,
            grace,
            cancel: Cancel::never(),
            next_link_watch: started,
            has_link_watch: true,
        }
    }

    /// Whether every device is held at its safe state.
    pub fn held(&self) -> bool {
        self.held
    }

    /// Holds every device at its safe state, or lets go.
    pub(in crate::runtime) fn set_held(&mut self, held: bool) {
        self.held = held;
    }

    /// How long a device may be lost before everything goes safe.
    pub fn grace(&self) -> Duration {
        self.grace
    }

    /// How long a device may go without an answer before it is asked one: a quarter of the
    /// grace time, so that a device lost while idle is noticed within half of it even when
    /// the question takes its retries (three tries of a 100 ms timeout, with the silence after
    /// each, take half a second: grace 1 s then holds the rest safe within 2 s of the loss).
    pub fn probe_interval(&self) -> Duration {
        (self.grace / 4).max(LEAST_PROBE_INTERVAL)
    }

    /// Whether the run is stopping (its exchanges are cut short).
    pub fn stopping(&self) -> bool {
        self.cancel.is_cancelled()
    }

    /// Keeps `cancel` as what says the run is stopping.
    pub(in crate::runtime) fn set_cancel(&mut self, cancel: &Cancel) {
        self.cancel = cancel.clone();
    }

    /// When the links are next to be asked (`None`: no link can be).
    pub fn next_link_watch(&self) -> Option<Duration> {
        self.has_link_watch.then_some(self.next_link_watch)
    }

    /// Whether the links are to be asked at `now`; if so, the next time is set.
    pub(in crate::runtime) fn link_watch_due(&mut self, now: Duration) -> bool {
        let due = now >= self.next_link_watch;
        if due {
            self.next_link_watch = now.saturating_add(LINK_WATCH_INTERVAL);
        }
        due
    }

    /// Whether some device's link can be watched (`has`), found at a look.
    pub(in crate::runtime) fn note_link_watch(&mut self, has: bool) {
        self.has_link_watch = has;
    }
}
