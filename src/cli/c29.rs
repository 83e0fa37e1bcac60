//! `rigscript c29`: drive one TRP-C29U module by hand — inputs, outputs, counters, latches,
//! watchdog, presets, identity, configuration, raw frames and a live monitor.

mod monitor;
mod show;

use crate::cli::output::{
    run_command, stop_flag, CommandError, EXIT_FAILED, EXIT_UNREACHABLE, EXIT_USAGE,
};
use crate::cli::sim::{parse_byte, ProtocolArg};
use crate::device::c29u::{
    watchdog_tenths, C29u, C29uError, C29uOptions, ConfigChange, CounterEdge, FrameGap, Preset,
    PresetWrite, Protocol, WatchdogInfo,
};
use crate::device::exchange::{format_frame, Direction};
use crate::protocol::c29u::{baud_code, BAUD_CODES};
use crate::protocol::c29u_ascii::ModuleName;
use crate::time::clock::SystemClock;
use crate::time::duration::parse_duration;
use clap::{Args, Subcommand, ValueEnum};
use serde_json::{json, Value};
use show::{byte_row, byte_table, set_channels, tenths};
use std::io::Write;
use std::time::Duration;

/// Options and subcommand of `rigscript c29`.
#[derive(Debug, Args)]
#[command(
    args_override_self = true,
    after_help = "Exit status: 0 done, 1 the module refused or misbehaved, 2 usage error, \
                        3 the module cannot be reached (no port, port busy, not a serial port, \
                        no permission, no answer)."
)]
pub struct C29Args {
    /// Serial port (such as /dev/ttyUSB0) or serial device server (tcp://HOST:PORT) (required)
    #[arg(long, global = true, value_name = "PATH")]
    pub port: Option<String>,
    /// Protocol the module's DIP switch selects
    #[arg(long, global = true, value_enum, default_value = "modbus")]
    pub protocol: ProtocolArg,
    /// Module ID (Modbus 1-247, ASCII 0-255; decimal or 0x..)
    #[arg(long, global = true, value_name = "N", default_value = "1", value_parser = parse_byte)]
    pub id: u8,
    /// Line speed: 1200, 2400, 4800, 9600, 19200, 38400, 57600 or 115200
    #[arg(long, global = true, value_name = "B", default_value_t = 9600, value_parser = parse_baud)]
    pub baud: u32,
    /// ASCII: the module expects checksums (its data format bit 6)
    #[arg(long, global = true)]
    pub checksum: bool,
    /// How long to wait for each answer, in milliseconds
    #[arg(long, global = true, value_name = "MS", default_value_t = 200,
          value_parser = clap::value_parser!(u64).range(1..=60_000))]
    pub timeout: u64,
    /// Further attempts after no answer or a garbled one
    #[arg(long, global = true, value_name = "N", default_value_t = 2,
          value_parser = clap::value_parser!(u32).range(0..=20))]
    pub retries: u32,
    /// Silence kept on a serial line before each request: auto (Modbus t3.5, ASCII t1.5 at the
    /// baud rate) or a duration up to 1s for a module that needs more; nothing over tcp://
    #[arg(long, global = true, value_name = "auto|DUR", default_value = "auto",
          value_parser = FrameGap::parse)]
    pub frame_gap: FrameGap,
    /// Print one JSON document instead of text (monitor: one JSON object a line)
    #[arg(long, global = true)]
    pub json: bool,
    /// Print every frame sent and received on standard error (hex, and text for ASCII)
    #[arg(long, global = true)]
    pub trace: bool,
    /// What to do
    #[command(subcommand)]
    pub command: C29Command,
}

/// On or off.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum OnOff {
    /// On (also `1`, `true`).
    #[value(alias = "1", alias = "true")]
    On,
    /// Off (also `0`, `false`).
    #[value(alias = "0", alias = "false")]
    Off,
}

impl OnOff {
    fn is_on(self) -> bool {
        self == OnOff::On
    }
}

/// The edge the counters count.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum EdgeArg {
    /// When an input becomes energized (factory setting).
    Rising,
    /// When an input is released.
    Falling,
}

