//! Every example exchange of the manual's sections 7 and 8, with and without checksum; where an
//! example contradicts its own rule (docs/trp-c29u-protocol.md), the rule is tested and the
//! literal example documented.

use super::frame::close;
use super::*;
use crate::protocol::c29u::WatchdogTimeout;

fn ch(n: u8) -> Channel {
    Channel::new(n).unwrap()
}

fn framed(text: &str, cs: bool) -> Vec<u8> {
    close(text.as_bytes().to_vec(), cs)
}

/// `text` decodes to `request` for `address`, with and without checksum.
fn decodes(text: &str, address: Address, request: &Request) {
    for cs in [false, true] {
        assert_eq!(
            decode_request(&framed(text, cs), cs),
            Ok((address, request.clone())),
            "{text} checksum={cs}"
        );
    }
}

/// As `decodes`, and `request` encodes back to exactly `text`.
fn request(text: &str, address: Address, request: &Request) {
    decodes(text, address, request);
    let id = match address {
        Address::Id(id) => id,
        Address::Broadcast => 0x5A,
    };
    for cs in [false, true] {
        assert_eq!(
            request.encode(id, cs),
            framed(text, cs),
            "{request:?} checksum={cs}"
        );
    }
}

/// `text` parses as `answer` to `request` sent to `id`, with and without checksum.
fn parses(req: &Request, id: u8, text: &str, answer: &Answer) {
    for cs in [false, true] {
        assert_eq!(
            parse_answer(req, &framed(text, cs), cs, id),
            Ok(answer.clone()),
            "{text} checksum={cs}"
        );
    }
}

/// As `parses`, and `answer` encodes back to exactly `text` (from `answer_id`).
fn answer(req: &Request, id: u8, text: &str, answer_id: u8, ans: &Answer) {
    parses(req, id, text, ans);
    for cs in [false, true] {
        assert_eq!(
            encode_answer(ans, answer_id, cs),
            framed(text, cs),
            "{ans:?}"
        );
    }
}

/// `text` parses to the error `err` for `request` to `id`, with and without checksum.
fn refused(req: &Request, id: u8, text: &str, err: &AsciiError) {
    for cs in [false, true] {
        assert_eq!(
            parse_answer(req, &framed(text, cs), cs, id).as_ref(),
            Err(err),
            "{text} checksum={cs}"
        );
    }
}

fn malformed(req: &Request, id: u8, text: &str) {
    for cs in [false, true] {
        let got = parse_answer(req, &framed(text, cs), cs, id);
        assert!(
            matches!(got, Err(AsciiError::Malformed { .. })),
            "{text}: {got:?}"
        );
    }
}

fn decode_err(text: &str) -> RequestError {
    decode_request(&framed(text, false), false).unwrap_err()
}

#[test]
fn s7_checksum_rule_gives_d7_not_the_manuals_a1() {
    assert_eq!(checksum(b"$06M"), 0xD7);
    assert_eq!(Request::ReadName.encode(6, true), b"$06MD7\r");
    assert_eq!(
        decode_request(b"$06MD7\r", true),
        Ok((Address::Id(6), Request::ReadName))
    );
    // The manual's literal checksum is refused (the module would stay silent).
    let err = decode_request(b"$06MA1\r", true).unwrap_err();
    assert_eq!(
        err,
        RequestError::BadChecksum {
            expected: 0xD7,
            got: Some(0xA1)
        }
    );
    assert_eq!(err.refusal(6), None);
    assert_eq!(
        parse_answer(&Request::ReadName, b"!06TRPC29A1\r", true, 6),
        Err(AsciiError::BadChecksum {
            expected: checksum(b"!06TRPC29"),
            got: Some(0xA1)
        })
    );
}

