//! Round trips of every request, answer and refusal through their frames, and parsers that never
//! panic on random bytes.

use super::frame::close;
use super::*;
use proptest::prelude::*;

fn channel() -> impl Strategy<Value = Channel> {
    (0u8..=7).prop_map(|n| Channel::new(n).unwrap())
}

fn printable(min: usize, max: usize) -> impl Strategy<Value = String> {
    prop::collection::vec(0x20u8..=0x7E, min..=max)
        .prop_map(|v| v.into_iter().map(char::from).collect())
}

fn name() -> impl Strategy<Value = ModuleName> {
    printable(1, 6).prop_map(|s| ModuleName::new(&s).unwrap())
}

fn preset() -> impl Strategy<Value = Preset> {
    prop_oneof![Just(Preset::PowerOn), Just(Preset::Safe)]
}

fn request() -> impl Strategy<Value = Request> {
    prop_oneof![
        (any::<u8>(), 3u8..=0x0A, any::<(bool, bool, bool)>()).prop_map(
            |(new_id, b, (e, c, h))| {
                Request::Configure {
                    new_id,
                    baud: BaudCode::new(b).unwrap(),
                    format: DataFormat {
                        falling_edge: e,
                        checksum: c,
                        hex_counters: h,
                    },
                }
            }
        ),
        any::<u8>().prop_map(Request::WriteOutputs),
        (channel(), any::<bool>()).prop_map(|(channel, on)| Request::WriteOutput { channel, on }),
        channel().prop_map(Request::ReadCounter),
        channel().prop_map(Request::ClearCounter),
        Just(Request::ClearCounters),
        Just(Request::SaveCounters),
        prop_oneof![Just(LatchLevel::Low), Just(LatchLevel::High)].prop_map(Request::ReadLatch),
        Just(Request::ClearLatch),
        Just(Request::ReadDio),
        Just(Request::ReadConfig),
        Just(Request::Reset),
        Just(Request::ReadName),
        Just(Request::ReadFirmware),
        Just(Request::ReadResetStatus),
        name().prop_map(Request::SetName),
        any::<bool>().prop_map(Request::SetLedMode),
        any::<u8>().prop_map(Request::EnableWatchdog),
        Just(Request::DisableWatchdog),
        Just(Request::ReadWatchdog),
        Just(Request::HostOk),
        preset().prop_map(Request::ReadPreset),
        preset().prop_map(Request::SavePreset),
        Just(Request::Synchronize),
        Just(Request::ReadSynchronized),
    ]
}

/// A request that has an answer, and an answer of the shape it gets.
fn exchange() -> impl Strategy<Value = (Request, Answer)> {
    let done = request()
        .prop_filter("answered by !ID alone", |r| {
            r.expects_answer()
                && matches!(
                    r,
                    Request::Configure { .. }
                        | Request::ClearCounter(_)
                        | Request::ClearCounters
                        | Request::SaveCounters
                        | Request::ClearLatch
                        | Request::Reset
                        | Request::SetName(_)
                        | Request::EnableWatchdog(_)
                        | Request::DisableWatchdog
                        | Request::SavePreset(_)
                )
        })
        .prop_map(|r| (r, Answer::Done));
    prop_oneof![
        done,
        request()
            .prop_filter("output write", Request::is_output_write)
            .prop_map(|r| (r, Answer::OutputWritten)),
        (channel(), any::<u16>(), any::<bool>())
            .prop_map(|(c, value, hex)| (Request::ReadCounter(c), Answer::Counter { value, hex })),
        any::<u8>().prop_map(|b| (Request::ReadLatch(LatchLevel::Low), Answer::Latch(b))),
        any::<(u8, u8)>()
            .prop_map(|(outputs, inputs)| (Request::ReadDio, Answer::Dio { outputs, inputs })),
        any::<(u8, u8, u8)>().prop_map(|(module_type, baud_code, format)| (
            Request::ReadConfig,
            Answer::Config(ConfigReport {
                module_type,
                baud_code,
                format
            })
        )),
        name().prop_map(|n| (Request::ReadName, Answer::Name(n))),
        printable(1, 24).prop_map(|t| (
            Request::ReadFirmware,
            Answer::Firmware(FirmwareVersion::new(&t).unwrap())
        )),
        any::<bool>().prop_map(|b| (Request::ReadResetStatus, Answer::ResetStatus(b))),
        any::<bool>().prop_map(|b| (Request::SetLedMode(b), Answer::Led(b))),
        any::<(u8, bool)>().prop_map(|(tenths, fired)| (
            Request::ReadWatchdog,
            Answer::Watchdog(WatchdogReading::of(tenths, fired))
        )),
        (preset(), any::<(u8, u8)>()).prop_map(|(p, (outputs, inputs))| (
            Request::ReadPreset(p),
            Answer::Preset { outputs, inputs }
        )),
        any::<(bool, u8, u8)>().prop_map(|(fresh, outputs, inputs_wire)| (
            Request::ReadSynchronized,
            Answer::Synchronized(SynchronizedData {
                fresh,
                outputs,
                inputs_wire
            })
        )),
    ]
}

