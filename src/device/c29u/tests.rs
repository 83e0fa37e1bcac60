//! Driver tests over in-memory links to the simulator, in virtual time, for both protocols.

use super::*;
use crate::link::far_end::ByteDevice;
use crate::link::memory::MemoryByteLink;
use crate::sim::c29u::{C29uModel as Model, Eeprom, ModuleConfig};
use crate::sim::c29u_line::{lock, MultiDrop, SharedModel, SimulatedC29u};
use crate::time::clock::{Clock, VirtualClock};
use std::sync::{Arc, Mutex};

struct Rig {
    clock: VirtualClock,
    model: SharedModel,
    driver: C29u,
}

fn model(protocol: Protocol, clock: &VirtualClock, id: u8, checksum: bool) -> SimulatedC29u {
    let eeprom = Eeprom {
        config: ModuleConfig {
            id,
            checksum,
            ..ModuleConfig::factory()
        },
        ..Eeprom::factory()
    };
    SimulatedC29u::new(Model::new(protocol, Arc::new(clock.clone()), eeprom))
}

fn rig_with(protocol: Protocol, checksum: bool) -> Rig {
    let clock = VirtualClock::at_epoch();
    let sim = model(protocol, &clock, 1, checksum);
    let model = sim.model();
    let link = MemoryByteLink::new(sim, "C29U").with_clock(Arc::new(clock.clone()));
    let options = C29uOptions {
        protocol,
        checksum,
        ..C29uOptions::default()
    };
    let driver = C29u::new(share(Box::new(link)), Arc::new(clock.clone()), options).unwrap();
    Rig {
        clock,
        model,
        driver,
    }
}

fn both() -> [Rig; 3] {
    [
        rig_with(Protocol::Ascii, false),
        rig_with(Protocol::Ascii, true),
        rig_with(Protocol::Modbus, false),
    ]
}

#[test]
fn inputs_are_logical_and_raw_is_active_low() {
    for mut r in both() {
        lock(&r.model).set_inputs(0b0011_0000);
        assert_eq!(r.driver.read_inputs().unwrap(), 0b0011_0000);
        assert_eq!(r.driver.read_inputs_raw().unwrap(), 0b1100_1111);
        let io = r.driver.read_io().unwrap();
        assert_eq!((io.outputs, io.inputs, io.inputs_raw), (0, 0x30, 0xCF));
    }
}

#[test]
fn outputs_byte_and_channel() {
    for mut r in both() {
        r.driver.write_outputs(0x21).unwrap();
        assert_eq!(lock(&r.model).outputs(), 0x21);
        r.driver.write_output(7, true).unwrap();
        r.driver.write_output(0, false).unwrap();
        assert_eq!(r.driver.read_outputs().unwrap(), 0xA0);
        assert!(matches!(
            r.driver.write_output(8, true),
            Err(C29uError::InvalidArgument(_))
        ));
    }
}

#[test]
fn counters_clear_and_save_across_reset() {
    for mut r in both() {
        lock(&r.model).pulse(2, 23).unwrap();
        lock(&r.model).pulse(5, 7).unwrap();
        assert_eq!(r.driver.read_counter(2).unwrap(), 23);
        assert_eq!(r.driver.read_counters().unwrap(), [0, 0, 23, 0, 0, 7, 0, 0]);
        r.driver.clear_counter(2).unwrap();
        assert_eq!(r.driver.read_counters().unwrap(), [0, 0, 0, 0, 0, 7, 0, 0]);
        r.driver.save_counters().unwrap();
        lock(&r.model).pulse(5, 1).unwrap();
        r.driver.reset().unwrap();
        assert_eq!(
            r.driver.read_counters().unwrap(),
            [0, 0, 0, 0, 0, 7, 0, 0],
            "unsaved count lost"
        );
        r.driver.clear_counters().unwrap();
        assert_eq!(r.driver.read_counters().unwrap(), [0; 8]);
    }
}

#[test]
fn latches_are_logical_like_inputs_and_raw_as_reported() {
    // DI1 energized then released: wire 0 then 1, so it latched low and high; DI2 energized.
    for active_low in [true, false] {
        let mut r = rig_with(Protocol::Modbus, false);
        r.driver.options.di_active_low = active_low;
        lock(&r.model).set_inputs(0x02);
        lock(&r.model).set_inputs(0x04);
        let l = r.driver.read_latches().unwrap();
        assert_eq!((l.low, l.high), (0x06, 0x02), "as the module reports them");
        let logical = if active_low {
            (0x06, 0x02)
        } else {
            (0x02, 0x06)
        };
        assert_eq!(
            (l.energized, l.released),
            logical,
            "active_low {active_low}"
        );
        // The inputs follow the same polarity.
        let inputs = r.driver.read_inputs().unwrap();
        assert_eq!(inputs, if active_low { 0x04 } else { 0xFB });
    }
}

