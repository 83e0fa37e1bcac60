//! Shrinking a counterexample to one a person can act on: the fewest events, each as simple as
//! it can be, as early and as close together as they can be, that still make the same check
//! fail. Greedy and deterministic: drop chunks of events, halving the chunk size down to single
//! events (delta debugging); drop pairs that only go together (neighbours across a chunk's
//! edge, and two events on the same thing however far apart: a press and its release, a loss
//! and its end, the flips of a bounce); fold a counted input's flips into its count (a count
//! carried to 296 and four bounced edges become a count carried to 300); simplify each event
//! (fewer pulses, fewer inputs, a shorter stall);
//! shorten each wait (to nothing first: two events between the same two ticks, then by halves),
//! the wait before the end too. Repeats until nothing helps or the budget is spent.

use super::plan::{Action, Event, Plan};
use std::time::{Duration, Instant};

/// A plan and how long its run lasts.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Candidate {
    /// The plan.
    pub plan: Plan,
    /// The run ends here.
    pub horizon: Duration,
}

/// What one replay of a candidate showed, when it still fails the same check.
pub trait Replay {
    /// When the check failed.
    fn at(&self) -> Duration;
    /// How many of the plan's events were played before it failed.
    fn played(&self) -> usize;
}

/// How much shrinking may cost.
#[derive(Debug, Clone, Copy)]
pub struct Budget {
    /// Replays at most.
    pub replays: usize,
    /// Wall-clock time at most.
    pub time: Duration,
}

/// The result of shrinking.
#[derive(Debug, Clone)]
pub struct Shrunk<O> {
    /// The smallest candidate found.
    pub candidate: Candidate,
    /// Its replay.
    pub replay: O,
    /// How many replays it took.
    pub replays: usize,
    /// Whether the budget ran out before nothing more helped.
    pub exhausted: bool,
}

struct Shrinker<O, F> {
    best: Candidate,
    replay: O,
    fails: F,
    replays: usize,
    budget: Budget,
    began: Instant,
    exhausted: bool,
    margin: Duration,
    quantum: Duration,
}

impl<O: Replay, F: FnMut(&Candidate) -> Option<O>> Shrinker<O, F> {
    /// Tries a candidate; keeps it (cut to the events it played) if it still fails.
    fn try_candidate(&mut self, mut c: Candidate) -> bool {
        if c == self.best {
            return false;
        }
        if self.replays >= self.budget.replays || self.began.elapsed() >= self.budget.time {
            self.exhausted = true;
            return false;
        }
        self.replays += 1;
        match (self.fails)(&c) {
            Some(r) => {
                c.plan.events.truncate(r.played());
                c.horizon = c.horizon.min(r.at().saturating_add(self.margin));
                self.best = c;
                self.replay = r;
                true
            }
            None => false,
        }
    }

    fn with_events(&self, events: Vec<Event>) -> Candidate {
        Candidate {
            plan: Plan {
                start: self.best.plan.start.clone(),
                events,
            },
            horizon: self.best.horizon,
        }
    }

    /// Drops chunks of events, halving the chunk size down to one.
    fn drop_events(&mut self) -> bool {
        let mut changed = false;
        let mut parts = 2usize;
        loop {
            let len = self.best.plan.events.len();
            if len == 0 || self.exhausted {
                return changed;
            }
            let chunk = len.div_ceil(parts.min(len));
            let mut dropped = false;
            let mut start = 0;
            while start < self.best.plan.events.len() {
                let mut events = self.best.plan.events.clone();
                let end = (start + chunk).min(events.len());
                events.drain(start..end);
                if self.try_candidate(self.with_events(events)) {
                    dropped = true;
                    changed = true;
                } else {
                    start += chunk;
                }
                if self.exhausted {
                    return changed;
                }
            }
            if !dropped {
                if chunk == 1 {
                    return changed;
                }
                parts = parts.saturating_mul(2);
            }
        }
    }

    /// Drops two events at once: neighbours (which chunks drop only when they share a chunk)
    /// and any two on the same thing, which may only go away together.
    fn drop_pairs(&mut self) -> bool {
        let mut changed = false;
        let mut i = 0;
        while i < self.best.plan.events.len() && !self.exhausted {
            let mut j = i + 1;
            let mut dropped = false;
            while j < self.best.plan.events.len() && !self.exhausted {
                let events = &self.best.plan.events;
                let together = j == i + 1
                    || events[i]
                        .action
                        .subject()
                        .is_some_and(|s| events[j].action.subject().as_ref() == Some(&s));
                if together {
                    let mut fewer = events.clone();
                    fewer.remove(j);
                    fewer.remove(i);
                    if self.try_candidate(self.with_events(fewer)) {
                        changed = true;
                        dropped = true;
                        break;
                    }
                }
                j += 1;
            }
            if !dropped {
                i += 1;
            }
        }
        changed
    }

