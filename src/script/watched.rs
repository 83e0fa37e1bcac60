//! The script's top-level variables a person may watch (the page, `/api/state`, `status`):
//! every variable by default, or those `watch(...)` names; read from the top level's scope as
//! numbers, booleans and short strings, at most `MAX_VARIABLES` of them.

use super::values::to_json;
use crate::runtime::snapshot::{Variable, Variables, MAX_VARIABLES, MAX_VARIABLE_CHARS};
use crate::suggest::closest;
use rhai::{Array, Dynamic, Engine, EvalAltResult, NativeCallContext, Position, Scope};
use serde_json::Value;
use std::cell::RefCell;
use std::rc::Rc;

/// Names `watch(...)` may hold at most (more is a script error: the page shows at most
/// `MAX_VARIABLES` anyway).
const MAX_CHOSEN: usize = MAX_VARIABLES;

/// The names a script chose with `watch(...)`, each with where it was named.
#[derive(Debug, Clone, Default)]
pub struct Watch {
    chosen: Rc<RefCell<Vec<(String, Position)>>>,
}

impl Watch {
    /// Registers `watch(name)` and `watch([names])`, which add to what this `Watch` holds.
    pub fn register(&self, engine: &mut Engine) {
        let one = self.clone();
        engine.register_fn(
            "watch",
            move |ctx: NativeCallContext, name: &str| -> Result<(), Box<EvalAltResult>> {
                one.choose(name, ctx.call_position())
            },
        );
        let many = self.clone();
        engine.register_fn(
            "watch",
            move |ctx: NativeCallContext, names: Array| -> Result<(), Box<EvalAltResult>> {
                for name in names {
                    let Some(name) = name.clone().into_immutable_string().ok() else {
                        return Err(format!(
                            "watch takes the names of top-level variables as strings, not {}",
                            name.type_name()
                        )
                        .into());
                    };
                    many.choose(&name, ctx.call_position())?;
                }
                Ok(())
            },
        );
    }

    fn choose(&self, name: &str, at: Position) -> Result<(), Box<EvalAltResult>> {
        let mut chosen = self.chosen.borrow_mut();
        if chosen.iter().any(|(n, _)| n == name) {
            return Ok(());
        }
        if chosen.len() >= MAX_CHOSEN {
            return Err(format!("watch names at most {MAX_CHOSEN} variables").into());
        }
        chosen.push((name.to_string(), at));
        Ok(())
    }

    /// Forgets the names chosen (the top level runs again: a restart or a reload), giving
    /// them back (a reload rolled back puts them back with `restore`).
    pub fn clear(&self) -> Vec<(String, Position)> {
        std::mem::take(&mut *self.chosen.borrow_mut())
    }

    /// Chooses `chosen` again, as `clear` gave them.
    pub fn restore(&self, chosen: Vec<(String, Position)>) {
        *self.chosen.borrow_mut() = chosen;
    }

    /// The first name chosen that `top` (the top level's scope, after it ran) has no variable
    /// or constant for: what is wrong, and where it was named.
    pub fn unknown(&self, top: &Scope) -> Option<(String, Position)> {
        let chosen = self.chosen.borrow();
        let (name, at) = chosen.iter().find(|(n, _)| !top.contains(n))?;
        let names = top.iter_raw().map(|(n, _, _)| n);
        let hint = match closest(name, names) {
            Some(near) => format!(" (did you mean {near:?}?)"),
            None => " (watch names a variable the top level declares with let or const)".into(),
        };
        Some((
            format!("watch: the top level has no variable called {name:?}{hint}"),
            *at,
        ))
    }

    /// The variables of `top` to show: those chosen, in the order chosen, or else every
    /// variable (constants left out: they never change), in the order declared.
    pub fn read(&self, top: &Scope) -> Variables {
        let chosen = self.chosen.borrow();
        let mut hidden = 0u64;
        let mut shown: Vec<Variable> = Vec::new();
        let mut show = |name: &str, value: &Dynamic| match shown_value(value) {
            Shown::Value(value) if shown.len() < MAX_VARIABLES => shown.push(Variable {
                name: name.to_string(),
                value,
            }),
            Shown::Value(_) | Shown::TooBig => hidden += 1,
            Shown::NotState => {}
        };
        if chosen.is_empty() {
            // The scope lists the latest first. A name declared twice shows its latest value
            // once, where it was first declared.
            let declared: Vec<_> = top.iter_raw().collect();
            let mut names: Vec<&str> = Vec::new();
            for &(name, constant, _) in declared.iter().rev() {
                if !constant && !names.contains(&name) {
                    names.push(name);
                }
            }
            for name in names {
                if let Some(value) = top.get(name) {
                    show(name, value);
                }
            }
        } else {
            for (name, _) in chosen.iter() {
                if let Some(value) = top.get(name) {
                    show(name, value);
                }
            }
        }
        Variables {
            shown,
            hidden,
            chosen: !chosen.is_empty(),
        }
    }
}

