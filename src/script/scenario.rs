//! Scenario tests (`rigscript test`): `*.test.rhai` files whose `test_*` functions load a
//! script under test on simulated devices in virtual time, play the field side, advance
//! time, and assert on what the simulators show.
//!
//! The test API:
//! - `rig(path)`, `rig(path, config)`, `rig_at(path, iso_time)`, `rig_at(path, iso_time,
//!   zone)`, `rig_at(path, iso_time, zone, config)`: the script at `path` (relative to the
//!   test file) on simulated devices (those of `config`, else `panel` and `io` as with
//!   `--sim`), wall time starting at 2026-03-28T12:00:00Z (or `iso_time`), cron and log in UTC
//!   (or the offset of `iso_time`, or the IANA `zone`). Its top level has run when `rig`
//!   returns.
//! - `r.advance(dur)` runs every tick due until virtual time has moved by `dur`; `r.tick()`
//!   runs the next tick (when no handler polls inputs, idle ticks are skipped, so this can move
//!   time to the next timer). Each tick at the period of rig.toml (20 ms by default). An
//!   invariant of the script found false fails the `advance` or `tick` it happened in, with
//!   the invariant's name and the tick's inputs and outputs (once: a test that catches it can
//!   go on to look at the rig).
//! - Field side: `r.press(dev, name)`, `r.release(dev, name)`, `r.turn(dev, name,
//!   half_turns)`, `r.set_inputs(dev, byte)`, `r.set_input(dev, ch, on)`, `r.pulse(dev, ch,
//!   n)`, `r.fail(dev)` (a silent line), `r.restore(dev)`, `r.power_cycle(dev)` (either
//!   device), `r.drop_answers(dev, n)`, `r.garble_answers(dev, n)`, `r.late_answers(dev, n,
//!   dur)` and `r.duplicate_answers(dev, n)` (the device's next `n` answers lost, garbled,
//!   arriving `dur` late, or twice),
//!   `r.ignore_writes(dev)` (a module acknowledges output writes without applying them),
//!   `r.refuse_writes(dev, code)` (it refuses them with that Modbus exception code: 4, 0xFF),
//!   `r.accept_writes(dev)` (its output stage sound again), `r.swap_module(dev, #{name,
//!   firmware, safe_value, power_on_value, watchdog})` (another module answers in its place
//!   behind the same link: same ID, its own name, firmware date `"YYMMDD"`, stored values and
//!   watchdog, a duration or `()` for off; keys left out take a factory module's),
//!   `r.signal_stop()`, `r.end()` (the run ends normally, as at `--for`).
//! - Time itself: `r.stall(dur)` (virtual time moves on without a tick: the host stalled),
//!   `r.step_wall(step)` (the wall clock steps by `"+1h"`, `"-90s"`...: NTP, a clock change).
//! - Read from the simulators: `r.outputs(dev)`, `r.relay(dev)`, `r.safe_mode(dev)`,
//!   `r.safe_value(dev)`, `r.power_on_value(dev)`, `r.watchdog(dev)` (`#{enabled,
//!   timeout_ms, expired}`), `r.counter(dev, ch)`.
//! - Read from the run: `r.records()`, `r.stopped()`, `r.exit_status()` (`()` while
//!   running), `r.log()`, `r.now()`, `r.overruns()`, `r.online(dev)`, `r.held_safe()`
//!   (outputs held safe for a device lost past its grace time), `r.errors()` (the script
//!   errors so far, as logged), `r.violation()` (the invariant found false, or `()`),
//!   `r.end_confirmed(dev)` (whether the end confirmed the device's safe state; `()` before
//!   the end).
//! - `r.expect_errors()`: the test expects the script under test to fail. A script error the
//!   test never looked at fails the test once it has passed: errors after its last
//!   `r.errors()` call count, unless it called `r.expect_errors()` on that rig.
//! - `assert(cond)`, `assert(cond, msg)`, `assert_eq(a, b)`, `assert_eq(a, b, msg)`.
//!
//! Each test has a run's limits for its own code (operations: `TEST_BUDGET`; heap memory: a
//! run's default, 256 MiB, which the rigs it builds count against) and two budgets
//! (`script::test_budget`): the virtual time its `advance`, `tick` and `stall` calls move in
//! all (30 days) and real time (60 s); over either, the call that went over fails the test.
//! The script under test keeps its rig's limits (operations, time per call, memory, timers).
//! A test file without a `test_*` function taking no parameters fails as `file::(no tests)`.

