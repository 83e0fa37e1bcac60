//! A compiled script as the scan loop's program: its top level adds handlers and timers,
//! and each handler call gets a fresh operation budget and time limit, and only the arguments
//! it takes. A call over a limit is a fault placed where the limit was hit.

use super::api::{register, resolve_variables, Arities, Handler, Rt};
use super::check::NotFound;
use super::engine::{sandboxed, Guard};
use super::error::{breach_fault, fault, innermost, is_stop};
use super::reads::{ReadSet, ReadTracker};
use super::watched::Watch;
use crate::config::ScriptLimits;
use crate::runtime::handlers::{Arg, Call};
use crate::runtime::invariants::InvariantCheck;
use crate::runtime::runner::{HandlerFault, Program, StopLimit};
use rhai::{Dynamic, Engine, EvalAltResult, FnPtr, Position, Scope, AST};
use std::collections::BTreeMap;
use std::rc::Rc;

/// A script bound to a runtime.
pub struct ScriptProgram {
    engine: Engine,
    ast: AST,
    file: String,
    arities: Arities,
    guard: Rc<Guard>,
    reads: ReadTracker,
    coverage: Option<Coverage>,
    /// `check`'s words for calls with no function, made at the first such error.
    not_found: std::cell::OnceCell<NotFound>,
    /// The top level's variables as it left them (a reload carries their values over).
    top: Scope<'static>,
    /// The file's name as the bindings place invariants in it (changed by a swap).
    placed: Rc<std::cell::RefCell<String>>,
    /// The variables `watch(...)` chose for the page and `status`.
    watch: Watch,
    /// A script compiled to replace this one at the next swap, with its file's name.
    staged: Option<(AST, String)>,
    /// The script before the last swap, its variables, file and watched names, until the
    /// swap is settled.
    previous: Option<Previous>,
}

