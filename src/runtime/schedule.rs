//! Script timers: `every(period)`, `after(delay)` and `cron(expr)`, polled once per scan tick.
//!
//! The schedule keeps no clock of its own: the scan loop passes in monotonic and wall time
//! (both from one `Clock`), so virtual time drives it in tests. `every` and `after` run on
//! monotonic time; `cron` on wall time in the schedule's time zone (`chrono::Local` in
//! production, any `chrono::TimeZone` in tests).
//!
//! Behaviour that matters:
//! - An `every` timer that fell behind by several periods (a long handler, a stalled tick)
//!   fires once, reports how many deadlines it skipped (`Fired::missed`), and re-arms at the
//!   first period boundary after the tick's own boundary (`due_at_tick`), keeping its original
//!   phase: a deadline that passed while the tick ran fires in the next tick. Overruns are
//!   counted, never made up for with a burst.
//! - A `cron` timer works the same way when the wall clock jumps forward (suspend, NTP step):
//!   once, with the skipped occurrences counted (up to `MAX_COUNTED_CRON_MISSES`). When the
//!   wall clock steps back, it re-arms from the new wall time, so wall times that come round
//!   again fire again.
//! - Cron occurrences are found by the `croner` crate, which follows Vixie cron / OCPS across
//!   DST changes (its search moves in real time, never backwards):
//!   - spring forward: a fixed time inside the gap (`0 30 2 * * *` on a day 02:00 jumps to
//!     03:00) fires once, at the first valid time after the gap (03:00); with a wildcard or
//!     step in the second, minute or hour field (`*/5 * * * * *`, `30 * * * *`) the job simply
//!     has no occurrences in the missing hour.
//!   - fall back: a fixed time in the repeated hour fires once, on its first pass; wildcard or
//!     step fields fire on both passes, because those are distinct real instants
//!     (`0 */15 * * * *` fires 100 times on a 25-hour day, and `0 0 * * * *` 25 times).
//! - A cron expression that matches no time at all (`0 0 30 2 *`) is refused when added; one
//!   that stops matching later (a year field) ends after its last occurrence.

use chrono::{DateTime, Local, TimeDelta, TimeZone, Utc};
use croner::parser::{CronParser, Seconds};
use croner::Cron;
use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::time::Duration;

/// How many skipped occurrences of a cron timer are counted after a wall-clock jump before
/// the count stops (it then reads as this value: "at least").
pub const MAX_COUNTED_CRON_MISSES: u64 = 10_000;

/// How many timers may be armed at once unless the schedule is told otherwise
/// (`set_max_timers`).
pub const DEFAULT_MAX_TIMERS: usize = 10_000;

/// Identifies one timer of a schedule; never reused within a schedule.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct TimerId(pub u64);

impl fmt::Display for TimerId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "timer {}", self.0)
    }
}

/// A timer that is due at this tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Fired {
    /// Which timer.
    pub id: TimerId,
    /// Deadlines (periods or cron occurrences) that passed without firing because the tick
    /// came late; 0 when on time.
    pub missed: u64,
    /// This was the timer's last firing (an `after`, or a cron expression that matches no
    /// later time): it is gone from the schedule.
    pub last: bool,
}

/// What a timer was made from, for messages.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TimerKind {
    /// Fires every period, first one period after it was made.
    Every(Duration),
    /// Fires once, this long after it was made.
    After(Duration),
    /// Fires at each wall-clock time the expression matches.
    Cron(String),
}

/// A timer that cannot be made.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ScheduleError {
    /// `every` needs a period above zero.
    #[error("every(0): a repeating timer needs a period above zero")]
    ZeroPeriod,
    /// The cron expression does not parse.
    #[error("{expr:?} is not a cron expression: {reason} (fields: [second] minute hour day-of-month month day-of-week)")]
    BadCron {
        /// The expression as given.
        expr: String,
        /// What the cron parser objected to.
        reason: String,
    },
    /// The cron expression parses but matches no future time.
    #[error("cron {expr:?} never fires: no time from now on matches it")]
    NeverFires {
        /// The expression as given.
        expr: String,
    },
    /// As many timers are armed as the run allows.
    #[error(
        "too many timers: {limit} are armed, the most this run allows; cancel() timers that \
         are no longer needed, or raise the limit (`timers` under [limits] in rig.toml, or \
         --max-timers)"
    )]
    TooManyTimers {
        /// The limit.
        limit: usize,
    },
}

/// Checks a cron expression without making a timer (for `rigscript check`).
pub fn validate_cron(expr: &str) -> Result<(), ScheduleError> {
    parse_cron(expr).map(|_| ())
}

/// Reads a cron expression as the schedule does (5 or 6 fields, seconds first when 6).
pub fn parse_cron(expr: &str) -> Result<Cron, ScheduleError> {
    CronParser::builder()
        .seconds(Seconds::Optional)
        .build()
        .parse(expr)
        .map_err(|e| ScheduleError::BadCron {
            expr: expr.to_string(),
            reason: e.to_string(),
        })
}

enum Trigger<Tz: TimeZone> {
    Every {
        period: Duration,
        next: Duration,
    },
    After {
        at: Duration,
    },
    Cron {
        cron: Box<Cron>,
        /// The next occurrence, in the schedule's zone: its offset tells croner which pass of a
        /// repeated hour the search is on.
        next: DateTime<Tz>,
        /// The wall time `next` was searched from, to notice the wall clock stepping back.
        searched_from: DateTime<Utc>,
    },
}

/// Where a timer waits in the schedule's queues: monotonic timers by deadline, cron timers by
/// wall-clock deadline.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Slot {
    Mono(Duration),
    Wall(DateTime<Utc>),
}

impl<Tz: TimeZone> Trigger<Tz> {
    fn slot(&self) -> Slot {
        match self {
            Trigger::Every { next, .. } => Slot::Mono(*next),
            Trigger::After { at } => Slot::Mono(*at),
            Trigger::Cron { next, .. } => Slot::Wall(next.with_timezone(&Utc)),
        }
    }
}

struct Timer<Tz: TimeZone> {
    kind: TimerKind,
    trigger: Trigger<Tz>,
}

