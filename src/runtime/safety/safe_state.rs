//! The safe state: written to every device that answers while the run goes on (a restart under
//! policy `restart`), and at the end of a run to every device it can reach, the lost ones
//! included, each in a bounded time; then the host watchdogs the runner turned on turned off
//! again where the safe state got through.

use crate::device::cancel::Cancel;
use crate::runtime::devices::{C29uDevice, Device, DeviceError};
use crate::runtime::state::Runtime;
use crate::time::duration::format_duration;
use std::time::Duration;

/// At the end, how many tries each device that answers gets (a lost one gets one).
pub const END_TRIES: u32 = 2;

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
                Some(Device::C29u(d)) => d.write_safe().map(|()| Some(safe_words(d))),
                Some(Device::Trc(d)) => match d.config.safe_relay {
                    Some(r) => d
                        .select_relay_confirmed(r)
                        .map(|()| Some(format!("{} relay {r}", d.name))),
                    None => Ok(None),
                },
                None => Ok(None),
            };
            match result {
                Ok(Some(s)) => done.push(s),
                Ok(None) => {}
                // A stop cut it short: the end writes it.
                Err(e) if e.is_cancelled() => {}
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

    /// The end of a run (`why`): the safe state written to every device, lost ones too (a
    /// link that failed is opened again first), each in at most `END_TRIES` tries without
    /// retries (one for a lost device), so a silent module costs a bounded time. With
    /// `release`, the host watchdogs the runner turned on are then turned off where the safe
    /// state got through; where it did not, the watchdog stays on and drives the module safe.
    /// The stop that ended the run does not cut these writes: they come after it. A write
    /// counts as reached only on an answer from the device (a TRC1000's relay selection gets
    /// none of its own: a request after it confirms it). Returns the names of the devices it
    /// did not reach.
    pub fn end_safe(&mut self, why: &str, release: bool) -> Vec<String> {
        self.set_cancel(&Cancel::never());
        let mut done = Vec::new();
        let mut unreached = Vec::new();
        for idx in 0..self.devices.len() {
            let was_lost = !self.online(idx);
            match self.write_safe_at_end(idx, was_lost) {
                Ok(Some(words)) => {
                    done.push(if was_lost {
                        format!("{words} (lost, but reached at the end)")
                    } else {
                        words
                    });
                    if let Some(d) = self.devices.get_mut(idx) {
                        d.health_mut().back();
                    }
                    if release {
                        self.release_watchdog(idx);
                    }
                }
                Ok(None) => {}
                Err(e) => {
                    let note = self.unreached_note(idx);
                    let name = self.device_name(idx);
                    self.log.error(&format!(
                        "{name}: the safe state did not reach it: {e}; {note}"
                    ));
                    // Lost, without the "trying again" of a run that goes on.
                    let now = self.now();
                    if let Some(d) = self.devices.get_mut(idx) {
                        d.health_mut().lose(now, &e, Duration::ZERO);
                    }
                    done.push(format!("{name} not reached"));
                    unreached.push(name);
                }
            }
        }
        if !done.is_empty() {
            self.log
                .info(&format!("safe state ({why}): {}", done.join(", ")));
        }
        unreached
    }

    /// Writes the safe state of the device at `idx` at the end; what was written, in words.
    fn write_safe_at_end(&mut self, idx: usize, lost: bool) -> Result<Option<String>, DeviceError> {
        let Some(d) = self.devices.get_mut(idx) else {
            return Ok(None);
        };
        if lost && d.health().link_failed {
            d.reopen()?;
        }
        let tries = if lost { 1 } else { END_TRIES };
        let mut last = None;
        for _ in 0..tries {
            let result = match &mut *d {
                Device::C29u(c) => c.write_safe_once().map(|()| Some(safe_words(c))),
                Device::Trc(t) => match t.config.safe_relay {
                    Some(r) => t
                        .select_relay_confirmed(r)
                        .map(|()| Some(format!("{} relay {r}", t.name))),
                    None => return Ok(None),
                },
            };
            match result {
                Ok(words) => return Ok(words),
                Err(e) if e.is_comm_failure() => last = Some(e),
                Err(e) => return Err(e),
            }
        }
        Err(last.unwrap_or_else(|| {
            d.health()
                .offline_error(d.name(), std::time::Duration::ZERO)
        }))
    }

    /// What happens to the device at `idx` when the safe state did not reach it.
    fn unreached_note(&mut self, idx: usize) -> String {
        match self.c29u(idx) {
            Some(d) => match d.watchdog {
                Some(t) => format!(
                    "its host watchdog, on, drives its outputs to {:#04x} within {}",
                    d.config.safe_value,
                    format_duration(t.as_duration())
                ),
                None => "it has no host watchdog: its outputs stay as they are".into(),
            },
            None => "the relay it holds is not known".into(),
        }
    }

    /// Turns off the host watchdog of the module at `idx` if the runner turned it on.
    fn release_watchdog(&mut self, idx: usize) {
        let Some(d) = self.c29u(idx) else { return };
        if let Err(e) = d.release_watchdog() {
            let name = d.name.clone();
            self.log.warn(&format!(
                "{name}: turning its watchdog off failed: {e}; it stays on, and the outputs \
                 are safe either way"
            ));
        }
    }
}

