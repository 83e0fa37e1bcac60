//! The faults a run's field may bring (with `--no-faults`, none), each kind with its weight in
//! `FAULT_WEIGHTS`: a device lost and restored (its line silent for about its grace time, a
//! moment, much longer, or for good), answers lost, garbled, late (a slow answer within the
//! driver's timeout, or one past it that lands in a later exchange) or sent twice, on either
//! device; either device power cycled behind the runner's back; the host stalling for any
//! length (a tick, a watchdog's timeout, the grace time, minutes); the wall clock stepping
//! across cron times, by an hour as at a DST change, or by seconds to months either way; and a
//! stop signal.

use super::field::{next_cron, Gen};
use super::plan::Action;
use super::profile::Kind;
use crate::time::zone::Zone;
use chrono::TimeDelta;
use std::time::Duration;

/// A kind of fault the search plays.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultKind {
    /// A device's line silent for a while (`r.fail`, then `r.restore`).
    Lose,
    /// Answers lost.
    Drop,
    /// Answers garbled.
    Garble,
    /// Answers late or slow.
    Late,
    /// Answers sent twice.
    Duplicate,
    /// A device power cycled.
    PowerCycle,
    /// The host stalled.
    Stall,
    /// The wall clock stepped.
    WallStep,
    /// A stop signal.
    Stop,
}

/// How often each kind of fault comes, against the others' weights.
pub const FAULT_WEIGHTS: [(FaultKind, u32); 9] = [
    (FaultKind::Lose, 20),
    (FaultKind::Drop, 14),
    (FaultKind::Garble, 12),
    (FaultKind::Late, 12),
    (FaultKind::Duplicate, 5),
    (FaultKind::PowerCycle, 10),
    (FaultKind::Stall, 13),
    (FaultKind::WallStep, 13),
    (FaultKind::Stop, 1),
];

