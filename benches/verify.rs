//! `rigscript verify`'s targets, measured:
//! - throughput: 1000 runs of 60 s virtual at a 20 ms period (3M ticks) of
//!   `scripts/interlock.rhai`, faults on, one job per core (target: 60 s of wall time or less on
//!   a 2-core machine);
//! - search: how long it takes to find a planted bug that needs three events in order
//!   (`tests/verify/interlock_guard_mask.rhai`: guards closed, reset, guard DI3 opening; and
//!   `interlock_trusts_a_lost_panel.rhai`: guards closed, reset, the panel lost), over seeds
//!   1-15 (target: median 30 s or less), and how small shrinking makes the counterexample
//!   (target: 10 events or fewer).
//!
//! Run: `cargo bench --bench verify` (a filter argument, `throughput` or `search`, picks one).
//! `cargo test --all-targets` runs it at a tiny size, to check that it still works.

#[path = "common/args.rs"]
mod args;
use args::BenchArgs;
use rigscript::config::RigConfig;
use rigscript::heap::CountingAlloc;
use rigscript::script::engine::DEFAULT_BUDGET;
use rigscript::verify::exec::Target;
use rigscript::verify::facts::Facts;
use rigscript::verify::horizon::Horizon;
use rigscript::verify::{search, Options, SHRINK_BUDGET};
use std::time::{Duration, Instant};

// As the `rigscript` binary has it: the heap counted for the script's memory limit.
#[global_allocator]
static HEAP: CountingAlloc = CountingAlloc;

/// How much work the benchmark does.
struct Sizes {
    runs: u64,
    run_for: Duration,
    seeds: u64,
}

const FULL: Sizes = Sizes {
    runs: 1000,
    run_for: Duration::from_secs(60),
    seeds: 15,
};

const SMOKE: Sizes = Sizes {
    runs: 4,
    run_for: Duration::from_secs(2),
    seeds: 1,
};

fn target(file: &str, run_for: Duration) -> Target {
    let path = format!("{}/{file}", env!("CARGO_MANIFEST_DIR"));
    let source = std::fs::read_to_string(&path).expect("the script");
    Target {
        compared: rigscript::verify::facts::Facts::read(&source).compared,
        source,
        file: file.to_string(),
        script: path.clone().into(),
        config_file: None,
        config: RigConfig::simulated_default(),
        budget: DEFAULT_BUDGET,
        run_for,
    }
}

fn jobs() -> usize {
    std::thread::available_parallelism().map_or(1, usize::from)
}

