//! `[mqtt]` against a real Mosquitto broker the tests start on free loopback ports, with a
//! generated password file and ACL and a TLS listener from a CA the test makes, and real
//! `rigscript run` processes on simulated devices: the last will announces a killed or a
//! frozen runner, retained state follows the simulated inputs, records made while the broker
//! was down all arrive after it is back (in order, once, equal to the records file), commands
//! reach their handler (or get an error reply) and an ACL-forbidden client cannot command, and
//! TLS connects with the right CA and is refused, saying why, with a wrong one. Hostile
//! brokers: megabytes retained on watched and command topics (dropped by the broker for the
//! rig's announced packet size), a listener that never answers, a proxy that cuts every
//! connection after a second, a wrong password; a cancelled handler's filter is unsubscribed.
//! A panic in the client's thread (made real: no file left to open) is an error in the log and
//! in `status`, and the rig runs on; a record over the broker's packet size is counted and the
//! rest arrive; a broker's shorter keep-alive is heeded and told, and a broker of the test's
//! own saying Server Keep Alive 0 keeps one connection. Every command of a flood gets a reply
//! and `mosquitto_rr` gets its reply on its Response Topic with its Correlation Data; the
//! end's safe outputs are the retained state before `offline`; the outbox goes to
//! `$STATE_DIRECTORY` without a home, and where it cannot be written the error names the key;
//! `lab` writes a retained ESC out; TLS to the plain port says the peer did not speak TLS.

use crate::common::{require_tool, rigscript, stderr, stdout, until, TempDir};
use serde_json::Value;
use std::fs::File;
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

/// A child process killed when dropped (a failed test leaves no broker or runner behind).
struct Proc(Child);

impl Drop for Proc {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

impl Proc {
    fn signal(&self, signal: i32) {
        // SAFETY: a plain kill(2) on our own child.
        unsafe { libc::kill(self.0.id() as i32, signal) };
    }

    /// Waits (bounded) for it to end; its exit status.
    fn wait_end(&mut self) -> Option<i32> {
        until(Duration::from_secs(15), || self.0.try_wait().unwrap())
            .map(|s| s.code().unwrap_or(-1))
    }
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn run_ok(cmd: &mut Command) {
    let out = cmd.output().expect("start a tool");
    assert!(out.status.success(), "{cmd:?} failed: {}", stderr(&out));
}

/// A CA and a certificate it signs for 127.0.0.1, made with the openssl CLI.
fn make_ca(dir: &Path, name: &str) -> PathBuf {
    let at = |f: &str| dir.join(format!("{name}-{f}"));
    run_ok(
        Command::new("openssl")
            .args([
                "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2", "-subj",
            ])
            .arg(format!("/CN=test CA {name}"))
            .arg("-keyout")
            .arg(at("ca.key"))
            .arg("-out")
            .arg(at("ca.pem")),
    );
    at("ca.pem")
}

fn make_server_cert(dir: &Path, ca: &str) {
    let at = |f: &str| dir.join(f);
    let ca_at = |f: &str| dir.join(format!("{ca}-{f}"));
    std::fs::write(at("san.ext"), "subjectAltName=IP:127.0.0.1,DNS:localhost\n").unwrap();
    run_ok(
        Command::new("openssl")
            .args([
                "req",
                "-newkey",
                "rsa:2048",
                "-nodes",
                "-subj",
                "/CN=127.0.0.1",
            ])
            .arg("-keyout")
            .arg(at("server.key"))
            .arg("-out")
            .arg(at("server.csr")),
    );
    run_ok(
        Command::new("openssl")
            .args(["x509", "-req", "-days", "2"])
            .arg("-in")
            .arg(at("server.csr"))
            .arg("-CA")
            .arg(ca_at("ca.pem"))
            .arg("-CAkey")
            .arg(ca_at("ca.key"))
            .arg("-CAcreateserial")
            .arg("-extfile")
            .arg(at("san.ext"))
            .arg("-out")
            .arg(at("server.pem")),
    );
}

/// Users of the test broker: the rig, an operator who may command, a viewer who may not.
const USERS: &[(&str, &str)] = &[
    ("rig", "rig-pw"),
    ("ops", "ops-pw"),
    ("viewer", "viewer-pw"),
];

/// A Mosquitto broker of the test's own: a plain listener with passwords and an ACL, and a
/// TLS listener; stopped and started again on the same ports, its state kept on disk.
struct Broker {
    dir: TempDir,
    port: u16,
    tls_port: u16,
    process: Option<Proc>,
}

impl Broker {
    fn start(tag: &str) -> Self {
        Self::start_with(tag, "")
    }

    /// A broker whose configuration has `extra` lines too (global options).
    fn start_with(tag: &str, extra: &str) -> Self {
        require_tool("mosquitto", "mosquitto");
        require_tool("mosquitto_sub", "mosquitto-clients");
        require_tool("openssl", "openssl");
        let dir = TempDir::new(tag);
        let d = dir.root();
        let passwords = d.join("passwords");
        std::fs::write(&passwords, "").unwrap();
        for (user, pw) in USERS {
            run_ok(
                Command::new("mosquitto_passwd")
                    .arg("-b")
                    .arg(&passwords)
                    .args([user, pw]),
            );
        }
        std::fs::write(
            d.join("acl"),
            "user rig\ntopic readwrite rigscript/#\ntopic readwrite homeassistant/#\n\
             topic readwrite lab/#\n\n\
             user ops\ntopic readwrite rigscript/+/cmd/#\ntopic read rigscript/#\n\n\
             user viewer\ntopic read rigscript/#\ntopic read homeassistant/#\ntopic read lab/#\n",
        )
        .unwrap();
        make_ca(d, "good");
        make_ca(d, "wrong");
        make_server_cert(d, "good");
        let (port, tls_port) = (free_port(), free_port());
        let p = |f: &str| d.join(f).display().to_string();
        // Run as whoever runs the tests (as root Mosquitto would switch to its own user, who
        // cannot read the test's files).
        let config = format!(
            "user {user}\npersistence true\npersistence_location {dir}/\nautosave_interval 1\n\
             per_listener_settings false\nallow_anonymous false\npassword_file {pw}\n\
             acl_file {acl}\nlog_dest stderr\nlog_type all\n{extra}\
             listener {port} 127.0.0.1\n\
             listener {tls_port} 127.0.0.1\ncafile {ca}\ncertfile {cert}\nkeyfile {key}\n",
            user = std::env::var("USER").unwrap_or_else(|_| "root".into()),
            dir = d.display(),
            pw = p("passwords"),
            acl = p("acl"),
            ca = p("good-ca.pem"),
            cert = p("server.pem"),
            key = p("server.key"),
        );
        std::fs::write(d.join("mosquitto.conf"), config).unwrap();
        let mut b = Self {
            dir,
            port,
            tls_port,
            process: None,
        };
        b.resume();
        b
    }

    /// Starts the broker (again) and waits until it takes connections.
    fn resume(&mut self) {
        let log = File::create(self.dir.path("broker.log")).unwrap();
        let child = Command::new("mosquitto")
            .arg("-c")
            .arg(self.dir.path("mosquitto.conf"))
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .expect("start mosquitto");
        self.process = Some(Proc(child));
        let port = self.port;
        until(Duration::from_secs(10), || {
            std::net::TcpStream::connect(("127.0.0.1", port)).ok()
        })
        .unwrap_or_else(|| panic!("mosquitto never listened: {}", self.log()));
    }

    /// Stops it (SIGTERM: it saves its sessions and retained messages).
    fn stop(&mut self) {
        if let Some(mut p) = self.process.take() {
            p.signal(libc::SIGTERM);
            p.wait_end().expect("mosquitto stopped");
        }
    }

    fn log(&self) -> String {
        std::fs::read_to_string(self.dir.path("broker.log")).unwrap_or_default()
    }

    /// The retained message on `topic` as `user` sees it, if any.
    fn retained(&self, topic: &str) -> Option<String> {
        let out = Command::new("mosquitto_sub")
            .args(["-h", "127.0.0.1", "-p", &self.port.to_string()])
            .args([
                "-u",
                "viewer",
                "-P",
                "viewer-pw",
                "-t",
                topic,
                "-C",
                "1",
                "-W",
                "1",
            ])
            .output()
            .ok()?;
        out.status
            .success()
            .then(|| stdout(&out).trim().to_string())
    }

    /// Polls until the retained message on `topic` satisfies `ok` (10 s at most).
    fn retained_until(&self, topic: &str, ok: impl Fn(&str) -> bool) -> String {
        until(Duration::from_secs(10), || {
            self.retained(topic).filter(|m| ok(m))
        })
        .unwrap_or_else(|| {
            panic!(
                "retained {topic} never as expected (last: {:?}); broker log:\n{}",
                self.retained(topic),
                self.log()
            )
        })
    }

