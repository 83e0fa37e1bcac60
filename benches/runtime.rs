//! The script runtime's costs, for each script in scripts/ on the in-memory simulators (`--sim`
//! devices: `panel`, a TRC1000, and `io`, a TRP-C29U): work per scan tick in virtual time with
//! the script's handlers active, scan-period jitter at a 10 ms period in real time, and the
//! wall time of a simulated day of `cron_rig.rhai`.
//!
//! The tail of the jitter on a virtual machine follows the time the host takes the virtual CPUs
//! away (steal time), which no process inside can prevent: each jitter line shows the steal
//! time during its run (from /proc/stat, Linux) to read it by, and each script's run follows a
//! run of a bare loop that only sleeps to the same 10 ms deadlines through the same clock: what
//! the machine itself allows at that moment, so the difference is what rigscript adds. Runs
//! hold the CPU wake-up latency request `rigscript run` holds at 10 ms (0 µs, when the process
//! may write /dev/cpu_dma_latency; the first jitter line says); the last line is interlock.rhai
//! without it.
//!
//! Many timers: work per tick with 20,000 and 150,000 `every` timers (one set that never fires
//! in the run, one spread over 1-2 s periods so that a share fires every tick), to show the
//! cost grows with the timers that fire, not with the timers there are.
//!
//! Run: `cargo bench --bench runtime` (a filter argument picks scripts by name; `timers` picks
//! the many-timer cases). CPU while
//! idling and resident memory of a real `rigscript run` process: `benches/process.sh`.

#[path = "common/args.rs"]
mod args;
use args::BenchArgs;
use rigscript::config::{RigConfig, ScriptLimits, WakeLatency};
use rigscript::runtime::devices::SimRig;
use rigscript::runtime::stats::Histogram;
use rigscript::runtime::wake_latency;
use rigscript::script::rig::Rig;
use rigscript::time::clock::{Clock, SharedClock, SystemClock, VirtualClock};
use rigscript::time::zone::Zone;
use rigscript::RigBuilder;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Counts the heap as `rigscript` does (its memory limit), so its cost is in the figures.
#[global_allocator]
static HEAP: rigscript::heap::CountingAlloc = rigscript::heap::CountingAlloc;

/// Where virtual wall time starts (as in the scenario tests).
const START: &str = "2026-03-28T00:00:30Z";

/// The scan period of the jitter runs.
const PERIOD: Duration = Duration::from_millis(10);

/// What the field side does before tick `n` so that the script's handlers run.
type Stimulus = fn(&SimRig, u64);

/// A script and the field activity that keeps its handlers busy.
struct Case {
    file: &'static str,
    stimulus: Stimulus,
}

/// How much work the benchmark does.
struct Sizes {
    warm_up: u64,
    ticks: u64,
    jitter_run: Duration,
    day: Duration,
    /// Timer counts of the many-timer cases.
    timers: &'static [u32],
    /// Ticks measured in each many-timer case.
    timer_ticks: u64,
}

const FULL: Sizes = Sizes {
    warm_up: 200,
    ticks: 20_000,
    jitter_run: Duration::from_secs(5),
    day: Duration::from_secs(24 * 3600),
    timers: &[20_000, 150_000],
    timer_ticks: 50,
};

/// `cargo test --all-targets` runs this without `--bench`: just check that it still works.
const SMOKE: Sizes = Sizes {
    warm_up: 5,
    ticks: 50,
    jitter_run: Duration::from_millis(100),
    day: Duration::from_secs(3600),
    timers: &[2_000],
    timer_ticks: 5,
};

