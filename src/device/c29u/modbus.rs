//! The TRP-C29U driver's Modbus RTU back end (manual sections 9-10 and their vendor addressing).

use super::transport::{AttemptFault, Transport};
use super::{
    exchange_fault, Backend, C29uError, ConfigChange, Firmware, Preset, PresetWrite, Protocol,
    Settings, SynchronizedIo, WatchdogInfo,
};
use crate::device::exchange::AnswerLen;
use crate::protocol::c29u::{baud_code, baud_rate};
use crate::protocol::c29u_modbus::{
    model_name, parse_response, seal, silence_gap, BitArea, CoilCommand, FrameReader, ModbusError,
    Request, Response, VendorRequest, VendorResponse, SLAVE_IDS,
};
use std::time::Duration;

/// USB-serial adapters hand bytes over in latency-timer chunks (16 ms on FTDI parts), so a gap
/// of 3.5 characters seen by the host is no proof the module stopped talking. A valid CRC ends
/// an answer at once; only an answer the CRC cannot end (a garbled one) waits this long.
const GAP_FLOOR: Duration = Duration::from_millis(20);

/// The Modbus back end: the module's ID and the line speed (for the frame gap).
pub(crate) struct ModbusBackend {
    id: u8,
    baud: u32,
}

fn unsupported(what: &'static str, hint: &'static str) -> C29uError {
    C29uError::Unsupported {
        what,
        protocol: Protocol::Modbus,
        hint,
    }
}

impl ModbusBackend {
    pub fn new(id: u8, baud: u32) -> Self {
        Self { id, baud }
    }

    fn gap(&self) -> Duration {
        silence_gap(self.baud).max(GAP_FLOOR)
    }

    fn call(&mut self, t: &mut Transport, request: &Request) -> Result<Response, C29uError> {
        let frame = request.encode(self.id);
        // The frame as sent (CRC aside) is what a person compares with a bus capture or the
        // manual; worded only when something went wrong (a poll must cost little).
        let name = || {
            describe_frame(
                frame
                    .get(..frame.len().saturating_sub(2))
                    .unwrap_or_default(),
            )
        };
        let (id, gap) = (self.id, Some(self.gap()));
        let expects = request.expects_answer();
        t.with_retries(|t| {
            let timeout = t.timeout;
            let mut reader = FrameReader::for_answers();
            reader.expect_answer(id, request);
            let mut fed = 0;
            let answer = t
                .exchange(&frame, expects, gap, answer_len(request), |received| {
                    let fresh = received.get(fed..).unwrap_or_default();
                    fed = received.len();
                    reader.push(fresh).into_iter().next()
                })
                .map_err(|e| exchange_fault(e, &t.port(), id, &name(), timeout, false))?;
            if !expects {
                // Only host OK goes unanswered; an empty vendor answer stands for it.
                return Ok(Response::Vendor(VendorResponse::WatchdogSet));
            }
            parse_response(request, id, &answer).map_err(|e| classify(e, &t.port(), id, &name()))
        })
    }

    fn vendor(
        &mut self,
        t: &mut Transport,
        request: VendorRequest,
    ) -> Result<VendorResponse, C29uError> {
        let request = Request::Vendor(request);
        match self.call(t, &request)? {
            Response::Vendor(answer) => Ok(answer),
            other => Err(unexpected(t, self.id, &request, &other)),
        }
    }

    fn bits(&mut self, t: &mut Transport, area: BitArea) -> Result<u8, C29uError> {
        let request = Request::ReadBits(area);
        match self.call(t, &request)? {
            Response::Bits(byte) => Ok(byte),
            other => Err(unexpected(t, self.id, &request, &other)),
        }
    }

    /// Counters 0..`count` (10-18/10-19: reads always start at channel 00).
    fn counters(&mut self, t: &mut Transport, count: u8) -> Result<Vec<u16>, C29uError> {
        let request = Request::read_counters(count);
        match self.call(t, &request)? {
            Response::Counters { values, .. } if values.len() == usize::from(count) => Ok(values),
            other => Err(unexpected(t, self.id, &request, &other)),
        }
    }

