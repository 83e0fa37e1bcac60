//! The whole picture of a run at a tick boundary, for whoever asks from outside the loop
//! (`rigscript status`, the control socket): every device's last reading and outputs, its
//! online state, the script's state, the tick figures and the events consumers lost. Made by
//! the loop only when asked, at most once a tick; a value, shared by every asker.
//!
//! Readings are the latest of what the loop read for the script and what it read for those
//! watching (`runtime::watched_image`: while someone watches, the inputs the script does not
//! read are read for them into an image of their own, so the script's edges stay its own).

pub use super::device_view::LatchState;
use super::device_view::{ModuleView, PanelView};
use super::devices::Device;
use super::forcing::ForceShown;
use super::observe::Dropped;
use super::stats::Stats;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The version of `RigSnapshot`'s JSON form (`rigscript status --json`); raised when a
/// field changes meaning or goes, not when one is added.
pub const SNAPSHOT_VERSION: u32 = 1;

/// A run as it stands.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RigSnapshot {
    /// `SNAPSHOT_VERSION`.
    pub version: u32,
    /// The script and how it is doing.
    pub script: ScriptState,
    /// Every device, by its name in the rig.
    pub devices: BTreeMap<String, DeviceState>,
    /// Every device is held at its safe state (one was lost past its grace time).
    pub held_safe: bool,
    /// What the loop measured.
    pub ticks: TickFigures,
    /// Events lost by each consumer of the event stream.
    pub dropped: Vec<Dropped>,
    /// Log lines lost because the log's output was not being read.
    pub log_dropped: u64,
    /// Whether rig.toml allows forcing (`force = true`).
    #[serde(default)]
    pub forcing: bool,
    /// The points forced now, by the operator (`runtime::forcing`).
    #[serde(default)]
    pub forces: Vec<ForceShown>,
    /// Records the records file did not take so far (dropped or refused; the log says why).
    #[serde(default)]
    pub records_lost: u64,
    /// Events lost by every consumer the run has had, those gone since included.
    #[serde(default)]
    pub dropped_in_all: u64,
    /// The MQTT client's connection and losses (a run with `[mqtt]` only).
    #[serde(default)]
    pub mqtt: Option<MqttState>,
}

/// The MQTT client as its thread counted it (`service::mqtt::health`).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct MqttState {
    /// The broker, `host:port`.
    pub broker: String,
    /// Whether the broker has accepted the connection now.
    pub connected: bool,
    /// Connections that failed or were refused so far.
    pub connect_failures: u64,
    /// Why the last one failed.
    pub last_error: Option<String>,
    /// Why the client stopped for good (its thread panicked): nothing more goes to the
    /// broker in this run, and the rig runs on.
    #[serde(default)]
    pub failed: Option<String>,
    /// Records waiting in the outbox for the broker's acknowledgement.
    pub outbox_waiting: u64,
    /// What the client lost, by kind.
    pub dropped: MqttDropped,
}

/// What the MQTT client lost, by kind (each bound it has).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct MqttDropped {
    /// Records the outbox had no room for (`outbox_max`).
    pub outbox_full: u64,
    /// Records the outbox could not write to disk.
    pub outbox_write: u64,
    /// Watched topics' messages over the rate or the size, or the loop too busy.
    pub messages: u64,
    /// Commands refused: too large, too many waiting, the loop busy or gone.
    pub commands: u64,
    /// `mqtt_publish` messages not sent (not connected, or the client's queue full).
    pub publishes: u64,
    /// Log lines for the broker not sent.
    pub log: u64,
    /// Publishes the broker refused (its ACL, a quota): records, states, replies...
    #[serde(default)]
    pub refused: u64,
    /// Publishes over the broker's Maximum Packet Size, not sent: records, states, log lines...
    #[serde(default)]
    pub too_large: u64,
    /// Replies to commands not sent: the reply queue was full (an error reply could not be
    /// sent either; the log says so).
    #[serde(default)]
    pub replies: u64,
}

