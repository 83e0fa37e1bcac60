//! The simulated TRP-C29U's Modbus RTU front end: frames requests out of the byte stream,
//! applies them to the protocol-agnostic model, and encodes the answers (sections 9-10).
//!
//! Readings this front end follows, where the manual is silent:
//! - Slave ID 0 (Modbus broadcast) is not supported: such frames are ignored, not executed.
//! - Refused model calls map to exception codes: safe mode -> FF, bad channel -> 02 (start
//!   channel), bad value -> 01 (data format), anything else -> 00 (syntax); any refused vendor
//!   (46) command answers `ID C6 00`.
//! - 46 0C answers EN = 1 while a timeout is set, even once it has fired (the ASCII `~IDWR`
//!   reports a fired watchdog as "D"; 10-9 as read defines only "EN 1 = enabled").
//! - 46 00 always answers the model code `0C 29` ("C29"); the settable ASCII name is not used.
//! - 03/04 read counters from start 00 only (10-18/10-19 give "SS=00"); another start is
//!   refused with 02 (start channel), by `decode_request`.
//! - 0F 00 with a start and count other than 0 and 8 writes only those channels (bit 0 of DD =
//!   channel NN), as standard Modbus does; 0F 03 saves all counters whatever the range.

use super::c29u::{C29uModel, C29uModelError, FIRMWARE_DATE};
use crate::protocol::c29u_modbus::{
    decode_request, encode_exception, encode_response, encode_vendor_error, BitArea, CoilCommand,
    CoilsTarget, ExceptionCode, FrameReader, Request, Response, VendorRequest, VendorResponse,
    NAME_CODE,
};

/// How the module answers one complete frame: `None` is silence (another slave ID, broadcast,
/// bad CRC, host OK).
pub fn answer(model: &mut C29uModel, frame: &[u8]) -> Option<Vec<u8>> {
    let my_id = model.config().id;
    match decode_request(frame) {
        Err(refused) => {
            if my_id != 0 && refused.id() == Some(my_id) {
                refused.answer()
            } else {
                None
            }
        }
        Ok((id, request)) => {
            if id == 0 || id != my_id {
                return None;
            }
            execute(model, id, request)
        }
    }
}

/// Applies a request addressed to this module and encodes its answer (from `id`, the ID the
/// request was sent to, even when the request changes it: 10-2 as read).
fn execute(model: &mut C29uModel, id: u8, request: Request) -> Option<Vec<u8>> {
    let function = request.function();
    let response = match request {
        Request::ReadBits(area) => Ok(Response::Bits(match area {
            BitArea::Outputs => model.outputs(),
            BitArea::Inputs => model.inputs_wire(),
            BitArea::LatchedLow => model.latched_low(),
            BitArea::LatchedHigh => model.latched_high(),
        })),
        Request::ReadCounters { function, count } => {
            let all = model.counters();
            match all.get(..usize::from(count)) {
                Some(values) => Ok(Response::Counters {
                    function,
                    values: values.to_vec(),
                }),
                None => Err(C29uModelError::BadChannel(count)),
            }
        }
        Request::WriteCoil(cmd) => write_coil(model, cmd).map(|()| Response::CoilWritten(cmd)),
        Request::WriteCoils {
            target,
            start,
            count,
            data,
        } => write_coils(model, target, start, count, data).map(|()| Response::CoilsWritten {
            target,
            start,
            count,
        }),
        Request::Vendor(v) => {
            return match vendor(model, v) {
                Ok(Some(r)) => Some(encode_response(id, &Response::Vendor(r))),
                Ok(None) => None,
                Err(_) => Some(encode_vendor_error(id)),
            };
        }
    };
    Some(match response {
        Ok(r) => encode_response(id, &r),
        Err(e) => encode_exception(id, function, exception_code(&e)),
    })
}

/// Function 05 (10-16).
fn write_coil(model: &mut C29uModel, cmd: CoilCommand) -> Result<(), C29uModelError> {
    match cmd {
        CoilCommand::Output { channel, on } => model.write_output(channel, on),
        CoilCommand::ClearLatches => {
            model.clear_latches();
            Ok(())
        }
        CoilCommand::ClearCounter { channel } => model.clear_counter(channel),
    }
}

