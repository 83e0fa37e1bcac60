//! `rigscript run` and `rigscript check` as a user runs them: exit statuses, what the run
//! shows on stderr, records files, `--stats`.

use crate::common::{rigscript, stderr, stdout, TempDir};
use std::process::{Command, Output};

fn run(args: &[&str]) -> Output {
    Command::new(rigscript()).args(args).output().unwrap()
}

#[test]
fn a_tiny_script_runs_for_a_second_on_the_simulators_and_shows_what_it_does() {
    let d = TempDir::new("tiny");
    let s = d.file(
        "blink.rhai",
        "every(\"100ms\", || io.outputs = io.outputs ^ 1);\npanel.relay = 4;\n",
    );
    let o = run(&["run", "--sim", "--for", "1s", "--stats", &s]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(0), "{err}");
    assert!(
        err.contains("io: outputs 0x00 -> 0x01 (every 100ms)"),
        "{err}"
    );
    assert!(err.contains("panel: relay 0 -> 4 (top level)"), "{err}");
    assert!(err.contains("stopping: ran for 1s"), "{err}");
    assert!(
        err.contains("safe state (end of run): io outputs 0x00, panel relay 0"),
        "{err}"
    );
    let out = stdout(&o);
    for key in [
        "ticks: ",
        "jitter: p50 ",
        "overruns: ",
        "transactions per tick: ",
    ] {
        assert!(out.contains(key), "{out}");
    }
}