    /// Folds flips of an input into a count of it: a flip, or it and the input's next one,
    /// dropped and a pulse added to the nearest counter event of that input; with no counter
    /// event, two flips made one pulse. Dropping them alone would change the count.
    fn fold_pulses(&mut self) -> bool {
        let mut changed = false;
        let mut i = 0;
        while i < self.best.plan.events.len() && !self.exhausted {
            let events = &self.best.plan.events;
            let Some(Action::Input { dev, ch, .. }) = events.get(i).map(|e| &e.action) else {
                i += 1;
                continue;
            };
            let flip_of = |a: &Action| matches!(a, Action::Input { dev: d, ch: c, .. } if d == dev && c == ch);
            let next = (i + 1..events.len()).find(|j| flip_of(&events[*j].action));
            let counter = (0..events.len())
                .filter(|k| one_pulse_more(&events[*k].action, dev, *ch).is_some())
                .min_by_key(|k| k.abs_diff(i));
            let mut tries = Vec::new();
            match counter {
                Some(k) => {
                    for drop in [next.map(|j| vec![i, j]), Some(vec![i])]
                        .into_iter()
                        .flatten()
                    {
                        let mut fewer = events.clone();
                        if let Some(more) = one_pulse_more(&events[k].action, dev, *ch) {
                            fewer[k].action = more;
                        }
                        for d in drop.iter().rev() {
                            fewer.remove(*d);
                        }
                        tries.push(fewer);
                    }
                }
                None => {
                    if let Some(j) = next {
                        let mut fewer = events.clone();
                        fewer.remove(j);
                        fewer[i].action = Action::Pulse {
                            dev: dev.clone(),
                            ch: *ch,
                            n: 1,
                        };
                        tries.push(fewer);
                    }
                }
            }
            let mut folded = false;
            for events in tries {
                if self.try_candidate(self.with_events(events)) {
                    changed = true;
                    folded = true;
                    break;
                }
            }
            if !folded {
                i += 1;
            }
        }
        changed
    }

    /// Replaces each event by a simpler one where that still fails.
    fn simplify_events(&mut self) -> bool {
        let mut changed = false;
        let mut i = 0;
        while i < self.best.plan.events.len() && !self.exhausted {
            let options = self.best.plan.events[i].action.simpler();
            for action in options {
                let mut events = self.best.plan.events.clone();
                if let Some(e) = events.get_mut(i) {
                    e.action = action;
                }
                if self.try_candidate(self.with_events(events)) {
                    changed = true;
                    break;
                }
            }
            i += 1;
        }
        changed
    }

    /// Shortens each wait (and the one before the end), moving everything after it earlier.
    fn shorten_waits(&mut self) -> bool {
        let mut changed = false;
        let mut i = 0;
        while i <= self.best.plan.events.len() && !self.exhausted {
            let events = &self.best.plan.events;
            let before = if i == 0 {
                Duration::ZERO
            } else {
                events.get(i - 1).map_or(Duration::ZERO, |e| e.at)
            };
            let at = events.get(i).map_or(self.best.horizon, |e| e.at);
            let gap = at.saturating_sub(before);
            let q = self.quantum.as_nanos().max(1);
            let round = |d: Duration| {
                let n = d.as_nanos() / q * q;
                Duration::from_nanos(u64::try_from(n).unwrap_or(u64::MAX))
            };
            let mut shorter: Vec<Duration> = [Duration::ZERO, gap / 4, gap / 2, gap * 3 / 4]
                .into_iter()
                .map(round)
                .collect();
            if i == self.best.plan.events.len() {
                // The end: no sooner than one margin after the last event.
                shorter = shorter.into_iter().map(|g| g.max(self.margin)).collect();
            }
            shorter.retain(|g| *g < gap);
            shorter.dedup();
            for g in shorter {
                let cut = gap - g;
                let mut c = self.best.clone();
                for e in c.plan.events.iter_mut().skip(i) {
                    e.at = e.at.saturating_sub(cut);
                }
                c.horizon = c.horizon.saturating_sub(cut);
                if self.try_candidate(c) {
                    changed = true;
                    break;
                }
            }
            i += 1;
        }
        changed
    }
}

