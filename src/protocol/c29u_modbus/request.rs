//! Typed Modbus requests to the TRP-C29U: encoding (master side) and decoding (simulator side).
//!
//! Vendor addressing (10-16..10-20): the high address byte of 05 and 0F selects what the
//! command acts on, so `05 02 NN` clears counter NN rather than writing coil 0x02NN.

use super::error::{ExceptionCode, RequestError};
use super::frame::{open_frame, seal_in_place};
use super::{
    FC_READ_BITS, FC_READ_HOLDING, FC_READ_INPUT, FC_VENDOR, FC_WRITE_COIL, FC_WRITE_COILS,
};

/// Which 8 bits function 01 reads: the low address byte `SS` of `ID 01 00 SS 00 08` (10-17).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BitArea {
    /// 00: the DO byte.
    Outputs,
    /// 20: the DI byte as on the wire (energized input = 0 bit: 8-11, 10-17).
    Inputs,
    /// 40: inputs latched at logic 0 since the last clear.
    LatchedLow,
    /// 60: inputs latched at logic 1 since the last clear.
    LatchedHigh,
}

impl BitArea {
    /// Every area, in address order.
    pub const ALL: [BitArea; 4] = [
        BitArea::Outputs,
        BitArea::Inputs,
        BitArea::LatchedLow,
        BitArea::LatchedHigh,
    ];

    /// The start address byte `SS`.
    pub fn address(self) -> u8 {
        match self {
            Self::Outputs => 0x00,
            Self::Inputs => 0x20,
            Self::LatchedLow => 0x40,
            Self::LatchedHigh => 0x60,
        }
    }

    /// The area at start address byte `SS`, if any.
    pub fn from_address(ss: u8) -> Option<Self> {
        Self::ALL.into_iter().find(|a| a.address() == ss)
    }
}

/// Function 03 or 04: both read the counters the same way (10-18, 10-19).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CounterFunction {
    /// 03, read holding registers.
    Holding,
    /// 04, read input registers (the manual's example).
    Input,
}

impl CounterFunction {
    /// The function code.
    pub fn code(self) -> u8 {
        match self {
            Self::Holding => FC_READ_HOLDING,
            Self::Input => FC_READ_INPUT,
        }
    }
}

/// What a function 05 write acts on: `ID 05 SS NN VV 00` (10-16).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CoilCommand {
    /// SS 00: switch DO channel NN on (value FF00) or off (0000).
    Output {
        /// DO channel 0-7.
        channel: u8,
        /// true = on.
        on: bool,
    },
    /// SS 01: clear the input latches (NN 00, value 0000).
    ClearLatches,
    /// SS 02: clear counter NN (value 0000).
    ClearCounter {
        /// DI channel 0-7.
        channel: u8,
    },
}

impl CoilCommand {
    /// The four bytes after the function code: `SS NN VH VL`.
    pub(crate) fn fields(self) -> [u8; 4] {
        match self {
            Self::Output { channel, on } => [0x00, channel, if on { 0xFF } else { 0x00 }, 0x00],
            Self::ClearLatches => [0x01, 0x00, 0x00, 0x00],
            Self::ClearCounter { channel } => [0x02, channel, 0x00, 0x00],
        }
    }
}

/// What a function 0F write acts on: the high address byte `SS` of `ID 0F SS NN 00 CN 01 DD` (10-20).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CoilsTarget {
    /// 00: DO channels NN..NN+CN-1 from the bits of DD (bit 0 = channel NN).
    Outputs,
    /// 02: clear counters NN..NN+CN-1.
    ClearCounters,
    /// 03: save all counters to EEPROM.
    SaveCounters,
}

impl CoilsTarget {
    /// The high address byte `SS`.
    pub fn address(self) -> u8 {
        match self {
            Self::Outputs => 0x00,
            Self::ClearCounters => 0x02,
            Self::SaveCounters => 0x03,
        }
    }

