//! The script's handlers and what each waits for (device events, counter thresholds, timers,
//! the end of the run), with the ids `cancel` takes.
//!
//! Timer handlers are kept by their timer, so a firing finds its handler in O(1) and a tick
//! costs the timers that fire, not the timers there are (a script may arm tens of thousands).
//! Device-event and `on_stop` handlers are kept in the order they were added.

use super::schedule::{Schedule, ScheduleError, TimerId, TimerKind};
use crate::protocol::trc1000::{Rotary, Switch};
use crate::time::duration::format_duration;
use crate::time::zone::Zone;
use chrono::{DateTime, Utc};
use std::collections::{BTreeMap, HashMap};
use std::rc::Rc;
use std::time::Duration;

/// What a handler is subscribed to.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Source {
    /// A TRC1000 switch going down.
    Press {
        /// Device index.
        dev: usize,
        /// Which switch.
        switch: Switch,
    },
    /// A TRC1000 switch coming up.
    Release {
        /// Device index.
        dev: usize,
        /// Which switch.
        switch: Switch,
    },
    /// A TRC1000 rotary moving.
    Turn {
        /// Device index.
        dev: usize,
        /// Which rotary.
        rotary: Rotary,
    },
    /// A TRP-C29U input becoming energized.
    Rise {
        /// Device index.
        dev: usize,
        /// Channel 0-7.
        ch: u8,
    },
    /// A TRP-C29U input being released.
    Fall {
        /// Device index.
        dev: usize,
        /// Channel 0-7.
        ch: u8,
    },
    /// A TRP-C29U counter reaching a threshold.
    Counter {
        /// Device index.
        dev: usize,
        /// Channel 0-7.
        ch: u8,
        /// The count that fires the handler.
        threshold: u16,
        /// Fires when the count is at or above the threshold; re-armed when a reading (this
        /// one or the one before, which after the script's own clear is the cleared count)
        /// shows it below, or the count went down (cleared, reset, wrapped).
        armed: bool,
    },
    /// A timer of the schedule.
    Timer(TimerId),
    /// The end of the run.
    Stop,
    /// An inbound command of this name (`on_command`, `runtime::remote`).
    Command(String),
    /// A message on a topic matching this filter (`on_message`).
    Message(String),
}

/// A handler and what it waits for.
#[derive(Debug, Clone)]
pub struct Registration<H> {
    /// Returned to the script, for `cancel`.
    pub id: u64,
    /// What it waits for.
    pub source: Source,
    /// The script's function.
    pub handler: H,
    /// The handler in words for the log and error messages: `panel.on_press S1` (shared with
    /// each call: a timer's every few milliseconds).
    pub label: Rc<str>,
    /// What a timer's firings have been since its last log line.
    pub(super) firings: Firings,
}

/// A timer's firings as the log tells them: the first one, then a summary at most every
/// `TIMER_LOG_INTERVAL`.
#[derive(Debug, Clone, Default)]
pub(super) struct Firings {
    /// When its last line was logged (`None` before the first firing).
    pub(super) logged_at: Option<Duration>,
    /// Firings since that line.
    pub(super) count: u64,
    /// Deadlines missed since that line.
    pub(super) missed: u64,
    /// A cron timer (its last firing is told: no later time matched).
    pub(super) cron: bool,
}

/// A value passed to a handler.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Arg {
    /// A number.
    Int(i64),
    /// A name.
    Str(String),
    /// A value given as JSON text (an inbound command's payload); text that is not JSON is
    /// passed as a string.
    Json(String),
}

/// A handler to run now, with its arguments.
#[derive(Debug, Clone)]
pub struct Call<H> {
    /// The script's function.
    pub handler: H,
    /// Its arguments (the script layer passes as many as the function takes).
    pub args: Vec<Arg>,
    /// The handler in words.
    pub label: Rc<str>,
}

impl<H: Clone> Registration<H> {
    /// A call of this handler with `args`.
    pub fn call(&self, args: Vec<Arg>) -> Call<H> {
        Call {
            handler: self.handler.clone(),
            args,
            label: Rc::clone(&self.label),
        }
    }
}

