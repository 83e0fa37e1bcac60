//! Taking control of a TRP-C29U, one exchange at a time: who it is and what it stores read and
//! recorded (name, firmware, watchdog, safe and power-on values: `identity::Found`; its reset
//! flag cleared, so that the periodic check sees a later reset), the stored safe and power-on values
//! set to the wanted ones (only where they differ, to spare the EEPROM), the outputs written
//! (leaving safe mode first if the module refuses because it is in it), and the host watchdog
//! on and fed. One exchange a step, so the runner can feed the other modules' watchdogs
//! between steps whatever each exchange takes.

use super::c29u::C29uDevice;
use super::identity::Found;
use super::DeviceError;
use crate::device::c29u::{C29u, C29uError, Preset, PresetWrite, WatchdogInfo, WatchdogTimeout};
use std::time::Duration;

/// Stores a preset without the outputs taking a value other than the safe one: over ASCII, where
/// the module stores only its current outputs (8-24), the outputs are driven to `value` first
/// when it is the safe value; any other value is refused (`PresetDrivesOutputs`, naming the
/// `c29` command that can store it).
fn store_at_safe_value(d: &mut C29u, preset: Preset, value: u8, safe: u8) -> Result<(), C29uError> {
    match d.store_preset(preset, value, PresetWrite::KeepOutputs) {
        Err(C29uError::PresetDrivesOutputs { .. }) if value == safe => {
            d.write_outputs(safe)?;
            d.store_preset(preset, value, PresetWrite::KeepOutputs)
        }
        other => other,
    }
}

/// What taking control of a module found worth telling.
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub struct ControlNotes {
    /// It was in safe mode; its watchdog was disabled to leave it.
    pub left_safe_mode: bool,
    /// Its own watchdog was on without rig.toml asking; the runner feeds it.
    pub adopted_watchdog: Option<WatchdogTimeout>,
    /// Its stored safe value was changed to the wanted one (from this).
    pub safe_value_was: Option<u8>,
    /// Its stored power-on value was changed to the wanted one (from this).
    pub power_on_value_was: Option<u8>,
    /// rig.toml sets no power-on value and the module's (this) is not its safe value: a power
    /// cycle drives it until the runner notices.
    pub power_on_unsafe: Option<u8>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stage {
    ReadName,
    ReadFirmware,
    ClearResetFlag,
    ReadWatchdog,
    ReadSafe,
    WriteSafe,
    ReadPowerOn,
    WritePowerOn,
    WriteOutputs,
    /// Refused in safe mode: turn the watchdog off (the only way out), then do `resume`.
    LeaveSafeMode {
        resume: Write,
    },
    Watchdog,
    Done,
}

/// A stage that writes, and so may be refused in safe mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Write {
    SafeValue,
    PowerOnValue,
    Outputs,
}

/// Taking control of one module, step by step.
#[derive(Debug, Clone)]
pub struct Takeover {
    outputs: u8,
    stage: Stage,
    before: Option<WatchdogInfo>,
    notes: ControlNotes,
    name: String,
    firmware: String,
}

impl Takeover {
    /// Taking control with `outputs` to write.
    pub fn new(outputs: u8) -> Self {
        Self {
            outputs,
            stage: Stage::ReadName,
            before: None,
            notes: ControlNotes::default(),
            name: String::new(),
            firmware: String::new(),
        }
    }

    /// What was found so far.
    pub fn notes(&self) -> &ControlNotes {
        &self.notes
    }

    /// Does the next exchange at `now`; true once the module is under control.
    pub fn step(&mut self, d: &mut C29uDevice, now: Duration) -> Result<bool, DeviceError> {
        self.stage = match self.stage {
            Stage::ReadName => {
                self.name = d.driver.name()?;
                Stage::ReadFirmware
            }
            Stage::ReadFirmware => {
                self.firmware = d.driver.firmware()?.text;
                Stage::ClearResetFlag
            }
            Stage::ClearResetFlag => {
                d.driver.take_reset_flag()?;
                d.reset_by_script = false;
                Stage::ReadWatchdog
            }
            Stage::ReadWatchdog => {
                self.before = Some(d.driver.watchdog()?);
                Stage::ReadSafe
            }
            Stage::ReadSafe => {
                let stored = d.driver.safe_value()?;
                d.stored.safe_value = Some(stored);
                if stored == d.config.safe_value {
                    Stage::ReadPowerOn
                } else {
                    self.notes.safe_value_was = Some(stored);
                    Stage::WriteSafe
                }
            }
            Stage::ReadPowerOn => {
                let stored = d.driver.power_on_value()?;
                d.stored.power_on_value = Some(stored);
                self.record(d, stored);
                match d.config.power_on_value {
                    None => {
                        if stored != d.config.safe_value {
                            self.notes.power_on_unsafe = Some(stored);
                        }
                        Stage::WriteOutputs
                    }
                    Some(wanted) if stored == wanted => Stage::WriteOutputs,
                    Some(_) => {
                        self.notes.power_on_value_was = Some(stored);
                        Stage::WritePowerOn
                    }
                }
            }
            Stage::WriteSafe => self.write(d, Write::SafeValue, now)?,
            Stage::WritePowerOn => self.write(d, Write::PowerOnValue, now)?,
            Stage::WriteOutputs => self.write(d, Write::Outputs, now)?,
            Stage::LeaveSafeMode { resume } => {
                d.driver.set_watchdog(None)?;
                d.stored.watchdog = Some(None);
                self.notes.left_safe_mode = true;
                match resume {
                    Write::SafeValue => Stage::WriteSafe,
                    Write::PowerOnValue => Stage::WritePowerOn,
                    Write::Outputs => Stage::WriteOutputs,
                }
            }
            Stage::Watchdog => {
                self.watchdog(d, now)?;
                d.controlled = true;
                Stage::Done
            }
            Stage::Done => Stage::Done,
        };
        Ok(self.stage == Stage::Done)
    }

