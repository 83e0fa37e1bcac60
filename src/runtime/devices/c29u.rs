//! A TRP-C29U as the runtime holds it: driver, input/counter/latch snapshots, the DO byte the
//! script wants and the one last written, the host watchdog the runner feeds, and what the
//! module holds in its EEPROM.

use super::identity::Found;
use super::{DeviceError, Health, Snapshot};
use crate::config::feeding::{FeedTiming, MOST_FEEDS_PER_TIMEOUT};
use crate::config::C29uConfig;
use crate::device::c29u::{C29u, C29uError, Latches, SharedLink, WatchdogTimeout};
use crate::device::cancel::Cancel;
use crate::link::{ByteLink, LinkError};
use std::time::Duration;

/// Opens the module's line again (a serial port after an unplug); `None` for a simulator.
pub type ByteReopener = Box<dyn FnMut() -> Result<Box<dyn ByteLink>, LinkError>>;

/// A TRP-C29U in the rig.
pub struct C29uDevice {
    /// The name scripts use.
    pub(super) name: String,
    /// Its configuration; the script may change the safe value, power-on value and watchdog.
    pub(super) config: C29uConfig,
    /// The driver, with the configured retries.
    pub(super) driver: C29u,
    /// A driver on the same line without retries: a lost module costs one timeout per try.
    probe: C29u,
    line: SharedLink,
    reopener: Option<ByteReopener>,
    /// Whether it answers.
    pub(super) health: Health,
    /// DI byte (bit n = DIn energized), read lazily.
    pub(super) inputs: Snapshot<u8>,
    /// The eight counters, read lazily.
    pub(super) counters: Snapshot<[u16; 8]>,
    /// The latches, read lazily.
    pub(super) latches: Snapshot<Latches>,
    /// The DI byte as last read for watchers only (`runtime::watched_image`).
    shown_inputs: Snapshot<u8>,
    /// The counters as last read for watchers only.
    shown_counters: Snapshot<[u16; 8]>,
    /// The DO byte the script wants.
    pub(super) outputs: u8,
    /// The DO byte last written (`None`: unknown, write again).
    outputs_written: Option<u8>,
    /// The handler that last changed `outputs`, for the log.
    pub(super) outputs_cause: String,
    /// The host watchdog the runner feeds (`None`: none).
    pub(super) watchdog: Option<WatchdogTimeout>,
    /// The runner turned that watchdog on (and turns it off at a clean end).
    pub(super) watchdog_ours: bool,
    /// When the watchdog was last fed.
    pub(super) last_feed: Duration,
    /// The runner has taken control of it (its watchdog is fed from then on).
    pub(super) controlled: bool,
    /// How late a feed can reach it on this rig (`None`: not worked out, a quarter of the
    /// timeout is used).
    pub(super) feed_timing: Option<FeedTiming>,
    /// What the module holds, so that unchanged values are not written again.
    pub(super) stored: Stored,
    /// Who it is and what it stored when last taken control of, before anything was written.
    pub(super) found: Option<Found>,
    /// Which item the next periodic check reads in turn (`identity::ModuleCheck`).
    pub(super) check_turn: usize,
    /// The script reset it (`.reset()`): its reset flag is no news.
    pub(super) reset_by_script: bool,
    /// Its last output write was refused (not for a safe mode its watchdog explains).
    pub(super) refusing: bool,
    /// Output writes it refused during the run.
    pub(super) refused_writes: u64,
}

