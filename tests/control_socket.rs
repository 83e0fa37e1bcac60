//! The control socket against real `rigscript run` processes: `status --json` follows the
//! module on a real pty while its inputs change, `list` shows the rigs that run and none that
//! ended (one killed with -9), `stop` ends a run with the safe state and exit status 143, a
//! second run of a live rig is refused, and hostile clients cost the loop no tick.

mod common;

use common::{rigscript, until, SimProcess, TempDir};
use serde_json::Value;
use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::net::UnixStream;
use std::process::{Child, Command, Output, Stdio};
use std::time::Duration;

/// A rig directory of the test's own, so runs of other tests are not seen.
struct Rigs {
    dir: TempDir,
}

impl Rigs {
    fn new(tag: &str) -> Self {
        Self {
            dir: TempDir::new(tag),
        }
    }

    fn command(&self, args: &[&str]) -> Command {
        let mut c = Command::new(rigscript());
        c.args(args).env("XDG_RUNTIME_DIR", &self.dir.0);
        c.env_remove("RUNTIME_DIRECTORY");
        c
    }

    fn run(&self, args: &[&str]) -> Run {
        Run(self
            .command(&[&["run"], args].concat())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap())
    }

    fn output(&self, args: &[&str]) -> Output {
        self.command(args).output().unwrap()
    }

    fn socket(&self, rig: &str) -> std::path::PathBuf {
        self.dir.path("rigscript").join(format!("{rig}.sock"))
    }

    /// `status RIG --json`, once it answers (the run may still be starting).
    fn status(&self, rig: &str) -> Value {
        let out = until(Duration::from_secs(10), || {
            let out = self.output(&["status", rig, "--json"]);
            out.status.success().then_some(out)
        })
        .unwrap_or_else(|| panic!("rig {rig} never answered status"));
        serde_json::from_slice(&out.stdout).unwrap()
    }

    fn list(&self) -> Vec<Value> {
        let out = self.output(&["list", "--json"]);
        assert!(out.status.success(), "{out:?}");
        serde_json::from_slice::<Value>(&out.stdout)
            .unwrap()
            .as_array()
            .unwrap()
            .clone()
    }
}

/// A run the test started, killed if the test fails before it ends.
struct Run(Child);

impl std::ops::Deref for Run {
    type Target = Child;
    fn deref(&self) -> &Child {
        &self.0
    }
}

impl std::ops::DerefMut for Run {
    fn deref_mut(&mut self) -> &mut Child {
        &mut self.0
    }
}

impl Drop for Run {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

fn wait_exit(child: &mut Child) -> i32 {
    until(Duration::from_secs(20), || child.try_wait().unwrap())
        .expect("the run ended")
        .code()
        .unwrap_or(-1)
}

fn stderr_of(child: &mut Child) -> String {
    let mut text = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut text)
        .unwrap();
    text
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
    let text = String::from_utf8_lossy(&text.stdout).to_string();
    assert!(text.contains("rig bench-a (pid "), "{text}");
    assert!(text.contains("DI 0-7: 0 1 0 1 0 0 0 0 (0x0a)"), "{text}");
    // A port the rig holds names the rig.
    let held = rigs.output(&["c29", "--port", &sim.path, "status"]);
    let said = String::from_utf8_lossy(&held.stderr).to_string();
    assert!(said.contains("rigscript status bench-a"), "{said}");
    // Stop: the safe state, the status of SIGTERM, and the module at its safe value.
    let stop = rigs.output(&["stop", "bench-a"]);
    let told = String::from_utf8_lossy(&stop.stdout).to_string();
    assert!(stop.status.success(), "{stop:?}");
    assert!(
        told.contains("exit status 143") && told.contains("safe state confirmed: io"),
        "{told}"
    );
    assert_eq!(wait_exit(&mut run), 143);
    let log = stderr_of(&mut run);
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
        let l = rigs.list();
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
    let said = String::from_utf8_lossy(&again.stderr).to_string();
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
    let said = String::from_utf8_lossy(&refused.stderr).to_string();
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
    let one = rigs.list();
    assert_eq!(one.len(), 1, "{one:?}");
    assert_eq!(one[0]["rig"], "beta");
    assert!(
        !rigs.socket("alpha").exists(),
        "the stale socket was cleaned up"
    );
    let stopped = rigs.output(&["stop", "beta"]);
    assert!(stopped.status.success(), "{stopped:?}");
    assert_eq!(wait_exit(&mut beta), 143);
    assert!(rigs.list().is_empty());
    let out = rigs.output(&["list"]);
    assert!(String::from_utf8_lossy(&out.stdout).contains("no rig is running"));
    // The killed rig's name is free again.
    let mut alpha = rigs.run(&["--sim", "--for", "300ms", &a]);
    assert_eq!(wait_exit(&mut alpha), 0, "{}", stderr_of(&mut alpha));
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
    // Hundreds of connections that send nothing: 16 are served, the others told so.
    let idle: Vec<UnixStream> = (0..300).map(|_| connect(&rigs, "steady")).collect();
    let refused = idle
        .iter()
        .skip(20)
        .take(5)
        .map(read_line)
        .filter(|l| l.contains("clients are connected to this rig already"))
        .count();
    assert_eq!(refused, 5, "connections past the limit are told so");
    // A run that cannot answer for its clients keeps its socket: `list` leaves it, and another
    // run of the script takes the next name instead of this one.
    rigs.output(&["list"]);
    assert!(
        rigs.socket("steady").exists(),
        "a busy run's socket was removed"
    );
    let second = rigs.output(&["run", "--sim", "--for", "100ms", &script]);
    let said = String::from_utf8_lossy(&second.stderr).to_string();
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
    // counted). It connects once the flood is gone: while every client slot was taken it was
    // refused and closed, and its request could meet a closed socket.
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
    assert!(
        String::from_utf8_lossy(&bad.stderr).contains("S99"),
        "{bad:?}"
    );
    let none = rigs.output(&["drive", "knob", "fail", "pump"]);
    assert!(
        String::from_utf8_lossy(&none.stderr).contains("pump is not a simulated device"),
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
        String::from_utf8_lossy(&refused.stderr).contains("drive acts on simulators only"),
        "{refused:?}"
    );
    assert_eq!(sim.state()["di"], 0, "the module's inputs were not touched");
    assert_eq!(rigs.output(&["stop", "real"]).status.code(), Some(0));
    assert_eq!(wait_exit(&mut run), 143);
}