#[test]
fn s8_3_configure_examples() {
    let to_01 = Request::Configure {
        new_id: 1,
        baud: BaudCode::from_baud(9600).unwrap(),
        format: DataFormat::default(),
    };
    request("%0001400600", Address::Id(0), &to_01);
    // The answer comes from the new ID.
    answer(&to_01, 0, "!01", 1, &Answer::Done);
    refused(
        &to_01,
        0,
        "!00",
        &AsciiError::WrongId {
            expected: 1,
            got: 0,
        },
    );
    // A refusal comes from the old ID.
    refused(&to_01, 0, "?00", &AsciiError::InvalidCommand);

    // "%000340054" (printed twice) has 7 characters after the ID, not 8: refused with ?00.
    let err = decode_err("%000340054");
    assert!(matches!(
        err,
        RequestError::BadParameter {
            address: Address::Id(0),
            output_write: false,
            ..
        }
    ));
    assert_eq!(err.refusal(0), Some(Refusal::InvalidCommand));
    // What it means: new ID 03, 4800 baud, checksum enabled; answered "!03".
    let to_03 = Request::Configure {
        new_id: 3,
        baud: BaudCode::from_baud(4800).unwrap(),
        format: DataFormat {
            checksum: true,
            ..DataFormat::default()
        },
    };
    request("%0003400540", Address::Id(0), &to_03);
    answer(&to_03, 0, "!03", 3, &Answer::Done);

    // Engineer mode: counters in hex.
    let hex = Request::Configure {
        new_id: 1,
        baud: BaudCode::new(0x06).unwrap(),
        format: DataFormat {
            hex_counters: true,
            ..DataFormat::default()
        },
    };
    request("%0101400601", Address::Id(1), &hex);
    answer(&hex, 1, "!01", 1, &Answer::Done);
    request("#010", Address::Id(1), &Request::ReadCounter(ch(0)));
    answer(
        &Request::ReadCounter(ch(0)),
        1,
        "!01001B",
        1,
        &Answer::Counter {
            value: 0x1B,
            hex: true,
        },
    );
    parses(
        &Request::ReadCounter(ch(0)),
        1,
        "!01001b",
        &Answer::Counter {
            value: 0x1B,
            hex: true,
        },
    );
}

#[test]
fn s8_3_configure_refuses_bad_parameters() {
    for text in ["%0001410600", "%0001400B00", "%0001400602", "%00014006G0"] {
        let err = decode_err(text);
        assert!(
            matches!(
                err,
                RequestError::BadParameter {
                    output_write: false,
                    ..
                }
            ),
            "{text}: {err:?}"
        );
        assert_eq!(err.refusal(0), Some(Refusal::InvalidCommand));
    }
}

#[test]
fn s8_4_output_writes() {
    // PP 0A and 00 both write all eight outputs; the encoder uses 00.
    decodes("#010A2F", Address::Id(1), &Request::WriteOutputs(0x2F));
    decodes("#010a2f", Address::Id(1), &Request::WriteOutputs(0x2F));
    answer(
        &Request::WriteOutputs(0x2F),
        1,
        ">",
        1,
        &Answer::OutputWritten,
    );
    request("#0100A8", Address::Id(1), &Request::WriteOutputs(0xA8));
    answer(
        &Request::WriteOutputs(0xA8),
        1,
        ">",
        1,
        &Answer::OutputWritten,
    );

    // "#01000G": data error, answered "!01" = parameter error.
    let err = decode_err("#01000G");
    assert!(matches!(
        err,
        RequestError::BadParameter {
            address: Address::Id(1),
            output_write: true,
            ..
        }
    ));
    assert_eq!(err.refusal(1), Some(Refusal::ParameterError));
    assert_eq!(err.refusal(2), None, "another module's frame");
    assert_eq!(encode_refusal(Refusal::ParameterError, 1, false), b"!01\r");
    refused(
        &Request::WriteOutputs(0),
        1,
        "!01",
        &AsciiError::ParameterError,
    );

    let single = [
        ("#011001", 0, true),
        ("#011201", 2, true),
        ("#011700", 7, false),
    ];
    for (text, n, on) in single {
        let r = Request::WriteOutput { channel: ch(n), on };
        request(text, Address::Id(1), &r);
        answer(&r, 1, ">", 1, &Answer::OutputWritten);
    }
}

#[test]
fn s8_4_bad_output_parameters_are_parameter_errors() {
    // Channel 8..F (the manual's "L=0~F" is from another model), DD not 00/01, unknown PP.
    for text in ["#011801", "#011F01", "#011002", "#01052F", "#01ZZ00"] {
        let err = decode_err(text);
        assert_eq!(err.refusal(1), Some(Refusal::ParameterError), "{text}");
    }
}

