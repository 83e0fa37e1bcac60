//! Polling a TRP-C29U's inputs (FC01) as fast as the line allows: rigscript (`run` with
//! `--period 1us` and one `io.on_rise` handler), rigscript's driver alone (a loop on a thread of
//! this process: what the exchange costs without the scan loop) and a C loop over libmodbus's
//! `modbus_read_bits`, with and without t3.5 of silence before each request, all against the
//! same simulator (served in this process on a pty) in the same run.
//!
//! Through a baud-accurate line (`sim::timed_line`: each byte handed over when its stop bit ends,
//! the module answering in the relay's thread as the request's last byte is in) at 9600 and
//! 115200 baud it reports polls per second (and the share of what a compliant master can reach:
//! 14 characters and t3.5 a poll), the 2nd, 50th and 99th percentiles of the silence each master
//! leaves before its requests, and where a poll's time goes (request, turnaround, answer,
//! silence); straight on the pty (at 115200 baud settings, the module served by a thread of its
//! own) how fast each goes. The masters of a setup take turns, 5 rounds of 3 s, and the table shows medians (and
//! percentiles of every silence seen). Every row shows CPU time per poll of the polling process
//! (user + system, from the scheduler's accounting, start-up excluded).
//!
//! Each setup runs rigscript as shipped (`--wake-latency auto`, which holds a 0 µs PM QoS
//! request at this tick rate) beside the C loop making the same request, then both without
//! (`--wake-latency off`), as the C loop runs by itself.
//!
//! Run: `cargo bench --bench line [WORDS]` (words pick rows: `9600`, `raw`, `libmodbus`...).
//! `LINE_BENCH_ROUNDS=N` takes N rounds instead of 5; `LINE_BENCH_BASELINE=PATH` adds the
//! gap-keeping rows run by another rigscript build (say, main's, copied aside) to compare a
//! change with in the same rounds.
//! `cargo test` runs it for 0.8 s a row, so the comparison never silently drops out;
//! it needs gcc and libmodbus-dev.

mod common;

#[path = "common/args.rs"]
mod args;

#[path = "common/percentile.rs"]
mod percentile;
use args::BenchArgs;
use common::{counting_module, idle_after, Served};
use percentile::percentile;
use rigscript::device::c29u::{C29u, C29uOptions};
use rigscript::link::line::wire_time;
use rigscript::protocol::c29u::Protocol;
use rigscript::protocol::c29u_modbus::silence_gap;
use rigscript::sim::timed_line::TimedLine;
use rigscript::sim::wire::{Frame, Side};
use rigscript::time::clock::SystemClock;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Who polls.
#[derive(Clone, Copy)]
enum Master {
    /// `rigscript run`, with `frame_gap = "auto"` (t3.5) or `"0s"`; `held`: with its default
    /// `--wake-latency auto` (a 0 µs PM QoS request at this period) instead of `off`;
    /// `baseline`: the build `LINE_BENCH_BASELINE` names (say, main's) instead of this one, to
    /// measure a change against it in the same rounds.
    Rigscript {
        gap: bool,
        held: bool,
        baseline: bool,
    },
    /// The C loop over libmodbus, sleeping t3.5 before each request or not at all; `held`:
    /// making the same PM QoS request as rigscript does by default.
    Libmodbus { gap: bool, held: bool },
    /// rigscript's driver without the script runtime (`C29u::read_inputs_raw` in a loop on a
    /// thread of this process, keeping the gap): what the exchange costs, so that the
    /// difference to the `rigscript` row is what the scan loop's tick adds.
    Driver,
}

impl Master {
    /// Whether it holds the CPU wake-up latency.
    fn holds(self) -> bool {
        matches!(
            self,
            Master::Rigscript { held: true, .. } | Master::Libmodbus { held: true, .. }
        )
    }

    fn name(self) -> String {
        let (base, gap, held, baseline) = match self {
            Master::Rigscript {
                gap,
                held,
                baseline,
            } => ("rigscript", gap, held, baseline),
            Master::Libmodbus { gap, held } => ("libmodbus", gap, held, false),
            Master::Driver => return "rigscript's driver alone (no scan loop)".into(),
        };
        let mut name = match (base, gap) {
            ("libmodbus", true) => "libmodbus + t3.5 sleep".to_string(),
            ("libmodbus", false) => "libmodbus back to back".to_string(),
            (_, true) => "rigscript".to_string(),
            (_, false) => "rigscript, frame_gap 0s".to_string(),
        };
        if baseline {
            name.push_str(", baseline build");
        }
        if held {
            name.push_str(", wake latency held");
        }
        name
    }
}

