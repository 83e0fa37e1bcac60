//! Invariants in a run: checked every tick after the handlers, a false one ends the run with
//! the safe state instead of the tick's outputs, and a broken one is a script error at its line.

use super::builder::RigBuilder;
use super::engine::DEFAULT_BUDGET;
use super::rig::Rig;
use crate::config::ErrorPolicy;
use std::time::Duration;

fn rig(script: &str, policy: ErrorPolicy, budget: u64) -> Rig {
    RigBuilder::for_tests()
        .on_error(policy)
        .budget(budget)
        .start(script, "t.rhai")
        .unwrap()
}

fn log(r: &Rig) -> String {
    r.runner.runtime().borrow().log_lines().join("\n")
}

const GUARDED: &str = r#"
let io = device("io");
invariant("power only with DI0 closed", || (io.outputs & 1) == 0 || io.input(0));
io.on_rise(1, || io.outputs = 1);
"#;

#[test]
fn a_false_invariant_writes_the_safe_state_instead_of_the_outputs_and_ends_with_1() {
    // Policy skip would go on after a script error; an invariant found false stops anyway.
    let mut r = rig(GUARDED, ErrorPolicy::Skip, DEFAULT_BUDGET);
    r.runner.advance(Duration::from_millis(40));
    r.sim.set_inputs("io", 0x02).unwrap();
    r.runner.advance(Duration::from_millis(40));
    assert_eq!(r.runner.status(), Some(1));
    assert_eq!(r.sim.outputs("io").unwrap(), 0, "0x01 was never written");
    let v = r.runner.violation().expect("a violation");
    assert_eq!(v.name, "power only with DI0 closed");
    assert_eq!(v.at.as_deref(), Some("t.rhai:3:1"));
    assert_eq!(v.readings(), "io outputs 0x01, inputs 0x02");
    let log = log(&r);
    assert!(
        log.contains(
            "invariant \"power only with DI0 closed\" is false (stated at t.rhai:3:1): io \
             outputs 0x01, inputs 0x02"
        ),
        "{log}"
    );
    assert!(!log.contains("io: outputs 0x00 -> 0x01"), "{log}");
    assert!(
        log.contains("safe state (invariant false): io outputs 0x00"),
        "{log}"
    );
    let rt = r.runner.runtime().borrow();
    let rec = rt.records_kept().last().unwrap().clone();
    assert_eq!(rec["name"], "invariant_violated");
    assert_eq!(rec["value"]["invariant"], "power only with DI0 closed");
    assert_eq!(rec["value"]["devices"]["io"]["inputs"], 2);
    assert_eq!(rec["value"]["devices"]["io"]["outputs"], 1);
}

#[test]
fn an_invariant_that_holds_lets_the_outputs_through() {
    let mut r = rig(GUARDED, ErrorPolicy::Stop, DEFAULT_BUDGET);
    r.runner.advance(Duration::from_millis(40));
    r.sim.set_inputs("io", 0x03).unwrap();
    r.runner.advance(Duration::from_millis(40));
    assert_eq!(r.runner.status(), None);
    assert_eq!(r.sim.outputs("io").unwrap(), 1);
}

#[test]
fn invariants_are_checked_every_tick_even_when_no_handler_polls() {
    // Only a 1 s timer: without the invariant, idle ticks would be skipped and the input
    // never read between timer firings.
    let script = r#"
        let io = device("io");
        io.outputs = 1;
        invariant("DI0 closed while powered", || io.outputs == 0 || io.input(0));
        every("1s", || {});
    "#;
    let mut r = rig(script, ErrorPolicy::Stop, DEFAULT_BUDGET);
    r.sim.set_inputs("io", 0x01).unwrap();
    r.runner.advance(Duration::from_millis(100));
    assert_eq!(r.runner.status(), None);
    r.sim.set_inputs("io", 0x00).unwrap();
    r.runner.advance(Duration::from_millis(40));
    assert_eq!(
        r.runner.status(),
        Some(1),
        "found within two ticks, not at the timer"
    );
    assert_eq!(r.sim.outputs("io").unwrap(), 0);
}

