//! A runtime over the in-memory simulators in virtual time, for the runtime's own unit tests.

use super::devices::links::TransactionCounter;
use super::devices::SimRig;
use super::log::Logger;
use super::records::Records;
use super::runner::Shared;
use super::state::Runtime;
use crate::config::RigConfig;
use crate::sim::rig::open_devices;
use crate::time::clock::{SharedClock, VirtualClock};
use crate::time::zone::Zone;
use std::cell::RefCell;
use std::rc::Rc;
use std::sync::Arc;
use std::time::Duration;

/// A module with a safe state that is easy to tell from zero, and a panel with a safe relay.
pub const RIG: &str = r#"
grace = "1s"

[devices.io]
kind = "trp-c29u"
port = "/dev/ttyUSB0"
safe_value = 0x05
power_on_value = 0x11
watchdog = "1s"

[devices.panel]
kind = "trc1000"
safe_relay = 3
"#;

/// The module's index in `RIG` (devices are in name order).
pub const IO: usize = 0;

/// The panel's index in `RIG`.
pub const PANEL: usize = 1;

/// A runtime whose handlers are names, its simulators and its clock.
pub struct TestRig {
    /// The runtime under test.
    pub rt: Runtime<&'static str>,
    /// The field side of the simulators.
    pub sim: SimRig,
    /// The virtual clock every part runs on.
    pub clock: VirtualClock,
}

impl TestRig {
    /// The rig `toml` describes, every device simulated, nothing done yet.
    pub fn new(toml: &str) -> Self {
        let config = RigConfig::parse(toml, "rig.toml").expect("test rig.toml");
        let clock = VirtualClock::at_epoch();
        let shared: SharedClock = Arc::new(clock.clone());
        let count = TransactionCounter::default();
        let opened = open_devices(&config, &shared, true, &count).expect("simulators open");
        let mut log = Logger::new(Arc::clone(&shared), Zone::utc(), false);
        log.keep_lines();
        let rt = Runtime::new(
            shared,
            Zone::utc(),
            opened.devices,
            Records::in_memory(),
            log,
            count,
            config.grace,
        );
        Self {
            rt,
            sim: opened.sim,
            clock,
        }
    }

    /// `RIG` with every device under control, as a run starts.
    pub fn started() -> Self {
        let mut r = Self::new(RIG);
        r.rt.start_devices().expect("the simulators answer");
        r
    }

    /// The runtime, shared as a scan loop holds it (`rt` is left without devices; the
    /// simulators and the clock stay here).
    pub fn shared_runtime(&mut self) -> Shared<&'static str> {
        let clock: SharedClock = Arc::new(self.clock.clone());
        let log = Logger::new(Arc::clone(&clock), Zone::utc(), false);
        let empty = Runtime::new(
            clock,
            Zone::utc(),
            Vec::new(),
            Records::in_memory(),
            log,
            TransactionCounter::default(),
            Duration::from_secs(1),
        );
        Rc::new(RefCell::new(std::mem::replace(&mut self.rt, empty)))
    }

    /// Moves virtual time on by `by` and starts the next tick (as the scan loop does).
    pub fn next_tick(&mut self, by: Duration) {
        self.clock.advance(by);
        self.rt.cycle.next_tick();
    }

    /// Requests sent so far on all links.
    pub fn requests(&self) -> u64 {
        self.rt.devices.transaction_count()
    }

    /// The log so far, one line each.
    pub fn log(&self) -> String {
        self.rt.log_lines().join("\n")
    }
}
