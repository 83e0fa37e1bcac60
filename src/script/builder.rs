//! The one way to say what a run needs besides its script: devices named in code (or read from
//! a rig.toml), real or simulated, in real or virtual time, the log, the records file, and the
//! services attached to its events before its top level runs; `RigBuilder::start`
//! (`script::rig`) then starts a Rhai script on it. What `rigscript run`, `test`, `check` and
//! `verify` build, and what programs that use rigscript as a library build.
//!
//! ```
//! use rigscript::config::{C29uConfig, Port};
//! use rigscript::RigBuilder;
//! use std::time::Duration;
//!
//! let mut rig = RigBuilder::new()
//!     .c29u("io", C29uConfig::with_defaults(Port::Simulated))
//!     .simulated()
//!     .virtual_time_from("2026-03-28T12:00:00Z".parse().unwrap())
//!     .log_to_stderr(false)
//!     .start("every(\"1s\", || io.outputs += 1);", "count.rhai")
//!     .unwrap();
//! rig.runner.advance(Duration::from_millis(3500));
//! assert_eq!(rig.sim.outputs("io").unwrap(), 3);
//! ```

use super::program::ScriptProgram;
use crate::config::mqtt::MqttConfig;
use crate::config::{C29uConfig, DeviceConfig, ErrorPolicy, RigConfig, Trc1000Config};
use crate::runtime::devices::links::TransactionCounter;
use crate::runtime::devices::{OpenError, Opened};
use crate::runtime::log::LogFormat;
use crate::runtime::observe::Events;
use crate::sim::rig::open_devices;
use crate::time::clock::{SharedClock, SystemClock, VirtualClock};
use crate::time::zone::Zone;
use chrono::{DateTime, Utc};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicUsize;
use std::sync::Arc;
use std::time::Duration;

/// What opens the devices: given the config, the clock, whether to simulate them all and the
/// request counter (`open_devices` unless `RigBuilder::open_with` says otherwise).
pub type Opener = Box<
    dyn FnOnce(&RigConfig, &SharedClock, bool, &TransactionCounter) -> Result<Opened, OpenError>
        + Send,
>;

/// What is given the program before its top level runs (`RigBuilder::prepare`).
type Prepare = Box<dyn FnOnce(&mut ScriptProgram) + Send>;

/// A service attached to the run's events (`RigBuilder::attach`).
type Attach = Box<dyn FnOnce(&Events) + Send>;

/// Builds a rig step by step, then starts a script on it (`start`).
///
/// Unless told otherwise: no devices, real hardware, real time in the local zone, the period,
/// error policy and grace time of `RigConfig::default()`, the log on stderr, the default
/// operation budget, no end time, nothing attached to the run's events.
pub struct RigBuilder {
    pub(super) config: RigConfig,
    pub(super) simulate: bool,
    clock: Option<SharedClock>,
    zone: Option<Zone>,
    pub(super) period: Option<Duration>,
    pub(super) end_after: Option<Duration>,
    records: Option<PathBuf>,
    pub(super) log_to_stderr: bool,
    pub(super) quiet: bool,
    pub(super) log_format: LogFormat,
    pub(super) keep_log: bool,
    pub(super) stop_flag: Arc<AtomicUsize>,
    pub(super) open: Opener,
    pub(super) prepare: Option<Prepare>,
    pub(super) attached: Vec<Attach>,
    /// Consumers given the run's events as soon as they exist (`watch_from_start`).
    pub(super) watching: Vec<Attach>,
}

impl Default for RigBuilder {
    fn default() -> Self {
        Self::new()
    }
}

impl RigBuilder {
    /// A rig with no devices yet, every setting at its default.
    pub fn new() -> Self {
        Self::from_config(RigConfig::default())
    }

    /// A rig with the devices and settings of a rig.toml (`RigConfig::load`).
    pub fn from_config(config: RigConfig) -> Self {
        Self {
            config,
            simulate: false,
            clock: None,
            zone: None,
            period: None,
            end_after: None,
            records: None,
            log_to_stderr: true,
            quiet: false,
            log_format: LogFormat::Text,
            keep_log: false,
            stop_flag: Arc::default(),
            open: Box::new(open_devices),
            prepare: None,
            attached: Vec::new(),
            watching: Vec::new(),
        }
    }

    /// Adds a device called `name` (a script sees it as a variable of that name), replacing
    /// one of the same name.
    pub fn device(mut self, name: &str, device: DeviceConfig) -> Self {
        self.config.devices.insert(name.to_string(), device);
        self
    }

    /// Adds a TRP-C29U called `name` (`Port::Simulated` for one that is always simulated).
    pub fn c29u(self, name: &str, config: C29uConfig) -> Self {
        self.device(name, DeviceConfig::C29u(config))
    }

    /// Adds a TRC1000 called `name`.
    pub fn trc1000(self, name: &str, config: Trc1000Config) -> Self {
        self.device(name, DeviceConfig::Trc1000(config))
    }

