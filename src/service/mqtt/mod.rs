//! The run's MQTT client (`[mqtt]` in rig.toml): one more consumer of the event stream and
//! one more asker on the control queue, on threads of its own, so a slow or absent broker
//! costs the scan loop nothing.
//!
//! It tells the broker the rig's status (retained `online`, last will `offline`), each
//! device's state (retained, on change), every record (QoS 1, through the on-disk outbox,
//! `outbox`), the warnings, errors and safe-state events (`topics::log_payload`), and what
//! the script publishes; it hands inbound commands and watched topics to the loop
//! (`runtime::remote`) and publishes the commands' replies.

pub mod discovery;
pub mod failure;
pub mod health;
mod link;
pub mod outbox;
mod pump;
pub mod tls;
pub mod topics;

use crate::config::mqtt::{MqttConfig, PasswordSource, Transport};
use crate::runtime::observe::{Events, TooManySubscribers};
use crate::runtime::requests::Requester;
use rumqttc::v5::mqttbytes::v5::LastWill;
use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::MqttOptions;
use rumqttc::TlsConfiguration;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;
pub use topics::Topics;

/// Events the client's queue holds: records must not be lost to a burst (each is small).
const EVENT_QUEUE: usize = 16_384;

/// The largest packet the client takes, as it tells the broker: a command or watched message
/// at its bounds (`topics::MAX_PAYLOAD`, `topics::MAX_TOPIC`) and room for the headers and a
/// publisher's properties. A message a little over the payload bound still arrives, and is
/// dropped here, counted; a larger one the broker drops.
pub const MAX_INBOUND_PACKET: u32 = (topics::MAX_PAYLOAD + topics::MAX_TOPIC + 1024) as u32;

/// How long a normal stop waits for the outbox to go out.
pub const FLUSH_WAIT: Duration = Duration::from_secs(2);

/// Why the client cannot start (the run does not start either: rig.toml asked for it).
#[derive(Debug, thiserror::Error)]
pub enum MqttError {
    /// The password cannot be had.
    #[error("mqtt: password_file {path}: {source}")]
    PasswordFile {
        /// The file.
        path: String,
        /// What the system said.
        #[source]
        source: std::io::Error,
    },
    /// The password's variable is not set.
    #[error("mqtt: password_env {0} is not set")]
    PasswordEnv(String),
    /// TLS cannot be set up.
    #[error("mqtt: {0}")]
    Tls(#[from] tls::TlsError),
    /// The outbox cannot be opened.
    #[error("mqtt: {source}: {}", if *.chosen {
        "rig.toml's [mqtt] outbox names it; give a directory the rig's user can write"
    } else {
        "the default outbox (beside the records file, else $STATE_DIRECTORY, \
         $XDG_STATE_HOME or ~/.local/state); set [mqtt] outbox in rig.toml to a directory the \
         rig's user can write"
    })]
    Outbox {
        /// What the outbox said.
        #[source]
        source: outbox::OutboxError,
        /// Whether rig.toml's `outbox` named the directory.
        chosen: bool,
    },
    /// The event stream has no room.
    #[error("mqtt: {0}")]
    Subscribe(#[from] TooManySubscribers),
    /// The client's thread cannot be started.
    #[error("mqtt: cannot start its thread: {0}")]
    Thread(std::io::Error),
}

/// What the client was set up with, resolved (names, password, TLS, the outbox's place).
#[derive(Clone)]
pub struct Settings {
    /// The broker as `host:port`, for messages.
    pub broker: String,
    host: String,
    port: u16,
    /// The rig's name on the broker.
    pub rig: String,
    /// Its topics.
    pub topics: Topics,
    username: Option<String>,
    password: Option<String>,
    tls: Option<Arc<rustls::ClientConfig>>,
    keepalive: Duration,
    /// The outbox's directory.
    pub outbox_dir: PathBuf,
    /// Whether rig.toml named it (`outbox`), for messages.
    outbox_chosen: bool,
    outbox_max: u64,
    ha_discovery: bool,
}

impl Settings {
    /// Resolves `config` for the run named `run_name` (its socket's name) whose records file
    /// is `records` (if any).
    pub fn resolve(
        config: &MqttConfig,
        run_name: &str,
        records: Option<&Path>,
    ) -> Result<Self, MqttError> {
        let rig = config
            .rig
            .clone()
            .unwrap_or_else(|| format!("{}-{run_name}", host_name()));
        let password = match &config.password {
            None => None,
            Some(PasswordSource::File(path)) => {
                let text =
                    std::fs::read_to_string(path).map_err(|source| MqttError::PasswordFile {
                        path: path.display().to_string(),
                        source,
                    })?;
                Some(text.lines().next().unwrap_or("").to_string())
            }
            Some(PasswordSource::Env(name)) => {
                Some(std::env::var(name).map_err(|_| MqttError::PasswordEnv(name.clone()))?)
            }
        };
        let tls = match config.transport {
            Transport::Plain => None,
            Transport::Tls => Some(tls::client_config(config.ca_file.as_deref())?),
        };
        Ok(Self {
            broker: format!("{}:{}", config.host, config.port),
            host: config.host.clone(),
            port: config.port,
            topics: Topics::new(&config.prefix, &rig),
            rig,
            username: config.username.clone(),
            password,
            tls,
            keepalive: config.keepalive,
            outbox_dir: config
                .outbox
                .clone()
                .unwrap_or_else(|| default_outbox(records, &|name| std::env::var_os(name))),
            outbox_chosen: config.outbox.is_some(),
            outbox_max: config.outbox_max,
            ha_discovery: config.ha_discovery,
        })
    }

