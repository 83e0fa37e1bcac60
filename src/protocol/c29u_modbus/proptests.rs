//! Property tests: round trips of every request and answer, no panics on random bytes, and the
//! frame reader recovering frames from arbitrarily split streams.

use super::*;
use proptest::prelude::*;

fn channel() -> impl Strategy<Value = u8> {
    0u8..=7
}

/// A channel range `start..start+count` inside 0..8.
fn range() -> impl Strategy<Value = (u8, u8)> {
    (0u8..=7).prop_flat_map(|start| (Just(start), 1u8..=(8 - start)))
}

fn counter_function() -> impl Strategy<Value = CounterFunction> {
    prop_oneof![Just(CounterFunction::Holding), Just(CounterFunction::Input)]
}

fn coil_command() -> impl Strategy<Value = CoilCommand> {
    prop_oneof![
        (channel(), any::<bool>()).prop_map(|(channel, on)| CoilCommand::Output { channel, on }),
        Just(CoilCommand::ClearLatches),
        channel().prop_map(|channel| CoilCommand::ClearCounter { channel }),
    ]
}

fn coils_target() -> impl Strategy<Value = CoilsTarget> {
    prop_oneof![
        Just(CoilsTarget::Outputs),
        Just(CoilsTarget::ClearCounters),
        Just(CoilsTarget::SaveCounters),
    ]
}

fn vendor_request() -> impl Strategy<Value = VendorRequest> {
    use VendorRequest::*;
    prop_oneof![
        Just(ReadName),
        any::<u8>().prop_map(SetId),
        Just(ReadConfig),
        any::<u8>().prop_map(SetBaud),
        Just(ReadFirmware),
        Just(ReadResetFlag),
        Just(Reset),
        any::<u8>().prop_map(SetWatchdog),
        Just(ReadWatchdog),
        any::<u8>().prop_map(SetLedMode),
        any::<u8>().prop_map(SetPowerOnValue),
        Just(ReadPowerOnValue),
        any::<u8>().prop_map(SetSafeValue),
        Just(ReadSafeValue),
        Just(HostOk),
    ]
}

/// Every request the module accepts.
fn request() -> impl Strategy<Value = Request> {
    prop_oneof![
        proptest::sample::select(BitArea::ALL.to_vec()).prop_map(Request::ReadBits),
        (counter_function(), 1u8..=8)
            .prop_map(|(function, count)| Request::ReadCounters { function, count }),
        coil_command().prop_map(Request::WriteCoil),
        (coils_target(), range(), any::<u8>()).prop_map(|(target, (start, count), data)| {
            Request::WriteCoils {
                target,
                start,
                count,
                data,
            }
        }),
        vendor_request().prop_map(Request::Vendor),
    ]
}

/// The module's normal answer to a vendor request, with arbitrary data.
fn vendor_answer(req: VendorRequest) -> BoxedStrategy<Option<VendorResponse>> {
    use VendorResponse as R;
    match req {
        VendorRequest::ReadName => any::<u16>().prop_map(|c| Some(R::Name(c))).boxed(),
        VendorRequest::SetId(_) => Just(Some(R::IdChanged)).boxed(),
        VendorRequest::ReadConfig => any::<u8>()
            .prop_map(|baud_code| Some(R::Config { baud_code }))
            .boxed(),
        VendorRequest::SetBaud(_) => Just(Some(R::BaudChanged)).boxed(),
        VendorRequest::ReadFirmware => any::<(u8, u8, u8)>()
            .prop_map(|(year, month, day)| Some(R::Firmware { year, month, day }))
            .boxed(),
        VendorRequest::ReadResetFlag => any::<bool>().prop_map(|f| Some(R::ResetFlag(f))).boxed(),
        VendorRequest::Reset => Just(Some(R::ResetDone)).boxed(),
        VendorRequest::SetWatchdog(_) => Just(Some(R::WatchdogSet)).boxed(),
        VendorRequest::ReadWatchdog => any::<(bool, u8)>()
            .prop_map(|(enabled, tenths)| Some(R::Watchdog { enabled, tenths }))
            .boxed(),
        VendorRequest::SetLedMode(_) => Just(Some(R::LedModeSet)).boxed(),
        VendorRequest::SetPowerOnValue(_) => Just(Some(R::PowerOnValueSet)).boxed(),
        VendorRequest::ReadPowerOnValue => {
            any::<u8>().prop_map(|v| Some(R::PowerOnValue(v))).boxed()
        }
        VendorRequest::SetSafeValue(_) => Just(Some(R::SafeValueSet)).boxed(),
        VendorRequest::ReadSafeValue => any::<u8>().prop_map(|v| Some(R::SafeValue(v))).boxed(),
        VendorRequest::HostOk => Just(None).boxed(),
    }
}

/// A request with the module's normal answer to it (None for host OK).
fn exchange() -> impl Strategy<Value = (Request, Option<Response>)> {
    request().prop_flat_map(|req| {
        let answer: BoxedStrategy<Option<Response>> = match req {
            Request::ReadBits(_) => any::<u8>().prop_map(|b| Some(Response::Bits(b))).boxed(),
            Request::ReadCounters { function, count } => {
                proptest::collection::vec(any::<u16>(), usize::from(count))
                    .prop_map(move |values| Some(Response::Counters { function, values }))
                    .boxed()
            }
            Request::WriteCoil(cmd) => Just(Some(Response::CoilWritten(cmd))).boxed(),
            Request::WriteCoils {
                target,
                start,
                count,
                ..
            } => Just(Some(Response::CoilsWritten {
                target,
                start,
                count,
            }))
            .boxed(),
            Request::Vendor(v) => vendor_answer(v)
                .prop_map(|a| a.map(Response::Vendor))
                .boxed(),
        };
        (Just(req), answer)
    })
}