#[test]
fn s8_5_to_8_8_counters() {
    request("#012", Address::Id(1), &Request::ReadCounter(ch(2)));
    answer(
        &Request::ReadCounter(ch(2)),
        1,
        "!0100023",
        1,
        &Answer::Counter {
            value: 23,
            hex: false,
        },
    );
    // Channels 0-7 (8-5 says 0-3).
    request("#017", Address::Id(1), &Request::ReadCounter(ch(7)));
    assert_eq!(decode_err("#018").refusal(1), Some(Refusal::InvalidCommand));

    request("#01C2", Address::Id(1), &Request::ClearCounter(ch(2)));
    answer(&Request::ClearCounter(ch(2)), 1, "!01", 1, &Answer::Done);
    assert_eq!(
        decode_err("#01C9").refusal(1),
        Some(Refusal::InvalidCommand)
    );

    // "#DCW" / "#DCS" (8-7, 8-8) mean "#IDCW" / "#IDCS".
    request("#01CW", Address::Id(1), &Request::ClearCounters);
    answer(&Request::ClearCounters, 1, "!01", 1, &Answer::Done);
    request("#01CS", Address::Id(1), &Request::SaveCounters);
    answer(&Request::SaveCounters, 1, "!01", 1, &Answer::Done);
    // After power fail or reset, the saved value.
    answer(
        &Request::ReadCounter(ch(0)),
        1,
        "!0100187",
        1,
        &Answer::Counter {
            value: 187,
            hex: false,
        },
    );
    malformed(&Request::ReadCounter(ch(0)), 1, "!0165536");
    malformed(&Request::ReadCounter(ch(0)), 1, "!01023");
    malformed(&Request::ReadCounter(ch(0)), 1, "!01000023");
}

#[test]
fn s8_9_and_8_10_latches() {
    request(
        "$01L0",
        Address::Id(1),
        &Request::ReadLatch(LatchLevel::Low),
    );
    request(
        "$01L1",
        Address::Id(1),
        &Request::ReadLatch(LatchLevel::High),
    );
    answer(
        &Request::ReadLatch(LatchLevel::Low),
        1,
        "!010200",
        1,
        &Answer::Latch(0x02),
    );
    // The manual's command line writes "#IDLS": read as "$IDLS", as 8-9's syntax table has it.
    assert_eq!(
        decode_err("#01L0"),
        RequestError::UnknownCommand {
            address: Address::Id(1)
        }
    );
    assert_eq!(
        decode_err("$01L2").refusal(1),
        Some(Refusal::InvalidCommand)
    );
    // The manual's "!010200 " carries a stray space.
    malformed(&Request::ReadLatch(LatchLevel::Low), 1, "!010200 ");

    request("$01C", Address::Id(1), &Request::ClearLatch);
    answer(&Request::ClearLatch, 1, "!01", 1, &Answer::Done);
}

#[test]
fn s8_11_dio_status() {
    request("$016", Address::Id(1), &Request::ReadDio);
    answer(
        &Request::ReadDio,
        1,
        "!0121CF",
        1,
        &Answer::Dio {
            outputs: 0x21,
            inputs: 0xCF,
        },
    );
    parses(
        &Request::ReadDio,
        1,
        "!0121cf",
        &Answer::Dio {
            outputs: 0x21,
            inputs: 0xCF,
        },
    );
}

#[test]
fn s8_12_config_without_the_manuals_space() {
    request("$012", Address::Id(1), &Request::ReadConfig);
    let report = ConfigReport {
        module_type: 0x40,
        baud_code: 0x06,
        format: 0x03,
    };
    answer(
        &Request::ReadConfig,
        1,
        "!01400603",
        1,
        &Answer::Config(report),
    );
    assert_eq!(report.model(), ConfigReport::MODEL_C29U);
    assert!(!report.checksum() && !report.falling_edge());
    assert_eq!(report.baud().map(BaudCode::baud), Some(9600));
    // The manual prints "! 01400603".
    malformed(&Request::ReadConfig, 1, "! 01400603");
}

