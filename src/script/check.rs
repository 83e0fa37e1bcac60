//! `rigscript check`: finds what can be found without running a script. It compiles it (so
//! syntax, `import` and `eval` are reported), then walks its syntax tree for literal
//! arguments: device names in `device("...")` against the rig, switch and rotary names,
//! channels, durations and cron expressions, the number of parameters of handlers and of
//! invariants (closures taking none), and methods of one kind of device called on the other
//! (for variables bound once to a `device("...")` literal).

use super::api::takes_words;
use super::engine::{sandboxed, DEFAULT_BUDGET};
use crate::config::{DeviceConfig, RigConfig};
use crate::protocol::trc1000::{Rotary, Switch};
use crate::runtime::schedule::validate_cron;
use crate::time::duration::parse_duration;
use rhai::{ASTNode, Expr, FnCallExpr, FnPtr, Position, Stmt, AST};
use std::collections::HashMap;
use std::fmt;

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

    fn members(self) -> &'static [&'static str] {
        match self {
            Kind::Trc => TRC_MEMBERS,
            Kind::C29u => C29U_MEMBERS,
        }
    }
}

const TRC_MEMBERS: &[&str] = &[
    "relay",
    "pressed",
    "rotary",
    "turned",
    "online",
    "on_press",
    "on_release",
    "on_turn",
];

const C29U_MEMBERS: &[&str] = &[
    "outputs",
    "output",
    "set_output",
    "inputs",
    "input",
    "counter",
    "counters",
    "clear_counter",
    "clear_counters",
    "save_counters",
    "latched",
    "clear_latch",
    "watchdog",
    "watchdog_off",
    "safe_value",
    "power_on_value",
    "name",
    "firmware",
    "reset",
    "in_safe_mode",
    "online",
    "on_rise",
    "on_fall",
    "on_counter",
];

/// Handler-taking calls: (name, index of the handler argument, the parameters it gets).
const HANDLERS: &[(&str, usize, &[&str])] = &[
    ("on_press", 1, &["switch name"]),
    ("on_release", 1, &["switch name"]),
    ("on_turn", 1, &["delta", "value"]),
    ("on_rise", 1, &["channel"]),
    ("on_fall", 1, &["channel"]),
    ("on_counter", 2, &["count"]),
    ("every", 1, &["missed"]),
    ("cron", 1, &["missed"]),
    ("after", 1, &[]),
    ("on_stop", 0, &[]),
    ("invariant", 1, &[]),
];

struct Checker<'a> {
    ast: &'a AST,
    devices: HashMap<String, Kind>,
    device_names: String,
    bound: HashMap<String, Kind>,
    problems: Vec<Problem>,
}

