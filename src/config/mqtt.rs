//! `[mqtt]` of rig.toml: the broker the run tells its state and records to, who it is there,
//! and where records wait while the broker is away (the outbox).

use super::error::ProblemKind;
use super::limits::{parse_size, SIZE_FORMS};
use super::reader::{bad, boolean, duration, string, Reader, TableRef};
use std::path::PathBuf;
use std::time::Duration;
use toml::de::DeValue;

/// The keep-alive when rig.toml gives none: a frozen runner is told within 15 s.
pub const DEFAULT_KEEPALIVE: Duration = Duration::from_secs(10);

/// The outbox's bound when rig.toml gives none.
pub const DEFAULT_OUTBOX_MAX: u64 = 64 << 20;

/// The shortest keep-alive the rig asks for: rumqttc, its MQTT client, refuses less than 5 s
/// for MQTT 5 (MQTT itself counts from 1 s), and a frozen rig is called offline within 1.5
/// times this plus the broker's own sweep anyway (measured: 8.5 s at 5 s with Mosquitto).
pub const MIN_KEEPALIVE: Duration = Duration::from_secs(5);

/// The longest keep-alive MQTT can say (a 16-bit count of seconds).
const MAX_KEEPALIVE: Duration = Duration::from_secs(65_535);

/// The smallest outbox worth having: a few thousand records.
const MIN_OUTBOX_MAX: u64 = 64 << 10;

const KEYS: &[&str] = &[
    "url",
    "rig",
    "username",
    "password_file",
    "password_env",
    "ca_file",
    "keepalive",
    "prefix",
    "outbox",
    "outbox_max",
    "ha_discovery",
];

/// Whether the broker is spoken to in the clear or over TLS.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Transport {
    /// `mqtt://`: plain TCP.
    Plain,
    /// `mqtts://`: TLS.
    Tls,
}

/// Where the broker password comes from (never rig.toml itself, never the log).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PasswordSource {
    /// The first line of this file.
    File(PathBuf),
    /// This environment variable.
    Env(String),
}

/// The broker a run reports to (`[mqtt]`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MqttConfig {
    /// Plain or TLS.
    pub transport: Transport,
    /// The broker's host name or address.
    pub host: String,
    /// Its port (default 1883, or 8883 for TLS).
    pub port: u16,
    /// This rig's name on the broker (default: host name and rig name, `HOST-NAME`).
    pub rig: Option<String>,
    /// The user to log in as.
    pub username: Option<String>,
    /// Where the password is.
    pub password: Option<PasswordSource>,
    /// The CA that signs the broker's certificate (TLS; default: the system's roots).
    pub ca_file: Option<PathBuf>,
    /// MQTT keep-alive: the broker calls the rig gone after 1.5 times this without a word.
    pub keepalive: Duration,
    /// The topics' prefix, `{rig}` standing for the rig's name (default `rigscript/{rig}`).
    pub prefix: String,
    /// The outbox's directory (default beside the records file, else the state directory).
    pub outbox: Option<PathBuf>,
    /// The outbox's bound in bytes.
    pub outbox_max: u64,
    /// Whether Home Assistant discovery configs are published.
    pub ha_discovery: bool,
}

/// The default topic prefix.
pub const DEFAULT_PREFIX: &str = "rigscript/{rig}";

/// Splits `mqtt://host[:port]` or `mqtts://host[:port]`; says what is wrong otherwise.
pub fn parse_url(url: &str) -> Result<(Transport, String, u16), String> {
    let (transport, rest) = if let Some(r) = url.strip_prefix("mqtts://") {
        (Transport::Tls, r)
    } else if let Some(r) = url.strip_prefix("mqtt://") {
        (Transport::Plain, r)
    } else {
        return Err("is not a broker URL; use mqtt://HOST[:PORT] or mqtts://HOST[:PORT]".into());
    };
    let rest = rest.strip_suffix('/').unwrap_or(rest);
    let default_port = match transport {
        Transport::Plain => 1883,
        Transport::Tls => 8883,
    };
    // `[::1]:1883` for an IPv6 address; else the last ':' starts the port.
    let (host, port) = match rest.strip_prefix('[') {
        Some(v6) => match v6.split_once(']') {
            Some((h, "")) => (h, None),
            Some((h, p)) => (h, Some(p.strip_prefix(':').unwrap_or(p))),
            None => return Err("has an IPv6 address without its ']'".into()),
        },
        None => match rest.rsplit_once(':') {
            Some((h, p)) => (h, Some(p)),
            None => (rest, None),
        },
    };
    let port = match port {
        None => default_port,
        Some(p) => p
            .parse()
            .ok()
            .filter(|&p: &u16| p != 0)
            .ok_or_else(|| format!("has no port number after ':' ({p:?}); use 1-65535"))?,
    };
    let host = host.to_string();
    let fits = !host.is_empty()
        && host
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '_' | ':'));
    if !fits {
        return Err("names no broker host; use mqtt://HOST[:PORT] (no user, path or query)".into());
    }
    Ok((transport, host, port))
}

