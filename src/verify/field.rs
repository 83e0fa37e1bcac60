//! A random but plausible field for one run: inputs opening and closing (with contact bounce),
//! counter pulses in steps of every size (to the values the script compares counters with, and
//! to their 16-bit wrap), switches pressed and released (several at once too), rotaries turned
//! both ways across their wrap; and, with faults on, the faults of `verify::faults` (twice as
//! often while a switch the script reads is held). Choices
//! lean toward what the script reads (each item it reads is left out of some runs, so none
//! starves another) and the gaps between events toward its timers, grace time and watchdogs.
//! The same seed makes the same plan.

use super::plan::{Action, Event, Plan, StartPoint};
use super::profile::{Kind, Profile};
use crate::protocol::trc1000::{Rotary, Switch};
use crate::script::reads::Item;
use crate::time::zone::Zone;
use chrono::{DateTime, TimeDelta, Utc};
use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

/// Weight of an item the script reads, at least, against 1 for one it does not.
pub const READ_WEIGHT: u32 = 10;

/// Chance that the next event is a fault, when faults are on.
pub const FAULT_CHANCE: f64 = 0.12;

/// The chance of a fault while a switch the script reads is held: a fault in the middle of an
/// operator's action (one hand on the button, the other on its way) is where a script's
/// timing shows.
pub const FAULT_CHANCE_HELD: f64 = 0.24;

/// Where wall time starts unless a run starts near a cron time or a DST change.
pub const BASE_START: &str = "2026-03-28T12:00:00Z";

/// The zones of the runs that cross a DST change: both hemispheres, and a change at another
/// hour of the UTC day.
pub const DST_ZONES: [&str; 3] = ["Europe/Berlin", "America/New_York", "Australia/Sydney"];

/// The years runs start in: any date in them (leap days, year ends and DST changes included).
pub const YEARS: std::ops::RangeInclusive<i32> = 2024..=2040;

/// The times in `year` at which `zone`'s offset from UTC changes, to the second.
pub fn offset_changes(zone: &Zone, year: i32) -> Vec<DateTime<Utc>> {
    use chrono::{Datelike, Offset};
    let offset = |t: DateTime<Utc>| zone.at(t).offset().fix();
    let Some(start) = chrono::NaiveDate::from_ymd_opt(year, 1, 1)
        .and_then(|d| d.and_hms_opt(0, 0, 0))
        .map(|t| t.and_utc())
    else {
        return Vec::new();
    };
    let mut out = Vec::new();
    let day = TimeDelta::days(1);
    let mut t = start;
    while t.year() == year {
        let next = t + day;
        if offset(t) != offset(next) {
            // Bisect the day, in whole seconds, to the first second of the new offset.
            let (mut lo, mut hi) = (0i64, 86_400i64);
            while hi - lo > 1 {
                let mid = (lo + hi) / 2;
                if offset(t + TimeDelta::seconds(mid)) == offset(t) {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            out.push(t + TimeDelta::seconds(hi));
        }
        t = next;
    }
    out
}

/// The step event times are made of: a millisecond, or a quarter of a shorter scan period
/// (round numbers in the test files people read).
pub fn quantum(period: Duration) -> Duration {
    Duration::from_millis(1)
        .min(period / 4)
        .max(Duration::from_micros(1))
}

/// Something in the field an event can act on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Target {
    Switch(usize, Switch),
    Rotary(usize, Rotary),
    Input(usize, u8),
    Counter(usize, u8),
}

/// The generator's state while it makes up one plan.
pub(super) struct Gen<'a> {
    pub(super) rng: fastrand::Rng,
    pub(super) profile: &'a Profile,
    pub(super) events: Vec<Event>,
    /// Current time in the plan.
    pub(super) t: Duration,
    /// Device index → inputs energized, as the plan has set them.
    pub(super) inputs: BTreeMap<usize, u8>,
    /// (device, switch) → when it is released.
    pub(super) held: BTreeMap<(usize, Switch), Duration>,
    /// Device index → when it answers again (`Duration::MAX`: never in this run).
    pub(super) lost_until: BTreeMap<usize, Duration>,
    /// Wall-clock steps so far, in seconds.
    pub(super) wall_steps: i64,
    pub(super) start: StartPoint,
    pub(super) stopped: bool,
    targets: Vec<(Target, u32)>,
    total_weight: u32,
}

