//! Checked values that requests and answers carry: channels, baud codes, formats, names.

use super::frame::is_printable;
use super::request::MODULE_TYPE;
use std::fmt;

/// Where a request goes: one module by its ID, or every module on the line (`~**`, `#**`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Address {
    /// One module, ID 00-FF.
    Id(u8),
    /// Every module; nobody answers.
    Broadcast,
}

impl fmt::Display for Address {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Address::Id(id) => write!(f, "id {id:02X}"),
            Address::Broadcast => f.write_str("broadcast"),
        }
    }
}

/// A DI or DO channel number, 0-7 (the "0-3" of 8-5 is from another model).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Channel(u8);

impl Channel {
    /// `Some` for 0..=7.
    pub fn new(n: u8) -> Option<Self> {
        (n <= 7).then_some(Self(n))
    }

    /// The channel number, 0-7.
    pub fn get(self) -> u8 {
        self.0
    }

    /// The channel as its one ASCII digit.
    pub(crate) fn digit(self) -> u8 {
        b'0' + self.0
    }

    /// Reads one ASCII digit 0-7.
    pub(crate) fn from_digit(c: u8) -> Option<Self> {
        c.checked_sub(b'0').and_then(Self::new)
    }
}

impl TryFrom<u8> for Channel {
    type Error = u8;
    fn try_from(n: u8) -> Result<Self, u8> {
        Self::new(n).ok_or(n)
    }
}

pub use crate::protocol::c29u::BaudCode;

/// The data format byte DD of `%` as 8-3 defines it (bits 5..1 must be 0).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct DataFormat {
    /// Bit 7: counters count falling edges instead of rising ones.
    pub falling_edge: bool,
    /// Bit 6: frames carry a checksum.
    pub checksum: bool,
    /// Bit 0: counters are answered as 4 hex digits ("engineer mode") instead of 5 decimal.
    pub hex_counters: bool,
}

/// Data format bit 7: counters count falling edges (8-3).
const FORMAT_FALLING: u8 = 0x80;
/// Data format bit 6: frames carry a checksum (8-3).
const FORMAT_CHECKSUM: u8 = 0x40;
/// Data format bit 0: counters answered in hex, "engineer mode" (8-3).
const FORMAT_HEX: u8 = 0x01;

impl DataFormat {
    /// The byte as sent in `%IDNNPPBBDD`.
    pub fn to_byte(self) -> u8 {
        let bit = |on: bool, bit: u8| if on { bit } else { 0 };
        bit(self.falling_edge, FORMAT_FALLING)
            | bit(self.checksum, FORMAT_CHECKSUM)
            | bit(self.hex_counters, FORMAT_HEX)
    }

    /// Reads the byte; `None` when a reserved bit (5..1) is set.
    pub fn from_byte(b: u8) -> Option<Self> {
        (b & !(FORMAT_FALLING | FORMAT_CHECKSUM | FORMAT_HEX) == 0).then_some(Self {
            falling_edge: b & FORMAT_FALLING != 0,
            checksum: b & FORMAT_CHECKSUM != 0,
            hex_counters: b & FORMAT_HEX != 0,
        })
    }
}

/// What `$ID2` reports (8-12 as read): I/O type, baud code and a format byte whose bits 2..0 are
/// the model, not the counter display mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ConfigReport {
    /// PP, the digital I/O type: 40 on this module.
    pub module_type: u8,
    /// BB, the baud code of 8-2 as sent (not checked, so an odd module still answers).
    pub baud_code: u8,
    /// DD as reported: bit 7 edge, bit 6 checksum, bits 2..0 model.
    pub format: u8,
}

impl ConfigReport {
    /// The model number in bits 2..0 for a TRP-C29U.
    pub const MODEL_C29U: u8 = 3;

    /// What a TRP-C29U with baud code `baud_code` and data format `format` reports: DD keeps the
    /// edge and checksum bits and carries the model in bits 2..0, so the hex-counter bit of 8-3
    /// is not reported (8-12: factory settings read `!01400603`).
    pub fn of_c29u(baud_code: u8, format: DataFormat) -> Self {
        Self {
            module_type: MODULE_TYPE,
            baud_code,
            format: (format.to_byte() & (FORMAT_FALLING | FORMAT_CHECKSUM)) | Self::MODEL_C29U,
        }
    }

