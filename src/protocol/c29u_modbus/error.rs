//! Exception codes and the typed errors of the Modbus codec (10-16..10-20).

use std::fmt;

/// The code byte of an exception answer `ID FC|80 CODE` (10-16..10-20).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ExceptionCode {
    /// 00: syntax error.
    Syntax,
    /// 01: data format error.
    DataFormat,
    /// 02: start channel error.
    StartChannel,
    /// 03: I/O out of range.
    Range,
    /// FF: the host watchdog has fired; outputs cannot change until it is disabled.
    SafeMode,
    /// Any code the manual does not list.
    Other(u8),
}

impl ExceptionCode {
    /// The code for a byte on the wire.
    pub fn from_byte(byte: u8) -> Self {
        match byte {
            0x00 => Self::Syntax,
            0x01 => Self::DataFormat,
            0x02 => Self::StartChannel,
            0x03 => Self::Range,
            0xFF => Self::SafeMode,
            other => Self::Other(other),
        }
    }

    /// The byte sent on the wire.
    pub fn to_byte(self) -> u8 {
        match self {
            Self::Syntax => 0x00,
            Self::DataFormat => 0x01,
            Self::StartChannel => 0x02,
            Self::Range => 0x03,
            Self::SafeMode => 0xFF,
            Self::Other(b) => b,
        }
    }
}

impl fmt::Display for ExceptionCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let what = match self {
            Self::Syntax => "syntax error",
            Self::DataFormat => "data format error",
            Self::StartChannel => "start channel error",
            Self::Range => "I/O out of range",
            Self::SafeMode => "module in safe mode",
            Self::Other(_) => "unknown exception",
        };
        write!(f, "{what} ({:02X})", self.to_byte())
    }
}

/// Why an answer frame could not be taken as the answer to the request that was sent.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ModbusError {
    /// The frame's CRC does not match its contents.
    #[error("answer has a bad CRC")]
    BadCrc,
    /// The answer came from another slave ID.
    #[error("answer from slave {got}, expected slave {expected}")]
    WrongId {
        /// The ID the request was sent to.
        expected: u8,
        /// The ID in the answer.
        got: u8,
    },
    /// An output write was refused because the host watchdog has fired (`ID 85 FF`, `ID 8F FF`).
    #[error("module in safe mode: output write refused (function {function:02X}); disable the watchdog to leave it")]
    SafeMode {
        /// The function code of the refused request.
        function: u8,
    },
    /// The module answered with an exception (`ID FC|80 CODE`).
    #[error("module refused function {function:02X}: {code}")]
    Exception {
        /// The function code of the refused request.
        function: u8,
        /// Why it refused.
        code: ExceptionCode,
    },
    /// The module refused a vendor function 46 command (`ID C6 00`).
    #[error("module refused the vendor (46) command")]
    VendorError,
    /// The answer carries a function code that belongs to neither the request nor its exception.
    #[error("answer has function {got:02X}, expected {expected:02X}")]
    UnexpectedFunction {
        /// The request's function code.
        expected: u8,
        /// The function code in the answer.
        got: u8,
    },
    /// The frame has a good CRC but not the layout the request calls for.
    #[error("malformed answer ({reason}): {bytes:02X?}")]
    Malformed {
        /// What is wrong with it.
        reason: &'static str,
        /// The whole frame as received.
        bytes: Vec<u8>,
    },
    /// The request gets no answer at all (46 2F host OK), so there is nothing to parse.
    #[error("this request gets no answer")]
    NoAnswerExpected,
}

/// Why the module does not act on a request frame; some of these are answered, some are silence.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RequestError {
    /// Bad CRC or too short to hold an ID, a function code and a CRC: the module stays silent (9-1).
    #[error("request has a bad CRC or is too short")]
    BadCrc,
    /// A standard function the module understands but whose contents it refuses.
    #[error("request to slave {id} for function {function:02X} refused: {code}")]
    Exception {
        /// The slave ID the request was sent to.
        id: u8,
        /// The request's function code.
        function: u8,
        /// The exception code to answer with.
        code: ExceptionCode,
    },
    /// A vendor function 46 request with an unknown sub-function or missing data: `ID C6 00`.
    #[error("vendor request to slave {id} refused")]
    VendorError {
        /// The slave ID the request was sent to.
        id: u8,
    },
}

impl RequestError {
    /// The slave ID the refused request was addressed to (None when the frame was unreadable).
    pub fn id(&self) -> Option<u8> {
        match self {
            Self::BadCrc => None,
            Self::Exception { id, .. } | Self::VendorError { id } => Some(*id),
        }
    }

    /// The frame the addressed module answers with; None means it stays silent.
    pub fn answer(&self) -> Option<Vec<u8>> {
        match *self {
            Self::BadCrc => None,
            Self::Exception { id, function, code } => {
                Some(super::encode_exception(id, function, code))
            }
            Self::VendorError { id } => Some(super::encode_vendor_error(id)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exception_codes_round_trip_every_byte() {
        for b in 0..=255u8 {
            assert_eq!(ExceptionCode::from_byte(b).to_byte(), b);
        }
        assert_eq!(ExceptionCode::from_byte(0xFF), ExceptionCode::SafeMode);
        assert_eq!(ExceptionCode::from_byte(0x03), ExceptionCode::Range);
    }

    #[test]
    fn refused_requests_answer_with_the_right_frame() {
        let e = RequestError::Exception {
            id: 1,
            function: 0x05,
            code: ExceptionCode::SafeMode,
        };
        assert_eq!(e.id(), Some(1));
        assert_eq!(e.answer().unwrap()[..3], [0x01, 0x85, 0xFF]);
        assert_eq!(
            RequestError::VendorError { id: 2 }.answer().unwrap()[..3],
            [0x02, 0xC6, 0x00]
        );
        assert_eq!(RequestError::BadCrc.answer(), None);
    }
}