    /// The target at high address byte `SS`, if any.
    pub fn from_address(ss: u8) -> Option<Self> {
        match ss {
            0x00 => Some(Self::Outputs),
            0x02 => Some(Self::ClearCounters),
            0x03 => Some(Self::SaveCounters),
            _ => None,
        }
    }
}

/// Vendor function 46, one variant per sub-function of section 10 (10-1..10-15).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum VendorRequest {
    /// 00: read the module name (`0C 29` = "C29").
    ReadName,
    /// 04: set a new slave ID; the answer still comes from the old one (10-2 as read).
    SetId(u8),
    /// 05: read the configuration (baud code).
    ReadConfig,
    /// 06: set the baud code (8-2 table).
    SetBaud(u8),
    /// 07: read the firmware date.
    ReadFirmware,
    /// 08: read (and clear) the reset flag.
    ReadResetFlag,
    /// 09: reset the module.
    Reset,
    /// 0B: host watchdog timeout in 0.1 s (00 = disable).
    SetWatchdog(u8),
    /// 0C: read the watchdog state.
    ReadWatchdog,
    /// 0D: LED panel mode (0 or 1, 10-10).
    SetLedMode(u8),
    /// 27: set the power-on DO value.
    SetPowerOnValue(u8),
    /// 28: read the power-on DO value.
    ReadPowerOnValue,
    /// 29: set the safe DO value.
    SetSafeValue(u8),
    /// 2A: read the safe DO value.
    ReadSafeValue,
    /// 2F: host OK, restarts the watchdog countdown; never answered (10-15).
    HostOk,
}

impl VendorRequest {
    /// Every sub-function code in section 10.
    pub const SUBS: [u8; 15] = [
        0x00, 0x04, 0x05, 0x06, 0x07, 0x08, 0x09, 0x0B, 0x0C, 0x0D, 0x27, 0x28, 0x29, 0x2A, 0x2F,
    ];

    /// The sub-function byte.
    pub fn sub(self) -> u8 {
        match self {
            Self::ReadName => 0x00,
            Self::SetId(_) => 0x04,
            Self::ReadConfig => 0x05,
            Self::SetBaud(_) => 0x06,
            Self::ReadFirmware => 0x07,
            Self::ReadResetFlag => 0x08,
            Self::Reset => 0x09,
            Self::SetWatchdog(_) => 0x0B,
            Self::ReadWatchdog => 0x0C,
            Self::SetLedMode(_) => 0x0D,
            Self::SetPowerOnValue(_) => 0x27,
            Self::ReadPowerOnValue => 0x28,
            Self::SetSafeValue(_) => 0x29,
            Self::ReadSafeValue => 0x2A,
            Self::HostOk => 0x2F,
        }
    }

    /// The bytes after the sub-function, with the manual's reserved zeros.
    fn payload(self) -> Vec<u8> {
        match self {
            Self::SetId(ip) => vec![ip, 0x00, 0x00, 0x00],
            Self::SetBaud(bd) => vec![0x00, bd, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00],
            Self::SetWatchdog(v)
            | Self::SetLedMode(v)
            | Self::SetPowerOnValue(v)
            | Self::SetSafeValue(v) => vec![v, 0x00],
            Self::ReadName
            | Self::ReadConfig
            | Self::ReadFirmware
            | Self::ReadResetFlag
            | Self::Reset
            | Self::ReadWatchdog
            | Self::ReadPowerOnValue
            | Self::ReadSafeValue
            | Self::HostOk => vec![0x00],
        }
    }

