//! The sandboxed Rhai engine: no file, process or network access (Rhai has none without
//! modules, and this build has no modules: `import` does not parse), `eval` disabled, and
//! limits on operations per handler call, call depth, expression depth, string, array and
//! map sizes. Printing goes through the runner's log.
//!
//! A run's engine also gets a `Guard`, which stops a call that goes over the run's limits
//! (`config::ScriptLimits`): operations and time on the run's clock per call, heap memory,
//! call depth, and the size of a string, array or map each time a variable holding one is
//! used (so a map filled by `m[key] = v` is stopped as it grows, not when next passed on).
//!
//! Where it stopped: Rhai reports its own limit errors inside a script function without a
//! position (it passes them out of every call unchanged), so a handler over a limit would
//! name no line. The guard therefore raises its error as an ordinary script error at the
//! next variable used after the breach, which Rhai places exactly; and since a script could
//! catch that, the breach stays on record until the call ends, and a call that goes on
//! regardless is cut off (uncatchably) after `GRACE_OPERATIONS`. Rhai's own limits stay set
//! just beyond the guard's as a backstop.

use crate::config::ScriptLimits;
use crate::heap::{self, format_bytes};
use crate::runtime::runner::StopLimit;
use crate::time::clock::SharedClock;
use crate::time::duration::format_duration;
use rhai::packages::{Package, StandardPackage};
use rhai::{Array, Dynamic, Engine, EvalAltResult, EvalContext, ImmutableString, Map, Position};
use std::cell::Cell;
use std::rc::Rc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Operations one handler call (or the top level) may take unless configured otherwise.
pub const DEFAULT_BUDGET: u64 = crate::config::DEFAULT_OPERATIONS;

/// Deepest function call nesting.
pub const MAX_CALL_LEVELS: usize = 48;
/// Longest string, in bytes.
pub const MAX_STRING: usize = 64 * 1024;
/// Most elements of an array.
pub const MAX_ARRAY: usize = 10_000;
/// Most entries of a map.
pub const MAX_MAP: usize = 10_000;
/// Most variables alive in one scope chain.
pub const MAX_VARIABLES: usize = 1_000;
/// Most functions a script may define.
pub const MAX_FUNCTIONS: usize = 1_000;

/// Operations a call may still take after a breach before it is cut off without waiting for
/// a variable to place the error.
pub const GRACE_OPERATIONS: u64 = 100;

/// The clock is read at least this often (in operations) to enforce the time per call, and
/// also after every device exchange (the slow operations).
const CLOCK_EVERY: u64 = 64;

/// Marks the errors the guard raises (`error::fault` turns them into the breach's words).
pub const LIMIT_MARKER: &str = "rigscript limit: ";

/// A new engine with the sandbox and its limits; `budget` is the operation budget of each
/// call into the script. Prints are dropped until the caller routes them (`on_print`).
pub fn sandboxed(budget: u64) -> Engine {
    thread_local! {
        // Rhai's standard package, built once a thread and shared: `verify` makes an engine
        // for every run, and building the package was most of that.
        static STANDARD: rhai::Shared<rhai::Module> = StandardPackage::new().as_shared_module();
    }
    // What `Engine::new` makes (the package, its string interner at Rhai's default size; the
    // printing it sets up is replaced below).
    let mut engine = Engine::new_raw();
    engine.set_max_strings_interned(rhai::default_limits::MAX_STRINGS_INTERNED);
    engine.register_global_module(STANDARD.with(rhai::Shared::clone));
    engine.disable_symbol("eval");
    engine.set_max_operations(budget.max(1));
    engine.set_max_call_levels(MAX_CALL_LEVELS);
    engine.set_max_expr_depths(64, 32);
    engine.set_max_string_size(MAX_STRING);
    engine.set_max_array_size(MAX_ARRAY);
    engine.set_max_map_size(MAX_MAP);
    engine.set_max_variables(MAX_VARIABLES);
    engine.set_max_functions(MAX_FUNCTIONS);
    engine.on_print(|_| {});
    engine.on_debug(|_, _, _| {});
    engine
}

