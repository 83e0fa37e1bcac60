//! Reloads in a run: the new script swapped in between ticks with the outputs as they were,
//! its top-level variables given the old values, `is_reload()` and `on_reload`; a script that
//! does not compile or fails to start leaves the old one running, its outputs kept.

use super::builder::RigBuilder;
use super::rig::Rig;
use std::time::Duration;

fn rig(script: &str) -> Rig {
    RigBuilder::for_tests().start(script, "a.rhai").unwrap()
}

fn log(r: &Rig) -> String {
    r.runner.runtime().borrow().log_lines().join("\n")
}

/// Steps the run tick by tick for `ms`, the module's outputs after each tick.
fn outputs_over(r: &mut Rig, ms: u64) -> Vec<u8> {
    let until = r.runner.next_deadline() + Duration::from_millis(ms);
    let mut seen = Vec::new();
    while r.runner.next_deadline() < until {
        r.runner.step();
        seen.push(r.sim.outputs("io").unwrap());
    }
    seen
}

/// The hash the first reload swapped in: the one the second reload swaps out.
fn reload_from(records: &[serde_json::Value]) -> serde_json::Value {
    records
        .iter()
        .find(|v| v["name"] == "reload")
        .map(|v| v["value"]["to"].clone())
        .unwrap_or_default()
}

const TOGGLING: &str = r#"
let io = device("io");
let n = 0;
if !is_reload() { io.outputs = 1; }
every(100, || { n += 1; io.outputs = if io.outputs == 1 { 2 } else { 1 }; });
"#;

#[test]
fn a_reload_keeps_the_outputs_and_carries_the_variables_closures_see() {
    let mut r = rig(TOGGLING);
    let before = outputs_over(&mut r, 1000);
    assert!(
        before.iter().skip(1).all(|v| [1, 2].contains(v)),
        "{before:?}"
    );
    // The same script again: nothing is written at the swap, the toggling goes on.
    r.runner.reload(TOGGLING, "a.rhai", "a test").unwrap();
    let across = outputs_over(&mut r, 500);
    assert!(across.iter().all(|v| [1, 2].contains(v)), "{across:?}");
    // A new script counting on from the old count: n carried, seen by its closure.
    let counting = r#"
        let io = device("io");
        let n = 0;
        let hello = "new";
        if !is_reload() { io.outputs = 1; }
        every(100, || { n += 1; io.outputs = n; });
    "#;
    r.runner.reload(counting, "b.rhai", "a test").unwrap();
    let after = outputs_over(&mut r, 300);
    // Its first timer is the first tick after the swap: n counts on from about 15 (1.5 s
    // of the old timer), not from 0.
    assert!(after[0] >= 10, "n carried: {after:?}");
    assert!(after.windows(2).all(|w| w[1] == w[0] + 1), "{after:?}");
    let l = log(&r);
    assert!(l.contains("reloaded b.rhai ("), "{l}");
    assert!(l.contains("variables carried: io, n"), "{l}");
    assert!(!l.contains("-> 0x00"), "never the safe state or zero: {l}");
    let records = r.records();
    let reload = records.iter().rfind(|v| v["name"] == "reload").unwrap();
    assert_eq!(reload["value"]["file"], "b.rhai", "{reload}");
    assert_eq!(
        reload["value"]["to"].as_str().unwrap().len(),
        64,
        "{reload}"
    );
    assert_eq!(reload["value"]["from"], reload_from(&records), "{reload}");
}

#[test]
fn on_reload_migrates_after_the_carry_and_runs_only_at_a_reload() {
    let first = r#"
        let io = device("io");
        let level = 3;
        on_reload(|| { level = 99; });
        every(100, || { io.outputs = level; });
    "#;
    let mut r = rig(first);
    r.runner.advance(Duration::from_millis(250));
    assert_eq!(
        r.sim.outputs("io").unwrap(),
        3,
        "on_reload never ran at the start"
    );
    let second = r#"
        let io = device("io");
        let level = 0;
        let was_reload = is_reload();
        on_reload(|| { level = level * 10 + (if was_reload { 1 } else { 0 }); });
        every(100, || { io.outputs = level; });
    "#;
    r.runner.reload(second, "a.rhai", "a test").unwrap();
    r.runner.advance(Duration::from_millis(150));
    assert_eq!(r.sim.outputs("io").unwrap(), 31, "{}", log(&r));
}

#[test]
fn a_script_that_does_not_compile_or_start_leaves_the_old_one_running() {
    let mut r = rig(TOGGLING);
    outputs_over(&mut r, 300);
    let e = r
        .runner
        .reload("let io = ;", "a.rhai", "a test")
        .unwrap_err();
    assert!(e.contains("a.rhai:1:"), "{e}");
    let e = r.runner.reload("\n  \n", "a.rhai", "a test").unwrap_err();
    assert!(e.contains("empty"), "{e}");
    let failing = r#"
        let io = device("io");
        let n = 1000;
        io.outputs = 0x77;
        every(10, || { io.outputs = 0x66; });
        throw "not today";
    "#;
    let e = r.runner.reload(failing, "a.rhai", "a test").unwrap_err();
    assert!(e.contains("not today"), "{e}");
    let after = outputs_over(&mut r, 500);
    assert!(after.iter().all(|v| [1, 2].contains(v)), "{after:?}");
    assert!(
        after.contains(&1) && after.contains(&2),
        "still toggling: {after:?}"
    );
    let l = log(&r);
    assert!(l.contains("refused: "), "{l}");
    assert!(!l.contains("0x77") && !l.contains("0x66"), "{l}");
    assert_eq!(r.runner.status(), None);
}

#[test]
fn within_the_rollback_window_an_error_or_a_false_invariant_brings_the_old_script_back() {
    let mut r = rig(TOGGLING);
    r.runner.set_rollback(Some(Duration::from_secs(2)));
    outputs_over(&mut r, 1000);
    // Fails at its third timer, 300 ms after the swap: back to the toggling, n as it was.
    let failing = r#"
        let io = device("io");
        let n = 0;
        let fired = 0;
        every(100, || { fired += 1; io.outputs = 0x30; if fired == 3 { throw "broken"; } });
    "#;
    r.runner.reload(failing, "b.rhai", "a test").unwrap();
    let seen = outputs_over(&mut r, 1000);
    assert!(seen.contains(&0x30), "the new script ran: {seen:?}");
    let tail = &seen[seen.len() - 5..];
    assert!(
        tail.iter().all(|v| [1, 2].contains(v)),
        "the old one again: {seen:?}"
    );
    let l = log(&r);
    assert!(l.contains("rolling back to a.rhai ("), "{l}");
    assert_eq!(r.runner.status(), None, "the run goes on");
    // A false invariant within the window: the same.
    let unsafe_ = r#"
        let io = device("io");
        let n = 0;
        invariant("never 3", || io.outputs != 3);
        every(100, || { io.outputs = 3; });
    "#;
    r.runner.reload(unsafe_, "c.rhai", "a test").unwrap();
    let seen = outputs_over(&mut r, 500);
    assert!(
        seen.iter().all(|v| [1, 2].contains(v)),
        "3 never written: {seen:?}"
    );
    assert_eq!(r.runner.status(), None, "{}", log(&r));
    // Past the window the reload stands, and an error is an error under the policy.
    let late = failing.replace("fired == 3", "fired == 30");
    r.runner.reload(&late, "b.rhai", "a test").unwrap();
    r.runner.advance(Duration::from_millis(3500));
    assert!(log(&r).contains("the reload stands"), "{}", log(&r));
    assert_eq!(r.runner.status(), Some(1), "policy stop after the window");
}
