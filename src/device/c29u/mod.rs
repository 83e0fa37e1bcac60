//! The TRP-C29U driver: one API over both of the module's protocols (ASCII and Modbus RTU),
//! chosen by configuration, on a serial line that several modules may share.

mod ascii;
mod modbus;
mod transport;

pub use crate::link::line::FrameGap;
pub use crate::protocol::c29u::{CounterEdge, Protocol, WatchdogTimeout};
pub use crate::protocol::c29u_ascii::Preset;
pub use transport::{share, SharedLink};

use crate::device::cancel::Cancel;
use crate::device::exchange::{format_frame, ExchangeError, Tracer};
use crate::link::{serial::SerialLink, tcp::TcpLink, LinkError};
use crate::protocol::c29u_modbus::SLAVE_IDS;
use crate::time::clock::SharedClock;
use std::time::Duration;
use transport::{AttemptFault, Transport};

/// How to reach one module and how patiently.
#[derive(Debug, Clone, PartialEq)]
pub struct C29uOptions {
    /// The protocol its DIP switch selects.
    pub protocol: Protocol,
    /// Its ID (ASCII 0-255, Modbus 1-247).
    pub id: u8,
    /// Line speed.
    pub baud: u32,
    /// ASCII only: checksums on commands and answers.
    pub checksum: bool,
    /// Wait for one answer.
    pub timeout: Duration,
    /// Further attempts after a timeout or a garbled answer.
    pub retries: u32,
    /// Inputs read 0 on the wire when energized (8-11, 10-17: true for the real module).
    pub di_active_low: bool,
    /// Silence kept on a serial line before each request to this module.
    pub frame_gap: FrameGap,
}

impl Default for C29uOptions {
    fn default() -> Self {
        Self {
            protocol: Protocol::Modbus,
            id: 1,
            baud: 9600,
            checksum: false,
            timeout: Duration::from_millis(200),
            retries: 2,
            di_active_low: true,
            frame_gap: FrameGap::Auto,
        }
    }
}

