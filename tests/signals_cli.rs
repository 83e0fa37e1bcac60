//! `rigscript run` as a real process against signals and closed outputs: every ending signal is
//! an orderly stop (on_stop, the safe state, 128 + the signal, the signal and its likely cause
//! named); a signal during the start is honoured at once, even with a silent module; a closed
//! stdout or stderr never kills the run; a script nested deep enough to overflow the stack is a
//! script error, not an abort; a loop thread that stops (frozen alone with ptrace) ends a run
//! without a guardian, and `rigscript test`, by their own watch instead of a hang.

use crate::common;

use crate::common::{both, kill, rigscript, stderr, wait_at_most, SimProcess, TempDir};
use std::io::{BufRead, BufReader, Read};
use std::os::fd::{FromRawFd, OwnedFd};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Reads `child`'s stderr line by line until a line contains `marker` (or it ends); the text so
/// far. The rest stays in the reader.
fn read_until(err: &mut impl BufRead, marker: &str) -> String {
    let mut log = String::new();
    while !log.contains(marker) {
        let mut line = String::new();
        if err.read_line(&mut line).unwrap_or(0) == 0 {
            break;
        }
        log.push_str(&line);
    }
    log
}

#[test]
fn every_ending_signal_is_an_orderly_stop_with_128_plus_the_signal() {
    let dir = TempDir::new("ending-signals");
    let script = dir.file(
        "work.rhai",
        "io.outputs = 0xF0;\non_stop(|| log(\"on_stop ran\"));\nevery(\"50ms\", || ());\n\
         after(\"100ms\", || log(\"ready\"));\n",
    );
    for (signal, status, name, cause) in [
        ("-HUP", 129, "SIGHUP", "SSH session"),
        ("-QUIT", 131, "SIGQUIT", "Ctrl-\\"),
        ("-USR1", 138, "SIGUSR1", "another program"),
        ("-USR2", 140, "SIGUSR2", "another program"),
        ("-ALRM", 142, "SIGALRM", "timer"),
        ("-XFSZ", 153, "SIGXFSZ", "RLIMIT_FSIZE"),
    ] {
        let mut child = Command::new(rigscript())
            .args(["run", "--sim", &script])
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let mut err = BufReader::new(child.stderr.take().unwrap());
        let mut log = read_until(&mut err, "script: ready");
        kill(child.id(), signal);
        let ended = wait_at_most(&mut child, Duration::from_secs(10));
        err.read_to_string(&mut log).unwrap();
        assert_eq!(ended.and_then(|s| s.code()), Some(status), "{name}: {log}");
        assert!(
            log.contains(&format!("stopping: {name} received (")) && log.contains(cause),
            "{name}: {log}"
        );
        assert!(log.contains("on_stop ran"), "{name}: {log}");
        assert!(
            log.contains("safe state (signal): io outputs 0x00"),
            "{name}: {log}"
        );
        assert!(
            log.contains(&format!("exit status {status}")),
            "{name}: {log}"
        );
    }
}

/// A pipe whose reading end is closed: writing to the other end fails with EPIPE.
fn broken_pipe() -> OwnedFd {
    let mut fds = [0; 2];
    // SAFETY: pipe fills two fresh descriptors, each owned once below.
    assert_eq!(unsafe { libc::pipe(fds.as_mut_ptr()) }, 0);
    // SAFETY: both are open and owned by nobody else.
    let (read, write) = unsafe { (OwnedFd::from_raw_fd(fds[0]), OwnedFd::from_raw_fd(fds[1])) };
    drop(read);
    write
}

#[test]
fn a_closed_stdout_or_stderr_never_kills_the_run() {
    let dir = TempDir::new("closed-outputs");
    let script = dir.file(
        "work.rhai",
        "io.outputs = 0xF0;\nevery(\"20ms\", || log(\"tick\"));\n",
    );
    // Errors before the run: said on a stderr nobody reads, with the status they call for.
    let o = Command::new(rigscript())
        .args([
            "run",
            "--config",
            &dir.path("missing.toml").display().to_string(),
        ])
        .arg(&script)
        .stderr(Stdio::from(broken_pipe()))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "no panic on a broken stderr");
    // A whole run with both closed: it ends as planned, --stats and all.
    let mut child = Command::new(rigscript())
        .args(["run", "--sim", "--for", "500ms", "--stats", &script])
        .stdout(Stdio::from(broken_pipe()))
        .stderr(Stdio::from(broken_pipe()))
        .spawn()
        .unwrap();
    let ended = wait_at_most(&mut child, Duration::from_secs(20));
    assert_eq!(ended.and_then(|s| s.code()), Some(0));
}

