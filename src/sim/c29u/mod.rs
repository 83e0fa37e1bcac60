//! Protocol-agnostic behavioural model of the TRP-C29U DIO module: outputs, inputs, counters,
//! latches, host watchdog, EEPROM. The ASCII and Modbus front ends decode frames and call it.
//!
//! Readings of the manual this model follows (docs/trp-c29u-protocol.md has the rest):
//! - Time: all timing comes from the model's `SharedClock`; the watchdog is brought up to date
//!   lazily from `clock.now()` at each call (`&self` getters report what it would be now).
//! - Watchdog (8-19, 8-22): only Host OK (`host_ok`) and setting a timeout restart the countdown;
//!   other commands do not. It fires once a whole timeout has passed since the last restart
//!   (elapsed >= timeout), driving DO to the safe value.
//! - Safe mode persists across `reset` and `power_cycle` until the watchdog is disabled (section
//!   5: "the digital out will not be changed until the watchdog disable" read as fail-safe, over
//!   "reboot then into power on mode"); while in it, a reset drives DO to the safe value.
//! - A reset or power cycle restarts the countdown of an enabled watchdog (8-19: "Reset and power
//!   fail will not affect watchdog mode") and does not itself set safe mode.
//! - Setting a new timeout while in safe mode keeps safe mode (only disabling leaves it);
//!   leaving safe mode leaves DO at the safe value until the host writes it.
//! - Counters (8-5..8-8): live values are RAM; reset and power cycle reload the saved EEPROM
//!   values. Clearing does not touch EEPROM.
//! - Latches (8-9, 10-17): latched low = the wire level has gone to 0 (input energized, the
//!   wiring being active-low) since the last clear; latched high = the wire level has gone to 1
//!   (input released). They are set by a change of the input, not by a level already held when
//!   they were cleared. They are RAM: a reset or power cycle clears them.
//! - What `#**` made the module remember is RAM too: lost on reset / power cycle (`$ID4` then
//!   answers `?ID`).
//! - A Modbus module's ID can only be set to 1..=247 (9-1); ASCII takes 00..=FF.

mod config;
mod eeprom;
mod history;
mod view;

#[cfg(test)]
mod tests;

pub use config::{baud_rate, CounterEdge, ModuleConfig, Protocol};
pub use eeprom::{validate_led_mode, validate_name, Eeprom, DEFAULT_NAME};
pub use history::{OutputCause, OutputChange, OutputHistory};
pub use view::{SimState, WatchdogState, WatchdogStatus, FIRMWARE_DATE, FIRMWARE_MODEL};

use crate::protocol::c29u_ascii::{SynchronizedData, WatchdogReading};
use crate::protocol::c29u_modbus::SLAVE_IDS;
use crate::time::clock::SharedClock;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Why the model refused a request.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum C29uModelError {
    /// Output write refused: the watchdog has fired, until it is disabled.
    #[error("module in safe mode: the host watchdog has fired; disable it to write outputs")]
    SafeMode,
    /// Channel outside 0..=7.
    #[error("channel {0} outside 0..=7")]
    BadChannel(u8),
    /// A value the module cannot take (name, baud code, LED mode, ID, data format).
    #[error("bad value: {0}")]
    BadValue(String),
    /// `$ID4` before any `#**` (the module answers `?ID`).
    #[error("no #** received since power on")]
    NotSynchronized,
    /// The EEPROM state file could not be read, parsed or written.
    #[error("{0}")]
    Io(String),
}

/// Number of DI channels (and of counters and DO channels).
pub const CHANNELS: u8 = 8;

/// The single-bit mask of a channel, or `BadChannel`.
fn channel_bit(ch: u8) -> Result<u8, C29uModelError> {
    if ch < CHANNELS {
        Ok(1u8 << ch)
    } else {
        Err(C29uModelError::BadChannel(ch))
    }
}

/// The duration of a watchdog timeout given in 0.1 s units.
fn tenths_duration(t: u8) -> Duration {
    Duration::from_millis(u64::from(t) * 100)
}

/// The simulated TRP-C29U: RAM state, EEPROM image, and the clock that drives its watchdog.
pub struct C29uModel {
    protocol: Protocol,
    clock: SharedClock,
    eeprom: Eeprom,
    state_file: Option<PathBuf>,
    /// The EEPROM image changed without reaching the state file (a failed best-effort write).
    unsaved: bool,
    outputs: u8,
    inputs: u8,
    counters: [u16; 8],
    latched_low: u8,
    latched_high: u8,
    /// When an enabled, not yet fired watchdog fires; `None` when disabled or fired.
    deadline: Option<Duration>,
    reset_flag: bool,
    /// What the last `#**` made the module remember (8-25).
    synchronized: Option<SynchronizedData>,
    history: OutputHistory,
    /// EEPROM writes that stored what was there already.
    eeprom_rewrites: u64,
}