fn utc(text: &str) -> DateTime<Utc> {
    DateTime::parse_from_rfc3339(text)
        .map(|t| t.with_timezone(&Utc))
        .unwrap_or(DateTime::<Utc>::UNIX_EPOCH)
}

/// The first time after `after` (in `zone`) that one of the cron expressions matches.
pub(super) fn next_cron(
    crons: &std::collections::BTreeSet<String>,
    after: DateTime<Utc>,
    zone: Zone,
) -> Option<DateTime<Utc>> {
    crons
        .iter()
        .filter_map(|e| crate::runtime::schedule::parse_cron(e).ok())
        .filter_map(|c| c.find_next_occurrence(&zone.at(after), false).ok())
        .map(|t| t.with_timezone(&Utc))
        .min()
}

impl<'a> Gen<'a> {
    pub(super) fn new(profile: &'a Profile, seed: u64) -> Self {
        let mut rng = fastrand::Rng::with_seed(seed);
        let mut targets = Vec::new();
        for (idx, d) in profile.devices.iter().enumerate() {
            let weight = |item: Item| u32::from(profile.reads.contains(idx, item));
            match d.kind {
                Kind::Trc => {
                    for s in Switch::all() {
                        targets.push((Target::Switch(idx, s), weight(Item::Switch(s))));
                    }
                    for r in Rotary::ALL {
                        targets.push((Target::Rotary(idx, r), weight(Item::Rotary(r))));
                    }
                }
                Kind::C29u => {
                    for ch in 0..8 {
                        targets.push((Target::Input(idx, ch), weight(Item::Input(ch))));
                        targets.push((Target::Counter(idx, ch), weight(Item::Counter(ch))));
                    }
                }
            }
        }
        Self::weigh(&mut rng, &mut targets);
        let total_weight = targets.iter().map(|(_, w)| *w).sum();
        let start = Self::start_point(&mut rng, profile);
        Self {
            rng,
            profile,
            events: Vec::new(),
            t: Duration::ZERO,
            inputs: BTreeMap::new(),
            held: BTreeMap::new(),
            lost_until: BTreeMap::new(),
            wall_steps: 0,
            start,
            stopped: false,
            targets,
            total_weight,
        }
    }

    /// Weighs the targets (marked 1 if read, 0 if not) for one run. Each item the script
    /// reads is left out of the run by a coin toss (at least one stays), so that no input
    /// starves another: in some runs a count builds with its reset button never pressed, a
    /// guard stays put while the buttons are tried. Those that stay weigh `READ_WEIGHT`, or
    /// half the number of items not read if that is more, and together the items not read
    /// weigh at most twice one read item: something the script never looks at is rarely worth
    /// an event, but not never.
    fn weigh(rng: &mut fastrand::Rng, targets: &mut [(Target, u32)]) {
        let read: Vec<usize> = (0..targets.len())
            .filter(|i| targets.get(*i).is_some_and(|t| t.1 > 0))
            .collect();
        let unread = u32::try_from(targets.len() - read.len()).unwrap_or(u32::MAX);
        let keep = read.get(rng.usize(0..read.len().max(1))).copied();
        let weight = READ_WEIGHT.max(unread / 2);
        for (i, t) in targets.iter_mut().enumerate() {
            t.1 = if t.1 == 0 {
                1
            } else if Some(i) == keep || rng.bool() {
                weight
            } else {
                0
            };
        }
    }

    /// `U(0, max)` in whole steps of `quantum(period)`.
    pub(super) fn up_to(&mut self, max: Duration) -> Duration {
        let q = quantum(self.profile.period);
        let steps = u64::try_from(max.as_nanos() / q.as_nanos().max(1)).unwrap_or(u64::MAX);
        q.saturating_mul(u32::try_from(self.rng.u64(0..=steps)).unwrap_or(u32::MAX))
    }