    /// Counters count falling edges (bit 7).
    pub fn falling_edge(&self) -> bool {
        self.format & FORMAT_FALLING != 0
    }

    /// Frames carry a checksum (bit 6).
    pub fn checksum(&self) -> bool {
        self.format & FORMAT_CHECKSUM != 0
    }

    /// Bits 2..0: 0 C28, 1 C24, 2 C26, 3 C29U.
    pub fn model(&self) -> u8 {
        self.format & 0x07
    }

    /// The baud code, when it is one of 8-2's.
    pub fn baud(&self) -> Option<BaudCode> {
        BaudCode::new(self.baud_code)
    }
}

/// Which of `$IDLS`'s latches: S=0 latched low (8-9); S=1, "no use" in the manual, is read as
/// latched high like Modbus 10-17.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LatchLevel {
    /// `$IDL0`: channels whose wire level has been 0 since the last clear.
    Low,
    /// `$IDL1`: channels whose wire level has been 1 since the last clear.
    High,
}

/// The two stored output values of 8-23/8-24: `P` power-on, `S` safe (watchdog expiry).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Preset {
    /// `P`: loaded at power on and after a reset.
    PowerOn,
    /// `S`: driven when the host watchdog expires.
    Safe,
}

impl Preset {
    pub(crate) fn letter(self) -> u8 {
        match self {
            Preset::PowerOn => b'P',
            Preset::Safe => b'S',
        }
    }

    pub(crate) fn from_letter(c: u8) -> Option<Self> {
        match c {
            b'P' => Some(Preset::PowerOn),
            b'S' => Some(Preset::Safe),
            _ => None,
        }
    }
}

/// What `#**` made a module remember and `$ID4` reads back (8-25, 8-26).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub struct SynchronizedData {
    /// A = 1: the first read since the `#**`.
    pub fresh: bool,
    /// The DO byte when the `#**` arrived.
    pub outputs: u8,
    /// The DI byte when the `#**` arrived, as on the wire (energized = 0 bit: 8-11).
    pub inputs_wire: u8,
}

/// A module name (8-14, 8-17): 1 to 6 printable ASCII characters.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct ModuleName(String);

impl ModuleName {
    /// Longest name the module stores.
    pub const MAX_LEN: usize = 6;

    /// `Some` for 1..=6 printable ASCII characters (space included).
    pub fn new(name: &str) -> Option<Self> {
        Self::from_bytes(name.as_bytes())
    }

    pub(crate) fn from_bytes(b: &[u8]) -> Option<Self> {
        let ok = (1..=Self::MAX_LEN).contains(&b.len()) && b.iter().all(|c| is_printable(*c));
        ok.then(|| Self(b.iter().map(|c| char::from(*c)).collect()))
    }

    /// The name.
    pub fn as_str(&self) -> &str {
        &self.0
    }
}

impl fmt::Display for ModuleName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

pub use crate::protocol::c29u::FirmwareDate;

/// `$IDF`'s answer (8-15 as read): opaque text after the ID, and the YYMMDD date when the text
/// ends in six digits that make one (`C29M090703` -> model `C29M`, 2009-07-03).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct FirmwareVersion {
    text: String,
    date: Option<FirmwareDate>,
}

impl FirmwareVersion {
    /// `Some` for non-empty printable ASCII text.
    pub fn new(text: &str) -> Option<Self> {
        Self::from_bytes(text.as_bytes())
    }

    /// The text a module with this model and date answers, such as `C29M090703`.
    pub fn from_parts(model: &str, date: FirmwareDate) -> Option<Self> {
        Self::new(&format!(
            "{model}{:02}{:02}{:02}",
            date.year, date.month, date.day
        ))
    }

    pub(crate) fn from_bytes(b: &[u8]) -> Option<Self> {
        if b.is_empty() || !b.iter().all(|c| is_printable(*c)) {
            return None;
        }
        let text: String = b.iter().map(|c| char::from(*c)).collect();
        let date = b
            .len()
            .checked_sub(6)
            .and_then(|start| b.get(start..))
            .and_then(parse_date);
        Some(Self { text, date })
    }

    /// Everything after the ID, as the module sent it.
    pub fn text(&self) -> &str {
        &self.text
    }

    /// The trailing date, when there is one.
    pub fn date(&self) -> Option<FirmwareDate> {
        self.date
    }

