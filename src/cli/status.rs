//! `rigscript status`, `list` and `stop`: a running rig seen and stopped from another terminal,
//! through its control socket (`service::control_socket`).
//!
//! Exit statuses: 0 done; 2 usage; 3 no such rig running (the running ones are listed); 1 the
//! rig did not answer.

use super::output::say;
use crate::config::RigConfig;
use crate::runtime::exit;
use crate::runtime::snapshot::{DeviceState, MqttState, RigSnapshot, ScriptState};
use crate::service::control_client::Connection;
use crate::service::control_protocol::{ClientRequest, Hello};
use crate::service::rig_dir::{self, Knock};
use clap::Args;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// How long `status` and `list` wait for a rig's answer.
const ANSWER_WAIT: Duration = Duration::from_secs(3);

/// How long `stop` waits for the rig's end (its on_stop handlers have 2 s, the end's writes
/// their own bounded tries).
const STOP_WAIT: Duration = Duration::from_secs(30);

/// How often `status --watch` asks.
const WATCH_EVERY: Duration = Duration::from_millis(250);

/// Options of `rigscript status`.
#[derive(Debug, Args)]
pub struct StatusArgs {
    /// The rig (as `rigscript list` names it); without it, the one rig running.
    pub rig: Option<String>,
    /// The rig of this rig.toml (its `name`, else the file's stem).
    #[arg(long, conflicts_with = "rig")]
    pub config: Option<PathBuf>,
    /// One JSON object (the snapshot, versioned: see docs/reference.md) for programs.
    #[arg(long)]
    pub json: bool,
    /// Redraw whenever something changes, until Ctrl-C or the run ends.
    #[arg(long)]
    pub watch: bool,
}

/// Options of `rigscript list`.
#[derive(Debug, Args)]
pub struct ListArgs {
    /// One JSON array of the rigs (name, pid, script, config, started, state).
    #[arg(long)]
    pub json: bool,
}

/// Options of `rigscript stop`.
#[derive(Debug, Args)]
pub struct StopArgs {
    /// The rig to stop (as `rigscript list` names it).
    pub rig: String,
}

/// Why a rig could not be reached, with the exit status it calls for.
pub(super) struct Unreached {
    message: String,
    status: i32,
}

impl Unreached {
    /// Tells it on stderr as `rigscript COMMAND: ...`; the exit status.
    pub(super) fn say(&self, command: &str) -> i32 {
        say(&format!("rigscript {command}: {}", self.message));
        self.status
    }
}

/// What runs, in words, for a message about a rig that does not.
fn running_list() -> String {
    let rigs = rig_dir::running_anywhere();
    if rigs.is_empty() {
        "no rig is running on this machine (for this user)".into()
    } else {
        let names: Vec<String> = rigs
            .iter()
            .map(|h| format!("{} (pid {})", h.rig, h.pid))
            .collect();
        format!("running: {}", names.join(", "))
    }
}

