//! A run's plan: where and when it starts, and the timed events the field and the faults play
//! on the simulated rig. Each event reads as a few words for people (`io DI2 off`, `panel S12
//! pressed`) and as one line of the scenario API for the test file that reproduces it.

use crate::protocol::trc1000::{Rotary, Switch};
use crate::time::duration::format_duration;
use chrono::{DateTime, FixedOffset};
use std::fmt;
use std::sync::Arc;
use std::time::Duration;

/// Counts from which a counter is near its wrap (65535, then 0).
pub const NEAR_WRAP: u16 = 65530;

/// One thing that happens to the rig.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Action {
    /// A TRP-C29U input energized or released.
    Input {
        /// Device name.
        dev: Arc<str>,
        /// Channel 0-7.
        ch: u8,
        /// Energized.
        on: bool,
    },
    /// All inputs of a TRP-C29U set at once.
    Inputs {
        /// Device name.
        dev: Arc<str>,
        /// Bit n = DIn energized.
        byte: u8,
    },
    /// Pulses on a TRP-C29U input (each leaves its level and comes back).
    Pulse {
        /// Device name.
        dev: Arc<str>,
        /// Channel 0-7.
        ch: u8,
        /// How many.
        n: u32,
    },
    /// Pulses that bring a counter up to `value` (none if it shows as much already): to a
    /// value the script compares it with, or to just below its 16-bit wrap.
    CounterTo {
        /// Device name.
        dev: Arc<str>,
        /// Channel 0-7.
        ch: u8,
        /// The count it ends at.
        value: u16,
    },
    /// A TRC1000 switch pressed.
    Press {
        /// Device name.
        dev: Arc<str>,
        /// Which switch.
        switch: Switch,
    },
    /// A TRC1000 switch released.
    Release {
        /// Device name.
        dev: Arc<str>,
        /// Which switch.
        switch: Switch,
    },
    /// A TRC1000 rotary turned.
    Turn {
        /// Device name.
        dev: Arc<str>,
        /// Which rotary.
        rotary: Rotary,
        /// Half-turns, negative the other way.
        half_turns: i32,
    },
    /// A device stops answering (cable pulled).
    Fail {
        /// Device name.
        dev: Arc<str>,
    },
    /// A device answers again.
    Restore {
        /// Device name.
        dev: Arc<str>,
    },
    /// A device's next answers are lost (the driver times out).
    DropAnswers {
        /// Device name.
        dev: Arc<str>,
        /// How many.
        n: u32,
    },
    /// A device's next answers arrive garbled.
    GarbleAnswers {
        /// Device name.
        dev: Arc<str>,
        /// How many.
        n: u32,
    },
    /// A device's next answers arrive late (given on time; past the driver's timeout they land
    /// in a later exchange's window).
    LateAnswers {
        /// Device name.
        dev: Arc<str>,
        /// How many.
        n: u32,
        /// How late each.
        by: Duration,
    },
    /// A device's next answers arrive twice.
    DuplicateAnswers {
        /// Device name.
        dev: Arc<str>,
        /// How many.
        n: u32,
    },
    /// A device reset or power cycled behind the runner's back (a module at its power-on
    /// value, a panel with its relay and counts at zero).
    PowerCycle {
        /// Device name.
        dev: Arc<str>,
    },
    /// The host stalls: time moves on with no tick (a watchdog may expire).
    Stall {
        /// For how long.
        by: Duration,
    },
    /// The wall clock steps (NTP, a manual change): cron sees it, `every` does not.
    WallStep {
        /// By how many seconds, negative back.
        seconds: i64,
    },
    /// SIGTERM.
    Stop,
}

/// Writes `+3` or `-3`.
fn signed(n: i64) -> String {
    if n >= 0 {
        format!("+{n}")
    } else {
        n.to_string()
    }
}

/// A wall-clock step as `"+1h"` / `"-90s"`.
pub fn wall_step_text(seconds: i64) -> String {
    let d = format_duration(Duration::from_secs(seconds.unsigned_abs()));
    if seconds < 0 {
        format!("-{d}")
    } else {
        format!("+{d}")
    }
}