/// A limit a call went over.
#[derive(Debug, Clone, PartialEq)]
pub enum Breach {
    /// More operations than the budget.
    Operations {
        /// The budget.
        budget: u64,
    },
    /// Longer than the time per call.
    Time {
        /// The limit.
        limit: Duration,
    },
    /// The heap grew past the run's memory limit.
    Memory {
        /// The limit, in bytes.
        limit: u64,
        /// Heap the run held when it was noticed (`heap::RunHeap`).
        used: u64,
    },
    /// An `on_stop` handler ran past what was left of the stop's budget for all of them.
    StopBudget {
        /// The budget of all the `on_stop` handlers together.
        budget: Duration,
    },
    /// Another ending signal came while an `on_stop` handler ran: the stop goes straight to
    /// the safe state.
    StopCut,
    /// Function calls nested too deep.
    Depth,
    /// A string, array or map grew past its size limit.
    Size {
        /// "string", "array" or "map".
        what: &'static str,
        /// Its length (bytes, elements or entries).
        len: usize,
        /// The most allowed.
        max: usize,
    },
}

impl Breach {
    /// Whether running the handler again would run away again (operations, time, memory):
    /// such a handler is never skipped.
    pub fn is_runaway(&self) -> bool {
        matches!(
            self,
            Breach::Operations { .. }
                | Breach::Time { .. }
                | Breach::Memory { .. }
                | Breach::StopBudget { .. }
        )
    }

    /// What happened and how to raise the limit, in words.
    pub fn cause(&self) -> String {
        match self {
            Breach::Operations { budget } => format!(
                "ran over its operation budget of {budget} operations in one call (a runaway \
                 loop?); a call that needs more can have it with --budget, or `operations` \
                 under [limits] in rig.toml"
            ),
            Breach::Time { limit } => format!(
                "ran for more than {} in one call (a loop waiting on a device?); a call that \
                 needs longer can have it with --handler-time, or `handler_time` under [limits] \
                 in rig.toml",
                format_duration(*limit)
            ),
            Breach::Memory { limit, used } => format!(
                "the run's memory reached {}, over its limit of {} (timers or data the script \
                 keeps growing?); raise it with --memory-limit, or `memory` under [limits] in \
                 rig.toml",
                format_bytes(*used),
                format_bytes(*limit)
            ),
            Breach::StopBudget { budget } => format!(
                "the on_stop handlers ran past the {} they have together (a stop must reach \
                 the safe state whatever the script does): do less in on_stop",
                format_duration(*budget)
            ),
            Breach::StopCut => "cut off by another signal while stopping".into(),
            Breach::Depth => format!(
                "function calls nested more than {MAX_CALL_LEVELS} deep (runaway recursion?)"
            ),
            Breach::Size { what, len, max } => {
                let unit = match *what {
                    "string" => "bytes",
                    "array" => "elements",
                    _ => "entries",
                };
                format!("a {what} grew to {len} {unit}, over the limit of {max}")
            }
        }
    }

    fn error(&self) -> Box<EvalAltResult> {
        let text = format!("{LIMIT_MARKER}{}", self.cause());
        EvalAltResult::ErrorRuntime(Dynamic::from(text), Position::NONE).into()
    }
}

/// The run's limits, watched while the script runs (see the module's doc).
pub struct Guard {
    limits: ScriptLimits,
    clock: SharedClock,
    transactions: Arc<AtomicU64>,
    started: Cell<Duration>,
    seen_transactions: Cell<u64>,
    breach: std::cell::RefCell<Option<Breach>>,
    cut_off_at: Cell<u64>,
    heap: heap::RunHeap,
    /// Within a stop, for this call: when the stop's budget runs out, and the flag another
    /// signal sets.
    stop: std::cell::RefCell<Option<StopLimit>>,
    /// Whether `stop` is set: the one thing looked at per operation outside a stop.
    in_stop: Cell<bool>,
}