    /// Reads a sub-function and what follows it. Reserved bytes are neither required nor
    /// checked (lengths are not reliable in section 10); data bytes are required.
    fn decode(sub: u8, rest: &[u8]) -> Option<Self> {
        let first = rest.first().copied();
        Some(match sub {
            0x00 => Self::ReadName,
            0x04 => Self::SetId(first?),
            0x05 => Self::ReadConfig,
            0x06 => Self::SetBaud(*rest.get(1)?),
            0x07 => Self::ReadFirmware,
            0x08 => Self::ReadResetFlag,
            0x09 => Self::Reset,
            0x0B => Self::SetWatchdog(first?),
            0x0C => Self::ReadWatchdog,
            0x0D => Self::SetLedMode(first?),
            0x27 => Self::SetPowerOnValue(first?),
            0x28 => Self::ReadPowerOnValue,
            0x29 => Self::SetSafeValue(first?),
            0x2A => Self::ReadSafeValue,
            0x2F => Self::HostOk,
            _ => return None,
        })
    }
}

/// The length with CRC of the request for vendor sub-function `sub` as section 10 writes it.
pub(crate) fn vendor_request_len(sub: u8) -> Option<usize> {
    match sub {
        0x00 | 0x05 | 0x07 | 0x08 | 0x09 | 0x0C | 0x28 | 0x2A | 0x2F => Some(6),
        0x0B | 0x0D | 0x27 | 0x29 => Some(7),
        0x04 => Some(9),
        0x06 => Some(13),
        _ => None,
    }
}

/// The length with CRC of the (non-error) answer to vendor sub-function `sub`, as the project
/// writes it (section 10 as docs/trp-c29u-protocol.md reads it); None for host OK, which is
/// never answered.
pub(crate) fn vendor_answer_len(sub: u8) -> Option<usize> {
    match sub {
        0x09 | 0x0B | 0x0D | 0x27 | 0x28 | 0x29 | 0x2A => Some(6),
        0x08 | 0x0C => Some(7),
        0x00 | 0x04 | 0x07 => Some(9),
        0x06 => Some(12),
        0x05 => Some(13),
        _ => None,
    }
}

/// One request to the module (section 10).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Request {
    /// 01: read 8 bits of one area, `ID 01 00 SS 00 08` (10-17).
    ReadBits(BitArea),
    /// 03/04: read counters 0..`count`, `ID FC 00 00 00 NN` (10-18, 10-19: the start channel
    /// SS is always 00, so channel N is the last of N + 1 counters).
    ReadCounters {
        /// 03 or 04.
        function: CounterFunction,
        /// How many, 1-8, from channel 0.
        count: u8,
    },
    /// 05: one coil write, `ID 05 SS NN VV 00` (10-16).
    WriteCoil(CoilCommand),
    /// 0F: coils write, `ID 0F SS NN 00 CN 01 DD` (10-20).
    WriteCoils {
        /// What the write acts on.
        target: CoilsTarget,
        /// First channel NN, 0-7.
        start: u8,
        /// Channel count CN, 1-8 (start + count <= 8).
        count: u8,
        /// The data byte DD (DO bits; 00 for clear and save).
        data: u8,
    },
    /// 46: vendor function.
    Vendor(VendorRequest),
}

impl Request {
    /// 0F 00: all eight outputs from `value` (bit n = DOn).
    pub fn write_outputs(value: u8) -> Self {
        Self::WriteCoils {
            target: CoilsTarget::Outputs,
            start: 0,
            count: 8,
            data: value,
        }
    }

    /// 0F 02: clear counters `start..start+count`.
    pub fn clear_counters(start: u8, count: u8) -> Self {
        Self::WriteCoils {
            target: CoilsTarget::ClearCounters,
            start,
            count,
            data: 0,
        }
    }

    /// 0F 03: save all counters to EEPROM (as the manual's example: channels 0-7).
    pub fn save_counters() -> Self {
        Self::WriteCoils {
            target: CoilsTarget::SaveCounters,
            start: 0,
            count: 8,
            data: 0,
        }
    }

    /// 04: read counters `0..count` (10-19).
    pub fn read_counters(count: u8) -> Self {
        Self::ReadCounters {
            function: CounterFunction::Input,
            count,
        }
    }