/// Whether a prefix can stand before the topics: no wildcards, no empty levels.
pub fn check_prefix(prefix: &str) -> Result<(), &'static str> {
    if prefix.is_empty()
        || prefix.contains(['#', '+', '\0'])
        || prefix.starts_with('/')
        || prefix.ends_with('/')
        || prefix.contains("//")
        || prefix.len() > 200
    {
        return Err(
            "is not a topic prefix: use levels like \"rigscript/{rig}\", without '#', \
                    '+', empty levels or a '/' at either end, at most 200 bytes",
        );
    }
    Ok(())
}

/// Reads the `[mqtt]` table; `None` when it has problems (all of them reported).
pub(super) fn read_mqtt(r: &mut Reader<'_>, table: &TableRef<'_, '_>) -> Option<MqttConfig> {
    r.check_keys(table, KEYS);
    let url = r.read(table, "url", |v| {
        parse_url(&string(v)?).map_err(|why| bad(v, why))
    });
    if table.get("url").is_none() {
        r.missing(table, "url", "url = \"mqtt://broker.lab:1883\"");
    }
    let rig = r.read(table, "rig", |v| {
        let s = string(v)?;
        super::check_rig_name(&s).map_err(|why| bad(v, why))?;
        Ok(s)
    });
    let username = r.read(table, "username", |v| match string(v)? {
        s if s.is_empty() || s.len() > 256 => Err(bad(v, "is not a user name (1-256 bytes)")),
        s => Ok(s),
    });
    let password_file = r.read(table, "password_file", |v| match string(v)? {
        s if s.trim().is_empty() => Err(bad(v, "is not a file name")),
        s => Ok(PasswordSource::File(PathBuf::from(s))),
    });
    let password_env = r.read(table, "password_env", |v| match string(v)? {
        s if s.is_empty() || s.contains(['=', '\0']) => {
            Err(bad(v, "is not an environment variable's name"))
        }
        s => Ok(PasswordSource::Env(s)),
    });
    if let (Some(_), Some(value)) = (&password_file, table.get("password_env")) {
        r.report(
            &value.span(),
            table.key_path("password_env"),
            ProblemKind::Conflict {
                other: "password_file",
            },
        );
    }
    let ca_file = r.read(table, "ca_file", |v| match string(v)? {
        s if s.trim().is_empty() => Err(bad(v, "is not a file name")),
        s => Ok(PathBuf::from(s)),
    });
    let keepalive = r
        .read(table, "keepalive", |v| match duration(v)? {
            d if d < MIN_KEEPALIVE => Err(bad(
                v,
                "is shorter than the MQTT client allows: use \"5s\" or more (the broker calls \
                 a frozen rig offline within 1.5 times the keep-alive plus its own check: about \
                 8 to 14 s at \"5s\")",
            )),
            d if d > MAX_KEEPALIVE || d.subsec_nanos() != 0 => Err(bad(
                v,
                "is not a keep-alive: use whole seconds from \"5s\" to \"65535s\" (MQTT counts \
                 it in seconds)",
            )),
            d => Ok(d),
        })
        .unwrap_or(DEFAULT_KEEPALIVE);
    let prefix = r
        .read(table, "prefix", |v| {
            let s = string(v)?;
            check_prefix(&s).map_err(|why| bad(v, why))?;
            Ok(s)
        })
        .unwrap_or_else(|| DEFAULT_PREFIX.to_string());
    let outbox = r.read(table, "outbox", |v| match string(v)? {
        s if s.trim().is_empty() => Err(bad(v, "is not a directory name")),
        s => Ok(PathBuf::from(s)),
    });
    let outbox_max = r
        .read(table, "outbox_max", |v| match v {
            DeValue::String(s) => match parse_size(s) {
                Ok(n) if n >= MIN_OUTBOX_MAX => Ok(n),
                Ok(_) => Err(bad(v, "is too small an outbox; use at least \"64KiB\"")),
                Err(e) => Err(bad(v, e.reason)),
            },
            _ => Err(bad(v, format!("is not a size; use {SIZE_FORMS}"))),
        })
        .unwrap_or(DEFAULT_OUTBOX_MAX);
    let ha_discovery = r.read(table, "ha_discovery", boolean).unwrap_or(false);
    let (transport, host, port) = url?;
    if transport == Transport::Plain {
        if let Some(value) = table.get("ca_file") {
            r.report(
                &value.span(),
                table.key_path("ca_file"),
                bad(
                    value.get_ref(),
                    "is for TLS: the url is mqtt://; use mqtts:// to speak TLS to the broker",
                ),
            );
            return None;
        }
    }
    Some(MqttConfig {
        transport,
        host,
        port,
        rig,
        username,
        password: password_file.or(password_env),
        ca_file,
        keepalive,
        prefix,
        outbox,
        outbox_max,
        ha_discovery,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::RigConfig;

    fn parse(text: &str) -> Result<Option<MqttConfig>, Vec<String>> {
        RigConfig::parse(text, "rig.toml")
            .map(|c| c.mqtt)
            .map_err(|e| match e {
                crate::config::ConfigError::Invalid(p) => {
                    p.iter().map(ToString::to_string).collect()
                }
                other => vec![other.to_string()],
            })
    }

    #[test]
    fn a_broker_with_defaults_and_every_key_read() {
        let m = parse("[mqtt]\nurl = \"mqtt://broker.lab\"\n")
            .unwrap()
            .unwrap();
        assert_eq!(
            (m.transport, m.host.as_str(), m.port),
            (Transport::Plain, "broker.lab", 1883)
        );
        assert_eq!(m.keepalive, DEFAULT_KEEPALIVE);
        assert_eq!(m.prefix, DEFAULT_PREFIX);
        assert_eq!(m.outbox_max, DEFAULT_OUTBOX_MAX);
        assert!(!m.ha_discovery);
        let m = parse(
            "[mqtt]\nurl = \"mqtts://[::1]:8884\"\nrig = \"bench2\"\nusername = \"rig\"\n\
             password_env = \"RIG_PW\"\nca_file = \"ca.pem\"\nkeepalive = \"5s\"\n\
             prefix = \"lab/{rig}\"\noutbox = \"/var/lib/rig\"\noutbox_max = \"1MiB\"\n\
             ha_discovery = true\n",
        )
        .unwrap()
        .unwrap();
        assert_eq!(
            (m.transport, m.host.as_str(), m.port),
            (Transport::Tls, "::1", 8884)
        );
        assert_eq!(m.password, Some(PasswordSource::Env("RIG_PW".into())));
        assert_eq!(m.keepalive, Duration::from_secs(5));
        assert_eq!(m.outbox_max, 1 << 20);
        assert!(m.ha_discovery);
        assert_eq!(parse("").unwrap(), None);
    }

    #[test]
    fn a_keep_alive_under_the_clients_floor_is_refused_with_the_reason() {
        let problems = parse("[mqtt]\nurl = \"mqtt://broker\"\nkeepalive = \"1s\"\n").unwrap_err();
        let all = problems.join("\n");
        assert!(
            all.contains("rig.toml:3: mqtt.keepalive: \"1s\" is shorter than the MQTT client allows: use \"5s\""),
            "{all}"
        );
    }

    #[test]
    fn bad_values_are_told_with_their_line_and_key_all_at_once() {
        let problems = parse(
            "[mqtt]\nurl = \"http://broker\"\nkeepalive = \"5500ms\"\nprefix = \"a/#\"\n\
             outbox_max = \"1KiB\"\npassword_file = \"pw\"\npassword_env = \"PW\"\nport = 1\n",
        )
        .unwrap_err();
        let all = problems.join("\n");
        for expected in [
            "rig.toml:2: mqtt.url: \"http://broker\" is not a broker URL",
            "rig.toml:3: mqtt.keepalive: \"5500ms\" is not a keep-alive",
            "rig.toml:4: mqtt.prefix: \"a/#\" is not a topic prefix",
            "rig.toml:5: mqtt.outbox_max: \"1KiB\" is too small an outbox",
            "rig.toml:7: mqtt.password_env",
            "rig.toml:8: mqtt.port: unknown key",
        ] {
            assert!(all.contains(expected), "{expected:?} not in:\n{all}");
        }
        let missing = parse("[mqtt]\nrig = \"b\"\n").unwrap_err().join("\n");
        assert!(missing.contains("mqtt.url"), "{missing}");
        let plain_ca = parse("[mqtt]\nurl = \"mqtt://b\"\nca_file = \"ca.pem\"\n")
            .unwrap_err()
            .join("\n");
        assert!(plain_ca.contains("is for TLS"), "{plain_ca}");
        let port = parse("[mqtt]\nurl = \"mqtt://b:0\"\n")
            .unwrap_err()
            .join("\n");
        assert!(port.contains("no port number"), "{port}");
    }
}
