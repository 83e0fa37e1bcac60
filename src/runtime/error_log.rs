//! The script errors of one run, in order, for scenario tests (`r.errors()`) and `verify`
//! (whose built-in checks are "no script error" and "no handler over its budget"). The first
//! `MAX_KEPT_ERRORS` are kept; later ones are counted.

/// Errors kept per run; a script failing every tick under policy `skip` is counted past this.
pub const MAX_KEPT_ERRORS: usize = 100;

/// One script error as the log showed it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ScriptError {
    /// `file:line:col: in handler: cause`.
    pub message: String,
    /// The handler ran over its operation budget.
    pub over_budget: bool,
}

/// The script errors of a run.
#[derive(Debug, Clone, Default)]
pub struct ErrorLog {
    kept: Vec<ScriptError>,
    total: u64,
    last: Option<ScriptError>,
}

impl ErrorLog {
    /// Notes an error.
    pub fn push(&mut self, message: &str, over_budget: bool) {
        self.total = self.total.saturating_add(1);
        let error = ScriptError {
            message: message.to_string(),
            over_budget,
        };
        if self.kept.len() < MAX_KEPT_ERRORS {
            self.kept.push(error.clone());
        }
        self.last = Some(error);
    }

    /// The errors kept, oldest first.
    pub fn kept(&self) -> &[ScriptError] {
        &self.kept
    }

    /// The latest error, kept or not.
    pub fn last(&self) -> Option<&ScriptError> {
        self.last.as_ref()
    }

    /// How many errors there were in all (kept or not).
    pub fn total(&self) -> u64 {
        self.total
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_errors_are_kept_and_all_are_counted() {
        let mut log = ErrorLog::default();
        for i in 0..MAX_KEPT_ERRORS + 5 {
            log.push(&format!("e{i}"), i == 0);
        }
        assert_eq!(log.total(), (MAX_KEPT_ERRORS + 5) as u64);
        assert_eq!(log.kept().len(), MAX_KEPT_ERRORS);
        assert!(log.kept()[0].over_budget);
        assert_eq!(log.kept()[1].message, "e1");
        assert_eq!(
            log.last().map(|e| e.message.as_str()),
            Some(format!("e{}", MAX_KEPT_ERRORS + 4).as_str()),
            "the latest is known past the kept ones"
        );
    }
}
