//! Taking control of a device: at start (a device that does not answer ends the run), when it
//! comes back after a loss, and when a module refused a write because its watchdog fired.

use crate::runtime::devices::{ControlNotes, Device, DeviceError, Found, Takeover};
use crate::runtime::log::Level;
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

/// The repeated-problem log key of a device's failing takeovers.
fn takeover_key(name: &str) -> String {
    format!("{name}/takeover")
}

/// The repeated-problem log key of a device found in safe mode.
fn safe_mode_key(name: &str) -> String {
    format!("{name}/safe-mode")
}

impl<H: Clone> Runtime<H> {
    /// Takes control of every device at start, in name order (see `take_control`), and logs
    /// what each is and what taking control found; a device that does not answer is
    /// unavailable and ends the start.
    pub fn start_devices(&mut self) -> Result<(), Unavailable> {
        for idx in 0..self.devices.len() {
            let name = self.devices.name(idx);
            match self.try_take_control(idx) {
                Ok(found) => {
                    for line in found {
                        self.log_mut().notice(&line);
                    }
                }
                Err(source) => {
                    return Err(Unavailable {
                        device: name,
                        source,
                    })
                }
            }
            let summary = self.describe_control(idx);
            self.log_mut().notice(&format!("{name}: {summary}"));
        }
        Ok(())
    }

    /// The device at `idx` in a few words: what it is and its safe state.
    fn describe_control(&mut self, idx: usize) -> String {
        match self.devices.get_mut(idx) {
            Some(Device::C29u(d)) => {
                let wd = match d.watchdog() {
                    Some(t) => format!("host watchdog {}", format_duration(t.as_duration())),
                    None => "no host watchdog".into(),
                };
                format!(
                    "{}, outputs at safe value {:#04x}, {wd}",
                    d.describe(),
                    d.config().safe_value
                )
            }
            Some(Device::Trc(d)) => match d.config().safe_relay {
                Some(r) => format!("{}, relay at safe position {r}", d.describe()),
                None => format!("{} (no safe relay set)", d.describe()),
            },
            None => String::new(),
        }
    }

    /// The TRP-C29U at `idx` refused a write because its watchdog has fired (the runner was
    /// too late to feed it): take control of it again as when it comes back after a loss.
    pub fn regain_control(&mut self, idx: usize) {
        let name = self.devices.name(idx);
        // Once, then counted: a module that stays in safe mode refuses every tick's write.
        self.log_mut().repeating(
            &safe_mode_key(&name),
            Level::Warn,
            &format!(
                "{name}: the module is in safe mode (its host watchdog fired: it was not fed \
                 in time); taking control again"
            ),
        );
        self.take_control(idx);
    }

    /// Puts the device at `idx` under supervision (again), after a loss or when it went
    /// safe: as `try_take_control`, with what it found logged; a failure loses the device.
    /// False if it failed.
    pub fn take_control(&mut self, idx: usize) -> bool {
        let before = self.devices.c29u(idx).and_then(|d| d.expected());
        match self.try_take_control(idx) {
            Ok(found) => {
                self.heard(idx, self.now());
                for line in found {
                    self.log_mut().notice(&line);
                }
                let name = self.devices.name(idx);
                let done = format!("{name}: taken control of");
                self.log_mut().settled(&takeover_key(&name), &done);
                self.log_mut().settled(&safe_mode_key(&name), &done);
                self.log_differences(idx, before.as_ref());
                true
            }
            Err(e) => {
                // A communication failure loses the device; a stop leaves it as it is, for
                // the end to write its safe state. A refusal is logged once, then counted:
                // a device that keeps refusing is tried again and again.
                if !e.is_comm_failure() && !e.is_cancelled() {
                    let name = self.devices.name(idx);
                    self.log_mut().repeating(
                        &takeover_key(&name),
                        Level::Error,
                        &format!("{name}: taking control failed: {e}"),
                    );
                }
                self.note_failure(idx, &e);
                false
            }
        }
    }

