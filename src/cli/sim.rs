//! `rigscript sim c29u`: serves simulated TRP-C29U modules on a pseudo-terminal, driven by
//! control lines on standard input.

use crate::cli::c29::parse_baud;
use crate::link::line::FrameGap;
use crate::protocol::c29u::frame_gap;
use crate::protocol::c29u::{baud_code, FirmwareDate};
use crate::protocol::c29u_modbus::silence_gap;
use crate::protocol::c29u_modbus::SLAVE_IDS;
use crate::sim::c29u::{C29uModel, Eeprom, OutputFault, Protocol};
use crate::sim::c29u_line::{lock, MultiDrop, SharedModel, SimulatedC29u};
use crate::sim::faults::drawn::Drawn;
use crate::sim::pty::{PtyServer, StrictTiming};
use crate::time::clock::{SharedClock, SystemClock};
use clap::{Args, Subcommand, ValueEnum};
use std::io::{BufRead, Write};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Which simulator to serve.
#[derive(Debug, Subcommand)]
pub enum SimCommand {
    /// Serve simulated TRP-C29U modules on a pseudo-terminal (its path is the first line printed).
    C29u(C29uSimArgs),
}

/// The protocol the simulated module's DIP switch selects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ProtocolArg {
    /// Modbus RTU (the factory setting).
    Modbus,
    /// Trycom's ASCII commands.
    Ascii,
}

impl From<ProtocolArg> for Protocol {
    fn from(arg: ProtocolArg) -> Self {
        match arg {
            ProtocolArg::Modbus => Protocol::Modbus,
            ProtocolArg::Ascii => Protocol::Ascii,
        }
    }
}

/// What `sim c29u --help` says of the control lines (a test holds it to `CONTROL_FORMS`).
pub const CONTROL_HELP: &str = "\
Control lines, one a line on standard input (each answers `ok`, a JSON line or `error: ...`;
`@ID` first addresses one module of several):
  di BYTE                  set the energized inputs (bit n = DIn): di 0x05
  di CH on, di CH off      energize or release one input, the others left as they are
  pulse CH N               N pulses on input CH (0-7): its counter counts them
  reset                    power cycle the module (back at its power-on value)
  state                    the module's state as one JSON line
  ignore-writes            the output stage fails: writes acknowledged, not applied
  refuse-writes CODE       output writes refused with that Modbus exception code (4, 0xFF)
  accept-writes            the output stage works again
  swap NAME SAFE POWER_ON  another module answers in its place (its own name and stored values)";

/// Options of `rigscript sim c29u`.
#[derive(Debug, Args)]
#[command(after_help = CONTROL_HELP)]
pub struct C29uSimArgs {
    /// Protocol the module answers.
    #[arg(long, value_enum, default_value = "modbus")]
    pub protocol: ProtocolArg,
    /// Module ID (Modbus RTU 1-247, ASCII 0-255); repeat (or give a list) for several modules
    /// on one line.
    #[arg(long, value_delimiter = ',', value_parser = parse_module_id)]
    pub id: Vec<u8>,
    /// Require checksums on ASCII commands (and add them to answers).
    #[arg(long)]
    pub checksum: bool,
    /// Also make a symlink to the pty here (removed on exit).
    #[arg(long)]
    pub link: Option<PathBuf>,
    /// Keep the module's EEPROM in this JSON file across runs (FILE.ID with several modules).
    #[arg(long)]
    pub state: Option<PathBuf>,
    /// Energized inputs at start (bit n = DIn), e.g. 0x05.
    #[arg(long, value_parser = parse_byte, default_value = "0")]
    pub di: u8,
    /// Probability (0-1) that an answer is dropped.
    #[arg(long, default_value = "0", value_parser = parse_probability)]
    pub drop: f64,
    /// Probability (0-1) that one bit of an answer is flipped (also `--corrupt`).
    #[arg(long, alias = "corrupt", default_value = "0", value_parser = parse_probability)]
    pub flip: f64,
    /// How late each answer is given, in milliseconds (the module answers one request at a
    /// time).
    #[arg(long, default_value = "0")]
    pub delay: u64,
    /// Seed for fault injection, for repeatable runs.
    #[arg(long)]
    pub seed: Option<u64>,
    /// The modules' configured line speed (default: as stored, factory 9600).
    #[arg(long, value_parser = parse_baud)]
    pub baud: Option<u32>,
    /// Time the line in real time at the configured baud: answers take their time on the
    /// wire, and a request that starts less than t3.5 (ASCII: t1.5) after the previous frame
    /// ended is dropped and counted (`state` shows "early_frames"); after a request that got
    /// no answer a pty only allows checking for one character of silence.
    #[arg(long)]
    pub strict_timing: bool,
}

