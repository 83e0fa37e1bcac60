//! A late answer is never taken for the next request's answer (docs/design/line-timing.md): after
//! a timeout the driver lets the line fall silent for one more timeout, dropping what comes,
//! before the retry. A DO read and a DI read have answers of the same shape, ASCII counter
//! answers carry no channel, and a name and a firmware answer are both text, so matching
//! answers to requests alone cannot tell them apart. Answers that come twice or torn end right
//! or in a clear error, and the line's silence holds after each (docs/design/line-timing.md).

use crate::common::{rigscript, run, stderr, stdout, SimProcess};
use rigscript::device::c29u::{share, C29u, C29uError, C29uOptions, Protocol};
use rigscript::link::far_end::ByteDevice;
use rigscript::link::memory::MemoryByteLink;
use rigscript::sim::c29u::{C29uModel as Model, Eeprom};
use rigscript::sim::c29u_line::{lock, SimulatedC29u};
use rigscript::time::clock::{Clock, VirtualClock};
use std::process::Output;
use std::sync::Arc;
use std::time::Duration;

fn c29(sim: &SimProcess, protocol: &str, args: &[&str]) -> Output {
    let mut all = vec!["c29", "--port", &sim.path, "--protocol", protocol];
    all.extend_from_slice(args);
    run(rigscript(), &all)
}

/// Either the truth (exit 0, and every reading shown is the module's state) or a clear timeout
/// (exit 3, and no reading shown): never anything else. A reading is a line whose first word is
/// the first word of an entry of `truth`; it must begin with that entry.
fn truth_or_timeout(out: &Output, truth: &[&str]) {
    let (stdout, stderr) = (stdout(out), stderr(out));
    let label = |line: &str| line.split_whitespace().next().map(str::to_string);
    let readings: Vec<&str> = stdout
        .lines()
        .filter(|line| truth.iter().any(|t| label(t) == label(line)))
        .collect();
    for reading in &readings {
        let right = truth.iter().find(|t| label(t) == label(reading));
        assert!(
            right.is_some_and(|t| reading.starts_with(t)),
            "wrong data {reading:?}, the truth is {truth:?}:\n{stdout}"
        );
    }
    match out.status.code() {
        Some(0) => {
            for right in truth {
                assert!(stdout.contains(right), "missing {right:?}:\n{stdout}");
            }
        }
        Some(3) => {
            assert!(stderr.contains("no answer"), "{stderr}");
            assert!(
                readings.is_empty(),
                "a reading shown on a timeout:\n{stdout}"
            );
        }
        other => panic!("exit {other:?}:\n{stdout}\n{stderr}"),
    }
}

#[test]
fn c29_status_never_shows_a_late_do_answer_as_the_inputs() {
    let mut sim = SimProcess::start(&["--delay", "250", "--di", "0x0A"]);
    let set = c29(&sim, "modbus", &["--timeout", "1000", "do", "0x21"]);
    assert_eq!(set.status.code(), Some(0), "{set:?}");
    assert_eq!(sim.state()["do"], 0x21);
    let truth = ["DI    0x0A", "DO    0x21"];
    // Each run's last request may be answered after it has given up and gone: the next run
    // (a new process) must not take that answer for one of its own.
    for _ in 0..4 {
        let out = c29(&sim, "modbus", &["--timeout", "200", "status"]);
        truth_or_timeout(&out, &truth);
    }
    let out = c29(&sim, "modbus", &["--timeout", "1000", "status"]);
    assert_eq!(out.status.code(), Some(0), "{out:?}");
    truth_or_timeout(&out, &truth);
    let state = sim.state();
    assert_eq!(
        (state["di"].as_u64(), state["do"].as_u64()),
        (Some(0x0A), Some(0x21))
    );
}

#[test]
fn c29_counters_in_ascii_are_never_shifted_by_a_late_answer() {
    let mut sim = SimProcess::start(&["--protocol", "ascii", "--delay", "250"]);
    assert_eq!(sim.control("pulse 3 7"), "ok");
    let out = c29(&sim, "ascii", &["--timeout", "200", "counters"]);
    truth_or_timeout(&out, &["DI3  7", "DI4  0"]);
}

#[test]
fn c29_info_in_ascii_never_reads_the_name_as_the_firmware() {
    let sim = SimProcess::start(&["--protocol", "ascii", "--delay", "250"]);
    let out = c29(&sim, "ascii", &["--timeout", "200", "info"]);
    truth_or_timeout(&out, &["firmware  C29M090703"]);
}

/// The module, with its answer to the `late`-th request (from 0) coming 250 ms late against a
/// 200 ms timeout, in virtual time.
fn module_late_once(protocol: Protocol, late: u64) -> (C29u, VirtualClock) {
    let clock = VirtualClock::at_epoch();
    let shared = Arc::new(clock.clone());
    let sim = SimulatedC29u::new(Model::new(protocol, shared.clone(), Eeprom::factory()));
    {
        let model = sim.model();
        let mut m = lock(&model);
        m.set_inputs(0x05);
        m.write_outputs(0x21).unwrap();
        m.pulse(3, 7).unwrap();
    }
    let link = MemoryByteLink::new(sim, "late once")
        .with_clock(shared.clone())
        .with_line(9600)
        .delay_answers(move |n| Duration::from_millis(if n == late { 250 } else { 0 }));
    let options = C29uOptions {
        protocol,
        timeout: Duration::from_millis(200),
        retries: 2,
        ..C29uOptions::default()
    };
    (
        C29u::new(share(Box::new(link)), shared, options).unwrap(),
        clock,
    )
}

