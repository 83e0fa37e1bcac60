//! The script's limits and the log, as a user meets them: a script that grows its memory, arms
//! too many timers, runs away in operations or time, recurses, grows a string or a map, each
//! stopped with its place and how to raise the limit, the safe state written; a log that never
//! blocks the loop or a signal, in text or JSON; and a day of an idle interlock whose log fits
//! on a screen. The memory limit is each run's own: runs that share a process (`verify --jobs
//! N`, runs on parallel threads) are held to their own heap, and a run gives its heap back when
//! it ends. This test binary counts its heap as `rigscript` does.

mod common;

use common::{rigscript, stderr, TempDir};
use rigscript::config::{C29uConfig, Port, RigConfig, ScriptLimits};
use rigscript::heap::{self, CountingAlloc};
use rigscript::runtime::log::LogFormat;
use rigscript::{Rig, RigBuilder};
use std::io::Read;
use std::path::PathBuf;
use std::process::{Child, Command, Output, Stdio};
use std::sync::mpsc;
use std::thread;
use std::time::{Duration, Instant};

#[global_allocator]
static HEAP: CountingAlloc = CountingAlloc;

/// A script started on the simulated default rig in virtual time, its log kept.
fn start(source: &str, limits: ScriptLimits) -> Rig {
    let config = RigConfig {
        limits,
        ..RigConfig::simulated_default()
    };
    RigBuilder::from_config(config)
        .simulated()
        .virtual_time_from("2026-03-28T00:00:30Z".parse().unwrap())
        .log_to_stderr(false)
        .keep_log()
        .start(source, "t.rhai")
        .unwrap()
}

fn log(rig: &Rig) -> String {
    rig.log().join("\n")
}

#[test]
fn a_runaway_handler_names_its_line_once_and_how_to_raise_the_budget() {
    let limits = ScriptLimits {
        operations: 10_000,
        ..ScriptLimits::default()
    };
    let mut rig = start(
        "io.outputs = 0x0F;\nevery(\"1s\", || {\n  let x = 0;\n  loop {\n    x += 1;\n  }\n});\n",
        limits,
    );
    rig.runner.advance(Duration::from_secs(2));
    assert_eq!(rig.runner.status(), Some(1));
    let log = log(&rig);
    let line = log
        .lines()
        .find(|l| l.contains("error: t.rhai:5:"))
        .unwrap_or_else(|| panic!("no error at line 5: {log}"));
    assert!(
        line.contains(": in every 1s: ran over its operation budget of 10000 operations"),
        "{line}"
    );
    assert!(line.contains("--budget"), "{line}");
    assert_eq!(line.matches("budget").count(), 2, "said once: {line}");
    assert!(
        log.contains("safe state (script error): io outputs 0x00"),
        "{log}"
    );
    assert_eq!(rig.sim.outputs("io").unwrap(), 0x00);
}

#[test]
fn limit_errors_inside_handlers_carry_their_line() {
    let cases = [
        (
            "fn deeper(n) {\n  deeper(n + 1)\n}\nevery(\"1s\", || {\n  deeper(0);\n});\n",
            "t.rhai:2:",
            "nested more than 48 deep",
        ),
        (
            "every(\"1s\", || {\n  let s = \"x\";\n  loop {\n    s += s;\n  }\n});\n",
            "t.rhai:4:",
            "a string grew to 131072 bytes, over the limit of 65536",
        ),
        (
            "every(\"1s\", || {\n  let m = #{};\n  for i in 0..20000 {\n    m[\"k\" + i] = i;\n  }\n});\n",
            "t.rhai:4:",
            "a map grew to 10001 entries, over the limit of 10000",
        ),
    ];
    for (source, at, cause) in cases {
        let mut rig = start(source, ScriptLimits::default());
        rig.runner.advance(Duration::from_secs(2));
        let log = log(&rig);
        let line = log
            .lines()
            .find(|l| l.contains("error: t.rhai:"))
            .unwrap_or_else(|| panic!("no placed error: {log}"));
        assert!(line.contains(at), "{at}: {line}");
        assert!(line.contains(cause), "{cause}: {line}");
        assert!(log.contains("safe state (script error)"), "{log}");
    }
}

