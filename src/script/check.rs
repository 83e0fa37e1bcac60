//! `rigscript check`: finds what can be found without running a script. It compiles it (so
//! syntax, `import` and `eval` are reported), then walks its syntax tree — the top level, every
//! script function and every closure (handler) — for:
//!
//! - calls of functions and methods that exist neither in the script API (with Rhai's standard
//!   library, as registered on the engine `run` uses) nor in the script, and calls with a number
//!   of arguments no overload takes, with "did you mean" suggestions by edit distance;
//! - literal arguments: device names in `device("...")` against the rig, switch and rotary
//!   names, channels, durations and cron expressions, the number of parameters of handlers,
//!   and invariants that are not closures taking no parameters;
//! - literal numbers assigned to a device property that cannot hold them (`io.outputs = 300`;
//!   the safe and power-on values 0-255, `panel.relay` 0-7), in the run's own words;
//! - properties and methods called on a variable known to hold a device (bound once to a
//!   `device("...")` literal, or a device's own name) that its kind does not have.
//!
//! A method whose name is also a key of a map in the script is left alone: Rhai calls a
//! function stored in a map property as a method.
//!
//! The same words serve a run: `NotFound` tells a call or property Rhai found nothing for as
//! the script ran (`ScriptProgram` asks it), instead of Rhai's "Function not found: ..".

use super::api::{
    no_relay, not_a_byte, register, takes_words, Arities, Io, Panel, BYTE_PROPERTIES, HANDLERS,
};
use super::engine::{sandboxed, DEFAULT_BUDGET};
use super::error::parse_position;
use super::point_names::{channel_named, rotary_named, switch_named, Way};
use super::reads::ReadTracker;
use crate::config::PointNames;
use crate::config::{DeviceConfig, RigConfig};
use crate::runtime::devices::links::TransactionCounter;
use crate::runtime::log::Logger;
use crate::runtime::records::Records;
use crate::runtime::schedule::validate_cron;
use crate::runtime::script_context::ScriptContext;
use crate::runtime::state::Runtime;
use crate::suggest::closest;
use crate::time::clock::SystemClock;
use crate::time::duration::parse_duration;
use crate::time::zone::Zone;
use rhai::{ASTNode, Dynamic, Engine, Expr, FnCallExpr, FnPtr, Position, Stmt, AST};
use std::any::TypeId;
use std::cell::RefCell;
use std::collections::{BTreeSet, HashMap, HashSet};
use std::fmt;
use std::rc::Rc;
use std::sync::Arc;
use std::time::Duration;

/// One problem found, at a line and column of the script.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Problem {
    /// 1-based line.
    pub line: usize,
    /// 1-based column.
    pub column: usize,
    /// What is wrong.
    pub message: String,
}

impl fmt::Display for Problem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}: {}", self.line, self.column, self.message)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Trc,
    C29u,
}

impl Kind {
    fn name(self) -> &'static str {
        match self {
            Kind::Trc => "TRC1000",
            Kind::C29u => "TRP-C29U",
        }
    }

    fn type_id(self) -> TypeId {
        match self {
            Kind::Trc => TypeId::of::<Panel>(),
            Kind::C29u => TypeId::of::<Io>(),
        }
    }

    /// The kind whose Rhai type is called `name`.
    fn named(name: &str) -> Option<Kind> {
        [Kind::Trc, Kind::C29u]
            .into_iter()
            .find(|k| k.name() == name)
    }

    fn other(self) -> Kind {
        match self {
            Kind::Trc => Kind::C29u,
            Kind::C29u => Kind::Trc,
        }
    }
}

/// Functions Rhai's evaluator handles itself, never registered: (name, the argument counts
/// they take in function-call style; `None` for any number from the first).
const SYNTACTIC: &[(&str, &[usize], Option<usize>)] = &[
    ("Fn", &[1], None),
    ("call", &[], Some(1)),
    ("curry", &[], Some(1)),
    ("type_of", &[1], None),
    ("is_shared", &[1], None),
    ("is_def_var", &[1], None),
    ("is_def_fn", &[2, 3], None),
];

/// What Rhai's anonymous functions (closures) are called: `anon$` and a hash.
const ANONYMOUS_PREFIX: &str = "anon$";

/// Every function the engine of a run knows, by name: its parameter counts, each with the
/// type of its first parameter (the receiver of a method call).
struct Registry {
    functions: HashMap<String, Vec<(usize, Option<TypeId>)>>,
}

impl Registry {
    /// The script API and Rhai's standard library, as `run` registers them (on a runtime with
    /// no devices: the bindings only need one to exist).
    fn of_the_api() -> Self {
        let mut engine = sandboxed(DEFAULT_BUDGET);
        let clock = SystemClock::shared();
        let runtime = Runtime::new(
            Arc::clone(&clock),
            Zone::utc(),
            Vec::new(),
            Records::in_memory(),
            Logger::new(clock, Zone::utc(), false),
            TransactionCounter::default(),
            Duration::ZERO,
        );
        register(
            &mut engine,
            &ScriptContext::new(&Rc::new(RefCell::new(runtime))),
            &Arities::default(),
            &ReadTracker::default(),
            &Rc::default(),
            &Default::default(),
        );
        Self::of(&engine)
    }

    fn of(engine: &Engine) -> Self {
        let mut functions: HashMap<String, Vec<(usize, Option<TypeId>)>> = HashMap::new();
        let listed = engine.collect_fn_metadata(
            None,
            |info| {
                let m = info.metadata;
                Some((
                    m.name.to_string(),
                    m.num_params,
                    m.param_types.first().copied(),
                ))
            },
            true,
        );
        for (name, params, first) in listed {
            functions.entry(name).or_default().push((params, first));
        }
        Self { functions }
    }

    /// The members of a device kind: its methods and (as `get$x`/`set$x`) its properties.
    fn members(&self, kind: Kind) -> (BTreeSet<&str>, BTreeSet<&str>) {
        let mut methods = BTreeSet::new();
        let mut properties = BTreeSet::new();
        for (name, overloads) in &self.functions {
            if !overloads.iter().any(|(_, t)| *t == Some(kind.type_id())) {
                continue;
            }
            match name
                .strip_prefix("get$")
                .or_else(|| name.strip_prefix("set$"))
            {
                Some(p) => {
                    properties.insert(p);
                }
                None if is_identifier(name) => {
                    methods.insert(name.as_str());
                }
                None => {}
            }
        }
        // `to_string` and `to_debug` are what printing a handle calls; nobody writes them.
        methods.retain(|m| !matches!(*m, "to_string" | "to_debug"));
        (methods, properties)
    }
}

/// The script API as `check` knows it, by name: what the engine of a run registers beyond
/// Rhai's standard library (the user guide's reference is tested against it).
#[cfg(any(test, feature = "internals"))]
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ScriptApi {
    /// Functions called on their own (`every`, `device`, ...).
    pub functions: BTreeSet<String>,
    /// A TRC1000 handle's methods and properties.
    pub trc1000: BTreeSet<String>,
    /// A TRP-C29U handle's methods and properties.
    pub c29u: BTreeSet<String>,
}

