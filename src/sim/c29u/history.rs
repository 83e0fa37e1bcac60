//! The simulated module's output history: every time its DO byte is set, when (virtual time),
//! to what, and why (a host write, the watchdog firing, a power on or a reset), so a test can
//! judge from the module's own record what the outputs held.
//!
//! Off by default (a `--sim` run of days would otherwise grow it); a test turns it on with a
//! capacity, and entries past the capacity are counted, not kept.

use std::time::Duration;

/// Why the module's DO byte was set.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutputCause {
    /// The host wrote the outputs (all eight, or one channel).
    HostWrite,
    /// The host watchdog fired and drove the stored safe value.
    WatchdogFired,
    /// Power came on (first power on, or unplug and replug): the stored power-on value, or
    /// the safe value while in safe mode.
    PowerOn {
        /// The module was in safe mode, so it drove its safe value.
        in_safe_mode: bool,
    },
    /// The host asked for a software reset (`$IDRS`, `46 09`), which does as a power on.
    Reset {
        /// The module was in safe mode, so it drove its safe value.
        in_safe_mode: bool,
    },
}

/// One setting of the DO byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OutputChange {
    /// When, on the model's clock (a watchdog firing at its deadline, even if noticed later).
    pub at: Duration,
    /// The DO byte before.
    pub before: u8,
    /// The DO byte after.
    pub after: u8,
    /// Why.
    pub cause: OutputCause,
}

/// The DO settings of one module, oldest first, up to a capacity.
#[derive(Debug, Clone, Default)]
pub struct OutputHistory {
    entries: Vec<OutputChange>,
    capacity: usize,
    lost: u64,
}

impl OutputHistory {
    /// A history that keeps up to `capacity` entries (0: off).
    pub fn with_capacity(capacity: usize) -> Self {
        Self {
            entries: Vec::new(),
            capacity,
            lost: 0,
        }
    }

    /// Notes one setting of the DO byte (nothing while off; counted as lost when full).
    pub fn note(&mut self, change: OutputChange) {
        if self.capacity == 0 {
            return;
        }
        if self.entries.len() < self.capacity {
            self.entries.push(change);
        } else {
            self.lost = self.lost.saturating_add(1);
        }
    }

    /// The settings kept, oldest first.
    pub fn entries(&self) -> &[OutputChange] {
        &self.entries
    }

    /// How many settings were not kept for want of room: a test that reads the history must
    /// see 0 here before it trusts it.
    pub fn lost(&self) -> u64 {
        self.lost
    }

    /// Whether the history is recording (a capacity above zero).
    pub fn is_on(&self) -> bool {
        self.capacity > 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn change(ms: u64, after: u8) -> OutputChange {
        OutputChange {
            at: Duration::from_millis(ms),
            before: 0,
            after,
            cause: OutputCause::HostWrite,
        }
    }

    #[test]
    fn keeps_up_to_its_capacity_and_counts_the_rest() {
        let mut h = OutputHistory::with_capacity(2);
        h.note(change(1, 1));
        h.note(change(2, 2));
        h.note(change(3, 3));
        assert_eq!(h.entries(), [change(1, 1), change(2, 2)]);
        assert_eq!(h.lost(), 1);
        let mut off = OutputHistory::default();
        off.note(change(1, 1));
        assert!(!off.is_on());
        assert!(off.entries().is_empty());
        assert_eq!(off.lost(), 0);
    }

    #[test]
    fn the_model_notes_writes_the_watchdog_power_cycles_and_resets_with_their_times() {
        use crate::sim::c29u::{C29uModel, Eeprom, Protocol};
        use crate::time::clock::{Clock, VirtualClock};
        use std::sync::Arc;

        let clock = VirtualClock::at_epoch();
        let eeprom = Eeprom {
            safe_value: 0x0F,
            power_on_value: 0x30,
            ..Eeprom::factory()
        };
        let mut m = C29uModel::new(Protocol::Modbus, Arc::new(clock.clone()), eeprom);
        m.record_outputs(16);
        let ms = Duration::from_millis;
        m.write_outputs(0x05).unwrap();
        m.write_output(7, true).unwrap();
        m.set_watchdog(3).unwrap();
        clock.advance(ms(1000));
        // Noticed at 1 s, fired at 0.3 s.
        assert!(m.in_safe_mode());
        m.power_cycle();
        m.set_watchdog(0).unwrap();
        m.write_outputs(0x11).unwrap();
        m.reset();
        assert_eq!(m.eeprom_rewrites(), 0);
        m.set_watchdog(0).unwrap();
        assert_eq!(m.eeprom_rewrites(), 1, "the same watchdog setting again");
        let seen: Vec<(u64, u8, u8, OutputCause)> = m
            .output_history()
            .entries()
            .iter()
            .map(|c| (c.at.as_millis() as u64, c.before, c.after, c.cause))
            .collect();
        assert_eq!(
            seen,
            [
                (0, 0x30, 0x05, OutputCause::HostWrite),
                (0, 0x05, 0x85, OutputCause::HostWrite),
                (300, 0x85, 0x0F, OutputCause::WatchdogFired),
                (
                    1000,
                    0x0F,
                    0x0F,
                    OutputCause::PowerOn { in_safe_mode: true }
                ),
                (1000, 0x0F, 0x11, OutputCause::HostWrite),
                (
                    1000,
                    0x11,
                    0x30,
                    OutputCause::Reset {
                        in_safe_mode: false
                    }
                ),
            ]
        );
        assert_eq!(m.output_history().lost(), 0);
        assert_eq!(clock.now(), ms(1000));
    }
}
