//! Requests of sections 8-1 to 8-26: typed values, their encoding, and decoding for the simulator.

use super::frame::{self, hex_byte, hex_pair, push_hex};
use super::types::{Address, BaudCode, Channel, DataFormat, LatchLevel, ModuleName, Preset};

/// The longest request, leading code to command, without checksum and CR: 8-1's
/// `%IDNNPPBBDD` (8-17's `~IDONN` with a six-character name is one shorter).
pub const LONGEST_REQUEST: usize = 11;

/// The digital I/O type PP that `%` carries and `$ID2` reports (8-1).
pub const MODULE_TYPE: u8 = 0x40;

/// One command to a TRP-C29U in ASCII mode (section 8, as docs/trp-c29u-protocol.md reads it).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Request {
    /// 8-1 `%IDNNPPBBDD`: new ID, baud code and data format (PP is always 40).
    Configure {
        /// NN, the new ID.
        new_id: u8,
        /// BB.
        baud: BaudCode,
        /// DD as 8-3 sets it.
        format: DataFormat,
    },
    /// 8-4 `#ID00DD` (also read from PP `0A`): all eight outputs, bit n = DOn.
    WriteOutputs(u8),
    /// 8-4 `#ID1LDD`: one output, DD `01` on or `00` off.
    WriteOutput {
        /// L.
        channel: Channel,
        /// DD = 01.
        on: bool,
    },
    /// 8-5 `#IDN`: one input counter.
    ReadCounter(Channel),
    /// 8-6 `#IDCN`: clear one input counter.
    ClearCounter(Channel),
    /// 8-7 `#IDCW`: clear all input counters.
    ClearCounters,
    /// 8-8 `#IDCS`: save all counters to EEPROM.
    SaveCounters,
    /// 8-9 `$IDL0` / `$IDL1`: read the latched inputs.
    ReadLatch(LatchLevel),
    /// 8-10 `$IDC`: clear the latches.
    ClearLatch,
    /// 8-11 `$ID6`: read outputs and inputs.
    ReadDio,
    /// 8-12 `$ID2`: read the configuration.
    ReadConfig,
    /// 8-13 `$IDRS`: reset the module.
    Reset,
    /// 8-14 `$IDM`: read the name.
    ReadName,
    /// 8-15 `$IDF`: read the firmware version.
    ReadFirmware,
    /// 8-16 `$ID5`: read (and clear) the reset flag.
    ReadResetStatus,
    /// 8-17 `~IDO` + name: rename the module.
    SetName(ModuleName),
    /// 8-18 `~IDLEDA`: LED mode, A = 1 (`true`) or 0.
    SetLedMode(bool),
    /// 8-19 `~IDWENN`: enable the host watchdog, NN x 0.1 s (00 disables, per 8-19's example).
    EnableWatchdog(u8),
    /// 8-20 `~IDWD`: disable the host watchdog (also leaves safe mode).
    DisableWatchdog,
    /// 8-21 `~IDWR`: read the watchdog state and timeout.
    ReadWatchdog,
    /// 8-22 `~**`: host OK, restarts every module's watchdog countdown; nobody answers.
    HostOk,
    /// 8-23 `~ID4P` / `~ID4S`: read the power-on or safe value.
    ReadPreset(Preset),
    /// 8-24 `~ID5P` / `~ID5S`: store the current outputs as the power-on or safe value.
    SavePreset(Preset),
    /// 8-25 `#**` (8-26 writes `###`): every module remembers its outputs and inputs; nobody
    /// answers.
    Synchronize,
    /// 8-26 `$ID4`: read the synchronized data `#**` made the module remember.
    ReadSynchronized,
}