fn cases() -> Vec<Case> {
    vec![
        Case {
            file: "rotary_relay.rhai",
            // A detent every 5 ticks, a reset press every 100.
            stimulus: |sim, n| {
                if n % 5 == 0 {
                    sim.turn("panel", "S41A", 2).unwrap();
                }
                match n % 100 {
                    0 => sim.set_switch("panel", "S1", true).unwrap(),
                    2 => sim.set_switch("panel", "S1", false).unwrap(),
                    _ => {}
                }
            },
        },
        Case {
            file: "counter_threshold.rhai",
            // A part every tick (a batch of 100 every 100 ticks), acknowledged 20 ticks later.
            stimulus: |sim, n| {
                sim.pulse("io", 0, 1).unwrap();
                match n % 100 {
                    20 => sim.set_input("io", 7, true).unwrap(),
                    22 => sim.set_input("io", 7, false).unwrap(),
                    _ => {}
                }
            },
        },
        Case {
            file: "safe_values.rhai",
            // Timers only: nothing to do on the field side.
            stimulus: |_, _| {},
        },
        Case {
            file: "cron_rig.rhai",
            // The unit under test answers a trigger with two pulses.
            stimulus: answer_trigger,
        },
        Case {
            file: "interlock.rhai",
            // Guards closed and armed early; a stop press trips it every 500 ticks, re-armed
            // 10 ticks later; the 20 ms check runs armed in between.
            stimulus: |sim, n| {
                if n == 0 {
                    sim.set_inputs("io", 0x0F).unwrap();
                }
                match n % 500 {
                    2 | 12 => sim.set_switch("panel", "S12", true).unwrap(),
                    4 | 14 => sim.set_switch("panel", "S12", false).unwrap(),
                    300 => sim.set_switch("panel", "S10", true).unwrap(),
                    302 => sim.set_switch("panel", "S10", false).unwrap(),
                    _ => {}
                }
            },
        },
    ]
}

/// `cron_rig.rhai`'s unit under test: two response pulses on DI2 while DO2 is on.
fn answer_trigger(sim: &SimRig, _: u64) {
    if sim.outputs("io").unwrap() & 0x04 != 0 {
        sim.pulse("io", 2, 2).unwrap();
    }
}

/// The run `rigscript run SCRIPT --sim` would put together, on `clock`.
fn rig(
    file: &str,
    clock: SharedClock,
    period: Option<Duration>,
    end: Option<Duration>,
    wake_latency: WakeLatency,
) -> Rig {
    let path = format!("{}/scripts/{file}", env!("CARGO_MANIFEST_DIR"));
    let source = std::fs::read_to_string(&path).expect("read the script");
    rig_from_source(
        &source,
        &path,
        clock,
        period,
        end,
        wake_latency,
        ScriptLimits::default(),
    )
}

/// The run of `source` (called `path` in messages) on the simulated rig, on `clock`.
fn rig_from_source(
    source: &str,
    path: &str,
    clock: SharedClock,
    period: Option<Duration>,
    end: Option<Duration>,
    wake_latency: WakeLatency,
    limits: ScriptLimits,
) -> Rig {
    let config = RigConfig {
        wake_latency,
        limits,
        ..RigConfig::simulated_default()
    };
    let mut setup = RigBuilder::from_config(config)
        .simulated()
        .clock(clock)
        .zone(Zone::utc())
        .log_to_stderr(false);
    if let Some(period) = period {
        setup = setup.period(period);
    }
    if let Some(end) = end {
        setup = setup.run_for(end);
    }
    let rig = setup.start(source, path).expect("start the script");
    assert!(
        rig.runner.status().is_none(),
        "{path} ended at its top level"
    );
    rig
}

fn virtual_clock() -> VirtualClock {
    let at = chrono::DateTime::parse_from_rfc3339(START).unwrap();
    VirtualClock::new(at.with_timezone(&chrono::Utc))
}

/// Mean real time per tick over `sizes.ticks` ticks in virtual time (after a warm-up), with
/// the field side driven before each tick; and transactions per tick.
fn tick_overhead(case: &Case, sizes: &Sizes) -> (Duration, f64) {
    let clock = virtual_clock();
    let mut rig = rig(case.file, Arc::new(clock), None, None, WakeLatency::Auto);
    let mut spent = Duration::ZERO;
    let total = sizes.warm_up + sizes.ticks;
    for n in 0..total {
        (case.stimulus)(&rig.sim, n);
        let t = Instant::now();
        rig.runner.step();
        if n >= sizes.warm_up {
            spent += t.elapsed();
        }
        assert!(rig.runner.status().is_none(), "{} stopped", case.file);
    }
    let per_tick = spent / u32::try_from(sizes.ticks).unwrap();
    (per_tick, rig.runner.stats().transactions_per_tick())
}