/// Parses a byte written as decimal, `0x..` hex or `0b..` binary.
pub fn parse_byte(text: &str) -> Result<u8, String> {
    let t = text.trim();
    let parsed = if let Some(hex) = t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
        u8::from_str_radix(hex, 16)
    } else if let Some(bin) = t.strip_prefix("0b").or_else(|| t.strip_prefix("0B")) {
        u8::from_str_radix(bin, 2)
    } else {
        t.parse::<u8>()
    };
    parsed.map_err(|_| format!("`{text}` is not a byte: write 0-255, 0x00-0xFF or 0b00000000"))
}

/// The IDs each protocol has, for messages.
const ID_RANGES: &str = "Modbus RTU modules take IDs 1-247, ASCII modules 0-255";

/// Reads a module ID (decimal, `0x..` or `0b..`): 0-255 here, 1-247 checked for Modbus later.
fn parse_module_id(text: &str) -> Result<u8, String> {
    parse_byte(text).map_err(|_| format!("`{text}` is not a module ID: {ID_RANGES}"))
}

impl C29uSimArgs {
    /// The IDs the protocol cannot have, refused as clap refuses a bad value (status 2).
    fn check_ids(&self) -> Result<(), clap::Error> {
        let bad = match self.protocol {
            ProtocolArg::Modbus => self.id.iter().find(|id| !SLAVE_IDS.contains(*id)),
            ProtocolArg::Ascii => None,
        };
        match bad {
            None => Ok(()),
            Some(id) => Err(crate::cli::usage_error(format!(
                "invalid value '{id}' for '--id <ID>': `{id}` is not a Modbus RTU module ID: \
                 {ID_RANGES}"
            ))),
        }
    }
}

fn parse_probability(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(p) if (0.0..=1.0).contains(&p) => Ok(p),
        _ => Err(format!("`{text}` is not a probability between 0 and 1")),
    }
}

/// The firmware a module put in by `swap` reports.
const SWAPPED_FIRMWARE: FirmwareDate = FirmwareDate {
    year: 14,
    month: 9,
    day: 1,
};

/// One control line from standard input.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Control {
    /// Set the energized inputs.
    Di(u8),
    /// Energize one input (`di CH on`) or release it (`di CH off`), the others as they are.
    DiChannel {
        /// The input, 0-7.
        channel: u8,
        /// Energized.
        on: bool,
    },
    /// N full pulses on one input.
    Pulse {
        /// The input, 0-7.
        channel: u8,
        /// How many pulses.
        count: u32,
    },
    /// Power cycle the module.
    Reset,
    /// Print the module's state as one JSON line.
    State,
    /// Its output stage faulty (`ignore-writes`, `refuse-writes CODE`) or sound again
    /// (`accept-writes`).
    OutputFault(Option<OutputFault>),
    /// Another module in its place (`swap NAME SAFE POWER_ON`): same ID, that name, those
    /// stored values, a later firmware, no watchdog.
    Swap {
        /// Its name.
        name: String,
        /// Its stored safe value.
        safe_value: u8,
        /// Its stored power-on value.
        power_on_value: u8,
    },
}

/// A control line with the module it is for (`@ID` prefix; the first module when absent).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ControlLine {
    /// The module ID named by `@ID`, if any.
    pub target: Option<u8>,
    /// What to do.
    pub control: Control,
}