/// Builds the C loop with gcc against libmodbus; fails loudly (never skips) without them.
fn build_c_loop() -> PathBuf {
    let source = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/line/modbus_poll.c");
    let binary = Path::new(env!("CARGO_TARGET_TMPDIR")).join("modbus_poll");
    let status = Command::new("gcc")
        .args(["-O2", "-Wall", "-Werror", "-I/usr/include/modbus", "-o"])
        .arg(&binary)
        .arg(&source)
        .arg("-lmodbus")
        .status()
        .unwrap_or_else(|e| panic!("cannot run gcc ({e}): install gcc (and libmodbus-dev)"));
    assert!(
        status.success(),
        "gcc could not build {}: install libmodbus-dev (`.ci/run` does)",
        source.display()
    );
    binary
}

/// A master at work: a process, or the driver on a thread of this process.
enum Poller {
    Process(Child),
    Thread {
        stop: Arc<AtomicBool>,
        /// Its thread id, for its CPU time (0 until it has started).
        tid: Arc<AtomicI32>,
        done: JoinHandle<Result<(), String>>,
    },
}

/// User + system time of process `pid`'s threads and those of its children.
fn process_tree_cpu(pid: u32) -> Duration {
    let tasks = std::fs::read_dir(format!("/proc/{pid}/task")).expect("the master is running");
    let own: Duration = tasks.flatten().map(|t| scheduled(&t.path())).sum();
    let children =
        std::fs::read_to_string(format!("/proc/{pid}/task/{pid}/children")).unwrap_or_default();
    own + children
        .split_whitespace()
        .filter_map(|c| c.parse::<u32>().ok())
        .map(process_tree_cpu)
        .sum::<Duration>()
}

impl Poller {
    /// User + system time it has used so far, from the scheduler's accounting.
    fn cpu_time(&self) -> Duration {
        match self {
            // `rigscript run` on a real port is a guardian with the runner as its child: the
            // polling is the child's, so a process's children count with it.
            Poller::Process(child) => process_tree_cpu(child.id()),
            Poller::Thread { tid, .. } => scheduled(Path::new(&format!(
                "/proc/self/task/{}",
                tid.load(Ordering::SeqCst)
            ))),
        }
    }

    /// Stops it (SIGTERM to a process); panics, naming `name`, if it failed.
    fn stop(self, name: &str) {
        match self {
            Poller::Process(child) => {
                let _ = Command::new("kill")
                    .arg("-TERM")
                    .arg(child.id().to_string())
                    .status();
                let output = child.wait_with_output().expect("the master ends");
                // `rigscript run` ends on SIGTERM with 128 + 15, the C loop with 0.
                assert!(
                    matches!(output.status.code(), Some(0 | 143)),
                    "{name} failed: {}",
                    String::from_utf8_lossy(&output.stderr)
                );
            }
            Poller::Thread { stop, done, .. } => {
                stop.store(true, Ordering::SeqCst);
                let outcome = done.join().expect("the driver's thread ends");
                if let Err(e) = outcome {
                    panic!("{name} failed: {e}");
                }
            }
        }
    }
}

/// CPU time of the task whose /proc directory is `task` (its `schedstat`'s first field).
fn scheduled(task: &Path) -> Duration {
    let nanos = std::fs::read_to_string(task.join("schedstat"))
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<u64>().ok())
        .unwrap_or(0);
    Duration::from_nanos(nanos)
}

/// rigscript's driver polling the inputs on `port` until stopped, on a thread of its own.
fn start_driver(port: &str, baud: u32) -> Poller {
    let stop = Arc::new(AtomicBool::new(false));
    let tid = Arc::new(AtomicI32::new(0));
    let (port, stopped, own_tid) = (port.to_string(), Arc::clone(&stop), Arc::clone(&tid));
    let done = std::thread::spawn(move || {
        // SAFETY: gettid has no arguments and cannot fail.
        own_tid.store(unsafe { libc::gettid() }, Ordering::SeqCst);
        let options = C29uOptions {
            baud,
            timeout: Duration::from_millis(200),
            ..C29uOptions::default()
        };
        let mut module =
            C29u::open(&port, SystemClock::shared(), options).map_err(|e| e.to_string())?;
        while !stopped.load(Ordering::Relaxed) {
            module.read_inputs_raw().map_err(|e| e.to_string())?;
        }
        Ok(())
    });
    while tid.load(Ordering::SeqCst) == 0 {
        std::thread::yield_now();
    }
    Poller::Thread { stop, tid, done }
}

