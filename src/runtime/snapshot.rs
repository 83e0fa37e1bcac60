//! The whole picture of a run at a tick boundary, for whoever asks from outside the loop
//! (`rigscript status`, the control socket): every device's last reading and outputs, its
//! online state, the script's state, the tick figures and the events consumers lost. Made by
//! the loop only when asked, at most once a tick; a value, shared by every asker.
//!
//! Readings are what the loop last read for the script (inputs are read lazily: an input no
//! handler reads shows as `None`, never a reading made for the asker, which would cost the
//! loop exchanges and could steal an edge from the script).

use super::devices::Device;
use super::forcing::ForceShown;
use super::observe::Dropped;
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
}

/// The script's side of a run.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
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
}

/// The scan loop's figures so far.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
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
        /// The DI byte last read (bit n: channel n on; `None`: the script reads none).
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
        /// The switches pressed at the last reading (`None`: the script reads none).
        pressed: Option<Vec<String>>,
        /// The rotaries' counts at the last reading, by name.
        rotaries: Option<BTreeMap<String, u8>>,
    },
}

/// A TRP-C29U's latches as read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct LatchState {
    /// Channels energized since the last clear.
    pub energized: u8,
    /// Channels released since the last clear.
    pub released: u8,
}

impl DeviceState {
    /// `device` as it stands; `simulated` as the rig says.
    pub fn of(device: &Device, simulated: bool, now: std::time::Duration) -> Self {
        let health = device.health();
        let online = health.online();
        let offline_reason = (!online).then(|| {
            format!(
                "{} (for {})",
                health.cause,
                crate::time::duration::format_duration(health.lost_for(now))
            )
        });
        match device {
            Device::C29u(c) => DeviceState::C29u {
                online,
                offline_reason,
                simulated,
                inputs: c.inputs.current,
                outputs: c.outputs,
                outputs_written: c.outputs_written(),
                counters: c.counters.current,
                latches: c.latches.current.map(|l| LatchState {
                    energized: l.energized,
                    released: l.released,
                }),
                watchdog_ms: c
                    .watchdog
                    .filter(|_| c.watchdog_ours)
                    .map(|w| u64::from(w.tenths()) * 100),
                safe_value: c.config.safe_value,
                safe_mode: c.refusing,
            },
            Device::Trc(t) => DeviceState::Trc {
                online,
                offline_reason,
                simulated,
                relay: t.relay,
                relay_written: t.relay_written,
                pressed: t
                    .switches
                    .current
                    .map(|s| s.pressed_names().into_iter().map(String::from).collect()),
                rotaries: t.rotaries.current.map(|r| {
                    r.iter()
                        .map(|(rotary, value)| (rotary.name().to_string(), value))
                        .collect()
                }),
            },
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
