//! What `rigscript run` tells the world besides its log: the JUnit report of `--junit FILE`,
//! and systemd's notifier when the environment asks for one (`service::notify`, attached at
//! `cli::run`).

use crate::report::junit;
use crate::report::measurements::{run_suite, RunOutcome};
use crate::runtime::records::MAX_KEPT_RECORDS;
use crate::script::rig::Rig;
use crate::service::notify::Notifier;
use std::path::PathBuf;
use std::time::Instant;

/// Log lines (warnings and errors) a JUnit report carries at most.
pub const MAX_REPORTED_PROBLEMS: usize = 100;

/// The outputs of one run.
pub struct RunOutputs {
    script: String,
    junit: Option<PathBuf>,
    notifier: Option<Notifier>,
    started: Instant,
    started_at: String,
}

impl RunOutputs {
    /// Outputs for a run of `script`: a JUnit report to `junit` if given, and systemd's
    /// notifier if the environment asks for one (a bad setting is reported on stderr and the
    /// run goes on without it). Refuses a report path whose directory does not exist, before
    /// anything runs.
    pub fn new(script: &str, junit: Option<PathBuf>) -> Result<Self, String> {
        if let Some(path) = &junit {
            junit::check_path(path)?;
        }
        let notifier = Notifier::from_env().unwrap_or_else(|e| {
            super::output::say(&format!("rigscript run: {e}"));
            None
        });
        Ok(Self {
            script: script.to_string(),
            junit,
            notifier,
            started: Instant::now(),
            started_at: junit::timestamp_now(),
        })
    }

    /// systemd's notifier, for the run to attach (once).
    pub fn take_notifier(&mut self) -> Option<Notifier> {
        self.notifier.take()
    }

    /// Whether the run should keep its log in memory (the report quotes its problems).
    pub fn keeps_log(&self) -> bool {
        self.junit.is_some()
    }

    /// The run could not start: writes the report with `error`; returns the exit status.
    pub fn not_started(&self, status: i32, error: &str) -> i32 {
        let problems = [error.to_string()];
        self.write_report(status, &[], false, &problems)
    }

    /// The run ended with `status`: the report; returns the exit status (1 instead of 0 if
    /// the report could not be written).
    pub fn finished(&mut self, rig: &Rig, status: i32) -> i32 {
        if self.junit.is_none() {
            return status;
        }
        let rt = rig.runner.runtime().borrow();
        let records = rt.records_kept();
        let problems: Vec<String> = rt
            .log_lines()
            .iter()
            .filter(|l| l.contains(" warning: ") || l.contains(" error: "))
            .cloned()
            .collect();
        let tail = problems.len().saturating_sub(MAX_REPORTED_PROBLEMS);
        let truncated = records.len() >= MAX_KEPT_RECORDS;
        self.write_report(
            status,
            records,
            truncated,
            problems.get(tail..).unwrap_or(&[]),
        )
    }

    fn write_report(
        &self,
        status: i32,
        records: &[serde_json::Value],
        records_truncated: bool,
        problems: &[String],
    ) -> i32 {
        let Some(path) = &self.junit else {
            return status;
        };
        let suite = run_suite(&RunOutcome {
            script: &self.script,
            started: self.started_at.clone(),
            elapsed: self.started.elapsed(),
            status,
            records,
            records_truncated,
            problems,
        });
        match junit::write(path, &[suite]) {
            Ok(()) => status,
            Err(e) => {
                super::output::say(&format!(
                    "rigscript run: cannot write the JUnit report {}: {e}",
                    path.display()
                ));
                if status == 0 {
                    1
                } else {
                    status
                }
            }
        }
    }
}
