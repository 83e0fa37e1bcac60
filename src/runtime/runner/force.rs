//! The loop's side of forcing (`runtime::forcing`): force and unforce requests answered
//! between ticks, forces expired on the run's clock, and the outputs they change written at
//! once rather than at the next tick.

use super::contract::{Program, Shared};
use super::{Runner, State};
use crate::runtime::requests::{Answer, Request};

/// Answers a `Force` or `Unforce` request; a force is taken only while the script runs (the
/// safe state of a restart or an end wins over it).
pub(super) fn answer_force<H: Clone>(rt: &Shared<H>, state: &State, request: &Request) -> Answer {
    let mut rt = rt.borrow_mut();
    let done = match request {
        Request::Force { .. } if *state != State::Running => {
            return Answer::Refused(format!(
                "the script is {}: its outputs are safe, and the safe state wins over a force",
                match state {
                    State::Restarting { .. } => "restarting",
                    _ => "ending",
                }
            ))
        }
        Request::Force { order, by } => rt.force(order, by),
        Request::Unforce { point, by } => rt.unforce(point, by),
        _ => return Answer::Refused("not a force request".into()),
    };
    match done {
        Ok(()) => Answer::Accepted,
        Err(e) => Answer::Refused(e.to_string()),
    }
}

impl<P: Program> Runner<P> {
    /// Ends the forces whose time is over; with those `changed` by requests, writes the
    /// outputs now (between ticks) and lets the next snapshot show it.
    pub(super) fn forces_changed(&mut self, changed: bool) {
        let expired = {
            let rt = self.rt.borrow();
            rt.next_force_expiry().is_some_and(|at| rt.now() >= at)
        } && self.rt.borrow_mut().expire_forces();
        if !(changed || expired) {
            return;
        }
        if let Some(served) = &mut self.served {
            served.made = None;
        }
        if self.state == State::Running {
            self.guarded(|r| r.rt.borrow_mut().flush_outputs());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::forcing::{ForceOrder, ForceValue};
    use crate::runtime::testing::TestRig;
    use std::time::Duration;

    #[test]
    fn a_force_is_refused_while_the_script_restarts_or_the_run_ends() {
        let mut r = TestRig::started();
        r.rt.allow_forcing(true);
        let rt = r.shared_runtime();
        let asked = Request::Force {
            order: ForceOrder {
                point: "io.DO1".into(),
                value: ForceValue::On(true),
                duration: "1m".into(),
            },
            by: "t".into(),
        };
        for state in [
            State::Restarting { at: Duration::ZERO },
            State::Stopped { status: 0 },
        ] {
            match answer_force(&rt, &state, &asked) {
                Answer::Refused(why) => assert!(why.contains("the safe state wins"), "{why}"),
                other => panic!("{other:?}"),
            }
        }
        assert!(rt.borrow().forces_shown().is_empty());
        assert_eq!(answer_force(&rt, &State::Running, &asked), Answer::Accepted);
        assert_eq!(rt.borrow().forces_shown().len(), 1);
    }
}
