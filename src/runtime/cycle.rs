//! The run's time as the scan loop counts it: the one clock, the zone, when the run started,
//! the tick number and the period boundary the current tick runs for. The runner moves it on
//! (`begin_tick`); everything else only reads it.

use crate::time::clock::SharedClock;
use crate::time::zone::Zone;
use chrono::{DateTime, Utc};
use std::time::Duration;

/// The run's clock and tick.
pub struct Cycle {
    /// The one source of time.
    clock: SharedClock,
    /// The zone of cron, `now()` and the log.
    zone: Zone,
    /// Monotonic time the run started.
    started: Duration,
    /// The current tick (0 while the top level runs at start).
    tick: u64,
    /// The period boundary the current tick runs for (at or before its start): timer
    /// deadlines are counted up to it, so one that passes while the tick runs falls to the
    /// next tick (see `Schedule::due_at_tick`).
    boundary: Option<Duration>,
}

impl Cycle {
    /// A run on `clock` starting now, before its first tick.
    pub fn new(clock: SharedClock, zone: Zone) -> Self {
        let started = clock.now();
        Self {
            clock,
            zone,
            started,
            tick: 0,
            boundary: None,
        }
    }

    /// Starts the next tick, for the period boundary `boundary`.
    pub fn begin_tick(&mut self, boundary: Duration) {
        self.tick = self.tick.saturating_add(1);
        self.boundary = Some(boundary);
    }

    /// Monotonic now.
    pub fn now(&self) -> Duration {
        self.clock.now()
    }

    /// Wall time now.
    pub fn wall(&self) -> DateTime<Utc> {
        self.clock.wall()
    }

    /// Wall time now in the run's zone, as RFC 3339 with milliseconds.
    pub fn wall_text(&self) -> String {
        self.zone
            .at(self.clock.wall())
            .to_rfc3339_opts(chrono::SecondsFormat::Millis, false)
    }

    /// The run's clock, for what measures time on it.
    pub fn clock(&self) -> &SharedClock {
        &self.clock
    }

    /// The zone of cron, `now()` and the log.
    pub fn zone(&self) -> Zone {
        self.zone
    }

    /// Monotonic time the run started.
    pub fn started(&self) -> Duration {
        self.started
    }

    /// How long the run has been going.
    pub fn uptime(&self) -> Duration {
        self.now().saturating_sub(self.started)
    }

    /// The current tick (0 while the top level runs at start).
    pub fn tick(&self) -> u64 {
        self.tick
    }

    /// The period boundary the current tick runs for (`None` before the first tick).
    pub fn boundary(&self) -> Option<Duration> {
        self.boundary
    }

    /// Moves to the next tick keeping the boundary, as a test that drives the parts by hand.
    #[cfg(test)]
    pub fn next_tick(&mut self) {
        self.tick += 1;
    }

    /// Sets the boundary of the current tick, as a test that drives the parts by hand.
    #[cfg(test)]
    pub fn set_boundary(&mut self, boundary: Duration) {
        self.boundary = Some(boundary);
    }
}
