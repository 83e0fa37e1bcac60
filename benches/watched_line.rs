//! A watched rig on a slow line: `rigscript run` with one TRP-C29U at 9600 baud (Modbus RTU,
//! through a baud-accurate line, `sim::timed_line`) and the default 20 ms period, unwatched and
//! then watched (a client following the page's event stream, as an open page does), for two
//! scripts: one that reads the DI byte every tick (`io.on_rise`) and one that reads nothing a
//! tick (as a tripped interlock). Prints each run's ticks, overruns, tick work and transactions
//! (`--stats`), and the module's requests a second: what reading the whole image for watchers
//! costs on the wire. Target: a watched rig keeps its period (no overrun).
//!
//! Run: `cargo bench --bench watched_line` (10 s a run); `cargo test` runs each for 1 s.

mod common;

#[path = "common/args.rs"]
mod args;

use args::BenchArgs;
use common::{counting_module, idle_after};
use rigscript::protocol::c29u::Protocol;
use rigscript::sim::timed_line::TimedLine;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::atomic::Ordering;
use std::time::Instant;

const BAUD: u32 = 9600;

fn main() {
    let args = BenchArgs::from_env();
    let run_for = if args.full { "10s" } else { "1s" };
    let dir = tempfile::tempdir().expect("a temporary directory");
    println!("one TRP-C29U at {BAUD} baud (Modbus RTU), period 20 ms, {run_for} a run");
    let scripts = [
        ("reads DI each tick", "io.on_rise(0, || {});\n"),
        ("reads nothing a tick", "every(\"1s\", || {});\n"),
    ];
    for (name, script) in scripts {
        if !args.picks(name) {
            continue;
        }
        for watched in [false, true] {
            let line = measure(dir.path(), script, watched, run_for);
            let who = if watched { "watched" } else { "unwatched" };
            println!("{name:<22} {who:<10} {line}");
        }
    }
}

/// One run of `script`; its figures on one line.
fn measure(dir: &Path, script: &str, watched: bool, run_for: &str) -> String {
    let (module, answered) = counting_module(Protocol::Modbus, BAUD);
    let relay = TimedLine::with_device(module, BAUD, idle_after(BAUD)).expect("start the relay");
    let config = dir.join("rig.toml");
    std::fs::write(
        &config,
        format!(
            "[devices.io]\nkind = \"trp-c29u\"\nport = \"{}\"\nbaud = {BAUD}\n",
            relay.path()
        ),
    )
    .expect("write rig.toml");
    let file = dir.join("script.rhai");
    std::fs::write(&file, format!("let io = device(\"io\");\n{script}")).expect("the script");
    let mut child = Command::new(env!("CARGO_BIN_EXE_rigscript"))
        .arg("run")
        .arg(&file)
        .arg("--config")
        .arg(&config)
        .args([
            "--ui",
            "127.0.0.1:0",
            "--stats",
            "--quiet",
            "--for",
            run_for,
        ])
        .env("XDG_RUNTIME_DIR", dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start rigscript");
    let mut err = BufReader::new(child.stderr.take().expect("stderr"));
    let mut seen = String::new();
    let addr = loop {
        let mut line = String::new();
        if err.read_line(&mut line).expect("read stderr") == 0 {
            panic!("rigscript ended before serving its page: {seen}");
        }
        seen.push_str(&line);
        if let Some(at) = line.split("ui: http://").nth(1) {
            break at.split('/').next().unwrap_or_default().to_string();
        }
    };
    let before = answered.load(Ordering::Relaxed);
    let started = Instant::now();
    // A viewer: the page's event stream, read to its end.
    let viewer = watched.then(|| {
        let mut s = TcpStream::connect(&addr).expect("connect to the page");
        let ask = format!("GET /api/events HTTP/1.1\r\nHost: {addr}\r\n\r\n");
        s.write_all(ask.as_bytes()).expect("ask for the stream");
        std::thread::spawn(move || {
            let mut sink = Vec::new();
            let _ = s.read_to_end(&mut sink);
            String::from_utf8_lossy(&sink[..sink.len().min(200)]).into_owned()
        })
    });
    let mut rest = String::new();
    err.read_to_string(&mut rest).expect("read stderr");
    let mut out = String::new();
    child
        .stdout
        .take()
        .expect("stdout")
        .read_to_string(&mut out)
        .expect("read stdout");
    let status = child.wait().expect("rigscript ends");
    let requests = answered.load(Ordering::Relaxed).saturating_sub(before);
    let per_second = requests as f64 / started.elapsed().as_secs_f64();
    if let Some(v) = viewer {
        let head = v.join().expect("the viewer's thread");
        assert!(
            head.starts_with("HTTP/1.1 200"),
            "the viewer was refused: {head}"
        );
    }
    assert!(status.success(), "rigscript failed: {seen}{rest}{out}");
    let all = format!("{rest}{out}");
    let stat = |key: &str| {
        all.lines()
            .find_map(|l| l.strip_prefix(key))
            .map_or("?".to_string(), |v| v.trim().to_string())
    };
    format!(
        "ticks {:>4}  overruns {:>2}  tick work {}  transactions/tick {}  module requests/s {per_second:.1}",
        stat("ticks:"),
        stat("overruns:"),
        stat("tick work:"),
        stat("transactions per tick:"),
    )
}
