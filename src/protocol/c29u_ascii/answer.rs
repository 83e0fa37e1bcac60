//! Answers to section 8's requests: parsing for the driver, encoding for the simulator.

use super::frame::{self, decimal_u16, hex_byte, hex_pair, hex_u16, push_hex};
use super::request::{Refusal, Request};
use super::types::{ConfigReport, FirmwareVersion, ModuleName, SynchronizedData};
use super::watchdog::WatchdogReading;

/// What a module answers when it carries out a request.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Answer {
    /// `!ID` with no data: done. After `%` the ID is the new one (`!NN`).
    Done,
    /// `>`: an output write is done (8-4).
    OutputWritten,
    /// 8-5 counter: 5 decimal digits, or 4 hex digits in engineer mode (`hex`).
    Counter {
        /// Edges counted, 0-65535.
        value: u16,
        /// The module answered 4 hex digits (data format bit 0).
        hex: bool,
    },
    /// 8-9 `$IDLS`: the latch byte, bit n = DIn (8-9 as read: the first of the 4 digits' bytes).
    Latch(u8),
    /// 8-11 `$ID6`: DO byte and DI byte as on the wire (energized = 0 bit: 8-11).
    Dio {
        /// AB: DO0..DO7.
        outputs: u8,
        /// CD: DI0..DI7, raw.
        inputs: u8,
    },
    /// 8-12 `$ID2`.
    Config(ConfigReport),
    /// 8-14 `$IDM`.
    Name(ModuleName),
    /// 8-15 `$IDF`.
    Firmware(FirmwareVersion),
    /// 8-16 `$ID5`: true = has been reset since the flag was last read.
    ResetStatus(bool),
    /// 8-18 `~IDLEDA`: `!IDON` (true) or `!IDOFF`.
    Led(bool),
    /// 8-21 `~IDWR`: `!IDWE` + NN, `!IDWD` + NN or a bare `!ID`, as [`WatchdogReading`] reads them.
    Watchdog(WatchdogReading),
    /// 8-23 `~ID4V`: `!IDABCD`, AB the stored DO value; CD is documented as DI0..DI7.
    Preset {
        /// AB: the stored power-on or safe DO value.
        outputs: u8,
        /// CD: the inputs byte the module adds (of no use to a driver).
        inputs: u8,
    },
    /// 8-26 `$ID4`: `!` + A + DO + DI + `00`, with or without the ID (8-26 as read).
    Synchronized(SynchronizedData),
}

/// Why an answer could not be taken as the answer to its request.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AsciiError {
    /// `?ID`: the module does not know the command.
    #[error("the module answered ?: command invalid")]
    InvalidCommand,
    /// `!ID` to an output write: parameter error (8-4). While the host watchdog has fired, the
    /// driver reports it as safe mode instead (see [`AsciiError::is_output_refusal`]).
    #[error("the module refused the output write: parameter error")]
    ParameterError,
    /// `!IDWE` to an output write: the module is in safe mode (8-19).
    #[error("the module is in safe mode (host watchdog fired): outputs are frozen until the watchdog is disabled")]
    SafeMode,
    /// Not an answer of the expected shape.
    #[error("malformed answer ({why}): {}", bytes.escape_ascii())]
    Malformed {
        /// The frame as received.
        bytes: Vec<u8>,
        /// What is wrong with it.
        why: &'static str,
    },
    /// An answer from another module.
    #[error("answer from id {got:02X}, expected {expected:02X}")]
    WrongId {
        /// The ID asked.
        expected: u8,
        /// The ID that answered.
        got: u8,
    },
    /// The answer's checksum is wrong or missing.
    #[error("bad checksum in answer: expected {expected:02X}, got {}", got.map_or("no hex digits".to_string(), |g| format!("{g:02X}")))]
    BadChecksum {
        /// The checksum of the characters before the last two.
        expected: u8,
        /// The last two characters read as hex, if they were hex.
        got: Option<u8>,
    },
    /// `~**` and `#**` have no answer to parse.
    #[error("broadcast requests have no answer")]
    NoAnswerExpected,
}

impl AsciiError {
    /// True when the module did answer an output write, but not with `>`: by 8-19, while
    /// the host watchdog has fired any such answer means "module in safe mode".
    pub fn is_output_refusal(&self) -> bool {
        matches!(
            self,
            AsciiError::InvalidCommand
                | AsciiError::ParameterError
                | AsciiError::SafeMode
                | AsciiError::Malformed { .. }
        )
    }

    /// The safe-mode rule (8-19 as read): an output write refused this way means the module is in
    /// safe mode when it says so (`!IDWE`) or when its watchdog, read after the refusal, has
    /// fired. A watchdog that is merely off (`WD00`) does not make a `?ID` safe mode.
    pub fn means_safe_mode(&self, watchdog: Option<WatchdogReading>) -> bool {
        *self == AsciiError::SafeMode
            || (self.is_output_refusal() && watchdog.is_some_and(WatchdogReading::fired))
    }
}

