//! The TCP link end to end: `rigscript c29 --port tcp://...` through a local relay (what a
//! serial device server or ser2net does) to `rigscript sim c29u` on a real pty.

use crate::common::{lose_a_module, rigscript, start_relay, stderr, stdout, Cut, SimProcess};
use serde_json::Value;
use std::net::TcpListener;
use std::process::{Command, Output};
use std::time::Duration;

fn rigscript_run(args: &[&str]) -> Output {
    Command::new(rigscript()).args(args).output().unwrap()
}

fn ok_json(args: &[&str]) -> Value {
    let out = rigscript_run(args);
    let stdout = stdout(&out);
    assert!(out.status.success(), "{args:?}: {stdout}{}", stderr(&out));
    serde_json::from_str(&stdout).unwrap()
}

#[test]
fn c29_commands_reach_the_module_through_a_tcp_serial_server() {
    for protocol in ["modbus", "ascii"] {
        let mut sim = SimProcess::start(&["--protocol", protocol, "--di", "0x05"]);
        let address = format!("tcp://127.0.0.1:{}", start_relay(&sim.path));
        let base = ["c29", "--port", &address, "--protocol", protocol];

        let out = rigscript_run(&[&base[..], &["status"]].concat());
        let stdout = stdout(&out);
        assert!(out.status.success(), "{stdout}");
        assert!(
            stdout.contains("DI    0x05  00000101  energized: DI0 DI2"),
            "{stdout}"
        );

        ok_json(&[&base[..], &["--json", "do", "0x21"]].concat());
        assert_eq!(sim.state()["do"], 0x21);
        let v = ok_json(&[&base[..], &["--json", "info"]].concat());
        assert!(
            v["module"].as_str().unwrap().contains(&address),
            "describes the link: {v}"
        );
    }
}

#[test]
fn scan_finds_a_module_behind_a_tcp_serial_server() {
    let sim = SimProcess::start(&["--protocol", "modbus", "--id", "4"]);
    let address = format!("tcp://127.0.0.1:{}", start_relay(&sim.path));
    let v = ok_json(&[
        "scan",
        "--json",
        "--ports",
        &address,
        "--ids",
        "3-5",
        "--protocols",
        "modbus",
    ]);
    assert_eq!(v["modules"][0]["id"], 4);
    assert_eq!(v["modules"][0]["port"], address.as_str());
}

#[test]
fn a_server_that_is_not_there_exits_3_with_a_hint() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    drop(listener);
    let address = format!("tcp://127.0.0.1:{port}");
    let out = rigscript_run(&["c29", "--port", &address, "status"]);
    assert_eq!(out.status.code(), Some(3));
    let stderr = stderr(&out);
    assert!(stderr.contains(&format!("127.0.0.1:{port}")), "{stderr}");
    assert!(stderr.contains("server is running"), "{stderr}");
}

#[test]
fn a_module_whose_server_closes_the_connection_is_lost_at_once_and_the_rest_goes_safe() {
    // The relay closes the connection when its serial line hangs up, as a device server does
    // whose module went away.
    let relayed = |pty: &str| format!("tcp://127.0.0.1:{}", start_relay(pty));
    let cut = (Cut::Kill, Duration::ZERO);
    let loss = lose_a_module("tcp-closed", relayed, cut, Duration::from_secs(10));
    // At the next identity check (every 5 s) it would be up to 5 s late.
    loss.assert_safe_within(Duration::from_secs(4));
    let lost = loss
        .log
        .lines()
        .find(|l| l.contains("lost: lost: "))
        .unwrap_or_else(|| panic!("the loss is told: {}", loss.log));
    // Told by the OS between exchanges, or by the exchange that was under way when it closed:
    // both name the server and the disconnection.
    assert!(
        lost.contains("disconnected: the server closed the connection (end of stream) (the OS says so between exchanges)")
            || lost.contains("disconnected: unexpected end of file"),
        "{lost}"
    );
}
