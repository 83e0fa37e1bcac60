//! Plays a plan on the simulated rig in virtual time, as a scenario test would (the same
//! `advance` between events), and watches every tick for findings. Records the steps it took,
//! so the test file that reproduces a finding does exactly the same.

use super::checks::{Finding, Watch};
use super::coverage::Coverage;
use super::plan::{Action, Plan};
use super::profile::Observed;
use crate::config::RigConfig;
use crate::runtime::devices::FieldError;
use crate::runtime::runner::EndReason;
use crate::script::builder::RigBuilder;
use crate::script::reads::Item;
use crate::script::rig::{Rig, RigError};
use crate::sim::faults::answer::AnswerFault;
use crate::time::clock::{Clock, VirtualClock};
use crate::time::zone::Zone;
use chrono::{TimeDelta, Utc};
use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

/// The script under verification and its rig.
#[derive(Debug, Clone)]
pub struct Target {
    /// The script's text.
    pub source: String,
    /// The script's path as messages name it.
    pub file: String,
    /// The script's file (its counterexample's test loads it from there).
    pub script: PathBuf,
    /// The rig.toml it was given, if one was (the test loads it too).
    pub config_file: Option<PathBuf>,
    /// The rig (every device simulated; no records file).
    pub config: RigConfig,
    /// Operations per handler call.
    pub budget: u64,
    /// How long each run lasts.
    pub run_for: Duration,
    /// Counter or rotary → the values the script's text compares it with (`Facts`).
    pub compared: BTreeMap<Item, BTreeSet<i64>>,
}

/// One step of a run as the test file writes it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Step {
    /// `r.advance(d)`.
    Advance(Duration),
    /// The action (a counter carried to its wrap is written as the pulses it took).
    Act(Action),
    /// `r.end()`: the run ended at `--for`.
    End,
}

/// What a run came to.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// The first finding, if any.
    pub finding: Option<Finding>,
    /// The steps taken, up to the finding.
    pub steps: Vec<Step>,
    /// How many events of the plan were played.
    pub played: usize,
    /// What the run exercised (when asked).
    pub coverage: Option<Coverage>,
    /// What the run saw of the script.
    pub observed: Observed,
}

/// Why a run could not be played.
#[derive(Debug, thiserror::Error)]
pub enum ExecError {
    /// The rig did not start.
    #[error(transparent)]
    Start(Box<RigError>),
    /// The plan named something the rig does not have.
    #[error("the field of this run does not fit the rig: {0}")]
    Field(#[from] FieldError),
    /// The plan's zone is unknown.
    #[error("{0}")]
    Zone(String),
}

/// What to keep besides the finding.
#[derive(Debug, Clone, Copy)]
pub struct Keep {
    /// Count what the run exercised.
    pub coverage: bool,
    /// Note timers and watchdogs after every tick (for the profile).
    pub observe: bool,
}

/// A run being played: the rig, its clock and what is watched (the exhaustive mode drives one
/// choice at a time through it, `exhaustive`).
pub(super) struct Player<'a> {
    pub(super) rig: Rig,
    pub(super) clock: VirtualClock,
    watch: Watch,
    steps: Vec<Step>,
    coverage: Option<Coverage>,
    observed: Observed,
    keep: Keep,
    target: &'a Target,
    /// Handler id of each timer → the instant after the tick it was first seen in (kept when
    /// `Some`: its deadlines follow from it and its kind).
    pub(super) timers_seen: Option<BTreeMap<u64, Duration>>,
}

/// The zone a plan names, read as the test file's `rig_at` reads it.
pub fn zone_of(name: &str) -> Result<Zone, ExecError> {
    Zone::parse(name).map_err(|e| ExecError::Zone(e.to_string()))
}