/// Checks `source` against the devices of `config`; every problem found, in order.
pub fn check(source: &str, config: &RigConfig) -> Vec<Problem> {
    let engine = sandboxed(DEFAULT_BUDGET);
    let ast = match engine.compile(source) {
        Ok(ast) => ast,
        Err(e) => {
            let (line, column) = line_col(e.position());
            return vec![Problem {
                line,
                column,
                message: e.err_type().to_string(),
            }];
        }
    };
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
    let device_names = config
        .devices
        .keys()
        .cloned()
        .collect::<Vec<_>>()
        .join(", ");
    let mut c = Checker {
        ast: &ast,
        devices,
        device_names,
        bound: HashMap::new(),
        problems: Vec::new(),
    };
    c.bind_variables();
    ast.walk(&mut |path: &[ASTNode]| {
        c.visit(path);
        true
    });
    c.problems.sort_by_key(|p| (p.line, p.column));
    c.problems.dedup();
    c.problems
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

impl Checker<'_> {
    fn report(&mut self, pos: Position, message: String) {
        let (line, column) = line_col(pos);
        self.problems.push(Problem {
            line,
            column,
            message,
        });
    }

    /// Variables bound to a `device("...")` literal (only those never bound to anything else).
    fn bind_variables(&mut self) {
        let mut seen: HashMap<String, Option<Kind>> = HashMap::new();
        let devices = &self.devices;
        self.ast.walk(&mut |path: &[ASTNode]| {
            if let Some(ASTNode::Stmt(Stmt::Var(x, ..))) = path.last() {
                let (ident, expr, _) = &**x;
                let kind = device_literal(expr).and_then(|(n, _)| devices.get(n).copied());
                let name = ident.name.to_string();
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
                self.bound.get(name).map(|k| (*k, name.to_string()))
            }
            e => device_literal(e)
                .and_then(|(n, _)| self.devices.get(n).map(|k| (*k, n.to_string()))),
        }
    }

    fn visit(&mut self, path: &[ASTNode]) {
        let expr = match path.last() {
            Some(ASTNode::Expr(e)) => *e,
            // A call as a statement is a statement of its own, with the same shape.
            Some(ASTNode::Stmt(Stmt::FnCall(call, pos))) => {
                self.check_device_name(call);
                self.check_call(call, *pos, None);
                return;
            }
            _ => return,
        };
        match expr {
            Expr::FnCall(call, pos) => {
                self.check_device_name(call);
                self.check_call(call, *pos, None);
            }
            Expr::Dot(bin, _, _) => {
                let object = self.kind_of(&bin.lhs);
                match &bin.rhs {
                    Expr::MethodCall(call, pos) => self.check_call(call, *pos, object),
                    Expr::Property(p, pos) => {
                        if let Some((kind, var)) = object {
                            self.check_member(kind, &var, p.2.as_str(), *pos);
                        }
                    }
                    _ => {}
                }
            }
            _ => {}
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

    fn check_member(&mut self, kind: Kind, var: &str, member: &str, pos: Position) {
        let other = match kind {
            Kind::Trc => Kind::C29u,
            Kind::C29u => Kind::Trc,
        };
        if !kind.members().contains(&member) && other.members().contains(&member) {
            self.report(
                pos,
                format!(
                    "{var} is a {}: it has no {member} (that is a {} member)",
                    kind.name(),
                    other.name()
                ),
            );
        }
    }

    fn check_call(&mut self, call: &FnCallExpr, pos: Position, object: Option<(Kind, String)>) {
        let name = call.name.as_str();
        let args = call.args.as_slice();
        if let Some((kind, var)) = &object {
            self.check_member(*kind, var, name, pos);
        }
        let is_method = object.is_some();
        match (name, args.first()) {
            ("pressed" | "on_press" | "on_release", Some(Expr::StringConstant(s, at)))
                if Switch::from_name(s).is_none() =>
            {
                self.report(
                    *at,
                    format!("no switch called {s:?} on a TRC1000: use S1-S45"),
                );
            }
            ("rotary" | "turned" | "on_turn", Some(Expr::StringConstant(s, at)))
                if Rotary::from_name(s).is_none() =>
            {
                self.report(
                    *at,
                    format!("no rotary called {s:?} on a TRC1000: use S37-S40 or S41A/B-S45A/B"),
                );
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

    /// `invariant(name, || bool)`: a name, and a closure (not a value computed once).
    fn check_invariant(&mut self, args: &[Expr], pos: Position) {
        match args {
            [name, check] => {
                if !matches!(name, Expr::StringConstant(..) | Expr::Variable(..)) {
                    let at = if name.position().is_none() {
                        pos
                    } else {
                        name.position()
                    };
                    self.report(
                        at,
                        "the first argument of invariant is its name, a string".into(),
                    );
                }
                let literal = matches!(
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
                if literal || matches!(check, Expr::FnCall(c, _) if c.name.as_str() != "Fn") {
                    let at = if check.position().is_none() {
                        pos
                    } else {
                        check.position()
                    };
                    self.report(
                        at,
                        "the check of invariant must be a closure taking no parameters, such \
                         as `|| io.outputs == 0`: a value is computed once, a closure every tick"
                            .into(),
                    );
                }
            }
            _ => self.report(
                pos,
                format!(
                    "invariant takes a name and a closure, `invariant(\"what it promises\", || \
                     ...)`; here it has {} argument(s)",
                    args.len()
                ),
            ),
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
            p[2].starts_with("3:1: invariant takes a name and a closure"),
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
}