/// Function 0F (10-20).
fn write_coils(
    model: &mut C29uModel,
    target: CoilsTarget,
    start: u8,
    count: u8,
    data: u8,
) -> Result<(), C29uModelError> {
    // Decoding has checked the range; a bad one is still refused rather than trusted.
    let channel = |i: u8| {
        start
            .checked_add(i)
            .filter(|ch| *ch < 8)
            .ok_or(C29uModelError::BadChannel(start))
    };
    match target {
        CoilsTarget::Outputs => {
            let mut value = model.outputs();
            for i in 0..count {
                let bit = 1u8 << channel(i)?;
                if (data >> i) & 1 == 1 {
                    value |= bit;
                } else {
                    value &= !bit;
                }
            }
            model.write_outputs(value)
        }
        CoilsTarget::ClearCounters => {
            for i in 0..count {
                model.clear_counter(channel(i)?)?;
            }
            Ok(())
        }
        CoilsTarget::SaveCounters => model.save_counters(),
    }
}

/// Vendor function 46 (10-1..10-15); `Ok(None)` means no answer (host OK).
fn vendor(
    model: &mut C29uModel,
    request: VendorRequest,
) -> Result<Option<VendorResponse>, C29uModelError> {
    use VendorResponse as R;
    Ok(Some(match request {
        VendorRequest::ReadName => R::Name(NAME_CODE),
        VendorRequest::SetId(id) => {
            let mut cfg = model.config();
            cfg.id = id;
            model.set_config(cfg)?;
            R::IdChanged
        }
        VendorRequest::ReadConfig => R::Config {
            baud_code: model.config().baud_code,
        },
        VendorRequest::SetBaud(code) => {
            let mut cfg = model.config();
            cfg.baud_code = code;
            model.set_config(cfg)?;
            R::BaudChanged
        }
        VendorRequest::ReadFirmware => R::Firmware {
            year: FIRMWARE_DATE.year,
            month: FIRMWARE_DATE.month,
            day: FIRMWARE_DATE.day,
        },
        VendorRequest::ReadResetFlag => R::ResetFlag(model.take_reset_flag()),
        VendorRequest::Reset => {
            model.reset();
            R::ResetDone
        }
        VendorRequest::SetWatchdog(tenths) => {
            model.set_watchdog(tenths)?;
            R::WatchdogSet
        }
        VendorRequest::ReadWatchdog => {
            let wd = model.watchdog();
            R::Watchdog {
                enabled: wd.enabled,
                tenths: wd.timeout_tenths,
            }
        }
        VendorRequest::SetLedMode(mode) => {
            model.set_led_mode(mode)?;
            R::LedModeSet
        }
        VendorRequest::SetPowerOnValue(v) => {
            model.set_power_on_value(v)?;
            R::PowerOnValueSet
        }
        VendorRequest::ReadPowerOnValue => R::PowerOnValue(model.power_on_value()),
        VendorRequest::SetSafeValue(v) => {
            model.set_safe_value(v)?;
            R::SafeValueSet
        }
        VendorRequest::ReadSafeValue => R::SafeValue(model.safe_value()),
        VendorRequest::HostOk => {
            model.host_ok();
            return Ok(None);
        }
    }))
}

/// The exception code a refusal of the model is answered with.
fn exception_code(e: &C29uModelError) -> ExceptionCode {
    match e {
        C29uModelError::SafeMode => ExceptionCode::SafeMode,
        C29uModelError::BadChannel(_) => ExceptionCode::StartChannel,
        C29uModelError::BadValue(_) => ExceptionCode::DataFormat,
        C29uModelError::NotSynchronized | C29uModelError::Io(_) => ExceptionCode::Syntax,
    }
}

/// Reassembles requests from the serial byte stream and answers them from the model.
#[derive(Debug, Clone)]
pub struct ModbusFrontEnd {
    reader: FrameReader,
}

