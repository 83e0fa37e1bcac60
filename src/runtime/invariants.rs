//! Invariants a script states (`invariant(name, || bool)`): what must hold after every tick's
//! handlers, before the tick's outputs are written. A false one is a fault: the outputs of that
//! tick are not written, the safe state is, and the run ends with status 1 whatever the error
//! policy says (an interlock that contradicts itself must stop). This module holds them and
//! describes a violation with the inputs and outputs of the tick it happened in.

use super::devices::Device;
use super::state::Runtime;
use super::subscriptions::Call;
use serde_json::{json, Value};
use std::fmt;
use std::time::Duration;

/// Invariants one script may state (each is evaluated every tick).
pub const MAX_INVARIANTS: usize = 100;

/// One stated invariant.
#[derive(Debug, Clone)]
pub struct Invariant<H> {
    /// Its name, as the script gave it.
    pub name: String,
    /// The script's function that says whether it holds.
    pub handler: H,
    /// Where it was stated (`file:line:column`), when known.
    pub at: Option<String>,
}

/// One invariant to evaluate this tick.
#[derive(Debug, Clone)]
pub struct Check<H> {
    /// The call that evaluates it (label `invariant "name"`).
    pub call: Call<H>,
    /// Its name.
    pub name: String,
    /// Where it was stated.
    pub at: Option<String>,
}

/// Why an invariant could not be added.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum InvariantError {
    /// The name is taken.
    #[error("there is already an invariant called {0:?}: give each its own name")]
    Duplicate(String),
    /// Too many.
    #[error("too many invariants (at most {MAX_INVARIANTS}): state fewer, each covering more")]
    TooMany,
    /// An empty name says nothing in a report.
    #[error("an invariant needs a name that says what it promises")]
    NoName,
}

/// What a device showed in the tick an invariant was found false.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DeviceReading {
    /// A TRP-C29U.
    C29u {
        /// Its name.
        name: String,
        /// The DI byte last read (`None`: never read).
        inputs: Option<u8>,
        /// The DO byte the script wanted.
        outputs: u8,
        /// Whether it answered.
        online: bool,
    },
    /// A TRC1000.
    Trc {
        /// Its name.
        name: String,
        /// The switches pressed at the last reading (`None`: never read).
        pressed: Option<Vec<&'static str>>,
        /// The relay the script wanted.
        relay: u8,
        /// Whether it answered.
        online: bool,
    },
}

impl DeviceReading {
    /// The reading as JSON, for the records.
    pub fn to_json(&self) -> Value {
        match self {
            DeviceReading::C29u {
                inputs,
                outputs,
                online,
                ..
            } => json!({"inputs": inputs, "outputs": outputs, "online": online}),
            DeviceReading::Trc {
                pressed,
                relay,
                online,
                ..
            } => json!({"pressed": pressed, "relay": relay, "online": online}),
        }
    }

    /// The device's name.
    pub fn name(&self) -> &str {
        match self {
            DeviceReading::C29u { name, .. } | DeviceReading::Trc { name, .. } => name,
        }
    }
}

impl fmt::Display for DeviceReading {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let lost = |online: bool| if online { "" } else { " (lost)" };
        match self {
            DeviceReading::C29u {
                name,
                inputs,
                outputs,
                online,
            } => {
                write!(f, "{name} outputs {outputs:#04x}, inputs ")?;
                match inputs {
                    Some(i) => write!(f, "{i:#04x}")?,
                    None => f.write_str("not read")?,
                }
                f.write_str(lost(*online))
            }
            DeviceReading::Trc {
                name,
                pressed,
                relay,
                online,
            } => {
                write!(f, "{name} relay {relay}, pressed ")?;
                match pressed {
                    Some(p) if p.is_empty() => f.write_str("none")?,
                    Some(p) => f.write_str(&p.join(" "))?,
                    None => f.write_str("not read")?,
                }
                f.write_str(lost(*online))
            }
        }
    }
}

/// An invariant found false.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Violation {
    /// The invariant's name.
    pub name: String,
    /// Where it was stated.
    pub at: Option<String>,
    /// How long the run had been going.
    pub uptime: Duration,
    /// What each device showed in that tick.
    pub devices: Vec<DeviceReading>,
}

impl Violation {
    /// The devices' readings in one line: `io outputs 0x0f, inputs 0x0b; panel relay 0, ...`.
    pub fn readings(&self) -> String {
        let parts: Vec<String> = self.devices.iter().map(ToString::to_string).collect();
        parts.join("; ")
    }

    /// The violation as the value of a record.
    pub fn to_json(&self) -> Value {
        let devices: serde_json::Map<String, Value> = self
            .devices
            .iter()
            .map(|d| (d.name().to_string(), d.to_json()))
            .collect();
        json!({
            "invariant": self.name,
            "at": self.at,
            "uptime_ms": u64::try_from(self.uptime.as_millis()).unwrap_or(u64::MAX),
            "devices": devices,
        })
    }
}

impl fmt::Display for Violation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "invariant {:?} is false", self.name)?;
        if let Some(at) = &self.at {
            write!(f, " (stated at {at})")?;
        }
        write!(f, ": {}", self.readings())
    }
}

impl<H: Clone> Runtime<H> {
    /// States an invariant (checked from the next tick on).
    pub fn add_invariant(
        &mut self,
        name: &str,
        handler: H,
        at: Option<String>,
    ) -> Result<(), InvariantError> {
        if name.trim().is_empty() {
            return Err(InvariantError::NoName);
        }
        if self.invariants.iter().any(|i| i.name == name) {
            return Err(InvariantError::Duplicate(name.to_string()));
        }
        if self.invariants.len() >= MAX_INVARIANTS {
            return Err(InvariantError::TooMany);
        }
        self.invariants.push(Invariant {
            name: name.to_string(),
            handler,
            at,
        });
        Ok(())
    }

    /// How to evaluate each invariant, in the order they were stated.
    pub fn invariant_checks(&self) -> Vec<Check<H>> {
        self.invariants
            .iter()
            .map(|i| Check {
                call: Call {
                    handler: i.handler.clone(),
                    args: Vec::new(),
                    label: format!("invariant {:?}", i.name),
                },
                name: i.name.clone(),
                at: i.at.clone(),
            })
            .collect()
    }

    /// What each device the script uses shows now: the last inputs read and the outputs the
    /// script wants (a device never read and still at its safe state is left out).
    pub fn readings(&self) -> Vec<DeviceReading> {
        self.devices
            .iter()
            .filter(|d| match d {
                Device::C29u(c) => c.inputs.current.is_some() || c.outputs != c.config.safe_value,
                Device::Trc(t) => {
                    t.switches.current.is_some() || Some(t.relay) != t.config.safe_relay
                }
            })
            .map(|d| match d {
                Device::C29u(c) => DeviceReading::C29u {
                    name: c.name.clone(),
                    inputs: c.inputs.current,
                    outputs: c.outputs,
                    online: c.health.online(),
                },
                Device::Trc(t) => DeviceReading::Trc {
                    name: t.name.clone(),
                    pressed: t.switches.current.map(|s| s.pressed_names()),
                    relay: t.relay,
                    online: t.health.online(),
                },
            })
            .collect()
    }

    /// Records and logs a violation: the invariant, where it was stated, and the tick's
    /// inputs and outputs.
    pub fn report_violation(&mut self, v: &Violation) {
        self.log.error(&format!(
            "{v}; the outputs of this tick are not written, the safe state is"
        ));
        let time = self.wall_text();
        self.records
            .record(&time, "invariant_violated", v.to_json(), &mut self.log);
    }
}
