//! The field side of a simulated rig: what a scenario test does to the simulators (press a
//! switch, turn a knob, energize an input, pull a cable) and what it reads back from them.

use super::links::Presence;
use crate::protocol::c29u::FirmwareDate;
use crate::sim::c29u::{Eeprom, OutputFault, WatchdogStatus};
use crate::sim::c29u_line::{lock, SharedModel};
use crate::sim::faults::answer::{AnswerFault, AnswerFaults};
use crate::sim::trc1000::Trc1000Sim;
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, MutexGuard};

/// One simulated device, shared with the link the runtime talks over.
#[derive(Clone)]
pub enum SimDevice {
    /// A simulated TRC1000.
    Trc {
        /// The board.
        board: Arc<Mutex<Trc1000Sim>>,
        /// Whether it answers.
        presence: Presence,
        /// Faults waiting for its next answers.
        faults: AnswerFaults,
    },
    /// A simulated TRP-C29U.
    C29u {
        /// The module.
        model: SharedModel,
        /// Whether it answers.
        presence: Presence,
        /// Faults waiting for its next answers.
        faults: AnswerFaults,
    },
}

/// The module `SimRig::swap_module` puts in another's place.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SwappedModule {
    /// Its name (8-14).
    pub name: String,
    /// Its firmware date.
    pub firmware: FirmwareDate,
    /// Its stored safe value.
    pub safe_value: u8,
    /// Its stored power-on value.
    pub power_on_value: u8,
    /// Its host watchdog, in 0.1 s (0: off).
    pub watchdog_tenths: u8,
}

impl Default for SwappedModule {
    /// A factory-fresh module of a later firmware: the factory name, zero values, no
    /// watchdog.
    fn default() -> Self {
        Self {
            name: crate::sim::c29u::DEFAULT_NAME.to_string(),
            firmware: FirmwareDate {
                year: 14,
                month: 9,
                day: 1,
            },
            safe_value: 0,
            power_on_value: 0,
            watchdog_tenths: 0,
        }
    }
}

/// Why a field-side action could not be done.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FieldError {
    /// No simulated device has that name.
    #[error("no simulated device called {name:?} (devices: {known})")]
    NoDevice {
        /// The name asked for.
        name: String,
        /// The names there are.
        known: String,
    },
    /// The device is of the other kind.
    #[error("{name} is a {kind}; {what} needs a {wanted}")]
    WrongKind {
        /// The device.
        name: String,
        /// What it is.
        kind: &'static str,
        /// What was asked.
        what: String,
        /// What it would take.
        wanted: &'static str,
    },
    /// The simulator refused (a bad switch name, a bad channel).
    #[error("{0}")]
    Refused(String),
}

/// The simulators of a rig by device name.
#[derive(Clone, Default)]
pub struct SimRig {
    devices: BTreeMap<String, SimDevice>,
}

fn board(b: &Arc<Mutex<Trc1000Sim>>) -> MutexGuard<'_, Trc1000Sim> {
    crate::sync::lock(b)
}

impl SimRig {
    /// Adds a simulator.
    pub fn insert(&mut self, name: &str, device: SimDevice) {
        self.devices.insert(name.to_string(), device);
    }

    /// The simulated devices' names, in order.
    pub fn names(&self) -> Vec<String> {
        self.devices.keys().cloned().collect()
    }

    /// Whether there are no simulators.
    pub fn is_empty(&self) -> bool {
        self.devices.is_empty()
    }

    /// The simulator called `name`.
    pub fn get(&self, name: &str) -> Result<&SimDevice, FieldError> {
        self.devices.get(name).ok_or_else(|| FieldError::NoDevice {
            name: name.to_string(),
            known: self.devices.keys().cloned().collect::<Vec<_>>().join(", "),
        })
    }

    /// The simulated TRC1000 called `name`, for `what`.
    pub fn trc(&self, name: &str, what: &str) -> Result<Arc<Mutex<Trc1000Sim>>, FieldError> {
        match self.get(name)? {
            SimDevice::Trc { board, .. } => Ok(Arc::clone(board)),
            SimDevice::C29u { .. } => Err(FieldError::WrongKind {
                name: name.to_string(),
                kind: "TRP-C29U",
                what: what.to_string(),
                wanted: "TRC1000",
            }),
        }
    }