proptest! {
    #[test]
    fn requests_round_trip(req in request(), id in any::<u8>()) {
        let frame = req.encode(id);
        prop_assert_eq!(decode_request(&frame), Ok((id, req)));
        prop_assert_eq!(frame.first(), Some(&id));
        prop_assert_eq!(frame.get(1), Some(&req.function()));
    }

    #[test]
    fn answers_round_trip((req, answer) in exchange(), id in any::<u8>()) {
        prop_assert_eq!(req.expects_answer(), answer.is_some());
        if let Some(answer) = answer {
            let frame = encode_response(id, &answer);
            prop_assert_eq!(Some(frame.len()), req.answer_len());
            prop_assert_eq!(parse_response(&req, id, &frame), Ok(answer));
        }
    }

    #[test]
    fn exceptions_round_trip(req in request(), id in any::<u8>(), code in any::<u8>()) {
        prop_assume!(req.expects_answer());
        let code = ExceptionCode::from_byte(code);
        let function = req.function();
        let (frame, want) = if function == FC_VENDOR {
            (encode_vendor_error(id), ModbusError::VendorError)
        } else if code == ExceptionCode::SafeMode {
            (encode_exception(id, function, code), ModbusError::SafeMode { function })
        } else {
            (encode_exception(id, function, code), ModbusError::Exception { function, code })
        };
        prop_assert_eq!(parse_response(&req, id, &frame), Err(want));
    }

    #[test]
    fn refused_requests_decode_to_their_answer(bytes in proptest::collection::vec(any::<u8>(), 0..12)) {
        let frame = seal(&bytes);
        match decode_request(&frame) {
            Ok((id, req)) => {
                let again = req.encode(id);
                prop_assert_eq!(again.get(..2), frame.get(..2));
            }
            Err(e) => {
                if let Some(answer) = e.answer() {
                    prop_assert_eq!(answer.first(), bytes.first());
                    prop_assert!(answer.get(1).is_some_and(|f| f & EXCEPTION_FLAG != 0));
                }
            }
        }
    }

    #[test]
    fn random_bytes_never_panic(
        bytes in proptest::collection::vec(any::<u8>(), 0..300),
        req in request(),
        id in any::<u8>(),
    ) {
        let _ = decode_request(&bytes);
        let _ = parse_response(&req, id, &bytes);
        let _ = decode_request(&seal(&bytes));
        let _ = parse_response(&req, id, &seal(&bytes));
        for mut reader in [FrameReader::for_requests(), FrameReader::for_answers(), {
            let mut r = FrameReader::for_answers();
            r.expect_answer(id, &req);
            r
        }] {
            for frame in reader.push(&bytes) {
                prop_assert!(open_frame(&frame).is_some());
                prop_assert!(frame.len() <= MAX_FRAME_LEN);
            }
            prop_assert!(reader.pending().len() < MAX_FRAME_LEN);
            let _ = reader.end_of_silence();
        }
    }

    #[test]
    fn request_stream_split_anywhere_gives_the_frames_back(
        reqs in proptest::collection::vec((request(), any::<u8>()), 1..6),
        cuts in proptest::collection::vec(any::<prop::sample::Index>(), 0..8),
    ) {
        let frames: Vec<Vec<u8>> = reqs.iter().map(|(r, id)| r.encode(*id)).collect();
        let stream = frames.concat();
        let mut points: Vec<usize> = cuts.iter().map(|i| i.index(stream.len() + 1)).collect();
        points.sort_unstable();
        let mut reader = FrameReader::for_requests();
        let mut got = Vec::new();
        let mut last = 0;
        for p in points.into_iter().chain([stream.len()]) {
            got.extend(reader.push(&stream[last..p]));
            last = p;
        }
        prop_assert_eq!(got, frames);
        prop_assert_eq!(reader.discarded(), 0);
    }

    #[test]
    fn answer_stream_split_anywhere_gives_the_frame_back(
        (req, answer) in exchange(),
        id in any::<u8>(),
        cut in any::<prop::sample::Index>(),
        expect in any::<bool>(),
    ) {
        let Some(answer) = answer else { return Ok(()); };
        let frame = encode_response(id, &answer);
        let mut reader = FrameReader::for_answers();
        if expect {
            reader.expect_answer(id, &req);
        }
        let p = cut.index(frame.len() + 1);
        let mut got = reader.push(&frame[..p]);
        got.extend(reader.push(&frame[p..]));
        prop_assert_eq!(got, vec![frame]);
    }

    #[test]
    fn expected_answer_after_garbage_from_other_slaves(
        (req, answer) in exchange(),
        id in 1u8..=247,
        garbage in proptest::collection::vec(any::<u8>(), 0..20),
    ) {
        let Some(answer) = answer else { return Ok(()); };
        // Garbage that does not contain the slave's ID cannot start its answer.
        let garbage: Vec<u8> = garbage.into_iter().filter(|b| *b != id).collect();
        let frame = encode_response(id, &answer);
        let mut reader = FrameReader::for_answers();
        reader.expect_answer(id, &req);
        let got = reader.push(&[&garbage[..], &frame[..]].concat());
        prop_assert_eq!(got, vec![frame]);
        prop_assert_eq!(reader.discarded(), garbage.len() as u64);
    }
}
