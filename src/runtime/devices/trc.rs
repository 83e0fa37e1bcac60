//! A TRC1000 as the runtime holds it: driver, switch and rotary snapshots, the relay the
//! script wants and the one last written.

use super::{DeviceError, Health, Snapshot};
use crate::config::Trc1000Config;
use crate::device::trc1000::Trc1000;
use crate::link::{LinkError, PacketLink};
use crate::protocol::trc1000::{RotaryValues, SwitchSet};

/// Opens the board's link again (real USB after an unplug); `None` for a simulator.
pub type PacketReopener = Box<dyn FnMut() -> Result<Box<dyn PacketLink>, LinkError>>;

/// A TRC1000 in the rig.
pub struct TrcDevice {
    /// The name scripts use.
    pub(super) name: String,
    /// Its configuration (safe relay).
    pub(super) config: Trc1000Config,
    /// The driver.
    pub(super) driver: Trc1000<Box<dyn PacketLink>>,
    reopener: Option<PacketReopener>,
    /// Whether it answers.
    pub(super) health: Health,
    /// The 45 switches, read lazily.
    pub(super) switches: Snapshot<SwitchSet>,
    /// The 14 rotary counters, read lazily, as the script sees them (the board's plus
    /// `rotary_offset`).
    pub(super) rotaries: Snapshot<RotaryValues>,
    /// The switches as last read for watchers only (`runtime::watched_image`).
    shown_switches: Snapshot<SwitchSet>,
    /// The rotaries as last read for watchers only (rebased as the script's are).
    shown_rotaries: Snapshot<RotaryValues>,
    /// Added (wrapping) to each count the board reports, so that the counts the script sees
    /// carry on across a loss: a board power cycled comes back counting from 0, and that is
    /// no turn of a knob.
    rotary_offset: [u8; 14],
    /// Taken (back) control of: the next reading of the rotaries sets `rotary_offset` so that
    /// it shows the counts last seen.
    rebase_pending: bool,
    /// The relay the script wants (0-7).
    pub(super) relay: u8,
    /// The relay last selected on the board (`None`: unknown, select again).
    pub(super) relay_written: Option<u8>,
    /// The relay last selected, even when no longer trusted: selecting it again (after the
    /// periodic check, or a return) is not news for the log.
    pub(super) relay_last: Option<u8>,
    /// The handler that last changed `relay`, for the log.
    pub(super) relay_cause: String,
}

impl TrcDevice {
    /// A board called `name` behind `driver`.
    pub fn new(
        name: &str,
        config: Trc1000Config,
        driver: Trc1000<Box<dyn PacketLink>>,
        reopener: Option<PacketReopener>,
    ) -> Self {
        Self {
            name: name.to_string(),
            relay: config.safe_relay.unwrap_or(0),
            config,
            driver,
            reopener,
            health: Health::default(),
            switches: Snapshot::default(),
            rotaries: Snapshot::default(),
            shown_switches: Snapshot::default(),
            shown_rotaries: Snapshot::default(),
            rotary_offset: [0; 14],
            rebase_pending: false,
            relay_written: None,
            relay_last: None,
            relay_cause: String::new(),
        }
    }

    /// The name scripts use.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Its configuration.
    #[inline]
    pub fn config(&self) -> &Trc1000Config {
        &self.config
    }

