//! Turns the run's event stream into journal entries, each in its tick: every event comes
//! with the tick it was published in (`Subscription::tick`; the loop moves it on as each tick
//! ends, so what comes between two ticks belongs to the next), so the journal takes no event a
//! tick, only overruns. The journal's writer and the replay tally their runs the one same way,
//! so their entries compare as they are.

use super::entry::{Entry, What};
use crate::protocol::trc1000::Switch;
use crate::runtime::observe::{EventKind, Reading, RunEvent};

/// The kinds of event a journal takes.
pub const KINDS: [EventKind; 11] = [
    EventKind::ScriptStarted,
    EventKind::ScriptFailed,
    EventKind::Overrun,
    EventKind::Woken,
    EventKind::Inputs,
    EventKind::Outputs,
    EventKind::DeviceLost,
    EventKind::DeviceBack,
    EventKind::Reloaded,
    EventKind::Operated,
    EventKind::Ended,
];

/// The tick events fall in, and what the last reading of each input was (a rotated part of
/// the journal starts with them).
#[derive(Debug, Default, Clone)]
pub struct Tally {
    /// The tick the last event was published in, as the loop numbers them (0 before the first
    /// tick ended).
    stamp: u64,
    /// The top level has run: what comes before the first tick ended is the first tick's.
    started: bool,
    /// The last reading of each device's inputs, by kind.
    readings: Vec<Entry>,
}

impl Tally {
    /// The tick what comes now belongs to.
    pub fn tick(&self) -> u64 {
        match self.stamp {
            0 => u64::from(self.started),
            t => t,
        }
    }

    /// The entry `event`, published in tick `stamp` (`Subscription::tick`), makes, if any.
    pub fn take(&mut self, stamp: u64, event: &RunEvent) -> Option<Entry> {
        self.stamp = stamp;
        let tick = self.tick();
        let what = match event {
            RunEvent::Overrun {
                tick: n,
                late_us,
                work_us,
            } => {
                return Some(Entry {
                    tick: *n,
                    what: What::Overrun {
                        late_us: *late_us,
                        work_us: *work_us,
                    },
                });
            }
            RunEvent::ScriptStarted {
                restarts, since, ..
            } => {
                self.started = true;
                What::Started {
                    restarts: *restarts,
                    since: *since,
                }
            }
            RunEvent::Woken { periods, late_us } => What::Woken {
                periods: *periods,
                late_us: *late_us,
            },
            RunEvent::ScriptFailed { message } => What::Failed {
                message: message.clone(),
            },
            RunEvent::Inputs { device, reading } => {
                let entry = Entry {
                    tick,
                    what: reading_what(device, reading),
                };
                self.remember(&entry);
                return Some(entry);
            }
            // Taken only by a journal that asks for the whole image (`run --journal-image`).
            RunEvent::Shown { device, reading } => {
                What::Shown(Box::new(reading_what(device, reading)))
            }
            RunEvent::Outputs {
                device,
                value,
                cause,
            } => What::Outputs {
                dev: device.clone(),
                value: *value,
                cause: cause.clone(),
            },
            RunEvent::DeviceLost { device, cause } => What::Lost {
                dev: device.clone(),
                cause: cause.clone(),
            },
            RunEvent::DeviceBack { device } => What::Back {
                dev: device.clone(),
            },
            RunEvent::Operated { act } => What::Operated(act.clone()),
            RunEvent::Reloaded { file, hash, source } => What::Reloaded {
                hash: hash.clone(),
                file: file.clone(),
                source: source.clone(),
            },
            RunEvent::Ended { status, reason, .. } => What::Ended {
                status: *status,
                reason: reason.clone(),
            },
            _ => return None,
        };
        Some(Entry { tick, what })
    }

    /// A loss of `events` before an event published in tick `stamp`, as an entry.
    pub fn gap(&mut self, stamp: u64, events: u64) -> Entry {
        self.stamp = stamp;
        Entry {
            tick: self.tick(),
            what: What::Gap { events },
        }
    }

    fn remember(&mut self, entry: &Entry) {
        let same = |e: &Entry| {
            std::mem::discriminant(&e.what) == std::mem::discriminant(&entry.what)
                && device(&e.what) == device(&entry.what)
        };
        match self.readings.iter_mut().find(|e| same(e)) {
            Some(e) => *e = entry.clone(),
            None => self.readings.push(entry.clone()),
        }
    }

    /// The last reading of each input of each device, as entries of their ticks.
    pub fn readings(&self) -> &[Entry] {
        &self.readings
    }
}

/// A reading of `dev` as an entry's `What`.
fn reading_what(dev: &str, reading: &Reading) -> What {
    let dev = dev.to_string();
    match reading {
        Reading::DigitalInputs { value } => What::Inputs { dev, byte: *value },
        Reading::Counters { values } => What::Counters {
            dev,
            values: *values,
        },
        Reading::Switches { pressed } => What::Switches {
            dev,
            pressed: pressed
                .iter()
                .filter_map(|name| Switch::from_name(name))
                .collect(),
        },
        Reading::Rotaries { values } => What::Rotaries {
            dev,
            values: *values,
        },
    }
}

/// The device an entry is about, if one.
pub fn device(what: &What) -> Option<&str> {
    match what {
        What::Inputs { dev, .. }
        | What::Counters { dev, .. }
        | What::Switches { dev, .. }
        | What::Rotaries { dev, .. }
        | What::Outputs { dev, .. }
        | What::Lost { dev, .. }
        | What::Back { dev } => Some(dev),
        _ => None,
    }
}
