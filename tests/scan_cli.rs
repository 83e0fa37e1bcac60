//! `rigscript scan` finds simulated TRP-C29U modules on real pseudo-terminals: both protocols,
//! several modules on one line, a checksum-only ASCII module, a pty given by symlink; and a
//! machine without USB lists no boards without failing.

use crate::common::{rigscript, stderr, stdout, SimProcess, TempDir};
use serde_json::Value;
use std::process::{Command, Output};

fn scan(args: &[&str]) -> Output {
    Command::new(rigscript())
        .arg("scan")
        .args(args)
        .output()
        .expect("run rigscript scan")
}

fn scan_json(args: &[&str]) -> Value {
    let mut all = vec!["--json"];
    all.extend_from_slice(args);
    let out = scan(&all);
    let stdout = stdout(&out);
    assert!(
        out.status.success(),
        "scan failed: {stdout}{}",
        stderr(&out)
    );
    assert_eq!(stdout.lines().count(), 1, "one JSON document: {stdout}");
    serde_json::from_str(&stdout).unwrap()
}

fn found_ids(v: &Value) -> Vec<u64> {
    v["modules"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["id"].as_u64().unwrap())
        .collect()
}

#[test]
fn finds_two_modbus_modules_on_one_line() {
    let sim = SimProcess::start(&["--protocol", "modbus", "--id", "1,2"]);
    let v = scan_json(&["--ports", &sim.path, "--ids", "1-3", "--timeout", "30"]);
    assert_eq!(found_ids(&v), vec![1, 2]);
    let m = &v["modules"][0];
    assert_eq!(m["port"], sim.path.as_str());
    assert_eq!(m["protocol"], "modbus");
    assert_eq!(m["baud"], 9600);
    assert_eq!(m["name"], "C29");
    assert_eq!(m["firmware"], "090703");
    assert_eq!(v["errors"], serde_json::json!([]));
    assert!(v["boards"].as_array().unwrap().is_empty() || v["boards"][0]["unit"].is_u64());
    assert!(v["ports"]
        .as_array()
        .unwrap()
        .iter()
        .any(|p| p["port"] == sim.path.as_str() && p["kind"] == "given"));
}

#[test]
fn finds_an_ascii_module_that_wants_checksums_and_lists_it_for_people() {
    let sim = SimProcess::start(&["--protocol", "ascii", "--id", "7", "--checksum"]);
    let out = scan(&[
        "--ports",
        &sim.path,
        "--ids",
        "6-8",
        "--protocols",
        "ascii",
        "--timeout",
        "30",
    ]);
    assert!(out.status.success());
    let stdout = stdout(&out);
    let line = format!(
        "  {}  ascii  9600  ID 7  name TRPC29  firmware C29M090703  checksum on",
        sim.path
    );
    assert!(stdout.lines().any(|l| l == line), "{line:?} in:\n{stdout}");
    assert!(
        stdout.contains(&format!(
            "rigscript c29 --port {} --protocol ascii --id 7 --baud 9600 --checksum status",
            sim.path
        )),
        "says how to talk to it: {stdout}"
    );
    assert!(stdout.starts_with("TRC1000 boards:"), "{stdout}");
    let stderr = stderr(&out);
    assert!(
        stderr.contains(&format!(
            "probing {} ascii at 9600 baud, IDs 6-8, 30 ms each",
            sim.path
        )),
        "progress on standard error: {stderr}"
    );
}

#[test]
fn default_protocols_find_each_module_in_its_own() {
    let modbus = SimProcess::start(&["--protocol", "modbus", "--id", "3"]);
    let ascii = SimProcess::start(&["--protocol", "ascii", "--id", "0"]);
    let ports = format!("{},{}", modbus.path, ascii.path);
    let v = scan_json(&["--ports", &ports, "--ids", "0-3", "--timeout", "30"]);
    let found: Vec<(String, String, u64)> = v["modules"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| {
            (
                m["port"].as_str().unwrap().to_string(),
                m["protocol"].as_str().unwrap().to_string(),
                m["id"].as_u64().unwrap(),
            )
        })
        .collect();
    assert_eq!(
        found,
        vec![
            (modbus.path.clone(), "modbus".to_string(), 3),
            (ascii.path.clone(), "ascii".to_string(), 0),
        ]
    );
    assert_eq!(v["modules"][1]["checksum"], false);
}

#[test]
fn a_symlinked_pty_is_listed_with_its_target_and_probed() {
    let dir = TempDir::new("scan-link");
    let link_text = dir.path("pty").display().to_string();
    let sim = SimProcess::start(&["--protocol", "modbus", "--link", &link_text]);
    let v = scan_json(&[
        "--ports",
        &link_text,
        "--ids",
        "1",
        "--protocols",
        "modbus",
        "--bauds",
        "9600,19200",
    ]);
    let entry = v["ports"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["port"] == link_text.as_str())
        .cloned()
        .unwrap();
    assert_eq!(entry["target"], sim.path.as_str());
    // A pty answers at any speed: the module is listed once, at the first.
    assert_eq!(found_ids(&v), vec![1]);
    assert_eq!(v["modules"][0]["baud"], 9600);
}

#[test]
fn a_given_port_that_does_not_exist_exits_3_after_the_rest_is_scanned() {
    let sim = SimProcess::start(&["--protocol", "modbus"]);
    let ports = format!("/dev/nonexistent,{}", sim.path);
    let out = scan(&[
        "--json",
        "--ports",
        &ports,
        "--ids",
        "1",
        "--protocols",
        "modbus",
    ]);
    assert_eq!(out.status.code(), Some(3));
    let stdout = stdout(&out);
    assert_eq!(
        stdout.lines().count(),
        1,
        "still one JSON document: {stdout}"
    );
    let v: Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(found_ids(&v), vec![1]);
    assert_eq!(v["errors"][0]["port"], "/dev/nonexistent");
    assert!(v["errors"][0]["error"]
        .as_str()
        .unwrap()
        .contains("not found"));
    let stderr = stderr(&out);
    assert!(stderr.contains("/dev/nonexistent"), "{stderr}");
}

#[test]
fn nothing_found_is_not_an_error() {
    let sim = SimProcess::start(&["--protocol", "modbus", "--id", "9"]);
    let out = scan(&["--ports", &sim.path, "--ids", "1-2", "--timeout", "20"]);
    assert!(out.status.success());
    let stdout = stdout(&out);
    assert!(
        stdout.contains("TRP-C29U modules:\n  none found"),
        "{stdout}"
    );
    let stderr = stderr(&out);
    assert!(stderr.contains("hint:"), "says what to try: {stderr}");
}
