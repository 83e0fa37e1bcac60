//! Losing devices and getting them back: a communication failure marks a device lost; it is
//! tried again (first before its host watchdog is due, then once a second) without retries and taken control of again when it answers;
//! past the grace time every output is held safe until all devices are back.

use crate::runtime::devices::{Device, DeviceError};
use crate::runtime::observe::RunEvent;
use crate::runtime::state::Runtime;
use crate::time::duration::format_duration;
use std::time::Duration;

/// How often a lost device is tried again.
pub const RETRY_INTERVAL: Duration = Duration::from_secs(1);

/// How soon a device just lost is tried the first time: at its host watchdog's feed interval
/// when the runner feeds one and that is sooner than `RETRY_INTERVAL`. One lost answer (noise
/// on the line, with `retries = 0`) would otherwise leave the watchdog unfed for a second, past
/// a short timeout, and the module would drop the script's outputs to the safe value for
/// nothing; a try that gets an answer takes control again, which feeds it. Later tries come
/// once a second, so a device that is really gone costs one timeout a second.
fn first_retry(d: &Device) -> Duration {
    match d {
        Device::C29u(c) if c.controlled() => c
            .feed_interval()
            .map_or(RETRY_INTERVAL, |feed| feed.min(RETRY_INTERVAL)),
        _ => RETRY_INTERVAL,
    }
}

impl<H: Clone> Runtime<H> {
    /// Notes a failed operation: a communication failure marks the device lost.
    pub fn note_failure(&mut self, idx: usize, error: &DeviceError) {
        if !error.is_comm_failure() {
            return;
        }
        let now = self.now();
        if let Some(d) = self.devices.get_mut(idx) {
            let name = d.name().to_string();
            let first_try = if d.health().online() {
                first_retry(d)
            } else {
                RETRY_INTERVAL
            };
            if d.health_mut().lose(now, error, first_try) {
                let when = if first_try < RETRY_INTERVAL {
                    format!(
                        "in {} (before its host watchdog is due), then every {}",
                        format_duration(first_try),
                        format_duration(RETRY_INTERVAL)
                    )
                } else {
                    format!("every {}", format_duration(RETRY_INTERVAL))
                };
                self.log_mut()
                    .warn(&format!("{name}: lost: {error}; trying again {when}"));
                self.events().publish(|| RunEvent::DeviceLost {
                    device: name,
                    cause: error.to_string(),
                });
            }
        }
    }

    /// When the next lost device is to be tried again (`None`: none is lost).
    pub fn next_retry(&self) -> Option<Duration> {
        self.devices
            .iter()
            .map(Device::health)
            .filter(|h| !h.online())
            .map(|h| h.next_retry())
            .min()
    }

    /// Tries lost devices whose retry time has come (one try each, without retries, so a
    /// lost device costs at most one timeout a second), takes control of those that are back,
    /// and holds every output safe while a device has been lost beyond the grace time. Once
    /// the run is stopping (`cancel`), no further device is tried: each try of a lost one can
    /// cost a reconnection (up to its timeout), and the end tries them all anyway.
    pub fn supervise(&mut self) {
        for idx in 0..self.devices.len() {
            if self.safety.stopping() {
                break;
            }
            let now = self.now();
            let due = self
                .devices
                .get(idx)
                .is_some_and(|d| !d.health().online() && now >= d.health().next_retry());
            if !due {
                continue;
            }
            self.feed_watchdogs();
            let Some(d) = self.devices.get_mut(idx) else {
                continue;
            };
            let health = d.health();
            let reopen = health.link_failed();
            let tried = if reopen { d.reopen() } else { Ok(()) };
            let tried = tried.and_then(|()| match d {
                Device::C29u(c) => c.probe(),
                Device::Trc(t) => t.probe(),
            });
            match tried {
                Ok(()) => {
                    let name = d.name().to_string();
                    let lost_for = d.health().lost_for(now);
                    // Back only once it is under control again: a device that answers a probe
                    // but fails the rest stays lost, and its grace time keeps running.
                    if self.take_control(idx) {
                        if let Some(d) = self.devices.get_mut(idx) {
                            d.health_mut().back();
                        }
                        self.log_mut().notice(&format!(
                            "{name}: back after {}; watchdog, safe value and outputs applied \
                             again",
                            format_duration(lost_for)
                        ));
                        self.events()
                            .publish(|| RunEvent::DeviceBack { device: name });
                    } else if let Some(d) = self.devices.get_mut(idx) {
                        // Only a lost answer moves the retry time on (`note_failure`); after a
                        // refusal it would stay past, and the device be tried every tick.
                        d.health_mut().put_off_retry(now, RETRY_INTERVAL);
                    }
                }
                Err(e) => {
                    let retry = now.saturating_add(RETRY_INTERVAL);
                    d.health_mut().note_try_failed(&e, retry);
                }
            }
        }
        self.check_grace();
    }

