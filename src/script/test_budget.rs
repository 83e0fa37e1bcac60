//! What one scenario test may use: a run's limits for the test's own code (operations, heap
//! memory, which the rigs it builds count against), and per test a virtual-time budget (what
//! `advance`, `tick` and `stall` may move the clock by in all) and a wall-time budget; and the
//! script errors of its rigs that the test never looked at, which fail it.

use super::engine::Breach;
use crate::config::{ScriptLimits, DEFAULT_MEMORY, DEFAULT_TIMERS};
use crate::heap::format_bytes;
use crate::time::duration::format_duration;
use std::cell::{Cell, RefCell};
use std::time::{Duration, Instant};

/// Operations a test function may take (its own, not the script under test's).
pub const TEST_BUDGET: u64 = 50_000_000;

/// Virtual time one test may move its rigs' clocks by, in all: a month of a rig's life.
pub const VIRTUAL_TIME_BUDGET: Duration = Duration::from_secs(30 * 24 * 3600);

/// Real time one test may take.
pub const WALL_TIME_BUDGET: Duration = Duration::from_secs(60);

/// The limits of a test function's own calls (its operations, its wall time, the heap it and
/// its rigs hold); the script under test keeps its rig's.
pub fn test_limits() -> ScriptLimits {
    ScriptLimits {
        operations: TEST_BUDGET,
        handler_time: WALL_TIME_BUDGET,
        memory: DEFAULT_MEMORY,
        timers: DEFAULT_TIMERS,
    }
}

/// A limit the test's own code went over, in words for its failure.
pub fn breach_text(breach: &Breach) -> String {
    match breach {
        Breach::Operations { budget } => format!(
            "the test ran over its operation budget of {budget} operations (a runaway loop?)"
        ),
        Breach::Time { limit } => format!(
            "the test ran for more than {} of real time, its wall-time budget",
            format_duration(*limit)
        ),
        Breach::Memory { limit, used } => format!(
            "the test's memory reached {}, over its limit of {} (rigs built in a loop? each rig \
             a test builds counts against it)",
            format_bytes(*used),
            format_bytes(*limit)
        ),
        other => other.cause(),
    }
}

/// One test's budgets, shared by the rigs it builds.
pub struct TestBudget {
    moved: Cell<Duration>,
    deadline: Instant,
    unobserved: RefCell<Option<String>>,
}

impl TestBudget {
    /// A test starts now.
    pub fn start() -> Self {
        Self::with_wall_time(WALL_TIME_BUDGET)
    }

    /// A test starts now with `wall` of real time (tests of the budget itself).
    pub(crate) fn with_wall_time(wall: Duration) -> Self {
        Self {
            moved: Cell::new(Duration::ZERO),
            deadline: Instant::now() + wall,
            unobserved: RefCell::new(None),
        }
    }

    /// Takes `by` of virtual time for `what` (`r.advance("1h")`), or says why the test may
    /// not move its clock that far.
    pub fn take_virtual(&self, what: &str, by: Duration) -> Result<(), String> {
        let used = self.moved.get();
        match used.checked_add(by) {
            Some(total) if total <= VIRTUAL_TIME_BUDGET => {
                self.moved.set(total);
                Ok(())
            }
            _ => Err(format!(
                "{what} would take the test past its virtual-time budget of {} ({} used): a \
                 test moves a rig's clock by at most that in all; split the scenario into tests",
                format_duration(VIRTUAL_TIME_BUDGET),
                format_duration(used)
            )),
        }
    }

    /// Notes virtual time `what` has already moved the clock by (a tick that skipped idle
    /// ticks); an error if that took the test past its budget.
    pub fn note_virtual(&self, what: &str, by: Duration) -> Result<(), String> {
        let used = self.moved.get();
        self.take_virtual(what, by).inspect_err(|_| {
            self.moved.set(used.saturating_add(by));
        })
    }

    /// Whether the test still has wall time left.
    pub fn wall_time_left(&self) -> bool {
        Instant::now() < self.deadline
    }

    /// The failure of a test whose wall time ran out during `what`.
    pub fn out_of_wall_time(what: &str) -> String {
        format!(
            "the test ran out of its wall-time budget of {} during {what} (a rig polling fast \
             over a long advance?)",
            format_duration(WALL_TIME_BUDGET)
        )
    }

    /// Notes script errors of a rig the test never looked at (the first such rig's).
    pub fn note_unobserved(&self, errors: u64, first: &str) {
        let mut slot = self.unobserved.borrow_mut();
        if slot.is_none() {
            *slot = Some(format!(
                "the script under test had {errors} error(s) the test did not look at, the \
                 first: {first}; a test that expects errors says so with r.expect_errors() or \
                 checks r.errors()"
            ));
        }
    }

    /// Script errors no test code looked at, if there were any.
    pub fn unobserved(&self) -> Option<String> {
        self.unobserved.borrow().clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn virtual_time_is_budgeted_over_the_whole_test() {
        let b = TestBudget::start();
        b.take_virtual("r.advance(\"20d\")", Duration::from_secs(20 * 86400))
            .unwrap();
        let e = b
            .take_virtual("r.advance(\"20d\")", Duration::from_secs(20 * 86400))
            .unwrap_err();
        assert!(
            e.starts_with("r.advance(\"20d\") would take the test past its virtual-time budget of"),
            "{e}"
        );
        assert!(e.contains("split the scenario into tests"), "{e}");
        b.take_virtual("r.advance(\"10d\")", Duration::from_secs(10 * 86400))
            .unwrap();
        assert!(b.note_virtual("r.tick()", Duration::from_secs(1)).is_err());
        assert!(b.take_virtual("r.stall(\"1s\")", Duration::MAX).is_err());
    }
}
