//! `rigscript c29` argument parsing, exit statuses, and commands over the in-memory simulator.

use super::*;
use crate::cli::{Cli, Command};
use crate::device::c29u::share;
use crate::link::memory::MemoryByteLink;
use crate::link::LinkError;
use crate::sim::c29u::{C29uModel as Model, Eeprom};
use crate::sim::c29u_line::{lock, SharedModel, SimulatedC29u};
use crate::time::clock::VirtualClock;
use clap::Parser;
use std::sync::Arc;

fn parse(args: &[&str]) -> Result<C29Args, clap::Error> {
    let mut all = vec!["rigscript", "c29"];
    all.extend_from_slice(args);
    Cli::try_parse_from(all).map(|cli| match cli.command {
        Command::C29(a) => a,
        _ => panic!("not c29"),
    })
}

fn rig(protocol: Protocol) -> (SharedModel, C29u) {
    let clock = VirtualClock::at_epoch();
    let sim = SimulatedC29u::new(Model::new(
        protocol,
        Arc::new(clock.clone()),
        Eeprom::factory(),
    ));
    let model = sim.model();
    let link = MemoryByteLink::new(sim, "C29U").with_clock(Arc::new(clock.clone()));
    let options = C29uOptions {
        protocol,
        ..C29uOptions::default()
    };
    let dev = C29u::new(share(Box::new(link)), Arc::new(clock), options).unwrap();
    (model, dev)
}

#[test]
fn frame_gap_is_auto_or_a_bounded_duration() {
    let gap = |extra: &[&str]| {
        let mut args = vec!["--port", "/dev/ttyUSB0"];
        args.extend_from_slice(extra);
        args.push("status");
        parse(&args).map(|a| a.options().frame_gap)
    };
    assert_eq!(gap(&[]).unwrap(), FrameGap::Auto);
    assert_eq!(
        gap(&["--frame-gap", "5ms"]).unwrap(),
        FrameGap::Fixed(Duration::from_millis(5))
    );
    assert_eq!(gap(&["--frame-gap", "auto"]).unwrap(), FrameGap::Auto);
    assert!(gap(&["--frame-gap", "3s"]).is_err());
}

#[test]
fn options_parse_before_or_after_the_command_with_defaults() {
    let a = parse(&["--port", "/dev/ttyUSB0", "status"]).unwrap();
    let o = a.options();
    assert_eq!(
        (o.protocol, o.id, o.baud, o.checksum, o.retries),
        (Protocol::Modbus, 1, 9600, false, 2)
    );
    assert_eq!(o.timeout, Duration::from_millis(200));
    let a = parse(&[
        "set",
        "3",
        "on",
        "--port",
        "tcp://gw:4001",
        "--protocol",
        "ascii",
        "--id",
        "0x10",
        "--checksum",
        "--baud",
        "115200",
        "--timeout",
        "40",
        "--retries",
        "0",
        "--json",
        "--trace",
    ])
    .unwrap();
    assert_eq!(a.port.as_deref(), Some("tcp://gw:4001"));
    let o = a.options();
    assert_eq!(
        (o.protocol, o.id, o.baud, o.checksum, o.retries),
        (Protocol::Ascii, 16, 115200, true, 0)
    );
    assert!(a.json && a.trace);
    assert!(matches!(
        a.command,
        C29Command::Set {
            channel: 3,
            state: OnOff::On
        }
    ));
}

#[test]
fn every_command_parses() {
    let cases: &[&[&str]] = &[
        &["status"],
        &["do"],
        &["do", "0b00100001"],
        &["set", "7", "off"],
        &["counters"],
        &["clear-counters"],
        &["clear-counters", "4"],
        &["save-counters"],
        &["latch"],
        &["clear-latch"],
        &["watchdog"],
        &["watchdog", "off"],
        &["watchdog", "1.5"],
        &["host-ok"],
        &["safe-value"],
        &["safe-value", "0x0F"],
        &["power-on-value"],
        &["power-on-value", "255"],
        &["info"],
        &["name"],
        &["name", "PUMP 1"],
        &["reset"],
        &["configure", "--new-id", "5"],
        &[
            "configure",
            "--new-baud",
            "19200",
            "--set-checksum",
            "on",
            "--counter-edge",
            "falling",
            "--hex-counters",
            "off",
        ],
        &["raw", "$016"],
        &["monitor", "--interval", "50"],
    ];
    for case in cases {
        assert!(parse(case).is_ok(), "{case:?}: {:?}", parse(case).err());
    }
}

