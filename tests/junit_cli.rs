//! `--junit FILE` on `rigscript run` and `rigscript test`: the reports are read back with an
//! independent XML parser and checked for what Jenkins and GitLab read (suites, cases, their
//! counts, failures and errors with messages, a measurement's value and limits).

use crate::common::{rigscript, stderr, stdout, TempDir};
use roxmltree::{Document, Node};
use std::path::Path;
use std::process::{Command, Output};

fn rigscript_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(rigscript())
        .current_dir(dir)
        .args(args)
        .output()
        .expect("run rigscript")
}

fn status(o: &Output) -> i32 {
    o.status.code().unwrap_or(-1)
}

fn attr<'a>(n: Node<'a, '_>, name: &str) -> &'a str {
    n.attribute(name)
        .unwrap_or_else(|| panic!("<{}> has no {name}", n.tag_name().name()))
}

fn count(n: Node<'_, '_>, name: &str) -> usize {
    attr(n, name).parse().unwrap()
}

fn children<'a, 'i>(n: Node<'a, 'i>, tag: &str) -> Vec<Node<'a, 'i>> {
    n.children().filter(|c| c.has_tag_name(tag)).collect()
}

fn child<'a, 'i>(n: Node<'a, 'i>, tag: &str) -> Option<Node<'a, 'i>> {
    n.children().find(|c| c.has_tag_name(tag))
}

fn property(case: Node<'_, '_>, name: &str) -> Option<String> {
    child(case, "properties")?
        .children()
        .find(|p| p.attribute("name") == Some(name))
        .and_then(|p| p.attribute("value"))
        .map(str::to_string)
}

/// Checks the counts in every suite and in the root against the cases themselves.
fn check_counts(doc: &Document<'_>) {
    let root = doc.root_element();
    assert!(root.has_tag_name("testsuites"));
    let (mut tests, mut failures, mut errors) = (0, 0, 0);
    for suite in children(root, "testsuite") {
        let cases = children(suite, "testcase");
        let failed = cases
            .iter()
            .filter(|c| child(**c, "failure").is_some())
            .count();
        let errored = cases
            .iter()
            .filter(|c| child(**c, "error").is_some())
            .count();
        assert_eq!(count(suite, "tests"), cases.len());
        assert_eq!(count(suite, "failures"), failed);
        assert_eq!(count(suite, "errors"), errored);
        assert!(attr(suite, "time").parse::<f64>().is_ok());
        for c in &cases {
            assert!(attr(*c, "time").parse::<f64>().is_ok());
            assert!(!attr(*c, "classname").is_empty());
        }
        tests += cases.len();
        failures += failed;
        errors += errored;
    }
    assert_eq!(count(root, "tests"), tests);
    assert_eq!(count(root, "failures"), failures);
    assert_eq!(count(root, "errors"), errors);
}

