//! Read and drive a TRP-C29U from Rust, in either of its protocols, with the driver rigscript
//! uses for real modules: outputs, inputs, counters, and the host watchdog taking the outputs
//! to their safe value.
//!
//! ```sh
//! cargo run --example c29u                  # simulated modules: Modbus RTU, then ASCII
//! rigscript sim c29u --link /tmp/c29u &     # or a simulator on a pty, as a real port
//! cargo run --example c29u -- --port /tmp/c29u
//! cargo run --example c29u -- --port /dev/ttyUSB0 --protocol ascii --id 1   # a real module
//! ```
//!
//! On a real module this drives the outputs (disconnect loads first) and leaves them off with
//! the watchdog disabled. On the simulator the program also plays the field side (energizes
//! inputs, pulses one) and checks that the driver saw it.

use clap::{Parser, ValueEnum};
use rigscript::device::c29u::{share, C29u, C29uError, C29uOptions, Protocol};
use rigscript::link::memory::MemoryByteLink;
use rigscript::sim::c29u::{C29uModel as Module, Eeprom, ModuleConfig};
use rigscript::sim::c29u_line::{lock, SharedModel, SimulatedC29u};
use rigscript::time::clock::SystemClock;
use std::error::Error;
use std::process::ExitCode;
use std::time::Duration;

/// Read and drive a TRP-C29U (simulated modules in both protocols unless --port is given).
#[derive(Debug, Parser)]
struct Args {
    /// A real module's serial port, or tcp://HOST:PORT of a serial device server.
    #[arg(long)]
    port: Option<String>,
    /// The protocol its DIP switch selects (with --port).
    #[arg(long, value_enum, default_value_t = Wire::Modbus)]
    protocol: Wire,
    /// Its ID (with --port).
    #[arg(long, default_value_t = 1)]
    id: u8,
    /// Line speed (with --port).
    #[arg(long, default_value_t = 9600)]
    baud: u32,
    /// ASCII checksums on (with --port).
    #[arg(long)]
    checksum: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Wire {
    Modbus,
    Ascii,
}

/// What the program read back, for the checks.
#[derive(Debug, Default, PartialEq, Eq)]
struct Seen {
    outputs: Vec<u8>,
    inputs: Option<u8>,
    counter: Option<u16>,
    refused_in_safe_mode: bool,
    outputs_in_safe_mode: u8,
}

/// A simulated module behind an in-memory link: the driver sends it real frames.
fn simulated(protocol: Protocol, checksum: bool) -> Result<(C29u, SharedModel), C29uError> {
    let clock = SystemClock::shared();
    let eeprom = Eeprom {
        config: ModuleConfig {
            checksum,
            ..ModuleConfig::factory()
        },
        ..Eeprom::factory()
    };
    let module = SimulatedC29u::new(Module::new(protocol, clock.clone(), eeprom));
    let field = module.model();
    let link = MemoryByteLink::new(module, format!("TRP-C29U ({protocol})"));
    let options = C29uOptions {
        protocol,
        checksum,
        ..C29uOptions::default()
    };
    Ok((C29u::new(share(Box::new(link)), clock, options)?, field))
}

/// Reads and drives `io`; with `field`, also plays the field side of the simulator.
fn exercise(io: &mut C29u, field: Option<&SharedModel>) -> Result<Seen, Box<dyn Error>> {
    let mut seen = Seen::default();
    println!("{}", io.describe());
    println!("  name {:?}, firmware {}", io.name()?, io.firmware()?.text);

    io.write_outputs(0x21)?;
    seen.outputs.push(io.read_outputs()?);
    io.write_output(3, true)?;
    seen.outputs.push(io.read_outputs()?);
    println!(
        "  outputs {:#04x} then {:#04x}",
        seen.outputs[0], seen.outputs[1]
    );

    if let Some(field) = field {
        lock(field).set_inputs(0b0000_0101);
        lock(field).pulse(1, 3)?;
    }
    let inputs = io.read_inputs()?;
    let counter = io.read_counter(1)?;
    println!("  inputs {inputs:#04x} (bit n = DIn energized), DI1 counted {counter} pulses");
    seen.inputs = Some(inputs);
    seen.counter = Some(counter);
    io.clear_counter(1)?;

    // The host watchdog: fed, the outputs stay; starved, the module takes them to its safe
    // value by itself and refuses writes until the watchdog is turned off.
    io.set_watchdog(Some(Duration::from_millis(300)))?;
    for _ in 0..3 {
        std::thread::sleep(Duration::from_millis(100));
        io.host_ok()?;
    }
    std::thread::sleep(Duration::from_millis(500));
    match io.write_outputs(0xFF) {
        Err(C29uError::SafeMode { .. }) => seen.refused_in_safe_mode = true,
        Err(e) => return Err(e.into()),
        Ok(()) => {}
    }
    seen.outputs_in_safe_mode = io.read_outputs()?;
    println!(
        "  watchdog starved: outputs {:#04x} (the safe value), writes {}",
        seen.outputs_in_safe_mode,
        if seen.refused_in_safe_mode {
            "refused"
        } else {
            "accepted"
        }
    );
    io.set_watchdog(None)?;
    io.write_outputs(0x00)?;
    Ok(seen)
}

/// Both protocols on simulated modules; returns what each run saw.
fn simulated_tour() -> Result<Vec<Seen>, Box<dyn Error>> {
    let mut all = Vec::new();
    for (protocol, checksum) in [(Protocol::Modbus, false), (Protocol::Ascii, true)] {
        let (mut io, field) = simulated(protocol, checksum)?;
        all.push(exercise(&mut io, Some(&field))?);
    }
    Ok(all)
}

fn run(args: &Args) -> Result<(), Box<dyn Error>> {
    match &args.port {
        None => simulated_tour().map(|_| ()),
        Some(port) => {
            let options = C29uOptions {
                protocol: match args.protocol {
                    Wire::Modbus => Protocol::Modbus,
                    Wire::Ascii => Protocol::Ascii,
                },
                id: args.id,
                baud: args.baud,
                checksum: args.checksum,
                ..C29uOptions::default()
            };
            let mut io = C29u::open(port, SystemClock::shared(), options)?;
            exercise(&mut io, None).map(|_| ())
        }
    }
}

fn main() -> ExitCode {
    match run(&Args::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("c29u: {e}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_protocols_read_and_drive_the_simulated_module() {
        let seen = simulated_tour().unwrap();
        assert_eq!(seen.len(), 2);
        for s in seen {
            assert_eq!(s.outputs, [0x21, 0x29]);
            assert_eq!(s.inputs, Some(0x05));
            assert_eq!(s.counter, Some(3));
            assert!(s.refused_in_safe_mode, "{s:?}");
            assert_eq!(s.outputs_in_safe_mode, 0x00, "the factory safe value");
        }
    }

    #[test]
    fn the_command_line_reads_as_documented() {
        let a = Args::parse_from(["c29u", "--port", "/tmp/c29u", "--protocol", "ascii"]);
        assert_eq!(a.port.as_deref(), Some("/tmp/c29u"));
        assert_eq!(a.protocol, Wire::Ascii);
        assert!(Args::try_parse_from(["c29u", "--protocol", "rtu"]).is_err());
    }
}
