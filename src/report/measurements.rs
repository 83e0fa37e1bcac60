//! A run as a JUnit test suite: each `measure(...)` a test case carrying its value and limits
//! (a value outside them is a `<failure>`), and one case for the run itself, an `<error>` when
//! it ended with a status other than 0 (done) or 4 (measurements failed, listed one by one).

use super::junit::{Outcome, TestCase, TestSuite};
use serde_json::Value;
use std::collections::HashMap;
use std::time::Duration;

/// The name of the test case that stands for the run itself.
pub const RUN_CASE: &str = "run";

/// What a finished (or failed to start) run leaves for its report.
#[derive(Debug, Clone)]
pub struct RunOutcome<'a> {
    /// The script, as given on the command line.
    pub script: &'a str,
    /// When the run started, as `YYYY-MM-DDTHH:MM:SS`.
    pub started: String,
    /// How long it ran.
    pub elapsed: Duration,
    /// Its exit status.
    pub status: i32,
    /// The records it kept, oldest first (`record` lines are skipped, `measure` lines used).
    pub records: &'a [Value],
    /// Whether older records may have been dropped from memory (the kept list was full).
    pub records_truncated: bool,
    /// Warnings and errors from the log, for the run's case.
    pub problems: &'a [String],
}

/// The suite for `run`.
pub fn run_suite(run: &RunOutcome<'_>) -> TestSuite {
    let measurements: Vec<&Value> = run
        .records
        .iter()
        .filter(|r| r.get("pass").is_some())
        .collect();
    let mut seen: HashMap<&str, usize> = HashMap::new();
    let total = counts(&measurements);
    let mut cases: Vec<TestCase> = measurements
        .iter()
        .map(|m| {
            let name = m.get("name").and_then(Value::as_str).unwrap_or("?");
            let nth = seen.entry(name).or_insert(0);
            *nth += 1;
            let numbered = match total.get(name) {
                Some(&n) if n > 1 => format!("{name} #{nth}"),
                _ => name.to_string(),
            };
            measurement_case(m, numbered, run.script)
        })
        .collect();
    cases.push(run_case(run));
    let mut notes = String::new();
    if run.records_truncated {
        notes = format!(
            "the run kept only its latest {} records in memory: earlier measurements are left \
             out of this report (the records file, --records, has them all)",
            run.records.len()
        );
    }
    TestSuite {
        name: run.script.to_string(),
        timestamp: run.started.clone(),
        time: run.elapsed,
        properties: vec![
            ("script".into(), run.script.to_string()),
            ("exit_status".into(), run.status.to_string()),
        ],
        cases,
        notes,
    }
}

fn counts<'v>(measurements: &[&'v Value]) -> HashMap<&'v str, usize> {
    let mut total = HashMap::new();
    for m in measurements {
        let name = m.get("name").and_then(Value::as_str).unwrap_or("?");
        *total.entry(name).or_insert(0) += 1;
    }
    total
}

fn number(v: Option<&Value>) -> Option<f64> {
    v.and_then(Value::as_f64)
}

fn limits_text(min: Option<f64>, max: Option<f64>, unit: &str) -> String {
    match (min, max) {
        (Some(lo), Some(hi)) => format!("[{lo}, {hi}]{unit}"),
        (Some(lo), None) => format!("at least {lo}{unit}"),
        (None, Some(hi)) => format!("at most {hi}{unit}"),
        (None, None) => "no limits".into(),
    }
}

fn measurement_case(m: &Value, name: String, script: &str) -> TestCase {
    let value = number(m.get("value"));
    let (min, max) = (number(m.get("min")), number(m.get("max")));
    let unit = m.get("unit").and_then(Value::as_str).unwrap_or("");
    let unit_suffix = if unit.is_empty() {
        String::new()
    } else {
        format!(" {unit}")
    };
    let shown = match value {
        Some(v) => format!("{v}{unit_suffix}"),
        None => "not a number".into(),
    };
    let limits = limits_text(min, max, &unit_suffix);
    let pass = m.get("pass").and_then(Value::as_bool).unwrap_or(false);
    let base = m.get("name").and_then(Value::as_str).unwrap_or("?");
    let outcome = if pass {
        Outcome::Passed
    } else {
        let why = match (value, min, max) {
            (None, _, _) => "not a number".to_string(),
            (Some(v), Some(lo), _) if v < lo => format!("below the minimum {lo}{unit_suffix}"),
            (Some(v), _, Some(hi)) if v > hi => format!("above the maximum {hi}{unit_suffix}"),
            _ => format!("outside {limits}"),
        };
        Outcome::Failure {
            message: format!("{base} = {shown}: {why}"),
            kind: "measurement".into(),
            detail: format!("{base} = {shown}, limits {limits}"),
        }
    };
    let mut properties = vec![("value".to_string(), property(m.get("value")))];
    for key in ["min", "max", "unit", "time"] {
        if let Some(v) = m.get(key) {
            properties.push((key.to_string(), property(Some(v))));
        }
    }
    TestCase {
        name,
        classname: script.to_string(),
        time: Duration::ZERO,
        outcome,
        properties,
        output: format!(
            "{base} = {shown}, limits {limits}{}",
            m.get("time")
                .and_then(Value::as_str)
                .map(|t| format!(", measured at {t}"))
                .unwrap_or_default()
        ),
    }
}