/// Every handler of the script, and the schedule of its timers.
pub struct Handlers<H> {
    /// Device-event handlers, in the order they were added.
    pub(super) events: Vec<Registration<H>>,
    /// `on_stop` handlers, in the order they were added.
    stops: Vec<Registration<H>>,
    /// `on_command` and `on_message` handlers, in the order they were added.
    remote: Vec<Registration<H>>,
    /// Timer handlers, by their timer.
    pub(super) timers: HashMap<TimerId, Registration<H>>,
    /// The timer of each timer handler, by handler id (for `cancel`).
    timer_of: HashMap<u64, TimerId>,
    /// How many `every` timers there are of each period (the fastest sets the tick).
    every_periods: BTreeMap<Duration, usize>,
    next_id: u64,
    /// The timers of `Source::Timer` handlers.
    pub(super) schedule: Schedule<Zone>,
}

impl<H: Clone> Handlers<H> {
    /// No handlers; timers keep time in `zone`.
    pub fn new(zone: Zone) -> Self {
        Self {
            events: Vec::new(),
            stops: Vec::new(),
            remote: Vec::new(),
            timers: HashMap::new(),
            timer_of: HashMap::new(),
            every_periods: BTreeMap::new(),
            next_id: 1,
            schedule: Schedule::with_time_zone(zone),
        }
    }

    /// How many timers may be armed at once (`timers` under `[limits]`); arming one more is
    /// a script error.
    pub fn set_max_timers(&mut self, max: usize) {
        self.schedule.set_max_timers(max);
    }

    /// Adds a handler; returns its id.
    pub fn add(&mut self, source: Source, handler: H, label: String) -> u64 {
        let id = self.next_id;
        self.next_id = self.next_id.saturating_add(1);
        let sub = Registration {
            id,
            source,
            handler,
            label: Rc::from(label),
            firings: Firings::default(),
        };
        match sub.source {
            Source::Timer(t) => {
                self.timer_of.insert(id, t);
                self.timers.insert(t, sub);
            }
            Source::Stop => self.stops.push(sub),
            Source::Command(_) | Source::Message(_) => self.remote.push(sub),
            _ => self.events.push(sub),
        }
        id
    }

    /// `every(period, fn)`, counted from monotonic `now`.
    pub fn every(
        &mut self,
        period: Duration,
        now: Duration,
        handler: H,
    ) -> Result<u64, ScheduleError> {
        let id = self.schedule.every(period, now)?;
        let label = format!("every {}", format_duration(period));
        *self.every_periods.entry(period).or_default() += 1;
        Ok(self.add(Source::Timer(id), handler, label))
    }

    /// `after(delay, fn)`, counted from monotonic `now`.
    pub fn after(
        &mut self,
        delay: Duration,
        now: Duration,
        handler: H,
    ) -> Result<u64, ScheduleError> {
        let id = self.schedule.after(delay, now)?;
        let label = format!("after {}", format_duration(delay));
        Ok(self.add(Source::Timer(id), handler, label))
    }

    /// `cron(expr, fn)`, next firing after wall time `wall`.
    pub fn cron(
        &mut self,
        expr: &str,
        wall: DateTime<Utc>,
        handler: H,
    ) -> Result<u64, ScheduleError> {
        let id = self.schedule.cron(expr, wall)?;
        let label = format!("cron {expr:?}");
        let sub = self.add(Source::Timer(id), handler, label);
        if let Some(s) = self.timers.get_mut(&id) {
            s.firings.cron = true;
        }
        Ok(sub)
    }

    /// Removes a handler or timer; false if there is none with that id.
    pub fn cancel(&mut self, id: u64) -> bool {
        if let Some(t) = self.timer_of.remove(&id) {
            if let Some(TimerKind::Every(period)) = self.schedule.kind(t) {
                let period = *period;
                if let Some(n) = self.every_periods.get_mut(&period) {
                    *n -= 1;
                    if *n == 0 {
                        self.every_periods.remove(&period);
                    }
                }
            }
            self.timers.remove(&t);
            self.schedule.cancel(t);
            return true;
        }
        for list in [&mut self.events, &mut self.stops, &mut self.remote] {
            if let Some(pos) = list.iter().position(|s| s.id == id) {
                list.remove(pos);
                return true;
            }
        }
        false
    }

