//! `rigscript run` under systemd's notification protocol, against a socket bound by the test
//! as systemd would bind it (`NOTIFY_SOCKET`): READY=1 only once every device is under
//! control, WATCHDOG=1 from the scan loop at half of `WATCHDOG_USEC` (so a loop that hangs
//! stops them), STOPPING=1 at the end.

use crate::common::{
    read_stderr, receive_notifications, run_command, watched_rig, Notification, SimProcess, TempDir,
};
use std::os::linux::net::SocketAddrExt;
use std::os::unix::net::{SocketAddr, UnixDatagram};
use std::path::Path;
use std::process::Child;
use std::time::{Duration, Instant};

/// A datagram socket bound at a path in `dir`, as systemd binds /run/systemd/notify.
fn listen_at_path(dir: &std::path::Path) -> (UnixDatagram, String) {
    let path = dir.join("notify.sock");
    let socket = UnixDatagram::bind(&path).unwrap();
    (socket, path.display().to_string())
}

/// A datagram socket in the abstract namespace, named after `dir` (so no other test's);
/// `NOTIFY_SOCKET` names it with a leading `@`.
fn listen_abstract(dir: &Path) -> (UnixDatagram, String) {
    let name = dir.display().to_string();
    let address = SocketAddr::from_abstract_name(name.as_bytes()).unwrap();
    (
        UnixDatagram::bind_addr(&address).unwrap(),
        format!("@{name}"),
    )
}

/// `rigscript run ARGS` told to notify `notify_socket`, with a watchdog of `watchdog_usec`.
fn start_run(args: &[&str], notify_socket: &str, watchdog_usec: Option<&str>) -> Child {
    let mut cmd = run_command(args);
    cmd.env("NOTIFY_SOCKET", notify_socket)
        .env_remove("WATCHDOG_USEC")
        .env_remove("WATCHDOG_PID");
    if let Some(usec) = watchdog_usec {
        cmd.env("WATCHDOG_USEC", usec);
    }
    cmd.spawn().expect("start rigscript run")
}

fn finish(mut child: Child) -> (i32, String) {
    let status = child.wait().unwrap();
    let err = read_stderr(&mut child);
    (status.code().unwrap_or(-1), err)
}

#[test]
fn ready_comes_once_the_module_is_under_control_then_watchdog_pings_then_stopping() {
    let mut sim = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let before = sim.state();
    assert_eq!(before["watchdog"]["enabled"], false, "{before}");
    let (dir, config, script) = watched_rig(&sim, "notify-ready");
    let (socket, name) = listen_at_path(&dir);
    let run = start_run(
        &["--quiet", "--config", &config, &script, "--for", "1500ms"],
        &name,
        Some("200000"),
    );

    socket
        .set_read_timeout(Some(Duration::from_secs(20)))
        .unwrap();
    let mut buf = [0u8; 4096];
    let n = socket.recv(&mut buf).expect("a first message");
    let first = String::from_utf8_lossy(&buf[..n]).into_owned();
    assert!(first.starts_with("READY=1\nSTATUS=running "), "{first:?}");
    assert!(first.ends_with(" on io"), "{first:?}");
    // By READY the runner has taken control: the module's watchdog and safe value are set.
    let at_ready = sim.state();
    assert_eq!(at_ready["watchdog"]["enabled"], true, "{at_ready}");
    assert_eq!(at_ready["safe_value"], 0x05, "{at_ready}");

    let rest = receive_notifications(&socket, |m| m.starts_with("STOPPING=1"));
    let (status, err) = finish(run);
    assert_eq!(status, 0, "{err}");
    let texts: Vec<&str> = rest.iter().map(|m| m.text.as_str()).collect();
    assert_eq!(
        texts.last().copied(),
        Some("STOPPING=1\nSTATUS=stopped; exit status 0"),
        "{texts:?}"
    );
    let pings: Vec<&Notification> = rest.iter().filter(|m| m.text == "WATCHDOG=1").collect();
    assert_eq!(
        pings.len() + 1,
        rest.len(),
        "only pings between READY and STOPPING: {texts:?}"
    );
    assert!(
        pings.len() >= 3,
        "{} pings in 1.5 s: {texts:?}",
        pings.len()
    );
    assert!(
        !texts.iter().any(|t| t.starts_with("READY")),
        "READY is sent once"
    );
    assert_eq!(sim.state()["do"], 0x05, "safe value at the end");
}

