//! Polling a TRP-C29U's inputs (FC01) as fast as the line allows: rigscript (`run` with
//! `--period 1us` and one `io.on_rise` handler) against a C loop over libmodbus's
//! `modbus_read_bits`, with and without t3.5 of silence before each request, all against the
//! same simulator (served in this process on a pty) in the same run.
//!
//! Through a baud-accurate line (`sim::relay`, each byte held 10 bit times) at 9600 and 115200
//! baud it reports polls per second (and the share of what a compliant master can reach: 14
//! characters and t3.5 a poll) and the 2nd and 50th percentiles of the silence each master
//! leaves before its requests; straight on the pty it reports how fast each can go. Every row
//! shows CPU time per poll of the polling process (user + system, from the scheduler's
//! accounting, start-up excluded).
//!
//! Run: `cargo bench --bench line` (10 s a row). `cargo test` runs it for half a second a row,
//! so the comparison never silently drops out; it needs gcc and libmodbus-dev.

use rigscript::link::line::wire_time;
use rigscript::protocol::c29u_modbus::silence_gap;
use rigscript::sim::c29u::{C29u as Model, Eeprom, ModuleConfig};
use rigscript::sim::c29u_line::SimulatedC29u;
use rigscript::sim::pty::{Faults, PtyServer};
use rigscript::sim::relay::LineRelay;
use rigscript::sim::wire::Side;
use rigscript::sim::ByteDevice;
use rigscript::time::clock::SystemClock;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The simulator, counting the requests it answers.
struct Counting<D> {
    inner: D,
    answered: Arc<AtomicU64>,
}

impl<D: ByteDevice> ByteDevice for Counting<D> {
    fn receive(&mut self, bytes: &[u8]) -> Vec<u8> {
        let answer = self.inner.receive(bytes);
        if !answer.is_empty() {
            self.answered.fetch_add(1, Ordering::Relaxed);
        }
        answer
    }

    fn line_idle(&mut self) -> Vec<u8> {
        self.inner.line_idle()
    }
}