/// Reads `frame` (CR optional) as the answer of module `expected_id` to `request`. For `%` the
/// `!` answer carries the new ID and a `?` answer the old one.
pub fn parse_answer(
    request: &Request,
    frame: &[u8],
    checksum: bool,
    expected_id: u8,
) -> Result<Answer, AsciiError> {
    if !request.expects_answer() {
        return Err(AsciiError::NoAnswerExpected);
    }
    let body = frame::open(frame, checksum).map_err(|f| AsciiError::BadChecksum {
        expected: f.expected,
        got: f.got,
    })?;
    let malformed = |why| AsciiError::Malformed {
        bytes: frame.to_vec(),
        why,
    };
    let check_id = |expected: u8, got: u8| {
        if got == expected {
            Ok(())
        } else {
            Err(AsciiError::WrongId { expected, got })
        }
    };
    match body {
        [b'?', id @ ..] => {
            check_id(
                expected_id,
                hex_byte(id).ok_or_else(|| malformed("?: no hex ID"))?,
            )?;
            Err(AsciiError::InvalidCommand)
        }
        [b'>'] if request.is_output_write() => Ok(Answer::OutputWritten),
        [b'!', rest @ ..] if *request == Request::ReadSynchronized => {
            // 8-26's example `!1010E00` carries no ID; accept both forms.
            let data = match rest {
                [_, _, _, _, _, _, _] => rest,
                [hi, lo, data @ ..] if data.len() == 7 => {
                    check_id(
                        expected_id,
                        hex_pair(*hi, *lo).ok_or_else(|| malformed("no hex ID"))?,
                    )?;
                    data
                }
                _ => return Err(malformed("$ID4: expected A + 6 hex digits")),
            };
            parse_synchronized(data)
                .map(Answer::Synchronized)
                .ok_or_else(|| malformed("$ID4: expected A + 6 hex digits"))
        }
        [b'!', hi, lo, data @ ..] => {
            let got = hex_pair(*hi, *lo).ok_or_else(|| malformed("no hex ID"))?;
            let expected = match request {
                Request::Configure { new_id, .. } => *new_id,
                _ => expected_id,
            };
            check_id(expected, got)?;
            parse_data(request, data).map_err(|fault| match fault {
                DataFault::Refused(e) => e,
                DataFault::Shape(why) => malformed(why),
            })
        }
        _ => Err(malformed("expected !, ? or >")),
    }
}

