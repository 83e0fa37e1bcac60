//! The web page's HTTP API against real `rigscript run --sim --ui 127.0.0.1:0` processes,
//! through a small HTTP client over `TcpStream`: the state follows the simulated field that
//! `POST /api/sim` drives, the event stream delivers the run's events, `/metrics` tells the
//! ticks, errors have their status, and hostile clients cost the loop no tick; forcing
//! (`force = true`: set, expired, removed, refused, cancelled by the safe state; from the page,
//! the API and `rigscript force`), tokens on a non-loopback bind, and a headless Chromium.
//! Only the owner changes the rig (the run's key, which another uid cannot read; the
//! environment's token checked as rig.toml's), and trickling clients are cut off at the
//! deadline and never keep the owner out.

use crate::common;

use crate::common::{rigscript, stderr, stdout, until, TempDir};
use serde_json::Value;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::process::{Child, Command, Stdio};
use std::sync::{mpsc, Arc, Mutex};
use std::time::{Duration, Instant};

/// A run serving its page; killed if the test fails before it ends.
struct Served {
    child: Child,
    addr: SocketAddr,
    /// The run's key, from the link it logs (`ui: http://ADDR/#key=KEY`).
    key: String,
    /// The run's log lines so far.
    log: Arc<Mutex<Vec<String>>>,
    dir: TempDir,
}

impl Drop for Served {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

/// Starts `rigscript run ARGS.. --ui 127.0.0.1:0` and waits for the address it serves.
fn serve(tag: &str, args: &[&str]) -> Served {
    serve_in(TempDir::new(tag), args)
}

/// `serve` with its runtime directory (and whatever files the test put there) `dir`.
fn serve_in(dir: TempDir, args: &[&str]) -> Served {
    serve_at(dir, args, "127.0.0.1:0", &[])
}

/// `serve_in` at `ui` (empty: a bare `--ui`) with `env` set; the address is reached through
/// 127.0.0.1.
fn serve_at(dir: TempDir, args: &[&str], ui: &str, env: &[(&str, &str)]) -> Served {
    let mut child = Command::new(rigscript())
        .arg("run")
        .args(args)
        .arg("--ui")
        .args((!ui.is_empty()).then_some(ui))
        .env("XDG_RUNTIME_DIR", dir.root())
        .env_remove("RUNTIME_DIRECTORY")
        .env_remove("RIGSCRIPT_UI_TOKEN")
        .env_remove("RIGSCRIPT_UI_READ_TOKEN")
        .envs(env.iter().copied())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = child.stderr.take().unwrap();
    let (tx, rx) = mpsc::channel();
    let log = Arc::new(Mutex::new(Vec::new()));
    let lines = Arc::clone(&log);
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if let Some(rest) = line.split("ui: http://").nth(1) {
                let _ = tx.send(rest.to_string());
            }
            lines.lock().unwrap().push(line);
        }
    });
    let link = rx
        .recv_timeout(Duration::from_secs(20))
        .expect("the run logs its page's address");
    let (addr, key) = link
        .split_once("/#key=")
        .expect("the link carries the run's key");
    let mut addr: SocketAddr = addr.parse().unwrap();
    if addr.ip().is_unspecified() {
        addr.set_ip(std::net::Ipv4Addr::LOCALHOST.into());
    }
    let key = key.trim().to_string();
    KEYS.lock().unwrap().push((addr, key.clone()));
    Served {
        child,
        addr,
        key,
        log,
        dir,
    }
}

/// Each served run's key by its address, for the helpers that change a rig (`post`, `delete`)
/// as the page's link would.
static KEYS: Mutex<Vec<(SocketAddr, String)>> = Mutex::new(Vec::new());

/// The `Authorization` line with the key of the run at `addr`.
fn key_line(addr: SocketAddr) -> String {
    let keys = KEYS.lock().unwrap();
    let key = keys
        .iter()
        .rev()
        .find(|(a, _)| *a == addr)
        .map(|(_, k)| k.as_str());
    key.map_or(String::new(), |k| format!("Authorization: Bearer {k}\r\n"))
}

/// Sends `head` (and `body`) raw, and reads the whole answer: (status, body).
fn exchange(addr: SocketAddr, head: &str, body: &[u8]) -> (u16, String) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    // A refused request may be cut off while it is still being sent: its answer counts.
    let _ = s.write_all(head.as_bytes());
    let _ = s.write_all(body);
    let text = read_answer(&mut s);
    let status = text
        .split(' ')
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    let body = text.split_once("\r\n\r\n").map_or("", |(_, b)| b);
    (status, body.to_string())
}

/// Reads an answer up to its `Content-Length` (a server may keep the connection), else to
/// the end.
fn read_answer(s: &mut TcpStream) -> String {
    let mut bytes = Vec::new();
    let mut chunk = [0u8; 4096];
    loop {
        let text = String::from_utf8_lossy(&bytes).to_string();
        if let Some((head, body)) = text.split_once("\r\n\r\n") {
            let length = head.lines().find_map(|l| {
                let (name, value) = l.split_once(':')?;
                name.eq_ignore_ascii_case("content-length")
                    .then(|| value.trim().parse::<usize>().ok())?
            });
            if length.is_some_and(|n| body.len() >= n) {
                return text;
            }
        }
        match s.read(&mut chunk) {
            Ok(0) | Err(_) => return String::from_utf8_lossy(&bytes).to_string(),
            Ok(n) => bytes.extend_from_slice(&chunk[..n]),
        }
    }
}

fn get(addr: SocketAddr, path: &str) -> (u16, String) {
    exchange(
        addr,
        &format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\n\r\n"),
        b"",
    )
}

fn post(addr: SocketAddr, path: &str, json: &str) -> (u16, String) {
    let head = format!(
        "POST {path} HTTP/1.1\r\nHost: {addr}\r\n{}Content-Type: application/json\r\n\
         Content-Length: {}\r\n\r\n",
        key_line(addr),
        json.len()
    );
    exchange(addr, &head, json.as_bytes())
}

fn state(addr: SocketAddr) -> Value {
    let (status, body) = get(addr, "/api/state");
    assert_eq!(status, 200, "{body}");
    serde_json::from_str(&body).unwrap()
}

fn drive(addr: SocketAddr, json: &str) {
    let (status, body) = post(addr, "/api/sim", json);
    assert_eq!(status, 200, "{json}: {body}");
}

