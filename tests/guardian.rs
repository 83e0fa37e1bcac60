//! The guardian against real processes and the TRP-C29U simulator on a real pty: whatever kills
//! the runner (kill -9, a crash, a stuck loop), the guardian writes the safe state and reads it
//! back; killing the pid that was started stops the runner in order; a clean end needs nothing
//! of it. `rigscript safe` writes and confirms the safe state by hand.

use crate::common;

use crate::common::{kill, rigscript, stderr, stdout, SimProcess, TempDir};
use std::io::Read;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The script most tests run: it drives the outputs and goes on ticking.
const WORK: &str = "io.outputs = 0x0F;\nevery(\"100ms\", || {});\n";

/// A handler that works for seconds within its (raised) limits, saying so first.
const BUSY: &str =
    "after(500, || {\n  log(\"busy\");\n  let x = 0;\n  for i in 0..1000000000 { x += 1; }\n});\n";

/// A module without a host watchdog: only the runner, or its guardian, can make it safe.
fn rig(sim: &SimProcess, dir: &TempDir) -> (String, String) {
    rig_with(sim, dir, "", WORK)
}

/// `rig` with more top-level keys in rig.toml and another script.
fn rig_with(sim: &SimProcess, dir: &TempDir, keys: &str, script: &str) -> (String, String) {
    let config = dir.file(
        "rig.toml",
        &format!(
            "period = \"20ms\"\n{keys}[devices.io]\nkind = \"trp-c29u\"\nport = \"{}\"\nsafe_value = 0x00\n",
            sim.path
        ),
    );
    let script = dir.file("work.rhai", script);
    (config, script)
}

/// `rigscript run --config CONFIG SCRIPT`, leaving no core file when the test makes it crash.
fn start_run(config: &str, script: &str) -> Child {
    use std::os::unix::process::CommandExt;
    let mut command = common::run_command(&["--config", config, script]);
    // SAFETY: setrlimit is async-signal-safe; a crash the test causes leaves no core file.
    unsafe {
        command.pre_exec(|| {
            let none = libc::rlimit {
                rlim_cur: 0,
                rlim_max: 0,
            };
            libc::setrlimit(libc::RLIMIT_CORE, &none);
            Ok(())
        });
    }
    command.spawn().expect("start rigscript run")
}