    /// The function code.
    pub fn function(&self) -> u8 {
        match self {
            Self::ReadBits(_) => FC_READ_BITS,
            Self::ReadCounters { function, .. } => function.code(),
            Self::WriteCoil(_) => FC_WRITE_COIL,
            Self::WriteCoils { .. } => FC_WRITE_COILS,
            Self::Vendor(_) => FC_VENDOR,
        }
    }

    /// The vendor sub-function, for 46 requests.
    pub fn vendor_sub(&self) -> Option<u8> {
        match self {
            Self::Vendor(v) => Some(v.sub()),
            _ => None,
        }
    }

    /// False only for host OK (46 2F), which the module never answers (10-15).
    pub fn expects_answer(&self) -> bool {
        !matches!(self, Self::Vendor(VendorRequest::HostOk))
    }

    /// The length with CRC of the normal answer, as the module is expected to send it
    /// (None when no answer comes). Vendor answers may differ on a real module (section 10).
    pub fn answer_len(&self) -> Option<usize> {
        match self {
            Self::ReadBits(_) => Some(6),
            Self::ReadCounters { count, .. } => Some(5 + 2 * usize::from(*count)),
            Self::WriteCoil(_) | Self::WriteCoils { .. } => Some(8),
            Self::Vendor(v) => vendor_answer_len(v.sub()),
        }
    }

    /// The frame for slave `id`, CRC included.
    pub fn encode(&self, id: u8) -> Vec<u8> {
        // Room for the longest request (a vendor write) and its CRC: one allocation, sealed in
        // place.
        let mut body = Vec::with_capacity(10);
        body.extend_from_slice(&[id, self.function()]);
        match *self {
            Self::ReadBits(area) => body.extend_from_slice(&[0x00, area.address(), 0x00, 0x08]),
            Self::ReadCounters { count, .. } => body.extend_from_slice(&[0x00, 0x00, 0x00, count]),
            Self::WriteCoil(cmd) => body.extend_from_slice(&cmd.fields()),
            Self::WriteCoils {
                target,
                start,
                count,
                data,
            } => body.extend_from_slice(&[target.address(), start, 0x00, count, 0x01, data]),
            Self::Vendor(v) => {
                body.push(v.sub());
                body.extend_from_slice(&v.payload());
            }
        }
        seal_in_place(body)
    }
}

