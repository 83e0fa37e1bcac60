//! The safe state: written to every device that answers while the run goes on (a restart under
//! policy `restart`), and at the end of a run to every device it can reach, the lost ones
//! included, each in a bounded time, and confirmed (read back); then the host watchdogs the
//! runner turned on turned off again where it was confirmed, and never elsewhere.

use super::confirm::{confirm_safe_state, SafeDriver, SafeReading, Unconfirmed};
use crate::device::cancel::Cancel;
use crate::runtime::devices::Device;
use crate::runtime::observe::RunEvent;
use crate::runtime::state::Runtime;
use crate::time::duration::format_duration;
use std::time::Duration;

/// At the end, how many tries each device that answers gets (a lost one gets one).
pub const END_TRIES: u32 = 2;

/// How the end left one device: what the runner hands on (to whoever finishes the job where
/// it did not confirm a device's safe state).
#[derive(Debug)]
pub struct DeviceEnd {
    /// The device's name.
    pub device: String,
    /// It was lost when the end came.
    pub was_lost: bool,
    /// Its safe state, confirmed or not and why.
    pub outcome: EndOutcome,
    /// The runner turned the module's host watchdog off (only after a confirmed safe state).
    pub watchdog_released: bool,
}

/// A device's safe state at the end.
#[derive(Debug)]
pub enum EndOutcome {
    /// Written and read back.
    Confirmed(SafeReading),
    /// Not confirmed.
    Unconfirmed(Unconfirmed),
    /// Nothing to write: a TRC1000 without a safe relay.
    NoSafeState,
}

impl DeviceEnd {
    /// Whether the device still needs its safe state (the end did not confirm one it has).
    pub fn needs_safe_state(&self) -> bool {
        matches!(self.outcome, EndOutcome::Unconfirmed(_))
    }
}

impl<H: Clone> Runtime<H> {
    /// Writes the safe state of every device that answers and confirms it (a TRP-C29U's safe
    /// value read back, a TRC1000's relay confirmed by a request after it). Logs what it
    /// confirmed and why, and each device it did not.
    pub fn write_safe_state(&mut self, why: &str) {
        self.cancel_forces(why);
        let mut done = Vec::new();
        for idx in 0..self.devices.len() {
            if !self.devices.online(idx) {
                if let Some(d) = self.devices.get(idx) {
                    done.push(format!("{} lost (its own watchdog, if on, acts)", d.name()));
                }
                continue;
            }
            let Some(d) = self.devices.get_mut(idx) else {
                continue;
            };
            match confirm_device(d, false, 1) {
                EndOutcome::Confirmed(reading) => done.push(words(d.name(), reading)),
                EndOutcome::NoSafeState => {}
                // A stop cut it short: the end writes it.
                EndOutcome::Unconfirmed(Unconfirmed::NoAnswer(e)) if e.is_cancelled() => {}
                EndOutcome::Unconfirmed(u) => {
                    let name = d.name().to_string();
                    done.push(not_reached(&name, &u));
                    self.log_mut()
                        .error(&format!("{name}: the safe state did not reach it: {u}"));
                    if let Unconfirmed::NoAnswer(e) = &u {
                        self.note_failure(idx, e);
                    }
                }
            }
        }
        if !done.is_empty() {
            self.log_mut()
                .info(&format!("safe state ({why}): {}", done.join(", ")));
        }
    }

