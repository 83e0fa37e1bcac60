//! The user guide (docs/guide/) against the code's own lists, so it cannot drift: every name
//! of the script API that `check` knows, every call of the scenario-test API, every rig.toml
//! key, every exit status and every control line of the simulator appears in the guide, and
//! what the guide documents exists in the code. Every script and rig.toml the guide shows is a
//! file under docs/guide/examples/, and those pass `rigscript check` and `rigscript test`.

use crate::common::{stderr, stdout};
use rigscript::config::{ConfigError, ProblemKind, RigConfig};
use rigscript::runtime::exit;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;

fn guide_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/guide")
}

/// One page of the guide.
fn page(name: &str) -> String {
    let path = guide_dir().join(name);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Every page of the guide (the `*.md` files), by name.
fn pages() -> Vec<(String, String)> {
    let mut found: Vec<(String, String)> = std::fs::read_dir(guide_dir())
        .expect("docs/guide")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "md"))
        .map(|p| {
            let name = p
                .file_name()
                .unwrap_or_default()
                .to_string_lossy()
                .into_owned();
            (name, std::fs::read_to_string(&p).expect("a guide page"))
        })
        .collect();
    found.sort();
    found
}

/// The files under docs/guide/examples/ (and its folders) whose names end in `suffix`.
fn examples(suffix: &str) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let mut dirs = vec![guide_dir().join("examples")];
    while let Some(dir) = dirs.pop() {
        for entry in std::fs::read_dir(&dir).expect("docs/guide/examples") {
            let p = entry.expect("an entry").path();
            if p.is_dir() {
                dirs.push(p);
            } else if p.to_string_lossy().ends_with(suffix) {
                found.push(p);
            }
        }
    }
    found.sort();
    found
}

/// The code spans (`...`) of `line`.
fn spans(line: &str) -> Vec<&str> {
    line.split('`').skip(1).step_by(2).collect()
}

/// The entries of a reference page: what each `### ` heading's code spans name, as
/// `receiver.name` for a method or property (`io.outputs`, `r.press`) and `name` for a
/// function (`every`).
fn entries(text: &str) -> BTreeSet<String> {
    let mut names = BTreeSet::new();
    for line in text.lines().filter(|l| l.starts_with("### ")) {
        for span in spans(line) {
            let head = span.split(['(', ' ', '=']).next().unwrap_or("");
            if !head.is_empty() {
                names.insert(head.to_string());
            }
        }
    }
    names
}

fn missing_from(documented: &BTreeSet<String>, wanted: &BTreeSet<String>) -> Vec<String> {
    wanted.difference(documented).cloned().collect()
}

#[test]
fn the_script_reference_documents_every_name_check_knows_and_no_other() {
    let api = rigscript::script::check::script_api();
    let mut wanted: BTreeSet<String> = api.functions.iter().cloned().collect();
    wanted.extend(api.trc1000.iter().map(|m| format!("panel.{m}")));
    wanted.extend(api.c29u.iter().map(|m| format!("io.{m}")));
    assert!(wanted.len() > 40, "the API as check knows it: {wanted:?}");
    // Rhai's own `print` and `debug` are the script's messages too (the runner takes them).
    let documented = entries(&page("02-script-api.md"));
    let missing = missing_from(&documented, &wanted);
    assert!(
        missing.is_empty(),
        "02-script-api.md lacks an entry (### `name`) for {missing:?}"
    );
    wanted.extend(["print".to_string(), "debug".to_string()]);
    let unknown = missing_from(&wanted, &documented);
    assert!(
        unknown.is_empty(),
        "02-script-api.md documents what the API lacks: {unknown:?}"
    );
}