/// `action` counting one pulse more, if it is a counter event of `dev`'s DI`ch`.
fn one_pulse_more(action: &Action, dev: &str, ch: u8) -> Option<Action> {
    match action {
        Action::Pulse { dev: d, ch: c, n } if &**d == dev && *c == ch => Some(Action::Pulse {
            dev: d.clone(),
            ch,
            n: n.saturating_add(1),
        }),
        Action::CounterTo {
            dev: d,
            ch: c,
            value,
        } if &**d == dev && *c == ch && *value < u16::MAX => Some(Action::CounterTo {
            dev: d.clone(),
            ch,
            value: value + 1,
        }),
        _ => None,
    }
}

/// Shrinks `candidate` (whose replay is `replay`); `fails` replays a candidate and says how it
/// failed the same check, or `None`. `margin` is how long a run goes on past the failure (a
/// scan period or two); waits are shortened in whole steps of `quantum`.
pub fn shrink<O: Replay>(
    candidate: Candidate,
    replay: O,
    fails: impl FnMut(&Candidate) -> Option<O>,
    budget: Budget,
    margin: Duration,
    quantum: Duration,
) -> Shrunk<O> {
    let mut best = candidate;
    best.plan.events.truncate(replay.played());
    best.horizon = best.horizon.min(replay.at().saturating_add(margin));
    let mut s = Shrinker {
        best,
        replay,
        fails,
        replays: 0,
        budget,
        began: Instant::now(),
        exhausted: false,
        margin,
        quantum,
    };
    loop {
        let dropped = s.drop_events();
        let paired = s.drop_pairs();
        let folded = s.fold_pulses();
        let simpler = s.simplify_events();
        let shorter = s.shorten_waits();
        if !(dropped || paired || folded || simpler || shorter) || s.exhausted {
            break;
        }
    }
    Shrunk {
        candidate: s.best,
        replay: s.replay,
        replays: s.replays,
        exhausted: s.exhausted,
    }
}

#[cfg(test)]
mod tests {
    use super::super::plan::{Action, StartPoint};
    use super::*;
    use std::sync::Arc;

    /// A made-up failure: DI1 on, then (at least 300 ms later) DI2 on, with DI1 still on.
    #[derive(Debug, Clone)]
    struct Seen {
        at: Duration,
        played: usize,
    }

    impl Replay for Seen {
        fn at(&self) -> Duration {
            self.at
        }
        fn played(&self) -> usize {
            self.played
        }
    }

    fn fails(c: &Candidate) -> Option<Seen> {
        let mut di1_since = None;
        for (i, e) in c.plan.events.iter().enumerate() {
            if e.at >= c.horizon {
                return None;
            }
            if let Action::Input { ch, on, .. } = e.action {
                match (ch, on) {
                    (1, true) => di1_since = di1_since.or(Some(e.at)),
                    (1, false) => di1_since = None,
                    (2, true)
                        if di1_since.is_some_and(|t| e.at >= t + Duration::from_millis(300)) =>
                    {
                        return Some(Seen {
                            at: e.at + Duration::from_millis(20),
                            played: i + 1,
                        });
                    }
                    _ => {}
                }
            }
        }
        None
    }

    /// A made-up failure that needs DI1 on at 300 ms or more before DI2 goes on, where a lone
    /// press of S5 (without its release) or a lone release (without its press) hides it: a
    /// press and its release shrink away only together.
    fn fails_unless_s5_half_there(c: &Candidate) -> Option<Seen> {
        let (mut presses, mut releases) = (0, 0);
        for e in &c.plan.events {
            match e.action {
                Action::Press { .. } => presses += 1,
                Action::Release { .. } => releases += 1,
                _ => {}
            }
        }
        if presses != releases {
            return None;
        }
        fails(c)
    }

    /// Shrinks `events` (a run of `horizon` from the base time) that `fails`, with a budget
    /// it never reaches.
    fn shrunk(
        events: Vec<Event>,
        horizon: Duration,
        fails: impl Fn(&Candidate) -> Option<Seen>,
    ) -> Shrunk<Seen> {
        let c = Candidate {
            plan: Plan {
                start: StartPoint {
                    wall: chrono::DateTime::parse_from_rfc3339("2026-03-28T12:00:00Z").unwrap(),
                    zone: "UTC".into(),
                },
                events,
            },
            horizon,
        };
        let first = fails(&c).expect("fails");
        let budget = Budget {
            replays: 10_000,
            time: Duration::from_secs(60),
        };
        shrink(
            c,
            first,
            fails,
            budget,
            Duration::from_millis(40),
            Duration::from_millis(1),
        )
    }