#[test]
fn latches_read_and_clear() {
    for mut r in both() {
        lock(&r.model).set_inputs(0x02);
        lock(&r.model).set_inputs(0x00);
        let latches = r.driver.read_latches().unwrap();
        assert_eq!((latches.low, latches.high), (0x02, 0x02));
        r.driver.clear_latches().unwrap();
        let latches = r.driver.read_latches().unwrap();
        assert_eq!((latches.low, latches.high), (0, 0));
    }
}

#[test]
fn watchdog_fires_to_safe_value_refuses_writes_and_host_ok_keeps_it_alive() {
    for mut r in both() {
        r.driver
            .store_preset(Preset::Safe, 0x14, PresetWrite::DriveOutputs)
            .unwrap();
        assert_eq!(r.driver.safe_value().unwrap(), 0x14);
        r.driver.write_outputs(0x01).unwrap();
        r.driver
            .set_watchdog(Some(Duration::from_millis(500)))
            .unwrap();
        let w = r.driver.watchdog().unwrap();
        assert!(w.enabled);
        assert_eq!(w.timeout_tenths, 5);
        for _ in 0..20 {
            r.clock.advance(Duration::from_millis(400));
            r.driver.host_ok().unwrap();
        }
        r.driver.write_outputs(0x03).unwrap();
        r.clock.advance(Duration::from_millis(600));
        assert_eq!(r.driver.read_outputs().unwrap(), 0x14);
        match r.driver.write_outputs(0x00) {
            Err(C29uError::SafeMode { id: 1, .. }) => {}
            other => panic!("expected safe mode, got {other:?}"),
        }
        assert!(matches!(
            r.driver.write_output(1, true),
            Err(C29uError::SafeMode { .. })
        ));
        r.driver.set_watchdog(None).unwrap();
        r.driver.write_outputs(0x00).unwrap();
        assert_eq!(lock(&r.model).outputs(), 0x00);
    }
}

#[test]
fn power_on_value_after_reset_and_reset_flag() {
    for mut r in both() {
        r.driver
            .store_preset(Preset::PowerOn, 0x13, PresetWrite::DriveOutputs)
            .unwrap();
        assert_eq!(r.driver.power_on_value().unwrap(), 0x13);
        assert_eq!(
            lock(&r.model).outputs(),
            0x00,
            "setting the value leaves the outputs as they were"
        );
        r.driver.take_reset_flag().unwrap();
        assert!(!r.driver.take_reset_flag().unwrap());
        r.driver.reset().unwrap();
        assert!(r.driver.take_reset_flag().unwrap());
        assert_eq!(r.driver.read_outputs().unwrap(), 0x13);
        r.driver.write_outputs(0x42).unwrap();
        r.driver.save_outputs_as(Preset::Safe).unwrap();
        assert_eq!(r.driver.safe_value().unwrap(), 0x42);
    }
}

#[test]
fn name_and_firmware_per_protocol() {
    let mut r = rig_with(Protocol::Ascii, false);
    assert_eq!(r.driver.name().unwrap(), "TRPC29");
    r.driver.set_name("ABCDE").unwrap();
    assert_eq!(r.driver.name().unwrap(), "ABCDE");
    assert!(matches!(
        r.driver.set_name("TOOLONG"),
        Err(C29uError::InvalidArgument(_))
    ));
    assert_eq!(r.driver.firmware().unwrap().date, Some((2009, 7, 3)));

    let mut r = rig_with(Protocol::Modbus, false);
    assert_eq!(r.driver.name().unwrap(), "C29");
    assert!(matches!(
        r.driver.set_name("X"),
        Err(C29uError::Unsupported { .. })
    ));
    assert_eq!(r.driver.firmware().unwrap().date, Some((2009, 7, 3)));
}