fn throughput(sizes: &Sizes, faults: bool) {
    let t = target("scripts/interlock.rhai", sizes.run_for);
    let opts = Options {
        runs: sizes.runs,
        seed: 1,
        jobs: jobs(),
        faults,
        shrink: SHRINK_BUDGET,
        interrupt: None,
    };
    let began = Instant::now();
    let s = search(&t, &opts, |_| {}).expect("interlock runs on the simulated rig");
    let wall = began.elapsed();
    assert!(
        s.counterexample.is_none(),
        "interlock.rhai keeps its invariant"
    );
    // With faults, fewer ticks than 3M: a stop signal ends some runs early, and a tick that
    // waits out a lost device's timeout skips the ticks it overran.
    println!(
        "throughput: interlock.rhai, {} runs x {} s virtual, faults {}, {} job(s): {:.1} s \
         wall (target <= 60 s), {} ticks, {:.0} ticks/s, {} events ({} faults)",
        s.runs,
        sizes.run_for.as_secs(),
        if faults { "on" } else { "off" },
        opts.jobs,
        wall.as_secs_f64(),
        s.coverage.ticks,
        s.coverage.ticks as f64 / wall.as_secs_f64(),
        s.events,
        s.faults
    );
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

fn search_planted(sizes: &Sizes, file: &str) {
    // As `rigscript verify` has it without `--for`: as long as the script's timers need.
    let source = target(file, Duration::ZERO).source;
    let t = target(file, Horizon::of(&Facts::read(&source), None).run_for);
    let (mut found, mut shrunk, mut runs, mut shrink_s) = (Vec::new(), Vec::new(), 0, Vec::new());
    for seed in 1..=sizes.seeds {
        let opts = Options {
            runs: 1000,
            seed,
            jobs: jobs(),
            faults: true,
            shrink: SHRINK_BUDGET,
            interrupt: None,
        };
        let s = search(&t, &opts, |_| {}).expect("runs on the simulated rig");
        let c = s
            .counterexample
            .unwrap_or_else(|| panic!("{file}: seed {seed} found nothing in 1000 runs"));
        found.push(s.search_time.as_secs_f64());
        shrunk.push(c.events.len());
        shrink_s.push(c.shrink_time.as_secs_f64());
        runs += s.runs;
    }
    println!(
        "search: {file}, seeds 1-{}: found in median {:.2} s (max {:.2} s; target median <= \
         30 s), {:.1} runs on average; shrunk to at most {} events (target <= 10), \
         shrinking median {:.2} s",
        sizes.seeds,
        median(found.clone()),
        found.iter().copied().fold(0.0, f64::max),
        runs as f64 / sizes.seeds as f64,
        shrunk.iter().max().unwrap_or(&0),
        median(shrink_s)
    );
}

/// The exhaustive mode: interlock.rhai proved to `depth`, and each planted bug found.
fn exhaustive(depth: usize, planted: &[&str]) {
    use rigscript::verify::exhaustive::{explore, result_line, Options};
    let opts = |depth| Options {
        depth,
        jobs: jobs(),
        faults: true,
        interrupt: None,
    };
    let t = target("scripts/interlock.rhai", Duration::from_secs(60));
    let s = explore(&t, &opts(depth), |_, _| {}).expect("interlock runs");
    println!(
        "exhaustive: interlock.rhai: {} in {:.1} s ({} sequences, {} job(s); target depth >= 4 \
         within 60 s on 2 cores)",
        result_line(&s),
        s.time.as_secs_f64(),
        s.sequences,
        jobs()
    );
    for file in planted {
        let t = target(file, Duration::from_secs(60));
        let s = explore(&t, &opts(4), |_, _| {}).expect("runs");
        let f = s
            .found
            .as_ref()
            .unwrap_or_else(|| panic!("{file}: nothing found"));
        println!(
            "exhaustive: {file}: {} choice(s), {} event(s), {} states, {:.1} s",
            f.choices.len(),
            f.events.len(),
            s.states,
            s.time.as_secs_f64()
        );
    }
}

fn main() {
    let args = BenchArgs::from_env();
    let sizes = if args.full { &FULL } else { &SMOKE };
    let wanted = |name: &str| args.picks(name);
    if wanted("throughput") {
        throughput(sizes, true);
        throughput(sizes, false);
    }
    if wanted("exhaustive") {
        if args.full {
            exhaustive(
                4,
                &[
                    "tests/verify/interlock_guard_mask.rhai",
                    "tests/verify/interlock_trusts_a_lost_panel.rhai",
                    "tests/verify/rotary_reset_keeps_count.rhai",
                    "tests/verify/counter_ack_keeps_waiting.rhai",
                    "tests/verify/two_hand_counts_scans_as_time.rhai",
                    "tests/verify/lubrication_trusts_the_wall_clock.rhai",
                    "tests/verify/tool_life_steps_over_the_limit.rhai",
                    "tests/verify/tool_life_misses_the_last_stroke.rhai",
                    "tests/verify/cure_cycle_end_leaves_heater_on.rhai",
                    "tests/verify/batch_tally_takes_the_threshold_as_a_period.rhai",
                ],
            );
        } else {
            exhaustive(1, &["tests/verify/tool_life_misses_the_last_stroke.rhai"]);
        }
    }
    if wanted("search") {
        search_planted(sizes, "tests/verify/interlock_guard_mask.rhai");
        search_planted(sizes, "tests/verify/interlock_trusts_a_lost_panel.rhai");
        // A bug behind a 75 s timer and one at a count of 300: their smoke runs would cost the
        // test suite seconds of debug-build ticks.
        if args.full {
            search_planted(sizes, "tests/verify/cure_cycle_end_leaves_heater_on.rhai");
            search_planted(sizes, "tests/verify/tool_life_misses_the_last_stroke.rhai");
            search_planted(sizes, "tests/verify/tool_life_steps_over_the_limit.rhai");
        }
    }
}
