//! Outputs: what the script wants (the DO byte, the relay), noted during the tick and written
//! at its end, one transaction per device, only where it changed; the safe state instead
//! while everything is held safe.

use super::devices::Device;
use super::state::Runtime;

impl<H: Clone> Runtime<H> {
    /// Sets the DO byte the script wants on the TRP-C29U at `idx` (written at the end of the
    /// tick).
    pub fn set_outputs(&mut self, idx: usize, value: u8) {
        let cause = self.cause.clone();
        if let Some(d) = self.c29u(idx) {
            if d.outputs != value {
                d.outputs = value;
                d.outputs_cause = cause;
            }
        }
    }

    /// Sets the relay the script wants on the TRC1000 at `idx` (selected at the end of the
    /// tick).
    pub fn set_relay(&mut self, idx: usize, relay: u8) {
        let cause = self.cause.clone();
        if let Some(d) = self.trc(idx) {
            if d.relay != relay {
                d.relay = relay;
                d.relay_cause = cause;
            }
        }
    }

    /// Puts what the script wants back to the safe values (a restarted script starts from
    /// them); a TRC1000 without a safe relay keeps its relay.
    pub fn reset_outputs(&mut self) {
        for d in &mut self.devices {
            match d {
                Device::Trc(t) => {
                    if let Some(r) = t.config.safe_relay {
                        t.relay = r;
                    }
                }
                Device::C29u(c) => c.outputs = c.config.safe_value,
            }
        }
    }

    /// Writes what changed, one transaction per device: the DO byte the script wants (the
    /// safe value while held safe), the relay it wants (the safe relay while held safe).
    pub fn flush_outputs(&mut self) {
        for idx in 0..self.devices.len() {
            if !self.online(idx) {
                continue;
            }
            let held = self.held_safe;
            let result = match self.devices.get_mut(idx) {
                Some(Device::Trc(d)) => {
                    let target = if held {
                        d.config.safe_relay
                    } else {
                        Some(d.relay)
                    };
                    match target {
                        Some(relay) if d.relay_written != Some(relay) => {
                            let before = d.relay_written;
                            let line = format!(
                                "{}: relay {} -> {relay} ({})",
                                d.name,
                                before.map_or("?".to_string(), |r| r.to_string()),
                                if held { "held safe" } else { &d.relay_cause }
                            );
                            d.select_relay(relay).map(|()| Some(line))
                        }
                        _ => Ok(None),
                    }
                }
                Some(Device::C29u(d)) => {
                    let target = if held { d.config.safe_value } else { d.outputs };
                    if d.outputs_written == Some(target) {
                        Ok(None)
                    } else {
                        let before = d.outputs_written;
                        let line = format!(
                            "{}: outputs {} -> {target:#04x} ({})",
                            d.name,
                            before.map_or("?".to_string(), |v| format!("{v:#04x}")),
                            if held { "held safe" } else { &d.outputs_cause }
                        );
                        d.write_outputs(target).map(|()| Some(line))
                    }
                }
                None => Ok(None),
            };
            match result {
                Ok(Some(line)) => self.log.activity(&line),
                Ok(None) => {}
                Err(e) if e.is_safe_mode() => self.regain_control(idx),
                Err(e) => {
                    if !e.is_comm_failure() {
                        let name = self.device_name(idx);
                        self.log
                            .error(&format!("{name}: writing outputs failed: {e}"));
                    }
                    self.note_failure(idx, &e);
                }
            }
        }
    }
}
