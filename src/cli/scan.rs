//! `rigscript scan`: lists TRC1000 boards and serial ports, then probes ports for TRP-C29U
//! modules (each protocol, baud rate and ID asked) and lists what answered.

use crate::cli::c29::parse_baud;
use crate::cli::output::{run_command, EXIT_OK, EXIT_UNREACHABLE};
use crate::cli::sim::{parse_byte, ProtocolArg};
use crate::cli::trc::board_json;
use crate::device::c29u::{open_port, share, C29u, C29uError, C29uOptions, Protocol, SharedLink};
use crate::link::usb::{list_boards, BoardInfo};
use crate::link::LinkError;
use crate::protocol::c29u::BAUD_CODES;
use crate::protocol::c29u_modbus::SLAVE_IDS;
use crate::time::clock::{SharedClock, SystemClock};
use clap::Args;
use serde_json::{json, Value};
use std::collections::BTreeSet;
use std::io::{IsTerminal, Write};
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

/// IDs tried when `--ids` is not given: each silent ID costs a timeout, so only the low ones
/// people use (and ASCII's INIT-mode ID 0).
const DEFAULT_IDS: std::ops::RangeInclusive<u8> = 1..=16;

/// Options of `rigscript scan`.
#[derive(Debug, Args)]
#[command(
    after_help = "Defaults keep a scan short, because every silent ID costs one timeout: \
                        IDs 1-16 (ASCII also 0, the ID of a module in INIT mode), 9600 baud (the \
                        factory setting), both protocols, 50 ms a try. ASCII modules are asked \
                        without and then with checksums. Widen with, for example, \
                        `--ids 1-247 --bauds all`. Exit status 3 when a port given with --ports \
                        cannot be opened (missing, busy, not a serial port, no permission); \
                        finding nothing is not an error."
)]
pub struct ScanArgs {
    /// Probe only these ports (paths, pty symlinks, tcp://HOST:PORT) [default: every serial port found]
    #[arg(long, value_delimiter = ',', value_name = "P,..")]
    pub ports: Vec<String>,
    /// IDs to try, such as 1-5,9; Modbus skips 0 and 248-255 [default: 1-16, ASCII also 0]
    #[arg(long, value_name = "LIST", value_parser = parse_ids)]
    pub ids: Option<IdList>,
    /// Baud rates to try, such as 9600,115200, or `all` [default: 9600]
    #[arg(long, value_name = "B,..|all", value_parser = parse_bauds)]
    pub bauds: Option<BaudList>,
    /// Protocols to try [default: modbus,ascii]
    #[arg(long, value_delimiter = ',', value_enum, value_name = "P,..")]
    pub protocols: Vec<ProtocolArg>,
    /// How long to wait for each answer, in milliseconds
    #[arg(long, value_name = "MS", default_value_t = 50,
          value_parser = clap::value_parser!(u64).range(1..=10_000))]
    pub timeout: u64,
    /// Print one JSON document instead of text
    #[arg(long)]
    pub json: bool,
}

/// IDs to probe, ascending, each once.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct IdList(pub Vec<u8>);

/// Baud rates to probe, in the order given.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BaudList(pub Vec<u32>);

/// Reads IDs written as numbers and ranges: `1-5,9`, `0x10-0x1F`.
pub fn parse_ids(text: &str) -> Result<IdList, String> {
    let mut ids = BTreeSet::new();
    for part in text.split(',').map(str::trim) {
        if part.is_empty() {
            return Err(format!(
                "`{text}` has an empty item: write IDs such as 1-5,9"
            ));
        }
        let (first, last) = match part.split_once('-') {
            Some((a, b)) => (parse_byte(a)?, parse_byte(b)?),
            None => {
                let id = parse_byte(part)?;
                (id, id)
            }
        };
        if first > last {
            return Err(format!("`{part}` runs backwards: write the lower ID first"));
        }
        ids.extend(first..=last);
    }
    Ok(IdList(ids.into_iter().collect()))
}