#[test]
fn configure_changes_id_and_the_driver_follows() {
    for mut r in both() {
        r.driver
            .configure(&ConfigChange {
                id: Some(5),
                baud: Some(19200),
                ..ConfigChange::default()
            })
            .unwrap();
        assert_eq!(lock(&r.model).config().id, 5);
        assert_eq!(lock(&r.model).config().baud_code, 0x07);
        assert_eq!(r.driver.options().id, 5);
        r.driver.write_outputs(0x55).unwrap();
        assert_eq!(lock(&r.model).outputs(), 0x55);
        assert_eq!(r.driver.settings().unwrap().baud, Some(19200));
    }
}

#[test]
fn ascii_configure_edge_checksum_and_hex_mode() {
    let mut r = rig_with(Protocol::Ascii, false);
    r.driver
        .configure(&ConfigChange {
            checksum: Some(true),
            counter_edge: Some(CounterEdge::Falling),
            hex_counters: Some(true),
            ..ConfigChange::default()
        })
        .unwrap();
    assert!(lock(&r.model).config().checksum);
    assert!(r.driver.options().checksum);
    let s = r.driver.settings().unwrap();
    assert_eq!(
        (s.checksum, s.counter_edge),
        (Some(true), Some(CounterEdge::Falling))
    );
    lock(&r.model).pulse(0, 0x1B).unwrap();
    assert_eq!(r.driver.read_counter(0).unwrap(), 0x1B);
    let mut m = rig_with(Protocol::Modbus, false);
    assert!(matches!(
        m.driver.configure(&ConfigChange {
            checksum: Some(true),
            ..ConfigChange::default()
        }),
        Err(C29uError::Unsupported { .. })
    ));
}

#[test]
fn synchronized_read_in_ascii_only() {
    let mut r = rig_with(Protocol::Ascii, false);
    lock(&r.model).set_inputs(0x0E);
    r.driver.write_outputs(0x01).unwrap();
    r.driver.synchronize().unwrap();
    let s = r.driver.read_synchronized().unwrap();
    assert_eq!((s.fresh, s.outputs, s.inputs), (true, 0x01, 0x0E));
    assert!(!r.driver.read_synchronized().unwrap().fresh);
    let mut m = rig_with(Protocol::Modbus, false);
    assert!(matches!(
        m.driver.synchronize(),
        Err(C29uError::Unsupported { .. })
    ));
}

#[test]
fn raw_frames_get_checksum_or_crc() {
    let mut r = rig_with(Protocol::Ascii, true);
    // "!01TRPC29" sums to 0x226: checksum 26.
    assert_eq!(r.driver.raw(b"$01M").unwrap(), b"!01TRPC2926\r");
    let mut m = rig_with(Protocol::Modbus, false);
    let answer = m.driver.raw(&[1, 1, 0, 0, 0, 8]).unwrap();
    assert_eq!(answer, crate::protocol::c29u_modbus::seal(&[1, 1, 1, 0]));
}

/// Drops the answers of one ID (a dead module) and flips a byte of the first few others.
struct Faulty {
    inner: MultiDrop,
    garble: usize,
}

impl ByteDevice for Faulty {
    fn receive(&mut self, bytes: &[u8]) -> Vec<u8> {
        let mut answer = self.inner.receive(bytes);
        if self.garble > 0 && !answer.is_empty() {
            self.garble -= 1;
            if let Some(b) = answer.get_mut(1) {
                *b ^= 0x40;
            }
        }
        answer
    }
}

#[test]
fn a_dead_id_times_out_alone_and_garbled_answers_are_retried() {
    for protocol in [Protocol::Ascii, Protocol::Modbus] {
        let clock = VirtualClock::at_epoch();
        let mut line = MultiDrop::new();
        line.attach(Box::new(model(protocol, &clock, 1, false)));
        line.attach(Box::new(model(protocol, &clock, 2, false)));
        let faulty = Arc::new(Mutex::new(Faulty {
            inner: line,
            garble: 2,
        }));
        let link = share(Box::new(
            MemoryByteLink::new(faulty.clone(), "bus").with_clock(Arc::new(clock.clone())),
        ));
        let opts = |id| C29uOptions {
            protocol,
            id,
            timeout: Duration::from_millis(100),
            retries: 2,
            ..C29uOptions::default()
        };
        let mut one = C29u::new(link.clone(), Arc::new(clock.clone()), opts(1)).unwrap();
        let mut two = C29u::new(link.clone(), Arc::new(clock.clone()), opts(2)).unwrap();
        let mut dead = C29u::new(link, Arc::new(clock.clone()), opts(9)).unwrap();

        // Two garbled answers, then a good one: within the retries.
        one.write_outputs(0x0F).unwrap();
        two.write_outputs(0xF0).unwrap();
        let before = clock.now();
        match dead.read_outputs() {
            Err(e @ C29uError::Timeout { .. }) => {
                let text = e.to_string();
                assert!(
                    text.contains("ID 9") && text.contains("nothing came back"),
                    "{text}"
                );
                assert!(e.is_unreachable());
            }
            other => panic!("expected a timeout, got {other:?}"),
        }
        assert_eq!(
            clock.now() - before,
            Duration::from_millis(500),
            "three attempts of 100 ms, each retry after 100 ms of silence (a late answer's chance)"
        );
        assert_eq!(one.read_outputs().unwrap(), 0x0F);
        assert_eq!(two.read_outputs().unwrap(), 0xF0);

        faulty.lock().unwrap().garble = 5;
        assert!(
            matches!(one.read_outputs(), Err(C29uError::Garbled { .. })),
            "retries exhausted"
        );
    }
}

