//! The TRP-C29U driver's ASCII back end (manual section 8).

use super::transport::{AttemptFault, Transport};
use super::{
    exchange_fault, Backend, C29uError, ConfigChange, CounterEdge, Firmware, Preset, PresetWrite,
    Settings, SynchronizedIo, WatchdogInfo,
};
use crate::protocol::c29u_ascii::{
    checksum, parse_answer, Answer, AsciiError, BaudCode, Channel, DataFormat, LatchLevel,
    ModuleName, Request, WatchdogReading, CR,
};

/// Cuts an answer at its CR (8: every answer ends with one).
fn line_frame(received: &[u8]) -> Option<Vec<u8>> {
    let end = received.iter().position(|&b| b == CR)?;
    received.get(..=end).map(<[u8]>::to_vec)
}

/// The ASCII back end: the module's ID and checksum setting.
pub(crate) struct AsciiBackend {
    id: u8,
    checksum: bool,
}

impl AsciiBackend {
    pub fn new(id: u8, checksum: bool) -> Self {
        Self { id, checksum }
    }

    fn call(&mut self, t: &mut Transport, request: &Request) -> Result<Answer, C29uError> {
        self.call_noting(t, request, &mut None)
    }

    /// As `call`, keeping in `refusal` the module's answer to the last attempt when it could not
    /// be taken (for the safe-mode rule, which needs it as the module said it).
    fn call_noting(
        &mut self,
        t: &mut Transport,
        request: &Request,
        refusal: &mut Option<AsciiError>,
    ) -> Result<Answer, C29uError> {
        let frame = request.encode(self.id, self.checksum);
        // Worded only when something went wrong (a poll must cost little).
        let name = || {
            format!(
                "`{}`",
                String::from_utf8_lossy(frame.strip_suffix(&[CR]).unwrap_or(&frame))
            )
        };
        let (id, with_checksum) = (self.id, self.checksum);
        let expects = request.expects_answer();
        t.with_retries(|t| {
            *refusal = None;
            let timeout = t.timeout;
            let answer = t
                .exchange(&frame, expects, None, None, line_frame)
                .map_err(|e| exchange_fault(e, &t.port(), id, &name(), timeout, true))?;
            if !expects {
                return Ok(Answer::Done);
            }
            parse_answer(request, &answer, with_checksum, id).map_err(|e| {
                let fault = classify(&e, &t.port(), id, &name());
                *refusal = Some(e);
                fault
            })
        })
    }

    fn expect_done(&mut self, t: &mut Transport, request: &Request) -> Result<(), C29uError> {
        match self.call(t, request)? {
            Answer::Done | Answer::OutputWritten => Ok(()),
            other => Err(self.unexpected(t, request, &other)),
        }
    }

    fn unexpected(&self, t: &Transport, request: &Request, answer: &Answer) -> C29uError {
        C29uError::Garbled {
            port: t.port(),
            id: self.id,
            request: format!("{request:?}"),
            detail: format!("unexpected answer {answer:?}"),
        }
    }

    /// An output write; a refusal is safe mode by the rule of [`AsciiError::means_safe_mode`]
    /// (the watchdog is read after a refusal that does not say so itself).
    fn write(&mut self, t: &mut Transport, request: &Request) -> Result<(), C29uError> {
        let mut refusal = None;
        let error = match self.call_noting(t, request, &mut refusal) {
            Ok(Answer::Done | Answer::OutputWritten) => return Ok(()),
            Ok(other) => return Err(self.unexpected(t, request, &other)),
            Err(e) => e,
        };
        let Some(refusal) = refusal.filter(AsciiError::is_output_refusal) else {
            return Err(error);
        };
        let watchdog = if refusal == AsciiError::SafeMode {
            None
        } else {
            self.watchdog_reading(t).ok()
        };
        if refusal.means_safe_mode(watchdog) {
            Err(C29uError::SafeMode {
                port: t.port(),
                id: self.id,
            })
        } else {
            Err(error)
        }
    }