impl Guard {
    /// Watches every call `engine` makes: time on `clock`, a clock reading after each new
    /// request counted by `transactions`, and the heap the run holds (when `heap::CountingAlloc`
    /// counts it; the run is the one on this thread, starting now).
    pub fn install(
        engine: &mut Engine,
        limits: ScriptLimits,
        clock: SharedClock,
        transactions: Arc<AtomicU64>,
    ) -> Rc<Guard> {
        let guard = Rc::new(Guard {
            limits,
            clock,
            transactions,
            started: Cell::new(Duration::ZERO),
            seen_transactions: Cell::new(0),
            breach: std::cell::RefCell::new(None),
            cut_off_at: Cell::new(0),
            heap: heap::RunHeap::start(),
            stop: std::cell::RefCell::new(None),
            in_stop: Cell::new(false),
        });
        guard.begin_call();
        // Rhai's own limits, beyond the guard's: a backstop for what the guard cannot see
        // (a string doubled inside an array, recursion that uses no variable).
        engine.set_max_operations(
            limits
                .operations
                .max(1)
                .saturating_add(GRACE_OPERATIONS + 1),
        );
        engine.set_max_call_levels(MAX_CALL_LEVELS + 4);
        engine.set_max_string_size(MAX_STRING * 2);
        engine.set_max_array_size(MAX_ARRAY * 2);
        engine.set_max_map_size(MAX_MAP * 2);
        let g = Rc::clone(&guard);
        engine.on_progress(move |ops| g.progress(ops));
        guard
    }

    /// The limits watched.
    pub fn limits(&self) -> &ScriptLimits {
        &self.limits
    }

    /// A call into the script starts now.
    pub fn begin_call(&self) {
        self.started.set(self.clock.now());
        self.seen_transactions
            .set(self.transactions.load(Ordering::Relaxed));
        self.breach.replace(None);
        self.stop.replace(None);
        self.in_stop.set(false);
    }

    /// The call that just began is an `on_stop` handler's, bounded by `limit` too.
    pub fn within_stop(&self, limit: StopLimit) {
        self.stop.replace(Some(limit));
        self.in_stop.set(true);
    }

    /// The call has ended: the limit it went over, if any (whether or not the script caught
    /// the error).
    pub fn end_call(&self) -> Option<Breach> {
        self.breach.replace(None)
    }

    /// Checks a variable as the script uses it (call from the engine's variable resolver):
    /// an error, placed at the variable, once a limit has been hit in this call, when calls
    /// nest too deep, or when the string, array or map it holds is over its size limit.
    pub fn check_var(
        &self,
        value: Option<&Dynamic>,
        ctx: &EvalContext,
    ) -> Result<(), Box<EvalAltResult>> {
        if let Some(b) = self.breach.borrow().as_ref() {
            return Err(b.error());
        }
        let breach = if ctx.call_level() > MAX_CALL_LEVELS {
            Some(Breach::Depth)
        } else {
            value.and_then(oversized)
        };
        match breach {
            Some(b) => {
                let err = b.error();
                self.trip(b, 0);
                Err(err)
            }
            None => Ok(()),
        }
    }

    fn progress(&self, ops: u64) -> Option<Dynamic> {
        if self.breach.borrow().is_some() {
            if ops >= self.cut_off_at.get() {
                // No variable came to place the error, or the script caught it and went on.
                let text = format!("{LIMIT_MARKER}{}", self.breach.borrow().as_ref()?.cause());
                return Some(Dynamic::from(text));
            }
            return None;
        }
        if let Some(b) = self.over(ops) {
            self.trip(b, ops);
        }
        None
    }

