//! What `verify` looks for after every tick: the script's own invariants, and the built-in
//! checks every script gets: no script error (a device fault counts unless the script handles
//! it; so is a call stopped by one of the script's limits), no handler over its operation
//! budget, time or memory (a runaway), every output held at its safe value while a
//! device is lost past its grace time (as the simulators show it), and every output safe once
//! the run has ended.

use crate::config::{DeviceConfig, RigConfig};
use crate::runtime::devices::SimRig;
use crate::script::rig::Rig;
use std::fmt;
use std::time::Duration;

/// Something that must hold.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Check {
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

impl Check {
    /// The check's name: the invariant's, or the built-in check's in words.
    pub fn name(&self) -> &str {
        match self {
            Check::Invariant(name) => name,
            Check::ScriptError => "no script error",
            Check::OverBudget => "no handler over its budget",
            Check::HeldSafe => "outputs held safe while a device is lost past its grace time",
            Check::EndSafe => "outputs safe after the run ends",
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

impl fmt::Display for Check {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Check::Invariant(name) => write!(f, "invariant {name:?}"),
            other => write!(f, "built-in check {:?}", other.name()),
        }
    }
}

/// A check found failing.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Finding {
    /// Which.
    pub check: Check,
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
                Check::OverBudget
            } else {
                Check::ScriptError
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
            .filter(|(name, _)| rt.device_index(name).is_some_and(|i| rt.online(i)))
            .filter(|(name, _)| rig.sim.answers(name).unwrap_or(false))
            .filter_map(|(name, safe)| {
                unsafe_device(&rig.sim, name, safe).map(|seen| (name.clone(), seen))
            })
            .collect()
    }

    /// A safety finding from the devices `unsafe_devices` found.
    fn safety(check: Check, at: Duration, bad: Vec<(String, String)>) -> Option<Finding> {
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
                check: Check::Invariant(v.name.clone()),
                at,
                detail: v.readings(),
                devices: Vec::new(),
            });
        }
        if let Some(f) = self.errors(rig, at) {
            return Some(f);
        }
        if rig.runner.runtime().borrow().held_safe() {
            return Self::safety(Check::HeldSafe, at, self.unsafe_devices(rig));
        }
        None
    }

    /// What the end of the run showed (its `on_stop` handlers' errors, the safe state).
    pub fn after_end(&mut self, rig: &Rig, at: Duration) -> Option<Finding> {
        if let Some(f) = self.errors(rig, at) {
            return Some(f);
        }
        Self::safety(Check::EndSafe, at, self.unsafe_devices(rig))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checks_have_names_people_read_and_file_names_can_hold() {
        let c = Check::Invariant("Power only with guards closed!".into());
        assert_eq!(
            c.to_string(),
            "invariant \"Power only with guards closed!\""
        );
        assert_eq!(c.slug(), "power_only_with_guards_closed");
        assert_eq!(
            Check::OverBudget.to_string(),
            "built-in check \"no handler over its budget\""
        );
        assert_eq!(Check::Invariant("?!".into()).slug(), "invariant");
        let long = Check::Invariant("power only with all guards closed and no stop pressed".into());
        assert_eq!(long.slug(), "power_only_with_all_guards_closed_and_no_stop");
    }
}
