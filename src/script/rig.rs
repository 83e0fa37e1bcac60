//! Puts a run together: the script compiled (before any device is touched), the records
//! file opened, the devices opened (real or simulated) and brought under control, the
//! script's top level run. Used by `rigscript run` and by scenario tests.

use super::engine::sandboxed;
use super::error::parse_error;
use super::program::ScriptProgram;
use crate::config::RigConfig;
use crate::runtime::core::Runtime;
use crate::runtime::devices::links::TransactionCounter;
use crate::runtime::devices::{open_devices, Device, OpenError, Opened, SimRig};
use crate::runtime::log::Logger;
use crate::runtime::records::{RecordError, Records};
use crate::runtime::safety::Unavailable;
use crate::runtime::scan::{RunOptions, Runner};
use crate::time::clock::SharedClock;
use crate::time::duration::format_duration;
use crate::time::zone::Zone;
use std::cell::RefCell;
use std::path::PathBuf;
use std::rc::Rc;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

/// Everything a run needs besides the script.
pub struct RigSetup {
    /// The rig (devices, period, policy, grace, records file).
    pub config: RigConfig,
    /// Replace every device by its simulator.
    pub simulate: bool,
    /// The clock (system time, or virtual time in scenario tests).
    pub clock: SharedClock,
    /// The zone of cron, `now()` and log lines.
    pub zone: Zone,
    /// Scan period, overriding the config's.
    pub period: Option<Duration>,
    /// End normally after this long.
    pub end_after: Option<Duration>,
    /// Records file, overriding the config's.
    pub records: Option<PathBuf>,
    /// Write the log to stderr.
    pub log_to_stderr: bool,
    /// Leave activity lines out of the log.
    pub quiet: bool,
    /// Keep the log in memory (scenario tests).
    pub keep_log: bool,
    /// Operations per handler call.
    pub budget: u64,
    /// Set on SIGINT/SIGTERM.
    pub stop_flag: Arc<AtomicBool>,
}

