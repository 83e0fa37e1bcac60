//! The unit files in packaging/systemd: systemd itself accepts them (`systemd-analyze
//! verify`), their restart policy follows rigscript's exit statuses, and their command lines
//! run as written (on simulated devices): the interlock unit's notifies as `Type=notify` with
//! its `WatchdogSec=` needs, the timer's check leaves its records and JUnit report in its
//! working directory.

use crate::common::{assert_systemd_accepts, receive_notifications, rigscript, stderr, TempDir};
use std::collections::BTreeMap;
use std::os::unix::net::UnixDatagram;
use std::path::{Path, PathBuf};
use std::process::Command;

fn packaging() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("packaging/systemd")
}

/// `section -> key -> values` (a key may repeat), comments and blank lines left out.
fn parse_unit(name: &str) -> BTreeMap<String, BTreeMap<String, Vec<String>>> {
    let text = std::fs::read_to_string(packaging().join(name)).unwrap();
    let mut units = BTreeMap::new();
    let mut section = String::new();
    for line in text.lines().map(str::trim) {
        if line.is_empty() || line.starts_with('#') || line.starts_with(';') {
            continue;
        }
        if let Some(s) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            section = s.to_string();
            continue;
        }
        let (key, value) = line
            .split_once('=')
            .unwrap_or_else(|| panic!("{name}: not key=value: {line}"));
        units
            .entry(section.clone())
            .or_insert_with(BTreeMap::new)
            .entry(key.trim().to_string())
            .or_insert_with(Vec::new)
            .push(value.trim().to_string());
    }
    units
}

fn value(
    unit: &BTreeMap<String, BTreeMap<String, Vec<String>>>,
    section: &str,
    key: &str,
) -> String {
    unit.get(section)
        .and_then(|s| s.get(key))
        .and_then(|v| v.last())
        .unwrap_or_else(|| panic!("[{section}] {key}= is missing"))
        .clone()
}

/// The unit's ExecStart as arguments, with the installed paths replaced by test ones.
fn exec_start(unit: &str, script: &Path, config: &Path) -> Vec<String> {
    let u = parse_unit(unit);
    value(&u, "Service", "ExecStart")
        .split_whitespace()
        .map(|a| match a {
            "/usr/local/bin/rigscript" => rigscript().to_string(),
            "/etc/rigscript/%i.rhai" => script.display().to_string(),
            "/etc/rigscript/%i.toml" => config.display().to_string(),
            other => {
                assert!(
                    !other.contains('%'),
                    "{unit}: unexpected specifier in {other}"
                );
                other.to_string()
            }
        })
        .collect()
}

#[test]
#[ignore = "needs systemd-analyze (tier 2: .ci/run installs systemd)"]
fn systemd_accepts_the_units() {
    // ExecStart's program pointed at the binary under test.
    assert_systemd_accepts("units-verify", |unit| {
        std::fs::read_to_string(packaging().join(unit))
            .unwrap()
            .replace("/usr/local/bin/rigscript", rigscript())
    });
}

