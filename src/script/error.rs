//! Script errors for people: `file:line:column`, and the cause without Rhai's own position
//! text; the innermost position of a nested call is the one that says where it went wrong.
//! A call stopped by a limit says which limit and how to raise it.

use super::engine::{Breach, LIMIT_MARKER, MAX_ARRAY, MAX_CALL_LEVELS, MAX_MAP, MAX_STRING};
use crate::runtime::runner::HandlerFault;
use rhai::{EvalAltResult, ParseError, ParseErrorType, Position};

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

/// The text of an error the engine's guard raised (`engine::Guard`), without its marker.
fn limit_text(err: &EvalAltResult) -> Option<String> {
    match err {
        EvalAltResult::ErrorRuntime(v, _) | EvalAltResult::ErrorTerminated(v, _)
            if v.is_string() =>
        {
            v.to_string().strip_prefix(LIMIT_MARKER).map(str::to_string)
        }
        _ => None,
    }
}

/// The cause of an error in words, without a position.
pub fn cause(err: &EvalAltResult) -> String {
    if let Some(text) = limit_text(err) {
        return text;
    }
    match err {
        EvalAltResult::ErrorRuntime(v, _) if v.is_string() => v.to_string(),
        EvalAltResult::ErrorTooManyOperations(_) => {
            "ran over its operation budget in one call (a runaway loop?); a call that needs \
             more can have it with --budget, or `operations` under [limits] in rig.toml"
                .into()
        }
        EvalAltResult::ErrorStackOverflow(_) => {
            format!("function calls nested more than {MAX_CALL_LEVELS} deep (runaway recursion?)")
        }
        EvalAltResult::ErrorDataTooLarge(what, _) => {
            let (what, max, unit) = match what.as_str() {
                w if w.contains("string") => ("string", MAX_STRING, "bytes"),
                w if w.contains("array") => ("array", MAX_ARRAY, "elements"),
                _ => ("map", MAX_MAP, "entries"),
            };
            format!("a {what} grew over the limit of {max} {unit}")
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

/// A runtime error as a fault for the scan loop; `fallback` places it when Rhai does not (its
/// own limit errors inside a function come out without a position): the start of the
/// handler that was running.
pub fn fault(file: &str, err: &EvalAltResult, fallback: Position) -> HandlerFault {
    let (inner, pos) = innermost(err);
    HandlerFault {
        location: location(file, if pos.is_none() { fallback } else { pos }),
        cause: cause(inner),
        over_budget: matches!(inner, EvalAltResult::ErrorTooManyOperations(_)),
    }
}

/// A call stopped by the guard for `breach`, placed where `result`'s error says (the
/// variable where the guard raised it), else at `fallback`. Whatever the script did with the
/// error (it may have caught it), the breach is what is reported.
pub fn breach_fault(
    file: &str,
    breach: &Breach,
    result: Result<(), &EvalAltResult>,
    fallback: Position,
) -> HandlerFault {
    let pos = match result {
        Err(e) => innermost(e).1,
        Ok(()) => Position::NONE,
    };
    HandlerFault {
        location: location(file, if pos.is_none() { fallback } else { pos }),
        cause: breach.cause(),
        over_budget: breach.is_runaway(),
    }
}

/// A compile error as `file:line:column: message`, at `parse_position`.
pub fn parse_error(file: &str, source: &str, err: &ParseError) -> String {
    let message = err.err_type().to_string();
    match location(file, parse_position(source, err)) {
        Some(at) => format!("{at}: {message}"),
        None => format!("{file}: {message}"),
    }
}

/// Where a compile error is: Rhai's position, except for a missing `;`, which Rhai finds only at
/// the token after it, often on the next line; the statement to end is the last text before
/// that token (comments aside), so the error is placed just after it.
pub fn parse_position(source: &str, err: &ParseError) -> Position {
    let pos = err.position();
    let missing_semicolon =
        matches!(err.err_type(), ParseErrorType::MissingToken(token, _) if token == ";");
    let (Some(line), Some(column)) = (pos.line(), pos.position()) else {
        return pos;
    };
    if !missing_semicolon {
        return pos;
    }
    let lines: Vec<&str> = source.lines().collect();
    let Some(current) = lines.get(line.wrapping_sub(1)) else {
        return pos;
    };
    let before: String = current.chars().take(column.saturating_sub(1)).collect();
    if !before.trim().is_empty() {
        return pos;
    }
    for (index, text) in lines[..line - 1].iter().enumerate().rev() {
        let code = text
            .split_once("//")
            .map_or(*text, |(code, _)| code)
            .trim_end();
        if !code.is_empty() {
            return Position::new(
                u16::try_from(index + 1).unwrap_or(u16::MAX),
                u16::try_from(code.chars().count() + 1).unwrap_or(u16::MAX),
            );
        }
    }
    pos
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
        let f = fault("s.rhai", &err, Position::NONE);
        assert_eq!(f.location.as_deref(), Some("s.rhai:3:5"));
        assert!(f.cause.contains("nope"), "{}", f.cause);
        assert!(!f.cause.contains("line"), "{}", f.cause);
    }

    #[test]
    fn parse_errors_name_file_line_and_column() {
        let e = rhai::Engine::new();
        let err = e.compile("let x = ;").unwrap_err();
        assert!(
            parse_error("s.rhai", "let x = ;", &err).starts_with("s.rhai:1:9: "),
            "{}",
            parse_error("s.rhai", "let x = ;", &err)
        );
    }

    #[test]
    fn a_missing_semicolon_is_placed_where_its_statement_ends() {
        let e = rhai::Engine::new();
        for source in [
            "let a = 1;\nlet b = 2;\nlet c = 3\nlet d = 4;\n",
            "let a = 1;\nlet b = 2;\nlet c = 3 // the third\n\n  // more\n  let d = 4;\n",
        ] {
            let err = e.compile(source).unwrap_err();
            assert_eq!(
                parse_error("syn.rhai", source, &err),
                "syn.rhai:3:10: Expecting ';' to terminate this statement",
                "{source:?}"
            );
        }
        // On the statement's own line, Rhai's place is already the right one.
        let source = "let c = 3 let d = 4;";
        let err = e.compile(source).unwrap_err();
        assert!(parse_error("s.rhai", source, &err).starts_with("s.rhai:1:11: "));
    }
}
