//! `rigscript c29` as a person runs it: the real binary against `rigscript sim c29u` on a real
//! pseudo-terminal. Every command in both protocols, ASCII with and without checksums, and on a
//! line shared by two modules; then the faults: silence, garbled answers, the wrong ID, a
//! simulator that dies under `monitor`, and a port that does not exist.

use crate::common::{rigscript, stderr, stdout, SimProcess};
use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::process::{Command, Output, Stdio};
use std::sync::mpsc;
use std::time::Duration;

/// How the simulated line is set up and which module the commands address.
#[derive(Clone, Copy)]
struct Flavor {
    protocol: &'static str,
    checksum: bool,
    /// Module IDs on the line.
    ids: &'static str,
    /// The module the commands talk to.
    target: u8,
    /// Also show that host OK keeps the watchdog from expiring (takes a second).
    keepalive: bool,
}

/// What one `rigscript c29` run printed and how it ended.
struct Run {
    status: i32,
    stdout: String,
    stderr: String,
}

impl Run {
    fn from(out: Output) -> Self {
        Self {
            status: out.status.code().unwrap_or(-1),
            stdout: stdout(&out),
            stderr: stderr(&out),
        }
    }

    fn ok(self, what: &str) -> Self {
        assert_eq!(
            self.status, 0,
            "`{what}` failed:\n{}\n{}",
            self.stdout, self.stderr
        );
        self
    }

    fn json(&self) -> Value {
        assert_eq!(
            self.stdout.lines().count(),
            1,
            "one JSON document: {}",
            self.stdout
        );
        serde_json::from_str(&self.stdout)
            .unwrap_or_else(|e| panic!("not JSON ({e}): {}", self.stdout))
    }
}

/// A simulator and the options that reach the module under test.
struct Rig {
    sim: SimProcess,
    flavor: Flavor,
}

impl Rig {
    fn start(flavor: Flavor, extra: &[&str]) -> Self {
        let mut args = vec!["--protocol", flavor.protocol, "--id", flavor.ids];
        if flavor.checksum {
            args.push("--checksum");
        }
        args.extend_from_slice(extra);
        Self {
            sim: SimProcess::start(&args),
            flavor,
        }
    }