    /// The simulated TRP-C29U called `name`, for `what`.
    pub fn c29u(&self, name: &str, what: &str) -> Result<SharedModel, FieldError> {
        match self.get(name)? {
            SimDevice::C29u { model, .. } => Ok(Arc::clone(model)),
            SimDevice::Trc { .. } => Err(FieldError::WrongKind {
                name: name.to_string(),
                kind: "TRC1000",
                what: what.to_string(),
                wanted: "TRP-C29U",
            }),
        }
    }

    /// Presses (or releases) a switch of a simulated TRC1000.
    pub fn set_switch(&self, dev: &str, switch: &str, pressed: bool) -> Result<(), FieldError> {
        let b = self.trc(dev, if pressed { "press" } else { "release" })?;
        let mut b = board(&b);
        let r = if pressed {
            b.press(switch)
        } else {
            b.release(switch)
        };
        r.map_err(|e| FieldError::Refused(e.to_string()))
    }

    /// Turns a rotary of a simulated TRC1000 by `half_turns`.
    pub fn turn(&self, dev: &str, rotary: &str, half_turns: i32) -> Result<(), FieldError> {
        let b = self.trc(dev, "turn")?;
        let r = board(&b).turn(rotary, half_turns);
        r.map_err(|e| FieldError::Refused(e.to_string()))
    }

    /// The relay a simulated TRC1000 has selected.
    pub fn relay(&self, dev: &str) -> Result<u8, FieldError> {
        let b = self.trc(dev, "relay")?;
        let relay = board(&b).relay().number();
        Ok(relay)
    }

    /// Sets the energized inputs of a simulated TRP-C29U.
    pub fn set_inputs(&self, dev: &str, energized: u8) -> Result<(), FieldError> {
        let m = self.c29u(dev, "set_inputs")?;
        lock(&m).set_inputs(energized);
        Ok(())
    }

    /// Energizes or releases one input of a simulated TRP-C29U.
    pub fn set_input(&self, dev: &str, channel: u8, on: bool) -> Result<(), FieldError> {
        let m = self.c29u(dev, "set_input")?;
        let mut m = lock(&m);
        if channel > 7 {
            return Err(FieldError::Refused(format!(
                "channel {channel} does not exist: use 0-7"
            )));
        }
        let bit = 1u8 << channel;
        let now = m.inputs();
        m.set_inputs(if on { now | bit } else { now & !bit });
        Ok(())
    }

    /// Applies `n` pulses to an input of a simulated TRP-C29U.
    pub fn pulse(&self, dev: &str, channel: u8, n: u32) -> Result<(), FieldError> {
        let m = self.c29u(dev, "pulse")?;
        let r = lock(&m).pulse(channel, n);
        r.map_err(|e| FieldError::Refused(e.to_string()))
    }

    /// Makes a simulated device stop answering, or answer again.
    pub fn set_gone(&self, dev: &str, gone: bool) -> Result<(), FieldError> {
        match self.get(dev)? {
            SimDevice::Trc { presence, .. } | SimDevice::C29u { presence, .. } => {
                presence.set_gone(gone);
            }
        }
        Ok(())
    }

    /// Drops, garbles, delays or (on a module) duplicates the next `n` answers of a simulated
    /// device; returns how many were queued (`sim::faults::answer::MAX_QUEUED` wait at most).
    pub fn fault_answers(
        &self,
        dev: &str,
        fault: AnswerFault,
        n: usize,
    ) -> Result<usize, FieldError> {
        match (self.get(dev)?, fault) {
            // USB's data toggle makes the host drop a packet sent again: a board's answer never
            // arrives twice.
            (SimDevice::Trc { .. }, AnswerFault::Duplicate) => Err(FieldError::WrongKind {
                name: dev.to_string(),
                kind: "TRC1000 (on USB, where a packet never arrives twice)",
                what: "a duplicated answer".into(),
                wanted: "TRP-C29U",
            }),
            (SimDevice::Trc { faults, .. } | SimDevice::C29u { faults, .. }, _) => {
                Ok(faults.push(fault, n))
            }
        }
    }

