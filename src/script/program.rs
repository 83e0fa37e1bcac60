//! A compiled script as the scan loop's program: its top level adds handlers and timers,
//! and each handler call gets a fresh operation budget and only the arguments it takes.

use super::api::{register, Arities, Rt};
use super::engine::sandboxed;
use super::error::{fault, is_stop};
use super::reads::{ReadSet, ReadTracker};
use crate::runtime::invariants::Check;
use crate::runtime::scan::{Fault, Program};
use crate::runtime::subscriptions::{Arg, Call};
use rhai::{Dynamic, Engine, FnPtr, Scope, AST};
use std::collections::BTreeMap;

/// A script bound to a runtime.
pub struct ScriptProgram {
    engine: Engine,
    ast: AST,
    file: String,
    arities: Arities,
    reads: ReadTracker,
    coverage: Option<Coverage>,
}

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
    /// Binds compiled `ast` (from the file called `file` in messages) to `rt`, with
    /// `budget` operations per call.
    pub fn new(rt: &Rt, ast: AST, file: &str, budget: u64) -> Self {
        let mut engine = sandboxed(budget);
        let arities = Arities::default();
        let reads = ReadTracker::default();
        register(&mut engine, rt, &arities, &reads, file);
        arities.learn(&ast);
        Self {
            engine,
            ast,
            file: file.to_string(),
            arities,
            reads,
            coverage: None,
        }
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
}

impl Program for ScriptProgram {
    type Handler = FnPtr;

    fn start(&mut self) -> Result<(), Fault> {
        let result = self.engine.run_ast_with_scope(&mut Scope::new(), &self.ast);
        self.note_reads(None);
        match result {
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
        let result = call.handler.call::<Dynamic>(&self.engine, &self.ast, args);
        if let Some(c) = self.coverage.as_mut() {
            match c.fired.get_mut(&call.label) {
                Some(n) => *n = n.saturating_add(1),
                None => {
                    c.fired.insert(call.label.clone(), 1);
                }
            }
        }
        self.note_reads(None);
        match result {
            Ok(_) => Ok(()),
            Err(e) if is_stop(&e) => Ok(()),
            Err(e) => Err(fault(&self.file, &e)),
        }
    }

    fn holds(&mut self, check: &Check<FnPtr>) -> Result<bool, Fault> {
        let (call, at) = (&check.call, check.at.as_deref());
        let result = call.handler.call::<Dynamic>(&self.engine, &self.ast, ());
        self.note_reads(Some(&check.name));
        match result {
            Ok(v) => v.as_bool().map_err(|_| Fault {
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
            Err(e) => {
                // Limit errors (the budget) come without a position: name the invariant's.
                let mut f = fault(&self.file, &e);
                if f.location.is_none() {
                    f.location = at.map(str::to_string);
                }
                Err(f)
            }
        }
    }
}