#[test]
fn bad_values_are_usage_errors() {
    for bad in [
        &["set", "9", "on"][..],
        &["set", "1", "maybe"],
        &["do", "300"],
        &["safe-value", "0x100"],
        &["clear-counters", "8"],
        &["--baud", "14400", "status"],
        &["--id", "256", "status"],
        &["--timeout", "0", "status"],
        &["watchdog", "30"],
        &["watchdog", "0.05"],
        &["watchdog", "soon"],
        &["name", "TOOLONGNAME"],
        &["configure"],
        &["frobnicate"],
    ] {
        let e = parse(bad).unwrap_err();
        assert!(e.use_stderr(), "{bad:?} parsed");
        assert_eq!(e.exit_code(), EXIT_USAGE, "{bad:?}");
    }
}

#[test]
fn watchdog_takes_off_seconds_or_a_duration() {
    assert_eq!(parse_watchdog("off"), Ok(WatchdogArg::Off));
    assert_eq!(parse_watchdog("OFF"), Ok(WatchdogArg::Off));
    assert_eq!(
        parse_watchdog("0.5"),
        Ok(WatchdogArg::Timeout(Duration::from_millis(500)))
    );
    assert_eq!(
        parse_watchdog("25.5"),
        Ok(WatchdogArg::Timeout(Duration::from_millis(25_500)))
    );
    assert_eq!(
        parse_watchdog("1500ms"),
        Ok(WatchdogArg::Timeout(Duration::from_millis(1500)))
    );
    assert!(parse_watchdog("0").unwrap_err().contains("0.1 s to 25.5 s"));
    assert!(parse_watchdog("0.15").is_err());
    assert!(parse_watchdog("").is_err());
}

#[test]
fn modbus_frames_are_hex_bytes_in_several_spellings() {
    let want = vec![1, 1, 0, 0x20, 0, 8];
    for text in [
        "01 01 00 20 00 08",
        "010100200008",
        "0x01,0x01,0x00,0x20,0x00,0x08",
        "1 1 0 20 0 8",
        "01:01:00:20:00:08",
    ] {
        assert_eq!(parse_hex_frame(text), Ok(want.clone()), "{text}");
    }
    assert!(parse_hex_frame("").is_err());
    assert!(parse_hex_frame("01 0G").unwrap_err().contains("hex"));
    assert!(parse_hex_frame("$016").is_err());
}

#[test]
fn exit_statuses_follow_reachability() {
    let unreachable = [
        CliError::from(LinkError::NotFound {
            what: "serial port /dev/x".into(),
            hint: "h".into(),
        }),
        CliError::from(LinkError::Disconnected {
            what: "serial port /dev/x".into(),
            detail: "d".into(),
        }),
        CliError::Device(C29uError::Timeout {
            port: "p".into(),
            id: 1,
            request: "r".into(),
            timeout: Duration::from_millis(1),
            received: Vec::new(),
            text: false,
        }),
    ];
    for e in &unreachable {
        assert_eq!(e.exit_status(), EXIT_UNREACHABLE, "{e}");
    }
    let usage = [
        CliError::Usage("u".into()),
        CliError::Device(C29uError::InvalidArgument("channel 9".into())),
    ];
    for e in &usage {
        assert_eq!(e.exit_status(), EXIT_USAGE, "{e}");
    }
    let failed = [
        CliError::Device(C29uError::SafeMode {
            port: "p".into(),
            id: 1,
        }),
        CliError::Device(C29uError::Garbled {
            port: "p".into(),
            id: 1,
            request: "r".into(),
            detail: "d".into(),
        }),
        CliError::Device(C29uError::Unsupported {
            what: "renaming the module",
            protocol: Protocol::Modbus,
            hint: "h",
        }),
    ];
    for e in &failed {
        assert_eq!(e.exit_status(), EXIT_FAILED, "{e}");
    }
}

