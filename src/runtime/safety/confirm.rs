//! One device's safe state, written and confirmed: a TRP-C29U's safe value written and the
//! outputs read back, a TRC1000's safe relay selected and a request after it answered. The
//! one way the runner's end, a safe state during the run, the guardian and `rigscript safe`
//! reach a safe state: a module's word that it took a write is not taken for it (a module can
//! acknowledge writes it does not apply, or refuse them claiming a safe mode it is not in).

use crate::device::c29u::C29u;
use crate::device::trc1000::Trc1000;
use crate::link::PacketLink;
use crate::runtime::devices::DeviceError;

/// A device's driver and the safe state to confirm on it.
pub enum SafeDriver<'a> {
    /// A TRP-C29U and its DO safe value.
    C29u {
        /// The driver (its retries are the caller's choice).
        driver: &'a mut C29u,
        /// The DO byte to write and read back.
        safe_value: u8,
    },
    /// A TRC1000 and its safe relay.
    Trc1000 {
        /// The driver.
        driver: &'a mut Trc1000<Box<dyn PacketLink>>,
        /// The relay to select.
        relay: u8,
    },
}

/// What the device was found holding once its safe state was confirmed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SafeReading {
    /// A TRP-C29U's outputs, read back (the safe value).
    Outputs(u8),
    /// A TRC1000's relay, selected and confirmed by the answer to a request after it.
    Relay(u8),
}

/// Why a device's safe state is not confirmed.
#[derive(Debug, thiserror::Error)]
pub enum Unconfirmed {
    /// The device did not answer (or garbled), to the write or to the read after it.
    #[error("no answer: {0}")]
    NoAnswer(#[source] DeviceError),
    /// The module refused the write and its outputs read another value.
    #[error("it refused the write ({error}) and its outputs read {read:#04x}, not {safe:#04x}")]
    Refused {
        /// The refusal.
        #[source]
        error: DeviceError,
        /// The outputs read after it.
        read: u8,
        /// The safe value.
        safe: u8,
    },
    /// The module acknowledged the write but its outputs read another value.
    #[error(
        "it acknowledged {safe:#04x} but its outputs read {read:#04x}: it does not apply what \
         it is sent"
    )]
    Ignored {
        /// The outputs read after the write.
        read: u8,
        /// The safe value.
        safe: u8,
    },
    /// Anything else the driver refused (a relay number out of range).
    #[error("{0}")]
    Failed(#[source] DeviceError),
}

impl Unconfirmed {
    /// What the device's outputs read, when it answered that far.
    pub fn read_back(&self) -> Option<u8> {
        match self {
            Unconfirmed::Refused { read, .. } | Unconfirmed::Ignored { read, .. } => Some(*read),
            Unconfirmed::NoAnswer(_) | Unconfirmed::Failed(_) => None,
        }
    }

    /// Whether the device answered nothing (as opposed to answering with something else).
    pub fn is_no_answer(&self) -> bool {
        matches!(self, Unconfirmed::NoAnswer(_))
    }
}

/// Writes the safe state through `target` and confirms it, in up to `tries` tries (at least
/// one): a TRP-C29U's safe value counts as reached only when its outputs read it back after
/// the write (a module in safe mode that refuses the write counts if it holds the safe value);
/// a TRC1000's relay when a request after the selection is answered. Each try is a write and
/// a read, so a silent device costs `tries` x 2 timeouts of the driver's at most.
pub fn confirm_safe_state(target: SafeDriver<'_>, tries: u32) -> Result<SafeReading, Unconfirmed> {
    match target {
        SafeDriver::C29u { driver, safe_value } => {
            retry(tries, || confirm_outputs(&mut *driver, safe_value))
        }
        SafeDriver::Trc1000 { driver, relay } => retry(tries, || {
            driver
                .select_relay_confirmed(relay)
                .map(|_| SafeReading::Relay(relay))
                .map_err(|e| unconfirmed(DeviceError::from(e)))
        }),
    }
}