/// The names the scenario-test API adds to the engine, as `r.name` for a method of the rig
/// handle and `name` for a function.
fn test_api() -> BTreeSet<String> {
    use rigscript::script::engine::sandboxed;
    let listed = |engine: &rhai::Engine| -> BTreeSet<(String, usize, String)> {
        engine
            .collect_fn_metadata(
                None,
                |info| {
                    let m = info.metadata;
                    let first = m
                        .param_types
                        .first()
                        .map(|t| format!("{t:?}"))
                        .unwrap_or_default();
                    Some((m.name.to_string(), m.num_params, first))
                },
                true,
            )
            .into_iter()
            .collect()
    };
    let mut engine = sandboxed(1000);
    let before = listed(&engine);
    let budget = std::rc::Rc::new(rigscript::script::test_budget::TestBudget::start());
    rigscript::script::scenario::register(&mut engine, Path::new("."), &budget);
    let rig = format!(
        "{:?}",
        std::any::TypeId::of::<rigscript::script::scenario::RigHandle>()
    );
    listed(&engine)
        .difference(&before)
        .filter(|(name, _, _)| name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_'))
        .map(|(name, _, first)| {
            if *first == rig {
                format!("r.{name}")
            } else {
                name.clone()
            }
        })
        .collect()
}

#[test]
fn the_test_reference_documents_every_call_of_the_test_api_and_no_other() {
    let wanted = test_api();
    assert!(wanted.len() > 30, "the test API: {wanted:?}");
    let documented = entries(&page("03-scenario-tests.md"));
    let missing = missing_from(&documented, &wanted);
    assert!(
        missing.is_empty(),
        "03-scenario-tests.md lacks an entry for {missing:?}"
    );
    let unknown = missing_from(&wanted, &documented);
    assert!(
        unknown.is_empty(),
        "03-scenario-tests.md documents what the test API lacks: {unknown:?}"
    );
}

/// The keys rig.toml accepts in the table `text` opens, as its unknown-key error lists them.
fn keys_of(text: &str) -> Vec<&'static str> {
    let text = format!("{text}\nzz_not_a_key = 1\n");
    match RigConfig::parse(&text, "rig.toml") {
        Err(ConfigError::Invalid(problems)) => problems
            .iter()
            .find_map(|p| match &p.kind {
                ProblemKind::UnknownKey { known, .. } => Some(known.to_vec()),
                _ => None,
            })
            .unwrap_or_else(|| panic!("no unknown-key problem for {text:?}: {problems:?}")),
        other => panic!("{text:?} was read as {other:?}"),
    }
}

#[test]
fn the_rig_toml_reference_documents_every_key_and_no_other() {
    let tables = [
        ("", "the top level"),
        ("[limits]", "[limits]"),
        ("[mqtt]\nurl = \"mqtt://broker\"", "[mqtt]"),
        (
            "[devices.panel]\nkind = \"trc1000\"",
            "[devices.NAME] trc1000",
        ),
        (
            "[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"",
            "[devices.NAME] trp-c29u",
        ),
    ];
    let text = page("05-rig-toml.md");
    // The first cell of each table row: `key`.
    let documented: BTreeSet<String> = text
        .lines()
        .filter(|l| l.starts_with("| `"))
        .filter_map(|l| spans(l).first().map(|s| s.to_string()))
        .collect();
    let mut all = BTreeSet::new();
    for (opening, what) in tables {
        for key in keys_of(opening) {
            assert!(
                documented.contains(key),
                "05-rig-toml.md has no row for {what}'s key `{key}`"
            );
            all.insert(key.to_string());
        }
    }
    let unknown: Vec<_> = documented.difference(&all).collect();
    assert!(
        unknown.is_empty(),
        "05-rig-toml.md documents keys rig.toml refuses: {unknown:?}"
    );
}

#[test]
fn the_exit_status_table_shows_every_status_of_the_code() {
    let text = page("07-unattended.md");
    let rows: BTreeSet<String> = text
        .lines()
        .filter(|l| l.starts_with("| "))
        .filter_map(|l| {
            l.split('|')
                .nth(1)
                .map(|c| c.trim().trim_matches('`').to_string())
        })
        .collect();
    let statuses = [
        exit::OK,
        exit::ERROR,
        exit::USAGE,
        exit::UNAVAILABLE,
        exit::MEASUREMENT_FAILED,
        exit::TROUBLE,
        exit::INTERNAL,
        exit::STALLED,
        exit::signal(2),
        exit::signal(15),
    ];
    for status in statuses {
        assert!(
            rows.contains(&status.to_string()),
            "07-unattended.md's exit status table has no row `| {status} |`"
        );
    }
    // And every status the table shows is one the code has: a constant, `stop(N)`'s N, or
    // 128 + a signal.
    for row in rows.iter().filter_map(|r| r.parse::<i32>().ok()) {
        let signalled = (1..=31).any(|n| exit::signal(n) == row);
        assert!(
            statuses.contains(&row) || signalled,
            "07-unattended.md shows exit status {row}, which runtime::exit does not have"
        );
    }
}

#[test]
fn the_commissioning_page_shows_every_control_line_of_the_simulator() {
    let text = page("06-commissioning.md");
    let refusal = rigscript::cli::sim::parse_control("zz").expect_err("not a control line");
    // "unknown control line `zz`: use `di BYTE`, ... optionally after `@ID`"
    let listed = refusal.split_once(": use ").map_or("", |(_, forms)| forms);
    let forms: Vec<&str> = spans(listed)
        .into_iter()
        .filter(|f| !f.starts_with('@'))
        .collect();
    assert!(forms.len() >= 4, "{refusal}");
    for form in forms {
        assert!(
            text.contains(&format!("`{form}`")),
            "06-commissioning.md does not show the simulator's control line `{form}`"
        );
    }
}

