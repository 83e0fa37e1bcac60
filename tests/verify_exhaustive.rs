//! `rigscript verify --exhaustive` as people run it: the five scripts proved to a stated depth
//! ("no violation in any sequence of up to K events (N states)"), and planted bugs found with a
//! shortest counterexample no longer than the random search's shrunk one (tests/verify), the
//! same on two runs, written as a test that `rigscript test` fails with the invariant. (The
//! interlock's lost-panel bug needs depth 3 with faults: its debug-build cost is left to
//! `cargo bench --bench verify exhaustive`.)

use crate::common::{rigscript, stdout, TempDir};
use serde_json::Value;
use std::process::Command;

/// `rigscript verify FILE --exhaustive --depth D ARGS.. --json --out OUT`: status, document.
fn explore(file: &str, depth: &str, extra: &[&str], out: &TempDir) -> (i32, Value) {
    let out_dir = out.to_string_lossy().into_owned();
    let mut args = vec!["verify", file, "--exhaustive", "--depth", depth, "--json"];
    args.extend_from_slice(extra);
    args.extend_from_slice(&["--out", &out_dir]);
    let o = Command::new(rigscript())
        .args(&args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("run rigscript");
    let doc = serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("{e}: {}", stdout(&o)));
    (o.status.code().unwrap_or(-1), doc)
}

#[test]
fn the_five_scripts_have_no_violation_in_any_sequence_up_to_a_stated_depth() {
    for (script, depth) in [
        ("interlock", "2"),
        ("rotary_relay", "3"),
        ("counter_threshold", "2"),
        ("safe_values", "2"),
        ("cron_rig", "2"),
    ] {
        let out = TempDir::new("verify-exhaustive");
        let (status, doc) = explore(&format!("scripts/{script}.rhai"), depth, &[], &out);
        assert_eq!(status, 0, "{script}: {doc:#}");
        let states = doc["states"].as_u64().unwrap();
        assert!(states > 1, "{script}: {doc:#}");
        assert_eq!(
            doc["line"],
            format!("no violation in any sequence of up to {depth} events ({states} states)")
        );
        assert!(!doc["abstracted"].as_array().unwrap().is_empty());
    }
}

/// (file, invariant, depth to explore, the most events its counterexample may have: the random
/// search's shortest shrink, unless that takes a value the exhaustive mode cuts away, extra
/// arguments).
const PLANTED: &[(&str, &str, &str, usize, &[&str])] = &[
    (
        "tests/verify/interlock_guard_mask.rhai",
        "power only with all guards closed and no stop pressed",
        "3",
        3,
        &["--no-faults"],
    ),
    (
        "tests/verify/rotary_reset_keeps_count.rhai",
        "the relay follows the knob, one position per detent",
        "3",
        2,
        &[],
    ),
    (
        "tests/verify/counter_ack_keeps_waiting.rhai",
        "the lamp is lit exactly while a batch waits for acknowledgement",
        "3",
        2,
        &[],
    ),
    (
        "tests/verify/two_hand_counts_scans_as_time.rhai",
        "the press starts only with both hands within half a second",
        "3",
        3,
        &[],
    ),
    (
        "tests/verify/lubrication_trusts_the_wall_clock.rhai",
        "the pump rests 30 s between runs",
        "4",
        1,
        &[],
    ),
    (
        "tests/verify/tool_life_steps_over_the_limit.rhai",
        "the press is enabled only while the tool has strokes left",
        "2",
        1,
        &[],
    ),
    (
        "tests/verify/tool_life_misses_the_last_stroke.rhai",
        "the press is enabled only while the tool has strokes left",
        "2",
        1,
        &[],
    ),
    (
        "tests/verify/cure_cycle_end_leaves_heater_on.rhai",
        "the door unlocks only with the heater off",
        "2",
        1,
        &[],
    ),
    (
        "tests/verify/batch_tally_takes_the_threshold_as_a_period.rhai",
        "a box tallied for every full batch",
        "2",
        // The search shrinks it to one event (the count carried to 65535, or 121 pulses); here
        // counts are cut to 49-51, so reaching 100 takes two.
        2,
        &[],
    ),
];

#[test]
fn each_planted_bug_is_found_shortest_the_same_twice_and_its_test_fails() {
    for (file, invariant, depth, most_events, extra) in PLANTED {
        let out = TempDir::new("verify-exhaustive-planted");
        let (status, one) = explore(file, depth, extra, &out);
        let (_, two) = explore(file, depth, extra, &out);
        assert_eq!(status, 1, "{file}: {one:#}");
        let c = &one["counterexample"];
        assert_eq!(c["name"], *invariant, "{file}: {c:#}");
        assert_eq!(c["choices"], two["counterexample"]["choices"], "{file}");
        assert_eq!(c["story"], two["counterexample"]["story"], "{file}");
        assert_eq!(one["states"], two["states"], "{file}");
        let events = c["events"].as_array().unwrap().len();
        assert!(events <= *most_events, "{file}: {events} events: {c:#}");
        assert_eq!(c["reproduced"], true, "{file}: {c:#}");
        let test = c["test_file"].as_str().unwrap();
        let o = Command::new(rigscript())
            .args(["test", test])
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(1), "{file}: {}", stdout(&o));
        assert!(
            stdout(&o).contains(&format!("invariant {invariant:?} is false")),
            "{file}: {}",
            stdout(&o)
        );
    }
}

#[test]
fn a_depth_without_exhaustive_and_a_seed_with_it_are_usage_errors() {
    for args in [
        &["verify", "scripts/interlock.rhai", "--depth", "2"][..],
        &[
            "verify",
            "scripts/interlock.rhai",
            "--exhaustive",
            "--seed",
            "1",
        ][..],
    ] {
        let o = Command::new(rigscript())
            .args(args)
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "{args:?}");
    }
}