    fn watchdog_reading(&mut self, t: &mut Transport) -> Result<WatchdogReading, C29uError> {
        match self.call(t, &Request::ReadWatchdog)? {
            Answer::Watchdog(reading) => Ok(reading),
            other => Err(self.unexpected(t, &Request::ReadWatchdog, &other)),
        }
    }

    fn channel(channel: u8) -> Result<Channel, C29uError> {
        Channel::new(channel)
            .ok_or_else(|| C29uError::InvalidArgument(format!("channel {channel}: use 0-7")))
    }

    /// The hex-counter setting, which `$ID2` cannot report: a counter answer's digit count tells.
    fn hex_counters(&mut self, t: &mut Transport) -> Result<bool, C29uError> {
        match self.call(t, &Request::ReadCounter(Self::channel(0)?))? {
            Answer::Counter { hex, .. } => Ok(hex),
            other => Err(self.unexpected(t, &Request::ReadCounter(Self::channel(0)?), &other)),
        }
    }
}

fn classify(e: &AsciiError, port: &str, id: u8, request: &str) -> AttemptFault {
    let refused = |reason: &str| {
        AttemptFault::Final(C29uError::Refused {
            port: port.to_string(),
            id,
            request: request.to_string(),
            reason: reason.to_string(),
        })
    };
    match e {
        AsciiError::InvalidCommand => {
            refused("invalid command (it answered `?`); check the protocol switch and the command")
        }
        AsciiError::ParameterError => refused("parameter error (it answered `!` instead of `>`)"),
        AsciiError::SafeMode => AttemptFault::Final(C29uError::SafeMode {
            port: port.to_string(),
            id,
        }),
        AsciiError::Malformed { .. }
        | AsciiError::WrongId { .. }
        | AsciiError::BadChecksum { .. } => AttemptFault::Retry(C29uError::Garbled {
            port: port.to_string(),
            id,
            request: request.to_string(),
            detail: e.to_string(),
        }),
        AsciiError::NoAnswerExpected => AttemptFault::Final(C29uError::Garbled {
            port: port.to_string(),
            id,
            request: request.to_string(),
            detail: e.to_string(),
        }),
    }
}

impl Backend for AsciiBackend {
    fn id(&self) -> u8 {
        self.id
    }

    fn read_io(&mut self, t: &mut Transport) -> Result<(u8, u8), C29uError> {
        match self.call(t, &Request::ReadDio)? {
            Answer::Dio { outputs, inputs } => Ok((outputs, inputs)),
            other => Err(self.unexpected(t, &Request::ReadDio, &other)),
        }
    }

    fn read_outputs(&mut self, t: &mut Transport) -> Result<u8, C29uError> {
        self.read_io(t).map(|(outputs, _)| outputs)
    }

    fn read_inputs_raw(&mut self, t: &mut Transport) -> Result<u8, C29uError> {
        self.read_io(t).map(|(_, inputs)| inputs)
    }

    fn write_outputs(&mut self, t: &mut Transport, value: u8) -> Result<(), C29uError> {
        self.write(t, &Request::WriteOutputs(value))
    }

    fn write_output(&mut self, t: &mut Transport, channel: u8, on: bool) -> Result<(), C29uError> {
        self.write(
            t,
            &Request::WriteOutput {
                channel: Self::channel(channel)?,
                on,
            },
        )
    }

    fn read_counter(&mut self, t: &mut Transport, channel: u8) -> Result<u16, C29uError> {
        let request = Request::ReadCounter(Self::channel(channel)?);
        match self.call(t, &request)? {
            Answer::Counter { value, .. } => Ok(value),
            other => Err(self.unexpected(t, &request, &other)),
        }
    }

    fn read_counters(&mut self, t: &mut Transport) -> Result<[u16; 8], C29uError> {
        let mut counters = [0u16; 8];
        for (channel, slot) in (0u8..).zip(counters.iter_mut()) {
            *slot = self.read_counter(t, channel)?;
        }
        Ok(counters)
    }

    fn clear_counter(&mut self, t: &mut Transport, channel: u8) -> Result<(), C29uError> {
        self.expect_done(t, &Request::ClearCounter(Self::channel(channel)?))
    }

