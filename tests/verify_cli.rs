//! `rigscript verify` as people run it: planted bugs found, shrunk to at most 6 events and
//! written as scenario tests that fail with the invariant's name, for two seeds each, two
//! searches at a time (one behind a 75 s timer and one at a count of 300 at the defaults; one
//! behind late answers, one behind a wall-clock step); a count reached through bounced edges
//! shrinks to the count; the five scripts pass with a bounded budget; the same seed gives the
//! same result whatever the number of jobs; the built-in checks; coverage warnings; exit
//! statuses, Ctrl-C's too. And invariants in `run`: a violation is a fault with exit 1.

use crate::common::{rigscript, stderr, stdout, TempDir};
use serde_json::Value;
use std::path::Path;
use std::process::{Command, Output};

fn run(args: &[&str]) -> Output {
    Command::new(rigscript())
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("run rigscript")
}

/// `rigscript verify ARGS.. --json --out OUT`: exit status and the JSON document.
fn verify_json(args: &[&str], out: &Path) -> (i32, Value) {
    let mut all = vec!["verify"];
    all.extend_from_slice(args);
    let out_dir = out.to_string_lossy().into_owned();
    all.extend_from_slice(&["--json", "--out", &out_dir]);
    let o = run(&all);
    let doc = serde_json::from_slice(&o.stdout)
        .unwrap_or_else(|e| panic!("not JSON ({e}): {}\nstderr: {}", stdout(&o), stderr(&o)));
    (o.status.code().unwrap_or(-1), doc)
}

/// Writes `source` as `name` in a fresh directory tagged `tag`; the directory and the path.
fn script(tag: &str, name: &str, source: &str) -> (TempDir, String) {
    let dir = TempDir::new(tag);
    let path = dir.join(name);
    std::fs::write(&path, source).unwrap();
    (dir, path.to_string_lossy().into_owned())
}

/// `verify` of `script` in `dir` on one module with `limits` under `[limits]` in its rig.toml:
/// `runs` runs of 10 s in `jobs` jobs, seed 1, no faults.
fn verify_limited(dir: &Path, script: &str, limits: &str, runs: &str, jobs: &str) -> (i32, Value) {
    let toml = dir.join("rig.toml");
    std::fs::write(
        &toml,
        format!(
            "period = \"20ms\"\n\n[limits]\n{limits}\n\n[devices.io]\nkind = \"trp-c29u\"\n\
             port = \"/dev/ttyUSB0\"\nsafe_value = 0x00\n"
        ),
    )
    .unwrap();
    let config = toml.to_string_lossy();
    let args = [
        script,
        "--config",
        &config,
        "--runs",
        runs,
        "--jobs",
        jobs,
        "--for",
        "10s",
        "--seed",
        "1",
        "--no-faults",
    ];
    verify_json(&args, &dir.join("out"))
}

/// The planted-bug variants: (file, the invariant that catches them, fewest events needed).
const PLANTED: &[(&str, &str, usize)] = &[
    (
        "tests/verify/interlock_guard_mask.rhai",
        "power only with all guards closed and no stop pressed",
        3,
    ),
    (
        "tests/verify/interlock_trusts_a_lost_panel.rhai",
        "power only with all guards closed and no stop pressed",
        3,
    ),
    (
        "tests/verify/rotary_reset_keeps_count.rhai",
        "the relay follows the knob, one position per detent",
        2,
    ),
    (
        "tests/verify/counter_ack_keeps_waiting.rhai",
        "the lamp is lit exactly while a batch waits for acknowledgement",
        2,
    ),
    (
        "tests/verify/two_hand_counts_scans_as_time.rhai",
        "the press starts only with both hands within half a second",
        3,
    ),
    (
        "tests/verify/lubrication_trusts_the_wall_clock.rhai",
        "the pump rests 30 s between runs",
        1,
    ),
    (
        "tests/verify/tool_life_steps_over_the_limit.rhai",
        "the press is enabled only while the tool has strokes left",
        1,
    ),
    (
        "tests/verify/batch_tally_takes_the_threshold_as_a_period.rhai",
        "a box tallied for every full batch",
        1,
    ),
];