    /// The one way to take control of a device, at start, after a loss and out of safe mode:
    /// a TRP-C29U gets its safe and power-on values (only where they differ), its outputs
    /// (the safe value while held safe) and its watchdog, one exchange at a time with the
    /// other modules' watchdogs fed between them (`Takeover`); a TRC1000 must answer, gets
    /// its relay selected (at once where a safe relay is configured, else at the next write)
    /// and its rotaries rebased (a power cycle's reset of its counts is no turn). Returns what
    /// it found, in log lines.
    pub fn try_take_control(&mut self, idx: usize) -> Result<Vec<String>, DeviceError> {
        let held = self.safety.held();
        let forces = &self.forces;
        let mut takeover = match self.devices.get_mut(idx) {
            Some(Device::C29u(d)) => {
                Takeover::new(d.outputs_to_write(held, |v| forces.outputs(idx, v)))
            }
            Some(Device::Trc(d)) => {
                d.note_taking_control();
                d.probe()?;
                if let Some(safe) = d.config().safe_relay {
                    d.select_relay(if held {
                        safe
                    } else {
                        forces.relay(idx, d.wanted_relay())
                    })?;
                }
                return Ok(Vec::new());
            }
            None => return Ok(Vec::new()),
        };
        loop {
            self.feed_watchdogs_except(Some(idx));
            let now = self.now();
            let Some(d) = self.devices.c29u(idx) else {
                return Ok(Vec::new());
            };
            if takeover.step(d, now)? {
                break;
            }
        }
        if let (Some(v), Some(d)) = (takeover.notes().power_on_unsafe, self.devices.c29u(idx)) {
            let line = format!(
                "{}: its power-on value {v:#04x} is not its safe value {:#04x}, and rig.toml \
                 sets none: after a power cycle it drives {v:#04x} until the runner notices \
                 (the next device check, within 5s); set power_on_value in rig.toml",
                d.name(),
                d.config().safe_value
            );
            self.log_mut().warn(&line);
        }
        Ok(self.describe_findings(idx, takeover.notes()))
    }

    /// The TRP-C29U at `idx` is not the module the runner took control of (`why`: another
    /// module behind the same link, or one reset or changed behind the runner's back): taken
    /// control of as a new one (`take_control` logs what differs from the one before).
    pub fn take_control_as_new(&mut self, idx: usize, why: &str) {
        let name = self.devices.name(idx);
        self.log_mut().warn(&format!(
            "{name}: {why}; taking control of it as a new module"
        ));
        self.take_control(idx);
    }

    /// Logs how the module at `idx` just taken control of differs from the one the runner
    /// expected there (`before`): another module, or one changed behind its back.
    fn log_differences(&mut self, idx: usize, before: Option<&Found>) {
        let Some(d) = self.devices.c29u(idx) else {
            return;
        };
        let (Some(before), Some(found)) = (before, d.found()) else {
            return;
        };
        let differs = found.differences(before);
        if !differs.is_empty() {
            let line = format!(
                "{}: the module taken control of differs from the one before: {}",
                d.name(),
                differs.join(", ")
            );
            self.log_mut().warn(&line);
        }
    }

    /// What taking control of the module at `idx` found, in log lines.
    fn describe_findings(&mut self, idx: usize, notes: &ControlNotes) -> Vec<String> {
        let Some(d) = self.devices.c29u(idx) else {
            return Vec::new();
        };
        let name = &d.name();
        let mut lines = Vec::new();
        if notes.left_safe_mode {
            lines.push(format!(
                "{name}: was in safe mode (its host watchdog had fired); its watchdog was \
                 turned off to leave it"
            ));
        }
        if let Some(was) = notes.safe_value_was {
            lines.push(format!(
                "{name}: stored safe value {was:#04x} -> {:#04x}",
                d.config().safe_value
            ));
        }
        if let (Some(was), Some(v)) = (notes.power_on_value_was, d.config().power_on_value) {
            lines.push(format!(
                "{name}: stored power-on value {was:#04x} -> {v:#04x}"
            ));
        }
        if let Some(own) = notes.adopted_watchdog {
            lines.push(format!(
                "{name}: its host watchdog is on ({}) though rig.toml sets none; the runner \
                 feeds it",
                format_duration(own.as_duration())
            ));
        }
        lines
    }
}

#[cfg(test)]
mod tests {
    use crate::device::exchange::Direction;
    use crate::protocol::c29u_ascii::{decode_request, Request};
    use crate::runtime::testing::{TestRig, IO, PANEL, RIG};
    use std::sync::{Arc, Mutex};
    use std::time::Duration;

    /// `RIG`'s module in ASCII (checksums on), with the power-on value `power_on`.
    fn ascii_rig(power_on: u8) -> TestRig {
        let toml = RIG.replace(
            "safe_value = 0x05\npower_on_value = 0x11",
            &format!(
                "protocol = \"ascii\"\nchecksum = true\nsafe_value = 0x05\n\
                 power_on_value = {power_on:#04x}"
            ),
        );
        TestRig::new(&toml)
    }

