//! TRC1000 wire codec: 8-byte commands and responses, switch and rotary names
//! (docs/trc1000-protocol.md).
//!
//! Pure: bytes in, typed values out, and back. No clocks, no I/O.

use std::fmt;

/// Every TRC1000 packet is this many bytes, both ways.
pub const PACKET_LEN: usize = 8;

/// One 8-byte interrupt packet.
pub type Packet = [u8; PACKET_LEN];

/// First byte of a "select relay" command.
pub const CMD_SELECT_RELAY: u8 = 0x05;
/// First byte of a "request input" command.
pub const CMD_REQUEST_INPUT: u8 = 0x41;
/// First byte of a "request rotary0" command.
pub const CMD_REQUEST_ROTARY0: u8 = 0x42;
/// First byte of a "request rotary1" command.
pub const CMD_REQUEST_ROTARY1: u8 = 0x43;
/// First byte of a "respond input" packet.
pub const RESP_INPUT: u8 = 0xC1;
/// First byte of a "respond rotary0" packet.
pub const RESP_ROTARY0: u8 = 0xC2;
/// First byte of a "respond rotary1" packet.
pub const RESP_ROTARY1: u8 = 0xC3;

/// Why bytes could not be read as a TRC1000 command or response.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// The slice holds fewer bytes than the packet type carries.
    #[error("TRC1000 packet too short: {got} bytes, need {needed}")]
    Short {
        /// Bytes the packet type carries.
        needed: usize,
        /// Bytes there were.
        got: usize,
    },
    /// The first byte is not a known command.
    #[error("unknown TRC1000 command byte 0x{0:02X}")]
    UnknownCommand(u8),
    /// The first byte is not a known response.
    #[error("unknown TRC1000 response byte 0x{0:02X}")]
    UnknownResponse(u8),
}

/// A relay position outside 0..=7.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("relay {0} does not exist: the TRC1000 selects relays 0-7")]
pub struct InvalidRelay(pub u8);

/// A relay position 0..=7 (the board selects exactly one at a time).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub struct Relay(u8);

impl Relay {
    /// The relay numbered `n`, if `n` is 0..=7.
    pub fn new(n: u8) -> Result<Self, InvalidRelay> {
        if n <= 7 {
            Ok(Self(n))
        } else {
            Err(InvalidRelay(n))
        }
    }

    /// The relay number, 0..=7.
    pub fn number(self) -> u8 {
        self.0
    }
}

impl fmt::Display for Relay {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// A command from the PC to the board (OUT endpoint 1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Command {
    /// `05 nn`: select a relay; no response.
    SelectRelay(Relay),
    /// `41`: ask for the switch states (answered by `C1`).
    RequestInput,
    /// `42`: ask for rotaries S41A..S44A (answered by `C2`).
    RequestRotary0,
    /// `43`: ask for rotaries S44B..S40 (answered by `C3`).
    RequestRotary1,
}

impl Command {
    /// The packet on the wire; unused bytes are zero.
    pub fn encode(&self) -> Packet {
        let mut p = [0u8; PACKET_LEN];
        match self {
            Command::SelectRelay(relay) => {
                p[0] = CMD_SELECT_RELAY;
                // Relay number in bits 4..2; the others are don't-care, sent as zero.
                p[1] = relay.number() << 2;
            }
            Command::RequestInput => p[0] = CMD_REQUEST_INPUT,
            Command::RequestRotary0 => p[0] = CMD_REQUEST_ROTARY0,
            Command::RequestRotary1 => p[0] = CMD_REQUEST_ROTARY1,
        }
        p
    }

    /// Reads a command packet (the board's side); don't-care bits and unused bytes are ignored.
    pub fn decode(packet: &Packet) -> Result<Self, DecodeError> {
        match packet {
            [CMD_SELECT_RELAY, nn, ..] => Ok(Command::SelectRelay(Relay((nn >> 2) & 0x07))),
            [CMD_REQUEST_INPUT, ..] => Ok(Command::RequestInput),
            [CMD_REQUEST_ROTARY0, ..] => Ok(Command::RequestRotary0),
            [CMD_REQUEST_ROTARY1, ..] => Ok(Command::RequestRotary1),
            [other, ..] => Err(DecodeError::UnknownCommand(*other)),
        }
    }