    /// The handler of a timer that fired for the last time: it goes with its timer.
    pub(super) fn remove_timer(&mut self, t: TimerId) -> Option<Registration<H>> {
        let sub = self.timers.remove(&t)?;
        self.timer_of.remove(&sub.id);
        Some(sub)
    }

    /// Forgets every handler and timer (ids go on counting, so an old id cancels nothing;
    /// the limit on timers stays).
    pub fn clear(&mut self) {
        self.events.clear();
        self.stops.clear();
        self.timers.clear();
        self.timer_of.clear();
        self.every_periods.clear();
        self.schedule.clear();
    }

    /// Takes every handler and timer out, leaving none, with ids going on (a reload keeps the
    /// old script's aside until the new one has started).
    pub fn take(&mut self) -> Self {
        let schedule = self.schedule.take();
        Self {
            events: std::mem::take(&mut self.events),
            stops: std::mem::take(&mut self.stops),
            remote: std::mem::take(&mut self.remote),
            timers: std::mem::take(&mut self.timers),
            timer_of: std::mem::take(&mut self.timer_of),
            every_periods: std::mem::take(&mut self.every_periods),
            next_id: self.next_id,
            schedule,
        }
    }

    /// Puts back what `take` took (the new script failed to start), ids going on.
    pub fn put_back(&mut self, mut old: Self) {
        old.next_id = old.next_id.max(self.next_id);
        *self = old;
    }

    /// The period of the fastest `every` timer, if there is one.
    pub fn fastest_every(&self) -> Option<Duration> {
        self.every_periods.keys().next().copied()
    }

    /// Something that changes when handlers come or go: their count and the next id.
    pub fn signature(&self) -> (usize, u64) {
        (self.len(), self.next_id)
    }

    /// Whether the script still waits for anything (handlers other than `on_stop`, timers).
    pub fn has_work(&self) -> bool {
        !self.events.is_empty() || !self.timers.is_empty() || !self.remote.is_empty()
    }

    /// The `on_command` or `on_message` handlers waiting for `source`'s kind: a command's of
    /// that name (the last one added), a message's whose filter matches (every one).
    pub fn remote_calls(&self, matches: impl Fn(&Source) -> bool) -> Vec<&Registration<H>> {
        self.remote.iter().filter(|s| matches(&s.source)).collect()
    }

    /// Whether some handler waits for device inputs (then every tick polls them).
    pub fn polls_inputs(&self) -> bool {
        !self.events.is_empty()
    }

    /// How many handlers there are, of every kind.
    pub fn len(&self) -> usize {
        self.events.len() + self.stops.len() + self.timers.len()
    }

    /// Whether there are no handlers at all.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Every handler in the order it was added, for inspection (sorts the timers: not for
    /// every tick).
    pub fn list(&self) -> Vec<&Registration<H>> {
        let mut all: Vec<&Registration<H>> = self
            .events
            .iter()
            .chain(&self.stops)
            .chain(self.timers.values())
            .collect();
        all.sort_by_key(|s| s.id);
        all
    }

    /// How many `on_stop` handlers there are.
    pub fn stop_count(&self) -> usize {
        self.stops.len()
    }

    /// The `on_stop` handlers, in the order they were added.
    pub fn stop_calls(&self) -> Vec<Call<H>> {
        self.stops.iter().map(|s| s.call(Vec::new())).collect()
    }

    /// When the next timer is due, if any.
    pub fn next_timer(&self, now: Duration, wall: DateTime<Utc>) -> Option<Duration> {
        self.schedule.next_deadline(now, wall)
    }

    /// What a timer was made from.
    pub fn timer_kind(&self, id: TimerId) -> Option<&TimerKind> {
        self.schedule.kind(id)
    }
}

/// The most `on_stop` handlers a script may register: together they get `STOP_BUDGET`, so
/// more would only be cut off.
pub const MAX_STOP_HANDLERS: usize = 100;

/// How long all the `on_stop` handlers of a stop may take together (each also within the
/// script's limits per call): a stop must reach the safe state whatever the script does.
pub const STOP_BUDGET: Duration = Duration::from_secs(2);

