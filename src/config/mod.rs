//! `rig.toml`: the named devices, the scan period, the error policy, the records file, the
//! CPU wake-up latency the run asks for, and the script's limits (`[limits]`).
//!
//! Every key is optional except a device's `kind` and a TRP-C29U's `port`; unknown keys and
//! bad values are errors naming the file, the line and the key, all of them at once:
//! `rig.toml:9: devices.io.protocol: "modbsu" is not a protocol; use "modbus" or "ascii"`.
//! Durations are written with a unit: `"20ms"`, `"1.5s"`, `"5m"`; a bare number is an error.

mod clash;
mod device;
mod error;
pub mod feeding;
mod limits;
pub mod mqtt;
mod names;
mod reader;
pub mod script_may_change;
#[cfg(test)]
mod tests;
mod wake_latency;

pub use device::{
    is_device_name, C29uConfig, DeviceConfig, FrameGap, Port, Protocol, Trc1000Address,
    Trc1000Config, WatchdogTimeout,
};
pub use error::{ConfigError, Problem, ProblemKind};
pub use limits::{
    parse_memory_limit, parse_size, ScriptLimits, SizeError, DEFAULT_HANDLER_TIME, DEFAULT_MEMORY,
    DEFAULT_OPERATIONS, DEFAULT_TIMERS, MIN_MEMORY, SIZE_FORMS,
};
pub use names::{PointNames, Points, MAX_NAME};
pub use script_may_change::ScriptMayChange;
pub use wake_latency::WakeLatency;

use crate::text_file::{read_text, TextKind};
use reader::{boolean, duration, line_and_column, string, Reader, TableRef};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::time::Duration;
use toml::de::{DeTable, DeValue};
use wake_latency::ACCEPTED_FORMS as WAKE_FORMS;

/// Scan period when rig.toml does not set one: 50 ticks a second.
pub const DEFAULT_PERIOD: Duration = Duration::from_millis(20);

/// The longest scan period: a tick reads the inputs the handlers wait for, so a longer one
/// would leave a press or a guard opening unseen for that long (slow work is `every("30s")`).
pub const MAX_PERIOD: Duration = Duration::from_secs(10);

/// `period` as rig.toml and `--period` take it: above zero, at most `MAX_PERIOD`; else what
/// to write instead (after the value, as in `"30s" is ...`).
pub fn check_period(period: Duration) -> Result<Duration, &'static str> {
    if period.is_zero() || period > MAX_PERIOD {
        return Err(
            "is not a period: use above zero up to 10s (each tick reads the inputs \
                    the handlers wait for, so a longer period leaves an input change unseen \
                    that long; for slow work keep the period and use every(\"30s\", ..))",
        );
    }
    Ok(period)
}

/// The shortest `stall` accepted: the loop beats at least every tenth of a second when it is
/// well (its waits and a device exchange's come in slices of 20 and 100 ms).
pub const MIN_STALL: Duration = Duration::from_millis(500);

/// The longest `stall` accepted, and the longest default.
pub const MAX_STALL: Duration = Duration::from_secs(60);

/// Whether `stall` can be a stall limit (`MIN_STALL` to `MAX_STALL`).
pub fn check_stall(stall: Duration) -> Result<Duration, &'static str> {
    if stall < MIN_STALL || stall > MAX_STALL {
        return Err(
            "is not a stall limit: use 500ms to 60s (how long the scan loop may show \
                    no sign of life before it is ended as stuck and the outputs made safe)",
        );
    }
    Ok(stall)
}

/// The stall limit when rig.toml sets none: the larger of 1 s and ten periods, at most
/// `MAX_STALL`. Long enough that nothing healthy comes near it (the loop beats every 20 ms
/// while it waits, every 100 ms in an exchange, every few dozen script operations), short
/// enough that a stuck handler leaves the outputs on for about a second.
pub fn default_stall(period: Duration) -> Duration {
    period
        .saturating_mul(10)
        .clamp(Duration::from_secs(1), MAX_STALL)
}