    /// The user, for messages.
    fn user(&self) -> &str {
        self.username.as_deref().unwrap_or(failure::ANONYMOUS)
    }

    /// Options for one connection: who the rig is, its last will, its keep-alive.
    fn options(&self) -> MqttOptions {
        let mut o = MqttOptions::new(
            format!("rigscript-{}", self.rig),
            self.host.clone(),
            self.port,
        );
        // rig.toml allows no shorter one; rumqttc's MQTT 5 client panics below 5 s.
        o.set_keep_alive(self.keepalive.max(crate::config::mqtt::MIN_KEEPALIVE));
        o.set_clean_start(true);
        o.set_last_will(LastWill::new(
            self.topics.status(),
            topics::OFFLINE,
            QoS::AtLeastOnce,
            true,
            None,
        ));
        // Announced in CONNECT: the broker drops a larger packet for this client instead of
        // sending it (rumqttc would end the connection on it, and a retained one would end
        // every connection made again).
        o.set_max_packet_size(Some(MAX_INBOUND_PACKET));
        o.set_outgoing_inflight_upper_limit(pump::WINDOW as u16 + 16);
        if let Some(user) = &self.username {
            o.set_credentials(user.clone(), self.password.clone().unwrap_or_default());
        }
        if let Some(tls) = &self.tls {
            o.set_transport(rumqttc::Transport::Tls(TlsConfiguration::Rustls(
                Arc::clone(tls),
            )));
        }
        o
    }
}

/// This machine's host name (`localhost` if it has none).
fn host_name() -> String {
    let name = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
    let name: String = name
        .split('.')
        .next()
        .unwrap_or("")
        .chars()
        .filter(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_'))
        .collect();
    if !name.is_empty() {
        name
    } else {
        "localhost".into()
    }
}

/// Runs `f`, its panic caught as what it said (a thread of the client's that panicked would
/// otherwise end unseen, the rig running on with MQTT silently dead).
fn catching<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f))
        .map_err(|payload| crate::runtime::runner::panic_message(payload.as_ref()))
}

/// Where the packaged unit keeps state when systemd gives no `$STATE_DIRECTORY`.
const SYSTEM_STATE: &str = "/var/lib/rigscript";

/// Beside the records file (`records.jsonl` → `records.outbox/`); else systemd's state
/// directory (`$STATE_DIRECTORY/outbox`, its first if it gives several); else the user's
/// (`$XDG_STATE_HOME/rigscript/outbox`, `~/.local/state/rigscript/outbox`); else, with no
/// home (`DynamicUser`, `HOME=/`), `/var/lib/rigscript/outbox`. `env` reads a variable.
fn default_outbox(
    records: Option<&Path>,
    env: &dyn Fn(&str) -> Option<std::ffi::OsString>,
) -> PathBuf {
    if let Some(r) = records {
        let stem = r
            .file_stem()
            .map_or_else(|| "records".into(), |s| s.to_string_lossy().into_owned());
        return r.with_file_name(format!("{stem}.outbox"));
    }
    let set = |name: &str| env(name).filter(|v| !v.is_empty());
    if let Some(dirs) = set("STATE_DIRECTORY") {
        let first = dirs.to_string_lossy().split(':').next().map(PathBuf::from);
        if let Some(dir) = first.filter(|d| d.is_absolute()) {
            return dir.join("outbox");
        }
    }
    let home = set("HOME")
        .map(PathBuf::from)
        .filter(|h| h.is_absolute() && h.parent().is_some());
    set("XDG_STATE_HOME")
        .map(PathBuf::from)
        .filter(|d| d.is_absolute())
        .or_else(|| home.map(|h| h.join(".local/state")))
        .map_or_else(|| PathBuf::from(SYSTEM_STATE), |d| d.join("rigscript"))
        .join("outbox")
}