/// One `on_stop` too many (`MAX_STOP_HANDLERS`).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "too many on_stop handlers (at most {MAX_STOP_HANDLERS}, with 2s for all of them): do the \
     work of several in one"
)]
pub struct TooManyStopHandlers;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::schedule::TimerKind;
    use crate::time::clock::{Clock, VirtualClock};

    fn store() -> Handlers<&'static str> {
        Handlers::new(Zone::utc())
    }

    #[test]
    fn taken_handlers_leave_none_ids_go_on_and_put_back_they_are_whole_again() {
        let clock = VirtualClock::at_epoch();
        let mut s = store();
        s.set_max_timers(2);
        s.every(Duration::from_secs(1), clock.now(), "a").unwrap();
        s.add(Source::Stop, "d", "on_stop".into());
        let old = s.take();
        assert!(s.is_empty() && !s.has_work());
        assert_eq!(s.next_timer(clock.now(), clock.wall()), None);
        let e = s.after(Duration::from_secs(1), clock.now(), "e").unwrap();
        assert_eq!(e, 3, "an id is never given twice");
        s.every(Duration::from_secs(1), clock.now(), "f").unwrap();
        assert!(
            s.every(Duration::from_secs(1), clock.now(), "g").is_err(),
            "the limit on timers stays"
        );
        s.put_back(old);
        let labels: Vec<&str> = s.list().iter().map(|x| &*x.label).collect();
        assert_eq!(labels, ["every 1s", "on_stop"]);
        assert_eq!(s.signature().1, 5, "ids go on from the new ones");
    }

    #[test]
    fn ids_count_up_and_cancel_takes_a_timer_off_the_schedule() {
        let clock = VirtualClock::at_epoch();
        let mut s = store();
        let a = s.every(Duration::from_secs(1), clock.now(), "a").unwrap();
        let b = s
            .after(Duration::from_millis(500), clock.now(), "b")
            .unwrap();
        let c = s.cron("0 * * * * *", clock.wall(), "c").unwrap();
        let d = s.add(Source::Stop, "d", "on_stop".into());
        assert_eq!((a, b, c, d), (1, 2, 3, 4));
        let labels: Vec<&str> = s.list().iter().map(|x| &*x.label).collect();
        assert_eq!(
            labels,
            ["every 1s", "after 500ms", "cron \"0 * * * * *\"", "on_stop"]
        );
        assert_eq!(
            s.next_timer(clock.now(), clock.wall()),
            Some(Duration::from_millis(500))
        );
        assert!(s.cancel(b));
        assert!(!s.cancel(b), "gone already");
        assert!(!s.cancel(99));
        assert_eq!(s.schedule.len(), 2, "its timer went with it");
        assert_eq!(
            s.next_timer(clock.now(), clock.wall()),
            Some(Duration::from_secs(1))
        );
    }

    #[test]
    fn a_bad_timer_is_refused_and_adds_nothing() {
        let clock = VirtualClock::at_epoch();
        let mut s = store();
        assert!(s.every(Duration::ZERO, clock.now(), "x").is_err());
        assert!(s.cron("not cron", clock.wall(), "x").is_err());
        assert!(s.list().is_empty());
        assert_eq!(
            s.add(Source::Stop, "y", "on_stop".into()),
            1,
            "no id was used"
        );
    }

    #[test]
    fn timers_remember_what_they_were_made_from() {
        let mut s = store();
        s.after(Duration::from_secs(2), Duration::ZERO, "x")
            .unwrap();
        let Source::Timer(t) = s.list()[0].source else {
            panic!("a timer")
        };
        assert_eq!(
            s.timer_kind(t),
            Some(&TimerKind::After(Duration::from_secs(2)))
        );
    }

    #[test]
    fn on_stop_alone_is_no_work_and_only_device_events_poll_inputs() {
        let mut s = store();
        s.add(Source::Stop, "bye", "on_stop".into());
        assert!(!s.has_work());
        assert!(!s.polls_inputs());
        s.after(Duration::from_secs(1), Duration::ZERO, "later")
            .unwrap();
        assert!(s.has_work());
        assert!(!s.polls_inputs(), "timers do not poll");
        s.add(
            Source::Rise { dev: 0, ch: 3 },
            "rise",
            "io.on_rise 3".into(),
        );
        assert!(s.polls_inputs());
    }

    #[test]
    fn stop_calls_come_in_the_order_they_were_added() {
        let mut s = store();
        s.add(Source::Stop, "first", "on_stop 1".into());
        s.add(
            Source::Rise { dev: 0, ch: 1 },
            "rise",
            "io.on_rise 1".into(),
        );
        s.add(Source::Stop, "second", "on_stop 2".into());
        let calls: Vec<(&str, String)> = s
            .stop_calls()
            .into_iter()
            .map(|c| (c.handler, c.label.to_string()))
            .collect();
        assert_eq!(
            calls,
            [
                ("first", "on_stop 1".into()),
                ("second", "on_stop 2".into())
            ]
        );
        assert!(s.stop_calls().iter().all(|c| c.args.is_empty()));
    }

    #[test]
    fn clear_forgets_every_handler_and_timer_and_old_ids_cancel_nothing() {
        let mut s = store();
        let old = s
            .every(Duration::from_secs(1), Duration::ZERO, "x")
            .unwrap();
        s.add(Source::Stop, "y", "on_stop".into());
        s.clear();
        assert!(s.is_empty());
        assert!(s.schedule.is_empty());
        assert!(!s.cancel(old));
        let new = s
            .every(Duration::from_secs(1), Duration::ZERO, "z")
            .unwrap();
        assert!(new > old, "ids go on counting");
        assert!(!s.cancel(old));
        assert!(s.has_work());
    }

    #[test]
    fn timers_past_the_limit_are_refused_and_cancel_makes_room_again() {
        let mut s = store();
        s.set_max_timers(2);
        let a = s
            .every(Duration::from_secs(1), Duration::ZERO, "a")
            .unwrap();
        s.after(Duration::from_secs(1), Duration::ZERO, "b")
            .unwrap();
        let full = s.after(Duration::from_secs(1), Duration::ZERO, "c");
        assert_eq!(full, Err(ScheduleError::TooManyTimers { limit: 2 }));
        assert_eq!(s.len(), 2, "the refused one added nothing");
        assert!(s.cancel(a));
        s.cron("0 * * * * *", DateTime::<Utc>::UNIX_EPOCH, "d")
            .unwrap();
        s.clear();
        s.every(Duration::from_secs(1), Duration::ZERO, "e")
            .unwrap();
        s.every(Duration::from_secs(1), Duration::ZERO, "f")
            .unwrap();
        assert!(
            s.every(Duration::from_secs(1), Duration::ZERO, "g")
                .is_err(),
            "clear keeps the limit"
        );
    }

    #[test]
    fn cancel_finds_each_kind_of_handler() {
        let mut s = store();
        let rise = s.add(Source::Rise { dev: 0, ch: 1 }, "r", "r".into());
        let stop = s.add(Source::Stop, "s", "s".into());
        let timer = s
            .every(Duration::from_secs(1), Duration::ZERO, "t")
            .unwrap();
        assert_eq!(s.len(), 3);
        assert!(s.cancel(timer) && s.cancel(stop) && s.cancel(rise));
        assert!(s.is_empty());
        assert!(!s.has_work());
        assert!(s.schedule.is_empty());
    }

    #[test]
    fn the_fastest_every_follows_timers_as_they_come_and_go() {
        let mut s = store();
        assert_eq!(s.fastest_every(), None);
        let sig = s.signature();
        let slow = s
            .every(Duration::from_secs(1), Duration::ZERO, "s")
            .unwrap();
        let fast = s
            .every(Duration::from_millis(20), Duration::ZERO, "f")
            .unwrap();
        let twin = s
            .every(Duration::from_millis(20), Duration::ZERO, "t")
            .unwrap();
        s.after(Duration::from_millis(1), Duration::ZERO, "a")
            .unwrap();
        assert_ne!(s.signature(), sig);
        assert_eq!(s.fastest_every(), Some(Duration::from_millis(20)));
        assert!(s.cancel(fast));
        assert_eq!(
            s.fastest_every(),
            Some(Duration::from_millis(20)),
            "its twin"
        );
        assert!(s.cancel(twin));
        assert_eq!(s.fastest_every(), Some(Duration::from_secs(1)));
        assert!(s.cancel(slow));
        assert_eq!(s.fastest_every(), None);
        s.every(Duration::from_millis(5), Duration::ZERO, "x")
            .unwrap();
        s.clear();
        assert_eq!(s.fastest_every(), None);
    }
}