/// Why a request to a module failed, in words that say what to try.
#[derive(Debug, thiserror::Error)]
pub enum C29uError {
    /// The link failed (port missing, permission, unplugged).
    #[error(transparent)]
    Link(#[from] LinkError),
    /// No complete answer in time.
    #[error("no answer from TRP-C29U ID {id} on {port} to {request} within {timeout:?}{}; check the ID, protocol, baud rate and wiring (`rigscript scan` finds modules)", received_note(received, *text))]
    Timeout {
        /// The link.
        port: String,
        /// The module's ID.
        id: u8,
        /// The request in words.
        request: String,
        /// How long it waited.
        timeout: Duration,
        /// What did arrive, if anything.
        received: Vec<u8>,
        /// The protocol is text (ASCII): show what arrived as text too.
        text: bool,
    },
    /// An answer arrived but could not be read.
    #[error("garbled answer from TRP-C29U ID {id} on {port} to {request}: {detail}; check for noise on the line or another master")]
    Garbled {
        /// The link.
        port: String,
        /// The module's ID.
        id: u8,
        /// The request in words.
        request: String,
        /// What was wrong.
        detail: String,
    },
    /// The module's host watchdog fired: it holds its safe value and refuses output writes.
    #[error("TRP-C29U ID {id} on {port} is in safe mode (its host watchdog expired): it refuses output writes until the watchdog is disabled (`watchdog off`)")]
    SafeMode {
        /// The link.
        port: String,
        /// The module's ID.
        id: u8,
    },
    /// The module answered that it will not do this.
    #[error("TRP-C29U ID {id} on {port} refused {request}: {reason}")]
    Refused {
        /// The link.
        port: String,
        /// The module's ID.
        id: u8,
        /// The request in words.
        request: String,
        /// The module's reason.
        reason: String,
    },
    /// The protocol in use has no command for this.
    #[error("{what} is not available in the {protocol} protocol: {hint}")]
    Unsupported {
        /// What was asked.
        what: &'static str,
        /// The protocol in use.
        protocol: Protocol,
        /// What to do instead.
        hint: &'static str,
    },
    /// Storing a power-on or safe value over ASCII would drive the outputs to it (8-24: the module
    /// only stores its current outputs), and the caller did not allow that.
    #[error("storing the {} {value:#04x} in TRP-C29U ID {id} on {port} would drive its outputs to {value:#04x} (they are at {outputs:#04x}): over ASCII the module can only store its current outputs (manual 8-24). Store it by hand when the outputs may take that value: `rigscript c29 --port PORT --protocol ascii --id {id}{} {} {value:#04x} --drive-outputs`", preset_words(*preset), if *checksum { " --checksum" } else { "" }, preset_command(*preset))]
    PresetDrivesOutputs {
        /// The link.
        port: String,
        /// The module's ID.
        id: u8,
        /// Frames carry checksums (for the command shown).
        checksum: bool,
        /// Which value.
        preset: Preset,
        /// The value to store.
        value: u8,
        /// The outputs now.
        outputs: u8,
    },
    /// A caller's argument is out of range.
    #[error("{0}")]
    InvalidArgument(String),
    /// The caller's `Cancel` cut the exchange short (a run stopping): it says nothing of the
    /// module, which may or may not have acted on the request.
    #[error("{request} to TRP-C29U ID {id} on {port} was cut short: the caller stopped waiting")]
    Cancelled {
        /// The link.
        port: String,
        /// The module's ID.
        id: u8,
        /// The request in words.
        request: String,
    },
}

/// How many received bytes an error message shows.
const SHOWN_BYTES: usize = 32;

/// A preset in words, for messages.
fn preset_words(preset: Preset) -> &'static str {
    match preset {
        Preset::PowerOn => "power-on value",
        Preset::Safe => "safe value",
    }
}

/// The `c29` command that stores a preset.
fn preset_command(preset: Preset) -> &'static str {
    match preset {
        Preset::PowerOn => "power-on-value",
        Preset::Safe => "safe-value",
    }
}

/// Whether storing a power-on or safe value may drive the outputs to it: over ASCII the module
/// can only store its current outputs (8-24). Modbus stores a value directly either way.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PresetWrite {
    /// Store it only when the outputs already hold it (or over Modbus); otherwise refuse with
    /// [`C29uError::PresetDrivesOutputs`]. Outputs never take another value.
    KeepOutputs,
    /// Drive the outputs to the value, store it, and drive them back (`c29 --drive-outputs`).
    DriveOutputs,
}

fn received_note(received: &[u8], text: bool) -> String {
    if received.is_empty() {
        return " (nothing came back)".to_string();
    }
    let shown = received.get(..SHOWN_BYTES).unwrap_or(received);
    let frame = format_frame(crate::device::exchange::Direction::Received, shown, text);
    let frame = frame.trim_start_matches("<< ");
    if shown.len() < received.len() {
        format!(
            " (only this came back: {frame} ... {} bytes in all)",
            received.len()
        )
    } else {
        format!(" (only this came back: {frame})")
    }
}

impl C29uError {
    /// True when the module could not be reached at all (as opposed to answering "no").
    pub fn is_unreachable(&self) -> bool {
        match self {
            Self::Link(e) => matches!(
                e,
                LinkError::NotFound { .. }
                    | LinkError::PermissionDenied { .. }
                    | LinkError::Busy { .. }
                    | LinkError::NotSerial { .. }
                    | LinkError::Disconnected { .. }
            ),
            Self::Timeout { .. } => true,
            _ => false,
        }
    }
}

/// Outputs and inputs read together.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct IoState {
    /// DO byte, bit n = DOn on.
    pub outputs: u8,
    /// DI byte, bit n = DIn energized.
    pub inputs: u8,
    /// DI byte as the module sent it.
    pub inputs_raw: u8,
}

