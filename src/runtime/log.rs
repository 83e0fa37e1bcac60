//! What the runner tells the operator as it runs: one timestamped line per event handled,
//! output written, timer fired, script message, warning or error; to stderr, and kept in
//! memory for scenario tests.

use crate::time::clock::SharedClock;
use crate::time::zone::Zone;
use std::io::Write;

/// Lines kept in memory at most (the oldest go first), so a long run cannot grow without bound.
pub const MAX_KEPT_LINES: usize = 10_000;

/// How much a line matters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Level {
    /// What the script is doing (events, outputs, timers); left out with `--quiet`.
    Activity,
    /// The script's own `print` and `log`, and the runner's notices.
    Info,
    /// Something the operator should look at.
    Warn,
    /// A failure.
    Error,
}

/// The runner's log.
pub struct Logger {
    clock: SharedClock,
    zone: Zone,
    to_stderr: bool,
    quiet: bool,
    kept: Option<Vec<String>>,
}

impl Logger {
    /// A log stamped with `clock`'s wall time in `zone`, written to stderr if `to_stderr`.
    pub fn new(clock: SharedClock, zone: Zone, to_stderr: bool) -> Self {
        Self {
            clock,
            zone,
            to_stderr,
            quiet: false,
            kept: None,
        }
    }

    /// Leaves out activity lines (warnings, errors and script messages still show).
    pub fn set_quiet(&mut self, quiet: bool) {
        self.quiet = quiet;
    }

    /// Keeps lines in memory too (scenario tests read them back).
    pub fn keep_lines(&mut self) {
        if self.kept.is_none() {
            self.kept = Some(Vec::new());
        }
    }

    /// The lines kept so far (empty unless `keep_lines` was called).
    pub fn lines(&self) -> &[String] {
        self.kept.as_deref().unwrap_or(&[])
    }

    /// Writes one line at `level`.
    pub fn line(&mut self, level: Level, message: &str) {
        if level == Level::Activity && self.quiet {
            return;
        }
        let stamp = self.zone.at(self.clock.wall()).format("%H:%M:%S%.3f");
        let line = match level {
            Level::Activity | Level::Info => format!("{stamp} {message}"),
            Level::Warn => format!("{stamp} warning: {message}"),
            Level::Error => format!("{stamp} error: {message}"),
        };
        if self.to_stderr {
            // A closed stderr must not stop the rig; the line is simply lost.
            let _ = writeln!(std::io::stderr().lock(), "{line}");
        }
        if let Some(kept) = &mut self.kept {
            if kept.len() >= MAX_KEPT_LINES {
                kept.remove(0);
            }
            kept.push(line);
        }
    }

    /// An activity line.
    pub fn activity(&mut self, message: &str) {
        self.line(Level::Activity, message);
    }

    /// An information line.
    pub fn info(&mut self, message: &str) {
        self.line(Level::Info, message);
    }

    /// A warning line.
    pub fn warn(&mut self, message: &str) {
        self.line(Level::Warn, message);
    }

    /// An error line.
    pub fn error(&mut self, message: &str) {
        self.line(Level::Error, message);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::time::clock::VirtualClock;
    use chrono::{TimeZone, Utc};
    use std::sync::Arc;
    use std::time::Duration;

    #[test]
    fn lines_carry_the_wall_time_in_the_zone_and_quiet_drops_only_activity() {
        let clock = VirtualClock::new(Utc.with_ymd_and_hms(2026, 3, 28, 12, 0, 1).unwrap());
        clock.advance(Duration::from_millis(20));
        let mut log = Logger::new(
            Arc::new(clock),
            Zone::parse("Europe/Amsterdam").unwrap(),
            false,
        );
        log.keep_lines();
        log.activity("io: outputs 0x00 -> 0x05");
        log.warn("late");
        log.set_quiet(true);
        log.activity("hidden");
        log.error("broken");
        assert_eq!(
            log.lines(),
            [
                "13:00:01.020 io: outputs 0x00 -> 0x05",
                "13:00:01.020 warning: late",
                "13:00:01.020 error: broken"
            ]
        );
    }
}
