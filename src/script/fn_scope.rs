//! Names a script's `fn` uses that only its top level binds. A Rhai function sees its
//! parameters, its own variables and the rig's devices, never the script's top-level `let`
//! and `const`: such a name compiles, then fails when the function runs ("Variable not
//! found"), in an interlock perhaps only the day a guard opens. `check` makes it an error.

use super::check::{only_function, Problem};
use rhai::{ASTNode, Expr, Position, Stmt, AST};
use std::collections::{BTreeMap, HashSet};

/// Every use, inside a named `fn`, of a name the script binds only at its top level (and
/// that is not a device of the rig, which functions do see), in order.
pub(super) fn top_level_names_in_functions(ast: &AST, devices: &HashSet<String>) -> Vec<Problem> {
    let top_level = bound_names(&ast.clone_statements_only());
    if top_level.is_empty() {
        return Vec::new();
    }
    let mut problems = Vec::new();
    for f in ast.iter_functions() {
        // A closure is an anonymous function whose parameters include what it captures: the
        // capture itself is a use in the function (or top level) that makes the closure.
        if f.name.starts_with("anon$") {
            continue;
        }
        let body = only_function(ast, f.name, f.params.len());
        let mut local = bound_names(&body);
        local.extend(f.params.iter().map(|p| p.to_string()));
        for (name, pos) in used_names(&body) {
            if top_level.contains(&name) && !local.contains(&name) && !devices.contains(&name) {
                problems.push(problem(f.name, &f.params, &name, pos));
            }
        }
    }
    problems
}

/// The error for `name` used at `pos` in `function(params)`.
fn problem(function: &str, params: &[&str], name: &str, pos: Position) -> Problem {
    let mut with = params.to_vec();
    with.push(name);
    Problem {
        line: pos.line().unwrap_or(0),
        column: pos.position().unwrap_or(0),
        message: format!(
            "`{name}` is bound at the script's top level, which a fn cannot see: it fails as \
             `{function}` runs (Variable not found). Pass it as an argument: \
             `fn {function}({list})`, called as `{function}({list})`",
            list = with.join(", ")
        ),
    }
}

/// The names `let`, `const` and `for` bind anywhere in `ast`.
fn bound_names(ast: &AST) -> HashSet<String> {
    let mut names = HashSet::new();
    ast.walk(&mut |path: &[ASTNode]| {
        match path.last() {
            Some(ASTNode::Stmt(Stmt::Var(x, ..))) => {
                names.insert(x.0.name.to_string());
            }
            Some(ASTNode::Stmt(Stmt::For(x, _))) => {
                names.insert(x.0.name.to_string());
                if let Some(counter) = &x.1 {
                    names.insert(counter.name.to_string());
                }
            }
            _ => {}
        }
        true
    });
    names
}

/// Each variable `ast` reads or writes, at its first use.
fn used_names(ast: &AST) -> Vec<(String, Position)> {
    let mut first: BTreeMap<String, Position> = BTreeMap::new();
    ast.walk(&mut |path: &[ASTNode]| {
        if let Some(ASTNode::Expr(Expr::Variable(x, _, pos))) = path.last() {
            first.entry(x.1.to_string()).or_insert(*pos);
        }
        true
    });
    let mut uses: Vec<(String, Position)> = first.into_iter().collect();
    uses.sort_by_key(|(_, pos)| (pos.line(), pos.position()));
    uses
}

#[cfg(test)]
mod tests {
    use crate::config::RigConfig;
    use crate::script::check::check;

    fn messages(source: &str) -> Vec<String> {
        check(source, &RigConfig::simulated_default())
            .iter()
            .map(ToString::to_string)
            .collect()
    }

    #[test]
    fn a_top_level_constant_used_in_a_fn_is_an_error_at_its_use_with_the_fix() {
        let found = messages(
            "const MOTOR = 3;\nfn start_motor() {\n    io.set_output(MOTOR, true);\n}\n\
             io.on_rise(0, || start_motor());\n",
        );
        assert_eq!(found.len(), 1, "{found:?}");
        assert!(found[0].starts_with("3:19: `MOTOR` is bound at the script's top level"));
        assert!(
            found[0].ends_with("`fn start_motor(MOTOR)`, called as `start_motor(MOTOR)`"),
            "{}",
            found[0]
        );
    }

    #[test]
    fn a_top_level_let_is_caught_as_a_const_is_and_each_name_once() {
        let found = messages(
            "let limit = 5;\nlet seen = 0;\nfn over(n) { n > limit && limit > 0 || seen > 1 }\n\
             every(\"1s\", || io.set_output(0, over(2)));\n",
        );
        let names: Vec<_> = found
            .iter()
            .map(|m| m.split('`').nth(1).unwrap_or_default().to_string())
            .collect();
        assert_eq!(names, ["limit", "seen"], "{found:?}");
    }

    #[test]
    fn parameters_locals_devices_and_closures_are_not_holes() {
        let clean = "const MOTOR = 3;\n\
             fn start(io, motor) { let on = true; io.set_output(motor, on); }\n\
             fn reset() { panel.relay = 0; for i in 0..8 { io.set_output(i, false); } }\n\
             fn shadow(MOTOR) { MOTOR + 1 }\n\
             io.on_rise(0, || start(io, MOTOR));\n\
             every(\"1s\", || { reset(); shadow(MOTOR); });\n";
        assert_eq!(messages(clean), Vec::<String>::new());
    }

    #[test]
    fn a_closure_made_inside_a_fn_that_captures_a_top_level_name_is_caught() {
        let found = messages(
            "const LAMP = 2;\nfn arm() {\n    every(\"1s\", || io.set_output(LAMP, true));\n}\narm();\n",
        );
        assert_eq!(found.len(), 1, "{found:?}");
        assert!(found[0].contains("`LAMP`"), "{}", found[0]);
    }
}