/// The seeds the planted bugs are searched with here, one a bug in turn (every bug at seeds
/// 1-20 is the benchmark's: `sh benches/verify_seeds.sh`, docs/benchmarks.md). Not 1: since idle devices are asked every quarter of
/// the grace time, the two-hand bug's search takes another course with it and misses in 120
/// runs (found with 18 of seeds 1-20 against 16 before).
const SEEDS: [&str; 2] = ["2", "3"];

#[test]
fn each_planted_bug_is_found_shrunk_and_its_written_test_reproduces() {
    // verify itself runs the written test before it says "reproduce:"; here `rigscript test`
    // runs it again, as a person would, for each planted bug. Two searches at a time
    // (each verify has two jobs): more at once starve each other's shrinking, whose budget is
    // partly wall-clock time.
    let queue: Vec<_> = PLANTED
        .iter()
        .zip(SEEDS.iter().cycle())
        .map(|(p, seed)| (*p, *seed))
        .collect();
    let queue = std::sync::Mutex::new(queue);
    let failures = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..2 {
            scope.spawn(|| loop {
                let next = queue.lock().unwrap().pop();
                let Some(((file, invariant, fewest), seed)) = next else {
                    break;
                };
                if let Err(e) = planted_bug_is_found(file, invariant, fewest, seed) {
                    failures.lock().unwrap().push(e);
                }
            });
        }
    });
    let failures = failures.into_inner().unwrap();
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}

/// Searches `file` with `seed`: found, shrunk to `fewest` to 6 events, told as a story, its
/// written test reproduced by verify and failing under `rigscript test` with the invariant.
fn planted_bug_is_found(
    file: &str,
    invariant: &str,
    fewest: usize,
    seed: &str,
) -> Result<(), String> {
    let out = TempDir::new("verify-planted");
    let (status, doc) = verify_json(&[file, "--runs", "120", "--seed", seed], &out);
    let what = format!("{file} seed {seed}");
    let check = |ok: bool, msg: String| {
        if ok {
            Ok(())
        } else {
            Err(format!("{what}: {msg}"))
        }
    };
    check(status == 1, format!("status {status}: {doc:#}"))?;
    let c = &doc["counterexample"];
    check(c["name"] == *invariant, format!("{c:#}"))?;
    let events = c["events"].as_array().map_or(0, Vec::len);
    check(
        (fewest..=6).contains(&events),
        format!("shrunk to {events} events: {c:#}"),
    )?;
    check(
        c["story"].as_str().unwrap_or("").contains(" → invariant "),
        format!("{c:#}"),
    )?;
    check(c["reproduced"] == true, format!("{c:#}"))?;
    check(c["candidates_not_reproduced"] == 0, format!("{c:#}"))?;
    let test = c["test_file"].as_str().unwrap_or_default();
    let o = run(&["test", test]);
    let stdout = stdout(&o);
    check(
        o.status.code() == Some(1),
        format!("the test must fail: {stdout}"),
    )?;
    check(
        stdout.contains(&format!("invariant {invariant:?} is false")),
        stdout.clone(),
    )?;
    Ok(())
}

#[test]
fn the_five_scripts_keep_their_invariants_under_a_bounded_search() {
    for script in [
        "interlock",
        "rotary_relay",
        "counter_threshold",
        "safe_values",
        "cron_rig",
    ] {
        let out = TempDir::new("verify-scripts");
        let path = format!("scripts/{script}.rhai");
        let (status, doc) = verify_json(
            &[&path, "--runs", "16", "--for", "20s", "--seed", "11"],
            &out,
        );
        assert_eq!(status, 0, "{script}: {doc:#}");
        assert_eq!(doc["result"], "pass");
        assert_eq!(doc["runs"], 16);
        let handlers = doc["coverage"]["handlers"].as_object().unwrap();
        assert!(
            handlers.values().any(|n| n.as_u64().unwrap() > 0),
            "{script}: {handlers:?}"
        );
        assert!(
            !doc["coverage"]["invariants"]
                .as_object()
                .unwrap()
                .is_empty(),
            "{script} states its invariants"
        );
        assert!(
            !out.exists() || std::fs::read_dir(&out).unwrap().next().is_none(),
            "nothing written on a pass"
        );
    }
}