/// Latched inputs, bit n = DIn: logical (the input polarity applied, as for inputs) and as the
/// module reports them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct Latches {
    /// Channels energized since the last clear.
    pub energized: u8,
    /// Channels released since the last clear.
    pub released: u8,
    /// Channels latched at logic 0 on the wire.
    pub low: u8,
    /// Channels latched at logic 1 on the wire.
    pub high: u8,
}

/// The host watchdog as the module reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct WatchdogInfo {
    /// A timeout is set: counting down, or fired.
    pub enabled: bool,
    /// Timeout in 0.1 s steps (0 when disabled).
    pub timeout_tenths: u8,
    /// It has fired: outputs are at the safe value; `None` where the protocol does not say.
    pub expired: Option<bool>,
}

/// Firmware version.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct Firmware {
    /// What the module says, as text.
    pub text: String,
    /// The release date (year, month, day) when the answer carries one.
    pub date: Option<(u16, u8, u8)>,
}

/// The module's communication settings as it reports them.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct Settings {
    /// Its ID.
    pub id: u8,
    /// Line speed.
    pub baud: Option<u32>,
    /// ASCII checksums (ASCII only).
    pub checksum: Option<bool>,
    /// Counted edge (ASCII only).
    pub counter_edge: Option<CounterEdge>,
    /// Model code (ASCII only; 3 = TRP-C29U).
    pub model: Option<u8>,
}

/// A change of the module's settings; `None` keeps a setting as it is.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ConfigChange {
    /// New ID.
    pub id: Option<u8>,
    /// New line speed.
    pub baud: Option<u32>,
    /// ASCII checksums on or off.
    pub checksum: Option<bool>,
    /// Which edge the counters count.
    pub counter_edge: Option<CounterEdge>,
    /// Counters answered in hex (ASCII engineer mode).
    pub hex_counters: Option<bool>,
}

/// What `#**` made the module remember, read back with `$ID4` (8-25, 8-26).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct SynchronizedIo {
    /// First read since the `#**`.
    pub fresh: bool,
    /// DO byte then.
    pub outputs: u8,
    /// DI byte then, bit n = energized.
    pub inputs: u8,
}

/// What one protocol does for each operation; `C29u` checks arguments and converts polarity.
pub(crate) trait Backend: Send {
    fn id(&self) -> u8;
    fn read_io(&mut self, t: &mut Transport) -> Result<(u8, u8), C29uError>;
    fn read_outputs(&mut self, t: &mut Transport) -> Result<u8, C29uError>;
    fn read_inputs_raw(&mut self, t: &mut Transport) -> Result<u8, C29uError>;
    fn write_outputs(&mut self, t: &mut Transport, value: u8) -> Result<(), C29uError>;
    fn write_output(&mut self, t: &mut Transport, channel: u8, on: bool) -> Result<(), C29uError>;
    fn read_counter(&mut self, t: &mut Transport, channel: u8) -> Result<u16, C29uError>;
    fn read_counters(&mut self, t: &mut Transport) -> Result<[u16; 8], C29uError>;
    fn clear_counter(&mut self, t: &mut Transport, channel: u8) -> Result<(), C29uError>;
    fn clear_counters(&mut self, t: &mut Transport) -> Result<(), C29uError>;
    fn save_counters(&mut self, t: &mut Transport) -> Result<(), C29uError>;
    /// Latched low and latched high, as the module reports them.
    fn read_latches(&mut self, t: &mut Transport) -> Result<(u8, u8), C29uError>;
    fn clear_latches(&mut self, t: &mut Transport) -> Result<(), C29uError>;
    fn set_watchdog(&mut self, t: &mut Transport, tenths: u8) -> Result<(), C29uError>;
    fn watchdog(&mut self, t: &mut Transport) -> Result<WatchdogInfo, C29uError>;
    fn host_ok(&mut self, t: &mut Transport) -> Result<(), C29uError>;
    fn read_preset(&mut self, t: &mut Transport, preset: Preset) -> Result<u8, C29uError>;
    fn set_preset(
        &mut self,
        t: &mut Transport,
        preset: Preset,
        value: u8,
        how: PresetWrite,
    ) -> Result<(), C29uError>;
    fn save_outputs_as(&mut self, t: &mut Transport, preset: Preset) -> Result<(), C29uError>;
    fn name(&mut self, t: &mut Transport) -> Result<String, C29uError>;
    fn set_name(&mut self, t: &mut Transport, name: &str) -> Result<(), C29uError>;
    fn firmware(&mut self, t: &mut Transport) -> Result<Firmware, C29uError>;
    fn settings(&mut self, t: &mut Transport) -> Result<Settings, C29uError>;
    fn configure(&mut self, t: &mut Transport, change: &ConfigChange) -> Result<(), C29uError>;
    fn reset(&mut self, t: &mut Transport) -> Result<(), C29uError>;
    fn take_reset_flag(&mut self, t: &mut Transport) -> Result<bool, C29uError>;
    fn set_led_mode(&mut self, t: &mut Transport, on: bool) -> Result<(), C29uError>;
    fn synchronize(&mut self, t: &mut Transport) -> Result<(), C29uError>;
    fn read_synchronized(&mut self, t: &mut Transport) -> Result<SynchronizedIo, C29uError>;
    fn raw(&mut self, t: &mut Transport, body: &[u8]) -> Result<Vec<u8>, C29uError>;
}