/// The control lines, as the start-up line and a refusal list them.
pub const CONTROL_FORMS: &[&str] = &[
    "di BYTE",
    "di CH on",
    "di CH off",
    "pulse CH N",
    "reset",
    "state",
    "ignore-writes",
    "refuse-writes CODE",
    "accept-writes",
    "swap NAME SAFE POWER_ON",
];

/// An input channel of a control line, 0-7.
fn parse_channel(word: &str) -> Result<u8, String> {
    match word.parse::<u8>() {
        Ok(c) if c < 8 => Ok(c),
        _ => Err(format!("`{word}` is not an input channel: write 0-7")),
    }
}

/// Parses a control line: `[@ID]` and one of `CONTROL_FORMS`.
pub fn parse_control(line: &str) -> Result<ControlLine, String> {
    let mut words = line.split_whitespace().peekable();
    let target = match words.peek() {
        Some(w) if w.starts_with('@') => {
            let id = parse_byte(w.trim_start_matches('@'))?;
            words.next();
            Some(id)
        }
        _ => None,
    };
    let words: Vec<&str> = words.collect();
    let control = match words.as_slice() {
        ["di", byte] => Control::Di(parse_byte(byte)?),
        ["di", ch, state] => Control::DiChannel {
            channel: parse_channel(ch)?,
            on: match *state {
                "on" => true,
                "off" => false,
                _ => return Err(format!("`{state}` is not an input state: write on or off")),
            },
        },
        ["pulse", ch, n] => {
            let channel = parse_channel(ch)?;
            let count = n
                .parse::<u32>()
                .map_err(|_| format!("`{n}` is not a pulse count: write a whole number"))?;
            Control::Pulse { channel, count }
        }
        ["reset"] => Control::Reset,
        ["state"] => Control::State,
        ["ignore-writes"] => Control::OutputFault(Some(OutputFault::Ignore)),
        ["refuse-writes", code] => {
            Control::OutputFault(Some(OutputFault::Refuse(parse_byte(code)?)))
        }
        ["accept-writes"] => Control::OutputFault(None),
        ["swap", name, safe, power_on] => Control::Swap {
            name: (*name).to_string(),
            safe_value: parse_byte(safe)?,
            power_on_value: parse_byte(power_on)?,
        },
        _ => {
            let forms: Vec<String> = CONTROL_FORMS.iter().map(|f| format!("`{f}`")).collect();
            let (last, rest) = forms.split_last().expect("control forms");
            return Err(format!(
                "unknown control line `{}`: use {} or {last}, optionally after `@ID`",
                line.trim(),
                rest.join(", ")
            ));
        }
    };
    Ok(ControlLine { target, control })
}

/// Applies one control line to the modules and returns the line to print; `early_frames`
/// (under strict timing) joins the state.
pub fn apply_control(
    line: &str,
    modules: &[(u8, SharedModel)],
    early_frames: Option<&AtomicU64>,
) -> String {
    let parsed = match parse_control(line) {
        Ok(p) => p,
        Err(e) => return format!("error: {e}"),
    };
    let found = match parsed.target {
        Some(id) => modules.iter().find(|(mid, _)| *mid == id),
        None => modules.first(),
    };
    let Some((_, model)) = found else {
        return format!(
            "error: no simulated module has ID {}",
            parsed.target.unwrap_or_default()
        );
    };
    let mut model = lock(model);
    match parsed.control {
        Control::Di(byte) => {
            model.set_inputs(byte);
            "ok".into()
        }
        Control::DiChannel { channel, on } => {
            let bit = 1u8 << channel;
            let inputs = model.inputs();
            model.set_inputs(if on { inputs | bit } else { inputs & !bit });
            "ok".into()
        }
        Control::Pulse { channel, count } => match model.pulse(channel, count) {
            Ok(()) => "ok".into(),
            Err(e) => format!("error: {e}"),
        },
        Control::Reset => {
            model.power_cycle();
            "ok".into()
        }
        Control::OutputFault(fault) => {
            model.set_output_fault(fault);
            "ok".into()
        }
        Control::Swap {
            name,
            safe_value,
            power_on_value,
        } => {
            let mut eeprom = Eeprom::factory();
            eeprom.name = name;
            eeprom.safe_value = safe_value;
            eeprom.power_on_value = power_on_value;
            match model.swap(eeprom, SWAPPED_FIRMWARE) {
                Ok(()) => "ok".into(),
                Err(e) => format!("error: {e}"),
            }
        }
        Control::State => {
            let mut state = match serde_json::to_value(model.state()) {
                Ok(state) => state,
                Err(e) => return format!("error: {e}"),
            };
            if let (Some(early), Some(map)) = (early_frames, state.as_object_mut()) {
                map.insert("early_frames".into(), early.load(Ordering::Relaxed).into());
            }
            state.to_string()
        }
    }
}

