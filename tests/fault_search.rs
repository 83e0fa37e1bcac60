//! The fault search: a property-based test of the runner itself. proptest makes cases (a
//! rig.toml, a script from a grammar of the script API, and a schedule of faults), each case
//! runs as `rigscript run` would (`rig::start_with` and `Runner::run`) in virtual time, with the
//! real drivers talking to simulated TRP-C29U modules through fault-injecting links, and the
//! oracle judges it from the modules' own output history (see `fault_search/oracle.rs` for the
//! rules). A failing case shrinks to a minimal one, printed with its rig.toml and script.
//!
//! Every kind of broken promise is shrunk on its own, from the first case that shows it, so one
//! run reports each defect it finds with its own minimal case.
//!
//! Environment: `FAULT_SEARCH_CASES` (default 24), `FAULT_SEARCH_SEED` (default 8; the search
//! is deterministic for a given seed and count), `FAULT_SEARCH_SHRINK` (shrink runs per kind,
//! default 300), `FAULT_SEARCH_MEMORY_MB` (heap growth that counts as unbounded, default 512).
//! The soak (README "Fault search"):
//! `FAULT_SEARCH_CASES=20000 FAULT_SEARCH_SEED=$RANDOM cargo test --release --test fault_search`.

#[path = "fault_search/case.rs"]
mod case;
#[path = "fault_search/harness.rs"]
mod harness;
#[path = "fault_search/oracle.rs"]
mod oracle;
#[path = "fault_search/probe.rs"]
mod probe;
#[path = "fault_search/render.rs"]
mod render;

use case::{Case, Fault, Module, Policy, Proto, Rig, Stmt};
use proptest::strategy::{Strategy, ValueTree};
use proptest::test_runner::{Config, RngSeed, TestRng, TestRunner};
use std::collections::BTreeMap;

#[global_allocator]
static HEAP: probe::Counting = probe::Counting;

fn env<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// The violations of `case`, with the run that showed them.
fn violations(case: &Case) -> (Vec<oracle::Violation>, harness::Run) {
    let run = harness::run(case);
    (oracle::check(case, &run), run)
}

/// `case` as files, its faults, and what the run did, for a failure message.
fn describe(case: &Case, run: &harness::Run) -> String {
    let faults: Vec<String> = case
        .faults
        .iter()
        .map(|(t, f)| format!("  at {t} ms: {f:?}"))
        .collect();
    let panics: Vec<String> = run.panics.iter().map(|p| format!("  {p}")).collect();
    let end = match &run.end {
        harness::End::Ran { status, log, .. } => {
            format!("exit status {status}; log:\n{}", log.join("\n"))
        }
        harness::End::ConfigRefused(why) => format!("rig.toml refused: {why}"),
        other => format!("{other:?}"),
    };
    format!(
        "--- rig.toml\n{}--- case.rhai\n{}--- faults\n{}\n--- panics\n{}\n--- run\n{end}",
        render::rig_toml(case),
        render::script(case),
        faults.join("\n"),
        panics.join("\n"),
    )
}

fn assert_keeps_promises(case: &Case) {
    let (found, run) = violations(case);
    let found: Vec<String> = found.iter().map(ToString::to_string).collect();
    assert!(
        found.is_empty(),
        "{}\n{}",
        found.join("\n"),
        describe(case, &run)
    );
}

/// Shrinks the case in `tree` (which shows a violation of `kind`) to the simplest one that
/// still does, in at most `steps` runs: proptest's simplify/complicate walk.
fn shrink(tree: &mut impl ValueTree<Value = Case>, kind: &str, steps: u32) -> Case {
    let fails = |c: &Case| violations(c).0.iter().any(|v| v.kind == kind);
    let mut best = tree.current();
    if !tree.simplify() {
        return best;
    }
    for _ in 0..steps {
        let candidate = tree.current();
        let more = if fails(&candidate) {
            best = candidate;
            tree.simplify()
        } else {
            tree.complicate()
        };
        if !more {
            break;
        }
    }
    best
}

/// What the search found of one kind: how many cases showed it and the simplest.
struct Finding {
    cases: u32,
    first: u32,
    minimal: Case,
}