/// Reads baud rates, comma-separated, or `all` for every rate the module has.
pub fn parse_bauds(text: &str) -> Result<BaudList, String> {
    if text.trim().eq_ignore_ascii_case("all") {
        return Ok(BaudList(BAUD_CODES.iter().map(|(_, b)| *b).collect()));
    }
    let mut bauds = Vec::new();
    for part in text.split(',') {
        let baud = parse_baud(part)?;
        if !bauds.contains(&baud) {
            bauds.push(baud);
        }
    }
    Ok(BaudList(bauds))
}

/// IDs as ranges for people: `0-16,20`.
pub fn ranges_text(ids: &[u8]) -> String {
    let mut parts: Vec<String> = Vec::new();
    let mut iter = ids.iter().copied().peekable();
    while let Some(start) = iter.next() {
        let mut end = start;
        while let Some(&next) = iter.peek() {
            if end.checked_add(1) == Some(next) {
                end = next;
                iter.next();
            } else {
                break;
            }
        }
        parts.push(if start == end {
            start.to_string()
        } else {
            format!("{start}-{end}")
        });
    }
    parts.join(",")
}

impl ScanArgs {
    fn protocols(&self) -> Vec<Protocol> {
        if self.protocols.is_empty() {
            vec![Protocol::Modbus, Protocol::Ascii]
        } else {
            let mut list: Vec<Protocol> = Vec::new();
            for p in &self.protocols {
                let p = Protocol::from(*p);
                if !list.contains(&p) {
                    list.push(p);
                }
            }
            list
        }
    }

    fn bauds(&self) -> Vec<u32> {
        self.bauds
            .as_ref()
            .map(|b| b.0.clone())
            .unwrap_or_else(|| vec![9600])
    }

    /// The IDs to ask in `protocol`: Modbus has 1-247 only.
    fn ids(&self, protocol: Protocol) -> Vec<u8> {
        let all: Vec<u8> = match &self.ids {
            Some(list) => list.0.clone(),
            None if protocol == Protocol::Ascii => std::iter::once(0).chain(DEFAULT_IDS).collect(),
            None => DEFAULT_IDS.collect(),
        };
        match protocol {
            Protocol::Ascii => all,
            Protocol::Modbus => all
                .into_iter()
                .filter(|id| SLAVE_IDS.contains(id))
                .collect(),
        }
    }
}

/// A serial port in the listing.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PortEntry {
    /// The path (or tcp:// address) to open.
    pub port: String,
    /// What it is: `USB 0403:6001 FTDI FT232R`, `PCI`, `given`...
    pub kind: String,
    /// Where a symlink points.
    pub target: Option<String>,
}

/// The serial ports the system lists. `serialport` (built without libudev) reads
/// /sys/class/tty and panics when it is missing, so a machine without it lists none.
fn system_ports(warnings: &mut Vec<String>) -> Vec<PortEntry> {
    if !Path::new("/sys/class/tty").is_dir() {
        return Vec::new();
    }
    match serialport::available_ports() {
        Ok(list) => list
            .into_iter()
            .map(|p| PortEntry {
                port: p.port_name,
                kind: port_kind(&p.port_type),
                target: None,
            })
            .collect(),
        Err(e) => {
            warnings.push(format!("cannot list serial ports: {e}"));
            Vec::new()
        }
    }
}

fn port_kind(kind: &serialport::SerialPortType) -> String {
    match kind {
        serialport::SerialPortType::UsbPort(usb) => {
            let mut text = format!("USB {:04x}:{:04x}", usb.vid, usb.pid);
            for part in [&usb.manufacturer, &usb.product].into_iter().flatten() {
                text.push(' ');
                text.push_str(part);
            }
            text
        }
        serialport::SerialPortType::PciPort => "PCI".into(),
        serialport::SerialPortType::BluetoothPort => "Bluetooth".into(),
        serialport::SerialPortType::Unknown => "serial".into(),
    }
}