    /// Every output byte the runner sends to the ASCII module from now on.
    fn output_writes(r: &mut TestRig) -> Arc<Mutex<Vec<u8>>> {
        let writes = Arc::new(Mutex::new(Vec::new()));
        let seen = Arc::clone(&writes);
        r.rt.devices
            .c29u(IO)
            .unwrap()
            .driver()
            .set_tracer(Some(Box::new(move |dir, frame| {
                if let (Direction::Sent, Ok((_, Request::WriteOutputs(v)))) =
                    (dir, decode_request(frame, true))
                {
                    seen.lock().unwrap().push(v);
                }
            })));
        writes
    }

    #[test]
    fn over_ascii_the_safe_value_is_stored_while_the_outputs_hold_it() {
        let mut r = ascii_rig(0x05);
        let writes = output_writes(&mut r);
        r.rt.start_devices().unwrap();
        assert_eq!(r.sim.safe_value("io").unwrap(), 0x05);
        assert_eq!(r.sim.power_on_value("io").unwrap(), 0x05);
        assert_eq!(r.sim.outputs("io").unwrap(), 0x05);
        let writes = writes.lock().unwrap();
        assert!(
            !writes.is_empty() && writes.iter().all(|v| *v == 0x05),
            "{writes:?}"
        );
    }