enum DataFault {
    Refused(AsciiError),
    Shape(&'static str),
}

fn parse_data(request: &Request, data: &[u8]) -> Result<Answer, DataFault> {
    use DataFault::Shape;
    let two_bytes = |data: &[u8]| match data {
        [a, b, c, d] => Some((hex_pair(*a, *b)?, hex_pair(*c, *d)?)),
        _ => None,
    };
    match request {
        Request::WriteOutputs(_) | Request::WriteOutput { .. } => match data {
            [] => Err(DataFault::Refused(AsciiError::ParameterError)),
            b"WE" => Err(DataFault::Refused(AsciiError::SafeMode)),
            _ => Err(Shape("output write: expected >, !ID or !IDWE")),
        },
        Request::Configure { .. }
        | Request::ClearCounter(_)
        | Request::ClearCounters
        | Request::SaveCounters
        | Request::ClearLatch
        | Request::Reset
        | Request::SetName(_)
        | Request::EnableWatchdog(_)
        | Request::DisableWatchdog
        | Request::SavePreset(_) => match data {
            [] => Ok(Answer::Done),
            _ => Err(Shape("expected !ID alone")),
        },
        Request::ReadCounter(_) => match data.len() {
            5 => decimal_u16(data).map(|value| Answer::Counter { value, hex: false }),
            4 => hex_u16(data).map(|value| Answer::Counter { value, hex: true }),
            _ => None,
        }
        .ok_or(Shape("counter: expected 5 decimal or 4 hex digits")),
        Request::ReadLatch(_) => two_bytes(data)
            .map(|(latch, _)| Answer::Latch(latch))
            .ok_or(Shape("latch: expected 4 hex digits")),
        Request::ReadDio => two_bytes(data)
            .map(|(outputs, inputs)| Answer::Dio { outputs, inputs })
            .ok_or(Shape("DIO: expected 4 hex digits")),
        Request::ReadPreset(_) => two_bytes(data)
            .map(|(outputs, inputs)| Answer::Preset { outputs, inputs })
            .ok_or(Shape("preset: expected 4 hex digits")),
        Request::ReadConfig => match data {
            [p1, p2, b1, b2, d1, d2] => (|| {
                Some(Answer::Config(ConfigReport {
                    module_type: hex_pair(*p1, *p2)?,
                    baud_code: hex_pair(*b1, *b2)?,
                    format: hex_pair(*d1, *d2)?,
                }))
            })(),
            _ => None,
        }
        .ok_or(Shape("config: expected 6 hex digits")),
        Request::ReadName => ModuleName::from_bytes(data)
            .map(Answer::Name)
            .ok_or(Shape("name: expected 1..6 printable characters")),
        Request::ReadFirmware => FirmwareVersion::from_bytes(data)
            .map(Answer::Firmware)
            .ok_or(Shape("firmware: expected printable text")),
        Request::ReadResetStatus => match data {
            b"0" => Ok(Answer::ResetStatus(false)),
            b"1" => Ok(Answer::ResetStatus(true)),
            _ => Err(Shape("reset status: expected 0 or 1")),
        },
        Request::SetLedMode(_) => match data {
            b"ON" => Ok(Answer::Led(true)),
            b"OFF" => Ok(Answer::Led(false)),
            _ => Err(Shape("LED: expected ON or OFF")),
        },
        Request::ReadWatchdog => match data {
            // 8-21 lists a bare `!ID` beside `!IDWANN`: no timeout set.
            [] => Some(Answer::Watchdog(WatchdogReading::Off)),
            [b'W', state, nn @ ..] => {
                let enabled = match state {
                    b'E' => Some(true),
                    b'D' => Some(false),
                    _ => None,
                };
                enabled
                    .zip(hex_byte(nn))
                    .map(|(e, nn)| Answer::Watchdog(WatchdogReading::from_wire(e, nn)))
            }
            _ => None,
        }
        .ok_or(Shape(
            "watchdog: expected WE or WD + 2 hex digits, or nothing",
        )),
        Request::ReadSynchronized | Request::HostOk | Request::Synchronize => {
            Err(Shape("no ID-form answer for this request"))
        }
    }
}

fn parse_synchronized(data: &[u8]) -> Option<SynchronizedData> {
    match data {
        [a, o1, o2, i1, i2, z1, z2] => {
            let fresh = match a {
                b'1' => true,
                b'0' => false,
                _ => return None,
            };
            // The trailing pair is always 00 in the manual; any hex is tolerated and ignored.
            hex_pair(*z1, *z2)?;
            Some(SynchronizedData {
                fresh,
                outputs: hex_pair(*o1, *o2)?,
                inputs_wire: hex_pair(*i1, *i2)?,
            })
        }
        _ => None,
    }
}

/// The frame a module with ID `id` sends for `answer` (after `%`, pass the new ID). The `$ID4`
/// answer carries no ID, like 8-26's example.
pub fn encode_answer(answer: &Answer, id: u8, checksum: bool) -> Vec<u8> {
    let mut out = Vec::with_capacity(16);
    let bang = |out: &mut Vec<u8>| {
        out.push(b'!');
        push_hex(out, id);
    };
    match answer {
        Answer::OutputWritten => out.push(b'>'),
        Answer::Synchronized(s) => {
            out.push(b'!');
            out.push(if s.fresh { b'1' } else { b'0' });
            push_hex(&mut out, s.outputs);
            push_hex(&mut out, s.inputs_wire);
            out.extend_from_slice(b"00");
        }
        Answer::Done => bang(&mut out),
        Answer::Counter { value, hex } => {
            bang(&mut out);
            if *hex {
                for b in value.to_be_bytes() {
                    push_hex(&mut out, b);
                }
            } else {
                out.extend_from_slice(format!("{value:05}").as_bytes());
            }
        }
        Answer::Latch(latch) => {
            bang(&mut out);
            push_hex(&mut out, *latch);
            out.extend_from_slice(b"00");
        }
        Answer::Dio { outputs, inputs } | Answer::Preset { outputs, inputs } => {
            bang(&mut out);
            push_hex(&mut out, *outputs);
            push_hex(&mut out, *inputs);
        }
        Answer::Config(r) => {
            bang(&mut out);
            for b in [r.module_type, r.baud_code, r.format] {
                push_hex(&mut out, b);
            }
        }
        Answer::Name(name) => {
            bang(&mut out);
            out.extend_from_slice(name.as_str().as_bytes());
        }
        Answer::Firmware(fw) => {
            bang(&mut out);
            out.extend_from_slice(fw.text().as_bytes());
        }
        Answer::ResetStatus(reset) => {
            bang(&mut out);
            out.push(if *reset { b'1' } else { b'0' });
        }
        Answer::Led(on) => {
            bang(&mut out);
            out.extend_from_slice(if *on { b"ON" } else { b"OFF" });
        }
        Answer::Watchdog(reading) => {
            let (enabled, tenths) = reading.to_wire();
            bang(&mut out);
            out.extend_from_slice(if enabled { b"WE" } else { b"WD" });
            push_hex(&mut out, tenths);
        }
    }
    frame::close(out, checksum)
}

/// The frame a module with ID `id` sends instead of carrying out a request.
pub fn encode_refusal(refusal: Refusal, id: u8, checksum: bool) -> Vec<u8> {
    let mut out = Vec::with_capacity(8);
    out.push(match refusal {
        Refusal::InvalidCommand => b'?',
        Refusal::ParameterError | Refusal::SafeMode => b'!',
    });
    push_hex(&mut out, id);
    if refusal == Refusal::SafeMode {
        out.extend_from_slice(b"WE");
    }
    frame::close(out, checksum)
}