/// A port named with --ports, with where its symlink points.
fn given_port(port: &str) -> PortEntry {
    let target = std::fs::canonicalize(port)
        .ok()
        .map(|p| p.display().to_string())
        .filter(|t| t != port);
    PortEntry {
        port: port.to_string(),
        kind: "given".into(),
        target,
    }
}

/// A module that answered.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct Found {
    /// Where.
    pub port: String,
    /// Which protocol it answered.
    pub protocol: Protocol,
    /// The line speed it answered at.
    pub baud: u32,
    /// Its ID.
    pub id: u8,
    /// ASCII: whether it wants checksums.
    pub checksum: Option<bool>,
    /// Its name.
    pub name: String,
    /// Its firmware text, when it gave one.
    pub firmware: Option<String>,
}

impl Found {
    fn text(&self) -> String {
        let protocol = match self.protocol {
            Protocol::Ascii => "ascii",
            Protocol::Modbus => "modbus",
        };
        let mut text = format!(
            "{}  {protocol}  {}  ID {}  name {}",
            self.port, self.baud, self.id, self.name
        );
        if let Some(fw) = &self.firmware {
            text.push_str(&format!("  firmware {fw}"));
        }
        if self.checksum == Some(true) {
            text.push_str("  checksum on");
        }
        text
    }

    fn options(&self) -> String {
        let protocol = match self.protocol {
            Protocol::Ascii => "ascii",
            Protocol::Modbus => "modbus",
        };
        let checksum = if self.checksum == Some(true) {
            " --checksum"
        } else {
            ""
        };
        format!(
            "--port {} --protocol {protocol} --id {} --baud {}{checksum}",
            self.port, self.id, self.baud
        )
    }
}

/// What one probe of one ID found.
enum Probe {
    /// A module answered.
    Found(Found),
    /// Silence.
    Nothing,
    /// Something answered that is not a module's answer.
    Odd(C29uError),
}

/// One probe setting: where, how fast, how long.
struct Line<'a> {
    port: &'a str,
    link: &'a SharedLink,
    clock: &'a SharedClock,
    baud: u32,
    timeout: Duration,
}

/// Asks `id` for its name (`$IDM`, `46 00`), then firmware and settings when it answers.
/// ASCII asks without a checksum, then with one: a module that wants them ignores the rest.
fn probe(line: &Line, protocol: Protocol, id: u8) -> Result<Probe, C29uError> {
    let checksums: &[bool] = match protocol {
        Protocol::Ascii => &[false, true],
        Protocol::Modbus => &[false],
    };
    for &checksum in checksums {
        let options = C29uOptions {
            protocol,
            id,
            baud: line.baud,
            checksum,
            timeout: line.timeout,
            retries: 0,
            ..C29uOptions::default()
        };
        let mut dev = C29u::new(Arc::clone(line.link), Arc::clone(line.clock), options)?;
        let name = match dev.name() {
            Ok(name) => name,
            Err(C29uError::Timeout { .. }) => continue,
            Err(e @ C29uError::Link(_)) => return Err(e),
            Err(e) => return Ok(Probe::Odd(e)),
        };
        let firmware = dev.firmware().ok().map(|f| f.text);
        return Ok(Probe::Found(Found {
            port: line.port.to_string(),
            protocol,
            baud: line.baud,
            id,
            checksum: (protocol == Protocol::Ascii).then_some(checksum),
            name,
            firmware,
        }));
    }
    Ok(Probe::Nothing)
}

/// Shows where a long probe is: one overwritten line on a terminal, a line per pass elsewhere.
struct Progress {
    terminal: bool,
    shown: bool,
}

impl Progress {
    fn new() -> Self {
        Self {
            terminal: std::io::stderr().is_terminal(),
            shown: false,
        }
    }

    fn pass(&mut self, port: &str, protocol: Protocol, baud: u32, ids: &[u8], timeout: u64) {
        if !self.terminal {
            eprintln!(
                "probing {port} {} at {baud} baud, IDs {}, {timeout} ms each",
                protocol_word(protocol),
                ranges_text(ids)
            );
        }
    }

