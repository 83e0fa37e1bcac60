//! What the benchmarks share: a simulated TRP-C29U served on a pty in a thread of the benchmark,
//! counting the requests it answers.

use rigscript::link::far_end::ByteDevice;
use rigscript::protocol::c29u::{baud_code, Protocol};
use rigscript::protocol::c29u_modbus::silence_gap;
use rigscript::sim::c29u::{C29uModel as Model, Eeprom, ModuleConfig};
use rigscript::sim::c29u_line::SimulatedC29u;
use rigscript::sim::faults::drawn::Drawn;
use rigscript::sim::pty::PtyServer;
use rigscript::time::clock::SystemClock;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// A device that counts the requests it answers.
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

/// A simulated module (ID 1, configured for `baud`) that counts the requests it answers in
/// the counter returned with it.
pub fn counting_module(protocol: Protocol, baud: u32) -> (Box<dyn ByteDevice>, Arc<AtomicU64>) {
    let eeprom = Eeprom {
        config: ModuleConfig {
            baud_code: baud_code(baud).expect("a baud rate of the module"),
            ..ModuleConfig::factory()
        },
        ..Eeprom::factory()
    };
    let answered = Arc::new(AtomicU64::new(0));
    let device = Counting {
        inner: SimulatedC29u::new(Model::new(protocol, SystemClock::shared(), eeprom)),
        answered: Arc::clone(&answered),
    };
    (Box::new(device), answered)
}

/// The silence after which a served module hears the line idle: requests end on their CRC,
/// and a pause inside one (a loaded machine stalling the test line for milliseconds) must not
/// cut it short, as silence_gap alone would.
#[allow(dead_code)]
pub fn idle_after(baud: u32) -> Duration {
    silence_gap(baud).max(Duration::from_millis(20))
}

/// A simulated module (ID 1, configured for `baud`) on a pty; stops when dropped.
#[allow(dead_code)] // not every benchmark serves one on a bare pty
pub struct Served {
    /// The pty clients open.
    pub path: String,
    answered: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Served {
    /// Serves a module speaking `protocol` at `baud`.
    #[allow(dead_code)]
    pub fn start(protocol: Protocol, baud: u32) -> Self {
        let mut server = PtyServer::open(None).expect("create a pty");
        let path = server.path().to_string();
        let stop = Arc::new(AtomicBool::new(false));
        let (mut device, answered) = counting_module(protocol, baud);
        let stop2 = Arc::clone(&stop);
        let thread = std::thread::spawn(move || {
            // A module answers at once: keep the simulator's own delays out of the timings.
            rigscript::sim::pty::prefer_realtime();
            server
                .serve(&mut *device, &Drawn::default(), idle_after(baud), &stop2)
                .expect("serve the simulator");
        });
        Self {
            path,
            answered,
            stop,
            thread: Some(thread),
        }
    }

    /// The counter of requests answered.
    #[allow(dead_code)]
    pub fn counter(&self) -> Arc<AtomicU64> {
        Arc::clone(&self.answered)
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
