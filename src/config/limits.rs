//! `[limits]` of rig.toml: what one handler call and the whole run may use before the script is
//! stopped as a runaway (operations and time per call, heap memory, timers armed at once).

use super::reader::{bad, duration, integer_in, Reader, TableRef};
use std::time::Duration;
use toml::de::DeValue;

/// Operations one handler call (or the top level) may take: about a tenth of a second of
/// script work.
pub const DEFAULT_OPERATIONS: u64 = 1_000_000;

/// How long one handler call (or the top level) may run, device exchanges included: well
/// inside the shortest host watchdog a module is usually given, so a slow handler is stopped
/// before the module's own watchdog would have to act.
pub const DEFAULT_HANDLER_TIME: Duration = Duration::from_secs(1);

/// Heap memory the whole run may hold (the script's data, its timers and what they capture,
/// and the runner's own few megabytes).
pub const DEFAULT_MEMORY: u64 = 256 << 20;

/// The least memory limit accepted: below it the runner itself would not fit.
pub const MIN_MEMORY: u64 = 16 << 20;

/// Timers (`every`, `after`, `cron`) armed at once.
pub const DEFAULT_TIMERS: usize = 10_000;

/// Sizes as rig.toml and `--memory-limit` take them, for messages.
pub const SIZE_FORMS: &str =
    r#""256MiB", "1GiB", "512MB" (KiB/MiB/GiB count in 1024s, KB/MB/GB in 1000s)"#;

const KEYS: &[&str] = &["operations", "handler_time", "memory", "timers"];

/// What a script may use; over any of them it is stopped as a runaway (script error at the
/// place it was, safe state written).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScriptLimits {
    /// Operations per handler call (`--budget`).
    pub operations: u64,
    /// Time per handler call on the run's clock, device exchanges included (`--handler-time`).
    pub handler_time: Duration,
    /// Heap bytes the process may hold while the script runs (`--memory-limit`).
    pub memory: u64,
    /// Timers armed at once (`--max-timers`).
    pub timers: usize,
}

impl Default for ScriptLimits {
    fn default() -> Self {
        Self {
            operations: DEFAULT_OPERATIONS,
            handler_time: DEFAULT_HANDLER_TIME,
            memory: DEFAULT_MEMORY,
            timers: DEFAULT_TIMERS,
        }
    }
}

/// A size (or memory limit) that cannot be used: `"12 parsecs" is not a size; use ...`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{text:?} {reason}")]
pub struct SizeError {
    /// The text as given.
    pub text: String,
    /// Why not, and what to use.
    pub reason: String,
}

impl SizeError {
    fn new(text: &str, reason: impl Into<String>) -> Self {
        Self {
            text: text.to_string(),
            reason: reason.into(),
        }
    }
}

/// Reads a size with its unit: `"256MiB"`, `"1.5GiB"`, `"512 MB"`, `"64KiB"`; a bare number
/// is refused (bytes or megabytes? the unit says).
pub fn parse_size(text: &str) -> Result<u64, SizeError> {
    let syntax = || SizeError::new(text, format!("is not a size; use {SIZE_FORMS}"));
    let t = text.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .ok_or_else(syntax)?;
    let (number, unit) = t.split_at(split);
    let scale: f64 = match unit.trim().to_ascii_lowercase().as_str() {
        "b" | "bytes" => 1.0,
        "kib" => 1024.0,
        "mib" => 1024.0 * 1024.0,
        "gib" => 1024.0 * 1024.0 * 1024.0,
        "kb" => 1e3,
        "mb" => 1e6,
        "gb" => 1e9,
        _ => return Err(syntax()),
    };
    if number.is_empty() || number.starts_with('.') || number.ends_with('.') {
        return Err(syntax());
    }
    let value: f64 = number.parse().map_err(|_| syntax())?;
    let bytes = (value * scale).round();
    if bytes >= u64::MAX as f64 {
        return Err(SizeError::new(text, "is too large a size"));
    }
    Ok(bytes as u64)
}

/// A memory limit: a size of at least `MIN_MEMORY`.
pub fn parse_memory_limit(text: &str) -> Result<u64, SizeError> {
    match parse_size(text)? {
        n if n >= MIN_MEMORY => Ok(n),
        _ => Err(SizeError::new(
            text,
            format!(
                "is too little memory for a run; use at least {}",
                crate::heap::format_bytes(MIN_MEMORY)
            ),
        )),
    }
}

/// Reads the `[limits]` table; a key left out keeps its default.
pub(super) fn read_limits(r: &mut Reader<'_>, table: &TableRef<'_, '_>) -> ScriptLimits {
    let defaults = ScriptLimits::default();
    r.check_keys(table, KEYS);
    let operations = r
        .read(table, "operations", |v| {
            integer_in(v, 1..=i64::MAX, "is not an operation budget; use 1 or more")
                .map(|n| n as u64)
        })
        .unwrap_or(defaults.operations);
    let handler_time = r
        .read(table, "handler_time", |v| match duration(v)? {
            d if d.is_zero() => Err(bad(v, "is not a time limit; it must be above zero")),
            d => Ok(d),
        })
        .unwrap_or(defaults.handler_time);
    let memory = r
        .read(table, "memory", |v| match v {
            DeValue::String(s) => parse_memory_limit(s).map_err(|e| bad(v, e.reason)),
            _ => Err(bad(v, format!("is not a size; use {SIZE_FORMS}"))),
        })
        .unwrap_or(defaults.memory);
    let timers = r
        .read(table, "timers", |v| {
            integer_in(
                v,
                1..=i64::from(u32::MAX),
                "is not a timer count; use 1 or more",
            )
            .map(|n| n as usize)
        })
        .unwrap_or(defaults.timers);
    ScriptLimits {
        operations,
        handler_time,
        memory,
        timers,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_take_binary_and_decimal_units() {
        assert_eq!(parse_size("256MiB"), Ok(256 << 20));
        assert_eq!(parse_size("1.5GiB"), Ok(3 << 29));
        assert_eq!(parse_size("512 MB"), Ok(512_000_000));
        assert_eq!(parse_size("64kib"), Ok(64 << 10));
        assert_eq!(parse_size("100 bytes"), Ok(100));
        for bad in [
            "",
            "256",
            "MiB",
            "1.MiB",
            ".5GiB",
            "12 parsecs",
            "-1MiB",
            "1e3MiB",
        ] {
            let e = parse_size(bad).unwrap_err();
            assert!(e.to_string().contains("\"256MiB\""), "{bad}: {e}");
        }
        assert_eq!(
            parse_size("99999999999GiB").unwrap_err().to_string(),
            "\"99999999999GiB\" is too large a size"
        );
    }

    #[test]
    fn a_memory_limit_must_leave_room_for_the_runner() {
        assert_eq!(parse_memory_limit("64MiB"), Ok(64 << 20));
        let e = parse_memory_limit("1MiB").unwrap_err().to_string();
        assert!(e.contains("at least 16 MiB"), "{e}");
    }
}
