//! Typed answers of the TRP-C29U: encoding (simulator side) and parsing against the request that
//! was sent (master side), as docs/trp-c29u-protocol.md reads 10-2, 10-9, 10-12 and 10-20.

use super::error::{ExceptionCode, ModbusError};
use super::frame::{open_frame, seal};
use super::request::{CoilCommand, CoilsTarget, CounterFunction, Request, VendorRequest};
use super::{EXCEPTION_FLAG, FC_READ_BITS, FC_VENDOR, FC_WRITE_COIL, FC_WRITE_COILS};

/// The answer to a vendor function 46 request, one variant per answered sub-function.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum VendorResponse {
    /// 00: `ID 46 00 00 HI LO 00`; the two bytes read as hex digits give the name (`0C 29` = "C29").
    Name(u16),
    /// 04: `ID 46 04 00 00 00 00`, sent from the old ID.
    IdChanged,
    /// 05: `ID 46 05 00 BD 00 00 00 00 00 00`.
    Config {
        /// Baud code (8-2 table).
        baud_code: u8,
    },
    /// 06: `ID 46 06 00 00 00 00 00 00 00` (seven zeros, as 10-4 writes it).
    BaudChanged,
    /// 07: `ID 46 07 YY MM DD 00`; the bytes as sent (10-5's `09 07 03` = 2009-07-03).
    Firmware {
        /// Year after 2000.
        year: u8,
        /// Month.
        month: u8,
        /// Day.
        day: u8,
    },
    /// 08: `ID 46 08 0D 00`, D = 1 when the module has been reset since the last read.
    ResetFlag(bool),
    /// 09: `ID 46 09 00`.
    ResetDone,
    /// 0B: `ID 46 0B 00`.
    WatchdogSet,
    /// 0C: `ID 46 0C EN WT` (10-9 as read).
    Watchdog {
        /// EN = 1.
        enabled: bool,
        /// WT, the timeout in 0.1 s.
        tenths: u8,
    },
    /// 0D: `ID 46 0D 00`.
    LedModeSet,
    /// 27: `ID 46 27 00`.
    PowerOnValueSet,
    /// 28: `ID 46 28 DD`, DD is the value itself (10-12 as read).
    PowerOnValue(u8),
    /// 29: `ID 46 29 00`.
    SafeValueSet,
    /// 2A: `ID 46 2A DD`.
    SafeValue(u8),
}

impl VendorResponse {
    /// The sub-function this answers.
    pub fn sub(self) -> u8 {
        match self {
            Self::Name(_) => 0x00,
            Self::IdChanged => 0x04,
            Self::Config { .. } => 0x05,
            Self::BaudChanged => 0x06,
            Self::Firmware { .. } => 0x07,
            Self::ResetFlag(_) => 0x08,
            Self::ResetDone => 0x09,
            Self::WatchdogSet => 0x0B,
            Self::Watchdog { .. } => 0x0C,
            Self::LedModeSet => 0x0D,
            Self::PowerOnValueSet => 0x27,
            Self::PowerOnValue(_) => 0x28,
            Self::SafeValueSet => 0x29,
            Self::SafeValue(_) => 0x2A,
        }
    }

    /// The bytes after the sub-function.
    fn payload(self) -> Vec<u8> {
        match self {
            Self::Name(code) => {
                let [hi, lo] = code.to_be_bytes();
                vec![0x00, hi, lo, 0x00]
            }
            Self::IdChanged => vec![0x00; 4],
            Self::Config { baud_code } => vec![0x00, baud_code, 0, 0, 0, 0, 0, 0],
            Self::BaudChanged => vec![0x00; 7],
            Self::Firmware { year, month, day } => vec![year, month, day, 0x00],
            Self::ResetFlag(flag) => vec![u8::from(flag), 0x00],
            Self::Watchdog { enabled, tenths } => vec![u8::from(enabled), tenths],
            Self::PowerOnValue(v) | Self::SafeValue(v) => vec![v],
            Self::ResetDone
            | Self::WatchdogSet
            | Self::LedModeSet
            | Self::PowerOnValueSet
            | Self::SafeValueSet => vec![0x00],
        }
    }
}