/// The script API's names, from the engine a run uses.
#[cfg(any(test, feature = "internals"))]
pub fn script_api() -> ScriptApi {
    let api = Registry::of_the_api();
    let library = Registry::of(&sandboxed(DEFAULT_BUDGET));
    let devices = [Kind::Trc.type_id(), Kind::C29u.type_id()];
    let functions = api
        .functions
        .iter()
        .filter(|(name, overloads)| {
            let known = library.functions.get(*name);
            is_identifier(name)
                && overloads.iter().any(|o| {
                    !o.1.is_some_and(|t| devices.contains(&t))
                        && !known.is_some_and(|k| k.contains(o))
                })
        })
        .map(|(name, _)| name.clone())
        .collect();
    let members = |kind| {
        let (methods, properties) = api.members(kind);
        methods
            .into_iter()
            .chain(properties)
            .map(String::from)
            .collect()
    };
    ScriptApi {
        functions,
        trc1000: members(Kind::Trc),
        c29u: members(Kind::C29u),
    }
}

/// True for names a script can write as a call (not operators, getters or indexers).
fn is_identifier(name: &str) -> bool {
    let mut chars = name.chars();
    chars
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// A function of the script: its parameter names.
struct ScriptFn {
    name: String,
    params: Vec<String>,
}

/// Where a closure is made: the function it is made in (`None`: the top level) and the
/// variables it captures (Rhai passes them as its first parameters).
struct ClosureSite {
    made_in: Option<String>,
    captured: Vec<String>,
}

struct Checker<'a> {
    ast: &'a AST,
    registry: &'a Registry,
    script_fns: Vec<ScriptFn>,
    closures: HashMap<String, ClosureSite>,
    devices: HashMap<String, Kind>,
    /// What rig.toml calls each device's points (`names`), by device.
    point_names: HashMap<String, PointNames>,
    device_names: String,
    bound: HashMap<String, Kind>,
    /// Names of the function being walked that hide a device variable of the same name.
    shadowed: HashSet<String>,
    /// Keys of map literals and property names: a method of that name may be a map's function.
    map_keys: HashSet<String>,
    /// Names the script binds with `let` or `const`.
    variables: HashSet<String>,
    problems: Vec<Problem>,
}

/// Checks `source` against the devices of `config`; every problem found, in order.
pub fn check(source: &str, config: &RigConfig) -> Vec<Problem> {
    let engine = sandboxed(DEFAULT_BUDGET);
    let ast = match engine.compile(source) {
        Ok(ast) => ast,
        Err(e) => {
            let (line, column) = line_col(parse_position(source, &e));
            return vec![Problem {
                line,
                column,
                message: e.err_type().to_string(),
            }];
        }
    };
    let registry = Registry::of_the_api();
    let mut c = Checker::new(&ast, &registry, config);
    c.bind_variables();
    // The top level, then each function on its own, so that its parameters hide the devices
    // they are named after.
    c.walk_part(&ast.clone_statements_only(), None);
    let functions: Vec<(String, usize)> = c
        .script_fns
        .iter()
        .map(|f| (f.name.clone(), f.params.len()))
        .collect();
    for (name, params) in functions {
        c.walk_part(&only_function(&ast, &name, params), Some(&name));
    }
    let devices = c.devices.keys().cloned().collect();
    c.problems
        .extend(super::fn_scope::top_level_names_in_functions(
            &ast, &devices,
        ));
    c.problems.sort_by_key(|p| (p.line, p.column));
    c.problems.dedup();
    c.problems
}

/// `check`'s words for a call Rhai finds no function for as a script runs (`explain`): the
/// same messages and suggestions, from the functions the run's engine has.
pub struct NotFound {
    registry: Registry,
}

impl NotFound {
    /// For the script API as `engine` has it registered.
    pub fn new(engine: &Engine) -> Self {
        Self {
            registry: Registry::of(engine),
        }
    }

    /// What `check` would say of the call at `pos` in `ast` that Rhai found no function for:
    /// `signature` is Rhai's `name (type, ..)`, the receiver first for a method. Where `check`
    /// has nothing to say (a function of that name takes that many arguments), the types are
    /// wrong, and the message says so. `None` for what is not a call by name (an operator).
    pub fn explain(&self, signature: &str, ast: &AST, pos: Position) -> Option<String> {
        let (name, types) = signature.split_once(" (")?;
        let types: Vec<&str> = match types.strip_suffix(')')? {
            "" => Vec::new(),
            list => list
                .split(", ")
                .map(|t| {
                    if t.contains("ImmutableString") {
                        "string"
                    } else {
                        t
                    }
                })
                .collect(),
        };
        let (call, receiver) = call_at(ast, pos, name)?;
        let mut c = Checker::new(ast, &self.registry, &RigConfig::default());
        let kind = types.first().and_then(|t| Kind::named(t));
        let (shown, given) = match (&call, kind) {
            (Call::Property(property), Some(kind)) => {
                let var = receiver.unwrap_or_else(|| "it".into());
                c.check_property(kind, &var, property, pos);
                return c.problems.pop().map(|p| p.message);
            }
            (Call::Property(_), None) => return None,
            (Call::Method, Some(kind)) => {
                let var = receiver.unwrap_or_else(|| "it".into());
                c.check_device_method(kind, &var, name, types.len() - 1, pos);
                (format!("{var}.{name}"), &types[1..])
            }
            (Call::Method, None) => {
                c.check_method(name, types.len().saturating_sub(1), pos);
                (format!(".{name}"), types.get(1..).unwrap_or_default())
            }
            (Call::Function, _) => {
                c.check_function(name, types.len(), pos);
                (name.to_string(), &types[..])
            }
        };
        Some(c.problems.pop().map_or_else(
            || {
                format!(
                    "{shown}({}): {name} takes arguments of other types",
                    given.join(", ")
                )
            },
            |p| p.message,
        ))
    }

    /// What `check` would say of the property at `pos` in `ast` that Rhai found no getter or
    /// setter for: `text` is Rhai's "Unknown property 'x' - a getter is not registered for
    /// type 'T'" (or "No writable property .."). `None` when it is not about a device.
    pub fn explain_property(&self, text: &str, ast: &AST, pos: Position) -> Option<String> {
        let quoted = |after: &str| -> Option<&str> {
            let rest = &text[text.find(after)? + after.len()..];
            rest.split('\'').next()
        };
        let property = quoted("property '")?;
        let kind = Kind::named(quoted("for type '")?)?;
        let var = receiver_at(ast, pos).unwrap_or_else(|| "it".into());
        let mut c = Checker::new(ast, &self.registry, &RigConfig::default());
        c.check_property(kind, &var, property, pos);
        c.problems.pop().map(|p| p.message)
    }
}

/// What kind of call a runtime error at a place was made by.
enum Call {
    Function,
    Method,
    /// Reading or setting a property (Rhai's `get$x`, `set$x`).
    Property(String),
}

/// The call of `name` at `pos` in `ast`, and the variable it is a method of, if it is one.
fn call_at(ast: &AST, pos: Position, name: &str) -> Option<(Call, Option<String>)> {
    if !is_identifier(name) {
        let property = name
            .strip_prefix("get$")
            .or_else(|| name.strip_prefix("set$"))?;
        return Some((Call::Property(property.to_string()), receiver_at(ast, pos)));
    }
    let mut found = None;
    ast.walk(&mut |path: &[ASTNode]| {
        match path.last() {
            Some(ASTNode::Expr(Expr::MethodCall(call, at))) if *at == pos && call.name == name => {
                let var = match Checker::receiver(path) {
                    Some(Expr::Variable(x, ..)) => Some(x.1.to_string()),
                    _ => None,
                };
                found = Some((Call::Method, var));
            }
            Some(ASTNode::Expr(Expr::FnCall(call, at)) | ASTNode::Stmt(Stmt::FnCall(call, at)))
                if *at == pos && call.name == name =>
            {
                found = Some((Call::Function, None));
            }
            _ => {}
        }
        found.is_none()
    });
    // Not found at its place (an `Fn` pointer called by name): a function call.
    Some(found.unwrap_or((Call::Function, None)))
}

