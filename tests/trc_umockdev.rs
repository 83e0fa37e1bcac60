//! The real `rigscript trc` binary against an emulated TRC1000 (umockdev): libusb sees a low-speed
//! 0D59:02AC board whose IN answers come from the simulator, so the CLI's output is checked
//! against the model, and OUT packets must match the script byte for byte (umockdev fails an OUT
//! that matches no line with an I/O error).

use crate::common::{require_tool, stderr, stdout, TempDir};
use rigscript::link::far_end::PacketDevice;
use rigscript::protocol::trc1000::{Command, Packet, Relay, Rotary};
use rigscript::sim::trc1000::Trc1000Sim;
use std::fmt::Write as _;
use std::path::Path;
use std::process::Output;

const BIN: &str = env!("CARGO_BIN_EXE_rigscript");

fn hex(bytes: &[u8]) -> String {
    bytes.iter().fold(String::new(), |mut s, b| {
        let _ = write!(s, "{b:02X}");
        s
    })
}

/// Device + configuration descriptors of a TRC1000: USB 1.1 low speed, vendor 0D59, one HID
/// interface with interrupt endpoints 0x82 IN and 0x01 OUT of 8 bytes.
fn descriptors(product_id: u16) -> Vec<u8> {
    let [pid_lo, pid_hi] = product_id.to_le_bytes();
    let device = [
        0x12, 0x01, 0x10, 0x01, // bLength, DEVICE, bcdUSB 1.10
        0x00, 0x00, 0x00,
        0x08, // class/subclass/protocol per interface, ep0 8 bytes (low speed)
        0x59, 0x0D, pid_lo, pid_hi, // idVendor 0D59, idProduct
        0x00, 0x01, 0x00, 0x00, 0x00, 0x01, // bcdDevice 1.00, no strings, 1 configuration
    ];
    let rest = [
        0x09, 0x04, 0x00, 0x00, 0x02, 0x03, 0x00, 0x00, 0x00, // interface 0, 2 endpoints, HID
        0x09, 0x21, 0x10, 0x01, 0x00, 0x01, 0x22, 0x1C,
        0x00, // HID 1.10, one report descriptor
        0x07, 0x05, 0x82, 0x03, 0x08, 0x00, 0x0A, // EP 0x82 IN, interrupt, 8 bytes, 10 ms
        0x07, 0x05, 0x01, 0x03, 0x08, 0x00, 0x0A, // EP 0x01 OUT, interrupt, 8 bytes, 10 ms
    ];
    let total = u16::try_from(9 + rest.len()).unwrap().to_le_bytes();
    let config = [
        0x09, 0x02, total[0], total[1], 0x01, 0x01, 0x00, 0x80, 0x32, // 1 interface, 100 mA
    ];
    [&device[..], &config[..], &rest[..]].concat()
}

/// The umockdev description of one board at `bus`:`address`.
fn device_description(bus: u8, address: u8, unit: u8) -> String {
    let pid = 0x02AC + u16::from(unit);
    let d = hex(&descriptors(pid));
    format!(
        "P: /devices/pci0000:00/0000:00:14.0/usb{bus}/{bus}-{address}\n\
         N: bus/usb/{bus:03}/{address:03}={d}\n\
         E: BUSNUM={bus:03}\n\
         E: DEVNAME=/dev/bus/usb/{bus:03}/{address:03}\n\
         E: DEVNUM={address:03}\n\
         E: DEVTYPE=usb_device\n\
         E: DRIVER=usb\n\
         E: PRODUCT=d59/{pid:x}/100\n\
         E: SUBSYSTEM=usb\n\
         E: TYPE=0/0/0\n\
         A: bConfigurationValue=1\n\
         A: bDeviceClass=00\n\
         A: bNumConfigurations=1\n\
         A: bNumInterfaces= 1\n\
         A: busnum={bus}\\n\n\
         A: devnum={address}\\n\n\
         A: devpath={address}\n\
         A: idProduct={pid:04x}\n\
         A: idVendor=0d59\n\
         A: speed=1.5\\n\n\
         H: descriptors={d}\n\n"
    )
}

/// An ioctl script: each OUT packet, followed by the IN packets that answer it.
#[derive(Default)]
struct Script(String);