/// The module name that a 46 00 name code stands for: its hex digits without leading zeros
/// (`0x0C29` -> "C29", 10-1).
pub fn model_name(code: u16) -> String {
    let text = format!("{code:04X}");
    let trimmed = text.trim_start_matches('0');
    if trimmed.is_empty() {
        "0".to_string()
    } else {
        trimmed.to_string()
    }
}

/// A normal (non-exception) answer from the module.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Response {
    /// 01: `ID 01 01 DD`, the 8 bits of the requested area.
    Bits(u8),
    /// 03/04: `ID FC BC DATA`, counters big-endian in channel order.
    Counters {
        /// 03 or 04, as requested.
        function: CounterFunction,
        /// One value per requested channel.
        values: Vec<u16>,
    },
    /// 05: the request echoed.
    CoilWritten(CoilCommand),
    /// 0F: `ID 0F SS NN 00 CN`, address and quantity echoed (10-20 as read).
    CoilsWritten {
        /// What was written.
        target: CoilsTarget,
        /// NN.
        start: u8,
        /// CN.
        count: u8,
    },
    /// 46.
    Vendor(VendorResponse),
}

impl Response {
    /// The function code of the frame.
    pub fn function(&self) -> u8 {
        match self {
            Self::Bits(_) => FC_READ_BITS,
            Self::Counters { function, .. } => function.code(),
            Self::CoilWritten(_) => FC_WRITE_COIL,
            Self::CoilsWritten { .. } => FC_WRITE_COILS,
            Self::Vendor(_) => FC_VENDOR,
        }
    }
}

/// The answer frame of slave `id`, CRC included. Counters beyond 125 values do not fit a
/// frame and are cut there (the module has 8).
pub fn encode_response(id: u8, response: &Response) -> Vec<u8> {
    let mut body = vec![id, response.function()];
    match response {
        Response::Bits(bits) => body.extend_from_slice(&[0x01, *bits]),
        Response::Counters { values, .. } => {
            let values = values.get(..values.len().min(125)).unwrap_or_default();
            // At most 125 values, so the byte count fits in a u8.
            body.push(u8::try_from(values.len() * 2).unwrap_or(u8::MAX));
            for v in values {
                body.extend_from_slice(&v.to_be_bytes());
            }
        }
        Response::CoilWritten(cmd) => body.extend_from_slice(&cmd.fields()),
        Response::CoilsWritten {
            target,
            start,
            count,
        } => body.extend_from_slice(&[target.address(), *start, 0x00, *count]),
        Response::Vendor(v) => {
            body.push(v.sub());
            body.extend_from_slice(&v.payload());
        }
    }
    seal(&body)
}

/// The exception answer `ID FC|80 CODE` to a request with function code `function`.
pub fn encode_exception(id: u8, function: u8, code: ExceptionCode) -> Vec<u8> {
    seal(&[id, function | EXCEPTION_FLAG, code.to_byte()])
}

/// The vendor function error answer `ID C6 00`.
pub fn encode_vendor_error(id: u8) -> Vec<u8> {
    seal(&[id, FC_VENDOR | EXCEPTION_FLAG, 0x00])
}

