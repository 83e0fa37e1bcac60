//! `wake_latency` (rig.toml, `--wake-latency`): what a run asks of the CPUs' idle states, as a
//! setting; `runtime::wake_latency` holds the request while the run goes.

use crate::time::duration::parse_duration;
use std::time::Duration;

/// Under `auto`, the longest scan period that gets a request: up to here a millisecond late is
/// at least 5% of a period.
pub const AUTO_UP_TO: Duration = Duration::from_millis(20);

/// What a run asks of the CPUs' idle states (`wake_latency` in rig.toml, `--wake-latency`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum WakeLatency {
    /// 0 µs for periods up to `AUTO_UP_TO`, nothing for longer ones (the default).
    #[default]
    Auto,
    /// No request: the CPUs sleep as deep as the OS likes.
    Off,
    /// Idle states that take longer than this to leave are not used.
    Limit(Duration),
}

/// The forms a wake latency may take, for error messages.
pub const ACCEPTED_FORMS: &str =
    "\"auto\", \"off\" or the longest wake-up a CPU may take (\"0us\", \"50us\")";

impl WakeLatency {
    /// Reads `auto`, `off` or a duration.
    pub fn parse(text: &str) -> Result<Self, String> {
        match text.trim() {
            "auto" => Ok(Self::Auto),
            "off" => Ok(Self::Off),
            other => parse_duration(other)
                .map(Self::Limit)
                .map_err(|_| format!("{text:?} is not a wake latency; use {ACCEPTED_FORMS}")),
        }
    }

    /// The latency to ask for at scan period `period`, if any.
    pub fn limit_for(self, period: Duration) -> Option<Duration> {
        match self {
            Self::Auto if period <= AUTO_UP_TO => Some(Duration::ZERO),
            Self::Auto | Self::Off => None,
            Self::Limit(limit) => Some(limit),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_auto_off_and_durations() {
        assert_eq!(WakeLatency::parse("auto"), Ok(WakeLatency::Auto));
        assert_eq!(WakeLatency::parse(" off "), Ok(WakeLatency::Off));
        assert_eq!(
            WakeLatency::parse("50us"),
            Ok(WakeLatency::Limit(Duration::from_micros(50)))
        );
        assert_eq!(
            WakeLatency::parse("0"),
            Ok(WakeLatency::Limit(Duration::ZERO))
        );
        let e = WakeLatency::parse("fast").unwrap_err();
        assert!(e.contains("\"fast\" is not a wake latency"), "{e}");
        assert!(e.contains("\"auto\""), "{e}");
    }

    #[test]
    fn auto_asks_for_zero_only_at_short_periods() {
        let ms = Duration::from_millis;
        assert_eq!(WakeLatency::Auto.limit_for(ms(10)), Some(Duration::ZERO));
        assert_eq!(WakeLatency::Auto.limit_for(ms(20)), Some(Duration::ZERO));
        assert_eq!(WakeLatency::Auto.limit_for(ms(21)), None);
        assert_eq!(WakeLatency::Off.limit_for(ms(1)), None);
        let l = Duration::from_micros(30);
        assert_eq!(WakeLatency::Limit(l).limit_for(ms(500)), Some(l));
    }
}