impl Script {
    fn out(&mut self, packet: Packet) -> &mut Self {
        let _ = writeln!(
            self.0,
            "USBDEVFS_REAPURBNDELAY 0 1 1 0 0 8 8 0 {}",
            hex(&packet)
        );
        self
    }

    fn answer(&mut self, packet: Packet) -> &mut Self {
        let _ = writeln!(
            self.0,
            " USBDEVFS_REAPURBNDELAY 0 1 130 0 0 8 8 0 {}",
            hex(&packet)
        );
        self
    }

    /// `command` OUT, answered by whatever the simulator answers.
    fn ask(&mut self, sim: &mut Trc1000Sim, command: Command) -> &mut Self {
        let packet = command.encode();
        self.out(packet);
        if let Some(answer) = sim.receive(&packet) {
            self.answer(answer);
        }
        self
    }
}

/// Runs `rigscript trc ARGS` with `devices` emulated and `script` on board 001:002.
fn run_trc(dir: &TempDir, devices: &str, script: Option<&Script>, args: &[&str]) -> Output {
    let args: Vec<&str> = std::iter::once("trc").chain(args.iter().copied()).collect();
    run_rigscript(dir, devices, script, &args)
}

/// Runs `rigscript ARGS` with `devices` emulated and `script` on board 001:002.
fn run_rigscript(dir: &TempDir, devices: &str, script: Option<&Script>, args: &[&str]) -> Output {
    require_tool("umockdev-run", "umockdev");
    let dev = dir.file("trc.umockdev", devices);
    let mut cmd = std::process::Command::new("umockdev-run");
    cmd.arg("-d").arg(&dev);
    if let Some(script) = script {
        let ioctl = dir.file("trc.ioctl", &script.0);
        cmd.arg("-i").arg(format!("/dev/bus/usb/001/002={ioctl}"));
    }
    cmd.arg("--").arg(BIN).args(args);
    cmd.output().expect("run umockdev-run")
}

fn json(o: &Output) -> serde_json::Value {
    serde_json::from_slice(&o.stdout)
        .unwrap_or_else(|e| panic!("not JSON ({e}): {}\nstderr: {}", stdout(o), stderr(o)))
}

fn one_board() -> String {
    device_description(1, 2, 0)
}

