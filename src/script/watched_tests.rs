//! The script's state as a snapshot shows it: its top-level variables as they stand, read no
//! more often than `VARIABLES_EVERY`, `watch(...)` choosing which, and each invariant with
//! whether it holds and when it was last found false.

use super::builder::RigBuilder;
use super::rig::Rig;
use crate::runtime::snapshot::{RigSnapshot, Variable};
use serde_json::json;
use std::time::Duration;

fn rig(script: &str) -> Rig {
    RigBuilder::for_tests().start(script, "a.rhai").unwrap()
}

fn run_for(r: &mut Rig, ms: u64) {
    let until = r.runner.next_deadline() + Duration::from_millis(ms);
    while r.runner.next_deadline() < until && r.runner.status().is_none() {
        r.runner.step();
    }
}

fn variable(s: &RigSnapshot, name: &str) -> Option<serde_json::Value> {
    s.script
        .variables
        .shown
        .iter()
        .find(|v| v.name == name)
        .map(|v| v.value.clone())
}

const COUNTING: &str = r#"
const LIMIT = 5;
let io = device("io");
let count = 0;
let phase = "idle";
invariant("at most LIMIT counts", || count <= LIMIT);
invariant("only DO0 is driven", || (io.outputs & 0xFE) == 0);
every(100, || { count += 1; phase = "counting"; });
"#;

#[test]
fn the_snapshot_shows_the_variables_as_handlers_left_them_and_every_invariant_holding() {
    let mut r = rig(COUNTING);
    let start = r.runner.snapshot();
    assert_eq!(variable(&start, "count"), Some(json!(0)));
    assert_eq!(start.script.variables.shown[0].name, "count", "in the order declared");
    assert_eq!(variable(&start, "phase"), Some(json!("idle")));
    assert_eq!(variable(&start, "LIMIT"), None, "constants never change: not shown");
    assert_eq!(start.script.variables.hidden, 0, "the device handle io is not state");
    run_for(&mut r, 350);
    let s = r.runner.snapshot();
    assert_eq!(variable(&s, "count"), Some(json!(3)), "{:?}", s.script.variables);
    assert_eq!(variable(&s, "phase"), Some(json!("counting")));
    let names: Vec<_> = s.script.invariants.iter().map(|i| i.name.as_str()).collect();
    assert_eq!(names, ["at most LIMIT counts", "only DO0 is driven"]);
    assert!(s.script.invariants.iter().all(|i| i.holds && i.failed_at_ms.is_none()));
    assert_eq!(s.script.invariants[0].at.as_deref(), Some("a.rhai:6:1"));
}

#[test]
fn the_invariant_the_run_ended_on_is_shown_false_with_when() {
    let mut r = rig(COUNTING);
    run_for(&mut r, 2000);
    assert_eq!(r.runner.status(), Some(1), "{}", r.log().join("\n"));
    let s = r.runner.snapshot();
    let broken = &s.script.invariants[0];
    assert!(!broken.holds, "{broken:?}");
    let at = broken.failed_at_ms.expect("when");
    assert!((600..=700).contains(&at), "the sixth count, at 600 ms: {at}");
    assert!(s.script.invariants[1].holds);
    assert_eq!(variable(&s, "count"), Some(json!(6)));
}

#[test]
fn watch_shows_what_it_names_constants_too_and_an_unknown_name_stops_the_start() {
    let mut r = rig(&format!("{COUNTING}\nwatch([\"count\", \"LIMIT\"]);"));
    run_for(&mut r, 250);
    let v = r.runner.snapshot().script.variables;
    assert_eq!(
        v.shown,
        [
            Variable {
                name: "count".into(),
                value: json!(2)
            },
            Variable {
                name: "LIMIT".into(),
                value: json!(5)
            }
        ]
    );
    assert!(v.chosen);
    let r = rig("let count = 0;\nwatch(\"cuont\");");
    assert_eq!(r.runner.status(), Some(1));
    let said = r.log().join("\n");
    assert!(
        said.contains("a.rhai:2:1") && said.contains("did you mean \"count\""),
        "{said}"
    );
}
