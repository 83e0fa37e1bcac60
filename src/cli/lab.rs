//! `rigscript lab --broker URL`: every rig the broker knows, from its retained topics alone
//! (status, each device's state, the last record): online or offline, when it was last heard
//! from. `--watch` goes on showing changes; `--json` prints one JSON object (a line each
//! change with `--watch`).
//!
//! Exit statuses: 0 shown; 2 usage; 3 the broker cannot be reached or refuses.

use super::output::say;
use crate::config::mqtt::{check_prefix, parse_url, Transport};
use crate::runtime::exit;
use crate::runtime::log::visible;
use crate::service::mqtt::{failure, tls, MAX_INBOUND_PACKET};
use clap::Args;
use rumqttc::v5::mqttbytes::v5::Packet;
use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::{Client, Event, MqttOptions, RecvTimeoutError};
use rumqttc::TlsConfiguration;
use serde_json::{json, Map, Value};
use std::collections::BTreeMap;
use std::io::Write;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Options of `rigscript lab`.
#[derive(Debug, Args)]
pub struct LabArgs {
    /// The broker: mqtt://HOST:PORT or mqtts://HOST:PORT (default ports 1883, 8883)
    #[arg(long)]
    pub broker: String,
    /// The user to log in as
    #[arg(long)]
    pub username: Option<String>,
    /// An environment variable holding the password
    #[arg(long)]
    pub password_env: Option<String>,
    /// The CA that signs the broker's certificate (mqtts://)
    #[arg(long)]
    pub ca_file: Option<PathBuf>,
    /// The level above the rigs' names in their topics (rig.toml's prefix without `/{rig}`)
    #[arg(long, default_value = "rigscript")]
    pub root: String,
    /// Print JSON
    #[arg(long)]
    pub json: bool,
    /// Go on showing changes until interrupted
    #[arg(long)]
    pub watch: bool,
}

/// A rig as its retained topics show it.
#[derive(Debug, Default, Clone, PartialEq)]
struct Rig {
    status: Option<String>,
    devices: BTreeMap<String, Value>,
    last_record: Option<Value>,
}

impl Rig {
    /// The latest `at` or `time` among its messages.
    fn last_heard(&self) -> Option<String> {
        let times = self
            .devices
            .values()
            .filter_map(|d| d.get("at"))
            .chain(self.last_record.iter().filter_map(|r| r.get("time")))
            .filter_map(Value::as_str);
        times.max().map(str::to_string)
    }

    fn to_json(&self, name: &str) -> Value {
        json!({"rig": name, "status": self.status, "devices": self.devices,
               "last_record": self.last_record, "last_heard": self.last_heard()})
    }
}

/// How long the retained messages get to come after the subscription is acknowledged: they
/// come at once, so a quiet spell this long means all are in.
const SETTLE: Duration = Duration::from_millis(300);

