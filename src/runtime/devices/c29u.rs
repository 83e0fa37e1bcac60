//! A TRP-C29U as the runtime holds it: driver, input/counter/latch snapshots, the DO byte the
//! script wants and the one last written, the host watchdog the runner feeds, and the steps
//! that put the module under the runner's supervision (at start and when it comes back).

use super::{DeviceError, Health, Snapshot};
use crate::config::C29uConfig;
use crate::device::c29u::{
    C29u, C29uError, Latches, Preset, PresetWrite, SharedLink, WatchdogTimeout,
};
use crate::link::{ByteLink, LinkError};
use std::time::Duration;

/// Opens the module's line again (a serial port after an unplug); `None` for a simulator.
pub type ByteReopener = Box<dyn FnMut() -> Result<Box<dyn ByteLink>, LinkError>>;

/// A TRP-C29U in the rig.
pub struct C29uDevice {
    /// The name scripts use.
    pub name: String,
    /// Its configuration; the script may change the safe value, power-on value and watchdog.
    pub config: C29uConfig,
    /// The driver, with the configured retries.
    pub driver: C29u,
    /// A driver on the same line without retries: a lost module costs one timeout per try.
    probe: C29u,
    line: SharedLink,
    reopener: Option<ByteReopener>,
    /// Whether it answers.
    pub health: Health,
    /// DI byte (bit n = DIn energized), read lazily.
    pub inputs: Snapshot<u8>,
    /// The eight counters, read lazily.
    pub counters: Snapshot<[u16; 8]>,
    /// The latches, read lazily.
    pub latches: Snapshot<Latches>,
    /// The DO byte the script wants.
    pub outputs: u8,
    /// The DO byte last written (`None`: unknown, write again).
    pub outputs_written: Option<u8>,
    /// The handler that last changed `outputs`, for the log.
    pub outputs_cause: String,
    /// The host watchdog the runner feeds (`None`: none).
    pub watchdog: Option<WatchdogTimeout>,
    /// The runner turned that watchdog on (and turns it off at a clean end).
    pub watchdog_ours: bool,
    /// When the watchdog was last fed.
    pub last_feed: Duration,
}

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
    /// Its stored safe value was changed to the configured one (from this).
    pub safe_value_was: Option<u8>,
    /// Its stored power-on value was changed to the configured one (from this).
    pub power_on_value_was: Option<u8>,
}

impl C29uDevice {
    /// A module called `name` on `line`.
    pub fn new(
        name: &str,
        config: C29uConfig,
        driver: C29u,
        probe: C29u,
        line: SharedLink,
        reopener: Option<ByteReopener>,
    ) -> Self {
        Self {
            name: name.to_string(),
            outputs: config.safe_value,
            watchdog: config.watchdog,
            config,
            driver,
            probe,
            line,
            reopener,
            health: Health::default(),
            inputs: Snapshot::default(),
            counters: Snapshot::default(),
            latches: Snapshot::default(),
            outputs_written: None,
            outputs_cause: String::new(),
            watchdog_ours: false,
            last_feed: Duration::ZERO,
        }
    }

    /// Reads the inputs into the snapshot at `tick`.
    pub fn read_inputs(&mut self, tick: u64) -> Result<u8, DeviceError> {
        let v = self.driver.read_inputs()?;
        self.inputs.update(v, tick);
        Ok(v)
    }

    /// Reads the counters into the snapshot at `tick`.
    pub fn read_counters(&mut self, tick: u64) -> Result<[u16; 8], DeviceError> {
        let v = self.driver.read_counters()?;
        self.counters.update(v, tick);
        Ok(v)
    }

    /// Reads the latches into the snapshot at `tick`.
    pub fn read_latches(&mut self, tick: u64) -> Result<Latches, DeviceError> {
        let v = self.driver.read_latches()?;
        self.latches.update(v, tick);
        Ok(v)
    }

    /// Writes the whole DO byte in one transaction and remembers it as written.
    pub fn write_outputs(&mut self, value: u8) -> Result<(), DeviceError> {
        self.driver.write_outputs(value)?;
        self.outputs_written = Some(value);
        Ok(())
    }

    /// A cheap request without retries that tells whether the module answers.
    pub fn probe(&mut self) -> Result<(), DeviceError> {
        self.probe.read_outputs()?;
        Ok(())
    }