fn read_report(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn run_writes_each_measurement_as_a_case_with_value_and_limits() {
    let dir = TempDir::new("junit-run");
    std::fs::write(
        dir.join("rig.rhai"),
        r#"
measure("supply", 3.3, #{ min: 3.0, max: 3.6, unit: "V" });
measure("supply", 3.9, #{ min: 3.0, max: 3.6, unit: "V" });
measure("leak <µA> & \"x\"", 0.5, #{ max: 1 });
record("serial", "A123");
measure("odd", 0.0 / 0.0);
"#,
    )
    .unwrap();
    let out = rigscript_in(
        &dir,
        &[
            "run",
            "rig.rhai",
            "--sim",
            "--quiet",
            "--junit",
            "report.xml",
        ],
    );
    assert_eq!(status(&out), 4, "{}", stderr(&out));
    let text = read_report(&dir.join("report.xml"));
    let doc = Document::parse(&text).unwrap_or_else(|e| panic!("{e}:\n{text}"));
    check_counts(&doc);
    let suite = children(doc.root_element(), "testsuite")[0];
    assert_eq!(attr(suite, "name"), "rig.rhai");
    let cases = children(suite, "testcase");
    let names: Vec<&str> = cases.iter().map(|c| attr(*c, "name")).collect();
    assert_eq!(
        names,
        ["supply #1", "supply #2", "leak <µA> & \"x\"", "odd", "run"],
        "records are no cases; repeated names are numbered"
    );
    assert!(child(cases[0], "failure").is_none());
    assert_eq!(property(cases[0], "value").as_deref(), Some("3.3"));
    assert_eq!(property(cases[0], "min").as_deref(), Some("3.0"));
    assert_eq!(property(cases[0], "max").as_deref(), Some("3.6"));
    assert_eq!(property(cases[0], "unit").as_deref(), Some("V"));
    let failure = child(cases[1], "failure").expect("3.9 V fails");
    assert_eq!(
        attr(failure, "message"),
        "supply = 3.9 V: above the maximum 3.6 V"
    );
    assert_eq!(attr(failure, "type"), "measurement");
    assert!(child(cases[2], "failure").is_none());
    assert_eq!(property(cases[2], "min"), None);
    let odd = child(cases[3], "failure").expect("NaN fails");
    assert_eq!(attr(odd, "message"), "odd = not a number: not a number");
    assert!(
        child(cases[4], "error").is_none(),
        "failed measurements are no error of the run"
    );
    let props = child(suite, "properties").unwrap();
    assert!(props
        .children()
        .any(|p| p.attribute("name") == Some("exit_status") && p.attribute("value") == Some("4")));
}

#[test]
fn the_packaged_timer_check_reports_its_measurement() {
    // packaging/systemd/bench-check.rhai on the simulator: nothing answers the trigger, so
    // the count is 0, below its minimum.
    let dir = TempDir::new("junit-check");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("packaging/systemd/bench-check.rhai");
    let report = dir.join("check.xml");
    let out = rigscript_in(
        &dir,
        &[
            "run",
            &script.display().to_string(),
            "--sim",
            "--quiet",
            "--junit",
            &report.display().to_string(),
        ],
    );
    assert_eq!(status(&out), 4, "{}", stderr(&out));
    let text = read_report(&report);
    let doc = Document::parse(&text).unwrap();
    check_counts(&doc);
    let case = doc
        .descendants()
        .find(|n| n.has_tag_name("testcase") && n.attribute("name") == Some("response_pulses"))
        .expect("a case for the measurement");
    assert_eq!(
        attr(child(case, "failure").unwrap(), "message"),
        "response_pulses = 0 pulses: below the minimum 1 pulses"
    );
    assert_eq!(property(case, "unit").as_deref(), Some("pulses"));
}

#[test]
fn a_run_that_fails_is_an_error_case_naming_the_place() {
    let dir = TempDir::new("junit-error");
    std::fs::write(
        dir.join("bad.rhai"),
        "measure(\"before\", 1);\nafter(\"50ms\", || {\n    let x = [1][5];\n});\n",
    )
    .unwrap();
    let out = rigscript_in(
        &dir,
        &["run", "bad.rhai", "--sim", "--quiet", "--junit", "r.xml"],
    );
    assert_eq!(status(&out), 1, "{}", stderr(&out));
    let text = read_report(&dir.join("r.xml"));
    let doc = Document::parse(&text).unwrap();
    check_counts(&doc);
    let run = doc
        .descendants()
        .find(|n| n.has_tag_name("testcase") && n.attribute("name") == Some("run"))
        .unwrap();
    let error = child(run, "error").expect("the run's error");
    assert_eq!(attr(error, "type"), "exit status 1");
    let message = attr(error, "message");
    assert!(
        message.starts_with("the run ended with exit status 1: ")
            && message.contains("bad.rhai:3:"),
        "{message}"
    );
}

#[test]
fn a_run_that_cannot_start_still_leaves_a_report() {
    let dir = TempDir::new("junit-absent");
    std::fs::write(
        dir.join("rig.toml"),
        "[devices.io]\nkind = \"trp-c29u\"\nport = \"/nonexistent/ttyUSB9\"\n",
    )
    .unwrap();
    std::fs::write(dir.join("s.rhai"), "measure(\"x\", 1);\n").unwrap();
    let out = rigscript_in(
        &dir,
        &["run", "s.rhai", "--config", "rig.toml", "--junit", "r.xml"],
    );
    assert_eq!(status(&out), 3, "{}", stderr(&out));
    let text = read_report(&dir.join("r.xml"));
    let doc = Document::parse(&text).unwrap();
    check_counts(&doc);
    let error = doc
        .descendants()
        .find(|n| n.has_tag_name("error"))
        .expect("an error case");
    assert_eq!(attr(error, "type"), "exit status 3");
    assert!(
        attr(error, "message").contains("/nonexistent/ttyUSB9"),
        "{}",
        attr(error, "message")
    );
}

#[test]
fn a_report_path_in_a_missing_directory_is_refused_before_the_run() {
    let dir = TempDir::new("junit-nodir");
    std::fs::write(dir.join("s.rhai"), "io.outputs = 0xFF;\n").unwrap();
    let out = rigscript_in(
        &dir,
        &["run", "s.rhai", "--sim", "--junit", "missing/r.xml"],
    );
    assert_eq!(status(&out), 2);
    let err = stderr(&out);
    assert!(
        err.contains("--junit missing/r.xml: the directory missing does not exist"),
        "{err}"
    );
    assert!(!err.contains("outputs"), "nothing ran: {err}");
    let out = rigscript_in(&dir, &["test", "--junit", ".", "s.rhai"]);
    assert_eq!(status(&out), 2, "{}", stderr(&out));
    assert!(
        stderr(&out).contains("--junit .: that is a directory"),
        "{}",
        stderr(&out)
    );
    assert!(out.stdout.is_empty(), "no test ran");
}

#[test]
fn test_writes_a_suite_per_file_and_a_case_per_test() {
    let dir = TempDir::new("junit-test");
    std::fs::write(
        dir.join("s.rhai"),
        "io.outputs = 0x03;\nevery(\"1s\", || {});\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("a.test.rhai"),
        "fn test_outputs() {\n    let r = rig(\"s.rhai\");\n    r.advance(\"40ms\");\n    \
         assert_eq(r.outputs(\"io\"), 3);\n}\n\nfn test_wrong() {\n    let r = rig(\"s.rhai\");\n    \
         r.advance(\"40ms\");\n    assert_eq(r.outputs(\"io\"), 4, \"expects 4 <on purpose>\");\n}\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("b.test.rhai"),
        "fn test_relay() {\n    let r = rig(\"s.rhai\");\n    assert_eq(r.relay(\"panel\"), 0);\n}\n",
    )
    .unwrap();
    let out = rigscript_in(&dir, &["test", ".", "--junit", "tests.xml"]);
    assert_eq!(status(&out), 1, "{}", stderr(&out));
    let stdout = stdout(&out);
    assert!(stdout.contains("2 passed, 1 failed"), "{stdout}");
    let text = read_report(&dir.join("tests.xml"));
    let doc = Document::parse(&text).unwrap();
    check_counts(&doc);
    let suites = children(doc.root_element(), "testsuite");
    let names: Vec<&str> = suites.iter().map(|s| attr(*s, "name")).collect();
    assert_eq!(names, ["./a.test.rhai", "./b.test.rhai"]);
    let cases = children(suites[0], "testcase");
    let case_names: Vec<&str> = cases.iter().map(|c| attr(*c, "name")).collect();
    assert_eq!(case_names, ["test_outputs", "test_wrong"]);
    assert_eq!(attr(cases[1], "classname"), "./a.test.rhai");
    let failure = child(cases[1], "failure").unwrap();
    let message = attr(failure, "message");
    assert!(
        message.contains("expects 4 <on purpose>: left 3, right 4")
            && message.contains("./a.test.rhai:10:"),
        "{message}"
    );
}
