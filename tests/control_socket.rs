//! The control socket against real `rigscript run` processes: `status --json` follows the
//! module on a real pty while its inputs change, `list` shows the rigs that run and none that
//! ended (one killed with -9), `stop` ends a run with the safe state and exit status 143, a
//! second run of a live rig is refused, and hostile clients cost the loop no tick. Only the
//! rig's owner speaks for it: a rig directory another uid made (in a private mount namespace)
//! or a socket others may write is refused, an impostor whose pid is not its hello's is not
//! believed, another uid is not served; a trickling client is cut off, a crowd of them does
//! not block `stop`, and a full house is told as such.

use crate::common;

use crate::common::rigs::Rigs;
use crate::common::{rigscript, stderr, stdout, until, SimProcess};
use serde_json::Value;
use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::net::UnixStream;
use std::process::{Child, Command};
use std::time::Duration;

/// `list --json`: the rigs the runtime directory holds.
fn list(rigs: &Rigs) -> Vec<Value> {
    let out = rigs.output(&["list", "--json"]);
    assert!(out.status.success(), "{out:?}");
    serde_json::from_slice::<Value>(&out.stdout)
        .unwrap()
        .as_array()
        .unwrap()
        .clone()
}

fn wait_exit(child: &mut Child) -> i32 {
    until(Duration::from_secs(20), || child.try_wait().unwrap())
        .expect("the run ended")
        .code()
        .unwrap_or(-1)
}

#[test]
fn status_follows_the_module_while_its_inputs_change_and_stop_ends_the_run_safe() {
    let rigs = Rigs::new("ctl-status");
    let mut sim = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let config = rigs.dir.file(
        "rig.toml",
        &format!(
            "name = \"bench-a\"\nperiod = \"20ms\"\n[devices.io]\nkind = \"trp-c29u\"\n\
             port = \"{}\"\nsafe_value = 0x40\nwatchdog = \"1s\"\n",
            sim.path
        ),
    );
    let script = rigs.dir.file(
        "mirror.rhai",
        "every(\"20ms\", || { io.outputs = io.inputs; let c = io.counters(); });\n",
    );
    let mut run = rigs.run(&["--config", &config, &script]);
    sim.control("di 0x05");
    let seen = until(Duration::from_secs(10), || {
        let s = rigs.status("bench-a");
        (s["devices"]["io"]["inputs"] == 5 && s["devices"]["io"]["outputs_written"] == 5)
            .then_some(s)
    })
    .expect("status shows the inputs and the outputs they drive");
    let module = sim.state();
    assert_eq!(module["do"], 5, "{module}");
    assert_eq!(seen["version"], 1);
    assert_eq!(seen["script"]["state"], "running");
    assert_eq!(seen["devices"]["io"]["kind"], "trp-c29u");
    assert_eq!(seen["devices"]["io"]["online"], true);
    assert_eq!(seen["devices"]["io"]["watchdog_ms"], 1000);
    // Inputs change: status follows, counters included.
    sim.control("di 0x0A");
    sim.control("pulse 2 7");
    let (seen, module) = until(Duration::from_secs(10), || {
        let s = rigs.status("bench-a");
        let module = sim.state();
        let io = &s["devices"]["io"];
        (io["inputs"] == 0x0A && io["counters"] == module["counters"] && module["do"] == 0x0A)
            .then_some((s, module))
    })
    .expect("status follows the inputs and the counters");
    assert!(
        seen["devices"]["io"]["counters"][2].as_u64() >= Some(7),
        "the pulses counted: {module}"
    );
    // The same for people.
    let text = rigs.output(&["status", "bench-a"]);
    let text = stdout(&text);
    assert!(text.contains("rig bench-a (pid "), "{text}");
    assert!(text.contains("DI 0-7: 0 1 0 1 0 0 0 0 (0x0a)"), "{text}");
    // A port the rig holds names the rig.
    let held = rigs.output(&["c29", "--port", &sim.path, "status"]);
    let said = stderr(&held);
    assert!(said.contains("rigscript status bench-a"), "{said}");
    // Stop: the safe state, the status of SIGTERM, and the module at its safe value.
    let stop = rigs.output(&["stop", "bench-a"]);
    let told = stdout(&stop);
    assert!(stop.status.success(), "{stop:?}");
    assert!(
        told.contains("exit status 143") && told.contains("safe state confirmed: io"),
        "{told}"
    );
    assert_eq!(wait_exit(&mut run), 143);
    let log = common::read_stderr(&mut run);
    assert!(log.contains("asked by rigscript stop (pid "), "{log}");
    assert_eq!(sim.state()["do"], 0x40);
    assert!(
        !rigs.socket("bench-a").exists(),
        "the socket went with the run"
    );
    let gone = rigs.output(&["status", "bench-a"]);
    assert_eq!(gone.status.code(), Some(3), "{gone:?}");
}

