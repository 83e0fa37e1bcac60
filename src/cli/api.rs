//! `rigscript api [NAME]`: the script reference in the terminal. Its one source is the user
//! guide's chapter docs/guide/02-script-api.md (compiled in), which a test holds to the names
//! the script engine registers; this only picks sections out of it.

use crate::runtime::exit;
use clap::Args;

/// The guide's script reference, as the binary was built with it.
const REFERENCE: &str = include_str!("../../docs/guide/02-script-api.md");

/// Options of `rigscript api`.
#[derive(Debug, Args)]
pub struct ApiArgs {
    /// A function, method or property (`every`, `set_output`, `io.set_output`, `relay`):
    /// print its section. Without one: every name with its first line.
    pub name: Option<String>,
}

/// One `### ...` entry of the reference.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Entry<'r> {
    /// The heading's forms, as written (`` `io.watchdog(seconds)`, `io.watchdog()` ``).
    pub heading: &'r str,
    /// The names its forms define (`watchdog`).
    pub names: Vec<&'r str>,
    /// The text under the heading, up to the next heading.
    pub body: &'r str,
}

/// The entries of a reference written as the guide's chapter is.
pub fn entries(text: &str) -> Vec<Entry<'_>> {
    let mut out = Vec::new();
    let mut rest = text;
    while let Some(at) = rest.find("\n### ") {
        let from = &rest[at + 5..];
        let heading_end = from.find('\n').unwrap_or(from.len());
        let heading = &from[..heading_end];
        let after = &from[heading_end..];
        let body_end = after.find("\n#").unwrap_or(after.len());
        out.push(Entry {
            heading,
            names: names_in(heading),
            body: after[..body_end].trim(),
        });
        rest = &after[body_end..];
    }
    out
}

/// The names a heading's backticked forms define: `io.set_output(ch, on)` -> `set_output`.
fn names_in(heading: &str) -> Vec<&str> {
    let mut names: Vec<&str> = heading
        .split('`')
        .skip(1)
        .step_by(2)
        .filter_map(|form| {
            let call = form.split('(').next()?.trim();
            let name = call.rsplit('.').next()?;
            (!name.is_empty()).then_some(name)
        })
        .collect();
    names.dedup();
    names
}

/// The first sentence of an entry's first paragraph, on one line.
fn first_sentence(body: &str) -> String {
    let paragraph = body.split("\n\n").next().unwrap_or("");
    let line = paragraph.split_whitespace().collect::<Vec<_>>().join(" ");
    match line.find(". ") {
        Some(end) => line[..=end].to_string(),
        None => line,
    }
}

/// The entry for `name` (`io.set_output` and `set_output` alike).
pub fn find<'e, 'r>(entries: &'e [Entry<'r>], name: &str) -> Option<&'e Entry<'r>> {
    let name = name.trim().trim_end_matches("()");
    let name = name.rsplit('.').next().unwrap_or(name);
    entries.iter().find(|e| e.names.contains(&name))
}

/// Runs `rigscript api`; returns the exit status.
pub fn run(args: ApiArgs) -> i32 {
    let all = entries(REFERENCE);
    match args.name {
        None => {
            for e in &all {
                println!(
                    "{}\n    {}",
                    e.heading.replace('`', ""),
                    first_sentence(e.body)
                );
            }
            println!("\n`rigscript api NAME` shows one in full; docs/guide/02-script-api.md has them all.");
            exit::OK
        }
        Some(name) => match find(&all, &name) {
            Some(e) => {
                println!("{}\n\n{}", e.heading.replace('`', ""), e.body);
                exit::OK
            }
            None => {
                let known = all.iter().flat_map(|e| e.names.iter().copied());
                let near = crate::suggest::closest(&name, known)
                    .map_or(String::new(), |n| format!("; did you mean `{n}`?"));
                eprintln!(
                    "rigscript api: `{name}` is not in the script API{near} (`rigscript api` lists them all)"
                );
                exit::USAGE
            }
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::script::check::script_api;

    #[test]
    fn every_name_the_engine_registers_has_its_entry() {
        let all = entries(REFERENCE);
        let api = script_api();
        for name in api.functions.iter().chain(&api.trc1000).chain(&api.c29u) {
            assert!(
                find(&all, name).is_some(),
                "`rigscript api {name}` finds nothing"
            );
        }
    }

    #[test]
    fn a_name_is_found_with_or_without_its_device_and_parentheses() {
        let all = entries(REFERENCE);
        let e = find(&all, "io.set_output").expect("set_output");
        assert_eq!(e.names, ["set_output"]);
        assert!(e.body.contains("DO"), "{}", e.body);
        assert_eq!(find(&all, "set_output()"), Some(e));
        assert_eq!(
            find(&all, "watchdog").map(|e| e.names.clone()),
            Some(vec!["watchdog"])
        );
        assert!(find(&all, "explode").is_none());
    }

    #[test]
    fn headings_name_what_their_forms_define() {
        assert_eq!(
            names_in("`measure(name, value, #{min, max, unit})`, `measure(name, value)`"),
            ["measure"]
        );
        assert_eq!(names_in("`panel.relay`"), ["relay"]);
        assert_eq!(names_in("`print(msg)`, `debug(value)`"), ["print", "debug"]);
    }
}