/// Bytes drawn mostly from the protocol's own alphabet, so parsers get past their first checks.
fn wire_bytes() -> impl Strategy<Value = Vec<u8>> {
    const ALPHABET: &[u8] = b"!?>#$%~*0123456789ABCDEFabcdefCLMNORSWXPEDGZ \r\n\x00\xff";
    prop::collection::vec(
        prop_oneof![prop::sample::select(ALPHABET), any::<u8>()],
        0..24,
    )
}

proptest! {
    #[test]
    fn request_round_trips(req in request(), id in any::<u8>(), cs in any::<bool>()) {
        let frame = req.encode(id, cs);
        prop_assert_eq!(frame.last(), Some(&CR));
        prop_assert!(frame.iter().filter(|b| **b == CR).count() == 1);
        let address = if req.is_broadcast() { Address::Broadcast } else { Address::Id(id) };
        prop_assert_eq!(decode_request(&frame, cs), Ok((address, req)));
    }

    #[test]
    fn answer_round_trips((req, ans) in exchange(), id in any::<u8>(), cs in any::<bool>()) {
        let from = match req { Request::Configure { new_id, .. } => new_id, _ => id };
        let frame = encode_answer(&ans, from, cs);
        prop_assert_eq!(parse_answer(&req, &frame, cs, id), Ok(ans));
    }

    #[test]
    fn refusal_round_trips(req in request(), id in any::<u8>(), cs in any::<bool>()) {
        prop_assume!(req.expects_answer());
        let invalid = encode_refusal(Refusal::InvalidCommand, id, cs);
        prop_assert_eq!(parse_answer(&req, &invalid, cs, id), Err(AsciiError::InvalidCommand));
        if req.is_output_write() {
            let param = encode_refusal(Refusal::ParameterError, id, cs);
            prop_assert_eq!(parse_answer(&req, &param, cs, id), Err(AsciiError::ParameterError));
            let safe = encode_refusal(Refusal::SafeMode, id, cs);
            prop_assert_eq!(parse_answer(&req, &safe, cs, id), Err(AsciiError::SafeMode));
        }
    }

    #[test]
    fn other_ids_are_told_apart(req in request(), id in any::<u8>(), other in any::<u8>()) {
        prop_assume!(id != other && req.expects_answer() && req != Request::ReadSynchronized);
        prop_assume!(!matches!(req, Request::Configure { .. }));
        let frame = encode_refusal(Refusal::InvalidCommand, other, false);
        prop_assert_eq!(
            parse_answer(&req, &frame, false, id),
            Err(AsciiError::WrongId { expected: id, got: other })
        );
    }

    #[test]
    fn random_bytes_never_panic(bytes in wire_bytes(), req in request(), id in any::<u8>(), cs in any::<bool>()) {
        let _ = decode_request(&bytes, cs);
        let _ = parse_answer(&req, &bytes, cs, id);
        // With a valid checksum the parsers go past the checksum check.
        let closed = close(bytes, true);
        let _ = decode_request(&closed, true);
        let _ = parse_answer(&req, &closed, true, id);
    }

    #[test]
    fn decode_errors_answer_only_their_own_id(bytes in wire_bytes(), id in any::<u8>()) {
        if let Err(err) = decode_request(&bytes, false) {
            if err.refusal(id).is_some() {
                let own = matches!(
                    err,
                    RequestError::UnknownCommand { address: Address::Id(a) }
                        | RequestError::BadParameter { address: Address::Id(a), .. } if a == id
                );
                prop_assert!(own);
            }
        }
    }
}