/// The fenced blocks of `lang` in `text`.
fn blocks<'t>(text: &'t str, lang: &str) -> Vec<String> {
    let open = format!("```{lang}");
    let mut found = Vec::new();
    let mut current: Option<Vec<&'t str>> = None;
    for line in text.lines() {
        match &mut current {
            None if line.trim_end() == open => current = Some(Vec::new()),
            Some(lines) if line.trim_end() == "```" => {
                found.push(lines.join("\n"));
                current = None;
            }
            Some(lines) => lines.push(line),
            None => {}
        }
    }
    found
}

#[test]
fn every_script_and_rig_toml_the_guide_shows_is_an_example_file() {
    for (lang, suffix) in [("rhai", ".rhai"), ("toml", ".toml")] {
        let files: Vec<String> = examples(suffix)
            .iter()
            .map(|p| std::fs::read_to_string(p).expect("an example"))
            .collect();
        // The README's first script is one of the guide's too.
        let readme = std::fs::read_to_string(guide_dir().join("../../README.md")).expect("README");
        for (name, text) in pages()
            .into_iter()
            .chain([("README.md".to_string(), readme)])
        {
            for block in blocks(&text, lang) {
                assert!(
                    files.iter().any(|f| f.contains(&block)),
                    "{name}: this {lang} block is in no file of docs/guide/examples/ \
                     (put it there, so that the tests check it):\n{block}"
                );
            }
        }
    }
}

#[test]
fn the_guide_s_rig_toml_examples_are_valid() {
    let tomls = examples(".toml");
    assert!(!tomls.is_empty());
    for path in tomls {
        if let Err(e) = RigConfig::load(&path) {
            panic!("{}: {e}", path.display());
        }
    }
}

#[test]
fn the_guide_s_scripts_pass_check() {
    let scripts: Vec<PathBuf> = examples(".rhai")
        .into_iter()
        .filter(|p| !p.to_string_lossy().ends_with(".test.rhai"))
        .collect();
    assert!(scripts.len() >= 4);
    for script in scripts {
        let out = Command::new(env!("CARGO_BIN_EXE_rigscript"))
            .arg("check")
            .arg(&script)
            .output()
            .expect("rigscript check");
        assert!(
            out.status.success(),
            "rigscript check {}: {}{}",
            script.display(),
            stdout(&out),
            stderr(&out)
        );
    }
}

#[test]
fn the_guide_s_scenario_tests_pass() {
    let out = Command::new(env!("CARGO_BIN_EXE_rigscript"))
        .arg("test")
        .arg(guide_dir().join("examples"))
        .output()
        .expect("rigscript test");
    let stdout = stdout(&out);
    assert!(
        out.status.success() && stdout.contains(" passed, 0 failed"),
        "rigscript test docs/guide/examples: {stdout}{}",
        stderr(&out)
    );
}

/// The rig.toml of chapter 5's "When rig.toml is wrong": a slip on each of five lines.
const BAD_TOML: &str = "period = 20\ngrce = \"1s\"\n\n[devices.io]\nkind = \"trp-c29u\"\n\
                        protocol = \"modbsu\"\nwatchdog = \"0.2s\"\nbaud = 9601\n\
                        port = \"/dev/ttyUSB0\"\n";

#[test]
fn the_rig_toml_errors_chapter_5_shows_are_the_ones_printed() {
    let text = page("05-rig-toml.md");
    let lines: Vec<&str> = text
        .lines()
        .skip_while(|l| !l.contains("--config bad.toml"))
        .take_while(|l| !l.starts_with("```"))
        .collect();
    let printed = match RigConfig::parse(BAD_TOML, "bad.toml") {
        Err(e) => format!("rigscript check: {e}"),
        Ok(_) => panic!("bad.toml was read"),
    };
    // Between the command and its exit status: exactly what check prints, every key listed
    // as the code lists it.
    let (Some(first), Some(last)) = (lines.first(), lines.last()) else {
        panic!("an empty block")
    };
    assert!(first.starts_with("$ rigscript check"), "{first}");
    assert_eq!(*last, "exit 2");
    assert_eq!(lines[1..lines.len() - 1].join("\n"), printed);
}

#[test]
fn every_fence_of_the_guide_stands_alone() {
    // A fence with text after it (```` ``` At most ````) opens a block where one should
    // close, and swallows the sections that follow.
    for (name, text) in pages() {
        for (i, line) in text.lines().enumerate() {
            let Some(rest) = line.trim_start().strip_prefix("```") else {
                continue;
            };
            assert!(
                rest.chars().all(|c| c.is_ascii_alphanumeric()),
                "{name}:{}: a fence with text after it: {line:?}",
                i + 1
            );
        }
    }
}
