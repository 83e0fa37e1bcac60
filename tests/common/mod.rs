//! Shared helpers for integration tests: the simulator as a real process on a real pty, and
//! required system tools.

#![allow(dead_code)]

pub mod rigs;

use rigscript::link::serial::SerialLink;
use rigscript::link::ByteLink;
use std::io::{BufRead, BufReader, ErrorKind, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::os::unix::fs::PermissionsExt;
use std::os::unix::net::UnixDatagram;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, Output, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Path of the rigscript binary under test.
pub fn rigscript() -> &'static str {
    env!("CARGO_BIN_EXE_rigscript")
}

/// Fails the test (never skips it) when a system tool is missing.
pub fn require_tool(tool: &str, package: &str) {
    let found = Command::new("sh")
        .arg("-c")
        .arg(format!("command -v {tool}"))
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    assert!(
        found,
        "`{tool}` is not installed: this test needs it. Install the Debian package `{package}` \
         (`.ci/run` does that) and run the tests again."
    );
}

/// A running `rigscript sim c29u` process, stopped with SIGTERM when dropped.
pub struct SimProcess {
    child: Child,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
    /// The pty path the simulator printed first.
    pub path: String,
}

impl SimProcess {
    /// Starts `rigscript sim c29u ARGS..` and waits for its pty path.
    pub fn start(args: &[&str]) -> Self {
        let mut child = Command::new(rigscript())
            .args(["sim", "c29u"])
            .args(args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("start rigscript sim c29u");
        let stdin = child.stdin.take().expect("stdin");
        let mut stdout = BufReader::new(child.stdout.take().expect("stdout"));
        let mut path = String::new();
        stdout.read_line(&mut path).expect("read the pty path");
        let path = path.trim().to_string();
        assert!(
            path.starts_with("/dev/"),
            "first line should be the pty path, got {path:?}"
        );
        Self {
            child,
            stdin,
            stdout,
            path,
        }
    }

    /// Its process ID.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Sends one control line and returns the simulator's one-line reply.
    pub fn control(&mut self, line: &str) -> String {
        writeln!(self.stdin, "{line}").expect("write control line");
        self.stdin.flush().expect("flush control line");
        let mut reply = String::new();
        self.stdout
            .read_line(&mut reply)
            .expect("read control reply");
        reply.trim().to_string()
    }

    /// The simulator's state as JSON.
    pub fn state(&mut self) -> serde_json::Value {
        let line = self.control("state");
        serde_json::from_str(&line).unwrap_or_else(|e| panic!("state is not JSON ({e}): {line}"))
    }

    /// Polls the simulator's state until `pred` holds of it, or `limit` passes; the last state.
    pub fn wait_for(
        &mut self,
        limit: Duration,
        pred: impl Fn(&serde_json::Value) -> bool,
    ) -> serde_json::Value {
        let start = Instant::now();
        loop {
            let s = self.state();
            if pred(&s) || start.elapsed() > limit {
                return s;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Sends SIGTERM and waits for the process; returns its exit code.
    pub fn terminate(mut self) -> Option<i32> {
        self.signal_term();
        self.child.wait().ok().and_then(|s| s.code())
    }

    /// Kills the simulator at once (SIGKILL), as a pulled cable would end the line, and waits.
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    fn signal_term(&mut self) {
        let _ = Command::new("kill")
            .arg("-TERM")
            .arg(self.child.id().to_string())
            .status();
    }
}

impl Drop for SimProcess {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            self.signal_term();
            for _ in 0..100 {
                if let Ok(Some(_)) = self.child.try_wait() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(10));
            }
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

/// The systemd units rigscript ships (packaging/systemd), by file name.
pub const UNITS: [&str; 3] = [
    "rigscript@.service",
    "rigscript-check@.service",
    "rigscript-check@.timer",
];

/// Asserts `systemd-analyze verify` takes the `UNITS` as instances without a word, each unit's
/// text as `text_of` gives it for its name (with its program pointed at a binary that exists:
/// verify looks for it).
pub fn assert_systemd_accepts(tag: &str, text_of: impl Fn(&str) -> String) {
    require_tool("systemd-analyze", "systemd");
    let dir = TempDir::new(tag);
    for unit in UNITS {
        std::fs::write(dir.path(unit), text_of(unit)).unwrap();
    }
    let out = Command::new("systemd-analyze")
        .current_dir(dir.root())
        .args([
            "verify",
            "./rigscript@interlock.service",
            "./rigscript-check@bench.service",
            "./rigscript-check@bench.timer",
        ])
        .output()
        .expect("run systemd-analyze");
    let said = format!("{}{}", stdout(&out), stderr(&out));
    assert!(out.status.success(), "systemd-analyze verify: {said}");
    assert_eq!(said.trim(), "", "systemd-analyze warns");
}

/// Sends `signal` (as `kill` writes it: `-TERM`) to process `pid`, failing the test if it
/// cannot.
pub fn kill(pid: impl ToString, signal: &str) {
    let pid = pid.to_string();
    let ok = Command::new("kill")
        .args([signal, &pid])
        .status()
        .expect("run kill")
        .success();
    assert!(ok, "kill {signal} {pid}");
}

/// Waits for `child` until it exits or `limit` passes (then kills it: a test must not hang);
/// its exit status, or `None` if it had to be killed.
pub fn wait_at_most(child: &mut Child, limit: Duration) -> Option<std::process::ExitStatus> {
    let started = Instant::now();
    while started.elapsed() < limit {
        if let Ok(Some(status)) = child.try_wait() {
            return Some(status);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = child.kill();
    let _ = child.wait();
    None
}

/// Runs a command and returns its output.
pub fn run(program: &str, args: &[&str]) -> Output {
    Command::new(program)
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {program}: {e}"))
}

/// A directory of a test's own (made by `tempfile`, named after `tag`), removed when dropped.
pub struct TempDir(tempfile::TempDir);

impl TempDir {
    /// A new empty directory whose name starts with `rigscript-TAG-`.
    pub fn new(tag: &str) -> Self {
        let dir = tempfile::Builder::new()
            .prefix(&format!("rigscript-{tag}-"))
            .tempdir()
            .expect("a temporary directory");
        // Open to others as a plain `mkdir` makes it: the tests of what another uid may read
        // must meet the modes of the files themselves, not a private parent.
        std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755)).unwrap();
        Self(dir)
    }

    /// The directory itself.
    pub fn root(&self) -> &Path {
        self.0.path()
    }

    /// The path of `name` in it.
    pub fn path(&self, name: &str) -> PathBuf {
        self.root().join(name)
    }

    /// Writes `text` to `name` in it and returns the file's path as text.
    pub fn file(&self, name: &str, text: &str) -> String {
        let p = self.path(name);
        std::fs::write(&p, text).unwrap();
        p.display().to_string()
    }
}

impl std::ops::Deref for TempDir {
    type Target = Path;

    fn deref(&self) -> &Path {
        self.root()
    }
}

impl AsRef<Path> for TempDir {
    fn as_ref(&self) -> &Path {
        self.root()
    }
}

impl AsRef<std::ffi::OsStr> for TempDir {
    fn as_ref(&self) -> &std::ffi::OsStr {
        self.root().as_os_str()
    }
}

/// What a finished command wrote on stderr, as text.
pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// What a finished command wrote on stdout, as text.
pub fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// What a finished command wrote on stdout, then on stderr, as text.
pub fn both(o: &Output) -> String {
    format!("{}{}", stdout(o), stderr(o))
}

/// The rest of a child's piped stderr, read until the child closes it.
pub fn read_stderr(child: &mut Child) -> String {
    let mut text = String::new();
    if let Some(err) = child.stderr.as_mut() {
        err.read_to_string(&mut text)
            .expect("read the child's stderr");
    }
    text
}

/// `rigscript run ARGS` with stdout discarded and stderr piped (`read_stderr`), for a caller
/// to add to (its environment, its limits) before spawning it.
pub fn run_command(args: &[&str]) -> Command {
    let mut command = Command::new(rigscript());
    command
        .arg("run")
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    command
}

/// Starts `rigscript run ARGS` as `run_command` makes it.
pub fn start_run(args: &[&str]) -> Child {
    run_command(args).spawn().expect("start rigscript run")
}

/// Fails loudly unless the tests run as root (CI does): a second uid needs it, through the
/// tools named.
pub fn require_root(tools: &[&str]) {
    // SAFETY: geteuid has no preconditions and cannot fail.
    let uid = unsafe { libc::geteuid() };
    assert_eq!(
        uid,
        0,
        "this test needs root (a second uid or a private mount namespace through {}); run it as \
         root, as CI does",
        tools.join(", ")
    );
    for tool in tools {
        require_tool(tool, "util-linux");
    }
}

/// `program ARGS` run as uid and gid 65534 (nobody) with no groups, through `setpriv`; its
/// output.
pub fn as_nobody(program: &str, args: &[&str]) -> Output {
    require_root(&["setpriv"]);
    Command::new("setpriv")
        .args(["--reuid=65534", "--regid=65534", "--clear-groups", program])
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {program} through setpriv: {e}"))
}

/// One systemd notification as a test's socket received it, and when.
pub struct Notification {
    /// The datagram's text, such as `READY=1\nSTATUS=...`.
    pub text: String,
    /// When it arrived.
    pub at: Instant,
}

/// Receives notifications on `socket` (bound as systemd binds its notify socket) until one
/// for which `last` holds, or 30 s pass.
pub fn receive_notifications(
    socket: &UnixDatagram,
    last: impl Fn(&str) -> bool,
) -> Vec<Notification> {
    socket
        .set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut got = Vec::new();
    let mut buf = [0u8; 4096];
    while Instant::now() < deadline {
        if let Ok(n) = socket.recv(&mut buf) {
            let text = String::from_utf8_lossy(&buf[..n]).into_owned();
            let done = last(&text);
            got.push(Notification {
                text,
                at: Instant::now(),
            });
            if done {
                break;
            }
        }
    }
    got
}

/// Relays each accepted connection to the serial port at `path`, one at a time, until the
/// client hangs up (what a serial device server or ser2net does); returns the listening port.
pub fn start_relay(path: &str) -> u16 {
    start_switchable_relay(path, Arc::default())
}

/// `start_relay` whose line goes silent while `silent` holds: bytes either way are dropped and
/// the connection stays up, as with a module that stopped answering behind a working server.
pub fn start_switchable_relay(path: &str, silent: Arc<AtomicBool>) -> u16 {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let path = path.to_string();
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            let stream = match stream {
                Ok(stream) => stream,
                Err(e) => {
                    eprintln!("relay on port {port}: accept failed: {e}");
                    break;
                }
            };
            let serial = match SerialLink::open(&path, 9600) {
                Ok(serial) => serial,
                Err(e) => {
                    eprintln!("relay on port {port}: cannot open {path}: {e}");
                    break;
                }
            };
            match relay(stream, serial, &silent) {
                Ended::Client => {}
                // Shown with the test's output when it fails: why its server hung up.
                Ended::Socket(why) => eprintln!("relay on port {port}: {why}"),
                // The module is gone: so is the server. A later client must not be relayed
                // to `path` again, which may by then name another test's pty (pty numbers are
                // reused), held while that client keeps reconnecting.
                Ended::Serial(why) => {
                    eprintln!("relay on port {port} to {path} stops: {why}");
                    break;
                }
            }
        }
    });
    port
}

/// How a relayed connection ended.
enum Ended {
    /// The client hung up.
    Client,
    /// The connection failed.
    Socket(String),
    /// The serial port failed (its module went away).
    Serial(String),
}

fn relay(mut socket: TcpStream, mut serial: SerialLink, silent: &AtomicBool) -> Ended {
    socket
        .set_read_timeout(Some(Duration::from_millis(1)))
        .unwrap();
    let mut buf = [0u8; 512];
    loop {
        match socket.read(&mut buf) {
            Ok(0) => return Ended::Client,
            Ok(_) if silent.load(Ordering::SeqCst) => {}
            Ok(n) => {
                if let Err(e) = serial.write_all(&buf[..n]) {
                    return Ended::Serial(format!("serial write: {e}"));
                }
            }
            Err(e)
                if matches!(
                    e.kind(),
                    ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted
                ) => {}
            Err(e) => return Ended::Socket(format!("socket read: {e}")),
        }
        match serial.read(&mut buf, Duration::from_millis(1)) {
            Ok(0) => {}
            Ok(_) if silent.load(Ordering::SeqCst) => {}
            Ok(n) => {
                if let Err(e) = socket.write_all(&buf[..n]) {
                    return Ended::Socket(format!("socket write: {e}"));
                }
            }
            Err(e) => return Ended::Serial(format!("serial read: {e}")),
        }
    }
}

/// `probe` until it gives something, or `None` after `limit`.
pub fn until<T>(limit: Duration, mut probe: impl FnMut() -> Option<T>) -> Option<T> {
    let start = Instant::now();
    loop {
        if let Some(v) = probe() {
            return Some(v);
        }
        if start.elapsed() > limit {
            return None;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A run of `script` (named `file`) on simulated devices in virtual time from the epoch, its log
/// kept, served a control queue: the rig, the queue's asker, and the run's stop flag.
pub fn served(
    config: rigscript::config::RigConfig,
    script: &str,
    file: &str,
) -> (
    rigscript::Rig,
    rigscript::runtime::requests::Requester,
    Arc<std::sync::atomic::AtomicUsize>,
) {
    let flag = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let mut rig = rigscript::RigBuilder::from_config(config)
        .simulated()
        .virtual_time_from(chrono::DateTime::UNIX_EPOCH)
        .keep_log()
        .stop_flag(Arc::clone(&flag))
        .start(script, file)
        .unwrap();
    let (ask, requests) = rigscript::runtime::requests::queue(&flag);
    let field = rig.sim.clone();
    rig.runner.serve(requests, file, field);
    (rig, ask, flag)
}

/// A rig of one module on `sim`'s pty, safe value 0x05 and a 1 s host watchdog, polled every
/// 20 ms, and a script that drives its outputs to 0xF0 and ticks every 100 ms: the directory
/// (named after `tag`), rig.toml's path and the script's.
pub fn watched_rig(sim: &SimProcess, tag: &str) -> (TempDir, String, String) {
    let dir = TempDir::new(tag);
    let config = dir.file(
        "rig.toml",
        &format!(
            "period = \"20ms\"\n[devices.io]\nkind = \"trp-c29u\"\nport = \"{}\"\n\
             safe_value = 0x05\nwatchdog = \"1s\"\n",
            sim.path
        ),
    );
    let script = dir.file(
        "work.rhai",
        "io.outputs = 0xF0;\nevery(\"100ms\", || {});\n",
    );
    (dir, config, script)
}

/// What became of a rig of two modules when one was lost (`lose_a_module`).
pub struct Loss {
    /// From the kill of the lost module's simulator until the other read back its safe value
    /// (`None`: not within the limit).
    pub to_safe: Option<Duration>,
    /// The run's log (its stderr), once it was stopped.
    pub log: String,
}

impl Loss {
    /// Asserts the rest of the rig read back safe within `limit` of the loss (a bound on being
    /// told at once, not a timing target: benches/loss.rs measures that).
    pub fn assert_safe_within(&self, limit: Duration) {
        let to_safe = self
            .to_safe
            .unwrap_or_else(|| panic!("never safe: {}", self.log));
        assert!(to_safe < limit, "{to_safe:?}: {}", self.log);
    }
}

/// How `lose_a_module` loses the module.
pub enum Cut {
    /// Kills its simulator: its pty closes, as an unplugged adapter's does.
    Kill,
    /// Sets the flag a `start_switchable_relay` silences its line with: the connection stays
    /// up, nothing answers.
    Silence(Arc<AtomicBool>),
}

/// Two simulated modules without host watchdogs, `kept` on its pty and `lost` at the port
/// `port` makes of its pty (the pty itself, or a TCP relay to it), driven by a run at
/// `grace = "1s"` whose script has only a 30 s timer: nothing polls. Once both drive the
/// script's outputs, waits `settle`, loses `lost` as `cut` says, and times until `kept` reads
/// back its safe value, within `limit`.
pub fn lose_a_module(
    tag: &str,
    port: impl FnOnce(&str) -> String,
    (cut, settle): (Cut, Duration),
    limit: Duration,
) -> Loss {
    let mut lost = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let mut kept = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let dir = TempDir::new(tag);
    let module = |name: &str, port: &str| {
        format!("[devices.{name}]\nkind = \"trp-c29u\"\nport = \"{port}\"\nsafe_value = 0x05\n")
    };
    let config = dir.file(
        "rig.toml",
        &format!(
            "grace = \"1s\"\n{}{}",
            module("kept", &kept.path),
            module("lost", &port(&lost.path))
        ),
    );
    let script = dir.file(
        "slow.rhai",
        "kept.outputs = 0xF0;\nlost.outputs = 0xF0;\nevery(\"30s\", || {});\n",
    );
    let mut run = start_run(&["--config", &config, &script]);
    let driven = until(Duration::from_secs(10), || {
        (kept.state()["do"] == 0xF0 && lost.state()["do"] == 0xF0).then_some(())
    });
    let to_safe = driven.and_then(|()| {
        std::thread::sleep(settle);
        match &cut {
            Cut::Kill => lost.kill(),
            Cut::Silence(flag) => flag.store(true, Ordering::SeqCst),
        }
        let killed = Instant::now();
        loop {
            if kept.state()["do"] == 0x05 {
                return Some(killed.elapsed());
            }
            if killed.elapsed() > limit {
                return None;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    });
    let _ = Command::new("kill")
        .args(["-TERM", &run.id().to_string()])
        .status();
    let _ = run.wait();
    let log = read_stderr(&mut run);
    Loss { to_safe, log }
}
