//! Writing and confirming a rig's safe state from rig.toml alone, device by device: what
//! `rigscript safe` does by hand and the guardian does when the runner died. Nothing here needs
//! the runner: each device is opened afresh, written, and read back.

use crate::config::{DeviceConfig, RigConfig};
use crate::runtime::devices::links::TransactionCounter;
use crate::runtime::devices::{Device, OpenError};
use crate::runtime::safety::{confirm_safe_state, SafeDriver, SafeReading, Unconfirmed, END_TRIES};
use crate::sim::rig::open_devices;
use crate::time::clock::SharedClock;
use std::collections::BTreeMap;
use std::fmt;

/// How one device's safe state went.
#[derive(Debug)]
pub struct DeviceOutcome {
    /// The device's name in rig.toml.
    pub device: String,
    /// What was confirmed, or why it was not.
    pub result: Result<Confirmed, SafeError>,
}

/// A safe state the device confirmed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Confirmed {
    /// Read back: a TRP-C29U's outputs, or a TRC1000's relay confirmed by a request after it.
    Reading(SafeReading),
    /// A TRC1000 without a `safe_relay` in rig.toml: nothing to write.
    NoSafeRelay,
    /// A simulated device: it lives in the runner and ended with it.
    Simulated,
}

/// Why a device's safe state is not confirmed.
#[derive(Debug, thiserror::Error)]
pub enum SafeError {
    /// The device cannot be opened (missing, busy, no permission).
    #[error("{}", .0.source)]
    Open(Box<OpenError>),
    /// It did not answer, or answered otherwise than its safe state.
    #[error(transparent)]
    Unconfirmed(#[from] Unconfirmed),
}

impl SafeError {
    /// Whether the device was not reached at all (as opposed to reached and not confirming).
    pub fn unreachable(&self) -> bool {
        match self {
            SafeError::Open(_) => true,
            SafeError::Unconfirmed(u) => u.is_no_answer(),
        }
    }
}

impl fmt::Display for Confirmed {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Confirmed::Reading(SafeReading::Outputs(v)) => {
                write!(f, "outputs {v:#04x} (read back)")
            }
            Confirmed::Reading(SafeReading::Relay(r)) => write!(f, "relay {r} (confirmed)"),
            Confirmed::NoSafeRelay => f.write_str("no safe_relay in rig.toml: relay left as it is"),
            Confirmed::Simulated => {
                f.write_str("simulated: nothing outside the runner to make safe")
            }
        }
    }
}

impl fmt::Display for DeviceOutcome {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.result {
            Ok(c) => write!(f, "{} {c}", self.device),
            Err(e) => write!(f, "{} NOT confirmed: {e}", self.device),
        }
    }
}

/// Writes and confirms the safe state of every device `config` names, one at a time (modules
/// sharing an RS-485 port each open it in turn), with each device's own timeout and retries.
pub fn make_safe(config: &RigConfig, clock: &SharedClock) -> Vec<DeviceOutcome> {
    config
        .devices
        .iter()
        .map(|(name, device)| DeviceOutcome {
            device: name.clone(),
            result: make_one_safe(config, name, device, clock),
        })
        .collect()
}

fn make_one_safe(
    config: &RigConfig,
    name: &str,
    device: &DeviceConfig,
    clock: &SharedClock,
) -> Result<Confirmed, SafeError> {
    if config.is_simulated(name) {
        return Ok(Confirmed::Simulated);
    }
    let alone = RigConfig {
        devices: BTreeMap::from([(name.to_string(), device.clone())]),
        ..config.clone()
    };
    let mut opened = open_devices(&alone, clock, false, &TransactionCounter::default())
        .map_err(|e| SafeError::Open(Box::new(e)))?;
    match opened.devices.first_mut() {
        Some(d) => confirm(d),
        None => Ok(Confirmed::Simulated),
    }
}

/// Writes the device's safe state and confirms it (`safety::confirm_safe_state`) with the
/// driver's configured retries, in two tries.
fn confirm(device: &mut Device) -> Result<Confirmed, SafeError> {
    let target = match device {
        Device::C29u(d) => {
            let (driver, safe_value) = d.safe_driver(false);
            SafeDriver::C29u { driver, safe_value }
        }
        Device::Trc(t) => match t.safe_driver() {
            Some((driver, relay)) => SafeDriver::Trc1000 { driver, relay },
            None => return Ok(Confirmed::NoSafeRelay),
        },
    };
    Ok(Confirmed::Reading(confirm_safe_state(target, END_TRIES)?))
}