/// Starts `master` polling `port` at `baud`.
fn start(master: Master, port: &str, baud: u32, c_loop: &Path, dir: &Path) -> Poller {
    let t35 = silence_gap(baud);
    let mut command = match master {
        Master::Driver => return start_driver(port, baud),
        Master::Rigscript {
            gap,
            held,
            baseline: from_baseline,
        } => {
            let binary = if from_baseline {
                baseline().expect("LINE_BENCH_BASELINE names a build")
            } else {
                PathBuf::from(env!("CARGO_BIN_EXE_rigscript"))
            };
            let config = dir.join(format!("rig-{baud}-{gap}.toml"));
            let frame_gap = if gap { "auto" } else { "0s" };
            std::fs::write(
                &config,
                format!(
                    "[devices.io]\nkind = \"trp-c29u\"\nport = \"{port}\"\nbaud = {baud}\n\
                     timeout = \"200ms\"\nframe_gap = \"{frame_gap}\"\n"
                ),
            )
            .expect("write rig.toml");
            let script = dir.join("poll.rhai");
            std::fs::write(&script, "io.on_rise(0, || {});\n").expect("write the script");
            let mut c = Command::new(binary);
            c.arg("run")
                .arg(&script)
                .arg("--config")
                .arg(&config)
                .args(["--period", "1us", "--quiet", "--wake-latency"])
                .arg(if held { "auto" } else { "off" });
            c
        }
        Master::Libmodbus { gap, held } => {
            let gap_us = if gap { t35.as_micros() } else { 0 };
            let mut c = Command::new(c_loop);
            c.arg(port)
                .arg(baud.to_string())
                .arg(gap_us.to_string())
                .arg(if held { "0" } else { "-1" });
            c
        }
    };
    let child = command
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {}: {e}", master.name()));
    Poller::Process(child)
}

/// Whether this process may hold a CPU wake-up latency, as the `held` rows do: a sandbox
/// without `/dev/cpu_dma_latency` (or the right to write it) shows the rows without.
fn can_hold_wake_latency() -> Result<(), String> {
    // A limit no CPU is held to: only whether the request can be made is of interest.
    rigscript::runtime::wake_latency::hold(Duration::from_secs(1000))
        .map(drop)
        .map_err(|e| e.to_string())
}

/// The rigscript build `LINE_BENCH_BASELINE` names, if any.
fn baseline() -> Option<PathBuf> {
    std::env::var_os("LINE_BENCH_BASELINE").map(PathBuf::from)
}

fn ms(d: Option<Duration>) -> String {
    d.map_or("-".into(), |d| format!("{:.3}", d.as_secs_f64() * 1e3))
}

/// What one master did in one measurement.
struct Run {
    rate: f64,
    cpu_us: f64,
    /// Silence before each request, through a relay.
    silences: Vec<Duration>,
    /// Requests that got no answer (lost on a loaded machine), through a relay.
    unanswered: usize,
    /// Where each answered poll's time went, through a relay.
    polls: Vec<Parts>,
}

/// One poll on the line, as the relay saw it.
#[derive(Clone, Copy)]
struct Parts {
    /// The request on the wire, first start bit to last stop bit.
    request: Duration,
    /// From the request's end to the answer's start (the module's and the relay's work).
    turnaround: Duration,
    /// The answer on the wire.
    answer: Duration,
    /// From the answer's end to the next request's start (the master's silence, with the
    /// hops from the relay to the master's pty and back).
    silence: Duration,
}