#[test]
fn list_shows_the_rigs_that_run_and_none_that_ended_one_of_them_killed() {
    let rigs = Rigs::new("ctl-list");
    let a = rigs.dir.file("alpha.rhai", "every(\"50ms\", || {});\n");
    let b = rigs.dir.file("beta.rhai", "every(\"50ms\", || {});\n");
    let mut alpha = rigs.run(&["--sim", &a]);
    let mut beta = rigs.run(&["--sim", &b]);
    let both = until(Duration::from_secs(10), || {
        let l = list(&rigs);
        (l.len() == 2).then_some(l)
    })
    .expect("both rigs listed");
    assert_eq!(both[0]["rig"], "alpha");
    assert_eq!(both[1]["rig"], "beta");
    assert_eq!(both[0]["pid"], alpha.id());
    assert_eq!(both[1]["state"], "running");
    // A second run of a script takes the next free name; one of a rig named in rig.toml is
    // refused, naming the first.
    let again = rigs.output(&["run", "--sim", "--for", "100ms", &a]);
    let said = stderr(&again);
    assert_eq!(again.status.code(), Some(0), "{said}");
    assert!(
        said.contains("rig alpha is running already: this run is rig alpha-2"),
        "{said}"
    );
    let named = rigs.dir.file(
        "named.toml",
        "name = \"gamma\"\n[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB9\"\n",
    );
    let mut gamma = rigs.run(&["--sim", "--config", &named, &a]);
    rigs.status("gamma");
    let refused = rigs.output(&["run", "--sim", "--config", &named, "--for", "1s", &a]);
    let said = stderr(&refused);
    assert_eq!(refused.status.code(), Some(3), "{said}");
    assert!(
        said.contains(&format!(
            "a rig called gamma is running already (pid {}",
            gamma.id()
        )),
        "{said}"
    );
    gamma.kill().unwrap();
    gamma.wait().unwrap();
    // Killed: its socket stays behind, and is never listed as running.
    alpha.kill().unwrap();
    alpha.wait().unwrap();
    assert!(rigs.socket("alpha").exists());
    let one = list(&rigs);
    assert_eq!(one.len(), 1, "{one:?}");
    assert_eq!(one[0]["rig"], "beta");
    assert!(
        !rigs.socket("alpha").exists(),
        "the stale socket was cleaned up"
    );
    let stopped = rigs.output(&["stop", "beta"]);
    assert!(stopped.status.success(), "{stopped:?}");
    assert_eq!(wait_exit(&mut beta), 143);
    assert!(list(&rigs).is_empty());
    let out = rigs.output(&["list"]);
    assert!(stdout(&out).contains("no rig is running"));
    // The killed rig's name is free again.
    let mut alpha = rigs.run(&["--sim", "--for", "300ms", &a]);
    assert_eq!(
        wait_exit(&mut alpha),
        0,
        "{}",
        common::read_stderr(&mut alpha)
    );
}

/// Connects to a rig's socket.
fn connect(rigs: &Rigs, rig: &str) -> UnixStream {
    let s = UnixStream::connect(rigs.socket(rig)).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    s
}

fn read_line(s: &UnixStream) -> String {
    let mut line = String::new();
    let _ = BufReader::new(s).read_line(&mut line);
    line
}