#[test]
fn the_state_follows_the_field_that_post_sim_drives_and_the_interlock_arms() {
    let run = serve("web-state", &["scripts/interlock.rhai", "--sim"]);
    let a = run.addr;
    // The guards closed, then S12 pressed: the interlock reads the guards and arms.
    drive(a, r#"{"device":"io","action":"set_inputs","value":15}"#);
    drive(a, r#"{"device":"panel","action":"press","name":"S12"}"#);
    let s = until(Duration::from_secs(10), || {
        let s = state(a);
        let pressed = s["devices"]["panel"]["pressed"].as_array().cloned()?;
        let armed = s["devices"]["io"]["outputs"].as_u64()? & 0x0F == 0x0F;
        // The script's variables are read a few times a second: `tripped` follows.
        let untripped = script_variable(&s, "tripped")? == false;
        (armed && untripped && pressed.iter().any(|p| p == "S12")).then_some(s)
    })
    .expect("S12 pressed arms the interlock: DO0-DO3 on, the variable `tripped` false");
    assert_eq!(s["devices"]["io"]["kind"], "trp-c29u");
    assert_eq!(s["devices"]["io"]["inputs"], 15, "{s}");
    drive(a, r#"{"device":"panel","action":"release","name":"S12"}"#);
    // A guard opens: the trip.
    drive(
        a,
        r#"{"device":"io","action":"set_input","channel":2,"on":false}"#,
    );
    until(Duration::from_secs(10), || {
        (state(a)["devices"]["io"]["outputs"].as_u64()? & 0x0F == 0).then_some(())
    })
    .expect("an open guard trips the interlock");
    // The script's own state: its variable `tripped` set again, its one invariant holding.
    let s = until(Duration::from_secs(5), || {
        let s = state(a);
        (script_variable(&s, "tripped")? == true).then_some(s)
    })
    .expect("the variable `tripped` is true again after the trip");
    let invariants = s["script"]["invariants"].as_array().expect("invariants");
    assert_eq!(invariants.len(), 1, "{s}");
    assert_eq!(
        invariants[0]["name"],
        "power only with all guards closed and no stop pressed"
    );
    assert_eq!(invariants[0]["holds"], true);
    assert_eq!(invariants[0]["at"], "scripts/interlock.rhai:53:1");
    // Tripped, the script reads no guard; whoever asks for the state watches, so the inputs
    // are read for them: the guards closed again show while the outputs stay off.
    drive(a, r#"{"device":"io","action":"set_inputs","value":15}"#);
    let s = until(Duration::from_secs(5), || {
        let s = state(a);
        (s["devices"]["io"]["inputs"] == 15).then_some(s)
    })
    .expect("the guards closed again are shown while tripped");
    assert_eq!(
        s["devices"]["io"]["outputs"].as_u64().unwrap() & 0x0F,
        0,
        "{s}"
    );
    assert!(s["devices"]["panel"]["rotaries"].is_object(), "{s}");
    // The counters take 33.9 ms at the module's 9600 baud: no 20 ms tick has the time, and
    // the state says so rather than stretch a tick.
    let s = until(Duration::from_secs(5), || {
        let s = state(a);
        s["devices"]["io"]["not_shown"].is_array().then_some(s)
    })
    .expect("the counters said not to be shown");
    assert!(s["devices"]["io"]["counters"].is_null(), "{s}");
    let why = s["devices"]["io"]["not_shown"][0]
        .as_str()
        .unwrap_or_default();
    assert!(why.starts_with("counters: a read takes 33.9 ms"), "{s}");
    assert_eq!(s["ticks"]["overruns"], 0, "{s}");
}

/// The value of the script's top-level variable `name` in a state, if shown.
fn script_variable(s: &Value, name: &str) -> Option<Value> {
    s["script"]["variables"]["shown"]
        .as_array()?
        .iter()
        .find(|v| v["name"] == name)
        .map(|v| v["value"].clone())
}

#[test]
fn bad_requests_have_their_status_and_a_message() {
    let run = serve("web-errors", &["scripts/interlock.rhai", "--sim"]);
    let a = run.addr;
    let cases = [
        (post(a, "/api/sim", "{not json"), 400, "a drive action is"),
        (
            post(a, "/api/sim", r#"{"device":"io","action":"explode"}"#),
            400,
            "explode",
        ),
        (
            post(a, "/api/sim", r#"{"device":"nope","action":"fail"}"#),
            404,
            "no device called nope",
        ),
        (
            post(
                a,
                "/api/sim",
                r#"{"device":"panel","action":"press","name":"S99"}"#,
            ),
            409,
            "S99",
        ),
        (get(a, "/api/sim"), 405, "not served"),
        (get(a, "/etc/passwd"), 404, "is not here"),
        (
            exchange(
                a,
                &format!(
                    "POST /api/sim HTTP/1.1\r\n{}Content-Type: text/plain\r\n\
                     Content-Length: 2\r\n\r\n",
                    key_line(a)
                ),
                b"{}",
            ),
            415,
            "application/json",
        ),
        (
            exchange(
                a,
                "GET /api/state HTTP/1.1\r\nHost: evil.example:80\r\n\r\n",
                b"",
            ),
            403,
            "is not this server",
        ),
    ];
    for ((status, body), want, says) in cases {
        assert_eq!(status, want, "{body}");
        let v: Value = serde_json::from_str(&body).unwrap();
        let message = v["error"].as_str().unwrap();
        assert!(message.contains(says), "{message}");
    }
}

#[test]
fn a_non_loopback_address_or_one_in_use_is_refused_before_anything_starts() {
    let dir = TempDir::new("web-refused");
    let out = Command::new(rigscript())
        .args([
            "run",
            "scripts/interlock.rhai",
            "--sim",
            "--ui",
            "0.0.0.0:0",
        ])
        .env("XDG_RUNTIME_DIR", dir.root())
        .env_remove("RIGSCRIPT_UI_TOKEN")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2), "{out:?}");
    let said = stderr(&out);
    assert!(
        said.contains("only with a token: set ui_token in rig.toml or RIGSCRIPT_UI_TOKEN"),
        "{said}"
    );
    // An address in use: exit 3, nothing started.
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = taken.local_addr().unwrap().to_string();
    let out = Command::new(rigscript())
        .args(["run", "scripts/interlock.rhai", "--sim", "--ui", &addr])
        .env("XDG_RUNTIME_DIR", dir.root())
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(3), "{out:?}");
    let said = stderr(&out);
    assert!(said.contains("cannot serve the web page on"), "{said}");
    assert!(!said.contains("interlock ready"), "{said}");
}

/// Reads from an event stream until a message satisfies `want`, or 10 s.
fn await_event(stream: &mut BufReader<TcpStream>, want: impl Fn(&Value) -> bool) -> Option<Value> {
    let start = Instant::now();
    let mut line = String::new();
    while start.elapsed() < Duration::from_secs(10) {
        line.clear();
        match stream.read_line(&mut line) {
            Ok(0) => return None,
            Ok(_) => {}
            Err(_) => continue,
        }
        if let Some(data) = line.strip_prefix("data: ") {
            if let Ok(v) = serde_json::from_str::<Value>(data) {
                if want(&v) {
                    return Some(v);
                }
            }
        }
    }
    None
}

#[test]
fn the_event_stream_delivers_the_run_s_events_and_metrics_tell_its_figures() {
    let run = serve("web-events", &["scripts/interlock.rhai", "--sim"]);
    let a = run.addr;
    let mut s = TcpStream::connect(a).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(1))).unwrap();
    write!(s, "GET /api/events HTTP/1.1\r\nHost: {a}\r\n\r\n").unwrap();
    let mut stream = BufReader::new(s);
    let mut status = String::new();
    stream.read_line(&mut status).unwrap();
    assert!(status.starts_with("HTTP/1.1 200"), "{status}");
    assert!(await_event(&mut stream, |v| v["event"] == "tick").is_some());
    drive(a, r#"{"device":"io","action":"set_inputs","value":15}"#);
    drive(a, r#"{"device":"panel","action":"press","name":"S12"}"#);
    let pressed = await_event(&mut stream, |v| {
        v["event"] == "inputs" && v["reading"]["pressed"][0] == "S12"
    });
    assert!(pressed.is_some(), "the press is streamed");
    let outputs = await_event(&mut stream, |v| {
        v["event"] == "outputs" && v["device"] == "io" && v["value"] == 15
    });
    assert!(outputs.is_some(), "the outputs written are streamed");
    let (code, text) = get(a, "/metrics");
    assert_eq!(code, 200);
    for name in [
        "rigscript_ticks_total ",
        "rigscript_overruns_total ",
        "rigscript_jitter_p99_seconds ",
        "rigscript_device_online{device=\"io\"} 1",
        "rigscript_device_inputs{device=\"io\"} 15",
        "rigscript_events_dropped_total{consumer=\"web history\"} 0",
    ] {
        assert!(
            text.lines().any(|l| l.starts_with(name)),
            "no {name} in\n{text}"
        );
    }
    // The history keeps what the plots need across a reload.
    let (code, history) = get(a, "/api/history");
    assert_eq!(code, 200);
    let h: Value = serde_json::from_str(&history).unwrap();
    let points = h["points"].as_array().unwrap();
    assert!(
        points
            .iter()
            .any(|p| p["device"] == "io" && p["series"] == "inputs" && p["value"] == 15),
        "{history}"
    );
}

#[test]
fn hostile_clients_cost_the_loop_no_tick_and_are_told_what_is_wrong() {
    let dir = TempDir::new("web-hostile-script");
    let script = dir.file(
        "steady.rhai",
        "every(\"200ms\", || { io.outputs = io.inputs; });\n",
    );
    let run = serve("web-hostile", &["--sim", "--period", "200ms", &script]);
    let a = run.addr;
    let before = state(a);
    let (code, _) = exchange(a, "\x00\x01 garbage\r\n\r\n", b"");
    assert_eq!(code, 400);
    let huge = format!("GET / HTTP/1.1\r\nX: {}\r\n\r\n", "a".repeat(64 * 1024));
    let (code, _) = exchange(a, &huge, b"");
    assert_eq!(code, 431);
    let (code, body) = exchange(
        a,
        "POST /api/sim HTTP/1.1\r\nContent-Type: application/json\r\nContent-Length: \
         1073741824\r\n\r\n",
        b"",
    );
    assert_eq!(code, 413, "{body}");
    // Hundreds of connections that send nothing hold no place against a request: each
    // newcomer takes the place of the one that has waited longest.
    let idle: Vec<TcpStream> = (0..300).map(|_| TcpStream::connect(a).unwrap()).collect();
    let (code, body) = get(a, "/api/state");
    assert_eq!(
        code, 200,
        "answered while 300 idle connections are open: {body}"
    );
    // A viewer that never reads its stream.
    let mut stalled = TcpStream::connect(a).unwrap();
    write!(stalled, "GET /api/events HTTP/1.1\r\nHost: {a}\r\n\r\n").unwrap();
    drop(idle);
    // The silent clients are let go within 5 s; then the state answers again, ticks on.
    let after = until(Duration::from_secs(20), || {
        let (code, body) = get(a, "/api/state");
        let s: Value = serde_json::from_str(&body).ok()?;
        (code == 200 && s["ticks"]["count"].as_u64() > before["ticks"]["count"].as_u64())
            .then_some(s)
    })
    .expect("the loop ticks on and answers");
    assert_eq!(after["script"]["state"], "running");
    assert_eq!(
        after["ticks"]["overruns"], before["ticks"]["overruns"],
        "no tick overran during the attack: {after}"
    );
    drop(stalled);
}

#[test]
fn the_page_and_its_plot_library_come_from_the_binary_and_weigh_little() {
    let run = serve("web-page", &["scripts/interlock.rhai", "--sim"]);
    let a = run.addr;
    let (code, page) = get(a, "/");
    assert_eq!(code, 200);
    assert!(page.contains("<script src=\"/uplot.js\">"), "{page}");
    assert!(
        !page.contains("http://") && !page.contains("https://"),
        "no CDN"
    );
    let (code, js) = get(a, "/uplot.js");
    assert_eq!(code, 200);
    assert!(js.contains("uPlot"));
    let (code, css) = get(a, "/uplot.css");
    assert_eq!(code, 200);
    let (code, layout) = get(a, "/api/layout");
    assert_eq!(code, 200);
    let layout: Value = serde_json::from_str(&layout).unwrap();
    assert_eq!(layout["switches"].as_array().unwrap().len(), 45);
    assert_eq!(layout["rotaries"].as_array().unwrap().len(), 14);
    let weight = page.len() + js.len() + css.len();
    assert!(weight <= 200 * 1024, "the first load is {weight} bytes");
}

/// A headless Chromium driven through chromedriver's WebDriver protocol (plain JSON over
/// HTTP); the browser and its driver end with it.
struct Browser {
    driver: Child,
    addr: SocketAddr,
    session: String,
}

/// What WebDriver calls an element in its answers.
const ELEMENT: &str = "element-6066-11e4-a52e-4f735466cecf";

impl Browser {
    fn start() -> Self {
        common::require_tool("chromium", "chromium");
        common::require_tool("chromedriver", "chromium-driver");
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let driver = Command::new("chromedriver")
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let addr: SocketAddr = format!("127.0.0.1:{port}").parse().unwrap();
        let mut b = Browser {
            driver,
            addr,
            session: String::new(),
        };
        until(Duration::from_secs(20), || {
            TcpStream::connect(addr).ok()?;
            (b.call("GET", "/status", None)["value"]["ready"] == true).then_some(())
        })
        .expect("chromedriver answers");
        let caps = serde_json::json!({"capabilities": {"alwaysMatch": {"goog:chromeOptions": {
            "args": ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"]
        }}}});
        let answer = b.call("POST", "/session", Some(caps));
        b.session = answer["value"]["sessionId"]
            .as_str()
            .unwrap_or_else(|| panic!("no session: {answer}"))
            .to_string();
        b
    }

    fn call(&self, method: &str, path: &str, body: Option<Value>) -> Value {
        let body = body.map(|b| b.to_string()).unwrap_or_default();
        let head = format!(
            "{method} {path} HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n\
             Content-Type: application/json\r\nContent-Length: {}\r\n\r\n",
            self.addr,
            body.len()
        );
        let (_, answer) = exchange(self.addr, &head, body.as_bytes());
        serde_json::from_str(&answer).unwrap_or(Value::Null)
    }

    fn session(&self, method: &str, path: &str, body: Option<Value>) -> Value {
        self.call(method, &format!("/session/{}{path}", self.session), body)
    }

    fn open(&self, url: &str) {
        self.session("POST", "/url", Some(serde_json::json!({ "url": url })));
    }

    /// The element `css` finds now, if any.
    fn find(&self, css: &str) -> Option<String> {
        let found = self.session(
            "POST",
            "/element",
            Some(serde_json::json!({"using": "css selector", "value": css})),
        );
        found["value"][ELEMENT].as_str().map(String::from)
    }

    /// Clicks what `css` finds (the page redraws: a stale element is found again).
    fn click(&self, css: &str) {
        until(Duration::from_secs(10), || {
            let e = self.find(css)?;
            let done = self.session(
                "POST",
                &format!("/element/{e}/click"),
                Some(serde_json::json!({})),
            );
            done["value"].is_null().then_some(())
        })
        .unwrap_or_else(|| panic!("could not click {css}"));
    }

    /// The page as a PNG, `width` x `height` CSS pixels.
    fn screenshot(&self, width: u32, height: u32) -> Vec<u8> {
        self.session(
            "POST",
            "/window/rect",
            Some(serde_json::json!({"width": width, "height": height})),
        );
        self.session(
            "POST",
            "/execute/sync",
            Some(serde_json::json!({"script": "window.scrollTo(0, 0)", "args": []})),
        );
        let shot = self.session("GET", "/screenshot", None);
        let text = shot["value"].as_str().expect("a screenshot");
        from_base64(text)
    }

    /// What `GET /element/{e}/WHAT` reads of the element `css` finds; found again when the
    /// page redrew it between the find and the read (a stale element is not an answer).
    fn read(&self, css: &str, what: &str) -> Option<serde_json::Value> {
        for _ in 0..5 {
            let e = self.find(css)?;
            let got = self.session("GET", &format!("/element/{e}/{what}"), None);
            if got["value"]["error"] != "stale element reference" {
                return Some(got["value"].clone());
            }
        }
        None
    }

    /// The text of what `css` finds.
    fn text(&self, css: &str) -> Option<String> {
        self.read(css, "text")?.as_str().map(String::from)
    }

    /// Whether what `css` finds has class `class`.
    fn has_class(&self, css: &str, class: &str) -> Option<bool> {
        let class_list = self.read(css, "attribute/class")?;
        Some(class_list.as_str()?.split(' ').any(|c| c == class))
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        if !self.session.is_empty() {
            self.session("DELETE", "", None);
        }
        let _ = self.driver.kill();
        let _ = self.driver.wait();
    }
}

#[test]
#[ignore = "needs chromium and chromium-driver (tier 2: .ci/run installs them)"]
fn a_browser_closes_the_guards_presses_s12_and_sees_the_power_lamps_then_the_trip() {
    let run = serve("web-browser", &["scripts/interlock.rhai", "--sim"]);
    let a = run.addr;
    let browser = Browser::start();
    browser.open(&format!("http://{a}/#key={}", run.key));
    until(Duration::from_secs(20), || browser.find("#sw-panel-S12"))
        .expect("the page shows the panel's switches");
    // The four guards: each input lamp clicked energizes its input.
    for n in 0..4 {
        browser.click(&format!("#di-io-{n}"));
    }
    until(Duration::from_secs(10), || {
        let s = state(a);
        (s["devices"]["io"]["outputs"].as_u64()? & 0x80 == 0x80).then_some(())
    })
    .expect("tripped before the reset");
    browser.click("#sw-panel-S12");
    until(Duration::from_secs(15), || {
        (0..4)
            .all(|n| browser.has_class(&format!("#do-io-{n}"), "on") == Some(true))
            .then_some(())
    })
    .expect("the power lamps DO0-DO3 light once S12 is clicked");
    let s = state(a);
    assert_eq!(s["devices"]["io"]["outputs"], 15, "{s}");
    assert_eq!(s["devices"]["panel"]["pressed"][0], "S12", "{s}");
    assert_eq!(browser.has_class("#sw-panel-S12", "on"), Some(true));
    // The script's state: `tripped` false once armed, its invariant shown holding.
    until(Duration::from_secs(10), || {
        (browser.text("#var-tripped")? == "false").then_some(())
    })
    .expect("the page shows the script's variable `tripped` false once armed");
    assert_eq!(browser.has_class("#inv-0", "holds"), Some(true));
    let invariant = browser.text("#inv-0").unwrap_or_default();
    assert!(
        invariant.contains("power only with all guards closed and no stop pressed"),
        "{invariant}"
    );
    // A guard opened from the page: the trip, on the page and in the state.
    browser.click("#di-io-2");
    until(Duration::from_secs(15), || {
        (browser.has_class("#do-io-0", "on") == Some(false)
            && browser.has_class("#do-io-7", "on") == Some(true))
        .then_some(())
    })
    .expect("the page shows the trip: power off, the trip lamp DO7 on");
    let s = state(a);
    assert_eq!(s["devices"]["io"]["outputs"], 0x80, "{s}");
    until(Duration::from_secs(10), || {
        (browser.text("#var-tripped")? == "true").then_some(())
    })
    .expect("the page shows `tripped` true after the trip");
    // The guide's picture of the page (docs/guide/web-page.png is this file, copied).
    let png = browser.screenshot(1000, 1250);
    assert!(png.starts_with(b"\x89PNG\r\n\x1a\n"), "a PNG");
    let path = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("web-page.png");
    std::fs::write(&path, &png).unwrap();
}

/// Standard base64 (WebDriver's screenshots), padding and all.
fn from_base64(text: &str) -> Vec<u8> {
    let value = |c: u8| match c {
        b'A'..=b'Z' => c - b'A',
        b'a'..=b'z' => c - b'a' + 26,
        b'0'..=b'9' => c - b'0' + 52,
        b'+' => 62,
        _ => 63,
    };
    let digits: Vec<u8> = text
        .bytes()
        .filter(|c| c.is_ascii_alphanumeric() || *c == b'+' || *c == b'/')
        .map(value)
        .collect();
    let mut out = Vec::with_capacity(digits.len() * 3 / 4);
    for chunk in digits.chunks(4) {
        let n = chunk
            .iter()
            .enumerate()
            .fold(0u32, |n, (i, d)| n | u32::from(*d) << (18 - 6 * i));
        let bytes = n.to_be_bytes();
        out.extend_from_slice(&bytes[1..chunk.len()]);
    }
    out
}

#[test]
#[ignore = "needs chromium and chromium-driver (tier 2: .ci/run installs them)"]
fn a_browser_forces_an_output_from_the_page_sees_it_marked_and_unforces_it() {
    let run = forcing_rig("web-force-browser", true);
    let a = run.addr;
    let browser = Browser::start();
    browser.open(&format!("http://{a}/#key={}", run.key));
    until(Duration::from_secs(20), || browser.find("#do-io-3"))
        .expect("the page shows the module's outputs");
    // A click on a lamp fills the form; the button forces.
    browser.click("#do-io-3");
    browser.click("#force-set");
    until(Duration::from_secs(10), || {
        (browser.find("#unforce-io\\.DO3").is_some()
            && browser.has_class("#do-io-3", "forced") == Some(true)
            && browser.has_class("#do-io-3", "on") == Some(true))
        .then_some(())
    })
    .expect("the page lists the force and marks the lamp, lit");
    assert_eq!(state(a)["devices"]["io"]["outputs_written"], 8);
    browser.click("#unforce-io\\.DO3");
    until(Duration::from_secs(10), || {
        (browser.has_class("#do-io-3", "forced") == Some(false)
            && browser.has_class("#do-io-3", "on") == Some(false))
        .then_some(())
    })
    .expect("unforced: the script's value again");
    run.logged("force: io.DO3 removed (by the web page with the run's key (127.0.0.1:");
}

#[test]
fn a_real_device_is_not_driven_from_the_page_while_its_simulated_neighbour_is() {
    let sim = common::SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let dir = TempDir::new("web-real");
    let config = dir.file(
        "rig.toml",
        &format!(
            "[devices.io]\nkind = \"trp-c29u\"\nport = \"{}\"\n[devices.panel]\nkind = \
             \"trc1000\"\nsim = true\n",
            sim.path
        ),
    );
    let script = dir.file(
        "mirror.rhai",
        "every(\"20ms\", || { io.outputs = io.inputs; let p = panel.pressed(\"S1\"); });\n",
    );
    let run = serve(
        "web-real-run",
        &["--config", &config, "--no-guardian", &script],
    );
    let a = run.addr;
    let (status, body) = post(a, "/api/sim", r#"{"device":"io","action":"fail"}"#);
    assert_eq!(status, 403, "{body}");
    assert!(body.contains("io is a real device"), "{body}");
    drive(a, r#"{"device":"panel","action":"press","name":"S1"}"#);
    until(Duration::from_secs(10), || {
        (state(a)["devices"]["panel"]["pressed"][0] == "S1").then_some(())
    })
    .expect("the simulated panel is driven");
    assert_eq!(state(a)["devices"]["io"]["online"], true);
}

/// A rig for forcing under `--sim`: DO0 follows DI0, the panel watched (its loss is seen at
/// once), a short grace time; `force` says whether rig.toml allows forcing.
fn forcing_rig(tag: &str, force: bool) -> Served {
    configured(
        tag,
        &format!(
            "period = \"50ms\"\ngrace = \"500ms\"\nforce = {force}\n\n[devices.io]\n\
             kind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\nsafe_value = 0x00\n\n\
             [devices.panel]\nkind = \"trc1000\"\n"
        ),
        "io.on_rise(0, || io.set_output(0, true));\n\
         io.on_fall(0, || io.set_output(0, false));\n\
         panel.on_press(\"S1\", || {});\n",
    )
}

/// A run of `script` under `--sim` with a rig.toml of its own: `name`, `records`
/// (records.jsonl beside it), then `rest` (settings, then the devices). `script` is a file,
/// or the text of a script written beside the config when it does not end in `.rhai`.
fn configured(tag: &str, rest: &str, script: &str) -> Served {
    let dir = TempDir::new(tag);
    let records = dir.path("records.jsonl");
    dir.file(
        "rig.toml",
        &format!(
            "name = \"{tag}\"\nrecords = \"{}\"\n{rest}",
            records.display()
        ),
    );
    let script = match script.ends_with(".rhai") {
        true => script.to_string(),
        false => dir.file("script.rhai", script),
    };
    let config = dir.path("rig.toml").display().to_string();
    serve_in(dir, &[&script, "--config", &config, "--sim"])
}

/// The interlock of scripts/ on a simulated rig that allows forcing (tripped at the start:
/// every guard open).
fn interlock_forcing_rig(tag: &str) -> Served {
    configured(
        tag,
        "period = \"20ms\"\nforce = true\n\n[devices.io]\nkind = \"trp-c29u\"\n\
         port = \"/dev/ttyUSB0\"\n\n[devices.panel]\nkind = \"trc1000\"\n",
        "scripts/interlock.rhai",
    )
}

/// The interlock's one invariant.
const POWER_PROMISE: &str = "power only with all guards closed and no stop pressed";

#[test]
fn a_force_that_would_break_an_invariant_is_refused_naming_it_and_taken_only_when_overridden() {
    let tag = "force-promise";
    let run = interlock_forcing_rig(tag);
    run.logged("interlock ready (tripped)");
    // Tripped, every guard open: power on DO0 would break the promise.
    let (status, out, err) = run.cli(&["force", tag, "io.DO0", "on", "--for", "1m"]);
    assert_eq!(status, 1, "{out}{err}");
    assert!(
        err.contains(&format!(
            "forcing io.DO0 on would break the invariant {POWER_PROMISE:?}"
        )) && err.contains("--override"),
        "{err}"
    );
    assert!(state(run.addr)["forces"].as_array().unwrap().is_empty());
    // An override that names no invariant is refused with the nearest.
    let force_overriding = |invariant: &str| {
        run.cli(&[
            "force",
            tag,
            "io.DO0",
            "on",
            "--for",
            "1m",
            "--override",
            invariant,
        ])
    };
    let (status, _, err) = force_overriding("power only");
    assert_eq!(status, 1, "{err}");
    assert!(err.contains("states no invariant called that"), "{err}");
    // Said explicitly: taken, told, logged, recorded, and shown as overridden.
    let (status, out, err) = force_overriding(POWER_PROMISE);
    assert_eq!(status, 0, "{err}");
    assert!(
        out.contains(&format!(
            "io.DO0 forced on for 1m, overriding the invariant {POWER_PROMISE:?}"
        )),
        "{out}"
    );
    let s = state_until(run.addr, "the invariant shown overridden", |s| {
        s["script"]["invariants"][0]["overridden"] == true
    });
    assert_eq!(s["script"]["invariants"][0]["holds"], false, "{s}");
    assert_eq!(
        s["devices"]["io"]["outputs_written"].as_u64().unwrap() & 1,
        1,
        "{s}"
    );
    assert_eq!(s["script"]["state"], "running", "{s}");
    run.logged(&format!("overriding the invariant {POWER_PROMISE:?}"));
    let (_, status_text, _) = run.cli(&["status", tag]);
    assert!(
        status_text.contains(&format!("invariant {POWER_PROMISE:?}: OVERRIDDEN"))
            && status_text.contains(&format!(", overriding the invariant {POWER_PROMISE:?}")),
        "{status_text}"
    );
    let set = run
        .force_records()
        .into_iter()
        .find(|r| r["event"] == "set")
        .expect("the force recorded");
    assert_eq!(set["overrides"][0], POWER_PROMISE);
    // Until the force ends.
    assert_eq!(run.cli(&["unforce", tag, "io.DO0"]).0, 0);
    let s = state_until(run.addr, "the invariant holding again", |s| {
        s["script"]["invariants"][0]["holds"] == true
    });
    assert_eq!(s["script"]["invariants"][0]["overridden"], false);
}

#[test]
#[ignore = "needs chromium and chromium-driver (tier 2: .ci/run installs them)"]
fn a_browser_is_asked_before_a_force_breaks_an_invariant_and_sees_it_overridden() {
    let run = interlock_forcing_rig("web-override");
    let browser = Browser::start();
    browser.open(&format!("http://{}/#key={}", run.addr, run.key));
    until(Duration::from_secs(20), || browser.find("#inv-0"))
        .expect("the page lists the script's invariant");
    assert_eq!(browser.has_class("#inv-0", "holds"), Some(true));
    // The power lamp clicked fills the form (on); the button asks the rig, which refuses.
    browser.click("#do-io-0");
    browser.click("#force-set");
    let asked = until(Duration::from_secs(10), || {
        browser.session("GET", "/alert/text", None)["value"]
            .as_str()
            .map(String::from)
    })
    .expect("the page asks whether to override");
    assert!(
        asked.contains(&format!("would break the invariant {POWER_PROMISE:?}")),
        "{asked}"
    );
    browser.session("POST", "/alert/accept", Some(serde_json::json!({})));
    until(Duration::from_secs(10), || {
        (browser.has_class("#inv-0", "overridden") == Some(true)
            && browser.has_class("#do-io-0", "on") == Some(true))
        .then_some(())
    })
    .expect("confirmed: the lamp lit and the invariant marked overridden");
    let row = browser.text("#inv-0").unwrap_or_default();
    assert!(row.contains("OVERRIDDEN"), "{row}");
    let listed = browser.text("#force-io\\.DO0").unwrap_or_default();
    assert!(listed.contains("overriding"), "{listed}");
    browser.click("#unforce-io\\.DO0");
    until(Duration::from_secs(10), || {
        (browser.has_class("#inv-0", "holds") == Some(true)).then_some(())
    })
    .expect("unforced: the invariant holds again");
}

impl Served {
    /// `rigscript ARGS..` against this run's rig directory: (status, stdout, stderr).
    fn cli(&self, args: &[&str]) -> (i32, String, String) {
        let out = Command::new(rigscript())
            .args(args)
            .env("XDG_RUNTIME_DIR", self.dir.root())
            .env_remove("RUNTIME_DIRECTORY")
            .output()
            .unwrap();
        (out.status.code().unwrap_or(-1), stdout(&out), stderr(&out))
    }

    /// Waits (at most 10 s) for a log line containing `text`.
    fn logged(&self, text: &str) -> String {
        until(Duration::from_secs(10), || {
            self.log
                .lock()
                .unwrap()
                .iter()
                .find(|l| l.contains(text))
                .cloned()
        })
        .unwrap_or_else(|| {
            panic!(
                "no log line with {text:?}:\n{}",
                self.log.lock().unwrap().join("\n")
            )
        })
    }

    /// The records file's `force` records so far.
    fn force_records(&self) -> Vec<Value> {
        std::fs::read_to_string(self.dir.path("records.jsonl"))
            .unwrap_or_default()
            .lines()
            .filter_map(|l| serde_json::from_str::<Value>(l).ok())
            .filter(|v| v["name"] == "force")
            .map(|v| v["value"].clone())
            .collect()
    }
}

fn delete(addr: SocketAddr, path: &str) -> (u16, String) {
    exchange(
        addr,
        &format!(
            "DELETE {path} HTTP/1.1\r\nHost: {addr}\r\n{}\r\n",
            key_line(addr)
        ),
        b"",
    )
}

/// Waits (at most 10 s) until the state satisfies `holds`.
fn state_until(addr: SocketAddr, what: &str, holds: impl Fn(&Value) -> bool) -> Value {
    until(Duration::from_secs(10), || {
        let s = state(addr);
        holds(&s).then_some(s)
    })
    .unwrap_or_else(|| panic!("{what}: {}", state(addr)))
}

#[test]
fn a_forced_output_holds_until_it_expires_and_a_forced_input_is_what_the_script_reads() {
    let run = forcing_rig("forced", true);
    let a = run.addr;
    assert_eq!(state(a)["forcing"], true);
    let (status, body) = post(
        a,
        "/api/force",
        r#"{"point":"io.DO3","value":true,"for":"1s"}"#,
    );
    assert_eq!(status, 200, "{body}");
    let s = state_until(a, "DO3 forced on", |s| {
        s["devices"]["io"]["outputs_written"] == 0x08
    });
    assert_eq!(s["forces"][0]["point"], "io.DO3");
    assert_eq!(
        s["devices"]["io"]["outputs"], 0,
        "the script commands nothing"
    );
    run.logged("force: io.DO3 forced on for 1s (by the web page with the run's key (127.0.0.1:");
    run.logged("io: outputs 0x00 -> 0x08 (forced)");
    // It expires on its own, on the run's clock: the script's value again.
    run.logged("force: io.DO3 expired after 1s: the script's value applies again");
    state_until(a, "the force gone and DO3 off", |s| {
        s["forces"].as_array().is_some_and(|f| f.is_empty())
            && s["devices"]["io"]["outputs_written"] == 0
    });
    // A forced input is what the script reads: DO0 follows the forced DI0.
    let (status, body) = post(
        a,
        "/api/force",
        r#"{"point":"io.DI0","value":true,"for":"1m"}"#,
    );
    assert_eq!(status, 200, "{body}");
    state_until(a, "the script sees DI0 and commands DO0", |s| {
        s["devices"]["io"]["outputs"] == 1 && s["devices"]["io"]["inputs"] == 1
    });
    let (status, body) = delete(a, "/api/force/io.DI0");
    assert_eq!(status, 200, "{body}");
    run.logged("force: io.DI0 removed (by the web page with the run's key (127.0.0.1:");
    state_until(a, "DI0 released again, DO0 off", |s| {
        s["devices"]["io"]["outputs"] == 0 && s["devices"]["io"]["inputs"] == 0
    });
    // Each refusal has its status and says why.
    for (json, want) in [
        (r#"{"point":"io.DO9","value":true,"for":"1m"}"#, 404),
        (r#"{"point":"pump.DO1","value":true,"for":"1m"}"#, 404),
        (r#"{"point":"io.DO1","value":7,"for":"1m"}"#, 400),
        (r#"{"point":"io.DO1","value":true,"for":"0s"}"#, 400),
        (r#"{"point":"io.DO1","value":true}"#, 400),
    ] {
        let (status, body) = post(a, "/api/force", json);
        assert_eq!(status, want, "{json}: {body}");
        assert!(body.contains("\"error\""), "{body}");
    }
    let (status, body) = delete(a, "/api/force/io.DI0");
    assert_eq!(status, 404, "{body}");
    let events: Vec<(String, String)> = until(Duration::from_secs(10), || {
        let r = run.force_records();
        (r.len() >= 4).then_some(r)
    })
    .expect("four force records")
    .iter()
    .map(|v| {
        (
            v["point"].as_str().unwrap_or("").to_string(),
            v["event"].as_str().unwrap_or("").to_string(),
        )
    })
    .collect();
    let want = [
        ("io.DO3", "set"),
        ("io.DO3", "expired"),
        ("io.DI0", "set"),
        ("io.DI0", "removed"),
    ];
    assert_eq!(
        events,
        want.map(|(p, e)| (p.to_string(), e.to_string())),
        "the records file tells each force's life"
    );
}

#[test]
fn forcing_is_refused_on_the_page_and_the_command_line_without_force_true() {
    let run = forcing_rig("unforced", false);
    let a = run.addr;
    assert_eq!(state(a)["forcing"], false);
    let (status, body) = post(
        a,
        "/api/force",
        r#"{"point":"io.DO3","value":true,"for":"5m"}"#,
    );
    assert_eq!(status, 403, "{body}");
    assert!(body.contains("force = true"), "{body}");
    let (status, body) = delete(a, "/api/force/io.DO3");
    assert_eq!(status, 403, "{body}");
    let (code, _, err) = run.cli(&["force", "unforced", "io.DO3", "on", "--for", "5m"]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("force = true"), "{err}");
    let (code, _, err) = run.cli(&["force", "unforced", "io.DO3", "on", "--for", "300"]);
    assert_eq!(
        code, 2,
        "a duration without its unit is a usage error: {err}"
    );
    assert_eq!(state(a)["devices"]["io"]["outputs_written"], 0);
    assert!(run.force_records().is_empty());
}

#[test]
fn the_safe_state_wins_over_a_force_set_from_the_command_line() {
    let run = forcing_rig("safewins", true);
    let a = run.addr;
    let (code, _, err) = run.cli(&["force", "safewins", "io.DO1", "on", "--for", "1m"]);
    assert_eq!(code, 0, "{err}");
    let (code, out, err) = run.cli(&["status", "safewins"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("FORCED: io.DO1 on for "), "{out}");
    assert!(out.contains("(by rigscript force (pid "), "{out}");
    let (_, json, _) = run.cli(&["status", "safewins", "--json"]);
    let s: Value = serde_json::from_str(&json).unwrap();
    assert_eq!(s["forces"][0]["point"], "io.DO1");
    assert_eq!(s["forces"][0]["value"], true);
    let (code, _, err) = run.cli(&["unforce", "safewins", "io.DO1"]);
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = run.cli(&["unforce", "safewins", "io.DO1"]);
    assert_eq!(code, 1, "not forced any more: {err}");
    assert!(err.contains("io.DO1 is not forced"), "{err}");
    // A device lost past its grace time: every output safe, the force cancelled for good.
    let (code, _, err) = run.cli(&["force", "safewins", "io.outputs", "0xff", "--for", "1m"]);
    assert_eq!(code, 0, "{err}");
    state_until(a, "the outputs forced", |s| {
        s["devices"]["io"]["outputs_written"] == 0xFF
    });
    drive(a, r#"{"device":"panel","action":"fail"}"#);
    run.logged("force: io.outputs cancelled: the safe state wins (panel lost past its grace time)");
    let s = state_until(a, "held safe at the safe value", |s| {
        s["held_safe"] == true && s["devices"]["io"]["outputs_written"] == 0
    });
    assert_eq!(s["forces"], serde_json::json!([]));
    let (code, _, err) = run.cli(&["force", "safewins", "io.DO2", "on", "--for", "1m"]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("the safe state wins over a force"), "{err}");
    drive(a, r#"{"device":"panel","action":"restore"}"#);
    state_until(a, "back, and nothing forced comes back", |s| {
        s["held_safe"] == false && s["devices"]["io"]["outputs_written"] == 0
    });
    // The end of the run cancels a force before on_stop and the end's safe state.
    let (code, _, err) = run.cli(&["force", "safewins", "io.DO2", "on", "--for", "1m"]);
    assert_eq!(code, 0, "{err}");
    state_until(a, "DO2 forced", |s| {
        s["devices"]["io"]["outputs_written"] == 4
    });
    let (code, out, err) = run.cli(&["stop", "safewins"]);
    assert_eq!(code, 0, "{out}{err}");
    run.logged("force: io.DO2 cancelled: the safe state wins (the run is ending)");
    let events: Vec<String> = run
        .force_records()
        .iter()
        .map(|v| {
            format!(
                "{} {}",
                v["point"].as_str().unwrap_or(""),
                v["event"].as_str().unwrap_or("")
            )
        })
        .collect();
    assert_eq!(
        events,
        [
            "io.DO1 set",
            "io.DO1 removed",
            "io.outputs set",
            "io.outputs cancelled",
            "io.DO2 set",
            "io.DO2 cancelled"
        ]
    );
}

fn with_token(addr: SocketAddr, method: &str, path: &str, token: Option<&str>) -> (u16, String) {
    let auth = token.map_or(String::new(), |t| format!("Authorization: Bearer {t}\r\n"));
    let body = if method == "POST" {
        r#"{"device":"io","action":"set_inputs","value":15}"#
    } else {
        ""
    };
    let head = format!(
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\n{auth}Content-Type: application/json\r\n\
         Content-Length: {}\r\n\r\n",
        body.len()
    );
    exchange(addr, &head, body.as_bytes())
}

#[test]
fn a_page_on_every_address_asks_for_its_token_and_a_read_token_only_looks() {
    let (control, read) = ("c0ntrol-token-1", "read-token-22");
    let run = serve_at(
        TempDir::new("web-token"),
        &["scripts/interlock.rhai", "--sim"],
        "0.0.0.0:0",
        &[
            ("RIGSCRIPT_UI_TOKEN", control),
            ("RIGSCRIPT_UI_READ_TOKEN", read),
        ],
    );
    let a = run.addr;
    // The page itself loads (it asks for the token); nothing else does without one.
    let (status, body) = with_token(a, "GET", "/", None);
    assert_eq!(status, 200, "{body}");
    assert!(body.contains("Authorization"), "the page sends the token");
    for path in ["/api/state", "/metrics", "/api/history", "/api/events"] {
        let (status, body) = with_token(a, "GET", path, None);
        assert_eq!(status, 401, "{path}: {body}");
        let (status, _) = with_token(a, "GET", path, Some("not-the-token"));
        assert_eq!(status, 401, "{path}");
    }
    let (status, body) = with_token(a, "GET", "/api/state", Some(read));
    assert_eq!(status, 200, "{body}");
    let (status, body) = with_token(a, "POST", "/api/sim", Some(read));
    assert_eq!(status, 403, "a read token only looks: {body}");
    let (status, body) = with_token(a, "POST", "/api/sim", None);
    assert_eq!(status, 401, "{body}");
    let (status, body) = with_token(a, "POST", "/api/sim", Some(control));
    assert_eq!(status, 200, "{body}");
    // The control token's change reaches the field: the page's state shows it once it is read
    // (by the script, or for the page at most every 250 ms), not necessarily at the next ask.
    let mut last = Value::Null;
    let shown = until(Duration::from_secs(5), || {
        let (status, body) = with_token(a, "GET", "/api/state", Some(control));
        assert_eq!(status, 200, "{body}");
        let s: Value = serde_json::from_str(&body).unwrap();
        last = s["devices"]["io"].clone();
        (last["inputs"] == 15).then_some(())
    });
    assert!(shown.is_some(), "the inputs set are shown: {last}");
    // Neither token is ever in the log.
    let log = run.log.lock().unwrap().join("\n");
    assert!(!log.contains(control) && !log.contains(read), "{log}");
}

#[test]
fn a_bare_ui_flag_serves_at_rig_toml_s_address_and_a_token_there_is_asked_for() {
    let dir = TempDir::new("web-bare-ui");
    let config = dir.file(
        "rig.toml",
        "ui = \"127.0.0.1:0\"\nui_token = \"from-rig-toml\"\n\n[devices.io]\n\
         kind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\n",
    );
    let script = dir.file("idle.rhai", "every(\"100ms\", || {});\n");
    let run = serve_at(dir, &[&script, "--config", &config, "--sim"], "", &[]);
    assert_ne!(run.addr.port(), 7878, "rig.toml's address, not the default");
    let (status, _) = with_token(run.addr, "GET", "/api/state", None);
    assert_eq!(status, 401);
    let (status, body) = with_token(run.addr, "GET", "/api/state", Some("from-rig-toml"));
    assert_eq!(status, 200, "{body}");
}

#[test]
fn records_and_measurements_with_their_verdict_are_kept_for_the_page() {
    let dir = TempDir::new("web-records");
    let script = dir.file(
        "measure.rhai",
        "after(\"300ms\", || {\n\
           record(\"serial\", \"A17\");\n\
           measure(\"volts\", 12.5, #{min: 11.0, max: 12.0, unit: \"V\"});\n\
           measure(\"amps\", 0.5, #{max: 1.0});\n\
         });\n\
         every(\"100ms\", || {});\n",
    );
    let run = serve_in(dir, &[&script, "--sim"]);
    let kept = until(Duration::from_secs(10), || {
        let (status, body) = get(run.addr, "/api/history");
        assert_eq!(status, 200, "{body}");
        let h: Value = serde_json::from_str(&body).unwrap();
        (h["records"].as_array().map_or(0, Vec::len) >= 3).then_some(h["records"].clone())
    })
    .expect("three records kept");
    assert_eq!(kept[0]["name"], "serial");
    assert_eq!(kept[1]["name"], "volts");
    assert_eq!(kept[1]["pass"], false);
    assert_eq!(kept[1]["unit"], "V");
    assert_eq!(kept[2]["pass"], true);
    let (_, page) = get(run.addr, "/");
    assert!(page.contains("id=\"records\""), "the page shows them");
}

#[test]
#[ignore = "needs chromium and chromium-driver (tier 2: .ci/run installs them)"]
fn a_browser_is_asked_for_the_token_once_and_the_page_works_with_it() {
    let token = "browser-token-7";
    let run = serve_at(
        TempDir::new("web-token-browser"),
        &["scripts/interlock.rhai", "--sim"],
        "0.0.0.0:0",
        &[("RIGSCRIPT_UI_TOKEN", token)],
    );
    let a = run.addr;
    let browser = Browser::start();
    browser.open(&format!("http://{a}/"));
    // The page's first API call is answered 401: it asks.
    until(Duration::from_secs(20), || {
        let asked = browser.session("GET", "/alert/text", None);
        asked["value"]
            .as_str()
            .filter(|t| t.contains("token"))
            .map(String::from)
    })
    .expect("the page asks for the token");
    browser.session(
        "POST",
        "/alert/text",
        Some(serde_json::json!({ "text": token })),
    );
    browser.session("POST", "/alert/accept", Some(serde_json::json!({})));
    until(Duration::from_secs(20), || browser.find("#sw-panel-S12"))
        .expect("with the token the page shows the panel");
    browser.click("#sw-panel-S12");
    until(Duration::from_secs(10), || {
        let (status, body) = with_token(a, "GET", "/api/state", Some(token));
        assert_eq!(status, 200, "{body}");
        let s: Value = serde_json::from_str(&body).ok()?;
        (s["devices"]["panel"]["pressed"][0] == "S12").then_some(())
    })
    .expect("a click drives the field with the token");
    // Kept for the session: a reload asks nothing.
    browser.open(&format!("http://{a}/"));
    until(Duration::from_secs(20), || browser.find("#sw-panel-S12")).expect("the page again");
    let asked = browser.session("GET", "/alert/text", None);
    assert!(asked["value"].as_str().is_none(), "asked again: {asked}");
}

/// HTTP clients that trickle a request into `addr` a byte every 300 ms, never ending it; one
/// let go connects again. They stop when the returned flag is set.
fn http_tricklers(addr: SocketAddr, n: usize) -> Arc<std::sync::atomic::AtomicBool> {
    use std::sync::atomic::{AtomicBool, Ordering};
    let stop = Arc::new(AtomicBool::new(false));
    for _ in 0..n {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || {
            while !stop.load(Ordering::SeqCst) {
                let Ok(mut s) = TcpStream::connect(addr) else {
                    std::thread::sleep(Duration::from_millis(100));
                    continue;
                };
                let mut sent = s.write_all(b"GET /api/state HTTP/1.1\r\nX-Slow: ").is_ok();
                while sent && !stop.load(Ordering::SeqCst) {
                    std::thread::sleep(Duration::from_millis(300));
                    sent = s.write_all(b"a").is_ok();
                }
            }
        });
    }
    stop
}

#[test]
fn trickling_clients_are_cut_off_at_the_deadline_and_never_keep_the_owner_out() {
    let run = serve("web-trickle", &["scripts/interlock.rhai", "--sim"]);
    let a = run.addr;
    state(a);
    // One trickler alone: answered 408 and closed once its request is 5 s old, whatever it
    // still sends (no linger it can stretch): its writes fail then.
    let mut slow = TcpStream::connect(a).unwrap();
    slow.write_all(b"GET /api/state HTTP/1.1\r\nX-Slow: ")
        .unwrap();
    slow.set_nonblocking(true).unwrap();
    let started = Instant::now();
    let mut said = Vec::new();
    let closed = loop {
        let mut chunk = [0u8; 1024];
        match slow.read(&mut chunk) {
            Ok(n) => said.extend_from_slice(&chunk[..n]),
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
            Err(_) => break true,
        }
        if started.elapsed() > Duration::from_secs(20) {
            break false;
        }
        if slow.write_all(b"a").is_err() {
            break true;
        }
        std::thread::sleep(Duration::from_millis(300));
    };
    let said = String::from_utf8_lossy(&said).to_string();
    assert!(closed, "a trickler was still connected after 20 s: {said}");
    assert!(said.starts_with("HTTP/1.1 408"), "{said:?}");
    // Forty of them, more than the 32 places, taking them again as they are let go: the
    // owner's reads are answered all the same.
    let stop = http_tricklers(a, 40);
    std::thread::sleep(Duration::from_secs(2));
    for _ in 0..10 {
        let (status, body) = get(a, "/api/state");
        assert_eq!(status, 200, "the state past 40 tricklers: {body}");
    }
    stop.store(true, std::sync::atomic::Ordering::SeqCst);
}

#[test]
#[ignore = "needs root and setpriv (tier 2: CI runs .ci/run as root)"]
fn another_user_changes_nothing_over_http_while_the_owner_does_with_the_run_s_key() {
    let run = forcing_rig("web-authority", true);
    let a = run.addr;
    // The key sits beside the socket, the owner's alone.
    let key_file = run.dir.path("rigscript").join("web-authority.key");
    let kept = std::fs::read_to_string(&key_file).expect("the run keeps its key");
    assert_eq!(kept.trim(), run.key);
    let body = r#"{"device":"io","action":"set_inputs","value":15}"#;
    let request = |auth: &str| {
        format!(
            "POST /api/sim HTTP/1.1\r\nHost: {a}\r\n{auth}Content-Type: application/json\r\n\
             Content-Length: {}\r\n\r\n{body}",
            body.len()
        )
    };
    // Another user: cannot read the key, looks, and is refused every change.
    let theirs = common::as_nobody(
        "bash",
        &["-c", &format!(
        "cat {key}; exec 3<>/dev/tcp/{ip}/{port}; printf '{req}' >&3; cat <&3; \
         exec 4<>/dev/tcp/{ip}/{port}; printf 'GET /api/state HTTP/1.1\\r\\nHost: {a}\\r\\n\\r\\n' >&4; \
         head -c 12 <&4",
        key = key_file.display(),
        ip = a.ip(),
        port = a.port(),
        req = request("").replace("\r\n", "\\r\\n"),
    )],
    );
    let (out, err) = (stdout(&theirs), stderr(&theirs));
    assert!(err.contains("Permission denied"), "{err}");
    assert!(!out.contains(&run.key), "another user read the key");
    assert!(
        out.starts_with("HTTP/1.1 401"),
        "a change without the key: {out}"
    );
    assert!(
        out.contains("HTTP/1.1 200"),
        "looking stays open on loopback: {out}"
    );
    let (status, body) = exchange(a, &request(""), b"");
    assert_eq!(status, 401, "{body}");
    assert!(body.contains("the run's key"), "{body}");
    // The owner: with the key over HTTP, and `rigscript force` over the socket.
    let (status, body) = exchange(
        a,
        &request(&format!("Authorization: Bearer {}\r\n", run.key)),
        b"",
    );
    assert_eq!(status, 200, "{body}");
    let (code, _, err) = run.cli(&["force", "web-authority", "io.DO3", "on", "--for", "5s"]);
    assert_eq!(code, 0, "{err}");
}

#[test]
fn the_environment_s_token_is_checked_as_rig_toml_s_is() {
    for token in ["abc", " spaced-token-1 "] {
        let dir = TempDir::new("web-env-token");
        let out = Command::new("timeout")
            .args([
                "20",
                rigscript(),
                "run",
                "scripts/interlock.rhai",
                "--sim",
                "--ui",
                "0.0.0.0:0",
            ])
            .env("RIGSCRIPT_UI_TOKEN", token)
            .env_remove("RIGSCRIPT_UI_READ_TOKEN")
            .env("XDG_RUNTIME_DIR", dir.root())
            .output()
            .unwrap();
        let said = stderr(&out);
        assert_eq!(out.status.code(), Some(2), "{token:?} was taken: {said}");
        assert!(said.contains("RIGSCRIPT_UI_TOKEN is not a token"), "{said}");
        assert!(
            !said.contains(token.trim()),
            "the token is never shown: {said}"
        );
    }
}

/// A rig whose points have names (rig.toml's `names`), forcing allowed, under `--sim`: the
/// guard door's rise starts the motor, its fall stops it.
fn named_rig(tag: &str) -> Served {
    configured(
        tag,
        "period = \"50ms\"\nforce = true\n\n\
         [devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\n\n\
         [devices.io.names]\nDI0 = \"guard door\"\nDO0 = \"motor\"\nDO1 = \"lamp\"\n\n\
         [devices.panel]\nkind = \"trc1000\"\n\n\
         [devices.panel.names]\nS12 = \"cycle start\"\nS41A = \"die selector\"\n\
         relay0 = \"no die\"\n",
        "io.on_rise(\"guard door\", || io.set_output(\"motor\", true));\n\
         io.on_fall(\"guard door\", || io.set_output(\"motor\", false));\n\
         panel.on_press(\"cycle start\", || {});\n\
         panel.on_turn(\"die selector\", |d, v| {});\n",
    )
}

#[test]
fn names_are_shown_in_the_state_status_the_log_and_force_records_and_the_cli_says_what_it_did() {
    let run = named_rig("named");
    let a = run.addr;
    let s = state(a);
    assert_eq!(s["devices"]["io"]["names"]["DI0"], "guard door", "{s}");
    assert_eq!(s["devices"]["panel"]["names"]["S12"], "cycle start", "{s}");
    // drive, force and unforce print what they did, the point with its name.
    let (code, out, err) = run.cli(&["drive", "named", "set-input", "io", "0", "on"]);
    assert_eq!(
        (code, out.trim()),
        (0, "named: io: DI0 \"guard door\" set on"),
        "{err}"
    );
    state_until(a, "the motor runs", |s| {
        s["devices"]["io"]["outputs_written"] == 1
    });
    run.logged("io: DI0 \"guard door\" on");
    run.logged("io: outputs 0x00 -> 0x01: DO0 \"motor\" on (io.on_rise DI0 \"guard door\")");
    let (code, out, err) = run.cli(&["drive", "named", "press", "S12"]);
    assert_eq!(
        (code, out.trim()),
        (0, "named: panel: S12 \"cycle start\" pressed"),
        "{err}"
    );
    run.logged("panel: S12 \"cycle start\" pressed");
    let (code, out, err) = run.cli(&["status", "named"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("DI0 \"guard door\" on"), "{out}");
    assert!(out.contains("DO0 \"motor\" on, DO1 \"lamp\" off"), "{out}");
    assert!(out.contains("relay: 0 \"no die\""), "{out}");
    let (code, out, err) = run.cli(&["force", "named", "io.DO1", "on", "--for", "5m"]);
    assert_eq!(
        (code, out.trim()),
        (0, "named: io.DO1 \"lamp\" forced on for 5m"),
        "{err}"
    );
    run.logged("force: io.DO1 \"lamp\" forced on for 5m");
    let (code, out, err) = run.cli(&["unforce", "named", "io.DO1"]);
    assert_eq!(
        (code, out.trim()),
        (
            0,
            "named: io.DO1 \"lamp\" unforced: the script's value applies again"
        ),
        "{err}"
    );
    let records = until(Duration::from_secs(10), || {
        let r = run.force_records();
        (r.len() == 2).then_some(r)
    })
    .expect("two force records");
    assert!(
        records.iter().all(|r| r["point_name"] == "lamp"),
        "{records:?}"
    );
}

#[test]
fn an_unknown_point_in_names_is_refused_at_start_and_check_refuses_an_unknown_name() {
    let dir = TempDir::new("names-refused");
    let config = dir.file(
        "rig.toml",
        "[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\n\
         [devices.io.names]\nDI0 = \"guard door\"\nDI9 = \"ghost\"\n",
    );
    let script = dir.file("s.rhai", "print(io.input(\"guard door\"));\n");
    let out = Command::new(rigscript())
        .args(["run", "--sim", "--config", &config, &script])
        .env("XDG_RUNTIME_DIR", dir.root())
        .output()
        .unwrap();
    let err = common::stderr(&out);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("rig.toml:6: devices.io.names.DI9: not a point of a TRP-C29U"),
        "{err}"
    );
    let config = dir.file(
        "good.toml",
        "[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\n\
         [devices.io.names]\nDI0 = \"guard door\"\n",
    );
    let script = dir.file("typo.rhai", "print(io.input(\"gaurd door\"));\n");
    let out = Command::new(rigscript())
        .args(["check", &script, "--config", &config])
        .output()
        .unwrap();
    let said = format!("{}{}", common::stdout(&out), common::stderr(&out));
    assert_ne!(out.status.code(), Some(0), "{said}");
    assert!(
        said.contains("typo.rhai:1:16: no channel called \"gaurd door\" on a TRP-C29U (did you mean \"guard door\"?)"),
        "{said}"
    );
}

#[test]
#[ignore = "needs chromium and chromium-driver (tier 2: .ci/run installs them)"]
fn a_browser_shows_each_point_s_name_beside_it() {
    let run = named_rig("web-names");
    let a = run.addr;
    let browser = Browser::start();
    browser.open(&format!("http://{a}/#key={}", run.key));
    let named = |css: &str| {
        until(Duration::from_secs(20), || {
            browser.text(css).filter(|t| !t.is_empty())
        })
        .unwrap_or_else(|| panic!("no name at {css}"))
    };
    assert_eq!(named("#name-di-io-0"), "guard door");
    assert_eq!(named("#name-do-io-0"), "motor");
    assert_eq!(named("#name-do-io-1"), "lamp");
    assert_eq!(named("#name-sw-panel-S12"), "cycle start");
    assert_eq!(named("#name-rot-panel-S41A"), "die selector");
    assert!(named("#relay-panel").contains("\"no die\""));
    assert!(
        browser.find("#name-di-io-1").is_none(),
        "an unnamed point has no name"
    );
}

#[test]
#[ignore = "needs chromium and chromium-driver (tier 2: .ci/run installs them)"]
fn a_browser_drives_a_simulated_input_with_forcing_on_and_plots_a_named_lane_a_channel() {
    let run = named_rig("web-plots");
    let a = run.addr;
    let browser = Browser::start();
    browser.open(&format!("http://{a}/#key={}", run.key));
    // The module's plot: a lane a channel, DI0-DI7 then DO0-DO7, each with its name; the
    // legend's first row is the time.
    let legend = |plot: &str, row: usize, part: &str| {
        browser.text(&format!(
            "#{plot} .u-legend .u-series:nth-child({row}) {part}"
        ))
    };
    until(Duration::from_secs(20), || {
        legend("plot-io", 2, ".u-label").filter(|t| t == "DI0 \"guard door\"")
    })
    .expect("the first lane is DI0, named");
    assert_eq!(legend("plot-io", 3, ".u-label").as_deref(), Some("DI1"));
    assert_eq!(
        legend("plot-io", 10, ".u-label").as_deref(),
        Some("DO0 \"motor\"")
    );
    assert_eq!(legend("plot-io", 17, ".u-label").as_deref(), Some("DO7"));
    // Forcing is on, and a click on a simulated input still drives it (forcing has its form).
    browser.click("#di-io-0");
    until(Duration::from_secs(10), || {
        (state(a)["devices"]["io"]["inputs"].as_u64()? & 1 == 1).then_some(())
    })
    .expect("the click drove DI0 on");
    let form = browser.find("#force-point").expect("the force form");
    let filled = browser.session("GET", &format!("/element/{form}/property/value"), None);
    assert_eq!(
        filled["value"], "",
        "the click did not fill the force form: {filled}"
    );
    // The legend shows the latest values without a hover: the guard, and the motor the
    // script follows it with.
    until(Duration::from_secs(10), || {
        (legend("plot-io", 2, ".u-value")? == "on" && legend("plot-io", 10, ".u-value")? == "on")
            .then_some(())
    })
    .expect("the legend shows DI0 and DO0 on");
    assert_eq!(legend("plot-io", 3, ".u-value").as_deref(), Some("off"));
    // The panel's plot: the relay, and the rotary the script reads once it turns.
    drive(
        a,
        r#"{"device":"panel","action":"turn","name":"S41A","half_turns":4}"#,
    );
    until(Duration::from_secs(10), || {
        (legend("rplot-panel", 2, ".u-label")? == "relay"
            && legend("rplot-panel", 3, ".u-label")? == "S41A \"die selector\"")
            .then_some(())
    })
    .expect("the panel's plot has the relay and the named rotary");
    until(Duration::from_secs(10), || {
        (legend("rplot-panel", 2, ".u-value")? == "0 \"no die\"").then_some(())
    })
    .expect("the relay's latest value, with its position's name");
}

#[test]
fn the_page_s_log_starts_at_the_run_s_first_line() {
    let run = serve("web-first-line", &["scripts/interlock.rhai", "--sim"]);
    // The take-over lines come before the page attaches to the run; its log has them.
    let first = run.logged("io: TRP-C29U ID 1 on simulated");
    let (status, body) = get(run.addr, "/api/history");
    assert_eq!(status, 200, "{body}");
    let history: Value = serde_json::from_str(&body).unwrap();
    let lines: Vec<&str> = history["log"]
        .as_array()
        .expect("a log")
        .iter()
        .filter_map(|l| l["message"].as_str())
        .collect();
    assert!(
        first.ends_with(lines.first().copied().unwrap_or("nothing")),
        "the page's first line is the run's ({first}): {lines:?}"
    );
    assert!(
        lines
            .iter()
            .any(|l| l.starts_with("panel: simulated TRC1000 panel")),
        "{lines:?}"
    );
}
