//! What `verify` knows about the script and its rig when it makes up a field: the devices,
//! what the script reads (from the switch and rotary names its source mentions, then from what
//! earlier runs saw it read), its timers, cron expressions and watchdogs (from its text, then
//! from what runs registered), the values it compares counters and rotaries with, the grace
//! time and the scan period. The field is weighted toward these.

use super::facts::Facts;
use crate::config::{DeviceConfig, RigConfig};
use crate::protocol::trc1000::{Rotary, Switch};
use crate::runtime::devices::Device;
use crate::runtime::handlers::Source;
use crate::runtime::schedule::TimerKind;
use crate::script::reads::{Item, ReadSet};
use crate::script::rig::Rig;
use std::collections::BTreeSet;
use std::sync::Arc;
use std::time::Duration;

/// The kind of a device.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A TRC1000 panel.
    Trc,
    /// A TRP-C29U module.
    C29u,
}

/// One device of the rig.
#[derive(Debug, Clone)]
pub struct DeviceInfo {
    /// Its name.
    pub name: Arc<str>,
    /// Its kind.
    pub kind: Kind,
    /// Its host watchdog, if one was seen on.
    pub watchdog: Option<Duration>,
    /// How long its driver waits for an answer (late answers are drawn around it).
    pub timeout: Duration,
}

/// What a run saw of the script, for the next runs' fields.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Observed {
    /// What the script read.
    pub reads: ReadSet,
    /// `every` and `after` durations.
    pub timers: BTreeSet<Duration>,
    /// Cron expressions.
    pub crons: BTreeSet<String>,
    /// Device index → host watchdog seen on.
    pub watchdogs: BTreeSet<(usize, Duration)>,
}

impl Observed {
    /// Takes in the timers and watchdogs the rig has now.
    pub fn look(&mut self, rig: &Rig) {
        let rt = rig.runner.runtime().borrow();
        for s in rt.handlers().list() {
            if let Source::Timer(id) = s.source {
                match rt.handlers().timer_kind(id) {
                    Some(TimerKind::Every(d) | TimerKind::After(d)) => {
                        self.timers.insert(*d);
                    }
                    Some(TimerKind::Cron(e)) => {
                        self.crons.insert(e.clone());
                    }
                    None => {}
                }
            }
        }
        for (idx, d) in rt.devices().iter().enumerate() {
            if let Device::C29u(c) = d {
                if let Some(w) = c.watchdog() {
                    self.watchdogs.insert((idx, w.as_duration()));
                }
            }
        }
    }

    /// Adds what another run saw.
    pub fn merge(&mut self, other: &Observed) {
        self.reads.union(&other.reads);
        self.timers.extend(other.timers.iter().copied());
        self.crons.extend(other.crons.iter().cloned());
        self.watchdogs.extend(other.watchdogs.iter().copied());
    }
}

/// Everything the field generator weighs its choices by.
#[derive(Debug, Clone)]
pub struct Profile {
    /// The devices, in the runtime's order (by name).
    pub devices: Vec<DeviceInfo>,
    /// What the script reads.
    pub reads: ReadSet,
    /// `every` and `after` durations.
    pub timers: BTreeSet<Duration>,
    /// Cron expressions.
    pub crons: BTreeSet<String>,
    /// How long a device may be lost before everything is held safe.
    pub grace: Duration,
    /// The scan period.
    pub period: Duration,
    /// How long each run lasts.
    pub run_for: Duration,
    /// What the script's text says: its timers and the values it compares counters and
    /// rotaries with.
    pub facts: Facts,
}