/// Runs `lab`.
pub fn run(args: LabArgs) -> i32 {
    let (transport, host, port) = match parse_url(&args.broker) {
        Ok(u) => u,
        Err(why) => {
            say(&format!("rigscript lab: --broker {:?} {why}", args.broker));
            return exit::USAGE;
        }
    };
    if let Err(why) = check_prefix(&args.root) {
        say(&format!("rigscript lab: --root {:?} {why}", args.root));
        return exit::USAGE;
    }
    let mut o = MqttOptions::new(
        format!("rigscript-lab-{}", std::process::id()),
        host.clone(),
        port,
    );
    o.set_keep_alive(Duration::from_secs(10));
    // Announced in CONNECT (MQTT 5): the broker drops a larger retained message for this
    // client instead of sending it, so one huge message under the root cannot end the view.
    o.set_max_packet_size(Some(MAX_INBOUND_PACKET));
    if let Some(user) = &args.username {
        let pw = match &args.password_env {
            Some(var) => match std::env::var(var) {
                Ok(p) => p,
                Err(_) => {
                    say(&format!("rigscript lab: --password-env {var} is not set"));
                    return exit::USAGE;
                }
            },
            None => String::new(),
        };
        o.set_credentials(user.clone(), pw);
    }
    if transport == Transport::Tls {
        match tls::client_config(args.ca_file.as_deref()) {
            Ok(c) => {
                o.set_transport(rumqttc::Transport::Tls(TlsConfiguration::Rustls(
                    Arc::clone(&c),
                )));
            }
            Err(e) => {
                say(&format!("rigscript lab: {e}"));
                return exit::USAGE;
            }
        }
    }
    let root = args.root.clone();
    let (client, mut connection) = Client::new(o, 64);
    for t in ["status", "state/+", "last_record"] {
        let _ = client.subscribe(format!("{root}/+/{t}"), QoS::AtMostOnce);
    }
    let mut rigs: BTreeMap<String, Rig> = BTreeMap::new();
    let mut subscribed = false;
    let mut quiet_since = Instant::now();
    let started = Instant::now();
    let mut shown: Option<BTreeMap<String, Rig>> = None;
    let stdout = std::io::stdout();
    loop {
        match connection.recv_timeout(Duration::from_millis(50)) {
            Ok(Ok(Event::Incoming(Packet::SubAck(_)))) => {
                subscribed = true;
                quiet_since = Instant::now();
            }
            Ok(Ok(Event::Incoming(Packet::Publish(p)))) => {
                take(
                    &mut rigs,
                    &root,
                    &String::from_utf8_lossy(&p.topic),
                    &p.payload,
                );
                quiet_since = Instant::now();
            }
            Ok(Ok(_)) => {}
            Ok(Err(e)) => {
                let peer = failure::Peer {
                    broker: &format!("{host}:{port}"),
                    user: args.username.as_deref().unwrap_or(failure::ANONYMOUS),
                    host: &host,
                    password_from: "--username / --password-env",
                };
                say(&format!("rigscript lab: {}", failure::describe(&e, &peer)));
                return exit::UNAVAILABLE;
            }
            Err(RecvTimeoutError::Timeout) => {}
            Err(_) => return exit::UNAVAILABLE,
        }
        let settled = subscribed && quiet_since.elapsed() >= SETTLE;
        if !settled {
            if started.elapsed() > Duration::from_secs(10) {
                say(&format!(
                    "rigscript lab: broker {host}:{port} did not answer within 10 s"
                ));
                return exit::UNAVAILABLE;
            }
            continue;
        }
        if shown.as_ref() != Some(&rigs) {
            let mut out = stdout.lock();
            let written = if args.json {
                let all: Vec<Value> = rigs.iter().map(|(n, r)| r.to_json(n)).collect();
                writeln!(out, "{}", json!({ "rigs": all }))
            } else {
                write_table(&mut out, &rigs)
            };
            if written.and_then(|()| out.flush()).is_err() {
                return exit::OK;
            }
            shown = Some(rigs.clone());
        }
        if !args.watch {
            let _ = client.disconnect();
            return exit::OK;
        }
    }
}

/// Files a retained message under its rig.
fn take(rigs: &mut BTreeMap<String, Rig>, root: &str, topic: &str, payload: &[u8]) {
    let Some(rest) = topic.strip_prefix(root).and_then(|r| r.strip_prefix('/')) else {
        return;
    };
    let Some((rig, what)) = rest.split_once('/') else {
        return;
    };
    let text = String::from_utf8_lossy(payload);
    // An empty retained message clears the topic.
    let r = rigs.entry(rig.to_string()).or_default();
    match what {
        "status" => r.status = (!text.is_empty()).then(|| text.into_owned()),
        "last_record" => r.last_record = serde_json::from_str(&text).ok(),
        _ => {
            if let Some(device) = what.strip_prefix("state/") {
                match serde_json::from_str::<Value>(&text) {
                    Ok(v) => {
                        r.devices.insert(device.to_string(), v);
                    }
                    Err(_) => {
                        r.devices.remove(device);
                    }
                }
            }
        }
    }
}

