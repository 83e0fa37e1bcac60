//! Losing devices and getting them back: a communication failure marks a device lost; it is
//! tried again once a second without retries and taken control of again when it answers;
//! past the grace time every output is held safe until all devices are back.

use crate::runtime::devices::{Device, DeviceError};
use crate::runtime::state::Runtime;
use crate::time::duration::format_duration;
use std::time::Duration;

/// How often a lost device is tried again.
pub const RETRY_INTERVAL: Duration = Duration::from_secs(1);

impl<H: Clone> Runtime<H> {
    /// Notes a failed operation: a communication failure marks the device lost.
    pub fn note_failure(&mut self, idx: usize, error: &DeviceError) {
        if !error.is_comm_failure() {
            return;
        }
        let now = self.now();
        if let Some(d) = self.devices.get_mut(idx) {
            let name = d.name().to_string();
            if d.health_mut().lose(now, error, RETRY_INTERVAL) {
                self.log.warn(&format!(
                    "{name}: lost: {error}; trying again every {}",
                    format_duration(RETRY_INTERVAL)
                ));
            }
        }
    }

    /// Tries lost devices whose retry time has come (one try each, without retries, so a
    /// lost device costs at most one timeout a second), takes control of those that are back,
    /// and holds every output safe while a device has been lost beyond the grace time.
    pub fn supervise(&mut self) {
        for idx in 0..self.devices.len() {
            let now = self.now();
            let Some(d) = self.devices.get_mut(idx) else {
                continue;
            };
            let health = d.health();
            if health.online() || now < health.next_retry {
                continue;
            }
            let reopen = health.link_failed;
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
                        self.log.info(&format!(
                            "{name}: back after {}; watchdog, safe value and outputs applied \
                             again",
                            format_duration(lost_for)
                        ));
                    }
                }
                Err(e) => {
                    let retry = now.saturating_add(RETRY_INTERVAL);
                    let h = d.health_mut();
                    h.next_retry = retry;
                    h.link_failed = h.link_failed || e.is_link_failure();
                }
            }
        }
        self.check_grace();
    }

    /// Holds everything safe once a device has been lost for longer than the grace time;
    /// lets go when every device is back.
    fn check_grace(&mut self) {
        let now = self.now();
        let beyond: Vec<String> = self
            .devices
            .iter()
            .filter(|d| d.health().lost_for(now) > self.grace)
            .map(|d| d.name().to_string())
            .collect();
        let all_back = self.devices.iter().all(|d| d.health().online());
        if !self.held_safe && !beyond.is_empty() {
            self.held_safe = true;
            self.log.warn(&format!(
                "{} lost for longer than the grace time ({}): every output is held at its \
                 safe state until it is back",
                beyond.join(", "),
                format_duration(self.grace)
            ));
        } else if self.held_safe && all_back {
            self.held_safe = false;
            self.log
                .info("every device is back: the script's outputs apply again");
        }
    }
}