    /// The text before the date (all of it when there is none).
    pub fn model(&self) -> &str {
        let cut = if self.date.is_some() {
            self.text.len().saturating_sub(6)
        } else {
            self.text.len()
        };
        self.text.get(..cut).unwrap_or(&self.text)
    }
}

fn parse_date(six: &[u8]) -> Option<FirmwareDate> {
    let two = |hi: u8, lo: u8| -> Option<u8> {
        if hi.is_ascii_digit() && lo.is_ascii_digit() {
            Some((hi - b'0') * 10 + (lo - b'0'))
        } else {
            None
        }
    };
    match six {
        [y1, y2, m1, m2, d1, d2] => {
            let date = FirmwareDate {
                year: two(*y1, *y2)?,
                month: two(*m1, *m2)?,
                day: two(*d1, *d2)?,
            };
            ((1..=12).contains(&date.month) && (1..=31).contains(&date.day)).then_some(date)
        }
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn channels_are_0_to_7() {
        assert_eq!(Channel::new(7).map(Channel::get), Some(7));
        assert_eq!(Channel::new(8), None);
        assert_eq!(Channel::from_digit(b'3'), Channel::new(3));
        assert_eq!(Channel::from_digit(b'8'), None);
        assert_eq!(Channel::from_digit(b'/'), None);
    }

    #[test]
    fn baud_codes_follow_8_2() {
        assert_eq!(BaudCode::from_baud(9600).map(BaudCode::code), Some(0x06));
        assert_eq!(BaudCode::new(0x0A).map(BaudCode::baud), Some(115_200));
        assert_eq!(BaudCode::new(0x03).map(BaudCode::baud), Some(1200));
        assert_eq!(BaudCode::new(0x02), None);
        assert_eq!(BaudCode::new(0x0B), None);
        assert_eq!(BaudCode::from_baud(14400), None);
    }

    #[test]
    fn data_format_bits_follow_8_3() {
        let f = DataFormat::from_byte(0x41).unwrap();
        assert!(f.checksum && f.hex_counters && !f.falling_edge);
        assert_eq!(f.to_byte(), 0x41);
        assert_eq!(DataFormat::from_byte(0x80).unwrap().to_byte(), 0x80);
        assert_eq!(DataFormat::from_byte(0x03), None, "bit 1 is reserved");
    }

    #[test]
    fn config_report_reads_the_model_bits() {
        let r = ConfigReport {
            module_type: 0x40,
            baud_code: 0x06,
            format: 0x43,
        };
        assert_eq!(r.model(), ConfigReport::MODEL_C29U);
        assert!(r.checksum() && !r.falling_edge());
        assert_eq!(r.baud().map(BaudCode::baud), Some(9600));
        // The module reports edge and checksum, and the model where the hex bit would be.
        let all = DataFormat::from_byte(0xC1).unwrap();
        assert_eq!(ConfigReport::of_c29u(0x06, all).format, 0xC3);
        assert_eq!(
            ConfigReport::of_c29u(0x06, DataFormat::default()).format,
            0x03
        );
        assert_eq!(ConfigReport::of_c29u(0x06, all).module_type, MODULE_TYPE);
    }

    #[test]
    fn names_are_1_to_6_printable_characters() {
        assert_eq!(ModuleName::new("ABCDE").unwrap().as_str(), "ABCDE");
        assert!(ModuleName::new("").is_none());
        assert!(ModuleName::new("ABCDEFG").is_none());
        assert!(ModuleName::new("AB\rC").is_none());
        assert!(ModuleName::new("é").is_none());
    }

    #[test]
    fn firmware_date_is_read_from_six_trailing_digits_only() {
        let f = FirmwareVersion::new("C29M090703").unwrap();
        assert_eq!(f.model(), "C29M");
        assert_eq!(
            f.date(),
            Some(FirmwareDate {
                year: 9,
                month: 7,
                day: 3
            })
        );
        // 8-15's literal answer text: no six-digit date at the end.
        let manual = FirmwareVersion::new("C29M0703").unwrap();
        assert_eq!(manual.date(), None);
        assert_eq!(manual.model(), "C29M0703");
        assert_eq!(
            FirmwareVersion::new("X991399").unwrap().date(),
            None,
            "month 13"
        );
        assert!(FirmwareVersion::new("").is_none());
        let built = FirmwareVersion::from_parts(
            "C29M",
            FirmwareDate {
                year: 9,
                month: 7,
                day: 3,
            },
        );
        assert_eq!(built, Some(f));
    }
}