    #[test]
    fn over_ascii_a_power_on_value_that_would_pulse_the_outputs_is_refused() {
        // rig.toml refuses it first (config::device); taking control refuses it too, for a
        // configuration made some other way.
        let mut r = ascii_rig(0x05);
        r.rt.devices.c29u(IO).unwrap().config_mut().power_on_value = Some(0x11);
        let writes = output_writes(&mut r);
        let e = r.rt.start_devices().unwrap_err().to_string();
        assert!(e.contains("would drive its outputs to 0x11"), "{e}");
        assert!(
            e.contains("--protocol ascii --id 1 --checksum power-on-value 0x11 --drive-outputs"),
            "{e}"
        );
        assert_eq!(r.sim.power_on_value("io").unwrap(), 0x00);
        let writes = writes.lock().unwrap();
        assert!(writes.iter().all(|v| *v == 0x05), "{writes:?}");
    }

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
        let at_start = r.log().matches("stored").count();
        let io = r.rt.devices.c29u(IO).unwrap();
        io.driver().set_safe_value(0x09).unwrap();
        io.driver().set_power_on_value(0x11).unwrap();
        assert!(r.rt.take_control(IO));
        assert_eq!(r.sim.safe_value("io").unwrap(), 0x05);
        let log = r.log();
        assert!(log.contains("io: stored safe value 0x09 -> 0x05"), "{log}");
        assert_eq!(log.matches("stored").count(), at_start + 1, "{log}");
        assert!(r.rt.take_control(IO));
        assert_eq!(
            r.log().matches("stored").count(),
            at_start + 1,
            "{}",
            r.log()
        );
    }

    #[test]
    fn what_taking_control_at_start_finds_is_logged() {
        let rig = RIG.replace("watchdog = \"1s\"\n", "");
        let mut r = TestRig::new(&rig);
        let io = r.rt.devices.c29u(IO).unwrap();
        io.driver().set_safe_value(0x0A).unwrap();
        io.driver()
            .set_watchdog(Some(Duration::from_millis(500)))
            .unwrap();
        r.clock.advance(Duration::from_secs(1));
        assert!(r.sim.safe_mode("io").unwrap());
        r.rt.start_devices().unwrap();
        let log = r.log();
        for found in [
            "io: was in safe mode (its host watchdog had fired); its watchdog was turned off \
             to leave it",
            "io: stored safe value 0x0a -> 0x05",
            "io: stored power-on value 0x00 -> 0x11",
            "io: its host watchdog is on (500ms) though rig.toml sets none; the runner feeds it",
            "outputs at safe value 0x05, host watchdog 500ms",
        ] {
            assert!(log.contains(found), "{found}: {log}");
        }
        assert!(!r.sim.safe_mode("io").unwrap());
        assert_eq!(r.sim.outputs("io").unwrap(), 0x05);
        let wd = r.sim.watchdog("io").unwrap();
        assert!(wd.enabled && wd.timeout_tenths == 5, "{wd:?}");
    }

    #[test]
    fn the_other_watchdogs_are_fed_while_control_of_a_slow_module_is_taken() {
        // A second module that answers each request at the last moment, so taking control
        // of it takes longer than the first one's watchdog.
        let rig = format!(
            "{RIG}\n[devices.slow]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB1\"\nretries = 0\n\
             timeout = \"300ms\"\nsafe_value = 0x33\npower_on_value = 0x01\nwatchdog = \"2s\"\n"
        );
        let mut r = TestRig::new(&rig);
        r.rt.start_devices().unwrap();
        let slow = r.rt.devices.index("slow").unwrap();
        r.sim
            .set_answer_delay("slow", Duration::from_millis(290))
            .unwrap();
        r.clock.advance(Duration::from_millis(900));
        assert!(r.rt.take_control(slow));
        let took = r.rt.now() - Duration::from_millis(900);
        assert!(
            took > Duration::from_millis(1200),
            "five exchanges: {took:?}"
        );
        assert!(
            !r.sim.safe_mode("io").unwrap(),
            "io was fed between the steps"
        );
    }

    #[test]
    fn taking_control_warns_when_a_power_on_value_is_not_set_and_the_modules_is_not_safe() {
        let rig = RIG.replace("power_on_value = 0x11\n", "");
        let mut r = TestRig::new(&rig);
        r.rt.start_devices().unwrap();
        assert!(
            r.log().contains(
                "io: its power-on value 0x00 is not its safe value 0x05, and rig.toml sets none: \
                 after a power cycle it drives 0x00 until the runner notices"
            ),
            "{}",
            r.log()
        );
        let mut r = TestRig::new(&rig);
        r.rt.devices
            .c29u(IO)
            .unwrap()
            .driver()
            .set_power_on_value(0x05)
            .unwrap();
        r.rt.start_devices().unwrap();
        assert!(!r.log().contains("power-on value"), "{}", r.log());
    }

    #[test]
    fn a_different_module_back_after_a_loss_is_named_with_what_differs() {
        let mut r = TestRig::started();
        r.sim.set_gone("io", true).unwrap();
        r.rt.cycle.next_tick();
        r.rt.inputs(IO);
        assert!(!r.rt.devices.online(IO));
        let other = crate::runtime::devices::SwappedModule {
            safe_value: 0x0F,
            ..Default::default()
        };
        r.sim.swap_module("io", &other).unwrap();
        r.sim.set_gone("io", false).unwrap();
        r.clock.advance(Duration::from_secs(1));
        r.rt.supervise();
        assert!(r.rt.devices.online(IO));
        let log = r.log();
        assert!(
            log.contains("io: the module taken control of differs from the one before: ")
                && log.contains("safe value 0x0f (was 0x05)"),
            "{log}"
        );
        assert_eq!(r.sim.safe_value("io").unwrap(), 0x05);
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
        r.rt.set_outputs(IO, 0x60);
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
        r.rt.set_outputs(IO, 0x60);
        r.rt.safety.set_held(true);
        assert!(r.rt.take_control(IO));
        assert_eq!(r.sim.outputs("io").unwrap(), 0x05);
    }

    #[test]
    fn a_panel_taken_control_of_again_gets_its_relay_at_the_next_write() {
        let mut r = TestRig::started();
        r.rt.set_relay(PANEL, 5);
        r.rt.flush_outputs();
        r.sim.power_cycle("panel").unwrap();
        assert_eq!(r.sim.relay("panel").unwrap(), 0);
        // The board fell off the bus: the first try finds it gone, the next takes it back.
        assert!(!r.rt.take_control(PANEL));
        assert!(r.rt.take_control(PANEL));
        r.rt.flush_outputs();
        assert_eq!(r.sim.relay("panel").unwrap(), 5);
    }

    #[test]
    fn failing_to_take_control_loses_the_device() {
        let mut r = TestRig::started();
        r.sim.set_gone("io", true).unwrap();
        assert!(!r.rt.take_control(IO));
        assert!(!r.rt.devices.online(IO));
    }
}

#[cfg(test)]
mod refusing_tests {
    use crate::runtime::testing::{TestRig, RIG};
    use crate::sim::c29u::OutputFault;
    use crate::sim::c29u_line::lock;

    #[test]
    fn a_module_refusing_with_ff_while_its_watchdog_is_off_is_not_taken_out_of_safe_mode() {
        // Safe mode is a watchdog that fired: with the watchdog found off, an FF refusal is a
        // module refusing writes, and turning its watchdog off again would only wear its
        // EEPROM with what it holds (found by the fault search, seed 121064 case 1055).
        let toml = RIG.replace("watchdog = \"1s\"\n", "");
        let mut r = TestRig::new(&toml);
        r.sim
            .set_output_fault("io", Some(OutputFault::Refuse(0xFF)))
            .unwrap();
        let refused = match r.rt.start_devices() {
            Err(e) => e.to_string(),
            Ok(()) => panic!("the module refuses its outputs, yet it was taken control of"),
        };
        let model = r.sim.c29u("io", "eeprom").unwrap();
        assert_eq!(lock(&model).eeprom_rewrites(), 0, "{refused}");
        assert!(refused.contains("it refuses writes"), "{refused}");
    }
}