impl Player<'_> {
    /// Notes the timers the rig has now that were not seen before (`timers_seen`).
    fn note_timers(&mut self) {
        let Some(seen) = self.timers_seen.as_mut() else {
            return;
        };
        let now = self.clock.now();
        let rt = self.rig.runner.runtime().borrow();
        for r in rt.handlers().list() {
            if matches!(r.source, crate::runtime::handlers::Source::Timer(_)) {
                seen.entry(r.id).or_insert(now);
            }
        }
    }

    /// Runs the ticks due up to `target` (`Runner::step_toward`, as `Runner::advance`), watching each; the finding,
    /// if one comes.
    pub(super) fn advance_to(&mut self, target: Duration) -> Option<Finding> {
        let from = self.clock.now();
        let mut ticked = false;
        while let Some(deadline) = self.rig.runner.step_toward(target) {
            ticked = true;
            if let Some(c) = self.coverage.as_mut() {
                c.after_tick(&self.rig);
            }
            if self.keep.observe {
                self.observed.look(&self.rig);
            }
            self.note_timers();
            let now = self.clock.now();
            let found = self.watch.after_tick(&self.rig, now);
            let ended = self.rig.runner.status().is_some();
            if found.is_some() || ended {
                self.steps
                    .push(Step::Advance(deadline.max(from).saturating_sub(from)));
                return found.or_else(|| self.watch.after_end(&self.rig, now));
            }
        }
        // The planned wait, not how far the clock moved: a tick that ran past `target` would
        // make the longer wait run the catch-up tick before the next event when replayed.
        // `r.advance("0s")` still runs the ticks that are due.
        let by = target.saturating_sub(from);
        if !by.is_zero() || ticked {
            self.steps.push(Step::Advance(by));
        }
        None
    }

    pub(super) fn apply(&mut self, action: &Action) -> Result<(), FieldError> {
        act(&mut self.rig, &self.clock, action, &mut self.steps)
    }

    pub(super) fn finish(mut self, finding: Option<Finding>, played: usize) -> Outcome {
        if let Some(c) = self.coverage.as_mut() {
            c.finish(&self.rig);
        }
        if let Some(c) = self.rig.runner.program().coverage() {
            self.observed.reads.union(&c.script_reads);
            for r in c.invariant_reads.values() {
                self.observed.reads.union(r);
            }
        }
        self.observed.look(&self.rig);
        Outcome {
            finding,
            steps: self.steps,
            played,
            coverage: self.coverage,
            observed: self.observed,
        }
    }
}

/// Plays `action` on `rig`'s simulated field (or its clock, or its runner), adding to `steps`
/// what a test file does to the same effect: the one way `verify` and `replay` act on a rig.
pub fn act(
    rig: &mut Rig,
    clock: &VirtualClock,
    action: &Action,
    steps: &mut Vec<Step>,
) -> Result<(), FieldError> {
    let sim = &rig.sim;
    let step = match action {
        Action::Input { dev, ch, on } => sim.set_input(dev, *ch, *on).map(|()| true),
        Action::Inputs { dev, byte } => sim.set_inputs(dev, *byte).map(|()| true),
        Action::Pulse { dev, ch, n } => sim.pulse(dev, *ch, *n).map(|()| true),
        Action::CounterTo { dev, ch, value } => {
            let now = sim.counter(dev, *ch)?;
            let n = u32::from(value.saturating_sub(now));
            if n > 0 {
                sim.pulse(dev, *ch, n)?;
                steps.push(Step::Act(Action::Pulse {
                    dev: dev.clone(),
                    ch: *ch,
                    n,
                }));
            }
            Ok(false)
        }
        Action::Press { dev, switch } => sim.set_switch(dev, switch.name(), true).map(|()| true),
        Action::Release { dev, switch } => sim.set_switch(dev, switch.name(), false).map(|()| true),
        Action::Turn {
            dev,
            rotary,
            half_turns,
        } => sim.turn(dev, rotary.name(), *half_turns).map(|()| true),
        Action::Fail { dev } => sim.set_gone(dev, true).map(|()| true),
        Action::Restore { dev } => sim.set_gone(dev, false).map(|()| true),
        Action::DropAnswers { dev, n } => sim
            .fault_answers(dev, AnswerFault::Drop, *n as usize)
            .map(|_| true),
        Action::GarbleAnswers { dev, n } => sim
            .fault_answers(dev, AnswerFault::Garble, *n as usize)
            .map(|_| true),
        Action::LateAnswers { dev, n, by } => sim
            .fault_answers(dev, AnswerFault::Late(*by), *n as usize)
            .map(|_| true),
        Action::DuplicateAnswers { dev, n } => sim
            .fault_answers(dev, AnswerFault::Duplicate, *n as usize)
            .map(|_| true),
        Action::PowerCycle { dev } => sim.power_cycle(dev).map(|()| true),
        Action::Stall { by } => {
            clock.advance(*by);
            Ok(true)
        }
        Action::WallStep { seconds } => {
            clock.step_wall(TimeDelta::seconds(*seconds));
            Ok(true)
        }
        Action::Stop => {
            rig.runner.signal_stop();
            Ok(true)
        }
    }?;
    if step {
        steps.push(Step::Act(action.clone()));
    }
    Ok(())
}