/// The string literals of `source` (without escapes resolved: names need none).
fn string_literals(source: &str) -> Vec<&str> {
    let mut out = Vec::new();
    let mut rest = source;
    while let Some(open) = rest.find('"') {
        let after = rest.get(open + 1..).unwrap_or("");
        let mut end = None;
        let mut escaped = false;
        for (i, c) in after.char_indices() {
            match c {
                '\\' if !escaped => escaped = true,
                '"' if !escaped => {
                    end = Some(i);
                    break;
                }
                _ => escaped = false,
            }
        }
        let Some(end) = end else { break };
        out.push(after.get(..end).unwrap_or(""));
        rest = after.get(end + 1..).unwrap_or("");
    }
    out
}

impl Profile {
    /// A first profile: the rig's devices, and the switches and rotaries the source names.
    pub fn new(config: &RigConfig, source: &str, period: Duration, run_for: Duration) -> Self {
        let devices: Vec<DeviceInfo> = config
            .devices
            .iter()
            .map(|(name, d)| DeviceInfo {
                name: Arc::from(name.as_str()),
                kind: match d {
                    DeviceConfig::Trc1000(_) => Kind::Trc,
                    DeviceConfig::C29u(_) => Kind::C29u,
                },
                watchdog: match d {
                    DeviceConfig::C29u(c) => c.watchdog.map(|w| w.as_duration()),
                    DeviceConfig::Trc1000(_) => None,
                },
                timeout: match d {
                    DeviceConfig::C29u(c) => c.timeout,
                    DeviceConfig::Trc1000(_) => crate::config::feeding::TRC1000_TIMEOUT,
                },
            })
            .collect();
        let mut reads = ReadSet::default();
        for text in string_literals(source) {
            let item = Switch::from_name(text)
                .map(Item::Switch)
                .or_else(|| Rotary::from_name(text).map(Item::Rotary));
            if let Some(item) = item {
                for (idx, d) in devices.iter().enumerate() {
                    if d.kind == Kind::Trc {
                        reads.add(idx, item);
                    }
                }
            }
        }
        let facts = Facts::read(source);
        Self {
            devices,
            reads,
            timers: facts.timers.clone(),
            crons: facts.crons.clone(),
            grace: config.grace,
            period,
            run_for,
            facts,
        }
    }

    /// Learns from what runs observed.
    pub fn learn(&mut self, seen: &Observed) {
        self.reads.union(&seen.reads);
        self.timers.extend(seen.timers.iter().copied());
        self.crons.extend(seen.crons.iter().cloned());
        for (idx, w) in &seen.watchdogs {
            if let Some(d) = self.devices.get_mut(*idx) {
                d.watchdog = Some(d.watchdog.map_or(*w, |old| old.min(*w)));
            }
        }
    }

    /// The durations worth landing events near: timers, the grace time, watchdogs (and a
    /// quarter of each, when the runner feeds it).
    pub fn interesting_durations(&self) -> Vec<Duration> {
        let mut out: BTreeSet<Duration> = self.timers.clone();
        out.insert(self.grace);
        for d in &self.devices {
            if let Some(w) = d.watchdog {
                out.insert(w);
                out.insert(w / 4);
            }
        }
        out.into_iter().filter(|d| !d.is_zero()).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn switch_and_rotary_names_in_the_source_are_read_items_of_every_panel() {
        let source = r#"const STOP = ["S10", "S11"]; let x = "S41A"; let y = "hello \"S3\""; "#;
        let config = RigConfig::simulated_default();
        let p = Profile::new(
            &config,
            source,
            Duration::from_millis(20),
            Duration::from_secs(1),
        );
        let panel = p.devices.iter().position(|d| d.kind == Kind::Trc).unwrap();
        let items: Vec<Item> = p.reads.items().into_iter().map(|(_, i)| i).collect();
        assert_eq!(
            items,
            vec![
                Item::Switch(Switch::new(10).unwrap()),
                Item::Switch(Switch::new(11).unwrap()),
                Item::Rotary(Rotary::S41A)
            ]
        );
        assert!(p.reads.contains(panel, Item::Rotary(Rotary::S41A)));
        assert_eq!(p.interesting_durations(), vec![Duration::from_secs(1)]);
    }
}
