//! The memory limit is each run's own: runs that share a process (`verify --jobs N`, runs on
//! parallel threads) are held to their own heap, so one run's growth never stops a neighbour.
//! And a run gives its heap back when it ends. This test binary counts its heap as `rigscript`
//! does.

use rigscript::config::{RigConfig, ScriptLimits};
use rigscript::heap::{self, CountingAlloc};
use rigscript::{Rig, RigBuilder};
use std::sync::mpsc;
use std::thread;
use std::time::Duration;

#[global_allocator]
static HEAP: CountingAlloc = CountingAlloc;

const LIMIT: u64 = 64 << 20;

/// Keeps 1,000 closures holding a 60 KB string each in an array every 100 ms (60 MB a tick;
/// an array of the strings themselves would meet the limit on a string's size first). They
/// stay in the run's scope after it stops, until the run is dropped.
const GROWS: &str = "let base = \"x\";\nbase.pad(60000, \"x\");\nlet keep = [];\nlet k = 0;\n\
    io.outputs = 0x0F;\n\
    every(\"100ms\", || {\n  for i in 0..1000 {\n    k += 1;\n    let t = base + k;\n    \
    keep.push(|| t.len());\n  }\n});\n";

/// Holds 2 MB while each tick runs (32 closures holding a 60 KB string each), no more.
const SMALL: &str = "let base = \"x\";\nbase.pad(60000, \"x\");\nio.outputs = 0x0F;\n\
    every(\"100ms\", || {\n  let held = [];\n  for i in 0..32 {\n    let t = base + i;\n    \
    held.push(|| t.len());\n  }\n});\n";

/// A script started on the simulated default rig in virtual time, its log kept.
fn start(source: &str, file: &str) -> Rig {
    let config = RigConfig {
        limits: ScriptLimits {
            memory: LIMIT,
            ..ScriptLimits::default()
        },
        ..RigConfig::simulated_default()
    };
    RigBuilder::from_config(config)
        .simulated()
        .virtual_time_from("2026-03-28T00:00:30Z".parse().unwrap())
        .log_to_stderr(false)
        .keep_log()
        .start(source, file)
        .unwrap()
}

#[test]
fn a_run_that_grows_past_its_limit_stops_alone_and_its_neighbour_runs_on() {
    let (small_started, small_is_started) = mpsc::channel();
    let (grower_stopped, grower_is_stopped) = mpsc::channel();
    let (small_done, small_is_done) = mpsc::channel::<()>();
    let small = thread::spawn(move || {
        let mut rig = start(SMALL, "small.rhai");
        rig.runner.advance(Duration::from_millis(500));
        small_started.send(()).unwrap();
        // The other run, stopped as it went over, still holds nearly the limit (its scope is
        // kept until it is dropped): with this run's 2 MB the process is over it, this run not.
        grower_is_stopped.recv().unwrap();
        rig.runner.advance(Duration::from_secs(3));
        let seen = (rig.runner.status(), rig.log().join("\n"));
        small_done.send(()).unwrap();
        seen
    });
    let grower = thread::spawn(move || {
        small_is_started.recv().unwrap();
        let mut rig = start(GROWS, "grows.rhai");
        rig.runner.advance(Duration::from_secs(10));
        let seen = (rig.runner.status(), rig.log().join("\n"));
        grower_stopped.send(()).unwrap();
        small_is_done.recv().unwrap();
        seen
    });
    let (grower_status, grower_log) = grower.join().unwrap();
    let (small_status, small_log) = small.join().unwrap();

    assert_eq!(grower_status, Some(1), "{grower_log}");
    let line = grower_log
        .lines()
        .find(|l| l.contains("over its limit of 64 MiB"))
        .unwrap_or_else(|| panic!("no memory error: {grower_log}"));
    assert!(line.contains("grows.rhai:"), "{line}");
    assert!(line.contains("the run's memory reached"), "{line}");

    assert_eq!(small_status, None, "{small_log}");
    assert!(!small_log.contains("memory"), "{small_log}");
}

#[test]
fn a_run_gives_its_heap_back_when_it_is_dropped() {
    // A handler that holds the device handle (which holds the runtime, which holds the
    // handler), and timers that keep 10 MB. Counted on this thread: the other test's runs
    // move the process's count.
    let source = "let io = device(\"io\");\nevery(\"100ms\", || { let n = io.inputs; });\n\
        let base = \"x\";\nbase.pad(60000, \"x\");\n\
        for i in 0..100 {\n  let t = base + i;\n  after(\"1h\", || t.len());\n}\n";
    let before = heap::thread_balance();
    let mut rig = start(source, "holds.rhai");
    rig.runner.advance(Duration::from_secs(1));
    let held = heap::thread_balance() - before;
    assert!(held > 5 << 20, "held {held}");
    drop(rig);
    let kept = heap::thread_balance() - before;
    assert!(kept < 1 << 20, "kept {kept} of {held} bytes after the run");
}