/// The socket of the rig asked for: by name, by config, or the only one running.
pub(super) fn find(rig: Option<&str>, config: Option<&Path>) -> Result<Connection, Unreached> {
    let name = match (rig, config) {
        (Some(r), _) => r.to_string(),
        (None, Some(path)) => {
            let c = RigConfig::load(path).map_err(|e| Unreached {
                message: e.to_string(),
                status: exit::USAGE,
            })?;
            rig_dir::rig_name(c.name.as_deref(), Some(path), Path::new(""))
        }
        (None, None) => {
            let rigs = rig_dir::running_anywhere();
            match rigs.as_slice() {
                [one] => one.rig.clone(),
                [] => {
                    return Err(Unreached {
                        message: "no rig is running on this machine (for this user)".into(),
                        status: exit::UNAVAILABLE,
                    })
                }
                _ => {
                    return Err(Unreached {
                        message: format!("several rigs are running; name one ({})", running_list()),
                        status: exit::USAGE,
                    })
                }
            }
        }
    };
    let not_running = |refused: &[String]| {
        let mut message = format!("no rig called {name} is running; {}", running_list());
        for why in refused {
            message.push_str(&format!("; not searched: {why}"));
        }
        Unreached {
            message,
            status: exit::UNAVAILABLE,
        }
    };
    let (path, owner) = rig_dir::find_socket(&name).map_err(|refused| not_running(&refused))?;
    match rig_dir::open(&path, owner, ANSWER_WAIT) {
        Ok((c, _)) => Ok(c),
        Err(Knock::Stale) => {
            let _ = std::fs::remove_file(&path);
            Err(not_running(&[]))
        }
        Err(Knock::Absent) => Err(not_running(&[])),
        Err(Knock::Refused(why)) => Err(Unreached {
            message: format!("rig {name}: {why}"),
            status: exit::ERROR,
        }),
        Err(Knock::Unanswered(why)) => Err(Unreached {
            message: format!("rig {name} did not answer: {why}"),
            status: exit::ERROR,
        }),
        Err(Knock::Answered(_)) => Err(not_running(&[])),
    }
}

/// Runs `rigscript status`.
pub fn status(args: StatusArgs) -> i32 {
    let mut c = match find(args.rig.as_deref(), args.config.as_deref()) {
        Ok(c) => c,
        Err(e) => return e.say("status"),
    };
    let hello = match c.hello() {
        Ok(h) => h,
        Err(e) => return say_failed("status", &e),
    };
    let mut shown: Option<RigSnapshot> = None;
    loop {
        let snapshot = match c.status() {
            Ok(s) => s,
            // The run ended while watched: its last state was shown.
            Err(_) if args.watch && shown.is_some() => {
                println!("rig {} has ended", hello.rig);
                return exit::OK;
            }
            Err(e) => return say_failed("status", &e),
        };
        let text = if args.json {
            serde_json::to_string(&snapshot).unwrap_or_default()
        } else {
            render(&hello, &snapshot)
        };
        let changed = shown.as_ref().map_or(true, |s| !same_state(s, &snapshot));
        if changed {
            let mut out = std::io::stdout();
            let cleared = if args.watch && !args.json {
                "\x1b[H\x1b[2J"
            } else {
                ""
            };
            if writeln!(out, "{cleared}{text}").is_err() {
                return exit::OK;
            }
            let _ = out.flush();
        }
        if !args.watch {
            return exit::OK;
        }
        shown = Some(snapshot);
        std::thread::sleep(WATCH_EVERY);
    }
}

/// Whether two snapshots show the same thing to a person (the clock and the tick count move
/// on always).
fn same_state(a: &RigSnapshot, b: &RigSnapshot) -> bool {
    a.devices == b.devices
        && a.script.state == b.script.state
        && a.script.errors == b.script.errors
        && a.held_safe == b.held_safe
        && a.forces.len() == b.forces.len()
        && a.forces
            .iter()
            .zip(&b.forces)
            .all(|(x, y)| x.point == y.point && x.value == y.value)
        && a.ticks.overruns == b.ticks.overruns
        && a.dropped == b.dropped
        && a.mqtt
            .as_ref()
            .map(|m| (m.connected, m.connect_failures, &m.failed, &m.dropped))
            == b.mqtt
                .as_ref()
                .map(|m| (m.connected, m.connect_failures, &m.failed, &m.dropped))
        && a.script.uptime_ms / 1000 == b.script.uptime_ms / 1000
}

fn say_failed(command: &str, e: &std::io::Error) -> i32 {
    say(&format!("rigscript {command}: the rig did not answer: {e}"));
    exit::ERROR
}