/// Reads `frame` as the answer of slave `expected_id` to `request`.
///
/// Standard functions are checked strictly (byte counts, echoes). Vendor 46 answers must carry
/// their data bytes, but trailing reserved bytes may be missing or extra, since section 10 does
/// not state the lengths consistently.
pub fn parse_response(
    request: &Request,
    expected_id: u8,
    frame: &[u8],
) -> Result<Response, ModbusError> {
    let malformed = |reason| ModbusError::Malformed {
        reason,
        bytes: frame.to_vec(),
    };
    if frame.len() < super::MIN_FRAME_LEN {
        return Err(malformed("shorter than ID, function and CRC"));
    }
    let body = open_frame(frame).ok_or(ModbusError::BadCrc)?;
    let [id, function, data @ ..] = body else {
        return Err(malformed("shorter than ID, function and CRC"));
    };
    if *id != expected_id {
        return Err(ModbusError::WrongId {
            expected: expected_id,
            got: *id,
        });
    }
    if !request.expects_answer() {
        return Err(ModbusError::NoAnswerExpected);
    }
    let expected_fc = request.function();
    if is_safe_mode_refusal(expected_fc, *function, data) {
        return Err(ModbusError::SafeMode {
            function: expected_fc,
        });
    }
    if *function == expected_fc | EXCEPTION_FLAG {
        if expected_fc == FC_VENDOR {
            return Err(ModbusError::VendorError);
        }
        let [code] = data else {
            return Err(malformed("exception answer without exactly one code byte"));
        };
        return Err(match ExceptionCode::from_byte(*code) {
            ExceptionCode::SafeMode => ModbusError::SafeMode {
                function: expected_fc,
            },
            code => ModbusError::Exception {
                function: expected_fc,
                code,
            },
        });
    }
    if *function != expected_fc {
        return Err(ModbusError::UnexpectedFunction {
            expected: expected_fc,
            got: *function,
        });
    }
    match *request {
        Request::ReadBits(_) => match data {
            [0x01, bits] => Ok(Response::Bits(*bits)),
            _ => Err(malformed("read bits answer is not 01 DD")),
        },
        Request::ReadCounters { function, count } => {
            let [bc, values @ ..] = data else {
                return Err(malformed("counter answer without byte count"));
            };
            if usize::from(*bc) != 2 * usize::from(count) || values.len() != usize::from(*bc) {
                return Err(malformed(
                    "counter answer byte count does not match the request",
                ));
            }
            let values = values
                .chunks_exact(2)
                .map(|c| match c {
                    [hi, lo] => u16::from_be_bytes([*hi, *lo]),
                    _ => 0,
                })
                .collect();
            Ok(Response::Counters { function, values })
        }
        Request::WriteCoil(cmd) => {
            if data == cmd.fields() {
                Ok(Response::CoilWritten(cmd))
            } else {
                Err(malformed("write coil answer does not echo the request"))
            }
        }
        Request::WriteCoils {
            target,
            start,
            count,
            ..
        } => {
            if data == [target.address(), start, 0x00, count] {
                Ok(Response::CoilsWritten {
                    target,
                    start,
                    count,
                })
            } else {
                Err(malformed(
                    "write coils answer does not echo address and quantity",
                ))
            }
        }
        Request::Vendor(v) => parse_vendor(v, data)
            .map(Response::Vendor)
            .map_err(malformed),
    }
}

/// 10-16 and 10-20: a module in safe mode answers any output write (05 or 0F) with code FF, and
/// 10-16's note writes that answer `ID 8F FF` even for a 05 request: either exception function
/// of an output write with code FF is the safe-mode refusal.
pub(crate) fn is_safe_mode_refusal(request_fc: u8, answer_fc: u8, data: &[u8]) -> bool {
    is_output_write(request_fc) && is_safe_mode_function(answer_fc) && data == [0xFF]
}

/// 05 and 0F, the functions that write outputs (10-16, 10-20).
pub(crate) fn is_output_write(function: u8) -> bool {
    function == FC_WRITE_COIL || function == FC_WRITE_COILS
}

/// The exception functions a safe-mode refusal comes with: `85` or `8F` (10-16, 10-20).
pub(crate) fn is_safe_mode_function(function: u8) -> bool {
    function == FC_WRITE_COIL | EXCEPTION_FLAG || function == FC_WRITE_COILS | EXCEPTION_FLAG
}