#[test]
fn a_signal_during_the_start_is_honoured_at_once_with_a_silent_module() {
    // The module answers ID 1 only; rig.toml asks ID 2, with 1 s timeouts and 10 retries: the
    // start's first exchange alone would take 21 s to fail.
    let sim = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let dir = TempDir::new("start-signal");
    let config = dir.file(
        "rig.toml",
        &format!(
            "[devices.io]\nkind = \"trp-c29u\"\nport = \"{}\"\nid = 2\ntimeout = \"1s\"\n\
             retries = 10\n",
            sim.path
        ),
    );
    let script = dir.file("work.rhai", "every(\"1s\", || ());\n");
    for (signal, status, name) in [("-TERM", 143, "SIGTERM"), ("-INT", 130, "SIGINT")] {
        let mut child = Command::new(rigscript())
            .args(["run", "--config", &config, &script])
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // Once the runner catches the signal, and a little into the first exchange.
        let started = Instant::now();
        while !catches(child.id(), libc::SIGTERM) && started.elapsed() < Duration::from_secs(10) {
            std::thread::sleep(Duration::from_millis(10));
        }
        std::thread::sleep(Duration::from_millis(300));
        kill(child.id(), signal);
        // Honoured within a cancel slice plus the end's writes; the exchange it cut would have
        // gone on for 20 s more.
        let ended = wait_at_most(&mut child, Duration::from_secs(10));
        let mut log = String::new();
        child
            .stderr
            .take()
            .unwrap()
            .read_to_string(&mut log)
            .unwrap();
        assert_eq!(ended.and_then(|s| s.code()), Some(status), "{name}: {log}");
        assert!(
            log.contains(&format!("stopping during the start: {name} received")),
            "{name}: {log}"
        );
        assert!(
            log.contains(&format!("stopped during the start by {name}")),
            "{log}"
        );
        // Not the end's tries either: the start wrote it nothing.
        assert!(
            log.contains("io: not under control yet: left as it is"),
            "{log}"
        );
        assert!(!log.contains("the safe state did not reach it"), "{log}");
    }
}

/// Whether process `pid` has a handler for `signal` (its SigCgt mask in /proc).
fn catches(pid: u32, signal: i32) -> bool {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("SigCgt:"))
        .and_then(|mask| u64::from_str_radix(mask.trim(), 16).ok())
        .is_some_and(|mask| mask & (1 << (signal - 1)) != 0)
}

/// Closures nested 50,000 deep inside an `after` handler: calling the chain nests too deep,
/// and dropping it (even uncalled) recurses once per link.
const DEEP: &str = "after(\"10ms\", || {\n  let f = || 0;\n  for i in 0..50000 { let g = f; f = || g.call() + 1; }\n  log(\"built\");\n  log(`${f.call()}`);\n});\n";
const DEEP_UNCALLED: &str = "after(\"10ms\", || {\n  let f = || 0;\n  for i in 0..50000 { let g = f; f = || g.call() + 1; }\n  log(\"built\");\n});\n";

#[test]
fn a_script_nested_deep_enough_to_overflow_the_stack_is_a_script_error_in_run_test_and_verify() {
    let dir = TempDir::new("deep-nesting");
    let deep = dir.file("deep.rhai", DEEP);
    let uncalled = dir.file("uncalled.rhai", DEEP_UNCALLED);
    // Generous time per call: building the chain is slow in a debug build on a busy machine.
    let run = |script: &str| {
        Command::new(rigscript())
            .args([
                "run",
                "--sim",
                "--for",
                "1s",
                "--handler-time",
                "60s",
                script,
            ])
            .output()
            .unwrap()
    };
    let o = run(&deep);
    let log = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{log}");
    assert!(
        log.contains("deep.rhai:3:") && log.contains("nested more than 48 deep"),
        "{log}"
    );
    assert!(log.contains("safe state (script error)"), "{log}");
    let o = run(&uncalled);
    let log = stderr(&o);
    assert_eq!(o.status.code(), Some(0), "{log}");
    assert!(log.contains("built"), "{log}");
    // The same scripts in a scenario test and under verify.
    let tests = dir.file(
        "deep.test.rhai",
        "fn test_deep() {\n  let r = rig(\"deep.rhai\");\n  r.expect_errors();\n  r.advance(\"100ms\");\n  \
         assert_eq(r.exit_status(), 1);\n}\nfn test_uncalled() {\n  let r = rig(\"uncalled.rhai\");\n  \
         r.advance(\"100ms\");\n}\n",
    );
    let o = Command::new(rigscript())
        .args(["test", &tests])
        .output()
        .unwrap();
    let out = both(&o);
    assert_eq!(o.status.code(), Some(0), "{out}");
    assert!(out.contains("2 passed, 0 failed"), "{out}");
    let o = Command::new(rigscript())
        .args([
            "verify",
            &uncalled,
            "--runs",
            "4",
            "--for",
            "1s",
            "--seed",
            "1",
            "--no-faults",
        ])
        .output()
        .unwrap();
    let out = both(&o);
    assert_eq!(o.status.code(), Some(0), "{out}");
    assert!(out.contains("no counterexample in 4 runs"), "{out}");
}