/// CPU time stolen by the hypervisor so far, all CPUs (the `steal` column of /proc/stat, in
/// USER_HZ ticks of 10 ms); `None` where there is no such file.
fn steal() -> Option<Duration> {
    let stat = std::fs::read_to_string("/proc/stat").ok()?;
    let cpu = stat.lines().find(|l| l.starts_with("cpu "))?;
    let ticks: u64 = cpu.split_whitespace().nth(8)?.parse().ok()?;
    Some(Duration::from_millis(ticks * 10))
}

/// Steal time since `before`, as text for a result line.
fn stolen_since(before: Option<Duration>) -> String {
    match (before, steal()) {
        (Some(a), Some(b)) => format!(", steal {} ms", b.saturating_sub(a).as_millis()),
        _ => String::new(),
    }
}

/// One result line: quantiles of how late ticks started.
fn lateness_line(ticks: u64, h: &Histogram, overruns: u64, stolen: &str) -> String {
    let us = |d: Duration| d.as_micros();
    format!(
        "{ticks} ticks, p50 {} µs, p99 {} µs, max {} µs, {overruns} overruns{stolen}",
        us(h.quantile(0.5)),
        us(h.quantile(0.99)),
        us(h.max()),
    )
}

/// The machine's own floor: a loop that does nothing but sleep to 10 ms deadlines for `run`,
/// with the scan loop's clock, thread hints and wake-up latency request, measured the same way.
fn bare_loop_jitter(run: Duration) -> String {
    let stolen_before = steal();
    let _ = rigscript::time::clock::prefer_prompt_wakeups();
    let _hold = WakeLatency::Auto
        .limit_for(Some(PERIOD))
        .and_then(|l| wake_latency::hold(l).ok());
    let clock = SystemClock::new();
    let start = clock.now();
    let mut deadline = start;
    let mut late = Histogram::default();
    let mut ticks = 0;
    while deadline < start + run {
        clock.sleep_until(deadline);
        late.add(clock.now().saturating_sub(deadline));
        ticks += 1;
        deadline += PERIOD;
    }
    lateness_line(ticks, &late, 0, &stolen_since(stolen_before))
}

/// Runs the script for `run` at a 10 ms period in real time, as `rigscript run` does.
fn jitter(case: &Case, sizes: &Sizes, wake: WakeLatency) -> String {
    let stolen_before = steal();
    let mut rig = rig(
        case.file,
        SystemClock::shared(),
        Some(PERIOD),
        Some(sizes.jitter_run),
        wake,
    );
    let status = rig.runner.run();
    assert!(status == 0 || status == 4, "{} exited {status}", case.file);
    let s = rig.runner.stats();
    lateness_line(s.ticks, &s.jitter, s.overruns, &stolen_since(stolen_before))
}

/// Wall time of `sizes.day` of `cron_rig.rhai` in virtual time, its unit under test answering.
fn cron_day(sizes: &Sizes) -> (Duration, u64, usize) {
    let clock = virtual_clock();
    let shared: SharedClock = Arc::new(clock.clone());
    let t = Instant::now();
    let mut rig = rig("cron_rig.rhai", shared, None, None, WakeLatency::Auto);
    let mut n = 0;
    while clock.now() < sizes.day && rig.runner.status().is_none() {
        answer_trigger(&rig.sim, n);
        rig.runner.step();
        n += 1;
    }
    let wall = t.elapsed();
    let records = rig.runner.runtime().borrow().records_kept().len();
    (wall, rig.runner.stats().ticks, records)
}

/// A script with `count` `every` timers whose periods are spread over `periods_ms` (first ..
/// last, one millisecond apart, round robin), each with an empty handler.
fn many_timers(count: u32, periods_ms: (u32, u32)) -> String {
    let (first, last) = periods_ms;
    let spread = last - first + 1;
    format!("for i in 0..{count} {{ every({first} + i % {spread}, || {{ }}); }}")
}