/// Runs `rigscript list`.
pub fn list(args: &ListArgs) -> i32 {
    let (found, refused) = rig_dir::survey();
    for why in &refused {
        say(&format!("rigscript list: not searched: {why}"));
    }
    let rigs: Vec<(Hello, Option<RigSnapshot>)> = found
        .into_iter()
        .map(|f| {
            let snapshot = rig_dir::open(&f.socket, f.owner, ANSWER_WAIT)
                .ok()
                .and_then(|(mut c, _)| c.status().ok());
            (f.hello, snapshot)
        })
        .collect();
    let text = if args.json {
        let rows: Vec<serde_json::Value> = rigs
            .iter()
            .map(|(h, s)| {
                serde_json::json!({
                    "rig": h.rig, "pid": h.pid, "script": h.script, "config": h.config,
                    "started": h.started,
                    "state": s.as_ref().map(|s| s.script.state.clone()),
                    "uptime_ms": s.as_ref().map(|s| s.script.uptime_ms),
                })
            })
            .collect();
        serde_json::Value::Array(rows).to_string()
    } else if rigs.is_empty() {
        "no rig is running on this machine (for this user)".to_string()
    } else {
        let mut lines = vec![format!(
            "{:<20} {:>8} {:>10} {:<11} {:<28} CONFIG",
            "RIG", "PID", "UPTIME", "STATE", "SCRIPT"
        )];
        for (h, s) in &rigs {
            let (uptime, state) = s.as_ref().map_or(("?".into(), "no answer"), |s| {
                (uptime(s.script.uptime_ms), s.script.state.as_str())
            });
            lines.push(format!(
                "{:<20} {:>8} {:>10} {:<11} {:<28} {}",
                h.rig,
                h.pid,
                uptime,
                state,
                h.script,
                h.config.as_deref().unwrap_or("(--sim)")
            ));
        }
        lines.join("\n")
    };
    let _ = writeln!(std::io::stdout(), "{text}");
    exit::OK
}

/// Runs `rigscript stop`: asks the rig to stop, then waits for its end and tells how it left
/// the devices.
pub fn stop(args: &StopArgs) -> i32 {
    let mut events = match find(Some(&args.rig), None) {
        Ok(c) => c,
        Err(e) => return e.say("stop"),
    };
    // Subscribed first, so the end is not missed between the request and the wait.
    if let Err(e) = events.subscribe() {
        return say_failed("stop", &e);
    }
    let asked = find(Some(&args.rig), None)
        .map_err(|e| e.message)
        .and_then(|mut c| c.ask(&ClientRequest::Stop).map_err(|e| e.to_string()));
    if let Err(e) = asked {
        say(&format!("rigscript stop: {}: {e}", args.rig));
        return exit::ERROR;
    }
    let until = Instant::now() + STOP_WAIT;
    loop {
        let left = until.saturating_duration_since(Instant::now());
        if left.is_zero() || events.set_read_wait(Some(left)).is_err() {
            break;
        }
        match events.next_event() {
            Ok(Some(e)) if e["event"] == "ended" => {
                let status = e["status"].as_i64().unwrap_or(-1);
                let list = |key: &str| -> Vec<String> {
                    e[key]
                        .as_array()
                        .map(|a| {
                            a.iter()
                                .filter_map(|v| v.as_str().map(String::from))
                                .collect()
                        })
                        .unwrap_or_default()
                };
                let (safe, unconfirmed) = (list("safe"), list("unconfirmed"));
                let mut line = format!("rig {} stopped: exit status {status}", args.rig);
                if !safe.is_empty() {
                    line.push_str(&format!("; safe state confirmed: {}", safe.join(", ")));
                }
                if !unconfirmed.is_empty() {
                    line.push_str(&format!(
                        "; safe state NOT confirmed: {} (see the rig's log)",
                        unconfirmed.join(", ")
                    ));
                    println!("{line}");
                    return exit::TROUBLE;
                }
                println!("{line}");
                return exit::OK;
            }
            Ok(Some(_)) => {}
            Ok(None) | Err(_) => break,
        }
    }
    say(&format!(
        "rigscript stop: {} was asked to stop, but its end was not seen within {}s; see its \
         log (the outputs go safe when it ends)",
        args.rig,
        STOP_WAIT.as_secs()
    ));
    exit::ERROR
}

