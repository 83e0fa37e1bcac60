//! The journal's targets, measured on a 20 ms rig (`scripts/interlock.rhai` on the simulators,
//! its `every("20ms")` reading the guards every tick) whose DI byte changes once a second:
//! - size: a day of it journaled in 20 MB or less (the lines the journal's tally makes of
//!   the run's events, as its writer writes them, header included);
//! - replay: that day replayed at 1000 times real time or faster (86.4 s or less).
//!
//! The run is tallied on the loop's own thread here (the writer's thread would fall behind a
//! run in virtual time and lose events); what is written is the same. The loop's cost of a
//! journal is benches/tick_instructions.sh's (JOURNAL=1).
//!
//! Run: `cargo bench --bench journal` (a day); `cargo test --all-targets` runs two minutes.

#[path = "common/args.rs"]
mod args;
use args::BenchArgs;
use rigscript::config::RigConfig;
use rigscript::heap::CountingAlloc;
use rigscript::journal::replay::{replay, Options};
use rigscript::journal::tally::{Tally, KINDS};
use rigscript::journal::{read_journal, Header, MAGIC, VERSION};
use rigscript::runtime::observe::{Bound, Kinds, Next};
use rigscript::time::clock::{Clock, VirtualClock};
use rigscript::RigBuilder;
use std::io::Write;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

#[global_allocator]
static HEAP: CountingAlloc = CountingAlloc;

fn main() {
    let args = BenchArgs::from_env();
    let length = if args.full {
        Duration::from_secs(86_400)
    } else {
        Duration::from_secs(120)
    };
    let file = "scripts/interlock.rhai";
    let path = format!("{}/{file}", env!("CARGO_MANIFEST_DIR"));
    let source = std::fs::read_to_string(&path).expect("the script");
    let config = RigConfig::simulated_default();
    let mut header = Header::first(file, &source, None, &config, config.period, None).unwrap();
    header.zone = "UTC".into();
    let dir = std::env::temp_dir().join(format!("rigscript-journal-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let journal = dir.join("day.journal");
    let mut out = std::io::BufWriter::new(std::fs::File::create(&journal).unwrap());
    write!(
        out,
        "{MAGIC} {VERSION}\nH {}\n",
        serde_json::to_string(&header).unwrap()
    )
    .unwrap();
    let sub = Arc::new(Mutex::new(None));
    let slot = Arc::clone(&sub);
    let clock = VirtualClock::new(
        chrono::DateTime::parse_from_rfc3339("2026-03-28T00:00:00Z")
            .unwrap()
            .to_utc(),
    );
    let mut rig = RigBuilder::from_config(config)
        .simulated()
        .clock(Arc::new(clock.clone()))
        .log_to_stderr(false)
        .quiet()
        .attach(move |events| {
            *slot.lock().unwrap() = events
                .subscribe_to("journal", Bound::events(1 << 16), Kinds::of(&KINDS))
                .ok()
        })
        .start(&source, file)
        .expect("interlock starts");
    let mut sub = sub.lock().unwrap().take().unwrap();
    let mut tally = Tally::default();
    let mut lines = 0u64;
    let mut drain = |sub: &mut rigscript::runtime::observe::Subscription,
                     out: &mut std::io::BufWriter<std::fs::File>| {
        while let Ok(next) = sub.handover(Duration::ZERO) {
            let entry = match next {
                Next::Event(e) => tally.take(sub.tick(), &e),
                Next::Dropped(n) => Some(tally.gap(sub.tick(), n)),
                Next::Quiet => None,
            };
            if let Some(e) = entry {
                writeln!(out, "{}", e.line()).unwrap();
                lines += 1;
            }
        }
    };
    // Guards closed, S12 pressed to arm; then once a second DI4 (no guard: the bench stays
    // armed and reads its inputs every tick, so every change is journaled) goes on or off,
    // and every tenth second S12 is pressed or released.
    rig.sim.set_inputs("io", 0x0F).unwrap();
    rig.runner.advance(Duration::from_millis(100));
    rig.sim.set_switch("panel", "S12", true).unwrap();
    let mut second = 0u64;
    while clock.now() < length && rig.runner.status().is_none() {
        rig.runner.advance(Duration::from_secs(1));
        second += 1;
        let byte = if second % 2 == 0 { 0x0F } else { 0x1F };
        rig.sim.set_inputs("io", byte).unwrap();
        if second % 10 == 0 {
            rig.sim
                .set_switch("panel", "S12", second % 20 == 0)
                .unwrap();
        }
        drain(&mut sub, &mut out);
    }
    rig.runner.signal_stop();
    drain(&mut sub, &mut out);
    out.flush().unwrap();
    drop(out);
    let bytes = std::fs::metadata(&journal).unwrap().len();
    let hours = length.as_secs_f64() / 3600.0;
    println!(
        "journal: {:.1} h of a 20 ms rig, inputs changing once a second: {lines} lines, {:.2} MB \
         ({:.2} MB a day; target 20 MB)",
        hours,
        bytes as f64 / 1e6,
        bytes as f64 / 1e6 * 24.0 / hours
    );
    let j = read_journal(&journal).expect("the journal reads back");
    let began = Instant::now();
    let outcome = replay(&j, &Options::default()).expect("the journal replays");
    let took = began.elapsed();
    assert_eq!(outcome.divergence, None, "the replay is exact");
    println!(
        "replay: {} ticks in {:.2} s: {:.0} times real time (target 1000)",
        outcome.ticks,
        took.as_secs_f64(),
        length.as_secs_f64() / took.as_secs_f64()
    );
    // RIGSCRIPT_KEEP_JOURNAL=1 keeps it, to replay with another build (`rigscript replay`).
    if std::env::var_os("RIGSCRIPT_KEEP_JOURNAL").is_some() {
        println!("kept {}", journal.display());
    } else {
        let _ = std::fs::remove_dir_all(&dir);
    }
}