/// A watchdog setting: off, or a timeout.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WatchdogArg {
    /// Disable it.
    Off,
    /// Enable it with this timeout.
    Timeout(Duration),
}

/// Why setting a preset in ASCII may touch the outputs (shown under `safe-value` and `power-on-value`).
const PRESET_HELP: &str = "In ASCII the module can only store its current outputs (8-24): a \
                           value the outputs hold already is stored as it is; any other value \
                           is refused unless --drive-outputs is given, which writes the value \
                           to the outputs, stores it, and writes the previous outputs back (so \
                           whatever is wired to them sees that value for a moment). Modbus \
                           stores it directly and ignores the flag.";

/// The `c29` subcommands.
#[derive(Debug, Clone, Subcommand)]
pub enum C29Command {
    /// Show the inputs (DI) and outputs (DO)
    Status,
    /// Show the outputs, or set all eight from BYTE (such as 0x21, 33 or 0b00100001)
    Do {
        /// New output byte, bit n = DOn
        #[arg(value_parser = parse_byte)]
        byte: Option<u8>,
    },
    /// Switch one output on or off
    Set {
        /// Output channel 0-7
        #[arg(value_parser = clap::value_parser!(u8).range(0..=7))]
        channel: u8,
        /// on or off
        #[arg(value_enum)]
        state: OnOff,
    },
    /// Show the eight input counters
    Counters,
    /// Clear one input counter, or all of them
    ClearCounters {
        /// Channel 0-7 (all when left out)
        #[arg(value_parser = clap::value_parser!(u8).range(0..=7))]
        channel: Option<u8>,
    },
    /// Save the counters to EEPROM so they survive a reset or power loss
    SaveCounters,
    /// Show the latched inputs
    Latch,
    /// Clear the latched inputs
    ClearLatch,
    /// Show the host watchdog, disable it (`off`), or enable it with a timeout in seconds
    #[command(
        after_help = "SECONDS is 0.1 to 25.5 in 0.1 s steps (or a duration such as 500ms). \
                            Once enabled, send `host-ok` (or run a script that does) before it \
                            expires, or the module drives its outputs to the safe value and \
                            refuses output writes until the watchdog is disabled."
    )]
    Watchdog {
        /// off, or a timeout such as 1.5
        #[arg(value_name = "off|SECONDS", value_parser = parse_watchdog)]
        setting: Option<WatchdogArg>,
    },
    /// Tell the watchdog the host is alive (restarts its countdown; ASCII: every module on the line)
    HostOk,
    /// Show the safe value (outputs when the watchdog expires), or set it
    #[command(after_help = PRESET_HELP)]
    SafeValue {
        /// New safe value, bit n = DOn
        #[arg(value_parser = parse_byte)]
        byte: Option<u8>,
        /// ASCII: drive the outputs to BYTE for a moment to store it (see below)
        #[arg(long, requires = "byte")]
        drive_outputs: bool,
    },
    /// Show the power-on value (outputs at power on and after reset), or set it
    #[command(after_help = PRESET_HELP)]
    PowerOnValue {
        /// New power-on value, bit n = DOn
        #[arg(value_parser = parse_byte)]
        byte: Option<u8>,
        /// ASCII: drive the outputs to BYTE for a moment to store it (see below)
        #[arg(long, requires = "byte")]
        drive_outputs: bool,
    },
    /// Show name, firmware, configuration, reset flag (reading clears it) and watchdog
    Info,
    /// Show the module's name, or rename it (ASCII only; 1-6 printable characters)
    Name {
        /// New name
        #[arg(value_parser = parse_name)]
        new: Option<String>,
    },
    /// Reset the module (outputs go to the power-on value; unsaved counts are lost)
    Reset,
    /// Change the module's ID, baud rate or data format; then show its settings
    Configure(ConfigureArgs),
    /// Send one raw frame (checksum or CRC appended) and print the answer as hex and text
    #[command(
        after_help = "ASCII: the frame as text, leading character and ID included, such \
                            as '$016' (the checksum, when on, and the CR are added). Modbus: the \
                            frame as hex bytes, ID included, such as '01 01 00 20 00 08' (the \
                            CRC is added). At most the protocol's longest request: 11 \
                            characters (ASCII), 254 bytes (Modbus)."
    )]
    Raw {
        /// The frame
        #[arg(value_name = "TEXT|HEX")]
        frame: String,
    },
    /// Show inputs, outputs and counters, then print every change until Ctrl-C
    Monitor {
        /// Poll period in milliseconds
        #[arg(long, value_name = "MS", default_value_t = 200,
              value_parser = clap::value_parser!(u64).range(1..=60_000))]
        interval: u64,
    },
}