    fn id(&mut self, port: &str, protocol: Protocol, baud: u32, id: u8, n: usize, of: usize) {
        if self.terminal {
            eprint!(
                "\rprobing {port} {} {baud} id {id} ({n}/{of})\x1b[K",
                protocol_word(protocol)
            );
            self.shown = true;
        }
    }

    fn clear(&mut self) {
        if self.shown {
            eprint!("\r\x1b[K");
            self.shown = false;
        }
    }
}

fn protocol_word(p: Protocol) -> &'static str {
    match p {
        Protocol::Ascii => "ascii",
        Protocol::Modbus => "modbus",
    }
}

/// Everything a scan found.
#[derive(Debug, Default)]
struct Outcome {
    boards: Vec<BoardInfo>,
    ports: Vec<PortEntry>,
    modules: Vec<Found>,
    /// Ports that could not be opened or failed, with why.
    errors: Vec<(String, String)>,
    /// Ports another program holds (also in `errors`).
    busy: Vec<String>,
    /// How many ports were opened and asked.
    probed: usize,
    warnings: Vec<String>,
}

/// Runs `rigscript scan` and returns the exit status.
pub fn run(args: ScanArgs) -> i32 {
    let mut status = EXIT_OK;
    let written = run_command(args.json, |out| -> Result<(), OutputError> {
        status = scan(&args, out)?;
        Ok(())
    });
    if written != EXIT_OK {
        written
    } else {
        status
    }
}