    /// Whether a simulated device answers (is not made gone).
    pub fn answers(&self, dev: &str) -> Result<bool, FieldError> {
        match self.get(dev)? {
            SimDevice::Trc { presence, .. } | SimDevice::C29u { presence, .. } => {
                Ok(!presence.is_gone())
            }
        }
    }

    /// Makes a simulated device take `delay` over each request (zero: answer at once).
    pub fn set_answer_delay(
        &self,
        dev: &str,
        delay: std::time::Duration,
    ) -> Result<(), FieldError> {
        match self.get(dev)? {
            SimDevice::Trc { presence, .. } | SimDevice::C29u { presence, .. } => {
                presence.set_delay(delay);
            }
        }
        Ok(())
    }

    /// Unplugs and replugs a simulated device.
    pub fn power_cycle(&self, dev: &str) -> Result<(), FieldError> {
        match self.get(dev)? {
            SimDevice::C29u { model, .. } => lock(model).power_cycle(),
            SimDevice::Trc {
                board: b, faults, ..
            } => {
                // A board that loses power falls off the USB bus: the request under way gets no
                // answer, and the runner takes it back at its next try. It comes back with relay
                // 0 and its counts at 0; held switches stay held.
                faults.clear();
                faults.push(AnswerFault::Drop, 1);
                let mut b = board(b);
                let held = b.switches();
                *b = Trc1000Sim::new();
                for s in held.pressed() {
                    b.set_switch(s, true);
                }
            }
        }
        Ok(())
    }

    /// Makes the output stage of a simulated TRP-C29U faulty (`None`: sound again): writes
    /// acknowledged and ignored, or refused with an exception code.
    pub fn set_output_fault(
        &self,
        dev: &str,
        fault: Option<OutputFault>,
    ) -> Result<(), FieldError> {
        let m = self.c29u(dev, "output fault")?;
        lock(&m).set_output_fault(fault);
        Ok(())
    }

    /// Puts another module in the place of a simulated TRP-C29U, behind the same open link:
    /// same ID and line settings, `other`'s name, firmware and stored values.
    pub fn swap_module(&self, dev: &str, other: &SwappedModule) -> Result<(), FieldError> {
        let m = self.c29u(dev, "swap")?;
        let mut m = lock(&m);
        let mut eeprom = Eeprom::factory();
        other.name.clone_into(&mut eeprom.name);
        eeprom.safe_value = other.safe_value;
        eeprom.power_on_value = other.power_on_value;
        eeprom.watchdog_tenths = other.watchdog_tenths;
        m.swap(eeprom, other.firmware)
            .map_err(|e| FieldError::Refused(e.to_string()))
    }

    /// The DO byte of a simulated TRP-C29U (as the module drives it now).
    pub fn outputs(&self, dev: &str) -> Result<u8, FieldError> {
        let m = self.c29u(dev, "outputs")?;
        let v = lock(&m).outputs();
        Ok(v)
    }

    /// Whether a simulated TRP-C29U is in safe mode.
    pub fn safe_mode(&self, dev: &str) -> Result<bool, FieldError> {
        let m = self.c29u(dev, "safe_mode")?;
        let v = lock(&m).in_safe_mode();
        Ok(v)
    }

    /// The stored safe value of a simulated TRP-C29U.
    pub fn safe_value(&self, dev: &str) -> Result<u8, FieldError> {
        let m = self.c29u(dev, "safe_value")?;
        let v = lock(&m).safe_value();
        Ok(v)
    }

    /// The stored power-on value of a simulated TRP-C29U.
    pub fn power_on_value(&self, dev: &str) -> Result<u8, FieldError> {
        let m = self.c29u(dev, "power_on_value")?;
        let v = lock(&m).power_on_value();
        Ok(v)
    }

    /// The host watchdog of a simulated TRP-C29U.
    pub fn watchdog(&self, dev: &str) -> Result<WatchdogStatus, FieldError> {
        let m = self.c29u(dev, "watchdog")?;
        let v = lock(&m).watchdog();
        Ok(v)
    }

    /// One live counter of a simulated TRP-C29U.
    pub fn counter(&self, dev: &str, channel: u8) -> Result<u16, FieldError> {
        let m = self.c29u(dev, "counter")?;
        let r = lock(&m).counter(channel);
        r.map_err(|e| FieldError::Refused(e.to_string()))
    }
}