use super::api::{duration, fail, R};
use super::builder::RigBuilder;
use super::engine::{sandboxed, Guard};
use super::error::{cause, innermost, location, parse_error};
use super::rig::Rig;
use super::test_budget::{breach_text, test_limits, TestBudget, TEST_BUDGET};
use super::values::{from_json, show, to_json};
use crate::config::RigConfig;
use crate::runtime::devices::{FieldError, SwappedModule};
use crate::runtime::runner::EndReason;
use crate::sim::c29u::OutputFault;
use crate::sim::faults::answer::AnswerFault;
use crate::text_file::{read_text, TextKind};
use crate::time::clock::{Clock, VirtualClock};
use crate::time::zone::Zone;
use chrono::{DateTime, FixedOffset, Utc};
use rhai::{Array, CallFnOptions, Dynamic, Engine, Map, Scope};
use std::cell::RefCell;
use std::path::{Path, PathBuf};
use std::rc::Rc;
use std::sync::Arc;

/// Where virtual wall time starts unless a test says otherwise.
pub const DEFAULT_START: &str = "2026-03-28T12:00:00Z";

/// One test function's outcome.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TestResult {
    /// `file::test_name`.
    pub name: String,
    /// Why it failed (`message at file:line:col`), or `None` if it passed.
    pub failure: Option<String>,
}

/// A script under test on its simulators.
struct Scenario {
    rig: Rig,
    clock: VirtualClock,
    violation_reported: bool,
    /// The test's budgets (shared by its rigs).
    budget: Rc<TestBudget>,
    /// Script errors the test has seen (`r.errors()`).
    errors_seen: u64,
    /// The test expects script errors (`r.expect_errors()`).
    errors_expected: bool,
}

impl Drop for Scenario {
    /// A rig whose script failed where the test never looked fails the test.
    fn drop(&mut self) {
        let errors = &self.rig.runner.errors;
        if !self.errors_expected && errors.total() > self.errors_seen {
            let index = usize::try_from(self.errors_seen).unwrap_or(usize::MAX);
            let first = errors
                .kept()
                .get(index)
                .map_or("(not kept)", |e| e.message.as_str());
            self.budget
                .note_unobserved(errors.total() - self.errors_seen, first);
        }
    }
}

impl Scenario {
    /// Moves the rig on by `by` within the test's budgets (`what` names the call).
    fn advance(&mut self, what: &str, by: std::time::Duration) -> R<()> {
        self.budget.take_virtual(what, by).or_else(fail)?;
        let runner = &mut self.rig.runner;
        let target = self.clock.now().saturating_add(by);
        // The wall-time budget is asked before each tick.
        while runner.tick_due_by(target) {
            if !self.budget.wall_time_left() {
                return fail(TestBudget::out_of_wall_time(what));
            }
            runner.step_toward(target);
        }
        runner.step_toward(target);
        self.violation()
    }

    /// An error naming the invariant found false, the first time the test drives the rig
    /// after it was.
    fn violation(&mut self) -> R<()> {
        if self.violation_reported {
            return Ok(());
        }
        match self.rig.runner.violation() {
            Some(v) => {
                self.violation_reported = true;
                fail(format!(
                    "{v} (t={})",
                    crate::time::duration::format_duration(v.uptime)
                ))
            }
            None => Ok(()),
        }
    }
}

/// A scenario as a test script holds it.
#[derive(Clone)]
pub struct RigHandle(Rc<RefCell<Scenario>>);

