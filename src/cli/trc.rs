//! `rigscript trc`: list TRC1000 boards, select a relay, read switches and rotaries, monitor.

use crate::cli::output::{run_command, stop_flag, CommandError, EXIT_FAILED, EXIT_UNREACHABLE};
use crate::device::exchange::{format_frame, TracedPacketLink};
use crate::device::trc1000::{rotary_changes, RotaryChange, Trc1000, Trc1000Error};
use crate::link::usb::{list_boards, BoardInfo, UsbPacketLink, UsbTarget};
use crate::link::{LinkError, PacketLink};
use crate::protocol::trc1000::{RotaryValues, Switch, SwitchSet};
use clap::{Args, Subcommand};
use serde_json::{json, Value};
use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Options and subcommand of `rigscript trc`.
#[derive(Debug, Args)]
pub struct TrcArgs {
    /// Board unit 0-3, as set by its DIP switch [default: 0]
    #[arg(long, global = true, value_parser = clap::value_parser!(u8).range(0..=3), conflicts_with = "device")]
    pub unit: Option<u8>,
    /// Board by USB bus and device address, such as 001:004 (when two boards share a unit)
    #[arg(long, global = true, value_name = "BUS:ADDR", value_parser = parse_bus_address)]
    pub device: Option<BusAddress>,
    /// How long to wait for each answer, in milliseconds
    #[arg(long, global = true, value_name = "MS", default_value_t = 500,
          value_parser = clap::value_parser!(u64).range(1..=60_000))]
    pub timeout: u64,
    /// Print JSON for machines instead of text (monitor: one JSON object a line)
    #[arg(long, global = true)]
    pub json: bool,
    /// Print every packet sent and received to standard error, as hex
    #[arg(long, global = true)]
    pub trace: bool,
    /// What to do
    #[command(subcommand)]
    pub command: TrcCommand,
}

/// The `trc` subcommands.
#[derive(Debug, Clone, Subcommand)]
pub enum TrcCommand {
    /// List the TRC1000 boards on this machine
    List,
    /// Select relay N (0-7)
    Relay {
        /// Relay number
        #[arg(value_parser = clap::value_parser!(u8).range(0..=7))]
        n: u8,
    },
    /// Show the pressed switches
    Inputs,
    /// Show the 14 rotary counters (half-turns, 0-255)
    Rotaries,
    /// Print presses, releases and turns as they happen, until Ctrl-C
    Monitor {
        /// Poll period in milliseconds
        #[arg(long, value_name = "MS", default_value_t = 20,
              value_parser = clap::value_parser!(u64).range(1..=10_000))]
        interval: u64,
    },
}

/// A USB bus number and device address.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BusAddress {
    /// USB bus number.
    pub bus: u8,
    /// Device address on that bus.
    pub address: u8,
}

/// Parses `BUS:ADDR` (decimal, leading zeros allowed, as lsusb prints them).
pub fn parse_bus_address(s: &str) -> Result<BusAddress, String> {
    let bad = || format!("{s:?} is not BUS:ADDR (such as 001:004, as `rigscript trc list` shows)");
    let (bus, address) = s.split_once(':').ok_or_else(bad)?;
    let num = |t: &str| {
        if t.is_empty() || !t.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        t.parse::<u8>().ok()
    };
    match (num(bus), num(address)) {
        (Some(bus), Some(address)) => Ok(BusAddress { bus, address }),
        _ => Err(bad()),
    }
}

/// Runs `rigscript trc` and returns the exit status.
pub fn run(args: TrcArgs) -> i32 {
    run_command(args.json, |out| run_to(&args, out))
}

