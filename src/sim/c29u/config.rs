//! The communication settings the TRP-C29U keeps in EEPROM (8-1..8-3, 10-2..10-4).

use super::SimError;
use serde::{Deserialize, Serialize};

pub use crate::protocol::c29u::{CounterEdge, Protocol};

/// The digital I/O module type every C29U reports and accepts in `%` and `$ID2` (8-1, 8-12).
pub const DIO_TYPE: u8 = 0x40;

/// The model code in bits 2..0 of the format reported by `$ID2` (8-12: 3 = TRP-C29U).
pub const MODEL_CODE: u8 = 3;

/// Data format bit 7: counters count falling edges (8-3).
const FMT_FALLING: u8 = 0x80;
/// Data format bit 6: ASCII checksum enabled (8-3).
const FMT_CHECKSUM: u8 = 0x40;
/// Data format bit 0: counters shown in hex, "engineer mode" (8-3).
const FMT_HEX: u8 = 0x01;

/// Settings stored in EEPROM that define how the module talks (8-1..8-3, 10-2..10-4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct ModuleConfig {
    /// Module address: 00-FF in ASCII mode, 1-247 for Modbus.
    pub id: u8,
    /// Baud rate code 03..=0A (8-2).
    pub baud_code: u8,
    /// ASCII checksum on commands and answers.
    pub checksum: bool,
    /// Which edge the input counters count.
    pub counter_edge: CounterEdge,
    /// ASCII counter answers in 4 hex digits instead of 5 decimal ones.
    pub hex_counters: bool,
}

impl ModuleConfig {
    /// Factory settings (section 4): ID 01, 9600 baud, no checksum, rising edges, decimal counters.
    pub fn factory() -> Self {
        Self {
            id: 1,
            baud_code: 0x06,
            checksum: false,
            counter_edge: CounterEdge::Rising,
            hex_counters: false,
        }
    }

    /// Settings from the fields of a `%IDNNPPBBDD` command (8-1); rejects a bad baud code or a
    /// data format with any of the unused bits 5..1 set.
    pub fn from_parts(id: u8, baud_code: u8, data_format: u8) -> Result<Self, SimError> {
        let used = FMT_FALLING | FMT_CHECKSUM | FMT_HEX;
        if data_format & !used != 0 {
            return Err(SimError::BadValue(format!(
                "data format {data_format:02X}: bits 5..1 must be 0 (8-3)"
            )));
        }
        let cfg = Self {
            id,
            baud_code,
            checksum: data_format & FMT_CHECKSUM != 0,
            counter_edge: if data_format & FMT_FALLING != 0 {
                CounterEdge::Falling
            } else {
                CounterEdge::Rising
            },
            hex_counters: data_format & FMT_HEX != 0,
        };
        cfg.validate()?;
        Ok(cfg)
    }

    /// The data format byte as SET by `%` (8-3): bit 7 falling, bit 6 checksum, bit 0 hex.
    pub fn data_format(&self) -> u8 {
        let mut dd = 0;
        if self.counter_edge == CounterEdge::Falling {
            dd |= FMT_FALLING;
        }
        if self.checksum {
            dd |= FMT_CHECKSUM;
        }
        if self.hex_counters {
            dd |= FMT_HEX;
        }
        dd
    }

    /// The data format byte as READ by `$ID2` (NOTES): bit 7 edge, bit 6 checksum, bits 2..0 = 3.
    pub fn reported_format(&self) -> u8 {
        (self.data_format() & (FMT_FALLING | FMT_CHECKSUM)) | MODEL_CODE
    }

    /// The line speed the baud code stands for, if it is one of 03..=0A.
    pub fn baud_rate(&self) -> Option<u32> {
        baud_rate(self.baud_code)
    }

    /// Checks what every protocol requires: a baud code from the 8-2 table.
    pub fn validate(&self) -> Result<(), SimError> {
        if baud_rate(self.baud_code).is_none() {
            return Err(SimError::BadValue(format!(
                "baud code {:02X} outside 03..=0A (8-2)",
                self.baud_code
            )));
        }
        Ok(())
    }
}

impl Default for ModuleConfig {
    fn default() -> Self {
        Self::factory()
    }
}

/// Baud rate for a code of the 8-2 table, `None` outside 03..=0A.
pub use crate::protocol::c29u::baud_rate;