impl Request {
    /// The frame for module `id` (ignored by broadcasts), with or without a checksum, CR included.
    pub fn encode(&self, id: u8, checksum: bool) -> Vec<u8> {
        let mut out = Vec::with_capacity(16);
        match self {
            Request::Configure {
                new_id,
                baud,
                format,
            } => {
                simple(&mut out, id, b'%', b"");
                for b in [*new_id, MODULE_TYPE, baud.code(), format.to_byte()] {
                    push_hex(&mut out, b);
                }
            }
            Request::WriteOutputs(value) => {
                simple(&mut out, id, b'#', b"");
                out.extend_from_slice(b"00");
                push_hex(&mut out, *value);
            }
            Request::WriteOutput { channel, on } => {
                simple(&mut out, id, b'#', b"");
                out.extend_from_slice(&[
                    b'1',
                    channel.digit(),
                    b'0',
                    if *on { b'1' } else { b'0' },
                ]);
            }
            Request::ReadCounter(ch) => {
                simple(&mut out, id, b'#', b"");
                out.push(ch.digit());
            }
            Request::ClearCounter(ch) => {
                simple(&mut out, id, b'#', b"");
                out.extend_from_slice(&[b'C', ch.digit()]);
            }
            Request::ClearCounters => {
                simple(&mut out, id, b'#', b"");
                out.extend_from_slice(b"CW");
            }
            Request::SaveCounters => {
                simple(&mut out, id, b'#', b"");
                out.extend_from_slice(b"CS");
            }
            Request::ReadLatch(level) => {
                simple(&mut out, id, b'$', b"");
                out.extend_from_slice(match level {
                    LatchLevel::Low => b"L0",
                    LatchLevel::High => b"L1",
                });
            }
            Request::ClearLatch => simple(&mut out, id, b'$', b"C"),
            Request::ReadDio => simple(&mut out, id, b'$', b"6"),
            Request::ReadConfig => simple(&mut out, id, b'$', b"2"),
            Request::Reset => simple(&mut out, id, b'$', b"RS"),
            Request::ReadName => simple(&mut out, id, b'$', b"M"),
            Request::ReadFirmware => simple(&mut out, id, b'$', b"F"),
            Request::ReadResetStatus => simple(&mut out, id, b'$', b"5"),
            Request::ReadSynchronized => simple(&mut out, id, b'$', b"4"),
            Request::SetName(name) => {
                simple(&mut out, id, b'~', b"O");
                out.extend_from_slice(name.as_str().as_bytes());
            }
            Request::SetLedMode(on) => {
                simple(&mut out, id, b'~', if *on { b"LED1" } else { b"LED0" });
            }
            Request::EnableWatchdog(tenths) => {
                simple(&mut out, id, b'~', b"WE");
                push_hex(&mut out, *tenths);
            }
            Request::DisableWatchdog => simple(&mut out, id, b'~', b"WD"),
            Request::ReadWatchdog => simple(&mut out, id, b'~', b"WR"),
            Request::ReadPreset(p) => simple(&mut out, id, b'~', &[b'4', p.letter()]),
            Request::SavePreset(p) => simple(&mut out, id, b'~', &[b'5', p.letter()]),
            Request::HostOk => out.extend_from_slice(b"~**"),
            Request::Synchronize => out.extend_from_slice(b"#**"),
        }
        frame::close(out, checksum)
    }

    /// False for the broadcasts `~**` and `#**`, which no module answers.
    pub fn expects_answer(&self) -> bool {
        !self.is_broadcast()
    }

    /// True for `~**` and `#**`, which carry no ID.
    pub fn is_broadcast(&self) -> bool {
        matches!(self, Request::HostOk | Request::Synchronize)
    }

    /// True for 8-4's output writes, answered by `>` when done.
    pub fn is_output_write(&self) -> bool {
        matches!(self, Request::WriteOutputs(_) | Request::WriteOutput { .. })
    }
}

fn simple(out: &mut Vec<u8>, id: u8, lead: u8, body: &[u8]) {
    out.push(lead);
    push_hex(out, id);
    out.extend_from_slice(body);
}