impl Default for ModbusFrontEnd {
    fn default() -> Self {
        Self::new()
    }
}

impl ModbusFrontEnd {
    /// A front end with an empty receive buffer.
    pub fn new() -> Self {
        Self {
            reader: FrameReader::for_requests(),
        }
    }

    /// Takes bytes as they arrive and returns the answers to every request they complete.
    pub fn receive(&mut self, model: &mut C29uModel, bytes: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        for frame in self.reader.push(bytes) {
            if let Some(a) = answer(model, &frame) {
                out.extend_from_slice(&a);
            }
        }
        out
    }

    /// The line has been silent for 3.5 characters: an incomplete request is dropped.
    /// The line fell silent: an unfinished request is dropped, and one that only the silence
    /// could end (a vendor request shorter than section 10 writes it) is answered.
    pub fn end_of_silence(&mut self, model: &mut C29uModel) -> Vec<u8> {
        self.reader
            .end_of_silence()
            .and_then(|frame| answer(model, &frame))
            .unwrap_or_default()
    }

    /// Bytes thrown away so far (garbage, bad CRCs, cut-off requests).
    pub fn discarded(&self) -> u64 {
        self.reader.discarded()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::c29u_modbus::{
        parse_response, seal, CounterFunction, ModbusError, Request, Response,
    };
    use crate::sim::c29u::{Eeprom, Protocol};
    use crate::time::clock::VirtualClock;
    use std::path::PathBuf;
    use std::sync::Arc;
    use std::time::Duration;

    /// Hex text (spaces between bytes) to bytes.
    fn hex(text: &str) -> Vec<u8> {
        text.split_whitespace()
            .map(|b| u8::from_str_radix(b, 16).unwrap())
            .collect()
    }

    /// A factory-fresh Modbus module in virtual time, behind a front end.
    struct Rig {
        model: C29uModel,
        front: ModbusFrontEnd,
        clock: VirtualClock,
    }

    impl Rig {
        fn new() -> Self {
            let clock = VirtualClock::at_epoch();
            let model =
                C29uModel::new(Protocol::Modbus, Arc::new(clock.clone()), Eeprom::factory());
            Self {
                model,
                front: ModbusFrontEnd::new(),
                clock,
            }
        }

        /// Sends raw bytes, returns what the module sends back.
        fn raw(&mut self, bytes: &[u8]) -> Vec<u8> {
            self.front.receive(&mut self.model, bytes)
        }

        /// Sends `body` + CRC; the answer without its (checked) CRC, or empty for silence.
        fn send(&mut self, body: &str) -> String {
            let out = self.raw(&seal(&hex(body)));
            if out.is_empty() {
                return String::new();
            }
            let (body, _) = out.split_at(out.len() - 2);
            assert_eq!(seal(body), out, "answer CRC");
            body.iter()
                .map(|b| format!("{b:02X}"))
                .collect::<Vec<_>>()
                .join(" ")
        }

        /// Sends a typed request to `id` and parses the answer.
        fn ask(&mut self, id: u8, req: Request) -> Result<Response, ModbusError> {
            let out = self.raw(&req.encode(id));
            parse_response(&req, id, &out)
        }

        fn advance_ms(&self, ms: u64) {
            self.clock.advance(Duration::from_millis(ms));
        }
    }

    #[test]
    fn manual_10_1_to_10_7_vendor_reads() {
        let mut r = Rig::new();
        assert_eq!(r.send("01 46 00 00"), "01 46 00 00 0C 29 00");
        assert_eq!(r.send("01 46 05 00"), "01 46 05 00 06 00 00 00 00 00 00");
        assert_eq!(r.send("01 46 07 00"), "01 46 07 09 07 03 00");
        // A fresh module has been reset (power on); the flag reads once.
        assert_eq!(r.send("01 46 08 00"), "01 46 08 01 00");
        assert_eq!(r.send("01 46 08 00"), "01 46 08 00 00");
        assert_eq!(r.send("01 46 09 00"), "01 46 09 00");
        assert_eq!(r.send("01 46 08 00"), "01 46 08 01 00");
    }

    #[test]
    fn manual_10_2_new_id_answers_from_the_old_one() {
        let mut r = Rig::new();
        assert_eq!(r.send("01 46 04 03 00 00 00"), "01 46 04 00 00 00 00");
        assert_eq!(r.send("01 46 00 00"), "", "old ID no longer answers");
        assert_eq!(r.send("03 46 00 00"), "03 46 00 00 0C 29 00");
        assert_eq!(r.model.config().id, 3);
        // IDs outside 1..=247 are refused, from the current ID.
        assert_eq!(r.send("03 46 04 F8 00 00 00"), "03 C6 00");
        assert_eq!(r.send("03 46 04 00 00 00 00"), "03 C6 00");
        assert_eq!(r.model.config().id, 3);
    }

    #[test]
    fn manual_10_4_baud_code() {
        let mut r = Rig::new();
        assert_eq!(
            r.send("01 46 06 00 0A 00 00 00 00 00 00"),
            "01 46 06 00 00 00 00 00 00 00"
        );
        assert_eq!(r.send("01 46 05 00"), "01 46 05 00 0A 00 00 00 00 00 00");
        assert_eq!(r.send("01 46 06 00 0B 00 00 00 00 00 00"), "01 C6 00");
        assert_eq!(r.model.config().baud_code, 0x0A);
    }

    #[test]
    fn manual_10_8_to_10_10_watchdog_and_led() {
        let mut r = Rig::new();
        assert_eq!(r.send("01 46 0C 00"), "01 46 0C 00 00");
        assert_eq!(r.send("01 46 0B 0F 00"), "01 46 0B 00");
        // 10-9 as read: `01 46 0C 01 0F` = enabled, 1.5 s.
        assert_eq!(r.send("01 46 0C 00"), "01 46 0C 01 0F");
        assert_eq!(r.send("01 46 0B 00 00"), "01 46 0B 00");
        assert_eq!(r.send("01 46 0C 00"), "01 46 0C 00 00");
        assert_eq!(r.send("01 46 0D 01 00"), "01 46 0D 00");
        assert_eq!(r.model.led_mode(), 1);
        assert_eq!(r.send("01 46 0D 02 00"), "01 C6 00");
    }

    #[test]
    fn manual_10_11_10_12_power_on_value_after_reset() {
        let mut r = Rig::new();
        assert_eq!(r.send("01 46 27 08 00"), "01 46 27 00");
        assert_eq!(r.send("01 46 28 00"), "01 46 28 08");
        assert_eq!(r.send("01 0F 00 00 00 08 01 FF"), "01 0F 00 00 00 08");
        assert_eq!(r.send("01 01 00 00 00 08"), "01 01 01 FF");
        assert_eq!(r.send("01 46 09 00"), "01 46 09 00");
        assert_eq!(r.send("01 01 00 00 00 08"), "01 01 01 08");
    }

    #[test]
    fn manual_10_13_watchdog_expiry_drives_the_safe_value_and_refuses_writes() {
        let mut r = Rig::new();
        assert_eq!(r.send("01 46 29 14 00"), "01 46 29 00");
        assert_eq!(r.send("01 46 2A 00"), "01 46 2A 14");
        assert_eq!(r.send("01 0F 00 00 00 08 01 25"), "01 0F 00 00 00 08");
        assert_eq!(r.send("01 46 0B 12 00"), "01 46 0B 00");
        r.advance_ms(1_799);
        assert_eq!(
            r.send("01 01 00 00 00 08"),
            "01 01 01 25",
            "not yet at 1.8 s"
        );
        r.advance_ms(1);
        assert_eq!(r.send("01 01 00 00 00 08"), "01 01 01 14");
        // Safe mode: every output write is refused with FF (10-16, 10-20).
        assert_eq!(r.send("01 05 00 03 FF 00"), "01 85 FF");
        assert_eq!(r.send("01 0F 00 00 00 08 01 25"), "01 8F FF");
        assert_eq!(
            r.ask(1, Request::write_outputs(0)),
            Err(ModbusError::SafeMode { function: 0x0F })
        );
        // Host OK does not leave safe mode; a reset does not either (fail-safe reading).
        assert_eq!(r.send("01 46 2F 00"), "");
        assert_eq!(r.send("01 05 00 03 FF 00"), "01 85 FF");
        assert_eq!(r.send("01 46 09 00"), "01 46 09 00");
        assert_eq!(r.send("01 01 00 00 00 08"), "01 01 01 14");
        assert_eq!(r.send("01 05 00 03 FF 00"), "01 85 FF");
        // Reads and non-output writes still work.
        assert_eq!(r.send("01 05 01 00 00 00"), "01 05 01 00 00 00");
        assert_eq!(r.send("01 46 0C 00"), "01 46 0C 01 12");
        // Disabling the watchdog leaves safe mode.
        assert_eq!(r.send("01 46 0B 00 00"), "01 46 0B 00");
        assert_eq!(r.send("01 05 00 03 FF 00"), "01 05 00 03 FF 00");
        assert_eq!(r.send("01 01 00 00 00 08"), "01 01 01 1C");
    }

    #[test]
    fn manual_10_15_host_ok_keeps_the_watchdog_from_firing() {
        let mut r = Rig::new();
        assert_eq!(r.send("01 46 29 FF 00"), "01 46 29 00");
        assert_eq!(r.send("01 46 0B 05 00"), "01 46 0B 00");
        for _ in 0..10 {
            r.advance_ms(400);
            assert_eq!(r.send("01 46 2F 00"), "", "host OK is never answered");
        }
        assert_eq!(r.send("01 05 00 00 FF 00"), "01 05 00 00 FF 00");
        assert_eq!(r.send("01 01 00 00 00 08"), "01 01 01 01");
        // Stop feeding it: 0.5 s later it has fired.
        r.advance_ms(500);
        assert_eq!(r.send("01 01 00 00 00 08"), "01 01 01 FF");
        assert!(r.model.in_safe_mode());
        // Host OK addressed to another ID does not count.
        let mut r = Rig::new();
        assert_eq!(r.send("01 46 0B 05 00"), "01 46 0B 00");
        r.advance_ms(400);
        assert_eq!(r.send("02 46 2F 00"), "");
        r.advance_ms(100);
        assert!(r.model.in_safe_mode());
    }

    #[test]
    fn manual_10_16_single_outputs_latches_and_counter() {
        let mut r = Rig::new();
        assert_eq!(r.send("01 05 00 03 FF 00"), "01 05 00 03 FF 00");
        assert_eq!(r.send("01 05 00 02 00 00"), "01 05 00 02 00 00");
        assert_eq!(r.model.outputs(), 0x08);
        assert_eq!(r.send("01 05 00 08 FF 00"), "01 85 02");
        assert_eq!(r.send("01 05 00 01 12 34"), "01 85 01");
        r.model.pulse(6, 5).unwrap();
        r.model.pulse(5, 2).unwrap();
        assert_eq!(r.send("01 05 02 06 00 00"), "01 05 02 06 00 00");
        assert_eq!(r.model.counters(), [0, 0, 0, 0, 0, 2, 0, 0]);
    }

    #[test]
    fn manual_10_17_read_do_di_latches() {
        let mut r = Rig::new();
        assert_eq!(r.send("01 0F 00 00 00 08 01 36"), "01 0F 00 00 00 08");
        assert_eq!(r.send("01 01 00 00 00 08"), "01 01 01 36");
        // DI5 energized reads as a 0 bit on the wire (10-17).
        r.model.set_inputs(0x20);
        assert_eq!(r.send("01 01 00 20 00 08"), "01 01 01 DF");
        r.model.set_inputs(0x00);
        // DI0 energized then released: latched low and latched high.
        r.model.set_inputs(0x01);
        r.model.set_inputs(0x00);
        assert_eq!(r.send("01 01 00 40 00 08"), "01 01 01 21");
        assert_eq!(r.send("01 01 00 60 00 08"), "01 01 01 21");
        assert_eq!(r.send("01 05 01 00 00 00"), "01 05 01 00 00 00");
        assert_eq!(r.send("01 01 00 40 00 08"), "01 01 01 00");
        assert_eq!(r.send("01 01 00 60 00 08"), "01 01 01 00");
        r.model.set_inputs(0x01);
        assert_eq!(r.send("01 01 00 40 00 08"), "01 01 01 01");
        assert_eq!(r.send("01 01 00 60 00 08"), "01 01 01 00");
        // Bad area and quantity.
        assert_eq!(r.send("01 01 00 10 00 08"), "01 81 02");
        assert_eq!(r.send("01 01 00 20 00 01"), "01 81 03");
    }

    #[test]
    fn manual_10_18_10_19_counters_after_pulses() {
        let mut r = Rig::new();
        for (ch, n) in [(0, 0x28), (1, 0x5A), (2, 0x53), (3, 0x55)] {
            r.model.pulse(ch, n).unwrap();
        }
        assert_eq!(
            r.send("01 04 00 00 00 04"),
            "01 04 08 00 28 00 5A 00 53 00 55"
        );
        assert_eq!(
            r.send("01 03 00 00 00 04"),
            "01 03 08 00 28 00 5A 00 53 00 55"
        );
        // 10-18: the start channel is always 00; another start is a start channel error.
        assert_eq!(r.send("01 03 00 02 00 02"), "01 83 02");
        // Edges from the field count too (rising by default).
        r.model.set_inputs(0x80);
        r.model.set_inputs(0x00);
        r.model.set_inputs(0x80);
        assert_eq!(
            r.ask(
                1,
                Request::ReadCounters {
                    function: CounterFunction::Holding,
                    count: 8
                }
            ),
            Ok(Response::Counters {
                function: CounterFunction::Holding,
                values: vec![0x28, 0x5A, 0x53, 0x55, 0, 0, 0, 2]
            })
        );
        assert_eq!(r.send("01 04 00 00 00 09"), "01 84 03");
        assert_eq!(r.send("01 04 00 08 00 01"), "01 84 02");
    }

    #[test]
    fn manual_10_20_outputs_clear_and_save() {
        let mut r = Rig::new();
        assert_eq!(r.send("01 0F 00 00 00 08 01 25"), "01 0F 00 00 00 08");
        assert_eq!(r.model.outputs(), 0x25);
        for ch in 0..8 {
            r.model.pulse(ch, u32::from(ch) + 1).unwrap();
        }
        // 10-20 as read: the answer echoes address and quantity.
        assert_eq!(r.send("01 0F 02 04 00 04 01 00"), "01 0F 02 04 00 04");
        assert_eq!(r.model.counters(), [1, 2, 3, 4, 0, 0, 0, 0]);
        assert_eq!(r.send("01 0F 03 00 00 08 01 00"), "01 0F 03 00 00 08");
        assert_eq!(r.model.eeprom().saved_counters, [1, 2, 3, 4, 0, 0, 0, 0]);
        // A partial output write touches only its channels: DO4..DO5 from bits 0..1.
        assert_eq!(r.send("01 0F 00 04 00 02 01 02"), "01 0F 00 04 00 02");
        assert_eq!(r.model.outputs(), 0x25 & !0x30 | 0x20);
        assert_eq!(r.send("01 0F 01 00 00 08 01 00"), "01 8F 02");
        assert_eq!(r.send("01 0F 00 04 00 05 01 00"), "01 8F 03");
    }

    /// A fresh, unique directory under the system temp dir, removed on drop.
    struct TempDir(PathBuf);

    impl TempDir {
        fn new(tag: &str) -> Self {
            let nanos = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_nanos())
                .unwrap_or(0);
            let dir = std::env::temp_dir().join(format!(
                "rigscript-modbus-{tag}-{}-{nanos}",
                std::process::id()
            ));
            std::fs::create_dir_all(&dir).unwrap();
            Self(dir)
        }
    }

    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    #[test]
    fn saved_counters_survive_power_cycles_and_restarts() {
        let dir = TempDir::new("eeprom");
        let path = dir.0.join("c29u.json");
        let clock = VirtualClock::at_epoch();
        let mut model =
            C29uModel::with_state_file(Protocol::Modbus, Arc::new(clock.clone()), path.clone())
                .unwrap();
        let mut front = ModbusFrontEnd::new();
        model.pulse(2, 187).unwrap();
        let save = Request::save_counters();
        assert!(!front.receive(&mut model, &save.encode(1)).is_empty());
        model.pulse(2, 10).unwrap();
        assert_eq!(model.counter(2).unwrap(), 197);
        // Unsaved counts are lost on power loss; the saved ones come back.
        model.power_cycle();
        let read = Request::read_counters(3);
        let out = front.receive(&mut model, &read.encode(1));
        assert_eq!(
            parse_response(&read, 1, &out),
            Ok(Response::Counters {
                function: CounterFunction::Input,
                values: vec![0, 0, 187]
            })
        );
        // A new simulator process on the same state file.
        drop(model);
        let mut model =
            C29uModel::with_state_file(Protocol::Modbus, Arc::new(clock), path).unwrap();
        let out = ModbusFrontEnd::new().receive(&mut model, &read.encode(1));
        assert_eq!(
            parse_response(&read, 1, &out),
            Ok(Response::Counters {
                function: CounterFunction::Input,
                values: vec![0, 0, 187]
            })
        );
    }