    /// The first byte of the response this command expects, if it gets one.
    pub fn response_code(&self) -> Option<u8> {
        match self {
            Command::SelectRelay(_) => None,
            Command::RequestInput => Some(RESP_INPUT),
            Command::RequestRotary0 => Some(RESP_ROTARY0),
            Command::RequestRotary1 => Some(RESP_ROTARY1),
        }
    }

    /// The command in words for messages, such as `request input (41)`.
    pub fn describe(&self) -> String {
        match self {
            Command::SelectRelay(r) => format!("select relay {r} (05)"),
            Command::RequestInput => "request input (41)".to_string(),
            Command::RequestRotary0 => "request rotary0 (42)".to_string(),
            Command::RequestRotary1 => "request rotary1 (43)".to_string(),
        }
    }
}

/// Switch numbers by (data byte b0..b5, bit 0..7); 0 marks an unused bit
/// (docs/trc1000-protocol.md, 'Answers').
const LAYOUT: [[u8; 8]; 6] = [
    [1, 2, 3, 4, 5, 6, 7, 8],
    [9, 10, 11, 12, 13, 14, 15, 16],
    [17, 18, 19, 20, 21, 22, 23, 24],
    [25, 26, 31, 32, 33, 34, 35, 36],
    [41, 42, 43, 44, 45, 37, 39, 38],
    [40, 27, 28, 29, 30, 0, 0, 0],
];

/// Bits of the last data byte (b5) that carry switches.
const B5_USED: u8 = 0b0001_1111;

const SWITCH_NAMES: [&str; 45] = [
    "S1", "S2", "S3", "S4", "S5", "S6", "S7", "S8", "S9", "S10", "S11", "S12", "S13", "S14", "S15",
    "S16", "S17", "S18", "S19", "S20", "S21", "S22", "S23", "S24", "S25", "S26", "S27", "S28",
    "S29", "S30", "S31", "S32", "S33", "S34", "S35", "S36", "S37", "S38", "S39", "S40", "S41",
    "S42", "S43", "S44", "S45",
];

/// One of the 45 panel switches S1..S45.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Switch(u8);

impl Switch {
    /// Number of switches on the board.
    pub const COUNT: usize = 45;

    /// Switch `S<n>`, if `n` is 1..=45.
    pub fn new(n: u8) -> Option<Self> {
        (1..=45).contains(&n).then_some(Self(n))
    }

    /// All switches in S-number order.
    pub fn all() -> impl Iterator<Item = Switch> {
        (1..=45).map(Switch)
    }

    /// The switch number, 1..=45.
    pub fn number(self) -> u8 {
        self.0
    }

    /// The switch name, such as `S17`.
    pub fn name(self) -> &'static str {
        SWITCH_NAMES
            .get(usize::from(self.0).wrapping_sub(1))
            .copied()
            .unwrap_or("S?")
    }

    /// The switch called `name` (case-insensitive, such as `s17`), if there is one.
    pub fn from_name(name: &str) -> Option<Self> {
        let digits = name.strip_prefix('S').or_else(|| name.strip_prefix('s'))?;
        // Only plain decimal digits: `S+3` or `S03` are not switch names.
        if digits.is_empty()
            || digits.starts_with('0')
            || !digits.bytes().all(|b| b.is_ascii_digit())
        {
            return None;
        }
        digits.parse::<u8>().ok().and_then(Switch::new)
    }

    /// Where the switch sits in a `C1` answer: (data byte 0..=5 = b0..b5, bit 0..=7).
    /// The packet offset is the data byte + 1.
    pub fn position(self) -> (usize, u8) {
        for (byte, bits) in LAYOUT.iter().enumerate() {
            for (bit, n) in (0u8..).zip(bits.iter()) {
                if *n == self.0 {
                    return (byte, bit);
                }
            }
        }
        // Unreachable for a constructed Switch: every number 1..=45 is in LAYOUT (tested).
        (0, 0)
    }
}

impl fmt::Display for Switch {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The states of all 45 switches (a set bit = pressed), as carried by a `C1` answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct SwitchSet([u8; 6]);

impl SwitchSet {
    /// No switch pressed.
    pub fn new() -> Self {
        Self::default()
    }