/// `master` polling for `window` after `warm_up`, through a relay at `baud` or (`relayed`
/// false) straight on the pty.
fn measure(
    master: Master,
    baud: u32,
    relayed: bool,
    (warm_up, window): (Duration, Duration),
    c_loop: &Path,
    dir: &Path,
) -> Run {
    // Through the line the module answers in the relay's thread; on the bare pty a thread of
    // its own serves it.
    let (served, relay, answered) = if relayed {
        let (module, answered) = counting_module(Protocol::Modbus, baud);
        let relay =
            TimedLine::with_device(module, baud, idle_after(baud)).expect("start the relay");
        (None, Some(relay), answered)
    } else {
        let served = Served::start(Protocol::Modbus, baud);
        let answered = served.counter();
        (Some(served), None, answered)
    };
    let port = match (&relay, &served) {
        (Some(r), _) => r.path().to_string(),
        (None, Some(s)) => s.path.clone(),
        (None, None) => unreachable!("a line or a pty"),
    };
    let polls = || answered.load(Ordering::Relaxed);
    let poller = start(master, &port, baud, c_loop, dir);
    std::thread::sleep(warm_up);
    let (cpu0, polls0, at0) = (poller.cpu_time(), polls(), Instant::now());
    let mark0 = relay.as_ref().map(TimedLine::now);
    std::thread::sleep(window);
    let (cpu1, polls1, elapsed) = (poller.cpu_time(), polls(), at0.elapsed());
    let mark1 = relay.as_ref().map(TimedLine::now);
    poller.stop(&master.name());
    let polls = polls1.saturating_sub(polls0);
    assert!(polls > 0, "{} made no poll in {window:?}", master.name());
    let rate = polls as f64 / elapsed.as_secs_f64();
    let cpu_us = cpu1.saturating_sub(cpu0).as_secs_f64() * 1e6 / polls as f64;
    let (silences, unanswered, polls) = match (relay, mark0, mark1) {
        (Some(relay), Some(from), Some(to)) => {
            let frames: Vec<Frame> = relay
                .stop()
                .expect("stop the relay")
                .into_iter()
                .filter(|f| f.start >= from && f.start <= to)
                .collect();
            // Each answered poll: request, answer, and the request after it.
            let polls = frames
                .windows(3)
                .filter(|w| {
                    w.iter()
                        .map(|f| f.side)
                        .eq([Side::Master, Side::Slave, Side::Master])
                })
                .map(|w| Parts {
                    request: w[0].end - w[0].start,
                    turnaround: w[1].start.saturating_sub(w[0].end),
                    answer: w[1].end - w[1].start,
                    silence: w[2].start.saturating_sub(w[1].end),
                })
                .collect();
            let silences = frames
                .iter()
                .filter(|f| f.side == Side::Master)
                .filter_map(|f| f.silence)
                .collect();
            // A request followed by another request got no answer.
            let unanswered = frames
                .windows(2)
                .filter(|w| w.iter().all(|f| f.side == Side::Master))
                .count();
            (silences, unanswered, polls)
        }
        _ => (Vec::new(), 0, Vec::new()),
    };
    Run {
        rate,
        cpu_us,
        silences,
        unanswered,
        polls,
    }
}

/// One line of the table from the runs of one master: medians of rate and CPU, percentiles of
/// every silence seen.
fn print_row(setup: &str, master: Master, baud: u32, relayed: bool, runs: &[Run]) {
    let rate = median(runs.iter().map(|r| r.rate).collect());
    let cpu_us = median(runs.iter().map(|r| r.cpu_us).collect());
    let mut silences: Vec<Duration> = runs.iter().flat_map(|r| r.silences.clone()).collect();
    silences.sort();
    let at = |p| ms(percentile(&silences, p));
    let t35 = silence_gap(baud);
    let (share, unanswered) = if relayed {
        let ideal = 1.0 / (wire_time(14, baud) + t35).as_secs_f64();
        (
            format!("{:.0}%", rate / ideal * 100.0),
            runs.iter().map(|r| r.unanswered).sum::<usize>().to_string(),
        )
    } else {
        ("-".into(), "-".into())
    };
    println!(
        "| {setup} | {} | {rate:.1} | {share} | {} | {} | {} | {unanswered} | {:.3} | {cpu_us:.1} |",
        master.name(),
        at(2.0),
        at(50.0),
        at(99.0),
        t35.as_secs_f64() * 1e3,
    );
}

/// Where the polls of one master went through the line: means over every answered poll, in
/// ms, beside what a compliant master on an ideal line takes.
fn breakdown_row(setup: &str, master: Master, baud: u32, runs: &[Run]) -> Option<String> {
    let polls: Vec<Parts> = runs.iter().flat_map(|r| r.polls.iter().copied()).collect();
    if polls.is_empty() {
        return None;
    }
    let mean = |part: fn(&Parts) -> Duration| {
        polls.iter().map(part).sum::<Duration>().as_secs_f64() * 1e3 / polls.len() as f64
    };
    let parts = [
        mean(|p| p.request),
        mean(|p| p.turnaround),
        mean(|p| p.answer),
        mean(|p| p.silence),
    ];
    let t35 = silence_gap(baud).as_secs_f64() * 1e3;
    let ideal = (wire_time(14, baud) + silence_gap(baud)).as_secs_f64() * 1e3;
    let late = polls
        .iter()
        .filter(|p| p.silence > silence_gap(baud) * 2)
        .count() as f64
        / polls.len() as f64
        * 100.0;
    Some(format!(
        "| {setup} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {late:.1}% | {:.3} | {ideal:.3} |",
        master.name(),
        parts[0],
        parts[1],
        parts[2],
        parts[3],
        parts[3] - t35,
        parts.iter().sum::<f64>(),
    ))
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied().unwrap_or(f64::NAN)
}