impl RigConfig {
    /// The run's stall limit at `period` (rig.toml's `stall`, else `default_stall`).
    pub fn stall_limit(&self, period: Duration) -> Duration {
        self.stall.unwrap_or_else(|| default_stall(period))
    }
}

/// The longest rig name.
pub const MAX_RIG_NAME: usize = 64;

/// Whether `name` can name a rig: 1-64 letters, digits, `.`, `_` or `-`, not starting with
/// `.` (it names the rig's control socket file).
pub fn check_rig_name(name: &str) -> Result<(), String> {
    let fits = !name.is_empty()
        && name.len() <= MAX_RIG_NAME
        && !name.starts_with('.')
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-'));
    if fits {
        Ok(())
    } else {
        Err(format!(
            "is not a rig name: use 1-{MAX_RIG_NAME} letters, digits, '.', '_' or '-', not \
             starting with '.'"
        ))
    }
}

/// How long a device may be lost before its safe state is enforced, when not configured.
pub const DEFAULT_GRACE: Duration = Duration::from_secs(1);

const TOP_KEYS: &[&str] = &[
    "name",
    "period",
    "on_error",
    "records",
    "grace",
    "stall",
    "wake_latency",
    "ui",
    "force",
    "ui_token",
    "ui_read_token",
    "limits",
    "mqtt",
    "devices",
];

/// The web page's address when `run --ui` names none.
pub const DEFAULT_UI: &str = "127.0.0.1:7878";

/// A token, kept out of every `Debug` form (the log, error messages).
#[derive(Clone, PartialEq, Eq)]
pub struct Secret(String);

impl Secret {
    /// `text` as a secret.
    pub fn new(text: String) -> Self {
        Self(text)
    }

    /// The text, to compare with.
    pub fn expose(&self) -> &str {
        &self.0
    }
}

impl std::fmt::Debug for Secret {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Secret(..)")
    }
}

/// What the runner does when a script handler fails.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum ErrorPolicy {
    /// Put every device in its safe state and end the run (the default).
    #[default]
    Stop,
    /// Put devices in their safe state and start the script again, with back-off.
    Restart,
    /// Report the error and go on with the next tick.
    Skip,
}

impl ErrorPolicy {
    /// The policy's name as written in rig.toml.
    pub fn as_str(self) -> &'static str {
        match self {
            ErrorPolicy::Stop => "stop",
            ErrorPolicy::Restart => "restart",
            ErrorPolicy::Skip => "skip",
        }
    }
}

/// A whole rig: loop settings and named devices.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RigConfig {
    /// The rig's name on this machine (`rigscript status NAME`; default: the config file's
    /// stem, else the script's).
    pub name: Option<String>,
    /// Scan period (above zero; default `DEFAULT_PERIOD`).
    pub period: Duration,
    /// What a handler error does (default stop).
    pub on_error: ErrorPolicy,
    /// JSON-lines file for `record` and `measure` (default none).
    pub records: Option<PathBuf>,
    /// How long a device may be lost before its outputs' safe state is enforced
    /// (default `DEFAULT_GRACE`).
    pub grace: Duration,
    /// How long the scan loop may show no sign of life before its watcher ends it as stuck
    /// (`stall`; default: `default_stall` of the run's period).
    pub stall: Option<Duration>,
    /// What the run asks of the CPUs' idle states (default auto).
    pub wake_latency: WakeLatency,
    /// Where the run serves its web page and HTTP API (`ui = "ADDR"`; default none: `run
    /// --ui` turns it on).
    pub ui: Option<std::net::SocketAddr>,
    /// Whether an operator may force outputs and inputs (`force = true`; default false):
    /// `rigscript force`, `POST /api/force` (`runtime::forcing`).
    pub force: bool,
    /// The web page's control token (`ui_token`; `RIGSCRIPT_UI_TOKEN` wins): required on a
    /// non-loopback address, and then asked of every request.
    pub ui_token: Option<Secret>,
    /// The web page's read token (`ui_read_token`; `RIGSCRIPT_UI_READ_TOKEN` wins): `GET`
    /// only.
    pub ui_read_token: Option<Secret>,
    /// What the script may use (`[limits]`; defaults when absent).
    pub limits: ScriptLimits,
    /// The MQTT broker the run reports to (`[mqtt]`; default none).
    pub mqtt: Option<mqtt::MqttConfig>,
    /// The devices simulated while the others are real (`sim = true`, `run --sim-device`).
    pub simulated: BTreeSet<String>,
    /// Devices by the name scripts use.
    pub devices: BTreeMap<String, DeviceConfig>,
}