#[test]
fn the_runner_keeps_its_promises_under_generated_faults() {
    let cases: u32 = env("FAULT_SEARCH_CASES", 24);
    let seed: u64 = env("FAULT_SEARCH_SEED", 8);
    let steps: u32 = env("FAULT_SEARCH_SHRINK", 300);
    let config = Config {
        rng_seed: RngSeed::Fixed(seed),
        failure_persistence: None,
        ..Config::default()
    };
    let mut runner = TestRunner::new(config.clone());
    let strategy = case::cases();
    // The same RNG state makes the same tree again: each kind shrinks from the original case.
    let tree_from = |rng: TestRng| {
        strategy
            .new_tree(&mut TestRunner::new_with_rng(config.clone(), rng))
            .unwrap_or_else(|e| panic!("fault search: cannot make a case: {e}"))
    };
    let mut found: BTreeMap<&'static str, Finding> = BTreeMap::new();
    let mut refused = 0u32;
    for n in 0..cases {
        let rng = runner.rng().clone();
        let case = tree_from(rng.clone()).current();
        // Move the main RNG on as making the case did.
        let _ = strategy.new_tree(&mut runner);
        let (kinds, run) = violations(&case);
        refused += u32::from(matches!(run.end, harness::End::ConfigRefused(_)));
        let mut kinds: Vec<&'static str> = kinds.iter().map(|v| v.kind).collect();
        kinds.sort_unstable();
        kinds.dedup();
        for kind in kinds {
            if let Some(f) = found.get_mut(kind) {
                f.cases += 1;
                continue;
            }
            let minimal = shrink(&mut tree_from(rng.clone()), kind, steps);
            found.insert(
                kind,
                Finding {
                    cases: 1,
                    first: n,
                    minimal,
                },
            );
        }
    }
    if found.is_empty() {
        return;
    }
    let mut report = format!(
        "fault search: FAULT_SEARCH_SEED={seed} FAULT_SEARCH_CASES={cases} ({refused} rig.toml \
         refused): {} kind(s) of broken promise\n",
        found.len()
    );
    for (kind, f) in &found {
        let (violations, run) = violations(&f.minimal);
        let shown: Vec<String> = violations
            .iter()
            .filter(|v| v.kind == *kind)
            .map(ToString::to_string)
            .collect();
        report.push_str(&format!(
            "\n===== {kind}: in {} of {cases} cases (first: case {}); minimal case:\n{:?}\n{}\n{}\n",
            f.cases,
            f.first,
            f.minimal,
            shown.join("\n"),
            describe(&f.minimal, &run)
        ));
    }
    panic!("{report}");
}

// ---- the search's own footing: a case without faults passes, and each kind of fault is
// ---- seen by the oracle where it must be.

fn module(protocol: Proto) -> Module {
    Module {
        protocol,
        line: 0,
        id: 1,
        timeout_ms: 100,
        retries: 2,
        watchdog_tenths: Some(10),
        safe: 0x05,
        power_on: None,
        fresh: false,
    }
}

fn rig(period_ms: u64, modules: Vec<Module>) -> Rig {
    Rig {
        period_ms,
        policy: Policy::Stop,
        grace_ms: 1000,
        run_for_ms: 10_000,
        budget: 200_000,
        modules,
    }
}

fn toggling() -> Vec<Stmt> {
    vec![
        Stmt::Every {
            ms: 300,
            body: vec![Stmt::Set {
                dev: 0,
                value: 0x30,
            }],
        },
        Stmt::Every {
            ms: 700,
            body: vec![
                Stmt::Set {
                    dev: 0,
                    value: 0x41,
                },
                Stmt::RecordInputs { dev: 0 },
            ],
        },
        Stmt::OnRise {
            dev: 0,
            ch: 1,
            body: vec![Stmt::Set {
                dev: 0,
                value: 0x52,
            }],
        },
    ]
}

#[test]
fn a_run_with_recoverable_faults_keeps_every_promise() {
    for protocol in [Proto::Modbus, Proto::Ascii] {
        assert_keeps_promises(&Case {
            rig: rig(20, vec![module(protocol)]),
            script: toggling(),
            faults: vec![
                (
                    500,
                    Fault::Input {
                        dev: 0,
                        value: 0x02,
                    },
                ),
                (
                    1200,
                    Fault::Drop {
                        line: 0,
                        answers: 1,
                    },
                ),
                (
                    2000,
                    Fault::Garble {
                        line: 0,
                        at: 3,
                        xor: 0x10,
                    },
                ),
                (2600, Fault::Silence { line: 0, ms: 3000 }),
                (
                    7000,
                    Fault::Input {
                        dev: 0,
                        value: 0x00,
                    },
                ),
                (8000, Fault::Sigterm),
            ],
        });
    }
}

#[test]
fn a_killed_runner_leaves_the_module_to_its_watchdog() {
    let case = Case {
        rig: rig(20, vec![module(Proto::Modbus)]),
        script: toggling(),
        faults: vec![(2000, Fault::Kill)],
    };
    let run = harness::run(&case);
    assert_eq!(run.killed_at, Some(std::time::Duration::from_secs(2)));
    assert_eq!(
        run.at_end[0].outputs, 0x30,
        "still the script's at the kill"
    );
    assert_eq!(
        run.after_wait[0].outputs, 0x05,
        "the module's watchdog acted"
    );
    assert_eq!(oracle::check(&case, &run), []);
}

#[test]
fn the_oracle_sees_a_stored_safe_value_the_script_changed() {
    let case = Case {
        rig: rig(20, vec![module(Proto::Modbus)]),
        script: vec![
            Stmt::SafeValue {
                dev: 0,
                value: 0xC3,
            },
            Stmt::Every {
                ms: 100,
                body: vec![Stmt::Set {
                    dev: 0,
                    value: 0x30,
                }],
            },
        ],
        faults: vec![(1000, Fault::Kill)],
    };
    let run = harness::run(&case);
    let kinds: Vec<&str> = oracle::check(&case, &run).iter().map(|v| v.kind).collect();
    // Today the script may store its own safe value; whether the runner refuses that (issue 8,
    // defect 5) or not, the module's own watchdog must not drive it.
    if run.after_wait[0].outputs != 0x05 {
        assert!(kinds.contains(&"not-safe-after-end"), "{kinds:?}");
        assert!(kinds.contains(&"unsafe-safe-value"), "{kinds:?}");
    } else {
        assert_eq!(kinds, Vec::<&str>::new());
    }
}