impl Gen<'_> {
    fn kind_of(&self, dev: usize) -> Option<Kind> {
        self.profile.devices.get(dev).map(|d| d.kind)
    }

    fn fault_kind(&mut self) -> FaultKind {
        let total: u32 = FAULT_WEIGHTS.iter().map(|(_, w)| w).sum();
        let mut x = self.rng.u32(0..total);
        for (kind, w) in FAULT_WEIGHTS {
            if x < w {
                return kind;
            }
            x -= w;
        }
        FaultKind::Drop
    }

    /// How late an answer comes: within the driver's timeout (slow), just past it (it lands
    /// in the retry's window), or a few timeouts late.
    fn lateness(&mut self, timeout: Duration) -> Duration {
        let q = super::field::quantum(self.profile.period);
        match self.rng.u8(0..10) {
            0..=3 => self.up_to(timeout).max(q),
            4..=7 => timeout + self.up_to(timeout / 4).max(q),
            _ => timeout + self.up_to(timeout.saturating_mul(3)),
        }
    }

    fn online_device(&mut self) -> Option<usize> {
        let t = self.t;
        let online: Vec<usize> = (0..self.profile.devices.len())
            .filter(|i| self.lost_until.get(i).map_or(true, |u| *u <= t))
            .collect();
        (!online.is_empty()).then(|| online[self.rng.usize(0..online.len())])
    }

    fn lose(&mut self, dev: usize) {
        let grace = self.profile.grace;
        let period = self.profile.period;
        let lost_for = match self.rng.u8(0..10) {
            // About the grace time: just within it, or just past it.
            0..=3 => (grace + self.up_to(period.saturating_mul(4))).saturating_sub(period * 2),
            4..=6 => self.up_to(grace),
            7..=8 => grace + self.up_to(grace.saturating_mul(2) + Duration::from_secs(2)),
            _ => Duration::MAX,
        };
        let name = self.name(dev);
        let t = self.t;
        self.push(t, Action::Fail { dev: name.clone() });
        let back = t.saturating_add(lost_for);
        if back < self.profile.run_for {
            self.push(back, Action::Restore { dev: name });
        }
        self.lost_until.insert(dev, back);
    }

    fn stall(&mut self) {
        let period = self.profile.period;
        let watchdogs: Vec<Duration> = self
            .profile
            .devices
            .iter()
            .filter_map(|d| d.watchdog)
            .collect();
        let by = if !watchdogs.is_empty() && self.rng.bool() {
            let w = watchdogs[self.rng.usize(0..watchdogs.len())];
            (w + self.up_to(period.saturating_mul(4))).saturating_sub(period * 2)
        } else {
            match self.rng.u8(0..10) {
                0..=4 => Duration::from_millis(50) + self.up_to(Duration::from_millis(1500)),
                5..=7 => {
                    let grace = self.profile.grace;
                    (grace + self.up_to(period.saturating_mul(4))).saturating_sub(period * 2)
                }
                _ => Duration::from_secs(2) + self.up_to(Duration::from_secs(180)),
            }
        };
        self.push(self.t, Action::Stall { by });
        self.t += by;
    }

    /// A wall-clock step: with cron timers, to just before or just past the next cron time
    /// (or back across the last); otherwise minutes to hours either way.
    fn wall_step(&mut self) {
        let zone = super::exec::zone_of(&self.start.zone).unwrap_or(Zone::utc());
        let elapsed = TimeDelta::from_std(self.t).unwrap_or(TimeDelta::zero());
        let wall = self.start.wall.to_utc() + elapsed + TimeDelta::seconds(self.wall_steps);
        let seconds = match next_cron(&self.profile.crons, wall, zone) {
            Some(next) if self.rng.f64() < 0.8 => {
                let ahead = (next - wall).num_seconds().max(0);
                let step = ahead + self.rng.i64(-1..=2);
                if self.rng.f64() < 0.2 {
                    -step.max(1)
                } else {
                    step.max(1)
                }
            }
            _ => {
                let size = match self.rng.u8(0..10) {
                    0..=2 => 3600, // a DST change, or a zone set wrong by an hour
                    3..=5 => self.rng.i64(60..=7200),
                    6..=7 => self.rng.i64(1..60),
                    _ => self.rng.i64(7200..=400 * 86_400),
                };
                if self.rng.bool() {
                    size
                } else {
                    -size
                }
            }
        };
        self.wall_steps += seconds;
        self.push(self.t, Action::WallStep { seconds });
    }

    /// One fault at the current time.
    pub(super) fn fault_event(&mut self) {
        let Some(dev) = self.online_device() else {
            return;
        };
        let name = self.name(dev);
        let timeout = self
            .profile
            .devices
            .get(dev)
            .map_or(Duration::from_millis(100), |d| d.timeout);
        let n = self.rng.u32(1..5);
        match self.fault_kind() {
            FaultKind::Lose => self.lose(dev),
            FaultKind::Drop => self.push(self.t, Action::DropAnswers { dev: name, n }),
            FaultKind::Garble => self.push(self.t, Action::GarbleAnswers { dev: name, n }),
            FaultKind::Late => {
                let by = self.lateness(timeout);
                self.push(self.t, Action::LateAnswers { dev: name, n, by });
            }
            FaultKind::Duplicate if self.kind_of(dev) == Some(Kind::C29u) => {
                self.push(self.t, Action::DuplicateAnswers { dev: name, n });
            }
            // A USB packet never arrives twice: a panel loses one instead.
            FaultKind::Duplicate => self.push(self.t, Action::DropAnswers { dev: name, n }),
            FaultKind::PowerCycle => self.push(self.t, Action::PowerCycle { dev: name }),
            FaultKind::Stall => self.stall(),
            FaultKind::WallStep => self.wall_step(),
            FaultKind::Stop => {
                self.push(self.t, Action::Stop);
                self.stopped = true;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::field::generate;
    use super::super::profile::Profile;
    use super::*;
    use crate::config::RigConfig;

    #[test]
    fn faults_come_with_their_ends_and_a_stop_ends_the_plan() {
        let config = RigConfig::simulated_default();
        let mut p = Profile::new(
            &config,
            "",
            Duration::from_millis(20),
            Duration::from_secs(60),
        );
        p.crons.insert("0 */5 * * * *".into());
        let (mut kinds, mut stops) = (std::collections::HashSet::new(), 0);
        let mut seen = std::collections::BTreeSet::new();
        for seed in 0..300 {
            let plan = generate(&p, seed, true);
            let mut lost = std::collections::BTreeSet::new();
            for (i, e) in plan.events.iter().enumerate() {
                kinds.insert(std::mem::discriminant(&e.action));
                match &e.action {
                    Action::PowerCycle { dev } => seen.insert(format!("{dev} power cycle")),
                    Action::GarbleAnswers { dev, .. } => seen.insert(format!("{dev} garbled")),
                    Action::LateAnswers { dev, by, .. } => {
                        let past = if *by > Duration::from_millis(250) {
                            "past"
                        } else {
                            "in"
                        };
                        seen.insert(format!("{dev} late {past}"))
                    }
                    Action::DuplicateAnswers { dev, .. } => seen.insert(format!("{dev} twice")),
                    Action::Stall { by } if *by > Duration::from_secs(10) => {
                        seen.insert("long stall".into())
                    }
                    Action::WallStep { seconds } if seconds.abs() > 86_400 => {
                        seen.insert("step of days".into())
                    }
                    _ => false,
                };
                match &e.action {
                    Action::Fail { dev } => assert!(lost.insert(dev.clone()), "lost twice"),
                    Action::Restore { dev } => assert!(lost.remove(dev)),
                    Action::Stop => {
                        stops += 1;
                        assert_eq!(i, plan.events.len() - 1, "nothing after a stop");
                    }
                    _ => {}
                }
            }
        }
        assert!(stops > 0);
        for what in [
            "panel power cycle",
            "io power cycle",
            "panel garbled",
            "panel late in",
            "panel late past",
            "io late past",
            "io twice",
            "long stall",
            "step of days",
        ] {
            assert!(seen.contains(what), "never {what}: {seen:?}");
        }
        assert!(
            !seen.contains("panel twice"),
            "a USB packet never comes twice"
        );
        // Fail, Restore, Drop, Garble, Late, Duplicate, PowerCycle, Stall, WallStep, Stop and
        // the field's.
        assert!(kinds.len() >= 16, "{} kinds of event", kinds.len());
    }
}
