//! What the scan loop and a script agree on: the `Program` it runs, how a handler fails, how a
//! run is driven and why it ended.

use crate::config::{ErrorPolicy, WakeLatency};
use crate::runtime::handlers::Call;
use crate::runtime::invariants::InvariantCheck;
use crate::runtime::signals;
use crate::runtime::state::Runtime;
use std::cell::RefCell;
use std::rc::Rc;
use std::sync::atomic::AtomicUsize;
use std::sync::Arc;
use std::time::Duration;

/// The runtime shared between the scan loop and the script's bindings.
pub type Shared<H> = Rc<RefCell<Runtime<H>>>;

/// Why a handler failed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HandlerFault {
    /// `file:line:column` of the fault, when known.
    pub location: Option<String>,
    /// What went wrong.
    pub cause: String,
    /// The handler ran over a limit that running it again would hit again (operations or
    /// time per call, memory): a runaway, never skipped.
    pub over_budget: bool,
}

/// What bounds an `on_stop` call besides the script's limits per call.
#[derive(Debug, Clone)]
pub struct StopLimit {
    /// When the budget of all the stop's `on_stop` handlers runs out, on the run's clock.
    pub until: Duration,
    /// That budget (`handlers::STOP_BUDGET`), for the message.
    pub budget: Duration,
    /// The run's stop flag, cleared as the stop began: set again by another signal.
    pub signal: Arc<AtomicUsize>,
}

/// The script, as the scan loop sees it.
pub trait Program {
    /// The script's handler type.
    type Handler: Clone;
    /// Runs the script's top level from scratch (it adds handlers and timers).
    fn start(&mut self) -> Result<(), HandlerFault>;
    /// Runs one handler.
    fn call(&mut self, call: &Call<Self::Handler>) -> Result<(), HandlerFault>;
    /// Runs one handler for its value, as JSON text (an `on_command` handler: its reply);
    /// a program without values answers `null`.
    fn answer(&mut self, call: &Call<Self::Handler>) -> Result<String, HandlerFault> {
        self.call(call).map(|()| "null".to_string())
    }
    /// Compiles `source` (the file `file`) to replace the script at the next `swap` (a
    /// reload); refused with why. A program that cannot be replaced refuses every one.
    fn stage(&mut self, source: &str, file: &str) -> Result<(), String> {
        let _ = (source, file);
        Err("this run's program cannot be reloaded".into())
    }
    /// Runs the staged script's top level in place of the running one (whose handlers the
    /// runtime has set aside) and gives its top-level variables the old values where they
    /// match: the names carried.
    fn swap(&mut self) -> Result<Vec<String>, HandlerFault> {
        Err(HandlerFault {
            location: None,
            cause: "this run's program cannot be reloaded".into(),
            over_budget: false,
        })
    }
    /// Puts the script before the last `swap` back, its variables as they were.
    fn swap_back(&mut self) {}
    /// Forgets the script before the last `swap`: the swap stands.
    fn settle(&mut self) {}
    /// The top-level variables a person may watch (the page, `status`); a program without
    /// variables shows none.
    fn variables(&self) -> crate::runtime::snapshot::Variables {
        crate::runtime::snapshot::Variables::default()
    }
    /// Evaluates an invariant: whether it holds.
    fn holds(&mut self, check: &InvariantCheck<Self::Handler>) -> Result<bool, HandlerFault>;
    /// Runs an `on_stop` handler, stopped also once `limit` runs out or another signal
    /// comes; a program without a way to stop a call midway just runs it.
    fn call_in_stop(
        &mut self,
        call: &Call<Self::Handler>,
        limit: StopLimit,
    ) -> Result<(), HandlerFault> {
        let _ = limit;
        self.call(call)
    }
}

/// How a run is driven.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Scan period.
    pub period: Duration,
    /// What a handler error does.
    pub policy: ErrorPolicy,
    /// End the run normally after this long (`--for`).
    pub end_after: Option<Duration>,
    /// The number of the signal that asks the run to stop (`signals::ENDING`; 0: none), set by
    /// the signal handler or a scenario test: stop at once, outputs safe. It also cuts the
    /// exchange under way short (`device::cancel`), within a `CANCEL_SLICE`.
    pub stop_flag: Arc<AtomicUsize>,
    /// What `run` asks of the CPUs' idle states while it runs in real time (`auto`: a 0 µs
    /// request while the loop ticks every 20 ms or faster, re-evaluated as handlers come
    /// and go).
    pub wake_latency: WakeLatency,
}

/// Why a run ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum EndReason {
    /// `--for` elapsed, or the script has nothing left to wait for.
    Finished(String),
    /// The script called `stop(code)`.
    Stopped(i64),
    /// An ending signal (`runtime::signals::ENDING`: the signal's number).
    Signal(i32),
    /// A script or runtime error (policy `stop`, or at the first start).
    Error(String),
    /// An invariant was found false (`runtime::invariants`).
    Violated(String),
    /// Someone asked for a stop through the control queue (`runtime::requests`): who.
    Requested(String),
}

impl std::fmt::Display for EndReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            EndReason::Finished(why) => write!(f, "{why}"),
            EndReason::Stopped(code) => write!(f, "the script called stop({code})"),
            EndReason::Signal(n) => write!(f, "{} received", signals::name(*n)),
            EndReason::Error(m) => write!(f, "script error: {m}"),
            EndReason::Violated(m) => write!(f, "{m}"),
            EndReason::Requested(by) => write!(f, "stop asked by {by}"),
        }
    }
}

/// `file:line:col: in handler: cause` (a limit's cause says which limit and how to raise it).
pub(super) fn describe(fault: &HandlerFault, label: &str) -> String {
    match &fault.location {
        Some(at) => format!("{at}: in {label}: {}", fault.cause),
        None => format!("in {label}: {}", fault.cause),
    }
}
