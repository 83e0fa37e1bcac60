//! Runs the runtime's own scenario tests (`tests/scenarios/*.test.rhai`) through
//! `rigscript test`, and checks how `rigscript test` reports failures.

use crate::common::{both, rigscript, stderr, stdout, TempDir};
use std::process::Command;

#[test]
fn the_runtime_scenarios_pass() {
    let out = Command::new(rigscript())
        .args(["test", "tests/scenarios"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let stdout = stdout(&out);
    assert!(out.status.success(), "{stdout}\n{}", stderr(&out));
    let last = stdout.lines().last().unwrap_or_default();
    assert!(last.ends_with(" passed, 0 failed"), "{stdout}");
    let passed: usize = last.split_whitespace().next().unwrap().parse().unwrap();
    assert!(passed >= 30, "{stdout}");
    assert!(
        stdout.lines().all(|l| l.starts_with("ok   ") || l == last),
        "{stdout}"
    );
}

#[test]
fn failures_name_the_test_the_message_and_where() {
    let dir = TempDir::new("scn");
    std::fs::write(
        dir.join("s.rhai"),
        "io.outputs = 3;\nevery(\"1s\", || {});\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("a.test.rhai"),
        r#"fn test_good() {
    let r = rig("s.rhai");
    r.tick();
    assert_eq(r.outputs("io"), 3);
}

fn test_bad() {
    let r = rig("s.rhai");
    r.tick();
    assert_eq(r.outputs("io"), 4, "outputs");
}

fn test_missing_script() {
    rig("nope.rhai");
}
"#,
    )
    .unwrap();
    let out = Command::new(rigscript())
        .arg("test")
        .arg(&dir)
        .output()
        .unwrap();
    let stdout = stdout(&out);
    assert_eq!(out.status.code(), Some(1), "{stdout}");
    let file = dir.join("a.test.rhai").display().to_string();
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 4, "{stdout}");
    assert_eq!(lines[0], format!("ok   {file}::test_good"));
    assert_eq!(
        lines[1],
        format!("FAIL {file}::test_bad: assert_eq failed: outputs: left 3, right 4 at {file}:10:5")
    );
    assert!(
        lines[2].starts_with(&format!("FAIL {file}::test_missing_script: cannot read ")),
        "{stdout}"
    );
    assert_eq!(lines[3], "1 passed, 2 failed");
}

/// Runs `rigscript test` on a directory holding `files` (name, text); the status and stdout.
fn test_dir(name: &str, files: &[(&str, &str)]) -> (Option<i32>, String, TempDir) {
    let dir = TempDir::new(name);
    for (file, body) in files {
        std::fs::write(dir.join(file), body).unwrap();
    }
    let out = Command::new(rigscript())
        .arg("test")
        .arg(&dir)
        .output()
        .unwrap();
    (out.status.code(), stdout(&out), dir)
}

#[test]
fn a_test_file_without_tests_fails() {
    let (status, stdout, dir) = test_dir(
        "no-tests",
        &[(
            "none.test.rhai",
            "fn helper() { 1 }\nfn test_takes(x) { x }\n",
        )],
    );
    let file = dir.join("none.test.rhai").display().to_string();
    assert_eq!(status, Some(1), "{stdout}");
    assert_eq!(
        stdout.lines().next().unwrap_or_default(),
        format!(
            "FAIL {file}::(no tests): {file} has no tests: a test is a function whose name starts \
             with test_ and that takes no parameters, such as `fn test_start() {{ .. }}`"
        )
    );
    assert!(stdout.ends_with("0 passed, 1 failed\n"), "{stdout}");
}

#[test]
fn a_test_that_advances_a_billion_hours_fails_on_its_virtual_time_budget() {
    let (status, stdout, dir) = test_dir(
        "forever",
        &[
            ("s.rhai", "io.outputs = 3;\nevery(\"1s\", || {});\n"),
            (
                "a.test.rhai",
                "fn test_forever() {\n    let r = rig(\"s.rhai\");\n    r.advance(\"1000000000h\");\n}\n\n\
                 fn test_stalls_count_too() {\n    let r = rig(\"s.rhai\");\n    \
                 r.stall(\"700h\");\n    r.advance(\"30h\");\n}\n",
            ),
        ],
    );
    let file = dir.join("a.test.rhai").display().to_string();
    assert_eq!(status, Some(1), "{stdout}");
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(
        lines[0],
        format!(
            "FAIL {file}::test_forever: r.advance(\"1000000000h\") would take the test past its \
             virtual-time budget of 720h (0s used): a test moves a rig's clock by at most that in \
             all; split the scenario into tests at {file}:3:7"
        )
    );
    assert!(
        lines[1].starts_with(&format!(
            "FAIL {file}::test_stalls_count_too: r.advance(\"30h\") would take the test past its \
             virtual-time budget of 720h (700h used)"
        )),
        "{stdout}"
    );
}