/// Reads the bytes after the function code of a 46 answer to `request`.
fn parse_vendor(request: VendorRequest, data: &[u8]) -> Result<VendorResponse, &'static str> {
    let [sub, rest @ ..] = data else {
        return Err("vendor answer without sub-function");
    };
    if *sub != request.sub() {
        return Err("vendor answer for another sub-function");
    }
    let flag = |b: u8| match b {
        0 => Ok(false),
        1 => Ok(true),
        _ => Err("flag byte is neither 00 nor 01"),
    };
    let short = "vendor answer too short for its data";
    Ok(match request {
        VendorRequest::ReadName => match rest {
            [_, hi, lo, ..] => VendorResponse::Name(u16::from_be_bytes([*hi, *lo])),
            _ => return Err(short),
        },
        VendorRequest::SetId(_) => VendorResponse::IdChanged,
        VendorRequest::ReadConfig => match rest {
            [_, baud_code, ..] => VendorResponse::Config {
                baud_code: *baud_code,
            },
            _ => return Err(short),
        },
        VendorRequest::SetBaud(_) => VendorResponse::BaudChanged,
        VendorRequest::ReadFirmware => match rest {
            [year, month, day, ..] => VendorResponse::Firmware {
                year: *year,
                month: *month,
                day: *day,
            },
            _ => return Err(short),
        },
        VendorRequest::ReadResetFlag => match rest {
            [d, ..] => VendorResponse::ResetFlag(flag(*d)?),
            _ => return Err(short),
        },
        VendorRequest::Reset => VendorResponse::ResetDone,
        VendorRequest::SetWatchdog(_) => VendorResponse::WatchdogSet,
        VendorRequest::ReadWatchdog => match rest {
            [en, wt, ..] => VendorResponse::Watchdog {
                enabled: flag(*en)?,
                tenths: *wt,
            },
            _ => return Err(short),
        },
        VendorRequest::SetLedMode(_) => VendorResponse::LedModeSet,
        VendorRequest::SetPowerOnValue(_) => VendorResponse::PowerOnValueSet,
        VendorRequest::ReadPowerOnValue => match rest {
            [v, ..] => VendorResponse::PowerOnValue(*v),
            _ => return Err(short),
        },
        VendorRequest::SetSafeValue(_) => VendorResponse::SafeValueSet,
        VendorRequest::ReadSafeValue => match rest {
            [v, ..] => VendorResponse::SafeValue(*v),
            _ => return Err(short),
        },
        VendorRequest::HostOk => return Err("host OK is never answered"),
    })
}

#[cfg(test)]
mod tests {
    use super::super::request::vendor_answer_len;
    use super::*;
    use crate::protocol::c29u_modbus::BitArea;

    #[test]
    fn answer_lengths_match_the_encoder() {
        let samples = [
            VendorResponse::Name(0x0C29),
            VendorResponse::IdChanged,
            VendorResponse::Config { baud_code: 6 },
            VendorResponse::BaudChanged,
            VendorResponse::Firmware {
                year: 9,
                month: 7,
                day: 3,
            },
            VendorResponse::ResetFlag(true),
            VendorResponse::ResetDone,
            VendorResponse::WatchdogSet,
            VendorResponse::Watchdog {
                enabled: true,
                tenths: 15,
            },
            VendorResponse::LedModeSet,
            VendorResponse::PowerOnValueSet,
            VendorResponse::PowerOnValue(8),
            VendorResponse::SafeValueSet,
            VendorResponse::SafeValue(0x12),
        ];
        for v in samples {
            assert_eq!(
                Some(encode_response(1, &Response::Vendor(v)).len()),
                vendor_answer_len(v.sub()),
                "{v:?}"
            );
        }
        let r = Request::read_counters(3);
        let a = encode_response(
            1,
            &Response::Counters {
                function: CounterFunction::Input,
                values: vec![1, 2, 3],
            },
        );
        assert_eq!(Some(a.len()), r.answer_len());
    }

    #[test]
    fn model_names() {
        assert_eq!(model_name(0x0C29), "C29");
        assert_eq!(model_name(0x0000), "0");
        assert_eq!(model_name(0x1234), "1234");
    }

