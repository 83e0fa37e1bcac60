//! Invariants on the run: stated, turned into this tick's checks, and a violation read from the
//! devices, recorded and logged (what they are: `invariants`).

use super::device_view::DeviceView;
use super::devices::Device;
use super::invariants::{DeviceReading, InvariantCheck, InvariantError, Violation};
use super::state::Runtime;
use std::rc::Rc;

impl<H: Clone> Runtime<H> {
    /// States an invariant (checked from the next tick on).
    pub fn add_invariant(
        &mut self,
        name: &str,
        handler: H,
        at: Option<String>,
    ) -> Result<(), InvariantError> {
        self.program.add_invariant(name, handler, at)
    }

    /// How to evaluate each invariant, in the order they were stated: the list itself, shared
    /// (the checks call the script, which may borrow the runtime meanwhile).
    pub fn invariant_checks(&self) -> Rc<Vec<InvariantCheck<H>>> {
        self.program().invariant_checks()
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
        self.log_mut().error(&format!(
            "{v}; the outputs of this tick are not written, the safe state is"
        ));
        let time = self.cycle().wall_text();
        self.figures
            .record(&time, "invariant_violated", v.to_json());
    }
}