#[test]
fn a_script_error_the_test_does_not_look_at_fails_it() {
    let script = "let io = device(\"io\");\nio.outputs = 3;\nlet ch = 9;\n\
                  every(\"100ms\", || io.set_output(ch, true));\n";
    let tests = r#"fn test_passes_over_the_error() {
    let r = rig("err.rhai");
    r.advance("150ms");
}

fn test_expects_errors() {
    let r = rig("err.rhai");
    r.expect_errors();
    r.advance("150ms");
}

fn test_looks_at_the_errors() {
    let r = rig("err.rhai");
    r.advance("150ms");
    assert_eq(r.errors().len(), 1);
}

fn test_looks_too_early() {
    let r = rig("err.rhai");
    assert_eq(r.errors(), []);
    r.advance("150ms");
}
"#;
    let (status, stdout, dir) =
        test_dir("unlooked", &[("err.rhai", script), ("a.test.rhai", tests)]);
    let file = dir.join("a.test.rhai").display().to_string();
    let script = dir.join("err.rhai").display().to_string();
    assert_eq!(status, Some(1), "{stdout}");
    let lines: Vec<&str> = stdout.lines().collect();
    let unlooked = format!(
        "the script under test had 1 error(s) the test did not look at, the first: \
         {script}:4:22: in every 100ms: channel 9 does not exist on io (TRP-C29U): use 0-7; a \
         test that expects errors says so with r.expect_errors() or checks r.errors()"
    );
    assert_eq!(
        lines,
        [
            format!("FAIL {file}::test_passes_over_the_error: {unlooked}").as_str(),
            &format!("ok   {file}::test_expects_errors"),
            &format!("ok   {file}::test_looks_at_the_errors"),
            &format!("FAIL {file}::test_looks_too_early: {unlooked}"),
            "2 passed, 2 failed",
        ],
        "{stdout}"
    );
}

#[test]
fn rigs_built_in_a_loop_count_against_the_tests_memory() {
    let (status, stdout, dir) = test_dir(
        "rig-loop",
        &[
            ("s.rhai", "every(\"1s\", || {});\n"),
            (
                "a.test.rhai",
                "fn test_rigs() {\n    let rigs = [];\n    for i in 0..10000 {\n        \
                 rigs.push(rig(\"s.rhai\"));\n    }\n}\n",
            ),
        ],
    );
    let file = dir.join("a.test.rhai").display().to_string();
    assert_eq!(status, Some(1), "{stdout}");
    assert!(
        stdout.starts_with(&format!(
            "FAIL {file}::test_rigs: the test's memory reached "
        )),
        "{stdout}"
    );
    assert!(
        stdout.contains("over its limit of 256 MiB (rigs built in a loop?"),
        "{stdout}"
    );
}

#[test]
fn no_test_files_is_a_usage_error() {
    let dir = TempDir::new("empty");
    let out = Command::new(rigscript())
        .arg("test")
        .arg(&dir)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("no *.test.rhai files"));
}

#[test]
fn the_scripts_in_scripts_pass_their_scenarios_and_check_clean() {
    let out = Command::new(rigscript())
        .arg("test")
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let stdout = stdout(&out);
    assert!(out.status.success(), "{stdout}\n{}", stderr(&out));
    for script in [
        "rotary_relay",
        "counter_threshold",
        "safe_values",
        "cron_rig",
        "interlock",
    ] {
        assert!(
            stdout.contains(&format!("scripts/tests/{script}.test.rhai::test_")),
            "{script} has scenario tests: {stdout}"
        );
        let check = Command::new(rigscript())
            .args(["check", &format!("scripts/{script}.rhai")])
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .unwrap();
        assert!(check.status.success(), "check {script}: {}", both(&check));
    }
    assert!(stdout.trim_end().ends_with(" passed, 0 failed"), "{stdout}");
}