/// One TRP-C29U module.
pub struct C29u {
    transport: Transport,
    backend: Box<dyn Backend>,
    options: C29uOptions,
}

fn check_channel(channel: u8) -> Result<u8, C29uError> {
    if channel < 8 {
        Ok(channel)
    } else {
        Err(C29uError::InvalidArgument(format!(
            "channel {channel} does not exist: use 0-7"
        )))
    }
}

/// Watchdog timeout in the module's 0.1 s steps (1-255), or why it cannot be one.
pub fn watchdog_tenths(timeout: Duration) -> Result<u8, C29uError> {
    WatchdogTimeout::from_duration(timeout)
        .map(WatchdogTimeout::tenths)
        .ok_or_else(|| {
            C29uError::InvalidArgument(format!(
                "watchdog timeout {timeout:?} is not possible: use 0.1 s to 25.5 s in 0.1 s steps"
            ))
        })
}

impl C29u {
    /// A driver for the module `options` describes, on a (possibly shared) line.
    pub fn new(
        link: SharedLink,
        clock: SharedClock,
        options: C29uOptions,
    ) -> Result<Self, C29uError> {
        let backend: Box<dyn Backend> = match options.protocol {
            Protocol::Ascii => Box::new(ascii::AsciiBackend::new(options.id, options.checksum)),
            Protocol::Modbus => {
                if !SLAVE_IDS.contains(&options.id) {
                    return Err(C29uError::InvalidArgument(format!(
                        "Modbus ID {} is not possible: use 1-247",
                        options.id
                    )));
                }
                Box::new(modbus::ModbusBackend::new(options.id, options.baud))
            }
        };
        Ok(Self {
            transport: Transport::new(
                link,
                clock,
                options.timeout,
                options.retries,
                options.protocol,
                options.frame_gap,
            ),
            backend,
            options,
        })
    }

    /// Opens `port` (a serial device path, or `tcp://host:port`) and makes a driver on it.
    pub fn open(port: &str, clock: SharedClock, options: C29uOptions) -> Result<Self, C29uError> {
        Self::new(
            share(open_port(port, options.baud, options.timeout)?),
            clock,
            options,
        )
    }

