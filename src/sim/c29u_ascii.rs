//! The simulated TRP-C29U's ASCII front end: reassembles CR-ended frames from a byte stream,
//! decodes them with `protocol::c29u_ascii`, carries them out on the `C29uModel` and answers.
//!
//! Readings (see also `protocol::c29u_ascii`'s list):
//! - The module is silent on a bad checksum, a frame with no readable ID, another ID, and
//!   broadcasts; it also stays silent when its DIP switch selects Modbus (section 4).
//! - 8-1 / 8-3: `%` is answered `!NN` from the new ID, framed with the checksum setting the
//!   request came with; the following frames use the new settings.
//! - 8-19: an output write in safe mode is answered `!IDWE`.
//! - 8-21: `~IDWR` answers as [`WatchdogReading`](crate::protocol::c29u_ascii::WatchdogReading)
//!   reads it (the model stores 0 for "disabled").
//! - 8-23: `~ID4V`'s second byte ("DI0~DI7") is the inputs as on the wire now.
//! - A LF right after a CR (a CR LF line end) is ignored; a frame longer than
//!   [`AsciiFrontEnd::MAX_FRAME`] is dropped up to the next CR.

use super::c29u::{
    C29uModel, C29uModelError, ModuleConfig, Protocol, FIRMWARE_DATE, FIRMWARE_MODEL,
};
use crate::protocol::c29u_ascii::{
    decode_request, encode_answer, encode_refusal, Address, Answer, FirmwareVersion, LatchLevel,
    ModuleName, Preset, Refusal, Request, CR,
};

/// One frame (with or without its CR) in, the module's answer out; `None` means silence.
pub fn answer(model: &mut C29uModel, frame: &[u8]) -> Option<Vec<u8>> {
    if model.protocol() != Protocol::Ascii {
        return None;
    }
    // The settings the request arrived with frame the answer, even when `%` changes them.
    let cfg = model.config();
    let (address, request) = match decode_request(frame, cfg.checksum) {
        Ok(decoded) => decoded,
        Err(err) => {
            return err
                .refusal(cfg.id)
                .map(|r| encode_refusal(r, cfg.id, cfg.checksum))
        }
    };
    match request {
        Request::HostOk => {
            model.host_ok();
            return None;
        }
        Request::Synchronize => {
            model.synchronize();
            return None;
        }
        _ => {}
    }
    if address != Address::Id(cfg.id) {
        return None;
    }
    Some(match carry_out(model, &request, cfg) {
        // After a `%` the model already holds the new ID: `!NN`.
        Ok(answer) => encode_answer(&answer, model.config().id, cfg.checksum),
        Err(refusal) => encode_refusal(refusal, cfg.id, cfg.checksum),
    })
}