    #[test]
    fn other_ids_broadcast_and_bad_crcs_get_silence() {
        let mut r = Rig::new();
        assert_eq!(r.send("02 01 00 00 00 08"), "");
        assert_eq!(
            r.send("00 0F 00 00 00 08 01 FF"),
            "",
            "broadcast is ignored"
        );
        assert_eq!(r.model.outputs(), 0x00);
        let mut bad = seal(&hex("01 0F 00 00 00 08 01 FF"));
        bad[7] = 0xFE;
        assert!(r.raw(&bad).is_empty());
        assert_eq!(r.model.outputs(), 0x00);
        // Refusals are for this ID only.
        assert_eq!(r.send("02 01 00 10 00 08"), "");
        assert_eq!(r.send("02 46 77 00"), "");
        assert_eq!(r.send("01 46 77 00"), "01 C6 00");
        // An unsupported function: syntax error.
        assert_eq!(r.send("01 06 00 00 00 01"), "01 86 00");
        // After the bad frame the line still works.
        assert_eq!(r.send("01 01 00 00 00 08"), "01 01 01 00");
    }

    #[test]
    fn stream_pieces_garbage_and_back_to_back_requests() {
        let mut r = Rig::new();
        let a = Request::write_outputs(0x81).encode(1);
        let b = Request::ReadBits(BitArea::Outputs).encode(1);
        let stream = [&[0xFF, 0x00][..], &a, &b].concat();
        let mut out = Vec::new();
        for chunk in stream.chunks(3) {
            out.extend(r.raw(chunk));
        }
        let want = [seal(&hex("01 0F 00 00 00 08")), seal(&hex("01 01 01 81"))].concat();
        assert_eq!(out, want);
        assert_eq!(r.front.discarded(), 2);
    }

    #[test]
    fn silence_drops_a_cut_off_request() {
        let mut r = Rig::new();
        let f = Request::write_outputs(0x0F).encode(1);
        assert!(r.raw(&f[..6]).is_empty());
        assert!(r.front.end_of_silence(&mut r.model).is_empty());
        assert!(r.raw(&f[6..]).is_empty());
        assert_eq!(r.model.outputs(), 0);
        assert_eq!(r.send("01 01 00 00 00 08"), "01 01 01 00");
    }

    #[test]
    fn a_short_vendor_request_is_answered_after_silence() {
        // `01 46 28` without the reserved byte: only the silence ends it.
        let mut r = Rig::new();
        assert!(r.raw(&seal(&hex("01 46 28"))).is_empty());
        let out = r.front.end_of_silence(&mut r.model);
        assert_eq!(out, seal(&hex("01 46 28 00")));
    }
}