    fn clear_counters(&mut self, t: &mut Transport) -> Result<(), C29uError> {
        self.expect_done(t, &Request::ClearCounters)
    }

    fn save_counters(&mut self, t: &mut Transport) -> Result<(), C29uError> {
        self.expect_done(t, &Request::SaveCounters)
    }

    fn read_latches(&mut self, t: &mut Transport) -> Result<(u8, u8), C29uError> {
        let mut read = |level| {
            let request = Request::ReadLatch(level);
            match self.call(t, &request)? {
                Answer::Latch(byte) => Ok(byte),
                other => Err(self.unexpected(t, &request, &other)),
            }
        };
        Ok((read(LatchLevel::Low)?, read(LatchLevel::High)?))
    }

    fn clear_latches(&mut self, t: &mut Transport) -> Result<(), C29uError> {
        self.expect_done(t, &Request::ClearLatch)
    }

    fn set_watchdog(&mut self, t: &mut Transport, tenths: u8) -> Result<(), C29uError> {
        if tenths == 0 {
            self.expect_done(t, &Request::DisableWatchdog)
        } else {
            self.expect_done(t, &Request::EnableWatchdog(tenths))
        }
    }

    fn watchdog(&mut self, t: &mut Transport) -> Result<WatchdogInfo, C29uError> {
        let reading = self.watchdog_reading(t)?;
        Ok(WatchdogInfo {
            enabled: reading.timeout().is_some(),
            timeout_tenths: reading.timeout().map_or(0, |t| t.tenths()),
            expired: Some(reading.fired()),
        })
    }

    fn host_ok(&mut self, t: &mut Transport) -> Result<(), C29uError> {
        self.expect_done(t, &Request::HostOk)
    }

    fn read_preset(&mut self, t: &mut Transport, preset: Preset) -> Result<u8, C29uError> {
        let request = Request::ReadPreset(preset);
        match self.call(t, &request)? {
            Answer::Preset { outputs, .. } => Ok(outputs),
            other => Err(self.unexpected(t, &request, &other)),
        }
    }

    fn set_preset(
        &mut self,
        t: &mut Transport,
        preset: Preset,
        value: u8,
        how: PresetWrite,
    ) -> Result<(), C29uError> {
        // 8-24 stores the current outputs: a value they hold already is stored without a pulse.
        let before = self.read_outputs(t)?;
        if before == value {
            return self.expect_done(t, &Request::SavePreset(preset));
        }
        if how == PresetWrite::KeepOutputs {
            return Err(C29uError::PresetDrivesOutputs {
                port: t.port(),
                id: self.id,
                checksum: self.checksum,
                preset,
                value,
                outputs: before,
            });
        }
        self.write_outputs(t, value)?;
        let stored = self.expect_done(t, &Request::SavePreset(preset));
        self.write_outputs(t, before)?;
        stored
    }

    fn save_outputs_as(&mut self, t: &mut Transport, preset: Preset) -> Result<(), C29uError> {
        self.expect_done(t, &Request::SavePreset(preset))
    }

    fn name(&mut self, t: &mut Transport) -> Result<String, C29uError> {
        match self.call(t, &Request::ReadName)? {
            Answer::Name(name) => Ok(name.as_str().to_string()),
            other => Err(self.unexpected(t, &Request::ReadName, &other)),
        }
    }

    fn set_name(&mut self, t: &mut Transport, name: &str) -> Result<(), C29uError> {
        let name = ModuleName::new(name).ok_or_else(|| {
            C29uError::InvalidArgument(format!(
                "name {name:?} is not possible: use 1-6 printable ASCII characters"
            ))
        })?;
        self.expect_done(t, &Request::SetName(name))
    }

    fn firmware(&mut self, t: &mut Transport) -> Result<Firmware, C29uError> {
        match self.call(t, &Request::ReadFirmware)? {
            Answer::Firmware(version) => Ok(Firmware {
                text: version.text().to_string(),
                date: version
                    .date()
                    .map(|d| (2000 + u16::from(d.year), d.month, d.day)),
            }),
            other => Err(self.unexpected(t, &Request::ReadFirmware, &other)),
        }
    }

