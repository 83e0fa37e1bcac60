//! A case as the files a user would write: the rig.toml text and the Rhai script.

use super::case::{Case, Module, Policy, Proto, Stmt, HUGE_TIMEOUT_MS};
use std::fmt::Write;

/// The serial port of line `n` (never opened: the fault search puts simulators behind it).
pub fn port(line: u8) -> String {
    format!("/dev/ttyFAULT{line}")
}

/// The line a port names, if it is one of ours.
pub fn line_of(port: &str) -> Option<u8> {
    port.strip_prefix("/dev/ttyFAULT")?.parse().ok()
}

/// The name of entry `n`.
pub fn name(entry: usize) -> String {
    format!("io{entry}")
}

fn duration(ms: u64) -> String {
    if ms == HUGE_TIMEOUT_MS {
        "1000000h".into()
    } else {
        format!("{ms}ms")
    }
}

/// The case's rig.toml.
pub fn rig_toml(case: &Case) -> String {
    let r = &case.rig;
    let policy = match r.policy {
        Policy::Stop => "stop",
        Policy::Restart => "restart",
        Policy::Skip => "skip",
    };
    let mut t = format!(
        "period = \"{}ms\"\non_error = \"{policy}\"\ngrace = \"{}ms\"\nwake_latency = \"off\"\n",
        r.period_ms, r.grace_ms
    );
    let _ = write!(t, "\n[limits]\noperations = {}\n", r.budget);
    for (i, m) in r.modules.iter().enumerate() {
        device(&mut t, i, m);
    }
    t
}

fn device(t: &mut String, i: usize, m: &Module) {
    let protocol = match m.protocol {
        Proto::Modbus => "modbus",
        Proto::Ascii => "ascii",
    };
    let _ = write!(
        t,
        "\n[devices.{}]\nkind = \"trp-c29u\"\nport = \"{}\"\nprotocol = \"{protocol}\"\nid = {}\n\
         timeout = \"{}\"\nretries = {}\nsafe_value = {:#04x}\n",
        name(i),
        port(m.line),
        m.id,
        duration(m.timeout_ms),
        m.retries,
        m.safe
    );
    if let Some(w) = m.watchdog_tenths {
        let _ = writeln!(t, "watchdog = \"{}.{}s\"", w / 10, w % 10);
    }
    if let Some(p) = m.power_on {
        let _ = writeln!(t, "power_on_value = {p:#04x}");
    }
}

/// Writes the script of a case.
struct Script<'a> {
    case: &'a Case,
    /// Declarations the top level needs first (call counters, the big string).
    head: Vec<String>,
    body: String,
    counters: usize,
}

/// The case's script.
pub fn script(case: &Case) -> String {
    let mut s = Script {
        case,
        head: Vec::new(),
        body: String::new(),
        counters: 0,
    };
    let mut body = String::new();
    for st in &case.script {
        s.statement(st, 0, &mut body);
    }
    s.body = body;
    let mut out = s.head.join("\n");
    if !out.is_empty() {
        out.push('\n');
    }
    out.push_str(&s.body);
    out
}

impl Script<'_> {
    fn dev(&self, dev: u8) -> String {
        name(self.case.entry(dev))
    }

    fn block(&mut self, body: &[Stmt], depth: usize) -> String {
        let mut b = String::new();
        for st in body {
            self.statement(st, depth + 1, &mut b);
        }
        let pad = "    ".repeat(depth);
        format!("{{\n{b}{pad}}}")
    }

    fn statement(&mut self, st: &Stmt, depth: usize, out: &mut String) {
        let pad = "    ".repeat(depth);
        let line = match st {
            Stmt::Set { dev, value } => format!("{}.outputs = {value:#04x};", self.dev(*dev)),
            Stmt::SetBit { dev, ch, on } => format!("{}.set_output({ch}, {on});", self.dev(*dev)),
            Stmt::RecordInputs { dev } => {
                let d = self.dev(*dev);
                format!("record(\"{d}\", {d}.inputs);")
            }
            Stmt::RecordCounters { dev } => {
                let d = self.dev(*dev);
                format!("record(\"{d}.counters\", {d}.counters());")
            }
            Stmt::SafeValue { dev, value } => {
                format!("{}.safe_value = {value:#04x};", self.dev(*dev))
            }
            Stmt::PowerOnValue { dev, value } => {
                format!("{}.power_on_value = {value:#04x};", self.dev(*dev))
            }
            Stmt::Watchdog { dev, seconds } => format!("{}.watchdog({seconds});", self.dev(*dev)),
            Stmt::WatchdogOff { dev } => format!("{}.watchdog_off();", self.dev(*dev)),
            Stmt::Reset { dev } => format!("{}.reset();", self.dev(*dev)),
            Stmt::Throw { on_call } => {
                self.counters += 1;
                let c = format!("calls_{}", self.counters);
                self.head.push(format!("let {c} = 0;"));
                format!("{c} += 1; if {c} == {on_call} {{ throw \"fault search: boom\"; }}")
            }
            Stmt::Spin { iterations } => {
                format!("let n = 0; for i in 0..{iterations} {{ n += 1; }}")
            }
            Stmt::Grow { timers } => {
                let big = "let big = \"0123456789abcdef\"; for i in 0..11 { big += big; }";
                if !self.head.iter().any(|h| h == big) {
                    self.head.push(big.to_string());
                }
                // Four strings a timer: each may be as large as a string may be.
                format!(
                    "for i in 0..{timers} {{ let a = big + i; let b = big + i; let c = big + i; \
                     let d = big + i; after(\"1h\", || a.len() + b.len() + c.len() + d.len()); }}"
                )
            }
            Stmt::BigString => "let s = \"x\"; loop { s += s; }".into(),
            Stmt::Stop { code } => format!("stop({code});"),
            Stmt::Every { ms, body } => {
                format!("every(\"{ms}ms\", || {});", self.block(body, depth))
            }
            Stmt::After { ms, body } => {
                format!("after(\"{ms}ms\", || {});", self.block(body, depth))
            }
            Stmt::OnRise { dev, ch, body } => {
                let d = self.dev(*dev);
                format!("{d}.on_rise({ch}, || {});", self.block(body, depth))
            }
            Stmt::OnFall { dev, ch, body } => {
                let d = self.dev(*dev);
                format!("{d}.on_fall({ch}, || {});", self.block(body, depth))
            }
            Stmt::OnStop { body } => format!("on_stop(|| {});", self.block(body, depth)),
        };
        let _ = writeln!(out, "{pad}{line}");
    }
}