    /// A `mosquitto_sub` of `user` on `topic` writing `topic payload` lines to `file`; with
    /// `session`, a persistent QoS 1 session of that id (the broker keeps what comes while
    /// the subscriber is away).
    fn subscribe(&self, user: &str, topic: &str, file: &Path, session: Option<&str>) -> Proc {
        let pw = USERS.iter().find(|(u, _)| *u == user).unwrap().1;
        let mut c = Command::new("mosquitto_sub");
        c.args([
            "-h",
            "127.0.0.1",
            "-p",
            &self.port.to_string(),
            "-u",
            user,
            "-P",
            pw,
        ])
        .args(["-t", topic, "-v", "-q", "1"]);
        if let Some(id) = session {
            c.args(["-c", "-i", id]);
        }
        let child = c
            .stdout(File::create(file).unwrap())
            .stderr(Stdio::null())
            .spawn()
            .expect("start mosquitto_sub");
        Proc(child)
    }

    /// `rigscript lab --json` as the viewer sees it.
    fn lab(&self) -> Value {
        let out = Command::new(rigscript())
            .args([
                "lab",
                "--broker",
                &format!("mqtt://127.0.0.1:{}", self.port),
            ])
            .args([
                "--username",
                "viewer",
                "--password-env",
                "TEST_MQTT_PW",
                "--json",
            ])
            .env("TEST_MQTT_PW", "viewer-pw")
            .output()
            .expect("run rigscript lab");
        assert!(out.status.success(), "rigscript lab: {}", stderr(&out));
        serde_json::from_slice(&out.stdout).expect("lab's JSON")
    }

    /// Waits (bounded) until the broker has acknowledged a subscription of client `id`.
    fn wait_subscribed(&self, id: &str) {
        let said = format!("Sending SUBACK to {id}");
        until(Duration::from_secs(10), || {
            self.log().contains(&said).then_some(())
        })
        .unwrap_or_else(|| panic!("{id} never subscribed: {}", self.log()));
    }

    fn publish(&self, user: &str, topic: &str, payload: &str) {
        let pw = USERS.iter().find(|(u, _)| *u == user).unwrap().1;
        run_ok(
            Command::new("mosquitto_pub")
                .args([
                    "-h",
                    "127.0.0.1",
                    "-p",
                    &self.port.to_string(),
                    "-u",
                    user,
                    "-P",
                    pw,
                ])
                .args(["-t", topic, "-m", payload, "-q", "1"]),
        );
    }

    /// Publishes the contents of `file` on `topic` as `user` (QoS 1), retained with `retain`.
    fn publish_file(&self, user: &str, topic: &str, file: &str, retain: bool) {
        let pw = USERS.iter().find(|(u, _)| *u == user).unwrap().1;
        let mut c = Command::new("mosquitto_pub");
        c.args(["-h", "127.0.0.1", "-p", &self.port.to_string()])
            .args(["-u", user, "-P", pw, "-t", topic, "-f", file, "-q", "1"]);
        if retain {
            c.arg("-r");
        }
        run_ok(&mut c);
    }