/// A simulated module on a line that records every value its outputs take, frame by frame.
struct OutputWatch {
    inner: SimulatedC29u,
    model: SharedModel,
    history: Arc<Mutex<Vec<u8>>>,
}

impl ByteDevice for OutputWatch {
    fn receive(&mut self, bytes: &[u8]) -> Vec<u8> {
        let answer = self.inner.receive(bytes);
        let now = lock(&self.model).outputs();
        let mut history = self.history.lock().unwrap();
        if history.last() != Some(&now) {
            history.push(now);
        }
        answer
    }
}

/// An ASCII driver whose module's output history is recorded.
fn watched_ascii() -> (C29u, SharedModel, Arc<Mutex<Vec<u8>>>) {
    let clock = VirtualClock::at_epoch();
    let sim = model(Protocol::Ascii, &clock, 1, false);
    let shared = sim.model();
    let history = Arc::new(Mutex::new(vec![0x00]));
    let watch = OutputWatch {
        inner: sim,
        model: shared.clone(),
        history: history.clone(),
    };
    let link = MemoryByteLink::new(watch, "C29U").with_clock(Arc::new(clock.clone()));
    let options = C29uOptions {
        protocol: Protocol::Ascii,
        ..C29uOptions::default()
    };
    let driver = C29u::new(share(Box::new(link)), Arc::new(clock), options).unwrap();
    (driver, shared, history)
}

#[test]
fn ascii_presets_never_pulse_the_outputs_unless_allowed() {
    let (mut driver, model, history) = watched_ascii();
    // A value the outputs do not hold: refused, nothing stored, the outputs untouched.
    let cases = [
        (
            Preset::PowerOn,
            0xFF,
            "the power-on value 0xff",
            "power-on-value 0xff",
        ),
        (Preset::Safe, 0x05, "the safe value 0x05", "safe-value 0x05"),
    ];
    for (preset, value, what, command) in cases {
        match driver.store_preset(preset, value, PresetWrite::KeepOutputs) {
            Err(e @ C29uError::PresetDrivesOutputs { .. }) => {
                let text = e.to_string();
                assert!(
                    text.contains(&format!("storing {what} in TRP-C29U ID 1")),
                    "{text}"
                );
                assert!(
                    text.contains("(they are at 0x00)") && text.contains("8-24"),
                    "{text}"
                );
                let hint = format!("--protocol ascii --id 1 {command} --drive-outputs`");
                assert!(text.contains(&hint), "{text}");
            }
            other => panic!("expected a refusal, got {other:?}"),
        }
    }
    assert!(matches!(
        driver.set_power_on_value(0xFF),
        Err(C29uError::PresetDrivesOutputs {
            value: 0xFF,
            outputs: 0x00,
            ..
        })
    ));
    assert_eq!(
        *history.lock().unwrap(),
        vec![0x00],
        "the outputs never moved"
    );
    assert_eq!(lock(&model).power_on_value(), 0x00);

    // A value the outputs hold: stored as it is (`~ID5V` alone), no pulse.
    driver.write_outputs(0x05).unwrap();
    driver.set_safe_value(0x05).unwrap();
    driver.set_power_on_value(0x05).unwrap();
    assert_eq!(lock(&model).safe_value(), 0x05);
    assert_eq!(lock(&model).power_on_value(), 0x05);
    assert_eq!(*history.lock().unwrap(), vec![0x00, 0x05]);

    // Only when the caller allows it do the outputs take the value for a moment.
    driver
        .store_preset(Preset::PowerOn, 0x42, PresetWrite::DriveOutputs)
        .unwrap();
    assert_eq!(lock(&model).power_on_value(), 0x42);
    assert_eq!(*history.lock().unwrap(), vec![0x00, 0x05, 0x42, 0x05]);
}

