//! Noticing a loss between exchanges, whatever the script reads: the links the OS can tell
//! the end of (a serial port's hang-up or error, a TCP connection's close or reset) are asked
//! every `LINK_WATCH_INTERVAL` without reading anything, and a device not heard from for a
//! quarter of the grace time (one the script does not read, a module without a host watchdog
//! to feed) is asked once, so that a loss starts its grace time when it happens, not at the next device
//! check.

use crate::device::c29u::C29uError;
use crate::device::trc1000::Trc1000Error;
use crate::link::{fd, LinkError, Watch};
use crate::runtime::devices::{Device, DeviceError};
use crate::runtime::log::Level;
use crate::runtime::state::Runtime;
use std::time::Duration;

/// How often the links the OS can tell the end of are asked: one `ppoll` for them all, only
/// when the loop is awake anyway or this is due; a loss is noticed within this time.
pub const LINK_WATCH_INTERVAL: Duration = Duration::from_millis(100);

/// The shortest time between two probes of one device, whatever the grace time (a grace of
/// zero would otherwise ask an idle device at every turn of the loop).
pub const LEAST_PROBE_INTERVAL: Duration = Duration::from_millis(50);

impl<H: Clone> Runtime<H> {
    /// Notes that the device at `idx` answered at `at` (it needs no probe for a while).
    pub fn heard(&mut self, idx: usize, at: Duration) {
        if let Some(d) = self.devices.get_mut(idx) {
            d.health_mut().heard(at);
        }
    }

    /// When the device at `idx` is due a probe, if it is: not heard from for `probe_interval`.
    /// One the script read in the current tick, with the next tick (`next_tick`) within half
    /// the grace time of that read, is left to that tick: a slow period (longer than the
    /// probe interval) must not add a probe between every two reads.
    fn probe_due(&self, idx: usize, next_tick: Duration) -> Option<Duration> {
        let h = self.devices.get(idx)?.health();
        if !h.online() {
            return None;
        }
        let read_now = h.read_in(self.cycle().tick());
        if read_now && next_tick <= h.heard_at().saturating_add(self.safety.grace() / 2) {
            return None;
        }
        Some(h.heard_at().saturating_add(self.safety.probe_interval()))
    }

    /// When the loop next has to look at the links or probe a device (`None`: no device has
    /// a link to watch and none is due a probe before `next_tick`, the next tick's deadline).
    pub fn next_liveness(&self, next_tick: Duration) -> Option<Duration> {
        let probes = (0..self.devices.len())
            .filter_map(|idx| self.probe_due(idx, next_tick))
            .min();
        let watch = self.safety.next_link_watch();
        match (probes, watch) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Asks the OS which links have ended, if that is due, and probes each device due a probe
    /// (`probe_due`, with the next tick at `next_tick`); a device found lost is marked lost at
    /// once (its grace time runs from now), with the OS's reason.
    pub fn watch_liveness(&mut self, now: Duration, next_tick: Duration) {
        if self.safety.link_watch_due(now) {
            self.watch_links();
        }
        for idx in 0..self.devices.len() {
            let due = self.probe_due(idx, next_tick).is_some_and(|at| now >= at);
            if due && !self.safety.stopping() {
                self.probe_idle(idx);
            }
        }
    }

    /// One `ppoll` over the links that have a descriptor; a link that ended marks every
    /// device on it lost.
    fn watch_links(&mut self) {
        let watched: Vec<(usize, Watch)> = self
            .devices
            .iter()
            .enumerate()
            .filter(|(_, d)| d.health().online())
            .filter_map(|(idx, d)| link_watch(d).map(|w| (idx, w)))
            .collect();
        let has = !watched.is_empty() || self.devices.iter().any(has_watch);
        self.safety.note_link_watch(has);
        if watched.is_empty() {
            return;
        }
        let watches: Vec<Watch> = watched.iter().map(|(_, w)| *w).collect();
        let ended = match fd::ended(&watches) {
            Ok(ended) => ended,
            Err(e) => {
                self.log_mut().repeating(
                    "links/watch",
                    Level::Warn,
                    &format!(
                        "could not ask the OS whether the links are up ({e}): a loss is \
                         noticed at the next exchange"
                    ),
                );
                return;
            }
        };
        for ((idx, _), why) in watched.into_iter().zip(ended) {
            let Some(why) = why else { continue };
            let Some(d) = self.devices.get(idx) else {
                continue;
            };
            let link = LinkError::Disconnected {
                what: link_name(d),
                detail: format!("{why} (the OS says so between exchanges)"),
            };
            let error = match d {
                Device::C29u(_) => DeviceError::C29u(C29uError::Link(link)),
                Device::Trc(_) => DeviceError::Trc(Trc1000Error::Link(link)),
            };
            self.note_failure(idx, &error);
        }
    }

    /// Asks the device at `idx` one question (its outputs, its switches), as a script's read
    /// would: an answer is heard, a communication failure marks it lost.
    fn probe_idle(&mut self, idx: usize) {
        if !self.ready_for_exchange(idx) {
            return;
        }
        let result = match self.devices.get_mut(idx) {
            Some(Device::C29u(d)) => d
                .driver()
                .read_outputs()
                .map(drop)
                .map_err(DeviceError::from),
            Some(Device::Trc(d)) => d.probe(),
            None => return,
        };
        let now = self.now();
        match result {
            Ok(()) => self.heard(idx, now),
            Err(e) => {
                self.note_failure(idx, &e);
                // An answer that was a refusal is an answer all the same.
                if !e.is_comm_failure() {
                    self.heard(idx, now);
                }
            }
        }
    }
}

/// The watched descriptor of a device's link, if it has one.
fn link_watch(d: &Device) -> Option<Watch> {
    match d {
        Device::C29u(c) => c.link_watch(),
        // USB transfers are made only when asked (interrupt transfers, no polling thread):
        // a board unplugged fails its next one at once, which `probe_idle` makes.
        Device::Trc(_) => None,
    }
}

/// Whether a device's link has a descriptor to watch (lost or not).
fn has_watch(d: &Device) -> bool {
    link_watch(d).is_some()
}

/// The link of a device in words, for the loss's log line.
fn link_name(d: &Device) -> String {
    d.describe()
}

#[cfg(test)]
mod tests {
    use crate::runtime::testing::{TestRig, IO, PANEL};
    use std::time::Duration;