/// Runs `rigscript sim ...` and returns the exit status.
pub fn run(command: SimCommand) -> i32 {
    match command {
        SimCommand::C29u(args) if args.check_ids().is_err() => {
            let _ = args.check_ids().map_err(|e| e.print());
            crate::cli::output::EXIT_USAGE
        }
        SimCommand::C29u(args) => match serve_c29u(args) {
            Ok(()) => 0,
            Err(message) => {
                eprintln!("rigscript sim c29u: {message}");
                1
            }
        },
    }
}

fn build_model(
    args: &C29uSimArgs,
    id: Option<u8>,
    clock: &SharedClock,
    several: bool,
) -> Result<C29uModel, String> {
    let protocol = Protocol::from(args.protocol);
    let mut model = match &args.state {
        Some(path) => {
            let path = match (several, id) {
                (true, Some(id)) => PathBuf::from(format!("{}.{id}", path.display())),
                _ => path.clone(),
            };
            C29uModel::with_state_file(protocol, Arc::clone(clock), path)
                .map_err(|e| e.to_string())?
        }
        None => C29uModel::new(protocol, Arc::clone(clock), Eeprom::factory()),
    };
    let mut config = model.config();
    if let Some(id) = id {
        config.id = id;
    }
    if args.checksum {
        config.checksum = true;
    }
    if let Some(code) = args.baud.and_then(baud_code) {
        config.baud_code = code;
    }
    model.set_config(config).map_err(|e| e.to_string())?;
    // Inputs energized when the power comes on are levels, not edges: nothing counts or latches.
    model.set_inputs(args.di);
    model.power_cycle();
    Ok(model)
}