#[test]
fn hostile_clients_cost_the_loop_no_tick_and_are_told_what_is_wrong() {
    let rigs = Rigs::new("ctl-hostile");
    let script = rigs.dir.file(
        "steady.rhai",
        "every(\"200ms\", || { io.outputs = io.inputs; });\n",
    );
    let mut run = rigs.run(&["--sim", "--period", "200ms", &script]);
    let before = rigs.status("steady");
    // Garbage, and a line far past the limit: each told, then let go.
    let mut garbage = connect(&rigs, "steady");
    garbage.write_all(b"\x00\x01 not json\n").unwrap();
    let said = read_line(&garbage);
    assert!(
        said.contains("\"ok\":false") && said.contains("not a request"),
        "{said}"
    );
    let mut long = connect(&rigs, "steady");
    let chunk = vec![b'x'; 64 * 1024];
    // The run reads 4 KiB of it and hangs up; the rest is refused by a closed socket.
    let mut sent = 0usize;
    while sent < 1 << 30 && long.write_all(&chunk).is_ok() {
        sent += chunk.len();
    }
    assert!(sent < 1 << 30, "the run stopped reading the long line");
    // Hundreds of connections that send nothing hold no place against a request: each
    // newcomer takes the place of the client that has waited longest.
    let idle: Vec<UnixStream> = (0..300).map(|_| connect(&rigs, "steady")).collect();
    let out = rigs.output(&["status", "steady"]);
    assert!(
        out.status.success(),
        "answered past 300 idle clients: {out:?}"
    );
    // A run with a crowd at its socket keeps it: `list` leaves it, and another run of the
    // script takes the next name instead of this one.
    rigs.output(&["list"]);
    assert!(
        rigs.socket("steady").exists(),
        "a busy run's socket was removed"
    );
    let second = rigs.output(&["run", "--sim", "--for", "100ms", &script]);
    let said = stderr(&second);
    assert_eq!(second.status.code(), Some(0), "{said}");
    assert!(said.contains("this run is rig steady-2"), "{said}");
    assert!(rigs.socket("steady").exists());
    drop(idle);
    drop(garbage);
    drop(long);
    // The silent clients are let go within 5 s; then status answers again, ticks on.
    let after = until(Duration::from_secs(15), || {
        let s = rigs.status("steady");
        (s["ticks"]["count"].as_u64() > before["ticks"]["count"].as_u64()).then_some(s)
    })
    .expect("the loop ticks on");
    assert_eq!(after["script"]["state"], "running");
    assert!(
        after["ticks"]["count"].as_u64() > before["ticks"]["count"].as_u64(),
        "{after}"
    );
    assert_eq!(
        after["ticks"]["overruns"], before["ticks"]["overruns"],
        "no tick overran during the attack: {after}"
    );
    // A subscriber that never reads costs the loop nothing either (its events are dropped,
    // counted).
    let mut stalled = connect(&rigs, "steady");
    stalled.write_all(b"{\"request\":\"subscribe\"}\n").unwrap();
    let ticks = after["ticks"]["count"].as_u64().unwrap_or(0);
    let later = until(Duration::from_secs(15), || {
        let s = rigs.status("steady");
        (s["ticks"]["count"].as_u64() > Some(ticks + 10)).then_some(s)
    })
    .expect("the loop ticks on with a stalled subscriber");
    assert_eq!(
        later["ticks"]["overruns"], before["ticks"]["overruns"],
        "no tick overran with a stalled subscriber: {later}"
    );
    let stop = rigs.output(&["stop", "steady"]);
    assert!(stop.status.success(), "{stop:?}");
    assert_eq!(wait_exit(&mut run), 143);
    drop(stalled);
}

/// Clients that trickle a request into `path` a byte every 300 ms, never ending it; one let
/// go connects again. They stop when the returned flag is set.
fn tricklers(path: std::path::PathBuf, n: usize) -> std::sync::Arc<std::sync::atomic::AtomicBool> {
    use std::sync::atomic::{AtomicBool, Ordering};
    let stop = std::sync::Arc::new(AtomicBool::new(false));
    for _ in 0..n {
        let (stop, path) = (std::sync::Arc::clone(&stop), path.clone());
        std::thread::spawn(move || {
            while !stop.load(Ordering::SeqCst) {
                let Ok(mut s) = UnixStream::connect(&path) else {
                    std::thread::sleep(Duration::from_millis(100));
                    continue;
                };
                while !stop.load(Ordering::SeqCst) && s.write_all(b" ").is_ok() {
                    std::thread::sleep(Duration::from_millis(300));
                }
            }
        });
    }
    stop
}