/// Options of `c29 configure`; at least one is needed.
#[derive(Debug, Clone, Args)]
#[group(required = true, multiple = true)]
pub struct ConfigureArgs {
    /// New ID (Modbus 1-247, ASCII 0-255)
    #[arg(long, value_name = "N", value_parser = parse_byte)]
    pub new_id: Option<u8>,
    /// New line speed
    #[arg(long, value_name = "B", value_parser = parse_baud)]
    pub new_baud: Option<u32>,
    /// ASCII: checksums on or off
    #[arg(long, value_enum, value_name = "on|off")]
    pub set_checksum: Option<OnOff>,
    /// ASCII: which input edge the counters count
    #[arg(long, value_enum)]
    pub counter_edge: Option<EdgeArg>,
    /// ASCII: counters answered in hex (engineer mode)
    #[arg(long, value_enum, value_name = "on|off")]
    pub hex_counters: Option<OnOff>,
}

/// Reads a baud rate the module supports (8-2).
pub fn parse_baud(text: &str) -> Result<u32, String> {
    let rates: Vec<String> = BAUD_CODES.iter().map(|(_, b)| b.to_string()).collect();
    text.trim()
        .parse::<u32>()
        .ok()
        .filter(|&b| baud_code(b).is_some())
        .ok_or_else(|| {
            format!(
                "`{text}` is not a baud rate the module has: use {}",
                rates.join(", ")
            )
        })
}

/// Reads `off`, a number of seconds, or a duration with a unit.
fn parse_watchdog(text: &str) -> Result<WatchdogArg, String> {
    let t = text.trim();
    if t.eq_ignore_ascii_case("off") {
        return Ok(WatchdogArg::Off);
    }
    let bare_number = !t.is_empty() && t.bytes().all(|b| b.is_ascii_digit() || b == b'.');
    let duration = if bare_number {
        parse_duration(&format!("{t}s"))
    } else {
        parse_duration(t)
    }
    .map_err(|e| format!("{e}; or `off`"))?;
    watchdog_tenths(duration).map_err(|e| e.to_string())?;
    Ok(WatchdogArg::Timeout(duration))
}

fn parse_name(text: &str) -> Result<String, String> {
    ModuleName::new(text)
        .map(|n| n.as_str().to_string())
        .ok_or_else(|| format!("`{text}` is not a module name: use 1-6 printable ASCII characters"))
}

/// Reads a Modbus frame written as hex bytes: `01 01 00 20`, `01010020`, `0x01,0x01`.
fn parse_hex_frame(text: &str) -> Result<Vec<u8>, String> {
    let bad = |why: &str| {
        format!("`{text}` is not a Modbus frame in hex ({why}): write bytes such as `01 01 00 20 00 08`")
    };
    let mut digits = String::new();
    for word in text.split(|c: char| c.is_whitespace() || c == ',' || c == ':') {
        let word = word
            .strip_prefix("0x")
            .or_else(|| word.strip_prefix("0X"))
            .unwrap_or(word);
        if word.len() % 2 == 1 {
            digits.push('0');
        }
        digits.push_str(word);
    }
    if digits.is_empty() {
        return Err(bad("it is empty"));
    }
    digits
        .as_bytes()
        .chunks(2)
        .map(|pair| {
            std::str::from_utf8(pair)
                .ok()
                .and_then(|p| u8::from_str_radix(p, 16).ok())
                .ok_or_else(|| bad("not hex digits"))
        })
        .collect()
}

