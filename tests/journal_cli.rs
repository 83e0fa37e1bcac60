//! `run --journal` and `replay` as a person uses them, real processes on the wall clock: a
//! rig idle between its timers, asked its status while it runs (each ask wakes it for a tick
//! its script did not schedule), replays exactly against its own script, and an edit is told
//! where it first writes otherwise.

use crate::common::rigs::Rigs;
use crate::common::{stderr, stdout, until};
use std::time::Duration;

const SCRIPT: &str = "let io = device(\"io\");\nlet n = 0;\n\
                      every(\"300ms\", || { n += 1; io.outputs = n % 64; });\n";

#[test]
fn a_run_asked_its_status_replays_exactly_and_an_edit_is_told_where_it_differs() {
    let rigs = Rigs::new("journal-cli");
    let script = rigs.dir.file("idle.rhai", SCRIPT);
    let journal = rigs.dir.path("idle.journal");
    let journal = journal.to_str().unwrap();
    let mut run = rigs.run(&["--sim", "--for", "4s", "--journal", journal, &script]);
    // Asked now and then, as a person watching it does.
    let mut asked = 0;
    while run.try_wait().unwrap().is_none() && asked < 6 {
        if rigs.output(&["status", "idle", "--json"]).status.success() {
            asked += 1;
        }
        std::thread::sleep(Duration::from_millis(370));
    }
    let ended = until(Duration::from_secs(20), || run.try_wait().unwrap());
    assert_eq!(
        ended.and_then(|s| s.code()),
        Some(0),
        "the run ended by --for"
    );
    assert!(asked >= 3, "status answered {asked} time(s)");
    let text = std::fs::read_to_string(journal).unwrap();
    assert!(
        text.lines().any(|l| l.split(' ').nth(1) == Some("wake")),
        "the ticks made for status are journaled:\n{text}"
    );
    let same = rigs.output(&["replay", journal]);
    assert!(same.status.success(), "{}{}", stdout(&same), stderr(&same));
    assert!(
        stdout(&same).contains("outputs: as the run wrote them"),
        "{}",
        stdout(&same)
    );
    let edited = rigs
        .dir
        .file("edited.rhai", &SCRIPT.replace("n % 64", "n % 2"));
    let differs = rigs.output(&["replay", journal, &edited]);
    assert_eq!(differs.status.code(), Some(1), "{differs:?}");
    let told = stdout(&differs);
    assert!(
        told.contains("first divergence at tick") && told.contains("io wrote 0x02"),
        "{told}"
    );
}
