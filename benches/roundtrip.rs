//! Request round trips per second through the real TRP-C29U driver over a pseudo-terminal to
//! the simulator served in this process, for each protocol, with no frame gap (a pty has no
//! wire). Run: `cargo bench --bench roundtrip`.

mod common;

#[path = "common/args.rs"]
mod args;
use args::BenchArgs;
use common::Served;
use rigscript::device::c29u::{share, C29u, C29uOptions, FrameGap, Protocol};
use rigscript::link::serial::SerialLink;
use rigscript::time::clock::SystemClock;
use std::time::{Duration, Instant};

/// Round trips measured per protocol (after a short warm-up).
const ROUND_TRIPS: u32 = 2000;
const WARM_UP: u32 = 50;
const BAUD: u32 = 9600;

/// Round trips per second of `count` `request`s on a fresh simulator.
fn measure(protocol: Protocol, count: u32, request: fn(&mut C29u)) -> f64 {
    let served = Served::start(protocol, BAUD);
    let link = SerialLink::open(&served.path, BAUD).expect("open the pty");
    let options = C29uOptions {
        protocol,
        timeout: Duration::from_millis(500),
        retries: 0,
        // The exchange itself; the silence a line needs is measured by benches/line.rs.
        frame_gap: FrameGap::Fixed(Duration::ZERO),
        ..C29uOptions::default()
    };
    let mut dev = C29u::new(share(Box::new(link)), SystemClock::shared(), options).unwrap();
    for _ in 0..WARM_UP {
        request(&mut dev);
    }
    let start = Instant::now();
    for _ in 0..count {
        request(&mut dev);
    }
    f64::from(count) / start.elapsed().as_secs_f64()
}

fn main() {
    // `cargo bench` passes `--bench`; `cargo test --all-targets` runs this without it, and then
    // a few round trips only check that the benchmark still works.
    let args = BenchArgs::from_env();
    let count = if args.full { ROUND_TRIPS } else { 20 };
    // A word selects protocols by name.
    let wanted = |name: &str| args.picks(name);
    if wanted("modbus") {
        let rate = measure(Protocol::Modbus, count, |d| {
            d.read_outputs().expect("read_outputs");
        });
        println!("modbus: {rate:.0} round trips/s (read_outputs, {count} requests over a pty)");
    }
    if wanted("ascii") {
        let rate = measure(Protocol::Ascii, count, |d| {
            d.read_io().expect("read_io");
        });
        println!("ascii: {rate:.0} round trips/s (read_io, {count} requests over a pty)");
    }
}