fn field<T>(r: Result<T, FieldError>) -> R<T> {
    r.or_else(|e| fail(e.to_string()))
}

fn u8_arg(what: &str, v: i64) -> R<u8> {
    u8::try_from(v).or_else(|_| fail(format!("{v} is not a {what} (0-255)")))
}

fn channel_arg(v: i64) -> R<u8> {
    match u8::try_from(v) {
        Ok(c) if c < 8 => Ok(c),
        _ => fail(format!("channel {v} does not exist: use 0-7")),
    }
}

fn parse_time(text: &str) -> R<DateTime<FixedOffset>> {
    DateTime::parse_from_rfc3339(text).or_else(|e| {
        fail(format!(
            "{text:?} is not an ISO 8601 time such as \"2026-03-29T00:30:00+01:00\": {e}"
        ))
    })
}

/// Loads the script under test.
fn load(
    budget: &Rc<TestBudget>,
    base: &Path,
    script: &str,
    config: Option<&str>,
    start_at: DateTime<FixedOffset>,
    zone: Zone,
) -> R<RigHandle> {
    let path = base.join(script);
    let config = match config {
        Some(c) => {
            let p = base.join(c);
            RigConfig::load(&p).or_else(|e| fail(e.to_string()))?
        }
        None => RigConfig::simulated_default(),
    };
    let source = read_text(&path, TextKind::Script)
        .or_else(|e| fail(format!("cannot read {}: {e}", path.display())))?;
    let clock = VirtualClock::new(start_at.with_timezone(&Utc));
    let rig = RigBuilder::from_config(config)
        .simulated()
        .clock(Arc::new(clock.clone()))
        .zone(zone)
        .log_to_stderr(false)
        .keep_log()
        .start(&source, &path.display().to_string())
        .or_else(|e| fail(format!("cannot start {}: {e}", path.display())))?;
    Ok(RigHandle(Rc::new(RefCell::new(Scenario {
        rig,
        clock,
        violation_reported: false,
        budget: Rc::clone(budget),
        errors_seen: 0,
        errors_expected: false,
    }))))
}

impl RigHandle {
    fn sim<T>(
        &self,
        f: impl FnOnce(&crate::runtime::devices::SimRig) -> Result<T, FieldError>,
    ) -> R<T> {
        field(f(&self.0.borrow().rig.sim))
    }
}

/// Registers the test API on `engine` for one test, whose budgets are `budget`; script paths
/// are relative to `base`.
pub fn register(engine: &mut Engine, base: &Path, budget: &Rc<TestBudget>) {
    engine.register_type_with_name::<RigHandle>("Rig");
    let default_start = parse_time(DEFAULT_START).ok();
    let (b, t) = (base.to_path_buf(), Rc::clone(budget));
    let start0 = default_start;
    engine.register_fn("rig", move |path: &str| -> R<RigHandle> {
        let at = start0.map_or_else(|| parse_time(DEFAULT_START), Ok)?;
        load(&t, &b, path, None, at, Zone::utc())
    });
    let (b, t) = (base.to_path_buf(), Rc::clone(budget));
    engine.register_fn("rig", move |path: &str, config: &str| -> R<RigHandle> {
        let at = default_start.map_or_else(|| parse_time(DEFAULT_START), Ok)?;
        load(&t, &b, path, Some(config), at, Zone::utc())
    });
    let (b, t) = (base.to_path_buf(), Rc::clone(budget));
    engine.register_fn("rig_at", move |path: &str, time: &str| -> R<RigHandle> {
        let at = parse_time(time)?;
        load(&t, &b, path, None, at, Zone::Fixed(*at.offset()))
    });
    let (b, t) = (base.to_path_buf(), Rc::clone(budget));
    engine.register_fn(
        "rig_at",
        move |path: &str, time: &str, zone: &str| -> R<RigHandle> {
            let at = parse_time(time)?;
            let zone = Zone::parse(zone).or_else(|e| fail(e.to_string()))?;
            load(&t, &b, path, None, at, zone)
        },
    );
    let (b, t) = (base.to_path_buf(), Rc::clone(budget));
    engine.register_fn(
        "rig_at",
        move |path: &str, time: &str, zone: &str, config: &str| -> R<RigHandle> {
            let at = parse_time(time)?;
            let zone = Zone::parse(zone).or_else(|e| fail(e.to_string()))?;
            load(&t, &b, path, Some(config), at, zone)
        },
    );
    register_driving(engine);
    register_field(engine);
    register_observations(engine);
    register_asserts(engine);
}

