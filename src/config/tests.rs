//! Tests of rig.toml reading: every key, every error with its line, the defaults.

use super::*;
use proptest::prelude::*;

const EXAMPLE: &str = r#"period = "20ms"
on_error = "stop"          # stop (default) | restart | skip
records = "records.jsonl"  # optional
grace = "2s"
wake_latency = "50us"      # auto (default) | off | a duration

[devices.panel]
kind = "trc1000"
unit = 0
safe_relay = 0

[devices.io]
kind = "trp-c29u"
port = "/dev/ttyUSB0"
protocol = "modbus"
id = 1
baud = 9600
checksum = false
timeout = "100ms"
retries = 2
watchdog = "2s"
safe_value = 0x00
power_on_value = 0x00
di_active_low = true
"#;

fn parse(text: &str) -> Result<RigConfig, ConfigError> {
    RigConfig::parse(text, "rig.toml")
}

/// The problems `text` has, as people read them.
fn problems(text: &str) -> Vec<String> {
    match parse(text) {
        Ok(c) => panic!("accepted: {c:?}"),
        Err(e) => {
            assert!(!e.problems().is_empty(), "{e}");
            e.problems().iter().map(|p| p.to_string()).collect()
        }
    }
}

/// The one problem of `text`.
fn problem(text: &str) -> Problem {
    let err = parse(text).unwrap_err();
    match err.problems() {
        [p] => p.clone(),
        other => panic!("expected one problem, got {other:?}"),
    }
}

fn c29u(extra: &str) -> Result<C29uConfig, ConfigError> {
    let text = format!("[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\n{extra}\n");
    let mut c = parse(&text)?;
    match c.devices.remove("io") {
        Some(DeviceConfig::C29u(io)) => Ok(io),
        other => panic!("{other:?}"),
    }
}

fn trc(extra: &str) -> Result<Trc1000Config, ConfigError> {
    let text = format!("[devices.panel]\nkind = \"trc1000\"\n{extra}\n");
    let mut c = parse(&text)?;
    match c.devices.remove("panel") {
        Some(DeviceConfig::Trc1000(p)) => Ok(p),
        other => panic!("{other:?}"),
    }
}

/// The single problem of a C29U table with `extra` lines (which start on line 4).
fn c29u_problem(extra: &str) -> String {
    let text = format!("[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\n{extra}\n");
    problem(&text).to_string()
}

#[test]
fn the_example_reads_as_written() {
    let c = parse(EXAMPLE).unwrap();
    let mut devices = BTreeMap::new();
    devices.insert(
        "panel".to_string(),
        DeviceConfig::Trc1000(Trc1000Config {
            address: Trc1000Address::Unit(0),
            safe_relay: Some(0),
            names: Default::default(),
        }),
    );
    devices.insert(
        "io".to_string(),
        DeviceConfig::C29u(C29uConfig {
            port: Port::Serial("/dev/ttyUSB0".into()),
            protocol: Protocol::Modbus,
            id: 1,
            baud: 9600,
            checksum: false,
            timeout: Duration::from_millis(100),
            retries: 2,
            watchdog: WatchdogTimeout::from_tenths(20),
            safe_value: 0,
            power_on_value: Some(0),
            di_active_low: true,
            frame_gap: FrameGap::Auto,
            script_may_change: ScriptMayChange {
                safe_value: false,
                power_on_value: false,
                watchdog: false,
            },
            names: Default::default(),
        }),
    );
    assert_eq!(
        c,
        RigConfig {
            name: None,
            period: Duration::from_millis(20),
            on_error: ErrorPolicy::Stop,
            records: Some("records.jsonl".into()),
            grace: Duration::from_secs(2),
            stall: None,
            wake_latency: WakeLatency::Limit(Duration::from_micros(50)),
            ui: None,
            force: false,
            ui_token: None,
            ui_read_token: None,
            limits: ScriptLimits::default(),
            mqtt: None,
            devices,
            simulated: Default::default(),
        }
    );
}

#[test]
fn an_empty_file_is_all_defaults_and_no_devices() {
    let c = parse("").unwrap();
    assert_eq!(c, RigConfig::default());
    assert_eq!(c.period, Duration::from_millis(20));
    assert_eq!(c.on_error, ErrorPolicy::Stop);
    assert_eq!(c.records, None);
    assert_eq!(c.grace, Duration::from_secs(1));
    assert_eq!(c.wake_latency, WakeLatency::Auto);
    assert!(c.devices.is_empty());
}

#[test]
fn device_defaults() {
    assert_eq!(
        trc("").unwrap(),
        Trc1000Config {
            address: Trc1000Address::Unit(0),
            safe_relay: None,
            names: Default::default(),
        }
    );
    let io = c29u("").unwrap();
    assert_eq!(
        io,
        C29uConfig::with_defaults(Port::Serial("/dev/ttyUSB0".into()))
    );
    assert_eq!(io.protocol, Protocol::Modbus);
    assert_eq!(io.id, 1);
    assert_eq!(io.baud, 9600);
    assert!(!io.checksum);
    assert_eq!(io.timeout, Duration::from_millis(100));
    assert_eq!(io.retries, 2);
    assert_eq!(io.watchdog, None);
    assert_eq!(io.safe_value, 0);
    assert_eq!(io.power_on_value, None);
    assert!(io.di_active_low);
}