#[test]
fn the_same_seed_gives_the_same_counterexample_whatever_the_jobs() {
    let out = TempDir::new("verify-seed");
    let file = "tests/verify/interlock_guard_mask.rhai";
    // Seed 1 finds it early (run 6 today), after runs the two jobs split; seed 5 found it in
    // run 52 with 147 events to shrink: 40 s a search in a debug build for the same check.
    let (_, one) = verify_json(&[file, "--runs", "60", "--seed", "1", "--jobs", "1"], &out);
    let (_, two) = verify_json(&[file, "--runs", "60", "--seed", "1", "--jobs", "2"], &out);
    assert_eq!(one["seed"], 1);
    let strip = |d: &Value| {
        let c = &d["counterexample"];
        (c["run"].clone(), c["story"].clone(), c["events"].clone())
    };
    assert_eq!(strip(&one), strip(&two));
    assert!(one["counterexample"]["run"].as_u64().is_some());
}

#[test]
fn a_pass_reports_coverage_and_warns_of_what_was_never_exercised() {
    let (_dir, s) = script(
        "verify-coverage",
        "idle.rhai",
        r#"let panel = device("panel");
after("10m", || panel.relay = 1);
panel.on_press("S3", || {});
invariant("the relay stays at 0", || panel.relay == 0);
"#,
    );
    let o = run(&[
        "verify",
        &s,
        "--runs",
        "4",
        "--for",
        "5s",
        "--seed",
        "2",
        "--no-faults",
    ]);
    let stdout = stdout(&o);
    assert_eq!(o.status.code(), Some(0), "{stdout}{}", stderr(&o));
    assert!(stdout.contains("seed 2"), "{stdout}");
    assert!(
        stdout.contains("handler panel.on_press S3: fired"),
        "{stdout}"
    );
    assert!(
        stdout.contains("warning: handler after 10m never fired"),
        "{stdout}"
    );
    assert!(
        stdout.contains(
            "warning: invariant \"the relay stays at 0\": the values it reads never changed"
        ),
        "{stdout}"
    );
    assert!(stdout.contains("faults were off"), "{stdout}");
}

#[test]
fn a_device_fault_the_script_does_not_handle_is_a_finding() {
    let (dir, s) = script(
        "verify-fault",
        "careless.rhai",
        "let io = device(\"io\");\nevery(\"100ms\", || io.clear_counter(0));\n",
    );
    let out = dir.join("out");
    let (status, doc) = verify_json(&[&s, "--runs", "40", "--for", "10s", "--seed", "3"], &out);
    assert_eq!(status, 1, "{doc:#}");
    let c = &doc["counterexample"];
    assert_eq!(c["name"], "no script error", "{c:#}");
    assert!(
        c["detail"].as_str().unwrap().contains("careless.rhai:2:"),
        "{c:#}"
    );
    let o = run(&["test", c["test_file"].as_str().unwrap()]);
    let stdout = stdout(&o);
    assert_eq!(o.status.code(), Some(1), "{stdout}");
    assert!(stdout.contains("no script error"), "{stdout}");
    // Without faults the module always answers.
    let (status, doc) = verify_json(
        &[
            &s,
            "--runs",
            "4",
            "--for",
            "5s",
            "--seed",
            "3",
            "--no-faults",
        ],
        &out,
    );
    assert_eq!(status, 0, "{doc:#}");
}

#[test]
fn a_runaway_handler_is_a_finding_of_one_event() {
    let (dir, s) = script(
        "verify-budget",
        "runaway.rhai",
        "let io = device(\"io\");\nio.on_rise(5, || { loop {} });\n",
    );
    let (status, doc) = verify_json(
        &[
            &s, "--runs", "20", "--for", "10s", "--seed", "1", "--budget", "20000",
        ],
        &dir.join("out"),
    );
    assert_eq!(status, 1, "{doc:#}");
    let c = &doc["counterexample"];
    assert_eq!(c["name"], "no handler over its budget", "{c:#}");
    assert_eq!(c["events"].as_array().unwrap().len(), 1, "{c:#}");
}