/// A wall-clock step written `"+1h"`, `"-90s"` (a duration with a sign; none means forward).
fn wall_step(text: &str) -> R<chrono::TimeDelta> {
    let (negative, rest) = match text.trim().strip_prefix('-') {
        Some(rest) => (true, rest),
        None => (false, text.trim().trim_start_matches('+')),
    };
    let d = crate::time::duration::parse_duration(rest).or_else(|e| fail(e.to_string()))?;
    let step = chrono::TimeDelta::from_std(d)
        .or_else(|_| fail(format!("a wall-clock step of {text:?} is too large")))?;
    Ok(if negative { -step } else { step })
}

fn register_driving(engine: &mut Engine) {
    engine.register_fn("advance", |r: &mut RigHandle, d: Dynamic| -> R<()> {
        let what = format!("r.advance({})", show(&d));
        let d = duration(&d)?;
        r.0.borrow_mut().advance(&what, d)
    });
    engine.register_fn("tick", |r: &mut RigHandle| -> R<()> {
        let mut s = r.0.borrow_mut();
        let before = s.clock.now();
        s.rig.runner.step();
        let moved = s.clock.now().saturating_sub(before);
        s.budget.note_virtual("r.tick()", moved).or_else(fail)?;
        s.violation()
    });
    engine.register_fn("stall", |r: &mut RigHandle, d: Dynamic| -> R<()> {
        let what = format!("r.stall({})", show(&d));
        let d = duration(&d)?;
        let s = r.0.borrow();
        s.budget.take_virtual(&what, d).or_else(fail)?;
        s.clock.advance(d);
        Ok(())
    });
    engine.register_fn("step_wall", |r: &mut RigHandle, step: &str| -> R<()> {
        let step = wall_step(step)?;
        r.0.borrow().clock.step_wall(step);
        Ok(())
    });
    engine.register_fn("signal_stop", |r: &mut RigHandle| {
        r.0.borrow_mut().rig.runner.signal_stop();
    });
    engine.register_fn("end", |r: &mut RigHandle| {
        r.0.borrow_mut()
            .rig
            .runner
            .finish(EndReason::Finished("the test ended the run".into()));
    });
}