fn serve_c29u(args: C29uSimArgs) -> Result<(), String> {
    let clock = SystemClock::shared();
    let ids: Vec<Option<u8>> = if args.id.is_empty() {
        vec![None]
    } else {
        args.id.iter().copied().map(Some).collect()
    };
    let several = ids.len() > 1;
    let mut line = MultiDrop::new();
    let mut modules = Vec::new();
    let mut baud_code = 0x06;
    for id in ids {
        let model = build_model(&args, id, &clock, several)?;
        baud_code = model.config().baud_code;
        let sim = SimulatedC29u::new(model);
        let shared = sim.model();
        let id = lock(&shared).config().id;
        modules.push((id, shared));
        line.attach(Box::new(sim));
    }

    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&stop))
            .map_err(|e| format!("cannot handle signals: {e}"))?;
    }

    let mut server = PtyServer::open(args.link.as_deref()).map_err(|e| e.to_string())?;
    if let (true, Some(link)) = (server.replaced_stale_link(), &args.link) {
        eprintln!(
            "replaced the stale link {} (its pty was gone: a simulator that did not get to \
             remove it)",
            link.display()
        );
    }
    {
        let mut out = std::io::stdout().lock();
        writeln!(out, "{}", server.path()).map_err(|e| e.to_string())?;
        out.flush().map_err(|e| e.to_string())?;
    }
    eprintln!(
        "simulated TRP-C29U ({:?}, ID {}) on {}; control lines: {}; Ctrl-C to stop",
        args.protocol,
        modules
            .iter()
            .map(|(id, _)| id.to_string())
            .collect::<Vec<_>>()
            .join(","),
        server.path(),
        CONTROL_FORMS.join(" | ")
    );

    // Standard input may end (a pipe closed, </dev/null) without the simulator ending.
    let control_modules = modules.clone();
    let early = Arc::new(AtomicU64::new(0));
    let early_shown = args.strict_timing.then(|| Arc::clone(&early));
    std::thread::spawn(move || {
        let stdin = std::io::stdin();
        for line in stdin.lock().lines() {
            let Ok(line) = line else { break };
            if line.trim().is_empty() {
                continue;
            }
            let reply = apply_control(&line, &control_modules, early_shown.as_deref());
            let mut out = std::io::stdout().lock();
            let _ = writeln!(out, "{reply}");
            let _ = out.flush();
        }
    });

    let baud = crate::protocol::c29u::baud_rate(baud_code).unwrap_or(9600);
    let gap = silence_gap(baud);
    if args.strict_timing {
        server.strict_timing(StrictTiming {
            baud,
            required: frame_gap(args.protocol.into(), FrameGap::Auto, baud),
            early,
        });
    }
    let faults = Drawn {
        drop: args.drop,
        flip: args.flip,
        late: Duration::from_millis(args.delay),
        seed: args.seed,
    };
    server
        .serve(&mut line, &faults, gap, &stop)
        .map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_parse_in_three_bases_and_reject_nonsense() {
        assert_eq!(parse_byte("0x0F"), Ok(15));
        assert_eq!(parse_byte("0b101"), Ok(5));
        assert_eq!(parse_byte("200"), Ok(200));
        assert!(parse_byte("256").is_err());
        assert!(parse_byte("0xZZ").unwrap_err().contains("not a byte"));
    }

    #[test]
    fn the_help_shows_every_control_line() {
        for form in CONTROL_FORMS {
            assert!(
                CONTROL_HELP.contains(form),
                "sim c29u --help does not show `{form}`"
            );
        }
    }

    #[test]
    fn control_lines_parse_with_and_without_target() {
        assert_eq!(
            parse_control("di 0x05"),
            Ok(ControlLine {
                target: None,
                control: Control::Di(5)
            })
        );
        assert_eq!(
            parse_control("@2 pulse 3 10"),
            Ok(ControlLine {
                target: Some(2),
                control: Control::Pulse {
                    channel: 3,
                    count: 10
                }
            })
        );
        assert_eq!(
            parse_control(" reset ").map(|c| c.control),
            Ok(Control::Reset)
        );
        assert_eq!(
            parse_control("state").map(|c| c.control),
            Ok(Control::State)
        );
        assert!(parse_control("pulse 8 1").unwrap_err().contains("0-7"));
        assert!(parse_control("pulse 1 -3")
            .unwrap_err()
            .contains("pulse count"));
        assert!(parse_control("explode")
            .unwrap_err()
            .contains("unknown control line"));
        assert!(parse_control("di").is_err());
        assert_eq!(
            parse_control("di 3 on").map(|c| c.control),
            Ok(Control::DiChannel {
                channel: 3,
                on: true
            })
        );
        assert!(parse_control("di 8 on").unwrap_err().contains("0-7"));
        assert!(parse_control("di 3 high")
            .unwrap_err()
            .contains("on or off"));
    }

    #[test]
    fn one_input_is_set_and_released_the_others_left_as_they_are() {
        let clock: SharedClock = SystemClock::shared();
        let model: SharedModel = Arc::new(std::sync::Mutex::new(C29uModel::new(
            Protocol::Modbus,
            clock,
            Eeprom::factory(),
        )));
        let modules = [(1u8, Arc::clone(&model))];
        for (line, inputs) in [
            ("di 0x05", 0x05),
            ("di 3 on", 0x0d),
            ("di 0 off", 0x0c),
            ("di 0 off", 0x0c),
            ("di 7 on", 0x8c),
        ] {
            assert_eq!(apply_control(line, &modules, None), "ok", "{line}");
            assert_eq!(lock(&model).inputs(), inputs, "{line}");
        }
    }
}