    /// The end of a run (`why`): the safe state written to every device and confirmed
    /// (`confirm::confirm_safe_state`), lost ones too (a link that failed is opened again
    /// first), each in at most `END_TRIES` tries without retries (one for a lost device), so a
    /// silent module costs a bounded time. With `release`, the host watchdogs the runner
    /// turned on are then turned off where the safe state was confirmed; where it was not,
    /// the watchdog stays on and drives the module safe. The stop that ended the run does not
    /// cut these writes: they come after it. Returns how it left each device.
    pub fn end_safe(&mut self, why: &str, release: bool) -> Vec<DeviceEnd> {
        self.cancel_forces(why);
        self.set_cancel(&Cancel::never());
        let mut done = Vec::new();
        let mut ends = Vec::new();
        for idx in 0..self.devices.len() {
            let was_lost = !self.devices.online(idx);
            let name = self.devices.name(idx);
            let outcome = self.write_safe_at_end(idx, was_lost);
            let mut watchdog_released = false;
            match &outcome {
                EndOutcome::Confirmed(reading) => {
                    let w = words(&name, *reading);
                    done.push(if was_lost {
                        format!("{w} (lost, but reached at the end)")
                    } else {
                        w
                    });
                    if let Some(d) = self.devices.get_mut(idx) {
                        d.health_mut().back();
                    }
                    // Told as any write is: the run's last word on its outputs (the MQTT
                    // client's retained state, the web page) is the safe state, not what the
                    // script drove last.
                    let value = match *reading {
                        SafeReading::Outputs(v) | SafeReading::Relay(v) => v,
                    };
                    self.events().publish(|| RunEvent::Outputs {
                        device: name.clone(),
                        value,
                        cause: format!("safe state ({why})"),
                    });
                    if release {
                        watchdog_released = self.release_watchdog(idx);
                    }
                }
                EndOutcome::NoSafeState => {}
                EndOutcome::Unconfirmed(u) => {
                    let note = self.unreached_note(idx);
                    self.log_mut().error(&format!(
                        "{name}: the safe state did not reach it: {u}; {note}"
                    ));
                    if let Unconfirmed::NoAnswer(e) = u {
                        // Lost, without the "trying again" of a run that goes on.
                        let now = self.now();
                        if let Some(d) = self.devices.get_mut(idx) {
                            d.health_mut().lose(now, e, Duration::ZERO);
                        }
                    }
                    done.push(not_reached(&name, u));
                }
            }
            ends.push(DeviceEnd {
                device: name,
                was_lost,
                outcome,
                watchdog_released,
            });
        }
        if !done.is_empty() {
            self.log_mut()
                .info(&format!("safe state ({why}): {}", done.join(", ")));
        }
        ends
    }

    /// Writes and confirms the safe state of the device at `idx` at the end.
    fn write_safe_at_end(&mut self, idx: usize, lost: bool) -> EndOutcome {
        let Some(d) = self.devices.get_mut(idx) else {
            return EndOutcome::NoSafeState;
        };
        if lost && d.health().link_failed() {
            if let Err(e) = d.reopen() {
                return EndOutcome::Unconfirmed(Unconfirmed::NoAnswer(e));
            }
        }
        confirm_device(d, true, if lost { 1 } else { END_TRIES })
    }

    /// What happens to the device at `idx` when the safe state did not reach it.
    fn unreached_note(&mut self, idx: usize) -> String {
        match self.devices.c29u(idx) {
            Some(d) => match d.watchdog() {
                Some(t) => format!(
                    "its host watchdog is left on: it drives its outputs to {:#04x} within {} \
                     (if the module acts on it)",
                    d.config().safe_value,
                    format_duration(t.as_duration())
                ),
                None => "it has no host watchdog: its outputs stay as they are".into(),
            },
            None => "the relay it holds is not known".into(),
        }
    }

    /// Turns off the host watchdog of the module at `idx` if the runner turned it on; true
    /// if it did.
    fn release_watchdog(&mut self, idx: usize) -> bool {
        let Some(d) = self.devices.c29u(idx) else {
            return false;
        };
        let ours = d.watchdog_turned_on().is_some();
        match d.release_watchdog() {
            Ok(()) => ours,
            Err(e) => {
                let name = d.name().to_string();
                self.log_mut().warn(&format!(
                    "{name}: turning its watchdog off failed: {e}; it stays on, and the \
                     outputs are safe either way"
                ));
                false
            }
        }
    }
}

/// Writes and confirms the safe state of `d`: without the driver's retries at the end
/// (`single`), in `tries` tries.
fn confirm_device(d: &mut Device, single: bool, tries: u32) -> EndOutcome {
    let result = match d {
        Device::C29u(c) => {
            let (driver, safe_value) = c.safe_driver(single);
            let result = confirm_safe_state(SafeDriver::C29u { driver, safe_value }, tries);
            // Unconfirmed, what the outputs hold is not what the runner wants: written again.
            c.note_safe_state(result.is_ok());
            result
        }
        Device::Trc(t) => {
            let Some((driver, relay)) = t.safe_driver() else {
                return EndOutcome::NoSafeState;
            };
            let result = confirm_safe_state(SafeDriver::Trc1000 { driver, relay }, tries);
            t.note_safe_state(result.is_ok());
            result
        }
    };
    match result {
        Ok(reading) => EndOutcome::Confirmed(reading),
        Err(u) => EndOutcome::Unconfirmed(u),
    }
}

/// `io outputs 0x05`, `panel relay 3`.
fn words(name: &str, reading: SafeReading) -> String {
    match reading {
        SafeReading::Outputs(v) => format!("{name} outputs {v:#04x}"),
        SafeReading::Relay(r) => format!("{name} relay {r}"),
    }
}