#[test]
fn without_config_or_sim_it_is_a_usage_error() {
    let d = TempDir::new("usage");
    let s = d.file("s.rhai", "print(1);");
    let o = run(&["run", &s]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("give --config rig.toml"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn a_bad_config_is_exit_2_and_a_missing_device_exit_3() {
    let d = TempDir::new("config");
    let s = d.file("s.rhai", "print(1);");
    let bad = d.file(
        "bad.toml",
        "[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/x\"\nprotocol = \"modbsu\"\n",
    );
    let o = run(&["run", "--config", &bad, &s]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("bad.toml:4: devices.io.protocol"),
        "{}",
        stderr(&o)
    );
    let missing = d.file(
        "missing.toml",
        "[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/rigscript-no-such-port\"\n",
    );
    let o = run(&["run", "--config", &missing, &s]);
    assert_eq!(o.status.code(), Some(3), "{}", stderr(&o));
    assert!(stderr(&o).contains("device io"), "{}", stderr(&o));
}

#[test]
fn two_entries_for_one_module_are_refused_by_check_and_run() {
    let d = TempDir::new("clash");
    let s = d.file("s.rhai", "print(1);");
    let cfg = d.file(
        "rig.toml",
        "[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/x\"\nsafe_value = 0x05\n\n\
         [devices.io2]\nkind = \"trp-c29u\"\nport = \"/dev/x\"\nsafe_value = 0xFF\n",
    );
    for cmd in ["check", "run"] {
        let o = run(&[cmd, "--config", &cfg, &s]);
        assert_eq!(o.status.code(), Some(2), "{cmd}: {}", stderr(&o));
        let err = stderr(&o);
        assert!(
            err.contains("rig.toml:6: devices.io2: is the same module as devices.io (line 1)"),
            "{cmd}: {err}"
        );
    }
}

#[test]
fn script_errors_are_exit_1_with_file_line_and_column() {
    let d = TempDir::new("errors");
    // A name `check` cannot see: the error comes when the handler runs.
    let s = d.file(
        "runtime.rhai",
        "let name = \"nope\";\nafter(\"50ms\", || device(name));\n",
    );
    let o = run(&["run", "--sim", &s]);
    assert_eq!(o.status.code(), Some(1));
    let err = stderr(&o);
    assert!(
        err.contains(&format!(
            "{s}:2:18: in after 50ms: no device called \"nope\""
        )),
        "{err}"
    );
}

#[test]
fn a_script_check_rejects_does_not_run() {
    let d = TempDir::new("check-first");
    // The interlock's off switch misspelt: it would fail just when a guard opens.
    let s = d.file(
        "interlock.rhai",
        "let io = device(\"io\");\nio.on_rise(0, |ch| {\n    io.set_ouptut(7, false);\n});\n",
    );
    let checked = run(&["check", &s]);
    assert_eq!(checked.status.code(), Some(1));
    let problem = stdout(&checked).lines().next().unwrap().to_string();
    assert_eq!(
        problem,
        format!(
            "{s}:3:8: io is a TRP-C29U: it has no method set_ouptut; did you mean `set_output`?"
        )
    );
    let o = run(&["run", "--sim", "--for", "200ms", &s]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains(&problem), "check's message: {err}");
    assert!(err.contains("fix them first"), "{err}");
    assert!(!err.contains("safe state"), "nothing was started: {err}");
    for (name, text) in [
        ("syntax.rhai", "let x = ;\n"),
        ("import.rhai", "import \"fs\" as fs;\n"),
    ] {
        let s = d.file(name, text);
        let o = run(&["run", "--sim", &s]);
        assert_eq!(o.status.code(), Some(2), "{name}: {}", stderr(&o));
        assert!(stderr(&o).contains(&format!("{s}:1:")), "{}", stderr(&o));
    }
}

#[test]
fn an_endless_file_is_refused_with_its_limit() {
    let d = TempDir::new("endless");
    let s = d.file("ok.rhai", "let x = 1;\n");
    for (args, says) in [
        (
            vec!["run", "/dev/zero", "--sim"],
            "cannot read /dev/zero: it holds more than 4 MiB, the most a script may be",
        ),
        (
            vec!["check", "/dev/zero"],
            "cannot read /dev/zero: it holds more than 4 MiB, the most a script may be",
        ),
        (
            vec!["run", &s, "--sim", "--config", "/dev/zero"],
            "/dev/zero: cannot read: it holds more than 1 MiB, the most a rig.toml may be",
        ),
        (
            vec!["check", &s, "--config", "/dev/zero"],
            "/dev/zero: cannot read: it holds more than 1 MiB, the most a rig.toml may be",
        ),
    ] {
        let o = run(&args);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(says), "{args:?}: {err}");
        assert!(err.contains("give the"), "what to do: {err}");
    }
}

#[test]
fn a_failed_measurement_is_exit_4_and_records_are_json_lines() {
    let d = TempDir::new("records");
    let s = d.file(
        "m.rhai",
        "record(\"id\", 42);\nmeasure(\"v\", 3.3, #{min: 3.0, max: 3.2, unit: \"V\"});\n",
    );
    let records = d.root().join("out.jsonl").display().to_string();
    let o = run(&["run", "--sim", "--records", &records, &s]);
    assert_eq!(o.status.code(), Some(4), "{}", stderr(&o));
    let text = std::fs::read_to_string(&records).unwrap();
    let lines: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 2);
    assert_eq!(lines[0]["name"], "id");
    assert_eq!(lines[0]["value"], 42);
    assert!(lines[0]["time"].as_str().unwrap().contains('T'));
    assert_eq!(lines[1]["pass"], false);
    assert_eq!(lines[1]["unit"], "V");
}

#[test]
fn check_and_run_name_a_timer_shorter_than_the_period_with_the_period() {
    let d = TempDir::new("short-timer");
    let s = d.file("fast.rhai", "let n = 0;\n  every(\"100ms\", || n += 1);\n");
    let cfg = d.file(
        "rig.toml",
        "period = \"5s\"\n[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/x\"\n",
    );
    let warning = format!(
        "{s}:2:3: warning: every(\"100ms\") is shorter than the rig's period 5s: it fires at \
         most once a period"
    );
    let o = run(&["check", "--config", &cfg, &s]);
    assert_eq!(
        o.status.code(),
        Some(0),
        "a warning is no problem: {}",
        stdout(&o)
    );
    assert!(stdout(&o).contains(&warning), "{}", stdout(&o));
    assert!(
        stdout(&o).contains(&format!("{s}: ok, with 1 warning(s)")),
        "{}",
        stdout(&o)
    );
    // `run` names the period it runs at, `--period` included, in its log.
    let logged = format!(
        "warning: {s}:2:3: every(\"100ms\") is shorter than the rig's period 5s: it fires at \
         most once a period"
    );
    let o = run(&["run", "--sim", "--period", "5s", "--for", "10ms", &s]);
    assert!(stderr(&o).contains(&logged), "{}", stderr(&o));
    let o = run(&["run", "--sim", "--period", "50ms", "--for", "10ms", &s]);
    assert!(
        !stderr(&o).contains("every(\"100ms\") is shorter"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn an_empty_script_or_one_with_nothing_to_run_is_a_warning_in_check_and_verify() {
    let d = TempDir::new("nothing-to-run");
    let empty = d.file("empty.rhai", "// to do\n");
    let once = d.file("once.rhai", "io.outputs = 0x01;\n");
    for (s, why) in [
        (&empty, "the script is empty: there is nothing to run"),
        (
            &once,
            "nothing to run: the script sets up no handler, timer or invariant, so a run does \
             its top level once and ends",
        ),
    ] {
        let warning = format!("{s}: warning: {why}");
        let o = run(&["check", s]);
        assert_eq!(o.status.code(), Some(0), "{}", stdout(&o));
        assert!(stdout(&o).contains(&warning), "{}", stdout(&o));
        let o = run(&["verify", s, "--runs", "1"]);
        assert!(stderr(&o).contains(&warning), "{}", stderr(&o));
    }
}

#[test]
fn check_reports_problems_with_line_and_column() {
    let d = TempDir::new("check");
    let good = d.file("good.rhai", "io.on_rise(3, |ch| io.outputs = 1 << ch);\n");
    let o = run(&["check", &good]);
    assert_eq!(o.status.code(), Some(0), "{}", stdout(&o));
    let bad = d.file(
        "bad.rhai",
        "let io = device(\"oi\");\npanel.on_press(\"S46\", || {});\n",
    );
    let o = run(&["check", &bad]);
    assert_eq!(o.status.code(), Some(1));
    let out = stdout(&o);
    assert!(
        out.contains(&format!("{bad}:1:17: no device called \"oi\"")),
        "{out}"
    );
    assert!(
        out.contains(&format!("{bad}:2:16: no switch called \"S46\"")),
        "{out}"
    );
    let cfg = d.file(
        "rig.toml",
        "[devices.oi]\nkind = \"trp-c29u\"\nport = \"/dev/x\"\n",
    );
    let o = run(&["check", "--config", &cfg, &bad]);
    assert_eq!(o.status.code(), Some(1));
    let out = stdout(&o);
    assert!(!out.contains("no device called"), "{out}");
}

/// Whether this process may write Linux's PM QoS file, as `run` would.
fn may_hold_wake_latency() -> bool {
    std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/cpu_dma_latency")
        .is_ok()
}

/// Whether process `pid` has /dev/cpu_dma_latency open.
fn holds_wake_latency(pid: u32) -> bool {
    std::fs::read_dir(format!("/proc/{pid}/fd"))
        .map(|fds| {
            fds.flatten().any(|fd| {
                std::fs::read_link(fd.path())
                    .is_ok_and(|t| t == std::path::Path::new("/dev/cpu_dma_latency"))
            })
        })
        .unwrap_or(false)
}

#[test]
fn a_short_period_holds_the_wake_latency_request_while_running_and_stats_say_so() {
    let d = TempDir::new("wake");
    let s = d.file("idle.rhai", "every(\"10ms\", || ());\n");
    let child = Command::new(rigscript())
        .args([
            "run", "--sim", "--period", "10ms", "--for", "3s", "--stats", &s,
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let allowed = may_hold_wake_latency();
    let give_up = std::time::Instant::now() + std::time::Duration::from_secs(2);
    let mut seen = false;
    while !seen && std::time::Instant::now() < give_up {
        seen = holds_wake_latency(child.id());
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let o = child.wait_with_output().unwrap();
    let (out, err) = (stdout(&o), stderr(&o));
    assert_eq!(o.status.code(), Some(0), "{err}");
    assert_eq!(seen, allowed, "the request is held exactly when it can be");
    if allowed {
        assert!(out.contains("wake latency: held at 0 µs\n"), "{out}");
        assert!(err.contains("CPU wake-up latency held at 0 µs"), "{err}");
    } else {
        assert!(
            out.contains("wake latency: not held (/dev/cpu_dma_latency: "),
            "{out}"
        );
        assert!(err.contains("61-rigscript-wake-latency.rules"), "{err}");
    }
}

#[test]
fn the_wake_latency_follows_the_period_and_the_option() {
    let d = TempDir::new("wake-options");
    let s = d.file("idle.rhai", "every(\"50ms\", || ());\n");
    let stats = |extra: &[&str]| {
        let mut args = vec!["run", "--sim", "--for", "200ms", "--stats", "-q", &s];
        args.extend_from_slice(extra);
        let o = run(&args);
        assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
        stdout(&o)
    };
    let none = "wake latency: not requested\n";
    assert!(stats(&["--period", "50ms"]).contains(none));
    assert!(stats(&["--period", "10ms", "--wake-latency", "off"]).contains(none));
    let explicit = stats(&["--period", "50ms", "--wake-latency", "75us"]);
    if may_hold_wake_latency() {
        assert!(
            explicit.contains("wake latency: held at 75 µs\n"),
            "{explicit}"
        );
    } else {
        assert!(explicit.contains("wake latency: not held ("), "{explicit}");
    }
    let o = run(&["run", "--sim", "--wake-latency", "low", &s]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("\"low\" is not a wake latency; use \"auto\", \"off\""),
        "{}",
        stderr(&o)
    );
}

#[test]
fn run_help_shows_the_exit_statuses() {
    let o = run(&["run", "--help"]);
    assert_eq!(o.status.code(), Some(0));
    let out = stdout(&o);
    for line in [
        "Exit status (the first that applies):",
        "    5  the run ended, but something failed on the way: script errors recovered",
        "  130  stopped by SIGINT (128 + 2); 143: stopped by SIGTERM (128 + 15) or by",
        "Before the run starts: 2 usage or rig.toml error, or a script `rigscript check`",
        "rejects; 3 a device not available (missing, busy, no answer), or a run of the",
    ] {
        assert!(out.contains(line), "{line}: {out}");
    }
}

/// Starts `run --sim SCRIPT`, waits until it logs `ready`, sends `signal`, and returns the
/// exit status and the log.
fn stopped_by(signal: &str, script: &str) -> (Option<i32>, String) {
    use std::io::{BufRead, BufReader};
    let mut child = Command::new(rigscript())
        .args(["run", "--sim", script])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let mut log = String::new();
    while !log.contains("script: ready") {
        let mut line = String::new();
        if err.read_line(&mut line).unwrap() == 0 {
            break;
        }
        log.push_str(&line);
    }
    let ok = Command::new("kill")
        .args([signal, &child.id().to_string()])
        .status()
        .unwrap()
        .success();
    assert!(ok);
    let status = child.wait().unwrap();
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut err, &mut rest).unwrap();
    (status.code(), log + rest.as_str())
}

#[test]
fn signals_end_the_run_with_128_plus_the_signal_after_the_safe_state() {
    let d = TempDir::new("signals");
    let s = d.file(
        "work.rhai",
        "io.outputs = 0xF0;\nevery(\"50ms\", || ());\nafter(\"100ms\", || log(\"ready\"));\n",
    );
    for (signal, status, name) in [("-INT", 130, "SIGINT"), ("-TERM", 143, "SIGTERM")] {
        let (code, log) = stopped_by(signal, &s);
        assert_eq!(code, Some(status), "{log}");
        assert!(log.contains(&format!("stopping: {name} received")), "{log}");
        assert!(
            log.contains("safe state (signal): io outputs 0x00"),
            "{log}"
        );
        assert!(log.contains(&format!("exit status {status}")), "{log}");
    }
}

#[test]
fn a_run_with_recovered_errors_does_not_end_0() {
    let d = TempDir::new("skip-status");
    let cfg = d.file(
        "rig.toml",
        "on_error = \"skip\"\n[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/x\"\n",
    );
    // A channel `check` cannot see: each call fails as it runs.
    let s = d.file(
        "s.rhai",
        "let ch = 9;\nevery(\"100ms\", || io.set_output(ch, true));\n",
    );
    let o = run(&["run", "--sim", "--config", &cfg, "--for", "350ms", &s]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(5), "{err}");
    assert!(
        err.contains("3 script error(s) recovered from: exit status 5"),
        "{err}"
    );
}

#[test]
fn a_slow_script_at_a_short_period_does_not_hold_the_wake_latency() {
    let d = TempDir::new("wake-slow");
    // cron_rig's shape: two ticks a second at most, at the default 20 ms period.
    let s = d.file("slow.rhai", "every(\"500ms\", || ());\n");
    let child = Command::new(rigscript())
        .args(["run", "--sim", "--for", "1500ms", "--stats", &s])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let give_up = std::time::Instant::now() + std::time::Duration::from_millis(1200);
    let mut seen = false;
    while !seen && std::time::Instant::now() < give_up {
        seen = holds_wake_latency(child.id());
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let o = child.wait_with_output().unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(!seen, "no request while nothing ticks fast");
    assert!(
        stdout(&o).contains("wake latency: not requested\n"),
        "{}",
        stdout(&o)
    );
}

#[test]
fn the_wake_latency_is_released_when_the_fast_handler_goes() {
    let d = TempDir::new("wake-release");
    let s = d.file(
        "fast_then_slow.rhai",
        "let fast = every(\"10ms\", || ());\nafter(\"300ms\", || cancel(fast));\nevery(\"1s\", || ());\n",
    );
    let o = run(&["run", "--sim", "--for", "600ms", &s]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(0), "{err}");
    if may_hold_wake_latency() {
        assert!(
            err.contains("CPU wake-up latency held at 0 µs (ticks every 20ms)"),
            "{err}"
        );
        assert!(
            err.contains("CPU wake-up latency released: no handler needs ticks of 20 ms or less"),
            "{err}"
        );
    } else {
        assert_eq!(
            err.matches("CPU wake-up latency not held").count(),
            1,
            "asked once: {err}"
        );
    }
}

/// Makes a named pipe at `path`.
fn mkfifo(path: &std::path::Path) {
    let c = std::ffi::CString::new(path.as_os_str().as_encoded_bytes()).unwrap();
    // SAFETY: a valid C string.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0, "mkfifo");
}

/// Waits until `child` exits or 10 s pass (then kills it and fails, saying `what`).
fn exits_within_10s(child: &mut std::process::Child, what: &str) -> std::process::ExitStatus {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return status;
        }
        if std::time::Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("not within 10 s: {what}");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

/// Collects `child`'s stderr on a thread, into the text returned.
fn collect_stderr(child: &mut std::process::Child) -> std::sync::Arc<std::sync::Mutex<String>> {
    use std::io::{BufRead, BufReader};
    let err = BufReader::new(child.stderr.take().unwrap());
    let text = std::sync::Arc::new(std::sync::Mutex::new(String::new()));
    let theirs = std::sync::Arc::clone(&text);
    std::thread::spawn(move || {
        for line in err.lines() {
            let Ok(line) = line else { break };
            let mut t = theirs.lock().unwrap();
            t.push_str(&line);
            t.push('\n');
        }
    });
    text
}

#[test]
fn a_records_pipe_nobody_reads_never_holds_the_run_and_sigterm_still_stops_it_safely() {
    use std::os::unix::fs::OpenOptionsExt;
    let d = TempDir::new("records-fifo-stuck");
    let fifo = d.root().join("records.fifo");
    mkfifo(&fifo);
    // Someone has the pipe open for reading, and never reads.
    let _reader = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(&fifo)
        .unwrap();
    // Far more than the pipe (64 KiB) and the records queue together hold.
    let s = d.file(
        "r.rhai",
        "io.outputs = 0xF0;\nlet big = \"x\";\nbig.pad(1000, 'x');\n\
         for n in 0..3000 { record(\"n\", `${n} ${big}`); }\n\
         every(\"50ms\", || record(\"tick\", 1));\nafter(\"100ms\", || log(\"ready\"));\n",
    );
    let mut child = Command::new(rigscript())
        // The top level writes 3 MB of records: on a loaded machine a debug build can take
        // most of the default second per call for that, which is not what this test is about.
        .args([
            "run",
            "--sim",
            "--stats",
            "--handler-time",
            "30s",
            "--records",
        ])
        .arg(&fifo)
        .arg(&s)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let log = collect_stderr(&mut child);
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    while !log.lock().unwrap().contains("script: ready") {
        if std::time::Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "the run did not get past its records within 10 s: {}",
                log.lock().unwrap()
            );
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let ok = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap()
        .success();
    assert!(ok);
    let status = exits_within_10s(&mut child, "SIGTERM with a records pipe nobody reads");
    let mut stats = String::new();
    std::io::Read::read_to_string(&mut child.stdout.take().unwrap(), &mut stats).unwrap();
    // The stderr thread ends with the process; give it the last lines.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    while !log.lock().unwrap().contains("exit status") && std::time::Instant::now() < deadline {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let log = log.lock().unwrap().clone();
    assert!(log.contains("stopping: SIGTERM received"), "{log}");
    assert!(
        log.contains("safe state (signal): io outputs 0x00"),
        "{log}"
    );
    assert!(log.contains("records not written"), "{log}");
    assert!(
        log.contains("record(s) not written to the records file: exit status 5"),
        "{log}"
    );
    assert_eq!(status.code(), Some(5), "{log}");
    assert!(stats.contains("records not written: "), "{stats}");
}

#[test]
fn a_records_pipe_with_no_reader_is_refused_at_start_without_waiting() {
    let d = TempDir::new("records-fifo-none");
    let fifo = d.root().join("records.fifo");
    mkfifo(&fifo);
    let s = d.file("r.rhai", "record(\"n\", 1);\n");
    let mut child = Command::new(rigscript())
        .args(["run", "--sim", "--for", "1s", "--records"])
        .arg(&fifo)
        .arg(&s)
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let status = exits_within_10s(&mut child, "start with a records pipe that has no reader");
    let mut err = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut err).unwrap();
    assert_eq!(status.code(), Some(2), "{err}");
    assert!(
        err.contains("a named pipe (FIFO) that nothing reads; start its reader first"),
        "{err}"
    );
}

#[test]
fn a_full_disk_for_the_records_is_told_once_with_the_count_and_the_run_ends_5() {
    // /dev/full refuses every write with ENOSPC, as a full disk does.
    let d = TempDir::new("records-full");
    let s = d.file(
        "r.rhai",
        "for n in 0..20 { record(\"n\", n); }\nmeasure(\"v\", 1.0, #{min: 0.0});\n",
    );
    let o = run(&["run", "--sim", "--records", "/dev/full", &s]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(5), "{err}");
    assert_eq!(
        err.matches("records file /dev/full: disk full: records are not written")
            .count(),
        1,
        "{err}"
    );
    assert!(
        err.contains("records file /dev/full: disk full, 21 records not written"),
        "{err}"
    );
    assert!(
        err.contains("21 record(s) not written to the records file: exit status 5"),
        "{err}"
    );
    assert!(!err.contains("in top level"), "not a script error: {err}");
}

#[test]
fn records_the_disk_refuses_are_counted_in_status_while_the_run_goes_on() {
    // /dev/full refuses every write with ENOSPC, as a full disk does.
    let d = TempDir::new("records-full-live");
    let s = d.file("lossy.rhai", "every(\"50ms\", || record(\"n\", 1));\n");
    let mut rig = Command::new(rigscript())
        .args(["run", "--sim", "--records", "/dev/full", &s])
        .env("XDG_RUNTIME_DIR", d.root())
        .env_remove("RUNTIME_DIRECTORY")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let lost = |at_least: u64| {
        crate::common::until(std::time::Duration::from_secs(10), || {
            let o = Command::new(rigscript())
                .args(["status", "lossy", "--json"])
                .env("XDG_RUNTIME_DIR", d.root())
                .env_remove("RUNTIME_DIRECTORY")
                .output()
                .ok()?;
            let v: serde_json::Value = serde_json::from_slice(&o.stdout).ok()?;
            let n = v["records_lost"].as_u64()?;
            (n >= at_least).then_some(n)
        })
    };
    let first = lost(3).expect("records_lost counted while the run goes on");
    let later = lost(first + 3).expect("and it goes on counting");
    assert!(later > first);
    // SAFETY: a plain kill(2) on our own child.
    unsafe { libc::kill(rig.id() as i32, libc::SIGTERM) };
    let _ = rig.wait();
}

#[test]
fn quiet_leaves_the_script_s_messages_warnings_errors_and_the_safe_state_only() {
    let d = TempDir::new("quiet");
    let s = d.file(
        "q.rhai",
        "every(\"50ms\", || io.outputs = io.outputs ^ 1);\nprint(\"hello\");\nwarn(\"careful\");\n",
    );
    let o = run(&[
        "run", "--sim", "--for", "300ms", "--period", "10ms", "-q", &s,
    ]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(0), "{err}");
    // Each line is "HH:MM:SS.mmm message": what is left once the time is cut off.
    let lines: Vec<&str> = err
        .lines()
        .map(|l| l.split_once(' ').map_or(l, |(_, rest)| rest))
        .collect();
    assert_eq!(
        lines,
        [
            "script: hello",
            "warning: script: careful",
            "safe state (end of run): io outputs 0x00, panel relay 0",
        ],
        "{err}"
    );
}

#[test]
fn a_missing_semicolon_is_reported_where_its_statement_ends() {
    let d = TempDir::new("syntax");
    let s = d.file(
        "syn.rhai",
        "let io = device(\"io\");\nlet x = 1;\nlet y = 2\nio.outputs = x + y;\n",
    );
    let want = format!("{s}:3:10: Expecting ';' to terminate this statement");
    let o = run(&["check", &s]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stdout(&o).contains(&want), "{}", stdout(&o));
    let o = run(&["run", "--sim", "--for", "100ms", &s]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains(&want), "{}", stderr(&o));
}

#[test]
fn test_without_paths_outside_the_repository_says_what_it_looks_for() {
    let d = TempDir::new("test-elsewhere");
    let o = Command::new(rigscript())
        .arg("test")
        .current_dir(d.root())
        .output()
        .unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("no test files given, and no scripts/tests/ in this directory"),
        "{err}"
    );
    assert!(err.contains("rigscript test PATH.."), "{err}");
    assert!(!err.contains("No such file or directory"), "{err}");
}