/// What can end a `c29` command early.
#[derive(Debug, thiserror::Error)]
enum CliError {
    #[error(transparent)]
    Device(#[from] C29uError),
    #[error("{0}")]
    Usage(String),
    #[error("cannot write output: {0}")]
    Output(#[from] std::io::Error),
    #[error("cannot watch for Ctrl-C: {0}")]
    Signal(std::io::Error),
}

impl From<crate::link::LinkError> for CliError {
    fn from(e: crate::link::LinkError) -> Self {
        CliError::Device(C29uError::Link(e))
    }
}

impl CommandError for CliError {
    fn exit_status(&self) -> i32 {
        match self {
            CliError::Device(e) if e.is_unreachable() => EXIT_UNREACHABLE,
            // A preset refused for want of --drive-outputs: the command needs the flag.
            CliError::Device(
                C29uError::InvalidArgument(_) | C29uError::PresetDrivesOutputs { .. },
            )
            | CliError::Usage(_) => EXIT_USAGE,
            _ => EXIT_FAILED,
        }
    }

    fn held_by(&self) -> Vec<u32> {
        match self {
            CliError::Device(C29uError::Link(e)) => e.held_by(),
            _ => Vec::new(),
        }
    }
}

impl C29Args {
    /// The driver options these arguments describe.
    pub fn options(&self) -> C29uOptions {
        C29uOptions {
            protocol: self.protocol.into(),
            id: self.id,
            baud: self.baud,
            checksum: self.checksum,
            timeout: Duration::from_millis(self.timeout),
            retries: self.retries,
            frame_gap: self.frame_gap,
            ..C29uOptions::default()
        }
    }
}

/// Runs `rigscript c29` and returns the exit status.
pub fn run(args: C29Args) -> i32 {
    run_command(args.json, |out| run_to(&args, out))
}

fn run_to(args: &C29Args, out: &mut dyn Write) -> Result<(), CliError> {
    let port = args.port.as_deref().ok_or_else(|| {
        CliError::Usage(
            "--port is required: give the serial port (such as /dev/ttyUSB0) or tcp://HOST:PORT; \
             `rigscript scan` lists ports and finds modules"
                .into(),
        )
    })?;
    let options = args.options();
    let as_text = options.protocol == Protocol::Ascii;
    let mut dev = C29u::open(port, SystemClock::shared(), options)?;
    if args.trace {
        dev.set_tracer(Some(Box::new(move |direction, bytes| {
            eprintln!("{}", format_frame(direction, bytes, as_text));
        })));
    }
    if let C29Command::Monitor { interval } = args.command {
        let stop = stop_flag().map_err(CliError::Signal)?;
        return monitor::run(
            &mut dev,
            Duration::from_millis(interval),
            args.json,
            out,
            &stop,
        );
    }
    let report = execute(&args.command, &mut dev)?;
    if args.json {
        writeln!(out, "{}", report.json)?;
    } else {
        write!(out, "{}", report.text)?;
    }
    Ok(())
}

/// What a command found or did, for people and for machines.
#[derive(Debug)]
struct Report {
    json: Value,
    text: String,
}

impl Report {
    fn new(json: Value, text: impl Into<String>) -> Self {
        let mut text = text.into();
        if !text.ends_with('\n') {
            text.push('\n');
        }
        Self { json, text }
    }
}

fn outputs_report(outputs: u8, done: &str) -> Report {
    Report::new(
        json!({ "do": outputs, "on": set_channels(outputs) }),
        format!(
            "{done}{}",
            byte_table(&[byte_row("DO", outputs, "on", "DO")])
        ),
    )
}

/// `--drive-outputs` as the driver takes it.
fn preset_write(drive_outputs: bool) -> PresetWrite {
    if drive_outputs {
        PresetWrite::DriveOutputs
    } else {
        PresetWrite::KeepOutputs
    }
}

fn preset_report(name: &str, key: &str, value: u8, done: &str) -> Report {
    Report::new(
        json!({ key: value, "on": set_channels(value) }),
        format!("{done}{}", byte_table(&[byte_row(name, value, "on", "DO")])),
    )
}

fn watchdog_json(w: &WatchdogInfo) -> Value {
    json!({
        "enabled": w.enabled,
        "timeout_tenths": w.timeout_tenths,
        "timeout_s": f64::from(w.timeout_tenths) / 10.0,
        "expired": w.expired,
    })
}

fn watchdog_text(w: &WatchdogInfo) -> String {
    let t = tenths(w.timeout_tenths);
    match (w.timeout_tenths, w.enabled, w.expired) {
        (0, _, _) => "disabled".to_string(),
        (_, _, Some(true)) => format!(
            "expired (timeout {t}): outputs at the safe value; `watchdog off` leaves safe mode"
        ),
        (_, true, Some(false)) => format!("enabled, timeout {t}"),
        (_, true, None) => format!("enabled, timeout {t} (the module does not report expiry)"),
        (_, false, Some(false)) => format!("disabled (timeout {t} stored)"),
        (_, false, None) => format!(
            "not counting, timeout {t}: disabled, or expired with the outputs at the safe value \
             (the module does not say which); `watchdog off` leaves safe mode"
        ),
    }
}

fn on_off(b: bool) -> &'static str {
    if b {
        "on"
    } else {
        "off"
    }
}

fn edge_name(edge: CounterEdge) -> &'static str {
    match edge {
        CounterEdge::Rising => "rising",
        CounterEdge::Falling => "falling",
    }
}