/// The script's variables on one line and its invariants a line each, for `status`.
fn render_script_state(script: &ScriptState) -> Vec<String> {
    let mut out = Vec::new();
    let v = &script.variables;
    if !v.shown.is_empty() || v.hidden > 0 {
        let mut line: Vec<String> = v
            .shown
            .iter()
            .map(|v| format!("{} = {}", v.name, v.value))
            .collect();
        if v.hidden > 0 {
            line.push(format!("{} more not shown", v.hidden));
        }
        out.push(format!("  variables: {}", line.join(", ")));
    }
    for i in &script.invariants {
        let failed = i.failed_at_ms.map(|ms| format!(" at {}", uptime(ms)));
        if i.overridden {
            out.push(format!(
                "  invariant {:?}: OVERRIDDEN by a force (false on the outputs written)",
                i.name
            ));
            continue;
        }
        out.push(match (i.holds, failed) {
            (true, None) => format!("  invariant {:?}: holds", i.name),
            (true, Some(at)) => format!("  invariant {:?}: holds (last false{at})", i.name),
            (false, at) => format!(
                "  invariant {:?}: FALSE{}",
                i.name,
                at.unwrap_or_default()
            ),
        });
    }
    out
}

/// `status` for people.
pub fn render(hello: &Hello, s: &RigSnapshot) -> String {
    let mut out = Vec::new();
    out.push(format!(
        "rig {} (pid {}): {} {}, up {}",
        hello.rig,
        hello.pid,
        s.script.file,
        s.script.state,
        uptime(s.script.uptime_ms)
    ));
    if let Some(config) = &hello.config {
        out.push(format!("  config: {config}"));
    }
    if !s.script.hash.is_empty() {
        let reloaded = match &s.script.reloaded {
            Some(at) => format!(", reloaded {} time(s), last {at}", s.script.reloads),
            None => ", never reloaded".into(),
        };
        out.push(format!(
            "  script sha256: {}{reloaded}",
            crate::content_hash::short(&s.script.hash)
        ));
    }
    let mut errors = format!(
        "  script errors: {}, restarts: {}",
        s.script.errors, s.script.restarts
    );
    if let Some(last) = &s.script.last_error {
        errors.push_str(&format!("; last: {last}"));
    }
    out.push(errors);
    if s.held_safe {
        out.push("  HELD SAFE: a device was lost past its grace time".into());
    }
    for f in &s.forces {
        let overriding: Vec<String> = f.overrides.iter().map(|o| format!("{o:?}")).collect();
        out.push(format!(
            "  FORCED: {} {} for {} more (by {}){}",
            f.point,
            f.value.text(),
            crate::time::duration::format_duration(Duration::from_millis(f.remaining_ms)),
            f.by,
            match overriding.is_empty() {
                true => String::new(),
                false => format!(", overriding the invariant {}", overriding.join(", ")),
            }
        ));
    }
    out.extend(render_script_state(&s.script));
    for (name, d) in &s.devices {
        out.extend(render_device(name, d));
    }
    out.push(format!(
        "ticks: {} every {}; jitter p99 {}; work p99 {}; overruns {}; transactions {}",
        s.ticks.count,
        micros_text(s.ticks.period_us),
        micros_text(s.ticks.jitter_p99_us),
        micros_text(s.ticks.work_p99_us),
        s.ticks.overruns,
        s.ticks.transactions
    ));
    let lost: Vec<String> = s
        .dropped
        .iter()
        .filter(|d| d.events > 0)
        .map(|d| format!("{} lost {}", d.consumer, d.events))
        .collect();
    if !lost.is_empty() || s.log_dropped > 0 {
        out.push(format!(
            "dropped: {}{}",
            lost.join(", "),
            if s.log_dropped > 0 {
                format!(" log lines {}", s.log_dropped)
            } else {
                String::new()
            }
        ));
    }
    if let Some(m) = &s.mqtt {
        out.push(render_mqtt(m));
    }
    out.join("\n")
}

