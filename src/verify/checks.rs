//! What `verify` looks for after every tick: the script's own invariants, and the built-in
//! checks every script gets: no script error (a device fault counts unless the script handles
//! it; so is a call stopped by one of the script's limits), no handler over its operation
//! budget, time or memory (a runaway), every output held at its safe value while a
//! device is lost past its grace time (as the simulators show it), and every output safe once
//! the run has ended.

use crate::config::{DeviceConfig, RigConfig};
use crate::protocol::trc1000::{Rotary, Switch};
use crate::runtime::devices::{Device, SimRig};
use crate::runtime::invariants::Violation;
use crate::script::reads::Item;
use crate::script::rig::Rig;
use std::fmt;
use std::time::Duration;

/// A property every run `verify` makes must keep (not an `InvariantCheck`, the loop's
/// evaluation of one invariant, nor a `ModuleCheck`, the 5 s read-back of a module).
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Property {
    /// An invariant of the script, by name.
    Invariant(String),
    /// No script error.
    ScriptError,
    /// No handler (or invariant) over its operation budget, time or memory per call: the
    /// limits whose breach would recur (`script::engine::Breach::is_runaway`); the other limits' breaches
    /// (timers, sizes, call depth) are script errors.
    OverBudget,
    /// While a device is lost past its grace time, every device that answers shows its safe
    /// state.
    HeldSafe,
    /// Once the run has ended, every device that answers shows its safe state.
    EndSafe,
}

impl Property {
    /// The check's name: the invariant's, or the built-in check's in words.
    pub fn name(&self) -> &str {
        match self {
            Property::Invariant(name) => name,
            Property::ScriptError => "no script error",
            Property::OverBudget => "no handler over its budget",
            Property::HeldSafe => "outputs held safe while a device is lost past its grace time",
            Property::EndSafe => "outputs safe after the run ends",
        }
    }

    /// The name as part of a file name: lower case, words joined by `_`.
    pub fn slug(&self) -> String {
        let mut out = String::new();
        for c in self.name().chars() {
            if c.is_ascii_alphanumeric() {
                out.push(c.to_ascii_lowercase());
            } else if !out.ends_with('_') && !out.is_empty() {
                out.push('_');
            }
        }
        let mut out = out.trim_end_matches('_').to_string();
        if out.len() > 48 {
            // At a word's end: the name stays readable.
            let cut = out.get(..48).and_then(|s| s.rfind('_')).unwrap_or(48);
            out.truncate(cut);
        }
        if out.is_empty() {
            "invariant".into()
        } else {
            out
        }
    }
}

impl fmt::Display for Property {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Property::Invariant(name) => write!(f, "invariant {name:?}"),
            other => write!(f, "built-in check {:?}", other.name()),
        }
    }
}

/// A check found failing.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Finding {
    /// Which.
    pub check: Property,
    /// When (virtual time since the start of the run).
    pub at: Duration,
    /// What was seen.
    pub detail: String,
    /// The devices not at their safe state (the built-in safety checks).
    pub devices: Vec<String>,
}

impl fmt::Display for Finding {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} false: {}", self.check, self.detail)
    }
}

/// A device's safe state as rig.toml sets it.
#[derive(Debug, Clone)]
enum Safe {
    Outputs(u8),
    Relay(Option<u8>),
}

/// Watches one run for findings.
#[derive(Debug, Clone)]
pub struct Watch {
    errors_seen: u64,
    safe: Vec<(String, Safe)>,
}

/// A device's safe state unkept: `io outputs 0xf0, safe value 0x00`.
fn unsafe_device(sim: &SimRig, name: &str, safe: &Safe) -> Option<String> {
    match safe {
        Safe::Outputs(v) => match sim.outputs(name) {
            Ok(now) if now != *v => Some(format!("{name} outputs {now:#04x}, safe value {v:#04x}")),
            _ => None,
        },
        Safe::Relay(Some(r)) => match sim.relay(name) {
            Ok(now) if now != *r => Some(format!("{name} relay {now}, safe relay {r}")),
            _ => None,
        },
        Safe::Relay(None) => None,
    }
}