/// Carries out an addressed request on the model; `cfg` is the configuration it arrived with.
fn carry_out(
    model: &mut C29uModel,
    request: &Request,
    cfg: ModuleConfig,
) -> Result<Answer, Refusal> {
    let invalid = |_: C29uModelError| Refusal::InvalidCommand;
    let done = |r: Result<(), C29uModelError>| r.map(|()| Answer::Done).map_err(invalid);
    Ok(match request {
        Request::Configure {
            new_id,
            baud,
            format,
        } => {
            let next = ModuleConfig::from_parts(*new_id, baud.code(), *format).map_err(invalid)?;
            return done(model.set_config(next));
        }
        Request::WriteOutputs(value) => return output_write(model.write_outputs(*value)),
        Request::WriteOutput { channel, on } => {
            return output_write(model.write_output(channel.get(), *on))
        }
        Request::ReadCounter(ch) => Answer::Counter {
            value: model.counter(ch.get()).map_err(invalid)?,
            hex: cfg.hex_counters,
        },
        Request::ClearCounter(ch) => return done(model.clear_counter(ch.get())),
        Request::ClearCounters => {
            model.clear_counters();
            Answer::Done
        }
        Request::SaveCounters => return done(model.save_counters()),
        Request::ReadLatch(LatchLevel::Low) => Answer::Latch(model.latched_low()),
        Request::ReadLatch(LatchLevel::High) => Answer::Latch(model.latched_high()),
        Request::ClearLatch => {
            model.clear_latches();
            Answer::Done
        }
        Request::ReadDio => Answer::Dio {
            outputs: model.outputs(),
            inputs: model.inputs_wire(),
        },
        Request::ReadConfig => Answer::Config(cfg.report()),
        Request::Reset => {
            model.reset();
            Answer::Done
        }
        Request::ReadName => {
            Answer::Name(ModuleName::new(model.name()).ok_or(Refusal::InvalidCommand)?)
        }
        Request::ReadFirmware => Answer::Firmware(
            FirmwareVersion::from_parts(FIRMWARE_MODEL, FIRMWARE_DATE)
                .ok_or(Refusal::InvalidCommand)?,
        ),
        Request::ReadResetStatus => Answer::ResetStatus(model.take_reset_flag()),
        Request::SetName(name) => return done(model.set_name(name.as_str())),
        Request::SetLedMode(on) => {
            model.set_led_mode(u8::from(*on)).map_err(invalid)?;
            Answer::Led(*on)
        }
        Request::EnableWatchdog(tenths) => return done(model.set_watchdog(*tenths)),
        Request::DisableWatchdog => return done(model.set_watchdog(0)),
        Request::ReadWatchdog => Answer::Watchdog(model.watchdog_reading()),
        Request::ReadPreset(preset) => Answer::Preset {
            outputs: match preset {
                Preset::PowerOn => model.power_on_value(),
                Preset::Safe => model.safe_value(),
            },
            inputs: model.inputs_wire(),
        },
        Request::SavePreset(Preset::PowerOn) => return done(model.save_outputs_as_power_on()),
        Request::SavePreset(Preset::Safe) => return done(model.save_outputs_as_safe()),
        Request::ReadSynchronized => {
            Answer::Synchronized(model.read_synchronized().map_err(invalid)?)
        }
        // Broadcasts are carried out by `answer` and never reach here.
        Request::HostOk | Request::Synchronize => return Err(Refusal::InvalidCommand),
    })
}

/// 8-4 / 8-19: `>` when done, `!IDWE` in safe mode, `!ID` for anything else the model refuses.
fn output_write(result: Result<(), C29uModelError>) -> Result<Answer, Refusal> {
    match result {
        Ok(()) => Ok(Answer::OutputWritten),
        Err(C29uModelError::SafeMode) => Err(Refusal::SafeMode),
        Err(_) => Err(Refusal::ParameterError),
    }
}

/// Splits a byte stream arriving in arbitrary pieces into CR-ended frames and answers each.
#[derive(Debug, Clone, Default)]
pub struct AsciiFrontEnd {
    frame: Vec<u8>,
    /// The current frame grew past `MAX_FRAME`: drop bytes up to the next CR.
    discarding: bool,
    /// The last byte was a CR, so a LF now is the rest of a CR LF line end.
    after_cr: bool,
}

impl AsciiFrontEnd {
    /// Longest frame kept; the longest request (`%IDNNPPBBDD` + checksum) has 13 characters.
    pub const MAX_FRAME: usize = 64;

    /// A front end with nothing buffered.
    pub fn new() -> Self {
        Self::default()
    }

    /// Takes bytes as they arrive and returns the answers to every frame they complete.
    pub fn receive(&mut self, model: &mut C29uModel, bytes: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        for &b in bytes {
            let after_cr = std::mem::replace(&mut self.after_cr, b == CR);
            if b == CR {
                if !self.discarding && !self.frame.is_empty() {
                    if let Some(reply) = answer(model, &self.frame) {
                        out.extend_from_slice(&reply);
                    }
                }
                self.frame.clear();
                self.discarding = false;
            } else if self.discarding || (b == b'\n' && after_cr) {
                // Inside an over-long frame, or the LF of a CR LF line end.
            } else if self.frame.len() >= Self::MAX_FRAME {
                self.frame.clear();
                self.discarding = true;
            } else {
                self.frame.push(b);
            }
        }
        out
    }

