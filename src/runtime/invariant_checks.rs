//! Invariants on the run: stated, turned into this tick's checks, and a violation read from the
//! devices, recorded and logged (what they are: `invariants`).

use super::device_view::DeviceView;
use super::devices::Device;
use super::invariants::{DeviceReading, InvariantCheck, InvariantError, Violation, MAX_INVARIANTS};
use super::state::Runtime;
use super::subscriptions::Call;
use std::rc::Rc;

impl<H: Clone> Runtime<H> {
    /// States an invariant (checked from the next tick on).
    pub fn add_invariant(
        &mut self,
        name: &str,
        handler: H,
        at: Option<String>,
    ) -> Result<(), InvariantError> {
        if name.trim().is_empty() {
            return Err(InvariantError::NoName);
        }
        if self.invariants.iter().any(|i| i.name == name) {
            return Err(InvariantError::Duplicate(name.to_string()));
        }
        if self.invariants.len() >= MAX_INVARIANTS {
            return Err(InvariantError::TooMany);
        }
        Rc::make_mut(&mut self.invariants).push(InvariantCheck {
            call: Call {
                handler,
                args: Vec::new(),
                label: format!("invariant {name:?}").into(),
            },
            name: name.to_string(),
            at,
        });
        Ok(())
    }

    /// How to evaluate each invariant, in the order they were stated: the list itself, shared
    /// (the checks call the script, which may borrow the runtime meanwhile).
    pub fn invariant_checks(&self) -> Rc<Vec<InvariantCheck<H>>> {
        Rc::clone(&self.invariants)
    }

    /// What each device the script uses shows now: the last inputs read and the outputs the
    /// script wants (a device never read and still at its safe state is left out).
    pub fn readings(&self) -> Vec<DeviceReading> {
        self.devices
            .iter()
            .filter(|d| match d {
                Device::C29u(c) => {
                    c.inputs().current.is_some() || c.wanted_outputs() != c.config().safe_value
                }
                Device::Trc(t) => {
                    t.switches().current.is_some()
                        || Some(t.wanted_relay()) != t.config().safe_relay
                }
            })
            .map(|d| DeviceReading {
                name: d.name().to_string(),
                view: DeviceView::of(d),
            })
            .collect()
    }

    /// Records and logs a violation: the invariant, where it was stated, and the tick's
    /// inputs and outputs.
    pub fn report_violation(&mut self, v: &Violation) {
        self.log.error(&format!(
            "{v}; the outputs of this tick are not written, the safe state is"
        ));
        let time = self.wall_text();
        self.records
            .record(&time, "invariant_violated", v.to_json(), &mut self.log);
    }
}