/// A simulated module at `baud` on a pty in a thread; stops when dropped.
struct Served {
    path: String,
    answered: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Served {
    fn start(baud: u32) -> Self {
        let mut server = PtyServer::open(None).expect("create a pty");
        let path = server.path().to_string();
        let stop = Arc::new(AtomicBool::new(false));
        let answered = Arc::new(AtomicU64::new(0));
        let (stop2, answered2) = (Arc::clone(&stop), Arc::clone(&answered));
        let thread = std::thread::spawn(move || {
            let eeprom = Eeprom {
                config: ModuleConfig {
                    baud_code: rigscript::protocol::c29u::baud_code(baud).expect("a module baud"),
                    ..ModuleConfig::factory()
                },
                ..Eeprom::factory()
            };
            let model = Model::new(
                rigscript::protocol::c29u::Protocol::Modbus,
                SystemClock::shared(),
                eeprom,
            );
            let mut device = Counting {
                inner: SimulatedC29u::new(model),
                answered: answered2,
            };
            server
                .serve(&mut device, &Faults::default(), silence_gap(baud), &stop2)
                .expect("serve the simulator");
        });
        Self {
            path,
            answered,
            stop,
            thread: Some(thread),
        }
    }
}

impl Drop for Served {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Who polls.
#[derive(Clone, Copy)]
enum Master {
    /// `rigscript run`, with `frame_gap = "auto"` (t3.5) or `"0s"`.
    Rigscript { gap: bool },
    /// The C loop over libmodbus, sleeping t3.5 before each request or not at all.
    Libmodbus { gap: bool },
}

impl Master {
    fn name(self) -> &'static str {
        match self {
            Master::Rigscript { gap: true } => "rigscript",
            Master::Rigscript { gap: false } => "rigscript, frame_gap 0s",
            Master::Libmodbus { gap: true } => "libmodbus + t3.5 sleep",
            Master::Libmodbus { gap: false } => "libmodbus back to back",
        }
    }
}

/// Builds the C loop with gcc against libmodbus; fails loudly (never skips) without them.
fn build_c_loop() -> PathBuf {
    let source = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/line/modbus_poll.c");
    let binary = Path::new(env!("CARGO_TARGET_TMPDIR")).join("modbus_poll");
    let status = Command::new("gcc")
        .args(["-O2", "-Wall", "-Werror", "-I/usr/include/modbus", "-o"])
        .arg(&binary)
        .arg(&source)
        .arg("-lmodbus")
        .status()
        .unwrap_or_else(|e| panic!("cannot run gcc ({e}): install gcc (and libmodbus-dev)"));
    assert!(
        status.success(),
        "gcc could not build {}: install libmodbus-dev (`.ci/run` does)",
        source.display()
    );
    binary
}

/// Starts `master` polling `port` at `baud`.
fn start(master: Master, port: &str, baud: u32, c_loop: &Path, dir: &Path) -> Child {
    let t35 = silence_gap(baud);
    let mut command = match master {
        Master::Rigscript { gap } => {
            let config = dir.join(format!("rig-{baud}-{gap}.toml"));
            let frame_gap = if gap { "auto" } else { "0s" };
            std::fs::write(
                &config,
                format!(
                    "[devices.io]\nkind = \"trp-c29u\"\nport = \"{port}\"\nbaud = {baud}\n\
                     timeout = \"1s\"\nframe_gap = \"{frame_gap}\"\n"
                ),
            )
            .expect("write rig.toml");
            let script = dir.join("poll.rhai");
            std::fs::write(&script, "io.on_rise(0, || {});\n").expect("write the script");
            let mut c = Command::new(env!("CARGO_BIN_EXE_rigscript"));
            c.arg("run")
                .arg(&script)
                .arg("--config")
                .arg(&config)
                .args(["--period", "1us", "--wake-latency", "off", "--quiet"]);
            c
        }
        Master::Libmodbus { gap } => {
            let gap_us = if gap { t35.as_micros() } else { 0 };
            let mut c = Command::new(c_loop);
            c.arg(port).arg(baud.to_string()).arg(gap_us.to_string());
            c
        }
    };
    command
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {}: {e}", master.name()))
}

/// CPU time of every thread of `pid` (user + system), from the scheduler's accounting.
fn cpu_time(pid: u32) -> Duration {
    let tasks = std::fs::read_dir(format!("/proc/{pid}/task")).expect("the master is running");
    let nanos: u64 = tasks
        .flatten()
        .filter_map(|t| std::fs::read_to_string(t.path().join("schedstat")).ok())
        .filter_map(|s| s.split_whitespace().next()?.parse::<u64>().ok())
        .sum();
    Duration::from_nanos(nanos)
}

fn percentile(sorted: &[Duration], p: f64) -> Option<Duration> {
    if sorted.is_empty() {
        return None;
    }
    let rank = ((sorted.len() - 1) as f64 * p / 100.0).round() as usize;
    sorted.get(rank).copied()
}

fn ms(d: Option<Duration>) -> String {
    d.map_or("-".into(), |d| format!("{:.3}", d.as_secs_f64() * 1e3))
}

/// One row: `master` polling for `window` after `warm_up`, through a relay at `baud` or
/// (`relayed` false) straight on the pty.
fn measure(
    master: Master,
    baud: u32,
    relayed: bool,
    (warm_up, window): (Duration, Duration),
    c_loop: &Path,
    dir: &Path,
) {
    let served = Served::start(baud);
    let relay = relayed.then(|| LineRelay::start(&served.path, baud).expect("start the relay"));
    let port = relay
        .as_ref()
        .map_or(served.path.clone(), |r| r.path().to_string());
    let child = start(master, &port, baud, c_loop, dir);
    std::thread::sleep(warm_up);
    let (cpu0, polls0, at0) = (
        cpu_time(child.id()),
        served.answered.load(Ordering::Relaxed),
        Instant::now(),
    );
    let mark0 = relay.as_ref().map(LineRelay::now);
    std::thread::sleep(window);
    let (cpu1, polls1, elapsed) = (
        cpu_time(child.id()),
        served.answered.load(Ordering::Relaxed),
        at0.elapsed(),
    );
    let mark1 = relay.as_ref().map(LineRelay::now);
    let _ = Command::new("kill")
        .arg("-TERM")
        .arg(child.id().to_string())
        .status();
    let output = child.wait_with_output().expect("the master ends");
    assert!(
        output.status.success(),
        "{} failed: {}",
        master.name(),
        String::from_utf8_lossy(&output.stderr)
    );
    let polls = polls1.saturating_sub(polls0);
    assert!(polls > 0, "{} made no poll in {window:?}", master.name());
    let rate = polls as f64 / elapsed.as_secs_f64();
    let cpu_us = cpu1.saturating_sub(cpu0).as_secs_f64() * 1e6 / polls as f64;
    let t35 = silence_gap(baud);
    let (setup, share, p2, p50) = match (relay, mark0, mark1) {
        (Some(relay), Some(from), Some(to)) => {
            let mut silences: Vec<Duration> = relay
                .stop()
                .expect("stop the relay")
                .into_iter()
                .filter(|f| f.side == Side::Master && f.start >= from && f.start <= to)
                .filter_map(|f| f.silence)
                .collect();
            silences.sort();
            let ideal = 1.0 / (wire_time(14, baud) + t35).as_secs_f64();
            (
                format!("{baud} baud line"),
                format!("{:.0}%", rate / ideal * 100.0),
                percentile(&silences, 2.0),
                percentile(&silences, 50.0),
            )
        }
        _ => ("raw pty".to_string(), "-".to_string(), None, None),
    };
    println!(
        "| {setup} | {} | {rate:.1} | {share} | {} | {} | {:.3} | {cpu_us:.1} |",
        master.name(),
        ms(p2),
        ms(p50),
        t35.as_secs_f64() * 1e3,
    );
}

fn main() {
    let full = std::env::args().skip(1).any(|a| a == "--bench");
    let times = if full {
        (Duration::from_secs(1), Duration::from_secs(10))
    } else {
        (Duration::from_millis(300), Duration::from_millis(500))
    };
    let c_loop = build_c_loop();
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("line-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a scratch directory");
    println!(
        "| setup | master | polls/s | of 14 chars + t3.5 | silence p2 ms | silence p50 ms | t3.5 ms | CPU µs/poll |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    let with_gap = [
        Master::Rigscript { gap: true },
        Master::Libmodbus { gap: true },
        Master::Libmodbus { gap: false },
    ];
    for baud in [9600, 115_200] {
        for master in with_gap {
            measure(master, baud, true, times, &c_loop, &dir);
        }
    }
    let raw = [
        Master::Rigscript { gap: true },
        Master::Libmodbus { gap: true },
        Master::Rigscript { gap: false },
        Master::Libmodbus { gap: false },
    ];
    for master in raw {
        measure(master, 115_200, false, times, &c_loop, &dir);
    }
    let _ = std::fs::remove_dir_all(dir);
}
