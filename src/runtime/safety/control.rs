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

#[cfg(test)]
mod tests {
    use crate::runtime::testing::{TestRig, IO, PANEL, RIG};
    use std::time::Duration;

    #[test]
    fn at_start_every_device_gets_its_configured_safe_state_and_watchdog() {
        let mut r = TestRig::new(RIG);
        r.rt.start_devices().unwrap();
        assert_eq!(r.sim.safe_value("io").unwrap(), 0x05);
        assert_eq!(r.sim.power_on_value("io").unwrap(), 0x11);
        assert_eq!(r.sim.outputs("io").unwrap(), 0x05);
        let wd = r.sim.watchdog("io").unwrap();
        assert!(wd.enabled && wd.timeout_tenths == 10, "{wd:?}");
        assert_eq!(r.sim.relay("panel").unwrap(), 3);
        let log = r.log();
        assert!(
            log.contains("outputs at safe value 0x05, host watchdog 1s"),
            "{log}"
        );
        assert!(log.contains("relay at safe position 3"), "{log}");
    }

    #[test]
    fn stored_values_are_set_again_only_where_they_differ() {
        let mut r = TestRig::started();
        let io = r.rt.c29u(IO).unwrap();
        io.driver.set_safe_value(0x09).unwrap();
        io.driver.set_power_on_value(0x11).unwrap();
        assert!(r.rt.take_control(IO));
        assert_eq!(r.sim.safe_value("io").unwrap(), 0x05);
        let log = r.log();
        assert!(log.contains("io: stored safe value 0x09 -> 0x05"), "{log}");
        assert!(!log.contains("power-on value"), "{log}");
        assert!(r.rt.take_control(IO));
        assert_eq!(r.log().matches("stored").count(), 1, "{}", r.log());
    }

    #[test]
    fn a_device_that_does_not_answer_at_start_is_unavailable() {
        let mut r = TestRig::new(RIG);
        r.sim.set_gone("panel", true).unwrap();
        let e = r.rt.start_devices().unwrap_err();
        assert_eq!(e.device, "panel");
        assert!(
            e.to_string().starts_with("device panel is not available: "),
            "{e}"
        );
    }

    #[test]
    fn taking_control_again_leaves_safe_mode_and_writes_the_scripts_outputs() {
        let mut r = TestRig::started();
        r.rt.c29u(IO).unwrap().outputs = 0x60;
        r.clock.advance(Duration::from_secs(2));
        assert!(r.sim.safe_mode("io").unwrap());
        assert!(r.rt.take_control(IO));
        assert!(!r.sim.safe_mode("io").unwrap());
        assert_eq!(r.sim.outputs("io").unwrap(), 0x60);
        assert!(r.sim.watchdog("io").unwrap().enabled);
        assert!(
            r.log().contains("watchdog was turned off to leave it"),
            "{}",
            r.log()
        );
    }

    #[test]
    fn taking_control_while_held_safe_writes_the_safe_value() {
        let mut r = TestRig::started();
        r.rt.c29u(IO).unwrap().outputs = 0x60;
        r.rt.held_safe = true;
        assert!(r.rt.take_control(IO));
        assert_eq!(r.sim.outputs("io").unwrap(), 0x05);
    }

    #[test]
    fn a_panel_taken_control_of_again_gets_its_relay_at_the_next_write() {
        let mut r = TestRig::started();
        r.rt.set_relay(PANEL, 5);
        r.rt.flush_outputs();
        r.sim.power_cycle("panel").unwrap();
        assert!(r.rt.take_control(PANEL));
        r.rt.flush_outputs();
        assert_eq!(r.sim.relay("panel").unwrap(), 5);
    }

    #[test]
    fn failing_to_take_control_loses_the_device() {
        let mut r = TestRig::started();
        r.sim.set_gone("io", true).unwrap();
        assert!(!r.rt.take_control(IO));
        assert!(!r.rt.online(IO));
    }
}