#[test]
fn s8_13_to_8_16_reset_name_firmware_reset_status() {
    request("$01RS", Address::Id(1), &Request::Reset);
    answer(&Request::Reset, 1, "!01", 1, &Answer::Done);

    request("$01M", Address::Id(1), &Request::ReadName);
    answer(
        &Request::ReadName,
        1,
        "!01TRPC29",
        1,
        &Answer::Name(ModuleName::new("TRPC29").unwrap()),
    );

    request("$01F", Address::Id(1), &Request::ReadFirmware);
    // The manual's answer: opaque text, no six-digit date at its end.
    let manual = FirmwareVersion::new("C29M0703").unwrap();
    answer(
        &Request::ReadFirmware,
        1,
        "!01C29M0703",
        1,
        &Answer::Firmware(manual.clone()),
    );
    assert_eq!(manual.date(), None);
    // The simulator answers model C29M, 09-07-03 (the date of 10-5).
    let notes = FirmwareVersion::new("C29M090703").unwrap();
    answer(
        &Request::ReadFirmware,
        1,
        "!01C29M090703",
        1,
        &Answer::Firmware(notes.clone()),
    );
    assert_eq!(notes.model(), "C29M");
    assert_eq!(
        notes.date(),
        Some(FirmwareDate {
            year: 9,
            month: 7,
            day: 3
        })
    );

    request("$015", Address::Id(1), &Request::ReadResetStatus);
    answer(
        &Request::ReadResetStatus,
        1,
        "!011",
        1,
        &Answer::ResetStatus(true),
    );
    answer(
        &Request::ReadResetStatus,
        1,
        "!010",
        1,
        &Answer::ResetStatus(false),
    );
}

#[test]
fn s8_17_rename() {
    let name = ModuleName::new("ABCDE").unwrap();
    request("~01OABCDE", Address::Id(1), &Request::SetName(name.clone()));
    answer(&Request::SetName(name.clone()), 1, "!01", 1, &Answer::Done);
    answer(&Request::ReadName, 1, "!01ABCDE", 1, &Answer::Name(name));
    assert_eq!(decode_err("~01O").refusal(1), Some(Refusal::InvalidCommand));
    assert_eq!(
        decode_err("~01OABCDEFG").refusal(1),
        Some(Refusal::InvalidCommand)
    );
}

#[test]
fn s8_18_led_mode_answers_on_or_off() {
    request("~01LED0", Address::Id(1), &Request::SetLedMode(false));
    answer(
        &Request::SetLedMode(false),
        1,
        "!01OFF",
        1,
        &Answer::Led(false),
    );
    request("~01LED1", Address::Id(1), &Request::SetLedMode(true));
    answer(
        &Request::SetLedMode(true),
        1,
        "!01ON",
        1,
        &Answer::Led(true),
    );
    assert_eq!(
        decode_err("~01LED2").refusal(1),
        Some(Refusal::InvalidCommand)
    );
}

#[test]
fn s8_19_to_8_21_watchdog() {
    request("~01WEFF", Address::Id(1), &Request::EnableWatchdog(0xFF));
    answer(&Request::EnableWatchdog(0xFF), 1, "!01", 1, &Answer::Done);
    request("~01WE00", Address::Id(1), &Request::EnableWatchdog(0));
    answer(&Request::EnableWatchdog(0), 1, "!01", 1, &Answer::Done);
    assert_eq!(
        decode_err("~01WEF").refusal(1),
        Some(Refusal::InvalidCommand)
    );

    // Safe mode: an output write is answered "!IDWE".
    assert_eq!(encode_refusal(Refusal::SafeMode, 1, false), b"!01WE\r");
    refused(
        &Request::WriteOutputs(0x2F),
        1,
        "!01WE",
        &AsciiError::SafeMode,
    );
    let single = Request::WriteOutput {
        channel: ch(3),
        on: true,
    };
    refused(&single, 1, "!01WE", &AsciiError::SafeMode);
    assert!(AsciiError::SafeMode.is_output_refusal());
    assert!(AsciiError::ParameterError.is_output_refusal());
    assert!(!AsciiError::WrongId {
        expected: 1,
        got: 2
    }
    .is_output_refusal());

    request("~01WD", Address::Id(1), &Request::DisableWatchdog);
    answer(&Request::DisableWatchdog, 1, "!01", 1, &Answer::Done);

    // 8-21: 0F x 0.1 s is 1.5 s (the manual says 1.6). `D` with a timeout still set is a fired
    // watchdog ("disable or safe mode": disabling clears the timeout).
    let t = |n| WatchdogTimeout::from_tenths(n).unwrap();
    request("~01WR", Address::Id(1), &Request::ReadWatchdog);
    answer(
        &Request::ReadWatchdog,
        1,
        "!01WD0F",
        1,
        &Answer::Watchdog(WatchdogReading::Fired(t(0x0F))),
    );
    assert_eq!(
        t(0x0F).as_duration(),
        std::time::Duration::from_millis(1500)
    );
    answer(
        &Request::ReadWatchdog,
        1,
        "!01WEFF",
        1,
        &Answer::Watchdog(WatchdogReading::Counting(t(0xFF))),
    );
    parses(
        &Request::ReadWatchdog,
        1,
        "!01WD0f",
        &Answer::Watchdog(WatchdogReading::Fired(t(15))),
    );
    answer(
        &Request::ReadWatchdog,
        1,
        "!01WD00",
        1,
        &Answer::Watchdog(WatchdogReading::Off),
    );
    // 8-21's second answer form, a bare `!ID`: no timeout set.
    parses(
        &Request::ReadWatchdog,
        1,
        "!01",
        &Answer::Watchdog(WatchdogReading::Off),
    );
}