#[test]
fn a_handler_over_its_time_is_stopped_on_the_runs_clock() {
    // A module that stops answering costs a 2 s timeout per request; the handler keeps asking.
    let mut config = RigConfig::simulated_default();
    let io = C29uConfig {
        timeout: Duration::from_secs(2),
        retries: 0,
        ..C29uConfig::with_defaults(Port::Simulated)
    };
    config
        .devices
        .insert("io".into(), rigscript::config::DeviceConfig::C29u(io));
    // A long grace time: the idle module is asked only every 15 s, so the handler, not a
    // probe between ticks, is the first to find it silent.
    config.grace = Duration::from_secs(60);
    let mut rig = RigBuilder::from_config(config)
        .simulated()
        .virtual_time_from("2026-03-28T00:00:30Z".parse().unwrap())
        .log_to_stderr(false)
        .keep_log()
        .start(
            "every(\"1s\", || {\n  for i in 0..5 {\n    try { let n = io.name; } catch { }\n  }\n});\n",
            "t.rhai",
        )
        .unwrap();
    rig.runner.advance(Duration::from_millis(500));
    rig.sim.set_gone("io", true).unwrap();
    rig.runner.advance(Duration::from_secs(5));
    assert_eq!(rig.runner.status(), Some(1));
    let log = log(&rig);
    let line = log
        .lines()
        .find(|l| l.contains("ran for more than 1s in one call"))
        .unwrap_or_else(|| panic!("no time limit: {log}"));
    assert!(line.contains("error: t.rhai:"), "{line}");
    assert!(line.contains("--handler-time"), "{line}");
}

#[test]
fn arming_a_timer_past_the_limit_is_an_error_at_its_call() {
    let limits = ScriptLimits {
        timers: 10,
        ..ScriptLimits::default()
    };
    let rig = start(
        "let n = 0;\nwhile n < 20 {\n  after(\"1h\", || log(\"late\"));\n  n += 1;\n}\n",
        limits,
    );
    assert_eq!(rig.runner.status(), Some(1));
    let log = log(&rig);
    assert!(
        log.contains("error: t.rhai:3:3: in top level: too many timers: 10 are armed"),
        "{log}"
    );
    assert!(log.contains("--max-timers"), "{log}");
}

#[test]
fn a_virtual_day_of_the_idle_interlock_fits_on_a_screen() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scripts/interlock.rhai");
    let source = std::fs::read_to_string(&path).unwrap();
    // Ticks of 2 s instead of 20 ms keep the test short; the 20 ms timer then fires once a
    // tick with the rest counted as missed, which the log treats the same way.
    let mut rig = RigBuilder::from_config(RigConfig::simulated_default())
        .simulated()
        .virtual_time_from("2026-03-28T00:00:30Z".parse().unwrap())
        .period(Duration::from_secs(2))
        .log_to_stderr(false)
        .keep_log()
        .start(&source, "interlock.rhai")
        .unwrap();
    rig.runner.advance(Duration::from_secs(24 * 3600));
    assert_eq!(rig.runner.status(), None, "{}", log(&rig));
    let lines = rig.log();
    assert!(
        lines.len() < 40,
        "{} lines:\n{}",
        lines.len(),
        lines.join("\n")
    );
    assert!(
        !lines
            .iter()
            .any(|l| l.contains("relay ? ->") || l.contains("()")),
        "{}",
        lines.join("\n")
    );
}