/// A JSON value as a property: strings as they are, `null` as `NaN` (a measurement that was
/// not a number), numbers as JSON writes them.
fn property(v: Option<&Value>) -> String {
    match v {
        Some(Value::String(s)) => s.clone(),
        Some(Value::Null) | None => "NaN".into(),
        Some(other) => other.to_string(),
    }
}

fn run_case(run: &RunOutcome<'_>) -> TestCase {
    let mut case = TestCase::passed(RUN_CASE, run.script);
    case.time = run.elapsed;
    case.output = run.problems.join("\n");
    if !matches!(run.status, 0 | 4) {
        let last = run.problems.last().map(String::as_str).unwrap_or("");
        case.outcome = Outcome::Error {
            message: if last.is_empty() {
                format!("the run ended with exit status {}", run.status)
            } else {
                format!("the run ended with exit status {}: {last}", run.status)
            },
            kind: format!("exit status {}", run.status),
            detail: run.problems.join("\n"),
        };
    }
    case
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn outcome<'a>(records: &'a [Value], status: i32, problems: &'a [String]) -> RunOutcome<'a> {
        RunOutcome {
            script: "rig.rhai",
            started: "2026-03-28T12:00:00".into(),
            elapsed: Duration::from_secs(2),
            status,
            records,
            records_truncated: false,
            problems,
        }
    }

    #[test]
    fn each_measurement_is_a_case_with_its_value_and_limits() {
        let records = [
            json!({"time": "t1", "name": "count", "value": 3}),
            json!({"time": "t2", "name": "volts", "value": 3.3, "min": 3.0, "max": 3.6, "unit": "V", "pass": true}),
            json!({"time": "t3", "name": "pulses", "value": 0.0, "min": 1.0, "max": 3.0, "unit": "pulses", "pass": false}),
            json!({"time": "t4", "name": "volts", "value": 3.9, "min": 3.0, "max": 3.6, "unit": "V", "pass": false}),
            json!({"time": "t5", "name": "nan", "value": null, "pass": false}),
        ];
        let suite = run_suite(&outcome(&records, 4, &[]));
        let names: Vec<&str> = suite.cases.iter().map(|c| c.name.as_str()).collect();
        assert_eq!(names, ["volts #1", "pulses", "volts #2", "nan", "run"]);
        assert_eq!((suite.failures(), suite.errors()), (3, 0));
        assert_eq!(suite.cases[0].outcome, Outcome::Passed);
        assert_eq!(
            suite.cases[0].output,
            "volts = 3.3 V, limits [3, 3.6] V, measured at t2"
        );
        assert_eq!(
            suite.cases[0].properties,
            [
                ("value".to_string(), "3.3".to_string()),
                ("min".into(), "3.0".into()),
                ("max".into(), "3.6".into()),
                ("unit".into(), "V".into()),
                ("time".into(), "t2".into()),
            ]
        );
        let message = |i: usize| match &suite.cases[i].outcome {
            Outcome::Failure { message, .. } => message.clone(),
            other => panic!("case {i}: {other:?}"),
        };
        assert_eq!(message(1), "pulses = 0 pulses: below the minimum 1 pulses");
        assert_eq!(message(2), "volts = 3.9 V: above the maximum 3.6 V");
        assert_eq!(message(3), "nan = not a number: not a number");
        assert_eq!(suite.cases[3].properties[0].1, "NaN");
        assert_eq!(
            suite.cases[4].outcome,
            Outcome::Passed,
            "status 4 is no error"
        );
    }

    #[test]
    fn a_run_that_failed_is_an_error_case_with_the_log_problems() {
        let problems = ["12:00:01.000 error: a.rhai:3:5: in every 1s: boom".to_string()];
        let suite = run_suite(&outcome(&[], 1, &problems));
        assert_eq!(suite.errors(), 1);
        let run = suite.cases.last().unwrap();
        assert_eq!(run.name, RUN_CASE);
        assert_eq!(run.time, Duration::from_secs(2));
        match &run.outcome {
            Outcome::Error { message, kind, .. } => {
                assert_eq!(
                    message,
                    "the run ended with exit status 1: 12:00:01.000 error: a.rhai:3:5: in every \
                     1s: boom"
                );
                assert_eq!(kind, "exit status 1");
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_full_record_memory_is_said_in_the_report() {
        let mut o = outcome(&[], 0, &[]);
        o.records_truncated = true;
        let suite = run_suite(&o);
        assert!(suite.notes.contains("records file"), "{}", suite.notes);
    }
}
