//! Run a Rhai script from Rust on a rig assembled in code: a TRC1000 `panel` and a TRP-C29U
//! `io` named and configured here instead of in a rig.toml, run in the supervised scan loop
//! exactly as `rigscript run` runs it (safe state at the end, host watchdog fed).
//!
//! ```sh
//! cargo run --example script_on_rig                 # simulated devices; a second thread
//!                                                   # turns a knob and pulses an input
//! cargo run --example script_on_rig -- --for 10s --real --port /dev/ttyUSB0   # real devices
//! ```

use clap::Parser;
use rigscript::config::{C29uConfig, Port, Trc1000Address, Trc1000Config, WatchdogTimeout};
use rigscript::time::duration::parse_duration;
use rigscript::SimRig;
use rigscript::{Rig, RigBuilder};
use std::error::Error;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::AtomicUsize;
use std::sync::Arc;
use std::time::Duration;

/// The script: a heartbeat on DO7, the relay following rotary S41A, and the pulses counted on
/// DI0 measured every half second.
const SCRIPT: &str = r#"
let beats = 0;
every("250ms", || {
    io.set_output(7, !io.output(7));
    beats += 1;
});
panel.on_turn("S41A", |delta, value| {
    panel.relay = value % 8;
    log("relay " + panel.relay + " (S41A at " + value + ")");
});
every("500ms", || measure("di0_pulses", io.counter(0), #{ max: 100, unit: "pulses" }));
on_stop(|| log(beats + " heartbeats"));
"#;

/// Run a script on a TRC1000 `panel` and a TRP-C29U `io` assembled in code (simulated
/// unless --real).
#[derive(Debug, Parser)]
struct Args {
    /// How long to run ("2s", "5m").
    #[arg(long = "for", value_name = "DURATION", default_value = "2s", value_parser = duration)]
    run_for: Duration,
    /// Use real devices: the TRP-C29U on --port (Modbus ID 1), the TRC1000 at unit 0.
    #[arg(long)]
    real: bool,
    /// The TRP-C29U's serial port (with --real).
    #[arg(long, default_value = "/dev/ttyUSB0")]
    port: PathBuf,
}

fn duration(text: &str) -> Result<Duration, String> {
    parse_duration(text).map_err(|e| e.to_string())
}

/// The rig, in code: what a rig.toml would say.
fn rig(real: bool, port: PathBuf) -> RigBuilder {
    let io = C29uConfig {
        safe_value: 0x00,
        // The module drives its outputs safe by itself if this program stops feeding it.
        watchdog: WatchdogTimeout::from_duration(Duration::from_secs(2)),
        ..C29uConfig::with_defaults(if real {
            Port::Serial(port)
        } else {
            Port::Simulated
        })
    };
    let panel = Trc1000Config {
        address: Trc1000Address::Unit(0),
        safe_relay: Some(0),
        names: Default::default(),
    };
    let builder = RigBuilder::new().c29u("io", io).trc1000("panel", panel);
    if real {
        builder
    } else {
        builder.simulated()
    }
}

/// The field side while the script runs: a person turns S41A and a sensor pulses DI0.
fn play_field(sim: SimRig) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(200));
        // Errors here would be programming errors in the names: the simulator has both.
        let _ = sim.turn("panel", "S41A", 3);
        let _ = sim.pulse("io", 0, 5);
    })
}

/// Runs the script to its end (its log on stderr if `log_to_stderr`); returns the exit status
/// and the rig (records, log) it leaves.
fn run_script(
    args: &Args,
    stop: Arc<AtomicUsize>,
    log_to_stderr: bool,
) -> Result<(i32, Rig), Box<dyn Error>> {
    let mut rig = rig(args.real, args.port.clone())
        .run_for(args.run_for)
        .log_to_stderr(log_to_stderr)
        .keep_log()
        .stop_flag(stop)
        .start(SCRIPT, "script_on_rig.rhai")?;
    let field = (!rig.sim.is_empty()).then(|| play_field(rig.sim.clone()));
    let status = rig.runner.run();
    if let Some(f) = field {
        let _ = f.join();
    }
    Ok((status, rig))
}

fn main() -> ExitCode {
    let args = Args::parse();
    let stop = Arc::new(AtomicUsize::new(0));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        // The flag holds the signal's number: the exit status is 128 + it.
        let number = usize::try_from(signal).unwrap_or(1);
        if let Err(e) = signal_hook::flag::register_usize(signal, Arc::clone(&stop), number) {
            eprintln!("script_on_rig: cannot watch for signal {signal}: {e}");
            return ExitCode::FAILURE;
        }
    }
    match run_script(&args, stop, true) {
        Ok((status, rig)) => {
            for record in rig.records() {
                println!("{record}");
            }
            ExitCode::from(u8::try_from(status).unwrap_or(1))
        }
        Err(e) => {
            eprintln!("script_on_rig: {e}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_script_runs_on_the_rig_in_code_and_sees_the_field() {
        let args = Args::parse_from(["script_on_rig", "--for", "1200ms"]);
        let (status, rig) = run_script(&args, Arc::default(), false).unwrap();
        let log = rig.log().join("\n");
        assert_eq!(status, 0, "{log}");
        let records = rig.records();
        let last = records.last().expect("measurements");
        assert_eq!(last["name"], "di0_pulses");
        assert_eq!(last["value"], 5.0, "{log}");
        assert!(log.contains("relay 3 (S41A at 3)"), "{log}");
        assert!(log.contains("heartbeats"), "on_stop ran: {log}");
        assert!(
            log.contains("safe state (end of run): io outputs 0x00, panel relay 0"),
            "{log}"
        );
    }
}