#[test]
fn the_interlock_unit_restarts_only_where_a_restart_can_help() {
    let u = parse_unit("rigscript@.service");
    assert_eq!(value(&u, "Service", "Type"), "notify");
    // The runner is the guardian's child (the pid systemd started): its notifications must
    // count, and a stop's SIGTERM go to the guardian alone, which passes it on once.
    assert_eq!(value(&u, "Service", "NotifyAccess"), "all");
    assert_eq!(value(&u, "Service", "KillMode"), "mixed");
    assert!(
        value(&u, "Service", "ExecStopPost").contains(" safe --config "),
        "the safe state written once more after every end"
    );
    assert_eq!(value(&u, "Service", "Restart"), "on-failure");
    let prevented: Vec<i32> = value(&u, "Service", "RestartPreventExitStatus")
        .split_whitespace()
        .map(|s| s.parse().unwrap())
        .collect();
    // 1 would fail again (on_error = "restart" restarts in-process), 2 needs a person, 4 is a
    // result; 3 (a device missing at start) may come back, so it is restarted.
    assert_eq!(prevented, [1, 2, 4]);
    // SIGINT and SIGTERM end a run with 128 + signal: `systemctl stop` is not a failure.
    let success: Vec<i32> = value(&u, "Service", "SuccessExitStatus")
        .split_whitespace()
        .map(|s| s.parse().unwrap())
        .collect();
    assert_eq!(success, [130, 143]);
    assert!(value(&u, "Service", "WatchdogSec").ends_with('s'));
    // DynamicUser has no home: the MQTT outbox's default is $STATE_DIRECTORY, which
    // StateDirectory= gives (else a rig with [mqtt] and no records file could not start).
    assert_eq!(value(&u, "Service", "DynamicUser"), "yes");
    assert_eq!(value(&u, "Service", "StateDirectory"), "rigscript/%i");
    let check = parse_unit("rigscript-check@.service");
    assert_eq!(value(&check, "Service", "Type"), "oneshot");
    assert!(
        check
            .get("Service")
            .is_some_and(|s| !s.contains_key("Restart")),
        "the timer starts the next check; a failed one is not repeated"
    );
    let timer = parse_unit("rigscript-check@.timer");
    assert_eq!(value(&timer, "Timer", "Persistent"), "false");
}

#[test]
fn the_interlock_unit_runs_as_written_and_notifies_as_its_type_asks() {
    let dir = TempDir::new("units-notify");
    let script = dir.join("interlock.rhai");
    std::fs::write(&script, "every(\"100ms\", || {});\n").unwrap();
    let config = dir.join("interlock.toml");
    std::fs::write(
        &config,
        "[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\nwatchdog = \"2s\"\n",
    )
    .unwrap();
    let args = exec_start("rigscript@.service", &script, &config);
    let u = parse_unit("rigscript@.service");
    let watchdog_sec: u64 = value(&u, "Service", "WatchdogSec")
        .trim_end_matches('s')
        .parse()
        .unwrap();
    let socket_path = dir.join("notify.sock");
    let socket = UnixDatagram::bind(&socket_path).unwrap();
    // As systemd starts it, plus --sim (no hardware here) and an end.
    let child = Command::new(&args[0])
        .args(&args[1..])
        .args(["--sim", "--for", "1s"])
        .current_dir(&dir)
        .env("NOTIFY_SOCKET", &socket_path)
        .env("WATCHDOG_USEC", (watchdog_sec * 1_000_000).to_string())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let got: Vec<String> = receive_notifications(&socket, |m| m.starts_with("STOPPING"))
        .into_iter()
        .map(|n| n.text)
        .collect();
    let out = child.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    assert!(got[0].starts_with("READY=1\n"), "{got:?}");
    assert!(got.iter().any(|m| m == "WATCHDOG=1"), "{got:?}");
    assert!(got.last().unwrap().starts_with("STOPPING=1\n"), "{got:?}");
}

#[test]
fn the_check_unit_leaves_records_and_a_report_in_its_working_directory() {
    let dir = TempDir::new("units-check");
    let config = dir.join("bench.toml");
    std::fs::write(
        &config,
        "[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\n",
    )
    .unwrap();
    let work = dir.join("state");
    std::fs::create_dir_all(&work).unwrap();
    let args = exec_start(
        "rigscript-check@.service",
        &packaging().join("bench-check.rhai"),
        &config,
    );
    let out = Command::new(&args[0])
        .args(&args[1..])
        .arg("--sim")
        .current_dir(&work)
        .output()
        .unwrap();
    // Nothing answers the trigger on the simulator: the count is out of its limits.
    assert_eq!(out.status.code(), Some(4), "{}", stderr(&out));
    let records = std::fs::read_to_string(work.join("records.jsonl")).unwrap();
    assert!(
        records.contains("\"name\":\"response_pulses\""),
        "{records}"
    );
    let report = std::fs::read_to_string(work.join("junit.xml")).unwrap();
    let doc = roxmltree::Document::parse(&report).unwrap();
    assert_eq!(doc.root_element().attribute("failures"), Some("1"));
}