#[test]
fn outputs_not_at_the_rigs_safe_value_at_the_end_are_a_finding() {
    // The script stores its own safe value, so the end of the run leaves 0xF0 where rig.toml
    // says 0x00.
    let (dir, s) = script(
        "verify-end",
        "weakens.rhai",
        "let io = device(\"io\");\nio.safe_value = 0xF0;\nevery(\"1s\", || {});\n",
    );
    let (status, doc) = verify_json(
        &[
            &s,
            "--runs",
            "1",
            "--for",
            "2s",
            "--seed",
            "1",
            "--no-faults",
        ],
        &dir.join("out"),
    );
    assert_eq!(status, 1, "{doc:#}");
    let c = &doc["counterexample"];
    assert_eq!(c["name"], "outputs safe after the run ends", "{c:#}");
    assert_eq!(c["detail"], "io outputs 0xf0, safe value 0x00", "{c:#}");
    let test = c["test_file"].as_str().unwrap();
    let written = std::fs::read_to_string(test).unwrap();
    assert!(written.contains("r.end();"), "{written}");
    let o = run(&["test", test]);
    assert_eq!(o.status.code(), Some(1), "{}", stdout(&o));
}

#[test]
fn a_script_that_cannot_run_or_a_bad_config_is_a_usage_error() {
    let (dir, s) = script("verify-usage", "bad.rhai", "let x = device(\"nope\");\n");
    let o = run(&["verify", &s, "--runs", "1"]);
    assert_eq!(o.status.code(), Some(2));
    let check = run(&["check", &s]);
    let problem = stdout(&check);
    let problem = problem.lines().next().unwrap();
    assert!(
        stderr(&o).contains(problem),
        "the same message as check ({problem}): {}",
        stderr(&o)
    );
    let toml = dir.join("rig.toml");
    std::fs::write(&toml, "period = \"fast\"\n").unwrap();
    let t = toml.to_string_lossy().into_owned();
    let o = run(&["verify", "scripts/interlock.rhai", "--config", &t]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("rig.toml"), "{}", stderr(&o));
    let o = run(&["verify", "scripts/interlock.rhai", "--runs", "0"]);
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn in_run_a_false_invariant_ends_the_run_with_1_and_the_safe_state_recorded() {
    let (dir, s) = script(
        "verify-run",
        "contradicts.rhai",
        "let io = device(\"io\");\nio.outputs = 3;\ninvariant(\"at most one output\", || io.outputs < 2);\nevery(\"1s\", || {});\n",
    );
    let records = dir.join("records.jsonl");
    let o = run(&[
        "run",
        &s,
        "--sim",
        "--for",
        "2s",
        "--records",
        &records.to_string_lossy(),
    ]);
    let stderr = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("invariant \"at most one output\" is false (stated at "),
        "{stderr}"
    );
    assert!(stderr.contains("io outputs 0x03"), "{stderr}");
    assert!(
        !stderr.contains("io: outputs 0x00 -> 0x03"),
        "never written: {stderr}"
    );
    let rec = std::fs::read_to_string(&records).unwrap();
    assert!(rec.contains("\"invariant_violated\""), "{rec}");
    assert!(rec.contains("\"at most one output\""), "{rec}");
}

#[test]
fn a_call_over_the_scripts_limits_is_a_finding_that_names_the_limit() {
    a_call_over_a_limit_is_a_finding(&[(
        "timers",
        "timers = 50",
        "for i in 0..10 { after(\"1h\", || {}); }".to_string(),
        "no script error",
        "--max-timers",
    )]);
}