    /// Sends every frame and answer to `tracer` (`--trace`).
    pub fn set_tracer(&mut self, tracer: Option<Tracer>) {
        self.transport.set_tracer(tracer);
    }

    /// Cuts exchanges short once `cancel` is set (`C29uError::Cancelled`, never retried);
    /// `Cancel::never()` lets every exchange run its course.
    pub fn set_cancel(&mut self, cancel: Cancel) {
        self.transport.set_cancel(cancel);
    }

    /// The options in force (they follow configuration changes).
    pub fn options(&self) -> &C29uOptions {
        &self.options
    }

    /// The module in words, for messages: `TRP-C29U ID 1 on serial port ...`.
    pub fn describe(&self) -> String {
        format!(
            "TRP-C29U ID {} on {}",
            self.backend.id(),
            self.transport.port()
        )
    }

    fn logical(&self, raw: u8) -> u8 {
        if self.options.di_active_low {
            !raw
        } else {
            raw
        }
    }

    /// Outputs and inputs, in one transaction where the protocol has one.
    pub fn read_io(&mut self) -> Result<IoState, C29uError> {
        let (outputs, raw) = self.backend.read_io(&mut self.transport)?;
        Ok(IoState {
            outputs,
            inputs: self.logical(raw),
            inputs_raw: raw,
        })
    }

    /// Inputs, bit n = DIn energized.
    pub fn read_inputs(&mut self) -> Result<u8, C29uError> {
        let raw = self.backend.read_inputs_raw(&mut self.transport)?;
        Ok(self.logical(raw))
    }

    /// Inputs as the module sends them.
    pub fn read_inputs_raw(&mut self) -> Result<u8, C29uError> {
        self.backend.read_inputs_raw(&mut self.transport)
    }

    /// The DO byte.
    pub fn read_outputs(&mut self) -> Result<u8, C29uError> {
        self.backend.read_outputs(&mut self.transport)
    }

    /// Sets all eight outputs.
    pub fn write_outputs(&mut self, value: u8) -> Result<(), C29uError> {
        self.backend.write_outputs(&mut self.transport, value)
    }

    /// Sets one output.
    pub fn write_output(&mut self, channel: u8, on: bool) -> Result<(), C29uError> {
        let channel = check_channel(channel)?;
        self.backend.write_output(&mut self.transport, channel, on)
    }

    /// One input's counter.
    pub fn read_counter(&mut self, channel: u8) -> Result<u16, C29uError> {
        let channel = check_channel(channel)?;
        self.backend.read_counter(&mut self.transport, channel)
    }

    /// All eight counters.
    pub fn read_counters(&mut self) -> Result<[u16; 8], C29uError> {
        self.backend.read_counters(&mut self.transport)
    }

    /// Clears one counter.
    pub fn clear_counter(&mut self, channel: u8) -> Result<(), C29uError> {
        let channel = check_channel(channel)?;
        self.backend.clear_counter(&mut self.transport, channel)
    }

    /// Clears all counters.
    pub fn clear_counters(&mut self) -> Result<(), C29uError> {
        self.backend.clear_counters(&mut self.transport)
    }

    /// Saves all counters to EEPROM, so they survive a reset or power loss.
    pub fn save_counters(&mut self) -> Result<(), C29uError> {
        self.backend.save_counters(&mut self.transport)
    }

    /// The latched inputs.
    pub fn read_latches(&mut self) -> Result<Latches, C29uError> {
        let (low, high) = self.backend.read_latches(&mut self.transport)?;
        // An energized input is wire level 0 on an active-low module (8-11): it latches low.
        let (energized, released) = if self.options.di_active_low {
            (low, high)
        } else {
            (high, low)
        };
        Ok(Latches {
            energized,
            released,
            low,
            high,
        })
    }

    /// Clears the latches.
    pub fn clear_latches(&mut self) -> Result<(), C29uError> {
        self.backend.clear_latches(&mut self.transport)
    }

