//! What a reload costs the scan loop: the wall time of the swap the loop does at a tick
//! boundary (the text compiled again, the new top level run, the variables carried, the old
//! setup dropped), for each script in scripts/ on the in-memory simulators, swapped for itself.
//! Reading the file, `check` and the scenario tests happen off the loop and are not counted.
//! Target: at most 2 periods at 20 ms (40 ms) of pause, the tick's own work included.
//!
//! Run: `cargo bench --bench reload` (a filter argument picks scripts by name).

#[path = "common/args.rs"]
mod args;
use args::BenchArgs;
use rigscript::config::RigConfig;
use rigscript::RigBuilder;
use std::time::{Duration, Instant};

/// Reloads measured per script (`--bench`: in full; else a smoke run).
const RELOADS: (u32, u32) = (10, 100);

fn main() {
    let args = BenchArgs::from_env();
    let reloads = if args.full { RELOADS.1 } else { RELOADS.0 };
    println!("reload: wall time of the swap on the loop, {reloads} reloads each (target <= 40 ms)");
    for file in [
        "rotary_relay.rhai",
        "counter_threshold.rhai",
        "interlock.rhai",
        "safe_values.rhai",
        "cron_rig.rhai",
    ] {
        if !args.picks(file) {
            continue;
        }
        let path = format!("{}/scripts/{file}", env!("CARGO_MANIFEST_DIR"));
        let source = std::fs::read_to_string(&path).expect("a script of scripts/");
        let mut rig = RigBuilder::from_config(RigConfig::simulated_default())
            .simulated()
            .virtual_time_from(chrono::Utc::now())
            .log_to_stderr(false)
            .start(&source, file)
            .expect("the script starts");
        rig.runner.advance(Duration::from_secs(1));
        let mut worst = Duration::ZERO;
        let mut total = Duration::ZERO;
        for _ in 0..reloads {
            let start = Instant::now();
            rig.runner
                .reload(&source, file, "bench")
                .expect("the script reloads");
            let took = start.elapsed();
            worst = worst.max(took);
            total += took;
            rig.runner.advance(Duration::from_millis(100));
        }
        println!(
            "  {file:24} mean {:7.3} ms, worst {:7.3} ms",
            total.as_secs_f64() * 1e3 / f64::from(reloads),
            worst.as_secs_f64() * 1e3
        );
    }
}