#[test]
fn s8_19_safe_mode_rule_for_refused_output_writes() {
    let t = WatchdogTimeout::from_tenths(5).unwrap();
    // `!IDWE` says so itself.
    assert!(AsciiError::SafeMode.means_safe_mode(None));
    // Any other refusal is safe mode only while the watchdog reads as fired (8-19 as read) ...
    for refusal in [AsciiError::InvalidCommand, AsciiError::ParameterError] {
        assert!(refusal.means_safe_mode(Some(WatchdogReading::Fired(t))));
        // ... not when it is merely off (`WD00`) or counting.
        assert!(!refusal.means_safe_mode(Some(WatchdogReading::Off)));
        assert!(!refusal.means_safe_mode(Some(WatchdogReading::Counting(t))));
        assert!(!refusal.means_safe_mode(None));
    }
    // An answer from another module is no refusal at all.
    let wrong = AsciiError::WrongId {
        expected: 1,
        got: 2,
    };
    assert!(!wrong.means_safe_mode(Some(WatchdogReading::Fired(t))));
}

#[test]
fn s8_22_and_8_25_broadcasts_have_no_id_and_no_answer() {
    request("~**", Address::Broadcast, &Request::HostOk);
    request("#**", Address::Broadcast, &Request::Synchronize);
    assert_eq!(Request::HostOk.encode(7, false), b"~**\r");
    assert!(!Request::HostOk.expects_answer());
    assert!(!Request::Synchronize.expects_answer());
    assert!(Request::ReadSynchronized.expects_answer());
    assert_eq!(
        parse_answer(&Request::HostOk, b"!01\r", false, 1),
        Err(AsciiError::NoAnswerExpected)
    );
    // A broadcast never draws a refusal.
    let err = decode_err("#**X");
    assert_eq!(err.refusal(1), None);
}

#[test]
fn s8_23_and_8_24_power_on_and_safe_values() {
    request("~014S", Address::Id(1), &Request::ReadPreset(Preset::Safe));
    request(
        "~014P",
        Address::Id(1),
        &Request::ReadPreset(Preset::PowerOn),
    );
    answer(
        &Request::ReadPreset(Preset::Safe),
        1,
        "!01080F",
        1,
        &Answer::Preset {
            outputs: 0x08,
            inputs: 0x0F,
        },
    );
    assert_eq!(
        decode_err("~014X").refusal(1),
        Some(Refusal::InvalidCommand)
    );

    request("#010013", Address::Id(1), &Request::WriteOutputs(0x13));
    // 8-4: an output write succeeds with ">" ...
    answer(
        &Request::WriteOutputs(0x13),
        1,
        ">",
        1,
        &Answer::OutputWritten,
    );
    // ... the manual's "!01" here would be a parameter error.
    refused(
        &Request::WriteOutputs(0x13),
        1,
        "!01",
        &AsciiError::ParameterError,
    );
    request(
        "~015P",
        Address::Id(1),
        &Request::SavePreset(Preset::PowerOn),
    );
    request("~015S", Address::Id(1), &Request::SavePreset(Preset::Safe));
    answer(
        &Request::SavePreset(Preset::PowerOn),
        1,
        "!01",
        1,
        &Answer::Done,
    );
}