/// The MQTT client's line: the connection, then what it lost (only the kinds that lost some).
fn render_mqtt(m: &MqttState) -> String {
    let state = match (&m.failed, m.connected) {
        (Some(why), _) => format!("FAILED: {why}; MQTT is off for the rest of the run"),
        (None, true) => "connected".into(),
        (None, false) => "NOT CONNECTED".into(),
    };
    let mut line = format!("mqtt: broker {} {state}", m.broker);
    if m.connect_failures > 0 {
        line.push_str(&format!("; {} failed connections", m.connect_failures));
        if let Some(e) = &m.last_error {
            line.push_str(&format!(", last: {e}"));
        }
    }
    line.push_str(&format!("; outbox {} waiting", m.outbox_waiting));
    let lost: Vec<String> = m
        .dropped
        .by_kind()
        .iter()
        .filter(|(_, n)| *n > 0)
        .map(|(kind, n)| format!("{kind} {n}"))
        .collect();
    if !lost.is_empty() {
        line.push_str(&format!("; dropped: {}", lost.join(", ")));
    }
    line
}

fn render_device(name: &str, d: &DeviceState) -> Vec<String> {
    let online = |online: bool, why: &Option<String>| match (online, why) {
        (true, _) => "online".to_string(),
        (false, Some(why)) => format!("OFFLINE: {why}"),
        (false, None) => "OFFLINE".to_string(),
    };
    let sim = |s: bool| if s { ", simulated" } else { "" };
    match d {
        DeviceState::C29u {
            online: on,
            offline_reason,
            simulated,
            inputs,
            outputs,
            outputs_written,
            counters,
            latches,
            watchdog_ms,
            safe_value,
            safe_mode,
            names,
            not_shown,
        } => {
            let mut lines = vec![format!(
                "{name} (TRP-C29U{}): {}",
                sim(*simulated),
                online(*on, offline_reason)
            )];
            lines.push(format!(
                "  DI 0-7: {}",
                inputs.map_or("not read yet".to_string(), bits)
            ));
            let written = match outputs_written {
                Some(w) if w == outputs => String::new(),
                Some(w) => format!(" (module holds {w:#04x})"),
                None => " (not written yet)".to_string(),
            };
            if let Some(named) = named_channels(names, "DI", *inputs) {
                lines.push(format!("    {named}"));
            }
            lines.push(format!("  DO 0-7: {}{written}", bits(*outputs)));
            if let Some(named) = named_channels(names, "DO", Some(*outputs)) {
                lines.push(format!("    {named}"));
            }
            if let Some(c) = counters {
                let c: Vec<String> = c.iter().map(u16::to_string).collect();
                lines.push(format!("  counters: {}", c.join(" ")));
            }
            if let Some(l) = latches {
                lines.push(format!(
                    "  latches: energized {:08b}, released {:08b} (channel 7 first)",
                    l.energized, l.released
                ));
            }
            lines.push(format!(
                "  watchdog: {}; safe value {safe_value:#04x}{}",
                watchdog_ms.map_or("off".to_string(), |ms| format!("{}s", ms as f64 / 1000.0)),
                if *safe_mode {
                    "; IN SAFE MODE (refusing writes)"
                } else {
                    ""
                }
            ));
            lines.extend(not_shown.iter().map(|why| format!("  not shown: {why}")));
            lines
        }
        DeviceState::Trc {
            online: on,
            offline_reason,
            simulated,
            relay,
            relay_written,
            pressed,
            rotaries,
            names,
            not_shown,
        } => {
            let mut lines = vec![format!(
                "{name} (TRC1000{}): {}",
                sim(*simulated),
                online(*on, offline_reason)
            )];
            let written = match relay_written {
                Some(w) if w == relay => String::new(),
                Some(w) => format!(" (board holds {w})"),
                None => " (not selected yet)".to_string(),
            };
            let relay_name = names
                .get(&format!("relay{relay}"))
                .map_or(String::new(), |n| format!(" \"{n}\""));
            lines.push(format!("  relay: {relay}{relay_name}{written}"));
            let shown = |point: &str| match names.get(point) {
                Some(n) => format!("{point} \"{n}\""),
                None => point.to_string(),
            };
            lines.push(format!(
                "  pressed: {}",
                match pressed {
                    None => "not read yet".to_string(),
                    Some(p) if p.is_empty() => "none".to_string(),
                    Some(p) => p.iter().map(|s| shown(s)).collect::<Vec<_>>().join(" "),
                }
            ));
            if let Some(r) = rotaries {
                let r: Vec<String> = r.iter().map(|(k, v)| format!("{}={v}", shown(k))).collect();
                lines.push(format!("  rotaries: {}", r.join(" ")));
            }
            lines.extend(not_shown.iter().map(|why| format!("  not shown: {why}")));
            lines
        }
    }
}