/// A `rigscript run` process, killed if it outlives `limit`.
fn wait_for(mut child: Child, limit: Duration) -> (Option<i32>, Duration, Child) {
    let started = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return (status.code(), started.elapsed(), child);
        }
        if started.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            return (None, started.elapsed(), child);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn a_script_that_grows_memory_without_end_is_stopped_at_its_line() {
    let dir = TempDir::new("memory-limit");
    let script = dir.join("grow.rhai");
    // The reproducer: every timer holds a 60 KB string.
    std::fs::write(
        &script,
        "let base = \"x\";\nbase.pad(60000, \"x\");\nlet k = 0;\n\
         io.outputs = 0x0F;\n\
         every(\"100ms\", || {\n  for i in 0..1000 {\n    k += 1;\n    let t = base + k;\n    \
         after(\"1h\", || t.len());\n  }\n});\n",
    )
    .unwrap();
    let out: Output = Command::new(rigscript())
        .args(["run", "--sim", "--for", "60s", "--memory-limit", "64MiB"])
        .arg(&script)
        .output()
        .unwrap();
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    let line = err
        .lines()
        .find(|l| l.contains("over its limit of 64 MiB"))
        .unwrap_or_else(|| panic!("no memory error: {err}"));
    assert!(line.contains("grow.rhai:"), "{line}");
    assert!(
        line.contains("in every 100ms: the run's memory reached"),
        "{line}"
    );
    assert!(line.contains("--memory-limit"), "{line}");
    assert!(
        err.contains("safe state (script error): io outputs 0x00"),
        "{err}"
    );
}

/// `rigscript run --sim --stats ARGS..` of a script that prints 600 KB of log a second, with
/// stdout and stderr piped and nobody reading them; its directory and the process.
fn chatty_run(tag: &str, args: &[&str]) -> (TempDir, Child) {
    let dir = TempDir::new(tag);
    let script = dir.join("chatty.rhai");
    std::fs::write(
        &script,
        "let dashes = \"-\";\ndashes.pad(200, \"-\");\nevery(\"20ms\", || {\n  for i in 0..50 {\n    \
         print(\"a long line of chatter \" + i + \" \" + dashes);\n  }\n  \
         io.outputs = io.outputs ^ 1;\n});\n",
    )
    .unwrap();
    let child = Command::new(rigscript())
        .args(["run", "--sim", "--stats"])
        .args(args)
        .arg(&script)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    (dir, child)
}

/// What an ended run printed on stdout (`--stats`).
fn stdout_of(child: &mut Child) -> String {
    let mut out = String::new();
    child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut out)
        .unwrap();
    out
}

#[test]
fn a_stderr_nobody_reads_does_not_stall_the_run_and_the_drops_are_counted() {
    let (_dir, child) = chatty_run("log-pipe", &["--for", "3s"]);
    let (status, took, mut child) = wait_for(child, Duration::from_secs(60));
    assert_eq!(
        status,
        Some(0),
        "the run did not end by itself (took {took:?})"
    );
    let stats = stdout_of(&mut child);
    let dropped = stats
        .lines()
        .find_map(|l| l.strip_prefix("log lines dropped: "))
        .unwrap_or_else(|| panic!("no drop count in --stats: {stats}"));
    assert!(dropped.ends_with("(stderr not being read)"), "{dropped}");
    let n: u64 = dropped.split_whitespace().next().unwrap().parse().unwrap();
    assert!(n > 1000, "{n}");
}

#[test]
fn sigterm_ends_a_run_whose_stderr_nobody_reads() {
    let (_dir, child) = chatty_run("log-pipe-signal", &[]);
    // The 64 KiB pipe is full long before this.
    std::thread::sleep(Duration::from_millis(1500));
    let sent = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap()
        .success();
    assert!(sent);
    let (status, took, mut child) = wait_for(child, Duration::from_secs(60));
    assert_eq!(status, Some(143), "SIGTERM not honoured (waited {took:?})");
    let stats = stdout_of(&mut child);
    assert!(
        stats.lines().any(|l| l.starts_with("log lines dropped: ")),
        "the pipe was full: {stats}"
    );
}

