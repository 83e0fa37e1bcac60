//! A compiled script as the scan loop's program: its top level adds handlers and timers,
//! and each handler call gets a fresh operation budget and only the arguments it takes.

use super::api::{register, Arities, Rt};
use super::engine::sandboxed;
use super::error::{fault, is_stop};
use crate::runtime::scan::{Fault, Program};
use crate::runtime::subscriptions::{Arg, Call};
use rhai::{Dynamic, Engine, FnPtr, Scope, AST};

/// A script bound to a runtime.
pub struct ScriptProgram {
    engine: Engine,
    ast: AST,
    file: String,
    arities: Arities,
}

impl ScriptProgram {
    /// Binds compiled `ast` (from the file called `file` in messages) to `rt`, with
    /// `budget` operations per call.
    pub fn new(rt: &Rt, ast: AST, file: &str, budget: u64) -> Self {
        let mut engine = sandboxed(budget);
        let arities = Arities::default();
        register(&mut engine, rt, &arities);
        arities.learn(&ast);
        Self {
            engine,
            ast,
            file: file.to_string(),
            arities,
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
}

impl Program for ScriptProgram {
    type Handler = FnPtr;

    fn start(&mut self) -> Result<(), Fault> {
        match self.engine.run_ast_with_scope(&mut Scope::new(), &self.ast) {
            Ok(()) => Ok(()),
            Err(e) if is_stop(&e) => Ok(()),
            Err(e) => Err(fault(&self.file, &e)),
        }
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
        match call.handler.call::<Dynamic>(&self.engine, &self.ast, args) {
            Ok(_) => Ok(()),
            Err(e) if is_stop(&e) => Ok(()),
            Err(e) => Err(fault(&self.file, &e)),
        }
    }
}
