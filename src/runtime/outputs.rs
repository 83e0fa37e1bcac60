//! Outputs: what the script wants (the DO byte, the relay), noted during the tick and written
//! at its end, one transaction per device, only where it changed; the safe state instead
//! while everything is held safe. The log tells changes only (a relay selected again after
//! the periodic check is not one), and a write the device keeps refusing once, then counted.
//! A refused write leaves the outputs unconfirmed: it is tried again at the next tick (the
//! loop does not sleep past it, `outputs_pending`).

use super::devices::Device;
use super::log::Level;
use super::observe::{EventKind, Events, RunEvent};
use super::state::Runtime;

impl<H: Clone> Runtime<H> {
    /// Sets the DO byte the script wants on the TRP-C29U at `idx` (written at the end of the
    /// tick).
    pub fn set_outputs(&mut self, idx: usize, value: u8) {
        let cause = self.program().cause().to_string();
        if let Some(d) = self.devices.c29u(idx) {
            d.want_outputs(value, cause);
        }
    }

    /// Sets the relay the script wants on the TRC1000 at `idx` (selected at the end of the
    /// tick).
    pub fn set_relay(&mut self, idx: usize, relay: u8) {
        let cause = self.program().cause().to_string();
        if let Some(d) = self.devices.trc(idx) {
            d.want_relay(relay, cause);
        }
    }

    /// Puts what the script wants back to the safe values (a restarted script starts from
    /// them); a TRC1000 without a safe relay keeps its relay.
    pub fn reset_outputs(&mut self) {
        for d in self.devices.iter_mut() {
            d.want_safe_state();
        }
    }

    /// Whether a device that answers still has outputs to be written (a refused write, one
    /// not yet made): the loop ticks again at the next period boundary for it.
    pub fn outputs_pending(&self) -> bool {
        let held = self.safety.held();
        let forces = &self.forces;
        self.devices.iter().enumerate().any(|(idx, d)| {
            d.health().online()
                && match d {
                    Device::C29u(c) => {
                        let target = c.outputs_to_write(held, |v| forces.outputs(idx, v));
                        c.outputs_written() != Some(target)
                    }
                    Device::Trc(t) => {
                        let target = if held {
                            t.config().safe_relay
                        } else {
                            Some(forces.relay(idx, t.wanted_relay()))
                        };
                        target.is_some() && t.relay_written() != target
                    }
                }
        })
    }

