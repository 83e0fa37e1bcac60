//! What the run tells: the log, the records and measurements, and the stream of events
//! (`observe`) both feed. The runtime composes it; each line and record goes through it.

use super::log::Logger;
use super::observe::Events;
use super::records::{Limits, Records};
use serde_json::Value;

/// The run's log, records and event stream.
pub struct Figures {
    /// Records and measurements.
    records: Records,
    /// The log.
    log: Logger,
    /// Where what happens is told to whoever watches the run (the log's stream: its lines
    /// and everything else in one order).
    events: Events,
}

impl Figures {
    /// The figures of a run that logs to `log` and records to `records`.
    pub fn new(records: Records, log: Logger) -> Self {
        let events = log.events().clone();
        Self {
            records,
            log,
            events,
        }
    }

    /// The log.
    pub fn log(&self) -> &Logger {
        &self.log
    }

    /// The log, to write a line to.
    pub fn log_mut(&mut self) -> &mut Logger {
        &mut self.log
    }

    /// The records and measurements.
    pub fn records(&self) -> &Records {
        &self.records
    }

    /// The run's event stream.
    pub fn events(&self) -> &Events {
        &self.events
    }

    /// One record stamped `time`.
    pub fn record(&mut self, time: &str, name: &str, value: Value) {
        self.records.record(time, name, value, &mut self.log);
    }

    /// One measurement stamped `time`, logged with its limits; whether it is within them.
    pub fn measure(&mut self, time: &str, name: &str, value: f64, limits: &Limits) -> bool {
        let pass = self
            .records
            .measure(time, name, value, limits, &mut self.log);
        let unit = limits.unit.as_deref().unwrap_or("");
        let range = match (limits.min, limits.max) {
            (Some(a), Some(b)) => format!(" [{a}, {b}]"),
            (Some(a), None) => format!(" [>= {a}]"),
            (None, Some(b)) => format!(" [<= {b}]"),
            (None, None) => String::new(),
        };
        let line = format!(
            "measure {name} = {value}{unit}{range}: {}",
            if pass { "pass" } else { "FAIL" }
        );
        if pass {
            self.log.activity(&line);
        } else {
            self.log.warn(&line);
        }
        pass
    }

    /// Closes the records file with a bounded wait for what is queued; the records it did not
    /// take.
    pub fn close_records(&mut self) -> u64 {
        self.records.close(&mut self.log)
    }

    /// Closes the log, with a bounded wait for its last lines; how many lines it dropped.
    pub fn close_log(&mut self) -> u64 {
        self.log.close();
        self.log.dropped()
    }
}
