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
    pub name: String,
    /// Its configuration (safe relay).
    pub config: Trc1000Config,
    /// The driver.
    pub driver: Trc1000<Box<dyn PacketLink>>,
    reopener: Option<PacketReopener>,
    /// Whether it answers.
    pub health: Health,
    /// The 45 switches, read lazily.
    pub switches: Snapshot<SwitchSet>,
    /// The 14 rotary counters, read lazily, as the script sees them (the board's plus
    /// `rotary_offset`).
    pub rotaries: Snapshot<RotaryValues>,
    /// Added (wrapping) to each count the board reports, so that the counts the script sees
    /// carry on across a loss: a board power cycled comes back counting from 0, and that is
    /// no turn of a knob.
    rotary_offset: [u8; 14],
    /// Taken (back) control of: the next reading of the rotaries sets `rotary_offset` so that
    /// it shows the counts last seen.
    rebase_pending: bool,
    /// The relay the script wants (0-7).
    pub relay: u8,
    /// The relay last selected on the board (`None`: unknown, select again).
    pub relay_written: Option<u8>,
    /// The relay last selected, even when no longer trusted: selecting it again (after the
    /// periodic check, or a return) is not news for the log.
    pub relay_last: Option<u8>,
    /// The handler that last changed `relay`, for the log.
    pub relay_cause: String,
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
            rotary_offset: [0; 14],
            rebase_pending: false,
            relay_written: None,
            relay_last: None,
            relay_cause: String::new(),
        }
    }

    /// Reads the switches into the snapshot at `tick`.
    pub fn read_switches(&mut self, tick: u64) -> Result<SwitchSet, DeviceError> {
        let s = self.driver.read_switches()?;
        self.switches.update(s, tick);
        Ok(s)
    }

    /// Reads the rotaries into the snapshot at `tick` (rebased, after a loss, to the counts
    /// last seen).
    pub fn read_rotaries(&mut self, tick: u64) -> Result<RotaryValues, DeviceError> {
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
        let r = RotaryValues::from_array(shown);
        self.rotaries.update(r, tick);
        Ok(r)
    }

    /// Taken control of again after a loss (or at start): the counts the board reports next
    /// are the ones last seen, whatever it counts from now (a power cycle resets its counts;
    /// turns made while it was lost are not seen either: the runner cannot tell them apart).
    pub fn rebase_rotaries(&mut self) {
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