    #[test]
    fn typed_errors() {
        let req = Request::ReadBits(BitArea::Outputs);
        assert_eq!(
            parse_response(&req, 1, &seal(&[1, 0x81, 0x02])),
            Err(ModbusError::Exception {
                function: 0x01,
                code: ExceptionCode::StartChannel
            })
        );
        assert_eq!(
            parse_response(&req, 1, &seal(&[1, 0x03, 0x02, 0, 0])),
            Err(ModbusError::UnexpectedFunction {
                expected: 0x01,
                got: 0x03
            })
        );
        assert_eq!(
            parse_response(&req, 2, &seal(&[1, 0x01, 0x01, 0x00])),
            Err(ModbusError::WrongId {
                expected: 2,
                got: 1
            })
        );
        let mut bad = seal(&[1, 0x01, 0x01, 0x00]);
        bad[3] = 0xFF;
        assert_eq!(parse_response(&req, 1, &bad), Err(ModbusError::BadCrc));
        assert!(matches!(
            parse_response(&req, 1, &seal(&[1, 0x01, 0x02, 0x00, 0x00])),
            Err(ModbusError::Malformed { .. })
        ));
        assert!(matches!(
            parse_response(&req, 1, &[1, 0x01]),
            Err(ModbusError::Malformed { .. })
        ));
        assert_eq!(
            parse_response(
                &Request::Vendor(VendorRequest::HostOk),
                1,
                &seal(&[1, 0x46, 0x2F, 0x00])
            ),
            Err(ModbusError::NoAnswerExpected)
        );
        assert!(matches!(
            parse_response(
                &Request::Vendor(VendorRequest::ReadSafeValue),
                1,
                &seal(&[1, 0x46, 0x28, 0x12])
            ),
            Err(ModbusError::Malformed { .. })
        ));
    }

    #[test]
    fn safe_mode_is_its_own_error() {
        let req = Request::write_outputs(0x55);
        assert_eq!(
            parse_response(&req, 1, &seal(&[1, 0x8F, 0xFF])),
            Err(ModbusError::SafeMode { function: 0x0F })
        );
        assert_eq!(
            parse_response(&req, 1, &seal(&[1, 0x85, 0xFF])),
            Err(ModbusError::SafeMode { function: 0x0F })
        );
        // Another code from the other output function is no answer to this request.
        assert_eq!(
            parse_response(&req, 1, &seal(&[1, 0x85, 0x02])),
            Err(ModbusError::UnexpectedFunction {
                expected: 0x0F,
                got: 0x85
            })
        );
        // A read is never refused for safe mode with another function's code.
        assert_eq!(
            parse_response(
                &Request::ReadBits(BitArea::Outputs),
                1,
                &seal(&[1, 0x8F, 0xFF])
            ),
            Err(ModbusError::UnexpectedFunction {
                expected: 0x01,
                got: 0x8F
            })
        );
    }

    #[test]
    fn vendor_answers_tolerate_reserved_byte_differences() {
        let req = Request::Vendor(VendorRequest::ReadPowerOnValue);
        let expect = Ok(Response::Vendor(VendorResponse::PowerOnValue(0x08)));
        assert_eq!(
            parse_response(&req, 1, &seal(&[1, 0x46, 0x28, 0x08, 0x00])),
            expect
        );
        let req = Request::Vendor(VendorRequest::SetBaud(0x0A));
        let expect = Ok(Response::Vendor(VendorResponse::BaudChanged));
        assert_eq!(
            parse_response(&req, 1, &seal(&[1, 0x46, 0x06, 0x00])),
            expect
        );
        assert_eq!(
            parse_response(&req, 1, &seal(&[1, 0x46, 0x06, 0, 0, 0, 0, 0, 0, 0, 0])),
            expect
        );
        assert_eq!(parse_response(&req, 1, &seal(&[1, 0x46, 0x06])), expect);
    }
}