    fn write(&mut self, t: &mut Transport, request: Request) -> Result<(), C29uError> {
        self.call(t, &request).map(|_| ())
    }
}

/// How long the answer to `request` can be: an exception (ID, function, code, CRC) or the
/// normal answer.
fn answer_len(request: &Request) -> Option<AnswerLen> {
    const EXCEPTION_LEN: usize = 5;
    request.answer_len().map(|normal| AnswerLen {
        shortest: EXCEPTION_LEN.min(normal),
        normal,
    })
}

/// A request in words for messages: its bytes in hex, as section 10 writes them.
fn describe_frame(body: &[u8]) -> String {
    let hex: Vec<String> = body.iter().map(|b| format!("{b:02X}")).collect();
    format!("request `{}`", hex.join(" "))
}

fn unexpected(t: &Transport, id: u8, request: &Request, answer: &Response) -> C29uError {
    C29uError::Garbled {
        port: t.port(),
        id,
        request: format!("{request:?}"),
        detail: format!("unexpected answer {answer:?}"),
    }
}

fn classify(e: ModbusError, port: &str, id: u8, request: &str) -> AttemptFault {
    let refused = |reason: String| {
        AttemptFault::Final(C29uError::Refused {
            port: port.to_string(),
            id,
            request: request.to_string(),
            reason,
        })
    };
    match e {
        ModbusError::SafeMode { .. } => AttemptFault::Final(C29uError::SafeMode {
            port: port.to_string(),
            id,
        }),
        ModbusError::Exception { code, .. } => refused(format!("exception: {code}")),
        ModbusError::VendorError => refused("the vendor command was refused (C6 00)".to_string()),
        ModbusError::BadCrc
        | ModbusError::WrongId { .. }
        | ModbusError::UnexpectedFunction { .. }
        | ModbusError::Malformed { .. }
        | ModbusError::NoAnswerExpected => AttemptFault::Retry(C29uError::Garbled {
            port: port.to_string(),
            id,
            request: request.to_string(),
            detail: e.to_string(),
        }),
    }
}

impl Backend for ModbusBackend {
    fn id(&self) -> u8 {
        self.id
    }

    fn read_io(&mut self, t: &mut Transport) -> Result<(u8, u8), C29uError> {
        Ok((
            self.bits(t, BitArea::Outputs)?,
            self.bits(t, BitArea::Inputs)?,
        ))
    }

    fn read_outputs(&mut self, t: &mut Transport) -> Result<u8, C29uError> {
        self.bits(t, BitArea::Outputs)
    }

    fn read_inputs_raw(&mut self, t: &mut Transport) -> Result<u8, C29uError> {
        self.bits(t, BitArea::Inputs)
    }

    fn write_outputs(&mut self, t: &mut Transport, value: u8) -> Result<(), C29uError> {
        self.write(t, Request::write_outputs(value))
    }

    fn write_output(&mut self, t: &mut Transport, channel: u8, on: bool) -> Result<(), C29uError> {
        self.write(t, Request::WriteCoil(CoilCommand::Output { channel, on }))
    }

    fn read_counter(&mut self, t: &mut Transport, channel: u8) -> Result<u16, C29uError> {
        let values = self.counters(t, channel.saturating_add(1))?;
        Ok(values.last().copied().unwrap_or_default())
    }

    fn read_counters(&mut self, t: &mut Transport) -> Result<[u16; 8], C29uError> {
        let values = self.counters(t, 8)?;
        let mut counters = [0u16; 8];
        counters
            .iter_mut()
            .zip(values)
            .for_each(|(slot, v)| *slot = v);
        Ok(counters)
    }

    fn clear_counter(&mut self, t: &mut Transport, channel: u8) -> Result<(), C29uError> {
        self.write(t, Request::WriteCoil(CoilCommand::ClearCounter { channel }))
    }

    fn clear_counters(&mut self, t: &mut Transport) -> Result<(), C29uError> {
        self.write(t, Request::clear_counters(0, 8))
    }