/// How a variable's value is shown.
enum Shown {
    /// On its line.
    Value(Value),
    /// Not on a line (an array, a map, a blob): counted as hidden.
    TooBig,
    /// Not the script's state (a device handle, a closure): left out.
    NotState,
}

/// A value as shown: numbers, booleans, `()` and strings (cut at `MAX_VARIABLE_CHARS`).
fn shown_value(value: &Dynamic) -> Shown {
    let value = value.flatten_clone();
    let shown = value.is_unit()
        || value.is_bool()
        || value.is_int()
        || value.is_float()
        || value.is_string()
        || value.is_char();
    if value.is_array() || value.is_map() || value.is_blob() {
        return Shown::TooBig;
    }
    if !shown {
        return Shown::NotState;
    }
    Shown::Value(match to_json(&value) {
        Value::String(s) if s.chars().count() > MAX_VARIABLE_CHARS => {
            let mut cut: String = s.chars().take(MAX_VARIABLE_CHARS - 1).collect();
            cut.push('…');
            Value::String(cut)
        }
        v => v,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn top_of(script: &str, watch: &Watch) -> Scope<'static> {
        let mut engine = Engine::new();
        watch.register(&mut engine);
        let mut top = Scope::new();
        engine.run_with_scope(&mut top, script).expect("runs");
        top
    }

    fn shown(v: &Variables) -> Vec<(String, Value)> {
        v.shown
            .iter()
            .map(|v| (v.name.clone(), v.value.clone()))
            .collect()
    }

    #[test]
    fn every_variable_shows_by_default_in_declared_order_and_constants_do_not() {
        let w = Watch::default();
        let top = top_of(
            "const BATCH = 100; let count = 7; let armed = true; let state = \"idle\"; \
             let ratio = 0.5; let nothing = (); let count = 8;",
            &w,
        );
        let v = w.read(&top);
        assert_eq!(
            shown(&v),
            vec![
                ("count".into(), json!(8)),
                ("armed".into(), json!(true)),
                ("state".into(), json!("idle")),
                ("ratio".into(), json!(0.5)),
                ("nothing".into(), Value::Null),
            ]
        );
        assert_eq!((v.hidden, v.chosen), (0, false));
    }

    #[test]
    fn arrays_and_maps_are_counted_hidden_closures_left_out_and_long_strings_cut() {
        let w = Watch::default();
        let long = "x".repeat(200);
        let top = top_of(
            &format!("let a = [1, 2]; let m = #{{k: 1}}; let f = || 1; let s = \"{long}\";"),
            &w,
        );
        let v = w.read(&top);
        assert_eq!(v.hidden, 2, "{v:?}");
        assert_eq!(v.shown.len(), 1, "{v:?}");
        let s = v.shown[0].value.as_str().unwrap();
        assert_eq!(s.chars().count(), MAX_VARIABLE_CHARS);
        assert!(s.ends_with('…'), "{s}");
    }

    #[test]
    fn no_more_than_the_bound_are_shown_and_the_rest_are_counted() {
        let w = Watch::default();
        let script: String = (0..MAX_VARIABLES + 5)
            .map(|n| format!("let v{n} = {n};"))
            .collect();
        let v = w.read(&top_of(&script, &w));
        assert_eq!(v.shown.len(), MAX_VARIABLES);
        assert_eq!(v.hidden, 5);
        assert_eq!(v.shown[0].name, "v0");
    }

    #[test]
    fn watch_chooses_which_and_in_what_order_constants_included() {
        let w = Watch::default();
        let top = top_of(
            "const BATCH = 100; let count = 7; let noise = 1; watch([\"count\", \"BATCH\"]); \
             watch(\"count\");",
            &w,
        );
        let v = w.read(&top);
        assert_eq!(
            shown(&v),
            vec![("count".into(), json!(7)), ("BATCH".into(), json!(100))]
        );
        assert!(v.chosen);
        assert_eq!(w.unknown(&top), None);
    }

    #[test]
    fn a_watched_name_the_top_level_lacks_is_told_with_the_nearest_and_its_place() {
        let w = Watch::default();
        let top = top_of("let count = 7;\nwatch(\"cuont\");", &w);
        let (why, at) = w.unknown(&top).expect("unknown");
        assert!(why.contains("\"cuont\"") && why.contains("did you mean \"count\""), "{why}");
        assert_eq!(at.line(), Some(2));
        w.clear();
        assert_eq!(w.unknown(&top), None);
    }

    #[test]
    fn a_name_that_is_not_a_string_is_refused() {
        let mut engine = Engine::new();
        Watch::default().register(&mut engine);
        let err = engine.run("watch([1]);").unwrap_err().to_string();
        assert!(err.contains("as strings, not i64"), "{err}");
    }
}