#[test]
fn a_loop_stuck_in_a_handler_sends_no_watchdog_pings_until_it_turns_again() {
    // The handler keeps the loop busy for 800 ms; with pings due every 100 ms, the gap around
    // it shows they come from the loop itself (systemd would kill a loop stuck for longer
    // than WatchdogSec).
    let dir = TempDir::new("notify-stuck");
    let script = dir.join("stuck.rhai");
    std::fs::write(
        &script,
        "after(\"300ms\", || { let t0 = uptime(); while uptime() - t0 < 800 {} log(\"busy done\"); });\n\
         every(\"50ms\", || {});\n",
    )
    .unwrap();
    let (socket, name) = listen_abstract(&dir);
    let run = start_run(
        &[
            "--quiet",
            "--sim",
            "--budget",
            "1000000000",
            &script.display().to_string(),
            "--for",
            "2s",
        ],
        &name,
        Some("200000"),
    );
    let got = receive_notifications(&socket, |m| m.starts_with("STOPPING=1"));
    let (status, err) = finish(run);
    assert_eq!(status, 0, "{err}");
    assert!(err.contains("busy done"), "{err}");
    let texts: Vec<&str> = got.iter().map(|m| m.text.as_str()).collect();
    assert!(
        texts.first().is_some_and(|t| t.starts_with("READY=1")),
        "{texts:?}"
    );
    let pings: Vec<Instant> = got
        .iter()
        .filter(|m| m.text == "WATCHDOG=1")
        .map(|m| m.at)
        .collect();
    let longest = pings
        .windows(2)
        .map(|w| w[1].duration_since(w[0]))
        .max()
        .unwrap_or_default();
    assert!(
        longest >= Duration::from_millis(750),
        "the busy handler should leave a gap of at least 800 ms between pings; longest \
         {longest:?} in {} pings",
        pings.len()
    );
    assert!(pings.len() >= 4, "pings resume after it: {texts:?}");
}

#[test]
fn a_device_unavailable_at_start_means_no_ready() {
    let dir = TempDir::new("notify-absent");
    let config = dir.join("rig.toml");
    std::fs::write(
        &config,
        "[devices.io]\nkind = \"trp-c29u\"\nport = \"/nonexistent/ttyUSB9\"\n",
    )
    .unwrap();
    let script = dir.join("s.rhai");
    std::fs::write(&script, "every(\"1s\", || {});\n").unwrap();
    let (socket, name) = listen_at_path(&dir);
    let run = start_run(
        &[
            "--config",
            &config.display().to_string(),
            &script.display().to_string(),
        ],
        &name,
        Some("200000"),
    );
    let (status, err) = finish(run);
    assert_eq!(status, 3, "{err}");
    socket.set_nonblocking(true).unwrap();
    let mut buf = [0u8; 512];
    let mut got = Vec::new();
    while let Ok(n) = socket.recv(&mut buf) {
        got.push(String::from_utf8_lossy(&buf[..n]).into_owned());
    }
    assert!(
        !got.iter().any(|m| m.contains("READY=1")),
        "no READY for a rig that never ran: {got:?}"
    );
}

#[test]
fn a_bad_notify_socket_is_reported_and_the_run_goes_on() {
    let dir = TempDir::new("notify-bad");
    let script = dir.file("s.rhai", "every(\"100ms\", || log(\"tick\"));\n");
    let run = start_run(
        &["--sim", "--for", "1s", &script],
        "vsock:2:1",
        Some("200000"),
    );
    let (status, err) = finish(run);
    assert_eq!(status, 0, "{err}");
    // Said once, at the start, whatever the watchdog's pings would have been.
    let warning = "NOTIFY_SOCKET=\"vsock:2:1\" is not a socket path (/run/...) or an abstract \
                   name (@...); not notifying systemd";
    assert_eq!(err.matches("NOTIFY_SOCKET").count(), 1, "{err}");
    let said = err.find(warning).unwrap_or_else(|| panic!("{err}"));
    // The run goes on: its handler ticks for the whole second, and it ends as planned.
    let ticks = err.matches("script: tick").count();
    assert!(ticks >= 3, "{ticks} ticks in 1 s: {err}");
    assert!(said < err.find("script: tick").unwrap(), "{err}");
    assert!(err.contains("stopping: ran for 1s"), "{err}");
}

#[test]
fn notifications_nobody_receives_are_counted_and_told_at_the_end() {
    let dir = TempDir::new("notify-gone");
    let script = dir.file("s.rhai", "every(\"50ms\", || {});\n");
    let gone = dir.join("no-such.sock").display().to_string();
    let run = start_run(&["--sim", &script, "--for", "500ms"], &gone, Some("200000"));
    let (status, err) = finish(run);
    assert_eq!(status, 0, "{err}");
    // READY, the pings while the loop turned, STOPPING: all lost, all counted.
    let told = err
        .lines()
        .find(|l| l.contains("notifications to systemd could not be sent (first: READY=1: "))
        .unwrap_or_else(|| panic!("no report of the lost notifications: {err}"));
    let lost: u32 = told
        .split(" of ")
        .next()
        .and_then(|l| l.rsplit(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{told}"));
    assert!(lost >= 4, "READY, STOPPING and pings: {told}");
}