#[test]
fn a_memory_limit_finding_its_written_test_does_not_reproduce_is_told_as_a_defect_of_verify() {
    // Open: a finding over `[limits] memory` does not fail its written test under `rigscript
    // test` yet. What must hold meanwhile: no "reproduce:" that passes, but verify's own defect.
    let big = "let big = \"0123456789abcdef\"; for i in 0..11 { big += big; }";
    let (dir, s) = script(
        "verify-limit-memory",
        "grows.rhai",
        &format!(
            "let io = device(\"io\");\nevery(\"100ms\", || {{ {big} for i in 0..50 {{ let a = big + i; after(\"1h\", || a.len()); }} }});\n"
        ),
    );
    let (status, doc) = verify_limited(&dir, &s, "memory = \"32MiB\"", "2", "1");
    let text = doc.to_string();
    match status {
        // Reproduced after all: the finding names the limit, as the other limits' do.
        1 => assert!(text.contains("--memory-limit"), "{doc:#}"),
        70 => assert!(
            text.contains("defect of verify") || text.contains("\"reproduced\":false"),
            "{doc:#}"
        ),
        other => panic!("status {other}: {doc:#}"),
    }
}

/// (what, [limits] in rig.toml, the handler, the check, what the detail says)
fn a_call_over_a_limit_is_a_finding(cases: &[(&str, &str, String, &str, &str)]) {
    for (what, limit, body, check, says) in cases {
        let (dir, s) = script(
            &format!("verify-limit-{what}"),
            "grows.rhai",
            &format!("let io = device(\"io\");\nevery(\"100ms\", || {{ {body} }});\n"),
        );
        let (status, doc) = verify_limited(&dir, &s, limit, "2", "1");
        assert_eq!(status, 1, "{what}: {doc:#}");
        let c = &doc["counterexample"];
        assert_eq!(c["name"], *check, "{what}: {c:#}");
        let detail = c.to_string();
        assert!(detail.contains("grows.rhai:2:"), "{what}: placed: {c:#}");
        assert!(detail.contains(says), "{what}: {c:#}");
    }
}

#[test]
fn runs_played_at_once_are_each_held_to_their_own_memory_limit() {
    // Each run keeps about 19 MB in timers that never fire: within its 32 MiB alone, over it
    // only if two runs played at once were counted together (as when the limit was the
    // process's, a false finding against whichever run was checked).
    let (dir, s) = script(
        "verify-memory-jobs",
        "holds.rhai",
        "let io = device(\"io\");\nlet base = \"x\";\nbase.pad(60000, \"x\");\n\
         for i in 0..200 {\n  let t = base + i;\n  after(\"1h\", || t.len());\n}\n\
         every(\"100ms\", || { let n = io.inputs; });\n",
    );
    let (status, doc) = verify_limited(&dir, &s, "memory = \"32MiB\"", "40", "2");
    assert_eq!(status, 0, "{doc:#}");
}

#[test]
fn a_bug_behind_a_long_timer_or_a_count_of_hundreds_is_found_at_the_defaults() {
    // (file, invariant, what stretched the runs, seed). One seed each keeps the test short (a
    // replay of the timer's bug plays 75 s of ticks); `cargo bench --bench verify search`
    // tries seeds 1-15.
    let cases = [
        (
            "tests/verify/cure_cycle_end_leaves_heater_on.rhai",
            "the door unlocks only with the heater off",
            Some("its 1m15s timer"),
            "3",
        ),
        (
            "tests/verify/tool_life_misses_the_last_stroke.rhai",
            "the press is enabled only while the tool has strokes left",
            None,
            "1",
        ),
    ];
    for (file, invariant, stretched, seed) in cases {
        let out = TempDir::new("verify-defaults");
        let (status, doc) = verify_json(&[file, "--seed", seed], &out);
        assert_eq!(status, 1, "{file}: {doc:#}");
        assert_eq!(doc["run_for_stretched_for"].as_str(), stretched, "{doc:#}");
        let c = &doc["counterexample"];
        assert_eq!(c["name"], invariant, "{file}: {c:#}");
        assert_eq!(c["reproduced"], true, "{file}: {c:#}");
        let test = c["test_file"].as_str().expect("a test file");
        let o = run(&["test", test]);
        let stdout = stdout(&o);
        assert_eq!(o.status.code(), Some(1), "{file}: {stdout}");
        assert!(
            stdout.contains(&format!("invariant {invariant:?} is false")),
            "{file}: {stdout}"
        );
    }
}