fn register_field(engine: &mut Engine) {
    engine.register_fn("press", |r: &mut RigHandle, dev: &str, name: &str| {
        r.sim(|s| s.set_switch(dev, name, true))
    });
    engine.register_fn("release", |r: &mut RigHandle, dev: &str, name: &str| {
        r.sim(|s| s.set_switch(dev, name, false))
    });
    engine.register_fn(
        "turn",
        |r: &mut RigHandle, dev: &str, name: &str, half_turns: i64| -> R<()> {
            let n = i32::try_from(half_turns)
                .or_else(|_| fail(format!("turn by {half_turns}: too far")))?;
            r.sim(|s| s.turn(dev, name, n))
        },
    );
    engine.register_fn(
        "set_inputs",
        |r: &mut RigHandle, dev: &str, v: i64| -> R<()> {
            let v = u8_arg("DI byte", v)?;
            r.sim(|s| s.set_inputs(dev, v))
        },
    );
    engine.register_fn(
        "set_input",
        |r: &mut RigHandle, dev: &str, ch: i64, on: bool| -> R<()> {
            let ch = channel_arg(ch)?;
            r.sim(|s| s.set_input(dev, ch, on))
        },
    );
    engine.register_fn(
        "pulse",
        |r: &mut RigHandle, dev: &str, ch: i64, n: i64| -> R<()> {
            let ch = channel_arg(ch)?;
            let n =
                u32::try_from(n).or_else(|_| fail(format!("pulse count {n}: use 0 or more")))?;
            r.sim(|s| s.pulse(dev, ch, n))
        },
    );
    engine.register_fn("fail", |r: &mut RigHandle, dev: &str| {
        r.sim(|s| s.set_gone(dev, true))
    });
    engine.register_fn("restore", |r: &mut RigHandle, dev: &str| {
        r.sim(|s| s.set_gone(dev, false))
    });
    engine.register_fn("power_cycle", |r: &mut RigHandle, dev: &str| {
        r.sim(|s| s.power_cycle(dev))
    });
    engine.register_fn("ignore_writes", |r: &mut RigHandle, dev: &str| {
        r.sim(|s| s.set_output_fault(dev, Some(OutputFault::Ignore)))
    });
    engine.register_fn(
        "refuse_writes",
        |r: &mut RigHandle, dev: &str, code: i64| -> R<()> {
            let code = u8_arg("Modbus exception code", code)?;
            r.sim(|s| s.set_output_fault(dev, Some(OutputFault::Refuse(code))))
        },
    );
    engine.register_fn("accept_writes", |r: &mut RigHandle, dev: &str| {
        r.sim(|s| s.set_output_fault(dev, None))
    });
    engine.register_fn(
        "swap_module",
        |r: &mut RigHandle, dev: &str, other: Map| -> R<()> {
            let other = swapped_module(&other)?;
            r.sim(|s| s.swap_module(dev, &other))
        },
    );
    for (name, fault) in [
        ("drop_answers", AnswerFault::Drop),
        ("garble_answers", AnswerFault::Garble),
        ("duplicate_answers", AnswerFault::Duplicate),
    ] {
        engine.register_fn(name, move |r: &mut RigHandle, dev: &str, n: i64| -> R<()> {
            queue_answer_faults(r, name, dev, fault, n)
        });
    }
    engine.register_fn(
        "late_answers",
        |r: &mut RigHandle, dev: &str, n: i64, late: Dynamic| -> R<()> {
            let late = duration(&late)?;
            queue_answer_faults(r, "late_answers", dev, AnswerFault::Late(late), n)
        },
    );
}

/// Queues `fault` for the device's next `n` answers, or fails the test saying how many can wait.
fn queue_answer_faults(
    r: &mut RigHandle,
    name: &str,
    dev: &str,
    fault: AnswerFault,
    n: i64,
) -> R<()> {
    let n = usize::try_from(n).or_else(|_| fail(format!("{name}: {n} answers?")))?;
    let queued = r.sim(|s| s.fault_answers(dev, fault, n))?;
    if queued < n {
        return fail(format!(
            "{name}({dev:?}, {n}): only {queued} more can wait; make the device gone \
             with r.fail(dev) for a dead line"
        ));
    }
    Ok(())
}

/// The module `r.swap_module` puts in place, from the test's map.
fn swapped_module(map: &Map) -> R<SwappedModule> {
    let mut m = SwappedModule::default();
    for (key, value) in map {
        match key.as_str() {
            "name" => m.name = value.to_string(),
            "safe_value" => m.safe_value = u8_arg("safe value", value.as_int().unwrap_or(-1))?,
            "power_on_value" => {
                m.power_on_value = u8_arg("power-on value", value.as_int().unwrap_or(-1))?;
            }
            "watchdog" if value.is_unit() => m.watchdog_tenths = 0,
            "watchdog" => {
                let d = duration(value)?;
                m.watchdog_tenths =
                    crate::device::c29u::watchdog_tenths(d).or_else(|e| fail(e.to_string()))?;
            }
            "firmware" => m.firmware = firmware_date(&value.to_string())?,
            other => {
                return fail(format!(
                    "swap_module: unknown key {other:?} (name, firmware, safe_value, \
                     power_on_value, watchdog)"
                ))
            }
        }
    }
    Ok(m)
}