/// Why a frame is not a request the module carries out; [`RequestError::refusal`] says what the
/// module answers.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RequestError {
    /// The checksum is wrong or missing: the module stays silent.
    #[error("bad checksum: expected {expected:02X}, got {}", got.map_or("no hex digits".to_string(), |g| format!("{g:02X}")))]
    BadChecksum {
        /// The checksum of the characters before the last two.
        expected: u8,
        /// The last two characters read as hex, if they were hex.
        got: Option<u8>,
    },
    /// No leading code and ID to answer to: the module stays silent.
    #[error("not a request ({why}): {}", bytes.escape_ascii())]
    Malformed {
        /// The frame as received.
        bytes: Vec<u8>,
        /// What is wrong with it.
        why: &'static str,
    },
    /// An addressed frame that is no command of section 8: the module answers `?ID`.
    #[error("unknown command for {address}")]
    UnknownCommand {
        /// Who it was for.
        address: Address,
    },
    /// A known command with a parameter out of range: `!ID` for an output write (8-4), `?ID`
    /// for any other command.
    #[error("bad parameter for {address} ({why})")]
    BadParameter {
        /// Who it was for.
        address: Address,
        /// The command was an 8-4 output write.
        output_write: bool,
        /// What is wrong.
        why: &'static str,
    },
}

/// The answers a module gives instead of carrying out a request.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Refusal {
    /// `?ID`: command invalid.
    InvalidCommand,
    /// `!ID` to an output write: parameter error (8-4).
    ParameterError,
    /// `!IDWE` to an output write: the watchdog has fired, outputs are frozen (8-19).
    SafeMode,
}

impl RequestError {
    /// What the module with ID `id` answers, if anything: silence for bad checksums, malformed
    /// frames, broadcasts and other IDs.
    pub fn refusal(&self, id: u8) -> Option<Refusal> {
        let (address, refusal) = match self {
            RequestError::BadChecksum { .. } | RequestError::Malformed { .. } => return None,
            RequestError::UnknownCommand { address } => (address, Refusal::InvalidCommand),
            RequestError::BadParameter {
                address,
                output_write: true,
                ..
            } => (address, Refusal::ParameterError),
            RequestError::BadParameter { address, .. } => (address, Refusal::InvalidCommand),
        };
        (*address == Address::Id(id)).then_some(refusal)
    }
}

/// Reads one request frame (CR optional) as a module with checksums `checksum` would.
pub fn decode_request(frame: &[u8], checksum: bool) -> Result<(Address, Request), RequestError> {
    let body = frame::open(frame, checksum).map_err(|f| RequestError::BadChecksum {
        expected: f.expected,
        got: f.got,
    })?;
    let malformed = |why| RequestError::Malformed {
        bytes: frame.to_vec(),
        why,
    };
    let (lead, rest) = match body {
        [lead, rest @ ..] => (*lead, rest),
        [] => return Err(malformed("empty")),
    };
    match (lead, rest) {
        (b'~', b"**") => return Ok((Address::Broadcast, Request::HostOk)),
        // 8-25 writes `#**`, 8-26's example `###`: both are the same broadcast.
        (b'#', b"**" | b"##") => return Ok((Address::Broadcast, Request::Synchronize)),
        _ => {}
    }
    let (id, cmd) = match rest {
        [hi, lo, cmd @ ..] => (
            hex_pair(*hi, *lo).ok_or_else(|| malformed("no hex ID"))?,
            cmd,
        ),
        _ => return Err(malformed("too short for an ID")),
    };
    let address = Address::Id(id);
    let request = match lead {
        b'%' => decode_configure(cmd),
        b'#' => decode_hash(cmd),
        b'$' => decode_dollar(cmd),
        b'~' => decode_tilde(cmd),
        _ => return Err(malformed("unknown leading code")),
    };
    request.map(|r| (address, r)).map_err(|fault| match fault {
        DecodeFault::Unknown => RequestError::UnknownCommand { address },
        DecodeFault::Param { why, output_write } => RequestError::BadParameter {
            address,
            output_write,
            why,
        },
    })
}

enum DecodeFault {
    Unknown,
    Param {
        why: &'static str,
        output_write: bool,
    },
}

fn param(why: &'static str) -> DecodeFault {
    DecodeFault::Param {
        why,
        output_write: false,
    }
}

fn output_param(why: &'static str) -> DecodeFault {
    DecodeFault::Param {
        why,
        output_write: true,
    }
}