/// 100 `on_stop` handlers that loop, each allowed a minute and a billion operations: a stop
/// that ran them all would take an hour and more.
const LOOPING_STOPS: &str = "io.outputs = 0xF0;\nfor i in 0..100 { on_stop(|| { log(\"on_stop under way\"); loop { } }); }\n\
    every(\"50ms\", || ());\nafter(\"100ms\", || log(\"ready\"));\n";

/// Starts `run --sim` of `script` with generous limits per call, waits for `ready`.
fn started_with_looping_stops(
    script: &str,
) -> (Child, BufReader<std::process::ChildStderr>, String) {
    let mut child = Command::new(rigscript())
        .args([
            "run",
            "--sim",
            "--budget",
            "1000000000",
            "--handler-time",
            "60s",
            script,
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let log = read_until(&mut err, "script: ready");
    (child, err, log)
}

#[test]
fn a_stop_is_bounded_however_its_on_stop_handlers_behave() {
    let dir = TempDir::new("bounded-stop");
    let script = dir.file("loops.rhai", LOOPING_STOPS);
    let (mut child, mut err, mut log) = started_with_looping_stops(&script);
    kill(child.id(), "-TERM");
    let ended = wait_at_most(&mut child, Duration::from_secs(15));
    err.read_to_string(&mut log).unwrap();
    // The handler that ran out of the budget failed, and the 99 it left: exit 5.
    assert_eq!(ended.and_then(|s| s.code()), Some(5), "{log}");
    assert!(log.contains("ran past the 2s they have together"), "{log}");
    assert!(
        log.contains("99 on_stop handler(s) skipped, straight to the safe state"),
        "{log}"
    );
    assert!(
        log.contains("safe state (signal): io outputs 0x00"),
        "{log}"
    );
    // One more than the limit is a script error where it is registered.
    let many = dir.file("many.rhai", "for i in 0..101 {\n  on_stop(|| ());\n}\n");
    let o = Command::new(rigscript())
        .args(["run", "--sim", &many])
        .output()
        .unwrap();
    let log = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{log}");
    assert!(
        log.contains("many.rhai:2:") && log.contains("too many on_stop handlers (at most 100"),
        "{log}"
    );
}

#[test]
fn a_second_signal_while_stopping_goes_straight_to_the_safe_state() {
    let dir = TempDir::new("second-signal");
    let script = dir.file("loops.rhai", LOOPING_STOPS);
    let (mut child, mut err, mut log) = started_with_looping_stops(&script);
    kill(child.id(), "-TERM");
    // Once the first on_stop handler runs: a signal before it would skip all 100 (also right,
    // but not what this test is about).
    log.push_str(&read_until(&mut err, "on_stop under way"));
    kill(child.id(), "-INT");
    let ended = wait_at_most(&mut child, Duration::from_secs(15));
    err.read_to_string(&mut log).unwrap();
    // Stopped by the first signal; the second only cut the stop short.
    assert_eq!(ended.and_then(|s| s.code()), Some(143), "{log}");
    let cut = log.find("on_stop: cut off by SIGINT while stopping");
    let skipped = log.find("SIGINT received while stopping: 99 on_stop handler(s) skipped");
    let safe = log.find("safe state (signal): io outputs 0x00");
    assert!(
        cut.is_some() && cut < skipped && skipped < safe,
        "the handler under way cut, the rest skipped, then the safe state: {log}"
    );
    assert!(
        !log.contains("ran past the 2s"),
        "before the budget ran out: {log}"
    );
}

#[test]
fn a_run_in_a_background_process_group_is_not_stopped_by_its_own_log_writes() {
    common::require_tool("setsid", "util-linux");
    common::require_tool("stty", "coreutils");
    let dir = TempDir::new("background-tostop");
    let script = dir.file(
        "work.rhai",
        "every(\"50ms\", || ());\nafter(\"100ms\", || log(\"ready\"));\n",
    );
    // The run as a background job (its own process group) writing its log to a terminal with
    // `tostop`: SIGTTOU for each write unless ignored.
    let out = on_a_terminal(&format!(
        "stty tostop; set -m; '{}' run --sim --for 1s '{script}' & wait $!; echo status=$?",
        rigscript()
    ));
    assert!(
        out.contains("status=0"),
        "the job was stopped (150: SIGTTOU): {out}"
    );
    assert!(
        out.contains("script: ready") && out.contains("stopping: ran for 1s"),
        "{out}"
    );
    // In the foreground with a real device: the runner behind its guardian has a process
    // group of its own, in the background of the terminal.
    let sim = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let config = dir.file(
        "rig.toml",
        &format!(
            "[devices.io]\nkind = \"trp-c29u\"\nport = \"{}\"\nid = 1\n",
            sim.path
        ),
    );
    let out = on_a_terminal(&format!(
        "stty tostop; '{}' run --config '{config}' --for 1s '{script}'; echo status=$?",
        rigscript()
    ));
    assert!(out.contains("status=0"), "{out}");
    assert!(
        out.contains("safe state (end of run): io outputs 0x00"),
        "{out}"
    );
}

/// Runs `shell` (sh) in a session of its own on a new terminal; what the terminal showed, up
/// to `status=` or 15 s.
fn on_a_terminal(shell: &str) -> String {
    let (mut master, slave) = pty_pair();
    let mut session = Command::new("setsid")
        .args(["-c", "sh", "-c", shell])
        .stdin(Stdio::from(slave.try_clone().unwrap()))
        .stdout(Stdio::from(slave.try_clone().unwrap()))
        .stderr(Stdio::from(slave))
        .spawn()
        .unwrap();
    let (chunks, text) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut buf = [0u8; 4096];
        // Ends with EIO once every process on the terminal has gone.
        while let Ok(n) = master.read(&mut buf) {
            if n == 0 || chunks.send(buf[..n].to_vec()).is_err() {
                break;
            }
        }
    });
    let mut out = String::new();
    let started = Instant::now();
    while !out.contains("status=") && started.elapsed() < Duration::from_secs(15) {
        if let Ok(chunk) = text.recv_timeout(Duration::from_millis(100)) {
            out.push_str(&String::from_utf8_lossy(&chunk));
        }
    }
    let _ = wait_at_most(&mut session, Duration::from_secs(5));
    out
}

