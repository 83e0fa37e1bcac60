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

#[cfg(test)]
mod tests {
    use crate::runtime::testing::{TestRig, IO, PANEL};
    use std::time::Duration;

    const TICK: Duration = Duration::from_millis(20);

    #[test]
    fn host_watchdogs_are_fed_at_a_quarter_of_their_timeout() {
        let mut r = TestRig::started();
        let before = r.requests();
        for _ in 0..500 {
            r.next_tick(TICK);
            r.rt.feed_watchdogs();
        }
        assert!(!r.sim.safe_mode("io").unwrap(), "10 s fed, never expired");
        // At the first tick at least 250 ms after the last feed: every 260 ms at 20 ms ticks.
        assert_eq!(r.requests() - before, 10_000 / 260);
    }

    #[test]
    fn next_upkeep_is_the_earliest_feed_or_retry() {
        let mut r = TestRig::started();
        assert_eq!(r.rt.next_upkeep(), Some(Duration::from_millis(250)));
        r.sim.set_gone("panel", true).unwrap();
        r.clock.advance(Duration::from_millis(100));
        r.rt.switches(PANEL);
        let lost_at = r.rt.now();
        assert_eq!(r.rt.next_upkeep(), Some(Duration::from_millis(250)));
        r.rt.c29u(IO).unwrap().watchdog = None;
        assert_eq!(r.rt.next_upkeep(), Some(lost_at + Duration::from_secs(1)));
    }

    #[test]
    fn outputs_changed_behind_the_runners_back_are_noticed_and_written_again() {
        let mut r = TestRig::started();
        r.rt.set_outputs(IO, 0x21);
        r.rt.flush_outputs();
        r.sim.power_cycle("io").unwrap();
        assert_eq!(r.sim.outputs("io").unwrap(), 0x11, "the power-on value");
        r.rt.verify_outputs();
        assert!(
            r.log().contains(
                "io: outputs read 0x11 but 0x21 was written (module reset or power cycled?)"
            ),
            "{}",
            r.log()
        );
        r.rt.flush_outputs();
        assert_eq!(r.sim.outputs("io").unwrap(), 0x21);
    }

    #[test]
    fn relays_are_selected_again_at_each_check() {
        let mut r = TestRig::started();
        r.rt.set_relay(PANEL, 4);
        r.rt.flush_outputs();
        r.sim.power_cycle("panel").unwrap();
        assert_ne!(r.sim.relay("panel").unwrap(), 4);
        r.rt.verify_outputs();
        r.rt.flush_outputs();
        assert_eq!(r.sim.relay("panel").unwrap(), 4);
    }
}