    /// Replaces every device by its simulator, as `--sim` does; their field side is `Rig::sim`.
    pub fn simulated(mut self) -> Self {
        self.simulate = true;
        self
    }

    /// Runs on `clock` (a `VirtualClock` to control time from a test).
    pub fn clock(mut self, clock: SharedClock) -> Self {
        self.clock = Some(clock);
        self
    }

    /// Runs in virtual time starting at wall time `start`, in UTC unless `zone` says
    /// otherwise: nothing sleeps, `Runner::advance` moves time (as in scenario tests).
    pub fn virtual_time_from(mut self, start: DateTime<Utc>) -> Self {
        self.clock = Some(Arc::new(VirtualClock::new(start)));
        self.zone = self.zone.or(Some(Zone::utc()));
        self
    }

    /// The zone of cron, `now()` and log lines.
    pub fn zone(mut self, zone: Zone) -> Self {
        self.zone = Some(zone);
        self
    }

    /// The scan period, overriding the config's.
    pub fn period(mut self, period: Duration) -> Self {
        self.period = Some(period);
        self
    }

    /// What a handler error does.
    pub fn on_error(mut self, policy: ErrorPolicy) -> Self {
        self.config.on_error = policy;
        self
    }

    /// Ends the run normally after `duration` (`--for`).
    pub fn run_for(mut self, duration: Duration) -> Self {
        self.end_after = Some(duration);
        self
    }

    /// Appends records and measurements to this JSON-lines file (overriding rig.toml's; in
    /// virtual time the only one: `records_file`).
    pub fn records(mut self, path: impl Into<PathBuf>) -> Self {
        self.records = Some(path.into());
        self
    }

    /// Writes the log to stderr (on by default).
    pub fn log_to_stderr(mut self, on: bool) -> Self {
        self.log_to_stderr = on;
        self
    }

    /// Leaves activity lines out of the log (`--quiet`).
    pub fn quiet(mut self) -> Self {
        self.quiet = true;
        self
    }

    /// Writes log lines as text (the default) or as one JSON object a line.
    pub fn log_format(mut self, format: LogFormat) -> Self {
        self.log_format = format;
        self
    }

    /// Keeps the log in memory too, for `Rig::log`.
    pub fn keep_log(mut self) -> Self {
        self.keep_log = true;
        self
    }

    /// Operations each handler call may take (`--budget`).
    pub fn budget(mut self, operations: u64) -> Self {
        self.config.limits.operations = operations;
        self
    }

    /// A flag that stops the run when set (from a signal handler or another thread) to the
    /// number of the signal that asks it to (`signal_hook::flag::register_usize`; 15 for
    /// SIGTERM): the exit status is 128 + that number (`runtime::exit`).
    pub fn stop_flag(mut self, flag: Arc<AtomicUsize>) -> Self {
        self.stop_flag = flag;
        self
    }

    /// Opens the devices with `open` instead of `open_devices` (given the same config, clock,
    /// `simulate` flag and request counter: the fault search puts simulators behind
    /// fault-injecting links under the real drivers this way).
    pub fn open_with(
        mut self,
        open: impl FnOnce(&RigConfig, &SharedClock, bool, &TransactionCounter) -> Result<Opened, OpenError>
            + Send
            + 'static,
    ) -> Self {
        self.open = Box::new(open);
        self
    }

    /// Gives `prepare` the program before its top level runs (`verify` has it keep count of
    /// what the script does from the first line on).
    pub fn prepare(mut self, prepare: impl FnOnce(&mut ScriptProgram) + Send + 'static) -> Self {
        self.prepare = Some(Box::new(prepare));
        self
    }

    /// Attaches a service to the run: `attach` is given the run's event stream once every
    /// device is under control and before the script's top level runs, so a consumer that
    /// must see every record (the MQTT client) or the first start (systemd's READY) does.
    pub fn attach(mut self, attach: impl FnOnce(&Events) + Send + 'static) -> Self {
        self.attached.push(Box::new(attach));
        self
    }

    /// Gives `watch` the run's event stream as soon as it exists, before any device is
    /// opened: for a consumer that shows the log from the run's first line (the web page's
    /// history keeps the take-over lines and each module's identity). What asks the loop
    /// anything attaches with `attach`.
    pub fn watch_from_start(mut self, watch: impl FnOnce(&Events) + Send + 'static) -> Self {
        self.watching.push(Box::new(watch));
        self
    }

    /// The rig's config, with what was set in code.
    pub fn config(&self) -> &RigConfig {
        &self.config
    }

    /// The scan period the run will have.
    pub fn scan_period(&self) -> Duration {
        self.period.unwrap_or(self.config.period)
    }

    /// The clock the run will have.
    pub(super) fn run_clock(&self) -> SharedClock {
        self.clock.clone().unwrap_or_else(SystemClock::shared)
    }