    fn over(&self, ops: u64) -> Option<Breach> {
        if ops > self.limits.operations {
            return Some(Breach::Operations {
                budget: self.limits.operations,
            });
        }
        if let Some(used) = self.heap.over(self.limits.memory) {
            return Some(Breach::Memory {
                limit: self.limits.memory,
                used,
            });
        }
        if self.in_stop.get() && self.stop_signalled() {
            return Some(Breach::StopCut);
        }
        let tx = self.transactions.load(Ordering::Relaxed);
        if ops % CLOCK_EVERY == 0 || tx != self.seen_transactions.get() {
            // The script makes progress: the loop is alive (its time is bounded here).
            crate::guardian::pulse::beat();
            self.seen_transactions.set(tx);
            let now = self.clock.now();
            let ran = now.saturating_sub(self.started.get());
            if ran > self.limits.handler_time {
                return Some(Breach::Time {
                    limit: self.limits.handler_time,
                });
            }
            if let Some(budget) = self.in_stop.get().then(|| self.stop_over(now)).flatten() {
                return Some(Breach::StopBudget { budget });
            }
        }
        None
    }

    /// Within a stop: whether another signal has come.
    fn stop_signalled(&self) -> bool {
        self.stop
            .borrow()
            .as_ref()
            .is_some_and(|s| s.signal.load(Ordering::Relaxed) != 0)
    }

    /// Within a stop: its budget, if it is spent at `now`.
    fn stop_over(&self, now: Duration) -> Option<Duration> {
        let stop = self.stop.borrow();
        let stop = stop.as_ref()?;
        (now > stop.until).then_some(stop.budget)
    }

    fn trip(&self, breach: Breach, ops: u64) {
        // A stop's limits cut at the next operation: reaching the safe state matters more
        // than a line for the error (each operation could be a device exchange).
        let grace = match breach {
            Breach::StopBudget { .. } | Breach::StopCut => 0,
            _ => GRACE_OPERATIONS,
        };
        self.cut_off_at.set(ops.saturating_add(grace));
        self.breach.replace(Some(breach));
    }
}