impl Default for RigConfig {
    /// No devices, every setting at its default.
    fn default() -> Self {
        Self {
            name: None,
            period: DEFAULT_PERIOD,
            on_error: ErrorPolicy::Stop,
            records: None,
            grace: DEFAULT_GRACE,
            stall: None,
            wake_latency: WakeLatency::Auto,
            ui: None,
            force: false,
            ui_token: None,
            ui_read_token: None,
            limits: ScriptLimits::default(),
            mqtt: None,
            devices: BTreeMap::new(),
            simulated: BTreeSet::new(),
        }
    }
}

impl RigConfig {
    /// Reads and checks a rig.toml file; messages name it as `path` was given.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ConfigError> {
        let path = path.as_ref();
        let text = read_text(path, TextKind::Config).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Checks rig.toml text; `file_name` is used in messages.
    pub fn parse(text: &str, file_name: &str) -> Result<Self, ConfigError> {
        let doc = DeTable::parse(text).map_err(|e| {
            let (line, column) = line_and_column(text, e.span().map_or(0, |s| s.start));
            ConfigError::Syntax {
                file: file_name.to_string(),
                line,
                column,
                message: e.message().to_string(),
            }
        })?;
        let mut r = Reader::new(file_name, text);
        let root = TableRef {
            path: String::new(),
            span: 0..0,
            table: doc.get_ref(),
        };
        r.check_keys(&root, TOP_KEYS);
        let defaults = Self::default();
        let name = r.read(&root, "name", |v| {
            let s = string(v)?;
            check_rig_name(&s).map_err(|why| reader::bad(v, why))?;
            Ok(s)
        });
        let period = r
            .read(&root, "period", |v| {
                check_period(duration(v)?).map_err(|why| reader::bad(v, why))
            })
            .unwrap_or(defaults.period);
        let on_error = r
            .read(&root, "on_error", |v| match string(v)?.as_str() {
                "stop" => Ok(ErrorPolicy::Stop),
                "restart" => Ok(ErrorPolicy::Restart),
                "skip" => Ok(ErrorPolicy::Skip),
                _ => Err(reader::bad(
                    v,
                    r#"is not an error policy; use "stop", "restart" or "skip""#,
                )),
            })
            .unwrap_or(defaults.on_error);
        let records = r.read(&root, "records", |v| match string(v)? {
            s if s.trim().is_empty() => Err(reader::bad(v, "is not a file name")),
            s => Ok(PathBuf::from(s)),
        });
        let grace = r.read(&root, "grace", duration).unwrap_or(defaults.grace);
        let stall = r.read(&root, "stall", |v| {
            check_stall(duration(v)?).map_err(|why| reader::bad(v, why))
        });
        let wake_latency = r
            .read(&root, "wake_latency", |v| {
                let read = match v {
                    DeValue::String(s) => WakeLatency::parse(s).ok(),
                    _ => duration(v).ok().map(WakeLatency::Limit),
                };
                read.ok_or_else(|| {
                    reader::bad(v, format!("is not a wake latency; use {WAKE_FORMS}"))
                })
            })
            .unwrap_or(defaults.wake_latency);
        let ui = r.read(&root, "ui", |v| {
            string(v)?.parse().map_err(|_| {
                reader::bad(
                    v,
                    format!(
                        "is not an address; use HOST:PORT with an IP address (\"{DEFAULT_UI}\")"
                    ),
                )
            })
        });
        let force = r.read(&root, "force", boolean).unwrap_or(false);
        let token = |v: &DeValue<'_>| {
            let s = string(v)?;
            match crate::service::authority::check_token(&s) {
                // The value is not shown: a token stays out of messages too.
                Err(why) => Err(ProblemKind::BadValue {
                    value: "(the token)".into(),
                    reason: why.to_string(),
                }),
                Ok(()) => Ok(Secret::new(s)),
            }
        };
        let ui_token = r.read(&root, "ui_token", token);
        let ui_read_token = r.read(&root, "ui_read_token", token);
        let limits = match root.get("limits") {
            None => ScriptLimits::default(),
            Some(value) => match value.get_ref() {
                DeValue::Table(table) => limits::read_limits(
                    &mut r,
                    &TableRef {
                        path: "limits".into(),
                        span: value.span(),
                        table,
                    },
                ),
                other => {
                    r.report(
                        &value.span(),
                        "limits".into(),
                        ProblemKind::WrongType {
                            expected: "a table ([limits])",
                            found: reader::type_name(other),
                        },
                    );
                    ScriptLimits::default()
                }
            },
        };
        let mqtt = match root.get("mqtt") {
            None => None,
            Some(value) => match value.get_ref() {
                DeValue::Table(table) => mqtt::read_mqtt(
                    &mut r,
                    &TableRef {
                        path: "mqtt".into(),
                        span: value.span(),
                        table,
                    },
                ),
                other => {
                    r.report(
                        &value.span(),
                        "mqtt".into(),
                        ProblemKind::WrongType {
                            expected: "a table ([mqtt])",
                            found: reader::type_name(other),
                        },
                    );
                    None
                }
            },
        };
        let (devices, simulated) = match root.get("devices") {
            None => (BTreeMap::new(), BTreeSet::new()),
            Some(value) => match value.get_ref() {
                DeValue::Table(table) => {
                    let t = TableRef {
                        path: "devices".into(),
                        span: value.span(),
                        table,
                    };
                    let (devices, simulated) = device::read_devices(&mut r, &t);
                    clash::check(&mut r, &t, &devices);
                    feeding::check(&mut r, &t, &devices);
                    (devices, simulated)
                }
                other => {
                    r.report(
                        &value.span(),
                        "devices".into(),
                        ProblemKind::WrongType {
                            expected: "a table of devices ([devices.NAME])",
                            found: reader::type_name(other),
                        },
                    );
                    (BTreeMap::new(), BTreeSet::new())
                }
            },
        };
        let problems = r.finish();
        if !problems.is_empty() {
            return Err(ConfigError::Invalid(problems));
        }
        Ok(Self {
            name,
            period,
            on_error,
            records,
            grace,
            stall,
            wake_latency,
            ui,
            force,
            ui_token,
            ui_read_token,
            limits,
            mqtt,
            devices,
            simulated,
        })
    }

    /// Whether the device called `name` is simulated while the rig's others may be real
    /// (`sim = true` in its table, `run --sim-device NAME`, or a module with no port).
    pub fn is_simulated(&self, name: &str) -> bool {
        self.simulated.contains(name)
            || matches!(self.devices.get(name), Some(DeviceConfig::C29u(c)) if c.port == Port::Simulated)
    }

    /// Whether any device is real hardware: only those outlive the runner, and need its
    /// guardian.
    pub fn has_real_devices(&self) -> bool {
        self.devices.keys().any(|name| !self.is_simulated(name))
    }

    /// The rig `--sim` provides without a config: `panel`, a TRC1000 at unit 0 (safe relay 0),
    /// and `io`, a TRP-C29U at Modbus id 1, both simulated, everything else at its default.
    pub fn simulated_default() -> Self {
        let mut devices = BTreeMap::new();
        devices.insert(
            "panel".to_string(),
            DeviceConfig::Trc1000(Trc1000Config {
                address: Trc1000Address::Unit(0),
                safe_relay: Some(0),
                names: Default::default(),
            }),
        );
        devices.insert(
            "io".to_string(),
            DeviceConfig::C29u(C29uConfig::with_defaults(Port::Simulated)),
        );
        Self {
            devices,
            ..Self::default()
        }
    }
}
