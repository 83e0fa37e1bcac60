//! Keeping control while the run goes: host watchdogs fed at a quarter of their timeout, and
//! every few seconds the modules' outputs read back and the relays selected again.

use crate::runtime::devices::{Device, DeviceError};
use crate::runtime::state::Runtime;
use std::time::Duration;

impl<H: Clone> Runtime<H> {
    /// Feeds each host watchdog the runner keeps, at a quarter of its timeout (or every
    /// tick, if the period is longer than that).
    pub fn feed_watchdogs(&mut self) {
        let now = self.now();
        for idx in 0..self.devices.len() {
            if !self.online(idx) {
                continue;
            }
            let Some(d) = self.c29u(idx) else { continue };
            let Some(t) = d.watchdog else { continue };
            if let Err(e) = d.feed(now, t.as_duration() / 4) {
                self.note_failure(idx, &e);
            }
        }
    }

    /// When supervision next has work of its own: the earliest watchdog feed or retry of a
    /// lost device (`None`: nothing to feed, nothing lost).
    pub fn next_upkeep(&self) -> Option<Duration> {
        self.devices
            .iter()
            .filter_map(|d| {
                let h = d.health();
                if !h.online() {
                    return Some(h.next_retry);
                }
                match d {
                    Device::C29u(c) => c
                        .watchdog
                        .map(|t| c.last_feed.saturating_add(t.as_duration() / 4)),
                    Device::Trc(_) => None,
                }
            })
            .min()
    }

    /// Checks that the modules still drive what was written (a module reset or power cycled
    /// by someone else goes back to its power-on value) and selects each relay again (a board
    /// that was unplugged forgets it); run every few seconds.
    pub fn verify_outputs(&mut self) {
        for idx in 0..self.devices.len() {
            if !self.online(idx) {
                continue;
            }
            let result = match self.devices.get_mut(idx) {
                Some(Device::C29u(d)) => match d.outputs_written {
                    Some(written) => {
                        d.driver
                            .read_outputs()
                            .map_err(DeviceError::from)
                            .map(|actual| {
                                (actual != written).then(|| {
                                    d.outputs_written = None;
                                    format!(
                                        "{}: outputs read {actual:#04x} but {written:#04x} was \
                                     written (module reset or power cycled?); writing them again",
                                        d.name
                                    )
                                })
                            })
                    }
                    None => Ok(None),
                },
                Some(Device::Trc(d)) => {
                    d.relay_written = None;
                    Ok(None)
                }
                None => Ok(None),
            };
            match result {
                Ok(Some(line)) => self.log.warn(&line),
                Ok(None) => {}
                Err(e) => self.note_failure(idx, &e),
            }
        }
    }
}