#[test]
fn modbus_presets_are_stored_without_touching_the_outputs() {
    let mut r = rig_with(Protocol::Modbus, false);
    r.driver.write_outputs(0x81).unwrap();
    r.driver.set_safe_value(0x05).unwrap();
    r.driver.set_power_on_value(0x42).unwrap();
    let m = lock(&r.model);
    assert_eq!(
        (m.safe_value(), m.power_on_value(), m.outputs()),
        (0x05, 0x42, 0x81)
    );
}

/// Rewrites the module's answers: each (from, to) pair replaces an exact answer frame.
struct Rewrite {
    inner: SimulatedC29u,
    rules: Vec<(Vec<u8>, Vec<u8>)>,
    requests: Arc<Mutex<Vec<Vec<u8>>>>,
}

impl ByteDevice for Rewrite {
    fn receive(&mut self, bytes: &[u8]) -> Vec<u8> {
        self.requests.lock().unwrap().push(bytes.to_vec());
        let answer = self.inner.receive(bytes);
        match self.rules.iter().find(|(from, _)| *from == answer) {
            Some((_, to)) => to.clone(),
            None => answer,
        }
    }
}

/// A driver to a simulated module whose answers pass through `rules`, and the requests it got.
fn rewritten(
    protocol: Protocol,
    rules: Vec<(Vec<u8>, Vec<u8>)>,
) -> (Rig, Arc<Mutex<Vec<Vec<u8>>>>) {
    let clock = VirtualClock::at_epoch();
    let sim = model(protocol, &clock, 1, false);
    let shared = sim.model();
    let requests = Arc::new(Mutex::new(Vec::new()));
    let device = Rewrite {
        inner: sim,
        rules,
        requests: requests.clone(),
    };
    let link = MemoryByteLink::new(device, "C29U").with_clock(Arc::new(clock.clone()));
    let options = C29uOptions {
        protocol,
        ..C29uOptions::default()
    };
    let driver = C29u::new(share(Box::new(link)), Arc::new(clock.clone()), options).unwrap();
    let rig = Rig {
        clock,
        model: shared,
        driver,
    };
    (rig, requests)
}

#[test]
fn ascii_refusal_with_the_watchdog_merely_off_is_not_safe_mode() {
    // The module answers `?01` to output writes (a `>` turned into `?01`); its watchdog reads
    // `WD00`: off, not fired, so this is a refused command, not safe mode.
    let (mut r, _) = rewritten(Protocol::Ascii, vec![(b">\r".to_vec(), b"?01\r".to_vec())]);
    match r.driver.write_outputs(0x01) {
        Err(C29uError::Refused { .. }) => {}
        other => panic!("expected a refusal, got {other:?}"),
    }
    // Once its watchdog has fired, the same answer is safe mode.
    r.driver
        .set_watchdog(Some(Duration::from_millis(100)))
        .unwrap();
    r.clock.advance(Duration::from_millis(100));
    assert!(matches!(
        r.driver.write_outputs(0x01),
        Err(C29uError::SafeMode { .. })
    ));
    let w = r.driver.watchdog().unwrap();
    assert_eq!(
        (w.enabled, w.timeout_tenths, w.expired),
        (true, 1, Some(true))
    );
    r.driver.set_watchdog(None).unwrap();
    let w = r.driver.watchdog().unwrap();
    assert_eq!(
        (w.enabled, w.timeout_tenths, w.expired),
        (false, 0, Some(false))
    );
}

#[test]
fn ascii_bare_answer_to_read_watchdog_is_off() {
    // 8-21 lists a bare `!ID` as an answer to `~IDWR`.
    let (mut r, _) = rewritten(
        Protocol::Ascii,
        vec![(b"!01WD00\r".to_vec(), b"!01\r".to_vec())],
    );
    let w = r.driver.watchdog().unwrap();
    assert_eq!(
        (w.enabled, w.timeout_tenths, w.expired),
        (false, 0, Some(false))
    );
}