/// Why a run could not start, with the exit status it calls for.
#[derive(Debug, thiserror::Error)]
pub enum RigError {
    /// The script does not compile (exit 1).
    #[error("{0}")]
    Script(String),
    /// The records file cannot be opened (exit 2).
    #[error(transparent)]
    Records(#[from] RecordError),
    /// A device cannot be opened (exit 3).
    #[error(transparent)]
    Open(#[from] OpenError),
    /// A device does not answer (exit 3).
    #[error(transparent)]
    Unavailable(#[from] Unavailable),
}

impl RigError {
    /// The exit status for this error.
    pub fn status(&self) -> i32 {
        match self {
            RigError::Script(_) => 1,
            RigError::Records(_) => 2,
            RigError::Open(_) | RigError::Unavailable(_) => 3,
        }
    }
}

/// A run, ready to tick: the runner and the field side of its simulators.
pub struct Rig {
    /// The scan loop.
    pub runner: Runner<ScriptProgram>,
    /// The simulators (empty for real hardware).
    pub sim: SimRig,
}

/// Compiles `source` (called `file` in messages) and starts it on the rig `setup` describes;
/// its top level has run (a failing top level leaves the runner stopped with status 1).
pub fn start(source: &str, file: &str, setup: RigSetup) -> Result<Rig, RigError> {
    start_with(source, file, setup, open_devices)
}

/// As `start`, with the devices opened by `open` instead of `open_devices` (given the same
/// config, clock, `simulate` flag and request counter): the fault search puts simulators
/// behind fault-injecting links under the real drivers this way.
pub fn start_with(
    source: &str,
    file: &str,
    setup: RigSetup,
    open: impl FnOnce(&RigConfig, &SharedClock, bool, &TransactionCounter) -> Result<Opened, OpenError>,
) -> Result<Rig, RigError> {
    let ast = sandboxed(setup.budget)
        .compile(source)
        .map_err(|e| RigError::Script(parse_error(file, &e)))?;
    let records = match setup.records.as_ref().or(setup.config.records.as_ref()) {
        Some(path) => Records::to_file(path)?,
        None => Records::in_memory(),
    };
    let count = TransactionCounter::default();
    let opened = open(&setup.config, &setup.clock, setup.simulate, &count)?;
    let mut log = Logger::new(Arc::clone(&setup.clock), setup.zone, setup.log_to_stderr);
    log.set_quiet(setup.quiet);
    if setup.keep_log {
        log.keep_lines();
    }
    let runtime = Runtime::new(
        Arc::clone(&setup.clock),
        setup.zone,
        opened.devices,
        records,
        log,
        count,
        setup.config.grace,
    );
    let rt = Rc::new(RefCell::new(runtime));
    let started = rt.borrow_mut().start_devices();
    if let Err(e) = started {
        // Leave the devices that did start as a clean end would.
        let mut r = rt.borrow_mut();
        r.write_safe_state("a device is not available");
        r.release_watchdogs();
        return Err(e.into());
    }
    let program = ScriptProgram::new(&rt, ast, file, setup.budget);
    let period = setup.period.unwrap_or(setup.config.period);
    warn_short_watchdogs(&mut rt.borrow_mut(), period);
    let options = RunOptions {
        period,
        policy: setup.config.on_error,
        end_after: setup.end_after,
        stop_flag: setup.stop_flag,
        wake_latency: setup.config.wake_latency.limit_for(period),
    };
    let mut runner = Runner::new(rt, program, options);
    runner.start();
    Ok(Rig {
        runner,
        sim: opened.sim,
    })
}

/// Warns of host watchdogs shorter than two scan periods: the runner feeds them once a tick
/// at best, so the module could go safe between ticks.
fn warn_short_watchdogs(rt: &mut Runtime<rhai::FnPtr>, period: Duration) {
    let short: Vec<String> = rt
        .devices
        .iter()
        .filter_map(|d| match d {
            Device::C29u(c) => c
                .watchdog
                .filter(|t| t.as_duration() < period.saturating_mul(2))
                .map(|t| {
                    format!(
                        "{}: its host watchdog ({}) is shorter than two scan periods ({} each): \
                         it may fire between ticks; use a longer watchdog or a shorter period",
                        c.name,
                        format_duration(t.as_duration()),
                        format_duration(period)
                    )
                }),
            Device::Trc(_) => None,
        })
        .collect();
    for w in short {
        rt.log.warn(&w);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::time::clock::{Clock, VirtualClock};
    use chrono::{TimeZone, Utc};

    fn setup(clock: &VirtualClock) -> RigSetup {
        RigSetup {
            config: RigConfig::simulated_default(),
            simulate: true,
            clock: Arc::new(clock.clone()),
            zone: Zone::utc(),
            period: None,
            end_after: None,
            records: None,
            log_to_stderr: false,
            quiet: false,
            keep_log: true,
            budget: 100_000,
            stop_flag: Arc::default(),
        }
    }

    #[test]
    fn a_press_sets_outputs_at_the_end_of_the_tick() {
        let clock = VirtualClock::new(Utc.with_ymd_and_hms(2026, 3, 28, 12, 0, 0).unwrap());
        let script = r#"
            let io = device("io");
            let panel = device("panel");
            panel.on_press("S1", || { io.outputs = 0x05; });
        "#;
        let mut rig = start(script, "t.rhai", setup(&clock)).unwrap();
        rig.runner.advance(Duration::from_millis(100));
        assert_eq!(rig.sim.outputs("io").unwrap(), 0);
        rig.sim.set_switch("panel", "S1", true).unwrap();
        rig.runner.advance(Duration::from_millis(40));
        assert_eq!(rig.sim.outputs("io").unwrap(), 5);
        let log = rig.runner.runtime().borrow().log.lines().join("\n");
        assert!(log.contains("panel: S1 pressed"), "{log}");
        assert!(
            log.contains("io: outputs 0x00 -> 0x05 (panel.on_press S1)"),
            "{log}"
        );
        assert!(clock.now() >= Duration::from_millis(140));
    }
}