/// What can end a `trc` command early.
#[derive(Debug, thiserror::Error)]
enum CliError {
    #[error(transparent)]
    Device(#[from] Trc1000Error),
    #[error("cannot write output: {0}")]
    Output(#[from] std::io::Error),
    #[error("cannot watch for Ctrl-C: {0}")]
    Signal(std::io::Error),
}

impl From<LinkError> for CliError {
    fn from(e: LinkError) -> Self {
        CliError::Device(Trc1000Error::Link(e))
    }
}

impl CommandError for CliError {
    fn exit_status(&self) -> i32 {
        match self {
            CliError::Device(d) if d.is_unreachable() => EXIT_UNREACHABLE,
            _ => EXIT_FAILED,
        }
    }

    fn held_by(&self) -> Vec<u32> {
        match self {
            CliError::Device(Trc1000Error::Link(e)) => e.held_by(),
            _ => Vec::new(),
        }
    }
}

fn run_to(args: &TrcArgs, out: &mut dyn Write) -> Result<(), CliError> {
    if let TrcCommand::List = args.command {
        return list(args.json, out);
    }
    let target = match (args.device, args.unit) {
        (Some(BusAddress { bus, address }), _) => UsbTarget::BusAddress { bus, address },
        (None, unit) => UsbTarget::Unit(unit.unwrap_or(0)),
    };
    let link: Box<dyn PacketLink> = if args.trace {
        Box::new(TracedPacketLink::new(
            UsbPacketLink::open(target)?,
            Box::new(|direction, packet| eprintln!("{}", format_frame(direction, packet, false))),
        ))
    } else {
        Box::new(UsbPacketLink::open(target)?)
    };
    let mut trc = Trc1000::new(link);
    trc.set_timeout(Duration::from_millis(args.timeout));
    let stop = match args.command {
        TrcCommand::Monitor { .. } => stop_flag().map_err(CliError::Signal)?,
        _ => Arc::new(AtomicBool::new(false)),
    };
    execute(&args.command, &mut trc, args.json, out, &stop)
}

fn list(json: bool, out: &mut dyn Write) -> Result<(), CliError> {
    let boards = list_boards()?;
    if json {
        let list: Vec<Value> = boards.iter().map(board_json).collect();
        writeln!(out, "{}", json!({ "boards": list }))?;
    } else if boards.is_empty() {
        writeln!(out, "no TRC1000 boards found")?;
        eprintln!(
            "hint: check the cable and power; if `lsusb` shows 0d59:02ac-02af but this list is \
             empty, install the udev rule (see README)"
        );
    } else {
        for b in &boards {
            writeln!(
                out,
                "unit {}  {:03}:{:03}  (0d59:{:04x})",
                b.unit, b.bus, b.address, b.product_id
            )?;
        }
    }
    Ok(())
}

/// One board as JSON, as `trc list` and `scan` print it.
pub(crate) fn board_json(b: &BoardInfo) -> Value {
    json!({
        "unit": b.unit,
        "bus": b.bus,
        "address": b.address,
        "device": format!("{:03}:{:03}", b.bus, b.address),
        "product_id": format!("{:04x}", b.product_id),
    })
}

/// Runs a board command on an open board (any link: USB, or the simulator in tests).
fn execute<L: PacketLink>(
    command: &TrcCommand,
    trc: &mut Trc1000<L>,
    json: bool,
    out: &mut dyn Write,
    stop: &AtomicBool,
) -> Result<(), CliError> {
    match command {
        TrcCommand::List => list(json, out),
        TrcCommand::Relay { n } => {
            trc.select_relay(*n)?;
            if json {
                writeln!(out, "{}", json!({ "board": trc.describe(), "relay": n }))?;
            } else {
                writeln!(out, "selected relay {n} on {}", trc.describe())?;
            }
            Ok(())
        }
        TrcCommand::Inputs => {
            let pressed = trc.read_switches()?.pressed_names();
            if json {
                writeln!(out, "{}", json!({ "pressed": pressed }))?;
            } else if pressed.is_empty() {
                writeln!(out, "none")?;
            } else {
                writeln!(out, "{}", pressed.join(" "))?;
            }
            Ok(())
        }
        TrcCommand::Rotaries => {
            let values = trc.read_rotaries()?;
            if json {
                let map: serde_json::Map<String, Value> = values
                    .iter()
                    .map(|(r, v)| (r.name().to_string(), json!(v)))
                    .collect();
                writeln!(out, "{}", json!({ "rotaries": map }))?;
            } else {
                for (r, v) in values.iter() {
                    writeln!(out, "{:<5} {v:>3}", r.name())?;
                }
            }
            Ok(())
        }
        TrcCommand::Monitor { interval } => {
            monitor(trc, Duration::from_millis(*interval), json, out, stop)
        }
    }
}

/// Something that changed on the panel between two polls.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PanelEvent {
    /// A switch went down.
    Pressed(Switch),
    /// A switch came up.
    Released(Switch),
    /// A rotary moved.
    Turned(RotaryChange),
}

impl PanelEvent {
    /// The event as one line of text.
    pub fn text(&self) -> String {
        match self {
            PanelEvent::Pressed(s) => format!("{s} pressed"),
            PanelEvent::Released(s) => format!("{s} released"),
            PanelEvent::Turned(c) => format!("{} {:+} (now {})", c.name(), c.delta, c.value),
        }
    }