    fn save_counters(&mut self, t: &mut Transport) -> Result<(), C29uError> {
        self.write(t, Request::save_counters())
    }

    fn read_latches(&mut self, t: &mut Transport) -> Result<(u8, u8), C29uError> {
        Ok((
            self.bits(t, BitArea::LatchedLow)?,
            self.bits(t, BitArea::LatchedHigh)?,
        ))
    }

    fn clear_latches(&mut self, t: &mut Transport) -> Result<(), C29uError> {
        self.write(t, Request::WriteCoil(CoilCommand::ClearLatches))
    }

    fn set_watchdog(&mut self, t: &mut Transport, tenths: u8) -> Result<(), C29uError> {
        self.vendor(t, VendorRequest::SetWatchdog(tenths))
            .map(|_| ())
    }

    fn watchdog(&mut self, t: &mut Transport) -> Result<WatchdogInfo, C29uError> {
        match self.vendor(t, VendorRequest::ReadWatchdog)? {
            // 10-9 does not say whether a fired watchdog still reads as enabled.
            VendorResponse::Watchdog { enabled, tenths } => Ok(WatchdogInfo {
                enabled,
                timeout_tenths: tenths,
                expired: if enabled { None } else { Some(false) },
            }),
            other => Err(unexpected(
                t,
                self.id,
                &Request::Vendor(VendorRequest::ReadWatchdog),
                &Response::Vendor(other),
            )),
        }
    }

    fn host_ok(&mut self, t: &mut Transport) -> Result<(), C29uError> {
        self.vendor(t, VendorRequest::HostOk).map(|_| ())
    }

    fn read_preset(&mut self, t: &mut Transport, preset: Preset) -> Result<u8, C29uError> {
        let request = match preset {
            Preset::PowerOn => VendorRequest::ReadPowerOnValue,
            Preset::Safe => VendorRequest::ReadSafeValue,
        };
        match self.vendor(t, request)? {
            VendorResponse::PowerOnValue(v) | VendorResponse::SafeValue(v) => Ok(v),
            other => Err(unexpected(
                t,
                self.id,
                &Request::Vendor(request),
                &Response::Vendor(other),
            )),
        }
    }

    fn set_preset(
        &mut self,
        t: &mut Transport,
        preset: Preset,
        value: u8,
        _how: PresetWrite,
    ) -> Result<(), C29uError> {
        // 10-11, 10-13: stored directly; the outputs are not touched either way.
        let request = match preset {
            Preset::PowerOn => VendorRequest::SetPowerOnValue(value),
            Preset::Safe => VendorRequest::SetSafeValue(value),
        };
        self.vendor(t, request).map(|_| ())
    }

    fn save_outputs_as(&mut self, t: &mut Transport, preset: Preset) -> Result<(), C29uError> {
        let outputs = self.read_outputs(t)?;
        self.set_preset(t, preset, outputs, PresetWrite::KeepOutputs)
    }

    fn name(&mut self, t: &mut Transport) -> Result<String, C29uError> {
        match self.vendor(t, VendorRequest::ReadName)? {
            VendorResponse::Name(code) => Ok(model_name(code)),
            other => Err(unexpected(
                t,
                self.id,
                &Request::Vendor(VendorRequest::ReadName),
                &Response::Vendor(other),
            )),
        }
    }

    fn set_name(&mut self, _t: &mut Transport, _name: &str) -> Result<(), C29uError> {
        Err(unsupported(
            "renaming the module",
            "set the DIP switch to ASCII, rename it, and switch back",
        ))
    }

    fn firmware(&mut self, t: &mut Transport) -> Result<Firmware, C29uError> {
        match self.vendor(t, VendorRequest::ReadFirmware)? {
            VendorResponse::Firmware { year, month, day } => Ok(Firmware {
                text: format!("{year:02}{month:02}{day:02}"),
                date: Some((2000 + u16::from(year), month, day)),
            }),
            other => Err(unexpected(
                t,
                self.id,
                &Request::Vendor(VendorRequest::ReadFirmware),
                &Response::Vendor(other),
            )),
        }
    }

