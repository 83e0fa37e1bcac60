//! Taking control of a device: at start (a device that does not answer ends the run), when it
//! comes back after a loss, and when a module refused a write because its watchdog fired.

use crate::runtime::devices::{Device, DeviceError};
use crate::runtime::state::Runtime;
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
            let name = self.device_name(idx);
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

    /// The TRP-C29U at `idx` refused a write because its watchdog has fired (the runner was
    /// too late to feed it): take control of it again as when it comes back after a loss.
    pub fn regain_control(&mut self, idx: usize) {
        let name = self.device_name(idx);
        self.log.warn(&format!(
            "{name}: the module is in safe mode (its host watchdog fired: it was not fed in \
             time); taking control again"
        ));
        self.take_control(idx);
    }

    /// Puts the device at `idx` under supervision (again): a TRP-C29U gets its safe and
    /// power-on values, its outputs (the safe value while held safe) and its watchdog; a
    /// TRC1000 gets its relay selected again at the next write. False if it failed.
    pub fn take_control(&mut self, idx: usize) -> bool {
        let now = self.now();
        let held = self.held_safe;
        let result = match self.devices.get_mut(idx) {
            Some(Device::C29u(d)) => {
                let target = if held { d.config.safe_value } else { d.outputs };
                let name = d.name.clone();
                d.take_control(target, now).map(|notes| {
                    let mut lines = Vec::new();
                    if notes.left_safe_mode {
                        lines.push(format!(
                            "{name}: was in safe mode (its host watchdog had fired); its \
                             watchdog was turned off to leave it"
                        ));
                    }
                    if let Some(was) = notes.safe_value_was {
                        lines.push(format!(
                            "{name}: stored safe value {was:#04x} -> {:#04x}",
                            d.config.safe_value
                        ));
                    }
                    if let (Some(was), Some(v)) =
                        (notes.power_on_value_was, d.config.power_on_value)
                    {
                        lines.push(format!(
                            "{name}: stored power-on value {was:#04x} -> {v:#04x}"
                        ));
                    }
                    if let Some(own) = notes.adopted_watchdog {
                        lines.push(format!(
                            "{name}: its host watchdog is on ({}) though rig.toml sets none; \
                             the runner feeds it",
                            format_duration(own.as_duration())
                        ));
                    }
                    lines
                })
            }
            Some(Device::Trc(d)) => {
                d.relay_written = None;
                d.probe().map(|()| Vec::new())
            }
            None => Ok(Vec::new()),
        };
        match result {
            Ok(lines) => {
                for l in lines {
                    self.log.info(&l);
                }
                true
            }
            Err(e) => {
                if !e.is_comm_failure() {
                    let name = self.device_name(idx);
                    self.log
                        .error(&format!("{name}: taking control failed: {e}"));
                }
                self.note_failure(idx, &e);
                false
            }
        }
    }
}