/// The script before a swap: its code, top-level variables, file and watched names.
type Previous = (AST, Scope<'static>, String, Vec<(String, Position)>);

/// What the script did, when asked to keep count (`verify`): how often each handler ran, what
/// the handlers and the top level read, and what each invariant read.
#[derive(Debug, Clone, Default)]
pub struct Coverage {
    /// Calls per handler label (`panel.on_press S12`, `every 20ms`).
    pub fired: BTreeMap<String, u64>,
    /// What the top level and the handlers read.
    pub script_reads: ReadSet,
    /// What each invariant read, by name.
    pub invariant_reads: BTreeMap<String, ReadSet>,
}

impl ScriptProgram {
    /// Binds compiled `ast` (from the file called `file` in messages) to the run through `rt`, watched by
    /// `limits` (operations and time per call on the runtime's clock, memory, sizes).
    pub fn new(rt: &Rt, ast: AST, file: &str, limits: ScriptLimits) -> Self {
        let mut engine = sandboxed(limits.operations);
        let guard = Guard::install(&mut engine, limits, rt.clock(), rt.transaction_counter());
        let arities = Arities::default();
        let reads = ReadTracker::default();
        let placed = Rc::new(std::cell::RefCell::new(file.to_string()));
        let watch = Watch::default();
        register(&mut engine, rt, &arities, &reads, &placed, &watch);
        resolve_variables(&mut engine, rt, &guard, &reads);
        arities.learn(&ast);
        Self {
            engine,
            ast,
            file: file.to_string(),
            arities,
            guard,
            reads,
            coverage: None,
            not_found: std::cell::OnceCell::new(),
            top: Scope::new(),
            placed,
            watch,
            staged: None,
            previous: None,
        }
    }

    /// Gives the top level's variables present in the script before the swap, with a value
    /// of the same type, their old values, written through the shared value a closure may
    /// hold (so the closures see them too). Constants are the new script's; function
    /// pointers (closures) name functions of the old script and are not carried. Returns
    /// the names carried.
    fn carry(&mut self) -> Vec<String> {
        let Some((_, old, _, _)) = &self.previous else {
            return Vec::new();
        };
        let mut names: Vec<String> = self
            .top
            .iter_raw()
            .filter(|(_, constant, _)| !constant)
            .map(|(name, _, _)| name.to_string())
            .collect();
        names.sort();
        names.dedup();
        let mut carried = Vec::new();
        for name in names {
            let (Some(before), Some(now)) =
                (old.get_value::<Dynamic>(&name), self.top.get_mut(&name))
            else {
                continue;
            };
            let now_type = now.flatten_clone().type_name();
            if before.is::<FnPtr>() || before.type_name() != now_type {
                continue;
            }
            if let Some(mut value) = now.write_lock::<Dynamic>() {
                *value = before;
                carried.push(name);
            }
        }
        carried
    }

    /// Starts keeping count of what the script does (see `Coverage`).
    pub fn track_coverage(&mut self) {
        self.reads.enable();
        self.coverage.get_or_insert_with(Coverage::default);
    }

    /// What the script did since `track_coverage`.
    pub fn coverage(&self) -> Option<&Coverage> {
        self.coverage.as_ref()
    }

    fn note_reads(&mut self, invariant: Option<&str>) {
        let Some(c) = self.coverage.as_mut() else {
            return;
        };
        let read = self.reads.take();
        match invariant {
            Some(name) => match c.invariant_reads.get_mut(name) {
                Some(set) => set.union(&read),
                None => {
                    c.invariant_reads.insert(name.to_string(), read);
                }
            },
            None => c.script_reads.union(&read),
        }
    }

    /// The file name used in messages.
    pub fn file(&self) -> &str {
        &self.file
    }

    /// The engine (with the API registered).
    pub fn engine(&self) -> &Engine {
        &self.engine
    }

    /// The limits the calls are watched by.
    pub fn limits(&self) -> &ScriptLimits {
        self.guard.limits()
    }

    /// How a call ended: a limit hit (whatever the script did about it), `stop()` (fine),
    /// or an error; placed at `fallback()` when Rhai gives no place.
    fn outcome(
        &self,
        result: Result<(), Box<EvalAltResult>>,
        fallback: impl FnOnce() -> Position,
    ) -> Result<(), HandlerFault> {
        let breach = self.guard.end_call();
        match (result, breach) {
            (result, Some(b)) => Err(breach_fault(
                &self.file,
                &b,
                result.as_ref().map(|_| ()).map_err(|e| &**e),
                fallback(),
            )),
            (Ok(()), None) => Ok(()),
            (Err(e), None) if is_stop(&e) => Ok(()),
            (Err(e), None) => Err(self.fault(&e, fallback())),
        }
    }

    /// Runs one handler, within `stop` too when it is an `on_stop` handler's call in a stop.
    fn call_limited(
        &mut self,
        call: &Call<Handler>,
        stop: Option<StopLimit>,
    ) -> Result<(), HandlerFault> {
        self.call_for_value(call, stop).map(|_| ())
    }

    /// Runs one handler and gives its value, within `stop` too when it is an `on_stop`
    /// handler's call in a stop.
    fn call_for_value(
        &mut self,
        call: &Call<Handler>,
        stop: Option<StopLimit>,
    ) -> Result<Dynamic, HandlerFault> {
        let n = self.arities.pick(&call.handler, call.args.len());
        let args: Vec<Dynamic> = call
            .args
            .iter()
            .take(n)
            .map(|a| match a {
                Arg::Int(i) => Dynamic::from(*i),
                Arg::Str(s) => Dynamic::from(s.clone()),
                Arg::Json(text) => match serde_json::from_str(text) {
                    Ok(v) => super::values::from_json(&v),
                    Err(_) => Dynamic::from(text.clone()),
                },
            })
            .collect();
        self.guard.begin_call();
        if let Some(limit) = stop {
            self.guard.within_stop(limit);
        }
        let result = call.handler.call::<Dynamic>(&self.engine, &self.ast, args);
        if let Some(c) = self.coverage.as_mut() {
            match c.fired.get_mut(&*call.label) {
                Some(n) => *n = n.saturating_add(1),
                None => {
                    c.fired.insert(call.label.to_string(), 1);
                }
            }
        }
        self.note_reads(None);
        let (result, value) = match result {
            Ok(v) => (Ok(()), v),
            Err(e) => (Err(e), Dynamic::UNIT),
        };
        self.outcome(result, || self.body_start(&call.handler, n))
            .map(|()| value)
    }

    /// A runtime error as a fault; a call Rhai found no function for is told in `check`'s
    /// words (its raw "Function not found: set_ouptut (TRP-C29U, i64, bool)" says little).
    fn fault(&self, err: &EvalAltResult, fallback: Position) -> HandlerFault {
        let mut f = fault(&self.file, err, fallback);
        let words = || self.not_found.get_or_init(|| NotFound::new(&self.engine));
        let said = match innermost(err).0 {
            EvalAltResult::ErrorFunctionNotFound(signature, pos) => {
                words().explain(signature, &self.ast, *pos)
            }
            EvalAltResult::ErrorDotExpr(text, pos) => {
                words().explain_property(text, &self.ast, *pos)
            }
            _ => None,
        };
        if let Some(cause) = said {
            f.cause = cause;
        }
        f
    }

    /// Where the body of `handler` starts when it gets `args` arguments, if it is a function
    /// of the script (a closure or a named function).
    fn body_start(&self, handler: &FnPtr, args: usize) -> Position {
        let params = handler.curry().len() + args;
        self.ast
            .iter_fn_def()
            .find(|f| f.name == handler.fn_name() && f.params.len() == params)
            .map_or(Position::NONE, |f| f.body.start_position())
    }
}

impl Program for ScriptProgram {
    type Handler = Handler;

    fn start(&mut self) -> Result<(), HandlerFault> {
        self.guard.begin_call();
        let _ = self.watch.clear();
        let mut top = Scope::new();
        let result = self.engine.run_ast_with_scope(&mut top, &self.ast);
        self.top = top;
        self.note_reads(None);
        self.outcome(result, || Position::NONE)?;
        match self.watch.unknown(&self.top) {
            Some((cause, at)) => Err(HandlerFault {
                location: super::error::location(&self.file, at),
                cause,
                over_budget: false,
            }),
            None => Ok(()),
        }
    }

    fn variables(&self) -> crate::runtime::snapshot::Variables {
        self.watch.read(&self.top)
    }

    fn stage(&mut self, source: &str, file: &str) -> Result<(), String> {
        let ast = self
            .engine
            .compile(source)
            .map_err(|e| super::error::parse_error(file, source, &e))?;
        self.staged = Some((ast, file.to_string()));
        Ok(())
    }

    fn swap(&mut self) -> Result<Vec<String>, HandlerFault> {
        let Some((ast, file)) = self.staged.take() else {
            return Err(HandlerFault {
                location: None,
                cause: "no script staged to swap in".into(),
                over_budget: false,
            });
        };
        let old_ast = std::mem::replace(&mut self.ast, ast);
        *self.placed.borrow_mut() = file.clone();
        let old_file = std::mem::replace(&mut self.file, file);
        let old_top = std::mem::take(&mut self.top);
        let old_watch = self.watch.clear();
        self.previous = Some((old_ast, old_top, old_file, old_watch));
        self.arities.learn(&self.ast);
        self.not_found = std::cell::OnceCell::new();
        self.start()?;
        Ok(self.carry())
    }

    fn swap_back(&mut self) {
        if let Some((ast, top, file, watch)) = self.previous.take() {
            self.ast = ast;
            self.top = top;
            self.watch.restore(watch);
            *self.placed.borrow_mut() = file.clone();
            self.file = file;
            self.arities.learn(&self.ast);
            self.not_found = std::cell::OnceCell::new();
        }
    }

    fn settle(&mut self) {
        self.previous = None;
    }

    fn call(&mut self, call: &Call<Handler>) -> Result<(), HandlerFault> {
        self.call_limited(call, None)
    }

    fn answer(&mut self, call: &Call<Handler>) -> Result<String, HandlerFault> {
        let value = self.call_for_value(call, None)?;
        Ok(super::values::to_json(&value).to_string())
    }

    fn call_in_stop(&mut self, call: &Call<Handler>, limit: StopLimit) -> Result<(), HandlerFault> {
        self.call_limited(call, Some(limit))
    }

    fn holds(&mut self, check: &InvariantCheck<Handler>) -> Result<bool, HandlerFault> {
        let (call, at) = (&check.call, check.at.as_deref());
        self.guard.begin_call();
        let result = call.handler.call::<Dynamic>(&self.engine, &self.ast, ());
        self.note_reads(Some(&check.name));
        // Where nothing places an error (Rhai's own limits), it is the invariant's.
        let placed = |mut f: HandlerFault| {
            if f.location.is_none() {
                f.location = at.map(str::to_string);
            }
            f
        };
        if let Some(b) = self.guard.end_call() {
            let ended = result.as_ref().map(|_| ()).map_err(|e| &**e);
            return Err(placed(breach_fault(&self.file, &b, ended, Position::NONE)));
        }
        match result {
            Ok(v) => v.as_bool().map_err(|_| HandlerFault {
                location: at.map(str::to_string),
                cause: format!(
                    "{} returned {} ({}), not true or false",
                    call.label,
                    super::values::show(&v),
                    v.type_name()
                ),
                over_budget: false,
            }),
            // stop() inside an invariant: the run is stopping anyway; it holds.
            Err(e) if is_stop(&e) => Ok(true),
            Err(e) => Err(placed(self.fault(&e, Position::NONE))),
        }
    }
}