#[test]
fn status_reports_logical_inputs_and_outputs_both_ways() {
    for protocol in [Protocol::Modbus, Protocol::Ascii] {
        let (model, mut dev) = rig(protocol);
        lock(&model).set_inputs(0x05);
        lock(&model).write_outputs(0x21).unwrap();
        let r = execute(&C29Command::Status, &mut dev).unwrap();
        assert_eq!(r.json["di"], 5);
        assert_eq!(r.json["di_raw"], 0xFA);
        assert_eq!(r.json["do"], 0x21);
        assert_eq!(r.json["energized"], json!([0, 2]));
        assert!(
            r.text.contains("DI    0x05  00000101  energized: DI0 DI2"),
            "{}",
            r.text
        );
        assert!(r.text.contains("DO    0x21  00100001  on: DO0 DO5"));
    }
}

#[test]
fn writes_reach_the_module() {
    for protocol in [Protocol::Modbus, Protocol::Ascii] {
        let (model, mut dev) = rig(protocol);
        execute(&C29Command::Do { byte: Some(0x81) }, &mut dev).unwrap();
        assert_eq!(lock(&model).outputs(), 0x81);
        let r = execute(
            &C29Command::Set {
                channel: 0,
                state: OnOff::Off,
            },
            &mut dev,
        )
        .unwrap();
        assert_eq!(lock(&model).outputs(), 0x80);
        assert_eq!(r.json["do"], 0x80);
        let store = |drive_outputs| C29Command::PowerOnValue {
            byte: Some(0x42),
            drive_outputs,
        };
        if protocol == Protocol::Ascii {
            // Without the flag, ASCII refuses a value the outputs do not hold, and says how.
            let e = execute(&store(false), &mut dev).unwrap_err();
            assert_eq!(e.exit_status(), EXIT_USAGE);
            assert!(e.to_string().contains("--drive-outputs"), "{e}");
            assert_eq!(lock(&model).power_on_value(), 0x00);
        }
        execute(&store(true), &mut dev).unwrap();
        assert_eq!(lock(&model).power_on_value(), 0x42);
        assert_eq!(
            lock(&model).outputs(),
            0x80,
            "outputs restored after an ASCII preset"
        );
    }
}

#[test]
fn drive_outputs_is_a_flag_of_setting_a_preset() {
    let a = parse(&["--port", "p", "safe-value", "0x05", "--drive-outputs"]).unwrap();
    assert!(matches!(
        a.command,
        C29Command::SafeValue {
            byte: Some(5),
            drive_outputs: true
        }
    ));
    assert!(parse(&["--port", "p", "power-on-value", "--drive-outputs"]).is_err());
}

#[test]
fn raw_modbus_frame_that_is_not_hex_is_a_usage_error() {
    let (_, mut dev) = rig(Protocol::Modbus);
    let e = execute(
        &C29Command::Raw {
            frame: "$016".into(),
        },
        &mut dev,
    )
    .unwrap_err();
    assert_eq!(e.exit_status(), EXIT_USAGE);
    let r = execute(
        &C29Command::Raw {
            frame: "01 01 00 20 00 08".into(),
        },
        &mut dev,
    )
    .unwrap();
    assert_eq!(r.json["answer"], "01 01 01 FF 11 C8");
}

#[test]
fn watchdog_words_say_what_is_known() {
    let w = |enabled, timeout_tenths, expired| WatchdogInfo {
        enabled,
        timeout_tenths,
        expired,
    };
    assert_eq!(watchdog_text(&w(false, 0, Some(false))), "disabled");
    assert_eq!(
        watchdog_text(&w(true, 15, Some(false))),
        "enabled, timeout 1.5 s"
    );
    assert!(watchdog_text(&w(true, 5, Some(true))).starts_with("expired"));
    assert!(watchdog_text(&w(false, 5, None)).contains("does not say which"));
    assert!(watchdog_text(&w(true, 5, None)).contains("does not report expiry"));
}