    fn settings(&mut self, t: &mut Transport) -> Result<Settings, C29uError> {
        match self.vendor(t, VendorRequest::ReadConfig)? {
            VendorResponse::Config { baud_code } => Ok(Settings {
                id: self.id,
                baud: baud_rate(baud_code),
                checksum: None,
                counter_edge: None,
                model: None,
            }),
            other => Err(unexpected(
                t,
                self.id,
                &Request::Vendor(VendorRequest::ReadConfig),
                &Response::Vendor(other),
            )),
        }
    }

    fn configure(&mut self, t: &mut Transport, change: &ConfigChange) -> Result<(), C29uError> {
        if change.checksum.is_some()
            || change.counter_edge.is_some()
            || change.hex_counters.is_some()
        {
            return Err(unsupported(
                "changing checksum, counter edge or hex counters",
                "set the DIP switch to ASCII for those settings",
            ));
        }
        let code = match change.baud {
            Some(rate) => Some(baud_code(rate).ok_or_else(|| {
                C29uError::InvalidArgument(format!(
                    "{rate} baud is not possible: use 1200, 2400, 4800, 9600, 19200, 38400, 57600 or 115200"
                ))
            })?),
            None => None,
        };
        if let Some(new_id) = change.id {
            if !SLAVE_IDS.contains(&new_id) {
                return Err(C29uError::InvalidArgument(format!(
                    "Modbus ID {new_id} is not possible: use 1-247"
                )));
            }
            // 10-2 as read: the module answers from its old ID, then uses the new one.
            self.vendor(t, VendorRequest::SetId(new_id))?;
            self.id = new_id;
        }
        if let (Some(code), Some(rate)) = (code, change.baud) {
            self.vendor(t, VendorRequest::SetBaud(code))?;
            t.set_baud(rate)?;
            self.baud = rate;
        }
        Ok(())
    }

    fn reset(&mut self, t: &mut Transport) -> Result<(), C29uError> {
        self.vendor(t, VendorRequest::Reset).map(|_| ())
    }

    fn take_reset_flag(&mut self, t: &mut Transport) -> Result<bool, C29uError> {
        match self.vendor(t, VendorRequest::ReadResetFlag)? {
            VendorResponse::ResetFlag(flag) => Ok(flag),
            other => Err(unexpected(
                t,
                self.id,
                &Request::Vendor(VendorRequest::ReadResetFlag),
                &Response::Vendor(other),
            )),
        }
    }

    fn set_led_mode(&mut self, t: &mut Transport, on: bool) -> Result<(), C29uError> {
        self.vendor(t, VendorRequest::SetLedMode(u8::from(on)))
            .map(|_| ())
    }

    fn synchronize(&mut self, _t: &mut Transport) -> Result<(), C29uError> {
        Err(unsupported(
            "the #** synchronized read",
            "read inputs and outputs directly, or use ASCII",
        ))
    }

    fn read_synchronized(&mut self, _t: &mut Transport) -> Result<SynchronizedIo, C29uError> {
        Err(unsupported(
            "the #** synchronized read",
            "read inputs and outputs directly, or use ASCII",
        ))
    }

    fn raw(&mut self, t: &mut Transport, body: &[u8]) -> Result<Vec<u8>, C29uError> {
        let frame = seal(body);
        let name = describe_frame(body);
        let port = t.port();
        let (id, gap) = (self.id, Some(self.gap()));
        // 10-15: host OK is the one request that gets no answer.
        let expects = !matches!(body, [_, 0x46, 0x2F, ..]);
        t.with_retries(|t| {
            let timeout = t.timeout;
            let mut reader = FrameReader::for_answers();
            let mut fed = 0;
            t.exchange(&frame, expects, gap, None, |received| {
                let fresh = received.get(fed..).unwrap_or_default();
                fed = received.len();
                reader.push(fresh).into_iter().next()
            })
            .map_err(|e| exchange_fault(e, &port, id, &name, timeout, false))
        })
    }
}
