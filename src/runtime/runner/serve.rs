//! A run served to askers from outside the loop: the control queue answered, the snapshot made
//! at most once a tick.

use super::contract::Program;
use super::remote::Waiting;
use super::{Runner, State};
use crate::runtime::devices::SimRig;
use crate::runtime::observe::{Events, OperatorAct};
use crate::runtime::requests::{Answer, Later, Request, Requests};
use crate::runtime::snapshot::{
    millis, DeviceState, InvariantState, RigSnapshot, ScriptState, TickFigures, Variables,
    SNAPSHOT_VERSION, VARIABLES_EVERY,
};
use std::cell::RefCell;
use std::sync::Arc;
use std::time::Duration;

/// A run served to askers from outside the loop (`Runner::serve`).
pub(super) struct Served {
    pub(super) requests: Requests,
    /// The script's file, for the snapshot.
    pub(super) script: String,
    /// The simulators of the rig's simulated devices, for `Request::Drive`.
    field: SimRig,
    /// The snapshot last made, with the tick and the exchange count it was made at.
    pub(super) made: Option<((u64, u64), Arc<RigSnapshot>)>,
    /// The commands and messages waiting for a tick to run their handlers.
    pub(super) waiting: Waiting,
    /// The reloads waiting for the next tick boundary, answered once done or refused.
    pub(super) reloads: Vec<Later>,
    /// The script's variables as last read, and when (read again after `VARIABLES_EVERY`).
    variables: RefCell<Option<(Duration, Variables)>>,
}

impl<P: Program> Runner<P> {
    /// Answers `requests` from now on, at tick boundaries and in the sleep slices, for the run
    /// of `script` whose simulated devices `field` holds.
    pub fn serve(&mut self, requests: Requests, script: &str, field: SimRig) {
        self.served = Some(Served {
            requests,
            script: script.to_string(),
            field,
            made: None,
            waiting: Waiting::default(),
            reloads: Vec::new(),
            variables: RefCell::new(None),
        });
    }

    /// What the loop measured so far (the snapshot's figures come from it).
    pub fn stats(&self) -> &crate::runtime::stats::Stats {
        &self.stats
    }

    /// The run's event stream, to attach consumers to.
    pub fn events(&self) -> &Events {
        &self.events
    }

    /// The run as it stands (see `runtime::snapshot`).
    pub fn snapshot(&self) -> RigSnapshot {
        let rt = self.rt.borrow();
        let now = rt.now();
        let (script, simulated) = match &self.served {
            Some(s) => (s.script.clone(), Some(&s.field)),
            None => (String::new(), None),
        };
        let state = match self.state {
            State::Running => "running",
            State::Restarting { .. } => "restarting",
            State::Stopped { .. } => "ended",
        };
        RigSnapshot {
            version: SNAPSHOT_VERSION,
            script: ScriptState {
                file: script,
                state: state.into(),
                uptime_ms: millis(rt.cycle().uptime()),
                errors: self.errors.total(),
                last_error: self.errors.last().map(|e| e.message.clone()),
                restarts: self.restarts,
                hash: self.identity.hash.clone(),
                reloads: self.identity.reloads,
                reloaded: self.identity.reloaded.clone(),
                variables: self.variables_shown(now),
                invariants: self.invariants_shown(),
            },
            devices: rt
                .devices
                .iter()
                .enumerate()
                .map(|(i, d)| {
                    let sim = simulated.is_some_and(|s| s.get(d.name()).is_ok());
                    let state = DeviceState::of(d, sim, now, rt.not_shown(i, now));
                    (d.name().to_string(), state)
                })
                .collect(),
            held_safe: rt.held_safe(),
            ticks: TickFigures::of(&self.stats, self.options.period),
            dropped: self.events.dropped(),
            log_dropped: rt.figures.log().dropped(),
            forcing: rt.forces.allowed(),
            forces: rt.forces_shown(),
            // Counted as it happens; the end's count takes in what was queued too.
            records_lost: self
                .trouble
                .records_lost
                .max(rt.figures.records().lost_so_far()),
            dropped_in_all: self.events.dropped_in_all(),
            mqtt: self
                .served
                .as_ref()
                .and_then(|s| s.requests.remote())
                .map(|r| r.shown()),
        }
    }

