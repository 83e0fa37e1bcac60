//! Request round trips per second through the real TRP-C29U driver over a pseudo-terminal to
//! the simulator served in this process, for each protocol. Run: `cargo bench --bench roundtrip`.

use rigscript::device::c29u::{share, C29u, C29uOptions, Protocol};
use rigscript::link::serial::SerialLink;
use rigscript::protocol::c29u_modbus::silence_gap;
use rigscript::sim::c29u::{C29uModel as Model, Eeprom};
use rigscript::sim::c29u_line::SimulatedC29u;
use rigscript::sim::pty::{Faults, PtyServer};
use rigscript::time::clock::SystemClock;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Round trips measured per protocol (after a short warm-up).
const ROUND_TRIPS: u32 = 2000;
const WARM_UP: u32 = 50;
const BAUD: u32 = 9600;

/// The simulator on a pty in a thread; stops when dropped.
struct Served {
    path: String,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Served {
    fn start(protocol: Protocol) -> Self {
        let mut server = PtyServer::open(None).expect("create a pty");
        let path = server.path().to_string();
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = Arc::clone(&stop);
        let thread = std::thread::spawn(move || {
            let model = Model::new(protocol, SystemClock::shared(), Eeprom::factory());
            let mut device = SimulatedC29u::new(model);
            server
                .serve(&mut device, &Faults::default(), silence_gap(BAUD), &stop2)
                .expect("serve the simulator");
        });
        Self {
            path,
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

/// Round trips per second of `count` `request`s on a fresh simulator.
fn measure(protocol: Protocol, count: u32, request: fn(&mut C29u)) -> f64 {
    let served = Served::start(protocol);
    let link = SerialLink::open(&served.path, BAUD).expect("open the pty");
    let options = C29uOptions {
        protocol,
        timeout: Duration::from_millis(500),
        retries: 0,
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
    let args: Vec<String> = std::env::args().skip(1).collect();
    let count = if args.iter().any(|a| a == "--bench") {
        ROUND_TRIPS
    } else {
        20
    };
    // A filter argument selects protocols by name.
    let filter: Vec<&String> = args.iter().filter(|a| !a.starts_with("--")).collect();
    let wanted = |name: &str| filter.is_empty() || filter.iter().any(|f| name.contains(f.as_str()));
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
