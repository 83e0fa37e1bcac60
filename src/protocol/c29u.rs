//! What both TRP-C29U protocols share: the protocol choice itself, the silence kept before
//! each request (the frame-gap rule), the baud rate codes (8-2), the watchdog timeout and the
//! firmware date.

use crate::link::line::FrameGap;
use serde::{Deserialize, Serialize};
use std::time::Duration;

/// Which protocol the module speaks, as chosen by its DIP switch (section 4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Protocol {
    /// TRPCOM ASCII commands (sections 6-8).
    Ascii,
    /// Modbus RTU (sections 9-10).
    Modbus,
}

/// Which input edge advances a channel's counter (8-3 bit 7).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CounterEdge {
    /// The input becomes energized (the factory default).
    Rising,
    /// The input is released.
    Falling,
}

impl std::fmt::Display for Protocol {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Ascii => "ASCII",
            Self::Modbus => "Modbus RTU",
        })
    }
}

/// Every (code, baud rate) pair of the table in 8-2.
pub const BAUD_CODES: [(u8, u32); 8] = [
    (0x03, 1200),
    (0x04, 2400),
    (0x05, 4800),
    (0x06, 9600),
    (0x07, 19200),
    (0x08, 38400),
    (0x09, 57600),
    (0x0A, 115200),
];

/// The baud rate a code stands for, if it is a valid code.
pub fn baud_rate(code: u8) -> Option<u32> {
    BAUD_CODES.iter().find(|(c, _)| *c == code).map(|(_, b)| *b)
}

/// The code for a baud rate, if the module supports that rate.
pub fn baud_code(rate: u32) -> Option<u8> {
    BAUD_CODES.iter().find(|(_, b)| *b == rate).map(|(c, _)| *c)
}

/// A valid baud rate code of 8-2: 03 = 1200 ... 0A = 115200.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct BaudCode(u8);

impl BaudCode {
    /// `Some` for codes 03..=0A.
    pub fn new(code: u8) -> Option<Self> {
        baud_rate(code).map(|_| Self(code))
    }

    /// The code for a line speed in the table, such as 9600 -> 06.
    pub fn from_baud(baud: u32) -> Option<Self> {
        baud_code(baud).map(Self)
    }

    /// The code as sent on the wire.
    pub fn code(self) -> u8 {
        self.0
    }

    /// The line speed in baud.
    pub fn baud(self) -> u32 {
        // Every BaudCode was checked against the table when it was made.
        baud_rate(self.0).unwrap_or(9600)
    }
}

/// A firmware release date as both protocols give it: `$IDF`'s trailing YYMMDD (8-15 as read)
/// and 46 07's `YY MM DD` bytes (10-5).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct FirmwareDate {
    /// Two-digit year, 0-99 (9 = 2009).
    pub year: u8,
    /// Month 1-12.
    pub month: u8,
    /// Day 1-31.
    pub day: u8,
}

/// A host watchdog timeout: 0.1 s x N, N = 1..255 (manual 8-19).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct WatchdogTimeout(u8);

impl WatchdogTimeout {
    /// The timeout for `tenths` x 0.1 s, if 1-255.
    pub fn from_tenths(tenths: u8) -> Option<Self> {
        (tenths > 0).then_some(Self(tenths))
    }

    /// The timeout equal to `d`, if it is a whole number of tenths from 0.1 s to 25.5 s.
    pub fn from_duration(d: Duration) -> Option<Self> {
        const TENTH_NS: u128 = 100_000_000;
        let nanos = d.as_nanos();
        if nanos % TENTH_NS != 0 {
            return None;
        }
        u8::try_from(nanos / TENTH_NS)
            .ok()
            .and_then(Self::from_tenths)
    }

    /// N, in units of 0.1 s, as the module takes it.
    pub fn tenths(self) -> u8 {
        self.0
    }

    /// The timeout as a duration.
    pub fn as_duration(self) -> Duration {
        Duration::from_millis(u64::from(self.0) * 100)
    }
}

/// The silence kept on a serial line at `baud` before each request to a module speaking
/// `protocol`, as `setting` says: `Fixed` is itself; `Auto` is Modbus RTU's t3.5, the silence
/// that also ends a frame (section 9; Modbus over Serial Line 2.5.1.1), and for ASCII t1.5, its
/// shape; each fixed above 19200 baud (1.75 ms, 0.75 ms). ASCII frames end at their CR, so no
/// module needs silence to find a frame's end; what a shared RS-485 pair needs is turnaround
/// (the answering module letting go of the line before the next request starts), and a
/// receiver that also frames by silence must see the request apart from the answer. Both take
/// well under 1.5 characters; t3.5 would cost a quarter of a 9600 baud poll, this a tenth.
pub fn frame_gap(protocol: Protocol, setting: FrameGap, baud: u32) -> Duration {
    let (half_chars, above_19200) = match (setting, protocol) {
        (FrameGap::Fixed(gap), _) => return gap,
        (FrameGap::Auto, Protocol::Modbus) => (7, Duration::from_micros(1_750)),
        (FrameGap::Auto, Protocol::Ascii) => (3, Duration::from_micros(750)),
    };
    if baud > 19_200 {
        return above_19200;
    }
    // Half a character of 10 bits is 5 bit times.
    Duration::from_nanos(half_chars * 5 * 1_000_000_000 / u64::from(baud.max(1)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn modbus_keeps_three_and_a_half_characters_ascii_one_and_a_half() {
        let auto = |p, baud| frame_gap(p, FrameGap::Auto, baud);
        assert_eq!(
            auto(Protocol::Ascii, 9600),
            Duration::from_micros(1562) + Duration::from_nanos(500)
        );
        assert_eq!(auto(Protocol::Ascii, 115_200), Duration::from_micros(750));
        assert_eq!(auto(Protocol::Ascii, 19_200), Duration::from_nanos(781_250));
        assert_eq!(
            auto(Protocol::Modbus, 9600),
            Duration::from_nanos(3_645_833)
        );
        assert_eq!(auto(Protocol::Modbus, 38_400), Duration::from_micros(1750));
        let five = Duration::from_millis(5);
        for p in [Protocol::Ascii, Protocol::Modbus] {
            assert_eq!(frame_gap(p, FrameGap::Fixed(five), 1200), five);
        }
    }

    #[test]
    fn table_of_8_2_both_ways() {
        assert_eq!(baud_rate(0x06), Some(9600));
        assert_eq!(baud_rate(0x0A), Some(115200));
        assert_eq!(baud_rate(0x03), Some(1200));
        assert_eq!(baud_rate(0x02), None);
        assert_eq!(baud_rate(0x0B), None);
        assert_eq!(baud_code(4800), Some(0x05));
        assert_eq!(baud_code(14400), None);
        for (code, rate) in BAUD_CODES {
            assert_eq!(baud_code(rate), Some(code));
        }
    }
}