    /// Writes what changed, one transaction per device: the DO byte the script wants (the
    /// safe value while held safe, never a forced one), the relay it wants (the safe relay
    /// while held safe); an operator's force (`forcing`) over the script's otherwise.
    pub fn flush_outputs(&mut self) {
        for idx in 0..self.devices.len() {
            if !self.ready_for_exchange(idx) {
                continue;
            }
            let held = self.safety.held();
            // Built only for a watched run: writes are on the tick's path.
            let watch = self
                .events()
                .wants(EventKind::Outputs)
                .then(|| self.events().clone());
            let result = match self.devices.get_mut(idx) {
                Some(Device::Trc(d)) => {
                    let forced = self.forces.relay(idx, d.wanted_relay());
                    let target = if held {
                        d.config().safe_relay
                    } else {
                        Some(forced)
                    };
                    match target {
                        Some(relay) if d.relay_written() != Some(relay) => {
                            let before = d.relay_last();
                            let cause = match (held, d.relay_cause()) {
                                (true, _) => "held safe",
                                (false, _) if forced != d.wanted_relay() => "forced",
                                (false, "") => "start",
                                (false, cause) => cause,
                            };
                            let line = (before != Some(relay)).then(|| {
                                let named = d.config().names.name_of(&format!("relay{relay}"));
                                format!(
                                    "{}: relay {} -> {relay}{} ({cause})",
                                    d.name(),
                                    before.map_or("?".to_string(), |r| r.to_string()),
                                    named.map_or(String::new(), |n| format!(" \"{n}\"")),
                                )
                            });
                            let told = watch.map(|e| (e, d.name().to_string(), cause.to_string()));
                            d.select_relay(relay).map(|()| {
                                tell_written(told, relay);
                                line
                            })
                        }
                        _ => Ok(None),
                    }
                }
                Some(Device::C29u(d)) => {
                    let forced = self.forces.outputs(idx, d.wanted_outputs());
                    let target = if held { d.config().safe_value } else { forced };
                    if d.outputs_written() == Some(target) {
                        Ok(None)
                    } else {
                        let before = d.outputs_written();
                        let cause = match held {
                            true => "held safe",
                            false if forced != d.wanted_outputs() => "forced",
                            false => d.outputs_cause(),
                        };
                        let line = format!(
                            "{}: outputs {} -> {target:#04x}{} ({cause})",
                            d.name(),
                            before.map_or("?".to_string(), |v| format!("{v:#04x}")),
                            named_changes(&d.config().names, before, target),
                        );
                        let told = watch.map(|e| (e, d.name().to_string(), cause.to_string()));
                        d.write_outputs(target).map(|()| {
                            tell_written(told, target);
                            Some(line)
                        })
                    }
                }
                None => Ok(None),
            };
            // The key of the repeated-problem log line; built only when there is a line.
            let refusal = |name: &str| format!("{name}/write");
            match result {
                Ok(Some(line)) => {
                    self.log_mut().activity(&line);
                    let name = self.devices.name(idx);
                    self.log_mut()
                        .settled(&refusal(&name), &format!("{name}: outputs written again"));
                }
                Ok(None) => {}
                // A module that refused even with its watchdog off is not in safe mode: its
                // refusals are refusals until a write gets through.
                Err(e)
                    if e.is_safe_mode()
                        && !self.devices.c29u(idx).is_some_and(|d| d.refusing()) =>
                {
                    self.regain_control(idx);
                }
                Err(e) => {
                    if !e.is_comm_failure() && !e.is_cancelled() {
                        let name = self.devices.name(idx);
                        if let Some(d) = self.devices.c29u(idx) {
                            // Unconfirmed: what the module drives is not known.
                            d.note_refused();
                        }
                        self.log_mut().repeating(
                            &refusal(&name),
                            Level::Error,
                            &format!("{name}: writing outputs failed: {e}; trying again"),
                        );
                    }
                    self.note_failure(idx, &e);
                }
            }
        }
    }
}

/// Tells the events a write made: `told` is the device and the cause, when anyone watches.
fn tell_written(told: Option<(Events, String, String)>, value: u8) {
    if let Some((events, device, cause)) = told {
        events.publish(|| RunEvent::Outputs {
            device,
            value,
            cause,
        });
    }
}

/// The channels an output write changes, with their names, when rig.toml names any of the
/// module's outputs (`: DO0 "motor" on, DO2 off`); nothing otherwise, the byte says it all.
fn named_changes(names: &crate::config::PointNames, before: Option<u8>, after: u8) -> String {
    if !names.iter().any(|(p, _)| p.starts_with("DO")) {
        return String::new();
    }
    let changed = before.map_or(after, |b| b ^ after);
    let each: Vec<String> = (0..8u8)
        .filter(|ch| changed & (1 << ch) != 0)
        .map(|ch| {
            let on = if after & (1 << ch) != 0 { "on" } else { "off" };
            format!("{} {on}", names.shown(&format!("DO{ch}")))
        })
        .collect();
    if each.is_empty() {
        String::new()
    } else {
        format!(": {}", each.join(", "))
    }
}

#[cfg(test)]
mod tests {
    use crate::runtime::testing::{TestRig, IO, PANEL};
    use std::time::Duration;

    #[test]
    fn what_the_script_sets_is_written_once_at_flush_and_only_when_it_changed() {
        let mut r = TestRig::started();
        r.rt.set_cause("io.on_rise DI3");
        r.rt.set_outputs(IO, 0x21);
        r.rt.set_relay(PANEL, 6);
        assert_eq!(r.sim.outputs("io").unwrap(), 0x05, "not before the flush");
        assert_eq!(r.sim.relay("panel").unwrap(), 3);
        let before = r.requests();
        r.rt.flush_outputs();
        assert_eq!(r.sim.outputs("io").unwrap(), 0x21);
        assert_eq!(r.sim.relay("panel").unwrap(), 6);
        assert_eq!(r.requests(), before + 2, "one transaction per device");
        let log = r.log();
        assert!(
            log.contains("io: outputs 0x05 -> 0x21 (io.on_rise DI3)"),
            "{log}"
        );
        assert!(
            log.contains("panel: relay 3 -> 6 (io.on_rise DI3)"),
            "{log}"
        );
        r.rt.set_outputs(IO, 0x21);
        r.rt.flush_outputs();
        assert_eq!(r.requests(), before + 2, "nothing changed, nothing written");
    }