#[test]
fn a_trickling_client_is_cut_off_a_crowd_of_them_does_not_block_stop_and_a_full_house_is_told() {
    let rigs = Rigs::new("ctl-trickle");
    let script = rigs.dir.file("steady.rhai", "every(\"200ms\", || {});\n");
    let mut run = rigs.run(&["--sim", "--period", "200ms", &script]);
    rigs.status("steady");
    // One trickler alone: told, and closed, once its request is 5 s old, whatever it sends.
    let mut slow = connect(&rigs, "steady");
    let started = std::time::Instant::now();
    let mut said = Vec::new();
    slow.set_nonblocking(true).unwrap();
    let closed = loop {
        let mut chunk = [0u8; 256];
        match slow.read(&mut chunk) {
            Ok(0) => break true,
            Ok(n) => said.extend_from_slice(&chunk[..n]),
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
            Err(_) => break true,
        }
        if started.elapsed() > Duration::from_secs(20) {
            break false;
        }
        if slow.write_all(b" ").is_err() {
            break true;
        }
        std::thread::sleep(Duration::from_millis(300));
    };
    let said = String::from_utf8_lossy(&said).to_string();
    assert!(closed, "a trickler was still served after 20 s: {said}");
    assert!(said.contains("within 5s of its first byte"), "{said:?}");
    // Sixteen subscribers, every place busy: the next is told the socket is full.
    let subscribers: Vec<UnixStream> = (0..16)
        .map(|_| {
            let mut s = connect(&rigs, "steady");
            s.write_all(b"{\"request\":\"subscribe\"}\n").unwrap();
            assert!(read_line(&s).contains("\"ok\":true"));
            s
        })
        .collect();
    let out = rigs.output(&["status", "steady"]);
    let said = stderr(&out);
    assert!(!out.status.success(), "{out:?}");
    assert!(
        said.contains("the rig's control socket is full (16 clients"),
        "a full house is told as such: {said}"
    );
    drop(subscribers);
    // Forty trickling clients, every place taken and taken again: `stop` gets through.
    let stop = tricklers(rigs.socket("steady"), 40);
    std::thread::sleep(Duration::from_secs(1));
    let out = rigs.output(&["stop", "steady"]);
    stop.store(true, std::sync::atomic::Ordering::SeqCst);
    let said = stdout(&out);
    assert!(out.status.success(), "stop past 40 tricklers: {out:?}");
    assert!(said.contains("rig steady stopped"), "{said}");
    assert_eq!(wait_exit(&mut run), 143);
}

#[test]
fn drive_acts_on_the_simulated_field_between_ticks_and_refuses_a_real_device() {
    let rigs = Rigs::new("ctl-drive");
    let script = rigs.dir.file(
        "knob.rhai",
        "panel.on_turn(\"S41A\", |d, v| { panel.relay = v % 8; });\n\
         every(\"20ms\", || { io.outputs = io.inputs; let p = panel.pressed(); });\n",
    );
    let mut run = rigs.run(&["--sim", &script]);
    rigs.status("knob");
    for args in [
        vec!["turn", "S41A", "+3"],
        vec!["press", "S12"],
        vec!["set-input", "io", "3", "on"],
        vec!["pulse", "io", "2", "4"],
    ] {
        let out = rigs.output(&[&["drive", "knob"], &args[..]].concat());
        assert!(out.status.success(), "{args:?}: {out:?}");
    }
    let seen = until(Duration::from_secs(10), || {
        let s = rigs.status("knob");
        let (io, panel) = (&s["devices"]["io"], &s["devices"]["panel"]);
        (panel["relay_written"] == 3
            && panel["pressed"] == serde_json::json!(["S12"])
            && io["outputs_written"] == 0x08)
            .then_some(s)
    })
    .expect("the script saw the knob, the switch and the input");
    assert_eq!(seen["devices"]["panel"]["relay"], 3);
    let bad = rigs.output(&["drive", "knob", "press", "S99"]);
    assert_eq!(bad.status.code(), Some(1));
    assert!(stderr(&bad).contains("S99"), "{bad:?}");
    let none = rigs.output(&["drive", "knob", "fail", "pump"]);
    assert!(
        stderr(&none).contains("pump is not a simulated device"),
        "{none:?}"
    );
    assert_eq!(rigs.output(&["stop", "knob"]).status.code(), Some(0));
    assert_eq!(wait_exit(&mut run), 143);
    // A rig of real devices is not driven.
    let mut sim = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let config = rigs.dir.file(
        "real.toml",
        &format!(
            "[devices.io]\nkind = \"trp-c29u\"\nport = \"{}\"\nwatchdog = \"1s\"\n",
            sim.path
        ),
    );
    let real = rigs.dir.file(
        "real.rhai",
        "every(\"20ms\", || { io.outputs = io.inputs; });\n",
    );
    let mut run = rigs.run(&["--config", &config, &real]);
    rigs.status("real");
    let refused = rigs.output(&["drive", "real", "set-inputs", "io", "0xff"]);
    assert_eq!(refused.status.code(), Some(1));
    assert!(
        stderr(&refused).contains("drive acts on simulators only"),
        "{refused:?}"
    );
    assert_eq!(sim.state()["di"], 0, "the module's inputs were not touched");
    assert_eq!(rigs.output(&["stop", "real"]).status.code(), Some(0));
    assert_eq!(wait_exit(&mut run), 143);
}