/// A firmware date written `"YYMMDD"`.
fn firmware_date(text: &str) -> R<crate::protocol::c29u::FirmwareDate> {
    let part = |at: usize| text.get(at..at + 2).and_then(|p| p.parse::<u8>().ok());
    match (text.len(), part(0), part(2), part(4)) {
        (6, Some(year), Some(month), Some(day)) => {
            Ok(crate::protocol::c29u::FirmwareDate { year, month, day })
        }
        _ => fail(format!("firmware {text:?}: write its date as \"YYMMDD\"")),
    }
}

fn register_observations(engine: &mut Engine) {
    engine.register_fn("outputs", |r: &mut RigHandle, dev: &str| -> R<i64> {
        r.sim(|s| s.outputs(dev)).map(i64::from)
    });
    engine.register_fn("relay", |r: &mut RigHandle, dev: &str| -> R<i64> {
        r.sim(|s| s.relay(dev)).map(i64::from)
    });
    engine.register_fn("safe_mode", |r: &mut RigHandle, dev: &str| -> R<bool> {
        r.sim(|s| s.safe_mode(dev))
    });
    engine.register_fn("safe_value", |r: &mut RigHandle, dev: &str| -> R<i64> {
        r.sim(|s| s.safe_value(dev)).map(i64::from)
    });
    engine.register_fn("power_on_value", |r: &mut RigHandle, dev: &str| -> R<i64> {
        r.sim(|s| s.power_on_value(dev)).map(i64::from)
    });
    engine.register_fn("watchdog", |r: &mut RigHandle, dev: &str| -> R<Map> {
        let w = r.sim(|s| s.watchdog(dev))?;
        let mut m = Map::new();
        m.insert("enabled".into(), Dynamic::from(w.enabled));
        m.insert(
            "timeout_ms".into(),
            Dynamic::from(i64::from(w.timeout_tenths) * 100),
        );
        m.insert("expired".into(), Dynamic::from(w.expired));
        Ok(m)
    });
    engine.register_fn(
        "counter",
        |r: &mut RigHandle, dev: &str, ch: i64| -> R<i64> {
            let ch = channel_arg(ch)?;
            r.sim(|s| s.counter(dev, ch)).map(i64::from)
        },
    );
    engine.register_fn("records", |r: &mut RigHandle| -> Array {
        let s = r.0.borrow();
        let rt = s.rig.runner.runtime().borrow();
        rt.records_kept().iter().map(from_json).collect()
    });
    engine.register_fn("stopped", |r: &mut RigHandle| {
        r.0.borrow().rig.runner.status().is_some()
    });
    engine.register_fn("exit_status", |r: &mut RigHandle| -> Dynamic {
        r.0.borrow()
            .rig
            .runner
            .status()
            .map_or(Dynamic::UNIT, |s| Dynamic::from(i64::from(s)))
    });
    engine.register_fn("log", |r: &mut RigHandle| -> Array {
        let s = r.0.borrow();
        let rt = s.rig.runner.runtime().borrow();
        rt.log_lines()
            .iter()
            .map(|l| Dynamic::from(l.clone()))
            .collect()
    });
    engine.register_fn("now", |r: &mut RigHandle| -> String {
        r.0.borrow()
            .rig
            .runner
            .runtime()
            .borrow()
            .cycle()
            .wall_text()
    });
    engine.register_fn("overruns", |r: &mut RigHandle| -> i64 {
        i64::try_from(r.0.borrow().rig.runner.stats().overruns).unwrap_or(i64::MAX)
    });
    engine.register_fn("held_safe", |r: &mut RigHandle| -> bool {
        r.0.borrow().rig.runner.runtime().borrow().held_safe()
    });
    engine.register_fn("errors", |r: &mut RigHandle| -> Array {
        let mut s = r.0.borrow_mut();
        s.errors_seen = s.rig.runner.errors.total();
        s.rig
            .runner
            .errors
            .kept()
            .iter()
            .map(|e| Dynamic::from(e.message.clone()))
            .collect()
    });
    engine.register_fn("expect_errors", |r: &mut RigHandle| {
        r.0.borrow_mut().errors_expected = true;
    });
    engine.register_fn("violation", |r: &mut RigHandle| -> Dynamic {
        r.0.borrow()
            .rig
            .runner
            .violation()
            .map_or(Dynamic::UNIT, |v| Dynamic::from(v.to_string()))
    });
    engine.register_fn(
        "end_confirmed",
        |r: &mut RigHandle, dev: &str| -> R<Dynamic> {
            let s = r.0.borrow();
            let report = s.rig.runner.end_report();
            if report.is_empty() {
                return Ok(Dynamic::UNIT);
            }
            match report.iter().find(|d| d.device == dev) {
                Some(d) => Ok(Dynamic::from(!d.needs_safe_state())),
                None => fail(format!("no device called {dev:?} at the end")),
            }
        },
    );
    engine.register_fn("online", |r: &mut RigHandle, dev: &str| -> R<bool> {
        let s = r.0.borrow();
        let rt = s.rig.runner.runtime().borrow();
        match rt.devices().index(dev) {
            Some(i) => Ok(rt.devices().online(i)),
            None => fail(format!(
                "no device called {dev:?} (devices: {})",
                rt.devices().names()
            )),
        }
    });
}

