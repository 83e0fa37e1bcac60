//! The guardian's targets, measured against real processes and the simulated TRP-C29U on a
//! real pty (a module without a host watchdog: only the runner or its guardian can make it
//! safe): `kill -9` of the runner at random moments of a run that drives its outputs every
//! tick, and the time from the kill until the module's outputs read back safe; the same for
//! `kill -9` of the pid that was started (the guardian: the runner stops in order); the
//! guardian's resident memory.
//!
//! Run: `cargo bench --bench guardian` (100 kills of each kind; `GUARDIAN_BENCH_KILLS=N`).
//! `cargo test` runs it with 1 of each, so it never silently drops out.

#[path = "../tests/common/mod.rs"]
mod common;

#[path = "common/args.rs"]
mod args;

#[path = "common/percentile.rs"]
mod percentile;
use percentile::percentile;

use args::BenchArgs;
use common::{rigscript, SimProcess, TempDir};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Whom the kill is for.
#[derive(Clone, Copy, PartialEq)]
enum Victim {
    /// The runner, the guardian's child: the guardian acts.
    Runner,
    /// The pid that was started, the guardian: the runner stops in order.
    Guardian,
}

fn main() {
    let args = BenchArgs::from_env();
    let kills: usize = std::env::var("GUARDIAN_BENCH_KILLS")
        .ok()
        .and_then(|n| n.parse().ok())
        .unwrap_or(if args.full { 100 } else { 1 });
    let mut sim = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let dir = TempDir::new("bench-guardian");
    let config = dir.file(
        "rig.toml",
        &format!(
            "period = \"20ms\"\n[devices.io]\nkind = \"trp-c29u\"\nport = \"{}\"\nsafe_value = 0x00\n",
            sim.path
        ),
    );
    // Never 0x00 while it runs: the kill cannot land on outputs that are safe by chance.
    let script = dir.file(
        "toggle.rhai",
        "io.outputs = 0x0F;\nevery(\"20ms\", || { io.outputs = io.outputs ^ 0xFF; });\n",
    );
    println!("guardian: {kills} kill -9 of each, module without a watchdog, 20 ms toggling");
    let mut rss = Vec::new();
    for victim in [Victim::Runner, Victim::Guardian] {
        let mut times = Vec::new();
        let mut unsafe_ends = 0;
        for i in 0..kills {
            let run = start(&config, &script);
            wait_until(&mut sim, |d| d != 0);
            if i == 0 && victim == Victim::Runner {
                rss.push(resident_kib(run.id()));
            }
            std::thread::sleep(Duration::from_millis(fastrand::u64(0..300)));
            match kill_and_time(&mut sim, run, victim) {
                Some(t) => times.push(t),
                None => unsafe_ends += 1,
            }
        }
        times.sort();
        let name = match victim {
            Victim::Runner => "kill -9 of the runner (the guardian acts)",
            Victim::Guardian => "kill -9 of the started pid (the runner stops in order)",
        };
        println!(
            "  {name}: {}/{kills} safe within 10 s; kill to outputs read safe: p50 {}, p99 {}, max {}",
            kills - unsafe_ends,
            ms(percentile(&times, 50.0)),
            ms(percentile(&times, 99.0)),
            ms(times.last().copied()),
        );
    }
    for kib in rss.into_iter().flatten() {
        println!("  guardian resident memory while the run goes on: {kib} KiB (VmRSS)");
    }
}

fn start(config: &str, script: &str) -> Child {
    Command::new(rigscript())
        .args(["run", "--quiet", "--config", config, script])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start rigscript run")
}

/// Polls the module until its outputs satisfy `pred`, for at most 10 s; whether they did.
fn wait_until(sim: &mut SimProcess, pred: impl Fn(u64) -> bool) -> bool {
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(10) {
        if sim.state()["do"].as_u64().is_some_and(&pred) {
            return true;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    false
}

/// Kills `victim` of `run` with SIGKILL; how long until the module's outputs read 0x00
/// (`None`: not within 10 s).
fn kill_and_time(sim: &mut SimProcess, mut run: Child, victim: Victim) -> Option<Duration> {
    let pid = match victim {
        Victim::Runner => runner_of(run.id())?,
        Victim::Guardian => run.id(),
    };
    let killed = Instant::now();
    Command::new("kill")
        .args(["-KILL", &pid.to_string()])
        .status()
        .ok()?;
    let safe = wait_until(sim, |d| d == 0).then(|| killed.elapsed());
    let _ = run.wait();
    if victim == Victim::Guardian {
        // The runner outlives the started pid by its orderly end; let it finish.
        let start = Instant::now();
        while std::path::Path::new(&format!("/proc/{pid}")).exists()
            && start.elapsed() < Duration::from_secs(10)
        {
            std::thread::sleep(Duration::from_millis(5));
        }
    }
    safe
}

fn runner_of(guardian: u32) -> Option<u32> {
    let path = format!("/proc/{guardian}/task/{guardian}/children");
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(10) {
        let text = std::fs::read_to_string(&path).unwrap_or_default();
        if let Some(pid) = text.split_whitespace().next() {
            return pid.parse().ok();
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    None
}

fn resident_kib(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
}

fn ms(d: Option<Duration>) -> String {
    d.map_or("-".into(), |d| format!("{:.1} ms", d.as_secs_f64() * 1e3))
}
