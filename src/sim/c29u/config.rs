//! The communication settings the TRP-C29U keeps in EEPROM (8-1..8-3, 10-2..10-4).

use super::C29uModelError;
use crate::protocol::c29u_ascii::{ConfigReport, DataFormat};
use serde::{Deserialize, Serialize};

pub use crate::protocol::c29u::{CounterEdge, Protocol};

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

    /// Settings from the fields of a `%IDNNPPBBDD` command (8-1); rejects a bad baud code.
    pub fn from_parts(id: u8, baud_code: u8, format: DataFormat) -> Result<Self, C29uModelError> {
        let cfg = Self {
            id,
            baud_code,
            checksum: format.checksum,
            counter_edge: if format.falling_edge {
                CounterEdge::Falling
            } else {
                CounterEdge::Rising
            },
            hex_counters: format.hex_counters,
        };
        cfg.validate()?;
        Ok(cfg)
    }

    /// The data format as `%` sets it (8-3).
    pub fn data_format(&self) -> DataFormat {
        DataFormat {
            falling_edge: self.counter_edge == CounterEdge::Falling,
            checksum: self.checksum,
            hex_counters: self.hex_counters,
        }
    }

    /// What `$ID2` answers for these settings (8-12 as read).
    pub fn report(&self) -> ConfigReport {
        ConfigReport::of_c29u(self.baud_code, self.data_format())
    }

    /// The line speed the baud code stands for, if it is one of 03..=0A.
    pub fn baud_rate(&self) -> Option<u32> {
        baud_rate(self.baud_code)
    }

    /// Checks what every protocol requires: a baud code from the 8-2 table.
    pub fn validate(&self) -> Result<(), C29uModelError> {
        if baud_rate(self.baud_code).is_none() {
            return Err(C29uModelError::BadValue(format!(
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