#[test]
fn top_level_keys() {
    let c = parse(
        "period = \"50ms\"\non_error = \"restart\"\ngrace = \"0s\"\nrecords = \"out/r.jsonl\"",
    )
    .unwrap();
    assert_eq!(c.period, Duration::from_millis(50));
    assert_eq!(c.on_error, ErrorPolicy::Restart);
    assert_eq!(c.grace, Duration::ZERO, "grace 0: safe at once");
    assert_eq!(c.records, Some(PathBuf::from("out/r.jsonl")));
    let c = parse("period = \"2.5ms\"\non_error = \"skip\"\ngrace = \"1m\"").unwrap();
    assert_eq!(c.period, Duration::from_micros(2500));
    assert_eq!(c.on_error, ErrorPolicy::Skip);
    assert_eq!(c.on_error.as_str(), "skip");
    assert_eq!(c.grace, Duration::from_secs(60));
    assert_eq!(
        parse("period = \"1.5s\"").unwrap().period,
        Duration::from_millis(1500)
    );
    let wake = |t: &str| parse(&format!("wake_latency = {t}")).unwrap().wake_latency;
    assert_eq!(wake("\"off\""), WakeLatency::Off);
    assert_eq!(wake("\"auto\""), WakeLatency::Auto);
    assert_eq!(wake("\"0us\""), WakeLatency::Limit(Duration::ZERO));
    assert_eq!(
        problems("wake_latency = 0"),
        vec![
            r#"rig.toml:1: wake_latency: 0 is not a wake latency; use "auto", "off" or the longest wake-up a CPU may take ("0us", "50us")"#
        ]
    );
}

#[test]
fn trc1000_keys() {
    assert_eq!(trc("unit = 3").unwrap().address, Trc1000Address::Unit(3));
    assert_eq!(
        trc("device = \"1:4\"").unwrap().address,
        Trc1000Address::BusAddress { bus: 1, address: 4 }
    );
    assert_eq!(
        trc("device = \"255:127\"").unwrap().address,
        Trc1000Address::BusAddress {
            bus: 255,
            address: 127
        }
    );
    assert_eq!(trc("safe_relay = 7").unwrap().safe_relay, Some(7));
}

#[test]
fn c29u_keys() {
    let io = c29u(
        "protocol = \"ascii\"\nid = 0\nbaud = 115200\nchecksum = true\ntimeout = \"250ms\"\n\
         retries = 0\nwatchdog = \"25.5s\"\nsafe_value = 0b1010_0101\npower_on_value = 0xA5\n\
         di_active_low = false",
    )
    .unwrap();
    assert_eq!(io.protocol, Protocol::Ascii);
    assert_eq!(io.id, 0);
    assert_eq!(io.baud, 115_200);
    assert!(io.checksum);
    assert_eq!(io.timeout, Duration::from_millis(250));
    assert_eq!(io.retries, 0);
    assert_eq!(io.watchdog.map(WatchdogTimeout::tenths), Some(255));
    assert_eq!(io.safe_value, 0xA5);
    assert_eq!(io.power_on_value, Some(0xA5));
    assert!(!io.di_active_low);
    assert_eq!(c29u("protocol = \"ascii\"\nid = 255").unwrap().id, 255);
    assert_eq!(c29u("id = 247").unwrap().id, 247);
    assert_eq!(c29u("retries = 10").unwrap().retries, 10);
}

#[test]
fn every_baud_rate_of_the_module() {
    for rate in [1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200] {
        assert_eq!(c29u(&format!("baud = {rate}")).unwrap().baud, rate);
    }
    assert_eq!(
        c29u_problem("baud = 14400"),
        "rig.toml:4: devices.io.baud: 14400 is not a baud rate of the module; \
         use one of 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200"
    );
    assert!(c29u_problem("baud = -9600").contains("is not a baud rate"));
}

#[test]
fn ports_serial_and_tcp() {
    assert_eq!(
        c29u("").unwrap().port.to_string(),
        "/dev/ttyUSB0",
        "the port line of the helper"
    );
    let tcp = |s: &str| {
        let text = format!("[devices.io]\nkind = \"trp-c29u\"\nport = \"{s}\"\n");
        match parse(&text).map(|mut c| c.devices.remove("io")) {
            Ok(Some(DeviceConfig::C29u(io))) => Ok(io.port),
            Ok(other) => panic!("{other:?}"),
            Err(e) => Err(e.to_string()),
        }
    };
    assert_eq!(
        tcp("tcp://moxa.lab:4001"),
        Ok(Port::Tcp {
            host: "moxa.lab".into(),
            port: 4001
        })
    );
    assert_eq!(
        tcp("tcp://[fe80::1]:4001"),
        Ok(Port::Tcp {
            host: "fe80::1".into(),
            port: 4001
        })
    );
    assert_eq!(
        tcp("tcp://[fe80::1]:4001").unwrap().to_string(),
        "tcp://[fe80::1]:4001"
    );
    assert_eq!(
        tcp("tcp://10.0.0.5:4001").unwrap().to_string(),
        "tcp://10.0.0.5:4001"
    );
    assert_eq!(tcp("COM3"), Ok(Port::Serial("COM3".into())));
    for bad in [
        "tcp://host",
        "tcp://:4001",
        "tcp://host:0",
        "tcp://host:70000",
        "udp://h:1",
        "",
        "tcp://h:1/x",
    ] {
        let err = tcp(bad).unwrap_err();
        assert_eq!(
            err,
            format!(
                "rig.toml:3: devices.io.port: {bad:?} is not a port; use a serial device \
                 (\"/dev/ttyUSB0\") or \"tcp://host:port\""
            )
        );
    }
}