    /// Where the run starts: mostly any time of any day of the years `YEARS` in UTC; some
    /// runs just before a cron time, some across a DST change of one of `DST_ZONES` that year.
    fn start_point(rng: &mut fastrand::Rng, profile: &Profile) -> StartPoint {
        let span = profile.run_for.mul_f64(0.9);
        let before = |rng: &mut fastrand::Rng, t: DateTime<Utc>| {
            let back = rng.u64(0..=u64::try_from(span.as_millis()).unwrap_or(0));
            t - TimeDelta::milliseconds(i64::try_from(back).unwrap_or(0))
        };
        let roll = rng.f64();
        let dst_share = if profile.crons.is_empty() { 0.1 } else { 0.3 };
        let utc_zone = Zone::utc();
        let year = rng.i32(YEARS);
        if roll < dst_share {
            let name = DST_ZONES[rng.usize(0..DST_ZONES.len())];
            let zone = Zone::parse(name).unwrap_or(utc_zone);
            let changes = offset_changes(&zone, year);
            if !changes.is_empty() {
                let change = changes[rng.usize(0..changes.len())];
                let wall = before(rng, change);
                return StartPoint {
                    wall: zone.at(wall).fixed_offset(),
                    zone: name.into(),
                };
            }
        }
        // Any second of any day of the year (the base day's year moved to `year`).
        let base = utc(BASE_START);
        let jan1 = chrono::NaiveDate::from_ymd_opt(year, 1, 1)
            .and_then(|d| d.and_hms_opt(0, 0, 0))
            .map_or(base, |t| t.and_utc());
        let days = if chrono::NaiveDate::from_ymd_opt(year, 2, 29).is_some() {
            366
        } else {
            365
        };
        let day = jan1 + TimeDelta::seconds(rng.i64(0..days * 86_400));
        if roll < dst_share + 0.3 {
            if let Some(at) = next_cron(&profile.crons, day, utc_zone) {
                return StartPoint {
                    wall: before(rng, at).fixed_offset(),
                    zone: "UTC".into(),
                };
            }
        }
        StartPoint {
            wall: (day + TimeDelta::milliseconds(rng.i64(0..1000))).fixed_offset(),
            zone: "UTC".into(),
        }
    }

    /// The gap to the next event: a tick or three, a timer's length give or take two ticks,
    /// or something longer.
    fn gap(&mut self) -> Duration {
        let period = self.profile.period;
        let roll = self.rng.f64();
        let durations = self.profile.interesting_durations();
        if roll < 0.35 {
            period.saturating_mul(self.rng.u32(0..3)) + self.up_to(period)
        } else if roll < 0.6 && !durations.is_empty() {
            let d = durations[self.rng.usize(0..durations.len())];
            let jitter = self.up_to(period.saturating_mul(4));
            (d + jitter).saturating_sub(period.saturating_mul(2))
        } else if roll < 0.85 {
            self.up_to(Duration::from_secs(1))
        } else {
            Duration::from_secs(1) + self.up_to(Duration::from_secs(4))
        }
    }

    pub(super) fn push(&mut self, at: Duration, action: Action) {
        self.events.push(Event { at, action });
    }

    pub(super) fn name(&self, idx: usize) -> Arc<str> {
        self.profile
            .devices
            .get(idx)
            .map_or_else(|| Arc::from("?"), |d| Arc::clone(&d.name))
    }

    fn pick_target(&mut self) -> Option<Target> {
        if self.total_weight == 0 {
            return None;
        }
        let mut x = self.rng.u32(0..self.total_weight);
        for (t, w) in &self.targets {
            if x < *w {
                return Some(*t);
            }
            x -= w;
        }
        None
    }

    /// A read switch of the same panel other than `not`, for pressing several at once.
    fn another_switch(&mut self, dev: usize, not: Switch) -> Option<Switch> {
        let read: Vec<Switch> = self
            .targets
            .iter()
            .filter_map(|(t, w)| match t {
                Target::Switch(d, s) if *d == dev && *s != not && *w > 1 => Some(*s),
                _ => None,
            })
            .collect();
        (!read.is_empty()).then(|| read[self.rng.usize(0..read.len())])
    }

    /// Whether a switch the script reads is held now.
    fn holding_read_switch(&self) -> bool {
        self.held.iter().any(|(&(dev, s), until)| {
            *until > self.t
                && self
                    .targets
                    .iter()
                    .any(|(t, w)| *t == Target::Switch(dev, s) && *w > 1)
        })
    }

    fn hold(&mut self) -> Duration {
        let period = self.profile.period;
        match self.rng.u8(0..10) {
            0..=3 => period.saturating_mul(self.rng.u32(1..4)),
            4..=7 => Duration::from_millis(100) + self.up_to(Duration::from_millis(900)),
            _ => Duration::from_secs(1) + self.up_to(Duration::from_secs(4)),
        }
    }

    fn press(&mut self, dev: usize, s: Switch) {
        let t = self.t;
        let hold = self.hold();
        self.held.insert((dev, s), t + hold);
        let name = self.name(dev);
        self.push(
            t,
            Action::Press {
                dev: Arc::clone(&name),
                switch: s,
            },
        );
        self.push(
            t + hold,
            Action::Release {
                dev: name,
                switch: s,
            },
        );
    }

