//! Keeping control while the run goes: host watchdogs fed at a quarter of their timeout, and
//! every few seconds each module checked (the one taken control of, not reset, its watchdog,
//! stored values and outputs as the runner left them) and the relays selected again.

use crate::runtime::devices::{CheckFinding, Device, ModuleCheck};
use crate::runtime::log::Level;
use crate::runtime::state::Runtime;
use crate::time::duration::format_duration;
use std::time::Duration;

impl<H: Clone> Runtime<H> {
    /// Feeds each host watchdog the runner keeps, at a quarter of its timeout.
    pub fn feed_watchdogs(&mut self) {
        self.feed_watchdogs_except(None);
    }

    /// `feed_watchdogs`, leaving out the device at `skip` (one being taken control of; then
    /// a stalled module is fed as it is, and checked at the next feed).
    pub fn feed_watchdogs_except(&mut self, skip: Option<usize>) {
        let now = self.now();
        for idx in 0..self.devices.len() {
            if !self.devices.online(idx) || skip == Some(idx) {
                continue;
            }
            let Some(d) = self.devices.c29u(idx) else {
                continue;
            };
            if let (Some(stall), None) = (d.stalled(now), skip) {
                self.after_stall(idx, stall);
                continue;
            }
            match d.feed(now) {
                Ok(true) => self.heard(idx, now),
                Ok(false) => {}
                Err(e) => self.note_failure(idx, &e),
            }
        }
    }

    /// The module at `idx` was not fed for `stall`, longer than its watchdog's timeout (the
    /// runner stalled: a paused VM, a stopped process, a blocked exchange): its watchdog has
    /// fired if it kept time as the runner did. Neither protocol reports that reliably, so the
    /// outputs the runner wants are written: a module in safe mode refuses, and is taken
    /// control of again at once, with the cause in the log; one that takes them is fed.
    fn after_stall(&mut self, idx: usize, stall: Duration) {
        let held = self.safety.held();
        let now = self.now();
        let forces = &self.forces;
        let Some(Device::C29u(d)) = self.devices.get_mut(idx) else {
            return;
        };
        let target = d.outputs_to_write(held, |v| forces.outputs(idx, v));
        let result = d.write_outputs(target).and_then(|()| d.feed(now));
        match result {
            Ok(_) => {}
            Err(e) if e.is_safe_mode() => {
                let timeout = d.watchdog().map_or(stall, |t| t.as_duration());
                let (name, safe) = (d.name().to_string(), d.config().safe_value);
                self.log_mut().warn(&format!(
                    "{name}: host watchdog fired after a {} stall (not fed for that long, its \
                     timeout is {}): its outputs went to the safe value {safe:#04x}; taking \
                     control again",
                    format_duration(stall),
                    format_duration(timeout)
                ));
                self.take_control(idx);
            }
            Err(e) => self.note_failure(idx, &e),
        }
    }

    /// When the next watchdog feed is due (`None`: nothing to feed). The scan loop wakes for
    /// it between ticks.
    pub fn next_feed(&self) -> Option<Duration> {
        self.devices
            .iter()
            .filter_map(|d| match d {
                Device::C29u(c) => c.next_feed(),
                Device::Trc(_) => None,
            })
            .min()
    }

    /// Checks each device, run every few seconds: a module is still the one taken control
    /// of, not reset, its watchdog and stored values as the runner left them, and its outputs
    /// what was written (`devices::ModuleCheck`: four requests, one a step with the other
    /// watchdogs fed between them); a module that is not is taken control of as a new one.
    /// Each relay is selected again (a board that was unplugged forgets it), confirmed by a
    /// request after it.
    pub fn check_devices(&mut self) {
        for idx in 0..self.devices.len() {
            if !self.ready_for_exchange(idx) {
                continue;
            }
            let result = match self.devices.get_mut(idx) {
                Some(Device::C29u(_)) => {
                    self.check_module(idx);
                    continue;
                }
                // A selection gets no answer, so a script that only writes the relay would
                // never learn that the board stopped answering: the check selects the relay
                // again (a board reset behind the runner's back gets it back) and confirms it
                // with a request after it.
                Some(Device::Trc(d)) => match d.relay_written() {
                    Some(relay) => d.select_relay_confirmed(relay),
                    None => Ok(()),
                },
                None => Ok(()),
            };
            if let Err(e) = result {
                self.note_failure(idx, &e);
            }
        }
    }