#[test]
fn an_invariant_that_reads_no_inputs_leaves_idle_ticks_skipped() {
    // Only outputs and script state: they change only in ticks that run anyway.
    let script = r#"
        let io = device("io");
        let on = false;
        invariant("DO0 as the script says", || io.output(0) == on);
        every("1m", || { on = !on; io.set_output(0, on); });
    "#;
    let mut r = rig(script, ErrorPolicy::Stop, DEFAULT_BUDGET);
    r.runner.advance(Duration::from_secs(3600));
    assert_eq!(r.runner.status(), None);
    assert!(
        r.runner.stats().ticks < 1_000,
        "{} ticks in an hour at 20 ms",
        r.runner.stats().ticks
    );
}

#[test]
fn an_invariant_that_throws_is_a_script_error_at_its_line() {
    let script = "let io = device(\"io\");\ninvariant(\"x\", || {\n  io.nope()\n});\nevery(\"1s\", || {});\n";
    let mut r = rig(script, ErrorPolicy::Skip, DEFAULT_BUDGET);
    r.runner.advance(Duration::from_millis(20));
    assert_eq!(r.runner.status(), Some(1), "never skipped");
    let e = &r.runner.errors.kept()[0];
    assert!(
        e.message.starts_with("t.rhai:3:6: in invariant \"x\":"),
        "{}",
        e.message
    );
    assert!(r.runner.violation().is_none());
}

#[test]
fn an_invariant_that_is_not_a_bool_is_a_script_error_where_it_was_stated() {
    let script =
        "let io = device(\"io\");\n\ninvariant(\"count\", || io.inputs);\nevery(\"1s\", || {});\n";
    let mut r = rig(script, ErrorPolicy::Restart, DEFAULT_BUDGET);
    r.runner.advance(Duration::from_millis(20));
    assert_eq!(r.runner.status(), Some(1), "never restarted");
    let e = &r.runner.errors.kept()[0].message;
    assert_eq!(
        e,
        "t.rhai:3:1: in invariant \"count\": invariant \"count\" returned 0 (i64), not true or false"
    );
}

#[test]
fn an_invariant_that_never_ends_is_stopped_by_the_budget() {
    let script = "invariant(\"spin\", || { loop {} });\nevery(\"1s\", || {});\n";
    let mut r = rig(script, ErrorPolicy::Skip, 10_000);
    r.runner.advance(Duration::from_millis(20));
    assert_eq!(r.runner.status(), Some(1));
    let e = &r.runner.errors.kept()[0];
    assert!(e.over_budget, "{e:?}");
    assert!(e.message.starts_with("t.rhai:1:"), "{}", e.message);
}

#[test]
fn invariants_need_distinct_names_and_a_closure() {
    let mut r = rig(
        "invariant(\"a\", || true);\ninvariant(\"a\", || true);\n",
        ErrorPolicy::Stop,
        DEFAULT_BUDGET,
    );
    assert_eq!(r.runner.status(), Some(1));
    let e = &r.runner.errors.kept()[0].message;
    assert!(
        e.contains("t.rhai:2:1") && e.contains("already an invariant called \"a\""),
        "{e}"
    );
    r = rig(
        "invariant(\"a\", true);\n",
        ErrorPolicy::Stop,
        DEFAULT_BUDGET,
    );
    let e = &r.runner.errors.kept()[0].message;
    assert!(e.contains("must be a closure taking no parameters"), "{e}");
    r = rig(
        "invariant(\"a\", |x| true);\n",
        ErrorPolicy::Stop,
        DEFAULT_BUDGET,
    );
    let e = &r.runner.errors.kept()[0].message;
    assert!(
        e.contains("the handler of invariant takes no parameters"),
        "{e}"
    );
}
