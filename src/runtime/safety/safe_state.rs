//! The end of a run (and a restart): the safe state written to every device that answers,
//! then the host watchdogs the runner turned on turned off again.

use crate::runtime::devices::Device;
use crate::runtime::state::Runtime;

impl<H: Clone> Runtime<H> {
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
                    let name = self.device_name(idx);
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

#[cfg(test)]
mod tests {
    use crate::runtime::testing::{TestRig, IO, PANEL, RIG};
    use std::time::Duration;

    #[test]
    fn the_safe_state_goes_to_every_device_that_answers() {
        let mut r = TestRig::started();
        r.rt.set_outputs(IO, 0x21);
        r.rt.set_relay(PANEL, 6);
        r.rt.flush_outputs();
        r.sim.set_gone("panel", true).unwrap();
        r.rt.tick += 1;
        r.rt.switches(PANEL);
        r.rt.write_safe_state("signal");
        assert_eq!(r.sim.outputs("io").unwrap(), 0x05);
        assert!(
            r.log().contains(
                "safe state (signal): io outputs 0x05, panel lost (its own watchdog, if on, acts)"
            ),
            "{}",
            r.log()
        );
    }

    #[test]
    fn a_module_in_safe_mode_already_holds_its_safe_value() {
        let mut r = TestRig::started();
        r.clock.advance(Duration::from_secs(2));
        r.rt.write_safe_state("end of run");
        assert!(r.rt.online(IO));
        assert!(!r.log().contains("failed"), "{}", r.log());
        assert_eq!(r.sim.outputs("io").unwrap(), 0x05);
    }

    #[test]
    fn only_the_watchdogs_the_runner_turned_on_are_turned_off() {
        let mut r = TestRig::started();
        r.rt.release_watchdogs();
        assert!(!r.sim.watchdog("io").unwrap().enabled);

        let rig = RIG.replace("watchdog = \"1s\"\n", "");
        let mut r = TestRig::new(&rig);
        let own = Some(Duration::from_secs(3));
        r.rt.c29u(IO).unwrap().driver.set_watchdog(own).unwrap();
        r.rt.start_devices().unwrap();
        assert!(r.log().contains("host watchdog 3s"), "{}", r.log());
        r.rt.release_watchdogs();
        assert!(
            r.sim.watchdog("io").unwrap().enabled,
            "the module's own stays on"
        );
    }
}