impl MqttDropped {
    /// Every kind as `(kind, count)`, the kinds as `/metrics` labels them.
    pub fn by_kind(&self) -> [(&'static str, u64); 9] {
        [
            ("outbox_full", self.outbox_full),
            ("outbox_write", self.outbox_write),
            ("messages", self.messages),
            ("commands", self.commands),
            ("publishes", self.publishes),
            ("log", self.log),
            ("refused", self.refused),
            ("too_large", self.too_large),
            ("replies", self.replies),
        ]
    }

    /// All lost, every kind.
    pub fn total(&self) -> u64 {
        self.by_kind().iter().map(|(_, n)| n).sum()
    }
}

/// The script's side of a run.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ScriptState {
    /// The script's file.
    pub file: String,
    /// `running`, `restarting` (policy restart, outputs safe meanwhile) or `ended`.
    pub state: String,
    /// How long the run has been going, in milliseconds.
    pub uptime_ms: u64,
    /// Script errors so far.
    pub errors: u64,
    /// The last one, with its file:line:column.
    pub last_error: Option<String>,
    /// Times the script was started again (policy restart).
    pub restarts: u64,
    /// The running script's content hash (SHA-256, hex; `script::content_hash`).
    #[serde(default)]
    pub hash: String,
    /// Times the script was reloaded.
    #[serde(default)]
    pub reloads: u64,
    /// When it was last reloaded (RFC 3339, the run's zone), if it was.
    #[serde(default)]
    pub reloaded: Option<String>,
    /// The script's top-level variables as they stand (read at most every `VARIABLES_EVERY`).
    #[serde(default)]
    pub variables: Variables,
    /// Each invariant the script states, and whether it holds.
    #[serde(default)]
    pub invariants: Vec<InvariantState>,
}

/// Top-level variables a snapshot shows at most; the rest are counted as hidden.
pub const MAX_VARIABLES: usize = 64;

/// Characters of a string variable shown at most; a longer one is cut and ends in "…".
pub const MAX_VARIABLE_CHARS: usize = 80;

/// How often the variables shown are read again at most: a page asking at every event costs
/// the loop one read of the script's variables in this time, however many watch.
pub const VARIABLES_EVERY: std::time::Duration = std::time::Duration::from_millis(250);

/// One of the script's top-level variables.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Variable {
    /// Its name in the script.
    pub name: String,
    /// A number, a boolean or a string (cut at `MAX_VARIABLE_CHARS`); null for `()`.
    pub value: serde_json::Value,
}

/// The script's top-level variables shown, and how many were not.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Variables {
    /// In the order the script declares them.
    pub shown: Vec<Variable>,
    /// Not shown: past `MAX_VARIABLES`, or an array or a map. Device handles and closures are
    /// not the script's state, and not counted.
    pub hidden: u64,
    /// The script chose which with `watch(...)`; otherwise every variable (not constants).
    pub chosen: bool,
}

/// An invariant the script states, as the loop last found it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct InvariantState {
    /// Its name, as the script gave it.
    pub name: String,
    /// Where it is stated (`file:line:column`), when known.
    pub at: Option<String>,
    /// Whether it held at the last tick (one found false ends the run, or rolls a reload
    /// back within `--rollback`).
    pub holds: bool,
    /// When it was last found false (the run's uptime, ms), if it ever was.
    pub failed_at_ms: Option<u64>,
    /// False on the outputs written now because of a force allowed to break it
    /// (`--override`), until that force ends.
    #[serde(default)]
    pub overridden: bool,
}

/// The scan loop's figures so far.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct TickFigures {
    /// The scan period, in microseconds.
    pub period_us: u64,
    /// Ticks run.
    pub count: u64,
    /// Ticks that ran past the next deadline.
    pub overruns: u64,
    /// How late ticks started: 99th percentile, in microseconds.
    pub jitter_p99_us: u64,
    /// Tick work: 99th percentile, in microseconds.
    pub work_p99_us: u64,
    /// Requests sent to devices, in all.
    pub transactions: u64,
    /// Tick work as a histogram (`/metrics`).
    #[serde(default)]
    pub work: Buckets,
    /// How late ticks started, as a histogram.
    #[serde(default)]
    pub jitter: Buckets,
    /// How late ticks started: median, in microseconds.
    #[serde(default)]
    pub jitter_p50_us: u64,
    /// How late ticks started: the latest, in microseconds.
    #[serde(default)]
    pub jitter_max_us: u64,
    /// Tick work: mean, in microseconds.
    #[serde(default)]
    pub work_mean_us: u64,
    /// Tick work: the longest, in microseconds.
    #[serde(default)]
    pub work_max_us: u64,
    /// The most requests in one tick.
    #[serde(default)]
    pub max_transactions: u64,
    /// How the run's CPU wake-up latency request went (real-time runs only).
    #[serde(default)]
    pub wake_latency: Option<String>,
    /// How the request for prompt wake-ups (timer slack, scheduler slice) went.
    #[serde(default)]
    pub prompt_wakeups: Option<String>,
}