    /// rig.toml's `[mqtt]` for rig `rig` on the plain listener.
    fn mqtt_table(&self, rig: &str, keepalive: &str) -> String {
        format!(
            "[mqtt]\nurl = \"mqtt://127.0.0.1:{}\"\nrig = \"{rig}\"\nusername = \"rig\"\n\
             password_env = \"TEST_MQTT_PW\"\nkeepalive = \"{keepalive}\"\noutbox = \"{}\"\n",
            self.port,
            self.dir.path(&format!("outbox-{rig}")).display()
        )
    }
}

impl Drop for Broker {
    fn drop(&mut self) {
        self.stop();
    }
}

/// A simulated rig (io, a TRP-C29U) with `mqtt` as its `[mqtt]` table, running `script`;
/// its log goes to `run.log` in `dir`.
fn run_rig(dir: &TempDir, name: &str, mqtt: &str, script: &str) -> Proc {
    let records = dir.path(&format!("{name}.jsonl"));
    let config = dir.file(
        &format!("{name}.toml"),
        &format!(
            "name = \"{name}\"\nrecords = \"{}\"\n{mqtt}\n[devices.io]\nkind = \"trp-c29u\"\nsim = true\n",
            records.display()
        ),
    );
    let script = dir.file(&format!("{name}.rhai"), script);
    let log = File::create(dir.path(&format!("{name}.log"))).unwrap();
    let child = Command::new(rigscript())
        .args(["run", "--config", &config, &script])
        .env("XDG_RUNTIME_DIR", dir.root())
        .env_remove("RUNTIME_DIRECTORY")
        .env("TEST_MQTT_PW", "rig-pw")
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .expect("start rigscript run");
    Proc(child)
}

fn lines(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .map(str::to_string)
        .collect()
}

/// The rig called `name` on the lab screen (`rigscript lab --json`).
fn lab_rig(lab: &Value, name: &str) -> Value {
    lab["rigs"]
        .as_array()
        .and_then(|rigs| rigs.iter().find(|r| r["rig"] == name))
        .cloned()
        .unwrap_or_else(|| panic!("rig {name} not on the lab screen: {lab}"))
}

#[test]
#[ignore = "needs mosquitto, mosquitto-clients and openssl (tier 2: .ci/run installs them)"]
fn the_last_will_says_offline_for_a_killed_runner_and_a_frozen_one() {
    let broker = Broker::start("mqtt-will");
    let dir = TempDir::new("mqtt-will-run");
    let script = "every(\"100ms\", || {});\n";
    let rig = run_rig(&dir, "killed", &broker.mqtt_table("killed", "5s"), script);
    broker.retained_until("rigscript/killed/status", |m| m == "online");
    rig.signal(libc::SIGKILL);
    broker.retained_until("rigscript/killed/status", |m| m == "offline");

    // The shortest keep-alive the rig may ask for, 5 s: the broker holds the rig to it (7.5 s
    // without a packet ends the connection; Mosquitto checks on a cadence of its own, seen up
    // to 6 s late), and the rig's pings keep a live connection up meanwhile.
    let frozen = run_rig(&dir, "frozen", &broker.mqtt_table("frozen", "5s"), script);
    broker.retained_until("rigscript/frozen/status", |m| m == "online");
    std::thread::sleep(Duration::from_secs(9));
    let log = broker.log();
    assert!(
        log.contains("as rigscript-frozen (p5, c1, k5, u'rig')"),
        "the rig asked for a 5 s keep-alive: {log}"
    );
    assert!(
        !log.contains("Client rigscript-frozen has exceeded timeout"),
        "a live rig pings within its keep-alive: {log}"
    );
    frozen.signal(libc::SIGSTOP);
    until(Duration::from_secs(30), || {
        (broker.retained("rigscript/frozen/status").as_deref() == Some("offline")).then_some(())
    })
    .unwrap_or_else(|| panic!("the frozen runner never offline: {}", broker.log()));
    frozen.signal(libc::SIGCONT);
    assert!(
        broker
            .log()
            .contains("Client rigscript-frozen has exceeded timeout, disconnecting."),
        "the broker called it offline for its keep-alive: {}",
        broker.log()
    );
}

#[test]
#[ignore = "needs mosquitto, mosquitto-clients and openssl (tier 2: .ci/run installs them)"]
fn retained_state_follows_the_simulated_inputs_and_a_normal_stop_says_offline() {
    let broker = Broker::start("mqtt-state");
    let dir = TempDir::new("mqtt-state-run");
    let script = "io.on_rise(0, || { io.outputs = 0x80; });\n";
    // The names table comes before its device's table (TOML allows it): run_rig writes that.
    let mqtt = format!(
        "{}ha_discovery = true\n\n[devices.io.names]\nDI0 = \"guard door\"\n",
        broker.mqtt_table("state", "10s")
    );
    let mut rig = run_rig(&dir, "state", &mqtt, script);
    let state = |m: &str| serde_json::from_str::<Value>(m).unwrap_or(Value::Null);
    broker.retained_until("rigscript/state/state/io", |m| state(m)["inputs"] == 0);
    let drive = |value: &str| {
        let ok = until(Duration::from_secs(10), || {
            Command::new(rigscript())
                .args(["drive", "state", "set-inputs", "io", value])
                .env("XDG_RUNTIME_DIR", dir.root())
                .env_remove("RUNTIME_DIRECTORY")
                .output()
                .ok()
                .filter(|o| o.status.success())
        });
        assert!(ok.is_some(), "drive state set-inputs io {value} failed");
    };
    drive("0x05");
    let m = broker.retained_until("rigscript/state/state/io", |m| state(m)["inputs"] == 5);
    let v = state(&m);
    assert_eq!(v["online"], true);
    assert_eq!(v["kind"], "trp-c29u");
    assert_eq!(v["outputs"], 0x80, "the handler's outputs: {v}");
    assert_eq!(v["names"]["DI0"], "guard door", "rig.toml's names: {v}");
    // One screen for the lab, from the retained topics alone.
    let lab = broker.lab();
    let mine = lab_rig(&lab, "state");
    assert_eq!(mine["status"], "online", "{lab}");
    assert_eq!(mine["devices"]["io"]["inputs"], 5, "{lab}");
    assert!(mine["last_heard"].is_string(), "{lab}");
    // Home Assistant sees DI0 as a binary sensor reading the state topic.
    let config = broker.retained_until("homeassistant/binary_sensor/state/io_di0/config", |m| {
        !m.is_empty()
    });
    let config = state(&config);
    assert_eq!(
        config["state_topic"], "rigscript/state/state/io",
        "{config}"
    );
    assert_eq!(
        config["availability_topic"], "rigscript/state/status",
        "{config}"
    );
    drive("0x00");
    broker.retained_until("rigscript/state/state/io", |m| state(m)["inputs"] == 0);
    rig.signal(libc::SIGTERM);
    assert_eq!(rig.wait_end(), Some(143));
    broker.retained_until("rigscript/state/status", |m| m == "offline");
    let lab = broker.lab();
    assert_eq!(lab_rig(&lab, "state")["status"], "offline", "{lab}");
}

/// The records file's lines, and the records the subscriber got with their seq taken out.
fn delivered(file: &Path) -> Vec<(u64, String)> {
    lines(file)
        .iter()
        .filter_map(|l| l.split_once(' '))
        .map(|(_, payload)| {
            let mut v: serde_json::Map<String, Value> = serde_json::from_str(payload).unwrap();
            let seq = v.remove("seq").and_then(|s| s.as_u64()).expect("a seq");
            (seq, Value::Object(v).to_string())
        })
        .collect()
}

fn canonical(line: &str) -> String {
    serde_json::from_str::<Value>(line).unwrap().to_string()
}

/// Waits up to `limit` for every record the run has made (its `records` file) to reach the
/// subscriber writing `got`, stops the rig (SIGTERM: 143, the outbox flushed), and checks that
/// what arrived, a record's repeats dropped by seq (QoS 1 is at least once), is the records
/// file: every seq once, in order, the same bodies. Returns how many came twice.
fn stop_and_check_delivery(rig: &mut Proc, records: &Path, got: &Path, limit: Duration) -> usize {
    let made = lines(records).len();
    until(limit, || (delivered(got).len() >= made).then_some(()))
        .unwrap_or_else(|| panic!("only {} of {made} records arrived", delivered(got).len()));
    rig.signal(libc::SIGTERM);
    assert_eq!(rig.wait_end(), Some(143));
    let file: Vec<String> = lines(records).iter().map(|l| canonical(l)).collect();
    until(Duration::from_secs(10), || {
        (delivered(got).len() >= file.len()).then_some(())
    })
    .expect("the stop flushed the outbox");
    let all = delivered(got);
    let mut kept: Vec<(u64, String)> = Vec::new();
    for (seq, body) in all.iter().cloned() {
        if kept.last().map_or(true, |(last, _)| seq > *last) {
            kept.push((seq, body));
        }
    }
    let seqs: Vec<u64> = kept.iter().map(|(s, _)| *s).collect();
    let expected: Vec<u64> = (1..=file.len() as u64).collect();
    assert_eq!(
        seqs, expected,
        "every record, in order, each seq once after duplicates dropped"
    );
    let bodies: Vec<String> = kept.iter().map(|(_, b)| canonical(b)).collect();
    assert_eq!(bodies, file, "the records delivered are the records file");
    all.len() - kept.len()
}

#[test]
#[ignore = "needs mosquitto, mosquitto-clients and openssl (tier 2: .ci/run installs them)"]
fn records_made_while_the_broker_is_down_10_s_all_arrive_in_order_once_and_equal_the_records_file()
{
    let mut broker = Broker::start("mqtt-records");
    let dir = TempDir::new("mqtt-records-run");
    let got = dir.path("records.sub");
    let _sub = broker.subscribe("viewer", "rigscript/rec/records", &got, Some("records-sub"));
    // The subscriber's session exists before the first record.
    broker.wait_subscribed("records-sub");
    let script =
        "let n = 0;\nrecord(\"start\", 0);\nevery(\"50ms\", || { n += 1; record(\"n\", n); });\n";
    let mut rig = run_rig(&dir, "rec", &broker.mqtt_table("rec", "5s"), script);
    let records = dir.path("rec.jsonl");
    until(Duration::from_secs(10), || {
        (delivered(&got).len() >= 5).then_some(())
    })
    .expect("records arrive while the broker is up");
    broker.stop();
    let at_stop = lines(&records).len();
    // The rig runs on and records while the broker is away: 200 records at one per 50 ms,
    // an outage of 10 s.
    until(Duration::from_secs(30), || {
        (lines(&records).len() >= at_stop + 200).then_some(())
    })
    .expect("the rig goes on recording without its broker");
    broker.resume();
    let again = stop_and_check_delivery(&mut rig, &records, &got, Duration::from_secs(20));
    assert!(
        again <= 64,
        "{again} records came twice: more than were in flight"
    );
    let log = std::fs::read_to_string(dir.path("rec.log")).unwrap();
    assert!(log.contains("mqtt: lost broker"), "{log}");

    // A restart goes on numbering where the last run stopped.
    let first_run = lines(&records).len();
    let again = dir.path("again.sub");
    let _sub2 = broker.subscribe("viewer", "rigscript/rec/records", &again, Some("again-sub"));
    broker.wait_subscribed("again-sub");
    let mut rig = run_rig(
        &dir,
        "rec",
        &broker.mqtt_table("rec", "5s"),
        "record(\"again\", 1);\n",
    );
    let first = until(Duration::from_secs(10), || {
        delivered(&again).first().cloned()
    })
    .expect("the restarted rig's record arrives");
    assert_eq!(first.0, first_run as u64 + 1, "{first:?}");
    rig.wait_end();
}

#[test]
#[ignore = "needs mosquitto, mosquitto-clients and openssl (tier 2: .ci/run installs them)"]
fn a_command_gets_its_handlers_reply_an_unknown_one_an_error_and_a_forbidden_client_none() {
    let broker = Broker::start("mqtt-cmd");
    let dir = TempDir::new("mqtt-cmd-run");
    let script = "let calls = 0;\n\
                  on_command(\"arm\", |p| { calls += 1; #{ calls: calls, level: p.level } });\n\
                  on_message(\"lab/+/ping\", |t, p| mqtt_publish(\"lab/pong\", #{ topic: t, n: p.n }));\n";
    let _rig = run_rig(&dir, "cmd", &broker.mqtt_table("cmd", "10s"), script);
    broker.retained_until("rigscript/cmd/status", |m| m == "online");
    let replies = dir.path("replies.sub");
    let _sub = broker.subscribe(
        "viewer",
        "rigscript/cmd/cmd/+/reply",
        &replies,
        Some("replies-sub"),
    );
    broker.wait_subscribed("replies-sub");
    // The viewer may not command: the broker drops its message, the handler never runs.
    broker.publish("viewer", "rigscript/cmd/cmd/arm", "{\"level\":1}");
    broker.publish("ops", "rigscript/cmd/cmd/arm", "{\"level\":2}");
    broker.publish("ops", "rigscript/cmd/cmd/disarm", "{}");
    let reply = |name: &str| {
        let topic = format!("rigscript/cmd/cmd/{name}/reply");
        until(Duration::from_secs(10), || {
            lines(&replies)
                .iter()
                .find_map(|l| l.strip_prefix(&format!("{topic} ")).map(str::to_string))
        })
        .unwrap_or_else(|| panic!("no reply on {topic}: {:?}", lines(&replies)))
    };
    let arm: Value = serde_json::from_str(&reply("arm")).unwrap();
    assert_eq!(
        arm,
        serde_json::json!({"ok": true, "value": {"calls": 1, "level": 2}}),
        "the forbidden command never reached the handler"
    );
    // A watched topic reaches on_message (once the rig has subscribed: asked again until then).
    let pongs = dir.path("pong.sub");
    let _pong = broker.subscribe("viewer", "lab/pong", &pongs, Some("pong-sub"));
    broker.wait_subscribed("pong-sub");
    let pong = until(Duration::from_secs(15), || {
        broker.publish("rig", "lab/bench2/ping", "{\"n\":7}");
        std::thread::sleep(Duration::from_millis(200));
        lines(&pongs).first().cloned()
    })
    .expect("on_message answered the ping");
    let pong: Value = serde_json::from_str(pong.strip_prefix("lab/pong ").unwrap()).unwrap();
    assert_eq!(
        pong,
        serde_json::json!({"topic": "lab/bench2/ping", "n": 7})
    );
    let disarm: Value = serde_json::from_str(&reply("disarm")).unwrap();
    assert_eq!(disarm["ok"], false);
    assert!(
        disarm["error"]
            .as_str()
            .unwrap()
            .contains("no handler for command \"disarm\""),
        "{disarm}"
    );
}

#[test]
#[ignore = "needs mosquitto, mosquitto-clients and openssl (tier 2: .ci/run installs them)"]
fn tls_with_the_right_ca_connects_and_a_wrong_ca_is_refused_saying_why() {
    let broker = Broker::start("mqtt-tls");
    let dir = TempDir::new("mqtt-tls-run");
    let tls = |rig: &str, ca: &str| {
        format!(
            "[mqtt]\nurl = \"mqtts://127.0.0.1:{}\"\nrig = \"{rig}\"\nusername = \"rig\"\n\
             password_env = \"TEST_MQTT_PW\"\nca_file = \"{}\"\noutbox = \"{}\"\n",
            broker.tls_port,
            broker.dir.path(&format!("{ca}-ca.pem")).display(),
            dir.path(&format!("outbox-{rig}")).display()
        )
    };
    let script = "every(\"100ms\", || {});\n";
    let _good = run_rig(&dir, "good", &tls("good", "good"), script);
    broker.retained_until("rigscript/good/status", |m| m == "online");
    let _wrong = run_rig(&dir, "wrong", &tls("wrong", "wrong"), script);
    // mqtts:// to the plain listener: the peer does not speak TLS, whatever the CA.
    let plain = tls("plain", "good").replace(
        &format!(":{}\"", broker.tls_port),
        &format!(":{}\"", broker.port),
    );
    let _plain = run_rig(&dir, "plain", &plain, script);
    let log = log_with(&dir, "plain", "TLS to broker");
    assert!(
        log.contains("the peer did not speak TLS (is the port a plain MQTT port?")
            && !log.contains("ca_file"),
        "{log}"
    );
    let log = log_with(&dir, "wrong", "TLS to broker");
    assert!(
        log.contains(&format!(
            "TLS to broker 127.0.0.1:{} failed",
            broker.tls_port
        )) && log.contains("UnknownIssuer")
            && log.contains("the run goes on"),
        "{log}"
    );
    assert_eq!(broker.retained("rigscript/wrong/status"), None);
}

/// Waits (bounded) until the log of the rig `run_rig` started as `name` in `dir` has `what`;
/// the log.
fn log_with(dir: &TempDir, name: &str, what: &str) -> String {
    let read = || std::fs::read_to_string(dir.path(&format!("{name}.log"))).unwrap_or_default();
    until(Duration::from_secs(15), || {
        let log = read();
        log.contains(what).then_some(log)
    })
    .unwrap_or_else(|| panic!("no {what:?} in the log:\n{}", read()))
}

/// `rigscript status NAME` of a rig `run_rig` started in `dir` (`--json`: the snapshot).
fn status(dir: &TempDir, name: &str, json: bool) -> Option<String> {
    let mut c = Command::new(rigscript());
    c.args(["status", name]);
    if json {
        c.arg("--json");
    }
    let out = c
        .env("XDG_RUNTIME_DIR", dir.root())
        .env_remove("RUNTIME_DIRECTORY")
        .output()
        .expect("run rigscript status");
    out.status.success().then(|| stdout(&out))
}

#[test]
#[ignore = "needs mosquitto, mosquitto-clients and openssl (tier 2: .ci/run installs them)"]
fn a_flood_on_a_watched_topic_is_counted_in_status_as_messages_dropped() {
    let broker = Broker::start("mqtt-flood");
    let dir = TempDir::new("mqtt-flood-run");
    let script = "on_message(\"lab/flood\", |t, p| {});\n";
    let _rig = run_rig(&dir, "flood", &broker.mqtt_table("flood", "10s"), script);
    broker.retained_until("rigscript/flood/status", |m| m == "online");
    let mqtt = || {
        let text = status(&dir, "flood", true)?;
        let v: Value = serde_json::from_str(&text).ok()?;
        Some(v["mqtt"].clone())
    };
    let connected = until(Duration::from_secs(10), || {
        mqtt().filter(|m| m["connected"] == true)
    })
    .expect("status shows the client connected");
    assert_eq!(connected["broker"], format!("127.0.0.1:{}", broker.port));
    assert_eq!(connected["dropped"]["messages"], 0, "{connected}");
    // More messages at once than the client hands the loop in a second (100); sent again
    // until the rig has subscribed to the watched topic and counts what it drops.
    let flood: String = (0..400).map(|n| format!("{{\"n\":{n}}}\n")).collect();
    let pw = USERS.iter().find(|(u, _)| *u == "rig").unwrap().1;
    let shown = until(Duration::from_secs(15), || {
        let mut pub_ = Command::new("mosquitto_pub")
            .args(["-h", "127.0.0.1", "-p", &broker.port.to_string()])
            .args(["-u", "rig", "-P", pw, "-t", "lab/flood", "-l", "-q", "0"])
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start mosquitto_pub");
        use std::io::Write as _;
        let _ = pub_.stdin.take().unwrap().write_all(flood.as_bytes());
        let _ = pub_.wait();
        mqtt().filter(|m| m["dropped"]["messages"].as_u64() > Some(0))
    })
    .unwrap_or_else(|| panic!("status never showed messages dropped: {:?}", mqtt()));
    assert_eq!(shown["connected"], true, "{shown}");
    assert_eq!(shown["dropped"]["commands"], 0, "{shown}");
    let text = status(&dir, "flood", false).expect("status");
    let line = text
        .lines()
        .find(|l| l.starts_with("mqtt: broker"))
        .unwrap_or_else(|| panic!("no mqtt line in\n{text}"));
    assert!(
        line.contains("connected") && line.contains("dropped: messages "),
        "{line}"
    );
}

/// The `mqtt` part of `rigscript status NAME --json`, once it answers.
fn mqtt_status(dir: &TempDir, name: &str) -> Option<Value> {
    let text = status(dir, name, true)?;
    let v: Value = serde_json::from_str(&text).ok()?;
    Some(v["mqtt"].clone())
}

/// Waits (bounded) for a line starting with `prefix` in `file`.
fn line_with(file: &Path, prefix: &str) -> String {
    until(Duration::from_secs(15), || {
        lines(file).into_iter().find(|l| l.starts_with(prefix))
    })
    .unwrap_or_else(|| panic!("no {prefix:?} line in {file:?}: {:?}", lines(file)))
}

#[test]
#[ignore = "needs mosquitto, mosquitto-clients and openssl (tier 2: .ci/run installs them)"]
fn huge_retained_messages_on_a_watched_topic_and_on_cmd_leave_the_connection_up() {
    let broker = Broker::start("mqtt-huge");
    let dir = TempDir::new("mqtt-huge-run");
    // Megabytes on a watched topic and on a command, retained: sent to the rig at each
    // subscription. The client announces its packet size limit; the broker drops these for it.
    let huge = dir.file("huge", &"x".repeat(3 << 20));
    broker.publish_file("rig", "lab/in/huge", &huge, true);
    broker.publish_file("ops", "rigscript/huge/cmd/arm", &huge, true);
    // A little over the payload bound: within the packet limit, so it arrives, and the client
    // drops it, counted.
    let over = dir.file("over", &"y".repeat(64 * 1024 + 100));
    broker.publish_file("rig", "lab/in/over", &over, true);
    let script = "on_message(\"lab/in/#\", |t, p| mqtt_publish(\"lab/out\", t));\n\
                  on_command(\"arm\", |p| \"armed\");\n";
    let _rig = run_rig(&dir, "huge", &broker.mqtt_table("huge", "10s"), script);
    until(Duration::from_secs(10), || {
        mqtt_status(&dir, "huge").filter(|m| m["connected"] == true)
    })
    .expect("status shows the client connected");
    let out = dir.path("out.sub");
    let _out = broker.subscribe("viewer", "lab/out", &out, Some("out-sub"));
    broker.wait_subscribed("out-sub");
    // Sent again until the rig has subscribed to the watched filter (it asks every 2 s): by
    // then the retained messages, huge and over, came before this one.
    until(Duration::from_secs(15), || {
        broker.publish("rig", "lab/in/ok", "{}");
        std::thread::sleep(Duration::from_millis(200));
        lines(&out)
            .contains(&"lab/out lab/in/ok".to_string())
            .then_some(())
    })
    .unwrap_or_else(|| panic!("the handler never saw lab/in/ok: {:?}", lines(&out)));
    let replies = dir.path("replies.sub");
    let _replies = broker.subscribe(
        "viewer",
        "rigscript/huge/cmd/+/reply",
        &replies,
        Some("huge-replies"),
    );
    broker.wait_subscribed("huge-replies");
    broker.publish("ops", "rigscript/huge/cmd/arm", "{}");
    let reply = line_with(&replies, "rigscript/huge/cmd/arm/reply ");
    assert!(reply.ends_with(r#"{"ok":true,"value":"armed"}"#), "{reply}");
    broker.publish_file("ops", "rigscript/huge/cmd/arm", &over, false);
    let refused = until(Duration::from_secs(15), || {
        lines(&replies)
            .into_iter()
            .find(|l| l.contains("\"ok\":false"))
    })
    .expect("an error reply for the command over the bound");
    assert!(refused.contains("a payload of 65636 bytes"), "{refused}");
    let m = mqtt_status(&dir, "huge").expect("status");
    assert_eq!(m["connected"], true, "{m}");
    assert_eq!(
        m["connect_failures"], 0,
        "the connection was never lost: {m}"
    );
    assert_eq!(m["dropped"]["messages"], 1, "the one over the bound: {m}");
    assert_eq!(m["dropped"]["commands"], 1, "the one over the bound: {m}");
    // What the broker dropped for the rig: the two huge ones, at each subscription.
    let log = broker.log();
    let dropped = log
        .lines()
        .filter(|l| l.contains("Dropping too large outgoing PUBLISH for rigscript-huge"))
        .count();
    assert_eq!(dropped, 2, "{log}");
    let seen = lines(&out);
    assert!(
        !seen
            .iter()
            .any(|l| l.contains("huge") || l.contains("over")),
        "{seen:?}"
    );
    // The lab screen reads every retained topic under the root: a huge retained message among
    // them is dropped by the broker for it too, and the screen still shows the rig.
    broker.publish_file("rig", "rigscript/huge/state/big", &huge, true);
    let lab = broker.lab();
    let mine = lab_rig(&lab, "huge");
    assert_eq!(mine["status"], "online", "{lab}");
    assert!(
        broker
            .log()
            .lines()
            .any(|l| l.contains("Dropping too large outgoing PUBLISH for rigscript-lab-")),
        "the broker dropped the huge message for the lab screen"
    );
}

#[test]
#[ignore = "needs mosquitto, mosquitto-clients and openssl (tier 2: .ci/run installs them)"]
fn a_cancelled_on_message_handler_unsubscribes_its_filter() {
    let broker = Broker::start("mqtt-unwatch");
    let dir = TempDir::new("mqtt-unwatch-run");
    let script =
        "let watch = on_message(\"lab/gone\", |t, p| mqtt_publish(\"lab/seen\", `gone ${p}`));\n\
                  on_message(\"lab/still\", |t, p| mqtt_publish(\"lab/seen\", `still ${p}`));\n\
                  on_command(\"unwatch\", |p| cancel(watch));\n";
    let _rig = run_rig(
        &dir,
        "unwatch",
        &broker.mqtt_table("unwatch", "10s"),
        script,
    );
    broker.retained_until("rigscript/unwatch/status", |m| m == "online");
    let seen = dir.path("seen.sub");
    let _seen = broker.subscribe("viewer", "lab/seen", &seen, Some("seen-sub"));
    broker.wait_subscribed("seen-sub");
    let saw = |what: &str| lines(&seen).contains(&format!("lab/seen {what}"));
    until(Duration::from_secs(15), || {
        broker.publish("rig", "lab/gone", "1");
        std::thread::sleep(Duration::from_millis(200));
        saw("gone 1").then_some(())
    })
    .expect("the handler answers before it is cancelled");
    let replies = dir.path("replies.sub");
    let _replies = broker.subscribe(
        "viewer",
        "rigscript/unwatch/cmd/+/reply",
        &replies,
        Some("unwatch-replies"),
    );
    broker.wait_subscribed("unwatch-replies");
    broker.publish("ops", "rigscript/unwatch/cmd/unwatch", "{}");
    let reply = line_with(&replies, "rigscript/unwatch/cmd/unwatch/reply ");
    assert!(reply.ends_with(r#"{"ok":true,"value":true}"#), "{reply}");
    let said = "Received UNSUBSCRIBE from rigscript-unwatch";
    until(Duration::from_secs(10), || {
        broker.log().contains(said).then_some(())
    })
    .unwrap_or_else(|| panic!("the rig never unsubscribed: {}", broker.log()));
    broker.publish("rig", "lab/gone", "2");
    broker.publish("rig", "lab/still", "3");
    // The broker routes in order: once the later message reached the rig, the earlier one
    // would have too, had the rig still subscribed.
    until(Duration::from_secs(15), || saw("still 3").then_some(()))
        .expect("the other handler still answers");
    assert!(!saw("gone 2"), "{:?}", lines(&seen));
    let log = broker.log();
    let after = &log[log.find(said).unwrap()..];
    assert!(
        !after
            .lines()
            .any(|l| l.contains("Sending PUBLISH to rigscript-unwatch") && l.contains("'lab/gone'")),
        "the broker still sent lab/gone to the rig:\n{after}"
    );
    let m = mqtt_status(&dir, "unwatch").expect("status");
    assert_eq!(
        m["dropped"]["messages"], 0,
        "nothing counted as dropped: {m}"
    );
}

#[test]
fn a_broker_that_accepts_and_never_answers_costs_the_loop_nothing_and_a_stop_ends_promptly() {
    let dir = TempDir::new("mqtt-mute-run");
    // Takes the TCP connection and never says a word (no CONNACK).
    let mute = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = mute.local_addr().unwrap().port();
    std::thread::spawn(move || {
        let mut held = Vec::new();
        for s in mute.incoming().flatten() {
            held.push(s);
        }
    });
    let mqtt = format!(
        "[mqtt]\nurl = \"mqtt://127.0.0.1:{port}\"\nrig = \"mute\"\nusername = \"rig\"\n\
         password_env = \"TEST_MQTT_PW\"\noutbox = \"{}\"\n",
        dir.path("outbox-mute").display()
    );
    let mut rig = run_rig(&dir, "mute", &mqtt, "every(\"50ms\", || {});\n");
    let m = until(Duration::from_secs(30), || {
        mqtt_status(&dir, "mute").filter(|m| m["connect_failures"].as_u64() >= Some(1))
    })
    .expect("status shows a failed connection");
    assert_eq!(m["connected"], false, "{m}");
    let why = m["last_error"].as_str().unwrap_or_default();
    assert!(
        why.contains(&format!("broker 127.0.0.1:{port} did not answer")),
        "{m}"
    );
    // The loop turned on while the client waited for an answer that never came: the 50 ms
    // timer kept its pace (a loop held by the connection would have few ticks, and one as
    // long as the client's wait). Not a timing test: a loaded machine may make a tick late.
    let snap: Value = serde_json::from_str(&status(&dir, "mute", true).unwrap()).unwrap();
    let ticks = snap["ticks"]["count"].as_u64().unwrap_or(0);
    let uptime_ms = snap["script"]["uptime_ms"].as_u64().unwrap_or(0);
    assert!(
        ticks * 50 * 2 >= uptime_ms,
        "fewer than half the ticks: {snap}"
    );
    let longest = snap["ticks"]["work_max_us"].as_u64().unwrap_or(u64::MAX);
    assert!(longest < 1_000_000, "a tick waited on the broker: {snap}");
    let text = status(&dir, "mute", false).expect("status");
    assert!(text.contains("NOT CONNECTED"), "{text}");
    rig.signal(libc::SIGTERM);
    assert_eq!(rig.wait_end(), Some(143));
}

#[test]
#[ignore = "needs mosquitto, mosquitto-clients and openssl (tier 2: .ci/run installs them)"]
fn a_wrong_password_is_told_naming_broker_and_user_and_retried_while_the_rig_runs() {
    let broker = Broker::start("mqtt-badpw");
    let dir = TempDir::new("mqtt-badpw-run");
    let wrong = dir.file("wrong-pw", "not-the-password\n");
    let mqtt = broker.mqtt_table("badpw", "10s").replace(
        "password_env = \"TEST_MQTT_PW\"",
        &format!("password_file = \"{wrong}\""),
    );
    let mut rig = run_rig(&dir, "badpw", &mqtt, "every(\"50ms\", || {});\n");
    // Retried (with back-off): the failures go on growing while the run goes on.
    let m = until(Duration::from_secs(30), || {
        mqtt_status(&dir, "badpw").filter(|m| m["connect_failures"].as_u64() >= Some(3))
    })
    .expect("status shows repeated refusals");
    assert_eq!(m["connected"], false, "{m}");
    let said = format!(
        "broker 127.0.0.1:{} refused user rig: wrong user name or password",
        broker.port
    );
    assert!(
        m["last_error"].as_str().unwrap_or("").contains(&said),
        "{m}"
    );
    let log = std::fs::read_to_string(dir.path("badpw.log")).unwrap();
    assert!(
        log.contains(&said) && log.contains("the run goes on, retrying in"),
        "{log}"
    );
    assert_eq!(broker.retained("rigscript/badpw/status"), None);
    rig.signal(libc::SIGTERM);
    assert_eq!(rig.wait_end(), Some(143));
}

/// A TCP proxy to `port` that, while `cutting`, ends each connection about 1 s after it came.
fn cutting_proxy(port: u16, cutting: std::sync::Arc<std::sync::atomic::AtomicBool>) -> u16 {
    use std::net::{Shutdown, TcpStream};
    use std::sync::atomic::Ordering;
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let at = listener.local_addr().unwrap().port();
    std::thread::spawn(move || {
        for client in listener.incoming().flatten() {
            let Ok(server) = TcpStream::connect(("127.0.0.1", port)) else {
                continue;
            };
            let pipe = |mut from: TcpStream, mut to: TcpStream| {
                std::thread::spawn(move || {
                    let _ = std::io::copy(&mut from, &mut to);
                    let _ = to.shutdown(Shutdown::Both);
                });
            };
            pipe(client.try_clone().unwrap(), server.try_clone().unwrap());
            pipe(server.try_clone().unwrap(), client.try_clone().unwrap());
            if cutting.load(Ordering::SeqCst) {
                std::thread::spawn(move || {
                    std::thread::sleep(Duration::from_secs(1));
                    let _ = client.shutdown(Shutdown::Both);
                    let _ = server.shutdown(Shutdown::Both);
                });
            }
        }
    });
    at
}

#[test]
#[ignore = "needs mosquitto, mosquitto-clients and openssl (tier 2: .ci/run installs them)"]
fn records_made_while_every_connection_is_cut_after_a_second_all_arrive_in_order_once() {
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;
    let broker = Broker::start("mqtt-cut");
    let dir = TempDir::new("mqtt-cut-run");
    let got = dir.path("records.sub");
    let _sub = broker.subscribe("viewer", "rigscript/cut/records", &got, Some("cut-sub"));
    broker.wait_subscribed("cut-sub");
    let cutting = Arc::new(AtomicBool::new(true));
    let port = cutting_proxy(broker.port, Arc::clone(&cutting));
    let mqtt = broker
        .mqtt_table("cut", "10s")
        .replace(&format!(":{}\"", broker.port), &format!(":{port}\""));
    let script = "let n = 0;\nevery(\"50ms\", || { n += 1; record(\"n\", n); });\n";
    let mut rig = run_rig(&dir, "cut", &mqtt, script);
    // Five connections made and cut.
    until(Duration::from_secs(40), || {
        let log = broker.log();
        (log.matches("as rigscript-cut ").count() >= 5).then_some(())
    })
    .unwrap_or_else(|| panic!("the rig did not connect again and again: {}", broker.log()));
    cutting.store(false, Ordering::SeqCst);
    let records = dir.path("cut.jsonl");
    stop_and_check_delivery(&mut rig, &records, &got, Duration::from_secs(30));
    let log = std::fs::read_to_string(dir.path("cut.log")).unwrap();
    assert!(
        log.contains(&format!(
            "mqtt: connected again to broker 127.0.0.1:{port} as cut"
        )),
        "{log}"
    );
}

#[test]
#[ignore = "needs mosquitto, mosquitto-clients and openssl (tier 2: .ci/run installs them)"]
fn publishes_the_acl_refuses_are_counted_and_told_naming_broker_user_and_topic() {
    let broker = Broker::start("mqtt-acl");
    let dir = TempDir::new("mqtt-acl-run");
    // The rig's user may write rigscript/# only: this prefix is outside its ACL.
    let mqtt = format!(
        "{}prefix = \"forbidden/{{rig}}\"\n",
        broker.mqtt_table("acl", "10s")
    );
    let script = "let n = 0;\nevery(\"100ms\", || { n += 1; record(\"n\", n); });\n";
    let mut rig = run_rig(&dir, "acl", &mqtt, script);
    let m = until(Duration::from_secs(15), || {
        mqtt_status(&dir, "acl").filter(|m| m["dropped"]["refused"].as_u64() >= Some(3))
    })
    .expect("status counts the refused publishes");
    assert_eq!(m["connected"], true, "{m}");
    assert_eq!(m["connect_failures"], 0, "{m}");
    // Refused records are not waited on for ever.
    let m = until(Duration::from_secs(10), || {
        mqtt_status(&dir, "acl").filter(|m| m["outbox_waiting"].as_u64() < Some(10))
    })
    .expect("the outbox does not fill with refused records");
    assert_eq!(m["dropped"]["outbox_full"], 0, "{m}");
    let log = std::fs::read_to_string(dir.path("acl.log")).unwrap();
    assert!(
        log.contains(&format!(
            "broker 127.0.0.1:{} refused user rig's publish on forbidden/acl/",
            broker.port
        )) && log.contains("NotAuthorized"),
        "{log}"
    );
    rig.signal(libc::SIGTERM);
    assert_eq!(rig.wait_end(), Some(143));
}

/// Sets the soft limit on the open files of process `pid` to `soft`; the limit it had.
fn limit_open_files(pid: u32, soft: u64) -> u64 {
    let mut old = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: reads the limit into `old`, a valid rlimit.
    let got = unsafe { libc::prlimit(pid as i32, libc::RLIMIT_NOFILE, std::ptr::null(), &mut old) };
    assert_eq!(got, 0, "prlimit: {}", std::io::Error::last_os_error());
    let new = libc::rlimit {
        rlim_cur: soft,
        rlim_max: old.rlim_max,
    };
    // SAFETY: a valid rlimit for our own child, the old one not asked for.
    let set = unsafe { libc::prlimit(pid as i32, libc::RLIMIT_NOFILE, &new, std::ptr::null_mut()) };
    assert_eq!(set, 0, "prlimit: {}", std::io::Error::last_os_error());
    old.rlim_cur
}

#[test]
fn a_panic_in_the_clients_thread_is_an_error_in_the_log_and_in_status_and_the_rig_runs_on() {
    let dir = TempDir::new("mqtt-panic-run");
    // Nothing listens there: the client connects again and again.
    let mqtt = format!(
        "[mqtt]\nurl = \"mqtt://127.0.0.1:{}\"\nrig = \"panic\"\noutbox = \"{}\"\n",
        free_port(),
        dir.path("outbox-panic").display()
    );
    let script = "io.outputs = 0x21;\nevery(\"50ms\", || {});\n";
    let mut rig = run_rig(&dir, "panic", &mqtt, script);
    until(Duration::from_secs(30), || {
        mqtt_status(&dir, "panic").filter(|m| m["connect_failures"].as_u64() >= Some(1))
    })
    .expect("status shows a failed connection");
    // With no file to open, the MQTT library's client panics as the next connection is made
    // (it builds a runtime for each and unwraps the failure): a real panic in the client's
    // thread, while the scan loop, which opens nothing as it runs, goes on.
    let pid = rig.0.id();
    let was = limit_open_files(pid, 3);
    let log = until(Duration::from_secs(20), || {
        let log = std::fs::read_to_string(dir.path("panic.log")).unwrap_or_default();
        log.contains("error: mqtt: the client's thread panicked")
            .then_some(log)
    });
    limit_open_files(pid, was);
    let log = log.unwrap_or_else(|| {
        panic!(
            "no error line for the panic:\n{}",
            std::fs::read_to_string(dir.path("panic.log")).unwrap_or_default()
        )
    });
    assert!(
        log.contains("Too many open files") && log.contains("MQTT is off for the rest of the run"),
        "{log}"
    );
    let m = mqtt_status(&dir, "panic").expect("status answers again");
    assert_eq!(m["connected"], false, "{m}");
    let failed = m["failed"].as_str().unwrap_or_default();
    assert!(
        failed.starts_with("the client's thread panicked: ")
            && failed.contains("Too many open files"),
        "{m}"
    );
    // The outputs are still the script's, and the loop still scans.
    let snap = |dir: &TempDir| -> Value {
        serde_json::from_str(&status(dir, "panic", true).expect("status")).unwrap()
    };
    let before = snap(&dir);
    assert_eq!(before["devices"]["io"]["outputs"], 0x21, "{before}");
    assert_eq!(before["script"]["state"], "running", "{before}");
    assert_eq!(before["held_safe"], false, "{before}");
    let ticks = before["ticks"]["count"].as_u64().unwrap();
    until(Duration::from_secs(10), || {
        (snap(&dir)["ticks"]["count"].as_u64() > Some(ticks)).then_some(())
    })
    .expect("the loop scans on");
    let text = status(&dir, "panic", false).expect("status");
    assert!(
        text.contains("FAILED: the client's thread panicked"),
        "{text}"
    );
    rig.signal(libc::SIGTERM);
    assert_eq!(rig.wait_end(), Some(143));
}

#[test]
#[ignore = "needs mosquitto, mosquitto-clients and openssl (tier 2: .ci/run installs them)"]
fn a_record_over_the_brokers_packet_size_is_counted_and_told_and_the_rest_arrive_in_order() {
    let broker = Broker::start_with("mqtt-big", "max_packet_size 2048\n");
    let dir = TempDir::new("mqtt-big-run");
    let got = dir.path("records.sub");
    let _sub = broker.subscribe("viewer", "rigscript/big/records", &got, Some("big-sub"));
    broker.wait_subscribed("big-sub");
    // One record of 3,000 characters between small ones; the broker takes 2,048 bytes a packet.
    let script = "let n = 0;\n\
                  every(\"50ms\", || {\n\
                    n += 1;\n\
                    if n == 5 { let big = \"\"; for i in 0..300 { big += \"0123456789\"; } record(\"big\", big); }\n\
                    else if n <= 10 { record(\"n\", n); }\n\
                  });\n";
    let mut rig = run_rig(&dir, "big", &broker.mqtt_table("big", "10s"), script);
    let records = dir.path("big.jsonl");
    until(Duration::from_secs(15), || {
        (delivered(&got).len() >= 9).then_some(())
    })
    .unwrap_or_else(|| panic!("the small records never all arrived: {:?}", lines(&got)));
    let m = mqtt_status(&dir, "big").expect("status");
    assert_eq!(m["dropped"]["too_large"], 1, "{m}");
    assert_eq!(m["connected"], true, "{m}");
    assert_eq!(
        m["connect_failures"], 0,
        "the connection was never lost: {m}"
    );
    assert_eq!(
        m["outbox_waiting"], 0,
        "nothing held behind the big one: {m}"
    );
    rig.signal(libc::SIGTERM);
    assert_eq!(rig.wait_end(), Some(143));
    // Every record but the big one, in order, each once: the records file has them all.
    let file: Vec<String> = lines(&records).iter().map(|l| canonical(l)).collect();
    assert_eq!(file.len(), 10, "{file:?}");
    let big = file
        .iter()
        .position(|l| l.contains("\"big\""))
        .expect("the big record") as u64
        + 1;
    let got = delivered(&got);
    let seqs: Vec<u64> = got.iter().map(|(s, _)| *s).collect();
    let expected: Vec<u64> = (1..=10).filter(|s| *s != big).collect();
    assert_eq!(seqs, expected);
    let bodies: Vec<String> = got.iter().map(|(_, b)| canonical(b)).collect();
    let small: Vec<String> = file
        .iter()
        .filter(|l| !l.contains("\"big\""))
        .cloned()
        .collect();
    assert_eq!(bodies, small);
    let log = std::fs::read_to_string(dir.path("big.log")).unwrap();
    let told = log
        .lines()
        .find(|l| l.contains("not sent:"))
        .unwrap_or_else(|| panic!("no line for the big record:\n{log}"));
    assert!(
        told.contains("a record on rigscript/big/records")
            && told.contains(&format!(
                "over broker 127.0.0.1:{}'s limit of 2048",
                broker.port
            )),
        "{told}"
    );
    assert!(!log.contains("lost broker"), "{log}");
    assert!(
        log.contains("1 publishes over the broker's Maximum Packet Size"),
        "{log}"
    );
}

#[test]
#[ignore = "needs mosquitto, mosquitto-clients and openssl (tier 2: .ci/run installs them)"]
fn a_broker_asking_for_a_shorter_keep_alive_is_heeded_and_told_and_calls_a_frozen_rig_offline_sooner(
) {
    // Mosquitto's max_keepalive (10 s at least) sends MQTT 5 clients asking for more a Server
    // Keep Alive; the client library pings at it.
    let broker = Broker::start_with("mqtt-maxka", "max_keepalive 10\n");
    let dir = TempDir::new("mqtt-maxka-run");
    let frozen = run_rig(
        &dir,
        "maxka",
        &broker.mqtt_table("maxka", "60s"),
        "every(\"100ms\", || {});\n",
    );
    broker.retained_until("rigscript/maxka/status", |m| m == "online");
    let log = log_with(&dir, "maxka", "asks for a keep-alive");
    assert!(
        log.contains(&format!(
            "broker 127.0.0.1:{} asks for a keep-alive of 10s (rig.toml's keepalive is 1m): a \
             frozen rig is called offline within 15s",
            broker.port
        )),
        "{log}"
    );
    // It pings at the broker's keep-alive (at its own it would first ping after 60 s, and the
    // broker would have dropped it after 15 s).
    until(Duration::from_secs(30), || {
        broker
            .log()
            .contains("Received PINGREQ from rigscript-maxka")
            .then_some(())
    })
    .unwrap_or_else(|| panic!("no ping within 30 s: {}", broker.log()));
    frozen.signal(libc::SIGSTOP);
    // 1.5 x 10 s and the broker's clock, well before 1.5 x 60 s.
    until(Duration::from_secs(40), || {
        (broker.retained("rigscript/maxka/status").as_deref() == Some("offline")).then_some(())
    })
    .unwrap_or_else(|| panic!("the frozen runner never offline: {}", broker.log()));
    frozen.signal(libc::SIGCONT);
    let log = broker.log();
    assert_eq!(
        log.matches("as rigscript-maxka ").count(),
        1,
        "one connection until it froze: {log}"
    );
}

/// The reply payloads on `topic` in a `mosquitto_sub -v` file, as JSON.
fn replies_on(file: &Path, topic: &str) -> Vec<Value> {
    let prefix = format!("{topic} ");
    lines(file)
        .iter()
        .filter_map(|l| l.strip_prefix(&prefix))
        .filter_map(|p| serde_json::from_str(p).ok())
        .collect()
}

#[test]
#[ignore = "needs mosquitto, mosquitto-clients and openssl (tier 2: .ci/run installs them)"]
fn every_command_of_a_flood_gets_a_reply_and_an_mqtt5_request_gets_it_where_it_asked_with_its_data()
{
    require_tool("mosquitto_rr", "mosquitto-clients");
    let broker = Broker::start("mqtt-replies");
    let dir = TempDir::new("mqtt-replies-run");
    let script = "let calls = 0;\n\
                  on_command(\"arm\", |p| { calls += 1; #{ calls: calls, n: p.n } });\n";
    let _rig = run_rig(&dir, "rr", &broker.mqtt_table("rr", "10s"), script);
    broker.retained_until("rigscript/rr/status", |m| m == "online");
    let fixed = "rigscript/rr/cmd/arm/reply";
    let replies = dir.path("replies.sub");
    let _sub = broker.subscribe("viewer", fixed, &replies, Some("replies-sub"));
    broker.wait_subscribed("replies-sub");
    // What arrives on the requester's own topic, with its Correlation Data (%D).
    let theirs = dir.path("theirs.sub");
    let _theirs = Proc(
        Command::new("mosquitto_sub")
            .args(["-h", "127.0.0.1", "-p", &broker.port.to_string()])
            .args([
                "-u",
                "viewer",
                "-P",
                "viewer-pw",
                "-i",
                "theirs-sub",
                "-V",
                "5",
            ])
            .args(["-t", "rigscript/lab-ops/#", "-q", "1", "-F", "%t %D %p"])
            .stdout(File::create(&theirs).unwrap())
            .stderr(Stdio::null())
            .spawn()
            .expect("start mosquitto_sub"),
    );
    broker.wait_subscribed("theirs-sub");

    // MQTT 5's request/response: mosquitto_rr names a Response Topic and waits there.
    let rr = Command::new("mosquitto_rr")
        .args(["-h", "127.0.0.1", "-p", &broker.port.to_string()])
        .args(["-u", "ops", "-P", "ops-pw", "-t", "rigscript/rr/cmd/arm"])
        .args([
            "-e",
            "rigscript/lab-ops/replies",
            "-m",
            "{\"n\":7}",
            "-W",
            "10",
        ])
        .args(["-D", "publish", "correlation-data", "req-42"])
        .output()
        .expect("run mosquitto_rr");
    let answer = stdout(&rr);
    assert!(rr.status.success(), "mosquitto_rr: {answer} {rr:?}");
    let answer: Value = serde_json::from_str(answer.trim()).unwrap();
    assert_eq!(
        answer,
        serde_json::json!({"ok": true, "value": {"calls": 1, "n": 7}})
    );
    let seen = until(Duration::from_secs(10), || lines(&theirs).first().cloned())
        .expect("the reply on the response topic");
    assert!(
        seen.starts_with("rigscript/lab-ops/replies req-42 {"),
        "the reply carries the request's Correlation Data: {seen}"
    );
    // A Response Topic under the rig's own topics is not spoken on: the fixed topic, as for
    // an MQTT 3 client.
    run_ok(
        Command::new("mosquitto_pub")
            .args(["-h", "127.0.0.1", "-p", &broker.port.to_string()])
            .args(["-u", "ops", "-P", "ops-pw", "-t", "rigscript/rr/cmd/arm"])
            .args(["-m", "{\"n\":8}", "-q", "1"])
            .args(["-D", "publish", "response-topic", "rigscript/rr/status"])
            .args(["-D", "publish", "correlation-data", "c-8"]),
    );
    until(Duration::from_secs(10), || {
        replies_on(&replies, fixed)
            .iter()
            .any(|r| r["value"]["n"] == 8)
            .then_some(())
    })
    .unwrap_or_else(|| panic!("no reply on {fixed}: {:?}", lines(&replies)));
    assert_eq!(
        broker.retained("rigscript/rr/status").as_deref(),
        Some("online")
    );

    // A flood: 600 commands at once (QoS 0: no acknowledgement paces them), far more than the
    // rig takes (16 wait at most) and more than the client's queue holds. Each gets a reply:
    // its handler's, or an error.
    let flood: String = (0..600)
        .map(|n| format!("{{\"n\":{}}}\n", 100 + n))
        .collect();
    let mut publisher = Command::new("mosquitto_pub")
        .args(["-h", "127.0.0.1", "-p", &broker.port.to_string()])
        .args(["-u", "ops", "-P", "ops-pw", "-t", "rigscript/rr/cmd/arm"])
        .args(["-q", "0", "-l"])
        .stdin(Stdio::piped())
        .spawn()
        .expect("start mosquitto_pub");
    std::io::Write::write_all(&mut publisher.stdin.take().unwrap(), flood.as_bytes()).unwrap();
    assert!(publisher.wait().unwrap().success());
    let flooded = |all: &[Value]| {
        all.iter()
            .filter(|r| r["value"]["n"].as_u64().is_some_and(|n| n >= 100) || r["ok"] == false)
            .count()
    };
    until(Duration::from_secs(60), || {
        (flooded(&replies_on(&replies, fixed)) >= 600).then_some(())
    })
    .unwrap_or_else(|| {
        panic!(
            "{} replies of 600: {:?}",
            flooded(&replies_on(&replies, fixed)),
            mqtt_status(&dir, "rr")
        )
    });
    std::thread::sleep(Duration::from_millis(500));
    let all = replies_on(&replies, fixed);
    assert_eq!(flooded(&all), 600, "one reply a command, none twice");
    // Every command the handler ran (its count) has its reply: 1 (mosquitto_rr's), 2, and
    // the flood's from 3 on, none missing.
    let mut ran: Vec<u64> = all
        .iter()
        .filter_map(|r| r["value"]["calls"].as_u64())
        .collect();
    ran.sort_unstable();
    let expected: Vec<u64> = (2..=ran.last().copied().unwrap_or(0)).collect();
    assert_eq!(ran, expected, "a reply for each command the rig ran");
    assert!(ran.len() > 2, "some of the flood ran: {ran:?}");
    for r in all.iter().filter(|r| r["ok"] == false) {
        assert!(
            r["error"]
                .as_str()
                .unwrap()
                .contains("commands wait for the rig already"),
            "{r}"
        );
    }
    let m = mqtt_status(&dir, "rr").unwrap();
    assert_eq!(m["dropped"]["replies"], 0, "{m}");
    assert_eq!(
        m["dropped"]["commands"].as_u64().unwrap() as usize,
        all.iter().filter(|r| r["ok"] == false).count(),
        "{m}"
    );
}

#[test]
#[ignore = "needs mosquitto, mosquitto-clients and openssl (tier 2: .ci/run installs them)"]
fn the_ends_safe_outputs_are_the_retained_state_before_the_status_goes_offline() {
    let broker = Broker::start("mqtt-end");
    let dir = TempDir::new("mqtt-end-run");
    let script = "io.outputs = 0x02;\nevery(\"100ms\", || {});\n";
    let mut rig = run_rig(&dir, "end", &broker.mqtt_table("end", "10s"), script);
    let state = |m: &str| serde_json::from_str::<Value>(m).unwrap_or(Value::Null);
    broker.retained_until("rigscript/end/state/io", |m| state(m)["outputs"] == 2);
    rig.signal(libc::SIGTERM);
    assert_eq!(rig.wait_end(), Some(143));
    broker.retained_until("rigscript/end/status", |m| m == "offline");
    let io = state(&broker.retained("rigscript/end/state/io").unwrap());
    assert_eq!(io["outputs"], 0, "the end wrote the safe value 0x00: {io}");
    assert_eq!(io["outputs_written"], 0, "{io}");
    let lab = broker.lab();
    let end = lab_rig(&lab, "end");
    assert_eq!(end["status"], "offline", "{lab}");
    assert_eq!(end["devices"]["io"]["outputs"], 0, "{lab}");
}

#[test]
#[ignore = "needs mosquitto, mosquitto-clients and openssl (tier 2: .ci/run installs them)"]
fn an_mqtt_rig_without_a_home_keeps_its_outbox_in_the_state_directory_or_names_the_key() {
    let broker = Broker::start("mqtt-home");
    let dir = TempDir::new("mqtt-home-run");
    // systemd's DynamicUser: no home to write in (here a file, so nothing can be made under
    // it), the unit's StateDirectory= given as $STATE_DIRECTORY.
    let not_a_home = dir.file("not-a-home", "");
    let state = dir.path("state");
    std::fs::create_dir(&state).unwrap();
    let config = |outbox: &str| {
        dir.file(
            "home.toml",
            &format!(
                "name = \"home\"\n[mqtt]\nurl = \"mqtt://127.0.0.1:{}\"\nrig = \"home\"\n\
                 username = \"rig\"\npassword_env = \"TEST_MQTT_PW\"\n{outbox}\n\
                 [devices.io]\nkind = \"trp-c29u\"\nsim = true\n",
                broker.port
            ),
        )
    };
    let script = dir.file("home.rhai", "every(\"100ms\", || record(\"n\", 1));\n");
    let start = |config: &str, state: &Path| {
        Command::new(rigscript())
            .args(["run", "--config", config, &script])
            .env("XDG_RUNTIME_DIR", dir.root())
            .env_remove("RUNTIME_DIRECTORY")
            .env_remove("XDG_STATE_HOME")
            .env("HOME", &not_a_home)
            .env("STATE_DIRECTORY", state)
            .env("TEST_MQTT_PW", "rig-pw")
            .stdout(Stdio::null())
            .stderr(File::create(dir.path("home.log")).unwrap())
            .spawn()
            .expect("start rigscript run")
    };
    let mut rig = Proc(start(&config(""), &state));
    broker.retained_until("rigscript/home/status", |m| m == "online");
    assert!(
        state.join("outbox/home.records").exists(),
        "the outbox in $STATE_DIRECTORY: {}",
        std::fs::read_to_string(dir.path("home.log")).unwrap_or_default()
    );
    rig.signal(libc::SIGTERM);
    assert_eq!(rig.wait_end(), Some(143));
    // Nowhere to write: a clear error naming the key that sets the place.
    let nowhere = Path::new(&not_a_home).join("state");
    for (outbox, says) in [
        ("", "set [mqtt] outbox in rig.toml"),
        (
            "outbox = \"/dev/null/outbox\"",
            "rig.toml's [mqtt] outbox names it",
        ),
    ] {
        let mut rig = Proc(start(&config(outbox), &nowhere));
        assert_eq!(rig.wait_end(), Some(2));
        let log = std::fs::read_to_string(dir.path("home.log")).unwrap();
        assert!(log.contains("mqtt: outbox ") && log.contains(says), "{log}");
    }
}

/// A broker of the test's own that accepts every connection with a CONNACK saying Server
/// Keep Alive 0 and answers pings; the connections and pings it saw.
fn keep_alive_off_broker() -> (u16, std::sync::Arc<[std::sync::atomic::AtomicU64; 2]>) {
    use std::io::{Read, Write};
    use std::sync::atomic::{AtomicU64, Ordering};
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let seen = std::sync::Arc::new([AtomicU64::new(0), AtomicU64::new(0)]);
    let counts = std::sync::Arc::clone(&seen);
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            let Ok(mut s) = stream else { return };
            counts[0].fetch_add(1, Ordering::SeqCst);
            let counts = std::sync::Arc::clone(&counts);
            std::thread::spawn(move || loop {
                let mut header = [0u8; 1];
                if s.read_exact(&mut header).is_err() {
                    return;
                }
                let (mut length, mut shift) = (0usize, 0);
                loop {
                    let mut b = [0u8; 1];
                    if s.read_exact(&mut b).is_err() {
                        return;
                    }
                    length |= usize::from(b[0] & 0x7f) << shift;
                    shift += 7;
                    if b[0] & 0x80 == 0 {
                        break;
                    }
                }
                let mut body = vec![0u8; length];
                if s.read_exact(&mut body).is_err() {
                    return;
                }
                let answer: &[u8] = match header[0] >> 4 {
                    // CONNACK: session not present, success, properties: Server Keep Alive 0.
                    1 => &[0x20, 0x06, 0x00, 0x00, 0x03, 0x13, 0x00, 0x00],
                    12 => {
                        counts[1].fetch_add(1, Ordering::SeqCst);
                        &[0xd0, 0x00]
                    }
                    _ => &[],
                };
                if s.write_all(answer).is_err() {
                    return;
                }
            });
        }
    });
    (port, seen)
}

#[test]
#[ignore = "needs mosquitto, mosquitto-clients and openssl (tier 2: .ci/run installs them)"]
fn a_server_keep_alive_of_zero_is_taken_as_off_not_as_a_ping_at_every_turn() {
    use std::sync::atomic::Ordering;
    let (port, seen) = keep_alive_off_broker();
    let dir = TempDir::new("mqtt-ka0-run");
    let mqtt = format!(
        "[mqtt]\nurl = \"mqtt://127.0.0.1:{port}\"\nrig = \"ka0\"\nkeepalive = \"5s\"\n\
         outbox = \"{}\"\n",
        dir.path("outbox").display()
    );
    let mut rig = run_rig(&dir, "ka0", &mqtt, "every(\"100ms\", || {});\n");
    let log = log_with(&dir, "ka0", "turns keep-alive off");
    assert!(
        log.contains(&format!(
            "mqtt: broker 127.0.0.1:{port} turns keep-alive off (Server Keep Alive 0)"
        )),
        "{log}"
    );
    std::thread::sleep(Duration::from_secs(5));
    let log = std::fs::read_to_string(dir.path("ka0.log")).unwrap();
    assert_eq!(
        seen[0].load(Ordering::SeqCst),
        1,
        "one connection, kept: {log}"
    );
    // Its own keep-alive, 2 s: a ping or two in 5 s (one more as it connects), not one a turn.
    let pings = seen[1].load(Ordering::SeqCst);
    assert!((1..=5).contains(&pings), "{pings} pings: {log}");
    rig.signal(libc::SIGTERM);
    assert_eq!(rig.wait_end(), Some(143));
}

#[test]
#[ignore = "needs mosquitto, mosquitto-clients and openssl (tier 2: .ci/run installs them)"]
fn lab_writes_out_the_control_characters_of_a_retained_status() {
    let broker = Broker::start("mqtt-lab-esc");
    let payload = broker.dir.path("evil");
    // Clear the screen, set the terminal's title, ring the bell, a C1 CSI.
    std::fs::write(&payload, "online\x1b[2J\x1b]0;pwned\x07\u{9b}31m").unwrap();
    broker.publish_file(
        "rig",
        "rigscript/evil/status",
        payload.to_str().unwrap(),
        true,
    );
    let out = Command::new(rigscript())
        .args([
            "lab",
            "--broker",
            &format!("mqtt://127.0.0.1:{}", broker.port),
        ])
        .args(["--username", "viewer", "--password-env", "TEST_MQTT_PW"])
        .env("TEST_MQTT_PW", "viewer-pw")
        .output()
        .expect("run rigscript lab");
    let text = stdout(&out);
    assert!(out.status.success(), "{text}");
    assert!(
        !text.chars().any(|c| c.is_control() && c != '\n'),
        "{text:?}"
    );
    assert!(
        text.contains("online\\x1b[2J\\x1b]0;pwned\\x07\\u{9b}31m"),
        "{text}"
    );
}