/// The runner: the one child of the guardian (the pid that was started).
fn runner_of(guardian: &Child) -> i32 {
    let path = format!("/proc/{0}/task/{0}/children", guardian.id());
    let start = Instant::now();
    loop {
        let text = std::fs::read_to_string(&path).unwrap_or_default();
        if let Some(pid) = text.split_whitespace().next() {
            return pid.parse().unwrap();
        }
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "no runner under the guardian"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Waits for the guardian to exit (killing it after a minute: a test must not hang); its
/// status and what it wrote on stderr.
fn finish(mut run: Child) -> (Option<i32>, String) {
    let status = common::wait_at_most(&mut run, Duration::from_secs(60));
    (status.and_then(|s| s.code()), common::read_stderr(&mut run))
}

/// Starts a run and waits until the script drives the module.
fn driven(tag: &str) -> (SimProcess, TempDir, Child) {
    let mut sim = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let dir = TempDir::new(tag);
    let (config, script) = rig(&sim, &dir);
    let run = start_run(&config, &script);
    let s = sim.wait_for(Duration::from_secs(10), |s| s["do"] == 0x0F);
    assert_eq!(s["do"], 0x0F, "the script drives the module: {s}");
    (sim, dir, run)
}

#[test]
fn a_runner_killed_with_sigkill_is_made_safe_by_its_guardian() {
    let (mut sim, _dir, run) = driven("guardian-kill");
    kill(runner_of(&run), "-KILL");
    let (status, err) = finish(run);
    assert_eq!(
        status,
        Some(137),
        "128 + SIGKILL, as a shell reports it: {err}"
    );
    assert_eq!(sim.state()["do"], 0x00, "{err}");
    assert!(
        err.contains("was killed by SIGKILL") && err.contains("before it confirmed the safe state"),
        "{err}"
    );
    assert!(
        err.contains("guardian: safe state (the runner died): io outputs 0x00 (read back)"),
        "{err}"
    );
}

#[test]
fn a_runner_that_crashes_is_made_safe_by_its_guardian() {
    // SIGILL as a crash in a C library would raise it (Rust's own SIGSEGV handler lets a
    // SIGSEGV sent by kill pass, as it did not come from a fault).
    let (mut sim, _dir, run) = driven("guardian-crash");
    kill(runner_of(&run), "-ILL");
    let (status, err) = finish(run);
    assert_eq!(status, Some(132), "128 + SIGILL: {err}");
    assert_eq!(sim.state()["do"], 0x00, "{err}");
    assert!(err.contains("crashed (SIGILL"), "{err}");
}

#[test]
fn a_stuck_runner_is_killed_and_made_safe_on_sigabrt() {
    // What systemd's service watchdog sends when the loop stopped turning.
    let (mut sim, _dir, run) = driven("guardian-stuck");
    let runner = runner_of(&run);
    kill(runner, "-STOP");
    kill(run.id(), "-ABRT");
    let (status, err) = finish(run);
    assert_eq!(status, Some(6), "told as a stall: {err}");
    assert_eq!(sim.state()["do"], 0x00, "{err}");
    assert!(
        err.contains("the scan loop stalled for")
            && err.contains("systemd's watchdog ended it (SIGABRT)")
            && !err.contains("SIGKILL"),
        "{err}"
    );
}

#[test]
fn a_runner_aborted_by_sigabrt_while_its_loop_was_silent_is_told_as_the_watchdog() {
    // systemd's watchdog may reach the runner itself (a unit whose KillMode signals the whole
    // group): its loop had been silent since it was stopped.
    let mut sim = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let dir = TempDir::new("guardian-abrt-runner");
    let (config, script) = rig_with(&sim, &dir, "stall = \"30s\"\n", WORK);
    let run = start_run(&config, &script);
    let s = sim.wait_for(Duration::from_secs(10), |s| s["do"] == 0x0F);
    assert_eq!(s["do"], 0x0F, "the script drives the module: {s}");
    let runner = runner_of(&run);
    kill(runner, "-STOP");
    std::thread::sleep(Duration::from_millis(1500));
    kill(runner, "-ABRT");
    kill(runner, "-CONT");
    let (status, err) = finish(run);
    assert_eq!(status, Some(6), "told as a stall: {err}");
    assert_eq!(sim.state()["do"], 0x00, "{err}");
    assert!(
        err.contains("the scan loop stalled for 1.")
            && err.contains("systemd's watchdog ended it (SIGABRT)"),
        "{err}"
    );
}

#[test]
fn a_loop_stuck_in_a_handler_is_ended_by_the_guardian_within_its_stall_limit() {
    // The runner is frozen in the middle of a long handler: its loop stops as it would inside
    // one script operation that never returns (no tick, no exchange, no operation counted).
    let mut sim = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let dir = TempDir::new("guardian-stall");
    let config = dir.file(
        "rig.toml",
        &format!(
            "period = \"20ms\"\nstall = \"1s\"\n[limits]\noperations = 1000000000\n\
             handler_time = \"60s\"\n[devices.io]\nkind = \"trp-c29u\"\nport = \"{}\"\n\
             safe_value = 0x00\n",
            sim.path
        ),
    );
    let script = dir.file("work.rhai", &format!("io.outputs = 0x0F;\n{BUSY}"));
    let mut run = start_run(&config, &script);
    let mut err = std::io::BufReader::new(run.stderr.take().unwrap());
    let mut log = String::new();
    while !log.contains("script: busy") {
        let mut line = String::new();
        if std::io::BufRead::read_line(&mut err, &mut line).unwrap_or(0) == 0 {
            break;
        }
        log.push_str(&line);
    }
    assert_eq!(
        sim.state()["do"],
        0x0F,
        "the script drives the module: {log}"
    );
    kill(runner_of(&run), "-STOP");
    let started = Instant::now();
    let status = loop {
        if let Some(status) = run.try_wait().unwrap() {
            break status.code();
        }
        if started.elapsed() > Duration::from_secs(60) {
            let _ = run.kill();
            break None;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    err.read_to_string(&mut log).unwrap();
    assert_eq!(status, Some(6), "{log}");
    assert_eq!(sim.state()["do"], 0x00, "{log}");
    assert!(
        log.contains("the scan loop stalled for 1.0 s (in handler `after 500ms`)")
            && log.contains("safe state (the runner died): io outputs 0x00 (read back)"),
        "{log}"
    );
}

#[test]
fn sigxfsz_to_the_pid_that_was_started_is_passed_on_as_an_orderly_stop() {
    let (mut sim, _dir, run) = driven("guardian-xfsz");
    kill(run.id(), "-XFSZ");
    let (status, err) = finish(run);
    assert_eq!(status, Some(153), "128 + SIGXFSZ: {err}");
    assert_eq!(sim.state()["do"], 0x00, "{err}");
    assert!(err.contains("stopping: SIGXFSZ received"), "{err}");
}

#[test]
fn a_healthy_loop_slower_than_its_stall_limit_is_never_ended() {
    // A period three times the limit, at 9600 baud, every exchange retried once: the loop
    // waits and exchanges for longer than `stall` at a time, and shows it is alive meanwhile.
    let mut sim = SimProcess::start(&["--protocol", "modbus", "--id", "1", "--baud", "9600"]);
    let dir = TempDir::new("guardian-slow");
    let config = dir.file(
        "rig.toml",
        &format!(
            "period = \"3s\"\nstall = \"1s\"\n[devices.io]\nkind = \"trp-c29u\"\n\
             port = \"{}\"\nbaud = 9600\ntimeout = \"1s\"\nretries = 1\nsafe_value = 0x00\n",
            sim.path
        ),
    );
    let script = dir.file(
        "slow.rhai",
        "io.outputs = 0x0F;\nevery(\"3s\", || { for i in 0..20 { let x = io.inputs; } });\n",
    );
    let run = common::start_run(&["--config", &config, &script, "--for", "7s"]);
    let (status, err) = finish(run);
    assert_eq!(status, Some(0), "{err}");
    assert!(!err.contains("stalled"), "{err}");
    assert_eq!(sim.state()["do"], 0x00, "{err}");
}

#[test]
fn kill_9_of_the_pid_that_was_started_stops_the_runner_in_order() {
    let (mut sim, _dir, mut run) = driven("guardian-gone");
    let runner = runner_of(&run);
    run.kill().unwrap();
    run.wait().unwrap();
    let s = sim.wait_for(Duration::from_secs(10), |s| s["do"] == 0x00);
    assert_eq!(s["do"], 0x00, "the runner wrote its safe state: {s}");
    let start = Instant::now();
    while std::path::Path::new(&format!("/proc/{runner}")).exists() {
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "the runner outlived its guardian"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn a_signal_to_the_pid_that_was_started_is_an_orderly_stop_the_guardian_does_not_repeat() {
    let (mut sim, _dir, run) = driven("guardian-term");
    kill(run.id(), "-TERM");
    let (status, err) = finish(run);
    assert_eq!(status, Some(143), "the runner's own status: {err}");
    assert_eq!(sim.state()["do"], 0x00, "{err}");
    assert!(err.contains("stopping: SIGTERM received"), "{err}");
    assert!(
        err.contains("safe state (signal): io outputs 0x00"),
        "{err}"
    );
    assert!(
        !err.contains("guardian"),
        "nothing for the guardian to do: {err}"
    );
}

#[test]
fn safe_writes_and_reads_back_the_safe_state_by_hand() {
    let mut sim = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let dir = TempDir::new("safe-cmd");
    let (config, _) = rig(&sim, &dir);
    let set = Command::new(rigscript())
        .args(["c29", "--port", &sim.path, "do", "0x0f"])
        .output()
        .unwrap();
    assert!(set.status.success(), "{set:?}");
    assert_eq!(sim.state()["do"], 0x0F);
    let out = Command::new(rigscript())
        .args(["safe", "--config", &config])
        .output()
        .unwrap();
    let stdout = stdout(&out);
    assert_eq!(out.status.code(), Some(0), "{out:?}");
    assert_eq!(stdout.trim(), "io outputs 0x00 (read back)");
    assert_eq!(sim.state()["do"], 0x00);
}

#[test]
fn safe_says_which_device_it_could_not_reach() {
    let dir = TempDir::new("safe-missing");
    let config = dir.file(
        "rig.toml",
        "[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/rigscript-no-such-port\"\n",
    );
    let out = Command::new(rigscript())
        .args(["safe", "--config", &config])
        .output()
        .unwrap();
    let stderr = stderr(&out);
    assert_eq!(out.status.code(), Some(3), "{stderr}");
    assert!(
        stderr.contains("rigscript safe: io NOT confirmed:")
            && stderr.contains("/dev/rigscript-no-such-port"),
        "{stderr}"
    );
}

#[test]
fn under_systemd_the_runner_behind_its_guardian_notifies_and_feeds_the_service_watchdog() {
    // systemd names the pid it started, the guardian, in $WATCHDOG_PID; the runner must still
    // feed the watchdog (the unit's NotifyAccess=all lets its messages through).
    let sim = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let dir = TempDir::new("guardian-notify");
    let (config, script) = rig(&sim, &dir);
    let socket_path = dir.path("notify.sock");
    let socket = std::os::unix::net::UnixDatagram::bind(&socket_path).unwrap();
    let run = Command::new("sh")
        .arg("-c")
        .arg(r#"WATCHDOG_PID=$$ exec "$0" run --config "$1" "$2" --for 2s"#)
        .args([rigscript(), &config, &script])
        .env("NOTIFY_SOCKET", &socket_path)
        .env("WATCHDOG_USEC", "1000000")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let got: Vec<String> = common::receive_notifications(&socket, |m| m.starts_with("STOPPING"))
        .into_iter()
        .map(|n| n.text)
        .collect();
    let (status, err) = finish(run);
    assert_eq!(status, Some(0), "{err}");
    assert!(got[0].starts_with("READY=1\n"), "{got:?}");
    assert!(got.iter().any(|m| m == "WATCHDOG=1"), "{got:?}\n{err}");
}
