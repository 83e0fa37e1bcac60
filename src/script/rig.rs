//! Puts a run together (`RigBuilder::start`): the script compiled (before any device is
//! touched), the records file opened, the devices opened (real or simulated) and brought
//! under control, the services attached to the run's events, the script's top level run.

use super::builder::RigBuilder;
use super::engine::sandboxed;
use super::error::parse_error;
use super::program::ScriptProgram;
use crate::device::cancel::Cancel;
use crate::runtime::devices::links::TransactionCounter;
use crate::runtime::devices::{OpenError, SimRig};
use crate::runtime::log::Logger;
use crate::runtime::records::{RecordError, Records};
use crate::runtime::runner::{panic_message, safe_after_panic, RunOptions, Runner};
use crate::runtime::safety::Unavailable;
use crate::runtime::script_context::ScriptContext;
use crate::runtime::state::Runtime;
use crate::runtime::{exit, signals};
use std::cell::RefCell;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::rc::Rc;
use std::sync::atomic::Ordering;
use std::sync::Arc;

/// Why a run could not start, with the exit status it calls for.
#[derive(Debug, thiserror::Error)]
pub enum RigError {
    /// The config names no devices (exit 2).
    #[error(
        "the config defines no devices (no [devices.NAME] tables), so there is nothing to {}",
        if *simulated {
            "simulate; --sim without --config gives the default rig: panel (a TRC1000) and io \
             (a TRP-C29U)"
        } else {
            "drive; add a [devices.NAME] table for each device (docs/guide/05-rig-toml.md), or try the script \
             with --sim and no --config: the default rig, panel (a TRC1000) and io (a TRP-C29U)"
        }
    )]
    NoDevices {
        /// Whether the run was to simulate them.
        simulated: bool,
    },
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
    /// An ending signal came while the devices were being taken control of (exit 128 +
    /// the signal); the devices already under control were left safe.
    #[error("stopped during the start by {}", signals::name(*.0))]
    Signal(i32),
    /// A bug: a panic while taking control of the devices (exit 70).
    #[error("internal error (a bug in rigscript; please report it): {0}")]
    Internal(String),
}