impl fmt::Display for Action {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Action::Input { dev, ch, on } => {
                write!(f, "{dev} DI{ch} {}", if *on { "on" } else { "off" })
            }
            Action::Inputs { dev, byte } => write!(f, "{dev} inputs {byte:#04x}"),
            Action::Pulse { dev, ch, n } => write!(f, "{dev} DI{ch} {n} pulse(s)"),
            Action::CounterTo { dev, ch, value } => {
                write!(f, "{dev} counter DI{ch} carried to {value}")
            }
            Action::Press { dev, switch } => write!(f, "{dev} {switch} pressed"),
            Action::Release { dev, switch } => write!(f, "{dev} {switch} released"),
            Action::Turn {
                dev,
                rotary,
                half_turns,
            } => write!(
                f,
                "{dev} {} turned {}",
                rotary.name(),
                signed(i64::from(*half_turns))
            ),
            Action::Fail { dev } => write!(f, "{dev} lost"),
            Action::Restore { dev } => write!(f, "{dev} back"),
            Action::DropAnswers { dev, n } => write!(f, "{dev} {n} answer(s) lost"),
            Action::GarbleAnswers { dev, n } => write!(f, "{dev} {n} answer(s) garbled"),
            Action::LateAnswers { dev, n, by } => {
                write!(f, "{dev} {n} answer(s) {} late", format_duration(*by))
            }
            Action::DuplicateAnswers { dev, n } => write!(f, "{dev} {n} answer(s) sent twice"),
            Action::PowerCycle { dev } => write!(f, "{dev} power cycled"),
            Action::Stall { by } => write!(f, "host stalled {}", format_duration(*by)),
            Action::WallStep { seconds } => write!(f, "wall clock {}", wall_step_text(*seconds)),
            Action::Stop => f.write_str("stop signal"),
        }
    }
}

impl Action {
    /// Whether this is a fault rather than something a person or the process does.
    pub fn is_fault(&self) -> bool {
        matches!(
            self,
            Action::Fail { .. }
                | Action::Restore { .. }
                | Action::DropAnswers { .. }
                | Action::GarbleAnswers { .. }
                | Action::LateAnswers { .. }
                | Action::DuplicateAnswers { .. }
                | Action::PowerCycle { .. }
                | Action::Stall { .. }
                | Action::WallStep { .. }
                | Action::Stop
        )
    }

    /// What the action acts on, when something else in a plan may act on it too (an input, a
    /// switch, a rotary, a counter, a device's line, the clocks): events on the same thing may
    /// only shrink away together (a press and its release, a loss and its end, a bounce).
    pub fn subject(&self) -> Option<String> {
        Some(match self {
            Action::Input { dev, ch, .. } => format!("{dev} DI{ch}"),
            Action::Inputs { dev, .. } => format!("{dev} DI"),
            Action::Pulse { dev, ch, .. } | Action::CounterTo { dev, ch, .. } => {
                format!("{dev} counter {ch}")
            }
            Action::Press { dev, switch } | Action::Release { dev, switch } => {
                format!("{dev} {switch}")
            }
            Action::Turn { dev, rotary, .. } => format!("{dev} {}", rotary.name()),
            Action::Fail { dev } | Action::Restore { dev } | Action::PowerCycle { dev } => {
                format!("{dev} line")
            }
            Action::DropAnswers { dev, .. }
            | Action::GarbleAnswers { dev, .. }
            | Action::LateAnswers { dev, .. }
            | Action::DuplicateAnswers { dev, .. } => format!("{dev} answers"),
            Action::Stall { .. } | Action::WallStep { .. } => "clocks".into(),
            Action::Stop => return None,
        })
    }