    fn switch(&mut self, dev: usize, s: Switch) {
        if self
            .held
            .get(&(dev, s))
            .is_some_and(|until| *until > self.t)
        {
            return; // held: its release is already planned
        }
        self.press(dev, s);
        if self.rng.f64() < 0.15 {
            // One, two or three more at the same instant (a palm across the panel).
            for _ in 0..self.rng.u32(1..=3) {
                if let Some(other) = self.another_switch(dev, s) {
                    if !self.held.get(&(dev, other)).is_some_and(|u| *u > self.t) {
                        self.press(dev, other);
                    }
                }
            }
        }
    }

    fn rotary(&mut self, dev: usize, r: Rotary) {
        let size = if self.rng.f64() < 0.7 {
            self.rng.i32(1..=6)
        } else {
            self.rng.i32(10..=100)
        };
        let half_turns = if self.rng.bool() { size } else { -size };
        let dev = self.name(dev);
        self.push(
            self.t,
            Action::Turn {
                dev,
                rotary: r,
                half_turns,
            },
        );
    }

    /// A whole DI byte: often all energized (a rig at rest: guards closed, sensors made) or
    /// none, otherwise any.
    fn input_byte(&mut self) -> u8 {
        match self.rng.u8(0..10) {
            0..=3 => 0xFF,
            4..=5 => 0x00,
            _ => self.rng.u8(..),
        }
    }

    fn input(&mut self, dev: usize, ch: u8) {
        let name = self.name(dev);
        let now = self.inputs.get(&dev).copied().unwrap_or(0);
        if self.rng.f64() < 0.1 {
            let byte = self.input_byte();
            self.inputs.insert(dev, byte);
            self.push(self.t, Action::Inputs { dev: name, byte });
            return;
        }
        let on = now & (1 << ch) == 0;
        // Contact bounce: the level flips a few times, a millisecond or so apart, and settles.
        let mut at = self.t;
        if self.rng.f64() < 0.3 {
            for i in 0..self.rng.u32(1..4) * 2 {
                self.push(
                    at,
                    Action::Input {
                        dev: Arc::clone(&name),
                        ch,
                        on: (i % 2 == 0) == on,
                    },
                );
                at += quantum(self.profile.period).saturating_mul(self.rng.u32(1..4));
            }
        }
        self.push(at, Action::Input { dev: name, ch, on });
        let next = if on { now | 1 << ch } else { now & !(1 << ch) };
        self.inputs.insert(dev, next);
        self.t = at;
    }

    /// A counter event, in steps of every size: a few pulses, tens, hundreds or thousands;
    /// to just below, at or just above a value the script compares the counter with (carried
    /// there from zero, or that many pulses from wherever it is: a count since a baseline);
    /// across such a value in one tick (`step_over`); or to just below the 16-bit wrap.
    fn counter(&mut self, dev: usize, ch: u8) {
        let marks = self.profile.facts.counter_values(ch);
        let aim = if marks.is_empty() { 0.0 } else { 0.35 };
        let roll = self.rng.f64();
        if roll < aim * 0.4 {
            let mark = marks[self.rng.usize(0..marks.len())];
            return self.step_over(dev, ch, mark);
        }
        let dev = self.name(dev);
        let action = if roll < aim {
            let mark = marks[self.rng.usize(0..marks.len())];
            let value = mark.saturating_add_signed(self.rng.i16(-5..=1));
            if self.rng.bool() {
                Action::CounterTo { dev, ch, value }
            } else {
                let n = u32::from(value.max(1));
                Action::Pulse { dev, ch, n }
            }
        } else if roll < aim + 0.12 {
            let value = u16::MAX - self.rng.u16(0..6);
            Action::CounterTo { dev, ch, value }
        } else {
            let n = match self.rng.u8(0..20) {
                0..=11 => self.rng.u32(1..6),
                12..=16 => self.rng.u32(6..60),
                17..=18 => self.rng.u32(60..1000),
                _ => self.rng.u32(1000..20_000),
            };
            Action::Pulse { dev, ch, n }
        };
        self.push(self.t, action);
    }