/// The timers of one script run. Timers wait in two queues ordered by deadline (monotonic
/// time for `every` and `after`, wall time for `cron`), so finding the due ones, re-arming
/// them and cancelling one cost O(log n) each whatever the number of timers.
pub struct Schedule<Tz: TimeZone = Local> {
    tz: Tz,
    next_id: u64,
    timers: BTreeMap<TimerId, Timer<Tz>>,
    by_mono: BTreeSet<(Duration, TimerId)>,
    by_wall: BTreeSet<(DateTime<Utc>, TimerId)>,
    /// No cron timer was searched from a wall time later than this: a poll before it means
    /// the wall clock stepped back.
    latest_search: Option<DateTime<Utc>>,
    max_timers: usize,
    missed_total: u64,
    /// `due_at_tick`'s working lists, kept between ticks: a tick fires timers without
    /// allocating for them (at most `max_timers` long).
    due_mono: Vec<(Duration, TimerId)>,
    fired: Vec<(Duration, TimerId, u64, bool)>,
}

impl Schedule<Local> {
    /// An empty schedule whose cron timers follow the machine's local time zone.
    pub fn new() -> Self {
        Self::with_time_zone(Local)
    }
}

impl Default for Schedule<Local> {
    fn default() -> Self {
        Self::new()
    }
}

impl<Tz: TimeZone> fmt::Debug for Schedule<Tz> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Schedule")
            .field(
                "timers",
                &self
                    .timers
                    .iter()
                    .map(|(id, t)| (id.0, &t.kind))
                    .collect::<Vec<_>>(),
            )
            .field("missed_total", &self.missed_total)
            .finish()
    }
}

impl<Tz: TimeZone> Schedule<Tz> {
    /// An empty schedule whose cron timers follow `tz`, holding at most `DEFAULT_MAX_TIMERS`.
    pub fn with_time_zone(tz: Tz) -> Self {
        Self {
            tz,
            next_id: 1,
            timers: BTreeMap::new(),
            by_mono: BTreeSet::new(),
            by_wall: BTreeSet::new(),
            latest_search: None,
            max_timers: DEFAULT_MAX_TIMERS,
            missed_total: 0,
            due_mono: Vec::new(),
            fired: Vec::new(),
        }
    }

    /// How many timers may be armed at once; adding one more is refused
    /// (`ScheduleError::TooManyTimers`). Timers already armed stay.
    pub fn set_max_timers(&mut self, max: usize) {
        self.max_timers = max;
    }

    /// Takes every timer out, leaving an empty schedule with the same zone, limit and ids
    /// going on (a reload: the old script's timers kept aside, ids never given twice).
    pub fn take(&mut self) -> Self {
        let mut fresh = Self::with_time_zone(self.tz.clone());
        fresh.max_timers = self.max_timers;
        fresh.next_id = self.next_id;
        fresh.missed_total = self.missed_total;
        std::mem::replace(self, fresh)
    }

    #[cfg(test)]
    /// The most timers that may be armed at once.
    pub fn max_timers(&self) -> usize {
        self.max_timers
    }

    /// Forgets every timer (ids are still never reused; the limit stays).
    pub fn clear(&mut self) {
        self.timers.clear();
        self.by_mono.clear();
        self.by_wall.clear();
        self.latest_search = None;
    }

    /// A timer that fires every `period`, first at `now_mono + period`.
    pub fn every(
        &mut self,
        period: Duration,
        now_mono: Duration,
    ) -> Result<TimerId, ScheduleError> {
        if period.is_zero() {
            return Err(ScheduleError::ZeroPeriod);
        }
        let next = now_mono.saturating_add(period);
        self.insert(TimerKind::Every(period), Trigger::Every { period, next })
    }

    /// A timer that fires once at `now_mono + delay` (at the next tick when `delay` is zero).
    pub fn after(&mut self, delay: Duration, now_mono: Duration) -> Result<TimerId, ScheduleError> {
        let at = now_mono.saturating_add(delay);
        self.insert(TimerKind::After(delay), Trigger::After { at })
    }

    /// A timer that fires at each wall-clock time after `now_wall` that `expr` matches in the
    /// schedule's time zone. Five fields (minute first) or six (second first).
    pub fn cron(&mut self, expr: &str, now_wall: DateTime<Utc>) -> Result<TimerId, ScheduleError> {
        self.check_room()?;
        let cron = parse_cron(expr)?;
        let from = now_wall.with_timezone(&self.tz);
        let next =
            cron.find_next_occurrence(&from, false)
                .map_err(|_| ScheduleError::NeverFires {
                    expr: expr.to_string(),
                })?;
        let trigger = Trigger::Cron {
            cron: Box::new(cron),
            next,
            searched_from: now_wall,
        };
        self.note_search(now_wall);
        self.insert(TimerKind::Cron(expr.to_string()), trigger)
    }

    /// Removes a timer; false if it was not there (already cancelled, or a spent `after`).
    pub fn cancel(&mut self, id: TimerId) -> bool {
        match self.timers.remove(&id) {
            Some(timer) => {
                self.unqueue(timer.trigger.slot(), id);
                true
            }
            None => false,
        }
    }

    #[cfg(test)]
    /// Whether a timer is still armed.
    pub fn contains(&self, id: TimerId) -> bool {
        self.timers.contains_key(&id)
    }

    /// What a timer was made from.
    pub fn kind(&self, id: TimerId) -> Option<&TimerKind> {
        self.timers.get(&id).map(|t| &t.kind)
    }

    #[cfg(test)]
    /// How many timers are armed.
    pub fn len(&self) -> usize {
        self.timers.len()
    }

    #[cfg(test)]
    /// Whether no timer is armed.
    pub fn is_empty(&self) -> bool {
        self.timers.is_empty()
    }

    #[cfg(test)]
    /// All deadlines skipped so far (the sum of every `Fired::missed`).
    pub fn missed_total(&self) -> u64 {
        self.missed_total
    }

    #[cfg(test)]
    /// The timers due at this tick, earliest deadline first (ties in creation order), each
    /// once. Repeating timers are re-armed; spent ones (`Fired::last`) removed. The wall clock
    /// is read only while cron timers are (or were) armed: most ticks of most scripts have none.
    pub fn due(
        &mut self,
        now_mono: Duration,
        now_wall: impl FnOnce() -> DateTime<Utc>,
    ) -> Vec<Fired> {
        self.due_at_tick(now_mono, now_mono, now_wall)
    }