    /// From the six data bytes b0..b5 of a `C1` answer; the unused bits of b5 are dropped.
    pub fn from_bytes(bytes: [u8; 6]) -> Self {
        let mut b = bytes;
        b[5] &= B5_USED;
        Self(b)
    }

    /// The six data bytes b0..b5 as sent in a `C1` answer.
    pub fn bytes(&self) -> [u8; 6] {
        self.0
    }

    /// Whether `switch` is pressed.
    pub fn is_pressed(&self, switch: Switch) -> bool {
        let (byte, bit) = switch.position();
        self.0.get(byte).is_some_and(|b| b & (1 << bit) != 0)
    }

    /// Marks `switch` pressed or released.
    pub fn set(&mut self, switch: Switch, pressed: bool) {
        let (byte, bit) = switch.position();
        if let Some(b) = self.0.get_mut(byte) {
            if pressed {
                *b |= 1 << bit;
            } else {
                *b &= !(1 << bit);
            }
        }
    }

    /// The pressed switches in S-number order.
    pub fn pressed(&self) -> Vec<Switch> {
        Switch::all().filter(|s| self.is_pressed(*s)).collect()
    }

    /// The names of the pressed switches in S-number order.
    pub fn pressed_names(&self) -> Vec<&'static str> {
        self.pressed().into_iter().map(Switch::name).collect()
    }

    /// Switches pressed in `newer` but not here, and switches released in `newer`, each in
    /// S-number order.
    pub fn changes(&self, newer: &SwitchSet) -> (Vec<Switch>, Vec<Switch>) {
        let mut pressed = Vec::new();
        let mut released = Vec::new();
        // Most readings are the last one again: no need to look at each of the 45.
        if self == newer {
            return (pressed, released);
        }
        for s in Switch::all() {
            match (self.is_pressed(s), newer.is_pressed(s)) {
                (false, true) => pressed.push(s),
                (true, false) => released.push(s),
                _ => {}
            }
        }
        (pressed, released)
    }
}

/// Which response packet carries a rotary.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RotaryPacket {
    /// `C2`, answer to `42`.
    Rotary0,
    /// `C3`, answer to `43`.
    Rotary1,
}

/// One of the 14 rotary encoders, in wire order (C2 bytes 1..7, then C3 bytes 1..7).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Rotary {
    /// The encoder marked S41A on the board.
    S41A,
    /// The encoder marked S41B on the board.
    S41B,
    /// The encoder marked S42A on the board.
    S42A,
    /// The encoder marked S42B on the board.
    S42B,
    /// The encoder marked S43A on the board.
    S43A,
    /// The encoder marked S43B on the board.
    S43B,
    /// The encoder marked S44A on the board.
    S44A,
    /// The encoder marked S44B on the board.
    S44B,
    /// The encoder marked S45A on the board.
    S45A,
    /// The encoder marked S45B on the board.
    S45B,
    /// The encoder marked S37 on the board.
    S37,
    /// The encoder marked S39 on the board.
    S39,
    /// The encoder marked S38 on the board.
    S38,
    /// The encoder marked S40 on the board.
    S40,
}

impl Rotary {
    /// Number of rotaries on the board.
    pub const COUNT: usize = 14;

    /// All rotaries in wire order.
    pub const ALL: [Rotary; 14] = [
        Rotary::S41A,
        Rotary::S41B,
        Rotary::S42A,
        Rotary::S42B,
        Rotary::S43A,
        Rotary::S43B,
        Rotary::S44A,
        Rotary::S44B,
        Rotary::S45A,
        Rotary::S45B,
        Rotary::S37,
        Rotary::S39,
        Rotary::S38,
        Rotary::S40,
    ];

    /// Position in wire order, 0..=13 (index into `RotaryValues`).
    pub fn index(self) -> usize {
        self as usize
    }

    /// The rotary at wire-order position `index`.
    pub fn from_index(index: usize) -> Option<Self> {
        Self::ALL.get(index).copied()
    }

