//! Knowing the module the runner talks to: who it is and what it stores, as taking control
//! found it (`Found`), and the periodic check that it still is, one exchange a step
//! (`ModuleCheck`). Behind a link that stays open (a serial server, a hub, an RS-485 bus) the
//! module on the line can change, and one can be reset or power cycled, without the link
//! telling.
//!
//! A check costs four requests: the reset flag (8-16, 10-6: set by a reset or power on, cleared
//! by reading it; a module swapped in has just powered on), the outputs, the host watchdog, and
//! one of the safe value, power-on value, name and firmware in turn, so each of those is read
//! every fourth check. The watchdog is read every time: it is what makes the module safe if
//! the runner dies.

use super::c29u::C29uDevice;
use super::DeviceError;
use crate::device::c29u::{WatchdogInfo, WatchdogTimeout};
use crate::time::duration::format_duration;

/// Who a module is and what it stores: as taking control found it before writing anything,
/// or as the runner expects it to be since.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Found {
    /// Its name (8-14; the model code over Modbus, 10-1).
    pub name: String,
    /// Its firmware, as it reports it (8-15, 10-5).
    pub firmware: String,
    /// Its host watchdog (`None`: off).
    pub watchdog: Option<WatchdogTimeout>,
    /// Its stored safe value.
    pub safe_value: u8,
    /// Its stored power-on value.
    pub power_on_value: u8,
}

impl Found {
    /// What differs from `was`, in words: `name ABCDEF (was TRPC29), safe value 0xff (was 0x05)`.
    pub fn differences(&self, was: &Found) -> Vec<String> {
        let mut out = Vec::new();
        let mut note = |what: &str, now: String, then: String| {
            if now != then {
                out.push(format!("{what} {now} (was {then})"));
            }
        };
        note("name", self.name.clone(), was.name.clone());
        note("firmware", self.firmware.clone(), was.firmware.clone());
        note(
            "host watchdog",
            watchdog_words(self.watchdog),
            watchdog_words(was.watchdog),
        );
        note(
            "safe value",
            format!("{:#04x}", self.safe_value),
            format!("{:#04x}", was.safe_value),
        );
        note(
            "power-on value",
            format!("{:#04x}", self.power_on_value),
            format!("{:#04x}", was.power_on_value),
        );
        out
    }
}

/// `1s`, `off`.
pub fn watchdog_words(w: Option<WatchdogTimeout>) -> String {
    w.map_or_else(|| "off".into(), |t| format_duration(t.as_duration()))
}

/// The watchdog a reading shows (`None`: off).
pub fn watchdog_of(info: WatchdogInfo) -> Option<WatchdogTimeout> {
    WatchdogTimeout::from_tenths(info.timeout_tenths).filter(|_| info.enabled)
}

/// What a periodic check found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CheckFinding {
    /// The module is as the runner left it.
    Same,
    /// Its reset flag is set: reset or power cycled behind the runner's back.
    Reset,
    /// An item reads other than the runner expects: another module, or one changed by
    /// someone else.
    Differs {
        /// The item.
        what: &'static str,
        /// What it reads.
        read: String,
        /// What the runner expects.
        expected: String,
    },
    /// The outputs read `read` though `written` was written (and no reset explains it).
    Outputs {
        /// What they read.
        read: u8,
        /// What was written.
        written: u8,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stage {
    ResetFlag,
    Outputs,
    Watchdog,
    InTurn,
}

/// One periodic check of a module, one exchange a step (the runner feeds the other modules'
/// watchdogs between steps).
#[derive(Debug, Clone)]
pub struct ModuleCheck {
    stage: Stage,
    outputs: Option<CheckFinding>,
}

impl Default for ModuleCheck {
    fn default() -> Self {
        Self::new()
    }
}

impl ModuleCheck {
    /// A check from its first request.
    pub fn new() -> Self {
        Self {
            stage: Stage::ResetFlag,
            outputs: None,
        }
    }

    /// Does the next exchange; `Some` once the check has its finding.
    pub fn step(&mut self, d: &mut C29uDevice) -> Result<Option<CheckFinding>, DeviceError> {
        match self.stage {
            Stage::ResetFlag => {
                let reset = d.driver.take_reset_flag()?;
                if std::mem::take(&mut d.reset_by_script) {
                    // The script's own `.reset()`: its outputs are written again anyway.
                } else if reset {
                    return Ok(Some(CheckFinding::Reset));
                }
                self.stage = Stage::Outputs;
            }
            Stage::Outputs => {
                if let Some(written) = d.outputs_written() {
                    let read = d.driver.read_outputs()?;
                    if read != written {
                        self.outputs = Some(CheckFinding::Outputs { read, written });
                    }
                }
                self.stage = Stage::Watchdog;
            }
            Stage::Watchdog => {
                let read = watchdog_of(d.driver.watchdog()?);
                if let Some(expected) = d.stored.watchdog {
                    if read != expected {
                        return Ok(Some(CheckFinding::Differs {
                            what: "host watchdog",
                            read: watchdog_words(read),
                            expected: watchdog_words(expected),
                        }));
                    }
                }
                self.stage = Stage::InTurn;
            }
            Stage::InTurn => {
                let turn = d.check_turn;
                d.check_turn = (turn + 1) % 4;
                if let Some(found) = d.expected() {
                    if let Some(differs) = read_in_turn(d, turn, &found)? {
                        return Ok(Some(differs));
                    }
                }
                return Ok(Some(self.outputs.take().unwrap_or(CheckFinding::Same)));
            }
        }
        Ok(None)
    }
}

/// Reads item `turn` of the safe value, power-on value, name and firmware; a finding if it
/// is not what `expected` says.
fn read_in_turn(
    d: &mut C29uDevice,
    turn: usize,
    expected: &Found,
) -> Result<Option<CheckFinding>, DeviceError> {
    let byte = |v: u8| format!("{v:#04x}");
    let (what, read, wanted) = match turn {
        0 => (
            "safe value",
            byte(d.driver.safe_value()?),
            byte(expected.safe_value),
        ),
        1 => (
            "power-on value",
            byte(d.driver.power_on_value()?),
            byte(expected.power_on_value),
        ),
        2 => ("name", d.driver.name()?, expected.name.clone()),
        _ => (
            "firmware",
            d.driver.firmware()?.text,
            expected.firmware.clone(),
        ),
    };
    Ok((read != wanted).then_some(CheckFinding::Differs {
        what,
        read,
        expected: wanted,
    }))
}
