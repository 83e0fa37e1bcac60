//! The host watchdog as `~IDWR` reports it (8-21) and what a refused output write means (8-19,
//! 8-21): one reading, used by the driver to interpret answers and by the simulator to give them.
//!
//! 8-21 answers `!IDWANN` (A = E enabled, A = D "disabled or safe mode") or a bare `!ID`. The
//! project reads them as: `WE` + NN counting; `WD00` or bare `!ID` off (no timeout set: 8-20's
//! `~IDWD` and 8-19's `~IDWE00` clear it); `WD` + NN with NN > 0 fired (a timeout still set, yet
//! not counting, so the module is in safe mode). 8-21's own example `!01WD0F` is such a module.

use crate::protocol::c29u::WatchdogTimeout;

/// The host watchdog's state as `~IDWR` tells it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum WatchdogReading {
    /// `!IDWD00`, or 8-21's bare `!ID`: no timeout set.
    Off,
    /// `!IDWE` + NN: counting down from NN x 0.1 s.
    Counting(WatchdogTimeout),
    /// `!IDWD` + NN, NN > 0: it fired; outputs hold the safe value and writes are refused.
    Fired(WatchdogTimeout),
}

impl WatchdogReading {
    /// The reading of a module whose stored timeout is `tenths` (0 = none) and that has `fired`.
    pub fn of(tenths: u8, fired: bool) -> Self {
        match WatchdogTimeout::from_tenths(tenths) {
            None => Self::Off,
            Some(t) if fired => Self::Fired(t),
            Some(t) => Self::Counting(t),
        }
    }

    /// Reads `WANN`: E/D and NN. `WE00` cannot be a counting watchdog (8-19: it disables).
    pub fn from_wire(enabled: bool, tenths: u8) -> Self {
        match (enabled, WatchdogTimeout::from_tenths(tenths)) {
            (_, None) => Self::Off,
            (true, Some(t)) => Self::Counting(t),
            (false, Some(t)) => Self::Fired(t),
        }
    }

    /// `WANN` as sent: (A = E, NN).
    pub fn to_wire(self) -> (bool, u8) {
        match self {
            Self::Off => (false, 0),
            Self::Counting(t) => (true, t.tenths()),
            Self::Fired(t) => (false, t.tenths()),
        }
    }

    /// The timeout still set, counting or fired.
    pub fn timeout(self) -> Option<WatchdogTimeout> {
        match self {
            Self::Off => None,
            Self::Counting(t) | Self::Fired(t) => Some(t),
        }
    }

    /// The module is in safe mode.
    pub fn fired(self) -> bool {
        matches!(self, Self::Fired(_))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(tenths: u8) -> WatchdogTimeout {
        WatchdogTimeout::from_tenths(tenths).unwrap()
    }

    #[test]
    fn readings_of_8_21() {
        assert_eq!(
            WatchdogReading::from_wire(true, 0x0F),
            WatchdogReading::Counting(t(15))
        );
        assert_eq!(
            WatchdogReading::from_wire(false, 0x0F),
            WatchdogReading::Fired(t(15))
        );
        assert_eq!(WatchdogReading::from_wire(false, 0), WatchdogReading::Off);
        assert_eq!(WatchdogReading::from_wire(true, 0), WatchdogReading::Off);
        assert!(WatchdogReading::Fired(t(1)).fired());
        assert!(!WatchdogReading::Off.fired());
        assert!(!WatchdogReading::Counting(t(1)).fired());
    }

    #[test]
    fn model_state_and_wire_agree() {
        for tenths in 0..=255u8 {
            for fired in [false, true] {
                let reading = WatchdogReading::of(tenths, fired);
                let (e, nn) = reading.to_wire();
                assert_eq!(WatchdogReading::from_wire(e, nn), reading);
                assert_eq!(reading.fired(), fired && tenths > 0);
                assert_eq!(reading.timeout().map_or(0, WatchdogTimeout::tenths), tenths);
            }
        }
    }
}
