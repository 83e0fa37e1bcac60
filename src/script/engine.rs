//! The sandboxed Rhai engine: no file, process or network access (Rhai has none without
//! modules, and this build has no modules: `import` does not parse), `eval` disabled, and
//! limits on operations per handler call, call depth, expression depth, string, array and
//! map sizes. Printing goes through the runner's log.

use rhai::Engine;

/// Operations one handler call (or the top level) may take before it is stopped as a
/// runaway: about a tenth of a second of script work.
pub const DEFAULT_BUDGET: u64 = 1_000_000;

/// Deepest function call nesting.
pub const MAX_CALL_LEVELS: usize = 48;
/// Longest string, in bytes.
pub const MAX_STRING: usize = 64 * 1024;
/// Most elements of an array.
pub const MAX_ARRAY: usize = 10_000;
/// Most entries of a map.
pub const MAX_MAP: usize = 10_000;
/// Most variables alive in one scope chain.
pub const MAX_VARIABLES: usize = 1_000;
/// Most functions a script may define.
pub const MAX_FUNCTIONS: usize = 1_000;

/// A new engine with the sandbox and its limits; `budget` is the operation budget of each
/// call into the script. Prints are dropped until the caller routes them (`on_print`).
pub fn sandboxed(budget: u64) -> Engine {
    let mut engine = Engine::new();
    engine.disable_symbol("eval");
    engine.set_max_operations(budget.max(1));
    engine.set_max_call_levels(MAX_CALL_LEVELS);
    engine.set_max_expr_depths(64, 32);
    engine.set_max_string_size(MAX_STRING);
    engine.set_max_array_size(MAX_ARRAY);
    engine.set_max_map_size(MAX_MAP);
    engine.set_max_variables(MAX_VARIABLES);
    engine.set_max_functions(MAX_FUNCTIONS);
    engine.on_print(|_| {});
    engine.on_debug(|_, _, _| {});
    engine
}

#[cfg(test)]
mod tests {
    use super::*;
    use rhai::EvalAltResult;

    #[test]
    fn import_and_eval_are_refused() {
        let e = sandboxed(DEFAULT_BUDGET);
        assert!(e.compile(r#"import "os" as os;"#).is_err());
        let err = e.compile(r#"eval("1 + 1")"#).unwrap_err();
        assert!(err.to_string().contains("eval"), "{err}");
    }

    #[test]
    fn a_runaway_loop_hits_the_budget() {
        let e = sandboxed(10_000);
        let err = e.run("loop { }").unwrap_err();
        assert!(
            matches!(*err, EvalAltResult::ErrorTooManyOperations(..)),
            "{err}"
        );
    }

    #[test]
    fn strings_arrays_and_recursion_are_bounded() {
        let e = sandboxed(DEFAULT_BUDGET);
        assert!(matches!(
            *e.run(r#"let s = "x"; loop { s += s; }"#).unwrap_err(),
            EvalAltResult::ErrorDataTooLarge(..)
        ));
        assert!(matches!(
            *e.run("let a = []; loop { a.push(1); }").unwrap_err(),
            EvalAltResult::ErrorDataTooLarge(..)
        ));
        let deep = e.run("fn f(n) { f(n + 1) } f(0);").unwrap_err();
        assert!(
            matches!(*deep, EvalAltResult::ErrorStackOverflow(..)),
            "{deep}"
        );
    }
}