    /// The zone the run will have: UTC in virtual time unless set, else the local one.
    pub(super) fn run_zone(&self) -> Zone {
        self.zone.unwrap_or(if self.clock.is_some() {
            Zone::utc()
        } else {
            Zone::Local
        })
    }

    fn is_virtual(&self) -> bool {
        self.clock.as_ref().is_some_and(|c| c.is_virtual())
    }

    /// The records file the run appends to: the one asked for, else rig.toml's `records`,
    /// but never rig.toml's in virtual time (`rigscript test`, `verify`: their records,
    /// dated whenever the test says, would mix with the rig's real ones).
    pub fn records_file(&self) -> Option<&Path> {
        let production = self
            .config
            .records
            .as_deref()
            .filter(|_| !self.is_virtual());
        self.records.as_deref().or(production)
    }

    /// The broker the run reports to (rig.toml's `[mqtt]`), never in virtual time (the
    /// broker and the outbox hold the rig's real records).
    pub fn mqtt(&self) -> Option<&MqttConfig> {
        self.config.mqtt.as_ref().filter(|_| !self.is_virtual())
    }
}

#[cfg(test)]
impl RigBuilder {
    /// The default simulated rig in virtual time from 2026-03-28 12:00 UTC, its log kept and
    /// not printed: what the crate's tests of a whole run start from.
    pub(crate) fn for_tests() -> Self {
        use chrono::TimeZone;
        RigBuilder::from_config(RigConfig::simulated_default())
            .simulated()
            .virtual_time_from(chrono::Utc.with_ymd_and_hms(2026, 3, 28, 12, 0, 0).unwrap())
            .log_to_stderr(false)
            .keep_log()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Port, Protocol, Trc1000Address};

    fn at_noon() -> DateTime<Utc> {
        "2026-03-28T12:00:00Z".parse().unwrap()
    }

    #[test]
    fn a_rig_in_code_runs_a_script_on_simulators_in_virtual_time() {
        let ascii = C29uConfig {
            protocol: Protocol::Ascii,
            id: 3,
            checksum: true,
            ..C29uConfig::with_defaults(Port::Simulated)
        };
        let mut rig = RigBuilder::new()
            .c29u("io", ascii)
            .trc1000(
                "panel",
                Trc1000Config {
                    address: Trc1000Address::Unit(0),
                    safe_relay: Some(2),
                    names: Default::default(),
                },
            )
            .simulated()
            .virtual_time_from(at_noon())
            .log_to_stderr(false)
            .keep_log()
            .run_for(Duration::from_secs(2))
            .start(
                r#"panel.on_press("S1", || { io.outputs = 0x21; measure("now", 1, #{min: 0}); });"#,
                "press.rhai",
            )
            .unwrap();
        rig.runner.advance(Duration::from_millis(100));
        rig.sim.set_switch("panel", "S1", true).unwrap();
        rig.runner.advance(Duration::from_millis(100));
        assert_eq!(rig.sim.outputs("io").unwrap(), 0x21);
        rig.runner.advance(Duration::from_secs(3));
        assert_eq!(rig.runner.status(), Some(0), "ended by run_for");
        assert_eq!(
            rig.sim.outputs("io").unwrap(),
            0x00,
            "safe state at the end"
        );
        assert_eq!(rig.sim.relay("panel").unwrap(), 2);
        assert_eq!(rig.records().len(), 1);
        assert_eq!(rig.records()[0]["pass"], true);
        let log = rig.log().join("\n");
        assert!(
            log.contains("12:00:00.1"),
            "wall time starts at noon UTC: {log}"
        );
        assert!(log.contains("stopped; exit status 0"), "{log}");
    }

    #[test]
    fn defaults_are_real_time_real_devices_and_the_local_zone() {
        let setup = RigBuilder::new();
        assert!(!setup.simulate);
        assert_eq!(setup.run_zone(), Zone::Local);
        assert!(!setup.run_clock().is_virtual());
        assert!(setup.log_to_stderr);
        assert_eq!(
            setup.config.limits.operations,
            crate::script::engine::DEFAULT_BUDGET
        );
        let setup = RigBuilder::new().virtual_time_from(at_noon());
        assert_eq!(setup.run_zone(), Zone::utc(), "virtual time is in UTC");
        let setup = RigBuilder::new()
            .zone(Zone::Local)
            .virtual_time_from(at_noon());
        assert_eq!(
            setup.run_zone(),
            Zone::Local,
            "an explicit zone wins over UTC"
        );
    }

    #[test]
    fn a_script_that_does_not_compile_is_refused_before_any_device_is_touched() {
        let err = RigBuilder::new()
            .c29u(
                "io",
                C29uConfig::with_defaults(Port::Serial("/nonexistent/tty".into())),
            )
            .log_to_stderr(false)
            .start("let x = ;", "bad.rhai")
            .err()
            .unwrap();
        assert_eq!(err.status(), 1, "{err}");
        assert!(err.to_string().contains("bad.rhai:1:"), "{err}");
    }
}