    /// The rotary name, such as `S41A`.
    pub fn name(self) -> &'static str {
        match self {
            Rotary::S41A => "S41A",
            Rotary::S41B => "S41B",
            Rotary::S42A => "S42A",
            Rotary::S42B => "S42B",
            Rotary::S43A => "S43A",
            Rotary::S43B => "S43B",
            Rotary::S44A => "S44A",
            Rotary::S44B => "S44B",
            Rotary::S45A => "S45A",
            Rotary::S45B => "S45B",
            Rotary::S37 => "S37",
            Rotary::S39 => "S39",
            Rotary::S38 => "S38",
            Rotary::S40 => "S40",
        }
    }

    /// The rotary called `name` (case-insensitive, such as `s41a`), if there is one.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL
            .iter()
            .copied()
            .find(|r| r.name().eq_ignore_ascii_case(name))
    }

    /// The response packet that carries this rotary and its byte offset (1..=7) in it.
    pub fn location(self) -> (RotaryPacket, usize) {
        let i = self.index();
        if i < 7 {
            (RotaryPacket::Rotary0, i + 1)
        } else {
            (RotaryPacket::Rotary1, i - 6)
        }
    }
}

impl fmt::Display for Rotary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The 14 rotary counters (half-turns, wrapping at 256), combining a `C2` and a `C3` answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct RotaryValues([u8; 14]);

impl RotaryValues {
    /// From the seven data bytes of a `C2` and of a `C3` answer.
    pub fn from_packets(rotary0: [u8; 7], rotary1: [u8; 7]) -> Self {
        let mut v = [0u8; 14];
        let (a, b) = v.split_at_mut(7);
        a.copy_from_slice(&rotary0);
        b.copy_from_slice(&rotary1);
        Self(v)
    }

    /// From all 14 counters in wire order.
    pub fn from_array(values: [u8; 14]) -> Self {
        Self(values)
    }

    /// All 14 counters in wire order.
    pub fn to_array(&self) -> [u8; 14] {
        self.0
    }

    /// The counter of `rotary`.
    pub fn get(&self, rotary: Rotary) -> u8 {
        self.0.get(rotary.index()).copied().unwrap_or(0)
    }

    /// Sets the counter of `rotary`.
    pub fn set(&mut self, rotary: Rotary, value: u8) {
        if let Some(v) = self.0.get_mut(rotary.index()) {
            *v = value;
        }
    }

    /// The seven data bytes of the `C2` answer.
    pub fn rotary0(&self) -> [u8; 7] {
        let mut out = [0u8; 7];
        out.copy_from_slice(&self.0[..7]);
        out
    }

    /// The seven data bytes of the `C3` answer.
    pub fn rotary1(&self) -> [u8; 7] {
        let mut out = [0u8; 7];
        out.copy_from_slice(&self.0[7..]);
        out
    }

    /// (rotary, counter) pairs in wire order.
    pub fn iter(&self) -> impl Iterator<Item = (Rotary, u8)> + '_ {
        Rotary::ALL.iter().copied().zip(self.0.iter().copied())
    }
}

/// The change of a half-turn counter between two reads: the signed 8-bit difference, so a wrap
/// counts the short way (0xFF -> 0x01 is +2, 0x01 -> 0xFF is -2).
pub fn rotary_delta(old: u8, new: u8) -> i8 {
    new.wrapping_sub(old) as i8
}

/// A response from the board to the PC (IN endpoint 2, address 0x82).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Response {
    /// `C1`: the switch states.
    Inputs(SwitchSet),
    /// `C2`: counters S41A S41B S42A S42B S43A S43B S44A.
    Rotary0([u8; 7]),
    /// `C3`: counters S44B S45A S45B S37 S39 S38 S40.
    Rotary1([u8; 7]),
}

impl Response {
    /// The packet on the wire; unused bytes are zero.
    pub fn encode(&self) -> Packet {
        let mut p = [0u8; PACKET_LEN];
        let (code, data): (u8, &[u8]) = match self {
            Response::Inputs(s) => (RESP_INPUT, &s.0),
            Response::Rotary0(v) => (RESP_ROTARY0, v),
            Response::Rotary1(v) => (RESP_ROTARY1, v),
        };
        p[0] = code;
        for (slot, b) in p.iter_mut().skip(1).zip(data) {
            *slot = *b;
        }
        p
    }