impl RigError {
    /// The exit status for this error.
    pub fn status(&self) -> i32 {
        match self {
            RigError::Script(_) => exit::ERROR,
            RigError::NoDevices { .. } | RigError::Records(_) => exit::USAGE,
            RigError::Open(_) | RigError::Unavailable(_) => exit::UNAVAILABLE,
            RigError::Internal(_) => exit::INTERNAL,
            RigError::Signal(n) => exit::signal(*n),
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

impl Drop for Rig {
    /// Lets go of the script's handlers and invariants first: their closures can hold device
    /// handles, which hold the runtime that holds the closures, a cycle of `Rc`s that would
    /// keep the run's runtime and every value its script kept alive after the run (each
    /// `verify` run's, for as long as the process lives).
    fn drop(&mut self) {
        if let Ok(mut rt) = self.runner.runtime().try_borrow_mut() {
            rt.forget_handlers();
        }
    }
}

impl Rig {
    /// The log lines kept so far (with `RigBuilder::keep_log`).
    pub fn log(&self) -> Vec<String> {
        self.runner.runtime().borrow().log_lines().to_vec()
    }

    /// The records and measurements kept so far, oldest first, as JSON objects.
    pub fn records(&self) -> Vec<serde_json::Value> {
        self.runner.runtime().borrow().records_kept().to_vec()
    }
}

impl RigBuilder {
    /// Compiles `source` (called `file` in messages), opens the devices, brings them under
    /// control, attaches the services and runs the script's top level; then tick the rig
    /// with `rig.runner` (a failing top level leaves the runner stopped with status 1).
    pub fn start(self, source: &str, file: &str) -> Result<Rig, RigError> {
        let setup = self;
        if setup.config.devices.is_empty() {
            return Err(RigError::NoDevices {
                simulated: setup.simulate,
            });
        }
        let limits = setup.config.limits;
        let ast = sandboxed(limits.operations)
            .compile(source)
            .map_err(|e| RigError::Script(parse_error(file, source, &e)))?;
        // The log first: its event stream is the run's, and the records file is a consumer of it.
        let (clock, zone) = (setup.run_clock(), setup.run_zone());
        let mut log = Logger::new(Arc::clone(&clock), zone, setup.log_to_stderr);
        log.set_quiet(setup.quiet);
        log.set_format(setup.log_format);
        log.set_devices(setup.config.devices.keys().cloned());
        if setup.keep_log {
            log.keep_lines();
        }
        let records = match setup.records_file() {
            Some(path) => Records::to_file(path, log.events())?,
            None => Records::in_memory(),
        };
        for watch in setup.watching {
            watch(log.events());
        }
        let count = TransactionCounter::default();
        let opened = (setup.open)(&setup.config, &clock, setup.simulate, &count)?;
        let mut runtime = Runtime::new(
            clock,
            zone,
            opened.devices,
            records,
            log,
            count,
            setup.config.grace,
        );
        runtime.limit_timers(limits.timers);
        runtime.allow_forcing(setup.config.force);
        // A signal during the start cuts its exchanges short from the first one: a silent module
        // with long timeouts and many retries must not hold a stop for all of them.
        runtime.set_cancel(&Cancel::when_set(Arc::clone(&setup.stop_flag)));
        let rt = Rc::new(RefCell::new(runtime));
        let started = catch_unwind(AssertUnwindSafe(|| rt.borrow_mut().start_devices()));
        let started = match started {
            Ok(started) => started,
            Err(panic) => {
                let message = panic_message(panic.as_ref());
                safe_after_panic(&rt, &message);
                return Err(RigError::Internal(message));
            }
        };
        if let Err(e) = started {
            // Leave the devices that did start as a clean end would.
            let mut r = rt.borrow_mut();
            let signal = setup.stop_flag.load(Ordering::SeqCst);
            if signal != 0 {
                let signal = i32::try_from(signal).unwrap_or(libc::SIGTERM);
                r.log_mut().notice(&format!(
                    "stopping during the start: {} received ({})",
                    signals::name(signal),
                    signals::likely_cause(signal)
                ));
                // A module not yet under control got from the start at most its safe values (the
                // outputs it is taken control with); the end's tries on one that has not answered
                // would cost all its timeouts, so it is left as it is.
                for d in &r.take_out_uncontrolled() {
                    r.log_mut().warn(&format!(
                        "{}: not under control yet: left as it is (the start writes a module nothing \
                         but its safe values)",
                        d.name()
                    ));
                }
                r.end_safe("signal", true);
                return Err(RigError::Signal(signal));
            }
            r.end_safe("a device is not available", true);
            return Err(e.into());
        }
        let events = rt.borrow_mut().log_mut().events().clone();
        for attach in setup.attached {
            attach(&events);
        }
        let mut program = ScriptProgram::new(&ScriptContext::new(&rt), ast, file, limits);
        if let Some(prepare) = setup.prepare {
            prepare(&mut program);
        }
        let period = setup.period.unwrap_or(setup.config.period);
        let options = RunOptions {
            period,
            policy: setup.config.on_error,
            end_after: setup.end_after,
            stop_flag: setup.stop_flag,
            wake_latency: setup.config.wake_latency,
        };
        let mut runner = Runner::new(rt, program, options);
        runner.name_script(source, file);
        runner.start();
        Ok(Rig {
            runner,
            sim: opened.sim,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::RigConfig;
    use crate::time::clock::{Clock, VirtualClock};
    use chrono::{TimeZone, Utc};
    use std::time::Duration;

    fn start(source: &str, file: &str, setup: RigBuilder) -> Result<Rig, RigError> {
        setup.start(source, file)
    }

    fn setup(clock: &VirtualClock) -> RigBuilder {
        RigBuilder::from_config(RigConfig::simulated_default())
            .simulated()
            .clock(Arc::new(clock.clone()))
            .log_to_stderr(false)
            .keep_log()
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
        let log = rig.runner.runtime().borrow().log_lines().join("\n");
        assert!(log.contains("panel: S1 pressed"), "{log}");
        assert!(
            log.contains("io: outputs 0x00 -> 0x05 (panel.on_press S1)"),
            "{log}"
        );
        assert!(clock.now() >= Duration::from_millis(140));
    }

    #[test]
    fn what_a_script_logs_cannot_forge_a_line_or_reach_the_terminal_raw() {
        let clock = VirtualClock::at_epoch();
        let script = "print(\"a\\n00:00:00.000 safe state (end of run): io outputs 0x00\");\n\
                      debug(\"b\\rc\");\nlog(\"d\\x1b[2Je\");\nwarn(\"f\\ng\");\n";
        let rig = start(script, "t.rhai", setup(&clock)).unwrap();
        let lines = rig.runner.runtime().borrow().log_lines().to_vec();
        let log = lines.join("\n");
        assert!(
            log.contains("script: a\\n00:00:00.000 safe state (end of run)"),
            "{log}"
        );
        assert!(log.contains("script: \"b\\rc\""), "{log}");
        assert!(log.contains("script: d\\x1b[2Je"), "{log}");
        assert!(log.contains("warning: script: f\\ng"), "{log}");
        assert!(
            lines.iter().all(|l| !l.chars().any(char::is_control)),
            "{lines:?}"
        );
        assert!(!lines
            .iter()
            .any(|l| l.starts_with("00:00:00.000 safe state")));
    }

    #[test]
    fn numbers_out_of_range_from_a_script_are_script_errors_at_their_line() {
        let clock = VirtualClock::at_epoch();
        for (script, message) in [
            (
                "io.watchdog(1e17);",
                "watchdog(100000000000000000) is not possible",
            ),
            ("io.watchdog(-0.04);", "watchdog(-0.04) is not possible"),
            ("io.watchdog(0.04);", "watchdog(0.04) is not possible"),
            ("io.watchdog(25.56);", "watchdog(25.56) is not possible"),
            ("io.watchdog(1.0 / 0.0);", "watchdog(inf) is not possible"),
            ("io.watchdog(9223372036854775807);", "is not possible"),
        ] {
            let rig = start(&format!("\n{script}"), "t.rhai", setup(&clock)).unwrap();
            assert_eq!(rig.runner.status(), Some(1), "{script}");
            let log = rig.runner.runtime().borrow().log_lines().join("\n");
            assert!(
                log.contains("t.rhai:2:4: in top level: "),
                "{script}: {log}"
            );
            assert!(log.contains(message), "{script}: {log}");
        }
        let rig = start("io.watchdog(25.54);", "t.rhai", setup(&clock)).unwrap();
        assert_eq!(rig.runner.status(), None, "started");
        assert_eq!(rig.sim.watchdog("io").unwrap().timeout_tenths, 255);
    }

    #[test]
    fn a_safe_value_assigned_every_tick_is_written_once() {
        let clock = VirtualClock::at_epoch();
        let script = "every(\"20ms\", || { io.safe_value = 0x05; io.watchdog(2); });";
        let mut rig = start(script, "t.rhai", setup(&clock)).unwrap();
        rig.runner.advance(Duration::from_millis(100));
        assert_eq!(rig.sim.safe_value("io").unwrap(), 0x05);
        let before = rig.runner.runtime().borrow().devices().transaction_count();
        rig.runner.advance(Duration::from_secs(10));
        let spent = rig.runner.runtime().borrow().devices().transaction_count() - before;
        // 500 assignments of each: only the watchdog feeds (every 500 ms: 20) and the device
        // checks (every 5 s: the module's reset flag, outputs, watchdog and one stored item,
        // the panel's relay selected and confirmed, 6 a check) and the panel nobody reads, asked
        // every 250 ms (a quarter of the grace time: 40) reach the devices.
        assert!(spent <= 72, "{spent} requests in 10 s");
    }

    #[test]
    fn a_watchdog_too_short_to_be_fed_on_this_rig_is_a_script_error() {
        let clock = VirtualClock::at_epoch();
        let rig = start("\nio.watchdog(0.5);", "t.rhai", setup(&clock)).unwrap();
        assert_eq!(rig.runner.status(), Some(1));
        let log = rig.runner.runtime().borrow().log_lines().join("\n");
        assert!(
            log.contains("t.rhai:2:4: in top level: io: a 500ms watchdog on io is too short for this rig: a feed may reach the module 7"),
            "{log}"
        );
        assert!(!rig.sim.watchdog("io").unwrap().enabled, "not set");
    }

    #[test]
    fn a_config_without_devices_says_so_and_points_to_the_default_rig() {
        let clock = VirtualClock::new(Utc.with_ymd_and_hms(2026, 3, 28, 12, 0, 0).unwrap());
        let mut s = setup(&clock);
        s.config = RigConfig::parse("period = \"20ms\"\n", "rig.toml").unwrap();
        let Err(e) = start("io.outputs = 1;", "t.rhai", s) else {
            panic!("a rig without devices started");
        };
        assert_eq!(e.status(), 2);
        assert_eq!(
            e.to_string(),
            "the config defines no devices (no [devices.NAME] tables), so there is nothing to \
             simulate; --sim without --config gives the default rig: panel (a TRC1000) and io \
             (a TRP-C29U)"
        );
        let mut s = setup(&clock);
        s.config = RigConfig::parse("", "rig.toml").unwrap();
        s.simulate = false;
        let text = start("", "t.rhai", s).err().unwrap().to_string();
        assert!(
            text.contains("nothing to drive; add a [devices.NAME] table"),
            "{text}"
        );
    }
}