    /// A counter carried to one below `mark` (from zero, or as many pulses from wherever it
    /// is), then, a tick or more later so the script reads it there, 2 to 4 pulses that one
    /// scan sees at once: the count steps over `mark` without landing on it, as two strokes
    /// between scans do. A script that waits for `count == mark` misses it.
    fn step_over(&mut self, dev: usize, ch: u8, mark: u16) {
        let dev = self.name(dev);
        let below = mark.saturating_sub(1);
        let approach = if self.rng.bool() {
            Action::CounterTo {
                dev: Arc::clone(&dev),
                ch,
                value: below,
            }
        } else {
            Action::Pulse {
                dev: Arc::clone(&dev),
                ch,
                n: u32::from(below.max(1)),
            }
        };
        self.push(self.t, approach);
        let period = self.profile.period;
        let at = self.t + period.saturating_mul(self.rng.u32(1..4)) + self.up_to(period);
        let n = self.rng.u32(2..=4);
        self.push(at, Action::Pulse { dev, ch, n });
        self.t = at;
    }

    fn field_event(&mut self) {
        match self.pick_target() {
            Some(Target::Switch(d, s)) => self.switch(d, s),
            Some(Target::Rotary(d, r)) => self.rotary(d, r),
            Some(Target::Input(d, ch)) => self.input(d, ch),
            Some(Target::Counter(d, ch)) => self.counter(d, ch),
            None => {}
        }
    }

    /// Inputs as a run finds them: some energized from the start (guards closed, a part on
    /// a sensor).
    fn initial_inputs(&mut self) {
        let at = self.profile.period / 2;
        for idx in 0..self.profile.devices.len() {
            if self.profile.devices.get(idx).map(|d| d.kind) == Some(Kind::C29u)
                && self.rng.f64() < 0.7
            {
                let byte = self.input_byte();
                self.inputs.insert(idx, byte);
                let dev = self.name(idx);
                self.push(at, Action::Inputs { dev, byte });
            }
        }
    }

    fn run(mut self, faults: bool) -> Plan {
        self.initial_inputs();
        loop {
            let gap = self.gap();
            self.t += gap;
            if self.t >= self.profile.run_for || self.stopped {
                break;
            }
            let chance = if self.holding_read_switch() {
                FAULT_CHANCE_HELD
            } else {
                FAULT_CHANCE
            };
            if faults && self.rng.f64() < chance {
                self.fault_event();
            } else {
                self.field_event();
            }
        }
        let end = self.profile.run_for;
        let mut plan = Plan {
            start: self.start,
            events: self.events.into_iter().filter(|e| e.at < end).collect(),
        };
        plan.sort();
        if let Some(stop) = plan.events.iter().position(|e| e.action == Action::Stop) {
            plan.events.truncate(stop + 1);
        }
        plan
    }
}