/// What device `d` showed of the items in `mask` (the invariant's reads), as read in the tick:
/// `io outputs 0x01, inputs 0x0f, counter DI0 300, latches on 0x01 off 0x00 (lost)`.
fn device_as_read(d: &Device, mask: u128) -> String {
    let reads = |item: Item| mask & item.mask() != 0;
    let mut parts = Vec::new();
    let online = match d {
        Device::C29u(c) => {
            parts.push(format!("{} outputs {:#04x}", c.name(), c.wanted_outputs()));
            if (0..8).any(|ch| reads(Item::Input(ch))) {
                parts.push(match c.inputs().current {
                    Some(i) => format!("inputs {i:#04x}"),
                    None => "inputs not read".into(),
                });
            }
            for ch in (0..8).filter(|ch| reads(Item::Counter(*ch))) {
                parts.push(match c.counters().current {
                    Some(n) => format!("counter DI{ch} {}", n.get(usize::from(ch)).unwrap_or(&0)),
                    None => format!("counter DI{ch} not read"),
                });
            }
            if reads(Item::Latches) {
                parts.push(match c.latches().current {
                    Some(l) => format!("latches on {:#04x} off {:#04x}", l.energized, l.released),
                    None => "latches not read".into(),
                });
            }
            c.health().online()
        }
        Device::Trc(t) => {
            parts.push(format!("{} relay {}", t.name(), t.wanted_relay()));
            if Switch::all().any(|s| reads(Item::Switch(s))) {
                parts.push(match t.switches().current {
                    Some(s) if s.pressed_names().is_empty() => "pressed none".into(),
                    Some(s) => format!("pressed {}", s.pressed_names().join(" ")),
                    None => "switches not read".into(),
                });
            }
            for r in Rotary::ALL.into_iter().filter(|r| reads(Item::Rotary(*r))) {
                parts.push(match t.rotaries().current {
                    Some(v) => format!("{} {}", r.name(), v.get(r)),
                    None => format!("{} not read", r.name()),
                });
            }
            t.health().online()
        }
    };
    let mut text = parts.join(", ");
    if !online {
        text.push_str(" (lost)");
    }
    text
}

/// The violation's readings with every input the invariant read, as read in that tick: the
/// runtime's line (DI bytes, switches, outputs) for the devices it read nothing of, and for
/// the others their outputs and each item it read (counters, rotaries, latches too).
fn as_read(rig: &Rig, v: &Violation) -> String {
    let reads = rig
        .runner
        .program()
        .coverage()
        .and_then(|c| c.invariant_reads.get(&v.name))
        .cloned()
        .unwrap_or_default();
    let rt = rig.runner.runtime().borrow();
    let mut parts = Vec::new();
    for (idx, d) in rt.devices().iter().enumerate() {
        let mask = reads.mask(idx) & !(Item::Outputs.mask() | Item::Relay.mask());
        if mask & !Item::Online.mask() != 0 {
            parts.push(device_as_read(d, mask));
        } else if let Some(r) = v.devices.iter().find(|r| r.name() == d.name()) {
            parts.push(r.to_string());
        }
    }
    parts.join("; ")
}

impl Watch {
    /// A watch for a run of the rig `config` describes.
    pub fn new(config: &RigConfig) -> Self {
        let safe = config
            .devices
            .iter()
            .map(|(name, d)| {
                let s = match d {
                    DeviceConfig::C29u(c) => Safe::Outputs(c.safe_value),
                    DeviceConfig::Trc1000(t) => Safe::Relay(t.safe_relay),
                };
                (name.clone(), s)
            })
            .collect();
        Self {
            errors_seen: 0,
            safe,
        }
    }

    /// The device names and their safe states as the test file asserts them: (name,
    /// `"outputs"` or `"relay"`, value).
    pub fn safe_states(&self) -> Vec<(String, &'static str, u8)> {
        self.safe
            .iter()
            .filter_map(|(n, s)| match s {
                Safe::Outputs(v) => Some((n.clone(), "outputs", *v)),
                Safe::Relay(r) => r.map(|r| (n.clone(), "relay", r)),
            })
            .collect()
    }

    fn errors(&mut self, rig: &Rig, at: Duration) -> Option<Finding> {
        let errors = &rig.runner.errors;
        if errors.total() <= self.errors_seen {
            return None;
        }
        let first_new = usize::try_from(self.errors_seen).unwrap_or(usize::MAX);
        self.errors_seen = errors.total();
        let e = errors.kept().get(first_new)?;
        Some(Finding {
            check: if e.over_budget {
                Property::OverBudget
            } else {
                Property::ScriptError
            },
            at,
            detail: e.message.clone(),
            devices: Vec::new(),
        })
    }