    /// As `due`, for a tick that runs for the period boundary `boundary` (at or before
    /// `now_mono`): what is due at `now_mono` fires, but deadlines are counted and re-armed
    /// from `boundary`, not from now. A deadline that passed while a long tick ran (retries,
    /// a module taken back, a slow handler) so falls to the catch-up tick that follows, on
    /// the last boundary passed: an `every` at the scan period fires in every tick that reads
    /// fresh inputs.
    pub fn due_at_tick(
        &mut self,
        now_mono: Duration,
        boundary: Duration,
        now_wall: impl FnOnce() -> DateTime<Utc>,
    ) -> Vec<Fired> {
        let boundary = boundary.min(now_mono);
        let mono_due = self.by_mono.first().is_some_and(|(at, _)| *at <= now_mono);
        if !mono_due && self.by_wall.is_empty() && self.latest_search.is_none() {
            return Vec::new();
        }
        let now_wall = now_wall();
        let behind = TimeDelta::from_std(now_mono.saturating_sub(boundary)).unwrap_or_default();
        let boundary_wall = now_wall - behind;
        if self.latest_search.is_some_and(|l| now_wall < l) {
            self.search_again_after_step_back(now_wall);
        }
        // (how late, id, missed, last): the latest deadline passed is the one that fires first.
        let mut fired = std::mem::take(&mut self.fired);
        fired.clear();
        let mut due = std::mem::take(&mut self.due_mono);
        take_due(&mut self.by_mono, now_mono, &mut due);
        let mut searched = false;
        for &(deadline, id) in &due {
            let late = now_mono.saturating_sub(deadline);
            let Some(timer) = self.timers.get_mut(&id) else {
                continue;
            };
            match &mut timer.trigger {
                Trigger::Every { period, next } => {
                    let (missed, rearmed) = rearm_every(*next, *period, boundary);
                    *next = rearmed;
                    self.by_mono.insert((rearmed, id));
                    fired.push((late, id, missed, false));
                }
                Trigger::After { .. } => {
                    self.timers.remove(&id);
                    fired.push((late, id, 0, true));
                }
                Trigger::Cron { .. } => {}
            }
        }
        let mut due_wall = Vec::new();
        take_due(&mut self.by_wall, now_wall, &mut due_wall);
        for (deadline, id) in due_wall {
            let late = (now_wall - deadline).to_std().unwrap_or(Duration::ZERO);
            let Some(timer) = self.timers.get_mut(&id) else {
                continue;
            };
            let Trigger::Cron {
                cron,
                next,
                searched_from,
            } = &mut timer.trigger
            else {
                continue;
            };
            let (missed, rearmed) = rearm_cron(cron, next, &boundary_wall.with_timezone(&self.tz));
            match rearmed {
                Some(n) => {
                    self.by_wall.insert((n.with_timezone(&Utc), id));
                    *next = n;
                    *searched_from = now_wall;
                    searched = true;
                    fired.push((late, id, missed, false));
                }
                None => {
                    self.timers.remove(&id);
                    fired.push((late, id, missed, true));
                }
            }
        }
        if searched {
            self.note_search(now_wall);
        }
        fired.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
        let out = fired
            .iter()
            .map(|&(_, id, missed, last)| {
                self.missed_total = self.missed_total.saturating_add(missed);
                Fired { id, missed, last }
            })
            .collect();
        self.fired = fired;
        self.due_mono = due;
        out
    }