/// A fresh rig for `target` started where `start` says, its first tick (the baseline
/// reading) not yet run.
pub(super) fn begin<'a>(
    target: &'a Target,
    start: &super::plan::StartPoint,
    keep: Keep,
) -> Result<Player<'a>, ExecError> {
    let zone = zone_of(&start.zone)?;
    let clock = VirtualClock::new(start.wall.with_timezone(&Utc));
    let rig = RigBuilder::from_config(target.config.clone())
        .simulated()
        .clock(Arc::new(clock.clone()))
        .zone(zone)
        .log_to_stderr(false)
        .quiet()
        .budget(target.budget)
        .prepare(|p| p.track_coverage())
        .start(&target.source, &target.file)
        .map_err(|e| ExecError::Start(Box::new(e)))?;
    let mut player = Player {
        coverage: keep
            .coverage
            .then(|| Coverage::start(&rig, &target.compared)),
        rig,
        clock,
        watch: Watch::new(&target.config),
        steps: Vec::new(),
        observed: Observed::default(),
        keep,
        target,
        timers_seen: None,
    };
    player.observed.look(&player.rig);
    Ok(player)
}

impl Player<'_> {
    /// What the top level found, before any tick.
    pub(super) fn first_finding(&mut self) -> Option<Finding> {
        let now = self.clock.now();
        self.watch.after_tick(&self.rig, now)
    }

    /// Ends the run here (as at `--for`) and checks what must hold after the end.
    pub(super) fn end(mut self) -> Outcome {
        if self.rig.runner.status().is_none() {
            self.rig
                .runner
                .finish(EndReason::Finished("verify: end of the run".into()));
            self.steps.push(Step::End);
        }
        let now = self.clock.now();
        let f = self.watch.after_end(&self.rig, now);
        self.finish(f, 0)
    }
}

/// Plays `plan` on a fresh rig for `target.run_for`; stops at the first finding.
pub fn execute(target: &Target, plan: &Plan, keep: Keep) -> Result<Outcome, ExecError> {
    let _ends = crate::guardian::pulse::EndsLoop;
    let mut player = begin(target, &plan.start, keep)?;
    if let Some(f) = player.first_finding() {
        return Ok(player.finish(Some(f), 0));
    }
    let end = player.target.run_for;
    let mut played = 0;
    for event in &plan.events {
        if event.at >= end {
            break;
        }
        if let Some(f) = player.advance_to(event.at.max(player.clock.now())) {
            return Ok(player.finish(Some(f), played));
        }
        if player.rig.runner.status().is_some() {
            break;
        }
        player.apply(&event.action)?;
        played += 1;
        if event.action == Action::Stop {
            let now = player.clock.now();
            let f = player.watch.after_end(&player.rig, now);
            return Ok(player.finish(f, played));
        }
    }
    if player.rig.runner.status().is_none() {
        if let Some(f) = player.advance_to(end.max(player.clock.now())) {
            return Ok(player.finish(Some(f), played));
        }
    }
    if player.rig.runner.status().is_none() {
        player
            .rig
            .runner
            .finish(EndReason::Finished("verify: end of the run".into()));
        player.steps.push(Step::End);
    }
    let now = player.clock.now();
    let f = player.watch.after_end(&player.rig, now);
    Ok(player.finish(f, played))
}

