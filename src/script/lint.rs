//! What `check` warns of: a script that runs, but not as its author likely meant. A timer
//! shorter than the rig's period (`every("100ms")` at a 5 s period fires at most once a
//! period, and counts the rest as missed), and a script with nothing to run (empty, or no
//! handler, timer or invariant: a run does its top level and ends).

use super::api::HANDLERS;
use super::check::only_function;
use super::engine::{sandboxed, DEFAULT_BUDGET};
use crate::time::duration::{format_duration, parse_duration};
use rhai::{ASTNode, Expr, Position, AST};
use std::time::Duration;

/// One warning: where it applies (`None`: the whole script) and what it says.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Warning {
    /// 1-based line and column, where the warning is about one place.
    pub at: Option<(usize, usize)>,
    /// What may not be meant.
    pub message: String,
}

impl Warning {
    /// The warning as `check` prints it for `file`: `file:3:1: warning: ...`, or
    /// `file: warning: ...` for the whole script.
    pub fn for_file(&self, file: &str) -> String {
        match self.at {
            Some((line, column)) => format!("{file}:{line}:{column}: warning: {}", self.message),
            None => format!("{file}: warning: {}", self.message),
        }
    }

    /// The warning for a log, whose line says it is a warning: `file:3:1: ...`.
    pub fn in_file(&self, file: &str) -> String {
        match self.at {
            Some((line, column)) => format!("{file}:{line}:{column}: {}", self.message),
            None => format!("{file}: {}", self.message),
        }
    }
}

/// The warnings of `source` at the scan `period`, in order (none for a script that does not
/// compile: `check` reports that).
pub fn warnings(source: &str, period: Duration) -> Vec<Warning> {
    let Ok(ast) = sandboxed(DEFAULT_BUDGET).compile(source) else {
        return Vec::new();
    };
    let mut found = Vec::new();
    let mut registers = false;
    let mut note = |path: &[ASTNode]| {
        let (call, pos) = match path.last() {
            Some(ASTNode::Expr(Expr::FnCall(call, pos))) => (&**call, *pos),
            Some(ASTNode::Stmt(rhai::Stmt::FnCall(call, pos))) => (&**call, *pos),
            Some(ASTNode::Expr(Expr::MethodCall(call, pos))) => (&**call, *pos),
            _ => return true,
        };
        let name = call.name.as_str();
        if name != "on_stop" && HANDLERS.iter().any(|(n, ..)| *n == name) {
            registers = true;
        }
        if name == "every" {
            if let Some(w) = short_timer(call.args.first(), pos, period) {
                found.push(w);
            }
        }
        true
    };
    ast.clone_statements_only().walk(&mut note);
    for f in ast.iter_functions() {
        only_function(&ast, f.name, f.params.len()).walk(&mut note);
    }
    if !registers {
        found.push(Warning {
            at: None,
            message: nothing_to_run(&ast),
        });
    }
    found.sort_by_key(|w| w.at);
    found
}

/// The warning for `every(LITERAL, ..)` at `pos` if the literal is shorter than `period`.
fn short_timer(arg: Option<&Expr>, pos: Position, period: Duration) -> Option<Warning> {
    let (written, every) = match arg? {
        Expr::StringConstant(s, _) => (format!("{s:?}"), parse_duration(s).ok()?),
        Expr::IntegerConstant(ms, _) => (
            ms.to_string(),
            Duration::from_millis(u64::try_from(*ms).ok()?),
        ),
        _ => return None,
    };
    (every < period).then(|| Warning {
        at: Some((pos.line().unwrap_or(0), pos.position().unwrap_or(0))),
        message: format!(
            "every({written}) is shorter than the rig's period {}: it fires at most once a \
             period (set a period of {} or less in rig.toml, or a longer timer)",
            format_duration(period),
            format_duration(every)
        ),
    })
}

/// Why there is nothing to run, in words.
fn nothing_to_run(ast: &AST) -> String {
    let empty = ast.statements().is_empty() && ast.iter_functions().next().is_none();
    if empty {
        "the script is empty: there is nothing to run".into()
    } else {
        "nothing to run: the script sets up no handler, timer or invariant, so a run does its \
         top level once and ends"
            .into()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn texts(source: &str, period_ms: u64) -> Vec<String> {
        warnings(source, Duration::from_millis(period_ms))
            .iter()
            .map(|w| w.for_file("s.rhai"))
            .collect()
    }

    #[test]
    fn a_timer_shorter_than_the_period_is_named_with_the_period() {
        let w = texts(
            "let n = 0;\n  every(\"100ms\", || n += 1);\nevery(\"5s\", || {});\n",
            5000,
        );
        assert_eq!(
            w,
            vec![
                "s.rhai:2:3: warning: every(\"100ms\") is shorter than the rig's period 5s: it \
                 fires at most once a period (set a period of 100ms or less in rig.toml, or a \
                 longer timer)"
            ]
        );
        let w = texts("fn start() { every(20, || {}); }\nstart();\n", 50);
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(
            w[0].starts_with(
                "s.rhai:1:14: warning: every(20) is shorter than the rig's period 50ms"
            ),
            "in a function too, in milliseconds: {w:?}"
        );
        assert!(
            texts("every(\"20ms\", || {});", 20).is_empty(),
            "as long is fine"
        );
        assert!(
            texts("let d = \"1ms\"; every(d, || {});", 20).is_empty(),
            "not literal"
        );
    }

    #[test]
    fn a_script_with_nothing_to_run_is_told() {
        assert_eq!(
            texts("", 20),
            vec!["s.rhai: warning: the script is empty: there is nothing to run"]
        );
        assert_eq!(texts("// only a comment\n", 20).len(), 1);
        let w = texts("io.outputs = 1;\non_stop(|| io.outputs = 0);\n", 20);
        assert_eq!(
            w,
            vec![
                "s.rhai: warning: nothing to run: the script sets up no handler, timer or \
                 invariant, so a run does its top level once and ends"
            ]
        );
        for runs in [
            "invariant(\"x\", || true);",
            "panel.on_press(\"S1\", || {});",
            "io.on_rise(0, || {});",
            "cron(\"0 * * * *\", || {});",
            "fn setup() { after(10, || {}); } setup();",
        ] {
            assert!(texts(runs, 20).is_empty(), "{runs}");
        }
    }

    #[test]
    fn a_script_that_does_not_compile_gets_no_warnings() {
        assert!(texts("every(", 20).is_empty());
    }
}