    #[test]
    fn a_press_and_its_release_far_apart_shrink_away_together() {
        // Fails without drop_pairs: neither can go alone, and they are never in one chunk.
        let dev: Arc<str> = Arc::from("io");
        let panel: Arc<str> = Arc::from("panel");
        let s5 = crate::protocol::trc1000::Switch::new(5).unwrap();
        let input = |ms: u64, ch: u8| Event {
            at: Duration::from_millis(ms),
            action: Action::Input {
                dev: dev.clone(),
                ch,
                on: true,
            },
        };
        let events = vec![
            Event {
                at: Duration::from_millis(10),
                action: Action::Press {
                    dev: panel.clone(),
                    switch: s5,
                },
            },
            input(20, 1),
            input(30, 3),
            input(500, 2),
            Event {
                at: Duration::from_millis(600),
                action: Action::Release {
                    dev: panel.clone(),
                    switch: s5,
                },
            },
        ];
        // The failure at DI2 comes before the release is played, so count them all played.
        let played = |c: &Candidate| {
            fails_unless_s5_half_there(c).map(|s| Seen {
                at: s.at,
                played: c.plan.events.len(),
            })
        };
        let s = shrunk(events, Duration::from_secs(2), played);
        assert_eq!(
            s.candidate.plan.events.len(),
            2,
            "{:?}",
            s.candidate.plan.events
        );
    }

    /// A made-up failure: DI0's count (carried, pulsed, and one a rising edge) reaches 300.
    fn counts_to_300(c: &Candidate) -> Option<Seen> {
        let (mut count, mut on) = (0u32, false);
        for (i, e) in c.plan.events.iter().enumerate() {
            match e.action {
                Action::CounterTo { value, .. } => count = u32::from(value),
                Action::Pulse { n, .. } => count += n,
                Action::Input { on: level, .. } => {
                    count += u32::from(level && !on);
                    on = level;
                }
                _ => {}
            }
            if count >= 300 {
                return Some(Seen {
                    at: e.at + Duration::from_millis(20),
                    played: i + 1,
                });
            }
        }
        None
    }

    #[test]
    fn bounced_edges_after_a_count_fold_into_it() {
        // Without fold_pulses this stays at 8 events: no flip can go alone, and the count
        // is never simplified upward.
        let dev: Arc<str> = Arc::from("io");
        let mut events = vec![Event {
            at: Duration::ZERO,
            action: Action::CounterTo {
                dev: dev.clone(),
                ch: 0,
                value: 296,
            },
        }];
        for i in 0..7u64 {
            events.push(Event {
                at: Duration::from_millis(i),
                action: Action::Input {
                    dev: dev.clone(),
                    ch: 0,
                    on: i % 2 == 0,
                },
            });
        }
        let s = shrunk(events, Duration::from_secs(2), counts_to_300);
        let e = &s.candidate.plan.events;
        assert_eq!(e.len(), 1, "{e:?}");
        assert!(
            matches!(e[0].action, Action::CounterTo { value: 300, .. }),
            "{e:?}"
        );
    }

    #[test]
    fn a_long_run_shrinks_to_the_two_events_that_matter_as_early_as_they_can_be() {
        let dev: Arc<str> = Arc::from("io");
        let mut events = Vec::new();
        for i in 0..60u64 {
            let ch = (i % 5) as u8;
            events.push(Event {
                at: Duration::from_millis(500 * i + 7),
                action: Action::Input {
                    dev: dev.clone(),
                    ch,
                    on: i % 3 != 0,
                },
            });
        }
        let s = shrunk(events, Duration::from_secs(60), fails);
        assert!(!s.exhausted);
        let e = &s.candidate.plan.events;
        assert_eq!(e.len(), 2, "{e:?}");
        assert!(matches!(
            e[0].action,
            Action::Input {
                ch: 1,
                on: true,
                ..
            }
        ));
        assert!(matches!(
            e[1].action,
            Action::Input {
                ch: 2,
                on: true,
                ..
            }
        ));
        assert_eq!(e[0].at, Duration::ZERO);
        let gap = e[1].at - e[0].at;
        assert!(
            gap >= Duration::from_millis(300) && gap < Duration::from_millis(400),
            "{gap:?}"
        );
        assert!(s.candidate.horizon <= e[1].at + Duration::from_millis(60));
    }
}