    /// When the outputs are to be held safe for a lost device, if one is lost and they are
    /// not held yet: the moment its grace time is over (the loop wakes for it between ticks,
    /// whatever the period and the timers).
    pub fn grace_ends(&self) -> Option<Duration> {
        if self.safety.held() {
            return None;
        }
        let first_lost = self
            .devices
            .iter()
            .filter_map(|d| d.health().lost_at())
            .min()?;
        // Held once lost for longer than the grace time, as `check_grace` has it.
        Some(
            first_lost
                .saturating_add(self.safety.grace())
                .saturating_add(Duration::from_nanos(1)),
        )
    }

    /// Between ticks, once a grace time is over (`grace_ends`) or supervision found one over:
    /// every output held at its safe state at once, the safe values written now rather than
    /// at the next tick. `was_held`: whether they were held before supervision looked.
    pub fn hold_safe_between_ticks(&mut self, was_held: bool) {
        self.check_grace();
        if self.safety.held() && !was_held {
            self.flush_outputs();
        }
    }

    /// Holds everything safe once a device has been lost for longer than the grace time;
    /// lets go when every device is back.
    fn check_grace(&mut self) {
        let now = self.now();
        let beyond: Vec<String> = self
            .devices
            .iter()
            .filter(|d| d.health().lost_for(now) > self.safety.grace())
            .map(|d| d.name().to_string())
            .collect();
        let all_back = self.devices.iter().all(|d| d.health().online());
        let held = self.safety.held();
        if !held && !beyond.is_empty() {
            self.safety.set_held(true);
            self.cancel_forces(&format!("{} lost past its grace time", beyond.join(", ")));
            let grace = format_duration(self.safety.grace());
            self.log_mut().warn(&format!(
                "{} lost for longer than the grace time ({grace}): every output is held at \
                 its safe state until it is back",
                beyond.join(", "),
            ));
        } else if held && all_back {
            self.safety.set_held(false);
            self.log_mut()
                .notice("every device is back: the script's outputs apply again");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::RETRY_INTERVAL;
    use crate::runtime::devices::DeviceError;
    use crate::runtime::testing::{TestRig, IO, PANEL, RIG};
    use std::time::Duration;

    const TICK: Duration = Duration::from_millis(20);

    /// Reads the module's inputs in a new tick, as a handler would.
    fn poll(r: &mut TestRig) {
        r.next_tick(TICK);
        r.rt.inputs(IO);
    }

    #[test]
    fn a_lost_device_is_tried_before_its_watchdog_is_due_then_once_a_second() {
        let mut r = TestRig::started();
        let feed = r.rt.devices.c29u(IO).unwrap().feed_interval().unwrap();
        assert!(
            feed < RETRY_INTERVAL,
            "the rig's watchdog is fed more often"
        );
        r.sim.set_gone("io", true).unwrap();
        poll(&mut r);
        assert!(!r.rt.devices.online(IO));
        assert_eq!(r.log().matches("io: lost: ").count(), 1);
        assert!(
            r.log().contains("then every 1s"),
            "the first try comes sooner: {}",
            r.log()
        );
        let before = r.requests();
        r.clock.advance(feed - TICK);
        r.rt.supervise();
        assert_eq!(r.requests(), before, "not before its first try");
        r.clock.advance(TICK);
        let tried_at = r.rt.now();
        r.rt.supervise();
        assert_eq!(r.requests(), before + 1, "one try, no retries");
        assert!(!r.rt.devices.online(IO));
        assert_eq!(
            r.rt.next_retry(),
            Some(tried_at + RETRY_INTERVAL),
            "then once a second"
        );
        let before = r.requests();
        r.clock.advance(tried_at + RETRY_INTERVAL - r.rt.now());
        r.rt.supervise();
        assert_eq!(r.requests(), before + 1, "one try, no retries");
        assert!(!r.rt.devices.online(IO));
        r.sim.set_gone("io", false).unwrap();
        r.rt.set_outputs(IO, 0x0C);
        r.clock.advance(RETRY_INTERVAL);
        r.rt.supervise();
        assert!(r.rt.devices.online(IO));
        assert!(!r.rt.held_safe(), "lost past the grace time, and now back");
        r.rt.flush_outputs();
        assert_eq!(
            r.sim.outputs("io").unwrap(),
            0x0C,
            "the script's outputs again"
        );
        assert!(r.log().contains("io: back after"), "{}", r.log());
        assert_eq!(r.log().matches("io: lost: ").count(), 1, "lost once");
    }

    #[test]
    fn past_the_grace_time_everything_is_held_safe_until_every_device_is_back() {
        let mut r = TestRig::started();
        r.rt.set_outputs(IO, 0x30);
        r.rt.flush_outputs();
        r.sim.set_gone("panel", true).unwrap();
        r.next_tick(TICK);
        r.rt.switches(PANEL);
        r.clock.advance(Duration::from_millis(900));
        r.rt.supervise();
        assert!(!r.rt.held_safe(), "within the grace time");
        r.clock.advance(Duration::from_millis(200));
        r.rt.supervise();
        assert!(r.rt.held_safe());
        r.rt.flush_outputs();
        assert_eq!(
            r.sim.outputs("io").unwrap(),
            0x05,
            "the device that answers goes safe"
        );
        assert!(r
            .log()
            .contains("panel lost for longer than the grace time (1s)"));
        r.sim.set_gone("panel", false).unwrap();
        r.clock.advance(RETRY_INTERVAL);
        r.rt.supervise();
        assert!(!r.rt.held_safe());
        r.rt.flush_outputs();
        assert_eq!(r.sim.outputs("io").unwrap(), 0x30);
        assert!(r.log().contains("every device is back"), "{}", r.log());
    }

    #[test]
    fn a_device_back_that_refuses_to_be_taken_control_of_is_tried_once_a_second_and_logged_once() {
        let toml = RIG.replace(
            "safe_value = 0x05\npower_on_value = 0x11",
            "protocol = \"ascii\"\nchecksum = true\nsafe_value = 0x05\npower_on_value = 0x05",
        );
        let mut r = TestRig::new(&toml);
        r.rt.start_devices().unwrap();
        r.sim.set_gone("io", true).unwrap();
        poll(&mut r);
        assert!(!r.rt.devices.online(IO));
        // It answers again, but every takeover is refused (here: a power-on value it cannot
        // store over ASCII without driving its outputs; a module answering with an exception
        // takes the same way).
        r.rt.devices.c29u(IO).unwrap().config_mut().power_on_value = Some(0x11);
        r.sim.set_gone("io", false).unwrap();
        let before = r.requests();
        let minute = 60_000 / TICK.as_millis();
        for _ in 0..minute {
            r.next_tick(TICK);
            r.rt.supervise();
        }
        assert!(!r.rt.devices.online(IO));
        let log = r.log();
        assert_eq!(log.matches("io: taking control failed").count(), 1, "{log}");
        let tries = r.requests() - before;
        // A takeover asks up to 8 things (identity and stored settings included); tried every
        // tick, a minute would be thousands.
        assert!(
            tries <= 61 * 8,
            "a try a second, a few requests each: {tries} requests in a minute"
        );
    }

    #[test]
    fn only_communication_failures_lose_a_device() {
        let mut r = TestRig::started();
        let refused = DeviceError::Offline {
            device: "io".into(),
            ago: Duration::ZERO,
            cause: String::new(),
        };
        r.rt.note_failure(IO, &refused);
        assert!(r.rt.devices.online(IO));
    }
}
