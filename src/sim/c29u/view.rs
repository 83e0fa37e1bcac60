//! Plain values the TRP-C29U model hands out: firmware, watchdog status, state.

use super::config::Protocol;
use crate::protocol::c29u::FirmwareDate;
use serde::{Deserialize, Serialize};

/// The firmware the simulated module reports (8-15 / 10-5 as read: model `C29M`, 09-07-03).
pub const FIRMWARE_MODEL: &str = "C29M";

/// The release date of [`FIRMWARE_MODEL`].
pub const FIRMWARE_DATE: FirmwareDate = FirmwareDate {
    year: 9,
    month: 7,
    day: 3,
};

/// Host watchdog mode and whether it has fired.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct WatchdogStatus {
    /// A timeout is set (stored in EEPROM).
    pub enabled: bool,
    /// Timeout in 0.1 s units, 0 when disabled.
    pub timeout_tenths: u8,
    /// The watchdog has fired: DO is at the safe value and output writes are refused.
    pub expired: bool,
}

/// The `watchdog` object of the `state` control line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct WatchdogState {
    /// A timeout is set.
    pub enabled: bool,
    /// Timeout in milliseconds, 0 when disabled.
    pub timeout_ms: u32,
    /// The watchdog has fired (safe mode).
    pub expired: bool,
}

/// Everything the `state` control line reports, serialized as exactly its JSON object.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SimState {
    /// Module ID.
    pub id: u8,
    /// `"ascii"` or `"modbus"`.
    pub protocol: Protocol,
    /// DO byte (JSON key `do`).
    #[serde(rename = "do")]
    pub outputs: u8,
    /// DI byte, logical: 1 = energized (JSON key `di`).
    #[serde(rename = "di")]
    pub inputs: u8,
    /// Live counter values, channel 0 first.
    pub counters: [u16; 8],
    /// Channels whose input has been energized since the last latch clear.
    pub latched_low: u8,
    /// Channels whose input has been released since the last latch clear.
    pub latched_high: u8,
    /// DO value driven when the watchdog fires.
    pub safe_value: u8,
    /// DO value driven at power on and after reset.
    pub power_on_value: u8,
    /// Module name.
    pub name: String,
    /// Host watchdog mode and status.
    pub watchdog: WatchdogState,
}
