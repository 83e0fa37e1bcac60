//! A lost device against the grace time, measured against real processes: two simulated
//! TRP-C29U modules without host watchdogs, `grace = "1s"`, a script whose only timer fires
//! every 30 s (nothing polls). One module is lost and the time is taken until the other reads
//! back its safe value. Target: within grace + 1 s (2 s). Three ways to lose it: its pty hangs
//! up (the simulator killed, as an unplugged USB-serial adapter), its TCP serial server closes
//! the connection, and its line goes silent behind a server that stays up (only a question
//! tells: the runner asks a device nobody reads every quarter of the grace time).
//!
//! Run: `cargo bench --bench loss` (20 losses of each; `LOSS_BENCH_RUNS=N`). `cargo test`
//! runs it with 1 of each, so it never silently drops out.

#[path = "../tests/common/mod.rs"]
mod common;

#[path = "common/args.rs"]
mod args;

#[path = "common/percentile.rs"]
mod percentile;
use percentile::percentile;

use args::BenchArgs;
use common::{lose_a_module, start_relay, start_switchable_relay, Cut};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

/// What makes the lost module's port of its pty.
type Port = Box<dyn FnOnce(&str) -> String>;

/// How long after the loss the other module must read safe: grace + 1 s.
const TARGET: Duration = Duration::from_secs(2);

fn main() {
    let args = BenchArgs::from_env();
    let runs: usize = std::env::var("LOSS_BENCH_RUNS")
        .ok()
        .and_then(|n| n.parse().ok())
        .unwrap_or(if args.full { 20 } else { 1 });
    println!("loss: {runs} of each, grace 1s, two modules without watchdogs, one 30 s timer");
    for way in ["pty hang-up", "tcp close", "silent line"] {
        if !args.picks(way) {
            continue;
        }
        let mut times = Vec::new();
        let mut late = 0;
        for _ in 0..runs {
            // A random moment against the loop's 100 ms look at the links and its probes.
            let settle = Duration::from_millis(fastrand::u64(0..500));
            let silent = Arc::new(AtomicBool::new(false));
            let (port, cut): (Port, Cut) = match way {
                "pty hang-up" => (Box::new(str::to_string), Cut::Kill),
                "tcp close" => (
                    Box::new(|pty: &str| format!("tcp://127.0.0.1:{}", start_relay(pty))),
                    Cut::Kill,
                ),
                _ => {
                    let flag = Arc::clone(&silent);
                    (
                        Box::new(move |pty: &str| {
                            format!("tcp://127.0.0.1:{}", start_switchable_relay(pty, flag))
                        }),
                        Cut::Silence(silent),
                    )
                }
            };
            let loss = lose_a_module("bench-loss", port, (cut, settle), Duration::from_secs(10));
            match loss.to_safe {
                Some(t) => {
                    late += usize::from(t > TARGET);
                    times.push(t);
                }
                None => late += 1,
            }
        }
        times.sort();
        println!(
            "  {way}: loss to the other module read safe: p50 {}, p99 {}, max {}; {}/{runs} \
             within grace + 1 s",
            ms(percentile(&times, 50.0)),
            ms(percentile(&times, 99.0)),
            ms(times.last().copied()),
            runs - late,
        );
    }
}

fn ms(d: Option<Duration>) -> String {
    d.map_or_else(|| "-".into(), |d| format!("{} ms", d.as_millis()))
}