/// The options to reach the module with now (after a configuration change).
fn reach_with(options: &C29uOptions) -> String {
    let protocol = match options.protocol {
        Protocol::Ascii => "ascii",
        Protocol::Modbus => "modbus",
    };
    let checksum = if options.protocol == Protocol::Ascii && options.checksum {
        " --checksum"
    } else {
        ""
    };
    format!(
        "--protocol {protocol} --id {} --baud {}{checksum}",
        options.id, options.baud
    )
}

fn settings_report(dev: &mut C29u, done: &str) -> Result<Report, CliError> {
    let s = dev.settings()?;
    let mut text = format!("{done}id        {}\n", s.id);
    if let Some(baud) = s.baud {
        text.push_str(&format!("baud      {baud}\n"));
    }
    if let Some(checksum) = s.checksum {
        text.push_str(&format!("checksum  {}\n", on_off(checksum)));
    }
    if let Some(edge) = s.counter_edge {
        text.push_str(&format!("counts    {} edges\n", edge_name(edge)));
    }
    text.push_str(&format!("reach it with {}\n", reach_with(dev.options())));
    Ok(Report::new(
        json!({
            "id": s.id,
            "baud": s.baud,
            "checksum": s.checksum,
            "counter_edge": s.counter_edge,
            "model": s.model,
            "options": reach_with(dev.options()),
        }),
        text,
    ))
}

fn info_report(dev: &mut C29u) -> Result<Report, CliError> {
    let name = dev.name()?;
    let firmware = dev.firmware()?;
    let settings = dev.settings()?;
    let reset = dev.take_reset_flag()?;
    let watchdog = dev.watchdog()?;
    let protocol = dev.options().protocol;
    let date = firmware
        .date
        .map(|(y, m, d)| format!("{y:04}-{m:02}-{d:02}"));
    let mut text = format!("module    {}\n", dev.describe());
    text.push_str(&format!("name      {name}\n"));
    text.push_str(&format!(
        "firmware  {}{}\n",
        firmware.text,
        date.as_ref().map(|d| format!(" ({d})")).unwrap_or_default()
    ));
    text.push_str(&format!("protocol  {protocol}\n"));
    if let Some(baud) = settings.baud {
        text.push_str(&format!("baud      {baud}\n"));
    }
    if let Some(checksum) = settings.checksum {
        text.push_str(&format!("checksum  {}\n", on_off(checksum)));
    }
    if let Some(edge) = settings.counter_edge {
        text.push_str(&format!("counts    {} edges\n", edge_name(edge)));
    }
    if let Some(model) = settings.model {
        let known = if model == 3 { " (TRP-C29U)" } else { "" };
        text.push_str(&format!("model     {model}{known}\n"));
    }
    text.push_str(&format!(
        "reset     {}\n",
        if reset {
            "yes: reset or powered on since the flag was last read (reading cleared it)"
        } else {
            "no"
        }
    ));
    text.push_str(&format!("watchdog  {}\n", watchdog_text(&watchdog)));
    Ok(Report::new(
        json!({
            "module": dev.describe(),
            "protocol": protocol,
            "id": settings.id,
            "name": name,
            "firmware": { "text": firmware.text, "date": date },
            "baud": settings.baud,
            "checksum": settings.checksum,
            "counter_edge": settings.counter_edge,
            "model": settings.model,
            "reset": reset,
            "watchdog": watchdog_json(&watchdog),
        }),
        text,
    ))
}