impl std::fmt::Debug for C29uModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("C29uModel")
            .field("protocol", &self.protocol)
            .field("eeprom", &self.eeprom)
            .field("state_file", &self.state_file)
            .field("outputs", &self.outputs)
            .field("inputs", &self.inputs)
            .field("counters", &self.counters)
            .field("latched_low", &self.latched_low)
            .field("latched_high", &self.latched_high)
            .field("deadline", &self.deadline)
            .field("reset_flag", &self.reset_flag)
            .field("synchronized", &self.synchronized)
            .finish_non_exhaustive()
    }
}

impl C29uModel {
    /// Powers on a module with the given EEPROM contents (no state file).
    pub fn new(protocol: Protocol, clock: SharedClock, eeprom: Eeprom) -> Self {
        let mut m = Self {
            protocol,
            clock,
            eeprom,
            state_file: None,
            unsaved: false,
            outputs: 0,
            inputs: 0,
            counters: [0; 8],
            latched_low: 0,
            latched_high: 0,
            deadline: None,
            reset_flag: true,
            synchronized: None,
            history: OutputHistory::default(),
            eeprom_rewrites: 0,
        };
        m.boot(|in_safe_mode| OutputCause::PowerOn { in_safe_mode });
        m
    }

    /// Powers on a module whose EEPROM is persisted to a JSON file: loaded if present (factory,
    /// written at once, otherwise) and saved atomically on every EEPROM change. An unreadable,
    /// corrupt or invalid file is `C29uModelError::Io` naming the file.
    pub fn with_state_file(
        protocol: Protocol,
        clock: SharedClock,
        path: PathBuf,
    ) -> Result<Self, C29uModelError> {
        let eeprom = match std::fs::read_to_string(&path) {
            Ok(text) => Eeprom::from_json(&text).map_err(|reason| {
                C29uModelError::Io(format!("EEPROM state file {}: {reason}", path.display()))
            })?,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                let fresh = Eeprom::factory();
                fresh.save(&path)?;
                fresh
            }
            Err(e) => {
                return Err(C29uModelError::Io(format!(
                    "EEPROM state file {}: {e}",
                    path.display()
                )))
            }
        };
        let mut m = Self::new(protocol, clock, eeprom);
        m.state_file = Some(path);
        Ok(m)
    }

    /// The protocol set by the DIP switch.
    pub fn protocol(&self) -> Protocol {
        self.protocol
    }

    /// The communication settings in EEPROM.
    pub fn config(&self) -> ModuleConfig {
        self.eeprom.config
    }

    /// Validates and stores new communication settings (takes effect at once; the front end
    /// answers the command that set them with the old ones). Modbus IDs must be 1..=247.
    pub fn set_config(&mut self, cfg: ModuleConfig) -> Result<(), C29uModelError> {
        self.tick();
        cfg.validate()?;
        if self.protocol == Protocol::Modbus && !SLAVE_IDS.contains(&cfg.id) {
            return Err(C29uModelError::BadValue(format!(
                "Modbus ID {} outside 1..=247 (9-1)",
                cfg.id
            )));
        }
        let mut next = self.eeprom.clone();
        next.config = cfg;
        self.commit(next)
    }

    // ---- field side -------------------------------------------------------------------------

    /// Sets the inputs (bit n = DIn energized): counts the configured edge of each channel that
    /// changed and sets its latch.
    pub fn set_inputs(&mut self, energized: u8) {
        self.tick();
        let changed = self.inputs ^ energized;
        let rising = changed & energized;
        let falling = changed & !energized;
        self.latched_low |= rising;
        self.latched_high |= falling;
        let counted = match self.eeprom.config.counter_edge {
            CounterEdge::Rising => rising,
            CounterEdge::Falling => falling,
        };
        self.add_counts(counted, 1);
        self.inputs = energized;
    }

    /// Applies `n` full pulses to channel `ch`: each one leaves the resting level and comes back
    /// (energize then release from released; release then energize from energized), so the
    /// channel counts `n` whichever edge is configured, ends where it was, and latches both ways.
    pub fn pulse(&mut self, ch: u8, n: u32) -> Result<(), C29uModelError> {
        let bit = channel_bit(ch)?;
        self.tick();
        if n == 0 {
            return Ok(());
        }
        self.latched_low |= bit;
        self.latched_high |= bit;
        // Only n modulo 2^16 matters to a 16-bit wrapping counter.
        let steps = (n % 0x1_0000) as u16;
        self.add_counts(bit, steps);
        Ok(())
    }

    /// Unplug and replug: counters reload from EEPROM, latches and the `#**` data are lost, DO is the
    /// power-on value (the safe value while in safe mode), the reset flag is set, an enabled
    /// watchdog starts counting again.
    pub fn power_cycle(&mut self) {
        self.tick();
        self.boot(|in_safe_mode| OutputCause::PowerOn { in_safe_mode });
    }

    // ---- host side --------------------------------------------------------------------------

    /// DO byte, bit n = DOn (as it is now, including a watchdog that has just fired).
    pub fn outputs(&self) -> u8 {
        if self.fires_now() {
            self.eeprom.safe_value
        } else {
            self.outputs
        }
    }

    /// Writes all eight outputs; `SafeMode` once the watchdog has fired.
    pub fn write_outputs(&mut self, value: u8) -> Result<(), C29uModelError> {
        self.tick();
        if self.eeprom.safe_mode {
            return Err(C29uModelError::SafeMode);
        }
        self.drive(self.clock.now(), value, OutputCause::HostWrite);
        Ok(())
    }

    /// Writes one output; `BadChannel` outside 0..=7, `SafeMode` once the watchdog has fired.
    pub fn write_output(&mut self, ch: u8, on: bool) -> Result<(), C29uModelError> {
        let bit = channel_bit(ch)?;
        self.tick();
        if self.eeprom.safe_mode {
            return Err(C29uModelError::SafeMode);
        }
        let value = if on {
            self.outputs | bit
        } else {
            self.outputs & !bit
        };
        self.drive(self.clock.now(), value, OutputCause::HostWrite);
        Ok(())
    }

    /// DI byte, logical: bit n = 1 when DIn is energized.
    pub fn inputs(&self) -> u8 {
        self.inputs
    }

    /// DI byte as sent on the wire: active-low (8-11, 10-17: an energized input is a 0 bit).
    pub fn inputs_wire(&self) -> u8 {
        !self.inputs
    }

    /// One channel's live counter.
    pub fn counter(&self, ch: u8) -> Result<u16, C29uModelError> {
        self.counters
            .get(usize::from(ch))
            .copied()
            .ok_or(C29uModelError::BadChannel(ch))
    }

    /// All eight live counters, channel 0 first.
    pub fn counters(&self) -> [u16; 8] {
        self.counters
    }

    /// Clears one live counter (EEPROM keeps its saved value, 8-6).
    pub fn clear_counter(&mut self, ch: u8) -> Result<(), C29uModelError> {
        channel_bit(ch)?;
        self.tick();
        if let Some(slot) = self.counters.get_mut(usize::from(ch)) {
            *slot = 0;
        }
        Ok(())
    }

    /// Clears all live counters (EEPROM keeps the saved values, 8-7).
    pub fn clear_counters(&mut self) {
        self.tick();
        self.counters = [0; 8];
    }

    /// Saves all live counters to EEPROM, to be reloaded at reset and power on (8-8).
    pub fn save_counters(&mut self) -> Result<(), C29uModelError> {
        self.tick();
        let mut next = self.eeprom.clone();
        next.saved_counters = self.counters;
        self.commit(next)
    }

    /// Channels whose input has been energized (wire level gone to 0) since the last clear.
    pub fn latched_low(&self) -> u8 {
        self.latched_low
    }

    /// Channels whose input has been released (wire level gone to 1) since the last clear.
    pub fn latched_high(&self) -> u8 {
        self.latched_high
    }

    /// Clears both latch bytes (8-10, Modbus 05 01).
    pub fn clear_latches(&mut self) {
        self.tick();
        self.latched_low = 0;
        self.latched_high = 0;
    }

    /// Sets the host watchdog timeout in 0.1 s units and starts counting; 0 disables it and
    /// leaves safe mode (DO stays as it is). Stored in EEPROM: reset and power loss keep it.
    pub fn set_watchdog(&mut self, tenths: u8) -> Result<(), C29uModelError> {
        self.tick();
        let mut next = self.eeprom.clone();
        next.watchdog_tenths = tenths;
        if tenths == 0 {
            next.safe_mode = false;
        }
        self.commit(next)?;
        self.restart_countdown();
        Ok(())
    }

    /// The watchdog as `~IDWR` reports it (8-21), as of now.
    pub fn watchdog_reading(&mut self) -> WatchdogReading {
        let status = self.watchdog();
        WatchdogReading::of(status.timeout_tenths, status.expired)
    }

    /// The watchdog's mode and whether it has fired, as of now.
    pub fn watchdog(&mut self) -> WatchdogStatus {
        self.tick();
        WatchdogStatus {
            enabled: self.eeprom.watchdog_tenths != 0,
            timeout_tenths: self.eeprom.watchdog_tenths,
            expired: self.eeprom.safe_mode,
        }
    }

    /// Host OK (`~**`, `46 2F`): restarts the countdown of an enabled watchdog that has not
    /// fired; it does not leave safe mode.
    pub fn host_ok(&mut self) {
        self.tick();
        self.restart_countdown();
    }

    /// The watchdog has fired and not been disabled since.
    pub fn in_safe_mode(&mut self) -> bool {
        self.tick();
        self.eeprom.safe_mode
    }

    /// DO value driven when the watchdog fires.
    pub fn safe_value(&self) -> u8 {
        self.eeprom.safe_value
    }

    /// Stores the safe value in EEPROM (DO is not changed).
    pub fn set_safe_value(&mut self, v: u8) -> Result<(), C29uModelError> {
        self.tick();
        let mut next = self.eeprom.clone();
        next.safe_value = v;
        self.commit(next)
    }

    /// DO value driven at power on and after a reset.
    pub fn power_on_value(&self) -> u8 {
        self.eeprom.power_on_value
    }

    /// Stores the power-on value in EEPROM (DO is not changed).
    pub fn set_power_on_value(&mut self, v: u8) -> Result<(), C29uModelError> {
        self.tick();
        let mut next = self.eeprom.clone();
        next.power_on_value = v;
        self.commit(next)
    }

    /// Stores the current DO as the safe value (`~ID5S`).
    pub fn save_outputs_as_safe(&mut self) -> Result<(), C29uModelError> {
        self.tick();
        self.set_safe_value(self.outputs)
    }

    /// Stores the current DO as the power-on value (`~ID5P`).
    pub fn save_outputs_as_power_on(&mut self) -> Result<(), C29uModelError> {
        self.tick();
        self.set_power_on_value(self.outputs)
    }

    /// The module name (8-14).
    pub fn name(&self) -> &str {
        &self.eeprom.name
    }

    /// Renames the module: 1..=6 printable ASCII characters (8-17).
    pub fn set_name(&mut self, name: &str) -> Result<(), C29uModelError> {
        self.tick();
        validate_name(name)?;
        let mut next = self.eeprom.clone();
        name.clone_into(&mut next.name);
        self.commit(next)
    }

    /// True once after a reset or power on, then false (8-16, 10-6).
    pub fn take_reset_flag(&mut self) -> bool {
        self.tick();
        std::mem::take(&mut self.reset_flag)
    }

    /// Software reset (`$IDRS`, `46 09`): the same as a power cycle.
    pub fn reset(&mut self) {
        self.tick();
        self.boot(|in_safe_mode| OutputCause::Reset { in_safe_mode });
    }

    /// LED operating mode, 0 or 1 (8-18, 10-10).
    pub fn led_mode(&self) -> u8 {
        self.eeprom.led_mode
    }

    /// Stores the LED operating mode: 0 or 1.
    pub fn set_led_mode(&mut self, mode: u8) -> Result<(), C29uModelError> {
        self.tick();
        validate_led_mode(mode)?;
        let mut next = self.eeprom.clone();
        next.led_mode = mode;
        self.commit(next)
    }

    /// `#**` broadcast: remembers DO and DI (wire form), fresh until read (8-25).
    pub fn synchronize(&mut self) {
        self.tick();
        self.synchronized = Some(SynchronizedData {
            fresh: true,
            outputs: self.outputs,
            inputs_wire: self.inputs_wire(),
        });
    }

    /// `$ID4`: what the last `#**` remembered, fresh only on the first read after it (8-26).
    pub fn read_synchronized(&mut self) -> Result<SynchronizedData, C29uModelError> {
        self.tick();
        let data = self
            .synchronized
            .as_mut()
            .ok_or(C29uModelError::NotSynchronized)?;
        let out = *data;
        data.fresh = false;
        Ok(out)
    }

    /// Everything the `state` control line reports, as of now.
    pub fn state(&mut self) -> SimState {
        let wd = self.watchdog();
        SimState {
            id: self.eeprom.config.id,
            protocol: self.protocol,
            outputs: self.outputs,
            inputs: self.inputs,
            counters: self.counters,
            latched_low: self.latched_low,
            latched_high: self.latched_high,
            safe_value: self.eeprom.safe_value,
            power_on_value: self.eeprom.power_on_value,
            name: self.eeprom.name.clone(),
            watchdog: WatchdogState {
                enabled: wd.enabled,
                timeout_ms: u32::from(wd.timeout_tenths) * 100,
                expired: wd.expired,
            },
        }
    }

    // ---- additions beyond the contract ------------------------------------------------------

    /// The EEPROM image as it stands.
    pub fn eeprom(&self) -> &Eeprom {
        &self.eeprom
    }

    /// The JSON file the EEPROM is persisted to, if any.
    pub fn state_file(&self) -> Option<&Path> {
        self.state_file.as_deref()
    }

    /// The clock driving the watchdog.
    pub fn clock(&self) -> &SharedClock {
        &self.clock
    }

    /// Starts keeping the output history (every DO setting and its cause), up to `capacity`
    /// entries; what was kept before is dropped.
    pub fn record_outputs(&mut self, capacity: usize) {
        self.history = OutputHistory::with_capacity(capacity);
    }

    /// How many EEPROM writes stored what was there already (each wears the EEPROM for
    /// nothing; a host should read before it writes).
    pub fn eeprom_rewrites(&self) -> u64 {
        self.eeprom_rewrites
    }

    /// The output history, as of the last call that brought the model up to date (a
    /// watchdog due since shows once any host-side call or `state` has been made).
    pub fn output_history(&self) -> &OutputHistory {
        &self.history
    }

    /// Writes the EEPROM image to the state file if a best-effort write (the watchdog firing)
    /// failed earlier; a no-op otherwise.
    pub fn flush(&mut self) -> Result<(), C29uModelError> {
        self.tick();
        if self.unsaved {
            if let Some(path) = &self.state_file {
                self.eeprom.save(path)?;
            }
            self.unsaved = false;
        }
        Ok(())
    }

    // ---- internals --------------------------------------------------------------------------

    /// Power-on sequence shared by `new`, `power_cycle` and `reset`; `cause` names it in the
    /// output history.
    fn boot(&mut self, cause: fn(bool) -> OutputCause) {
        self.counters = self.eeprom.saved_counters;
        self.latched_low = 0;
        self.latched_high = 0;
        self.synchronized = None;
        self.reset_flag = true;
        let in_safe_mode = self.eeprom.safe_mode;
        let value = if in_safe_mode {
            self.eeprom.safe_value
        } else {
            self.eeprom.power_on_value
        };
        self.drive(self.clock.now(), value, cause(in_safe_mode));
        self.restart_countdown();
    }

    /// Starts a fresh countdown if the watchdog is enabled and has not fired.
    fn restart_countdown(&mut self) {
        self.deadline = if self.eeprom.watchdog_tenths != 0 && !self.eeprom.safe_mode {
            Some(
                self.clock
                    .now()
                    .saturating_add(tenths_duration(self.eeprom.watchdog_tenths)),
            )
        } else {
            None
        };
    }

    /// The watchdog's deadline has passed but `tick` has not yet acted on it.
    fn fires_now(&self) -> bool {
        self.deadline.is_some_and(|d| self.clock.now() >= d)
    }

    /// Sets the DO byte and notes it in the history.
    fn drive(&mut self, at: Duration, value: u8, cause: OutputCause) {
        self.history.note(OutputChange {
            at,
            before: self.outputs,
            after: value,
            cause,
        });
        self.outputs = value;
    }

    /// Brings the watchdog up to date: fires it if its deadline has passed.
    fn tick(&mut self) {
        let Some(fired_at) = self.deadline.filter(|_| self.fires_now()) else {
            return;
        };
        self.deadline = None;
        self.eeprom.safe_mode = true;
        self.drive(fired_at, self.eeprom.safe_value, OutputCause::WatchdogFired);
        // Best effort: the caller may not be able to report an error; `flush` or the next
        // EEPROM write retries, since each write stores the whole image.
        if let Some(path) = &self.state_file {
            self.unsaved = self.eeprom.save(path).is_err();
        }
    }

    /// Makes `next` the EEPROM image, writing the state file first; on a write error nothing
    /// changes.
    fn commit(&mut self, next: Eeprom) -> Result<(), C29uModelError> {
        if next == self.eeprom {
            self.eeprom_rewrites = self.eeprom_rewrites.saturating_add(1);
        }
        if let Some(path) = &self.state_file {
            next.save(path)?;
        }
        self.eeprom = next;
        self.unsaved = false;
        Ok(())
    }

    /// Advances the counters of the channels in `mask` by `steps`, wrapping at 65535.
    fn add_counts(&mut self, mask: u8, steps: u16) {
        for (ch, c) in self.counters.iter_mut().enumerate() {
            if mask & (1u8 << ch) != 0 {
                *c = c.wrapping_add(steps);
            }
        }
    }
}
