//! The silence before every frame on a serial line (Modbus over Serial Line 2.5.1.1): the driver
//! polls back to back at 9600 and 115200 baud through `rigscript sim c29u --strict-timing`,
//! which times the line at the module's baud and drops (and counts) every request that starts
//! less than t3.5 after the frame before it ended, as a module on a shared RS-485 line would.

use crate::common::{rigscript, run, stderr, stdout, SimProcess, TempDir};
use rigscript::device::c29u::{share, C29u, C29uError, C29uOptions};
use rigscript::link::serial::SerialLink;
use rigscript::link::ByteLink;
use rigscript::protocol::c29u_modbus::seal;
use rigscript::time::clock::SystemClock;
use std::time::Duration;

fn early_frames(sim: &mut SimProcess) -> u64 {
    let state = sim.state();
    state["early_frames"]
        .as_u64()
        .unwrap_or_else(|| panic!("state has no early_frames: {state}"))
}

fn strict_sim(baud: u32, ids: &str) -> SimProcess {
    SimProcess::start(&[
        "--strict-timing",
        "--baud",
        &baud.to_string(),
        "--id",
        ids,
        "--di",
        "0x0A",
    ])
}

#[test]
fn back_to_back_requests_to_two_modules_keep_the_silence_of_the_line() {
    for (baud, rounds) in [(9600u32, 12u8), (115_200, 60)] {
        let mut sim = strict_sim(baud, "1,2");
        let link = share(Box::new(SerialLink::open(&sim.path, baud).unwrap()));
        // No retries and a long timeout: a dropped request shows as an error, load does not.
        let options = |id| C29uOptions {
            id,
            baud,
            timeout: Duration::from_secs(1),
            retries: 0,
            ..C29uOptions::default()
        };
        let clock = SystemClock::shared();
        let mut one = C29u::new(link.clone(), clock.clone(), options(1)).unwrap();
        let mut two = C29u::new(link, clock, options(2)).unwrap();
        for round in 0..rounds {
            let at = |what: &str, e: C29uError| -> u8 {
                panic!("{what} at {baud} baud, round {round}: {e}")
            };
            assert_eq!(one.read_inputs().unwrap_or_else(|e| at("ID 1 DI", e)), 0x0A);
            // The next module waits for the silence after the first one's answer.
            assert_eq!(two.read_inputs().unwrap_or_else(|e| at("ID 2 DI", e)), 0x0A);
            // A write and a read in the same breath, as a tick does.
            one.write_outputs(round)
                .map_err(|e| at("ID 1 DO write", e))
                .ok();
            assert_eq!(
                one.read_outputs().unwrap_or_else(|e| at("ID 1 DO", e)),
                round
            );
            // No answer: the next request counts from the end of this one on the wire.
            one.host_ok().map_err(|e| at("host OK", e)).ok();
        }
        assert_eq!(early_frames(&mut sim), 0, "at {baud} baud");
    }
}

#[test]
fn run_polls_back_to_back_at_9600_and_115200_without_an_early_frame() {
    for baud in [9600u32, 115_200] {
        let mut sim = strict_sim(baud, "1");
        let dir = TempDir::new(&format!("line-timing-{baud}"));
        let config = dir.join("rig.toml");
        std::fs::write(
            &config,
            format!(
                "[devices.io]\nkind = \"trp-c29u\"\nport = \"{}\"\nbaud = {baud}\ntimeout = \"1s\"\nretries = 0\n",
                sim.path
            ),
        )
        .unwrap();
        let script = dir.join("poll.rhai");
        std::fs::write(&script, "io.on_rise(0, || {});\n").unwrap();
        let out = run(
            rigscript(),
            &[
                "run",
                script.to_str().unwrap(),
                "--config",
                config.to_str().unwrap(),
                "--period",
                "1us",
                "--for",
                "1500ms",
                "--stats",
                "--wake-latency",
                "off",
            ],
        );
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(0), "at {baud} baud: {err}");
        assert!(!err.contains("no answer"), "a request was lost: {err}");
        let stats = stdout(&out);
        let ticks: u64 = stats
            .lines()
            .find_map(|l| l.strip_prefix("ticks: "))
            .and_then(|n| n.trim().parse().ok())
            .unwrap_or_else(|| panic!("no tick count in {stats}"));
        assert!(ticks > 5, "it polled: {err}");
        assert_eq!(early_frames(&mut sim), 0, "at {baud} baud: {err}");
    }
}

#[test]
fn a_master_that_keeps_no_silence_loses_its_requests() {
    // The control experiment: a master that sends each request the moment the answer before
    // it is in (as libmodbus and mbpoll do) merges it with that answer on the line.
    let mut sim = strict_sim(9600, "1");
    let mut link = SerialLink::open(&sim.path, 9600).unwrap();
    let request = seal(&[1, 1, 0, 0x20, 0, 8]);
    let mut answered = 0;
    for _ in 0..10 {
        link.write_all(&request).unwrap();
        let mut buf = [0u8; 16];
        let mut got = 0;
        while got < 6 {
            match link.read(&mut buf, Duration::from_millis(300)).unwrap() {
                0 => break,
                n => got += n,
            }
        }
        if got == 6 {
            answered += 1;
        }
    }
    drop(link);
    let early = early_frames(&mut sim);
    assert!(early >= 1, "no request was early");
    assert_eq!(answered + early, 10, "every early request went unanswered");
    // The driver, keeping the silence, gets every answer from the same simulator.
    let out = run(rigscript(), &["c29", "--port", &sim.path, "status"]);
    assert_eq!(out.status.code(), Some(0), "{out:?}");
    assert!(stdout(&out).contains("DI    0x0A"));
    assert_eq!(early_frames(&mut sim), early);
}

#[test]
fn the_silence_holds_after_timeouts_and_garbled_answers() {
    // Answers dropped (a timeout, then a retry) and corrupted (a bad CRC, then a retry): every
    // retry is a new frame and keeps the line's silence like any other.
    let mut sim = SimProcess::start(&[
        "--strict-timing",
        "--baud",
        "115200",
        "--di",
        "0x0A",
        "--drop",
        "0.1",
        "--corrupt",
        "0.2",
        "--seed",
        "7",
    ]);
    let link = share(Box::new(SerialLink::open(&sim.path, 115_200).unwrap()));
    let options = C29uOptions {
        baud: 115_200,
        timeout: Duration::from_millis(200),
        retries: 6,
        ..C29uOptions::default()
    };
    let mut io = C29u::new(link, SystemClock::shared(), options).unwrap();
    for poll in 0..30 {
        match io.read_inputs() {
            Ok(di) => assert_eq!(di, 0x0A, "poll {poll}"),
            Err(e) => panic!("poll {poll}: {e}"),
        }
    }
    assert_eq!(early_frames(&mut sim), 0);
}
