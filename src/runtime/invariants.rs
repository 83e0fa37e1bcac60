//! Invariants a script states (`invariant(name, || bool)`): what must hold after every tick's
//! handlers, before the tick's outputs are written. A false one is a fault: the outputs of that
//! tick are not written, the safe state is, and the run ends with status 1 whatever the error
//! policy says (an interlock that contradicts itself must stop). This module says what they
//! are and describes a violation with the inputs and outputs of the tick it happened in;
//! stating and checking them on the run is `invariant_checks`.

use super::device_view::DeviceView;
use super::handlers::Call;
use serde_json::{json, Value};
use std::fmt;
use std::time::Duration;

/// Invariants one script may state (each is evaluated every tick).
pub const MAX_INVARIANTS: usize = 100;

/// One stated invariant, as the loop evaluates it every tick (built once, when stated: a
/// tick only shares the list).
#[derive(Debug, Clone)]
pub struct InvariantCheck<H> {
    /// The call that evaluates it (label `invariant "name"`).
    pub call: Call<H>,
    /// Its name, as the script gave it.
    pub name: String,
    /// Where it was stated (`file:line:column`), when known.
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

/// What a device showed in the tick an invariant was found false: its name and its reading.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceReading {
    /// Its name.
    pub name: String,
    /// What it showed.
    pub view: DeviceView,
}

impl DeviceReading {
    /// The reading as JSON, for the records.
    pub fn to_json(&self) -> Value {
        match &self.view {
            DeviceView::C29u(m) => {
                json!({"inputs": m.inputs, "outputs": m.outputs, "online": m.online})
            }
            DeviceView::Trc(p) => json!({
                "pressed": p.switches.map(|s| s.pressed_names()),
                "relay": p.relay,
                "online": p.online,
            }),
        }
    }

    /// The device's name.
    pub fn name(&self) -> &str {
        &self.name
    }
}

impl fmt::Display for DeviceReading {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let name = &self.name;
        match &self.view {
            DeviceView::C29u(m) => {
                write!(f, "{name} outputs {:#04x}, inputs ", m.outputs)?;
                match m.inputs {
                    Some(i) => write!(f, "{i:#04x}")?,
                    None => f.write_str("not read")?,
                }
            }
            DeviceView::Trc(p) => {
                write!(f, "{name} relay {}, pressed ", p.relay)?;
                match p.switches.map(|s| s.pressed_names()) {
                    Some(names) if names.is_empty() => f.write_str("none")?,
                    Some(names) => f.write_str(&names.join(" "))?,
                    None => f.write_str("not read")?,
                }
            }
        }
        f.write_str(if self.view.online() { "" } else { " (lost)" })
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
            "uptime_ms": super::snapshot::millis(self.uptime),
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
