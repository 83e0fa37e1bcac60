//! What the script records and measures, on the run: stamped with the run's wall time, a
//! measurement logged as pass or FAIL (`figures`), and kept for scenario tests and the JUnit
//! report.

use super::records::Limits;
use super::state::Runtime;
use serde_json::Value;

impl<H: Clone> Runtime<H> {
    /// `record(name, value)`: one record, stamped now.
    pub fn record(&mut self, name: &str, value: Value) {
        let time = self.cycle().wall_text();
        self.figures.record(&time, name, value);
    }

    /// `measure(name, value, limits)`: one measurement, stamped now and logged with its
    /// limits; whether it is within them.
    pub fn measure(&mut self, name: &str, value: f64, limits: &Limits) -> bool {
        let time = self.cycle().wall_text();
        self.figures.measure(&time, name, value, limits)
    }

    /// The records and measurements kept so far, oldest first, as JSON objects.
    pub fn records_kept(&self) -> &[Value] {
        self.figures.records().kept()
    }
}