/// What the module holds in its EEPROM, as last read or written (`None`: not known).
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct Stored {
    /// Its watchdog safe value.
    pub(super) safe_value: Option<u8>,
    /// Its power-on value.
    pub(super) power_on_value: Option<u8>,
    /// Its host watchdog (`Some(None)`: off).
    pub(super) watchdog: Option<Option<WatchdogTimeout>>,
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
            shown_inputs: Snapshot::default(),
            shown_counters: Snapshot::default(),
            outputs_written: None,
            outputs_cause: String::new(),
            watchdog_ours: false,
            last_feed: Duration::ZERO,
            controlled: false,
            feed_timing: None,
            stored: Stored::default(),
            found: None,
            check_turn: 0,
            reset_by_script: false,
            refusing: false,
            refused_writes: 0,
        }
    }

    /// The name scripts use.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Its configuration, with what the script changed since.
    #[inline]
    pub fn config(&self) -> &C29uConfig {
        &self.config
    }

    /// Its configuration, for a test to change what a rig.toml could not.
    #[cfg(test)]
    pub fn config_mut(&mut self) -> &mut C29uConfig {
        &mut self.config
    }

    /// The driver, for requests that change nothing the runtime holds of the module (reads,
    /// the script's own requests).
    pub fn driver(&mut self) -> &mut C29u {
        &mut self.driver
    }

    /// Its link in words.
    pub fn describe(&self) -> String {
        self.driver.describe()
    }

    /// Whether it answers.
    #[inline]
    pub fn health(&self) -> &Health {
        &self.health
    }

    /// The DI byte as last read.
    #[inline]
    pub fn inputs(&self) -> &Snapshot<u8> {
        &self.inputs
    }

    /// The counters as last read.
    #[inline]
    pub fn counters(&self) -> &Snapshot<[u16; 8]> {
        &self.counters
    }

    /// The latches as last read.
    #[inline]
    pub fn latches(&self) -> &Snapshot<Latches> {
        &self.latches
    }

    /// The DO byte the script wants.
    #[inline]
    pub fn wanted_outputs(&self) -> u8 {
        self.outputs
    }

    /// The DO byte to drive: the safe value while every output is held safe, else what the
    /// script wants with an operator's force (`force`) over it.
    #[inline]
    pub fn outputs_to_write(&self, held: bool, force: impl FnOnce(u8) -> u8) -> u8 {
        if held {
            self.config.safe_value
        } else {
            force(self.outputs)
        }
    }

    /// The handler that last changed the DO byte the script wants ("": none yet).
    pub fn outputs_cause(&self) -> &str {
        &self.outputs_cause
    }

    /// The script wants `value` on the outputs, for `cause` (kept only if it is a change).
    #[inline]
    pub fn want_outputs(&mut self, value: u8, cause: String) {
        if self.outputs != value {
            self.outputs = value;
            self.outputs_cause = cause;
        }
    }

    /// The next write of the outputs is for `cause` (an operator's force ended).
    pub fn credit_outputs_to(&mut self, cause: String) {
        self.outputs_cause = cause;
    }

    /// The host watchdog the runner feeds (`None`: none).
    pub fn watchdog(&self) -> Option<WatchdogTimeout> {
        self.watchdog
    }

    /// The host watchdog the runner turned on (and turns off at a clean end), if it did.
    pub fn watchdog_turned_on(&self) -> Option<WatchdogTimeout> {
        self.watchdog.filter(|_| self.watchdog_ours)
    }

    /// Whether the runner has taken control of it (and feeds its watchdog).
    pub fn controlled(&self) -> bool {
        self.controlled
    }

    /// Who it was and what it stored when last taken control of.
    pub fn found(&self) -> Option<&Found> {
        self.found.as_ref()
    }

    /// Whether its last output write was refused (not for a safe mode its watchdog explains).
    pub fn refusing(&self) -> bool {
        self.refusing
    }

    /// Output writes it refused during the run.
    pub fn refused_writes(&self) -> u64 {
        self.refused_writes
    }

    /// It refused an output write: what it drives is not known (written again), and the
    /// refusal is counted.
    pub fn note_refused(&mut self) {
        self.outputs_written = None;
        self.refusing = true;
        self.refused_writes = self.refused_writes.saturating_add(1);
    }

    /// Resets the module (the script's `.reset()`): it comes back at its power-on value, so
    /// the outputs are written again at the end of the tick, and the periodic check knows
    /// this reset.
    pub fn reset_module(&mut self) -> Result<(), DeviceError> {
        self.driver.reset()?;
        self.outputs_written = None;
        self.reset_by_script = true;
        Ok(())
    }

    /// Clears counter `channel` on the module and in the last reading.
    pub fn clear_counter(&mut self, channel: u8) -> Result<(), DeviceError> {
        self.driver.clear_counter(channel)?;
        if let Some(slot) = self
            .counters
            .current
            .as_mut()
            .and_then(|v| v.get_mut(usize::from(channel)))
        {
            *slot = 0;
        }
        Ok(())
    }

    /// Clears every counter on the module and in the last reading.
    pub fn clear_counters(&mut self) -> Result<(), DeviceError> {
        self.driver.clear_counters()?;
        if let Some(v) = self.counters.current.as_mut() {
            *v = [0; 8];
        }
        Ok(())
    }

    /// Clears the latches on the module and in the last reading.
    pub fn clear_latches(&mut self) -> Result<(), DeviceError> {
        self.driver.clear_latches()?;
        if let Some(l) = self.latches.current.as_mut() {
            *l = Latches::default();
        }
        Ok(())
    }

    /// Puts forced inputs (`force`) over the last reading.
    pub fn force_inputs(&mut self, force: impl FnOnce(u8) -> u8) {
        if let Some(v) = self.inputs.current {
            self.inputs.current = Some(force(v));
        }
    }

    /// The inputs are read again at their next access, even in this tick (a force changed).
    pub fn reread_inputs(&mut self) {
        self.inputs.tick = None;
    }

    /// The driver to write and confirm the safe value with (`single`: without retries, at
    /// the end), and the safe value.
    pub fn safe_driver(&mut self, single: bool) -> (&mut C29u, u8) {
        let safe = self.config.safe_value;
        (
            if single {
                &mut self.probe
            } else {
                &mut self.driver
            },
            safe,
        )
    }

    /// Whether the safe value was confirmed on the outputs (`false`: what they hold is not
    /// what the runner wants, written again).
    pub fn note_safe_state(&mut self, confirmed: bool) {
        self.outputs_written = confirmed.then_some(self.config.safe_value);
    }

    /// Reads the inputs into the snapshot at `tick`.
    pub fn read_inputs(&mut self, tick: u64) -> Result<u8, DeviceError> {
        let v = self.fetch_inputs()?;
        self.inputs.update(v, tick);
        Ok(v)
    }

    /// Reads the inputs, kept nowhere.
    pub fn fetch_inputs(&mut self) -> Result<u8, DeviceError> {
        Ok(self.driver.read_inputs()?)
    }

    /// Reads the counters into the snapshot at `tick`.
    pub fn read_counters(&mut self, tick: u64) -> Result<[u16; 8], DeviceError> {
        let v = self.fetch_counters()?;
        self.counters.update(v, tick);
        Ok(v)
    }

    /// Reads the counters, kept nowhere.
    pub fn fetch_counters(&mut self) -> Result<[u16; 8], DeviceError> {
        Ok(self.driver.read_counters()?)
    }

    /// The inputs as last read for watchers only.
    pub fn shown_inputs(&mut self) -> &mut Snapshot<u8> {
        &mut self.shown_inputs
    }

    /// The counters as last read for watchers only.
    pub fn shown_counters(&mut self) -> &mut Snapshot<[u16; 8]> {
        &mut self.shown_counters
    }

    /// The DI byte a person is shown: the later of the script's reading and the one made for
    /// watchers.
    pub fn latest_inputs(&self) -> Option<u8> {
        self.inputs.or_later(&self.shown_inputs)
    }

    /// The counters a person is shown (as `latest_inputs`).
    pub fn latest_counters(&self) -> Option<[u16; 8]> {
        self.counters.or_later(&self.shown_counters)
    }

    /// The line's timing, for how long an exchange takes on it: protocol, baud, frame gap.
    pub fn line_options(&self) -> &crate::device::c29u::C29uOptions {
        self.driver.options()
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
        self.refusing = false;
        Ok(())
    }

    /// The DO byte last written (`None`: unknown, written again at the next flush).
    pub fn outputs_written(&self) -> Option<u8> {
        self.outputs_written
    }

    /// The module was seen to drive `value` by a write other than `write_outputs` (a
    /// takeover's step, the safe state confirmed).
    pub(super) fn note_outputs_written(&mut self, value: u8) {
        self.outputs_written = Some(value);
    }

    /// What the module drives is not known any more (a reset, a refusal, a read-back that
    /// differs): the next flush writes the outputs again.
    pub fn forget_outputs_written(&mut self) {
        self.outputs_written = None;
    }

    /// Cuts the exchanges of both its drivers short once `cancel` is set.
    pub fn set_cancel(&mut self, cancel: &Cancel) {
        self.driver.set_cancel(cancel.clone());
        self.probe.set_cancel(cancel.clone());
    }

    /// A cheap request without retries that tells whether the module answers.
    pub fn probe(&mut self) -> Result<(), DeviceError> {
        self.probe.read_outputs()?;
        Ok(())
    }

    /// The descriptor the OS reports the end of this module's link on (`link::fd::ended`),
    /// if it has one.
    pub fn link_watch(&self) -> Option<crate::link::Watch> {
        self.line.lock().unwrap_or_else(|e| e.into_inner()).watch()
    }

    /// Opens the line again, if this module has a real one.
    pub fn reopen(&mut self) -> Result<(), DeviceError> {
        if let Some(open) = &mut self.reopener {
            let mut line = crate::sync::lock(&self.line);
            // Release the old port first: serial ports are opened exclusively.
            let what = line.describe();
            *line = Box::new(super::links::ClosedLink(what));
            *line = open().map_err(C29uError::Link)?;
        }
        Ok(())
    }

    /// How often the runner feeds this module's watchdog, if it feeds one: a quarter of the
    /// timeout, or sooner where an exchange on this rig can take long (`config::feeding`);
    /// a tenth of it where even that is too late (a module's own watchdog, adopted).
    pub fn feed_interval(&self) -> Option<Duration> {
        let timeout = self.watchdog?.as_duration();
        Some(match &self.feed_timing {
            Some(t) => t
                .interval(timeout)
                .unwrap_or(timeout / MOST_FEEDS_PER_TIMEOUT),
            None => timeout / 4,
        })
    }

    /// How long it has gone unfed at `now`, if longer than its watchdog's timeout (the
    /// runner stalled and the watchdog has fired, if the module kept time alike).
    pub fn stalled(&self, now: Duration) -> Option<Duration> {
        let timeout = self.watchdog?.as_duration();
        let unfed = now.saturating_sub(self.last_feed);
        (self.controlled && self.health.online() && unfed > timeout).then_some(unfed)
    }

    /// When the watchdog is next to be fed, if the runner feeds one.
    pub fn next_feed(&self) -> Option<Duration> {
        if !self.controlled || !self.health.online() {
            return None;
        }
        self.feed_interval()
            .map(|i| self.last_feed.saturating_add(i))
    }

    /// Host OK, if the runner feeds a watchdog and its feed is due at `now`.
    pub fn feed(&mut self, now: Duration) -> Result<bool, DeviceError> {
        if !self.next_feed().is_some_and(|due| now >= due) {
            return Ok(false);
        }
        self.driver.host_ok()?;
        self.last_feed = now;
        Ok(true)
    }

    /// Who the module should be and what it should store now: as taking control found it,
    /// with the values the runner stored since (`None` before it was taken control of).
    pub fn expected(&self) -> Option<Found> {
        let f = self.found.as_ref()?;
        Some(Found {
            name: f.name.clone(),
            firmware: f.firmware.clone(),
            watchdog: self.stored.watchdog.unwrap_or(f.watchdog),
            safe_value: self.stored.safe_value.unwrap_or(f.safe_value),
            power_on_value: self.stored.power_on_value.unwrap_or(f.power_on_value),
        })
    }

    /// Turns off the watchdog the runner turned on (at a clean end, outputs already safe), in
    /// one try: if it fails the watchdog stays on and the module goes safe by itself, where
    /// its outputs already are.
    pub fn release_watchdog(&mut self) -> Result<(), DeviceError> {
        if self.watchdog_ours && self.watchdog.is_some() {
            self.probe.set_watchdog(None)?;
            self.stored.watchdog = Some(None);
            self.watchdog_ours = false;
        }
        Ok(())
    }
}