/// The plan of one run, from its seed.
pub fn generate(profile: &Profile, seed: u64, faults: bool) -> Plan {
    Gen::new(profile, seed).run(faults)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::RigConfig;

    fn profile() -> Profile {
        let config = RigConfig::simulated_default();
        Profile::new(
            &config,
            r#"panel.on_press("S12", || {});"#,
            Duration::from_millis(20),
            Duration::from_secs(60),
        )
    }

    #[test]
    fn dst_changes_are_found_for_any_year_and_runs_start_on_many_dates() {
        let berlin = Zone::parse("Europe/Berlin").unwrap();
        let changes: Vec<String> = offset_changes(&berlin, 2031)
            .iter()
            .map(|t| t.to_rfc3339())
            .collect();
        assert_eq!(
            changes,
            ["2031-03-30T01:00:00+00:00", "2031-10-26T01:00:00+00:00"]
        );
        assert!(offset_changes(&Zone::utc(), 2031).is_empty());
        let p = profile();
        let (mut years, mut zones) = (BTreeMap::new(), std::collections::BTreeSet::new());
        for seed in 0..200 {
            let start = generate(&p, seed, false).start;
            *years
                .entry(chrono::Datelike::year(&start.wall))
                .or_insert(0) += 1;
            zones.insert(start.zone);
        }
        assert!(years.len() >= 10, "{years:?}");
        assert!(zones.len() >= 3, "{zones:?}");
    }

    #[test]
    fn the_same_seed_makes_the_same_plan_and_another_seed_another() {
        let p = profile();
        let a = generate(&p, 7, true);
        assert_eq!(a, generate(&p, 7, true));
        assert_ne!(a, generate(&p, 8, true));
        assert!(a.events.len() > 20, "{} events in 60 s", a.events.len());
        assert!(
            a.events.windows(2).all(|w| w[0].at <= w[1].at),
            "in time order"
        );
        assert!(a.events.iter().all(|e| e.at < Duration::from_secs(60)));
    }

    #[test]
    fn what_the_script_reads_comes_up_far_more_often() {
        let p = profile();
        let (mut s12, mut s13) = (0, 0);
        for seed in 0..200 {
            for e in generate(&p, seed, false).events {
                if let Action::Press { switch, .. } = e.action {
                    match switch.number() {
                        12 => s12 += 1,
                        13 => s13 += 1,
                        _ => {}
                    }
                }
            }
        }
        assert!(s12 > 4 * s13.max(1), "S12 {s12} times, S13 {s13}");
    }

    #[test]
    fn every_press_is_released_and_no_fault_comes_without_faults() {
        let p = profile();
        for seed in 0..50 {
            let plan = generate(&p, seed, false);
            assert!(plan.events.iter().all(|e| !e.action.is_fault()));
            let mut held = std::collections::BTreeSet::new();
            for e in &plan.events {
                match &e.action {
                    Action::Press { switch, .. } => assert!(held.insert(*switch), "pressed twice"),
                    Action::Release { switch, .. } => assert!(held.remove(switch)),
                    _ => {}
                }
            }
        }
    }

    /// A profile of a script that reads counter DI0 of `io` and resets it on DI7.
    fn counting(source: &str) -> Profile {
        let config = RigConfig::simulated_default();
        let mut p = Profile::new(
            &config,
            source,
            Duration::from_millis(20),
            Duration::from_secs(60),
        );
        let io = p.devices.iter().position(|d| d.kind == Kind::C29u).unwrap();
        p.reads.add(io, Item::Counter(0));
        p.reads.add(io, Item::Input(7));
        p
    }

    #[test]
    fn counter_events_come_in_steps_of_every_size_and_reach_the_values_compared_with() {
        let p = counting("let io = device(\"io\"); every(\"20ms\", || io.counter(0) >= 300);");
        let (mut near, mut sizes) = (0, std::collections::BTreeSet::new());
        for seed in 0..100 {
            for e in generate(&p, seed, false).events {
                let (to, n) = match e.action {
                    Action::CounterTo { ch: 0, value, .. } => (u32::from(value), None),
                    Action::Pulse { ch: 0, n, .. } => (n, Some(n)),
                    _ => continue,
                };
                if (295..=301).contains(&to) {
                    near += 1;
                } else if let Some(n) = n {
                    sizes.insert(n.ilog10());
                }
            }
        }
        assert!(near > 100, "{near} events to just below, at or above 300");
        assert_eq!(
            sizes,
            (0..=4).collect(),
            "ones, tens, hundreds, thousands, ten thousands"
        );
    }

    #[test]
    fn random_runs_step_counters_over_the_values_compared_with_in_one_scan() {
        let p = counting("let io = device(\"io\"); every(\"20ms\", || io.counter(0) == 300);");
        let stepped = (0..40)
            .filter(|seed| {
                // One below the mark (absolute, or as many pulses from zero), then 2 to 4
                // pulses at least a period later, with nothing on that counter between.
                generate(&p, *seed, false).events.windows(2).any(|w| {
                    let below = matches!(
                        w[0].action,
                        Action::CounterTo {
                            ch: 0,
                            value: 299,
                            ..
                        } | Action::Pulse { ch: 0, n: 299, .. }
                    );
                    let over = matches!(
                        w[1].action,
                        Action::Pulse {
                            ch: 0,
                            n: 2..=4,
                            ..
                        }
                    );
                    below && over && w[1].at >= w[0].at + p.period
                })
            })
            .count();
        assert!(stepped >= 8, "{stepped} of 40 runs stepped over 300");
    }

    #[test]
    fn no_input_the_script_reads_starves_another() {
        // The reset button (DI7) weighs as much as the counter, yet some runs leave it alone
        // so that a count can build.
        let p = counting("");
        let alone = (0..100)
            .map(|seed| generate(&p, seed, false).events)
            .filter(|events| {
                let counts = events
                    .iter()
                    .any(|e| matches!(e.action, Action::Pulse { ch: 0, .. }));
                let resets = events
                    .iter()
                    .any(|e| matches!(e.action, Action::Input { ch: 7, .. }));
                counts && !resets
            })
            .count();
        assert!(alone >= 20, "{alone} of 100 runs count with no reset");
    }
}