    /// The event as one JSON object.
    pub fn json(&self) -> Value {
        match self {
            PanelEvent::Pressed(s) => json!({ "event": "pressed", "switch": s.name() }),
            PanelEvent::Released(s) => json!({ "event": "released", "switch": s.name() }),
            PanelEvent::Turned(c) => json!({
                "event": "turned", "rotary": c.name(), "delta": c.delta, "value": c.value
            }),
        }
    }
}

/// The last panel state seen, to turn successive reads into events.
#[derive(Debug, Clone)]
pub struct PanelWatch {
    switches: SwitchSet,
    rotaries: RotaryValues,
}

impl PanelWatch {
    /// Starts from the board's present state (no events for what is already pressed).
    pub fn start<L: PacketLink>(trc: &mut Trc1000<L>) -> Result<Self, Trc1000Error> {
        Ok(Self {
            switches: trc.read_switches()?,
            rotaries: trc.read_rotaries()?,
        })
    }

    /// Reads the board again and returns what changed: presses, releases, then turns.
    pub fn poll<L: PacketLink>(
        &mut self,
        trc: &mut Trc1000<L>,
    ) -> Result<Vec<PanelEvent>, Trc1000Error> {
        let switches = trc.read_switches()?;
        let rotaries = trc.read_rotaries()?;
        let (pressed, released) = self.switches.changes(&switches);
        let mut events: Vec<PanelEvent> = pressed.into_iter().map(PanelEvent::Pressed).collect();
        events.extend(released.into_iter().map(PanelEvent::Released));
        events.extend(
            rotary_changes(&self.rotaries, &rotaries)
                .into_iter()
                .map(PanelEvent::Turned),
        );
        self.switches = switches;
        self.rotaries = rotaries;
        Ok(events)
    }
}

fn monitor<L: PacketLink>(
    trc: &mut Trc1000<L>,
    interval: Duration,
    json: bool,
    out: &mut dyn Write,
    stop: &AtomicBool,
) -> Result<(), CliError> {
    let mut watch = PanelWatch::start(trc)?;
    eprintln!("monitoring {}; Ctrl-C to stop", trc.describe());
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(interval);
        let events = match watch.poll(trc) {
            Ok(events) => events,
            // One missed answer is worth a warning, not the end of the session.
            Err(e @ Trc1000Error::Timeout { .. }) => {
                eprintln!("warning: {e}");
                continue;
            }
            Err(e) => return Err(e.into()),
        };
        for e in &events {
            if json {
                writeln!(out, "{}", e.json())?;
            } else {
                writeln!(out, "{}", e.text())?;
            }
        }
        out.flush()?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cli::{Cli, Command};
    use crate::link::memory::MemoryPacketLink;
    use crate::sim::trc1000::Trc1000Sim;
    use clap::Parser;

    fn parse(args: &[&str]) -> Result<TrcArgs, clap::Error> {
        let mut all = vec!["rigscript", "trc"];
        all.extend_from_slice(args);
        Cli::try_parse_from(all).map(|cli| match cli.command {
            Command::Trc(a) => a,
            #[allow(unreachable_patterns)]
            _ => panic!("not trc"),
        })
    }

    fn sim_board(sim: Trc1000Sim) -> Trc1000<MemoryPacketLink<Trc1000Sim>> {
        Trc1000::new(MemoryPacketLink::new(sim, "TRC1000 unit 0"))
    }

    fn output(command: TrcCommand, sim: Trc1000Sim, json: bool) -> String {
        let mut trc = sim_board(sim);
        let mut out = Vec::new();
        execute(&command, &mut trc, json, &mut out, &AtomicBool::new(false)).unwrap();
        String::from_utf8(out).unwrap()
    }

    #[test]
    fn options_parse_before_or_after_the_command() {
        let a = parse(&["--unit", "2", "--json", "inputs"]).unwrap();
        assert_eq!((a.unit, a.json, a.timeout), (Some(2), true, 500));
        let a = parse(&["rotaries", "--device", "001:004", "--timeout", "50"]).unwrap();
        assert_eq!(a.device, Some(BusAddress { bus: 1, address: 4 }));
        assert_eq!(a.timeout, 50);
        assert!(matches!(
            parse(&["relay", "7"]).unwrap().command,
            TrcCommand::Relay { n: 7 }
        ));
    }

    #[test]
    fn bad_usage_is_a_clap_usage_error() {
        for bad in [
            &["--unit", "4", "inputs"][..],
            &["relay", "8"],
            &["relay"],
            &["--device", "1-4", "inputs"],
            &["--device", "1:4", "--unit", "0", "inputs"],
            &["--timeout", "0", "inputs"],
            &["frobnicate"],
        ] {
            let e = parse(bad).unwrap_err();
            assert!(e.use_stderr(), "{bad:?} parsed");
        }
    }

    #[test]
    fn bus_address_accepts_lsusb_style_numbers_only() {
        assert_eq!(
            parse_bus_address("001:002"),
            Ok(BusAddress { bus: 1, address: 2 })
        );
        assert_eq!(
            parse_bus_address("3:127"),
            Ok(BusAddress {
                bus: 3,
                address: 127
            })
        );
        for bad in ["", ":", "1:", ":2", "1:2:3", "a:b", "1:256", "+1:2", "1 :2"] {
            assert!(parse_bus_address(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn inputs_prints_pressed_names_or_none() {
        let mut sim = Trc1000Sim::new();
        assert_eq!(output(TrcCommand::Inputs, sim.clone(), false), "none\n");
        sim.press("S41").unwrap();
        sim.press("S3").unwrap();
        assert_eq!(output(TrcCommand::Inputs, sim.clone(), false), "S3 S41\n");
        let v: Value = serde_json::from_str(&output(TrcCommand::Inputs, sim, true)).unwrap();
        assert_eq!(v, json!({ "pressed": ["S3", "S41"] }));
    }

    #[test]
    fn rotaries_prints_all_fourteen_by_name() {
        let mut sim = Trc1000Sim::new();
        sim.turn("S45B", 9).unwrap();
        sim.turn("S37", -2).unwrap();
        let text = output(TrcCommand::Rotaries, sim.clone(), false);
        assert_eq!(text.lines().count(), 14);
        assert!(text.lines().any(|l| l == "S45B    9"), "{text}");
        assert!(text.lines().any(|l| l == "S37   254"), "{text}");
        let v: Value = serde_json::from_str(&output(TrcCommand::Rotaries, sim, true)).unwrap();
        let map = v["rotaries"].as_object().unwrap();
        assert_eq!(map.len(), 14);
        assert_eq!(map["S45B"], 9);
        assert_eq!(map["S37"], 254);
        assert_eq!(map["S41A"], 0);
    }

    #[test]
    fn relay_selects_and_says_so() {
        let mut trc = sim_board(Trc1000Sim::new());
        let mut out = Vec::new();
        let cmd = TrcCommand::Relay { n: 6 };
        execute(&cmd, &mut trc, true, &mut out, &AtomicBool::new(false)).unwrap();
        assert_eq!(trc.link_mut().device().relay().number(), 6);
        let v: Value = serde_json::from_slice(&out).unwrap();
        assert_eq!(v["relay"], 6);
    }

    #[test]
    fn panel_watch_reports_presses_releases_and_signed_turns() {
        let mut sim = Trc1000Sim::new();
        sim.press("S1").unwrap();
        sim.turn("S41A", -1).unwrap();
        let mut trc = sim_board(sim);
        let mut watch = PanelWatch::start(&mut trc).unwrap();
        assert_eq!(watch.poll(&mut trc).unwrap(), vec![]);
        let sim = trc.link_mut().device();
        sim.release("S1").unwrap();
        sim.press("S38").unwrap();
        sim.turn("S41A", 2).unwrap();
        sim.turn("S40", -3).unwrap();
        let events = watch.poll(&mut trc).unwrap();
        let text: Vec<String> = events.iter().map(PanelEvent::text).collect();
        assert_eq!(
            text,
            vec![
                "S38 pressed",
                "S1 released",
                "S41A +2 (now 1)",
                "S40 -3 (now 253)"
            ]
        );
        assert_eq!(
            events[3].json(),
            json!({ "event": "turned", "rotary": "S40", "delta": -3, "value": 253 })
        );
        assert_eq!(watch.poll(&mut trc).unwrap(), vec![]);
    }

    #[test]
    fn monitor_stops_when_told() {
        let mut trc = sim_board(Trc1000Sim::new());
        let mut out = Vec::new();
        let stop = AtomicBool::new(true);
        let cmd = TrcCommand::Monitor { interval: 1 };
        execute(&cmd, &mut trc, false, &mut out, &stop).unwrap();
        assert!(out.is_empty());
    }

    #[test]
    fn unreachable_boards_exit_3_and_other_failures_exit_1() {
        let nf = CliError::from(LinkError::NotFound {
            what: "TRC1000 unit 1".into(),
            hint: "plug it in".into(),
        });
        assert_eq!(nf.exit_status(), EXIT_UNREACHABLE);
        let timeout = CliError::Device(Trc1000Error::Timeout {
            board: "b".into(),
            request: "r".into(),
            timeout: Duration::from_millis(1),
            discarded: 0,
        });
        assert_eq!(timeout.exit_status(), EXIT_FAILED);
        let mut out = Vec::new();
        assert_eq!(crate::cli::output::report_error(&nf, true, &mut out), 3);
        let v: Value = serde_json::from_slice(&out).unwrap();
        assert_eq!(v["status"], 3);
        assert!(v["error"].as_str().unwrap().contains("TRC1000 unit 1"));
    }
}