    fn base(&self, id: u8) -> Vec<String> {
        let mut base: Vec<String> = [
            "c29",
            "--port",
            &self.sim.path,
            "--protocol",
            self.flavor.protocol,
            "--timeout",
            "300",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        base.extend(["--id".to_string(), id.to_string()]);
        if self.flavor.checksum {
            base.push("--checksum".into());
        }
        base
    }

    /// Runs `rigscript c29 ARGS` at the module's ID.
    fn c29(&self, args: &[&str]) -> Run {
        self.c29_at(self.flavor.target, args)
    }

    fn c29_at(&self, id: u8, args: &[&str]) -> Run {
        let out = Command::new(rigscript())
            .args(self.base(id))
            .args(args)
            .stdin(Stdio::null())
            .output()
            .expect("run rigscript c29");
        Run::from(out)
    }

    fn ok(&self, args: &[&str]) -> Run {
        self.c29(args).ok(&args.join(" "))
    }

    fn json(&self, args: &[&str]) -> Value {
        let mut all = vec!["--json"];
        all.extend_from_slice(args);
        self.ok(&all).json()
    }

    /// A control line for the module under test.
    fn control(&mut self, line: &str) {
        let reply = self.sim.control(&format!("@{} {line}", self.flavor.target));
        assert_eq!(reply, "ok", "control `{line}`");
    }

    fn state(&mut self) -> Value {
        self.state_of(self.flavor.target)
    }

    fn state_of(&mut self, id: u8) -> Value {
        let line = self.sim.control(&format!("@{id} state"));
        serde_json::from_str(&line).unwrap_or_else(|e| panic!("state is not JSON ({e}): {line}"))
    }

    fn ascii(&self) -> bool {
        self.flavor.protocol == "ascii"
    }
}

const MODBUS: Flavor = Flavor {
    protocol: "modbus",
    checksum: false,
    ids: "1",
    target: 1,
    keepalive: true,
};
const ASCII: Flavor = Flavor {
    protocol: "ascii",
    checksum: false,
    ids: "1",
    target: 1,
    keepalive: true,
};
const ASCII_CHECKSUM: Flavor = Flavor {
    protocol: "ascii",
    checksum: true,
    ids: "1",
    target: 1,
    keepalive: false,
};
const MODBUS_SHARED: Flavor = Flavor {
    protocol: "modbus",
    checksum: false,
    ids: "1,2",
    target: 2,
    keepalive: false,
};
const ASCII_SHARED: Flavor = Flavor {
    protocol: "ascii",
    checksum: true,
    ids: "1,2",
    target: 2,
    keepalive: false,
};

/// Inputs and outputs: status, do, set, with JSON and the simulator agreeing.
fn io_commands(r: &mut Rig) {
    r.control("di 0x05");
    let text = r.ok(&["status"]).stdout;
    assert!(
        text.contains("DI    0x05  00000101  energized: DI0 DI2"),
        "{text}"
    );
    assert!(text.contains("DO    0x00  00000000  on: none"), "{text}");
    let v = r.json(&["status"]);
    assert_eq!((v["di"].as_u64(), v["do"].as_u64()), (Some(5), Some(0)));
    assert_eq!(v["di_raw"], 0xFA, "active-low on the wire");

    r.ok(&["do", "0x21"]);
    assert_eq!(r.state()["do"], 0x21);
    let text = r.ok(&["do"]).stdout;
    assert!(text.contains("0x21  00100001  on: DO0 DO5"), "{text}");
    assert_eq!(r.json(&["do"])["do"], 0x21);

    let v = r.json(&["set", "7", "on"]);
    assert_eq!(v["do"], 0xA1);
    r.ok(&["set", "0", "off"]);
    assert_eq!(r.state()["do"], 0xA0);
}

/// Counters, clearing, saving to EEPROM, latches.
fn counter_and_latch_commands(r: &mut Rig) {
    r.control("pulse 3 5");
    r.control("pulse 6 2");
    let v = r.json(&["counters"]);
    assert_eq!(v["counters"][3], 5);
    assert_eq!(v["counters"][6], 2);
    assert!(r.ok(&["counters"]).stdout.contains("DI3  5\n"));

    r.ok(&["clear-counters", "3"]);
    let state = r.state();
    assert_eq!(
        (state["counters"][3].as_u64(), state["counters"][6].as_u64()),
        (Some(0), Some(2))
    );
    r.ok(&["clear-counters"]);
    assert_eq!(r.state()["counters"][6], 0);

    r.control("pulse 4 7");
    r.ok(&["save-counters"]);
    r.control("pulse 4 1");
    r.control("reset");
    assert_eq!(
        r.json(&["counters"])["counters"][4],
        7,
        "saved count survives a power cycle, the unsaved pulse does not"
    );

    r.ok(&["clear-latch"]);
    r.control("di 0x0C"); // DI0 released, DI3 energized (DI2 stays)
    let v = r.json(&["latch"]);
    let state = r.state();
    assert_eq!(v["low"], state["latched_low"]);
    assert_eq!(v["high"], state["latched_high"]);
    assert_eq!(
        (v["low"].as_u64(), v["high"].as_u64()),
        (Some(0x08), Some(0x01))
    );
    assert!(r
        .ok(&["latch"])
        .stdout
        .contains("low   0x08  00001000  latched: DI3"));
    r.ok(&["clear-latch"]);
    let state = r.state();
    assert_eq!(
        (
            state["latched_low"].as_u64(),
            state["latched_high"].as_u64()
        ),
        (Some(0), Some(0))
    );
}

/// Safe and power-on values, reset, host watchdog with host OK, expiry and safe mode.
fn preset_and_watchdog_commands(r: &mut Rig) {
    r.ok(&["do", "0x30"]);
    if r.flavor.protocol == "ascii" {
        // ASCII stores only the current outputs: another value needs --drive-outputs.
        let refused = r.c29(&["safe-value", "0x0F"]);
        assert_eq!(refused.status, 2, "{}", refused.stderr);
        assert!(
            refused.stderr.contains("--drive-outputs"),
            "{}",
            refused.stderr
        );
        assert_eq!(r.state()["safe_value"], 0x00);
        // The value the outputs hold is stored as it is.
        r.ok(&["power-on-value", "0x30"]);
        assert_eq!(r.state()["power_on_value"], 0x30);
    }
    let text = r.ok(&["safe-value", "0x0F", "--drive-outputs"]).stdout;
    assert!(text.contains("safe  0x0F  00001111"), "{text}");
    r.ok(&["power-on-value", "0x42", "--drive-outputs"]);
    let state = r.state();
    assert_eq!(state["safe_value"], 0x0F);
    assert_eq!(state["power_on_value"], 0x42);
    assert_eq!(state["do"], 0x30, "outputs restored after storing presets");
    assert_eq!(r.json(&["safe-value"])["safe_value"], 0x0F);
    assert_eq!(r.json(&["power-on-value"])["power_on_value"], 0x42);

    r.ok(&["reset"]);
    assert_eq!(r.state()["do"], 0x42, "reset loads the power-on value");

    assert!(r.ok(&["watchdog"]).stdout.contains("disabled"));
    if r.flavor.keepalive {
        // 2 s: each `host-ok` below is a process of its own, which a loaded machine may take
        // most of a second to start; the watchdog's margin is not what is tested here.
        r.ok(&["watchdog", "2.0"]);
        let wd = &r.state()["watchdog"];
        assert_eq!(
            (wd["enabled"].as_bool(), wd["timeout_ms"].as_u64()),
            (Some(true), Some(2000))
        );
        assert_eq!(r.json(&["watchdog"])["timeout_tenths"], 20);
        // Host OK every 0.5 s for 2.5 s keeps a 2 s watchdog from expiring.
        for _ in 0..5 {
            std::thread::sleep(Duration::from_millis(500));
            r.ok(&["host-ok"]);
        }
        assert_eq!(
            r.state()["watchdog"]["expired"],
            false,
            "host OK kept it alive"
        );
        std::thread::sleep(Duration::from_millis(2500));
    } else {
        r.ok(&["watchdog", "0.2"]);
        assert_eq!(r.json(&["watchdog"])["timeout_tenths"], 2);
        r.ok(&["host-ok"]);
        std::thread::sleep(Duration::from_millis(400));
    }
    let state = r.state();
    assert_eq!(state["watchdog"]["expired"], true);
    assert_eq!(state["do"], 0x0F, "expired: outputs at the safe value");

    let refused = r.c29(&["set", "1", "on"]);
    assert_eq!(refused.status, 1, "{}", refused.stderr);
    assert!(refused.stderr.contains("safe mode"), "{}", refused.stderr);
    assert!(
        refused.stderr.contains("watchdog off"),
        "says what to do: {}",
        refused.stderr
    );
    let refused = r.c29(&["do", "0"]);
    assert_eq!(refused.status, 1);
    assert_eq!(refused.json_error_or_none(), None);
    let v = {
        let run = r.c29(&["--json", "set", "1", "on"]);
        assert_eq!(run.status, 1);
        run.json()
    };
    assert_eq!(v["status"], 1);
    assert!(v["error"].as_str().unwrap().contains("safe mode"));

    r.ok(&["watchdog", "off"]);
    assert_eq!(r.state()["watchdog"]["enabled"], false);
    r.ok(&["set", "4", "on"]);
    assert_eq!(r.state()["do"], 0x1F);
}

impl Run {
    /// The JSON error document on standard output, if there is one.
    fn json_error_or_none(&self) -> Option<Value> {
        serde_json::from_str(&self.stdout).ok()
    }
}

/// Identity, raw frames, tracing; name and configuration last (they change how to reach it).
fn identity_and_config_commands(r: &mut Rig) {
    let target = r.flavor.target;
    let v = r.json(&["info"]);
    assert_eq!(v["id"], target);
    assert_eq!(v["baud"], 9600);
    assert_eq!(v["firmware"]["date"], "2009-07-03");
    assert_eq!(v["watchdog"]["enabled"], false);
    assert!(v["reset"].is_boolean());
    assert_eq!(
        r.json(&["info"])["reset"],
        false,
        "reading the flag cleared it"
    );
    let text = r.ok(&["info"]).stdout;
    assert!(text.contains("firmware"), "{text}");
    assert!(text.contains("watchdog  disabled"), "{text}");

    // Raw frames and traces: one known request each way.
    if r.ascii() {
        let id = format!("{target:02X}");
        let text = r.ok(&["raw", &format!("${id}6")]).stdout;
        // DO 0x1F, DI2 and DI3 energized: 0xF3 on the wire.
        assert!(text.contains(&format!("\"!{id}1FF3")), "{text}");
        let run = r.ok(&["--trace", "status"]);
        let sent = if r.flavor.checksum {
            let sum = format!("${id}6").bytes().map(u32::from).sum::<u32>() & 0xFF;
            format!("\"${id}6{sum:02X}\\r\"")
        } else {
            format!("\"${id}6\\r\"")
        };
        assert!(
            run.stderr.contains(&format!(
                ">> 24 {} {} 36",
                hex(id.as_bytes()[0]),
                hex(id.as_bytes()[1])
            )),
            "{}",
            run.stderr
        );
        assert!(run.stderr.contains(&sent), "{sent} in {}", run.stderr);
        assert!(run.stderr.contains("<< 21 "), "{}", run.stderr);
        assert_eq!(
            r.json(&["raw", &format!("${id}M")])["text"],
            format!("!{id}TRPC29{}\r", checksum_of(r, &format!("!{id}TRPC29")))
        );
    } else {
        let frame = format!("{target:02X} 01 00 20 00 08");
        let v = r.json(&["raw", &frame]);
        assert!(
            v["answer"]
                .as_str()
                .unwrap()
                .starts_with(&format!("{target:02X} 01 01 F3")),
            "{v}"
        );
        let run = r.ok(&["--trace", "status"]);
        assert!(
            run.stderr.contains(&format!(">> {frame} ")),
            "{}",
            run.stderr
        );
        assert!(
            run.stderr.contains(&format!("<< {target:02X} 01 01 F3")),
            "{}",
            run.stderr
        );
    }

    if r.ascii() {
        r.ok(&["name", "PUMP1"]);
        assert_eq!(r.state()["name"], "PUMP1");
        assert_eq!(r.ok(&["name"]).stdout, "PUMP1\n");
    } else {
        assert_eq!(r.ok(&["name"]).stdout, "C29\n");
        let run = r.c29(&["name", "PUMP1"]);
        assert_eq!(run.status, 1);
        assert!(run.stderr.contains("not available"), "{}", run.stderr);
        assert!(
            run.stderr.contains("ASCII"),
            "says what to do: {}",
            run.stderr
        );
    }

    if r.ascii() {
        let v = r.json(&[
            "configure",
            "--counter-edge",
            "falling",
            "--hex-counters",
            "on",
        ]);
        assert_eq!(v["counter_edge"], "falling");
        assert_eq!(r.json(&["info"])["counter_edge"], "falling");
        let flip = if r.flavor.checksum { "off" } else { "on" };
        let v = r.json(&["configure", "--set-checksum", flip]);
        assert_eq!(v["checksum"], !r.flavor.checksum);
        // The module now wants the other checksum setting: the old options fail. Without a
        // checksum a module that wants one stays silent; with one, a module that wants none
        // answers without, which fails the answer's checksum test.
        let run = r.c29(&["--timeout", "50", "--retries", "0", "status"]);
        if r.flavor.checksum {
            assert_eq!(run.status, 1, "{}", run.stderr);
            assert!(run.stderr.contains("checksum"), "{}", run.stderr);
        } else {
            assert_eq!(run.status, 3, "{}", run.stderr);
        }
        r.flavor.checksum = !r.flavor.checksum;
        r.ok(&["status"]);
    } else {
        let run = r.c29(&["configure", "--set-checksum", "on"]);
        assert_eq!(run.status, 1);
        assert!(run.stderr.contains("not available"), "{}", run.stderr);
        let v = r.json(&["configure", "--new-baud", "19200"]);
        assert_eq!(v["baud"], 19200);
        let v = r
            .c29(&["--json", "--baud", "19200", "info"])
            .ok("info at 19200")
            .json();
        assert_eq!(v["baud"], 19200);
    }

    let text = r.ok(&["configure", "--new-id", "5"]).stdout;
    assert!(text.contains("--id 5"), "says how to reach it now: {text}");
    assert_eq!(r.state()["id"], 5);
    let at5 = r
        .c29_at(5, &["--json", "status"])
        .ok("status at ID 5")
        .json();
    assert_eq!(at5["do"], 0x1F);
    let old = r.c29_at(target, &["--timeout", "50", "--retries", "0", "status"]);
    assert_eq!(old.status, 3, "the old ID is silent now: {}", old.stderr);
}

fn hex(b: u8) -> String {
    format!("{b:02X}")
}

/// The two checksum digits `r`'s module adds to an answer, or nothing.
fn checksum_of(r: &Rig, text: &str) -> String {
    if r.flavor.checksum {
        format!("{:02X}", text.bytes().map(u32::from).sum::<u32>() & 0xFF)
    } else {
        String::new()
    }
}

fn every_command(flavor: Flavor) {
    let mut r = Rig::start(flavor, &[]);
    io_commands(&mut r);
    counter_and_latch_commands(&mut r);
    preset_and_watchdog_commands(&mut r);
    identity_and_config_commands(&mut r);
    if flavor.ids.contains(',') {
        // The other module on the line heard every frame and did nothing it was not told
        // (it keeps the settings the line started with).
        r.flavor = flavor;
        let other = r.state_of(1);
        assert_eq!(other["id"], 1);
        assert_eq!(other["do"], 0);
        assert_eq!(
            other["counters"],
            serde_json::json!([0, 0, 0, 0, 0, 0, 0, 0])
        );
        assert_eq!(other["safe_value"], 0);
        assert_eq!(other["name"], "TRPC29");
        let run = r.c29_at(1, &["--json", "status"]).ok("status of module 1");
        assert_eq!(run.json()["di"], 0);
    }
}

#[test]
fn every_command_modbus() {
    every_command(MODBUS);
}

#[test]
fn every_command_ascii_without_checksum() {
    every_command(ASCII);
}

#[test]
fn every_command_ascii_with_checksum() {
    every_command(ASCII_CHECKSUM);
}

#[test]
fn every_command_modbus_two_modules_on_one_line() {
    every_command(MODBUS_SHARED);
}

#[test]
fn every_command_ascii_two_modules_on_one_line() {
    every_command(ASCII_SHARED);
}

#[test]
fn usage_errors_exit_2_and_say_what_to_write() {
    let r = Rig::start(MODBUS, &[]);
    for (args, says) in [
        (&["set", "9", "on"][..], "0..=7"),
        (&["do", "300"], "not a byte"),
        (&["watchdog", "30"], "25.5 s"),
        (&["--id", "0", "status"], "1-247"),
        (&["raw", "$016"], "hex"),
    ] {
        let run = r.c29(args);
        assert_eq!(run.status, 2, "{args:?}: {}", run.stderr);
        assert!(run.stderr.contains(says), "{args:?}: {}", run.stderr);
    }
    let out = Command::new(rigscript())
        .args(["c29", "status"])
        .output()
        .unwrap();
    let run = Run::from(out);
    assert_eq!(run.status, 2);
    assert!(run.stderr.contains("--port is required"), "{}", run.stderr);
}

#[test]
fn a_raw_frame_longer_than_the_protocol_allows_is_refused_unsent() {
    for (flavor, fits, too_long, says) in [
        (
            MODBUS,
            format!("01 0F 00 00 00 08 01 {}", "00 ".repeat(247)),
            "01 ".repeat(5000),
            "a raw frame of 5000 bytes is too long: at most 254",
        ),
        (
            ASCII,
            "%0101400600".to_string(),
            "$".repeat(5000),
            "a raw frame of 5000 characters is too long: at most 11",
        ),
    ] {
        let r = Rig::start(flavor, &[]);
        // Refused before it is sent (sent, it got no answer: exit 3 after seconds).
        let run = r.c29(&["raw", &too_long]);
        assert_eq!(run.status, 2, "{}", run.stderr);
        assert!(run.stderr.contains(says), "{}", run.stderr);
        assert!(run.stderr.len() < 500, "a short error: {}", run.stderr);
        // The longest request still goes out.
        let run = r.c29(&["raw", &fits]);
        assert!(!run.stderr.contains("too long"), "{}", run.stderr);
    }
}

#[test]
fn no_answer_exits_3_naming_port_id_and_request() {
    for (protocol, request) in [("modbus", "`01 01 00 00 00 08`"), ("ascii", "`$016`")] {
        let flavor = Flavor { protocol, ..MODBUS };
        let r = Rig::start(flavor, &["--drop", "1"]);
        let run = r.c29(&["--timeout", "40", "--retries", "1", "status"]);
        assert_eq!(run.status, 3, "{}", run.stderr);
        assert!(run.stderr.contains("no answer"), "{}", run.stderr);
        assert!(
            run.stderr.contains(&r.sim.path),
            "names the port: {}",
            run.stderr
        );
        assert!(run.stderr.contains("ID 1"), "{}", run.stderr);
        assert!(
            run.stderr.contains(request),
            "names the request: {}",
            run.stderr
        );
        assert!(
            run.stderr.contains("rigscript scan"),
            "says what to try: {}",
            run.stderr
        );
    }
}

#[test]
fn garbled_answers_exit_1_with_a_clear_message() {
    // Modbus CRC and ASCII checksums catch a flipped bit (ASCII without checksums cannot).
    for flavor in [MODBUS, ASCII_CHECKSUM] {
        let r = Rig::start(flavor, &["--corrupt", "1", "--seed", "3"]);
        let run = r.c29(&["--retries", "1", "status"]);
        assert_eq!(run.status, 1, "{}", run.stderr);
        assert!(run.stderr.contains("garbled answer"), "{}", run.stderr);
        assert!(
            run.stderr.contains("noise"),
            "says what to check: {}",
            run.stderr
        );
        assert!(!run.stderr.contains("panicked"));
    }
}

#[test]
fn a_module_with_another_id_is_silent_to_this_one() {
    for protocol in ["modbus", "ascii"] {
        let flavor = Flavor {
            protocol,
            ids: "2",
            target: 1,
            checksum: false,
            keepalive: false,
        };
        let r = Rig::start(flavor, &[]);
        let run = r.c29(&["--timeout", "40", "--retries", "0", "status"]);
        assert_eq!(run.status, 3, "{}", run.stderr);
        assert!(
            run.stderr.contains("no answer from TRP-C29U ID 1"),
            "{}",
            run.stderr
        );
        r.c29_at(2, &["status"]).ok("status at ID 2");
    }
}

#[test]
fn a_port_that_does_not_exist_exits_3_with_a_hint() {
    let out = Command::new(rigscript())
        .args(["c29", "--port", "/dev/nonexistent", "--json", "status"])
        .output()
        .unwrap();
    let run = Run::from(out);
    assert_eq!(run.status, 3);
    assert!(
        run.stderr.contains("/dev/nonexistent not found"),
        "{}",
        run.stderr
    );
    assert!(run.stderr.contains("rigscript scan"), "{}", run.stderr);
    let v = run.json();
    assert_eq!(v["status"], 3);
}

/// `rigscript c29 ... monitor` as a child whose standard output arrives line by line.
struct Monitor {
    child: std::process::Child,
    lines: mpsc::Receiver<String>,
}

impl Monitor {
    fn start(r: &Rig, extra: &[&str]) -> Self {
        let mut child = Command::new(rigscript())
            .args(r.base(r.flavor.target))
            .args(extra)
            .args(["monitor", "--interval", "30"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let stdout = BufReader::new(child.stdout.take().unwrap());
        let (tx, lines) = mpsc::channel();
        std::thread::spawn(move || {
            for line in stdout.lines() {
                let Ok(line) = line else { break };
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        Self { child, lines }
    }

    /// The next line that contains `text` (failing after 5 s).
    fn expect(&self, text: &str) -> String {
        loop {
            match self.lines.recv_timeout(Duration::from_secs(5)) {
                Ok(line) if line.contains(text) => return line,
                Ok(_) => continue,
                Err(e) => panic!("no line with {text:?} from monitor: {e}"),
            }
        }
    }

    /// Waits (at most 5 s) for the monitor to end; returns its status and standard error.
    fn wait(mut self) -> (i32, String) {
        for _ in 0..500 {
            if let Ok(Some(status)) = self.child.try_wait() {
                let mut stderr = String::new();
                use std::io::Read;
                let _ = self
                    .child
                    .stderr
                    .take()
                    .unwrap()
                    .read_to_string(&mut stderr);
                return (status.code().unwrap_or(-1), stderr);
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        let _ = self.child.kill();
        panic!("monitor did not end");
    }

    fn interrupt(&self) {
        Command::new("kill")
            .args(["-INT", &self.child.id().to_string()])
            .status()
            .unwrap();
    }
}

#[test]
fn monitor_prints_changes_and_ends_on_ctrl_c() {
    for flavor in [MODBUS, ASCII] {
        let mut r = Rig::start(flavor, &[]);
        r.ok(&["power-on-value", "0x10", "--drive-outputs"]);
        let m = Monitor::start(&r, &[]);
        m.expect("DO    0x00");
        r.control("di 0x04");
        m.expect("DI2 energized");
        r.control("pulse 1 3");
        m.expect("counter DI1 3 (was 0)");
        r.control("reset");
        m.expect("DO4 on");
        m.interrupt();
        let (status, stderr) = m.wait();
        assert_eq!(status, 0, "{stderr}");
    }
}

#[test]
fn monitor_json_is_one_object_a_line() {
    let mut r = Rig::start(MODBUS, &[]);
    let m = Monitor::start(&r, &["--json"]);
    let first: Value = serde_json::from_str(&m.expect("\"state\"")).unwrap();
    assert_eq!(first["do"], 0);
    r.control("di 0x80");
    let line: Value = serde_json::from_str(&m.expect("\"input\"")).unwrap();
    assert_eq!(line["channel"], 7);
    assert_eq!(line["energized"], true);
    m.interrupt();
    assert_eq!(m.wait().0, 0);
}

#[test]
fn monitor_ends_with_disconnected_when_the_port_goes_away() {
    let mut r = Rig::start(MODBUS, &[]);
    let m = Monitor::start(&r, &[]);
    m.expect("DO    0x00");
    r.sim.kill();
    let (status, stderr) = m.wait();
    assert_eq!(status, 3, "{stderr}");
    assert!(stderr.contains("disconnected"), "{stderr}");
    assert!(stderr.contains(&r.sim.path), "names the port: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}
