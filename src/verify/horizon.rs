//! How long each run lasts: a minute, or longer when the script's own times need it (a timer
//! must be able to fire twice after the event that starts it, a cron schedule to come round
//! once more), up to a bound; `--for` decides instead when given.

use super::facts::Facts;
use super::field::BASE_START;
use crate::runtime::schedule::parse_cron;
use crate::time::duration::format_duration;
use chrono::{DateTime, Utc};
use std::time::Duration;

/// How long a run lasts unless the script needs longer.
pub const DEFAULT: Duration = Duration::from_secs(60);

/// The longest verify stretches runs by itself (longer only with `--for`).
pub const LONGEST: Duration = Duration::from_secs(600);

/// Beyond a cron schedule's period: its next firing and the ticks after it.
const AFTER_CRON: Duration = Duration::from_secs(10);

/// How long runs last, and why.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Horizon {
    /// Virtual time each run lasts.
    pub run_for: Duration,
    /// What made it longer than `DEFAULT` (`None`: it was not stretched).
    pub stretched_for: Option<String>,
    /// What the script needs that the runs do not last long enough for (`--for` too short, or
    /// past `LONGEST`).
    pub short_of: Option<String>,
}

/// The gap between the next two times `expr` matches (in UTC, from the runs' usual start).
fn cron_period(expr: &str) -> Option<Duration> {
    let cron = parse_cron(expr).ok()?;
    let from: DateTime<Utc> = DateTime::parse_from_rfc3339(BASE_START).ok()?.to_utc();
    let first = cron.find_next_occurrence(&from, false).ok()?;
    let second = cron.find_next_occurrence(&first, false).ok()?;
    (second - first).to_std().ok()
}

/// The run length the script's times need, and the time that needs it most.
fn needed(facts: &Facts) -> Option<(Duration, String)> {
    let timers = facts.timers.iter().map(|d| {
        (
            d.saturating_mul(2),
            format!("its {} timer", format_duration(*d)),
        )
    });
    let crons = facts.crons.iter().filter_map(|e| {
        let p = cron_period(e)?;
        Some((
            p.saturating_add(AFTER_CRON),
            format!("its cron {e:?} (every {})", format_duration(p)),
        ))
    });
    timers.chain(crons).max_by_key(|(d, _)| *d)
}

/// Whole seconds, up.
fn whole_seconds(d: Duration) -> Duration {
    let s = d.as_secs() + u64::from(d.subsec_nanos() > 0);
    Duration::from_secs(s)
}

impl Horizon {
    /// The horizon for a script with `facts`; `asked` is `--for`.
    pub fn of(facts: &Facts, asked: Option<Duration>) -> Self {
        let need = needed(facts).filter(|(d, _)| *d > DEFAULT);
        let short = |run_for: Duration, need: &Option<(Duration, String)>, why: &str| {
            need.as_ref()
                .filter(|(d, _)| *d > run_for)
                .map(|(d, what)| {
                    format!(
                        "{what} needs runs of {}, {why} {}: what it does later is not searched",
                        format_duration(whole_seconds(*d)),
                        format_duration(run_for)
                    )
                })
        };
        if let Some(run_for) = asked {
            return Self {
                run_for,
                stretched_for: None,
                short_of: short(run_for, &need, "--for gives"),
            };
        }
        match &need {
            None => Self {
                run_for: DEFAULT,
                stretched_for: None,
                short_of: None,
            },
            Some((d, what)) => {
                let run_for = whole_seconds(*d).min(LONGEST);
                Self {
                    run_for,
                    stretched_for: Some(what.clone()),
                    short_of: short(run_for, &need, "verify stretches them to at most")
                        .map(|s| format!("{s} (use --for)")),
                }
            }
        }
    }

    /// The line that says why runs last longer than a minute, or what they miss.
    pub fn notes(&self) -> Vec<String> {
        let mut out = Vec::new();
        if let Some(what) = &self.stretched_for {
            out.push(format!(
                "runs last {} instead of {} for {what} (--for sets it)",
                format_duration(self.run_for),
                format_duration(DEFAULT)
            ));
        }
        if let Some(s) = &self.short_of {
            out.push(format!("warning: {s}"));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn facts(source: &str) -> Facts {
        Facts::read(source)
    }

    #[test]
    fn runs_stretch_to_let_the_longest_timer_fire_twice_unless_for_is_given() {
        let f = facts(r#"every("20ms", || {}); after("75s", || {});"#);
        let h = Horizon::of(&f, None);
        assert_eq!(h.run_for, Duration::from_secs(150));
        assert_eq!(h.stretched_for.as_deref(), Some("its 1m15s timer"));
        assert_eq!(h.short_of, None);
        assert!(h.notes()[0].starts_with("runs last 2m30s instead of 1m for its 1m15s timer"));

        let asked = Horizon::of(&f, Some(Duration::from_secs(60)));
        assert_eq!(asked.run_for, Duration::from_secs(60));
        assert_eq!(asked.stretched_for, None);
        assert_eq!(
            asked.short_of.as_deref(),
            Some(
                "its 1m15s timer needs runs of 2m30s, --for gives 1m: what it does later is \
                 not searched"
            )
        );
    }

    #[test]
    fn short_timers_keep_a_minute_and_a_cron_schedule_is_waited_for_once_more() {
        assert_eq!(
            Horizon::of(&facts(r#"every("20s", || {});"#), None).run_for,
            DEFAULT
        );
        let h = Horizon::of(&facts(r#"cron("0 */5 * * * *", || {});"#), None);
        assert_eq!(h.run_for, Duration::from_secs(310));
        let daily = Horizon::of(&facts(r#"cron("0 0 3 * * *", || {});"#), None);
        assert_eq!(daily.run_for, LONGEST);
        assert!(
            daily
                .short_of
                .as_deref()
                .is_some_and(|s| s.contains("(use --for)")),
            "{daily:?}"
        );
    }
}
