//! The CPU wake-up latency a run asks for (Linux PM QoS, `/dev/cpu_dma_latency`), so that idle
//! CPUs wait in states they leave at once and ticks start on time.
//!
//! Why: a tick's timer fires on an idle CPU, and leaving a deep idle state costs from tens of
//! microseconds (C-states on bare metal) to milliseconds (a virtual CPU that halted hands its
//! physical CPU back to the host, which may run something else first). Measured on a 2-vCPU
//! Firecracker VM at a 10 ms period: p99 lateness 0.5-3.5 ms without a request, 0.09-0.15 ms
//! with 0 µs. The cost is power: while the request is held idle CPUs poll instead of sleeping.
//! The kernel drops the request when the file is closed, however the process ends. The setting
//! (auto, off, a limit) is `config::WakeLatency`.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Where Linux takes CPU latency requests.
pub const PM_QOS_DEVICE: &str = "/dev/cpu_dma_latency";

/// A latency request could not be made.
#[derive(Debug, thiserror::Error)]
#[error("{}: {source}", path.display())]
pub struct WakeLatencyError {
    /// The PM QoS file.
    pub path: PathBuf,
    /// What the OS said.
    #[source]
    pub source: std::io::Error,
}

/// A latency request the OS honours for as long as this value lives.
#[derive(Debug)]
pub struct LatencyHold {
    _file: File,
    limit: Duration,
}

impl LatencyHold {
    /// The latency asked for.
    pub fn limit(&self) -> Duration {
        self.limit
    }
}

/// Asks Linux to keep every CPU able to wake within `limit` until the hold is dropped.
pub fn hold(limit: Duration) -> Result<LatencyHold, WakeLatencyError> {
    hold_at(Path::new(PM_QOS_DEVICE), limit)
}

/// `hold` through the PM QoS file at `path`: the kernel takes the limit in microseconds as a
/// native-endian 32-bit integer, kept while the file stays open.
pub fn hold_at(path: &Path, limit: Duration) -> Result<LatencyHold, WakeLatencyError> {
    let error = |source| WakeLatencyError {
        path: path.to_path_buf(),
        source,
    };
    let micros = i32::try_from(limit.as_micros()).unwrap_or(i32::MAX);
    let mut file = OpenOptions::new().write(true).open(path).map_err(error)?;
    file.write_all(&micros.to_ne_bytes()).map_err(error)?;
    Ok(LatencyHold { _file: file, limit })
}

/// How the run's latency request went, for the log and `--stats`.
pub fn describe(outcome: &Option<Result<LatencyHold, WakeLatencyError>>) -> String {
    match outcome {
        None => "not requested".into(),
        Some(Ok(h)) => format!("held at {} µs", h.limit().as_micros()),
        Some(Err(e)) => format!("not held ({e})"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fresh file standing in for the PM QoS device.
    fn qos_file(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("rigscript-qos-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(name);
        std::fs::write(&path, b"").unwrap();
        path
    }

    #[test]
    fn a_hold_writes_microseconds_as_a_native_i32_and_keeps_the_file_open() {
        let path = qos_file("held");
        let h = hold_at(&path, Duration::from_micros(75)).unwrap();
        assert_eq!(h.limit(), Duration::from_micros(75));
        assert_eq!(std::fs::read(&path).unwrap(), 75i32.to_ne_bytes());
        assert_eq!(describe(&Some(Ok(h))), "held at 75 µs");
    }

    #[test]
    fn limits_beyond_an_i32_of_microseconds_are_clamped() {
        let path = qos_file("clamped");
        hold_at(&path, Duration::from_secs(10_000)).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), i32::MAX.to_ne_bytes());
    }

    #[test]
    fn a_missing_file_is_an_error_naming_it() {
        let path = qos_file("x").with_file_name("absent");
        let e = hold_at(&path, Duration::ZERO).unwrap_err();
        let text = describe(&Some(Err(e)));
        assert!(text.starts_with("not held ("), "{text}");
        assert!(text.contains(&path.display().to_string()), "{text}");
        assert_eq!(describe(&None), "not requested");
    }
}