    /// Enables the host watchdog with `timeout` (0.1-25.5 s), or disables it with `None`.
    pub fn set_watchdog(&mut self, timeout: Option<Duration>) -> Result<(), C29uError> {
        let tenths = match timeout {
            Some(t) => watchdog_tenths(t)?,
            None => 0,
        };
        self.backend.set_watchdog(&mut self.transport, tenths)
    }

    /// The watchdog's state.
    pub fn watchdog(&mut self) -> Result<WatchdogInfo, C29uError> {
        self.backend.watchdog(&mut self.transport)
    }

    /// Host OK: restarts the watchdog countdown (no answer; in ASCII it reaches every module).
    pub fn host_ok(&mut self) -> Result<(), C29uError> {
        self.backend.host_ok(&mut self.transport)
    }

    /// The stored safe value.
    pub fn safe_value(&mut self) -> Result<u8, C29uError> {
        self.backend.read_preset(&mut self.transport, Preset::Safe)
    }

    /// Stores the safe value without the outputs taking another value: over ASCII only when
    /// they hold it already (see [`PresetWrite::KeepOutputs`]).
    pub fn set_safe_value(&mut self, value: u8) -> Result<(), C29uError> {
        self.store_preset(Preset::Safe, value, PresetWrite::KeepOutputs)
    }

    /// The stored power-on value.
    pub fn power_on_value(&mut self) -> Result<u8, C29uError> {
        self.backend
            .read_preset(&mut self.transport, Preset::PowerOn)
    }

    /// Stores the power-on value without the outputs taking another value: over ASCII only
    /// when they hold it already (see [`PresetWrite::KeepOutputs`]).
    pub fn set_power_on_value(&mut self, value: u8) -> Result<(), C29uError> {
        self.store_preset(Preset::PowerOn, value, PresetWrite::KeepOutputs)
    }

    /// Stores the safe or power-on value; `how` says whether the outputs may be driven to it.
    pub fn store_preset(
        &mut self,
        preset: Preset,
        value: u8,
        how: PresetWrite,
    ) -> Result<(), C29uError> {
        self.backend
            .set_preset(&mut self.transport, preset, value, how)
    }

    /// Stores the current outputs as the safe or power-on value.
    pub fn save_outputs_as(&mut self, preset: Preset) -> Result<(), C29uError> {
        self.backend.save_outputs_as(&mut self.transport, preset)
    }

    /// The module's name.
    pub fn name(&mut self) -> Result<String, C29uError> {
        self.backend.name(&mut self.transport)
    }

    /// Renames the module (ASCII only; 1-6 printable characters).
    pub fn set_name(&mut self, name: &str) -> Result<(), C29uError> {
        self.backend.set_name(&mut self.transport, name)
    }

    /// Firmware version.
    pub fn firmware(&mut self) -> Result<Firmware, C29uError> {
        self.backend.firmware(&mut self.transport)
    }

    /// Communication settings as the module reports them.
    pub fn settings(&mut self) -> Result<Settings, C29uError> {
        self.backend.settings(&mut self.transport)
    }

    /// Changes the module's settings; the driver then talks to it with the new ones.
    pub fn configure(&mut self, change: &ConfigChange) -> Result<(), C29uError> {
        self.backend.configure(&mut self.transport, change)?;
        if let Some(id) = change.id {
            self.options.id = id;
        }
        if let Some(baud) = change.baud {
            self.options.baud = baud;
        }
        if let Some(checksum) = change.checksum {
            self.options.checksum = checksum;
        }
        Ok(())
    }

    /// Resets the module (outputs go to the power-on value, unsaved counts are lost).
    pub fn reset(&mut self) -> Result<(), C29uError> {
        self.backend.reset(&mut self.transport)
    }

    /// Reads (and so clears) the flag the module sets when it has been reset.
    pub fn take_reset_flag(&mut self) -> Result<bool, C29uError> {
        self.backend.take_reset_flag(&mut self.transport)
    }