/// `io not reached (outputs read 0x1f)`.
fn not_reached(name: &str, u: &Unconfirmed) -> String {
    match u.read_back() {
        Some(v) => format!("{name} not reached (outputs read {v:#04x})"),
        None => format!("{name} not reached"),
    }
}

#[cfg(test)]
mod tests {
    use super::EndOutcome;
    use crate::runtime::safety::{SafeReading, Unconfirmed};
    use crate::runtime::testing::{TestRig, IO, PANEL, RIG};
    use crate::sim::c29u::OutputFault;
    use std::time::Duration;

    /// `RIG` started, with the script's outputs at 0x1F on the module.
    fn at_0x1f() -> TestRig {
        let mut r = TestRig::started();
        r.rt.set_outputs(IO, 0x1F);
        r.rt.flush_outputs();
        assert_eq!(r.sim.outputs("io").unwrap(), 0x1F);
        r
    }

    #[test]
    fn a_module_that_ignores_writes_is_not_safe_at_the_end_and_keeps_its_watchdog() {
        let mut r = at_0x1f();
        r.sim
            .set_output_fault("io", Some(OutputFault::Ignore))
            .unwrap();
        let ends = r.rt.end_safe("signal", true);
        let io = &ends[IO];
        assert!(io.needs_safe_state() && !io.watchdog_released, "{io:?}");
        assert!(
            matches!(
                io.outcome,
                EndOutcome::Unconfirmed(Unconfirmed::Ignored {
                    read: 0x1F,
                    safe: 0x05
                })
            ),
            "{io:?}"
        );
        assert!(matches!(
            ends[PANEL].outcome,
            EndOutcome::Confirmed(SafeReading::Relay(3))
        ));
        assert!(r.sim.watchdog("io").unwrap().enabled, "left on");
        let log = r.log();
        assert!(
            log.contains(
                "io: the safe state did not reach it: it acknowledged 0x05 but its outputs \
                 read 0x1f: it does not apply what it is sent; its host watchdog is left on"
            ),
            "{log}"
        );
        assert!(
            log.contains("safe state (signal): io not reached (outputs read 0x1f), panel relay 3"),
            "{log}"
        );
        assert!(!log.contains("io outputs 0x05"), "{log}");
    }

    #[test]
    fn a_module_that_refuses_writes_as_if_in_safe_mode_is_not_safe_at_the_end() {
        let mut r = at_0x1f();
        r.sim
            .set_output_fault("io", Some(OutputFault::Refuse(0xFF)))
            .unwrap();
        let ends = r.rt.end_safe("end of run", true);
        assert!(
            matches!(
                &ends[IO].outcome,
                EndOutcome::Unconfirmed(Unconfirmed::Refused { read: 0x1F, .. })
            ),
            "{:?}",
            ends[IO]
        );
        assert!(r.sim.watchdog("io").unwrap().enabled, "left on");
        let log = r.log();
        assert!(
            log.contains("io: the safe state did not reach it: it refused the write (")
                && log.contains("and its outputs read 0x1f, not 0x05"),
            "{log}"
        );
        // Its watchdog, left on and unfed, is what can still make it safe.
        r.clock.advance(Duration::from_secs(1));
        assert_eq!(r.sim.outputs("io").unwrap(), 0x05);
    }

    #[test]
    fn a_module_refusing_with_another_code_during_a_restart_is_named() {
        let mut r = at_0x1f();
        r.sim
            .set_output_fault("io", Some(OutputFault::Refuse(0x04)))
            .unwrap();
        r.rt.write_safe_state("script error");
        let log = r.log();
        assert!(
            log.contains("io: the safe state did not reach it: it refused the write (")
                && log.contains("(04)"),
            "{log}"
        );
        assert!(
            log.contains("safe state (script error): io not reached (outputs read 0x1f)"),
            "{log}"
        );
    }

    #[test]
    fn the_safe_state_goes_to_every_device_that_answers() {
        let mut r = TestRig::started();
        r.rt.set_outputs(IO, 0x21);
        r.rt.set_relay(PANEL, 6);
        r.rt.flush_outputs();
        r.sim.set_gone("panel", true).unwrap();
        r.rt.cycle.next_tick();
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
        assert!(r.rt.devices.online(IO));
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
        r.rt.devices
            .c29u(IO)
            .unwrap()
            .driver()
            .set_watchdog(own)
            .unwrap();
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
        r.rt.cycle.next_tick();
        r.rt.inputs(IO);
        assert!(!r.rt.devices.online(IO));
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
                && log.contains(
                    "its host watchdog is left on: it drives its outputs to 0x05 within 1s"
                ),
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