#[test]
fn a_count_reached_through_bounced_edges_shrinks_to_the_count_alone() {
    // Seed 12 finds the tool-life bug with a count carried to 296 and four bounced edges of
    // DI0 at the same instant: no edge can go alone, so shrinking left 8 events until the
    // edges were folded into the count.
    let out = TempDir::new("verify-fold");
    let file = "tests/verify/tool_life_misses_the_last_stroke.rhai";
    let (status, doc) = verify_json(&[file, "--seed", "12"], &out);
    assert_eq!(status, 1, "{doc:#}");
    let c = &doc["counterexample"];
    assert_eq!(c["reproduced"], true, "{c:#}");
    let events = c["events"].as_array().map_or(0, Vec::len);
    assert_eq!(events, 1, "{c:#}");
}

#[test]
fn ctrl_c_prints_the_summary_so_far_with_the_seed_and_ends_with_130() {
    use std::io::{BufRead, BufReader};
    use std::process::Stdio;
    let (dir, s) = script(
        "verify-interrupt",
        "idle.rhai",
        "let io = device(\"io\");\nevery(\"20ms\", || io.inputs);\n",
    );
    let mut child = Command::new(rigscript())
        .args([
            "verify", &s, "--runs", "1000000", "--for", "5s", "--seed", "5",
        ])
        .args(["--no-faults", "--out", &dir.join("out").to_string_lossy()])
        .stdout(Stdio::piped())
        .spawn()
        .expect("run rigscript");
    let mut stdout = BufReader::new(child.stdout.take().unwrap());
    let mut first = String::new();
    stdout.read_line(&mut first).unwrap();
    // The first line comes once the signals are watched.
    assert!(first.contains("seed 5"), "{first}");
    let sent = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut stdout, &mut rest).unwrap();
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130), "{rest}");
    assert!(rest.contains("interrupted: "), "{rest}");
    assert!(rest.contains("no counterexample in "), "{rest}");
    assert!(rest.contains("; seed 5"), "{rest}");
    assert!(
        rest.contains(&format!(
            "to repeat these runs: rigscript verify {s} --seed 5 --for 5s"
        )),
        "{rest}"
    );
}

#[test]
fn verify_and_the_test_it_writes_never_write_the_rigs_records_file() {
    // rig.toml names a records file (and a broker no one listens on): virtual-time runs must
    // leave both alone, whatever the script records.
    let (dir, s) = script(
        "verify-records",
        "weakens.rhai",
        "let io = device(\"io\");\nio.safe_value = 0xF0;\nevery(\"1s\", || record(\"tick\", 1));\n",
    );
    let records = dir.join("production.jsonl");
    let toml = dir.join("rig.toml");
    std::fs::write(
        &toml,
        format!(
            "records = \"{}\"\n\n[mqtt]\nurl = \"mqtt://127.0.0.1:9\"\noutbox = \"{}\"\n\n\
             [devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\nsafe_value = 0x00\n",
            records.display(),
            dir.join("outbox").display()
        ),
    )
    .unwrap();
    let config = toml.to_string_lossy().into_owned();
    let (status, doc) = verify_json(
        &[
            &s,
            "--config",
            &config,
            "--runs",
            "2",
            "--for",
            "3s",
            "--seed",
            "1",
            "--no-faults",
        ],
        &dir.join("out"),
    );
    assert_eq!(status, 1, "{doc:#}");
    let test = doc["counterexample"]["test_file"].as_str().unwrap();
    assert!(
        std::fs::read_to_string(test).unwrap().contains("rig.toml"),
        "the written test runs on rig.toml's rig"
    );
    let o = run(&["test", test]);
    assert_eq!(o.status.code(), Some(1), "{}", stdout(&o));
    assert!(
        !records.exists(),
        "a virtual-time run wrote the rig's records file: {}",
        std::fs::read_to_string(&records).unwrap_or_default()
    );
    assert!(!dir.join("outbox").exists(), "nor may it open the outbox");
}