    /// Records who the module is and what it stored, before anything was written to it.
    fn record(&self, d: &mut C29uDevice, power_on_value: u8) {
        let watchdog = self.before.and_then(super::identity::watchdog_of);
        d.found = Some(Found {
            name: self.name.clone(),
            firmware: self.firmware.clone(),
            watchdog,
            safe_value: self.notes.safe_value_was.unwrap_or(d.config.safe_value),
            power_on_value,
        });
    }

    /// One write; a refusal in safe mode (the first time) leads out of it and back here. A
    /// module that still answers "safe mode" with its watchdog off is not in safe mode but
    /// refuses writes: its watchdog goes back on (it may yet make the module safe by itself),
    /// and the refusal is the error, as a refusal (`refusing`: not taken for safe mode again
    /// until a write gets through).
    fn write(
        &mut self,
        d: &mut C29uDevice,
        step: Write,
        now: Duration,
    ) -> Result<Stage, DeviceError> {
        let safe = d.config.safe_value;
        let result = match step {
            Write::SafeValue => store_at_safe_value(&mut d.driver, Preset::Safe, safe, safe),
            Write::PowerOnValue => match d.config.power_on_value {
                Some(v) => store_at_safe_value(&mut d.driver, Preset::PowerOn, v, safe),
                None => Ok(()),
            },
            Write::Outputs => d.driver.write_outputs(self.outputs),
        };
        match result {
            Err(C29uError::SafeMode { .. })
                if !self.notes.left_safe_mode && self.may_be_in_safe_mode(d) =>
            {
                return Ok(Stage::LeaveSafeMode { resume: step });
            }
            Err(C29uError::SafeMode { port, id }) => {
                d.refusing = true;
                self.watchdog(d, now)?;
                return Err(C29uError::Refused {
                    port,
                    id,
                    request: "the write".into(),
                    reason: "exception: module in safe mode (FF), with its watchdog off: it \
                             refuses writes"
                        .into(),
                }
                .into());
            }
            other => other?,
        }
        Ok(match step {
            Write::SafeValue => {
                d.stored.safe_value = Some(d.config.safe_value);
                Stage::ReadPowerOn
            }
            Write::PowerOnValue => {
                d.stored.power_on_value = d.config.power_on_value;
                Stage::WriteOutputs
            }
            Write::Outputs => {
                d.note_outputs_written(self.outputs);
                d.refusing = false;
                Stage::Watchdog
            }
        })
    }

    /// Whether a "safe mode" refusal can be one: safe mode is a watchdog that fired, so a
    /// module whose watchdog was found off (or that is known to refuse writes) is refusing,
    /// and turning its watchdog off again would only store what it holds already.
    fn may_be_in_safe_mode(&self, d: &C29uDevice) -> bool {
        !d.refusing
            && self
                .before
                .map_or(true, |w| w.enabled || w.expired == Some(true))
    }

    /// The host watchdog on and fed: the wanted one, or the module's own when none is wanted
    /// (adopted: the runner feeds it, and leaves it on at the end).
    fn watchdog(&mut self, d: &mut C29uDevice, now: Duration) -> Result<(), DeviceError> {
        let before = self.before.unwrap_or(WatchdogInfo {
            enabled: false,
            timeout_tenths: 0,
            expired: None,
        });
        let module_own =
            WatchdogTimeout::from_tenths(before.timeout_tenths).filter(|_| before.enabled);
        let left = self.notes.left_safe_mode;
        match (d.watchdog, module_own) {
            (Some(t), _) => {
                let same = before.enabled && before.timeout_tenths == t.tenths();
                if same && !left {
                    d.driver.host_ok()?;
                } else {
                    d.driver.set_watchdog(Some(t.as_duration()))?;
                }
                d.stored.watchdog = Some(Some(t));
                d.watchdog_ours = true;
            }
            (None, Some(own)) => {
                if left {
                    d.driver.set_watchdog(Some(own.as_duration()))?;
                } else {
                    d.driver.host_ok()?;
                }
                d.stored.watchdog = Some(Some(own));
                d.watchdog = Some(own);
                self.notes.adopted_watchdog = Some(own);
            }
            (None, None) => d.stored.watchdog = Some(None),
        }
        d.last_feed = now;
        Ok(())
    }
}