/// A shell script that answers the control protocol as a rig called `rig` whose process id
/// is `pid` would, and says, when asked to stop, that it stopped safe: an impostor.
fn impostor(rig: &str, pid: u32) -> String {
    format!(
        "#!/bin/sh\nwhile read -r line; do case \"$line\" in\n\
         *hello*) echo '{{\"ok\":true,\"hello\":{{\"protocol\":1,\"rig\":\"{rig}\",\"pid\":{pid},\
         \"script\":\"fake.rhai\",\"config\":null,\"started\":\"2026-01-01T00:00:00Z\"}}}}';;\n\
         *subscribe*) echo '{{\"ok\":true}}'; sleep 1; echo '{{\"event\":\"ended\",\"status\":143,\
         \"safe\":[\"io\"],\"unconfirmed\":[]}}';;\n\
         *) echo '{{\"ok\":true}}';;\n\
         esac; done\n"
    )
}

/// Fails loudly unless the tests run as root with the tools a second uid and a private mount
/// namespace take.
fn require_root() {
    common::require_root(&["setpriv", "unshare"]);
    common::require_tool("socat", "socat");
}

#[test]
#[ignore = "needs root, setpriv, unshare and socat (tier 2: CI runs .ci/run as root)"]
fn root_refuses_a_rig_directory_another_user_made_and_never_believes_its_socket() {
    require_root();
    let rigs = Rigs::new("ctl-foreign");
    let responder = rigs.dir.file("impostor.sh", &impostor("interlock", 1));
    // In a private mount namespace with a /tmp of its own: the machine's is never touched. The
    // binary and the script are opened before that /tmp hides them (a checkout, and so the
    // binary under test, may itself live under /tmp), then copied into it.
    let script = format!(
        "set -e\n\
         impostor=\"$(cat {responder})\"\n\
         exec 3<{bin} 4<{script}\n\
         mount -t tmpfs tmpfs /tmp\n\
         cat /proc/self/fd/3 >/tmp/rigscript-under-test\n\
         chmod 755 /tmp/rigscript-under-test\n\
         cat /proc/self/fd/4 >/tmp/interlock.rhai\n\
         exec 3<&- 4<&-\n\
         printf '%s\\n' \"$impostor\" >/tmp/impostor.sh\n\
         chmod 755 /tmp/impostor.sh\n\
         setpriv --reuid=65534 --regid=65534 --clear-groups sh -c \
           'mkdir -m 700 /tmp/rigscript-0 && exec socat UNIX-LISTEN:/tmp/rigscript-0/interlock.sock,fork EXEC:/tmp/impostor.sh' \
           </dev/null >/dev/null 2>&1 &\n\
         fake=$!\n\
         for i in $(seq 50); do [ -S /tmp/rigscript-0/interlock.sock ] && break; sleep 0.1; done\n\
         set +e\n\
         bin=/tmp/rigscript-under-test\n\
         env -u XDG_RUNTIME_DIR -u RUNTIME_DIRECTORY $bin stop interlock; echo \"stop=$?\"\n\
         env -u XDG_RUNTIME_DIR -u RUNTIME_DIRECTORY $bin list; echo \"list=$?\"\n\
         env -u XDG_RUNTIME_DIR -u RUNTIME_DIRECTORY $bin run --sim --for 300ms /tmp/interlock.rhai 2>&1; \
           echo \"run=$?\"\n\
         echo \"left: $(ls /tmp/rigscript-0)\"\n\
         kill $fake\n",
        bin = rigscript(),
        script = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/interlock.rhai"),
    );
    let out = Command::new("unshare")
        .args(["--mount", "--propagation", "private", "sh", "-c", &script])
        .output()
        .unwrap();
    let (said, err) = (stdout(&out), stderr(&out));
    assert!(said.contains("stop=3"), "root's stop: {said}\n{err}");
    assert!(!said.contains("safe state confirmed"), "{said}");
    assert!(
        err.contains("/tmp/rigscript-0 belongs to uid 65534 (mode 0700)"),
        "the refusal names the directory, its owner and mode: {err}"
    );
    assert!(said.contains("list=0"), "{said}\n{err}");
    assert!(
        !said.contains("fake.rhai"),
        "list showed the impostor: {said}"
    );
    // Root's own run does not put its socket there: it runs, and says it cannot be seen.
    assert!(said.contains("run=0"), "{said}");
    assert!(
        said.contains("warning: cannot make the control socket")
            && said.contains("/tmp/rigscript-0 belongs to uid 65534"),
        "{said}"
    );
    assert!(said.contains("left: interlock.sock\n"), "{said}");
}