/// Reads one complete request frame as the module does: the slave ID it is addressed to and
/// the request, or why the module refuses it (answered with an exception) or ignores it.
pub fn decode_request(frame: &[u8]) -> Result<(u8, Request), RequestError> {
    let body = open_frame(frame).ok_or(RequestError::BadCrc)?;
    let [id, function, rest @ ..] = body else {
        return Err(RequestError::BadCrc);
    };
    let (id, function) = (*id, *function);
    let refuse = |code| RequestError::Exception { id, function, code };
    let request = match function {
        FC_READ_BITS => {
            let [ah, al, qh, ql] = rest else {
                return Err(refuse(ExceptionCode::Syntax));
            };
            let area = match (*ah, BitArea::from_address(*al)) {
                (0x00, Some(area)) => area,
                _ => return Err(refuse(ExceptionCode::StartChannel)),
            };
            if (*qh, *ql) != (0x00, 0x08) {
                return Err(refuse(ExceptionCode::Range));
            }
            Request::ReadBits(area)
        }
        FC_READ_HOLDING | FC_READ_INPUT => {
            let [sh, sl, nh, nl] = rest else {
                return Err(refuse(ExceptionCode::Syntax));
            };
            // 10-18, 10-19: "Start channel number SS=00" is the only start the manual gives.
            if (*sh, *sl) != (0, 0) {
                return Err(refuse(ExceptionCode::StartChannel));
            }
            if *nh != 0 || *nl == 0 || *nl > 8 {
                return Err(refuse(ExceptionCode::Range));
            }
            let function = if function == FC_READ_HOLDING {
                CounterFunction::Holding
            } else {
                CounterFunction::Input
            };
            Request::ReadCounters {
                function,
                count: *nl,
            }
        }
        FC_WRITE_COIL => {
            let [ss, nn, vh, vl] = rest else {
                return Err(refuse(ExceptionCode::Syntax));
            };
            let on = match (*vh, *vl) {
                (0xFF, 0x00) => true,
                (0x00, 0x00) => false,
                _ => return Err(refuse(ExceptionCode::DataFormat)),
            };
            let (ss, nn) = (*ss, *nn);
            let cmd = match ss {
                0x00 if nn <= 7 => CoilCommand::Output { channel: nn, on },
                0x01 if nn == 0 => CoilCommand::ClearLatches,
                0x02 if nn <= 7 => CoilCommand::ClearCounter { channel: nn },
                _ => return Err(refuse(ExceptionCode::StartChannel)),
            };
            // 10-16: the clear commands carry DD = 00.
            if on && ss != 0x00 {
                return Err(refuse(ExceptionCode::DataFormat));
            }
            Request::WriteCoil(cmd)
        }
        FC_WRITE_COILS => {
            let [ss, nn, ch, cn, bc, data @ ..] = rest else {
                return Err(refuse(ExceptionCode::Syntax));
            };
            let [data] = data else {
                return Err(refuse(ExceptionCode::Syntax));
            };
            if *bc != 1 {
                return Err(refuse(ExceptionCode::Syntax));
            }
            let target = match CoilsTarget::from_address(*ss) {
                Some(t) if *nn <= 7 => t,
                _ => return Err(refuse(ExceptionCode::StartChannel)),
            };
            if *ch != 0 || *cn == 0 || u16::from(*nn) + u16::from(*cn) > 8 {
                return Err(refuse(ExceptionCode::Range));
            }
            Request::WriteCoils {
                target,
                start: *nn,
                count: *cn,
                data: *data,
            }
        }
        FC_VENDOR => {
            let [sub, rest @ ..] = rest else {
                return Err(RequestError::VendorError { id });
            };
            Request::Vendor(
                VendorRequest::decode(*sub, rest).ok_or(RequestError::VendorError { id })?,
            )
        }
        _ => return Err(refuse(ExceptionCode::Syntax)),
    };
    Ok((id, request))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::c29u_modbus::frame::seal;

    fn refused(frame_body: &[u8]) -> ExceptionCode {
        match decode_request(&seal(frame_body)) {
            Err(RequestError::Exception { code, .. }) => code,
            other => panic!("expected an exception for {frame_body:02X?}, got {other:?}"),
        }
    }

    #[test]
    fn vendor_lengths_match_the_encoder() {
        for sub in VendorRequest::SUBS {
            let mut body = vec![0x01, FC_VENDOR, sub];
            body.extend_from_slice(&[0x00; 8]);
            let v = VendorRequest::decode(sub, &body[3..]).unwrap();
            assert_eq!(v.sub(), sub);
            assert_eq!(
                Some(Request::Vendor(v).encode(1).len()),
                vendor_request_len(sub),
                "sub {sub:02X}"
            );
        }
        assert_eq!(vendor_request_len(0x01), None);
    }

    #[test]
    fn only_host_ok_goes_unanswered() {
        assert!(!Request::Vendor(VendorRequest::HostOk).expects_answer());
        assert_eq!(Request::Vendor(VendorRequest::HostOk).answer_len(), None);
        assert!(Request::Vendor(VendorRequest::Reset).expects_answer());
        assert!(Request::ReadBits(BitArea::Inputs).expects_answer());
    }

    #[test]
    fn bad_addresses_and_quantities_get_the_manual_codes() {
        assert_eq!(
            refused(&[1, 0x01, 0x00, 0x10, 0x00, 0x08]),
            ExceptionCode::StartChannel
        );
        assert_eq!(
            refused(&[1, 0x01, 0x01, 0x00, 0x00, 0x08]),
            ExceptionCode::StartChannel
        );
        assert_eq!(
            refused(&[1, 0x01, 0x00, 0x20, 0x00, 0x01]),
            ExceptionCode::Range
        );
        assert_eq!(refused(&[1, 0x01, 0x00, 0x20, 0x00]), ExceptionCode::Syntax);
        assert_eq!(
            refused(&[1, 0x04, 0x00, 0x08, 0x00, 0x01]),
            ExceptionCode::StartChannel
        );
        assert_eq!(
            refused(&[1, 0x04, 0x00, 0x00, 0x00, 0x09]),
            ExceptionCode::Range
        );
        assert_eq!(
            refused(&[1, 0x03, 0x00, 0x00, 0x00, 0x00]),
            ExceptionCode::Range
        );
        assert_eq!(
            refused(&[1, 0x03, 0x00, 0x04, 0x00, 0x04]),
            ExceptionCode::StartChannel,
            "10-18: the start is always 00"
        );
        assert_eq!(
            refused(&[1, 0x05, 0x00, 0x08, 0xFF, 0x00]),
            ExceptionCode::StartChannel
        );
        assert_eq!(
            refused(&[1, 0x05, 0x03, 0x00, 0xFF, 0x00]),
            ExceptionCode::StartChannel
        );
        assert_eq!(
            refused(&[1, 0x05, 0x00, 0x01, 0x12, 0x34]),
            ExceptionCode::DataFormat
        );
        assert_eq!(
            refused(&[1, 0x05, 0x02, 0x01, 0xFF, 0x00]),
            ExceptionCode::DataFormat
        );
        assert_eq!(
            refused(&[1, 0x0F, 0x01, 0x00, 0x00, 0x08, 0x01, 0x00]),
            ExceptionCode::StartChannel
        );
        assert_eq!(
            refused(&[1, 0x0F, 0x02, 0x04, 0x00, 0x05, 0x01, 0x00]),
            ExceptionCode::Range
        );
        assert_eq!(
            refused(&[1, 0x0F, 0x00, 0x00, 0x00, 0x08, 0x02, 0x00, 0x00]),
            ExceptionCode::Syntax
        );
        assert_eq!(
            refused(&[1, 0x06, 0x00, 0x00, 0x00, 0x01]),
            ExceptionCode::Syntax
        );
    }

    #[test]
    fn vendor_requests_refused_with_c6() {
        assert_eq!(
            decode_request(&seal(&[7, 0x46, 0x55, 0x00])),
            Err(RequestError::VendorError { id: 7 })
        );
        // Set ID without its data byte.
        assert_eq!(
            decode_request(&seal(&[7, 0x46, 0x04])),
            Err(RequestError::VendorError { id: 7 })
        );
        assert_eq!(
            decode_request(&seal(&[7, 0x46])),
            Err(RequestError::VendorError { id: 7 })
        );
    }

    #[test]
    fn vendor_reserved_bytes_are_optional_but_data_is_kept() {
        assert_eq!(
            decode_request(&seal(&[1, 0x46, 0x28])),
            Ok((1, Request::Vendor(VendorRequest::ReadPowerOnValue)))
        );
        assert_eq!(
            decode_request(&seal(&[1, 0x46, 0x0B, 0x12])),
            Ok((1, Request::Vendor(VendorRequest::SetWatchdog(0x12))))
        );
    }

    #[test]
    fn bad_crc_is_silence() {
        let mut f = Request::ReadBits(BitArea::Outputs).encode(1);
        f[7] ^= 0x40;
        assert_eq!(decode_request(&f), Err(RequestError::BadCrc));
        assert_eq!(decode_request(&[0x01, 0x01]), Err(RequestError::BadCrc));
    }
}
