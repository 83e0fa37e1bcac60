//! What the script records and measures, on the run: stamped with the run's wall time, a
//! measurement logged as pass or FAIL, and kept for scenario tests and the JUnit report.

use super::records::Limits;
use super::state::Runtime;
use serde_json::Value;

impl<H: Clone> Runtime<H> {
    /// `record(name, value)`: one record, stamped now.
    pub fn record(&mut self, name: &str, value: Value) {
        let time = self.cycle().wall_text();
        self.records.record(&time, name, value, &mut self.log);
    }

    /// `measure(name, value, limits)`: one measurement, stamped now and logged with its
    /// limits; whether it is within them.
    pub fn measure(&mut self, name: &str, value: f64, limits: &Limits) -> bool {
        let time = self.cycle().wall_text();
        let pass = self
            .records
            .measure(&time, name, value, limits, &mut self.log);
        let unit = limits.unit.as_deref().unwrap_or("");
        let range = match (limits.min, limits.max) {
            (Some(a), Some(b)) => format!(" [{a}, {b}]"),
            (Some(a), None) => format!(" [>= {a}]"),
            (None, Some(b)) => format!(" [<= {b}]"),
            (None, None) => String::new(),
        };
        let line = format!(
            "measure {name} = {value}{unit}{range}: {}",
            if pass { "pass" } else { "FAIL" }
        );
        if pass {
            self.log.activity(&line);
        } else {
            self.log.warn(&line);
        }
        pass
    }

    /// The records and measurements kept so far, oldest first, as JSON objects.
    pub fn records_kept(&self) -> &[Value] {
        self.records.kept()
    }
}
