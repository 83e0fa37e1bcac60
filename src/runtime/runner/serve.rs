//! A run served to askers from outside the loop: the control queue answered, the snapshot made
//! at most once a tick.

use super::contract::Program;
use super::{Runner, State};
use crate::runtime::devices::SimRig;
use crate::runtime::observe::Events;
use crate::runtime::requests::{Answer, Request, Requests};
use crate::runtime::snapshot::{
    micros, DeviceState, RigSnapshot, ScriptState, TickFigures, SNAPSHOT_VERSION,
};
use std::sync::Arc;

/// A run served to askers from outside the loop (`Runner::serve`).
pub(super) struct Served {
    pub(super) requests: Requests,
    /// The script's file, for the snapshot.
    pub(super) script: String,
    /// The simulators of the rig's simulated devices, for `Request::Drive`.
    field: SimRig,
    /// The snapshot last made, with the tick and the exchange count it was made at.
    made: Option<((u64, u64), Arc<RigSnapshot>)>,
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
        });
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
                uptime_ms: u64::try_from(rt.uptime().as_millis()).unwrap_or(u64::MAX),
                errors: self.errors.total(),
                last_error: self.errors.last().map(|e| e.message.clone()),
                restarts: self.restarts,
            },
            devices: rt
                .devices
                .iter()
                .map(|d| {
                    let sim = simulated.is_some_and(|s| s.get(d.name()).is_ok());
                    (d.name().to_string(), DeviceState::of(d, sim, now))
                })
                .collect(),
            held_safe: rt.held_safe,
            ticks: TickFigures {
                period_us: micros(self.options.period),
                count: self.stats.ticks,
                overruns: self.stats.overruns,
                jitter_p99_us: micros(self.stats.jitter.quantile(0.99)),
                work_p99_us: micros(self.stats.work.quantile(0.99)),
                transactions: self.stats.transactions,
            },
            dropped: self.events.dropped(),
            log_dropped: rt.log.dropped(),
        }
    }

    /// Answers what waits in the control queue (a snapshot made at most once a tick).
    pub(super) fn answer_requests(&mut self) {
        let Some(served) = &self.served else {
            return;
        };
        // Between ticks only the devices' upkeep (feeds, retries) changes what is shown, and
        // each of its exchanges counts: a snapshot stands until the next tick or exchange.
        let tick = (self.stats.ticks, self.rt.borrow().transaction_count());
        let mut made = served.made.clone().filter(|(at, _)| *at == tick);
        let mut asked = false;
        // Made lazily, only if a request needs it: the closure cannot borrow `self` whole.
        let snapshot = std::cell::OnceCell::new();
        served.requests.drain(|request| match request {
            Request::Snapshot => {
                asked = true;
                let s = match &made {
                    Some((_, s)) => Arc::clone(s),
                    None => Arc::clone(snapshot.get_or_init(|| Arc::new(self.snapshot()))),
                };
                Answer::Snapshot(s)
            }
            Request::Drive(drive) => match drive.apply(&served.field) {
                Ok(()) => Answer::Accepted,
                Err(why) => Answer::Refused(why),
            },
        });
        if asked && made.is_none() {
            made = snapshot.into_inner().map(|s| (tick, s));
        }
        if let Some(served) = &mut self.served {
            if made.is_some() {
                served.made = made;
            }
        }
    }
}