    /// LED mode (8-18, 10-10).
    pub fn set_led_mode(&mut self, on: bool) -> Result<(), C29uError> {
        self.backend.set_led_mode(&mut self.transport, on)
    }

    /// Broadcasts `#**`: every module on the line remembers its outputs and inputs (ASCII only).
    pub fn synchronize(&mut self) -> Result<(), C29uError> {
        self.backend.synchronize(&mut self.transport)
    }

    /// Reads what `#**` made this module remember (ASCII only).
    pub fn read_synchronized(&mut self) -> Result<SynchronizedIo, C29uError> {
        let mut s = self.backend.read_synchronized(&mut self.transport)?;
        s.inputs = self.logical(s.inputs);
        Ok(s)
    }

    /// Sends one raw frame (ASCII text without ID framing rules applied; Modbus bytes without
    /// CRC), with the checksum or CRC appended, and returns the answer as received.
    /// A frame longer than the protocol's longest request is refused unsent (a long one
    /// holds the line for seconds and can be no request the module knows).
    pub fn raw(&mut self, body: &[u8]) -> Result<Vec<u8>, C29uError> {
        let (most, unit, what) = match self.options.protocol {
            Protocol::Ascii => (
                crate::protocol::c29u_ascii::LONGEST_REQUEST,
                "characters",
                "the longest ASCII request (manual 8-1), without checksum and CR",
            ),
            Protocol::Modbus => (
                crate::protocol::c29u_modbus::MAX_FRAME_LEN - 2,
                "bytes",
                "a Modbus RTU frame's 256 bytes less the CRC",
            ),
        };
        if body.len() > most {
            return Err(C29uError::InvalidArgument(format!(
                "a raw frame of {} {unit} is too long: at most {most} ({what})",
                body.len()
            )));
        }
        self.backend.raw(&mut self.transport, body)
    }
}

/// Opens a serial port path or a `tcp://host:port` serial device server.
pub fn open_port(
    port: &str,
    baud: u32,
    timeout: Duration,
) -> Result<Box<dyn crate::link::ByteLink>, LinkError> {
    let mut link: Box<dyn crate::link::ByteLink> = if port.starts_with(crate::link::tcp::SCHEME) {
        Box::new(TcpLink::connect(port, timeout.max(Duration::from_secs(2)))?)
    } else {
        Box::new(SerialLink::open(port, baud)?)
    };
    if let Some(line) = link.line() {
        line.just_opened = true;
    }
    Ok(link)
}

/// Turns the end of an exchange into a fault: silence is worth retrying, link failures are not.
pub(crate) fn exchange_fault(
    e: ExchangeError,
    port: &str,
    id: u8,
    request: &str,
    timeout: Duration,
    text: bool,
) -> AttemptFault {
    match e {
        ExchangeError::Link(e) => AttemptFault::Final(C29uError::Link(e)),
        ExchangeError::Timeout { received } => AttemptFault::Retry(C29uError::Timeout {
            port: port.to_string(),
            id,
            request: request.to_string(),
            timeout,
            received,
            text,
        }),
        ExchangeError::Overflow { received } => AttemptFault::Retry(C29uError::Garbled {
            port: port.to_string(),
            id,
            request: request.to_string(),
            detail: format!(
                "more bytes than any answer has and no answer among them{}",
                received_note(&received, text)
            ),
        }),
        ExchangeError::Busy { heard, within } => AttemptFault::Final(C29uError::Garbled {
            port: port.to_string(),
            id,
            request: request.to_string(),
            detail: format!(
                "the line never fell silent to let the request out ({heard} bytes in {within:?} from something else on it)"
            ),
        }),
        ExchangeError::Cancelled => AttemptFault::Final(C29uError::Cancelled {
            port: port.to_string(),
            id,
            request: request.to_string(),
        }),
    }
}

#[cfg(test)]
mod tests;