/// The upper bounds of the histograms' buckets, in microseconds (50 µs to 1 s).
pub const BUCKET_BOUNDS_US: [u64; 13] = [
    50, 100, 250, 500, 1_000, 2_500, 5_000, 10_000, 25_000, 50_000, 100_000, 250_000, 1_000_000,
];

/// A histogram as Prometheus has it: the values at or below each of `BUCKET_BOUNDS_US`, how
/// many in all and their sum.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Buckets {
    /// Values at or below each bound, cumulative.
    pub le: Vec<u64>,
    /// Values counted.
    pub count: u64,
    /// Their sum, in microseconds.
    pub sum_us: u64,
}

impl Buckets {
    /// `h` over `BUCKET_BOUNDS_US`.
    pub fn of(h: &super::stats::Histogram) -> Self {
        Self {
            le: h.cumulative(&BUCKET_BOUNDS_US),
            count: h.count(),
            sum_us: h.sum_us(),
        }
    }
}

impl TickFigures {
    /// The figures of `stats`, the loop's measurement, for a loop of `period`.
    pub fn of(stats: &Stats, period: std::time::Duration) -> Self {
        Self {
            period_us: micros(period),
            count: stats.ticks,
            overruns: stats.overruns,
            jitter_p99_us: micros(stats.jitter.quantile(0.99)),
            work_p99_us: micros(stats.work.quantile(0.99)),
            transactions: stats.transactions,
            jitter_p50_us: micros(stats.jitter.quantile(0.5)),
            jitter_max_us: micros(stats.jitter.max()),
            work_mean_us: micros(stats.work.mean()),
            work_max_us: micros(stats.work.max()),
            max_transactions: stats.max_transactions,
            wake_latency: stats.wake_latency.clone(),
            prompt_wakeups: stats.prompt_wakeups.clone(),
            work: Buckets::of(&stats.work),
            jitter: Buckets::of(&stats.jitter),
        }
    }
}

impl RigSnapshot {
    /// The run's figures as `run --stats` prints them at the end.
    pub fn stats_text(&self) -> StatsText<'_> {
        StatsText(self)
    }
}

/// `RigSnapshot::stats_text`.
pub struct StatsText<'a>(&'a RigSnapshot);

fn ms(us: u64) -> String {
    format!("{:.3}ms", us as f64 / 1000.0)
}

impl std::fmt::Display for StatsText<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = self.0;
        let t = &s.ticks;
        writeln!(f, "ticks: {}", t.count)?;
        if let Some(w) = &t.wake_latency {
            writeln!(f, "wake latency: {w}")?;
        }
        writeln!(
            f,
            "jitter: p50 {} p99 {} max {}",
            ms(t.jitter_p50_us),
            ms(t.jitter_p99_us),
            ms(t.jitter_max_us)
        )?;
        writeln!(
            f,
            "tick work: mean {} p99 {} max {}",
            ms(t.work_mean_us),
            ms(t.work_p99_us),
            ms(t.work_max_us)
        )?;
        writeln!(f, "overruns: {}", t.overruns)?;
        if let Some(p) = &t.prompt_wakeups {
            writeln!(f, "prompt wake-ups: {p}")?;
        }
        if s.log_dropped > 0 {
            writeln!(
                f,
                "log lines dropped: {} (stderr not being read)",
                s.log_dropped
            )?;
        }
        if s.records_lost > 0 {
            writeln!(
                f,
                "records not written: {} (the log says why)",
                s.records_lost
            )?;
        }
        if s.dropped_in_all > 0 {
            writeln!(
                f,
                "events dropped: {} (by the event stream's consumers in all: the log, the \
                 records file, subscribers)",
                s.dropped_in_all
            )?;
        }
        let per_tick = if t.count == 0 {
            0.0
        } else {
            t.transactions as f64 / t.count as f64
        };
        write!(
            f,
            "transactions per tick: {per_tick:.2} (max {})",
            t.max_transactions
        )
    }
}