#[test]
fn watchdog_times() {
    // A quick module, so that even a 0.1 s watchdog can be fed in time.
    let wd = |s: &str| {
        c29u(&format!("timeout = \"10ms\"\nretries = 0\nwatchdog = {s}"))
            .map(|io| io.watchdog.map(|w| w.tenths()))
    };
    assert_eq!(wd("\"2s\"").unwrap(), Some(20));
    assert_eq!(wd("\"0.1s\"").unwrap(), Some(1));
    assert_eq!(wd("\"100ms\"").unwrap(), Some(1));
    assert_eq!(wd("\"1500ms\"").unwrap(), Some(15));
    assert_eq!(wd("\"25.5s\"").unwrap(), Some(255));
    assert_eq!(wd("\"off\"").unwrap(), None);
    assert_eq!(wd("\"0s\"").unwrap(), None, "0 disables, as on the module");
    for bad in [
        "\"25.6s\"",
        "\"2.05s\"",
        "\"50ms\"",
        "\"1m\"",
        "\"on\"",
        "1",
        "1500",
        "0",
    ] {
        assert_eq!(
            c29u_problem(&format!("watchdog = {bad}")),
            format!(
                "rig.toml:4: devices.io.watchdog: {bad} is not a watchdog time; \
                 use 0.1s to 25.5s in steps of 0.1s, or \"off\""
            ),
            "{bad}"
        );
    }
}

#[test]
fn ids_follow_the_protocol() {
    for (extra, msg) in [
        ("id = 0", "0 is not a Modbus id; use 1-247"),
        ("id = 248", "248 is not a Modbus id; use 1-247"),
        (
            "protocol = \"ascii\"\nid = 256",
            "256 is not an ASCII id; use 0-255",
        ),
        (
            "protocol = \"ascii\"\nid = -1",
            "-1 is not an ASCII id; use 0-255",
        ),
    ] {
        let p = c29u_problem(extra);
        assert!(p.ends_with(&format!("devices.io.id: {msg}")), "{p}");
    }
    // The protocol line may come after the id line: the range still follows it.
    assert_eq!(c29u("id = 0\nprotocol = \"ascii\"").unwrap().id, 0);
}

#[test]
fn the_briefs_example_error() {
    let text = "period = \"20ms\"\n\n[devices.panel]\nkind = \"trc1000\"\n\n\
                [devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\nprotocol = \"modbsu\"\n";
    assert_eq!(
        parse(text).unwrap_err().to_string(),
        r#"rig.toml:9: devices.io.protocol: "modbsu" is not a protocol; use "modbus" or "ascii""#
    );
    let p = problem(text);
    assert_eq!(p.line, 9);
    assert_eq!(p.key, "devices.io.protocol");
    assert_eq!(
        p.kind,
        ProblemKind::BadValue {
            value: "\"modbsu\"".into(),
            reason: r#"is not a protocol; use "modbus" or "ascii""#.into()
        }
    );
}

#[test]
fn bad_values_name_line_and_key() {
    let cases: &[(&str, &str)] = &[
        (
            "period = \"0ms\"",
            r#"rig.toml:1: period: "0ms" is not a period: use above zero up to 10s (each tick reads the inputs the handlers wait for, so a longer period leaves an input change unseen that long; for slow work keep the period and use every("30s", ..))"#,
        ),
        (
            "period = 20",
            r#"rig.toml:1: period: 20 has no unit: write "20ms", "20s" or "20m" (a duration is a number with a unit ("250us", "20ms", "1.5s", "5m", "2h", "1h30m"))"#,
        ),
        (
            "grace = 2.5",
            r#"rig.toml:1: grace: 2.5 has no unit: write "2.5ms", "2.5s" or "2.5m" (a duration is a number with a unit ("250us", "20ms", "1.5s", "5m", "2h", "1h30m"))"#,
        ),
        (
            "grace = \"10\"",
            r#"rig.toml:1: grace: "10" has no unit: write "10ms", "10s" or "10m" (a duration is a number with a unit ("250us", "20ms", "1.5s", "5m", "2h", "1h30m"))"#,
        ),
        (
            "\nperiod = \"0s\"",
            r#"rig.toml:2: period: "0s" is not a period: use above zero up to 10s (each tick reads the inputs the handlers wait for, so a longer period leaves an input change unseen that long; for slow work keep the period and use every("30s", ..))"#,
        ),
        (
            "period = \"10.5s\"",
            r#"rig.toml:1: period: "10.5s" is not a period: use above zero up to 10s (each tick reads the inputs the handlers wait for, so a longer period leaves an input change unseen that long; for slow work keep the period and use every("30s", ..))"#,
        ),
        (
            "period = \"fast\"",
            r#"rig.toml:1: period: "fast" is not a duration; use a number with a unit ("250us", "20ms", "1.5s", "5m", "2h", "1h30m")"#,
        ),
        (
            "period = -5",
            r#"rig.toml:1: period: -5 is not a duration; use a number with a unit ("250us", "20ms", "1.5s", "5m", "2h", "1h30m")"#,
        ),
        (
            "period = nan",
            r#"rig.toml:1: period: nan is not a duration; use a number with a unit ("250us", "20ms", "1.5s", "5m", "2h", "1h30m")"#,
        ),
        (
            "period = true",
            r#"rig.toml:1: period: expected a duration ("20ms", "1.5s"), found a boolean"#,
        ),
        (
            "on_error = \"panic\"",
            r#"rig.toml:1: on_error: "panic" is not an error policy; use "stop", "restart" or "skip""#,
        ),
        (
            "on_error = 1",
            "rig.toml:1: on_error: expected a string, found an integer",
        ),
        (
            "records = \"\"",
            r#"rig.toml:1: records: "" is not a file name"#,
        ),
        (
            "records = [\"a\"]",
            "rig.toml:1: records: expected a string, found an array",
        ),
        (
            "grace = \"-1s\"",
            r#"rig.toml:1: grace: "-1s" is not a duration; use a number with a unit ("250us", "20ms", "1.5s", "5m", "2h", "1h30m")"#,
        ),
        (
            "grace = 1979-05-27",
            "rig.toml:1: grace: expected a duration (\"20ms\", \"1.5s\"), found a date-time",
        ),
        (
            "\n\nwake_latency = \"low\"",
            r#"rig.toml:3: wake_latency: "low" is not a wake latency; use "auto", "off" or the longest wake-up a CPU may take ("0us", "50us")"#,
        ),
        (
            "wake_latency = true",
            r#"rig.toml:1: wake_latency: true is not a wake latency; use "auto", "off" or the longest wake-up a CPU may take ("0us", "50us")"#,
        ),
        (
            "devices = 3",
            "rig.toml:1: devices: expected a table of devices ([devices.NAME]), found an integer",
        ),
        (
            "[devices]\nio = 3",
            "rig.toml:2: devices.io: expected a table ([devices.NAME]), found an integer",
        ),
    ];
    for (text, want) in cases {
        assert_eq!(problems(text), vec![want.to_string()], "{text}");
    }
}