    fn settings(&mut self, t: &mut Transport) -> Result<Settings, C29uError> {
        match self.call(t, &Request::ReadConfig)? {
            Answer::Config(report) => Ok(Settings {
                id: self.id,
                baud: report.baud().map(BaudCode::baud),
                checksum: Some(report.checksum()),
                counter_edge: Some(if report.falling_edge() {
                    CounterEdge::Falling
                } else {
                    CounterEdge::Rising
                }),
                model: Some(report.model()),
            }),
            other => Err(self.unexpected(t, &Request::ReadConfig, &other)),
        }
    }

    fn configure(&mut self, t: &mut Transport, change: &ConfigChange) -> Result<(), C29uError> {
        let current = self.settings(t)?;
        let hex_counters = match change.hex_counters {
            Some(hex) => hex,
            None => self.hex_counters(t)?,
        };
        let baud = match change.baud.or(current.baud) {
            Some(rate) => BaudCode::from_baud(rate).ok_or_else(|| {
                C29uError::InvalidArgument(format!(
                    "{rate} baud is not possible: use 1200, 2400, 4800, 9600, 19200, 38400, 57600 or 115200"
                ))
            })?,
            None => return Err(C29uError::InvalidArgument("the module reports no valid baud code; give --new-baud".into())),
        };
        let format = DataFormat {
            falling_edge: change.counter_edge.or(current.counter_edge)
                == Some(CounterEdge::Falling),
            checksum: change
                .checksum
                .or(current.checksum)
                .unwrap_or(self.checksum),
            hex_counters,
        };
        let new_id = change.id.unwrap_or(self.id);
        self.expect_done(
            t,
            &Request::Configure {
                new_id,
                baud,
                format,
            },
        )?;
        // 8-1: from now on the module answers with the new ID, speed and checksum setting.
        self.id = new_id;
        self.checksum = format.checksum;
        if change.baud.is_some() {
            t.set_baud(baud.baud())?;
        }
        Ok(())
    }

    fn reset(&mut self, t: &mut Transport) -> Result<(), C29uError> {
        self.expect_done(t, &Request::Reset)
    }

    fn take_reset_flag(&mut self, t: &mut Transport) -> Result<bool, C29uError> {
        match self.call(t, &Request::ReadResetStatus)? {
            Answer::ResetStatus(flag) => Ok(flag),
            other => Err(self.unexpected(t, &Request::ReadResetStatus, &other)),
        }
    }

    fn set_led_mode(&mut self, t: &mut Transport, on: bool) -> Result<(), C29uError> {
        match self.call(t, &Request::SetLedMode(on))? {
            Answer::Led(_) | Answer::Done => Ok(()),
            other => Err(self.unexpected(t, &Request::SetLedMode(on), &other)),
        }
    }

    fn synchronize(&mut self, t: &mut Transport) -> Result<(), C29uError> {
        self.expect_done(t, &Request::Synchronize)
    }

    fn read_synchronized(&mut self, t: &mut Transport) -> Result<SynchronizedIo, C29uError> {
        match self.call(t, &Request::ReadSynchronized)? {
            Answer::Synchronized(data) => Ok(SynchronizedIo {
                fresh: data.fresh,
                outputs: data.outputs,
                inputs: data.inputs_wire,
            }),
            other => Err(self.unexpected(t, &Request::ReadSynchronized, &other)),
        }
    }

    fn raw(&mut self, t: &mut Transport, body: &[u8]) -> Result<Vec<u8>, C29uError> {
        let mut frame = body.to_vec();
        if self.checksum {
            frame.extend_from_slice(format!("{:02X}", checksum(body)).as_bytes());
        }
        frame.push(CR);
        let name = format!("`{}`", String::from_utf8_lossy(body));
        let port = t.port();
        let id = self.id;
        // 8-22, 8-25: broadcasts get no answer, so there is none to wait for.
        let expects = !(body.starts_with(b"~**") || body.starts_with(b"#**"));
        t.with_retries(|t| {
            let timeout = t.timeout;
            t.exchange(&frame, expects, None, None, line_frame)
                .map_err(|e| exchange_fault(e, &port, id, &name, timeout, true))
        })
    }
}