/// What `c29 status`, `counters` and `info` read, in order.
fn readings(dev: &mut C29u) -> Result<Vec<String>, C29uError> {
    let io = dev.read_io()?;
    let mut out = vec![
        format!("DO {:#04x}", io.outputs),
        format!("DI {:#04x}", io.inputs),
    ];
    out.extend(dev.read_counters()?.iter().map(|c| format!("count {c}")));
    out.push(format!("name {}", dev.name()?));
    out.push(format!("firmware {}", dev.firmware()?.text));
    Ok(out)
}

#[test]
fn an_answer_late_once_at_any_position_leaves_every_reading_right() {
    for protocol in [Protocol::Modbus, Protocol::Ascii] {
        let (mut dev, _) = module_late_once(protocol, u64::MAX);
        let truth = readings(&mut dev).unwrap();
        assert_eq!(&truth[..2], ["DO 0x21", "DI 0x05"]);
        assert_eq!(truth[5], "count 7", "{truth:?}");
        for late in 0..=14 {
            let (mut dev, clock) = module_late_once(protocol, late);
            let got = readings(&mut dev);
            assert_eq!(
                got.as_ref().ok(),
                Some(&truth),
                "{protocol:?}, answer {late} late: {got:?}"
            );
            // After the readings, the late request's own answer must not be lying in wait.
            let again = readings(&mut dev).unwrap();
            assert_eq!(again, truth, "{protocol:?}, answer {late} late, read again");
            assert!(clock.now() < Duration::from_secs(5));
        }
    }
}

/// The module behind a wrapper that answers the `n`-th request (from 0) twice, or only its
/// first three bytes, and notes when each request arrived.
struct Mangled {
    inner: SimulatedC29u,
    clock: VirtualClock,
    twice: u64,
    torn: u64,
    heard: Arc<std::sync::Mutex<Vec<(Duration, usize, usize)>>>,
    n: u64,
}

impl ByteDevice for Mangled {
    fn receive(&mut self, bytes: &[u8]) -> Vec<u8> {
        let mut answer = self.inner.receive(bytes);
        if self.n == self.twice {
            answer.extend(answer.clone());
        }
        if self.n == self.torn {
            answer.truncate(3);
        }
        self.n += 1;
        self.heard
            .lock()
            .unwrap()
            .push((self.clock.now(), bytes.len(), answer.len()));
        answer
    }
}

#[test]
fn answers_twice_or_torn_end_right_or_in_a_clear_error_and_the_silence_holds_after_them() {
    use rigscript::link::line::wire_time;
    use rigscript::protocol::c29u_modbus::silence_gap;
    for (twice, torn) in [
        (0, u64::MAX),
        (2, u64::MAX),
        (u64::MAX, 0),
        (u64::MAX, 3),
        (1, 2),
    ] {
        let clock = VirtualClock::at_epoch();
        let shared = Arc::new(clock.clone());
        let sim = SimulatedC29u::new(Model::new(
            Protocol::Modbus,
            shared.clone(),
            Eeprom::factory(),
        ));
        {
            let model = sim.model();
            let mut m = lock(&model);
            m.set_inputs(0x05);
            m.write_outputs(0x21).unwrap();
        }
        let heard = Arc::new(std::sync::Mutex::new(Vec::new()));
        let device = Mangled {
            inner: sim,
            clock: clock.clone(),
            twice,
            torn,
            heard: heard.clone(),
            n: 0,
        };
        let link = MemoryByteLink::new(device, "mangled")
            .with_clock(shared.clone())
            .with_line(9600);
        let options = C29uOptions {
            timeout: Duration::from_millis(200),
            retries: 2,
            ..C29uOptions::default()
        };
        let mut dev = C29u::new(share(Box::new(link)), shared, options).unwrap();
        for _ in 0..3 {
            match dev.read_io() {
                Ok(io) => assert_eq!((io.outputs, io.inputs), (0x21, 0x05)),
                Err(e @ (C29uError::Garbled { .. } | C29uError::Timeout { .. })) => {
                    panic!("retries should have recovered: {e}")
                }
                Err(e) => panic!("{e}"),
            }
        }
        // Every request came after the line's last frame (whatever answered before it) had
        // ended and t3.5 had passed.
        let heard = heard.lock().unwrap().clone();
        for pair in heard.windows(2) {
            let ((at, request, answer), (next, _, _)) = (pair[0], pair[1]);
            let frames_end = at + wire_time(request, 9600) + wire_time(answer, 9600);
            assert!(
                next >= frames_end + silence_gap(9600),
                "twice {twice} torn {torn}: {heard:?}"
            );
        }
    }
}