#[test]
fn modbus_8f_ff_to_a_single_output_write_is_safe_mode_at_once() {
    // 10-16: "you will get the response ID 8F FF" to a 05 write in safe mode.
    let seal = crate::protocol::c29u_modbus::seal;
    let (mut r, requests) = rewritten(
        Protocol::Modbus,
        vec![(seal(&[1, 0x85, 0xFF]), seal(&[1, 0x8F, 0xFF]))],
    );
    r.driver
        .set_watchdog(Some(Duration::from_millis(100)))
        .unwrap();
    r.clock.advance(Duration::from_millis(100));
    requests.lock().unwrap().clear();
    let before = r.clock.now();
    assert!(matches!(
        r.driver.write_output(3, true),
        Err(C29uError::SafeMode { .. })
    ));
    assert_eq!(requests.lock().unwrap().len(), 1, "not retried");
    assert_eq!(r.clock.now(), before, "no timeout waited");
}

#[test]
fn modbus_counters_are_read_from_channel_00() {
    // 10-18/10-19 give the start channel as 00 only: channel 3 is the last of four.
    let (mut r, requests) = rewritten(Protocol::Modbus, Vec::new());
    lock(&r.model).pulse(3, 7).unwrap();
    assert_eq!(r.driver.read_counter(3).unwrap(), 7);
    assert_eq!(r.driver.read_counter(0).unwrap(), 0);
    let seal = crate::protocol::c29u_modbus::seal;
    let sent = requests.lock().unwrap().clone();
    assert_eq!(
        sent,
        vec![seal(&[1, 0x04, 0, 0, 0, 4]), seal(&[1, 0x04, 0, 0, 0, 1])]
    );
}

#[test]
fn a_stop_cuts_the_wait_for_a_silent_module_within_a_slice_and_sends_nothing_after() {
    use crate::device::cancel::{Cancel, CANCEL_SLICE};
    use std::sync::atomic::{AtomicUsize, Ordering};
    for protocol in [Protocol::Ascii, Protocol::Modbus] {
        // Signals in the first try's wait, and in the settling before the second.
        for signal_after in [Duration::from_millis(350), Duration::from_millis(1300)] {
            let clock = VirtualClock::at_epoch();
            let mut line = MultiDrop::default();
            line.attach(Box::new(model(protocol, &clock, 1, false)));
            let heard = Arc::new(AtomicUsize::new(0));
            let line = Heard {
                inner: line,
                bytes: Arc::clone(&heard),
            };
            let link = share(Box::new(
                MemoryByteLink::new(line, "bus").with_clock(Arc::new(clock.clone())),
            ));
            let opts = |id| C29uOptions {
                protocol,
                id,
                timeout: Duration::from_secs(1),
                retries: 5,
                ..C29uOptions::default()
            };
            // ID 9 is not on the line: silent, while the line itself works.
            let mut silent = C29u::new(link.clone(), Arc::new(clock.clone()), opts(9)).unwrap();
            let mut other = C29u::new(link, Arc::new(clock.clone()), opts(1)).unwrap();
            let flag = Arc::new(AtomicUsize::new(0));
            silent.set_cancel(Cancel::when_set(Arc::clone(&flag)));
            let start = clock.now();
            clock.set_at(start + signal_after, Arc::clone(&flag), 15);
            match silent.read_inputs() {
                Err(e @ C29uError::Cancelled { .. }) => {
                    assert!(e.to_string().contains("ID 9"), "{e}");
                }
                other => panic!("{protocol:?}: expected a cut exchange, got {other:?}"),
            }
            let took = clock.now() - start;
            assert!(
                took <= signal_after + CANCEL_SLICE,
                "{protocol:?}: {took:?} for a signal after {signal_after:?} (the retries: 11 s)"
            );
            let seen = heard.load(Ordering::SeqCst);
            assert!(
                matches!(silent.read_inputs(), Err(C29uError::Cancelled { .. })),
                "a cut driver sends nothing more"
            );
            assert_eq!(heard.load(Ordering::SeqCst), seen);
            // The line settles (the cut request's late answer could still come), then works.
            assert_eq!(other.read_outputs().unwrap(), 0);
        }
    }
}

/// A line that counts the bytes sent on it.
struct Heard<D> {
    inner: D,
    bytes: Arc<std::sync::atomic::AtomicUsize>,
}

impl<D: ByteDevice> ByteDevice for Heard<D> {
    fn receive(&mut self, bytes: &[u8]) -> Vec<u8> {
        self.bytes
            .fetch_add(bytes.len(), std::sync::atomic::Ordering::SeqCst);
        self.inner.receive(bytes)
    }

    fn line_idle(&mut self) -> Vec<u8> {
        self.inner.line_idle()
    }
}