fn raw_report(dev: &mut C29u, frame: &str) -> Result<Report, CliError> {
    let body = match dev.options().protocol {
        Protocol::Ascii => frame.as_bytes().to_vec(),
        Protocol::Modbus => parse_hex_frame(frame).map_err(CliError::Usage)?,
    };
    let answer = dev.raw(&body)?;
    if answer.is_empty() {
        return Ok(Report::new(
            json!({ "answer": Value::Null }),
            "sent; this frame gets no answer",
        ));
    }
    let hex = format_frame(Direction::Received, &answer, false);
    let hex = hex.trim_start_matches("<< ").to_string();
    Ok(Report::new(
        json!({ "answer": hex, "text": String::from_utf8_lossy(&answer) }),
        format_frame(Direction::Received, &answer, true),
    ))
}

fn configure_report(dev: &mut C29u, args: &ConfigureArgs) -> Result<Report, CliError> {
    let change = ConfigChange {
        id: args.new_id,
        baud: args.new_baud,
        checksum: args.set_checksum.map(OnOff::is_on),
        counter_edge: args.counter_edge.map(|e| match e {
            EdgeArg::Rising => CounterEdge::Rising,
            EdgeArg::Falling => CounterEdge::Falling,
        }),
        hex_counters: args.hex_counters.map(OnOff::is_on),
    };
    dev.configure(&change)?;
    let hex = args
        .hex_counters
        .map(|h| format!("counters  {}\n", if h.is_on() { "hex" } else { "decimal" }))
        .unwrap_or_default();
    let mut report = settings_report(dev, &format!("configured {}\n{hex}", dev.describe()))?;
    if let Some(h) = args.hex_counters {
        report.json["hex_counters"] = json!(h.is_on());
    }
    Ok(report)
}

