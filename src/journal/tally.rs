//! Turns the run's event stream into journal entries, each in its tick: the loop tells a
//! tick's `Tick` at the tick's end, so what comes before it (inputs read, outputs written,
//! a loss, the end) belongs to the tick after the last one told. The journal's writer and
//! the replay tally their runs the one same way, so their entries compare as they are.

use super::entry::{Entry, What};
use crate::protocol::trc1000::Switch;
use crate::runtime::observe::{EventKind, Reading, RunEvent};

/// The kinds of event a journal takes.
pub const KINDS: [EventKind; 8] = [
    EventKind::ScriptStarted,
    EventKind::ScriptFailed,
    EventKind::Tick,
    EventKind::Inputs,
    EventKind::Outputs,
    EventKind::DeviceLost,
    EventKind::DeviceBack,
    EventKind::Ended,
];

/// The tick events fall in, and what the last reading of each input was (a rotated part of
/// the journal starts with them).
#[derive(Debug, Default, Clone)]
pub struct Tally {
    /// The last tick told (`None` before the first).
    told: Option<u64>,
    /// The top level has run: what comes before the first tick told is the first tick's.
    started: bool,
    /// The last reading of each device's inputs, by kind.
    readings: Vec<Entry>,
}

impl Tally {
    /// The tick what comes now belongs to.
    pub fn tick(&self) -> u64 {
        match self.told {
            Some(t) => t + 1,
            None => u64::from(self.started),
        }
    }

    /// The entry `event` makes, if any.
    pub fn take(&mut self, event: &RunEvent) -> Option<Entry> {
        let tick = self.tick();
        let what = match event {
            RunEvent::Tick {
                tick: n,
                late_us,
                work_us,
                overrun,
            } => {
                self.told = Some(*n);
                if !overrun {
                    return None;
                }
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
            RunEvent::ScriptFailed { message } => What::Failed {
                message: message.clone(),
            },
            RunEvent::Inputs { device, reading } => {
                let dev = device.clone();
                let what = match reading {
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
                };
                let entry = Entry { tick, what };
                self.remember(&entry);
                return Some(entry);
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
            RunEvent::Ended { status, reason, .. } => What::Ended {
                status: *status,
                reason: reason.clone(),
            },
            _ => return None,
        };
        Some(Entry { tick, what })
    }

    /// A loss of `events` here, as an entry.
    pub fn gap(&self, events: u64) -> Entry {
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
