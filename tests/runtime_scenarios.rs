//! Runs the runtime's own scenario tests (`tests/scenarios/*.test.rhai`) through
//! `rigscript test`, and checks how `rigscript test` reports failures.

mod common;

use common::rigscript;
use std::process::Command;

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

#[test]
fn the_runtime_scenarios_pass() {
    let out = Command::new(rigscript())
        .args(["test", "tests/scenarios"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", text(&out.stderr));
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
    let dir = std::env::temp_dir().join(format!("rigscript-scn-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
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
    let stdout = text(&out.stdout);
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
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn no_test_files_is_a_usage_error() {
    let dir = std::env::temp_dir().join(format!("rigscript-empty-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = Command::new(rigscript())
        .arg("test")
        .arg(&dir)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out.stderr).contains("no *.test.rhai files"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_scripts_in_scripts_pass_their_scenarios_and_check_clean() {
    let out = Command::new(rigscript())
        .arg("test")
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", text(&out.stderr));
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
        assert!(
            check.status.success(),
            "check {script}: {}{}",
            text(&check.stdout),
            text(&check.stderr)
        );
    }
    assert!(stdout.trim_end().ends_with(" passed, 0 failed"), "{stdout}");
}
