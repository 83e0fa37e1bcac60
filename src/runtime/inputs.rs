//! Lazy per-tick input reads: the first access in a tick reads the device, later ones reuse
//! that reading; a lost device is not asked and answers with its last reading.

use super::devices::{C29uDevice, Device, DeviceError, Snapshot, TrcDevice};
use super::state::Runtime;
use crate::device::c29u::Latches;
use crate::protocol::trc1000::{rotary_delta, Rotary, RotaryValues, SwitchSet};

/// One input of one kind of device: which devices have it, where its reading is kept and
/// how it is read.
struct Input<D, T> {
    device: fn(&mut Device) -> Option<&mut D>,
    snapshot: fn(&D) -> &Snapshot<T>,
    read: fn(&mut D, u64) -> Result<T, DeviceError>,
}

const SWITCHES: Input<TrcDevice, SwitchSet> = Input {
    device: Device::as_trc,
    snapshot: |d| &d.switches,
    read: TrcDevice::read_switches,
};

const ROTARIES: Input<TrcDevice, RotaryValues> = Input {
    device: Device::as_trc,
    snapshot: |d| &d.rotaries,
    read: TrcDevice::read_rotaries,
};

const INPUTS: Input<C29uDevice, u8> = Input {
    device: Device::as_c29u,
    snapshot: |d| &d.inputs,
    read: C29uDevice::read_inputs,
};

const COUNTERS: Input<C29uDevice, [u16; 8]> = Input {
    device: Device::as_c29u,
    snapshot: |d| &d.counters,
    read: C29uDevice::read_counters,
};

const LATCHES: Input<C29uDevice, Latches> = Input {
    device: Device::as_c29u,
    snapshot: |d| &d.latches,
    read: C29uDevice::read_latches,
};

impl<H: Clone> Runtime<H> {
    /// `input` of the device at `idx`: read at the first access in a tick while the device
    /// answers (a communication failure marks it lost); the last reading otherwise. `None`
    /// if the device has no such input or was never read.
    fn read_lazily<D, T: Copy>(&mut self, idx: usize, input: &Input<D, T>) -> Option<T> {
        let tick = self.tick;
        let online = self.online(idx);
        let d = self.devices.get_mut(idx).and_then(input.device)?;
        if online && !(input.snapshot)(d).fresh(tick) {
            if let Err(e) = (input.read)(d, tick) {
                self.note_failure(idx, &e);
            }
        }
        let d = self.devices.get_mut(idx).and_then(input.device)?;
        (input.snapshot)(d).current
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
        let tick = self.tick;
        self.trc(idx)
            .and_then(|d| d.rotaries.change_at(tick))
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
        self.read_lazily(idx, &LATCHES)
            .unwrap_or(Latches { low: 0, high: 0 })
    }
}
