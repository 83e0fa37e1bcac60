//! Script errors for people: `file:line:column`, and the cause without Rhai's own position
//! text; the innermost position of a nested call is the one that says where it went wrong.

use crate::runtime::scan::Fault;
use rhai::{EvalAltResult, ParseError, Position};

/// Marks the `ErrorTerminated` that `stop()` raises to end the handler at once (and a device
/// operation a stop cut short).
pub const STOP_MARKER: &str = "rigscript: stop()";

/// `file:line:column` of `pos`, or `None` when Rhai has no position.
pub fn location(file: &str, pos: Position) -> Option<String> {
    match (pos.line(), pos.position()) {
        (Some(line), Some(col)) => Some(format!("{file}:{line}:{col}")),
        (Some(line), None) => Some(format!("{file}:{line}")),
        _ => None,
    }
}

/// The innermost error of a chain of calls and the innermost known position.
pub fn innermost(err: &EvalAltResult) -> (&EvalAltResult, Position) {
    let mut current = err;
    let mut pos = err.position();
    while let EvalAltResult::ErrorInFunctionCall(_, _, inner, p) = current {
        if !p.is_none() {
            pos = *p;
        }
        current = inner;
        if !current.position().is_none() {
            pos = current.position();
        }
    }
    (current, pos)
}

/// The cause of an error in words, without a position.
pub fn cause(err: &EvalAltResult) -> String {
    match err {
        EvalAltResult::ErrorRuntime(v, _) if v.is_string() => v.to_string(),
        EvalAltResult::ErrorTooManyOperations(_) => {
            "too many operations in one call (the operation budget)".into()
        }
        other => {
            let text = other.to_string();
            match text.rfind(" (line ") {
                Some(at) if text.ends_with(')') => text.get(..at).unwrap_or(&text).to_string(),
                _ => text,
            }
        }
    }
}

/// Whether `err` is the unwinding of `stop()`.
pub fn is_stop(err: &EvalAltResult) -> bool {
    matches!(innermost(err).0, EvalAltResult::ErrorTerminated(v, _) if v.to_string() == STOP_MARKER)
}

/// A runtime error as a fault for the scan loop.
pub fn fault(file: &str, err: &EvalAltResult) -> Fault {
    let (inner, pos) = innermost(err);
    Fault {
        location: location(file, pos),
        cause: cause(inner),
        over_budget: matches!(inner, EvalAltResult::ErrorTooManyOperations(_)),
    }
}

/// A compile error as `file:line:column: message`.
pub fn parse_error(file: &str, err: &ParseError) -> String {
    let message = err.err_type().to_string();
    match location(file, err.position()) {
        Some(at) => format!("{at}: {message}"),
        None => format!("{file}: {message}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_error_inside_a_function_is_placed_where_it_happened() {
        let e = rhai::Engine::new();
        let err = e
            .run("fn f() {\n  let x = 1;\n  x.nope()\n}\nf();")
            .unwrap_err();
        let f = fault("s.rhai", &err);
        assert_eq!(f.location.as_deref(), Some("s.rhai:3:5"));
        assert!(f.cause.contains("nope"), "{}", f.cause);
        assert!(!f.cause.contains("line"), "{}", f.cause);
    }

    #[test]
    fn parse_errors_name_file_line_and_column() {
        let e = rhai::Engine::new();
        let err = e.compile("let x = ;").unwrap_err();
        assert!(
            parse_error("s.rhai", &err).starts_with("s.rhai:1:9: "),
            "{}",
            parse_error("s.rhai", &err)
        );
    }
}