/// One device as the loop last saw it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind")]
pub enum DeviceState {
    /// A TRP-C29U module.
    #[serde(rename = "trp-c29u")]
    C29u {
        /// Whether it answers.
        online: bool,
        /// Why it went offline (while it is).
        offline_reason: Option<String>,
        /// Whether it is a simulator.
        simulated: bool,
        /// The DI byte last read (bit n: channel n on; `None`: never read, for the script or
        /// a watcher).
        inputs: Option<u8>,
        /// The DO byte the script commands (bit n: channel n on).
        outputs: u8,
        /// The DO byte last written to the module.
        outputs_written: Option<u8>,
        /// The counters last read.
        counters: Option<[u16; 8]>,
        /// The latches last read: channels energized and released since the last clear.
        latches: Option<LatchState>,
        /// The host watchdog's timeout while the runner keeps it on, in milliseconds.
        watchdog_ms: Option<u64>,
        /// The module's safe value (what it drives when the watchdog bites).
        safe_value: u8,
        /// Whether it refuses output writes (its safe mode, after a watchdog timeout).
        safe_mode: bool,
        /// Parts of its inputs a watcher is not shown fresher than the script reads them, and
        /// why (`runtime::watched_image`: a read takes longer than a tick leaves).
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        not_shown: Vec<String>,
        /// What rig.toml calls its channels, by point (`"DI0": "guard door"`).
        #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
        names: BTreeMap<String, String>,
    },
    /// A TRC1000 panel.
    #[serde(rename = "trc1000")]
    Trc {
        /// Whether it answers.
        online: bool,
        /// Why it went offline (while it is).
        offline_reason: Option<String>,
        /// Whether it is a simulator.
        simulated: bool,
        /// The relay the script commands (0: none).
        relay: u8,
        /// The relay last selected on the board.
        relay_written: Option<u8>,
        /// The switches pressed at the last reading (`None`: never read).
        pressed: Option<Vec<String>>,
        /// The rotaries' counts at the last reading, by name.
        rotaries: Option<BTreeMap<String, u8>>,
        /// Parts of its inputs a watcher is not shown fresher than the script reads them, and
        /// why (`runtime::watched_image`: a read takes longer than a tick leaves).
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        not_shown: Vec<String>,
        /// What rig.toml calls its switches, rotaries and relay positions, by point
        /// (`"S12": "cycle start"`, `"relay2": "die B"`).
        #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
        names: BTreeMap<String, String>,
    },
}

impl DeviceState {
    /// `device` as it stands; `simulated` as the rig says; `not_shown`: the parts of its inputs
    /// watchers are not shown (`Runtime::not_shown`).
    pub fn of(
        device: &Device,
        simulated: bool,
        now: std::time::Duration,
        not_shown: Vec<String>,
    ) -> Self {
        let health = device.health();
        let online = health.online();
        let offline_reason = (!online).then(|| {
            format!(
                "{} (for {})",
                health.cause(),
                crate::time::duration::format_duration(health.lost_for(now))
            )
        });
        match device {
            Device::C29u(c) => {
                let view = ModuleView::of(c);
                DeviceState::C29u {
                    online,
                    offline_reason,
                    simulated,
                    inputs: c.latest_inputs(),
                    outputs: view.outputs,
                    outputs_written: c.outputs_written(),
                    counters: c.latest_counters(),
                    latches: view.latches,
                    watchdog_ms: c.watchdog_turned_on().map(|w| u64::from(w.tenths()) * 100),
                    safe_value: c.config().safe_value,
                    safe_mode: c.refusing(),
                    names: device.names().to_map(),
                    not_shown,
                }
            }
            Device::Trc(t) => {
                let view = PanelView::of(t);
                DeviceState::Trc {
                    online,
                    offline_reason,
                    simulated,
                    relay: view.relay,
                    relay_written: t.relay_written(),
                    pressed: t
                        .latest_switches()
                        .map(|s| s.pressed_names().into_iter().map(String::from).collect()),
                    rotaries: t.latest_rotaries().map(|r| {
                        r.iter()
                            .map(|(rotary, value)| (rotary.name().to_string(), value))
                            .collect()
                    }),
                    names: device.names().to_map(),
                    not_shown,
                }
            }
        }
    }

    /// Whether the device answers.
    pub fn online(&self) -> bool {
        match self {
            DeviceState::C29u { online, .. } | DeviceState::Trc { online, .. } => *online,
        }
    }
}

/// Microseconds of `d`, saturating.
pub fn micros(d: std::time::Duration) -> u64 {
    u64::try_from(d.as_micros()).unwrap_or(u64::MAX)
}

/// Milliseconds of `d`, saturating.
pub fn millis(d: std::time::Duration) -> u64 {
    u64::try_from(d.as_millis()).unwrap_or(u64::MAX)
}
