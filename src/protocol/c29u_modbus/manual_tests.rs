//! Every example exchange of manual section 10, with the CRCs the manual leaves out, and the
//! examples docs/trp-c29u-protocol.md corrects kept as tests of the difference.

use super::*;

/// Hex text (spaces between bytes) to bytes.
fn hex(text: &str) -> Vec<u8> {
    text.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

/// Checks one exchange: the request encodes to `sent` + CRC and decodes back; the answer
/// `answer` + CRC encodes from `response` and parses back against the request.
fn exchange(sent: &str, request: Request, answer: &str, response: Response) {
    let id = hex(sent)[0];
    let sent = seal(&hex(sent));
    assert_eq!(request.encode(id), sent, "request {request:?}");
    assert_eq!(decode_request(&sent), Ok((id, request)));
    let answer = seal(&hex(answer));
    assert_eq!(
        encode_response(id, &response),
        answer,
        "answer {response:?}"
    );
    assert_eq!(parse_response(&request, id, &answer), Ok(response));
    let mut reader = FrameReader::for_answers();
    reader.expect_answer(id, &request);
    assert_eq!(reader.push(&answer), vec![answer.clone()]);
}

fn vendor(v: VendorRequest) -> Request {
    Request::Vendor(v)
}

fn vendor_ok(v: VendorResponse) -> Response {
    Response::Vendor(v)
}

#[test]
fn crcs_of_manual_frames_on_the_wire() {
    // The CRCs the manual omits, written out once so a change of codec shows here.
    assert_eq!(seal(&hex("01 46 00 00")), hex("01 46 00 00 E0 0D"));
    assert_eq!(
        seal(&hex("01 05 00 03 FF 00")),
        hex("01 05 00 03 FF 00 7C 3A")
    );
    assert_eq!(
        seal(&hex("01 01 00 00 00 08")),
        hex("01 01 00 00 00 08 3D CC")
    );
    assert_eq!(
        seal(&hex("01 04 00 00 00 04")),
        hex("01 04 00 00 00 04 F1 C9")
    );
}

#[test]
fn ex_10_1_read_name() {
    exchange(
        "01 46 00 00",
        vendor(VendorRequest::ReadName),
        "01 46 00 00 0C 29 00",
        vendor_ok(VendorResponse::Name(0x0C29)),
    );
    assert_eq!(model_name(0x0C29), "C29");
}

#[test]
fn ex_10_1_error_answer() {
    let req = vendor(VendorRequest::ReadName);
    assert_eq!(
        parse_response(&req, 1, &seal(&hex("01 C6 00"))),
        Err(ModbusError::VendorError)
    );
    assert_eq!(encode_vendor_error(1), seal(&hex("01 C6 00")));
}

#[test]
fn ex_10_2_set_id_answers_from_the_old_id() {
    // 10-2 as read: the module answers from its old ID (02), then uses the new one (03).
    exchange(
        "02 46 04 03 00 00 00",
        vendor(VendorRequest::SetId(3)),
        "02 46 04 00 00 00 00",
        vendor_ok(VendorResponse::IdChanged),
    );
}

#[test]
fn ex_10_2_literal_answer_from_01_is_another_slave() {
    // The manual shows `02 46 04 03 …` answered by `01 46 04 …`; the project reads that as
    // an answer from the wrong slave.
    let req = vendor(VendorRequest::SetId(3));
    assert_eq!(
        parse_response(&req, 2, &seal(&hex("01 46 04 00 00 00 00"))),
        Err(ModbusError::WrongId {
            expected: 2,
            got: 1
        })
    );
}

#[test]
fn ex_10_3_read_config() {
    exchange(
        "01 46 05 00",
        vendor(VendorRequest::ReadConfig),
        "01 46 05 00 06 00 00 00 00 00 00",
        vendor_ok(VendorResponse::Config { baud_code: 0x06 }),
    );
}

#[test]
fn ex_10_4_set_baud() {
    exchange(
        "01 46 06 00 0A 00 00 00 00 00 00",
        vendor(VendorRequest::SetBaud(0x0A)),
        "01 46 06 00 00 00 00 00 00 00",
        vendor_ok(VendorResponse::BaudChanged),
    );
}

#[test]
fn ex_10_5_firmware() {
    exchange(
        "01 46 07 00",
        vendor(VendorRequest::ReadFirmware),
        "01 46 07 09 07 03 00",
        vendor_ok(VendorResponse::Firmware {
            year: 9,
            month: 7,
            day: 3,
        }),
    );
}

#[test]
fn ex_10_6_reset_flag() {
    // The manual writes the flag as "1"; it is the byte 01.
    exchange(
        "01 46 08 00",
        vendor(VendorRequest::ReadResetFlag),
        "01 46 08 01 00",
        vendor_ok(VendorResponse::ResetFlag(true)),
    );
}

#[test]
fn ex_10_7_reset() {
    exchange(
        "01 46 09 00",
        vendor(VendorRequest::Reset),
        "01 46 09 00",
        vendor_ok(VendorResponse::ResetDone),
    );
}

#[test]
fn ex_10_8_watchdog_500_ms() {
    exchange(
        "01 46 0B 05 00",
        vendor(VendorRequest::SetWatchdog(0x05)),
        "01 46 0B 00",
        vendor_ok(VendorResponse::WatchdogSet),
    );
}

#[test]
fn ex_10_9_read_watchdog_en_wt() {
    // 10-9 as read: `ID 46 0C EN WT`; the example `01 46 0C 01 0F` = enabled, 1.5 s.
    exchange(
        "01 46 0C 00",
        vendor(VendorRequest::ReadWatchdog),
        "01 46 0C 01 0F",
        vendor_ok(VendorResponse::Watchdog {
            enabled: true,
            tenths: 0x0F,
        }),
    );
}

#[test]
fn ex_10_9_format_line_single_byte_is_not_accepted() {
    // The format line `ID 46 0C WT` (one byte) contradicts the example; the project reads two.
    let req = vendor(VendorRequest::ReadWatchdog);
    assert!(matches!(
        parse_response(&req, 1, &seal(&hex("01 46 0C 0F"))),
        Err(ModbusError::Malformed { .. })
    ));
}

#[test]
fn ex_10_10_led_mode() {
    exchange(
        "01 46 0D 01 00",
        vendor(VendorRequest::SetLedMode(1)),
        "01 46 0D 00",
        vendor_ok(VendorResponse::LedModeSet),
    );
}

#[test]
fn ex_10_11_set_power_on_value() {
    exchange(
        "01 46 27 01 00",
        vendor(VendorRequest::SetPowerOnValue(0x01)),
        "01 46 27 00",
        vendor_ok(VendorResponse::PowerOnValueSet),
    );
    // "Then send 01 46 09 00": the reset that loads it (answer as 10-7).
    assert_eq!(
        vendor(VendorRequest::Reset).encode(1),
        seal(&hex("01 46 09 00"))
    );
}

#[test]
fn ex_10_12_power_on_value_is_the_byte() {
    // 10-12 as read: `01 46 28 08` means the value 0x08, not the "00010011" the manual prints.
    exchange(
        "01 46 28 00",
        vendor(VendorRequest::ReadPowerOnValue),
        "01 46 28 08",
        vendor_ok(VendorResponse::PowerOnValue(0x08)),
    );
    let parsed = parse_response(
        &vendor(VendorRequest::ReadPowerOnValue),
        1,
        &seal(&hex("01 46 28 08")),
    );
    assert_ne!(
        parsed,
        Ok(vendor_ok(VendorResponse::PowerOnValue(0b0001_0011)))
    );
}

#[test]
fn ex_10_13_set_safe_value_then_watchdog() {
    exchange(
        "01 46 29 14 00",
        vendor(VendorRequest::SetSafeValue(0x14)),
        "01 46 29 00",
        vendor_ok(VendorResponse::SafeValueSet),
    );
    exchange(
        "01 46 0B 12 00",
        vendor(VendorRequest::SetWatchdog(0x12)),
        "01 46 0B 00",
        vendor_ok(VendorResponse::WatchdogSet),
    );
}

#[test]
fn ex_10_14_read_safe_value() {
    exchange(
        "01 46 2A 00",
        vendor(VendorRequest::ReadSafeValue),
        "01 46 2A 12",
        vendor_ok(VendorResponse::SafeValue(0x12)),
    );
}

#[test]
fn ex_10_15_host_ok_has_no_answer() {
    let req = vendor(VendorRequest::HostOk);
    let sent = seal(&hex("01 46 2F 00"));
    assert_eq!(req.encode(1), sent);
    assert_eq!(decode_request(&sent), Ok((1, req)));
    assert!(!req.expects_answer());
}

#[test]
fn ex_10_16_single_output() {
    exchange(
        "01 05 00 03 FF 00",
        Request::WriteCoil(CoilCommand::Output {
            channel: 3,
            on: true,
        }),
        "01 05 00 03 FF 00",
        Response::CoilWritten(CoilCommand::Output {
            channel: 3,
            on: true,
        }),
    );
    exchange(
        "01 05 00 02 00 00",
        Request::WriteCoil(CoilCommand::Output {
            channel: 2,
            on: false,
        }),
        "01 05 00 02 00 00",
        Response::CoilWritten(CoilCommand::Output {
            channel: 2,
            on: false,
        }),
    );
}

#[test]
fn ex_10_16_clear_latches_and_counter() {
    exchange(
        "01 05 01 00 00 00",
        Request::WriteCoil(CoilCommand::ClearLatches),
        "01 05 01 00 00 00",
        Response::CoilWritten(CoilCommand::ClearLatches),
    );
    exchange(
        "01 05 02 06 00 00",
        Request::WriteCoil(CoilCommand::ClearCounter { channel: 6 }),
        "01 05 02 06 00 00",
        Response::CoilWritten(CoilCommand::ClearCounter { channel: 6 }),
    );
}

#[test]
fn ex_10_16_safe_mode_and_error_answers() {
    let req = Request::WriteCoil(CoilCommand::Output {
        channel: 3,
        on: true,
    });
    assert_eq!(
        encode_exception(1, 0x05, ExceptionCode::SafeMode),
        seal(&hex("01 85 FF"))
    );
    assert_eq!(
        parse_response(&req, 1, &seal(&hex("01 85 FF"))),
        Err(ModbusError::SafeMode { function: 0x05 })
    );
    // 10-16's note: "you will get the response ID 8F FF" to a 05 output write in safe mode.
    assert_eq!(
        parse_response(&req, 1, &seal(&hex("01 8F FF"))),
        Err(ModbusError::SafeMode { function: 0x05 })
    );
    let mut reader = FrameReader::for_answers();
    reader.expect_answer(1, &req);
    assert_eq!(
        reader.push(&seal(&hex("01 8F FF"))),
        vec![seal(&hex("01 8F FF"))],
        "the reader takes 8F FF as the answer to a 05 request"
    );
    assert_eq!(
        parse_response(&req, 1, &seal(&hex("01 85 02"))),
        Err(ModbusError::Exception {
            function: 0x05,
            code: ExceptionCode::StartChannel
        })
    );
}

#[test]
fn ex_10_17_read_bits() {
    exchange(
        "01 01 00 00 00 08",
        Request::ReadBits(BitArea::Outputs),
        "01 01 01 36",
        Response::Bits(0x36),
    );
    exchange(
        "01 01 00 20 00 08",
        Request::ReadBits(BitArea::Inputs),
        "01 01 01 DF",
        Response::Bits(0xDF),
    );
    // The manual writes the quantity as "00 8".
    exchange(
        "01 01 00 40 00 08",
        Request::ReadBits(BitArea::LatchedLow),
        "01 01 01 01",
        Response::Bits(0x01),
    );
    assert_eq!(
        Request::ReadBits(BitArea::LatchedHigh).encode(1),
        seal(&hex("01 01 00 60 00 08"))
    );
}

#[test]
fn ex_10_18_holding_counters() {
    exchange(
        "01 03 00 00 00 02",
        Request::ReadCounters {
            function: CounterFunction::Holding,
            count: 2,
        },
        "01 03 04 00 28 00 5A",
        Response::Counters {
            function: CounterFunction::Holding,
            values: vec![0x28, 0x5A],
        },
    );
}

#[test]
fn ex_10_19_input_counters() {
    exchange(
        "01 04 00 00 00 04",
        Request::read_counters(4),
        "01 04 08 00 28 00 5A 00 53 00 55",
        Response::Counters {
            function: CounterFunction::Input,
            values: vec![0x28, 0x5A, 0x53, 0x55],
        },
    );
}

#[test]
fn ex_10_18_10_19_the_start_channel_is_always_00() {
    // "Start channel number SS=00": the only start the manual gives; any other is refused with
    // the start channel error of 10-18/10-19's answer table.
    for function in [0x03, 0x04] {
        assert_eq!(
            decode_request(&seal(&[1, function, 0x00, 0x02, 0x00, 0x02])),
            Err(RequestError::Exception {
                id: 1,
                function,
                code: ExceptionCode::StartChannel
            })
        );
    }
    // So channel 3 alone is read as the last of four.
    assert_eq!(
        Request::read_counters(4).encode(1),
        seal(&hex("01 04 00 00 00 04"))
    );
}

#[test]
fn ex_10_20_write_outputs() {
    exchange(
        "01 0F 00 00 00 08 01 25",
        Request::write_outputs(0x25),
        "01 0F 00 00 00 08",
        Response::CoilsWritten {
            target: CoilsTarget::Outputs,
            start: 0,
            count: 8,
        },
    );
}

#[test]
fn ex_10_20_clear_counters_echoes_address_and_quantity() {
    // 10-20 as read: clearing CH4-7 is answered `01 0F 02 04 00 04`.
    exchange(
        "01 0F 02 04 00 04 01 00",
        Request::clear_counters(4, 4),
        "01 0F 02 04 00 04",
        Response::CoilsWritten {
            target: CoilsTarget::ClearCounters,
            start: 4,
            count: 4,
        },
    );
}

#[test]
fn ex_10_20_literal_clear_answer_is_rejected() {
    // The manual's `01 0F 02 00 00 0F` echoes neither address nor quantity.
    let parsed = parse_response(
        &Request::clear_counters(4, 4),
        1,
        &seal(&hex("01 0F 02 00 00 0F")),
    );
    assert!(matches!(parsed, Err(ModbusError::Malformed { .. })));
}

#[test]
fn ex_10_20_save_counters() {
    exchange(
        "01 0F 03 00 00 08 01 00",
        Request::save_counters(),
        "01 0F 03 00 00 08",
        Response::CoilsWritten {
            target: CoilsTarget::SaveCounters,
            start: 0,
            count: 8,
        },
    );
}

#[test]
fn ex_10_20_safe_mode_answer() {
    assert_eq!(
        parse_response(&Request::write_outputs(0x25), 1, &seal(&hex("01 8F FF"))),
        Err(ModbusError::SafeMode { function: 0x0F })
    );
}