    /// The monotonic time at which the earliest timer is due (possibly already past), or
    /// `None` when no timer is armed. Cron deadlines are converted from wall time at `now_wall`.
    pub fn next_deadline(&self, now_mono: Duration, now_wall: DateTime<Utc>) -> Option<Duration> {
        let mono = self.by_mono.first().map(|(at, _)| *at);
        let wall = self.by_wall.first().map(|(at, _)| {
            let ahead = (*at - now_wall).to_std().unwrap_or(Duration::ZERO);
            now_mono.saturating_add(ahead)
        });
        match (mono, wall) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// The wall clock stepped back: every cron timer searched from a later wall time searches
    /// again from `now_wall`, so wall times that come round again fire again. Costs a pass
    /// over the timers, once per step back. (A search from an earlier time finds at least the
    /// occurrences the last one found; should it fail all the same, the timer keeps its
    /// deadline rather than vanish.)
    fn search_again_after_step_back(&mut self, now_wall: DateTime<Utc>) {
        let from = now_wall.with_timezone(&self.tz);
        for (id, timer) in &mut self.timers {
            let Trigger::Cron {
                cron,
                next,
                searched_from,
            } = &mut timer.trigger
            else {
                continue;
            };
            if now_wall >= *searched_from {
                continue;
            }
            if let Ok(n) = cron.find_next_occurrence(&from, false) {
                self.by_wall.remove(&(next.with_timezone(&Utc), *id));
                self.by_wall.insert((n.with_timezone(&Utc), *id));
                *next = n;
            }
            *searched_from = now_wall;
        }
        // Every cron timer left was searched from `now_wall` or before.
        self.latest_search = Some(now_wall);
    }

    fn note_search(&mut self, wall: DateTime<Utc>) {
        if self.latest_search.map_or(true, |l| wall > l) {
            self.latest_search = Some(wall);
        }
    }

    fn check_room(&self) -> Result<(), ScheduleError> {
        if self.timers.len() >= self.max_timers {
            return Err(ScheduleError::TooManyTimers {
                limit: self.max_timers,
            });
        }
        Ok(())
    }

    fn insert(&mut self, kind: TimerKind, trigger: Trigger<Tz>) -> Result<TimerId, ScheduleError> {
        self.check_room()?;
        let id = TimerId(self.next_id);
        self.next_id = self.next_id.saturating_add(1);
        match trigger.slot() {
            Slot::Mono(at) => self.by_mono.insert((at, id)),
            Slot::Wall(at) => self.by_wall.insert((at, id)),
        };
        self.timers.insert(id, Timer { kind, trigger });
        Ok(id)
    }

    fn unqueue(&mut self, slot: Slot, id: TimerId) {
        match slot {
            Slot::Mono(at) => self.by_mono.remove(&(at, id)),
            Slot::Wall(at) => self.by_wall.remove(&(at, id)),
        };
    }
}

/// Takes the entries of `queue` due at or before `now` into `into`, earliest first (each is
/// put back by its timer once re-armed, so a poll fires a timer at most once).
fn take_due<K: Ord + Copy>(
    queue: &mut BTreeSet<(K, TimerId)>,
    now: K,
    into: &mut Vec<(K, TimerId)>,
) {
    into.clear();
    // One by one, not `split_off`: that allocates a node for what stays every tick.
    let end = (now, TimerId(u64::MAX));
    while let Some(&first) = queue.first() {
        if first >= end {
            break;
        }
        queue.pop_first();
        into.push(first);
    }
}

/// For an `every` timer due at `next` and polled at `now >= next`: how many further deadlines
/// passed unfired up to `now` (a tick's boundary, which may come before `next`), and the first
/// period boundary strictly after `now`.
fn rearm_every(next: Duration, period: Duration, now: Duration) -> (u64, Duration) {
    let period_ns = period.as_nanos().max(1);
    let passed = now.saturating_sub(next).as_nanos() / period_ns + 1;
    let missed = u64::try_from(passed - 1).unwrap_or(u64::MAX);
    let rearmed = passed
        .checked_mul(period_ns)
        .and_then(|step| step.checked_add(next.as_nanos()))
        .and_then(nanos_to_duration)
        // Beyond what a Duration holds: never again, in practice.
        .unwrap_or(Duration::MAX);
    (missed, rearmed)
}

/// For a cron timer due at `next` and polled at `now >= next`: how many further occurrences
/// passed unfired (counted up to `MAX_COUNTED_CRON_MISSES`), and the first occurrence after
/// `now` (`None` when the expression never matches again).
fn rearm_cron<Tz: TimeZone>(
    cron: &Cron,
    next: &DateTime<Tz>,
    now: &DateTime<Tz>,
) -> (u64, Option<DateTime<Tz>>) {
    let mut missed = 0u64;
    let mut cursor = next.clone();
    loop {
        match cron.find_next_occurrence(&cursor, false) {
            Ok(n) if n <= *now && missed < MAX_COUNTED_CRON_MISSES => {
                missed += 1;
                cursor = n;
            }
            Ok(n) if n > *now => return (missed, Some(n)),
            // Too many to count: find the next one from now instead of walking there.
            Ok(_) => return (missed, cron.find_next_occurrence(now, false).ok()),
            Err(_) => return (missed, None),
        }
    }
}

fn nanos_to_duration(nanos: u128) -> Option<Duration> {
    let secs = u64::try_from(nanos / 1_000_000_000).ok()?;
    let sub = u32::try_from(nanos % 1_000_000_000).ok()?;
    Some(Duration::new(secs, sub))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::time::clock::{Clock, VirtualClock};
    use chrono_tz::America::New_York;
    use chrono_tz::Europe::Amsterdam;
    use proptest::prelude::*;

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    fn utc(y: i32, mo: u32, d: u32, h: u32, mi: u32, s: u32) -> DateTime<Utc> {
        Utc.with_ymd_and_hms(y, mo, d, h, mi, s).unwrap()
    }

    /// Local midnight of a day in a zone, as a UTC instant.
    fn midnight<Tz: TimeZone>(tz: &Tz, y: i32, mo: u32, d: u32) -> DateTime<Utc> {
        tz.with_ymd_and_hms(y, mo, d, 0, 0, 0)
            .single()
            .unwrap()
            .with_timezone(&Utc)
    }

    /// Runs the schedule as the scan loop would, sleeping from deadline to deadline, until
    /// monotonic time `until`; gives each firing with the wall time it fired at.
    fn run<Tz: TimeZone>(
        s: &mut Schedule<Tz>,
        clock: &VirtualClock,
        until: Duration,
    ) -> Vec<(DateTime<Utc>, Fired)> {
        let mut out = Vec::new();
        while let Some(deadline) = s.next_deadline(clock.now(), clock.wall()) {
            if deadline > until {
                break;
            }
            clock.advance_to(deadline);
            let fired = s.due(clock.now(), || clock.wall());
            assert!(!fired.is_empty(), "a deadline came and nothing fired");
            out.extend(fired.into_iter().map(|f| (clock.wall(), f)));
        }
        clock.advance_to(until);
        out
    }

    #[test]
    fn deadlines_that_pass_while_a_tick_runs_fall_to_the_catch_up_tick() {
        let mut s = Schedule::with_time_zone(Utc);
        let wall = || utc(2026, 3, 28, 12, 0, 0);
        let id = s.every(ms(20), Duration::ZERO).unwrap();
        let once = |missed| {
            vec![Fired {
                id,
                missed,
                last: false,
            }]
        };
        // The tick of the 20 ms boundary reaches the timers at 65 ms (it ran long first).
        assert_eq!(s.due_at_tick(ms(65), ms(20), wall), once(0));
        // The catch-up tick on the last boundary passed (60 ms), at 66 ms: the deadlines of
        // 40 and 60 ms passed meanwhile, so the timer fires once more, with one missed.
        assert_eq!(s.due_at_tick(ms(66), ms(60), wall), once(1));
        // And in the next tick, on time.
        assert_eq!(s.due_at_tick(ms(80), ms(80), wall), once(0));
        // `due` is a tick on time.
        assert_eq!(s.due(ms(100), wall), once(0));
    }

    fn local_times<Tz: TimeZone>(tz: &Tz, fired: &[(DateTime<Utc>, Fired)]) -> Vec<String>
    where
        Tz::Offset: fmt::Display,
    {
        fired
            .iter()
            .map(|(t, _)| t.with_timezone(tz).to_rfc3339())
            .collect()
    }

    #[test]
    fn every_fires_each_period_from_creation() {
        let clock = VirtualClock::at_epoch();
        let mut s = Schedule::with_time_zone(Utc);
        clock.advance(ms(5));
        let id = s.every(ms(20), clock.now()).unwrap();
        assert_eq!(s.next_deadline(clock.now(), clock.wall()), Some(ms(25)));
        assert!(s.due(ms(24), || clock.wall()).is_empty());
        assert_eq!(
            s.due(ms(25), || clock.wall()),
            vec![Fired {
                id,
                missed: 0,
                last: false
            }]
        );
        assert!(
            s.due(ms(25), || clock.wall()).is_empty(),
            "once per deadline"
        );
        assert_eq!(s.next_deadline(ms(25), clock.wall()), Some(ms(45)));
        let fired = run(&mut s, &clock, ms(1005));
        assert_eq!(fired.len(), 49, "45, 65, .. 985, 1005");
        assert!(fired.iter().all(|(_, f)| f.id == id && f.missed == 0));
        assert_eq!(s.missed_total(), 0);
    }

    #[test]
    fn a_late_every_fires_once_counts_the_skipped_and_keeps_its_phase() {
        let mut s = Schedule::with_time_zone(Utc);
        let wall = utc(2024, 1, 1, 0, 0, 0);
        let id = s.every(ms(20), Duration::ZERO).unwrap();
        // Due at 20; the tick comes at 95: deadlines 20, 40, 60, 80 have passed.
        assert_eq!(
            s.due(ms(95), || wall),
            vec![Fired {
                id,
                missed: 3,
                last: false
            }]
        );
        assert_eq!(
            s.next_deadline(ms(95), wall),
            Some(ms(100)),
            "next boundary, same phase"
        );
        assert_eq!(s.missed_total(), 3);
        // Exactly on a boundary: that boundary is the one that fires.
        assert_eq!(
            s.due(ms(140), || wall),
            vec![Fired {
                id,
                missed: 2,
                last: false
            }]
        );
        assert_eq!(s.next_deadline(ms(140), wall), Some(ms(160)));
        assert_eq!(s.missed_total(), 5);
    }

    #[test]
    fn every_needs_a_period() {
        let mut s = Schedule::with_time_zone(Utc);
        assert_eq!(
            s.every(Duration::ZERO, ms(1)),
            Err(ScheduleError::ZeroPeriod)
        );
        assert!(s.is_empty());
    }

    #[test]
    fn every_near_the_end_of_time_does_not_overflow() {
        let mut s = Schedule::with_time_zone(Utc);
        let wall = utc(2024, 1, 1, 0, 0, 0);
        let id = s.every(Duration::MAX, Duration::ZERO).unwrap();
        assert_eq!(s.next_deadline(Duration::ZERO, wall), Some(Duration::MAX));
        assert_eq!(
            s.due(Duration::MAX, || wall),
            vec![Fired {
                id,
                missed: 0,
                last: false
            }]
        );
        assert_eq!(s.next_deadline(Duration::MAX, wall), Some(Duration::MAX));
    }

    #[test]
    fn after_fires_once_then_is_gone() {
        let clock = VirtualClock::at_epoch();
        let mut s = Schedule::with_time_zone(Utc);
        let id = s.after(ms(1500), clock.now()).unwrap();
        assert_eq!(s.kind(id), Some(&TimerKind::After(ms(1500))));
        let fired = run(&mut s, &clock, Duration::from_secs(10));
        assert_eq!(fired.len(), 1);
        assert_eq!(
            fired[0].1,
            Fired {
                id,
                missed: 0,
                last: true
            }
        );
        assert_eq!(fired[0].0.timestamp_millis(), 1500);
        assert!(!s.contains(id));
        assert!(!s.cancel(id), "a spent after cannot be cancelled");
        assert_eq!(s.next_deadline(clock.now(), clock.wall()), None);
    }

    #[test]
    fn after_zero_fires_at_the_next_tick() {
        let mut s = Schedule::with_time_zone(Utc);
        let wall = utc(2024, 1, 1, 0, 0, 0);
        let id = s.after(Duration::ZERO, ms(7)).unwrap();
        assert_eq!(
            s.due(ms(7), || wall),
            vec![Fired {
                id,
                missed: 0,
                last: true
            }]
        );
    }

    #[test]
    fn cancel_stops_any_kind_of_timer() {
        let clock = VirtualClock::new(utc(2024, 1, 1, 0, 0, 0));
        let mut s = Schedule::with_time_zone(Utc);
        let every = s.every(ms(100), clock.now()).unwrap();
        let after = s.after(ms(250), clock.now()).unwrap();
        let cron = s.cron("* * * * * *", clock.wall()).unwrap();
        let kept = s.every(ms(1000), clock.now()).unwrap();
        assert_eq!(s.len(), 4);
        assert!(s.cancel(every));
        assert!(s.cancel(after));
        assert!(s.cancel(cron));
        assert!(!s.cancel(cron), "twice");
        assert!(!s.cancel(TimerId(999)), "never made");
        let fired = run(&mut s, &clock, Duration::from_secs(5));
        assert_eq!(fired.len(), 5);
        assert!(fired.iter().all(|(_, f)| f.id == kept));
    }

    #[test]
    fn due_timers_come_in_deadline_order_not_creation_order() {
        let mut s = Schedule::with_time_zone(Utc);
        let wall = utc(2024, 1, 1, 0, 0, 0);
        let late = s.after(ms(30), Duration::ZERO).unwrap();
        let early = s.after(ms(10), Duration::ZERO).unwrap();
        let every = s.every(ms(20), Duration::ZERO).unwrap();
        let tie = s.after(ms(20), Duration::ZERO).unwrap();
        let ids: Vec<TimerId> = s.due(ms(35), || wall).into_iter().map(|f| f.id).collect();
        assert_eq!(ids, vec![early, every, tie, late]);
    }

    #[test]
    fn ids_are_never_reused() {
        let mut s = Schedule::with_time_zone(Utc);
        let a = s.after(ms(1), Duration::ZERO).unwrap();
        assert!(s.cancel(a));
        let b = s.after(ms(1), Duration::ZERO).unwrap();
        assert_ne!(a, b);
        assert!(b > a);
    }

    #[test]
    fn cron_every_five_minutes_over_an_hour() {
        let start = utc(2024, 6, 1, 10, 0, 0);
        let clock = VirtualClock::new(start);
        let mut s = Schedule::with_time_zone(Utc);
        let id = s.cron("*/5 * * * *", clock.wall()).unwrap();
        assert_eq!(s.kind(id), Some(&TimerKind::Cron("*/5 * * * *".into())));
        assert_eq!(
            s.next_deadline(clock.now(), clock.wall()),
            Some(Duration::from_secs(300)),
            "wall deadline as monotonic time"
        );
        let fired = run(&mut s, &clock, Duration::from_secs(3600));
        let minutes: Vec<u32> = fired
            .iter()
            .map(|(t, _)| chrono::Timelike::minute(t))
            .collect();
        assert_eq!(minutes, vec![5, 10, 15, 20, 25, 30, 35, 40, 45, 50, 55, 0]);
        assert!(fired
            .iter()
            .all(|(t, f)| f.id == id && f.missed == 0 && chrono::Timelike::second(t) == 0));
        assert_eq!(fired.last().unwrap().0, utc(2024, 6, 1, 11, 0, 0));
    }

    #[test]
    fn cron_from_a_fraction_of_a_second_fires_on_the_next_whole_match() {
        let mut s = Schedule::with_time_zone(Utc);
        let at = utc(2024, 6, 1, 10, 0, 4) + chrono::Duration::milliseconds(700);
        let id = s.cron("*/5 * * * * *", at).unwrap();
        assert_eq!(s.next_deadline(Duration::ZERO, at), Some(ms(300)));
        // Exactly at an occurrence when made: that one is not "after now", the next is.
        let at = utc(2024, 6, 1, 10, 0, 5);
        let other = s.cron("*/5 * * * * *", at).unwrap();
        assert_eq!(
            s.due(Duration::ZERO, || at),
            vec![Fired {
                id,
                missed: 0,
                last: false
            }]
        );
        assert!(s.due(Duration::ZERO, || at).is_empty());
        assert_eq!(
            s.due(ms(5000), || at + chrono::Duration::seconds(5)),
            vec![
                Fired {
                    id,
                    missed: 0,
                    last: false
                },
                Fired {
                    id: other,
                    missed: 0,
                    last: false
                }
            ]
        );
    }

    #[test]
    fn daily_cron_across_spring_forward_in_amsterdam() {
        // 2024-03-31: 02:00 CET jumps to 03:00 CEST; 02:30 does not exist that day.
        let start = midnight(&Amsterdam, 2024, 3, 29);
        let clock = VirtualClock::new(start);
        let mut s = Schedule::with_time_zone(Amsterdam);
        s.cron("0 30 2 * * *", clock.wall()).unwrap();
        s.cron("0 0 9 * * *", clock.wall()).unwrap();
        let fired = run(&mut s, &clock, Duration::from_secs(4 * 86_400));
        assert_eq!(
            local_times(&Amsterdam, &fired),
            vec![
                "2024-03-29T02:30:00+01:00",
                "2024-03-29T09:00:00+01:00",
                "2024-03-30T02:30:00+01:00",
                "2024-03-30T09:00:00+01:00",
                // In the gap: once, at the first valid time after it — not skipped, not twice.
                "2024-03-31T03:00:00+02:00",
                "2024-03-31T09:00:00+02:00",
                "2024-04-01T02:30:00+02:00",
                "2024-04-01T09:00:00+02:00",
            ]
        );
        // The 09:00 job keeps local time: 23 real hours between the two around the change.
        let nine: Vec<_> = fired.iter().skip(1).step_by(2).map(|(t, _)| *t).collect();
        assert_eq!((nine[2] - nine[1]).num_hours(), 23);
        assert_eq!((nine[3] - nine[2]).num_hours(), 24);
    }

    #[test]
    fn daily_cron_across_fall_back_in_amsterdam() {
        // 2024-10-27: 03:00 CEST falls back to 02:00 CET; 02:30 happens twice that day.
        let start = midnight(&Amsterdam, 2024, 10, 25);
        let clock = VirtualClock::new(start);
        let mut s = Schedule::with_time_zone(Amsterdam);
        s.cron("0 30 2 * * *", clock.wall()).unwrap();
        s.cron("0 0 9 * * *", clock.wall()).unwrap();
        let fired = run(&mut s, &clock, Duration::from_secs(4 * 86_400));
        assert_eq!(
            local_times(&Amsterdam, &fired),
            vec![
                "2024-10-25T02:30:00+02:00",
                "2024-10-25T09:00:00+02:00",
                "2024-10-26T02:30:00+02:00",
                "2024-10-26T09:00:00+02:00",
                // The repeated hour: once, on its first pass.
                "2024-10-27T02:30:00+02:00",
                "2024-10-27T09:00:00+01:00",
                "2024-10-28T02:30:00+01:00",
                "2024-10-28T09:00:00+01:00",
            ]
        );
        let nine: Vec<_> = fired.iter().skip(1).step_by(2).map(|(t, _)| *t).collect();
        assert_eq!((nine[2] - nine[1]).num_hours(), 25);
        assert!(fired.iter().all(|(_, f)| f.missed == 0));
    }

    #[test]
    fn step_and_wildcard_crons_follow_real_time_over_dst_days() {
        for (day, hours) in [
            ((2024, 3, 31), 23),
            ((2024, 10, 27), 25),
            ((2024, 6, 1), 24),
        ] {
            let start = midnight(&Amsterdam, day.0, day.1, day.2);
            let clock = VirtualClock::new(start);
            let mut s = Schedule::with_time_zone(Amsterdam);
            let quarter = s.cron("0 */15 * * * *", clock.wall()).unwrap();
            let hourly = s.cron("0 0 * * * *", clock.wall()).unwrap();
            let fired = run(&mut s, &clock, Duration::from_secs(hours * 3600));
            let count = |id| fired.iter().filter(|(_, f)| f.id == id).count() as u64;
            assert_eq!(count(quarter), hours * 4, "{day:?}");
            assert_eq!(count(hourly), hours, "{day:?}");
            // Real time only moves forward, 15 minutes at a time.
            let q: Vec<_> = fired
                .iter()
                .filter(|(_, f)| f.id == quarter)
                .map(|(t, _)| *t)
                .collect();
            assert!(q
                .windows(2)
                .all(|w| w[1] - w[0] == chrono::Duration::minutes(15)));
        }
    }

    #[test]
    fn a_fixed_minute_of_every_hour_follows_the_hours_that_exist() {
        // The hour field is a wildcard, so 02:30 is simply absent on the short day (not moved
        // to 03:00 as a fixed-time job is) and happens on both passes on the long day.
        for (day, hours) in [((2024, 3, 31), 23usize), ((2024, 10, 27), 25)] {
            let clock = VirtualClock::new(midnight(&Amsterdam, day.0, day.1, day.2));
            let mut s = Schedule::with_time_zone(Amsterdam);
            s.cron("30 * * * *", clock.wall()).unwrap();
            let fired = run(&mut s, &clock, Duration::from_secs(hours as u64 * 3600));
            assert_eq!(fired.len(), hours, "{day:?}");
            let at_0230 = local_times(&Amsterdam, &fired)
                .into_iter()
                .filter(|t| t.contains("T02:30:00"))
                .count();
            assert_eq!(at_0230, hours - 23, "{day:?}");
        }
    }

    #[test]
    fn new_york_fixed_times_in_the_gap_and_the_repeat() {
        // 2024-03-10 02:00 EST -> 03:00 EDT; 2024-11-03 02:00 EDT -> 01:00 EST.
        let clock = VirtualClock::new(midnight(&New_York, 2024, 3, 9));
        let mut s = Schedule::with_time_zone(New_York);
        s.cron("30 2 * * *", clock.wall()).unwrap();
        let fired = run(&mut s, &clock, Duration::from_secs(3 * 86_400));
        assert_eq!(
            local_times(&New_York, &fired),
            vec![
                "2024-03-09T02:30:00-05:00",
                "2024-03-10T03:00:00-04:00",
                "2024-03-11T02:30:00-04:00",
            ]
        );
        let clock = VirtualClock::new(midnight(&New_York, 2024, 11, 2));
        let mut s = Schedule::with_time_zone(New_York);
        s.cron("30 1 * * *", clock.wall()).unwrap();
        let fired = run(&mut s, &clock, Duration::from_secs(3 * 86_400));
        assert_eq!(
            local_times(&New_York, &fired),
            vec![
                "2024-11-02T01:30:00-04:00",
                "2024-11-03T01:30:00-04:00",
                "2024-11-04T01:30:00-05:00",
            ]
        );
    }

    #[test]
    fn a_day_of_every_five_seconds_in_virtual_time() {
        let clock = VirtualClock::new(utc(2024, 6, 1, 0, 0, 0));
        let mut s = Schedule::with_time_zone(Utc);
        let id = s.cron("*/5 * * * * *", clock.wall()).unwrap();
        let fired = run(&mut s, &clock, Duration::from_secs(86_400));
        assert_eq!(fired.len(), 17_280);
        assert!(fired.iter().all(|(_, f)| f.id == id && f.missed == 0));
        assert_eq!(fired.last().unwrap().0, utc(2024, 6, 2, 0, 0, 0));
        // The 25-hour day in Amsterdam has 25 hours of them.
        let clock = VirtualClock::new(midnight(&Amsterdam, 2024, 10, 27));
        let mut s = Schedule::with_time_zone(Amsterdam);
        s.cron("*/5 * * * * *", clock.wall()).unwrap();
        assert_eq!(
            run(&mut s, &clock, Duration::from_secs(25 * 3600)).len(),
            18_000
        );
    }

    #[test]
    fn a_wall_clock_jump_fires_cron_once_and_counts_the_skipped() {
        let t0 = utc(2024, 6, 1, 10, 0, 0);
        let mut s = Schedule::with_time_zone(Utc);
        let id = s.cron("*/5 * * * *", t0).unwrap();
        // The machine slept from 10:00 to 10:31:30: 10:05 .. 10:30 passed (6 occurrences).
        let woke = utc(2024, 6, 1, 10, 31, 30);
        assert_eq!(
            s.due(ms(1), || woke),
            vec![Fired {
                id,
                missed: 5,
                last: false
            }]
        );
        assert_eq!(s.missed_total(), 5);
        assert_eq!(
            s.next_deadline(ms(1), woke),
            Some(ms(1) + Duration::from_secs(210))
        );
    }

    #[test]
    fn a_huge_wall_clock_jump_counts_up_to_the_cap() {
        let t0 = utc(2024, 6, 1, 0, 0, 0);
        let mut s = Schedule::with_time_zone(Utc);
        let id = s.cron("* * * * * *", t0).unwrap();
        let woke = utc(2024, 6, 2, 0, 0, 0) + chrono::Duration::milliseconds(500);
        assert_eq!(
            s.due(Duration::ZERO, || woke),
            vec![Fired {
                id,
                missed: MAX_COUNTED_CRON_MISSES,
                last: false
            }]
        );
        assert_eq!(s.next_deadline(Duration::ZERO, woke), Some(ms(500)));
    }

    #[test]
    fn a_wall_clock_step_back_rearms_cron_from_the_new_time() {
        let t0 = utc(2024, 6, 1, 10, 0, 0);
        let mut s = Schedule::with_time_zone(Utc);
        let id = s.cron("0 * * * *", t0).unwrap();
        assert_eq!(
            s.due(ms(1), || utc(2024, 6, 1, 11, 0, 0)),
            vec![Fired {
                id,
                missed: 0,
                last: false
            }]
        );
        // Stepped back to 09:30: 10:00 comes round again and fires again, not 12:00.
        let back = utc(2024, 6, 1, 9, 30, 0);
        assert!(s.due(ms(2), || back).is_empty());
        assert_eq!(
            s.next_deadline(ms(2), back),
            Some(ms(2) + Duration::from_secs(1800))
        );
        assert_eq!(
            s.due(ms(3), || utc(2024, 6, 1, 10, 0, 0)),
            vec![Fired {
                id,
                missed: 0,
                last: false
            }]
        );
    }

    #[test]
    fn a_cron_that_stops_matching_ends_after_its_last_time() {
        let clock = VirtualClock::new(utc(2029, 12, 31, 0, 0, 0));
        let mut s = Schedule::with_time_zone(Utc);
        let id = s.cron("0 0 12 1 1 * 2030", clock.wall()).unwrap();
        let fired = run(&mut s, &clock, Duration::from_secs(400 * 86_400));
        assert_eq!(fired.len(), 1);
        assert_eq!(fired[0].0, utc(2030, 1, 1, 12, 0, 0));
        assert!(fired[0].1.last, "the firing says it was the last");
        assert!(!s.contains(id));
        assert!(s.is_empty());
    }

    #[test]
    fn timers_past_the_limit_are_refused_until_one_goes() {
        let wall = utc(2024, 1, 1, 0, 0, 0);
        let mut s = Schedule::with_time_zone(Utc);
        assert_eq!(s.max_timers(), DEFAULT_MAX_TIMERS);
        s.set_max_timers(3);
        let every = s.every(ms(10), Duration::ZERO).unwrap();
        s.after(ms(10), Duration::ZERO).unwrap();
        s.cron("* * * * * *", wall).unwrap();
        let full = ScheduleError::TooManyTimers { limit: 3 };
        assert_eq!(s.every(ms(10), Duration::ZERO), Err(full.clone()));
        assert_eq!(s.after(ms(10), Duration::ZERO), Err(full.clone()));
        assert_eq!(s.cron("* * * * * *", wall), Err(full.clone()));
        assert_eq!(s.len(), 3);
        let text = full.to_string();
        assert!(
            text.contains("3 are armed") && text.contains("--max-timers"),
            "{text}"
        );
        // A cancelled timer or a spent `after` makes room.
        assert!(s.cancel(every));
        s.every(ms(10), Duration::ZERO).unwrap();
        assert_eq!(s.due(ms(10), || wall).len(), 2);
        s.after(ms(10), ms(10)).unwrap();
        // Clearing forgets the timers, not the limit, and ids go on.
        s.clear();
        assert!(s.is_empty());
        assert_eq!(s.next_deadline(ms(10), wall), None);
        assert_eq!(s.max_timers(), 3);
        let fresh = s.after(ms(1), ms(10)).unwrap();
        assert!(fresh > every);
    }

    #[test]
    fn polls_cost_the_due_timers_not_all_timers() {
        // 100,000 timers of which one fires per poll: each poll is a handful of queue
        // operations (the old linear scan touched every timer; this would take minutes).
        let wall = utc(2024, 1, 1, 0, 0, 0);
        let mut s = Schedule::with_time_zone(Utc);
        s.set_max_timers(200_000);
        for i in 0..100_000u64 {
            s.after(ms(1 + i), Duration::ZERO).unwrap();
        }
        for i in 1..=100_000u64 {
            let fired = s.due(ms(i), || wall);
            assert_eq!(fired.len(), 1);
            assert!(fired[0].last);
        }
        assert!(s.is_empty());
    }

    #[test]
    fn bad_and_impossible_cron_expressions_are_refused() {
        let now = utc(2024, 6, 1, 0, 0, 0);
        let mut s = Schedule::with_time_zone(Utc);
        for bad in [
            "",
            "* * *",
            "61 * * * *",
            "*/0 * * * *",
            "5/5 * * * *",
            "every day",
        ] {
            match s.cron(bad, now) {
                Err(ScheduleError::BadCron { expr, reason }) => {
                    assert_eq!(expr, bad);
                    assert!(!reason.is_empty());
                }
                other => panic!("{bad:?}: {other:?}"),
            }
            assert!(validate_cron(bad).is_err());
        }
        assert_eq!(
            s.cron("0 0 30 2 *", now),
            Err(ScheduleError::NeverFires {
                expr: "0 0 30 2 *".into()
            })
        );
        assert!(s.is_empty());
        let shown = s.cron("61 * * * *", now).unwrap_err().to_string();
        assert!(
            shown.starts_with("\"61 * * * *\" is not a cron expression: "),
            "{shown}"
        );
        assert!(validate_cron("*/5 * * * * *").is_ok());
        assert!(validate_cron("@hourly").is_ok());
    }

    #[test]
    fn the_default_schedule_uses_local_time() {
        let mut s = Schedule::new();
        let now = Utc::now();
        let id = s.cron("0 0 * * * *", now).unwrap();
        let ahead = s.next_deadline(Duration::ZERO, now).unwrap();
        assert!(ahead <= Duration::from_secs(3600));
        assert!(s.contains(id));
        assert!(format!("{s:?}").contains("Cron(\"0 0 * * * *\")"));
    }

    proptest! {
        #[test]
        fn random_cron_text_never_panics(expr in any::<String>()) {
            let mut s = Schedule::with_time_zone(Utc);
            let _ = s.cron(&expr, utc(2024, 6, 1, 0, 0, 0));
        }

        #[test]
        fn cron_like_text_never_panics(expr in "[0-9*/,LW#?+ -]{0,30}") {
            let _ = validate_cron(&expr);
        }

        #[test]
        fn the_queues_fire_what_a_scan_of_every_timer_would(
            timers in proptest::collection::vec((any::<bool>(), 1u64..200), 1..40),
            cancels in proptest::collection::vec(any::<prop::sample::Index>(), 0..10),
            polls in proptest::collection::vec(0u64..150, 1..30),
        ) {
            // The model: each timer's deadline, scanned in full at every poll.
            let wall = utc(2024, 1, 1, 0, 0, 0);
            let mut s = Schedule::with_time_zone(Utc);
            let mut model: Vec<(TimerId, bool, u64, u64)> = Vec::new(); // id, repeats, period, next
            for (repeats, period) in &timers {
                let id = if *repeats {
                    s.every(ms(*period), Duration::ZERO).unwrap()
                } else {
                    s.after(ms(*period), Duration::ZERO).unwrap()
                };
                model.push((id, *repeats, *period, *period));
            }
            for c in cancels {
                let i = c.index(model.len());
                let id = model[i].0;
                prop_assert_eq!(s.cancel(id), model.iter().any(|m| m.0 == id && m.3 != u64::MAX));
                model[i].3 = u64::MAX;
            }
            let mut now = 0u64;
            for step in polls {
                now += step;
                let mut expected: Vec<(u64, TimerId, u64, bool)> = Vec::new();
                for m in &mut model {
                    if m.3 == u64::MAX || m.3 > now {
                        continue;
                    }
                    let late = now - m.3;
                    if m.1 {
                        let missed = late / m.2;
                        expected.push((late, m.0, missed, false));
                        m.3 += (missed + 1) * m.2;
                    } else {
                        expected.push((late, m.0, 0, true));
                        m.3 = u64::MAX;
                    }
                }
                expected.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
                let expected: Vec<Fired> = expected
                    .into_iter()
                    .map(|(_, id, missed, last)| Fired { id, missed, last })
                    .collect();
                prop_assert_eq!(s.due(ms(now), || wall), expected);
                let next = model.iter().map(|m| m.3).filter(|n| *n != u64::MAX).min();
                prop_assert_eq!(s.next_deadline(ms(now), wall), next.map(ms));
                prop_assert_eq!(s.len(), model.iter().filter(|m| m.3 != u64::MAX).count());
            }
        }

        #[test]
        fn every_fires_once_per_poll_and_counts_the_rest(
            period_ms in 1u64..1000,
            polls in proptest::collection::vec(0u64..5000, 1..20),
        ) {
            let wall = utc(2024, 1, 1, 0, 0, 0);
            let mut s = Schedule::with_time_zone(Utc);
            let id = s.every(ms(period_ms), Duration::ZERO).unwrap();
            let mut now = Duration::ZERO;
            let mut fired_plus_missed = 0u64;
            for step in polls {
                now += ms(step);
                for f in s.due(now, || wall) {
                    prop_assert_eq!(f.id, id);
                    fired_plus_missed += 1 + f.missed;
                }
                let next = s.next_deadline(now, wall).unwrap();
                prop_assert!(next > now && next <= now + ms(period_ms));
                prop_assert_eq!(next.as_millis() % u128::from(period_ms), 0);
            }
            // Every deadline up to now was either fired or counted as missed, exactly once.
            prop_assert_eq!(fired_plus_missed, now.as_millis() as u64 / period_ms);
        }
    }
}
