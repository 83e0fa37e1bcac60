//! A module's fail-safe settings as its script changes them: refused where rig.toml gives
//! the setting and does not let the script change it (`script_may_change`), never weakened
//! behind the operator's back; and written to the module only when they differ from what it
//! holds (its EEPROM wears, and a script may assign the same value every tick).

use super::c29u::C29uDevice;
use super::DeviceError;
use crate::config::feeding::FeedTiming;
use crate::device::c29u::WatchdogTimeout;
use crate::time::duration::format_duration;
use std::time::Duration;

/// Why a script may not change a setting.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SettingRefused {
    /// rig.toml gives the setting and does not let the script change it.
    #[error(
        "rig.toml sets {device}'s {what} ({configured}); a script may {action} only where \
         [devices.{device}] allows it: {key} = [\"{setting}\"]"
    )]
    Locked {
        /// The device.
        device: String,
        /// The setting in words ("safe value").
        what: &'static str,
        /// Its key in rig.toml.
        setting: &'static str,
        /// What rig.toml sets.
        configured: String,
        /// What the script tried ("change it", "turn it off", "lengthen it").
        action: &'static str,
        /// `script_may_change`.
        key: &'static str,
    },
    /// A watchdog the runner could not feed in time on this rig.
    #[error("a {} watchdog on {device} {reason}", format_duration(*timeout))]
    TooShort {
        /// The device.
        device: String,
        /// The timeout asked for.
        timeout: Duration,
        /// The arithmetic (`FeedTiming::explain`).
        reason: String,
    },
}

impl C29uDevice {
    fn locked(
        &self,
        what: &'static str,
        setting: &'static str,
        configured: String,
        action: &'static str,
    ) -> DeviceError {
        DeviceError::Refused(Box::new(SettingRefused::Locked {
            device: self.name.clone(),
            what,
            setting,
            configured,
            action,
            key: crate::config::script_may_change::KEY,
        }))
    }

    /// `io.safe_value = value`: stored in the module (if it holds another), and the runner's
    /// own safe state from then on.
    pub fn change_safe_value(&mut self, value: u8) -> Result<(), DeviceError> {
        let configured = self.config.safe_value;
        if value != configured && !self.config.script_may_change.safe_value {
            return Err(self.locked(
                "safe value",
                "safe_value",
                format!("{configured:#04x}"),
                "change it",
            ));
        }
        if self.stored.safe_value != Some(value) {
            self.driver.set_safe_value(value)?;
            self.stored.safe_value = Some(value);
        }
        self.config.safe_value = value;
        Ok(())
    }

    /// `io.power_on_value = value`: stored in the module if it holds another.
    pub fn change_power_on_value(&mut self, value: u8) -> Result<(), DeviceError> {
        if let Some(configured) = self.config.power_on_value {
            if value != configured && !self.config.script_may_change.power_on_value {
                return Err(self.locked(
                    "power-on value",
                    "power_on_value",
                    format!("{configured:#04x}"),
                    "change it",
                ));
            }
        }
        if self.stored.power_on_value != Some(value) {
            self.driver.set_power_on_value(value)?;
            self.stored.power_on_value = Some(value);
        }
        self.config.power_on_value = Some(value);
        Ok(())
    }

    /// `io.watchdog(seconds)` / `io.watchdog_off()`: the host watchdog the runner keeps fed,
    /// from `now` (set on the module only if it holds another).
    pub fn change_watchdog(
        &mut self,
        wanted: Option<WatchdogTimeout>,
        now: Duration,
    ) -> Result<(), DeviceError> {
        if let (Some(configured), false) =
            (self.config.watchdog, self.config.script_may_change.watchdog)
        {
            let action = match wanted {
                None => Some("turn it off"),
                Some(t) if t > configured => Some("lengthen it"),
                Some(_) => None,
            };
            if let Some(action) = action {
                return Err(self.locked(
                    "host watchdog",
                    "watchdog",
                    format_duration(configured.as_duration()),
                    action,
                ));
            }
        }
        if let (Some(t), Some(timing)) = (wanted, &self.feed_timing) {
            check_feedable(&self.name, t, timing)?;
        }
        if self.stored.watchdog != Some(wanted) {
            self.driver
                .set_watchdog(wanted.map(WatchdogTimeout::as_duration))?;
            self.stored.watchdog = Some(wanted);
            // Setting the timeout restarts the module's countdown; an unchanged value is not
            // sent, so it feeds nothing and the feed schedule must go on as it was.
            self.last_feed = now;
        }
        self.watchdog = wanted;
        self.watchdog_ours = wanted.is_some();
        Ok(())
    }
}

fn check_feedable(
    device: &str,
    t: WatchdogTimeout,
    timing: &FeedTiming,
) -> Result<(), DeviceError> {
    let timeout = t.as_duration();
    if timing.interval(timeout).is_some() {
        return Ok(());
    }
    Err(DeviceError::Refused(Box::new(SettingRefused::TooShort {
        device: device.to_string(),
        timeout,
        reason: timing.explain(timeout),
    })))
}