/// A new pseudo-terminal: its master (for reading what is written to the terminal) and its
/// slave (the terminal itself).
fn pty_pair() -> (std::fs::File, OwnedFd) {
    let (mut master, mut slave) = (0, 0);
    // SAFETY: openpty fills two fresh descriptors, each owned once below; the name, termios
    // and window size are not asked for.
    let done = unsafe {
        libc::openpty(
            &mut master,
            &mut slave,
            std::ptr::null_mut(),
            std::ptr::null(),
            std::ptr::null(),
        )
    };
    assert_eq!(done, 0, "openpty: {}", std::io::Error::last_os_error());
    // SAFETY: both are open and owned by nobody else.
    unsafe {
        (
            std::fs::File::from(OwnedFd::from_raw_fd(master)),
            OwnedFd::from_raw_fd(slave),
        )
    }
}

#[test]
fn a_records_file_past_the_file_size_limit_ends_the_run_in_order_naming_sigxfsz() {
    let dir = TempDir::new("xfsz");
    let script = dir.file(
        "work.rhai",
        "io.outputs = 0xF0;\nevery(\"20ms\", || record(\"x\", \"a line of some length, again and again\"));\n",
    );
    let records = dir.path("records.jsonl").display().to_string();
    // 1 block of 512 bytes (dash's unit): a dozen records.
    let mut child = Command::new("sh")
        .arg("-c")
        .arg(format!(
            "ulimit -f 1; exec '{}' run --sim --records '{records}' '{script}'",
            rigscript()
        ))
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let ended = wait_at_most(&mut child, Duration::from_secs(15));
    let mut log = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut log)
        .unwrap();
    // 128 + SIGXFSZ would be 153; the records it cost are something that failed on the way,
    // which comes first (exit 5).
    assert_eq!(ended.and_then(|s| s.code()), Some(5), "{log}");
    assert!(log.contains("records not written"), "{log}");
    assert!(
        log.contains("stopping: SIGXFSZ received (") && log.contains("the records file?"),
        "{log}"
    );
    assert!(
        log.contains("safe state (signal): io outputs 0x00"),
        "{log}"
    );
}