    /// Reads a response from a slice of any length; bytes past the data are ignored.
    /// `C1` needs 7 bytes (its last byte is unused), `C2`/`C3` need 8.
    pub fn decode(bytes: &[u8]) -> Result<Self, DecodeError> {
        let short = |needed| DecodeError::Short {
            needed,
            got: bytes.len(),
        };
        match bytes {
            [] => Err(short(1)),
            [RESP_INPUT, rest @ ..] => match rest {
                [b0, b1, b2, b3, b4, b5, ..] => Ok(Response::Inputs(SwitchSet::from_bytes([
                    *b0, *b1, *b2, *b3, *b4, *b5,
                ]))),
                _ => Err(short(7)),
            },
            [code @ (RESP_ROTARY0 | RESP_ROTARY1), rest @ ..] => {
                let data: [u8; 7] = rest
                    .get(..7)
                    .and_then(|d| d.try_into().ok())
                    .ok_or_else(|| short(8))?;
                Ok(if *code == RESP_ROTARY0 {
                    Response::Rotary0(data)
                } else {
                    Response::Rotary1(data)
                })
            }
            [other, ..] => Err(DecodeError::UnknownResponse(*other)),
        }
    }

    /// The first byte of this response on the wire.
    pub fn code(&self) -> u8 {
        match self {
            Response::Inputs(_) => RESP_INPUT,
            Response::Rotary0(_) => RESP_ROTARY0,
            Response::Rotary1(_) => RESP_ROTARY1,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn relay(n: u8) -> Relay {
        Relay::new(n).unwrap()
    }

    // Vendor document, "Set Relais": 05, relay number in bits 4..2 of byte 1.
    #[test]
    fn select_relay_puts_the_number_in_bits_4_to_2() {
        assert_eq!(
            Command::SelectRelay(relay(0)).encode(),
            [0x05, 0, 0, 0, 0, 0, 0, 0]
        );
        assert_eq!(
            Command::SelectRelay(relay(1)).encode(),
            [0x05, 0x04, 0, 0, 0, 0, 0, 0]
        );
        assert_eq!(
            Command::SelectRelay(relay(5)).encode(),
            [0x05, 0x14, 0, 0, 0, 0, 0, 0]
        );
        assert_eq!(
            Command::SelectRelay(relay(7)).encode(),
            [0x05, 0x1C, 0, 0, 0, 0, 0, 0]
        );
    }

    #[test]
    fn relays_above_7_are_refused() {
        assert_eq!(Relay::new(8), Err(InvalidRelay(8)));
        assert_eq!(Relay::new(255), Err(InvalidRelay(255)));
        assert_eq!(Relay::new(7).unwrap().number(), 7);
    }

    #[test]
    fn select_relay_decode_ignores_dont_care_bits_and_unused_bytes() {
        // Bits 7..5 and 1..0 set, relay 3 in bits 4..2, junk in the unused bytes.
        let p = [0x05, 0b1110_1111, 9, 9, 9, 9, 9, 9];
        assert_eq!(Command::decode(&p), Ok(Command::SelectRelay(relay(3))));
    }

    // Vendor document, "Request Input/Rotary0/Rotary1": one command byte, rest unused.
    #[test]
    fn requests_are_one_byte_and_zero_padded() {
        assert_eq!(Command::RequestInput.encode(), [0x41, 0, 0, 0, 0, 0, 0, 0]);
        assert_eq!(
            Command::RequestRotary0.encode(),
            [0x42, 0, 0, 0, 0, 0, 0, 0]
        );
        assert_eq!(
            Command::RequestRotary1.encode(),
            [0x43, 0, 0, 0, 0, 0, 0, 0]
        );
        assert_eq!(
            Command::decode(&[0x41, 1, 2, 3, 4, 5, 6, 7]),
            Ok(Command::RequestInput)
        );
        assert_eq!(
            Command::decode(&[0x42, 0, 0, 0, 0, 0, 0, 0]),
            Ok(Command::RequestRotary0)
        );
        assert_eq!(
            Command::decode(&[0x43, 0, 0, 0, 0, 0, 0, 0]),
            Ok(Command::RequestRotary1)
        );
    }

    #[test]
    fn unknown_commands_are_typed_errors() {
        assert_eq!(
            Command::decode(&[0x44, 0, 0, 0, 0, 0, 0, 0]),
            Err(DecodeError::UnknownCommand(0x44))
        );
        assert_eq!(
            Command::decode(&[0xC1, 0, 0, 0, 0, 0, 0, 0]),
            Err(DecodeError::UnknownCommand(0xC1))
        );
    }

    #[test]
    fn requests_name_the_response_they_expect() {
        assert_eq!(Command::RequestInput.response_code(), Some(0xC1));
        assert_eq!(Command::RequestRotary0.response_code(), Some(0xC2));
        assert_eq!(Command::RequestRotary1.response_code(), Some(0xC3));
        assert_eq!(Command::SelectRelay(relay(2)).response_code(), None);
    }

    // Vendor document, "Respond Input", with the layout of docs/trc1000-protocol.md.
    #[test]
    fn respond_input_bytes_0_to_2_are_s1_to_s24_in_order() {
        let r = Response::decode(&[0xC1, 0x01, 0x80, 0x05, 0, 0, 0, 0]).unwrap();
        let Response::Inputs(set) = r else {
            panic!("not inputs: {r:?}")
        };
        assert_eq!(set.pressed_names(), vec!["S1", "S16", "S17", "S19"]);
    }

    #[test]
    fn respond_input_scrambled_bytes_follow_notes() {
        let expected: [(usize, [&str; 8]); 3] = [
            (3, ["S25", "S26", "S31", "S32", "S33", "S34", "S35", "S36"]),
            (4, ["S41", "S42", "S43", "S44", "S45", "S37", "S39", "S38"]),
            (5, ["S40", "S27", "S28", "S29", "S30", "", "", ""]),
        ];
        for (byte, names) in expected {
            for (bit, name) in names.iter().enumerate() {
                let mut p = [0xC1, 0, 0, 0, 0, 0, 0, 0];
                p[byte + 1] = 1 << bit;
                let Ok(Response::Inputs(set)) = Response::decode(&p) else {
                    panic!("C1 did not decode")
                };
                let want: Vec<&str> = if name.is_empty() { vec![] } else { vec![*name] };
                assert_eq!(set.pressed_names(), want, "b{byte} bit {bit}");
            }
        }
    }

    #[test]
    fn every_switch_has_a_unique_position_that_round_trips() {
        let mut seen = std::collections::HashSet::new();
        for s in Switch::all() {
            let (byte, bit) = s.position();
            assert!(byte < 6 && bit < 8, "{s}");
            assert_eq!(LAYOUT[byte][bit as usize], s.number(), "{s}");
            assert!(seen.insert((byte, bit)), "{s} shares a bit");
            let mut set = SwitchSet::new();
            set.set(s, true);
            assert_eq!(set.pressed(), vec![s]);
            assert!(set.is_pressed(s));
            let mut bytes = [0u8; 6];
            bytes[byte] = 1 << bit;
            assert_eq!(set.bytes(), bytes);
            set.set(s, false);
            assert_eq!(set, SwitchSet::new());
        }
        assert_eq!(seen.len(), 45);
    }

    #[test]
    fn switch_positions_spot_checks() {
        let pos = |n: &str| Switch::from_name(n).unwrap().position();
        assert_eq!(pos("S1"), (0, 0));
        assert_eq!(pos("S8"), (0, 7));
        assert_eq!(pos("S9"), (1, 0));
        assert_eq!(pos("S24"), (2, 7));
        assert_eq!(pos("S27"), (5, 1));
        assert_eq!(pos("S31"), (3, 2));
        assert_eq!(pos("S37"), (4, 5));
        assert_eq!(pos("S38"), (4, 7));
        assert_eq!(pos("S39"), (4, 6));
        assert_eq!(pos("S40"), (5, 0));
        assert_eq!(pos("S45"), (4, 4));
    }

    #[test]
    fn switch_names_parse_case_insensitively_and_strictly() {
        assert_eq!(Switch::from_name("S17"), Switch::new(17));
        assert_eq!(Switch::from_name("s17"), Switch::new(17));
        assert_eq!(Switch::from_name("S45").unwrap().name(), "S45");
        for bad in [
            "", "S", "S0", "S46", "S017", "S+3", "17", "X17", "S1 ", "S41A", "S256",
        ] {
            assert_eq!(Switch::from_name(bad), None, "{bad:?}");
        }
        for s in Switch::all() {
            assert_eq!(Switch::from_name(s.name()), Some(s));
            assert_eq!(s.name(), format!("S{}", s.number()));
        }
    }

    #[test]
    fn pressed_lists_in_s_number_order_whatever_the_bit_order() {
        let mut set = SwitchSet::new();
        for n in ["S38", "S3", "S27", "S41", "S37"] {
            set.set(Switch::from_name(n).unwrap(), true);
        }
        assert_eq!(set.pressed_names(), vec!["S3", "S27", "S37", "S38", "S41"]);
    }

    #[test]
    fn unused_bits_of_b5_and_byte_7_are_ignored() {
        let a = Response::decode(&[0xC1, 0, 0, 0, 0, 0, 0xE0, 0xFF]).unwrap();
        assert_eq!(a, Response::Inputs(SwitchSet::new()));
        assert_eq!(a.encode(), [0xC1, 0, 0, 0, 0, 0, 0, 0]);
    }

    #[test]
    fn switch_changes_split_presses_and_releases() {
        let s = |n: &str| Switch::from_name(n).unwrap();
        let mut old = SwitchSet::new();
        old.set(s("S1"), true);
        old.set(s("S40"), true);
        let mut new = SwitchSet::new();
        new.set(s("S40"), true);
        new.set(s("S2"), true);
        assert_eq!(old.changes(&new), (vec![s("S2")], vec![s("S1")]));
    }

    // Vendor document, "Respond Rotary0" and "Respond Rotary1".
    #[test]
    fn respond_rotary0_carries_s41a_to_s44a() {
        let p = [0xC2, 1, 2, 3, 4, 5, 6, 7];
        assert_eq!(
            Response::decode(&p),
            Ok(Response::Rotary0([1, 2, 3, 4, 5, 6, 7]))
        );
        let v = RotaryValues::from_packets([1, 2, 3, 4, 5, 6, 7], [0; 7]);
        let names: Vec<(&str, u8)> = v.iter().take(7).map(|(r, x)| (r.name(), x)).collect();
        assert_eq!(
            names,
            vec![
                ("S41A", 1),
                ("S41B", 2),
                ("S42A", 3),
                ("S42B", 4),
                ("S43A", 5),
                ("S43B", 6),
                ("S44A", 7)
            ]
        );
    }

    #[test]
    fn respond_rotary1_carries_s44b_to_s40() {
        let p = [0xC3, 11, 12, 13, 14, 15, 16, 17];
        assert_eq!(
            Response::decode(&p),
            Ok(Response::Rotary1([11, 12, 13, 14, 15, 16, 17]))
        );
        let v = RotaryValues::from_packets([0; 7], [11, 12, 13, 14, 15, 16, 17]);
        let names: Vec<(&str, u8)> = v.iter().skip(7).map(|(r, x)| (r.name(), x)).collect();
        assert_eq!(
            names,
            vec![
                ("S44B", 11),
                ("S45A", 12),
                ("S45B", 13),
                ("S37", 14),
                ("S39", 15),
                ("S38", 16),
                ("S40", 17)
            ]
        );
    }

    #[test]
    fn every_rotary_location_matches_the_vendor_tables() {
        use RotaryPacket::*;
        let table = [
            ("S41A", Rotary0, 1),
            ("S41B", Rotary0, 2),
            ("S42A", Rotary0, 3),
            ("S42B", Rotary0, 4),
            ("S43A", Rotary0, 5),
            ("S43B", Rotary0, 6),
            ("S44A", Rotary0, 7),
            ("S44B", Rotary1, 1),
            ("S45A", Rotary1, 2),
            ("S45B", Rotary1, 3),
            ("S37", Rotary1, 4),
            ("S39", Rotary1, 5),
            ("S38", Rotary1, 6),
            ("S40", Rotary1, 7),
        ];
        for (i, (name, packet, offset)) in table.iter().enumerate() {
            let r = Rotary::from_name(name).unwrap();
            assert_eq!(r.name(), *name);
            assert_eq!(r.index(), i);
            assert_eq!(Rotary::from_index(i), Some(r));
            assert_eq!(r.location(), (*packet, *offset), "{name}");
            // Setting one counter changes exactly that byte of that packet.
            let mut v = RotaryValues::default();
            v.set(r, 0xAB);
            let (p0, p1) = (
                Response::Rotary0(v.rotary0()),
                Response::Rotary1(v.rotary1()),
            );
            let enc = if *packet == Rotary0 {
                p0.encode()
            } else {
                p1.encode()
            };
            assert_eq!(enc[*offset], 0xAB, "{name}");
            assert_eq!(enc.iter().filter(|b| **b == 0xAB).count(), 1, "{name}");
        }
        assert_eq!(Rotary::from_index(14), None);
    }

    #[test]
    fn rotary_names_parse_case_insensitively() {
        assert_eq!(Rotary::from_name("s41a"), Some(Rotary::S41A));
        assert_eq!(Rotary::from_name("S40"), Some(Rotary::S40));
        for bad in ["S41", "S36", "S45C", "", "S41AA"] {
            assert_eq!(Rotary::from_name(bad), None, "{bad:?}");
        }
    }

    #[test]
    fn rotary_delta_is_the_signed_8_bit_difference() {
        assert_eq!(rotary_delta(0xFF, 0x01), 2);
        assert_eq!(rotary_delta(0x01, 0xFF), -2);
        assert_eq!(rotary_delta(10, 14), 4);
        assert_eq!(rotary_delta(14, 10), -4);
        assert_eq!(rotary_delta(7, 7), 0);
        assert_eq!(rotary_delta(0, 0x7F), 127);
        assert_eq!(rotary_delta(0, 0x80), -128);
    }

    #[test]
    fn short_and_unknown_responses_are_typed_errors() {
        assert_eq!(
            Response::decode(&[]),
            Err(DecodeError::Short { needed: 1, got: 0 })
        );
        assert_eq!(
            Response::decode(&[0xC1, 0, 0, 0, 0, 0]),
            Err(DecodeError::Short { needed: 7, got: 6 })
        );
        assert!(Response::decode(&[0xC1, 0, 0, 0, 0, 0, 0]).is_ok());
        assert_eq!(
            Response::decode(&[0xC2, 1, 2, 3, 4, 5, 6]),
            Err(DecodeError::Short { needed: 8, got: 7 })
        );
        assert_eq!(
            Response::decode(&[0x41, 0, 0, 0, 0, 0, 0, 0]),
            Err(DecodeError::UnknownResponse(0x41))
        );
        // Longer slices are fine: bytes past the packet are ignored.
        assert_eq!(
            Response::decode(&[0xC3, 1, 2, 3, 4, 5, 6, 7, 8, 9]),
            Ok(Response::Rotary1([1, 2, 3, 4, 5, 6, 7]))
        );
    }

    fn any_command() -> impl Strategy<Value = Command> {
        prop_oneof![
            (0u8..=7).prop_map(|n| Command::SelectRelay(Relay(n))),
            Just(Command::RequestInput),
            Just(Command::RequestRotary0),
            Just(Command::RequestRotary1),
        ]
    }

    fn any_response() -> impl Strategy<Value = Response> {
        prop_oneof![
            any::<[u8; 6]>().prop_map(|b| Response::Inputs(SwitchSet::from_bytes(b))),
            any::<[u8; 7]>().prop_map(Response::Rotary0),
            any::<[u8; 7]>().prop_map(Response::Rotary1),
        ]
    }

    proptest! {
        #[test]
        fn commands_round_trip(c in any_command()) {
            prop_assert_eq!(Command::decode(&c.encode()), Ok(c));
        }

        #[test]
        fn responses_round_trip(r in any_response()) {
            let p = r.encode();
            prop_assert_eq!(Response::decode(&p), Ok(r));
            prop_assert_eq!(p[0], r.code());
        }

        #[test]
        fn rotary_values_round_trip_through_packets(v in any::<[u8; 14]>()) {
            let rv = RotaryValues::from_array(v);
            let back = RotaryValues::from_packets(rv.rotary0(), rv.rotary1());
            prop_assert_eq!(back.to_array(), v);
        }

        #[test]
        fn rotary_delta_undoes_wrapping_add(old in any::<u8>(), d in any::<i8>()) {
            prop_assert_eq!(rotary_delta(old, old.wrapping_add(d as u8)), d);
        }

        #[test]
        fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..20)) {
            let _ = Response::decode(&bytes);
            let mut p = [0u8; 8];
            for (slot, b) in p.iter_mut().zip(&bytes) { *slot = *b; }
            let _ = Command::decode(&p);
            if let Ok(Response::Inputs(set)) = Response::decode(&bytes) {
                let _ = set.pressed_names();
            }
        }

        #[test]
        fn random_names_never_panic(name in ".{0,8}") {
            let _ = Switch::from_name(&name);
            let _ = Rotary::from_name(&name);
        }
    }
}