fn decode_configure(cmd: &[u8]) -> Result<Request, DecodeFault> {
    let [n1, n2, p1, p2, b1, b2, d1, d2] = cmd else {
        return Err(param("%: NNPPBBDD must be 8 hex digits"));
    };
    let byte = |h, l| hex_pair(h, l).ok_or(param("%: not hex"));
    let new_id = byte(*n1, *n2)?;
    if byte(*p1, *p2)? != MODULE_TYPE {
        return Err(param("%: I/O type PP must be 40"));
    }
    let baud = BaudCode::new(byte(*b1, *b2)?).ok_or(param("%: baud code outside 03..0A"))?;
    let format = DataFormat::from_byte(byte(*d1, *d2)?).ok_or(param("%: reserved format bits"))?;
    Ok(Request::Configure {
        new_id,
        baud,
        format,
    })
}

fn decode_hash(cmd: &[u8]) -> Result<Request, DecodeFault> {
    match cmd {
        b"CW" => Ok(Request::ClearCounters),
        b"CS" => Ok(Request::SaveCounters),
        [b'C', n] => Channel::from_digit(*n)
            .map(Request::ClearCounter)
            .ok_or(param("#IDCN: channel outside 0..7")),
        [n] if n.is_ascii_digit() => Channel::from_digit(*n)
            .map(Request::ReadCounter)
            .ok_or(param("#IDN: channel outside 0..7")),
        // Any four characters are 8-4's #IDPPDD: a bad PP or DD is its parameter error.
        [p1, p2, d1, d2] => {
            let value = hex_pair(*d1, *d2).ok_or(output_param("#IDPPDD: DD not hex"))?;
            match [*p1, p2.to_ascii_uppercase()] {
                [b'0', b'0'] | [b'0', b'A'] => Ok(Request::WriteOutputs(value)),
                [b'1', l] => {
                    let channel =
                        Channel::from_digit(l).ok_or(output_param("#ID1L: L outside 0..7"))?;
                    match value {
                        0 | 1 => Ok(Request::WriteOutput {
                            channel,
                            on: value == 1,
                        }),
                        _ => Err(output_param("#ID1LDD: DD must be 00 or 01")),
                    }
                }
                _ => Err(output_param("#IDPPDD: PP must be 00, 0A or 1L")),
            }
        }
        _ => Err(DecodeFault::Unknown),
    }
}

fn decode_dollar(cmd: &[u8]) -> Result<Request, DecodeFault> {
    match cmd {
        b"L0" => Ok(Request::ReadLatch(LatchLevel::Low)),
        b"L1" => Ok(Request::ReadLatch(LatchLevel::High)),
        [b'L', _] => Err(param("$IDLS: S must be 0 or 1")),
        b"C" => Ok(Request::ClearLatch),
        b"6" => Ok(Request::ReadDio),
        b"2" => Ok(Request::ReadConfig),
        b"RS" => Ok(Request::Reset),
        b"M" => Ok(Request::ReadName),
        b"F" => Ok(Request::ReadFirmware),
        b"5" => Ok(Request::ReadResetStatus),
        b"4" => Ok(Request::ReadSynchronized),
        _ => Err(DecodeFault::Unknown),
    }
}

fn decode_tilde(cmd: &[u8]) -> Result<Request, DecodeFault> {
    match cmd {
        [b'O', name @ ..] => ModuleName::from_bytes(name)
            .map(Request::SetName)
            .ok_or(param("~IDO: name must be 1..6 printable characters")),
        b"LED0" => Ok(Request::SetLedMode(false)),
        b"LED1" => Ok(Request::SetLedMode(true)),
        [b'L', b'E', b'D', ..] => Err(param("~IDLEDA: A must be 0 or 1")),
        [b'W', b'E', nn @ ..] => hex_byte(nn)
            .map(Request::EnableWatchdog)
            .ok_or(param("~IDWENN: NN must be 2 hex digits")),
        b"WD" => Ok(Request::DisableWatchdog),
        b"WR" => Ok(Request::ReadWatchdog),
        [b'4', v] => Preset::from_letter(*v)
            .map(Request::ReadPreset)
            .ok_or(param("~ID4V: V must be P or S")),
        [b'5', v] => Preset::from_letter(*v)
            .map(Request::SavePreset)
            .ok_or(param("~ID5V: V must be P or S")),
        _ => Err(DecodeFault::Unknown),
    }
}