    /// The devices that answer, and that the runner has under control, but do not show
    /// their safe state. (A device gone in the simulator shows nothing; one the runner counts
    /// as lost cannot be written to until it is back.)
    fn unsafe_devices(&self, rig: &Rig) -> Vec<(String, String)> {
        let rt = rig.runner.runtime().borrow();
        self.safe
            .iter()
            .filter(|(name, _)| {
                rt.devices()
                    .index(name)
                    .is_some_and(|i| rt.devices().online(i))
            })
            .filter(|(name, _)| rig.sim.answers(name).unwrap_or(false))
            .filter_map(|(name, safe)| {
                unsafe_device(&rig.sim, name, safe).map(|seen| (name.clone(), seen))
            })
            .collect()
    }

    /// A safety finding from the devices `unsafe_devices` found.
    fn safety(check: Property, at: Duration, bad: Vec<(String, String)>) -> Option<Finding> {
        if bad.is_empty() {
            return None;
        }
        let (devices, seen): (Vec<String>, Vec<String>) = bad.into_iter().unzip();
        Some(Finding {
            check,
            at,
            detail: seen.join("; "),
            devices,
        })
    }

    /// What the tick that just ran showed, at `at`.
    pub fn after_tick(&mut self, rig: &Rig, at: Duration) -> Option<Finding> {
        if let Some(v) = rig.runner.violation() {
            return Some(Finding {
                check: Property::Invariant(v.name.clone()),
                at,
                detail: as_read(rig, v),
                devices: Vec::new(),
            });
        }
        if let Some(f) = self.errors(rig, at) {
            return Some(f);
        }
        if rig.runner.runtime().borrow().held_safe() {
            return Self::safety(Property::HeldSafe, at, self.unsafe_devices(rig));
        }
        None
    }

    /// What the end of the run showed (its `on_stop` handlers' errors, the safe state).
    pub fn after_end(&mut self, rig: &Rig, at: Duration) -> Option<Finding> {
        if let Some(f) = self.errors(rig, at) {
            return Some(f);
        }
        Self::safety(Property::EndSafe, at, self.unsafe_devices(rig))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checks_have_names_people_read_and_file_names_can_hold() {
        let c = Property::Invariant("Power only with guards closed!".into());
        assert_eq!(
            c.to_string(),
            "invariant \"Power only with guards closed!\""
        );
        assert_eq!(c.slug(), "power_only_with_guards_closed");
        assert_eq!(
            Property::OverBudget.to_string(),
            "built-in check \"no handler over its budget\""
        );
        assert_eq!(Property::Invariant("?!".into()).slug(), "invariant");
        let long =
            Property::Invariant("power only with all guards closed and no stop pressed".into());
        assert_eq!(long.slug(), "power_only_with_all_guards_closed_and_no_stop");
    }

    #[test]
    fn a_violation_shows_every_input_the_invariant_read_as_read() {
        use super::super::exec::{execute, Keep, Target};
        use super::super::plan::{Action, Event, Plan, StartPoint};
        use std::sync::Arc;
        let source = r#"
let io = device("io");
let panel = device("panel");
io.outputs = 1;
invariant("counted and turned", || {
    let l = io.latched();
    io.outputs == 0 || io.counter(2) < 300 || panel.rotary("S41A") != 4
});
every("20ms", || {});
"#;
        let target = Target {
            source: source.into(),
            file: "t.rhai".into(),
            script: "t.rhai".into(),
            config_file: None,
            config: RigConfig::simulated_default(),
            budget: 100_000,
            run_for: Duration::from_secs(1),
            compared: Default::default(),
        };
        let at = |ms, action| Event {
            at: Duration::from_millis(ms),
            action,
        };
        let plan = Plan {
            start: StartPoint {
                wall: chrono::DateTime::parse_from_rfc3339("2026-03-28T12:00:00Z").unwrap(),
                zone: "UTC".into(),
            },
            events: vec![
                at(
                    10,
                    Action::Turn {
                        dev: Arc::from("panel"),
                        rotary: Rotary::S41A,
                        half_turns: 4,
                    },
                ),
                at(
                    30,
                    Action::CounterTo {
                        dev: Arc::from("io"),
                        ch: 2,
                        value: 300,
                    },
                ),
            ],
        };
        let keep = Keep {
            coverage: false,
            observe: false,
        };
        let f = execute(&target, &plan, keep)
            .unwrap()
            .finding
            .expect("found false");
        assert_eq!(
            f.detail,
            "io outputs 0x01, counter DI2 300, latches on 0x04 off 0x04; panel relay 0, S41A 4"
        );
    }
}
