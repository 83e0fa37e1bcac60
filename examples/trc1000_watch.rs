//! Watch a TRC1000 panel board from Rust: poll its switches and rotary encoders and print each
//! change, with the driver rigscript uses for real boards.
//!
//! ```sh
//! cargo run --example trc1000_watch                    # a simulated board, with a few
//!                                                      # presses and turns played on it
//! cargo run --example trc1000_watch -- --unit 0        # a real board (Ctrl-C to stop)
//! ```
//!
//! A real board needs USB access (packaging/udev/60-rigscript.rules).

use clap::Parser;
use rigscript::device::trc1000::{rotary_changes, Trc1000};
use rigscript::link::memory::MemoryPacketLink;
use rigscript::link::usb::{UsbPacketLink, UsbTarget};
use rigscript::link::PacketLink;
use rigscript::sim::trc1000::Trc1000Sim;
use std::error::Error;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Watch a TRC1000's switches and rotaries (a simulated board unless --unit is given).
#[derive(Debug, Parser)]
struct Args {
    /// A real board's DIP-switch unit (0-3).
    #[arg(long, value_parser = clap::value_parser!(u8).range(0..=3))]
    unit: Option<u8>,
    /// Time between polls, in milliseconds.
    #[arg(long, value_name = "MS", default_value_t = 20)]
    interval: u64,
    /// Stop after this many polls (default: a real board until Ctrl-C; the simulated one
    /// after its played events).
    #[arg(long)]
    polls: Option<u32>,
}

/// Polls `board` `polls` times (or until `stop`), calling `before_poll(board, n)` first each
/// time; returns every change seen, as printed.
fn watch<L: PacketLink>(
    board: &mut Trc1000<L>,
    polls: Option<u32>,
    interval: Duration,
    stop: &AtomicBool,
    mut before_poll: impl FnMut(&mut Trc1000<L>, u32),
) -> Result<Vec<String>, Box<dyn Error>> {
    println!("watching {}", board.describe());
    let mut switches = board.read_switches()?;
    let mut rotaries = board.read_rotaries()?;
    println!("  pressed at start: {:?}", switches.pressed_names());
    let mut seen = Vec::new();
    let mut n = 0;
    while polls.map_or(true, |p| n < p) && !stop.load(Ordering::Relaxed) {
        std::thread::sleep(interval);
        before_poll(board, n);
        n += 1;
        let before = seen.len();
        let now = board.read_switches()?;
        let (pressed, released) = switches.changes(&now);
        seen.extend(pressed.iter().map(|s| format!("{} pressed", s.name())));
        seen.extend(released.iter().map(|s| format!("{} released", s.name())));
        switches = now;
        let now = board.read_rotaries()?;
        for c in rotary_changes(&rotaries, &now) {
            seen.push(format!("{} turned {:+} to {}", c.name(), c.delta, c.value));
        }
        rotaries = now;
        for line in seen.iter().skip(before) {
            println!("  {line}");
        }
    }
    Ok(seen)
}

/// A simulated board with a few presses and turns played on it between polls.
fn simulated(interval: Duration) -> Result<Vec<String>, Box<dyn Error>> {
    let link = MemoryPacketLink::new(Trc1000Sim::new(), "TRC1000");
    let mut board = Trc1000::new(link);
    board.select_relay(5)?;
    println!(
        "selected relay 5; the board shows relay {}",
        board.link_mut().device().relay().number()
    );
    let stop = AtomicBool::new(false);
    watch(&mut board, Some(10), interval, &stop, |board, n| {
        let sim = board.link_mut().device();
        let played = match n {
            2 => sim.press("S3"),
            4 => sim.turn("S41A", 3),
            6 => sim.release("S3"),
            8 => sim.turn("S40", -2),
            _ => Ok(()),
        };
        played.expect("the simulator knows these names");
    })
}

fn run(args: &Args) -> Result<(), Box<dyn Error>> {
    let interval = Duration::from_millis(args.interval);
    let Some(unit) = args.unit else {
        return simulated(interval).map(|_| ());
    };
    let stop = Arc::new(AtomicBool::new(false));
    signal_hook::flag::register(signal_hook::consts::SIGINT, Arc::clone(&stop))?;
    let mut board = Trc1000::new(UsbPacketLink::open(UsbTarget::Unit(unit))?);
    watch(&mut board, args.polls, interval, &stop, |_, _| {}).map(|_| ())
}

fn main() -> ExitCode {
    match run(&Args::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("trc1000_watch: {e}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_press_release_and_turn_on_the_simulated_board_is_seen() {
        let seen = simulated(Duration::from_millis(1)).unwrap();
        assert_eq!(
            seen,
            [
                "S3 pressed",
                "S41A turned +3 to 3",
                "S3 released",
                "S40 turned -2 to 254"
            ]
        );
    }

    #[test]
    fn units_beyond_3_are_refused() {
        assert!(Args::try_parse_from(["trc1000_watch", "--unit", "4"]).is_err());
    }
}
