//! A compiled script as the scan loop's program: its top level adds handlers and timers,
//! and each handler call gets a fresh operation budget and time limit, and only the arguments
//! it takes. A call over a limit is a fault placed where the limit was hit.

use super::api::{register, resolve_variables, Arities, Rt};
use super::engine::{sandboxed, Guard};
use super::error::{breach_fault, fault, is_stop};
use crate::config::ScriptLimits;
use crate::runtime::scan::{Fault, Program};
use crate::runtime::subscriptions::{Arg, Call};
use rhai::{Dynamic, Engine, EvalAltResult, FnPtr, Position, Scope, AST};
use std::rc::Rc;
use std::sync::Arc;

/// A script bound to a runtime.
pub struct ScriptProgram {
    engine: Engine,
    ast: AST,
    file: String,
    arities: Arities,
    guard: Rc<Guard>,
}

impl ScriptProgram {
    /// Binds compiled `ast` (from the file called `file` in messages) to `rt`, watched by
    /// `limits` (operations and time per call on the runtime's clock, memory, sizes).
    pub fn new(rt: &Rt, ast: AST, file: &str, limits: ScriptLimits) -> Self {
        let mut engine = sandboxed(limits.operations);
        let (clock, transactions) = {
            let r = rt.borrow();
            (Arc::clone(&r.clock), Arc::clone(&r.transactions))
        };
        let guard = Guard::install(&mut engine, limits, clock, transactions);
        let arities = Arities::default();
        register(&mut engine, rt, &arities);
        resolve_variables(&mut engine, rt, &guard);
        arities.learn(&ast);
        Self {
            engine,
            ast,
            file: file.to_string(),
            arities,
            guard,
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
    ) -> Result<(), Fault> {
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
            (Err(e), None) => Err(fault(&self.file, &e, fallback())),
        }
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
    type Handler = FnPtr;

    fn start(&mut self) -> Result<(), Fault> {
        self.guard.begin_call();
        let result = self.engine.run_ast_with_scope(&mut Scope::new(), &self.ast);
        self.outcome(result, || Position::NONE)
    }

    fn call(&mut self, call: &Call<FnPtr>) -> Result<(), Fault> {
        let n = self.arities.pick(&call.handler, call.args.len());
        let args: Vec<Dynamic> = call
            .args
            .iter()
            .take(n)
            .map(|a| match a {
                Arg::Int(i) => Dynamic::from(*i),
                Arg::Str(s) => Dynamic::from(s.clone()),
            })
            .collect();
        self.guard.begin_call();
        let result = call
            .handler
            .call::<Dynamic>(&self.engine, &self.ast, args)
            .map(|_| ());
        self.outcome(result, || self.body_start(&call.handler, n))
    }
}
