//! Writing and confirming a rig's safe state from rig.toml alone, device by device: what
//! `rigscript safe` does by hand and the guardian does when the runner died. Nothing here needs
//! the runner: each device is opened afresh, written, and read back.

use crate::config::{DeviceConfig, Port, RigConfig};
use crate::runtime::devices::links::TransactionCounter;
use crate::runtime::devices::{open_devices, Device, DeviceError, OpenError};
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
    /// A TRP-C29U's outputs, read back after the write.
    Outputs(u8),
    /// A TRC1000's relay, selected and confirmed by a request after it.
    Relay(u8),
    /// A TRC1000 without a `safe_relay` in rig.toml: nothing to write.
    NoSafeRelay,
}

/// Why a device's safe state is not confirmed.
#[derive(Debug, thiserror::Error)]
pub enum SafeError {
    /// The device cannot be opened (missing, busy, no permission).
    #[error("{}", .0.source)]
    Open(Box<OpenError>),
    /// It did not answer, or answered with an error.
    #[error("{0}")]
    Device(#[from] DeviceError),
    /// It answered the write, but its outputs read back otherwise: it refused or ignored it.
    #[error("outputs read back {read:#04x} after {wanted:#04x} was written: the module did not apply its safe value")]
    NotApplied {
        /// The safe value written.
        wanted: u8,
        /// What the module's outputs read.
        read: u8,
    },
    /// A simulated device lives inside the runner: nothing outside it can reach it.
    #[error("simulated: it lives in the runner, nothing outside it can reach it")]
    Simulated,
}

impl SafeError {
    /// Whether the device was not reached at all (as opposed to reached and not confirming).
    pub fn unreachable(&self) -> bool {
        match self {
            SafeError::Open(_) | SafeError::Simulated => true,
            SafeError::Device(e) => e.is_comm_failure() || e.is_link_failure(),
            SafeError::NotApplied { .. } => false,
        }
    }
}

impl fmt::Display for Confirmed {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Confirmed::Outputs(v) => write!(f, "outputs {v:#04x} (read back)"),
            Confirmed::Relay(r) => write!(f, "relay {r} (confirmed)"),
            Confirmed::NoSafeRelay => f.write_str("no safe_relay in rig.toml: relay left as it is"),
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
    if let DeviceConfig::C29u(c) = device {
        if c.port == Port::Simulated {
            return Err(SafeError::Simulated);
        }
    }
    let alone = RigConfig {
        devices: BTreeMap::from([(name.to_string(), device.clone())]),
        ..config.clone()
    };
    let mut opened = open_devices(&alone, clock, false, &TransactionCounter::default())
        .map_err(|e| SafeError::Open(Box::new(e)))?;
    match opened.devices.first_mut() {
        Some(d) => confirm_safe(d),
        None => Err(SafeError::Simulated),
    }
}

/// Writes the device's safe state and confirms it: a TRP-C29U's outputs are read back (a
/// module in safe mode refuses the write but should hold the value already, which the
/// read-back shows either way); a TRC1000's relay is confirmed by a request after it.
pub fn confirm_safe(device: &mut Device) -> Result<Confirmed, SafeError> {
    match device {
        Device::C29u(d) => {
            d.write_safe()?;
            let wanted = d.config.safe_value;
            let read = d.driver.read_outputs().map_err(DeviceError::from)?;
            if read == wanted {
                Ok(Confirmed::Outputs(read))
            } else {
                Err(SafeError::NotApplied { wanted, read })
            }
        }
        Device::Trc(t) => match t.config.safe_relay {
            Some(r) => {
                t.select_relay_confirmed(r)?;
                Ok(Confirmed::Relay(r))
            }
            None => Ok(Confirmed::NoSafeRelay),
        },
    }
}