#[test]
fn bad_trc1000_values() {
    let cases: &[(&str, &str)] = &[
        ("unit = 4", "rig.toml:3: devices.panel.unit: 4 is not a unit; use 0-3"),
        ("unit = \"0\"", "rig.toml:3: devices.panel.unit: expected an integer, found a string"),
        ("safe_relay = 8", "rig.toml:3: devices.panel.safe_relay: 8 is not a relay; use 0-7"),
        (
            "device = \"1-4\"",
            r#"rig.toml:3: devices.panel.device: "1-4" is not a USB bus and address; use "BUS:ADDRESS" as lsusb shows them ("1:4"), address 1-127"#,
        ),
        ("device = \"1:0\"", "rig.toml:3: devices.panel.device: \"1:0\" is not a USB bus"),
        ("device = \"1:128\"", "rig.toml:3: devices.panel.device: \"1:128\" is not a USB bus"),
        ("device = \"256:1\"", "rig.toml:3: devices.panel.device: \"256:1\" is not a USB bus"),
        (
            "unit = 1\ndevice = \"1:4\"",
            "rig.toml:4: devices.panel.device: cannot be given together with unit; use one of them",
        ),
        (
            "port = \"/dev/ttyUSB0\"",
            "rig.toml:3: devices.panel.port: unknown key; known keys here: kind, unit, device, safe_relay, sim",
        ),
    ];
    for (extra, want) in cases {
        let text = format!("[devices.panel]\nkind = \"trc1000\"\n{extra}\n");
        let got = problems(&text);
        assert_eq!(got.len(), 1, "{got:?}");
        assert!(got[0].starts_with(want), "{extra}: {got:?}");
    }
}