    /// Bytes of an unfinished frame held so far.
    pub fn pending(&self) -> usize {
        self.frame.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::c29u_ascii::{checksum, parse_answer, AsciiError};
    use crate::sim::c29u::Eeprom;
    use crate::time::clock::VirtualClock;
    use proptest::prelude::*;
    use std::sync::Arc;
    use std::time::Duration;

    struct Bench {
        clock: VirtualClock,
        model: C29uModel,
        front: AsciiFrontEnd,
    }

    impl Bench {
        fn new() -> Self {
            let clock = VirtualClock::at_epoch();
            let model = C29uModel::new(Protocol::Ascii, Arc::new(clock.clone()), Eeprom::factory());
            Self {
                clock,
                model,
                front: AsciiFrontEnd::new(),
            }
        }

        /// Sends `text` + CR, returns the answer without its CR ("" = silence).
        fn send(&mut self, text: &str) -> String {
            let mut frame = text.as_bytes().to_vec();
            frame.push(CR);
            let out = self.front.receive(&mut self.model, &frame);
            let text = String::from_utf8(out).unwrap();
            match text.strip_suffix('\r') {
                Some(t) => t.to_string(),
                None => {
                    assert!(text.is_empty(), "answer without CR: {text:?}");
                    text
                }
            }
        }

        /// As `send`, with a checksum added to the request and checked and removed from the answer.
        fn send_cs(&mut self, text: &str) -> String {
            let framed = format!("{text}{:02X}", checksum(text.as_bytes()));
            let answer = self.send(&framed);
            if answer.is_empty() {
                return answer;
            }
            let (body, cs) = answer.split_at(answer.len() - 2);
            assert_eq!(cs, format!("{:02X}", checksum(body.as_bytes())), "{answer}");
            body.to_string()
        }

        fn advance_ms(&self, ms: u64) {
            self.clock.advance(Duration::from_millis(ms));
        }
    }

    #[test]
    fn counters_after_pulses_decimal_then_hex_8_3_and_8_5() {
        let mut b = Bench::new();
        b.model.pulse(2, 23).unwrap();
        assert_eq!(b.send("#012"), "!0100023");
        assert_eq!(b.send("#010"), "!0100000");
        assert_eq!(b.send("%0101400601"), "!01");
        b.model.pulse(0, 0x1B).unwrap();
        assert_eq!(b.send("#010"), "!01001B");
        assert_eq!(b.send("#01C0"), "!01");
        assert_eq!(b.send("#010"), "!010000");
        assert_eq!(b.send("#01CW"), "!01");
        assert_eq!(b.send("#012"), "!010000");
        // Channel 8 does not exist (0-7, as 8-6 has it).
        assert_eq!(b.send("#018"), "?01");
    }

    #[test]
    fn saved_counters_come_back_after_reset_8_8() {
        let mut b = Bench::new();
        b.model.pulse(0, 187).unwrap();
        assert_eq!(b.send("#01CS"), "!01");
        b.model.pulse(0, 5).unwrap();
        assert_eq!(b.send("#010"), "!0100192");
        assert_eq!(b.send("$01RS"), "!01");
        assert_eq!(b.send("#010"), "!0100187");
        // Cleared but not saved: the saved value returns after a power cycle (8-6).
        assert_eq!(b.send("#01C0"), "!01");
        b.model.power_cycle();
        assert_eq!(b.send("#010"), "!0100187");
    }

    #[test]
    fn latches_and_dio_status_8_9_to_8_11() {
        let mut b = Bench::new();
        assert_eq!(b.send("$01L0"), "!010000");
        b.model.set_inputs(0x02);
        b.model.set_inputs(0x00);
        // DI1 was energized (wire 0) then released (wire 1): latched both ways.
        assert_eq!(b.send("$01L0"), "!010200");
        assert_eq!(b.send("$01L1"), "!010200");
        assert_eq!(b.send("$01C"), "!01");
        assert_eq!(b.send("$01L0"), "!010000");
        assert_eq!(b.send("$01L2"), "?01");

        assert_eq!(b.send("#0100A8"), ">");
        assert_eq!(b.send("#010A21"), ">");
        b.model.set_inputs(0x30);
        assert_eq!(
            b.send("$016"),
            "!0121CF",
            "DI4, DI5 energized read as 0 bits"
        );
        assert_eq!(b.send("#011701"), ">");
        assert_eq!(b.send("#011000"), ">");
        assert_eq!(b.model.outputs(), 0xA0);
        assert_eq!(b.send("#01000G"), "!01", "8-4: parameter error");
        assert_eq!(b.send("#011801"), "!01");
        assert_eq!(b.model.outputs(), 0xA0);
    }

    #[test]
    fn config_name_firmware_led_8_12_to_8_18() {
        let mut b = Bench::new();
        assert_eq!(b.send("$012"), "!01400603");
        assert_eq!(b.send("$01M"), "!01TRPC29");
        assert_eq!(b.send("~01OABCDE"), "!01");
        assert_eq!(b.send("$01M"), "!01ABCDE");
        assert_eq!(b.send("~01OABCDEFG"), "?01");
        assert_eq!(b.send("$01F"), "!01C29M090703");
        assert_eq!(b.send("~01LED0"), "!01OFF");
        assert_eq!(b.send("~01LED1"), "!01ON");
        assert_eq!(b.model.led_mode(), 1);
        assert_eq!(b.send("$01X"), "?01");
    }

    #[test]
    fn power_on_value_after_reset_8_13_8_16_8_24() {
        let mut b = Bench::new();
        assert_eq!(b.send("$015"), "!011", "fresh from power on");
        assert_eq!(b.send("$015"), "!010");
        assert_eq!(b.send("#010013"), ">");
        assert_eq!(b.send("~015P"), "!01");
        assert_eq!(b.send("#010000"), ">");
        assert_eq!(b.send("~014P"), "!0113FF");
        assert_eq!(b.send("$01RS"), "!01");
        assert_eq!(b.send("$016"), "!0113FF");
        assert_eq!(b.send("$015"), "!011");
        assert_eq!(b.send("$015"), "!010");
    }

    #[test]
    fn watchdog_expiry_refuses_output_writes_until_disabled_8_19_to_8_22() {
        let mut b = Bench::new();
        assert_eq!(b.send("#010008"), ">");
        assert_eq!(b.send("~015S"), "!01");
        assert_eq!(b.send("~014S"), "!0108FF");
        assert_eq!(b.send("#010001"), ">");
        assert_eq!(b.send("~01WR"), "!01WD00");
        assert_eq!(b.send("~01WE0F"), "!01");
        assert_eq!(b.send("~01WR"), "!01WE0F");

        // Host OK keeps it alive: 1.0 s + 1.0 s with a ~** in between (timeout 1.5 s).
        b.advance_ms(1000);
        assert_eq!(b.send("~**"), "", "no answer to host OK");
        b.advance_ms(1000);
        assert_eq!(b.send("#010002"), ">");
        // Other commands do not feed it.
        b.advance_ms(400);
        assert_eq!(b.send("$016"), "!0102FF");
        b.advance_ms(100);
        assert_eq!(b.send("#0100FF"), "!01WE", "safe mode");
        assert_eq!(b.send("#011301"), "!01WE");
        assert_eq!(b.send("$016"), "!0108FF", "outputs at the safe value");
        assert_eq!(b.send("~01WR"), "!01WD0F", "D: disabled or safe mode");
        // A reset keeps safe mode.
        assert_eq!(b.send("$01RS"), "!01");
        assert_eq!(b.send("#0100FF"), "!01WE");
        assert_eq!(b.send("~**"), "");
        assert_eq!(
            b.send("#0100FF"),
            "!01WE",
            "host OK does not leave safe mode"
        );
        assert_eq!(b.send("~01WD"), "!01");
        assert_eq!(b.send("#0100FF"), ">");
        assert_eq!(b.send("~01WR"), "!01WD00");
    }

    #[test]
    fn watchdog_we00_disables_and_the_driver_reads_safe_mode() {
        let mut b = Bench::new();
        assert_eq!(b.send("~01WE01"), "!01");
        b.advance_ms(100);
        let reply = b.send("#010001");
        let request = Request::WriteOutputs(1);
        let err = parse_answer(&request, reply.as_bytes(), false, 1).unwrap_err();
        assert_eq!(err, AsciiError::SafeMode);
        assert_eq!(b.send("~01WE00"), "!01");
        assert_eq!(b.send("#010001"), ">");
    }

    #[test]
    fn synchronized_data_is_fresh_once_8_25_8_26() {
        let mut b = Bench::new();
        assert_eq!(b.send("$014"), "?01", "no #** yet");
        assert_eq!(b.send("#010001"), ">");
        b.model.set_inputs(0xF1);
        assert_eq!(b.send("#**"), "", "broadcast: no answer");
        b.model.set_inputs(0x00);
        assert_eq!(b.send("#0100FF"), ">");
        assert_eq!(b.send("$014"), "!1010E00");
        assert_eq!(b.send("$014"), "!0010E00");
    }

    #[test]
    fn other_ids_are_ignored_and_unknown_commands_answered() {
        let mut b = Bench::new();
        assert_eq!(b.send("$026"), "");
        assert_eq!(b.send("#020001"), "");
        assert_eq!(b.model.outputs(), 0);
        assert_eq!(b.send("$02Z"), "", "unknown command for another module");
        assert_eq!(b.send("$01Z"), "?01");
        assert_eq!(b.send("$G16"), "", "no readable ID");
        assert_eq!(b.send("$016"), "!0100FF");
    }

    #[test]
    fn configure_moves_id_and_checksum_8_1_to_8_3() {
        let mut b = Bench::new();
        assert_eq!(b.send("%0102400600"), "!02", "answered from the new ID");
        assert_eq!(b.send("$016"), "");
        assert_eq!(b.send("$026"), "!0200FF");
        // Checksum on: this answer still comes without one (the request had none) ...
        assert_eq!(b.send("%0202400640"), "!02");
        // ... and from now on a frame without a valid checksum is ignored.
        assert_eq!(b.send("$026"), "");
        assert_eq!(b.send("$026A1"), "");
        assert_eq!(b.send_cs("$026"), "!0200FF");
        assert_eq!(b.send_cs("$022"), "!02400643");
        assert_eq!(b.send_cs("$02Z"), "?02");
        // Section 7: "$06M" carries D7.
        assert_eq!(b.send_cs("%0206400640"), "!06");
        assert_eq!(
            b.send("$06MD7"),
            format!("!06TRPC29{:02X}", checksum(b"!06TRPC29"))
        );
        assert_eq!(b.send("$06MA1"), "", "the manual's A1 is a bad checksum");
        // Bad parameters leave the configuration alone.
        assert_eq!(b.send_cs("%0607410640"), "?06", "PP must be 40");
        assert_eq!(b.send_cs("%0607400B40"), "?06");
        assert_eq!(b.model.config().id, 6);
        // Back to plain frames, falling edges.
        assert_eq!(b.send_cs("%0601400680"), "!01");
        assert_eq!(b.send("$012"), "!01400683");
    }

    #[test]
    fn a_modbus_module_is_silent_in_ascii() {
        let clock = VirtualClock::at_epoch();
        let mut model = C29uModel::new(Protocol::Modbus, Arc::new(clock), Eeprom::factory());
        assert_eq!(answer(&mut model, b"$016\r"), None);
    }

    #[test]
    fn frames_are_reassembled_from_pieces() {
        let mut b = Bench::new();
        let mut out = Vec::new();
        for piece in [&b"$0"[..], b"16\r$01", b"M", b"\r\n$01", b"5\r\n"] {
            out.extend(b.front.receive(&mut b.model, piece));
        }
        assert_eq!(out, b"!0100FF\r!01TRPC29\r!011\r");
        assert_eq!(b.front.pending(), 0);
        out = b.front.receive(&mut b.model, b"$01");
        assert!(out.is_empty());
        assert_eq!(b.front.pending(), 3);
    }

    #[test]
    fn over_long_garbage_is_dropped_up_to_the_next_cr() {
        let mut b = Bench::new();
        let mut junk = vec![b'X'; AsciiFrontEnd::MAX_FRAME + 10];
        junk.extend_from_slice(b"$016\r");
        assert!(
            b.front.receive(&mut b.model, &junk).is_empty(),
            "the tail of an over-long frame is not a frame"
        );
        assert_eq!(b.send("$016"), "!0100FF");
        assert_eq!(b.front.receive(&mut b.model, b"\r\r\n\r"), b"");
    }

    fn request_strategy() -> impl Strategy<Value = Request> {
        use crate::protocol::c29u_ascii::Channel;
        let ch = (0u8..=7).prop_map(|n| Channel::new(n).unwrap());
        prop_oneof![
            any::<u8>().prop_map(Request::WriteOutputs),
            (ch.clone(), any::<bool>())
                .prop_map(|(channel, on)| Request::WriteOutput { channel, on }),
            ch.clone().prop_map(Request::ReadCounter),
            ch.prop_map(Request::ClearCounter),
            Just(Request::ClearCounters),
            Just(Request::SaveCounters),
            Just(Request::ReadLatch(LatchLevel::Low)),
            Just(Request::ReadLatch(LatchLevel::High)),
            Just(Request::ClearLatch),
            Just(Request::ReadDio),
            Just(Request::ReadConfig),
            Just(Request::Reset),
            Just(Request::ReadName),
            Just(Request::ReadFirmware),
            Just(Request::ReadResetStatus),
            Just(Request::SetName(ModuleName::new("AB C").unwrap())),
            any::<bool>().prop_map(Request::SetLedMode),
            (0u8..4).prop_map(Request::EnableWatchdog),
            Just(Request::DisableWatchdog),
            Just(Request::ReadWatchdog),
            Just(Request::HostOk),
            Just(Request::ReadPreset(Preset::PowerOn)),
            Just(Request::ReadPreset(Preset::Safe)),
            Just(Request::SavePreset(Preset::PowerOn)),
            Just(Request::SavePreset(Preset::Safe)),
            Just(Request::Synchronize),
            Just(Request::ReadSynchronized),
        ]
    }

    proptest! {
        #[test]
        fn every_answer_parses_as_the_driver_expects(
            steps in prop::collection::vec((request_strategy(), 0u64..300, any::<u8>()), 1..40),
            cs in any::<bool>(),
        ) {
            let mut b = Bench::new();
            if cs {
                prop_assert_eq!(b.send("%0101400640"), "!01");
            }
            for (request, ms, inputs) in steps {
                b.advance_ms(ms);
                b.model.set_inputs(inputs);
                let reply = b.front.receive(&mut b.model, &request.encode(1, cs));
                if !request.expects_answer() {
                    prop_assert!(reply.is_empty());
                    continue;
                }
                match parse_answer(&request, &reply, cs, 1) {
                    Ok(_)
                    | Err(AsciiError::InvalidCommand)
                    | Err(AsciiError::SafeMode) => {}
                    Err(e) => prop_assert!(false, "{:?} -> {:?}: {}", request, reply.escape_ascii().to_string(), e),
                }
            }
        }

        #[test]
        fn chunking_does_not_change_the_answers(
            frames in prop::collection::vec(request_strategy(), 0..12),
            cuts in prop::collection::vec(0usize..200, 0..8),
        ) {
            let stream: Vec<u8> = frames.iter().flat_map(|r| r.encode(1, false)).collect();
            let mut whole = Bench::new();
            let expected = whole.front.receive(&mut whole.model, &stream);
            let mut pieces = Bench::new();
            let mut cuts: Vec<usize> = cuts.into_iter().map(|c| c.min(stream.len())).collect();
            cuts.sort_unstable();
            let mut got = Vec::new();
            let mut start = 0;
            for cut in cuts.into_iter().chain([stream.len()]) {
                got.extend(pieces.front.receive(&mut pieces.model, stream.get(start..cut).unwrap_or(&[])));
                start = cut;
            }
            prop_assert_eq!(got, expected);
        }

        #[test]
        fn random_bytes_never_panic_the_front_end(
            chunks in prop::collection::vec(prop::collection::vec(any::<u8>(), 0..90), 0..6),
        ) {
            let mut b = Bench::new();
            for chunk in chunks {
                let _ = b.front.receive(&mut b.model, &chunk);
                prop_assert!(b.front.pending() <= AsciiFrontEnd::MAX_FRAME);
            }
        }
    }
}