    /// The driver, for requests that change nothing the runtime holds of the board.
    pub fn driver(&mut self) -> &mut Trc1000<Box<dyn PacketLink>> {
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

    /// The switches as last read.
    #[inline]
    pub fn switches(&self) -> &Snapshot<SwitchSet> {
        &self.switches
    }

    /// The rotaries as last read (as the script sees them).
    #[inline]
    pub fn rotaries(&self) -> &Snapshot<RotaryValues> {
        &self.rotaries
    }

    /// The relay the script wants (0-7).
    #[inline]
    pub fn wanted_relay(&self) -> u8 {
        self.relay
    }

    /// The handler that last changed the relay the script wants ("": none yet).
    pub fn relay_cause(&self) -> &str {
        &self.relay_cause
    }

    /// The relay last selected on the board (`None`: unknown, selected again).
    #[inline]
    pub fn relay_written(&self) -> Option<u8> {
        self.relay_written
    }

    /// The relay last selected, even when no longer trusted.
    pub fn relay_last(&self) -> Option<u8> {
        self.relay_last
    }

    /// The script wants `relay`, for `cause` (kept only if it is a change).
    #[inline]
    pub fn want_relay(&mut self, relay: u8, cause: String) {
        if self.relay != relay {
            self.relay = relay;
            self.relay_cause = cause;
        }
    }

    /// The next selection of the relay is for `cause` (an operator's force ended).
    pub fn credit_relay_to(&mut self, cause: String) {
        self.relay_cause = cause;
    }

    /// The relay on the board is not known any more: the next write selects it again.
    #[cfg(test)]
    pub fn forget_relay_written(&mut self) {
        self.relay_written = None;
    }

    /// Taking control of it (again): the relay on the board is not known, and the counts
    /// it reports next are rebased to the ones last seen (`rebase_rotaries`).
    pub fn note_taking_control(&mut self) {
        self.relay_written = None;
        self.rebase_rotaries();
    }

    /// Puts forced switches (`force`) over the last reading.
    pub fn force_switches(&mut self, force: impl FnOnce(SwitchSet) -> SwitchSet) {
        if let Some(v) = self.switches.current {
            self.switches.current = Some(force(v));
        }
    }

    /// The switches are read again at their next access, even in this tick (a force
    /// changed).
    pub fn reread_switches(&mut self) {
        self.switches.tick = None;
    }

    /// The driver to select and confirm the safe relay with, and that relay (`None`: no
    /// safe relay is set). What the board holds is not known until `note_safe_state`.
    pub fn safe_driver(&mut self) -> Option<(&mut Trc1000<Box<dyn PacketLink>>, u8)> {
        let relay = self.config.safe_relay?;
        self.relay_written = None;
        Some((&mut self.driver, relay))
    }

    /// Whether the safe relay was confirmed selected.
    pub fn note_safe_state(&mut self, confirmed: bool) {
        if let (true, Some(relay)) = (confirmed, self.config.safe_relay) {
            self.relay_written = Some(relay);
            self.relay_last = Some(relay);
        }
    }

    /// Reads the switches into the snapshot at `tick`.
    pub fn read_switches(&mut self, tick: u64) -> Result<SwitchSet, DeviceError> {
        let s = self.fetch_switches()?;
        self.switches.update(s, tick);
        Ok(s)
    }

    /// Reads the switches, kept nowhere.
    pub fn fetch_switches(&mut self) -> Result<SwitchSet, DeviceError> {
        Ok(self.driver.read_switches()?)
    }

    /// Reads the rotaries into the snapshot at `tick`.
    pub fn read_rotaries(&mut self, tick: u64) -> Result<RotaryValues, DeviceError> {
        let r = self.fetch_rotaries()?;
        self.rotaries.update(r, tick);
        Ok(r)
    }

    /// The switches as last read for watchers only.
    pub fn shown_switches(&mut self) -> &mut Snapshot<SwitchSet> {
        &mut self.shown_switches
    }

    /// The rotaries as last read for watchers only.
    pub fn shown_rotaries(&mut self) -> &mut Snapshot<RotaryValues> {
        &mut self.shown_rotaries
    }

    /// The switches a person is shown: the later of the script's reading and the one made
    /// for watchers.
    pub fn latest_switches(&self) -> Option<SwitchSet> {
        self.switches.or_later(&self.shown_switches)
    }

    /// The rotaries a person is shown (as `latest_switches`).
    pub fn latest_rotaries(&self) -> Option<RotaryValues> {
        self.rotaries.or_later(&self.shown_rotaries)
    }

    /// Reads the rotaries as the script sees them (rebased, after a loss, to the counts the
    /// script last saw), kept nowhere.
    pub fn fetch_rotaries(&mut self) -> Result<RotaryValues, DeviceError> {
        let board = self.driver.read_rotaries()?.to_array();
        if std::mem::take(&mut self.rebase_pending) {
            if let Some(seen) = self.rotaries.current {
                for ((offset, seen), board) in self
                    .rotary_offset
                    .iter_mut()
                    .zip(seen.to_array())
                    .zip(board)
                {
                    *offset = seen.wrapping_sub(board);
                }
            }
        }
        let mut shown = board;
        for (v, offset) in shown.iter_mut().zip(self.rotary_offset) {
            *v = v.wrapping_add(offset);
        }
        Ok(RotaryValues::from_array(shown))
    }

    /// Taken control of again after a loss (or at start): the counts the board reports next
    /// are the ones last seen, whatever it counts from now (a power cycle resets its counts;
    /// turns made while it was lost are not seen either: the runner cannot tell them apart).
    fn rebase_rotaries(&mut self) {
        self.rebase_pending = true;
    }

    /// Selects `relay` on the board and remembers it as written.
    pub fn select_relay(&mut self, relay: u8) -> Result<(), DeviceError> {
        self.driver.select_relay(relay)?;
        self.relay_written = Some(relay);
        self.relay_last = Some(relay);
        Ok(())
    }

    /// Selects `relay` and confirms a board took it (`Trc1000::select_relay_confirmed`): the
    /// safe state's selection, which must not be counted as reached on the word of an OUT
    /// transfer alone. Unconfirmed, the relay on the board is unknown (selected again later).
    pub fn select_relay_confirmed(&mut self, relay: u8) -> Result<(), DeviceError> {
        self.relay_written = None;
        self.driver.select_relay_confirmed(relay)?;
        self.relay_written = Some(relay);
        Ok(())
    }

    /// A cheap request that tells whether the board answers.
    pub fn probe(&mut self) -> Result<(), DeviceError> {
        self.driver.read_switches()?;
        Ok(())
    }

    /// Opens the USB link again, if this board has a real one.
    pub fn reopen(&mut self) -> Result<(), DeviceError> {
        if let Some(open) = &mut self.reopener {
            let what = self.driver.describe();
            // Release the old handle first: the interface is claimed exclusively.
            *self.driver.link_mut() = Box::new(super::links::ClosedLink(what));
            let link = open().map_err(crate::device::trc1000::Trc1000Error::Link)?;
            *self.driver.link_mut() = link;
        }
        Ok(())
    }
}
