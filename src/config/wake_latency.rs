//! `wake_latency` (rig.toml, `--wake-latency`): what a run asks of the CPUs' idle states, as a
//! setting; `runtime::wake_latency` holds the request while the run goes.

use crate::time::duration::parse_duration;
use std::time::Duration;

/// Under `auto`, the longest interval between ticks that gets a request: up to here a
/// millisecond late is at least 5% of it.
pub const AUTO_UP_TO: Duration = Duration::from_millis(20);

/// What a run asks of the CPUs' idle states (`wake_latency` in rig.toml, `--wake-latency`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum WakeLatency {
    /// 0 µs while the loop ticks every `AUTO_UP_TO` or faster (a handler polls inputs at such a
    /// period, or a timer is that fast), nothing otherwise (the default).
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

    /// The latency to ask for while the loop ticks every `tick` (`None`: it wakes only now
    /// and then, for single timers, cron or upkeep), if any.
    pub fn limit_for(self, tick: Option<Duration>) -> Option<Duration> {
        match self {
            Self::Auto => tick.filter(|t| *t <= AUTO_UP_TO).map(|_| Duration::ZERO),
            Self::Off => None,
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
            WakeLatency::parse("0us"),
            Ok(WakeLatency::Limit(Duration::ZERO))
        );
        // A bare number has no unit (a duration anywhere on the command line needs one).
        assert!(WakeLatency::parse("0").is_err());
        let e = WakeLatency::parse("fast").unwrap_err();
        assert!(e.contains("\"fast\" is not a wake latency"), "{e}");
        assert!(e.contains("\"auto\""), "{e}");
    }

    #[test]
    fn auto_asks_for_zero_only_while_the_loop_ticks_fast() {
        let ms = |n| Some(Duration::from_millis(n));
        assert_eq!(WakeLatency::Auto.limit_for(ms(10)), Some(Duration::ZERO));
        assert_eq!(WakeLatency::Auto.limit_for(ms(20)), Some(Duration::ZERO));
        assert_eq!(WakeLatency::Auto.limit_for(ms(21)), None);
        assert_eq!(WakeLatency::Auto.limit_for(None), None, "only now and then");
        assert_eq!(WakeLatency::Off.limit_for(ms(1)), None);
        let l = Duration::from_micros(30);
        assert_eq!(WakeLatency::Limit(l).limit_for(ms(500)), Some(l));
        assert_eq!(WakeLatency::Limit(l).limit_for(None), Some(l));
    }
}
