//! Plain values the TRP-C29U model hands out: firmware, watchdog status, snapshot, state.

use super::config::Protocol;
use serde::{Deserialize, Serialize};

/// The firmware identity the module reports (8-15, 10-5).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Firmware {
    /// Module type text, `C29M`.
    pub model: &'static str,
    /// Two-digit year (9 = 2009).
    pub year: u8,
    /// Month 1..=12.
    pub month: u8,
    /// Day of month.
    pub day: u8,
}

/// The firmware of the simulated module (NOTES 8-15 / 10-5: `C29M`, 09-07-03).
pub const FIRMWARE: Firmware = Firmware {
    model: "C29M",
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

/// DO and DI as remembered by the last `#**` broadcast (8-25, 8-26).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Snapshot {
    /// True only on the first read after the `#**`.
    pub fresh: bool,
    /// DO byte at the time of the `#**`.
    pub outputs: u8,
    /// DI byte at the time of the `#**`, wire form (active-low).
    pub inputs_wire: u8,
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
