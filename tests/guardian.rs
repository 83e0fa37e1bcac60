//! The guardian against real processes and the TRP-C29U simulator on a real pty: whatever kills
//! the runner (kill -9, a crash, a stuck loop), the guardian writes the safe state and reads it
//! back; killing the pid that was started stops the runner in order; a clean end needs nothing
//! of it. `rigscript safe` writes and confirms the safe state by hand.

mod common;

use common::{rigscript, SimProcess, TempDir};
use std::io::Read;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A module without a host watchdog: only the runner, or its guardian, can make it safe.
fn rig(sim: &SimProcess, dir: &TempDir) -> (String, String) {
    let config = dir.file(
        "rig.toml",
        &format!(
            "period = \"20ms\"\n[devices.io]\nkind = \"trp-c29u\"\nport = \"{}\"\nsafe_value = 0x00\n",
            sim.path
        ),
    );
    let script = dir.file(
        "work.rhai",
        "io.outputs = 0x0F;\nevery(\"100ms\", || {});\n",
    );
    (config, script)
}

fn start_run(config: &str, script: &str) -> Child {
    use std::os::unix::process::CommandExt;
    let mut command = Command::new(rigscript());
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
    command
        .args(["run", "--config", config, script])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Polls the simulator until `pred` holds of its state, or 10 s pass.
fn wait_for(sim: &mut SimProcess, pred: impl Fn(&serde_json::Value) -> bool) -> serde_json::Value {
    let start = Instant::now();
    loop {
        let s = sim.state();
        if pred(&s) || start.elapsed() > Duration::from_secs(10) {
            return s;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
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

fn kill(pid: impl ToString, signal: &str) {
    let ok = Command::new("kill")
        .args([signal, &pid.to_string()])
        .status()
        .unwrap()
        .success();
    assert!(ok, "kill {signal}");
}

/// Waits for the guardian to exit; its status and what it wrote on stderr.
fn finish(mut run: Child) -> (Option<i32>, String) {
    let status = run.wait().unwrap();
    let mut err = String::new();
    run.stderr.take().unwrap().read_to_string(&mut err).unwrap();
    (status.code(), err)
}

/// Starts a run and waits until the script drives the module.
fn driven(tag: &str) -> (SimProcess, TempDir, Child) {
    let mut sim = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let dir = TempDir::new(tag);
    let (config, script) = rig(&sim, &dir);
    let run = start_run(&config, &script);
    let s = wait_for(&mut sim, |s| s["do"] == 0x0F);
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
    assert_eq!(status, Some(137), "the stuck runner was killed: {err}");
    assert_eq!(sim.state()["do"], 0x00, "{err}");
}

#[test]
fn kill_9_of_the_pid_that_was_started_stops_the_runner_in_order() {
    let (mut sim, _dir, mut run) = driven("guardian-gone");
    let runner = runner_of(&run);
    run.kill().unwrap();
    run.wait().unwrap();
    let s = wait_for(&mut sim, |s| s["do"] == 0x00);
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
    let stdout = String::from_utf8_lossy(&out.stdout);
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
    let stderr = String::from_utf8_lossy(&out.stderr);
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