/// The running client: `finish` ends it (flushing the outbox for up to `FLUSH_WAIT`).
pub struct MqttService {
    closing: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

/// A client whose outbox is open, ready to attach to a run (`start`).
pub struct Prepared {
    settings: Settings,
    outbox: outbox::Outbox,
}

impl Prepared {
    /// Opens the outbox of `settings` (before any device is touched: an outbox that cannot be
    /// opened stops the run from starting).
    pub fn new(settings: Settings) -> Result<Self, MqttError> {
        let outbox = outbox::Outbox::open(&settings.outbox_dir, &settings.rig, settings.outbox_max)
            .map_err(|source| MqttError::Outbox {
                source,
                chosen: settings.outbox_chosen,
            })?;
        Ok(Self { settings, outbox })
    }

    /// Starts the client, fed by `events`, asking the loop through `requester`.
    pub fn start(self, events: &Events, requester: Requester) -> Result<MqttService, MqttError> {
        // Every kind but ticks, which the client never reads: a tick's event would be built
        // and queued for it on the loop's thread every period.
        use crate::runtime::observe::{Bound, EventKind, Kinds};
        let kinds = Kinds::of(&[
            EventKind::ScriptStarted,
            EventKind::ScriptFailed,
            EventKind::ScriptRestarting,
            EventKind::Inputs,
            EventKind::Shown,
            EventKind::Outputs,
            EventKind::DeviceLost,
            EventKind::DeviceBack,
            EventKind::Log,
            EventKind::Record,
            EventKind::Ended,
            EventKind::Published,
        ]);
        let subscription = events.subscribe_to("mqtt", Bound::events(EVENT_QUEUE), kinds)?;
        // The devices' state on the broker is the rig's whole I/O image, kept current for its
        // subscribers as long as the client runs (`runtime::watched_image`).
        let watching = events.watching();
        let closing = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&closing);
        let Prepared { settings, outbox } = self;
        let counts = health::ClientHealth::new(&settings.broker);
        // What the loop turns away counts beside the client's own losses, all shown in status.
        requester.share(Box::new(counts.clone()));
        let broker = settings.broker.clone();
        let thread = std::thread::Builder::new()
            .name("mqtt".into())
            .spawn(move || {
                let _watching = watching;
                let asker = requester.clone();
                let shown = counts.clone();
                let ran = catching(|| {
                    pump::Pump::new(settings, subscription, requester, outbox, flag, counts).run()
                });
                // Nothing else would tell: the rig runs on, its status says the client is gone
                // (the broker sees the connection drop and publishes the last will).
                if let Err(why) = ran {
                    let why = format!("the client's thread panicked: {why}");
                    shown.stopped(&why);
                    pump::tell(
                        &asker,
                        true,
                        crate::runtime::log::Level::Error,
                        &format!(
                            "mqtt: {why}; MQTT is off for the rest of the run: nothing more \
                             goes to broker {broker} (its last will says offline); the rig runs \
                             on"
                        ),
                    );
                }
            })
            .map_err(MqttError::Thread)?;
        Ok(MqttService {
            closing,
            thread: Some(thread),
        })
    }
}

impl MqttService {
    /// Ends the client once the run has ended: the outbox gets up to `FLUSH_WAIT` to go
    /// out, the status goes `offline`, what is left waits for the next start.
    pub fn finish(mut self) {
        self.closing.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for MqttService {
    fn drop(&mut self) {
        self.closing.store(true, Ordering::SeqCst);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_outbox_works_under_systemd_and_without_a_home() {
        let at = |vars: &[(&str, &str)], records: Option<&str>| {
            let vars: Vec<(String, String)> = vars
                .iter()
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect();
            let env = move |name: &str| vars.iter().find(|(k, _)| k == name).map(|(_, v)| v.into());
            default_outbox(records.map(Path::new), &env)
                .display()
                .to_string()
        };
        assert_eq!(at(&[], Some("out/r.jsonl")), "out/r.outbox");
        let systemd = [
            ("STATE_DIRECTORY", "/var/lib/rigscript/bench:/x"),
            ("HOME", "/"),
        ];
        assert_eq!(at(&systemd, None), "/var/lib/rigscript/bench/outbox");
        assert_eq!(
            at(&[("HOME", "/home/ann"), ("XDG_STATE_HOME", "")], None),
            "/home/ann/.local/state/rigscript/outbox"
        );
        assert_eq!(
            at(&[("HOME", "/home/ann"), ("XDG_STATE_HOME", "/s")], None),
            "/s/rigscript/outbox"
        );
        for no_home in [&[("HOME", "/")][..], &[("HOME", "")], &[]] {
            assert_eq!(at(no_home, None), "/var/lib/rigscript/outbox");
        }
    }

    #[test]
    fn a_panic_is_caught_as_what_it_said_and_a_value_passes_through() {
        assert_eq!(catching(|| 7), Ok(7));
        let n = 3;
        assert_eq!(
            catching(|| -> u8 { panic!("broke on {n}") }),
            Err("broke on 3".to_string())
        );
        assert_eq!(
            catching(|| -> u8 { panic!("static") }),
            Err("static".to_string())
        );
    }
}