#[test]
fn s8_26_synchronized_data_with_or_without_id() {
    // The manual's "###" is the "#**" broadcast of 8-25; "#**" is what the driver sends.
    decodes("###", Address::Broadcast, &Request::Synchronize);
    assert_eq!(Request::Synchronize.encode(1, false), b"#**\r");
    assert_eq!(
        decode_err("###X").refusal(1),
        None,
        "a broadcast draws no refusal"
    );
    request("$014", Address::Id(1), &Request::ReadSynchronized);
    let fresh = Answer::Synchronized(SynchronizedData {
        fresh: true,
        outputs: 0x01,
        inputs_wire: 0x0E,
    });
    answer(&Request::ReadSynchronized, 1, "!1010E00", 1, &fresh);
    parses(&Request::ReadSynchronized, 1, "!011010E00", &fresh);
    parses(&Request::ReadSynchronized, 1, "!1010e00", &fresh);
    answer(
        &Request::ReadSynchronized,
        1,
        "!0010E00",
        1,
        &Answer::Synchronized(SynchronizedData {
            fresh: false,
            outputs: 0x01,
            inputs_wire: 0x0E,
        }),
    );
    refused(
        &Request::ReadSynchronized,
        1,
        "!021010E00",
        &AsciiError::WrongId {
            expected: 1,
            got: 2,
        },
    );
    // Before any "#**": "?ID".
    refused(
        &Request::ReadSynchronized,
        1,
        "?01",
        &AsciiError::InvalidCommand,
    );
    malformed(&Request::ReadSynchronized, 1, "!2010E00");
}

#[test]
fn invalid_commands_and_ids() {
    let err = decode_err("$01Z");
    assert_eq!(
        err,
        RequestError::UnknownCommand {
            address: Address::Id(1)
        }
    );
    assert_eq!(err.refusal(1), Some(Refusal::InvalidCommand));
    assert_eq!(err.refusal(2), None);
    assert_eq!(encode_refusal(Refusal::InvalidCommand, 1, false), b"?01\r");
    refused(&Request::ReadDio, 1, "?01", &AsciiError::InvalidCommand);
    refused(
        &Request::ReadDio,
        1,
        "?02",
        &AsciiError::WrongId {
            expected: 1,
            got: 2,
        },
    );
    refused(
        &Request::ReadDio,
        1,
        "!020000",
        &AsciiError::WrongId {
            expected: 1,
            got: 2,
        },
    );
    // No address to answer to: silence.
    for text in ["", "$", "$0", "$G16", "@016", "\n$016"] {
        assert!(
            matches!(decode_err(text), RequestError::Malformed { .. }),
            "{text:?}"
        );
    }
    // Lower-case IDs are accepted from hosts too.
    decodes("$0a6", Address::Id(0x0A), &Request::ReadDio);
}

#[test]
fn answers_of_the_wrong_shape_are_malformed() {
    malformed(&Request::ReadDio, 1, "!01");
    malformed(&Request::ClearLatch, 1, "!0100");
    malformed(&Request::WriteOutputs(1), 1, "!01XX");
    malformed(&Request::WriteOutputs(1), 1, ">>");
    malformed(&Request::ReadDio, 1, ">");
    malformed(&Request::SetLedMode(true), 1, "!01on");
    malformed(&Request::ReadWatchdog, 1, "!01WX0F");
    malformed(&Request::ReadResetStatus, 1, "!012");
    malformed(&Request::ReadName, 1, "!01");
    malformed(&Request::ReadName, 1, "!01ABCDEFG");
    malformed(&Request::ReadDio, 1, "");
    malformed(&Request::ReadDio, 1, "?0");
    // A checksum expected but absent.
    assert!(matches!(
        parse_answer(&Request::ReadDio, b"!0121CF\r", true, 1),
        Err(AsciiError::BadChecksum { .. })
    ));
}

#[test]
fn the_longest_request_is_8_1s_configure() {
    let configure = Request::Configure {
        new_id: 1,
        baud: BaudCode::from_baud(9600).unwrap(),
        format: DataFormat::default(),
    };
    let name = Request::SetName(ModuleName::new("ABCDEF").unwrap());
    // Without the CR (and checksum) the encodings add.
    let body = |r: &Request| r.encode(1, false).len() - 1;
    assert_eq!(body(&configure), LONGEST_REQUEST);
    assert!(body(&name) < LONGEST_REQUEST);
}