    /// The script's variables, read from the program at most every `VARIABLES_EVERY` of a
    /// served run: however many ask, the loop reads them a few times a second at most.
    fn variables_shown(&self, now: Duration) -> Variables {
        let Some(served) = &self.served else {
            return self.program.variables();
        };
        let mut cache = served.variables.borrow_mut();
        match &*cache {
            Some((at, v)) if now.saturating_sub(*at) < VARIABLES_EVERY => v.clone(),
            _ => {
                let v = self.program.variables();
                *cache = Some((now, v.clone()));
                v
            }
        }
    }

    /// Each invariant the script states: it holds unless it is the one the run ended on, or
    /// a force allowed to break it does (overridden).
    fn invariants_shown(&self) -> Vec<InvariantState> {
        let checks = self.rt.borrow().invariant_checks();
        let violated = self.violation.as_ref().map(|v| v.name.as_str());
        checks
            .iter()
            .map(|c| InvariantState {
                name: c.name.clone(),
                at: c.at.clone(),
                holds: violated != Some(c.name.as_str()) && !self.overridden.contains(&c.name),
                overridden: self.overridden.contains(&c.name),
                failed_at_ms: self
                    .invariants_failed
                    .get(&c.name)
                    .map(|t| millis(*t)),
            })
            .collect()
    }

    /// Answers what waits in the control queue (a snapshot made at most once a tick).
    pub(super) fn answer_requests(&mut self) {
        let Some(served) = &self.served else {
            return;
        };
        // The snapshot of this turn, looked for or made only when a request asks for one.
        let mut made: Option<((u64, u64), Arc<RigSnapshot>)> = None;
        // Remote requests may run script handlers, which need the loop itself: after the drain.
        let mut remote = Vec::new();
        let mut forced = false;
        let mut asked = false;
        let later = served.requests.drain(|request| match request {
            Request::Snapshot => {
                asked = true;
                let (_, snapshot) = made.get_or_insert_with(|| {
                    // Between ticks only the devices' upkeep (feeds, retries) changes what is
                    // shown, and each of its exchanges counts: a snapshot stands until the
                    // next tick or exchange.
                    let at = (
                        self.stats.ticks,
                        self.rt.borrow().devices.transaction_count(),
                    );
                    match &served.made {
                        Some((when, s)) if *when == at => (at, Arc::clone(s)),
                        _ => (at, Arc::new(self.snapshot())),
                    }
                });
                Some(Answer::Snapshot(Arc::clone(snapshot)))
            }
            Request::Drive(drive) => Some(match drive.apply(&served.field) {
                Ok(()) => Answer::Accepted,
                Err(why) => Answer::Refused(why),
            }),
            // Judged against the invariants by the program: after the drain.
            Request::Force { .. } | Request::Unforce { .. } => None,
            Request::Remote(r) => {
                remote.push(r.clone());
                Some(Answer::Accepted)
            }
            // At the next tick boundary, answered then.
            Request::Reload { .. } => None,
        });
        if let (Some(made), Some(served)) = (made, &mut self.served) {
            served.made = Some(made);
        }
        let began = {
            let mut rt = self.rt.borrow_mut();
            if asked {
                let now = rt.now();
                rt.snapshot_asked(now);
            }
            rt.watching_began()
        };
        let (forces, later): (Vec<Later>, Vec<Later>) = later.into_iter().partition(|l| {
            matches!(l.request, Request::Force { .. } | Request::Unforce { .. })
        });
        for f in forces {
            forced = true;
            let answer = self.answer_force(&f.request);
            if answer == Answer::Accepted {
                self.tell_operated(|| match &f.request {
                    Request::Force { order, by } => Some(OperatorAct::Force {
                        order: order.clone(),
                        by: by.clone(),
                    }),
                    Request::Unforce { point, by } => Some(OperatorAct::Unforce {
                        point: point.clone(),
                        by: by.clone(),
                    }),
                    _ => None,
                });
            }
            f.answer(answer);
        }
        for r in remote {
            self.take_remote(r);
        }
        self.forces_changed(forced);
        if let Some(served) = self.served.as_mut() {
            served.reloads.extend(later);
        }
        // What waits runs at the next period boundary, even when the loop was idle until later.
        // So does the first read for someone who just began to watch.
        if began
            || self
                .served
                .as_ref()
                .is_some_and(|s| !s.waiting.is_empty() || !s.reloads.is_empty())
        {
            self.tick_soon();
        }
    }
}