/// The variable whose property is used at `pos`, if it is one.
fn receiver_at(ast: &AST, pos: Position) -> Option<String> {
    let mut found = None;
    ast.walk(&mut |path: &[ASTNode]| {
        if let Some(ASTNode::Expr(Expr::Property(_, at))) = path.last() {
            if *at == pos {
                if let Some(Expr::Variable(x, ..)) = Checker::receiver(path) {
                    found = Some(x.1.to_string());
                }
            }
        }
        found.is_none()
    });
    found
}

impl<'a> Checker<'a> {
    /// A checker of `ast` against the devices of `config`, with the functions of `registry`;
    /// where closures are made and the names maps use are surveyed.
    fn new(ast: &'a AST, registry: &'a Registry, config: &RigConfig) -> Self {
        let devices: HashMap<String, Kind> = config
            .devices
            .iter()
            .map(|(n, d)| {
                let k = match d {
                    DeviceConfig::Trc1000(_) => Kind::Trc,
                    DeviceConfig::C29u(_) => Kind::C29u,
                };
                (n.clone(), k)
            })
            .collect();
        let point_names = config
            .devices
            .iter()
            .map(|(n, d)| {
                let names = match d {
                    DeviceConfig::Trc1000(t) => t.names.clone(),
                    DeviceConfig::C29u(c) => c.names.clone(),
                };
                (n.clone(), names)
            })
            .collect();
        let device_names = config
            .devices
            .keys()
            .cloned()
            .collect::<Vec<_>>()
            .join(", ");
        let script_fns = ast
            .iter_functions()
            .map(|f| ScriptFn {
                name: f.name.to_string(),
                params: f.params.iter().map(ToString::to_string).collect(),
            })
            .collect();
        let mut c = Checker {
            ast,
            registry,
            script_fns,
            closures: HashMap::new(),
            devices,
            point_names,
            device_names,
            bound: HashMap::new(),
            shadowed: HashSet::new(),
            map_keys: HashSet::new(),
            variables: HashSet::new(),
            problems: Vec::new(),
        };
        c.survey();
        c
    }
}

/// The function `name` with `params` parameters of `ast`, alone, to walk by itself.
pub(super) fn only_function(ast: &AST, name: &str, params: usize) -> AST {
    // Not `clone_functions_only_filtered`: into an AST without functions it copies them all.
    let mut part = ast.clone_functions_only();
    part.retain_functions(|_, _, n, p| n == name && p == params);
    part
}

fn line_col(pos: Position) -> (usize, usize) {
    (pos.line().unwrap_or(0), pos.position().unwrap_or(0))
}

/// The string literal `device("...")` names, if `e` is such a call.
fn device_literal(e: &Expr) -> Option<(&str, Position)> {
    match e {
        Expr::FnCall(call, _) if call.name.as_str() == "device" => match call.args.as_slice() {
            [Expr::StringConstant(s, pos)] => Some((s.as_str(), *pos)),
            _ => None,
        },
        _ => None,
    }
}

/// The anonymous function a `curry(Fn(anon), captured..)` call makes, with what it captures.
fn closure_made_by(call: &FnCallExpr) -> Option<(String, Vec<String>)> {
    if call.name.as_str() != "curry" {
        return None;
    }
    let (first, captured) = call.args.split_first()?;
    let Expr::DynamicConstant(d, _) = first else {
        return None;
    };
    let f = (**d).clone().try_cast::<FnPtr>()?;
    let names = captured
        .iter()
        .filter_map(|e| match e {
            Expr::Variable(x, ..) => Some(x.1.to_string()),
            _ => None,
        })
        .collect();
    Some((f.fn_name().to_string(), names))
}

fn suggestion(found: Option<&str>) -> String {
    found.map_or_else(String::new, |s| format!("; did you mean `{s}`?"))
}

/// "1 argument", "0 or 1 arguments", "2, 3 or 4 arguments".
fn counts_words(counts: &BTreeSet<usize>) -> String {
    let list: Vec<String> = counts.iter().map(ToString::to_string).collect();
    let text = match list.as_slice() {
        [] => "no".to_string(),
        [one] => one.clone(),
        [init @ .., last] => format!("{} or {last}", init.join(", ")),
    };
    if counts.len() == 1 && counts.contains(&1) {
        format!("{text} argument")
    } else {
        format!("{text} arguments")
    }
}

