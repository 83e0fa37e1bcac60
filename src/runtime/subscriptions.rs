//! The script's handlers and what each waits for (device events, counter thresholds, timers,
//! the end of the run), with the ids `cancel` takes.

use super::schedule::{Schedule, ScheduleError, TimerId, TimerKind};
use super::state::Runtime;
use crate::protocol::trc1000::{Rotary, Switch};
use crate::time::duration::format_duration;
use crate::time::zone::Zone;
use chrono::{DateTime, Utc};
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
        /// Fires when the count is at or above the threshold; re-armed when a reading shows
        /// it below again (cleared, reset, wrapped).
        armed: bool,
    },
    /// A timer of the schedule.
    Timer(TimerId),
    /// The end of the run.
    Stop,
}

/// A handler and what it waits for.
#[derive(Debug, Clone)]
pub struct Subscription<H> {
    /// Returned to the script, for `cancel`.
    pub id: u64,
    /// What it waits for.
    pub source: Source,
    /// The script's function.
    pub handler: H,
    /// The handler in words for the log and error messages: `panel.on_press S1`.
    pub label: String,
    /// When a timer's firing was last logged (a fast `every` is logged once a second).
    pub(super) last_logged: Option<Duration>,
}

/// A value passed to a handler.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Arg {
    /// A number.
    Int(i64),
    /// A name.
    Str(String),
}

/// A handler to run now, with its arguments.
#[derive(Debug, Clone)]
pub struct Call<H> {
    /// The script's function.
    pub handler: H,
    /// Its arguments (the script layer passes as many as the function takes).
    pub args: Vec<Arg>,
    /// The handler in words.
    pub label: String,
}

impl<H: Clone> Subscription<H> {
    /// A call of this handler with `args`.
    pub fn call(&self, args: Vec<Arg>) -> Call<H> {
        Call {
            handler: self.handler.clone(),
            args,
            label: self.label.clone(),
        }
    }
}

/// Every handler of the script, and the schedule of its timers.
pub struct Subscriptions<H> {
    /// In the order they were added.
    pub(super) list: Vec<Subscription<H>>,
    next_id: u64,
    /// The timers of `Source::Timer` handlers.
    pub(super) schedule: Schedule<Zone>,
    zone: Zone,
}

impl<H: Clone> Subscriptions<H> {
    /// No handlers; timers keep time in `zone`.
    pub fn new(zone: Zone) -> Self {
        Self {
            list: Vec::new(),
            next_id: 1,
            schedule: Schedule::with_time_zone(zone),
            zone,
        }
    }

    /// Adds a handler; returns its id.
    pub fn add(&mut self, source: Source, handler: H, label: String) -> u64 {
        let id = self.next_id;
        self.next_id = self.next_id.saturating_add(1);
        self.list.push(Subscription {
            id,
            source,
            handler,
            label,
            last_logged: None,
        });
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
        Ok(self.add(Source::Timer(id), handler, label))
    }

    /// `after(delay, fn)`, counted from monotonic `now`.
    pub fn after(&mut self, delay: Duration, now: Duration, handler: H) -> u64 {
        let id = self.schedule.after(delay, now);
        let label = format!("after {}", format_duration(delay));
        self.add(Source::Timer(id), handler, label)
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
        Ok(self.add(Source::Timer(id), handler, label))
    }

    /// Removes a handler or timer; false if there is none with that id.
    pub fn cancel(&mut self, id: u64) -> bool {
        let Some(pos) = self.list.iter().position(|s| s.id == id) else {
            return false;
        };
        let sub = self.list.remove(pos);
        if let Source::Timer(t) = sub.source {
            self.schedule.cancel(t);
        }
        true
    }

    /// Forgets every handler and timer (ids go on counting, so an old id cancels nothing).
    pub fn clear(&mut self) {
        self.list.clear();
        self.schedule = Schedule::with_time_zone(self.zone);
    }

    /// Whether the script still waits for anything (handlers other than `on_stop`, timers).
    pub fn has_work(&self) -> bool {
        self.list.iter().any(|s| s.source != Source::Stop)
    }

    /// Whether some handler waits for device inputs (then every tick polls them).
    pub fn polls_inputs(&self) -> bool {
        self.list
            .iter()
            .any(|s| !matches!(s.source, Source::Timer(_) | Source::Stop))
    }

    /// The handlers, for inspection.
    pub fn list(&self) -> &[Subscription<H>] {
        &self.list
    }

    /// The `on_stop` handlers, in the order they were added.
    pub fn stop_calls(&self) -> Vec<Call<H>> {
        self.list
            .iter()
            .filter(|s| s.source == Source::Stop)
            .map(|s| s.call(Vec::new()))
            .collect()
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

/// The script's side: what its registrations do to the run's handlers.
impl<H: Clone> Runtime<H> {
    /// Adds a handler; returns its id.
    pub fn subscribe(&mut self, source: Source, handler: H, label: String) -> u64 {
        self.handlers.add(source, handler, label)
    }

    /// `every(period, fn)`.
    pub fn every(&mut self, period: Duration, handler: H) -> Result<u64, ScheduleError> {
        let now = self.now();
        self.handlers.every(period, now, handler)
    }

    /// `after(delay, fn)`.
    pub fn after(&mut self, delay: Duration, handler: H) -> u64 {
        let now = self.now();
        self.handlers.after(delay, now, handler)
    }

    /// `cron(expr, fn)`.
    pub fn cron(&mut self, expr: &str, handler: H) -> Result<u64, ScheduleError> {
        let wall = self.clock.wall();
        self.handlers.cron(expr, wall, handler)
    }

    /// Removes a handler or timer; false if there is none with that id.
    pub fn cancel(&mut self, id: u64) -> bool {
        self.handlers.cancel(id)
    }

    /// Whether the script still waits for anything (handlers other than `on_stop`, timers).
    pub fn has_work(&self) -> bool {
        self.handlers.has_work()
    }

    /// The `on_stop` handlers, in the order they were added.
    pub fn stop_calls(&self) -> Vec<Call<H>> {
        self.handlers.stop_calls()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::schedule::TimerKind;
    use crate::time::clock::{Clock, VirtualClock};

    fn store() -> Subscriptions<&'static str> {
        Subscriptions::new(Zone::utc())
    }

    #[test]
    fn ids_count_up_and_cancel_takes_a_timer_off_the_schedule() {
        let clock = VirtualClock::at_epoch();
        let mut s = store();
        let a = s.every(Duration::from_secs(1), clock.now(), "a").unwrap();
        let b = s.after(Duration::from_millis(500), clock.now(), "b");
        let c = s.cron("0 * * * * *", clock.wall(), "c").unwrap();
        let d = s.add(Source::Stop, "d", "on_stop".into());
        assert_eq!((a, b, c, d), (1, 2, 3, 4));
        let labels: Vec<&str> = s.list().iter().map(|x| x.label.as_str()).collect();
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
        s.after(Duration::from_secs(2), Duration::ZERO, "x");
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
        s.after(Duration::from_secs(1), Duration::ZERO, "later");
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
            .map(|c| (c.handler, c.label))
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
        assert!(s.list().is_empty());
        assert!(s.schedule.is_empty());
        assert!(!s.cancel(old));
        let new = s
            .every(Duration::from_secs(1), Duration::ZERO, "z")
            .unwrap();
        assert!(new > old, "ids go on counting");
        assert!(!s.cancel(old));
        assert!(s.has_work());
    }
}