#[test]
#[ignore = "needs umockdev (tier 2: .ci/run installs it)"]
fn list_shows_each_board_with_its_unit_and_bus_address() {
    let dir = TempDir::new("list");
    let o = run_trc(&dir, &one_board(), None, &["list"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert_eq!(stdout(&o), "unit 0  001:002  (0d59:02ac)\n");

    let two = one_board() + device_description(1, 3, 1).as_str();
    let o = run_trc(&dir, &two, None, &["--json", "list"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let v = json(&o);
    let boards = v["boards"].as_array().unwrap();
    assert_eq!(boards.len(), 2, "{v}");
    assert_eq!(boards[0]["unit"], 0);
    assert_eq!(boards[0]["device"], "001:002");
    assert_eq!(boards[1]["unit"], 1);
    assert_eq!(boards[1]["device"], "001:003");
    assert_eq!(boards[1]["product_id"], "02ad");
}

#[test]
#[ignore = "needs umockdev (tier 2: .ci/run installs it)"]
fn inputs_reports_the_switches_pressed_on_the_model() {
    let mut sim = Trc1000Sim::new();
    for s in ["S41", "S3", "S27", "S38"] {
        sim.press(s).unwrap();
    }
    let expected = sim.switches().pressed_names();
    let mut script = Script::default();
    script.ask(&mut sim, Command::RequestInput);

    let dir = TempDir::new("inputs");
    let o = run_trc(&dir, &one_board(), Some(&script), &["inputs", "--json"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert_eq!(json(&o), serde_json::json!({ "pressed": expected }));
    assert_eq!(expected, vec!["S3", "S27", "S38", "S41"]);

    let o = run_trc(&dir, &one_board(), Some(&script), &["inputs"]);
    assert_eq!(stdout(&o), "S3 S27 S38 S41\n");
}

#[test]
#[ignore = "needs umockdev (tier 2: .ci/run installs it)"]
fn rotaries_reports_the_turned_counters_of_the_model() {
    let mut sim = Trc1000Sim::new();
    sim.turn("S41A", 6).unwrap();
    sim.turn("S44A", 3).unwrap();
    sim.turn("S44B", 5).unwrap();
    sim.turn("S40", -2).unwrap();
    sim.turn("S38", 300).unwrap();
    let mut script = Script::default();
    script
        .ask(&mut sim, Command::RequestRotary0)
        .ask(&mut sim, Command::RequestRotary1);

    let dir = TempDir::new("rotaries");
    let o = run_trc(&dir, &one_board(), Some(&script), &["--json", "rotaries"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let v = json(&o);
    let map = v["rotaries"].as_object().unwrap();
    assert_eq!(map.len(), 14);
    for r in Rotary::ALL {
        assert_eq!(map[r.name()], sim.rotaries().get(r), "{}", r.name());
    }
    assert_eq!(map["S40"], 254);
    assert_eq!(map["S38"], 44);
}

#[test]
#[ignore = "needs umockdev (tier 2: .ci/run installs it)"]
fn relay_5_sends_exactly_05_14() {
    let mut script = Script::default();
    script.out([0x05, 0x14, 0, 0, 0, 0, 0, 0]);
    let dir = TempDir::new("relay");
    let o = run_trc(&dir, &one_board(), Some(&script), &["relay", "5"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(stdout(&o).contains("relay 5"), "{}", stdout(&o));

    // The same script refuses any other packet, so the check above is on the exact bytes.
    let o = run_trc(&dir, &one_board(), Some(&script), &["relay", "4"]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
}

#[test]
#[ignore = "needs umockdev (tier 2: .ci/run installs it)"]
fn a_stale_answer_before_the_real_one_is_dropped() {
    let mut sim = Trc1000Sim::new();
    sim.press("S9").unwrap();
    let mut script = Script::default();
    script
        .out(Command::RequestInput.encode())
        .answer([0xC3, 1, 2, 3, 4, 5, 6, 7])
        .answer(sim.receive(&Command::RequestInput.encode()).unwrap());
    let dir = TempDir::new("stale");
    let o = run_trc(&dir, &one_board(), Some(&script), &["inputs", "--trace"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert_eq!(stdout(&o), "S9\n");
    // --trace shows the request, the stale packet and the answer, in order.
    let err = stderr(&o);
    let trace: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with(">>") || l.starts_with("<<"))
        .collect();
    assert_eq!(
        trace,
        [
            ">> 41 00 00 00 00 00 00 00",
            "<< C3 01 02 03 04 05 06 07",
            "<< C1 00 01 00 00 00 00 00"
        ]
    );
}

#[test]
#[ignore = "needs umockdev (tier 2: .ci/run installs it)"]
fn a_board_chosen_by_bus_address_is_used() {
    let mut sim = Trc1000Sim::new();
    sim.press("S45").unwrap();
    let mut script = Script::default();
    script.ask(&mut sim, Command::RequestInput);
    let dir = TempDir::new("busaddr");
    let o = run_trc(
        &dir,
        &one_board(),
        Some(&script),
        &["--device", "001:002", "inputs"],
    );
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert_eq!(stdout(&o), "S45\n");

    let o = run_trc(&dir, &one_board(), None, &["--device", "001:009", "inputs"]);
    assert_eq!(o.status.code(), Some(3), "{}", stderr(&o));
    assert!(stderr(&o).contains("001:009"), "{}", stderr(&o));
}

#[test]
#[ignore = "needs umockdev (tier 2: .ci/run installs it)"]
fn a_missing_unit_exits_3_and_says_what_to_try() {
    let dir = TempDir::new("missing");
    let o = run_trc(&dir, &one_board(), None, &["--unit", "1", "inputs"]);
    assert_eq!(o.status.code(), Some(3), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(err.contains("TRC1000 unit 1"), "{err}");
    assert!(err.contains("not found"), "{err}");
    assert!(err.contains("rigscript trc list"), "{err}");
    assert!(stdout(&o).is_empty());
}

/// Without umockdev, on a machine with no USB at all, listing finds nothing and is not an error.
#[test]
fn without_usb_list_is_empty_and_succeeds() {
    let o = std::process::Command::new(BIN)
        .args(["trc", "--json", "list"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    if !Path::new("/dev/bus/usb").exists() {
        assert_eq!(json(&o), serde_json::json!({ "boards": [] }));
        let o = std::process::Command::new(BIN)
            .args(["trc", "inputs"])
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(3), "{}", stderr(&o));
    }
}

#[test]
#[ignore = "needs umockdev (tier 2: .ci/run installs it)"]
fn monitor_prints_presses_and_signed_turns_and_stops_cleanly_on_ctrl_c() {
    let mut sim = Trc1000Sim::new();
    sim.turn("S40", 1).unwrap();
    let mut script = Script::default();
    let poll = |sim: &mut Trc1000Sim, script: &mut Script| {
        script
            .ask(sim, Command::RequestInput)
            .ask(sim, Command::RequestRotary0)
            .ask(sim, Command::RequestRotary1);
    };
    poll(&mut sim, &mut script); // the starting state: no events for it
    sim.press("S3").unwrap();
    sim.turn("S41A", 2).unwrap();
    sim.turn("S40", -3).unwrap();
    // Enough unchanged polls (20 ms apart) that the script outlasts the wait for the first event.
    for _ in 0..500 {
        poll(&mut sim, &mut script);
    }
    let dir = TempDir::new("monitor");
    let out = dir.path("monitor.out");
    // Inside the emulation: start the monitor, wait for its first event, then Ctrl-C it.
    let shell = "\"$RIGSCRIPT\" trc monitor > \"$OUT\" & pid=$!; n=0; \
                 while ! grep -q pressed \"$OUT\" && [ $n -lt 500 ]; do sleep 0.02; n=$((n+1)); done; \
                 kill -INT $pid; wait $pid";
    require_tool("umockdev-run", "umockdev");
    let dev = dir.file("trc.umockdev", &one_board());
    let ioctl = dir.file("trc.ioctl", &script.0);
    let mut cmd = std::process::Command::new("umockdev-run");
    cmd.arg("-d")
        .arg(&dev)
        .arg("-i")
        .arg(format!("/dev/bus/usb/001/002={ioctl}"))
        .args(["--", "sh", "-c", shell])
        .env("RIGSCRIPT", BIN)
        .env("OUT", &out);
    let o = cmd.output().expect("run umockdev-run");
    let text = std::fs::read_to_string(&out).unwrap_or_default();
    assert_eq!(o.status.code(), Some(0), "{}\n{text}", stderr(&o));
    assert_eq!(text, "S3 pressed\nS41A +2 (now 2)\nS40 -3 (now 254)\n");
}

#[test]
#[ignore = "needs umockdev (tier 2: .ci/run installs it)"]
fn safe_selects_the_safe_relay_and_confirms_it_with_a_request_after_it() {
    // What the guardian does for a board when its runner died: the relay selection gets no
    // answer of its own, so the request after it is what confirms that a board took it.
    let mut sim = Trc1000Sim::new();
    let mut script = Script::default();
    script
        .ask(&mut sim, Command::SelectRelay(Relay::new(3).unwrap()))
        .ask(&mut sim, Command::RequestInput);
    let dir = TempDir::new("safe");
    let config = dir.file(
        "rig.toml",
        "[devices.panel]\nkind = \"trc1000\"\nunit = 0\nsafe_relay = 3\n",
    );
    let o = run_rigscript(
        &dir,
        &one_board(),
        Some(&script),
        &["safe", "--config", &config],
    );
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert_eq!(stdout(&o), "panel relay 3 (confirmed)\n");
    assert_eq!(sim.relay().number(), 3);

    // A board that takes the selection but never answers is not confirmed.
    let mut silent = Script::default();
    silent.out(Command::SelectRelay(Relay::new(3).unwrap()).encode());
    let o = run_rigscript(
        &dir,
        &one_board(),
        Some(&silent),
        &["safe", "--config", &config],
    );
    assert_ne!(o.status.code(), Some(0), "{}", stdout(&o));
    assert!(stderr(&o).contains("panel NOT confirmed"), "{}", stderr(&o));
}
