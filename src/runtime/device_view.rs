//! One typed reading of a device as the loop last saw it, cheap enough to make every tick (no
//! strings, `Copy`): what verify's coverage compares from tick to tick, what a violated
//! invariant reports, and what the snapshot (`runtime::snapshot`) serializes for outsiders.

use super::devices::{C29uDevice, Device, TrcDevice};
use crate::protocol::trc1000::{RotaryValues, SwitchSet};
use serde::{Deserialize, Serialize};

/// What one device showed: the last values read and the outputs the script commands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceView {
    /// A TRP-C29U module.
    C29u(ModuleView),
    /// A TRC1000 panel.
    Trc(PanelView),
}

/// A TRP-C29U as last read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ModuleView {
    /// Whether it answers.
    pub online: bool,
    /// The DI byte last read (bit n: channel n on; `None`: never read).
    pub inputs: Option<u8>,
    /// The DO byte the script commands.
    pub outputs: u8,
    /// The counters last read (`None`: the script reads none).
    pub counters: Option<[u16; 8]>,
    /// The latches last read (`None`: the script reads none).
    pub latches: Option<LatchState>,
}

/// A TRC1000 as last read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PanelView {
    /// Whether it answers.
    pub online: bool,
    /// The relay the script commands.
    pub relay: u8,
    /// The switches pressed at the last reading (`None`: never read).
    pub switches: Option<SwitchSet>,
    /// The rotaries' values at the last reading (`None`: never read).
    pub rotaries: Option<RotaryValues>,
}

/// A TRP-C29U's latched inputs, logical (bit n: DIn).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct LatchState {
    /// Channels energized since the last clear.
    pub energized: u8,
    /// Channels released since the last clear.
    pub released: u8,
}

impl DeviceView {
    /// What `device` shows now.
    pub fn of(device: &Device) -> Self {
        match device {
            Device::C29u(c) => DeviceView::C29u(ModuleView::of(c)),
            Device::Trc(t) => DeviceView::Trc(PanelView::of(t)),
        }
    }

    /// Whether the device answers.
    pub fn online(&self) -> bool {
        match self {
            DeviceView::C29u(m) => m.online,
            DeviceView::Trc(p) => p.online,
        }
    }
}

impl ModuleView {
    /// What module `c` shows now.
    pub fn of(c: &C29uDevice) -> Self {
        ModuleView {
            online: c.health().online(),
            inputs: c.inputs().current,
            outputs: c.wanted_outputs(),
            counters: c.counters().current,
            latches: c.latches().current.map(|l| LatchState {
                energized: l.energized,
                released: l.released,
            }),
        }
    }
}

impl PanelView {
    /// What panel `t` shows now.
    pub fn of(t: &TrcDevice) -> Self {
        PanelView {
            online: t.health().online(),
            relay: t.wanted_relay(),
            switches: t.switches().current,
            rotaries: t.rotaries().current,
        }
    }
}