/// A string, array or map over its size limit (by its own length; Rhai's backstop counts
/// what is nested).
fn oversized(v: &Dynamic) -> Option<Breach> {
    let (what, len, max) = if v.is_string() {
        (
            "string",
            v.read_lock::<ImmutableString>()?.len(),
            MAX_STRING,
        )
    } else if v.is_array() {
        ("array", v.read_lock::<Array>()?.len(), MAX_ARRAY)
    } else if v.is_map() {
        ("map", v.read_lock::<Map>()?.len(), MAX_MAP)
    } else {
        return None;
    };
    (len > max).then_some(Breach::Size { what, len, max })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::time::clock::{Clock, VirtualClock};

    #[test]
    fn import_and_eval_are_refused() {
        let e = sandboxed(DEFAULT_BUDGET);
        assert!(e.compile(r#"import "os" as os;"#).is_err());
        let err = e.compile(r#"eval("1 + 1")"#).unwrap_err();
        assert!(err.to_string().contains("eval"), "{err}");
    }

    #[test]
    fn a_runaway_loop_hits_the_budget() {
        let e = sandboxed(10_000);
        let err = e.run("loop { }").unwrap_err();
        assert!(
            matches!(*err, EvalAltResult::ErrorTooManyOperations(..)),
            "{err}"
        );
    }

    #[test]
    fn strings_arrays_and_recursion_are_bounded() {
        let e = sandboxed(DEFAULT_BUDGET);
        assert!(matches!(
            *e.run(r#"let s = "x"; loop { s += s; }"#).unwrap_err(),
            EvalAltResult::ErrorDataTooLarge(..)
        ));
        assert!(matches!(
            *e.run("let a = []; loop { a.push(1); }").unwrap_err(),
            EvalAltResult::ErrorDataTooLarge(..)
        ));
        let deep = e.run("fn f(n) { f(n + 1) } f(0);").unwrap_err();
        assert!(
            matches!(*deep, EvalAltResult::ErrorStackOverflow(..)),
            "{deep}"
        );
    }

    /// An engine with a guard whose variable checks are wired as the script API wires them.
    fn guarded(limits: ScriptLimits, clock: &VirtualClock) -> (Engine, Rc<Guard>) {
        guarded_counting(limits, clock, Arc::default())
    }

    /// The same, counting device exchanges in `transactions`.
    fn guarded_counting(
        limits: ScriptLimits,
        clock: &VirtualClock,
        transactions: Arc<AtomicU64>,
    ) -> (Engine, Rc<Guard>) {
        let mut e = sandboxed(limits.operations);
        let guard = Guard::install(&mut e, limits, Arc::new(clock.clone()), transactions);
        let g = Rc::clone(&guard);
        #[allow(deprecated)]
        e.on_var(move |name, _, ctx| {
            let value = ctx.scope().get(name).cloned();
            g.check_var(value.as_ref(), &ctx).map(|()| None)
        });
        (e, guard)
    }

    fn budget(operations: u64) -> ScriptLimits {
        ScriptLimits {
            operations,
            ..ScriptLimits::default()
        }
    }

    fn limit_error(err: &EvalAltResult) -> (String, Position) {
        let (inner, pos) = crate::script::error::innermost(err);
        (inner.to_string(), pos)
    }

    #[test]
    fn a_loop_over_budget_is_stopped_at_a_variable_with_its_line() {
        let clock = VirtualClock::at_epoch();
        let (e, guard) = guarded(budget(10_000), &clock);
        guard.begin_call();
        let err = e.run("let x = 0;\nloop {\n  x += 1;\n}").unwrap_err();
        let (text, pos) = limit_error(&err);
        assert!(text.contains("operation budget of 10000"), "{text}");
        assert!(text.contains("--budget"), "{text}");
        assert_eq!(pos.line(), Some(3), "{err:?}");
        assert!(matches!(guard.end_call(), Some(Breach::Operations { .. })));
    }

    #[test]
    fn a_caught_breach_is_cut_off_and_still_reported() {
        let clock = VirtualClock::at_epoch();
        let (e, guard) = guarded(budget(10_000), &clock);
        guard.begin_call();
        let err = e
            .run("let x = 0;\nloop { try { x += 1; } catch { } }")
            .unwrap_err();
        assert!(
            matches!(*err, EvalAltResult::ErrorTerminated(..)),
            "uncatchable in the end: {err:?}"
        );
        assert!(matches!(guard.end_call(), Some(Breach::Operations { .. })));
        // A script that catches the error and returns is reported all the same.
        guard.begin_call();
        let caught = e.run("let x = 0;\ntry { loop { x += 1; } } catch { }");
        assert!(caught.is_ok());
        assert!(matches!(guard.end_call(), Some(Breach::Operations { .. })));
        // A fresh call starts with a clean slate.
        guard.begin_call();
        e.run("let y = 1;").unwrap();
        assert_eq!(guard.end_call(), None);
    }

    #[test]
    fn time_per_call_is_on_the_runs_clock() {
        let clock = VirtualClock::at_epoch();
        let limits = ScriptLimits {
            handler_time: Duration::from_millis(500),
            ..ScriptLimits::default()
        };
        let transactions = Arc::new(AtomicU64::new(0));
        let (mut e, guard) = guarded_counting(limits, &clock, Arc::clone(&transactions));
        let c = clock.clone();
        // A device exchange that takes 100 ms of the run's time.
        e.register_fn("slow", move || {
            transactions.fetch_add(1, Ordering::Relaxed);
            c.advance(Duration::from_millis(100));
        });
        guard.begin_call();
        e.run("let n = 0;\nwhile n < 4 { slow(); n += 1; }")
            .unwrap();
        assert_eq!(guard.end_call(), None, "400 ms is within 500 ms");
        guard.begin_call();
        let err = e
            .run("let n = 0;\nwhile n < 100 {\n  slow();\n  n += 1;\n}")
            .unwrap_err();
        let (text, pos) = limit_error(&err);
        assert!(text.contains("ran for more than 500ms"), "{text}");
        assert!(text.contains("--handler-time"), "{text}");
        assert!(pos.line().is_some(), "{err:?}");
        assert!(matches!(guard.end_call(), Some(Breach::Time { .. })));
        assert!(
            clock.now() <= Duration::from_millis(400 + 700),
            "stopped at the first exchange past 500 ms: {:?}",
            clock.now()
        );
    }

    #[test]
    fn a_map_is_stopped_as_it_grows() {
        let clock = VirtualClock::at_epoch();
        let (e, guard) = guarded(ScriptLimits::default(), &clock);
        guard.begin_call();
        let err = e
            .run("let m = #{};\nfor i in 0..20000 {\n  m[\"k\" + i] = i;\n}")
            .unwrap_err();
        let (text, pos) = limit_error(&err);
        assert!(
            text.contains("a map grew to 10001 entries, over the limit of 10000"),
            "{text}"
        );
        assert_eq!(pos.line(), Some(3), "{err:?}");
    }

    #[test]
    fn deep_recursion_is_placed_where_it_recurses() {
        let clock = VirtualClock::at_epoch();
        let (e, guard) = guarded(ScriptLimits::default(), &clock);
        guard.begin_call();
        let err = e.run("fn f(n) {\n  f(n + 1)\n}\nf(0);").unwrap_err();
        let (text, pos) = limit_error(&err);
        assert!(text.contains("nested more than 48 deep"), "{text}");
        assert_eq!(pos.line(), Some(2), "{err:?}");
    }

    #[test]
    fn a_call_in_a_stop_ends_with_the_stops_budget_or_another_signal() {
        let clock = VirtualClock::at_epoch();
        let transactions = Arc::new(AtomicU64::new(0));
        let (mut e, guard) =
            guarded_counting(ScriptLimits::default(), &clock, Arc::clone(&transactions));
        let c = clock.clone();
        // A device exchange that takes 100 ms of the run's time.
        e.register_fn("slow", move || {
            transactions.fetch_add(1, Ordering::Relaxed);
            c.advance(Duration::from_millis(100));
        });
        let signal = Arc::new(std::sync::atomic::AtomicUsize::new(0));
        let limit = StopLimit {
            until: clock.now() + Duration::from_millis(250),
            budget: Duration::from_secs(2),
            signal: Arc::clone(&signal),
        };
        guard.begin_call();
        guard.within_stop(limit.clone());
        let _ = e.run("loop {\n  slow();\n}").unwrap_err();
        let breach = guard.end_call();
        assert_eq!(
            breach,
            Some(Breach::StopBudget {
                budget: Duration::from_secs(2)
            })
        );
        let cause = breach.map(|b| b.cause()).unwrap_or_default();
        assert!(
            cause.contains("ran past the 2s they have together"),
            "{cause}"
        );
        assert!(
            clock.now() <= Duration::from_millis(400),
            "{:?}",
            clock.now()
        );
        // Another signal cuts it at once, budget or not.
        guard.begin_call();
        guard.within_stop(StopLimit {
            until: clock.now() + Duration::from_secs(60),
            ..limit
        });
        signal.store(15, Ordering::SeqCst);
        let _ = e.run("let x = 0;\nloop { x += 1; }").unwrap_err();
        assert_eq!(guard.end_call(), Some(Breach::StopCut));
        // Outside a stop neither applies.
        guard.begin_call();
        e.run("let y = 0;\nwhile y < 10 { y += 1; }").unwrap();
        assert_eq!(guard.end_call(), None);
    }
}