/// The named channels of `prefix` (`DI`, `DO`) with their state in `value`:
/// `DI0 "guard door" on, DI3 "parts" off` (`?` where not read); `None` if none is named.
fn named_channels(
    names: &std::collections::BTreeMap<String, String>,
    prefix: &str,
    value: Option<u8>,
) -> Option<String> {
    let each: Vec<String> = (0..8u8)
        .filter_map(|ch| {
            let point = format!("{prefix}{ch}");
            let name = names.get(&point)?;
            let state = value.map_or("?", |v| if v & (1 << ch) != 0 { "on" } else { "off" });
            Some(format!("{point} \"{name}\" {state}"))
        })
        .collect();
    (!each.is_empty()).then(|| each.join(", "))
}

/// A byte as its eight channels, channel 0 first, and in hex.
fn bits(value: u8) -> String {
    let chans: Vec<&str> = (0..8)
        .map(|n| if value & (1 << n) != 0 { "1" } else { "0" })
        .collect();
    format!("{} ({value:#04x})", chans.join(" "))
}

fn uptime(ms: u64) -> String {
    crate::time::duration::format_duration(Duration::from_secs(ms / 1000))
}

fn micros_text(us: u64) -> String {
    if us >= 1000 {
        format!("{:.3}ms", us as f64 / 1000.0)
    } else {
        format!("{us}us")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bits_read_channel_0_first() {
        assert_eq!(bits(0x05), "1 0 1 0 0 0 0 0 (0x05)");
        assert_eq!(bits(0x80), "0 0 0 0 0 0 0 1 (0x80)");
    }

    #[test]
    fn the_script_s_variables_share_a_line_and_each_invariant_has_its_own() {
        use crate::runtime::snapshot::{InvariantState, Variable, Variables};
        let invariant = |name: &str, holds, failed_at_ms| InvariantState {
            name: name.into(),
            at: None,
            holds,
            failed_at_ms,
            overridden: false,
        };
        let script = ScriptState {
            variables: Variables {
                shown: vec![
                    Variable {
                        name: "tripped".into(),
                        value: serde_json::json!(true),
                    },
                    Variable {
                        name: "state".into(),
                        value: serde_json::json!("armed"),
                    },
                ],
                hidden: 2,
                chosen: false,
            },
            invariants: vec![
                invariant("guards", true, None),
                invariant("lamp", true, Some(3_000)),
                invariant("power", false, Some(61_000)),
            ],
            ..ScriptState::default()
        };
        assert_eq!(
            render_script_state(&script),
            [
                "  variables: tripped = true, state = \"armed\", 2 more not shown",
                "  invariant \"guards\": holds",
                "  invariant \"lamp\": holds (last false at 3s)",
                "  invariant \"power\": FALSE at 1m1s",
            ]
        );
    }
}