/// Runs one command (not `monitor`) on an open module.
fn execute(command: &C29Command, dev: &mut C29u) -> Result<Report, CliError> {
    Ok(match command {
        C29Command::Status => {
            let io = dev.read_io()?;
            Report::new(
                json!({
                    "di": io.inputs,
                    "di_raw": io.inputs_raw,
                    "do": io.outputs,
                    "energized": set_channels(io.inputs),
                    "on": set_channels(io.outputs),
                }),
                byte_table(&[
                    byte_row("DI", io.inputs, "energized", "DI"),
                    byte_row("DO", io.outputs, "on", "DO"),
                ]),
            )
        }
        C29Command::Do { byte: None } => outputs_report(dev.read_outputs()?, ""),
        C29Command::Do { byte: Some(value) } => {
            dev.write_outputs(*value)?;
            outputs_report(*value, "outputs set\n")
        }
        C29Command::Set { channel, state } => {
            dev.write_output(*channel, state.is_on())?;
            let outputs = dev.read_outputs()?;
            outputs_report(
                outputs,
                &format!("DO{channel} switched {}\n", on_off(state.is_on())),
            )
        }
        C29Command::Counters => {
            let counters = dev.read_counters()?;
            let text: String = (0..)
                .zip(counters.iter())
                .map(|(ch, v)| format!("DI{ch}  {v}\n"))
                .collect();
            Report::new(json!({ "counters": counters }), text)
        }
        C29Command::ClearCounters { channel: Some(ch) } => {
            dev.clear_counter(*ch)?;
            Report::new(
                json!({ "cleared": [ch] }),
                format!("cleared the counter of DI{ch}"),
            )
        }
        C29Command::ClearCounters { channel: None } => {
            dev.clear_counters()?;
            Report::new(
                json!({ "cleared": (0..8).collect::<Vec<u8>>() }),
                "cleared all eight counters",
            )
        }
        C29Command::SaveCounters => {
            dev.save_counters()?;
            Report::new(
                json!({ "saved": true }),
                "saved the counters to EEPROM (they survive a reset or power loss)",
            )
        }
        C29Command::Latch => {
            let l = dev.read_latches()?;
            Report::new(
                json!({
                    "low": l.low,
                    "high": l.high,
                    "low_channels": set_channels(l.low),
                    "high_channels": set_channels(l.high),
                }),
                format!(
                    "{}low:  seen at 0 on the wire (energized) since the last clear\n\
                     high: seen at 1 on the wire (released) since the last clear\n",
                    byte_table(&[
                        byte_row("low", l.low, "latched", "DI"),
                        byte_row("high", l.high, "latched", "DI"),
                    ])
                ),
            )
        }
        C29Command::ClearLatch => {
            dev.clear_latches()?;
            Report::new(json!({ "cleared": true }), "cleared the latches")
        }
        C29Command::Watchdog { setting: None } => {
            let w = dev.watchdog()?;
            Report::new(
                watchdog_json(&w),
                format!("watchdog  {}", watchdog_text(&w)),
            )
        }
        C29Command::Watchdog {
            setting: Some(WatchdogArg::Off),
        } => {
            dev.set_watchdog(None)?;
            Report::new(
                json!({ "enabled": false }),
                "watchdog disabled (outputs accept writes again)",
            )
        }
        C29Command::Watchdog {
            setting: Some(WatchdogArg::Timeout(t)),
        } => {
            dev.set_watchdog(Some(*t))?;
            let steps = watchdog_tenths(*t)?;
            Report::new(
                json!({
                    "enabled": true,
                    "timeout_tenths": steps,
                    "timeout_s": f64::from(steps) / 10.0,
                }),
                format!(
                    "watchdog enabled, timeout {}: send `host-ok` before it expires, or the \
                     outputs go to the safe value",
                    tenths(steps)
                ),
            )
        }
        C29Command::HostOk => {
            dev.host_ok()?;
            let whom = match dev.options().protocol {
                Protocol::Ascii => "every module on the line",
                Protocol::Modbus => "the module",
            };
            Report::new(
                json!({ "sent": true }),
                format!("sent host OK to {whom} (it gets no answer)"),
            )
        }
        C29Command::SafeValue { byte: None, .. } => {
            preset_report("safe", "safe_value", dev.safe_value()?, "")
        }
        C29Command::SafeValue {
            byte: Some(v),
            drive_outputs,
        } => {
            dev.store_preset(Preset::Safe, *v, preset_write(*drive_outputs))?;
            preset_report("safe", "safe_value", *v, "safe value stored\n")
        }
        C29Command::PowerOnValue { byte: None, .. } => {
            preset_report("power", "power_on_value", dev.power_on_value()?, "")
        }
        C29Command::PowerOnValue {
            byte: Some(v),
            drive_outputs,
        } => {
            dev.store_preset(Preset::PowerOn, *v, preset_write(*drive_outputs))?;
            preset_report("power", "power_on_value", *v, "power-on value stored\n")
        }
        C29Command::Info => info_report(dev)?,
        C29Command::Name { new: None } => {
            let name = dev.name()?;
            Report::new(json!({ "name": name }), name)
        }
        C29Command::Name { new: Some(name) } => {
            dev.set_name(name)?;
            Report::new(
                json!({ "name": name }),
                format!("renamed {} to {name}", dev.describe()),
            )
        }
        C29Command::Reset => {
            dev.reset()?;
            Report::new(
                json!({ "reset": true }),
                "reset: outputs are at the power-on value, unsaved counts are lost",
            )
        }
        C29Command::Configure(args) => configure_report(dev, args)?,
        C29Command::Raw { frame } => raw_report(dev, frame)?,
        C29Command::Monitor { .. } => {
            return Err(CliError::Usage(
                "monitor runs on its own, not as one request".into(),
            ))
        }
    })
}

#[cfg(test)]
mod tests;