    #[test]
    fn an_idle_device_is_asked_every_quarter_grace_and_one_gone_silent_is_lost_then() {
        let mut r = TestRig::started();
        assert_eq!(
            r.rt.safety.probe_interval(),
            Duration::from_millis(250),
            "grace 1 s"
        );
        // Nobody reads the panel; the module is heard at each feed of its watchdog.
        let due =
            r.rt.devices.get(PANEL).unwrap().health().heard_at() + r.rt.safety.probe_interval();
        assert!(r
            .rt
            .next_liveness(Duration::MAX)
            .is_some_and(|at| at <= due));
        r.clock.advance(due - r.rt.now() - Duration::from_millis(1));
        let before = r.requests();
        let now = r.rt.now();
        r.rt.watch_liveness(now, Duration::MAX);
        assert_eq!(r.requests(), before, "not yet");
        r.clock.advance(Duration::from_millis(1));
        r.rt.feed_watchdogs();
        let before = r.requests();
        let now = r.rt.now();
        r.rt.watch_liveness(now, Duration::MAX);
        assert_eq!(r.requests(), before + 1, "one question to the panel");
        assert_eq!(r.rt.devices.get(PANEL).unwrap().health().heard_at(), now);
        // It goes silent: asked again a quarter of the grace time on, and lost then, not at the next
        // device check.
        r.sim.set_gone("panel", true).unwrap();
        r.clock.advance(r.rt.safety.probe_interval());
        let now = r.rt.now();
        r.rt.watch_liveness(now, Duration::MAX);
        assert!(!r.rt.devices.online(PANEL));
        assert!(r.log().contains("panel: lost: "), "{}", r.log());
        assert!(r.rt.devices.online(IO));
    }

    #[test]
    fn a_device_the_script_reads_is_not_asked_besides() {
        let mut r = TestRig::started();
        for _ in 0..100 {
            r.next_tick(Duration::from_millis(20));
            let now = r.rt.now();
            r.rt.cycle.set_boundary(now);
            let before = r.requests();
            r.rt.switches(PANEL);
            let now = r.rt.now();
            r.rt.watch_liveness(now, Duration::MAX);
            // The read, and the module's feed when it falls due: never a probe of the panel.
            assert!(r.requests() - before <= 2);
            assert!(r.rt.devices.get(PANEL).unwrap().health().heard_at() == now);
        }
    }

    #[test]
    fn a_device_read_every_slow_tick_is_left_to_the_next_tick() {
        let mut r = TestRig::started();
        r.next_tick(Duration::from_millis(20));
        let read_at = r.rt.now();
        r.rt.cycle.set_boundary(read_at);
        r.rt.switches(PANEL);
        r.clock.advance(Duration::from_millis(300));
        r.rt.feed_watchdogs();
        let now = r.rt.now();
        let before = r.requests();
        // A 500 ms period: the next tick reads it within half the grace time.
        r.rt.watch_liveness(now, read_at + Duration::from_millis(500));
        assert_eq!(r.requests(), before, "no probe between two reads");
        // A period longer than half the grace time: asked between the reads.
        r.rt.watch_liveness(now, read_at + Duration::from_millis(600));
        assert_eq!(r.requests(), before + 1);
    }
}