fn retry(
    tries: u32,
    mut once: impl FnMut() -> Result<SafeReading, Unconfirmed>,
) -> Result<SafeReading, Unconfirmed> {
    let mut result = once();
    for _ in 1..tries {
        if result.is_ok() {
            break;
        }
        result = once();
    }
    result
}

/// A driver's error as a reason for no confirmation.
fn unconfirmed(e: DeviceError) -> Unconfirmed {
    if e.is_comm_failure() || e.is_cancelled() {
        Unconfirmed::NoAnswer(e)
    } else {
        Unconfirmed::Failed(e)
    }
}

/// One try at a module: the write, then the outputs read back whatever the write's answer.
fn confirm_outputs(driver: &mut C29u, safe: u8) -> Result<SafeReading, Unconfirmed> {
    let written = match driver.write_outputs(safe).map_err(DeviceError::from) {
        Err(e) if e.is_comm_failure() || e.is_cancelled() => return Err(Unconfirmed::NoAnswer(e)),
        other => other,
    };
    let read = driver
        .read_outputs()
        .map_err(|e| unconfirmed(DeviceError::from(e)))?;
    match written {
        _ if read == safe => Ok(SafeReading::Outputs(read)),
        Ok(()) => Err(Unconfirmed::Ignored { read, safe }),
        Err(error) => Err(Unconfirmed::Refused { error, read, safe }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::testing::{TestRig, IO, PANEL};
    use crate::sim::c29u::OutputFault;

    fn confirm_io(r: &mut TestRig, tries: u32) -> Result<SafeReading, Unconfirmed> {
        let driver = r.rt.devices.c29u(IO).unwrap().driver();
        confirm_safe_state(
            SafeDriver::C29u {
                driver,
                safe_value: 0x05,
            },
            tries,
        )
    }

    #[test]
    fn a_safe_value_counts_only_when_the_outputs_read_it_back() {
        let mut r = TestRig::started();
        r.rt.devices
            .c29u(IO)
            .unwrap()
            .driver()
            .write_outputs(0x1F)
            .unwrap();
        assert_eq!(confirm_io(&mut r, 1).unwrap(), SafeReading::Outputs(0x05));

        r.rt.devices
            .c29u(IO)
            .unwrap()
            .driver()
            .write_outputs(0x1F)
            .unwrap();
        r.sim
            .set_output_fault("io", Some(OutputFault::Ignore))
            .unwrap();
        let before = r.requests();
        let u = confirm_io(&mut r, 2).unwrap_err();
        assert!(
            matches!(
                u,
                Unconfirmed::Ignored {
                    read: 0x1F,
                    safe: 0x05
                }
            ),
            "{u}"
        );
        assert_eq!(r.requests() - before, 4, "two tries of a write and a read");

        r.sim
            .set_output_fault("io", Some(OutputFault::Refuse(0x04)))
            .unwrap();
        let u = confirm_io(&mut r, 1).unwrap_err();
        assert_eq!(u.read_back(), Some(0x1F));
        assert!(u.to_string().contains("(04)"), "{u}");

        r.sim.set_gone("io", true).unwrap();
        assert!(confirm_io(&mut r, 1).unwrap_err().is_no_answer());
    }

    #[test]
    fn a_relay_counts_only_when_a_request_after_the_selection_is_answered() {
        let mut r = TestRig::started();
        let confirm = |r: &mut TestRig| {
            let driver = r.rt.devices.trc(PANEL).unwrap().driver();
            confirm_safe_state(SafeDriver::Trc1000 { driver, relay: 3 }, 1)
        };
        assert_eq!(confirm(&mut r).unwrap(), SafeReading::Relay(3));
        r.sim.set_gone("panel", true).unwrap();
        assert!(confirm(&mut r).unwrap_err().is_no_answer());
    }
}