#[cfg(test)]
mod tests {
    use super::super::checks::Property;
    use super::super::plan::{Event, StartPoint};
    use super::*;
    use crate::protocol::trc1000::Switch;

    const SCRIPT: &str = r#"
let io = device("io");
let panel = device("panel");
panel.on_press("S12", || if io.inputs == 0x0F { io.outputs = 1; });
io.on_fall(3, || {});
invariant("power only with DI3 closed", || io.outputs == 0 || io.input(3));
"#;

    fn target() -> Target {
        Target {
            source: SCRIPT.into(),
            file: "t.rhai".into(),
            script: "t.rhai".into(),
            config_file: None,
            config: RigConfig::simulated_default(),
            budget: 100_000,
            run_for: Duration::from_secs(2),
            compared: BTreeMap::new(),
        }
    }

    fn plan() -> Plan {
        let io: Arc<str> = Arc::from("io");
        Plan {
            start: StartPoint {
                wall: chrono::DateTime::parse_from_rfc3339("2026-03-28T12:00:00Z").unwrap(),
                zone: "UTC".into(),
            },
            events: vec![
                Event {
                    at: Duration::ZERO,
                    action: Action::Inputs {
                        dev: io.clone(),
                        byte: 0x0F,
                    },
                },
                Event {
                    at: Duration::ZERO,
                    action: Action::Press {
                        dev: Arc::from("panel"),
                        switch: Switch::new(12).unwrap(),
                    },
                },
                Event {
                    at: Duration::from_millis(25),
                    action: Action::Input {
                        dev: io,
                        ch: 3,
                        on: false,
                    },
                },
                Event {
                    at: Duration::from_millis(500),
                    action: Action::Stop,
                },
            ],
        }
    }

    #[test]
    fn a_plan_plays_the_same_every_time_and_stops_at_the_finding() {
        let keep = Keep {
            coverage: true,
            observe: true,
        };
        let a = execute(&target(), &plan(), keep).unwrap();
        let b = execute(&target(), &plan(), keep).unwrap();
        let f = a.finding.clone().expect("the invariant is found false");
        assert_eq!(
            f.check,
            Property::Invariant("power only with DI3 closed".into())
        );
        assert_eq!(f.at, Duration::from_millis(40));
        assert_eq!(a.played, 3, "the stop after the finding is not played");
        assert_eq!(a.steps, b.steps);
        assert_eq!(b.finding, Some(f));
        // The first tick (the baseline reading) runs before the events at 0 ms, so the test
        // file must say so, or its first reading would already see S12 held.
        assert_eq!(a.steps[0], Step::Advance(Duration::ZERO));
        assert_eq!(
            a.steps.last(),
            Some(&Step::Advance(Duration::from_millis(15)))
        );
        let c = a.coverage.expect("coverage kept");
        assert_eq!(c.fired.get("panel.on_press S12"), Some(&1));
        assert_eq!(c.fired.get("io.on_fall DI3"), Some(&1));
        assert!(a
            .observed
            .reads
            .contains(0, crate::script::reads::Item::Input(3)));
    }

    #[test]
    fn a_counter_carried_to_its_wrap_is_written_as_the_pulses_it_took() {
        let mut p = plan();
        p.events = vec![Event {
            at: Duration::from_millis(10),
            action: Action::CounterTo {
                dev: Arc::from("io"),
                ch: 2,
                value: 65532,
            },
        }];
        let keep = Keep {
            coverage: false,
            observe: false,
        };
        let o = execute(&target(), &p, keep).unwrap();
        assert!(o.finding.is_none(), "{:?}", o.finding);
        assert!(o.steps.contains(&Step::Act(Action::Pulse {
            dev: Arc::from("io"),
            ch: 2,
            n: 65532
        })));
        assert_eq!(o.steps.last(), Some(&Step::End));
    }
}