#[test]
fn bad_c29u_values() {
    let cases: &[(&str, &str)] = &[
        ("protocol = \"rtu\"", r#"rig.toml:4: devices.io.protocol: "rtu" is not a protocol; use "modbus" or "ascii""#),
        (
            "checksum = true",
            "rig.toml:4: devices.io.checksum: true is for the ascii protocol only; Modbus RTU frames always carry a CRC",
        ),
        ("checksum = \"no\"", "rig.toml:4: devices.io.checksum: expected true or false, found a string"),
        ("timeout = \"0ms\"", "rig.toml:4: devices.io.timeout: \"0ms\" is not a timeout; use 1ms to 1s (a silent module costs this per try, and a SIGTERM waits for it)"),
        ("timeout = 250", "rig.toml:4: devices.io.timeout: 250 has no unit: write \"250ms\""),
        ("retries = 11", "rig.toml:4: devices.io.retries: 11 is not a retry count; use 0-10"),
        ("safe_value = 256", "rig.toml:4: devices.io.safe_value: 256 is not a DO byte; use 0-255 (0x00-0xFF, 0b00000000-0b11111111)"),
        ("power_on_value = -1", "rig.toml:4: devices.io.power_on_value: -1 is not a DO byte"),
        // ASCII stores only the current outputs: a power-on value apart from the safe one
        // would have the runner drive the outputs to it (docs/design/safety.md).
        (
            "protocol = \"ascii\"\npower_on_value = 0x0F",
            "rig.toml:5: devices.io.power_on_value: 0x0F differs from safe_value 0x00: an ASCII module stores only its current outputs as its power-on value (manual 8-24), so the runner would have to drive the outputs to it; store it once by hand, when the outputs may take that value (`rigscript c29 --port /dev/ttyUSB0 --protocol ascii --id 1 power-on-value 0x0f --drive-outputs`)",
        ),
        ("di_active_low = 1", "rig.toml:4: devices.io.di_active_low: expected true or false, found an integer"),
        ("id = 99999999999999999999", "rig.toml:4: devices.io.id: 99999999999999999999 is not a Modbus id"),
        (
            "prtocol = \"ascii\"",
            "rig.toml:4: devices.io.prtocol: unknown key (did you mean `protocol`?); known keys here: kind, port, protocol, id, \
             baud, checksum, timeout, retries, watchdog, safe_value, power_on_value, di_active_low, \
             frame_gap",
        ),
        ("safe_relay = 0", "rig.toml:4: devices.io.safe_relay: unknown key; known keys here"),
        (
            "timout = \"50ms\"",
            "rig.toml:4: devices.io.timout: unknown key (did you mean `timeout`?); known keys here: kind,",
        ),
    ];
    for (extra, want) in cases {
        let got = c29u_problem(extra);
        assert!(got.starts_with(want), "{extra}: {got}");
    }
    // With ASCII, checksum may be on.
    assert!(
        c29u("protocol = \"ascii\"\nchecksum = true")
            .unwrap()
            .checksum
    );
}

#[test]
fn missing_and_unknown_kinds() {
    assert_eq!(
        problems("period = \"20ms\"\n\n[devices.io]\nport = \"/dev/ttyUSB0\"\n"),
        vec![r#"rig.toml:3: devices.io.kind: missing; give kind = "trc1000" or kind = "trp-c29u""#]
    );
    assert_eq!(
        problems("[devices.io]\nkind = \"trp-c29\"\nport = \"x\"\n"),
        vec![
            r#"rig.toml:2: devices.io.kind: "trp-c29" is not a device kind; use "trc1000" or "trp-c29u""#
        ]
    );
    assert_eq!(
        problems("[devices.io]\nkind = \"trp-c29u\"\nid = 3\n"),
        vec![
            r#"rig.toml:1: devices.io.port: missing; give the serial port ("/dev/ttyUSB0") or a device server ("tcp://host:port")"#
        ]
    );
}

#[test]
fn a_rig_name_names_a_socket_file_or_is_refused() {
    assert_eq!(
        parse("name = \"bench-2.a_b\"\n").unwrap().name.as_deref(),
        Some("bench-2.a_b")
    );
    for bad in ["", ".hidden", "a/b", "two words", "ü"] {
        let text = format!("name = {bad:?}\n");
        let p = problems(&text);
        assert!(
            p.len() == 1 && p[0].contains("is not a rig name"),
            "{bad:?}: {p:?}"
        );
    }
    let long = format!("name = \"{}\"\n", "x".repeat(65));
    assert_eq!(problems(&long).len(), 1);
}

#[test]
fn unknown_top_level_keys() {
    assert_eq!(
        problems("period = \"20ms\"\nperoid = 30\n"),
        vec!["rig.toml:2: peroid: unknown key (did you mean `period`?); known keys here: name, period, on_error, records, grace, stall, wake_latency, ui, force, ui_token, ui_read_token, limits, mqtt, devices"]
    );
    assert_eq!(
        problems("[device.io]\nkind = \"trc1000\"\n"),
        vec!["rig.toml:1: device: unknown key (did you mean `devices`?); known keys here: name, period, on_error, records, grace, stall, wake_latency, ui, force, ui_token, ui_read_token, limits, mqtt, devices"]
    );
}

#[test]
fn device_names_must_be_identifiers() {
    assert_eq!(
        problems("[devices.\"my io\"]\nkind = \"trc1000\"\n"),
        vec![
            r#"rig.toml:1: devices: "my io" is not a usable device name; use letters, digits and _, starting with a letter or _ (at most 64)"#
        ]
    );
    assert!(!problems("[devices.1st]\nkind = \"trc1000\"\n").is_empty());
    assert!(parse("[devices._panel_2]\nkind = \"trc1000\"\n").is_ok());
    assert!(is_device_name("io"));
    assert!(is_device_name("_x9"));
    assert!(!is_device_name(""));
    assert!(!is_device_name("a-b"));
    assert!(!is_device_name("é"));
    assert!(!is_device_name(&"a".repeat(65)));
}

#[test]
fn every_problem_at_once_in_file_order() {
    let text = "period = 0\nbogus = 1\n\n[devices.panel]\nkind = \"trc1000\"\nunit = 9\n\n\
                [devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\nbaud = 1234\nid = 0\n";
    let err = parse(text).unwrap_err();
    let lines: Vec<(usize, &str)> = err
        .problems()
        .iter()
        .map(|p| (p.line, p.key.as_str()))
        .collect();
    assert_eq!(
        lines,
        vec![
            (1, "period"),
            (2, "bogus"),
            (6, "devices.panel.unit"),
            (11, "devices.io.baud"),
            (12, "devices.io.id"),
        ]
    );
    assert_eq!(err.to_string().lines().count(), 5);
}

#[test]
fn inline_tables_work_too() {
    let c = parse("devices = { panel = { kind = \"trc1000\", unit = 2 } }").unwrap();
    assert_eq!(
        c.devices.get("panel"),
        Some(&DeviceConfig::Trc1000(Trc1000Config {
            address: Trc1000Address::Unit(2),
            safe_relay: None,
            names: Default::default(),
        }))
    );
    assert_eq!(
        problems("\ndevices = { panel = { kind = \"trc1000\", unit = 5 } }"),
        vec!["rig.toml:2: devices.panel.unit: 5 is not a unit; use 0-3"]
    );
}

#[test]
fn toml_syntax_errors_give_line_and_column() {
    let err = parse("period = \"20ms\"\n\n[devices.io\nkind = 1\n").unwrap_err();
    match &err {
        ConfigError::Syntax {
            file, line, column, ..
        } => {
            assert_eq!(file, "rig.toml");
            assert_eq!(*line, 3);
            assert_eq!(*column, 12);
        }
        other => panic!("{other:?}"),
    }
    assert!(
        err.to_string()
            .starts_with("rig.toml:3:12: not valid TOML: "),
        "{err}"
    );
    let dup = parse("period = 1\nperiod = 2\n").unwrap_err();
    assert!(
        dup.to_string()
            .starts_with("rig.toml:2:1: not valid TOML: duplicate key"),
        "{dup}"
    );
    let text = "a = \"é\"\nb = ";
    assert!(matches!(
        parse(text),
        Err(ConfigError::Syntax {
            line: 2,
            column: 5,
            ..
        })
    ));
}

#[test]
fn load_names_the_file_as_given() {
    let dir = std::env::temp_dir().join(format!("rigscript-config-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("bench.toml");
    std::fs::write(&path, "period = \"10ms\"\n").unwrap();
    assert_eq!(
        RigConfig::load(&path).unwrap().period,
        Duration::from_millis(10)
    );
    std::fs::write(&path, "\non_error = \"ignore\"\n").unwrap();
    let shown = RigConfig::load(&path).unwrap_err().to_string();
    assert!(
        shown.starts_with(&format!("{}:2: on_error: ", path.display())),
        "{shown}"
    );
    let missing = dir.join("nope.toml");
    let err = RigConfig::load(&missing).unwrap_err();
    assert!(matches!(err, ConfigError::Read { .. }));
    assert!(err
        .to_string()
        .starts_with(&format!("{}: cannot read: ", missing.display())));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_simulated_default_rig() {
    let c = RigConfig::simulated_default();
    assert_eq!(c.period, DEFAULT_PERIOD);
    assert_eq!(c.on_error, ErrorPolicy::Stop);
    assert_eq!(c.devices.len(), 2);
    match c.devices.get("panel") {
        Some(DeviceConfig::Trc1000(p)) => {
            assert_eq!(p.address, Trc1000Address::Unit(0));
            assert_eq!(p.safe_relay, Some(0));
        }
        other => panic!("{other:?}"),
    }
    match c.devices.get("io") {
        Some(d @ DeviceConfig::C29u(io)) => {
            assert_eq!(d.kind_name(), "trp-c29u");
            assert_eq!(io.port, Port::Simulated);
            assert_eq!(io.protocol, Protocol::Modbus);
            assert_eq!(io.id, 1);
            assert_eq!(io.safe_value, 0);
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn watchdog_timeouts_in_tenths() {
    assert_eq!(WatchdogTimeout::from_tenths(0), None);
    let w = WatchdogTimeout::from_tenths(15).unwrap();
    assert_eq!(w.as_duration(), Duration::from_millis(1500));
    assert_eq!(WatchdogTimeout::from_duration(w.as_duration()), Some(w));
    assert_eq!(
        WatchdogTimeout::from_duration(Duration::from_millis(25_600)),
        None
    );
    assert_eq!(
        WatchdogTimeout::from_duration(Duration::from_millis(150)),
        None
    );
    assert_eq!(WatchdogTimeout::from_duration(Duration::ZERO), None);
    assert_eq!(
        WatchdogTimeout::from_duration(Duration::from_millis(25_500)).map(WatchdogTimeout::tenths),
        Some(255)
    );
}

proptest! {
    #[test]
    fn random_text_never_panics(text in any::<String>()) {
        let _ = parse(&text);
    }

    #[test]
    fn random_values_for_every_key_never_panic(
        key in prop::sample::select(vec![
            "period", "on_error", "records", "grace", "kind", "unit", "device", "safe_relay",
            "port", "protocol", "id", "baud", "checksum", "timeout", "retries", "watchdog",
            "safe_value", "power_on_value", "di_active_low", "frame_gap",
        ]),
        value in prop_oneof![
            any::<i64>().prop_map(|n| n.to_string()),
            any::<f64>().prop_map(|x| format!("{x:?}")),
            "[ -~]{0,12}".prop_map(|s| format!("{s:?}")),
            Just("true".to_string()),
            Just("[1, 2]".to_string()),
        ],
        kind in prop::sample::select(vec!["trc1000", "trp-c29u"]),
    ) {
        let top = format!("{key} = {value}\n");
        let _ = parse(&top);
        let dev = format!("[devices.d]\nkind = \"{kind}\"\nport = \"/dev/x\"\n{key} = {value}\n");
        if let Err(e) = parse(&dev) {
            // Whatever is wrong is reported on a line of the file, never line 0.
            for p in e.problems() {
                prop_assert!(p.line >= 1 && p.line <= 4, "{}", p);
            }
        }
    }
}

#[test]
fn limits_default_and_read() {
    assert_eq!(parse("").unwrap().limits, ScriptLimits::default());
    let c = parse(
        "[limits]\noperations = 5000\nhandler_time = \"250ms\"\nmemory = \"64MiB\"\ntimers = 200\n",
    )
    .unwrap();
    assert_eq!(
        c.limits,
        ScriptLimits {
            operations: 5000,
            handler_time: Duration::from_millis(250),
            memory: 64 << 20,
            timers: 200,
        }
    );
    // A key left out keeps its default.
    let c = parse("[limits]\nmemory = \"1GB\"\n").unwrap();
    assert_eq!(c.limits.memory, 1_000_000_000);
    assert_eq!(c.limits.timers, DEFAULT_TIMERS);
    assert_eq!(c.limits.operations, DEFAULT_OPERATIONS);
    assert_eq!(c.limits.handler_time, DEFAULT_HANDLER_TIME);
}

#[test]
fn bad_limits_name_line_and_key() {
    assert_eq!(
        problems(
            "[limits]\noperations = 0\nhandler_time = \"0s\"\nmemory = 256\ntimers = -1\nram = 1\n"
        ),
        vec![
            "rig.toml:2: limits.operations: 0 is not an operation budget; use 1 or more",
            "rig.toml:3: limits.handler_time: \"0s\" is not a time limit; it must be above zero",
            r#"rig.toml:4: limits.memory: 256 is not a size; use "256MiB", "1GiB", "512MB" (KiB/MiB/GiB count in 1024s, KB/MB/GB in 1000s)"#,
            "rig.toml:5: limits.timers: -1 is not a timer count; use 1 or more",
            "rig.toml:6: limits.ram: unknown key; known keys here: operations, handler_time, memory, timers",
        ]
    );
    assert_eq!(
        problems("[limits]\nmemory = \"1MiB\"\n"),
        vec!["rig.toml:2: limits.memory: \"1MiB\" is too little memory for a run; use at least 16 MiB"]
    );
    assert_eq!(
        problems("limits = 3\n"),
        vec!["rig.toml:1: limits: expected a table ([limits]), found an integer"]
    );
}

#[test]
fn two_entries_for_one_module_name_each_other_with_their_lines() {
    let text = "[devices.a]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\nsafe_value = 0x05\n\n\
                [devices.b]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\nsafe_value = 0xFF\n";
    assert_eq!(
        problems(text),
        vec![
            "rig.toml:6: devices.b: is the same module as devices.a (line 1): TRP-C29U ID 1 on \
             /dev/ttyUSB0; two entries would drive one module with two safe values. Give each \
             module its own ID (`rigscript scan` lists the modules on a line) or remove one entry"
        ]
    );
    // Other IDs on the line, or the same ID on another line, are fine.
    parse(&text.replace("safe_value = 0xFF", "id = 2")).unwrap();
    parse(&text.replace(
        "port = \"/dev/ttyUSB0\"\nsafe_value = 0xFF",
        "port = \"/dev/ttyUSB1\"",
    ))
    .unwrap();
}

#[test]
fn modules_on_one_line_at_two_speeds_clash() {
    let text =
        "[devices.b]\nkind = \"trp-c29u\"\nport = \"tcp://gw:4001\"\nid = 2\nbaud = 19200\n\n\
                [devices.a]\nkind = \"trp-c29u\"\nport = \"tcp://gw:4001\"\n";
    let p = problems(text);
    assert_eq!(p.len(), 1, "{p:?}");
    assert!(
        p[0].starts_with(
            "rig.toml:7: devices.a: is on the same line as devices.b (line 1): tcp://gw:4001 at \
             9600 baud, and 19200 baud there"
        ),
        "{p:?}"
    );
}

#[test]
fn two_entries_for_one_board_clash() {
    let text = "[devices.p]\nkind = \"trc1000\"\n\n[devices.q]\nkind = \"trc1000\"\nunit = 0\n";
    let p = problems(text);
    assert_eq!(p.len(), 1, "{p:?}");
    assert!(
        p[0].starts_with(
            "rig.toml:4: devices.q: is the same board as devices.p (line 1): TRC1000 unit 0;"
        ),
        "{p:?}"
    );
    parse(&text.replace("unit = 0", "unit = 1")).unwrap();
}

#[test]
fn a_watchdog_that_cannot_be_fed_in_time_is_refused_with_the_arithmetic() {
    // Default timing: 100 ms timeout, 2 retries, Modbus at 9600 baud on a serial port. A
    // silent module costs 3 x (100 ms settling + 16.7 ms request + 100 ms timeout) = 650 ms;
    // then the feed: 100 ms settling + 8.3 ms request; 20 ms to wake: 778 ms late at worst.
    let p = c29u_problem("watchdog = \"0.8s\"");
    assert!(
        p.starts_with(
            "rig.toml:4: devices.io.watchdog: \"0.8s\" is too short for this rig: a feed may \
             reach the module 778ms after it is due"
        ),
        "{p}"
    );
    for part in [
        "waiting for the longest exchange 650ms (io: 3 tries x (100ms silence + 16.7ms request \
         + 100ms timeout)), then 100ms silence + 8.33ms request on its line, 20ms for the loop \
         to wake), which leaves 21.7ms",
        "of the 800ms between feeds, less than a tenth; use a watchdog of at least 0.9s, or \
         shorter timeouts or fewer retries",
    ] {
        assert!(p.contains(part), "{part}: {p}");
    }
    c29u("watchdog = \"0.9s\"").unwrap();
    // One slow module on the line makes every watchdog of the rig wait for it.
    let slow = "[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\nwatchdog = \"3s\"\n\n\
                [devices.slow]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB1\"\ntimeout = \"1s\"\n\
                retries = 1\n";
    let p = problems(slow);
    assert_eq!(p.len(), 1, "{p:?}");
    assert!(
        p[0].starts_with("rig.toml:4: devices.io.watchdog: \"3s\" is too short"),
        "{p:?}"
    );
    assert!(p[0].contains("(slow: 2 tries x (1s silence + "), "{p:?}");
    parse(&slow.replace("retries = 1", "retries = 0")).unwrap();
}

#[test]
fn feeds_come_at_a_quarter_of_the_timeout_or_sooner_when_exchanges_can_be_long() {
    let c =
        parse("[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\nwatchdog = \"1s\"\n")
            .unwrap();
    let t = feeding::feed_timing(&c.devices, "io").unwrap();
    assert_eq!(t.late_by().as_millis(), 778);
    let ms = Duration::from_millis;
    assert_eq!(t.interval(ms(1000)).map(|i| i.as_millis()), Some(221));
    assert_eq!(t.interval(ms(4000)), Some(ms(1000)), "a quarter");
    assert_eq!(t.interval(ms(800)), None, "less than a tenth left");
    assert!(feeding::feed_timing(&c.devices, "nope").is_none());
}

#[test]
fn script_may_change_lists_what_a_script_may_change_of_what_rig_toml_sets() {
    let io = c29u("").unwrap();
    assert_eq!(
        io.script_may_change,
        ScriptMayChange::ALL,
        "nothing set here"
    );
    let io = c29u("safe_value = 5\nwatchdog = \"2s\"").unwrap();
    assert_eq!(
        io.script_may_change,
        ScriptMayChange {
            safe_value: false,
            power_on_value: true,
            watchdog: false
        }
    );
    let io = c29u("safe_value = 5\nwatchdog = \"2s\"\nscript_may_change = [\"watchdog\"]").unwrap();
    assert!(io.script_may_change.watchdog && !io.script_may_change.safe_value);
    for (bad, shown) in [("[\"safe\"]", "\"safe\""), ("[1]", "1")] {
        assert_eq!(
            c29u_problem(&format!("safe_value = 5\nscript_may_change = {bad}")),
            format!(
                "rig.toml:5: devices.io.script_may_change: {shown} is not a setting a script \
                 may be allowed to change; use \"safe_value\", \"power_on_value\" or \"watchdog\""
            )
        );
    }
    assert!(
        c29u_problem("script_may_change = \"watchdog\"").contains("expected a list of settings")
    );
}

#[test]
fn a_device_marked_sim_is_simulated_while_the_others_are_real() {
    let c = parse(
        "[devices.panel]\nkind = \"trc1000\"\nsim = true\n\
         [devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\n\
         [devices.spare]\nkind = \"trp-c29u\"\nid = 2\nsim = true\n",
    )
    .unwrap();
    assert!(c.is_simulated("panel"));
    assert!(c.is_simulated("spare"), "a simulated module needs no port");
    assert!(!c.is_simulated("io"));
    assert!(c.has_real_devices());
    let all_sim = parse("[devices.panel]\nkind = \"trc1000\"\nsim = true\n").unwrap();
    assert!(!all_sim.has_real_devices(), "nothing outlives the runner");
    assert!(problems("[devices.io]\nkind = \"trp-c29u\"\nid = 2\n")
        .iter()
        .any(|p| p.contains("port")));
    assert!(
        problems("[devices.panel]\nkind = \"trc1000\"\nsim = 1\n")
            .iter()
            .any(|p| p.contains("devices.panel.sim")),
        "{:?}",
        problems("[devices.panel]\nkind = \"trc1000\"\nsim = 1\n")
    );
}

#[test]
fn ui_names_the_web_page_s_address_and_a_host_name_is_refused() {
    let c = parse("ui = \"127.0.0.1:0\"\n").unwrap();
    assert_eq!(c.ui, Some("127.0.0.1:0".parse().unwrap()));
    assert_eq!(parse("").unwrap().ui, None);
    let why = problems("ui = \"localhost:7878\"\n").join("\n");
    assert!(why.contains("is not an address"), "{why}");
}

#[test]
fn ui_tokens_are_read_kept_out_of_debug_and_a_short_one_is_refused_unshown() {
    let c = parse("ui_token = \"c0ntrol-token\"\nui_read_token = \"look-only-1\"\n").unwrap();
    assert_eq!(
        c.ui_token.as_ref().map(|s| s.expose()),
        Some("c0ntrol-token")
    );
    assert_eq!(
        c.ui_read_token.as_ref().map(|s| s.expose()),
        Some("look-only-1")
    );
    assert!(!format!("{c:?}").contains("c0ntrol-token"));
    let why = problems("ui_token = \"abc\"\n").join("\n");
    assert!(why.contains("at least 8 characters"), "{why}");
    assert!(!why.contains("\"abc\""), "the token is not shown: {why}");
}

#[test]
fn the_stall_limit_defaults_to_ten_periods_within_bounds_and_is_checked() {
    let config = parse("").unwrap();
    assert_eq!(config.stall, None);
    assert_eq!(
        config.stall_limit(Duration::from_millis(10)),
        Duration::from_secs(1)
    );
    assert_eq!(
        config.stall_limit(Duration::from_secs(3)),
        Duration::from_secs(30)
    );
    assert_eq!(
        config.stall_limit(Duration::from_secs(10)),
        Duration::from_secs(60)
    );
    let set = parse("stall = \"2s\"").unwrap();
    assert_eq!(
        set.stall_limit(Duration::from_secs(3)),
        Duration::from_secs(2)
    );
    for bad in ["\"100ms\"", "\"2m\"", "3"] {
        let got = problems(&format!("stall = {bad}"));
        assert_eq!(got.len(), 1, "{bad}: {got:?}");
        assert!(got[0].contains("stall"), "{got:?}");
    }
    assert!(problems("stall = \"100ms\"")[0].contains("500ms to 60s"));
}