#[test]
fn json_logs_are_one_object_a_line() {
    let dir = TempDir::new("log-json");
    let script = dir.join("j.rhai");
    std::fs::write(&script, "io.outputs = 5;\nprint(\"hi\");\n").unwrap();
    let out = Command::new(rigscript())
        .args(["run", "--sim", "--for", "200ms", "--log-format", "json"])
        .arg(&script)
        .output()
        .unwrap();
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(0), "{err}");
    let lines: Vec<serde_json::Value> = err
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    for l in &lines {
        for key in ["time", "level", "source", "message", "device"] {
            assert!(l.get(key).is_some(), "{key} missing: {l}");
        }
    }
    assert!(lines
        .iter()
        .any(|l| l["source"] == "script" && l["message"] == "hi"));
    assert!(lines
        .iter()
        .any(|l| l["device"] == "io" && l["message"] == "outputs 0x00 -> 0x05 (top level)"));
    let bad = Command::new(rigscript())
        .args(["run", "--sim", "--log-format", "xml"])
        .arg(&script)
        .output()
        .unwrap();
    let err = stderr(&bad);
    assert_eq!(bad.status.code(), Some(2), "{err}");
    assert!(err.contains("[possible values: text, json]"), "{err}");
}

#[test]
fn bad_limit_flags_say_what_is_accepted() {
    for (flag, value, says) in [
        ("--memory-limit", "256", "use \"256MiB\""),
        ("--memory-limit", "1MiB", "at least 16 MiB"),
        ("--handler-time", "0s", "above zero"),
        ("--max-timers", "0", "0"),
        ("--budget", "0", "0"),
    ] {
        let out = Command::new(rigscript())
            .args(["run", "--sim", flag, value, "x.rhai"])
            .output()
            .unwrap();
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(2), "{flag} {value}: {err}");
        assert!(err.contains(says), "{flag} {value}: {err}");
    }
}

#[test]
fn json_format_is_a_library_setting_too() {
    let mut rig = RigBuilder::new()
        .c29u("io", C29uConfig::with_defaults(Port::Simulated))
        .simulated()
        .virtual_time_from("2026-03-28T00:00:30Z".parse().unwrap())
        .log_to_stderr(false)
        .log_format(LogFormat::Json)
        .keep_log()
        .start("io.outputs = 1;\nevery(\"1s\", || 1);", "t.rhai")
        .unwrap();
    rig.runner.advance(Duration::from_millis(100));
    // The kept lines stay text (scenario tests read them); JSON is what goes out.
    assert!(log(&rig).contains("io: outputs 0x00 -> 0x01 (top level)"));
}

/// The memory limit of the runs that share a process below.
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

/// The default limits with a memory limit of `bytes`.
fn limit(bytes: u64) -> ScriptLimits {
    ScriptLimits {
        memory: bytes,
        ..ScriptLimits::default()
    }
}

#[test]
fn a_run_that_grows_past_its_limit_stops_alone_and_its_neighbour_runs_on() {
    let (small_started, small_is_started) = mpsc::channel();
    let (grower_stopped, grower_is_stopped) = mpsc::channel();
    let (small_done, small_is_done) = mpsc::channel::<()>();
    let small = thread::spawn(move || {
        let mut rig = start(SMALL, limit(LIMIT));
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
        let mut rig = start(GROWS, limit(LIMIT));
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
    assert!(line.contains("t.rhai:"), "{line}");
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
    let mut rig = start(source, limit(LIMIT));
    rig.runner.advance(Duration::from_secs(1));
    let held = heap::thread_balance() - before;
    assert!(held > 5 << 20, "held {held}");
    drop(rig);
    let kept = heap::thread_balance() - before;
    assert!(kept < 1 << 20, "kept {kept} of {held} bytes after the run");
}