impl Checker<'_> {
    fn report(&mut self, pos: Position, message: String) {
        let (line, column) = line_col(pos);
        self.problems.push(Problem {
            line,
            column,
            message,
        });
    }

    /// Walks the top level and every function once before checking: where closures are made
    /// and what they capture, and the names maps use as keys.
    fn survey(&mut self) {
        let mut closures = HashMap::new();
        let mut keys = HashSet::new();
        let mut variables = HashSet::new();
        let mut note = |made_in: Option<&str>, path: &[ASTNode]| {
            let call = match path.last() {
                Some(ASTNode::Stmt(Stmt::Var(x, ..))) => {
                    variables.insert(x.0.name.to_string());
                    None
                }
                Some(ASTNode::Expr(Expr::FnCall(call, _))) => Some(&**call),
                Some(ASTNode::Stmt(Stmt::FnCall(call, _))) => Some(&**call),
                Some(ASTNode::Expr(Expr::Map(m, _))) => {
                    keys.extend(m.0.iter().map(|(k, _)| k.name.to_string()));
                    None
                }
                Some(ASTNode::Expr(Expr::Property(p, _))) => {
                    keys.insert(p.2.to_string());
                    None
                }
                // A map literal of constants is folded into one value.
                Some(ASTNode::Expr(Expr::DynamicConstant(d, _))) => {
                    if let Some(map) = d.read_lock::<rhai::Map>() {
                        keys.extend(map.keys().map(ToString::to_string));
                    }
                    None
                }
                _ => None,
            };
            if let Some((anon, captured)) = call.and_then(closure_made_by) {
                closures.insert(
                    anon,
                    ClosureSite {
                        made_in: made_in.map(ToString::to_string),
                        captured,
                    },
                );
            }
            true
        };
        self.ast
            .clone_statements_only()
            .walk(&mut |path: &[ASTNode]| note(None, path));
        for f in &self.script_fns {
            only_function(self.ast, &f.name, f.params.len())
                .walk(&mut |path: &[ASTNode]| note(Some(&f.name), path));
        }
        self.closures = closures;
        self.map_keys = keys;
        self.variables = variables;
    }

    /// The parameters of the function `name` that hide device variables: all of a named
    /// function's; a closure's own, and those it captures from a function where they are hidden.
    fn hidden_in(&self, name: &str, depth: usize) -> HashSet<String> {
        let Some(f) = self.script_fns.iter().find(|f| f.name == name) else {
            return HashSet::new();
        };
        if !name.starts_with(ANONYMOUS_PREFIX) {
            return f.params.iter().cloned().collect();
        }
        let Some(site) = self.closures.get(name) else {
            return f.params.iter().cloned().collect();
        };
        let mut hidden: HashSet<String> =
            f.params.iter().skip(site.captured.len()).cloned().collect();
        if let Some(outer) = &site.made_in {
            if depth < 64 {
                let outer_hidden = self.hidden_in(outer, depth + 1);
                hidden.extend(
                    site.captured
                        .iter()
                        .filter(|c| outer_hidden.contains(*c))
                        .cloned(),
                );
            }
        }
        hidden
    }

    fn walk_part(&mut self, part: &AST, function: Option<&str>) {
        self.shadowed = function.map_or_else(HashSet::new, |f| self.hidden_in(f, 0));
        part.walk(&mut |path: &[ASTNode]| {
            self.visit(path);
            true
        });
    }

    /// Variables bound to a `device("...")` literal (only those never bound to anything else).
    fn bind_variables(&mut self) {
        let mut seen: HashMap<String, Option<Kind>> = HashMap::new();
        let devices = &self.devices;
        self.ast.walk(&mut |path: &[ASTNode]| {
            let bound = match path.last() {
                Some(ASTNode::Stmt(Stmt::Var(x, ..))) => {
                    let (ident, expr, _) = &**x;
                    let kind = device_literal(expr).and_then(|(n, _)| devices.get(n).copied());
                    Some((ident.name.to_string(), kind))
                }
                Some(ASTNode::Stmt(Stmt::For(x, _))) => {
                    let (var, counter, _) = &**x;
                    if let Some(c) = counter {
                        seen.insert(c.name.to_string(), None);
                    }
                    Some((var.name.to_string(), None))
                }
                _ => None,
            };
            if let Some((name, kind)) = bound {
                let entry = seen.entry(name).or_insert(kind);
                if *entry != kind {
                    *entry = None;
                }
            }
            true
        });
        // Each device is also a variable of its name, unless the script binds that name to
        // something else.
        for (name, kind) in &self.devices {
            seen.entry(name.clone()).or_insert(Some(*kind));
        }
        self.bound = seen
            .into_iter()
            .filter_map(|(n, k)| k.map(|k| (n, k)))
            .collect();
    }

    fn kind_of(&self, object: &Expr) -> Option<(Kind, String)> {
        match object {
            Expr::Variable(x, _, _) => {
                let name = x.1.as_str();
                if self.shadowed.contains(name) {
                    return None;
                }
                self.bound.get(name).map(|k| (*k, name.to_string()))
            }
            e => device_literal(e)
                .and_then(|(n, _)| self.devices.get(n).map(|k| (*k, n.to_string()))),
        }
    }

    /// The object a method call or property at the end of `path` is applied to, when the
    /// chain starts there: `x.m()` (the member right of a dot) or `x.m().n()` (its first link).
    fn receiver<'p>(path: &'p [ASTNode<'p>]) -> Option<&'p Expr> {
        let (node, parents) = path.split_last()?;
        let ASTNode::Expr(me) = node else {
            return None;
        };
        let (parent, grand) = parents.split_last()?;
        let ASTNode::Expr(parent) = parent else {
            return None;
        };
        let Expr::Dot(bin, ..) = parent else {
            return None;
        };
        if std::ptr::eq(&bin.rhs, *me) {
            // The member right of the dot: its object is the left side, unless this dot is
            // itself a later link of a chain.
            let is_link = matches!(grand.last(), Some(ASTNode::Expr(Expr::Dot(outer, ..)))
                if std::ptr::eq(&outer.rhs, *parent));
            return (!is_link).then_some(&bin.lhs);
        }
        if std::ptr::eq(&bin.lhs, *me) {
            // The first link of a chain `x.(me.rest)`: the object is the outer dot's left side.
            if let Some(ASTNode::Expr(Expr::Dot(outer, ..))) = grand.last() {
                if std::ptr::eq(&outer.rhs, *parent) {
                    return Some(&outer.lhs);
                }
            }
        }
        None
    }

    fn visit(&mut self, path: &[ASTNode]) {
        match path.last() {
            // A call as a statement is a statement of its own, with the same shape.
            Some(ASTNode::Stmt(Stmt::FnCall(call, pos))) => {
                self.check_device_name(call);
                self.check_call(call, *pos, None);
                self.check_exists(call, *pos, None);
            }
            Some(ASTNode::Expr(Expr::FnCall(call, pos))) => {
                self.check_device_name(call);
                self.check_call(call, *pos, None);
                self.check_exists(call, *pos, None);
            }
            Some(ASTNode::Expr(Expr::MethodCall(call, pos))) => {
                let object = Self::receiver(path).and_then(|o| self.kind_of(o));
                self.check_call(call, *pos, Some(object.as_ref()));
                self.check_exists(call, *pos, Some(object));
            }
            Some(ASTNode::Expr(Expr::Property(p, pos))) => {
                if let Some((kind, var)) = Self::receiver(path).and_then(|o| self.kind_of(o)) {
                    self.check_property(kind, &var, p.2.as_str(), *pos);
                }
            }
            Some(ASTNode::Stmt(Stmt::Assignment(x))) => self.check_assigned(&x.0, &x.1),
            _ => {}
        }
    }

    /// A literal number assigned to a device property that cannot hold it (`io.outputs =
    /// 300`, `panel.relay = 9`), in the words the run would fail with.
    fn check_assigned(&mut self, op: &rhai::OpAssignment, bin: &rhai::BinaryExpr) {
        let (Expr::Dot(dot, ..), Expr::IntegerConstant(n, at)) = (&bin.lhs, &bin.rhs) else {
            return;
        };
        let Expr::Property(p, _) = &dot.rhs else {
            return;
        };
        if op.is_op_assignment() {
            return;
        }
        let Some((kind, var)) = self.kind_of(&dot.lhs) else {
            return;
        };
        let property = p.2.as_str();
        let message = match kind {
            Kind::C29u => BYTE_PROPERTIES
                .iter()
                .find(|(name, _)| *name == property)
                .filter(|_| u8::try_from(*n).is_err())
                .map(|(_, what)| not_a_byte(what, *n)),
            Kind::Trc => (property == "relay" && !(0..8).contains(n)).then(|| no_relay(&var, *n)),
        };
        if let Some(message) = message {
            self.report(*at, message);
        }
    }

    fn check_device_name(&mut self, call: &FnCallExpr) {
        if call.name.as_str() != "device" {
            return;
        }
        if let [Expr::StringConstant(name, at)] = call.args.as_slice() {
            if !self.devices.contains_key(name.as_str()) {
                self.report(
                    *at,
                    format!(
                        "no device called {:?} in the rig (devices: {})",
                        name.as_str(),
                        self.device_names
                    ),
                );
            }
        }
    }

    /// The parameter counts of the script's own functions called `name`.
    fn script_counts(&self, name: &str) -> BTreeSet<usize> {
        self.script_fns
            .iter()
            .filter(|f| f.name == name)
            .map(|f| f.params.len())
            .collect()
    }

    /// How many arguments a call of `name` may have: in function-call style, or as a method
    /// (the receiver not counted; a script function called as a method gets it as `this`).
    /// `None` when any number from the given one on will do.
    fn allowed(&self, name: &str, method: bool) -> (BTreeSet<usize>, Option<usize>) {
        let mut counts = self.script_counts(name);
        let mut from = None;
        for (params, _) in self.registry.functions.get(name).into_iter().flatten() {
            if method {
                if let Some(n) = params.checked_sub(1) {
                    counts.insert(n);
                }
            } else {
                counts.insert(*params);
            }
        }
        if let Some((_, fixed, any)) = SYNTACTIC.iter().find(|(n, ..)| *n == name) {
            for n in *fixed {
                // As a method the receiver is the first argument.
                counts.insert(if method { n.saturating_sub(1) } else { *n });
            }
            from = any.map(|n| if method { 0 } else { n });
        }
        (counts, from)
    }

    /// Every name a script can call, for suggestions.
    fn callable_names(&self) -> impl Iterator<Item = &str> {
        self.registry
            .functions
            .keys()
            .map(String::as_str)
            .filter(|n| is_identifier(n))
            .chain(
                self.script_fns
                    .iter()
                    .map(|f| f.name.as_str())
                    .filter(|n| !n.starts_with(ANONYMOUS_PREFIX)),
            )
            .chain(SYNTACTIC.iter().map(|(n, ..)| *n))
    }

    /// The device kinds whose methods are all the overloads of `name`, if it is one.
    fn device_method_of(&self, name: &str) -> Option<Kind> {
        let overloads = self.registry.functions.get(name)?;
        [Kind::C29u, Kind::Trc]
            .into_iter()
            .find(|k| overloads.iter().all(|(_, t)| *t == Some(k.type_id())))
    }

    /// A device of `kind` in the rig, for examples in messages.
    fn example_device(&self, kind: Kind) -> String {
        let mut names: Vec<&String> = self
            .devices
            .iter()
            .filter(|(_, k)| **k == kind)
            .map(|(n, _)| n)
            .collect();
        names.sort();
        names.first().map_or_else(
            || match kind {
                Kind::Trc => "panel".to_string(),
                Kind::C29u => "io".to_string(),
            },
            |n| (*n).clone(),
        )
    }

    /// Whether the called function or method exists, and takes this many arguments.
    /// `method`: `None` for a function call, else the device the receiver is known to be.
    fn check_exists(
        &mut self,
        call: &FnCallExpr,
        pos: Position,
        method: Option<Option<(Kind, String)>>,
    ) {
        let name = call.name.as_str();
        if call.op_token.is_some() || !is_identifier(name) {
            return;
        }
        let given = call.args.len();
        match method {
            None => self.check_function(name, given, pos),
            Some(None) => self.check_method(name, given, pos),
            Some(Some((kind, var))) => self.check_device_method(kind, &var, name, given, pos),
        }
    }

    fn check_function(&mut self, name: &str, given: usize, pos: Position) {
        let (counts, from) = self.allowed(name, false);
        if counts.contains(&given) || from.is_some_and(|f| given >= f) {
            return;
        }
        if let Some(kind) = self.device_method_of(name) {
            let dev = self.example_device(kind);
            self.report(
                pos,
                format!(
                    "{name} is a method of a {}: call it on the device, as {dev}.{name}(..)",
                    kind.name()
                ),
            );
        } else if counts.is_empty() && from.is_none() && self.variables.contains(name) {
            self.report(
                pos,
                format!(
                    "{name} is a variable, not a function: call the function it holds as \
                     {name}.call(..)"
                ),
            );
        } else if counts.is_empty() && from.is_none() {
            let near = closest(name, self.callable_names());
            self.report(
                pos,
                format!(
                    "no function called {name} in the script API or this script{}",
                    suggestion(near)
                ),
            );
        } else {
            let mut takes = counts_words(&counts);
            if let [only] = self
                .script_fns
                .iter()
                .filter(|f| f.name == name)
                .collect::<Vec<_>>()[..]
            {
                if !only.params.is_empty() {
                    takes.push_str(&format!(" ({})", only.params.join(", ")));
                }
            }
            self.report(pos, format!("{name} takes {takes}, not {given}"));
        }
    }

    fn check_method(&mut self, name: &str, given: usize, pos: Position) {
        // A function stored in a map is called as a method of the map.
        if self.map_keys.contains(name) {
            return;
        }
        let (counts, from) = self.allowed(name, true);
        if counts.contains(&given) || from.is_some_and(|f| given >= f) {
            return;
        }
        if counts.is_empty() && from.is_none() {
            let near = closest(name, self.callable_names());
            self.report(
                pos,
                format!(
                    "no method called {name} in the script API or this script{}",
                    suggestion(near)
                ),
            );
        } else {
            let mut message = format!(".{name}(..) takes {}, not {given}", counts_words(&counts));
            if !self.script_counts(name).is_empty() {
                message.push_str(
                    " (a function of the script called as a method gets its object as `this`)",
                );
            }
            self.report(pos, message);
        }
    }

    fn check_device_method(
        &mut self,
        kind: Kind,
        var: &str,
        name: &str,
        given: usize,
        pos: Position,
    ) {
        let dynamic = TypeId::of::<Dynamic>();
        let mut counts = self.script_counts(name);
        for (params, first) in self.registry.functions.get(name).into_iter().flatten() {
            if *first == Some(kind.type_id()) || *first == Some(dynamic) {
                counts.extend(params.checked_sub(1));
            }
        }
        if matches!(name, "type_of" | "is_shared") {
            counts.insert(0);
        }
        if counts.contains(&given) {
            return;
        }
        let (methods, properties) = self.registry.members(kind);
        let message = if !counts.is_empty() {
            format!("{var}.{name} takes {}, not {given}", counts_words(&counts))
        } else if let Some(message) = self.member_of_the_other_kind(kind, var, name) {
            message
        } else if properties.contains(name) {
            format!("{var}.{name} is a property: write {var}.{name}, without ()")
        } else {
            let near = closest(name, methods.iter().copied())
                .or_else(|| closest(name, properties.iter().copied()));
            format!(
                "{var} is a {}: it has no method {name}{}",
                kind.name(),
                suggestion(near)
            )
        };
        self.report(pos, message);
    }

    /// The message for `var.member` when `member` belongs to the other kind of device.
    fn member_of_the_other_kind(&self, kind: Kind, var: &str, member: &str) -> Option<String> {
        let (methods, properties) = self.registry.members(kind.other());
        (methods.contains(member) || properties.contains(member)).then(|| {
            format!(
                "{var} is a {}: it has no {member} (that is a {} member)",
                kind.name(),
                kind.other().name()
            )
        })
    }

    fn check_property(&mut self, kind: Kind, var: &str, property: &str, pos: Position) {
        let (methods, properties) = self.registry.members(kind);
        if properties.contains(property) {
            return;
        }
        let message = if let Some(message) = self.member_of_the_other_kind(kind, var, property) {
            message
        } else if methods.contains(property) {
            let takes_nothing = self
                .registry
                .functions
                .get(property)
                .is_some_and(|o| o.iter().any(|(n, t)| *n == 1 && *t == Some(kind.type_id())));
            let args = if takes_nothing { "()" } else { "(..)" };
            format!("{var}.{property} is a method: call it, as {var}.{property}{args}")
        } else {
            let near = closest(property, properties.iter().copied())
                .or_else(|| closest(property, methods.iter().copied()));
            format!(
                "{var} is a {}: it has no property {property}{}",
                kind.name(),
                suggestion(near)
            )
        };
        self.report(pos, message);
    }

    /// The names rig.toml gives the points of the device a method is called on: that
    /// device's when the receiver is one by name, else those of every device of `kind`.
    fn names_on(&self, object: Option<&(Kind, String)>, kind: Kind) -> PointNames {
        if let Some(names) = object.and_then(|(_, var)| self.point_names.get(var)) {
            return names.clone();
        }
        PointNames::from_pairs(
            self.point_names
                .iter()
                .filter(|(dev, _)| self.devices.get(*dev) == Some(&kind))
                .flat_map(|(_, names)| names.iter()),
        )
    }

    /// Checks the literal arguments of a call and the parameters of the handler it is given;
    /// `method` holds the device a method is called on, when it is known.
    fn check_call(
        &mut self,
        call: &FnCallExpr,
        pos: Position,
        method: Option<Option<&(Kind, String)>>,
    ) {
        let is_method = method.is_some();
        let object = method.flatten();
        let name = call.name.as_str();
        let args = call.args.as_slice();
        let on_trc = "a TRC1000";
        match (name, args.first()) {
            ("pressed" | "on_press" | "on_release", Some(Expr::StringConstant(s, at))) => {
                let names = self.names_on(object, Kind::Trc);
                if let Err(e) = switch_named(&names, on_trc, s) {
                    self.report(*at, e);
                }
            }
            ("rotary" | "turned" | "on_turn", Some(Expr::StringConstant(s, at))) => {
                let names = self.names_on(object, Kind::Trc);
                if let Err(e) = rotary_named(&names, on_trc, s) {
                    self.report(*at, e);
                }
            }
            (
                "output" | "set_output" | "input" | "counter" | "clear_counter" | "on_rise"
                | "on_fall" | "on_counter",
                Some(Expr::StringConstant(s, at)),
            ) if is_method => {
                let way = if matches!(name, "output" | "set_output") {
                    Way::Output
                } else {
                    Way::Input
                };
                let names = self.names_on(object, Kind::C29u);
                if let Err(e) = channel_named(&names, "a TRP-C29U", s, way) {
                    self.report(*at, e);
                }
            }
            (
                "output" | "set_output" | "input" | "counter" | "clear_counter" | "on_rise"
                | "on_fall" | "on_counter",
                Some(Expr::IntegerConstant(n, at)),
            ) if !(0..8).contains(n) && (is_method || !call.args.is_empty()) => {
                self.report(
                    *at,
                    format!("channel {n} does not exist on a TRP-C29U: use 0-7"),
                );
            }
            ("every" | "after", Some(Expr::StringConstant(s, at))) if !is_method => {
                if let Err(e) = parse_duration(s) {
                    self.report(*at, e.to_string());
                }
            }
            ("cron", Some(Expr::StringConstant(s, at))) if !is_method => {
                if let Err(e) = validate_cron(s) {
                    self.report(*at, e.to_string());
                }
            }
            ("invariant", _) if !is_method => self.check_invariant(args, pos),
            _ => {}
        }
        let device_only = matches!(
            name,
            "on_press" | "on_release" | "on_turn" | "on_rise" | "on_fall" | "on_counter"
        );
        if device_only && !is_method {
            return;
        }
        if let Some((_, index, params)) = HANDLERS.iter().find(|(n, ..)| *n == name) {
            if let Some(handler) = args.get(*index) {
                if let Some((takes, at)) = self.arity(handler) {
                    if takes > params.len() {
                        let at = if at.is_none() { pos } else { at };
                        self.report(
                            at,
                            format!(
                                "the handler of {name} {}; this function takes {takes}",
                                takes_words(params)
                            ),
                        );
                    }
                }
            }
        }
    }

    /// `invariant(name, || bool)`: a name, and a closure (not a value computed once). Another
    /// number of arguments is reported as for every call.
    fn check_invariant(&mut self, args: &[Expr], pos: Position) {
        let [name, check] = args else {
            return;
        };
        let place = |e: &Expr| {
            if e.position().is_none() {
                pos
            } else {
                e.position()
            }
        };
        if !matches!(name, Expr::StringConstant(..) | Expr::Variable(..)) {
            self.report(
                place(name),
                "the first argument of invariant is its name, a string".into(),
            );
        }
        let value = matches!(
            check,
            Expr::BoolConstant(..)
                | Expr::IntegerConstant(..)
                | Expr::FloatConstant(..)
                | Expr::StringConstant(..)
                | Expr::CharConstant(..)
                | Expr::Unit(..)
                | Expr::And(..)
                | Expr::Or(..)
                | Expr::Dot(..)
                | Expr::Index(..)
        );
        if value || matches!(check, Expr::FnCall(c, _) if c.name.as_str() != "Fn") {
            self.report(
                place(check),
                "the check of invariant must be a closure taking no parameters, such as `|| \
                 io.outputs == 0`: a value is computed once, a closure every tick"
                    .into(),
            );
        }
    }

    /// How many parameters the function `e` stands for takes (captured variables taken off).
    fn arity(&self, e: &Expr) -> Option<(usize, Position)> {
        let (fn_name, curried, pos) = match e {
            Expr::DynamicConstant(d, pos) => {
                let f = (**d).clone().try_cast::<FnPtr>()?;
                (f.fn_name().to_string(), f.curry().len(), *pos)
            }
            Expr::FnCall(call, pos) if call.name.as_str() == "Fn" => match call.args.as_slice() {
                [Expr::StringConstant(s, _)] => (s.to_string(), 0, *pos),
                _ => return None,
            },
            Expr::Stmt(block) => {
                // A closure that captures variables: `curry(Fn(anon), captured..)`.
                let call = block.statements().iter().find_map(|s| match s {
                    Stmt::FnCall(call, _) if call.name.as_str() == "curry" => Some(call),
                    _ => None,
                })?;
                let (first, captured) = call.args.split_first()?;
                let (inner, _) = self.arity(first)?;
                return Some((inner.saturating_sub(captured.len()), e.position()));
            }
            _ => return None,
        };
        let counts: Vec<usize> = self
            .ast
            .iter_functions()
            .filter(|f| f.name == fn_name)
            .map(|f| f.params.len().saturating_sub(curried))
            .collect();
        counts.into_iter().min().map(|n| (n, pos))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn problems(source: &str) -> Vec<String> {
        check(source, &RigConfig::simulated_default())
            .iter()
            .map(ToString::to_string)
            .collect()
    }

    #[test]
    fn names_rig_toml_gives_are_taken_and_others_refused_with_the_nearest() {
        let config = RigConfig::parse(
            "[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\n\
             [devices.io.names]\nDI0 = \"guard door\"\nDO0 = \"motor\"\n\
             [devices.panel]\nkind = \"trc1000\"\n\
             [devices.panel.names]\nS12 = \"cycle start\"\nS41A = \"die selector\"\n",
            "rig.toml",
        )
        .unwrap();
        let good = "io.on_rise(\"guard door\", |ch| io.set_output(\"motor\", true));\n\
                    panel.on_press(\"cycle start\", |s| print(panel.rotary(\"die selector\")));\n\
                    let d = device(\"io\"); print(d.input(\"guard door\"));\n";
        assert_eq!(check(good, &config), vec![]);
        let bad = "print(io.input(\"gaurd door\"));\nprint(io.input(\"motor\"));\n\
                   panel.on_press(\"cycle strat\", || 1);\n";
        let p: Vec<String> = check(bad, &config)
            .iter()
            .map(ToString::to_string)
            .collect();
        assert_eq!(p.len(), 3, "{p:?}");
        assert!(
            p[0].starts_with(
                "1:16: no channel called \"gaurd door\" on a TRP-C29U (did you mean \"guard door\"?)"
            ),
            "{p:?}"
        );
        assert!(p[1].contains("\"motor\" names DO0"), "{p:?}");
        assert!(p[2].contains("(did you mean \"cycle start\"?)"), "{p:?}");
        // Without names in rig.toml, a name is no channel.
        let p = problems("print(io.input(\"guard door\"));");
        assert!(p[0].contains("no channel called \"guard door\""), "{p:?}");
    }

    #[test]
    fn a_good_script_has_no_problems() {
        let p = problems(
            r#"
let io = device("io");
let panel = device("panel");
let n = 0;
panel.on_press("S1", |name| { n += 1; io.outputs = n; });
panel.on_turn("S41A", |delta, value| { panel.relay = value % 8; });
io.on_counter(2, 100, |count| { io.clear_counter(2); });
every("1s", || io.set_output(0, !io.output(0)));
cron("0 */5 * * * *", || print(now()));
after(500, || stop());
on_stop(|| print("bye"));
"#,
        );
        assert!(p.is_empty(), "{p:?}");
    }

    #[test]
    fn each_problem_is_reported_at_its_line_and_column() {
        let p = problems(
            r#"let io = device("oi");
device("nope");
let panel = device("panel");
panel.on_press("S99", || {});
panel.on_turn("S41A", |a, b, c| {});
let io2 = device("io");
io2.on_rise(9, || {});
io2.on_press("S1", || {});
panel.outputs = 3;
every("1 fortnight", || {});
cron("not cron", || {});
after("1s", |x| {});
"#,
        );
        assert_eq!(p.len(), 10, "{p:#?}");
        assert!(
            p[0].starts_with("1:17: no device called \"oi\""),
            "{}",
            p[0]
        );
        let p: Vec<String> = p
            .into_iter()
            .filter(|l| !l.starts_with("2:8: no device called \"nope\""))
            .collect();
        assert_eq!(p.len(), 9, "{p:#?}");
        assert!(
            p[1].starts_with("4:16: no switch called \"S99\""),
            "{}",
            p[1]
        );
        assert!(
            p[2].starts_with("5:23: the handler of on_turn takes at most 2"),
            "{}",
            p[2]
        );
        assert!(p[3].starts_with("7:13: channel 9"), "{}", p[3]);
        assert!(
            p[4].starts_with("8:5: io2 is a TRP-C29U: it has no on_press"),
            "{}",
            p[4]
        );
        assert!(
            p[5].starts_with("9:7: panel is a TRC1000: it has no outputs"),
            "{}",
            p[5]
        );
        assert!(p[6].starts_with("10:7: "), "{}", p[6]);
        assert!(p[7].starts_with("11:6: "), "{}", p[7]);
        assert!(
            p[8].starts_with("12:13: the handler of after takes no parameters"),
            "{}",
            p[8]
        );
    }

    #[test]
    fn device_names_are_variables_too() {
        let p = problems("io.on_press(\"S1\", || {});\npanel.outputs = 1;\nlet io = 5;\n");
        assert_eq!(
            p.len(),
            1,
            "io is rebound to a number, so it is not checked: {p:?}"
        );
        let p = problems("io.on_press(\"S1\", || {});\npanel.outputs = 1;\n");
        assert_eq!(p.len(), 2, "{p:?}");
        assert!(p[0].starts_with("1:4: io is a TRP-C29U"), "{p:?}");
        assert!(p[1].starts_with("2:7: panel is a TRC1000"), "{p:?}");
    }

    #[test]
    fn invariants_must_be_closures_taking_no_parameters() {
        let good = problems(
            "let limit = 3;\ninvariant(\"low\", || io.outputs <= limit);\ninvariant(\"a\", || true);\n",
        );
        assert!(good.is_empty(), "{good:?}");
        let p = problems(
            "invariant(\"x\", |a| true);\ninvariant(\"y\", io.outputs == 0);\ninvariant(\"z\");\ninvariant(\"w\", true);\n",
        );
        assert_eq!(p.len(), 4, "{p:#?}");
        assert!(
            p[0].starts_with("1:16: the handler of invariant takes no parameters"),
            "{}",
            p[0]
        );
        assert!(
            p[1].starts_with("2:") && p[1].contains("must be a closure"),
            "{}",
            p[1]
        );
        assert!(
            p[2].starts_with("3:1: invariant takes 2 arguments, not 1"),
            "{}",
            p[2]
        );
        assert!(
            p[3].starts_with("4:16: the check of invariant must be a closure"),
            "{}",
            p[3]
        );
    }

    #[test]
    fn syntax_errors_and_the_sandbox_are_reported() {
        let p = problems("let x = ;");
        assert_eq!(p.len(), 1);
        assert!(p[0].starts_with("1:9: "), "{p:?}");
        assert!(!problems(r#"import "fs" as fs;"#).is_empty());
        assert!(!problems(r#"eval("1")"#).is_empty());
    }

    #[test]
    fn unknown_methods_inside_handlers_are_found_with_a_suggestion() {
        // The issue's example: `check` said ok, and `run` failed two seconds later.
        let p = problems("every(\"2s\", || { io.set_outptu(2, true); });\n");
        assert_eq!(
            p,
            vec!["1:21: io is a TRP-C29U: it has no method set_outptu; did you mean `set_output`?"]
        );
    }

    #[test]
    fn calls_are_checked_in_closures_script_functions_and_handlers_alike() {
        let p = problems(
            r#"fn helper(n) {
    io.clear_countr(n);
    baz();
}
panel.on_press("S1", |name| {
    helper(1, 2);
    print(name.lenn());
});
cron("0 * * * * *", || { io.outputz = 1; });
io.on_rise(0, || { let f = |x| x + 1; f(2); });
after("1s", || panel.set_output(1, true));
"#,
        );
        let want = [
            "2:8: io is a TRP-C29U: it has no method clear_countr; did you mean `clear_counter`?",
            "3:5: no function called baz in the script API or this script",
            "6:5: helper takes 1 argument (n), not 2",
            "7:16: no method called lenn in the script API or this script; did you mean `len`?",
            "9:29: io is a TRP-C29U: it has no property outputz; did you mean `outputs`?",
            "10:39: f is a variable, not a function: call the function it holds as f.call(..)",
            "11:22: panel is a TRC1000: it has no set_output (that is a TRP-C29U member)",
        ];
        let p: Vec<&str> = p.iter().map(String::as_str).collect();
        assert_eq!(p.len(), want.len(), "{p:#?}");
        for (got, want) in p.iter().zip(want) {
            assert_eq!(*got, want);
        }
    }

    #[test]
    fn argument_counts_and_members_used_the_wrong_way() {
        let p = problems(
            "io.set_output(1);\nio.counters;\nio.outputs();\nset_output(2, true);\nstop(1, 2);\n\
             fn double(x) { x * 2 }\nprint(3.double());\n",
        );
        assert_eq!(
            p,
            vec![
                "1:4: io.set_output takes 2 arguments, not 1",
                "2:4: io.counters is a method: call it, as io.counters()",
                "3:4: io.outputs is a property: write io.outputs, without ()",
                "4:1: set_output is a method of a TRP-C29U: call it on the device, as io.set_output(..)",
                "5:1: stop takes 0 or 1 arguments, not 2",
                "7:9: .double(..) takes 1 argument, not 0 (a function of the script called as a \
                 method gets its object as `this`)",
            ]
        );
    }

    /// Valid uses of the standard library, maps of functions, methods of the script, `this`,
    /// function pointers and parameters named like devices: none may be reported.
    const VALID: &[&str] = &[
        "let a = [3, 1, 2]; a.sort(); let b = a.map(|x| x * 2).filter(|x| x > 2); print(b.len());",
        "let s = \"hello\"; print(s.sub_string(1, 2) + s.to_upper() + s.len());",
        "let m = #{a: 1}; print(m.keys()); print(\"a\" in m); m.b = 2; print(m.values().len());",
        "let obj = #{ n: 1, twice: |x| x * 2 }; print(obj.twice(4));",
        "let k = #{}; k.step = |x| x + 1; print(k.step(1));",
        "fn inc() { this += 1; } let n = 1; n.inc(); print(n);",
        "fn double(x) { x * 2 } print(double(2)); let f = Fn(\"double\"); print(f.call(3)); \
         let g = |x, y| x + y; print(g.call(1, 2)); let h = g.curry(1); print(h.call(2)); \
         print(call(h, 5)); print(is_def_fn(\"double\", 1));",
        "print(type_of(1)); print(1.type_of()); for (x, i) in [1, 2] { print(x + i); } \
         for i in 0..3 { print(i); } print(max(1, 2)); print(abs(-3)); \
         print(parse_int(\"5\") + 1); print(1.5.floor()); print(to_string(5));",
        "io.outputs = io.outputs | 1; io.set_output(0, io.output(1)); print(io.counters().len()); \
         print(panel.pressed()); panel.relay = 2; print(io.watchdog()); io.watchdog(2); \
         io.watchdog(1.5); io.watchdog_off(); print(io.latched().on); print(io.online);",
        "let x = 5; print(x.to_string()); print(`${x}`); debug(x); log(\"a\"); warn(\"b\"); \
         record(\"r\", 1); measure(\"m\", 1.0, #{min: 0, max: 2}); \
         cancel(every(\"1s\", || {})); on_stop(|| {}); print(now() + uptime());",
        "let io2 = device(\"io\"); io2.on_rise(1, |ch| io2.set_output(ch, true));",
        "let x = 1; every(\"1s\", || { x += 1; io.outputs = x; });",
        "fn show(io) { io.len() } print(show([1]));",
        "let f = |panel| panel.len(); print(f.call(\"ab\"));",
        "let io = device(\"io\"); every(\"1s\", || { let g = |panel| panel.len(); print(g.call(\"x\")); io.outputs = 1; });",
    ];

    /// Each a mistake `run` fails on, on its line, at the top level or in a handler.
    const MISTAKES: &[&str] = &[
        "io.set_outptu(2, true);",
        "every(\"2s\", || { io.set_outptu(2, true); });",
        "foo(1);",
        "io.set_output(1);",
        "io.outputz = 1;",
        "io.outputs = 300;",
        "every(\"1s\", || { panel.relay = 8; });",
        "io.safe_value = -1;",
        "fn bar(x) { x } bar(1, 2);",
        "let a = [1]; a.psh(3);",
        "print(io.counters);",
        "io.outputs();",
        "set_output(2, true);",
        "let f = |x| x + 1; f(2);",
        "panel.set_output(1, true);",
        "every(\"1s\", |missed| { print(missed.lenn()); });",
        "fn helper() { io.clear_countr(1); } helper();",
        "fn double(x) { x * 2 } print(3.double());",
    ];

    /// How a run of `source` on the simulated rig ends within three virtual seconds.
    fn run_status(source: &str) -> (Option<i32>, String) {
        use crate::script::builder::RigBuilder;
        use crate::time::clock::VirtualClock;
        use chrono::{TimeZone, Utc};
        let clock = VirtualClock::new(Utc.with_ymd_and_hms(2026, 3, 28, 12, 0, 0).unwrap());
        let mut rig = RigBuilder::from_config(RigConfig::simulated_default())
            .simulated()
            .clock(Arc::new(clock))
            .zone(Zone::utc())
            .run_for(Duration::from_secs(3))
            .log_to_stderr(false)
            .quiet()
            .keep_log()
            .start(source, "t.rhai")
            .expect("the rig starts");
        rig.runner.advance(Duration::from_millis(3500));
        let log = rig.runner.runtime().borrow().log_lines().join("\n");
        (rig.runner.status(), log)
    }

    #[test]
    fn literal_numbers_a_device_property_cannot_hold_are_reported_as_the_run_would() {
        let p = problems(
            "io.outputs = 300;\npanel.relay = 9;\nio.outputs = 0xFF;\npanel.relay = 7;\n\
             let x = 300;\nio.outputs = x;\nio.outputs += 300;\n",
        );
        assert_eq!(
            p,
            [
                "1:14: 300 is not a DO byte: use 0-255 (0x00-0xFF, 0b00000000-0b11111111)",
                "2:15: relay 9 does not exist on panel (TRC1000): use 0-7",
            ]
        );
    }

    #[test]
    fn a_call_with_no_function_fails_at_run_time_in_checks_words() {
        // Run without `check` first, as scenario tests and the fault search start scripts;
        // the last three `check` cannot see.
        for (seen, source, says) in [
            // The issue's interlock: Rhai said "Function not found: set_ouptut (TRP-C29U, i64,
            // bool)".
            (
                true,
                "let d = if true { io } else { panel };\nevery(\"1s\", || d.set_ouptut(7, false));",
                "t.rhai:2:18: in every 1s: d is a TRP-C29U: it has no method set_ouptut; did you \
                 mean `set_output`?",
            ),
            (
                false,
                "every(\"1s\", || io.set_output(1, 1));",
                "t.rhai:1:19: in every 1s: io.set_output(i64, i64): set_output takes arguments \
                 of other types",
            ),
            (
                false,
                "let d = if true { io } else { panel };\nd.relay = 3;",
                "t.rhai:2:3: in top level: d is a TRP-C29U: it has no relay (that is a TRC1000 \
                 member)",
            ),
            (
                false,
                "let name = \"nope\";\nlet f = Fn(name);\nf.call(1);",
                "in top level: no function called nope in the script API or this script",
            ),
        ] {
            assert_eq!(problems(source).is_empty(), !seen, "{source}");
            let (status, log) = run_status(source);
            assert_eq!(status, Some(1), "{source}\n{log}");
            assert!(log.contains(says), "{source}: {log}");
            assert!(!log.contains("Function not found"), "{log}");
        }
    }

    #[test]
    fn what_check_passes_runs_and_what_it_reports_fails() {
        for source in VALID {
            assert_eq!(problems(source), Vec::<String>::new(), "{source}");
            let (status, log) = run_status(source);
            assert_ne!(status, Some(1), "{source}\n{log}");
        }
        for source in MISTAKES {
            let p = problems(source);
            assert_eq!(p.len(), 1, "{source}: {p:?}");
            let (status, log) = run_status(source);
            assert_eq!(status, Some(1), "{source} should fail when run\n{log}");
            // The run says what check says (`NotFound` for Rhai's "Function not found").
            let (place, message) = p[0].split_once(": ").unwrap();
            let line = place.split(':').next().unwrap();
            assert!(
                log.contains(&format!("t.rhai:{line}:")) && log.contains(message),
                "{source}: check says {message:?} at {place}, the run:\n{log}"
            );
        }
    }

    #[test]
    fn the_shipped_scripts_have_no_problems() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let mut checked = 0;
        for dir in ["scripts", "tests/scenarios/scripts", "packaging/systemd"] {
            for entry in std::fs::read_dir(root.join(dir)).unwrap() {
                let path = entry.unwrap().path();
                if path.extension().is_none_or(|e| e != "rhai") {
                    continue;
                }
                let source = std::fs::read_to_string(&path).unwrap();
                let p = problems(&source);
                // worker.rhai sets channel 9 on purpose, to test how a run ends on a script error.
                let expected: &[&str] = if path.ends_with("worker.rhai") {
                    &["6:19: channel 9 does not exist on a TRP-C29U: use 0-7"]
                } else {
                    &[]
                };
                assert_eq!(p, expected, "{}", path.display());
                checked += 1;
            }
        }
        assert!(checked >= 13, "found only {checked} scripts");
    }
}
