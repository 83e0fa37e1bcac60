//! The loop's side of forcing (`runtime::forcing`): force and unforce requests answered
//! between ticks, forces expired on the run's clock, and the outputs they change written at
//! once rather than at the next tick.

use super::contract::{Program, Shared};
use super::{Runner, State};
use crate::runtime::forcing::MAX_FORCES;
use crate::runtime::requests::{Answer, Request};

/// What the invariants say of the outputs as they would be written, the forces over them.
#[derive(Debug, PartialEq, Eq)]
pub(super) enum Judged {
    /// Every invariant holds, or is false only where a force held was allowed to break it
    /// (those named).
    Holds { overridden: Vec<String> },
    /// This invariant (stated at `at`) would be false, and no force may break it.
    Breaks { name: String, at: Option<String> },
}

/// Evaluates the script's invariants on the outputs and relays as they would be written (the
/// script's reads of them give the forced values meanwhile). An invariant that cannot be
/// evaluated on them is not taken as holding.
pub(super) fn judge<P: Program>(rt: &Shared<P::Handler>, program: &mut P) -> Judged {
    let checks = rt.borrow().invariant_checks();
    rt.borrow_mut().forces.set_judging(true);
    let _judging = Judging(rt);
    let mut overridden = Vec::new();
    let mut broken = None;
    for check in checks.iter() {
        if program.holds(check).unwrap_or(false) {
            continue;
        }
        if rt.borrow().forces.overridden(&check.name) {
            overridden.push(check.name.clone());
        } else {
            broken = Some(Judged::Breaks {
                name: check.name.clone(),
                at: check.at.clone(),
            });
            break;
        }
    }
    broken.unwrap_or(Judged::Holds { overridden })
}

/// Ends a judging however it ends (a panic in an invariant too): the script's reads of its
/// outputs give what it wants again.
struct Judging<'a, H>(&'a Shared<H>);

impl<H> Drop for Judging<'_, H> {
    fn drop(&mut self) {
        if let Ok(mut rt) = self.0.try_borrow_mut() {
            rt.forces.set_judging(false);
        }
    }
}

impl<P: Program> Runner<P> {
    /// Answers a `Force` or `Unforce` request. A force is taken only while the script runs
    /// (the safe state of a restart or an end wins over it), and a force of outputs only if
    /// the invariants hold on what would then be written, or the order overrides the one
    /// that would not.
    pub(super) fn answer_force(&mut self, request: &Request) -> Answer {
        let (order, by) = match request {
            Request::Force { order, by } => (order, by),
            Request::Unforce { point, by } => {
                let done = self.rt.borrow_mut().unforce(point, by);
                self.judge_forces();
                return match done {
                    Ok(()) => Answer::Accepted,
                    Err(e) => Answer::Refused(e.to_string()),
                };
            }
            _ => return Answer::Refused("not a force request".into()),
        };
        if self.state != State::Running {
            return Answer::Refused(format!(
                "the script is {}: its outputs are safe, and the safe state wins over a force",
                match self.state {
                    State::Restarting { .. } => "restarting",
                    _ => "ending",
                }
            ));
        }
        if let Some(why) = self.unknown_override(&order.overrides) {
            return Answer::Refused(why);
        }
        let staged = match self.rt.borrow_mut().stage_force(order, by) {
            Ok(s) => s,
            Err(e) => return Answer::Refused(e.to_string()),
        };
        match judge(&self.rt, &mut self.program) {
            Judged::Breaks { name, at } => {
                let point = staged.point().to_string();
                self.rt.borrow_mut().withdraw_force(staged);
                let place = at.map(|a| format!(" ({a})")).unwrap_or_default();
                Answer::Refused(format!(
                    "forcing {point} {} would break the invariant {name:?}{place}: refused. \
                     To force it anyway, say so: --override {name:?} (on the page: confirm); \
                     it is then logged and recorded as breaking it",
                    order.value.text()
                ))
            }
            Judged::Holds { overridden } => {
                self.rt.borrow_mut().confirm_force(staged);
                self.overridden = overridden;
                Answer::Accepted
            }
        }
    }