fn main() {
    let BenchArgs { full, words } = BenchArgs::from_env();
    // Words given (`cargo bench --bench line -- 9600 libmodbus`) pick rows by setup or master.
    let wanted = |setup: &str, master: Master| {
        words.is_empty()
            || words
                .iter()
                .all(|w| setup.contains(w.as_str()) || master.name().contains(w.as_str()))
    };
    // The masters of a setup take turns, round after round, and the table shows medians, so
    // load that comes and goes on the machine falls on all of them alike.
    let (times, rounds) = if full {
        (
            (Duration::from_millis(500), Duration::from_secs(3)),
            std::env::var("LINE_BENCH_ROUNDS")
                .ok()
                .and_then(|r| r.parse().ok())
                .unwrap_or(5),
        )
    } else {
        ((Duration::from_millis(300), Duration::from_millis(500)), 1)
    };
    let c_loop = build_c_loop();
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("line-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a scratch directory");
    println!(
        "| setup | master | polls/s | of 14 chars + t3.5 | silence p2 ms | p50 ms | p99 ms | unanswered | t3.5 ms | CPU µs/poll |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let rig = |gap, held| Master::Rigscript {
        gap,
        held,
        baseline: false,
    };
    let c = |gap, held| Master::Libmodbus { gap, held };
    // Masters holding the wake latency (rigscript's default) go first, then as the C loop
    // runs by itself; rigscript's own hold is system wide, so theirs are rows of their own.
    let on_a_line = [
        rig(true, true),
        c(true, true),
        rig(true, false),
        Master::Driver,
        c(true, false),
        c(false, false),
    ];
    let on_the_pty = [
        rig(true, true),
        c(true, true),
        rig(true, false),
        Master::Driver,
        c(true, false),
        rig(false, false),
        c(false, false),
    ];
    let setups = [
        ("9600 baud line", 9600, true, &on_a_line[..]),
        ("115200 baud line", 115_200, true, &on_a_line[..]),
        ("raw pty", 115_200, false, &on_the_pty[..]),
    ];
    let mut breakdown = Vec::new();
    let baseline: Vec<Master> = baseline()
        .map(|_| {
            [true, false]
                .map(|held| Master::Rigscript {
                    gap: true,
                    held,
                    baseline: true,
                })
                .to_vec()
        })
        .unwrap_or_default();
    let can_hold = can_hold_wake_latency();
    if let Err(why) = &can_hold {
        println!("(rows holding the wake latency left out: {why})\n");
    }
    for (setup, baud, relayed, masters) in setups {
        let masters: Vec<Master> = masters
            .iter()
            .copied()
            .chain(baseline.iter().copied())
            .filter(|&m| wanted(setup, m) && (can_hold.is_ok() || !m.holds()))
            .collect();
        let mut runs: Vec<Vec<Run>> = masters.iter().map(|_| Vec::new()).collect();
        for round in 0..rounds {
            // Each round starts one master further on, so none always runs after the same one.
            for i in 0..masters.len() {
                let at = (i + round) % masters.len();
                if let (Some(&master), Some(seen)) = (masters.get(at), runs.get_mut(at)) {
                    seen.push(measure(master, baud, relayed, times, &c_loop, &dir));
                }
            }
        }
        for (&master, seen) in masters.iter().zip(runs) {
            print_row(setup, master, baud, relayed, &seen);
            breakdown.extend(breakdown_row(setup, master, baud, &seen));
        }
    }
    if !breakdown.is_empty() {
        println!(
            "\nWhere a poll's time goes on the line (means, ms; silences over 2 x t3.5 are the \
             machine waking someone late):\n"
        );
        println!(
            "| setup | master | request | turnaround | answer | silence | silence - t3.5 | silences > 2 x t3.5 | poll | ideal poll |"
        );
        println!("|---|---|---|---|---|---|---|---|---|---|");
        for row in breakdown {
            println!("{row}");
        }
    }
    let _ = std::fs::remove_dir_all(dir);
}