fn register_asserts(engine: &mut Engine) {
    engine.register_fn("assert", |cond: bool| -> R<()> {
        if cond {
            Ok(())
        } else {
            fail("assertion failed")
        }
    });
    engine.register_fn("assert", |cond: bool, msg: &str| -> R<()> {
        if cond {
            Ok(())
        } else {
            fail(format!("assertion failed: {msg}"))
        }
    });
    let eq = |a: &Dynamic, b: &Dynamic, msg: &str| -> R<()> {
        if to_json(a) == to_json(b) {
            Ok(())
        } else {
            let what = if msg.is_empty() {
                "assert_eq failed".to_string()
            } else {
                format!("assert_eq failed: {msg}")
            };
            fail(format!("{what}: left {}, right {}", show(a), show(b)))
        }
    };
    engine.register_fn("assert_eq", move |a: Dynamic, b: Dynamic| eq(&a, &b, ""));
    engine.register_fn("assert_eq", move |a: Dynamic, b: Dynamic, msg: &str| {
        eq(&a, &b, msg)
    });
}

/// An engine with the test API for one test, its budgets, and the guard that watches the
/// test's own calls (operations, wall time, the heap it and its rigs hold); a test's own
/// `print` and `debug` go to stderr.
fn test_engine(base: &Path) -> (Engine, Rc<TestBudget>, Rc<Guard>) {
    let mut engine = sandboxed(TEST_BUDGET);
    let budget = Rc::new(TestBudget::start());
    register(&mut engine, base, &budget);
    let guard = Guard::install(
        &mut engine,
        test_limits(),
        crate::time::clock::SystemClock::shared(),
        Arc::default(),
    );
    engine.on_print(|s| eprintln!("{s}"));
    engine.on_debug(|s, _, _| eprintln!("{s}"));
    (engine, budget, guard)
}

/// Runs every `test_*` function of the test file at `path` (called `file` in messages),
/// each in a fresh engine; calls `report` with each result as it comes.
pub fn run_file(path: &Path, file: &str, mut report: impl FnMut(&TestResult)) -> Vec<TestResult> {
    let base: PathBuf = path.parent().map(Path::to_path_buf).unwrap_or_default();
    match read_text(path, TextKind::TestFile) {
        Ok(source) => run_source(&source, &base, file, report),
        Err(e) => {
            let r = TestResult {
                name: format!("{file}::(load)"),
                failure: Some(format!("cannot read {file}: {e}")),
            };
            report(&r);
            vec![r]
        }
    }
}