/// The thread of process `pid` named `name` (as /proc shows it, cut to 15 bytes).
fn thread_named(pid: u32, name: &str) -> i32 {
    let started = Instant::now();
    loop {
        for task in std::fs::read_dir(format!("/proc/{pid}/task")).unwrap() {
            let task = task.unwrap().path();
            let comm = std::fs::read_to_string(task.join("comm")).unwrap_or_default();
            if comm.trim() == name {
                return task.file_name().unwrap().to_str().unwrap().parse().unwrap();
            }
        }
        assert!(
            started.elapsed() < Duration::from_secs(10),
            "no thread {name}"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Stops thread `tid` alone, as a loop stuck in one operation stops, while the rest of its
/// process goes on (ptrace: this test process is its tracer until the process ends).
fn freeze_thread(tid: i32) {
    // SAFETY: plain ptrace requests on a thread of a child of this process; nothing is read
    // or written in it.
    unsafe {
        assert_eq!(
            libc::ptrace(libc::PTRACE_SEIZE, tid, 0usize, 0usize),
            0,
            "PTRACE_SEIZE: {}",
            std::io::Error::last_os_error()
        );
        assert_eq!(
            libc::ptrace(libc::PTRACE_INTERRUPT, tid, 0usize, 0usize),
            0,
            "PTRACE_INTERRUPT: {}",
            std::io::Error::last_os_error()
        );
    }
}

/// Waits for `child`, one of whose threads (`tid`) this process traces (`freeze_thread`): the
/// traced thread's end must be collected too (`__WALL`) before the process can be.
fn wait_traced(child: &mut Child, tid: i32, limit: Duration) -> Option<std::process::ExitStatus> {
    let started = Instant::now();
    while started.elapsed() < limit {
        let mut status = 0;
        // SAFETY: collects a state change of a thread this process traces, into a local.
        unsafe { libc::waitpid(tid, &mut status, libc::WNOHANG | libc::__WALL) };
        if let Ok(Some(status)) = child.try_wait() {
            return Some(status);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = child.kill();
    // SAFETY: as above, waiting this time.
    unsafe { libc::waitpid(tid, std::ptr::null_mut(), libc::__WALL) };
    let _ = child.wait();
    None
}

/// A handler that works for seconds within its (raised) limits, saying so first.
const BUSY: &str =
    "after(500, || {\n  log(\"busy\");\n  let x = 0;\n  for i in 0..1000000000 { x += 1; }\n});\n";

#[test]
fn a_run_without_a_guardian_whose_loop_stops_is_ended_by_its_own_watch_naming_the_handler() {
    // Only simulated devices: no guardian process; a thread of the run watches its loop.
    let dir = TempDir::new("lone-stall");
    let config = dir.file(
        "rig.toml",
        "stall = \"1s\"\n[limits]\noperations = 1000000000\nhandler_time = \"60s\"\n\
         [devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/null\"\nsim = true\n",
    );
    let script = dir.file("busy.rhai", BUSY);
    let mut child = Command::new(rigscript())
        .args(["run", "--config", &config, &script])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let mut log = read_until(&mut err, "script: busy");
    let tid = thread_named(child.id(), "rigscript-scrip");
    freeze_thread(tid);
    let ended = wait_traced(&mut child, tid, Duration::from_secs(60));
    err.read_to_string(&mut log).unwrap();
    assert_eq!(ended.and_then(|s| s.code()), Some(6), "{log}");
    assert!(
        log.contains("the scan loop stalled for 1.0 s (in handler `after 500ms`)")
            && log.contains("the simulated devices end with it"),
        "{log}"
    );
}

#[test]
fn a_scenario_test_whose_loop_stops_ends_with_an_error_instead_of_hanging() {
    let dir = TempDir::new("test-stall");
    dir.file(
        "busy.rhai",
        "every(\"500ms\", || { let x = 0; for i in 0..200000 { x += 1; } });\n",
    );
    let tests = dir.file(
        "busy.test.rhai",
        "fn test_busy() {\n  let r = rig(\"busy.rhai\");\n  for i in 0..100000 { r.advance(\"1s\"); }\n}\n",
    );
    let mut child = Command::new(rigscript())
        .args(["test", &tests])
        .current_dir(dir.path(""))
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(500));
    let tid = thread_named(child.id(), "rigscript-scrip");
    freeze_thread(tid);
    let ended = wait_traced(&mut child, tid, Duration::from_secs(60));
    let mut log = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut log)
        .unwrap();
    assert_eq!(ended.and_then(|s| s.code()), Some(1), "{log}");
    assert!(
        log.contains("rigscript test: the scan loop stalled for")
            && log.contains("(in ")
            && log.contains("ended, as `run` would be"),
        "{log}"
    );
}
