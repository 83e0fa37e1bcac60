//! The faults a run's field may bring (with `--no-faults`, none): a device lost and restored
//! (lost for about its grace time, a moment, much longer, or for good), answers lost or
//! garbled, a module power cycled behind the runner's back, the host stalling long enough for
//! a watchdog to expire, the wall clock stepping across cron times, and a stop signal.

use super::field::{next_cron, Gen};
use super::plan::Action;
use super::profile::Kind;
use crate::time::zone::Zone;
use chrono::TimeDelta;
use std::time::Duration;

impl Gen<'_> {
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
            Duration::from_millis(50) + self.up_to(Duration::from_millis(1500))
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
                let size = self.rng.i64(60..=7200);
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
        let kind = self.profile.devices.get(dev).map(|d| d.kind);
        match self.rng.u8(0..100) {
            0..=24 => self.lose(dev),
            25..=44 => {
                let n = self.rng.u32(1..5);
                self.push(self.t, Action::DropAnswers { dev: name, n });
            }
            45..=59 if kind == Some(Kind::C29u) => {
                let n = self.rng.u32(1..5);
                self.push(self.t, Action::GarbleAnswers { dev: name, n });
            }
            60..=69 if kind == Some(Kind::C29u) => {
                self.push(self.t, Action::PowerCycle { dev: name });
            }
            70..=84 => self.stall(),
            85..=98 => self.wall_step(),
            99 => {
                self.push(self.t, Action::Stop);
                self.stopped = true;
            }
            _ => {
                let n = self.rng.u32(1..5);
                self.push(self.t, Action::DropAnswers { dev: name, n });
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
        for seed in 0..300 {
            let plan = generate(&p, seed, true);
            let mut lost = std::collections::BTreeSet::new();
            for (i, e) in plan.events.iter().enumerate() {
                kinds.insert(std::mem::discriminant(&e.action));
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
        // Fail, Restore, Drop, Garble, PowerCycle, Stall, WallStep, Stop and the field's.
        assert!(kinds.len() >= 14, "{} kinds of event", kinds.len());
    }
}