/// Runs every `test_*` function of a test file's text `source` as `run_file` does, its paths
/// read from the directory `base` (`verify` runs a counterexample's test this way before it
/// writes it).
pub fn run_source(
    source: &str,
    base: &Path,
    file: &str,
    mut report: impl FnMut(&TestResult),
) -> Vec<TestResult> {
    let mut results = Vec::new();
    let mut push = |r: TestResult| {
        report(&r);
        results.push(r);
    };
    let engine = sandboxed(TEST_BUDGET);
    let ast = match engine.compile(source) {
        Ok(ast) => ast,
        Err(e) => {
            push(TestResult {
                name: format!("{file}::(compile)"),
                failure: Some(parse_error(file, source, &e)),
            });
            return results;
        }
    };
    let mut tests: Vec<String> = ast
        .iter_functions()
        .filter(|f| f.name.starts_with("test_") && f.params.is_empty())
        .map(|f| f.name.to_string())
        .collect();
    if tests.is_empty() {
        push(TestResult {
            name: format!("{file}::(no tests)"),
            failure: Some(format!(
                "{file} has no tests: a test is a function whose name starts with test_ and \
                 that takes no parameters, such as `fn test_start() {{ .. }}`"
            )),
        });
        return results;
    }
    // In the order they are written.
    tests.sort_by_key(|name| source.find(&format!("fn {name}(")).unwrap_or(usize::MAX));
    for name in tests {
        let (engine, budget, guard) = test_engine(base);
        let options = CallFnOptions::new().eval_ast(false);
        guard.begin_call();
        let result = engine
            .call_fn_with_options::<Dynamic>(options, &mut Scope::new(), &ast, &name, ())
            .map(drop);
        let breach = guard.end_call();
        // The rigs the test built are gone now: their unobserved errors are noted.
        let failure = match (result, breach) {
            (result, Some(b)) => {
                let at = result.err().and_then(|e| location(file, innermost(&e).1));
                Some(at.map_or_else(
                    || breach_text(&b),
                    |at| format!("{} at {at}", breach_text(&b)),
                ))
            }
            (Err(e), None) => {
                let (inner, pos) = innermost(&e);
                Some(match location(file, pos) {
                    Some(at) => format!("{} at {at}", cause(inner)),
                    None => cause(inner),
                })
            }
            (Ok(()), None) => budget.unobserved(),
        };
        push(TestResult {
            name: format!("{file}::{name}"),
            failure,
        });
    }
    results
}

/// The `*.test.rhai` files under `path` (itself, if it is one), sorted.
pub fn test_files(path: &Path) -> std::io::Result<Vec<PathBuf>> {
    if path.is_file() {
        return Ok(vec![path.to_path_buf()]);
    }
    let mut found = Vec::new();
    let mut dirs = vec![path.to_path_buf()];
    while let Some(dir) = dirs.pop() {
        for entry in std::fs::read_dir(&dir)? {
            let p = entry?.path();
            if p.is_dir() {
                dirs.push(p);
            } else if p
                .file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.ends_with(".test.rhai"))
            {
                found.push(p);
            }
        }
    }
    found.sort();
    Ok(found)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn a_test_out_of_wall_time_fails_in_the_advance_it_ran_out_in() {
        let dir = std::env::temp_dir().join(format!("rigscript-wall-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // Polls the inputs: every tick runs.
        std::fs::write(dir.join("s.rhai"), "io.on_rise(0, || {});\n").unwrap();
        let mut engine = sandboxed(TEST_BUDGET);
        let budget = Rc::new(TestBudget::with_wall_time(Duration::ZERO));
        register(&mut engine, &dir, &budget);
        let err = engine
            .run("let r = rig(\"s.rhai\");\nr.advance(\"1h\");")
            .unwrap_err();
        let (inner, pos) = innermost(&err);
        assert_eq!(
            cause(inner),
            "the test ran out of its wall-time budget of 1m during r.advance(\"1h\") (a rig \
             polling fast over a long advance?)"
        );
        assert_eq!(pos.line(), Some(2));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