/// `io outputs 0x05`.
fn safe_words(d: &C29uDevice) -> String {
    format!("{} outputs {:#04x}", d.name, d.config.safe_value)
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
        r.rt.end_safe("end of run", true);
        assert!(!r.sim.watchdog("io").unwrap().enabled);

        let rig = RIG.replace("watchdog = \"1s\"\n", "");
        let mut r = TestRig::new(&rig);
        let own = Some(Duration::from_secs(3));
        r.rt.c29u(IO).unwrap().driver.set_watchdog(own).unwrap();
        r.rt.start_devices().unwrap();
        assert!(r.log().contains("host watchdog 3s"), "{}", r.log());
        r.rt.end_safe("end of run", true);
        assert!(
            r.sim.watchdog("io").unwrap().enabled,
            "the module's own stays on"
        );
    }

    #[test]
    fn at_the_end_a_lost_device_is_tried_once_and_gets_its_safe_state_if_it_answers() {
        let mut r = TestRig::started();
        r.rt.set_outputs(IO, 0xF1);
        r.rt.flush_outputs();
        // Lost (say while the runner tried to reconnect), and answering again by the end.
        r.sim.set_gone("io", true).unwrap();
        r.rt.tick += 1;
        r.rt.inputs(IO);
        assert!(!r.rt.online(IO));
        r.sim.set_gone("io", false).unwrap();
        r.rt.end_safe("signal", true);
        assert_eq!(r.sim.outputs("io").unwrap(), 0x05);
        assert!(!r.sim.watchdog("io").unwrap().enabled, "a clean end");
        assert!(
            r.log()
                .contains("safe state (signal): io outputs 0x05 (lost, but reached at the end)"),
            "{}",
            r.log()
        );
    }

    #[test]
    fn at_the_end_a_silent_module_costs_a_bounded_time_and_keeps_its_watchdog() {
        let mut r = TestRig::started();
        r.rt.set_outputs(IO, 0xF1);
        r.rt.flush_outputs();
        r.sim.set_gone("io", true).unwrap();
        let before = r.rt.now();
        let requests = r.requests();
        r.rt.end_safe("signal", true);
        // END_TRIES tries without retries, 100 ms each; nothing more is sent to it.
        assert_eq!(
            r.requests() - requests,
            2 + 2,
            "two to io, two to the panel (the selection and the request that confirms it)"
        );
        assert!(r.rt.now() - before < Duration::from_millis(500));
        let log = r.log();
        assert!(
            log.contains("io: the safe state did not reach it: ")
                && log.contains("its host watchdog, on, drives its outputs to 0x05 within 1s"),
            "{log}"
        );
        assert!(r.sim.watchdog("io").unwrap().enabled, "left on");
        r.clock.advance(Duration::from_secs(1));
        assert_eq!(r.sim.outputs("io").unwrap(), 0x05, "its own watchdog acted");
        assert!(
            log.contains("safe state (signal): io not reached, panel relay 3"),
            "{log}"
        );
    }
}
