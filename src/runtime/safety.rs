//! Fail-safe supervision: taking control of every device at start (safe and power-on values
//! stored, outputs safe, host watchdog on), trying lost devices again in the background and
//! taking control of them again when they are back, holding every output safe while a device
//! has been lost for longer than its grace time, and the safe state at the end.

use super::core::Runtime;
use super::devices::{Device, DeviceError};
use crate::time::duration::format_duration;

/// A device that could not be brought under control at start.
#[derive(Debug, thiserror::Error)]
#[error("device {device} is not available: {source}")]
pub struct Unavailable {
    /// The device's name.
    pub device: String,
    /// Why.
    #[source]
    pub source: DeviceError,
}

impl<H: Clone> Runtime<H> {
    /// Takes control of every device at start: a TRP-C29U gets its configured safe value
    /// (also its own watchdog safe value) and power-on value, its outputs at the safe value,
    /// and its host watchdog on; a TRC1000 must answer and gets its safe relay if configured.
    pub fn start_devices(&mut self) -> Result<(), Unavailable> {
        for idx in 0..self.devices.len() {
            let now = self.now();
            let result = match self.devices.get_mut(idx) {
                Some(Device::C29u(d)) => {
                    let safe = d.config.safe_value;
                    d.outputs = safe;
                    d.take_control(safe, now).map(|_| ())
                }
                Some(Device::Trc(d)) => d.probe().and_then(|()| match d.config.safe_relay {
                    Some(r) => d.select_relay(r),
                    None => Ok(()),
                }),
                None => Ok(()),
            };
            let name = self.devices.get(idx).map_or("", Device::name).to_string();
            if let Err(source) = result {
                return Err(Unavailable {
                    device: name,
                    source,
                });
            }
            let summary = self.describe_control(idx);
            self.log.info(&format!("{name}: {summary}"));
        }
        Ok(())
    }

    /// The device at `idx` in a few words: what it is and its safe state.
    fn describe_control(&mut self, idx: usize) -> String {
        match self.devices.get_mut(idx) {
            Some(Device::C29u(d)) => {
                let wd = match d.watchdog {
                    Some(t) => format!("host watchdog {}", format_duration(t.as_duration())),
                    None => "no host watchdog".into(),
                };
                format!(
                    "{}, outputs at safe value {:#04x}, {wd}",
                    d.driver.describe(),
                    d.config.safe_value
                )
            }
            Some(Device::Trc(d)) => match d.config.safe_relay {
                Some(r) => format!("{}, relay at safe position {r}", d.driver.describe()),
                None => format!("{} (no safe relay set)", d.driver.describe()),
            },
            None => String::new(),
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
                    let retry = now.saturating_add(super::core::RETRY_INTERVAL);
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

    /// Writes the safe state of every device that answers: a TRP-C29U's safe value, a
    /// TRC1000's safe relay (where configured). Logs what it wrote and why.
    pub fn write_safe_state(&mut self, why: &str) {
        let mut done = Vec::new();
        for idx in 0..self.devices.len() {
            if !self.online(idx) {
                if let Some(d) = self.devices.get(idx) {
                    done.push(format!("{} lost (its own watchdog, if on, acts)", d.name()));
                }
                continue;
            }
            let result = match self.devices.get_mut(idx) {
                Some(Device::C29u(d)) => d
                    .write_safe()
                    .map(|()| Some(format!("{} outputs {:#04x}", d.name, d.config.safe_value))),
                Some(Device::Trc(d)) => match d.config.safe_relay {
                    Some(r) => d
                        .select_relay(r)
                        .map(|()| Some(format!("{} relay {r}", d.name))),
                    None => Ok(None),
                },
                None => Ok(None),
            };
            match result {
                Ok(Some(s)) => done.push(s),
                Ok(None) => {}
                Err(e) => {
                    let name = self.devices.get(idx).map_or("", Device::name).to_string();
                    self.log
                        .error(&format!("{name}: writing the safe state failed: {e}"));
                    self.note_failure(idx, &e);
                }
            }
        }
        if !done.is_empty() {
            self.log
                .info(&format!("safe state ({why}): {}", done.join(", ")));
        }
    }

    /// Turns off the host watchdogs the runner turned on, once the outputs are safe at a
    /// clean end (a killed runner leaves them on, so the modules go safe by themselves).
    pub fn release_watchdogs(&mut self) {
        for idx in 0..self.devices.len() {
            if !self.online(idx) {
                continue;
            }
            let Some(d) = self.c29u(idx) else { continue };
            if let Err(e) = d.release_watchdog() {
                let name = d.name.clone();
                self.log
                    .warn(&format!("{name}: turning its watchdog off failed: {e}"));
                self.note_failure(idx, &e);
            }
        }
    }
}