/// One rig a line: name, status, when last heard from, each device in brief, the last record.
/// Whatever came from the broker is written out visibly (`log::visible`): any user who may
/// publish under the root could otherwise move the cursor, clear the screen or set the
/// terminal's title on the operator's terminal.
fn write_table(out: &mut impl Write, rigs: &BTreeMap<String, Rig>) -> std::io::Result<()> {
    if rigs.is_empty() {
        return writeln!(out, "no rigs on this broker");
    }
    let width = rigs
        .keys()
        .map(|n| visible(n).chars().count())
        .max()
        .unwrap_or(3)
        .max(3);
    writeln!(
        out,
        "{:width$}  {:7}  {:29}  DEVICES",
        "RIG", "STATUS", "LAST HEARD"
    )?;
    for (name, r) in rigs {
        let devices: Vec<String> = r.devices.iter().map(|(n, d)| brief(n, d)).collect();
        writeln!(
            out,
            "{:width$}  {:7}  {:29}  {}",
            visible(name),
            visible(r.status.as_deref().unwrap_or("?")),
            visible(&r.last_heard().unwrap_or_else(|| "-".into())),
            visible(&devices.join("; "))
        )?;
        if let Some(rec) = &r.last_record {
            writeln!(
                out,
                "{:width$}  last record: {}",
                "",
                visible(&rec.to_string())
            )?;
        }
    }
    Ok(())
}

/// A device in a few words: `io online in 0x05 out 0x80`.
fn brief(name: &str, d: &Value) -> String {
    let empty = Map::new();
    let o = d.as_object().unwrap_or(&empty);
    let online = if o.get("online") == Some(&Value::Bool(true)) {
        "online"
    } else {
        "OFFLINE"
    };
    let byte = |k: &str| {
        o.get(k)
            .and_then(Value::as_u64)
            .map(|v| format!("{k} 0x{v:02x}"))
    };
    let mut parts = vec![name.to_string(), online.to_string()];
    parts.extend(byte("inputs"));
    parts.extend(byte("outputs"));
    if let Some(r) = o.get("relay").and_then(Value::as_u64) {
        parts.push(format!("relay {r}"));
    }
    if o.get("safe_mode") == Some(&Value::Bool(true)) {
        parts.push("SAFE MODE".into());
    }
    parts.join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_writes_out_every_control_character_a_rig_user_published() {
        let mut rigs = BTreeMap::new();
        let nasty = "offline\x1b[2J\x1b]0;pwned\x07\u{9b}31m\u{202e}";
        take(
            &mut rigs,
            "rigscript",
            "rigscript/a\x1bb/status",
            nasty.as_bytes(),
        );
        take(
            &mut rigs,
            "rigscript",
            "rigscript/a\x1bb/state/io\x07",
            br#"{"online":false,"outputs":2,"at":"\u001b[1A"}"#,
        );
        take(
            &mut rigs,
            "rigscript",
            "rigscript/a\x1bb/last_record",
            "{\"v\":\"\u{9b}0m\"}".as_bytes(),
        );
        let mut out = Vec::new();
        write_table(&mut out, &rigs).unwrap();
        let text = String::from_utf8(out).unwrap();
        assert!(
            !text
                .chars()
                .any(|c| c.is_control() && c != '\n' || c == '\u{202e}'),
            "{text:?}"
        );
        for shown in [
            "a\\x1bb",
            "offline\\x1b[2J\\x1b]0;pwned\\x07\\u{9b}31m\\u{202e}",
            "io\\x07 OFFLINE",
            "\\x1b[1A",
            "\\u{9b}0m",
        ] {
            assert!(text.contains(shown), "{shown} in {text}");
        }
    }
}
