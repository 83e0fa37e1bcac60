//! The run's journal: what the scan loop took in (inputs that changed, device losses and
//! returns, the stop, overrun ticks) and what it wrote, one compact line an event, after a
//! header that holds the rig, the script's text and its hash, so a replay needs nothing else.
//! Written off the loop by a consumer of the event stream (`write`), read back line by line
//! (`read`), replayed in virtual time against the recorded script or an edited one (`replay`).
//!
//! The format, version 1 (docs/design/journal.md): a first line `rigscript-journal 1`, a
//! header line `H {json}`, then one entry a line, `TICK KIND FIELDS...`, ticks numbered as
//! the run counts them (0 the script's top level, then 1, 2, ...). Ticks in which nothing
//! came in or went out are not written: a replay runs them as the run did.

pub mod entry;
pub mod read;
pub mod replay;
pub mod tally;
pub mod to_test;
pub mod write;

pub use entry::{Entry, What};
pub use read::read_journal;

use crate::content_hash::content_hash;
use serde::{Deserialize, Serialize};

/// The first line of every journal this version writes.
pub const MAGIC: &str = "rigscript-journal";

/// The format's version: a journal of another is refused, naming its first line.
pub const VERSION: u32 = 1;

/// What a journal says of its run, once at its top (and again at the top of each rotated
/// part): enough to run the script again on a simulated rig of the same shape.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// The script's path as the run named it.
    pub script_file: String,
    /// The script's text.
    pub script: String,
    /// SHA-256 of the text, in hex.
    pub hash: String,
    /// The rig.toml's path, if the run had one.
    pub config_file: Option<String>,
    /// The rig.toml's text, if the run had one (none: `--sim`'s default rig).
    pub config: Option<String>,
    /// Devices the run simulated (`--sim-device`, or all under `--sim`).
    pub simulated: Vec<String>,
    /// The scan period, in microseconds (after `--period`).
    pub period_us: u64,
    /// The run's end (`--for`), in milliseconds, if it had one.
    pub run_for_ms: Option<u64>,
    /// Operations a handler call may take (after `--budget`).
    pub operations: u64,
    /// The zone of cron and `now()`: an IANA name, `UTC`, or `local` when it could not be
    /// named (a replay then takes its own machine's).
    pub zone: String,
    /// Which part of the run's journal this is (0 the first; rotation makes the next).
    pub part: u32,
    /// The tick this part starts at (0 for the first part).
    pub from_tick: u64,
    /// Names the run, so parts of one run are told from parts of another.
    pub run: String,
    /// `run --rollback`, in milliseconds: a replay undoes a reload as the run did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rollback_ms: Option<u64>,
}

impl Header {
    /// The first part's header of a run of `script` (its text `source`) on the rig of
    /// `config_file` (its text `config`, none under `--sim` alone).
    pub fn first(
        script: &str,
        source: &str,
        config_file: Option<&std::path::Path>,
        rig: &crate::config::RigConfig,
        period: std::time::Duration,
        run_for: Option<std::time::Duration>,
    ) -> std::io::Result<Self> {
        let config = config_file.map(std::fs::read_to_string).transpose()?;
        let now = chrono::Utc::now();
        Ok(Self {
            script_file: script.into(),
            script: source.into(),
            hash: content_hash(source),
            config_file: config_file.map(|p| p.display().to_string()),
            config,
            simulated: rig
                .devices
                .keys()
                .filter(|d| rig.is_simulated(d))
                .cloned()
                .collect(),
            period_us: u64::try_from(period.as_micros()).unwrap_or(u64::MAX),
            run_for_ms: run_for.map(crate::runtime::snapshot::millis),
            operations: rig.limits.operations,
            zone: local_zone_name(),
            part: 0,
            from_tick: 0,
            run: format!(
                "{}-{}",
                now.format("%Y%m%dT%H%M%S%.3fZ"),
                std::process::id()
            ),
            rollback_ms: None,
        })
    }
}

/// The zone of the machine, named so a replay elsewhere reads cron the same (`TZ`, else
/// /etc/localtime's link into the zone database; `local` when neither names one).
pub fn local_zone_name() -> String {
    if let Ok(tz) = std::env::var("TZ") {
        let tz = tz.trim_start_matches(':');
        if crate::time::zone::Zone::parse(tz).is_ok() {
            return tz.to_string();
        }
    }
    std::fs::read_link("/etc/localtime")
        .ok()
        .and_then(|p| {
            let p = p.to_string_lossy().into_owned();
            p.split_once("zoneinfo/").map(|(_, name)| name.to_string())
        })
        .filter(|name| crate::time::zone::Zone::parse(name).is_ok())
        .unwrap_or_else(|| "local".into())
}

#[cfg(test)]
mod tests;