    /// Opens the line again, if this module has a real one.
    pub fn reopen(&mut self) -> Result<(), DeviceError> {
        if let Some(open) = &mut self.reopener {
            let mut line = self.line.lock().unwrap_or_else(|e| e.into_inner());
            // Release the old port first: serial ports are opened exclusively.
            let what = line.describe();
            *line = Box::new(super::links::ClosedLink(what));
            *line = open().map_err(C29uError::Link)?;
        }
        Ok(())
    }

    /// Host OK, if the runner feeds a watchdog and `interval` has passed since the last feed.
    pub fn feed(&mut self, now: Duration, interval: Duration) -> Result<bool, DeviceError> {
        if self.watchdog.is_none() || now.saturating_sub(self.last_feed) < interval {
            return Ok(false);
        }
        self.driver.host_ok()?;
        self.last_feed = now;
        Ok(true)
    }

    /// Puts the module under the runner's supervision: the configured safe and power-on
    /// values stored (only where they differ, to spare the EEPROM), `outputs` written (leaving
    /// safe mode first if the module is in it), and the host watchdog on and fed.
    pub fn take_control(
        &mut self,
        outputs: u8,
        now: Duration,
    ) -> Result<ControlNotes, DeviceError> {
        let mut notes = ControlNotes::default();
        let before = self.driver.watchdog()?;
        let safe_value = self.config.safe_value;
        let safe = self.driver.safe_value()?;
        if safe != safe_value {
            self.leaving_safe_mode(&mut notes, |d| {
                store_at_safe_value(d, Preset::Safe, safe_value, safe_value)
            })?;
            notes.safe_value_was = Some(safe);
        }
        if let Some(v) = self.config.power_on_value {
            let stored = self.driver.power_on_value()?;
            if stored != v {
                self.leaving_safe_mode(&mut notes, |d| {
                    store_at_safe_value(d, Preset::PowerOn, v, safe_value)
                })?;
                notes.power_on_value_was = Some(stored);
            }
        }
        self.leaving_safe_mode(&mut notes, |d| d.write_outputs(outputs))?;
        self.outputs_written = Some(outputs);
        let module_own =
            WatchdogTimeout::from_tenths(before.timeout_tenths).filter(|_| before.enabled);
        match (self.watchdog, module_own) {
            (Some(t), _) => {
                let same = before.enabled && before.timeout_tenths == t.tenths();
                if same && !notes.left_safe_mode {
                    self.driver.host_ok()?;
                } else {
                    self.driver.set_watchdog(Some(t.as_duration()))?;
                }
                self.watchdog_ours = true;
            }
            (None, Some(own)) => {
                if notes.left_safe_mode {
                    self.driver.set_watchdog(Some(own.as_duration()))?;
                } else {
                    self.driver.host_ok()?;
                }
                self.watchdog = Some(own);
                notes.adopted_watchdog = Some(own);
            }
            (None, None) => {}
        }
        self.last_feed = now;
        Ok(notes)
    }

    /// Runs `op`; if the module refuses because it is in safe mode, disables the watchdog
    /// (the only way out) and runs it once more.
    fn leaving_safe_mode(
        &mut self,
        notes: &mut ControlNotes,
        op: impl Fn(&mut C29u) -> Result<(), C29uError>,
    ) -> Result<(), DeviceError> {
        match op(&mut self.driver) {
            Err(C29uError::SafeMode { .. }) if !notes.left_safe_mode => {
                self.driver.set_watchdog(None)?;
                notes.left_safe_mode = true;
                Ok(op(&mut self.driver)?)
            }
            other => Ok(other?),
        }
    }

    /// Writes the safe value to the outputs; a module in safe mode already holds it.
    pub fn write_safe(&mut self) -> Result<(), DeviceError> {
        match self.driver.write_outputs(self.config.safe_value) {
            Ok(()) | Err(C29uError::SafeMode { .. }) => {
                self.outputs_written = Some(self.config.safe_value);
                Ok(())
            }
            Err(e) => Err(e.into()),
        }
    }

    /// Turns off the watchdog the runner turned on (at a clean end, outputs already safe).
    pub fn release_watchdog(&mut self) -> Result<(), DeviceError> {
        if self.watchdog_ours && self.watchdog.is_some() {
            self.driver.set_watchdog(None)?;
            self.watchdog_ours = false;
        }
        Ok(())
    }
}