    #[test]
    fn while_held_safe_the_safe_values_are_written_instead() {
        let mut r = TestRig::started();
        r.rt.set_outputs(IO, 0xF0);
        r.rt.set_relay(PANEL, 7);
        r.rt.flush_outputs();
        r.rt.safety.set_held(true);
        r.rt.set_outputs(IO, 0xF1);
        r.rt.flush_outputs();
        assert_eq!(r.sim.outputs("io").unwrap(), 0x05);
        assert_eq!(r.sim.relay("panel").unwrap(), 3);
        assert!(
            r.log().contains("io: outputs 0xf0 -> 0x05 (held safe)"),
            "{}",
            r.log()
        );
        r.rt.safety.set_held(false);
        r.rt.flush_outputs();
        assert_eq!(
            r.sim.outputs("io").unwrap(),
            0xF1,
            "the script's outputs again"
        );
        assert_eq!(r.sim.relay("panel").unwrap(), 7);
    }

    #[test]
    fn a_write_refused_in_safe_mode_takes_control_again_with_the_scripts_outputs() {
        let mut r = TestRig::started();
        // Someone else sets a 0.1 s watchdog behind the runner's back; it fires although the
        // runner fed on time (a stall is caught before this: see upkeep).
        let io = r.rt.devices.c29u(IO).unwrap();
        io.driver()
            .set_watchdog(Some(Duration::from_millis(100)))
            .unwrap();
        r.clock.advance(Duration::from_millis(150));
        assert!(r.sim.safe_mode("io").unwrap());
        r.rt.set_outputs(IO, 0x42);
        r.rt.flush_outputs();
        assert!(!r.sim.safe_mode("io").unwrap());
        assert_eq!(r.sim.outputs("io").unwrap(), 0x42);
        assert!(
            r.sim.watchdog("io").unwrap().enabled,
            "the watchdog is on again"
        );
        assert!(r.rt.devices.online(IO));
        let log = r.log();
        assert!(log.contains("io: the module is in safe mode"), "{log}");
        assert!(log.contains("io: was in safe mode"), "{log}");
    }

    #[test]
    fn a_lost_device_is_not_written_and_its_outputs_wait() {
        let mut r = TestRig::started();
        r.sim.set_gone("io", true).unwrap();
        r.rt.set_outputs(IO, 0x33);
        r.rt.flush_outputs();
        assert!(!r.rt.devices.online(IO), "the failed write loses it");
        let before = r.requests();
        r.rt.flush_outputs();
        assert_eq!(r.requests(), before, "a lost device is not written");
        assert_eq!(
            r.rt.devices.c29u(IO).unwrap().wanted_outputs(),
            0x33,
            "what the script wants is kept"
        );
    }

    #[test]
    fn reset_outputs_goes_back_to_the_safe_values() {
        let mut r = TestRig::started();
        r.rt.set_outputs(IO, 0x77);
        r.rt.set_relay(PANEL, 1);
        r.rt.reset_outputs();
        assert_eq!(r.rt.devices.c29u(IO).unwrap().wanted_outputs(), 0x05);
        assert_eq!(r.rt.devices.trc(PANEL).unwrap().wanted_relay(), 3);
    }

    #[test]
    fn a_relay_selected_again_after_the_check_is_not_logged_again() {
        let mut r = TestRig::started();
        r.rt.flush_outputs();
        let lines = r.rt.log_lines().len();
        for _ in 0..10 {
            // What the periodic check does: the board may have forgotten its relay.
            r.rt.devices.trc(PANEL).unwrap().forget_relay_written();
            let before = r.requests();
            r.rt.flush_outputs();
            assert_eq!(r.requests(), before + 1, "selected again");
        }
        assert_eq!(r.rt.log_lines().len(), lines, "{}", r.log());
        r.rt.set_relay(PANEL, 5);
        r.rt.flush_outputs();
        assert!(r.log().contains("panel: relay 3 -> 5 ("), "{}", r.log());
    }
}