/// Real time per tick (mean and worst) over `ticks` ticks in virtual time of a script with
/// `count` timers, after the first two seconds (every timer of 1-2 s has fired once by then).
fn timer_ticks(count: u32, periods_ms: (u32, u32), ticks: u64) -> (Duration, Duration) {
    let clock = virtual_clock();
    let source = many_timers(count, periods_ms);
    let mut rig = rig_from_source(
        &source,
        "many_timers.rhai",
        Arc::new(clock),
        None,
        None,
        WakeLatency::Auto,
        ScriptLimits {
            // The top level adds every timer in one call.
            operations: u64::from(count) * 20,
            timers: count as usize,
            ..ScriptLimits::default()
        },
    );
    rig.runner.advance(Duration::from_secs(2));
    let (mut total, mut worst) = (Duration::ZERO, Duration::ZERO);
    for _ in 0..ticks {
        let t = Instant::now();
        rig.runner.step();
        let spent = t.elapsed();
        total += spent;
        worst = worst.max(spent);
        assert!(rig.runner.status().is_none(), "many_timers stopped");
    }
    (total / u32::try_from(ticks).unwrap(), worst)
}

fn main() {
    let args = BenchArgs::from_env();
    let sizes = if args.full { &FULL } else { &SMOKE };
    let wanted = |name: &str| args.picks(name);
    println!(
        "tick work: mean real time per tick over {} ticks in virtual time (target <= 20 µs)",
        sizes.ticks
    );
    let cases = cases();
    for case in cases.iter().filter(|c| wanted(c.file)) {
        let (per_tick, tx) = tick_overhead(case, sizes);
        println!(
            "  {:24} {:6.1} µs/tick, {tx:.2} transactions/tick",
            case.file,
            per_tick.as_secs_f64() * 1e6
        );
    }
    println!(
        "jitter: lateness of tick starts at a 10 ms period over {} s, real time (target p99 <= 1 ms)",
        sizes.jitter_run.as_secs_f64()
    );
    println!(
        "  wake latency {}",
        wake_latency::describe(
            &WakeLatency::Auto
                .limit_for(Some(PERIOD))
                .map(wake_latency::hold)
        )
    );
    for case in cases.iter().filter(|c| wanted(c.file)) {
        println!(
            "  {:24} {}",
            "(bare sleep loop)",
            bare_loop_jitter(sizes.jitter_run)
        );
        println!(
            "  {:24} {}",
            case.file,
            jitter(case, sizes, WakeLatency::Auto)
        );
    }
    if let Some(case) = cases
        .iter()
        .find(|c| c.file == "interlock.rhai" && wanted(c.file))
    {
        println!(
            "  {:24} {}",
            "interlock, latency off",
            jitter(case, sizes, WakeLatency::Off)
        );
    }
    if wanted("timers") {
        println!(
            "many timers: real time per tick over {} ticks ({} s) in virtual time, mean and worst",
            sizes.timer_ticks,
            sizes.timer_ticks as f64 * 0.02
        );
        let kinds = [
            ("none firing (1-2 h)", (3_600_000, 7_199_999)),
            ("spread over 1-2 s", (1000, 1999)),
            ("all every 1 s", (1000, 1000)),
        ];
        for &count in sizes.timers {
            for (what, periods) in kinds {
                let (mean, worst) = timer_ticks(count, periods, sizes.timer_ticks);
                println!(
                    "  {count:>7} timers, {what:20} mean {:10.1} µs/tick, worst {:10.1} µs",
                    mean.as_secs_f64() * 1e6,
                    worst.as_secs_f64() * 1e6
                );
            }
        }
    }
    if wanted("cron_rig.rhai") {
        let (wall, ticks, records) = cron_day(sizes);
        println!(
            "cron_rig.rhai: {} h of virtual time in {:.3} s ({ticks} ticks, {records} \
             measurements; target a day in < 1 s)",
            sizes.day.as_secs() / 3600,
            wall.as_secs_f64()
        );
    }
}
