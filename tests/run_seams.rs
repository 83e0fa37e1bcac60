//! The loop's seams in virtual time, through the library: the events a run publishes (ticks,
//! inputs that change, outputs written, log lines, the end), the snapshot answered through the
//! control queue, a requested stop, and a consumer that falls behind losing events, counted.

use crate::common;

use rigscript::config::RigConfig;
use rigscript::runtime::observe::{Reading, RunEvent};
use rigscript::runtime::requests::{self, Answer, AskError, Request};
use std::sync::atomic::AtomicUsize;
use std::sync::Arc;
use std::time::Duration;

const SCRIPT: &str = r#"
every("20ms", || { io.outputs = io.inputs; });
"#;

fn started() -> (rigscript::Rig, requests::Requester, Arc<AtomicUsize>) {
    common::served(RigConfig::simulated_default(), SCRIPT, "mirror.rhai")
}

/// Asks for a snapshot from another thread while the loop runs ticks in virtual time.
fn snapshot(rig: &mut rigscript::Rig, ask: &requests::Requester) -> Answer {
    let asker = ask.clone();
    let asked = std::thread::spawn(move || asker.ask(Request::Snapshot, Duration::from_secs(10)));
    while !asked.is_finished() {
        rig.runner.advance(Duration::from_millis(20));
        std::thread::yield_now();
    }
    asked.join().unwrap().unwrap()
}

#[test]
fn a_run_tells_its_ticks_inputs_outputs_and_end_and_answers_snapshots_and_a_stop() {
    let (mut rig, ask, _flag) = started();
    let events = rig.runner.events().subscribe("test", 10_000).unwrap();
    rig.sim.set_inputs("io", 0x05).unwrap();
    rig.runner.advance(Duration::from_millis(100));
    let Answer::Snapshot(s) = snapshot(&mut rig, &ask) else {
        panic!("not a snapshot")
    };
    assert_eq!(s.script.file, "mirror.rhai");
    assert_eq!(s.script.state, "running");
    let io = serde_json::to_value(&s.devices["io"]).unwrap();
    assert_eq!(io["inputs"], 5, "{io}");
    assert_eq!(io["outputs_written"], 5, "{io}");
    assert_eq!(io["simulated"], true);
    assert!(s.ticks.count >= 5);
    ask.stop("the test");
    rig.runner.advance(Duration::from_millis(100));
    assert_eq!(rig.runner.status(), Some(143));
    assert!(
        rig.log()
            .iter()
            .any(|l| l.contains("stopping: asked by the test")),
        "{:?}",
        rig.log()
    );
    let seen: Vec<_> = std::iter::from_fn(|| events.next(Duration::ZERO).ok()).collect();
    assert!(seen.iter().any(|e| matches!(**e, RunEvent::Tick { .. })));
    assert!(seen.iter().any(|e| **e
        == RunEvent::Inputs {
            device: "io".into(),
            reading: Reading::DigitalInputs { value: 5 }
        }));
    assert!(seen.iter().any(|e| matches!(&**e,
        RunEvent::Outputs { device, value: 5, .. } if device == "io")));
    assert!(seen.iter().any(|e| matches!(&**e,
        RunEvent::Log { level: "notice", message, .. } if message.contains("asked by the test"))));
    let Some(RunEvent::Ended {
        status,
        safe,
        unconfirmed,
        ..
    }) = seen.last().map(|e| (**e).clone())
    else {
        panic!("the last event is the end: {seen:?}")
    };
    assert_eq!(status, 143);
    assert_eq!(safe, vec!["io".to_string(), "panel".to_string()]);
    assert!(unconfirmed.is_empty());
    assert_eq!(events.dropped(), 0);
    // The run has ended: askers are told so at once.
    assert_eq!(
        ask.ask(Request::Snapshot, Duration::from_secs(5)),
        Err(AskError::Gone)
    );
}

#[test]
fn a_consumer_that_never_reads_loses_events_counted_and_the_run_goes_on() {
    let (mut rig, ask, _flag) = started();
    let stalled = rig.runner.events().subscribe("stalled", 4).unwrap();
    rig.runner.advance(Duration::from_secs(1));
    let before = stalled.dropped();
    assert!(before > 40, "{before}");
    let Answer::Snapshot(s) = snapshot(&mut rig, &ask) else {
        panic!("not a snapshot")
    };
    // The loop runs on while the answer is on its way, so the stalled consumer loses more:
    // the count the snapshot shows lies between the losses before it was asked and after.
    let after = stalled.dropped();
    let counted = s.dropped.iter().find(|d| d.consumer == "stalled").unwrap();
    assert!(
        (before..=after).contains(&counted.events),
        "{before}..={after}: {s:?}"
    );
    assert!(s.ticks.count >= 50, "every tick ran: {:?}", s.ticks);
}
