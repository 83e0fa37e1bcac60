//! A rig assembled in Rust: devices named in code (or read from a rig.toml), real or simulated,
//! in real or virtual time, and a Rhai script started on it. What `rigscript run` and
//! `rigscript test` do from the command line, for programs that use rigscript as a library.
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

use super::rig::{start, Rig, RigError, RigSetup};
use crate::config::{C29uConfig, DeviceConfig, ErrorPolicy, RigConfig, Trc1000Config};
use crate::runtime::log::LogFormat;
use crate::time::clock::{SharedClock, SystemClock, VirtualClock};
use crate::time::zone::Zone;
use chrono::{DateTime, Utc};
use serde_json::Value;
use std::path::PathBuf;
use std::sync::atomic::AtomicUsize;
use std::sync::Arc;
use std::time::Duration;

/// Builds a rig step by step, then starts a script on it (`start`).
///
/// Unless told otherwise: no devices, real hardware, real time in the local zone, the period,
/// error policy and grace time of `RigConfig::default()`, the log on stderr, the default
/// operation budget, no end time.
pub struct RigBuilder {
    config: RigConfig,
    simulate: bool,
    clock: Option<SharedClock>,
    zone: Option<Zone>,
    period: Option<Duration>,
    end_after: Option<Duration>,
    records: Option<PathBuf>,
    log_to_stderr: bool,
    quiet: bool,
    log_format: LogFormat,
    keep_log: bool,
    stop_flag: Arc<AtomicUsize>,
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

    /// The scan period.
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

    /// Appends records and measurements to this JSON-lines file.
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

    /// What `start` will run with.
    pub fn setup(self) -> RigSetup {
        let virtual_time = self.clock.is_some();
        RigSetup {
            config: self.config,
            simulate: self.simulate,
            clock: self.clock.unwrap_or_else(SystemClock::shared),
            zone: self.zone.unwrap_or(if virtual_time {
                Zone::utc()
            } else {
                Zone::Local
            }),
            period: self.period,
            end_after: self.end_after,
            records: self.records,
            log_to_stderr: self.log_to_stderr,
            quiet: self.quiet,
            log_format: self.log_format,
            keep_log: self.keep_log,
            stop_flag: self.stop_flag,
        }
    }

    /// Compiles `source` (called `file` in messages), opens the devices, brings them under
    /// control and runs the script's top level; then tick the rig with `rig.runner`.
    pub fn start(self, source: &str, file: &str) -> Result<Rig, RigError> {
        start(source, file, self.setup())
    }
}

impl Rig {
    /// The log lines kept so far (with `RigBuilder::keep_log`).
    pub fn log(&self) -> Vec<String> {
        self.runner.runtime().borrow().log_lines().to_vec()
    }

    /// The records and measurements kept so far, oldest first, as JSON objects.
    pub fn records(&self) -> Vec<Value> {
        self.runner.runtime().borrow().records_kept().to_vec()
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
        let setup = RigBuilder::new().setup();
        assert!(!setup.simulate);
        assert_eq!(setup.zone, Zone::Local);
        assert!(setup.log_to_stderr);
        assert_eq!(
            setup.config.limits.operations,
            crate::script::engine::DEFAULT_BUDGET
        );
        let setup = RigBuilder::new()
            .zone(Zone::Local)
            .virtual_time_from(at_noon())
            .setup();
        assert_eq!(setup.zone, Zone::Local, "an explicit zone wins over UTC");
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