    /// Why an order's `--override` is refused: it names no invariant the script states.
    fn unknown_override(&self, overrides: &[String]) -> Option<String> {
        let checks = self.rt.borrow().invariant_checks();
        let unknown = overrides
            .iter()
            .find(|o| !checks.iter().any(|c| c.name == **o))?;
        let names = checks.iter().map(|c| c.name.as_str());
        let hint = match crate::suggest::closest(unknown, names) {
            Some(near) => format!(" (did you mean {near:?}?)"),
            None if checks.is_empty() => " (it states none)".into(),
            None => format!(
                " (it states {})",
                checks
                    .iter()
                    .map(|c| format!("{:?}", c.name))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        };
        Some(format!(
            "--override {unknown:?}: the script states no invariant called that{hint}"
        ))
    }

    /// Ends, newest first, the forces of outputs with which the outputs would make an
    /// invariant false, unless the force was allowed to break it; keeps which invariants
    /// are overridden now. Called before a tick's outputs are written, and after an unforce.
    pub(super) fn judge_forces(&mut self) {
        if !self.rt.borrow().forces.hold_outputs() {
            self.overridden.clear();
            return;
        }
        // Each turn ends a force or returns: at most one turn a force, and one more.
        for _ in 0..=MAX_FORCES {
            match judge(&self.rt, &mut self.program) {
                Judged::Holds { overridden } => {
                    self.overridden = overridden;
                    return;
                }
                Judged::Breaks { name, at } => {
                    let ended = self
                        .rt
                        .borrow_mut()
                        .end_force_breaking(&name, at.as_deref());
                    if !ended {
                        return;
                    }
                }
            }
        }
    }

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
    use crate::script::builder::RigBuilder;
    use crate::script::rig::Rig;
    use std::time::Duration;

    /// A motor (DO0) the script never starts, and its promise: only with the guard (DI0)
    /// closed.
    const GUARDED: &str = r#"
let io = device("io");
every("20ms", || { let closed = io.input(0); });
invariant("motor only with the guard closed", || !io.output(0) || io.input(0));
"#;

    fn rig() -> Rig {
        let r = RigBuilder::for_tests().start(GUARDED, "a.rhai").unwrap();
        r.runner.runtime().borrow_mut().allow_forcing(true);
        r
    }

    fn ticks(r: &mut Rig, n: usize) {
        for _ in 0..n {
            r.runner.step();
        }
    }

    fn force(point: &str, overrides: &[&str]) -> Request {
        Request::Force {
            order: ForceOrder {
                point: point.into(),
                value: ForceValue::On(true),
                duration: "1m".into(),
                overrides: overrides.iter().map(|o| o.to_string()).collect(),
            },
            by: "t".into(),
        }
    }

    fn invariant(r: &Rig) -> crate::runtime::snapshot::InvariantState {
        r.runner.snapshot().script.invariants[0].clone()
    }

    #[test]
    fn a_force_that_would_break_an_invariant_is_refused_naming_it_and_taken_when_overridden() {
        let mut r = rig();
        ticks(&mut r, 2);
        let refused = r.runner.answer_force(&force("io.DO0", &[]));
        let Answer::Refused(why) = refused else {
            panic!("{refused:?}")
        };
        assert!(
            why.contains("forcing io.DO0 on would break the invariant \"motor only with the guard closed\" (a.rhai:4:1)")
                && why.contains("--override"),
            "{why}"
        );
        assert!(r.runner.snapshot().forces.is_empty(), "withdrawn");
        ticks(&mut r, 2);
        assert_eq!(r.sim.outputs("io").unwrap(), 0, "nothing written");
        // Said explicitly: taken, logged and recorded with it, shown as overridden.
        let asked = force("io.DO0", &["motor only with the guard closed"]);
        assert_eq!(r.runner.answer_force(&asked), Answer::Accepted);
        ticks(&mut r, 3);
        assert_eq!(r.sim.outputs("io").unwrap(), 1, "the force holds");
        assert_eq!(r.runner.status(), None, "the run goes on");
        let shown = invariant(&r);
        assert!(shown.overridden && !shown.holds, "{shown:?}");
        assert_eq!(
            r.runner.snapshot().forces[0].overrides,
            ["motor only with the guard closed"]
        );
        let log = r.log().join("\n");
        assert!(
            log.contains("overriding the invariant \"motor only with the guard closed\""),
            "{log}"
        );
        let records = r.records();
        let set = records.iter().find(|v| v["name"] == "force").expect("a record");
        assert_eq!(set["value"]["overrides"][0], "motor only with the guard closed");
        // Until the force ends.
        let unforce = Request::Unforce {
            point: "io.DO0".into(),
            by: "t".into(),
        };
        assert_eq!(r.runner.answer_force(&unforce), Answer::Accepted);
        let shown = invariant(&r);
        assert!(shown.holds && !shown.overridden, "{shown:?}");
    }

    #[test]
    fn a_force_taken_while_it_kept_the_promise_ends_the_tick_it_would_break_it() {
        let mut r = rig();
        r.sim.set_input("io", 0, true).unwrap();
        ticks(&mut r, 3);
        assert_eq!(r.runner.answer_force(&force("io.DO0", &[])), Answer::Accepted);
        ticks(&mut r, 2);
        assert_eq!(r.sim.outputs("io").unwrap(), 1, "forced on, the guard closed");
        // The guard opens: the force ends before the outputs of that tick are written.
        r.sim.set_input("io", 0, false).unwrap();
        ticks(&mut r, 2);
        assert_eq!(r.sim.outputs("io").unwrap(), 0, "the script's value again");
        assert!(r.runner.snapshot().forces.is_empty());
        assert_eq!(r.runner.status(), None, "the run goes on");
        assert!(invariant(&r).holds);
        let log = r.log().join("\n");
        assert!(
            log.contains("io.DO0 ended: with it the outputs would break the invariant \"motor only with the guard closed\""),
            "{log}"
        );
        let ended = r
            .records()
            .into_iter()
            .find(|v| v["name"] == "force" && v["value"]["event"] == "ended")
            .expect("the end recorded");
        assert_eq!(ended["value"]["breaks"], "motor only with the guard closed");
    }

    #[test]
    fn an_override_naming_no_invariant_is_refused_with_the_nearest() {
        let mut r = rig();
        ticks(&mut r, 1);
        let Answer::Refused(why) = r
            .runner
            .answer_force(&force("io.DO0", &["motor only with the guard close"]))
        else {
            panic!("taken")
        };
        assert!(
            why.contains("states no invariant called that (did you mean \"motor only with the guard closed\"?)"),
            "{why}"
        );
    }

    #[test]
    fn an_input_force_is_taken_the_script_reacting_to_it() {
        let mut r = rig();
        ticks(&mut r, 1);
        assert_eq!(r.runner.answer_force(&force("io.DI0", &[])), Answer::Accepted);
        ticks(&mut r, 2);
        assert_eq!(r.runner.snapshot().forces.len(), 1);
    }

    #[test]
    fn a_force_is_refused_while_the_script_restarts_or_the_run_ends() {
        let mut r = rig();
        ticks(&mut r, 1);
        for state in [
            State::Restarting { at: Duration::ZERO },
            State::Stopped { status: 0 },
        ] {
            r.runner.state = state;
            match r.runner.answer_force(&force("io.DO1", &[])) {
                Answer::Refused(why) => assert!(why.contains("the safe state wins"), "{why}"),
                other => panic!("{other:?}"),
            }
        }
        assert!(r.runner.snapshot().forces.is_empty());
        r.runner.state = State::Running;
        assert_eq!(r.runner.answer_force(&force("io.DO1", &[])), Answer::Accepted);
        assert_eq!(r.runner.snapshot().forces.len(), 1);
    }
}