/// Standard output failed.
#[derive(Debug, thiserror::Error)]
#[error("cannot write output: {0}")]
struct OutputError(#[from] std::io::Error);

impl crate::cli::output::CommandError for OutputError {
    fn exit_status(&self) -> i32 {
        crate::cli::output::EXIT_FAILED
    }
}

fn scan(args: &ScanArgs, out: &mut dyn Write) -> Result<i32, OutputError> {
    let text = !args.json;
    let mut outcome = Outcome::default();
    outcome.boards = match list_boards() {
        Ok(boards) => boards,
        Err(e) => {
            outcome
                .warnings
                .push(format!("cannot list TRC1000 boards: {e}"));
            Vec::new()
        }
    };
    let mut warnings = Vec::new();
    outcome.ports = system_ports(&mut warnings);
    outcome.warnings.extend(warnings);
    for port in &args.ports {
        outcome.ports.retain(|p| &p.port != port);
        outcome.ports.push(given_port(port));
    }
    if text {
        print_boards_and_ports(&outcome, out)?;
        writeln!(out, "TRP-C29U modules:")?;
        out.flush()?;
    }
    let to_probe: Vec<String> = if args.ports.is_empty() {
        outcome.ports.iter().map(|p| p.port.clone()).collect()
    } else {
        args.ports.clone()
    };
    let mut progress = Progress::new();
    let clock = SystemClock::shared();
    let timeout = Duration::from_millis(args.timeout);
    for port in &to_probe {
        probe_port(
            args,
            port,
            &clock,
            timeout,
            &mut progress,
            &mut outcome,
            out,
        )?;
    }
    progress.clear();
    for w in &outcome.warnings {
        eprintln!("warning: {w}");
    }
    for (port, e) in &outcome.errors {
        eprintln!("error: {port}: {e}");
    }
    if args.json {
        writeln!(out, "{}", outcome_json(&outcome))?;
    } else if outcome.modules.is_empty() {
        writeln!(out, "  none found")?;
        if !outcome.busy.is_empty() {
            eprintln!(
                "hint: {} could not be asked while another program holds it: end that program \
                 (named above) and scan again",
                outcome.busy.join(", ")
            );
        }
        if outcome.probed > 0 {
            eprintln!(
                "hint: check the cable, the protocol switch and the baud rate; widen the search \
                 with --ids 0-255 --bauds all (see --help)"
            );
        }
    } else {
        writeln!(
            out,
            "talk to one with `rigscript c29 {} status`",
            outcome
                .modules
                .first()
                .map(Found::options)
                .unwrap_or_default()
        )?;
    }
    let given_failed = outcome
        .errors
        .iter()
        .any(|(port, _)| args.ports.contains(port));
    Ok(if given_failed {
        EXIT_UNREACHABLE
    } else {
        EXIT_OK
    })
}

fn print_boards_and_ports(outcome: &Outcome, out: &mut dyn Write) -> std::io::Result<()> {
    if outcome.boards.is_empty() {
        writeln!(out, "TRC1000 boards: none")?;
    } else {
        writeln!(out, "TRC1000 boards:")?;
        for b in &outcome.boards {
            // A board a running rig holds cannot be opened here: say which rig has it.
            match crate::cli::output::rig_holding_path(&b.node()) {
                Some(rig) => writeln!(out, "  {b}: {rig}")?,
                None => writeln!(out, "  {b}")?,
            }
        }
    }
    if outcome.ports.is_empty() {
        writeln!(out, "serial ports: none")?;
    } else {
        writeln!(out, "serial ports:")?;
        for p in &outcome.ports {
            match &p.target {
                Some(t) => writeln!(out, "  {}  {} (-> {t})", p.port, p.kind)?,
                None => writeln!(out, "  {}  {}", p.port, p.kind)?,
            }
        }
    }
    Ok(())
}

fn outcome_json(o: &Outcome) -> Value {
    json!({
        "boards": o.boards.iter().map(board_json).collect::<Vec<_>>(),
        "ports": o.ports.iter().map(|p| json!({
            "port": p.port, "kind": p.kind, "target": p.target,
        })).collect::<Vec<_>>(),
        "modules": o.modules,
        "errors": o.errors.iter().map(|(port, e)| json!({ "port": port, "error": e }))
            .collect::<Vec<_>>(),
        "warnings": o.warnings,
    })
}

/// Probes one port at each baud rate, protocol and ID; a port that fails is recorded and left.
fn probe_port(
    args: &ScanArgs,
    port: &str,
    clock: &SharedClock,
    timeout: Duration,
    progress: &mut Progress,
    outcome: &mut Outcome,
    out: &mut dyn Write,
) -> Result<(), OutputError> {
    let mut counted = false;
    for baud in args.bauds() {
        let link = match open_port(port, baud, timeout) {
            Ok(link) => share(link),
            Err(e) => {
                if matches!(e, LinkError::Busy { .. }) {
                    outcome.busy.push(port.to_string());
                }
                let error = match crate::cli::output::rig_holding(&e.held_by()) {
                    Some(rig) => format!("{e}; {rig}"),
                    None => e.to_string(),
                };
                outcome.errors.push((port.to_string(), error));
                return Ok(());
            }
        };
        if !counted {
            outcome.probed += 1;
            counted = true;
        }
        let line = Line {
            port,
            link: &link,
            clock,
            baud,
            timeout,
        };
        for protocol in args.protocols() {
            // A module has one speed: one found at an earlier baud (a pty answers at any) is done.
            let ids: Vec<u8> = args
                .ids(protocol)
                .into_iter()
                .filter(|id| {
                    !outcome
                        .modules
                        .iter()
                        .any(|m| m.port == port && m.protocol == protocol && m.id == *id)
                })
                .collect();
            if ids.is_empty() {
                continue;
            }
            progress.pass(port, protocol, baud, &ids, args.timeout);
            if protocol == Protocol::Ascii {
                // Bytes of other probes may sit unfinished in an ASCII module's line buffer and
                // spoil the first command; a bare CR ends them.
                let sent = crate::sync::lock(&link).write_all(b"\r");
                if let Err(e) = sent {
                    outcome.errors.push((port.to_string(), e.to_string()));
                    return Ok(());
                }
            }
            for (n, &id) in (1..).zip(ids.iter()) {
                progress.id(port, protocol, baud, id, n, ids.len());
                match probe(&line, protocol, id) {
                    Ok(Probe::Found(found)) => {
                        if !args.json {
                            progress.clear();
                            writeln!(out, "  {}", found.text())?;
                            out.flush()?;
                        }
                        outcome.modules.push(found);
                    }
                    Ok(Probe::Nothing) => {}
                    Ok(Probe::Odd(e)) => outcome.warnings.push(format!(
                        "something answered {} ID {id} at {baud} baud on {port}, but not as a \
                         TRP-C29U would: {e}",
                        protocol_word(protocol)
                    )),
                    Err(e) => {
                        progress.clear();
                        outcome.errors.push((port.to_string(), e.to_string()));
                        return Ok(());
                    }
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cli::{Cli, Command};
    use clap::Parser;

    fn parse(args: &[&str]) -> Result<ScanArgs, clap::Error> {
        let mut all = vec!["rigscript", "scan"];
        all.extend_from_slice(args);
        Cli::try_parse_from(all).map(|cli| match cli.command {
            Command::Scan(a) => a,
            _ => panic!("not scan"),
        })
    }

    #[test]
    fn id_lists_take_ranges_and_single_ids() {
        assert_eq!(parse_ids("1-5,9"), Ok(IdList(vec![1, 2, 3, 4, 5, 9])));
        assert_eq!(parse_ids("9, 3-4 ,3"), Ok(IdList(vec![3, 4, 9])));
        assert_eq!(parse_ids("0x10-0x12"), Ok(IdList(vec![16, 17, 18])));
        assert_eq!(parse_ids("0-255").unwrap().0.len(), 256);
        for bad in ["", "1,,2", "5-1", "1-300", "a", "1-"] {
            assert!(parse_ids(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn ranges_text_compresses_runs() {
        assert_eq!(ranges_text(&[0, 1, 2, 3, 7, 9, 10]), "0-3,7,9-10");
        assert_eq!(ranges_text(&[254, 255]), "254-255");
        assert_eq!(ranges_text(&[]), "");
    }

    #[test]
    fn bauds_from_the_table_or_all() {
        assert_eq!(
            parse_bauds("9600,115200,9600"),
            Ok(BaudList(vec![9600, 115200]))
        );
        assert_eq!(parse_bauds("all").unwrap().0.len(), 8);
        assert!(parse_bauds("14400").unwrap_err().contains("9600"));
    }

    #[test]
    fn defaults_are_short_and_modbus_skips_impossible_ids() {
        let a = parse(&[]).unwrap();
        assert_eq!(a.protocols(), vec![Protocol::Modbus, Protocol::Ascii]);
        assert_eq!(a.bauds(), vec![9600]);
        assert_eq!(a.ids(Protocol::Modbus), (1..=16).collect::<Vec<u8>>());
        assert_eq!(a.ids(Protocol::Ascii), (0..=16).collect::<Vec<u8>>());
        assert_eq!(a.timeout, 50);
        let a = parse(&["--ids", "0-255", "--protocols", "ascii,ascii"]).unwrap();
        assert_eq!(a.protocols(), vec![Protocol::Ascii]);
        assert_eq!(a.ids(Protocol::Ascii).len(), 256);
        assert_eq!(a.ids(Protocol::Modbus), (1..=247).collect::<Vec<u8>>());
    }

    #[test]
    fn bad_options_are_usage_errors() {
        for bad in [
            &["--ids", "5-1"][..],
            &["--bauds", "300"],
            &["--protocols", "canbus"],
            &["--timeout", "0"],
        ] {
            assert!(parse(bad).unwrap_err().use_stderr(), "{bad:?}");
        }
    }

    #[test]
    fn a_given_pty_symlink_shows_its_target() {
        let dir = std::env::temp_dir().join(format!("rigscript-scan-{}", std::process::id()));
        let _ = std::fs::remove_file(&dir);
        std::os::unix::fs::symlink("/dev/null", &dir).unwrap();
        let entry = given_port(dir.to_str().unwrap());
        std::fs::remove_file(&dir).unwrap();
        assert_eq!(entry.target.as_deref(), Some("/dev/null"));
        assert_eq!(given_port("/dev/null").target, None);
    }
}