    /// The periodic check of the TRP-C29U at `idx` (see `check_devices`).
    fn check_module(&mut self, idx: usize) {
        let mut check = ModuleCheck::new();
        let finding = loop {
            if !self.ready_for_exchange(idx) {
                return;
            }
            let Some(d) = self.devices.c29u(idx) else {
                return;
            };
            match check.step(d) {
                Ok(Some(finding)) => break finding,
                Ok(None) => {}
                Err(e) => {
                    self.note_failure(idx, &e);
                    return;
                }
            }
        };
        let name = self.devices.name(idx);
        let key = format!("{name}/read-back");
        match finding {
            CheckFinding::Same => self
                .log_mut()
                .settled(&key, &format!("{name}: outputs as written")),
            CheckFinding::Outputs { read, written } => {
                if let Some(d) = self.devices.c29u(idx) {
                    d.forget_outputs_written();
                }
                self.log_mut().repeating(
                    &key,
                    Level::Warn,
                    &format!(
                        "{name}: outputs read {read:#04x} but {written:#04x} was written (someone \
                         else writes them, or the module does not apply what it is sent); \
                         writing them again"
                    ),
                );
            }
            CheckFinding::Reset => self.take_control_as_new(
                idx,
                "reset or power cycled behind the runner's back (its reset flag is set)",
            ),
            CheckFinding::Differs {
                what,
                read,
                expected,
            } => self.take_control_as_new(
                idx,
                &format!(
                    "its {what} reads {read}, not {expected}: another module answers on its \
                     line, or someone changed it"
                ),
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::runtime::devices::SwappedModule;
    use crate::runtime::testing::{TestRig, IO, PANEL};
    use crate::sim::c29u::OutputFault;
    use std::time::Duration;

    const TICK: Duration = Duration::from_millis(20);

    #[test]
    fn host_watchdogs_are_fed_at_their_interval() {
        let mut r = TestRig::started();
        // The rig's 1 s watchdog: a feed may be 778 ms late (config::feeding), so every
        // 221.7 ms rather than every quarter.
        let interval = r.rt.devices.c29u(IO).unwrap().feed_interval().unwrap();
        assert_eq!(interval.as_micros(), 221_666);
        let before = r.requests();
        for _ in 0..500 {
            r.next_tick(TICK);
            r.rt.feed_watchdogs();
        }
        assert!(!r.sim.safe_mode("io").unwrap(), "10 s fed, never expired");
        // At the first tick at least 221.7 ms after the last feed: every 240 ms at 20 ms ticks.
        assert_eq!(r.requests() - before, 10_000 / 240);
    }

    #[test]
    fn next_feed_and_next_retry() {
        let mut r = TestRig::started();
        let interval = r.rt.devices.c29u(IO).unwrap().feed_interval().unwrap();
        assert_eq!(r.rt.next_feed(), Some(interval));
        assert_eq!(r.rt.next_retry(), None);
        r.sim.set_gone("panel", true).unwrap();
        r.clock.advance(Duration::from_millis(100));
        r.rt.switches(PANEL);
        let lost_at = r.rt.now();
        assert_eq!(r.rt.next_retry(), Some(lost_at + Duration::from_secs(1)));
        assert_eq!(r.rt.next_feed(), Some(interval));
        r.sim.set_gone("io", true).unwrap();
        r.next_tick(TICK);
        r.rt.inputs(IO);
        assert_eq!(r.rt.next_feed(), None, "a lost module is not fed");
    }

    #[test]
    fn a_feed_due_before_an_exchange_is_sent_first() {
        let mut r = TestRig::started();
        r.clock.advance(Duration::from_millis(900));
        assert!(!r.sim.safe_mode("io").unwrap());
        // A slow panel read (any exchange) would let the module's 1 s watchdog fire, but the
        // feed that fell due goes out before it.
        r.sim
            .set_answer_delay("panel", Duration::from_millis(300))
            .unwrap();
        r.next_tick(TICK);
        r.rt.switches(PANEL);
        assert!(r.rt.now() > Duration::from_millis(1200));
        assert!(!r.sim.safe_mode("io").unwrap());
    }

    #[test]
    fn a_module_reset_behind_the_runners_back_is_taken_control_of_as_a_new_one() {
        let mut r = TestRig::started();
        r.rt.set_outputs(IO, 0x21);
        r.rt.flush_outputs();
        r.sim.power_cycle("io").unwrap();
        assert_eq!(r.sim.outputs("io").unwrap(), 0x11, "the power-on value");
        r.rt.check_devices();
        assert!(
            r.log().contains(
                "io: reset or power cycled behind the runner's back (its reset flag is set); \
                 taking control of it as a new module"
            ),
            "{}",
            r.log()
        );
        assert_eq!(
            r.sim.outputs("io").unwrap(),
            0x21,
            "the script's outputs at once"
        );
        assert!(r.sim.watchdog("io").unwrap().enabled);
    }

    #[test]
    fn outputs_that_do_not_read_as_written_are_written_again_and_the_line_is_not_repeated() {
        let mut r = TestRig::started();
        r.rt.set_outputs(IO, 0x21);
        r.rt.flush_outputs();
        r.sim
            .set_output_fault("io", Some(OutputFault::Ignore))
            .unwrap();
        r.rt.set_outputs(IO, 0x0F);
        r.rt.flush_outputs();
        for _ in 0..3 {
            r.rt.check_devices();
            r.rt.flush_outputs();
        }
        let log = r.log();
        assert_eq!(
            log.matches("io: outputs read 0x21 but 0x0f was written")
                .count(),
            1,
            "{log}"
        );
        r.sim.set_output_fault("io", None).unwrap();
        r.rt.check_devices();
        r.rt.flush_outputs();
        assert_eq!(r.sim.outputs("io").unwrap(), 0x0F);
    }

    #[test]
    fn a_check_costs_four_requests() {
        let mut r = TestRig::started();
        let before = r.requests();
        r.rt.check_devices();
        assert_eq!(
            r.requests() - before,
            4 + 2,
            "the module: reset flag, outputs, watchdog, one item in turn; the panel: the \
             selection and the request that confirms it"
        );
    }

    #[test]
    fn a_different_module_behind_the_same_link_is_taken_control_of_as_a_new_one() {
        let mut r = TestRig::started();
        r.rt.set_outputs(IO, 0x21);
        r.rt.flush_outputs();
        let other = SwappedModule {
            name: "OTHER".into(),
            safe_value: 0xFF,
            power_on_value: 0x00,
            watchdog_tenths: 0,
            ..SwappedModule::default()
        };
        r.sim.swap_module("io", &other).unwrap();
        r.rt.check_devices();
        let log = r.log();
        assert!(
            log.contains("io: the module taken control of differs from the one before: ")
                && log.contains("firmware 140901 (was 090703)")
                && log.contains("host watchdog off (was 1s)")
                && log.contains("safe value 0xff (was 0x05)")
                && log.contains("power-on value 0x00 (was 0x11)"),
            "{log}"
        );
        assert_eq!(r.sim.safe_value("io").unwrap(), 0x05, "rewritten");
        assert_eq!(r.sim.power_on_value("io").unwrap(), 0x11);
        assert!(r.sim.watchdog("io").unwrap().enabled);
        assert_eq!(r.sim.outputs("io").unwrap(), 0x21);
    }

    #[test]
    fn a_watchdog_turned_off_behind_the_runners_back_is_noticed_at_the_next_check() {
        let mut r = TestRig::started();
        // Another master on the line turns it off; no reset, outputs untouched.
        let model = r.sim.c29u("io", "test").unwrap();
        crate::sim::c29u_line::lock(&model).set_watchdog(0).unwrap();
        r.rt.check_devices();
        assert!(
            r.log().contains(
                "io: its host watchdog reads off, not 1s: another module answers on its line, \
                 or someone changed it; taking control of it as a new module"
            ),
            "{}",
            r.log()
        );
        assert!(r.sim.watchdog("io").unwrap().enabled);
    }

    #[test]
    fn a_stored_value_changed_behind_the_runners_back_is_noticed_within_four_checks() {
        let mut r = TestRig::started();
        let model = r.sim.c29u("io", "test").unwrap();
        crate::sim::c29u_line::lock(&model)
            .set_power_on_value(0xFF)
            .unwrap();
        for _ in 0..4 {
            r.rt.check_devices();
        }
        assert!(
            r.log()
                .contains("io: its power-on value reads 0xff, not 0x11"),
            "{}",
            r.log()
        );
        assert_eq!(r.sim.power_on_value("io").unwrap(), 0x11, "rewritten");
    }

    #[test]
    fn the_scripts_own_reset_is_no_news() {
        let mut r = TestRig::started();
        let io = r.rt.devices.c29u(IO).unwrap();
        io.reset_module().unwrap();
        r.rt.check_devices();
        assert!(!r.log().contains("reset or power cycled"), "{}", r.log());
    }

    #[test]
    fn relays_are_selected_again_at_each_check() {
        let mut r = TestRig::started();
        r.rt.set_relay(PANEL, 4);
        r.rt.flush_outputs();
        r.sim.power_cycle("panel").unwrap();
        assert_ne!(r.sim.relay("panel").unwrap(), 4);
        r.rt.check_devices();
        r.rt.flush_outputs();
        assert_eq!(r.sim.relay("panel").unwrap(), 4);
    }

    #[test]
    fn after_a_stall_longer_than_the_watchdog_the_module_is_taken_control_of_at_once() {
        let mut r = TestRig::started();
        r.rt.set_outputs(IO, 0x60);
        r.rt.flush_outputs();
        // The runner stalls (a paused VM, a stopped process): nothing is fed for 1.2 s.
        r.clock.advance(Duration::from_millis(1200));
        assert!(r.sim.safe_mode("io").unwrap(), "its 1 s watchdog fired");
        assert_eq!(r.sim.outputs("io").unwrap(), 0x05);
        // The first feed opportunity after the stall notices it.
        r.next_tick(TICK);
        r.rt.feed_watchdogs();
        assert!(!r.sim.safe_mode("io").unwrap());
        assert_eq!(
            r.sim.outputs("io").unwrap(),
            0x60,
            "the script's outputs at once"
        );
        let log = r.log();
        assert!(
            log.contains(
                "io: host watchdog fired after a 1.22s stall (not fed for that long, its \
                 timeout is 1s): its outputs went to the safe value 0x05; taking control again"
            ),
            "{log}"
        );
        assert!(!log.contains("power cycled"), "{log}");
    }

    #[test]
    fn a_feed_that_is_late_but_in_time_is_just_a_feed() {
        let mut r = TestRig::started();
        r.clock.advance(Duration::from_millis(900));
        let before = r.requests();
        r.rt.feed_watchdogs();
        assert_eq!(r.requests() - before, 1, "one host OK, no check");
        assert!(!r.log().contains("stall"), "{}", r.log());
    }
}
