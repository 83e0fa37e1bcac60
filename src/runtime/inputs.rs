//! Lazy per-tick input reads: the first access in a tick reads the device, later ones reuse
//! that reading; a lost device is not asked and answers with its last reading.

use super::devices::{C29uDevice, Device, DeviceError, Snapshot, TrcDevice};
use super::observe::{EventKind, Reading, RunEvent};
use super::state::Runtime;
use crate::device::c29u::Latches;
use crate::protocol::trc1000::{rotary_delta, Rotary, RotaryValues, SwitchSet};

/// One input of one kind of device: which devices have it, where its reading is kept and
/// how it is read.
struct Input<D, T> {
    device: fn(&mut Device) -> Option<&mut D>,
    snapshot: fn(&D) -> &Snapshot<T>,
    read: fn(&mut D, u64) -> Result<T, DeviceError>,
    /// The reading as an event (`None`: not told; latches).
    event: fn(&T) -> Option<Reading>,
}

const SWITCHES: Input<TrcDevice, SwitchSet> = Input {
    device: Device::as_trc,
    snapshot: |d| d.switches(),
    read: TrcDevice::read_switches,
    event: |s| {
        Some(Reading::Switches {
            pressed: s.pressed_names(),
        })
    },
};

const ROTARIES: Input<TrcDevice, RotaryValues> = Input {
    device: Device::as_trc,
    snapshot: |d| d.rotaries(),
    read: TrcDevice::read_rotaries,
    event: |r| {
        Some(Reading::Rotaries {
            values: r.to_array(),
        })
    },
};

const INPUTS: Input<C29uDevice, u8> = Input {
    device: Device::as_c29u,
    snapshot: |d| d.inputs(),
    read: C29uDevice::read_inputs,
    event: |&value| Some(Reading::DigitalInputs { value }),
};

const COUNTERS: Input<C29uDevice, [u16; 8]> = Input {
    device: Device::as_c29u,
    snapshot: |d| d.counters(),
    read: C29uDevice::read_counters,
    event: |&values| Some(Reading::Counters { values }),
};

const LATCHES: Input<C29uDevice, Latches> = Input {
    device: Device::as_c29u,
    snapshot: |d| d.latches(),
    read: C29uDevice::read_latches,
    event: |_| None,
};

impl<H: Clone> Runtime<H> {
    /// `input` of the device at `idx`: read at the first access in a tick while the device
    /// answers (a communication failure marks it lost); the last reading otherwise. `None`
    /// if the device has no such input or was never read.
    fn read_lazily<D, T: Copy + PartialEq>(
        &mut self,
        idx: usize,
        input: &Input<D, T>,
    ) -> Option<T> {
        self.devices.note_access();
        let tick = self.cycle().tick();
        let d = self.devices.get_mut(idx).and_then(input.device)?;
        if !(input.snapshot)(d).fresh(tick) && self.ready_for_exchange(idx) {
            let d = self.devices.get_mut(idx).and_then(input.device)?;
            match (input.read)(d, tick) {
                Err(e) => self.note_failure(idx, &e),
                Ok(_) => {
                    // The tick's boundary stands for now: no clock read on the read's path.
                    self.heard(
                        idx,
                        self.cycle().boundary().unwrap_or(self.cycle().started()),
                    );
                    if let Some(d) = self.devices.get_mut(idx) {
                        d.health_mut().note_read(tick);
                    }
                    self.force_readings(idx);
                    self.tell_change(idx, input);
                }
            }
        }
        let d = self.devices.get_mut(idx).and_then(input.device)?;
        (input.snapshot)(d).current
    }

    /// Tells the events a reading just made that differs from the one before.
    fn tell_change<D, T: Copy + PartialEq>(&mut self, idx: usize, input: &Input<D, T>) {
        if !self.events().wants(EventKind::Inputs) {
            return;
        }
        let Some(d) = self.devices.get_mut(idx).and_then(input.device) else {
            return;
        };
        let snapshot = (input.snapshot)(d);
        if snapshot.current == snapshot.previous {
            return;
        }
        let Some(reading) = snapshot.current.as_ref().and_then(input.event) else {
            return;
        };
        // Named only for a change: the name's allocation would cost every tick.
        let Some(device) = self.devices.get(idx).map(|d| d.name().to_string()) else {
            return;
        };
        self.events()
            .publish(|| RunEvent::Inputs { device, reading });
    }

    /// The switches of the TRC1000 at `idx` (nothing pressed before the first reading).
    pub fn switches(&mut self, idx: usize) -> SwitchSet {
        self.read_lazily(idx, &SWITCHES).unwrap_or_default()
    }

    /// The rotaries of the TRC1000 at `idx` (all 0 before the first reading).
    pub fn rotaries(&mut self, idx: usize) -> RotaryValues {
        self.read_lazily(idx, &ROTARIES).unwrap_or_default()
    }