    /// Simpler versions of this action, simplest first (for shrinking).
    pub fn simpler(&self) -> Vec<Action> {
        let mut out = Vec::new();
        match self {
            Action::Inputs { dev, byte } => {
                // One bit fewer at a time: the fewest inputs that still show it.
                for bit in 0..8 {
                    if byte & (1 << bit) != 0 {
                        out.push(Action::Inputs {
                            dev: Arc::clone(dev),
                            byte: byte & !(1 << bit),
                        });
                    }
                }
            }
            Action::Pulse { dev, ch, n } if *n > 1 => {
                for m in [1, n / 2] {
                    out.push(Action::Pulse {
                        dev: Arc::clone(dev),
                        ch: *ch,
                        n: m,
                    });
                }
            }
            Action::CounterTo { dev, ch, value } if (NEAR_WRAP..u16::MAX).contains(value) => {
                out.push(Action::CounterTo {
                    dev: Arc::clone(dev),
                    ch: *ch,
                    value: u16::MAX,
                });
            }
            Action::Turn {
                dev,
                rotary,
                half_turns,
            } if half_turns.abs() > 1 => {
                for h in [half_turns.signum(), half_turns / 2] {
                    out.push(Action::Turn {
                        dev: Arc::clone(dev),
                        rotary: *rotary,
                        half_turns: h,
                    });
                }
            }
            Action::DropAnswers { dev, n } if *n > 1 => out.push(Action::DropAnswers {
                dev: Arc::clone(dev),
                n: n - 1,
            }),
            Action::GarbleAnswers { dev, n } if *n > 1 => out.push(Action::GarbleAnswers {
                dev: Arc::clone(dev),
                n: n - 1,
            }),
            Action::LateAnswers { dev, n, by } => {
                if *n > 1 {
                    out.push(Action::LateAnswers {
                        dev: Arc::clone(dev),
                        n: n - 1,
                        by: *by,
                    });
                }
                if *by > Duration::from_millis(1) {
                    out.push(Action::LateAnswers {
                        dev: Arc::clone(dev),
                        n: *n,
                        by: *by / 2,
                    });
                }
            }
            Action::DuplicateAnswers { dev, n } if *n > 1 => out.push(Action::DuplicateAnswers {
                dev: Arc::clone(dev),
                n: n - 1,
            }),
            Action::Stall { by } if *by > Duration::from_millis(1) => {
                out.push(Action::Stall { by: *by / 2 });
            }
            Action::WallStep { seconds } if seconds.abs() > 1 => {
                out.push(Action::WallStep {
                    seconds: seconds / 2,
                });
            }
            _ => {}
        }
        out.retain(|a| a != self);
        out.dedup();
        out
    }
}

/// An action at a time since the start of the run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Event {
    /// When (virtual time since the run started).
    pub at: Duration,
    /// What.
    pub action: Action,
}

/// Where a run starts: wall time and the zone of cron, `now()` and the log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StartPoint {
    /// Wall time at the start, with the offset it is written in.
    pub wall: DateTime<FixedOffset>,
    /// The zone: `"UTC"` or an IANA name.
    pub zone: String,
}

impl StartPoint {
    /// The wall time as the test file writes it (RFC 3339 with milliseconds).
    pub fn wall_text(&self) -> String {
        self.wall
            .to_rfc3339_opts(chrono::SecondsFormat::Millis, true)
    }
}

/// What a run plays: where it starts and its events in time order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Plan {
    /// Where it starts.
    pub start: StartPoint,
    /// The events, in time order (ties in the order given).
    pub events: Vec<Event>,
}

impl Plan {
    /// Sorts the events by time, keeping the order of those at the same time.
    pub fn sort(&mut self) {
        self.events.sort_by_key(|e| e.at);
    }
}

/// `t=0.120s`.
pub fn time_text(at: Duration) -> String {
    format!("t={}.{:03}s", at.as_secs(), at.subsec_millis())
}

/// The events as one line: `t=0.120s io DI2 off · t=0.140s panel S12 pressed`.
pub fn trace(events: &[Event]) -> String {
    let parts: Vec<String> = events
        .iter()
        .map(|e| format!("{} {}", time_text(e.at), e.action))
        .collect();
    parts.join(" · ")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn io() -> Arc<str> {
        Arc::from("io")
    }

    #[test]
    fn events_read_as_a_person_would_say_them() {
        let events = vec![
            Event {
                at: Duration::from_millis(120),
                action: Action::Input {
                    dev: io(),
                    ch: 2,
                    on: false,
                },
            },
            Event {
                at: Duration::from_millis(140),
                action: Action::Press {
                    dev: Arc::from("panel"),
                    switch: Switch::new(12).unwrap(),
                },
            },
            Event {
                at: Duration::from_secs(61),
                action: Action::WallStep { seconds: -5400 },
            },
        ];
        assert_eq!(
            trace(&events),
            "t=0.120s io DI2 off · t=0.140s panel S12 pressed · t=61.000s wall clock -1h30m"
        );
    }

    #[test]
    fn simpler_actions_are_smaller_and_never_the_same() {
        let a = Action::Inputs {
            dev: io(),
            byte: 0x0A,
        };
        assert_eq!(
            a.simpler(),
            vec![
                Action::Inputs {
                    dev: io(),
                    byte: 0x08
                },
                Action::Inputs {
                    dev: io(),
                    byte: 0x02
                }
            ]
        );
        let p = Action::Pulse {
            dev: io(),
            ch: 1,
            n: 2,
        };
        assert_eq!(p.simpler().len(), 1, "1 and 2/2 are the same");
        assert!(Action::Stop.simpler().is_empty());
        assert!(Action::Pulse {
            dev: io(),
            ch: 1,
            n: 1
        }
        .simpler()
        .is_empty());
    }
}
