//! Records for test rigs: `record(name, value)` and `measure(name, value, limits)` append one
//! JSON object per line, with a timestamp, to the records file, and are kept in memory.

use serde_json::{json, Map, Value};
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Records kept in memory at most (the oldest go first); the file keeps them all.
pub const MAX_KEPT_RECORDS: usize = 100_000;

/// Why a record could not be written.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The records file cannot be opened or written.
    #[error("records file {}: {source}", path.display())]
    File {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
}

/// The limits a measurement must keep; either may be absent.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Limits {
    /// Lowest acceptable value.
    pub min: Option<f64>,
    /// Highest acceptable value.
    pub max: Option<f64>,
    /// Unit, for people.
    pub unit: Option<String>,
}

impl Limits {
    /// Whether `value` lies within the limits (a NaN never does).
    pub fn pass(&self, value: f64) -> bool {
        !value.is_nan()
            && self.min.map_or(true, |min| value >= min)
            && self.max.map_or(true, |max| value <= max)
    }
}

/// The records of one run.
#[derive(Default)]
pub struct Records {
    file: Option<(PathBuf, File)>,
    kept: Vec<Value>,
    failed: u64,
}

impl Records {
    /// Records kept in memory only.
    pub fn in_memory() -> Self {
        Self::default()
    }

    /// Records appended to `path` too (created if missing).
    pub fn to_file(path: &Path) -> Result<Self, RecordError> {
        let file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .map_err(|source| RecordError::File {
                path: path.to_path_buf(),
                source,
            })?;
        Ok(Self {
            file: Some((path.to_path_buf(), file)),
            ..Self::default()
        })
    }

    /// Appends `{"time", "name", "value"}`.
    pub fn record(&mut self, time: &str, name: &str, value: Value) -> Result<(), RecordError> {
        self.append(json!({ "time": time, "name": name, "value": value }))
    }

    /// Appends `{"time", "name", "value", "min", "max", "unit", "pass"}` (absent limits left
    /// out) and returns whether the value passed; a failure is counted for the exit status.
    pub fn measure(
        &mut self,
        time: &str,
        name: &str,
        value: f64,
        limits: &Limits,
    ) -> Result<bool, RecordError> {
        let pass = limits.pass(value);
        let mut object = Map::new();
        object.insert("time".into(), json!(time));
        object.insert("name".into(), json!(name));
        // JSON has no NaN: a NaN measurement is recorded as null (and fails).
        object.insert(
            "value".into(),
            serde_json::Number::from_f64(value).map_or(Value::Null, Value::Number),
        );
        if let Some(min) = limits.min {
            object.insert("min".into(), json!(min));
        }
        if let Some(max) = limits.max {
            object.insert("max".into(), json!(max));
        }
        if let Some(unit) = &limits.unit {
            object.insert("unit".into(), json!(unit));
        }
        object.insert("pass".into(), json!(pass));
        if !pass {
            self.failed = self.failed.saturating_add(1);
        }
        self.append(Value::Object(object))?;
        Ok(pass)
    }

    /// Measurements that failed their limits so far.
    pub fn failed(&self) -> u64 {
        self.failed
    }

    /// The records kept in memory, oldest first.
    pub fn kept(&self) -> &[Value] {
        &self.kept
    }

    fn append(&mut self, record: Value) -> Result<(), RecordError> {
        if let Some((path, file)) = &mut self.file {
            // One write per line, so a reader (or a crash) never sees half a record.
            let line = format!("{record}\n");
            file.write_all(line.as_bytes())
                .and_then(|()| file.flush())
                .map_err(|source| RecordError::File {
                    path: path.clone(),
                    source,
                })?;
        }
        if self.kept.len() >= MAX_KEPT_RECORDS {
            self.kept.remove(0);
        }
        self.kept.push(record);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn measurements_pass_within_limits_and_failures_are_counted() {
        let mut r = Records::in_memory();
        let limits = Limits {
            min: Some(1.0),
            max: Some(2.0),
            unit: Some("V".into()),
        };
        assert!(r.measure("t", "v", 1.5, &limits).unwrap());
        assert!(r.measure("t", "v", 2.0, &limits).unwrap());
        assert!(!r.measure("t", "v", 2.5, &limits).unwrap());
        assert!(!r.measure("t", "v", f64::NAN, &limits).unwrap());
        assert_eq!(r.failed(), 2);
        assert_eq!(
            r.kept()[2],
            json!({"time": "t", "name": "v", "value": 2.5, "min": 1.0, "max": 2.0, "unit": "V", "pass": false})
        );
        assert_eq!(r.kept()[3]["value"], Value::Null);
        assert!(Limits::default().pass(-1e9));
    }

    #[test]
    fn records_are_appended_as_json_lines() {
        let dir = std::env::temp_dir().join(format!("rigscript-records-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("r.jsonl");
        let _ = std::fs::remove_file(&path);
        let mut r = Records::to_file(&path).unwrap();
        r.record("t1", "count", json!(3)).unwrap();
        r.measure("t2", "v", 0.5, &Limits::default()).unwrap();
        let mut again = Records::to_file(&path).unwrap();
        again.record("t3", "x", json!("y")).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<Value> = text
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        assert_eq!(lines.len(), 3);
        assert_eq!(lines[0], json!({"time": "t1", "name": "count", "value": 3}));
        assert_eq!(lines[2]["value"], json!("y"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