    /// How far a rotary of the TRC1000 at `idx` moved between the last two readings, if the
    /// last one was made this tick (0 otherwise).
    pub fn turned(&mut self, idx: usize, rotary: Rotary) -> i64 {
        self.rotaries(idx);
        let tick = self.cycle().tick();
        self.devices
            .trc(idx)
            .and_then(|d| d.rotaries().change_at(tick))
            .map_or(0, |(old, new)| {
                i64::from(rotary_delta(old.get(rotary), new.get(rotary)))
            })
    }

    /// The inputs of the TRP-C29U at `idx` (bit n = DIn energized; 0 before the first
    /// reading).
    pub fn inputs(&mut self, idx: usize) -> u8 {
        self.read_lazily(idx, &INPUTS).unwrap_or(0)
    }

    /// The counters of the TRP-C29U at `idx` (all 0 before the first reading).
    pub fn counters(&mut self, idx: usize) -> [u16; 8] {
        self.read_lazily(idx, &COUNTERS).unwrap_or([0; 8])
    }

    /// The latches of the TRP-C29U at `idx` (none before the first reading).
    pub fn latches(&mut self, idx: usize) -> Latches {
        self.read_lazily(idx, &LATCHES).unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use crate::device::c29u::Latches;
    use crate::protocol::trc1000::{Rotary, Switch};
    use crate::runtime::testing::{TestRig, IO, PANEL};
    use std::time::Duration;

    const TICK: Duration = Duration::from_millis(20);

    #[test]
    fn the_first_access_in_a_tick_reads_and_later_ones_reuse_that_reading() {
        let mut r = TestRig::started();
        r.sim.set_inputs("io", 0b1000).unwrap();
        r.next_tick(TICK);
        let before = r.requests();
        assert_eq!(r.rt.inputs(IO), 0b1000);
        assert_eq!(r.requests(), before + 1);
        r.sim.set_inputs("io", 0b0100).unwrap();
        assert_eq!(r.rt.inputs(IO), 0b1000, "same tick: the snapshot");
        assert_eq!(r.requests(), before + 1);
        r.next_tick(TICK);
        assert_eq!(r.rt.inputs(IO), 0b0100, "next tick: read again");
        assert_eq!(r.requests(), before + 2);
    }

    #[test]
    fn switches_rotaries_counters_and_latches_are_read_lazily_too() {
        let mut r = TestRig::started();
        r.sim.set_switch("panel", "S2", true).unwrap();
        r.sim.turn("panel", "S41A", 3).unwrap();
        r.sim.pulse("io", 4, 7).unwrap();
        r.sim.set_input("io", 1, true).unwrap();
        r.next_tick(TICK);
        let mut cost = Vec::new();
        for _ in 0..3 {
            let before = r.requests();
            let s2 = Switch::from_name("S2").unwrap();
            assert!(r.rt.switches(PANEL).is_pressed(s2));
            let s41a = Rotary::from_name("S41A").unwrap();
            assert_eq!(r.rt.rotaries(PANEL).get(s41a), 3);
            assert_eq!(r.rt.counters(IO)[4], 7);
            assert_ne!(r.rt.latches(IO), Latches::default());
            cost.push(r.requests() - before);
        }
        assert!(cost[0] >= 4, "each read once: {cost:?}");
        assert_eq!(cost[1..], [0, 0], "then the snapshot: {cost:?}");
    }

    #[test]
    fn turned_is_the_change_made_this_tick_only() {
        let mut r = TestRig::started();
        let s41a = Rotary::from_name("S41A").unwrap();
        r.next_tick(TICK);
        assert_eq!(
            r.rt.turned(PANEL, s41a),
            0,
            "the first reading is a baseline"
        );
        r.sim.turn("panel", "S41A", -2).unwrap();
        r.next_tick(TICK);
        assert_eq!(r.rt.turned(PANEL, s41a), -2);
        r.next_tick(TICK);
        assert_eq!(r.rt.turned(PANEL, s41a), 0);
    }

    #[test]
    fn a_lost_device_answers_with_its_last_reading_and_is_not_asked() {
        let mut r = TestRig::started();
        r.sim.set_inputs("io", 0x81).unwrap();
        r.next_tick(TICK);
        assert_eq!(r.rt.inputs(IO), 0x81);
        r.sim.set_gone("io", true).unwrap();
        r.next_tick(TICK);
        assert_eq!(
            r.rt.inputs(IO),
            0x81,
            "the failed read leaves the last reading"
        );
        assert!(!r.rt.devices.online(IO));
        let before = r.requests();
        r.next_tick(TICK);
        assert_eq!(r.rt.inputs(IO), 0x81);
        assert_eq!(r.rt.counters(IO), [0; 8], "never read: nothing counted");
        assert_eq!(r.requests(), before);
    }

    #[test]
    fn inputs_a_device_does_not_have_are_empty_and_cost_nothing() {
        let mut r = TestRig::started();
        r.sim.set_inputs("io", 0xFF).unwrap();
        r.next_tick(TICK);
        let before = r.requests();
        assert_eq!(r.rt.switches(IO), Default::default());
        assert_eq!(r.rt.inputs(PANEL), 0);
        assert_eq!(r.rt.counters(9), [0; 8]);
        assert_eq!(r.rt.latches(PANEL), Latches::default());
        assert_eq!(r.requests(), before);
    }
}