#[test]
#[ignore = "needs socat (tier 2: .ci/run installs it)"]
fn stop_believes_only_the_process_its_hello_names() {
    common::require_tool("socat", "socat");
    let rigs = Rigs::new("ctl-impostor");
    let responder = rigs.dir.file("impostor.sh", &impostor("interlock", 1));
    std::fs::set_permissions(
        &responder,
        std::os::unix::fs::PermissionsExt::from_mode(0o755),
    )
    .unwrap();
    let dir = rigs.dir.path("rigscript");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::set_permissions(&dir, std::os::unix::fs::PermissionsExt::from_mode(0o700)).unwrap();
    let socket = rigs.socket("interlock");
    let mut fake = Command::new("socat")
        .arg(format!("UNIX-LISTEN:{},fork", socket.display()))
        .arg(format!("EXEC:{responder}"))
        .spawn()
        .unwrap();
    until(Duration::from_secs(5), || socket.exists().then_some(())).expect("the impostor listens");
    let out = rigs.output(&["stop", "interlock"]);
    let list = list(&rigs);
    let _ = fake.kill();
    let _ = fake.wait();
    let (said, err) = (stdout(&out), stderr(&out));
    assert!(!out.status.success(), "{said}");
    assert!(!said.contains("safe state confirmed"), "{said}");
    assert!(err.contains("is not the rig it names (pid 1"), "{err}");
    assert!(list.is_empty(), "{list:?}");
}

#[test]
#[ignore = "needs root, setpriv and socat (tier 2: CI runs .ci/run as root)"]
fn a_socket_opened_to_others_still_serves_only_its_user_and_root() {
    require_root();
    let rigs = Rigs::new("ctl-others");
    let script = rigs.dir.file("steady.rhai", "every(\"200ms\", || {});\n");
    let mut run = rigs.run(&["--sim", "--period", "200ms", &script]);
    rigs.status("steady");
    // Someone loosened the modes: the kernel lets another user connect; the run does not
    // serve it.
    let dir = rigs.dir.path("rigscript");
    for (path, mode) in [
        (rigs.dir.root(), 0o711),
        (&dir, 0o711),
        (&rigs.socket("steady"), 0o666),
    ] {
        std::fs::set_permissions(path, std::os::unix::fs::PermissionsExt::from_mode(mode)).unwrap();
    }
    // Reading only: the run answers before any request.
    let out = common::as_nobody(
        "socat",
        &[
            "-u",
            &format!("UNIX-CONNECT:{}", rigs.socket("steady").display()),
            "-",
        ],
    );
    let said = stdout(&out);
    assert!(
        said.contains("only the rig's user (and root) may use its control socket"),
        "{said} {}",
        stderr(&out)
    );
    // Nor does its owner's client believe a socket others may write.
    let stop = rigs.output(&["stop", "steady"]);
    let said = stderr(&stop);
    assert!(!stop.status.success(), "{said}");
    assert!(
        said.contains("steady.sock is writable by others (mode 0666"),
        "{said}"
    );
    std::fs::set_permissions(
        rigs.socket("steady"),
        std::os::unix::fs::PermissionsExt::from_mode(0o600),
    )
    .unwrap();
    let stop = rigs.output(&["stop", "steady"]);
    assert!(
        stop.status.success(),
        "the run went on, its owner stops it: {stop:?}"
    );
    assert_eq!(wait_exit(&mut run), 143);
}
